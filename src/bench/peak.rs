//! Device-peak micro-benchmarks: the roofline every kernel is judged against.
//!
//! - FMA: 2^20 invocations, each 8 independent vec4 FMA chains (64 FLOP per iteration); the
//!   iteration count doubles until one submission takes `min_submit_ms`.
//! - Stream: `dst = src * s` over vec4 buffers (32 bytes per element), repeated in one
//!   submission until it takes `min_submit_ms`; swept over working-set sizes, the headline
//!   number is the largest size (past the caches).

use super::plot::{Panel, Series};
use super::{BenchConfig, MachineInfo, Stats, time_gpu};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessType, Barrier, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Recorder,
    Resource,
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

/// Runs both micro-benchmarks; `progress` receives one line per step.
pub fn run(ctx: &Context, cfg: &BenchConfig, progress: &mut dyn FnMut(&str)) -> Result<PeakReport> {
    let fma = run_fma(ctx, cfg, progress)?;
    let stream = run_stream(ctx, cfg, progress)?;
    Ok(PeakReport {
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
