//! Rooflines that bind: a kernel's documented work model (samples, gathers, FLOPs, bytes per
//! frame) against the rates `bench peak` measures, in the same run.
//!
//! A work model is a list of [`Term`]s, each a count per frame of one resource named by its
//! peak key (`fma` in FLOP, `stream` in bytes, a probe's key such as
//! `buffer_gather_coherent` in its unit). Each resource alone bounds the frame's time from
//! below by count / rate; the largest of those bounds is the roofline that **binds**, and
//! the kernel's fraction of it is that bound over the measured time (1.0: running at that
//! resource's measured peak). Counts are models, not hardware counters: each kernel's module
//! documents what it counts and what it leaves out (so a fraction is a lower bound of the
//! resource's true use when the model leaves work out).

use super::BenchConfig;
use crate::error::Result;
use crate::gpu::Context;
use serde::Serialize;
use std::collections::BTreeMap;

/// Measured rates per second by peak key.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Rates(pub BTreeMap<String, f64>);

impl Rates {
    pub fn insert(&mut self, key: &str, per_s: f64) {
        self.0.insert(key.to_string(), per_s);
    }

    pub fn get(&self, key: &str) -> Option<f64> {
        self.0
            .get(key)
            .copied()
            .filter(|r| r.is_finite() && *r > 0.0)
    }

    /// The FMA peak in GFLOP/s (NaN when not measured).
    pub fn fma_gflops(&self) -> f64 {
        self.get("fma").map_or(f64::NAN, |r| r * 1e-9)
    }

    /// The mean of two measurements of each rate (the peaks before and after `bench all`'s
    /// kernels); a key measured once keeps its one value.
    pub fn mean(a: &Rates, b: &Rates) -> Rates {
        let mut out = a.clone();
        for (k, v) in &b.0 {
            out.0
                .entry(k.clone())
                .and_modify(|x| *x = 0.5 * (*x + v))
                .or_insert(*v);
        }
        out
    }
}

/// `count` units of `resource` per frame.
#[derive(Clone, Debug, Serialize)]
pub struct Term {
    pub resource: String,
    pub what: String,
    pub count: f64,
}

impl Term {
    pub fn new(resource: &str, what: impl Into<String>, count: f64) -> Term {
        Term {
            resource: resource.to_string(),
            what: what.into(),
            count,
        }
    }
}

/// One resource's bound: the model's total count of it over its measured rate.
#[derive(Clone, Debug, Serialize)]
pub struct Bound {
    pub resource: String,
    pub count: f64,
    pub rate_per_s: f64,
    pub bound_ms: f64,
    /// bound_ms / the measured time.
    pub fraction: f64,
}

/// A kernel's place under its rooflines.
#[derive(Clone, Debug, Serialize)]
pub struct Roofline {
    /// What the measured time covers (the passes the model counts).
    pub covers: String,
    pub measured_ms: f64,
    pub terms: Vec<Term>,
    /// Per resource, the largest bound first.
    pub bounds: Vec<Bound>,
    /// The resource whose bound is largest: the roofline that binds.
    pub binding: String,
    /// Its bound / the measured time.
    pub fraction: f64,
    /// The FLOP term's fraction of the FMA peak (the figure the benchmarks gave before).
    pub fma_fraction: Option<f64>,
    /// Resources of the model with no measured rate (left out of the bounds).
    pub unmeasured: Vec<String>,
}

impl Roofline {
    /// The model's terms against `rates` for a measured time of `measured_ms`.
    pub fn evaluate(covers: &str, terms: Vec<Term>, measured_ms: f64, rates: &Rates) -> Roofline {
        let mut totals: BTreeMap<&str, f64> = BTreeMap::new();
        for t in &terms {
            *totals.entry(t.resource.as_str()).or_default() += t.count;
        }
        let mut bounds = Vec::new();
        let mut unmeasured = Vec::new();
        for (res, count) in totals {
            match rates.get(res) {
                Some(rate) => {
                    let bound_ms = count / rate * 1e3;
                    bounds.push(Bound {
                        resource: res.to_string(),
                        count,
                        rate_per_s: rate,
                        bound_ms,
                        fraction: bound_ms / measured_ms,
                    });
                }
                None => unmeasured.push(res.to_string()),
            }
        }
        bounds.sort_by(|a, b| b.bound_ms.total_cmp(&a.bound_ms));
        let (binding, fraction) = bounds
            .first()
            .map_or((String::from("none"), f64::NAN), |b| {
                (b.resource.clone(), b.fraction)
            });
        let fma_fraction = bounds
            .iter()
            .find(|b| b.resource == "fma")
            .map(|b| b.fraction);
        Roofline {
            covers: covers.to_string(),
            measured_ms,
            terms,
            bounds,
            binding,
            fraction,
            fma_fraction,
            unmeasured,
        }
    }

    /// One line: the binding roofline, the fraction of it, the FMA fraction beside.
    pub fn summary(&self) -> String {
        let fma = self.fma_fraction.map_or(String::from("no FLOP term"), |f| {
            format!("{:.1}% of the FMA peak", 100.0 * f)
        });
        let next = self
            .bounds
            .get(1)
            .map(|b| format!("; next {} {:.1}%", b.resource, 100.0 * b.fraction))
            .unwrap_or_default();
        format!(
            "binds: {} at {:.1}% of its peak{next}; {fma} ({})",
            self.binding,
            100.0 * self.fraction,
            self.covers
        )
    }
}

/// The rates a work model needs, measured now: FMA (unless `fma_gflops` is given), streaming
/// if named, and each named probe, all short (1 warm-up, 5 samples, <= 20 ms a submission).
pub fn measure_rates(
    ctx: &Context,
    cfg: &BenchConfig,
    terms: &[Term],
    fma_gflops: Option<f64>,
) -> Result<Rates> {
    let short = BenchConfig {
        warmup: 1,
        samples: 5,
        min_submit_ms: cfg.min_submit_ms.min(20.0),
    };
    let mut rates = Rates::default();
    let mut keys: Vec<&str> = terms.iter().map(|t| t.resource.as_str()).collect();
    keys.sort_unstable();
    keys.dedup();
    match fma_gflops {
        Some(g) => rates.insert("fma", g * 1e9),
        None => rates.insert(
            "fma",
            super::peak::run_fma(ctx, &short, &mut |_| {})?.throughput_median * 1e9,
        ),
    }
    if keys.contains(&"stream") {
        let s = super::peak::run_stream(ctx, &short, &mut |_| {})?;
        rates.insert("stream", s.throughput_median * 1e9);
    }
    let kinds = super::peak::kinds_of(&keys)?;
    let (probes, _) = super::peak::run_probes(ctx, &short, &kinds, &mut |_| {})?;
    for p in probes {
        rates.insert(&p.key, p.rate_per_s);
    }
    Ok(rates)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_bound_binds_and_terms_of_one_resource_add() {
        let mut rates = Rates::default();
        rates.insert("fma", 1e9);
        rates.insert("buffer_gather_coherent", 1e6);
        // 1e6 FLOP: 1 ms; 2 x 1500 loads: 3 ms; measured 6 ms.
        let r = Roofline::evaluate(
            "test",
            vec![
                Term::new("fma", "flop", 1e6),
                Term::new("buffer_gather_coherent", "a", 1500.0),
                Term::new("buffer_gather_coherent", "b", 1500.0),
                Term::new("atomic_spread", "unmeasured", 1.0),
            ],
            6.0,
            &rates,
        );
        assert_eq!(r.binding, "buffer_gather_coherent");
        assert!((r.fraction - 0.5).abs() < 1e-12);
        assert!((r.fma_fraction.unwrap() - 1.0 / 6.0).abs() < 1e-12);
        assert_eq!(r.unmeasured, vec!["atomic_spread".to_string()]);
    }
}
