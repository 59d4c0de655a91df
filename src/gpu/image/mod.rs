//! Images (2D, 2D arrays, cube maps, 3D; mip levels), their views, and samplers.
//!
//! An [`Image`] has a shape ([`ImageDesc`]) and any number of views, created on first use
//! and cached by [`ViewDesc`] (type, format, subresources). Formats are checked against the
//! device's format features when the image or view is created, with errors that say which
//! feature is missing.

use super::context::{Context, Shared};
use super::lifetime::{Retired, Stamp, Used};
use super::memory::{AliasGroup, Backing, Placement};
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::AllocationScheme;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// The dimensionality of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum ImageDim {
    /// 2D, with one or more array layers.
    D2,
    /// 2D with a multiple of six layers, viewable as cube maps.
    Cube,
    D3,
}

/// What an image is (the name is given separately): dimension, format, extent, mip levels,
/// array layers, usage, whether views may use other formats, and placement.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ImageDesc {
    pub dim: ImageDim,
    pub format: vk::Format,
    /// Width, height, depth (depth 1 unless 3D).
    pub extent: [u32; 3],
    pub mips: u32,
    pub layers: u32,
    pub usage: vk::ImageUsageFlags,
    /// Views may use other compatible formats (e.g. sRGB and UNORM views of one image).
    pub mutable_format: bool,
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

    pub fn mutable_format(mut self) -> Self {
        self.mutable_format = true;
        self
    }

    pub fn placement(mut self, placement: Placement) -> Self {
        self.placement = placement;
        self
    }

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

/// The texel block of a format: `width` x `height` texels stored in `bytes` bytes
/// (1 x 1 for uncompressed formats). Buffer-image copies of a block-compressed image move
/// whole blocks: regions start on a block boundary and end on one or at the mip edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FormatBlock {
    pub width: u32,
    pub height: u32,
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

fn is_depth_stencil(format: vk::Format) -> bool {
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

/// A range of mip levels and array layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Subresources {
    pub base_mip: u32,
    pub mip_count: u32,
    pub base_layer: u32,
    pub layer_count: u32,
}

impl Subresources {
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

/// A view of an image: type and format (the image's when `None`) and subresources (all of
/// them when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ViewDesc {
    pub view_type: Option<vk::ImageViewType>,
    pub format: Option<vk::Format>,
    pub subresources: Option<Subresources>,
}

impl ViewDesc {
    pub fn format(mut self, format: vk::Format) -> Self {
        self.format = Some(format);
        self
    }

    pub fn view_type(mut self, t: vk::ImageViewType) -> Self {
        self.view_type = Some(t);
        self
    }

    pub fn subresources(mut self, s: Subresources) -> Self {
        self.subresources = Some(s);
        self
    }
}

/// A region of one mip level for copies: `layers` from `base_layer`, texel `offset` and
/// `extent` (depth 1 unless 3D).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageRegion {
    pub mip: u32,
    pub base_layer: u32,
    pub layers: u32,
    pub offset: [u32; 3],
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

    pub fn texels(&self) -> u64 {
        self.extent.iter().map(|&e| e as u64).product::<u64>() * self.layers as u64
    }

    /// Bytes of the region's tightly packed texels (whole blocks for a compressed format).
    pub fn byte_size(&self, desc: &ImageDesc) -> Result<u64> {
        Ok(desc.block()?.bytes_for(self.extent) * self.layers as u64)
    }

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
                self.offset[i] % bw == 0
                    && (self.extent[i] % bw == 0 || self.offset[i] + self.extent[i] == e[i])
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

/// The Vulkan image, its views and memory; destroyed when the last holder drops it and the
/// GPU is done with it.
pub(crate) struct ImageInner {
    pub(crate) shared: Arc<Shared>,
    pub(crate) raw: vk::Image,
    backing: Mutex<Option<Backing>>,
    pub(crate) desc: ImageDesc,
    pub(crate) name: String,
    alloc_size: u64,
    views: Mutex<HashMap<ViewDesc, vk::ImageView>>,
    pub(crate) stamp: Stamp,
    /// Per-subresource state for tracking (see `track`).
    pub(crate) state: Mutex<super::track::ImageState>,
}

impl Used for ImageInner {
    fn stamp(&self, value: u64) {
        self.stamp.raise(value);
        if let Some(b) = lock(&self.backing).as_ref() {
            b.stamp(value)
        }
    }
}

impl Drop for ImageInner {
    fn drop(&mut self) {
        let mut items: Vec<Retired> = lock(&self.views)
            .drain()
            .map(|(_, v)| Retired::View(v))
            .collect();
        let backing = lock(&self.backing).take();
        // A caller's image (from_raw) is the caller's to destroy; the views are vkshade's.
        if !matches!(backing, Some(Backing::External)) {
            items.push(Retired::Image(self.raw));
            items.extend(backing.and_then(Backing::retire));
        }
        self.shared.retire(self.stamp.get(), items);
    }
}

/// A Vulkan image (the owning handle).
pub struct Image {
    inner: Arc<ImageInner>,
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Image")
            .field("name", &self.inner.name)
            .field("desc", &self.inner.desc)
            .finish()
    }
}

fn format_features_for(usage: vk::ImageUsageFlags) -> vk::FormatFeatureFlags {
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

fn create_info(desc: &ImageDesc) -> vk::ImageCreateInfo<'static> {
    let mut flags = vk::ImageCreateFlags::empty();
    if desc.dim == ImageDim::Cube {
        flags |= vk::ImageCreateFlags::CUBE_COMPATIBLE;
    }
    if desc.mutable_format {
        flags |= vk::ImageCreateFlags::MUTABLE_FORMAT | vk::ImageCreateFlags::EXTENDED_USAGE;
    }
    let [width, height, depth] = desc.extent;
    vk::ImageCreateInfo::default()
        .flags(flags)
        .image_type(desc.image_type())
        .format(desc.format)
        .extent(vk::Extent3D {
            width,
            height,
            depth,
        })
        .mip_levels(desc.mips)
        .array_layers(desc.layers)
        .samples(vk::SampleCountFlags::TYPE_1)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(desc.usage)
        .sharing_mode(vk::SharingMode::EXCLUSIVE)
        .initial_layout(vk::ImageLayout::UNDEFINED)
}

/// Checks a description against the device's limits and format support.
fn check_image_desc(shared: &Shared, name: &str, desc: &ImageDesc) -> Result<()> {
    let limits = &shared.info.limits;
    let [w, h, d] = desc.extent;
    if w == 0 || h == 0 || d == 0 || desc.layers == 0 || desc.mips == 0 {
        return Err(Error::InvalidArgument(format!(
            "image '{name}' has an empty extent {:?}, {} mips, {} layers",
            desc.extent, desc.mips, desc.layers
        )));
    }
    let bad = |why: String| Err(Error::InvalidArgument(format!("image '{name}': {why}")));
    if is_depth_stencil(desc.format) {
        return bad(format!(
            "{:?} is a depth/stencil format; vkshade's images are colour images",
            desc.format
        ));
    }
    match desc.dim {
        ImageDim::D3 if desc.layers > 1 => return bad("3D images cannot have array layers".into()),
        ImageDim::D2 | ImageDim::Cube if d > 1 => {
            return bad(format!("depth {d} needs a 3D image"));
        }
        ImageDim::Cube if w != h || desc.layers % 6 != 0 => {
            return bad(format!(
                "a cube map needs square faces and a multiple of 6 layers, not {w}x{h} x {}",
                desc.layers
            ));
        }
        _ => {}
    }
    if desc.mips > full_mip_count(desc.extent) {
        return bad(format!(
            "{} mip levels, but extent {:?} has at most {}",
            desc.mips,
            desc.extent,
            full_mip_count(desc.extent)
        ));
    }
    let (max, limit_name) = match desc.dim {
        ImageDim::D3 => (limits.max_image_dimension_3d, "maxImageDimension3D"),
        ImageDim::Cube => (limits.max_image_dimension_cube, "maxImageDimensionCube"),
        ImageDim::D2 => (limits.max_image_dimension_2d, "maxImageDimension2D"),
    };
    for (axis, e) in ["width", "height", "depth"].iter().zip(desc.extent) {
        if e > max {
            return Err(Error::Limit {
                what: format!("{axis} of image '{name}'"),
                requested: e as u64,
                limit_name,
                limit: max as u64,
            });
        }
    }
    if desc.layers > limits.max_image_array_layers {
        return Err(Error::Limit {
            what: format!("array layers of image '{name}'"),
            requested: desc.layers as u64,
            limit_name: "maxImageArrayLayers",
            limit: limits.max_image_array_layers as u64,
        });
    }
    if is_bc(desc.format) && !shared.features.texture_compression_bc {
        return Err(Error::Unsupported {
            device: shared.info.name.clone(),
            what: format!(
                "format {:?} for image '{name}' without the textureCompressionBC feature \
                 (request it in ContextDesc features; the device {} it)",
                desc.format,
                if shared.info.features.texture_compression_bc {
                    "supports"
                } else {
                    "lacks"
                }
            ),
        });
    }
    // With a mutable format, storage may be meant for a view of another format only.
    let mut usage = desc.usage;
    if desc.mutable_format {
        usage &= !vk::ImageUsageFlags::STORAGE;
    }
    shared.require_format(
        desc.format,
        format_features_for(usage),
        &format!("image '{name}' ({:?})", desc.usage),
    )?;
    let info = create_info(desc);
    // SAFETY: valid physical device and parameters.
    let props = unsafe {
        shared.instance.get_physical_device_image_format_properties(
            shared.physical,
            info.format,
            info.image_type,
            info.tiling,
            info.usage,
            info.flags,
        )
    };
    match props {
        Ok(p) => {
            if desc.mips > p.max_mip_levels || desc.layers > p.max_array_layers {
                return bad(format!(
                    "format {:?} allows {} mips and {} layers here",
                    desc.format, p.max_mip_levels, p.max_array_layers
                ));
            }
        }
        Err(vk::Result::ERROR_FORMAT_NOT_SUPPORTED) => {
            return Err(Error::Unsupported {
                device: shared.info.name.clone(),
                what: format!(
                    "format {:?} as a {:?} image with {:?} for '{name}'",
                    desc.format, desc.dim, desc.usage
                ),
            });
        }
        Err(e) => return Err(e).vk("vkGetPhysicalDeviceImageFormatProperties"),
    }
    Ok(())
}

/// Memory requirements of an image that would be created from `desc`.
pub(crate) fn image_requirements(
    shared: &Shared,
    name: &str,
    desc: &ImageDesc,
) -> Result<vk::MemoryRequirements> {
    check_image_desc(shared, name, desc)?;
    let info = create_info(desc);
    let query = vk::DeviceImageMemoryRequirements::default().create_info(&info);
    let mut out = vk::MemoryRequirements2::default();
    // SAFETY: valid create info; maintenance4 is enabled on every vkshade device.
    unsafe {
        shared
            .device
            .get_device_image_memory_requirements(&query, &mut out)
    };
    Ok(out.memory_requirements)
}

impl Image {
    /// Creates an image with its own memory, checking extent, mips and layers against the
    /// device limits and the format's support for the usage.
    pub fn new(ctx: &Context, name: &str, desc: ImageDesc) -> Result<Image> {
        Image::create(ctx, name, desc, None)
    }

    /// Creates an image bound to an alias group's memory (see [`AliasGroup`]).
    pub fn in_group(
        ctx: &Context,
        name: &str,
        desc: ImageDesc,
        group: &AliasGroup,
    ) -> Result<Image> {
        Image::create(ctx, name, desc, Some(group))
    }

    fn create(
        ctx: &Context,
        name: &str,
        desc: ImageDesc,
        group: Option<&AliasGroup>,
    ) -> Result<Image> {
        let shared = &ctx.shared;
        shared.collect();
        check_image_desc(shared, name, &desc)?;
        let info = create_info(&desc);
        // SAFETY: valid device and create info (checked above).
        let raw = unsafe { shared.device.create_image(&info, None) }.vk("vkCreateImage")?;
        let mut dedicated_req = vk::MemoryDedicatedRequirements::default();
        let mut req2 = vk::MemoryRequirements2::default().push_next(&mut dedicated_req);
        let req_info = vk::ImageMemoryRequirementsInfo2::default().image(raw);
        // SAFETY: `raw` was just created.
        unsafe {
            shared
                .device
                .get_image_memory_requirements2(&req_info, &mut req2)
        };
        let backing = super::memory::back(
            shared,
            name,
            req2.memory_requirements,
            (
                AllocationScheme::DedicatedImage(raw),
                dedicated_req.prefers_dedicated_allocation == vk::TRUE,
                dedicated_req.requires_dedicated_allocation == vk::TRUE,
            ),
            desc.placement,
            false,
            group,
        );
        let (backing, memory, offset) = match backing {
            Ok(b) => b,
            Err(e) => {
                // SAFETY: never bound or used.
                unsafe { shared.device.destroy_image(raw, None) };
                return Err(e);
            }
        };
        let alloc_size = backing.size();
        let image = Image {
            inner: Arc::new(ImageInner {
                shared: shared.clone(),
                raw,
                backing: Mutex::new(Some(backing)),
                desc,
                name: name.to_string(),
                alloc_size,
                views: Mutex::new(HashMap::new()),
                stamp: Stamp::default(),
                state: Mutex::new(super::track::ImageState::new(desc.mips, desc.layers)),
            }),
        };
        // SAFETY: memory of this device sized by the requirements; on failure `image` drops
        // and destroys the image.
        unsafe { shared.device.bind_image_memory(raw, memory, offset) }.vk("vkBindImageMemory")?;
        shared.set_name(raw, name);
        Ok(image)
    }

    /// Wraps an image the caller created (a renderer's G-buffer), so vkshade can bind and
    /// copy it. vkshade never destroys it; views it creates are its own.
    ///
    /// # Safety
    /// `raw` must be an image of this context's device created exactly as `desc` describes
    /// (type, format, extent, mips, layers, usage, mutable-format flag), bound to memory,
    /// and valid until every vkshade handle is dropped and the timeline has passed
    /// [`Image::last_use`]. Its current layout must be declared with
    /// [`Image::assume_access`] before tracked use (UNDEFINED otherwise).
    pub unsafe fn from_raw(
        ctx: &Context,
        name: &str,
        raw: vk::Image,
        desc: ImageDesc,
    ) -> Result<Image> {
        check_image_desc(&ctx.shared, name, &desc)?;
        ctx.shared.set_name(raw, name);
        Ok(Image {
            inner: Arc::new(ImageInner {
                shared: ctx.shared.clone(),
                raw,
                backing: Mutex::new(Some(Backing::External)),
                desc,
                name: name.to_string(),
                alloc_size: 0,
                views: Mutex::new(HashMap::new()),
                stamp: Stamp::default(),
                state: Mutex::new(super::track::ImageState::new(desc.mips, desc.layers)),
            }),
        })
    }

    pub(crate) fn keep(&self) -> Arc<ImageInner> {
        self.inner.clone()
    }

    pub fn raw(&self) -> vk::Image {
        self.inner.raw
    }

    pub fn desc(&self) -> &ImageDesc {
        &self.inner.desc
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }

    pub fn allocation_size(&self) -> u64 {
        self.inner.alloc_size
    }

    /// Whether the image is bound to an alias group's memory.
    pub fn is_alias_member(&self) -> bool {
        matches!(lock(&self.inner.backing).as_ref(), Some(Backing::Group(_)))
    }

    /// Fails unless the image has `usage` (needed by `what`).
    pub(crate) fn require_usage(&self, usage: vk::ImageUsageFlags, what: &str) -> Result<()> {
        if !self.inner.desc.usage.contains(usage) {
            return Err(Error::InvalidArgument(format!(
                "image '{}' lacks {usage:?} usage, needed for {what}",
                self.inner.name
            )));
        }
        Ok(())
    }

    /// Timeline value of the last submission that used the image (0: none yet).
    pub fn last_use(&self) -> u64 {
        self.inner.stamp.get()
    }

    /// Every subresource.
    pub fn all(&self) -> Subresources {
        self.inner.desc.all()
    }

    /// Declares how (and so in which layout) `subresources` were last accessed outside
    /// vkshade's tracking.
    pub fn assume_access(
        &self,
        subresources: Subresources,
        access: impl Into<super::sync::AccessSet>,
    ) -> Result<()> {
        subresources.check(&self.inner.name, &self.inner.desc)?;
        lock(&self.inner.state).assume(&subresources, access.into());
        Ok(())
    }

    /// The view over every subresource with the image's own format.
    pub fn view(&self) -> Result<vk::ImageView> {
        self.inner
            .view(&ViewDesc::default(), vk::ImageUsageFlags::empty())
    }

    /// A view (created on first use, then cached).
    pub fn view_with(&self, desc: &ViewDesc) -> Result<vk::ImageView> {
        self.inner.view(desc, vk::ImageUsageFlags::empty())
    }
}

impl ImageInner {
    /// The subresources a view covers.
    pub(crate) fn view_range(&self, desc: &ViewDesc) -> Subresources {
        desc.subresources.unwrap_or_else(|| self.desc.all())
    }

    /// Creates or finds the view. `needs` are the usages the caller binds it for (checked
    /// against the view format's features).
    pub(crate) fn view(
        &self,
        desc: &ViewDesc,
        needs: vk::ImageUsageFlags,
    ) -> Result<vk::ImageView> {
        let range = self.view_range(desc);
        range.check(&self.name, &self.desc)?;
        let format = desc.format.unwrap_or(self.desc.format);
        if format != self.desc.format && !self.desc.mutable_format {
            return Err(Error::InvalidArgument(format!(
                "a {format:?} view of image '{}' ({:?}) needs the image created with \
                 mutable_format()",
                self.name, self.desc.format
            )));
        }
        if format != self.desc.format
            && (texel_size(format).is_none() || texel_size(format) != texel_size(self.desc.format))
        {
            return Err(Error::InvalidArgument(format!(
                "view format {format:?} is not size-compatible with image '{}' ({:?})",
                self.name, self.desc.format
            )));
        }
        if !needs.is_empty() {
            self.shared.require_format(
                format,
                format_features_for(needs),
                &format!("a view of image '{}' used as {needs:?}", self.name),
            )?;
        }
        let view_type = desc.view_type.unwrap_or_else(|| {
            let d = ImageDesc {
                layers: range.layer_count,
                ..self.desc
            };
            if d.dim == ImageDim::Cube && range.layer_count % 6 != 0 {
                if range.layer_count == 1 {
                    vk::ImageViewType::TYPE_2D
                } else {
                    vk::ImageViewType::TYPE_2D_ARRAY
                }
            } else {
                d.default_view_type()
            }
        });
        check_view_type(&self.name, &self.desc, view_type, &range)?;
        let key = ViewDesc {
            view_type: Some(view_type),
            format: Some(format),
            subresources: Some(range),
        };
        let mut views = lock(&self.views);
        if let Some(&v) = views.get(&key) {
            return Ok(v);
        }
        // A view whose format cannot be stored to must not inherit the image's STORAGE usage.
        let mut usage = self.desc.usage;
        if !self
            .shared
            .format_features(format)
            .contains(vk::FormatFeatureFlags::STORAGE_IMAGE)
        {
            usage &= !vk::ImageUsageFlags::STORAGE;
        }
        let mut usage_info = vk::ImageViewUsageCreateInfo::default().usage(usage);
        let info = vk::ImageViewCreateInfo::default()
            .image(self.raw)
            .view_type(view_type)
            .format(format)
            .subresource_range(range.vk())
            .push_next(&mut usage_info);
        // SAFETY: the image is alive and bound; type, format and range were checked.
        let view =
            unsafe { self.shared.device.create_image_view(&info, None) }.vk("vkCreateImageView")?;
        self.shared.set_name(
            view,
            &format!(
                "{} view {format:?} mips {}+{} layers {}+{}",
                self.name, range.base_mip, range.mip_count, range.base_layer, range.layer_count
            ),
        );
        views.insert(key, view);
        Ok(view)
    }
}

/// Fails unless a `view_type` view of `range` is allowed for an image of `desc`.
fn check_view_type(
    name: &str,
    desc: &ImageDesc,
    view_type: vk::ImageViewType,
    range: &Subresources,
) -> Result<()> {
    use vk::ImageViewType as T;
    let n = range.layer_count;
    let ok = match (desc.dim, view_type) {
        (ImageDim::D3, T::TYPE_3D) => true,
        (ImageDim::D3, _) | (_, T::TYPE_3D) => false,
        (_, T::TYPE_2D) => n == 1,
        (_, T::TYPE_2D_ARRAY) => true,
        (ImageDim::Cube, T::CUBE) => n == 6,
        (ImageDim::Cube, T::CUBE_ARRAY) => n % 6 == 0,
        _ => false,
    };
    if !ok {
        return Err(Error::InvalidArgument(format!(
            "a {view_type:?} view of {n} layer(s) of image '{name}' ({:?}, {} layers) is not \
             possible",
            desc.dim, desc.layers
        )));
    }
    Ok(())
}

/// Filtering, addressing and level-of-detail of a sampler.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SamplerDesc {
    pub mag_filter: vk::Filter,
    pub min_filter: vk::Filter,
    pub mipmap_mode: vk::SamplerMipmapMode,
    /// Address modes for u, v, w.
    pub address: [vk::SamplerAddressMode; 3],
    pub border: vk::BorderColor,
    pub mip_lod_bias: f32,
    pub min_lod: f32,
    /// `vk::LOD_CLAMP_NONE` for every level.
    pub max_lod: f32,
    /// Maximum anisotropy (needs the `sampler_anisotropy` feature), `None` for off.
    pub anisotropy: Option<f32>,
    /// Unnormalized coordinates (texel units; nearest/linear, clamp, one level).
    pub unnormalized: bool,
}

impl SamplerDesc {
    /// Linear filtering and linear mip interpolation, clamp to edge, every level.
    pub fn linear() -> Self {
        SamplerDesc {
            mag_filter: vk::Filter::LINEAR,
            min_filter: vk::Filter::LINEAR,
            mipmap_mode: vk::SamplerMipmapMode::LINEAR,
            address: [vk::SamplerAddressMode::CLAMP_TO_EDGE; 3],
            border: vk::BorderColor::FLOAT_TRANSPARENT_BLACK,
            mip_lod_bias: 0.0,
            min_lod: 0.0,
            max_lod: vk::LOD_CLAMP_NONE,
            anisotropy: None,
            unnormalized: false,
        }
    }

    /// Nearest filtering and nearest mip, clamp to edge, every level.
    pub fn nearest() -> Self {
        SamplerDesc {
            mag_filter: vk::Filter::NEAREST,
            min_filter: vk::Filter::NEAREST,
            mipmap_mode: vk::SamplerMipmapMode::NEAREST,
            ..Self::linear()
        }
    }

    pub fn address(mut self, mode: vk::SamplerAddressMode) -> Self {
        self.address = [mode; 3];
        self
    }

    pub fn address_uvw(
        mut self,
        u: vk::SamplerAddressMode,
        v: vk::SamplerAddressMode,
        w: vk::SamplerAddressMode,
    ) -> Self {
        self.address = [u, v, w];
        self
    }

    pub fn border(mut self, border: vk::BorderColor) -> Self {
        self.border = border;
        self
    }

    pub fn lod(mut self, min: f32, max: f32) -> Self {
        self.min_lod = min;
        self.max_lod = max;
        self
    }

    pub fn anisotropy(mut self, max: f32) -> Self {
        self.anisotropy = Some(max);
        self
    }

    pub fn unnormalized(mut self) -> Self {
        self.unnormalized = true;
        self.mipmap_mode = vk::SamplerMipmapMode::NEAREST;
        self.min_filter = self.mag_filter;
        self.max_lod = 0.0;
        self
    }

    /// Whether any filter is linear (the image format then needs linear filtering).
    pub fn filters_linearly(&self) -> bool {
        self.mag_filter == vk::Filter::LINEAR
            || self.min_filter == vk::Filter::LINEAR
            || self.mipmap_mode == vk::SamplerMipmapMode::LINEAR
    }

    fn check(&self, ctx: &Context, name: &str) -> Result<()> {
        let bad = |why: String| Err(Error::InvalidArgument(format!("sampler '{name}': {why}")));
        if self
            .min_lod
            .partial_cmp(&self.max_lod)
            .is_none_or(|o| o.is_gt())
            || !self.mip_lod_bias.is_finite()
        {
            return bad(format!(
                "LOD range {}..{} / bias {} is invalid",
                self.min_lod, self.max_lod, self.mip_lod_bias
            ));
        }
        let limits = ctx.limits();
        if self.mip_lod_bias.abs() > limits.max_sampler_lod_bias {
            return bad(format!(
                "LOD bias {} exceeds maxSamplerLodBias = {}",
                self.mip_lod_bias, limits.max_sampler_lod_bias
            ));
        }
        if let Some(a) = self.anisotropy {
            if !ctx.features().sampler_anisotropy {
                return Err(Error::Unsupported {
                    device: ctx.info().name.clone(),
                    what: format!(
                        "anisotropic filtering for sampler '{name}': request the \
                         sampler_anisotropy feature in ContextDesc::features"
                    ),
                });
            }
            if !(1.0..=limits.max_sampler_anisotropy).contains(&a) {
                return bad(format!(
                    "anisotropy {a} is outside 1..=maxSamplerAnisotropy ({})",
                    limits.max_sampler_anisotropy
                ));
            }
        }
        if self.unnormalized {
            let clamp = self.address.iter().take(2).all(|m| {
                matches!(
                    *m,
                    vk::SamplerAddressMode::CLAMP_TO_EDGE | vk::SamplerAddressMode::CLAMP_TO_BORDER
                )
            });
            if self.min_filter != self.mag_filter
                || self.mipmap_mode != vk::SamplerMipmapMode::NEAREST
                || self.min_lod != 0.0
                || self.max_lod != 0.0
                || self.anisotropy.is_some()
                || !clamp
            {
                return bad(
                    "unnormalized coordinates need equal min/mag filters, nearest mips, LOD 0, \
                     clamp addressing and no anisotropy"
                        .into(),
                );
            }
        }
        Ok(())
    }
}

pub(crate) struct SamplerInner {
    shared: Arc<Shared>,
    pub(crate) raw: vk::Sampler,
    pub(crate) desc: SamplerDesc,
    pub(crate) name: String,
    stamp: Stamp,
}

impl Used for SamplerInner {
    fn stamp(&self, value: u64) {
        self.stamp.raise(value);
    }
}

impl Drop for SamplerInner {
    fn drop(&mut self) {
        self.shared
            .retire(self.stamp.get(), [Retired::Sampler(self.raw)]);
    }
}

/// A sampler object (the owning handle).
pub struct Sampler {
    inner: Arc<SamplerInner>,
}

impl std::fmt::Debug for Sampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sampler")
            .field("name", &self.inner.name)
            .field("desc", &self.inner.desc)
            .finish()
    }
}

impl Sampler {
    pub fn new(ctx: &Context, name: &str, desc: SamplerDesc) -> Result<Sampler> {
        desc.check(ctx, name)?;
        let mut info = vk::SamplerCreateInfo::default()
            .mag_filter(desc.mag_filter)
            .min_filter(desc.min_filter)
            .mipmap_mode(desc.mipmap_mode)
            .address_mode_u(desc.address[0])
            .address_mode_v(desc.address[1])
            .address_mode_w(desc.address[2])
            .border_color(desc.border)
            .mip_lod_bias(desc.mip_lod_bias)
            .min_lod(desc.min_lod)
            .max_lod(desc.max_lod)
            .unnormalized_coordinates(desc.unnormalized);
        if let Some(a) = desc.anisotropy {
            info = info.anisotropy_enable(true).max_anisotropy(a);
        }
        // SAFETY: valid device and create info (checked above).
        let raw = unsafe { ctx.shared.device.create_sampler(&info, None) }.vk("vkCreateSampler")?;
        ctx.shared.set_name(raw, name);
        Ok(Sampler {
            inner: Arc::new(SamplerInner {
                shared: ctx.shared.clone(),
                raw,
                desc,
                name: name.to_string(),
                stamp: Stamp::default(),
            }),
        })
    }

    pub fn raw(&self) -> vk::Sampler {
        self.inner.raw
    }

    pub fn desc(&self) -> &SamplerDesc {
        &self.inner.desc
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }

    pub(crate) fn keep(&self) -> Arc<SamplerInner> {
        self.inner.clone()
    }
}
