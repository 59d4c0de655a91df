//! Subsurface-diffusion ground truth: brute force over dense surface samples.
//!
//! B(xo) = sum_j Rd(|xj - xo|) E_j A_j over every covered texel j of a texture-space geometry
//! (its surface point, irradiance and surface area), in f64, with Euclidean 3D distances (no
//! UV mapping, no seams, no sampling). The profile is not truncated: sources are summed out
//! to the radius holding 1 - 1e-5 of each channel's reflectance (a uniform grid finds them).
//! Near field: a source closer than 3 texel sizes is split into 4 x 4 sub-samples of its
//! texel parallelogram (from its Jacobian) with the same E, so the peak of Rd at r -> 0 is
//! integrated over the texel instead of sampled at its centre.
//!
//! Also the analytic plane cases: a uniformly lit plane (B = E K(R), or E R_tot) and a
//! half-plane shadow edge (a 1D integral over the lit fraction of each circle).

use crate::geom::profile::{Profile, ProfileKind};
use crate::scene::texspace::{COVERED, TexGeometry};
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Surface samples with their irradiance and area.
pub struct Sources {
    pub pos: Vec<DVec3>,
    /// Texel edge vectors (dP/du / N, dP/dv / N), for the near-field split.
    pub edges: Vec<(DVec3, DVec3)>,
    pub e: Vec<[f64; 3]>,
    pub area: Vec<f64>,
    /// Unit normals.
    pub normal: Vec<DVec3>,
}

impl Sources {
    /// Every covered texel of `geo` with irradiance `e` (rgba per texel).
    pub fn from_texels(geo: &TexGeometry, e: &[[f32; 4]]) -> Sources {
        let nf = geo.size as f64;
        let mut s = Sources {
            pos: Vec::new(),
            edges: Vec::new(),
            e: Vec::new(),
            area: Vec::new(),
            normal: Vec::new(),
        };
        for (i, ei) in e.iter().enumerate().take(geo.texels()) {
            if geo.pos[i][3] != COVERED {
                continue;
            }
            let v = |a: [f32; 4]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
            s.pos.push(v(geo.pos[i]));
            s.edges.push((v(geo.dpdu[i]) / nf, v(geo.dpdv[i]) / nf));
            s.e.push([ei[0] as f64, ei[1] as f64, ei[2] as f64]);
            s.area.push(geo.nrm[i][3] as f64);
            s.normal.push(v(geo.nrm[i]));
        }
        s
    }
}

/// The radius holding 1 - 1e-5 of channel c's reflectance, untruncated profile.
fn cutoff(profile: &Profile, c: usize) -> f64 {
    let target = (1.0 - 1e-5) * profile.r_tot[c];
    let (mut lo, mut hi) = (0.0, 1e4);
    let f = |r: f64| match profile.kind {
        ProfileKind::Dipole => profile.dipole[c].cdf(r),
        ProfileKind::Burley => profile.burley[c].a * profile.burley[c].p(r),
    };
    for _ in 0..200 {
        let m = 0.5 * (lo + hi);
        if f(m) < target {
            lo = m;
        } else {
            hi = m;
        }
    }
    hi
}

/// B at each receiver position (rgb), brute force (see the module documentation).
pub fn brute_force(sources: &Sources, receivers: &[DVec3], profile: &Profile) -> Vec<[f64; 3]> {
    brute_force_where(sources, receivers, profile, |_, _| true)
}

/// [`brute_force`] over the sources `keep(receiver, source)` accepts (to split the truth by
/// where its light comes from).
pub fn brute_force_where(
    sources: &Sources,
    receivers: &[DVec3],
    profile: &Profile,
    keep: impl Fn(usize, usize) -> bool + Sync,
) -> Vec<[f64; 3]> {
    let radius = [0, 1, 2].map(|c| cutoff(profile, c));
    let rmax = radius.iter().cloned().fold(0.0, f64::max);
    let cell = rmax;
    let key = |p: DVec3| {
        let q = (p / cell).floor();
        (q.x as i64, q.y as i64, q.z as i64)
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
    for (j, p) in sources.pos.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(j as u32);
    }
    receivers
        .par_iter()
        .enumerate()
        .map(|(ri, &xo)| {
            let (kx, ky, kz) = key(xo);
            let mut b = [0f64; 3];
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let Some(list) = grid.get(&(kx + dx, ky + dy, kz + dz)) else {
                            continue;
                        };
                        for &j in list {
                            let j = j as usize;
                            let r = (sources.pos[j] - xo).length();
                            if r > rmax || !keep(ri, j) {
                                continue;
                            }
                            let (ea, eb) = sources.edges[j];
                            let f =
                                profile.rd_over_texel(xo, sources.pos[j], ea, eb, sources.area[j]);
                            let e = sources.e[j];
                            for c in 0..3 {
                                if r <= radius[c] {
                                    b[c] += f[c] * e[c];
                                }
                            }
                        }
                    }
                }
            }
            b
        })
        .collect()
}

/// B at signed distance `s` (mm) from the edge of a half-plane lit with E = 1 (s < 0 on the
/// lit side), with the profile truncated at each channel's sampling radius (what the
/// sampler estimates: K(R) times the lit fraction of p).
pub fn shadow_edge(profile: &Profile, c: usize, s: f64) -> f64 {
    let r_max = profile.radius[c];
    let lit_fraction = |r: f64| {
        if r <= s.abs() {
            if s < 0.0 { 1.0 } else { 0.0 }
        } else {
            let f = (s.abs() / r).acos() / std::f64::consts::PI;
            if s < 0.0 { 1.0 - f } else { f }
        }
    };
    // Simpson on sqrt-spaced radii (the integrand ~ r near 0).
    let n = 4_000;
    let g = |q: f64| {
        let r = q * q;
        2.0 * std::f64::consts::PI * r * profile.rd(c, r) * lit_fraction(r) * 2.0 * q
    };
    let qm = r_max.sqrt();
    let h = qm / n as f64;
    let mut sum = g(0.0) + g(qm);
    for i in 1..n {
        sum += g(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

/// Per-channel comparison of an estimate with a reference over texels with weights (areas).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ChannelError {
    pub texels: usize,
    /// sqrt(sum A (B - T)^2 / sum A T^2).
    pub rel_rmse: [f64; 3],
    /// max |B - T| / T over texels with T > 1e-3 max T.
    pub max_rel: [f64; 3],
    /// sum A B / sum A T.
    pub energy_ratio: [f64; 3],
}

impl ChannelError {
    pub fn of(estimate: &[[f64; 3]], reference: &[[f64; 3]], weights: &[f64]) -> ChannelError {
        let mut out = ChannelError {
            texels: estimate.len(),
            ..Default::default()
        };
        for c in 0..3 {
            let tmax = reference.iter().map(|t| t[c]).fold(0.0, f64::max);
            let (mut d2, mut t2, mut sb, mut st, mut mx) = (0.0, 0.0, 0.0, 0.0, 0.0f64);
            for ((b, t), w) in estimate.iter().zip(reference).zip(weights) {
                d2 += w * (b[c] - t[c]).powi(2);
                t2 += w * t[c] * t[c];
                sb += w * b[c];
                st += w * t[c];
                if t[c] > 1e-3 * tmax {
                    mx = mx.max((b[c] - t[c]).abs() / t[c]);
                }
            }
            out.rel_rmse[c] = if t2 > 0.0 { (d2 / t2).sqrt() } else { 0.0 };
            out.max_rel[c] = mx;
            out.energy_ratio[c] = if st > 0.0 { sb / st } else { 1.0 };
        }
        out
    }
}
