//! `vkshade btf synth|eval|render`: synthetic BTF directories, one interpolated tile through
//! the GPU path, and cloth-covered objects with (optionally) the CPU interpolation and the
//! direct ray-cast as references.

use super::Gpu;
use crate::bench::btf::{Garment, GarmentConfig};
use crate::bench::time_passes;
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::io::FloatImage;
use crate::kernels::btf::cloth::{self, Pattern, SynthConfig};
use crate::kernels::btf::cpu;
use crate::kernels::btf::dirs::{self, Angles, Maps, Triangulation};
use crate::kernels::btf::gpu::{
    BtfInputs, BtfKernel, GPU_CPU_BOUND_BLOCK, Layout, PASS_SHADE, Packing, Sampled, Texture,
};
use crate::kernels::btf::load;
use crate::kernels::btf::synth::{self, FileFormat, srgb_encode};
use crate::kernels::{Kernel, KernelInfo};
use crate::report::MachineInfo;
use crate::scene::gbuffer::{self, Camera, Frame, GBuffer, Light, Object};
use glam::Vec3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The metadata file `btf synth` writes beside the images (the ground truth reads it).
pub const META: &str = "btf.json";

/// What `btf.json` holds.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct SynthMeta {
    pub tool: String,
    pub synth: SynthConfig,
    pub format: String,
    pub brdf: String,
    pub ms: f64,
}

/// Runs `vkshade btf synth`: synthesises `size` x `size` texels of `pattern` repeating every
/// `period` texels (default: one tile, period = size) and writes them to `out`.
pub fn synth_command(
    pattern: Pattern,
    size: u32,
    period: Option<u32>,
    samples: u32,
    format: FileFormat,
    out: &Path,
) -> Result<SynthMeta> {
    let cfg = SynthConfig {
        samples,
        period: period.unwrap_or(size),
        ..SynthConfig::tile(pattern, size)
    };
    cfg.check()?;
    crate::io::outdir::check_claimable(out, "btf synth")?;
    let t = Instant::now();
    let btf = synth::synthesize(&cfg)?;
    let meta = SynthMeta {
        tool: "vkshade btf synth".into(),
        synth: cfg,
        format: format!("{format:?}").to_lowercase(),
        brdf: format!(
            "Lambert (KD {} x albedo) + normalised Blinn-Phong (KS {}, exponent {}), value = radiance under irradiance pi, shadowing and masking by ray-casting",
            cloth::KD,
            cloth::KS,
            cloth::EXPONENT
        ),
        ms: t.elapsed().as_secs_f64() * 1e3,
    };
    synth::write_dir(&btf, out, format, &meta, "btf synth")?;
    Ok(meta)
}

/// The synthesis settings of a directory written by `btf synth` (for the ground truth).
pub fn read_meta(dir: &Path) -> Result<SynthMeta> {
    let path = dir.join(META);
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    let meta: SynthMeta = serde_json::from_str(&text)
        .map_err(|e| Error::input(&path, format!("not a btf synth description: {e}")))?;
    meta.synth.check()?;
    Ok(meta)
}

/// `THETA,PHI` in degrees.
pub fn parse_angles(s: &str) -> std::result::Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("'{s}': expected THETA,PHI in degrees"))?;
    match v[..] {
        [t, p] if t.is_finite() && p.is_finite() && (0.0..90.0).contains(&t) => Ok([t, p]),
        _ => Err(format!(
            "'{s}': expected THETA,PHI in degrees with 0 <= THETA < 90"
        )),
    }
}

fn angles_vector([t, p]: [f64; 2]) -> Vec3 {
    let (t, p) = (t.to_radians(), p.to_radians());
    Vec3::new(
        (t.sin() * p.cos()) as f32,
        (t.sin() * p.sin()) as f32,
        t.cos() as f32,
    )
}

/// What `btf eval` reports.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub size: [u32; 2],
    pub light_taps: Vec<(Angles, f64)>,
    pub view_taps: Vec<(Angles, f64)>,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms: f64,
}

/// Runs `vkshade btf eval`: the tile interpolated at one (light, view) pair through the GPU
/// path, written as linear EXR.
pub fn eval_command(
    ctx: &Context,
    dir: &Path,
    light: [f64; 2],
    view: [f64; 2],
    map_res: u32,
    texture: Texture,
    out: &Path,
) -> Result<EvalReport> {
    crate::io::check_writable(out)?;
    let btf = load::load_dir(dir)?;
    let maps = Maps::build(&Triangulation::new()?, map_res)?;
    let gb = GBuffer::tile(btf.size);
    let frame = Frame {
        camera: Camera::Orthographic(angles_vector(view)),
        lights: vec![Light {
            direction: angles_vector(light),
            rgb: [1.0; 3],
        }],
    };
    let mut rec = ctx.recorder("btf eval")?;
    let kernel = BtfKernel::new(&mut rec, &BtfInputs::new(&btf, &maps, &gb, texture))?;
    kernel.record(&mut rec, &frame)?;
    let rb = kernel.read_back(&mut rec)?;
    let t = rec.submit_and_wait()?;
    let px = kernel.collect(&rb)?;
    write_exr(
        out,
        &FloatImage {
            width: btf.size[0],
            height: btf.size[1],
            pixels: px,
        },
    )?;
    let d = dirs::directions();
    let taps = |v: Vec3| {
        let t = maps.lookup(v.as_dvec3().to_array());
        (0..3)
            .filter(|&k| t.weight[k] > 0.0)
            .map(|k| (d[t.index[k]], t.weight[k]))
            .collect()
    };
    Ok(EvalReport {
        size: btf.size,
        light_taps: taps(angles_vector(light)),
        view_taps: taps(angles_vector(view)),
        gpu_ms: t.get(PASS_SHADE).unwrap_or(f64::NAN),
    })
}

fn write_exr(path: &Path, img: &FloatImage) -> Result<()> {
    #[cfg(feature = "exr")]
    return crate::io::exr::write(path, img, crate::io::exr::Channels::Rgba);
    #[cfg(not(feature = "exr"))]
    {
        let _ = img;
        Err(Error::feature(
            format!("writing the EXR {}", path.display()),
            "exr",
        ))
    }
}

/// Everything `vkshade btf render` can be told.
#[derive(Clone, Debug)]
pub struct RenderConfig {
    pub btf: PathBuf,
    pub object: Object,
    /// A mesh with UVs (glTF, OBJ, PLY, OFF) to cover instead of `object`.
    pub mesh: Option<PathBuf>,
    pub lights: Vec<Light>,
    pub width: u32,
    pub height: u32,
    pub map_res: u32,
    pub layout: Layout,
    pub texture: Texture,
    pub reference: bool,
    /// Error at the top of the heat map.
    pub error_scale: f32,
    pub out: PathBuf,
    pub bench: crate::bench::BenchConfig,
    /// Light the cloth by an SG-fitted environment too (pass `btf env`).
    pub env: Option<EnvConfig>,
}

/// The environment of `btf render --env`: a map, fitted once with `lobes` SG lobes (on its
/// 128 x 64 downsampling) and turned `rotate_deg` about +Y.
#[derive(Clone, Debug, Serialize)]
pub struct EnvConfig {
    pub path: PathBuf,
    pub lobes: usize,
    pub rotate_deg: f32,
    /// How negative samples of the map (codec ringing) are treated.
    pub hdr: crate::scene::envmap::HdrPolicy,
}

impl EnvConfig {
    /// The map downsampled to the fit's 128 x 64, the lobes fitted to it and turned by the
    /// rotation (returned too).
    pub fn fit(
        &self,
    ) -> Result<(
        crate::scene::envmap::EnvMap,
        Vec<crate::geom::sg::Lobe>,
        glam::Mat3,
    )> {
        use crate::kernels::srbf::fit::{FitConfig, fit};
        let map = crate::scene::envmap::EnvMap::load_with(&self.path, self.hdr)?;
        if let Some(r) = &map.repair {
            super::progress(&format!("{}: {r}", self.path.display()));
        }
        let small = map.downsampled(128.min(map.width))?;
        let fitted = fit(
            &small.samples(),
            &FitConfig {
                lobes: self.lobes,
                ..FitConfig::default()
            },
        )?;
        let r = crate::geom::sg::rotation(Vec3::Y, self.rotate_deg);
        let lobes = fitted.lobes.iter().map(|l| l.rotated(r)).collect();
        Ok((small, lobes, r))
    }
}

/// The environment pass against its references (`btf render --env --reference`), over the
/// covered pixels, the environment's share alone (GPU: the frame again with the directional
/// lights off).
#[derive(Clone, Debug, Serialize)]
pub struct VsEnv {
    /// Relative L2 against ground truth (1): the BTF's own quadrature of the unfitted,
    /// rotated map (cell averages of L over the 81 light directions' cells).
    pub vs_quadrature: f64,
    /// Relative L2 against ground truth (2): the integral of the kernel's interpolated BTF
    /// over the map's directions.
    pub vs_interpolated: f64,
    /// Relative L2 of (1) against (2): the 81-direction quadrature's own error.
    pub quadrature_vs_interpolated: f64,
    /// GPU against the CPU twin: largest |difference| and the largest environment value.
    pub vs_twin_max_abs: f64,
    pub env_max: f64,
    pub truth_ms: f64,
}

pub use crate::scene::gbuffer::default_lights;

/// Errors against one reference.
#[derive(Clone, Debug, Serialize)]
pub struct VsCpu {
    /// Largest and RMS |GPU - CPU| over covered, unambiguous pixels and channels.
    pub max_abs: f64,
    pub rms: f64,
    pub pixels: usize,
    /// Pixels left out: a map coordinate within 1e-3 texels of a texel border, where f32
    /// on the GPU may pick the neighbouring map texel.
    pub ambiguous_pixels: usize,
    /// The bound stated for the stored formats (see tests/btf.rs).
    pub bound: f64,
    pub cpu_ms: f64,
}

/// Errors against the direct ray-cast, split at 75 deg.
#[derive(Clone, Debug, Serialize)]
pub struct VsRayCast {
    pub within_75: Band,
    pub grazing: Band,
    pub all: Band,
    pub ray_cast_ms: f64,
}

/// RMSE and PSNR (peak 1, linear) of one band of pixels.
#[derive(Clone, Debug, Serialize)]
pub struct Band {
    pub pixels: usize,
    pub rmse: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub psnr_db: f64,
    pub max_abs: f64,
}

impl Band {
    fn of(pairs: impl Iterator<Item = ([f32; 4], [f64; 4])>) -> Band {
        let (mut se, mut n, mut max) = (0.0, 0usize, 0.0f64);
        for (g, t) in pairs {
            for i in 0..3 {
                let e = g[i] as f64 - t[i];
                se += e * e;
                max = max.max(e.abs());
            }
            n += 1;
        }
        let rmse = (se / (3 * n.max(1)) as f64).sqrt();
        Band {
            pixels: n,
            rmse,
            psnr_db: if n == 0 {
                f64::NAN
            } else {
                -20.0 * rmse.log10()
            },
            max_abs: max,
        }
    }
}

/// What `report.json` of `btf render` holds.
#[derive(Clone, Debug, Serialize)]
pub struct RenderReport {
    pub tool: &'static str,
    pub machine: MachineInfo,
    pub btf: String,
    pub tile: [u32; 2],
    pub object: String,
    pub size: [u32; 2],
    pub covered_pixels: usize,
    pub map_resolution: u32,
    pub lights: Vec<[f32; 6]>,
    pub packing: Packing,
    /// The texel format of the packed BTF (rgba8 or bc1).
    pub texture: Texture,
    /// Device bytes of the packed BTF (array textures) and of the two maps.
    pub texture_bytes: u64,
    pub texture_mib: f64,
    pub map_bytes: u64,
    pub gpu_ms: crate::report::Stats,
    /// Host ms per frame outside waiting (recording the pass and submitting).
    pub host_ms: crate::report::Stats,
    pub fps: f64,
    pub load_ms: f64,
    pub kernel: KernelInfo,
    pub vs_cpu: Option<VsCpu>,
    pub vs_ray_cast: Option<VsRayCast>,
    /// With --env: the environment, GPU ms of `btf env`, and (with --reference) its errors.
    pub env: Option<EnvConfig>,
    pub env_gpu_ms: Option<crate::report::Stats>,
    pub vs_env: Option<VsEnv>,
    pub png: String,
    pub exr: String,
    pub notes: Vec<String>,
}

/// Runs `vkshade btf render`.
pub fn render(
    ctx: &Context,
    cfg: &RenderConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<RenderReport> {
    let report_path = cfg.out.join("report.json");
    crate::io::outdir::claim(&cfg.out, "btf render")?;
    let meta = if cfg.reference {
        Some(read_meta(&cfg.btf).map_err(|e| {
            Error::InvalidArgument(format!(
                "--reference ray-casts the heightfield the BTF was synthesised from, described in {}: {e}",
                cfg.btf.join(META).display()
            ))
        })?)
    } else {
        None
    };
    let session = Session::new(ctx, cfg, progress)?;
    let (vs_cpu, vs_ray_cast, mut truth) = match &meta {
        Some(meta) => {
            let vs_cpu = session.vs_cpu();
            let (vs_ray_cast, truth) = session.vs_ray_cast(meta, progress)?;
            (Some(vs_cpu), Some(vs_ray_cast), Some(truth))
        }
        None => (None, None, None),
    };
    let vs_env = match (&session.env, cfg.reference) {
        (Some(env), true) => {
            let (vs, t1) = session.vs_env(env, progress)?;
            // The picture's truth: the directional lights ray-cast plus the environment's
            // quadrature truth (1).
            if let Some(t) = truth.as_mut() {
                for (a, b) in t.iter_mut().zip(&t1) {
                    for i in 0..3 {
                        a[i] += b[i];
                    }
                }
            }
            Some(vs)
        }
        _ => None,
    };
    let (png, exr) = session.pictures(truth.as_deref())?;
    let mut report = session.report(vs_cpu, vs_ray_cast, &png, &exr);
    report.vs_env = vs_env;
    crate::io::write_json(&report_path, &report)?;
    Ok(report)
}

/// A render: the loaded BTF, the maps, the G-buffer, the kernel and its output.
struct Session<'a> {
    ctx: &'a Context,
    cfg: &'a RenderConfig,
    btf: synth::Btf,
    load_ms: f64,
    maps: Maps,
    gb: GBuffer,
    frame: Frame,
    kernel: BtfKernel,
    /// Linear RGBA per pixel, as the GPU shaded it.
    out: Vec<[f32; 4]>,
    gpu_ms: crate::report::Stats,
    host_ms: crate::report::Stats,
    /// With --env: the lobes (and their buffer, which the kernel reads), the map they were
    /// fitted to, the rotation, the environment's share of `out` (GPU, lights off) and the
    /// GPU ms of `btf env`.
    env: Option<SessionEnv>,
}

struct SessionEnv {
    _buffer: crate::gpu::Buffer,
    lobes: Vec<[f32; 4]>,
    map: crate::scene::envmap::EnvMap,
    rotation: glam::Mat3,
    out: Vec<[f32; 4]>,
    gpu_ms: crate::report::Stats,
}

impl<'a> Session<'a> {
    /// Loads the BTF, builds the maps and the G-buffer, shades once, and times the pass.
    fn new(
        ctx: &'a Context,
        cfg: &'a RenderConfig,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Session<'a>> {
        let t = Instant::now();
        let btf = load::load_dir(&cfg.btf)?;
        let load_ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "loaded {} ({} x {} texels x 6561 images) in {load_ms:.0} ms",
            cfg.btf.display(),
            btf.size[0],
            btf.size[1]
        ));
        let maps = Maps::build(&Triangulation::new()?, cfg.map_res)?;
        let gb = match &cfg.mesh {
            Some(path) => {
                let character = crate::scene::load(path)?;
                gbuffer::render_mesh(&character.mesh, cfg.width, cfg.height)
                    .map_err(|e| Error::input(path, e.to_string()))?
            }
            None => gbuffer::render_object(cfg.object, cfg.width, cfg.height)?,
        };
        let frame = Frame {
            camera: Camera::Perspective(Vec3::from(gbuffer::EYE)),
            lights: cfg.lights.clone(),
        };
        frame.check()?;
        let mut rec = ctx.recorder("btf render")?;
        let inputs = BtfInputs {
            layout: cfg.layout,
            ..BtfInputs::new(&btf, &maps, &gb, cfg.texture)
        };
        let (kernel, env) = match &cfg.env {
            None => (BtfKernel::new(&mut rec, &inputs)?, None),
            Some(e) => {
                let t = Instant::now();
                let (map, lobes, rotation) = e.fit()?;
                progress(&format!(
                    "fitted {} lobes to {} in {:.0} ms, turned {} deg about +Y",
                    lobes.len(),
                    e.path.display(),
                    t.elapsed().as_secs_f64() * 1e3,
                    e.rotate_deg
                ));
                let texels = crate::kernels::btf::env::lobe_texels(&lobes);
                let buffer = rec.buffer_with(
                    "btf render lobes",
                    crate::gpu::BufferDesc::storage(16 * texels.len() as u64),
                    &texels,
                )?;
                let l = ctx.limits();
                let prep = crate::kernels::btf::gpu::Prepared::new(
                    &inputs,
                    l.max_image_dimension_2d,
                    l.max_image_array_layers,
                )?;
                let env_in = crate::kernels::btf::gpu::EnvInputs {
                    lobes: &buffer,
                    lobe_count: lobes.len() as u32,
                    visibility: None,
                };
                let k = BtfKernel::from_prepared_env(&mut rec, &prep, env_in)?;
                (k, Some((buffer, texels, map, rotation)))
            }
        };
        kernel.record(&mut rec, &frame)?;
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let out = kernel.collect(&rb)?;
        let timed = time_passes(ctx, &cfg.bench, &kernel, &frame)?;
        let gpu_ms = timed[0].1.clone();
        let env = match env {
            None => None,
            Some((buffer, lobes, map, rotation)) => {
                // The environment's share alone: the same frame with the lights off.
                let dark = Frame {
                    lights: frame
                        .lights
                        .iter()
                        .map(|l| Light {
                            rgb: [0.0; 3],
                            ..*l
                        })
                        .collect(),
                    ..frame.clone()
                };
                let mut rec = ctx.recorder("btf render env only")?;
                kernel.record(&mut rec, &dark)?;
                let rb = kernel.read_back(&mut rec)?;
                rec.submit_and_wait()?;
                let env_ms = timed
                    .iter()
                    .find(|(n, _)| *n == crate::kernels::btf::gpu::PASS_ENV)
                    .map(|(_, s)| s.clone())
                    .ok_or_else(|| Error::InvalidArgument("btf env was not timed".into()))?;
                progress(&format!(
                    "btf env {} x {}: {:.3} ms (median GPU)",
                    cfg.width, cfg.height, env_ms.median
                ));
                Some(SessionEnv {
                    _buffer: buffer,
                    lobes,
                    map,
                    rotation,
                    out: kernel.collect(&rb)?,
                    gpu_ms: env_ms,
                })
            }
        };
        // Host time of a frame outside waiting: recording the pass (push constants) and
        // submitting, over as many frames as the GPU timing took.
        let mut host = Vec::new();
        for _ in 0..cfg.bench.samples.max(1) {
            let t = Instant::now();
            let mut rec = ctx.recorder("btf render host timing")?;
            kernel.record(&mut rec, &frame)?;
            let sub = rec.submit()?;
            host.push(t.elapsed().as_secs_f64() * 1e3);
            sub.wait()?;
        }
        let host_ms = crate::report::Stats::of(&host)
            .ok_or_else(|| Error::InvalidArgument("no host timing samples".into()))?;
        progress(&format!(
            "btf shade {} x {}: {:.3} ms (median GPU)",
            cfg.width, cfg.height, gpu_ms.median
        ));
        Ok(Session {
            ctx,
            cfg,
            btf,
            load_ms,
            maps,
            gb,
            frame,
            kernel,
            out,
            gpu_ms,
            host_ms,
            env,
        })
    }

    /// The environment's share (GPU, lights off) against the twin and the two quadrature
    /// truths; returns them and truth (1) per pixel.
    fn vs_env(
        &self,
        env: &SessionEnv,
        progress: &mut dyn FnMut(&str),
    ) -> Result<(VsEnv, Vec<[f64; 4]>)> {
        use crate::kernels::btf::env as benv;
        let sampled = Sampled::of(&self.btf, self.cfg.texture);
        let packed = sampled.packed(self.btf.size);
        let cam = &self.frame.camera;
        let (twin, amb) = benv::shade(&packed, &self.maps, &self.gb, cam, &env.lobes, None);
        progress("integrating the rotated map over the 81 light directions' cells at every pixel");
        let t = Instant::now();
        let (t1, t2) = benv::truths(
            &packed,
            &self.maps,
            &self.gb,
            cam,
            &env.map,
            env.rotation,
            None,
        );
        let truth_ms = t.elapsed().as_secs_f64() * 1e3;
        let gpu: Vec<[f64; 4]> = env.out.iter().map(|p| p.map(|x| x as f64)).collect();
        let (mut max, mut peak) = (0.0f64, 0.0f64);
        for k in 0..gpu.len() {
            if twin[k][3] == 0.0 || amb[k] {
                continue;
            }
            for i in 0..3 {
                max = max.max((gpu[k][i] - twin[k][i]).abs());
                peak = peak.max(twin[k][i]);
            }
        }
        let vs = VsEnv {
            vs_quadrature: benv::rel_l2(&gpu, &t1),
            vs_interpolated: benv::rel_l2(&gpu, &t2),
            quadrature_vs_interpolated: benv::rel_l2(&t1, &t2),
            vs_twin_max_abs: max,
            env_max: peak,
            truth_ms,
        };
        Ok((vs, t1))
    }

    /// The GPU against the CPU interpolation (f64) of the data the GPU samples (for BC1:
    /// encoded and decoded again, see io::bc1; for block: the blocks, decoded per tap as the
    /// shader does).
    fn vs_cpu(&self) -> VsCpu {
        let (cfg, out) = (self.cfg, &self.out);
        let sampled = Sampled::of(&self.btf, cfg.texture);
        let t = Instant::now();
        let (want, ambiguous) = cpu::shade(
            &sampled.packed(self.btf.size),
            &self.maps,
            &self.gb,
            &self.frame,
        );
        let (mut want, mut ambiguous) = (want, ambiguous);
        if let Some(env) = &self.env {
            let (e, amb) = crate::kernels::btf::env::shade(
                &sampled.packed(self.btf.size),
                &self.maps,
                &self.gb,
                &self.frame.camera,
                &env.lobes,
                None,
            );
            for k in 0..want.len() {
                for i in 0..3 {
                    want[k][i] += e[k][i];
                }
                ambiguous[k] |= amb[k];
            }
        }
        let cpu_ms = t.elapsed().as_secs_f64() * 1e3;
        let (mut max, mut se, mut n, mut amb) = (0.0f64, 0.0, 0usize, 0usize);
        for k in 0..out.len() {
            if want[k][3] == 0.0 {
                continue;
            }
            if ambiguous[k] {
                amb += 1;
                continue;
            }
            for i in 0..3 {
                let e = out[k][i] as f64 - want[k][i];
                max = max.max(e.abs());
                se += e * e;
            }
            n += 1;
        }
        VsCpu {
            max_abs: max,
            rms: (se / (3 * n.max(1)) as f64).sqrt(),
            pixels: n,
            ambiguous_pixels: amb,
            // RGBA8: the sampler's 8-bit sub-texel weights (tests/btf.rs gpu_cpu_bound). BC1:
            // against io::bc1's decoding, plus the vendors' palette spread
            // (io::bc1::PALETTE_TOLERANCE steps of at most 4.5e-3 in linear, per light; the
            // two lights sum to < 2).
            bound: match cfg.texture {
                Texture::Rgba8 => 5e-3,
                Texture::Bc1 => 5e-3 + 2.0 * crate::io::bc1::PALETTE_TOLERANCE as f64 * 4.5e-3,
                Texture::Block => GPU_CPU_BOUND_BLOCK,
            },
            cpu_ms,
        }
    }

    /// The GPU against the heightfield `meta` describes, ray-cast at every pixel's exact
    /// directions; and that truth per pixel.
    fn vs_ray_cast(
        &self,
        meta: &SynthMeta,
        progress: &mut dyn FnMut(&str),
    ) -> Result<(VsRayCast, Vec<[f64; 4]>)> {
        let btf = &self.btf;
        // The ray-cast holds the directional lights only: compare their share.
        let out: Vec<[f32; 4]> = match &self.env {
            None => self.out.clone(),
            Some(env) => self
                .out
                .iter()
                .zip(&env.out)
                .map(|(a, e)| [a[0] - e[0], a[1] - e[1], a[2] - e[2], a[3]])
                .collect(),
        };
        if meta.synth.size != btf.size || meta.synth.period != btf.size[0] {
            return Err(Error::input(
                self.cfg.btf.join(META),
                format!(
                    "describes a {:?} sample of period {}, but the images are {:?}",
                    meta.synth.size, meta.synth.period, btf.size
                ),
            ));
        }
        progress("ray-casting the heightfield at every pixel's exact directions");
        let t = Instant::now();
        let (truth, theta) = crate::reference::btf::ray_cast(&meta.synth, &self.gb, &self.frame);
        let ray_cast_ms = t.elapsed().as_secs_f64() * 1e3;
        let covered = |k: &usize| truth[*k][3] > 0.0;
        let band = |f: &dyn Fn(usize) -> bool| {
            Band::of(
                (0..out.len())
                    .filter(covered)
                    .filter(|&k| f(k))
                    .map(|k| (out[k], truth[k])),
            )
        };
        let vs = VsRayCast {
            within_75: band(&|k| theta[k] <= 75.0),
            grazing: band(&|k| theta[k] > 75.0),
            all: band(&|_| true),
            ray_cast_ms,
        };
        Ok((vs, truth))
    }

    /// render.png and render.exr (linear): the result, or with a truth result | truth |
    /// error. Returns their paths.
    fn pictures(&self, truth: Option<&[[f64; 4]]>) -> Result<(PathBuf, PathBuf)> {
        let (gb, out) = (&self.gb, &self.out);
        let png = self.cfg.out.join("render.png");
        let exr = self.cfg.out.join("render.exr");
        let result_pic =
            self.picture(&|k| out[k].map(|x| x as f64)[..3].try_into().unwrap_or([0.0; 3]));
        let result_float = FloatImage {
            width: gb.width,
            height: gb.height,
            pixels: out.clone(),
        };
        match truth {
            None => {
                crate::render::write_png(
                    &png,
                    result_pic.width,
                    result_pic.height,
                    &result_pic.rgb,
                )?;
                write_exr(&exr, &result_float)?;
            }
            Some(truth) => {
                let truth_pic = self.picture(&|k| [truth[k][0], truth[k][1], truth[k][2]]);
                let error = self.error(truth);
                let pic = crate::render::side_by_side(
                    &result_pic,
                    &truth_pic,
                    &error,
                    self.cfg.error_scale,
                )?;
                crate::render::write_png(&png, pic.width, pic.height, &pic.rgb)?;
                let truth_float = FloatImage {
                    width: gb.width,
                    height: gb.height,
                    pixels: truth.iter().map(|t| t.map(|x| x as f32)).collect(),
                };
                let err_float = FloatImage {
                    width: gb.width,
                    height: gb.height,
                    pixels: error
                        .iter()
                        .map(|&e| {
                            let e = if e.is_finite() { e } else { 0.0 };
                            [e, e, e, 1.0]
                        })
                        .collect(),
                };
                write_exr(
                    &exr,
                    &crate::render::side_by_side_linear(&result_float, &truth_float, &err_float)?,
                )?;
            }
        }
        Ok((png, exr))
    }

    /// An 8-bit sRGB picture of the linear RGB `px` gives per pixel.
    fn picture(&self, px: &dyn Fn(usize) -> [f64; 3]) -> crate::render::Picture {
        crate::render::Picture {
            width: self.gb.width,
            height: self.gb.height,
            rgb: (0..self.out.len())
                .flat_map(|k| px(k).map(|x| srgb_encode(x as f32)))
                .collect(),
        }
    }

    /// The largest channel error against `truth` per pixel (NaN where the truth sees no
    /// surface).
    fn error(&self, truth: &[[f64; 4]]) -> Vec<f32> {
        let out = &self.out;
        (0..out.len())
            .map(|k| {
                if truth[k][3] > 0.0 {
                    (0..3)
                        .map(|i| (out[k][i] as f64 - truth[k][i]).abs())
                        .fold(0.0, f64::max) as f32
                } else {
                    f32::NAN
                }
            })
            .collect()
    }

    /// The report of the render.
    fn report(
        &self,
        vs_cpu: Option<VsCpu>,
        vs_ray_cast: Option<VsRayCast>,
        png: &Path,
        exr: &Path,
    ) -> RenderReport {
        let (cfg, kernel) = (self.cfg, &self.kernel);
        let texture_bytes = kernel.texture_bytes();
        RenderReport {
            tool: "vkshade btf render",
            machine: MachineInfo::of(self.ctx),
            btf: cfg.btf.display().to_string(),
            tile: self.btf.size,
            object: match &cfg.mesh {
                Some(p) => p.display().to_string(),
                None => format!("{:?}", cfg.object).to_lowercase(),
            },
            size: [cfg.width, cfg.height],
            covered_pixels: self.gb.covered(),
            map_resolution: cfg.map_res,
            lights: cfg
                .lights
                .iter()
                .map(|l| {
                    let d = l.direction.normalize();
                    [d.x, d.y, d.z, l.rgb[0], l.rgb[1], l.rgb[2]]
                })
                .collect(),
            packing: kernel.packing(),
            texture: kernel.texture(),
            texture_bytes,
            texture_mib: texture_bytes as f64 / (1u64 << 20) as f64,
            map_bytes: kernel.map_bytes(),
            fps: 1000.0 / self.gpu_ms.median,
            gpu_ms: self.gpu_ms.clone(),
            host_ms: self.host_ms.clone(),
            load_ms: self.load_ms,
            kernel: KernelInfo::of(kernel, 1),
            vs_cpu,
            vs_ray_cast,
            env: cfg.env.clone(),
            env_gpu_ms: self.env.as_ref().map(|e| e.gpu_ms.clone()),
            vs_env: None,
            png: png.display().to_string(),
            exr: exr.display().to_string(),
            notes: RENDER_NOTES.iter().map(|n| n.to_string()).collect(),
        }
    }
}

/// The notes of every `btf render` report.
const RENDER_NOTES: [&str; 3] = [
    "Directions are interpolated through nearest-texel parabolic index/weight maps (Delaunay triangulation of the 81 UBO2003 directions); beyond 75 deg btflib's zero-weight virtual ring fades the BTF towards 0 at the horizon.",
    "The packed BTF is RGBA8 sRGB (decoded to linear by the sampler, bilinear inside a tile, repeat in uv); RGB8 is not a sampled format on most devices.",
    "vs_ray_cast: the heightfield ray-cast at each pixel's exact tangent-space directions, filtered over the tile texels like the GPU, clipped at 1 like the 8-bit images; its error includes the 8-bit storage. Bands by the larger polar angle of view and lights.",
];

/// What `btf tile` reports.
#[derive(Clone, Debug, Serialize)]
pub struct TileReport {
    pub sample_size: [u32; 2],
    pub period: load::Period,
    pub origin: [u32; 2],
}

/// Runs `vkshade btf tile`: finds the repeat period of the BTF sample in `dir` (local minima
/// of the 2D offset cost) and writes one tile cut at `origin` as a new directory `out`.
pub fn tile_command(
    dir: &Path,
    origin: [u32; 2],
    format: FileFormat,
    out: &Path,
) -> Result<TileReport> {
    crate::io::outdir::check_claimable(out, "btf tile")?;
    let btf = load::load_dir(dir)?;
    let period = load::find_period(&btf)?;
    let tile = load::cut_tile(&btf, origin, period.period)?;
    let report = TileReport {
        sample_size: btf.size,
        period,
        origin,
    };
    synth::write_dir(&tile, out, format, &report, "btf tile")?;
    Ok(report)
}

/// The subcommands of `vkshade btf`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum Command {
    /// Ray-cast a periodic cloth heightfield (known BRDF, shadowing, masking) at the 81 x 81
    /// UBO2003 directions and write a UBO2003-style directory (one image per (light, view),
    /// angles in the names: btf_tlTTT_plPPP_tvTTT_pvPPP.png) plus btf.json.
    Synth {
        /// weave, knit or rib.
        #[arg(long, value_parser = super::choice::<Pattern>("pattern"))]
        pattern: Pattern,
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
        #[arg(long, default_value = "png", value_parser = super::choice::<FileFormat>("image format"))]
        format: FileFormat,
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
        #[arg(long, default_value = "png", value_parser = super::choice::<FileFormat>("image format"))]
        format: FileFormat,
        #[arg(short = 'o', long)]
        out: PathBuf,
    },
    /// The tile interpolated at one (light, view) pair through the GPU path, as linear EXR.
    Eval {
        /// A UBO2003-style directory (from `btf synth`, or your own in PNG/EXR).
        #[arg(long)]
        btf: PathBuf,
        /// THETA,PHI in degrees in the tile's tangent frame (as in the file names).
        #[arg(long, value_parser = parse_angles)]
        light: [f64; 2],
        /// THETA,PHI in degrees.
        #[arg(long, value_parser = parse_angles)]
        view: [f64; 2],
        /// Index/weight map resolution.
        #[arg(long, default_value_t = 128)]
        map_res: u32,
        /// Texel format of the packed BTF: block (overlapping 4x4 blocks of linear RGB,
        /// 16 bytes each, decoded and filtered by the shader: the fast one on lavapipe),
        /// bc1 (sRGB BC1, needs the device feature textureCompressionBC) or rgba8 (sRGB).
        #[arg(long, default_value = "block", value_parser = super::choice::<Texture>("texture format"))]
        texture: Texture,
        #[arg(short = 'o', long)]
        out: PathBuf,
    },
    /// A cloth-covered object: DIR/render.png (with --reference: result | direct ray-cast |
    /// error), DIR/render.exr (linear) and DIR/report.json (GPU time, texture memory, map
    /// resolution, errors).
    Render(RenderArgs),
}

/// The arguments of `vkshade btf render`.
#[derive(clap::Args, Clone, Debug)]
pub struct RenderArgs {
    #[arg(long)]
    pub btf: PathBuf,
    /// sphere, cylinder, plane, or a mesh file with UVs (.glb/.gltf/.obj/.ply/.off;
    /// centred, scaled to radius 1.2, uv x 8).
    #[arg(long, default_value = "sphere")]
    pub object: String,
    // The brackets are the help text's notation for an optional part, not doc links.
    #[allow(rustdoc::broken_intra_doc_links)]
    /// A directional light X,Y,Z[,R,G,B] (towards the light, world space; y up, camera
    /// on +z); up to 2 (default: a warm key light and a cool grazing fill).
    #[arg(long)]
    pub light: Vec<String>,
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    #[arg(long, default_value_t = 128)]
    pub map_res: u32,
    /// Texture layout: rows (one 81-layer array, images side by side with gutters) or
    /// layers (one image per layer, split over arrays of maxImageArrayLayers; rgba8 and
    /// bc1 only). Default: rows. Also with --anim.
    #[arg(long, value_parser = super::choice::<Layout>("layout"))]
    pub layout: Option<Layout>,
    /// Texel format of the packed BTF: block (overlapping 4x4 blocks of linear RGB,
    /// 16 bytes each, decoded and filtered by the shader: the fast one on lavapipe),
    /// bc1 (sRGB BC1, needs the device feature textureCompressionBC) or rgba8 (sRGB).
    #[arg(long, default_value = "block", value_parser = super::choice::<Texture>("texture format"))]
    pub texture: Texture,
    /// Compare with the f64 CPU interpolation and with the heightfield ray-cast at the
    /// exact directions (needs the btf.json of `btf synth`).
    #[arg(long)]
    pub reference: bool,
    #[arg(long, default_value_t = 0.1)]
    pub error_scale: f32,
    #[arg(long, default_value = "out/btf")]
    pub out: PathBuf,
    /// With --anim: the glTF mesh parts to cover with cloth, comma-separated (node or mesh
    /// names, e.g. Torso,Legs).
    #[arg(long, value_delimiter = ',')]
    pub part: Vec<String>,
    /// Play this animation of the --object glTF: per frame the parts are skinned, their
    /// G-buffer rasterised and shaded on the GPU; writes DIR/frame_NNNN.png and
    /// DIR/anim.json (GPU ms per pass, host ms per frame).
    #[arg(long)]
    pub anim: Option<String>,
    /// With --anim: frames to render.
    #[arg(long, default_value_t = 30)]
    pub frames: u32,
    /// With --anim: frames per second of animation time.
    #[arg(long, default_value_t = 30.0)]
    pub frame_rate: f32,
    /// With --anim: BTF tile repeats per unit of the mesh's uv.
    #[arg(long, default_value_t = 8.0)]
    pub tile_scale: f32,
    /// Light the cloth by this equirectangular HDR environment too (EXR or .hdr), fitted
    /// with --env-lobes SG lobes (pass `btf env`); with --reference, the environment's share
    /// is compared with the BTF's own quadrature of the unfitted map.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// With --env: turn the environment this many degrees about +Y.
    #[arg(long, default_value_t = 0.0)]
    pub rotate: f32,
    /// With --env: SG lobes fitted to the map.
    #[arg(long, default_value_t = 32)]
    pub env_lobes: usize,
    #[command(flatten)]
    pub hdr: super::Hdr,
}

impl Command {
    /// Runs `vkshade btf synth|tile|eval|render` and prints its summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        match self {
            Command::Synth {
                pattern,
                size,
                period,
                samples,
                format,
                out,
            } => run_synth(*pattern, *size, *period, *samples, *format, out),
            Command::Tile {
                btf,
                origin,
                format,
                out,
            } => run_tile(btf, origin, *format, out),
            Command::Eval {
                btf,
                light,
                view,
                map_res,
                texture,
                out,
            } => run_eval(gpu, btf, *light, *view, *map_res, *texture, out),
            Command::Render(a) => a.run(gpu),
        }
    }
}

/// The context a BTF command storing its texture as `texture` needs (BC1 asks for the
/// device feature textureCompressionBC, and says which option needs it when it is missing).
pub fn context(gpu: &Gpu, texture: Texture) -> Result<Context> {
    let bc1 = texture == Texture::Bc1;
    gpu.context_with(crate::gpu::Features {
        texture_compression_bc: bc1,
        ..Default::default()
    })
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

/// `vkshade btf synth`.
fn run_synth(
    pattern: Pattern,
    size: u32,
    period: Option<u32>,
    samples: u32,
    format: FileFormat,
    out: &Path,
) -> Result<()> {
    eprintln!(
        "synthesising {} x {size} x 6561 images of {pattern:?}",
        size
    );
    let m = synth_command(pattern, size, period, samples, format, out)?;
    println!(
        "wrote 6561 {} images of {size} x {size} texels ({:?}) and {} to {} in {:.1} s",
        m.format,
        pattern,
        META,
        out.display(),
        m.ms / 1e3
    );
    Ok(())
}

/// `vkshade btf tile`: `origin` is X,Y.
fn run_tile(dir: &Path, origin: &str, format: FileFormat, out: &Path) -> Result<()> {
    let bad = || Error::InvalidArgument(format!("--origin '{origin}': expected X,Y"));
    let v: Vec<u32> = origin
        .split(',')
        .map(|x| x.trim().parse::<u32>().map_err(|_| bad()))
        .collect::<Result<_>>()?;
    let origin: [u32; 2] = v.as_slice().try_into().map_err(|_| bad())?;
    let r = tile_command(dir, origin, format, out)?;
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

/// `vkshade btf eval`: the taps of each direction and the GPU time.
fn run_eval(
    gpu: &Gpu,
    dir: &Path,
    light: [f64; 2],
    view: [f64; 2],
    map_res: u32,
    texture: Texture,
    out: &Path,
) -> Result<()> {
    let ctx = context(gpu, texture)?;
    let r = eval_command(&ctx, dir, light, view, map_res, texture, out)?;
    let taps = |t: &[(Angles, f64)]| {
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
    super::finish(ctx)
}

/// A `--light` of `btf render`: X,Y,Z[,R,G,B].
fn parse_light(s: &str) -> Result<Light> {
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
    let bound = crate::kernels::sss::cpu::MAX_LIGHT_COORDINATE;
    let strength = crate::kernels::sss::cpu::MAX_LIGHT_STRENGTH;
    if d.iter().any(|x| !x.is_finite() || x.abs() > bound) {
        return Err(Error::InvalidArgument(format!(
            "--light '{s}': the direction's coordinates must be finite within +-{bound:e} \
             (normalising a larger vector overflows f32)"
        )));
    }
    if Vec3::from(d).length() < 1e-6 {
        return Err(Error::InvalidArgument(format!(
            "--light '{s}': zero direction"
        )));
    }
    if rgb
        .iter()
        .any(|c| !(c.is_finite() && (0.0..=strength).contains(c)))
    {
        return Err(Error::InvalidArgument(format!(
            "--light '{s}': R,G,B must be finite and in 0..={strength:e}"
        )));
    }
    Ok(Light {
        direction: Vec3::from(d),
        rgb,
    })
}

impl RenderArgs {
    /// The render these arguments describe: the lights (the default pair when none is
    /// given) and the object, a built-in shape or a mesh file.
    pub fn config(&self) -> Result<RenderConfig> {
        let lights = if self.light.is_empty() {
            default_lights()
        } else {
            self.light
                .iter()
                .map(|s| parse_light(s))
                .collect::<Result<_>>()?
        };
        if !(self.error_scale.is_finite() && self.error_scale > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "--error-scale must be > 0, not {}",
                self.error_scale
            )));
        }
        let (object, mesh) = match <Object as clap::ValueEnum>::from_str(&self.object, false) {
            Ok(o) => (o, None),
            Err(_) => (Object::Sphere, Some(PathBuf::from(&self.object))),
        };
        Ok(RenderConfig {
            btf: self.btf.clone(),
            object,
            mesh,
            lights,
            width: self.width,
            height: self.height,
            map_res: self.map_res,
            layout: self.layout.unwrap_or(self.texture.default_layout()),
            texture: self.texture,
            reference: self.reference,
            error_scale: self.error_scale,
            out: self.out.clone(),
            bench: crate::bench::BenchConfig::default(),
            env: self.env.as_ref().map(|p| EnvConfig {
                path: p.clone(),
                lobes: self.env_lobes,
                rotate_deg: self.rotate,
                hdr: self.hdr.policy(),
            }),
        })
    }

    /// `vkshade btf render`: renders, compares (with `--reference`) and prints the summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        if self.anim.is_some() || !self.part.is_empty() {
            return self.run_anim(gpu);
        }
        let cfg = self.config()?;
        let ctx = context(gpu, self.texture)?;
        eprintln!("vkshade btf render on {}", ctx.info().name);
        let r = render(&ctx, &cfg, &mut |l| super::progress(l))?;
        display(&r);
        super::finish(ctx)
    }
}

/// The summary `vkshade btf render` prints: GPU time and memory, the errors against the
/// references (with `--reference`) and what was written.
pub fn display(r: &RenderReport) {
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
    if let (Some(e), Some(ms)) = (&r.env, &r.env_gpu_ms) {
        println!(
            "environment {} ({} lobes, turned {} deg): btf env {:.3} ms GPU (median)",
            e.path.display(),
            e.lobes,
            e.rotate_deg,
            ms.median
        );
    }
    if let Some(v) = &r.vs_env {
        println!(
            "environment vs the BTF's quadrature of the map (1): relative L2 {:.4}; vs the interpolated BTF's integral (2): {:.4}; (1) vs (2): {:.4}; vs CPU twin: max {:.2e} (peak {:.3})",
            v.vs_quadrature,
            v.vs_interpolated,
            v.quadrature_vs_interpolated,
            v.vs_twin_max_abs,
            v.env_max
        );
    }
    println!(
        "host {:.3} ms per frame (median; recording + submit, no waits)",
        r.host_ms.median
    );
    println!("wrote {}, {} and report.json", r.png, r.exr);
}

/// The context the moving garment needs: 64-bit buffer atomics for the rasteriser (and
/// textureCompressionBC for `--texture bc1`).
pub fn anim_context(gpu: &Gpu, texture: Texture) -> Result<Context> {
    gpu.context_with(crate::gpu::Features {
        texture_compression_bc: texture == Texture::Bc1,
        buffer_int64_atomics: true,
        ..Default::default()
    })
}

/// What `btf render --anim` writes to anim.json.
#[derive(Clone, Debug, Serialize)]
pub struct AnimReport {
    pub tool: &'static str,
    pub machine: MachineInfo,
    pub config: GarmentConfig,
    pub btf: String,
    pub frames: u32,
    pub frame_rate: f32,
    pub triangles: usize,
    pub vertices: usize,
    /// GPU ms of each pass over the frames.
    pub pass_ms: Vec<(&'static str, crate::report::Stats)>,
    /// Host ms per frame outside waiting: joint matrices, recording (with the output's
    /// readback copy) and submit.
    pub host_ms: crate::report::Stats,
    pub covered_pixels: Vec<usize>,
    pub pngs: Vec<String>,
}

/// `vkshade btf render --anim`: the garment in motion, one PNG per frame.
pub fn render_anim(
    ctx: &Context,
    btf_dir: &Path,
    cfg: &GarmentConfig,
    (frames, frame_rate): (u32, f32),
    out: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<AnimReport> {
    let report_path = out.join("anim.json");
    crate::io::outdir::claim(out, "btf render")?;
    if frames == 0 || !(frame_rate.is_finite() && frame_rate > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "--frames {frames} and --frame-rate {frame_rate}: need at least one frame at a positive rate"
        )));
    }
    let btf = load::load_dir(btf_dir)?;
    let maps = Maps::build(&Triangulation::new()?, cfg.map_res)?;
    let g = Garment::new(ctx, cfg, &btf, &maps)?;
    let (triangles, vertices) = g.counts();
    progress(&format!(
        "{} of {}: {triangles} triangles, {vertices} vertices, animation '{}' ({:.2} s)",
        cfg.parts.join("+"),
        cfg.mesh.display(),
        g.animation().name,
        g.animation().duration
    ));
    let names = g.passes();
    let mut pass = vec![Vec::new(); names.len()];
    let (mut host, mut covered, mut pngs) = (Vec::new(), Vec::new(), Vec::new());
    let [w, h] = cfg.size;
    for i in 0..frames {
        let t0 = Instant::now();
        let m = g.matrices(i as f32 / frame_rate);
        let mut rec = ctx.recorder(&format!("garment frame {i}"))?;
        g.record(&mut rec, &m)?;
        let rb = g.read_back(&mut rec)?;
        let sub = rec.submit()?;
        host.push(t0.elapsed().as_secs_f64() * 1e3);
        let timings = sub.wait()?;
        for (n, p) in names.iter().zip(pass.iter_mut()) {
            p.push(
                timings
                    .get(n)
                    .ok_or_else(|| Error::InvalidArgument(format!("pass '{n}' was not timed")))?,
            );
        }
        let px: Vec<[f32; 4]> = rb.to_vec()?;
        covered.push(px.iter().filter(|p| p[3] > 0.0).count());
        let rgb: Vec<u8> = px
            .iter()
            .flat_map(|p| [p[0], p[1], p[2]].map(srgb_encode))
            .collect();
        let png = out.join(format!("frame_{i:04}.png"));
        crate::render::write_png(&png, w, h, &rgb)?;
        pngs.push(png.display().to_string());
    }
    let stats = |s: &[f64]| {
        crate::report::Stats::of(s).ok_or_else(|| Error::InvalidArgument("no samples".into()))
    };
    let report = AnimReport {
        tool: "vkshade btf render --anim",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        btf: btf_dir.display().to_string(),
        frames,
        frame_rate,
        triangles,
        vertices,
        pass_ms: names
            .iter()
            .zip(&pass)
            .map(|(n, p)| Ok((*n, stats(p)?)))
            .collect::<Result<_>>()?,
        host_ms: stats(&host)?,
        covered_pixels: covered,
        pngs,
    };
    crate::io::write_json(&report_path, &report)?;
    Ok(report)
}

impl RenderArgs {
    /// The moving garment these arguments describe.
    pub fn garment(&self) -> Result<GarmentConfig> {
        let (Some(anim), false) = (&self.anim, self.part.is_empty()) else {
            return Err(Error::InvalidArgument(
                "--anim and --part go together: the parts of the --object glTF to cover, and the animation to play".into(),
            ));
        };
        if !(self.tile_scale.is_finite() && self.tile_scale > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "--tile-scale must be > 0, not {}",
                self.tile_scale
            )));
        }
        let cfg = self.config()?;
        let mesh = cfg.mesh.ok_or_else(|| {
            Error::InvalidArgument("--anim needs --object to be a glTF character".into())
        })?;
        Ok(GarmentConfig {
            mesh,
            parts: self.part.clone(),
            anim: anim.clone(),
            size: [self.width, self.height],
            tile_scale: self.tile_scale,
            map_res: self.map_res,
            texture: self.texture,
            layout: self.layout.unwrap_or(self.texture.default_layout()),
            lights: cfg.lights,
            env_lobes: match &cfg.env {
                Some(e) => e.fit()?.1,
                None => Vec::new(),
            },
            tiles: true,
        })
    }

    /// `vkshade btf render --anim`.
    fn run_anim(&self, gpu: &Gpu) -> Result<()> {
        let cfg = self.garment()?;
        let ctx = anim_context(gpu, self.texture)?;
        eprintln!("vkshade btf render --anim on {}", ctx.info().name);
        let r = render_anim(
            &ctx,
            &self.btf,
            &cfg,
            (self.frames, self.frame_rate),
            &self.out,
            &mut |l| super::progress(l),
        )?;
        println!(
            "{} frames of {} x {} ({} triangles):",
            r.frames, cfg.size[0], cfg.size[1], r.triangles
        );
        let mut total = 0.0;
        for (n, s) in &r.pass_ms {
            println!("  {n:<18} {:.3} ms GPU (median)", s.median);
            total += s.median;
        }
        println!(
            "  frame              {total:.3} ms GPU = {:.1} fps; host {:.3} ms per frame (median, recording + submit, no waits)",
            1000.0 / total,
            r.host_ms.median
        );
        println!(
            "wrote {} .. {} and anim.json",
            r.pngs.first().map_or("", |s| s.as_str()),
            r.pngs.last().map_or("", |s| s.as_str())
        );
        super::finish(ctx)
    }
}

/// `vkshade bench btf --anim`: the garment's per-frame cost.
pub fn bench_anim(gpu: &Gpu, opts: &super::bench::Opts, texture: Texture) -> Result<()> {
    super::bench::check_outputs(opts, false)?;
    let bench = opts.config()?;
    let cfg = GarmentConfig {
        mesh: PathBuf::from("data/bcn_epileptic.glb"),
        parts: vec!["Torso".into(), "Legs".into()],
        anim: "Epileptisch".into(),
        size: [512, 512],
        tile_scale: 8.0,
        map_res: 128,
        texture,
        layout: texture.default_layout(),
        lights: default_lights(),
        env_lobes: Vec::new(),
        tiles: true,
    };
    // The environment pass (`btf env`, per-pixel light factors) is not timed here: at
    // 512 x 512 it costs seconds a frame on lavapipe (README, "BTF cloth shading"); `btf
    // render --env` measures it.
    let ctx = anim_context(gpu, texture)?;
    eprintln!("bench btf --anim on {}", ctx.info().name);
    let r = crate::bench::btf::run_anim(&ctx, &cfg, &bench, 32, &mut |l| super::progress(l))?;
    println!("device                 {}", r.machine.device);
    println!(
        "garment                {} ({} triangles, {} vertices), {} x {}, tile 32 x {} per uv, {:?}",
        cfg.parts.join("+"),
        r.triangles,
        r.vertices,
        cfg.size[0],
        cfg.size[1],
        cfg.tile_scale,
        texture
    );
    for ((n, s), (_, share)) in r.pass_ms.iter().zip(&r.pass_share) {
        println!(
            "  {n:<20} {:>7.3} ms GPU (median, spread {:.0}%), {:>5.1}% of the frame",
            s.median,
            100.0 * s.spread,
            100.0 * share
        );
    }
    println!(
        "frame                  {:.3} ms GPU = {:.1} fps; wall clock {:.1} fps (2 in flight); host {:.3} ms per frame (median; max {:.3})",
        r.frame_gpu_ms.median, r.fps_gpu, r.fps_wall, r.host_ms.median, r.host_ms.max
    );
    println!(
        "same run               btf shade alone on the static sphere ({} px covered; the garment: {}): {:.3} ms GPU = {:.1} fps",
        r.sphere_covered_pixels,
        r.covered_pixels,
        r.sphere_btf_ms.median,
        1000.0 / r.sphere_btf_ms.median
    );
    if let Some(cpu) = r.cpu_ms_per_frame {
        println!(
            "cpu                    {cpu:.3} ms of process CPU time per frame (lavapipe's workers included; 2 in flight)"
        );
    }
    if let Some(e) = &r.every_pixel {
        let passes: Vec<String> = e
            .pass_ms
            .iter()
            .map(|(n, s)| format!("{n} {:.3}", s.median))
            .collect();
        println!(
            "same run               every pixel (no tile list): {:.3} ms GPU = {:.1} fps; wall clock {:.1} fps; cpu {} ms per frame; per pass ms: {}",
            e.frame_gpu_ms.median,
            1000.0 / e.frame_gpu_ms.median,
            e.fps_wall,
            e.cpu_ms_per_frame.map_or("-".into(), |c| format!("{c:.3}")),
            passes.join(", ")
        );
    }
    println!(
        "tiles                  {} of 16 x 4 px hold a covered pixel, {} listed with last frame's: raster resolve and btf shade run {} px of {}",
        r.covered_tiles,
        r.listed_tiles,
        r.listed_tiles * 64,
        cfg.size[0] * cfg.size[1]
    );
    for t in &r.targets {
        println!(
            "target                 {}: {:.1} vs {:.0}: {}",
            t.name,
            t.measured,
            t.target,
            if t.pass { "pass" } else { "MISS" }
        );
    }
    super::bench::write_json(opts, &r)?;
    super::finish(ctx)
}
