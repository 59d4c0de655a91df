//! Cloth under the SG environment through the BTF's light basis (`btf env basis`,
//! kernels::btf::basis): the method against the exact pass's twin and the BTF's own
//! quadrature of the unfitted rotated map (ground truth (1) of the shared notes), and the
//! GPU pass against its CPU twin under validation.

mod common;

use common::with_gpu;
use glam::Vec3;
use std::sync::OnceLock;
use vkshade::geom::sg::{Lobe, fibonacci_sphere, rotation};
use vkshade::gpu::{Buffer, BufferDesc, Context};
use vkshade::kernels::Kernel;
use vkshade::kernels::btf::basis::{BasisData, LightBasis, RANK, Visibility};
use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
use vkshade::kernels::btf::dirs::{Maps, Triangulation};
use vkshade::kernels::btf::env::{self, lobe_texels, rel_l2};
use vkshade::kernels::btf::gpu::{
    BasisVisibility, BtfInputs, BtfKernel, EnvBasisInputs, Prepared, Sampled, Texture,
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

fn forest() -> &'static EnvMap {
    static M: OnceLock<EnvMap> = OnceLock::new();
    M.get_or_init(|| {
        EnvMap::load(std::path::Path::new(vkshade::kernels::srbf::DEFAULT_ENV)).unwrap_or_else(
            |e| {
                panic!(
                    "{e}\nThe Blender studio lights come from `apt-get install blender-data` \
                     (tools/setup.sh)."
                )
            },
        )
    })
}

/// The forest map at 128 x 64, as the frame's fit samples it.
fn small() -> &'static EnvMap {
    static M: OnceLock<EnvMap> = OnceLock::new();
    M.get_or_init(|| forest().downsampled(128).unwrap())
}

/// The frame's environment: `lobes` SG lobes fitted to [`small`].
fn forest_lobes(lobes: usize) -> Vec<Lobe> {
    use vkshade::kernels::srbf::fit::{FitConfig, fit};
    fit(
        &small().samples(),
        &FitConfig {
            lobes,
            ..FitConfig::default()
        },
    )
    .unwrap()
    .lobes
}

/// The basis keeps most of the weave's energy, and more with rank (the white-light metric).
#[test]
fn the_weave_is_nearly_low_rank_in_light() {
    let mut last = 0.0;
    for rank in [2, 4, 8, 16] {
        let c = LightBasis::fit_rank(weave(), rank).unwrap().captured();
        assert!(c > last, "rank {rank}: {c} <= {last}");
        last = c;
    }
    // Measured 0.990 at rank 8: a basis that missed the leading directions would be far lower.
    let c8 = LightBasis::fit_rank(weave(), 8).unwrap().captured();
    assert!(c8 > 0.98, "{c8}");
    assert!(LightBasis::fit_rank(weave(), 0).is_err());
    assert!(LightBasis::fit_rank(weave(), 82).is_err());
}

/// The method under the forest map fitted with 16 lobes (the frame's default) and 32 (the
/// standalone `btf render --env` default), turned about +Y and a tilted axis, with and
/// without a scalar visibility per pixel, against (a) the exact pass's twin (the same
/// lobes, 81 cell factors per pixel, sRGB-8 BTF: the BTF's own quadrature of the fitted
/// environment) and (b) ground truth (1), the BTF's own quadrature of the unfitted map
/// turned the same way. (a) is what the basis and the table add: measured 1.5-1.8%; 3%
/// leaves room and still fails a basis that lost a leading direction (rank 4 of the white
/// metric: ~9%). (b) is the measure, <= 5%, asserted at 32 lobes: at 16 the SG fit
/// itself errs up to 6.9% against (b) in the tilted case (the exact twin as much as the
/// basis), which is the environment fit's error, not the cloth's; it is printed.
#[test]
fn basis_matches_the_btf_quadrature() {
    let btf = weave();
    let maps = maps();
    let gbuffer = render_object(Object::Sphere, 48, 40).unwrap();
    let n = (gbuffer.width * gbuffer.height) as usize;
    let camera = Camera::Perspective(Vec3::from(EYE));
    let sampled = Sampled::of(btf, Texture::Rgba8);
    let packed = sampled.packed(btf.size);
    for ((axis, deg, scalar_vis), count) in [
        (Vec3::Y, 0.0f32, false),
        (Vec3::Y, 70.0, false),
        (Vec3::new(1.0, 1.0, 0.3), 130.0, true),
    ]
    .into_iter()
    .flat_map(|c| [(c, 16), (c, 32)])
    {
        let fitted = forest_lobes(count);
        let data = BasisData::new(btf, &fitted).unwrap();
        assert!(data.captured > 0.9, "captured {}", data.captured);
        let r = rotation(axis, deg);
        let rotated: Vec<Lobe> = fitted.iter().map(|l| l.rotated(r)).collect();
        let lobes = lobe_texels(&rotated);
        let j = rotated.len();
        let scalar: Vec<f32> = (0..n)
            .map(|k| 0.3 + 0.7 * ((k * 37 % 101) as f32 / 100.0))
            .collect();
        let per_lobe: Vec<f32> = scalar
            .iter()
            .flat_map(|&v| std::iter::repeat_n(v, j))
            .collect();
        let vis = scalar_vis.then_some(&per_lobe[..]);
        let (exact, _) = env::shade(&packed, &maps, &gbuffer, &camera, &lobes, vis);
        let fast = data.shade(
            &maps,
            &gbuffer,
            &camera,
            &lobes,
            vis.map_or(Visibility::None, Visibility::PerPixel),
            u32::MAX,
        );
        let truth = |map: &EnvMap| {
            env::truths(
                &packed,
                &maps,
                &gbuffer,
                &camera,
                map,
                r,
                scalar_vis.then_some(&scalar[..]),
            )
            .0
        };
        let (t1, full) = (truth(small()), truth(forest()));
        let vs_exact = rel_l2(&fast.radiance, &exact);
        let vs_truth = rel_l2(&fast.radiance, &t1);
        eprintln!(
            "{count} lobes, {deg} deg: basis vs exact twin {vs_exact:.4}; vs truth (1) {vs_truth:.4} \
             (exact twin {:.4}); on the full-resolution map {:.4} (exact twin {:.4})",
            rel_l2(&exact, &t1),
            rel_l2(&fast.radiance, &full),
            rel_l2(&exact, &full),
        );
        assert!(
            vs_exact < 0.03,
            "{count} lobes, {deg} deg: basis vs exact {vs_exact}"
        );
        assert!(
            vs_truth < 0.05,
            "{count} lobes, {deg} deg: basis vs truth (1) {vs_truth}"
        );
    }
}

fn prepared(ctx: &Context, gbuffer: &GBuffer) -> vkshade::Result<Prepared> {
    let l = ctx.limits();
    let maps = maps();
    Prepared::new(
        &BtfInputs::new(weave(), &maps, gbuffer, Texture::Rgba8),
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
            let e = vkshade::geom::sg::integral(s as f64) as f32;
            let a = (1.0 + 0.15 * i as f32) / e;
            Lobe::new(axis, s, [a, 0.8 * a, 0.6 * a])
        })
        .collect()
}

/// `btf shade` (lights off) + `btf env basis` on the GPU against the twin, per pixel:
/// |GPU - twin| <= 4 x 2^-b x (the twin's sum of |w L_s B_s|) + 1e-6, b the device's
/// subTexelPrecisionBits: both fetches of a term (lobe table, coefficients) are bilinear
/// with weights rounded to b bits, each off by at most 2^-b x (the largest minus the
/// smallest of its 4 texels) <= 2^-b x 2 |texel| (all values are f16 on both sides, so
/// nothing else differs beyond f32 rounding). A per-pixel visibility, none, and a part mask
/// that excludes the sphere (nothing added) are run.
#[test]
fn gpu_matches_the_cpu_twin() {
    let btf = weave();
    let maps = maps();
    let gbuffer = render_object(Object::Sphere, 48, 40).unwrap();
    let camera = Camera::Perspective(Vec3::from(EYE));
    let frame = Frame {
        camera,
        lights: vec![Light {
            direction: Vec3::new(0.5, 0.8, 0.6),
            rgb: [0.0; 3],
        }],
    };
    let base = test_lobes();
    let data = BasisData::new(btf, &base).unwrap();
    let lobes = lobe_texels(
        &base
            .iter()
            .map(|l| l.rotated(rotation(Vec3::new(0.2, 1.0, 0.1), 40.0)))
            .collect::<Vec<_>>(),
    );
    let j = lobes.len() / 2;
    let n = (gbuffer.width * gbuffer.height) as usize;
    let vis: Vec<f32> = (0..n * j)
        .map(|q| ((q as u32).wrapping_mul(2654435761) >> 8) as f32 / (1u32 << 24) as f32)
        .collect();
    for (visibility, mask) in [(None, u32::MAX), (Some(&vis[..]), u32::MAX), (None, 0u32)] {
        let (out, bits) = with_gpu(|ctx| {
            let prep = prepared(ctx, &gbuffer)?;
            let mut rec = ctx.recorder("btf env basis test")?;
            let buf = |rec: &mut vkshade::gpu::Recorder,
                       name: &str,
                       d: &[f32]|
             -> vkshade::Result<Buffer> {
                rec.buffer_with(name, BufferDesc::storage(4 * d.len() as u64), d)
            };
            let flat: Vec<f32> = lobes.iter().flatten().copied().collect();
            let lobe_buf = buf(&mut rec, "lobes", &flat)?;
            let vis_buf = visibility
                .map(|v| buf(&mut rec, "visibility", v))
                .transpose()?;
            let mut k = BtfKernel::from_prepared(&mut rec, &prep)?;
            k.add_env_basis(
                &mut rec,
                None,
                EnvBasisInputs {
                    lobes: &lobe_buf,
                    data: &data,
                    visibility: vis_buf
                        .as_ref()
                        .map_or(BasisVisibility::None, BasisVisibility::PerPixel),
                    part_mask: mask,
                },
            )?;
            assert_eq!(k.env_basis_lobes(), Some(j as u32));
            k.record(&mut rec, &frame)?;
            let rb = k.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            let bits = common::sub_texel_bits(ctx);
            Ok((k.collect(&rb)?, bits))
        });
        let twin = data.shade(
            &maps,
            &gbuffer,
            &camera,
            &lobes,
            visibility.map_or(Visibility::None, Visibility::PerPixel),
            mask,
        );
        let q = 2f64.powi(-(bits as i32));
        let (mut compared, mut lit, mut worst) = (0usize, 0usize, 0f64);
        for (k, o) in out.iter().enumerate() {
            if twin.ambiguous[k] || gbuffer.texels[3 * k][3].abs() < 0.5 {
                continue;
            }
            compared += 1;
            let t = twin.radiance[k];
            if t[0] > 1e-3 {
                lit += 1;
            }
            let bound = 4.0 * q * twin.scale[k] + 1e-6;
            for ch in 0..3 {
                let d = (o[ch] as f64 - t[ch]).abs();
                worst = worst.max(d / bound);
                assert!(
                    d <= bound,
                    "pixel {k} ch {ch}: GPU {} twin {} (bound {bound:.3e}, mask {mask:#x})",
                    o[ch],
                    t[ch]
                );
            }
        }
        eprintln!(
            "mask {mask:#x}, visibility {}: worst {worst:.4} of the bound, {compared} compared, {lit} lit",
            visibility.is_some()
        );
        assert!(compared * 10 > gbuffer.covered() * 8, "{compared} compared");
        if mask == 0 {
            assert_eq!(lit, 0);
            assert!(
                out.iter()
                    .all(|p| p[0] == 0.0 && p[1] == 0.0 && p[2] == 0.0)
            );
        } else {
            assert!(lit > 300, "{lit} lit by the environment");
        }
    }
    assert_eq!(RANK % 4, 0);
}

/// `BasisVisibility::PerVertexLight`'s `listed` is a GPU-written list the pass is dispatched
/// over indirectly: a buffer without INDIRECT_BUFFER usage, or shorter than the list's head,
/// is refused when the pass is added, naming the buffer.
#[test]
fn a_per_vertex_light_list_without_indirect_usage_is_refused() {
    let gbuffer = render_object(Object::Sphere, 16, 12).unwrap();
    let base = test_lobes();
    let data = BasisData::new(weave(), &base).unwrap();
    let lobes: Vec<f32> = lobe_texels(&base).into_iter().flatten().collect();
    let (px, j, nv) = (16 * 12u64, base.len() as u64, 3u64);
    with_gpu(|ctx| {
        let prep = prepared(ctx, &gbuffer)?;
        let mut rec = ctx.recorder("btf env basis listed check")?;
        let zeros = |rec: &mut vkshade::gpu::Recorder, name: &str, desc: BufferDesc| {
            let words = vec![0u32; (desc.size / 4) as usize];
            rec.buffer_with(name, desc, &words[..])
        };
        let lobe_buf = rec.buffer_with(
            "lobes",
            BufferDesc::storage(4 * lobes.len() as u64),
            &lobes[..],
        )?;
        let keys = zeros(&mut rec, "keys", BufferDesc::storage(8 * px))?;
        let positions = zeros(&mut rec, "positions", BufferDesc::storage(16 * nv))?;
        let triangles = zeros(&mut rec, "triangles", BufferDesc::storage(16))?;
        let visibility = zeros(&mut rec, "visibility", BufferDesc::storage(4 * j * nv))?;
        let normals = zeros(&mut rec, "normals", BufferDesc::storage(16 * nv))?;
        let tangents = zeros(&mut rec, "tangents", BufferDesc::storage(16 * nv))?;
        let plain = zeros(&mut rec, "plain list", BufferDesc::storage(16 + 4 * nv))?;
        let short = zeros(
            &mut rec,
            "short list",
            BufferDesc::storage(8).usage(ash::vk::BufferUsageFlags::INDIRECT_BUFFER),
        )?;
        for (list, name) in [(&plain, "plain list"), (&short, "short list")] {
            let mut k = BtfKernel::from_prepared(&mut rec, &prep)?;
            let e = k
                .add_env_basis(
                    &mut rec,
                    None,
                    EnvBasisInputs {
                        lobes: &lobe_buf,
                        data: &data,
                        visibility: BasisVisibility::PerVertexLight {
                            keys: &keys,
                            positions: &positions,
                            triangles: &triangles,
                            visibility: &visibility,
                            normals: &normals,
                            tangents: &tangents,
                            vertices: &[0, 1, 2],
                            listed: Some(list),
                        },
                        part_mask: u32::MAX,
                    },
                )
                .unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.contains(name) && msg.contains("INDIRECT_BUFFER"),
                "{msg}"
            );
        }
        rec.submit_and_wait()
    });
}
