//! `vkshade env`: environment light on a moving character. The environment (an HDR map fitted
//! with SG lobes once) turns per frame; each vertex's lobes are shadowed by the character's
//! own sphere tree on the GPU (kernels::env). With `--reference`, every frame is compared with
//! the ray-traced truth (environment x visibility x cosine, rays against the posed mesh) beside
//! the AO-weighted floor, and written as DIR/env_NNNN.ply (posed positions, normals,
//! per-vertex irradiance `r g b`, linear, radiometric).

use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::sg::Lobe;
use crate::gpu::{Context, Recorder};
use crate::kernels::ao::cpu::CpuAo;
use crate::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use crate::kernels::ao::{AoKernel, AoParams, Correction, Prepared as AoPrepared};
use crate::kernels::env::cpu::{self as env_cpu, TruthConfig};
use crate::kernels::env::{
    DEFAULT_TRACE_GRID, EnvKernel, EnvVisibility, PASS_BVH_LEAVES, PASS_BVH_REFIT, PASS_ROTATE,
    PASS_SHADOW, PASS_TRACE,
};
use crate::kernels::pose::{PoseKernel, Prepared as PosePrepared};
use crate::kernels::srbf::fit::{FitConfig, fit};
use crate::scene::Character;
use crate::scene::spheretree::{BuildConfig, SphereTree};
use glam::{Mat3, Mat4, Vec3, Vec4};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a run is made of.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EnvRunConfig {
    /// Skinned character (.glb/.gltf).
    pub mesh: PathBuf,
    /// Animation (`None`: the first that moves).
    pub animation: Option<String>,
    /// Frames, evenly spaced over the animation (t = duration * i / frames).
    pub frames: usize,
    /// The environment (HDR map).
    pub env: PathBuf,
    /// Lobes fitted to it.
    pub lobes: usize,
    /// Width of the map the lobes are fitted to.
    pub fit_width: u32,
    /// Degrees the environment turns about +Y per frame.
    pub rotate_deg: f32,
    /// Rays per vertex of AO's static correction bake (bind pose).
    pub correction_rays: usize,
    /// Compare every frame with the ray-traced truth and write its PLY.
    pub reference: bool,
    /// Rays per vertex of the truth.
    pub rays: usize,
    /// Output folder.
    pub out: PathBuf,
    /// How negative samples of the map (codec ringing) are treated.
    pub hdr: crate::scene::envmap::HdrPolicy,
    /// What turns the caps' split of the light into each lobe's visibility: rays traced
    /// through the posed mesh every frame, `trace_grid`^2 per vertex, correcting each lobe
    /// (`Some`), or AO's visibility as a scale (`None`).
    pub trace_grid: Option<u32>,
}

impl Default for EnvRunConfig {
    fn default() -> Self {
        EnvRunConfig {
            mesh: PathBuf::from("data/bcn_epileptic.glb"),
            animation: Some("Epileptisch".into()),
            frames: 3,
            env: PathBuf::from(crate::kernels::srbf::DEFAULT_ENV),
            lobes: 32,
            fit_width: 128,
            rotate_deg: 40.0,
            correction_rays: 1024,
            reference: false,
            rays: 2048,
            out: PathBuf::from("out/env"),
            hdr: Default::default(),
            trace_grid: Some(DEFAULT_TRACE_GRID),
        }
    }
}

/// The character, its sphere tree, AO's correction and the fitted lobes: everything built once
/// on the CPU.
pub struct EnvScene {
    /// The character.
    pub character: Character,
    /// The animation played (`None`: the rest pose).
    pub animation: Option<String>,
    /// The pose kernel's input.
    pub pose_prep: PosePrepared,
    /// AO's input (mesh and sphere tree).
    pub ao_prep: AoPrepared,
    /// AO's parameters (the defaults, with the static correction).
    pub ao_params: AoParams,
    /// AO's static correction factors.
    pub correction: Vec<f32>,
    /// The fitted lobes (unrotated).
    pub lobes: Vec<Lobe>,
    /// The fit's relative L2 on the map it was fitted to.
    pub fit_rel_l2: f64,
    /// Milliseconds the fit took.
    pub fit_ms: f64,
    /// Milliseconds the tree build and the correction bake took.
    pub setup_ms: f64,
    /// The run's [`EnvRunConfig::trace_grid`].
    pub trace_grid: Option<u32>,
}

impl EnvScene {
    /// Loads the character, builds its sphere tree (AO's defaults), bakes AO's correction,
    /// fits the environment.
    pub fn load(cfg: &EnvRunConfig, progress: &mut dyn FnMut(&str)) -> Result<EnvScene> {
        let t = Instant::now();
        let map = super::load_env(&cfg.env, cfg.hdr, progress)?;
        let small = map.downsampled(cfg.fit_width.min(map.width))?;
        let fitted = fit(
            &small.samples(),
            &FitConfig {
                lobes: cfg.lobes,
                ..FitConfig::default()
            },
        )?;
        let fit_ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "{}: fitted {} lobes on {}x{}, relative L2 {:.3} ({fit_ms:.0} ms)",
            cfg.env.display(),
            fitted.lobes.len(),
            small.width,
            small.height,
            fitted.rel_l2
        ));
        Self::with_lobes(cfg, fitted.lobes, fitted.rel_l2, fit_ms, progress)
    }

    /// As [`EnvScene::load`] with given lobes (no fit).
    pub fn with_lobes(
        cfg: &EnvRunConfig,
        lobes: Vec<Lobe>,
        fit_rel_l2: f64,
        fit_ms: f64,
        progress: &mut dyn FnMut(&str),
    ) -> Result<EnvScene> {
        let t = Instant::now();
        let character = crate::scene::load(&cfg.mesh)?;
        let animation = character
            .pick_animation(cfg.animation.as_deref())?
            .map(|a| a.name.clone());
        let joints = character.rig.joints.len();
        let (tree, _) = SphereTree::build(&character.mesh, &BuildConfig::default())?;
        let ao_prep = AoPrepared::new(&character.mesh, &tree, joints)?;
        let pose_prep = PosePrepared::new(&character.mesh, joints)?;
        let ao_params = AoParams::default();
        let correction = {
            let c = Correction::bake(&character.mesh, cfg.correction_rays);
            let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
            c.factors(&cpu_ao, &ao_prep, &ao_params)
        };
        let setup_ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "{}: {} vertices, {} spheres, animation {}; tree + AO correction ({} rays) {setup_ms:.0} ms",
            cfg.mesh.display(),
            character.mesh.positions.len(),
            tree.spheres.iter().filter(|s| s.used()).count(),
            animation.as_deref().unwrap_or("(rest pose)"),
            cfg.correction_rays
        ));
        Ok(EnvScene {
            character,
            animation,
            pose_prep,
            ao_prep,
            ao_params,
            correction,
            lobes,
            fit_rel_l2,
            fit_ms,
            setup_ms,
            trace_grid: cfg.trace_grid,
        })
    }

    /// The skinning matrices at `frame` of `frames` (evenly spaced over the animation).
    pub fn matrices(&self, frame: usize, frames: usize) -> Result<Vec<Mat4>> {
        let anim = match &self.animation {
            Some(n) => Some(self.character.animation(n)?),
            None => None,
        };
        let t = anim.map(|a| a.duration).unwrap_or(0.0) * frame as f32 / frames.max(1) as f32;
        Ok(self.character.rig.skinning_matrices(anim, t))
    }
}

/// The environment's rotation at `frame`: `deg` degrees per frame about +Y.
pub fn rotation(frame: usize, deg: f32) -> Mat3 {
    crate::geom::sg::rotation(Vec3::Y, deg * frame as f32)
}

/// The three kernels of one character on the GPU, in recording order: pose, AO, environment.
pub struct EnvGpu {
    /// The character's pose.
    pub pose: PoseKernel,
    /// AO on that pose (with the static correction).
    pub ao: AoKernel,
    /// The environment on both.
    pub env: EnvKernel,
}

impl EnvGpu {
    /// Creates the kernels; their uploads are recorded into `rec`.
    pub fn new(rec: &mut Recorder, scene: &EnvScene) -> Result<EnvGpu> {
        let pose = PoseKernel::new(rec, &scene.pose_prep)?;
        let ao = AoKernel::on_pose(rec, &scene.ao_prep, scene.ao_params, &pose)?;
        ao.set_correction(rec, &scene.correction)?;
        let mesh = &scene.character.mesh;
        let visibility = match scene.trace_grid {
            Some(grid) => EnvVisibility::Traced {
                rest: &mesh.positions,
                triangles: &mesh.triangles,
                grid,
            },
            None => EnvVisibility::Ao,
        };
        let env = EnvKernel::with_visibility(rec, &scene.lobes, &pose, &ao, visibility)?;
        Ok(EnvGpu { pose, ao, env })
    }

    /// Records one frame: pose, AO, environment (barriers from the declared accesses).
    pub fn record(&self, rec: &mut Recorder, matrices: &[Mat4], rotation: &Mat3) -> Result<()> {
        self.pose.record(rec, matrices)?;
        self.ao.record(rec, matrices)?;
        self.env.record(rec, rotation)
    }
}

/// One frame of a run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EnvFrameReport {
    /// Frame index.
    pub frame: usize,
    /// Environment rotation about +Y, degrees.
    pub rotation_deg: f32,
    /// GPU ms of `env rotate`.
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub rotate_ms: f64,
    /// GPU ms of `env shadow`.
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub shadow_ms: f64,
    /// GPU ms of the traced visibility (passes `env bvh leaves`, `env bvh refit`,
    /// `env trace`); 0 with AO's visibility, NaN (null) when untimed.
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub trace_ms: f64,
    /// GPU ms of the whole recording (pose, AO, environment); NaN (null) when a pass went
    /// untimed.
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub frame_ms: f64,
    /// Host ms: recording and submitting the frame.
    pub host_ms: f64,
    /// Relative L2 vs the truth of this method (with `--reference`).
    pub rel_l2: Option<f64>,
    /// The same of the AO-weighted floor AO(x) sum_j E_j(n).
    pub floor_rel_l2: Option<f64>,
    /// The same of the unshadowed sum_j E_j(n).
    pub unshadowed_rel_l2: Option<f64>,
    /// The same of the caps' product alone (no AO correction; CPU twin).
    pub caps_only_rel_l2: Option<f64>,
    /// Vertices the truth finds enclosed (E = 0: inside another part of the posed mesh).
    pub enclosed: Option<usize>,
    /// This method's relative L2 over the other vertices.
    pub open_rel_l2: Option<f64>,
    /// The floor's over the same.
    pub open_floor_rel_l2: Option<f64>,
    /// Mean |AO(x) - ray-traced visibility of the posed mesh| (cosine-weighted, unbounded
    /// rays, as many per vertex as the truth's): AO's own error at this pose.
    pub ao_mae: Option<f64>,
    /// With traced visibility: mean |the kernel's traced visibility - the same with the
    /// truth's ray count| (its noise).
    pub traced_mae: Option<f64>,
    /// Relative L2 vs the truth of this method with the ray-traced visibility in place of
    /// AO(x) (CPU twin): what is left is the per-lobe split by the caps alone, so
    /// `rel_l2` minus this is roughly what AO's error costs.
    pub traced_ao_rel_l2: Option<f64>,
    /// With traced visibility: relative L2 vs the truth of the caps' split scaled by the
    /// same rays' escaped fraction (module `env/shadow`'s formula with the rays in place of
    /// AO; CPU twin), i.e. the rays used as one number per vertex instead of per lobe.
    pub traced_scale_rel_l2: Option<f64>,
    /// The PLY written (with `--reference`).
    pub ply: Option<String>,
}

/// A run's report (DIR/report.json).
#[derive(Clone, Debug, serde::Serialize)]
pub struct EnvReport {
    /// The run's settings.
    pub config: EnvRunConfig,
    /// Vertices shaded.
    pub vertices: usize,
    /// Lobes.
    pub lobes: usize,
    /// The fit's relative L2 and time.
    pub fit_rel_l2: f64,
    /// Milliseconds the fit took.
    pub fit_ms: f64,
    /// Per frame.
    pub frames: Vec<EnvFrameReport>,
}

fn v3(v: &[[f32; 4]]) -> Vec<Vec3> {
    v.iter().map(|p| Vec4::from_array(*p).truncate()).collect()
}

/// Runs the kernels over the frames (one at a time); with `cfg.reference`, compares each with
/// the ray-traced truth and writes its PLY.
pub fn run(ctx: &Context, cfg: &EnvRunConfig, progress: &mut dyn FnMut(&str)) -> Result<EnvReport> {
    if cfg.frames == 0 {
        return Err(Error::InvalidArgument("--frames must be at least 1".into()));
    }
    if !cfg.rotate_deg.is_finite() {
        return Err(Error::InvalidArgument(format!(
            "--rotate must be finite, not {}",
            cfg.rotate_deg
        )));
    }
    let max = crate::kernels::env::MAX_LOBES;
    if !(1..=max).contains(&cfg.lobes) {
        return Err(Error::InvalidArgument(format!(
            "--lobes must be in 1..={max}, not {}",
            cfg.lobes
        )));
    }
    if let Some(g) = cfg.trace_grid
        && !(1..=crate::kernels::env::MAX_TRACE_GRID).contains(&g)
    {
        return Err(Error::InvalidArgument(format!(
            "--trace-grid must be 0 (AO's visibility) or 1..={}, not {g}",
            crate::kernels::env::MAX_TRACE_GRID
        )));
    }
    crate::io::outdir::claim(&cfg.out, "env")?;
    let scene = EnvScene::load(cfg, progress)?;
    run_scene(ctx, cfg, &scene, progress)
}

/// [`run`] on a scene already built.
pub fn run_scene(
    ctx: &Context,
    cfg: &EnvRunConfig,
    scene: &EnvScene,
    progress: &mut dyn FnMut(&str),
) -> Result<EnvReport> {
    let mut setup = ctx.recorder("env setup")?;
    let kernels = EnvGpu::new(&mut setup, scene)?;
    setup.submit_and_wait()?;
    // One untimed warm-up frame: drivers may compile pipelines at first use.
    let mut rec = ctx.recorder("env warm-up")?;
    kernels.record(&mut rec, &scene.matrices(0, cfg.frames)?, &Mat3::IDENTITY)?;
    rec.submit_and_wait()?;
    let mesh = &scene.character.mesh;
    let diagonal = {
        let (lo, hi) = mesh.bounds();
        (hi - lo).length()
    };
    let mut frames = Vec::new();
    for frame in 0..cfg.frames {
        let matrices = scene.matrices(frame, cfg.frames)?;
        let r = rotation(frame, cfg.rotate_deg);
        let start = Instant::now();
        let mut rec = ctx.recorder(&format!("env frame {frame}"))?;
        kernels.record(&mut rec, &matrices, &r)?;
        let env_rb = kernels.env.read_back(&mut rec)?;
        let ao_rb = kernels.ao.read_back(&mut rec)?;
        let sph_rb = rec.read_back(kernels.ao.posed_spheres())?;
        let scale_rb = rec.read_back(kernels.env.scale_visibility())?;
        let ext_rb = rec.read_back(kernels.ao.posed_extents())?;
        let submission = rec.submit()?;
        let host_ms = start.elapsed().as_secs_f64() * 1e3;
        let timings = submission.wait()?;
        let out = env_rb.data()?;
        let ao = ao_rb.data()?;
        let mut report = EnvFrameReport {
            frame,
            rotation_deg: cfg.rotate_deg * frame as f32,
            rotate_ms: timings.get(PASS_ROTATE).unwrap_or(f64::NAN),
            shadow_ms: timings.get(PASS_SHADOW).unwrap_or(f64::NAN),
            trace_ms: if kernels.env.traced().is_some() {
                [PASS_BVH_LEAVES, PASS_BVH_REFIT, PASS_TRACE]
                    .iter()
                    .map(|p| timings.get(p).unwrap_or(f64::NAN))
                    .sum()
            } else {
                0.0
            },
            frame_ms: timings.total_ms(),
            host_ms,
            rel_l2: None,
            floor_rel_l2: None,
            unshadowed_rel_l2: None,
            caps_only_rel_l2: None,
            enclosed: None,
            open_rel_l2: None,
            open_floor_rel_l2: None,
            ao_mae: None,
            traced_mae: None,
            traced_ao_rel_l2: None,
            traced_scale_rel_l2: None,
            ply: None,
        };
        if cfg.reference {
            let (positions, normals) = (v3(&ao.positions), v3(&ao.normals));
            let lobes = env_cpu::rotate(&scene.lobes, r);
            let bvh = Bvh::build(&positions, &mesh.triangles);
            let truth = {
                let _p = crate::progress::Progress::start(
                    &format!("frame {frame}: ray-traced truth"),
                    positions.len() as u64,
                );
                env_cpu::ray_traced(
                    &positions,
                    &normals,
                    &bvh,
                    &lobes,
                    &TruthConfig {
                        rays: cfg.rays,
                        offset: 1e-4 * diagonal,
                        seed: 0xe4f1 + frame as u64,
                    },
                )
            };
            let mine: Vec<[f32; 3]> = out
                .shadowed
                .irradiance
                .iter()
                .map(|e| [e[0], e[1], e[2]])
                .collect();
            // The caps' product alone (CPU twin without AO's correction), for comparison.
            let spheres: Vec<Vec4> = sph_rb
                .to_vec::<[f32; 4]>()?
                .iter()
                .map(|s| Vec4::from_array(*s))
                .collect();
            let extents: Vec<f32> = ext_rb.to_vec()?;
            // The caps' split scaled by a visibility (None: the caps' product alone), on the
            // CPU twin.
            let caps_scaled_by = |ao: Option<&[f32]>| -> Vec<[f32; 3]> {
                let out = env_cpu::shadow(
                    &lobes,
                    kernels.env.table(),
                    &env_cpu::ShadowInputs {
                        positions: &positions,
                        normals: &normals,
                        spheres: &spheres,
                        extents: &extents,
                        shape: kernels.ao.tree_shape(),
                        params: kernels.env.ao_params(),
                        ao,
                        rays: None,
                    },
                );
                out.irradiance.iter().map(|e| [e[0], e[1], e[2]]).collect()
            };
            report.caps_only_rel_l2 = Some(env_cpu::relative_l2(&caps_scaled_by(None), &truth));
            // The split alone: the same caps with the posed mesh's ray-traced visibility in
            // place of AO(x).
            let traced_ao = {
                let _p = crate::progress::Progress::start(
                    &format!("frame {frame}: ray-traced AO"),
                    positions.len() as u64,
                );
                let all: Vec<usize> = (0..positions.len()).collect();
                crate::geom::visibility::ambient_visibility(
                    &positions,
                    &normals,
                    &bvh,
                    &all,
                    &crate::geom::visibility::RayConfig {
                        rays: cfg.rays,
                        offset: 1e-4 * diagonal,
                        seed: 0xa0e4 + frame as u64,
                    },
                )
            };
            let mae_to_traced = |a: &[f32]| {
                a.iter()
                    .zip(&traced_ao)
                    .map(|(a, t)| (a - t).abs() as f64)
                    .sum::<f64>()
                    / traced_ao.len().max(1) as f64
            };
            if kernels.env.traced().is_some() {
                let scale = scale_rb.to_vec::<f32>()?;
                report.traced_mae = Some(mae_to_traced(&scale));
                report.traced_scale_rel_l2 =
                    Some(env_cpu::relative_l2(&caps_scaled_by(Some(&scale)), &truth));
            }
            report.ao_mae = Some(mae_to_traced(&ao.visibility));
            report.traced_ao_rel_l2 = Some(env_cpu::relative_l2(
                &caps_scaled_by(Some(&traced_ao)),
                &truth,
            ));
            let e = env_cpu::against_truth(&lobes, &normals, &ao.visibility, &mine, &truth);
            report.enclosed = Some(e.enclosed);
            report.open_rel_l2 = Some(e.open_rel_l2);
            report.open_floor_rel_l2 = Some(e.open_floor_rel_l2);
            report.rel_l2 = Some(e.rel_l2);
            report.floor_rel_l2 = Some(e.floor_rel_l2);
            report.unshadowed_rel_l2 = Some(e.unshadowed_rel_l2);
            let ply = frame_ply(&cfg.out, frame);
            write_truth_ply(
                &ply,
                &format!(
                    "vkshade env: frame {frame}, environment irradiance r g b (linear, radiometric, \
                     no 1/pi); truth_*: ray-traced ({} rays/vertex); ao: AO's visibility",
                    cfg.rays
                ),
                (&positions, &normals, &mesh.triangles),
                &mine,
                &truth,
                &ao.visibility,
            )?;
            report.ply = Some(ply.display().to_string());
        }
        progress(&frame_line(&report));
        frames.push(report);
    }
    let report = EnvReport {
        config: cfg.clone(),
        vertices: mesh.positions.len(),
        lobes: scene.lobes.len(),
        fit_rel_l2: scene.fit_rel_l2,
        fit_ms: scene.fit_ms,
        frames,
    };
    crate::io::write_json(&cfg.out.join("report.json"), &report)?;
    Ok(report)
}

/// A posed mesh (positions, normals, triangles) with a method's environment irradiance
/// (`r g b`), the ray-traced truth's (`truth_r truth_g truth_b`) and AO's visibility (`ao`)
/// per vertex, as `vkshade env --reference` and `vkshade frame --reference` write it.
pub fn write_truth_ply(
    path: &Path,
    comment: &str,
    (positions, normals, triangles): (&[Vec3], &[Vec3], &[[u32; 3]]),
    mine: &[[f32; 3]],
    truth: &[[f64; 3]],
    ao: &[f32],
) -> Result<()> {
    let channel = |c: usize| mine.iter().map(|e| e[c]).collect::<Vec<f32>>();
    let truth_channel = |c: usize| truth.iter().map(|e| e[c] as f32).collect::<Vec<f32>>();
    crate::scene::ply_write::write_ply_properties(
        path,
        comment,
        positions,
        normals,
        triangles,
        &[
            ("r", &channel(0)),
            ("g", &channel(1)),
            ("b", &channel(2)),
            ("truth_r", &truth_channel(0)),
            ("truth_g", &truth_channel(1)),
            ("truth_b", &truth_channel(2)),
            ("ao", ao),
        ],
    )
}

/// DIR/env_NNNN.ply.
pub fn frame_ply(dir: &Path, frame: usize) -> PathBuf {
    dir.join(format!("env_{frame:04}.ply"))
}

fn frame_line(f: &EnvFrameReport) -> String {
    let err = match (f.rel_l2, f.floor_rel_l2, f.unshadowed_rel_l2) {
        (Some(a), Some(b), Some(c)) => format!(
            "; rel L2 vs truth: env shadow {:.2}%, AO floor {:.2}%, unshadowed {:.2}%",
            100.0 * a,
            100.0 * b,
            100.0 * c
        ),
        _ => String::new(),
    };
    format!(
        "frame {}: rotate {:.3} ms, shadow {:.3} ms (frame {:.2} ms GPU, host {:.2} ms){err}",
        f.frame, f.rotate_ms, f.shadow_ms, f.frame_ms, f.host_ms
    )
}

/// `vkshade env` arguments.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Skinned character (.glb/.gltf).
    #[arg(long, default_value = "data/bcn_epileptic.glb")]
    pub mesh: PathBuf,
    /// Animation to play.
    #[arg(long, default_value = "Epileptisch")]
    pub anim: String,
    /// Frames, evenly spaced over the animation.
    #[arg(long, default_value_t = 3)]
    pub frames: usize,
    /// The environment (HDR map).
    #[arg(long, default_value = crate::kernels::srbf::DEFAULT_ENV)]
    pub env: PathBuf,
    /// Lobes fitted to the environment (1..=64).
    #[arg(long, default_value_t = 32)]
    pub lobes: usize,
    /// Degrees the environment turns about +Y per frame.
    #[arg(long, default_value_t = 40.0)]
    pub rotate: f32,
    /// Compare every frame with the ray-traced truth (and the AO-weighted floor) and write
    /// DIR/env_NNNN.ply.
    #[arg(long)]
    pub reference: bool,
    /// Rays per vertex of the truth.
    #[arg(long, default_value_t = 2048)]
    pub rays: usize,
    /// Output folder.
    #[arg(long, default_value = "out/env")]
    pub out: PathBuf,
    /// Rays per vertex and axis that correct the caps' per-lobe split each frame (grid^2
    /// rays through the posed mesh, 1..=16); 0: AO's visibility as a scale instead.
    #[arg(long, default_value_t = DEFAULT_TRACE_GRID)]
    pub trace_grid: u32,
    #[command(flatten)]
    pub hdr: super::Hdr,
}

impl Args {
    /// The run's configuration.
    pub fn config(&self) -> EnvRunConfig {
        EnvRunConfig {
            mesh: self.mesh.clone(),
            animation: Some(self.anim.clone()),
            frames: self.frames,
            env: self.env.clone(),
            lobes: self.lobes,
            rotate_deg: self.rotate,
            reference: self.reference,
            rays: self.rays,
            out: self.out.clone(),
            hdr: self.hdr.policy(),
            trace_grid: (self.trace_grid > 0).then_some(self.trace_grid),
            ..EnvRunConfig::default()
        }
    }

    /// Runs the command and prints the table.
    pub fn run(&self, gpu: &super::Gpu) -> Result<()> {
        let cfg = self.config();
        let ctx = gpu.context()?;
        let report = run(&ctx, &cfg, &mut super::progress)?;
        display(&report);
        super::finish(ctx)
    }
}

/// Prints the per-frame table.
pub fn display(r: &EnvReport) {
    println!(
        "{} vertices x {} lobes (fit rel L2 {:.3}, {:.0} ms); the caps' split {}",
        r.vertices,
        r.lobes,
        r.fit_rel_l2,
        r.fit_ms,
        match r.config.trace_grid {
            Some(g) => format!(
                "corrected per lobe by {} rays per vertex traced through the posed mesh each frame",
                g * g
            ),
            None => "scaled by AO's visibility".into(),
        }
    );
    println!(
        "{:>5} {:>7} {:>10} {:>10} {:>9} {:>9} {:>11} {:>11} {:>9} {:>11} {:>10} {:>9} {:>16} {:>7} {:>10} {:>9} {:>8}",
        "frame",
        "rot deg",
        "rotate ms",
        "shadow ms",
        "frame ms",
        "host ms",
        "env shadow",
        "rays scale",
        "AO floor",
        "caps only",
        "unshadowed",
        "enclosed",
        "open: env/floor",
        "AO MAE",
        "traced AO",
        "trace ms",
        "rays MAE"
    );
    let pct = |x: Option<f64>| {
        x.map(|v| format!("{:.2}%", 100.0 * v))
            .unwrap_or("-".into())
    };
    for f in &r.frames {
        println!(
            "{:>5} {:>7.0} {:>10.3} {:>10.3} {:>9.2} {:>9.2} {:>11} {:>11} {:>9} {:>11} {:>10} {:>9} {:>16} {:>7} {:>10} {:>9.3} {:>8}",
            f.frame,
            f.rotation_deg,
            f.rotate_ms,
            f.shadow_ms,
            f.frame_ms,
            f.host_ms,
            pct(f.rel_l2),
            pct(f.traced_scale_rel_l2),
            pct(f.floor_rel_l2),
            pct(f.caps_only_rel_l2),
            pct(f.unshadowed_rel_l2),
            f.enclosed.map(|n| n.to_string()).unwrap_or("-".into()),
            format!("{}/{}", pct(f.open_rel_l2), pct(f.open_floor_rel_l2)),
            f.ao_mae.map(|m| format!("{m:.4}")).unwrap_or("-".into()),
            pct(f.traced_ao_rel_l2),
            f.trace_ms,
            f.traced_mae
                .map(|m| format!("{m:.4}"))
                .unwrap_or("-".into())
        );
    }
    if r.frames.iter().any(|f| f.ply.is_some()) {
        println!(
            "relative L2 over vertices vs the ray-traced truth ({} rays/vertex); AO MAE: AO vs \
             the posed mesh's ray-traced visibility; rays scale: the caps' split scaled by the \
             kernel's rays' escaped fraction instead of corrected per lobe; traced AO: the \
             caps' split scaled by the truth's visibility (the split's own error); rays MAE: the kernel's traced visibility vs the \
             same; PLYs in {}",
            r.config.rays,
            r.config.out.display()
        );
    }
}

/// `vkshade bench env`: the environment kernel's passes on BCN_Epileptic at its farthest
/// Epileptisch pose (of 8), forest map fitted with 32 lobes, lobe counts 8..64.
pub fn bench(gpu: &super::Gpu, opts: &super::bench::Opts, quick: bool) -> Result<()> {
    use crate::bench::env::{EnvBenchInput, run as bench_run};
    super::bench::check_outputs(opts, false)?;
    let bcfg = opts.config()?;
    let cfg = EnvRunConfig::default();
    let scene = EnvScene::load(&cfg, &mut super::progress)?;
    let ctx = gpu.context()?;
    let report = {
        let mut setup = ctx.recorder("env bench setup")?;
        let kernels = EnvGpu::new(&mut setup, &scene)?;
        setup.submit_and_wait()?;
        let matrices = scene.matrices(3, 8)?;
        let counts: &[usize] = if quick { &[32] } else { &[8, 16, 32, 64] };
        bench_run(
            &ctx,
            &bcfg,
            &EnvBenchInput {
                pose: &kernels.pose,
                ao: &kernels.ao,
                matrices: &matrices,
                lobes: &scene.lobes,
                counts,
                trace: match scene.trace_grid {
                    Some(grid) => EnvVisibility::Traced {
                        rest: &scene.character.mesh.positions,
                        triangles: &scene.character.mesh.triangles,
                        grid,
                    },
                    None => EnvVisibility::Ao,
                },
            },
        )?
    };
    println!(
        "{} vertices; cut {:.1} spheres/vertex, {:.1} caps above the horizon (lookups = caps x lobes)",
        report.vertices, report.cut_per_vertex, report.caps_per_vertex
    );
    println!(
        "{:>5} {:>10} {:>10} {:>11} {:>9} {:>9} {:>12}",
        "lobes", "rotate ms", "shadow ms", "pose+AO ms", "host ms", "CPU ms", "lookups/vtx"
    );
    for r in &report.rows {
        println!(
            "{:>5} {:>10.3} {:>10.3} {:>11.3} {:>9.3} {:>9.1} {:>12.0}",
            r.lobes,
            r.rotate.median,
            r.shadow.median,
            r.pose_ao.median,
            r.host_ms,
            r.cpu_ms,
            r.lookups_per_vertex
        );
    }
    println!("roofline: {}", report.roofline.summary());
    if let Some(t) = &report.trace {
        println!(
            "traced visibility, {} rays x {} vertices through {} triangles: refit + rays {:.3} ms \
             GPU (env trace {:.3} ms, {:.2} Mrays/s), CPU twin {:.1} ms ({:.2}x the GPU)",
            t.grid * t.grid,
            report.vertices,
            t.triangles,
            t.gpu.median,
            t.trace.median,
            t.rays_per_s * 1e-6,
            t.cpu_ms,
            t.cpu_ms / t.gpu.median
        );
    }
    super::bench::write_json(opts, &report)?;
    super::finish(ctx)
}
