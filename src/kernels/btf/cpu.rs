//! The CPU twin of `btf shade`: the same 9-tap interpolation over the same packed texels
//! and maps, in f64 (sRGB decoded exactly, bilinear filtering with exact weights).

use super::dirs::{self, Maps};
use super::synth::srgb_decode;
use crate::geom::bilinear;
use crate::scene::gbuffer::{Frame, GBuffer, frame_of, to_tangent};
use rayon::prelude::*;

/// A map texel border closer than this (in texels) to a pixel's continuous map coordinate
/// makes the pixel ambiguous: f32 on the GPU may pick the neighbouring texel.
pub const AMBIGUOUS_MARGIN: f64 = 1e-3;

/// The packed BTF as the GPU holds it, decoded on the fly: RGBA8 sRGB texels (slice-major;
/// also the decoded BC1 texels), or the blocks of the `block` format (slice-major, each
/// slice's blocks row-major, see [`super::block`]).
pub struct Packed<'a> {
    pub size: [u32; 2],
    data: Data<'a>,
}

enum Data<'a> {
    Texels(&'a [u8], Box<[f64; 256]>),
    Blocks(&'a [[u32; 4]]),
}

impl<'a> Packed<'a> {
    pub fn new(size: [u32; 2], texels: &'a [u8]) -> Self {
        let mut lut = Box::new([0.0; 256]);
        for (b, l) in lut.iter_mut().enumerate() {
            *l = srgb_decode(b as u8);
        }
        Packed {
            size,
            data: Data::Texels(texels, lut),
        }
    }

    /// The `block` format's blocks.
    pub fn blocks(size: [u32; 2], blocks: &'a [[u32; 4]]) -> Self {
        Packed {
            size,
            data: Data::Blocks(blocks),
        }
    }

    /// Whether f32 on the GPU may pick a different bilinear footprint at `uv` than f64
    /// here, where that matters: for blocks, a neighbouring footprint may lie in the next
    /// block, whose encoding of the shared texel differs (sampled textures are continuous
    /// there).
    pub fn footprint_ambiguous(&self, uv: [f64; 2]) -> bool {
        if matches!(self.data, Data::Texels(..)) {
            return false;
        }
        (0..2).any(|i| {
            let x = uv[i].rem_euclid(1.0) * self.size[i] as f64 - 0.5;
            let f = x - x.floor();
            !(AMBIGUOUS_MARGIN..=1.0 - AMBIGUOUS_MARGIN).contains(&f)
        })
    }

    /// Bilinear filtering of slice `s` at `uv` with REPEAT wrapping (texel centres at
    /// (i + 0.5) / size), as a sampler with linear filtering does (for blocks: as the
    /// shader does, inside the footprint's block).
    pub fn bilinear(&self, s: usize, uv: [f64; 2]) -> [f64; 3] {
        let [w, h] = self.size;
        match &self.data {
            Data::Texels(texels, lut) => bilinear(self.size, uv, |c, r| {
                let k = 4 * (s * (w * h) as usize + (r * w + c) as usize);
                [0, 1, 2].map(|i| lut[texels[k + i] as usize])
            }),
            Data::Blocks(blocks) => {
                let n = (super::block::blocks(w) * super::block::blocks(h)) as usize;
                super::block::bilinear(self.size, &blocks[s * n..(s + 1) * n], uv)
            }
        }
    }
}

/// One frame shaded on the CPU: linear RGBA per pixel (alpha 0 outside the object) and
/// whether the pixel is ambiguous (see [`AMBIGUOUS_MARGIN`]).
pub fn shade(
    packed: &Packed,
    maps: &Maps,
    gbuffer: &GBuffer,
    frame: &Frame,
) -> (Vec<[f64; 4]>, Vec<bool>) {
    let n = gbuffer.width as usize * gbuffer.height as usize;
    (0..n)
        .into_par_iter()
        .map(|k| {
            let Some(px) = gbuffer.pixel(k) else {
                return ([0.0; 4], false);
            };
            let tbn = frame_of(&px);
            let vt = to_tangent(frame.camera.view(px.position), tbn);
            let mut sum = [0.0; 3];
            let mut ambiguous = packed.footprint_ambiguous(px.uv);
            if vt[2] > 0.0 {
                let (_, mv) = maps.texel_of(vt);
                ambiguous |= mv < AMBIGUOUS_MARGIN || vt[2] < 1e-6;
                let tv = maps.lookup(vt);
                for light in &frame.lights {
                    let lt = to_tangent(light.direction.as_dvec3().normalize(), tbn);
                    if lt[2].abs() < 1e-6 {
                        ambiguous = true;
                    }
                    if lt[2] <= 0.0 {
                        continue;
                    }
                    let (_, ml) = maps.texel_of(lt);
                    ambiguous |= ml < AMBIGUOUS_MARGIN;
                    let tl = maps.lookup(lt);
                    let mut c = [0.0; 3];
                    for a in 0..3 {
                        for e in 0..3 {
                            let w = tv.weight[a] * tl.weight[e];
                            if w == 0.0 {
                                continue;
                            }
                            let t = packed.bilinear(tv.index[a] * dirs::COUNT + tl.index[e], px.uv);
                            for i in 0..3 {
                                c[i] += w * t[i];
                            }
                        }
                    }
                    for i in 0..3 {
                        sum[i] += light.rgb[i] as f64 * c[i];
                    }
                }
            } else if vt[2] > -1e-6 {
                ambiguous = true;
            }
            ([sum[0], sum[1], sum[2], 1.0], ambiguous)
        })
        .unzip()
}
