//! Lifetimes of Vulkan objects while the GPU may still use them.
//!
//! Every submission vkshade makes (or hands to a caller to make) signals one value of the
//! context's timeline semaphore. Each resource stamps the highest value of a submission that
//! used it ([`Stamp`]); when its last handle goes, its Vulkan objects are *retired* behind that
//! value ([`Shared::retire`]) and destroyed only once the timeline has reached it
//! ([`Shared::collect`]). A recording keeps what it touches alive until it is submitted and
//! stamped, so nothing here depends on a destructor running: a leaked submission or recorder
//! only keeps memory, it never frees early.

use super::context::Shared;
use super::validation::lock;
use crate::error::{Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::Allocation;
use std::any::Any;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// A Vulkan object (or memory) waiting for the GPU to finish with it.
pub(crate) enum Retired {
    Buffer(vk::Buffer),
    Image(vk::Image),
    View(vk::ImageView),
    Sampler(vk::Sampler),
    Memory(Allocation),
    Pipeline(vk::Pipeline),
    PipelineLayout(vk::PipelineLayout),
    SetLayout(vk::DescriptorSetLayout),
    DescriptorPool(vk::DescriptorPool),
    /// A command pool with the command buffers allocated from it (pooled for reuse).
    CommandPool(vk::CommandPool, Vec<vk::CommandBuffer>),
    /// A timestamp query pool (pooled for reuse).
    QueryPool(vk::QueryPool),
    /// A readback staging buffer (pooled for reuse).
    Readback(super::recycle::PooledBuffer),
}

/// The timeline value of the last submission that used a resource (0: none).
#[derive(Debug, Default)]
pub(crate) struct Stamp(AtomicU64);

impl Stamp {
    pub fn get(&self) -> u64 {
        self.0.load(Ordering::Acquire)
    }

    pub fn raise(&self, value: u64) {
        self.0.fetch_max(value, Ordering::AcqRel);
    }
}

/// Something a recording uses: kept alive by the recording, stamped when it is submitted.
pub(crate) trait Used: Any + Send + Sync {
    /// Records that the submission signalling `value` uses this object.
    fn stamp(&self, value: u64);
    /// Whether the host may read or write this object's memory (needs a host barrier after
    /// device writes).
    fn host_visible(&self) -> bool {
        false
    }
}

/// Objects a recording touches, deduplicated by address.
#[derive(Default)]
pub(crate) struct KeepAlive {
    items: Vec<Arc<dyn Used>>,
    seen: std::collections::HashSet<usize>,
    pub host_visible: bool,
}

impl KeepAlive {
    pub fn add(&mut self, item: Arc<dyn Used>) {
        let key = Arc::as_ptr(&item) as *const () as usize;
        if self.seen.insert(key) {
            self.host_visible |= item.host_visible();
            self.items.push(item);
        }
    }

    /// Stamps every item with `value` and releases them: from now on their destruction
    /// waits for `value`.
    pub fn stamp_all(&mut self, value: u64) {
        for item in self.items.drain(..) {
            item.stamp(value);
        }
        self.seen.clear();
    }
}

impl Shared {
    /// The highest timeline value the GPU has completed.
    pub fn completed(&self) -> u64 {
        // SAFETY: the timeline semaphore lives as long as `self`.
        unsafe { self.device.get_semaphore_counter_value(self.timeline) }.unwrap_or(0)
    }

    /// Reserves the next timeline value (signalled by the submission it is reserved for).
    pub fn reserve_value(&self) -> u64 {
        self.next_value.fetch_add(1, Ordering::AcqRel) + 1
    }

    /// Blocks until the timeline reaches `value` (or `timeout_ns` passes: `Ok(false)`).
    pub fn wait_value(&self, value: u64, timeout_ns: u64) -> Result<bool> {
        if value == 0 || self.completed() >= value {
            return Ok(true);
        }
        let sems = [self.timeline];
        let values = [value];
        let info = vk::SemaphoreWaitInfo::default()
            .semaphores(&sems)
            .values(&values);
        // SAFETY: our own timeline semaphore; waiting has no other precondition.
        match unsafe { self.device.wait_semaphores(&info, timeout_ns) } {
            Ok(()) => Ok(true),
            Err(vk::Result::TIMEOUT) => Ok(false),
            Err(e) => Err(e).vk("vkWaitSemaphores"),
        }
    }

    /// Destroys `items` once the timeline reaches `value` (at once if it has).
    pub fn retire(&self, value: u64, items: impl IntoIterator<Item = Retired>) {
        let done = self.completed();
        let mut grave = lock(&self.graveyard);
        for item in items {
            if value <= done {
                // SAFETY: every submission that used the object has completed.
                unsafe { self.reuse_or_destroy(item) };
            } else {
                grave.push((value, item));
            }
        }
    }

    /// Destroys every retired object whose submissions have completed.
    pub fn collect(&self) {
        let done = self.completed();
        let mut grave = lock(&self.graveyard);
        let (ready, waiting): (Vec<_>, Vec<_>) = grave.drain(..).partition(|(v, _)| *v <= done);
        *grave = waiting;
        drop(grave);
        for (_, item) in ready {
            // SAFETY: as in `retire`: the GPU is done with it.
            unsafe { self.reuse_or_destroy(item) };
        }
    }

    /// Number of objects still waiting for the GPU.
    pub fn retired_pending(&self) -> usize {
        lock(&self.graveyard).len()
    }

    /// Destroys one object.
    ///
    /// # Safety
    /// No pending GPU work may use `item`.
    pub(crate) unsafe fn destroy(&self, item: Retired) {
        let d = &self.device;
        // SAFETY: the caller guarantees the object is idle; each was created on this device.
        unsafe {
            match item {
                Retired::Buffer(b) => d.destroy_buffer(b, None),
                Retired::Image(i) => d.destroy_image(i, None),
                Retired::View(v) => d.destroy_image_view(v, None),
                Retired::Sampler(s) => d.destroy_sampler(s, None),
                Retired::Memory(a) => self.free_memory(a),
                Retired::Pipeline(p) => d.destroy_pipeline(p, None),
                Retired::PipelineLayout(l) => d.destroy_pipeline_layout(l, None),
                Retired::SetLayout(l) => d.destroy_descriptor_set_layout(l, None),
                Retired::DescriptorPool(p) => d.destroy_descriptor_pool(p, None),
                // Destroying a pool frees its command buffers.
                Retired::CommandPool(p, _) => d.destroy_command_pool(p, None),
                Retired::QueryPool(q) => d.destroy_query_pool(q, None),
                Retired::Readback(b) => {
                    d.destroy_buffer(b.raw, None);
                    self.free_memory(b.allocation);
                }
            }
        }
    }
}
