//! Compute dispatches: with the caller's barriers, or with those their bind group's declared
//! accesses call for; direct (workgroup counts from the host) or indirect (read by the GPU
//! from a buffer an earlier command wrote).

use super::Recorder;
use crate::error::{Error, Result};
use crate::gpu::image::{ImageInner, Subresources};
use crate::gpu::memory::{Buffer, BufferInner, require_buffer_usage};
use crate::gpu::pipeline::{BindGroup, BindGroupInner, ComputePipeline, Target};
use crate::gpu::sync::{AccessSet, AccessType};
use ash::vk;
use std::sync::Arc;

/// Bytes of a `VkDispatchIndirectCommand` (three u32 workgroup counts).
pub const DISPATCH_INDIRECT_SIZE: u64 = 12;

/// Dispatches recorded so far in this process, per pipeline name (all contexts together).
static DISPATCHED: std::sync::Mutex<std::collections::BTreeMap<String, u64>> =
    std::sync::Mutex::new(std::collections::BTreeMap::new());

/// How many dispatches of each pipeline (by its name: the embedded module's, e.g.
/// `"srbf/shade"`, for vkshade's own) were recorded in this process so far, on any context.
/// `vkshade validate` checks with it that every module of spv/ ran.
pub fn dispatched_pipelines() -> std::collections::BTreeMap<String, u64> {
    crate::gpu::validation::lock(&DISPATCHED).clone()
}

/// The uses of a dispatch: the bind group's declared accesses, plus an indirect read of
/// `indirect`, one use per resource (or per image subresource).
///
/// Bindings of one resource are merged into one access: applied one after another, a write
/// binding followed by a read binding of the same buffer would queue the read's barrier
/// before the dispatch (which then writes) and leave the tracker believing the last access
/// a read, so a later read of the same kind got no barrier after the dispatch's write.
pub(super) fn dispatch_uses(
    inner: &BindGroupInner,
    indirect: Option<&Arc<BufferInner>>,
) -> Vec<(Target, AccessSet)> {
    let mut buffers: Vec<(Arc<BufferInner>, AccessSet)> = Vec::new();
    // Per image, the ranges its bindings cover and their accesses.
    type Ranges = Vec<(Subresources, AccessSet)>;
    let mut images: Vec<(Arc<ImageInner>, Ranges)> = Vec::new();
    let bound = inner.uses.iter().map(|u| (&u.target, u.access));
    let args = indirect.map(|b| Target::Buffer(b.clone()));
    let all = bound.chain(args.iter().map(|t| (t, AccessType::IndirectBuffer.into())));
    for (target, access) in all {
        match target {
            Target::Buffer(b) => match buffers.iter_mut().find(|(o, _)| Arc::ptr_eq(o, b)) {
                Some((_, a)) => *a = *a | access,
                None => buffers.push((b.clone(), access)),
            },
            Target::Image(i, range) => match images.iter_mut().find(|(o, _)| Arc::ptr_eq(o, i)) {
                Some((_, ranges)) => ranges.push((*range, access)),
                None => images.push((i.clone(), vec![(*range, access)])),
            },
        }
    }
    let mut uses: Vec<(Target, AccessSet)> = buffers
        .into_iter()
        .map(|(b, a)| (Target::Buffer(b), a))
        .collect();
    for (image, ranges) in images {
        let first = ranges[0].0;
        if ranges.iter().all(|(r, _)| *r == first) {
            let access = ranges.iter().fold(AccessSet::EMPTY, |u, (_, a)| u | *a);
            uses.push((Target::Image(image, first), access));
            continue;
        }
        // Different ranges of one image (say mip 0 sampled, mip 1 stored): one use per
        // subresource, with the accesses of every binding that covers it. Bindings that
        // overlap share a layout (checked when the group was made).
        let mut subs: Vec<((u32, u32), AccessSet)> = Vec::new();
        for (range, access) in &ranges {
            for sub in range.iter() {
                match subs.iter_mut().find(|(s, _)| *s == sub) {
                    Some((_, a)) => *a = *a | *access,
                    None => subs.push((sub, *access)),
                }
            }
        }
        for ((mip, layer), access) in subs {
            let one = Subresources {
                base_mip: mip,
                mip_count: 1,
                base_layer: layer,
                layer_count: 1,
            };
            uses.push((Target::Image(image.clone(), one), access));
        }
    }
    uses
}

/// Where a recorded dispatch takes its workgroup counts from.
#[derive(Clone, Copy)]
enum Groups {
    /// From the host.
    Direct([u32; 3]),
    /// From a `VkDispatchIndirectCommand` in a buffer (kept alive by the caller) at an offset.
    Indirect(vk::Buffer, u64),
}

impl Recorder {
    fn check_dispatch(
        &self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        groups: [u32; 3],
    ) -> Result<()> {
        let p = pipeline.keep();
        self.check_owner(p.shared(), || format!("pipeline '{}'", pipeline.name()))?;
        self.check_bind_group(bind)?;
        let interface_err = |reason: String| Error::Interface {
            pipeline: pipeline.name().to_string(),
            reason,
        };
        if !bind.is_for(pipeline) {
            return Err(interface_err(
                "bind group was created for a different pipeline".into(),
            ));
        }
        if push.len() as u32 != pipeline.push_constant_size() {
            return Err(interface_err(format!(
                "push constants are {} bytes, the shader declares {}",
                push.len(),
                pipeline.push_constant_size()
            )));
        }
        let max = self.shared.info.limits.max_compute_work_group_count;
        for axis in 0..3 {
            if groups[axis] > max[axis] {
                return Err(Error::Limit {
                    what: format!(
                        "workgroup count along axis {axis} for '{}'",
                        pipeline.name()
                    ),
                    requested: groups[axis] as u64,
                    limit_name: "maxComputeWorkGroupCount",
                    limit: max[axis] as u64,
                });
            }
        }
        Ok(())
    }

    /// Dispatches `groups` workgroups; barriers are the caller's. The bind group's declared
    /// accesses still update the tracked state (as if the caller's barriers were right), so
    /// later tracked uses order themselves after this dispatch.
    pub fn dispatch(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        groups: [u32; 3],
    ) -> Result<()> {
        self.check_dispatch(pipeline, bind, push, groups)?;
        self.declare_untracked(bind, None);
        self.record_dispatch(pipeline, bind, push, Groups::Direct(groups));
        Ok(())
    }

    /// Updates the tracked state with a dispatch's uses without queueing barriers (the
    /// caller's barriers stand in for the ones these uses would need).
    fn declare_untracked(&mut self, bind: &BindGroup, indirect: Option<&Arc<BufferInner>>) {
        self.flush_barriers();
        let inner = bind.keep();
        for (target, access) in dispatch_uses(&inner, indirect) {
            match &target {
                Target::Buffer(b) => {
                    let _ = self.local.use_buffer(b, access);
                    self.keep.add(b.clone());
                }
                Target::Image(i, range) => {
                    let _ = self.local.use_image(i, range, access, false);
                    self.keep.add(i.clone());
                }
            }
        }
    }

    /// Applies a dispatch's uses through the tracker, queueing the barriers they need.
    pub(super) fn declare_tracked(
        &mut self,
        bind: &BindGroup,
        indirect: Option<&Arc<BufferInner>>,
    ) {
        let inner = bind.keep();
        for (target, access) in dispatch_uses(&inner, indirect) {
            match &target {
                Target::Buffer(b) => self.use_buffer_inner(b, access),
                Target::Image(i, range) => self.use_image_inner(i, *range, access, false),
            }
        }
    }

    /// Dispatches `groups` workgroups with the barriers its declared accesses call for
    /// (batched into one barrier before the dispatch).
    pub fn dispatch_tracked(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        groups: [u32; 3],
    ) -> Result<()> {
        self.check_dispatch(pipeline, bind, push, groups)?;
        self.declare_tracked(bind, None);
        self.flush_barriers();
        self.record_dispatch(pipeline, bind, push, Groups::Direct(groups));
        Ok(())
    }

    /// Checks an indirect dispatch: the pipeline and bind group as for a direct one, and
    /// `args` (this context's, with INDIRECT_BUFFER usage, a 4-aligned `offset` and a whole
    /// `VkDispatchIndirectCommand` inside it).
    fn check_indirect(
        &self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        args: &Buffer,
        offset: u64,
    ) -> Result<()> {
        self.check_dispatch(pipeline, bind, push, [0; 3])?;
        self.check_indirect_args(args, offset)
    }

    pub(super) fn check_indirect_args(&self, args: &Buffer, offset: u64) -> Result<()> {
        let inner = args.keep();
        self.check_owner(&inner.shared, || format!("buffer '{}'", inner.name))?;
        require_buffer_usage(
            args,
            vk::BufferUsageFlags::INDIRECT_BUFFER,
            "indirect dispatch arguments",
        )?;
        if !offset.is_multiple_of(4)
            || offset
                .checked_add(DISPATCH_INDIRECT_SIZE)
                .is_none_or(|end| end > args.size())
        {
            return Err(Error::InvalidArgument(format!(
                "indirect dispatch arguments at offset {offset} of buffer '{}' ({} bytes): the \
                 offset must be a multiple of 4 and the {DISPATCH_INDIRECT_SIZE} bytes of \
                 VkDispatchIndirectCommand must lie inside the buffer",
                args.name(),
                args.size()
            )));
        }
        Ok(())
    }

    /// Dispatches the workgroup counts the GPU reads from `args` at `offset` (a
    /// `VkDispatchIndirectCommand`: three u32, written by an earlier command); barriers
    /// are the caller's, as for [`Recorder::dispatch`] (the indirect read of `args` still
    /// updates the tracked state). The counts are not known here, so the GPU must keep them
    /// within `maxComputeWorkGroupCount`; a zero count dispatches nothing.
    pub fn dispatch_indirect(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        args: &Buffer,
        offset: u64,
    ) -> Result<()> {
        self.check_indirect(pipeline, bind, push, args, offset)?;
        let a = args.keep();
        self.declare_untracked(bind, Some(&a));
        self.record_dispatch(pipeline, bind, push, Groups::Indirect(a.raw, offset));
        Ok(())
    }

    /// [`Recorder::dispatch_indirect`] with the barriers its uses call for: the bind
    /// group's declared accesses and an [`AccessType::IndirectBuffer`] read of `args`
    /// (merged with its binding's access when `args` is also bound), batched into one
    /// barrier before the dispatch.
    pub fn dispatch_indirect_tracked(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        args: &Buffer,
        offset: u64,
    ) -> Result<()> {
        self.check_indirect(pipeline, bind, push, args, offset)?;
        let a = args.keep();
        self.declare_tracked(bind, Some(&a));
        self.flush_barriers();
        self.record_dispatch(pipeline, bind, push, Groups::Indirect(a.raw, offset));
        Ok(())
    }

    fn record_dispatch(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        groups: Groups,
    ) {
        self.keep.add(pipeline.keep());
        self.keep.add(bind.keep());
        *crate::gpu::validation::lock(&DISPATCHED)
            .entry(pipeline.name().to_string())
            .or_default() += 1;
        if bind.keep().uses.iter().any(|u| {
            u.access.iter().any(AccessType::is_write)
                && matches!(&u.target, Target::Buffer(b) if b.desc.placement.location.host_visible())
        }) {
            self.needs_host_barrier = true;
        }
        let device = &self.shared.device;
        // SAFETY: recording; pipeline, layout and sets are alive (kept) and compatible
        // (checked).
        unsafe {
            device.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, pipeline.raw());
            if !bind.sets().is_empty() {
                device.cmd_bind_descriptor_sets(
                    self.cmd,
                    vk::PipelineBindPoint::COMPUTE,
                    pipeline.layout(),
                    0,
                    bind.sets(),
                    &[],
                );
            }
            if !push.is_empty() {
                device.cmd_push_constants(
                    self.cmd,
                    pipeline.layout(),
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    push,
                );
            }
            match groups {
                Groups::Direct(g) => {
                    if g.iter().all(|&n| n > 0) {
                        device.cmd_dispatch(self.cmd, g[0], g[1], g[2]);
                    }
                }
                Groups::Indirect(buffer, offset) => {
                    device.cmd_dispatch_indirect(self.cmd, buffer, offset)
                }
            }
        }
    }

    fn groups_for(pipeline: &ComputePipeline, invocations: [u32; 3]) -> [u32; 3] {
        let l = pipeline.local_size();
        [0, 1, 2].map(|i| invocations[i].div_ceil(l[i]))
    }

    /// [`Recorder::dispatch`] with enough workgroups to cover `invocations`.
    pub fn dispatch_invocations(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        invocations: [u32; 3],
    ) -> Result<()> {
        self.dispatch(
            pipeline,
            bind,
            push,
            Self::groups_for(pipeline, invocations),
        )
    }

    /// [`Recorder::dispatch_tracked`] with enough workgroups to cover `invocations`.
    pub fn dispatch_invocations_tracked(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        invocations: [u32; 3],
    ) -> Result<()> {
        self.dispatch_tracked(
            pipeline,
            bind,
            push,
            Self::groups_for(pipeline, invocations),
        )
    }
}
