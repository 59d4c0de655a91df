//! Explicit barriers ([`Barrier`]) and barriers planned from declared uses
//! ([`PlannedBarrier`]), and how each is recorded.

use super::Recorder;
use crate::error::{Error, Result};
use crate::gpu::image::{Image, Subresources};
use crate::gpu::memory::Buffer;
use crate::gpu::sync::{AccessSet, AccessType, barrier_masks};
use ash::vk;
use std::sync::Arc;

/// One barrier to record; see [`AccessType`] for the vocabulary.
#[derive(Clone, Copy)]
pub enum Barrier<'a> {
    /// All memory: every resource accessed as `prev` before and as `next` after.
    Global {
        /// The accesses to wait for.
        prev: AccessSet,
        /// The accesses that wait.
        next: AccessSet,
    },
    /// A whole buffer.
    Buffer {
        /// The buffer.
        buffer: &'a Buffer,
        /// How it was accessed before.
        prev: AccessSet,
        /// How it is accessed after.
        next: AccessSet,
    },
    /// Subresources of an image; with `discard` their old contents are dropped (old layout
    /// UNDEFINED).
    Image {
        /// The image.
        image: &'a Image,
        /// The mips and layers the barrier covers.
        range: Subresources,
        /// How they were accessed before (their layout included).
        prev: AccessSet,
        /// How they are accessed after (their layout included).
        next: AccessSet,
        /// Whether the old contents may be dropped.
        discard: bool,
    },
}

impl<'a> Barrier<'a> {
    /// A global barrier: every resource accessed as `prev` before and as `next` after.
    pub fn global(prev: impl Into<AccessSet>, next: impl Into<AccessSet>) -> Self {
        Barrier::Global {
            prev: prev.into(),
            next: next.into(),
        }
    }

    /// A barrier on a whole buffer.
    pub fn buffer(
        buffer: &'a Buffer,
        prev: impl Into<AccessSet>,
        next: impl Into<AccessSet>,
    ) -> Self {
        Barrier::Buffer {
            buffer,
            prev: prev.into(),
            next: next.into(),
        }
    }

    /// Every subresource of an image.
    pub fn image(image: &'a Image, prev: impl Into<AccessSet>, next: impl Into<AccessSet>) -> Self {
        Barrier::Image {
            image,
            range: image.all(),
            prev: prev.into(),
            next: next.into(),
            discard: false,
        }
    }

    /// An image barrier that discards the old contents (first use, or full overwrite).
    pub fn image_discard(image: &'a Image, next: impl Into<AccessSet>) -> Self {
        Barrier::Image {
            image,
            range: image.all(),
            prev: AccessType::Nothing.into(),
            next: next.into(),
            discard: true,
        }
    }

    /// Restricts an image barrier to `range`.
    pub fn range(self, range: Subresources) -> Self {
        match self {
            Barrier::Image {
                image,
                prev,
                next,
                discard,
                ..
            } => Barrier::Image {
                image,
                range,
                prev,
                next,
                discard,
            },
            other => other,
        }
    }
}

/// A barrier derived from declared uses. It keeps the resource it names alive, so
/// recording it later ([`Recorder::record_planned`]) never names a destroyed object.
#[derive(Clone)]
pub struct PlannedBarrier {
    /// The resource's name.
    pub resource: String,
    pub(super) buffer: Option<vk::Buffer>,
    pub(super) image: Option<(vk::Image, Subresources)>,
    pub(super) target: Arc<dyn crate::gpu::lifetime::Used>,
    /// The context of the resource.
    pub(super) owner: Arc<crate::gpu::context::Shared>,
    /// The accesses the barrier waits for.
    pub prev: AccessSet,
    /// The accesses that wait.
    pub next: AccessSet,
    /// Make `prev`'s (already available) writes visible to `next`.
    pub force_visible: bool,
    /// An image's layout before (UNDEFINED for a buffer, or to discard the contents).
    pub old_layout: vk::ImageLayout,
    /// An image's layout after (UNDEFINED for a buffer).
    pub new_layout: vk::ImageLayout,
}

impl std::fmt::Debug for PlannedBarrier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlannedBarrier")
            .field("resource", &self.resource)
            .field("image_range", &self.image.map(|(_, r)| r))
            .field("prev", &self.prev)
            .field("next", &self.next)
            .field("force_visible", &self.force_visible)
            .field("old_layout", &self.old_layout)
            .field("new_layout", &self.new_layout)
            .finish()
    }
}

impl PlannedBarrier {
    /// The buffer it is for, if a buffer.
    pub fn buffer(&self) -> Option<vk::Buffer> {
        self.buffer
    }

    /// The image and subresources it is for, if an image.
    pub fn image(&self) -> Option<(vk::Image, Subresources)> {
        self.image
    }

    fn masks(&self) -> crate::gpu::sync::BarrierMasks {
        barrier_masks(
            self.prev,
            self.next,
            self.force_visible || self.old_layout != self.new_layout,
        )
    }

    /// Appends the Vulkan barrier to `buffers` or `images`.
    pub(super) fn push_vk(
        &self,
        buffers: &mut Vec<vk::BufferMemoryBarrier2<'static>>,
        images: &mut Vec<vk::ImageMemoryBarrier2<'static>>,
    ) {
        let m = self.masks();
        if let Some(b) = self.buffer {
            buffers.push(crate::gpu::sync::buffer_barrier_masks(
                b,
                0,
                vk::WHOLE_SIZE,
                m,
            ));
        }
        if let Some((image, range)) = self.image {
            images.push(crate::gpu::sync::image_barrier_masks(
                image,
                range.vk(),
                m,
                self.old_layout,
                self.new_layout,
            ));
        }
    }
}

impl Recorder {
    /// Records one pipeline barrier holding all of `barriers` (after any pending ones). The
    /// tracked state of each buffer and image named becomes what the barrier declares. An
    /// image range outside the image, or image accesses without a layout, are errors.
    ///
    /// Explicit barriers are the caller's word: a wrong `prev` (and so a wrong old layout)
    /// is reported by the validation layer, not checked here.
    pub fn barrier(&mut self, barriers: &[Barrier<'_>]) -> Result<()> {
        for b in barriers {
            match *b {
                Barrier::Buffer { buffer, .. } => {
                    let inner = buffer.keep();
                    self.check_owner(&inner.shared, || format!("buffer '{}'", inner.name))?;
                }
                Barrier::Image { image, .. } => {
                    let inner = image.keep();
                    self.check_owner(&inner.shared, || format!("image '{}'", inner.name))?;
                }
                Barrier::Global { .. } => {}
            }
            if let Barrier::Image {
                image,
                range,
                prev,
                next,
                discard,
            } = *b
            {
                range.check(image.name(), image.desc())?;
                check_image_access(image, next)?;
                if discard && !next.iter().any(AccessType::is_write) {
                    return Err(Error::InvalidArgument(format!(
                        "a barrier discarding the contents of image '{}' for a read ({next:?}) \
                         would read undefined contents",
                        image.name()
                    )));
                }
                if !discard && !prev.is_empty() {
                    check_image_access(image, prev)?;
                }
            }
        }
        self.flush_barriers();
        let mut memory = Vec::new();
        let mut buffers = Vec::new();
        let mut images = Vec::new();
        for b in barriers {
            match *b {
                Barrier::Global { prev, next } => {
                    memory.push(crate::gpu::sync::memory_barrier(prev, next))
                }
                Barrier::Buffer { buffer, prev, next } => {
                    let inner = buffer.keep();
                    self.local
                        .declare_buffer(&inner, |s| declare_barrier(s, prev, next, false));
                    self.keep.add(inner);
                    buffers.push(crate::gpu::sync::buffer_barrier(
                        buffer.raw(),
                        0,
                        vk::WHOLE_SIZE,
                        prev,
                        next,
                    ))
                }
                Barrier::Image {
                    image,
                    range,
                    prev,
                    next,
                    discard,
                } => {
                    let inner = image.keep();
                    self.local
                        .declare_image(&inner, &range, |s| declare_barrier(s, prev, next, true));
                    self.keep.add(inner);
                    images.push(crate::gpu::sync::image_barrier(
                        image.raw(),
                        range.vk(),
                        prev,
                        next,
                        discard,
                    ))
                }
            }
        }
        let dep = vk::DependencyInfo::default()
            .memory_barriers(&memory)
            .buffer_memory_barriers(&buffers)
            .image_memory_barriers(&images);
        // SAFETY: recording; every handle is alive (kept by this recorder).
        unsafe { self.device().cmd_pipeline_barrier2(self.cmd, &dep) };
        Ok(())
    }

    /// Records planned barriers (e.g. collected from several kernels and merged by a render
    /// graph) as one `vkCmdPipelineBarrier2`. The resources they name must be alive: they
    /// are the ones the collecting recorder keeps.
    pub fn record_planned(&mut self, planned: &[PlannedBarrier]) -> Result<()> {
        for p in planned {
            self.check_owner(&p.owner, || {
                format!("the planned barrier of '{}'", p.resource)
            })?;
        }
        self.flush_barriers();
        let (mut buffers, mut images) = (Vec::new(), Vec::new());
        for p in planned {
            self.keep.add(p.target.clone());
            p.push_vk(&mut buffers, &mut images);
        }
        let dep = vk::DependencyInfo::default()
            .buffer_memory_barriers(&buffers)
            .image_memory_barriers(&images);
        // SAFETY: recording; each planned barrier keeps its resource alive, and this recorder
        // now keeps them too; all belong to this device (checked).
        unsafe { self.shared.device.cmd_pipeline_barrier2(self.cmd, &dep) };
        Ok(())
    }

    /// Records the barriers queued by declared uses, as one `vkCmdPipelineBarrier2`.
    /// Commands vkshade records call this first; call it before adding your own commands
    /// to [`Recorder::raw`].
    pub fn flush_barriers(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let pending = std::mem::take(&mut self.pending);
        let (mut buffers, mut images) = (Vec::new(), Vec::new());
        for p in &pending {
            p.push_vk(&mut buffers, &mut images);
        }
        let dep = vk::DependencyInfo::default()
            .buffer_memory_barriers(&buffers)
            .image_memory_barriers(&images);
        // SAFETY: recording; every handle is kept alive by this recorder.
        unsafe { self.shared.device.cmd_pipeline_barrier2(self.cmd, &dep) };
    }
}

/// Fails unless `access` gives `image` a layout it can be in (image accesses only, and the
/// usage the layout needs).
pub(super) fn check_image_access(image: &Image, access: AccessSet) -> Result<()> {
    let layout = access.layout();
    let usage = image.desc().usage;
    let needs = match layout {
        vk::ImageLayout::UNDEFINED => {
            return Err(Error::InvalidArgument(format!(
                "{access:?} are not image accesses (no layout) for image '{}'",
                image.name()
            )));
        }
        vk::ImageLayout::TRANSFER_DST_OPTIMAL => vk::ImageUsageFlags::TRANSFER_DST,
        vk::ImageLayout::TRANSFER_SRC_OPTIMAL => vk::ImageUsageFlags::TRANSFER_SRC,
        vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL => vk::ImageUsageFlags::SAMPLED,
        vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL => vk::ImageUsageFlags::COLOR_ATTACHMENT,
        _ => vk::ImageUsageFlags::empty(),
    };
    let storage = access.contains(AccessType::ComputeShaderWrite)
        || access.contains(AccessType::ComputeShaderReadOther);
    let needs = if storage {
        needs | vk::ImageUsageFlags::STORAGE
    } else {
        needs
    };
    if !usage.contains(needs) {
        return Err(Error::InvalidArgument(format!(
            "image '{}' lacks {needs:?} usage, needed for {access:?}",
            image.name()
        )));
    }
    Ok(())
}

/// The state after an explicit barrier from `prev` to `next`: `next` reads are ordered
/// after `prev` (and see its writes); a `next` write becomes the last access.
fn declare_barrier(
    state: &mut crate::gpu::track::AccessState,
    prev: AccessSet,
    next: AccessSet,
    image: bool,
) {
    let layout = if image {
        next.layout()
    } else {
        vk::ImageLayout::UNDEFINED
    };
    let writes = next.iter().any(AccessType::is_write);
    *state = if writes || prev.is_empty() {
        crate::gpu::track::AccessState {
            layout,
            ..crate::gpu::track::AccessState::after(next)
        }
    } else {
        // `next` reads see `prev`'s writes; later reads chain through them.
        crate::gpu::track::AccessState {
            last: next,
            reads: next,
            wrote: prev.iter().any(AccessType::is_write) || (image && prev.layout() != layout),
            layout,
        }
    };
}
