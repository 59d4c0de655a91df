//! `vkshade frame` (any skinned glTF character with named skin and cloth parts) and
//! `vkshade demo` (the same on the built-in character): N frames of an animation rendered on
//! the GPU, frames in flight, written as frame_NNNN.png / .exr, an animated PNG of the
//! sequence, a contact sheet, a per-pass GPU timing chart and report.json.

use super::Gpu;
use crate::error::{Error, Result};
use crate::frame::{CharacterFrame, FrameConfig, FrameInput, SetupReport};
use crate::io::FloatImage;
use glam::Mat3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `vkshade frame`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// The skinned glTF character.
    #[arg(long, default_value = crate::kernels::sss::DEFAULT_MESH)]
    pub mesh: PathBuf,
    /// Its parts rendered as skin, comma-separated (node or mesh names; "" for none).
    #[arg(long, default_value = "Head")]
    pub skin: String,
    /// Its parts rendered as cloth, comma-separated ("" for none).
    #[arg(long, default_value = "Torso,Legs")]
    pub cloth: String,
    /// A BTF directory (`vkshade btf synth` layout); default: a woven tile synthesised in
    /// memory.
    #[arg(long)]
    pub btf: Option<PathBuf>,
    /// The HDR environment (EXR or .hdr), fitted once with spherical Gaussians.
    #[arg(long, default_value = crate::kernels::srbf::DEFAULT_ENV)]
    pub env: PathBuf,
    /// No environment: the directional lights alone.
    #[arg(long)]
    pub no_env: bool,
    #[command(flatten)]
    pub hdr: super::Hdr,
    /// Lobes of the environment's fit.
    #[arg(long, default_value_t = 16)]
    pub env_lobes: usize,
    /// Rays per vertex and axis that correct the environment's per-lobe split each frame
    /// (grid^2 rays through the posed mesh, 1..=16); 0: AO's visibility as a scale instead.
    #[arg(long, default_value_t = crate::kernels::env::DEFAULT_TRACE_GRID)]
    pub env_trace_grid: u32,
    /// The brightest lobes the cloth's environment looks up at every pixel; the others' light
    /// factors are interpolated from the cloth's vertices (0: every lobe from the vertices,
    /// the fastest; at least --env-lobes: every lobe at every pixel, the most exact)
    #[arg(long, default_value_t = 0)]
    pub cloth_pixel_lobes: usize,
    /// The cloth BTF's texel format for `btf shade`: block (decoded and filtered in the
    /// shader, the fastest on lavapipe), rgba8 (sRGB) or bc1 (sRGB BC1, needs the device
    /// feature textureCompressionBC).
    #[arg(long, default_value = "block",
          value_parser = super::choice::<crate::kernels::btf::pack::Texture>("texture format"))]
    pub cloth_texture: crate::kernels::btf::pack::Texture,
    /// Diffuse every atlas segment, shade every pixel and the environment at every vertex,
    /// not only what the camera sees (the same images, slower: an A/B switch for the
    /// culling)
    #[arg(long)]
    pub no_cull: bool,
    /// The animation to play.
    #[arg(long, default_value = "Epileptisch")]
    pub anim: String,
    /// Frames, spread evenly over one loop of the animation.
    #[arg(long, default_value_t = 24)]
    pub frames: usize,
    /// Degrees the environment turns about the vertical over the sequence.
    #[arg(long, default_value_t = 360.0)]
    pub rotate: f32,
    /// Output width and height.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// The skin's texture-space atlas side.
    #[arg(long, default_value_t = 512)]
    pub atlas: u32,
    /// Diffusion samples per texel.
    #[arg(long, default_value_t = 32)]
    pub samples: u32,
    /// Millimetres per model unit (default: 1000 for the built-in character, else 1).
    #[arg(long)]
    pub mm_per_unit: Option<f64>,
    /// BTF tile repeats per unit of the cloth's uv.
    #[arg(long, default_value_t = 20.0)]
    pub tile_scale: f32,
    /// A cloth part's own BTF, PART=weave|knit|rib|DIRECTORY (a pattern synthesised in
    /// memory, or a `btf synth`-layout directory); repeat for more parts. The other cloth
    /// parts take --btf.
    #[arg(long = "part-btf", value_name = "PART=BTF")]
    pub part_btf: Vec<String>,
    /// A cloth part's own tile scale, PART=REPEATS; repeat for more parts. The other cloth
    /// parts take --tile-scale.
    #[arg(long = "part-tile-scale", value_name = "PART=REPEATS")]
    pub part_tile_scale: Vec<String>,
    /// The skin's scattering material: skin1 or skin2 (Jensen et al. 2001's measured
    /// skins), or SA_R,SA_G,SA_B/SS_R,SS_G,SS_B[/ETA] (sigma_a and sigma_s' per mm).
    #[arg(long, default_value = "skin1")]
    pub skin_material: String,
    /// A skin part's own scattering material, PART=MATERIAL (as --skin-material); repeat for
    /// more parts (multi-region skin: each texel diffuses with its part's profile). The
    /// other skin parts take --skin-material.
    #[arg(long = "part-skin", value_name = "PART=MATERIAL")]
    pub part_skin: Vec<String>,
    /// Radiance multiplier before tone mapping.
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// Frames submitted before the oldest is waited for.
    #[arg(long, default_value_t = 2)]
    pub in_flight: usize,
    /// Output directory.
    #[arg(long, default_value = "out/frame")]
    pub out: PathBuf,
    /// After the sequence, three poses (1/6, 1/2 and 5/6 of the loop) compared with their
    /// truths: the environment light shadowed by the character against rays cast through
    /// the posed mesh (with the AO-weighted floor and the unshadowed light beside it), the
    /// compose pass against its CPU twin; each pose written as DIR/reference_NNNN.ply
    /// (posed positions, normals, environment irradiance r g b and the truth's, AO).
    #[arg(long)]
    pub reference: bool,
    /// Rays per vertex of the environment's ray-traced truth (with --reference).
    #[arg(long, default_value_t = 1024)]
    pub rays: usize,
    /// Rays per vertex of AO's static correction, baked once in the bind pose where the
    /// frame computes AO's visibility (--reference, --env-trace-grid 0); 0: AO and the
    /// environment's shadowing by the sphere tree alone.
    #[arg(long, default_value_t = 1024)]
    pub ao_correction_rays: usize,
    /// Where the parts' colours come from: "gltf", each part's glTF base colour (factor
    /// times its sRGB texture) as its albedo, or "measured", the skin profile's and the
    /// BTF's own colours. The demo uses "measured": its character's only material is the
    /// exporter's placeholder grey.
    #[arg(long, default_value = "gltf", value_parser = ["gltf", "measured"])]
    pub materials: String,
}

/// An invalid argument's message without its prefix (to be wrapped in another).
fn argument_message(e: Error) -> String {
    match e {
        Error::InvalidArgument(m) => m,
        other => other.to_string(),
    }
}

/// A `--part-*` flag's PART=VALUE, both sides non-empty.
fn split_part(flag: &str, s: &str) -> Result<(String, String)> {
    match s.split_once('=') {
        Some((p, v)) if !p.trim().is_empty() && !v.trim().is_empty() => {
            Ok((p.trim().to_string(), v.trim().to_string()))
        }
        _ => Err(Error::InvalidArgument(format!(
            "{flag} '{s}': expected PART=VALUE"
        ))),
    }
}

impl Args {
    /// `--part-skin`, one entry per part named.
    fn skin_parts(&self) -> Result<Vec<crate::frame::SkinPart>> {
        let mut out: Vec<crate::frame::SkinPart> = Vec::new();
        for s in &self.part_skin {
            let (part, v) = split_part("--part-skin", s)?;
            if out.iter().any(|o| o.part == part) {
                return Err(Error::InvalidArgument(format!(
                    "--part-skin names part '{part}' twice"
                )));
            }
            let material = crate::frame::parse_skin_material(&v).map_err(|e| {
                Error::InvalidArgument(format!("--part-skin '{s}': {}", argument_message(e)))
            })?;
            out.push(crate::frame::SkinPart { part, material });
        }
        Ok(out)
    }

    /// `--part-btf` and `--part-tile-scale`, one entry per part named.
    fn cloth_parts(&self) -> Result<Vec<crate::frame::ClothPart>> {
        let split = split_part;
        let mut out: Vec<crate::frame::ClothPart> = Vec::new();
        fn entry(out: &mut Vec<crate::frame::ClothPart>, part: String) -> usize {
            match out.iter().position(|c| c.part == part) {
                Some(i) => i,
                None => {
                    out.push(crate::frame::ClothPart {
                        part,
                        btf: None,
                        tile_scale: None,
                    });
                    out.len() - 1
                }
            }
        }
        let mut seen = std::collections::HashSet::new();
        for s in &self.part_btf {
            let (p, v) = split("--part-btf", s)?;
            if !seen.insert(("btf", p.clone())) {
                return Err(Error::InvalidArgument(format!(
                    "--part-btf names part '{p}' twice"
                )));
            }
            let i = entry(&mut out, p);
            out[i].btf = Some(crate::frame::BtfSource::parse(&v));
        }
        for s in &self.part_tile_scale {
            let (p, v) = split("--part-tile-scale", s)?;
            if !seen.insert(("scale", p.clone())) {
                return Err(Error::InvalidArgument(format!(
                    "--part-tile-scale names part '{p}' twice"
                )));
            }
            let t: f32 = v.parse().map_err(|_| {
                Error::InvalidArgument(format!("--part-tile-scale '{s}': '{v}' is not a number"))
            })?;
            let i = entry(&mut out, p);
            out[i].tile_scale = Some(t);
        }
        Ok(out)
    }

    fn config(&self) -> Result<FrameConfig> {
        let list = |s: &str| -> Vec<String> {
            s.split(',')
                .map(str::trim)
                .filter(|t| !t.is_empty())
                .map(String::from)
                .collect()
        };
        let d = FrameConfig::default();
        let cloth_parts = self.cloth_parts()?;
        let skin_parts = self.skin_parts()?;
        let skin_material =
            crate::frame::parse_skin_material(&self.skin_material).map_err(|e| {
                Error::InvalidArgument(format!("--skin-material: {}", argument_message(e)))
            })?;
        let cfg = FrameConfig {
            mesh: self.mesh.clone(),
            skin: list(&self.skin),
            cloth: list(&self.cloth),
            anim: self.anim.clone(),
            size: [self.size, self.size],
            atlas: self.atlas,
            samples: self.samples,
            mm_per_unit: self
                .mm_per_unit
                .unwrap_or_else(|| crate::kernels::sss::default_mm_per_unit(&self.mesh)),
            tile_scale: self.tile_scale,
            btf: self.btf.clone(),
            exposure: self.exposure,
            env: (!self.no_env).then(|| self.env.clone()),
            env_lobes: self.env_lobes,
            env_hdr: self.hdr.policy(),
            env_trace_grid: (self.env_trace_grid > 0).then_some(self.env_trace_grid),
            cull: !self.no_cull,
            cloth_pixel_lobes: self.cloth_pixel_lobes,
            cloth_texture: self.cloth_texture,
            // The reference compares (and writes) every vertex's environment irradiance.
            env_every_vertex: self.reference,
            // ... and reports the AO-weighted floor beside it.
            ao_visibility: self.reference,
            ao_correction_rays: self.ao_correction_rays,
            materials: match self.materials.as_str() {
                "measured" => crate::frame::Materials::Measured,
                _ => crate::frame::Materials::Gltf,
            },
            cloth_parts,
            skin_material,
            skin_parts,
            ..d
        };
        cfg.check()?;
        if self.frames == 0 || self.frames > 10_000 {
            return Err(Error::InvalidArgument(format!(
                "--frames {} must be in 1..=10000",
                self.frames
            )));
        }
        if !self.rotate.is_finite() {
            return Err(Error::InvalidArgument("--rotate must be finite".into()));
        }
        if !(16..=8192).contains(&self.size) {
            return Err(Error::InvalidArgument(format!(
                "--size {} must be in 16..=8192",
                self.size
            )));
        }
        if !(1..=4096).contains(&self.samples) {
            return Err(Error::InvalidArgument(format!(
                "--samples {} must be in 1..=4096",
                self.samples
            )));
        }
        if !(self.exposure.is_finite() && self.exposure > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "--exposure {} must be finite and > 0",
                self.exposure
            )));
        }
        if !(1..=16).contains(&self.in_flight) {
            return Err(Error::InvalidArgument(format!(
                "--in-flight {} must be in 1..=16",
                self.in_flight
            )));
        }
        if self.reference && !(1..=1 << 20).contains(&self.rays) {
            return Err(Error::InvalidArgument(format!(
                "--rays {} must be in 1..=1048576",
                self.rays
            )));
        }
        if self.ao_correction_rays > 1 << 20 {
            return Err(Error::InvalidArgument(format!(
                "--ao-correction-rays {} must be at most 1048576 (0: off)",
                self.ao_correction_rays
            )));
        }
        Ok(cfg)
    }

    /// Runs the frames and writes everything under `--out`.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        let cfg = self.config()?;
        crate::io::outdir::check_claimable(&self.out, "frame")?;
        let ctx = context_for(gpu, cfg.cloth_texture)?;
        eprintln!("vkshade frame on {}", ctx.info().name);
        let t = Instant::now();
        let report = render(&ctx, &cfg, self, &mut |l| super::progress(l))?;
        display(&report, &self.out);
        eprintln!("total {:.1} s", t.elapsed().as_secs_f64());
        super::finish(ctx)
    }
}

/// The context a character frame needs: 64-bit buffer atomics for the rasteriser.
pub fn context(gpu: &Gpu) -> Result<crate::gpu::Context> {
    context_for(gpu, crate::kernels::btf::pack::Texture::Block)
}

/// As [`context`], with the device feature textureCompressionBC when the cloth's BTF is
/// packed as BC1 (`--cloth-texture bc1`), saying which option needs it when it is missing.
fn context_for(
    gpu: &Gpu,
    cloth_texture: crate::kernels::btf::pack::Texture,
) -> Result<crate::gpu::Context> {
    let bc1 = cloth_texture == crate::kernels::btf::pack::Texture::Bc1;
    gpu.context_with(crate::gpu::Features {
        buffer_int64_atomics: true,
        texture_compression_bc: bc1,
        ..Default::default()
    })
    .map_err(|e| match e {
        crate::Error::Unsupported { device, what } if bc1 => crate::Error::Unsupported {
            device,
            what: format!(
                "{what} (--cloth-texture bc1 needs it; use --cloth-texture block or rgba8)"
            ),
        },
        e => e,
    })
}

/// `vkshade demo`: the frame on the built-in character, 24 frames, out/demo/, the Legs in a
/// corduroy rib.
pub fn demo(gpu: &Gpu) -> Result<()> {
    use clap::{Args as _, FromArgMatches};
    let matches = Args::augment_args(clap::Command::new("frame")).get_matches_from([
        "frame",
        "--out",
        "out/demo",
        "--materials",
        "measured",
        // A shirt and trousers: the Torso keeps the woven tile, the Legs wear a corduroy
        // rib at a coarser tile (one BTF kernel per distinct BTF).
        "--part-btf",
        "Legs=rib",
        "--part-tile-scale",
        "Legs=10",
    ]);
    let args =
        Args::from_arg_matches(&matches).map_err(|e| Error::InvalidArgument(e.to_string()))?;
    args.run(gpu)
}

/// Median GPU ms of one pass over the frames.
#[derive(Clone, Debug, Serialize)]
pub struct PassTime {
    pub name: String,
    pub ms: f64,
}

/// What `vkshade frame` writes to report.json.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub tool: &'static str,
    pub device: String,
    pub config: FrameConfig,
    pub frames: usize,
    pub in_flight: usize,
    pub env_rotation_deg: f32,
    pub setup: SetupReport,
    pub setup_ms: f64,
    /// Median GPU ms per pass.
    pub passes: Vec<PassTime>,
    /// Median GPU ms of the whole frame (sum of its passes).
    pub gpu_ms: f64,
    pub fps_gpu: f64,
    /// Median host ms per frame outside waiting (recording, uniforms, submission).
    pub host_ms: f64,
    /// Wall-clock ms per frame over the sequence (frames in flight, readback and file
    /// writing included).
    pub wall_ms: f64,
    pub device_memory_bytes: u64,
    /// The process's resident memory (MiB, Linux VmRSS) after the first frame and after the
    /// last, and its largest value in between, less the frames the command keeps for the
    /// animated PNG and the contact sheet (W x H x 3 bytes each): a frame loop that leaks
    /// shows the growth here (lavapipe's device memory is host memory, so it counts too).
    pub rss_mib_first: Option<f64>,
    pub rss_mib_last: Option<f64>,
    pub rss_mib_max: Option<f64>,
    pub files: Vec<String>,
    /// With --reference: each stage against its truth at three poses.
    pub reference: Vec<ReferencePose>,
}

/// The pixel of a reference pose whose compose output differs most from the twin's.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ComposeWorst {
    pub pixel: usize,
    pub gpu: [f32; 3],
    pub twin: [f32; 3],
    pub skin: bool,
}

/// One pose of `vkshade frame --reference`: the frame's stages against their truths.
#[derive(Clone, Debug, Serialize)]
pub struct ReferencePose {
    /// Animation time (s) and the environment's turn (degrees).
    pub time: f32,
    pub rotation_deg: f32,
    /// Environment irradiance per vertex (the frame's `env shadow`) against the ray-traced
    /// truth, with the AO-weighted floor and the unshadowed light beside it; None without an
    /// environment.
    pub env: Option<crate::kernels::env::cpu::TruthErrors>,
    pub rays: usize,
    /// The compose pass against its CPU twin on the same stages: relative RMS of the linear
    /// radiance, and the largest difference of the 8-bit image (levels).
    pub compose_rel_rms: f64,
    pub compose_max_levels: u32,
    /// The pixel that weighs most in `compose_rel_rms` (the largest squared difference from
    /// the twin over its channels): its index (row-major), GPU and twin radiance, and
    /// whether it is skin.
    pub compose_worst: ComposeWorst,
    /// The cloth: the light basis against the BTF's own quadrature of the same lobes and
    /// visibility, the GPU against the twins; None without cloth.
    pub cloth: Option<crate::frame::ClothErrors>,
    /// The PLY written for the pose.
    pub ply: Option<String>,
}

/// Renders the frames and writes the pictures and report.
pub fn render(
    ctx: &crate::gpu::Context,
    cfg: &FrameConfig,
    args: &Args,
    progress: &mut dyn FnMut(&str),
) -> Result<FrameReport> {
    let t0 = Instant::now();
    let frame = CharacterFrame::new(ctx, cfg, progress)?;
    let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
    crate::io::outdir::claim(&args.out, "frame")?;
    let n = args.frames;
    let duration = frame.animation().duration;
    let inputs: Vec<FrameInput> = (0..n)
        .map(|i| FrameInput {
            time: duration * i as f32 / n as f32,
            env_rotation: Mat3::from_rotation_y((args.rotate * i as f32 / n as f32).to_radians()),
        })
        .collect();
    let names = crate::frame::pass_names(&frame);
    let mut per_pass: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let (mut host, mut total) = (Vec::new(), Vec::new());
    let [w, h] = cfg.size;
    let mut rgb_frames: Vec<Vec<u8>> = Vec::new();
    let mut files = Vec::new();
    let mut rss: Vec<f64> = Vec::new();
    let t = Instant::now();
    crate::frame::run(ctx, &frame, &inputs, args.in_flight, |f| {
        let mut sum = 0.0;
        for (name, v) in names.iter().zip(per_pass.iter_mut()) {
            let ms = f
                .timings
                .get(name)
                .ok_or_else(|| Error::InvalidArgument(format!("pass '{name}' was not timed")))?;
            v.push(ms);
            sum += ms;
        }
        total.push(sum);
        host.push(f.host_ms);
        let rgb: Vec<u8> = f
            .output
            .ldr
            .iter()
            .flat_map(|p| {
                let b = p.to_le_bytes();
                [b[0], b[1], b[2]]
            })
            .collect();
        let png = args.out.join(format!("frame_{:04}.png", f.index));
        crate::render::write_png(&png, w, h, &rgb)?;
        let exr = args.out.join(format!("frame_{:04}.exr", f.index));
        let img = FloatImage {
            width: w,
            height: h,
            pixels: f.output.hdr.clone(),
        };
        crate::io::exr::write(&exr, &img, crate::io::exr::Channels::Rgba)?;
        if f.index == 0 || f.index + 1 == n {
            files.push(png.display().to_string());
            files.push(exr.display().to_string());
        }
        progress(&format!(
            "frame {} (t {:.2} s): GPU {:.1} ms, host {:.3} ms",
            f.index, inputs[f.index].time, sum, f.host_ms
        ));
        rgb_frames.push(rgb);
        let kept: usize = rgb_frames.iter().map(Vec::len).sum();
        if let Some(m) = resident_mib() {
            rss.push(m - kept as f64 / (1 << 20) as f64);
        }
        Ok(())
    })?;
    let wall_ms = t.elapsed().as_secs_f64() * 1e3 / n as f64;
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let apng = args.out.join("animation.png");
    crate::render::write_apng(&apng, w, h, &rgb_frames, 80)?;
    files.push(apng.display().to_string());
    let sheet = args.out.join("contact_sheet.png");
    contact_sheet(&sheet, w, h, &rgb_frames)?;
    files.push(sheet.display().to_string());
    let chart = args.out.join("timing.png");
    timing_chart(&chart, &names, &per_pass)?;
    files.push(chart.display().to_string());
    let gpu_ms = median(&total);
    let reference = if args.reference {
        reference_poses(ctx, &frame, args, progress)?
    } else {
        Vec::new()
    };
    let report = FrameReport {
        tool: "vkshade frame",
        device: ctx.info().name.clone(),
        config: cfg.clone(),
        frames: n,
        in_flight: args.in_flight,
        env_rotation_deg: args.rotate,
        setup: frame.setup.clone(),
        setup_ms,
        passes: names
            .iter()
            .zip(&per_pass)
            .map(|(n, v)| PassTime {
                name: n.to_string(),
                ms: median(v),
            })
            .collect(),
        gpu_ms,
        fps_gpu: 1000.0 / gpu_ms,
        host_ms: median(&host),
        wall_ms,
        device_memory_bytes: frame.memory_bytes(),
        rss_mib_first: rss.first().copied(),
        rss_mib_last: rss.last().copied(),
        rss_mib_max: rss.iter().copied().reduce(f64::max),
        files,
        reference,
    };
    crate::io::write_json(&args.out.join("report.json"), &report)?;
    Ok(report)
}

/// Every frame at half size on a grid of up to 6 columns.
fn contact_sheet(path: &Path, w: u32, h: u32, frames: &[Vec<u8>]) -> Result<()> {
    let cols = frames.len().clamp(1, 6);
    let rows = frames.len().div_ceil(cols);
    let (sw, sh) = ((w / 2).max(1) as usize, (h / 2).max(1) as usize);
    let (width, height) = (cols * sw, rows * sh);
    let mut out = vec![0u8; width * height * 3];
    for (k, f) in frames.iter().enumerate() {
        let (cx, cy) = ((k % cols) * sw, (k / cols) * sh);
        for y in 0..sh {
            for x in 0..sw {
                for c in 0..3 {
                    // The mean of the 2 x 2 block (sRGB bytes; a thumbnail).
                    let mut s = 0u32;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = (
                            (2 * x + dx).min(w as usize - 1),
                            (2 * y + dy).min(h as usize - 1),
                        );
                        s += f[(sy * w as usize + sx) * 3 + c] as u32;
                    }
                    out[((cy + y) * width + cx + x) * 3 + c] = (s / 4) as u8;
                }
            }
        }
    }
    crate::render::write_png(path, width as u32, height as u32, &out)
}

/// GPU ms of each pass over the frames (the passes under 2% of the frame are summed into
/// "other").
fn timing_chart(path: &Path, names: &[&str], per_pass: &[Vec<f64>]) -> Result<()> {
    use crate::bench::plot::{Panel, Series, draw};
    let frames = per_pass.first().map_or(0, Vec::len);
    let total: Vec<f64> = (0..frames)
        .map(|i| per_pass.iter().map(|v| v[i]).sum())
        .collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let whole = mean(&total);
    let mut series = vec![Series {
        name: "whole frame".into(),
        points: total
            .iter()
            .enumerate()
            .map(|(i, &m)| (i as f64, m))
            .collect(),
    }];
    let mut other = vec![0.0; frames];
    for (name, v) in names.iter().zip(per_pass) {
        if mean(v) < 0.02 * whole {
            for (o, m) in other.iter_mut().zip(v) {
                *o += m;
            }
            continue;
        }
        series.push(Series {
            name: name.to_string(),
            points: v.iter().enumerate().map(|(i, &m)| (i as f64, m)).collect(),
        });
    }
    series.push(Series {
        name: "other passes".into(),
        points: other
            .iter()
            .enumerate()
            .map(|(i, &m)| (i as f64, m))
            .collect(),
    });
    draw(
        path,
        &[Panel {
            title: "character frame: GPU ms per pass".into(),
            x_label: "frame".into(),
            y_label: "GPU ms".into(),
            log_x: false,
            log_y: false,
            series,
        }],
    )
}

/// The summary `vkshade frame` prints.
pub fn display(r: &FrameReport, out: &Path) {
    println!(
        "{} frames at {} x {}: GPU {:.1} ms (median) = {:.1} fps, host {:.3} ms/frame, wall {:.1} ms/frame; setup {:.1} s; device memory {:.1} MiB",
        r.frames,
        r.config.size[0],
        r.config.size[1],
        r.gpu_ms,
        r.fps_gpu,
        r.host_ms,
        r.wall_ms,
        r.setup_ms / 1e3,
        r.device_memory_bytes as f64 / (1 << 20) as f64
    );
    for p in &r.passes {
        println!("  {:<24} {:>8.3} ms", p.name, p.ms);
    }
    if let (Some(a), Some(b), Some(m)) = (r.rss_mib_first, r.rss_mib_last, r.rss_mib_max) {
        println!(
            "host resident memory (less the frames kept for the animation) {a:.1} MiB after \
             the first frame, {b:.1} MiB after the last (max {m:.1})"
        );
    }
    if !r.reference.is_empty() {
        println!("stages against their truths (--reference):");
        println!(
            "  {:>7} {:>6}  {:>10} {:>10} {:>11} {:>8} {:>10} {:>10}  {:>11} {:>9}  {:>10} {:>10}",
            "time s",
            "turn",
            "env rel L2",
            "AO floor",
            "unshadowed",
            "enclosed",
            "env open",
            "floor open",
            "compose rel",
            "8-bit max",
            "cloth env",
            "cloth GPU"
        );
        let f = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{:.2}%", 100.0 * v));
        for p in &r.reference {
            println!(
                "  {:>7.2} {:>6.0}  {:>10} {:>10} {:>11} {:>8} {:>10} {:>10}  {:>11.2e} {:>9}  {:>10} {:>10}",
                p.time,
                p.rotation_deg,
                f(p.env.map(|e| e.rel_l2)),
                f(p.env.map(|e| e.floor_rel_l2)),
                f(p.env.map(|e| e.unshadowed_rel_l2)),
                p.env.map_or("-".to_string(), |e| e.enclosed.to_string()),
                f(p.env.map(|e| e.open_rel_l2)),
                f(p.env.map(|e| e.open_floor_rel_l2)),
                p.compose_rel_rms,
                p.compose_max_levels,
                f(p.cloth.map(|c| c.basis_vs_quadrature)),
                p.cloth
                    .map_or("-".to_string(), |c| format!("{:.1e}", c.gpu_vs_twins))
            );
        }
        if let Some(rays) = r.reference.first().map(|p| p.rays) {
            println!(
                "  (env: {rays} rays a vertex through the posed mesh; compose: the CPU twin on the \
                 same stages; cloth env: the light basis against the BTF's own quadrature of the \
                 same lobes and visibility; cloth GPU: against the twins; reference_NNNN.ply: \
                 positions, normals, r g b, truth_r g b, ao)"
            );
        }
    }
    println!(
        "wrote {} (frame_NNNN.png/.exr, animation.png, contact_sheet.png, timing.png, report.json)",
        out.display()
    );
}

/// The process's resident set in MiB (Linux: VmRSS of /proc/self/status); None elsewhere
/// or when it cannot be read.
fn resident_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// `--reference`: three poses rendered with their stages read back, each against its truth.
fn reference_poses(
    ctx: &crate::gpu::Context,
    frame: &CharacterFrame,
    args: &Args,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<ReferencePose>> {
    use crate::kernels::env::cpu as env_cpu;
    let duration = frame.animation().duration;
    let mesh = &frame.character.mesh;
    let mut out = Vec::new();
    for k in 0..3 {
        let at = (2 * k + 1) as f32 / 6.0;
        let rotation_deg = args.rotate * at;
        let input = FrameInput {
            time: duration * at,
            env_rotation: Mat3::from_rotation_y(rotation_deg.to_radians()),
        };
        let mut rec = ctx.recorder(&format!("frame reference pose {k}"))?;
        frame.record(&mut rec, &input)?;
        let rb = frame.read_back_stages(&mut rec)?;
        rec.submit()?.wait()?;
        let st = frame.collect_stages(&rb)?;
        // The compose pass against its twin.
        let (hdr, ldr) = frame.compose_twin(&frame.params(), &st);
        let (mut num, mut den) = (0.0f64, 0.0f64);
        let mut worst = (0.0f64, ComposeWorst::default());
        for (i, (a, b)) in st.output.hdr.iter().zip(&hdr).enumerate() {
            for c in 0..3 {
                let d = a[c] as f64 - b[c] as f64;
                num += d * d;
                den += (b[c] as f64).powi(2);
                if d * d > worst.0 {
                    worst = (
                        d * d,
                        ComposeWorst {
                            pixel: i,
                            gpu: [a[0], a[1], a[2]],
                            twin: [b[0], b[1], b[2]],
                            skin: st.gbuffer[i][3] != 0.0
                                && (crate::kernels::raster::pack::key_triangle(st.keys[i])
                                    as usize)
                                    < frame.setup.skin_triangles,
                        },
                    );
                }
            }
        }
        let compose_max_levels = st
            .output
            .ldr
            .iter()
            .zip(&ldr)
            .map(|(a, b)| {
                (0..4)
                    .map(|c| ((a >> (8 * c)) & 255).abs_diff((b >> (8 * c)) & 255))
                    .max()
                    .unwrap_or(0)
            })
            .max()
            .unwrap_or(0);
        let mut pose = ReferencePose {
            time: input.time,
            rotation_deg,
            env: None,
            rays: args.rays,
            compose_rel_rms: (num / den.max(1e-30)).sqrt(),
            compose_max_levels,
            compose_worst: worst.1,
            cloth: frame.cloth_errors(&st)?,
            ply: None,
        };
        if let Some(base) = frame.env_lobes() {
            let ao = st.ao.as_deref().ok_or_else(|| {
                Error::InvalidArgument(
                    "frame --reference: the frame computed no AO visibility for the floor".into(),
                )
            })?;
            let positions: Vec<glam::Vec3> = st
                .positions
                .iter()
                .map(|p| glam::Vec3::new(p[0], p[1], p[2]))
                .collect();
            let normals: Vec<glam::Vec3> = st
                .normals
                .iter()
                .map(|n| glam::Vec3::new(n[0], n[1], n[2]))
                .collect();
            let lobes = env_cpu::rotate(base, input.env_rotation);
            let bvh = crate::geom::bvh::Bvh::build(&positions, &mesh.triangles);
            let (lo, hi) = positions.iter().fold(
                (
                    glam::Vec3::splat(f32::INFINITY),
                    glam::Vec3::splat(f32::NEG_INFINITY),
                ),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            );
            let truth = {
                let _p = crate::progress::Progress::start(
                    &format!("reference pose {k}: ray-traced environment"),
                    positions.len() as u64,
                );
                env_cpu::ray_traced(
                    &positions,
                    &normals,
                    &bvh,
                    &lobes,
                    &env_cpu::TruthConfig {
                        rays: args.rays,
                        offset: 1e-4 * (hi - lo).length(),
                        seed: 0x5eed + k as u64,
                    },
                )
            };
            let mine: Vec<[f32; 3]> = st
                .env_irradiance
                .iter()
                .map(|e| [e[0], e[1], e[2]])
                .collect();
            pose.env = Some(env_cpu::against_truth(&lobes, &normals, ao, &mine, &truth));
            let ply = args.out.join(format!("reference_{k:04}.ply"));
            super::env::write_truth_ply(
                &ply,
                &format!(
                    "vkshade frame --reference: t {:.3} s, environment turned {rotation_deg:.1} \
                     deg; r g b: environment irradiance shadowed by the character (linear, \
                     radiometric, no 1/pi); truth_*: ray-traced ({} rays/vertex); ao: AO's \
                     visibility",
                    input.time, args.rays
                ),
                (&positions, &normals, &mesh.triangles),
                &mine,
                &truth,
                ao,
            )?;
            pose.ply = Some(ply.display().to_string());
        }
        progress(&format!(
            "reference pose {k} (t {:.2} s): env rel L2 {} (AO floor {}), compose vs twin {:.2e}",
            pose.time,
            pose.env
                .map(|e| e.rel_l2)
                .map_or("-".into(), |v| format!("{:.2}%", 100.0 * v)),
            pose.env
                .map(|e| e.floor_rel_l2)
                .map_or("-".into(), |v| format!("{:.2}%", 100.0 * v)),
            pose.compose_rel_rms
        ));
        out.push(pose);
    }
    Ok(out)
}
