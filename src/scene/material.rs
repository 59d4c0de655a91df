//! A part's surface colour as a glTF material gives it: the base-colour factor and, where
//! present, the base-colour texture (sRGB-encoded RGBA8 with its wrap modes), read by
//! `gltf_load::load_materials`. How a renderer applies it is its own choice (the character
//! frame's is in `kernels::compose`); sampling is defined here once so that a GPU pass and its
//! CPU twin agree: texel centres at ((i + 0.5) / w, (j + 0.5) / h), v down the rows as in
//! glTF, the four texels decoded from sRGB to linear and then blended bilinearly (as a
//! Vulkan `_SRGB` format filters).

use crate::error::{Error, Result};
use std::path::Path;

/// Largest texture side accepted (a 8192^2 RGBA8 texture is 256 MiB on the host already).
pub const MAX_TEXTURE_SIDE: u32 = 8192;

/// A glTF sampler's wrap mode along one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Wrap {
    Repeat,
    Clamp,
    Mirror,
}

impl Wrap {
    /// The code the compose shader reads (0 repeat, 1 clamp, 2 mirrored repeat).
    pub fn code(self) -> u32 {
        match self {
            Wrap::Repeat => 0,
            Wrap::Clamp => 1,
            Wrap::Mirror => 2,
        }
    }

    /// Integer texel index `i` folded into 0..n.
    pub fn apply(self, i: i32, n: i32) -> i32 {
        match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::Clamp => i.clamp(0, n - 1),
            Wrap::Mirror => {
                let k = i.rem_euclid(2 * n);
                if k < n { k } else { 2 * n - 1 - k }
            }
        }
    }
}

/// A base-colour texture, decoded.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Where it came from (image name or URI), for messages.
    pub source: String,
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 at v = 0; r | g << 8 | b << 16 | a << 24, sRGB-encoded.
    pub texels: Vec<u32>,
    /// Wrap along u and v.
    pub wrap: [Wrap; 2],
}

/// sRGB-encoded 8-bit value to linear (the exact piecewise curve, f32).
pub fn srgb_to_linear(c: u32) -> f32 {
    let x = c as f32 / 255.0;
    if x <= 0.04045 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// Checks the size against [`MAX_TEXTURE_SIDE`] and the texel count.
    pub fn check(&self, file: &Path) -> Result<()> {
        let ok_side = |s: u32| (1..=MAX_TEXTURE_SIDE).contains(&s);
        if !ok_side(self.width) || !ok_side(self.height) {
            return Err(Error::input(
                file,
                format!(
                    "base-colour texture '{}' is {} x {} texels (1..={MAX_TEXTURE_SIDE} each)",
                    self.source, self.width, self.height
                ),
            ));
        }
        if self.texels.len() != self.width as usize * self.height as usize {
            return Err(Error::input(
                file,
                format!(
                    "base-colour texture '{}' holds {} texels for {} x {}",
                    self.source,
                    self.texels.len(),
                    self.width,
                    self.height
                ),
            ));
        }
        Ok(())
    }

    /// Linear rgb at `uv` (clamped to [-512, 512], where every wrap mode has long repeated):
    /// bilinear over the four nearest texels, each decoded from sRGB first, the texture's
    /// wrap modes at its borders (f32, in the compose shader's order).
    pub fn sample(&self, uv: [f32; 2]) -> [f32; 3] {
        let (w, h) = (self.width as i32, self.height as i32);
        let uv = uv.map(|x| x.clamp(-512.0, 512.0));
        let tx = uv[0] * w as f32 - 0.5;
        let ty = uv[1] * h as f32 - 0.5;
        let (fx0, fy0) = (tx.floor(), ty.floor());
        let (fx, fy) = (tx - fx0, ty - fy0);
        let (ix, iy) = (fx0 as i32, fy0 as i32);
        let mut sum = [0f32; 3];
        for k in 0..4 {
            let (ox, oy) = (k & 1, k >> 1);
            let wgt = (if ox == 1 { fx } else { 1.0 - fx }) * (if oy == 1 { fy } else { 1.0 - fy });
            let x = self.wrap[0].apply(ix + ox, w);
            let y = self.wrap[1].apply(iy + oy, h);
            let t = self.texels[(y * w + x) as usize];
            for (c, s) in sum.iter_mut().enumerate() {
                *s += wgt * srgb_to_linear((t >> (8 * c)) & 0xFF);
            }
        }
        sum
    }
}

/// One part's material: the glTF base colour.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// The material's name ("(default)" where the part has none).
    pub name: String,
    /// baseColorFactor (linear rgba).
    pub factor: [f32; 4],
    /// baseColorTexture, decoded.
    pub texture: Option<Texture>,
}

impl Default for Material {
    /// The glTF default material: white, untextured.
    fn default() -> Self {
        Material {
            name: "(default)".into(),
            factor: [1.0; 4],
            texture: None,
        }
    }
}

impl Material {
    /// Linear base colour (factor times texture) at `uv`.
    pub fn colour(&self, uv: [f32; 2]) -> [f32; 3] {
        let t = self.texture.as_ref().map_or([1.0; 3], |t| t.sample(uv));
        [0, 1, 2].map(|c| self.factor[c] * t[c])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tex(w: u32, h: u32, f: impl Fn(u32, u32) -> u32, wrap: Wrap) -> Texture {
        Texture {
            source: "t".into(),
            width: w,
            height: h,
            texels: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect(),
            wrap: [wrap; 2],
        }
    }

    #[test]
    fn srgb_decoding_meets_the_curves_ends_and_its_knee() {
        assert_eq!(srgb_to_linear(0), 0.0);
        assert!((srgb_to_linear(255) - 1.0).abs() < 1e-6);
        // 10/255 = 0.0392 is on the linear segment; 11/255 = 0.0431 on the power one: the
        // two pieces meet at 0.04045 to 1e-7 (the standard's constants).
        assert!((srgb_to_linear(10) - 10.0 / 255.0 / 12.92).abs() < 1e-9);
        assert!((srgb_to_linear(128) - 0.2158605).abs() < 1e-6);
    }

    /// Catches a sampler that drops the half-texel offset, blends before decoding, or
    /// swaps u and v: a horizontal ramp read at texel centres and halfway between.
    #[test]
    fn bilinear_sampling_hits_texel_centres_and_blends_decoded_values() {
        let t = tex(
            4,
            2,
            |x, _| if x % 2 == 0 { 0xFF000000 } else { 0xFFFFFFFF },
            Wrap::Clamp,
        );
        // Centre of texel 1 (white) and of texel 2 (black).
        assert!((t.sample([1.5 / 4.0, 0.25])[0] - 1.0).abs() < 1e-6);
        assert!(t.sample([2.5 / 4.0, 0.75])[1].abs() < 1e-6);
        // Halfway: the mean of the decoded values (0.5), not decode(127.5) (0.21).
        assert!((t.sample([2.0 / 4.0, 0.25])[2] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn wrap_modes_fold_indices_as_gltf_defines_them() {
        assert_eq!(
            [-1, 0, 4, 5].map(|i| Wrap::Repeat.apply(i, 4)),
            [3, 0, 0, 1]
        );
        assert_eq!([-1, 0, 4, 5].map(|i| Wrap::Clamp.apply(i, 4)), [0, 0, 3, 3]);
        assert_eq!(
            [-2, -1, 4, 5, 8].map(|i| Wrap::Mirror.apply(i, 4)),
            [1, 0, 3, 2, 0]
        );
        // Repeat across the u = 0 seam blends the last and first texels.
        let t = tex(
            4,
            1,
            |x, _| if x == 3 { 0xFFFFFFFF } else { 0xFF000000 },
            Wrap::Repeat,
        );
        assert!((t.sample([0.0, 0.5])[0] - 0.5).abs() < 1e-6);
    }
}
