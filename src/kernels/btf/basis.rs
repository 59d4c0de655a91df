//! Cloth under the SG environment at frame rate: the BTF's 81 light directions folded into a
//! rank-[`RANK`] light basis, as bi-scale radiance transfer (Sloan et al. 2003) folds a BTF's
//! lighting into a few coefficients per texel and view.
//!
//! The exact pass (`btf env`, [`super::env`]) computes per pixel the 81 light factors c_i of
//! the rotated lobes (J x 81 cell integrals, ~5000 `exp`) and sums c_i T(l_i, v) over 81 x 3
//! view taps: seconds a frame on lavapipe. Here both sides go through one small basis:
//! - **BTF side (once per BTF).** Every (view, texel, channel) row y_i = T_i sqrt(Omega_i)
//!   over the 81 cells (Omega_i the cell's solid angle) is projected on the leading
//!   eigenvectors U of their Gram matrix (uncentred PCA, [`LightBasis::fit`]). The weight
//!   sqrt(Omega_i) makes the truncation minimise the error of sum_i c_i T_i under a smooth
//!   environment, where c_i ~ L Omega_i / pi. Coefficients B_k = sum_i T_i P_ik with
//!   P_ik = U_ik sqrt(Omega_i), stored per view as RGBA16F texture arrays
//!   ([`coefficient_texels`]).
//! - **Light side (once per lobe set).** For a unit lobe of sharpness lambda_j with
//!   tangent-space axis a, Q_jk(a) = sum_i Ut_ik W_ij(a), Ut_ik = U_ik / sqrt(Omega_i) and
//!   W_ij the exact pass's cell integral of the lobe (midpoint rule or splat,
//!   [`super::env::lobe_weights`]), tabulated over an octahedral map of the axis (the whole
//!   sphere: a lobe below the horizon still lights the low rings) ([`lobe_table`]).
//! - **Per pixel.** L_k = sum_j (V_j a_j / pi) Q_jk(a_j) (J x 2 filtered fetches; a_j the
//!   rotated lobe's axis in the pixel's tangent frame), then
//!   L_o = sum_k L_k B_k(uv, v) over the 3 view taps (3 x [`GROUPS`] filtered fetches).
//!   At full rank and with an exact table this is the exact pass's sum; the error is the
//!   truncation (reported by [`LightBasis::captured`]) and the table's interpolation.
//!
//! Visibility per lobe comes per pixel (as `btf env` takes it) or per vertex, interpolated
//! at the pixel with barycentrics from the G-buffer position on the pixel's triangle (as
//! the character frame has it from the environment kernel).

use super::dirs::Maps;
use super::env::{self, CELLS};
use super::synth::Btf;
use crate::error::{Error, Result};
use crate::scene::gbuffer::{Camera, GBuffer};
use glam::Vec3;
use half::f16;
use rayon::prelude::*;

/// Basis functions over the 81 light directions.
pub const RANK: usize = 8;
/// RGBA texels per (view, texel) holding the RANK x 3 coefficients (scalar s = 3 k + channel
/// is component s % 4 of group s / 4).
pub const GROUPS: usize = RANK * 3 / 4;
/// Side of each lobe's octahedral table.
pub const TABLE_SIDE: u32 = 64;
/// Table layers per lobe (RANK values, 4 per texel).
pub const TABLE_LAYERS_PER_LOBE: usize = RANK / 4;
/// Most (view, texel, channel) rows the fit reads: larger BTFs are strided through.
pub const FIT_MAX_ROWS: usize = 1 << 18;

/// The light basis of one BTF.
#[derive(Clone, Debug)]
pub struct LightBasis {
    /// Rank kept.
    pub rank: usize,
    /// Ut: light factors to coefficients, `[cell * rank + k]`.
    pub light: Vec<f32>,
    /// P: a BTF light row to its coefficients, `[cell * rank + k]`.
    pub project: Vec<f32>,
    /// Eigenvalues of the weighted Gram matrix, decreasing (all 81).
    pub spectrum: Vec<f64>,
}

impl LightBasis {
    /// The rank-[`RANK`] basis of `btf`.
    pub fn fit(btf: &Btf) -> Result<LightBasis> {
        Self::fit_rank(btf, RANK)
    }

    /// The basis of rank `rank` (1..=81) in the metric of white light (each cell's solid
    /// angle; see the module's doc).
    pub fn fit_rank(btf: &Btf, rank: usize) -> Result<LightBasis> {
        let omega: Vec<f64> = env::cells().iter().map(|c| c.solid_angle).collect();
        let mut metric = vec![0f64; CELLS * CELLS];
        for i in 0..CELLS {
            metric[i * CELLS + i] = omega[i];
        }
        Self::fit_metric(btf, rank, &metric)
    }

    /// The basis of rank `rank` that minimises the expected error of sum_i c_i T_i for
    /// light factors c with second moment `metric` = E[c c^T] (81 x 81, row-major): the
    /// BTF's rows are whitened by C^(1/2) and truncated there, so light-space detail that
    /// the lighting cannot resolve costs nothing ([`lighting_moment`] measures C for a lobe
    /// set).
    pub fn fit_metric(btf: &Btf, rank: usize, metric: &[f64]) -> Result<LightBasis> {
        if !(1..=CELLS).contains(&rank) {
            return Err(Error::InvalidArgument(format!(
                "light basis rank {rank}: 1..={CELLS}"
            )));
        }
        let n = btf.image_len();
        if n == 0 || btf.texels.len() != n * CELLS * CELLS {
            return Err(Error::InvalidArgument(format!(
                "BTF of {} x {} texels holds {} values; 81 x 81 images need {}",
                btf.size[0],
                btf.size[1],
                btf.texels.len(),
                n * CELLS * CELLS
            )));
        }
        if let Some(i) = btf
            .texels
            .iter()
            .position(|t| !t.iter().all(|x| x.is_finite()))
        {
            return Err(Error::InvalidArgument(format!(
                "BTF texel {i} (slice {}) is not finite",
                i / n
            )));
        }
        if metric.len() != CELLS * CELLS || !metric.iter().all(|x| x.is_finite()) {
            return Err(Error::InvalidArgument(
                "the light basis metric must be 81 x 81 finite values".into(),
            ));
        }
        // C^(1/2) and C^(-1/2), C regularised by 1e-6 of its mean eigenvalue (light factors
        // from a few broad lobes span fewer than 81 dimensions).
        let (lam, vecs) = crate::geom::linalg::jacobi_eigen(metric.to_vec(), CELLS);
        let floor = 1e-6 * lam.iter().map(|x| x.max(0.0)).sum::<f64>() / CELLS as f64;
        if floor.is_nan() || floor <= 0.0 {
            return Err(Error::InvalidArgument(
                "the light basis metric is zero".into(),
            ));
        }
        let mut root = vec![0f64; CELLS * CELLS];
        let mut inv_root = vec![0f64; CELLS * CELLS];
        for e in 0..CELLS {
            let l = lam[e].max(0.0) + floor;
            let (r, ir) = (l.sqrt(), 1.0 / l.sqrt());
            for a in 0..CELLS {
                let va = vecs[a * CELLS + e];
                for b in 0..CELLS {
                    let vb = va * vecs[b * CELLS + e];
                    root[a * CELLS + b] += r * vb;
                    inv_root[a * CELLS + b] += ir * vb;
                }
            }
        }
        let stride = (n * CELLS * 3).div_ceil(FIT_MAX_ROWS).max(1);
        // Gram matrix of the weighted rows, one partial sum per view.
        let gram = (0..CELLS)
            .into_par_iter()
            .map(|view| {
                let mut g = vec![0f64; CELLS * CELLS];
                let mut y = [0f64; CELLS];
                let mut row = [0f64; CELLS];
                for texel in (0..n).step_by(stride) {
                    for ch in 0..3 {
                        for (i, r) in row.iter_mut().enumerate() {
                            *r = btf.image(i, view)[texel][ch] as f64;
                        }
                        for (a, ya) in y.iter_mut().enumerate() {
                            *ya = (0..CELLS).map(|b| root[a * CELLS + b] * row[b]).sum();
                        }
                        for a in 0..CELLS {
                            let ya = y[a];
                            if ya == 0.0 {
                                continue;
                            }
                            for b in a..CELLS {
                                g[a * CELLS + b] += ya * y[b];
                            }
                        }
                    }
                }
                g
            })
            .reduce(
                || vec![0f64; CELLS * CELLS],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let mut full = gram;
        for a in 0..CELLS {
            for b in 0..a {
                full[a * CELLS + b] = full[b * CELLS + a];
            }
        }
        let (values, vectors) = crate::geom::linalg::jacobi_eigen(full, CELLS);
        let mut order: Vec<usize> = (0..CELLS).collect();
        order.sort_by(|&a, &b| values[b].total_cmp(&values[a]));
        let mut light = vec![0f32; CELLS * rank];
        let mut project = vec![0f32; CELLS * rank];
        for (k, &col) in order.iter().take(rank).enumerate() {
            // Light side C^(-1/2) u, BTF side C^(1/2) u (both symmetric).
            for i in 0..CELLS {
                let (mut l, mut p) = (0.0, 0.0);
                for e in 0..CELLS {
                    let u = vectors[e * CELLS + col];
                    l += inv_root[i * CELLS + e] * u;
                    p += root[i * CELLS + e] * u;
                }
                light[i * rank + k] = l as f32;
                project[i * rank + k] = p as f32;
            }
        }
        Ok(LightBasis {
            rank,
            light,
            project,
            spectrum: order.iter().map(|&c| values[c].max(0.0)).collect(),
        })
    }

    /// The fraction of the weighted BTF's energy the kept rank holds.
    pub fn captured(&self) -> f64 {
        let total: f64 = self.spectrum.iter().sum();
        if total > 0.0 {
            self.spectrum[..self.rank].iter().sum::<f64>() / total
        } else {
            1.0
        }
    }
}

/// Light factor samples [`lighting_moment`] draws.
pub const MOMENT_SAMPLES: usize = 4096;

/// E[c c^T] of the light factors of `lobes` (host lobes: axis, sharpness, amplitude; the
/// channels' mean) over [`MOMENT_SAMPLES`] uniformly random tangent frames (the rotation
/// of the environment and the surface's orientation together) and random per-lobe
/// visibility (1 half of the time, uniform in [0, 1] otherwise): the lighting statistics
/// [`LightBasis::fit_metric`] fits the basis to. Deterministic (fixed seed).
pub fn lighting_moment(lobes: &[crate::geom::sg::Lobe]) -> Vec<f64> {
    use crate::geom::{Rng, uniform_sphere};
    let cells = env::cell_texels();
    let chunks = 64;
    (0..chunks)
        .into_par_iter()
        .map(|chunk| {
            let mut rng = Rng::new(0x5eed_0000 + chunk as u64);
            let mut m = vec![0f64; CELLS * CELLS];
            let mut c = vec![[0f32; 3]; CELLS];
            for _ in 0..MOMENT_SAMPLES / chunks {
                let n = uniform_sphere(rng.f32(), rng.f32());
                let helper = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
                let t = (helper - n * n.dot(helper)).normalize();
                let phi = std::f32::consts::TAU * rng.f32();
                let t = t * phi.cos() + n.cross(t) * phi.sin();
                let b = n.cross(t);
                c.iter_mut().for_each(|x| *x = [0.0; 3]);
                for l in lobes {
                    let v = if rng.f32() < 0.5 { 1.0 } else { rng.f32() };
                    let a = l.axis().normalize();
                    let amp = (l.amplitude[0] + l.amplitude[1] + l.amplitude[2]) / 3.0;
                    let s = v * amp * std::f32::consts::FRAC_1_PI;
                    env::lobe_weights(
                        &cells,
                        [a.dot(t), a.dot(b), a.dot(n)],
                        l.sharpness,
                        [s, 0.0, 0.0],
                        &mut c,
                    );
                }
                for a in 0..CELLS {
                    let ca = c[a][0] as f64;
                    for bb in 0..CELLS {
                        m[a * CELLS + bb] += ca * c[bb][0] as f64;
                    }
                }
            }
            m
        })
        .reduce(
            || vec![0f64; CELLS * CELLS],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        )
        .into_iter()
        .map(|x| x / MOMENT_SAMPLES as f64)
        .collect()
}

/// Rounds to the nearest f16 and back (what an RGBA16F texel holds).
fn half(x: f32) -> f32 {
    f16::from_f32(x).to_f32()
}

/// The BTF's coefficients as the GPU holds them: [`GROUPS`] arrays of RGBA16F texels (as
/// f32 values already rounded to f16), each 81 layers (one per view) of the tile, layer-major
/// then row-major. Requires a rank-[`RANK`] basis.
pub fn coefficient_texels(btf: &Btf, basis: &LightBasis) -> Result<Vec<Vec<[f32; 4]>>> {
    if basis.rank != RANK {
        return Err(Error::InvalidArgument(format!(
            "the GPU light basis has rank {RANK}, not {}",
            basis.rank
        )));
    }
    let n = btf.image_len();
    let per_view: Vec<Vec<[f32; RANK * 3]>> = (0..CELLS)
        .into_par_iter()
        .map(|view| {
            let mut out = vec![[0f32; RANK * 3]; n];
            for i in 0..CELLS {
                let img = btf.image(i, view);
                let p = &basis.project[i * RANK..(i + 1) * RANK];
                for (o, t) in out.iter_mut().zip(img) {
                    for k in 0..RANK {
                        for ch in 0..3 {
                            o[3 * k + ch] += t[ch] * p[k];
                        }
                    }
                }
            }
            out
        })
        .collect();
    Ok((0..GROUPS)
        .map(|g| {
            per_view
                .iter()
                .flat_map(|v| {
                    v.iter()
                        .map(move |c| [0, 1, 2, 3].map(|q| half(c[4 * g + q])))
                })
                .collect()
        })
        .collect())
}

fn sgn(x: f32) -> f32 {
    if x >= 0.0 { 1.0 } else { -1.0 }
}

/// Octahedral coordinates in [0, 1]^2 of unit `d` (as the shader computes them).
pub fn oct_encode(d: [f32; 3]) -> [f32; 2] {
    let s = d[0].abs() + d[1].abs() + d[2].abs();
    let (mut x, mut y) = (d[0] / s, d[1] / s);
    if d[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sgn(ox);
        y = (1.0 - ox.abs()) * sgn(oy);
    }
    [x * 0.5 + 0.5, y * 0.5 + 0.5]
}

/// The unit direction at octahedral coordinates `uv`.
pub fn oct_decode(uv: [f32; 2]) -> [f32; 3] {
    let (mut x, mut y) = (uv[0] * 2.0 - 1.0, uv[1] * 2.0 - 1.0);
    let z = 1.0 - x.abs() - y.abs();
    if z < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sgn(ox);
        y = (1.0 - ox.abs()) * sgn(oy);
    }
    Vec3::new(x, y, z).normalize().to_array()
}

/// The light side's table for lobes of `sharpness` (one per lobe, in the order the lobe
/// buffer holds them): per lobe [`TABLE_LAYERS_PER_LOBE`] layers of [`TABLE_SIDE`]^2 RGBA16F
/// texels (rounded to f16), layer `j * TABLE_LAYERS_PER_LOBE + q` holding Q_jk for
/// k = 4 q .. 4 q + 3 at the octahedral texel centres.
pub fn lobe_table(basis: &LightBasis, sharpness: &[f32]) -> Result<Vec<[f32; 4]>> {
    if basis.rank != RANK {
        return Err(Error::InvalidArgument(format!(
            "the GPU light basis has rank {RANK}, not {}",
            basis.rank
        )));
    }
    if let Some((j, s)) = sharpness
        .iter()
        .enumerate()
        .find(|(_, s)| !(s.is_finite() && **s > 0.0))
    {
        return Err(Error::InvalidArgument(format!(
            "lobe {j}: sharpness {s} must be finite and > 0"
        )));
    }
    let cells = env::cell_texels();
    let side = TABLE_SIDE as usize;
    let per_lobe: Vec<Vec<[f32; 4]>> = sharpness
        .par_iter()
        .map(|&lambda| {
            let mut layers = vec![[0f32; 4]; TABLE_LAYERS_PER_LOBE * side * side];
            let mut w = vec![[0f32; 3]; CELLS];
            for t in 0..side * side {
                let uv = [
                    ((t % side) as f32 + 0.5) / side as f32,
                    ((t / side) as f32 + 0.5) / side as f32,
                ];
                let axis = oct_decode(uv);
                w.iter_mut().for_each(|x| *x = [0.0; 3]);
                env::lobe_weights(&cells, axis, lambda, [1.0, 0.0, 0.0], &mut w);
                for k in 0..RANK {
                    let q: f32 = (0..CELLS)
                        .map(|i| basis.light[i * RANK + k] * w[i][0])
                        .sum();
                    layers[(k / 4) * side * side + t][k % 4] = half(q);
                }
            }
            layers
        })
        .collect();
    Ok(per_lobe.concat())
}

/// Bilinear filtering of an RGBA layer (`size`, row-major) at `uv`, repeat or clamp to
/// edge, f64 weights (as a sampler with exact weights).
fn bilinear4(texels: &[[f32; 4]], size: [u32; 2], uv: [f64; 2], repeat: bool) -> [f64; 4] {
    crate::geom::bilinear_n(size, uv, repeat, |c, r| {
        texels[(r * size[0] + c) as usize].map(f64::from)
    })
}

/// Per-lobe visibility of the pass, as the CPU twin takes it.
#[derive(Clone, Copy)]
pub enum Visibility<'a> {
    /// Every lobe fully visible.
    None,
    /// `[pixel * J + j]`.
    PerPixel(&'a [f32]),
    /// `[vertex * J + j]`, interpolated at the pixel's G-buffer position on its triangle
    /// (`triangle[pixel]`, vertex ids of `triangles`, posed `positions`).
    PerVertex {
        triangle: &'a [u32],
        positions: &'a [[f32; 4]],
        triangles: &'a [[u32; 4]],
        visibility: &'a [f32],
    },
    /// The light factors per vertex (`btf env vertices`, [`BasisData::vertex_light`]) from
    /// `[vertex * J + j]` in each vertex's frame (posed `normals`, `tangents` with the
    /// handedness in w), interpolated at the pixel as [`Visibility::PerVertex`] interpolates
    /// the visibility; the back face's where the pixel's normal faces away from the
    /// interpolated vertex normal.
    PerVertexLight {
        triangle: &'a [u32],
        positions: &'a [[f32; 4]],
        triangles: &'a [[u32; 4]],
        visibility: &'a [f32],
        normals: &'a [[f32; 4]],
        tangents: &'a [[f32; 4]],
    },
}

/// The light factors of one vertex ([`BasisData::vertex_light`]).
#[derive(Clone, Copy, Debug)]
pub struct VertexLight {
    /// L_k per channel (scalar 3 k + channel) as the front face sees it.
    pub front: [f64; RANK * 3],
    /// The same for the back face (the normal negated).
    pub back: [f64; RANK * 3],
    /// The unit normal (f32, as the pass stores it).
    pub normal: Vec3,
}

/// Barycentrics of `p` on triangle (a, b, c) by least squares in the triangle's plane,
/// clamped into the triangle (f32, as the shader).
pub fn barycentrics(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f32; 3] {
    let (e1, e2, d) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d20, d21) = (d.dot(e1), d.dot(e2));
    let den = d00 * d11 - d01 * d01;
    if den.abs() <= 1e-30 {
        return [1.0, 0.0, 0.0];
    }
    let v = ((d11 * d20 - d01 * d21) / den).clamp(0.0, 1.0);
    let w = ((d00 * d21 - d01 * d20) / den).clamp(0.0, 1.0 - v);
    [1.0 - v - w, v, w]
}

/// What the CPU twin returns per pixel.
pub struct Shaded {
    /// Radiance (alpha 1 where covered).
    pub radiance: Vec<[f64; 4]>,
    /// Where f32 on the GPU may pick another view map texel.
    pub ambiguous: Vec<bool>,
    /// sum over view taps and basis scalars of |w_a L_s B_s|: the size of the terms whose
    /// fetches the device's filtering weights round (the GPU-twin bound scales with it).
    pub scale: Vec<f64>,
}

/// Everything the pass reads besides the G-buffer and the lobes, host side.
pub struct BasisData {
    /// The BTF tile's size.
    pub size: [u32; 2],
    /// [`coefficient_texels`].
    pub coefficients: Vec<Vec<[f32; 4]>>,
    /// [`lobe_table`].
    pub table: Vec<[f32; 4]>,
    /// Lobes the table covers.
    pub lobe_count: usize,
    /// The basis's captured energy ([`LightBasis::captured`]).
    pub captured: f64,
    /// Under [`Visibility::PerVertexLight`], bit j: lobe j's light factors are looked up at
    /// each pixel, the other lobes' interpolated from the vertices (0 from
    /// [`BasisData::new`]: every lobe from the vertices; [`brightest_lobes`] picks some).
    pub pixel_lobes: u64,
}

/// The `k` lobes with the most energy (luminance of the amplitude times the lobe's integral
/// 2 pi (1 - e^(-2 lambda)) / lambda) as a mask (bit j: lobe j), for
/// [`BasisData::pixel_lobes`]: what the interpolation of the light factors from the vertices
/// gets wrong grows with a lobe's energy.
pub fn brightest_lobes(lobes: &[crate::geom::sg::Lobe], k: usize) -> u64 {
    let energy: Vec<f32> = lobes
        .iter()
        .map(|l| {
            let a = l.amplitude;
            let lum = 0.2126 * a[0] + 0.7152 * a[1] + 0.0722 * a[2];
            lum * std::f32::consts::TAU * (1.0 - (-2.0 * l.sharpness).exp()) / l.sharpness
        })
        .collect();
    let mut order: Vec<usize> = (0..lobes.len().min(64)).collect();
    order.sort_by(|&a, &b| energy[b].total_cmp(&energy[a]));
    order.iter().take(k).fold(0u64, |m, &j| m | 1 << j)
}

impl BasisData {
    /// Fits the basis of `btf` to the lighting of `lobes` ([`lighting_moment`]) and
    /// tabulates them.
    pub fn new(btf: &Btf, lobes: &[crate::geom::sg::Lobe]) -> Result<BasisData> {
        let basis = LightBasis::fit_metric(btf, RANK, &lighting_moment(lobes))?;
        let sharpness: Vec<f32> = lobes.iter().map(|l| l.sharpness).collect();
        let sharpness = &sharpness[..];
        Ok(BasisData {
            size: btf.size,
            coefficients: coefficient_texels(btf, &basis)?,
            table: lobe_table(&basis, sharpness)?,
            lobe_count: sharpness.len(),
            captured: basis.captured(),
            pixel_lobes: 0,
        })
    }

    /// L_k of one pixel (tangent frame `tbn`, f32) under `lobes` (two vec4 per lobe) with
    /// per-lobe visibility `vis`.
    fn light(
        &self,
        lobes: &[[f32; 4]],
        vis: &dyn Fn(usize) -> f32,
        tbn: [Vec3; 3],
        mask: u64,
    ) -> [f64; RANK * 3] {
        let side = TABLE_SIDE as usize;
        let layer = side * side;
        let mut l = [0f64; RANK * 3];
        for (j, lb) in lobes.chunks_exact(2).enumerate() {
            if mask & (1 << j) == 0 {
                continue;
            }
            let p = Vec3::new(lb[0][0], lb[0][1], lb[0][2]);
            let local = [p.dot(tbn[0]), p.dot(tbn[1]), p.dot(tbn[2])];
            let uv = oct_encode(local);
            let s = vis(j) * std::f32::consts::FRAC_1_PI;
            let scale = [lb[1][0] * s, lb[1][1] * s, lb[1][2] * s];
            for q in 0..TABLE_LAYERS_PER_LOBE {
                let base = (j * TABLE_LAYERS_PER_LOBE + q) * layer;
                let t = bilinear4(
                    &self.table[base..base + layer],
                    [TABLE_SIDE; 2],
                    [uv[0] as f64, uv[1] as f64],
                    false,
                );
                for (c, tc) in t.iter().enumerate() {
                    let k = 4 * q + c;
                    for ch in 0..3 {
                        l[3 * k + ch] += scale[ch] as f64 * tc;
                    }
                }
            }
        }
        l
    }

    /// The twin of `btf env vertices`: the light factors of vertex `v` under `lobes` with
    /// visibility `[v * J + j]`, in the vertex's tangent frame (its normal, its tangent
    /// Gram-Schmidt-orthogonalised against it as the rasteriser's resolve does, f32), for
    /// the front face and the back face.
    pub fn vertex_light(
        &self,
        lobes: &[[f32; 4]],
        visibility: &[f32],
        normal: [f32; 4],
        tangent: [f32; 4],
        v: usize,
    ) -> VertexLight {
        let j = lobes.len() / 2;
        let n = Vec3::new(normal[0], normal[1], normal[2]);
        let len = n.length();
        let n = if len > 0.0 { n / len } else { Vec3::Z };
        let tg = Vec3::new(tangent[0], tangent[1], tangent[2]);
        let hand = if tangent[3] >= 0.0 { 1.0 } else { -1.0 };
        let mut tt = tg - n * n.dot(tg);
        if tt.dot(tt) < 1e-12 {
            tt = if n.x.abs() < 0.9 {
                n.cross(Vec3::X)
            } else {
                n.cross(Vec3::Y)
            };
        }
        let t = tt.normalize();
        let b = hand * n.cross(t);
        let vis = |jj: usize| visibility[v * j + jj];
        VertexLight {
            front: self.light(lobes, &vis, [t, b, n], !self.pixel_lobes),
            back: self.light(lobes, &vis, [t, b, -n], !self.pixel_lobes),
            normal: n,
        }
    }

    /// The CPU twin of `btf env basis`: per pixel the environment's radiance (alpha 1 where
    /// covered, only parts in `part_mask`), f64 over the f32 lobe frames.
    pub fn shade(
        &self,
        maps: &Maps,
        gbuffer: &GBuffer,
        camera: &Camera,
        lobes: &[[f32; 4]],
        visibility: Visibility<'_>,
        part_mask: u32,
    ) -> Shaded {
        let j = lobes.len() / 2;
        let n = gbuffer.width as usize * gbuffer.height as usize;
        let texels = (self.size[0] * self.size[1]) as usize;
        // Mode 3: every vertex's light factors first (the pass computes the listed ones; a
        // pixel reads only its triangle's).
        let vertex_lights: Vec<VertexLight> = match visibility {
            Visibility::PerVertexLight {
                visibility,
                normals,
                tangents,
                ..
            } => (0..normals.len())
                .into_par_iter()
                .map(|v| self.vertex_light(lobes, visibility, normals[v], tangents[v], v))
                .collect(),
            _ => Vec::new(),
        };
        let out = (0..n)
            .into_par_iter()
            .map(|k| {
                let g = &gbuffer.texels[3 * k..3 * k + 3];
                if g[0][3].abs() < 0.5 {
                    return ([0.0; 4], false, 0.0);
                }
                let part = g[0][3].abs() as u32 - 1;
                if part >= 32 || part_mask & (1 << part) == 0 {
                    return ([0.0; 4], false, 0.0);
                }
                let v3 = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
                let nn = v3(g[1]).normalize();
                let t = (v3(g[2]) - nn * nn.dot(v3(g[2]))).normalize();
                let b = if g[0][3] < 0.0 { -1.0 } else { 1.0 } * nn.cross(t);
                let pos = v3(g[0]);
                let uv = [g[1][3] as f64, g[2][3] as f64];
                let view = camera.view(pos.as_dvec3());
                let vt = [
                    view.dot(t.as_dvec3()),
                    view.dot(b.as_dvec3()),
                    view.dot(nn.as_dvec3()),
                ];
                if vt[2] <= 1e-6 {
                    return ([0.0, 0.0, 0.0, 1.0], vt[2] > -1e-6, 0.0);
                }
                let (_, mv) = maps.texel_of(vt);
                let ambiguous = mv < super::cpu::AMBIGUOUS_MARGIN;
                // The pixel's triangle and its barycentrics there, for the per-vertex forms.
                let on_triangle = match visibility {
                    Visibility::PerVertex {
                        triangle,
                        positions,
                        triangles,
                        ..
                    }
                    | Visibility::PerVertexLight {
                        triangle,
                        positions,
                        triangles,
                        ..
                    } => {
                        let tri = triangles[triangle[k] as usize];
                        let p = |i: u32| v3(positions[i as usize]);
                        Some((tri, barycentrics(pos, p(tri[0]), p(tri[1]), p(tri[2]))))
                    }
                    _ => None,
                };
                let vis: Box<dyn Fn(usize) -> f32> = match (visibility, on_triangle) {
                    (Visibility::PerPixel(v), _) => Box::new(move |jj| v[k * j + jj]),
                    (
                        Visibility::PerVertex { visibility, .. }
                        | Visibility::PerVertexLight { visibility, .. },
                        Some((tri, w)),
                    ) => Box::new(move |jj| {
                        (0..3)
                            .map(|c| w[c] * visibility[tri[c] as usize * j + jj])
                            .sum()
                    }),
                    _ => Box::new(|_| 1.0),
                };
                let l = match (visibility, on_triangle) {
                    (Visibility::PerVertexLight { .. }, Some((tri, w))) => {
                        let vl = |c: usize| &vertex_lights[tri[c] as usize];
                        let nv: Vec3 = (0..3).map(|c| w[c] * vl(c).normal).sum();
                        let back = v3(g[1]).dot(nv) < 0.0;
                        // The lobes looked up at the pixel (pixel_lobes), then the others
                        // from the vertices.
                        let mut l = self.light(lobes, &*vis, [t, b, nn], self.pixel_lobes);
                        for (c, &wc) in w.iter().enumerate() {
                            let side = if back { &vl(c).back } else { &vl(c).front };
                            for (ls, x) in l.iter_mut().zip(side) {
                                *ls += wc as f64 * x;
                            }
                        }
                        l
                    }
                    _ => self.light(lobes, &*vis, [t, b, nn], u64::MAX),
                };
                let taps = maps.lookup(vt);
                let mut sum = [0.0; 3];
                let mut scale = 0.0;
                for a in 0..3 {
                    if taps.weight[a] == 0.0 {
                        continue;
                    }
                    let view_layer = taps.index[a] * texels;
                    for (g, group) in self.coefficients.iter().enumerate() {
                        let c =
                            bilinear4(&group[view_layer..view_layer + texels], self.size, uv, true);
                        for (q, cq) in c.iter().enumerate() {
                            let s = 4 * g + q;
                            let term = taps.weight[a] * l[s] * cq;
                            sum[s % 3] += term;
                            scale += term.abs();
                        }
                    }
                }
                ([sum[0], sum[1], sum[2], 1.0], ambiguous, scale)
            })
            .collect::<Vec<_>>();
        Shaded {
            radiance: out.iter().map(|o| o.0).collect(),
            ambiguous: out.iter().map(|o| o.1).collect(),
            scale: out.iter().map(|o| o.2).collect(),
        }
    }
}
