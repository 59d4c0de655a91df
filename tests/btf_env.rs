//! Cloth under the SG environment (`btf env`): the GPU pass against its CPU twin, and the
//! whole method against the BTF's own quadrature of the rotated, unfitted map (ground
//! truth (1) of the shared notes) on Blender's forest light. Every GPU test runs under
//! validation.

mod common;

use common::with_gpu;
use glam::Vec3;
use std::sync::OnceLock;
use vkshade::geom::sg::{Lobe, fibonacci_sphere, rotation};
use vkshade::gpu::{Buffer, BufferDesc, Context};
use vkshade::kernels::Kernel;
use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
use vkshade::kernels::btf::cpu;
use vkshade::kernels::btf::dirs::{Maps, Triangulation};
use vkshade::kernels::btf::env::{self, lobe_texels};
use vkshade::kernels::btf::gpu::{
    BtfInputs, BtfKernel, EnvInputs, GPU_CPU_BOUND_BLOCK, Prepared, Sampled, Texture,
};
use vkshade::kernels::btf::synth::{Btf, synthesize};
use vkshade::scene::envmap::EnvMap;
use vkshade::scene::gbuffer::{Camera, EYE, Frame, GBuffer, Light, Object, render_object};

fn weave() -> &'static Btf {
    static B: OnceLock<Btf> = OnceLock::new();
    B.get_or_init(|| synthesize(&SynthConfig::tile(Pattern::Weave, 8)).unwrap())
}

fn maps() -> Maps {
    Maps::build(&Triangulation::new().unwrap(), 32).unwrap()
}

fn frame(lights: bool) -> Frame {
    let rgb = if lights { [1.0, 0.95, 0.9] } else { [0.0; 3] };
    Frame {
        camera: Camera::Perspective(Vec3::from(EYE)),
        lights: vec![Light {
            direction: Vec3::new(0.5, 0.8, 0.6),
            rgb,
        }],
    }
}

/// Runs `btf shade` + `btf env` once (G-buffer uploaded) and returns the result.
fn run(
    ctx: &Context,
    prep: &Prepared,
    lobes: &[[f32; 4]],
    visibility: Option<&[f32]>,
    frame: &Frame,
) -> vkshade::Result<Vec<[f32; 4]>> {
    let mut rec = ctx.recorder("btf env test")?;
    let buf =
        |rec: &mut vkshade::gpu::Recorder, name: &str, data: &[f32]| -> vkshade::Result<Buffer> {
            rec.buffer_with(name, BufferDesc::storage(4 * data.len() as u64), data)
        };
    let flat: Vec<f32> = lobes.iter().flatten().copied().collect();
    let lobe_buf = buf(&mut rec, "lobes", &flat)?;
    let vis_buf = visibility
        .map(|v| buf(&mut rec, "visibility", v))
        .transpose()?;
    let k = BtfKernel::from_prepared_env(
        &mut rec,
        prep,
        EnvInputs {
            lobes: &lobe_buf,
            lobe_count: (lobes.len() / 2) as u32,
            visibility: vis_buf.as_ref(),
        },
    )?;
    assert_eq!(k.env_lobes(), Some((lobes.len() / 2) as u32));
    k.record(&mut rec, frame)?;
    let rb = k.read_back(&mut rec)?;
    rec.submit_and_wait()?;
    k.collect(&rb)
}

fn prepared(ctx: &Context, gbuffer: &GBuffer, texture: Texture) -> vkshade::Result<Prepared> {
    let l = ctx.limits();
    let maps = maps();
    Prepared::new(
        &BtfInputs::new(weave(), &maps, gbuffer, texture),
        l.max_image_dimension_2d,
        l.max_image_array_layers,
    )
}

/// Lobes of every regime: broad (midpoint rule), splatted, a sun.
fn test_lobes() -> Vec<Lobe> {
    let sharp = [1.5f32, 6.0, 20.0, 40.0, 150.0, 900.0, 2600.0];
    fibonacci_sphere(sharp.len())
        .into_iter()
        .zip(sharp)
        .enumerate()
        .map(|(i, (axis, s))| {
            let e = sg_integral(s);
            // Comparable energy per lobe (amplitude x integral ~ 1..2).
            let a = (1.0 + 0.15 * i as f32) / e;
            Lobe::new(axis, s, [a, 0.8 * a, 0.6 * a])
        })
        .collect()
}

fn sg_integral(s: f32) -> f32 {
    vkshade::geom::sg::integral(s as f64) as f32
}

#[test]
fn gpu_matches_the_cpu_twin() {
    let btf = weave();
    let maps = maps();
    let gbuffer = render_object(Object::Sphere, 48, 40).unwrap();
    let lobes = lobe_texels(&test_lobes());
    let j = lobes.len() / 2;
    let n = (gbuffer.width * gbuffer.height) as usize;
    // A per-pixel, per-lobe visibility in [0, 1] (a fixed hash).
    let vis: Vec<f32> = (0..n * j)
        .map(|q| ((q as u32).wrapping_mul(2654435761) >> 8) as f32 / (1u32 << 24) as f32)
        .collect();
    let frame = frame(true);
    for (texture, visibility) in [
        (Texture::Block, None),
        (Texture::Block, Some(&vis[..])),
        (Texture::Rgba8, Some(&vis[..])),
    ] {
        let out = with_gpu(|ctx| {
            let prep = prepared(ctx, &gbuffer, texture)?;
            run(ctx, &prep, &lobes, visibility, &frame)
        });
        let sampled = Sampled::of(btf, texture);
        let packed = sampled.packed(btf.size);
        let (direct, amb1) = cpu::shade(&packed, &maps, &gbuffer, &frame);
        let (envc, amb2) = env::shade(&packed, &maps, &gbuffer, &frame.camera, &lobes, visibility);
        let cells = env::cell_texels();
        let (mut max_rel, mut compared, mut lit) = (0f64, 0usize, 0usize);
        for k in 0..n {
            let (g, d, e) = (out[k], direct[k], envc[k]);
            assert_eq!(g[3] as f64, d[3], "coverage of pixel {k}");
            if amb1[k] || amb2[k] || d[3] == 0.0 {
                continue;
            }
            compared += 1;
            // The light the pixel's taps are weighted by: the directional light (strength
            // <= 1) plus sum_i c_i of the environment (f32 light factors, as the twin).
            let weight = 1.0
                + light_sum(
                    &gbuffer,
                    k,
                    &cells,
                    &lobes,
                    visibility.map(|v| &v[k * j..(k + 1) * j]),
                );
            if e[0] > 0.01 {
                lit += 1;
            }
            for ch in 0..3 {
                let want = d[ch] + e[ch];
                max_rel = max_rel.max((g[ch] as f64 - want).abs() / weight);
            }
        }
        // Ambiguous pixels: a view-map texel border, or one of the splatted lobes' 4 x 96
        // points within CELL_MARGIN of a cell border (about 10% of the pixels).
        assert!(
            compared * 10 > gbuffer.covered() * 8,
            "{compared} of {} compared",
            gbuffer.covered()
        );
        assert!(lit > 300, "{lit} lit by the environment");
        // Per unit of light weight: the texture's own GPU-CPU bound (block: exact decode,
        // f32 weights, 1e-5; RGBA8: the sampler's 8-bit fixed-point bilinear weights, 2^-8,
        // plus the sRGB decode, 1.1e-3), plus the light factors' f32 differences (exp and
        // log within a few ulp on the device: 1e-5 relative, measured below 1e-6).
        let bound = match texture {
            Texture::Block => GPU_CPU_BOUND_BLOCK + 1e-5,
            _ => 2f64.powi(-8) + 1.1e-3 + 1e-5,
        };
        eprintln!(
            "{texture:?} visibility {}: max |GPU - twin| per unit light {max_rel:.2e} (bound {bound:.1e})",
            visibility.is_some()
        );
        assert!(max_rel < bound, "{texture:?}: {max_rel}");
    }
}

/// sum_i |c_i| (all channels' largest) of pixel `k`, as the twin computes the factors.
fn light_sum(
    gb: &GBuffer,
    k: usize,
    cells: &[[f32; 4]],
    lobes: &[[f32; 4]],
    vis: Option<&[f32]>,
) -> f64 {
    let g = &gb.texels[3 * k..3 * k + 3];
    let v = |a: [f32; 4]| Vec3::new(a[0], a[1], a[2]);
    let n = v(g[1]).normalize();
    let t = (v(g[2]) - n * n.dot(v(g[2]))).normalize();
    let b = if g[0][3] < 0.0 { -1.0 } else { 1.0 } * n.cross(t);
    let (c, _) = env::light_factors(cells, lobes, vis, [t, b, n]);
    (0..3)
        .map(|ch| c.iter().map(|x| x[ch].abs() as f64).sum::<f64>())
        .fold(0.0, f64::max)
}

/// The method (32 lobes fitted to the 128 x 64 forest map, turned about +Y and a tilted
/// axis) against ground truth (1), the BTF's own quadrature of the same map turned the same
/// way: relative L2 over the sphere's pixels <= 5% (the target), for the GPU and the
/// twin; a scalar visibility per pixel scales both. (1) vs (2) is printed: the quadrature
/// error of the 81 directions itself.
#[test]
fn cloth_under_the_environment_matches_the_btf_quadrature() {
    use vkshade::kernels::srbf::fit::{FitConfig, fit};
    let env_map = EnvMap::load(std::path::Path::new(vkshade::kernels::srbf::DEFAULT_ENV))
        .unwrap_or_else(|e| {
            panic!("{e}\nThe Blender studio lights come from `apt-get install blender-data` (tools/setup.sh).")
        });
    let small = env_map.downsampled(128).unwrap();
    let fitted = fit(
        &small.samples(),
        &FitConfig {
            lobes: 32,
            ..FitConfig::default()
        },
    )
    .unwrap();
    let btf = weave();
    let maps = maps();
    let gbuffer = render_object(Object::Sphere, 48, 40).unwrap();
    let n = (gbuffer.width * gbuffer.height) as usize;
    let frame = frame(false);
    let sampled = Sampled::of(btf, Texture::Block);
    let packed = sampled.packed(btf.size);
    for (axis, deg, scalar_vis) in [
        (Vec3::Y, 0.0f32, false),
        (Vec3::Y, 70.0, false),
        (Vec3::new(1.0, 1.0, 0.3), 130.0, true),
    ] {
        let r = rotation(axis, deg);
        let rotated: Vec<Lobe> = fitted.lobes.iter().map(|l| l.rotated(r)).collect();
        let lobes = lobe_texels(&rotated);
        let j = rotated.len();
        // A scalar visibility per pixel (every lobe equally), so truth (1) holds it exactly.
        let scalar: Vec<f32> = (0..n)
            .map(|k| 0.3 + 0.7 * ((k * 37 % 101) as f32 / 100.0))
            .collect();
        let per_lobe: Vec<f32> = scalar
            .iter()
            .flat_map(|&v| std::iter::repeat_n(v, j))
            .collect();
        let vis = scalar_vis.then_some(&per_lobe[..]);
        let out = with_gpu(|ctx| {
            let prep = prepared(ctx, &gbuffer, Texture::Block)?;
            run(ctx, &prep, &lobes, vis, &frame)
        });
        let gpu: Vec<[f64; 4]> = out.iter().map(|p| p.map(|x| x as f64)).collect();
        let (twin, _) = env::shade(&packed, &maps, &gbuffer, &frame.camera, &lobes, vis);
        let (t1, t2) = env::truths(
            &packed,
            &maps,
            &gbuffer,
            &frame.camera,
            &small,
            r,
            scalar_vis.then_some(&scalar[..]),
        );
        let (e_gpu, e_twin, e12) = (
            env::rel_l2(&gpu, &t1),
            env::rel_l2(&twin, &t1),
            env::rel_l2(&t1, &t2),
        );
        let e_gpu2 = env::rel_l2(&gpu, &t2);
        eprintln!(
            "rotate {axis:?} {deg} deg, visibility {scalar_vis}: GPU vs (1) {e_gpu:.4}, twin vs (1) {e_twin:.4}, GPU vs (2) {e_gpu2:.4}, (1) vs (2) {e12:.4}"
        );
        assert!(e_gpu <= 0.05, "GPU vs truth (1): {e_gpu}");
        assert!(e_twin <= 0.05, "twin vs truth (1): {e_twin}");
    }
}
