//! Cloth under the SG environment: the BTF's 81 light directions lit by the rotated lobes.
//!
//! Quadrature. The BTF texel T(l, v) is the radiance under a directional light of
//! irradiance pi at normal incidence ([`super::cloth`]): T = pi rho(l, v) cos(theta_l), so
//! the cosine is already in the data and under an environment L
//!   L_o(v) = int rho L cos dw = (1/pi) int T(w, v) L(w) dw ~ sum_i c_i T(l_i, v),
//!   c_i = (1/pi) int_{cell i} L(w) dw.
//! The cells partition the upper hemisphere into ring sectors around the 81 directions
//! ([`cells`]): ring r spans theta in [`THETA_BOUNDS`]`[r]..[r + 1]` (7.5 deg either side of
//! the sampled ring, the last down to the horizon), sector k of a ring of n spans phi within
//! 180/n deg of 360 k/n deg. Their solid angles are close to the Voronoi cells' (shared
//! notes, frame.md section 4).
//!
//! Light factors under lobes. With the environment a sum of SG lobes
//! L = sum_j a_j G(w; p_j, lambda_j) and a per-lobe visibility V_j at the shading point,
//! c_i = sum_j (V_j a_j / pi) W_ij, W_ij = int_{cell i} G_j dw, with p_j in the point's
//! tangent frame. W_ij is integrated over each cell, never point-sampled at l_i alone for a
//! lobe narrower than the 15 deg spacing ([`lobe_weights`]):
//! - lambda <= [`LAM_SPLAT`] (wider than about half a cell): the midpoint rule on the cells,
//!   W_ij = G_j(l_i) Omega_i (a smooth integrand; error measured in the tests);
//! - sharper lobes are splatted: [`SPLAT_RINGS`] x [`SPLAT_AZIMUTHS`] points of the lobe's
//!   own equal-weight quadrature (polar angle by the inverse CDF of the lobe's radial
//!   density, azimuths uniform), each point's weight I/(R M) added to the cell holding it
//!   (I = 2 pi (1 - e^(-2 lambda)) / lambda the lobe's integral, so no energy is lost above
//!   the horizon). A sun of lambda 2600 lands in its cell whatever the spacing.
//!
//! This module holds the CPU side: the cells, the lobe weights (in f32, operation for
//! operation as `glsl/btf/shade_env.glsl` computes them), the CPU twin of the pass `btf env`
//! and the two ground truths of the note: (1) the BTF's own quadrature of the unfitted,
//! rotated map, c_i = (1/pi) int_cell L; (2) the integral of the kernel's interpolated BTF
//! over the map, c_i = (1/pi) int B_i(w) L(w) dw with B_i the direction map's weights.

use super::cpu::{AMBIGUOUS_MARGIN, Packed};
use super::dirs::{self, Maps};
use crate::geom::sg::Lobe;
use crate::scene::envmap::EnvMap;
use crate::scene::gbuffer::{Camera, GBuffer};
use glam::{Mat3, Vec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Cells per hemisphere (one per sampled light direction).
pub const CELLS: usize = dirs::COUNT;
/// Polar boundaries of the six rings (degrees): 7.5 deg either side of the sampled rings,
/// the last ring down to the horizon.
pub const THETA_BOUNDS: [f64; 7] = [0.0, 7.5, 22.5, 37.5, 52.5, 67.5, 90.0];
/// Lobes at most this sharp use the midpoint rule on the cells; sharper ones are splatted.
/// lambda 24 is a width 1/sqrt(lambda) = 0.2 rad, 0.78 of the 15 deg spacing.
pub const LAM_SPLAT: f32 = 24.0;
/// Polar strata of a splatted lobe.
pub const SPLAT_RINGS: u32 = 8;
/// Azimuths per polar stratum of a splatted lobe.
pub const SPLAT_AZIMUTHS: u32 = 12;

/// One cell of the partition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    /// The sampled light direction (tangent frame).
    pub dir: [f64; 3],
    /// Polar range (radians).
    pub theta: [f64; 2],
    /// Azimuth range (radians; the first ring's cap spans [0, 2 pi]).
    pub phi: [f64; 2],
    /// Its solid angle: (cos theta0 - cos theta1) (phi1 - phi0).
    pub solid_angle: f64,
}

/// The 81 cells in UBO2003 order ([`dirs::directions`]).
pub fn cells() -> Vec<Cell> {
    let mut out = Vec::with_capacity(CELLS);
    for (r, &(_, n)) in dirs::RINGS.iter().enumerate() {
        let t = [
            THETA_BOUNDS[r].to_radians(),
            THETA_BOUNDS[r + 1].to_radians(),
        ];
        let half = PI / n as f64;
        for k in 0..n {
            let centre = 2.0 * PI * k as f64 / n as f64;
            let phi = if n == 1 {
                [0.0, 2.0 * PI]
            } else {
                [centre - half, centre + half]
            };
            out.push(Cell {
                dir: dirs::directions()[out.len()].vector(),
                theta: t,
                phi,
                solid_angle: (t[0].cos() - t[1].cos()) * (phi[1] - phi[0]),
            });
        }
    }
    out
}

/// The BTF's albedo per channel: its mean over the tile of the radiance seen from the
/// normal (view 0) under a uniform environment of radiance 1, sum_i (Omega_i / pi) T(l_i, 0)
/// by the cells' quadrature above, over the same sum for a white Lambertian surface
/// (T = cos theta_l), so that a Lambertian BTF of reflectance rho gives rho exactly. (The
/// quadrature alone gives 1.059 for white: the last ring's midpoint overweights the
/// horizon.)
pub fn albedo(btf: &super::synth::Btf) -> [f64; 3] {
    let cells = cells();
    let n = btf.image_len().max(1);
    let white: f64 = cells.iter().map(|c| c.solid_angle / PI * c.dir[2]).sum();
    let mut sum = [0f64; 3];
    for (i, c) in cells.iter().enumerate() {
        let w = c.solid_angle / PI;
        for t in btf.image(i, 0) {
            for (s, v) in sum.iter_mut().zip(t) {
                *s += w * *v as f64;
            }
        }
    }
    sum.map(|s| s / n as f64 / white)
}

/// Sub-cells per cell along each axis of the midpoint rule (cos theta and phi split evenly,
/// so every sub-cell of a cell has the same solid angle).
pub const MIDPOINT_SUB: usize = 2;

/// The midpoint rule's points as the shader reads them (binding `cells`): per sub-cell
/// (direction xyz, solid angle), f32, [`MIDPOINT_SUB`]^2 consecutive sub-cells per cell in
/// cell order.
pub fn cell_texels() -> Vec<[f32; 4]> {
    cells()
        .iter()
        .flat_map(|c| {
            let s = MIDPOINT_SUB;
            let (z0, z1) = (c.theta[0].cos(), c.theta[1].cos());
            let d_omega = c.solid_angle / (s * s) as f64;
            let c = *c;
            (0..s * s).map(move |q| {
                let z = z0 + (z1 - z0) * ((q / s) as f64 + 0.5) / s as f64;
                let phi = c.phi[0] + (c.phi[1] - c.phi[0]) * ((q % s) as f64 + 0.5) / s as f64;
                let r = (1.0 - z * z).max(0.0).sqrt();
                [r * phi.cos(), r * phi.sin(), z, d_omega].map(|x| x as f32)
            })
        })
        .collect()
}

/// First cell of each ring.
const RING_START: [u32; 6] = [0, 1, 7, 19, 37, 57];
/// Cosines of the ring boundaries 7.5 .. 67.5 deg, f32 (the shader holds the same).
const COS_BOUNDS: [f32; 5] = [
    0.991_444_9,
    0.923_879_5,
    0.793_353_3,
    0.608_761_4,
    0.382_683_4,
];

/// The cell holding tangent-space unit direction `d` (f32, as the shader finds it), and how
/// close `d` is to the cell's border in the quantities the test compares (ring: |z - cos
/// bound|; sector: distance of phi n / 2 pi + 1/2 to an integer); `None` below the horizon.
pub fn cell_of(d: [f32; 3]) -> Option<(usize, f32)> {
    if d[2] <= 0.0 {
        return None;
    }
    let mut ring = 0usize;
    let mut margin = d[2].abs();
    for (r, &c) in COS_BOUNDS.iter().enumerate() {
        margin = margin.min((d[2] - c).abs());
        if d[2] < c {
            ring = r + 1;
        }
    }
    let n = dirs::RINGS[ring].1;
    if n == 1 {
        return Some((0, margin));
    }
    let x = d[1].atan2(d[0]) * (n as f32 / std::f32::consts::TAU) + 0.5;
    let f = x.floor();
    margin = margin.min((x - f).min(1.0 - (x - f)));
    let mut s = f as i32;
    if s < 0 {
        s += n as i32;
    }
    if s >= n as i32 {
        s -= n as i32;
    }
    Some((RING_START[ring] as usize + s as usize, margin))
}

/// The smallest border margin ([`cell_of`]) below which f32 rounding on the GPU may put a
/// splat point in the neighbouring cell; the twin flags such pixels as ambiguous. The
/// point's direction differs by a few ulp (~1e-6) between device and host and atan by
/// ~1e-6 rad, i.e. < 5e-6 in the sector coordinate phi n / 2 pi (n <= 24): 2e-5 leaves a
/// factor of 4.
pub const CELL_MARGIN: f32 = 2e-5;

/// Adds `scale` x W_i of a unit-amplitude lobe (tangent-space unit `axis`, `lambda`) to
/// `out[i]` for every cell i ([`LAM_SPLAT`] chooses the rule); returns the smallest border
/// margin of a splat point (infinity for the midpoint rule). Same operations as the shader.
pub fn lobe_weights(
    cells: &[[f32; 4]],
    axis: [f32; 3],
    lambda: f32,
    scale: [f32; 3],
    out: &mut [[f32; 3]],
) -> f32 {
    let mut margin = f32::INFINITY;
    if lambda <= LAM_SPLAT {
        for (sub, o) in cells
            .chunks_exact(MIDPOINT_SUB * MIDPOINT_SUB)
            .zip(out.iter_mut())
        {
            let mut w = 0.0;
            for c in sub {
                let cos = axis[0] * c[0] + axis[1] * c[1] + axis[2] * c[2];
                w += c[3] * (lambda * (cos - 1.0)).exp();
            }
            for k in 0..3 {
                o[k] += scale[k] * w;
            }
        }
        return margin;
    }
    // Equal-weight strata of the radial density e^(-lambda u), u = 1 - cos t in [0, 2].
    // (lambda > LAM_SPLAT: no cancellation in 1 - e^(-2 lambda) or 1 - q tail.)
    let tail = 1.0 - (-2.0 * lambda).exp();
    let weight = std::f32::consts::TAU * tail / lambda / (SPLAT_RINGS * SPLAT_AZIMUTHS) as f32;
    let [e1, e2] = basis(axis);
    for k in 0..SPLAT_RINGS {
        let q = (k as f32 + 0.5) / SPLAT_RINGS as f32;
        let u = -(1.0 - q * tail).ln() / lambda;
        let cos_t = 1.0 - u;
        let sin_t = (u * (2.0 - u)).max(0.0).sqrt();
        for m in 0..SPLAT_AZIMUTHS {
            let phi =
                std::f32::consts::TAU * (m as f32 + 0.5 * (k & 1) as f32) / SPLAT_AZIMUTHS as f32;
            let (s, c) = (phi.sin() * sin_t, phi.cos() * sin_t);
            let d = [0, 1, 2].map(|i| cos_t * axis[i] + c * e1[i] + s * e2[i]);
            if let Some((cell, mg)) = cell_of(d) {
                margin = margin.min(mg);
                for i in 0..3 {
                    out[cell][i] += scale[i] * weight;
                }
            }
        }
    }
    margin
}

/// An orthonormal pair perpendicular to unit `n` (Duff et al. 2017's branchless basis).
fn basis(n: [f32; 3]) -> [[f32; 3]; 2] {
    let sign = 1f32.copysign(n[2]);
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    [
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    ]
}

/// The lobes as the pass reads them (binding `lobes`, the layout `EnvKernel::lobes()` writes):
/// two vec4 per lobe, (axis xyz world, sharpness), (amplitude rgb, 0).
pub fn lobe_texels(lobes: &[Lobe]) -> Vec<[f32; 4]> {
    lobes
        .iter()
        .flat_map(|l| {
            let a = l.axis().normalize();
            [
                [a.x, a.y, a.z, l.sharpness],
                [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0],
            ]
        })
        .collect()
}

/// The f32 tangent frame of G-buffer pixel `k` as the shader builds it, (t, b, n), its uv and
/// position; `None` where the pixel is empty.
fn frame_f32(gb: &GBuffer, k: usize) -> Option<([Vec3; 3], [f64; 2], Vec3)> {
    let g = &gb.texels[3 * k..3 * k + 3];
    if g[0][3].abs() < 0.5 {
        return None;
    }
    let v = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
    let n = v(g[1]).normalize();
    let t = (v(g[2]) - n * n.dot(v(g[2]))).normalize();
    let s = if g[0][3] < 0.0 { -1.0 } else { 1.0 };
    let b = s * n.cross(t);
    Some(([t, b, n], [g[1][3] as f64, g[2][3] as f64], v(g[0])))
}

/// The light factors c_i (f32, as the shader) of a shading point with tangent frame `tbn`
/// under `lobes` (texels of [`lobe_texels`]) with per-lobe visibility `vis` (1 where
/// `None`); returns them and the smallest splat margin.
pub fn light_factors(
    cells: &[[f32; 4]],
    lobes: &[[f32; 4]],
    vis: Option<&[f32]>,
    [t, b, n]: [Vec3; 3],
) -> (Vec<[f32; 3]>, f32) {
    let mut c = vec![[0f32; 3]; CELLS];
    let mut margin = f32::INFINITY;
    for (j, l) in lobes.chunks_exact(2).enumerate() {
        let p = Vec3::new(l[0][0], l[0][1], l[0][2]);
        let local = [p.dot(t), p.dot(b), p.dot(n)];
        let v = vis.map_or(1.0, |v| v[j]);
        let s = v * std::f32::consts::FRAC_1_PI;
        let scale = [l[1][0] * s, l[1][1] * s, l[1][2] * s];
        margin = margin.min(lobe_weights(cells, local, l[0][3], scale, &mut c));
    }
    (c, margin)
}

/// The view-interpolated BTF at every light direction: sum over the 3 view taps, f64 (the
/// sum the pass weights by c_i).
fn view_row(packed: &Packed, maps: &Maps, vt: [f64; 3], uv: [f64; 2], i: usize) -> [f64; 3] {
    let tv = maps.lookup(vt);
    let mut out = [0.0; 3];
    for a in 0..3 {
        if tv.weight[a] == 0.0 {
            continue;
        }
        let t = packed.bilinear(tv.index[a] * dirs::COUNT + i, uv);
        for k in 0..3 {
            out[k] += tv.weight[a] * t[k];
        }
    }
    out
}

/// The CPU twin of `btf env`: per pixel, sum_i c_i x (view-interpolated BTF at light i),
/// f64 over the f32 light factors; alpha 1 where covered. `visibility`: per pixel, per
/// lobe, `[pixel * J + j]`. The flags mark pixels where f32 on the GPU may legitimately
/// differ: a view map texel border or a splat point on a cell border (see [`CELL_MARGIN`]).
pub fn shade(
    packed: &Packed,
    maps: &Maps,
    gbuffer: &GBuffer,
    camera: &Camera,
    lobes: &[[f32; 4]],
    visibility: Option<&[f32]>,
) -> (Vec<[f64; 4]>, Vec<bool>) {
    let cells = cell_texels();
    let j = lobes.len() / 2;
    let n = gbuffer.width as usize * gbuffer.height as usize;
    (0..n)
        .into_par_iter()
        .map(|k| {
            let Some((tbn, uv, pos)) = frame_f32(gbuffer, k) else {
                return ([0.0; 4], false);
            };
            let [t, b, nn] = tbn;
            let view = camera.view(pos.as_dvec3());
            let vt = [
                view.dot(t.as_dvec3()),
                view.dot(b.as_dvec3()),
                view.dot(nn.as_dvec3()),
            ];
            let mut ambiguous = packed.footprint_ambiguous(uv);
            if vt[2] <= 1e-6 {
                return ([0.0, 0.0, 0.0, 1.0], ambiguous || vt[2] > -1e-6);
            }
            let (_, mv) = maps.texel_of(vt);
            ambiguous |= mv < AMBIGUOUS_MARGIN;
            let vis = visibility.map(|v| &v[k * j..(k + 1) * j]);
            let (c, margin) = light_factors(&cells, lobes, vis, tbn);
            ambiguous |= margin < CELL_MARGIN;
            let mut sum = [0.0; 3];
            for (i, ci) in c.iter().enumerate() {
                if ci.iter().all(|&x| x == 0.0) {
                    continue;
                }
                let row = view_row(packed, maps, vt, uv, i);
                for ch in 0..3 {
                    sum[ch] += ci[ch] as f64 * row[ch];
                }
            }
            ([sum[0], sum[1], sum[2], 1.0], ambiguous)
        })
        .unzip()
}

/// Sub-cells per cell along each axis of the truths' quadrature (equal solid angles: cos
/// theta and phi split evenly).
pub const TRUTH_SUB: usize = 8;

/// The two ground truths of the note, per pixel (alpha 1 where covered): (1) sum_i c_i T_i
/// with c_i = (1/pi) int_cell L_R (the unfitted map turned by `rotation`, L_R(w) = L(R^-1
/// w), nearest texel, times the pixel's scalar `visibility` if given); (2) the same integral
/// of L_R against the direction map's interpolation weights B_i(w) instead of the cell
/// indicator: the exact integral of the BTF as the kernel interpolates it. Both integrate
/// over [`TRUTH_SUB`]^2 sub-cells per cell, f64.
pub fn truths(
    packed: &Packed,
    maps: &Maps,
    gbuffer: &GBuffer,
    camera: &Camera,
    env: &EnvMap,
    rotation: Mat3,
    visibility: Option<&[f32]>,
) -> (Vec<[f64; 4]>, Vec<[f64; 4]>) {
    let cells = cells();
    // (tangent direction, solid angle, cell) of every sub-cell.
    let sub: Vec<([f64; 3], f64, usize)> = cells
        .iter()
        .enumerate()
        .flat_map(|(i, c)| {
            let s = TRUTH_SUB;
            let (z0, z1) = (c.theta[0].cos(), c.theta[1].cos());
            let d_omega = c.solid_angle / (s * s) as f64;
            (0..s * s).map(move |q| {
                let z = z0 + (z1 - z0) * ((q / s) as f64 + 0.5) / s as f64;
                let phi = c.phi[0] + (c.phi[1] - c.phi[0]) * ((q % s) as f64 + 0.5) / s as f64;
                let r = (1.0 - z * z).max(0.0).sqrt();
                ([r * phi.cos(), r * phi.sin(), z], d_omega, i)
            })
        })
        .collect();
    let n = gbuffer.width as usize * gbuffer.height as usize;
    (0..n)
        .into_par_iter()
        .map(|k| {
            let Some(px) = gbuffer.pixel(k) else {
                return ([0.0; 4], [0.0; 4]);
            };
            let (t, b, nn) = crate::scene::gbuffer::frame_of(&px);
            let view = camera.view(px.position);
            let vt = [view.dot(t), view.dot(b), view.dot(nn)];
            if vt[2] <= 0.0 {
                return ([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]);
            }
            let v = visibility.map_or(1.0, |v| v[k] as f64);
            let mut c1 = vec![[0.0f64; 3]; CELLS];
            let mut c2 = vec![[0.0f64; 3]; CELLS];
            for &(d, d_omega, i) in &sub {
                let w = t * d[0] + b * d[1] + nn * d[2];
                let l = env.rotated_lookup(rotation, w.as_vec3());
                let taps = maps.lookup(d);
                for ch in 0..3 {
                    let e = l[ch] as f64 * d_omega * v / PI;
                    c1[i][ch] += e;
                    for a in 0..3 {
                        c2[taps.index[a]][ch] += taps.weight[a] * e;
                    }
                }
            }
            let mut s1 = [0.0; 3];
            let mut s2 = [0.0; 3];
            for i in 0..CELLS {
                let row = view_row(packed, maps, vt, px.uv, i);
                for ch in 0..3 {
                    s1[ch] += c1[i][ch] * row[ch];
                    s2[ch] += c2[i][ch] * row[ch];
                }
            }
            ([s1[0], s1[1], s1[2], 1.0], [s2[0], s2[1], s2[2], 1.0])
        })
        .unzip()
}

/// Relative L2 of `a` against `truth` over the pixels where `truth` is covered (alpha > 0),
/// all channels: sqrt(sum |a - t|^2 / sum |t|^2).
pub fn rel_l2(a: &[[f64; 4]], truth: &[[f64; 4]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, t) in a.iter().zip(truth) {
        if t[3] <= 0.0 {
            continue;
        }
        for ch in 0..3 {
            num += (x[ch] - t[ch]).powi(2);
            den += t[ch] * t[ch];
        }
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Catches an albedo taken from another view, without the cells' weights or without
    /// the white normalisation: a Lambertian BTF of reflectance (0.2, 0.5, 0.8) with a view
    /// dependence that only view 0 escapes.
    #[test]
    fn albedo_of_a_lambertian_btf_is_its_reflectance() {
        let dirs = dirs::directions();
        let size = [2u32, 3];
        let n = 6;
        let rho = [0.2f32, 0.5, 0.8];
        let mut texels = Vec::with_capacity(81 * 81 * n);
        for v in 0..81 {
            for l in dirs.iter() {
                let cos = l.vector()[2] as f32;
                let view_gain = if v == 0 { 1.0 } else { 1.7 };
                texels.extend(std::iter::repeat_n(rho.map(|r| r * cos * view_gain), n));
            }
        }
        let btf = super::super::synth::Btf { size, texels };
        let a = albedo(&btf);
        for c in 0..3 {
            assert!((a[c] - rho[c] as f64).abs() < 1e-6, "{a:?}");
        }
    }

    #[test]
    fn cells_partition_the_hemisphere() {
        let c = cells();
        assert_eq!(c.len(), CELLS);
        let total: f64 = c.iter().map(|c| c.solid_angle).sum();
        assert!((total - 2.0 * PI).abs() < 1e-12, "{total}");
        // Every sub-cell centre's cell is its own (the f32 lookup agrees with the ranges).
        for (i, cell) in c.iter().enumerate() {
            for (a, b) in [(0.3, 0.4), (0.9, 0.1), (0.5, 0.95)] {
                let th = cell.theta[0] + a * (cell.theta[1] - cell.theta[0]);
                let ph = cell.phi[0] + b * (cell.phi[1] - cell.phi[0]);
                let d = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()].map(|x| x as f32);
                assert_eq!(cell_of(d).unwrap().0, i, "cell {i} at {th} {ph}");
            }
            let d = cell.dir.map(|x| x as f32);
            assert_eq!(cell_of(d).unwrap().0, i);
        }
        assert!(cell_of([1.0, 0.0, -0.01]).is_none());
    }

    /// W_i of a unit lobe by fine midpoint quadrature over each cell, f64.
    fn exact(axis: [f64; 3], lambda: f64) -> Vec<f64> {
        let s = 48;
        cells()
            .iter()
            .map(|c| {
                let (z0, z1) = (c.theta[0].cos(), c.theta[1].cos());
                let mut sum = 0.0;
                for q in 0..s * s {
                    let z = z0 + (z1 - z0) * ((q / s) as f64 + 0.5) / s as f64;
                    let phi = c.phi[0] + (c.phi[1] - c.phi[0]) * ((q % s) as f64 + 0.5) / s as f64;
                    let r = (1.0 - z * z).sqrt();
                    let cos = axis[0] * r * phi.cos() + axis[1] * r * phi.sin() + axis[2] * z;
                    sum += (lambda * (cos - 1.0)).exp();
                }
                sum * c.solid_angle / (s * s) as f64
            })
            .collect()
    }

    #[test]
    fn lobe_weights_integrate_each_cell() {
        // Error of the per-cell weights as a fraction of the lobe's energy above the
        // horizon: sum_i |W_i - exact_i| / sum_i exact_i (the worst case moves that much
        // energy between neighbouring cells), and the energy error |sum W - sum exact|.
        let cells32 = cell_texels();
        let mut worst = Vec::new();
        for lambda in [3.0f64, 8.0, 16.0, 24.0, 32.0, 64.0, 128.0, 512.0, 2600.0] {
            let (mut move_max, mut energy_max): (f64, f64) = (0.0, 0.0);
            for (th, ph) in [
                (0.0f64, 0.0f64),
                (0.2, 0.4),
                (0.52, 1.1),
                (0.9, 2.0),
                (1.3, 0.3),
                (1.6, 4.0),
            ] {
                let axis = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
                let want = exact(axis, lambda);
                let mut got = vec![[0f32; 3]; CELLS];
                lobe_weights(
                    &cells32,
                    axis.map(|x| x as f32),
                    lambda as f32,
                    [1.0; 3],
                    &mut got,
                );
                let total = crate::geom::sg::integral(lambda);
                let moved: f64 = want
                    .iter()
                    .zip(&got)
                    .map(|(w, g)| (w - g[0] as f64).abs())
                    .sum();
                let energy: f64 =
                    got.iter().map(|g| g[0] as f64).sum::<f64>() - want.iter().sum::<f64>();
                move_max = move_max.max(moved / total);
                energy_max = energy_max.max(energy.abs() / total);
            }
            worst.push((lambda, move_max, energy_max));
        }
        eprintln!("lambda, max sum|dW|/W, max |dE|/E: {worst:?}");
        for (lambda, moved, energy) in worst {
            assert!(
                moved < 0.15 && energy < 0.04,
                "lambda {lambda}: {moved} {energy}"
            );
        }
    }
}
