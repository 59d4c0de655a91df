//! `vkshade sss`: texture-space subsurface diffusion of a mesh. Writes `irradiance.exr`,
//! `diffuse.exr` (texture space, linear float RGB; diffuse alpha = the fraction of the samples
//! not lost) and `transmission.exr` (light through thin parts; alpha = thickness in mm),
//! `render.png` (the mesh lit with subsurface diffusion + transmission | the same irradiance
//! shaded as plain Lambertian with the same total reflectance, same camera), with
//! `--reference` `reference.png` (diffusion alone | brute-force truth | error heat map), and
//! `report.json`. Where the mesh's UVs overlap, the passes run in a unique atlas (those files
//! are in its layout) and `*_mesh_uv.exr` hold the same results in the mesh's own UVs. With
//! `--anim`, every frame runs on the GPU (skinning, texture-space
//! geometry, BVH refit, irradiance, diffusion; the host records and submits) and writes
//! `frame_NNNN/irradiance.exr`, `diffuse.exr` and `posed.obj` (the posed mesh with its atlas
//! UVs, model units) and `frame_NNNN.png` (the posed mesh lit with that frame's diffusion);
//! the report gives GPU ms per pass and host ms per frame, and with
//! `--reference` the brute-force truth at every frame's pose.

use super::Gpu;
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;
use crate::gpu::{Context, Timings};
use crate::io::FloatImage;
use crate::kernels::pose::{PoseKernel, Prepared};
use crate::kernels::sss::Regions;
use crate::kernels::sss::contact::Contact;
use crate::kernels::sss::cpu::{self, DiffusionGeometry, Light, SamplerParams};
use crate::kernels::sss::gpu::{
    PASS_DIFFUSION, PASS_IRRADIANCE, PASS_IRRADIANCE_RAYS, PASS_VERTEX,
};
use crate::kernels::sss::posed;
use crate::kernels::sss::profile::DEFAULT_ENERGY;
use crate::kernels::sss::{
    Material, PosedBuffers, Profile, ProfileKind, SssKernel, SssOutput, TexGeometry,
};
use crate::kernels::{Kernel, KernelInfo, run_frames};
use crate::reference::sss::{ChannelError, Sources, brute_force, brute_force_where};
use crate::render::ValueImage;
use crate::report::MachineInfo;
use crate::scene::texspace::{COVERED, TexReport};
use crate::scene::{Animation, Character, Mesh};
use glam::{DVec3, Vec2, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use crate::kernels::sss::{
    DEFAULT_MESH, DEFAULT_MESH_MM_PER_UNIT, DEFAULT_PART, default_mm_per_unit, load_character,
    load_mesh,
};

/// Everything `vkshade sss` can be told.
#[derive(Clone, Debug)]
pub struct SssConfig {
    pub mesh: PathBuf,
    /// A glTF mesh (node or mesh name) to use alone, e.g. `Head`.
    pub part: Option<String>,
    pub mm_per_unit: f64,
    /// `dir:X,Y,Z[:E]` or `point:X,Y,Z:I` (see [`Light::parse`]).
    pub lights: Vec<String>,
    pub profile: ProfileKind,
    pub material: Material,
    /// Fraction of each channel's reflectance inside its sampling radius.
    pub energy: f64,
    pub samples: u32,
    /// Shadow rays per texel where a triangle's corners disagree (else interpolated).
    pub shadow_refine: bool,
    pub size: u32,
    /// With `anim`: frames spread over the animation (the mesh is posed and re-rasterised
    /// for each); without: the same frame repeated (timing).
    pub frames: usize,
    /// An animation of the mesh's skeleton (glTF); `None`: the rest pose.
    pub anim: Option<String>,
    pub reference: bool,
    pub out: PathBuf,
    pub image: (u32, u32),
    /// Relative error at the top of the heat map.
    pub error_scale: f32,
}

impl Default for SssConfig {
    fn default() -> Self {
        SssConfig {
            mesh: PathBuf::from(DEFAULT_MESH),
            part: Some(DEFAULT_PART.into()),
            mm_per_unit: DEFAULT_MESH_MM_PER_UNIT,
            lights: vec!["dir:0.3,0.4,1".into()],
            profile: ProfileKind::Dipole,
            material: Material::SKIN1,
            energy: DEFAULT_ENERGY,
            samples: 32,
            shadow_refine: true,
            size: 512,
            frames: 1,
            anim: None,
            reference: false,
            out: PathBuf::from("out/sss"),
            image: (480, 480),
            error_scale: 0.1,
        }
    }
}

impl SssConfig {
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidArgument(m));
        if ![256, 512, 1024, 2048].contains(&self.size) && !(16..=4096).contains(&self.size) {
            return bad(format!("--size {} must be in 16..=4096", self.size));
        }
        if !(1..=4096).contains(&self.samples) {
            return bad(format!(
                "--samples must be in 1..=4096, not {}",
                self.samples
            ));
        }
        if !(1..=10_000).contains(&self.frames) {
            return bad(format!(
                "--frames must be in 1..=10000, not {}",
                self.frames
            ));
        }
        if !(self.mm_per_unit.is_finite() && self.mm_per_unit > 0.0) {
            return bad(format!(
                "--mm-per-unit must be > 0, not {}",
                self.mm_per_unit
            ));
        }
        if self.lights.is_empty() {
            return bad("give at least one --light".into());
        }
        if !(self.error_scale.is_finite() && self.error_scale > 0.0) {
            return bad(format!(
                "--error-scale must be > 0, not {}",
                self.error_scale
            ));
        }
        self.material.check()
    }

    pub fn parsed_lights(&self) -> Result<Vec<Light>> {
        let lights = self
            .lights
            .iter()
            .map(|s| Light::parse(s, self.mm_per_unit as f32))
            .collect::<Result<Vec<_>>>()?;
        cpu::check_lights(&lights)?;
        Ok(lights)
    }
}

/// GPU against CPU twin, per channel: max |gpu - cpu| / max cpu, and the fraction of
/// texels differing by more than 1e-4 of the channel's maximum.
#[derive(Clone, Debug, Serialize)]
pub struct TwinError {
    pub irradiance_max_rel: f64,
    pub irradiance_texels_differing: f64,
    pub diffuse_max_rel: [f64; 3],
    pub diffuse_rel_rmse: [f64; 3],
    pub diffuse_texels_differing: f64,
    /// Transmission: max |gpu - cpu| / max cpu over channels, and the fraction of texels
    /// whose thickness ray found a different back surface.
    pub transmission_max_rel: f64,
    pub transmission_texels_differing: f64,
}

impl TwinError {
    pub fn of(
        geo: &TexGeometry,
        gpu: &SssOutput,
        e: &[[f32; 4]],
        b: &[[f32; 4]],
        t: &[[f32; 4]],
    ) -> TwinError {
        let valid: Vec<usize> = (0..geo.texels()).filter(|&i| geo.pos[i][3] > 0.0).collect();
        let n = valid.len().max(1) as f64;
        let emax = valid
            .iter()
            .map(|&i| e[i][0])
            .fold(0f32, f32::max)
            .max(1e-30) as f64;
        let mut e_worst = 0f64;
        let mut e_diff = 0usize;
        for &i in &valid {
            let d = (gpu.irradiance[i][0] - e[i][0]).abs() as f64 / emax;
            e_worst = e_worst.max(d);
            e_diff += (d > 1e-4) as usize;
        }
        let mut worst = [0f64; 3];
        let mut rmse = [0f64; 3];
        let mut b_diff = 0usize;
        for c in 0..3 {
            let bmax = valid
                .iter()
                .map(|&i| b[i][c])
                .fold(0f32, f32::max)
                .max(1e-30) as f64;
            let (mut d2, mut t2) = (0f64, 0f64);
            for &i in &valid {
                let d = (gpu.diffuse[i][c] - b[i][c]).abs() as f64;
                worst[c] = worst[c].max(d / bmax);
                d2 += d * d;
                t2 += (b[i][c] as f64).powi(2);
            }
            rmse[c] = if t2 > 0.0 { (d2 / t2).sqrt() } else { 0.0 };
        }
        for &i in &valid {
            let differs = (0..3)
                .any(|c| (gpu.diffuse[i][c] - b[i][c]).abs() > 1e-4 * b[i][c].abs().max(1e-6));
            b_diff += differs as usize;
        }
        let tmax = valid
            .iter()
            .map(|&i| t[i][0].max(t[i][1]).max(t[i][2]))
            .fold(0f32, f32::max)
            .max(1e-30) as f64;
        let mut t_worst = 0f64;
        let mut t_diff = 0usize;
        for &i in &valid {
            for (g, c) in gpu.transmission[i].iter().zip(&t[i]).take(3) {
                t_worst = t_worst.max((g - c).abs() as f64 / tmax);
            }
            t_diff +=
                ((gpu.transmission[i][3] - t[i][3]).abs() > 1e-3 * t[i][3].max(1e-3)) as usize;
        }
        TwinError {
            transmission_max_rel: t_worst,
            transmission_texels_differing: t_diff as f64 / n,
            irradiance_max_rel: e_worst,
            irradiance_texels_differing: e_diff as f64 / n,
            diffuse_max_rel: worst,
            diffuse_rel_rmse: rmse,
            diffuse_texels_differing: b_diff as f64 / n,
        }
    }
}

/// The method against the brute-force ground truth, split by where the error comes from.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceReport {
    pub sources: usize,
    pub ms: f64,
    /// Every covered texel.
    pub all: ChannelError,
    /// Texels none of whose samples leaves their triangle through a seam or an open edge.
    pub interior: ChannelError,
    /// Texels some of whose samples leave their triangle through a seam (the surface goes on
    /// elsewhere in the atlas) or an open edge (no surface).
    pub seam: ChannelError,
    /// Share of the covered texels in `seam`.
    pub seam_texels: f64,
    /// 1 - K(R)/R_tot per channel: the reflectance beyond the sampling radius. The sampler
    /// scales by R_tot (the tail taken at the sampled mean), so on a uniformly lit surface
    /// truncation costs nothing; elsewhere the tail sees other light than the disc.
    pub truncation: [f64; 3],
    /// Share of the truth's (area-weighted) energy that comes from other pieces of the mesh
    /// (eyeballs, the inside of the mouth: separate connected pieces that touch the skin).
    pub contact_share: [f64; 3],
    /// The largest share of one texel's truth from other pieces (texels whose truth is at
    /// least 1e-3 of the largest).
    pub contact_max_share: [f64; 3],
    /// The method without its contact term against the truth from the receiver's own piece.
    pub own_piece: ChannelError,
    /// The contact term against the truth from the other pieces, over the texels that have
    /// contact entries (relative to the whole truth there).
    pub contact: ChannelError,
}

/// What the per-vertex shadowing changes against a shadow ray per texel (CPU, same lights):
/// area-weighted relative RMSE over covered texels of E, and of B from the CPU twin of the
/// diffusion fed with each.
#[derive(Clone, Debug, Serialize)]
pub struct ShadowingReport {
    pub method: &'static str,
    pub irradiance_rel_rmse: f64,
    pub diffuse_rel_rmse: [f64; 3],
    pub diffuse_energy_ratio: [f64; 3],
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct SssReport {
    pub tool: &'static str,
    pub machine: MachineInfo,
    pub mesh: String,
    pub part: Option<String>,
    pub anim: Option<String>,
    pub mm_per_unit: f64,
    pub lights: Vec<String>,
    pub profile: Profile,
    pub sampler: SamplerParams,
    /// Samples per texel (shared by the three channels).
    pub samples: u32,
    pub size: u32,
    pub texture: TexReport,
    pub kernel: KernelInfo,
    pub gpu_ms_irradiance: f64,
    pub gpu_ms_diffusion: f64,
    pub fps: f64,
    /// GPU ms per pass and host ms per frame (with --anim: the per-frame geometry passes
    /// included).
    pub frame_cost: FrameCost,
    /// With --anim: the contact entries of the rest pose reused at the last frame's pose.
    pub contact_reuse: Option<ContactReuse>,
    /// With --anim: the refitted BVH at the last frame's pose.
    pub bvh: Option<BvhQuality>,
    /// With --anim and --reference: the brute-force truth at every frame's pose.
    pub reference_poses: Vec<PoseReference>,
    /// Mean fraction of the samples not lost (a non-manifold edge, outside the texture or no
    /// surface where one lands) over covered texels.
    pub accepted_fraction: f64,
    pub gpu_vs_cpu: TwinError,
    pub shadowing: ShadowingReport,
    pub cpu_ms_irradiance: f64,
    pub cpu_ms_diffusion: f64,
    pub reference: Option<ReferenceReport>,
    pub files: Vec<String>,
    pub notes: Vec<String>,
}

/// Runs `vkshade sss`.
pub fn run(ctx: &Context, cfg: &SssConfig, progress: &mut dyn FnMut(&str)) -> Result<SssReport> {
    cfg.validate()?;
    crate::io::outdir::claim(&cfg.out, "sss")?;
    let lights = cfg.parsed_lights()?;
    let character = load_character(&cfg.mesh, cfg.part.as_deref())?;
    let anim = match &cfg.anim {
        Some(name) => Some(character.animation(name)?),
        None => None,
    };
    let scale_warning = scale_warning(cfg, &character.mesh);
    if let Some(w) = &scale_warning {
        progress(&format!("warning: {w}"));
    }
    let mut session = Session::new(ctx, cfg, &character, anim, lights, progress)?;
    let frames = session.frames(progress)?;
    let twin = session.cpu_twin(&frames.gpu, progress);
    let contact_reuse = session.contact_reuse(&frames.gpu, &twin.dg, progress);
    let bvh = session.bvh_quality();
    if let Some(b) = &bvh {
        progress(&format!(
            "BVH refit ({} levels): SAH cost {:.1}, a tree built for the pose {:.1}",
            b.levels, b.sah_refitted, b.sah_built_for_pose
        ));
    }
    let covered = session.covered();
    let mut files = session.write_textures(&frames.gpu)?;
    let (reference, truth) = match cfg.reference {
        true => {
            let (r, t) = session.reference(&frames.gpu, &twin.dg, &covered, progress);
            (Some(r), Some(t))
        }
        false => (None, None),
    };
    files.extend(pictures(
        cfg,
        &session.geo,
        &session.profile,
        &frames.gpu,
        truth.as_deref(),
    )?);
    let notes = session.notes(scale_warning);
    let mut report = session.report(frames, twin, &covered, reference, files, notes);
    report.contact_reuse = contact_reuse;
    report.bvh = bvh;
    report.reference_poses = session.pose_references(progress)?;
    crate::io::write_json(&cfg.out.join("report.json"), &report)?;
    Ok(report)
}

/// A scale that makes the mesh smaller than a fingertip or larger than a room is almost
/// always a units mistake (the coefficients are per mm): the warning saying so, if it is.
fn scale_warning(cfg: &SssConfig, mesh: &Mesh) -> Option<String> {
    let (lo, hi) = mesh
        .positions
        .iter()
        .fold(None, |acc: Option<(Vec3, Vec3)>, p| {
            Some(acc.map_or((*p, *p), |(lo, hi)| (lo.min(*p), hi.max(*p))))
        })?;
    let extent_mm = (hi - lo).length() as f64 * cfg.mm_per_unit;
    (!(10.0..=10_000.0).contains(&extent_mm)).then(|| {
        format!(
            "{} is {extent_mm:.3} mm across at --mm-per-unit {}: scattering lengths are \
             in mm, so the result is unlikely to mean anything; check the model's units",
            cfg.mesh.display(),
            cfg.mm_per_unit
        )
    })
}

/// The texture-space geometry, the profile and the kernel of a run.
struct Session<'a> {
    ctx: &'a Context,
    cfg: &'a SssConfig,
    character: &'a Character,
    anim: Option<&'a Animation>,
    lights: Vec<Light>,
    /// The geometry of the last frame run (the rest pose, or the last pose of `anim`).
    geo: TexGeometry,
    profile: Profile,
    /// `profile` over the whole mesh, as the CPU twin takes it (built once).
    regions: Regions,
    params: SamplerParams,
    kernel: SssKernel,
    /// With --anim: the rest pose's texture-space geometry (the kernel's UV layout) and the
    /// contact entries the kernel reuses in every pose (built once, for the rest pose).
    rest: Option<(TexGeometry, Contact)>,
    /// With --anim: the skinning pass whose posed buffers the kernel reads.
    pose: Option<PoseKernel>,
    /// With --anim and --reference: each frame's time, posed mesh (the GPU's pose) and
    /// outputs, for the brute-force truth at every pose.
    kept: Vec<(f32, Mesh, SssOutput)>,
}

/// The GPU path against the brute-force truth at one pose of the animation (every 3rd
/// covered texel of the pose's CPU rasterisation as a receiver, every covered texel as a
/// source, the GPU's irradiance).
#[derive(Clone, Debug, Serialize)]
pub struct PoseReference {
    pub time: f32,
    /// How far the vertices moved from the rest pose (mm).
    pub moved_mm: f64,
    pub error: ChannelError,
    pub ms: f64,
}

/// Host milliseconds of a frame outside waiting, and the GPU ms of every pass.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameCost {
    /// Median GPU ms per pass, in recording order.
    pub gpu_ms_per_pass: Vec<(String, f64)>,
    /// Median GPU ms of the whole frame (every pass).
    pub gpu_ms_total: f64,
    /// Median host ms per frame spent recording and submitting (command recording, the
    /// lights' and push constants' bytes), excluding the waits.
    pub host_ms_per_frame: f64,
    /// Median host ms per frame evaluating the animation into joint matrices (the rig on
    /// the CPU: per joint, not per vertex; not in host_ms_per_frame).
    pub host_ms_animation: f64,
}

/// What reusing the rest pose's contact entries in a posed frame costs, against entries
/// built for that pose (the CPU twin's diffusion of the GPU irradiance with each): relative
/// RMSE of B per channel over covered texels (area-weighted), the largest relative difference
/// of B at one texel (texels with B at least 1e-3 of the largest), and the build time the
/// reuse saves per frame.
#[derive(Clone, Debug, Serialize)]
pub struct ContactReuse {
    pub diffuse_rel_rmse: [f64; 3],
    pub diffuse_energy_ratio: [f64; 3],
    pub diffuse_max_rel: [f64; 3],
    pub build_ms_per_pose: f64,
}

/// The refitted BVH's quality at the last frame: the SAH-like cost (geom::bvh::sah_cost) of the
/// rest pose's topology refitted, and of a tree built for the pose.
#[derive(Clone, Debug, Serialize)]
pub struct BvhQuality {
    pub levels: usize,
    pub sah_refitted: f64,
    pub sah_built_for_pose: f64,
}

/// What the frames gave: the last frame's outputs and the median pass times.
struct Frames {
    gpu: SssOutput,
    /// Median GPU ms of the vertex and irradiance passes, and of the diffusion pass.
    ms_irradiance: f64,
    ms_diffusion: f64,
    in_flight: usize,
    cost: FrameCost,
}

/// The CPU twin of both passes on the last frame's geometry, and what the per-vertex
/// shadowing changes.
struct CpuTwin {
    /// The walk maps and contact sums of the last pose, built once for every CPU diffusion
    /// (the kernel built its own with the geometry upload).
    dg: DiffusionGeometry,
    error: TwinError,
    shadowing: ShadowingReport,
    ms_irradiance: f64,
    ms_diffusion: f64,
}

/// The GPU times of a frame: (vertex + irradiance passes (with the texels' rays, when
/// refined), diffusion pass).
fn pass_times(timings: &Timings) -> (f64, f64) {
    (
        timings.get(PASS_VERTEX).unwrap_or(f64::NAN)
            + timings.get(PASS_IRRADIANCE).unwrap_or(f64::NAN)
            + timings.get(PASS_IRRADIANCE_RAYS).unwrap_or(0.0),
        timings.get(PASS_DIFFUSION).unwrap_or(f64::NAN),
    )
}

impl<'a> Session<'a> {
    /// Rasterises the texture-space geometry, tabulates the profile and uploads the kernel.
    fn new(
        ctx: &'a Context,
        cfg: &'a SssConfig,
        character: &'a Character,
        anim: Option<&'a Animation>,
        lights: Vec<Light>,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Session<'a>> {
        let mesh = &character.mesh;
        let t = Instant::now();
        let geo = TexGeometry::build(mesh, cfg.size, cfg.mm_per_unit)?;
        let r = &geo.report;
        progress(&format!(
            "{}: {} triangles, {:.0} mm^2; {}^2 texture: {} charts ({} mirrored), {} overlapping \
             texels -> {} layer(s), {} covered + {} gutter texels ({:.0} ms)",
            mesh.name,
            r.triangles,
            r.mesh_area_mm2,
            cfg.size,
            r.charts,
            r.mirrored_charts,
            r.overlapping_texels,
            r.layers,
            r.covered_texels,
            r.gutter_texels,
            t.elapsed().as_secs_f64() * 1e3
        ));
        let profile = Profile::new(cfg.profile, cfg.material, cfg.energy)?;
        progress(&format!(
            "{:?} {} (eta {}): R_tot {:.4?}, radius {:.2?} mm, K(R) {:.4?}",
            cfg.profile,
            cfg.material.name,
            cfg.material.eta,
            profile.r_tot,
            profile.radius,
            profile.k
        ));
        let params = SamplerParams {
            samples: cfg.samples,
            shadow_refine: cfg.shadow_refine,
            ..SamplerParams::default()
        };
        let mut setup = ctx.recorder("sss setup")?;
        let (kernel, rest, pose) = match anim {
            None => (
                SssKernel::new(&mut setup, &geo, &profile, params)?,
                None,
                None,
            ),
            Some(_) => {
                let prep = Prepared::new(mesh, character.rig.joints.len())?;
                let pose = PoseKernel::new(&mut setup, &prep)?;
                let src = PosedBuffers {
                    positions: pose.positions(),
                    normals: pose.normals(),
                    mm_per_unit: cfg.mm_per_unit as f32,
                };
                let k =
                    SssKernel::new_posed(&mut setup, &geo, &mesh.positions, &profile, params, src)?;
                let contact = Contact::build(&geo, &Regions::from(&profile));
                (k, Some((geo.clone(), contact)), Some(pose))
            }
        };
        setup.submit_and_wait()?;
        Ok(Session {
            rest,
            pose,
            kept: Vec::new(),
            ctx,
            cfg,
            character,
            anim,
            lights,
            geo,
            regions: Regions::from(&profile),
            profile,
            params,
            kernel,
        })
    }

    /// Runs the frames (repeated, or over the animation) and takes the medians of their
    /// times.
    fn frames(&mut self, progress: &mut dyn FnMut(&str)) -> Result<Frames> {
        let mut times: Vec<(f64, f64)> = Vec::new();
        let mut cost = FrameCost::default();
        let (last, in_flight) = match self.anim {
            None => self.repeated_frames(&mut times)?,
            Some(a) => self.animated_frames(a, &mut times, &mut cost, progress)?,
        };
        let gpu = last.ok_or_else(|| Error::InvalidArgument("no frame ran".into()))?;
        let median = |f: &dyn Fn(&(f64, f64)) -> f64| {
            let mut v: Vec<f64> = times.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (ms_e, ms_b) = (median(&|t| t.0), median(&|t| t.1));
        progress(&format!(
            "GPU: irradiance {ms_e:.2} ms + diffusion {ms_b:.2} ms ({:.1} fps)",
            1000.0 / (ms_e + ms_b)
        ));
        if cost.gpu_ms_per_pass.is_empty() {
            cost.gpu_ms_total = ms_e + ms_b;
        }
        Ok(Frames {
            gpu,
            ms_irradiance: ms_e,
            ms_diffusion: ms_b,
            in_flight,
            cost,
        })
    }

    /// The same frame `cfg.frames` times, two in flight: the last one's outputs.
    fn repeated_frames(&self, times: &mut Vec<(f64, f64)>) -> Result<(Option<SssOutput>, usize)> {
        let mut last = None;
        let inputs: Vec<&[Light]> = vec![&self.lights[..]; self.cfg.frames];
        let in_flight = run_frames(self.ctx, &self.kernel, inputs, 2, |r| {
            times.push(pass_times(&r.timings));
            last = Some(r.output);
            Ok(())
        })?;
        Ok((last, in_flight))
    }

    /// Each frame on the GPU path: the skinning pass (`kernels::pose`), then the kernel's
    /// frame: vertex frames, walk records, texel geometry and the BVH refit from the posed
    /// buffers, lights, irradiance, diffusion. The host evaluates the joint matrices,
    /// records and submits; host ms is recording and submitting, not waiting. Each frame's
    /// irradiance.exr, diffuse.exr and posed mesh (OBJ) go to frame_NNNN/ (read back after
    /// the frame). The CPU geometry of the last pose is built afterwards (for the twin and
    /// the reference).
    fn animated_frames(
        &mut self,
        a: &Animation,
        times: &mut Vec<(f64, f64)>,
        cost: &mut FrameCost,
        progress: &mut dyn FnMut(&str),
    ) -> Result<(Option<SssOutput>, usize)> {
        let cfg = self.cfg;
        let pose = self
            .pose
            .as_ref()
            .ok_or_else(|| Error::InvalidArgument("--anim without a pose kernel".into()))?;
        let mut last = None;
        let mut last_posed = None;
        let mut per_pass: Vec<(String, Vec<f64>)> = Vec::new();
        let (mut host, mut animation, mut total) = (vec![], vec![], vec![]);
        for f in 0..cfg.frames {
            // Frames spread over the animation, at the middles of N equal spans.
            let time = a.duration * (f as f32 + 0.5) / cfg.frames as f32;
            let t = Instant::now();
            let m = self.character.rig.skinning_matrices(Some(a), time);
            animation.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let mut rec = self.ctx.recorder(&format!("sss frame {f}"))?;
            pose.record(&mut rec, &m)?;
            self.kernel.record(&mut rec, &self.lights[..])?;
            let rb = self.kernel.read_back(&mut rec)?;
            let submission = rec.submit()?;
            host.push(t.elapsed().as_secs_f64() * 1e3);
            let timings = submission.wait()?;
            times.push(pass_times(&timings));
            total.push(timings.passes.iter().map(|p| p.ms).sum::<f64>());
            for p in &timings.passes {
                match per_pass.iter_mut().find(|(n, _)| *n == p.name) {
                    Some((_, v)) => v.push(p.ms),
                    None => per_pass.push((p.name.to_string(), vec![p.ms])),
                }
            }
            let out = self.kernel.collect(&rb)?;
            let posed = self.write_frame(f, &out, pose)?;
            let moved = posed
                .positions
                .iter()
                .zip(&self.character.mesh.positions)
                .map(|(p, q)| (*p - *q).length() as f64)
                .fold(0f64, f64::max);
            progress(&format!(
                "frame {f} ({} at {time:.2} s): vertices moved up to {:.1} mm; GPU {:.2} ms, \
                 host {:.3} ms",
                a.name,
                moved * cfg.mm_per_unit,
                total.last().copied().unwrap_or(f64::NAN),
                host.last().copied().unwrap_or(f64::NAN)
            ));
            if cfg.reference {
                self.kept.push((time, posed.clone(), out.clone()));
            }
            last = Some(out);
            last_posed = Some(posed);
        }
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
        };
        cost.gpu_ms_per_pass = per_pass.into_iter().map(|(n, v)| (n, median(v))).collect();
        cost.gpu_ms_total = median(total);
        cost.host_ms_per_frame = median(host);
        cost.host_ms_animation = median(animation);
        // The CPU twin's geometry: the GPU's own pose of the last frame, rasterised.
        if let Some(posed) = last_posed {
            self.geo = TexGeometry::build(&posed, cfg.size, cfg.mm_per_unit)?;
        }
        Ok((last, 1))
    }

    /// frame_NNNN/: irradiance.exr, diffuse.exr and the posed mesh the GPU used (read back
    /// from the skinning pass's buffers after the frame; OBJ, model units, atlas UVs per
    /// corner). Returns that posed mesh (seam copies welded, as the kernel welds them).
    fn write_frame(&self, f: usize, out: &SssOutput, pose: &PoseKernel) -> Result<Mesh> {
        let dir = self.cfg.out.join(format!("frame_{f:04}"));
        let texture = |v: &[[f32; 4]]| FloatImage {
            width: self.geo.size,
            height: self.geo.size,
            pixels: v.to_vec(),
        };
        for (name, data) in [
            ("irradiance.exr", &out.irradiance),
            ("diffuse.exr", &out.diffuse),
        ] {
            crate::io::exr::write(
                &dir.join(name),
                &texture(data),
                crate::io::exr::Channels::Rgba,
            )?;
        }
        let mut rec = self.ctx.recorder("sss posed mesh readback")?;
        let rb = pose.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let data = rb.data()?;
        let mut posed = self.character.mesh.clone();
        let weld = posed::weld_first(&posed.positions);
        posed.positions = weld.iter().map(|&w| data.positions[w as usize]).collect();
        posed.normals = data.normals;
        let obj = posed_obj(&posed.positions, &self.geo, self.cfg.mm_per_unit);
        crate::io::write_atomic(&dir.join("posed.obj"), obj.as_bytes())?;
        frame_picture(
            &self.cfg.out.join(format!("frame_{f:04}.png")),
            self.cfg,
            &self.geo,
            &posed.positions,
            out,
        )?;
        Ok(posed)
    }

    /// The CPU twin of both passes and of the transmission on the last frame's geometry,
    /// compared with the GPU's outputs `gpu`.
    fn cpu_twin(&self, gpu: &SssOutput, progress: &mut dyn FnMut(&str)) -> CpuTwin {
        let (geo, lights, regions, params) = (&self.geo, &self.lights, &self.regions, &self.params);
        let t = Instant::now();
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let cpu_e = cpu::irradiance(geo, &bvh, lights, params.shadow_refine);
        let ms_irradiance = t.elapsed().as_secs_f64() * 1e3;
        // A posed kernel reuses the rest pose's contact entries: so does its twin.
        let dg = match &self.rest {
            Some((_, contact)) => DiffusionGeometry {
                walk: crate::kernels::sss::walk::SurfaceWalk::build(geo),
                contact: contact.clone(),
            },
            None => DiffusionGeometry::build(geo, regions),
        };
        let t = Instant::now();
        let cpu_b = cpu::diffusion_with(&dg, geo, regions, &cpu_e, params);
        let ms_diffusion = t.elapsed().as_secs_f64() * 1e3;
        let cpu_t = cpu::transmission(geo, &bvh, lights, regions);
        let error = TwinError::of(geo, gpu, &cpu_e, &cpu_b, &cpu_t);
        let shadowing = self.shadowing(&bvh, &dg, &cpu_e, &cpu_b);
        progress(&format!(
            "per-vertex shadowing against a ray per texel: E rel RMSE {:.4}, B rel RMSE {:.4?}",
            shadowing.irradiance_rel_rmse, shadowing.diffuse_rel_rmse
        ));
        progress(&format!(
            "CPU twin ({ms_irradiance:.0} + {ms_diffusion:.0} ms): irradiance max rel {:.1e}, \
             diffuse rel RMSE {:.1e} {:.1e} {:.1e}",
            error.irradiance_max_rel,
            error.diffuse_rel_rmse[0],
            error.diffuse_rel_rmse[1],
            error.diffuse_rel_rmse[2]
        ));
        CpuTwin {
            dg,
            error,
            shadowing,
            ms_irradiance,
            ms_diffusion,
        }
    }

    /// The CPU irradiance `cpu_e` and diffusion `cpu_b` against the same with a shadow ray
    /// per texel everywhere.
    fn shadowing(
        &self,
        bvh: &Bvh,
        dg: &DiffusionGeometry,
        cpu_e: &[[f32; 4]],
        cpu_b: &[[f32; 4]],
    ) -> ShadowingReport {
        let (geo, regions, params) = (&self.geo, &self.regions, &self.params);
        let e_ray = cpu::irradiance_per_texel_rays(geo, bvh, &self.lights);
        let b_ray = cpu::diffusion_with(dg, geo, regions, &e_ray, params);
        let w: Vec<f64> = (0..geo.texels())
            .map(|i| {
                if geo.pos[i][3] == COVERED {
                    geo.nrm[i][3] as f64
                } else {
                    0.0
                }
            })
            .collect();
        let e_err = ChannelError::of(&as3(cpu_e), &as3(&e_ray), &w);
        let b_err = ChannelError::of(&as3(cpu_b), &as3(&b_ray), &w);
        ShadowingReport {
            method: if params.shadow_refine {
                "shadow rays per mesh vertex; a ray per texel in triangles whose corners \
                 disagree (compared with a shadow ray per texel everywhere)"
            } else {
                "shadow rays per mesh vertex, visibility interpolated over each triangle \
                 (compared with a shadow ray per texel)"
            },
            irradiance_rel_rmse: e_err.rel_rmse[0],
            diffuse_rel_rmse: b_err.rel_rmse,
            diffuse_energy_ratio: b_err.energy_ratio,
        }
    }

    /// What reusing the rest pose's contact entries costs at the last frame's pose: the CPU
    /// diffusion of the GPU irradiance with them against the same with entries built for
    /// the pose (CPU, ~1 s).
    fn contact_reuse(
        &self,
        gpu: &SssOutput,
        dg: &DiffusionGeometry,
        progress: &mut dyn FnMut(&str),
    ) -> Option<ContactReuse> {
        self.rest.as_ref()?;
        let (geo, regions, params) = (&self.geo, &self.regions, &self.params);
        let t = Instant::now();
        let per_pose = Contact::build(geo, regions);
        let build_ms_per_pose = t.elapsed().as_secs_f64() * 1e3;
        let reused = cpu::diffusion_with(dg, geo, regions, &gpu.irradiance, params);
        let fresh_dg = DiffusionGeometry {
            walk: dg.walk.clone(),
            contact: per_pose,
        };
        let fresh = cpu::diffusion_with(&fresh_dg, geo, regions, &gpu.irradiance, params);
        let covered = self.covered();
        let w: Vec<f64> = covered.iter().map(|&i| geo.nrm[i][3] as f64).collect();
        let pick = |v: &[[f32; 4]]| -> Vec<[f64; 3]> {
            covered
                .iter()
                .map(|&i| [0, 1, 2].map(|c| v[i][c] as f64))
                .collect()
        };
        let (a, b) = (pick(&reused), pick(&fresh));
        let err = ChannelError::of(&a, &b, &w);
        let diffuse_max_rel = [0, 1, 2].map(|c| {
            let top = b.iter().map(|x| x[c]).fold(0f64, f64::max);
            a.iter()
                .zip(&b)
                .filter(|(_, y)| y[c] >= 1e-3 * top)
                .map(|(x, y)| (x[c] - y[c]).abs() / y[c])
                .fold(0f64, f64::max)
        });
        let r = ContactReuse {
            diffuse_rel_rmse: err.rel_rmse,
            diffuse_energy_ratio: err.energy_ratio,
            diffuse_max_rel,
            build_ms_per_pose,
        };
        progress(&format!(
            "contact entries of the rest pose at the last pose: B rel RMSE {:.2e} {:.2e} {:.2e}, \
             max rel {:.2e} {:.2e} {:.2e} against entries built for the pose ({:.0} ms a pose)",
            r.diffuse_rel_rmse[0],
            r.diffuse_rel_rmse[1],
            r.diffuse_rel_rmse[2],
            r.diffuse_max_rel[0],
            r.diffuse_max_rel[1],
            r.diffuse_max_rel[2],
            r.build_ms_per_pose
        ));
        Some(r)
    }

    /// The refitted BVH's SAH cost at the last frame's pose against a tree built for it.
    fn bvh_quality(&self) -> Option<BvhQuality> {
        let (rest, _) = self.rest.as_ref()?;
        let top = crate::geom::bvh::BvhTopology::build(&rest.positions, &rest.triangles).ok()?;
        let (nodes, _) = crate::geom::bvh::refit(&top, &self.geo.positions);
        let fresh = Bvh::build(&self.geo.positions, &self.geo.triangles)
            .flat()
            .0;
        Some(BvhQuality {
            levels: top.levels(),
            sah_refitted: crate::geom::bvh::sah_cost(&nodes),
            sah_built_for_pose: crate::geom::bvh::sah_cost(&fresh),
        })
    }

    /// With --anim and --reference: the GPU's diffusion against the brute force at every
    /// frame's pose.
    fn pose_references(&self, progress: &mut dyn FnMut(&str)) -> Result<Vec<PoseReference>> {
        let (cfg, mesh) = (self.cfg, &self.character.mesh);
        let mut out = Vec::new();
        for (time, posed, gpu) in &self.kept {
            let t = Instant::now();
            let geo = TexGeometry::build(posed, cfg.size, cfg.mm_per_unit)?;
            let moved_mm = posed
                .positions
                .iter()
                .zip(&mesh.positions)
                .map(|(p, q)| (*p - *q).length() as f64)
                .fold(0f64, f64::max)
                * cfg.mm_per_unit;
            let covered: Vec<usize> = (0..geo.texels())
                .filter(|&i| geo.pos[i][3] == COVERED)
                .collect();
            let receivers: Vec<usize> = covered.iter().copied().step_by(3).collect();
            let at: Vec<DVec3> = receivers
                .iter()
                .map(|&i| Vec3::from_slice(&geo.pos[i][..3]).as_dvec3())
                .collect();
            let truth = brute_force(
                &Sources::from_texels(&geo, &gpu.irradiance),
                &at,
                &self.profile,
            );
            let est: Vec<[f64; 3]> = receivers
                .iter()
                .map(|&i| [0, 1, 2].map(|c| gpu.diffuse[i][c] as f64))
                .collect();
            let w: Vec<f64> = receivers.iter().map(|&i| geo.nrm[i][3] as f64).collect();
            let error = ChannelError::of(&est, &truth, &w);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            progress(&format!(
                "pose at {time:.2} s (moved {moved_mm:.0} mm) vs brute force: rel RMSE {:.4?}, \
                 energy {:.4?} ({ms:.0} ms)",
                error.rel_rmse, error.energy_ratio
            ));
            out.push(PoseReference {
                time: *time,
                moved_mm,
                error,
                ms,
            });
        }
        Ok(out)
    }

    /// The covered texels of the last frame's geometry.
    fn covered(&self) -> Vec<usize> {
        let geo = &self.geo;
        (0..geo.texels())
            .filter(|&i| geo.pos[i][3] == COVERED)
            .collect()
    }

    /// irradiance.exr, diffuse.exr and transmission.exr (texture space, linear float).
    fn write_textures(&self, gpu: &SssOutput) -> Result<Vec<String>> {
        let mut files = Vec::new();
        let texture = |v: &[[f32; 4]]| FloatImage {
            width: self.geo.size,
            height: self.geo.size,
            pixels: v.to_vec(),
        };
        for (name, data) in [
            ("irradiance.exr", &gpu.irradiance),
            ("diffuse.exr", &gpu.diffuse),
            ("transmission.exr", &gpu.transmission),
        ] {
            let path = self.cfg.out.join(name);
            crate::io::exr::write(&path, &texture(data), crate::io::exr::Channels::Rgba)?;
            files.push(path.display().to_string());
            // The passes ran in a unique atlas: also the result in the mesh's own UVs, for a
            // renderer that textures the mesh with them (overlapping texels keep one point).
            if self.geo.report.layout != crate::scene::texspace::Layout::Original {
                let mesh_uv = name.replace(".exr", "_mesh_uv.exr");
                let path = self.cfg.out.join(mesh_uv);
                let back = self.geo.to_source_layout(data, self.geo.size);
                crate::io::exr::write(&path, &texture(&back), crate::io::exr::Channels::Rgba)?;
                files.push(path.display().to_string());
            }
        }
        Ok(files)
    }

    /// The GPU diffusion against the brute-force truth over the `covered` texels, split by
    /// where the error comes from; and the truth as a texture (for reference.png).
    fn reference(
        &self,
        gpu: &SssOutput,
        dg: &DiffusionGeometry,
        covered: &[usize],
        progress: &mut dyn FnMut(&str),
    ) -> (ReferenceReport, Vec<[f32; 4]>) {
        let (geo, profile) = (&self.geo, &self.profile);
        let t = Instant::now();
        let sources = Sources::from_texels(geo, &gpu.irradiance);
        let receivers: Vec<DVec3> = covered
            .iter()
            .map(|&i| Vec3::from_slice(&geo.pos[i][..3]).as_dvec3())
            .collect();
        let truth = brute_force(&sources, &receivers, profile);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let est: Vec<[f64; 3]> = covered
            .iter()
            .map(|&i| [0, 1, 2].map(|c| gpu.diffuse[i][c] as f64))
            .collect();
        let w: Vec<f64> = covered.iter().map(|&i| geo.nrm[i][3] as f64).collect();
        let split = |keep: &dyn Fn(usize) -> bool| {
            let idx: Vec<usize> = (0..covered.len()).filter(|&k| keep(k)).collect();
            ChannelError::of(
                &idx.iter().map(|&k| est[k]).collect::<Vec<_>>(),
                &idx.iter().map(|&k| truth[k]).collect::<Vec<_>>(),
                &idx.iter().map(|&k| w[k]).collect::<Vec<_>>(),
            )
        };
        let near_seam = self.near_seam(dg, covered);
        let own = self.own_piece_truth(&sources, &receivers, covered);
        let touch = dg.contact.apply(&gpu.irradiance);
        let energy =
            |v: &[[f64; 3]], c: usize| v.iter().zip(&w).map(|(x, a)| x[c] * a).sum::<f64>();
        let without: Vec<[f64; 3]> = covered
            .iter()
            .zip(&est)
            .map(|(&i, b)| [0, 1, 2].map(|c| b[c] - touch[i][c] as f64))
            .collect();
        let contact = contact_error(dg, covered, &own, &touch, &truth, &w);
        let seam_texels = near_seam.iter().filter(|&&b| b).count() as f64 / covered.len() as f64;
        let rep = ReferenceReport {
            sources: sources.pos.len(),
            ms,
            all: ChannelError::of(&est, &truth, &w),
            interior: split(&|k| !near_seam[k]),
            seam: split(&|k| near_seam[k]),
            seam_texels,
            truncation: [0, 1, 2].map(|c| 1.0 - profile.k[c] / profile.r_tot[c]),
            contact_share: [0, 1, 2].map(|c| 1.0 - energy(&own, c) / energy(&truth, c)),
            contact_max_share: [0, 1, 2].map(|c| contact_max_share(&truth, &own, c)),
            own_piece: ChannelError::of(&without, &own, &w),
            contact,
        };
        for line in reference_lines(&rep) {
            progress(&line);
        }
        (rep, self.truth_texture(covered, &truth))
    }

    /// Which `covered` texels have samples (the same pattern as the CPU twin's) leaving
    /// their triangle by a seam or an open edge.
    fn near_seam(&self, dg: &DiffusionGeometry, covered: &[usize]) -> Vec<bool> {
        let geo = &self.geo;
        let pattern = cpu::sample_pattern(&self.profile, self.params.samples);
        covered
            .iter()
            .map(|&i| {
                let tt = geo.texel_tri[i];
                let texel = dg.walk.texel(
                    tt[0],
                    f32::from_bits(tt[1]),
                    f32::from_bits(tt[2]),
                    cpu::rotation(i as u32),
                );
                pattern.iter().any(|q| {
                    texel
                        .exit(q[0], q[1])
                        .is_some_and(|k| dg.walk.is_seam(texel.triangle(), k))
                })
            })
            .collect()
    }

    /// The brute-force truth at `receivers` from the sources on each receiver's own
    /// connected piece of the mesh only.
    fn own_piece_truth(
        &self,
        sources: &Sources,
        receivers: &[DVec3],
        covered: &[usize],
    ) -> Vec<[f64; 3]> {
        let geo = &self.geo;
        let (piece, _) = crate::kernels::sss::contact::pieces(geo);
        let piece_of = |i: usize| piece[geo.texel_tri[i][0] as usize];
        let source_piece: Vec<u32> = (0..geo.texels())
            .filter(|&i| geo.pos[i][3] == COVERED)
            .map(piece_of)
            .collect();
        brute_force_where(sources, receivers, &self.profile, |r, j| {
            source_piece[j] == piece_of(covered[r])
        })
    }

    /// The truth at the `covered` texels as an RGBA texture (alpha 1 where covered).
    fn truth_texture(&self, covered: &[usize], truth: &[[f64; 3]]) -> Vec<[f32; 4]> {
        let mut tex = vec![[0f32; 4]; self.geo.texels()];
        for (k, &i) in covered.iter().enumerate() {
            tex[i] = [
                truth[k][0] as f32,
                truth[k][1] as f32,
                truth[k][2] as f32,
                1.0,
            ];
        }
        tex
    }

    fn notes(&self, scale_warning: Option<String>) -> Vec<String> {
        let mut notes: Vec<String> = scale_warning.into_iter().collect();
        if self.ctx.info().device_type == "CPU" {
            notes.push(
                "the device is a CPU implementation (lavapipe): times measure the CPU".into(),
            );
        }
        notes.push(
            "samples are per texel, shared by the three channels (radii from the mixture of the \
             channels' pdfs, one-sample MIS weights); irradiance shadows are rays \
             through a BVH of the mesh on the GPU, one per mesh vertex and light, refined by a \
             ray per texel where a triangle's corners disagree (interpolated over the triangle \
             with --vertex-shadows; see `shadowing`); the texture-space geometry is \
             rasterised on the CPU once; with --anim each frame computes the vertex frames, \
             texel geometry, surface-walk records and a refit of the rest pose's BVH on the \
             GPU from the posed vertices (contact entries: the rest pose's, see \
             `contact_reuse`); transmission: thickness along -n by a ray per vertex, \
             back irradiance times the profile beyond the thickness (flat-slab model), \
             interpolated per texel, added in render.png, not in diffuse.exr"
                .into(),
        );
        notes.push(
            "reference: brute force over every covered texel (position, GPU irradiance, area) \
             with the untruncated profile and Euclidean distances; `seam` = texels some of whose \
             samples leave their triangle through a seam or an open edge; `own_piece` / \
             `contact`: the truth split by the connected piece of the mesh its light comes from"
                .into(),
        );
        notes
    }

    /// The report of the run.
    fn report(
        &self,
        frames: Frames,
        twin: CpuTwin,
        covered: &[usize],
        reference: Option<ReferenceReport>,
        files: Vec<String>,
        notes: Vec<String>,
    ) -> SssReport {
        let cfg = self.cfg;
        let (ms_e, ms_b) = (frames.ms_irradiance, frames.ms_diffusion);
        let accepted_fraction = covered
            .iter()
            .map(|&i| frames.gpu.diffuse[i][3] as f64)
            .sum::<f64>()
            / covered.len() as f64;
        SssReport {
            tool: "vkshade sss",
            machine: MachineInfo::of(self.ctx),
            mesh: cfg.mesh.display().to_string(),
            part: cfg.part.clone(),
            anim: self.anim.map(|a| a.name.clone()),
            mm_per_unit: cfg.mm_per_unit,
            lights: cfg.lights.clone(),
            profile: self.profile.clone(),
            sampler: self.params,
            samples: cfg.samples,
            size: cfg.size,
            texture: self.geo.report.clone(),
            kernel: KernelInfo::of(&self.kernel, frames.in_flight),
            gpu_ms_irradiance: ms_e,
            gpu_ms_diffusion: ms_b,
            fps: 1000.0 / frames.cost.gpu_ms_total,
            frame_cost: frames.cost.clone(),
            contact_reuse: None,
            bvh: None,
            reference_poses: Vec::new(),
            accepted_fraction,
            gpu_vs_cpu: twin.error,
            shadowing: twin.shadowing,
            cpu_ms_irradiance: twin.ms_irradiance,
            cpu_ms_diffusion: twin.ms_diffusion,
            reference,
            files,
            notes,
        }
    }
}

/// The posed mesh as OBJ text: positions `p` (model units, vec4), the triangles of `geo` with
/// its atlas UVs per corner (`vt`, one per triangle corner: the texture-space layout the
/// EXRs are in, u right and v down the rows, texel (x, y) centred at ((x + 0.5) / N,
/// (y + 0.5) / N)).
fn posed_obj(p: &[Vec3], geo: &TexGeometry, mm_per_unit: f64) -> String {
    use std::fmt::Write;
    let mut s = format!(
        "# vkshade sss --anim: the posed mesh (model units; {mm_per_unit} mm per unit), \
         {}^2 atlas UVs per corner (v down the texture's rows)\n",
        geo.size
    );
    for v in p {
        let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
    }
    for t in &geo.corner_uvs {
        for uv in t {
            let _ = writeln!(s, "vt {} {}", uv.x, uv.y);
        }
    }
    for (k, t) in geo.triangles.iter().enumerate() {
        let _ = writeln!(
            s,
            "f {}/{} {}/{} {}/{}",
            t[0] + 1,
            3 * k + 1,
            t[1] + 1,
            3 * k + 2,
            t[2] + 1,
            3 * k + 3
        );
    }
    s
}

/// RGB of RGBA texels, in f64.
fn as3(v: &[[f32; 4]]) -> Vec<[f64; 3]> {
    v.iter()
        .map(|x| [x[0] as f64, x[1] as f64, x[2] as f64])
        .collect()
}

/// The contact term's error, relative to the whole truth at the texels that have contact
/// entries: the truth plus (contact term - light from other pieces), i.e. the own-piece
/// truth `own` plus the contact term `touch`, against the whole truth.
fn contact_error(
    dg: &DiffusionGeometry,
    covered: &[usize],
    own: &[[f64; 3]],
    touch: &[[f32; 3]],
    truth: &[[f64; 3]],
    w: &[f64],
) -> ChannelError {
    let touched: Vec<usize> = (0..covered.len())
        .filter(|&k| dg.contact.range[covered[k]][1] > 0)
        .collect();
    let shifted: Vec<[f64; 3]> = touched
        .iter()
        .map(|&k| {
            let i = covered[k];
            [0, 1, 2].map(|c| own[k][c] + touch[i][c] as f64)
        })
        .collect();
    let full: Vec<[f64; 3]> = touched.iter().map(|&k| truth[k]).collect();
    let ww: Vec<f64> = touched.iter().map(|&k| w[k]).collect();
    ChannelError::of(&shifted, &full, &ww)
}

/// The largest share of one texel's truth in channel `c` from other pieces of the mesh,
/// over the texels whose truth is at least 1e-3 of the largest.
fn contact_max_share(truth: &[[f64; 3]], own: &[[f64; 3]], c: usize) -> f64 {
    let top = truth.iter().map(|t| t[c]).fold(0.0, f64::max);
    truth
        .iter()
        .zip(own)
        .filter(|(t, _)| t[c] > 1e-3 * top)
        .map(|(t, o)| 1.0 - o[c] / t[c])
        .fold(0.0, f64::max)
}

/// The progress lines of the reference: where the error comes from, and the totals.
fn reference_lines(rep: &ReferenceReport) -> [String; 2] {
    [
        format!(
            "{:.0}% of the texels sample across a seam or border: rel RMSE there {:.4?}, \
             elsewhere {:.4?}; light from other pieces of the mesh: {:.4?} of the truth; \
             without the contact term vs the own-piece truth: rel RMSE {:.4?}",
            100.0 * rep.seam_texels,
            rep.seam.rel_rmse,
            rep.interior.rel_rmse,
            rep.contact_share,
            rep.own_piece.rel_rmse
        ),
        format!(
            "vs brute force ({} sources, {:.0} ms): rel RMSE {:.4?}, max rel {:.3?}, energy \
             ratio {:.4?}",
            rep.sources, rep.ms, rep.all.rel_rmse, rep.all.max_rel, rep.all.energy_ratio
        ),
    ]
}

/// Bilinear lookup of a texture-space RGB image at `uv`, over valid (alpha > 0) texels.
fn lookup(tex: &[[f32; 4]], valid: &[[f32; 4]], size: u32, uv: Vec2) -> [f32; 3] {
    let n = size as i64;
    let t = uv * size as f32 - Vec2::splat(0.5);
    let (x0, y0) = (t.x.floor() as i64, t.y.floor() as i64);
    let (fx, fy) = (t.x - x0 as f32, t.y - y0 as f32);
    let mut sum = [0f32; 3];
    let mut wsum = 0f32;
    for (dx, dy, w) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        let (x, y) = ((x0 + dx).clamp(0, n - 1), (y0 + dy).clamp(0, n - 1));
        let i = (y * n + x) as usize;
        if valid[i][3] > 0.0 {
            for c in 0..3 {
                sum[c] += w * tex[i][c];
            }
            wsum += w;
        }
    }
    if wsum > 0.0 {
        sum.map(|s| s / wsum)
    } else {
        [0.0; 3]
    }
}

/// render.png (SSS | Lambertian) and, with a truth, reference.png (result | truth | error).
fn pictures(
    cfg: &SssConfig,
    geo: &TexGeometry,
    profile: &Profile,
    gpu: &SssOutput,
    truth: Option<&[[f32; 4]]>,
) -> Result<Vec<String>> {
    use crate::render::{shade_rgb, write_png};
    let atlas = AtlasView::new(cfg, geo);
    // Exit radiance L = B / pi (Fresnel transmittance left out); the Lambertian comparison
    // has the same total reflectance: L = R_tot E / pi.
    let pi = std::f32::consts::PI;
    let sss = atlas.image(&|uv| {
        let b = lookup(&gpu.diffuse, &geo.pos, geo.size, uv);
        let t = lookup(&gpu.transmission, &geo.pos, geo.size, uv);
        [0, 1, 2].map(|c| (b[c] + t[c]) / pi)
    });
    let r_tot = profile.r_tot.map(|r| r as f32);
    let lambert = atlas.image(&|uv| {
        let e = lookup(&gpu.irradiance, &geo.pos, geo.size, uv);
        [0, 1, 2].map(|c| r_tot[c] * e[c] / pi)
    });
    let exposure = exposure(&sss);
    let a = shade_rgb([&sss[0], &sss[1], &sss[2]], exposure)?;
    let b = shade_rgb([&lambert[0], &lambert[1], &lambert[2]], exposure)?;
    let mut rgb = Vec::with_capacity(a.rgb.len() * 2);
    let w = a.width as usize;
    for y in 0..a.height as usize {
        rgb.extend_from_slice(&a.rgb[3 * w * y..3 * w * (y + 1)]);
        rgb.extend_from_slice(&b.rgb[3 * w * y..3 * w * (y + 1)]);
    }
    let path = cfg.out.join("render.png");
    write_png(&path, a.width * 2, a.height, &rgb)?;
    let mut files = vec![path.display().to_string()];
    if let Some(truth) = truth {
        let path = cfg.out.join("reference.png");
        reference_picture(&path, cfg, geo, &atlas, gpu, truth, exposure)?;
        files.push(path.display().to_string());
    }
    Ok(files)
}

/// frame_NNNN.png of an animated run: the posed mesh (`posed`, model units) seen from the
/// pictures' camera, lit with the frame's subsurface diffusion and transmission (exit
/// radiance B / pi, as render.png's left half), exposed per frame.
fn frame_picture(
    path: &Path,
    cfg: &SssConfig,
    geo: &TexGeometry,
    posed: &[Vec3],
    gpu: &SssOutput,
) -> Result<()> {
    use crate::render::{shade_rgb, write_png};
    let mut frame_geo = geo.clone();
    let scale = cfg.mm_per_unit as f32;
    frame_geo.positions = posed.iter().map(|p| *p * scale).collect();
    let atlas = AtlasView::new(cfg, &frame_geo);
    let pi = std::f32::consts::PI;
    let sss = atlas.image(&|uv| {
        let b = lookup(&gpu.diffuse, &geo.pos, geo.size, uv);
        let t = lookup(&gpu.transmission, &geo.pos, geo.size, uv);
        [0, 1, 2].map(|c| (b[c] + t[c]) / pi)
    });
    let picture = shade_rgb([&sss[0], &sss[1], &sss[2]], exposure(&sss))?;
    write_png(path, picture.width, picture.height, &picture.rgb)
}

/// The mesh seen from the pictures' camera, each pixel holding the atlas UV it shows.
struct AtlasView {
    u: ValueImage,
    v: ValueImage,
}

impl AtlasView {
    fn new(cfg: &SssConfig, geo: &TexGeometry) -> AtlasView {
        use crate::render::{View, rasterize};
        // One vertex per triangle corner, carrying its atlas UV.
        let mut positions = Vec::with_capacity(3 * geo.triangles.len());
        let mut us = Vec::new();
        let mut vs = Vec::new();
        let mut tris = Vec::new();
        for (t, tri) in geo.triangles.iter().enumerate() {
            for (&v, uv) in tri.iter().zip(&geo.corner_uvs[t]) {
                positions.push(geo.positions[v as usize]);
                us.push(uv.x);
                vs.push(uv.y);
            }
            let b = 3 * t as u32;
            tris.push([b, b + 1, b + 2]);
        }
        let view = View {
            direction: Vec3::new(-0.35, -0.25, -1.0).normalize(),
            width: cfg.image.0,
            height: cfg.image.1,
            ..Default::default()
        };
        AtlasView {
            u: rasterize(&positions, &tris, &us, &positions, &view),
            v: rasterize(&positions, &tris, &vs, &positions, &view),
        }
    }

    /// Three channel images of `f` at each pixel's UV (NaN where no surface is seen).
    fn image(&self, f: &dyn Fn(Vec2) -> [f32; 3]) -> [ValueImage; 3] {
        let mut ch = [self.u.clone(), self.u.clone(), self.u.clone()];
        for p in 0..self.u.value.len() {
            let (u, v) = (self.u.value[p], self.v.value[p]);
            let rgb = if u.is_finite() && v.is_finite() {
                f(Vec2::new(u, v))
            } else {
                [f32::NAN; 3]
            };
            for c in 0..3 {
                ch[c].value[p] = rgb[c];
            }
        }
        ch
    }
}

/// The exposure that maps the 99th percentile of the luminance of `rgb` to 0.9.
fn exposure(rgb: &[ValueImage; 3]) -> f32 {
    let mut lum: Vec<f32> = rgb[0]
        .value
        .iter()
        .zip(&rgb[1].value)
        .zip(&rgb[2].value)
        .filter(|((r, _), _)| r.is_finite())
        .map(|((r, g), b)| 0.2126 * r + 0.7152 * g + 0.0722 * b)
        .collect();
    lum.sort_by(f32::total_cmp);
    let p99 = lum
        .get(lum.len() * 99 / 100)
        .copied()
        .unwrap_or(1.0)
        .max(1e-9);
    0.9 / p99
}

/// reference.png: the diffusion alone | the truth | the error relative to the brightest
/// truth texel, at the exposure of render.png.
fn reference_picture(
    path: &Path,
    cfg: &SssConfig,
    geo: &TexGeometry,
    atlas: &AtlasView,
    gpu: &SssOutput,
    truth: &[[f32; 4]],
    exposure: f32,
) -> Result<()> {
    use crate::render::{shade_rgb, side_by_side, write_png};
    let pi = std::f32::consts::PI;
    let sss = atlas.image(&|uv| lookup(&gpu.diffuse, &geo.pos, geo.size, uv).map(|b| b / pi));
    let a = shade_rgb([&sss[0], &sss[1], &sss[2]], exposure)?;
    let t_img = atlas.image(&|uv| lookup(truth, &geo.pos, geo.size, uv).map(|b| b / pi));
    let t_pic = shade_rgb([&t_img[0], &t_img[1], &t_img[2]], exposure)?;
    let scale = truth
        .iter()
        .map(|t| t[0].max(t[1]).max(t[2]))
        .fold(0f32, f32::max)
        .max(1e-12)
        / pi;
    let err: Vec<f32> = (0..sss[0].value.len())
        .map(|p| {
            (0..3)
                .map(|c| (sss[c].value[p] - t_img[c].value[p]).abs())
                .fold(0f32, f32::max)
                / scale
        })
        .collect();
    let pic = side_by_side(&a, &t_pic, &err, cfg.error_scale)?;
    write_png(path, pic.width, pic.height, &pic.rgb)
}

/// The arguments of `vkshade sss`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Mesh with UVs (.glb/.gltf .obj .ply; a skinned mesh is used in its bind pose).
    #[arg(long, default_value = DEFAULT_MESH)]
    pub mesh: PathBuf,
    /// Use only this glTF mesh (node or mesh name); `--part ''` uses the whole file.
    /// Default: Head for the built-in character, the whole file for any other mesh (OBJ,
    /// PLY and OFF files have no parts).
    #[arg(long)]
    pub part: Option<String>,
    /// Millimetres per model unit (scattering coefficients are per mm). Default: 1, or
    /// 1000 for the built-in BCN_Epileptic mesh (modelled in metres).
    #[arg(long)]
    pub mm_per_unit: Option<f64>,
    // The brackets are the help text's notation for an optional part, not doc links.
    #[allow(rustdoc::broken_intra_doc_links)]
    /// dir:X,Y,Z[:E] (arriving from X,Y,Z; irradiance E, default 1) or point:X,Y,Z:I
    /// (position in model units, intensity I). Repeatable.
    #[arg(long = "light")]
    pub lights: Vec<String>,
    /// dipole (tabulated inverse CDF) or burley (analytic inverse CDF).
    #[arg(
        long,
        default_value = "dipole",
        ignore_case = true,
        value_parser = super::choice::<ProfileKind>("profile")
    )]
    pub profile: ProfileKind,
    /// skin1 or skin2 (Jensen 2001), or custom with --sigma-a and --sigma-s.
    #[arg(long, default_value = "skin1")]
    pub material: String,
    /// Absorption coefficients R,G,B per mm (custom material).
    #[arg(long, value_delimiter = ',', num_args = 3)]
    pub sigma_a: Option<Vec<f64>>,
    /// Reduced scattering coefficients R,G,B per mm (custom material).
    #[arg(long, value_delimiter = ',', num_args = 3)]
    pub sigma_s: Option<Vec<f64>>,
    /// Relative index of refraction (default 1.3).
    #[arg(long, default_value_t = crate::kernels::sss::profile::DEFAULT_ETA)]
    pub eta: f64,
    /// Fraction of each channel's reflectance inside its sampling radius.
    #[arg(long, default_value_t = crate::kernels::sss::profile::DEFAULT_ENERGY)]
    pub energy: f64,
    /// Samples per texel (one set shared by the three channels).
    #[arg(long, default_value_t = 32)]
    pub samples: u32,
    /// Shadows from the mesh's vertices only, interpolated over each triangle (faster); by
    /// default a texel casts its own shadow ray where its triangle's corners disagree.
    #[arg(long)]
    pub vertex_shadows: bool,
    /// Texture size (N x N texels).
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Frames to run: spread over --anim (each at the middle of one of N equal spans of the
    /// animation; skinning and the texture-space geometry on the GPU each frame; every
    /// frame written to frame_NNNN/), or the same frame repeated; timings are medians.
    #[arg(long, default_value_t = 1)]
    pub frames: usize,
    /// Animation of the mesh's skeleton (glTF; name or unique substring).
    #[arg(long)]
    pub anim: Option<String>,
    /// Compare with the brute-force ground truth (f64, every covered texel).
    #[arg(long)]
    pub reference: bool,
    #[arg(long, default_value = "out/sss")]
    pub out: PathBuf,
}

impl Args {
    /// The run these arguments describe: the material (named, or custom from both
    /// coefficient triples), the scale and the lights (the default light when none is given).
    pub fn config(&self) -> Result<SssConfig> {
        let three = |v: &Option<Vec<f64>>, what: &str| -> Result<Option<[f64; 3]>> {
            v.as_ref()
                .map(|v| {
                    v.as_slice().try_into().map_err(|_| {
                        Error::InvalidArgument(format!("{what} takes three values R,G,B"))
                    })
                })
                .transpose()
        };
        let material = match (
            three(&self.sigma_a, "--sigma-a")?,
            three(&self.sigma_s, "--sigma-s")?,
        ) {
            (Some(sa), Some(ss)) => Material::custom(sa, ss, self.eta)?,
            (None, None) => Material::named(&self.material)?.with_eta(self.eta)?,
            _ => {
                return Err(Error::InvalidArgument(
                    "a custom material needs both --sigma-a and --sigma-s".into(),
                ));
            }
        };
        Ok(SssConfig {
            mesh: self.mesh.clone(),
            part: match &self.part {
                None => (self.mesh == std::path::Path::new(DEFAULT_MESH))
                    .then(|| DEFAULT_PART.to_string()),
                Some(p) if p.is_empty() => None,
                Some(p) => Some(p.clone()),
            },
            mm_per_unit: self
                .mm_per_unit
                .unwrap_or_else(|| default_mm_per_unit(&self.mesh)),
            lights: if self.lights.is_empty() {
                SssConfig::default().lights
            } else {
                self.lights.clone()
            },
            profile: self.profile,
            material,
            energy: self.energy,
            samples: self.samples,
            shadow_refine: !self.vertex_shadows,
            size: self.size,
            frames: self.frames,
            anim: self.anim.clone(),
            reference: self.reference,
            out: self.out.clone(),
            ..Default::default()
        })
    }

    /// `vkshade sss`: runs the frames and prints the summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        let cfg = self.config()?;
        let ctx = gpu.context()?;
        eprintln!("vkshade sss on {}", ctx.info().name);
        let r = run(&ctx, &cfg, &mut |l| super::progress(l))?;
        display(&r, &cfg);
        super::finish(ctx)
    }
}

/// The line `vkshade sss` prints: the timings of the two passes and where the files went.
pub fn display(r: &SssReport, cfg: &SssConfig) {
    if r.anim.is_some() {
        let passes: Vec<String> = (r.frame_cost.gpu_ms_per_pass.iter())
            .map(|(n, ms)| format!("{n} {ms:.2}"))
            .collect();
        println!(
            "per frame (medians): GPU {:.2} ms ({}); host {:.3} ms recording + submitting, \
             {:.3} ms evaluating the animation",
            r.frame_cost.gpu_ms_total,
            passes.join(", "),
            r.frame_cost.host_ms_per_frame,
            r.frame_cost.host_ms_animation
        );
    }
    println!(
        "{} {}^2 texels x {} samples: irradiance {:.2} ms + diffusion {:.2} ms GPU = {:.1} fps; wrote {}",
        r.mesh,
        r.size,
        r.samples,
        r.gpu_ms_irradiance,
        r.gpu_ms_diffusion,
        r.fps,
        cfg.out.display()
    );
}
