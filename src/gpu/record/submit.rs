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
            Retired::CommandPool(std::mem::take(&mut self.pool)),
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
        Ok(Recorded {
            finished: Some(self.take_finished()),
            value: 0,
        })
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
