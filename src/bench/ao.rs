//! `vkshade bench ao`: the sphere-tree ambient occlusion kernel swept over vertex count,
//! sphere count and refinement threshold, against the device peak, the same method on the
//! CPU and the ray-traced ground truth, all measured in the same run.

use super::plot::{Panel, Series};
use super::{BenchConfig, MachineInfo, Stats, time_cpu, time_gpu_passes};
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::kernels::ao::cpu::{self, CpuAo};
use crate::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use crate::kernels::ao::{AoKernel, AoParams, Blend, Correction, Occlusion, Prepared};
use crate::reference::ErrorStats;
use crate::reference::ao::{RayConfig, mesh_visibility};
use crate::scene::spheretree::{BuildConfig, SphereTree};
use crate::scene::{self, Character, Mesh};
use glam::Mat4;
use serde::Serialize;
use std::path::PathBuf;

/// Arithmetic operations per unit of work, counted from the shaders' source (a documented
/// model, not a hardware counter; transcendentals count as one).
pub mod flop_model {
    /// Blend four matrices (4 x 32), transform position and normal (2 x 28), normalise (8).
    pub const SKIN_VERTEX: f64 = 192.0;
    /// Blend four matrices and transform the centre.
    pub const SKIN_SPHERE: f64 = 156.0;
    /// Distance to a tested node and the refinement test.
    pub const TESTED: f64 = 9.0;
    /// h, cos theta, the per-sphere occlusion (formula or table) and the blend.
    pub const USED: f64 = 40.0;
    /// Extra per used sphere with the mask blend: local axis, cap angle, 128 directions.
    pub const MASK: f64 = 800.0;
}

/// Settings of `bench ao`.
#[derive(Clone, Debug, Serialize)]
pub struct AoBenchConfig {
    pub mesh: PathBuf,
    pub animation: Option<String>,
    pub bench: BenchConfig,
    /// Frames compared with the ray-traced mesh for the error axis of the tau sweep.
    pub reference_frames: usize,
    /// Rays per vertex of that reference.
    pub rays: usize,
    /// Subdivision levels of the vertex-count sweep.
    pub subdivisions: Vec<u32>,
    /// Tree depths of the sphere-count sweep.
    pub depths: Vec<u32>,
    pub taus: Vec<f32>,
    /// Runs of the CPU baseline and of the ray tracer.
    pub cpu_runs: usize,
}

impl Default for AoBenchConfig {
    fn default() -> Self {
        AoBenchConfig {
            mesh: PathBuf::from(crate::kernels::ao::DEFAULT_MESH),
            animation: Some(crate::kernels::ao::DEFAULT_ANIMATION.into()),
            bench: BenchConfig {
                warmup: 2,
                samples: 10,
                min_submit_ms: 50.0,
            },
            reference_frames: 2,
            rays: 1024,
            subdivisions: vec![0, 1, 2],
            depths: vec![1, 2, 3, 4],
            taus: vec![0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0],
            cpu_runs: 5,
        }
    }
}

/// One measured configuration.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub vertices: usize,
    pub spheres: usize,
    pub tau: f32,
    pub blend: Blend,
    pub occlusion: Occlusion,
    pub correct: bool,
    pub skin_ms: Stats,
    pub ao_ms: Stats,
    /// Median skin + median ao.
    pub total_ms: f64,
    pub fps: f64,
    pub spheres_tested_per_vertex: f64,
    pub spheres_used_per_vertex: f64,
    /// GFLOP of one frame under `flop_model`.
    pub gflop_per_frame: f64,
    pub gflops: f64,
    /// gflops / the device's measured FMA peak.
    pub fraction_of_peak: f64,
    /// Device memory of the kernel's buffers.
    pub gpu_memory_bytes: u64,
    /// Against the ray-traced mesh, mean over the reference frames (tau sweep only).
    pub mae: Option<f64>,
    pub p95: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct TargetCheck {
    pub name: String,
    pub target: f64,
    pub measured: f64,
    pub pass: bool,
}

/// What `bench ao` writes.
#[derive(Clone, Debug, Serialize)]
pub struct AoBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: AoBenchConfig,
    pub flop_model: [(&'static str, f64); 5],
    /// FMA peak measured in this run.
    pub peak_fma_gflops: f64,
    /// The default configuration (base mesh, depth 3, tau 0.5, mask blend, table).
    pub headline: Point,
    /// The same method on the CPU (rayon, all cores): skinning + occlusion of one frame.
    pub cpu_same_method_ms: Stats,
    /// The ray-traced ground truth of one frame (4096 rays per vertex, rayon).
    pub raytrace_ms: Stats,
    pub speedup_vs_cpu: f64,
    pub speedup_vs_raytrace: f64,
    /// Device memory of the kernel's buffers for the headline mesh.
    pub gpu_memory_bytes: u64,
    pub vertex_sweep: Vec<Point>,
    pub sphere_sweep: Vec<Point>,
    pub tau_sweep: Vec<Point>,
    pub targets: Vec<TargetCheck>,
}

/// Targets (bench/targets.json, compiled in).
pub const TARGETS: &str = include_str!("../../bench/targets.json");

struct Case<'m> {
    character: &'m Character,
    mesh: &'m Mesh,
    tree: &'m SphereTree,
}

/// Times one configuration (kernel built for it) and reads its per-vertex stats.
fn measure(
    ctx: &Context,
    cfg: &BenchConfig,
    case: &Case<'_>,
    params: AoParams,
    factors: Option<&[f32]>,
    matrices: &[Mat4],
    peak: f64,
) -> Result<Point> {
    let prep = Prepared::new(case.mesh, case.tree, case.character.rig.joints.len())?;
    let kernel = AoKernel::new(ctx, &prep, params)?;
    if let Some(f) = factors {
        kernel.set_correction(ctx, f)?;
    }
    let times = time_gpu_passes(ctx, cfg, &["ao skin", "ao occlusion"], |rec| {
        kernel.record(rec, matrices)
    })?;
    let mut rec = ctx.recorder("ao bench stats")?;
    kernel.record(&mut rec, matrices)?;
    let rb = kernel.read_back(&mut rec)?;
    rec.submit_and_wait()?;
    let stats = rb.data()?.stats;
    let nv = stats.len() as f64;
    let tested = stats.iter().map(|s| s[0] as f64).sum::<f64>() / nv;
    let used = stats.iter().map(|s| s[1] as f64).sum::<f64>() / nv;
    let spheres = case.tree.spheres.iter().filter(|s| s.used()).count();
    let per_used = flop_model::USED
        + if params.blend == Blend::Mask {
            flop_model::MASK
        } else {
            0.0
        };
    let flop = nv * (flop_model::SKIN_VERTEX + tested * flop_model::TESTED + used * per_used)
        + case.tree.spheres.len() as f64 * flop_model::SKIN_SPHERE;
    let total = times[0].median + times[1].median;
    let gflops = flop / (total * 1e-3) * 1e-9;
    Ok(Point {
        vertices: stats.len(),
        spheres,
        tau: params.tau,
        blend: params.blend,
        occlusion: params.occlusion,
        correct: params.correct,
        skin_ms: times[0].clone(),
        ao_ms: times[1].clone(),
        total_ms: total,
        fps: 1000.0 / total,
        spheres_tested_per_vertex: tested,
        spheres_used_per_vertex: used,
        gflop_per_frame: flop * 1e-9,
        gflops,
        fraction_of_peak: gflops / peak,
        gpu_memory_bytes: kernel.memory_bytes(),
        mae: None,
        p95: None,
    })
}

/// Runs the benchmark; `progress` receives one line per measurement.
pub fn run(
    ctx: &Context,
    cfg: &AoBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<AoBenchReport> {
    let targets: serde_json::Value = serde_json::from_str(TARGETS)
        .map_err(|e| Error::InvalidArgument(format!("bench/targets.json: {e}")))?;
    let character = scene::load(&cfg.mesh)?;
    let anim = character.pick_animation(cfg.animation.as_deref())?;
    let duration = anim.map(|a| a.duration).unwrap_or(0.0);
    let matrices = character.rig.skinning_matrices(anim, 0.37 * duration);

    progress("device peak (FMA) for the roofline");
    let peak_cfg = BenchConfig {
        warmup: 1,
        samples: 3,
        min_submit_ms: cfg.bench.min_submit_ms,
    };
    let peak = super::peak::run_fma(ctx, &peak_cfg, &mut |_| {})?.throughput_median;
    progress(&format!("  {peak:.1} GFLOP/s"));

    let base_tree = SphereTree::build(&character.mesh, &BuildConfig::default())?.0;
    let base = Case {
        character: &character,
        mesh: &character.mesh,
        tree: &base_tree,
    };
    let defaults = AoParams::default();
    let timing_only = AoParams {
        correct: false,
        ..defaults
    };

    // Headline, with the static correction as the CLI uses it.
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let prep = Prepared::new(&character.mesh, &base_tree, character.rig.joints.len())?;
    let correction = Correction::bake(&character.mesh, cfg.rays);
    let factors = correction.factors(&cpu_ao, &prep, &defaults);
    let headline = measure(
        ctx,
        &cfg.bench,
        &base,
        defaults,
        Some(&factors),
        &matrices,
        peak,
    )?;
    progress(&format!(
        "headline: {} vertices, {} spheres: skin {:.3} + ao {:.3} ms = {:.0} fps, {:.1} spheres/vertex, {:.1} GFLOP/s ({:.1}% of peak)",
        headline.vertices,
        headline.spheres,
        headline.skin_ms.median,
        headline.ao_ms.median,
        headline.fps,
        headline.spheres_used_per_vertex,
        headline.gflops,
        100.0 * headline.fraction_of_peak
    ));
    let gpu_memory_bytes = headline.gpu_memory_bytes;

    // Same method on the CPU, and the ray tracer, on the same frame.
    let cpu_same_method_ms = time_cpu(cfg.cpu_runs, || {
        let posed = cpu::skin(&prep, &matrices);
        cpu_ao.frame(&posed, prep.shape, &defaults, Some(&factors))
    });
    let posed = cpu::skin(&prep, &matrices);
    let diag = {
        let (lo, hi) = character.mesh.bounds();
        (hi - lo).length()
    };
    let all: Vec<usize> = (0..posed.positions.len()).collect();
    let raytrace_ms = time_cpu(cfg.cpu_runs.min(2), || {
        let bvh = crate::geom::Bvh::build(&posed.positions, &character.mesh.triangles);
        mesh_visibility(
            &posed.positions,
            &posed.normals,
            &bvh,
            &all,
            &RayConfig::for_scene(diag),
        )
    });
    progress(&format!(
        "CPU same method {:.2} ms; ray-traced truth (4096 rays) {:.0} ms",
        cpu_same_method_ms.median, raytrace_ms.median
    ));

    let mut vertex_sweep = Vec::new();
    let mut mesh = character.mesh.clone();
    for level in 0..=cfg.subdivisions.iter().copied().max().unwrap_or(0) {
        if cfg.subdivisions.contains(&level) {
            let tree = SphereTree::build(&mesh, &BuildConfig::default())?.0;
            let case = Case {
                character: &character,
                mesh: &mesh,
                tree: &tree,
            };
            let p = measure(ctx, &cfg.bench, &case, timing_only, None, &matrices, peak)?;
            progress(&format!(
                "vertices {}: {:.3} ms ({:.0} fps)",
                p.vertices, p.total_ms, p.fps
            ));
            vertex_sweep.push(p);
        }
        mesh = mesh.subdivide();
    }

    let mut sphere_sweep = Vec::new();
    for &depth in &cfg.depths {
        let tree = SphereTree::build(
            &character.mesh,
            &BuildConfig {
                depth,
                ..Default::default()
            },
        )?
        .0;
        let case = Case {
            character: &character,
            mesh: &character.mesh,
            tree: &tree,
        };
        let p = measure(ctx, &cfg.bench, &case, timing_only, None, &matrices, peak)?;
        progress(&format!(
            "spheres {}: {:.3} ms, {:.1} spheres/vertex",
            p.spheres, p.total_ms, p.spheres_used_per_vertex
        ));
        sphere_sweep.push(p);
    }

    // Error against time: tau x blend, with the reference frames ray-traced once.
    let ref_cfg = RayConfig {
        rays: cfg.rays,
        ..RayConfig::for_scene(diag)
    };
    let frames: Vec<(Vec<Mat4>, Vec<f32>)> = (0..cfg.reference_frames.max(1))
        .map(|k| {
            let t = duration * (k as f32 + 0.5) / cfg.reference_frames.max(1) as f32;
            let m = character.rig.skinning_matrices(anim, t);
            let posed = cpu::skin(&prep, &m);
            let bvh = crate::geom::Bvh::build(&posed.positions, &character.mesh.triangles);
            let truth = mesh_visibility(&posed.positions, &posed.normals, &bvh, &all, &ref_cfg);
            (m, truth)
        })
        .collect();
    let mut tau_sweep = Vec::new();
    for blend in [Blend::Product, Blend::Mask] {
        for &tau in &cfg.taus {
            let params = AoParams {
                tau,
                blend,
                ..defaults
            };
            let f = correction.factors(&cpu_ao, &prep, &params);
            let mut p = measure(ctx, &cfg.bench, &base, params, Some(&f), &matrices, peak)?;
            let (mut mae, mut p95) = (0.0, 0.0);
            for (m, truth) in &frames {
                let posed = cpu::skin(&prep, m);
                let v: Vec<f32> = cpu_ao
                    .frame(&posed, prep.shape, &params, Some(&f))
                    .iter()
                    .map(|v| v.visibility)
                    .collect();
                let e = ErrorStats::of(&v, truth);
                mae += e.mae / frames.len() as f64;
                p95 += e.p95 / frames.len() as f64;
            }
            p.mae = Some(mae);
            p.p95 = Some(p95);
            progress(&format!(
                "{blend:?} tau {tau}: {:.3} ms, MAE {mae:.4}",
                p.total_ms
            ));
            tau_sweep.push(p);
        }
    }
    let mae_default = tau_sweep
        .iter()
        .find(|p| p.blend == defaults.blend && (p.tau - defaults.tau).abs() < 1e-6)
        .and_then(|p| p.mae)
        .unwrap_or(f64::NAN);

    let t = &targets["ao"];
    let check = |name: &str, target: Option<f64>, measured: f64, at_least: bool| {
        target.map(|target| TargetCheck {
            name: name.to_string(),
            target,
            measured,
            pass: if at_least {
                measured >= target
            } else {
                measured <= target
            },
        })
    };
    let targets: Vec<TargetCheck> = [
        check(
            "fps (skinning + AO, headline)",
            t["fps_min"].as_f64(),
            headline.fps,
            true,
        ),
        check(
            "MAE vs ray-traced mesh (headline settings)",
            t["mae_max"].as_f64(),
            mae_default,
            false,
        ),
        check(
            "GPU memory of the kernel (MiB)",
            t["gpu_memory_mib_max"].as_f64(),
            gpu_memory_bytes as f64 / (1 << 20) as f64,
            false,
        ),
    ]
    .into_iter()
    .flatten()
    .collect();

    Ok(AoBenchReport {
        benchmark: "ao",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        flop_model: [
            ("skin_vertex", flop_model::SKIN_VERTEX),
            ("skin_sphere", flop_model::SKIN_SPHERE),
            ("tested", flop_model::TESTED),
            ("used", flop_model::USED),
            ("mask", flop_model::MASK),
        ],
        peak_fma_gflops: peak,
        speedup_vs_cpu: cpu_same_method_ms.median / headline.total_ms,
        speedup_vs_raytrace: raytrace_ms.median / headline.total_ms,
        headline,
        cpu_same_method_ms,
        raytrace_ms,
        gpu_memory_bytes,
        vertex_sweep,
        sphere_sweep,
        tau_sweep,
        targets,
    })
}

/// Error against time (tau sweep), time against vertices and against spheres.
pub fn panels(r: &AoBenchReport) -> Vec<Panel> {
    let series = |blend: Blend| Series {
        name: format!("{blend:?} blend"),
        points: r
            .tau_sweep
            .iter()
            .filter(|p| p.blend == blend)
            .filter_map(|p| p.mae.map(|m| (p.total_ms, m)))
            .collect(),
    };
    vec![
        Panel {
            title: "Error against time (tau sweep)".into(),
            x_label: "GPU ms per frame (skin + AO)".into(),
            y_label: "MAE vs ray-traced mesh".into(),
            log_x: false,
            log_y: false,
            series: vec![series(Blend::Product), series(Blend::Mask)],
        },
        Panel {
            title: "Time against vertex count".into(),
            x_label: "vertices".into(),
            y_label: "GPU ms per frame".into(),
            log_x: true,
            log_y: false,
            series: vec![Series {
                name: format!("{} spheres", r.headline.spheres),
                points: r
                    .vertex_sweep
                    .iter()
                    .map(|p| (p.vertices as f64, p.total_ms))
                    .collect(),
            }],
        },
        Panel {
            title: "Time against sphere count".into(),
            x_label: "spheres in the tree".into(),
            y_label: "GPU ms per frame".into(),
            log_x: true,
            log_y: false,
            series: vec![Series {
                name: format!("{} vertices", r.headline.vertices),
                points: r
                    .sphere_sweep
                    .iter()
                    .map(|p| (p.spheres as f64, p.total_ms))
                    .collect(),
            }],
        },
    ]
}
