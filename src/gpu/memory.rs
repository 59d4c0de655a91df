//! Buffers and images over gpu-allocator.
//!
//! Kernel data lives in device-local memory (`MemoryUsage::GpuOnly`) and moves through staging
//! buffers with explicit barriers, so the code is correct on discrete GPUs even though lavapipe
//! exposes a single host-visible memory type. Every resource destroys itself on drop and keeps
//! the device alive until then.

use super::context::{Context, Shared};
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use std::sync::Arc;

/// Where a resource's memory lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemoryUsage {
    /// Device-local; reached from the host only through staging copies.
    GpuOnly,
    /// Host-visible, written by the host, read by the device (staging, per-frame uniforms).
    Upload,
    /// Host-visible and cached, written by the device, read by the host.
    Readback,
}

impl MemoryUsage {
    fn location(self) -> MemoryLocation {
        match self {
            MemoryUsage::GpuOnly => MemoryLocation::GpuOnly,
            MemoryUsage::Upload => MemoryLocation::CpuToGpu,
            MemoryUsage::Readback => MemoryLocation::GpuToCpu,
        }
    }
}

/// What to create: a name (shown in validation messages), size, usage and memory.
#[derive(Clone, Debug)]
pub struct BufferDesc {
    pub name: String,
    pub size: u64,
    pub usage: vk::BufferUsageFlags,
    pub memory: MemoryUsage,
}

impl BufferDesc {
    /// A device-local storage buffer that can be copied to and from.
    pub fn storage(name: impl Into<String>, size: u64) -> Self {
        BufferDesc {
            name: name.into(),
            size,
            usage: vk::BufferUsageFlags::STORAGE_BUFFER
                | vk::BufferUsageFlags::TRANSFER_DST
                | vk::BufferUsageFlags::TRANSFER_SRC,
            memory: MemoryUsage::GpuOnly,
        }
    }
}

/// The Vulkan buffer and its memory. Destroyed when the last holder drops it: the owning
/// [`Buffer`] and any bind group or recording that uses it.
pub(crate) struct BufferInner {
    shared: Arc<Shared>,
    raw: vk::Buffer,
    allocation: Option<Allocation>,
    desc: BufferDesc,
}

impl BufferInner {
    /// The mapped bytes of a host-visible buffer.
    fn mapped(&self) -> Option<&[u8]> {
        self.allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .map(|s| &s[..self.desc.size as usize])
    }

    pub(crate) fn name(&self) -> &str {
        &self.desc.name
    }

    fn not_mapped(&self) -> Error {
        Error::InvalidArgument(format!(
            "buffer '{}' is {:?}, not host-visible; use Context::read_buffer / upload_buffer",
            self.desc.name, self.desc.memory
        ))
    }

    /// Mapped bytes of a host-visible buffer that only the caller reads (readback staging).
    pub(crate) fn mapped_bytes(&self) -> Result<&[u8]> {
        self.mapped().ok_or_else(|| self.not_mapped())
    }
}

impl Drop for BufferInner {
    fn drop(&mut self) {
        // SAFETY: the last holder is gone: no bind group or recording refers to the buffer,
        // and every submission in vkshade waits for completion. The buffer goes before its
        // memory, which may be a dedicated block freed with it.
        unsafe { self.shared.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.allocation.take() {
            let _ = lock(&self.shared.allocator).free(a);
        }
    }
}

/// A Vulkan buffer with its memory (the owning handle; host access goes through it).
pub struct Buffer {
    inner: Arc<BufferInner>,
}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("desc", &self.inner.desc)
            .finish()
    }
}

impl Buffer {
    /// Creates a buffer, refusing sizes the device cannot address: a storage buffer beyond
    /// `maxStorageBufferRange`, a uniform buffer beyond `maxUniformBufferRange`, anything
    /// beyond `maxMemoryAllocationSize`.
    pub fn new(ctx: &Context, desc: BufferDesc) -> Result<Buffer> {
        let shared = &ctx.shared;
        let limits = &shared.info.limits;
        if desc.size == 0 {
            return Err(Error::InvalidArgument(format!(
                "buffer '{}' has size 0",
                desc.name
            )));
        }
        let checks = [
            (
                vk::BufferUsageFlags::STORAGE_BUFFER,
                limits.max_storage_buffer_range,
                "maxStorageBufferRange",
            ),
            (
                vk::BufferUsageFlags::UNIFORM_BUFFER,
                limits.max_uniform_buffer_range,
                "maxUniformBufferRange",
            ),
            (
                vk::BufferUsageFlags::empty(),
                limits.max_memory_allocation_size,
                "maxMemoryAllocationSize",
            ),
        ];
        for (usage, limit, limit_name) in checks {
            if desc.usage.contains(usage) && desc.size > limit {
                return Err(Error::Limit {
                    what: format!("size in bytes of buffer '{}'", desc.name),
                    requested: desc.size,
                    limit_name,
                    limit,
                });
            }
        }
        let info = vk::BufferCreateInfo::default()
            .size(desc.size)
            .usage(desc.usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let raw = unsafe { shared.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        // SAFETY: `raw` was just created on this device.
        let requirements = unsafe { shared.device.get_buffer_memory_requirements(raw) };
        let allocation = lock(&shared.allocator).allocate(&AllocationCreateDesc {
            name: &desc.name,
            requirements,
            location: desc.memory.location(),
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: not yet bound or used.
                unsafe { shared.device.destroy_buffer(raw, None) };
                return Err(Error::Alloc {
                    name: desc.name,
                    source,
                });
            }
        };
        // SAFETY: memory from this device's allocator, sized by the requirements.
        let bound = unsafe {
            shared
                .device
                .bind_buffer_memory(raw, allocation.memory(), allocation.offset())
        };
        let inner = Arc::new(BufferInner {
            shared: shared.clone(),
            raw,
            allocation: Some(allocation),
            desc,
        });
        bound.vk("vkBindBufferMemory")?;
        shared.set_name(raw, &inner.desc.name);
        Ok(Buffer { inner })
    }

    /// A reference that keeps the Vulkan buffer alive (for bind groups and recordings).
    pub(crate) fn keep(&self) -> Arc<BufferInner> {
        self.inner.clone()
    }

    pub fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }

    pub fn size(&self) -> u64 {
        self.inner.desc.size
    }

    pub fn name(&self) -> &str {
        &self.inner.desc.name
    }

    pub fn usage(&self) -> vk::BufferUsageFlags {
        self.inner.desc.usage
    }

    pub fn memory(&self) -> MemoryUsage {
        self.inner.desc.memory
    }

    /// The mapped bytes of a host-visible buffer (`Upload` or `Readback`).
    pub fn mapped(&self) -> Result<&[u8]> {
        self.inner.mapped_bytes()
    }

    /// The mapped bytes of a host-visible buffer, writable. Host writes are visible to
    /// commands submitted afterwards (the memory is host-coherent); synchronising with work
    /// already submitted is the caller's part, as in Vulkan.
    pub fn mapped_mut(&mut self) -> Result<&mut [u8]> {
        let size = self.inner.desc.size as usize;
        let ptr = self
            .inner
            .allocation
            .as_ref()
            .and_then(|a| a.mapped_ptr())
            .ok_or_else(|| self.inner.not_mapped())?;
        // SAFETY: the mapping covers `size` bytes and lives as long as the allocation, which
        // `self.inner` keeps. `Buffer` is the only handle through which the host reads or
        // writes the mapping (bind groups and recordings hold the object, never the bytes),
        // and `&mut self` makes this borrow exclusive among them.
        Ok(unsafe { std::slice::from_raw_parts_mut(ptr.as_ptr().cast::<u8>(), size) })
    }

    /// Copies `data` into a host-visible buffer at byte `offset`.
    pub fn write<T: bytemuck::Pod>(&mut self, offset: u64, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let size = self.size();
        let end = offset
            .checked_add(bytes.len() as u64)
            .filter(|&end| end <= size)
            .ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "write of {} bytes at offset {offset} overruns buffer '{}' of {size} bytes",
                    bytes.len(),
                    self.name(),
                ))
            })?;
        self.mapped_mut()?[offset as usize..end as usize].copy_from_slice(bytes);
        Ok(())
    }
}

/// What to create for an image: 2D or 3D, one mip level.
#[derive(Clone, Debug)]
pub struct ImageDesc {
    pub name: String,
    pub format: vk::Format,
    /// Width, height, depth (depth 1 for 2D).
    pub extent: [u32; 3],
    /// Array layers (2D only).
    pub layers: u32,
    pub usage: vk::ImageUsageFlags,
}

impl ImageDesc {
    pub fn image_type(&self) -> vk::ImageType {
        if self.extent[2] > 1 {
            vk::ImageType::TYPE_3D
        } else {
            vk::ImageType::TYPE_2D
        }
    }

    fn view_type(&self) -> vk::ImageViewType {
        match (self.image_type(), self.layers) {
            (vk::ImageType::TYPE_3D, _) => vk::ImageViewType::TYPE_3D,
            (_, 1) => vk::ImageViewType::TYPE_2D,
            _ => vk::ImageViewType::TYPE_2D_ARRAY,
        }
    }

    /// Bytes per texel for the formats vkshade uses.
    pub fn texel_size(&self) -> Result<u64> {
        texel_size(self.format).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "image '{}': format {:?} is not supported by vkshade's upload/readback",
                self.name, self.format
            ))
        })
    }

    /// Size in bytes of the tightly packed contents.
    pub fn byte_size(&self) -> Result<u64> {
        Ok(self.texel_size()?
            * self.extent.iter().map(|&e| e as u64).product::<u64>()
            * self.layers as u64)
    }
}

/// Texel size in bytes of the uncompressed colour formats vkshade moves through staging.
pub fn texel_size(format: vk::Format) -> Option<u64> {
    use vk::Format as F;
    Some(match format {
        F::R8_UNORM | F::R8_UINT => 1,
        F::R8G8_UNORM | F::R16_SFLOAT | F::R16_UINT => 2,
        F::R8G8B8A8_UNORM | F::R8G8B8A8_SRGB | F::R32_SFLOAT | F::R32_UINT | F::R16G16_SFLOAT => 4,
        F::R16G16B16A16_SFLOAT | F::R32G32_SFLOAT => 8,
        F::R32G32B32A32_SFLOAT => 16,
        _ => return None,
    })
}

/// The Vulkan image, its view and memory; destroyed when the last holder drops it.
pub(crate) struct ImageInner {
    shared: Arc<Shared>,
    raw: vk::Image,
    view: vk::ImageView,
    allocation: Option<Allocation>,
    desc: ImageDesc,
}

/// A Vulkan image with one view over all of it (the owning handle).
pub struct Image {
    inner: Arc<ImageInner>,
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Image")
            .field("desc", &self.inner.desc)
            .finish()
    }
}

impl Image {
    /// Creates a device-local image, checking the extent against maxImageDimension2D/3D and
    /// maxImageArrayLayers, and the format's support for the requested usage.
    pub fn new(ctx: &Context, desc: ImageDesc) -> Result<Image> {
        let shared = &ctx.shared;
        let limits = &shared.info.limits;
        let [w, h, d] = desc.extent;
        if w == 0 || h == 0 || d == 0 || desc.layers == 0 {
            return Err(Error::InvalidArgument(format!(
                "image '{}' has an empty extent {:?} x {} layers",
                desc.name, desc.extent, desc.layers
            )));
        }
        if d > 1 && desc.layers > 1 {
            return Err(Error::InvalidArgument(format!(
                "image '{}': 3D images cannot have array layers",
                desc.name
            )));
        }
        let (max, limit_name) = if d > 1 {
            (limits.max_image_dimension_3d, "maxImageDimension3D")
        } else {
            (limits.max_image_dimension_2d, "maxImageDimension2D")
        };
        for (axis, e) in ["width", "height", "depth"].iter().zip(desc.extent) {
            if e > max {
                return Err(Error::Limit {
                    what: format!("{axis} of image '{}'", desc.name),
                    requested: e as u64,
                    limit_name,
                    limit: max as u64,
                });
            }
        }
        if desc.layers > limits.max_image_array_layers {
            return Err(Error::Limit {
                what: format!("array layers of image '{}'", desc.name),
                requested: desc.layers as u64,
                limit_name: "maxImageArrayLayers",
                limit: limits.max_image_array_layers as u64,
            });
        }
        // SAFETY: valid physical device.
        let props = unsafe {
            shared
                .instance
                .get_physical_device_format_properties(shared.physical, desc.format)
        };
        let needed = format_features_for(desc.usage);
        if !props.optimal_tiling_features.contains(needed) {
            return Err(Error::Unsupported {
                device: shared.info.name.clone(),
                what: format!(
                    "format {:?} with {:?} for image '{}' (optimal tiling has {:?})",
                    desc.format, desc.usage, desc.name, props.optimal_tiling_features
                ),
            });
        }
        let info = vk::ImageCreateInfo::default()
            .image_type(desc.image_type())
            .format(desc.format)
            .extent(vk::Extent3D {
                width: w,
                height: h,
                depth: d,
            })
            .mip_levels(1)
            .array_layers(desc.layers)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(desc.usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        // SAFETY: valid device and create info.
        let raw = unsafe { shared.device.create_image(&info, None) }.vk("vkCreateImage")?;
        // SAFETY: `raw` was just created.
        let requirements = unsafe { shared.device.get_image_memory_requirements(raw) };
        let allocation = lock(&shared.allocator).allocate(&AllocationCreateDesc {
            name: &desc.name,
            requirements,
            location: MemoryLocation::GpuOnly,
            linear: false,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: unused image.
                unsafe { shared.device.destroy_image(raw, None) };
                return Err(Error::Alloc {
                    name: desc.name,
                    source,
                });
            }
        };
        let mut image = ImageInner {
            shared: shared.clone(),
            raw,
            view: vk::ImageView::null(),
            allocation: Some(allocation),
            desc,
        };
        let a = image.allocation.as_ref().expect("just set");
        // SAFETY: memory from this device's allocator, sized by the requirements.
        unsafe { shared.device.bind_image_memory(raw, a.memory(), a.offset()) }
            .vk("vkBindImageMemory")?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(raw)
            .view_type(image.desc.view_type())
            .format(image.desc.format)
            .subresource_range(full_range(image.desc.layers));
        // SAFETY: valid bound image.
        image.view =
            unsafe { shared.device.create_image_view(&view_info, None) }.vk("vkCreateImageView")?;
        shared.set_name(raw, &image.desc.name);
        shared.set_name(image.view, &format!("{} view", image.desc.name));
        Ok(Image {
            inner: Arc::new(image),
        })
    }

    /// A reference that keeps the Vulkan image alive (for bind groups).
    pub(crate) fn keep(&self) -> Arc<ImageInner> {
        self.inner.clone()
    }

    pub fn raw(&self) -> vk::Image {
        self.inner.raw
    }

    pub fn view(&self) -> vk::ImageView {
        self.inner.view
    }

    pub fn desc(&self) -> &ImageDesc {
        &self.inner.desc
    }

    pub fn name(&self) -> &str {
        &self.inner.desc.name
    }

    /// The subresource range covering every layer (one mip level, colour aspect).
    pub fn full_range(&self) -> vk::ImageSubresourceRange {
        full_range(self.inner.desc.layers)
    }

    pub(crate) fn copy_region(&self, buffer_offset: u64) -> vk::BufferImageCopy {
        let [w, h, d] = self.inner.desc.extent;
        vk::BufferImageCopy {
            buffer_offset,
            buffer_row_length: 0,
            buffer_image_height: 0,
            image_subresource: vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: self.inner.desc.layers,
            },
            image_offset: vk::Offset3D::default(),
            image_extent: vk::Extent3D {
                width: w,
                height: h,
                depth: d,
            },
        }
    }
}

fn full_range(layers: u32) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: layers,
    }
}

fn format_features_for(usage: vk::ImageUsageFlags) -> vk::FormatFeatureFlags {
    let mut f = vk::FormatFeatureFlags::empty();
    if usage.contains(vk::ImageUsageFlags::SAMPLED) {
        f |= vk::FormatFeatureFlags::SAMPLED_IMAGE;
    }
    if usage.contains(vk::ImageUsageFlags::STORAGE) {
        f |= vk::FormatFeatureFlags::STORAGE_IMAGE;
    }
    if usage.contains(vk::ImageUsageFlags::TRANSFER_DST) {
        f |= vk::FormatFeatureFlags::TRANSFER_DST;
    }
    if usage.contains(vk::ImageUsageFlags::TRANSFER_SRC) {
        f |= vk::FormatFeatureFlags::TRANSFER_SRC;
    }
    f
}

impl Drop for ImageInner {
    fn drop(&mut self) {
        // SAFETY: as for BufferInner: the last holder is gone.
        unsafe { self.shared.device.destroy_image_view(self.view, None) };
        // SAFETY: as above; the image goes before its memory.
        unsafe { self.shared.device.destroy_image(self.raw, None) };
        if let Some(a) = self.allocation.take() {
            let _ = lock(&self.shared.allocator).free(a);
        }
    }
}

/// Filtering and addressing for sampled images.
#[derive(Clone, Copy, Debug)]
pub struct SamplerDesc {
    pub filter: vk::Filter,
    pub address_mode: vk::SamplerAddressMode,
    /// Unnormalized coordinates (texel units; nearest/clamp only).
    pub unnormalized: bool,
}

pub(crate) struct SamplerInner {
    shared: Arc<Shared>,
    raw: vk::Sampler,
}

/// A sampler object (the owning handle).
pub struct Sampler {
    inner: Arc<SamplerInner>,
}

impl Sampler {
    pub fn new(ctx: &Context, name: &str, desc: SamplerDesc) -> Result<Sampler> {
        let info = vk::SamplerCreateInfo::default()
            .mag_filter(desc.filter)
            .min_filter(desc.filter)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(desc.address_mode)
            .address_mode_v(desc.address_mode)
            .address_mode_w(desc.address_mode)
            .max_lod(0.0)
            .unnormalized_coordinates(desc.unnormalized);
        // SAFETY: valid device and create info.
        let raw = unsafe { ctx.shared.device.create_sampler(&info, None) }.vk("vkCreateSampler")?;
        ctx.shared.set_name(raw, name);
        Ok(Sampler {
            inner: Arc::new(SamplerInner {
                shared: ctx.shared.clone(),
                raw,
            }),
        })
    }

    pub fn raw(&self) -> vk::Sampler {
        self.inner.raw
    }

    pub(crate) fn keep(&self) -> Arc<SamplerInner> {
        self.inner.clone()
    }
}

impl Drop for SamplerInner {
    fn drop(&mut self) {
        // SAFETY: the last holder is gone (see BufferInner::drop).
        unsafe { self.shared.device.destroy_sampler(self.raw, None) };
    }
}
