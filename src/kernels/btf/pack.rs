//! The BTF kernel's data as the GPU holds it, packed on the CPU with no device: the texel
//! formats and layouts, the packing of the 6561 images into array textures within a
//! device's limits, the direction map and G-buffer texels, and [`Prepared`], everything
//! `btf shade` reads, checked and laid out. The CPU twin reads the same texels in slice
//! order ([`Sampled`]).

use super::dirs::{self, Maps};
use super::synth::{Btf, srgb_encode};
use crate::error::{Error, Result};
use crate::scene::gbuffer::GBuffer;
use ash::vk;
use rayon::prelude::*;

/// Array textures the shader binds (`btf[4]`).
pub const MAX_ARRAYS: u32 = 4;
/// The texel format of the packed BTF: 8-bit sRGB, decoded to linear by the sampler.
pub const FORMAT: vk::Format = vk::Format::R8G8B8A8_SRGB;
const COUNT: u32 = dirs::COUNT as u32;
const SLICES: u32 = COUNT * COUNT;

/// The texel format the BTF is stored in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Texture {
    /// RGBA8 sRGB, 4 bytes per texel ([`FORMAT`]).
    Rgba8,
    /// BC1 sRGB, 4 x 4 texels in 8 bytes (0.5 bytes per texel, [`BC1_FORMAT`]); the sampler
    /// decodes the palette colour from sRGB before filtering. Needs the device feature
    /// textureCompressionBC; in the 'rows' layout the gutters are 4 texels (one block).
    Bc1,
    /// Overlapping 4 x 4 blocks of linear RGB, 16 bytes each (two 11:11:10 endpoints and
    /// sixteen 4-bit indices; [`super::block`]), in an RGBA32UI array texture ([`BLOCK_FORMAT`])
    /// and decoded and bilinearly filtered by the shader from one texelFetch per tap: no
    /// sampler decode (lavapipe's sRGB and BC1 decode are software), 1.89 bytes per texel for
    /// 32 x 32 tiles. 'rows' layout only.
    Block,
}

/// GPU against the CPU twin for [`Texture::Block`], max absolute difference per channel:
/// both decode the same blocks with the same footprint (pixels whose footprint f32 may
/// place differently are left out as ambiguous), so only f32 rounding remains: per light,
/// ~40 f32 products and sums (9 taps of 4 decoded texels and their weights) of values up
/// to ~1.3, each within 2^-24, for two lights: 2 x 40 x 1.3 x 6e-8 = 6.2e-6. Measured on
/// lavapipe: 2.1e-7.
pub const GPU_CPU_BOUND_BLOCK: f64 = 1e-5;

/// The texel format of [`Texture::Block`]: one 4 x 4 block per texel.
pub const BLOCK_FORMAT: vk::Format = vk::Format::R32G32B32A32_UINT;

/// The BC1 format of [`Texture::Bc1`].
pub const BC1_FORMAT: vk::Format = vk::Format::BC1_RGB_SRGB_BLOCK;

impl Texture {
    pub fn format(self) -> vk::Format {
        match self {
            Texture::Rgba8 => FORMAT,
            Texture::Bc1 => BC1_FORMAT,
            Texture::Block => BLOCK_FORMAT,
        }
    }

    /// The layout used when none is asked for ('rows': one array, the faster on lavapipe).
    pub fn default_layout(self) -> Layout {
        Layout::Rows
    }

    /// Array textures the shader binds: four for the sampled formats (`btf[4]`), one for
    /// blocks.
    pub fn bound_arrays(self) -> u32 {
        match self {
            Texture::Block => 1,
            _ => MAX_ARRAYS,
        }
    }

    /// One black texel (a block for BC1 and blocks): what a bound but unused array holds.
    pub fn black(self) -> &'static [u8] {
        match self {
            Texture::Rgba8 => &[0, 0, 0, 255],
            Texture::Bc1 => &[0; 8],
            Texture::Block => &[0; 16],
        }
    }
}

/// What the CPU twin reads: the data the GPU samples, in the texture's own terms.
pub enum Sampled {
    /// RGBA8 sRGB texels, slice-major (RGBA8; BC1 decoded again).
    Texels(Vec<u8>),
    /// The blocks of [`Texture::Block`], slice-major.
    Blocks(Vec<[u32; 4]>),
}

impl Sampled {
    pub fn of(btf: &Btf, texture: Texture) -> Sampled {
        match texture {
            Texture::Block => Sampled::Blocks(encode_blocks(btf)),
            t => Sampled::Texels(sampled_texels(btf, t)),
        }
    }

    /// The CPU twin's view of it.
    pub fn packed(&self, size: [u32; 2]) -> super::cpu::Packed<'_> {
        match self {
            Sampled::Texels(t) => super::cpu::Packed::new(size, t),
            Sampled::Blocks(b) => super::cpu::Packed::blocks(size, b),
        }
    }
}

/// The blocks of every slice for [`Texture::Block`] (slice-major, row-major blocks).
pub fn encode_blocks(btf: &Btf) -> Vec<[u32; 4]> {
    let [w, h] = btf.size;
    btf.texels
        .par_chunks((w * h) as usize)
        .flat_map_iter(|img| super::block::encode_image(w, h, img))
        .collect()
}

/// The texels the GPU samples, as RGBA8 sRGB slice-major (the CPU twin's input): the packed
/// texels for RGBA8, the BC1 encoding decoded again (as `io::bc1` decodes) for BC1. For
/// [`Texture::Block`] (whose texels depend on the block read, see [`Sampled`]): the RGBA8
/// texels.
pub fn sampled_texels(btf: &Btf, texture: Texture) -> Vec<u8> {
    let packed = pack(btf);
    match texture {
        Texture::Rgba8 | Texture::Block => packed,
        Texture::Bc1 => {
            let [w, h] = btf.size;
            let n = (w * h) as usize * 4;
            packed
                .par_chunks(n)
                .flat_map_iter(|img| {
                    crate::io::bc1::decode_image(w, h, &crate::io::bc1::encode_image(w, h, img))
                })
                .collect()
        }
    }
}

/// The BC1 blocks of every slice (slice-major, row-major blocks within a slice).
pub fn encode_bc1(btf: &Btf) -> Vec<u8> {
    let [w, h] = btf.size;
    pack(btf)
        .par_chunks((w * h) as usize * 4)
        .flat_map_iter(|img| crate::io::bc1::encode_image(w, h, img))
        .collect()
}

/// How the images are arranged in the array textures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// One image per layer, 6561 layers split over up to four array textures of at most
    /// maxImageArrayLayers layers; the sampler's REPEAT wraps the tile. The shader picks
    /// the array per tap (a branch that diverges across pixels).
    Layers,
    /// One array texture of 81 layers (one per view); a layer is a row of the 81 light
    /// images, each with a gutter left and right holding the wrapped columns (1; 4 for BC1), so
    /// bilinear filtering never reaches a neighbouring image (REPEAT wraps rows). Needs
    /// 81 (w + 2 gutter) <= maxImageDimension2D.
    Rows,
}

/// How the 6561 images are laid out on a device: `arrays` 2D array textures of
/// `layers_per_array` layers of `layer_extent` texels (the last array may hold fewer).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Packing {
    pub layout: Layout,
    pub texture: Texture,
    pub tile: [u32; 2],
    /// Wrapped columns left and right of each image in the rows layout: 1 for RGBA8 (all
    /// bilinear filtering needs), 4 for BC1 (one block column, so every image starts on a
    /// block and its gutters are copies of its own edge blocks); 0 in the layers layout.
    pub gutter: u32,
    pub layer_extent: [u32; 2],
    pub layers_per_array: u32,
    pub arrays: u32,
}

impl Packing {
    /// The packing of a `tile`-sized BTF within limits of maxImageDimension2D and
    /// maxImageArrayLayers (queried from the device); `layer_cap` optionally lowers the
    /// layers per array (to exercise multi-array packing on any device).
    pub fn for_limits(
        layout: Layout,
        tile: [u32; 2],
        max_dim_2d: u32,
        max_layers: u32,
        layer_cap: Option<u32>,
    ) -> Result<Packing> {
        Self::for_format(
            layout,
            Texture::Rgba8,
            tile,
            max_dim_2d,
            max_layers,
            layer_cap,
        )
    }

    /// [`Packing::for_limits`] for the texel format `texture`.
    pub fn for_format(
        layout: Layout,
        texture: Texture,
        tile: [u32; 2],
        max_dim_2d: u32,
        max_layers: u32,
        layer_cap: Option<u32>,
    ) -> Result<Packing> {
        let max_layers = max_layers.min(layer_cap.unwrap_or(u32::MAX)).max(1);
        let gutter = match (layout, texture) {
            (Layout::Layers, Texture::Block) => {
                return Err(Error::InvalidArgument(
                    "BTF texture 'block' is packed in the 'rows' layout only; use --layout rows"
                        .into(),
                ));
            }
            (Layout::Layers, _) => 0,
            (Layout::Rows, Texture::Block) => 0,
            (Layout::Rows, Texture::Rgba8) => 1,
            (Layout::Rows, Texture::Bc1) => {
                if !tile[0].is_multiple_of(4) {
                    return Err(Error::InvalidArgument(format!(
                        "BTF texture bc1 in the 'rows' layout needs a tile width that is a \
                         multiple of 4 (BC1 blocks are 4 x 4), not {}; use --layout layers",
                        tile[0]
                    )));
                }
                4
            }
        };
        let layer_extent = match (layout, texture) {
            (Layout::Layers, _) => tile,
            (Layout::Rows, Texture::Block) => [
                COUNT * super::block::blocks(tile[0]),
                super::block::blocks(tile[1]),
            ],
            (Layout::Rows, _) => [COUNT * (tile[0] + 2 * gutter), tile[1]],
        };
        let side = layer_extent[0].max(layer_extent[1]);
        if side > max_dim_2d {
            return Err(Error::Limit {
                what: format!("BTF packing ({layout:?}): layer side"),
                requested: side as u64,
                limit_name: "maxImageDimension2D",
                limit: max_dim_2d as u64,
            });
        }
        let total = match layout {
            Layout::Layers => SLICES,
            Layout::Rows => COUNT,
        };
        if layout == Layout::Rows && max_layers < COUNT {
            // The shader reads the 81 view layers from one array (Vulkan guarantees 256).
            return Err(Error::Limit {
                what: "BTF packing (Rows): the 81 view layers in one array texture".into(),
                requested: COUNT as u64,
                limit_name: "maxImageArrayLayers",
                limit: max_layers as u64,
            });
        }
        let layers = max_layers.min(total);
        let arrays = total.div_ceil(layers);
        if arrays > MAX_ARRAYS {
            return Err(Error::Limit {
                what: format!(
                    "BTF packing ({layout:?}): {total} layers need {arrays} array textures (the shader binds {MAX_ARRAYS}); layers per array"
                ),
                requested: total.div_ceil(MAX_ARRAYS) as u64,
                limit_name: "maxImageArrayLayers",
                limit: layers as u64,
            });
        }
        Ok(Packing {
            layout,
            texture,
            tile,
            gutter,
            layer_extent,
            layers_per_array: layers,
            arrays,
        })
    }

    /// Layers in all.
    pub fn total_layers(&self) -> u32 {
        match self.layout {
            Layout::Layers => SLICES,
            Layout::Rows => COUNT,
        }
    }

    /// Layers of array `a`.
    pub fn layers(&self, a: u32) -> u32 {
        (self.total_layers() - a * self.layers_per_array).min(self.layers_per_array)
    }

    /// Bytes of the packed BTF (gutters included; BC1: whole blocks).
    pub fn bytes(&self) -> u64 {
        let [w, h] = self.layer_extent;
        self.total_layers() as u64
            * match self.texture {
                Texture::Rgba8 => w as u64 * h as u64 * 4,
                Texture::Bc1 => crate::io::bc1::encoded_len(w, h) as u64,
                Texture::Block => w as u64 * h as u64 * 16,
            }
    }

    /// Bytes of one layer as uploaded.
    pub fn layer_bytes(&self) -> usize {
        (self.bytes() / self.total_layers() as u64) as usize
    }

    /// The bytes of all layers in order as uploaded: RGBA8 texels, BC1 blocks of each
    /// layer (row-major blocks) encoded from the arranged RGBA8 texels, or the `block`
    /// format's blocks ([`Packing::arrange_blocks`]).
    pub fn upload_bytes(&self, btf: &Btf) -> Vec<u8> {
        match self.texture {
            Texture::Rgba8 => self.arrange(&pack(btf)),
            Texture::Bc1 => {
                let [w, h] = self.layer_extent;
                self.arrange(&pack(btf))
                    .par_chunks((w * h) as usize * 4)
                    .flat_map_iter(|layer| crate::io::bc1::encode_image(w, h, layer))
                    .collect()
            }
            Texture::Block => {
                bytemuck::cast_slice(&self.arrange_blocks(&encode_blocks(btf))).to_vec()
            }
        }
    }

    /// The blocks of all layers in order ([`Texture::Block`], 'rows'), from the slice-major
    /// [`encode_blocks`]: layer v, block row by holds block row by of images (v, 0..81).
    pub fn arrange_blocks(&self, blocks: &[[u32; 4]]) -> Vec<[u32; 4]> {
        let (bw, bh) = (
            super::block::blocks(self.tile[0]) as usize,
            super::block::blocks(self.tile[1]) as usize,
        );
        let n = COUNT as usize;
        let mut out = Vec::with_capacity(blocks.len());
        for v in 0..n {
            for by in 0..bh {
                for l in 0..n {
                    let img = &blocks[(v * n + l) * bw * bh..][..bw * bh];
                    out.extend_from_slice(&img[by * bw..(by + 1) * bw]);
                }
            }
        }
        out
    }

    /// The RGBA8 texels of all layers in order, from the slice-major [`pack`]ed images.
    pub fn arrange(&self, packed: &[u8]) -> Vec<u8> {
        match self.layout {
            Layout::Layers => packed.to_vec(),
            Layout::Rows => {
                let [w, h] = [self.tile[0] as usize, self.tile[1] as usize];
                let g = self.gutter as usize;
                let n = COUNT as usize;
                let [lw, lh] = self.layer_extent;
                let mut out = Vec::with_capacity(n * lw as usize * lh as usize * 4);
                for v in 0..n {
                    for r in 0..h {
                        for l in 0..n {
                            let img = &packed[(v * n + l) * w * h * 4..][..w * h * 4];
                            let row = &img[r * w * 4..(r + 1) * w * 4];
                            out.extend_from_slice(&row[(w - g) * 4..]);
                            out.extend_from_slice(row);
                            out.extend_from_slice(&row[..g * 4]);
                        }
                    }
                }
                out
            }
        }
    }
}

/// The packed texels: slice-major (slice = view * 81 + light), RGBA8 sRGB, alpha 255.
pub fn pack(btf: &Btf) -> Vec<u8> {
    btf.texels
        .iter()
        .flat_map(|p| {
            let [r, g, b] = p.map(srgb_encode);
            [r, g, b, 255]
        })
        .collect()
}

/// What the kernel is built from.
pub struct BtfInputs<'a> {
    pub btf: &'a Btf,
    pub maps: &'a Maps,
    pub gbuffer: &'a GBuffer,
    pub layout: Layout,
    pub texture: Texture,
    /// Lower the layers per array below the device's limit (tests of multi-array packing).
    pub layer_cap: Option<u32>,
}

impl<'a> BtfInputs<'a> {
    /// `texture` texels in their default layout, within the device's layer limit.
    pub fn new(btf: &'a Btf, maps: &'a Maps, gbuffer: &'a GBuffer, texture: Texture) -> Self {
        BtfInputs {
            btf,
            maps,
            gbuffer,
            layout: texture.default_layout(),
            texture,
            layer_cap: None,
        }
    }
}

/// The direction map as the shader reads it (RGBA32UI): per texel, the three sample
/// indices in bits 0-7, 8-15, 16-23 of x and their f32 weights (bit patterns) in y, z, w.
pub fn map_texels(maps: &Maps) -> Vec<[u32; 4]> {
    maps.index
        .iter()
        .zip(&maps.weight)
        .map(|(i, w)| {
            [
                i[0] as u32 | (i[1] as u32) << 8 | (i[2] as u32) << 16,
                w[0].to_bits(),
                w[1].to_bits(),
                w[2].to_bits(),
            ]
        })
        .collect()
}

/// The G-buffer as the shader reads it: three layers of RGBA32F, layer j holding vec4 j of
/// every pixel.
pub fn gbuffer_layers(gb: &GBuffer) -> Vec<[f32; 4]> {
    (0..3)
        .flat_map(|j| gb.texels.iter().skip(j).step_by(3).copied())
        .collect()
}

/// Everything `btf shade` reads, checked and packed for one device's limits: the layers of
/// the array textures, the direction map and the G-buffer layers.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub(super) packing: Packing,
    /// The bytes of all layers in order ([`Packing::upload_bytes`]).
    pub(super) texels: Vec<u8>,
    /// The direction map's side and its texels ([`map_texels`]).
    pub(super) map_res: u32,
    pub(super) map: Vec<[u32; 4]>,
    /// Output width and height: the G-buffer's.
    pub(super) size: [u32; 2],
    /// The G-buffer's three layers ([`gbuffer_layers`]); none when it lives on the GPU
    /// ([`Prepared::for_gpu_gbuffer`]).
    pub(super) gbuffer: Option<Vec<[f32; 4]>>,
}

impl Prepared {
    /// Checks `inputs` and packs them for a device whose maxImageDimension2D and
    /// maxImageArrayLayers are `max_dim_2d` and `max_layers`.
    pub fn new(inputs: &BtfInputs<'_>, max_dim_2d: u32, max_layers: u32) -> Result<Prepared> {
        let gb = inputs.gbuffer;
        gb.check()?;
        let limits = (max_dim_2d, max_layers);
        let size = [gb.width, gb.height];
        let mut prep = Self::build(inputs, size, limits)?;
        prep.gbuffer = Some(gbuffer_layers(gb));
        Ok(prep)
    }

    /// As [`Prepared::new`] for a G-buffer of `size` pixels that lives on the GPU (written
    /// by the rasteriser, bound with `BtfKernel::on_gbuffer`); `inputs.gbuffer` is not read.
    pub fn for_gpu_gbuffer(
        inputs: &BtfInputs<'_>,
        size: [u32; 2],
        max_dim_2d: u32,
        max_layers: u32,
    ) -> Result<Prepared> {
        if size[0] == 0 || size[1] == 0 || size[0] > 16384 || size[1] > 16384 {
            return Err(Error::InvalidArgument(format!(
                "G-buffer of {} x {} pixels",
                size[0], size[1]
            )));
        }
        Self::build(inputs, size, (max_dim_2d, max_layers))
    }

    fn build(
        inputs: &BtfInputs<'_>,
        size: [u32; 2],
        (max_dim_2d, max_layers): (u32, u32),
    ) -> Result<Prepared> {
        let btf = inputs.btf;
        if btf.texels.len() != SLICES as usize * btf.image_len() || btf.image_len() == 0 {
            return Err(Error::InvalidArgument(format!(
                "BTF holds {} texels, not 6561 images of {} x {}",
                btf.texels.len(),
                btf.size[0],
                btf.size[1]
            )));
        }
        let side = size[0].max(size[1]);
        if side > max_dim_2d {
            return Err(Error::Limit {
                what: "BTF G-buffer texture side".into(),
                requested: side as u64,
                limit_name: "maxImageDimension2D",
                limit: max_dim_2d as u64,
            });
        }
        let packing = Packing::for_format(
            inputs.layout,
            inputs.texture,
            btf.size,
            max_dim_2d,
            max_layers,
            inputs.layer_cap,
        )?;
        inputs.maps.check()?;
        Ok(Prepared {
            packing,
            texels: packing.upload_bytes(btf),
            map_res: inputs.maps.res,
            map: map_texels(inputs.maps),
            size,
            gbuffer: None,
        })
    }

    /// The packing chosen.
    pub fn packing(&self) -> Packing {
        self.packing
    }

    /// The bytes of all layers in order, as uploaded.
    pub fn texels(&self) -> &[u8] {
        &self.texels
    }

    /// The bytes of array `a` (< `packing().arrays`): its layers.
    pub fn array_bytes(&self, a: u32) -> &[u8] {
        let per_layer = self.packing.layer_bytes();
        let start = (a * self.packing.layers_per_array) as usize * per_layer;
        &self.texels[start..start + self.packing.layers(a) as usize * per_layer]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_follows_the_limits() {
        let p = Packing::for_limits(Layout::Layers, [32, 32], 16384, 2048, None).unwrap();
        assert_eq!((p.layers_per_array, p.arrays), (2048, 4));
        assert_eq!(p.layers(3), 6561 - 3 * 2048);
        assert_eq!(p.bytes(), 6561 * 32 * 32 * 4);
        let p = Packing::for_limits(Layout::Layers, [32, 32], 16384, 8192, None).unwrap();
        assert_eq!((p.layers_per_array, p.arrays), (6561, 1));
        assert!(Packing::for_limits(Layout::Layers, [32, 32], 16384, 256, None).is_err());
        assert!(Packing::for_limits(Layout::Layers, [64, 64], 32, 2048, None).is_err());
        let p = Packing::for_limits(Layout::Rows, [32, 32], 16384, 2048, None).unwrap();
        assert_eq!(
            (p.layer_extent, p.layers_per_array, p.arrays),
            ([81 * 34, 32], 81, 1)
        );
        assert!(Packing::for_limits(Layout::Rows, [32, 32], 2048, 2048, None).is_err());
        // Block: 11 x 11 blocks of 16 bytes per 32 x 32 image, rows only.
        let p =
            Packing::for_format(Layout::Rows, Texture::Block, [32, 32], 16384, 2048, None).unwrap();
        assert_eq!((p.layer_extent, p.gutter, p.arrays), ([81 * 11, 11], 0, 1));
        assert_eq!(p.bytes(), 6561 * 121 * 16);
        assert!(p.bytes() as f64 / (1u64 << 20) as f64 <= 17.2);
        assert!(
            Packing::for_format(Layout::Layers, Texture::Block, [32, 32], 16384, 2048, None)
                .is_err()
        );
        assert!(
            Packing::for_format(Layout::Rows, Texture::Block, [32, 32], 800, 2048, None).is_err()
        );
        // Rows read all 81 view layers from one array.
        assert!(Packing::for_limits(Layout::Rows, [32, 32], 16384, 2048, Some(80)).is_err());
    }

    #[test]
    fn rows_carry_wrapped_gutters() {
        let p = Packing::for_limits(Layout::Rows, [2, 1], 16384, 2048, None).unwrap();
        let packed: Vec<u8> = (0..6561 * 2 * 4).map(|i| (i / 4 % 251) as u8).collect();
        let rows = p.arrange(&packed);
        assert_eq!(rows.len() as u64, p.bytes());
        // Layer 0 (view 0), light 0: gutter = texel 1, texels 0 1, gutter = texel 0.
        let texel = |b: &[u8], i: usize| b[4 * i];
        assert_eq!(
            [0, 1, 2, 3].map(|i| texel(&rows, i)),
            [
                texel(&packed, 1),
                texel(&packed, 0),
                texel(&packed, 1),
                texel(&packed, 0)
            ]
        );
    }

    /// A 2 x 1 tile whose texels count up, 4 x 4 maps and a 3 x 2 G-buffer.
    fn small() -> (Btf, Maps, GBuffer) {
        let btf = Btf {
            size: [2, 1],
            texels: (0..6561 * 2)
                .map(|i| [(i % 7) as f32 / 7.0, 0.5, 1.0])
                .collect(),
        };
        let maps = Maps {
            res: 4,
            index: vec![[3, 1, 80, 0]; 16],
            weight: vec![[0.5, 0.25, 0.25, 0.0]; 16],
        };
        (btf, maps, GBuffer::tile([3, 2]))
    }

    #[test]
    fn prepared_holds_what_the_shader_reads() {
        let (btf, maps, gb) = small();
        let inputs = BtfInputs::new(&btf, &maps, &gb, Texture::Rgba8);
        let p = Prepared::new(&inputs, 16384, 2048).unwrap();
        assert_eq!(p.packing.layer_extent, [81 * 4, 1]);
        assert_eq!(p.texels.len() as u64, p.packing.bytes());
        assert_eq!(p.texels, p.packing.arrange(&pack(&btf)));
        assert_eq!(p.array_bytes(0), &p.texels[..]);
        // The map: indices in the low three bytes of x, weights' bits in y, z, w.
        assert_eq!(p.map_res, 4);
        assert_eq!(p.map.len(), 16);
        let w = [0.5f32, 0.25, 0.25].map(f32::to_bits);
        assert_eq!(p.map[5], [3 | 1 << 8 | 80 << 16, w[0], w[1], w[2]]);
        // The G-buffer: layer j holds vec4 j of every pixel.
        assert_eq!(p.size, [3, 2]);
        let layers = p.gbuffer.as_ref().expect("a CPU G-buffer");
        assert_eq!(layers.len(), 3 * 6);
        for (j, k) in [(0, 0), (1, 4), (2, 5)] {
            assert_eq!(layers[j * 6 + k], gb.texels[3 * k + j]);
        }
        // Layers split over four arrays: each array's bytes are its layers, in order.
        let capped = BtfInputs {
            layout: Layout::Layers,
            layer_cap: Some(1700),
            ..inputs
        };
        let p = Prepared::new(&capped, 16384, 2048).unwrap();
        assert_eq!((p.packing.layers_per_array, p.packing.arrays), (1700, 4));
        let arrays: Vec<u8> = (0..4).flat_map(|a| p.array_bytes(a).to_vec()).collect();
        assert_eq!(p.array_bytes(3).len(), (6561 - 3 * 1700) * 2 * 4);
        assert!(arrays == p.texels && p.texels == pack(&btf));
        // Blocks: one array of 81 view layers, 1 x 1 block per 2 x 1 image.
        let p = Prepared::new(
            &BtfInputs::new(&btf, &maps, &gb, Texture::Block),
            16384,
            2048,
        )
        .unwrap();
        assert_eq!((p.packing.layer_extent, p.packing.arrays), ([81, 1], 1));
        assert_eq!(p.texels.len(), 6561 * 16);
    }

    #[test]
    fn prepared_refuses_what_does_not_fit() {
        let (btf, maps, gb) = small();
        let inputs = BtfInputs::new(&btf, &maps, &gb, Texture::Rgba8);
        let e = Prepared::new(&inputs, 2, 2048).unwrap_err().to_string();
        assert!(
            e.contains("G-buffer") && e.contains("maxImageDimension2D"),
            "{e}"
        );
        let e = Prepared::new(&inputs, 300, 2048).unwrap_err().to_string();
        assert!(e.contains("layer side"), "{e}");
        let short = Btf {
            size: [2, 1],
            texels: btf.texels[..100].to_vec(),
        };
        let e = Prepared::new(
            &BtfInputs::new(&short, &maps, &gb, Texture::Rgba8),
            16384,
            2048,
        );
        assert!(e.unwrap_err().to_string().contains("6561 images"));
        let mut bad = maps.clone();
        bad.index[2][1] = 81;
        let e = Prepared::new(
            &BtfInputs::new(&btf, &bad, &gb, Texture::Rgba8),
            16384,
            2048,
        );
        assert!(e.unwrap_err().to_string().contains("texel 2"));
    }
}
