//! `vkshade bench frame`: the character frame's whole-frame and per-pass GPU time, host time,
//! and each pass's bandwidth against the streaming peak measured in the same run.

use super::{BenchConfig, MachineInfo, Stats, time_gpu_passes};
use crate::error::{Error, Result};
use crate::frame::{CharacterFrame, FrameConfig, FrameInput};
use crate::gpu::Context;
use serde::Serialize;
use std::time::Instant;

/// One pass of the frame.
#[derive(Clone, Debug, Serialize)]
pub struct PassRow {
    pub name: String,
    pub gpu_ms: Stats,
    /// Share of the frame's median GPU time.
    pub share: f64,
    /// Bytes of every resource the pass binds, each counted once (an upper bound of what it
    /// can touch; a pass that reads a texture sparsely touches less).
    pub bound_bytes: u64,
    /// bound_bytes / median time, GB/s.
    pub gb_s: f64,
    /// gb_s / the streaming peak measured in this run: the pass's place under the memory
    /// roof (an upper bound, see bound_bytes).
    pub fraction_of_stream_peak: f64,
}

/// What `vkshade bench frame` writes.
#[derive(Clone, Debug, Serialize)]
pub struct FrameBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: FrameConfig,
    pub bench: BenchConfig,
    /// Streaming bandwidth measured in this run (GB/s) and f32 FMA throughput (GFLOP/s).
    pub stream_gb_s: f64,
    pub fma_gflops: f64,
    pub passes: Vec<PassRow>,
    /// The whole frame: the sum of its passes per submission.
    pub frame_ms: Stats,
    pub fps: f64,
    /// Host ms per frame outside waiting (matrices, recording, uniforms, submission).
    pub host_ms: Stats,
    /// Targets of issue 18 on this machine class: >= 20 fps, host <= 2 ms.
    pub target_fps: f64,
    pub target_host_ms: f64,
    pub device_memory_bytes: u64,
}

/// Runs the benchmark: the peaks first (short), then the frame over the animation.
pub fn run(
    ctx: &Context,
    cfg: &FrameConfig,
    bench: &BenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<FrameBenchReport> {
    let peak_cfg = BenchConfig {
        warmup: 1,
        samples: 5,
        min_submit_ms: 20.0,
    };
    let stream = super::peak::run_stream(ctx, &peak_cfg, progress)?;
    let fma = super::peak::run_fma(ctx, &peak_cfg, progress)?;
    let stream_gb_s = stream.throughput_median;
    let fma_gflops = fma.throughput_median;
    progress(&format!(
        "peaks: stream {stream_gb_s:.2} GB/s, FMA {fma_gflops:.1} GFLOP/s"
    ));
    let frame = CharacterFrame::new(ctx, cfg, progress)?;
    let infos = frame.passes_by_name();
    let names: Vec<&str> = infos.iter().map(|p| p.name).collect();
    let all = names.join("+");
    let mut timed: Vec<&str> = names.clone();
    timed.push(&all);
    let duration = frame.animation().duration;
    let n = (bench.warmup + bench.samples.max(1)) as f32;
    let mut k = 0usize;
    let mut host = Vec::new();
    let stats = time_gpu_passes(ctx, bench, &timed, |rec| {
        let t = Instant::now();
        let input = FrameInput {
            time: duration * k as f32 / n,
            env_rotation: glam::Mat3::from_rotation_y(k as f32 * 0.1),
        };
        k += 1;
        frame.record(rec, &input)?;
        host.push(t.elapsed().as_secs_f64() * 1e3);
        Ok(())
    })?;
    let (frame_ms, pass_stats) = stats
        .split_last()
        .ok_or_else(|| Error::InvalidArgument("no pass timed".into()))?;
    let whole = frame_ms.median;
    let passes = infos
        .iter()
        .zip(pass_stats)
        .map(|(info, s)| {
            let mut seen = std::collections::BTreeMap::new();
            for u in &info.uses {
                seen.entry(u.resource.clone()).or_insert(u.bytes);
            }
            let bytes: u64 = seen.values().sum();
            let gb_s = bytes as f64 / (s.median * 1e-3) / 1e9;
            PassRow {
                name: info.name.to_string(),
                gpu_ms: s.clone(),
                share: s.median / whole,
                bound_bytes: bytes,
                gb_s,
                fraction_of_stream_peak: gb_s / stream_gb_s,
            }
        })
        .collect();
    // The host samples include the warm-up frames; keep the timed ones.
    let host = Stats::of(&host[bench.warmup.min(host.len())..]).unwrap_or_else(Stats::none);
    Ok(FrameBenchReport {
        benchmark: "frame",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        bench: bench.clone(),
        stream_gb_s,
        fma_gflops,
        passes,
        frame_ms: frame_ms.clone(),
        fps: 1000.0 / whole,
        host_ms: host,
        target_fps: 20.0,
        target_host_ms: 2.0,
        device_memory_bytes: frame.memory_bytes(),
    })
}

/// `bench all`'s frame: the character frame built once, then timed once per round (the
/// whole frame per submission, over the animation). Work model: every pass's bound bytes
/// (each resource once per pass: an upper bound of what it touches) against the streaming
/// peak; no FLOP model and no CPU twin.
pub struct AllBench<'a> {
    ctx: &'a Context,
    bench: BenchConfig,
    frame: CharacterFrame,
    bytes: u64,
}

/// What the frame's roofline covers.
pub const COVERS: &str = "every pass of the frame";

impl<'a> AllBench<'a> {
    pub fn new(ctx: &'a Context, cfg: &FrameConfig, bench: &BenchConfig) -> Result<AllBench<'a>> {
        let frame = CharacterFrame::new(ctx, cfg, &mut |_| {})?;
        let bytes = frame
            .passes()
            .iter()
            .map(|info| {
                let mut seen = std::collections::BTreeMap::new();
                for u in &info.uses {
                    seen.entry(u.resource.clone()).or_insert(u.bytes);
                }
                seen.values().sum::<u64>()
            })
            .sum();
        Ok(AllBench {
            ctx,
            bench: bench.clone(),
            frame,
            bytes,
        })
    }

    /// One round: the whole frame's GPU time over the animation.
    pub fn round(&self) -> Result<super::all::Round> {
        let infos = self.frame.passes_by_name();
        let names: Vec<&str> = infos.iter().map(|p| p.name).collect();
        let all = names.join("+");
        let duration = self.frame.animation().duration;
        let n = (self.bench.warmup + self.bench.samples.max(1)) as f32;
        let mut k = 0usize;
        let stats = time_gpu_passes(self.ctx, &self.bench, &[&all], |rec| {
            let input = FrameInput {
                time: duration * k as f32 / n,
                env_rotation: glam::Mat3::from_rotation_y(k as f32 * 0.1),
            };
            k += 1;
            self.frame.record(rec, &input)
        })?;
        let s = &stats[0];
        Ok(super::all::Round {
            kernel: "frame",
            headline: format!("BCN_Epileptic character frame, {} passes", names.len()),
            gpu_ms: s.median,
            within_iqr_rel: s.iqr_rel,
            terms: vec![super::roofline::Term::new(
                "stream",
                "bound bytes of every pass",
                self.bytes as f64,
            )],
            covers: COVERS,
            covered_ms: s.median,
            cpu_ms: f64::NAN,
            target_fps: Some(20.0),
        })
    }
}

/// The table `bench frame` prints.
pub fn print(r: &FrameBenchReport) {
    println!("device                 {}", r.machine.device);
    println!("host CPU               {}", r.machine.host_cpu);
    println!(
        "peaks (this run)       stream {:.2} GB/s, FMA {:.1} GFLOP/s",
        r.stream_gb_s, r.fma_gflops
    );
    println!(
        "frame                  {} x {}, atlas {}^2 x {} samples, {} cloth part(s), {} skin part(s)",
        r.config.size[0],
        r.config.size[1],
        r.config.atlas,
        r.config.samples,
        r.config.cloth.len(),
        r.config.skin.len()
    );
    println!(
        "{:<24} {:>9} {:>7} {:>11} {:>8} {:>9}",
        "pass", "GPU ms", "share", "bound MiB", "GB/s", "of peak"
    );
    for p in &r.passes {
        println!(
            "{:<24} {:>9.3} {:>6.1}% {:>11.2} {:>8.2} {:>8.1}%",
            p.name,
            p.gpu_ms.median,
            100.0 * p.share,
            p.bound_bytes as f64 / (1 << 20) as f64,
            p.gb_s,
            100.0 * p.fraction_of_stream_peak
        );
    }
    let verdict = |ok: bool| if ok { "met" } else { "MISSED" };
    println!(
        "whole frame              {:.2} ms (spread {:.0}%) = {:.1} fps (target {:.0}: {}), host {:.3} ms/frame (target {:.0}: {})",
        r.frame_ms.median,
        100.0 * r.frame_ms.spread,
        r.fps,
        r.target_fps,
        verdict(r.fps >= r.target_fps),
        r.host_ms.median,
        r.target_host_ms,
        verdict(r.host_ms.median <= r.target_host_ms)
    );
    println!(
        "device memory          {:.1} MiB",
        r.device_memory_bytes as f64 / (1 << 20) as f64
    );
}
