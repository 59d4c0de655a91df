//! Compute dispatches: with the caller's barriers, or with those their bind group's declared
//! accesses call for.

use super::Recorder;
use crate::error::{Error, Result};
use crate::gpu::pipeline::{BindGroup, ComputePipeline, Target};
use crate::gpu::sync::AccessType;
use ash::vk;

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
        self.flush_barriers();
        let inner = bind.keep();
        for u in &inner.uses {
            match &u.target {
                // The caller's barriers stand in for the ones these uses would need.
                Target::Buffer(b) => {
                    let _ = self.local.use_buffer(b, u.access);
                    self.keep.add(b.clone());
                }
                Target::Image(i, range) => {
                    let _ = self.local.use_image(i, range, u.access, false);
                    self.keep.add(i.clone());
                }
            }
        }
        self.record_dispatch(pipeline, bind, push, groups);
        Ok(())
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
        let inner = bind.keep();
        for u in &inner.uses {
            match &u.target {
                Target::Buffer(b) => self.use_buffer_inner(b, u.access),
                Target::Image(i, range) => self.use_image_inner(i, *range, u.access, false),
            }
        }
        self.flush_barriers();
        self.record_dispatch(pipeline, bind, push, groups);
        Ok(())
    }

    fn record_dispatch(
        &mut self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
        push: &[u8],
        groups: [u32; 3],
    ) {
        self.keep.add(pipeline.keep());
        self.keep.add(bind.keep());
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
            if groups.iter().all(|&g| g > 0) {
                device.cmd_dispatch(self.cmd, groups[0], groups[1], groups[2]);
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
