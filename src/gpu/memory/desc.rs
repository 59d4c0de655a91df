//! Where a resource's memory lives ([`Location`], [`Dedicated`], [`Placement`]) and what a
//! buffer is ([`BufferDesc`]).

use ash::vk;
use gpu_allocator::MemoryLocation;

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
    pub(super) fn gpu_allocator(self) -> MemoryLocation {
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
