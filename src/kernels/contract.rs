//! The kernel contract: what every kernel provides, and the code written once for all of them.
//!
//! A kernel is shaders + the method's code + this small glue. It is *prepared* from a scene
//! (packed on the CPU, then created on the GPU with its uploads recorded into a caller's
//! recording), *records* a frame into a caller's recording, *reads back* its outputs, and
//! reports its memory. Its CPU twin lives beside it (`kernels::NAME::cpu`) and its ground
//! truth in `reference::NAME`.
//!
//! A kernel states its passes once, in [`Kernel::pass_table`]: each [`Pass`] names itself,
//! holds what it touches (a pipeline with its bind group, whose declared accesses are the
//! pass's uses, or a buffer it uploads into) and a function that gives the frame's arguments
//! (push constants and grid, or the bytes to upload). Everything else is derived from that
//! table, so what a pass declares and what it records cannot drift apart:
//! [`Kernel::passes`] (names and uses for reports), [`Kernel::plan_pass`] (barriers for a
//! render graph, [`record_as_graph`]), [`Kernel::record_pass`] (a labelled, timed pass with
//! barriers from the tracker) and [`Kernel::record`]. The frame runner ([`run_frames`]) and
//! the pass timer (`bench::time_passes`) work for any kernel.

#![warn(missing_docs)]

use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType, BarrierMode, BindGroup, Buffer, ComputePipeline, Context, DeclaredUse,
    MemoryReport, PlannedBarrier, Recorder, Submission, Timings, Use,
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
    /// The binding's name in the shader (`(upload)` for an upload pass).
    pub binding: String,
    /// The name of the buffer or image used.
    pub resource: String,
    /// The access types, e.g. `{ComputeShaderReadOther}`.
    pub access: String,
    /// Bytes of the bound range (what the pass can touch at most).
    pub bytes: u64,
}

impl From<DeclaredUse> for UseInfo {
    fn from(u: DeclaredUse) -> Self {
        UseInfo {
            binding: u.binding,
            resource: u.resource,
            access: format!("{:?}", u.access),
            bytes: u.bytes,
        }
    }
}

/// The size of a dispatch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Grid {
    /// Invocations per axis; the recorder rounds up to whole workgroups.
    Invocations([u32; 3]),
    /// Workgroups per axis.
    Groups([u32; 3]),
}

/// One frame's arguments of a dispatch pass.
#[derive(Clone, Debug, PartialEq)]
pub struct Dispatch {
    /// Push-constant bytes (the pipeline's reflected block).
    pub push: Vec<u8>,
    /// How many invocations or workgroups to dispatch.
    pub grid: Grid,
}

impl Dispatch {
    /// Push constants from 32-bit words (`u32`, or `f32` through `to_bits`), little-endian.
    pub fn words(words: &[u32], grid: Grid) -> Dispatch {
        Dispatch {
            push: words.iter().flat_map(|w| w.to_le_bytes()).collect(),
            grid,
        }
    }

    /// Records the dispatch of `pipeline` with `bind`, barriers from its declared accesses
    /// (no pass label: [`Pass::record`] adds one).
    pub fn record(
        &self,
        rec: &mut Recorder,
        pipeline: &ComputePipeline,
        bind: &BindGroup,
    ) -> Result<()> {
        match self.grid {
            Grid::Invocations(n) => rec.dispatch_invocations_tracked(pipeline, bind, &self.push, n),
            Grid::Groups(g) => rec.dispatch_tracked(pipeline, bind, &self.push, g),
        }
    }
}

/// Gives a dispatch pass's arguments for one frame.
pub type DispatchArgs<K> = fn(&K, &<K as Kernel>::Input) -> Result<Dispatch>;
/// Gives the bytes an upload pass writes for one frame (nothing is recorded when empty).
pub type UploadBytes<K> = fn(&K, &<K as Kernel>::Input) -> Result<Vec<u8>>;
/// Gives an indirect dispatch pass's push-constant bytes for one frame (the pipeline's
/// reflected block; the workgroup counts come from the GPU).
pub type PushBytes<K> = fn(&K, &<K as Kernel>::Input) -> Result<Vec<u8>>;

/// The head of an empty GPU-appended list: (0 workgroups, 1, 1, 0 entries), the
/// `VkDispatchIndirectCommand` of the pass over the list followed by its count, as the
/// passes that append to such a list (the rasteriser's tiles, the frame's vertex list,
/// the SSS texels' shadow rays, the BTF's pixels) expect it reset before each frame.
pub const EMPTY_LIST_HEAD: [u32; 4] = [0, 1, 1, 0];

/// The first `count` entries of a GPU-appended list read back whole (`words`: the four-word
/// head, then the entries), or an error naming `what` when `count` exceeds the buffer's room.
pub fn list_entries<'w>(words: &'w [u32], count: usize, what: &str) -> Result<&'w [u32]> {
    words.get(4..).and_then(|e| e.get(..count)).ok_or_else(|| {
        Error::InvalidArgument(format!(
            "{what}: the list counts {count} entries, room for {}",
            words.len().saturating_sub(4)
        ))
    })
}

/// Where an indirect dispatch reads its workgroup counts: a `VkDispatchIndirectCommand`
/// (three u32) at `offset` in `buffer`, written on the GPU by an earlier pass.
#[derive(Clone, Copy)]
pub struct IndirectArgs<'k> {
    /// The buffer holding the command (INDIRECT_BUFFER usage).
    pub buffer: &'k Buffer,
    /// Its byte offset (a multiple of 4).
    pub offset: u64,
}

/// What a pass touches and how it is recorded.
pub enum Step<'k, K: Kernel + ?Sized> {
    /// A compute dispatch. Its uses are `bind`'s declared accesses (reflection defaults plus
    /// the kernel's overrides, [`ComputePipeline::bind_declared`]).
    Dispatch {
        /// The pipeline dispatched.
        pipeline: &'k ComputePipeline,
        /// Its bind group; the pass's uses are its declared accesses.
        bind: &'k BindGroup,
        /// Gives the frame's push constants and grid.
        args: DispatchArgs<K>,
    },
    /// A compute dispatch whose workgroup counts the GPU reads from `indirect` (written by
    /// an earlier pass, e.g. a count of the tiles some geometry covers). Its uses are
    /// `bind`'s declared accesses plus an [`AccessType::IndirectBuffer`] read of
    /// `indirect.buffer` (merged with that buffer's binding when it is also bound).
    DispatchIndirect {
        /// The pipeline dispatched.
        pipeline: &'k ComputePipeline,
        /// Its bind group; its declared accesses are uses of the pass.
        bind: &'k BindGroup,
        /// Where the workgroup counts are read.
        indirect: IndirectArgs<'k>,
        /// Gives the frame's push constants.
        push: PushBytes<K>,
    },
    /// A host-to-device upload into `buffer` at offset 0 (a transfer write).
    Upload {
        /// The buffer written.
        buffer: &'k Buffer,
        /// Gives the frame's bytes.
        bytes: UploadBytes<K>,
    },
}

/// One pass as a kernel declares it in [`Kernel::pass_table`].
pub struct Pass<'k, K: Kernel + ?Sized> {
    /// Debug label and timing name.
    pub name: &'static str,
    /// What the pass touches and how it is recorded.
    pub step: Step<'k, K>,
}

impl<'k, K: Kernel + ?Sized> Pass<'k, K> {
    /// A dispatch pass.
    pub fn dispatch(
        name: &'static str,
        pipeline: &'k ComputePipeline,
        bind: &'k BindGroup,
        args: DispatchArgs<K>,
    ) -> Self {
        Pass {
            name,
            step: Step::Dispatch {
                pipeline,
                bind,
                args,
            },
        }
    }

    /// An indirect dispatch pass: `pipeline` with `bind`, the workgroup counts read by the
    /// GPU from `indirect`, the push constants from `push`.
    pub fn dispatch_indirect(
        name: &'static str,
        pipeline: &'k ComputePipeline,
        bind: &'k BindGroup,
        indirect: IndirectArgs<'k>,
        push: PushBytes<K>,
    ) -> Self {
        Pass {
            name,
            step: Step::DispatchIndirect {
                pipeline,
                bind,
                indirect,
                push,
            },
        }
    }

    /// An upload pass.
    pub fn upload(name: &'static str, buffer: &'k Buffer, bytes: UploadBytes<K>) -> Self {
        Pass {
            name,
            step: Step::Upload { buffer, bytes },
        }
    }

    /// An upload pass that empties a GPU-appended list: [`EMPTY_LIST_HEAD`] into the head
    /// at the start of `buffer`, before the pass that appends to it.
    pub fn list_reset(name: &'static str, buffer: &'k Buffer) -> Self {
        Pass::upload(name, buffer, |_, _| {
            Ok(bytemuck::cast_slice(&EMPTY_LIST_HEAD).to_vec())
        })
    }

    /// The pass's name and declared uses, for reports.
    pub fn info(&self) -> PassInfo {
        let uses = match &self.step {
            Step::Dispatch { bind, .. } => bind.accesses().into_iter().map(UseInfo::from).collect(),
            Step::DispatchIndirect { bind, indirect, .. } => {
                let mut uses: Vec<UseInfo> =
                    bind.accesses().into_iter().map(UseInfo::from).collect();
                uses.push(UseInfo {
                    binding: "(indirect)".into(),
                    resource: indirect.buffer.name().to_string(),
                    access: format!("{:?}", AccessSet::from(AccessType::IndirectBuffer)),
                    bytes: 12,
                });
                uses
            }
            Step::Upload { buffer, .. } => vec![UseInfo {
                binding: "(upload)".into(),
                resource: buffer.name().to_string(),
                access: format!("{:?}", AccessSet::from(AccessType::TransferWrite)),
                bytes: buffer.size(),
            }],
        };
        PassInfo {
            name: self.name,
            uses,
        }
    }

    /// Plans the barriers the pass needs from its declared uses, recording nothing.
    pub fn plan(&self, rec: &mut Recorder) -> Result<Vec<PlannedBarrier>> {
        match &self.step {
            Step::Dispatch { bind, .. } => rec.plan_dispatch(bind),
            Step::DispatchIndirect { bind, indirect, .. } => {
                rec.plan_dispatch_indirect(bind, indirect.buffer, indirect.offset)
            }
            Step::Upload { buffer, .. } => {
                rec.plan(&[Use::Buffer(buffer, AccessType::TransferWrite.into())])
            }
        }
    }

    /// Records the pass for one frame in a labelled, timed pass, barriers from the tracker
    /// (or collected, in [`BarrierMode::Collect`]).
    pub fn record(&self, kernel: &K, rec: &mut Recorder, input: &K::Input) -> Result<()> {
        rec.begin_pass(self.name);
        let result = match &self.step {
            Step::Dispatch {
                pipeline,
                bind,
                args,
            } => args(kernel, input).and_then(|d| d.record(rec, pipeline, bind)),
            Step::DispatchIndirect {
                pipeline,
                bind,
                indirect,
                push,
            } => push(kernel, input).and_then(|p| {
                rec.dispatch_indirect_tracked(pipeline, bind, &p, indirect.buffer, indirect.offset)
            }),
            Step::Upload { buffer, bytes } => bytes(kernel, input).and_then(|b| {
                if b.is_empty() {
                    Ok(())
                } else {
                    rec.upload(buffer, 0, &b)
                }
            }),
        };
        rec.end_pass();
        result
    }
}

/// What every kernel provides (see the module documentation). A kernel implements
/// [`Kernel::pass_table`] and the readback; the per-pass methods are derived from the table.
pub trait Kernel {
    /// What one frame takes (AO: the joint matrices).
    type Input: ?Sized;
    /// The readbacks recorded for a frame.
    type Readback;
    /// Host copies of a frame's outputs.
    type Output;

    /// Short name (`ao`), used in labels and reports.
    fn name(&self) -> &'static str;
    /// The passes of one frame, in order: the one place a kernel declares them.
    fn pass_table(&self) -> Vec<Pass<'_, Self>>;
    /// Checks one frame's input before any of it is recorded (default: nothing to check).
    fn check_input(&self, _input: &Self::Input) -> Result<()> {
        Ok(())
    }
    /// Records copies of the frame's outputs to the host.
    fn read_back(&self, rec: &mut Recorder) -> Result<Self::Readback>;
    /// The outputs, once the submission holding the readback is complete.
    fn collect(&self, readback: &Self::Readback) -> Result<Self::Output>;
    /// Device memory of the kernel's resources.
    fn memory(&self) -> MemoryReport;

    /// The passes [`Kernel::record`] records, in order, with declared accesses.
    fn passes(&self) -> Vec<PassInfo> {
        self.pass_table().iter().map(Pass::info).collect()
    }
    /// Records pass `pass` (an index into [`Kernel::passes`]) in its labelled, timed pass;
    /// barriers come from the declared accesses through the recorder's tracking. The input
    /// is checked ([`Kernel::check_input`]) before anything is recorded.
    fn record_pass(&self, rec: &mut Recorder, pass: usize, input: &Self::Input) -> Result<()> {
        self.check_input(input)?;
        let table = self.pass_table();
        let p = table
            .get(pass)
            .ok_or_else(|| no_such_pass(self.name(), table.len(), pass))?;
        p.record(self, rec, input)
    }
    /// Plans the barriers pass `pass` needs from its declared accesses, without recording
    /// them (see [`Recorder::plan`]); a render graph records them merged with its own.
    fn plan_pass(&self, rec: &mut Recorder, pass: usize) -> Result<Vec<PlannedBarrier>> {
        let table = self.pass_table();
        let p = table
            .get(pass)
            .ok_or_else(|| no_such_pass(self.name(), table.len(), pass))?;
        p.plan(rec)
    }
    /// Records one frame: the input checked once, then every pass in order.
    fn record(&self, rec: &mut Recorder, input: &Self::Input) -> Result<()> {
        self.check_input(input)?;
        for pass in self.pass_table() {
            pass.record(self, rec, input)?;
        }
        Ok(())
    }
}

fn no_such_pass(kernel: &str, passes: usize, pass: usize) -> Error {
    Error::InvalidArgument(format!(
        "kernel '{kernel}' has {passes} passes; pass index {pass} is out of range"
    ))
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
    kernel.check_input(input)?;
    let table = kernel.pass_table();
    rec.set_barrier_mode(BarrierMode::Collect);
    let mut result = Ok(());
    for pass in &table {
        let planned = match pass.plan(rec) {
            Ok(p) => merge(pass.name, p),
            Err(e) => {
                result = Err(e);
                break;
            }
        };
        if let Err(e) = rec
            .record_planned(&planned)
            .and_then(|_| pass.record(kernel, rec, input))
        {
            result = Err(e);
            break;
        }
    }
    rec.set_barrier_mode(BarrierMode::Emit);
    result
}

/// One completed frame from [`run_frames`].
pub struct FrameResult<O> {
    /// Position of the frame's input in the sequence given to [`run_frames`].
    pub index: usize,
    /// The kernel's output for the frame, read back.
    pub output: O,
    /// GPU times of the frame's passes.
    pub timings: Timings,
    /// Host milliseconds the frame cost outside waiting: recording its passes and
    /// readbacks (uniforms and uploads staged included) and submitting.
    pub host_ms: f64,
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
    type Pending<R> = (usize, Submission, R, f64);
    let mut pending: VecDeque<Pending<K::Readback>> = VecDeque::new();
    let mut most = 0;
    let mut finish = |(index, submission, readback, host_ms): Pending<K::Readback>| {
        let timings = submission.wait()?;
        let output = kernel.collect(&readback)?;
        on_frame(FrameResult {
            index,
            output,
            timings,
            host_ms,
        })
    };
    for (index, input) in inputs.into_iter().enumerate() {
        let start = std::time::Instant::now();
        let mut rec = ctx.recorder(&format!("{} frame {index}", kernel.name()))?;
        kernel.record(&mut rec, input.borrow())?;
        let readback = kernel.read_back(&mut rec)?;
        let submission = rec.submit()?;
        let host_ms = start.elapsed().as_secs_f64() * 1e3;
        pending.push_back((index, submission, readback, host_ms));
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

/// What every kernel's report.json carries about the kernel itself: its passes with their
/// declared accesses, its memory (used by its resources, reserved by the context) and how
/// many frames were in flight together.
#[derive(Clone, Debug, serde::Serialize)]
pub struct KernelInfo {
    /// The kernel's name ([`Kernel::name`]).
    pub name: &'static str,
    /// Its passes in recording order, with their declared uses.
    pub passes: Vec<PassInfo>,
    /// Device memory of its resources ([`Kernel::memory`]).
    pub memory: MemoryReport,
    /// The most frames that were in flight together.
    pub frames_in_flight: usize,
}

impl KernelInfo {
    /// Describes `kernel` for a report, with the frames in flight that [`run_frames`] returned.
    pub fn of<K: Kernel>(kernel: &K, frames_in_flight: usize) -> Self {
        KernelInfo {
            name: kernel.name(),
            passes: kernel.passes(),
            memory: kernel.memory(),
            frames_in_flight,
        }
    }
}
