//! The `vkshade` command-line tool: a thin layer over the library. Each command's arguments,
//! run and printed summary live in its `vkshade::app` module; this file parses and dispatches.

use clap::{Parser, Subcommand};
use std::process::ExitCode;
use vkshade::app;

#[derive(Parser)]
#[command(
    name = "vkshade",
    version,
    about = "Real-time appearance kernels as hand-written Vulkan compute pipelines",
    long_about = "Real-time appearance kernels as hand-written Vulkan compute pipelines.\n\n\
        Runs on the best Vulkan device present (a discrete GPU before lavapipe); pick another \
        with --device. With --validate, the Khronos validation layer runs with synchronization \
        validation, and any message it raises makes the command fail."
)]
struct Cli {
    // The global options (--device, --validate): every command makes its context from them.
    #[command(flatten)]
    gpu: app::Gpu,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List Vulkan devices, the limits that matter to the kernels, and whether the
    /// validation layer is installed.
    Info(app::info::Args),
    /// Benchmarks (median GPU time from timestamp queries).
    #[command(subcommand)]
    Bench(app::bench::Command),
    /// Regenerate or check the committed SPIR-V in spv/ against the GLSL in glsl/.
    #[command(subcommand)]
    Shaders(app::shaders::Command),
    /// Ambient occlusion of a skinned character from a sphere tree, per frame of an
    /// animation: DIR/ao_NNNN.ply (posed mesh, per-vertex `ao` = visibility, 1 = unoccluded),
    /// DIR/ao_NNNN.png (with --reference: result | truth | error), its linear twin
    /// DIR/ao_NNNN.exr, and DIR/report.json.
    Ao(app::ao::Args),
    /// The main demo: the character frame on the built-in character (BCN_Epileptic's
    /// Epileptisch animation, 24 frames: skin, cloth, ambient occlusion, a turning
    /// environment), pictures in out/demo/.
    Demo,
    /// The character frame: an animated glTF character's skin and cloth rendered per frame
    /// on the GPU: DIR/frame_NNNN.png and .exr, DIR/animation.png (animated PNG),
    /// DIR/contact_sheet.png, DIR/timing.png (GPU ms per pass), DIR/report.json.
    Frame(app::frame::Args),
    /// Environment lighting by spherical Gaussians (SRBFs) rotated on the GPU with
    /// precomputed per-vertex transfer.
    #[command(subcommand)]
    Srbf(app::srbf::Command),
    /// Bidirectional texture functions (cloth): synthesise a BTF, interpolate one tile, render
    /// a cloth-covered object through 2D array textures and parabolic-map lookup.
    #[command(subcommand)]
    Btf(app::btf::Command),
    /// Texture-space subsurface diffusion (skin): DIR/irradiance.exr, DIR/diffuse.exr
    /// (texture space, linear float; B = int E Rd dA before the exit Fresnel and 1/pi),
    /// DIR/render.png (SSS | Lambertian), with --reference DIR/reference.png, and
    /// DIR/report.json.
    Sss(app::sss::Args),
    /// Environment light on a moving character: SG lobes of an HDR map, turned per frame,
    /// shadowed per vertex by the character's sphere tree; with --reference, the error vs the
    /// ray-traced truth and the AO-weighted floor, and DIR/env_NNNN.ply (irradiance r g b).
    Env(app::env::Args),
    /// Sphere trees.
    #[command(subcommand)]
    Spheretree(app::scene::TreeCommand),
    /// Meshes.
    #[command(subcommand)]
    Mesh(app::scene::MeshCommand),
    /// Every pipeline vkshade ships, each on a small input, under every validation feature
    /// the installed layer offers (core, synchronization, best practices, GPU-assisted where
    /// it completes): a table per case, a non-zero exit on any message or on a spv/ module
    /// no case ran.
    Validate(app::validate::Args),
}

/// Prints the library's warnings to stderr (`warning: ...`): e.g. a damaged cache file that
/// is set aside and recomputed (`srbf shade`), or an environment map's small negative samples
/// set to 0. Nothing below the warning level.
struct StderrLog;

impl log::Log for StderrLog {
    fn enabled(&self, meta: &log::Metadata) -> bool {
        meta.level() <= log::Level::Warn
    }

    fn log(&self, record: &log::Record) {
        if self.enabled(record.metadata()) {
            let level = match record.level() {
                log::Level::Error => "error",
                _ => "warning",
            };
            eprintln!("{level}: {}", record.args());
        }
    }

    fn flush(&self) {}
}

static LOG: StderrLog = StderrLog;

fn main() -> ExitCode {
    // Only fails when a logger is already set, which nothing here does before this line.
    if log::set_logger(&LOG).is_ok() {
        log::set_max_level(log::LevelFilter::Warn);
    }
    // A third-party decoder's panic that vkshade catches and reports as an error naming the
    // file (vkshade::io::panic_scope) is not printed; any other panic is, as before.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !vkshade::io::panic_scope::active() {
            default_hook(info)
        }
    }));
    let cli = Cli::parse();
    let gpu = &cli.gpu;
    let result = match &cli.command {
        Command::Info(a) => a.run(),
        Command::Bench(c) => c.run(gpu),
        Command::Shaders(c) => c.run(),
        Command::Ao(a) => a.run(gpu),
        Command::Demo => app::frame::demo(gpu),
        Command::Frame(a) => a.run(gpu),
        Command::Srbf(c) => c.run(gpu),
        Command::Btf(c) => c.run(gpu),
        Command::Sss(a) => a.run(gpu),
        Command::Env(a) => a.run(gpu),
        Command::Spheretree(c) => c.run(),
        Command::Mesh(c) => c.run(),
        Command::Validate(a) => a.run(gpu),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
