//! Physical devices: what each offers ([`DeviceInfo`]), the queue family vkshade uses on it,
//! and which one a [`DeviceSelector`] picks.

use super::instance::{VALIDATION_LAYER, layer_present, load_entry};
use super::{Features, REQUIRED_API};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;

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

/// The device limits that matter to the kernels.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceLimits {
    /// `maxStorageBufferRange`: the most bytes one storage-buffer binding may cover.
    pub max_storage_buffer_range: u64,
    /// `maxUniformBufferRange`: the most bytes one uniform-buffer binding may cover.
    pub max_uniform_buffer_range: u64,
    /// `maxMemoryAllocationSize` (Vulkan 1.1): the largest single allocation.
    pub max_memory_allocation_size: u64,
    /// `maxPushConstantsSize`: bytes of push constants a pipeline may declare.
    pub max_push_constants_size: u32,
    /// `maxImageDimension2D`: the largest width or height of a 2D image.
    pub max_image_dimension_2d: u32,
    /// `maxImageDimension3D`: the largest extent along any axis of a 3D image.
    pub max_image_dimension_3d: u32,
    /// `maxImageDimensionCube`: the largest face size of a cube-compatible image.
    pub max_image_dimension_cube: u32,
    /// `maxImageArrayLayers`: the most array layers of an image.
    pub max_image_array_layers: u32,
    /// `maxSamplerAnisotropy`: the highest anisotropy a sampler may ask for.
    pub max_sampler_anisotropy: f32,
    /// `maxSamplerLodBias`: the largest absolute mip LOD bias of a sampler.
    pub max_sampler_lod_bias: f32,
    /// `maxComputeSharedMemorySize`: bytes of workgroup-shared memory a compute shader may use.
    pub max_compute_shared_memory_size: u32,
    /// `maxComputeWorkGroupInvocations`: the most invocations in one workgroup.
    pub max_compute_work_group_invocations: u32,
    /// `maxComputeWorkGroupSize`: the largest workgroup size per axis.
    pub max_compute_work_group_size: [u32; 3],
    /// `maxComputeWorkGroupCount`: the most workgroups one dispatch may launch per axis.
    pub max_compute_work_group_count: [u32; 3],
    /// `maxBoundDescriptorSets`: the most descriptor sets a pipeline layout may use.
    pub max_bound_descriptor_sets: u32,
    /// `minStorageBufferOffsetAlignment`: what a storage-buffer binding's offset must be a multiple of.
    pub min_storage_buffer_offset_alignment: u64,
    /// `minUniformBufferOffsetAlignment`: what a uniform-buffer binding's offset must be a multiple of.
    pub min_uniform_buffer_offset_alignment: u64,
    /// Invocations per subgroup (Vulkan 1.1 subgroup properties).
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
    /// The device name the driver reports (`<unnamed>` if it reports none).
    pub name: String,
    /// Discrete GPU, integrated GPU, virtual GPU, CPU or other, in words.
    pub device_type: String,
    #[serde(skip)]
    pub(crate) kind: vk::PhysicalDeviceType,
    /// The Vulkan version the device supports, as `major.minor.patch`.
    pub api_version: String,
    /// The driver's name and version information (Vulkan 1.2 driver properties).
    pub driver: String,
    /// PCI vendor id (a Khronos vendor id for a vendor without one).
    pub vendor_id: u32,
    /// The vendor's device id.
    pub device_id: u32,
    /// Device-local heap size in bytes (largest device-local heap).
    pub device_local_bytes: u64,
    /// Whether the device meets vkshade's requirements, and if not why.
    pub usable: std::result::Result<(), String>,
    /// The limits vkshade checks its work against.
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
pub(super) fn pick_queue_family(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
) -> Option<(u32, u32)> {
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

pub(super) fn describe_device(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    index: usize,
) -> DeviceInfo {
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
        buffer_int64_atomics: core.shader_int64 == vk::TRUE
            && f12.shader_buffer_int64_atomics == vk::TRUE,
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
        limits: DeviceLimits::from_vk(l, subgroup.subgroup_size, family.map(|f| f.1).unwrap_or(0)),
    }
    .with_maintenance3(instance, pd)
}

impl DeviceLimits {
    /// The limits of interest from the core `limits`, with the subgroup size and the
    /// timestamp bits of the chosen queue family (0: none); the maximum allocation size is
    /// left 0 for `with_maintenance3`.
    fn from_vk(
        l: &vk::PhysicalDeviceLimits,
        subgroup_size: u32,
        timestamp_valid_bits: u32,
    ) -> Self {
        DeviceLimits {
            max_storage_buffer_range: l.max_storage_buffer_range as u64,
            max_uniform_buffer_range: l.max_uniform_buffer_range as u64,
            max_memory_allocation_size: 0, // filled by with_maintenance3 (Vulkan 1.1 properties)
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
            subgroup_size,
            timestamp_period_ns: l.timestamp_period,
            timestamp_valid_bits,
        }
    }
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

/// What `vkshade info` reports: every device, and whether validation is available.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SystemInfo {
    /// The Vulkan loader's instance version, as `major.minor.patch`.
    pub loader_version: String,
    /// Whether the Khronos validation layer is installed.
    pub validation_layer: bool,
    /// Every physical device, in enumeration order.
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

pub(super) fn select_device(infos: &[DeviceInfo], sel: &DeviceSelector) -> Result<usize> {
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
