//! `vkshade bench btf`: GPU time of `btf shade` on a cloth-covered sphere over resolution,
//! map resolution, tile size, layout and light count (one at a time around the headline),
//! filtered fetches per second against the rate a fetch probe sustains on the same texture
//! in the same run, the speed-up over the CPU interpolation, and texture memory.
//!
//! Timing does not depend on the texels, so the sweeps use hashed texels (the ray-cast
//! synthesis of a 32 x 32 tile takes ~20 s on two cores); the maps, G-buffer and lights are
//! the real ones.

use super::{BenchConfig, MachineInfo, Stats, time_cpu, time_gpu};
use crate::bench::time_passes;
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, Buffer, BufferDesc, Context, Image, ImageDesc, ImageRegion,
    Resource, Sampler, SamplerDesc,
};
use crate::kernels::btf::cpu;
use crate::kernels::btf::dirs::{self, Maps, Triangulation};
use crate::kernels::btf::gpu::{BtfInputs, BtfKernel, FORMAT, Layout, Packing, Sampled, Texture};
use crate::kernels::btf::synth::Btf;
use crate::scene::gbuffer::{Camera, EYE, Frame, GBuffer, Light, Object, render_object};
use glam::Vec3;
use serde::Serialize;
use std::time::Instant;

/// What `bench btf` measures.
#[derive(Clone, Debug, Serialize)]
pub struct BtfBenchConfig {
    pub bench: BenchConfig,
    /// Square output sizes.
    pub resolutions: Vec<u32>,
    pub map_resolutions: Vec<u32>,
    pub tiles: Vec<u32>,
    /// (resolution, map resolution, tile, lights) of the headline.
    pub headline: (u32, u32, u32, usize),
    pub object: Object,
    pub cpu_runs: usize,
    /// Fetches per invocation of the probe.
    pub probe_fetches: u32,
    /// Texel format of the headline and sweeps (at its default layout).
    pub texture: Texture,
    /// Whether the device may store BC1 (the context has textureCompressionBC): the
    /// headline is then also measured in BC1 (it is always measured in every other format).
    pub bc1_available: bool,
}

impl Default for BtfBenchConfig {
    fn default() -> Self {
        BtfBenchConfig {
            bench: BenchConfig::default(),
            resolutions: vec![256, 512, 1024],
            map_resolutions: vec![32, 128, 512],
            tiles: vec![8, 16, 32],
            headline: (512, 128, 32, 1),
            object: Object::Sphere,
            cpu_runs: 3,
            probe_fetches: 16,
            texture: Texture::Block,
            bc1_available: true,
        }
    }
}

/// One configuration's timing.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub resolution: u32,
    pub map_resolution: u32,
    pub tile: u32,
    pub layout: Layout,
    pub texture: Texture,
    pub lights: usize,
    pub covered_pixels: usize,
    pub gpu_ms: Stats,
    pub fps: f64,
    /// Filtered BTF fetches (taps with non-zero weight) and map texel fetches per frame.
    pub taps_per_frame: u64,
    pub map_fetches_per_frame: u64,
    pub taps_per_second: f64,
    /// taps_per_second / the sustained fetch rate of the probe for this texture: filtered
    /// fetches (rgba8, bc1), or block texel fetches (block: one per tap).
    pub fraction_of_fetch_rate: f64,
    pub texture_bytes: u64,
    pub texture_mib: f64,
    pub packing: Packing,
}

/// What `bench btf` writes.
#[derive(Clone, Debug, Serialize)]
pub struct BtfBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: BtfBenchConfig,
    /// Sustained filtered fetches per second from the rows-layout RGBA8 sRGB array texture
    /// (probe; the reference of rgba8 and bc1 points).
    pub probe_fetches_per_second: f64,
    pub probe_ms: Stats,
    /// Sustained texelFetch of blocks per second from the `block` texture (probe; the
    /// reference of block points).
    pub probe_block_fetches_per_second: f64,
    pub probe_block_ms: Stats,
    pub headline: Point,
    /// The headline configuration in each texel format the device can store (each at its
    /// default layout, 'rows'), measured in this run; the headline's own format first.
    pub formats: Vec<Point>,
    /// The same 9-tap interpolation on the CPU (f64, rayon), headline configuration.
    pub cpu_same_method_ms: Stats,
    pub speedup_vs_cpu: f64,
    pub sweep: Vec<Point>,
    pub targets: Vec<super::ao::TargetCheck>,
    /// The headline against its binding roofline ([`work_model`], rates measured in this
    /// run).
    pub roofline: super::roofline::Roofline,
}

/// The work model of one frame of `p`: texel fetches (the taps with a non-zero weight, as
/// counted on the CPU: the shader issues all 9 per lit pixel and light, ~22% more, so the
/// fraction is a lower bound) at the sampling rate of the texture's format (`block`: one
/// nearest 16-byte texel, rated as nearest RGBA32F; `rgba8` and `bc1`: bilinear, rated as
/// bilinear RGBA8, which flatters BC1's software decode on lavapipe), plus the direction-map
/// fetches and three G-buffer `texelFetch`es per covered pixel (nearest RGBA32F).
pub fn work_model(p: &Point) -> Vec<super::roofline::Term> {
    use super::roofline::Term;
    let nearest = "sample2d_nearest_rgba32f_coherent";
    let taps = match p.texture {
        Texture::Block => nearest,
        _ => "sample2d_bilinear_rgba8_coherent",
    };
    vec![
        Term::new(taps, "BTF taps (non-zero weight)", p.taps_per_frame as f64),
        Term::new(
            nearest,
            "direction-map fetches and G-buffer texelFetch (3 per covered pixel)",
            p.map_fetches_per_frame as f64 + 3.0 * p.covered_pixels as f64,
        ),
    ]
}

/// What the roofline of [`work_model`] covers.
pub const COVERS: &str = "btf shade pass";

/// Texels for timing: hashed bytes (the work does not depend on them).
fn hashed_btf(tile: u32) -> Btf {
    let n = dirs::COUNT * dirs::COUNT * (tile * tile) as usize;
    let mut h = 0x2545_f491_4f6c_dd1du64;
    let texels = (0..n)
        .map(|_| {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            [0, 1, 2].map(|k| ((h >> (8 * k)) & 0xff) as f32 / 255.0)
        })
        .collect();
    Btf {
        size: [tile, tile],
        texels,
    }
}

fn frame(lights: usize) -> Frame {
    let all = crate::scene::gbuffer::default_lights();
    Frame {
        camera: Camera::Perspective(Vec3::from(EYE)),
        lights: all.into_iter().take(lights.max(1)).collect::<Vec<Light>>(),
    }
}

/// Taps (non-zero weight pairs per lit light) and map fetches of one frame.
fn count_work(maps: &Maps, gb: &GBuffer, frame: &Frame) -> (u64, u64) {
    use crate::scene::gbuffer::{frame_of, to_tangent};
    let (mut taps, mut map) = (0u64, 0u64);
    for k in 0..(gb.width * gb.height) as usize {
        let Some(px) = gb.pixel(k) else { continue };
        let tbn = frame_of(&px);
        let v = to_tangent(frame.camera.view(px.position), tbn);
        if v[2] <= 0.0 {
            continue;
        }
        map += 2;
        let wv = maps.lookup(v);
        for l in &frame.lights {
            let lt = to_tangent(l.direction.as_dvec3().normalize(), tbn);
            if lt[2] <= 0.0 {
                continue;
            }
            map += 2;
            let wl = maps.lookup(lt);
            let nv = wv.weight.iter().filter(|w| **w != 0.0).count() as u64;
            let nl = wl.weight.iter().filter(|w| **w != 0.0).count() as u64;
            taps += nv * nl;
        }
    }
    (taps, map)
}

struct Setup {
    maps: Maps,
    gb: GBuffer,
}

#[allow(clippy::too_many_arguments)]
fn measure(
    ctx: &Context,
    cfg: &BtfBenchConfig,
    btf: &Btf,
    setup: &Setup,
    (texture, layout): (Texture, Layout),
    lights: usize,
    probe_rates: (f64, f64),
) -> Result<Point> {
    let probe_rate = match texture {
        Texture::Block => probe_rates.1,
        _ => probe_rates.0,
    };
    let mut rec = ctx.recorder("bench btf setup")?;
    let kernel = BtfKernel::new(
        &mut rec,
        &BtfInputs {
            layout,
            ..BtfInputs::new(btf, &setup.maps, &setup.gb, texture)
        },
    )?;
    rec.submit_and_wait()?;
    let f = frame(lights);
    let gpu_ms = time_passes(ctx, &cfg.bench, &kernel, &f)?.remove(0).1;
    let (taps, map) = count_work(&setup.maps, &setup.gb, &f);
    let taps_per_second = taps as f64 / (gpu_ms.median * 1e-3);
    let texture_bytes = kernel.texture_bytes();
    Ok(Point {
        resolution: setup.gb.width,
        map_resolution: setup.maps.res,
        tile: btf.size[0],
        layout,
        texture,
        lights,
        covered_pixels: setup.gb.covered(),
        fps: 1000.0 / gpu_ms.median,
        gpu_ms,
        taps_per_frame: taps,
        map_fetches_per_frame: map,
        taps_per_second,
        fraction_of_fetch_rate: taps_per_second / probe_rate,
        texture_bytes,
        texture_mib: texture_bytes as f64 / (1u64 << 20) as f64,
        packing: kernel.packing(),
    })
}

/// The fetch probes: sustained filtered fetches per second from a rows-layout RGBA8 texture
/// (`block` false), or texel fetches per second from the rows of blocks (`block` true).
fn probe(ctx: &Context, cfg: &BtfBenchConfig, btf: &Btf, block: bool) -> Result<(f64, Stats)> {
    let l = ctx.limits();
    let texture = if block {
        Texture::Block
    } else {
        Texture::Rgba8
    };
    let p = Packing::for_format(
        Layout::Rows,
        texture,
        btf.size,
        l.max_image_dimension_2d,
        l.max_image_array_layers,
        None,
    )?;
    let format = if block { texture.format() } else { FORMAT };
    let desc = ImageDesc::d2_array(format, p.layer_extent, p.layers(0));
    let img = Image::new(ctx, "bench btf probe texture", desc)?;
    let sampler = Sampler::new(
        ctx,
        "bench btf probe sampler",
        SamplerDesc::linear()
            .address(ash::vk::SamplerAddressMode::REPEAT)
            .lod(0.0, 0.0),
    )?;
    let size = cfg.headline.0;
    let out = Buffer::new(
        ctx,
        "bench btf probe out",
        BufferDesc::storage(size as u64 * size as u64 * 16),
    )?;
    let name = if block {
        "btf/fetch_block"
    } else {
        "btf/fetch"
    };
    let pipeline = crate::shaders::pipeline(ctx, name)?;
    let mut res = vec![
        ("tex", Resource::texture(&img)),
        ("result", Resource::Buffer(&out)),
    ];
    if !block {
        res.push(("smp", Resource::Sampler(&sampler)));
    }
    let bind =
        pipeline.bind_declared(&res, &[("result", AccessSet::from(A::ComputeShaderWrite))])?;
    let mut rec = ctx.recorder("bench btf probe upload")?;
    rec.upload_image(&img, ImageRegion::whole(&desc), &p.upload_bytes(btf))?;
    rec.submit_and_wait()?;
    let fetches = cfg.probe_fetches;
    let mut push: Vec<u8> = [size, size, fetches, p.layers(0)]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    // About 8 pixels per texel, as the sphere shows the tile (blocks: 3 texels each, and
    // the probe's coordinates span the whole layer of 81 images).
    let s = if block {
        1.0 / (8.0 * 3.0 * p.layer_extent[0] as f32)
    } else {
        1.0 / (8.0 * btf.size[0] as f32)
    };
    for v in [s, s, 0.0, 0.0] {
        push.extend_from_slice(&v.to_le_bytes());
    }
    let pass = if block {
        "btf block fetch probe"
    } else {
        "btf fetch probe"
    };
    let stats = time_gpu(ctx, &cfg.bench, pass, |rec| {
        rec.begin_pass(pass);
        let r = rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [size, size, 1]);
        rec.end_pass();
        r
    })?;
    let rate = (size as f64 * size as f64 * fetches as f64) / (stats.median * 1e-3);
    Ok((rate, stats))
}

/// Runs the benchmark.
pub fn run(
    ctx: &Context,
    cfg: &BtfBenchConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<BtfBenchReport> {
    let (res, map_res, tile, lights) = cfg.headline;
    if cfg.resolutions.is_empty() || cfg.map_resolutions.is_empty() || cfg.tiles.is_empty() {
        return Err(Error::InvalidArgument("bench btf: empty sweep".into()));
    }
    let tri = Triangulation::new()?;
    let setup = |r: u32, m: u32| -> Result<Setup> {
        Ok(Setup {
            maps: Maps::build(&tri, m)?,
            gb: render_object(cfg.object, r, r)?,
        })
    };
    let head_btf = hashed_btf(tile);
    let (probe_rate, probe_ms) = probe(ctx, cfg, &head_btf, false)?;
    progress(&format!(
        "fetch probe: {:.1} M filtered fetches/s ({:.2} ms)",
        probe_rate / 1e6,
        probe_ms.median
    ));
    let (probe_block_rate, probe_block_ms) = probe(ctx, cfg, &head_btf, true)?;
    progress(&format!(
        "block fetch probe: {:.1} M block fetches/s ({:.2} ms)",
        probe_block_rate / 1e6,
        probe_block_ms.median
    ));
    let probe_rates = (probe_rate, probe_block_rate);
    let head_setup = setup(res, map_res)?;
    let fmt = (cfg.texture, cfg.texture.default_layout());
    let headline = measure(ctx, cfg, &head_btf, &head_setup, fmt, lights, probe_rates)?;
    let mut formats = vec![headline.clone()];
    for other in [Texture::Block, Texture::Bc1, Texture::Rgba8] {
        if other == cfg.texture || (other == Texture::Bc1 && !cfg.bc1_available) {
            continue;
        }
        let p = measure(
            ctx,
            cfg,
            &head_btf,
            &head_setup,
            (other, other.default_layout()),
            lights,
            probe_rates,
        )?;
        progress(&format!(
            "headline in {other:?}: {:.2} ms = {:.1} fps, {:.2} MiB",
            p.gpu_ms.median, p.fps, p.texture_mib
        ));
        formats.push(p);
    }
    progress(&format!(
        "headline {res}^2, map {map_res}, tile {tile}, {lights} light(s): {:.2} ms = {:.1} fps",
        headline.gpu_ms.median, headline.fps
    ));
    let mut sweep = Vec::new();
    let mut push = |p: Point, progress: &mut dyn FnMut(&str)| {
        progress(&format!(
            "{}^2 map {} tile {} {:?} {} light(s): {:.2} ms, {:.1}% of the probe's fetch rate",
            p.resolution,
            p.map_resolution,
            p.tile,
            p.layout,
            p.lights,
            p.gpu_ms.median,
            100.0 * p.fraction_of_fetch_rate
        ));
        sweep.push(p);
    };
    for &r in &cfg.resolutions {
        let s = setup(r, map_res)?;
        push(
            measure(ctx, cfg, &head_btf, &s, fmt, lights, probe_rates)?,
            progress,
        );
    }
    for &m in &cfg.map_resolutions {
        let s = setup(res, m)?;
        push(
            measure(ctx, cfg, &head_btf, &s, fmt, lights, probe_rates)?,
            progress,
        );
    }
    for &t in &cfg.tiles {
        let b = hashed_btf(t);
        push(
            measure(ctx, cfg, &b, &head_setup, fmt, lights, probe_rates)?,
            progress,
        );
    }
    push(
        measure(
            ctx,
            cfg,
            &head_btf,
            &head_setup,
            (
                Texture::Rgba8,
                match fmt.1 {
                    Layout::Rows => Layout::Layers,
                    Layout::Layers => Layout::Rows,
                },
            ),
            lights,
            probe_rates,
        )?,
        progress,
    );
    push(
        measure(ctx, cfg, &head_btf, &head_setup, fmt, 2, probe_rates)?,
        progress,
    );

    let sampled = Sampled::of(&head_btf, cfg.texture);
    let f = frame(lights);
    let cpu_ms = time_cpu(cfg.cpu_runs, || {
        cpu::shade(
            &sampled.packed(head_btf.size),
            &head_setup.maps,
            &head_setup.gb,
            &f,
        )
    });
    progress(&format!("CPU interpolation: {:.1} ms", cpu_ms.median));
    let targets_json: serde_json::Value = serde_json::from_str(super::ao::TARGETS)
        .map_err(|e| Error::InvalidArgument(format!("bench/targets.json: {e}")))?;
    let t = &targets_json["btf"];
    let check = super::ao::TargetCheck::of;
    let targets = [
        check(
            "fps (512 x 512 sphere, 1 light, 32 x 32 tile, map 128)",
            t["fps_min"].as_f64(),
            headline.fps,
            true,
        ),
        check(
            "texture memory of the packed BTF, 32 x 32 tile (MiB)",
            t["texture_mib_max"].as_f64(),
            headline.texture_mib,
            false,
        ),
    ]
    .into_iter()
    .flatten()
    .collect();
    let terms = work_model(&headline);
    progress("rates of the work model (probes)");
    let rates = super::roofline::measure_rates(ctx, &cfg.bench, &terms, None)?;
    let roofline =
        super::roofline::Roofline::evaluate(COVERS, terms, headline.gpu_ms.median, &rates);
    Ok(BtfBenchReport {
        roofline,
        benchmark: "btf",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        probe_fetches_per_second: probe_rate,
        probe_ms,
        probe_block_fetches_per_second: probe_block_rate,
        probe_block_ms,
        speedup_vs_cpu: cpu_ms.median / headline.gpu_ms.median,
        headline,
        formats,
        cpu_same_method_ms: cpu_ms,
        sweep,
        targets,
    })
}

/// `bench all`'s BTF: maps, G-buffer and hashed texels once, then the headline (and the CPU
/// interpolation) once per round.
pub struct AllBench<'a> {
    ctx: &'a Context,
    cfg: &'a BtfBenchConfig,
    btf: Btf,
    setup: Setup,
    sampled: Sampled,
    fps_min: Option<f64>,
}

impl<'a> AllBench<'a> {
    pub fn new(ctx: &'a Context, cfg: &'a BtfBenchConfig) -> Result<AllBench<'a>> {
        let targets: serde_json::Value = serde_json::from_str(super::ao::TARGETS)
            .map_err(|e| Error::InvalidArgument(format!("bench/targets.json: {e}")))?;
        let (res, map_res, tile, _) = cfg.headline;
        let tri = Triangulation::new()?;
        let setup = Setup {
            maps: Maps::build(&tri, map_res)?,
            gb: render_object(cfg.object, res, res)?,
        };
        let btf = hashed_btf(tile);
        let sampled = Sampled::of(&btf, cfg.texture);
        Ok(AllBench {
            ctx,
            cfg,
            btf,
            setup,
            sampled,
            fps_min: targets["btf"]["fps_min"].as_f64(),
        })
    }

    /// One round: the headline's GPU time and work model, the CPU twin's wall time.
    pub fn round(&self) -> Result<super::all::Round> {
        let lights = self.cfg.headline.3;
        let fmt = (self.cfg.texture, self.cfg.texture.default_layout());
        let p = measure(
            self.ctx,
            self.cfg,
            &self.btf,
            &self.setup,
            fmt,
            lights,
            (f64::NAN, f64::NAN),
        )?;
        let f = frame(lights);
        let cpu_ms = time_cpu(1, || {
            cpu::shade(
                &self.sampled.packed(self.btf.size),
                &self.setup.maps,
                &self.setup.gb,
                &f,
            )
        });
        Ok(super::all::Round {
            kernel: "btf",
            headline: format!(
                "{}^2 sphere, tile {}, map {}, {} light(s), {}",
                p.resolution,
                p.tile,
                p.map_resolution,
                p.lights,
                format!("{:?}", p.texture).to_lowercase()
            ),
            gpu_ms: p.gpu_ms.median,
            within_iqr_rel: p.gpu_ms.iqr_rel,
            terms: work_model(&p),
            covers: COVERS,
            covered_ms: p.gpu_ms.median,
            cpu_ms: cpu_ms.median,
            target_fps: self.fps_min,
        })
    }
}

/// A cloth garment in motion, all on the GPU per frame: the pose kernel skins the chosen
/// parts with the frame's joint matrices, the rasteriser writes their G-buffer from the
/// posed buffers, and the BTF pass shades that G-buffer (barriers from the three kernels'
/// declared accesses; nothing crosses to the host inside a frame). `btf render --anim` and
/// `bench btf --anim` drive it.
pub struct Garment {
    /// The character (its mesh: the chosen parts joined, `scene::gltf_load::load_parts`).
    pub character: crate::scene::Character,
    /// Part index of every triangle.
    pub parts: Vec<u32>,
    anim: usize,
    /// The camera (fixed, framing the garment over the whole animation).
    pub camera: crate::kernels::raster::pack::Camera,
    /// The BTF pass's frame: the camera position and the lights.
    pub frame: Frame,
    pose: crate::kernels::pose::PoseKernel,
    raster: crate::kernels::raster::gpu::RasterKernel,
    btf: BtfKernel,
    /// The lobes `btf env` reads (with `GarmentConfig::env_lobes`).
    _env_lobes: Option<Buffer>,
}

/// What a [`Garment`] is built from.
#[derive(Clone, Debug, Serialize)]
pub struct GarmentConfig {
    /// The glTF character.
    pub mesh: std::path::PathBuf,
    /// Its mesh parts to cover with cloth (node or mesh names).
    pub parts: Vec<String>,
    /// The animation.
    pub anim: String,
    /// Image width and height.
    pub size: [u32; 2],
    /// BTF tile repeats per unit of the mesh's uv.
    pub tile_scale: f32,
    /// Direction map resolution.
    pub map_res: u32,
    /// Texel format of the BTF.
    pub texture: Texture,
    /// How the BTF's images are packed into array textures (`Texture::default_layout`
    /// unless asked; 'layers' shades through `btf/shade_layers_pixels`).
    pub layout: Layout,
    /// Lights (1..=2).
    #[serde(skip)]
    pub lights: Vec<Light>,
    /// Resolve and shade over the rasteriser's tile list (false: every pixel, the path
    /// before the tile list; `bench btf --anim` times it in the same run).
    pub tiles: bool,
    /// SG environment lobes (world space, already rotated) lighting the cloth too through
    /// the pass `btf env` (every pixel); empty: none.
    #[serde(skip)]
    pub env_lobes: Vec<crate::geom::sg::Lobe>,
}

/// Labels of a garment frame's passes, in order.
pub fn garment_passes() -> Vec<&'static str> {
    use crate::kernels::{pose::gpu as p, raster::gpu as r};
    vec![
        p::PASS_JOINTS,
        p::PASS_SKIN,
        r::PASS_CLEAR,
        r::PASS_VISIBILITY,
        r::PASS_TILES,
        r::PASS_RESOLVE,
        crate::kernels::btf::gpu::PASS_SHADE,
    ]
}

impl Garment {
    /// Loads the parts, frames the camera on the garment's bounds over 16 poses of the
    /// animation (CPU, once), creates the three kernels and uploads their static data
    /// (submitted and waited for here).
    pub fn new(ctx: &Context, cfg: &GarmentConfig, btf: &Btf, maps: &Maps) -> Result<Garment> {
        use crate::kernels::raster::gpu::{Posed, Prepared as RasterPrep, RasterKernel};
        use crate::kernels::{pose, raster};
        let names: Vec<&str> = cfg.parts.iter().map(String::as_str).collect();
        let (character, parts) = crate::frame::load_parts(&cfg.mesh, &names)?;
        let anim = crate::frame::animation_index(&character, &cfg.anim, &cfg.mesh)?;
        let joints = character.rig.joints.len();
        let pose_prep = pose::Prepared::new(&character.mesh, joints)?;
        // Bounds over the animation, so the fixed camera keeps the garment in view.
        let (lo, hi) = crate::frame::animation_bounds(&character, &pose_prep, anim)?;
        let camera = raster::pack::Camera::framing(
            (lo + hi) * 0.5,
            (hi - lo).length() * 0.5,
            Vec3::new(0.25, 0.15, 1.0),
        );
        let frame = Frame {
            camera: Camera::Perspective(camera.eye),
            lights: cfg.lights.clone(),
        };
        frame.check()?;
        raster::gpu::check_device(ctx)?;
        let mut rec = ctx.recorder("garment setup")?;
        let pose = pose::PoseKernel::new(&mut rec, &pose_prep)?;
        let rprep = RasterPrep::new(&character.mesh, &parts, cfg.size, cfg.tile_scale)?;
        let posed = Posed {
            positions: pose.positions(),
            normals: pose.normals(),
            tangents: pose.tangents(),
        };
        let tiling = if cfg.tiles {
            raster::gpu::Tiling::Tiles
        } else {
            raster::gpu::Tiling::Full
        };
        let raster = RasterKernel::with_tiling(&mut rec, &rprep, &posed, tiling)?;
        let l = ctx.limits();
        let unused = GBuffer::tile([1, 1]);
        let inputs = BtfInputs {
            layout: cfg.layout,
            ..BtfInputs::new(btf, maps, &unused, cfg.texture)
        };
        let bprep = crate::kernels::btf::gpu::Prepared::for_gpu_gbuffer(
            &inputs,
            cfg.size,
            l.max_image_dimension_2d,
            l.max_image_array_layers,
        )?;
        // Shaded over the rasteriser's tile list: only where the garment is (or was last
        // frame), one workgroup per listed tile.
        let (btf, env_lobes) = match (raster.tiles(), cfg.env_lobes.is_empty()) {
            (Some(tiles), true) => (
                BtfKernel::on_gbuffer_tiles(&mut rec, &bprep, raster.gbuffer(), tiles)?,
                None,
            ),
            (None, true) => (
                BtfKernel::on_gbuffer(&mut rec, &bprep, raster.gbuffer())?,
                None,
            ),
            (_, false) => {
                // The environment pass runs over every pixel (it has no tile list yet).
                let texels = crate::kernels::btf::env::lobe_texels(&cfg.env_lobes);
                let buf = rec.buffer_with(
                    "garment env lobes",
                    BufferDesc::storage(16 * texels.len() as u64),
                    &texels,
                )?;
                let env = crate::kernels::btf::gpu::EnvInputs {
                    lobes: &buf,
                    lobe_count: cfg.env_lobes.len() as u32,
                    visibility: None,
                };
                let k = BtfKernel::on_gbuffer_env(&mut rec, &bprep, raster.gbuffer(), env)?;
                (k, Some(buf))
            }
        };
        rec.submit_and_wait()?;
        Ok(Garment {
            character,
            parts,
            anim,
            camera,
            frame,
            pose,
            raster,
            btf,
            _env_lobes: env_lobes,
        })
    }

    /// The animation played.
    pub fn animation(&self) -> &crate::scene::Animation {
        &self.character.animations[self.anim]
    }

    /// The skinning matrices at `time` seconds (wrapped into the animation).
    pub fn matrices(&self, time: f32) -> Vec<glam::Mat4> {
        crate::frame::looped_matrices(&self.character, self.anim, time)
    }

    /// Records one frame: skinning, rasterisation, BTF shading.
    pub fn record(&self, rec: &mut crate::gpu::Recorder, matrices: &[glam::Mat4]) -> Result<()> {
        use crate::kernels::Kernel;
        self.pose.record(rec, matrices)?;
        self.raster.record(rec, &self.camera)?;
        self.btf.record(rec, &self.frame)
    }

    /// The shaded image's readback (linear RGBA per pixel; alpha 0 where empty).
    pub fn read_back(&self, rec: &mut crate::gpu::Recorder) -> Result<crate::gpu::Readback> {
        use crate::kernels::Kernel;
        self.btf.read_back(rec)
    }

    /// Triangles and vertices posed and rasterised per frame.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.character.mesh.triangles.len(),
            self.character.mesh.positions.len(),
        )
    }

    /// Labels of its frame's passes, in order ([`garment_passes`] without `raster tiles`
    /// when the garment is shaded over every pixel).
    pub fn passes(&self) -> Vec<&'static str> {
        let mut names = garment_passes();
        if self.raster.tiles().is_none() {
            names.retain(|n| *n != crate::kernels::raster::gpu::PASS_TILES);
        }
        if self.btf.env_lobes().is_some() {
            names.push(crate::kernels::btf::gpu::PASS_ENV);
        }
        names
    }

    /// The rasteriser writing the garment's G-buffer and tile list.
    pub fn raster(&self) -> &crate::kernels::raster::gpu::RasterKernel {
        &self.raster
    }

    /// Device memory of the three kernels.
    pub fn memory_bytes(&self) -> u64 {
        use crate::kernels::Kernel;
        self.pose.memory().used_bytes
            + self.raster.memory().used_bytes
            + self.btf.memory().used_bytes
    }
}

/// What `bench btf --anim` writes.
#[derive(Clone, Debug, Serialize)]
pub struct AnimBenchReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: GarmentConfig,
    pub bench: BenchConfig,
    pub triangles: usize,
    pub vertices: usize,
    /// Median GPU ms of each pass over the timed frames (poses spread over the animation).
    pub pass_ms: Vec<(&'static str, Stats)>,
    /// Median GPU ms of a whole frame (sum of its passes per frame).
    pub frame_gpu_ms: Stats,
    /// 1000 / frame_gpu_ms.median.
    pub fps_gpu: f64,
    /// Frames per second of wall clock with two frames in flight and no readback.
    pub fps_wall: f64,
    /// Host ms per frame outside waiting: joint matrices + recording + submit.
    pub host_ms: Stats,
    /// Each pass's share of the frame's GPU time (same run).
    pub pass_share: Vec<(&'static str, f64)>,
    pub memory_mib: f64,
    /// Pixels the garment covers at the animation's start.
    pub covered_pixels: usize,
    /// 16 x 4 tiles holding a covered pixel then, and tiles listed in all (those plus the
    /// tiles covered only the frame before): the workgroups of `raster resolve` and
    /// `btf shade`.
    pub covered_tiles: usize,
    pub listed_tiles: usize,
    /// Same run: `btf shade` alone on the static sphere (same size, texture, lights).
    pub sphere_covered_pixels: usize,
    pub sphere_btf_ms: Stats,
    /// CPU ms of the whole process per frame over the wall-clock frames (lavapipe's
    /// workers included: on a CPU device, the frame's work in CPU time, which other
    /// processes' load changes less than wall time); None where /proc is not readable.
    pub cpu_ms_per_frame: Option<f64>,
    /// Same run, the frame over every pixel (no tile list; GPU ms per pass, wall fps and
    /// CPU ms per frame), when measured.
    pub every_pixel: Option<EveryPixel>,
    pub targets: Vec<super::ao::TargetCheck>,
}

/// The every-pixel frame of `bench btf --anim`, timed in the same run.
#[derive(Clone, Debug, Serialize)]
pub struct EveryPixel {
    /// Median GPU ms of each pass.
    pub pass_ms: Vec<(&'static str, Stats)>,
    /// Median GPU ms of a whole frame.
    pub frame_gpu_ms: Stats,
    /// Frames per second of wall clock with two frames in flight and no readback.
    pub fps_wall: f64,
    /// CPU ms of the process per frame over those frames.
    pub cpu_ms_per_frame: Option<f64>,
}

/// CPU seconds (user + system, all threads) this process has used, from /proc/self/stat.
fn process_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces) end with ')'.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // The kernel reports in USER_HZ, 100 on Linux.
    Some(ticks / 100.0)
}

/// Times `g`'s frames: per-pass GPU ms over `bench.warmup + bench.samples` poses, then the
/// wall-clock fps and process CPU ms per frame with two frames in flight.
type FrameTimes = (Vec<Vec<f64>>, Vec<f64>, Vec<f64>, f64, Option<f64>);

fn time_garment(ctx: &Context, g: &Garment, bench: &BenchConfig) -> Result<FrameTimes> {
    let names = g.passes();
    let n = bench.warmup + bench.samples.max(1);
    let duration = g.animation().duration;
    let mut samples = vec![Vec::new(); names.len()];
    let (mut frame_ms, mut host_ms) = (Vec::new(), Vec::new());
    for i in 0..n {
        let t0 = Instant::now();
        let m = g.matrices(duration * i as f32 / n as f32);
        let mut rec = ctx.recorder("garment frame")?;
        g.record(&mut rec, &m)?;
        let sub = rec.submit()?;
        let host = t0.elapsed().as_secs_f64() * 1e3;
        let t = sub.wait()?;
        if i < bench.warmup {
            continue;
        }
        host_ms.push(host);
        let mut sum = 0.0;
        for (name, s) in names.iter().zip(samples.iter_mut()) {
            let ms = t
                .get(name)
                .ok_or_else(|| Error::InvalidArgument(format!("pass '{name}' was not timed")))?;
            sum += ms;
            s.push(ms);
        }
        frame_ms.push(sum);
    }
    // Wall clock: two frames in flight, no readback (the figure a renderer would see).
    let frames = bench.samples.max(10);
    let cpu0 = process_cpu_s();
    let t0 = Instant::now();
    let mut pending = std::collections::VecDeque::new();
    for i in 0..frames {
        let m = g.matrices(duration * i as f32 / frames as f32);
        let mut rec = ctx.recorder("garment frame")?;
        g.record(&mut rec, &m)?;
        pending.push_back(rec.submit()?);
        if pending.len() >= 2
            && let Some(s) = pending.pop_front()
        {
            s.wait()?;
        }
    }
    while let Some(s) = pending.pop_front() {
        s.wait()?;
    }
    let fps_wall = frames as f64 / t0.elapsed().as_secs_f64();
    let cpu = match (cpu0, process_cpu_s()) {
        (Some(a), Some(b)) => Some((b - a) * 1e3 / frames as f64),
        _ => None,
    };
    Ok((samples, frame_ms, host_ms, fps_wall, cpu))
}

/// `bench btf --anim`: skinning + G-buffer + BTF of the garment per frame, timed over poses
/// spread across the animation (hashed BTF texels: the work does not depend on them).
pub fn run_anim(
    ctx: &Context,
    cfg: &GarmentConfig,
    bench: &BenchConfig,
    tile: u32,
    progress: &mut dyn FnMut(&str),
) -> Result<AnimBenchReport> {
    let btf = hashed_btf(tile);
    let maps = Maps::build(&Triangulation::new()?, cfg.map_res)?;
    let g = Garment::new(ctx, cfg, &btf, &maps)?;
    let (triangles, vertices) = g.counts();
    progress(&format!(
        "{}: {triangles} triangles, {vertices} vertices at {} x {}",
        cfg.parts.join("+"),
        cfg.size[0],
        cfg.size[1]
    ));
    let names = g.passes();
    let (samples, frame_ms, host_ms, fps_wall, cpu_ms_per_frame) = time_garment(ctx, &g, bench)?;
    // Same run: `btf shade` alone on the static sphere at the same size, texture and lights
    // (the reference the static bench's fps is for).
    let sphere = render_object(Object::Sphere, cfg.size[0], cfg.size[1])?;
    let mut rec = ctx.recorder("bench btf sphere setup")?;
    let k = BtfKernel::new(&mut rec, &BtfInputs::new(&btf, &maps, &sphere, cfg.texture))?;
    rec.submit_and_wait()?;
    let f = Frame {
        camera: Camera::Perspective(Vec3::from(EYE)),
        lights: cfg.lights.clone(),
    };
    let sphere_btf_ms = time_passes(ctx, bench, &k, &f)?.remove(0).1;
    drop(k);
    let (covered, covered_tiles, listed_tiles) = {
        use crate::kernels::Kernel;
        let mut rec = ctx.recorder("garment coverage")?;
        g.record(&mut rec, &g.matrices(0.0))?;
        let rb = g.read_back(&mut rec)?;
        let raster = g.raster().read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let covered = rb
            .to_vec::<[f32; 4]>()?
            .iter()
            .filter(|p| p[3] > 0.0)
            .count();
        let tiles = g.raster().collect(&raster)?.tiles;
        let (c, s) = tiles.map_or((0, 0), |t| (t.covered.len(), t.stale.len()));
        (covered, c, c + s)
    };
    let stats = |s: &[f64]| Stats::of(s).ok_or_else(|| Error::InvalidArgument("no samples".into()));
    // Same run: the frame over every pixel (the path before the tile list).
    let every_pixel = if cfg.tiles {
        progress("the same frame over every pixel (same run)");
        let full_cfg = GarmentConfig {
            tiles: false,
            ..cfg.clone()
        };
        let full = Garment::new(ctx, &full_cfg, &btf, &maps)?;
        let (samples, frame_ms, _, fps_wall, cpu_ms_per_frame) = time_garment(ctx, &full, bench)?;
        let pass_ms = full
            .passes()
            .into_iter()
            .zip(&samples)
            .map(|(n, s)| Ok((n, stats(s)?)))
            .collect::<Result<_>>()?;
        Some(EveryPixel {
            pass_ms,
            frame_gpu_ms: stats(&frame_ms)?,
            fps_wall,
            cpu_ms_per_frame,
        })
    } else {
        None
    };
    let pass_ms: Vec<(&'static str, Stats)> = names
        .iter()
        .zip(&samples)
        .map(|(n, s)| Ok((*n, stats(s)?)))
        .collect::<Result<_>>()?;
    let frame_gpu_ms = stats(&frame_ms)?;
    let fps_gpu = 1000.0 / frame_gpu_ms.median;
    let pass_share = pass_ms
        .iter()
        .map(|(n, s)| (*n, s.median / frame_gpu_ms.median))
        .collect();
    let targets = [super::ao::TargetCheck::of(
        "fps (issue 17: skinning + G-buffer 512 x 512 + BTF on Torso and Legs)",
        Some(60.0),
        fps_wall,
        true,
    )]
    .into_iter()
    .flatten()
    .collect();
    Ok(AnimBenchReport {
        benchmark: "btf --anim",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        bench: bench.clone(),
        triangles,
        vertices,
        pass_ms,
        frame_gpu_ms,
        fps_gpu,
        fps_wall,
        host_ms: stats(&host_ms)?,
        pass_share,
        memory_mib: g.memory_bytes() as f64 / (1u64 << 20) as f64,
        covered_pixels: covered,
        covered_tiles,
        listed_tiles,
        sphere_covered_pixels: sphere.covered(),
        sphere_btf_ms,
        cpu_ms_per_frame,
        every_pixel,
        targets,
    })
}
