//! Command recording: passes (debug labels + timestamps), barriers (explicit or derived from
//! declared uses), dispatches, copies, staged uploads and readbacks, then a submission.
//!
//! A [`Recorder`] keeps everything it records alive (reference counts) until it is
//! submitted; submitting stamps each object with the timeline value the submission signals,
//! so dropping a resource afterwards only retires it behind that value. Nothing borrows:
//! kernels, resources and recordings can be dropped in any order, and a leaked
//! [`Submission`] or [`Recorded`] leaks memory, never frees it early.
//!
//! Tracked state follows submissions, not recordings (`local`): a recording keeps its uses
//! to itself and joins them to each resource's state when it is submitted, with the joining
//! barriers in a prologue command buffer submitted just before it. Recordings may be
//! submitted in any order, from any thread, or dropped unsubmitted (then they change
//! nothing). Every resource must belong to the recorder's context
//! ([`Error::WrongContext`](crate::error::Error::WrongContext) otherwise).
//!
//! The recorder's commands live beside it, one file per concern: `barrier` (explicit and
//! planned barriers), `uses` (declared uses and the barriers they queue), `dispatch`,
//! `transfer` and `image_transfer` (copies, uploads, readbacks, blits), `timing`
//! (timestamp queries) and `submit` (submission and what it hands back).

mod barrier;
mod dispatch;
mod image_transfer;
mod local;
mod submit;
mod timing;
mod transfer;
mod uses;

pub use barrier::{Barrier, PlannedBarrier};
pub use dispatch::{DISPATCH_INDIRECT_SIZE, dispatched_pipelines};
pub use submit::{Recorded, Submission};
pub use timing::{MAX_PASSES, PassTiming, Timings};
pub use transfer::Readback;
pub use uses::{AliasUse, BarrierMode, Use};

use super::context::{Context, Shared};
use super::image::Subresources;
use super::lifetime::KeepAlive;
use super::sync::AccessSet;
use crate::error::{Result, VkResultExt};
use ash::vk;
use std::ffi::CString;
use std::sync::Arc;
use timing::{Pass, Queries};

/// Records one command buffer (its own, or a caller's).
pub struct Recorder {
    shared: Arc<Shared>,
    name: String,
    /// Null for a caller's command buffer.
    pool: vk::CommandPool,
    /// Every command buffer allocated from `pool` (the first is `cmd`).
    cmds: Vec<vk::CommandBuffer>,
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
    /// This recording's own view of the resources it uses (see `local`).
    local: local::LocalTracker,
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
    ///
    /// Tracking: vkshade cannot put barriers before this recording when the caller submits
    /// it, so it joins each resource to its tracked state at the resource's first use here
    /// (the barrier goes in `cmd` there), and commits the recording's end state at
    /// [`Recorder::finish`]. If another recording is submitted or finished with one of the
    /// same resources in between, `finish` refuses with an error naming the resource (record
    /// in the order you submit); dropping the recorder unfinished changes no tracked state.
    pub unsafe fn record_into(&self, cmd: vk::CommandBuffer, name: &str) -> Result<Recorder> {
        let mut rec = Recorder::empty(self, name, vk::CommandPool::null(), cmd);
        rec.local = local::LocalTracker::joining();
        rec.start_queries()?;
        Ok(rec)
    }
}

impl Recorder {
    fn new(ctx: &Context, name: &str) -> Result<Recorder> {
        ctx.shared.collect();
        let shared = &ctx.shared;
        let device = &shared.device;
        let (pool, cmds) = match shared.take_command_pool() {
            Some(reused) => reused,
            None => {
                let info = vk::CommandPoolCreateInfo::default()
                    .flags(vk::CommandPoolCreateFlags::TRANSIENT)
                    .queue_family_index(shared.queue_family);
                // SAFETY: valid device and create info.
                let pool =
                    unsafe { device.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
                super::recycle::Counters::bump(&shared.counters.command_pools);
                (pool, Vec::new())
            }
        };
        // From here `rec` owns the pool and its command buffers: its Drop retires them on
        // any failure.
        let mut rec = Recorder::empty(ctx, name, pool, vk::CommandBuffer::null());
        rec.cmds = cmds;
        rec.cmd = match rec.cmds.first() {
            Some(&c) => c,
            None => {
                let c = submit::allocate_command_buffer(shared, pool)?;
                rec.cmds.push(c);
                c
            }
        };
        shared.set_name(rec.cmd, name);
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: a fresh command buffer, or one of a pool reset after its work completed
        // (initial state).
        unsafe { device.begin_command_buffer(rec.cmd, &begin) }.vk("vkBeginCommandBuffer")?;
        rec.start_queries()?;
        Ok(rec)
    }

    fn empty(ctx: &Context, name: &str, pool: vk::CommandPool, cmd: vk::CommandBuffer) -> Recorder {
        Recorder {
            shared: ctx.shared.clone(),
            name: name.to_string(),
            pool,
            cmds: Vec::new(),
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
            local: local::LocalTracker::default(),
        }
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

    /// Fails unless `owner` is this recorder's context (`what` names the resource).
    fn check_owner(
        &self,
        owner: &Arc<super::context::Shared>,
        what: impl FnOnce() -> String,
    ) -> Result<()> {
        self.shared
            .check_owner(owner, what, || format!("recorder '{}'", self.name))
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

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("name", &self.name)
            .field("context", &self.shared.id)
            .field("external", &self.is_external())
            .field("passes", &self.queries.passes.len())
            .finish()
    }
}
