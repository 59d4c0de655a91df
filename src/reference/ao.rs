//! Ambient-occlusion ground truth: cosine-weighted ray casting.
//!
//! For each receiver, `rays` directions stratified over the cosine-weighted hemisphere
//! (a sqrt(rays) x sqrt(rays) jittered grid, seeded per vertex, so results are reproducible);
//! visibility = fraction of rays that escape. The integrand is the same as the method's
//! (cosine-weighted, unbounded distance), so the estimator is unbiased for it; its binomial
//! standard error is at most 0.5 / sqrt(rays) (0.0078 at 4096 rays), and stratification
//! lowers it further.

use crate::geom::{Bvh, Rng, cosine_hemisphere, orthonormal_basis};
use glam::{Vec3, Vec4};
use rayon::prelude::*;

/// Ray-casting settings.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RayConfig {
    /// Rays per receiver (rounded up to a square).
    pub rays: usize,
    /// Ray origins move this far along the normal (scene units) to leave the surface.
    pub offset: f32,
    pub seed: u64,
}

impl RayConfig {
    /// 4096 rays, offset 1e-4 of the scene's size.
    pub fn for_scene(diagonal: f32) -> RayConfig {
        RayConfig {
            rays: 4096,
            offset: 1e-4 * diagonal,
            seed: 0x5eed,
        }
    }
}

/// Stratified cosine-weighted directions around `n` for receiver `index`.
pub fn directions(n: Vec3, index: usize, cfg: &RayConfig) -> impl Iterator<Item = Vec3> {
    let g = (cfg.rays as f64).sqrt().ceil() as usize;
    let (t, b) = orthonormal_basis(n);
    let mut rng = Rng::new(cfg.seed ^ (index as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    (0..g * g).map(move |k| {
        let u1 = ((k / g) as f32 + rng.f32()) / g as f32;
        let u2 = ((k % g) as f32 + rng.f32()) / g as f32;
        let l = cosine_hemisphere(u1.min(0.999_999), u2);
        t * l.x + b * l.y + n * l.z
    })
}

/// Visibility of `receivers` (vertex indices) of a posed triangle mesh. Each receiver done
/// advances the current [`crate::progress`] counter by one.
pub fn mesh_visibility(
    positions: &[Vec3],
    normals: &[Vec3],
    bvh: &Bvh,
    receivers: &[usize],
    cfg: &RayConfig,
) -> Vec<f32> {
    receivers
        .par_iter()
        .map(|&i| {
            let n = normals[i];
            let o = positions[i] + n * cfg.offset;
            let mut total = 0usize;
            let mut escaped = 0usize;
            for d in directions(n, i, cfg) {
                total += 1;
                if !bvh.any_hit(o, d, f32::INFINITY) {
                    escaped += 1;
                }
            }
            crate::progress::advance(1);
            escaped as f32 / total as f32
        })
        .collect()
}

/// Whether the ray from `o` along unit `d` hits sphere (centre, radius) at t > 0.
#[inline]
pub fn ray_hits_sphere(o: Vec3, d: Vec3, s: Vec4) -> bool {
    let oc = s.truncate() - o;
    let b = d.dot(oc);
    let c = oc.length_squared() - s.w * s.w;
    c < 0.0 || (b > 0.0 && b * b >= c)
}

/// Visibility of receiver `index` at (p, n) against the exact union of `spheres`.
pub fn spheres_visibility(
    p: Vec3,
    n: Vec3,
    index: usize,
    spheres: &[Vec4],
    cfg: &RayConfig,
) -> f32 {
    // Only spheres reaching above the tangent plane can be hit.
    let live: Vec<Vec4> = spheres
        .iter()
        .copied()
        .filter(|s| s.w >= 0.0 && n.dot(s.truncate() - p) > -s.w)
        .collect();
    let mut total = 0usize;
    let mut escaped = 0usize;
    for d in directions(n, index, cfg) {
        total += 1;
        if !live.iter().any(|s| ray_hits_sphere(p, d, *s)) {
            escaped += 1;
        }
    }
    escaped as f32 / total as f32
}
