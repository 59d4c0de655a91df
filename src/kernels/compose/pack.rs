//! What the compose pass holds: fixed per character ([`Prepared`]) and per frame
//! ([`FrameParams`], uploaded by the pass `compose params`).

use crate::error::{Error, Result};
use crate::kernels::raster::pack::Camera;
use crate::scene::gbuffer::Light;
use crate::scene::texspace::TexGeometry;
use glam::Vec3;

/// Directional lights a frame can have.
pub const MAX_LIGHTS: usize = 2;

/// The specular layer of skin (Kelemen/Szirmay-Kalos with a Beckmann highlight).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SkinSpecular {
    /// Specular intensity rho_s (d'Eon and Luebke: 0.18).
    pub rho_s: f32,
    /// Beckmann roughness m (0.3).
    pub roughness: f32,
    /// Fresnel reflectance at normal incidence (0.028 for eta 1.4).
    pub f0: f32,
}

impl Default for SkinSpecular {
    fn default() -> Self {
        SkinSpecular {
            rho_s: 0.18,
            roughness: 0.3,
            f0: 0.028,
        }
    }
}

/// The environment of a frame as the pass sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Environment {
    /// No environment: no lobe lights the skin; the background colour.
    None([f32; 3]),
    /// Rotated lobes in the kernel's lobe buffer (two vec4 each): their count, and the
    /// background colour.
    Lobes(u32, [f32; 3]),
}

/// One frame's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameParams {
    /// The camera the G-buffer was rasterised with.
    pub camera: Camera,
    /// Directional lights (at most [`MAX_LIGHTS`]).
    pub lights: Vec<Light>,
    /// Exposure: the radiance multiplier before tone mapping.
    pub exposure: f32,
    /// The skin's specular layer.
    pub specular: SkinSpecular,
}

impl FrameParams {
    /// Checks the values the shader would turn into NaN or out-of-range reads.
    pub fn check(&self) -> Result<()> {
        self.camera.check()?;
        if self.lights.len() > MAX_LIGHTS {
            return Err(Error::InvalidArgument(format!(
                "{} lights; the compose pass takes at most {MAX_LIGHTS}",
                self.lights.len()
            )));
        }
        for l in &self.lights {
            let ok = l.direction.is_finite()
                && l.direction.length() > 1e-6
                && l.rgb.iter().all(|c| c.is_finite() && *c >= 0.0);
            if !ok {
                return Err(Error::InvalidArgument(format!(
                    "light {:?} needs a finite non-zero direction and finite rgb >= 0",
                    l
                )));
            }
        }
        let s = &self.specular;
        let ok = self.exposure.is_finite()
            && self.exposure > 0.0
            && s.rho_s.is_finite()
            && s.rho_s >= 0.0
            && s.roughness.is_finite()
            && (0.01..=1.0).contains(&s.roughness)
            && (0.0..1.0).contains(&s.f0);
        if !ok {
            return Err(Error::InvalidArgument(format!(
                "exposure {} must be > 0; specular {:?} needs rho_s >= 0, roughness in \
                 [0.01, 1], f0 in [0, 1)",
                self.exposure, s
            )));
        }
        Ok(())
    }

    /// The pass's parameter block (std430 `Params` of glsl/compose/shade.comp).
    pub fn bytes(&self, size: [u32; 2], env: Environment, atlas: [u32; 3]) -> Vec<u8> {
        let b = self.camera.basis(size);
        let v4 = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
        let mut f: Vec<[f32; 4]> = vec![
            v4(self.camera.eye, self.exposure),
            v4(b.forward, 0.0),
            v4(b.right * b.tan_x, 0.0),
            v4(b.up * b.tan_y, 0.0),
        ];
        let mut dirs = [[0f32; 4]; MAX_LIGHTS];
        let mut rgb = [[0f32; 4]; MAX_LIGHTS];
        for (i, l) in self.lights.iter().enumerate() {
            dirs[i] = v4(l.direction.normalize(), 0.0);
            rgb[i] = [l.rgb[0], l.rgb[1], l.rgb[2], 0.0];
        }
        f.extend(dirs);
        f.extend(rgb);
        let s = &self.specular;
        f.push([s.rho_s, s.roughness, s.f0, 0.0]);
        let (background, lobes) = match env {
            Environment::None(c) => ([c[0], c[1], c[2], 0.0], 0),
            Environment::Lobes(n, c) => ([c[0], c[1], c[2], 0.0], n),
        };
        f.push(background);
        let mut out: Vec<u8> = bytemuck::cast_slice(&f).to_vec();
        for u in [
            size[0],
            size[1],
            self.lights.len() as u32,
            lobes,
            atlas[0],
            atlas[1],
            atlas[2],
            0,
        ] {
            out.extend_from_slice(&u.to_le_bytes());
        }
        out
    }
}

/// What is fixed per character: the skin triangles (the first `skin_triangles` of the
/// character's mesh) with their atlas corners, and which atlas texels hold diffusion.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Output width and height (the G-buffer's).
    pub size: [u32; 2],
    /// The texture-space atlas's side.
    pub atlas_size: u32,
    /// Per skin triangle: its vertex ids in the character's mesh, 0.
    pub skin_tris: Vec<[u32; 4]>,
    /// Per skin triangle: (uv0, uv1), (uv2, 0, 0) atlas corners.
    pub skin_uvs: Vec<[f32; 4]>,
    /// Per atlas texel: 1 where the diffusion holds a value (covered or gutter), else 0.
    pub mask: Vec<f32>,
    /// Skin triangles: the triangle ids below this are skin.
    pub skin_triangles: u32,
}

impl Prepared {
    /// From the skin's texture-space geometry (its triangles are the first of the
    /// character's mesh, with the same vertex ids) for a `size` image.
    pub fn new(size: [u32; 2], skin: &TexGeometry) -> Result<Prepared> {
        if size[0] == 0 || size[1] == 0 || size[0] > 16384 || size[1] > 16384 {
            return Err(Error::InvalidArgument(format!(
                "image of {} x {} pixels (1..=16384 each)",
                size[0], size[1]
            )));
        }
        if skin.triangles.len() != skin.corner_uvs.len() {
            return Err(Error::InvalidArgument(format!(
                "skin geometry with {} triangles and {} atlas corner triples",
                skin.triangles.len(),
                skin.corner_uvs.len()
            )));
        }
        let skin_tris = skin
            .triangles
            .iter()
            .map(|t| [t[0], t[1], t[2], 0])
            .collect();
        let mut skin_uvs = Vec::with_capacity(2 * skin.corner_uvs.len());
        for c in &skin.corner_uvs {
            if c.iter().any(|uv| !uv.is_finite()) {
                return Err(Error::InvalidArgument(
                    "skin atlas corner uv is not finite".into(),
                ));
            }
            skin_uvs.push([c[0].x, c[0].y, c[1].x, c[1].y]);
            skin_uvs.push([c[2].x, c[2].y, 0.0, 0.0]);
        }
        let mask = skin
            .pos
            .iter()
            .map(|p| if p[3] > 0.0 { 1.0 } else { 0.0 })
            .collect();
        Ok(Prepared {
            size,
            atlas_size: skin.size,
            skin_triangles: skin.triangles.len() as u32,
            skin_tris,
            skin_uvs,
            mask,
        })
    }

    /// A character without skin: no skin triangle, a 1-texel empty atlas.
    pub fn without_skin(size: [u32; 2]) -> Prepared {
        Prepared {
            size,
            atlas_size: 1,
            skin_tris: vec![[0; 4]],
            skin_uvs: vec![[0.0; 4]; 2],
            mask: vec![0.0],
            skin_triangles: 0,
        }
    }
}
