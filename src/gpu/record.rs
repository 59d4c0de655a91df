//! Command recording: passes (debug labels + timestamps), barriers, dispatches, copies,
//! staged uploads and readbacks, then one submission.

use super::context::{Context, Shared};
use super::memory::{Buffer, BufferDesc, BufferInner, Image, MemoryUsage};
use super::pipeline::{BindGroup, ComputePipeline};
use super::sync::{AccessSet, AccessType, buffer_barrier, image_barrier, memory_barrier};
use super::validation::lock;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use std::ffi::CString;
use std::sync::Arc;

/// One barrier to record; see [`AccessType`] for the vocabulary.
#[derive(Clone, Copy)]
pub enum Barrier<'a> {
    /// All memory: every resource accessed as `prev` before and as `next` after.
    Global { prev: AccessSet, next: AccessSet },
    Buffer {
        buffer: &'a Buffer,
        prev: AccessSet,
        next: AccessSet,
    },
    /// An image; with `discard` its old contents are dropped (old layout UNDEFINED).
    Image {
        image: &'a Image,
        prev: AccessSet,
        next: AccessSet,
        discard: bool,
    },
}

impl<'a> Barrier<'a> {
    pub fn global(prev: impl Into<AccessSet>, next: impl Into<AccessSet>) -> Self {
        Barrier::Global {
            prev: prev.into(),
            next: next.into(),
        }
    }

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

    pub fn image(image: &'a Image, prev: impl Into<AccessSet>, next: impl Into<AccessSet>) -> Self {
        Barrier::Image {
            image,
            prev: prev.into(),
            next: next.into(),
            discard: false,
        }
    }

    /// An image barrier that discards the old contents (first use, or full overwrite).
    pub fn image_discard(image: &'a Image, next: impl Into<AccessSet>) -> Self {
        Barrier::Image {
            image,
            prev: AccessType::Nothing.into(),
            next: next.into(),
            discard: true,
        }
    }
}

/// GPU time of one named pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PassTiming {
    pub name: String,
    /// Nesting depth (0 = outermost).
    pub depth: usize,
    pub ms: f64,
}

/// GPU times of the passes of one submission, from timestamp queries.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Timings {
    pub passes: Vec<PassTiming>,
    /// Passes that got no timing: beyond the query capacity (`MAX_PASSES`), or no
    /// timestamps on this queue.
    pub untimed: Vec<String>,
}

impl Timings {
    /// Milliseconds of the first pass called `name`.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.passes.iter().find(|p| p.name == name).map(|p| p.ms)
    }

    /// Sum over all outermost passes.
    pub fn total_ms(&self) -> f64 {
        self.passes
            .iter()
            .filter(|p| p.depth == 0)
            .map(|p| p.ms)
            .sum()
    }
}

struct Pass {
    name: String,
    depth: usize,
    begin: Option<u32>,
    end: Option<u32>,
}

/// Data copied back to the host by a [`Recorder`]; readable after the submission completes.
///
/// The staging buffer is shared with the recorder, so dropping a `Readback` before the
/// submission is harmless.
pub struct Readback {
    staging: Arc<BufferInner>,
    submitted: Arc<std::sync::atomic::AtomicBool>,
}

impl Readback {
    /// The bytes read back. Fails if the recorder was not submitted.
    pub fn bytes(&self) -> Result<&[u8]> {
        if !self.submitted.load(std::sync::atomic::Ordering::Acquire) {
            return Err(Error::InvalidArgument(format!(
                "readback '{}' read before its recorder was submitted",
                self.staging.name()
            )));
        }
        self.staging.mapped_bytes()
    }

    /// The data read back as a vector of `T`.
    pub fn to_vec<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        let bytes = self.bytes()?;
        let n = bytes.len() / std::mem::size_of::<T>();
        let mut out = vec![T::zeroed(); n];
        bytemuck::cast_slice_mut::<T, u8>(&mut out)
            .copy_from_slice(&bytes[..n * std::mem::size_of::<T>()]);
        Ok(out)
    }
}

/// Maximum number of timestamped passes per recorder.
pub const MAX_PASSES: u32 = 128;

/// Records one command buffer and submits it.
///
/// Everything recorded (pipelines, bind groups, buffers, images) is borrowed for `'a`, so the
/// compiler rejects dropping a resource that a recorded command still uses.
pub struct Recorder<'a> {
    shared: Arc<Shared>,
    name: String,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    query_pool: vk::QueryPool,
    queries_used: u32,
    passes: Vec<Pass>,
    open: Vec<usize>,
    /// Staging buffers the recorded copies use, kept until the recorder is dropped.
    transient: Vec<Arc<BufferInner>>,
    readbacks: Vec<Arc<std::sync::atomic::AtomicBool>>,
    pending_host_read: bool,
    _borrows: std::marker::PhantomData<&'a ()>,
}

impl Context {
    /// Starts recording a command buffer named `name` (shown in validation messages).
    pub fn recorder<'a>(&self, name: &str) -> Result<Recorder<'a>> {
        Recorder::new(self, name)
    }

    /// Records into a command buffer of the caller's (a renderer's frame), which the caller
    /// submits. Pass timestamps work as usual; [`Recorder::finish`] returns what the
    /// commands use.
    ///
    /// # Safety
    /// `cmd` must be a primary command buffer of this device in the recording state, for a
    /// queue of this context's queue family, and must not be reset or freed while vkshade
    /// records; the [`Recorded`] returned by `finish` must be kept until the submission of
    /// `cmd` has completed.
    pub unsafe fn record_into<'a>(
        &self,
        cmd: vk::CommandBuffer,
        name: &str,
    ) -> Result<Recorder<'a>> {
        let mut rec = Recorder::empty(self, name, vk::CommandPool::null(), cmd);
        rec.start_queries()?;
        Ok(rec)
    }
}

impl<'a> Recorder<'a> {
    fn new(ctx: &Context, name: &str) -> Result<Recorder<'a>> {
        let device = &ctx.shared.device;
        let info = vk::CommandPoolCreateInfo::default()
            .flags(vk::CommandPoolCreateFlags::TRANSIENT)
            .queue_family_index(ctx.shared.queue_family);
        // SAFETY: valid device and create info.
        let pool = unsafe { device.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
        let mut rec = Recorder::empty(ctx, name, pool, vk::CommandBuffer::null());
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid pool.
        rec.cmd =
            unsafe { device.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
        ctx.shared.set_name(rec.cmd, name);
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: fresh command buffer.
        unsafe { device.begin_command_buffer(rec.cmd, &begin) }.vk("vkBeginCommandBuffer")?;
        rec.start_queries()?;
        Ok(rec)
    }

    fn empty(
        ctx: &Context,
        name: &str,
        pool: vk::CommandPool,
        cmd: vk::CommandBuffer,
    ) -> Recorder<'a> {
        Recorder {
            shared: ctx.shared.clone(),
            name: name.to_string(),
            pool,
            cmd,
            query_pool: vk::QueryPool::null(),
            queries_used: 0,
            passes: Vec::new(),
            open: Vec::new(),
            transient: Vec::new(),
            readbacks: Vec::new(),
            pending_host_read: false,
            _borrows: std::marker::PhantomData,
        }
    }

    /// Creates the timestamp pool and resets it in the command buffer (when the queue has
    /// timestamps).
    fn start_queries(&mut self) -> Result<()> {
        if self.shared.info.limits.timestamp_valid_bits == 0 {
            return Ok(());
        }
        let qinfo = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::TIMESTAMP)
            .query_count(2 * MAX_PASSES);
        // SAFETY: valid device and create info.
        self.query_pool = unsafe { self.shared.device.create_query_pool(&qinfo, None) }
            .vk("vkCreateQueryPool")?;
        // SAFETY: recording; the pool is new.
        unsafe {
            self.shared
                .device
                .cmd_reset_query_pool(self.cmd, self.query_pool, 0, 2 * MAX_PASSES)
        };
        Ok(())
    }

    /// Whether this recorder writes into a caller's command buffer ([`Context::record_into`]).
    pub fn is_external(&self) -> bool {
        self.pool == vk::CommandPool::null()
    }

    /// The command buffer being recorded, for callers that add their own commands.
    pub fn raw(&self) -> vk::CommandBuffer {
        self.cmd
    }

    fn device(&self) -> &ash::Device {
        &self.shared.device
    }

    fn timestamp(&mut self, stage: vk::PipelineStageFlags2) -> Option<u32> {
        if self.query_pool == vk::QueryPool::null() || self.queries_used >= 2 * MAX_PASSES {
            return None;
        }
        let q = self.queries_used;
        self.queries_used += 1;
        // SAFETY: recording; query `q` was reset at the start of this command buffer.
        unsafe {
            self.device()
                .cmd_write_timestamp2(self.cmd, stage, self.query_pool, q)
        };
        Some(q)
    }

    /// Opens a named pass: a debug label, and a timestamp when the queue supports them.
    /// Passes nest; each must be closed with [`Recorder::end_pass`].
    pub fn begin_pass(&mut self, name: &str) {
        if let Some(du) = &self.shared.debug_device {
            let cname = CString::new(name.replace('\0', " ")).unwrap_or_default();
            let label = vk::DebugUtilsLabelEXT::default()
                .label_name(&cname)
                .color([0.2, 0.6, 1.0, 1.0]);
            // SAFETY: recording.
            unsafe { du.cmd_begin_debug_utils_label(self.cmd, &label) };
        }
        // BOTTOM_OF_PIPE: the value is written once every earlier command has completed, so
        // a pass's time never includes the tail of the previous one (a TOP_OF_PIPE value can
        // be written early). ALL_COMMANDS means the same but draws a best-practices warning.
        let begin = self.timestamp(vk::PipelineStageFlags2::BOTTOM_OF_PIPE);
        self.open.push(self.passes.len());
        self.passes.push(Pass {
            name: name.to_string(),
            depth: self.open.len() - 1,
            begin,
            end: None,
        });
    }

    /// Closes the innermost open pass.
    pub fn end_pass(&mut self) {
        let Some(i) = self.open.pop() else {
            return;
        };
        let end = if self.passes[i].begin.is_some() {
            self.timestamp(vk::PipelineStageFlags2::BOTTOM_OF_PIPE)
        } else {
            None
        };
        self.passes[i].end = end;
        if let Some(du) = &self.shared.debug_device {
            // SAFETY: matches the label opened in begin_pass.
            unsafe { du.cmd_end_debug_utils_label(self.cmd) };
        }
    }

    /// Records one pipeline barrier holding all of `barriers`.
    pub fn barrier(&mut self, barriers: &[Barrier<'a>]) {
        let mut memory = Vec::new();
        let mut buffers = Vec::new();
        let mut images = Vec::new();
        for b in barriers {
            match *b {
                Barrier::Global { prev, next } => memory.push(memory_barrier(prev, next)),
                Barrier::Buffer { buffer, prev, next } => {
                    buffers.push(buffer_barrier(buffer.raw(), 0, vk::WHOLE_SIZE, prev, next))
                }
                Barrier::Image {
                    image,
                    prev,
                    next,
                    discard,
                } => images.push(image_barrier(
                    image.raw(),
                    image.full_range(),
                    prev,
                    next,
                    discard,
                )),
            }
        }
        let dep = vk::DependencyInfo::default()
            .memory_barriers(&memory)
            .buffer_memory_barriers(&buffers)
            .image_memory_barriers(&images);
        // SAFETY: recording; every handle is alive (borrowed for the call).
        unsafe { self.device().cmd_pipeline_barrier2(self.cmd, &dep) };
    }

    /// Dispatches `groups` workgroups. The bind group must belong to `pipeline`, `push` must
    /// be exactly the shader's push-constant size, and the group counts within the limits.
    pub fn dispatch(
        &mut self,
        pipeline: &'a ComputePipeline,
        bind: &'a BindGroup,
        push: &[u8],
        groups: [u32; 3],
    ) -> Result<()> {
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
        let device = &self.shared.device;
        // SAFETY: recording; pipeline, layout and sets are alive and compatible (checked).
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
        Ok(())
    }

    /// Dispatches enough workgroups to cover `invocations` (rounded up per axis).
    pub fn dispatch_invocations(
        &mut self,
        pipeline: &'a ComputePipeline,
        bind: &'a BindGroup,
        push: &[u8],
        invocations: [u32; 3],
    ) -> Result<()> {
        let l = pipeline.local_size();
        let groups = [0, 1, 2].map(|i| invocations[i].div_ceil(l[i]));
        self.dispatch(pipeline, bind, push, groups)
    }

    /// Copies `size` bytes between buffers (TRANSFER stage; barriers are the caller's).
    pub fn copy_buffer(
        &mut self,
        src: &'a Buffer,
        src_offset: u64,
        dst: &'a Buffer,
        dst_offset: u64,
        size: u64,
    ) -> Result<()> {
        self.copy_raw(src, src_offset, dst, dst_offset, size)
    }

    /// Copy between buffers where the recorder itself keeps one of them alive (staging).
    fn copy_raw(
        &mut self,
        src: &Buffer,
        src_offset: u64,
        dst: &Buffer,
        dst_offset: u64,
        size: u64,
    ) -> Result<()> {
        let fits = |offset: u64, len: u64| offset.checked_add(size).is_some_and(|end| end <= len);
        if size == 0 || !fits(src_offset, src.size()) || !fits(dst_offset, dst.size()) {
            return Err(Error::InvalidArgument(format!(
                "copy of {size} bytes from '{}'+{src_offset} to '{}'+{dst_offset} is empty or out of bounds",
                src.name(),
                dst.name()
            )));
        }
        let region = vk::BufferCopy {
            src_offset,
            dst_offset,
            size,
        };
        // SAFETY: recording; bounds checked above.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, src.raw(), dst.raw(), &[region])
        };
        Ok(())
    }

    /// Fills a whole buffer with a repeated 32-bit value (TRANSFER stage).
    pub fn fill_buffer(&mut self, buffer: &'a Buffer, value: u32) {
        // SAFETY: recording.
        unsafe {
            self.device()
                .cmd_fill_buffer(self.cmd, buffer.raw(), 0, vk::WHOLE_SIZE, value)
        };
    }

    /// Copies `data` into `dst` at `offset` through a staging buffer kept alive until the
    /// submission completes. The copy is a `TransferWrite`: add a barrier before using `dst`.
    pub fn upload<T: bytemuck::Pod>(
        &mut self,
        dst: &'a Buffer,
        offset: u64,
        data: &[T],
    ) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Ok(());
        }
        let staging = self.upload_staging(dst.name(), bytes)?;
        self.copy_raw(&staging, 0, dst, offset, bytes.len() as u64)
    }

    /// Copies tightly packed texel data into a whole image through staging, with the layout
    /// transitions: `prev` is how the image was last used (old contents are discarded).
    pub fn upload_image(
        &mut self,
        image: &'a Image,
        prev: impl Into<AccessSet>,
        data: &[u8],
    ) -> Result<()> {
        let expected = image.desc().byte_size()?;
        if data.len() as u64 != expected {
            return Err(Error::InvalidArgument(format!(
                "image '{}' needs {expected} bytes of texels, got {}",
                image.name(),
                data.len()
            )));
        }
        let staging = self.upload_staging(image.name(), data)?;
        self.barrier(&[Barrier::Image {
            image,
            prev: prev.into(),
            next: AccessType::TransferWrite.into(),
            discard: true,
        }]);
        // SAFETY: recording; the image is in TRANSFER_DST_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_buffer_to_image(
                self.cmd,
                staging.raw(),
                image.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[image.copy_region(0)],
            )
        };
        Ok(())
    }

    /// A host-visible buffer kept alive by this recorder until it is dropped.
    fn staging(&mut self, name: String, size: u64, readback: bool) -> Result<Buffer> {
        let (usage, memory) = if readback {
            (vk::BufferUsageFlags::TRANSFER_DST, MemoryUsage::Readback)
        } else {
            (vk::BufferUsageFlags::TRANSFER_SRC, MemoryUsage::Upload)
        };
        let ctx = Context {
            shared: self.shared.clone(),
        };
        let buffer = Buffer::new(
            &ctx,
            BufferDesc {
                name,
                size,
                usage,
                memory,
            },
        )?;
        self.transient.push(buffer.keep());
        Ok(buffer)
    }

    /// A staging buffer holding `bytes`, to copy from.
    fn upload_staging(&mut self, name: &str, bytes: &[u8]) -> Result<Buffer> {
        let mut staging = self.staging(format!("{name} staging"), bytes.len() as u64, false)?;
        staging.write(0, bytes)?;
        Ok(staging)
    }

    /// A staging buffer to copy `size` bytes into, and the readback sharing it.
    fn readback_staging(&mut self, name: &str, size: u64) -> Result<(Buffer, Readback)> {
        let staging = self.staging(format!("{name} readback"), size, true)?;
        let submitted = Arc::new(std::sync::atomic::AtomicBool::new(false));
        self.readbacks.push(submitted.clone());
        self.pending_host_read = true;
        let readback = Readback {
            staging: staging.keep(),
            submitted,
        };
        Ok((staging, readback))
    }

    /// Copies a whole buffer back to the host. `prev` is the buffer's last access; afterwards
    /// the buffer has been accessed as `TransferRead`.
    pub fn read_back(
        &mut self,
        buffer: &'a Buffer,
        prev: impl Into<AccessSet>,
    ) -> Result<Readback> {
        let (staging, readback) = self.readback_staging(buffer.name(), buffer.size())?;
        self.barrier(&[Barrier::buffer(buffer, prev, AccessType::TransferRead)]);
        self.copy_raw(buffer, 0, &staging, 0, buffer.size())?;
        Ok(readback)
    }

    /// Copies a whole image back to the host (tightly packed). `prev` is its last access;
    /// afterwards the image is in the `TransferRead` layout.
    pub fn read_back_image(
        &mut self,
        image: &'a Image,
        prev: impl Into<AccessSet>,
    ) -> Result<Readback> {
        let size = image.desc().byte_size()?;
        let (staging, readback) = self.readback_staging(image.name(), size)?;
        self.barrier(&[Barrier::image(image, prev, AccessType::TransferRead)]);
        // SAFETY: recording; the image is in TRANSFER_SRC_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_image_to_buffer(
                self.cmd,
                image.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                staging.raw(),
                &[image.copy_region(0)],
            )
        };
        Ok(readback)
    }

    /// Closes open passes and makes readbacks visible to the host.
    fn close(&mut self) {
        while !self.open.is_empty() {
            self.end_pass();
        }
        if self.pending_host_read {
            self.barrier(&[Barrier::global(
                AccessType::TransferWrite,
                AccessType::HostRead,
            )]);
            self.pending_host_read = false;
        }
    }

    /// Ends recording and submits without waiting. `waits` and `signals` are semaphores of
    /// the caller's (e.g. a renderer's frame): the work starts after the waits and signals
    /// when done. The returned [`Submission`] keeps everything recorded alive; dropping it
    /// waits for completion.
    pub fn submit(
        mut self,
        waits: &[vk::SemaphoreSubmitInfo<'_>],
        signals: &[vk::SemaphoreSubmitInfo<'_>],
    ) -> Result<Submission<'a>> {
        if self.is_external() {
            return Err(Error::InvalidArgument(format!(
                "recorder '{}' writes into the caller's command buffer: finish() it and submit that",
                self.name
            )));
        }
        self.close();
        let device = self.shared.device.clone();
        // SAFETY: recording state; ends it.
        unsafe { device.end_command_buffer(self.cmd) }.vk("vkEndCommandBuffer")?;
        // SAFETY: valid device.
        let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
            .vk("vkCreateFence")?;
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = vk::SubmitInfo2::default()
            .wait_semaphore_infos(waits)
            .command_buffer_infos(&cmds)
            .signal_semaphore_infos(signals);
        let submitted = {
            let queue = lock(&self.shared.queue);
            // SAFETY: the command buffer is executable; the queue is externally synchronised
            // by the lock.
            unsafe { device.queue_submit2(*queue, &[submit], fence) }.vk("vkQueueSubmit2")
        };
        if let Err(e) = submitted {
            // SAFETY: never submitted.
            unsafe { device.destroy_fence(fence, None) };
            return Err(e);
        }
        Ok(Submission {
            recorder: Some(self),
            fence,
        })
    }

    /// Ends recording, submits, waits for completion and returns the pass timings.
    pub fn submit_and_wait(self) -> Result<Timings> {
        self.submit(&[], &[])?.wait()
    }

    /// Marks readbacks ready and reads the timestamps (the work has completed).
    fn complete(&self) -> Result<Timings> {
        for flag in &self.readbacks {
            flag.store(true, std::sync::atomic::Ordering::Release);
        }
        self.collect_timings()
    }

    /// Finishes a recorder made by [`Context::record_into`]: closes its passes and returns
    /// what the recorded commands use, to keep until the caller's submission completes.
    pub fn finish(mut self) -> Result<Recorded<'a>> {
        if !self.is_external() {
            return Err(Error::InvalidArgument(format!(
                "recorder '{}' owns its command buffer: use submit()",
                self.name
            )));
        }
        self.close();
        Ok(Recorded { recorder: self })
    }

    fn collect_timings(&self) -> Result<Timings> {
        let mut timings = Timings::default();
        if self.queries_used == 0 {
            timings.untimed = self.passes.iter().map(|p| p.name.clone()).collect();
            return Ok(timings);
        }
        let mut raw = vec![0u64; self.queries_used as usize];
        // SAFETY: queries 0..queries_used were written by the completed submission.
        unsafe {
            self.device().get_query_pool_results(
                self.query_pool,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .vk("vkGetQueryPoolResults")?;
        let limits = &self.shared.info.limits;
        let mask = if limits.timestamp_valid_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << limits.timestamp_valid_bits) - 1
        };
        for p in &self.passes {
            let (Some(b), Some(e)) = (p.begin, p.end) else {
                timings.untimed.push(p.name.clone());
                continue;
            };
            let ticks = raw[e as usize].wrapping_sub(raw[b as usize]) & mask;
            timings.passes.push(PassTiming {
                name: p.name.clone(),
                depth: p.depth,
                ms: ticks as f64 * limits.timestamp_period_ns as f64 * 1e-6,
            });
        }
        Ok(timings)
    }

    /// The recorder's name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

impl Drop for Recorder<'_> {
    fn drop(&mut self) {
        // SAFETY: either completed (Submission waits before dropping it; Recorded's contract
        // is that the caller's submission completed) or never submitted. An external command
        // buffer belongs to the caller and is not freed here (its pool is null).
        unsafe {
            self.shared.device.destroy_query_pool(self.query_pool, None);
            self.shared.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// Work submitted by [`Recorder::submit`]. Dropping it waits for the work to finish.
pub struct Submission<'a> {
    recorder: Option<Recorder<'a>>,
    fence: vk::Fence,
}

impl Submission<'_> {
    /// Whether the work has finished (does not block).
    pub fn is_complete(&self) -> Result<bool> {
        let r = self.recorder.as_ref().expect("present until dropped");
        // SAFETY: fence of this device.
        unsafe { r.shared.device.get_fence_status(self.fence) }.vk("vkGetFenceStatus")
    }

    /// Waits for the work and returns the pass timings; readbacks become readable.
    pub fn wait(mut self) -> Result<Timings> {
        let r = self.recorder.as_ref().expect("present until dropped");
        // SAFETY: fence of this device, submitted.
        unsafe {
            r.shared
                .device
                .wait_for_fences(&[self.fence], true, u64::MAX)
        }
        .vk("vkWaitForFences")?;
        let timings = r.complete();
        self.release();
        timings
    }

    fn release(&mut self) {
        if let Some(r) = self.recorder.take() {
            // SAFETY: the fence was waited for (or the wait failed: the device is lost and
            // nothing executes any more).
            unsafe { r.shared.device.destroy_fence(self.fence, None) };
        }
    }
}

impl Drop for Submission<'_> {
    fn drop(&mut self) {
        if let Some(r) = &self.recorder {
            // SAFETY: fence of this device; waiting makes the recorder's resources idle.
            let _ = unsafe {
                r.shared
                    .device
                    .wait_for_fences(&[self.fence], true, u64::MAX)
            };
        }
        self.release();
    }
}

/// Commands recorded into a caller's command buffer ([`Context::record_into`]) and the
/// resources they use (staging, readbacks, timestamps).
pub struct Recorded<'a> {
    recorder: Recorder<'a>,
}

impl Recorded<'_> {
    /// Call once the caller's submission of the command buffer has completed: readbacks
    /// become readable and the pass timings are returned.
    ///
    /// # Safety
    /// The command buffer must have completed execution.
    pub unsafe fn complete(self) -> Result<Timings> {
        self.recorder.complete()
    }
}

impl Context {
    /// Creates a device-local buffer holding `data` (uploaded through staging, followed by a
    /// barrier that makes the data visible to every compute-shader and transfer access,
    /// [`sync::COMPUTE_OR_TRANSFER`](super::sync::COMPUTE_OR_TRANSFER)).
    pub fn upload_buffer<T: bytemuck::Pod>(
        &self,
        mut desc: BufferDesc,
        data: &[T],
    ) -> Result<Buffer> {
        let bytes = std::mem::size_of_val(data) as u64;
        if bytes > desc.size {
            return Err(Error::InvalidArgument(format!(
                "{bytes} bytes of data do not fit buffer '{}' of {} bytes",
                desc.name, desc.size
            )));
        }
        desc.usage |= vk::BufferUsageFlags::TRANSFER_DST;
        let buffer = Buffer::new(self, desc)?;
        let mut rec = self.recorder(&format!("upload {}", buffer.name()))?;
        rec.upload(&buffer, 0, data)?;
        rec.barrier(&[Barrier::buffer(
            &buffer,
            AccessType::TransferWrite,
            super::sync::COMPUTE_OR_TRANSFER,
        )]);
        rec.submit_and_wait()?;
        Ok(buffer)
    }

    /// Reads a whole buffer back to the host. `prev` is how the buffer was last accessed.
    pub fn read_buffer<T: bytemuck::Pod>(
        &self,
        buffer: &Buffer,
        prev: impl Into<AccessSet>,
    ) -> Result<Vec<T>> {
        let mut rec = self.recorder(&format!("read {}", buffer.name()))?;
        let rb = rec.read_back(buffer, prev)?;
        rec.submit_and_wait()?;
        rb.to_vec()
    }
}
