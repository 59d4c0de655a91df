//! `vkshade validate`: every pipeline vkshade ships, each on a small real input, under every
//! validation feature the installed layer offers; a table (case, pipelines, features,
//! messages, time) and a non-zero exit on any message. And `vkshade bench soak`.
//!
//! **Cases.** Each case is a vkshade command line with small sizes ([`CASES`]), run in
//! this process through the same code as the CLI, its context made with the row's
//! validation features and a sink that copies every message (see
//! [`ValidationConfig::tee`]). Outputs go to a fresh folder per case under `--out`.
//!
//! **Features.** The layer (1.3.239 on Debian 12) offers, through
//! `VkValidationFeatureEnableEXT`: core checks (always on), `SYNCHRONIZATION_VALIDATION`,
//! `BEST_PRACTICES`, `GPU_ASSISTED` (with `GPU_ASSISTED_RESERVE_BINDING_SLOT`, which only
//! moves the slot it instruments through) and `DEBUG_PRINTF` (prints shader `debugPrintfEXT`
//! output: no vkshade shader has any, and the layer refuses it together with GPU-assisted,
//! so it checks nothing here). Every case runs once with core + synchronization + best
//! practices, and once with GPU-assisted added, where GPU-assisted completes on the device.
//!
//! **GPU-assisted.** With the layer 1.3.239 on lavapipe the first submission under
//! GPU-assisted validation never completes (the layer's semaphore tracking; see
//! tests/pipeline.rs, `gpu_assisted_validation_starts_and_shuts_down_clean`), and when it
//! gives up it reports `UNASSIGNED-VkSemaphore-state-timeout`. So GPU-assisted rows run in a
//! child process (this executable, `validate --gpu-assisted-child CASE`) with a time limit;
//! the first case is the probe: if it hangs or reports that message, the row says "layer
//! problem, not a vkshade message" and the remaining GPU-assisted rows are not run (they
//! would hang the same way; the table says so), never reported clean nor failed.
//!
//! **Allow-list.** [`ALLOWED`] lists message ids that are advice not applying to vkshade,
//! each with the reason; they do not fail the run but the table shows their count.
//!
//! **Coverage.** After the cases, every module embedded from spv/ must have been dispatched
//! (the process-wide [`dispatched_pipelines`]) except the core's test fixtures (`test/`):
//! a new shader cannot escape the command.

use super::Gpu;
use crate::bench::soak::{self, SoakConfig, SoakReport};
use crate::error::{Error, Result};
use crate::gpu::{MessageSink, ValidationConfig, ValidationMessage, dispatched_pipelines};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One case: a name and the command line it runs (`{out}`: the case's output folder,
/// `{btf}`: a 4-texel rib BTF synthesised first, `{data}`: the repository's data/), or, for
/// a library path no command takes, a function run on a context made from the row's
/// settings.
pub struct Case {
    pub name: &'static str,
    pub args: &'static [&'static str],
    /// Instead of `args`: a library run.
    pub library: Option<fn(&Gpu) -> Result<()>>,
}

/// A case running a command line.
const fn cli(name: &'static str, args: &'static [&'static str]) -> Case {
    Case {
        name,
        args,
        library: None,
    }
}

/// Every case, in order (the first is the GPU-assisted probe: keep it small).
pub const CASES: &[Case] = &[
    cli(
        "btf-rows",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "cylinder",
            "--width",
            "48",
            "--height",
            "40",
            "--map-res",
            "32",
            "--layout",
            "rows",
            "--texture",
            "rgba8",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-layers-env",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "cylinder",
            "--width",
            "48",
            "--height",
            "40",
            "--map-res",
            "32",
            "--layout",
            "layers",
            "--texture",
            "rgba8",
            "--env",
            "{forest}",
            "--env-lobes",
            "8",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-rows-env",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "sphere",
            "--width",
            "48",
            "--height",
            "40",
            "--map-res",
            "32",
            "--layout",
            "rows",
            "--texture",
            "rgba8",
            "--env",
            "{forest}",
            "--env-lobes",
            "8",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-block-env",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "sphere",
            "--width",
            "48",
            "--height",
            "40",
            "--map-res",
            "32",
            "--env",
            "{forest}",
            "--env-lobes",
            "8",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-anim-block",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "{data}/bcn_epileptic.glb",
            "--anim",
            "Epileptisch",
            "--part",
            "Torso,Legs",
            "--frames",
            "2",
            "--width",
            "64",
            "--height",
            "64",
            "--map-res",
            "32",
            "--texture",
            "block",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-anim-rgba8",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "{data}/bcn_epileptic.glb",
            "--anim",
            "Epileptisch",
            "--part",
            "Torso,Legs",
            "--frames",
            "2",
            "--width",
            "64",
            "--height",
            "64",
            "--map-res",
            "32",
            "--texture",
            "rgba8",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "btf-anim-layers",
        &[
            "btf",
            "render",
            "--btf",
            "{btf}",
            "--object",
            "{data}/bcn_epileptic.glb",
            "--anim",
            "Epileptisch",
            "--part",
            "Torso,Legs",
            "--frames",
            "2",
            "--width",
            "64",
            "--height",
            "64",
            "--map-res",
            "32",
            "--texture",
            "rgba8",
            "--layout",
            "layers",
            "--out",
            "{out}",
        ],
    ),
    Case {
        name: "btf-env-basis",
        args: &[],
        library: Some(btf_env_basis),
    },
    cli(
        "env",
        &["env", "--frames", "2", "--lobes", "8", "--out", "{out}"],
    ),
    // AO's visibility as the scale (module env/shadow; the default traces rays).
    cli(
        "env-ao-scale",
        &[
            "env",
            "--frames",
            "1",
            "--lobes",
            "8",
            "--trace-grid",
            "0",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "ao-fixed-cut",
        &["ao", "--frames", "1", "--cut", "fixed", "--out", "{out}"],
    ),
    cli(
        "sss",
        &["sss", "--size", "64", "--samples", "4", "--out", "{out}"],
    ),
    cli(
        "sss-posed",
        &[
            "sss",
            "--size",
            "64",
            "--samples",
            "4",
            "--frames",
            "2",
            "--anim",
            "Epileptisch",
            "--out",
            "{out}",
        ],
    ),
    Case {
        name: "sss-irradiance-in",
        args: &[],
        library: Some(sss_irradiance_in),
    },
    Case {
        name: "sss-posed-geometry",
        args: &[],
        library: Some(sss_posed_geometry),
    },
    cli(
        "srbf",
        &[
            "srbf",
            "shade",
            "--mesh",
            "{data}/testwuson.glb",
            "--lobes",
            "16",
            "--basis",
            "64",
            "--directions",
            "32",
            "--frames",
            "2",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "srbf-sun-rays",
        &[
            "srbf",
            "shade",
            "--mesh",
            "{data}/testwuson.glb",
            "--lobes",
            "16",
            "--basis",
            "64",
            "--directions",
            "32",
            "--frames",
            "2",
            "--sun",
            "rays",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "srbf-glossy",
        &[
            "srbf",
            "shade",
            "--mesh",
            "{data}/testwuson.glb",
            "--lobes",
            "16",
            "--basis",
            "64",
            "--directions",
            "32",
            "--frames",
            "2",
            "--brdf",
            "phong",
            "--views",
            "4",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "srbf-glossy-cta",
        &[
            "srbf",
            "shade",
            "--mesh",
            "{data}/testwuson.glb",
            "--lobes",
            "16",
            "--basis",
            "64",
            "--directions",
            "32",
            "--frames",
            "2",
            "--brdf",
            "phong",
            "--views",
            "4",
            "--cta",
            "--cta-clusters",
            "8",
            "--cta-iterations",
            "1",
            "--sun",
            "rays",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "frame",
        &[
            "frame",
            "--frames",
            "2",
            "--size",
            "96",
            "--atlas",
            "64",
            "--samples",
            "4",
            "--out",
            "{out}",
        ],
    ),
    // Every atlas segment and every pixel (modules sss/diffusion_env and compose/shade; the
    // default culls to what the camera sees).
    cli(
        "frame-no-cull",
        &[
            "frame",
            "--frames",
            "1",
            "--size",
            "64",
            "--atlas",
            "64",
            "--samples",
            "4",
            "--no-cull",
            "--out",
            "{out}",
        ],
    ),
    // The environment shadowed with AO's visibility as the scale over the frame's vertex
    // list (module env/shadow_listed; the default traces rays).
    cli(
        "frame-ao-scale",
        &[
            "frame",
            "--frames",
            "1",
            "--size",
            "64",
            "--atlas",
            "64",
            "--samples",
            "4",
            "--env-trace-grid",
            "0",
            "--out",
            "{out}",
        ],
    ),
    cli(
        "bench-peak",
        &[
            "bench",
            "peak",
            "--samples",
            "1",
            "--warmup",
            "0",
            "--min-ms",
            "1",
        ],
    ),
    cli(
        "bench-btf",
        &[
            "bench",
            "btf",
            "--quick",
            "--samples",
            "1",
            "--warmup",
            "0",
            "--min-ms",
            "1",
        ],
    ),
];

/// The default environment map of the env and SRBF commands.
const FOREST: &str = "/usr/share/blender/datafiles/studiolights/world/forest.exr";

/// SSS paths no command takes: an irradiance uploaded by the caller (`sss/diffusion`, rgb,
/// two gathers), and a per-vertex rgb irradiance on an unposed kernel
/// (`sss/vertex_env`, `sss/irradiance_env`, `sss/diffusion_env`), on the built-in head at
/// 64 x 64 texels.
fn sss_irradiance_in(gpu: &Gpu) -> Result<()> {
    use crate::kernels::sss::cpu::SamplerParams;
    use crate::kernels::sss::{Material, Profile, ProfileKind, SssKernel};
    use crate::kernels::{Kernel, run_frames};
    use crate::scene::texspace::TexGeometry;
    let path = crate::shaders::source_root().join("data/bcn_epileptic.glb");
    let mesh = crate::kernels::sss::load_mesh(&path, Some("Head"))?;
    let geo = TexGeometry::build(&mesh, 64, 1000.0)?;
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.99)?;
    let params = SamplerParams {
        samples: 4,
        ..Default::default()
    };
    let ctx = gpu.context()?;
    let run = || -> Result<()> {
        let mut setup = ctx.recorder("validate: sss setup")?;
        let mut kernel = SssKernel::new(&mut setup, &geo, &p, params)?;
        setup.submit_and_wait()?;
        let e = vec![[0.5f32, 0.4, 0.3, 0.0]; geo.texels()];
        let mut rec = ctx.recorder("validate: sss uploaded irradiance")?;
        kernel.upload_irradiance(&mut rec, &e)?;
        kernel.record_diffusion(&mut rec)?;
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        kernel.collect(&rb)?;
        let ve: Vec<[f32; 4]> = geo
            .normals
            .iter()
            .map(|n| [0.6 + 0.4 * n.x, 0.5, 0.4, 0.0])
            .collect();
        let mut setup = ctx.recorder("validate: sss vertex irradiance")?;
        let buffer = setup.buffer_with(
            "validate: vertex E",
            crate::gpu::BufferDesc::storage(ve.len() as u64 * 16),
            &ve,
        )?;
        kernel.set_vertex_irradiance(&mut setup, Some(&buffer))?;
        setup.submit_and_wait()?;
        let lights: [crate::kernels::sss::cpu::Light; 0] = [];
        run_frames(&ctx, &kernel, [&lights[..]], 1, |_| Ok(()))?;
        Ok(())
    };
    let result = run();
    let finished = super::finish(ctx);
    result.and(finished)
}

/// A posed SSS kernel's geometry read back (`sss/pose_texels`, which a frame does not run:
/// tests and diagnostics read the texel positions and normals of the last pose through it),
/// on the built-in head at 64 x 64 texels, after one posed frame.
fn sss_posed_geometry(gpu: &Gpu) -> Result<()> {
    use crate::kernels::Kernel;
    use crate::kernels::pose::{PoseKernel, Prepared};
    use crate::kernels::sss::cpu::{Light, SamplerParams};
    use crate::kernels::sss::{Material, PosedBuffers, Profile, ProfileKind, SssKernel};
    use crate::scene::texspace::TexGeometry;
    let path = crate::shaders::source_root().join("data/bcn_epileptic.glb");
    let ch = crate::kernels::sss::load_character(&path, Some("Head"))?;
    let anim = ch.animation("Epileptisch")?;
    let m = ch.rig.skinning_matrices(Some(anim), 0.4 * anim.duration);
    let rest = TexGeometry::build(&ch.mesh, 64, 1000.0)?;
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.99)?;
    let params = SamplerParams {
        samples: 4,
        ..Default::default()
    };
    let lights = [Light::Directional {
        toward: glam::Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let ctx = gpu.context()?;
    let run = || -> Result<()> {
        let mut setup = ctx.recorder("validate: sss posed setup")?;
        let prep = Prepared::new(&ch.mesh, ch.rig.joints.len())?;
        let pose = PoseKernel::new(&mut setup, &prep)?;
        let src = PosedBuffers {
            positions: pose.positions(),
            normals: pose.normals(),
            mm_per_unit: 1000.0,
        };
        let kernel = SssKernel::new_posed(&mut setup, &rest, &ch.mesh.positions, &p, params, src)?;
        setup.submit_and_wait()?;
        let mut rec = ctx.recorder("validate: sss posed frame")?;
        pose.record(&mut rec, &m)?;
        kernel.record(&mut rec, &lights[..])?;
        let geometry = kernel.read_back_geometry(&mut rec)?;
        rec.submit_and_wait()?;
        drop(geometry);
        Ok(())
    };
    let result = run();
    let finished = super::finish(ctx);
    result.and(finished)
}

/// The BTF's environment light-basis pass on a kernel that is not over a tile list
/// (`btf/env_basis`; the frame runs `btf/env_basis_pixels`): an 8-texel weave on a 48 x 40
/// sphere, eight lobes.
fn btf_env_basis(gpu: &Gpu) -> Result<()> {
    use crate::geom::sg::{Lobe, fibonacci_sphere};
    use crate::kernels::Kernel;
    use crate::kernels::btf::basis::BasisData;
    use crate::kernels::btf::cloth::{Pattern, SynthConfig};
    use crate::kernels::btf::dirs::{Maps, Triangulation};
    use crate::kernels::btf::env::lobe_texels;
    use crate::kernels::btf::gpu::{
        BasisVisibility, BtfInputs, BtfKernel, EnvBasisInputs, Prepared, Texture,
    };
    use crate::scene::gbuffer::{Camera, EYE, Frame, Light, Object, render_object};
    let btf = crate::kernels::btf::synth::synthesize(&SynthConfig::tile(Pattern::Weave, 8))?;
    let maps = Maps::build(&Triangulation::new()?, 32)?;
    let gbuffer = render_object(Object::Sphere, 48, 40)?;
    let lobes: Vec<Lobe> = fibonacci_sphere(8)
        .into_iter()
        .map(|axis| Lobe::new(axis, 6.0, [0.1, 0.08, 0.06]))
        .collect();
    let data = BasisData::new(&btf, &lobes)?;
    let texels = lobe_texels(&lobes);
    let flat: Vec<f32> = texels.iter().flatten().copied().collect();
    let frame = Frame {
        camera: Camera::Perspective(glam::Vec3::from(EYE)),
        lights: vec![Light {
            direction: glam::Vec3::new(0.5, 0.8, 0.6),
            rgb: [1.0; 3],
        }],
    };
    let ctx = gpu.context()?;
    let run = || -> Result<()> {
        let l = ctx.limits();
        let prep = Prepared::new(
            &BtfInputs::new(&btf, &maps, &gbuffer, Texture::Rgba8),
            l.max_image_dimension_2d,
            l.max_image_array_layers,
        )?;
        let mut rec = ctx.recorder("validate: btf env basis")?;
        let lobe_buf = rec.buffer_with(
            "validate: lobes",
            crate::gpu::BufferDesc::storage(4 * flat.len() as u64),
            &flat,
        )?;
        let mut k = BtfKernel::from_prepared(&mut rec, &prep)?;
        k.add_env_basis(
            &mut rec,
            None,
            EnvBasisInputs {
                lobes: &lobe_buf,
                data: &data,
                visibility: BasisVisibility::None,
                part_mask: u32::MAX,
            },
        )?;
        k.record(&mut rec, &frame)?;
        let rb = k.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        k.collect(&rb)?;
        Ok(())
    };
    let result = run();
    let finished = super::finish(ctx);
    result.and(finished)
}

/// Message ids that do not fail `vkshade validate`, each advice that does not apply to
/// vkshade: (messageIdNumber, messageIdName, why). The table shows how many were raised.
pub const ALLOWED: &[(i32, &str, &str)] = &[(
    0x822806fa_u32 as i32,
    "BestPractices-vkCreateInstance-specialuse-extension-debugging",
    "warns that VK_EXT_debug_utils / VK_EXT_validation_features are debugging extensions: \
     enabling them for debugging is what a validated context is for",
)];

/// Modules of spv/ no case runs, each with the reason and the test that dispatches it
/// under validation instead. The coverage check reports them (a module neither run nor
/// listed here fails it).
pub const NOT_IN_A_CASE: &[(&str, &str)] = &[];

/// The layer's own message under GPU-assisted validation on lavapipe (see the module doc).
pub const LAYER_PROBLEM: &str = "UNASSIGNED-VkSemaphore-state-timeout";

/// Validation features of a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum FeatureSet {
    /// Core, synchronization and best-practices checks.
    Standard,
    /// The same with GPU-assisted validation (instrumented shaders).
    GpuAssisted,
}

impl FeatureSet {
    /// The features in words, as the table shows them.
    pub fn label(self) -> &'static str {
        match self {
            FeatureSet::Standard => "core+sync+best-practices",
            FeatureSet::GpuAssisted => "core+sync+best-practices+gpu-assisted",
        }
    }

    fn config(self, tee: Arc<MessageSink>) -> ValidationConfig {
        ValidationConfig {
            synchronization: true,
            best_practices: true,
            gpu_assisted: self == FeatureSet::GpuAssisted,
            // Every message reaches the tee (the allow-list is applied there and shown in the
            // table); the context drops the allowed ones, so the command itself passes.
            ignored_ids: ALLOWED.iter().map(|(id, _, _)| *id).collect(),
            tee: Some(tee),
        }
    }
}

/// How a row ended.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Status {
    /// No message outside the allow-list, and the command succeeded.
    Clean,
    /// Validation messages (listed in the row).
    Messages,
    /// The command failed (the error).
    Failed(String),
    /// The layer's own problem, not a vkshade message (what happened).
    LayerProblem(String),
}

/// One line of the table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub case: String,
    pub features: FeatureSet,
    /// Pipelines the case dispatched (names of spv/ modules).
    pub pipelines: Vec<String>,
    /// Messages outside the allow-list.
    pub messages: Vec<String>,
    /// Allowed messages raised, per id name.
    pub allowed: BTreeMap<String, usize>,
    pub seconds: f64,
    pub status: Status,
}

/// Settings of a validate run.
#[derive(Clone, Debug)]
pub struct ValidateConfig {
    /// Cases to run (names from [`CASES`]); empty: all.
    pub cases: Vec<String>,
    /// Where each case writes its outputs (`DIR/CASE/`, `DIR/CASE-gpu-assisted/`).
    pub out: PathBuf,
    /// The executable GPU-assisted rows run in (`vkshade`); `None`: no GPU-assisted rows.
    pub gpu_assisted_exe: Option<PathBuf>,
    /// Time limit of one GPU-assisted row.
    pub gpu_assisted_timeout: Duration,
    /// Check that every spv/ module (but `test/`) was dispatched (only meaningful with all
    /// cases).
    pub coverage: bool,
}

/// The rows and the coverage check.
#[derive(Clone, Debug, Serialize)]
pub struct ValidateReport {
    pub rows: Vec<Row>,
    /// Modules of spv/ (but `test/`) no case dispatched (empty when not checked).
    pub not_exercised: Vec<String>,
    pub coverage_checked: bool,
    pub seconds: f64,
}

impl ValidateReport {
    /// Whether the run passes: no row with messages or a failure, every module exercised.
    pub fn passed(&self) -> bool {
        self.not_exercised.is_empty()
            && self
                .rows
                .iter()
                .all(|r| matches!(r.status, Status::Clean | Status::LayerProblem(_)))
    }
}

/// The cases `names` selects (all when empty); an unknown name is an error listing them.
pub fn select(names: &[String]) -> Result<Vec<&'static Case>> {
    if names.is_empty() {
        return Ok(CASES.iter().collect());
    }
    names
        .iter()
        .map(|n| {
            CASES.iter().find(|c| c.name == n).ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "unknown validate case '{n}' (cases: {})",
                    CASES.iter().map(|c| c.name).collect::<Vec<_>>().join(", ")
                ))
            })
        })
        .collect()
}

/// The command lines vkshade's cases parse (the subset of `vkshade`'s commands they use).
#[derive(clap::Parser)]
#[command(name = "vkshade")]
struct Line {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(clap::Subcommand)]
enum Cmd {
    Ao(super::ao::Args),
    Sss(super::sss::Args),
    Env(super::env::Args),
    #[command(subcommand)]
    Srbf(super::srbf::Command),
    #[command(subcommand)]
    Btf(super::btf::Command),
    Frame(super::frame::Args),
    #[command(subcommand)]
    Bench(super::bench::Command),
}

impl Cmd {
    fn run(&self, gpu: &Gpu) -> Result<()> {
        match self {
            Cmd::Ao(a) => a.run(gpu),
            Cmd::Sss(a) => a.run(gpu),
            Cmd::Env(a) => a.run(gpu),
            Cmd::Srbf(c) => c.run(gpu),
            Cmd::Btf(c) => c.run(gpu),
            Cmd::Frame(a) => a.run(gpu),
            Cmd::Bench(c) => c.run(gpu),
        }
    }
}

/// `case`'s command line with its placeholders filled.
fn command_line(case: &Case, out: &Path, btf: &Path) -> Vec<String> {
    let data = crate::shaders::source_root().join("data");
    std::iter::once("vkshade".to_string())
        .chain(case.args.iter().map(|a| {
            a.replace("{out}", &out.display().to_string())
                .replace("{btf}", &btf.display().to_string())
                .replace("{data}", &data.display().to_string())
                .replace("{forest}", FOREST)
        }))
        .collect()
}

/// The BTF the btf cases render (synthesised once, on the CPU).
fn btf_dir(root: &Path) -> Result<PathBuf> {
    let dir = root.join("rib4");
    if !dir.join("btf.json").exists() {
        use clap::Parser;
        let line = [
            "vkshade",
            "btf",
            "synth",
            "--pattern",
            "rib",
            "--size",
            "4",
            "-o",
        ]
        .iter()
        .map(|s| s.to_string())
        .chain([dir.display().to_string()]);
        let parsed = Line::try_parse_from(line)
            .map_err(|e| Error::InvalidArgument(format!("validate: btf synth: {e}")))?;
        parsed.command.run(&Gpu {
            device: Default::default(),
            validate: false,
            validation: None,
        })?;
    }
    Ok(dir)
}

/// Runs `case` in this process under `features`, with `gpu`'s device.
pub fn run_case(case: &Case, features: FeatureSet, gpu: &Gpu, root: &Path) -> Result<Row> {
    use clap::Parser;
    let suffix = match features {
        FeatureSet::Standard => "",
        FeatureSet::GpuAssisted => "-gpu-assisted",
    };
    let out = root.join(format!("{}{suffix}", case.name));
    if out.exists() {
        return Err(Error::InvalidArgument(format!(
            "validate: {} exists; give an --out folder validate has not used",
            out.display()
        )));
    }
    let parsed = match case.library {
        Some(_) => None,
        None => {
            let btf = btf_dir(root)?;
            let line = command_line(case, &out, &btf);
            Some(Line::try_parse_from(&line).map_err(|e| {
                Error::InvalidArgument(format!(
                    "validate case {}: {}: {e}",
                    case.name,
                    line.join(" ")
                ))
            })?)
        }
    };
    let tee = MessageSink::new(Vec::new());
    let gpu = Gpu {
        device: gpu.device.clone(),
        validate: true,
        validation: Some(features.config(tee.clone())),
    };
    let before = dispatched_pipelines();
    let t = Instant::now();
    let result = match (&parsed, case.library) {
        (Some(p), _) => p.command.run(&gpu),
        (None, Some(f)) => f(&gpu),
        (None, None) => Ok(()),
    };
    let seconds = t.elapsed().as_secs_f64();
    let after = dispatched_pipelines();
    let pipelines: Vec<String> = after
        .iter()
        .filter(|(name, n)| before.get(*name) != Some(*n))
        .map(|(name, _)| name.clone())
        .collect();
    Ok(row(
        case.name,
        features,
        pipelines,
        &tee.take(),
        result,
        seconds,
    ))
}

/// A row from what a case raised and how it ended.
fn row(
    case: &str,
    features: FeatureSet,
    pipelines: Vec<String>,
    raised: &[ValidationMessage],
    result: Result<()>,
    seconds: f64,
) -> Row {
    let mut allowed = BTreeMap::new();
    let mut messages = Vec::new();
    let mut layer = Vec::new();
    for m in raised {
        if let Some((_, name, _)) = ALLOWED.iter().find(|(id, _, _)| *id == m.id_number) {
            *allowed.entry(name.to_string()).or_insert(0) += 1;
        } else if features == FeatureSet::GpuAssisted && m.id_name == LAYER_PROBLEM {
            layer.push(m.to_string());
        } else {
            messages.push(m.to_string());
        }
    }
    let status = if !messages.is_empty() {
        Status::Messages
    } else if !layer.is_empty() {
        Status::LayerProblem(format!(
            "layer problem, not a vkshade message: {LAYER_PROBLEM} ({} time(s))",
            layer.len()
        ))
    } else {
        match result {
            Ok(()) => Status::Clean,
            Err(e) => Status::Failed(e.to_string()),
        }
    };
    Row {
        case: case.to_string(),
        features,
        pipelines,
        messages,
        allowed,
        seconds,
        status,
    }
}

/// The line a GPU-assisted child prints its row on.
const ROW_PREFIX: &str = "vkshade-validate-row: ";

/// Runs a GPU-assisted row in a child process of `exe` with a time limit.
fn run_child(case: &Case, cfg: &ValidateConfig, exe: &Path, gpu: &Gpu) -> Result<Row> {
    use std::io::Read;
    let device = match &gpu.device {
        crate::gpu::DeviceSelector::Best => "best".to_string(),
        crate::gpu::DeviceSelector::Index(i) => i.to_string(),
        crate::gpu::DeviceSelector::Name(n) => n.clone(),
    };
    let t = Instant::now();
    let mut child = std::process::Command::new(exe)
        .args([
            "--device",
            &device,
            "validate",
            "--gpu-assisted-child",
            case.name,
        ])
        .arg("--out")
        .arg(&cfg.out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .map_err(|e| Error::io(exe, e))?;
    let mut stdout = child.stdout.take();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(o) = stdout.as_mut() {
            let _ = o.read_to_string(&mut s);
        }
        s
    });
    let timed_out = loop {
        match child.try_wait().map_err(|e| Error::io(exe, e))? {
            Some(_) => break false,
            None if t.elapsed() > cfg.gpu_assisted_timeout => {
                let _ = child.kill();
                let _ = child.wait();
                break true;
            }
            None => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    let seconds = t.elapsed().as_secs_f64();
    let text = reader.join().unwrap_or_default();
    let parsed = text
        .lines()
        .find_map(|l| l.strip_prefix(ROW_PREFIX))
        .and_then(|j| serde_json::from_str::<ChildRow>(j).ok());
    Ok(match parsed {
        Some(c) => Row {
            case: case.name.to_string(),
            features: FeatureSet::GpuAssisted,
            pipelines: c.pipelines,
            messages: c.messages,
            allowed: c.allowed,
            seconds,
            status: c.status.into_status(),
        },
        None if timed_out => Row {
            case: case.name.to_string(),
            features: FeatureSet::GpuAssisted,
            pipelines: Vec::new(),
            messages: Vec::new(),
            allowed: BTreeMap::new(),
            seconds,
            status: Status::LayerProblem(format!(
                "layer problem, not a vkshade message: no progress in {:.0} s under \
                 GPU-assisted validation (the layer's semaphore-state hang on this device, \
                 which it reports as {LAYER_PROBLEM} when it gives up)",
                cfg.gpu_assisted_timeout.as_secs_f64()
            )),
        },
        None => Row {
            case: case.name.to_string(),
            features: FeatureSet::GpuAssisted,
            pipelines: Vec::new(),
            messages: Vec::new(),
            allowed: BTreeMap::new(),
            seconds,
            status: Status::Failed(format!(
                "the GPU-assisted child ({}) ended without a result",
                exe.display()
            )),
        },
    })
}

/// A row as a child prints it (statuses as text: the enum's serde form is one-way).
#[derive(serde::Deserialize, Serialize)]
struct ChildRow {
    pipelines: Vec<String>,
    messages: Vec<String>,
    allowed: BTreeMap<String, usize>,
    status: (String, String),
}

impl ChildRow {
    fn of(r: &Row) -> ChildRow {
        let status = match &r.status {
            Status::Clean => ("clean".into(), String::new()),
            Status::Messages => ("messages".into(), String::new()),
            Status::Failed(e) => ("failed".into(), e.clone()),
            Status::LayerProblem(e) => ("layer".into(), e.clone()),
        };
        ChildRow {
            pipelines: r.pipelines.clone(),
            messages: r.messages.clone(),
            allowed: r.allowed.clone(),
            status,
        }
    }
}

trait IntoStatus {
    fn into_status(self) -> Status;
}

impl IntoStatus for (String, String) {
    fn into_status(self) -> Status {
        match self.0.as_str() {
            "clean" => Status::Clean,
            "messages" => Status::Messages,
            "layer" => Status::LayerProblem(self.1),
            _ => Status::Failed(self.1),
        }
    }
}

/// Runs the selected cases (standard features, then GPU-assisted where it completes) and
/// the coverage check.
pub fn run(
    cfg: &ValidateConfig,
    gpu: &Gpu,
    progress: &mut dyn FnMut(&str),
) -> Result<ValidateReport> {
    let cases = select(&cfg.cases)?;
    std::fs::create_dir_all(&cfg.out).map_err(|e| Error::io(&cfg.out, e))?;
    let t = Instant::now();
    let mut rows = Vec::new();
    for case in &cases {
        progress(&format!(
            "validate: {} ({})",
            case.name,
            FeatureSet::Standard.label()
        ));
        let r = run_case(case, FeatureSet::Standard, gpu, &cfg.out)?;
        progress(&format!("validate: {}: {}", case.name, status_text(&r)));
        rows.push(r);
    }
    if let Some(exe) = &cfg.gpu_assisted_exe {
        let mut stop: Option<String> = None;
        for case in &cases {
            if let Some(why) = &stop {
                rows.push(Row {
                    case: case.name.to_string(),
                    features: FeatureSet::GpuAssisted,
                    pipelines: Vec::new(),
                    messages: Vec::new(),
                    allowed: BTreeMap::new(),
                    seconds: 0.0,
                    status: Status::LayerProblem(format!("not run: {why}")),
                });
                continue;
            }
            progress(&format!(
                "validate: {} ({})",
                case.name,
                FeatureSet::GpuAssisted.label()
            ));
            let r = run_child(case, cfg, exe, gpu)?;
            progress(&format!("validate: {}: {}", case.name, status_text(&r)));
            if let Status::LayerProblem(_) = r.status {
                stop = Some(format!(
                    "GPU-assisted validation did not complete on this device (case {}): \
                     layer problem, not a vkshade message",
                    case.name
                ));
            }
            rows.push(r);
        }
    }
    let coverage = cfg.coverage && cfg.cases.is_empty();
    let not_exercised = if coverage {
        let ran = dispatched_pipelines();
        crate::shaders::EMBEDDED
            .iter()
            .map(|(n, _)| *n)
            .filter(|n| !n.starts_with("test/") && !ran.contains_key(*n))
            .filter(|n| !NOT_IN_A_CASE.iter().any(|(m, _)| m == n))
            .map(str::to_string)
            .collect()
    } else {
        Vec::new()
    };
    Ok(ValidateReport {
        rows,
        not_exercised,
        coverage_checked: coverage,
        seconds: t.elapsed().as_secs_f64(),
    })
}

fn status_text(r: &Row) -> String {
    match &r.status {
        Status::Clean => "clean".into(),
        Status::Messages => format!("{} message(s)", r.messages.len()),
        Status::Failed(e) => format!("FAILED: {e}"),
        Status::LayerProblem(e) => e.clone(),
    }
}

/// The table `vkshade validate` prints.
pub fn table(r: &ValidateReport) -> String {
    let mut s = format!(
        "{:<18} {:<38} {:>8} {:>7} {:>8}  {:<}\n",
        "case", "features", "messages", "allowed", "time s", "status / pipelines"
    );
    for row in &r.rows {
        let allowed: usize = row.allowed.values().sum();
        s.push_str(&format!(
            "{:<18} {:<38} {:>8} {:>7} {:>8.1}  {}\n",
            row.case,
            row.features.label(),
            row.messages.len(),
            allowed,
            row.seconds,
            status_text(row)
        ));
        if !row.pipelines.is_empty() {
            s.push_str(&format!(
                "{:<18} pipelines: {}\n",
                "",
                row.pipelines.join(" ")
            ));
        }
        for m in &row.messages {
            s.push_str(&format!("{:<18} {m}\n", ""));
        }
        for (name, n) in &row.allowed {
            s.push_str(&format!("{:<18} allowed: {name} x{n}\n", ""));
        }
    }
    if r.coverage_checked {
        if r.not_exercised.is_empty() {
            let ran = dispatched_pipelines();
            let shipped: Vec<&str> = crate::shaders::EMBEDDED
                .iter()
                .map(|(n, _)| *n)
                .filter(|n| !n.starts_with("test/"))
                .collect();
            s.push_str(&format!(
                "coverage: {} of the {} spv/ modules (test/ fixtures aside) dispatched by the \
                 cases\n",
                shipped.iter().filter(|n| ran.contains_key(**n)).count(),
                shipped.len()
            ));
            for (m, why) in NOT_IN_A_CASE {
                s.push_str(&format!("coverage: {m} in no case: {why}\n"));
            }
        } else {
            s.push_str(&format!(
                "coverage: NOT dispatched by any case: {}\n",
                r.not_exercised.join(", ")
            ));
        }
    } else {
        s.push_str("coverage: not checked (a subset of the cases ran)\n");
    }
    s
}

/// `vkshade validate`'s arguments.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Cases to run, comma-separated (default: all, with the check that every spv/ module
    /// ran).
    #[arg(long, value_delimiter = ',')]
    pub cases: Vec<String>,
    /// Folder for the cases' outputs (must not exist yet, or be empty).
    #[arg(long, default_value = "out/validate")]
    pub out: PathBuf,
    /// Seconds a GPU-assisted row may run before it is reported as the layer's hang (a
    /// case that completes under it takes a few seconds: the cases are small).
    #[arg(long, default_value_t = 15.0)]
    pub gpu_assisted_timeout: f64,
    /// Leave out the GPU-assisted rows.
    #[arg(long)]
    pub no_gpu_assisted: bool,
    /// Internal: run one case under GPU-assisted validation and print its row.
    #[arg(long, hide = true)]
    pub gpu_assisted_child: Option<String>,
    /// Also write the table as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

impl Args {
    /// Runs the cases, prints the table; an error when any row has messages or failed, or
    /// a module of spv/ ran in no case.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        if let Some(name) = &self.gpu_assisted_child {
            let case = select(std::slice::from_ref(name))?[0];
            let r = run_case(case, FeatureSet::GpuAssisted, gpu, &self.out)?;
            let json = serde_json::to_string(&ChildRow::of(&r))
                .map_err(|e| Error::InvalidArgument(format!("row JSON: {e}")))?;
            println!("{ROW_PREFIX}{json}");
            return Ok(());
        }
        if !(self.gpu_assisted_timeout > 0.0 && self.gpu_assisted_timeout.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "--gpu-assisted-timeout must be a positive number of seconds, not {}",
                self.gpu_assisted_timeout
            )));
        }
        if self.out.exists()
            && std::fs::read_dir(&self.out)
                .map_err(|e| Error::io(&self.out, e))?
                .next()
                .is_some()
        {
            return Err(Error::InvalidArgument(format!(
                "--out {} is not empty; validate writes into a fresh or empty folder",
                self.out.display()
            )));
        }
        let exe = if self.no_gpu_assisted {
            None
        } else {
            Some(std::env::current_exe().map_err(|e| Error::io("current executable", e))?)
        };
        let cfg = ValidateConfig {
            cases: self.cases.clone(),
            out: self.out.clone(),
            gpu_assisted_exe: exe,
            gpu_assisted_timeout: Duration::from_secs_f64(self.gpu_assisted_timeout),
            coverage: true,
        };
        let report = run(&cfg, gpu, &mut |l| super::progress(l))?;
        print!("{}", table(&report));
        if let Some(path) = &self.json {
            crate::io::write_json(path, &report)?;
        }
        println!("validate: {:.1} s", report.seconds);
        if report.passed() {
            Ok(())
        } else {
            Err(Error::InvalidArgument(
                "validate: messages, failures or pipelines not exercised (see the table)".into(),
            ))
        }
    }
}

/// The kernels `bench soak` drives.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SoakKernel {
    /// Sphere-tree AO on Testwuson (skinning + occlusion), its Run animation.
    Ao,
    /// The character frame (pose, AO, environment, G-buffer, skin, cloth, compose) on
    /// BCN_Epileptic at 96 x 96, atlas 64.
    Frame,
}

/// `vkshade bench soak`'s arguments.
#[derive(clap::Args, Clone, Debug)]
pub struct SoakArgs {
    /// Frames to run (default: 10,000 for ao, 2,000 for frame; see the README for times).
    #[arg(long)]
    pub frames: Option<usize>,
    /// The kernel.
    #[arg(long, value_enum, default_value = "ao")]
    pub kernel: SoakKernel,
    /// Folder for soak.csv, soak.png and soak.json.
    #[arg(long, default_value = "out/soak")]
    pub out: PathBuf,
}

impl SoakArgs {
    /// Runs the soak under validation (whatever --validate says), writes the curve, and
    /// fails on growth, any message or a leak at shutdown.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        let frames = self.frames.unwrap_or(match self.kernel {
            SoakKernel::Ao => 10_000,
            SoakKernel::Frame => 2_000,
        });
        let gpu = Gpu {
            device: gpu.device.clone(),
            validate: true,
            validation: gpu.validation.clone(),
        };
        crate::io::check_writable(&self.out.join("soak.csv"))?;
        let report = soak_run(&gpu, self.kernel, &SoakConfig::new(frames), &mut |l| {
            super::progress(l)
        })?;
        write_soak(&self.out, &report)?;
        let v = &report.verdict;
        println!(
            "soak {}: {} frames in {:.1} s ({:.2} ms/frame); device {} B in use at the baseline, \
             {} B max in the last quarter; RSS {:.1} MiB at the baseline, {:.1} MiB max in the \
             last quarter (allowed {:.1}); 0 validation messages, no leaks; wrote {}",
            report.kernel,
            report.config.frames,
            report.wall_s,
            report.ms_per_frame,
            v.baseline.device_used_bytes,
            v.last_quarter_device_used,
            v.baseline.rss_bytes as f64 / (1 << 20) as f64,
            v.last_quarter_rss as f64 / (1 << 20) as f64,
            v.rss_allowed as f64 / (1 << 20) as f64,
            self.out.display()
        );
        if v.problems.is_empty() {
            Ok(())
        } else {
            Err(Error::InvalidArgument(format!(
                "soak: memory not flat: {}",
                v.problems.join("; ")
            )))
        }
    }
}

/// Writes DIR/soak.csv, DIR/soak.json and (with plots) DIR/soak.png.
pub fn write_soak(dir: &Path, report: &SoakReport) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::io::write_atomic(&dir.join("soak.csv"), soak::csv(report).as_bytes())?;
    crate::io::write_json(&dir.join("soak.json"), report)?;
    if cfg!(feature = "plots") {
        crate::bench::plot::draw(&dir.join("soak.png"), &soak::panels(report))?;
    }
    Ok(())
}

/// Runs a soak of `kernel` on a context made from `gpu` (validated), shuts it down and
/// fails on any validation message or leak; returns the curve and its verdict.
pub fn soak_run(
    gpu: &Gpu,
    kernel: SoakKernel,
    cfg: &SoakConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SoakReport> {
    let features = crate::gpu::Features {
        buffer_int64_atomics: kernel == SoakKernel::Frame,
        ..Default::default()
    };
    let ctx = gpu.context_with(features)?;
    let result = match kernel {
        SoakKernel::Ao => soak_ao(&ctx, cfg, progress),
        SoakKernel::Frame => soak_frame(&ctx, cfg, progress),
    };
    let messages = ctx.shutdown()?;
    if !messages.is_empty() {
        for m in &messages {
            eprintln!("{m}");
        }
        return Err(Error::InvalidArgument(format!(
            "soak: {} validation message(s) or leak report(s) (listed above)",
            messages.len()
        )));
    }
    result
}

fn soak_ao(
    ctx: &crate::gpu::Context,
    cfg: &SoakConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SoakReport> {
    use crate::kernels::ao::{AoKernel, AoParams, Prepared};
    use crate::scene::spheretree::{BuildConfig, SphereTree};
    let path = crate::shaders::source_root().join("data/testwuson.glb");
    let c = crate::scene::load(&path)?;
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default())?;
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len())?;
    let anim = c.animation("Run")?;
    let mut setup = ctx.recorder("soak ao setup")?;
    let kernel = AoKernel::new(&mut setup, &prep, AoParams::default())?;
    setup.submit_and_wait()?;
    let n = prep_vertices(&c);
    let mut step = |i: usize| -> Result<()> {
        let t = anim.duration * (i % 97) as f32 / 97.0;
        let m = c.rig.skinning_matrices(Some(anim), t);
        let mut rec = ctx.recorder("soak ao frame")?;
        kernel.record(&mut rec, &m)?;
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let d = rb.data()?;
        if d.visibility.len() != n || d.visibility.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Err(Error::InvalidArgument(format!(
                "soak ao frame {i}: {} visibilities for {n} vertices, or one outside [0, 1]",
                d.visibility.len()
            )));
        }
        Ok(())
    };
    soak::run(ctx, "ao (Testwuson, Run)", cfg, &mut step, progress)
}

fn prep_vertices(c: &crate::scene::Character) -> usize {
    c.mesh.positions.len()
}

fn soak_frame(
    ctx: &crate::gpu::Context,
    cfg: &SoakConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SoakReport> {
    use crate::frame::{CharacterFrame, FrameConfig, FrameInput};
    let fc = FrameConfig {
        mesh: crate::shaders::source_root().join("data/bcn_epileptic.glb"),
        size: [96, 96],
        atlas: 64,
        samples: 4,
        btf_tile: 8,
        ..FrameConfig::default()
    };
    let frame = CharacterFrame::new(ctx, &fc, &mut |_| {})?;
    let duration = frame.animation().duration;
    let mut step = |i: usize| -> Result<()> {
        let input = FrameInput {
            time: duration * (i % 97) as f32 / 97.0,
            env_rotation: glam::Mat3::from_rotation_y(i as f32 * 0.1),
        };
        let mut rec = ctx.recorder("soak frame")?;
        frame.record(&mut rec, &input)?;
        let rb = frame.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let out = frame.collect(&rb)?;
        if out.hdr.iter().any(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(Error::InvalidArgument(format!(
                "soak frame {i}: a non-finite pixel"
            )));
        }
        Ok(())
    };
    soak::run(
        ctx,
        "character frame (BCN_Epileptic 96x96)",
        cfg,
        &mut step,
        progress,
    )
}
