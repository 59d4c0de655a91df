//! The `vkshade` command-line tool: a thin layer over the library.

use clap::{Args, Parser, Subcommand};
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
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Device peak: f32 FMA throughput (GFLOP/s) and streaming bandwidth (GB/s), each grown
    /// until one submission takes --min-ms; the roofline the kernels are judged against.
    Peak {
        #[command(flatten)]
        opts: BenchOpts,
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
        if self.samples == 0 || !self.min_ms.is_finite() || self.min_ms <= 0.0 {
            return Err(Error::InvalidArgument(
                "--samples must be >= 1 and --min-ms > 0".into(),
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
    })
}

fn progress(line: &str) {
    eprintln!("  {line}");
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
        bench::write_json(&path, &sys)?;
        println!("\nwrote {}", path.display());
    }
    Ok(())
}

fn cmd_bench_peak(g: &Global, opts: &BenchOpts) -> Result<()> {
    let cfg = opts.config()?;
    for path in opts.json.iter().chain(&opts.plot) {
        bench::check_output(path)?;
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
        bench::write_json(path, &report)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &opts.plot {
        bench::plot::draw(path, &bench::peak::panels(&report))?;
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Info { json } => cmd_info(json.clone()),
        Command::Bench(BenchCommand::Peak { opts }) => cmd_bench_peak(&cli.global, opts),
        Command::Shaders(cmd) => cmd_shaders(cmd),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
