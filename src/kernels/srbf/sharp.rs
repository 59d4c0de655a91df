//! Compact lighting lobes, shaded from per-vertex visibility instead of through the basis.
//!
//! A fixed SG transfer basis is smooth: it cannot follow the step of a shadow boundary, and a
//! light source much narrower than the basis functions samples the projected transfer at
//! nearly one direction, right where its ripples are (measured on the bunny: a sun or a lamp
//! puts 3-5% relative L2 of "transfer" error into the result, against < 0.1% for every other
//! lobe of the same fit). So lobes sharper than `factor` x the basis sharpness are taken out
//! of the basis path and shaded directly:
//!
//! ```text
//! L_o,v += (albedo / pi) * sum_taps weight_t V_v(w_t) max(0, n_v . w_t)
//! ```
//!
//! over the texel directions w_t of the visibility grid (the W x H equirectangular grid whose
//! texel centres the visibility was ray-cast for; the same one the transfer was projected
//! from). Each compact lobe, rotated, is one of two kinds ([`taps`]):
//!
//! - **A point source** (a sun): one tap, the whole integral / pi at the texel holding the
//!   axis. A lobe is a point when the fit could not resolve it: its sharpness
//!   is at least [`POINT_FRACTION`] of the fit's cap, 2 pi / dO for the fit grid's texels
//!   around its axis ([`is_point`]; see [`super::fit`]), so its width is the fit grid's, not
//!   the light's. Spreading such a lobe by its shape was measured worse against the ground
//!   truth (bunny, 8 rotations: sunrise 0.9-1.4% against 0.4-0.5% with one tap, interior
//!   2.5-3.2% against 2.1-2.5%, city 1.5-1.9% against 1.3-1.4%; glossy sunrise,
//!   uncompressed, 4 rotations: 1.9-2.2% against 0.6-0.9%): the map itself, box-filtered to
//!   the grid, holds a sun in the texel of its centre.
//! - **A resolved lobe** (a lamp, a softbox: sharper than the basis, broader than the fit's
//!   texel): [`SPREAD_TAPS`] taps, the 2 x 2 texels whose centres surround its axis, each its
//!   integral over the texel, by [`SPREAD_SUB`]^2 sub-samples,
//!   renormalised to the lobe's whole integral. Its width (1 / sqrt(lambda) about 1.3-1.8 deg
//!   for Blender's studio lamps) is a third of a 5.6-degree texel, so an axis off a texel's
//!   centre puts a tenth or more of the light in a neighbour, whose visibility and, on the
//!   glossy path, BRDF differ (studio's four lamps have 47-53% of their light outside the
//!   texel of their axis): one tap there took the glossy bunny under studio from 2.4-3.6% to
//!   4.0-5.1% (uncompressed, 8 rotations). The 2 x 2 block holds 99.1-99.8% of what the
//!   3 x 3 block around each of those lamps does (the 3 x 3 block, measured first, gave the
//!   same errors to the four decimals printed at 2.25x the taps).
//!
//! The GPU computes the taps in pass `srbf sharp` (glsl/srbf/sharp.comp), and pass
//! `srbf shade` adds them from the visibility bits: one visibility load per tap and vertex.
//! Which lobes are points is known when the kernel is made, so the taps' count is a
//! specialization constant: skipping a point's three zero taps in the shading loop instead
//! (a uniform branch per tap) made `srbf shade` 2.3x slower on lavapipe (bench srbf:
//! 1.0 -> 2.35 ms).
//!
//! **A sun at any rotation** (issue 19, item 5). A point's grid tap above shadows it with the
//! visibility of the texel centre that holds its rotated axis: a sun between two grid
//! directions takes its neighbour's shadow (5.6 degrees away at 64 x 32), so a shadow boundary
//! stands still while the sun moves across a texel and then jumps. With shadow rays
//! ([`super::inputs::SunRays`]) each compact lobe is instead one tap at its exact rotated axis
//! w_j = R xi_j, shadowed by a ray cast per frame, vertex and compact lobe against a BVH built
//! once for the static mesh:
//!
//! ```text
//! L_o,v += (albedo / pi) * sum_j weight_j V_v(w_j) max(0, n_v . w_j)
//! ```
//!
//! with V_v(w) = [n_v . w > 0 and no hit along p_v + offset n_v + t w, t > 0], the rule of
//! [`crate::geom::visibility::direction_visibility`] (the visibility the transfer and the
//! ground truth are cast with) and its offset. The rays are cast in pass `srbf sharp`
//! (glsl/srbf/sharp_rays.comp, the traversal of glsl/common/bvh.glsl that SSS uses): one bit
//! per compact lobe and vertex, which `srbf shade` reads where the grid path reads the grid's
//! bits. [`ray_taps`], [`ray_bits`] and [`shade_bits`] are the CPU twin (the CPU BVH,
//! [`crate::geom::Bvh`]). What is left is the lobe's own width: the tap puts the whole lobe at
//! its axis, so a vertex within about 1 / sqrt(lambda) of the shadow boundary (the penumbra)
//! takes the axis's bit for the whole lobe.

use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::sg::{self, Lobe};
use crate::geom::visibility::Visibility;
use glam::{Mat3, Vec3};

/// Lobes sharper than this factor times the basis sharpness are compact candidates.
pub const DEFAULT_FACTOR: f32 = 32.0;
/// Grid taps of a resolved compact lobe: the 2 x 2 texels whose centres surround its rotated
/// axis ([`taps`]; the first is the texel holding it). A point source has one.
pub const SPREAD_TAPS: usize = 4;
/// Sub-samples per side of a texel when a resolved lobe is integrated over it.
pub const SPREAD_SUB: u32 = 8;
/// A lobe at least this fraction of the fit's sharpness cap is a point source ([`is_point`]).
/// The suns of Blender's studio lights end at 0.93-1.0 of it, their lamps at 0.5-0.74.
pub const POINT_FRACTION: f64 = 0.85;
/// The default fit width of `srbf shade` (`--fit-width`) and the one of `bench srbf`.
pub const DEFAULT_FIT_WIDTH: u32 = 128;

/// Grid taps of compact lobes with these point flags: one a point source, [`SPREAD_TAPS`]
/// a resolved lobe.
pub fn tap_count(points: &[bool]) -> usize {
    points
        .iter()
        .map(|p| if *p { 1 } else { SPREAD_TAPS })
        .sum()
}

/// [`is_point`] for each lobe.
pub fn points(lobes: &[Lobe], fit_width: u32) -> Vec<bool> {
    lobes.iter().map(|l| is_point(l, fit_width)).collect()
}

/// Refuses a fit width that is not even and at least 2 (the fit's own rule).
pub fn check_fit_width(fit_width: u32) -> Result<()> {
    if fit_width < 2 || !fit_width.is_multiple_of(2) {
        return Err(Error::InvalidArgument(format!(
            "compact lobes: fit width {fit_width} (the lobes' map width: even, at least 2)"
        )));
    }
    Ok(())
}

/// The compact lobes' (amplitude, flag) rows for glsl/srbf/sharp.comp: w = 1 where the lobe
/// is resolved (spread over its texels), 0 where it is a point (`points[j]`).
pub fn flag_resolved(mut amps: Vec<[f32; 4]>, points: &[bool]) -> Vec<[f32; 4]> {
    for (a, p) in amps.iter_mut().zip(points) {
        a[3] = if *p { 0.0 } else { 1.0 };
    }
    amps
}

/// Whether `lobe`, fitted to a `fit_width` x `fit_width / 2` map, is a point source: its
/// sharpness is at least [`POINT_FRACTION`] of the fit's cap min(the default
/// [`super::fit::FitConfig::max_sharpness`],
/// 2 pi / dO), dO the largest texel solid angle of the fit grid's rows next to its axis (the
/// fit clamps a lobe at the cap of the sample nearest its axis, which may lie a row away).
pub fn is_point(lobe: &Lobe, fit_width: u32) -> bool {
    let w = fit_width.max(2) as f64;
    let h = (fit_width / 2).max(1) as i64;
    let axis = lobe.axis().as_dvec3().normalize();
    let theta = axis.y.clamp(-1.0, 1.0).acos();
    let row = ((theta / std::f64::consts::PI * h as f64).floor() as i64).clamp(0, h - 1);
    let d_omega = (row - 1..=row + 1)
        .filter(|r| (0..h).contains(r))
        .map(|r| {
            let (t0, t1) = (
                std::f64::consts::PI * r as f64 / h as f64,
                std::f64::consts::PI * (r + 1) as f64 / h as f64,
            );
            std::f64::consts::TAU / w * (t0.cos() - t1.cos())
        })
        .fold(0.0, f64::max);
    let max_sharpness = super::fit::FitConfig::default().max_sharpness as f64;
    let cap = max_sharpness.min(std::f64::consts::TAU / d_omega);
    lobe.sharpness as f64 >= POINT_FRACTION * cap
}
/// Of the candidates, those holding at least this share of the lighting's energy
/// (luminance-weighted integral) are shaded directly, the strongest first.
pub const MIN_SHARE: f32 = 0.02;
/// Compact lobes shaded directly by default, and at most (one bit each in the shadow rays'
/// word; `pack::MAX_TAPS` holds four grid taps for each).
pub const DEFAULT_MAX_LOBES: usize = 4;
pub const MAX_LOBES: usize = 32;

/// Splits `lobes` into (through the basis, compact). Candidates are the lobes with
/// sharpness above `factor * basis_sharpness`; of those, the ones holding at least
/// [`MIN_SHARE`] of all the lobes' energy (luminance of amplitude x integral) are compact, the
/// strongest first, at most `max_lobes` (capped at [`MAX_LOBES`]). A factor of 0 or infinity,
/// or `max_lobes` 0, keeps every lobe in the basis path.
pub fn split(
    lobes: &[Lobe],
    basis_sharpness: f32,
    factor: f32,
    max_lobes: usize,
) -> (Vec<Lobe>, Vec<Lobe>) {
    if !(factor > 0.0 && factor.is_finite()) || max_lobes == 0 {
        return (lobes.to_vec(), Vec::new());
    }
    let energy = |l: &Lobe| {
        let a = l.amplitude;
        (0.2126 * a[0] + 0.7152 * a[1] + 0.0722 * a[2]) as f64 * sg::integral(l.sharpness as f64)
    };
    let total: f64 = lobes.iter().map(energy).sum();
    let threshold = factor * basis_sharpness;
    let mut order: Vec<usize> = (0..lobes.len())
        .filter(|&i| {
            lobes[i].sharpness > threshold && energy(&lobes[i]) >= MIN_SHARE as f64 * total
        })
        .collect();
    order.sort_by(|&a, &b| energy(&lobes[b]).total_cmp(&energy(&lobes[a])));
    order.truncate(max_lobes.min(MAX_LOBES));
    let compact: Vec<Lobe> = order.iter().map(|&i| lobes[i]).collect();
    let smooth = (0..lobes.len())
        .filter(|i| !order.contains(i))
        .map(|i| lobes[i])
        .collect();
    (smooth, compact)
}

/// One tap: a texel of the visibility grid, its centre direction and the radiance x solid
/// angle / pi it carries (per channel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tap {
    pub texel: u32,
    pub dir: Vec3,
    pub weight: [f32; 3],
}

/// Direction of (u, v) on the equirectangular grid (the convention of
/// [`crate::scene::envmap::direction_of`], in f32 as on the GPU).
fn direction(u: f32, v: f32) -> Vec3 {
    let (theta, phi) = (std::f32::consts::PI * v, std::f32::consts::TAU * (u - 0.5));
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Vec3::new(st * sp, ct, -st * cp)
}

/// The taps of the compact lobes rotated by `rotation` (L_R(w) = L(R^-1 w)) on a W x H grid,
/// lobe by lobe ([`tap_count`] in all), each with its texel's centre direction and its share
/// of the lobe's integral / pi. `points[j]` says whether lobe j is a point source
/// ([`is_point`]): one tap, its whole integral at the texel holding its rotated axis.
/// Otherwise [`SPREAD_TAPS`] taps: that texel, its neighbour across the nearer side in u, the
/// one across the nearer side in v, and the one across both (the 2 x 2 block of texels whose
/// centres surround the axis), each share the lobe integrated over the texel
/// on a [`SPREAD_SUB`]^2 grid of sub-samples (solid-angle weighted), renormalised to the
/// lobe's integral; a tap off the grid (a row past a pole) or with no share is zero at the
/// first texel. The same arithmetic as glsl/srbf/sharp.comp, in f32.
pub fn taps(
    compact: &[Lobe],
    points: &[bool],
    rotation: Mat3,
    width: u32,
    height: u32,
) -> Vec<Tap> {
    let mut out = Vec::with_capacity(compact.len() * SPREAD_TAPS);
    for (j, lobe) in compact.iter().enumerate() {
        let axis = (rotation * lobe.axis()).normalize();
        let cells = footprint(axis, width, height);
        let (x0, y0) = cells[0].unwrap_or_default();
        let scale = sg::integral(lobe.sharpness as f64) as f32 / std::f32::consts::PI;
        let tap = |x: u32, y: u32, share: f32| Tap {
            texel: y * width + x,
            dir: direction(
                (x as f32 + 0.5) / width as f32,
                (y as f32 + 0.5) / height as f32,
            ),
            weight: lobe.amplitude.map(|a| a * scale * share),
        };
        if points.get(j).copied().unwrap_or(true) {
            out.push(tap(x0, y0, 1.0));
            continue;
        }
        let shares = spread_shares(axis, lobe.sharpness, &cells, width, height);
        for (c, cell) in cells.iter().enumerate() {
            out.push(match (&shares, cell) {
                (Some(s), Some((x, y))) if s[c] > 0.0 => tap(*x, *y, s[c]),
                (None, _) if c == 0 => tap(x0, y0, 1.0),
                _ => tap(x0, y0, 0.0),
            });
        }
    }
    out
}

/// The 2 x 2 texels around unit direction `axis` on a W x H grid, in [`taps`]' order: the
/// texel holding it, then across the nearer side in u (the column wraps), in v, and both; a
/// row past a pole is None.
fn footprint(axis: Vec3, width: u32, height: u32) -> [Option<(u32, u32)>; SPREAD_TAPS] {
    let (x0, y0) = texel_of(axis, width, height);
    let (fu, fv) = texel_coords(axis, width, height);
    let dx: i64 = if fu - (x0 as f32) < 0.5 { -1 } else { 1 };
    let dy: i64 = if fv - (y0 as f32) < 0.5 { -1 } else { 1 };
    let at = |sx: i64, sy: i64| {
        let y = y0 as i64 + sy;
        let x = (x0 as i64 + sx).rem_euclid(width as i64) as u32;
        (0..height as i64).contains(&y).then_some((x, y as u32))
    };
    [at(0, 0), at(dx, 0), at(0, dy), at(dx, dy)]
}

/// Each texel's share of a lobe of `sharpness` at unit `axis` (sub-sampled, summed to 1);
/// None when the lobe has no weight at any sub-sample.
fn spread_shares(
    axis: Vec3,
    sharpness: f32,
    cells: &[Option<(u32, u32)>; SPREAD_TAPS],
    width: u32,
    height: u32,
) -> Option<[f32; SPREAD_TAPS]> {
    let mut e = [0f32; SPREAD_TAPS];
    let sub = SPREAD_SUB as f32;
    for (ec, cell) in e.iter_mut().zip(cells) {
        let Some((x, y)) = *cell else {
            continue;
        };
        for j in 0..SPREAD_SUB {
            let v = (y as f32 + (j as f32 + 0.5) / sub) / height as f32;
            let sin_theta = (std::f32::consts::PI * v).sin();
            for i in 0..SPREAD_SUB {
                let u = (x as f32 + (i as f32 + 0.5) / sub) / width as f32;
                let d = direction(u, v);
                *ec += (sharpness * (axis.dot(d) - 1.0)).exp() * sin_theta;
            }
        }
    }
    let total: f32 = e.iter().sum();
    (total > 0.0 && total.is_finite()).then(|| e.map(|x| x / total))
}

/// Texel (column, row) holding direction `d` on a W x H grid.
fn texel_of(d: Vec3, width: u32, height: u32) -> (u32, u32) {
    let (u, v) = texel_coords(d, width, height);
    let x = (u.floor().max(0.0) as u32) % width;
    let y = (v.floor().max(0.0) as u32).min(height - 1);
    (x, y)
}

/// Direction `d` in texel units of a W x H grid: (u W, v H).
fn texel_coords(d: Vec3, width: u32, height: u32) -> (f32, f32) {
    let theta = d.x.hypot(d.z).atan2(d.y);
    let phi = d.x.atan2(-d.z);
    let u = 0.5 + phi / std::f32::consts::TAU;
    let v = theta / std::f32::consts::PI;
    (u * width as f32, v * height as f32)
}

/// The compact lobes' radiance per vertex, from the taps and the visibility (whose
/// directions must be the grid's texel centres): sum_t weight_t V_v(t) max(0, n_v . w_t),
/// without the albedo. An error if the sizes disagree.
pub fn shade(taps: &[Tap], normals: &[Vec3], vis: &Visibility) -> Result<Vec<[f32; 3]>> {
    if normals.len() != vis.vertices {
        return Err(Error::InvalidArgument(format!(
            "compact lobes: {} normals for a visibility of {} vertices",
            normals.len(),
            vis.vertices
        )));
    }
    Ok(shade_with(taps, normals, |v, t| {
        vis.visible(v, t.texel as usize)
    }))
}

/// sum_t weight_t [seen(v, t)] max(0, n_v . w_t) per vertex v (f32, the GPU's order).
fn shade_with(taps: &[Tap], normals: &[Vec3], seen: impl Fn(usize, &Tap) -> bool) -> Vec<[f32; 3]> {
    normals
        .iter()
        .enumerate()
        .map(|(v, n)| {
            let mut sum = [0f32; 3];
            for t in taps {
                if seen(v, t) {
                    let c = n.dot(t.dir).max(0.0);
                    for (s, w) in sum.iter_mut().zip(t.weight) {
                        *s += w * c;
                    }
                }
            }
            sum
        })
        .collect()
}

/// The taps of the compact lobes rotated by `rotation` for shadow rays: lobe j's whole
/// integral / pi at its exact rotated axis R xi_j (normalised in f32, as
/// glsl/srbf/sharp_rays.comp does), `texel` holding j (its bit in [`ray_bits`]). At most
/// [`MAX_LOBES`] lobes (32 bits).
pub fn ray_taps(compact: &[Lobe], rotation: Mat3) -> Vec<Tap> {
    compact
        .iter()
        .take(MAX_LOBES)
        .enumerate()
        .map(|(j, lobe)| {
            let scale = sg::integral(lobe.sharpness as f64) as f32 / std::f32::consts::PI;
            Tap {
                texel: j as u32,
                dir: (rotation * lobe.axis()).normalize(),
                weight: lobe.amplitude.map(|a| a * scale),
            }
        })
        .collect()
}

/// Per vertex, bit j set when tap j's direction w is visible: n . w > 0 and no hit of the
/// ray from p + offset n along w ([`crate::geom::visibility::direction_visibility`]'s rule).
/// Vertices are the first `min(positions.len(), normals.len())`.
pub fn ray_bits(
    taps: &[Tap],
    positions: &[Vec3],
    normals: &[Vec3],
    bvh: &Bvh,
    offset: f32,
) -> Vec<u32> {
    use rayon::prelude::*;
    positions
        .par_iter()
        .zip(normals.par_iter())
        .map(|(p, n)| {
            let origin = *p + offset * *n;
            taps.iter().take(32).enumerate().fold(0u32, |bits, (j, t)| {
                if n.dot(t.dir) > 0.0 && !bvh.any_hit(origin, t.dir, f32::INFINITY) {
                    bits | 1 << j
                } else {
                    bits
                }
            })
        })
        .collect()
}

/// The compact lobes' radiance per vertex from [`ray_taps`] and [`ray_bits`]:
/// sum_j weight_j [bit j] max(0, n_v . w_j), without the albedo. An error if the sizes
/// disagree.
pub fn shade_bits(taps: &[Tap], normals: &[Vec3], bits: &[u32]) -> Result<Vec<[f32; 3]>> {
    if normals.len() != bits.len() {
        return Err(Error::InvalidArgument(format!(
            "compact lobes: {} normals for the shadow-ray bits of {} vertices",
            normals.len(),
            bits.len()
        )));
    }
    Ok(shade_with(taps, normals, |v, t| {
        t.texel < 32 && bits[v] >> t.texel & 1 == 1
    }))
}

/// Checks that `vis` was cast for the texel centres of a `width` x `height` grid (the taps
/// index it by texel), to 1e-5.
pub fn check_grid(vis: &Visibility, width: u32, height: u32) -> Result<()> {
    let n = (width as usize) * (height as usize);
    if width == 0 || height == 0 || vis.directions.len() != n {
        return Err(Error::InvalidArgument(format!(
            "compact lobes: the visibility has {} directions, not the {width} x {height} grid's \
             {n}",
            vis.directions.len()
        )));
    }
    for (p, d) in vis.directions.iter().enumerate() {
        let (x, y) = (p as u32 % width, p as u32 / width);
        let c = direction(
            (x as f32 + 0.5) / width as f32,
            (y as f32 + 0.5) / height as f32,
        );
        if (c - *d).length() > 1e-5 {
            return Err(Error::InvalidArgument(format!(
                "compact lobes: visibility direction {p} ({d}) is not the centre of texel \
                 ({x}, {y}) of a {width} x {height} grid ({c})"
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_takes_the_sharpest_above_the_threshold() {
        let lobes: Vec<Lobe> = [10.0, 5000.0, 900.0, 1200.0, 30.0]
            .iter()
            .map(|&s| Lobe::new(Vec3::Y, s, [1.0; 3]))
            .collect();
        // Energies (2 pi / lambda x amplitude): the 5000 lobe holds 0.7% of the total, below
        // MIN_SHARE; the 1200 lobe (x 100) the most.
        let lobes: Vec<Lobe> = lobes
            .iter()
            .map(|l| {
                let a = if l.sharpness == 1200.0 { 100.0 } else { 1.0 };
                Lobe {
                    amplitude: [a; 3],
                    ..*l
                }
            })
            .collect();
        let (smooth, compact) = split(&lobes, 30.0, 32.0, DEFAULT_MAX_LOBES);
        assert_eq!(
            compact.iter().map(|l| l.sharpness).collect::<Vec<_>>(),
            [1200.0]
        );
        assert_eq!(smooth.len(), 4);
        assert_eq!(split(&lobes, 30.0, 0.0, 4).1.len(), 0);
        assert_eq!(split(&lobes, 30.0, 32.0, 0).1.len(), 0);
        // Equal lobes: the strongest first, at most max_lobes (and never above MAX_LOBES).
        let many: Vec<Lobe> = (0..10)
            .map(|i| Lobe::new(Vec3::X, 2000.0, [1.0 + i as f32; 3]))
            .collect();
        let (smooth, compact) = split(&many, 30.0, 32.0, 3);
        assert_eq!((smooth.len(), compact.len()), (7, 3));
        assert!(
            smooth
                .iter()
                .all(|l| l.amplitude[0] < compact[2].amplitude[0])
        );
        let all: Vec<Lobe> = (0..40)
            .map(|_| Lobe::new(Vec3::X, 2000.0, [1.0; 3]))
            .collect();
        assert_eq!(split(&all, 30.0, 32.0, 1000).1.len(), MAX_LOBES);
    }

    /// A tap carries the lobe's whole integral / pi at the texel of its rotated axis, also
    /// next to a pole and across the u = 0 / 1 seam.
    #[test]
    fn a_tap_holds_the_integral_at_the_rotated_axis() {
        let r = sg::rotation(Vec3::new(0.2, 1.0, -0.3), 75.0);
        let env =
            crate::scene::EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "grid").unwrap();
        for axis in [
            Vec3::new(0.3, 0.5, -0.8),
            Vec3::new(0.01, 1.0, 0.02),
            Vec3::new(0.0, 0.1, 1.0),
            Vec3::new(-1e-4, -0.2, -1.0),
        ] {
            let l = Lobe::new(axis, 2500.0, [2.0, 1.0, 0.5]);
            let t = taps(&[l], &[true], r, 64, 32);
            assert_eq!(t.len(), 1);
            let want = sg::integral(2500.0) / std::f64::consts::PI;
            let middle = t[0];
            for c in 0..3 {
                let expect = want * l.amplitude[c] as f64;
                assert!((middle.weight[c] as f64 - expect).abs() < 1e-6 * expect);
            }
            let rotated = (r * l.axis()).normalize();
            let (x, y) = env.texel_of(rotated);
            assert_eq!(middle.texel, y * 64 + x);
            assert!((middle.dir - env.direction(x, y)).length() < 1e-5);
        }
    }

    /// A black 64 x 32 grid, `n` normals spread over the sphere and their visibility of the
    /// grid's texel centres with no geometry (n . w > 0).
    fn open_grid(n: usize) -> (crate::scene::EnvMap, Vec<Vec3>, Visibility) {
        let env =
            crate::scene::EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "grid").unwrap();
        let dirs: Vec<Vec3> = env.samples().iter().map(|s| s.0).collect();
        let bvh = crate::geom::Bvh::build(&[], &[]);
        let normals = sg::fibonacci_sphere(n);
        let positions = vec![Vec3::ZERO; n];
        let vis =
            crate::geom::visibility::direction_visibility(&positions, &normals, &bvh, &dirs, 0.0);
        (env, normals, vis)
    }

    /// Against the brute-force sum over the same grid with the lobe rasterised into it: a
    /// lobe narrower than a sub-texel lands in the texel of its axis there too, so the two
    /// agree to rounding (texel indexing, the cosine at the texel centre, the scale).
    #[test]
    fn shading_matches_the_grid_sum_of_the_rasterised_lobe() {
        use crate::reference::srbf::{rasterise_lobes, shade_brute_force_radiance};
        let (env, normals, vis) = open_grid(50);
        check_grid(&vis, 64, 32).unwrap();
        let l = Lobe::new(Vec3::new(0.4, 0.6, 0.7), 2.0e6, [1.0e3, 2.0e3, 3.0e3]);
        let r = sg::rotation(Vec3::Z, 20.0);
        let t = taps(&[l], &[true], r, 64, 32);
        let got = shade(&t, &normals, &vis).unwrap();
        let raster = rasterise_lobes(&[l], r, &env);
        let want = shade_brute_force_radiance(&env, &raster, &normals, &vis, [1.0; 3]).unwrap();
        let scale = want.iter().map(|w| w[2]).fold(0.0f64, f64::max);
        for (g, w) in got.iter().zip(&want) {
            for c in 0..3 {
                assert!(
                    (g[c] as f64 - w[c]).abs() < 1e-5 * scale,
                    "{g:?} vs {w:?} (scale {scale})"
                );
            }
        }
    }

    /// A resolved lobe (a lamp: sharper than the basis, broader than the fit's texel) against
    /// the reference rasteriser (16 x 16 sub-samples a texel over the whole grid): each tap
    /// holds the lobe's integral over its texel, so away from the poles shading from the taps
    /// follows the brute-force grid sum of the rasterised lobe up to the light the 2 x 2
    /// block leaves out (renormalised into it) and the 8 x 8 sub-samples' quadrature.
    /// Measured: 2.7e-3, 8.8e-5 (across the u seam) and 3.3e-5 (across the equator) of the
    /// largest radiance off the poles, against 1.5e-2, 5.8e-2 and 6.4e-2 with one tap; bound
    /// 1e-2, and one tap must err 3x more. By a pole a texel is narrow in u and the lobe
    /// covers the whole first row: there the four taps err about as one tap does (9.4e-3
    /// against 7.7e-3), and the test holds them to 1.5e-2.
    #[test]
    fn a_resolved_lobe_spreads_over_its_texels_as_the_rasteriser_does() {
        use crate::reference::srbf::{rasterise_lobes, shade_brute_force_radiance};
        let (env, normals, vis) = open_grid(400);
        // Axes off their texels' centres (not rotated): at mid latitude, by the pole, across
        // the u seam (+z) and across the rows' boundary at the equator.
        for axis in [
            Vec3::new(0.4, 0.6, 0.7),
            Vec3::new(0.02, 1.0, 0.05),
            Vec3::new(-0.01, -0.1, 1.0),
            Vec3::new(0.3, 0.002, -1.0),
        ] {
            let l = Lobe::new(axis, 1500.0, [1.0e3, 2.0e3, 3.0e3]);
            assert!(!is_point(&l, DEFAULT_FIT_WIDTH));
            let r = Mat3::IDENTITY;
            let t = taps(&[l], &[false], r, 64, 32);
            assert_eq!(t.len(), SPREAD_TAPS);
            // The shares sum to the lobe's integral, and more than one tap holds light.
            let sum: f64 = t.iter().map(|x| x.weight[2] as f64).sum();
            let want = sg::integral(1500.0) / std::f64::consts::PI * 3.0e3;
            assert!((sum - want).abs() < 1e-5 * want, "{sum} vs {want}");
            assert!(t.iter().filter(|x| x.weight[2] > 0.01 * sum as f32).count() > 1);
            let got = shade(&t, &normals, &vis).unwrap();
            let raster = rasterise_lobes(&[l], r, &env);
            let want = shade_brute_force_radiance(&env, &raster, &normals, &vis, [1.0; 3]).unwrap();
            let scale = want.iter().map(|w| w[2]).fold(0.0f64, f64::max);
            let worst = got
                .iter()
                .zip(&want)
                .flat_map(|(g, w)| (0..3).map(move |c| (g[c] as f64 - w[c]).abs()))
                .fold(0.0f64, f64::max);
            eprintln!(
                "axis {axis}: worst {:.2e} of the largest radiance",
                worst / scale
            );
            let polar = axis.y.abs() > 0.99;
            let bound = if polar { 1.5e-2 } else { 1e-2 };
            assert!(
                worst < bound * scale,
                "axis {axis}: {worst} vs scale {scale}"
            );
            // One tap at the axis's texel instead misses the neighbours' share.
            let one = shade(&taps(&[l], &[true], r, 64, 32), &normals, &vis).unwrap();
            let worst_one = one
                .iter()
                .zip(&want)
                .flat_map(|(g, w)| (0..3).map(move |c| (g[c] as f64 - w[c]).abs()))
                .fold(0.0f64, f64::max);
            eprintln!("  one tap: {:.2e}", worst_one / scale);
            assert!(polar || worst_one > 3.0 * worst, "{worst_one} vs {worst}");
        }
    }

    /// A lobe at the fit's sharpness cap is a point source, one at half of it is resolved;
    /// the cap is 2 pi / dO of the fit grid's texels by the axis, and at most 10,000.
    #[test]
    fn point_sources_are_the_lobes_at_the_fits_cap() {
        // At the equator of a 128 x 64 fit grid: dO = (2 pi / 128) (pi / 64) sin(~90 deg).
        let d_omega = std::f64::consts::TAU / 128.0
            * ((31.0 * std::f64::consts::PI / 64.0).cos()
                - (32.0 * std::f64::consts::PI / 64.0).cos());
        let cap = (std::f64::consts::TAU / d_omega) as f32;
        let at = |axis: Vec3, sharpness: f32| Lobe::new(axis, sharpness, [1.0; 3]);
        let equator = Vec3::new(0.3, 0.01, -0.95);
        assert!(is_point(&at(equator, cap), 128));
        assert!(is_point(&at(equator, 0.9 * cap), 128));
        assert!(!is_point(&at(equator, 0.5 * cap), 128));
        // Blender's studio lamps (1342-2159) are resolved on the default grid, its suns
        // (2423-2615 by the horizon) points.
        assert!(!is_point(&at(equator, 2159.0), 128));
        assert!(is_point(&at(equator, 2423.0), 128));
        // By the pole the texels are small: the cap is the fit's own 10,000.
        assert!(is_point(&at(Vec3::Y, 9000.0), 128));
        assert!(!is_point(&at(Vec3::Y, 5000.0), 128));
        // A finer fit resolves more: the sun of a 128-wide fit is a lamp of a 512-wide one.
        assert!(!is_point(&at(equator, 2423.0), 512));
        assert!(check_fit_width(128).is_ok());
        assert!(check_fit_width(0).is_err() && check_fit_width(127).is_err());
    }
}
