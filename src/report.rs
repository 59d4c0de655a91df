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
    /// First and third quartiles (linear interpolation between order statistics).
    pub q1: f64,
    pub q3: f64,
    /// Relative interquartile range (q3 - q1) / median: the noise figure `bench all` and
    /// `bench compare` use (robust to one slow outlier, unlike `spread`).
    pub iqr_rel: f64,
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
        let (q1, q3) = (quantile(&v, 0.25), quantile(&v, 0.75));
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
            q1,
            q3,
            iqr_rel: if median > 0.0 {
                (q3 - q1) / median
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
            q1: f64::NAN,
            q3: f64::NAN,
            iqr_rel: 0.0,
        }
    }
}

/// The `p` quantile (0..=1) of sorted, non-empty `v`, interpolating linearly between order
/// statistics (the "type 7" estimator of R and numpy's default).
pub fn quantile(v: &[f64], p: f64) -> f64 {
    let x = p.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x.fract());
    match v.get(i + 1) {
        Some(&next) => v[i] + (next - v[i]) * f,
        None => v[i],
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
