//! Declared uses: each names a resource and how it is accessed next; the tracked state
//! turns it into the barriers it needs, queued until the next command ([`BarrierMode::Emit`])
//! or collected for a render graph to record ([`BarrierMode::Collect`]).

use super::barrier::check_image_access;
use super::{Barrier, PlannedBarrier, Recorder};
use crate::error::{Error, Result};
use crate::gpu::image::{Image, ImageInner, Subresources};
use crate::gpu::memory::{Buffer, BufferInner};
use crate::gpu::pipeline::BindGroup;
use crate::gpu::sync::{AccessSet, AccessType};
use crate::gpu::track::{RangeTransition, Transition};
use ash::vk;
use std::sync::Arc;

/// Who records the barriers that declared uses need.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BarrierMode {
    /// vkshade records them (batched, one `vkCmdPipelineBarrier2` per group).
    Emit,
    /// vkshade records none: the caller (a render graph) has planned them beforehand
    /// ([`Recorder::plan`], [`Recorder::plan_dispatch`]) and recorded them merged with its
    /// own. A tracked command whose uses were planned applies nothing again; what an
    /// unplanned use would have needed is kept for checking ([`Recorder::take_collected`]),
    /// so after a correct plan it is empty.
    Collect,
}

/// A declared use of a resource, for [`Recorder::plan`].
#[derive(Clone, Copy)]
pub enum Use<'a> {
    /// A whole buffer, and how it is accessed next.
    Buffer(&'a Buffer, AccessSet),
    /// Subresources of an image, and how they are accessed next (layout included).
    Image(&'a Image, Subresources, AccessSet),
}

/// A member of an alias group starting to be used (see [`Recorder::alias_switch`]).
pub enum AliasUse<'a> {
    /// A buffer member, and how it is accessed first.
    Buffer(&'a Buffer, AccessSet),
    /// An image member (all of it), and how it is accessed first.
    Image(&'a Image, AccessSet),
}

impl Recorder {
    /// Sets who records barriers derived from declared uses (default [`BarrierMode::Emit`]).
    /// Leaving Collect mode drops planned uses no command consumed.
    pub fn set_barrier_mode(&mut self, mode: BarrierMode) {
        self.flush_barriers();
        if mode == BarrierMode::Emit {
            self.planned_uses.clear();
        }
        self.mode = mode;
    }

    /// Barriers collected in [`BarrierMode::Collect`] since the last call.
    pub fn take_collected(&mut self) -> Vec<PlannedBarrier> {
        std::mem::take(&mut self.collected)
    }

    /// Applies `uses` to the tracked state and returns the barriers they need, without
    /// recording them (whatever the barrier mode): a render graph plans a pass this way,
    /// merges the barriers with its own, records them ([`Recorder::record_planned`]), then
    /// records the pass in [`BarrierMode::Collect`].
    pub fn plan(&mut self, uses: &[Use<'_>]) -> Result<Vec<PlannedBarrier>> {
        self.flush_barriers();
        self.planning = true;
        let mode = std::mem::replace(&mut self.mode, BarrierMode::Collect);
        let earlier = std::mem::take(&mut self.collected);
        let mut result = Ok(());
        for u in uses {
            let r = match *u {
                Use::Buffer(b, access) => self.use_buffer(b, access),
                Use::Image(i, range, access) => self.use_image(i, range, access),
            };
            if let Err(e) = r {
                result = Err(e);
                break;
            }
        }
        let planned = std::mem::replace(&mut self.collected, earlier);
        self.mode = mode;
        self.planning = false;
        result.map(|_| planned)
    }

    /// [`Recorder::plan`] for the declared accesses of a bind group (what a tracked
    /// dispatch with it would use).
    pub fn plan_dispatch(&mut self, bind: &BindGroup) -> Result<Vec<PlannedBarrier>> {
        self.check_bind_group(bind)?;
        Ok(self.plan_dispatch_uses(bind, None))
    }

    /// [`Recorder::plan_dispatch`] for an indirect dispatch reading its workgroup counts
    /// from `args` at `offset` (what [`Recorder::dispatch_indirect_tracked`] would use: the
    /// bind group's declared accesses and an indirect read of `args`).
    pub fn plan_dispatch_indirect(
        &mut self,
        bind: &BindGroup,
        args: &Buffer,
        offset: u64,
    ) -> Result<Vec<PlannedBarrier>> {
        self.check_bind_group(bind)?;
        self.check_indirect_args(args, offset)?;
        Ok(self.plan_dispatch_uses(bind, Some(&args.keep())))
    }

    fn plan_dispatch_uses(
        &mut self,
        bind: &BindGroup,
        indirect: Option<&Arc<BufferInner>>,
    ) -> Vec<PlannedBarrier> {
        self.flush_barriers();
        self.planning = true;
        let mode = std::mem::replace(&mut self.mode, BarrierMode::Collect);
        let earlier = std::mem::take(&mut self.collected);
        self.declare_tracked(bind, indirect);
        self.keep.add(bind.keep());
        let planned = std::mem::replace(&mut self.collected, earlier);
        self.mode = mode;
        self.planning = false;
        planned
    }

    /// Declares that `buffer` is accessed as `next` from here on; queues the barrier the
    /// tracked state calls for (none for a read after reads). Fails for a buffer of another
    /// context.
    pub fn use_buffer(&mut self, buffer: &Buffer, next: impl Into<AccessSet>) -> Result<()> {
        let inner = buffer.keep();
        self.check_owner(&inner.shared, || format!("buffer '{}'", inner.name))?;
        self.use_buffer_inner(&inner, next.into());
        Ok(())
    }

    /// Fails unless `image` belongs to this recorder's context.
    pub(super) fn owns_image(&self, image: &Image) -> Result<()> {
        let inner = image.keep();
        self.check_owner(&inner.shared, || format!("image '{}'", inner.name))
    }

    /// Fails unless `bind` (its pipeline) belongs to this recorder's context.
    pub(super) fn check_bind_group(&self, bind: &BindGroup) -> Result<()> {
        let inner = bind.keep();
        self.check_owner(inner.shared(), || "a bind group".to_string())
    }

    /// In planning, records a marker; in Collect mode, consumes a matching marker. Returns
    /// whether the use was planned already (and so must not be applied again).
    fn planned_already(
        &mut self,
        key: usize,
        range: Option<Subresources>,
        next: AccessSet,
    ) -> bool {
        if self.planning {
            self.planned_uses.push((key, range, next));
            return false;
        }
        if self.mode != BarrierMode::Collect {
            return false;
        }
        match self
            .planned_uses
            .iter()
            .position(|u| *u == (key, range, next))
        {
            Some(i) => {
                self.planned_uses.remove(i);
                true
            }
            None => false,
        }
    }

    pub(super) fn use_buffer_inner(&mut self, inner: &Arc<BufferInner>, next: AccessSet) {
        self.keep.add(inner.clone());
        if self.planned_already(Arc::as_ptr(inner) as usize, None, next) {
            return;
        }
        if next.iter().any(AccessType::is_write) && inner.desc.placement.location.host_visible() {
            self.needs_host_barrier = true;
        }
        if let Some(t) = self.local.use_buffer(inner, next) {
            self.queue_buffer(inner, t);
        }
    }

    /// Declares that `range` of `image` is accessed as `next` from here on (layout
    /// included); queues the barriers the tracked state calls for.
    pub fn use_image(
        &mut self,
        image: &Image,
        range: Subresources,
        next: impl Into<AccessSet>,
    ) -> Result<()> {
        self.use_image_checked(image, range, next.into(), false)
    }

    /// As [`Recorder::use_image`], discarding the old contents (the next access overwrites
    /// them all, or the image is a fresh alias-group member).
    pub fn discard_image(
        &mut self,
        image: &Image,
        range: Subresources,
        next: impl Into<AccessSet>,
    ) -> Result<()> {
        self.use_image_checked(image, range, next.into(), true)
    }

    fn use_image_checked(
        &mut self,
        image: &Image,
        range: Subresources,
        next: AccessSet,
        discard: bool,
    ) -> Result<()> {
        let inner = image.keep();
        self.check_owner(&inner.shared, || format!("image '{}'", inner.name))?;
        range.check(image.name(), image.desc())?;
        check_image_access(image, next)?;
        if discard && !next.iter().any(AccessType::is_write) {
            return Err(Error::InvalidArgument(format!(
                "discarding the contents of image '{}' for a read ({next:?}) would read \
                 undefined contents",
                image.name()
            )));
        }
        self.use_image_inner(&inner, range, next, discard);
        Ok(())
    }

    pub(super) fn use_image_inner(
        &mut self,
        inner: &Arc<ImageInner>,
        range: Subresources,
        next: AccessSet,
        discard: bool,
    ) {
        self.keep.add(inner.clone());
        if self.planned_already(Arc::as_ptr(inner) as usize, Some(range), next) {
            return;
        }
        for t in self.local.use_image(inner, &range, next, discard) {
            self.queue_image(inner, t);
        }
    }

    /// Starts using a member of an alias group after another member: waits for every
    /// `prev` access of the previous member (to the shared memory) and discards the new
    /// member's contents. Buffers get a global dependency; images a discarding barrier.
    pub fn alias_switch(
        &mut self,
        prev: impl Into<AccessSet>,
        next_member: AliasUse<'_>,
    ) -> Result<()> {
        let prev = prev.into();
        let member = match next_member {
            AliasUse::Buffer(b, _) => {
                let inner = b.keep();
                self.check_owner(&inner.shared, || format!("buffer '{}'", inner.name))?;
                b.is_alias_member()
            }
            AliasUse::Image(i, _) => {
                let inner = i.keep();
                self.check_owner(&inner.shared, || format!("image '{}'", inner.name))?;
                i.is_alias_member()
            }
        };
        if !member {
            return Err(Error::InvalidArgument(
                "alias_switch names a resource that is not in an alias group".into(),
            ));
        }
        match next_member {
            AliasUse::Buffer(b, next) => {
                self.flush_barriers();
                self.barrier(&[Barrier::global(prev, next)])?;
                let inner = b.keep();
                self.local
                    .declare_buffer(&inner, |s| *s = crate::gpu::track::BufferState::after(next));
                self.keep.add(inner);
            }
            AliasUse::Image(img, next) => {
                let inner = img.keep();
                self.local
                    .declare_image(&inner, &img.all(), |s| *s = Default::default());
                self.barrier(&[Barrier::Image {
                    image: img,
                    range: img.all(),
                    prev,
                    next,
                    discard: true,
                }])?;
            }
        }
        Ok(())
    }

    fn queue(&mut self, planned: PlannedBarrier) {
        match self.mode {
            BarrierMode::Emit => {
                // Barriers in one vkCmdPipelineBarrier2 do not chain: a second barrier on the
                // same resource must come in a later call, or it would not wait for the
                // first (its layout transition included).
                let same = |p: &PlannedBarrier| {
                    (p.buffer.is_some() && p.buffer == planned.buffer)
                        || matches!((p.image, planned.image), (Some((a, _)), Some((b, _))) if a == b)
                };
                if self.pending.iter().any(same) {
                    self.flush_barriers();
                }
                self.pending.push(planned)
            }
            BarrierMode::Collect => self.collected.push(planned),
        }
    }

    fn queue_buffer(&mut self, inner: &Arc<BufferInner>, t: Transition) {
        self.queue(PlannedBarrier {
            resource: inner.name.clone(),
            buffer: Some(inner.raw),
            image: None,
            target: inner.clone(),
            owner: inner.shared.clone(),
            prev: t.prev,
            next: t.next,
            force_visible: t.force_visible,
            old_layout: vk::ImageLayout::UNDEFINED,
            new_layout: vk::ImageLayout::UNDEFINED,
        });
    }

    fn queue_image(&mut self, inner: &Arc<ImageInner>, r: RangeTransition) {
        let t = r.transition;
        self.queue(PlannedBarrier {
            resource: inner.name.clone(),
            buffer: None,
            image: Some((inner.raw, r.range)),
            target: inner.clone(),
            owner: inner.shared.clone(),
            prev: t.prev,
            next: t.next,
            force_visible: t.force_visible,
            old_layout: t.old_layout,
            new_layout: t.new_layout,
        });
    }
}
