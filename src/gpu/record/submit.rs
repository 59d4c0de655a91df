//! Ending a recording: submitting it ([`Submission`]) or handing a caller's command buffer
//! back ([`Recorded`]), with what the work uses kept alive until its timeline value.

use super::timing::Queries;
use super::{Recorder, Timings};
use crate::error::{Error, Result, VkResultExt};
use crate::gpu::Barrier;
use crate::gpu::context::Shared;
use crate::gpu::lifetime::{KeepAlive, Retired};
use crate::gpu::sync::AccessType;
use crate::gpu::validation::lock;
use ash::vk;
use std::sync::Arc;

/// What a recording hands over when it is submitted: stamped and released at once, except
/// the query and command pools, retired behind the submission's value.
pub(super) struct Finished {
    shared: Arc<Shared>,
    queries: Queries,
    pool: vk::CommandPool,
    /// Every command buffer allocated from `pool` (pooled with it).
    cmds: Vec<vk::CommandBuffer>,
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
    pub(super) fn retire(&mut self, value: u64) {
        if !self.ring_chunks.is_empty() {
            lock(&self.shared.staging).mark(&self.ring_chunks, 0);
            self.ring_chunks.clear();
        }
        let pools = [
            Retired::QueryPool(std::mem::take(&mut self.queries.pool)),
            Retired::CommandPool(
                std::mem::take(&mut self.pool),
                std::mem::take(&mut self.cmds),
            ),
        ];
        self.shared.retire(value, pools);
    }
}

impl Recorder {
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

    pub(super) fn take_finished(&mut self) -> Finished {
        self.done = true;
        Finished {
            shared: self.shared.clone(),
            queries: Queries {
                pool: std::mem::take(&mut self.queries.pool),
                used: self.queries.used,
                passes: std::mem::take(&mut self.queries.passes),
            },
            pool: std::mem::take(&mut self.pool),
            cmds: std::mem::take(&mut self.cmds),
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
    /// own timeline ([`Context::timeline`](crate::gpu::Context::timeline), refused with an error); a binary semaphore waited
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
        let pool = self.pool;
        let local = std::mem::take(&mut self.local);
        let recorder = self.name.clone();
        let mut finished = self.take_finished();
        let shared = finished.shared.clone();
        let mut resolved = None;
        let mut pool_cmds = std::mem::take(&mut finished.cmds);
        let value = shared.submit_locked(
            || {
                // Join this recording to the tracked state as of the submissions before it
                // (under the queue lock, so in submission order).
                let joins = resolved.insert(local.resolve(&recorder)?);
                if joins.is_empty() {
                    return Ok(None);
                }
                // The pool's second command buffer, allocated the first time it is needed.
                let spare = match pool_cmds.get(1) {
                    Some(&c) => c,
                    None => {
                        let c = allocate_command_buffer(&shared, pool)?;
                        pool_cmds.push(c);
                        c
                    }
                };
                record_prologue(&shared, spare, &recorder, joins)?;
                Ok(Some(spare))
            },
            |queue, value, prologue| {
                finished.stamp(value);
                let cmds: Vec<_> = prologue
                    .into_iter()
                    .chain([cmd])
                    .map(|c| vk::CommandBufferSubmitInfo::default().command_buffer(c))
                    .collect();
                let mut all_signals: Vec<vk::SemaphoreSubmitInfo<'_>> = signals.to_vec();
                all_signals.push(shared.timeline_signal(value));
                let submit = vk::SubmitInfo2::default()
                    .wait_semaphore_infos(waits)
                    .command_buffer_infos(&cmds)
                    .signal_semaphore_infos(&all_signals);
                // SAFETY: the command buffers are executable and everything they use is kept
                // alive until `value`; the queue is externally synchronised by the lock held.
                unsafe {
                    shared
                        .device
                        .queue_submit2(queue, &[submit], vk::Fence::null())
                }
                .vk("vkQueueSubmit2")
            },
        );
        finished.cmds = pool_cmds;
        let value = match value {
            Ok(v) => v,
            Err(e) => {
                // Nothing ran: the tracked state goes back to what it was.
                if let Some(r) = resolved {
                    r.undo();
                }
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

    /// Finishes a recorder made by [`Context::record_into`](crate::gpu::Context::record_into): closes its passes and returns
    /// what the caller's submission needs ([`Recorded::signal`]).
    pub fn finish(mut self) -> Result<Recorded> {
        if !self.is_external() {
            return Err(Error::InvalidArgument(format!(
                "recorder '{}' owns its command buffer: use submit()",
                self.name
            )));
        }
        self.close();
        self.local.commit_joined(&self.name)?;
        Ok(Recorded {
            finished: Some(self.take_finished()),
            value: 0,
        })
    }
}

/// Allocates one primary command buffer from `pool`, which the caller alone uses.
pub(super) fn allocate_command_buffer(
    shared: &Shared,
    pool: vk::CommandPool,
) -> Result<vk::CommandBuffer> {
    let alloc = vk::CommandBufferAllocateInfo::default()
        .command_pool(pool)
        .level(vk::CommandBufferLevel::PRIMARY)
        .command_buffer_count(1);
    // SAFETY: a pool of this device, externally synchronised by its one user.
    let cmd = unsafe { shared.device.allocate_command_buffers(&alloc) }
        .vk("vkAllocateCommandBuffers")?[0];
    crate::gpu::recycle::Counters::bump(&shared.counters.command_buffers);
    Ok(cmd)
}

/// Records the barriers that join a recording to the tracked state into `cmd`, a command
/// buffer of its pool in the initial state (submitted just before it, in the same batch).
fn record_prologue(
    shared: &Shared,
    cmd: vk::CommandBuffer,
    recorder: &str,
    joins: &super::local::Resolved,
) -> Result<()> {
    let device = &shared.device;
    shared.set_name(cmd, &format!("{recorder} (joins)"));
    let begin =
        vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
    let mut buffers = Vec::new();
    let mut images = Vec::new();
    for (b, t) in &joins.buffers {
        let m = crate::gpu::sync::barrier_masks(t.prev, t.next, t.force_visible);
        buffers.push(crate::gpu::sync::buffer_barrier_masks(
            b.raw,
            0,
            vk::WHOLE_SIZE,
            m,
        ));
    }
    for (i, r) in &joins.images {
        let t = &r.transition;
        let m = crate::gpu::sync::barrier_masks(
            t.prev,
            t.next,
            t.force_visible || t.old_layout != t.new_layout,
        );
        images.push(crate::gpu::sync::image_barrier_masks(
            i.raw,
            r.range.vk(),
            m,
            t.old_layout,
            t.new_layout,
        ));
    }
    let dep = vk::DependencyInfo::default()
        .buffer_memory_barriers(&buffers)
        .image_memory_barriers(&images);
    // SAFETY: a fresh command buffer; every handle named is alive (the recording keeps them
    // until its submission completes) and of this device.
    unsafe {
        device
            .begin_command_buffer(cmd, &begin)
            .vk("vkBeginCommandBuffer")?;
        device.cmd_pipeline_barrier2(cmd, &dep);
        device.end_command_buffer(cmd).vk("vkEndCommandBuffer")?;
    }
    Ok(())
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

/// Commands recorded into a caller's command buffer ([`Context::record_into`](crate::gpu::Context::record_into)) and what
/// they use (staging, readbacks, timestamps).
pub struct Recorded {
    finished: Option<Finished>,
    value: u64,
}

impl Recorded {
    /// Reserves this recording's timeline value, stamps what it uses, and returns the
    /// signal to add to the caller's `vkQueueSubmit2` of the command buffer (see the
    /// contract of [`Context::record_into`](crate::gpu::Context::record_into)). Calling it again returns the same signal.
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

impl std::fmt::Debug for Submission {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Submission")
            .field("value", &self.value)
            .finish()
    }
}

impl std::fmt::Debug for Recorded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorded")
            .field("value", &self.value)
            .finish()
    }
}
