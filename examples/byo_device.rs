//! Bring your own device: a renderer that owns its Vulkan instance, device, queue and
//! allocator runs vkshade's ambient-occlusion kernel inside its own command buffers.
//!
//! Everything Vulkan-side is plain ash + gpu-allocator; vkshade only sees the handles through
//! [`Context::from_external`]. The example
//!
//! 1. creates a Vulkan 1.3 instance with the Khronos validation layer (synchronization
//!    validation and best practices on) and a debug messenger collecting every warning and
//!    error,
//! 2. creates a device with one compute queue and the features vkshade needs, and its own
//!    allocator,
//! 3. records the AO kernel's construction uploads and then each frame's work into its own
//!    command buffers and submits them itself, two frames in flight,
//! 4. checks every frame against vkshade's CPU implementation of the same method, and
//! 5. tears everything down in the order the handles depend on each other.
//!
//! It fails (non-zero exit) on any validation message, on a frame outside the GPU-vs-CPU
//! bound, or on a leak. Run with `cargo run --release --example byo_device`; `cargo test`
//! runs it too (tests/byo_device.rs).

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::collections::VecDeque;
use std::ffi::{CStr, c_char, c_void};
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use vkshade::gpu::{Context, ExternalDevice, Recorded};
use vkshade::kernels::ao::cpu::{self, CpuAo};
use vkshade::kernels::ao::{
    AoKernel, AoParams, DEFAULT_ANIMATION, DEFAULT_MESH, FrameReadback, PASS_OCCLUSION, PASS_POSE,
    PASS_SKIN, Prepared,
};
use vkshade::reference::ErrorStats;
use vkshade::scene::spheretree::{BuildConfig, SphereTree};

/// Frames rendered.
pub const FRAMES: usize = 8;
/// Frame slots (command pool, command buffer, fence): the most frames in flight at once.
pub const SLOTS: usize = 2;

/// GPU vs CPU bounds, the same as tests/ao.rs (`gpu_matches_the_cpu_implementation_on_testwuson`):
/// both run the same f32 operations in the same order, but Vulkan lets acos/atan be off by
/// up to 4096 ulp (~5e-4 near 1; Mesa uses polynomial approximations), sqrt and division by
/// a few ulp, and leaves FMA contraction to the driver. Per sphere that is ~1e-4, over ~35
/// spheres of random sign a few 1e-4 per vertex; a refinement or mask comparison tied at
/// that precision can flip and move one vertex by at most one sphere's share, hence the
/// loose maximum next to the tight mean and 95th percentile.
pub const MAX_ABS_BOUND: f64 = 1e-2;
pub const MAE_BOUND: f64 = 1e-4;
pub const P95_BOUND: f64 = 5e-4;
/// Fraction of vertices whose cut (spheres tested, spheres used) must match the CPU's.
pub const SAME_CUT_FRACTION: f64 = 0.995;

/// `BestPractices-vkCreateInstance-specialuse-extension-debugging`: the layer warns that
/// VK_EXT_debug_utils and VK_EXT_validation_features are debugging extensions. Enabling them
/// to debug is the point here, so this one id (and only it) is dropped.
const IGNORED_MESSAGE_IDS: [i32; 1] = [0x822806fa_u32 as i32];

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";
/// Fence and timeline waits: generous for a software rasteriser on a busy machine.
const TIMEOUT_NS: u64 = 60_000_000_000;

/// One frame's results.
#[derive(Clone, Debug)]
pub struct FrameResult {
    pub index: usize,
    /// Animation time of the pose (seconds).
    pub time: f32,
    /// GPU time of `ao skin` + `ao occlusion` (timestamp queries).
    pub gpu_ms: f64,
    pub skin_ms: f64,
    pub occlusion_ms: f64,
    /// Frames submitted and not yet waited for, right after this frame's submission.
    pub in_flight_at_submit: usize,
    /// Whether the previous frame's fence was still unsignalled when this frame was
    /// submitted (the two were genuinely on the GPU together).
    pub overlapped_previous: bool,
    pub error: ErrorStats,
    /// Vertices whose cut matches the CPU's.
    pub same_cut: usize,
    pub mean_visibility: f64,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct Summary {
    pub device: String,
    pub vertices: usize,
    pub frames: Vec<FrameResult>,
    /// The most frames submitted and not yet waited for at once.
    pub max_in_flight: usize,
    /// Frames submitted while the previous one was observed still running.
    pub overlapped_frames: usize,
    /// Largest |GPU - CPU| visibility over all frames and vertices.
    pub max_abs_error: f64,
    /// Whether every frame is within the bounds above.
    pub within_bound: bool,
    /// Validation messages collected (a run with any returns `Err`, so this is empty).
    pub validation_messages: Vec<String>,
    /// Messages dropped because their id is in `IGNORED_MESSAGE_IDS`.
    pub ignored_messages: u64,
}

/// Formats a failed Vulkan call.
fn vk_err(call: &'static str) -> impl Fn(vk::Result) -> String {
    move |r| format!("{call} failed: {r}")
}

/// Formats a vkshade error with what was being done.
fn vks_err(what: &'static str) -> impl Fn(vkshade::Error) -> String {
    move |e| format!("{what}: {e}")
}

/// Locks a mutex, taking the data over if a thread panicked while holding it (nothing here
/// leaves the data half-updated).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

// ---------------------------------------------------------------------------------------
// Validation messages

/// Where the debug callback puts messages. The messenger gets a raw pointer to it, so it
/// lives in an `Arc` that the instance guard keeps until the messenger and the instance
/// are destroyed.
#[derive(Default)]
struct Collector {
    messages: Mutex<Vec<String>>,
    ignored: Mutex<u64>,
}

fn c_text(p: *const c_char) -> String {
    if p.is_null() {
        return String::new();
    }
    // SAFETY: the layer passes NUL-terminated strings that live for the callback's duration.
    unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

/// The messenger callback: stores WARNING and ERROR messages. A panic must not unwind into
/// the Vulkan loader, so the body runs under `catch_unwind` and any panic is dropped.
unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    kind: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    let _ = std::panic::catch_unwind(|| {
        use vk::DebugUtilsMessageSeverityFlagsEXT as S;
        if data.is_null() || user_data.is_null() || !severity.intersects(S::WARNING | S::ERROR) {
            return;
        }
        // SAFETY: `user_data` is `Arc::as_ptr` of the Collector registered with this
        // messenger (and chained into vkCreateInstance); the instance guard holds that Arc
        // until after vkDestroyInstance, so it is alive whenever the layer calls us.
        let collector = unsafe { &*(user_data as *const Collector) };
        // SAFETY: non-null (checked), valid for the duration of the call.
        let data = unsafe { &*data };
        if IGNORED_MESSAGE_IDS.contains(&data.message_id_number) {
            *lock(&collector.ignored) += 1;
            return;
        }
        let level = if severity.contains(S::ERROR) {
            "ERROR"
        } else {
            "WARNING"
        };
        lock(&collector.messages).push(format!(
            "[{level} {kind:?} {} (id {:#x})] {}",
            c_text(data.p_message_id_name),
            data.message_id_number as u32,
            c_text(data.p_message)
        ));
    });
    vk::FALSE
}

// ---------------------------------------------------------------------------------------
// Instance

/// The instance, its messenger and the loader. Dropping it destroys the messenger and the
/// instance (every device must be gone by then).
struct InstanceGuard {
    entry: ash::Entry,
    instance: ash::Instance,
    debug: ash::ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
    /// Keeps the callback's target alive as long as the messenger and instance exist.
    _collector: Arc<Collector>,
}

impl Drop for InstanceGuard {
    fn drop(&mut self) {
        // SAFETY: `run` drops the device guard before this one, so the messenger is the
        // instance's only child left; it is destroyed first. The collector the callback
        // writes to is still alive (held by `self`) during both calls.
        unsafe {
            self.debug
                .destroy_debug_utils_messenger(self.messenger, None);
            self.instance.destroy_instance(None);
        }
    }
}

fn messenger_info(collector: &Arc<Collector>) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    use vk::DebugUtilsMessageSeverityFlagsEXT as S;
    use vk::DebugUtilsMessageTypeFlagsEXT as T;
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(S::WARNING | S::ERROR)
        .message_type(T::GENERAL | T::VALIDATION | T::PERFORMANCE)
        .pfn_user_callback(Some(on_message))
        .user_data(Arc::as_ptr(collector) as *mut c_void)
}

fn create_instance(collector: &Arc<Collector>) -> Result<InstanceGuard, String> {
    // SAFETY: loads the system Vulkan loader; no preconditions.
    let entry = unsafe { ash::Entry::load() }.map_err(|e| format!("no Vulkan loader: {e}"))?;
    // SAFETY: plain enumeration on a loaded entry.
    let layers = unsafe { entry.enumerate_instance_layer_properties() }
        .map_err(vk_err("vkEnumerateInstanceLayerProperties"))?;
    if !layers
        .iter()
        .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER))
    {
        return Err(
            "VK_LAYER_KHRONOS_validation is not installed (apt-get install vulkan-validationlayers)"
                .into(),
        );
    }
    let extensions = [
        ash::ext::debug_utils::NAME.as_ptr(),
        // Provided by the validation layer itself.
        ash::ext::validation_features::NAME.as_ptr(),
    ];
    let layer_names = [VALIDATION_LAYER.as_ptr()];
    let enables = [
        vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION,
        vk::ValidationFeatureEnableEXT::BEST_PRACTICES,
    ];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    // Chained into vkCreateInstance so messages of instance creation and destruction are
    // collected too (the messenger below only exists between the two).
    let mut chained = messenger_info(collector);
    let app = vk::ApplicationInfo::default()
        .application_name(c"vkshade byo_device")
        .api_version(vk::API_VERSION_1_3);
    let info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layer_names)
        .enabled_extension_names(&extensions)
        .push_next(&mut chained)
        .push_next(&mut features);
    // SAFETY: every pointer in `info` (names, app info, chained structs, the collector the
    // callback writes to) outlives the call; the collector outlives the instance (guard).
    let instance =
        unsafe { entry.create_instance(&info, None) }.map_err(vk_err("vkCreateInstance"))?;
    let debug = ash::ext::debug_utils::Instance::new(&entry, &instance);
    // SAFETY: the instance has VK_EXT_debug_utils enabled; the messenger is destroyed in
    // InstanceGuard::drop, before the instance and while the collector is alive.
    let messenger =
        match unsafe { debug.create_debug_utils_messenger(&messenger_info(collector), None) } {
            Ok(m) => m,
            Err(e) => {
                // SAFETY: the instance has no children yet.
                unsafe { instance.destroy_instance(None) };
                return Err(vk_err("vkCreateDebugUtilsMessengerEXT")(e));
            }
        };
    Ok(InstanceGuard {
        entry,
        instance,
        debug,
        messenger,
        _collector: collector.clone(),
    })
}

// ---------------------------------------------------------------------------------------
// Device

/// The logical device, its queue and the allocator. Dropping it (on an error path) waits for
/// the device, drops the allocator and destroys the device; the success path does the same
/// explicitly (see `run`).
struct DeviceGuard {
    physical: vk::PhysicalDevice,
    name: String,
    device: ash::Device,
    queue: Arc<Mutex<vk::Queue>>,
    family: u32,
    allocator: Option<Arc<Mutex<Allocator>>>,
}

impl DeviceGuard {
    /// Drops the allocator, which frees its memory blocks: every allocation made from it
    /// (vkshade's included) must be freed and vkshade's context must be gone, else this
    /// fails and leaks the allocator rather than free memory the GPU may use.
    fn drop_allocator(&mut self) -> Result<(), String> {
        let Some(shared) = self.allocator.take() else {
            return Ok(());
        };
        let allocator = match Arc::try_unwrap(shared) {
            Ok(m) => m.into_inner().unwrap_or_else(|p| p.into_inner()),
            Err(still_shared) => {
                let n = Arc::strong_count(&still_shared) - 1;
                std::mem::forget(still_shared);
                return Err(format!(
                    "the allocator is still shared by {n} other owner(s) (vkshade's context not shut down?)"
                ));
            }
        };
        let report = allocator.generate_report();
        drop(allocator);
        if report.allocations.is_empty() {
            Ok(())
        } else {
            let names: Vec<String> = report
                .allocations
                .iter()
                .map(|a| format!("'{}' ({} bytes)", a.name, a.size))
                .collect();
            Err(format!(
                "allocations alive at shutdown: {}",
                names.join(", ")
            ))
        }
    }
}

impl Drop for DeviceGuard {
    fn drop(&mut self) {
        // SAFETY: our own device. On the error path work may still be queued: wait for it
        // (we own the device, so idling it is ours to do). Then nothing uses the allocator's
        // memory or the device, and every child object was destroyed by the guards dropped
        // before this one.
        unsafe {
            let _ = self.device.device_wait_idle();
        }
        let _ = self.drop_allocator();
        // SAFETY: as above; the allocator (whose blocks are device memory) is gone.
        unsafe { self.device.destroy_device(None) };
    }
}

/// The physical device to use: the first that is Vulkan 1.3 with the features vkshade needs
/// and a compute queue, discrete GPUs first and CPU devices (lavapipe) last.
fn pick_device(inst: &InstanceGuard) -> Result<(vk::PhysicalDevice, u32, String), String> {
    let instance = &inst.instance;
    // SAFETY: valid instance.
    let devices = unsafe { instance.enumerate_physical_devices() }
        .map_err(vk_err("vkEnumeratePhysicalDevices"))?;
    let rank = |t: vk::PhysicalDeviceType| match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    };
    let mut candidates = Vec::new();
    let mut rejected = Vec::new();
    for pd in devices {
        // SAFETY: `pd` comes from this instance.
        let props = unsafe { instance.get_physical_device_properties(pd) };
        let name = props
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .push_next(&mut f13)
            .push_next(&mut f12);
        // SAFETY: as above; the chained structs outlive the call.
        unsafe { instance.get_physical_device_features2(pd, &mut f2) };
        // SAFETY: as above.
        let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
        // A compute family, preferring one with timestamps (for per-pass GPU times).
        let family = families
            .iter()
            .enumerate()
            .filter(|(_, f)| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.queue_count > 0)
            .min_by_key(|(_, f)| f.timestamp_valid_bits == 0)
            .map(|(i, _)| i as u32);
        let why = if props.api_version < vk::API_VERSION_1_3 {
            Some("not Vulkan 1.3")
        } else if f13.synchronization2 == vk::FALSE || f13.maintenance4 == vk::FALSE {
            Some("no synchronization2 / maintenance4")
        } else if f12.timeline_semaphore == vk::FALSE {
            Some("no timelineSemaphore")
        } else if family.is_none() {
            Some("no compute queue")
        } else {
            None
        };
        match (why, family) {
            (None, Some(family)) => candidates.push((rank(props.device_type), pd, family, name)),
            (why, _) => rejected.push(format!("{name}: {}", why.unwrap_or("?"))),
        }
    }
    candidates.sort_by_key(|c| c.0);
    candidates
        .into_iter()
        .next()
        .map(|(_, pd, family, name)| (pd, family, name))
        .ok_or_else(|| format!("no usable Vulkan device ({})", rejected.join("; ")))
}

fn create_device(inst: &InstanceGuard) -> Result<DeviceGuard, String> {
    let (physical, family, name) = pick_device(inst)?;
    let priorities = [1.0f32];
    let queues = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    // What vkshade's contract asks for (Context::from_external): synchronization2 and
    // maintenance4 (Vulkan 1.3), timeline semaphores (Vulkan 1.2).
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
        .synchronization2(true)
        .maintenance4(true);
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default().timeline_semaphore(true);
    let info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queues)
        .push_next(&mut f13)
        .push_next(&mut f12);
    // SAFETY: `physical` comes from this instance and supports every enabled feature
    // (checked in pick_device); the family index exists with at least one queue.
    let device = unsafe { inst.instance.create_device(physical, &info, None) }
        .map_err(vk_err("vkCreateDevice"))?;
    // SAFETY: queue 0 of `family` was requested above.
    let queue = unsafe { device.get_device_queue(family, 0) };
    let mut guard = DeviceGuard {
        physical,
        name,
        device,
        queue: Arc::new(Mutex::new(queue)),
        family,
        allocator: None,
    };
    let allocator = Allocator::new(&AllocatorCreateDesc {
        instance: inst.instance.clone(),
        device: guard.device.clone(),
        physical_device: physical,
        debug_settings: Default::default(),
        buffer_device_address: false,
        allocation_sizes: Default::default(),
    })
    .map_err(|e| format!("gpu-allocator: {e}"))?;
    guard.allocator = Some(Arc::new(Mutex::new(allocator)));
    Ok(guard)
}

// ---------------------------------------------------------------------------------------
// Frame slots

/// One frame slot: a command pool with one command buffer, and the fence of its last
/// submission.
struct Slot {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

/// The caller's command pools and fences. Dropping it waits for the fences (so no pool is
/// destroyed under a running command buffer) and destroys them.
struct Slots {
    device: ash::Device,
    slots: Vec<Slot>,
    /// Fences submitted and not yet waited for.
    pending: Vec<vk::Fence>,
}

impl Slots {
    fn new(dev: &DeviceGuard, n: usize) -> Result<Slots, String> {
        let mut slots = Slots {
            device: dev.device.clone(),
            slots: Vec::new(),
            pending: Vec::new(),
        };
        for _ in 0..n {
            // Pools are reset whole each frame: no per-buffer reset flag needed.
            let info = vk::CommandPoolCreateInfo::default()
                .flags(vk::CommandPoolCreateFlags::TRANSIENT)
                .queue_family_index(dev.family);
            // SAFETY: valid device; `family` is the device's queue family. Destroyed in Drop.
            let pool = unsafe { dev.device.create_command_pool(&info, None) }
                .map_err(vk_err("vkCreateCommandPool"))?;
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            // SAFETY: `pool` is valid; destroying the pool frees the buffer.
            let cmd = match unsafe { dev.device.allocate_command_buffers(&alloc) } {
                Ok(c) => c[0],
                Err(e) => {
                    // SAFETY: nothing allocated from the fresh pool.
                    unsafe { dev.device.destroy_command_pool(pool, None) };
                    return Err(vk_err("vkAllocateCommandBuffers")(e));
                }
            };
            // SAFETY: valid device; destroyed in Drop after being waited for.
            let fence = match unsafe {
                dev.device
                    .create_fence(&vk::FenceCreateInfo::default(), None)
            } {
                Ok(f) => f,
                Err(e) => {
                    // SAFETY: the buffer was never used.
                    unsafe { dev.device.destroy_command_pool(pool, None) };
                    return Err(vk_err("vkCreateFence")(e));
                }
            };
            slots.slots.push(Slot { pool, cmd, fence });
        }
        Ok(slots)
    }

    /// Waits for `fence` (submitted earlier) and resets it for the next submission.
    fn wait(&mut self, fence: vk::Fence) -> Result<(), String> {
        // SAFETY: `fence` is one of ours, in a pending submission.
        unsafe { self.device.wait_for_fences(&[fence], true, TIMEOUT_NS) }
            .map_err(vk_err("vkWaitForFences"))?;
        self.pending.retain(|f| *f != fence);
        // SAFETY: signalled and no longer used by any pending submission.
        unsafe { self.device.reset_fences(&[fence]) }.map_err(vk_err("vkResetFences"))
    }

    /// Destroys the pools and fences once everything submitted has completed.
    fn destroy(&mut self) -> Result<(), String> {
        let mut result = Ok(());
        if !self.pending.is_empty() {
            // SAFETY: our fences, each in a submission.
            result = unsafe { self.device.wait_for_fences(&self.pending, true, TIMEOUT_NS) }
                .map_err(vk_err("vkWaitForFences"));
            if result.is_err() {
                // Never destroy a pool whose command buffer may still run: leak them.
                self.slots.clear();
                return result;
            }
            self.pending.clear();
        }
        for s in self.slots.drain(..) {
            // SAFETY: every submission of these objects has completed (waited above or
            // by the caller), so no command buffer of the pool is pending.
            unsafe {
                self.device.destroy_fence(s.fence, None);
                self.device.destroy_command_pool(s.pool, None);
            }
        }
        result
    }
}

impl Drop for Slots {
    fn drop(&mut self) {
        let _ = self.destroy();
    }
}

// ---------------------------------------------------------------------------------------
// Submission

/// Ends `cmd` and submits it on the caller's queue with vkshade's timeline signal and the
/// caller's fence.
///
/// # Safety
/// `cmd` must be recording, and `recorded` must be what vkshade recorded into it. The
/// timeline value is reserved under the queue lock held for the submit, so no other
/// submission can come between them.
unsafe fn submit(
    dev: &DeviceGuard,
    cmd: vk::CommandBuffer,
    recorded: &mut Recorded,
    fence: vk::Fence,
) -> Result<(), String> {
    // SAFETY: `cmd` is recording (the caller's contract).
    unsafe { dev.device.end_command_buffer(cmd) }.map_err(vk_err("vkEndCommandBuffer"))?;
    // vkshade's timeline value, reserved under the lock we submit with: values are signalled
    // in the order they are handed out, whatever other threads do.
    let queue = lock(&dev.queue);
    let signals = [recorded.signal_locked(&queue)];
    let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
    let batch = vk::SubmitInfo2::default()
        .command_buffer_infos(&cmds)
        .signal_semaphore_infos(&signals);
    // SAFETY: the queue is externally synchronised by the lock we hold; `cmd` is executable
    // and everything it uses is kept alive by `recorded` (vkshade's resources, until its
    // timeline value) and by us (the pool, until the fence); the fence is unsignalled and
    // not in another submission.
    unsafe { dev.device.queue_submit2(*queue, &[batch], fence) }.map_err(vk_err("vkQueueSubmit2"))
}

/// Begins `slot`'s command buffer for one submission (after resetting its pool).
fn begin(dev: &DeviceGuard, slot: &Slot) -> Result<(), String> {
    // SAFETY: the slot's previous submission completed (its fence was waited for), so no
    // command buffer of the pool is pending.
    unsafe {
        dev.device
            .reset_command_pool(slot.pool, vk::CommandPoolResetFlags::empty())
    }
    .map_err(vk_err("vkResetCommandPool"))?;
    let info =
        vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
    // SAFETY: the buffer is in the initial state after the pool reset.
    unsafe { dev.device.begin_command_buffer(slot.cmd, &info) }
        .map_err(vk_err("vkBeginCommandBuffer"))
}

/// A frame submitted and not yet waited for.
struct InFlight {
    meta: FrameMeta,
    recorded: Recorded,
    readback: FrameReadback,
}

/// What the CPU check and the report need of a frame.
struct FrameMeta {
    index: usize,
    slot: usize,
    time: f32,
    matrices: Vec<glam::Mat4>,
    in_flight_at_submit: usize,
    overlapped_previous: bool,
}

/// Everything needed to check a frame on the CPU.
struct Twin<'a> {
    prep: &'a Prepared,
    cpu_ao: &'a CpuAo,
    params: AoParams,
}

/// A completed frame's GPU outputs, waiting for the CPU check.
struct Completed {
    frame: FrameMeta,
    timings: vkshade::gpu::Timings,
    data: vkshade::kernels::ao::FrameData,
}

/// Reads a frame's timings and outputs, once its fence has signalled (the readback
/// buffers are copied out, so nothing later can change them).
fn read(frame: InFlight) -> Result<Completed, String> {
    let InFlight {
        meta,
        recorded,
        readback,
    } = frame;
    // The fence covers the whole batch, so vkshade's timeline value has been reached and
    // this does not block on it; it reads the timestamps. The readbacks are host-readable
    // from then on.
    let timings = recorded
        .wait(TIMEOUT_NS)
        .map_err(vks_err("Recorded::wait"))?;
    let data = readback.data().map_err(vks_err("reading the frame back"))?;
    Ok(Completed {
        frame: meta,
        timings,
        data,
    })
}

/// Compares a completed frame with the CPU twin.
fn check(done: Completed, twin: &Twin<'_>) -> Result<FrameResult, String> {
    let Completed {
        frame,
        timings,
        data,
    } = done;
    let posed = cpu::skin(twin.prep, &frame.matrices);
    let cpu = twin
        .cpu_ao
        .frame(&posed, twin.prep.shape, &twin.params, None);
    let cpu_vis: Vec<f32> = cpu.iter().map(|v| v.visibility).collect();
    if data.visibility.len() != cpu_vis.len() {
        return Err(format!(
            "frame {}: {} GPU values for {} vertices",
            frame.index,
            data.visibility.len(),
            cpu_vis.len()
        ));
    }
    let same_cut = data
        .stats
        .iter()
        .zip(&cpu)
        .filter(|(g, c)| **g == [c.tested, c.used])
        .count();
    // The vertices' skinning (the pose pass) and the spheres'.
    let skin_ms =
        timings.get(PASS_POSE).unwrap_or(f64::NAN) + timings.get(PASS_SKIN).unwrap_or(f64::NAN);
    let occlusion_ms = timings.get(PASS_OCCLUSION).unwrap_or(f64::NAN);
    Ok(FrameResult {
        index: frame.index,
        time: frame.time,
        gpu_ms: skin_ms + occlusion_ms,
        skin_ms,
        occlusion_ms,
        in_flight_at_submit: frame.in_flight_at_submit,
        overlapped_previous: frame.overlapped_previous,
        error: ErrorStats::of(&data.visibility, &cpu_vis),
        same_cut,
        mean_visibility: data.visibility.iter().map(|v| *v as f64).sum::<f64>()
            / data.visibility.len().max(1) as f64,
    })
}

// ---------------------------------------------------------------------------------------
// The run

/// Creates the caller's Vulkan objects, runs [`FRAMES`] frames of AO through vkshade with
/// [`SLOTS`] frames in flight, checks them against the CPU, and tears everything down.
/// `Err` on any failure, including any validation message.
pub fn run() -> Result<Summary, String> {
    let collector = Arc::new(Collector::default());
    // Teardown order: vkshade's objects and context, our pools and fences (both inside
    // `frames`), the allocator, the device, the messenger and the instance. On an error
    // path the guards' Drop impls keep that order (locals drop in reverse).
    let inst = create_instance(&collector)?;
    let mut dev = create_device(&inst)?;
    let result = frames(&inst, &dev);
    // vkshade is gone (shut down, or dropped on an error path) when `frames` returns.
    let alloc = dev.drop_allocator();
    drop(dev);
    drop(inst);
    let messages = std::mem::take(&mut *lock(&collector.messages));
    let ignored = *lock(&collector.ignored);
    if !messages.is_empty() {
        let mut text = format!("{} validation message(s):", messages.len());
        for m in &messages {
            text.push_str("\n  ");
            text.push_str(m);
        }
        if let Err(e) = &result {
            text.push_str(&format!("\n(and the run failed: {e})"));
        }
        return Err(text);
    }
    alloc?;
    let mut summary = result?;
    summary.validation_messages = messages;
    summary.ignored_messages = ignored;
    Ok(summary)
}

/// The part of the run that uses vkshade: on return (Ok or Err) every vkshade object is gone
/// and the caller's frame slots are destroyed.
fn frames(inst: &InstanceGuard, dev: &DeviceGuard) -> Result<Summary, String> {
    // CPU side: the character, its sphere tree, the GPU layout, the CPU twin.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_MESH);
    let character = vkshade::scene::load(&path).map_err(vks_err("loading the character"))?;
    let anim = character
        .pick_animation(Some(DEFAULT_ANIMATION))
        .map_err(vks_err("animation"))?;
    let (tree, _) = SphereTree::build(&character.mesh, &BuildConfig::default())
        .map_err(vks_err("building the sphere tree"))?;
    let prep = Prepared::new(&character.mesh, &tree, character.rig.joints.len())
        .map_err(vks_err("preparing the AO inputs"))?;
    // The method without the static correction (baking it means ray-tracing the mesh, which
    // has nothing to do with bringing a device); the correction buffer stays at 1.
    let params = AoParams {
        correct: false,
        ..AoParams::default()
    };

    // SAFETY: from_external's contract: the handles are valid and stay so until `ext` and
    // everything made from it are gone: `frames` shuts `ext` down (or drops it) before
    // returning, and the caller destroys the device and instance only after that. The
    // device is Vulkan 1.3 with synchronization2, maintenance4 and timelineSemaphore
    // (create_device); `queue` is queue 0 of `queue_family`, which supports compute, and
    // every use of it here holds its lock (`submit`). The allocator was made for this device.
    // The instance has VK_EXT_debug_utils enabled (create_instance).
    let ext = unsafe {
        Context::from_external(ExternalDevice {
            entry: inst.entry.clone(),
            instance: inst.instance.clone(),
            physical_device: dev.physical,
            device: dev.device.clone(),
            queue: dev.queue.clone(),
            queue_family: dev.family,
            debug_utils: true,
            allocator: dev.allocator.clone(),
            features: Default::default(),
            memory: Default::default(),
        })
    }
    .map_err(vks_err("Context::from_external"))?;
    let mut slots = Slots::new(dev, SLOTS)?;

    // The kernel: buffers and pipelines are created now, the uploads of the mesh, tree and
    // table are recorded into our slot-0 command buffer and run when we submit it.
    begin(dev, &slots.slots[0])?;
    // SAFETY: record_into's contract: slot 0's buffer is a primary command buffer of this
    // device for `queue_family`, recording, and neither reset nor freed until it has been
    // submitted and its fence waited for. It is submitted (`submit`) with the signal of
    // this very Recorded, before any other vkshade submission or signal.
    let mut setup_rec = unsafe { ext.record_into(slots.slots[0].cmd, "byo kernel setup") }
        .map_err(vks_err("record_into"))?;
    let kernel = AoKernel::new(&mut setup_rec, &prep, params).map_err(vks_err("AoKernel::new"))?;
    let mut setup = setup_rec.finish().map_err(vks_err("finish"))?;
    let setup_fence = slots.slots[0].fence;
    // SAFETY: slot 0's buffer is recording and holds exactly what `setup` recorded; the
    // value is reserved under the queue lock of the submit.
    unsafe { submit(dev, slots.slots[0].cmd, &mut setup, setup_fence)? };
    slots.pending.push(setup_fence);
    // The uploads must be done before slot 0 is reused; waiting here also checks them.
    slots.wait(setup_fence)?;
    setup.wait(TIMEOUT_NS).map_err(vks_err("setup wait"))?;

    // The CPU twin: the same parameters and the kernel's own occlusion table.
    let cpu_ao = CpuAo::new(kernel.table().clone());
    let twin = Twin {
        prep: &prep,
        cpu_ao: &cpu_ao,
        params,
    };

    let duration = anim.map(|a| a.duration).unwrap_or(0.0);
    let mut in_flight: VecDeque<InFlight> = VecDeque::new();
    // Frames whose fence has signalled, waiting to be read (see below).
    let mut fenced = Vec::new();
    let mut max_in_flight = 0;
    for index in 0..FRAMES {
        let slot = index % SLOTS;
        // The slot is free once its previous frame (index - SLOTS) has completed: with
        // round-robin slots that is the oldest frame in flight.
        let mut oldest = None;
        if in_flight.len() == SLOTS {
            let frame = in_flight.pop_front().expect("non-empty");
            debug_assert_eq!(frame.meta.slot, slot);
            slots.wait(slots.slots[slot].fence)?;
            oldest = Some(frame);
        }
        let time = duration * index as f32 / FRAMES as f32;
        let matrices = character.rig.skinning_matrices(anim, time);
        begin(dev, &slots.slots[slot])?;
        // SAFETY: record_into's contract: as for the setup above: this slot's buffer is
        // recording, its previous submission completed, and it is submitted right below
        // with this Recorded's signal before any other vkshade submission or signal.
        let mut rec =
            unsafe { ext.record_into(slots.slots[slot].cmd, &format!("byo frame {index}")) }
                .map_err(vks_err("record_into"))?;
        kernel
            .record(&mut rec, &matrices)
            .map_err(vks_err("AoKernel::record"))?;
        let readback = kernel
            .read_back(&mut rec)
            .map_err(vks_err("AoKernel::read_back"))?;
        let mut recorded = rec.finish().map_err(vks_err("finish"))?;
        // Is the previous frame still running? (Observed, not assumed: a fast device may
        // have finished it already.)
        let overlapped_previous = match in_flight.back() {
            // SAFETY: a fence of ours, in a pending submission.
            Some(prev) => !unsafe {
                dev.device
                    .get_fence_status(slots.slots[prev.meta.slot].fence)
            }
            .map_err(vk_err("vkGetFenceStatus"))?,
            None => false,
        };
        let fence = slots.slots[slot].fence;
        // SAFETY: the slot's buffer is recording and holds exactly what `recorded` recorded;
        // the value is reserved under the queue lock of the submit.
        unsafe { submit(dev, slots.slots[slot].cmd, &mut recorded, fence)? };
        slots.pending.push(fence);
        in_flight.push_back(InFlight {
            meta: FrameMeta {
                index,
                slot,
                time,
                matrices,
                in_flight_at_submit: in_flight.len() + 1,
                overlapped_previous,
            },
            recorded,
            readback,
        });
        max_in_flight = max_in_flight.max(in_flight.len());
        fenced.extend(oldest);
    }
    while let Some(frame) = in_flight.pop_front() {
        slots.wait(slots.slots[frame.meta.slot].fence)?;
        fenced.push(frame);
    }
    // Timings and outputs are read once the loop is over. Reading a frame's timestamps
    // (vkGetQueryPoolResults, inside Recorded::wait) idles the whole queue on lavapipe:
    // measured here, a read made after frame i's fence had signalled returned only once
    // every frame submitted so far had finished. Read inside the loop, it would keep any
    // two frames from ever running together. A Recorded holds its query pool, not our
    // command buffer, and each frame has its own readback buffers, so they can wait.
    let completed = fenced
        .into_iter()
        .map(read)
        .collect::<Result<Vec<_>, _>>()?;
    // The CPU twin runs after the frame loop: it takes longer than a frame on the GPU, and
    // run inside the loop it would leave the GPU idle between frames, so no two would ever
    // be on it together.
    let done = completed
        .into_iter()
        .map(|c| check(c, &twin))
        .collect::<Result<Vec<_>, _>>()?;

    // Shutdown, in dependency order: every fence has been waited for (above); vkshade's
    // objects go, then its context (which waits for its own timeline only, never for our
    // device, and drops its clone of our allocator); then our pools and fences.
    let vertices = kernel.vertex_count();
    drop(kernel);
    let leftover = ext.shutdown().map_err(vks_err("Context::shutdown"))?;
    if !leftover.is_empty() {
        return Err(format!(
            "vkshade collected messages on an external device (expected none): {leftover:?}"
        ));
    }
    slots.destroy()?;

    let max_abs_error = done.iter().map(|f| f.error.max).fold(0.0, f64::max);
    let within_bound = done.iter().all(|f| {
        f.error.max < MAX_ABS_BOUND
            && f.error.mae < MAE_BOUND
            && f.error.p95 < P95_BOUND
            && f.same_cut as f64 >= SAME_CUT_FRACTION * vertices as f64
    });
    Ok(Summary {
        device: dev.name.clone(),
        vertices,
        overlapped_frames: done.iter().filter(|f| f.overlapped_previous).count(),
        frames: done,
        max_in_flight,
        max_abs_error,
        within_bound,
        validation_messages: Vec::new(),
        ignored_messages: 0,
    })
}

/// Prints a summary.
pub fn print(s: &Summary) {
    println!(
        "device: {}; {} vertices; {} frames, at most {} in flight, {} submitted while the previous was still running",
        s.device,
        s.vertices,
        s.frames.len(),
        s.max_in_flight,
        s.overlapped_frames
    );
    for f in &s.frames {
        println!(
            "frame {} (t = {:.3} s): GPU {:.3} ms (skin {:.3}, occlusion {:.3}); in flight {}; \
             |GPU - CPU| max {:.2e} mae {:.2e} p95 {:.2e}; same cut {}/{}; mean visibility {:.4}",
            f.index,
            f.time,
            f.gpu_ms,
            f.skin_ms,
            f.occlusion_ms,
            f.in_flight_at_submit,
            f.error.max,
            f.error.mae,
            f.error.p95,
            f.same_cut,
            s.vertices,
            f.mean_visibility
        );
    }
    println!(
        "max |GPU - CPU| = {:.3e} (bound {MAX_ABS_BOUND:e}; mae < {MAE_BOUND:e}, p95 < {P95_BOUND:e}): {}",
        s.max_abs_error,
        if s.within_bound { "ok" } else { "OUT OF BOUND" }
    );
    println!(
        "validation messages: {} ({} ignored by id)",
        s.validation_messages.len(),
        s.ignored_messages
    );
}

#[allow(dead_code)] // unused when tests/byo_device.rs includes this file
fn main() -> std::process::ExitCode {
    match run() {
        Ok(summary) => {
            print(&summary);
            if summary.within_bound {
                std::process::ExitCode::SUCCESS
            } else {
                eprintln!("GPU and CPU disagree beyond the bound");
                std::process::ExitCode::FAILURE
            }
        }
        Err(e) => {
            eprintln!("byo_device failed: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
