//! Ambient-occlusion ground truths: cosine-weighted ray casting.
//!
//! A mesh's truth is [`crate::geom::visibility::ambient_visibility`] at
//! [`RayConfig::for_scene`] (4096 stratified rays per receiver): the integrand is the same as
//! the method's (cosine-weighted, unbounded distance), so the estimator is unbiased for it.
//! Here: the same rays cast against the exact union of a sphere set, to measure what a sphere
//! approximation itself costs.

use crate::geom::visibility::{RayConfig, cosine_directions};
use glam::{Vec3, Vec4};

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
    for d in cosine_directions(n, index, cfg) {
        total += 1;
        if !live.iter().any(|s| ray_hits_sphere(p, d, *s)) {
            escaped += 1;
        }
    }
    escaped as f32 / total as f32
}
