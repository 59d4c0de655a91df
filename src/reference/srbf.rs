//! SRBF-lighting ground truth: brute-force diffuse precomputed-radiance transfer under an
//! environment map, in f64, with per-direction visibility from ray casting.
//!
//! For vertex v with normal n, albedo rho and environment rotation R:
//!
//! ```text
//! B_v = (rho / pi) * sum_p L(R^-1 w_p) V_v(w_p) max(0, n . w_p) dOmega_p
//! ```
//!
//! over the texels p of the map, w_p the direction of texel p's centre and dOmega_p its exact
//! solid angle ([`EnvMap::solid_angle`]). This is the midpoint rule of the hemisphere
//! integral, so it carries quadrature error against the continuous integral: the cosine lobe
//! straddling the horizon and sampled at texel centres. sum_p max(0, n . w_p) dOmega_p, which
//! is pi for the exact integral, is off by at most 1.21e-3 relative at 64 x 32 (measured over
//! 505 normals; n = +Y is the worst), 7.5e-5 at 256 x 128, 4.7e-6 at 1024 x 512 and 1.2e-6 at
//! 2048 x 1024 (falling as 1 / H^2); the unit tests hold these bounds.
//!
//! L(R^-1 w_p) is a nearest-texel lookup into the same map at the rotated direction: this
//! resampling is part of the ground truth (the method being judged is compared against this
//! sum, not against a continuous rotation of L). For rotations about +Y by multiples of
//! 360 / W degrees the lookup lands exactly on texel centres, so it is exact: it equals the
//! unrotated sum over the map with its columns shifted.

use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::brdf::Brdf;
use crate::geom::sg::{self, Lobe};
use crate::geom::visibility::Visibility;
use crate::scene::EnvMap;
use glam::{Mat3, Vec3};
use rayon::prelude::*;

/// Brute-force outgoing radiance per vertex, f64: (albedo / pi) * sum over the env's texels p
/// of L(R^-1 w_p) * V(w_p) * max(0, n . w_p) * dOmega_p, where w_p is texel p's direction and
/// V comes from `vis`, which must have been computed for exactly `env.samples()`'s directions
/// (the same count and the same vectors; an error otherwise). `normals` must have one entry
/// per vertex of `vis`, `rotation` must be a rotation (orthonormal to 1e-4, det +1) and the
/// albedo finite and non-negative; otherwise an error.
pub fn shade_brute_force(
    env: &EnvMap,
    rotation: Mat3,
    normals: &[Vec3],
    vis: &Visibility,
    albedo: [f32; 3],
) -> Result<Vec<[f64; 3]>> {
    let samples = env.samples();
    if vis.directions.len() != samples.len() {
        return Err(Error::InvalidArgument(format!(
            "the visibility has {} directions, the environment {} ({} x {}) has {} texels; \
             compute it for the map's own directions (EnvMap::samples)",
            vis.directions.len(),
            env.source.display(),
            env.width,
            env.height,
            samples.len()
        )));
    }
    if let Some(i) = samples
        .iter()
        .zip(&vis.directions)
        .position(|(s, d)| (s.0 - *d).length() > 1e-6)
    {
        return Err(Error::InvalidArgument(format!(
            "visibility direction {i} ({}) is not the direction of texel {i} of {} ({}); \
             compute it for the map's own directions (EnvMap::samples)",
            vis.directions[i],
            env.source.display(),
            samples[i].0
        )));
    }
    if normals.len() != vis.vertices {
        return Err(Error::InvalidArgument(format!(
            "{} normals for a visibility of {} vertices",
            normals.len(),
            vis.vertices
        )));
    }
    check_rotation_and_albedo(rotation, albedo)?;
    let rt = rotation.transpose();
    // The rotated radiance times the solid angle does not depend on the vertex.
    let weighted: Vec<[f64; 3]> = samples
        .par_iter()
        .map(|(w, d_omega, _)| {
            let l = env.lookup(rt * *w);
            l.map(|c| c as f64 * d_omega)
        })
        .collect();
    Ok(sum_visible(&samples, &weighted, normals, vis, albedo))
}

/// The ground truth under any rotation: the rotation moves the map's texel directions
/// instead of resampling the map,
///
/// ```text
/// B_v = (rho / pi) * sum_p L_p dOmega_p V_v(R w_p) max(0, n . R w_p)
/// ```
///
/// (the change of variables w = R w' in the integral of L(R^-1 w) V(w) cos), with the
/// visibility ray-cast along every rotated direction (BVH of `mesh`, rays from
/// p + 1e-4 diagonal x n). Every texel keeps its radiance and exact solid angle, so a
/// one-texel sun keeps its energy at any rotation; [`shade_brute_force`]'s nearest-texel
/// lookup of the rotated map drops or doubles such a texel for rotations that do not map the
/// grid onto itself (it equals this sum for rotations about +Y by multiples of 360 / W
/// degrees). Costs a ray per (vertex, texel) per call, except for those rotations when
/// `grid_visibility` (the visibility of `env`'s own texel directions,
/// [`crate::scene::envmap::texel_visibility`]) is
/// given: then it is [`shade_brute_force`] with it, the same sum.
pub fn shade_ground_truth(
    env: &EnvMap,
    rotation: Mat3,
    mesh: &crate::scene::Mesh,
    grid_visibility: Option<&Visibility>,
    albedo: [f32; 3],
) -> Result<Vec<[f64; 3]>> {
    check_rotation_and_albedo(rotation, albedo)?;
    if let Some(vis) = grid_visibility
        && maps_grid_onto_itself(env, rotation)
    {
        // The rotated directions are the grid's own: the precomputed visibility is exact.
        return shade_brute_force(env, rotation, &mesh.normals, vis, albedo);
    }
    let scale = albedo.map(|a| a as f64 / std::f64::consts::PI);
    let sums = ray_cast_sum(
        env,
        rotation,
        mesh,
        &mesh.positions,
        &mesh.normals,
        |_, n, w| n.dot(w),
    );
    Ok(sums
        .into_iter()
        .map(|s| [0, 1, 2].map(|c| s[c] * scale[c]))
        .collect())
}

/// sum_p L_p dOmega_p V_i(R w_p) f(i, n_i, R w_p) for every point i, f64, with f the
/// caller's BRDF x cosine factor (terms with f <= 0 are skipped, as are texels whose
/// radiance is 0 in every channel: they add exactly 0). The visibility is ray-cast per
/// (point, texel) against `occluder`'s BVH from x_i + 1e-4 diagonal x n_i (the offset of
/// [`crate::scene::envmap::texel_visibility`]), streamed: nothing of size points x texels is
/// held, so a full-resolution map (524,288 texels at 1024 x 512) costs time, not memory.
fn ray_cast_sum(
    env: &EnvMap,
    rotation: Mat3,
    occluder: &crate::scene::Mesh,
    points: &[Vec3],
    normals: &[Vec3],
    f: impl Fn(usize, glam::DVec3, glam::DVec3) -> f64 + Sync,
) -> Vec<[f64; 3]> {
    // (rotated direction in f32 for the ray, in f64 for the terms, L dOmega).
    let texels: Vec<(Vec3, glam::DVec3, [f64; 3])> = env
        .samples()
        .into_iter()
        .filter(|(_, _, l)| l.iter().any(|&c| c != 0.0))
        .map(|(w, d_omega, l)| {
            let r = (rotation * w).normalize();
            (r, r.as_dvec3(), l.map(|c| c as f64 * d_omega))
        })
        .collect();
    let (lo, hi) = occluder.bounds();
    let offset = 1e-4 * (hi - lo).length();
    let bvh = Bvh::build(&occluder.positions, &occluder.triangles);
    (0..points.len().min(normals.len()))
        .into_par_iter()
        .map(|i| {
            let (p, n) = (points[i], normals[i]);
            let origin = p + offset * n;
            let nd = n.as_dvec3();
            let mut sum = [0f64; 3];
            for (w, wd, le) in &texels {
                if n.dot(*w) <= 0.0 {
                    continue;
                }
                let term = f(i, nd, *wd);
                if term > 0.0 && !bvh.any_hit(origin, *w, f32::INFINITY) {
                    for c in 0..3 {
                        sum[c] += le[c] * term;
                    }
                }
            }
            sum
        })
        .collect()
}

/// The glossy ground truth: radiance toward a camera at `camera` (model units) of each
/// point `points[i]` with unit normal `normals[i]` under `env` rotated by `rotation`,
///
/// ```text
/// B_i = albedo * sum_p L_p dOmega_p V_i(R w_p) rho(R w_p, o_i) max(0, n_i . R w_p)
/// ```
///
/// over every texel p of `env` (pass the map at its own resolution for the full truth), f64,
/// rho and o_i from the model ([`Brdf`], [`Brdf::view_direction`]), the visibility ray-cast
/// along every rotated direction against `occluder` (rays from x + 1e-4 diagonal x n, as
/// [`crate::scene::envmap::texel_visibility`]). The points may be any subset of the
/// occluder's vertices (or other points). One ray per (point, texel): cost scales with both.
#[allow(clippy::too_many_arguments)]
pub fn shade_glossy_truth(
    env: &EnvMap,
    rotation: Mat3,
    occluder: &crate::scene::Mesh,
    points: &[Vec3],
    normals: &[Vec3],
    brdf: &Brdf,
    camera: Vec3,
    albedo: [f32; 3],
) -> Result<Vec<[f64; 3]>> {
    check_rotation_and_albedo(rotation, albedo)?;
    brdf.check()?;
    if points.len() != normals.len() {
        return Err(Error::InvalidArgument(format!(
            "{} points and {} normals",
            points.len(),
            normals.len()
        )));
    }
    if !camera.is_finite() {
        return Err(Error::InvalidArgument(format!(
            "camera {camera} is not finite"
        )));
    }
    let views: Vec<glam::DVec3> = points
        .iter()
        .zip(normals)
        .map(|(p, n)| Brdf::view_direction(n.as_dvec3(), p.as_dvec3(), camera.as_dvec3()))
        .collect();
    let sums = ray_cast_sum(env, rotation, occluder, points, normals, |i, n, w| {
        brdf.cosine_weighted(n, w, views[i])
    });
    Ok(sums
        .into_iter()
        .map(|s| [0, 1, 2].map(|c| s[c] * albedo[c] as f64))
        .collect())
}

/// Whether `rotation` is about +Y by a multiple of 360 / W degrees (to 1e-4 of a column), so
/// that it maps the texel centres of `env` onto texel centres.
fn maps_grid_onto_itself(env: &EnvMap, rotation: Mat3) -> bool {
    let x = rotation * Vec3::X;
    if (rotation * Vec3::Y - Vec3::Y).length() > 1e-6 {
        return false;
    }
    let angle = (-x.z as f64).atan2(x.x as f64);
    let columns = angle * env.width as f64 / std::f64::consts::TAU;
    (columns - columns.round()).abs() < 1e-4
}

fn check_rotation_and_albedo(rotation: Mat3, albedo: [f32; 3]) -> Result<()> {
    let gram = rotation.transpose() * rotation;
    let off = (gram - Mat3::IDENTITY).to_cols_array().map(f32::abs);
    if !rotation.is_finite() || off.iter().any(|&e| e > 1e-4) || rotation.determinant() <= 0.0 {
        return Err(Error::InvalidArgument(format!(
            "the environment rotation {rotation} is not a rotation matrix (orthonormal, det +1)"
        )));
    }
    if albedo.iter().any(|a| !a.is_finite() || *a < 0.0) {
        return Err(Error::InvalidArgument(format!(
            "albedo {albedo:?} must be finite and non-negative"
        )));
    }
    Ok(())
}

/// The same sum with the radiance of every texel of `env` given directly (`radiance[p]` for
/// texel p, row-major, already rotated; it may be negative): e.g. the fitted lobes
/// rasterised by [`rasterise_lobes`], which isolates the fit's share of the method's error.
pub fn shade_brute_force_radiance(
    env: &EnvMap,
    radiance: &[[f64; 3]],
    normals: &[Vec3],
    vis: &Visibility,
    albedo: [f32; 3],
) -> Result<Vec<[f64; 3]>> {
    let samples = env.samples();
    if radiance.len() != samples.len() || vis.directions.len() != samples.len() {
        return Err(Error::InvalidArgument(format!(
            "{} radiance values and {} visibility directions for a map of {} texels",
            radiance.len(),
            vis.directions.len(),
            samples.len()
        )));
    }
    if normals.len() != vis.vertices {
        return Err(Error::InvalidArgument(format!(
            "{} normals for a visibility of {} vertices",
            normals.len(),
            vis.vertices
        )));
    }
    let weighted: Vec<[f64; 3]> = samples
        .iter()
        .zip(radiance)
        .map(|((_, d_omega, _), l)| l.map(|c| c * d_omega))
        .collect();
    Ok(sum_visible(&samples, &weighted, normals, vis, albedo))
}

/// Mean radiance over every texel of `env`'s grid of the lobes rotated by `rotation`
/// (L~_R(w) = L~(R^-1 w)): each texel integrated on a 16 x 16 grid of sub-texels weighted by
/// their solid angles; a lobe narrower than a sub-texel (1 / sqrt(lambda) below its angular
/// size) puts its whole integral into the texel holding its axis instead.
pub fn rasterise_lobes(lobes: &[Lobe], rotation: Mat3, env: &EnvMap) -> Vec<[f64; 3]> {
    const SUB: u32 = 16;
    let (w, h) = (env.width, env.height);
    let sub_angle = std::f64::consts::PI / (h * SUB) as f64;
    let rotated: Vec<Lobe> = lobes.iter().map(|l| l.rotated(rotation)).collect();
    let (sharp, smooth): (Vec<Lobe>, Vec<Lobe>) = rotated
        .into_iter()
        .partition(|l| 1.0 / (l.sharpness as f64).sqrt() < sub_angle);
    let mut out: Vec<[f64; 3]> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let (x, y) = (p % w, p / w);
            let mut sum = [0f64; 3];
            let mut weight = 0f64;
            for j in 0..SUB {
                let v = (y as f64 + (j as f64 + 0.5) / SUB as f64) / h as f64;
                let theta = std::f64::consts::PI * v;
                let d_omega = theta.sin();
                for i in 0..SUB {
                    let u = (x as f64 + (i as f64 + 0.5) / SUB as f64) / w as f64;
                    let dir = crate::scene::envmap::direction_of(u, v);
                    for l in &smooth {
                        let g = (l.sharpness as f64 * (l.axis().as_dvec3().dot(dir) - 1.0)).exp();
                        for (s, a) in sum.iter_mut().zip(l.amplitude) {
                            *s += a as f64 * g * d_omega;
                        }
                    }
                    weight += d_omega;
                }
            }
            sum.map(|s| if weight > 0.0 { s / weight } else { 0.0 })
        })
        .collect();
    for l in &sharp {
        let (x, y) = env.texel_of(l.axis());
        let total = sg::integral(l.sharpness as f64) / env.solid_angle(y);
        let t = &mut out[(y * w + x) as usize];
        for (tc, a) in t.iter_mut().zip(l.amplitude) {
            *tc += a as f64 * total;
        }
    }
    out
}

/// (albedo / pi) sum_p weighted_p V_v(w_p) max(0, n . w_p) for every vertex.
fn sum_visible(
    samples: &[(Vec3, f64, [f32; 3])],
    weighted: &[[f64; 3]],
    normals: &[Vec3],
    vis: &Visibility,
    albedo: [f32; 3],
) -> Vec<[f64; 3]> {
    let dirs: Vec<[f64; 3]> = samples.iter().map(|s| s.0.as_dvec3().to_array()).collect();
    let scale = albedo.map(|a| a as f64 / std::f64::consts::PI);
    (0..vis.vertices)
        .into_par_iter()
        .map(|v| {
            let n = normals[v].as_dvec3();
            let mut sum = [0.0f64; 3];
            for (k, &word) in vis.row(v).iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    let p = k * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let w = dirs[p];
                    let cos = n.x * w[0] + n.y * w[1] + n.z * w[2];
                    if cos > 0.0 {
                        for c in 0..3 {
                            sum[c] += weighted[p][c] * cos;
                        }
                    }
                }
            }
            [0, 1, 2].map(|c| sum[c] * scale[c])
        })
        .collect()
}

/// The resolution of `--reference`'s brute-force truth (`--reference-width`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ReferenceWidth {
    /// The direction map (`--directions`, 64 x 32 by default): the texels the transfer and
    /// the compact lobes' visibility use, so a sun is a texel of that size (the behaviour
    /// before `--reference-width`).
    Directions,
    /// The map at its own resolution: every texel, no downsampling.
    Full,
    /// The map box-filtered to this width (even, dividing the map's width).
    Width(u32),
}

impl std::str::FromStr for ReferenceWidth {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "directions" => Ok(ReferenceWidth::Directions),
            "full" => Ok(ReferenceWidth::Full),
            w => w.parse::<u32>().map(ReferenceWidth::Width).map_err(|_| {
                format!("'{s}': expected full, directions or a width (an even number)")
            }),
        }
    }
}

impl std::fmt::Display for ReferenceWidth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReferenceWidth::Directions => write!(f, "directions"),
            ReferenceWidth::Full => write!(f, "full"),
            ReferenceWidth::Width(w) => write!(f, "{w}"),
        }
    }
}

impl ReferenceWidth {
    /// The map the truth integrates: `env` itself, or a box-filtered copy; `None` when it
    /// is the direction map (`direction_width` wide) the run already holds.
    pub fn map(self, env: &EnvMap, direction_width: u32) -> Result<Option<EnvMap>> {
        let w = match self {
            ReferenceWidth::Directions => return Ok(None),
            ReferenceWidth::Full => env.width,
            ReferenceWidth::Width(w) => w,
        };
        if w == direction_width.min(env.width) {
            return Ok(None);
        }
        if w > env.width || !env.width.is_multiple_of(w) || w % 2 != 0 {
            return Err(Error::InvalidArgument(format!(
                "--reference-width {w}: {} is {} x {}; the width must be even, at most {}                  and divide it (or 'full')",
                env.source.display(),
                env.width,
                env.height,
                env.width
            )));
        }
        Ok(Some(if w == env.width {
            env.clone()
        } else {
            env.downsampled(w)?
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// sum_p max(0, n . w_p) dOmega_p over a W x W/2 map (pi for the exact integral).
    fn cosine_quadrature(env: &EnvMap, n: Vec3) -> f64 {
        env.samples()
            .iter()
            .map(|(w, d, _)| (n.as_dvec3().dot(w.as_dvec3())).max(0.0) * d)
            .sum()
    }

    #[test]
    fn rasterised_lobes_keep_their_integral() {
        let env = EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "grid").unwrap();
        let lobes = [
            Lobe {
                axis: Vec3::new(0.3, 0.8, -0.2).normalize().to_array(),
                sharpness: 5.0,
                amplitude: [1.0, 2.0, 0.5],
            },
            Lobe {
                axis: Vec3::new(-0.5, 0.1, 0.7).normalize().to_array(),
                sharpness: 2.0e6,
                amplitude: [1.0e4, 0.0, 3.0e3],
            },
        ];
        let r = sg::rotation(Vec3::new(1.0, 2.0, 0.5), 40.0);
        let raster = rasterise_lobes(&lobes, r, &env);
        let samples = env.samples();
        for c in 0..3 {
            let got: f64 = raster.iter().zip(&samples).map(|(l, s)| l[c] * s.1).sum();
            let want: f64 = lobes
                .iter()
                .map(|l| l.amplitude[c] as f64 * sg::integral(l.sharpness as f64))
                .sum();
            assert!(
                (got - want).abs() <= 2e-3 * want,
                "channel {c}: {got} vs {want}"
            );
        }
        // The sharp lobe lands in the texel of its rotated axis.
        let (x, y) = env.texel_of(r * lobes[1].axis());
        let sharp = 1.0e4 * sg::integral(2.0e6);
        assert!(raster[(y * 64 + x) as usize][0] * env.solid_angle(y) > sharp);
    }

    #[test]
    fn cosine_quadrature_bound_at_64x32() {
        let env = EnvMap::from_texels(64, 32, vec![[1.0; 3]; 64 * 32], "const").unwrap();
        let mut worst: f64 = 0.0;
        let mut rng = crate::geom::Rng::new(7);
        let mut normals = vec![Vec3::Y, -Vec3::Y, Vec3::X, Vec3::Z, Vec3::ONE.normalize()];
        for _ in 0..500 {
            normals.push(crate::geom::uniform_sphere(rng.f32(), rng.f32()));
        }
        for n in normals {
            let rel =
                (cosine_quadrature(&env, n) - std::f64::consts::PI).abs() / std::f64::consts::PI;
            worst = worst.max(rel);
        }
        println!("64x32 cosine quadrature: max relative error {worst:.3e}");
        assert!(worst < 1.25e-3, "quadrature error {worst}");
        // The midpoint rule's error falls as 1 / H^2 (n = +Y is the worst case above).
        for (w, bound) in [(256u32, 8e-5), (1024, 5e-6), (2048, 1.25e-6)] {
            let env =
                EnvMap::from_texels(w, w / 2, vec![[1.0; 3]; (w * w / 2) as usize], "c").unwrap();
            let rel = (cosine_quadrature(&env, Vec3::Y) - std::f64::consts::PI).abs()
                / std::f64::consts::PI;
            println!(
                "{w}x{} cosine quadrature, n = +Y: relative error {rel:.3e}",
                w / 2
            );
            assert!(rel < bound, "{w}: {rel}");
        }
    }
}
