//! The shape every kernel has, and the code written once for all of them.
//!
//! A kernel is shaders + the method's code + this small glue: it is *prepared* from a scene
//! (its constructor records the uploads into a caller's recording), *records* a frame into
//! a caller's recording with each pass's accesses declared ([`Kernel::passes`]), *reads
//! back* its outputs, and reports its memory. Its CPU twin and ground truth live beside it
//! (`kernels::NAME::cpu`, `reference::NAME`). The frame runner ([`run_frames`]), the pass
//! timer ([`time_passes`]) and the report envelope (`report::KernelReport`) work for any
//! kernel.

use crate::error::{Error, Result};
use crate::gpu::{
    BarrierMode, Context, DeclaredUse, MemoryReport, PlannedBarrier, Recorder, Submission, Timings,
};
use std::collections::VecDeque;

/// One pass of a kernel's frame and the accesses it declares.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PassInfo {
    /// The pass's label (debug label and timing name).
    pub name: &'static str,
    /// (binding, resource, access) of every resource the pass touches.
    pub uses: Vec<UseInfo>,
}

/// One declared use, in a serialisable form.
#[derive(Clone, Debug, serde::Serialize)]
pub struct UseInfo {
    pub binding: String,
    pub resource: String,
    /// The access types, e.g. `{ComputeShaderReadOther}`.
    pub access: String,
}

impl From<DeclaredUse> for UseInfo {
    fn from(u: DeclaredUse) -> Self {
        UseInfo {
            binding: u.binding,
            resource: u.resource,
            access: format!("{:?}", u.access),
        }
    }
}

/// What every kernel provides (see the module documentation).
pub trait Kernel {
    /// What one frame takes (AO: the joint matrices).
    type Input: ?Sized;
    /// The readbacks recorded for a frame.
    type Readback;
    /// Host copies of a frame's outputs.
    type Output;

    /// Short name (`ao`), used in labels and reports.
    fn name(&self) -> &'static str;
    /// The passes [`Kernel::record`] records, in order, with declared accesses.
    fn passes(&self) -> Vec<PassInfo>;
    /// Records pass `pass` (an index into [`Kernel::passes`]) in its labelled, timed pass;
    /// barriers come from the declared accesses through the recorder's tracking.
    fn record_pass(&self, rec: &mut Recorder, pass: usize, input: &Self::Input) -> Result<()>;
    /// Plans the barriers pass `pass` needs from its declared accesses, without recording
    /// them (see [`Recorder::plan`]); a render graph records them merged with its own.
    fn plan_pass(&self, rec: &mut Recorder, pass: usize) -> Result<Vec<PlannedBarrier>>;
    /// Records one frame: every pass in order.
    fn record(&self, rec: &mut Recorder, input: &Self::Input) -> Result<()> {
        for pass in 0..self.passes().len() {
            self.record_pass(rec, pass, input)?;
        }
        Ok(())
    }
    /// Records copies of the frame's outputs to the host.
    fn read_back(&self, rec: &mut Recorder) -> Result<Self::Readback>;
    /// The outputs, once the submission holding the readback is complete.
    fn collect(&self, readback: &Self::Readback) -> Result<Self::Output>;
    /// Device memory of the kernel's resources.
    fn memory(&self) -> MemoryReport;
}

/// Records one frame the way a render graph drives a kernel: for each pass, plan its
/// barriers from the declared accesses, hand them to `merge` (the graph adds its own and
/// may reorder), record them, then record the pass with vkshade emitting no barriers.
pub fn record_as_graph<K: Kernel>(
    rec: &mut Recorder,
    kernel: &K,
    input: &K::Input,
    mut merge: impl FnMut(&'static str, Vec<PlannedBarrier>) -> Vec<PlannedBarrier>,
) -> Result<()> {
    let passes = kernel.passes();
    rec.set_barrier_mode(BarrierMode::Collect);
    let mut result = Ok(());
    for (i, pass) in passes.iter().enumerate() {
        let planned = match kernel.plan_pass(rec, i) {
            Ok(p) => merge(pass.name, p),
            Err(e) => {
                result = Err(e);
                break;
            }
        };
        rec.record_planned(&planned);
        if let Err(e) = kernel.record_pass(rec, i, input) {
            result = Err(e);
            break;
        }
    }
    rec.set_barrier_mode(BarrierMode::Emit);
    result
}

/// One completed frame from [`run_frames`].
pub struct FrameResult<O> {
    pub index: usize,
    pub output: O,
    pub timings: Timings,
}

/// Runs `kernel` over `inputs`, keeping up to `in_flight` frames submitted at once (each
/// frame is recorded and submitted before the oldest is waited for), and hands each
/// completed frame to `on_frame` in order. Returns the largest number of frames that were
/// in flight together.
pub fn run_frames<K, I>(
    ctx: &Context,
    kernel: &K,
    inputs: impl IntoIterator<Item = I>,
    in_flight: usize,
    mut on_frame: impl FnMut(FrameResult<K::Output>) -> Result<()>,
) -> Result<usize>
where
    K: Kernel,
    I: std::borrow::Borrow<K::Input>,
{
    if in_flight == 0 {
        return Err(Error::InvalidArgument(
            "frames in flight must be at least 1".into(),
        ));
    }
    let mut pending: VecDeque<(usize, Submission, K::Readback)> = VecDeque::new();
    let mut most = 0;
    let mut finish = |(index, submission, readback): (usize, Submission, K::Readback)| {
        let timings = submission.wait()?;
        let output = kernel.collect(&readback)?;
        on_frame(FrameResult {
            index,
            output,
            timings,
        })
    };
    for (index, input) in inputs.into_iter().enumerate() {
        let mut rec = ctx.recorder(&format!("{} frame {index}", kernel.name()))?;
        kernel.record(&mut rec, input.borrow())?;
        let readback = kernel.read_back(&mut rec)?;
        pending.push_back((index, rec.submit()?, readback));
        most = most.max(pending.len());
        if pending.len() >= in_flight
            && let Some(oldest) = pending.pop_front()
        {
            finish(oldest)?;
        }
    }
    while let Some(oldest) = pending.pop_front() {
        finish(oldest)?;
    }
    Ok(most)
}

/// GPU time of each of the kernel's passes over `warmup + samples` submissions of one
/// frame (median and spread in each [`crate::report::Stats`]), in the order of
/// [`Kernel::passes`].
pub fn time_passes<K: Kernel>(
    ctx: &Context,
    cfg: &crate::bench::BenchConfig,
    kernel: &K,
    input: &K::Input,
) -> Result<Vec<(&'static str, crate::report::Stats)>> {
    let names: Vec<&'static str> = kernel.passes().iter().map(|p| p.name).collect();
    let stats = crate::bench::time_gpu_passes(ctx, cfg, &names, |rec| kernel.record(rec, input))?;
    Ok(names.into_iter().zip(stats).collect())
}

/// What every kernel's report.json carries about the kernel itself: its passes with their
/// declared accesses, its memory (used by its resources, reserved by the context) and how
/// many frames were in flight together.
#[derive(Clone, Debug, serde::Serialize)]
pub struct KernelInfo {
    pub name: &'static str,
    pub passes: Vec<PassInfo>,
    pub memory: MemoryReport,
    pub frames_in_flight: usize,
}

impl KernelInfo {
    pub fn of<K: Kernel>(kernel: &K, frames_in_flight: usize) -> Self {
        KernelInfo {
            name: kernel.name(),
            passes: kernel.passes(),
            memory: kernel.memory(),
            frames_in_flight,
        }
    }
}
