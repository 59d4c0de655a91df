//! The `vkshade` command-line tool: a thin layer over the library.

use clap::{Args, FromArgMatches, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use vkshade::bench::{self, BenchConfig};
use vkshade::gpu::{Context, ContextDesc, DeviceSelector, ValidationConfig};
use vkshade::{Error, Result};

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
    #[command(flatten)]
    global: Global,
    #[command(subcommand)]
    command: Command,
}

#[derive(Args)]
struct Global {
    /// Device to use: an index from `vkshade info`, a substring of its name, or "best".
    #[arg(long, global = true, default_value = "best")]
    device: DeviceSelector,
    /// Run under the Khronos validation layer (synchronization validation on); any
    /// validation message makes the command fail.
    #[arg(long, global = true)]
    validate: bool,
}

#[derive(Subcommand)]
enum Command {
    /// List Vulkan devices, the limits that matter to the kernels, and whether the
    /// validation layer is installed.
    Info {
        /// Also write the report as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Benchmarks (median GPU time from timestamp queries).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Regenerate or check the committed SPIR-V in spv/ against the GLSL in glsl/.
    #[command(subcommand)]
    Shaders(ShaderCommand),
    /// Ambient occlusion of a skinned character from a sphere tree, per frame of an
    /// animation: DIR/ao_NNNN.ply (posed mesh, per-vertex `ao` = visibility, 1 = unoccluded),
    /// DIR/ao_NNNN.png (with --reference: result | truth | error), its linear twin
    /// DIR/ao_NNNN.exr, and DIR/report.json.
    Ao(AoArgs),
    /// The main demo: `ao` on the built-in default (Testwuson's Run animation, 8 frames,
    /// compared with the ray-traced mesh), pictures in out/ao/.
    Demo,
    /// Environment lighting by spherical Gaussians (SRBFs) rotated on the GPU with
    /// precomputed per-vertex transfer.
    #[command(subcommand)]
    Srbf(SrbfCommand),
    /// Texture-space subsurface diffusion (skin): DIR/irradiance.exr, DIR/diffuse.exr
    /// (texture space, linear float; B = int E Rd dA before the exit Fresnel and 1/pi),
    /// DIR/render.png (SSS | Lambertian), with --reference DIR/reference.png, and
    /// DIR/report.json.
    Sss(SssArgs),
    /// Sphere trees.
    #[command(subcommand)]
    Spheretree(TreeCommand),
    /// Meshes.
    #[command(subcommand)]
    Mesh(MeshCommand),
}

#[derive(Args)]
struct AoArgs {
    /// Character (.glb/.gltf with skin and animations) or static mesh (.obj .ply .off).
    #[arg(long, default_value = vkshade::kernels::ao::DEFAULT_MESH)]
    mesh: PathBuf,
    /// Animation to play (default: Run for the built-in character, else the first that moves).
    #[arg(long)]
    anim: Option<String>,
    /// Frames, evenly spaced over the animation.
    #[arg(long, default_value_t = 8)]
    frames: usize,
    /// Use this .sph sphere tree (Dublin toolkit format) instead of building one.
    #[arg(long)]
    tree: Option<PathBuf>,
    /// Refine a tree node when size / distance > tau (0 < tau <= 1; smaller = finer cut).
    #[arg(long, default_value_t = 0.8)]
    tau: f32,
    /// A node's size for refinement: `extent` (reach of its skinned leaves) or `radius`.
    #[arg(long, default_value = "extent")]
    refine: vkshade::kernels::ao::Refine,
    /// Per-sphere occlusion: `table` (2D lookup) or `exact` (closed form).
    #[arg(long, default_value = "table")]
    occlusion: vkshade::kernels::ao::Occlusion,
    /// Overlap handling: `mask` (cone-mask union), `product`, or `sum`.
    #[arg(long, default_value = "mask")]
    blend: vkshade::kernels::ao::Blend,
    /// The published method alone: no static correction baked in the bind pose.
    #[arg(long)]
    no_correction: bool,
    /// A receiver inside a leaf sphere clamps h to 1 instead of leaving that sphere out.
    #[arg(long)]
    clamp_inside: bool,
    /// Compare every frame with the ray-traced mesh (MAE, RMSE, p95, max; error decomposition);
    /// pictures become result | truth | error side by side.
    #[arg(long)]
    reference: bool,
    /// Error at the top of the heat map in the --reference pictures (larger errors saturate).
    #[arg(long, default_value_t = 0.2)]
    error_scale: f32,
    /// Frames submitted before the oldest is waited for (frames in flight).
    #[arg(long, default_value_t = 2)]
    in_flight: usize,
    /// Rays per vertex of the ground truth.
    #[arg(long, default_value_t = 4096)]
    rays: usize,
    /// Rays per vertex of the bind-pose bake of the static correction.
    #[arg(long, default_value_t = 4096)]
    correction_rays: usize,
    #[command(flatten)]
    tree_opts: TreeOpts,
    /// Output directory.
    #[arg(long, default_value = "out/ao")]
    out: PathBuf,
}

#[derive(Subcommand)]
enum SrbfCommand {
    /// Fit spherical Gaussians to an equirectangular HDR environment (EXR or .hdr); reports
    /// the fit error for 8, 16, ... up to --lobes lobes and writes the largest fit as JSON.
    Fit {
        #[arg(long, default_value = vkshade::app::srbf::DEFAULT_ENV)]
        env: PathBuf,
        #[arg(long, default_value_t = 64)]
        lobes: usize,
        /// Width of the downsampled map the lobes are fitted to.
        #[arg(long, default_value_t = 128)]
        fit_width: u32,
        #[arg(short = 'o', long, default_value = "out/srbf/fit.json")]
        out: PathBuf,
    },
    /// Shade a mesh under a rotated environment: per frame DIR/shade_NNNN.ply (per-vertex
    /// linear RGB radiance r, g, b) and DIR/shade_NNNN.png (with --reference: result |
    /// brute-force truth | error), and DIR/report.json.
    Shade(SrbfShadeArgs),
}

#[derive(Args)]
struct SrbfShadeArgs {
    /// Mesh (.obj .ply .off .glb/.gltf; a skinned mesh is shaded in its bind pose).
    #[arg(long, default_value = vkshade::app::srbf::DEFAULT_MESH)]
    mesh: PathBuf,
    /// Equirectangular environment (EXR, including DWAB, or Radiance .hdr).
    #[arg(long, default_value = vkshade::app::srbf::DEFAULT_ENV)]
    env: PathBuf,
    #[arg(long, default_value_t = 64)]
    lobes: usize,
    /// Transfer basis functions (spherical Gaussians on a Fibonacci lattice).
    #[arg(long, default_value_t = 256)]
    basis: usize,
    /// Rotate the environment, e.g. y:30 (L_R(w) = L(R^-1 w)); with --frames, the start of a
    /// spin about that axis.
    #[arg(long)]
    rotate: Option<vkshade::app::srbf::AxisAngle>,
    /// Frames of a continuous 360-degree spin (about +Y, or --rotate's axis).
    #[arg(long, default_value_t = 1)]
    frames: usize,
    /// Diffuse albedo R,G,B (default 1,1,1).
    #[arg(long, value_delimiter = ',', num_args = 3, default_values_t = [1.0f32, 1.0, 1.0])]
    albedo: Vec<f32>,
    /// Compare each frame with the brute-force integration of the rotated map (f64).
    #[arg(long)]
    reference: bool,
    /// Width of the map whose texel directions carry the transfer and the ground truth.
    #[arg(long, default_value_t = 64)]
    directions: u32,
    #[arg(long, default_value_t = 2)]
    in_flight: usize,
    #[arg(long, default_value = "out/srbf")]
    out: PathBuf,
}

#[derive(Args)]
struct SssArgs {
    /// Mesh with UVs (.glb/.gltf .obj .ply; a skinned mesh is used in its bind pose).
    #[arg(long, default_value = vkshade::app::sss::DEFAULT_MESH)]
    mesh: PathBuf,
    /// Use only this glTF mesh (node or mesh name); `--part ''` uses the whole file.
    #[arg(long, default_value = vkshade::app::sss::DEFAULT_PART)]
    part: String,
    /// Millimetres per model unit (scattering coefficients are per mm).
    #[arg(long, default_value_t = 1.0)]
    mm_per_unit: f64,
    /// dir:X,Y,Z[:E] (arriving from X,Y,Z; irradiance E, default 1) or point:X,Y,Z:I
    /// (position in model units, intensity I). Repeatable.
    #[arg(long = "light")]
    lights: Vec<String>,
    /// dipole (tabulated inverse CDF) or burley (analytic inverse CDF).
    #[arg(long, default_value = "dipole")]
    profile: String,
    /// skin1 or skin2 (Jensen 2001), or custom with --sigma-a and --sigma-s.
    #[arg(long, default_value = "skin1")]
    material: String,
    /// Absorption coefficients R,G,B per mm (custom material).
    #[arg(long, value_delimiter = ',', num_args = 3)]
    sigma_a: Option<Vec<f64>>,
    /// Reduced scattering coefficients R,G,B per mm (custom material).
    #[arg(long, value_delimiter = ',', num_args = 3)]
    sigma_s: Option<Vec<f64>>,
    /// Relative index of refraction (default 1.3).
    #[arg(long, default_value_t = vkshade::kernels::sss::profile::DEFAULT_ETA)]
    eta: f64,
    /// Fraction of each channel's reflectance inside its sampling radius.
    #[arg(long, default_value_t = vkshade::kernels::sss::profile::DEFAULT_ENERGY)]
    energy: f64,
    /// Samples per texel per channel.
    #[arg(long, default_value_t = 32)]
    samples: u32,
    /// Texture size (N x N texels).
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Frames to run: spread over --anim (posed and re-rasterised each frame), or the same
    /// frame repeated; timings are medians, the last frame is written.
    #[arg(long, default_value_t = 1)]
    frames: usize,
    /// Animation of the mesh's skeleton (glTF; name or unique substring).
    #[arg(long)]
    anim: Option<String>,
    /// Compare with the brute-force ground truth (f64, every covered texel).
    #[arg(long)]
    reference: bool,
    #[arg(long, default_value = "out/sss")]
    out: PathBuf,
}

#[derive(Args)]
struct TreeOpts {
    /// Levels below the root when building a tree (3 gives 8/64/512 spheres).
    #[arg(long, default_value_t = 3)]
    depth: u32,
    /// Branch factor when building a tree.
    #[arg(long, default_value_t = 8)]
    branch: u32,
    /// Sphere fit: `volume` (same volume as the cluster) or `bounding` (covers it).
    #[arg(long, default_value = "volume")]
    fit: vkshade::scene::spheretree::Fit,
    /// Interior samples (voxels) to cluster.
    #[arg(long, default_value_t = 200_000)]
    samples: usize,
}

impl TreeOpts {
    fn config(&self) -> vkshade::scene::spheretree::BuildConfig {
        vkshade::scene::spheretree::BuildConfig {
            depth: self.depth,
            branch: self.branch,
            fit: self.fit,
            samples: self.samples,
            ..Default::default()
        }
    }
}

#[derive(Subcommand)]
enum TreeCommand {
    /// Build a sphere tree for a mesh (bind pose) and report how tightly each level fits.
    Build {
        mesh: PathBuf,
        /// Output .sph file.
        #[arg(short, long)]
        out: PathBuf,
        #[command(flatten)]
        opts: TreeOpts,
        /// Also write the fit report as JSON.
        #[arg(long)]
        report: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum MeshCommand {
    /// Load a mesh, validate it, and report what was found and repaired.
    Info { mesh: PathBuf },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Device peak: f32 FMA throughput (GFLOP/s) and streaming bandwidth (GB/s), each grown
    /// until one submission takes --min-ms; the roofline the kernels are judged against.
    Peak {
        #[command(flatten)]
        opts: BenchOpts,
    },
    /// Sphere-tree AO: sweeps vertex count (subdivision), sphere count (tree depth) and the
    /// refinement threshold tau (error against the ray-traced mesh vs time); reports ms per
    /// frame, spheres per vertex, GFLOP/s as a fraction of the measured FMA peak, and the
    /// speed-up over the same method on the CPU and over ray tracing, all in the same run;
    /// checks bench/targets.json.
    Ao {
        #[command(flatten)]
        opts: BenchOpts,
        /// Character to benchmark.
        #[arg(long, default_value = vkshade::kernels::ao::DEFAULT_MESH)]
        mesh: PathBuf,
        /// Animation (default: Run for the built-in character).
        #[arg(long)]
        anim: Option<String>,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
    },
    /// SRBF lighting: GPU time of rotation (`srbf lighting`) and shading (`srbf shade`)
    /// over lobes x basis size x vertices, GFLOP/s against the FMA peak measured in the same
    /// run, and the speed-up over the same method on the CPU and over brute force.
    Srbf {
        #[command(flatten)]
        opts: BenchOpts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
    },
    /// Texture-space SSS on the BCN_Epileptic head: GPU time of irradiance and diffusion
    /// over texture size x samples per texel, error against the brute-force ground truth vs
    /// time, throughput against the FMA and bandwidth peaks, and the speed-up over the same
    /// sampler on the CPU and over the brute force.
    Sss {
        #[command(flatten)]
        opts: BenchOpts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
    },
}

#[derive(Args)]
struct BenchOpts {
    /// Write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write a PNG plot of the sweeps to this file.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Timed submissions per measurement (the median is reported).
    #[arg(long, default_value_t = 10)]
    samples: usize,
    /// Untimed warm-up submissions per measurement.
    #[arg(long, default_value_t = 2)]
    warmup: usize,
    /// Grow the work until one submission takes at least this many milliseconds.
    #[arg(long, default_value_t = 100.0)]
    min_ms: f64,
}

impl BenchOpts {
    fn config(&self) -> Result<BenchConfig> {
        if !(1..=100_000).contains(&self.samples)
            || self.warmup > 100_000
            || !self.min_ms.is_finite()
            || self.min_ms <= 0.0
            || self.min_ms > 60_000.0
        {
            return Err(Error::InvalidArgument(
                "--samples must be in 1..=100000, --warmup <= 100000, --min-ms in (0, 60000]"
                    .into(),
            ));
        }
        Ok(BenchConfig {
            warmup: self.warmup,
            samples: self.samples,
            min_submit_ms: self.min_ms,
        })
    }
}

#[derive(Subcommand)]
enum ShaderCommand {
    /// Compile every glsl/**/*.comp into spv/ (rewriting only what changed).
    Build {
        /// Source tree holding glsl/ and spv/ (default: the tree vkshade was built from).
        #[arg(long)]
        root: Option<PathBuf>,
    },
    /// Fail if any spv/ module is missing, stale or orphaned.
    Check {
        #[arg(long)]
        root: Option<PathBuf>,
    },
}

fn context(g: &Global) -> Result<Context> {
    Context::new(&ContextDesc {
        device: g.device.clone(),
        validation: g.validate.then(ValidationConfig::default),
        ..ContextDesc::default()
    })
}

/// A progress line on stderr (without breaking a progress counter being drawn).
fn progress(line: &str) {
    vkshade::progress::message(&format!("  {line}"));
}

fn cmd_info(json: Option<PathBuf>) -> Result<()> {
    let sys = vkshade::gpu::enumerate_devices()?;
    println!("Vulkan loader {}", sys.loader_version);
    println!(
        "validation layer VK_LAYER_KHRONOS_validation: {}",
        if sys.validation_layer {
            "installed"
        } else {
            "NOT installed (apt-get install vulkan-validationlayers)"
        }
    );
    if sys.devices.is_empty() {
        println!("no Vulkan devices found; {}", vkshade::error::INSTALL_HINT);
    }
    for d in &sys.devices {
        let l = &d.limits;
        println!(
            "\n[{}] {} ({}), Vulkan {}, driver {}",
            d.index, d.name, d.device_type, d.api_version, d.driver
        );
        match &d.usable {
            Ok(()) => println!("    usable by vkshade: yes"),
            Err(why) => println!("    usable by vkshade: NO ({why})"),
        }
        let mib = |b: u64| format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64);
        println!(
            "    device-local memory         {}",
            mib(d.device_local_bytes)
        );
        println!(
            "    maxStorageBufferRange       {}",
            mib(l.max_storage_buffer_range)
        );
        println!(
            "    maxMemoryAllocationSize     {}",
            mib(l.max_memory_allocation_size)
        );
        println!(
            "    maxUniformBufferRange       {} B",
            l.max_uniform_buffer_range
        );
        println!(
            "    maxPushConstantsSize        {} B",
            l.max_push_constants_size
        );
        println!(
            "    maxImageDimension2D / 3D    {} / {}",
            l.max_image_dimension_2d, l.max_image_dimension_3d
        );
        println!(
            "    maxImageArrayLayers         {}",
            l.max_image_array_layers
        );
        println!(
            "    maxComputeSharedMemorySize  {} B",
            l.max_compute_shared_memory_size
        );
        println!(
            "    maxComputeWorkGroupInvocations {}",
            l.max_compute_work_group_invocations
        );
        println!(
            "    maxComputeWorkGroupSize     {:?}",
            l.max_compute_work_group_size
        );
        println!(
            "    maxComputeWorkGroupCount    {:?}",
            l.max_compute_work_group_count
        );
        println!("    subgroupSize                {}", l.subgroup_size);
        println!(
            "    timestamps                  {} valid bits, {} ns/tick",
            l.timestamp_valid_bits, l.timestamp_period_ns
        );
    }
    if let Some(path) = json {
        vkshade::io::write_json(&path, &sys)?;
        println!("\nwrote {}", path.display());
    }
    Ok(())
}

fn cmd_bench_peak(g: &Global, opts: &BenchOpts) -> Result<()> {
    let cfg = opts.config()?;
    for path in opts.json.iter().chain(&opts.plot) {
        vkshade::io::check_writable(path)?;
    }
    if opts.plot.is_some() {
        bench::plot::ensure_available()?;
    }
    let ctx = context(g)?;
    eprintln!(
        "bench peak on {} (min {} ms per submission, {} samples)",
        ctx.info().name,
        cfg.min_submit_ms,
        cfg.samples
    );
    let report = bench::peak::run(&ctx, &cfg, &mut |l| progress(l))?;
    println!("device           {}", report.machine.device);
    println!(
        "f32 FMA          {:.1} GFLOP/s (median of {}; best {:.1}); {}",
        report.fma_gflops, report.fma.gpu_ms.n, report.fma.throughput_best, report.fma.problem
    );
    println!(
        "stream bandwidth {:.2} GB/s (median of {}; best {:.2}); {}",
        report.bandwidth_gb_s,
        report.stream.gpu_ms.n,
        report.stream.throughput_best,
        report.stream.problem
    );
    if let Some(path) = &opts.json {
        vkshade::io::write_json(path, &report)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &opts.plot {
        bench::plot::draw(path, &bench::peak::panels(&report))?;
        println!("wrote {}", path.display());
    }
    finish(ctx)
}

fn cmd_bench_ao(
    g: &Global,
    opts: &BenchOpts,
    mesh: &std::path::Path,
    anim: Option<&str>,
    quick: bool,
) -> Result<()> {
    use vkshade::bench::ao::{AoBenchConfig, panels, run};
    for path in opts.json.iter().chain(&opts.plot) {
        vkshade::io::check_writable(path)?;
    }
    if opts.plot.is_some() {
        bench::plot::ensure_available()?;
    }
    let mut cfg = AoBenchConfig {
        mesh: mesh.to_path_buf(),
        bench: opts.config()?,
        ..Default::default()
    };
    cfg.bench.min_submit_ms = opts.min_ms.min(cfg.bench.min_submit_ms);
    if anim.is_some() || mesh != std::path::Path::new(vkshade::kernels::ao::DEFAULT_MESH) {
        cfg.animation = anim.map(str::to_string);
    }
    if quick {
        cfg.subdivisions = vec![0, 1];
        cfg.depths = vec![2, 3];
        cfg.taus = vec![0.3, 0.5, 0.8];
        cfg.reference_frames = 1;
        cfg.rays = 256;
        cfg.cpu_runs = 2;
    }
    let ctx = context(g)?;
    eprintln!("bench ao on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    let h = &r.headline;
    println!("device                 {}", r.machine.device);
    println!(
        "headline               {} vertices, {} spheres, tau {}: skin {:.3} ms + AO {:.3} ms (median GPU) = {:.0} fps",
        h.vertices, h.spheres, h.tau, h.skin_ms.median, h.ao_ms.median, h.fps
    );
    println!(
        "work                   {:.1} spheres tested, {:.1} used per vertex; {:.2} GFLOP/s = {:.1}% of the {:.1} GFLOP/s FMA peak",
        h.spheres_tested_per_vertex,
        h.spheres_used_per_vertex,
        h.gflops,
        100.0 * h.fraction_of_peak,
        r.peak_fma_gflops
    );
    println!(
        "baselines              same method on the CPU (rayon) {:.2} ms: {:.1}x; ray-traced truth {:.0} ms: {:.0}x",
        r.cpu_same_method_ms.median, r.speedup_vs_cpu, r.raytrace_ms.median, r.speedup_vs_raytrace
    );
    println!(
        "gpu memory             {:.2} MiB in the kernel's buffers; {:.1} MiB reserved by the context's allocator",
        r.gpu_memory_bytes as f64 / (1u64 << 20) as f64,
        r.headline.gpu_memory_reserved_bytes as f64 / (1u64 << 20) as f64
    );
    for t in &r.targets {
        println!(
            "target {:<40} {:>10.4} (target {}) {}",
            t.name,
            t.measured,
            t.target,
            if t.pass { "PASS" } else { "MISS" }
        );
    }
    if let Some(path) = &opts.json {
        vkshade::io::write_json(path, &r)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &opts.plot {
        bench::plot::draw(path, &panels(&r))?;
        println!("wrote {}", path.display());
    }
    finish(ctx)
}

fn cmd_shaders(cmd: &ShaderCommand) -> Result<()> {
    let (root, write) = match cmd {
        ShaderCommand::Build { root } => (root, true),
        ShaderCommand::Check { root } => (root, false),
    };
    let root = root.clone().unwrap_or_else(vkshade::shaders::source_root);
    let statuses = vkshade::shaders::build_all(&root, write)?;
    let mut bad = Vec::new();
    for s in &statuses {
        println!("{:<10} {}", format!("{:?}", s.state).to_lowercase(), s.name);
        use vkshade::shaders::ModuleState as M;
        if matches!(s.state, M::Stale | M::Missing) || (!write && s.state == M::Orphan) {
            bad.push(s.name.clone());
        }
    }
    if bad.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!(
            "spv/ is out of date for {}; run `vkshade shaders build`",
            bad.join(", ")
        )))
    }
}

/// Shuts the context down; with validation, any message collected is an error.
fn finish(ctx: Context) -> Result<()> {
    let validated = ctx.validation_enabled();
    let messages = ctx.shutdown()?;
    if validated {
        if messages.is_empty() {
            eprintln!("validation: clean (0 messages)");
        } else {
            for m in &messages {
                eprintln!("{m}");
            }
            return Err(Error::InvalidArgument(format!(
                "{} validation message(s)",
                messages.len()
            )));
        }
    }
    Ok(())
}

fn cmd_ao(g: &Global, a: &AoArgs, demo: bool) -> Result<()> {
    use vkshade::app::ao;
    let default_mesh = a.mesh == std::path::Path::new(vkshade::kernels::ao::DEFAULT_MESH);
    if default_mesh && !a.mesh.exists() {
        return Err(Error::input(
            &a.mesh,
            "the built-in character is missing: run tools/setup.sh (it converts assimp's Testwuson.X)",
        ));
    }
    let cfg = ao::AoRunConfig {
        mesh: a.mesh.clone(),
        animation: a
            .anim
            .clone()
            .or_else(|| default_mesh.then(|| vkshade::kernels::ao::DEFAULT_ANIMATION.to_string())),
        frames: a.frames,
        tree: a.tree.clone(),
        build: a.tree_opts.config(),
        params: vkshade::kernels::ao::AoParams {
            tau: a.tau,
            refine: a.refine,
            occlusion: a.occlusion,
            blend: a.blend,
            clamp_inside: a.clamp_inside,
            correct: !a.no_correction,
        },
        reference: a.reference,
        rays: a.rays,
        correction_rays: a.correction_rays,
        error_scale: a.error_scale,
        in_flight: a.in_flight,
        out: a.out.clone(),
        ..Default::default()
    };
    let ctx = context(g)?;
    eprintln!("vkshade ao on {}", ctx.info().name);
    let report = ao::run(&ctx, &cfg, &mut |l| progress(l))?;
    let s = &report.summary;
    println!(
        "{} frames of {}: skin {:.3} ms + ao {:.3} ms GPU (median) = {:.0} fps; {:.1} spheres/vertex",
        s.frames,
        report.mesh.path,
        s.skin_ms_median,
        s.ao_ms_median,
        s.fps,
        s.spheres_used_per_vertex_mean
    );
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
    if demo {
        println!("pictures: {}", ao::frame_png(&cfg.out, 0).display());
    }
    finish(ctx)
}

fn cmd_bench_srbf(g: &Global, opts: &BenchOpts, quick: bool) -> Result<()> {
    use vkshade::bench::srbf::{SrbfBenchConfig, run};
    for path in opts.json.iter() {
        vkshade::io::check_writable(path)?;
    }
    let mut cfg = SrbfBenchConfig {
        bench: opts.config()?,
        ..Default::default()
    };
    cfg.bench.min_submit_ms = opts.min_ms.min(cfg.bench.min_submit_ms);
    if quick {
        cfg.lobes = vec![16, 64];
        cfg.basis = vec![64, 256];
        cfg.vertices = vec![3205];
        cfg.cpu_runs = 1;
    }
    let ctx = context(g)?;
    eprintln!("bench srbf on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    let h = &r.headline;
    println!("device                 {}", r.machine.device);
    println!(
        "headline               {} lobes x {} basis x {} vertices: lighting {:.3} ms + shade {:.3} ms (median GPU) = {:.0} fps",
        h.lobes, h.basis, h.vertices, h.lighting_ms.median, h.shade_ms.median, h.fps
    );
    println!(
        "work                   {:.3} GFLOP/frame; {:.2} GFLOP/s = {:.1}% of the {:.1} GFLOP/s FMA peak",
        h.gflop_per_frame,
        h.gflops,
        100.0 * h.fraction_of_peak,
        r.peak_fma_gflops
    );
    println!(
        "baselines              same method on the CPU {:.2} ms: {:.3}x; brute force {:.1} ms: {:.3}x (speed-up of the GPU path)",
        r.cpu_same_method_ms.median,
        r.speedup_vs_cpu,
        r.brute_force_ms.median,
        r.speedup_vs_brute_force
    );
    println!(
        "gpu memory             {:.2} MiB in the kernel's buffers; {:.1} MiB reserved by the context's allocator",
        h.gpu_memory_bytes as f64 / (1u64 << 20) as f64,
        h.gpu_memory_reserved_bytes as f64 / (1u64 << 20) as f64
    );
    let target = 200.0;
    println!(
        "target fps (bunny, 64 lobes, 256 basis)         {:>10.1} (target {target}) {}",
        h.fps,
        if h.fps >= target { "PASS" } else { "MISS" }
    );
    if let Some(path) = &opts.json {
        vkshade::io::write_json(path, &r)?;
        println!("wrote {}", path.display());
    }
    finish(ctx)
}

fn cmd_bench_sss(g: &Global, opts: &BenchOpts, quick: bool) -> Result<()> {
    use vkshade::bench::sss::{SssBenchConfig, panels, run};
    for path in opts.json.iter().chain(&opts.plot) {
        vkshade::io::check_writable(path)?;
    }
    if opts.plot.is_some() {
        bench::plot::ensure_available()?;
    }
    let mut cfg = SssBenchConfig::default();
    // This benchmark's passes take seconds on lavapipe: its own defaults (1 warm-up, 3 timed
    // submissions) unless the options were changed.
    let given = opts.config()?;
    if given.samples != BenchConfig::default().samples
        || given.warmup != BenchConfig::default().warmup
    {
        cfg.bench = given;
    }
    if quick {
        cfg.sizes = vec![128, 256];
        cfg.samples = vec![8, 32];
        cfg.headline = (256, 32);
        cfg.error_size = 128;
    }
    let ctx = context(g)?;
    eprintln!("bench sss on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    let h = &r.headline;
    println!("device                 {}", r.machine.device);
    println!(
        "headline               {}^2 texels x {} samples/texel/channel: irradiance {:.1} ms + diffusion {:.1} ms (median GPU) = {:.2} fps",
        h.size, h.samples, h.irradiance_ms.median, h.diffusion_ms.median, h.fps
    );
    println!(
        "throughput             {:.2e} samples/s = {:.1}% of the {:.1} GFLOP/s FMA peak, {:.1}% of {:.1} GB/s (work model in bench/sss.rs)",
        h.samples_per_s,
        100.0 * h.fraction_of_fma_peak,
        r.peak_fma_gflops,
        100.0 * h.fraction_of_bandwidth,
        r.bandwidth_gb_s
    );
    println!(
        "baselines              same sampler on the CPU {:.0} ms: {:.2}x; brute force at {}^2 {:.0} ms: {:.1}x (speed-up of the GPU path)",
        r.cpu_same_method_ms.median,
        r.speedup_vs_cpu,
        r.brute_force_size,
        r.brute_force_ms.median,
        r.speedup_vs_brute_force
    );
    let target = 30.0;
    println!(
        "target fps (head, 512^2, 32 samples)            {:>10.2} (target {target}) {}",
        h.fps,
        if h.fps >= target { "PASS" } else { "MISS" }
    );
    if let Some(path) = &opts.json {
        vkshade::io::write_json(path, &r)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &opts.plot {
        bench::plot::draw(path, &panels(&r))?;
        println!("wrote {}", path.display());
    }
    finish(ctx)
}

fn cmd_sss(g: &Global, a: &SssArgs) -> Result<()> {
    use vkshade::app::sss;
    use vkshade::kernels::sss::Material;
    let three = |v: &Option<Vec<f64>>, what: &str| -> Result<Option<[f64; 3]>> {
        v.as_ref()
            .map(|v| {
                v.as_slice()
                    .try_into()
                    .map_err(|_| Error::InvalidArgument(format!("{what} takes three values R,G,B")))
            })
            .transpose()
    };
    let material = match (
        three(&a.sigma_a, "--sigma-a")?,
        three(&a.sigma_s, "--sigma-s")?,
    ) {
        (Some(sa), Some(ss)) => Material::custom(sa, ss, a.eta)?,
        (None, None) => Material::named(&a.material)?.with_eta(a.eta)?,
        _ => {
            return Err(Error::InvalidArgument(
                "a custom material needs both --sigma-a and --sigma-s".into(),
            ));
        }
    };
    let cfg = sss::SssConfig {
        mesh: a.mesh.clone(),
        part: (!a.part.is_empty()).then(|| a.part.clone()),
        mm_per_unit: a.mm_per_unit,
        lights: if a.lights.is_empty() {
            sss::SssConfig::default().lights
        } else {
            a.lights.clone()
        },
        profile: a.profile.parse()?,
        material,
        energy: a.energy,
        samples: a.samples,
        size: a.size,
        frames: a.frames,
        anim: a.anim.clone(),
        reference: a.reference,
        out: a.out.clone(),
        ..Default::default()
    };
    let ctx = context(g)?;
    eprintln!("vkshade sss on {}", ctx.info().name);
    let r = sss::run(&ctx, &cfg, &mut |l| progress(l))?;
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
    finish(ctx)
}

fn cmd_srbf(g: &Global, cmd: &SrbfCommand) -> Result<()> {
    use vkshade::app::srbf;
    match cmd {
        SrbfCommand::Fit {
            env,
            lobes,
            fit_width,
            out,
        } => {
            let r = srbf::fit_command(env, *lobes, *fit_width, out, &mut |l| progress(l))?;
            println!(
                "fitted {} lobes to {} ({}x{}): relative L2 {:.4}; wrote {}",
                r.lobes.len(),
                r.env,
                r.fit_size[0],
                r.fit_size[1],
                r.errors.last().map(|e| e.1).unwrap_or(f64::NAN),
                out.display()
            );
            Ok(())
        }
        SrbfCommand::Shade(a) => {
            let albedo: [f32; 3] =
                a.albedo.as_slice().try_into().map_err(|_| {
                    Error::InvalidArgument("--albedo takes three values R,G,B".into())
                })?;
            let cfg = srbf::ShadeConfig {
                mesh: a.mesh.clone(),
                env: a.env.clone(),
                lobes: a.lobes,
                basis: a.basis,
                rotate: a.rotate,
                frames: a.frames,
                albedo,
                reference: a.reference,
                direction_width: a.directions,
                in_flight: a.in_flight,
                out: a.out.clone(),
                ..Default::default()
            };
            let ctx = context(g)?;
            eprintln!("vkshade srbf shade on {}", ctx.info().name);
            let r = srbf::shade(&ctx, &cfg, &mut |l| progress(l))?;
            println!(
                "{} frames of {} ({} vertices), {} lobes x {} basis: lighting {:.3} ms + shade {:.3} ms GPU (median) = {:.0} fps; fit error {:.4}, transfer projection error {:.4}",
                r.frames.len(),
                r.mesh,
                r.vertices,
                r.lobes,
                r.basis,
                r.gpu_ms_lighting_median,
                r.gpu_ms_shade_median,
                r.fps,
                r.fit_rel_l2,
                r.transfer_rel_l2
            );
            if let Some(worst) = r
                .frames
                .iter()
                .filter_map(|f| f.vs_ground_truth.map(|e| e.all))
                .reduce(f64::max)
            {
                println!(
                    "vs brute-force ground truth: relative L2 at most {worst:.4} over the frames"
                );
            }
            println!(
                "wrote shade_NNNN.ply, shade_NNNN.png and report.json to {}",
                cfg.out.display()
            );
            finish(ctx)
        }
    }
}

fn cmd_tree_build(
    mesh: &std::path::Path,
    out: &std::path::Path,
    opts: &TreeOpts,
    report: Option<&std::path::Path>,
) -> Result<()> {
    vkshade::io::check_writable(out)?;
    let c = vkshade::scene::load(mesh)?;
    let t = std::time::Instant::now();
    let (tree, fit) = vkshade::scene::SphereTree::build(&c.mesh, &opts.config())?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    tree.write_sph(out)?;
    println!(
        "{}: {} levels below the root, branch {}, fit {:?}, from {} ({} cells of {:.4}), {ms:.0} ms",
        mesh.display(),
        tree.levels - 1,
        tree.branch,
        opts.fit,
        fit.samples_from,
        fit.interior_cells,
        fit.cell_size
    );
    println!("level  spheres  volume coverage  volume excess  surface coverage");
    for l in &fit.levels {
        println!(
            "{:>5}  {:>7}  {:>14.1}%  {:>12.1}%  {:>15.1}%",
            l.level,
            l.spheres,
            100.0 * l.volume_coverage,
            100.0 * l.volume_excess,
            100.0 * l.surface_coverage
        );
    }
    if let Some(path) = report {
        vkshade::io::write_json(path, &fit)?;
        println!("wrote {}", path.display());
    }
    println!("wrote {}", out.display());
    Ok(())
}

fn cmd_mesh_info(mesh: &std::path::Path) -> Result<()> {
    let c = vkshade::scene::load(mesh)?;
    println!(
        "{}",
        serde_json::to_string_pretty(&c.mesh.report).unwrap_or_default()
    );
    println!("skinned: {}, joints: {}", c.skinned, c.rig.joints.len());
    for a in &c.animations {
        println!(
            "animation '{}': {:.3} s, {} channels",
            a.name,
            a.duration,
            a.channels.len()
        );
    }
    let (lo, hi) = c.mesh.bounds();
    println!("bounds: {lo} .. {hi}");
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Info { json } => cmd_info(json.clone()),
        Command::Bench(BenchCommand::Peak { opts }) => cmd_bench_peak(&cli.global, opts),
        Command::Bench(BenchCommand::Ao {
            opts,
            mesh,
            anim,
            quick,
        }) => cmd_bench_ao(&cli.global, opts, mesh, anim.as_deref(), *quick),
        Command::Bench(BenchCommand::Srbf { opts, quick }) => {
            cmd_bench_srbf(&cli.global, opts, *quick)
        }
        Command::Bench(BenchCommand::Sss { opts, quick }) => {
            cmd_bench_sss(&cli.global, opts, *quick)
        }
        Command::Shaders(cmd) => cmd_shaders(cmd),
        Command::Ao(a) => cmd_ao(&cli.global, a, false),
        Command::Demo => {
            let matches = AoArgs::augment_args(clap::Command::new("ao"))
                .get_matches_from(["ao", "--reference"]);
            match AoArgs::from_arg_matches(&matches) {
                Ok(args) => cmd_ao(&cli.global, &args, true),
                Err(e) => Err(Error::InvalidArgument(e.to_string())),
            }
        }
        Command::Spheretree(TreeCommand::Build {
            mesh,
            out,
            opts,
            report,
        }) => cmd_tree_build(mesh, out, opts, report.as_deref()),
        Command::Mesh(MeshCommand::Info { mesh }) => cmd_mesh_info(mesh),
        Command::Srbf(cmd) => cmd_srbf(&cli.global, cmd),
        Command::Sss(a) => cmd_sss(&cli.global, a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
