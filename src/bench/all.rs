//! `vkshade bench all`: the device peaks, then every kernel's headline (and the character
//! frame) in interleaved rounds, then the peaks again; one JSON, a summary table, one plot.
//!
//! Method (what a reader needs to trust the figures):
//! - **Setup once** per kernel (meshes, trees, transfers, texture-space geometry), outside
//!   any timing.
//! - **Rounds**: each round measures every kernel once (`warmup` + `samples` submissions of
//!   its headline, the median GPU ms; its CPU twin once, wall clock), in an order rotated by
//!   one each round, so slow drift of the machine hits every kernel alike rather than the
//!   last ones.
//! - **Figures** are the median over the rounds with the interquartile range (IQR); a
//!   figure whose relative IQR exceeds `noise_bound` is flagged, as is a round whose own
//!   submissions spread more than that.
//! - **Peaks before and after**: every probe of `bench peak` at the start and at the end;
//!   the FMA and streaming peaks differing by more than `noise_bound` says the machine
//!   changed speed during the run. The rooflines use the mean of the two.

use super::peak::PeakReport;
use super::roofline::{Rates, Roofline, Term};
use super::{BenchConfig, MachineInfo, Stats};
use crate::error::Result;
use crate::gpu::Context;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// One kernel's measurement in one round.
#[derive(Clone, Debug, Serialize)]
pub struct Round {
    pub kernel: &'static str,
    /// The headline configuration, in words.
    pub headline: String,
    /// Median GPU ms of the whole headline frame over the round's submissions.
    pub gpu_ms: f64,
    /// The largest relative IQR of the round's timed passes over its submissions.
    pub within_iqr_rel: f64,
    /// The work model of one frame.
    pub terms: Vec<Term>,
    /// What the work model covers, and the median GPU ms of that part.
    pub covers: &'static str,
    pub covered_ms: f64,
    /// The CPU twin's wall ms (NaN: none; `null` in JSON).
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub cpu_ms: f64,
    /// The fps target of bench/targets.json, if any.
    pub target_fps: Option<f64>,
}

/// Settings of `bench all`.
#[derive(Clone, Debug, Serialize)]
pub struct AllConfig {
    /// Rounds over the kernels.
    pub rounds: usize,
    /// Each kernel's measurement in a round.
    pub bench: BenchConfig,
    /// The peak probes before and after.
    pub peak: BenchConfig,
    /// Relative IQR above which a figure is flagged as noisy.
    pub noise_bound: f64,
    /// Kernels to run, in order: ao, sss, srbf, btf, frame.
    pub kernels: Vec<String>,
}

/// Every kernel `bench all` knows, in its default order.
pub const KERNELS: &[&str] = &["ao", "sss", "srbf", "btf", "frame"];

impl Default for AllConfig {
    fn default() -> Self {
        AllConfig {
            rounds: 5,
            bench: BenchConfig {
                warmup: 1,
                samples: 5,
                min_submit_ms: 20.0,
            },
            peak: BenchConfig {
                warmup: 1,
                samples: 5,
                min_submit_ms: 20.0,
            },
            noise_bound: 0.10,
            kernels: KERNELS.iter().map(|k| k.to_string()).collect(),
        }
    }
}

/// One figure over repeated measurements: what `bench compare` reads.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Figure {
    /// `KERNEL.fps`, `KERNEL.gpu_ms`, `KERNEL.binding_fraction`, `KERNEL.vs_cpu`, `peak.KEY`.
    pub name: String,
    pub unit: String,
    pub higher_is_better: bool,
    /// One value per repeat (round, or before/after for the peaks).
    pub values: Vec<f64>,
    /// NaN (`null` in JSON) where no value was measured.
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub median: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub q1: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub q3: f64,
    /// (q3 - q1) / median.
    pub iqr_rel: f64,
    /// iqr_rel above the run's noise bound.
    pub noisy: bool,
}

impl Figure {
    /// The figure of `values` (non-finite ones dropped; None when none is left).
    pub fn of(
        name: &str,
        unit: &str,
        higher_is_better: bool,
        values: &[f64],
        noise_bound: f64,
    ) -> Option<Figure> {
        let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        let s = Stats::of(&finite)?;
        Some(Figure {
            name: name.to_string(),
            unit: unit.to_string(),
            higher_is_better,
            values: finite,
            median: s.median,
            q1: s.q1,
            q3: s.q3,
            iqr_rel: s.iqr_rel,
            noisy: s.iqr_rel > noise_bound,
        })
    }
}

/// One kernel's line of the summary.
#[derive(Clone, Debug, Serialize)]
pub struct KernelSummary {
    pub kernel: String,
    pub headline: String,
    pub fps: Figure,
    pub gpu_ms: Figure,
    /// The binding roofline at the median time (rates: the mean of the peaks before and
    /// after), with every bound.
    pub roofline: Roofline,
    /// The binding fraction per round (same rates), over the rounds.
    pub binding_fraction: Figure,
    /// The CPU twin's time over the GPU time, per round (None: no twin).
    pub vs_cpu: Option<Figure>,
    pub target_fps: Option<f64>,
    /// PASS or MISS on the median fps; "-" without a target.
    pub target: String,
}

/// A peak before and after the kernels.
#[derive(Clone, Debug, Serialize)]
pub struct Drift {
    pub key: String,
    pub before: f64,
    pub after: f64,
    /// after / before.
    pub ratio: f64,
}

/// What `bench all` writes (DIR/all.json).
#[derive(Clone, Debug, Serialize)]
pub struct AllReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    /// UTC date and time of the start, ISO 8601.
    pub date: String,
    pub config: AllConfig,
    /// Wall seconds of the whole run, the kernels' setup included.
    pub wall_s: f64,
    pub peak_before: PeakReport,
    pub peak_after: PeakReport,
    /// Every peak rate after / before.
    pub peak_drift: Vec<Drift>,
    pub kernels: Vec<KernelSummary>,
    /// Every figure (what `bench compare` compares): kernels' fps, binding fraction and
    /// speed-up over the CPU twin, and every peak (before and after as two repeats).
    pub figures: Vec<Figure>,
    pub warnings: Vec<String>,
    /// Every round's raw measurements, round by round.
    pub rounds: Vec<Vec<Round>>,
}

/// A kernel's setup, measured once per round.
pub struct Entry<'a> {
    pub name: &'static str,
    pub round: Box<dyn Fn() -> Result<Round> + 'a>,
}

/// The UTC date and time of `t` (seconds since 1970), ISO 8601.
pub fn iso_date(t: u64) -> String {
    let (days, secs) = ((t / 86_400) as i64, t % 86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
}

/// Runs the peaks, the kernels' rounds and the peaks again. `entries` hold the kernels'
/// setups (made by the caller, which owns their configurations); `progress` gets a line per
/// step.
pub fn run(
    ctx: &Context,
    cfg: &AllConfig,
    entries: &[Entry<'_>],
    progress: &mut dyn FnMut(&str),
) -> Result<AllReport> {
    let start = Instant::now();
    let date = iso_date(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
    );
    let t = Instant::now();
    let peak_before = super::peak::run(ctx, &cfg.peak, &mut |_| {})?;
    progress(&format!(
        "peaks before the kernels: FMA {:.1} GFLOP/s, stream {:.2} GB/s, {} probes ({:.1} s)",
        peak_before.fma_gflops,
        peak_before.bandwidth_gb_s,
        peak_before.probes.len(),
        t.elapsed().as_secs_f64()
    ));
    let mut rounds: Vec<Vec<Round>> = Vec::new();
    let t = Instant::now();
    for r in 0..cfg.rounds.max(1) {
        let mut this = Vec::new();
        for k in 0..entries.len() {
            let e = &entries[(k + r) % entries.len()];
            let m = (e.round)()?;
            progress(&format!(
                "round {}: {:<6} {:>9.3} ms GPU ({:.1} fps, IQR {:.1}% over its submissions){}",
                r + 1,
                m.kernel,
                m.gpu_ms,
                1000.0 / m.gpu_ms,
                100.0 * m.within_iqr_rel,
                if m.cpu_ms.is_finite() {
                    format!(", CPU twin {:.1} ms", m.cpu_ms)
                } else {
                    String::new()
                }
            ));
            this.push(m);
        }
        rounds.push(this);
    }
    progress(&format!(
        "{} round(s) in {:.1} s",
        rounds.len(),
        t.elapsed().as_secs_f64()
    ));
    let t = Instant::now();
    let peak_after = super::peak::run(ctx, &cfg.peak, &mut |_| {})?;
    progress(&format!(
        "peaks after the kernels: FMA {:.1} GFLOP/s, stream {:.2} GB/s ({:.1} s)",
        peak_after.fma_gflops,
        peak_after.bandwidth_gb_s,
        t.elapsed().as_secs_f64()
    ));
    let mut report = summarise(
        cfg,
        MachineInfo::of(ctx),
        date,
        peak_before,
        peak_after,
        rounds,
        entries.iter().map(|e| e.name).collect(),
    );
    report.wall_s = start.elapsed().as_secs_f64();
    Ok(report)
}

/// The summary of measured rounds and peaks (no GPU: the figures, rooflines and warnings).
pub fn summarise(
    cfg: &AllConfig,
    machine: MachineInfo,
    date: String,
    peak_before: PeakReport,
    peak_after: PeakReport,
    rounds: Vec<Vec<Round>>,
    order: Vec<&'static str>,
) -> AllReport {
    let bound = cfg.noise_bound;
    let (rb, ra) = (peak_before.rates(), peak_after.rates());
    let rates = Rates::mean(&rb, &ra);
    let mut warnings = Vec::new();
    let mut peak_drift = Vec::new();
    let mut figures = Vec::new();
    for (key, before) in &rb.0 {
        let Some(after) = ra.0.get(key).copied() else {
            continue;
        };
        let ratio = after / before;
        if matches!(key.as_str(), "fma" | "stream") && (ratio - 1.0).abs() > bound {
            warnings.push(format!(
                "the {key} peak changed by {:+.0}% between the start and the end of the run: the machine's speed changed under the kernels",
                100.0 * (ratio - 1.0)
            ));
        }
        peak_drift.push(Drift {
            key: key.clone(),
            before: *before,
            after,
            ratio,
        });
        let unit = match key.as_str() {
            "fma" => "FLOP/s".to_string(),
            "stream" => "bytes/s".to_string(),
            _ => peak_before
                .probes
                .iter()
                .find(|p| &p.key == key)
                .map_or(String::from("/s"), |p| format!("{}/s", p.unit)),
        };
        figures.extend(Figure::of(
            &format!("peak.{key}"),
            &unit,
            true,
            &[*before, after],
            bound,
        ));
    }
    let mut kernels = Vec::new();
    for name in order {
        let mine: Vec<&Round> = rounds
            .iter()
            .flatten()
            .filter(|m| m.kernel == name)
            .collect();
        let Some(first) = mine.first() else { continue };
        let fps: Vec<f64> = mine.iter().map(|m| 1000.0 / m.gpu_ms).collect();
        let ms: Vec<f64> = mine.iter().map(|m| m.gpu_ms).collect();
        let fractions: Vec<f64> = mine
            .iter()
            .map(|m| Roofline::evaluate(m.covers, m.terms.clone(), m.covered_ms, &rates).fraction)
            .collect();
        let vs_cpu: Vec<f64> = mine.iter().map(|m| m.cpu_ms / m.gpu_ms).collect();
        let Some(fps) = Figure::of(&format!("{name}.fps"), "fps", true, &fps, bound) else {
            continue;
        };
        let Some(gpu_ms) = Figure::of(&format!("{name}.gpu_ms"), "ms", false, &ms, bound) else {
            continue;
        };
        let covered: Vec<f64> = mine.iter().map(|m| m.covered_ms).collect();
        let covered = Stats::of(&covered).map_or(f64::NAN, |s| s.median);
        let roofline = Roofline::evaluate(first.covers, first.terms.clone(), covered, &rates);
        let binding_fraction = Figure::of(
            &format!("{name}.binding_fraction"),
            &format!("of {}", roofline.binding),
            true,
            &fractions,
            bound,
        )
        .unwrap_or_else(|| Figure {
            name: format!("{name}.binding_fraction"),
            unit: "none".into(),
            higher_is_better: true,
            values: vec![],
            median: f64::NAN,
            q1: f64::NAN,
            q3: f64::NAN,
            iqr_rel: 0.0,
            noisy: false,
        });
        let vs_cpu = Figure::of(&format!("{name}.vs_cpu"), "x", true, &vs_cpu, bound);
        for f in [Some(&fps), Some(&binding_fraction), vs_cpu.as_ref()]
            .into_iter()
            .flatten()
        {
            if f.noisy {
                warnings.push(format!(
                    "{}: spread over {} rounds is {:.0}% (IQR / median), above the {:.0}% bound",
                    f.name,
                    f.values.len(),
                    100.0 * f.iqr_rel,
                    100.0 * bound
                ));
            }
        }
        for (r, m) in mine.iter().enumerate() {
            if m.within_iqr_rel > bound {
                warnings.push(format!(
                    "{name}, round {}: its submissions spread {:.0}% (IQR / median)",
                    r + 1,
                    100.0 * m.within_iqr_rel
                ));
            }
        }
        let target = match first.target_fps {
            Some(t) if fps.median >= t => "PASS",
            Some(_) => "MISS",
            None => "-",
        };
        figures.push(fps.clone());
        figures.push(gpu_ms.clone());
        figures.push(binding_fraction.clone());
        figures.extend(vs_cpu.clone());
        kernels.push(KernelSummary {
            kernel: name.to_string(),
            headline: first.headline.clone(),
            fps,
            gpu_ms,
            roofline,
            binding_fraction,
            vs_cpu,
            target_fps: first.target_fps,
            target: target.to_string(),
        });
    }
    AllReport {
        benchmark: "all",
        machine,
        date,
        config: cfg.clone(),
        wall_s: 0.0,
        peak_before,
        peak_after,
        peak_drift,
        kernels,
        figures,
        warnings,
        rounds,
    }
}

/// The summary table (Markdown), one line per kernel, then the peaks and the warnings.
pub fn table(r: &AllReport) -> String {
    let mut s = String::new();
    let pct = |f: f64| {
        if f.is_finite() {
            format!("{:.1}%", 100.0 * f)
        } else {
            "-".into()
        }
    };
    s.push_str(&format!(
        "{} ({}, {}), {} rounds x {} submissions, {}\n\nhost CPU: {}\n\n",
        r.machine.device,
        r.machine.driver,
        r.date,
        r.config.rounds,
        r.config.bench.samples,
        format_args!("{:.0} s", r.wall_s),
        r.machine.host_cpu
    ));
    s.push_str("| kernel | headline | fps (IQR) | binding roofline | fraction of it (IQR) | FMA fraction | vs CPU twin | target |\n");
    s.push_str("|---|---|---|---|---|---|---|---|\n");
    for k in &r.kernels {
        s.push_str(&format!(
            "| {} | {} | {:.1} ({:.1}%) | {} | {} ({:.1}%) | {} | {} | {} |\n",
            k.kernel,
            k.headline,
            k.fps.median,
            100.0 * k.fps.iqr_rel,
            k.roofline.binding,
            pct(k.binding_fraction.median),
            100.0 * k.binding_fraction.iqr_rel,
            k.roofline.fma_fraction.map_or("-".into(), pct),
            k.vs_cpu
                .as_ref()
                .map_or("-".into(), |f| format!("{:.2}x", f.median)),
            match k.target_fps {
                Some(t) => format!("{} (>= {t})", k.target),
                None => "-".into(),
            }
        ));
    }
    let drift = |key: &str, unit: &str| {
        r.peak_drift
            .iter()
            .find(|d| d.key == key)
            .map_or("-".into(), |d| {
                format!(
                    "{}{unit} -> {}{unit} ({:+.1}%)",
                    super::peak::si(d.before),
                    super::peak::si(d.after),
                    100.0 * (d.ratio - 1.0)
                )
            })
    };
    s.push_str(&format!(
        "\npeaks before -> after: FMA {}; stream {}\n",
        drift("fma", "FLOP/s"),
        drift("stream", "B/s")
    ));
    for w in &r.warnings {
        s.push_str(&format!("warning: {w}\n"));
    }
    s
}

/// One summary plot: each kernel's fps per round over its median (drift and noise), and
/// the peaks' after / before.
pub fn panels(r: &AllReport) -> Vec<super::plot::Panel> {
    use super::plot::{Panel, Series};
    let series = r
        .kernels
        .iter()
        .map(|k| Series {
            name: format!("{} ({:.1} fps)", k.kernel, k.fps.median),
            points: k
                .fps
                .values
                .iter()
                .enumerate()
                .map(|(i, v)| ((i + 1) as f64, v / k.fps.median))
                .collect(),
        })
        .collect();
    // One point per kernel (its own series, so the legend names its binding roofline).
    let fractions = r
        .kernels
        .iter()
        .enumerate()
        .filter(|(_, k)| k.binding_fraction.median.is_finite())
        .map(|(i, k)| Series {
            name: format!("{} {}: {}", i + 1, k.kernel, k.roofline.binding),
            points: vec![((i + 1) as f64, k.binding_fraction.median)],
        })
        .collect();
    vec![
        Panel {
            title: format!("bench all: fps per round / median, {}", r.machine.device),
            x_label: "round".into(),
            y_label: "fps / median".into(),
            log_x: false,
            log_y: false,
            series,
        },
        Panel {
            title: "fraction of the binding roofline (median over the rounds)".into(),
            x_label: "kernel".into(),
            y_label: "fraction".into(),
            log_x: false,
            log_y: false,
            series: fractions,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_are_iso_utc() {
        assert_eq!(iso_date(0), "1970-01-01T00:00:00Z");
        // 2000-03-01 (after a leap day of a century leap year), 12:34:56.
        assert_eq!(iso_date(951_914_096), "2000-03-01T12:34:56Z");
        assert_eq!(iso_date(1_798_761_599), "2026-12-31T23:59:59Z");
    }

    #[test]
    fn figures_drop_non_finite_values_and_flag_noise() {
        let f = Figure::of(
            "x.fps",
            "fps",
            true,
            &[10.0, f64::NAN, 10.0, 14.0, 10.0],
            0.05,
        )
        .unwrap();
        assert_eq!(f.values.len(), 4);
        assert_eq!(f.median, 10.0);
        // Quartiles of [10, 10, 10, 14]: 10 and 11 (type 7).
        assert!((f.q3 - 11.0).abs() < 1e-12);
        assert!(f.noisy);
        assert!(Figure::of("y", "", true, &[f64::NAN], 0.1).is_none());
    }
}
