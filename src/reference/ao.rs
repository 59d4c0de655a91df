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

/// Visibility of `receivers` against the exact union of `spheres` (rayon), each receiver with
/// its own rays (those of [`crate::geom::visibility::ambient_visibility`] for the same index
/// and configuration, so the two compare ray for ray). Spheres that contain the receiver are
/// left out, as the method leaves them out: a receiver slightly inside a sphere of its own
/// surface would otherwise see nothing.
pub fn proxy_visibility(
    positions: &[Vec3],
    normals: &[Vec3],
    receivers: &[usize],
    spheres: &[Vec4],
    cfg: &RayConfig,
) -> Vec<f32> {
    use rayon::prelude::*;
    receivers
        .par_iter()
        .map(|&i| {
            let p = positions[i];
            let outside: Vec<Vec4> = spheres
                .iter()
                .copied()
                .filter(|s| s.w >= 0.0 && s.truncate().distance(p) > s.w)
                .collect();
            spheres_visibility(p, normals[i], i, &outside, cfg)
        })
        .collect()
}

/// Popping: how often a method's per-vertex result changes by more than `jump` between
/// consecutive frames while the ray-traced truth (common random rays: the same directions
/// per receiver in every frame) changes by less than `calm`. `method[f][k]` and
/// `truth[f][k]` are frame f's values of the k-th sampled receiver.
pub fn count_jumps(method: &[Vec<f32>], truth: &[Vec<f32>], jump: f32, calm: f32) -> JumpCount {
    let mut count = JumpCount::default();
    for f in 1..method.len().min(truth.len()) {
        let now = method[f].iter().zip(&truth[f]);
        let before = method[f - 1].iter().zip(&truth[f - 1]);
        for ((m1, t1), (m0, t0)) in now.zip(before) {
            let dm = (m1 - m0).abs();
            let dt = (t1 - t0).abs();
            count.steps += 1;
            count.largest_calm_step = count
                .largest_calm_step
                .max(if dt < calm { dm } else { 0.0 });
            if dm > jump && dt < calm {
                count.jumps += 1;
            }
        }
    }
    count
}

/// What [`count_jumps`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct JumpCount {
    /// Vertex-steps compared (sampled receivers x (frames - 1)).
    pub steps: usize,
    /// Steps where the method jumped and the truth did not.
    pub jumps: usize,
    /// The method's largest change over the steps where the truth was calm.
    pub largest_calm_step: f32,
}
