//! `vkshade bench soak`: many frames of one kernel on one context, device memory and host
//! memory sampled as they go, to show that a long run neither grows nor leaks.
//!
//! Every `every` frames the run records the allocator's live bytes and reserved blocks
//! ([`Context::memory_report`]) and the process's resident set (`/proc/self/statm`). After
//! the run [`Verdict::of`] checks the curve flat past the warm-up:
//! - **device memory**: the largest `used_bytes` and `reserved_bytes` of the last quarter
//!   equal the first sample after the warm-up, exactly. A steady frame loop reuses its
//!   pools and readback buffers (see `gpu::recycle`), so any growth at all is a leak; the
//!   allocator's counters are exact, so no tolerance is needed.
//! - **host RSS**: the largest sample of the last quarter is within [`RSS_TOLERANCE`] (2%)
//!   of the first sample after the warm-up, or within [`RSS_SLACK_BYTES`] (4 MiB) of it,
//!   whichever is larger. The validation layer and malloc keep per-object state that
//!   settles in steps of a few hundred KiB (measured: see the CHANGELOG); a leak of one
//!   1 KiB object per frame grows 7.3 MiB over the last three quarters of 10,000 frames and
//!   is caught.
//!
//! The caller makes the context (validated, for the soak's purpose) and checks the messages
//! and leaks at shutdown; this module only drives frames and judges the curve.

use crate::error::{Error, Result};
use crate::gpu::Context;
use serde::Serialize;
use std::time::Instant;

/// Relative growth of host RSS allowed over the last quarter (see the module doc).
pub const RSS_TOLERANCE: f64 = 0.02;
/// Absolute growth of host RSS always allowed (see the module doc).
pub const RSS_SLACK_BYTES: u64 = 4 << 20;

/// One sample of the memory curve.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Sample {
    /// Frames completed when the sample was taken.
    pub frame: usize,
    /// Bytes of live device allocations (the allocator's report).
    pub device_used_bytes: u64,
    /// Bytes of device memory blocks the allocator holds.
    pub device_reserved_bytes: u64,
    /// Live device allocations.
    pub allocations: u64,
    /// Resident host memory of the process.
    pub rss_bytes: u64,
}

/// Settings of a soak run.
#[derive(Clone, Debug, Serialize)]
pub struct SoakConfig {
    /// Frames to run.
    pub frames: usize,
    /// Frames between samples.
    pub every: usize,
    /// Frames before the baseline sample (the first after them).
    pub warmup: usize,
}

impl SoakConfig {
    /// `frames` frames, about 100 samples, a warm-up of a tenth of the run (at least one
    /// sample interval).
    pub fn new(frames: usize) -> SoakConfig {
        let every = (frames / 100).max(1);
        SoakConfig {
            frames,
            every,
            warmup: (frames / 10).max(every),
        }
    }
}

/// Whether the curve stayed flat, and why not.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    /// The baseline: the first sample at or after the warm-up.
    pub baseline: Sample,
    /// The largest device `used_bytes` in the last quarter.
    pub last_quarter_device_used: u64,
    /// The largest device `reserved_bytes` in the last quarter.
    pub last_quarter_device_reserved: u64,
    /// The largest RSS in the last quarter.
    pub last_quarter_rss: u64,
    /// The RSS allowed in the last quarter.
    pub rss_allowed: u64,
    /// Empty when flat; else what grew.
    pub problems: Vec<String>,
}

impl Verdict {
    /// Judges `samples` of a run of `cfg` (see the module doc for the criterion).
    pub fn of(samples: &[Sample], cfg: &SoakConfig) -> Result<Verdict> {
        let baseline = *samples
            .iter()
            .find(|s| s.frame >= cfg.warmup)
            .ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "no sample after the warm-up of {} frames ({} samples)",
                    cfg.warmup,
                    samples.len()
                ))
            })?;
        let quarter = cfg.frames - cfg.frames / 4;
        let last: Vec<&Sample> = samples
            .iter()
            .filter(|s| s.frame >= quarter.max(baseline.frame))
            .collect();
        let max = |f: fn(&Sample) -> u64| last.iter().map(|s| f(s)).max().unwrap_or(0);
        let used = max(|s| s.device_used_bytes);
        let reserved = max(|s| s.device_reserved_bytes);
        let rss = max(|s| s.rss_bytes);
        let rss_allowed = baseline.rss_bytes
            + ((baseline.rss_bytes as f64 * RSS_TOLERANCE) as u64).max(RSS_SLACK_BYTES);
        let mut problems = Vec::new();
        if used > baseline.device_used_bytes {
            problems.push(format!(
                "device memory in use grew from {} to {} bytes",
                baseline.device_used_bytes, used
            ));
        }
        if reserved > baseline.device_reserved_bytes {
            problems.push(format!(
                "device memory reserved grew from {} to {} bytes",
                baseline.device_reserved_bytes, reserved
            ));
        }
        if rss > rss_allowed {
            problems.push(format!(
                "host RSS grew from {} to {} bytes (allowed {rss_allowed})",
                baseline.rss_bytes, rss
            ));
        }
        Ok(Verdict {
            baseline,
            last_quarter_device_used: used,
            last_quarter_device_reserved: reserved,
            last_quarter_rss: rss,
            rss_allowed,
            problems,
        })
    }
}

/// A soak run's curve and timing.
#[derive(Clone, Debug, Serialize)]
pub struct SoakReport {
    /// The kernel driven, in words.
    pub kernel: String,
    pub config: SoakConfig,
    pub samples: Vec<Sample>,
    /// Wall-clock seconds of the frames (setup excluded).
    pub wall_s: f64,
    /// Mean wall-clock ms per frame (submit and wait included).
    pub ms_per_frame: f64,
    pub verdict: Verdict,
}

/// Resident bytes of this process (`/proc/self/statm`, second field, in 4 KiB pages: the
/// page size of the x86-64 and aarch64 Linux kernels vkshade runs on).
pub fn rss_bytes() -> Result<u64> {
    let path = std::path::Path::new("/proc/self/statm");
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    text.split_whitespace()
        .nth(1)
        .and_then(|f| f.parse::<u64>().ok())
        .map(|pages| pages * 4096)
        .ok_or_else(|| Error::input(path, format!("no resident page count in {text:?}")))
}

fn sample(ctx: &Context, frame: usize) -> Result<Sample> {
    let m = ctx.memory_report();
    Ok(Sample {
        frame,
        device_used_bytes: m.used_bytes,
        device_reserved_bytes: m.reserved_bytes,
        allocations: m.allocations,
        rss_bytes: rss_bytes()?,
    })
}

/// Runs `frame` (one frame: record, submit, wait, check) `cfg.frames` times, sampling the
/// memory every `cfg.every` frames (and before the first), and judges the curve.
pub fn run(
    ctx: &Context,
    kernel: &str,
    cfg: &SoakConfig,
    frame: &mut dyn FnMut(usize) -> Result<()>,
    progress: &mut dyn FnMut(&str),
) -> Result<SoakReport> {
    if cfg.frames == 0 || cfg.every == 0 {
        return Err(Error::InvalidArgument(format!(
            "a soak needs at least one frame and a sample interval of one frame or more \
             (got {} frames, every {})",
            cfg.frames, cfg.every
        )));
    }
    let mut samples = vec![sample(ctx, 0)?];
    let t = Instant::now();
    for i in 0..cfg.frames {
        frame(i)?;
        let done = i + 1;
        if done % cfg.every == 0 || done == cfg.frames {
            ctx.maintain();
            samples.push(sample(ctx, done)?);
        }
        if done % (cfg.frames / 10).max(1) == 0 {
            let s = samples[samples.len() - 1];
            progress(&format!(
                "{kernel}: {done}/{} frames, device {} B in use, RSS {:.1} MiB, {:.2} ms/frame",
                cfg.frames,
                s.device_used_bytes,
                s.rss_bytes as f64 / (1 << 20) as f64,
                t.elapsed().as_secs_f64() * 1e3 / done as f64
            ));
        }
    }
    let wall_s = t.elapsed().as_secs_f64();
    let verdict = Verdict::of(&samples, cfg)?;
    Ok(SoakReport {
        kernel: kernel.to_string(),
        config: cfg.clone(),
        samples,
        wall_s,
        ms_per_frame: wall_s * 1e3 / cfg.frames as f64,
        verdict,
    })
}

/// The curve as CSV: frame, device used, device reserved, allocations, RSS.
pub fn csv(r: &SoakReport) -> String {
    let mut s =
        String::from("frame,device_used_bytes,device_reserved_bytes,allocations,rss_bytes\n");
    for x in &r.samples {
        s.push_str(&format!(
            "{},{},{},{},{}\n",
            x.frame, x.device_used_bytes, x.device_reserved_bytes, x.allocations, x.rss_bytes
        ));
    }
    s
}

/// The curve as plot panels (MiB against frames): device memory, and host RSS.
pub fn panels(r: &SoakReport) -> Vec<super::plot::Panel> {
    let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
    let series = |name: &str, f: &dyn Fn(&Sample) -> u64| super::plot::Series {
        name: name.into(),
        points: r
            .samples
            .iter()
            .map(|s| (s.frame as f64, mib(f(s))))
            .collect(),
    };
    vec![
        super::plot::Panel {
            title: format!("{}: device memory", r.kernel),
            x_label: "frame".into(),
            y_label: "MiB".into(),
            log_x: false,
            log_y: false,
            series: vec![
                series("in use", &|s| s.device_used_bytes),
                series("reserved", &|s| s.device_reserved_bytes),
            ],
        },
        super::plot::Panel {
            title: format!("{}: host RSS", r.kernel),
            x_label: "frame".into(),
            y_label: "MiB".into(),
            log_x: false,
            log_y: false,
            series: vec![series("RSS", &|s| s.rss_bytes)],
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(frame: usize, used: u64, rss: u64) -> Sample {
        Sample {
            frame,
            device_used_bytes: used,
            device_reserved_bytes: 64 << 20,
            allocations: 10,
            rss_bytes: rss,
        }
    }

    /// A flat curve passes; device growth of one byte, or RSS growth past the tolerance in
    /// the last quarter, fails; growth during the warm-up does not count.
    #[test]
    fn the_verdict_judges_the_last_quarter_against_the_baseline() {
        let cfg = SoakConfig {
            frames: 100,
            every: 10,
            warmup: 10,
        };
        let mb = 1u64 << 20;
        let curve = |f: &dyn Fn(usize) -> (u64, u64)| -> Vec<Sample> {
            (0..=10)
                .map(|k| {
                    let (u, r) = f(k * 10);
                    s(k * 10, u, r)
                })
                .collect()
        };
        let flat = curve(&|i| {
            if i == 0 {
                (0, 50 * mb)
            } else {
                (1000, 300 * mb)
            }
        });
        assert!(Verdict::of(&flat, &cfg).unwrap().problems.is_empty());
        let device = curve(&|i| (1000 + (i >= 80) as u64, 300 * mb));
        let v = Verdict::of(&device, &cfg).unwrap();
        assert_eq!(v.problems.len(), 1, "{:?}", v.problems);
        assert!(v.problems[0].contains("device memory in use"));
        // 2% of 300 MiB is 6 MiB: 5 MiB passes, 7 MiB fails.
        let ok = curve(&|i| (1000, 300 * mb + if i >= 80 { 5 * mb } else { 0 }));
        assert!(Verdict::of(&ok, &cfg).unwrap().problems.is_empty());
        let grew = curve(&|i| (1000, 300 * mb + if i >= 80 { 7 * mb } else { 0 }));
        assert!(Verdict::of(&grew, &cfg).unwrap().problems[0].contains("host RSS"));
        assert!(Verdict::of(&flat[..1], &cfg).is_err());
    }

    #[test]
    fn rss_is_read() {
        let r = rss_bytes().unwrap();
        assert!(r > 1 << 20, "{r}");
    }
}
