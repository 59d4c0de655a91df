//! `vkshade bench peak|ao|srbf|btf|sss|frame|env|all|compare|table`: the benchmarks'
//! options, runs and printed summaries
//! (the sweeps themselves are in [`crate::bench`]).

use super::{Gpu, finish, progress};
use crate::bench::{self, BenchConfig};
use crate::error::{Error, Result};
use crate::kernels::btf::gpu::Texture;
use crate::kernels::srbf::glossy::ViewSpec;
use std::path::{Path, PathBuf};

/// The subcommands of `vkshade bench`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum Command {
    /// Device peak: f32 FMA throughput (GFLOP/s) and streaming bandwidth (GB/s), each grown
    /// until one submission takes --min-ms, and the probes (sampling 2D/3D nearest/bilinear
    /// RGBA8/16F/32F coherent/random, storage buffer and image gathers, uniform-buffer reads
    /// at a dynamic index, shared memory, barriers, atomics): the rooflines the kernels are
    /// judged against.
    Peak {
        #[command(flatten)]
        opts: Opts,
    },
    /// Sphere-tree AO: sweeps vertex count (subdivision), sphere count (tree depth) and the
    /// refinement threshold tau (error against the ray-traced mesh vs time); reports ms per
    /// frame, spheres per vertex, GFLOP/s as a fraction of the measured FMA peak, and the
    /// speed-up over the same method on the CPU and over ray tracing, all in the same run;
    /// checks bench/targets.json.
    Ao {
        #[command(flatten)]
        opts: Opts,
        /// Character to benchmark.
        #[arg(long, default_value = crate::kernels::ao::DEFAULT_MESH)]
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
        opts: Opts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
        /// Instead of the timing sweep: CTA against clustered PCA and the uncompressed
        /// transfer at matched bytes per vertex, diffuse and glossy (error against the
        /// brute-force truth, bytes, fps, compression time); writes compare.json,
        /// compare.md and compare.png into --out.
        #[arg(long)]
        compare: bool,
        #[command(flatten)]
        cmp: CompareArgs,
    },
    /// BTF shading: GPU time over resolution x map resolution x tile size, texel fetches
    /// per second against the fetch rate the device sustains (measured in the same run), the
    /// speed-up over the CPU interpolation, texture memory; checks bench/targets.json.
    Btf {
        #[command(flatten)]
        opts: Opts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
        /// Texel format of the headline and sweeps (the headline is also measured in the
        /// other formats; bc1 when the device supports it).
        #[arg(long, default_value = "block", value_parser = super::choice::<Texture>("texture format"))]
        texture: Texture,
        /// Instead: the moving garment (BCN_Epileptic's Torso and Legs, Epileptisch), per
        /// frame skinning + G-buffer 512 x 512 (compute rasteriser) + BTF: fps, GPU ms per
        /// pass and host ms per frame.
        #[arg(long)]
        anim: bool,
    },
    /// The character frame (BCN_Epileptic: Head skin, Torso and Legs cloth, 512 x 512, atlas
    /// 512^2 x 32 samples): whole-frame and per-pass GPU ms, host ms per frame, each pass's
    /// bandwidth against the streaming peak measured in the same run.
    Frame {
        #[command(flatten)]
        opts: Opts,
    },
    /// Many frames of one kernel under validation (default 10,000 AO frames): device memory
    /// (the allocator's report) and host RSS sampled every 1% of the run must stay flat after
    /// the warm-up (criterion in `bench::soak`), with no validation message and no leak at
    /// shutdown; writes DIR/soak.csv, soak.json and soak.png.
    Soak(super::validate::SoakArgs),
    /// Environment light shadowed by the character (BCN_Epileptic, Epileptisch, forest map):
    /// GPU ms of `env rotate` and `env shadow` over the lobe count, beside the pose and AO
    /// passes, host ms per frame, the CPU twin's ms and the table lookups per vertex; the
    /// traced visibility's BVH refit and rays against their CPU twin.
    Env {
        #[command(flatten)]
        opts: Opts,
        /// Only the headline lobe count (32).
        #[arg(long)]
        quick: bool,
    },
    /// Everything in one run: the peaks, every kernel's headline (ao, sss, srbf, btf, frame)
    /// in interleaved rounds, the peaks again; per kernel fps, the fraction of its binding
    /// roofline, the ratio to its CPU twin and its target, each as the median and IQR over
    /// the rounds, with warnings where the spread or the peaks' drift exceed --noise-pct.
    /// Writes DIR/all.json, DIR/summary.md and DIR/all.png.
    All {
        /// Directory for all.json, summary.md and all.png (created if missing).
        #[arg(long, value_name = "DIR")]
        json: PathBuf,
        /// Rounds over the kernels (each figure's repeats).
        #[arg(long, default_value_t = 5)]
        rounds: usize,
        /// Timed submissions of each kernel's headline per round (median taken).
        #[arg(long, default_value_t = 5)]
        samples: usize,
        /// Untimed submissions before them.
        #[arg(long, default_value_t = 1)]
        warmup: usize,
        /// Peak probes grow until one submission takes this many ms.
        #[arg(long, default_value_t = 20.0)]
        min_ms: f64,
        /// Kernels to run, comma-separated (default: ao,sss,srbf,btf,frame).
        #[arg(long, value_delimiter = ',')]
        kernels: Vec<String>,
        /// Relative IQR (percent) above which a figure is flagged as noisy.
        #[arg(long, default_value_t = 10.0)]
        noise_pct: f64,
        /// Smoke run (CI): 1 round, 2 samples, 2 ms probes, SRBF on a synthetic transfer of
        /// the bunny's shape (no ray-cast); checks that everything runs, no figure of it is
        /// meaningful.
        #[arg(long)]
        quick: bool,
        /// Read every input (data/*.glb, /usr/share/... bunny and studio light) under this
        /// folder instead (an absolute path loses its leading /): a machine without the
        /// Debian data packages (tools/bench-gpu.sh).
        #[arg(long, value_name = "DIR")]
        data_root: Option<PathBuf>,
    },
    /// Compare two `bench all` runs (their all.json): per figure the ratio B/A and whether
    /// it is beyond the noise of both runs; exits non-zero when a kernel figure got worse
    /// beyond the noise and by more than --threshold percent.
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Regression threshold, percent.
        #[arg(long, default_value_t = 5.0)]
        threshold: f64,
    },
    /// The README's results table from the all.json of each recorded machine (Markdown on
    /// stdout): machine, date, peaks, and each kernel's figures.
    Table {
        /// all.json files, one per machine.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Texture-space SSS on the BCN_Epileptic head: GPU time of irradiance and diffusion
    /// over texture size x samples per texel, error against the brute-force ground truth vs
    /// time, throughput against the FMA and bandwidth peaks, and the speed-up over the same
    /// sampler on the CPU and over the brute force.
    Sss {
        #[command(flatten)]
        opts: Opts,
        /// Smaller sweeps (for a quick check).
        #[arg(long)]
        quick: bool,
        /// The animated head instead: skinning, per-frame texture-space geometry and BVH
        /// refit, irradiance with shadows and diffusion on the GPU every frame (fps, host ms
        /// per frame).
        #[arg(long)]
        anim: bool,
    },
}

/// What every benchmark is told: where its results go and how it measures.
#[derive(clap::Args, Clone, Debug)]
pub struct Opts {
    /// Write the results as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a PNG plot of the sweeps to this file.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Timed submissions per measurement (the median is reported).
    #[arg(long, default_value_t = 10)]
    pub samples: usize,
    /// Untimed warm-up submissions per measurement.
    #[arg(long, default_value_t = 2)]
    pub warmup: usize,
    /// Grow the work until one submission takes at least this many milliseconds.
    #[arg(long, default_value_t = 100.0)]
    pub min_ms: f64,
}

impl Opts {
    /// The measurement settings, refused outside their ranges.
    pub fn config(&self) -> Result<BenchConfig> {
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

impl Command {
    /// Runs the benchmark and prints its summary (and writes the JSON and plot asked for).
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        match self {
            Command::Peak { opts } => peak(gpu, opts),
            Command::Frame { opts } => frame(gpu, opts),
            Command::Soak(a) => a.run(gpu),
            Command::Ao {
                opts,
                mesh,
                anim,
                quick,
            } => ao(gpu, opts, mesh, anim.as_deref(), *quick),
            Command::Srbf {
                opts,
                compare: true,
                cmp,
                ..
            } => srbf_compare(gpu, opts, cmp),
            Command::Srbf { opts, quick, .. } => srbf(gpu, opts, *quick),
            Command::Btf {
                opts,
                anim: true,
                texture,
                ..
            } => super::btf::bench_anim(gpu, opts, *texture),
            Command::Btf {
                opts,
                quick,
                texture,
                anim: false,
            } => btf(gpu, opts, *quick, *texture),
            Command::Sss {
                opts, anim: true, ..
            } => sss_anim(gpu, opts),
            Command::Sss { opts, quick, .. } => sss(gpu, opts, *quick),
            Command::Env { opts, quick } => super::env::bench(gpu, opts, *quick),
            Command::All {
                json,
                rounds,
                samples,
                warmup,
                min_ms,
                kernels,
                noise_pct,
                quick,
                data_root,
            } => {
                let d = bench::all::AllConfig::default();
                let mut cfg = bench::all::AllConfig {
                    rounds: *rounds,
                    bench: BenchConfig {
                        warmup: *warmup,
                        samples: *samples,
                        ..d.bench.clone()
                    },
                    peak: BenchConfig {
                        min_submit_ms: *min_ms,
                        ..d.peak.clone()
                    },
                    noise_bound: noise_pct / 100.0,
                    kernels: if kernels.is_empty() {
                        d.kernels.clone()
                    } else {
                        kernels.clone()
                    },
                };
                if *quick {
                    cfg.rounds = 1;
                    cfg.bench.samples = 2;
                    cfg.peak.samples = 2;
                    cfg.peak.min_submit_ms = 2.0;
                }
                all(gpu, json, &cfg, data_root.as_deref(), *quick)
            }
            Command::Compare { a, b, threshold } => compare(a, b, *threshold),
            Command::Table { files } => table(files),
        }
    }
}

/// Refuses unwritable output paths before anything runs (the plot's only where the
/// benchmark draws one).
pub(super) fn check_outputs(opts: &Opts, plots: bool) -> Result<()> {
    let plot = opts.plot.iter().filter(|_| plots);
    for path in opts.json.iter().chain(plot) {
        crate::io::check_writable(path)?;
    }
    if plots && opts.plot.is_some() {
        bench::plot::ensure_available()?;
    }
    Ok(())
}

/// Writes the report as JSON where `--json` asks for it.
pub(super) fn write_json<R: serde::Serialize>(opts: &Opts, report: &R) -> Result<()> {
    if let Some(path) = &opts.json {
        crate::io::write_json(path, report)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Draws the plot where `--plot` asks for it.
fn write_plot(opts: &Opts, panels: impl FnOnce() -> Vec<bench::plot::Panel>) -> Result<()> {
    if let Some(path) = &opts.plot {
        bench::plot::draw(path, &panels())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// `bench peak`.
fn peak(gpu: &Gpu, opts: &Opts) -> Result<()> {
    let cfg = opts.config()?;
    check_outputs(opts, true)?;
    let ctx = gpu.context()?;
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
    for p in &report.probes {
        println!(
            "{:<34} {:>10}{}/s (IQR {:.1}% of the time; {})",
            p.key,
            bench::peak::si(p.rate_per_s),
            p.unit,
            100.0 * p.gpu_ms.iqr_rel,
            p.what
        );
    }
    for s in &report.skipped_probes {
        println!("skipped {s}");
    }
    write_json(opts, &report)?;
    write_plot(opts, || bench::peak::panels(&report))?;
    finish(ctx)
}

/// `bench ao`.
fn ao(gpu: &Gpu, opts: &Opts, mesh: &Path, anim: Option<&str>, quick: bool) -> Result<()> {
    use crate::bench::ao::{AoBenchConfig, panels, run};
    check_outputs(opts, true)?;
    let mut cfg = AoBenchConfig {
        mesh: mesh.to_path_buf(),
        bench: opts.config()?,
        ..Default::default()
    };
    cfg.bench.min_submit_ms = opts.min_ms.min(cfg.bench.min_submit_ms);
    if anim.is_some() || mesh != Path::new(crate::kernels::ao::DEFAULT_MESH) {
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
    let ctx = gpu.context()?;
    eprintln!("bench ao on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    print_ao(&r);
    write_json(opts, &r)?;
    write_plot(opts, || panels(&r))?;
    finish(ctx)
}

fn print_ao(r: &bench::ao::AoBenchReport) {
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
    println!("roofline               {}", r.roofline.summary());
    println!(
        "baselines              same method on the CPU (rayon) {:.2} ms: {:.1}x; ray-traced truth {:.0} ms: {:.0}x",
        r.cpu_same_method_ms.median, r.speedup_vs_cpu, r.raytrace_ms.median, r.speedup_vs_raytrace
    );
    println!(
        "gpu memory             {:.2} MiB in the kernel's buffers; {:.1} MiB reserved by the context's allocator",
        r.gpu_memory_bytes as f64 / (1u64 << 20) as f64,
        r.headline.gpu_memory_reserved_bytes as f64 / (1u64 << 20) as f64
    );
    println!(
        "cut                    GPU ms    fps  CPU twin ms  GPU/CPU  spheres/vertex  MAE    p95    MAE alone"
    );
    for c in &r.cut_comparison {
        let p = &c.point;
        println!(
            "  {:<20} {:>7.3} {:>6.0} {:>12.2} {:>7.2}x {:>15.1} {:>6.4} {:>6.3} {:>9.4}",
            format!("{:?}", c.cut),
            p.total_ms,
            p.fps,
            c.cpu_twin_ms.median,
            c.speedup_vs_cpu,
            p.spheres_used_per_vertex,
            p.mae.unwrap_or(f64::NAN),
            p.p95.unwrap_or(f64::NAN),
            c.mae_alone
        );
    }
    println!(
        "                       (MAE, p95: the CPU twin's visibility against the ray-traced mesh \
         over the reference frames; tests/ao.rs holds the GPU to the twin within MAE 1e-4)"
    );
    print_targets(&r.targets);
}

/// The settings of `bench srbf --compare`.
#[derive(clap::Args, Clone, Debug)]
pub struct CompareArgs {
    /// --compare: the mesh (default: Testwuson, 3205 vertices, a few minutes; the full
    /// bunny is /usr/share/glmark2/models/bunny.obj).
    #[arg(long, default_value = "data/testwuson.glb")]
    pub compare_mesh: PathBuf,
    /// --compare: the environment map.
    #[arg(long, default_value = crate::kernels::srbf::DEFAULT_ENV)]
    pub compare_env: PathBuf,
    /// --compare: storage points, bytes of transfer streamed per vertex (4 of them the
    /// cluster id).
    #[arg(long, value_delimiter = ',', default_values_t = [20usize, 36, 68, 132])]
    pub bytes: Vec<usize>,
    /// --compare: clusters of both methods.
    #[arg(long, default_value_t = 16)]
    pub clusters: usize,
    /// --compare: the glossy view basis, M terms of the BRDF's factorisation (default 24:
    /// the uncompressed Testwuson transfer, 79 MB, fits one storage buffer on lavapipe).
    #[arg(long, conflicts_with = "views")]
    pub terms: Option<usize>,
    /// --compare: the glossy view basis, an N x N view grid instead of --terms.
    #[arg(long)]
    pub views: Option<u32>,
    /// --compare: width of the map the truth integrates, or `full` (its own resolution).
    #[arg(long, default_value = "256")]
    pub truth_width: String,
    /// --compare: CTA's view rank (glossy).
    #[arg(long, default_value_t = 24)]
    pub cta_view_rank: usize,
    /// --compare: CTA's light rank (glossy).
    #[arg(long, default_value_t = 32)]
    pub cta_light_rank: usize,
    /// --compare: only diffuse or only glossy (default both).
    #[arg(long)]
    pub only: Option<String>,
    /// --compare: output directory (also the cache of the projected transfers).
    #[arg(long, default_value = "out/bench-srbf-compare")]
    pub out: PathBuf,
}

/// `bench srbf --compare`.
fn srbf_compare(gpu: &Gpu, opts: &Opts, a: &CompareArgs) -> Result<()> {
    use crate::bench::srbf_compare::{CompareConfig, run, table, write_outputs};
    check_outputs(opts, true)?;
    let truth_width = match a.truth_width.as_str() {
        "full" => None,
        w => Some(w.parse::<u32>().map_err(|_| {
            Error::InvalidArgument(format!(
                "--truth-width '{w}': expected full or an even width dividing the map's"
            ))
        })?),
    };
    let (diffuse, glossy) = match a.only.as_deref() {
        None => (true, true),
        Some("diffuse") => (true, false),
        Some("glossy") => (false, true),
        Some(o) => {
            return Err(Error::InvalidArgument(format!(
                "--only '{o}': expected diffuse or glossy"
            )));
        }
    };
    let mut cfg = CompareConfig {
        mesh: a.compare_mesh.clone(),
        env: a.compare_env.clone(),
        bench: opts.config()?,
        bytes: a.bytes.clone(),
        clusters: a.clusters,
        view: ViewSpec::from_args(a.views, a.terms),
        cta_view_rank: a.cta_view_rank,
        cta_light_rank: a.cta_light_rank,
        truth_width,
        diffuse,
        glossy,
        out: a.out.clone(),
        ..Default::default()
    };
    cfg.bench.min_submit_ms = opts.min_ms.min(cfg.bench.min_submit_ms);
    cfg.check()?;
    let ctx = gpu.context()?;
    eprintln!("bench srbf --compare on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    print!("{}", table(&r));
    for p in write_outputs(&r)? {
        println!("wrote {}", p.display());
    }
    write_json(opts, &r)?;
    write_plot(opts, || crate::bench::srbf_compare::panels(&r))?;
    finish(ctx)
}

/// `bench srbf` (draws no plot).
fn srbf(gpu: &Gpu, opts: &Opts, quick: bool) -> Result<()> {
    use crate::bench::srbf::{SrbfBenchConfig, run};
    check_outputs(opts, false)?;
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
    let ctx = gpu.context()?;
    eprintln!("bench srbf on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    print_srbf(&r);
    write_json(opts, &r)?;
    finish(ctx)
}

fn print_srbf(r: &bench::srbf::SrbfBenchReport) {
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
    println!("roofline               {}", r.roofline.summary());
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
}

/// `bench sss`.
fn sss(gpu: &Gpu, opts: &Opts, quick: bool) -> Result<()> {
    use crate::bench::sss::{SssBenchConfig, panels, run};
    check_outputs(opts, true)?;
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
    let ctx = gpu.context()?;
    eprintln!("bench sss on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    print_sss(&r);
    write_json(opts, &r)?;
    write_plot(opts, || panels(&r))?;
    finish(ctx)
}

/// `bench frame`.
fn frame(gpu: &Gpu, opts: &Opts) -> Result<()> {
    check_outputs(opts, false)?;
    let bench_cfg = opts.config()?;
    let ctx = super::frame::context(gpu)?;
    eprintln!("bench frame on {}", ctx.info().name);
    let cfg = crate::frame::FrameConfig::default();
    let r = bench::frame::run(&ctx, &cfg, &bench_cfg, &mut |l| progress(l))?;
    bench::frame::print(&r);
    write_json(opts, &r)?;
    finish(ctx)
}

/// `bench sss --anim`.
fn sss_anim(gpu: &Gpu, opts: &Opts) -> Result<()> {
    check_outputs(opts, false)?;
    let cfg = bench::sss::SssAnimBenchConfig::default();
    let ctx = gpu.context()?;
    eprintln!("bench sss --anim on {}", ctx.info().name);
    let r = bench::sss::run_anim(&ctx, &cfg, &mut |l| progress(l))?;
    bench::sss::print_anim(&r);
    write_json(opts, &r)?;
    finish(ctx)
}

fn print_sss(r: &bench::sss::SssBenchReport) {
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
    println!("roofline               {}", r.roofline.summary());
    println!(
        "baselines              same sampler on the CPU {:.0} ms: {:.2}x; brute force at {}^2 {:.0} ms: {:.1}x (speed-up of the GPU path)",
        r.cpu_same_method_ms.median,
        r.speedup_vs_cpu,
        r.brute_force_size,
        r.brute_force_ms.median,
        r.speedup_vs_brute_force
    );
    println!(
        "two skin regions       {:.2} ms: {:.3}x the one-region headline (same run)",
        r.two_regions.total_ms, r.two_regions_vs_one
    );
    let target = 30.0;
    println!(
        "target fps (head, 512^2, 32 samples)            {:>10.2} (target {target}) {}",
        h.fps,
        if h.fps >= target { "PASS" } else { "MISS" }
    );
}

/// `bench btf` (draws no plot yet).
fn btf(gpu: &Gpu, opts: &Opts, quick: bool, texture: Texture) -> Result<()> {
    use crate::bench::btf::{BtfBenchConfig, run};
    if opts.plot.is_some() {
        return Err(Error::InvalidArgument(
            "bench btf writes no plot yet (its sweeps are in the --json report)".into(),
        ));
    }
    check_outputs(opts, false)?;
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
    let ctx = match super::btf::context(gpu, Texture::Bc1) {
        Ok(ctx) => ctx,
        Err(e) if texture != Texture::Bc1 => {
            eprintln!("bench btf: no BC1 comparison ({e})");
            cfg.bc1_available = false;
            gpu.context()?
        }
        Err(e) => return Err(e),
    };
    eprintln!("bench btf on {}", ctx.info().name);
    let r = run(&ctx, &cfg, &mut |l| progress(l))?;
    print_btf(&r);
    write_json(opts, &r)?;
    finish(ctx)
}

fn print_btf(r: &bench::btf::BtfBenchReport) {
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
        Texture::Block => ("block fetches", r.probe_block_fetches_per_second),
        _ => ("filtered fetches", r.probe_fetches_per_second),
    };
    println!(
        "fetches                {:.1} M taps/s = {:.1}% of the {:.1} M {what}/s the fetch probe sustains",
        h.taps_per_second / 1e6,
        100.0 * h.fraction_of_fetch_rate,
        rate / 1e6
    );
    println!("roofline               {}", r.roofline.summary());
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
}

/// One line per bench target: name, measured, target, PASS or MISS.
fn print_targets(targets: &[crate::bench::ao::TargetCheck]) {
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

/// `bench all`.
fn all(
    gpu: &Gpu,
    dir: &Path,
    cfg: &bench::all::AllConfig,
    data_root: Option<&Path>,
    quick: bool,
) -> Result<()> {
    use bench::all::{Entry, KERNELS};
    let start = std::time::Instant::now();
    // Positive and at most `hi` (NaN is neither).
    let positive_to = |x: f64, hi: f64| x > 0.0 && x <= hi;
    if !(1..=1000).contains(&cfg.rounds)
        || !(1..=1000).contains(&cfg.bench.samples)
        || cfg.bench.warmup > 1000
        || !positive_to(cfg.peak.min_submit_ms, 60_000.0)
        || !positive_to(cfg.noise_bound, f64::MAX)
    {
        return Err(Error::InvalidArgument(
            "bench all: --rounds and --samples must be in 1..=1000, --warmup <= 1000, \
             --min-ms in (0, 60000], --noise-pct > 0"
                .into(),
        ));
    }
    if let Some(k) = cfg.kernels.iter().find(|k| !KERNELS.contains(&k.as_str())) {
        return Err(Error::InvalidArgument(format!(
            "bench all: unknown kernel '{k}' (one of {})",
            KERNELS.join(", ")
        )));
    }
    crate::io::outdir::claim(dir, "bench all")?;
    let (json, summary, png) = (
        dir.join("all.json"),
        dir.join("summary.md"),
        dir.join("all.png"),
    );
    for p in [&json, &summary, &png] {
        crate::io::check_writable(p)?;
    }
    // The frame needs 64-bit buffer atomics; the other kernels run on any context.
    let ctx = if cfg.kernels.iter().any(|k| k == "frame") {
        super::frame::context(gpu)?
    } else {
        gpu.context()?
    };
    eprintln!(
        "bench all on {}: {} rounds x {} submissions (+{} warm-up) per kernel",
        ctx.info().name,
        cfg.rounds,
        cfg.bench.samples,
        cfg.bench.warmup
    );
    let rooted = |p: &Path| match data_root {
        Some(r) => r.join(p.strip_prefix("/").unwrap_or(p)),
        None => p.to_path_buf(),
    };
    let ao_cfg = bench::ao::AoBenchConfig {
        mesh: rooted(Path::new(crate::kernels::ao::DEFAULT_MESH)),
        bench: cfg.bench.clone(),
        // The static correction's rays change its factors, not the work timed.
        rays: 256,
        ..Default::default()
    };
    let srbf_cfg = bench::srbf::SrbfBenchConfig {
        mesh: rooted(Path::new(crate::kernels::srbf::DEFAULT_MESH)),
        env: rooted(Path::new(crate::kernels::srbf::DEFAULT_ENV)),
        bench: cfg.bench.clone(),
        ..Default::default()
    };
    let sss_cfg = bench::sss::SssBenchConfig {
        mesh: rooted(Path::new(crate::kernels::sss::DEFAULT_MESH)),
        bench: cfg.bench.clone(),
        ..Default::default()
    };
    let btf_cfg = bench::btf::BtfBenchConfig {
        bench: cfg.bench.clone(),
        bc1_available: false,
        ..Default::default()
    };
    let mut frame_cfg = crate::frame::FrameConfig::default();
    frame_cfg.mesh = rooted(&frame_cfg.mesh);
    frame_cfg.env = frame_cfg.env.as_deref().map(rooted);
    let (mut ao, mut sss, mut srbf, mut btf, mut frame) = (None, None, None, None, None);
    for k in &cfg.kernels {
        let t = std::time::Instant::now();
        match k.as_str() {
            "ao" => ao = Some(bench::ao::AllBench::new(&ctx, &ao_cfg)?),
            "sss" => sss = Some(bench::sss::AllBench::new(&ctx, &sss_cfg)?),
            "srbf" => srbf = Some(bench::srbf::AllBench::new(&ctx, &srbf_cfg, quick)?),
            "btf" => btf = Some(bench::btf::AllBench::new(&ctx, &btf_cfg)?),
            _ => frame = Some(bench::frame::AllBench::new(&ctx, &frame_cfg, &cfg.bench)?),
        }
        progress(&format!("set up {k} in {:.1} s", t.elapsed().as_secs_f64()));
    }
    let mut entries: Vec<Entry<'_>> = Vec::new();
    for k in &cfg.kernels {
        match k.as_str() {
            "ao" => {
                if let Some(b) = &ao {
                    entries.push(Entry {
                        name: "ao",
                        round: Box::new(|| b.round()),
                    });
                }
            }
            "sss" => {
                if let Some(b) = &sss {
                    entries.push(Entry {
                        name: "sss",
                        round: Box::new(|| b.round()),
                    });
                }
            }
            "srbf" => {
                if let Some(b) = &srbf {
                    entries.push(Entry {
                        name: "srbf",
                        round: Box::new(|| b.round()),
                    });
                }
            }
            "btf" => {
                if let Some(b) = &btf {
                    entries.push(Entry {
                        name: "btf",
                        round: Box::new(|| b.round()),
                    });
                }
            }
            _ => {
                if let Some(b) = &frame {
                    entries.push(Entry {
                        name: "frame",
                        round: Box::new(|| b.round()),
                    });
                }
            }
        }
    }
    let mut report = bench::all::run(&ctx, cfg, &entries, &mut |l| progress(l))?;
    report.wall_s = start.elapsed().as_secs_f64();
    drop(entries);
    drop((ao, sss, srbf, btf, frame));
    let text = bench::all::table(&report);
    print!("{text}");
    crate::io::write_json(&json, &report)?;
    std::fs::write(&summary, &text).map_err(|e| Error::Io {
        path: summary.clone(),
        source: e,
    })?;
    println!("wrote {} and {}", json.display(), summary.display());
    // The plot is a convenience: a machine without a font (or a build without plots) still
    // gets the JSON and the table.
    match bench::plot::draw(&png, &bench::all::panels(&report)) {
        Ok(()) => println!("wrote {}", png.display()),
        Err(e) => eprintln!("bench all: no plot ({e})"),
    }
    finish(ctx)
}

/// `bench compare`.
fn compare(a: &Path, b: &Path, threshold: f64) -> Result<()> {
    use bench::compare::{Run, compare, render};
    if !(threshold.is_finite() && threshold >= 0.0) {
        return Err(Error::InvalidArgument(
            "bench compare: --threshold must be a percentage >= 0".into(),
        ));
    }
    let (ra, rb) = (Run::load(a)?, Run::load(b)?);
    let c = compare(&ra, &rb, threshold / 100.0);
    print!("{}", render(&ra, &rb, &c));
    let bad = c.regressions();
    if bad.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!(
            "bench compare: {} regression(s) beyond {threshold}%: {}",
            bad.len(),
            bad.iter()
                .map(|r| format!("{} ({:.3}x)", r.name, r.ratio))
                .collect::<Vec<_>>()
                .join(", ")
        )))
    }
}

/// `bench table`.
fn table(files: &[PathBuf]) -> Result<()> {
    let mut runs = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(f).map_err(|e| Error::Io {
            path: f.clone(),
            source: e,
        })?;
        runs.push((f.display().to_string(), text));
    }
    print!("{}", bench::compare::readme_table(&runs)?);
    Ok(())
}
