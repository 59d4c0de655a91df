//! The logical device: how to create one ([`ContextDesc`], [`Features`], [`MemoryConfig`]),
//! its queue, timeline semaphore and allocator, or a caller's device wrapped
//! ([`ExternalDevice`]).

use super::adapter::{
    DeviceInfo, DeviceSelector, describe_device, pick_queue_family, select_device,
};
use super::instance::{ValidationConfig, create_instance};
use super::{Context, Shared};
use crate::error::{Error, Result, VkResultExt};
use crate::gpu::memory::MemoryStats;
use crate::gpu::staging::StagingRing;
use crate::gpu::validation::MessageSink;
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{CString, c_char};
use std::mem::ManuallyDrop;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

/// Optional device features a kernel may need. Requested ones are enabled at device
/// creation; a missing one is an error naming it. [`DeviceInfo::features`] lists what a
/// device supports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Features {
    /// `shaderFloat16` (float16 arithmetic in shaders).
    pub shader_float16: bool,
    /// `shaderInt16`.
    pub shader_int16: bool,
    /// `storageBuffer16BitAccess` (16-bit types in storage buffers).
    pub storage_16bit: bool,
    /// `shaderFloat64`.
    pub shader_float64: bool,
    /// `samplerAnisotropy`.
    pub sampler_anisotropy: bool,
    /// `textureCompressionBC` (BC1-7 formats).
    pub texture_compression_bc: bool,
    /// `shaderInt64` and `shaderBufferInt64Atomics` together: 64-bit integers and 64-bit
    /// atomics on storage buffers (the compute rasteriser's depth + id keys).
    pub buffer_int64_atomics: bool,
}

impl Features {
    const NAMES: [&'static str; 7] = [
        "shaderFloat16",
        "shaderInt16",
        "storageBuffer16BitAccess",
        "shaderFloat64",
        "samplerAnisotropy",
        "textureCompressionBC",
        "shaderInt64 + shaderBufferInt64Atomics",
    ];

    fn flags(&self) -> [bool; 7] {
        [
            self.shader_float16,
            self.shader_int16,
            self.storage_16bit,
            self.shader_float64,
            self.sampler_anisotropy,
            self.texture_compression_bc,
            self.buffer_int64_atomics,
        ]
    }

    /// Names of the features in `self` that `supported` lacks.
    pub fn missing_from(&self, supported: &Features) -> Vec<&'static str> {
        self.flags()
            .iter()
            .zip(supported.flags())
            .zip(Self::NAMES)
            .filter(|((want, have), _)| **want && !*have)
            .map(|(_, n)| n)
            .collect()
    }
}

/// Memory settings of a context.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryConfig {
    /// Size of the allocator's device-local blocks (gpu-allocator default: 256 MiB).
    pub device_block_bytes: u64,
    /// Size of the allocator's host-visible blocks (gpu-allocator default: 64 MiB).
    pub host_block_bytes: u64,
    /// Size of the staging ring uploads go through (0: one-off staging buffers only).
    pub staging_ring_bytes: u64,
}

impl Default for MemoryConfig {
    fn default() -> Self {
        MemoryConfig {
            device_block_bytes: 64 << 20,
            host_block_bytes: 16 << 20,
            staging_ring_bytes: 16 << 20,
        }
    }
}

impl MemoryConfig {
    fn allocation_sizes(&self) -> gpu_allocator::AllocationSizes {
        gpu_allocator::AllocationSizes::new(self.device_block_bytes, self.host_block_bytes)
    }
}

/// Lower limits and a memory budget for a context: the device's own limits stay what it
/// reports, but vkshade checks its work against these (each only lowers, never raises, the
/// device's value). For a renderer that leaves vkshade part of the device, and for tests of
/// the refusals at limits too large to reach by real allocation on the test device (lavapipe's
/// `maxImageDimension3D` 4096 would need a multi-GiB texture).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LimitOverrides {
    /// Bytes of live allocations the context may hold at once, staging ring included: an
    /// allocation that would pass it is refused as [`Error::Limit`] naming "memory budget".
    pub memory_budget: Option<u64>,
    /// Lowers `maxStorageBufferRange`.
    pub max_storage_buffer_range: Option<u64>,
    /// Lowers `maxImageDimension3D`.
    pub max_image_dimension_3d: Option<u32>,
    /// Lowers `maxImageDimension2D`.
    pub max_image_dimension_2d: Option<u32>,
}

impl LimitOverrides {
    /// `info`'s limits lowered to these.
    fn apply(&self, info: &mut DeviceInfo) {
        let l = &mut info.limits;
        if let Some(v) = self.max_storage_buffer_range {
            l.max_storage_buffer_range = l.max_storage_buffer_range.min(v);
        }
        if let Some(v) = self.max_image_dimension_3d {
            l.max_image_dimension_3d = l.max_image_dimension_3d.min(v);
        }
        if let Some(v) = self.max_image_dimension_2d {
            l.max_image_dimension_2d = l.max_image_dimension_2d.min(v);
        }
    }
}

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    /// Which physical device to use.
    pub device: DeviceSelector,
    /// `None`: no validation layer. `Some`: the layer is required and an error if missing.
    ///
    /// Several validated contexts in one process: the layer up to at least 1.3.239 (Debian
    /// 12's) keeps each device's state in a global map it changes without a lock when an
    /// instance or device is made or destroyed (KhronosGroup/Vulkan-ValidationLayers#4391),
    /// so making or shutting down a validated context while another thread calls Vulkan
    /// through another one can crash inside the layer. Make and shut down validated contexts
    /// only while no other thread is using one (vkshade's tests run their GPU tests one at a
    /// time for this: `hold_gpu` in tests/common/mod.rs).
    pub validation: Option<ValidationConfig>,
    /// Optional features to enable (an error if the device lacks one).
    pub features: Features,
    /// Device extensions to enable, e.g. `"VK_EXT_shader_atomic_float"` (an error if missing).
    pub extensions: Vec<String>,
    /// Allocator block sizes and the staging ring's size.
    pub memory: MemoryConfig,
    /// Limits lower than the device's, and a memory budget (default: none).
    pub limits: LimitOverrides,
}

impl ContextDesc {
    /// Best device, validation with synchronization checks: what the tests use.
    pub fn validated() -> Self {
        ContextDesc {
            validation: Some(ValidationConfig::default()),
            ..ContextDesc::default()
        }
    }
}

/// A device created outside vkshade (see [`Context::from_external`]).
#[derive(Clone)]
pub struct ExternalDevice {
    /// The loader the instance was created with.
    pub entry: ash::Entry,
    /// The caller's instance (Vulkan 1.3).
    pub instance: ash::Instance,
    /// The physical device `device` was created on.
    pub physical_device: vk::PhysicalDevice,
    /// The caller's logical device.
    pub device: ash::Device,
    /// The queue vkshade submits to, behind the caller's lock (vkshade locks it for each
    /// submission; the caller locks it for its own).
    pub queue: Arc<Mutex<vk::Queue>>,
    /// The family of `queue` (compute-capable).
    pub queue_family: u32,
    /// Whether the instance has VK_EXT_debug_utils enabled.
    pub debug_utils: bool,
    /// The caller's allocator, shared; `None` makes vkshade create its own on the device.
    pub allocator: Option<Arc<Mutex<Allocator>>>,
    /// Optional features the caller enabled on the device.
    pub features: Features,
    /// Memory settings (block sizes apply only to an allocator vkshade creates).
    pub memory: MemoryConfig,
}

/// Checks the requested extensions against what `physical` offers.
fn check_extensions(
    instance: &ash::Instance,
    physical: vk::PhysicalDevice,
    info: &DeviceInfo,
    wanted: &[String],
) -> Result<Vec<CString>> {
    // SAFETY: valid physical device.
    let available = unsafe { instance.enumerate_device_extension_properties(physical) }
        .vk("vkEnumerateDeviceExtensionProperties")?;
    let mut names = Vec::new();
    for w in wanted {
        let present = available.iter().any(|e| {
            e.extension_name_as_c_str()
                .is_ok_and(|n| n.to_bytes() == w.as_bytes())
        });
        if !present {
            return Err(Error::Unsupported {
                device: info.name.clone(),
                what: format!("device extension {w}"),
            });
        }
        names.push(
            CString::new(w.as_str()).map_err(|_| {
                Error::InvalidArgument(format!("extension name {w:?} contains NUL"))
            })?,
        );
    }
    Ok(names)
}

/// Creates the logical device with one queue of `family`, the required features
/// (synchronization2, maintenance4, timelineSemaphore) and the requested optional ones.
fn create_device(
    instance: &ash::Instance,
    physical: vk::PhysicalDevice,
    info: &DeviceInfo,
    family: u32,
    desc: &ContextDesc,
) -> Result<ash::Device> {
    let missing = desc.features.missing_from(&info.features);
    if !missing.is_empty() {
        return Err(Error::Unsupported {
            device: info.name.clone(),
            what: format!("the requested feature(s) {}", missing.join(", ")),
        });
    }
    let extensions = check_extensions(instance, physical, info, &desc.extensions)?;
    let extension_ptrs: Vec<*const c_char> = extensions.iter().map(|e| e.as_ptr()).collect();
    let f = desc.features;
    let priorities = [1.0f32];
    let queue_info = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    // maintenance4 (mandatory in 1.3) allows the LocalSizeId of SPIR-V 1.6 modules and the
    // memory-requirement queries without objects.
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
        .synchronization2(true)
        .maintenance4(true);
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
        .timeline_semaphore(true)
        .shader_float16(f.shader_float16)
        .shader_buffer_int64_atomics(f.buffer_int64_atomics);
    let mut f11 =
        vk::PhysicalDeviceVulkan11Features::default().storage_buffer16_bit_access(f.storage_16bit);
    let core = vk::PhysicalDeviceFeatures::default()
        .shader_int16(f.shader_int16)
        .shader_float64(f.shader_float64)
        .shader_int64(f.buffer_int64_atomics)
        .sampler_anisotropy(f.sampler_anisotropy)
        .texture_compression_bc(f.texture_compression_bc);
    let mut features2 = vk::PhysicalDeviceFeatures2::default()
        .features(core)
        .push_next(&mut f13)
        .push_next(&mut f12)
        .push_next(&mut f11);
    let device_info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_info)
        .enabled_extension_names(&extension_ptrs)
        .push_next(&mut features2);
    // SAFETY: valid physical device and create info; features checked above.
    unsafe { instance.create_device(physical, &device_info, None) }.vk("vkCreateDevice")
}

/// Creates the timeline semaphore every submission signals.
fn create_timeline(device: &ash::Device) -> Result<vk::Semaphore> {
    let mut type_info = vk::SemaphoreTypeCreateInfo::default()
        .semaphore_type(vk::SemaphoreType::TIMELINE)
        .initial_value(0);
    let info = vk::SemaphoreCreateInfo::default().push_next(&mut type_info);
    // SAFETY: valid device with timelineSemaphore enabled.
    unsafe { device.create_semaphore(&info, None) }.vk("vkCreateSemaphore")
}

fn new_allocator(
    instance: &ash::Instance,
    device: &ash::Device,
    physical: vk::PhysicalDevice,
    memory: &MemoryConfig,
) -> Result<Allocator> {
    let mut debug_settings = gpu_allocator::AllocatorDebugSettings::default();
    debug_settings.log_leaks_on_shutdown = true;
    Allocator::new(&AllocatorCreateDesc {
        instance: instance.clone(),
        device: device.clone(),
        physical_device: physical,
        debug_settings,
        buffer_device_address: false,
        allocation_sizes: memory.allocation_sizes(),
    })
    .map_err(|source| Error::Alloc {
        name: "allocator".into(),
        source,
    })
}

impl Context {
    /// Creates the instance (validation layer and messenger chained in when requested),
    /// picks a device and creates it with one compute queue and the requested features.
    pub fn new(desc: &ContextDesc) -> Result<Context> {
        let validation = desc.validation.as_ref();
        let mut parts = create_instance(validation)?;
        let instance = parts.instance.clone();
        // SAFETY: valid instance.
        let pds =
            unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
        if pds.is_empty() {
            return Err(Error::NoDevice {
                reason: "the Vulkan loader found no physical device".into(),
            });
        }
        let infos: Vec<DeviceInfo> = pds
            .iter()
            .enumerate()
            .map(|(i, &pd)| describe_device(&instance, pd, i))
            .collect();
        let chosen = select_device(&infos, &desc.device)?;
        let physical = pds[chosen];
        let mut info = infos[chosen].clone();
        desc.limits.apply(&mut info);
        let (queue_family, _) =
            pick_queue_family(&instance, physical).ok_or_else(|| Error::NoDevice {
                reason: format!("{} has no compute queue", info.name),
            })?;
        let device = create_device(&instance, physical, &info, queue_family, desc)?;
        let setup = create_timeline(&device).and_then(|t| {
            new_allocator(&instance, &device, physical, &desc.memory).map(|a| (t, a))
        });
        let (timeline, allocator) = match setup {
            Ok(x) => x,
            Err(e) => {
                // SAFETY: only the timeline may exist on the device; destroying a null
                // semaphore is a no-op.
                unsafe { device.destroy_device(None) };
                return Err(e);
            }
        };
        // SAFETY: family and index 0 were requested at device creation.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let debug_device = parts
            .debug_instance
            .is_some()
            .then(|| ash::ext::debug_utils::Device::new(&instance, &device));
        parts.partial.instance = None; // ownership moves into Shared
        let shared = Shared {
            id: super::next_context_id(),
            _entry: parts.entry,
            instance,
            debug_instance: parts.debug_instance,
            messenger: parts.messenger,
            sink: parts.sink,
            debug_device,
            physical,
            info,
            features: desc.features,
            device,
            queue: Arc::new(Mutex::new(queue)),
            queue_family,
            allocator: ManuallyDrop::new(Arc::new(Mutex::new(allocator))),
            own_allocator: true,
            validation: validation.is_some(),
            owned: true,
            timeline,
            next_value: AtomicU64::new(0),
            graveyard: Mutex::new(Vec::new()),
            staging: Mutex::new(StagingRing::new(desc.memory.staging_ring_bytes)),
            stats: MemoryStats::default(),
            budget: AtomicU64::new(desc.limits.memory_budget.unwrap_or(u64::MAX)),
            recycled: Default::default(),
            counters: Default::default(),
        };
        shared.set_name(queue, "vkshade queue");
        shared.set_name(timeline, "vkshade timeline");
        Ok(Context {
            shared: Arc::new(shared),
        })
    }

    /// Wraps a device the caller created (a renderer's), so vkshade's kernels run on it.
    /// vkshade uses the caller's allocator when given (else makes its own), creates one
    /// timeline semaphore, and never destroys the instance, the device or the queue, nor
    /// calls `vkDeviceWaitIdle` on them: at shutdown it waits only for its own timeline.
    /// Validation messages go to the caller's own messenger.
    ///
    /// # Safety
    /// The handles must be valid and stay so until every vkshade object made from this
    /// context is dropped. The device must be Vulkan 1.3 and created with the
    /// `synchronization2`, `maintenance4` and `timelineSemaphore` features (and those in
    /// `features`); `queue` must belong to `queue_family` and support compute, and every
    /// use of it by the caller must hold its lock. A given allocator must belong to this
    /// device. With `debug_utils`, the instance must have VK_EXT_debug_utils enabled.
    pub unsafe fn from_external(ext: ExternalDevice) -> Result<Context> {
        // SAFETY: valid instance (the caller's contract).
        let index = unsafe { ext.instance.enumerate_physical_devices() }
            .ok()
            .and_then(|pds| pds.iter().position(|&p| p == ext.physical_device))
            .unwrap_or(0);
        let mut info = describe_device(&ext.instance, ext.physical_device, index);
        // SAFETY: valid handles (the caller's contract).
        let families = unsafe {
            ext.instance
                .get_physical_device_queue_family_properties(ext.physical_device)
        };
        let family = families.get(ext.queue_family as usize).ok_or_else(|| {
            Error::InvalidArgument(format!("queue family {} does not exist", ext.queue_family))
        })?;
        if !family.queue_flags.contains(vk::QueueFlags::COMPUTE) {
            return Err(Error::InvalidArgument(format!(
                "queue family {} has no compute support",
                ext.queue_family
            )));
        }
        info.limits.timestamp_valid_bits = family.timestamp_valid_bits;
        if let Err(why) = &info.usable {
            return Err(Error::NoDevice {
                reason: format!("{} is not usable: {why}", info.name),
            });
        }
        let debug_device = ext
            .debug_utils
            .then(|| ash::ext::debug_utils::Device::new(&ext.instance, &ext.device));
        let (allocator, own_allocator) = match ext.allocator {
            Some(a) => (a, false),
            None => (
                Arc::new(Mutex::new(new_allocator(
                    &ext.instance,
                    &ext.device,
                    ext.physical_device,
                    &ext.memory,
                )?)),
                true,
            ),
        };
        let timeline = create_timeline(&ext.device)?;
        Ok(Context {
            shared: Arc::new(Shared {
                id: super::next_context_id(),
                _entry: ext.entry,
                instance: ext.instance,
                debug_instance: None,
                messenger: vk::DebugUtilsMessengerEXT::null(),
                sink: MessageSink::new(Vec::new()),
                debug_device,
                physical: ext.physical_device,
                info,
                features: ext.features,
                device: ext.device,
                queue: ext.queue,
                queue_family: ext.queue_family,
                allocator: ManuallyDrop::new(allocator),
                own_allocator,
                validation: false,
                owned: false,
                timeline,
                next_value: AtomicU64::new(0),
                graveyard: Mutex::new(Vec::new()),
                staging: Mutex::new(StagingRing::new(ext.memory.staging_ring_bytes)),
                stats: MemoryStats::default(),
                budget: AtomicU64::new(u64::MAX),
                recycled: Default::default(),
                counters: Default::default(),
            }),
        })
    }

    /// The handles of this context's device, e.g. to share it with another library
    /// (see [`Context::from_external`]); the allocator is not shared.
    pub fn external_handles(&self) -> ExternalDevice {
        let s = &self.shared;
        ExternalDevice {
            entry: s._entry.clone(),
            instance: s.instance.clone(),
            physical_device: s.physical,
            device: s.device.clone(),
            queue: s.queue.clone(),
            queue_family: s.queue_family,
            debug_utils: s.debug_device.is_some(),
            allocator: None,
            features: s.features,
            memory: MemoryConfig::default(),
        }
    }
}
