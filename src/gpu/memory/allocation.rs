//! Allocating device memory through gpu-allocator, with the counters behind
//! [`MemoryReport`], and the backing a resource's memory comes from.

use super::{AliasGroup, AliasInner, Buffer, Dedicated, Placement};
use crate::error::{Error, Result};
use crate::gpu::context::{Context, Shared};
use crate::gpu::lifetime::Retired;
use crate::gpu::pipeline::Resource;
use crate::gpu::validation::lock;
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use std::sync::Arc;
use std::sync::atomic::Ordering;

/// Memory statistics of a context (all its resources) or a kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MemoryReport {
    /// Bytes of live allocations (sub-allocations and dedicated ones).
    pub used_bytes: u64,
    /// Bytes of device memory reserved in the allocator's blocks (used or not). For an
    /// allocator shared with a renderer this covers the renderer's allocations too.
    pub reserved_bytes: u64,
    /// Live allocations.
    pub allocations: u64,
    /// Highest `used_bytes` seen since the context was created.
    pub peak_used_bytes: u64,
    /// Bytes of the staging ring (included in the numbers above).
    pub staging_ring_bytes: u64,
}

/// Counters kept by the context (the allocator's own report gives the reserved bytes).
#[derive(Debug, Default)]
pub(crate) struct MemoryStats {
    used: std::sync::atomic::AtomicU64,
    peak: std::sync::atomic::AtomicU64,
    count: std::sync::atomic::AtomicU64,
}

impl Shared {
    /// Allocates memory for `requirements` with `placement`. `dedicated_for` names the object
    /// a dedicated allocation is made for; `prefers_dedicated` comes from the driver.
    pub(crate) fn allocate(
        &self,
        name: &str,
        requirements: vk::MemoryRequirements,
        placement: Placement,
        linear: bool,
        dedicated: (AllocationScheme, bool, bool),
    ) -> Result<Allocation> {
        let (scheme, prefers, requires) = dedicated;
        let budget = self.budget.load(Ordering::Acquire);
        if budget != u64::MAX {
            let used = self.stats.used.load(Ordering::Acquire);
            if used.saturating_add(requirements.size) > budget {
                return Err(Error::Limit {
                    what: format!(
                        "device memory for '{name}' ({} bytes on top of {used} in use)",
                        requirements.size
                    ),
                    requested: used.saturating_add(requirements.size),
                    limit_name: "memory budget",
                    limit: budget,
                });
            }
        }
        let use_dedicated = match placement.dedicated {
            Dedicated::Always => true,
            Dedicated::Auto => prefers || requires,
            Dedicated::Never => requires,
        };
        let allocation = lock(&self.allocator)
            .allocate(&AllocationCreateDesc {
                name,
                requirements,
                location: placement.location.gpu_allocator(),
                linear,
                allocation_scheme: if use_dedicated {
                    scheme
                } else {
                    AllocationScheme::GpuAllocatorManaged
                },
            })
            .map_err(|source| Error::Alloc {
                name: name.to_string(),
                source,
            })?;
        let size = allocation.size();
        let used = self.stats.used.fetch_add(size, Ordering::AcqRel) + size;
        self.stats.peak.fetch_max(used, Ordering::AcqRel);
        self.stats.count.fetch_add(1, Ordering::AcqRel);
        super::super::recycle::Counters::bump(&self.counters.memory_allocations);
        Ok(allocation)
    }

    /// Frees memory from [`Shared::allocate`].
    ///
    /// # Safety
    /// No pending GPU work may use the memory.
    pub(crate) unsafe fn free_memory(&self, allocation: Allocation) {
        self.stats
            .used
            .fetch_sub(allocation.size(), Ordering::AcqRel);
        self.stats.count.fetch_sub(1, Ordering::AcqRel);
        let _ = lock(&self.allocator).free(allocation);
    }

    pub(crate) fn memory_report(&self) -> MemoryReport {
        let report = lock(&self.allocator).generate_report();
        MemoryReport {
            used_bytes: self.stats.used.load(Ordering::Acquire),
            reserved_bytes: report.total_capacity_bytes,
            allocations: self.stats.count.load(Ordering::Acquire),
            peak_used_bytes: self.stats.peak.load(Ordering::Acquire),
            staging_ring_bytes: lock(&self.staging).capacity(),
        }
    }
}

impl Context {
    /// Memory used and reserved by this context's resources.
    pub fn memory_report(&self) -> MemoryReport {
        self.shared.memory_report()
    }

    /// The memory of a set of buffers (a kernel's): their allocations' bytes and count; the
    /// reserved, peak and ring bytes are the context's (blocks are shared).
    pub fn memory_of(&self, buffers: &[&Buffer]) -> MemoryReport {
        MemoryReport {
            used_bytes: buffers.iter().map(|b| b.allocation_size()).sum(),
            allocations: buffers.len() as u64,
            ..self.memory_report()
        }
    }

    /// As [`Context::memory_of`], over the buffers and images of `resources` (a kernel's
    /// bindings): each buffer, buffer range and image counts as given (give each resource
    /// once), the elements of an array each, a sampler not at all.
    pub fn memory_of_resources<'a>(
        &self,
        resources: impl IntoIterator<Item = Resource<'a>>,
    ) -> MemoryReport {
        fn add(res: &Resource<'_>, bytes: &mut u64, count: &mut u64) {
            let size = match res {
                Resource::Buffer(b) | Resource::BufferRange { buffer: b, .. } => {
                    b.allocation_size()
                }
                Resource::StorageImage(i) | Resource::Texture(i) | Resource::Sampled(i, _) => {
                    i.image.allocation_size()
                }
                Resource::Sampler(_) => return,
                Resource::Array(items) => {
                    return items.iter().for_each(|r| add(r, bytes, count));
                }
            };
            *bytes += size;
            *count += 1;
        }
        let (mut used_bytes, mut allocations) = (0, 0);
        for res in resources {
            add(&res, &mut used_bytes, &mut allocations);
        }
        MemoryReport {
            used_bytes,
            allocations,
            ..self.memory_report()
        }
    }
}

/// Where a resource's memory comes from.
pub(crate) enum Backing {
    /// Its own allocation (sub-allocated or dedicated), freed with it.
    Own(Allocation),
    /// Memory of an alias group, freed with the group.
    Group(Arc<AliasInner>),
    /// Memory owned by the caller ([`Buffer::from_raw`], [`Image::from_raw`](crate::gpu::Image::from_raw)).
    External,
}

impl Backing {
    pub fn size(&self) -> u64 {
        match self {
            Backing::Own(a) => a.size(),
            _ => 0,
        }
    }

    /// Stamps an alias group's memory with a use of one of its members.
    pub fn stamp(&self, value: u64) {
        if let Backing::Group(g) = self {
            g.stamp.raise(value);
        }
    }

    /// The objects to retire with the resource.
    pub fn retire(self) -> Option<Retired> {
        match self {
            Backing::Own(a) => Some(Retired::Memory(a)),
            _ => None,
        }
    }
}

/// Memory for a new buffer or image: bound in `group`, or an allocation of its own per
/// `placement` (dedicated when the policy and the driver's `dedicated` answer say so).
/// Returns the backing and where to bind.
pub(crate) fn back(
    shared: &Shared,
    name: &str,
    requirements: vk::MemoryRequirements,
    dedicated: (AllocationScheme, bool, bool),
    placement: Placement,
    linear: bool,
    group: Option<&AliasGroup>,
) -> Result<(Backing, vk::DeviceMemory, u64)> {
    if let Some(g) = group {
        let (m, o) = g.inner.bind_point(name, &requirements)?;
        return Ok((Backing::Group(g.keep()), m, o));
    }
    let a = shared.allocate(name, requirements, placement, linear, dedicated)?;
    // SAFETY: reading the handle of a live allocation.
    let memory = unsafe { a.memory() };
    let offset = a.offset();
    Ok((Backing::Own(a), memory, offset))
}
