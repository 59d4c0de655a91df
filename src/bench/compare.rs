//! `vkshade bench compare A.json B.json [--threshold PCT]`: two `bench all` runs, figure by
//! figure.
//!
//! For each figure in both runs: the ratio of the medians B / A, and whether the change is
//! beyond the noise of both runs: |B / A - 1| larger than the larger of the two relative
//! interquartile ranges (a change inside either run's own spread is not evidence). A kernel's
//! speed (`KERNEL.fps`, `KERNEL.gpu_ms`) that got worse beyond the noise *and* by more than
//! the threshold is a **regression**; the command exits non-zero when there is one. The
//! other figures are shown with their verdicts for context and never fail the comparison:
//! the peaks (a machine whose peaks moved moves its kernels' figures too), the binding
//! fractions (they move with the peaks measured in each run, and the binding roofline itself
//! can change between runs) and the ratios to the CPU twins (the twin's wall time has its
//! own noise).

use super::all::Figure;
use crate::error::{Error, Result};
use serde::Serialize;
use std::path::Path;

/// The figures of a `bench all` JSON and where they came from.
#[derive(Clone, Debug)]
pub struct Run {
    pub path: String,
    pub device: String,
    pub date: String,
    pub figures: Vec<Figure>,
}

impl Run {
    /// Reads `path` (a `bench all` JSON): an error naming the file and what is wrong.
    pub fn load(path: &Path) -> Result<Run> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::InvalidArgument(format!("{name}: cannot read it: {e}")))?;
        Run::parse(&name, &text)
    }

    /// Parses the text of a `bench all` JSON named `name`.
    pub fn parse(name: &str, text: &str) -> Result<Run> {
        let v: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| Error::InvalidArgument(format!("{name}: not JSON: {e}")))?;
        let figures = v.get("figures").ok_or_else(|| {
            Error::InvalidArgument(format!(
                "{name}: no \"figures\" array (is it the all.json of `vkshade bench all`?)"
            ))
        })?;
        let figures: Vec<Figure> = serde_json::from_value(figures.clone())
            .map_err(|e| Error::InvalidArgument(format!("{name}: bad \"figures\": {e}")))?;
        let text_of =
            |v: Option<&serde_json::Value>| v.and_then(|v| v.as_str()).unwrap_or("?").to_string();
        Ok(Run {
            path: name.to_string(),
            device: text_of(v.pointer("/machine/device")),
            date: text_of(v.get("date")),
            figures,
        })
    }
}

/// How one figure changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Verdict {
    /// Better beyond the noise of both runs.
    Better,
    /// Worse beyond the noise, by no more than the threshold.
    Worse,
    /// Worse beyond the noise and by more than the threshold (kernel speed figures only).
    Regression,
    /// Inside the spread of one run or the other.
    WithinNoise,
}

/// One figure of both runs.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub name: String,
    pub unit: String,
    pub a: f64,
    pub b: f64,
    /// b / a.
    pub ratio: f64,
    /// The larger relative IQR of the two runs.
    pub noise: f64,
    pub verdict: Verdict,
}

/// The comparison of two runs.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    pub threshold: f64,
    pub rows: Vec<Row>,
    /// Figures in one run only.
    pub only_in_a: Vec<String>,
    pub only_in_b: Vec<String>,
}

impl Comparison {
    /// The regressions (kernel figures worse beyond noise and threshold).
    pub fn regressions(&self) -> Vec<&Row> {
        self.rows
            .iter()
            .filter(|r| r.verdict == Verdict::Regression)
            .collect()
    }
}

/// Whether a figure can fail a comparison: a kernel's speed.
fn gates(name: &str) -> bool {
    name.ends_with(".fps") || name.ends_with(".gpu_ms")
}

/// Compares the figures of `a` and `b`; `threshold` is a fraction (0.05: 5%).
pub fn compare(a: &Run, b: &Run, threshold: f64) -> Comparison {
    let mut rows = Vec::new();
    let mut only_in_a = Vec::new();
    for fa in &a.figures {
        let Some(fb) = b.figures.iter().find(|f| f.name == fa.name) else {
            only_in_a.push(fa.name.clone());
            continue;
        };
        let ratio = fb.median / fa.median;
        let noise = fa.iqr_rel.max(fb.iqr_rel);
        // The change in the figure's good direction (> 0 better).
        let gain = if fa.higher_is_better {
            ratio - 1.0
        } else {
            1.0 / ratio - 1.0
        };
        let beyond = (ratio - 1.0).abs() > noise && ratio.is_finite();
        let gates = gates(&fa.name);
        let verdict = if !beyond {
            Verdict::WithinNoise
        } else if gain > 0.0 {
            Verdict::Better
        } else if gates && -gain > threshold {
            Verdict::Regression
        } else {
            Verdict::Worse
        };
        rows.push(Row {
            name: fa.name.clone(),
            unit: fa.unit.clone(),
            a: fa.median,
            b: fb.median,
            ratio,
            noise,
            verdict,
        });
    }
    let only_in_b = b
        .figures
        .iter()
        .filter(|f| !a.figures.iter().any(|g| g.name == f.name))
        .map(|f| f.name.clone())
        .collect();
    Comparison {
        threshold,
        rows,
        only_in_a,
        only_in_b,
    }
}

/// The comparison as text: one line per figure, kernels first.
pub fn render(a: &Run, b: &Run, c: &Comparison) -> String {
    let mut s = format!(
        "A: {} ({}, {})\nB: {} ({}, {})\nthreshold {:.1}%; a change counts when |B/A - 1| exceeds the larger relative IQR of the two runs\n\n",
        a.path,
        a.device,
        a.date,
        b.path,
        b.device,
        b.date,
        100.0 * c.threshold
    );
    s.push_str(&format!(
        "{:<44} {:>12} {:>12} {:>8} {:>7}  verdict\n",
        "figure", "A", "B", "B/A", "noise"
    ));
    let mut rows: Vec<&Row> = c.rows.iter().collect();
    rows.sort_by_key(|r| r.name.starts_with("peak."));
    for r in rows {
        s.push_str(&format!(
            "{:<44} {:>12.4e} {:>12.4e} {:>8.3} {:>6.1}%  {}\n",
            r.name,
            r.a,
            r.b,
            r.ratio,
            100.0 * r.noise,
            match r.verdict {
                Verdict::Better => "better",
                Verdict::Worse if gates(&r.name) => "worse (within threshold)",
                Verdict::Worse => "worse (context: never fails)",
                Verdict::Regression => "REGRESSION",
                Verdict::WithinNoise => "within noise",
            }
        ));
    }
    for (which, names) in [("A", &c.only_in_a), ("B", &c.only_in_b)] {
        if !names.is_empty() {
            s.push_str(&format!("only in {which}: {}\n", names.join(", ")));
        }
    }
    for fa in &a.figures {
        if let Some(fb) = b.figures.iter().find(|f| f.name == fa.name)
            && fa.name.ends_with(".binding_fraction")
            && fa.unit != fb.unit
        {
            s.push_str(&format!(
                "note: {}: the binding roofline changed ({} in A, {} in B)\n",
                fa.name, fa.unit, fb.unit
            ));
        }
    }
    if let Some(p) = c.rows.iter().find(|r| r.name == "peak.fma")
        && p.verdict != Verdict::WithinNoise
    {
        s.push_str(&format!(
            "note: the FMA peak differs between the runs (B/A {:.2}): the machines or their load differ, so kernel figures move with them\n",
            p.ratio
        ));
    }
    let n = c.regressions().len();
    s.push_str(&format!(
        "{n} regression(s) beyond {:.1}%\n",
        100.0 * c.threshold
    ));
    s
}

/// The README's results table from `bench all` JSONs, one `(name, text)` per recorded
/// machine: per machine a heading (device, driver, date, host CPUs and their model, the FMA
/// and streaming peaks before and after), then one row per kernel. Nothing is typed by hand.
pub fn readme_table(runs: &[(String, String)]) -> Result<String> {
    let mut s = String::new();
    for (name, text) in runs {
        let v: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| Error::InvalidArgument(format!("{name}: not JSON: {e}")))?;
        let missing = |what: &str| {
            Error::InvalidArgument(format!("{name}: no {what} (not a bench all JSON?)"))
        };
        let str_at = |p: &str| {
            v.pointer(p)
                .and_then(|x| x.as_str())
                .ok_or_else(|| missing(p))
        };
        let num_at = |v: &serde_json::Value, p: &str| {
            v.pointer(p).and_then(|x| x.as_f64()).unwrap_or(f64::NAN)
        };
        let kernels = v
            .get("kernels")
            .and_then(|k| k.as_array())
            .ok_or_else(|| missing("kernels"))?;
        s.push_str(&format!(
            "**{}** ({}; {} host CPUs, {}), `bench all` of {} ({} rounds): FMA {:.1} / {:.1} GFLOP/s, stream {:.2} / {:.2} GB/s (before / after the kernels)\n\n",
            str_at("/machine/device")?,
            str_at("/machine/driver")?,
            num_at(&v, "/machine/host_cpus"),
            // (recordings made before the host CPU was recorded)
            v.pointer("/machine/host_cpu")
                .and_then(|x| x.as_str())
                .unwrap_or("CPU model not recorded"),
            str_at("/date")?,
            num_at(&v, "/config/rounds"),
            num_at(&v, "/peak_before/fma_gflops"),
            num_at(&v, "/peak_after/fma_gflops"),
            num_at(&v, "/peak_before/bandwidth_gb_s"),
            num_at(&v, "/peak_after/bandwidth_gb_s"),
        ));
        s.push_str("| kernel | headline | fps (IQR) | binding roofline | fraction of it | FMA fraction | vs CPU twin | target |\n");
        s.push_str("|---|---|---|---|---|---|---|---|\n");
        let pct = |f: f64| {
            if f.is_finite() {
                format!("{:.1}%", 100.0 * f)
            } else {
                "-".into()
            }
        };
        for k in kernels {
            let text = |p: &str| k.pointer(p).and_then(|x| x.as_str()).unwrap_or("-");
            let vs_cpu = num_at(k, "/vs_cpu/median");
            s.push_str(&format!(
                "| {} | {} | {:.1} ({:.1}%) | {} | {} | {} | {} | {} |\n",
                text("/kernel"),
                text("/headline"),
                num_at(k, "/fps/median"),
                100.0 * num_at(k, "/fps/iqr_rel"),
                text("/roofline/binding"),
                pct(num_at(k, "/binding_fraction/median")),
                pct(num_at(k, "/roofline/fma_fraction")),
                if vs_cpu.is_finite() {
                    format!("{vs_cpu:.2}x")
                } else {
                    "-".into()
                },
                match k.pointer("/target_fps").and_then(|x| x.as_f64()) {
                    Some(t) => format!("{} (>= {t})", text("/target")),
                    None => "-".into(),
                }
            ));
        }
        s.push('\n');
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fig(name: &str, higher: bool, values: &[f64]) -> Figure {
        Figure::of(name, "u", higher, values, 0.1).unwrap()
    }

    fn run(figures: Vec<Figure>) -> Run {
        Run {
            path: "x".into(),
            device: "d".into(),
            date: "t".into(),
            figures,
        }
    }

    #[test]
    fn lower_is_better_figures_turn_the_verdict_round() {
        // gpu ms 10 -> 12 (IQR ~1%): worse by 17% of speed, beyond noise and a 5% threshold.
        let a = run(vec![fig("k.gpu_ms", false, &[9.9, 10.0, 10.1])]);
        let b = run(vec![fig("k.gpu_ms", false, &[11.9, 12.0, 12.1])]);
        let c = compare(&a, &b, 0.05);
        assert_eq!(c.rows[0].verdict, Verdict::Regression);
        let c = compare(&b, &a, 0.05);
        assert_eq!(c.rows[0].verdict, Verdict::Better);
    }

    #[test]
    fn only_speed_figures_regress() {
        for name in ["peak.fma", "k.binding_fraction", "k.vs_cpu"] {
            let a = run(vec![fig(name, true, &[100.0, 100.0])]);
            let b = run(vec![fig(name, true, &[50.0, 50.0])]);
            assert_eq!(
                compare(&a, &b, 0.05).rows[0].verdict,
                Verdict::Worse,
                "{name}"
            );
        }
        let a = run(vec![fig("k.fps", true, &[100.0, 100.0])]);
        let b = run(vec![fig("k.fps", true, &[50.0, 50.0])]);
        assert_eq!(compare(&a, &b, 0.05).rows[0].verdict, Verdict::Regression);
    }
}
