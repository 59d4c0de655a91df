//! `vkshade bench sss`: GPU time of the SSS passes (irradiance, diffusion) over texture size
//! x samples per texel on the BCN_Epileptic head (skin1 dipole, one directional light),
//! error against the brute-force ground truth as a function of time (at the size where the
//! truth is affordable), throughput against the FMA and bandwidth peaks measured in the same
//! run, and the speed-up over the same sampler on the CPU and over the brute force.

use super::{BenchConfig, MachineInfo, Stats, time_cpu};
use crate::bench::time_passes;
use crate::error::Result;
use crate::geom::bvh::Bvh;
use crate::gpu::Context;
use crate::kernels::Kernel;
use crate::kernels::sss::cpu::{self, Light, SamplerParams};
use crate::kernels::sss::gpu::{PASS_DIFFUSION, PASS_IRRADIANCE, PASS_VERTEX};
use crate::kernels::sss::load_mesh;
use crate::kernels::sss::{Material, Profile, ProfileKind, SssKernel, TexGeometry};
use crate::reference::sss::{ChannelError, Sources, brute_force};
use crate::scene::texspace::COVERED;
use glam::{DVec3, Vec3};
use serde::Serialize;
use std::path::PathBuf;

/// Work per diffusion sample (documented model, not a counter; one sample serves the three
/// channels): ~30 FLOP (barycentric rates, the inside test, the UV map of the triangle or of
/// the neighbour it leaves into, rounding to the nearest texel, three weighted sums) and 2
/// loads: the pattern texel (ux, uy, w_r, w_g; the same for every texel, so it is served
/// from cache) and the gathered grey irradiance (4 bytes). The bytes count the gather only.
pub mod work_model {
    pub const FLOP_PER_SAMPLE: f64 = 30.0;
    pub const BYTES_PER_SAMPLE: f64 = 4.0;
}

#[derive(Clone, Debug, Serialize)]
pub struct SssBenchConfig {
    pub mesh: PathBuf,
    pub part: String,
    pub mm_per_unit: f64,
    pub bench: BenchConfig,
    pub sizes: Vec<u32>,
    pub samples: Vec<u32>,
    /// The headline (size, samples).
    pub headline: (u32, u32),
    /// Size of the error-against-time sweep (the brute force runs once at this size).
    pub error_size: u32,
    pub cpu_runs: usize,
}

impl Default for SssBenchConfig {
    fn default() -> Self {
        SssBenchConfig {
            mesh: PathBuf::from(crate::kernels::sss::DEFAULT_MESH),
            part: crate::kernels::sss::DEFAULT_PART.into(),
            mm_per_unit: 1000.0,
            bench: BenchConfig {
                warmup: 1,
                samples: 3,
                min_submit_ms: 100.0,
            },
            sizes: vec![256, 512],
            samples: vec![8, 16, 32, 64],
            headline: (512, 32),
            error_size: 256,
            cpu_runs: 1,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub size: u32,
    pub samples: u32,
    /// Pass `sss vertex light`: shadow and transmission rays per mesh vertex.
    pub vertex_light_ms: Stats,
    /// Pass `sss irradiance`: per texel, the vertices' shadowing interpolated.
    pub irradiance_ms: Stats,
    pub diffusion_ms: Stats,
    pub total_ms: f64,
    pub fps: f64,
    /// Diffusion samples per second (covered and gutter texels x samples; a sample serves the
    /// three channels).
    pub samples_per_s: f64,
    pub fraction_of_fma_peak: f64,
    /// The gathered irradiance bytes per second against the streaming bandwidth peak. Not a
    /// bound: neighbouring texels gather neighbouring texels, so most gathers hit the cache.
    pub gathered_vs_stream_bandwidth: f64,
    /// At `error_size`: against the brute force.
    pub error: Option<ChannelError>,
    pub gpu_memory_bytes: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SssBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: SssBenchConfig,
    pub peak_fma_gflops: f64,
    pub bandwidth_gb_s: f64,
    pub headline: Point,
    /// The same sampler on the CPU (rayon), headline configuration: irradiance, transmission
    /// and diffusion.
    pub cpu_same_method_ms: Stats,
    pub speedup_vs_cpu: f64,
    /// Brute force at `error_size` against the GPU at (`error_size`, headline samples).
    pub brute_force_ms: Stats,
    pub brute_force_size: u32,
    pub speedup_vs_brute_force: f64,
    pub sweep: Vec<Point>,
}

fn lights() -> Vec<Light> {
    vec![Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }]
}

struct Truth {
    covered: Vec<usize>,
    b: Vec<[f64; 3]>,
}

#[allow(clippy::too_many_arguments)]
fn measure(
    ctx: &Context,
    cfg: &SssBenchConfig,
    geo: &TexGeometry,
    profile: &Profile,
    samples: u32,
    peaks: (f64, f64),
    truth: Option<&Truth>,
) -> Result<Point> {
    let params = SamplerParams {
        samples,
        ..SamplerParams::default()
    };
    let mut setup = ctx.recorder("sss bench setup")?;
    let kernel = SssKernel::new(&mut setup, geo, profile, params)?;
    setup.submit_and_wait()?;
    let lights = lights();
    let passes = time_passes(ctx, &cfg.bench, &kernel, &lights[..])?;
    let get = |name: &str| {
        passes
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, s)| s.clone())
            .unwrap_or_else(Stats::none)
    };
    let (v, e, d) = (get(PASS_VERTEX), get(PASS_IRRADIANCE), get(PASS_DIFFUSION));
    let total = v.median + e.median + d.median;
    let texels = geo.pos.iter().filter(|p| p[3] > 0.0).count() as f64;
    let n = texels * samples as f64;
    let per_s = n / (d.median * 1e-3);
    let error = match truth {
        None => None,
        Some(t) => {
            let mut rec = ctx.recorder("sss bench readback")?;
            kernel.record(&mut rec, &lights[..])?;
            let rb = kernel.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            let out = kernel.collect(&rb)?;
            let est: Vec<[f64; 3]> = t
                .covered
                .iter()
                .map(|&i| [0, 1, 2].map(|c| out.diffuse[i][c] as f64))
                .collect();
            let w: Vec<f64> = t.covered.iter().map(|&i| geo.nrm[i][3] as f64).collect();
            Some(ChannelError::of(&est, &t.b, &w))
        }
    };
    Ok(Point {
        size: geo.size,
        samples,
        vertex_light_ms: v,
        irradiance_ms: e,
        diffusion_ms: d,
        total_ms: total,
        fps: 1000.0 / total,
        samples_per_s: per_s,
        fraction_of_fma_peak: per_s * work_model::FLOP_PER_SAMPLE * 1e-9 / peaks.0,
        gathered_vs_stream_bandwidth: per_s * work_model::BYTES_PER_SAMPLE * 1e-9 / peaks.1,
        error,
        gpu_memory_bytes: kernel.memory().used_bytes,
    })
}

pub fn run(
    ctx: &Context,
    cfg: &SssBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SssBenchReport> {
    let mesh = load_mesh(&cfg.mesh, Some(&cfg.part))?;
    let profile = Profile::new(
        ProfileKind::Dipole,
        Material::SKIN1,
        crate::kernels::sss::profile::DEFAULT_ENERGY,
    )?;
    progress("device peaks (FMA, streaming) for the roofline");
    let fma = super::peak::run_fma(ctx, &cfg.bench, &mut |_| {})?.throughput_median;
    let bw = super::peak::run_stream(ctx, &cfg.bench, &mut |_| {})?.throughput_median;
    progress(&format!("  {fma:.1} GFLOP/s, {bw:.1} GB/s"));
    let peaks = (fma, bw);

    // Error against time at error_size: the truth once, from the CPU twin's irradiance
    // (the same rays as the GPU's).
    let geo_e = TexGeometry::build(&mesh, cfg.error_size, cfg.mm_per_unit)?;
    let bvh = Bvh::build(&geo_e.positions, &geo_e.triangles);
    let e = cpu::irradiance(
        &geo_e,
        &bvh,
        &lights(),
        SamplerParams::default().shadow_refine,
    );
    let covered: Vec<usize> = (0..geo_e.texels())
        .filter(|&i| geo_e.pos[i][3] == COVERED)
        .collect();
    let receivers: Vec<DVec3> = covered
        .iter()
        .map(|&i| Vec3::from_slice(&geo_e.pos[i][..3]).as_dvec3())
        .collect();
    let sources = Sources::from_texels(&geo_e, &e);
    let mut b = Vec::new();
    let brute = time_cpu(1, || b = brute_force(&sources, &receivers, &profile));
    progress(&format!(
        "brute force at {0}^2 ({1} texels): {2:.0} ms",
        cfg.error_size,
        covered.len(),
        brute.median
    ));
    let truth = Truth { covered, b };

    let mut sweep = Vec::new();
    let mut at_error_size_headline = None;
    for &size in &cfg.sizes {
        let geo = if size == cfg.error_size {
            geo_e.clone()
        } else {
            TexGeometry::build(&mesh, size, cfg.mm_per_unit)?
        };
        for &s in &cfg.samples {
            let t = (size == cfg.error_size).then_some(&truth);
            let p = measure(ctx, cfg, &geo, &profile, s, peaks, t)?;
            progress(&format!(
                "  {size}^2 x {s}: vertex light {:.1} + irradiance {:.1} + diffusion {:.1} ms = {:.2} fps{}",
                p.vertex_light_ms.median,
                p.irradiance_ms.median,
                p.diffusion_ms.median,
                p.fps,
                p.error
                    .as_ref()
                    .map(|e| format!(
                        "; rel RMSE {:.3?}, energy {:.3?}",
                        e.rel_rmse, e.energy_ratio
                    ))
                    .unwrap_or_default()
            ));
            if size == cfg.error_size && s == cfg.headline.1 {
                at_error_size_headline = Some(p.total_ms);
            }
            sweep.push(p);
        }
    }
    let (hs, hn) = cfg.headline;
    let headline = match sweep.iter().find(|p| p.size == hs && p.samples == hn) {
        Some(p) => p.clone(),
        None => {
            let geo = TexGeometry::build(&mesh, hs, cfg.mm_per_unit)?;
            measure(ctx, cfg, &geo, &profile, hn, peaks, None)?
        }
    };
    // The CPU twin at the headline.
    let geo = TexGeometry::build(&mesh, hs, cfg.mm_per_unit)?;
    let bvh = Bvh::build(&geo.positions, &geo.triangles);
    let params = SamplerParams {
        samples: hn,
        ..SamplerParams::default()
    };
    // The walk's maps and the contact sums are built once per pose on both sides (the GPU's
    // come with the geometry upload, outside the timed passes).
    let dg = cpu::DiffusionGeometry::build(&geo, &profile);
    let cpu_ms = time_cpu(cfg.cpu_runs, || {
        let e = cpu::irradiance(&geo, &bvh, &lights(), params.shadow_refine);
        // The GPU's irradiance pass also computes the transmission.
        let t = params
            .transmission
            .then(|| cpu::transmission(&geo, &bvh, &lights(), &profile));
        (cpu::diffusion_with(&dg, &geo, &profile, &e, &params), t)
    });
    progress(&format!(
        "CPU same sampler at {hs}^2 x {hn}: {:.0} ms",
        cpu_ms.median
    ));
    let gpu_at_error = match at_error_size_headline {
        Some(ms) => ms,
        None => measure(ctx, cfg, &geo_e, &profile, hn, peaks, None)?.total_ms,
    };
    Ok(SssBenchReport {
        benchmark: "vkshade bench sss",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        peak_fma_gflops: fma,
        bandwidth_gb_s: bw,
        speedup_vs_cpu: cpu_ms.median / headline.total_ms,
        cpu_same_method_ms: cpu_ms,
        speedup_vs_brute_force: brute.median / gpu_at_error,
        brute_force_ms: brute,
        brute_force_size: cfg.error_size,
        headline,
        sweep,
    })
}

/// Panels for `--plot`: relative RMSE (red channel and the worst channel) against GPU time,
/// and time against samples per size.
pub fn panels(r: &SssBenchReport) -> Vec<super::plot::Panel> {
    use super::plot::{Panel, Series};
    let at_err: Vec<&Point> = r.sweep.iter().filter(|p| p.error.is_some()).collect();
    let err_series = (0..3)
        .map(|c| Series {
            name: ["R", "G", "B"][c].into(),
            points: at_err
                .iter()
                .map(|p| {
                    (
                        p.total_ms,
                        p.error.as_ref().map(|e| e.rel_rmse[c]).unwrap_or(f64::NAN),
                    )
                })
                .collect(),
        })
        .collect();
    let time_series = r
        .config
        .sizes
        .iter()
        .map(|&s| Series {
            name: format!("{s}^2"),
            points: r
                .sweep
                .iter()
                .filter(|p| p.size == s)
                .map(|p| (p.samples as f64, p.total_ms))
                .collect(),
        })
        .collect();
    vec![
        Panel {
            title: format!("error vs time at {}^2 (samples 8..64)", r.brute_force_size),
            x_label: "GPU ms per frame".into(),
            y_label: "relative RMSE vs brute force".into(),
            log_x: true,
            log_y: true,
            series: err_series,
        },
        Panel {
            title: "GPU time per frame".into(),
            x_label: "samples per texel".into(),
            y_label: "ms".into(),
            log_x: true,
            log_y: true,
            series: time_series,
        },
    ]
}
