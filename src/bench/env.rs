//! `vkshade bench env`: GPU time of the environment kernel's passes (`env rotate`,
//! `env shadow`) on a posed character, beside the pose and AO passes it runs after, the host
//! time of recording the frame, the CPU twin's time, and the shader's work per vertex (caps x
//! lobes table lookups), over the lobe count; the largest count's `env shadow` against the
//! roofline that binds it ([`roofline_terms`]); and the traced visibility's passes (BVH refit
//! and rays) against their CPU twin.

use super::{BenchConfig, Stats, time_gpu_passes};
use crate::error::{Error, Result};
use crate::geom::sg::Lobe;
use crate::gpu::Context;
use crate::kernels::ao::AoKernel;
use crate::kernels::env::{EnvKernel, EnvVisibility, PASS_ROTATE, PASS_SHADOW, cpu};
use crate::kernels::pose::PoseKernel;
use glam::{Mat4, Vec3, Vec4};
use serde::Serialize;
use std::time::Instant;

/// One lobe count's measurement.
#[derive(Clone, Debug, Serialize)]
pub struct EnvBenchRow {
    /// Lobes.
    pub lobes: usize,
    /// GPU ms of `env rotate`.
    pub rotate: Stats,
    /// GPU ms of `env shadow`.
    pub shadow: Stats,
    /// GPU ms of the pose and AO passes of the same frame (pose skin + ao skin + ao occlusion).
    pub pose_ao: Stats,
    /// Host ms of recording the whole frame (pose, AO, environment), median.
    pub host_ms: f64,
    /// Milliseconds of the CPU twin's shadow pass (rayon), one run.
    pub cpu_ms: f64,
    /// Cap-lobe table lookups per vertex (caps above the horizon x lobes).
    pub lookups_per_vertex: f64,
}

/// The traced visibility's measurement (passes `env bvh leaves`, `env bvh refit`, `env trace`).
#[derive(Clone, Debug, Serialize)]
pub struct TraceBench {
    /// Strata per axis (rays per vertex = grid^2).
    pub grid: u32,
    /// Triangles in the BVH.
    pub triangles: usize,
    /// GPU ms of the three passes together.
    pub gpu: Stats,
    /// GPU ms of `env trace` alone.
    pub trace: Stats,
    /// Rays per second of `env trace` (median).
    pub rays_per_s: f64,
    /// Milliseconds of the CPU twin (refit and rays, rayon), median of 3 runs.
    pub cpu_ms: f64,
}

/// The benchmark's report.
#[derive(Clone, Debug, Serialize)]
pub struct EnvBenchReport {
    /// Vertices shaded.
    pub vertices: usize,
    /// Spheres of the cut per vertex, and those above the horizon (caps evaluated).
    pub cut_per_vertex: f64,
    /// See [`EnvBenchReport::cut_per_vertex`].
    pub caps_per_vertex: f64,
    /// Per lobe count.
    pub rows: Vec<EnvBenchRow>,
    /// The traced visibility (when the input has a mesh to trace).
    pub trace: Option<TraceBench>,
    /// `env shadow` at the largest lobe count against its rooflines ([`roofline_terms`],
    /// rates measured in the same run).
    pub roofline: super::roofline::Roofline,
}

/// FLOP the model counts per cap-lobe lookup: the product lobe's angle to the cap (dot, a
/// cubic acos), the table's s coordinate (clamps), its bilinear blend (3 lerps) and the cap's
/// size against the lobe's (a division), the horizon share, and the factor of the product
/// (with traced rays; a log without). Transcendentals count as the few FMAs lavapipe expands
/// them to (~8 each). The lobe's own terms (log2, sqrt) are taken once per lobe.
pub const FLOP_PER_LOOKUP: f64 = 52.0;
/// FLOP per sphere of the cut: distance, refinement weight, the parent blend, AO's occlusion
/// of the cap, its angle and horizon (asin, acos, sqrt), the log of its transmission.
pub const FLOP_PER_CAP: f64 = 60.0;
/// Loads a lookup makes: the 4 corners of its bilinear cell at the nearest lambda sample as
/// one rgba32f texel (`CapTable::quads`, an image `table`) at coordinates that vary per lane.
pub const GATHERS_PER_LOOKUP: f64 = 1.0;

/// The work model of `env shadow` for `vertices` vertices, `cut` spheres of the cut and
/// `caps` caps above the horizon per vertex, and `lobes` lobes: FLOP (fma), and the cap
/// table's loads (image_gather_coherent: the table, 7.1 MiB as quads, of which a lobe's
/// sharpness row (49 KiB) is read, stays in the caches, which the random probe's large buffer
/// does not; against the random buffer-gather rate the pass ran at 20x "its peak", when the
/// table was a storage buffer). Every cap and lobe takes one lookup. The cut's sphere reads
/// (a few per node, mostly shared by neighbouring vertices) and the per-vertex lobe setup are
/// left out.
pub fn roofline_terms(
    vertices: usize,
    cut: f64,
    caps: f64,
    lobes: usize,
) -> Vec<super::roofline::Term> {
    use super::roofline::Term;
    let v = vertices as f64;
    let lookups = v * caps * lobes as f64;
    vec![
        Term::new(
            "fma",
            "FLOP (FLOP_PER_LOOKUP x lookups + FLOP_PER_CAP x cut spheres)",
            lookups * FLOP_PER_LOOKUP + v * cut * FLOP_PER_CAP,
        ),
        Term::new(
            "image_gather_coherent",
            "cap-table reads (GATHERS_PER_LOOKUP x lookups)",
            lookups * GATHERS_PER_LOOKUP,
        ),
    ]
}

/// What the benchmark runs on: the character's posed frame and its kernels' inputs.
pub struct EnvBenchInput<'a> {
    /// The character's pose kernel.
    pub pose: &'a PoseKernel,
    /// AO on that pose.
    pub ao: &'a AoKernel,
    /// The frame's skinning matrices.
    pub matrices: &'a [Mat4],
    /// The fitted lobes (the counts benchmarked take the first k, repeating when k exceeds
    /// them).
    pub lobes: &'a [Lobe],
    /// Lobe counts to time.
    pub counts: &'a [usize],
    /// [`EnvVisibility::Traced`] (the mesh the pose kernel skins and the grid): the traced
    /// visibility is timed too; [`EnvVisibility::Ao`]: it is not.
    pub trace: EnvVisibility<'a>,
}

/// Times the environment kernel at each lobe count on `input`'s posed frame.
pub fn run(ctx: &Context, cfg: &BenchConfig, input: &EnvBenchInput) -> Result<EnvBenchReport> {
    if input.lobes.is_empty() {
        return Err(Error::InvalidArgument("no lobes to benchmark".into()));
    }
    let r = crate::geom::sg::rotation(Vec3::new(0.2, 1.0, 0.1), 35.0);
    // The frame's posed data for the twin and the cost count (read back once).
    let (ao_data, spheres, extents) = {
        let mut rec = ctx.recorder("env bench inputs")?;
        input.pose.record(&mut rec, input.matrices)?;
        input.ao.record(&mut rec, input.matrices)?;
        let a = input.ao.read_back(&mut rec)?;
        let s = rec.read_back(input.ao.posed_spheres())?;
        let e = rec.read_back(input.ao.posed_extents())?;
        rec.submit_and_wait()?;
        (a.data()?, s.to_vec::<[f32; 4]>()?, e.to_vec::<f32>()?)
    };
    let v3 = |v: &[[f32; 4]]| -> Vec<Vec3> {
        v.iter().map(|p| Vec4::from_array(*p).truncate()).collect()
    };
    let (positions, normals) = (v3(&ao_data.positions), v3(&ao_data.normals));
    let spheres: Vec<Vec4> = spheres.iter().map(|s| Vec4::from_array(*s)).collect();
    // The cut the shadow pass walks.
    let traced = matches!(input.trace, EnvVisibility::Traced { .. });
    let params = crate::kernels::env::shadow_cut(input.ao.params(), traced);
    let inputs = cpu::ShadowInputs {
        positions: &positions,
        normals: &normals,
        spheres: &spheres,
        extents: &extents,
        shape: input.ao.tree_shape(),
        params: &params,
        ao: Some(&ao_data.visibility),
        rays: None,
    };
    let (caps, cut) = cpu::caps_per_vertex(&inputs);
    // With traced visibility the kernel runs module `env/shadow_rays`, and its twin reads the
    // rays' escape bits (cast once by the twin of `env trace`).
    let mut bits: Option<(Vec<u32>, u32, u32)> = None;
    let mut rows = Vec::new();
    for &k in input.counts {
        let lobes: Vec<Lobe> = (0..k).map(|i| input.lobes[i % input.lobes.len()]).collect();
        let mut setup = ctx.recorder("env bench setup")?;
        let env =
            EnvKernel::with_visibility(&mut setup, &lobes, input.pose, input.ao, input.trace)?;
        setup.submit_and_wait()?;
        if let (None, Some((top, tcfg))) = (&bits, env.traced()) {
            let (_, b) = cpu::traced_rays(top, &positions, &normals, tcfg);
            bits = Some((b, tcfg.grid, tcfg.seed));
        }
        debug_assert_eq!(env.ao_params(), &params);
        let inputs = cpu::ShadowInputs {
            rays: bits.as_ref().map(|(bits, grid, seed)| cpu::RayBits {
                bits,
                grid: *grid,
                seed: *seed,
            }),
            ..inputs
        };
        let mut host = Vec::new();
        let names = [PASS_ROTATE, PASS_SHADOW, "pose skin+ao skin+ao occlusion"];
        let stats = time_gpu_passes(ctx, cfg, &names, |rec| {
            let t = Instant::now();
            input.pose.record(rec, input.matrices)?;
            input.ao.record(rec, input.matrices)?;
            env.record(rec, &r)?;
            host.push(t.elapsed().as_secs_f64() * 1e3);
            Ok(())
        })?;
        let rotated = cpu::rotate(&lobes, r);
        let t = Instant::now();
        let twin = cpu::shadow(&rotated, env.table(), &inputs);
        let cpu_ms = t.elapsed().as_secs_f64() * 1e3;
        std::hint::black_box(&twin);
        host.sort_by(f64::total_cmp);
        let mut stats = stats.into_iter();
        let mut next = || stats.next().expect("three passes timed");
        rows.push(EnvBenchRow {
            lobes: k,
            rotate: next(),
            shadow: next(),
            pose_ao: next(),
            host_ms: host[host.len() / 2],
            cpu_ms,
            lookups_per_vertex: caps * k as f64,
        });
    }
    let trace = match input.trace {
        EnvVisibility::Ao => None,
        EnvVisibility::Traced {
            triangles, grid, ..
        } => {
            let lobes = &input.lobes[..1];
            let mut setup = ctx.recorder("env bench trace setup")?;
            let env =
                EnvKernel::with_visibility(&mut setup, lobes, input.pose, input.ao, input.trace)?;
            setup.submit_and_wait()?;
            let names = [
                "env bvh leaves+env bvh refit+env trace",
                crate::kernels::env::PASS_TRACE,
            ];
            let stats = time_gpu_passes(ctx, cfg, &names, |rec| {
                input.pose.record(rec, input.matrices)?;
                input.ao.record(rec, input.matrices)?;
                env.record(rec, &r)
            })?;
            let (top, tcfg) = env.traced().expect("built with traced visibility");
            let mut cpu = Vec::new();
            for _ in 0..3 {
                let t = Instant::now();
                std::hint::black_box(cpu::traced_visibility(top, &positions, &normals, tcfg));
                cpu.push(t.elapsed().as_secs_f64() * 1e3);
            }
            cpu.sort_by(f64::total_cmp);
            let mut stats = stats.into_iter();
            let (gpu, trace) = (stats.next().expect("timed"), stats.next().expect("timed"));
            let rays = positions.len() as f64 * (grid * grid) as f64;
            Some(TraceBench {
                grid,
                triangles: triangles.len(),
                rays_per_s: rays / (trace.median * 1e-3),
                gpu,
                trace,
                cpu_ms: cpu[1],
            })
        }
    };
    let last = rows
        .last()
        .ok_or_else(|| Error::InvalidArgument("no lobe counts to benchmark".into()))?;
    let terms = roofline_terms(positions.len(), cut, caps, last.lobes);
    let rates = super::roofline::measure_rates(ctx, cfg, &terms, None)?;
    let roofline = super::roofline::Roofline::evaluate(
        &format!("env shadow, {} lobes", last.lobes),
        terms,
        last.shadow.median,
        &rates,
    );
    Ok(EnvBenchReport {
        vertices: positions.len(),
        cut_per_vertex: cut,
        caps_per_vertex: caps,
        rows,
        trace,
        roofline,
    })
}
