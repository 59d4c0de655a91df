//! `vkshade bench ao`: the sphere-tree ambient occlusion kernel swept over vertex count,
//! sphere count and refinement threshold, against the device peak, the same method on the
//! CPU and the ray-traced ground truth, all measured in the same run.

use super::plot::{Panel, Series};
use super::{BenchConfig, MachineInfo, Stats, time_cpu};
use crate::error::{Error, Result};
use crate::geom::visibility::{RayConfig, ambient_visibility};
use crate::gpu::Context;
use crate::kernels::ao::cpu::{self, CpuAo};
use crate::kernels::ao::fixed::FIXED_SLOTS;
use crate::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use crate::kernels::ao::{
    AoKernel, AoParams, Blend, Correction, Cut, FixedCut, Occlusion, Prepared,
};
use crate::kernels::ao::{PASS_OCCLUSION, PASS_POSE, PASS_SKIN};
use crate::progress::Progress;
use crate::reference::ErrorStats;
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

/// Loads per unit of work (a documented model, read off glsl/ao/occlusion.comp and
/// glsl/pose/skin.comp; a load of any width up to 16 bytes counts as one, at the rate of
/// `buffer_gather_coherent`: neighbouring vertices walk mostly the same nodes).
pub mod load_model {
    /// Position, normal, joint indices and weights (skinning), the correction factor.
    pub const PER_VERTEX: f64 = 5.0;
    /// The node's sphere and its extent.
    pub const PER_TESTED: f64 = 2.0;
    /// Four table entries (the bilinear lookup of the per-sphere occlusion).
    pub const PER_USED: f64 = 4.0;
}

/// The work model of one frame of `p` (`nodes` spheres skinned): FLOPs ([`flop_model`]) and
/// storage-buffer loads ([`load_model`]).
pub fn work_model(p: &Point, nodes: usize) -> Vec<super::roofline::Term> {
    use super::roofline::Term;
    let nv = p.vertices as f64;
    vec![
        Term::new("fma", "FLOP (flop_model)", p.gflop_per_frame * 1e9),
        Term::new(
            "buffer_gather_coherent",
            "storage-buffer loads (load_model)",
            nv * (load_model::PER_VERTEX
                + p.spheres_tested_per_vertex * load_model::PER_TESTED
                + p.spheres_used_per_vertex * load_model::PER_USED)
                + nodes as f64 * load_model::PER_VERTEX,
        ),
    ]
}

/// What the roofline of [`work_model`] covers.
pub const COVERS: &str = "pose + skin + occlusion passes";

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
    /// Device memory of the kernel's buffers (their allocations).
    pub gpu_memory_bytes: u64,
    /// Device memory the context's allocator holds in blocks (used or not) at this point.
    pub gpu_memory_reserved_bytes: u64,
    /// The CPU twin's visibility against the ray-traced mesh, mean over the reference frames
    /// (tau sweep and cut comparison; tests/ao.rs holds the GPU to the twin within MAE 1e-4).
    pub mae: Option<f64>,
    pub p95: Option<f64>,
}

/// One cut of the side-by-side comparison: the headline settings with that cut, timed on
/// the GPU and on the CPU twin and compared with the ray-traced reference frames.
#[derive(Clone, Debug, Serialize)]
pub struct CutPoint {
    pub cut: Cut,
    /// GPU times, work and the configured method's error (with the static correction).
    pub point: Point,
    /// MAE of the method alone (no static correction; the CPU twin's, as `Point::mae`), mean
    /// over the reference frames.
    pub mae_alone: f64,
    /// The CPU twin of the same cut (rayon): skinning + occlusion of one frame.
    pub cpu_twin_ms: Stats,
    /// cpu_twin_ms / the GPU's total.
    pub speedup_vs_cpu: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct TargetCheck {
    pub name: String,
    pub target: f64,
    pub measured: f64,
    pub pass: bool,
}

impl TargetCheck {
    /// `measured` against `target` (none: no check), which is a floor when `at_least`,
    /// else a ceiling.
    pub fn of(name: &str, target: Option<f64>, measured: f64, at_least: bool) -> Option<Self> {
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
    }
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
    /// The default (adaptive) cut and the published fixed cut side by side, headline
    /// settings otherwise.
    pub cut_comparison: Vec<CutPoint>,
    pub targets: Vec<TargetCheck>,
    /// The headline against its binding roofline ([`work_model`], rates measured in this
    /// run).
    pub roofline: super::roofline::Roofline,
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
    let mut setup = ctx.recorder("ao bench setup")?;
    let kernel = AoKernel::new(&mut setup, &prep, params)?;
    if let Some(f) = factors {
        kernel.set_correction(&mut setup, f)?;
    }
    setup.submit_and_wait()?;
    // Skinning (the vertices' pose pass plus the spheres') and occlusion; the joints upload
    // is not counted.
    let skin = format!("{PASS_POSE}+{PASS_SKIN}");
    let times = super::time_gpu_passes(ctx, cfg, &[&skin, PASS_OCCLUSION], |rec| {
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
        gpu_memory_reserved_bytes: kernel.memory().reserved_bytes,
        mae: None,
        p95: None,
    })
}

/// What every step of the benchmark shares: the character, its base tree and correction,
/// the timed frame's matrices and the measured peak.
struct Setup<'a> {
    ctx: &'a Context,
    cfg: &'a AoBenchConfig,
    character: Character,
    anim_duration: f32,
    matrices: Vec<Mat4>,
    peak: f64,
    base_tree: SphereTree,
    prep: Prepared,
    cpu_ao: CpuAo,
    correction: Correction,
    diagonal: f32,
}

/// A ray-traced reference frame of the tau sweep.
struct ReferenceFrame {
    matrices: Vec<Mat4>,
    truth: Vec<f32>,
}

/// Runs the benchmark; `progress` receives one line per measurement (and a terminal shows
/// a counter over the long steps).
pub fn run(
    ctx: &Context,
    cfg: &AoBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<AoBenchReport> {
    let targets: serde_json::Value = serde_json::from_str(TARGETS)
        .map_err(|e| Error::InvalidArgument(format!("bench/targets.json: {e}")))?;
    let setup = Setup::new(ctx, cfg, progress)?;
    let frames = setup.reference_frames();
    let (cpu_same_method_ms, raytrace_ms) = setup.baselines(progress);
    let measurements = 3 + cfg.subdivisions.len() + cfg.depths.len() + 2 * cfg.taus.len();
    let counter = Progress::start("bench ao measurements", measurements as u64);
    let headline = setup.headline(progress)?;
    counter.add(1);
    let vertex_sweep = setup.vertex_sweep(&counter, progress)?;
    let sphere_sweep = setup.sphere_sweep(&counter, progress)?;
    let tau_sweep = setup.tau_sweep(&frames, &counter, progress)?;
    let cut_comparison = setup.cut_comparison(&frames, &counter, progress)?;
    drop(counter);
    let vs_cpu = cpu_same_method_ms.median / headline.total_ms;
    let targets = check_targets(&targets["ao"], &headline, &tau_sweep, vs_cpu);
    let terms = work_model(&headline, setup.base_tree.spheres.len());
    progress("rates of the work model (probes)");
    let rates = super::roofline::measure_rates(ctx, &cfg.bench, &terms, Some(setup.peak))?;
    let roofline = super::roofline::Roofline::evaluate(COVERS, terms, headline.total_ms, &rates);
    Ok(AoBenchReport {
        roofline,
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
        peak_fma_gflops: setup.peak,
        speedup_vs_cpu: vs_cpu,
        speedup_vs_raytrace: raytrace_ms.median / headline.total_ms,
        gpu_memory_bytes: headline.gpu_memory_bytes,
        headline,
        cpu_same_method_ms,
        raytrace_ms,
        vertex_sweep,
        sphere_sweep,
        tau_sweep,
        cut_comparison,
        targets,
    })
}

/// `bench all`'s AO: the setup once, then the headline (and the CPU twin) once per round.
pub struct AllBench<'a> {
    setup: Setup<'a>,
    factors: Vec<f32>,
    fps_min: Option<f64>,
}

impl<'a> AllBench<'a> {
    pub fn new(ctx: &'a Context, cfg: &'a AoBenchConfig) -> Result<AllBench<'a>> {
        let targets: serde_json::Value = serde_json::from_str(TARGETS)
            .map_err(|e| Error::InvalidArgument(format!("bench/targets.json: {e}")))?;
        let setup = Setup::new(ctx, cfg, &mut |_| {})?;
        let factors = setup
            .correction
            .factors(&setup.cpu_ao, &setup.prep, &AoParams::default());
        Ok(AllBench {
            setup,
            factors,
            fps_min: targets["ao"]["fps_min"].as_f64(),
        })
    }

    /// One round: the headline's GPU time and work model, the CPU twin's wall time.
    pub fn round(&self) -> Result<super::all::Round> {
        let s = &self.setup;
        let defaults = AoParams::default();
        let p = s.measure(&s.base(), defaults, Some(&self.factors))?;
        let cpu = time_cpu(1, || {
            let posed = cpu::skin(&s.prep, &s.matrices);
            s.cpu_ao
                .frame(&posed, s.prep.shape, &defaults, Some(&self.factors))
        });
        Ok(super::all::Round {
            kernel: "ao",
            headline: format!(
                "Testwuson, {} vertices, {} spheres, tau {}",
                p.vertices, p.spheres, p.tau
            ),
            gpu_ms: p.total_ms,
            within_iqr_rel: p.skin_ms.iqr_rel.max(p.ao_ms.iqr_rel),
            terms: work_model(&p, s.base_tree.spheres.len()),
            covers: COVERS,
            covered_ms: p.total_ms,
            cpu_ms: cpu.median,
            target_fps: self.fps_min,
        })
    }
}

impl<'a> Setup<'a> {
    /// Loads the character, measures the FMA peak, builds the base tree, bakes the correction.
    fn new(
        ctx: &'a Context,
        cfg: &'a AoBenchConfig,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Setup<'a>> {
        let character = scene::load(&cfg.mesh)?;
        let anim = character.pick_animation(cfg.animation.as_deref())?;
        let anim_duration = anim.map(|a| a.duration).unwrap_or(0.0);
        let matrices = character.rig.skinning_matrices(anim, 0.37 * anim_duration);

        progress("device peak (FMA) for the roofline");
        let peak_cfg = BenchConfig {
            warmup: 1,
            samples: 3,
            min_submit_ms: cfg.bench.min_submit_ms,
        };
        let peak = super::peak::run_fma(ctx, &peak_cfg, &mut |_| {})?.throughput_median;
        progress(&format!("  {peak:.1} GFLOP/s"));

        let base_tree = SphereTree::build(&character.mesh, &BuildConfig::default())?.0;
        let prep = Prepared::new(&character.mesh, &base_tree, character.rig.joints.len())?;
        let correction = {
            let _p = Progress::start("static correction bake", prep.vertex_count() as u64);
            Correction::bake(&character.mesh, cfg.rays)
        };
        let diagonal = {
            let (lo, hi) = character.mesh.bounds();
            (hi - lo).length()
        };
        Ok(Setup {
            ctx,
            cfg,
            anim_duration,
            matrices,
            peak,
            base_tree,
            prep,
            cpu_ao: CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE)),
            correction,
            diagonal,
            character,
        })
    }

    fn base(&self) -> Case<'_> {
        Case {
            character: &self.character,
            mesh: &self.character.mesh,
            tree: &self.base_tree,
        }
    }

    /// Times one configuration of `case` at the benchmark's frame.
    fn measure(&self, case: &Case<'_>, params: AoParams, factors: Option<&[f32]>) -> Result<Point> {
        measure(
            self.ctx,
            &self.cfg.bench,
            case,
            params,
            factors,
            &self.matrices,
            self.peak,
        )
    }

    /// The default configuration, with the static correction as the CLI uses it.
    fn headline(&self, progress: &mut dyn FnMut(&str)) -> Result<Point> {
        let defaults = AoParams::default();
        let factors = self.correction.factors(&self.cpu_ao, &self.prep, &defaults);
        let h = self.measure(&self.base(), defaults, Some(&factors))?;
        progress(&format!(
            "headline: {} vertices, {} spheres: skin {:.3} + ao {:.3} ms = {:.0} fps, {:.1} spheres/vertex, {:.1} GFLOP/s ({:.1}% of peak)",
            h.vertices,
            h.spheres,
            h.skin_ms.median,
            h.ao_ms.median,
            h.fps,
            h.spheres_used_per_vertex,
            h.gflops,
            100.0 * h.fraction_of_peak
        ));
        Ok(h)
    }

    /// The same method on the CPU, and the ray tracer, on the benchmark's frame.
    fn baselines(&self, progress: &mut dyn FnMut(&str)) -> (Stats, Stats) {
        let defaults = AoParams::default();
        let factors = self.correction.factors(&self.cpu_ao, &self.prep, &defaults);
        let cpu_same_method_ms = time_cpu(self.cfg.cpu_runs, || {
            let posed = cpu::skin(&self.prep, &self.matrices);
            self.cpu_ao
                .frame(&posed, self.prep.shape, &defaults, Some(&factors))
        });
        let posed = cpu::skin(&self.prep, &self.matrices);
        let all: Vec<usize> = (0..posed.positions.len()).collect();
        let runs = self.cfg.cpu_runs.min(2);
        // time_cpu runs once untimed first.
        let _p = Progress::start("ray-tracing baseline", ((runs + 1) * all.len()) as u64);
        let raytrace_ms = time_cpu(runs, || {
            let bvh = crate::geom::Bvh::build(&posed.positions, &self.character.mesh.triangles);
            ambient_visibility(
                &posed.positions,
                &posed.normals,
                &bvh,
                &all,
                &RayConfig::for_scene(self.diagonal),
            )
        });
        progress(&format!(
            "CPU same method {:.2} ms; ray-traced truth (4096 rays) {:.0} ms",
            cpu_same_method_ms.median, raytrace_ms.median
        ));
        (cpu_same_method_ms, raytrace_ms)
    }

    /// Time against vertex count: the mesh subdivided, a tree built for each level.
    fn vertex_sweep(
        &self,
        counter: &Progress,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Vec<Point>> {
        let timing_only = AoParams {
            correct: false,
            ..AoParams::default()
        };
        let mut sweep = Vec::new();
        let mut mesh = self.character.mesh.clone();
        for level in 0..=self.cfg.subdivisions.iter().copied().max().unwrap_or(0) {
            if self.cfg.subdivisions.contains(&level) {
                let tree = SphereTree::build(&mesh, &BuildConfig::default())?.0;
                let case = Case {
                    character: &self.character,
                    mesh: &mesh,
                    tree: &tree,
                };
                let p = self.measure(&case, timing_only, None)?;
                counter.add(1);
                progress(&format!(
                    "vertices {}: {:.3} ms ({:.0} fps)",
                    p.vertices, p.total_ms, p.fps
                ));
                sweep.push(p);
            }
            mesh = mesh.subdivide();
        }
        Ok(sweep)
    }

    /// Time against sphere count: trees of each depth over the base mesh.
    fn sphere_sweep(
        &self,
        counter: &Progress,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Vec<Point>> {
        let timing_only = AoParams {
            correct: false,
            ..AoParams::default()
        };
        let mut sweep = Vec::new();
        for &depth in &self.cfg.depths {
            let build = BuildConfig {
                depth,
                ..Default::default()
            };
            let tree = SphereTree::build(&self.character.mesh, &build)?.0;
            let case = Case {
                character: &self.character,
                mesh: &self.character.mesh,
                tree: &tree,
            };
            let p = self.measure(&case, timing_only, None)?;
            counter.add(1);
            progress(&format!(
                "spheres {}: {:.3} ms, {:.1} spheres/vertex",
                p.spheres, p.total_ms, p.spheres_used_per_vertex
            ));
            sweep.push(p);
        }
        Ok(sweep)
    }

    /// The frames of the tau sweep's error axis, ray-traced once.
    fn reference_frames(&self) -> Vec<ReferenceFrame> {
        let n = self.cfg.reference_frames.max(1);
        let all: Vec<usize> = (0..self.prep.vertex_count()).collect();
        let ray_cfg = RayConfig {
            rays: self.cfg.rays,
            ..RayConfig::for_scene(self.diagonal)
        };
        let anim = self
            .character
            .pick_animation(self.cfg.animation.as_deref())
            .ok()
            .flatten();
        let _p = Progress::start("ray-traced reference frames", (n * all.len()) as u64);
        (0..n)
            .map(|k| {
                let t = self.anim_duration * (k as f32 + 0.5) / n as f32;
                let matrices = self.character.rig.skinning_matrices(anim, t);
                let posed = cpu::skin(&self.prep, &matrices);
                let bvh = crate::geom::Bvh::build(&posed.positions, &self.character.mesh.triangles);
                let truth =
                    ambient_visibility(&posed.positions, &posed.normals, &bvh, &all, &ray_cfg);
                ReferenceFrame { matrices, truth }
            })
            .collect()
    }

    /// The adaptive and the fixed cut at the headline settings: GPU time, CPU twin time, and
    /// error (with and without the static correction) against the reference frames.
    fn cut_comparison(
        &self,
        frames: &[ReferenceFrame],
        counter: &Progress,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Vec<CutPoint>> {
        let mut out = Vec::new();
        for cut in [Cut::Adaptive, Cut::Fixed] {
            let params = AoParams {
                cut,
                ..AoParams::default()
            };
            let plain = AoParams {
                correct: false,
                ..params
            };
            // The kernel chooses the same lists (deterministic) from the same input.
            let fixed = match cut {
                Cut::Fixed => Some(FixedCut::select(&self.prep, &params, FIXED_SLOTS)?),
                Cut::Adaptive => None,
            };
            let twin = |posed: &cpu::Posed, params: &AoParams, f: Option<&[f32]>| match &fixed {
                Some(l) => self.cpu_ao.fixed_frame(posed, l, params, f),
                None => self.cpu_ao.frame(posed, self.prep.shape, params, f),
            };
            let factors = match &fixed {
                Some(l) => self
                    .correction
                    .fixed_factors(&self.cpu_ao, &self.prep, l, &params),
                None => self.correction.factors(&self.cpu_ao, &self.prep, &params),
            };
            let mut p = self.measure(&self.base(), params, Some(&factors))?;
            let (mut mae, mut p95, mut mae_alone) = (0.0, 0.0, 0.0);
            for frame in frames {
                let posed = cpu::skin(&self.prep, &frame.matrices);
                let vis = |v: Vec<cpu::VertexAo>| -> Vec<f32> {
                    v.iter().map(|v| v.visibility).collect()
                };
                let e = ErrorStats::of(&vis(twin(&posed, &params, Some(&factors))), &frame.truth);
                let alone = ErrorStats::of(&vis(twin(&posed, &plain, None)), &frame.truth);
                let k = frames.len() as f64;
                mae += e.mae / k;
                p95 += e.p95 / k;
                mae_alone += alone.mae / k;
            }
            p.mae = Some(mae);
            p.p95 = Some(p95);
            let cpu_twin_ms = time_cpu(self.cfg.cpu_runs, || {
                let posed = cpu::skin(&self.prep, &self.matrices);
                twin(&posed, &params, Some(&factors))
            });
            counter.add(1);
            progress(&format!(
                "{cut:?} cut: {:.3} ms GPU ({:.0} fps), CPU twin {:.2} ms, MAE {mae:.4} (alone {mae_alone:.4}), {:.1} spheres/vertex",
                p.total_ms, p.fps, cpu_twin_ms.median, p.spheres_used_per_vertex
            ));
            out.push(CutPoint {
                cut,
                speedup_vs_cpu: cpu_twin_ms.median / p.total_ms,
                point: p,
                mae_alone,
                cpu_twin_ms,
            });
        }
        Ok(out)
    }

    /// Error against time: tau x blend, each timed and compared with the reference frames.
    fn tau_sweep(
        &self,
        frames: &[ReferenceFrame],
        counter: &Progress,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Vec<Point>> {
        let mut sweep = Vec::new();
        for blend in [Blend::Product, Blend::Mask] {
            for &tau in &self.cfg.taus {
                let params = AoParams {
                    tau,
                    blend,
                    ..AoParams::default()
                };
                let f = self.correction.factors(&self.cpu_ao, &self.prep, &params);
                let mut p = self.measure(&self.base(), params, Some(&f))?;
                let (mut mae, mut p95) = (0.0, 0.0);
                for frame in frames {
                    let posed = cpu::skin(&self.prep, &frame.matrices);
                    let v: Vec<f32> = self
                        .cpu_ao
                        .frame(&posed, self.prep.shape, &params, Some(&f))
                        .iter()
                        .map(|v| v.visibility)
                        .collect();
                    let e = ErrorStats::of(&v, &frame.truth);
                    mae += e.mae / frames.len() as f64;
                    p95 += e.p95 / frames.len() as f64;
                }
                p.mae = Some(mae);
                p.p95 = Some(p95);
                counter.add(1);
                progress(&format!(
                    "{blend:?} tau {tau}: {:.3} ms, MAE {mae:.4}",
                    p.total_ms
                ));
                sweep.push(p);
            }
        }
        Ok(sweep)
    }
}

/// The targets of bench/targets.json (`ao` section) against the headline, the tau sweep and
/// the headline's speed-up over its CPU twin (`vs_cpu`, both timed in this run).
fn check_targets(
    t: &serde_json::Value,
    headline: &Point,
    tau_sweep: &[Point],
    vs_cpu: f64,
) -> Vec<TargetCheck> {
    let defaults = AoParams::default();
    let mae_default = tau_sweep
        .iter()
        .find(|p| p.blend == defaults.blend && (p.tau - defaults.tau).abs() < 1e-6)
        .and_then(|p| p.mae)
        .unwrap_or(f64::NAN);
    let check = TargetCheck::of;
    [
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
            headline.gpu_memory_bytes as f64 / (1 << 20) as f64,
            false,
        ),
        check(
            "GPU speed-up over the CPU twin (same run)",
            t["vs_cpu_min"].as_f64(),
            vs_cpu,
            true,
        ),
    ]
    .into_iter()
    .flatten()
    .collect()
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
