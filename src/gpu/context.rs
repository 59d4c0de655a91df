//! Instance, physical-device choice, logical device, queue, allocator and validation.

use super::validation::{MessageSink, Severity, ValidationMessage, debug_callback, lock};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{CStr, CString, c_char};
use std::mem::ManuallyDrop;
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

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    pub device: DeviceSelector,
    /// `None`: no validation layer. `Some`: the layer is required and an error if missing.
    pub validation: Option<ValidationConfig>,
}

impl ContextDesc {
    /// Best device, validation with synchronization checks: what the tests use.
    pub fn validated() -> Self {
        ContextDesc {
            device: DeviceSelector::Best,
            validation: Some(ValidationConfig::default()),
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
    pub queue: vk::Queue,
    pub queue_family: u32,
    /// Whether the instance has VK_EXT_debug_utils enabled.
    pub debug_utils: bool,
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
    pub max_image_array_layers: u32,
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
    let mut features2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut sync2);
    // SAFETY: as above.
    unsafe { instance.get_physical_device_features2(pd, &mut features2) };
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
        limits: DeviceLimits {
            max_storage_buffer_range: l.max_storage_buffer_range as u64,
            max_uniform_buffer_range: l.max_uniform_buffer_range as u64,
            max_memory_allocation_size: 0, // filled below from Vulkan 1.1 properties
            max_push_constants_size: l.max_push_constants_size,
            max_image_dimension_2d: l.max_image_dimension2_d,
            max_image_dimension_3d: l.max_image_dimension3_d,
            max_image_array_layers: l.max_image_array_layers,
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
    pub device: ash::Device,
    pub queue: Mutex<vk::Queue>,
    pub queue_family: u32,
    pub allocator: ManuallyDrop<Mutex<Allocator>>,
    pub validation: bool,
    /// Whether vkshade created (and so destroys) the instance and device.
    owned: bool,
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
}

impl Drop for Shared {
    fn drop(&mut self) {
        // SAFETY: this is the last owner: every resource holding an Arc<Shared> is gone.
        unsafe {
            let _ = self.device.device_wait_idle();
            {
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
            ManuallyDrop::drop(&mut self.allocator);
            if self.owned {
                self.device.destroy_device(None);
                if let Some(di) = &self.debug_instance {
                    di.destroy_debug_utils_messenger(self.messenger, None);
                }
                self.instance.destroy_instance(None);
            }
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

impl Context {
    /// Creates the instance (validation layer and messenger chained in when requested),
    /// picks a device and creates it with one compute queue.
    pub fn new(desc: &ContextDesc) -> Result<Context> {
        let entry = load_entry()?;
        let validation = desc.validation.as_ref();
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
        let mut features =
            vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
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
                    reason: "the Vulkan loader found no driver (VK_ERROR_INCOMPATIBLE_DRIVER)"
                        .into(),
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

        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        // maintenance4 (mandatory in 1.3) allows the LocalSizeId of SPIR-V 1.6 modules.
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
            .synchronization2(true)
            .maintenance4(true);
        let mut features2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f13);
        let device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .push_next(&mut features2);
        // SAFETY: valid physical device and create info.
        let device =
            unsafe { instance.create_device(physical, &device_info, None) }.vk("vkCreateDevice")?;
        // SAFETY: family and index 0 were requested above.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let mut debug_settings = gpu_allocator::AllocatorDebugSettings::default();
        debug_settings.log_leaks_on_shutdown = true;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings,
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: nothing was created on the device yet.
                unsafe { device.destroy_device(None) };
                return Err(Error::Alloc {
                    name: "allocator".into(),
                    source,
                });
            }
        };
        let debug_device =
            has_debug_utils.then(|| ash::ext::debug_utils::Device::new(&instance, &device));
        partial.instance = None; // ownership moves into Shared
        let shared = Shared {
            _entry: entry,
            instance,
            debug_instance,
            messenger,
            sink,
            debug_device,
            physical,
            info,
            device,
            queue: Mutex::new(queue),
            queue_family,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            validation: validation.is_some(),
            owned: true,
        };
        shared.set_name(queue, "vkshade queue");
        Ok(Context {
            shared: Arc::new(shared),
        })
    }

    /// Wraps a device the caller created (a renderer's), so vkshade's kernels run on it.
    /// vkshade makes its own allocator on the device and never destroys the instance, the
    /// device or the queue; [`Context::shutdown`] (or the last resource) only frees what
    /// vkshade allocated. Validation messages go to the caller's own messenger.
    ///
    /// # Safety
    /// The handles must be valid and stay so until every vkshade object made from this
    /// context is dropped. The device must be Vulkan 1.3 and created with the
    /// `synchronization2` and `maintenance4` features, and `queue` must belong to
    /// `queue_family`, support compute, and not be used by other threads while vkshade
    /// submits to it (vkshade locks it only against its own submissions). With
    /// `debug_utils`, the instance must have VK_EXT_debug_utils enabled (object names and
    /// pass labels are then set).
    pub unsafe fn from_external(ext: ExternalDevice) -> Result<Context> {
        let mut info = describe_device(&ext.instance, ext.physical_device, 0);
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
        let mut debug_settings = gpu_allocator::AllocatorDebugSettings::default();
        debug_settings.log_leaks_on_shutdown = true;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: ext.instance.clone(),
            device: ext.device.clone(),
            physical_device: ext.physical_device,
            debug_settings,
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        })
        .map_err(|source| Error::Alloc {
            name: "allocator".into(),
            source,
        })?;
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
                device: ext.device,
                queue: Mutex::new(ext.queue),
                queue_family: ext.queue_family,
                allocator: ManuallyDrop::new(Mutex::new(allocator)),
                validation: false,
                owned: false,
            }),
        })
    }

    /// The handles of this context's device, e.g. to share it with another library
    /// (see [`Context::from_external`]).
    pub fn external_handles(&self) -> ExternalDevice {
        let s = &self.shared;
        ExternalDevice {
            entry: s._entry.clone(),
            instance: s.instance.clone(),
            physical_device: s.physical,
            device: s.device.clone(),
            queue: *lock(&s.queue),
            queue_family: s.queue_family,
            debug_utils: s.debug_device.is_some(),
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

    /// Waits until the device is idle.
    pub fn wait_idle(&self) -> Result<()> {
        let _q = lock(&self.shared.queue);
        // SAFETY: valid device; the queue lock keeps submissions out meanwhile.
        unsafe { self.shared.device.device_wait_idle() }.vk("vkDeviceWaitIdle")
    }

    /// Destroys the device now. Fails if any resource (buffer, pipeline, ...) or another
    /// clone of this context is still alive; on success returns the messages collected,
    /// including those raised while destroying the device (undestroyed objects, leaks).
    pub fn shutdown(self) -> Result<Vec<ValidationMessage>> {
        let sink = self.shared.sink.clone();
        match Arc::try_unwrap(self.shared) {
            Ok(shared) => drop(shared),
            Err(still_shared) => {
                let n = Arc::strong_count(&still_shared) - 1;
                return Err(Error::Leak(format!(
                    "{n} GPU resource(s) or context clone(s) still alive at shutdown"
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
