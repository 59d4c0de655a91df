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
