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

use super::context::{Context, Shared};
use super::lifetime::{Retired, Stamp, Used};
use super::sync::AccessSet;
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

/// Where a resource's memory lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum Location {
    /// Device-local; reached from the host only through staging copies.
    Device,
    /// Host-visible, written by the host, read by the device (staging, per-frame data).
    Upload,
    /// Host-visible and cached where possible, written by the device, read by the host.
    Readback,
}

impl Location {
    fn gpu_allocator(self) -> MemoryLocation {
        match self {
            Location::Device => MemoryLocation::GpuOnly,
            Location::Upload => MemoryLocation::CpuToGpu,
            Location::Readback => MemoryLocation::GpuToCpu,
        }
    }

    /// Whether the host can map the memory (upload and readback memory).
    pub fn host_visible(self) -> bool {
        self != Location::Device
    }
}

/// Whether a resource gets a `VkDeviceMemory` of its own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub enum Dedicated {
    /// Dedicated when the driver prefers or requires it (VkMemoryDedicatedRequirements),
    /// otherwise sub-allocated from the allocator's blocks.
    #[default]
    Auto,
    /// Always a dedicated allocation.
    Always,
    /// Sub-allocated unless the driver *requires* a dedicated allocation.
    Never,
}

/// Where and how a resource's memory is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub struct Placement {
    /// Where the memory lives.
    pub location: Location,
    /// Whether it gets a `VkDeviceMemory` of its own.
    pub dedicated: Dedicated,
}

impl Placement {
    /// Device-local, dedicated when the driver prefers it.
    pub const DEVICE: Placement = Placement {
        location: Location::Device,
        dedicated: Dedicated::Auto,
    };
    /// Host-visible for host writes, dedicated when the driver prefers it.
    pub const UPLOAD: Placement = Placement {
        location: Location::Upload,
        dedicated: Dedicated::Auto,
    };
    /// Host-visible for device writes the host reads, dedicated when the driver prefers it.
    pub const READBACK: Placement = Placement {
        location: Location::Readback,
        dedicated: Dedicated::Auto,
    };

    /// The same location with dedicated-allocation policy `d`.
    pub const fn dedicated(mut self, d: Dedicated) -> Placement {
        self.dedicated = d;
        self
    }
}

/// What a buffer is: size, usage and placement (the name is given separately).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BufferDesc {
    /// Size in bytes.
    pub size: u64,
    /// How the buffer may be used (checked by each command that uses it).
    pub usage: vk::BufferUsageFlags,
    /// Where its memory lives and whether it gets an allocation of its own.
    pub placement: Placement,
}

impl BufferDesc {
    /// A device-local storage buffer that can be copied to and from.
    pub const fn storage(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::from_raw(
                vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_DST.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_SRC.as_raw(),
            ),
            placement: Placement::DEVICE,
        }
    }

    /// A device-local uniform buffer that can be copied to and from.
    pub const fn uniform(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::from_raw(
                vk::BufferUsageFlags::UNIFORM_BUFFER.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_DST.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_SRC.as_raw(),
            ),
            placement: Placement::DEVICE,
        }
    }

    /// A host-visible buffer the host writes and the device reads (copy source, storage).
    pub const fn upload(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::from_raw(
                vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_DST.as_raw()
                    | vk::BufferUsageFlags::STORAGE_BUFFER.as_raw(),
            ),
            placement: Placement::UPLOAD,
        }
    }

    /// A host-visible buffer the device writes and the host reads.
    pub const fn readback(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::from_raw(
                vk::BufferUsageFlags::TRANSFER_DST.as_raw()
                    | vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
                    | vk::BufferUsageFlags::STORAGE_BUFFER.as_raw(),
            ),
            placement: Placement::READBACK,
        }
    }

    /// Adds `usage` to the buffer's usages.
    pub const fn usage(mut self, usage: vk::BufferUsageFlags) -> Self {
        self.usage = vk::BufferUsageFlags::from_raw(self.usage.as_raw() | usage.as_raw());
        self
    }

    /// Sets where the buffer's memory lives.
    pub const fn placement(mut self, placement: Placement) -> Self {
        self.placement = placement;
        self
    }
}

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
}

/// Where a resource's memory comes from.
pub(crate) enum Backing {
    /// Its own allocation (sub-allocated or dedicated), freed with it.
    Own(Allocation),
    /// Memory of an alias group, freed with the group.
    Group(Arc<AliasInner>),
    /// Memory owned by the caller ([`Buffer::from_raw`], [`super::Image::from_raw`]).
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

/// Memory shared by transient resources that are never live at the same time (aliasing).
///
/// Each member is bound at offset 0. Switching from one member to another needs a barrier
/// from every access of the previous member to the first access of the next, and an image
/// member starts from `discard` (its contents are undefined): see
/// [`super::Recorder::alias_switch`].
pub struct AliasGroup {
    inner: Arc<AliasInner>,
}

pub(crate) struct AliasInner {
    shared: Arc<Shared>,
    name: String,
    allocation: Mutex<Option<Allocation>>,
    memory: vk::DeviceMemory,
    offset: u64,
    size: u64,
    type_bits: u32,
    location: Location,
    stamp: Stamp,
}

/// One future member of an alias group, to size the group's memory.
#[derive(Clone, Copy, Debug)]
pub enum AliasMember<'a> {
    /// A buffer that will be created from this description.
    Buffer(&'a BufferDesc),
    /// An image that will be created from this description.
    Image(&'a super::image::ImageDesc),
}

impl AliasGroup {
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
                AliasMember::Image(d) => super::image::image_requirements(shared, name, d)?,
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
            || self.offset % req.alignment.max(1) != 0
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
    pub(crate) state: Mutex<super::track::BufferState>,
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
        let mut items = vec![Retired::Buffer(self.raw)];
        items.extend(backing.and_then(Backing::retire));
        self.shared.retire(self.stamp.get(), items);
    }
}

/// A Vulkan buffer with its memory (the owning handle).
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
            }),
        })
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
    /// renderer's draw), so the next tracked use waits for it.
    pub fn assume_access(&self, access: impl Into<AccessSet>) {
        *lock(&self.inner.state) = super::track::BufferState::after(access.into());
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
