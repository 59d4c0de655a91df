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

#[cfg(test)]
mod tests {
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
