//! Instance, physical-device choice, logical device, queue, allocator and validation.

use super::lifetime::Retired;
use super::memory::MemoryStats;
use super::staging::StagingRing;
use super::validation::{MessageSink, Severity, ValidationMessage, debug_callback, lock};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{CStr, CString, c_char};
use std::mem::ManuallyDrop;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";
/// The API version vkshade needs: synchronization2 and vkCmdWriteTimestamp2 are core in 1.3.
pub const REQUIRED_API: u32 = vk::API_VERSION_1_3;

/// Which physical device to use.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum DeviceSelector {
    /// Discrete GPU first, then integrated, virtual, and CPU (lavapipe) last.
    #[default]
    Best,
    /// Index in the order `vkshade info` lists them.
    Index(usize),
    /// Case-insensitive substring of the device name.
    Name(String),
}

impl std::str::FromStr for DeviceSelector {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        Ok(match s.parse::<usize>() {
            Ok(i) => DeviceSelector::Index(i),
            Err(_) if s.is_empty() || s.eq_ignore_ascii_case("best") => DeviceSelector::Best,
            Err(_) => DeviceSelector::Name(s.to_string()),
        })
    }
}

/// What the Khronos validation layer checks.
#[derive(Clone, Debug)]
pub struct ValidationConfig {
    /// Synchronization validation (hazards between accesses); on by default.
    pub synchronization: bool,
    /// Best-practices warnings.
    pub best_practices: bool,
    /// GPU-assisted validation (instrumented shaders; slow).
    pub gpu_assisted: bool,
    /// `messageIdNumber`s to drop (documented false positives only).
    pub ignored_ids: Vec<i32>,
}

/// Message ids ignored by default, each a documented false positive for vkshade.
pub const DEFAULT_IGNORED_IDS: &[(i32, &str)] = &[(
    0x822806fa_u32 as i32,
    "BestPractices-vkCreateInstance-specialuse-extension-debugging: warns that \
     VK_EXT_debug_utils / VK_EXT_validation_features are debugging extensions; enabling them \
     for debugging is exactly what a validated context does",
)];

impl Default for ValidationConfig {
    fn default() -> Self {
        ValidationConfig {
            synchronization: true,
            best_practices: true,
            gpu_assisted: false,
            ignored_ids: DEFAULT_IGNORED_IDS.iter().map(|(id, _)| *id).collect(),
        }
    }
}

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
}

impl Features {
    const NAMES: [&'static str; 6] = [
        "shaderFloat16",
        "shaderInt16",
        "storageBuffer16BitAccess",
        "shaderFloat64",
        "samplerAnisotropy",
        "textureCompressionBC",
    ];

    fn flags(&self) -> [bool; 6] {
        [
            self.shader_float16,
            self.shader_int16,
            self.storage_16bit,
            self.shader_float64,
            self.sampler_anisotropy,
            self.texture_compression_bc,
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

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    pub device: DeviceSelector,
    /// `None`: no validation layer. `Some`: the layer is required and an error if missing.
    pub validation: Option<ValidationConfig>,
    /// Optional features to enable (an error if the device lacks one).
    pub features: Features,
    /// Device extensions to enable, e.g. `"VK_EXT_shader_atomic_float"` (an error if missing).
    pub extensions: Vec<String>,
    pub memory: MemoryConfig,
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
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub physical_device: vk::PhysicalDevice,
    pub device: ash::Device,
    /// The queue vkshade submits to, behind the caller's lock (vkshade locks it for each
    /// submission; the caller locks it for its own).
    pub queue: Arc<Mutex<vk::Queue>>,
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

/// The device limits that matter to the kernels.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceLimits {
    pub max_storage_buffer_range: u64,
    pub max_uniform_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    pub max_push_constants_size: u32,
    pub max_image_dimension_2d: u32,
    pub max_image_dimension_3d: u32,
    pub max_image_dimension_cube: u32,
    pub max_image_array_layers: u32,
    pub max_sampler_anisotropy: f32,
    pub max_sampler_lod_bias: f32,
    pub max_compute_shared_memory_size: u32,
    pub max_compute_work_group_invocations: u32,
    pub max_compute_work_group_size: [u32; 3],
    pub max_compute_work_group_count: [u32; 3],
    pub max_bound_descriptor_sets: u32,
    pub min_storage_buffer_offset_alignment: u64,
    pub min_uniform_buffer_offset_alignment: u64,
    pub subgroup_size: u32,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Valid bits of timestamps on the chosen queue family (0: no timestamps).
    pub timestamp_valid_bits: u32,
}

/// Identity and limits of one physical device.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceInfo {
    /// Position in the enumeration order (what `--device N` selects).
    pub index: usize,
    pub name: String,
    pub device_type: String,
    #[serde(skip)]
    pub(crate) kind: vk::PhysicalDeviceType,
    pub api_version: String,
    pub driver: String,
    pub vendor_id: u32,
    pub device_id: u32,
    /// Device-local heap size in bytes (largest device-local heap).
    pub device_local_bytes: u64,
    /// Whether the device meets vkshade's requirements, and if not why.
    pub usable: std::result::Result<(), String>,
    pub limits: DeviceLimits,
    /// Optional features the device supports.
    pub features: Features,
}

fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

fn type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

fn type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
        vk::PhysicalDeviceType::CPU => "CPU",
        _ => "other",
    }
}

/// The queue family vkshade uses: compute-capable with timestamps, preferring one that
/// also does graphics (the family a renderer shares with us).
fn pick_queue_family(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Option<(u32, u32)> {
    // SAFETY: `pd` comes from this instance.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    families
        .iter()
        .enumerate()
        .filter(|(_, f)| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.queue_count > 0)
        .min_by_key(|(_, f)| {
            (
                f.timestamp_valid_bits == 0,
                !f.queue_flags.contains(vk::QueueFlags::GRAPHICS),
            )
        })
        .map(|(i, f)| (i as u32, f.timestamp_valid_bits))
}

fn describe_device(instance: &ash::Instance, pd: vk::PhysicalDevice, index: usize) -> DeviceInfo {
    let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default()
        .push_next(&mut subgroup)
        .push_next(&mut driver);
    // SAFETY: valid handles; the chained structs live across the call.
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    let props = props2.properties;
    let mut sync2 = vk::PhysicalDeviceVulkan13Features::default();
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f11 = vk::PhysicalDeviceVulkan11Features::default();
    let mut features2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut sync2)
        .push_next(&mut f12)
        .push_next(&mut f11);
    // SAFETY: as above.
    unsafe { instance.get_physical_device_features2(pd, &mut features2) };
    let core = features2.features;
    let features = Features {
        shader_float16: f12.shader_float16 == vk::TRUE,
        shader_int16: core.shader_int16 == vk::TRUE,
        storage_16bit: f11.storage_buffer16_bit_access == vk::TRUE,
        shader_float64: core.shader_float64 == vk::TRUE,
        sampler_anisotropy: core.sampler_anisotropy == vk::TRUE,
        texture_compression_bc: core.texture_compression_bc == vk::TRUE,
    };
    // SAFETY: as above.
    let mem = unsafe { instance.get_physical_device_memory_properties(pd) };
    let device_local_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    let family = pick_queue_family(instance, pd);
    let usable = if props.api_version < REQUIRED_API {
        Err(format!(
            "Vulkan {} < 1.3 required",
            version_string(props.api_version)
        ))
    } else if sync2.synchronization2 == vk::FALSE || sync2.maintenance4 == vk::FALSE {
        Err("no synchronization2 or maintenance4 feature".into())
    } else if f12.timeline_semaphore == vk::FALSE {
        Err("no timelineSemaphore feature".into())
    } else if family.is_none() {
        Err("no compute queue family".into())
    } else {
        Ok(())
    };
    let l = &props.limits;
    let driver_name = driver
        .driver_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let driver_info = driver
        .driver_info_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    DeviceInfo {
        index,
        name: props
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|_| "<unnamed>".into()),
        device_type: type_name(props.device_type).into(),
        kind: props.device_type,
        api_version: version_string(props.api_version),
        driver: format!("{driver_name} {driver_info}").trim().to_string(),
        vendor_id: props.vendor_id,
        device_id: props.device_id,
        device_local_bytes,
        usable,
        features,
        limits: DeviceLimits {
            max_storage_buffer_range: l.max_storage_buffer_range as u64,
            max_uniform_buffer_range: l.max_uniform_buffer_range as u64,
            max_memory_allocation_size: 0, // filled below from Vulkan 1.1 properties
            max_push_constants_size: l.max_push_constants_size,
            max_image_dimension_2d: l.max_image_dimension2_d,
            max_image_dimension_3d: l.max_image_dimension3_d,
            max_image_dimension_cube: l.max_image_dimension_cube,
            max_image_array_layers: l.max_image_array_layers,
            max_sampler_anisotropy: l.max_sampler_anisotropy,
            max_sampler_lod_bias: l.max_sampler_lod_bias,
            max_compute_shared_memory_size: l.max_compute_shared_memory_size,
            max_compute_work_group_invocations: l.max_compute_work_group_invocations,
            max_compute_work_group_size: l.max_compute_work_group_size,
            max_compute_work_group_count: l.max_compute_work_group_count,
            max_bound_descriptor_sets: l.max_bound_descriptor_sets,
            min_storage_buffer_offset_alignment: l.min_storage_buffer_offset_alignment,
            min_uniform_buffer_offset_alignment: l.min_uniform_buffer_offset_alignment,
            subgroup_size: subgroup.subgroup_size,
            timestamp_period_ns: l.timestamp_period,
            timestamp_valid_bits: family.map(|f| f.1).unwrap_or(0),
        },
    }
    .with_maintenance3(instance, pd)
}

impl DeviceInfo {
    fn with_maintenance3(mut self, instance: &ash::Instance, pd: vk::PhysicalDevice) -> Self {
        let mut m3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut m3);
        // SAFETY: valid handles.
        unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
        self.limits.max_memory_allocation_size = m3.max_memory_allocation_size;
        self
    }
}

fn load_entry() -> Result<ash::Entry> {
    // SAFETY: loading the system Vulkan loader; its initialisation has no preconditions.
    unsafe { ash::Entry::load() }.map_err(|e| Error::Loader(e.to_string()))
}

fn layer_present(entry: &ash::Entry, name: &CStr) -> Result<bool> {
    // SAFETY: plain enumeration.
    let layers = unsafe { entry.enumerate_instance_layer_properties() }
        .vk("vkEnumerateInstanceLayerProperties")?;
    Ok(layers
        .iter()
        .any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == name)))
}

fn extension_present(entry: &ash::Entry, layer: Option<&CStr>, name: &CStr) -> Result<bool> {
    // SAFETY: plain enumeration.
    let exts = unsafe { entry.enumerate_instance_extension_properties(layer) }
        .vk("vkEnumerateInstanceExtensionProperties")?;
    Ok(exts
        .iter()
        .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name)))
}

/// What `vkshade info` reports: every device, and whether validation is available.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SystemInfo {
    pub loader_version: String,
    pub validation_layer: bool,
    pub devices: Vec<DeviceInfo>,
}

/// Lists the physical devices without creating a logical device.
pub fn enumerate_devices() -> Result<SystemInfo> {
    let entry = load_entry()?;
    // SAFETY: plain query.
    let loader = unsafe { entry.try_enumerate_instance_version() }
        .vk("vkEnumerateInstanceVersion")?
        .unwrap_or(vk::API_VERSION_1_0);
    let validation_layer = layer_present(&entry, VALIDATION_LAYER)?;
    let app = vk::ApplicationInfo::default()
        .application_name(c"vkshade")
        .api_version(REQUIRED_API);
    let info = vk::InstanceCreateInfo::default().application_info(&app);
    // SAFETY: valid create info; the instance is destroyed below.
    let instance = unsafe { entry.create_instance(&info, None) }.vk("vkCreateInstance")?;
    // SAFETY: valid instance.
    let pds = unsafe { instance.enumerate_physical_devices() };
    let devices = pds.map(|pds| {
        pds.iter()
            .enumerate()
            .map(|(i, &pd)| describe_device(&instance, pd, i))
            .collect()
    });
    // SAFETY: no child objects remain.
    unsafe { instance.destroy_instance(None) };
    Ok(SystemInfo {
        loader_version: version_string(loader),
        validation_layer,
        devices: devices.vk("vkEnumeratePhysicalDevices")?,
    })
}

/// Everything that must outlive every resource: resources hold an `Arc` of it.
pub(crate) struct Shared {
    // Field order is irrelevant: Drop below destroys explicitly.
    _entry: ash::Entry,
    pub instance: ash::Instance,
    debug_instance: Option<ash::ext::debug_utils::Instance>,
    messenger: vk::DebugUtilsMessengerEXT,
    /// The callback receives `Arc::as_ptr(&sink)` as user data; this Arc keeps it alive until
    /// the messenger and instance are gone.
    pub sink: Arc<MessageSink>,
    pub debug_device: Option<ash::ext::debug_utils::Device>,
    pub physical: vk::PhysicalDevice,
    pub info: DeviceInfo,
    /// Optional features enabled on the device.
    pub features: Features,
    pub device: ash::Device,
    pub queue: Arc<Mutex<vk::Queue>>,
    pub queue_family: u32,
    pub allocator: ManuallyDrop<Arc<Mutex<Allocator>>>,
    /// Whether vkshade created the allocator (and so reports its leaks).
    own_allocator: bool,
    pub validation: bool,
    /// Whether vkshade created (and so destroys) the instance and device.
    owned: bool,
    /// The timeline every submission signals (see `lifetime`).
    pub timeline: vk::Semaphore,
    /// The last timeline value handed out.
    pub next_value: AtomicU64,
    /// Objects waiting for the timeline to reach a value.
    pub graveyard: Mutex<Vec<(u64, Retired)>>,
    pub staging: Mutex<StagingRing>,
    pub stats: MemoryStats,
}

impl Shared {
    /// Names a Vulkan object for validation messages and debuggers (no-op without debug-utils).
    pub fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.debug_device {
            let name = CString::new(name.replace('\0', " ")).unwrap_or_default();
            let info = vk::DebugUtilsObjectNameInfoEXT::default()
                .object_handle(handle)
                .object_name(&name);
            // SAFETY: `handle` is a live object of this device. Naming cannot fail in a way
            // that matters, so the result is ignored.
            let _ = unsafe { du.set_debug_utils_object_name(&info) };
        }
    }

    /// The signal of timeline value `value`, for a `vkQueueSubmit2`.
    pub fn timeline_signal(&self, value: u64) -> vk::SemaphoreSubmitInfo<'static> {
        vk::SemaphoreSubmitInfo::default()
            .semaphore(self.timeline)
            .value(value)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
    }

    /// Locks the queue, reserves the next timeline value and runs `submit` with both. If
    /// `submit` fails, the value is signalled from the host (after earlier work) so nothing
    /// waits for it forever.
    pub fn submit_locked(&self, submit: impl FnOnce(vk::Queue, u64) -> Result<()>) -> Result<u64> {
        let queue = lock(&self.queue);
        let value = self.reserve_value();
        if let Err(e) = submit(*queue, value) {
            if self.wait_value(value - 1, 10_000_000_000).unwrap_or(false)
                && self.completed() < value
            {
                let info = vk::SemaphoreSignalInfo::default()
                    .semaphore(self.timeline)
                    .value(value);
                // SAFETY: our timeline; `value` exceeds the current value and no pending
                // signal is lower (everything before it completed).
                let _ = unsafe { self.device.signal_semaphore(&info) };
            }
            return Err(e);
        }
        Ok(value)
    }

    /// Waits for vkshade's own work at shutdown: device idle for a device vkshade owns, the
    /// timeline for a caller's device (never vkDeviceWaitIdle on it). False if it timed out.
    fn wait_own_work(&self) -> bool {
        if self.owned {
            // The queue lock keeps out submissions through handles shared with
            // `external_handles()`.
            let _queue = lock(&self.queue);
            // SAFETY: our own device; every queue use holds the lock we hold.
            return unsafe { self.device.device_wait_idle() }.is_ok();
        }
        let last = self.next_value.load(std::sync::atomic::Ordering::Acquire);
        self.wait_value(last, 10_000_000_000).unwrap_or(false)
    }
}

impl Drop for Shared {
    fn drop(&mut self) {
        let idle = self.wait_own_work();
        if !idle {
            // Never free what the GPU may still use: leak it, and say so.
            let n = lock(&self.graveyard).len();
            self.sink.push(ValidationMessage {
                severity: Severity::Error,
                kind: "VKSHADE".into(),
                id_number: 0,
                id_name: "vkshade-work-never-completed".into(),
                text: format!(
                    "work recorded by vkshade did not complete (a Recorded signalled but never \
                     submitted?): {n} object(s) and the staging ring are leaked"
                ),
                objects: Vec::new(),
                labels: Vec::new(),
            });
            std::mem::forget(std::mem::take(&mut *lock(&self.graveyard)));
            if let Some(a) = lock(&self.staging).allocation.take() {
                std::mem::forget(a);
            }
        }
        // SAFETY: this is the last owner: every resource holding an Arc<Shared> is gone, and
        // the GPU is idle with respect to vkshade's work (or what it may use was leaked).
        unsafe {
            for (_, item) in std::mem::take(&mut *lock(&self.graveyard)) {
                self.destroy(item);
            }
            let (buffer, allocation) = {
                let mut st = lock(&self.staging);
                (st.buffer, st.allocation.take())
            };
            if let Some(a) = allocation {
                self.device.destroy_buffer(buffer, None);
                self.free_memory(a);
            }
            if self.own_allocator {
                self.report_leaks();
            }
            if idle {
                ManuallyDrop::drop(&mut self.allocator);
                self.device.destroy_semaphore(self.timeline, None);
            } else {
                // Dropping the allocator frees every block, whatever is still in use:
                // leak it (and, below, the device) instead.
                let allocator = ManuallyDrop::take(&mut self.allocator);
                std::mem::forget(allocator);
            }
            if self.owned && idle {
                self.device.destroy_device(None);
                if let Some(di) = &self.debug_instance {
                    di.destroy_debug_utils_messenger(self.messenger, None);
                }
                self.instance.destroy_instance(None);
            }
        }
    }
}

impl Shared {
    /// Reports allocations still alive in vkshade's own allocator.
    fn report_leaks(&self) {
        let alloc = lock(&self.allocator);
        let report = alloc.generate_report();
        if !report.allocations.is_empty() {
            let names: Vec<_> = report
                .allocations
                .iter()
                .map(|a| format!("'{}' ({} bytes)", a.name, a.size))
                .collect();
            self.sink.push(ValidationMessage {
                severity: Severity::Error,
                kind: "VKSHADE".into(),
                id_number: 0,
                id_name: "vkshade-memory-leak".into(),
                text: format!("allocations alive at shutdown: {}", names.join(", ")),
                objects: Vec::new(),
                labels: Vec::new(),
            });
        }
    }
}

/// A Vulkan device with one queue, an allocator and (optionally) validation.
///
/// Cloning is cheap and shares the device. Resources keep the device alive; call
/// [`Context::shutdown`] to destroy it and collect any leak or validation report.
#[derive(Clone)]
pub struct Context {
    pub(crate) shared: Arc<Shared>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("device", &self.shared.info.name)
            .field("validation", &self.shared.validation)
            .finish()
    }
}

/// An instance with validation and messenger, before a device exists.
///
/// Fields drop in declaration order: `partial` (which destroys the instance on failure)
/// must go before the sink its messenger writes to and the loader (`entry`).
struct InstanceParts {
    /// Destroys the instance if a later step fails.
    partial: Partial,
    sink: Arc<MessageSink>,
    instance: ash::Instance,
    debug_instance: Option<ash::ext::debug_utils::Instance>,
    messenger: vk::DebugUtilsMessengerEXT,
    entry: ash::Entry,
}

/// Creates the instance, with the validation layer, its features and the messenger chained
/// in when `validation` is given.
fn create_instance(validation: Option<&ValidationConfig>) -> Result<InstanceParts> {
    let entry = load_entry()?;
    if validation.is_some() && !layer_present(&entry, VALIDATION_LAYER)? {
        return Err(Error::NoValidationLayer);
    }
    let has_debug_utils = extension_present(&entry, None, ash::ext::debug_utils::NAME)?
        || (validation.is_some()
            && extension_present(&entry, Some(VALIDATION_LAYER), ash::ext::debug_utils::NAME)?);
    if validation.is_some() && !has_debug_utils {
        return Err(Error::Unsupported {
            device: "instance".into(),
            what: "VK_EXT_debug_utils, needed to collect validation messages".into(),
        });
    }
    let has_validation_features = match validation {
        Some(_) => extension_present(
            &entry,
            Some(VALIDATION_LAYER),
            ash::ext::validation_features::NAME,
        )?,
        None => false,
    };
    let sink = MessageSink::new(
        validation
            .map(|v| v.ignored_ids.clone())
            .unwrap_or_default(),
    );
    let user_data = Arc::as_ptr(&sink) as *mut std::ffi::c_void;
    let mut layers: Vec<*const c_char> = Vec::new();
    let mut extensions: Vec<*const c_char> = Vec::new();
    if validation.is_some() {
        layers.push(VALIDATION_LAYER.as_ptr());
    }
    if has_debug_utils {
        extensions.push(ash::ext::debug_utils::NAME.as_ptr());
    }
    if has_validation_features {
        extensions.push(ash::ext::validation_features::NAME.as_ptr());
    }
    let mut enables = Vec::new();
    if let Some(v) = validation {
        if v.synchronization {
            enables.push(vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION);
        }
        if v.best_practices {
            enables.push(vk::ValidationFeatureEnableEXT::BEST_PRACTICES);
        }
        if v.gpu_assisted {
            enables.push(vk::ValidationFeatureEnableEXT::GPU_ASSISTED);
        }
        if !enables.is_empty() && !has_validation_features {
            return Err(Error::Unsupported {
                device: "validation layer".into(),
                what: "VK_EXT_validation_features (synchronization validation)".into(),
            });
        }
    }
    let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(user_data);
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let app = vk::ApplicationInfo::default()
        .application_name(c"vkshade")
        .engine_name(c"vkshade")
        .api_version(REQUIRED_API);
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions);
    if has_debug_utils {
        info = info.push_next(&mut messenger_info);
    }
    if has_validation_features && !enables.is_empty() {
        info = info.push_next(&mut features);
    }
    // SAFETY: all pointers in `info` outlive the call.
    let instance = match unsafe { entry.create_instance(&info, None) } {
        Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
            return Err(Error::NoDevice {
                reason: "the Vulkan loader found no driver (VK_ERROR_INCOMPATIBLE_DRIVER)".into(),
            });
        }
        other => other.vk("vkCreateInstance")?,
    };
    // From here on, failures must destroy what was created: `Partial` does that.
    let mut partial = Partial {
        instance: Some(instance.clone()),
        debug: None,
        messenger: vk::DebugUtilsMessengerEXT::null(),
    };
    let debug_instance =
        has_debug_utils.then(|| ash::ext::debug_utils::Instance::new(&entry, &instance));
    let messenger = match &debug_instance {
        Some(di) => {
            // SAFETY: valid create info; destroyed in Shared::drop or Partial::drop.
            unsafe { di.create_debug_utils_messenger(&messenger_info, None) }
                .vk("vkCreateDebugUtilsMessengerEXT")?
        }
        None => vk::DebugUtilsMessengerEXT::null(),
    };
    partial.debug = debug_instance.clone();
    partial.messenger = messenger;
    Ok(InstanceParts {
        entry,
        instance,
        debug_instance,
        messenger,
        sink,
        partial,
    })
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
        .shader_float16(f.shader_float16);
    let mut f11 =
        vk::PhysicalDeviceVulkan11Features::default().storage_buffer16_bit_access(f.storage_16bit);
    let core = vk::PhysicalDeviceFeatures::default()
        .shader_int16(f.shader_int16)
        .shader_float64(f.shader_float64)
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
        let info = infos[chosen].clone();
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

    /// Identity and limits of the chosen device.
    pub fn info(&self) -> &DeviceInfo {
        &self.shared.info
    }

    /// Shorthand for `info().limits`.
    pub fn limits(&self) -> &DeviceLimits {
        &self.shared.info.limits
    }

    /// The optional features enabled on the device.
    pub fn features(&self) -> &Features {
        &self.shared.features
    }

    /// Whether the validation layer is active.
    pub fn validation_enabled(&self) -> bool {
        self.shared.validation
    }

    /// The store of validation messages (shared; survives [`Context::shutdown`]).
    pub fn messages(&self) -> Arc<MessageSink> {
        self.shared.sink.clone()
    }

    /// The raw device, for callers that record their own commands alongside vkshade's.
    pub fn raw_device(&self) -> &ash::Device {
        &self.shared.device
    }

    /// The queue family index vkshade submits to.
    pub fn queue_family(&self) -> u32 {
        self.shared.queue_family
    }

    /// The timeline semaphore vkshade's submissions signal.
    pub fn timeline(&self) -> vk::Semaphore {
        self.shared.timeline
    }

    /// The highest timeline value completed.
    pub fn completed_value(&self) -> u64 {
        self.shared.completed()
    }

    /// Blocks until the timeline reaches `value` (e.g. a resource's `last_use()`), then
    /// destroys whatever was waiting for it.
    pub fn wait_for(&self, value: u64) -> Result<()> {
        let last = self
            .shared
            .next_value
            .load(std::sync::atomic::Ordering::Acquire);
        if value > last {
            return Err(Error::InvalidArgument(format!(
                "timeline value {value} was never handed out (the last is {last}): waiting \
                 for it would never end"
            )));
        }
        self.shared.wait_value(value, u64::MAX)?;
        self.shared.collect();
        Ok(())
    }

    /// Waits for every submission vkshade made or handed out on this context (its own
    /// timeline only; other work on a shared queue is not waited for).
    pub fn wait_idle(&self) -> Result<()> {
        let last = self
            .shared
            .next_value
            .load(std::sync::atomic::Ordering::Acquire);
        self.wait_for(last)
    }

    /// Destroys retired objects whose submissions have completed; returns how many still
    /// wait for the GPU. Called by vkshade itself on every recording and creation.
    pub fn maintain(&self) -> usize {
        self.shared.collect();
        self.shared.retired_pending()
    }

    /// Peak bytes of the staging ring held at once so far.
    pub fn staging_ring_peak(&self) -> u64 {
        self.shared.ring_peak()
    }

    /// Destroys the device now. Fails if any resource (buffer, pipeline, submission...)
    /// or another clone of this context is still alive; on success returns the messages
    /// collected, including those raised while destroying the device (undestroyed objects,
    /// leaks).
    pub fn shutdown(self) -> Result<Vec<ValidationMessage>> {
        let sink = self.shared.sink.clone();
        match Arc::try_unwrap(self.shared) {
            Ok(shared) => drop(shared),
            Err(still_shared) => {
                let n = Arc::strong_count(&still_shared) - 1;
                return Err(Error::Leak(format!(
                    "{n} GPU resource(s), submission(s) or context clone(s) still alive at shutdown"
                )));
            }
        }
        Ok(sink.take())
    }
}

fn select_device(infos: &[DeviceInfo], sel: &DeviceSelector) -> Result<usize> {
    let list = || {
        infos
            .iter()
            .map(|d| format!("{}: {} ({})", d.index, d.name, d.device_type))
            .collect::<Vec<_>>()
            .join("; ")
    };
    let check = |i: usize| match &infos[i].usable {
        Ok(()) => Ok(i),
        Err(why) => Err(Error::NoDevice {
            reason: format!("{} is not usable: {why}", infos[i].name),
        }),
    };
    match sel {
        DeviceSelector::Index(i) if *i < infos.len() => check(*i),
        DeviceSelector::Index(i) => Err(Error::DeviceNotFound {
            selector: i.to_string(),
            available: list(),
        }),
        DeviceSelector::Name(n) => {
            let n = n.to_lowercase();
            match infos
                .iter()
                .position(|d| d.name.to_lowercase().contains(&n))
            {
                Some(i) => check(i),
                None => Err(Error::DeviceNotFound {
                    selector: n,
                    available: list(),
                }),
            }
        }
        DeviceSelector::Best => infos
            .iter()
            .filter(|d| d.usable.is_ok())
            .min_by_key(|d| (type_rank(d.kind), d.index))
            .map(|d| d.index)
            .ok_or_else(|| Error::NoDevice {
                reason: format!("none of the devices meets the requirements: {}", {
                    infos
                        .iter()
                        .map(|d| format!("{}: {:?}", d.name, d.usable))
                        .collect::<Vec<_>>()
                        .join("; ")
                }),
            }),
    }
}

/// Destroys a half-built instance when `Context::new` fails part-way.
struct Partial {
    instance: Option<ash::Instance>,
    debug: Option<ash::ext::debug_utils::Instance>,
    messenger: vk::DebugUtilsMessengerEXT,
}

impl Drop for Partial {
    fn drop(&mut self) {
        if let Some(instance) = self.instance.take() {
            // SAFETY: only the messenger may have been created on this instance.
            unsafe {
                if let Some(d) = &self.debug
                    && self.messenger != vk::DebugUtilsMessengerEXT::null()
                {
                    d.destroy_debug_utils_messenger(self.messenger, None);
                }
                instance.destroy_instance(None);
            }
        }
    }
}
