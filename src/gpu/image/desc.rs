//! What an image is: its dimension, format, extent, mips, layers and usage ([`ImageDesc`]),
//! ranges of its subresources ([`Subresources`]) and regions of one mip level for copies
//! ([`ImageRegion`]).

use super::format::{FormatBlock, format_block, texel_size};
use crate::error::{Error, Result};
use crate::gpu::memory::Placement;
use ash::vk;

/// The dimensionality of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum ImageDim {
    /// 2D, with one or more array layers.
    D2,
    /// 2D with a multiple of six layers, viewable as cube maps.
    Cube,
    /// 3D, one layer; depth slices are addressed by offset and extent.
    D3,
}

/// What an image is (the name is given separately): dimension, format, extent, mip levels,
/// array layers, usage, whether views may use other formats, and placement.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ImageDesc {
    /// Dimension: 2D (array), cube-compatible 2D, or 3D.
    pub dim: ImageDim,
    /// The texel format (a colour format; checked against the device at creation).
    pub format: vk::Format,
    /// Width, height, depth (depth 1 unless 3D).
    pub extent: [u32; 3],
    /// Mip levels (1 to a full chain).
    pub mips: u32,
    /// Array layers (six per cube for [`ImageDim::Cube`], 1 for 3D).
    pub layers: u32,
    /// How the image may be used; each usage needs the matching format feature.
    pub usage: vk::ImageUsageFlags,
    /// Views may use other compatible formats (e.g. sRGB and UNORM views of one image).
    pub mutable_format: bool,
    /// Where its memory lives and whether it gets an allocation of its own.
    pub placement: Placement,
}

/// The number of mip levels of a full chain for `extent`.
pub fn full_mip_count(extent: [u32; 3]) -> u32 {
    32 - extent
        .iter()
        .copied()
        .max()
        .unwrap_or(1)
        .max(1)
        .leading_zeros()
}

impl ImageDesc {
    const DEFAULT_USAGE: vk::ImageUsageFlags = vk::ImageUsageFlags::from_raw(
        vk::ImageUsageFlags::SAMPLED.as_raw()
            | vk::ImageUsageFlags::TRANSFER_DST.as_raw()
            | vk::ImageUsageFlags::TRANSFER_SRC.as_raw(),
    );

    fn new(dim: ImageDim, format: vk::Format, extent: [u32; 3], layers: u32) -> Self {
        ImageDesc {
            dim,
            format,
            extent,
            mips: 1,
            layers,
            usage: Self::DEFAULT_USAGE,
            mutable_format: false,
            placement: Placement::DEVICE,
        }
    }

    /// A 2D image (sampled, copyable; add usages with [`ImageDesc::usage`]).
    pub fn d2(format: vk::Format, [w, h]: [u32; 2]) -> Self {
        Self::new(ImageDim::D2, format, [w, h, 1], 1)
    }

    /// A 2D array image of `layers` layers.
    pub fn d2_array(format: vk::Format, [w, h]: [u32; 2], layers: u32) -> Self {
        Self::new(ImageDim::D2, format, [w, h, 1], layers)
    }

    /// A cube map (six layers per cube, `cubes` cubes).
    pub fn cube(format: vk::Format, size: u32, cubes: u32) -> Self {
        Self::new(ImageDim::Cube, format, [size, size, 1], 6 * cubes)
    }

    /// A 3D image.
    pub fn d3(format: vk::Format, extent: [u32; 3]) -> Self {
        Self::new(ImageDim::D3, format, extent, 1)
    }

    /// Adds usages.
    pub fn usage(mut self, usage: vk::ImageUsageFlags) -> Self {
        self.usage |= usage;
        self
    }

    /// Sets the mip level count (0: the full chain).
    pub fn mips(mut self, mips: u32) -> Self {
        self.mips = if mips == 0 {
            full_mip_count(self.extent)
        } else {
            mips
        };
        self
    }

    /// Lets views use other formats of the same texel size (e.g. sRGB and UNORM views).
    pub fn mutable_format(mut self) -> Self {
        self.mutable_format = true;
        self
    }

    /// Sets where the image's memory lives.
    pub fn placement(mut self, placement: Placement) -> Self {
        self.placement = placement;
        self
    }

    /// The Vulkan image type: 3D for [`ImageDim::D3`], else 2D.
    pub fn image_type(&self) -> vk::ImageType {
        match self.dim {
            ImageDim::D3 => vk::ImageType::TYPE_3D,
            _ => vk::ImageType::TYPE_2D,
        }
    }

    /// The view type of a view over all layers.
    pub fn default_view_type(&self) -> vk::ImageViewType {
        match (self.dim, self.layers) {
            (ImageDim::D3, _) => vk::ImageViewType::TYPE_3D,
            (ImageDim::Cube, 6) => vk::ImageViewType::CUBE,
            (ImageDim::Cube, _) => vk::ImageViewType::CUBE_ARRAY,
            (ImageDim::D2, 1) => vk::ImageViewType::TYPE_2D,
            (ImageDim::D2, _) => vk::ImageViewType::TYPE_2D_ARRAY,
        }
    }

    /// The extent of mip level `mip`.
    pub fn mip_extent(&self, mip: u32) -> [u32; 3] {
        self.extent.map(|e| (e >> mip).max(1))
    }

    /// Bytes per texel of the format (uncompressed colour formats only).
    pub fn texel_size(&self) -> Result<u64> {
        texel_size(self.format).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "format {:?} has no per-texel size vkshade can stage (compressed or \
                 depth/stencil formats are not uploaded texel by texel)",
                self.format
            ))
        })
    }

    /// The format's texel block (1 x 1 for uncompressed formats, 4 x 4 for BC1).
    pub fn block(&self) -> Result<FormatBlock> {
        format_block(self.format).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "format {:?} has no texel block size vkshade can stage (only uncompressed \
                 colour formats and BC1 are uploaded; depth/stencil formats are not)",
                self.format
            ))
        })
    }

    /// Size in bytes of one mip level's tightly packed texels (texel blocks for a
    /// block-compressed format, partial blocks at the edges counted whole), all layers.
    pub fn mip_byte_size(&self, mip: u32) -> Result<u64> {
        Ok(self.block()?.bytes_for(self.mip_extent(mip)) * self.layers as u64)
    }

    /// Size in bytes of mip 0, all layers (tightly packed).
    pub fn byte_size(&self) -> Result<u64> {
        self.mip_byte_size(0)
    }

    /// Every subresource of the image.
    pub fn all(&self) -> Subresources {
        Subresources {
            base_mip: 0,
            mip_count: self.mips,
            base_layer: 0,
            layer_count: self.layers,
        }
    }
}

/// A range of mip levels and array layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Subresources {
    /// First mip level.
    pub base_mip: u32,
    /// Number of mip levels from `base_mip`.
    pub mip_count: u32,
    /// First array layer.
    pub base_layer: u32,
    /// Number of array layers from `base_layer`.
    pub layer_count: u32,
}

impl Subresources {
    /// Every (mip, layer) in the range, mip-major.
    pub fn iter(&self) -> impl Iterator<Item = (u32, u32)> + use<> {
        let (layers, base_layer) = (self.layer_count, self.base_layer);
        (self.base_mip..self.base_mip + self.mip_count)
            .flat_map(move |mip| (base_layer..base_layer + layers).map(move |layer| (mip, layer)))
    }

    /// One mip level, every layer of `desc`.
    pub fn mip(desc: &ImageDesc, mip: u32) -> Self {
        Subresources {
            base_mip: mip,
            mip_count: 1,
            base_layer: 0,
            layer_count: desc.layers,
        }
    }

    /// One layer, every mip level of `desc`.
    pub fn layer(desc: &ImageDesc, layer: u32) -> Self {
        Subresources {
            base_mip: 0,
            mip_count: desc.mips,
            base_layer: layer,
            layer_count: 1,
        }
    }

    /// The range as Vulkan spells it (colour aspect).
    pub fn vk(&self) -> vk::ImageSubresourceRange {
        vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            base_mip_level: self.base_mip,
            level_count: self.mip_count,
            base_array_layer: self.base_layer,
            layer_count: self.layer_count,
        }
    }

    /// Checks the range is non-empty and inside `desc`.
    pub fn check(&self, name: &str, desc: &ImageDesc) -> Result<()> {
        let inside = |base: u32, count: u32, total: u32| {
            count > 0 && base.checked_add(count).is_some_and(|end| end <= total)
        };
        if !inside(self.base_mip, self.mip_count, desc.mips)
            || !inside(self.base_layer, self.layer_count, desc.layers)
        {
            return Err(Error::InvalidArgument(format!(
                "subresources mips {}..+{} layers {}..+{} are empty or outside image '{name}' \
                 ({} mips, {} layers)",
                self.base_mip,
                self.mip_count,
                self.base_layer,
                self.layer_count,
                desc.mips,
                desc.layers
            )));
        }
        Ok(())
    }
}

/// A region of one mip level for copies: `layers` from `base_layer`, texel `offset` and
/// `extent` (depth 1 unless 3D).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageRegion {
    /// The mip level.
    pub mip: u32,
    /// First array layer.
    pub base_layer: u32,
    /// Number of array layers from `base_layer`.
    pub layers: u32,
    /// Texel offset of the region's corner within the mip level.
    pub offset: [u32; 3],
    /// Width, height and depth in texels.
    pub extent: [u32; 3],
}

impl ImageRegion {
    /// All of mip level `mip`, every layer.
    pub fn mip(desc: &ImageDesc, mip: u32) -> Self {
        ImageRegion {
            mip,
            base_layer: 0,
            layers: desc.layers,
            offset: [0; 3],
            extent: desc.mip_extent(mip),
        }
    }

    /// All of mip 0.
    pub fn whole(desc: &ImageDesc) -> Self {
        Self::mip(desc, 0)
    }

    /// Texels in the region, over all its layers.
    pub fn texels(&self) -> u64 {
        self.extent.iter().map(|&e| e as u64).product::<u64>() * self.layers as u64
    }

    /// Bytes of the region's tightly packed texels (whole blocks for a compressed format).
    pub fn byte_size(&self, desc: &ImageDesc) -> Result<u64> {
        Ok(desc.block()?.bytes_for(self.extent) * self.layers as u64)
    }

    /// The subresources the region touches: its mip level and layers.
    pub fn subresources(&self) -> Subresources {
        Subresources {
            base_mip: self.mip,
            mip_count: 1,
            base_layer: self.base_layer,
            layer_count: self.layers,
        }
    }

    pub(crate) fn layers_vk(&self) -> vk::ImageSubresourceLayers {
        vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: self.mip,
            base_array_layer: self.base_layer,
            layer_count: self.layers,
        }
    }

    /// Checks the region is non-empty and inside `desc`.
    pub fn check(&self, name: &str, desc: &ImageDesc) -> Result<()> {
        self.subresources().check(name, desc)?;
        let e = desc.mip_extent(self.mip);
        let fits = (0..3).all(|i| {
            self.extent[i] > 0
                && self.offset[i]
                    .checked_add(self.extent[i])
                    .is_some_and(|end| end <= e[i])
        });
        if !fits {
            return Err(Error::InvalidArgument(format!(
                "region offset {:?} extent {:?} is empty or outside mip {} ({:?}) of image '{name}'",
                self.offset, self.extent, self.mip, e
            )));
        }
        if let Some(b) = format_block(desc.format).filter(FormatBlock::compressed) {
            let aligned = (0..2).all(|i| {
                let bw = [b.width, b.height][i];
                self.offset[i].is_multiple_of(bw)
                    && (self.extent[i].is_multiple_of(bw)
                        || self.offset[i] + self.extent[i] == e[i])
            });
            if !aligned {
                return Err(Error::InvalidArgument(format!(
                    "region offset {:?} extent {:?} of image '{name}' ({:?}) is not aligned to \
                     its {}x{} texel blocks (it must start on a block and end on one or at the \
                     edge of mip {} {:?})",
                    self.offset, self.extent, desc.format, b.width, b.height, self.mip, e
                )));
            }
        }
        Ok(())
    }
}
