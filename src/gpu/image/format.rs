//! Formats: the texel blocks vkshade moves through staging, and the format features an
//! image's usage needs (checked against the device).

use crate::error::{Error, Result};
use crate::gpu::context::Shared;
use ash::vk;

/// The texel block of a format: `width` x `height` texels stored in `bytes` bytes
/// (1 x 1 for uncompressed formats). Buffer-image copies of a block-compressed image move
/// whole blocks: regions start on a block boundary and end on one or at the mip edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FormatBlock {
    /// Block width in texels.
    pub width: u32,
    /// Block height in texels.
    pub height: u32,
    /// Bytes one block takes.
    pub bytes: u64,
}

impl FormatBlock {
    /// Whether the format is block-compressed.
    pub fn compressed(&self) -> bool {
        self.width > 1 || self.height > 1
    }

    /// Bytes of a tightly packed `extent` (one layer), partial edge blocks counted whole.
    pub fn bytes_for(&self, extent: [u32; 3]) -> u64 {
        extent[0].div_ceil(self.width) as u64
            * extent[1].div_ceil(self.height) as u64
            * extent[2] as u64
            * self.bytes
    }
}

/// The texel block of the formats vkshade moves through staging: the uncompressed colour
/// formats of [`texel_size`] and BC1 (RGB/RGBA, UNORM/SRGB: 4 x 4 texels in 8 bytes).
pub fn format_block(format: vk::Format) -> Option<FormatBlock> {
    if is_bc(format) {
        return Some(FormatBlock {
            width: 4,
            height: 4,
            bytes: 8,
        });
    }
    texel_size(format).map(|bytes| FormatBlock {
        width: 1,
        height: 1,
        bytes,
    })
}

/// Whether `format` is one of the BC formats vkshade stages (needs `textureCompressionBC`).
pub fn is_bc(format: vk::Format) -> bool {
    use vk::Format as F;
    matches!(
        format,
        F::BC1_RGB_UNORM_BLOCK
            | F::BC1_RGB_SRGB_BLOCK
            | F::BC1_RGBA_UNORM_BLOCK
            | F::BC1_RGBA_SRGB_BLOCK
    )
}

/// Texel size in bytes of the uncompressed colour formats vkshade moves through staging.
pub fn texel_size(format: vk::Format) -> Option<u64> {
    use vk::Format as F;
    Some(match format {
        F::R8_UNORM | F::R8_SNORM | F::R8_UINT | F::R8_SINT | F::R8_SRGB => 1,
        F::R8G8_UNORM
        | F::R8G8_SNORM
        | F::R8G8_UINT
        | F::R16_SFLOAT
        | F::R16_UINT
        | F::R16_SINT
        | F::R16_UNORM => 2,
        F::R8G8B8A8_UNORM
        | F::R8G8B8A8_SNORM
        | F::R8G8B8A8_SRGB
        | F::R8G8B8A8_UINT
        | F::B8G8R8A8_UNORM
        | F::B8G8R8A8_SRGB
        | F::R32_SFLOAT
        | F::R32_UINT
        | F::R32_SINT
        | F::R16G16_SFLOAT
        | F::R16G16_UNORM
        | F::R16G16_UINT
        | F::B10G11R11_UFLOAT_PACK32
        | F::A2B10G10R10_UNORM_PACK32 => 4,
        F::R16G16B16A16_SFLOAT
        | F::R16G16B16A16_UNORM
        | F::R16G16B16A16_UINT
        | F::R32G32_SFLOAT
        | F::R32G32_UINT => 8,
        F::R32G32B32A32_SFLOAT | F::R32G32B32A32_UINT | F::R32G32B32A32_SINT => 16,
        _ => return None,
    })
}

pub(super) fn is_depth_stencil(format: vk::Format) -> bool {
    use vk::Format as F;
    matches!(
        format,
        F::D16_UNORM
            | F::X8_D24_UNORM_PACK32
            | F::D32_SFLOAT
            | F::S8_UINT
            | F::D16_UNORM_S8_UINT
            | F::D24_UNORM_S8_UINT
            | F::D32_SFLOAT_S8_UINT
    )
}

pub(super) fn format_features_for(usage: vk::ImageUsageFlags) -> vk::FormatFeatureFlags {
    let mut f = vk::FormatFeatureFlags::empty();
    for (u, feature) in [
        (
            vk::ImageUsageFlags::SAMPLED,
            vk::FormatFeatureFlags::SAMPLED_IMAGE,
        ),
        (
            vk::ImageUsageFlags::STORAGE,
            vk::FormatFeatureFlags::STORAGE_IMAGE,
        ),
        (
            vk::ImageUsageFlags::TRANSFER_DST,
            vk::FormatFeatureFlags::TRANSFER_DST,
        ),
        (
            vk::ImageUsageFlags::TRANSFER_SRC,
            vk::FormatFeatureFlags::TRANSFER_SRC,
        ),
        (
            vk::ImageUsageFlags::COLOR_ATTACHMENT,
            vk::FormatFeatureFlags::COLOR_ATTACHMENT,
        ),
    ] {
        if usage.contains(u) {
            f |= feature;
        }
    }
    f
}

impl Shared {
    /// Optimal-tiling features of `format`.
    pub(crate) fn format_features(&self, format: vk::Format) -> vk::FormatFeatureFlags {
        // SAFETY: valid physical device.
        unsafe {
            self.instance
                .get_physical_device_format_properties(self.physical, format)
        }
        .optimal_tiling_features
    }

    /// Fails unless `format` has every feature in `needed` (optimal tiling).
    pub(crate) fn require_format(
        &self,
        format: vk::Format,
        needed: vk::FormatFeatureFlags,
        what: &str,
    ) -> Result<()> {
        let have = self.format_features(format);
        if !have.contains(needed) {
            return Err(Error::Unsupported {
                device: self.info.name.clone(),
                what: format!(
                    "format {format:?} with {:?} for {what} (it has {have:?})",
                    needed & !have
                ),
            });
        }
        Ok(())
    }
}
