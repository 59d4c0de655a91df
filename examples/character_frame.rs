//! A renderer's own loop driving the character frame through vkshade's public API: the
//! built-in character (BCN_Epileptic, Head as skin, Torso and Legs as cloth) animated over
//! 8 frames, two frames in flight, on a validated context (synchronization validation on).
//! Every frame's images are checked against the compose pass's CPU twin run on that frame's
//! own stages (G-buffer, posed vertices, diffusion, cloth radiance, read back with it).
//! Run with `cargo run --release --example character_frame`; `cargo test` runs it too
//! (tests/character_frame.rs).

use std::collections::VecDeque;
use vkshade::frame::{CharacterFrame, FrameConfig, FrameInput, StageReadback};
use vkshade::gpu::{Context, ContextDesc, Features, Submission};

/// Frames rendered and frames kept in flight.
pub const FRAMES: usize = 8;
pub const IN_FLIGHT: usize = 2;
/// The largest relative difference allowed between a GPU pixel and the CPU twin's (the
/// bound of tests/frame.rs, justified there: FMA contraction and transcendental ulps through
/// the pixel's barycentrics and the bilinear atlas lookup).
pub const MAX_REL: f32 = 2e-4;

/// What the loop saw.
pub struct Summary {
    pub frames: usize,
    pub max_in_flight: usize,
    /// The worst |GPU - CPU| / max(|CPU|, 1e-3) over every frame's pixels.
    pub worst_rel: f32,
    pub gpu_ms: Vec<f64>,
    pub validation_messages: usize,
}

/// Runs the loop on a fresh validated context; the messages are counted at shutdown.
pub fn run() -> vkshade::Result<Summary> {
    let ctx = Context::new(&ContextDesc {
        features: Features {
            buffer_int64_atomics: true, // the rasteriser's 64-bit atomicMin
            ..Features::default()
        },
        ..ContextDesc::validated()
    })?;
    let result = frames(&ctx);
    let messages = ctx.shutdown()?;
    for m in &messages {
        eprintln!("validation: {m}");
    }
    let mut s = result?;
    s.validation_messages = messages.len();
    Ok(s)
}

fn frames(ctx: &Context) -> vkshade::Result<Summary> {
    let cfg = FrameConfig {
        mesh: std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb"),
        size: [160, 160],
        atlas: 128,
        samples: 8,
        btf_tile: 8,
        ..FrameConfig::default()
    };
    let frame = CharacterFrame::new(ctx, &cfg, &mut |l| eprintln!("{l}"))?;
    let duration = frame.animation().duration;
    let mut pending: VecDeque<(usize, Submission, StageReadback)> = VecDeque::new();
    let mut summary = Summary {
        frames: 0,
        max_in_flight: 0,
        worst_rel: 0.0,
        gpu_ms: Vec::new(),
        validation_messages: 0,
    };
    let params = frame.params();
    let mut check = |(i, sub, rb): (usize, Submission, StageReadback)| -> vkshade::Result<()> {
        let timings = sub.wait()?;
        let stages = frame.collect_stages(&rb)?;
        let (hdr, _) = frame.compose_twin(&params, &stages);
        let mut worst = 0f32;
        for (g, t) in stages.output.hdr.iter().zip(&hdr) {
            for c in 0..3 {
                worst = worst.max((g[c] - t[c]).abs() / t[c].abs().max(1e-3));
            }
        }
        let ms: f64 = timings.passes.iter().map(|p| p.ms).sum();
        println!(
            "frame {i}: GPU {ms:.1} ms, worst relative difference to the CPU twin {worst:.2e}"
        );
        summary.worst_rel = summary.worst_rel.max(worst);
        summary.gpu_ms.push(ms);
        summary.frames += 1;
        Ok(())
    };
    for i in 0..FRAMES {
        let input = FrameInput {
            time: duration * i as f32 / FRAMES as f32,
            env_rotation: glam::Mat3::from_rotation_y(i as f32 * 0.4),
        };
        let mut rec = ctx.recorder(&format!("frame {i}"))?;
        frame.record(&mut rec, &input)?;
        let rb = frame.read_back_stages(&mut rec)?;
        pending.push_back((i, rec.submit()?, rb));
        summary.max_in_flight = summary.max_in_flight.max(pending.len());
        if pending.len() >= IN_FLIGHT
            && let Some(p) = pending.pop_front()
        {
            check(p)?;
        }
    }
    while let Some(p) = pending.pop_front() {
        check(p)?;
    }
    Ok(summary)
}

fn main() -> vkshade::Result<()> {
    let s = run()?;
    println!(
        "{} frames, {} in flight at most, worst relative difference {:.2e} (bound {MAX_REL:e}), {} validation messages",
        s.frames, s.max_in_flight, s.worst_rel, s.validation_messages
    );
    if s.worst_rel > MAX_REL || s.validation_messages > 0 {
        return Err(vkshade::Error::InvalidArgument(
            "the frame differs from its CPU twin, or validation reported".into(),
        ));
    }
    Ok(())
}
