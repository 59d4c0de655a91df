//! Objects a frame loop would otherwise create and destroy every frame, kept for reuse once
//! the GPU is done with them: command pools (with their command buffers), timestamp query
//! pools and readback staging buffers. Also the count of every Vulkan object a context has
//! created, so a test (or a renderer) can check that a steady frame loop creates none.
//!
//! Pooled objects hold raw handles only (never an `Arc` of the context, which would keep it
//! alive forever); the context destroys what is still pooled when it is destroyed.

use super::context::Shared;
use super::lifetime::Retired;
use super::memory::MappedPtr;
use super::validation::lock;
use ash::vk;
use gpu_allocator::vulkan::Allocation;
use std::sync::atomic::{AtomicU64, Ordering};

/// At most this many idle command pools, and as many query pools, are kept.
const MAX_POOLS: usize = 16;
/// Idle readback buffers kept, in bytes at most.
const MAX_READBACK_BYTES: u64 = 256 << 20;

/// A readback staging buffer waiting for reuse: the buffer, its memory and its mapping.
pub(crate) struct PooledBuffer {
    pub raw: vk::Buffer,
    pub allocation: Allocation,
    pub size: u64,
    pub mapped: MappedPtr,
}

/// Idle objects ready for reuse.
#[derive(Default)]
pub(crate) struct Recycled {
    command_pools: Vec<(vk::CommandPool, Vec<vk::CommandBuffer>)>,
    query_pools: Vec<vk::QueryPool>,
    readbacks: Vec<PooledBuffer>,
}

/// How many Vulkan objects of each kind a context has created so far (never decremented).
/// After a frame loop's first frames, further frames should leave it unchanged.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CreationCounts {
    /// `vkCreateBuffer` (vkshade's own buffers, staging and readbacks included).
    pub buffers: u64,
    /// `vkCreateImage`.
    pub images: u64,
    /// Device memory allocations through the allocator.
    pub memory_allocations: u64,
    /// `vkCreateCommandPool`.
    pub command_pools: u64,
    /// `vkAllocateCommandBuffers` (one each).
    pub command_buffers: u64,
    /// `vkCreateQueryPool`.
    pub query_pools: u64,
    /// `vkCreateDescriptorPool` (one per bind group).
    pub descriptor_pools: u64,
}

/// The counters behind [`CreationCounts`].
#[derive(Default)]
pub(crate) struct Counters {
    pub buffers: AtomicU64,
    pub images: AtomicU64,
    pub memory_allocations: AtomicU64,
    pub command_pools: AtomicU64,
    pub command_buffers: AtomicU64,
    pub query_pools: AtomicU64,
    pub descriptor_pools: AtomicU64,
}

impl Counters {
    /// Counts one creation.
    pub fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The counts now.
    pub fn snapshot(&self) -> CreationCounts {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        CreationCounts {
            buffers: get(&self.buffers),
            images: get(&self.images),
            memory_allocations: get(&self.memory_allocations),
            command_pools: get(&self.command_pools),
            command_buffers: get(&self.command_buffers),
            query_pools: get(&self.query_pools),
            descriptor_pools: get(&self.descriptor_pools),
        }
    }
}

impl Shared {
    /// An idle command pool (reset, with the command buffers it holds), if one is pooled.
    pub fn take_command_pool(&self) -> Option<(vk::CommandPool, Vec<vk::CommandBuffer>)> {
        lock(&self.recycled).command_pools.pop()
    }

    /// An idle timestamp query pool, if one is pooled (the caller resets its queries).
    pub fn take_query_pool(&self) -> Option<vk::QueryPool> {
        lock(&self.recycled).query_pools.pop()
    }

    /// The smallest idle readback buffer of at least `size` bytes, if one is pooled.
    pub fn take_readback(&self, size: u64) -> Option<PooledBuffer> {
        let mut r = lock(&self.recycled);
        let best = r
            .readbacks
            .iter()
            .enumerate()
            .filter(|(_, b)| b.size >= size)
            .min_by_key(|(_, b)| b.size)
            .map(|(i, _)| i)?;
        Some(r.readbacks.swap_remove(best))
    }

    /// Keeps `item` for reuse if it is a kind vkshade pools (and the pool has room), else
    /// destroys it.
    ///
    /// # Safety
    /// No pending GPU work may use `item`.
    pub(crate) unsafe fn reuse_or_destroy(&self, item: Retired) {
        let item = match item {
            Retired::CommandPool(pool, cmds) if pool != vk::CommandPool::null() => {
                let mut r = lock(&self.recycled);
                // SAFETY: the caller guarantees none of the pool's command buffers is pending.
                let reset = unsafe {
                    self.device
                        .reset_command_pool(pool, vk::CommandPoolResetFlags::empty())
                };
                if r.command_pools.len() < MAX_POOLS && reset.is_ok() {
                    r.command_pools.push((pool, cmds));
                    return;
                }
                Retired::CommandPool(pool, cmds)
            }
            Retired::QueryPool(pool) if pool != vk::QueryPool::null() => {
                let mut r = lock(&self.recycled);
                if r.query_pools.len() < MAX_POOLS {
                    r.query_pools.push(pool);
                    return;
                }
                Retired::QueryPool(pool)
            }
            Retired::Readback(b) => {
                let mut r = lock(&self.recycled);
                let held: u64 = r.readbacks.iter().map(|b| b.size).sum();
                if held + b.size <= MAX_READBACK_BYTES {
                    r.readbacks.push(b);
                    return;
                }
                Retired::Readback(b)
            }
            other => other,
        };
        // SAFETY: as the caller guarantees.
        unsafe { self.destroy(item) };
    }

    /// Destroys everything pooled (the context is going away).
    ///
    /// # Safety
    /// The GPU must be idle with respect to vkshade's work.
    pub(crate) unsafe fn destroy_recycled(&self) {
        let r = std::mem::take(&mut *lock(&self.recycled));
        let items = r
            .command_pools
            .into_iter()
            .map(|(p, c)| Retired::CommandPool(p, c))
            .chain(r.query_pools.into_iter().map(Retired::QueryPool))
            .chain(r.readbacks.into_iter().map(Retired::Readback));
        for item in items {
            // SAFETY: pooled objects are idle (they were pooled once their work completed).
            unsafe { self.destroy(item) };
        }
    }
}
