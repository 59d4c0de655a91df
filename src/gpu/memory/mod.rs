//! Buffers over gpu-allocator, with the memory placement chosen by the caller.
//!
//! Every resource is created with a [`Placement`]: where its memory lives ([`Location`]) and
//! whether it gets an allocation of its own ([`Dedicated`]). Transient resources can share
//! memory through an [`AliasGroup`]. A renderer's own buffers are wrapped with
//! [`Buffer::from_raw`]. Destruction is deferred until the GPU is done (see `lifetime`).
//!
//! Host access to mapped memory is by copy ([`Buffer::write`], [`Buffer::read`]): each waits
//! for the last submission that used the buffer, and submissions that use the buffer wait for
//! a copy in progress, so the host never touches bytes the device is reading or writing.
//!
//! Here: buffers (creation, host copies, the owning handle). Beside them: `desc` (where
//! memory lives, and what a buffer is), `allocation` (allocating through gpu-allocator,
//! memory reports, the backing of a resource) and `alias` (alias groups).

mod alias;
mod allocation;
mod desc;

pub(crate) use alias::AliasInner;
pub use alias::{AliasGroup, AliasMember};
pub use allocation::MemoryReport;
pub(crate) use allocation::{Backing, MemoryStats, back};
pub use desc::{BufferDesc, Dedicated, Location, Placement};

use super::context::{Context, Shared};
use super::lifetime::{Retired, Stamp, Used};
use super::sync::AccessSet;
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::AllocationScheme;
use std::sync::{Arc, Mutex};

/// Pointer to mapped memory; the allocation it points into is owned by the same object.
#[derive(Clone, Copy)]
pub(crate) struct MappedPtr(pub std::ptr::NonNull<u8>);
// SAFETY: the pointer is only dereferenced under the buffer's host lock (see Buffer::write).
unsafe impl Send for MappedPtr {}
// SAFETY: as above.
unsafe impl Sync for MappedPtr {}

/// The Vulkan buffer and its memory. Destroyed when the last holder drops it and the GPU
/// has finished the submissions that used it.
pub(crate) struct BufferInner {
    pub(crate) shared: Arc<Shared>,
    pub(crate) raw: vk::Buffer,
    backing: Mutex<Option<Backing>>,
    pub(crate) desc: BufferDesc,
    pub(crate) name: String,
    alloc_size: u64,
    pub(crate) stamp: Stamp,
    mapped: Option<MappedPtr>,
    /// Held while the host copies to or from the mapping, and while a submission stamps the
    /// buffer: the two never overlap.
    host: Mutex<()>,
    /// Last access, for state tracking (see `track`).
    pub(crate) state: Mutex<super::track::BufferTrack>,
    /// A readback staging buffer: pooled for reuse when dropped (see `recycle`).
    pooled: bool,
}

impl BufferInner {
    /// Bytes of the allocation backing the buffer.
    pub(crate) fn alloc_bytes(&self) -> u64 {
        self.alloc_size
    }
}

impl Used for BufferInner {
    fn stamp(&self, value: u64) {
        let _host = self.mapped.map(|_| lock(&self.host));
        self.stamp.raise(value);
        if let Some(b) = lock(&self.backing).as_ref() {
            b.stamp(value)
        }
    }

    fn host_visible(&self) -> bool {
        self.mapped.is_some()
    }
}

impl Drop for BufferInner {
    fn drop(&mut self) {
        let backing = lock(&self.backing).take();
        // A caller's buffer (from_raw) is the caller's to destroy.
        if matches!(backing, Some(Backing::External)) {
            return;
        }
        let backing = match (backing, self.mapped) {
            (Some(Backing::Own(allocation)), Some(mapped)) if self.pooled => {
                let pooled = super::recycle::PooledBuffer {
                    raw: self.raw,
                    allocation,
                    size: self.desc.size,
                    mapped,
                };
                self.shared
                    .retire(self.stamp.get(), [Retired::Readback(pooled)]);
                return;
            }
            (backing, _) => backing,
        };
        let mut items = vec![Retired::Buffer(self.raw)];
        items.extend(backing.and_then(Backing::retire));
        self.shared.retire(self.stamp.get(), items);
    }
}

/// A Vulkan buffer with its memory. A shared handle: clones are the same buffer (one
/// tracked state, one name), so several kernels can bind the buffer one of them writes (the
/// character's posed vertices); the buffer is retired when the last clone is dropped and the
/// work using it completes.
#[derive(Clone)]
pub struct Buffer {
    inner: Arc<BufferInner>,
}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("name", &self.inner.name)
            .field("desc", &self.inner.desc)
            .finish()
    }
}

/// How long a host copy waits for the GPU to finish with a buffer before failing.
const HOST_WAIT_NS: u64 = 60_000_000_000;

impl Buffer {
    /// Creates a buffer with its own memory, refusing sizes the device cannot address: a
    /// storage buffer beyond `maxStorageBufferRange`, a uniform buffer beyond
    /// `maxUniformBufferRange`, anything beyond `maxMemoryAllocationSize`.
    pub fn new(ctx: &Context, name: &str, desc: BufferDesc) -> Result<Buffer> {
        Buffer::create(ctx, name, desc, None)
    }

    /// Creates a buffer bound to the memory of an alias group (see [`AliasGroup`]); its
    /// placement's location must be the group's.
    pub fn in_group(
        ctx: &Context,
        name: &str,
        desc: BufferDesc,
        group: &AliasGroup,
    ) -> Result<Buffer> {
        Buffer::create(ctx, name, desc, Some(group))
    }

    fn create(
        ctx: &Context,
        name: &str,
        desc: BufferDesc,
        group: Option<&AliasGroup>,
    ) -> Result<Buffer> {
        let shared = &ctx.shared;
        shared.collect();
        check_buffer_desc(shared, name, &desc)?;
        if let Some(g) = group {
            g.check_member_context(shared, || format!("buffer '{name}'"))?;
        }
        if let Some(g) = group
            && g.inner.location() != desc.placement.location
        {
            return Err(Error::InvalidArgument(format!(
                "buffer '{name}' wants {:?} memory but alias group '{}' is {:?}",
                desc.placement.location,
                g.name(),
                g.inner.location()
            )));
        }
        let info = vk::BufferCreateInfo::default()
            .size(desc.size)
            .usage(desc.usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let raw = unsafe { shared.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        super::recycle::Counters::bump(&shared.counters.buffers);
        let mut dedicated_req = vk::MemoryDedicatedRequirements::default();
        let mut req2 = vk::MemoryRequirements2::default().push_next(&mut dedicated_req);
        let req_info = vk::BufferMemoryRequirementsInfo2::default().buffer(raw);
        // SAFETY: `raw` was just created on this device.
        unsafe {
            shared
                .device
                .get_buffer_memory_requirements2(&req_info, &mut req2)
        };
        let backing = back(
            shared,
            name,
            req2.memory_requirements,
            (
                AllocationScheme::DedicatedBuffer(raw),
                dedicated_req.prefers_dedicated_allocation == vk::TRUE,
                dedicated_req.requires_dedicated_allocation == vk::TRUE,
            ),
            desc.placement,
            true,
            group,
        );
        let (backing, memory, offset) = match backing {
            Ok(b) => b,
            Err(e) => {
                // SAFETY: never bound or used.
                unsafe { shared.device.destroy_buffer(raw, None) };
                return Err(e);
            }
        };
        // Host access only for memory placed for it: device-local memory that happens to
        // be mappable (lavapipe, integrated GPUs) is not, so code stays portable.
        let mapped = match &backing {
            Backing::Own(a) if desc.placement.location.host_visible() => {
                a.mapped_ptr().map(|p| MappedPtr(p.cast()))
            }
            _ => None,
        };
        let alloc_size = backing.size();
        let inner = Arc::new(BufferInner {
            shared: shared.clone(),
            raw,
            backing: Mutex::new(Some(backing)),
            desc,
            name: name.to_string(),
            alloc_size,
            stamp: Stamp::default(),
            mapped,
            host: Mutex::new(()),
            state: Mutex::default(),
            pooled: false,
        });
        // SAFETY: memory of this device, sized and aligned by the requirements (checked for
        // alias groups); on failure `inner` is dropped and destroys the buffer.
        unsafe { shared.device.bind_buffer_memory(raw, memory, offset) }
            .vk("vkBindBufferMemory")?;
        shared.set_name(raw, name);
        Ok(Buffer { inner })
    }

    /// Wraps a buffer the caller created (a renderer's), so vkshade can bind and copy it.
    /// vkshade never destroys it and never maps it.
    ///
    /// # Safety
    /// `raw` must be a buffer of this context's device created with `desc.size` and
    /// `desc.usage`, bound to memory, and must stay valid until every vkshade handle to it is
    /// dropped *and* the context's timeline has passed [`Buffer::last_use`] (see
    /// [`Context::wait_for`]).
    pub unsafe fn from_raw(
        ctx: &Context,
        name: &str,
        raw: vk::Buffer,
        desc: BufferDesc,
    ) -> Result<Buffer> {
        check_buffer_desc(&ctx.shared, name, &desc)?;
        ctx.shared.set_name(raw, name);
        Ok(Buffer {
            inner: Arc::new(BufferInner {
                shared: ctx.shared.clone(),
                raw,
                backing: Mutex::new(Some(Backing::External)),
                desc,
                name: name.to_string(),
                alloc_size: 0,
                stamp: Stamp::default(),
                mapped: None,
                host: Mutex::new(()),
                state: Mutex::default(),
                pooled: false,
            }),
        })
    }

    /// A readback staging buffer of at least `size` bytes: a pooled one whose last use has
    /// completed, else a new one (its size rounded up to a power of two, so later readbacks
    /// of similar sizes can reuse it). Dropped, it goes back to the pool.
    pub(crate) fn readback_staging(ctx: &Context, name: &str, size: u64) -> Result<Buffer> {
        let shared = &ctx.shared;
        shared.collect();
        if let Some(p) = shared.take_readback(size) {
            shared.set_name(p.raw, name);
            let alloc_size = p.allocation.size();
            return Ok(Buffer {
                inner: Arc::new(BufferInner {
                    shared: shared.clone(),
                    raw: p.raw,
                    backing: Mutex::new(Some(Backing::Own(p.allocation))),
                    desc: BufferDesc::readback(p.size),
                    name: name.to_string(),
                    alloc_size,
                    stamp: Stamp::default(),
                    mapped: Some(p.mapped),
                    host: Mutex::new(()),
                    state: Mutex::default(),
                    pooled: true,
                }),
            });
        }
        let rounded = size.max(4096).next_power_of_two();
        let mut buffer = Buffer::new(ctx, name, BufferDesc::readback(rounded))?;
        // Pool it only if it is mapped (always, for READBACK placement) and not shared.
        if let Some(inner) = Arc::get_mut(&mut buffer.inner) {
            inner.pooled = inner.mapped.is_some();
        }
        Ok(buffer)
    }

    /// Whether the buffer is bound to an alias group's memory.
    pub fn is_alias_member(&self) -> bool {
        matches!(lock(&self.inner.backing).as_ref(), Some(Backing::Group(_)))
    }

    /// Another owning handle to the same buffer.
    pub(crate) fn from_keep(inner: Arc<BufferInner>) -> Buffer {
        Buffer { inner }
    }

    /// A reference that keeps the Vulkan buffer alive (for bind groups and recordings).
    pub(crate) fn keep(&self) -> Arc<BufferInner> {
        self.inner.clone()
    }

    /// The Vulkan buffer, for callers that record their own commands with it.
    pub fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }

    /// Size in bytes.
    pub fn size(&self) -> u64 {
        self.inner.desc.size
    }

    /// The name given at creation (also its debug-utils name).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The usages the buffer was created with.
    pub fn usage(&self) -> vk::BufferUsageFlags {
        self.inner.desc.usage
    }

    /// What the buffer is (size, usage, placement).
    pub fn desc(&self) -> &BufferDesc {
        &self.inner.desc
    }

    /// Where the buffer's memory lives.
    pub fn placement(&self) -> Placement {
        self.inner.desc.placement
    }

    /// Bytes of the buffer's own allocation (0 for wrapped buffers and alias-group members).
    pub fn allocation_size(&self) -> u64 {
        self.inner.alloc_size
    }

    /// Timeline value of the last submission that used the buffer (0: none yet).
    pub fn last_use(&self) -> u64 {
        self.inner.stamp.get()
    }

    /// Declares how the buffer was last accessed outside vkshade's tracking (e.g. by a
    /// renderer's draw), so the next tracked use waits for it. It applies to recordings
    /// submitted from now on (each joins its first use to the state at its submission).
    pub fn assume_access(&self, access: impl Into<AccessSet>) {
        let mut g = lock(&self.inner.state);
        g.state = super::track::BufferState::after(access.into());
        g.version += 1;
    }

    fn host_range(&self, offset: u64, len: u64, what: &str) -> Result<MappedPtr> {
        let inner = &self.inner;
        let ptr = inner.mapped.ok_or_else(|| {
            Error::InvalidArgument(format!(
                "buffer '{}' is {:?} memory, not host-visible; {what} it through a recording \
                 (Recorder::upload / Recorder::read_back)",
                inner.name, inner.desc.placement.location
            ))
        })?;
        if offset
            .checked_add(len)
            .is_none_or(|end| end > inner.desc.size)
        {
            return Err(Error::InvalidArgument(format!(
                "{what} of {len} bytes at offset {offset} overruns buffer '{}' of {} bytes",
                inner.name, inner.desc.size
            )));
        }
        Ok(ptr)
    }

    /// Waits (with the host lock held) until no submission uses the buffer.
    fn wait_idle_locked(&self) -> Result<()> {
        let value = self.inner.stamp.get();
        if !self.inner.shared.wait_value(value, HOST_WAIT_NS)? {
            return Err(Error::InvalidArgument(format!(
                "buffer '{}' is still used by submission {value} after {} s (was a recording \
                 into a caller's command buffer never submitted?)",
                self.inner.name,
                HOST_WAIT_NS / 1_000_000_000
            )));
        }
        Ok(())
    }

    /// Copies `data` into a host-visible buffer at byte `offset`, after waiting for every
    /// submission that used the buffer. Visible to submissions made afterwards.
    pub fn write<T: bytemuck::Pod>(&self, offset: u64, data: &[T]) -> Result<()> {
        not_zero_sized::<T>()?;
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let ptr = self.host_range(offset, bytes.len() as u64, "write")?;
        let _host = lock(&self.inner.host);
        self.wait_idle_locked()?;
        // SAFETY: the range is inside the mapping (checked); no submission uses the buffer
        // (waited for, and new ones stamp it under the host lock we hold); the source is a
        // separate Rust slice.
        unsafe {
            std::ptr::copy_nonoverlapping(
                bytes.as_ptr(),
                ptr.0.as_ptr().add(offset as usize),
                bytes.len(),
            )
        };
        Ok(())
    }

    /// Copies bytes out of a host-visible buffer into `out`, after waiting for every
    /// submission that used the buffer. Device writes must have been made available to the
    /// host (recordings do that when they touch a host-visible buffer).
    pub fn read_into<T: bytemuck::Pod>(&self, offset: u64, out: &mut [T]) -> Result<()> {
        not_zero_sized::<T>()?;
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(out);
        let ptr = self.host_range(offset, bytes.len() as u64, "read")?;
        let _host = lock(&self.inner.host);
        self.wait_idle_locked()?;
        // SAFETY: as in `write`: in range, idle, and not aliased by `out`.
        unsafe {
            std::ptr::copy_nonoverlapping(
                ptr.0.as_ptr().add(offset as usize),
                bytes.as_mut_ptr(),
                bytes.len(),
            )
        };
        Ok(())
    }

    /// The whole buffer (or as many whole `T` as fit) copied to a vector.
    pub fn read<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        not_zero_sized::<T>()?;
        let n = self.size() as usize / std::mem::size_of::<T>().max(1);
        let mut out = vec![T::zeroed(); n];
        self.read_into(0, &mut out)?;
        Ok(out)
    }

    /// The mapped pointer of a host-visible buffer, for zero-copy access.
    ///
    /// # Safety
    /// The caller must not read bytes that a submission in flight writes, nor write bytes
    /// that one reads or writes: wait for [`Buffer::last_use`] first, and submit no work
    /// using the buffer while the pointer is used. Device writes must be made available to
    /// the host (a `HostRead` barrier) before reading.
    pub unsafe fn mapped_ptr(&self) -> Option<std::ptr::NonNull<u8>> {
        self.inner.mapped.map(|p| p.0)
    }
}

/// Refuses zero-sized element types (bytemuck cannot cast them).
pub(crate) fn not_zero_sized<T>() -> Result<()> {
    if std::mem::size_of::<T>() == 0 {
        return Err(Error::InvalidArgument(format!(
            "{} is zero-sized: no bytes to copy",
            std::any::type_name::<T>()
        )));
    }
    Ok(())
}

/// Fails unless `buffer` has `usage` (needed by `what`).
pub(crate) fn require_buffer_usage(
    buffer: &Buffer,
    usage: vk::BufferUsageFlags,
    what: &str,
) -> Result<()> {
    if !buffer.usage().contains(usage) {
        return Err(Error::InvalidArgument(format!(
            "buffer '{}' lacks {usage:?} usage, needed for {what}",
            buffer.name()
        )));
    }
    Ok(())
}

fn check_buffer_desc(shared: &Shared, name: &str, desc: &BufferDesc) -> Result<()> {
    let limits = &shared.info.limits;
    if desc.size == 0 {
        return Err(Error::InvalidArgument(format!(
            "buffer '{name}' has size 0"
        )));
    }
    let checks = [
        (
            vk::BufferUsageFlags::STORAGE_BUFFER,
            limits.max_storage_buffer_range,
            "maxStorageBufferRange",
        ),
        (
            vk::BufferUsageFlags::UNIFORM_BUFFER,
            limits.max_uniform_buffer_range,
            "maxUniformBufferRange",
        ),
        (
            vk::BufferUsageFlags::empty(),
            limits.max_memory_allocation_size,
            "maxMemoryAllocationSize",
        ),
    ];
    for (usage, limit, limit_name) in checks {
        if desc.usage.contains(usage) && desc.size > limit {
            return Err(Error::Limit {
                what: format!("size in bytes of buffer '{name}'"),
                requested: desc.size,
                limit_name,
                limit,
            });
        }
    }
    Ok(())
}
