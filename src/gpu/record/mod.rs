//! Command recording: passes (debug labels + timestamps), barriers (explicit or derived from
//! declared uses), dispatches, copies, staged uploads and readbacks, then a submission.
//!
//! A [`Recorder`] keeps everything it records alive (reference counts) until it is
//! submitted; submitting stamps each object with the timeline value the submission signals,
//! so dropping a resource afterwards only retires it behind that value. Nothing borrows:
//! kernels, resources and recordings can be dropped in any order, and a leaked
//! [`Submission`] or [`Recorded`] leaks memory, never frees it early.

use super::context::{Context, Shared};
use super::image::{Image, ImageInner, ImageRegion, Subresources};
use super::lifetime::{KeepAlive, Retired};
use super::memory::{Buffer, BufferDesc, BufferInner, require_buffer_usage};
use super::pipeline::{BindGroup, ComputePipeline, Target};
use super::sync::{AccessSet, AccessType, barrier_masks};
use super::track::{RangeTransition, Transition};
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
    /// Subresources of an image; with `discard` their old contents are dropped (old layout
    /// UNDEFINED).
    Image {
        image: &'a Image,
        range: Subresources,
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

/// A barrier derived from declared uses. It keeps the resource it names alive, so
/// recording it later ([`Recorder::record_planned`]) never names a destroyed object.
#[derive(Clone)]
pub struct PlannedBarrier {
    /// The resource's name.
    pub resource: String,
    buffer: Option<vk::Buffer>,
    image: Option<(vk::Image, Subresources)>,
    target: Arc<dyn super::lifetime::Used>,
    pub prev: AccessSet,
    pub next: AccessSet,
    /// Make `prev`'s (already available) writes visible to `next`.
    pub force_visible: bool,
    pub old_layout: vk::ImageLayout,
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

    fn masks(&self) -> super::sync::BarrierMasks {
        barrier_masks(
            self.prev,
            self.next,
            self.force_visible || self.old_layout != self.new_layout,
        )
    }

    /// Appends the Vulkan barrier to `buffers` or `images`.
    fn push_vk(
        &self,
        buffers: &mut Vec<vk::BufferMemoryBarrier2<'static>>,
        images: &mut Vec<vk::ImageMemoryBarrier2<'static>>,
    ) {
        let m = self.masks();
        if let Some(b) = self.buffer {
            buffers.push(super::sync::buffer_barrier_masks(b, 0, vk::WHOLE_SIZE, m));
        }
        if let Some((image, range)) = self.image {
            images.push(super::sync::image_barrier_masks(
                image,
                range.vk(),
                m,
                self.old_layout,
                self.new_layout,
            ));
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

/// Data copied back to the host by a recording; readable once the recording is submitted
/// (reading waits for the submission to complete).
pub struct Readback {
    /// Stamped with the submission's timeline value when the recording is submitted (0
    /// until then).
    staging: Buffer,
}

impl Readback {
    /// The bytes read back (waits for the submission). Fails if the recording was not
    /// submitted.
    pub fn bytes(&self) -> Result<Vec<u8>> {
        self.to_vec::<u8>()
    }

    /// The data read back as a vector of `T` (waits for the submission).
    pub fn to_vec<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        super::memory::not_zero_sized::<T>()?;
        if self.staging.last_use() == 0 {
            return Err(Error::InvalidArgument(format!(
                "readback '{}' read before its recording was submitted",
                self.staging.name()
            )));
        }
        self.staging.read()
    }
}

/// Maximum number of timestamped passes per recorder.
pub const MAX_PASSES: u32 = 128;

/// Timestamp queries of one recording.
struct Queries {
    pool: vk::QueryPool,
    used: u32,
    passes: Vec<Pass>,
}

impl Queries {
    /// Reads the timings (the work has completed).
    fn collect(&self, shared: &Shared) -> Result<Timings> {
        let mut timings = Timings::default();
        if self.used == 0 {
            timings.untimed = self.passes.iter().map(|p| p.name.clone()).collect();
            return Ok(timings);
        }
        let mut raw = vec![0u64; self.used as usize];
        // SAFETY: queries 0..used were written by the completed submission.
        unsafe {
            shared.device.get_query_pool_results(
                self.pool,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .vk("vkGetQueryPoolResults")?;
        let limits = &shared.info.limits;
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
}

/// What a recording hands over when it is submitted: stamped and released at once, except
/// the query and command pools, retired behind the submission's value.
struct Finished {
    shared: Arc<Shared>,
    queries: Queries,
    pool: vk::CommandPool,
    keep: KeepAlive,
    ring_chunks: Vec<u64>,
}

impl Finished {
    /// Stamps everything with `value` (under the queue lock, before submitting).
    fn stamp(&mut self, value: u64) {
        self.keep.stamp_all(value);
        if !self.ring_chunks.is_empty() {
            lock(&self.shared.staging).mark(&self.ring_chunks, value);
            self.ring_chunks.clear();
        }
    }

    /// Retires the pools behind `value` (0: never submitted).
    fn retire(&mut self, value: u64) {
        if !self.ring_chunks.is_empty() {
            lock(&self.shared.staging).mark(&self.ring_chunks, 0);
            self.ring_chunks.clear();
        }
        let pools = [
            Retired::QueryPool(std::mem::take(&mut self.queries.pool)),
            Retired::CommandPool(std::mem::take(&mut self.pool)),
        ];
        self.shared.retire(value, pools);
    }
}

/// Records one command buffer (its own, or a caller's).
pub struct Recorder {
    shared: Arc<Shared>,
    name: String,
    /// Null for a caller's command buffer.
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    queries: Queries,
    open: Vec<usize>,
    keep: KeepAlive,
    ring_chunks: Vec<u64>,
    /// Barriers queued by declared uses, recorded before the next command.
    pending: Vec<PlannedBarrier>,
    mode: BarrierMode,
    collected: Vec<PlannedBarrier>,
    /// Uses already applied by `plan`/`plan_dispatch` (resource address, image range,
    /// access): the tracked command that makes them consumes the entry instead of applying
    /// the use twice.
    planned_uses: Vec<(usize, Option<Subresources>, AccessSet)>,
    /// Set while `plan`/`plan_dispatch` apply uses (they record markers, not consume them).
    planning: bool,
    needs_host_barrier: bool,
    done: bool,
}

impl Context {
    /// Starts recording a command buffer named `name` (shown in validation messages).
    pub fn recorder(&self, name: &str) -> Result<Recorder> {
        Recorder::new(self, name)
    }

    /// Records into a command buffer of the caller's (a renderer's frame), which the caller
    /// submits. Pass timestamps work as usual; [`Recorder::finish`] returns a [`Recorded`]
    /// whose [`Recorded::signal`] gives the timeline signal the submission must carry.
    ///
    /// # Safety
    /// `cmd` must be a primary command buffer of this device in the recording state, for a
    /// queue of this context's queue family, and must not be reset or freed while vkshade
    /// records. The caller must submit `cmd` only with the semaphore signal returned by
    /// [`Recorded::signal`] in the same batch, and must make that submission before any
    /// later vkshade submission or `signal` on this context (timeline values are signalled
    /// in the order they are handed out); until it is submitted, the resources it uses stay
    /// alive (a `Recorded` that is never signalled is treated as never submitted).
    pub unsafe fn record_into(&self, cmd: vk::CommandBuffer, name: &str) -> Result<Recorder> {
        let mut rec = Recorder::empty(self, name, vk::CommandPool::null(), cmd);
        rec.start_queries()?;
        Ok(rec)
    }
}

impl Recorder {
    fn new(ctx: &Context, name: &str) -> Result<Recorder> {
        ctx.shared.collect();
        let device = &ctx.shared.device;
        let info = vk::CommandPoolCreateInfo::default()
            .flags(vk::CommandPoolCreateFlags::TRANSIENT)
            .queue_family_index(ctx.shared.queue_family);
        // SAFETY: valid device and create info.
        let pool = unsafe { device.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
        // From here `rec` owns the pool: its Drop retires it on any failure.
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

    fn empty(ctx: &Context, name: &str, pool: vk::CommandPool, cmd: vk::CommandBuffer) -> Recorder {
        Recorder {
            shared: ctx.shared.clone(),
            name: name.to_string(),
            pool,
            cmd,
            queries: Queries {
                pool: vk::QueryPool::null(),
                used: 0,
                passes: Vec::new(),
            },
            open: Vec::new(),
            keep: KeepAlive::default(),
            ring_chunks: Vec::new(),
            pending: Vec::new(),
            mode: BarrierMode::Emit,
            collected: Vec::new(),
            planned_uses: Vec::new(),
            planning: false,
            needs_host_barrier: false,
            done: false,
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
        self.queries.pool = unsafe { self.shared.device.create_query_pool(&qinfo, None) }
            .vk("vkCreateQueryPool")?;
        // SAFETY: recording; the pool is new.
        unsafe {
            self.shared
                .device
                .cmd_reset_query_pool(self.cmd, self.queries.pool, 0, 2 * MAX_PASSES)
        };
        Ok(())
    }

    /// Whether this recorder writes into a caller's command buffer ([`Context::record_into`]).
    pub fn is_external(&self) -> bool {
        self.pool == vk::CommandPool::null()
    }

    /// The command buffer being recorded, for callers that add their own commands (call
    /// [`Recorder::flush_barriers`] first so pending barriers precede them).
    pub fn raw(&self) -> vk::CommandBuffer {
        self.cmd
    }

    /// The recorder's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The context this recorder records for.
    pub fn context(&self) -> Context {
        Context {
            shared: self.shared.clone(),
        }
    }

    fn device(&self) -> &ash::Device {
        &self.shared.device
    }

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
            match *u {
                Use::Buffer(b, access) => self.use_buffer(b, access),
                Use::Image(i, range, access) => {
                    if let Err(e) = self.use_image(i, range, access) {
                        result = Err(e);
                        break;
                    }
                }
            }
        }
        let planned = std::mem::replace(&mut self.collected, earlier);
        self.mode = mode;
        self.planning = false;
        result.map(|_| planned)
    }

    /// [`Recorder::plan`] for the declared accesses of a bind group (what a tracked
    /// dispatch with it would use).
    pub fn plan_dispatch(&mut self, bind: &BindGroup) -> Vec<PlannedBarrier> {
        self.flush_barriers();
        self.planning = true;
        let mode = std::mem::replace(&mut self.mode, BarrierMode::Collect);
        let earlier = std::mem::take(&mut self.collected);
        let inner = bind.keep();
        for u in &inner.uses {
            match &u.target {
                Target::Buffer(b) => self.use_buffer_inner(b, u.access),
                Target::Image(i, range) => self.use_image_inner(i, *range, u.access, false),
            }
        }
        self.keep.add(inner);
        let planned = std::mem::replace(&mut self.collected, earlier);
        self.mode = mode;
        self.planning = false;
        planned
    }

    /// Records planned barriers (e.g. collected from several kernels and merged by a render
    /// graph) as one `vkCmdPipelineBarrier2`. The resources they name must be alive: they
    /// are the ones the collecting recorder keeps.
    pub fn record_planned(&mut self, planned: &[PlannedBarrier]) {
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
        // now keeps them too.
        unsafe { self.shared.device.cmd_pipeline_barrier2(self.cmd, &dep) };
    }

    fn timestamp(&mut self, stage: vk::PipelineStageFlags2) -> Option<u32> {
        if self.queries.pool == vk::QueryPool::null() || self.queries.used >= 2 * MAX_PASSES {
            return None;
        }
        let q = self.queries.used;
        self.queries.used += 1;
        // SAFETY: recording; query `q` was reset at the start of this command buffer.
        unsafe {
            self.device()
                .cmd_write_timestamp2(self.cmd, stage, self.queries.pool, q)
        };
        Some(q)
    }

    /// Opens a named pass: a debug label, and a timestamp when the queue supports them.
    /// Passes nest; each must be closed with [`Recorder::end_pass`].
    pub fn begin_pass(&mut self, name: &str) {
        self.flush_barriers();
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
        self.open.push(self.queries.passes.len());
        self.queries.passes.push(Pass {
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
        self.flush_barriers();
        let end = if self.queries.passes[i].begin.is_some() {
            self.timestamp(vk::PipelineStageFlags2::BOTTOM_OF_PIPE)
        } else {
            None
        };
        self.queries.passes[i].end = end;
        if let Some(du) = &self.shared.debug_device {
            // SAFETY: matches the label opened in begin_pass.
            unsafe { du.cmd_end_debug_utils_label(self.cmd) };
        }
    }

    // ---- barriers -------------------------------------------------------------------------

    /// Records one pipeline barrier holding all of `barriers` (after any pending ones). The
    /// tracked state of each buffer and image named becomes what the barrier declares. An
    /// image range outside the image, or image accesses without a layout, are errors.
    ///
    /// Explicit barriers are the caller's word: a wrong `prev` (and so a wrong old layout)
    /// is reported by the validation layer, not checked here.
    pub fn barrier(&mut self, barriers: &[Barrier<'_>]) -> Result<()> {
        for b in barriers {
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
                    memory.push(super::sync::memory_barrier(prev, next))
                }
                Barrier::Buffer { buffer, prev, next } => {
                    self.keep.add(buffer.keep());
                    declare_barrier(&mut lock(&buffer.keep().state), prev, next, false);
                    buffers.push(super::sync::buffer_barrier(
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
                    self.keep.add(inner.clone());
                    let mut state = lock(&inner.state);
                    for layer in range.base_layer..range.base_layer + range.layer_count {
                        for mip in range.base_mip..range.base_mip + range.mip_count {
                            let mut s = state.get(mip, layer);
                            declare_barrier(&mut s, prev, next, true);
                            state.set(mip, layer, s);
                        }
                    }
                    drop(state);
                    images.push(super::sync::image_barrier(
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

    /// Declares that `buffer` is accessed as `next` from here on; queues the barrier the
    /// tracked state calls for (none for a read after reads).
    pub fn use_buffer(&mut self, buffer: &Buffer, next: impl Into<AccessSet>) {
        self.use_buffer_inner(&buffer.keep(), next.into());
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

    fn use_buffer_inner(&mut self, inner: &Arc<BufferInner>, next: AccessSet) {
        self.keep.add(inner.clone());
        if self.planned_already(Arc::as_ptr(inner) as usize, None, next) {
            return;
        }
        if next.iter().any(AccessType::is_write) && inner.desc.placement.location.host_visible() {
            self.needs_host_barrier = true;
        }
        let t = lock(&inner.state).apply_buffer(next);
        if let Some(t) = t {
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
        range.check(image.name(), image.desc())?;
        check_image_access(image, next)?;
        self.use_image_inner(&image.keep(), range, next, discard);
        Ok(())
    }

    fn use_image_inner(
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
        let transitions = lock(&inner.state).apply(&range, next, discard);
        for t in transitions {
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
            AliasUse::Buffer(b, _) => b.is_alias_member(),
            AliasUse::Image(i, _) => i.is_alias_member(),
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
                *lock(&b.keep().state) = super::track::BufferState::after(next);
                self.keep.add(b.keep());
            }
            AliasUse::Image(img, next) => {
                let inner = img.keep();
                lock(&inner.state).assume(&img.all(), AccessSet::EMPTY);
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
            BarrierMode::Emit => self.pending.push(planned),
            BarrierMode::Collect => self.collected.push(planned),
        }
    }

    fn queue_buffer(&mut self, inner: &Arc<BufferInner>, t: Transition) {
        self.queue(PlannedBarrier {
            resource: inner.name.clone(),
            buffer: Some(inner.raw),
            image: None,
            target: inner.clone(),
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
            prev: t.prev,
            next: t.next,
            force_visible: t.force_visible,
            old_layout: t.old_layout,
            new_layout: t.new_layout,
        });
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

    // ---- dispatches -----------------------------------------------------------------------

    fn check_dispatch(
        &self,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
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
                Target::Buffer(b) => {
                    let _ = lock(&b.state).apply_buffer(u.access);
                    self.keep.add(b.clone());
                }
                Target::Image(i, range) => {
                    let _ = lock(&i.state).apply(range, u.access, false);
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

    // ---- buffer transfers -----------------------------------------------------------------

    /// Copies `size` bytes between buffers, with the barriers the tracked state calls for
    /// (`TransferRead` of `src`, `TransferWrite` of `dst`).
    pub fn copy_buffer(
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
        if src.raw() == dst.raw() {
            return Err(Error::InvalidArgument(format!(
                "copy within buffer '{}': use two buffers",
                src.name()
            )));
        }
        require_buffer_usage(src, vk::BufferUsageFlags::TRANSFER_SRC, "a copy from it")?;
        require_buffer_usage(dst, vk::BufferUsageFlags::TRANSFER_DST, "a copy to it")?;
        self.use_buffer(src, AccessType::TransferRead);
        self.use_buffer(dst, AccessType::TransferWrite);
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset,
            dst_offset,
            size,
        };
        // SAFETY: recording; bounds checked; both kept alive.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, src.raw(), dst.raw(), &[region])
        };
        Ok(())
    }

    /// Fills a whole buffer with a repeated 32-bit value (a tracked `TransferWrite`).
    pub fn fill_buffer(&mut self, buffer: &Buffer, value: u32) -> Result<()> {
        require_buffer_usage(buffer, vk::BufferUsageFlags::TRANSFER_DST, "fill_buffer")?;
        self.use_buffer(buffer, AccessType::TransferWrite);
        self.flush_barriers();
        // SAFETY: recording; kept alive.
        unsafe {
            self.device()
                .cmd_fill_buffer(self.cmd, buffer.raw(), 0, vk::WHOLE_SIZE, value)
        };
        Ok(())
    }

    /// Staging space holding `bytes`: a chunk of the context's ring when it has room
    /// (waiting for earlier submissions to give space back), else a one-off buffer kept
    /// by this recording. Returns (buffer, offset).
    fn stage(&mut self, what: &str, bytes: &[u8], align: u64) -> Result<(vk::Buffer, u64)> {
        if let Some((id, offset)) = self.shared.ring_alloc(bytes.len() as u64, align)? {
            self.ring_chunks.push(id);
            // SAFETY: the chunk [offset, offset + len) is ours alone until this recording is
            // submitted and completes; the ring's mapping covers it.
            unsafe { self.shared.ring_write(offset, bytes) };
            return Ok((self.shared.ring_buffer(), offset));
        }
        let ctx = self.context();
        let staging = Buffer::new(
            &ctx,
            &format!("{what} staging"),
            BufferDesc::upload(bytes.len() as u64),
        )?;
        staging.write(0, bytes)?;
        let raw = staging.raw();
        self.keep.add(staging.keep());
        Ok((raw, 0))
    }

    /// Copies `data` into `dst` at `offset` through staging (a tracked `TransferWrite`).
    pub fn upload<T: bytemuck::Pod>(
        &mut self,
        dst: &Buffer,
        offset: u64,
        data: &[T],
    ) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Ok(());
        }
        if offset
            .checked_add(bytes.len() as u64)
            .is_none_or(|end| end > dst.size())
        {
            return Err(Error::InvalidArgument(format!(
                "upload of {} bytes at offset {offset} overruns buffer '{}' of {} bytes",
                bytes.len(),
                dst.name(),
                dst.size()
            )));
        }
        let (src, src_offset) = self.stage(dst.name(), bytes, 4)?;
        self.use_buffer(dst, AccessType::TransferWrite);
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset,
            dst_offset: offset,
            size: bytes.len() as u64,
        };
        // SAFETY: recording; staging holds the bytes and stays alive until completion.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, src, dst.raw(), &[region])
        };
        Ok(())
    }

    fn readback_buffer(&mut self, what: &str, size: u64) -> Result<(Buffer, Readback)> {
        let ctx = self.context();
        let staging = Buffer::new(
            &ctx,
            &format!("{what} readback"),
            BufferDesc::readback(size),
        )?;
        self.keep.add(staging.keep());
        self.needs_host_barrier = true;
        let handle = Buffer::from_keep(staging.keep());
        Ok((staging, Readback { staging: handle }))
    }

    /// Copies a whole buffer back to the host (a tracked `TransferRead`).
    pub fn read_back(&mut self, buffer: &Buffer) -> Result<Readback> {
        self.read_back_range(buffer, 0, buffer.size())
    }

    /// Copies `size` bytes from `offset` of `buffer` back to the host.
    pub fn read_back_range(&mut self, buffer: &Buffer, offset: u64, size: u64) -> Result<Readback> {
        if size == 0
            || offset
                .checked_add(size)
                .is_none_or(|end| end > buffer.size())
        {
            return Err(Error::InvalidArgument(format!(
                "readback of {size} bytes at {offset} is empty or outside buffer '{}' ({} bytes)",
                buffer.name(),
                buffer.size()
            )));
        }
        require_buffer_usage(buffer, vk::BufferUsageFlags::TRANSFER_SRC, "a readback")?;
        let (staging, readback) = self.readback_buffer(buffer.name(), size)?;
        self.use_buffer(buffer, AccessType::TransferRead);
        *lock(&staging.keep().state) =
            super::track::BufferState::after(AccessType::TransferWrite.into());
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset: offset,
            dst_offset: 0,
            size,
        };
        // SAFETY: recording; both buffers kept alive; bounds checked.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, buffer.raw(), staging.raw(), &[region])
        };
        Ok(readback)
    }

    // ---- image transfers ------------------------------------------------------------------

    /// Copies tightly packed texels into `region` of `image` through staging (a tracked
    /// `TransferWrite`; a region covering the whole mip level discards its old contents).
    pub fn upload_image(&mut self, image: &Image, region: ImageRegion, data: &[u8]) -> Result<()> {
        region.check(image.name(), image.desc())?;
        image.require_usage(vk::ImageUsageFlags::TRANSFER_DST, "an upload to it")?;
        let block = image.desc().block()?;
        let expected = region.byte_size(image.desc())?;
        if data.len() as u64 != expected {
            return Err(Error::InvalidArgument(format!(
                "region {:?} of image '{}' needs {expected} bytes of texels, got {}",
                region.extent,
                image.name(),
                data.len()
            )));
        }
        // bufferOffset: a multiple of the texel block size and of 4.
        let (src, offset) = self.stage(image.name(), data, block.bytes.max(4))?;
        let whole = region.offset == [0; 3] && region.extent == image.desc().mip_extent(region.mip);
        self.use_image_inner(
            &image.keep(),
            region.subresources(),
            AccessType::TransferWrite.into(),
            whole,
        );
        self.flush_barriers();
        // SAFETY: recording; the subresources are in TRANSFER_DST_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_buffer_to_image(
                self.cmd,
                src,
                image.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[copy_region(&region, offset)],
            )
        };
        Ok(())
    }

    /// Copies `region` of `image` back to the host, tightly packed (a tracked `TransferRead`).
    pub fn read_back_image(&mut self, image: &Image, region: ImageRegion) -> Result<Readback> {
        region.check(image.name(), image.desc())?;
        image.require_usage(vk::ImageUsageFlags::TRANSFER_SRC, "a readback")?;
        let size = region.byte_size(image.desc())?;
        let (staging, readback) = self.readback_buffer(image.name(), size)?;
        self.use_image(image, region.subresources(), AccessType::TransferRead)?;
        *lock(&staging.keep().state) =
            super::track::BufferState::after(AccessType::TransferWrite.into());
        self.flush_barriers();
        // SAFETY: recording; the subresources are in TRANSFER_SRC_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_image_to_buffer(
                self.cmd,
                image.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                staging.raw(),
                &[copy_region(&region, 0)],
            )
        };
        Ok(readback)
    }

    /// Declares `src_region` of `src` a `TransferRead` and `dst_region` of `dst` a
    /// `TransferWrite` (discarding the old contents when it covers the whole mip level),
    /// and records the barriers.
    fn use_for_transfer(
        &mut self,
        src: &Image,
        src_region: &ImageRegion,
        dst: &Image,
        dst_region: &ImageRegion,
    ) -> Result<()> {
        src.require_usage(vk::ImageUsageFlags::TRANSFER_SRC, "a transfer from it")?;
        dst.require_usage(vk::ImageUsageFlags::TRANSFER_DST, "a transfer to it")?;
        self.use_image(src, src_region.subresources(), AccessType::TransferRead)?;
        let whole = dst_region.offset == [0; 3]
            && dst_region.extent == dst.desc().mip_extent(dst_region.mip);
        self.use_image_inner(
            &dst.keep(),
            dst_region.subresources(),
            AccessType::TransferWrite.into(),
            whole,
        );
        self.flush_barriers();
        Ok(())
    }

    /// Copies `src_region` of `src` to `dst` at `dst_region` (same extent; formats of the
    /// same texel size).
    pub fn copy_image(
        &mut self,
        src: &Image,
        src_region: ImageRegion,
        dst: &Image,
        dst_region: ImageRegion,
    ) -> Result<()> {
        src_region.check(src.name(), src.desc())?;
        dst_region.check(dst.name(), dst.desc())?;
        if src_region.extent != dst_region.extent || src_region.layers != dst_region.layers {
            return Err(Error::InvalidArgument(format!(
                "image copy from '{}' {:?}x{} to '{}' {:?}x{}: extents and layer counts must match",
                src.name(),
                src_region.extent,
                src_region.layers,
                dst.name(),
                dst_region.extent,
                dst_region.layers
            )));
        }
        if src.desc().texel_size()? != dst.desc().texel_size()? {
            return Err(Error::InvalidArgument(format!(
                "image copy from '{}' ({:?}) to '{}' ({:?}): texel sizes differ",
                src.name(),
                src.desc().format,
                dst.name(),
                dst.desc().format
            )));
        }
        if src.raw() == dst.raw() {
            return Err(Error::InvalidArgument(format!(
                "image copy within '{}': use two images",
                src.name()
            )));
        }
        self.use_for_transfer(src, &src_region, dst, &dst_region)?;
        let to_offset = |o: [u32; 3]| vk::Offset3D {
            x: o[0] as i32,
            y: o[1] as i32,
            z: o[2] as i32,
        };
        let region = vk::ImageCopy {
            src_subresource: src_region.layers_vk(),
            src_offset: to_offset(src_region.offset),
            dst_subresource: dst_region.layers_vk(),
            dst_offset: to_offset(dst_region.offset),
            extent: vk::Extent3D {
                width: src_region.extent[0],
                height: src_region.extent[1],
                depth: src_region.extent[2],
            },
        };
        // SAFETY: recording; layouts set by the barriers above; regions checked.
        unsafe {
            self.device().cmd_copy_image(
                self.cmd,
                src.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
            )
        };
        Ok(())
    }

    /// Clears `range` of `image` to `color` (float formats; a tracked `TransferWrite` that
    /// discards the old contents).
    pub fn clear_image(
        &mut self,
        image: &Image,
        range: Subresources,
        color: [f32; 4],
    ) -> Result<()> {
        range.check(image.name(), image.desc())?;
        if !image
            .desc()
            .usage
            .contains(vk::ImageUsageFlags::TRANSFER_DST)
        {
            return Err(Error::InvalidArgument(format!(
                "image '{}' lacks TRANSFER_DST usage, needed to clear it",
                image.name()
            )));
        }
        self.use_image_inner(&image.keep(), range, AccessType::TransferWrite.into(), true);
        self.flush_barriers();
        let value = vk::ClearColorValue { float32: color };
        // SAFETY: recording; the range is in TRANSFER_DST_OPTIMAL.
        unsafe {
            self.device().cmd_clear_color_image(
                self.cmd,
                image.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &value,
                &[range.vk()],
            )
        };
        Ok(())
    }

    /// Scales `src_region` of `src` into `dst_region` of `dst` with `filter` (format
    /// features BLIT_SRC/BLIT_DST, and linear filtering for `LINEAR`, are checked).
    pub fn blit_image(
        &mut self,
        src: &Image,
        src_region: ImageRegion,
        dst: &Image,
        dst_region: ImageRegion,
        filter: vk::Filter,
    ) -> Result<()> {
        src_region.check(src.name(), src.desc())?;
        dst_region.check(dst.name(), dst.desc())?;
        let mut src_needs = vk::FormatFeatureFlags::BLIT_SRC;
        if filter == vk::Filter::LINEAR {
            src_needs |= vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR;
        }
        self.shared.require_format(
            src.desc().format,
            src_needs,
            &format!("blitting from '{}'", src.name()),
        )?;
        self.shared.require_format(
            dst.desc().format,
            vk::FormatFeatureFlags::BLIT_DST,
            &format!("blitting to '{}'", dst.name()),
        )?;
        if src_region.layers != dst_region.layers {
            return Err(Error::InvalidArgument(format!(
                "blit from '{}' to '{}': layer counts differ",
                src.name(),
                dst.name()
            )));
        }
        let same = src.raw() == dst.raw();
        if same && src_region.mip == dst_region.mip {
            return Err(Error::InvalidArgument(format!(
                "blit within one mip level of '{}'",
                src.name()
            )));
        }
        self.use_for_transfer(src, &src_region, dst, &dst_region)?;
        let corners = |r: &ImageRegion| {
            [
                vk::Offset3D {
                    x: r.offset[0] as i32,
                    y: r.offset[1] as i32,
                    z: r.offset[2] as i32,
                },
                vk::Offset3D {
                    x: (r.offset[0] + r.extent[0]) as i32,
                    y: (r.offset[1] + r.extent[1]) as i32,
                    z: (r.offset[2] + r.extent[2]) as i32,
                },
            ]
        };
        let blit = vk::ImageBlit {
            src_subresource: src_region.layers_vk(),
            src_offsets: corners(&src_region),
            dst_subresource: dst_region.layers_vk(),
            dst_offsets: corners(&dst_region),
        };
        // SAFETY: recording; layouts set by the barriers above; regions and features checked.
        unsafe {
            self.device().cmd_blit_image(
                self.cmd,
                src.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[blit],
                filter,
            )
        };
        Ok(())
    }

    /// Fills mips 1.. of `image` by successive linear blits from mip 0.
    pub fn generate_mips(&mut self, image: &Image) -> Result<()> {
        let desc = *image.desc();
        for mip in 1..desc.mips {
            self.blit_image(
                image,
                ImageRegion::mip(&desc, mip - 1),
                image,
                ImageRegion::mip(&desc, mip),
                vk::Filter::LINEAR,
            )?;
        }
        Ok(())
    }

    // ---- ending ---------------------------------------------------------------------------

    /// Closes open passes, records pending barriers and makes device writes to host-visible
    /// memory available to the host.
    fn close(&mut self) {
        while !self.open.is_empty() {
            self.end_pass();
        }
        self.flush_barriers();
        if self.needs_host_barrier || self.keep.host_visible {
            // A global barrier names no image: it cannot fail.
            let _ = self.barrier(&[Barrier::global(
                AccessType::TransferWrite | AccessType::ComputeShaderWrite,
                AccessType::HostRead,
            )]);
            self.needs_host_barrier = false;
        }
    }

    fn take_finished(&mut self) -> Finished {
        self.done = true;
        Finished {
            shared: self.shared.clone(),
            queries: Queries {
                pool: std::mem::take(&mut self.queries.pool),
                used: self.queries.used,
                passes: std::mem::take(&mut self.queries.passes),
            },
            pool: std::mem::take(&mut self.pool),
            keep: std::mem::take(&mut self.keep),
            ring_chunks: std::mem::take(&mut self.ring_chunks),
        }
    }

    /// Ends recording and submits without waiting. Dropping the returned [`Submission`]
    /// does not wait: what the work uses stays alive until it completes.
    pub fn submit(self) -> Result<Submission> {
        // SAFETY: no semaphores of the caller's are involved.
        unsafe { self.submit_with(&[], &[]) }
    }

    /// As [`Recorder::submit`], with semaphores of the caller's (e.g. a renderer's frame):
    /// the work starts after the waits and signals `signals` when done.
    ///
    /// # Safety
    /// Every semaphore must be a live semaphore of this device, other than the context's
    /// own timeline ([`Context::timeline`], refused with an error); a binary semaphore waited
    /// on must have a signal submitted before (or with) this submission and no other wait
    /// on it, one signalled must not be signalled already; timeline values must follow the
    /// Vulkan rules (signals increase). The semaphores must stay alive until the submission
    /// completes.
    pub unsafe fn submit_with(
        mut self,
        waits: &[vk::SemaphoreSubmitInfo<'_>],
        signals: &[vk::SemaphoreSubmitInfo<'_>],
    ) -> Result<Submission> {
        if waits
            .iter()
            .chain(signals)
            .any(|s| s.semaphore == self.shared.timeline)
        {
            return Err(Error::InvalidArgument(
                "the context's own timeline semaphore cannot be waited on or signalled through \
                 submit_with: vkshade signals it itself"
                    .into(),
            ));
        }
        if self.is_external() {
            return Err(Error::InvalidArgument(format!(
                "recorder '{}' writes into the caller's command buffer: finish() it and submit that",
                self.name
            )));
        }
        self.close();
        // SAFETY: recording state; ends it.
        unsafe { self.shared.device.end_command_buffer(self.cmd) }.vk("vkEndCommandBuffer")?;
        let cmd = self.cmd;
        let mut finished = self.take_finished();
        let shared = finished.shared.clone();
        let value = shared.submit_locked(|queue, value| {
            finished.stamp(value);
            let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
            let mut all_signals: Vec<vk::SemaphoreSubmitInfo<'_>> = signals.to_vec();
            all_signals.push(shared.timeline_signal(value));
            let submit = vk::SubmitInfo2::default()
                .wait_semaphore_infos(waits)
                .command_buffer_infos(&cmds)
                .signal_semaphore_infos(&all_signals);
            // SAFETY: the command buffer is executable and everything it uses is kept alive
            // until `value`; the queue is externally synchronised by the caller's lock.
            unsafe {
                shared
                    .device
                    .queue_submit2(queue, &[submit], vk::Fence::null())
            }
            .vk("vkQueueSubmit2")
        });
        let value = match value {
            Ok(v) => v,
            Err(e) => {
                finished.retire(0);
                return Err(e);
            }
        };
        Ok(Submission {
            finished: Some(finished),
            value,
        })
    }

    /// Ends recording, submits, waits for completion and returns the pass timings.
    pub fn submit_and_wait(self) -> Result<Timings> {
        self.submit()?.wait()
    }

    /// Finishes a recorder made by [`Context::record_into`]: closes its passes and returns
    /// what the caller's submission needs ([`Recorded::signal`]).
    pub fn finish(mut self) -> Result<Recorded> {
        if !self.is_external() {
            return Err(Error::InvalidArgument(format!(
                "recorder '{}' owns its command buffer: use submit()",
                self.name
            )));
        }
        self.close();
        Ok(Recorded {
            finished: Some(self.take_finished()),
            value: 0,
        })
    }
}

/// Fails unless `access` gives `image` a layout it can be in (image accesses only, and the
/// usage the layout needs).
fn check_image_access(image: &Image, access: AccessSet) -> Result<()> {
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
    state: &mut super::track::AccessState,
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
        super::track::AccessState {
            layout,
            ..super::track::AccessState::after(next)
        }
    } else {
        // `next` reads see `prev`'s writes; later reads chain through them.
        super::track::AccessState {
            last: next,
            reads: next,
            wrote: prev.iter().any(AccessType::is_write) || (image && prev.layout() != layout),
            layout,
        }
    };
}

fn copy_region(region: &ImageRegion, buffer_offset: u64) -> vk::BufferImageCopy {
    vk::BufferImageCopy {
        buffer_offset,
        buffer_row_length: 0,
        buffer_image_height: 0,
        image_subresource: region.layers_vk(),
        image_offset: vk::Offset3D {
            x: region.offset[0] as i32,
            y: region.offset[1] as i32,
            z: region.offset[2] as i32,
        },
        image_extent: vk::Extent3D {
            width: region.extent[0],
            height: region.extent[1],
            depth: region.extent[2],
        },
    }
}

/// A declared use of a resource, for [`Recorder::plan`].
#[derive(Clone, Copy)]
pub enum Use<'a> {
    Buffer(&'a Buffer, AccessSet),
    Image(&'a Image, Subresources, AccessSet),
}

/// A member of an alias group starting to be used (see [`Recorder::alias_switch`]).
pub enum AliasUse<'a> {
    Buffer(&'a Buffer, AccessSet),
    Image(&'a Image, AccessSet),
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.done {
            return;
        }
        // Never submitted: nothing recorded runs. Give back ring space and pools.
        let mut f = self.take_finished();
        f.retire(0);
    }
}

/// Work submitted by [`Recorder::submit`]. Dropping it does not wait; the work's resources
/// stay alive until it completes.
pub struct Submission {
    finished: Option<Finished>,
    value: u64,
}

impl Submission {
    /// The timeline value this submission signals when complete.
    pub fn value(&self) -> u64 {
        self.value
    }

    /// Whether the work has finished (does not block).
    pub fn is_complete(&self) -> bool {
        let f = self.finished.as_ref().expect("present until dropped");
        f.shared.completed() >= self.value
    }

    /// Waits for the work and returns the pass timings; readbacks become readable.
    pub fn wait(self) -> Result<Timings> {
        let f = self.finished.as_ref().expect("present until dropped");
        f.shared.wait_value(self.value, u64::MAX)?;
        let timings = f.queries.collect(&f.shared);
        f.shared.collect();
        timings
    }
}

impl Drop for Submission {
    fn drop(&mut self) {
        if let Some(mut f) = self.finished.take() {
            f.retire(self.value);
        }
    }
}

/// Commands recorded into a caller's command buffer ([`Context::record_into`]) and what
/// they use (staging, readbacks, timestamps).
pub struct Recorded {
    finished: Option<Finished>,
    value: u64,
}

impl Recorded {
    /// Reserves this recording's timeline value, stamps what it uses, and returns the
    /// signal to add to the caller's `vkQueueSubmit2` of the command buffer (see the
    /// contract of [`Context::record_into`]). Calling it again returns the same signal.
    pub fn signal(&mut self) -> vk::SemaphoreSubmitInfo<'static> {
        let shared = self
            .finished
            .as_ref()
            .expect("present until dropped")
            .shared
            .clone();
        let queue = lock(&shared.queue);
        self.signal_locked(&queue)
    }

    /// As [`Recorded::signal`], for a caller that already holds the queue lock (the one in
    /// `ExternalDevice::queue`) for its submission: reserving the value and submitting are
    /// then one step that no other thread can interleave.
    pub fn signal_locked(
        &mut self,
        _queue: &std::sync::MutexGuard<'_, vk::Queue>,
    ) -> vk::SemaphoreSubmitInfo<'static> {
        let f = self.finished.as_mut().expect("present until dropped");
        if self.value == 0 {
            self.value = f.shared.reserve_value();
            f.stamp(self.value);
        }
        f.shared.timeline_signal(self.value)
    }

    /// The timeline value (0 until [`Recorded::signal`]).
    pub fn value(&self) -> u64 {
        self.value
    }

    /// Waits until the caller's submission has completed and returns the pass timings;
    /// readbacks become readable. Fails after `timeout_ns` or if never signalled.
    pub fn wait(self, timeout_ns: u64) -> Result<Timings> {
        let f = self.finished.as_ref().expect("present until dropped");
        if self.value == 0 {
            return Err(Error::InvalidArgument(
                "Recorded::wait before Recorded::signal: the work was never submitted".into(),
            ));
        }
        if !f.shared.wait_value(self.value, timeout_ns)? {
            return Err(Error::InvalidArgument(format!(
                "recorded work (timeline value {}) did not complete within {} ms",
                self.value,
                timeout_ns / 1_000_000
            )));
        }
        f.queries.collect(&f.shared)
    }
}

impl Drop for Recorded {
    fn drop(&mut self) {
        if let Some(mut f) = self.finished.take() {
            f.retire(self.value);
        }
    }
}

impl Recorder {
    /// Creates a buffer and records the upload of `data` into it (kernel construction uses
    /// this: the upload runs with the caller's submission).
    pub fn buffer_with<T: bytemuck::Pod>(
        &mut self,
        name: &str,
        desc: BufferDesc,
        data: &[T],
    ) -> Result<Buffer> {
        let bytes = std::mem::size_of_val(data) as u64;
        if bytes > desc.size {
            return Err(Error::InvalidArgument(format!(
                "{bytes} bytes of data do not fit buffer '{name}' of {} bytes",
                desc.size
            )));
        }
        let desc = desc.usage(vk::BufferUsageFlags::TRANSFER_DST);
        let buffer = Buffer::new(&self.context(), name, desc)?;
        self.upload(&buffer, 0, data)?;
        Ok(buffer)
    }
}

impl Context {
    /// Creates a buffer holding `data`: records the upload, submits and waits. A convenience
    /// for tests and tools; kernels record uploads with [`Recorder::buffer_with`].
    pub fn upload_buffer<T: bytemuck::Pod>(
        &self,
        name: &str,
        desc: BufferDesc,
        data: &[T],
    ) -> Result<Buffer> {
        let mut rec = self.recorder(&format!("upload {name}"))?;
        let buffer = rec.buffer_with(name, desc, data)?;
        rec.submit_and_wait()?;
        Ok(buffer)
    }

    /// Reads a whole buffer back to the host: records the copy, submits and waits.
    pub fn read_buffer<T: bytemuck::Pod>(&self, buffer: &Buffer) -> Result<Vec<T>> {
        let mut rec = self.recorder(&format!("read {}", buffer.name()))?;
        let rb = rec.read_back(buffer)?;
        rec.submit_and_wait()?;
        rb.to_vec()
    }

    /// Uploads mip 0 of `image` (tightly packed texels, all layers) in chunks of at most
    /// `chunk_bytes` (whole rows, slices or layers), each recorded and submitted on its own
    /// and staged through the ring, so a large texture volume needs no staging buffer of its
    /// size. Returns the timeline value of the last chunk (see [`Context::wait_for`]).
    pub fn upload_image_streamed(
        &self,
        image: &Image,
        data: &[u8],
        chunk_bytes: u64,
    ) -> Result<u64> {
        let desc = *image.desc();
        let block = desc.block()?;
        let [w, h, d] = desc.extent;
        if data.len() as u64 != desc.byte_size()? {
            return Err(Error::InvalidArgument(format!(
                "image '{}' needs {} bytes of texels, got {}",
                image.name(),
                desc.byte_size()?,
                data.len()
            )));
        }
        // A row of texel blocks (a row of texels for an uncompressed format).
        let row = block.bytes_for([w, 1, 1]);
        let slice = block.bytes_for([w, h, 1]);
        // Units along the slowest axis: layers (2D arrays), depth slices (3D) or block rows.
        let (units, unit_bytes) = if desc.layers > 1 {
            (desc.layers, slice)
        } else if d > 1 {
            (d, slice)
        } else {
            (h.div_ceil(block.height), row)
        };
        let per_chunk = (chunk_bytes / unit_bytes).clamp(1, units as u64) as u32;
        let mut last = 0;
        let mut start = 0u32;
        while start < units {
            let n = per_chunk.min(units - start);
            let mut region = ImageRegion::whole(&desc);
            if desc.layers > 1 {
                region.base_layer = start;
                region.layers = n;
            } else if d > 1 {
                region.offset[2] = start;
                region.extent[2] = n;
            } else {
                region.offset[1] = start * block.height;
                region.extent[1] = (n * block.height).min(h - region.offset[1]);
            }
            let bytes = &data
                [(start as u64 * unit_bytes) as usize..((start + n) as u64 * unit_bytes) as usize];
            let mut rec = self.recorder(&format!("upload {} part {start}", image.name()))?;
            rec.upload_image(image, region, bytes)?;
            last = rec.submit()?.value();
            start += n;
        }
        Ok(last)
    }
}
