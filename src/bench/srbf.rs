//! `vkshade bench srbf`: GPU time of the SRBF passes over lobes x basis size x vertices
//! (clustered-PCA transfer),
//! GFLOP/s against the FMA peak measured in the same run, and the speed-up over the same
//! method on the CPU and over the brute-force integration, on the glmark2 bunny under a
//! Blender studio light.

use super::{BenchConfig, MachineInfo, Stats, time_cpu};
use crate::bench::time_passes;
use crate::error::Result;
use crate::geom::Rng;
use crate::geom::sg::{self, Lobe};
use crate::gpu::Context;
use crate::kernels::Kernel;
use crate::kernels::srbf::cpca::{Cpca, CpcaConfig};
use crate::kernels::srbf::diffuse_transfer;
use crate::kernels::srbf::fit::{FitConfig, fit};
use crate::kernels::srbf::gpu::{
    CompactInputs, PASS_LIGHTING, PASS_PROJECT, PASS_SHADE, PASS_SHARP, SrbfFrame, SrbfInputs,
    SrbfKernel,
};
use crate::kernels::srbf::sharp::DEFAULT_FIT_WIDTH;
use crate::kernels::srbf::transfer::Basis;
use crate::reference::srbf::shade_brute_force;
use crate::scene::envmap::EnvMap;
use crate::scene::envmap::texel_visibility;
use glam::Vec3;
use serde::Serialize;
use std::path::PathBuf;

/// Operation counts per unit of work (documented, not a hardware counter).
pub mod flop_model {
    /// One (lobe, basis function) pair of `srbf lighting`: rotation share, the SG inner
    /// product (a length, a division, two exponentials counted as 10 each) and 3 FMAs.
    pub const LIGHTING_PAIR: f64 = 40.0;
    /// One (row, basis function) term of `srbf project`, and one (vertex, component) term of
    /// `srbf shade`: 3 FMAs.
    pub const TERM: f64 = 6.0;
}

/// The work model of one frame of `p` (compressed transfer): FLOPs ([`flop_model`]),
/// storage-buffer loads at neighbouring addresses (`shade`: the weights, 8 half-precision
/// components to a uvec4, the vertex's slot and normal, one visibility word per compact
/// lobe; `project`: every row's basis coefficients as vec4s) and uniform-buffer reads at a
/// uniform index (`shade`: the cluster's mean and component rows, two per compact lobe).
/// `lighting` and `sharp` read a few KiB and are left out.
pub fn work_model(p: &Point) -> Vec<super::roofline::Term> {
    use super::roofline::Term;
    let nv = p.vertices as f64;
    let m = p.components as f64;
    let compact = p.compact_lobes as f64;
    let rows = (p.clusters * (p.components + 1)) as f64;
    vec![
        Term::new("fma", "FLOP (flop_model)", p.gflop_per_frame * 1e9),
        Term::new(
            "buffer_gather_coherent",
            "shade: weights, slot, normal, visibility; project: rows",
            nv * ((p.components.div_ceil(8)) as f64 + 2.0 + compact)
                + rows * (p.basis as f64 / 4.0),
        ),
        Term::new(
            "ubo_uniform",
            "shade: projected rows and compact-lobe taps",
            nv * (m + 1.0 + 2.0 * compact),
        ),
    ]
}

/// What the roofline of [`work_model`] covers.
pub const COVERS: &str = "lighting + project + sharp + shade passes";

/// What `bench srbf` measures.
#[derive(Clone, Debug, Serialize)]
pub struct SrbfBenchConfig {
    pub mesh: PathBuf,
    pub env: PathBuf,
    pub bench: BenchConfig,
    pub lobes: Vec<usize>,
    pub basis: Vec<usize>,
    /// Vertex counts (the mesh's own, and the mesh's vertices repeated or cut).
    pub vertices: Vec<usize>,
    /// The headline: (lobes, basis, vertices = the mesh's).
    pub headline: (usize, usize),
    /// Width of the direction map of the brute-force baseline and of the headline's real
    /// transfer and visibility (64, as `vkshade srbf shade`).
    pub brute_force_width: u32,
    pub cpu_runs: usize,
    /// The transfer compression of every point (the headline's on the real transfer).
    pub cpca: CpcaConfig,
}

impl Default for SrbfBenchConfig {
    fn default() -> Self {
        SrbfBenchConfig {
            mesh: PathBuf::from(crate::kernels::srbf::DEFAULT_MESH),
            env: PathBuf::from(crate::kernels::srbf::DEFAULT_ENV),
            bench: BenchConfig::default(),
            lobes: vec![16, 64, 256],
            basis: vec![64, 256, 1024],
            vertices: vec![3205, 34835],
            headline: (64, 256),
            brute_force_width: 64,
            cpu_runs: 3,
            cpca: CpcaConfig::default(),
        }
    }
}

/// One configuration's timing.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub lobes: usize,
    pub basis: usize,
    pub vertices: usize,
    /// 0 clusters: the uncompressed transfer.
    pub clusters: usize,
    pub components: usize,
    pub lighting_ms: Stats,
    pub project_ms: Stats,
    /// Taps of the compact lobes (see `compact_lobes`).
    pub sharp_ms: Stats,
    pub shade_ms: Stats,
    /// Lobes shaded from the visibility instead of through the basis (0 without it).
    pub compact_lobes: usize,
    pub total_ms: f64,
    pub fps: f64,
    pub gflop_per_frame: f64,
    pub gflops: f64,
    pub fraction_of_peak: f64,
    pub gpu_memory_bytes: u64,
    pub gpu_memory_reserved_bytes: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SrbfBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: SrbfBenchConfig,
    pub flop_model: [(&'static str, f64); 2],
    pub peak_fma_gflops: f64,
    /// The mesh's real transfer (at `brute_force_width` directions), compressed.
    pub headline: Point,
    /// Function-space relative L2 of the headline's compression.
    pub headline_cpca_rel_l2: f64,
    /// The same, uncompressed.
    pub uncompressed: Point,
    pub cpu_same_method_ms: Stats,
    pub speedup_vs_cpu: f64,
    pub brute_force_ms: Stats,
    pub speedup_vs_brute_force: f64,
    pub sweep: Vec<Point>,
    pub skipped: Vec<String>,
    /// The headline against its binding roofline ([`work_model`], rates measured in this
    /// run).
    pub roofline: super::roofline::Roofline,
}

/// A transfer of the given shape with random values (the passes' cost depends on the shape
/// and on how the vertices spread over clusters, not on the values).
fn synthetic_cpca(basis: usize, vertices: usize, cfg: &CpcaConfig, seed: u64) -> Cpca {
    let mut rng = Rng::new(seed);
    let (clusters, m) = (cfg.clusters.min(vertices), cfg.components.min(basis));
    Cpca {
        basis: Basis::fibonacci(basis),
        vertices,
        clusters,
        components: m,
        cluster_of: (0..vertices).map(|_| rng.below(clusters) as u32).collect(),
        rows: (0..clusters * (m + 1) * basis)
            .map(|_| rng.f32() * 0.01)
            .collect(),
        weights: (0..vertices * m).map(|_| rng.f32()).collect(),
        rel_l2: f64::NAN,
    }
}

fn synthetic_lobes(n: usize, seed: u64) -> Vec<Lobe> {
    let mut rng = Rng::new(seed);
    sg::fibonacci_sphere(n)
        .into_iter()
        .map(|axis| Lobe {
            axis: axis.to_array(),
            sharpness: 2.0 + 50.0 * rng.f32(),
            amplitude: [rng.f32(), rng.f32(), rng.f32()],
        })
        .collect()
}

pub(super) fn measure(
    ctx: &Context,
    cfg: &BenchConfig,
    lobes: &[Lobe],
    t: &Cpca,
    compact: Option<CompactInputs<'_>>,
    compressed: bool,
    peak: f64,
) -> Result<Point> {
    let mut setup = ctx.recorder("srbf bench setup")?;
    let mut inputs = SrbfInputs::new(lobes, t);
    inputs.compact = compact;
    let kernel = SrbfKernel::new(&mut setup, &inputs)?;
    setup.submit_and_wait()?;
    let frame = SrbfFrame {
        rotation: sg::rotation(Vec3::Y, 30.0),
        albedo: [1.0; 3],
    };
    let passes = time_passes(ctx, cfg, &kernel, &frame)?;
    let get = |name: &str| {
        passes
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, s)| s.clone())
            .unwrap_or_else(Stats::none)
    };
    let (lighting, project, sharp, shade) = (
        get(PASS_LIGHTING),
        get(PASS_PROJECT),
        get(PASS_SHARP),
        get(PASS_SHADE),
    );
    let total = lighting.median + project.median + sharp.median + shade.median;
    let k = t.basis.len() as f64;
    let rows = (t.clusters * (t.components + 1)) as f64;
    let flop = lobes.len() as f64 * k * flop_model::LIGHTING_PAIR
        + rows * k * flop_model::TERM
        + t.vertices as f64 * (t.components + 1) as f64 * flop_model::TERM;
    let gflops = flop / (total * 1e-3) * 1e-9;
    let memory = kernel.memory();
    Ok(Point {
        lobes: lobes.len(),
        basis: t.basis.len(),
        vertices: t.vertices,
        clusters: if compressed { t.clusters } else { 0 },
        components: if compressed { t.components } else { 0 },
        lighting_ms: lighting,
        project_ms: project,
        sharp_ms: sharp,
        shade_ms: shade,
        compact_lobes: kernel.compact_count(),
        total_ms: total,
        fps: 1000.0 / total,
        gflop_per_frame: flop * 1e-9,
        gflops,
        fraction_of_peak: gflops / peak,
        gpu_memory_bytes: memory.used_bytes,
        gpu_memory_reserved_bytes: memory.reserved_bytes,
    })
}

/// `lobes` lobes fitted to `env` downsampled to `srbf shade`'s default fit width, and the
/// width of the map they were fitted to (which decides which compact lobes are points).
fn fit_lobes(env: &EnvMap, lobes: usize) -> Result<(crate::kernels::srbf::fit::Fit, u32)> {
    let small = env.downsampled(DEFAULT_FIT_WIDTH.min(env.width))?;
    let fitted = fit(
        &small.samples(),
        &FitConfig {
            lobes,
            ..FitConfig::default()
        },
    )?;
    Ok((fitted, small.width))
}

/// Runs the benchmark.
pub fn run(
    ctx: &Context,
    cfg: &SrbfBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SrbfBenchReport> {
    let character = crate::scene::load(&cfg.mesh)?;
    let mesh = &character.mesh;
    let nv = mesh.positions.len();
    progress("device peak (FMA) for the roofline");
    let peak = super::peak::run_fma(ctx, &cfg.bench, &mut |_| {})?.throughput_median;
    progress(&format!("  {peak:.1} GFLOP/s"));

    // Headline: a real fit, the mesh's real transfer (visibility ray-cast at the directions
    // of the brute-force baseline), compressed as configured; and the same uncompressed.
    let env = EnvMap::load(&cfg.env)?;
    let (hl, hk) = cfg.headline;
    let (fitted, fit_width) = fit_lobes(&env, hl)?;
    let dir_env = env.downsampled(cfg.brute_force_width.min(env.width))?;
    progress("transfer of the mesh (visibility, projection, compression)");
    let vis = texel_visibility(mesh, &dir_env);
    let real = diffuse_transfer(&Basis::fibonacci(hk), &dir_env, &mesh.normals, &vis)?;
    let cpca = Cpca::compress(&real, &cfg.cpca)?;
    // The shipped default: compact lobes shaded from the visibility.
    let compact = CompactInputs {
        visibility: &vis,
        normals: &mesh.normals,
        width: dir_env.width,
        height: dir_env.height,
        factor: crate::kernels::srbf::sharp::DEFAULT_FACTOR,
        max_lobes: crate::kernels::srbf::sharp::DEFAULT_MAX_LOBES,
        fit_width,
    };
    let headline = measure(
        ctx,
        &cfg.bench,
        &fitted.lobes,
        &cpca,
        Some(compact),
        true,
        peak,
    )?;
    progress(&format!(
        "headline: {hl} lobes ({} compact) x {hk} basis x {nv} vertices, {} clusters x {} components: lighting {:.3} + project {:.3} + sharp {:.3} + shade {:.3} ms = {:.0} fps, {:.1} GFLOP/s ({:.1}% of peak)",
        headline.compact_lobes,
        cpca.clusters,
        cpca.components,
        headline.lighting_ms.median,
        headline.project_ms.median,
        headline.sharp_ms.median,
        headline.shade_ms.median,
        headline.fps,
        headline.gflops,
        100.0 * headline.fraction_of_peak
    ));
    let uncompressed = measure(
        ctx,
        &cfg.bench,
        &fitted.lobes,
        &Cpca::exact(&real),
        Some(compact),
        false,
        peak,
    )?;
    progress(&format!(
        "uncompressed: {:.3} ms = {:.0} fps",
        uncompressed.total_ms, uncompressed.fps
    ));

    // Baselines: the same method on the CPU, and brute force.
    let frame = SrbfFrame {
        rotation: sg::rotation(Vec3::Y, 30.0),
        albedo: [1.0; 3],
    };
    let cpu_inputs = SrbfInputs::new(&fitted.lobes, &cpca).with_compact(compact);
    let cpu = time_cpu(cfg.cpu_runs, || cpu_inputs.cpu_pipeline(&frame));
    progress(&format!("CPU same method: {:.2} ms", cpu.median));
    let brute = time_cpu(1, || {
        shade_brute_force(&dir_env, frame.rotation, &mesh.normals, &vis, frame.albedo)
    });
    progress(&format!(
        "brute force ({}x{} directions): {:.1} ms",
        dir_env.width, dir_env.height, brute.median
    ));

    // Sweep: lobes x basis x vertices (synthetic lobes and transfer).
    let mut sweep = Vec::new();
    let mut skipped = Vec::new();
    let max_bytes = ctx.limits().max_storage_buffer_range;
    for &v in &cfg.vertices {
        for &k in &cfg.basis {
            let m = cfg.cpca.components.min(k);
            let bytes = (m.div_ceil(8) * 16 * (v + 64 * cfg.cpca.clusters)) as u64;
            if bytes > max_bytes {
                skipped.push(format!(
                    "{k} basis x {v} vertices: the weights ({bytes} bytes) exceed \
                     maxStorageBufferRange ({max_bytes})"
                ));
                progress(&format!(
                    "  skipped: {}",
                    skipped.last().expect("just pushed")
                ));
                continue;
            }
            let t = synthetic_cpca(k, v, &cfg.cpca, 2);
            for &l in &cfg.lobes {
                let p = measure(
                    ctx,
                    &cfg.bench,
                    &synthetic_lobes(l, 3),
                    &t,
                    None,
                    true,
                    peak,
                )?;
                progress(&format!(
                    "  {l} lobes x {k} basis x {v} vertices: {:.3} ms ({:.1} GFLOP/s)",
                    p.total_ms, p.gflops
                ));
                sweep.push(p);
            }
        }
    }
    let total = headline.total_ms;
    let terms = work_model(&headline);
    progress("rates of the work model (probes)");
    let rates = super::roofline::measure_rates(ctx, &cfg.bench, &terms, Some(peak))?;
    let roofline = super::roofline::Roofline::evaluate(COVERS, terms, total, &rates);
    Ok(SrbfBenchReport {
        roofline,
        benchmark: "vkshade bench srbf",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        flop_model: [
            ("lighting per (lobe, basis) pair", flop_model::LIGHTING_PAIR),
            (
                "project per (row, basis) and shade per (vertex, component) term",
                flop_model::TERM,
            ),
        ],
        peak_fma_gflops: peak,
        speedup_vs_cpu: cpu.median / total,
        speedup_vs_brute_force: brute.median / total,
        cpu_same_method_ms: cpu,
        brute_force_ms: brute,
        headline,
        headline_cpca_rel_l2: cpca.rel_l2,
        uncompressed,
        sweep,
        skipped,
    })
}

/// `bench all`'s SRBF: the fit, transfer and compression once, then the headline (and the
/// CPU twin) once per round.
pub struct AllBench<'a> {
    ctx: &'a Context,
    cfg: &'a SrbfBenchConfig,
    normals: Vec<Vec3>,
    lobes: Vec<Lobe>,
    /// The visibility for compact lobes and its grid (None: a synthetic transfer).
    vis: Option<(crate::geom::visibility::Visibility, u32, u32)>,
    /// Width of the map the lobes were fitted to (with `vis`).
    fit_width: u32,
    cpca: Cpca,
    fps_min: Option<f64>,
}

impl<'a> AllBench<'a> {
    /// `synthetic`: the sweep's synthetic transfer of the bunny's size and compressed shape
    /// (the same work per frame, no compact lobe) instead of ray-casting the real one
    /// (minutes on a loaded 2-core machine): `bench all --quick`.
    pub fn new(
        ctx: &'a Context,
        cfg: &'a SrbfBenchConfig,
        synthetic: bool,
    ) -> Result<AllBench<'a>> {
        let targets: serde_json::Value = serde_json::from_str(super::ao::TARGETS).map_err(|e| {
            crate::error::Error::InvalidArgument(format!("bench/targets.json: {e}"))
        })?;
        let character = crate::scene::load(&cfg.mesh)?;
        let (hl, hk) = cfg.headline;
        let fps_min = targets["srbf"]["fps_min"].as_f64();
        if synthetic {
            let nv = character.mesh.positions.len();
            return Ok(AllBench {
                ctx,
                cfg,
                normals: character.mesh.normals.clone(),
                lobes: synthetic_lobes(hl, 3),
                vis: None,
                fit_width: DEFAULT_FIT_WIDTH,
                cpca: synthetic_cpca(hk, nv, &cfg.cpca, 2),
                fps_min,
            });
        }
        let env = EnvMap::load(&cfg.env)?;
        let (fitted, fit_width) = fit_lobes(&env, hl)?;
        let dir_env = env.downsampled(cfg.brute_force_width.min(env.width))?;
        let vis = texel_visibility(&character.mesh, &dir_env);
        let real = diffuse_transfer(
            &Basis::fibonacci(hk),
            &dir_env,
            &character.mesh.normals,
            &vis,
        )?;
        let cpca = Cpca::compress(&real, &cfg.cpca)?;
        Ok(AllBench {
            ctx,
            cfg,
            normals: character.mesh.normals.clone(),
            lobes: fitted.lobes,
            vis: Some((vis, dir_env.width, dir_env.height)),
            fit_width,
            cpca,
            fps_min,
        })
    }

    /// One round: the headline's GPU time and work model, the CPU twin's wall time.
    pub fn round(&self) -> Result<super::all::Round> {
        let compact = self.vis.as_ref().map(|(vis, width, height)| CompactInputs {
            visibility: vis,
            normals: &self.normals,
            width: *width,
            height: *height,
            factor: crate::kernels::srbf::sharp::DEFAULT_FACTOR,
            max_lobes: crate::kernels::srbf::sharp::DEFAULT_MAX_LOBES,
            fit_width: self.fit_width,
        });
        let p = measure(
            self.ctx,
            &self.cfg.bench,
            &self.lobes,
            &self.cpca,
            compact,
            true,
            f64::NAN,
        )?;
        let frame = SrbfFrame {
            rotation: sg::rotation(Vec3::Y, 30.0),
            albedo: [1.0; 3],
        };
        let mut inputs = SrbfInputs::new(&self.lobes, &self.cpca);
        if let Some(c) = compact {
            inputs = inputs.with_compact(c);
        }
        let cpu = time_cpu(1, || inputs.cpu_pipeline(&frame));
        let within = [&p.lighting_ms, &p.project_ms, &p.sharp_ms, &p.shade_ms]
            .iter()
            .map(|s| s.iqr_rel)
            .fold(0.0, f64::max);
        Ok(super::all::Round {
            kernel: "srbf",
            headline: format!(
                "bunny, {} vertices, {} lobes ({} compact), {} basis{}",
                p.vertices,
                p.lobes,
                p.compact_lobes,
                p.basis,
                if self.vis.is_none() {
                    " (synthetic transfer)"
                } else {
                    ""
                }
            ),
            gpu_ms: p.total_ms,
            within_iqr_rel: within,
            terms: work_model(&p),
            covers: COVERS,
            covered_ms: p.total_ms,
            cpu_ms: cpu.median,
            target_fps: self.fps_min,
        })
    }
}
