//! Images (2D, 2D arrays, cube maps, 3D; mip levels), their views, and samplers.
//!
//! An [`Image`] has a shape ([`ImageDesc`]) and any number of views, created on first use
//! and cached by [`ViewDesc`] (type, format, subresources). Formats are checked against the
//! device's format features when the image or view is created, with errors that say which
//! feature is missing.
//!
//! Here: creating an image (checks, memory, binding) and the owning handle. Beside it:
//! `desc` (shapes, subresources, regions), `format` (texel blocks and format features),
//! `view` (cached views) and `sampler`.

mod desc;
mod format;
mod sampler;
mod view;

pub use desc::{ImageDesc, ImageDim, ImageRegion, Subresources, full_mip_count};
pub use format::{FormatBlock, format_block, is_bc, texel_size};
pub(crate) use sampler::SamplerInner;
pub use sampler::{Sampler, SamplerDesc};
pub use view::ViewDesc;

use super::context::{Context, Shared};
use super::lifetime::{Retired, Stamp, Used};
use super::memory::{AliasGroup, Backing};
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use format::{format_features_for, is_depth_stencil};
use gpu_allocator::vulkan::AllocationScheme;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

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

impl ImageInner {
    /// Bytes of the allocation backing the image (every mip and layer).
    pub(crate) fn alloc_bytes(&self) -> u64 {
        self.alloc_size
    }
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

/// A Vulkan image. A shared handle, as [`super::Buffer`] is: clones are the same image (one
/// tracked state per subresource, one name), so a kernel can bind an image another kernel
/// writes (AO's posed tree, read by the environment's shadow pass); the image is retired
/// when the last clone is dropped and the work using it completes.
#[derive(Clone)]
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
    check_shape(shared, name, desc)?;
    check_format_support(shared, name, desc)
}

/// Checks the extent, mips and layers: non-empty, consistent with the dimension, and within
/// the device's limits; and that the format is a colour format.
fn check_shape(shared: &Shared, name: &str, desc: &ImageDesc) -> Result<()> {
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
        ImageDim::Cube if w != h || !desc.layers.is_multiple_of(6) => {
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
    Ok(())
}

/// Checks the device can make an image of this format with this usage, type, mips and
/// layers (and has `textureCompressionBC` for a BC format).
fn check_format_support(shared: &Shared, name: &str, desc: &ImageDesc) -> Result<()> {
    let bad = |why: String| Err(Error::InvalidArgument(format!("image '{name}': {why}")));
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
        if let Some(g) = group {
            g.check_member_context(shared, || format!("image '{name}'"))?;
        }
        let info = create_info(&desc);
        // SAFETY: valid device and create info (checked above).
        let raw = unsafe { shared.device.create_image(&info, None) }.vk("vkCreateImage")?;
        super::recycle::Counters::bump(&shared.counters.images);
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

    /// The Vulkan image, for callers that record their own commands with it.
    pub fn raw(&self) -> vk::Image {
        self.inner.raw
    }

    /// What the image is (shape, format, usage, placement).
    pub fn desc(&self) -> &ImageDesc {
        &self.inner.desc
    }

    /// The name given at creation (also its debug-utils name).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// Bytes of the image's own allocation (0 for an alias-group member or a caller's image).
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
}
