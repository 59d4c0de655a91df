//! The G-buffer the BTF pass shades (position, normal, tangent, uv per pixel), generated on
//! the CPU by ray-casting analytic objects (a sphere, a cylinder, a tilted plane) or
//! rasterising a mesh with UVs (`render_mesh`) from a
//! pinhole camera, or a flat tile seen by an orthographic camera (`btf eval`); and the
//! per-frame camera and lights.
//!
//! Every object's (tangent, bitangent = normal x tangent, normal) frame is right-handed with
//! texture u increasing along the tangent and v along the bitangent, as in the BTF's own
//! frame (x = u, y = v, z = normal).

use crate::error::{Error, Result};
use glam::{DVec3, Vec3};

/// Lights one frame can have (push constants of `btf shade`).
pub const MAX_LIGHTS: usize = 2;

/// Pixels of a G-buffer: three vec4 each, (position, tag), (normal, u), (tangent, v). The
/// tag is 0 where nothing is covered, else s * (1 + part): s = +-1 the handedness of the
/// tangent frame (bitangent = s * normal x tangent; -1 where the UVs are mirrored) and
/// `part` the part (material) id. The analytic objects write 1: part 0, right-handed.
#[derive(Clone, Debug)]
pub struct GBuffer {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<[f32; 4]>,
}

/// One G-buffer pixel, unpacked.
#[derive(Clone, Copy, Debug)]
pub struct Pixel {
    pub position: DVec3,
    pub normal: DVec3,
    pub tangent: DVec3,
    pub uv: [f64; 2],
    /// +1, or -1 where the frame is left-handed (bitangent = handedness * normal x tangent).
    pub handedness: f64,
    /// The part (material) id.
    pub part: u32,
}

impl GBuffer {
    /// Checks sizes and values (the shader must never read out of bounds or produce NaN).
    pub fn check(&self) -> Result<()> {
        let n = self.width as usize * self.height as usize;
        if n == 0 || self.width > 16384 || self.height > 16384 || self.texels.len() != 3 * n {
            return Err(Error::InvalidArgument(format!(
                "G-buffer of {} vec4 for {} x {} pixels",
                self.texels.len(),
                self.width,
                self.height
            )));
        }
        if self.texels.iter().flatten().any(|x| !x.is_finite()) {
            return Err(Error::InvalidArgument(
                "G-buffer holds non-finite values".into(),
            ));
        }
        Ok(())
    }

    /// The pixel at index `k`, if the G-buffer covers it.
    pub fn pixel(&self, k: usize) -> Option<Pixel> {
        let g = &self.texels[3 * k..3 * k + 3];
        let tag = g[0][3];
        if tag.abs() < 0.5 {
            return None;
        }
        let v = |a: [f32; 4]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        Some(Pixel {
            position: v(g[0]),
            normal: v(g[1]),
            tangent: v(g[2]),
            uv: [g[1][3] as f64, g[2][3] as f64],
            handedness: if tag < 0.0 { -1.0 } else { 1.0 },
            part: (tag.abs() - 1.0).round() as u32,
        })
    }

    /// Pixels the object covers.
    pub fn covered(&self) -> usize {
        self.texels
            .chunks_exact(3)
            .filter(|g| g[0][3].abs() >= 0.5)
            .count()
    }

    /// A flat `size` x `size` tile seen from above: pixel (c, r) at uv of texel centre
    /// ((c + 0.5) / size, (r + 0.5) / size) of one BTF tile, normal z, tangent x.
    pub fn tile(size: [u32; 2]) -> GBuffer {
        let mut texels = Vec::with_capacity(3 * (size[0] * size[1]) as usize);
        for r in 0..size[1] {
            for c in 0..size[0] {
                let (u, v) = (
                    (c as f32 + 0.5) / size[0] as f32,
                    (r as f32 + 0.5) / size[1] as f32,
                );
                texels.push([u, v, 0.0, 1.0]);
                texels.push([0.0, 0.0, 1.0, u]);
                texels.push([1.0, 0.0, 0.0, v]);
            }
        }
        GBuffer {
            width: size[0],
            height: size[1],
            texels,
        }
    }
}

/// The test objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Object {
    /// Unit sphere, 8 x 4 tiles over (phi, theta).
    Sphere,
    /// Vertical cylinder of radius 0.8 and height 2.2 (the cloth draped round it), 6 tiles
    /// around.
    Cylinder,
    /// A 3 x 3 square tilted 60 deg back from the camera, 5 x 5 tiles: the grazing band.
    Plane,
}

/// The pinhole camera of the object renders: at `EYE`, looking at the origin, y up.
pub const EYE: [f32; 3] = [0.0, 0.6, 3.4];
const FOV_Y_DEG: f64 = 40.0;

/// Ray-casts `object` at `width` x `height` from the camera at [`EYE`].
pub fn render_object(object: Object, width: u32, height: u32) -> Result<GBuffer> {
    if !(1..=8192).contains(&width) || !(1..=8192).contains(&height) {
        return Err(Error::InvalidArgument(format!(
            "image size {width} x {height} outside 1..=8192"
        )));
    }
    let eye = DVec3::new(EYE[0] as f64, EYE[1] as f64, EYE[2] as f64);
    let fwd = (-eye).normalize();
    let right = fwd.cross(DVec3::Y).normalize();
    let up = right.cross(fwd);
    let tan = (FOV_Y_DEG.to_radians() / 2.0).tan();
    let aspect = width as f64 / height as f64;
    use rayon::prelude::*;
    let texels: Vec<[f32; 4]> = (0..width * height)
        .into_par_iter()
        .flat_map_iter(|k| {
            let (x, y) = (k % width, k / width);
            let sx = ((x as f64 + 0.5) / width as f64 * 2.0 - 1.0) * tan * aspect;
            let sy = (1.0 - (y as f64 + 0.5) / height as f64 * 2.0) * tan;
            let dir = (fwd + right * sx + up * sy).normalize();
            let hit = intersect(object, eye, dir);
            let g = match hit {
                Some((p, n, t, uv)) => [
                    [p.x as f32, p.y as f32, p.z as f32, 1.0],
                    [n.x as f32, n.y as f32, n.z as f32, uv[0] as f32],
                    [t.x as f32, t.y as f32, t.z as f32, uv[1] as f32],
                ],
                None => [[0.0; 4]; 3],
            };
            g.into_iter()
        })
        .collect();
    Ok(GBuffer {
        width,
        height,
        texels,
    })
}

type Hit = (DVec3, DVec3, DVec3, [f64; 2]);

fn intersect(object: Object, o: DVec3, d: DVec3) -> Option<Hit> {
    use std::f64::consts::{PI, TAU};
    match object {
        Object::Sphere => {
            let b = o.dot(d);
            let c = o.length_squared() - 1.0;
            let disc = b * b - c;
            if disc < 0.0 {
                return None;
            }
            let t = -b - disc.sqrt();
            if t <= 0.0 {
                return None;
            }
            let p = o + d * t;
            let n = p.normalize();
            let theta = n.y.clamp(-1.0, 1.0).acos();
            let phi = n.z.atan2(n.x).rem_euclid(TAU);
            let tangent = DVec3::new(-phi.sin(), 0.0, phi.cos());
            Some((p, n, tangent, [phi / TAU * 8.0, theta / PI * 4.0]))
        }
        Object::Cylinder => {
            let r = 0.8;
            let (a, b, c) = (
                d.x * d.x + d.z * d.z,
                o.x * d.x + o.z * d.z,
                o.x * o.x + o.z * o.z - r * r,
            );
            let disc = b * b - a * c;
            if a < 1e-12 || disc < 0.0 {
                return None;
            }
            let t = (-b - disc.sqrt()) / a;
            let p = o + d * t;
            if t <= 0.0 || p.y.abs() > 1.1 {
                return None;
            }
            let n = DVec3::new(p.x, 0.0, p.z) / r;
            let phi = p.z.atan2(p.x).rem_euclid(TAU);
            let tangent = DVec3::new(-phi.sin(), 0.0, phi.cos());
            // bitangent = n x t = -y.
            let tile = TAU * r / 6.0;
            Some((p, n, tangent, [phi / TAU * 6.0, -p.y / tile]))
        }
        Object::Plane => {
            let a = 60f64.to_radians();
            let n = DVec3::new(0.0, a.cos(), a.sin());
            let denom = d.dot(n);
            if denom.abs() < 1e-12 {
                return None;
            }
            let t = -o.dot(n) / denom;
            if t <= 0.0 || denom > 0.0 {
                return None;
            }
            let p = o + d * t;
            let tangent = DVec3::X;
            let bitangent = n.cross(tangent);
            let (u, v) = (p.dot(tangent), p.dot(bitangent));
            if u.abs() > 1.5 || v.abs() > 1.5 {
                return None;
            }
            Some((
                p,
                n,
                tangent,
                [(u + 1.5) / 3.0 * 5.0, (v + 1.5) / 3.0 * 5.0],
            ))
        }
    }
}

/// Where the view direction comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Camera {
    /// A pinhole at this position (view = normalize(eye - position)).
    Perspective(Vec3),
    /// Every pixel seen from this direction (unit, towards the camera).
    Orthographic(Vec3),
}

impl Camera {
    /// The push-constant vec4 (w = 1 perspective, 0 orthographic).
    pub fn push(&self) -> [f32; 4] {
        match self {
            Camera::Perspective(p) => [p.x, p.y, p.z, 1.0],
            Camera::Orthographic(d) => {
                let d = d.normalize();
                [d.x, d.y, d.z, 0.0]
            }
        }
    }

    /// The unit direction towards the camera from `position`, in f64.
    pub fn view(&self, position: DVec3) -> DVec3 {
        match self {
            Camera::Perspective(p) => (p.as_dvec3() - position).normalize(),
            Camera::Orthographic(d) => d.as_dvec3().normalize(),
        }
    }
}

/// A directional light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Towards the light (world space; normalised when used).
    pub direction: Vec3,
    /// Strength per channel (1: the BTF's own unit irradiance).
    pub rgb: [f32; 3],
}

/// One frame's input: camera and up to [`MAX_LIGHTS`] lights.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub camera: Camera,
    pub lights: Vec<Light>,
}

impl Frame {
    pub fn check(&self) -> Result<()> {
        if self.lights.is_empty() || self.lights.len() > MAX_LIGHTS {
            return Err(Error::InvalidArgument(format!(
                "{} lights: the BTF pass takes 1..={MAX_LIGHTS}",
                self.lights.len()
            )));
        }
        for l in &self.lights {
            if !l.direction.is_finite()
                || l.direction.length() < 1e-6
                || l.rgb.iter().any(|c| !c.is_finite() || *c < 0.0)
            {
                return Err(Error::InvalidArgument(format!("bad light {l:?}")));
            }
        }
        let c = match self.camera {
            Camera::Perspective(p) => p.is_finite(),
            Camera::Orthographic(d) => d.is_finite() && d.length() > 1e-6,
        };
        if !c {
            return Err(Error::InvalidArgument(format!(
                "bad camera {:?}",
                self.camera
            )));
        }
        Ok(())
    }
}

/// The tangent frame of a pixel as the shader builds it: unit normal, tangent
/// Gram-Schmidt-orthogonalised against it, bitangent = handedness * normal x tangent.
pub fn frame_of(p: &Pixel) -> (DVec3, DVec3, DVec3) {
    let n = p.normal.normalize();
    let t = (p.tangent - n * n.dot(p.tangent)).normalize();
    (t, n.cross(t) * p.handedness, n)
}

/// `w` (world) in the tangent frame (t, b, n).
pub fn to_tangent(w: DVec3, (t, b, n): (DVec3, DVec3, DVec3)) -> [f64; 3] {
    [w.dot(t), w.dot(b), w.dot(n)]
}

/// The default lights of `btf render` and `bench btf`: a warm key light and a dim cool
/// grazing fill.
pub fn default_lights() -> Vec<Light> {
    vec![
        Light {
            direction: Vec3::new(0.5, 0.8, 0.6),
            rgb: [1.0, 0.95, 0.9],
        },
        Light {
            direction: Vec3::new(-0.9, 0.1, 0.2),
            rgb: [0.3, 0.35, 0.5],
        },
    ]
}

/// Texture repeats per unit of a mesh's own uv in [`render_mesh`].
pub const MESH_UV_SCALE: f64 = 8.0;

/// The G-buffer of a mesh with UVs seen from the camera at [`EYE`]: the mesh is centred and
/// scaled to a radius of 1.2; per pixel the nearest triangle (CPU z-buffer of triangle ids),
/// then the pixel's ray intersected with it for exact barycentrics; normals interpolated,
/// tangents per vertex from the UV gradients (Gram-Schmidt against the normal), uv scaled by
/// [`MESH_UV_SCALE`].
pub fn render_mesh(mesh: &crate::scene::Mesh, width: u32, height: u32) -> Result<GBuffer> {
    if !(1..=8192).contains(&width) || !(1..=8192).contains(&height) {
        return Err(Error::InvalidArgument(format!(
            "image size {width} x {height} outside 1..=8192"
        )));
    }
    let Some(uvs) = &mesh.uvs else {
        return Err(Error::input(
            &mesh.name,
            "has no texture coordinates: a BTF needs uv and a tangent frame",
        ));
    };
    let (lo, hi) = mesh.bounds();
    let centre = ((lo + hi) * 0.5).as_dvec3();
    let radius = mesh
        .positions
        .iter()
        .map(|p| (p.as_dvec3() - centre).length())
        .fold(0.0, f64::max)
        .max(1e-12);
    let scale = 1.2 / radius;
    let pos: Vec<DVec3> = mesh
        .positions
        .iter()
        .map(|p| (p.as_dvec3() - centre) * scale)
        .collect();
    let nrm: Vec<DVec3> = mesh.normals.iter().map(|n| n.as_dvec3()).collect();
    let uv: Vec<[f64; 2]> = uvs.iter().map(|t| [t.x as f64, t.y as f64]).collect();
    // Per-vertex tangents: accumulated dP/du of the triangles around each vertex.
    let mut tan = vec![DVec3::ZERO; pos.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let (e1, e2) = (pos[b] - pos[a], pos[c] - pos[a]);
        let (du1, dv1) = (uv[b][0] - uv[a][0], uv[b][1] - uv[a][1]);
        let (du2, dv2) = (uv[c][0] - uv[a][0], uv[c][1] - uv[a][1]);
        let det = du1 * dv2 - du2 * dv1;
        if det.abs() < 1e-20 {
            continue;
        }
        let dpdu = (e1 * dv2 - e2 * dv1) / det;
        for v in [a, b, c] {
            tan[v] += dpdu;
        }
    }
    // Camera (as render_object).
    let eye = DVec3::new(EYE[0] as f64, EYE[1] as f64, EYE[2] as f64);
    let fwd = (-eye).normalize();
    let right = fwd.cross(DVec3::Y).normalize();
    let up = right.cross(fwd);
    let tan_fov = (FOV_Y_DEG.to_radians() / 2.0).tan();
    let aspect = width as f64 / height as f64;
    let (w, h) = (width as usize, height as usize);
    // Z-buffer of triangle ids (screen-space depth, for visibility only).
    let mut depth = vec![f64::INFINITY; w * h];
    let mut id = vec![u32::MAX; w * h];
    let project = |p: DVec3| {
        let q = p - eye;
        let z = q.dot(fwd);
        let x = q.dot(right) / (z * tan_fov * aspect);
        let y = q.dot(up) / (z * tan_fov);
        [
            (x + 1.0) * 0.5 * width as f64,
            (1.0 - y) * 0.5 * height as f64,
            z,
        ]
    };
    for (ti, t) in mesh.triangles.iter().enumerate() {
        let s = t.map(|i| project(pos[i as usize]));
        if s.iter().any(|p| p[2] <= 1e-6) {
            continue;
        }
        let x0 = s
            .iter()
            .map(|p| p[0])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let x1 = s
            .iter()
            .map(|p| p[0])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(width as f64) as usize;
        let y0 = s
            .iter()
            .map(|p| p[1])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let y1 = s
            .iter()
            .map(|p| p[1])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(height as f64) as usize;
        let edge = |a: [f64; 3], b: [f64; 3], x: f64, y: f64| {
            (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
        };
        let area = edge(s[0], s[1], s[2][0], s[2][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        for y in y0..y1 {
            for x in x0..x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let b0 = edge(s[1], s[2], px, py) / area;
                let b1 = edge(s[2], s[0], px, py) / area;
                let b2 = 1.0 - b0 - b1;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                let z = b0 * s[0][2] + b1 * s[1][2] + b2 * s[2][2];
                let k = y * w + x;
                if z < depth[k] {
                    depth[k] = z;
                    id[k] = ti as u32;
                }
            }
        }
    }
    let mut texels = Vec::with_capacity(3 * w * h);
    for k in 0..w * h {
        let (x, y) = (k % w, k / w);
        let g = (|| {
            let ti = *id.get(k).filter(|&&i| i != u32::MAX)?;
            let [a, b, c] = mesh.triangles[ti as usize].map(|i| i as usize);
            let sx = ((x as f64 + 0.5) / width as f64 * 2.0 - 1.0) * tan_fov * aspect;
            let sy = (1.0 - (y as f64 + 0.5) / height as f64 * 2.0) * tan_fov;
            let d = (fwd + right * sx + up * sy).normalize();
            // Barycentrics of the ray's hit on the triangle's plane (Moller-Trumbore).
            let (e1, e2) = (pos[b] - pos[a], pos[c] - pos[a]);
            let pv = d.cross(e2);
            let det = e1.dot(pv);
            if det.abs() < 1e-18 {
                return None;
            }
            let tv = eye - pos[a];
            let u = (tv.dot(pv) / det).clamp(0.0, 1.0);
            let qv = tv.cross(e1);
            let v = (d.dot(qv) / det).clamp(0.0, 1.0 - u);
            let t = e2.dot(qv) / det;
            let w0 = 1.0 - u - v;
            let p = eye + d * t;
            let mut n = (nrm[a] * w0 + nrm[b] * u + nrm[c] * v).normalize_or_zero();
            if n == DVec3::ZERO {
                n = e1.cross(e2).normalize();
            }
            if n.dot(d) > 0.0 {
                n = -n; // seen from behind: shade the side facing the camera
            }
            let tg = tan[a] * w0 + tan[b] * u + tan[c] * v;
            let mut tg = tg - n * n.dot(tg);
            if tg.length_squared() < 1e-24 {
                tg = n.any_orthonormal_vector();
            }
            let tx = [
                uv[a][0] * w0 + uv[b][0] * u + uv[c][0] * v,
                uv[a][1] * w0 + uv[b][1] * u + uv[c][1] * v,
            ]
            .map(|x| x * MESH_UV_SCALE);
            Some([
                [p.x as f32, p.y as f32, p.z as f32, 1.0],
                [n.x as f32, n.y as f32, n.z as f32, tx[0] as f32],
                [tg.x as f32, tg.y as f32, tg.z as f32, tx[1] as f32],
            ])
        })();
        texels.extend(g.unwrap_or([[0.0; 4]; 3]));
    }
    Ok(GBuffer {
        width,
        height,
        texels,
    })
}
