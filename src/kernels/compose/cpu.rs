//! The compose pass on the CPU (f32, the shader's operations in the shader's order): the
//! twin the GPU output is tested against.

use super::pack::{Environment, FrameParams, Prepared};
use crate::kernels::raster::pack::{Camera, key_triangle};
use crate::kernels::sss::pack::{needed_segment, needed_segment_words};
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::PI;

/// Host copies of what the pass reads.
pub struct HostInputs<'a> {
    /// G-buffer texels, layer-major (3 layers of width x height).
    pub gbuffer: &'a [[f32; 4]],
    /// Per pixel (depth bits << 32 | triangle).
    pub keys: &'a [u64],
    /// Posed positions (xyz, 1).
    pub positions: &'a [[f32; 4]],
    /// The skin's diffusion per atlas texel.
    pub diffuse: &'a [[f32; 4]],
    /// The cloth's radiance per pixel.
    pub cloth: &'a [[f32; 4]],
    /// The rotated lobes (two vec4 each: axis + sharpness, rgb amplitude).
    pub lobes: &'a [[f32; 4]],
    /// Per vertex and lobe visibility (vertex-major); empty: unshadowed.
    pub lobe_visibility: &'a [f32],
}

fn schlick(f0: f32, c: f32) -> f32 {
    let x = 1.0 - c.clamp(0.0, 1.0);
    let x2 = x * x;
    f0 + (1.0 - f0) * x2 * x2 * x
}

/// `<G1, G2>` of two unit-amplitude spherical Gaussians (see the shader).
pub fn sg_inner(p1: Vec3, l1: f32, p2: Vec3, l2: f32) -> f32 {
    let r = (l1 * p1 + l2 * p2).length();
    let e = -2.0 * l1 * l2 * (1.0 - p1.dot(p2)) / (r + l1 + l2);
    2.0 * PI * e.exp() * (1.0 - (-2.0 * r).exp()) / r.max(1e-6)
}

fn atlas_lookup(prep: &Prepared, diffuse: &[[f32; 4]], uv: Vec2) -> Vec3 {
    let n = prep.atlas_size as i32;
    let t = uv * n as f32 - Vec2::splat(0.5);
    let f0 = t.floor();
    let f = t - f0;
    let i0 = (f0.x as i32, f0.y as i32);
    let mut sum = Vec3::ZERO;
    let mut wsum = 0.0f32;
    for k in 0..4 {
        let (ox, oy) = (k & 1, k >> 1);
        let w = (if ox == 1 { f.x } else { 1.0 - f.x }) * (if oy == 1 { f.y } else { 1.0 - f.y });
        let cx = (i0.0 + ox).clamp(0, n - 1);
        let cy = (i0.1 + oy).clamp(0, n - 1);
        let i = (cy * n + cx) as usize;
        if prep.mask[i] > 0.0 {
            sum += w * Vec4::from_array(diffuse[i]).truncate();
            wsum += w;
        }
    }
    if wsum > 0.0 { sum / wsum } else { Vec3::ZERO }
}

fn prep_background(env: Environment) -> [f32; 3] {
    match env {
        Environment::None(c) | Environment::Lobes(_, c) => c,
    }
}

/// Narkowicz's fit of the ACES filmic curve.
pub fn aces(x: Vec3) -> Vec3 {
    ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(Vec3::ZERO, Vec3::ONE)
}

/// Linear to sRGB-encoded, one channel.
pub fn srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// The ray through the centre of pixel `px` of a `size` frame (glsl/compose/skin_uv.glsl
/// `pixel_ray`; `right` and `up` pre-scaled by the half-field tangents).
fn pixel_ray(px: [u32; 2], size: [u32; 2], fwd: Vec3, right: Vec3, up: Vec3) -> Vec3 {
    let s = (Vec2::new(px[0] as f32, px[1] as f32) + 0.5)
        / Vec2::new(size[0] as f32, size[1] as f32)
        * 2.0
        - 1.0;
    (fwd + right * s.x - up * s.y).normalize()
}

/// A skin pixel's barycentrics (w0, u, v) on skin triangle `tri` along the ray eye + t d,
/// and the atlas uv they give (glsl/compose/skin_uv.glsl).
fn skin_uv(prep: &Prepared, positions: &[[f32; 4]], tri: u32, eye: Vec3, d: Vec3) -> (Vec3, Vec2) {
    let t = prep.skin_tris[tri as usize];
    let p = |v: u32| Vec4::from_array(positions[v as usize]).truncate();
    let (a, bb, c) = (p(t[0]), p(t[1]), p(t[2]));
    let (e1, e2) = (bb - a, c - a);
    let pv = d.cross(e2);
    let det = e1.dot(pv);
    let tv = eye - a;
    let inv = if det != 0.0 { 1.0 / det } else { 0.0 };
    let u = (tv.dot(pv) * inv).clamp(0.0, 1.0);
    let qv = tv.cross(e1);
    let v = (d.dot(qv) * inv).clamp(0.0, 1.0 - u);
    let w0 = 1.0 - u - v;
    let uv01 = prep.skin_uvs[2 * tri as usize];
    let uv2 = prep.skin_uvs[2 * tri as usize + 1];
    let uv = Vec2::new(uv01[0], uv01[1]) * w0
        + Vec2::new(uv01[2], uv01[3]) * u
        + Vec2::new(uv2[0], uv2[1]) * v;
    (Vec3::new(w0, u, v), uv)
}

/// Texels: `compose need` takes the bilinear footprint's floor at t -/+ this, so a coordinate
/// this close to a texel boundary marks the texels on both sides (the two passes' uv differ
/// by rounding at most, far less than this).
pub const NEED_MARGIN: f32 = 0.01;

/// Pass `compose need` on the CPU (glsl/compose/need.comp): the bitmap of the atlas's 8x1
/// row segments holding the texels [`shade`] reads the diffusion at (the 2 x 2 bilinear
/// footprint of every skin pixel, widened to 3 where within [`NEED_MARGIN`] of a texel
/// boundary), in the layout of
/// `kernels::sss::pack::needed_segment`. A pixel is skin where its key names a skin triangle
/// (an empty key names none). Reads the keys and the posed positions of `inp`.
pub fn needed_segments(prep: &Prepared, camera: &Camera, inp: &HostInputs<'_>) -> Vec<u32> {
    let n = prep.atlas_size;
    let mut words = vec![0u32; needed_segment_words(n) as usize];
    let [w, h] = prep.size;
    let b = camera.basis(prep.size);
    let (fwd, right, up) = (b.forward, b.right * b.tan_x, b.up * b.tan_y);
    for y in 0..h {
        for x in 0..w {
            let idx = (y * w + x) as usize;
            let tri = key_triangle(inp.keys[idx]);
            if tri >= prep.skin_triangles {
                continue;
            }
            let d = pixel_ray([x, y], prep.size, fwd, right, up);
            let (_, uv) = skin_uv(prep, inp.positions, tri, camera.eye, d);
            let nf = n as f32;
            let t = uv * nf - Vec2::splat(0.5);
            let (lo_b, hi_b) = (Vec2::splat(-2.0), Vec2::splat(nf + 1.0));
            let lo = (t - Vec2::splat(NEED_MARGIN)).floor().clamp(lo_b, hi_b);
            let hi = (t + Vec2::splat(NEED_MARGIN)).floor().clamp(lo_b, hi_b);
            let last = n as i32 - 1;
            let (ax, ay) = ((lo.x as i32).clamp(0, last), (lo.y as i32).clamp(0, last));
            let (bx, by) = (
                (hi.x as i32 + 1).clamp(0, last),
                (hi.y as i32 + 1).clamp(0, last),
            );
            for ty in ay..=by {
                for tx in [ax as u32, bx as u32] {
                    let s = needed_segment(tx, ty as u32, n);
                    words[(s / 32) as usize] |= 1 << (s % 32);
                }
            }
        }
    }
    words
}

/// Pass `compose classify` on the CPU: the tile entries of `tiles` (`tx | ty << 16`, of the
/// rasteriser's 16 x 4 tiles) split into (those without a skin pixel, those with one), each
/// sorted; a pixel is skin where its key names a triangle below `prep.skin_triangles`.
pub fn tile_classes(prep: &Prepared, keys: &[u64], tiles: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let [w, h] = prep.size;
    let [tw, th] = crate::kernels::raster::pack::TILE;
    let (mut plain, mut skin) = (Vec::new(), Vec::new());
    for &e in tiles {
        let (x0, y0) = ((e & 0xffff) * tw, (e >> 16) * th);
        let has_skin = (y0..(y0 + th).min(h)).any(|y| {
            (x0..(x0 + tw).min(w))
                .any(|x| key_triangle(keys[(y * w + x) as usize]) < prep.skin_triangles)
        });
        if has_skin { &mut skin } else { &mut plain }.push(e);
    }
    plain.sort_unstable();
    skin.sort_unstable();
    (plain, skin)
}

/// The pass on the CPU: (linear radiance per pixel, RGBA8 word per pixel).
pub fn shade(
    prep: &Prepared,
    params: &FrameParams,
    env: Environment,
    visibility: bool,
    inp: &HostInputs<'_>,
) -> (Vec<[f32; 4]>, Vec<u32>) {
    let [w, h] = prep.size;
    let pixels = w as usize * h as usize;
    let b = params.camera.basis(prep.size);
    let (fwd, right, up) = (b.forward, b.right * b.tan_x, b.up * b.tan_y);
    let eye = params.camera.eye;
    let lobes_n = match env {
        Environment::Lobes(n, _) => n as usize,
        Environment::None(_) => 0,
    };
    let background = Vec3::from_array(prep_background(env));
    let sp = params.specular;
    let (rho_s, m, f0) = (sp.rho_s, sp.roughness, sp.f0);
    let mut hdr = vec![[0f32; 4]; pixels];
    let mut ldr = vec![0u32; pixels];
    for y in 0..h {
        for x in 0..w {
            let idx = (y * w + x) as usize;
            let d = pixel_ray([x, y], prep.size, fwd, right, up);
            let g0 = inp.gbuffer[idx];
            let radiance = if g0[3] == 0.0 {
                background
            } else {
                let tri = key_triangle(inp.keys[idx]);
                let part = (g0[3].abs() + 0.5) as u32 - 1;
                let gbuffer_uv = [
                    inp.gbuffer[pixels + idx][3],
                    inp.gbuffer[2 * pixels + idx][3],
                ];
                let colour = Vec3::from_array(
                    prep.surfaces
                        .get(part as usize)
                        .map_or([1.0; 3], |s| s.colour_at_gbuffer_uv(gbuffer_uv)),
                );
                if tri < prep.skin_triangles {
                    let t = prep.skin_tris[tri as usize];
                    let (bc, uv) = skin_uv(prep, inp.positions, tri, eye, d);
                    let (w0, u, v) = (bc.x, bc.y, bc.z);
                    let n = Vec4::from_array(inp.gbuffer[pixels + idx]).truncate();
                    let view = -d;
                    let nv = n.dot(view).max(1e-4);
                    let diffused = atlas_lookup(prep, inp.diffuse, uv);
                    let mut radiance = (1.0 - schlick(f0, nv)) / PI * diffused * colour;
                    let mut spec = Vec3::ZERO;
                    for l in &params.lights {
                        let ld = l.direction.normalize();
                        let nl = n.dot(ld);
                        if nl <= 0.0 {
                            continue;
                        }
                        let hv = ld + view;
                        let hh = hv.dot(hv);
                        if hh < 1e-8 {
                            continue;
                        }
                        let hn = hv / hh.sqrt();
                        let nh = n.dot(hn).max(1e-4);
                        let nh2 = nh * nh;
                        let tan2 = (1.0 - nh2) / nh2;
                        let ph = (-tan2 / (m * m)).exp() / (m * m * nh2 * nh2);
                        spec += Vec3::from_array(l.rgb)
                            * (rho_s * ph / PI * schlick(f0, hn.dot(view)) * nl / hh);
                    }
                    if lobes_n > 0 {
                        let r = -view - 2.0 * n.dot(-view) * n;
                        let nr = n.dot(r);
                        let hv = r + view;
                        let hh = hv.dot(hv);
                        if nr > 0.0 && hh > 1e-8 {
                            let lam = (2.0 / (m * m)) / (4.0 * nv.max(0.1));
                            let fr = schlick(f0, (hv / hh.sqrt()).dot(view));
                            let scale = rho_s * fr * nr / hh / (PI * m * m);
                            for j in 0..lobes_n {
                                let ax = Vec4::from_array(inp.lobes[2 * j]);
                                let vis = if visibility {
                                    let lv = |vert: u32| {
                                        inp.lobe_visibility[vert as usize * lobes_n + j]
                                    };
                                    lv(t[0]) * w0 + lv(t[1]) * u + lv(t[2]) * v
                                } else {
                                    1.0
                                };
                                spec += Vec4::from_array(inp.lobes[2 * j + 1]).truncate()
                                    * (scale * vis * sg_inner(r, lam, ax.truncate(), ax.w));
                            }
                        }
                    }
                    radiance += spec;
                    radiance
                } else {
                    Vec4::from_array(inp.cloth[idx]).truncate() * colour
                }
            };
            let radiance = radiance.max(Vec3::ZERO);
            hdr[idx] = radiance
                .extend(if g0[3] == 0.0 { 0.0 } else { 1.0 })
                .to_array();
            let mapped = aces(radiance * params.exposure);
            let q = mapped.to_array().map(|c| (srgb(c) * 255.0).round() as u32);
            ldr[idx] = q[0] | (q[1] << 8) | (q[2] << 16) | (255 << 24);
        }
    }
    (hdr, ldr)
}
