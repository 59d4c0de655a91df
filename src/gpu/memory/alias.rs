//! Alias groups: one allocation shared by transient resources that are never live at the
//! same time.

use super::{BufferDesc, Dedicated, Location, Placement};
use crate::error::{Error, Result};
use crate::gpu::context::{Context, Shared};
use crate::gpu::lifetime::{Retired, Stamp};
use crate::gpu::validation::lock;
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationScheme};
use std::sync::{Arc, Mutex};

/// Memory shared by transient resources that are never live at the same time (aliasing).
///
/// Each member is bound at offset 0. Switching from one member to another needs a barrier
/// from every access of the previous member to the first access of the next, and an image
/// member starts from `discard` (its contents are undefined): see
/// [`Recorder::alias_switch`](crate::gpu::Recorder::alias_switch).
pub struct AliasGroup {
    pub(crate) inner: Arc<AliasInner>,
}

pub(crate) struct AliasInner {
    pub(crate) shared: Arc<Shared>,
    name: String,
    allocation: Mutex<Option<Allocation>>,
    memory: vk::DeviceMemory,
    offset: u64,
    size: u64,
    type_bits: u32,
    location: Location,
    pub(super) stamp: Stamp,
}

/// One future member of an alias group, to size the group's memory.
#[derive(Clone, Copy, Debug)]
pub enum AliasMember<'a> {
    /// A buffer that will be created from this description.
    Buffer(&'a BufferDesc),
    /// An image that will be created from this description.
    Image(&'a crate::gpu::image::ImageDesc),
}

impl AliasGroup {
    /// Fails unless a member made by `member_ctx` (named by `member`) may join this group:
    /// both must belong to one context.
    pub(crate) fn check_member_context(
        &self,
        member_ctx: &Arc<Shared>,
        member: impl FnOnce() -> String,
    ) -> Result<()> {
        member_ctx.check_owner(
            &self.inner.shared,
            || format!("alias group '{}'", self.name()),
            member,
        )
    }

    /// Memory large and aligned enough for each of `members` (one at a time), in the memory
    /// types all of them accept.
    pub fn new(
        ctx: &Context,
        name: &str,
        location: Location,
        members: &[AliasMember<'_>],
    ) -> Result<AliasGroup> {
        let shared = &ctx.shared;
        if members.is_empty() {
            return Err(Error::InvalidArgument(format!(
                "alias group '{name}' has no members"
            )));
        }
        let mut req = vk::MemoryRequirements {
            size: 0,
            alignment: 1,
            memory_type_bits: !0,
        };
        for m in members {
            let r = match m {
                AliasMember::Buffer(d) => buffer_requirements(shared, d)?,
                AliasMember::Image(d) => crate::gpu::image::image_requirements(shared, name, d)?,
            };
            req.size = req.size.max(r.size);
            req.alignment = req.alignment.max(r.alignment);
            req.memory_type_bits &= r.memory_type_bits;
        }
        if req.memory_type_bits == 0 {
            return Err(Error::Unsupported {
                device: shared.info.name.clone(),
                what: format!("one memory type for all members of alias group '{name}'"),
            });
        }
        let allocation = shared.allocate(
            name,
            req,
            Placement {
                location,
                dedicated: Dedicated::Never,
            },
            false,
            (AllocationScheme::GpuAllocatorManaged, false, false),
        )?;
        // SAFETY: reading the handle of a live allocation.
        let memory = unsafe { allocation.memory() };
        Ok(AliasGroup {
            inner: Arc::new(AliasInner {
                shared: shared.clone(),
                name: name.to_string(),
                memory,
                offset: allocation.offset(),
                size: req.size,
                type_bits: req.memory_type_bits,
                allocation: Mutex::new(Some(allocation)),
                location,
                stamp: Stamp::default(),
            }),
        })
    }

    /// Bytes of the group's memory (enough for its largest member).
    pub fn size(&self) -> u64 {
        self.inner.size
    }

    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    pub(crate) fn keep(&self) -> Arc<AliasInner> {
        self.inner.clone()
    }
}

impl AliasInner {
    /// Checks that a member with `req` fits; returns (memory, offset) to bind at.
    pub(crate) fn bind_point(
        &self,
        member: &str,
        req: &vk::MemoryRequirements,
    ) -> Result<(vk::DeviceMemory, u64)> {
        if req.size > self.size
            || !self.offset.is_multiple_of(req.alignment.max(1))
            || req.memory_type_bits & self.type_bits != self.type_bits
        {
            return Err(Error::InvalidArgument(format!(
                "'{member}' ({} bytes, alignment {}, memory types {:#x}) does not fit alias group \
                 '{}' ({} bytes, memory types {:#x}); list it among the group's members",
                req.size, req.alignment, req.memory_type_bits, self.name, self.size, self.type_bits
            )));
        }
        Ok((self.memory, self.offset))
    }

    pub(crate) fn location(&self) -> Location {
        self.location
    }
}

impl Drop for AliasInner {
    fn drop(&mut self) {
        if let Some(a) = lock(&self.allocation).take() {
            self.shared.retire(self.stamp.get(), [Retired::Memory(a)]);
        }
    }
}

fn buffer_requirements(shared: &Shared, desc: &BufferDesc) -> Result<vk::MemoryRequirements> {
    let info = vk::BufferCreateInfo::default()
        .size(desc.size.max(1))
        .usage(desc.usage)
        .sharing_mode(vk::SharingMode::EXCLUSIVE);
    let query = vk::DeviceBufferMemoryRequirements::default().create_info(&info);
    let mut out = vk::MemoryRequirements2::default();
    // SAFETY: valid create info; maintenance4 (core 1.3) is enabled on every vkshade device.
    unsafe {
        shared
            .device
            .get_device_buffer_memory_requirements(&query, &mut out)
    };
    Ok(out.memory_requirements)
}

impl std::fmt::Debug for AliasGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AliasGroup")
            .field("name", &self.inner.name)
            .field("size", &self.inner.size)
            .finish()
    }
}
