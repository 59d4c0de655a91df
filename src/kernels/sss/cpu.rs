//! The CPU twin of the GPU passes: the same irradiance (same rays through the same BVH) and
//! the same diffusion sampler (same hash, same sample sequence, same f32 arithmetic as
//! glsl/sss/diffusion.comp, in the same order).

use super::contact::Contact;
use super::profile::Profile;
use super::regions::Regions;
use super::walk::{Landing, SurfaceWalk};
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;
use crate::scene::texspace::{COVERED, NO_TRIANGLE, TexGeometry};
use glam::Vec3;
use rayon::prelude::*;

/// A light (positions and directions in mm, after scaling by mm per unit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Arriving from `toward` (the vector points to the light); irradiance `e` on a surface
    /// facing it.
    Directional { toward: Vec3, e: f32 },
    /// At `pos` (mm) with intensity `i`: irradiance i cos / d^2 (d in mm).
    Point { pos: Vec3, i: f32 },
}

/// At most this many lights per frame.
pub const MAX_LIGHTS: usize = 16;

/// Largest |coordinate| of a light's direction or position: normalising or measuring a
/// vector squares its components in f32, and 3 x (1e18)^2 = 3e36 stays below f32's 3.4e38
/// (a 1e30 component overflows to infinity and the direction becomes NaN).
pub const MAX_LIGHT_COORDINATE: f32 = 1e18;

/// Largest light strength (irradiance or intensity): the shading multiplies it by albedos,
/// profiles and areas and sums over texels in f32; 1e12 is the radiance bound of the
/// environment maps ([`crate::scene::envmap::MAX_RADIANCE`]), for the same reason.
pub const MAX_LIGHT_STRENGTH: f32 = 1e12;

impl Light {
    /// At point `p`: the unit direction towards the light, the shadow ray's length (a point
    /// light's distance less `bias`) and the irradiance on a surface facing it.
    pub fn arriving_at(&self, p: Vec3, bias: f32) -> (Vec3, f32, f32) {
        match *self {
            Light::Directional { toward, e } => (toward, f32::INFINITY, e),
            Light::Point { pos, i } => {
                let d = pos - p;
                let dist = d.length();
                (d / dist, dist - bias, i / (dist * dist))
            }
        }
    }

    /// Parses `dir:X,Y,Z[:E]` or `point:X,Y,Z:I` (point position in model units, scaled by
    /// `mm_per_unit`).
    pub fn parse(s: &str, mm_per_unit: f32) -> Result<Light> {
        let bad = |m: &str| {
            Error::InvalidArgument(format!(
                "--light '{s}': {m} (expected dir:X,Y,Z[:E] or point:X,Y,Z:I)"
            ))
        };
        let parts: Vec<&str> = s.split(':').collect();
        let xyz: Vec<f32> = parts
            .get(1)
            .ok_or_else(|| bad("no coordinates"))?
            .split(',')
            .map(|t| t.trim().parse::<f32>().map_err(|_| bad("not a number")))
            .collect::<Result<_>>()?;
        if xyz.len() != 3 || xyz.iter().any(|x| !x.is_finite()) {
            return Err(bad("needs three finite coordinates"));
        }
        if xyz.iter().any(|x| x.abs() > MAX_LIGHT_COORDINATE) {
            return Err(bad(&format!(
                "a coordinate is beyond +-{MAX_LIGHT_COORDINATE:e} (normalising it would \
                 overflow f32)"
            )));
        }
        let v = Vec3::new(xyz[0], xyz[1], xyz[2]);
        let value = match parts.get(2) {
            Some(t) => t.trim().parse::<f32>().map_err(|_| bad("bad strength"))?,
            None => 1.0,
        };
        if parts.len() > 3 || !(value.is_finite() && (0.0..=MAX_LIGHT_STRENGTH).contains(&value)) {
            return Err(bad(&format!(
                "strength must be finite and in 0..={MAX_LIGHT_STRENGTH:e}"
            )));
        }
        let light = match parts[0] {
            "dir" => {
                if v.length() < 1e-6 {
                    return Err(bad("zero direction"));
                }
                Light::Directional {
                    toward: v.normalize(),
                    e: value,
                }
            }
            "point" if parts.len() == 3 => {
                let pos = v * mm_per_unit;
                if !pos.is_finite() || pos.abs().max_element() > MAX_LIGHT_COORDINATE {
                    return Err(bad(&format!(
                        "the position in mm ({mm_per_unit} mm per unit) is beyond \
                         +-{MAX_LIGHT_COORDINATE:e}"
                    )));
                }
                Light::Point { pos, i: value }
            }
            "point" => return Err(bad("a point light needs an intensity")),
            _ => return Err(bad("unknown kind")),
        };
        Ok(light)
    }

    /// The GPU layout: (xyz, kind 0 directional / 1 point), (strength, 0, 0, 0).
    pub fn gpu(&self) -> [[f32; 4]; 2] {
        match *self {
            Light::Directional { toward, e } => [toward.extend(0.0).into(), [e, 0.0, 0.0, 0.0]],
            Light::Point { pos, i } => [pos.extend(1.0).into(), [i, 0.0, 0.0, 0.0]],
        }
    }
}

/// Checks a frame's lights.
pub fn check_lights(lights: &[Light]) -> Result<()> {
    if lights.len() > MAX_LIGHTS {
        return Err(Error::InvalidArgument(format!(
            "{} lights (at most {MAX_LIGHTS})",
            lights.len()
        )));
    }
    for (k, l) in lights.iter().enumerate() {
        let problem = match *l {
            Light::Directional { toward, e } => {
                if !(toward.is_finite() && (toward.length() - 1.0).abs() < 1e-3) {
                    Some(format!("direction {toward} is not a finite unit vector"))
                } else if !(e.is_finite() && (0.0..=MAX_LIGHT_STRENGTH).contains(&e)) {
                    Some(format!(
                        "irradiance {e} is not in 0..={MAX_LIGHT_STRENGTH:e}"
                    ))
                } else {
                    None
                }
            }
            Light::Point { pos, i } => {
                if !pos.is_finite() || pos.abs().max_element() > MAX_LIGHT_COORDINATE {
                    Some(format!(
                        "position {pos} (mm) is not finite within +-{MAX_LIGHT_COORDINATE:e}"
                    ))
                } else if !(i.is_finite() && (0.0..=MAX_LIGHT_STRENGTH).contains(&i)) {
                    Some(format!(
                        "intensity {i} is not in 0..={MAX_LIGHT_STRENGTH:e}"
                    ))
                } else {
                    None
                }
            }
        };
        if let Some(p) = problem {
            return Err(Error::InvalidArgument(format!("light {k}: {p}")));
        }
    }
    Ok(())
}

/// The shadow-ray offset along the normal (mm) for a mesh of this extent.
pub fn shadow_bias(extent_mm: f32) -> f32 {
    1e-3 * extent_mm
}

/// Irradiance of one point (white lights: the same E in every channel), shadow rays
/// through `bvh` from `p + n * bias`.
pub fn irradiance_at(bvh: &Bvh, p: Vec3, n: Vec3, lights: &[Light], bias: f32) -> f32 {
    let mut e = 0.0;
    let o = p + n * bias;
    for l in lights {
        let (dir, tmax, strength) = l.arriving_at(p, bias);
        let c = n.dot(dir);
        if c <= 0.0 || strength == 0.0 {
            continue;
        }
        if bvh.any_hit(o, dir, tmax) {
            continue;
        }
        e += strength * c;
    }
    e
}

/// Per-vertex position (mm) and unit normal, as the GPU reads them (`verts`, two vec4 per
/// vertex). A zero or missing normal falls back to the area-weighted normal of the vertex's
/// triangles.
pub fn vertex_frames(geo: &TexGeometry) -> Vec<[[f32; 4]; 2]> {
    let mut face = vec![Vec3::ZERO; geo.positions.len()];
    for t in &geo.triangles {
        let p = t.map(|i| geo.positions[i as usize]);
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        for &i in t {
            face[i as usize] += n;
        }
    }
    geo.positions
        .iter()
        .enumerate()
        .map(|(v, p)| {
            let n = geo
                .normals
                .get(v)
                .and_then(|n| n.try_normalize())
                .unwrap_or_else(|| face[v].normalize_or_zero());
            [p.extend(0.0).into(), n.extend(0.0).into()]
        })
        .collect()
}

/// Visibility bits of `lights` from `p` (bit l: light l not blocked along a ray from
/// `p + n * bias`), as pass `sss vertex light` computes them per vertex.
pub fn visibility(bvh: &Bvh, p: Vec3, n: Vec3, lights: &[Light], bias: f32) -> u32 {
    let o = p + n * bias;
    let mut bits = 0;
    for (l, light) in lights.iter().enumerate() {
        let (dir, tmax) = match *light {
            Light::Directional { toward, .. } => (toward, f32::INFINITY),
            Light::Point { pos, .. } => {
                let d = pos - p;
                let dist = d.length();
                (d / dist, dist - bias)
            }
        };
        if !bvh.any_hit(o, dir, tmax) {
            bits |= 1 << l;
        }
    }
    bits
}

/// The per-vertex visibility bits (pass `sss vertex light`).
pub fn vertex_visibility(geo: &TexGeometry, bvh: &Bvh, lights: &[Light]) -> Vec<u32> {
    let bias = shadow_bias(geo.extent_mm());
    vertex_frames(geo)
        .par_iter()
        .map(|f| {
            let p = Vec3::from_slice(&f[0][..3]);
            let n = Vec3::from_slice(&f[1][..3]);
            visibility(bvh, p, n, lights, bias)
        })
        .collect()
}

/// Per texel, what the irradiance pass reads (image `corners`): the vertex indices of the
/// texel's triangle and its centre's barycentrics w1, w2 as 16-bit fractions of 2^16, packed
/// w1 | w2 << 16 (resolution 1.5e-5); zero for empty texels.
pub fn texel_corners_packed(geo: &TexGeometry) -> Vec<[u32; 4]> {
    geo.texel_tri
        .iter()
        .map(|t| {
            let Some(tri) = geo.triangles.get(t[0] as usize) else {
                return [0; 4];
            };
            let q = |bits: u32| (f32::from_bits(bits) * 65536.0).round().clamp(0.0, 65535.0) as u32;
            [tri[0], tri[1], tri[2], q(t[1]) | q(t[2]) << 16]
        })
        .collect()
}

/// The texel's triangle corners and barycentrics as the shader decodes them from
/// [`texel_corners_packed`] (w0 = 1 - w1 - w2 in f32); None for empty texels.
fn texel_corners(geo: &TexGeometry, i: usize) -> Option<([usize; 3], [f32; 3])> {
    let t = geo.texel_tri[i];
    let tri = geo.triangles.get(t[0] as usize)?;
    let q = |bits: u32| (f32::from_bits(bits) * 65536.0).round().clamp(0.0, 65535.0);
    let (w1, w2) = (q(t[1]) * (1.0 / 65536.0), q(t[2]) * (1.0 / 65536.0));
    Some((tri.map(|v| v as usize), [1.0 - w1 - w2, w1, w2]))
}

/// The irradiance pass on the CPU: E per texel (rgb, alpha 1 where the texel is valid), the
/// shader's method: the texel's own cosine and point-light distance, the visibility of each
/// light interpolated from the triangle's vertices ([`vertex_visibility`]).
pub fn irradiance(geo: &TexGeometry, bvh: &Bvh, lights: &[Light], refine: bool) -> Vec<[f32; 4]> {
    let vis = vertex_visibility(geo, bvh, lights);
    irradiance_from_visibility(geo, bvh, lights, &vis, refine)
}

/// [`irradiance`] from given per-vertex visibility bits; `refine`: a shadow ray from the texel
/// where the triangle's corners disagree (else, and in gutter texels, their visibility
/// interpolated).
pub fn irradiance_from_visibility(
    geo: &TexGeometry,
    bvh: &Bvh,
    lights: &[Light],
    vis: &[u32],
    refine: bool,
) -> Vec<[f32; 4]> {
    irradiance_with_vertex_irradiance(geo, bvh, lights, vis, refine, None)
}

/// [`irradiance`] plus a per-vertex rgb irradiance (the GPU's
/// [`super::SssKernel::set_vertex_irradiance`]): per texel, `vertex_e` of its triangle's
/// corners interpolated with the barycentrics the shader decodes and added to the lights' E
/// (the shader's arithmetic: w0 E0 + w1 E1 + w2 E2, then E_lights + that).
pub fn irradiance_with_vertex(
    geo: &TexGeometry,
    bvh: &Bvh,
    lights: &[Light],
    refine: bool,
    vertex_e: &[[f32; 4]],
) -> Vec<[f32; 4]> {
    let vis = vertex_visibility(geo, bvh, lights);
    irradiance_with_vertex_irradiance(geo, bvh, lights, &vis, refine, Some(vertex_e))
}

/// [`irradiance_from_visibility`] with an optional per-vertex rgb irradiance added
/// ([`irradiance_with_vertex`]).
pub fn irradiance_with_vertex_irradiance(
    geo: &TexGeometry,
    bvh: &Bvh,
    lights: &[Light],
    vis: &[u32],
    refine: bool,
    vertex_e: Option<&[[f32; 4]]>,
) -> Vec<[f32; 4]> {
    let bias = shadow_bias(geo.extent_mm());
    (0..geo.texels())
        .into_par_iter()
        .map(|i| {
            let p = geo.pos[i];
            if p[3] == 0.0 {
                return [0.0; 4];
            }
            let Some((ids, w)) = texel_corners(geo, i) else {
                return [0.0; 4];
            };
            // Gutter texels (no surface of their own: they repeat a chart's border for
            // filtering) interpolate instead of casting a ray.
            let refine = refine && p[3] == COVERED;
            let p = Vec3::new(p[0], p[1], p[2]);
            let n = Vec3::from_slice(&geo.nrm[i][..3]);
            let b = ids.map(|v| vis[v]);
            let mut e = 0.0;
            for (l, light) in lights.iter().enumerate() {
                let (dir, tmax, strength) = light.arriving_at(p, bias);
                let c = n.dot(dir);
                if c <= 0.0 || strength == 0.0 {
                    continue;
                }
                let cb = b.map(|x| (x >> l) & 1);
                // Exactly 0 or 1 when the corners agree (as the shader).
                let v = if cb[0] == cb[1] && cb[1] == cb[2] {
                    cb[0] as f32
                } else if refine {
                    if bvh.any_hit(p + n * bias, dir, tmax) {
                        0.0
                    } else {
                        1.0
                    }
                } else {
                    w[0] * cb[0] as f32 + w[1] * cb[1] as f32 + w[2] * cb[2] as f32
                };
                e += strength * c * v;
            }
            match vertex_e {
                Some(ve) => {
                    let [a, b, c] = ids.map(|v| ve[v]);
                    let at = |k: usize| e + (w[0] * a[k] + w[1] * b[k] + w[2] * c[k]);
                    [at(0), at(1), at(2), 1.0]
                }
                None => [e, e, e, 1.0],
            }
        })
        .collect()
}

/// Irradiance with a shadow ray from every texel (the method before per-vertex shadowing;
/// kept to measure what the interpolation changes, report.json `shadowing`).
pub fn irradiance_per_texel_rays(geo: &TexGeometry, bvh: &Bvh, lights: &[Light]) -> Vec<[f32; 4]> {
    let bias = shadow_bias(geo.extent_mm());
    (0..geo.texels())
        .into_par_iter()
        .map(|i| {
            let p = geo.pos[i];
            if p[3] == 0.0 {
                return [0.0; 4];
            }
            let n = Vec3::new(geo.nrm[i][0], geo.nrm[i][1], geo.nrm[i][2]);
            let e = irradiance_at(bvh, Vec3::new(p[0], p[1], p[2]), n, lights, bias);
            [e, e, e, 1.0]
        })
        .collect()
}

/// The transmission through thin parts on the CPU (the shaders' arithmetic): per vertex, a
/// ray from just inside the surface along -n finds the back surface at distance t
/// (thickness); if t is below `max_thickness`, the back point's irradiance E_b (its own
/// geometric normal, shadow rays as for the front) times R_tot - F(t) per channel
/// ([`Profile::tail_f32`]): the diffuse transmission of a locally flat slab lit uniformly
/// from behind. Per texel, the vertices' (rgb, t) interpolated with the texel's barycentrics
/// (alpha: the interpolated thickness; 0 where no vertex of the triangle transmits).
pub fn transmission(
    geo: &TexGeometry,
    bvh: &Bvh,
    lights: &[Light],
    regions: &Regions,
) -> Vec<[f32; 4]> {
    let vt = vertex_transmission(geo, bvh, lights, regions);
    (0..geo.texels())
        .into_par_iter()
        .map(|i| {
            if geo.pos[i][3] == 0.0 {
                return [0.0; 4];
            }
            let Some((ids, w)) = texel_corners(geo, i) else {
                return [0.0; 4];
            };
            [0, 1, 2, 3].map(|c| w[0] * vt[ids[0]][c] + w[1] * vt[ids[1]][c] + w[2] * vt[ids[2]][c])
        })
        .collect()
}

/// The per-vertex transmission (rgb, thickness) of [`transmission`], each vertex with its
/// region's profile ([`Regions::of_vertices`]).
pub fn vertex_transmission(
    geo: &TexGeometry,
    bvh: &Bvh,
    lights: &[Light],
    regions: &Regions,
) -> Vec<[f32; 4]> {
    let bias = shadow_bias(geo.extent_mm());
    let region = regions.of_vertices(&geo.triangles, geo.positions.len());
    vertex_frames(geo)
        .par_iter()
        .zip(&region)
        .map(|(f, &r)| {
            let profile = regions.profile(r as usize);
            let max_t = profile.max_radius() as f32;
            let p = Vec3::from_slice(&f[0][..3]);
            let n = Vec3::from_slice(&f[1][..3]);
            let o = p - n * bias;
            let Some((t, nb)) = bvh.closest_hit(o, -n, max_t) else {
                return [0.0; 4];
            };
            let nb = if nb.dot(n) > 0.0 { -nb } else { nb };
            let xb = o - n * t;
            let eb = irradiance_at(bvh, xb, nb, lights, bias);
            let thick = t + bias;
            let tr = [0, 1, 2].map(|c| eb * profile.tail_f32(c, thick));
            [tr[0], tr[1], tr[2], thick]
        })
        .collect()
}

/// PCG hash (O'Neill), as in the shader.
pub fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// The texel's rotation of the shared sample pattern (radians), as the shader computes it.
pub fn rotation(texel: u32) -> f32 {
    std::f32::consts::TAU * ((pcg(texel) >> 8) as f32 / 16_777_216.0)
}

/// The shared sample pattern the GPU reads from an image, one texel per sample:
/// (ux, uy, w_r, w_g); w_b = 3 - w_r - w_g (the one-sample MIS weights p_c / mean p sum to 3).
/// Radii r from [`Profile::mixture_sequence`] (stratified over the mixture of the channels'
/// pdfs), directions on the golden-angle spiral: (ux, uy) = r (cos 2 pi 0.618034 s,
/// sin 2 pi 0.618034 s). Each texel turns the whole pattern by its own angle ([`rotation`]).
pub fn sample_pattern(profile: &Profile, n: u32) -> Vec<[f32; 4]> {
    let golden = std::f64::consts::TAU * 0.618_034;
    profile
        .mixture_sequence(n)
        .iter()
        .enumerate()
        .map(|(s, q)| {
            let r = q[0] as f64;
            let a = golden * s as f64;
            [(r * a.cos()) as f32, (r * a.sin()) as f32, q[1], q[2]]
        })
        .collect()
}

/// Sample `q`'s weights per channel (the blue one as the shader derives it).
pub fn pattern_weights(q: &[f32; 4]) -> [f32; 3] {
    [q[2], q[3], 3.0 - q[2] - q[3]]
}

/// The sum of each channel's weights over a pattern, in order (f32, as both sides use it).
pub fn pattern_totals(pattern: &[[f32; 4]]) -> [f32; 3] {
    let mut t = [0f32; 3];
    for q in pattern {
        let w = pattern_weights(q);
        for c in 0..3 {
            t[c] += w[c];
        }
    }
    t
}

/// The diffusion sampler's settings.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct SamplerParams {
    /// Samples per texel, shared by the three channels (one-sample MIS over channels).
    pub samples: u32,
    /// Also compute the transmission through thin parts (in the irradiance pass).
    pub transmission: bool,
    /// Shadows: a ray per texel where the triangle's corners disagree (true), or the corners'
    /// visibility interpolated (false; faster, blurrier shadow edges).
    pub shadow_refine: bool,
}

impl Default for SamplerParams {
    fn default() -> Self {
        SamplerParams {
            samples: 32,
            transmission: true,
            shadow_refine: true,
        }
    }
}

impl SamplerParams {
    pub fn check(&self) -> Result<()> {
        if !(1..=4096).contains(&self.samples) {
            return Err(Error::InvalidArgument(format!(
                "{} samples per texel (1..=4096)",
                self.samples
            )));
        }
        Ok(())
    }
}

/// What the diffusion reads besides the texels: the surface walk and the contact sums.
pub struct DiffusionGeometry {
    pub walk: SurfaceWalk,
    pub contact: Contact,
}

impl DiffusionGeometry {
    pub fn build(geo: &TexGeometry, regions: &Regions) -> DiffusionGeometry {
        DiffusionGeometry {
            walk: SurfaceWalk::build(geo),
            contact: Contact::build(geo, regions),
        }
    }
}

/// The diffusion pass on the CPU: B per texel (rgb; alpha the fraction of the samples not
/// lost), from irradiance `e` (rgba, as the irradiance pass writes it). One sample set for
/// the three channels ([`Profile::mixture_sequence`]), as the shader; each texel with its
/// region's profile ([`Regions`]: the exit point's).
pub fn diffusion(
    geo: &TexGeometry,
    regions: &Regions,
    e: &[[f32; 4]],
    params: &SamplerParams,
) -> Vec<[f32; 4]> {
    diffusion_with(
        &DiffusionGeometry::build(geo, regions),
        geo,
        regions,
        e,
        params,
    )
}

/// [`diffusion`] with the walk and contact sums built once.
pub fn diffusion_with(
    dg: &DiffusionGeometry,
    geo: &TexGeometry,
    regions: &Regions,
    e: &[[f32; 4]],
    params: &SamplerParams,
) -> Vec<[f32; 4]> {
    let nf = geo.size as f32;
    // Per region: R_tot, its sample pattern and the pattern's totals.
    struct RegionSampler {
        scale: [f32; 3],
        pattern: Vec<[f32; 4]>,
        total: [f32; 3],
    }
    let per_region: Vec<RegionSampler> = regions
        .profiles()
        .iter()
        .map(|p| {
            let pattern = sample_pattern(p, params.samples);
            RegionSampler {
                scale: p.r_tot.map(|k| k as f32),
                total: pattern_totals(&pattern),
                pattern,
            }
        })
        .collect();
    let contact = dg.contact.apply(e);
    let walk = &dg.walk;
    (0..geo.texels())
        .into_par_iter()
        .map(|i| {
            let tt = geo.texel_tri[i];
            if geo.pos[i][3] == 0.0 || tt[0] == NO_TRIANGLE {
                return [0.0; 4];
            }
            let RegionSampler {
                scale,
                pattern,
                total,
            } = &per_region[regions.of_triangle(tt[0] as usize)];
            let texel = walk.texel(
                tt[0],
                f32::from_bits(tt[1]),
                f32::from_bits(tt[2]),
                rotation(i as u32),
            );
            // Samples off the surface (past an open border) count with no light; lost ones
            // (a non-manifold edge, outside the texture, no surface there) leave the sum and
            // the rest renormalise.
            let mut sum = [0f32; 3];
            let mut lost_w = [0f32; 3];
            let mut lost = 0u32;
            for q in pattern {
                let w = pattern_weights(q);
                let ej = match texel.land(q[0], q[1]) {
                    Landing::Atlas(uv) => nearest(geo, nf, uv.x, uv.y).map(|j| e[j]),
                    Landing::Off => Some([0.0; 4]),
                    Landing::Lost => None,
                };
                match ej {
                    Some(ej) => {
                        for c in 0..3 {
                            sum[c] += w[c] * ej[c];
                        }
                    }
                    None => {
                        for c in 0..3 {
                            lost_w[c] += w[c];
                        }
                        lost += 1;
                    }
                }
            }
            let mut out = [0f32; 4];
            for c in 0..3 {
                let wsum = total[c] - lost_w[c];
                let own = if wsum > 0.0 { sum[c] / wsum } else { e[i][c] };
                out[c] = scale[c] * own + contact[i][c];
            }
            out[3] = (params.samples - lost) as f32 / params.samples as f32;
            out
        })
        .collect()
}

/// The texel nearest to texel coordinates (tx, ty) (texel centres at integers); None when it
/// is outside the texture or empty.
fn nearest(geo: &TexGeometry, nf: f32, tx: f32, ty: f32) -> Option<usize> {
    let (fx, fy) = ((tx + 0.5).floor(), (ty + 0.5).floor());
    if !(tx.is_finite() && ty.is_finite()) || fx < 0.0 || fy < 0.0 || fx >= nf || fy >= nf {
        return None;
    }
    let t = fy as usize * nf as usize + fx as usize;
    if geo.pos[t][3] == 0.0 {
        return None;
    }
    Some(t)
}
