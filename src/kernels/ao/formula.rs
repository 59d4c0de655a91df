//! Per-sphere occlusion: the exact formula, the 2D table over (solid angle, angle to the
//! normal), and the fixed direction set of the cone-mask overlap model.
//!
//! Everything here is evaluated in f32 exactly as `glsl/common/ao.glsl` does it, so the CPU
//! implementation of the method (cpu.rs) reproduces the GPU to rounding.

use std::f32::consts::PI;

/// Cosine-weighted fraction of the hemisphere above `n` occluded by a sphere seen at angle
/// `theta` from `n` (`cos_t` = cos theta), at distance `h` radii (h > 1). 1 = the whole
/// hemisphere. Handles spheres fully above, straddling and below the horizon.
/// (Lagarde & de Rousiers 2014, "Moving Frostbite to PBR", sec. 3.2; the cosine is included.)
pub fn sphere_occlusion(cos_t: f32, h: f32) -> f32 {
    let h = h.max(1.0 + 1e-6);
    let cos_t = cos_t.clamp(-1.0, 1.0);
    let h2 = h * h;
    let hc = h * cos_t;
    if hc >= 1.0 {
        return cos_t / h2;
    }
    if hc <= -1.0 {
        return 0.0;
    }
    let k2 = 1.0 - hc * hc;
    let sin2 = (1.0 - cos_t * cos_t).max(1e-12);
    let a = (-cos_t * ((h2 - 1.0) / sin2).sqrt()).clamp(-1.0, 1.0);
    let term = (cos_t * a.acos() - (k2 * (h2 - 1.0)).sqrt()) / h2;
    ((term + (k2 / (h2 - 1.0)).sqrt().atan()) / PI).clamp(0.0, 1.0)
}

/// Whether any of the sphere (distance / radius `h`, cosine `cos_t` of its centre to the
/// normal) lies above the horizon: the exact [`sphere_occlusion`] is positive exactly when
/// h cos_t > -1 (its f32 value may round to 0 just above that). For a caller that needs
/// only whether the sphere counts (glsl/common/ao.glsl, the same operations).
pub fn sphere_above_horizon(cos_t: f32, h: f32) -> bool {
    h.max(1.0 + 1e-6) * cos_t.clamp(-1.0, 1.0) > -1.0
}

/// The occlusion table: `I(psi, theta)` sampled on a regular grid over
/// u = psi / 2pi = 1 - sqrt(1 - 1/h^2) in [0, 1] and v = theta / pi in [0, 1].
#[derive(Clone, Debug)]
pub struct OcclusionTable {
    /// Samples along u (solid angle).
    pub n_psi: u32,
    /// Samples along v (angle to the normal).
    pub n_theta: u32,
    /// Row-major: `values[j * n_psi + i]` at u = i / (n_psi - 1), v = j / (n_theta - 1).
    pub values: Vec<f32>,
}

/// Default table size (64 x 64 floats = 16 KiB).
pub const TABLE_SIZE: u32 = 64;

impl OcclusionTable {
    /// Fills the table from the exact formula (evaluated in f64 for the entries).
    pub fn new(n_psi: u32, n_theta: u32) -> OcclusionTable {
        let (n_psi, n_theta) = (n_psi.max(2), n_theta.max(2));
        let mut values = Vec::with_capacity((n_psi * n_theta) as usize);
        for j in 0..n_theta {
            let theta = j as f64 / (n_theta - 1) as f64 * std::f64::consts::PI;
            for i in 0..n_psi {
                let u = i as f64 / (n_psi - 1) as f64;
                values.push(if u <= 0.0 {
                    0.0
                } else {
                    exact_f64(theta.cos(), h_of_u(u))
                } as f32);
            }
        }
        OcclusionTable {
            n_psi,
            n_theta,
            values,
        }
    }

    /// The table as bilinear quads, (n_psi - 1) x (n_theta - 1) row-major: quad (i, j) holds
    /// entries (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1), so that the shaders' lookup is
    /// one image load.
    pub fn quads(&self) -> Vec<[f32; 4]> {
        let (w, h) = (self.n_psi as usize, self.n_theta as usize);
        let v = &self.values;
        (0..h - 1)
            .flat_map(|j| {
                (0..w - 1).map(move |i| {
                    [
                        v[j * w + i],
                        v[j * w + i + 1],
                        v[(j + 1) * w + i],
                        v[(j + 1) * w + i + 1],
                    ]
                })
            })
            .collect()
    }

    /// Bilinear lookup at (cos theta, h), as the shader does it.
    pub fn lookup(&self, cos_t: f32, h: f32) -> f32 {
        let (u, v) = table_coords(cos_t, h);
        let x = u * (self.n_psi - 1) as f32;
        let y = v * (self.n_theta - 1) as f32;
        let i0 = (x as u32).min(self.n_psi - 2);
        let j0 = (y as u32).min(self.n_theta - 2);
        let (fx, fy) = (x - i0 as f32, y - j0 as f32);
        let at = |i: u32, j: u32| self.values[(j * self.n_psi + i) as usize];
        let a = at(i0, j0) + (at(i0 + 1, j0) - at(i0, j0)) * fx;
        let b = at(i0, j0 + 1) + (at(i0 + 1, j0 + 1) - at(i0, j0 + 1)) * fx;
        a + (b - a) * fy
    }
}

/// Table coordinates (u, v) in [0, 1] of a sphere at (cos theta, h).
pub fn table_coords(cos_t: f32, h: f32) -> (f32, f32) {
    let inv_h2 = 1.0 / (h * h).max(1.0);
    let u = 1.0 - (1.0 - inv_h2).max(0.0).sqrt();
    let v = cos_t.clamp(-1.0, 1.0).acos() * (1.0 / PI);
    (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0))
}

/// h for table coordinate u (u = 1 is the touching sphere, h = 1).
fn h_of_u(u: f64) -> f64 {
    let s = 1.0 - u; // sqrt(1 - 1/h^2)
    (1.0 / (1.0 - s * s)).sqrt().max(1.0 + 1e-9)
}

/// The exact formula in f64 (table entries, tests).
pub fn exact_f64(cos_t: f64, h: f64) -> f64 {
    let h = h.max(1.0 + 1e-12);
    let h2 = h * h;
    let hc = h * cos_t;
    if hc >= 1.0 {
        return cos_t / h2;
    }
    if hc <= -1.0 {
        return 0.0;
    }
    let k2 = 1.0 - hc * hc;
    let sin2 = (1.0 - cos_t * cos_t).max(1e-300);
    let a = (-cos_t * ((h2 - 1.0) / sin2).sqrt()).clamp(-1.0, 1.0);
    let term = (cos_t * a.acos() - (k2 * (h2 - 1.0)).sqrt()) / h2;
    ((term + (k2 / (h2 - 1.0)).sqrt().atan()) / std::f64::consts::PI).clamp(0.0, 1.0)
}

/// Directions of the cone-mask overlap model.
pub const MASK_DIRECTIONS: usize = 128;

/// `MASK_DIRECTIONS` cosine-distributed directions on the +Z hemisphere (a spherical
/// Fibonacci set: stratified in cos^2 theta, golden-angle azimuths). Each stands for an equal
/// share of the cosine-weighted hemisphere.
pub fn mask_directions() -> Vec<[f32; 4]> {
    let golden = PI * (3.0 - 5f32.sqrt());
    (0..MASK_DIRECTIONS)
        .map(|i| {
            let u = (i as f32 + 0.5) / MASK_DIRECTIONS as f32; // sin^2 theta
            let r = u.sqrt();
            let phi = golden * i as f32;
            [r * phi.cos(), r * phi.sin(), (1.0 - u).sqrt(), 0.0]
        })
        .collect()
}

/// Cells per side of [`nearest_direction_table`]: 64 x 64 over the cap centre's (x, y) in
/// [-1, 1]^2, one grid for z >= 0 and one for z < 0.
pub const NEAREST_RES: usize = 64;

/// The cell of [`nearest_direction_table`] that holds the local direction `wl`. Only exact
/// f32 operations before the truncation (x * 0.5 is exact, so a fused multiply-add rounds
/// as the separate add does), so the CPU and the shader agree wherever they agree on `wl`.
pub fn nearest_cell(wl: [f32; 3]) -> usize {
    let last = (NEAREST_RES - 1) as f32;
    let cell = |v: f32| ((v * 0.5 + 0.5) * NEAREST_RES as f32).clamp(0.0, last) as usize;
    let below = usize::from(wl[2] < 0.0);
    (below * NEAREST_RES + cell(wl[1])) * NEAREST_RES + cell(wl[0])
}

/// For each cell of [`nearest_cell`], the mask direction nearest the cell's centre (first of
/// equals): what a cap too small to hold a direction claims in the mask blend. A lookup,
/// not a search: on SIMD drivers that run both sides of a branch (lavapipe), searching the
/// 128 directions cost every cap a fifth of the occlusion pass. Within a cell the answer can
/// differ from the exact nearest near the boundaries of the directions' Voronoi cells (a
/// cell spans ~1.8 degrees at the normal, more towards the horizon); the mask blend only
/// needs a direction near the cap to decide whether it is hidden.
pub fn nearest_direction_table() -> Vec<u8> {
    let dirs = mask_directions();
    let n = NEAREST_RES;
    let mut out = vec![0u8; 2 * n * n];
    for below in 0..2 {
        for iy in 0..n {
            for ix in 0..n {
                let x = (ix as f64 + 0.5) / n as f64 * 2.0 - 1.0;
                let y = (iy as f64 + 0.5) / n as f64 * 2.0 - 1.0;
                let r2 = x * x + y * y;
                let (x, y, z) = if r2 > 1.0 {
                    (x / r2.sqrt(), y / r2.sqrt(), 0.0)
                } else {
                    let z = (1.0 - r2).sqrt();
                    (x, y, if below == 1 { -z } else { z })
                };
                let mut best = (f64::NEG_INFINITY, 0usize);
                for (k, d) in dirs.iter().enumerate() {
                    let c = d[0] as f64 * x + d[1] as f64 * y + d[2] as f64 * z;
                    if c > best.0 {
                        best = (c, k);
                    }
                }
                out[(below * n + iy) * n + ix] = best.1 as u8;
            }
        }
    }
    out
}

/// Samples per axis of the pairwise overlap table ([`OverlapTable`]; 32^3 floats = 128 KiB).
pub const OVERLAP_SIZE: u32 = 32;

/// The pairwise overlap of two spherical caps as a 3D table (the published method's overlap
/// model, after Malmer et al.): the fraction of the smaller cap's solid angle that lies
/// inside the larger, `F = |C1 ∩ C2| / min(|C1|, |C2|)` in [0, 1], as a function of the
/// caps' half-angles a1, a2 and the angle g between their axes.
///
/// Axes (each sampled at `n` points over [0, 1]): the larger half-angle over pi/2, the
/// ratio of the smaller to the larger, and t = (g - |a1 - a2|) / (2 min(a1, a2)): the
/// transition from one cap holding the other (t <= 0, F = 1) to disjoint caps (t >= 1,
/// F = 0). F is symmetric in the two caps, and for small caps it depends on the ratio and t
/// alone (a flat picture scales), so the first axis carries only the curvature of the
/// sphere of directions; all samples fall where F changes (a table over g itself would spend
/// most of them on F = 0 or 1, and one over 1 - cos a would put a fifth of a radian in the
/// first cell).
///
/// The cosine-weighted, horizon-clipped overlap has no closed form and depends on where the
/// pair sits relative to the normal (five parameters, not three), so the method
/// approximates it from the table: overlap(1, 2) ~ F * min(I1, I2), with I the caps' own
/// cosine-weighted occlusions ([`pair_overlap`]). That is exact for a cap inside another
/// and for disjoint caps; between them it assumes the shared part weighs what the smaller
/// cap's average does. Its error is measured against numerical integration of the union in
/// this module's tests.
#[derive(Clone, Debug)]
pub struct OverlapTable {
    /// Samples per axis.
    pub n: u32,
    /// `values[(k * n + j) * n + i]` at larger half-angle / (pi/2) = i / (n - 1), ratio =
    /// j / (n - 1), t = k / (n - 1).
    pub values: Vec<f32>,
}

impl OverlapTable {
    /// Fills the table by numerical integration (f64): per entry, the unweighted overlap of
    /// the two caps integrated over the smaller one, in 1024 rings of equal solid angle with
    /// each ring's share inside the larger cap in closed form.
    pub fn new(n: u32) -> OverlapTable {
        use rayon::prelude::*;
        let n = n.max(2);
        let axis = |i: u32| i as f64 / (n - 1) as f64;
        let values = (0..n * n * n)
            .into_par_iter()
            .map(|e| {
                let (i, j, k) = (e % n, (e / n) % n, e / (n * n));
                // A point cap is the limit of a small one: the smallest half-angle sampled.
                let large = (axis(i) * std::f64::consts::FRAC_PI_2).max(1e-3);
                let small = (axis(j) * large).max(1e-4);
                let g = large - small + axis(k) * 2.0 * small;
                cap_overlap_fraction_f64(large, small, g, 1024) as f32
            })
            .collect();
        OverlapTable { n, values }
    }

    /// The table as bilinear quads per slice k, (n - 1) x (n - 1) x n (i fastest): quad
    /// (i, j, k) holds entries (i, j, k), (i + 1, j, k), (i, j + 1, k), (i + 1, j + 1, k), so
    /// that the shader's trilinear lookup is two image loads.
    pub fn quads(&self) -> Vec<[f32; 4]> {
        let n = self.n as usize;
        let v = &self.values;
        let at = move |i: usize, j: usize, k: usize| v[(k * n + j) * n + i];
        (0..n)
            .flat_map(|k| {
                (0..n - 1).flat_map(move |j| {
                    (0..n - 1).map(move |i| {
                        [
                            at(i, j, k),
                            at(i + 1, j, k),
                            at(i, j + 1, k),
                            at(i + 1, j + 1, k),
                        ]
                    })
                })
            })
            .collect()
    }

    /// Trilinear lookup of F at (cos a1, cos a2, cos g), as the shader does it.
    pub fn lookup(&self, cos_a1: f32, cos_a2: f32, cos_g: f32) -> f32 {
        let c = overlap_coords(cos_a1, cos_a2, cos_g);
        let n = self.n;
        let last = (n - 1) as f32;
        let (x, y, z) = (c[0] * last, c[1] * last, c[2] * last);
        let i0 = (x as u32).min(n - 2);
        let j0 = (y as u32).min(n - 2);
        let k0 = (z as u32).min(n - 2);
        let (fx, fy, fz) = (x - i0 as f32, y - j0 as f32, z - k0 as f32);
        let at = |i: u32, j: u32, k: u32| self.values[((k * n + j) * n + i) as usize];
        let plane = |k: u32| {
            let a = at(i0, j0, k) + (at(i0 + 1, j0, k) - at(i0, j0, k)) * fx;
            let b = at(i0, j0 + 1, k) + (at(i0 + 1, j0 + 1, k) - at(i0, j0 + 1, k)) * fx;
            a + (b - a) * fy
        };
        let (p0, p1) = (plane(k0), plane(k0 + 1));
        p0 + (p1 - p0) * fz
    }
}

/// The overlap table at [`OVERLAP_SIZE`], built once per process (a few hundred ms of
/// integration) and shared by the GPU kernel and the CPU twin.
pub fn overlap_table() -> &'static OverlapTable {
    static TABLE: std::sync::OnceLock<OverlapTable> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| OverlapTable::new(OVERLAP_SIZE))
}

/// Table coordinates (larger half-angle / (pi/2), smaller / larger, t) in [0, 1] of two
/// caps of half-angle cosines `cos_a1`, `cos_a2` whose axes make an angle of cosine `cos_g`
/// ([`OverlapTable`]).
pub fn overlap_coords(cos_a1: f32, cos_a2: f32, cos_g: f32) -> [f32; 3] {
    let a1 = cos_a1.clamp(0.0, 1.0).acos();
    let a2 = cos_a2.clamp(0.0, 1.0).acos();
    let g = cos_g.clamp(-1.0, 1.0).acos();
    let (large, small) = (a1.max(a2), a1.min(a2));
    let width = (2.0 * small).max(1e-6);
    [
        (large * (2.0 / PI)).clamp(0.0, 1.0),
        (small / large.max(1e-6)).clamp(0.0, 1.0),
        ((g - (large - small)) / width).clamp(0.0, 1.0),
    ]
}

/// The pairwise overlap the published variant uses for a cap (occlusion `occ`, half-angle
/// cosine `cos_a`) and an earlier one (`occ_j`, `cos_aj`), their axes at cosine `cos_g`:
/// F * min(occ, occ_j) ([`OverlapTable`]; how a cap's pairwise overlaps combine is
/// `cpu::CpuAo::fixed_vertex`).
///
/// `sin_a`, `sin_aj` are the half-angles' sines (1 / h): caps whose axes are at least
/// a + a_j apart (cos g <= cos(a + a_j)) are disjoint and skip the lookup (three arc
/// cosines and eight loads); the table holds 0 there too.
#[allow(clippy::too_many_arguments)]
pub fn pair_overlap(
    table: &OverlapTable,
    occ: f32,
    cos_a: f32,
    sin_a: f32,
    occ_j: f32,
    cos_aj: f32,
    sin_aj: f32,
    cos_g: f32,
) -> f32 {
    let cos_sum = cos_a * cos_aj - sin_a * sin_aj;
    if cos_g <= cos_sum {
        return 0.0;
    }
    table.lookup(cos_a, cos_aj, cos_g) * occ.min(occ_j)
}

/// |C1 ∩ C2| / min(|C1|, |C2|) for caps of half-angles `a1`, `a2` (radians, in (0, pi/2])
/// whose axes are `g` apart, by numerical integration over the smaller cap in `rings` rings
/// of equal solid angle (midpoint rule in cos theta); each ring's share of azimuth inside
/// the larger cap is exact.
pub fn cap_overlap_fraction_f64(a1: f64, a2: f64, g: f64, rings: usize) -> f64 {
    let (small, large) = if a1 <= a2 { (a1, a2) } else { (a2, a1) };
    let (cos_l, cos_s) = (large.cos(), small.cos());
    let (cos_g, sin_g) = (g.cos(), g.sin());
    let mut sum = 0.0;
    for r in 0..rings {
        // cos theta uniform over [cos small, 1]: rings of equal solid angle.
        let x = cos_s + (1.0 - cos_s) * (r as f64 + 0.5) / rings as f64;
        let sin_t = (1.0 - x * x).max(0.0).sqrt();
        let den = sin_t * sin_g;
        sum += if den < 1e-12 {
            // On the axis (or the axes coincide): the whole ring is in or out.
            if x * cos_g >= cos_l { 1.0 } else { 0.0 }
        } else {
            let c = (cos_l - x * cos_g) / den;
            if c <= -1.0 {
                1.0
            } else if c >= 1.0 {
                0.0
            } else {
                c.acos() / std::f64::consts::PI
            }
        };
    }
    sum / rings as f64
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_sphere_counts_exactly_when_its_occlusion_is_positive() {
        // The occlusion in f64 (the same closed form), to see what f32 rounds to 0.
        let exact = |c: f64, h: f64| {
            let (h2, hc) = (h * h, h * c);
            if hc >= 1.0 {
                return c / h2;
            }
            if hc <= -1.0 {
                return 0.0;
            }
            let k2 = 1.0 - hc * hc;
            let a = (-c * ((h2 - 1.0) / (1.0 - c * c).max(1e-24)).sqrt()).clamp(-1.0, 1.0);
            let term = (c * a.acos() - (k2 * (h2 - 1.0)).sqrt()) / h2;
            (term + (k2 / (h2 - 1.0)).sqrt().atan()) / std::f64::consts::PI
        };
        let (mut compared, mut differ) = (0, 0);
        for i in 0..=400 {
            let cos_t = -1.0 + 2.0 * i as f32 / 400.0;
            for k in 1..=200 {
                let h = 1.0 + 0.05 * k as f32;
                let counts = sphere_above_horizon(cos_t, h);
                let occ = sphere_occlusion(cos_t, h);
                compared += 1;
                // A positive occlusion always counts.
                assert!(
                    occ <= 0.0 || counts,
                    "cos_t {cos_t}, h {h}: {occ} > 0 uncounted"
                );
                if counts != (occ > 0.0) {
                    // Counted where f32 rounded the occlusion to 0: just above the horizon,
                    // where it is negligible.
                    differ += 1;
                    let e = exact(f64::from(cos_t), f64::from(h));
                    assert!(
                        e > 0.0 && e < 1e-5,
                        "cos_t {cos_t}, h {h}: exact occlusion {e}"
                    );
                }
            }
        }
        assert!(differ * 100 < compared, "{differ} of {compared} differ");
    }

    use super::*;
    use crate::geom::{Rng, cosine_hemisphere};
    use glam::Vec3;

    /// Monte Carlo: cosine-weighted rays from the origin (normal +Z) against a sphere.
    fn monte_carlo(cos_t: f32, h: f32, n: usize) -> f32 {
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let c = Vec3::new(sin_t, 0.0, cos_t) * h; // radius 1
        let mut rng = Rng::new(42);
        let hits = (0..n)
            .filter(|_| {
                let d = cosine_hemisphere(rng.f32(), rng.f32());
                let b = d.dot(c);
                b > 0.0 && c.length_squared() - b * b <= 1.0
            })
            .count();
        hits as f32 / n as f32
    }

    #[test]
    fn exact_formula_matches_monte_carlo() {
        // Above, straddling and below the horizon; near and far.
        for &(c, h) in &[
            (1.0, 1.5),
            (0.8, 3.0),
            (0.3, 1.2),
            (0.0, 1.1),
            (-0.2, 1.4),
            (-0.5, 1.05),
            (-0.9, 4.0),
        ] {
            let mc = monte_carlo(c, h, 400_000);
            let ex = sphere_occlusion(c, h);
            // Binomial standard error <= 0.5 / sqrt(4e5) = 8e-4: a 3e-3 bound is ~4 sigma.
            assert!(
                (mc - ex).abs() < 3e-3,
                "cos_t {c} h {h}: formula {ex}, Monte Carlo {mc}"
            );
        }
    }

    /// A receiver on or inside a sphere (h <= 1: the cut's spheres may contain a vertex)
    /// is evaluated as one just outside it, never NaN. Mutant `1.0 + 1e-6` -> `1.0 - 1e-6` in
    /// the clamp (issue 23's full AO-formula run): h < 1 reaches sqrt(h^2 - 1) and gives NaN.
    #[test]
    fn a_receiver_inside_its_sphere_is_clamped_to_its_surface() {
        for cos_t in [-0.9f32, -0.2, 0.0, 0.3, 0.999] {
            let outside = sphere_occlusion(cos_t, 1.0 + 1e-6);
            for h in [0.0f32, 0.5, 1.0 - 1e-6, 1.0] {
                let v = sphere_occlusion(cos_t, h);
                assert!(
                    v.is_finite() && v == outside,
                    "cos {cos_t} h {h}: {v} vs {outside}"
                );
            }
        }
    }

    #[test]
    fn limits() {
        assert_eq!(sphere_occlusion(-1.0, 2.0), 0.0);
        assert!((sphere_occlusion(1.0, 2.0) - 0.25).abs() < 1e-6);
        // Touching sphere: (1 + cos t) / 2.
        for c in [-0.5f32, 0.0, 0.5] {
            assert!(
                (sphere_occlusion(c, 1.0) - (1.0 + c) / 2.0).abs() < 2e-3,
                "{c}"
            );
        }
        // f32 and f64 agree.
        for &(c, h) in &[(0.3, 1.2), (-0.4, 1.7), (0.9, 8.0)] {
            assert!((sphere_occlusion(c, h) as f64 - exact_f64(c as f64, h as f64)).abs() < 2e-6);
        }
    }

    #[test]
    fn table_error_against_the_formula() {
        let t = OcclusionTable::new(TABLE_SIZE, TABLE_SIZE);
        let mut rng = Rng::new(3);
        let mut max = 0f32;
        for _ in 0..200_000 {
            let c = rng.f32() * 2.0 - 1.0;
            let h = 1.0 + 1.0 / (rng.f32() + 1e-3) - 1.0 / 1.001;
            max = max.max((t.lookup(c, h) - sphere_occlusion(c, h)).abs());
        }
        // Bilinear interpolation error falls ~4x per doubling of the table; at 64 x 64 the
        // measured worst case is 3.6e-4 (mean 4.5e-5), near h = 1 and cos theta = 1.
        eprintln!("64x64 table: max |table - exact| = {max}");
        assert!(max < 1e-3, "table error {max}");
    }

    #[test]
    fn mask_directions_are_cosine_distributed() {
        let d = mask_directions();
        // Mean of cos theta under the cosine-weighted density is 2/3.
        let mean: f32 = d.iter().map(|v| v[2]).sum::<f32>() / d.len() as f32;
        assert!((mean - 2.0 / 3.0).abs() < 2e-3, "{mean}");
        assert!(
            d.iter()
                .all(|v| (Vec3::new(v[0], v[1], v[2]).length() - 1.0).abs() < 1e-5)
        );
    }

    /// The quads the shaders read: quad (i, j[, k]) at row-major index, i fastest, holds the
    /// entry and its +i, +j, +i+j neighbours (glsl/ao/occlusion.comp and fixed.comp index
    /// them so; the GPU-vs-twin tests check the lookups themselves).
    #[test]
    fn table_quads_hold_each_cell_corners_in_shader_order() {
        let t = OcclusionTable::new(7, 5);
        let q = t.quads();
        let (w, h) = (t.n_psi as usize, t.n_theta as usize);
        assert_eq!(q.len(), (w - 1) * (h - 1));
        let at = |i: usize, j: usize| t.values[j * w + i];
        for j in 0..h - 1 {
            for i in 0..w - 1 {
                let want = [at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)];
                assert_eq!(q[j * (w - 1) + i], want, "quad ({i}, {j})");
            }
        }
        let o = OverlapTable::new(4);
        let q = o.quads();
        let n = o.n as usize;
        assert_eq!(q.len(), (n - 1) * (n - 1) * n);
        let at = |i: usize, j: usize, k: usize| o.values[(k * n + j) * n + i];
        for k in 0..n {
            for j in 0..n - 1 {
                for i in 0..n - 1 {
                    let want = [
                        at(i, j, k),
                        at(i + 1, j, k),
                        at(i, j + 1, k),
                        at(i + 1, j + 1, k),
                    ];
                    assert_eq!(
                        q[(k * (n - 1) + j) * (n - 1) + i],
                        want,
                        "quad ({i}, {j}, {k})"
                    );
                }
            }
        }
    }

    /// The overlap table against direct integration (its interpolation error), and the
    /// pairwise model it serves against numerical integration of the cosine-weighted union
    /// of two random caps (its modelling error), with the product and sum blends beside it.
    #[test]
    fn overlap_table_and_pair_model_against_the_integrated_union() {
        let table = OverlapTable::new(OVERLAP_SIZE);
        let mut rng = Rng::new(7);
        let mut table_max = 0f64;
        for _ in 0..20_000 {
            let a1 = 0.02 + 1.5 * rng.f32() as f64;
            let a2 = 0.02 + 1.5 * rng.f32() as f64;
            let g = std::f64::consts::PI * rng.f32() as f64;
            let exact = cap_overlap_fraction_f64(a1, a2, g, 4096);
            let t = table.lookup(a1.cos() as f32, a2.cos() as f32, g.cos() as f32) as f64;
            table_max = table_max.max((t - exact).abs());
        }
        // Cosine-distributed quadrature directions for the union: 512 x 512 midpoints.
        let side = 512;
        let dirs: Vec<Vec3> = (0..side * side)
            .map(|k| {
                let (i, j) = (k % side, k / side);
                cosine_hemisphere(
                    (i as f32 + 0.5) / side as f32,
                    (j as f32 + 0.5) / side as f32,
                )
            })
            .collect();
        let (mut model, mut product, mut sum) = (Vec::new(), Vec::new(), Vec::new());
        let mut pairs = 0;
        while pairs < 400 {
            // Two spheres at random directions (below the horizon too) and distances.
            let mut cap = || {
                let d = Vec3::new(
                    rng.f32() * 2.0 - 1.0,
                    rng.f32() * 2.0 - 1.0,
                    rng.f32() * 2.0 - 1.0,
                );
                let h = 1.05 + 4.0 * rng.f32() * rng.f32();
                (d.normalize_or(Vec3::Z), h)
            };
            let ((w1, h1), (w2, h2)) = (cap(), cap());
            let (ca1, ca2) = (
                (1.0 - 1.0 / (h1 * h1)).sqrt(),
                (1.0 - 1.0 / (h2 * h2)).sqrt(),
            );
            let (i1, i2) = (sphere_occlusion(w1.z, h1), sphere_occlusion(w2.z, h2));
            let cos_g = w1.dot(w2);
            // Only pairs that overlap above the horizon test the overlap model.
            if i1 <= 0.0 || i2 <= 0.0 || cos_g < (ca1.acos() + ca2.acos()).cos() {
                continue;
            }
            pairs += 1;
            let hit = dirs
                .iter()
                .filter(|d| d.dot(w1) >= ca1 || d.dot(w2) >= ca2)
                .count();
            let union = hit as f32 / dirs.len() as f32;
            let approx =
                i1 + i2 - pair_overlap(&table, i2, ca2, 1.0 / h2, i1, ca1, 1.0 / h1, cos_g);
            model.push((approx - union).abs());
            product.push((1.0 - (1.0 - i1) * (1.0 - i2) - union).abs());
            sum.push((i1 + i2 - union).abs());
        }
        let stats = |v: &[f32]| {
            let mut s = v.to_vec();
            s.sort_by(f32::total_cmp);
            (
                s.iter().sum::<f32>() / s.len() as f32,
                s[s.len() * 95 / 100],
                s[s.len() - 1],
            )
        };
        let (m, p, s) = (stats(&model), stats(&product), stats(&sum));
        eprintln!(
            "overlap table {n}^3: max |table - integrated fraction| = {table_max:.2e}\n\
             union of {pairs} overlapping cap pairs, |blend - integrated union| (mean, p95, max):\n\
             table pair model {m:.4?}\nproduct {p:.4?}\nsum {s:.4?}",
            n = OVERLAP_SIZE
        );
        // Trilinear interpolation of a function with kinks where one cap starts to hold the
        // other (t = 0) and where the caps separate (t = 1), both on grid planes; between
        // them F is smooth. Measured max 2.9e-3 at 32^3; bound 1e-2 (a 3x margin).
        assert!(table_max < 1e-2, "table error {table_max}");
        // The model against the integrated union (512^2 cosine-distributed midpoints, whose
        // own error is ~1e-3): measured mean 0.0076, p95 0.043, max 0.12 (a small cap
        // straddling the larger one's rim, where the shared part's cosine weight differs
        // most from the smaller cap's average); product 0.028 and sum 0.048 on the same
        // pairs. Bound: mean < 0.015, and better than both closed-form blends.
        assert!(m.0 < 0.015, "pair model mean error {m:?}");
        // The model must beat both closed-form blends on overlapping pairs (mean error).
        assert!(
            m.0 < p.0 && m.0 < s.0,
            "model {m:?}, product {p:?}, sum {s:?}"
        );
    }
}

/// Tests added for issue 23's mutation runs (kept apart from the module's own tests).
#[cfg(test)]
mod mutation_tests {
    use super::*;

    /// A sphere that touches or holds the receiver (h <= 1, as `clamp_inside` evaluates it)
    /// is looked up in the table's last column, u = 1, where the occlusion is the touching
    /// sphere's (1 + cos theta) / 2 (`limits`), down to straight below the receiver
    /// (cos theta = -1, the table's last row). Bilinear in theta = acos(cos theta) at 64
    /// rows: error <= (pi / 63)^2 / 8 * 1/2 = 1.6e-4; bound 1e-3. Catches cargo-mutants'
    /// survivor in `OcclusionTable::lookup` (issue 23): `self.n_psi - 2` -> `self.n_psi + 2`
    /// (the corner tap then lies past the table: a panic at the last row).
    #[test]
    fn touching_spheres_read_the_last_column_down_to_the_last_row() {
        let t = OcclusionTable::new(TABLE_SIZE, TABLE_SIZE);
        for h in [1.0f32, 0.5] {
            for c in [-1.0f32, -0.999, -0.5, 0.0, 0.5, 1.0] {
                let got = t.lookup(c, h);
                let want = (1.0 + c) / 2.0;
                assert!((got - want).abs() < 1e-3, "h {h} cos {c}: {got} vs {want}");
            }
        }
    }

    /// The direction [`nearest_direction_table`] holds at [`nearest_cell`]`(wl)` is nearly the
    /// mask direction nearest `wl`, over the whole sphere (caps centred below the horizon
    /// look up the lower grid) and at its edges (x or y = +-1 exactly, z = +-1): its angle to
    /// `wl` exceeds the exact nearest's by at most a cell's angular span (a 2/64 cell spans
    /// ~1.8 deg at the normal, up to ~16 deg at the rim; measured worst 0.13 rad; bound 0.3).
    /// Catches cargo-mutants' survivors in `nearest_cell` (issue 23): `NEAREST_RES - 1` ->
    /// `+ 1` (x = 1 wraps to the next row's far side), `wl[2] < 0.0` -> `== 0.0` (caps below
    /// the horizon read the upper grid), `below * NEAREST_RES` -> `below + NEAREST_RES` (the
    /// wrong grid, or past the table).
    #[test]
    fn nearest_cell_finds_a_near_nearest_direction_everywhere() {
        let dirs = mask_directions();
        let table = nearest_direction_table();
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut wls: Vec<[f32; 3]> = (0..4000)
            .map(|i| {
                let z = 1.0 - (i as f64 + 0.5) / 2000.0;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = golden * i as f64;
                [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
            })
            .collect();
        for a in [1.0f32, -1.0] {
            wls.extend([[a, 0.0, 0.0], [0.0, a, 0.0], [0.0, 0.0, a]]);
        }
        let angle = |d: &[f32; 4], w: &[f32; 3]| {
            let c =
                d[0] as f64 * w[0] as f64 + d[1] as f64 * w[1] as f64 + d[2] as f64 * w[2] as f64;
            c.clamp(-1.0, 1.0).acos()
        };
        let mut worst = 0f64;
        for wl in &wls {
            let best = dirs
                .iter()
                .map(|d| angle(d, wl))
                .fold(f64::INFINITY, f64::min);
            let got = angle(&dirs[table[nearest_cell(*wl)] as usize], wl);
            worst = worst.max(got - best);
            assert!(
                got - best < 0.3,
                "{wl:?}: {got} rad vs the nearest's {best}"
            );
        }
        eprintln!("nearest_cell: worst excess angle {worst} rad");
    }
}
