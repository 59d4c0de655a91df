//! `vkshade ao`: sphere-tree ambient occlusion over the frames of an animation, with PLY, PNG
//! and EXR output per frame, a JSON report and (optionally) the ray-traced ground truth.

use super::Gpu;
use crate::error::{Error, Result};
use crate::geom::visibility::{RayConfig, ambient_visibility};
use crate::gpu::{Context, Timings};
use crate::kernels::ao::cpu::{self, CpuAo, Posed, VertexAo};
use crate::kernels::ao::fit::{FitConfig, FitSummary, Proxy, fit_tree};
use crate::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use crate::kernels::ao::{
    AoKernel, AoParams, Blend, Correction, Cut, DEFAULT_ANIMATION, DEFAULT_MESH, FixedCut,
    FrameData, Occlusion, PASS_OCCLUSION, PASS_POSE, PASS_SKIN, Prepared, Refine,
};
use crate::kernels::{KernelInfo, run_frames};
use crate::progress::Progress;
use crate::reference::ErrorStats;
use crate::reference::ao::{JumpCount, count_jumps, proxy_visibility, spheres_visibility};
use crate::report::{MachineInfo, Stats};
use crate::scene::spheretree::{BuildConfig, FitReport, SphereTree};
use crate::scene::{self, Animation, Character, Mesh, MeshReport};
use glam::{Mat4, Vec3, Vec4};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Most frames one run writes (each is a PLY and a PNG).
pub const MAX_FRAMES: usize = 100_000;
/// Most rays per vertex for the ground truth and the correction bake.
pub const MAX_RAYS: usize = 1 << 20;

/// Everything `vkshade ao` can be told.
#[derive(Clone, Debug)]
pub struct AoRunConfig {
    pub mesh: PathBuf,
    /// Animation name; `None`: the first animation that moves (static meshes: rest pose).
    pub animation: Option<String>,
    pub frames: usize,
    /// A `.sph` tree to use instead of building one.
    pub tree: Option<PathBuf>,
    pub build: BuildConfig,
    /// Volume spheres as built, or refitted to the mesh (a `.sph` tree is used as it is).
    pub proxy: Proxy,
    /// Sample this many vertices of every frame for the popping count (0: none): the GPU's
    /// result and the ray-traced truth (common random rays) between consecutive frames.
    pub jump_vertices: usize,
    pub params: AoParams,
    /// Rays per vertex of the bind-pose bake of the static correction.
    pub correction_rays: usize,
    /// Compare every frame with the ray-traced mesh.
    pub reference: bool,
    /// Rays per vertex of the ground truth.
    pub rays: usize,
    /// Every n-th vertex enters the error decomposition (which ray-traces sphere unions).
    pub decompose_stride: usize,
    pub out: PathBuf,
    pub image: (u32, u32),
    /// Error at the top of the heat map of the `--reference` pictures.
    pub error_scale: f32,
    /// Frames submitted before the oldest is waited for.
    pub in_flight: usize,
}

impl Default for AoRunConfig {
    fn default() -> Self {
        AoRunConfig {
            mesh: PathBuf::from(DEFAULT_MESH),
            animation: None,
            frames: 8,
            tree: None,
            build: BuildConfig::default(),
            proxy: Proxy::Volume,
            jump_vertices: 0,
            params: AoParams::default(),
            correction_rays: 4096,
            reference: false,
            rays: 4096,
            decompose_stride: 4,
            out: PathBuf::from("out/ao"),
            image: (640, 480),
            error_scale: 0.2,
            in_flight: 2,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct MeshInfo {
    pub path: String,
    pub vertices: usize,
    pub triangles: usize,
    pub skinned: bool,
    pub joints: usize,
    pub validation: MeshReport,
}

#[derive(Clone, Debug, Serialize)]
pub struct TreeInfo {
    /// "built" or the `.sph` path.
    pub source: String,
    pub levels: u32,
    pub branch: u32,
    /// Used spheres per level below the root.
    pub spheres_per_level: Vec<usize>,
    pub spheres_total: usize,
    pub build_ms: f64,
    pub fit: Option<FitReport>,
    /// The refit of the spheres to the mesh (`--proxy fitted`).
    pub proxy_fit: Option<FitSummary>,
}

/// The fixed cut's lists (`--cut fixed`), chosen in the bind pose.
#[derive(Clone, Debug, Serialize)]
pub struct FixedCutInfo {
    /// Slots per vertex (the cap).
    pub slots: u32,
    /// Mean nodes of the bind-pose hard cut per vertex, before the cap.
    pub mean_cut: f64,
    /// Vertices whose bind-pose cut held more nodes than the cap.
    pub truncated: usize,
    /// Mean bind-pose occlusion of the nodes the cap left out.
    pub dropped_occlusion: f64,
    /// Samples per axis of the pairwise overlap table.
    pub overlap_table_size: u32,
}

impl FixedCutInfo {
    fn of(f: &FixedCut) -> FixedCutInfo {
        FixedCutInfo {
            slots: f.slots,
            mean_cut: f.mean_cut,
            truncated: f.truncated,
            dropped_occlusion: f.dropped_occlusion,
            overlap_table_size: crate::kernels::ao::formula::OVERLAP_SIZE,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct CorrectionInfo {
    pub rays: usize,
    pub cap: f32,
    pub bake_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct GpuTimes {
    pub skin_ms: f64,
    pub ao_ms: f64,
    pub total_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct PerVertex {
    pub mean: f64,
    pub max: u32,
}

/// Where the error comes from (mean absolute differences over the decomposition subset).
#[derive(Clone, Debug, Serialize)]
pub struct Decomposition {
    pub vertices: usize,
    pub rays: usize,
    /// |table - exact formula|, same cut and blending.
    pub table: f64,
    /// |blended analytic - exact union of the cut's spheres| (exact formula).
    pub overlap: f64,
    /// |union of the cut - union of all leaf spheres|.
    pub cut: f64,
    /// |union of all leaf spheres - ray-traced mesh|.
    pub proxy: f64,
    /// Per level below the root: |union of that level's spheres - ray-traced mesh| (rays
    /// against the spheres vs rays against the mesh, the same rays).
    pub proxy_per_level: Vec<f64>,
    /// The method without the static correction against the mesh.
    pub method_uncorrected: f64,
    /// The method as configured against the mesh (same subset).
    pub method: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct FrameReference {
    /// The method as configured against the ray-traced mesh, all vertices.
    pub error: ErrorStats,
    /// Over vertices the truth sees at least 5% of the sky (buried geometry excluded).
    pub error_exposed: ErrorStats,
    /// The method without the static correction.
    pub error_uncorrected: ErrorStats,
    /// The bind-pose truth used as if static (what the dynamic method must beat).
    pub error_static_bind_pose: ErrorStats,
    pub decomposition: Option<Decomposition>,
    pub ray_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub index: usize,
    pub time_s: f32,
    pub gpu: GpuTimes,
    /// Host milliseconds the frame cost outside waiting (recording and submitting).
    pub host_ms: f64,
    pub spheres_tested_per_vertex: PerVertex,
    pub spheres_used_per_vertex: PerVertex,
    pub mean_visibility: f64,
    pub reference: Option<FrameReference>,
    pub ply: String,
    pub png: String,
    /// The picture's linear float twin (same pixels; alpha = coverage).
    pub exr: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub frames: usize,
    pub skin_ms_median: f64,
    pub ao_ms_median: f64,
    pub total_ms_median: f64,
    /// Median host milliseconds per frame outside waiting (recording and submitting).
    pub host_ms_median: f64,
    /// 1000 / median(skin + ao).
    pub fps: f64,
    pub spheres_used_per_vertex_mean: f64,
    pub mae_mean: Option<f64>,
    pub rmse_mean: Option<f64>,
    pub p95_mean: Option<f64>,
    pub max_max: Option<f64>,
    pub mae_exposed_mean: Option<f64>,
    pub mae_uncorrected_mean: Option<f64>,
    pub mae_static_bind_pose_mean: Option<f64>,
    /// Popping between consecutive frames (`--jumps`): steps where the GPU's result changed
    /// by more than 0.1 while the ray-traced truth changed by less than 0.02.
    pub jumps: Option<JumpCount>,
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct AoReport {
    pub tool: &'static str,
    pub machine: MachineInfo,
    pub mesh: MeshInfo,
    pub animation: Option<String>,
    pub animation_duration_s: f32,
    pub tree: TreeInfo,
    pub params: AoParams,
    pub table_size: [u32; 2],
    pub correction: Option<CorrectionInfo>,
    /// The fixed cut's lists (`--cut fixed`).
    pub fixed_cut: Option<FixedCutInfo>,
    pub reference_rays: Option<usize>,
    /// Passes with declared accesses, memory, frames in flight.
    pub kernel: KernelInfo,
    pub frames: Vec<FrameReport>,
    pub summary: Summary,
    pub notes: Vec<String>,
}

/// Loads a `.sph` tree (skin weights from the mesh) or builds one.
pub fn tree_for(c: &Character, cfg: &AoRunConfig) -> Result<(SphereTree, TreeInfo)> {
    let t = Instant::now();
    let (tree, source, fit) = match &cfg.tree {
        Some(path) => {
            let mut tree = SphereTree::read_sph(path)?;
            let (lo, hi) = c.mesh.bounds();
            tree.assign_skin(&c.mesh, 0.01 * (hi - lo).length());
            (tree, path.display().to_string(), None)
        }
        None => {
            let (tree, fit) = SphereTree::build(&c.mesh, &cfg.build)?;
            (tree, "built".to_string(), Some(fit))
        }
    };
    let (tree, proxy_fit) = match (cfg.proxy, &cfg.tree) {
        (Proxy::Fitted, None) => {
            let (tree, summary) = fit_tree(&c.mesh, &tree, &FitConfig::default())?;
            (tree, Some(summary))
        }
        _ => (tree, None),
    };
    let spheres_per_level: Vec<usize> = (1..tree.levels).map(|l| tree.used_at(l)).collect();
    let info = TreeInfo {
        source,
        levels: tree.levels,
        branch: tree.branch,
        spheres_total: tree.spheres.iter().filter(|s| s.used()).count(),
        spheres_per_level,
        build_ms: t.elapsed().as_secs_f64() * 1e3,
        fit,
        proxy_fit,
    };
    Ok((tree, info))
}

fn to_vec3(v: &[[f32; 4]]) -> Vec<Vec3> {
    v.iter().map(|p| Vec4::from_array(*p).truncate()).collect()
}

/// Node ranges of the levels below the root of a complete tree.
fn level_ranges(shape: cpu::TreeShape) -> Vec<std::ops::Range<usize>> {
    let b = shape.branch as usize;
    let (mut start, mut width) = (1usize, b);
    let mut out = Vec::new();
    while start < shape.node_count as usize {
        out.push(start..(start + width).min(shape.node_count as usize));
        start += width;
        width *= b;
    }
    out
}

/// Error decomposition on every `stride`-th vertex of a CPU-posed frame.
#[allow(clippy::too_many_arguments)]
fn decompose(
    cpu_ao: &CpuAo,
    prep: &Prepared,
    fixed: Option<&FixedCut>,
    posed: &Posed,
    params: &AoParams,
    correction: Option<&[f32]>,
    truth: &[f32],
    stride: usize,
    rays: usize,
    cfg: &RayConfig,
) -> Decomposition {
    use rayon::prelude::*;
    let subset: Vec<usize> = (0..posed.positions.len()).step_by(stride.max(1)).collect();
    let cfg = RayConfig { rays, ..*cfg };
    let exact = AoParams {
        occlusion: Occlusion::Exact,
        correct: false,
        ..*params
    };
    let plain = AoParams {
        correct: false,
        ..*params
    };
    let first_leaf = prep.shape.first_leaf as usize;
    let rows: Vec<[f32; 6]> = subset
        .par_iter()
        .map(|&i| {
            let (p, n) = (posed.positions[i], posed.normals[i]);
            let vertex = |params: &AoParams| match fixed {
                Some(f) => cpu_ao.fixed_vertex(i, p, n, posed, f, params),
                None => cpu_ao.vertex(p, n, posed, prep.shape, params),
            };
            let with_table = vertex(&plain).visibility;
            let with_exact = vertex(&exact).visibility;
            let mut cut = Vec::new();
            // As for the leaves: a sphere holding the receiver is left out.
            let mut keep = |s: Vec4| {
                if s.truncate().distance(p) > s.w {
                    cut.push(s)
                }
            };
            match fixed {
                Some(f) => f.list(i).for_each(|k| keep(posed.spheres[k as usize])),
                None => {
                    cpu::walk_cut(
                        p,
                        &posed.spheres,
                        &posed.extents,
                        prep.shape,
                        &exact,
                        |_, s, _| keep(s),
                    );
                }
            }
            let union_cut = spheres_visibility(p, n, i, &cut, &cfg);
            let leaves: Vec<Vec4> = posed.spheres[first_leaf..]
                .iter()
                .copied()
                .filter(|s| s.w >= 0.0 && s.truncate().distance(p) > s.w)
                .collect();
            let union_leaves = spheres_visibility(p, n, i, &leaves, &cfg);
            let configured = match correction {
                Some(c) if params.correct => (with_table * c[i]).min(1.0),
                _ => with_table,
            };
            [
                with_table,
                with_exact,
                union_cut,
                union_leaves,
                configured,
                truth[i],
            ]
        })
        .collect();
    let mean = |f: &dyn Fn(&[f32; 6]) -> f32| {
        rows.iter().map(|r| f(r).abs() as f64).sum::<f64>() / rows.len().max(1) as f64
    };
    let shape = prep.shape;
    let proxy_per_level = level_ranges(shape)
        .into_iter()
        .map(|range| {
            let v = proxy_visibility(
                &posed.positions,
                &posed.normals,
                &subset,
                &posed.spheres[range],
                &cfg,
            );
            v.iter()
                .zip(&subset)
                .map(|(v, &i)| (v - truth[i]).abs() as f64)
                .sum::<f64>()
                / subset.len().max(1) as f64
        })
        .collect();
    Decomposition {
        vertices: rows.len(),
        rays: cfg.rays,
        table: mean(&|r| r[0] - r[1]),
        overlap: mean(&|r| r[1] - r[2]),
        cut: mean(&|r| r[2] - r[3]),
        proxy: mean(&|r| r[3] - r[5]),
        proxy_per_level,
        method_uncorrected: mean(&|r| r[0] - r[5]),
        method: mean(&|r| r[4] - r[5]),
    }
}

impl AoRunConfig {
    /// Refuses settings outside their documented ranges, naming the option.
    pub fn validate(&self) -> Result<()> {
        self.params.validate()?;
        if !(1..=16).contains(&self.in_flight) {
            return Err(Error::InvalidArgument(format!(
                "--in-flight must be in 1..=16, not {}",
                self.in_flight
            )));
        }
        if !(1..=MAX_FRAMES).contains(&self.frames) {
            return Err(Error::InvalidArgument(format!(
                "--frames must be in 1..={MAX_FRAMES}, not {}",
                self.frames
            )));
        }
        for (name, rays) in [
            ("--rays", self.rays),
            ("--correction-rays", self.correction_rays),
        ] {
            if !(1..=MAX_RAYS).contains(&rays) {
                return Err(Error::InvalidArgument(format!(
                    "{name} must be in 1..={MAX_RAYS}, not {rays}"
                )));
            }
        }
        if self.image.0 == 0 || self.image.1 == 0 || self.image.0 > 8192 || self.image.1 > 8192 {
            return Err(Error::InvalidArgument(format!(
                "image size {:?} outside 1..=8192",
                self.image
            )));
        }
        if !(self.error_scale.is_finite() && self.error_scale > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "--error-scale must be finite and > 0, not {}",
                self.error_scale
            )));
        }
        Ok(())
    }
}

/// The static correction as baked for this run.
struct Baked {
    bind_visibility: Vec<f32>,
    factors: Vec<f32>,
    info: CorrectionInfo,
}

/// Everything a frame needs, prepared once per run.
struct Session<'a> {
    ctx: &'a Context,
    cfg: &'a AoRunConfig,
    character: &'a Character,
    anim: Option<&'a Animation>,
    prep: Prepared,
    kernel: AoKernel,
    cpu_ao: CpuAo,
    /// The fixed cut's lists (`--cut fixed`; the kernel's own).
    fixed: Option<FixedCut>,
    correction: Option<Baked>,
    /// The bind-pose truth used as if static (the baseline the animated method must beat).
    static_bind: Option<Vec<f32>>,
    /// Points of every frame, so the camera frames the whole animation and pictures line up.
    frame_points: Vec<Vec3>,
    view: crate::render::View,
    ray_cfg: RayConfig,
}

/// What one GPU frame gave back.
struct GpuFrame {
    gpu: GpuTimes,
    host_ms: f64,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    visibility: Vec<f32>,
    stats: Vec<[u32; 2]>,
}

impl GpuFrame {
    fn new(data: FrameData, timings: &Timings, host_ms: f64) -> GpuFrame {
        // Skinning: the vertices (the pose's pass) and the sphere centres.
        let skin_ms =
            timings.get(PASS_POSE).unwrap_or(f64::NAN) + timings.get(PASS_SKIN).unwrap_or(f64::NAN);
        let ao_ms = timings.get(PASS_OCCLUSION).unwrap_or(f64::NAN);
        GpuFrame {
            gpu: GpuTimes {
                skin_ms,
                ao_ms,
                total_ms: skin_ms + ao_ms,
            },
            host_ms,
            positions: to_vec3(&data.positions),
            normals: to_vec3(&data.normals),
            visibility: data.visibility,
            stats: data.stats,
        }
    }
}

/// Runs the kernel over the animation, writing DIR/ao_NNNN.{ply,png,exr} and
/// DIR/report.json. With `cfg.reference`, each picture is result | ray-traced truth | error.
pub fn run(ctx: &Context, cfg: &AoRunConfig, progress: &mut dyn FnMut(&str)) -> Result<AoReport> {
    cfg.validate()?;
    crate::io::outdir::claim(&cfg.out, "ao")?;
    let character = scene::load(&cfg.mesh)?;
    let anim = character.pick_animation(cfg.animation.as_deref())?;
    let mesh = &character.mesh;
    progress(&format!(
        "{}: {} vertices, {} triangles, {} joints{}",
        cfg.mesh.display(),
        mesh.positions.len(),
        mesh.triangles.len(),
        character.rig.joints.len(),
        anim.map(|a| format!(", animation '{}' ({:.2} s)", a.name, a.duration))
            .unwrap_or_default()
    ));
    let (tree, tree_info) = tree_for(&character, cfg)?;
    progress(&format!(
        "sphere tree ({}): {:?} spheres per level, {:.0} ms",
        tree_info.source, tree_info.spheres_per_level, tree_info.build_ms
    ));
    let session = Session::new(ctx, cfg, &character, anim, &tree, progress)?;
    let times = session.frame_times();
    let units = if cfg.reference {
        mesh.positions.len() as u64
    } else {
        1
    };
    let counter = Progress::start(
        if cfg.reference {
            "frames (ray-traced reference)"
        } else {
            "frames"
        },
        times.len() as u64 * units,
    );
    let matrices: Vec<Vec<Mat4>> = times
        .iter()
        .map(|&t| character.rig.skinning_matrices(anim, t))
        .collect();
    let mut frames = Vec::with_capacity(times.len());
    let inputs = matrices.iter().map(Vec::as_slice);
    // On a CPU device (lavapipe) the ray-traced reference of one frame would run on the
    // same cores as the next frame's "GPU" work and time the contention: one at a time.
    let cpu_device = ctx.info().device_type == "CPU";
    let limit = if cfg.reference && cpu_device {
        1
    } else {
        cfg.in_flight
    };
    let sampled: Vec<usize> = if cfg.jump_vertices > 0 {
        let nv = mesh.positions.len();
        (0..nv)
            .step_by(nv.div_ceil(cfg.jump_vertices).max(1))
            .collect()
    } else {
        Vec::new()
    };
    let (mut jump_method, mut jump_truth) = (Vec::new(), Vec::new());
    let in_flight = run_frames(ctx, &session.kernel, inputs, limit, |r| {
        let (index, time) = (r.index, times[r.index]);
        if !sampled.is_empty() {
            jump_method.push(sampled.iter().map(|&i| r.output.visibility[i]).collect());
            jump_truth.push(session.sampled_truth(&matrices[index], &sampled));
        }
        let f = GpuFrame::new(r.output, &r.timings, r.host_ms);
        frames.push(session.frame(index, time, &matrices[index], f, progress)?);
        if !cfg.reference {
            counter.add(1);
        }
        Ok(())
    })?;
    drop(counter);
    let mut report = session.report(tree_info, frames, in_flight);
    if !sampled.is_empty() {
        let jumps = count_jumps(&jump_method, &jump_truth, 0.1, 0.02);
        progress(&format!(
            "popping: {} of {} vertex-steps jumped by more than 0.1 where the truth moved less than 0.02 (largest calm step {:.3})",
            jumps.jumps, jumps.steps, jumps.largest_calm_step
        ));
        report.summary.jumps = Some(jumps);
    }
    crate::io::write_json(&cfg.out.join("report.json"), &report)?;
    Ok(report)
}

impl<'a> Session<'a> {
    /// Uploads the kernel, bakes the correction, frames the camera, warms the pipeline up.
    fn new(
        ctx: &'a Context,
        cfg: &'a AoRunConfig,
        character: &'a Character,
        anim: Option<&'a Animation>,
        tree: &SphereTree,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Session<'a>> {
        let mesh = &character.mesh;
        let prep = Prepared::new(mesh, tree, character.rig.joints.len())?;
        // Construction and the correction record their uploads; one submission runs them.
        let mut setup = ctx.recorder("ao setup")?;
        let kernel = AoKernel::new(&mut setup, &prep, cfg.params)?;
        let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
        let fixed = kernel.fixed_cut().cloned();
        if let Some(f) = &fixed {
            progress(&format!(
                "fixed cut chosen in the bind pose: {:.1} nodes per vertex before the cap of {} ({} vertices truncated)",
                f.mean_cut, f.slots, f.truncated
            ));
        }
        let correction = if cfg.params.correct {
            let baked = bake(cfg, mesh, &cpu_ao, &prep, fixed.as_ref())?;
            kernel.set_correction(&mut setup, &baked.factors)?;
            progress(&format!(
                "static correction baked in the bind pose ({} rays/vertex, {:.0} ms)",
                baked.info.rays, baked.info.bake_ms
            ));
            Some(baked)
        } else {
            None
        };
        setup.submit_and_wait()?;
        let static_bind = match (&correction, cfg.reference) {
            (_, false) => None,
            (Some(b), true) => Some(b.bind_visibility.clone()),
            (None, true) => {
                let _p = Progress::start("bind-pose reference", mesh.positions.len() as u64);
                Some(Correction::bake(mesh, cfg.correction_rays).bind_visibility)
            }
        };
        let diagonal = {
            let (lo, hi) = mesh.bounds();
            (hi - lo).length()
        };
        let mut session = Session {
            ctx,
            cfg,
            character,
            anim,
            prep,
            kernel,
            cpu_ao,
            fixed,
            correction,
            static_bind,
            frame_points: Vec::new(),
            view: crate::render::View {
                width: cfg.image.0,
                height: cfg.image.1,
                ..Default::default()
            },
            ray_cfg: RayConfig {
                rays: cfg.rays,
                ..RayConfig::for_scene(diagonal)
            },
        };
        for t in session.frame_times() {
            let m = character.rig.skinning_matrices(anim, t);
            let posed = cpu::skin(&session.prep, &m);
            session
                .frame_points
                .extend(posed.positions.iter().step_by(7).copied());
        }
        // One untimed warm-up submission: drivers may compile pipelines at first use.
        let m = character.rig.skinning_matrices(anim, 0.0);
        let mut rec = ctx.recorder("ao warm-up")?;
        session.kernel.record(&mut rec, &m)?;
        rec.submit_and_wait()?;
        Ok(session)
    }

    /// Animation times of the frames (one frame, the rest pose, without an animation).
    fn frame_times(&self) -> Vec<f32> {
        let duration = self.anim.map(|a| a.duration).unwrap_or(0.0);
        let frames = if self.anim.is_some() {
            self.cfg.frames
        } else {
            1
        };
        (0..frames)
            .map(|i| duration * i as f32 / frames as f32)
            .collect()
    }

    /// One frame the GPU completed: PLY, optional reference, pictures, a progress line.
    fn frame(
        &self,
        index: usize,
        time: f32,
        matrices: &[Mat4],
        f: GpuFrame,
        progress: &mut dyn FnMut(&str),
    ) -> Result<FrameReport> {
        let cfg = self.cfg;
        let png = frame_png(&cfg.out, index);
        let (ply, exr) = (png.with_extension("ply"), png.with_extension("exr"));
        scene::ply_write::write_ply(
            &ply,
            &format!(
                "vkshade ambient occlusion: {} frame {index} t={time:.4}s; ao = ambient visibility, 1 = unoccluded",
                cfg.mesh.display()
            ),
            &f.positions,
            &f.normals,
            &self.character.mesh.triangles,
            "ao",
            &f.visibility,
        )?;
        let (reference, truth) = match cfg.reference {
            true => {
                let (r, t) = self.reference(matrices, &f.visibility);
                (Some(r), Some(t))
            }
            false => (None, None),
        };
        self.pictures(&png, &exr, &f, truth.as_deref())?;
        let per_vertex = |k: usize| PerVertex {
            mean: f.stats.iter().map(|s| s[k] as f64).sum::<f64>() / f.stats.len() as f64,
            max: f.stats.iter().map(|s| s[k]).max().unwrap_or(0),
        };
        progress(&format!(
            "frame {index} (t = {time:.3} s): skin {:.3} ms + ao {:.3} ms GPU, {:.1} spheres/vertex{}",
            f.gpu.skin_ms,
            f.gpu.ao_ms,
            per_vertex(1).mean,
            reference
                .as_ref()
                .map(|r| format!(
                    ", vs ray-traced mesh: MAE {:.4} p95 {:.3} max {:.3}",
                    r.error.mae, r.error.p95, r.error.max
                ))
                .unwrap_or_default()
        ));
        Ok(FrameReport {
            index,
            time_s: time,
            gpu: f.gpu.clone(),
            host_ms: f.host_ms,
            spheres_tested_per_vertex: per_vertex(0),
            spheres_used_per_vertex: per_vertex(1),
            mean_visibility: f.visibility.iter().map(|&v| v as f64).sum::<f64>()
                / f.visibility.len() as f64,
            reference,
            ply: ply.display().to_string(),
            png: png.display().to_string(),
            exr: exr.display().to_string(),
        })
    }

    /// The ray-traced truth of `receivers` in a frame (CPU skinning; the rays of a receiver
    /// are the same in every frame).
    fn sampled_truth(&self, matrices: &[Mat4], receivers: &[usize]) -> Vec<f32> {
        let posed = cpu::skin(&self.prep, matrices);
        let bvh = crate::geom::Bvh::build(&posed.positions, &self.character.mesh.triangles);
        ambient_visibility(
            &posed.positions,
            &posed.normals,
            &bvh,
            receivers,
            &self.ray_cfg,
        )
    }

    /// The ray-traced truth of a frame (from the CPU's own skinning, independent of the
    /// GPU) and the errors measured against it.
    fn reference(&self, matrices: &[Mat4], visibility: &[f32]) -> (FrameReference, Vec<f32>) {
        let (cfg, prep) = (self.cfg, &self.prep);
        let t = Instant::now();
        let posed = cpu::skin(prep, matrices);
        let bvh = crate::geom::Bvh::build(&posed.positions, &self.character.mesh.triangles);
        let all: Vec<usize> = (0..posed.positions.len()).collect();
        let truth = ambient_visibility(&posed.positions, &posed.normals, &bvh, &all, &self.ray_cfg);
        let ray_ms = t.elapsed().as_secs_f64() * 1e3;
        let exposed: Vec<usize> = (0..truth.len()).filter(|&i| truth[i] >= 0.05).collect();
        let pick = |v: &[f32]| exposed.iter().map(|&i| v[i]).collect::<Vec<f32>>();
        let plain = AoParams {
            correct: false,
            ..cfg.params
        };
        let uncorrected: Vec<f32> = self
            .cpu_frame(&posed, &plain, None)
            .iter()
            .map(|v| v.visibility)
            .collect();
        let decomposition = (cfg.decompose_stride > 0).then(|| {
            decompose(
                &self.cpu_ao,
                prep,
                self.fixed.as_ref(),
                &posed,
                &cfg.params,
                self.correction.as_ref().map(|c| &c.factors[..]),
                &truth,
                cfg.decompose_stride,
                cfg.rays.min(1024),
                &self.ray_cfg,
            )
        });
        let reference = FrameReference {
            error: ErrorStats::of(visibility, &truth),
            error_exposed: ErrorStats::of(&pick(visibility), &pick(&truth)),
            error_uncorrected: ErrorStats::of(&uncorrected, &truth),
            error_static_bind_pose: ErrorStats::of(
                self.static_bind.as_deref().unwrap_or(&[]),
                &truth,
            ),
            decomposition,
            ray_ms,
        };
        (reference, truth)
    }

    /// The CPU twin of the configured cut on a posed frame.
    fn cpu_frame(
        &self,
        posed: &Posed,
        params: &AoParams,
        correction: Option<&[f32]>,
    ) -> Vec<VertexAo> {
        match &self.fixed {
            Some(f) => self.cpu_ao.fixed_frame(posed, f, params, correction),
            None => self
                .cpu_ao
                .frame(posed, self.prep.shape, params, correction),
        }
    }

    /// Writes the frame's PNG and its linear EXR twin: the result alone, or with a truth,
    /// result | truth | error (heat map up to `cfg.error_scale`) at the same camera.
    fn pictures(&self, png: &Path, exr: &Path, f: &GpuFrame, truth: Option<&[f32]>) -> Result<()> {
        use crate::render::{rasterize, shade, side_by_side, side_by_side_linear};
        let tris = &self.character.mesh.triangles;
        let raster =
            |values: &[f32]| rasterize(&f.positions, tris, values, &self.frame_points, &self.view);
        let result = raster(&f.visibility);
        let (picture, linear) = match truth {
            None => (shade(&result), result.to_float()),
            Some(truth) => {
                let error: Vec<f32> = f
                    .visibility
                    .iter()
                    .zip(truth)
                    .map(|(v, t)| (v - t).abs())
                    .collect();
                let (truth, error) = (raster(truth), raster(&error));
                (
                    side_by_side(
                        &shade(&result),
                        &shade(&truth),
                        &error.value,
                        self.cfg.error_scale,
                    )?,
                    side_by_side_linear(&result.to_float(), &truth.to_float(), &error.to_float())?,
                )
            }
        };
        crate::render::write_png(png, picture.width, picture.height, &picture.rgb)?;
        crate::io::exr::write(exr, &linear, crate::io::exr::Channels::Rgba)
    }

    /// The report of the run: inputs, per-frame results and their summary.
    fn report(&self, tree: TreeInfo, frames: Vec<FrameReport>, in_flight: usize) -> AoReport {
        let (cfg, ctx, character) = (self.cfg, self.ctx, self.character);
        let mesh = &character.mesh;
        let mut notes = vec![
            "gpu times are single submissions per frame (timestamps); use `vkshade bench ao` for medians over many".to_string(),
        ];
        if ctx.info().device_type == "CPU" {
            notes.push(
                "the device is a CPU implementation (lavapipe): times measure the CPU, not a GPU"
                    .into(),
            );
            if cfg.reference && cfg.in_flight > 1 {
                notes.push(
                    "with --reference on a CPU device frames ran one at a time, so the CPU ray \
                     tracing did not share the cores with the timed kernel"
                        .into(),
                );
            }
        }
        AoReport {
            tool: "vkshade ao",
            machine: MachineInfo::of(ctx),
            mesh: MeshInfo {
                path: cfg.mesh.display().to_string(),
                vertices: mesh.positions.len(),
                triangles: mesh.triangles.len(),
                skinned: character.skinned,
                joints: character.rig.joints.len(),
                validation: mesh.report.clone(),
            },
            animation: self.anim.map(|a| a.name.clone()),
            animation_duration_s: self.anim.map(|a| a.duration).unwrap_or(0.0),
            tree,
            params: cfg.params,
            table_size: [TABLE_SIZE, TABLE_SIZE],
            correction: self.correction.as_ref().map(|c| c.info.clone()),
            fixed_cut: self.fixed.as_ref().map(FixedCutInfo::of),
            reference_rays: cfg.reference.then_some(cfg.rays),
            kernel: KernelInfo::of(&self.kernel, in_flight),
            summary: summarize(&frames),
            frames,
            notes,
        }
    }
}

/// Bakes the static correction in the bind pose (a terminal shows its progress).
fn bake(
    cfg: &AoRunConfig,
    mesh: &Mesh,
    cpu_ao: &CpuAo,
    prep: &Prepared,
    fixed: Option<&FixedCut>,
) -> Result<Baked> {
    let t = Instant::now();
    let c = {
        let _p = Progress::start("static correction bake", mesh.positions.len() as u64);
        Correction::bake(mesh, cfg.correction_rays)
    };
    let factors = match fixed {
        Some(f) => c.fixed_factors(cpu_ao, prep, f, &cfg.params),
        None => c.factors(cpu_ao, prep, &cfg.params),
    };
    Ok(Baked {
        info: CorrectionInfo {
            rays: cfg.correction_rays,
            cap: c.cap,
            bake_ms: t.elapsed().as_secs_f64() * 1e3,
        },
        bind_visibility: c.bind_visibility,
        factors,
    })
}

/// Medians of the times and means of the errors over the frames.
fn summarize(frames: &[FrameReport]) -> Summary {
    let median = |f: &dyn Fn(&FrameReport) -> f64| {
        let v: Vec<f64> = frames.iter().map(f).collect();
        Stats::of(&v).map(|s| s.median).unwrap_or(f64::NAN)
    };
    let refs: Vec<&FrameReference> = frames.iter().filter_map(|f| f.reference.as_ref()).collect();
    let mean_of = |f: &dyn Fn(&FrameReference) -> f64| {
        (!refs.is_empty()).then(|| refs.iter().map(|r| f(r)).sum::<f64>() / refs.len() as f64)
    };
    let total = median(&|f| f.gpu.total_ms);
    Summary {
        frames: frames.len(),
        skin_ms_median: median(&|f| f.gpu.skin_ms),
        ao_ms_median: median(&|f| f.gpu.ao_ms),
        total_ms_median: total,
        host_ms_median: median(&|f| f.host_ms),
        fps: 1000.0 / total,
        spheres_used_per_vertex_mean: frames
            .iter()
            .map(|f| f.spheres_used_per_vertex.mean)
            .sum::<f64>()
            / frames.len().max(1) as f64,
        mae_mean: mean_of(&|r| r.error.mae),
        rmse_mean: mean_of(&|r| r.error.rmse),
        p95_mean: mean_of(&|r| r.error.p95),
        max_max: (!refs.is_empty()).then(|| refs.iter().map(|r| r.error.max).fold(0.0, f64::max)),
        mae_exposed_mean: mean_of(&|r| r.error_exposed.mae),
        mae_uncorrected_mean: mean_of(&|r| r.error_uncorrected.mae),
        mae_static_bind_pose_mean: mean_of(&|r| r.error_static_bind_pose.mae),
        jumps: None,
    }
}

/// Path of frame `index`'s picture in `dir`.
pub fn frame_png(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("ao_{index:04}.png"))
}

/// The arguments of `vkshade ao` (and, at their defaults plus `--reference`, `vkshade demo`).
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Character (.glb/.gltf with skin and animations) or static mesh (.obj .ply .off).
    #[arg(long, default_value = DEFAULT_MESH)]
    pub mesh: PathBuf,
    /// Animation to play (default: Run for the built-in character, else the first that moves).
    #[arg(long)]
    pub anim: Option<String>,
    /// Frames, evenly spaced over the animation.
    #[arg(long, default_value_t = 8)]
    pub frames: usize,
    /// Use this .sph sphere tree (Dublin toolkit format) instead of building one.
    #[arg(long)]
    pub tree: Option<PathBuf>,
    /// The spheres of a built tree: `volume` (volume-equivalent at cluster centroids) or
    /// `fitted` (refitted to the mesh).
    #[arg(long, default_value = "volume", value_parser = super::choice::<Proxy>("proxy"))]
    pub proxy: Proxy,
    /// Count popping over this many sampled vertices: steps between consecutive frames where
    /// the result jumps by more than 0.1 while the ray-traced truth moves less than 0.02.
    #[arg(long, default_value_t = 0)]
    pub jumps: usize,
    /// The cut: `adaptive` (walked through the skinned tree every frame) or `fixed` (the
    /// published variant: per-vertex lists chosen in the bind pose, pairwise overlap table).
    #[arg(long, default_value = "adaptive", value_parser = super::choice::<Cut>("cut"))]
    pub cut: Cut,
    /// Refine a tree node when size / distance > tau (0 < tau <= 1; smaller = finer cut).
    #[arg(long, default_value_t = 0.8)]
    pub tau: f32,
    /// Blend a node into its children over this fraction of its refinement distance
    /// (0 = the hard cut, which pops when it changes).
    #[arg(long, default_value_t = 0.5)]
    pub band: f32,
    /// A node's size for refinement: `extent` (reach of its skinned leaves) or `radius`.
    #[arg(long, default_value = "extent", value_parser = super::choice::<Refine>("refinement"))]
    pub refine: Refine,
    /// Per-sphere occlusion: `table` (2D lookup) or `exact` (closed form).
    #[arg(long, default_value = "table", value_parser = super::choice::<Occlusion>("occlusion"))]
    pub occlusion: Occlusion,
    /// Overlap handling: `mask` (cone-mask union), `product`, or `sum`.
    #[arg(long, default_value = "mask", value_parser = super::choice::<Blend>("blend"))]
    pub blend: Blend,
    /// The published method alone: no static correction baked in the bind pose.
    #[arg(long)]
    pub no_correction: bool,
    /// A receiver inside a leaf sphere clamps h to 1 instead of leaving that sphere out.
    #[arg(long)]
    pub clamp_inside: bool,
    /// Compare every frame with the ray-traced mesh (MAE, RMSE, p95, max; error decomposition);
    /// pictures become result | truth | error side by side.
    #[arg(long)]
    pub reference: bool,
    /// Error at the top of the heat map in the --reference pictures (larger errors saturate).
    #[arg(long, default_value_t = 0.2)]
    pub error_scale: f32,
    /// Frames submitted before the oldest is waited for (frames in flight).
    #[arg(long, default_value_t = 2)]
    pub in_flight: usize,
    /// Rays per vertex of the ground truth.
    #[arg(long, default_value_t = 4096)]
    pub rays: usize,
    /// Rays per vertex of the bind-pose bake of the static correction.
    #[arg(long, default_value_t = 4096)]
    pub correction_rays: usize,
    #[command(flatten)]
    pub tree_opts: super::scene::TreeOpts,
    /// Output directory.
    #[arg(long, default_value = "out/ao")]
    pub out: PathBuf,
}

impl Args {
    /// The run these arguments describe; refuses a missing built-in character up front.
    pub fn config(&self) -> Result<AoRunConfig> {
        let default_mesh = self.mesh == Path::new(DEFAULT_MESH);
        if default_mesh && !self.mesh.exists() {
            return Err(Error::input(
                &self.mesh,
                "the built-in character is missing: run tools/setup.sh (it converts assimp's Testwuson.X)",
            ));
        }
        Ok(AoRunConfig {
            mesh: self.mesh.clone(),
            animation: self
                .anim
                .clone()
                .or_else(|| default_mesh.then(|| DEFAULT_ANIMATION.to_string())),
            frames: self.frames,
            tree: self.tree.clone(),
            build: self.tree_opts.config(),
            proxy: self.proxy,
            jump_vertices: self.jumps,
            params: AoParams {
                tau: self.tau,
                band: self.band,
                refine: self.refine,
                occlusion: self.occlusion,
                blend: self.blend,
                clamp_inside: self.clamp_inside,
                correct: !self.no_correction,
                cut: self.cut,
            },
            reference: self.reference,
            rays: self.rays,
            correction_rays: self.correction_rays,
            error_scale: self.error_scale,
            in_flight: self.in_flight,
            out: self.out.clone(),
            ..Default::default()
        })
    }

    /// `vkshade ao`: runs the frames and prints the summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        self.command(gpu, false)
    }

    /// The run, its summary, and with `demo` where the first picture is.
    fn command(&self, gpu: &Gpu, demo: bool) -> Result<()> {
        let cfg = self.config()?;
        let ctx = gpu.context()?;
        eprintln!("vkshade ao on {}", ctx.info().name);
        let report = run(&ctx, &cfg, &mut |l| super::progress(l))?;
        display(&report, &cfg);
        if demo {
            println!("pictures: {}", frame_png(&cfg.out, 0).display());
        }
        super::finish(ctx)
    }
}

/// `vkshade demo`: `ao --reference` with every other option at its default.
pub fn demo(gpu: &Gpu) -> Result<()> {
    use clap::{Args as _, FromArgMatches};
    let matches =
        Args::augment_args(clap::Command::new("ao")).get_matches_from(["ao", "--reference"]);
    let args =
        Args::from_arg_matches(&matches).map_err(|e| Error::InvalidArgument(e.to_string()))?;
    args.command(gpu, true)
}

/// The summary `vkshade ao` prints: timings, errors against the truth (with `--reference`)
/// and what was written.
pub fn display(report: &AoReport, cfg: &AoRunConfig) {
    let s = &report.summary;
    if let Some(f) = &report.fixed_cut {
        println!(
            "fixed cut: {} slots per vertex ({:.1} nodes in the bind-pose cut, {} vertices truncated), pairwise overlap table {}^3",
            f.slots, f.mean_cut, f.truncated, f.overlap_table_size
        );
    }
    println!(
        "{} frames of {}: skin {:.3} ms + ao {:.3} ms GPU (median) = {:.0} fps, host {:.3} ms/frame; {:.1} spheres/vertex",
        s.frames,
        report.mesh.path,
        s.skin_ms_median,
        s.ao_ms_median,
        s.fps,
        s.host_ms_median,
        s.spheres_used_per_vertex_mean
    );
    if let Some(j) = &s.jumps {
        println!(
            "popping: {} jumps in {} vertex-steps (> 0.1 where the truth moved < 0.02)",
            j.jumps, j.steps
        );
    }
    if let (Some(mae), Some(p95), Some(max)) = (s.mae_mean, s.p95_mean, s.max_max) {
        println!(
            "vs ray-traced mesh: MAE {mae:.4}, p95 {p95:.3}, max {max:.3} (mean over frames); \
             without the static correction MAE {:.4}; bind-pose AO held static MAE {:.4}",
            s.mae_uncorrected_mean.unwrap_or(f64::NAN),
            s.mae_static_bind_pose_mean.unwrap_or(f64::NAN)
        );
    }
    println!(
        "wrote {} frames (ao_NNNN.ply, ao_NNNN.png, ao_NNNN.exr) and report.json to {}",
        report.frames.len(),
        cfg.out.display()
    );
}
