//! Device-peak micro-benchmarks: the roofline every kernel is judged against.
//!
//! - FMA: 2^20 invocations, each 8 independent vec4 FMA chains (64 FLOP per iteration); the
//!   iteration count doubles until one submission takes `min_submit_ms`.
//! - Stream: `dst = src * s` over vec4 buffers (32 bytes per element), repeated in one
//!   submission until it takes `min_submit_ms`; swept over working-set sizes, the headline
//!   number is the largest size (past the caches).
//! - Probes ([`ProbeKind`]): sampling (2D/3D, nearest/bilinear, RGBA8/16F/32F, coherent and
//!   random coordinates), storage buffer and storage image gathers, uniform-buffer reads at
//!   a dynamic index, shared-memory reads, workgroup barriers, atomics. Each grows its loop
//!   count until one submission takes min(`min_submit_ms`, 20 ms). These are the rooflines
//!   the kernels' work models ([`super::roofline`]) name.

use super::plot::{Panel, Series};
use super::{BenchConfig, MachineInfo, Stats, time_gpu};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType, Barrier, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, Recorder, Resource, Sampler, SamplerDesc,
};
use crate::shaders;
use serde::Serialize;

/// One step of a sweep.
#[derive(Clone, Debug, Serialize)]
pub struct SweepPoint {
    /// The swept quantity (FMA: loop iterations; stream: working set in bytes).
    pub x: f64,
    /// Repeats in one submission (stream) or 1.
    pub repeats: u64,
    pub gpu_ms_median: f64,
    pub throughput: f64,
}

/// Result of one micro-benchmark at its final size.
#[derive(Clone, Debug, Serialize)]
pub struct PeakResult {
    pub unit: &'static str,
    /// What was run, in words.
    pub problem: String,
    /// Total work of one submission (FLOP or bytes).
    pub work_per_submit: f64,
    pub gpu_ms: Stats,
    /// Work / median time.
    pub throughput_median: f64,
    /// Work / minimum time.
    pub throughput_best: f64,
    pub sweep: Vec<SweepPoint>,
}

/// What `vkshade bench peak` writes.
#[derive(Clone, Debug, Serialize)]
pub struct PeakReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: BenchConfig,
    /// Median f32 FMA throughput, GFLOP/s.
    pub fma_gflops: f64,
    /// Median streaming bandwidth at the largest working set, GB/s (1e9 bytes).
    pub bandwidth_gb_s: f64,
    pub fma: PeakResult,
    pub stream: PeakResult,
    /// The probes beyond FMA and streaming (see [`ProbeKind`]).
    pub probes: Vec<ProbeResult>,
    /// Probes the device could not run, with the reason.
    pub skipped_probes: Vec<String>,
}

impl PeakReport {
    /// Every measured rate, per second, by key: `fma` (FLOP/s), `stream` (bytes/s) and each
    /// probe's key (its unit per second).
    pub fn rates(&self) -> super::roofline::Rates {
        let mut r = super::roofline::Rates::default();
        r.insert("fma", self.fma_gflops * 1e9);
        r.insert("stream", self.bandwidth_gb_s * 1e9);
        for p in &self.probes {
            r.insert(&p.key, p.rate_per_s);
        }
        r
    }
}

const FMA_INVOCATIONS: u32 = 1 << 20;
const FLOP_PER_ITERATION: f64 = 64.0;

fn fma_push(iterations: u32) -> Vec<u8> {
    let mut p = Vec::with_capacity(12);
    p.extend_from_slice(&iterations.to_le_bytes());
    p.extend_from_slice(&0.999_f32.to_le_bytes());
    p.extend_from_slice(&1.0e-3_f32.to_le_bytes());
    p
}

/// Runs every micro-benchmark; `progress` receives one line per step.
pub fn run(ctx: &Context, cfg: &BenchConfig, progress: &mut dyn FnMut(&str)) -> Result<PeakReport> {
    let fma = run_fma(ctx, cfg, progress)?;
    let stream = run_stream(ctx, cfg, progress)?;
    let (probes, skipped_probes) = run_probes(ctx, cfg, &ProbeKind::all(), progress)?;
    Ok(PeakReport {
        probes,
        skipped_probes,
        benchmark: "peak",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        fma_gflops: fma.throughput_median,
        bandwidth_gb_s: stream.throughput_median,
        fma,
        stream,
    })
}

fn record_fma<'a>(
    rec: &mut Recorder,
    pipeline: &'a ComputePipeline,
    bind: &'a BindGroup,
    out: &'a Buffer,
    iterations: u32,
) -> Result<()> {
    // Orders this submission's writes after the previous one's.
    rec.barrier(&[Barrier::buffer(
        out,
        AccessType::ComputeShaderWrite,
        AccessType::ComputeShaderWrite,
    )])?;
    rec.begin_pass("fma");
    rec.dispatch_invocations(
        pipeline,
        bind,
        &fma_push(iterations),
        [FMA_INVOCATIONS, 1, 1],
    )?;
    rec.end_pass();
    Ok(())
}

fn record_stream<'a>(
    rec: &mut Recorder,
    pipeline: &'a ComputePipeline,
    bind: &'a BindGroup,
    dst: &'a Buffer,
    push: &[u8],
    n: u32,
    repeats: u64,
) -> Result<()> {
    let waw = || {
        Barrier::buffer(
            dst,
            AccessType::ComputeShaderWrite,
            AccessType::ComputeShaderWrite,
        )
    };
    rec.barrier(&[waw()])?;
    rec.begin_pass("stream");
    for r in 0..repeats {
        if r > 0 {
            rec.barrier(&[waw()])?;
        }
        rec.dispatch_invocations(pipeline, bind, push, [n, 1, 1])?;
    }
    rec.end_pass();
    Ok(())
}

/// Peak f32 FMA throughput in GFLOP/s.
pub fn run_fma(
    ctx: &Context,
    cfg: &BenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<PeakResult> {
    let pipeline = ComputePipeline::from_spirv(ctx, "bench/fma", shaders::spirv("bench/fma")?)?;
    let out = Buffer::new(
        ctx,
        "fma out",
        BufferDesc::storage(FMA_INVOCATIONS as u64 * 16),
    )?;
    let bind = pipeline.bind(&[("outbuf", Resource::Buffer(&out))])?;
    let flops = |iterations: u32| FMA_INVOCATIONS as f64 * iterations as f64 * FLOP_PER_ITERATION;
    let probe = BenchConfig {
        warmup: 1,
        samples: 3,
        ..cfg.clone()
    };
    let mut iterations = 8u32;
    let mut sweep = Vec::new();
    loop {
        let s = time_gpu(ctx, &probe, "fma", |rec| {
            record_fma(rec, &pipeline, &bind, &out, iterations)
        })?;
        let gflops = flops(iterations) / (s.median * 1e-3) * 1e-9;
        progress(&format!(
            "fma: {iterations} iterations x {FMA_INVOCATIONS} invocations: {:.3} ms, {gflops:.1} GFLOP/s",
            s.median
        ));
        sweep.push(SweepPoint {
            x: iterations as f64,
            repeats: 1,
            gpu_ms_median: s.median,
            throughput: gflops,
        });
        if s.median >= cfg.min_submit_ms || iterations >= 1 << 24 {
            break;
        }
        iterations *= 2;
    }
    let s = time_gpu(ctx, cfg, "fma", |rec| {
        record_fma(rec, &pipeline, &bind, &out, iterations)
    })?;
    let work = flops(iterations);
    Ok(PeakResult {
        unit: "GFLOP/s",
        problem: format!(
            "{FMA_INVOCATIONS} invocations x {iterations} iterations x 8 vec4 FMA chains (64 FLOP/iteration)"
        ),
        work_per_submit: work,
        throughput_median: work / (s.median * 1e-3) * 1e-9,
        throughput_best: work / (s.min * 1e-3) * 1e-9,
        gpu_ms: s,
        sweep,
    })
}

/// Working-set sizes of the stream sweep (each buffer; twice this is moved per pass).
fn stream_sizes(ctx: &Context) -> Vec<u64> {
    let l = ctx.limits();
    let group_cap = l.max_compute_work_group_count[0] as u64 * 256 * 16;
    let cap = (256u64 << 20)
        .min(l.max_storage_buffer_range)
        .min(l.max_memory_allocation_size)
        .min(group_cap);
    let mut sizes: Vec<u64> = [1u64 << 20, 4 << 20, 16 << 20, 64 << 20]
        .into_iter()
        .filter(|&s| s < cap)
        .collect();
    sizes.push(cap / 16 * 16);
    sizes
}

/// Streaming bandwidth in GB/s, swept over working-set sizes.
pub fn run_stream(
    ctx: &Context,
    cfg: &BenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<PeakResult> {
    let pipeline =
        ComputePipeline::from_spirv(ctx, "bench/stream", shaders::spirv("bench/stream")?)?;
    let sizes = stream_sizes(ctx);
    let largest = *sizes
        .last()
        .ok_or_else(|| Error::InvalidArgument("no stream sizes".into()))?;
    let src = Buffer::new(ctx, "stream src", BufferDesc::storage(largest))?;
    let dst = Buffer::new(ctx, "stream dst", BufferDesc::storage(largest))?;
    {
        let mut rec = ctx.recorder("stream init")?;
        rec.fill_buffer(&src, 1.0f32.to_bits())?;
        rec.fill_buffer(&dst, 0)?;
        rec.barrier(&[Barrier::global(
            AccessType::TransferWrite,
            AccessType::ComputeShaderReadOther | AccessType::ComputeShaderWrite,
        )])?;
        rec.submit_and_wait()?;
    }
    let probe = BenchConfig {
        warmup: 1,
        samples: 3,
        ..cfg.clone()
    };
    let mut sweep = Vec::new();
    let mut last = None;
    for &bytes in &sizes {
        let n = (bytes / 16) as u32;
        let src_r = Resource::BufferRange {
            buffer: &src,
            offset: 0,
            size: bytes,
        };
        let dst_r = Resource::BufferRange {
            buffer: &dst,
            offset: 0,
            size: bytes,
        };
        let bind = pipeline.bind(&[("src", src_r), ("dst", dst_r)])?;
        let mut push = Vec::new();
        push.extend_from_slice(&n.to_le_bytes());
        push.extend_from_slice(&1.0001f32.to_le_bytes());
        let mut repeats = 1u64;
        let s = loop {
            let s = time_gpu(ctx, &probe, "stream", |rec| {
                record_stream(rec, &pipeline, &bind, &dst, &push, n, repeats)
            })?;
            if s.median >= cfg.min_submit_ms || repeats >= 1 << 16 {
                break s;
            }
            // Jump close to the target in one step, then double.
            let factor = (cfg.min_submit_ms / s.median.max(1e-3)).ceil() as u64;
            repeats = (repeats * factor.clamp(2, 64)).min(1 << 16);
        };
        let gbs = 2.0 * bytes as f64 * repeats as f64 / (s.median * 1e-3) * 1e-9;
        progress(&format!(
            "stream: {:.1} MiB x {repeats} repeats: {:.3} ms, {gbs:.1} GB/s",
            bytes as f64 / (1 << 20) as f64,
            s.median
        ));
        sweep.push(SweepPoint {
            x: bytes as f64,
            repeats,
            gpu_ms_median: s.median,
            throughput: gbs,
        });
        if bytes == largest {
            last = Some((
                repeats,
                time_gpu(ctx, cfg, "stream", |rec| {
                    record_stream(rec, &pipeline, &bind, &dst, &push, n, repeats)
                })?,
            ));
        }
    }
    let (repeats, s) =
        last.ok_or_else(|| Error::InvalidArgument("stream sweep was empty".into()))?;
    let work = 2.0 * largest as f64 * repeats as f64;
    Ok(PeakResult {
        unit: "GB/s",
        problem: format!(
            "dst = src * s over {:.1} MiB of vec4 (read + write), {repeats} dispatches per submit",
            largest as f64 / (1 << 20) as f64
        ),
        work_per_submit: work,
        throughput_median: work / (s.median * 1e-3) * 1e-9,
        throughput_best: work / (s.min * 1e-3) * 1e-9,
        gpu_ms: s,
        sweep,
    })
}

/// The two sweeps as plot panels.
pub fn panels(report: &PeakReport) -> Vec<Panel> {
    vec![
        Panel {
            title: format!("FMA throughput, {}", report.machine.device),
            x_label: "loop iterations per invocation".into(),
            y_label: "GFLOP/s".into(),
            log_x: true,
            log_y: false,
            series: vec![Series {
                name: "f32 FMA".into(),
                points: report
                    .fma
                    .sweep
                    .iter()
                    .map(|p| (p.x, p.throughput))
                    .collect(),
            }],
        },
        Panel {
            title: format!("Streaming bandwidth, {}", report.machine.device),
            x_label: "working set per buffer (MiB)".into(),
            y_label: "GB/s".into(),
            log_x: true,
            log_y: false,
            series: vec![Series {
                name: "dst = src * s".into(),
                points: report
                    .stream
                    .sweep
                    .iter()
                    .map(|p| (p.x / (1 << 20) as f64, p.throughput))
                    .collect(),
            }],
        },
    ]
}

/// The grid of the sampling probes (invocations 512 x 512) and the invocations of the other
/// probes: 2^18, enough to fill a large GPU (an H200's 132 SMs hold ~270 k threads) and a few
/// ms of one call each on lavapipe.
const PROBE_GRID: u32 = 512;
const PROBE_INVOCATIONS: u32 = 1 << 18;
/// Texture sizes of the sampling probes: 2048^2 texels in 2D (16 / 32 / 64 MiB in RGBA8 /
/// RGBA16F / RGBA32F) and 128^3 in 3D (8 / 16 / 32 MiB), past a CPU's caches; on a GPU with a
/// 50+ MB L2 the random probes measure mostly L2 (the figure a kernel meets too).
const TEX_2D: u32 = 2048;
const TEX_3D: u32 = 128;
/// Elements of the gather probes' buffer and image: 2^22 vec4 = 64 MiB.
const GATHER_BITS: u32 = 22;
/// Counters of the spread atomics probe: 2^20 (4 MiB).
const ATOMIC_BITS: u32 = 20;
/// The most loop iterations a probe grows to.
const MAX_LOOPS: u32 = 1 << 16;

/// A texel format of the sampling probes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProbeFormat {
    Rgba8,
    Rgba16f,
    Rgba32f,
}

impl ProbeFormat {
    const ALL: [ProbeFormat; 3] = [
        ProbeFormat::Rgba8,
        ProbeFormat::Rgba16f,
        ProbeFormat::Rgba32f,
    ];

    fn vk(self) -> ash::vk::Format {
        match self {
            ProbeFormat::Rgba8 => ash::vk::Format::R8G8B8A8_UNORM,
            ProbeFormat::Rgba16f => ash::vk::Format::R16G16B16A16_SFLOAT,
            ProbeFormat::Rgba32f => ash::vk::Format::R32G32B32A32_SFLOAT,
        }
    }

    fn name(self) -> &'static str {
        match self {
            ProbeFormat::Rgba8 => "rgba8",
            ProbeFormat::Rgba16f => "rgba16f",
            ProbeFormat::Rgba32f => "rgba32f",
        }
    }
}

/// What one probe measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProbeKind {
    /// `textureLod` from a 2D (`dim3` false) or 3D texture, nearest or bilinear.
    Sample {
        dim3: bool,
        bilinear: bool,
        format: ProbeFormat,
        random: bool,
    },
    /// vec4 loads from a storage buffer or an rgba32f storage image.
    Gather { image: bool, random: bool },
    /// vec4 reads from a uniform buffer at a dynamic index, uniform or per lane.
    Ubo { per_lane: bool },
    /// Bytes read from shared memory.
    SharedRead,
    /// Workgroup barriers (each with a shared write and read between).
    Barrier,
    /// `atomicAdd` on a storage buffer, contended (one counter per workgroup) or spread.
    Atomic { spread: bool },
}

impl ProbeKind {
    /// Every probe, in the order `bench peak` runs them.
    pub fn all() -> Vec<ProbeKind> {
        let mut v = Vec::new();
        for dim3 in [false, true] {
            for format in ProbeFormat::ALL {
                for bilinear in [false, true] {
                    for random in [false, true] {
                        v.push(ProbeKind::Sample {
                            dim3,
                            bilinear,
                            format,
                            random,
                        });
                    }
                }
            }
        }
        for image in [false, true] {
            for random in [false, true] {
                v.push(ProbeKind::Gather { image, random });
            }
        }
        v.push(ProbeKind::Ubo { per_lane: false });
        v.push(ProbeKind::Ubo { per_lane: true });
        v.push(ProbeKind::SharedRead);
        v.push(ProbeKind::Barrier);
        v.push(ProbeKind::Atomic { spread: false });
        v.push(ProbeKind::Atomic { spread: true });
        v
    }

    /// The probe's key in reports and work models (e.g. `sample2d_bilinear_rgba8_random`).
    pub fn key(self) -> String {
        let pattern = |random: bool| if random { "random" } else { "coherent" };
        match self {
            ProbeKind::Sample {
                dim3,
                bilinear,
                format,
                random,
            } => format!(
                "sample{}_{}_{}_{}",
                if dim3 { "3d" } else { "2d" },
                if bilinear { "bilinear" } else { "nearest" },
                format.name(),
                pattern(random)
            ),
            ProbeKind::Gather { image, random } => format!(
                "{}_gather_{}",
                if image { "image" } else { "buffer" },
                pattern(random)
            ),
            ProbeKind::Ubo { per_lane } => {
                format!("ubo_{}", if per_lane { "per_lane" } else { "uniform" })
            }
            ProbeKind::SharedRead => "shared_read".into(),
            ProbeKind::Barrier => "barrier".into(),
            ProbeKind::Atomic { spread } => {
                format!("atomic_{}", if spread { "spread" } else { "contended" })
            }
        }
    }

    /// What is counted.
    pub fn unit(self) -> &'static str {
        match self {
            ProbeKind::Sample { .. } => "samples",
            ProbeKind::Gather { .. } => "vec4 loads",
            ProbeKind::Ubo { .. } => "vec4 reads",
            ProbeKind::SharedRead => "bytes",
            ProbeKind::Barrier => "workgroup barriers",
            ProbeKind::Atomic { .. } => "atomics",
        }
    }

    /// What it runs, in words.
    pub fn describe(self) -> String {
        match self {
            ProbeKind::Sample {
                dim3,
                bilinear,
                format,
                random,
            } => format!(
                "textureLod, {} {} {}, {} coordinates",
                if dim3 {
                    format!("3D {TEX_3D}^3")
                } else {
                    format!("2D {TEX_2D}^2")
                },
                format.name(),
                if bilinear { "bilinear" } else { "nearest" },
                if random {
                    "hashed"
                } else {
                    "neighbouring-texel"
                }
            ),
            ProbeKind::Gather { image, random } => format!(
                "vec4 loads from a 64 MiB {}, {} elements",
                if image {
                    "rgba32f storage image (imageLoad)"
                } else {
                    "storage buffer"
                },
                if random { "hashed" } else { "neighbouring" }
            ),
            ProbeKind::Ubo { per_lane } => format!(
                "vec4 reads from a 16 KiB uniform buffer at a dynamic index {}",
                if per_lane {
                    "hashed per lane"
                } else {
                    "uniform across the workgroup"
                }
            ),
            ProbeKind::SharedRead => {
                "4 vec4 reads from a 256-vec4 shared array per iteration".into()
            }
            ProbeKind::Barrier => {
                "barrier(); shared write, barrier, neighbour read per iteration (2 barriers)".into()
            }
            ProbeKind::Atomic { spread } => {
                if spread {
                    "atomicAdd on hashed counters of 2^20 (result used)".into()
                } else {
                    "atomicAdd, every invocation of a workgroup on one counter".into()
                }
            }
        }
    }
}

/// One probe's result.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeResult {
    pub key: String,
    pub what: String,
    pub unit: &'static str,
    /// Loop iterations per invocation after growing to the target time.
    pub loops: u32,
    /// Units of work in one submission.
    pub count_per_submit: f64,
    pub gpu_ms: Stats,
    /// count / median time, per second.
    pub rate_per_s: f64,
    /// count / the third and first quartiles of the time: the rate's interquartile range.
    pub rate_q1_per_s: f64,
    pub rate_q3_per_s: f64,
}

/// `x` with an SI prefix (k, M, G, T) and 3 significant digits: rates from 1e3 to 1e13.
pub fn si(x: f64) -> String {
    let (v, p) = [(1e12, "T"), (1e9, "G"), (1e6, "M"), (1e3, "k")]
        .into_iter()
        .find(|(s, _)| x.abs() >= *s)
        .map_or((x, ""), |(s, p)| (x / s, p));
    format!("{v:.3} {p}")
}

/// Times `record(rec, loops)` (one pass named `pass`), growing `loops` from 1 until a
/// submission takes `target_ms` (one jump by the measured ratio, then doubling), then
/// `cfg.warmup + cfg.samples` submissions at that size.
fn time_probe(
    ctx: &Context,
    cfg: &BenchConfig,
    target_ms: f64,
    pass: &str,
    mut record: impl FnMut(&mut Recorder, u32) -> Result<()>,
) -> Result<(u32, Stats)> {
    let calibrate = BenchConfig {
        warmup: 1,
        samples: 1,
        ..cfg.clone()
    };
    let mut loops = 1u32;
    let mut timed = |cfg: &BenchConfig, loops: u32| {
        time_gpu(ctx, cfg, pass, |rec| {
            rec.begin_pass(pass);
            let r = record(rec, loops);
            rec.end_pass();
            r
        })
    };
    loop {
        let s = timed(&calibrate, loops)?;
        if s.median >= 0.5 * target_ms || loops >= MAX_LOOPS {
            break;
        }
        let factor = (target_ms / s.median.max(1e-3)).ceil().clamp(2.0, 1024.0) as u32;
        loops = loops.saturating_mul(factor).min(MAX_LOOPS);
    }
    Ok((loops, timed(cfg, loops)?))
}

/// Hashed texels of `bytes` bytes in `format`, every value finite in [0.5, 1) (so no
/// format meets a NaN or denormal path).
fn hashed_texels(format: ProbeFormat, bytes: u64) -> Vec<u8> {
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        h ^= h << 13;
        h ^= h >> 7;
        h ^= h << 17;
        h
    };
    let mut out = Vec::with_capacity(bytes as usize);
    match format {
        ProbeFormat::Rgba8 => {
            while (out.len() as u64) < bytes {
                out.extend_from_slice(&next().to_le_bytes());
            }
        }
        ProbeFormat::Rgba16f => {
            while (out.len() as u64) < bytes {
                let r = next();
                for k in 0..4 {
                    let half = 0x3800u16 | ((r >> (16 * k)) as u16 & 0x3ff);
                    out.extend_from_slice(&half.to_le_bytes());
                }
            }
        }
        ProbeFormat::Rgba32f => {
            while (out.len() as u64) < bytes {
                let r = next();
                for k in 0..2 {
                    let f = 0x3f00_0000u32 | ((r >> (32 * k)) as u32 & 0x7f_ffff);
                    out.extend_from_slice(&f.to_le_bytes());
                }
            }
        }
    }
    out.truncate(bytes as usize);
    out
}

/// A device-local image of `desc` filled with hashed texels.
fn hashed_image(ctx: &Context, name: &str, desc: ImageDesc, format: ProbeFormat) -> Result<Image> {
    let img = Image::new(ctx, name, desc)?;
    let data = hashed_texels(format, desc.byte_size()?);
    let done = ctx.upload_image_streamed(&img, &data, 8 << 20)?;
    ctx.wait_for(done)?;
    Ok(img)
}

fn push_words(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// The probes of `kinds`, in the order given (resources are made once per group);
/// `progress` gets one line per probe. A probe the device cannot run (a format without
/// linear filtering, say) is skipped with the reason in the second list.
pub fn run_probes(
    ctx: &Context,
    cfg: &BenchConfig,
    kinds: &[ProbeKind],
    progress: &mut dyn FnMut(&str),
) -> Result<(Vec<ProbeResult>, Vec<String>)> {
    // Short probes: a submission of at most 20 ms is far above timestamp resolution on any
    // device, and keeps the 34 probes to seconds on lavapipe.
    let target = cfg.min_submit_ms.min(20.0);
    let mut results = Vec::new();
    let mut skipped = Vec::new();
    let out = Buffer::new(
        ctx,
        "probe out",
        BufferDesc::storage(PROBE_GRID as u64 * PROBE_GRID as u64 * 16),
    )?;
    let write_out = [("result", AccessSet::from(AccessType::ComputeShaderWrite))];
    let mut finish =
        |kind: ProbeKind, loops: u32, per_loop: f64, s: Stats, progress: &mut dyn FnMut(&str)| {
            let count = per_loop * loops as f64;
            let r = ProbeResult {
                key: kind.key(),
                what: kind.describe(),
                unit: kind.unit(),
                loops,
                count_per_submit: count,
                rate_per_s: count / (s.median * 1e-3),
                rate_q1_per_s: count / (s.q3 * 1e-3),
                rate_q3_per_s: count / (s.q1 * 1e-3),
                gpu_ms: s,
            };
            progress(&format!(
                "{:<34} {:>10}{}/s (IQR {:.1}%, {} loops, {:.2} ms)",
                r.key,
                si(r.rate_per_s),
                r.unit,
                100.0 * r.gpu_ms.iqr_rel,
                loops,
                r.gpu_ms.median
            ));
            results.push(r);
        };

    // Sampling: one image per (dimension, format), its four probes together.
    let sampling = |dim3: bool, format: ProbeFormat| {
        kinds
            .iter()
            .copied()
            .filter(move |k| match k {
                ProbeKind::Sample {
                    dim3: d, format: f, ..
                } => *d == dim3 && *f == format,
                _ => false,
            })
            .collect::<Vec<_>>()
    };
    for dim3 in [false, true] {
        for format in ProbeFormat::ALL {
            let group = sampling(dim3, format);
            if group.is_empty() {
                continue;
            }
            let desc = if dim3 {
                ImageDesc::d3(format.vk(), [TEX_3D; 3])
            } else {
                ImageDesc::d2(format.vk(), [TEX_2D, TEX_2D])
            };
            let img = hashed_image(
                ctx,
                &format!("probe texture {}", format.name()),
                desc,
                format,
            )?;
            let name = if dim3 {
                "bench/sample3d"
            } else {
                "bench/sample2d"
            };
            let pipeline = crate::shaders::pipeline(ctx, name)?;
            let size = if dim3 { TEX_3D } else { TEX_2D } as f32;
            for kind in group {
                let ProbeKind::Sample {
                    bilinear, random, ..
                } = kind
                else {
                    continue;
                };
                let base = if bilinear {
                    SamplerDesc::linear()
                } else {
                    SamplerDesc::nearest()
                };
                let sampler = Sampler::new(
                    ctx,
                    "probe sampler",
                    base.address(ash::vk::SamplerAddressMode::REPEAT)
                        .lod(0.0, 0.0),
                )?;
                let bind = match pipeline.bind_declared(
                    &[
                        ("tex", Resource::texture(&img)),
                        ("smp", Resource::Sampler(&sampler)),
                        ("result", Resource::Buffer(&out)),
                    ],
                    &write_out,
                ) {
                    Ok(b) => b,
                    Err(Error::Unsupported { what, .. }) => {
                        skipped.push(format!("{}: {what}", kind.key()));
                        continue;
                    }
                    Err(e) => return Err(e),
                };
                let pass = kind.key();
                let (loops, s) = time_probe(ctx, cfg, target, &pass, |rec, loops| {
                    let mut push = push_words(&[PROBE_GRID, PROBE_GRID, loops, u32::from(random)]);
                    for v in [1.0 / size, 1.0 / size, 1.0 / size, 0.0] {
                        push.extend_from_slice(&v.to_le_bytes());
                    }
                    rec.dispatch_invocations_tracked(
                        &pipeline,
                        &bind,
                        &push,
                        [PROBE_GRID, PROBE_GRID, 1],
                    )
                })?;
                finish(
                    kind,
                    loops,
                    PROBE_GRID as f64 * PROBE_GRID as f64,
                    s,
                    progress,
                );
            }
        }
    }

    let n = PROBE_INVOCATIONS;
    let dst = Buffer::new(ctx, "probe dst", BufferDesc::storage(n as u64 * 16))?;
    let write_dst = [("dst", AccessSet::from(AccessType::ComputeShaderWrite))];

    // Gathers: one buffer and one storage image of 2^22 vec4s.
    let gathers: Vec<ProbeKind> = kinds
        .iter()
        .copied()
        .filter(|k| matches!(k, ProbeKind::Gather { .. }))
        .collect();
    if !gathers.is_empty() {
        let width_bits = GATHER_BITS / 2 + 1;
        let (w, h) = (1u32 << width_bits, 1u32 << (GATHER_BITS - width_bits));
        let src = Buffer::new(
            ctx,
            "probe gather src",
            BufferDesc::storage(16 << GATHER_BITS),
        )?;
        {
            let mut rec = ctx.recorder("probe gather init")?;
            rec.fill_buffer(&src, 0.75f32.to_bits())?;
            rec.submit_and_wait()?;
        }
        let desc = ImageDesc::d2(ProbeFormat::Rgba32f.vk(), [w, h])
            .usage(ash::vk::ImageUsageFlags::STORAGE);
        let img = hashed_image(ctx, "probe gather image", desc, ProbeFormat::Rgba32f)?;
        let pipeline = crate::shaders::pipeline(ctx, "bench/gather")?;
        let bind = pipeline.bind_declared(
            &[
                ("src", Resource::Buffer(&src)),
                ("img", Resource::storage_image(&img)),
                ("dst", Resource::Buffer(&dst)),
            ],
            &write_dst,
        )?;
        for kind in gathers {
            let ProbeKind::Gather { image, random } = kind else {
                continue;
            };
            let mode = u32::from(random) | (u32::from(image) << 1);
            let (loops, s) = time_probe(ctx, cfg, target, &kind.key(), |rec, loops| {
                let push = push_words(&[n, loops, mode, GATHER_BITS, width_bits]);
                rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])
            })?;
            finish(kind, loops, n as f64, s, progress);
        }
    }

    for kind in kinds.iter().copied() {
        match kind {
            ProbeKind::Ubo { per_lane } => {
                let table: Vec<f32> = (0..4096).map(|i| 0.5 + (i % 97) as f32 / 194.0).collect();
                let ubo = ctx.upload_buffer("probe ubo", BufferDesc::uniform(16384), &table)?;
                let pipeline = crate::shaders::pipeline(ctx, "bench/ubo")?;
                let bind = pipeline.bind_declared(
                    &[
                        ("table", Resource::Buffer(&ubo)),
                        ("dst", Resource::Buffer(&dst)),
                    ],
                    &write_dst,
                )?;
                let (loops, s) = time_probe(ctx, cfg, target, &kind.key(), |rec, loops| {
                    let push = push_words(&[n, loops, u32::from(per_lane), 12345]);
                    rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])
                })?;
                finish(kind, loops, n as f64, s, progress);
            }
            ProbeKind::SharedRead | ProbeKind::Barrier => {
                let barrier = kind == ProbeKind::Barrier;
                let pipeline = crate::shaders::pipeline(ctx, "bench/shared")?;
                let bind =
                    pipeline.bind_declared(&[("dst", Resource::Buffer(&dst))], &write_dst)?;
                let (loops, s) = time_probe(ctx, cfg, target, &kind.key(), |rec, loops| {
                    let push = push_words(&[n, loops, u32::from(barrier), 0]);
                    rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])
                })?;
                // Bandwidth: 4 vec4 (64 bytes) per invocation and iteration; barriers: two
                // per workgroup (256 invocations) and iteration.
                let per_loop = if barrier {
                    2.0 * (n / 256) as f64
                } else {
                    64.0 * n as f64
                };
                finish(kind, loops, per_loop, s, progress);
            }
            ProbeKind::Atomic { spread } => {
                let counters =
                    Buffer::new(ctx, "probe counters", BufferDesc::storage(4 << ATOMIC_BITS))?;
                {
                    let mut rec = ctx.recorder("probe counters init")?;
                    rec.fill_buffer(&counters, 0)?;
                    rec.submit_and_wait()?;
                }
                let pipeline = crate::shaders::pipeline(ctx, "bench/atomic")?;
                let bind = pipeline.bind_declared(
                    &[
                        ("counters", Resource::Buffer(&counters)),
                        ("dst", Resource::Buffer(&dst)),
                    ],
                    &write_dst,
                )?;
                let (loops, s) = time_probe(ctx, cfg, target, &kind.key(), |rec, loops| {
                    let push = push_words(&[n, loops, u32::from(spread), ATOMIC_BITS]);
                    rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])
                })?;
                finish(kind, loops, n as f64, s, progress);
            }
            _ => {}
        }
    }
    Ok((results, skipped))
}

/// The probes whose keys are in `keys` (unknown keys are an error naming them).
pub fn kinds_of(keys: &[&str]) -> Result<Vec<ProbeKind>> {
    let all = ProbeKind::all();
    keys.iter()
        .filter(|k| !matches!(**k, "fma" | "stream"))
        .map(|k| {
            all.iter()
                .copied()
                .find(|p| p.key() == *k)
                .ok_or_else(|| Error::InvalidArgument(format!("no peak probe named '{k}'")))
        })
        .collect()
}
