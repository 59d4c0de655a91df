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
use crate::kernels::sss::Regions;
use crate::kernels::sss::cpu::{self, Light, SamplerParams};
use crate::kernels::sss::gpu::{
    PASS_DIFFUSION, PASS_IRRADIANCE, PASS_IRRADIANCE_RAYS, PASS_VERTEX,
};
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
    /// Storage-image loads per sample (glsl/common/sss_diffusion.glsl) that differ per lane:
    /// the gathered grey irradiance (r32f), counted at the rate of `image_gather_coherent`
    /// (rgba32f loads; a narrower load is at least as fast, so the fraction is an upper
    /// bound). The pattern texel, the same for every lane, is left out.
    pub const LOADS_PER_SAMPLE: f64 = 1.0;
    /// Per texel: its start record and the 9 walk records of its triangle, its own source.
    pub const LOADS_PER_TEXEL: f64 = 11.0;
}

/// The work model of the diffusion pass of `p` (the roofline covers that pass, the frame's
/// largest): FLOPs and storage-image loads.
pub fn roofline_terms(p: &Point) -> Vec<super::roofline::Term> {
    use super::roofline::Term;
    let samples = p.samples_per_s * p.diffusion_ms.median * 1e-3;
    let texels = samples / p.samples as f64;
    vec![
        Term::new(
            "fma",
            "FLOP (work_model::FLOP_PER_SAMPLE)",
            samples * work_model::FLOP_PER_SAMPLE,
        ),
        Term::new(
            "image_gather_coherent",
            "storage-image loads (work_model)",
            samples * work_model::LOADS_PER_SAMPLE + texels * work_model::LOADS_PER_TEXEL,
        ),
    ]
}

/// What the roofline of [`roofline_terms`] covers.
pub const COVERS: &str = "diffusion pass";

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
    /// Pass `sss irradiance rays`: the shadow rays of the texels whose triangle a shadow
    /// boundary crosses.
    pub irradiance_rays_ms: Stats,
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
    /// The headline with two skin regions (multi-region skin: the head's triangles left of
    /// its mean x skin 1, the rest skin 2), measured in the same run.
    pub two_regions: Point,
    /// Its GPU time over the headline's (one region): what the per-texel profile costs.
    pub two_regions_vs_one: f64,
    /// The headline's diffusion pass against its binding roofline ([`roofline_terms`], rates
    /// measured in this run).
    pub roofline: super::roofline::Roofline,
}

/// Per triangle: 1 where its centroid lies at or right of the mesh's mean x, else 0.
fn halves(geo: &TexGeometry) -> Vec<u8> {
    let n = geo.positions.len().max(1) as f32;
    let mean_x = geo.positions.iter().map(|p| p.x).sum::<f32>() / n;
    geo.triangles
        .iter()
        .map(|t| {
            (t.iter().map(|&v| geo.positions[v as usize].x).sum::<f32>() >= 3.0 * mean_x) as u8
        })
        .collect()
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
    regions: &Regions,
    samples: u32,
    peaks: (f64, f64),
    truth: Option<&Truth>,
) -> Result<Point> {
    let params = SamplerParams {
        samples,
        ..SamplerParams::default()
    };
    let mut setup = ctx.recorder("sss bench setup")?;
    let kernel = SssKernel::new(&mut setup, geo, regions, params)?;
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
    let r = get(PASS_IRRADIANCE_RAYS);
    let total = v.median + e.median + r.median + d.median;
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
        irradiance_rays_ms: r,
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
    let regions = Regions::from(&profile);
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
            let p = measure(ctx, cfg, &geo, &regions, s, peaks, t)?;
            progress(&format!(
                "  {size}^2 x {s}: vertex light {:.1} + irradiance {:.1} + its rays {:.1} + diffusion {:.1} ms = {:.2} fps{}",
                p.vertex_light_ms.median,
                p.irradiance_ms.median,
                p.irradiance_rays_ms.median,
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
            measure(ctx, cfg, &geo, &regions, hn, peaks, None)?
        }
    };
    // The CPU twin at the headline.
    let geo = TexGeometry::build(&mesh, hs, cfg.mm_per_unit)?;
    // The headline again with two skin regions (each texel reads its own profile's rows).
    let skin2 = Profile::new(
        ProfileKind::Dipole,
        Material::SKIN2,
        crate::kernels::sss::profile::DEFAULT_ENERGY,
    )?;
    let two = Regions::new(vec![profile.clone(), skin2], halves(&geo))?;
    let two_regions = measure(ctx, cfg, &geo, &two, hn, peaks, None)?;
    progress(&format!(
        "  {hs}^2 x {hn}, two skin regions: vertex light {:.1} + irradiance {:.1} + its rays {:.1} + diffusion {:.1} ms = {:.2} fps",
        two_regions.vertex_light_ms.median,
        two_regions.irradiance_ms.median,
        two_regions.irradiance_rays_ms.median,
        two_regions.diffusion_ms.median,
        two_regions.fps
    ));
    let bvh = Bvh::build(&geo.positions, &geo.triangles);
    let params = SamplerParams {
        samples: hn,
        ..SamplerParams::default()
    };
    // The walk's maps and the contact sums are built once per pose on both sides (the GPU's
    // come with the geometry upload, outside the timed passes).
    let dg = cpu::DiffusionGeometry::build(&geo, &regions);
    let cpu_ms = time_cpu(cfg.cpu_runs, || {
        let e = cpu::irradiance(&geo, &bvh, &lights(), params.shadow_refine);
        // The GPU's irradiance pass also computes the transmission.
        let t = params
            .transmission
            .then(|| cpu::transmission(&geo, &bvh, &lights(), &regions));
        (cpu::diffusion_with(&dg, &geo, &regions, &e, &params), t)
    });
    progress(&format!(
        "CPU same sampler at {hs}^2 x {hn}: {:.0} ms",
        cpu_ms.median
    ));
    let gpu_at_error = match at_error_size_headline {
        Some(ms) => ms,
        None => measure(ctx, cfg, &geo_e, &regions, hn, peaks, None)?.total_ms,
    };
    let terms = roofline_terms(&headline);
    progress("rates of the work model (probes)");
    let rates = super::roofline::measure_rates(ctx, &cfg.bench, &terms, Some(fma))?;
    let roofline =
        super::roofline::Roofline::evaluate(COVERS, terms, headline.diffusion_ms.median, &rates);
    Ok(SssBenchReport {
        roofline,
        benchmark: "vkshade bench sss",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        peak_fma_gflops: fma,
        bandwidth_gb_s: bw,
        speedup_vs_cpu: cpu_ms.median / headline.total_ms,
        two_regions_vs_one: two_regions.total_ms / headline.total_ms,
        two_regions,
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

/// `vkshade bench sss --anim`: the whole per-frame path of a skinned head on the GPU.
#[derive(Clone, Debug, Serialize)]
pub struct SssAnimBenchConfig {
    pub mesh: PathBuf,
    pub part: String,
    pub animation: String,
    pub mm_per_unit: f64,
    pub size: u32,
    pub samples: u32,
    /// Untimed frames, then timed frames (poses spread over the animation).
    pub warmup: usize,
    pub frames: usize,
}

impl Default for SssAnimBenchConfig {
    fn default() -> Self {
        SssAnimBenchConfig {
            mesh: PathBuf::from(crate::kernels::sss::DEFAULT_MESH),
            part: crate::kernels::sss::DEFAULT_PART.into(),
            animation: "Epileptisch".into(),
            mm_per_unit: 1000.0,
            size: 512,
            samples: 32,
            warmup: 2,
            frames: 12,
        }
    }
}

/// What `bench sss --anim` measures.
#[derive(Clone, Debug, Serialize)]
pub struct SssAnimBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: SssAnimBenchConfig,
    /// GPU ms per pass (skinning, per-frame geometry, lights, shadows, irradiance,
    /// diffusion), over the timed frames.
    pub passes: Vec<(String, Stats)>,
    /// GPU ms of a whole frame (the sum of its passes) and the fps it gives.
    pub gpu_ms_per_frame: Stats,
    pub gpu_fps: f64,
    /// Frames per second of wall-clock time with two frames in flight (recording the next
    /// while the device runs the last).
    pub wall_fps: f64,
    /// Host ms per frame recording and submitting (pose joints, the kernels' passes, the
    /// lights), excluding the waits; and evaluating the animation into joint matrices.
    pub host_ms_per_frame: Stats,
    pub host_ms_animation: Stats,
    /// The same run's static frame (the rest pose's geometry uploaded once: lights, shadows,
    /// irradiance, diffusion; the sum of the passes' medians) and the ratio of the animated
    /// frame to it.
    pub static_gpu_ms_per_frame: f64,
    pub anim_over_static: f64,
    /// What the per-frame geometry cost the host before (CPU skinning, texture-space
    /// rasterisation, BVH, walk and contact build, packing: the old `sss --anim`), one pose.
    pub cpu_geometry_ms_per_frame_before: Stats,
    /// Of which the contact build.
    pub cpu_contact_ms_per_frame_before: Stats,
    /// The irradiance and diffusion with a per-vertex rgb irradiance against without.
    pub rgb_path: RgbPathCost,
}

/// Runs `bench sss --anim`.
pub fn run_anim(
    ctx: &Context,
    cfg: &SssAnimBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<SssAnimBenchReport> {
    use crate::kernels::pose::{PoseKernel, Prepared};
    use crate::kernels::sss::{PosedBuffers, load_character};
    let ch = load_character(&cfg.mesh, Some(&cfg.part))?;
    let anim = ch.animation(&cfg.animation)?;
    let mesh = &ch.mesh;
    let profile = Profile::new(
        ProfileKind::Dipole,
        Material::SKIN1,
        crate::kernels::sss::profile::DEFAULT_ENERGY,
    )?;
    let params = SamplerParams {
        samples: cfg.samples,
        ..SamplerParams::default()
    };
    let geo = TexGeometry::build(mesh, cfg.size, cfg.mm_per_unit)?;
    let lights = lights();
    let mut setup = ctx.recorder("sss anim bench setup")?;
    let prep = Prepared::new(mesh, ch.rig.joints.len())?;
    let pose = PoseKernel::new(&mut setup, &prep)?;
    let src = PosedBuffers {
        positions: pose.positions(),
        normals: pose.normals(),
        mm_per_unit: cfg.mm_per_unit as f32,
    };
    let mut kernel =
        SssKernel::new_posed(&mut setup, &geo, &mesh.positions, &profile, params, src)?;
    let still = SssKernel::new(&mut setup, &geo, &profile, params)?;
    setup.submit_and_wait()?;
    progress(&format!(
        "{}: {} vertices, {} triangles; {}^2 x {} samples",
        mesh.name,
        mesh.positions.len(),
        mesh.triangles.len(),
        cfg.size,
        cfg.samples
    ));
    let n = cfg.warmup + cfg.frames.max(1);
    let time_of = |f: usize| anim.duration * (f as f32 + 0.5) / n as f32;
    let mut per_pass: Vec<(String, Vec<f64>)> = Vec::new();
    let (mut gpu, mut host, mut animation) = (vec![], vec![], vec![]);
    // Two frames in flight: the host records frame f while the device runs frame f - 1.
    let mut pending: std::collections::VecDeque<crate::gpu::Submission> = Default::default();
    let mut finish = |sub: crate::gpu::Submission, timed: bool| -> Result<()> {
        let t = sub.wait()?;
        if timed {
            gpu.push(t.passes.iter().map(|p| p.ms).sum::<f64>());
            for p in &t.passes {
                match per_pass.iter_mut().find(|(n, _)| *n == p.name) {
                    Some((_, v)) => v.push(p.ms),
                    None => per_pass.push((p.name.to_string(), vec![p.ms])),
                }
            }
        }
        Ok(())
    };
    let mut wall = std::time::Instant::now();
    for f in 0..n {
        if f == cfg.warmup {
            while let Some(s) = pending.pop_front() {
                finish(s, false)?;
            }
            wall = std::time::Instant::now();
        }
        let t = std::time::Instant::now();
        let m = ch.rig.skinning_matrices(Some(anim), time_of(f));
        let ms_anim = t.elapsed().as_secs_f64() * 1e3;
        let t = std::time::Instant::now();
        let mut rec = ctx.recorder("sss anim frame")?;
        pose.record(&mut rec, &m)?;
        kernel.record(&mut rec, &lights[..])?;
        let sub = rec.submit()?;
        let ms_host = t.elapsed().as_secs_f64() * 1e3;
        if f >= cfg.warmup {
            host.push(ms_host);
            animation.push(ms_anim);
        }
        pending.push_back(sub);
        if pending.len() >= 2
            && let Some(s) = pending.pop_front()
        {
            finish(s, f > cfg.warmup)?;
        }
    }
    while let Some(s) = pending.pop_front() {
        finish(s, true)?;
    }
    let wall_fps = cfg.frames.max(1) as f64 / wall.elapsed().as_secs_f64();
    let stats = |v: &[f64]| Stats::of(v).unwrap_or_else(Stats::none);
    let gpu_ms = stats(&gpu);
    // The static frame in the same run.
    let bench = super::BenchConfig {
        warmup: 1,
        samples: 3,
        min_submit_ms: 0.0,
    };
    let still_passes = time_passes(ctx, &bench, &still, &lights[..])?;
    let static_ms = still_passes.iter().map(|(_, s)| s.median).sum::<f64>();
    // The rgb path: the last pose's frame without and with a per-vertex irradiance.
    let rgb_path = time_rgb_path(ctx, &bench, &mut kernel, &lights[..])?;
    // The old per-frame host work, one pose (the middle of the animation).
    let m = ch.rig.skinning_matrices(Some(anim), 0.5 * anim.duration);
    let regions = Regions::from(&profile);
    let room = crate::kernels::sss::pack::Room::of(&crate::kernels::sss::pack::Packed::new(
        &geo, &regions,
    )?);
    // The old per-frame host work (one run): pose, rasterise, then pack (BVH, walk and
    // contact builds); the contact build alone timed apart on the same pose.
    let before = time_cpu(1, || -> Result<()> {
        let posed = crate::scene::texspace::posed(mesh, &m)?;
        let g = TexGeometry::build(&posed, cfg.size, cfg.mm_per_unit)?;
        room.pack(&g, &regions).map(|_| ())
    });
    let posed = crate::scene::texspace::posed(mesh, &m)?;
    let g = TexGeometry::build(&posed, cfg.size, cfg.mm_per_unit)?;
    let contact = time_cpu(1, || {
        crate::kernels::sss::contact::Contact::build(&g, &regions)
    });
    let report = SssAnimBenchReport {
        benchmark: "vkshade bench sss --anim",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        passes: per_pass
            .iter()
            .map(|(n, v)| (n.clone(), stats(v)))
            .collect(),
        gpu_fps: 1000.0 / gpu_ms.median,
        wall_fps,
        host_ms_per_frame: stats(&host),
        host_ms_animation: stats(&animation),
        anim_over_static: gpu_ms.median / static_ms,
        static_gpu_ms_per_frame: static_ms,
        gpu_ms_per_frame: gpu_ms,
        cpu_geometry_ms_per_frame_before: before,
        cpu_contact_ms_per_frame_before: contact,
        rgb_path,
    };
    Ok(report)
}

/// What a per-vertex rgb irradiance ([`SssKernel::set_vertex_irradiance`], the character
/// frame's environment term) costs: the irradiance (with its rays pass) and diffusion passes
/// of the same frame without it (grey E) and with it (rgb E).
#[derive(Clone, Debug, Serialize)]
pub struct RgbPathCost {
    pub grey_irradiance_ms: f64,
    pub grey_diffusion_ms: f64,
    pub rgb_irradiance_ms: f64,
    pub rgb_diffusion_ms: f64,
}

/// Times `kernel`'s frame (the pose its posed buffers hold) without, then with, a constant
/// per-vertex irradiance (the cost does not depend on its values); leaves it unset.
fn time_rgb_path(
    ctx: &Context,
    bench: &super::BenchConfig,
    kernel: &mut SssKernel,
    lights: &[Light],
) -> Result<RgbPathCost> {
    use crate::gpu::{Buffer, BufferDesc};
    let of = |passes: &[(&str, Stats)], name: &str| {
        passes
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, s)| s.median)
            .unwrap_or(f64::NAN)
    };
    let grey = time_passes(ctx, bench, &*kernel, lights)?;
    let vertices = kernel.vertex_count() as usize;
    let mut rec = ctx.recorder("sss bench vertex irradiance")?;
    let e = vec![[0.25f32, 0.2, 0.15, 0.0]; vertices.max(1)];
    let buffer = Buffer::new(
        ctx,
        "sss bench vertex E",
        BufferDesc::storage(e.len() as u64 * 16),
    )?;
    rec.upload(&buffer, 0, &e)?;
    kernel.set_vertex_irradiance(&mut rec, Some(&buffer))?;
    rec.submit_and_wait()?;
    let rgb = time_passes(ctx, bench, &*kernel, lights)?;
    let mut rec = ctx.recorder("sss bench vertex irradiance off")?;
    kernel.set_vertex_irradiance(&mut rec, None)?;
    rec.submit_and_wait()?;
    Ok(RgbPathCost {
        grey_irradiance_ms: of(&grey, PASS_IRRADIANCE) + of(&grey, PASS_IRRADIANCE_RAYS),
        grey_diffusion_ms: of(&grey, PASS_DIFFUSION),
        rgb_irradiance_ms: of(&rgb, PASS_IRRADIANCE) + of(&rgb, PASS_IRRADIANCE_RAYS),
        rgb_diffusion_ms: of(&rgb, PASS_DIFFUSION),
    })
}

/// The table of `bench sss --anim`.
pub fn print_anim(r: &SssAnimBenchReport) {
    let c = &r.config;
    println!("device                 {}", r.machine.device);
    println!(
        "frame                  {} {}^2 x {} samples, {} ({} timed frames over the animation)",
        c.part, c.size, c.samples, c.animation, c.frames
    );
    for (name, s) in &r.passes {
        println!("  {name:<22} {:>8.2} ms GPU (median)", s.median);
    }
    let target = |ok: bool| if ok { "PASS" } else { "MISS" };
    println!(
        "GPU per frame          {:.2} ms = {:.1} fps (target >= 30) {}; wall clock {:.1} fps \
         (two in flight)",
        r.gpu_ms_per_frame.median,
        r.gpu_fps,
        target(r.gpu_fps >= 30.0),
        r.wall_fps
    );
    println!(
        "host per frame         {:.3} ms recording + submitting (target <= 1) {}; {:.3} ms \
         evaluating the animation",
        r.host_ms_per_frame.median,
        target(r.host_ms_per_frame.median <= 1.0),
        r.host_ms_animation.median
    );
    println!(
        "same run               static frame {:.2} ms GPU: animated / static = {:.2}; the \
         old CPU geometry per frame {:.0} ms host (contact build {:.0} ms)",
        r.static_gpu_ms_per_frame,
        r.anim_over_static,
        r.cpu_geometry_ms_per_frame_before.median,
        r.cpu_contact_ms_per_frame_before.median
    );
    let g = &r.rgb_path;
    println!(
        "per-vertex rgb E       irradiance {:.2} -> {:.2} ms, diffusion {:.2} -> {:.2} ms GPU \
         (grey -> rgb, same pose): {:+.2} ms per frame",
        g.grey_irradiance_ms,
        g.rgb_irradiance_ms,
        g.grey_diffusion_ms,
        g.rgb_diffusion_ms,
        g.rgb_irradiance_ms + g.rgb_diffusion_ms - g.grey_irradiance_ms - g.grey_diffusion_ms
    );
}

/// `bench all`'s SSS: the head's texture-space geometry and the CPU twin's maps once, then
/// the headline (and the CPU twin) once per round.
pub struct AllBench<'a> {
    ctx: &'a Context,
    cfg: &'a SssBenchConfig,
    regions: Regions,
    geo: TexGeometry,
    bvh: Bvh,
    dg: cpu::DiffusionGeometry,
    fps_min: Option<f64>,
}

impl<'a> AllBench<'a> {
    pub fn new(ctx: &'a Context, cfg: &'a SssBenchConfig) -> Result<AllBench<'a>> {
        let targets: serde_json::Value = serde_json::from_str(super::ao::TARGETS).map_err(|e| {
            crate::error::Error::InvalidArgument(format!("bench/targets.json: {e}"))
        })?;
        let mesh = load_mesh(&cfg.mesh, Some(&cfg.part))?;
        let profile = Profile::new(
            ProfileKind::Dipole,
            Material::SKIN1,
            crate::kernels::sss::profile::DEFAULT_ENERGY,
        )?;
        let geo = TexGeometry::build(&mesh, cfg.headline.0, cfg.mm_per_unit)?;
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let regions = Regions::from(&profile);
        let dg = cpu::DiffusionGeometry::build(&geo, &regions);
        Ok(AllBench {
            ctx,
            cfg,
            regions,
            geo,
            bvh,
            dg,
            fps_min: targets["sss"]["fps_min"].as_f64(),
        })
    }

    /// One round: the headline's GPU time and work model, the CPU twin's wall time.
    pub fn round(&self) -> Result<super::all::Round> {
        let hn = self.cfg.headline.1;
        let p = measure(
            self.ctx,
            self.cfg,
            &self.geo,
            &self.regions,
            hn,
            (f64::NAN, f64::NAN),
            None,
        )?;
        let params = SamplerParams {
            samples: hn,
            ..SamplerParams::default()
        };
        let cpu_ms = time_cpu(1, || {
            let e = cpu::irradiance(&self.geo, &self.bvh, &lights(), params.shadow_refine);
            let t = params
                .transmission
                .then(|| cpu::transmission(&self.geo, &self.bvh, &lights(), &self.regions));
            (
                cpu::diffusion_with(&self.dg, &self.geo, &self.regions, &e, &params),
                t,
            )
        });
        let within = [
            &p.vertex_light_ms,
            &p.irradiance_ms,
            &p.irradiance_rays_ms,
            &p.diffusion_ms,
        ]
        .iter()
        .map(|s| s.iqr_rel)
        .fold(0.0, f64::max);
        Ok(super::all::Round {
            kernel: "sss",
            headline: format!("BCN head, {}^2 texels x {} samples", p.size, p.samples),
            gpu_ms: p.total_ms,
            within_iqr_rel: within,
            terms: roofline_terms(&p),
            covers: COVERS,
            covered_ms: p.diffusion_ms.median,
            cpu_ms: cpu_ms.median,
            target_fps: self.fps_min,
        })
    }
}
