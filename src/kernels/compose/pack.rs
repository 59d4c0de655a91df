//! What the compose pass holds: fixed per character ([`Prepared`]) and per frame
//! ([`FrameParams`], uploaded by the pass `compose params`).

use crate::error::{Error, Result};
use crate::kernels::raster::pack::Camera;
use crate::scene::gbuffer::Light;
use crate::scene::material::Texture;
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
    /// `atlas`: atlas size, skin triangles, visibility mode, surface count.
    pub fn bytes(&self, size: [u32; 2], env: Environment, atlas: [u32; 4]) -> Vec<u8> {
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
            atlas[3],
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
    /// Per part id: its surface colour (empty: every part uncoloured).
    pub surfaces: Vec<Surface>,
}

/// How the pass colours one part: `scale` times the texture's linear colour at the pixel's
/// mesh uv (times 1 without a texture). Skin pixels multiply their diffuse exit by it (not
/// the specular layer: the surface reflection of skin is not tinted), cloth pixels the BTF
/// radiance. `uv_scale` is the raster's uv multiplier on the part (the G-buffer holds the
/// mesh's uv times it; the cloth's BTF tile repeats): the texture is read at the G-buffer's
/// uv times `1 / uv_scale`, rounded to f32 as the shader does.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    pub scale: [f32; 3],
    pub uv_scale: f32,
    pub texture: Option<Texture>,
}

impl Surface {
    /// No colouring.
    pub const WHITE: Surface = Surface {
        scale: [1.0; 3],
        uv_scale: 1.0,
        texture: None,
    };

    /// The colour at mesh uv `uv` (f32, as the shader computes it).
    pub fn colour(&self, uv: [f32; 2]) -> [f32; 3] {
        let t = self.texture.as_ref().map_or([1.0; 3], |t| t.sample(uv));
        [0, 1, 2].map(|c| self.scale[c] * t[c])
    }

    /// The colour at a pixel whose G-buffer holds `gbuffer_uv` (the mesh's uv times
    /// `uv_scale`).
    pub fn colour_at_gbuffer_uv(&self, gbuffer_uv: [f32; 2]) -> [f32; 3] {
        let inv = 1.0 / self.uv_scale;
        self.colour([gbuffer_uv[0] * inv, gbuffer_uv[1] * inv])
    }
}

/// The surfaces as the shader reads them: per part two uvec4 (scale rgb, 1 / uv scale as f32
/// bits;
/// texel offset, width, height, wrap u | wrap v << 2; width 0 without a texture) and every
/// texture's texels (RGBA8 sRGB words) one after another.
pub fn pack_surfaces(surfaces: &[Surface]) -> (Vec<[u32; 4]>, Vec<u32>) {
    let mut table = Vec::with_capacity(2 * surfaces.len().max(1));
    let mut texels = Vec::new();
    for s in surfaces {
        table.push([
            s.scale[0].to_bits(),
            s.scale[1].to_bits(),
            s.scale[2].to_bits(),
            (1.0 / s.uv_scale).to_bits(),
        ]);
        match &s.texture {
            Some(t) => {
                table.push([
                    texels.len() as u32,
                    t.width,
                    t.height,
                    t.wrap[0].code() | (t.wrap[1].code() << 2),
                ]);
                texels.extend_from_slice(&t.texels);
            }
            None => table.push([0; 4]),
        }
    }
    if table.is_empty() {
        table.push([1f32.to_bits(), 1f32.to_bits(), 1f32.to_bits(), 0]);
        table.push([0; 4]);
    }
    if texels.is_empty() {
        texels.push(0);
    }
    (table, texels)
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
            surfaces: Vec::new(),
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
            surfaces: Vec::new(),
        }
    }

    /// Colours the parts: `surfaces[p]` for part id p (the G-buffer's), read at the mesh uv
    /// (the G-buffer's over the part's `uv_scale`). Scales must be finite and >= 0, uv
    /// scales finite and > 0, and the textures together below 2^28 texels (one storage
    /// buffer).
    pub fn with_surfaces(mut self, surfaces: Vec<Surface>) -> Result<Prepared> {
        let mut texels = 0u64;
        for (p, s) in surfaces.iter().enumerate() {
            if s.scale.iter().any(|c| !c.is_finite() || *c < 0.0) {
                return Err(Error::InvalidArgument(format!(
                    "compose: part {p}'s colour scale {:?} (finite, >= 0)",
                    s.scale
                )));
            }
            if !(s.uv_scale.is_finite() && s.uv_scale > 0.0) {
                return Err(Error::InvalidArgument(format!(
                    "compose: part {p}'s uv scale {} (finite, > 0)",
                    s.uv_scale
                )));
            }
            if let Some(t) = &s.texture {
                if t.width == 0
                    || t.height == 0
                    || t.texels.len() != t.width as usize * t.height as usize
                {
                    return Err(Error::InvalidArgument(format!(
                        "compose: part {p}'s texture '{}' holds {} texels for {} x {}",
                        t.source,
                        t.texels.len(),
                        t.width,
                        t.height
                    )));
                }
                texels += t.texels.len() as u64;
            }
        }
        if texels >= 1 << 28 {
            return Err(Error::InvalidArgument(format!(
                "compose: the parts' textures hold {texels} texels together (below 2^28)"
            )));
        }
        self.surfaces = surfaces;
        Ok(self)
    }
}
