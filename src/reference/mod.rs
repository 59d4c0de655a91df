//! CPU ground truths (f32/f64, rayon): independent of the methods they judge. A truth uses
//! only the shared layers ([`crate::geom`]: ray-cast visibility, spherical Gaussians, and the
//! physics a method and its truth share, the diffusion profiles [`crate::geom::profile`] and
//! the synthetic cloth [`crate::geom::cloth`]; [`crate::scene`]); tests/layers.rs checks it.

pub mod ao;
pub mod btf;
pub mod srbf;
pub mod sss;

/// Error statistics of an estimate against a reference.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ErrorStats {
    pub n: usize,
    pub mae: f64,
    pub rmse: f64,
    pub p95: f64,
    pub max: f64,
    /// Mean signed error (estimate - reference): > 0 means too bright / too little occlusion.
    pub bias: f64,
}

impl ErrorStats {
    /// Statistics of `estimate - reference` over paired values.
    pub fn of(estimate: &[f32], reference: &[f32]) -> ErrorStats {
        let n = estimate.len().min(reference.len());
        if n == 0 {
            return ErrorStats::default();
        }
        let mut abs: Vec<f64> = Vec::with_capacity(n);
        let (mut sum, mut sum2, mut signed) = (0.0, 0.0, 0.0);
        for (e, r) in estimate.iter().zip(reference) {
            let d = *e as f64 - *r as f64;
            sum += d.abs();
            sum2 += d * d;
            signed += d;
            abs.push(d.abs());
        }
        abs.sort_by(f64::total_cmp);
        let p95 = abs[((n as f64 * 0.95).ceil() as usize).clamp(1, n) - 1];
        ErrorStats {
            n,
            mae: sum / n as f64,
            rmse: (sum2 / n as f64).sqrt(),
            p95,
            max: abs[n - 1],
            bias: signed / n as f64,
        }
    }
}
