//! The benchmark harness: warm-up, N timed submissions, GPU time from timestamp queries,
//! statistics (JSON and PNG output go through [`crate::io`] and [`plot`]).

pub mod all;
pub mod ao;
pub mod btf;
pub mod compare;
pub mod env;
pub mod frame;
pub mod peak;
pub mod plot;
pub mod roofline;
pub mod srbf;
pub mod srbf_compare;
pub mod sss;

use crate::error::{Error, Result};
use crate::gpu::{Context, Recorder};
use serde::Serialize;

pub use crate::report::{MachineInfo, Stats};

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

/// GPU time of each of `kernel`'s passes over `warmup + samples` submissions of one frame
/// (median and spread in each [`Stats`]), in the order of [`crate::kernels::Kernel::passes`].
pub fn time_passes<K: crate::kernels::Kernel>(
    ctx: &Context,
    cfg: &BenchConfig,
    kernel: &K,
    input: &K::Input,
) -> Result<Vec<(&'static str, Stats)>> {
    let names: Vec<&'static str> = kernel.passes().iter().map(|p| p.name).collect();
    let stats = time_gpu_passes(ctx, cfg, &names, |rec| kernel.record(rec, input))?;
    Ok(names.into_iter().zip(stats).collect())
}

/// As [`time_gpu`], for several passes of the same submissions (one `Stats` per pass, in
/// the order of `passes`). A name joining passes with `+` (`pose skin+ao skin`) times their
/// sum in each submission.
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
            let mut sum = 0.0;
            for part in pass.split('+') {
                sum += t.get(part).ok_or_else(|| {
                    Error::InvalidArgument(format!(
                        "benchmark pass '{part}' was not timed (no timestamps on this queue, or the pass was never opened)"
                    ))
                })?;
            }
            out.push(sum);
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
    Stats::of(&samples).unwrap_or_else(Stats::none)
}
pub mod soak;
