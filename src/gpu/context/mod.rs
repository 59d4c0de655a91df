//! Instance, physical-device choice, logical device, queue, allocator and validation.
//!
//! One file per stage: `instance` (loader, validation layer, messenger), `adapter` (what each
//! physical device offers and which one to use), `device` (the logical device, its queue,
//! timeline and allocator, or a caller's device wrapped). This file holds what they build:
//! [`Context`] and the state every resource shares.

mod adapter;
mod device;
mod instance;

pub use adapter::{DeviceInfo, DeviceLimits, DeviceSelector, SystemInfo, enumerate_devices};
pub use device::{ContextDesc, ExternalDevice, Features, LimitOverrides, MemoryConfig};
pub use instance::{DEFAULT_IGNORED_IDS, ValidationConfig};

use super::lifetime::Retired;
use super::memory::MemoryStats;
use super::staging::StagingRing;
use super::validation::{MessageSink, Severity, ValidationMessage, lock};
use crate::error::{Error, Result};
use ash::vk;
use gpu_allocator::vulkan::Allocator;
use std::ffi::CString;
use std::mem::ManuallyDrop;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

/// The API version vkshade needs: synchronization2 and vkCmdWriteTimestamp2 are core in 1.3.
pub const REQUIRED_API: u32 = vk::API_VERSION_1_3;

/// Everything that must outlive every resource: resources hold an `Arc` of it.
pub(crate) struct Shared {
    // Field order is irrelevant: Drop below destroys explicitly.
    /// This context's number in the process (for error messages: resources are checked
    /// against the context they are used with).
    pub id: u64,
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
    /// The most bytes of live allocations this context may hold (see
    /// [`LimitOverrides::memory_budget`]); `u64::MAX`: what the device gives.
    pub budget: AtomicU64,
    /// Idle pools and readback buffers for reuse (see `recycle`).
    pub recycled: Mutex<super::recycle::Recycled>,
    /// Objects created so far, per kind.
    pub counters: super::recycle::Counters,
}

/// The id the next context gets.
static NEXT_CONTEXT_ID: AtomicU64 = AtomicU64::new(1);

/// A fresh context id.
pub(crate) fn next_context_id() -> u64 {
    NEXT_CONTEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl Shared {
    /// How errors name this context.
    pub fn label(&self) -> String {
        format!("context #{} ({})", self.id, self.info.name)
    }

    /// Fails unless `owner` (the context that made `resource`) is this context. `user`
    /// names what uses the resource (a recorder, a pipeline, an alias group).
    pub fn check_owner(
        self: &Arc<Self>,
        owner: &Arc<Shared>,
        resource: impl FnOnce() -> String,
        user: impl FnOnce() -> String,
    ) -> Result<()> {
        if Arc::ptr_eq(self, owner) {
            return Ok(());
        }
        Err(Error::WrongContext {
            resource: resource(),
            owner: owner.label(),
            user: user(),
            context: self.label(),
        })
    }

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

    /// Locks the queue, runs `prepare` (whose failure submits nothing and reserves no
    /// value), reserves the next timeline value and runs `submit` with the queue, the value
    /// and what `prepare` made. If `submit` fails, the value is signalled from the host
    /// (after earlier work) so nothing waits for it forever.
    pub fn submit_locked<P>(
        &self,
        prepare: impl FnOnce() -> Result<P>,
        submit: impl FnOnce(vk::Queue, u64, P) -> Result<()>,
    ) -> Result<u64> {
        let queue = lock(&self.queue);
        let prepared = prepare()?;
        let value = self.reserve_value();
        if let Err(e) = submit(*queue, value, prepared) {
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
            self.destroy_recycled();
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

impl Context {
    /// This context's number in the process (as errors name it: `context #N`). Every
    /// resource belongs to the context that made it; using it with another context, even
    /// one on the same device, is an error.
    pub fn id(&self) -> u64 {
        self.shared.id
    }

    /// How many Vulkan objects of each kind this context has created so far. A steady frame
    /// loop (same work each frame) creates none after its first frames: command pools,
    /// query pools and readback buffers are reused once the GPU is done with them.
    pub fn creation_counts(&self) -> super::recycle::CreationCounts {
        self.shared.counters.snapshot()
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

    /// Sets the most bytes of live device allocations this context may hold (`None`: no
    /// budget but the device's), e.g. a renderer shrinking vkshade's share. An allocation
    /// past it fails with [`Error::Limit`] naming "memory budget" and its value; what is
    /// already allocated stays.
    pub fn set_memory_budget(&self, bytes: Option<u64>) {
        self.shared.budget.store(
            bytes.unwrap_or(u64::MAX),
            std::sync::atomic::Ordering::Release,
        );
    }

    /// The memory budget in force (`None`: none but the device's).
    pub fn memory_budget(&self) -> Option<u64> {
        match self
            .shared
            .budget
            .load(std::sync::atomic::Ordering::Acquire)
        {
            u64::MAX => None,
            b => Some(b),
        }
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
