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
    /// Bidirectional texture functions (cloth): synthesise a BTF, interpolate one tile, render
    /// a cloth-covered object through 2D array textures and parabolic-map lookup.
    #[command(subcommand)]
    Btf(BtfCommand),
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
    /// Clusters of the clustered-PCA transfer compression.
    #[arg(long, default_value_t = 64)]
    clusters: usize,
    /// Principal components per cluster (0: the uncompressed transfer).
    #[arg(long, default_value_t = 16)]
    components: usize,
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
    /// Width of the downsampled map the lobes are fitted to.
    #[arg(long, default_value_t = 128)]
    fit_width: u32,
    /// Lobes sharper than this factor x the basis sharpness (a sun, a lamp) are shaded from
    /// the ray-cast visibility instead of through the smooth transfer basis (0: off).
    #[arg(long, default_value_t = vkshade::kernels::srbf::sharp::DEFAULT_FACTOR)]
    sharp_factor: f32,
    /// The most compact lobes shaded from the visibility, the strongest first (0: off).
    #[arg(long, default_value_t = vkshade::kernels::srbf::sharp::DEFAULT_MAX_LOBES)]
    compact_lobes: usize,
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
    /// Millimetres per model unit (scattering coefficients are per mm). Default: 1, or
    /// 1000 for the built-in BCN_Epileptic mesh (modelled in metres).
    #[arg(long)]
    mm_per_unit: Option<f64>,
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
    /// Samples per texel (one set shared by the three channels).
    #[arg(long, default_value_t = 32)]
    samples: u32,
    /// Shadows from the mesh's vertices only, interpolated over each triangle (faster); by
    /// default a texel casts its own shadow ray where its triangle's corners disagree.
    #[arg(long)]
    vertex_shadows: bool,
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
enum BtfCommand {
    /// Ray-cast a periodic cloth heightfield (known BRDF, shadowing, masking) at the 81 x 81
    /// UBO2003 directions and write a UBO2003-style directory (one image per (light, view),
    /// angles in the names: btf_tlTTT_plPPP_tvTTT_pvPPP.png) plus btf.json.
    Synth {
        /// weave, knit or rib.
        #[arg(long)]
        pattern: vkshade::kernels::btf::synth::Pattern,
        /// Tile side in texels.
        #[arg(long, default_value_t = 32)]
        size: u32,
        /// Texels per pattern repeat (default: the size, one tile); a smaller period makes a
        /// larger sample for `btf tile`.
        #[arg(long)]
        period: Option<u32>,
        /// Rays per texel along each axis.
        #[arg(long, default_value_t = 1)]
        samples: u32,
        /// png (8-bit sRGB) or exr (linear float).
        #[arg(long, default_value = "png")]
        format: vkshade::kernels::btf::synth::FileFormat,
        #[arg(short = 'o', long)]
        out: PathBuf,
    },
    /// Find the repeat period of a larger BTF sample (local minima of a 2D offset cost over
    /// a few of its images) and write one tile of it as a new directory.
    Tile {
        #[arg(long)]
        btf: PathBuf,
        /// Texel where the tile starts (X,Y).
        #[arg(long, default_value = "0,0")]
        origin: String,
        /// png (8-bit sRGB) or exr (linear float; slower to write).
        #[arg(long, default_value = "png")]
        format: vkshade::kernels::btf::synth::FileFormat,
        #[arg(short = 'o', long)]
        out: PathBuf,
    },
    /// The tile interpolated at one (light, view) pair through the GPU path, as linear EXR.
    Eval {
        /// A UBO2003-style directory (from `btf synth`, or your own in PNG/EXR).
        #[arg(long)]
        btf: PathBuf,
        /// THETA,PHI in degrees in the tile's tangent frame (as in the file names).
        #[arg(long, value_parser = vkshade::app::btf::parse_angles)]
        light: [f64; 2],
        /// THETA,PHI in degrees.
        #[arg(long, value_parser = vkshade::app::btf::parse_angles)]
        view: [f64; 2],
        /// Index/weight map resolution.
        #[arg(long, default_value_t = 128)]
        map_res: u32,
        /// Texel format of the packed BTF: block (overlapping 4x4 blocks of linear RGB,
        /// 16 bytes each, decoded and filtered by the shader: the fast one on lavapipe),
        /// bc1 (sRGB BC1, needs the device feature textureCompressionBC) or rgba8 (sRGB).
        #[arg(long, default_value = "block")]
        texture: vkshade::kernels::btf::gpu::Texture,
        #[arg(short = 'o', long)]
        out: PathBuf,
    },
    /// A cloth-covered object: DIR/render.png (with --reference: result | direct ray-cast |
    /// error), DIR/render.exr (linear) and DIR/report.json (GPU time, texture memory, map
    /// resolution, errors).
    Render {
        #[arg(long)]
        btf: PathBuf,
        /// sphere, cylinder, plane, or a mesh file with UVs (.glb/.gltf/.obj/.ply/.off;
        /// centred, scaled to radius 1.2, uv x 8).
        #[arg(long, default_value = "sphere")]
        object: String,
        /// A directional light X,Y,Z[,R,G,B] (towards the light, world space; y up, camera
        /// on +z); up to 2 (default: a warm key light and a cool grazing fill).
        #[arg(long)]
        light: Vec<String>,
        #[arg(long, default_value_t = 512)]
        width: u32,
        #[arg(long, default_value_t = 512)]
        height: u32,
        #[arg(long, default_value_t = 128)]
        map_res: u32,
        /// Texture layout: rows (one 81-layer array, images side by side with gutters) or
        /// layers (one image per layer, split over arrays of maxImageArrayLayers; rgba8 and
        /// bc1 only). Default: rows.
        #[arg(long)]
        layout: Option<vkshade::kernels::btf::gpu::Layout>,
        /// Texel format of the packed BTF: block (overlapping 4x4 blocks of linear RGB,
        /// 16 bytes each, decoded and filtered by the shader: the fast one on lavapipe),
        /// bc1 (sRGB BC1, needs the device feature textureCompressionBC) or rgba8 (sRGB).
        #[arg(long, default_value = "block")]
        texture: vkshade::kernels::btf::gpu::Texture,
        /// Compare with the f64 CPU interpolation and with the heightfield ray-cast at the
        /// exact directions (needs the btf.json of `btf synth`).
        #[arg(long)]
        reference: bool,
        #[arg(long, default_value_t = 0.1)]
        error_scale: f32,
        #[arg(long, default_value = "out/btf")]
        out: PathBuf,
    },
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
    /// BTF shading: GPU time over resolution x map resolution x tile size, texel fetches
    /// per second against the fetch rate the device sustains (measured in the same run), the
    /// speed-up over the CPU interpolation, texture memory; checks bench/targets.json.
    Btf {
        #[command(flatten)]
        opts: BenchOpts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
        /// Texel format of the headline and sweeps (the headline is also measured in the
        /// other formats; bc1 when the device supports it).
        #[arg(long, default_value = "block")]
        texture: vkshade::kernels::btf::gpu::Texture,
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
    context_with(g, vkshade::gpu::Features::default())
}

/// A context with optional device features (an error naming a missing one).
fn context_with(g: &Global, features: vkshade::gpu::Features) -> Result<Context> {
    Context::new(&ContextDesc {
        device: g.device.clone(),
        validation: g.validate.then(ValidationConfig::default),
        features,
        ..ContextDesc::default()
    })
}

/// The context a BTF command storing its texture as `texture` needs.
fn btf_context(g: &Global, texture: vkshade::kernels::btf::gpu::Texture) -> Result<Context> {
    let bc1 = texture == vkshade::kernels::btf::gpu::Texture::Bc1;
    context_with(
        g,
        vkshade::gpu::Features {
            texture_compression_bc: bc1,
            ..Default::default()
        },
    )
    .map_err(|e| match e {
        Error::Unsupported { device, what } if bc1 => Error::Unsupported {
            device,
            what: format!(
                "{what} (the BTF's --texture bc1 needs it; use --texture block or rgba8)"
            ),
        },
        e => e,
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
    print_targets(&r.targets);
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
    let statuses =
        vkshade::shaders::build_all(&root, write, vkshade::kernels::generated_includes())?;
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
        "headline               {} lobes ({} compact) x {} basis x {} vertices, {} clusters x {} components (compression error {:.4}): lighting {:.3} + project {:.3} + sharp {:.3} + shade {:.3} ms (median GPU) = {:.0} fps",
        h.lobes,
        h.compact_lobes,
        h.basis,
        h.vertices,
        h.clusters,
        h.components,
        r.headline_cpca_rel_l2,
        h.lighting_ms.median,
        h.project_ms.median,
        h.sharp_ms.median,
        h.shade_ms.median,
        h.fps
    );
    println!(
        "uncompressed           {:.3} ms = {:.0} fps",
        r.uncompressed.total_ms, r.uncompressed.fps
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
        "headline               {}^2 texels x {} samples/texel: vertex light {:.1} ms + irradiance {:.1} ms + diffusion {:.1} ms (median GPU) = {:.2} fps",
        h.size,
        h.samples,
        h.vertex_light_ms.median,
        h.irradiance_ms.median,
        h.diffusion_ms.median,
        h.fps
    );
    println!(
        "throughput             {:.2e} samples/s = {:.1}% of the {:.1} GFLOP/s FMA peak; gathered bytes {:.1}% of the {:.1} GB/s stream bandwidth (mostly cache hits; work model in bench/sss.rs)",
        h.samples_per_s,
        100.0 * h.fraction_of_fma_peak,
        r.peak_fma_gflops,
        100.0 * h.gathered_vs_stream_bandwidth,
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
        mm_per_unit: a
            .mm_per_unit
            .unwrap_or_else(|| vkshade::app::sss::default_mm_per_unit(&a.mesh)),
        lights: if a.lights.is_empty() {
            sss::SssConfig::default().lights
        } else {
            a.lights.clone()
        },
        profile: a.profile.parse()?,
        material,
        energy: a.energy,
        samples: a.samples,
        shadow_refine: !a.vertex_shadows,
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
                clusters: a.clusters,
                components: a.components,
                rotate: a.rotate,
                frames: a.frames,
                albedo,
                reference: a.reference,
                direction_width: a.directions,
                fit_width: a.fit_width,
                sharp_factor: a.sharp_factor,
                compact_lobes: a.compact_lobes,
                in_flight: a.in_flight,
                out: a.out.clone(),
                ..Default::default()
            };
            let ctx = context(g)?;
            eprintln!("vkshade srbf shade on {}", ctx.info().name);
            let r = srbf::shade(&ctx, &cfg, &mut |l| progress(l))?;
            println!(
                "{} frames of {} ({} vertices), {} lobes ({} compact) x {} basis ({} clusters x {} components): lighting {:.3} + project {:.3} + sharp {:.3} + shade {:.3} ms GPU (median) = {:.0} fps; fit error {:.4}, transfer projection error {:.4}, compression error {:.4}",
                r.frames.len(),
                r.mesh,
                r.vertices,
                r.lobes,
                r.compact_lobes,
                r.basis,
                r.clusters,
                r.components,
                r.gpu_ms_lighting_median,
                r.gpu_ms_project_median,
                r.gpu_ms_sharp_median,
                r.gpu_ms_shade_median,
                r.fps,
                r.fit_rel_l2,
                r.transfer_rel_l2,
                r.cpca_rel_l2
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

fn parse_light(s: &str) -> Result<vkshade::kernels::btf::gbuffer::Light> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::InvalidArgument(format!("--light '{s}': expected X,Y,Z[,R,G,B]")))?;
    let (d, rgb) = match v[..] {
        [x, y, z] => ([x, y, z], [1.0; 3]),
        [x, y, z, r, g, b] => ([x, y, z], [r, g, b]),
        _ => {
            return Err(Error::InvalidArgument(format!(
                "--light '{s}': expected X,Y,Z[,R,G,B]"
            )));
        }
    };
    Ok(vkshade::kernels::btf::gbuffer::Light {
        direction: glam::Vec3::from(d),
        rgb,
    })
}

fn cmd_btf(g: &Global, cmd: &BtfCommand) -> Result<()> {
    use vkshade::app::btf;
    match cmd {
        BtfCommand::Synth {
            pattern,
            size,
            period,
            samples,
            format,
            out,
        } => {
            eprintln!(
                "synthesising {} x {size} x 6561 images of {pattern:?}",
                size
            );
            let m = btf::synth_command(*pattern, *size, *period, *samples, *format, out)?;
            println!(
                "wrote 6561 {} images of {size} x {size} texels ({:?}) and {} to {} in {:.1} s",
                m.format,
                pattern,
                btf::META,
                out.display(),
                m.ms / 1e3
            );
            Ok(())
        }
        BtfCommand::Tile {
            btf: dir,
            origin,
            format,
            out,
        } => {
            let bad = || Error::InvalidArgument(format!("--origin '{origin}': expected X,Y"));
            let v: Vec<u32> = origin
                .split(',')
                .map(|x| x.trim().parse::<u32>().map_err(|_| bad()))
                .collect::<Result<_>>()?;
            let origin: [u32; 2] = v.as_slice().try_into().map_err(|_| bad())?;
            let r = btf::tile_command(dir, origin, *format, out)?;
            println!(
                "{} x {} sample: repeat period {} x {} (cost {:.2e} against a median of {:.2e}); wrote the tile at {:?} to {}",
                r.sample_size[0],
                r.sample_size[1],
                r.period.period[0],
                r.period.period[1],
                r.period.cost,
                r.period.median_cost,
                r.origin,
                out.display()
            );
            Ok(())
        }
        BtfCommand::Eval {
            btf: dir,
            light,
            view,
            map_res,
            texture,
            out,
        } => {
            let ctx = btf_context(g, *texture)?;
            let r = btf::eval_command(&ctx, dir, *light, *view, *map_res, *texture, out)?;
            let taps = |t: &[(vkshade::kernels::btf::dirs::Angles, f64)]| {
                t.iter()
                    .map(|(a, w)| format!("({},{}) x {w:.3}", a.theta, a.phi))
                    .collect::<Vec<_>>()
                    .join(" + ")
            };
            println!("light taps: {}", taps(&r.light_taps));
            println!("view taps:  {}", taps(&r.view_taps));
            println!(
                "wrote the {} x {} tile to {} ({:.3} ms GPU)",
                r.size[0],
                r.size[1],
                out.display(),
                r.gpu_ms
            );
            finish(ctx)
        }
        BtfCommand::Render {
            btf: dir,
            object,
            light,
            width,
            height,
            map_res,
            layout,
            texture,
            reference,
            error_scale,
            out,
        } => {
            let lights = if light.is_empty() {
                btf::default_lights()
            } else {
                light
                    .iter()
                    .map(|s| parse_light(s))
                    .collect::<Result<_>>()?
            };
            if !(error_scale.is_finite() && *error_scale > 0.0) {
                return Err(Error::InvalidArgument(format!(
                    "--error-scale must be > 0, not {error_scale}"
                )));
            }
            let (shape, mesh) = match object.parse::<vkshade::kernels::btf::gbuffer::Object>() {
                Ok(o) => (o, None),
                Err(_) => (
                    vkshade::kernels::btf::gbuffer::Object::Sphere,
                    Some(PathBuf::from(object)),
                ),
            };
            let cfg = btf::RenderConfig {
                btf: dir.clone(),
                object: shape,
                mesh,
                lights,
                width: *width,
                height: *height,
                map_res: *map_res,
                layout: layout.unwrap_or(texture.default_layout()),
                texture: *texture,
                reference: *reference,
                error_scale: *error_scale,
                out: out.clone(),
                bench: BenchConfig::default(),
            };
            let ctx = btf_context(g, *texture)?;
            eprintln!("vkshade btf render on {}", ctx.info().name);
            let r = btf::render(&ctx, &cfg, &mut |l| progress(l))?;
            println!(
                "{} {} x {} ({} px covered), {} x {} tile, map {}: {:.3} ms GPU (median) = {:.1} fps; BTF textures {:.2} MiB in {} array(s) of {} layers, maps {:.2} MiB",
                r.object,
                r.size[0],
                r.size[1],
                r.covered_pixels,
                r.tile[0],
                r.tile[1],
                r.map_resolution,
                r.gpu_ms.median,
                r.fps,
                r.texture_mib,
                r.packing.arrays,
                r.packing.layers_per_array,
                r.map_bytes as f64 / (1u64 << 20) as f64
            );
            if let Some(c) = &r.vs_cpu {
                println!(
                    "vs CPU interpolation (f64): max {:.2e}, RMS {:.2e} over {} px ({} ambiguous left out); bound {:.0e}; CPU {:.0} ms",
                    c.max_abs, c.rms, c.pixels, c.ambiguous_pixels, c.bound, c.cpu_ms
                );
            }
            if let Some(t) = &r.vs_ray_cast {
                println!(
                    "vs direct ray-cast: PSNR {:.1} dB (RMSE {:.4}, {} px) within 75 deg, {:.1} dB (RMSE {:.4}, {} px) grazing, {:.1} dB all",
                    t.within_75.psnr_db,
                    t.within_75.rmse,
                    t.within_75.pixels,
                    t.grazing.psnr_db,
                    t.grazing.rmse,
                    t.grazing.pixels,
                    t.all.psnr_db
                );
            }
            println!("wrote {}, {} and report.json", r.png, r.exr);
            finish(ctx)
        }
    }
}

fn cmd_bench_btf(
    g: &Global,
    opts: &BenchOpts,
    quick: bool,
    texture: vkshade::kernels::btf::gpu::Texture,
) -> Result<()> {
    use vkshade::bench::btf::{BtfBenchConfig, run};
    if opts.plot.is_some() {
        return Err(Error::InvalidArgument(
            "bench btf writes no plot yet (its sweeps are in the --json report)".into(),
        ));
    }
    for path in opts.json.iter() {
        vkshade::io::check_writable(path)?;
    }
    let mut cfg = BtfBenchConfig {
        bench: opts.config()?,
        ..Default::default()
    };
    if quick {
        cfg.resolutions = vec![256, 512];
        cfg.map_resolutions = vec![32, 128];
        cfg.tiles = vec![8, 32];
        cfg.cpu_runs = 1;
    }
    cfg.texture = texture;
    // BC1 needs textureCompressionBC: without it a block or rgba8 run skips the bc1
    // comparison.
    let ctx = match btf_context(g, vkshade::kernels::btf::gpu::Texture::Bc1) {
        Ok(ctx) => ctx,
        Err(e) if texture != vkshade::kernels::btf::gpu::Texture::Bc1 => {
            eprintln!("bench btf: no BC1 comparison ({e})");
            cfg.bc1_available = false;
            context(g)?
        }
        Err(e) => return Err(e),
    };
    eprintln!("bench btf on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    let h = &r.headline;
    println!("device                 {}", r.machine.device);
    println!(
        "headline               {}^2 sphere ({} px covered), map {}, tile {}, {} light(s), {:?}: {:.2} ms (median GPU) = {:.1} fps",
        h.resolution,
        h.covered_pixels,
        h.map_resolution,
        h.tile,
        h.lights,
        h.layout,
        h.gpu_ms.median,
        h.fps
    );
    let (what, rate) = match h.texture {
        vkshade::kernels::btf::gpu::Texture::Block => {
            ("block fetches", r.probe_block_fetches_per_second)
        }
        _ => ("filtered fetches", r.probe_fetches_per_second),
    };
    println!(
        "fetches                {:.1} M taps/s = {:.1}% of the {:.1} M {what}/s the fetch probe sustains",
        h.taps_per_second / 1e6,
        100.0 * h.fraction_of_fetch_rate,
        rate / 1e6
    );
    println!(
        "baseline               same interpolation on the CPU (f64, rayon) {:.1} ms: {:.2}x (speed-up of the GPU path)",
        r.cpu_same_method_ms.median, r.speedup_vs_cpu
    );
    println!(
        "texture memory         {:.2} MiB ({:?} layout, {} array(s) of {} layers of {}x{})",
        h.texture_mib,
        h.packing.layout,
        h.packing.arrays,
        h.packing.layers_per_array,
        h.packing.layer_extent[0],
        h.packing.layer_extent[1]
    );
    for p in &r.formats {
        println!(
            "format {:<6} {:<7}  {:.2} ms = {:.1} fps, {:.2} MiB of texture",
            format!("{:?}", p.texture).to_lowercase(),
            format!("{:?}", p.layout),
            p.gpu_ms.median,
            p.fps,
            p.texture_mib
        );
    }
    println!(
        "sweep (resolution, map, tile, texture, layout, lights: ms, fps, % of fetch rate, MiB)"
    );
    for p in &r.sweep {
        println!(
            "  {:>5} {:>4} {:>3} {:<5} {:<7} {}: {:>9.2} ms {:>8.1} fps {:>6.1}% {:>7.2}",
            p.resolution,
            p.map_resolution,
            p.tile,
            format!("{:?}", p.texture).to_lowercase(),
            format!("{:?}", p.layout),
            p.lights,
            p.gpu_ms.median,
            p.fps,
            100.0 * p.fraction_of_fetch_rate,
            p.texture_mib
        );
    }
    print_targets(&r.targets);
    if let Some(path) = &opts.json {
        vkshade::io::write_json(path, &r)?;
        println!("wrote {}", path.display());
    }
    finish(ctx)
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
        Command::Btf(cmd) => cmd_btf(&cli.global, cmd),
        Command::Bench(BenchCommand::Btf {
            opts,
            quick,
            texture,
        }) => cmd_bench_btf(&cli.global, opts, *quick, *texture),
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

/// One line per bench target: name, measured, target, PASS or MISS.
fn print_targets(targets: &[vkshade::bench::ao::TargetCheck]) {
    for t in targets {
        println!(
            "target {:<58} {:>10.4} (target {}) {}",
            t.name,
            t.measured,
            t.target,
            if t.pass { "PASS" } else { "MISS" }
        );
    }
}
