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
    /// The host CPU as Linux names it: model name, family, model and stepping, the vector
    /// extensions a CPU device compiles for (avx2, avx512f), and the kernel's
    /// gather-data-sampling status; "unknown" where /proc/cpuinfo cannot be read. lavapipe's
    /// times depend on the host's microarchitecture as much as on its peaks (a gather, which
    /// every per-lane image load is, costs many times more on a CPU with that mitigation), so
    /// two recordings compare only beside these.
    pub host_cpu: String,
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
            host_cpu: host_cpu(),
        }
    }
}

/// [`MachineInfo::host_cpu`].
pub fn host_cpu() -> String {
    let Ok(info) = std::fs::read_to_string("/proc/cpuinfo") else {
        return "unknown".into();
    };
    let gds =
        std::fs::read_to_string("/sys/devices/system/cpu/vulnerabilities/gather_data_sampling")
            .map(|s| s.trim().to_string())
            .unwrap_or_else(|_| "unknown".into());
    describe_cpu(&info, &gds)
}

/// The description [`host_cpu`] gives of the first processor in a /proc/cpuinfo text, with
/// `gds` the gather-data-sampling status.
pub fn describe_cpu(cpuinfo: &str, gds: &str) -> String {
    let first = cpuinfo.split("\n\n").next().unwrap_or("");
    let field = |name: &str| {
        first.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == name).then(|| v.trim().to_string())
        })
    };
    let flags = field("flags").unwrap_or_default();
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    let vector: Vec<&str> = ["avx2", "avx512f"].into_iter().filter(|f| has(f)).collect();
    format!(
        "{} (family {}, model {}, stepping {}; {}; gather data sampling: {gds})",
        field("model name").unwrap_or_else(|| "unknown model".into()),
        field("cpu family").unwrap_or_else(|| "?".into()),
        field("model").unwrap_or_else(|| "?".into()),
        field("stepping").unwrap_or_else(|| "?".into()),
        if vector.is_empty() {
            "no avx2".to_string()
        } else {
            vector.join(" ")
        }
    )
}

#[cfg(test)]
mod tests {
    use super::describe_cpu;

    #[test]
    fn the_host_cpu_is_described_from_the_first_processor() {
        let info = "processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 85\n\
                    model name\t: Intel(R) Xeon(R) Platinum 8259CL CPU @ 2.50GHz\nstepping\t: 7\n\
                    flags\t\t: fpu sse2 avx avx2 avx512f avx512dq\n\n\
                    processor\t: 1\nmodel name\t: something else\n";
        assert_eq!(
            describe_cpu(info, "Mitigation: Microcode"),
            "Intel(R) Xeon(R) Platinum 8259CL CPU @ 2.50GHz (family 6, model 85, stepping 7; \
             avx2 avx512f; gather data sampling: Mitigation: Microcode)"
        );
        // A field missing or flags without AVX2: said so, not guessed.
        let old = "model name\t: Old CPU\ncpu family\t: 6\nflags\t: sse2 sse4_2\n";
        assert_eq!(
            describe_cpu(old, "unknown"),
            "Old CPU (family 6, model ?, stepping ?; no avx2; gather data sampling: unknown)"
        );
        assert!(describe_cpu("", "unknown").starts_with("unknown model"));
    }
}
