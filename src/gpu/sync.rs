//! Access types and their mapping to synchronization2 barriers.
//!
//! A resource is described by how it was last accessed (`prev`) and how it will be accessed
//! next (`next`). [`barrier_masks`] turns that into stage and access masks following the rules
//! of the Khronos synchronization examples:
//! - source stages: every previous access; source access: previous *writes* only (reads need
//!   no availability operation);
//! - destination access: only when there is something to make visible (a previous write or an
//!   image layout transition); a write-after-read needs an execution dependency alone.
//!
//! Sampled-image reads use `SHADER_READ` (the generic bit of the Khronos examples) rather than
//! synchronization2's narrower `SHADER_SAMPLED_READ`: the two are equivalent for sampled images,
//! and the best-practices layer of the 1.3.239 SDK flags the narrow bit on read-only layouts.

use ash::vk;
use std::fmt;
use std::ops::BitOr;

/// One way a resource is accessed. Each variant fixes pipeline stages, access flags and, for
/// images, the layout the image must be in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum AccessType {
    /// No access: the resource's contents are undefined or irrelevant.
    Nothing,
    /// Indirect draw or dispatch arguments read from a buffer.
    IndirectBuffer,
    /// An index buffer read by a draw.
    IndexBuffer,
    /// A vertex buffer read by a draw.
    VertexBuffer,
    /// Uniform buffer read in a vertex shader.
    VertexShaderReadUniformBuffer,
    /// Sampled image read in a vertex shader (SHADER_READ_ONLY_OPTIMAL).
    VertexShaderReadSampledImage,
    /// Storage buffer or storage image read in a vertex shader.
    VertexShaderReadOther,
    /// Uniform buffer read in a fragment shader.
    FragmentShaderReadUniformBuffer,
    /// Sampled image read in a fragment shader (SHADER_READ_ONLY_OPTIMAL).
    FragmentShaderReadSampledImage,
    /// Storage buffer or storage image read in a fragment shader.
    FragmentShaderReadOther,
    /// Colour attachment read (blending; COLOR_ATTACHMENT_OPTIMAL).
    ColorAttachmentRead,
    /// Depth/stencil attachment read by the fragment tests (read-only layout).
    DepthStencilAttachmentRead,
    /// Uniform buffer read in a compute shader.
    ComputeShaderReadUniformBuffer,
    /// Sampled image read in a compute shader (SHADER_READ_ONLY_OPTIMAL).
    ComputeShaderReadSampledImage,
    /// Storage buffer or storage image read in a compute shader.
    ComputeShaderReadOther,
    /// Source of a copy or blit (TRANSFER_SRC_OPTIMAL).
    TransferRead,
    /// Read by the host through mapped memory.
    HostRead,
    /// Storage buffer or storage image write in a vertex shader.
    VertexShaderWrite,
    /// Storage buffer or storage image write in a fragment shader.
    FragmentShaderWrite,
    /// Colour attachment write (COLOR_ATTACHMENT_OPTIMAL).
    ColorAttachmentWrite,
    /// Depth/stencil attachment write by the fragment tests.
    DepthStencilAttachmentWrite,
    /// Storage buffer or storage image write in a compute shader.
    ComputeShaderWrite,
    /// Destination of a copy, blit, clear or fill (TRANSFER_DST_OPTIMAL).
    TransferWrite,
    /// Written by the host through mapped memory.
    HostWrite,
    /// Any access by any command (a full barrier; GENERAL layout).
    General,
}

/// Stage, access and layout of one [`AccessType`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AccessInfo {
    /// The pipeline stages the access happens in.
    pub stages: vk::PipelineStageFlags2,
    /// The access flags it uses.
    pub access: vk::AccessFlags2,
    /// Layout for images; `UNDEFINED` for accesses that never touch images.
    pub layout: vk::ImageLayout,
}

/// Every compute-shader and transfer access: the state a freshly uploaded buffer is made
/// visible to (see `Context::upload_buffer`).
pub const COMPUTE_OR_TRANSFER: AccessSet = AccessSet(
    1 << AccessType::ComputeShaderReadUniformBuffer as u8
        | 1 << AccessType::ComputeShaderReadSampledImage as u8
        | 1 << AccessType::ComputeShaderReadOther as u8
        | 1 << AccessType::ComputeShaderWrite as u8
        | 1 << AccessType::TransferRead as u8
        | 1 << AccessType::TransferWrite as u8,
);

impl AccessType {
    /// Every access type, in declaration order (bit `i` of an [`AccessSet`] is `ALL[i]`).
    pub const ALL: [AccessType; 25] = [
        AccessType::Nothing,
        AccessType::IndirectBuffer,
        AccessType::IndexBuffer,
        AccessType::VertexBuffer,
        AccessType::VertexShaderReadUniformBuffer,
        AccessType::VertexShaderReadSampledImage,
        AccessType::VertexShaderReadOther,
        AccessType::FragmentShaderReadUniformBuffer,
        AccessType::FragmentShaderReadSampledImage,
        AccessType::FragmentShaderReadOther,
        AccessType::ColorAttachmentRead,
        AccessType::DepthStencilAttachmentRead,
        AccessType::ComputeShaderReadUniformBuffer,
        AccessType::ComputeShaderReadSampledImage,
        AccessType::ComputeShaderReadOther,
        AccessType::TransferRead,
        AccessType::HostRead,
        AccessType::VertexShaderWrite,
        AccessType::FragmentShaderWrite,
        AccessType::ColorAttachmentWrite,
        AccessType::DepthStencilAttachmentWrite,
        AccessType::ComputeShaderWrite,
        AccessType::TransferWrite,
        AccessType::HostWrite,
        AccessType::General,
    ];

    /// The stages, access flags and image layout of this access.
    pub fn info(self) -> AccessInfo {
        use AccessType as A;
        use vk::AccessFlags2 as F;
        use vk::ImageLayout as L;
        use vk::PipelineStageFlags2 as S;
        let (stages, access, layout) = match self {
            A::Nothing => (S::NONE, F::NONE, L::UNDEFINED),
            A::IndirectBuffer => (S::DRAW_INDIRECT, F::INDIRECT_COMMAND_READ, L::UNDEFINED),
            A::IndexBuffer => (S::INDEX_INPUT, F::INDEX_READ, L::UNDEFINED),
            A::VertexBuffer => (
                S::VERTEX_ATTRIBUTE_INPUT,
                F::VERTEX_ATTRIBUTE_READ,
                L::UNDEFINED,
            ),
            A::VertexShaderReadUniformBuffer => (S::VERTEX_SHADER, F::UNIFORM_READ, L::UNDEFINED),
            A::VertexShaderReadSampledImage => (
                S::VERTEX_SHADER,
                F::SHADER_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
            ),
            A::VertexShaderReadOther => (S::VERTEX_SHADER, F::SHADER_STORAGE_READ, L::GENERAL),
            A::FragmentShaderReadUniformBuffer => {
                (S::FRAGMENT_SHADER, F::UNIFORM_READ, L::UNDEFINED)
            }
            A::FragmentShaderReadSampledImage => (
                S::FRAGMENT_SHADER,
                F::SHADER_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
            ),
            A::FragmentShaderReadOther => (S::FRAGMENT_SHADER, F::SHADER_STORAGE_READ, L::GENERAL),
            A::ColorAttachmentRead => (
                S::COLOR_ATTACHMENT_OUTPUT,
                F::COLOR_ATTACHMENT_READ,
                L::COLOR_ATTACHMENT_OPTIMAL,
            ),
            A::DepthStencilAttachmentRead => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                F::DEPTH_STENCIL_ATTACHMENT_READ,
                L::DEPTH_STENCIL_READ_ONLY_OPTIMAL,
            ),
            A::ComputeShaderReadUniformBuffer => (S::COMPUTE_SHADER, F::UNIFORM_READ, L::UNDEFINED),
            A::ComputeShaderReadSampledImage => (
                S::COMPUTE_SHADER,
                F::SHADER_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
            ),
            A::ComputeShaderReadOther => (S::COMPUTE_SHADER, F::SHADER_STORAGE_READ, L::GENERAL),
            A::TransferRead => (S::ALL_TRANSFER, F::TRANSFER_READ, L::TRANSFER_SRC_OPTIMAL),
            A::HostRead => (S::HOST, F::HOST_READ, L::GENERAL),
            A::VertexShaderWrite => (S::VERTEX_SHADER, F::SHADER_STORAGE_WRITE, L::GENERAL),
            A::FragmentShaderWrite => (S::FRAGMENT_SHADER, F::SHADER_STORAGE_WRITE, L::GENERAL),
            A::ColorAttachmentWrite => (
                S::COLOR_ATTACHMENT_OUTPUT,
                F::COLOR_ATTACHMENT_WRITE,
                L::COLOR_ATTACHMENT_OPTIMAL,
            ),
            A::DepthStencilAttachmentWrite => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                F::DEPTH_STENCIL_ATTACHMENT_WRITE,
                L::DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
            ),
            A::ComputeShaderWrite => (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE, L::GENERAL),
            A::TransferWrite => (S::ALL_TRANSFER, F::TRANSFER_WRITE, L::TRANSFER_DST_OPTIMAL),
            A::HostWrite => (S::HOST, F::HOST_WRITE, L::GENERAL),
            A::General => (
                S::ALL_COMMANDS,
                F::MEMORY_READ | F::MEMORY_WRITE,
                L::GENERAL,
            ),
        };
        AccessInfo {
            stages,
            access,
            layout,
        }
    }

    /// Whether this access writes (needs an availability operation afterwards).
    pub fn is_write(self) -> bool {
        use AccessType as A;
        matches!(
            self,
            A::VertexShaderWrite
                | A::FragmentShaderWrite
                | A::ColorAttachmentWrite
                | A::DepthStencilAttachmentWrite
                | A::ComputeShaderWrite
                | A::TransferWrite
                | A::HostWrite
                | A::General
        )
    }
}

/// A set of [`AccessType`]s, built with `|`: `ComputeShaderReadOther | TransferRead`.
#[derive(Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct AccessSet(u32);

impl AccessSet {
    /// No access.
    pub const EMPTY: AccessSet = AccessSet(0);

    /// The raw bit set (bit `i` = `AccessType::ALL[i]`).
    pub const fn bits(self) -> u32 {
        self.0
    }

    /// A set from raw bits (unknown bits are dropped).
    pub const fn from_bits(bits: u32) -> AccessSet {
        AccessSet(bits & ((1 << AccessType::ALL.len()) - 1))
    }

    /// Whether `a` is in the set.
    pub fn contains(self, a: AccessType) -> bool {
        self.0 & (1 << a as u8) != 0
    }

    /// The access types in the set, in declaration order.
    pub fn iter(self) -> impl Iterator<Item = AccessType> {
        AccessType::ALL
            .into_iter()
            .filter(move |a| self.contains(*a))
    }

    /// Whether the set holds no access (only `Nothing`, or nothing at all).
    pub fn is_empty(self) -> bool {
        self.iter().all(|a| a == AccessType::Nothing)
    }

    /// Image layout required by these accesses: their common layout, else GENERAL.
    pub fn layout(self) -> vk::ImageLayout {
        let mut layouts = self
            .iter()
            .map(|a| a.info().layout)
            .filter(|l| *l != vk::ImageLayout::UNDEFINED);
        match layouts.next() {
            None => vk::ImageLayout::UNDEFINED,
            Some(first) if layouts.all(|l| l == first) => first,
            Some(_) => vk::ImageLayout::GENERAL,
        }
    }
}

impl fmt::Debug for AccessSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_set().entries(self.iter()).finish()
    }
}

impl From<AccessType> for AccessSet {
    fn from(a: AccessType) -> Self {
        AccessSet(1 << a as u8)
    }
}

impl BitOr for AccessType {
    type Output = AccessSet;
    fn bitor(self, rhs: AccessType) -> AccessSet {
        AccessSet::from(self) | rhs
    }
}

impl<T: Into<AccessSet>> BitOr<T> for AccessSet {
    type Output = AccessSet;
    fn bitor(self, rhs: T) -> AccessSet {
        AccessSet(self.0 | rhs.into().0)
    }
}

/// Source and destination scopes of one dependency.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BarrierMasks {
    /// Stages to wait for.
    pub src_stages: vk::PipelineStageFlags2,
    /// Writes to make available.
    pub src_access: vk::AccessFlags2,
    /// Stages that wait.
    pub dst_stages: vk::PipelineStageFlags2,
    /// Accesses the available writes are made visible to.
    pub dst_access: vk::AccessFlags2,
}

/// Masks for a dependency from `prev` to `next`. `layout_transition` forces the destination
/// access (a transition is a write that later accesses must see).
pub fn barrier_masks(prev: AccessSet, next: AccessSet, layout_transition: bool) -> BarrierMasks {
    let mut m = BarrierMasks {
        src_stages: vk::PipelineStageFlags2::NONE,
        src_access: vk::AccessFlags2::NONE,
        dst_stages: vk::PipelineStageFlags2::NONE,
        dst_access: vk::AccessFlags2::NONE,
    };
    for a in prev.iter() {
        let i = a.info();
        m.src_stages |= i.stages;
        if a.is_write() {
            m.src_access |= i.access;
        }
    }
    let make_visible = !m.src_access.is_empty() || layout_transition;
    for a in next.iter() {
        let i = a.info();
        m.dst_stages |= i.stages;
        if make_visible {
            m.dst_access |= i.access;
        }
    }
    m
}

/// A global memory barrier from `prev` to `next`.
pub fn memory_barrier(
    prev: impl Into<AccessSet>,
    next: impl Into<AccessSet>,
) -> vk::MemoryBarrier2<'static> {
    let m = barrier_masks(prev.into(), next.into(), false);
    vk::MemoryBarrier2::default()
        .src_stage_mask(m.src_stages)
        .src_access_mask(m.src_access)
        .dst_stage_mask(m.dst_stages)
        .dst_access_mask(m.dst_access)
}

/// A barrier on `size` bytes of `buffer` from `offset` (`vk::WHOLE_SIZE` for all of it).
pub fn buffer_barrier(
    buffer: vk::Buffer,
    offset: u64,
    size: u64,
    prev: impl Into<AccessSet>,
    next: impl Into<AccessSet>,
) -> vk::BufferMemoryBarrier2<'static> {
    buffer_barrier_masks(
        buffer,
        offset,
        size,
        barrier_masks(prev.into(), next.into(), false),
    )
}

/// A buffer barrier with the given masks.
pub fn buffer_barrier_masks(
    buffer: vk::Buffer,
    offset: u64,
    size: u64,
    m: BarrierMasks,
) -> vk::BufferMemoryBarrier2<'static> {
    vk::BufferMemoryBarrier2::default()
        .src_stage_mask(m.src_stages)
        .src_access_mask(m.src_access)
        .dst_stage_mask(m.dst_stages)
        .dst_access_mask(m.dst_access)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .buffer(buffer)
        .offset(offset)
        .size(size)
}

/// A barrier on an image, with the layout transition the accesses imply. With `discard`, the
/// old contents are not needed and the old layout is UNDEFINED.
pub fn image_barrier(
    image: vk::Image,
    range: vk::ImageSubresourceRange,
    prev: impl Into<AccessSet>,
    next: impl Into<AccessSet>,
    discard: bool,
) -> vk::ImageMemoryBarrier2<'static> {
    let (prev, next) = (prev.into(), next.into());
    let old_layout = if discard {
        vk::ImageLayout::UNDEFINED
    } else {
        prev.layout()
    };
    let new_layout = next.layout();
    let m = barrier_masks(prev, next, old_layout != new_layout);
    image_barrier_masks(image, range, m, old_layout, new_layout)
}

/// An image barrier with the given masks and layouts.
pub fn image_barrier_masks(
    image: vk::Image,
    range: vk::ImageSubresourceRange,
    m: BarrierMasks,
    old_layout: vk::ImageLayout,
    new_layout: vk::ImageLayout,
) -> vk::ImageMemoryBarrier2<'static> {
    vk::ImageMemoryBarrier2::default()
        .src_stage_mask(m.src_stages)
        .src_access_mask(m.src_access)
        .dst_stage_mask(m.dst_stages)
        .dst_access_mask(m.dst_access)
        .old_layout(old_layout)
        .new_layout(new_layout)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .image(image)
        .subresource_range(range)
}
