//! Pieces every JSON report shares, whichever command writes it: the identity of the machine
//! a result was measured on, and order statistics of repeated measurements.

use crate::gpu::Context;
use serde::Serialize;

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

    /// The statistics of no valid sample: every value NaN.
    pub fn none() -> Stats {
        Stats {
            n: 0,
            median: f64::NAN,
            min: f64::NAN,
            max: f64::NAN,
            mean: f64::NAN,
            spread: 0.0,
        }
    }
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
