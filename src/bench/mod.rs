//! The benchmark harness: warm-up, N timed submissions, GPU time from timestamp queries,
//! statistics, JSON and PNG output.

pub mod ao;
pub mod peak;
pub mod plot;

use crate::error::{Error, Result};
use crate::gpu::{Context, Recorder};
use serde::Serialize;
use std::path::Path;

/// How to time a kernel.
#[derive(Clone, Debug, Serialize)]
pub struct BenchConfig {
    /// Untimed submissions before sampling (driver warm-up, caches, JIT on lavapipe).
    pub warmup: usize,
    /// Timed submissions.
    pub samples: usize,
    /// Auto-sized benchmarks grow their work until one submission takes this long.
    pub min_submit_ms: f64,
}

impl Default for BenchConfig {
    fn default() -> Self {
        BenchConfig {
            warmup: 2,
            samples: 10,
            min_submit_ms: 100.0,
        }
    }
}

/// Order statistics of a set of samples (milliseconds unless stated).
#[derive(Clone, Debug, Serialize)]
pub struct Stats {
    pub n: usize,
    pub median: f64,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    /// Relative spread (max - min) / median.
    pub spread: f64,
}

impl Stats {
    /// Statistics of `samples`; `None` when empty or when any sample is not finite.
    pub fn of(samples: &[f64]) -> Option<Stats> {
        if samples.is_empty() || samples.iter().any(|s| !s.is_finite()) {
            return None;
        }
        let mut v = samples.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        let (min, max) = (v[0], v[n - 1]);
        Some(Stats {
            n,
            median,
            min,
            max,
            mean: v.iter().sum::<f64>() / n as f64,
            spread: if median > 0.0 {
                (max - min) / median
            } else {
                0.0
            },
        })
    }
}

/// Records `record` into a fresh command buffer `warmup + samples` times and returns the GPU
/// time of the pass `pass` that `record` opens, from timestamps.
pub fn time_gpu(
    ctx: &Context,
    cfg: &BenchConfig,
    pass: &str,
    record: impl FnMut(&mut Recorder) -> Result<()>,
) -> Result<Stats> {
    Ok(time_gpu_passes(ctx, cfg, &[pass], record)?.remove(0))
}

/// As [`time_gpu`], for several passes of the same submissions (one `Stats` per pass, in
/// the order of `passes`).
pub fn time_gpu_passes(
    ctx: &Context,
    cfg: &BenchConfig,
    passes: &[&str],
    mut record: impl FnMut(&mut Recorder) -> Result<()>,
) -> Result<Vec<Stats>> {
    let mut samples = vec![Vec::with_capacity(cfg.samples); passes.len()];
    for i in 0..cfg.warmup + cfg.samples.max(1) {
        let mut rec = ctx.recorder(passes.first().copied().unwrap_or("bench"))?;
        record(&mut rec)?;
        let t = rec.submit_and_wait()?;
        if i < cfg.warmup {
            continue;
        }
        for (pass, out) in passes.iter().zip(samples.iter_mut()) {
            out.push(t.get(pass).ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "benchmark pass '{pass}' was not timed (no timestamps on this queue, or the pass was never opened)"
                ))
            })?);
        }
    }
    passes
        .iter()
        .zip(&samples)
        .map(|(pass, s)| {
            Stats::of(s)
                .ok_or_else(|| Error::InvalidArgument(format!("no valid samples for '{pass}'")))
        })
        .collect()
}

/// Wall-clock milliseconds of `f` (median of `runs`, after one untimed run): for CPU
/// baselines measured beside the GPU.
pub fn time_cpu<T>(runs: usize, mut f: impl FnMut() -> T) -> Stats {
    std::hint::black_box(f());
    let samples: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let t = std::time::Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    Stats::of(&samples).unwrap_or(Stats {
        n: 0,
        median: f64::NAN,
        min: f64::NAN,
        max: f64::NAN,
        mean: f64::NAN,
        spread: 0.0,
    })
}

/// Checks up front that an output file can be created (its folder is made if missing), so a
/// long run does not fail at the end.
pub fn check_output(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let probe = dir.join(format!(".vkshade-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|e| Error::io(dir, e))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::InvalidArgument(format!("JSON encoding failed: {e}")))?;
    crate::shaders::write_atomic(path, format!("{text}\n").as_bytes())
}

/// Identity of the machine a result was measured on.
#[derive(Clone, Debug, Serialize)]
pub struct MachineInfo {
    pub device: String,
    pub device_type: String,
    pub driver: String,
    pub api_version: String,
    pub host_cpus: usize,
}

impl MachineInfo {
    pub fn of(ctx: &Context) -> Self {
        let i = ctx.info();
        MachineInfo {
            device: i.name.clone(),
            device_type: i.device_type.clone(),
            driver: i.driver.clone(),
            api_version: i.api_version.clone(),
            host_cpus: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
        }
    }
}
