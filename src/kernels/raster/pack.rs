//! The rasteriser's CPU side: the pinhole camera and its push constants, and the static
//! per-mesh data (triangles with part ids, UVs) as the GPU holds them.

use crate::error::{Error, Result};
use crate::scene::Mesh;
use glam::Vec3;

/// Counters of the visibility pass (indices into [`Counters`]).
pub mod counter {
    /// Triangles (or near-clipped pieces) scanned over the image.
    pub const SCANNED: usize = 0;
    /// Triangles crossing the near plane (clipped, one or two pieces scanned).
    pub const NEAR_CLIPPED: usize = 1;
    /// Triangles wholly behind the near plane (culled).
    pub const NEAR_CULLED: usize = 2;
    /// Triangles or pieces reaching past the guard band (culled).
    pub const GUARD_CULLED: usize = 3;
    /// Back-facing triangles (kept).
    pub const BACK_FACING: usize = 4;
    /// Triangles or pieces of zero area after snapping (nothing to scan).
    pub const ZERO_AREA: usize = 5;
    /// Triangles or pieces wholly off the image.
    pub const OFF_SCREEN: usize = 6;
}

/// The visibility pass's counters of one frame (see [`counter`]).
pub type Counters = [u32; 8];

/// Sub-pixel steps per pixel of the snapped screen positions.
pub const SUBPIXEL: f64 = 256.0;
/// Screen coordinates (pixels) beyond which a triangle is culled: 16384 x 256 = 2^22, so
/// edge-function products stay below 2^45.
pub const GUARD_BAND: f64 = 16384.0;

/// A pinhole camera in the mesh's own units: at `eye`, looking at `target`, `up` the
/// vertical of the image, `fov_y_deg` the vertical field of view, `near` the clip distance
/// along the view axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// The pinhole.
    pub eye: Vec3,
    /// The point the view axis passes through.
    pub target: Vec3,
    /// The world direction that appears upward.
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    /// Near plane distance (> 0) along the view axis.
    pub near: f32,
}

/// The camera's orthonormal basis and scales, as both passes and the CPU twin use them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Basis {
    /// Unit view axis.
    pub forward: Vec3,
    /// Unit right (forward x up).
    pub right: Vec3,
    /// Unit up (right x forward).
    pub up: Vec3,
    /// tan(fov_y / 2).
    pub tan_y: f32,
    /// tan(fov_y / 2) * width / height.
    pub tan_x: f32,
}

impl Camera {
    /// Checks the camera: finite, eye distinct from target, up not along the view axis,
    /// field of view in (0, 170) degrees, near > 0.
    pub fn check(&self) -> Result<()> {
        let f = self.target - self.eye;
        let ok = self.eye.is_finite()
            && self.target.is_finite()
            && self.up.is_finite()
            && f.length() > 1e-6
            && f.normalize().cross(self.up).length() > 1e-4
            && self.fov_y_deg > 0.0
            && self.fov_y_deg < 170.0
            && self.near.is_finite()
            && self.near > 0.0;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidArgument(format!(
                "bad raster camera {self:?}"
            )))
        }
    }

    /// The basis for an image of `size` pixels.
    pub fn basis(&self, size: [u32; 2]) -> Basis {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        let tan_y = (self.fov_y_deg.to_radians() * 0.5).tan();
        Basis {
            forward,
            right,
            up,
            tan_y,
            tan_x: tan_y * size[0] as f32 / size[1] as f32,
        }
    }

    /// A camera framing the sphere (`centre`, `radius`) from direction `from` (towards the
    /// camera), 40 degrees vertical field of view, near plane at 1% of the distance.
    pub fn framing(centre: Vec3, radius: f32, from: Vec3) -> Camera {
        let fov = 40f32;
        let dist = radius / (fov.to_radians() * 0.5).sin() * 1.05;
        Camera {
            eye: centre + from.normalize() * dist,
            target: centre,
            up: Vec3::Y,
            fov_y_deg: fov,
            near: dist * 0.01,
        }
    }
}

fn vec4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// Push constants of `raster visibility`.
pub fn visibility_push(camera: &Camera, size: [u32; 2], triangles: u32, row: u32) -> Vec<u8> {
    let b = camera.basis(size);
    let f: [[f32; 4]; 4] = [
        vec4(camera.eye, camera.near),
        vec4(b.forward, 0.0),
        vec4(b.right / b.tan_x, 0.0),
        vec4(b.up / b.tan_y, 0.0),
    ];
    let mut push: Vec<u8> = bytemuck::cast_slice(&f).to_vec();
    for u in [size[0], size[1], triangles, row] {
        push.extend_from_slice(&u.to_le_bytes());
    }
    push
}

/// Pixels of a tile (width, height) of the tile list: the workgroup size of `raster
/// resolve` and `btf shade`, one workgroup per listed tile.
pub const TILE: [u32; 2] = [16, 4];

/// The triangle a visibility key names: its low 32 bits (keys are `(depth bits << 32) |
/// triangle`; the empty key, `u64::MAX`, names `u32::MAX`, above every triangle count).
pub fn key_triangle(key: u64) -> u32 {
    (key & 0xFFFF_FFFF) as u32
}

/// Tiles per row and per column of a `size` image.
pub fn tile_grid(size: [u32; 2]) -> [u32; 2] {
    [size[0].div_ceil(TILE[0]), size[1].div_ceil(TILE[1])]
}

/// Push constants of `raster resolve` over every pixel.
pub fn resolve_push(camera: &Camera, size: [u32; 2], uv_scale: f32) -> Vec<u8> {
    resolve_push_mode(camera, size, uv_scale, false)
}

/// Push constants of `raster resolve`, over every pixel or (`tiles`) over the tile list.
pub fn resolve_push_mode(camera: &Camera, size: [u32; 2], uv_scale: f32, tiles: bool) -> Vec<u8> {
    let b = camera.basis(size);
    let f: [[f32; 4]; 4] = [
        vec4(camera.eye, uv_scale),
        vec4(b.forward, 0.0),
        vec4(b.right * b.tan_x, 0.0),
        vec4(b.up * b.tan_y, 0.0),
    ];
    let mut push: Vec<u8> = bytemuck::cast_slice(&f).to_vec();
    for u in [size[0], size[1], tiles as u32, 0] {
        push.extend_from_slice(&u.to_le_bytes());
    }
    push
}

/// What the rasteriser holds for one mesh, checked (no Vulkan).
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Per triangle: its three vertex indices and its part id.
    pub triangles: Vec<[u32; 4]>,
    /// Per vertex uv.
    pub uvs: Vec<[f32; 2]>,
    /// Vertices the posed buffers hold.
    pub vertex_count: usize,
    /// Image width and height.
    pub size: [u32; 2],
    /// Texture repeats per unit of the mesh's uv (the G-buffer holds uv * scale).
    pub uv_scale: f32,
    /// Invocations per row of the visibility grid (triangle t is at (t % row, t / row)).
    pub row: u32,
}

/// Invocations per grid row by default: 1024 workgroups of 64.
pub const DEFAULT_ROW: u32 = 65536;

impl Prepared {
    /// `mesh`'s triangles with `parts[t]` the part id of triangle `t` (all 0 when `parts`
    /// is empty), its UVs, for a `size` image with the uv scaled by `uv_scale`.
    pub fn new(mesh: &Mesh, parts: &[u32], size: [u32; 2], uv_scale: f32) -> Result<Prepared> {
        let uvs = mesh.uvs.as_ref().ok_or_else(|| {
            Error::input(
                &mesh.name,
                "has no texture coordinates: the G-buffer needs uv and a tangent frame",
            )
        })?;
        if !parts.is_empty() && parts.len() != mesh.triangles.len() {
            return Err(Error::InvalidArgument(format!(
                "{} part ids for {} triangles",
                parts.len(),
                mesh.triangles.len()
            )));
        }
        if mesh.triangles.is_empty() || mesh.triangles.len() > u32::MAX as usize - 1 {
            return Err(Error::input(
                &mesh.name,
                format!("{} triangles to rasterise", mesh.triangles.len()),
            ));
        }
        if !(1..=8192).contains(&size[0]) || !(1..=8192).contains(&size[1]) {
            return Err(Error::InvalidArgument(format!(
                "image size {} x {} outside 1..=8192",
                size[0], size[1]
            )));
        }
        if !uv_scale.is_finite() || uv_scale <= 0.0 {
            return Err(Error::InvalidArgument(format!(
                "uv scale {uv_scale} must be positive"
            )));
        }
        let triangles = (mesh.triangles.iter().enumerate())
            .map(|(t, [a, b, c])| [*a, *b, *c, parts.get(t).copied().unwrap_or(0)])
            .collect();
        Ok(Prepared {
            triangles,
            uvs: uvs.iter().map(|u| [u.x, u.y]).collect(),
            vertex_count: mesh.positions.len(),
            size,
            uv_scale,
            row: DEFAULT_ROW,
        })
    }

    /// The same with a uv multiplier per part: `scales[p]` for the triangles of part p (the
    /// G-buffer then holds each part's mesh uv times its own scale: a cloth part's BTF tile
    /// repeats). The uvs are multiplied here, once, and `uv_scale` becomes 1. A vertex used by
    /// parts of different scales, a part id without a scale, or a scale that is not finite
    /// and > 0 is refused.
    pub fn with_part_uv_scales(mut self, scales: &[f32]) -> Result<Prepared> {
        if let Some((p, s)) =
            (scales.iter().enumerate()).find(|(_, s)| !(s.is_finite() && **s > 0.0))
        {
            return Err(Error::InvalidArgument(format!(
                "part {p}'s uv scale {s} must be finite and > 0"
            )));
        }
        let mut of_vertex: Vec<Option<u32>> = vec![None; self.uvs.len()];
        for t in &self.triangles {
            let part = t[3];
            if part as usize >= scales.len() {
                return Err(Error::InvalidArgument(format!(
                    "part id {part} has no uv scale ({} given)",
                    scales.len()
                )));
            }
            for &v in &t[..3] {
                let slot = of_vertex.get_mut(v as usize).ok_or_else(|| {
                    Error::InvalidArgument(format!("vertex {v} past the {} uvs", self.uvs.len()))
                })?;
                match *slot {
                    Some(q) if q != part && scales[q as usize] != scales[part as usize] => {
                        return Err(Error::InvalidArgument(format!(
                            "vertex {v} is shared by parts {q} and {part}, whose uv scales \
                             differ ({} and {})",
                            scales[q as usize], scales[part as usize]
                        )));
                    }
                    _ => *slot = Some(part),
                }
            }
        }
        for (uv, part) in self.uvs.iter_mut().zip(&of_vertex) {
            let s = part.map_or(self.uv_scale, |p| scales[p as usize]);
            *uv = [uv[0] * s, uv[1] * s];
        }
        self.uv_scale = 1.0;
        Ok(self)
    }

    /// The same with `row` invocations per grid row (tests of multi-row grids).
    pub fn with_row(mut self, row: u32) -> Prepared {
        self.row = row.max(1);
        self
    }

    /// Rows of the visibility grid.
    pub fn rows(&self) -> u32 {
        (self.triangles.len() as u32).div_ceil(self.row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec2, Vec3};

    /// Two parts, a quad each (vertices 0..4 and 4..8): part 1's uvs scaled by its own
    /// factor, part 0's by its own; a vertex shared across parts of different scales, a part
    /// without a scale and a scale of 0 are refused.
    #[test]
    fn part_uv_scales_multiply_each_parts_uvs() {
        let positions: Vec<Vec3> = (0..8).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let uvs: Vec<Vec2> = (0..8).map(|i| Vec2::new(0.1 * i as f32, 0.5)).collect();
        let mut mesh = Mesh {
            name: "two quads".into(),
            normals: vec![Vec3::Z; positions.len()],
            positions,
            uvs: Some(uvs.clone()),
            triangles: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
            skin: None,
            report: Default::default(),
        };
        let parts = [0, 0, 1, 1];
        let prep = Prepared::new(&mesh, &parts, [8, 8], 2.0).unwrap();
        let scaled = prep.clone().with_part_uv_scales(&[3.0, 7.0]).unwrap();
        assert_eq!(scaled.uv_scale, 1.0);
        for (v, uv) in scaled.uvs.iter().enumerate() {
            let s = if v < 4 { 3.0 } else { 7.0 };
            assert_eq!(*uv, [uvs[v].x * s, uvs[v].y * s], "vertex {v}");
        }
        let e = prep.clone().with_part_uv_scales(&[3.0]).unwrap_err();
        assert!(e.to_string().contains("part id 1 has no uv scale"), "{e}");
        let e = prep.clone().with_part_uv_scales(&[3.0, 0.0]).unwrap_err();
        assert!(e.to_string().contains("part 1's uv scale 0"), "{e}");
        // Vertex 3 in a triangle of part 1 too.
        mesh.triangles.push([3, 5, 6]);
        let prep = Prepared::new(&mesh, &[0, 0, 1, 1, 1], [8, 8], 2.0).unwrap();
        let e = prep.clone().with_part_uv_scales(&[3.0, 7.0]).unwrap_err();
        assert!(
            e.to_string()
                .contains("vertex 3 is shared by parts 0 and 1"),
            "{e}"
        );
        // Equal scales may share vertices.
        assert!(prep.with_part_uv_scales(&[5.0, 5.0]).is_ok());
    }
}
