//! BTF kernel: packing round trip, GPU against the CPU interpolation (f64) and against the
//! direct ray-cast, the loader on good and bad data sets. Small sizes (8 x 8 tiles, 32 x 32
//! maps) keep it fast; every GPU test runs under validation.

mod common;

use common::{error_naming, temp_dir, with_gpu, with_gpu_features};
use glam::Vec3;
use std::sync::OnceLock;
use vkshade::gpu::ImageRegion;
use vkshade::kernels::Kernel;
use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
use vkshade::kernels::btf::dirs::{Maps, Triangulation};
use vkshade::kernels::btf::gpu::{
    BtfInputs, BtfKernel, GPU_CPU_BOUND_BLOCK, Layout, Sampled, Texture, encode_bc1, encode_blocks,
    pack, sampled_texels,
};
use vkshade::kernels::btf::synth::{Btf, FileFormat, synthesize, write_dir};
use vkshade::kernels::btf::{cpu, load};
use vkshade::scene::gbuffer::{Camera, Frame, GBuffer, Light, Object, render_object};

/// An 8 x 8 weave, synthesised once per test binary.
/// Every texture array of `k`, read back and concatenated (submits `rec` and waits).
fn read_back_arrays(mut rec: vkshade::gpu::Recorder, k: &BtfKernel) -> vkshade::Result<Vec<u8>> {
    let rbs: Vec<_> = k
        .arrays()
        .iter()
        .map(|a| rec.read_back_image(a, ImageRegion::whole(a.desc())))
        .collect::<vkshade::Result<_>>()?;
    rec.submit_and_wait()?;
    let mut back = Vec::new();
    for rb in rbs {
        back.extend(rb.bytes()?);
    }
    Ok(back)
}

fn weave() -> &'static (SynthConfig, Btf) {
    static B: OnceLock<(SynthConfig, Btf)> = OnceLock::new();
    B.get_or_init(|| {
        let cfg = SynthConfig::tile(Pattern::Weave, 8);
        let btf = synthesize(&cfg).unwrap();
        (cfg, btf)
    })
}

fn maps() -> Maps {
    Maps::build(&Triangulation::new().unwrap(), 32).unwrap()
}

fn frame() -> Frame {
    Frame {
        camera: Camera::Perspective(Vec3::from(vkshade::scene::gbuffer::EYE)),
        lights: vec![
            Light {
                direction: Vec3::new(0.5, 0.8, 0.6),
                rgb: [1.0, 0.95, 0.9],
            },
            Light {
                direction: Vec3::new(-0.9, 0.1, 0.2),
                rgb: [0.3, 0.35, 0.5],
            },
        ],
    }
}

/// Runs the kernel once and returns its output.
fn run(
    ctx: &vkshade::gpu::Context,
    btf: &Btf,
    maps: &Maps,
    gbuffer: &GBuffer,
    frame: &Frame,
    (texture, layout): (Texture, Layout),
) -> vkshade::Result<Vec<[f32; 4]>> {
    let mut rec = ctx.recorder("btf test")?;
    let k = BtfKernel::new(
        &mut rec,
        &BtfInputs {
            layout,
            ..BtfInputs::new(btf, maps, gbuffer, texture)
        },
    )?;
    k.record(&mut rec, frame)?;
    let rb = k.read_back(&mut rec)?;
    rec.submit_and_wait()?;
    k.collect(&rb)
}

#[test]
fn packing_round_trips_through_the_array_textures() {
    let (_, btf) = weave();
    let maps = maps();
    let gbuffer = GBuffer::tile([8, 8]);
    with_gpu(|ctx| {
        let packed = pack(btf);
        // Rows; one image per layer at the device's own limit, and at a lower cap that
        // splits the slices differently.
        for (layout, cap) in [
            (Layout::Rows, None),
            (Layout::Layers, None),
            (Layout::Layers, Some(1700)),
        ] {
            let mut rec = ctx.recorder("btf packing")?;
            let k = BtfKernel::new(
                &mut rec,
                &BtfInputs {
                    layout,
                    layer_cap: cap,
                    ..BtfInputs::new(btf, &maps, &gbuffer, Texture::Rgba8)
                },
            )?;
            let p = k.packing();
            assert!(p.layers_per_array <= ctx.limits().max_image_array_layers);
            if cap.is_some() {
                assert_eq!((p.layers_per_array, p.arrays), (1700, 4));
            }
            let back = read_back_arrays(rec, &k)?;
            let want = p.arrange(&packed);
            assert_eq!(back.len(), want.len(), "{layout:?}");
            assert!(
                back == want,
                "{layout:?}: texels differ after the round trip"
            );
            // Every image's texels are in there: un-arrange the rows.
            if layout == Layout::Rows {
                let (w, n) = (8usize, 81usize);
                for s in [0usize, 1, 80, 81, 3000, 6560] {
                    let (v, l) = (s / n, s % n);
                    for r in 0..8 {
                        let at = ((v * 8 + r) * n * (w + 2) + l * (w + 2) + 1) * 4;
                        assert_eq!(
                            &back[at..at + w * 4],
                            &packed[(s * 64 + r * w) * 4..][..w * 4]
                        );
                    }
                }
            }
            assert!(k.texture_bytes() >= p.bytes());
        }
        Ok(())
    });
    // BC1: the blocks come back as encoded, 8 bytes per 4 x 4 texels.
    with_gpu_features(BC, |ctx| {
        let mut rec = ctx.recorder("btf packing bc1")?;
        let k = BtfKernel::new(
            &mut rec,
            &BtfInputs {
                layout: Layout::Layers,
                layer_cap: Some(1700),
                ..BtfInputs::new(btf, &maps, &gbuffer, Texture::Bc1)
            },
        )?;
        let back = read_back_arrays(rec, &k)?;
        let want = encode_bc1(btf);
        assert_eq!(want.len(), 6561 * 4 * 8);
        assert!(back == want, "BC1 blocks differ after the round trip");
        assert!(k.texture_bytes() >= want.len() as u64);
        // Rows: 4-texel (one block) gutters; decoded, every layer is the arrangement of the
        // per-image decoded BC1 texels the CPU twin reads (gutter blocks are copies of the
        // image's edge blocks, interior blocks those of the per-image encoding).
        let mut rec = ctx.recorder("btf packing bc1 rows")?;
        let k = BtfKernel::new(
            &mut rec,
            &BtfInputs::new(btf, &maps, &gbuffer, Texture::Bc1),
        )?;
        let p = k.packing();
        assert_eq!((p.gutter, p.layer_extent), (4, [81 * 16, 8]));
        let rb = rec.read_back_image(&k.arrays()[0], ImageRegion::whole(k.arrays()[0].desc()))?;
        rec.submit_and_wait()?;
        let back = rb.bytes()?;
        assert_eq!(back.len() as u64, p.bytes());
        let [lw, lh] = p.layer_extent;
        let decoded: Vec<u8> = back
            .chunks(p.layer_bytes())
            .flat_map(|l| vkshade::io::bc1::decode_image(lw, lh, l))
            .collect();
        assert!(
            decoded == p.arrange(&sampled_texels(btf, Texture::Bc1)),
            "BC1 rows layout differs from the per-image decoded texels"
        );
        Ok(())
    });
    // Block: one RGBA32UI texel per overlapping 4 x 4 block, rows of blocks per view layer;
    // the 'layers' layout is refused.
    with_gpu(|ctx| {
        let mut rec = ctx.recorder("btf packing block")?;
        let k = BtfKernel::new(
            &mut rec,
            &BtfInputs::new(btf, &maps, &gbuffer, Texture::Block),
        )?;
        let p = k.packing();
        // An 8 x 8 tile takes 3 x 3 blocks.
        assert_eq!((p.gutter, p.layer_extent, p.arrays), (0, [81 * 3, 3], 1));
        let back = read_back_arrays(rec, &k)?;
        let blocks = encode_blocks(btf);
        assert_eq!(blocks.len(), 6561 * 9);
        let want = p.arrange_blocks(&blocks);
        assert_eq!(back.len() as u64, p.bytes());
        assert!(
            back == bytemuck::cast_slice::<[u32; 4], u8>(&want),
            "block texels differ after the round trip"
        );
        // Layer v, block row 1, image l: its blocks 3..6 of row 1 in the slice-major encoding.
        for (v, l) in [(0usize, 0usize), (5, 80), (80, 3)] {
            let at = ((v * 3 + 1) * 81 + l) * 3;
            assert_eq!(&want[at..at + 3], &blocks[(v * 81 + l) * 9 + 3..][..3]);
        }
        let mut rec = ctx.recorder("btf block layers")?;
        let e = BtfKernel::new(
            &mut rec,
            &BtfInputs {
                layout: Layout::Layers,
                ..BtfInputs::new(btf, &maps, &gbuffer, Texture::Block)
            },
        )
        .err()
        .expect("block in the layers layout is refused");
        assert!(e.to_string().contains("rows"), "{e}");
        drop(rec);
        Ok(())
    });
    // Without textureCompressionBC the error names the feature.
    with_gpu(|ctx| {
        let mut rec = ctx.recorder("btf bc1 without feature")?;
        let e = BtfKernel::new(
            &mut rec,
            &BtfInputs {
                layout: Layout::Layers,
                ..BtfInputs::new(btf, &maps, &gbuffer, Texture::Bc1)
            },
        )
        .err()
        .expect("bc1 without the feature is refused");
        assert!(e.to_string().contains("textureCompressionBC"), "{e}");
        drop(rec);
        Ok(())
    });
}

/// Largest difference between GPU and the f64 CPU interpolation allowed, for a device whose
/// bilinear weights are fixed point with `bits` = subTexelPrecisionBits (8 on lavapipe; the
/// spec allows 4): weights within 2^-(bits + 1) of exact, so over taps whose weights sum to 1
/// the filter is off by at most 2 * 2^-(bits + 1) = 2^-bits of the largest texel (1); the
/// sRGB decode (within ~0.5 ulp of 8 bits) and f32 rounding add 1.1e-3. Per light of
/// strength 1: 5e-3 for 8 bits. Measured on lavapipe: 1.2e-3 (two lights, sums up to ~1.3).
fn gpu_cpu_bound(bits: u32) -> f64 {
    2f64.powi(-(bits as i32)) + 1.1e-3
}
/// BC1: the CPU interpolates the texels as the device itself decodes them
/// ([`device_bc1_texels`]: the vendors' palettes differ, see bc1::PALETTE_TOLERANCE), so
/// only the filter differs, as for RGBA8, plus the re-encoding of the device's texels to
/// 8-bit sRGB: `residual` (linear, per texel) per light of strength 1, the two lights summing
/// to < 2.
fn gpu_cpu_bound_bc1(bits: u32, residual: f64) -> f64 {
    gpu_cpu_bound(bits) + 2.0 * residual
}

/// Every texel of `btf`'s BC1 encoding as this device decodes it (texelFetch, no filter),
/// re-encoded as 8-bit sRGB slice-major (the CPU twin's input), and the largest difference in
/// linear between a fetched value and its re-encoding.
fn device_bc1_texels(ctx: &vkshade::gpu::Context, btf: &Btf) -> vkshade::Result<(Vec<u8>, f64)> {
    use vkshade::gpu::{Buffer, BufferDesc, Image, ImageDesc, ImageRef, Resource};
    use vkshade::kernels::btf::gpu::BC1_FORMAT;
    use vkshade::kernels::btf::synth::{srgb_decode, srgb_encode};
    let [w, h] = btf.size;
    assert!(w % 4 == 0 && h % 4 == 0, "BC1 tiles are whole 4 x 4 blocks");
    let blocks = encode_bc1(btf);
    let per_slice = (w * h) as usize / 2; // bytes: 8 per 4 x 4 texels
    let slices = blocks.len() / per_slice;
    // Layers per image: the device's limit, and one dispatch's 65535 groups of 64 texels.
    let chunk = (ctx.limits().max_image_array_layers as usize)
        .min(65535 * 64 / (w * h) as usize)
        .max(1);
    let p = vkshade::shaders::pipeline(ctx, "test/fetch_layers")?;
    let (mut texels, mut residual) = (Vec::with_capacity(slices * (w * h) as usize * 4), 0f64);
    for first in (0..slices).step_by(chunk) {
        let layers = chunk.min(slices - first);
        let desc = ImageDesc::d2_array(BC1_FORMAT, [w, h], layers as u32);
        let image = Image::new(ctx, "bc1 layers", desc)?;
        let n = (w * h) as u64 * layers as u64;
        let out = Buffer::new(ctx, "decoded texels", BufferDesc::storage(n * 16))?;
        let bind = p.bind(&[
            ("tex", Resource::Texture(ImageRef::new(&image))),
            ("out_texels", Resource::Buffer(&out)),
        ])?;
        let push: Vec<u8> = [w, h, layers as u32, 0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut rec = ctx.recorder("decode bc1")?;
        rec.upload_image(
            &image,
            ImageRegion::whole(&desc),
            &blocks[first * per_slice..(first + layers) * per_slice],
        )?;
        rec.dispatch_invocations_tracked(&p, &bind, &push, [n as u32, 1, 1])?;
        let rb = rec.read_back(&out)?;
        rec.submit_and_wait()?;
        let got: Vec<[f32; 4]> = rb.to_vec()?;
        for g in got {
            for &l in &g[..3] {
                let b = srgb_encode(l);
                residual = residual.max((l as f64 - srgb_decode(b)).abs());
                texels.push(b);
            }
            texels.push(255);
        }
    }
    Ok((texels, residual))
}

const BC: vkshade::gpu::Features = vkshade::gpu::Features {
    shader_float16: false,
    shader_int16: false,
    storage_16bit: false,
    shader_float64: false,
    sampler_anisotropy: false,
    texture_compression_bc: true,
    buffer_int64_atomics: false,
};

#[test]
fn gpu_matches_the_cpu_interpolation_and_the_direct_ray_cast() {
    let (cfg, btf) = weave();
    let maps = maps();
    let frame = frame();
    for (object, texture, layout) in [
        (Object::Sphere, Texture::Rgba8, Layout::Rows),
        (Object::Sphere, Texture::Rgba8, Layout::Layers),
        (Object::Sphere, Texture::Bc1, Layout::Rows),
        (Object::Sphere, Texture::Bc1, Layout::Layers),
        (Object::Sphere, Texture::Block, Layout::Rows),
        (Object::Cylinder, Texture::Rgba8, Layout::Rows),
        (Object::Cylinder, Texture::Block, Layout::Rows),
        (Object::Plane, Texture::Rgba8, Layout::Rows),
        (Object::Plane, Texture::Block, Layout::Rows),
    ] {
        let gbuffer = render_object(object, 48, 40).unwrap();
        assert!(gbuffer.covered() > 300, "{object:?} covers too little");
        let run = |ctx: &vkshade::gpu::Context| {
            let out = run(ctx, btf, &maps, &gbuffer, &frame, (texture, layout))?;
            Ok((out, common::sub_texel_bits(ctx)))
        };
        // The data the GPU samples (BC1: the encoding as the device decodes it; block: the
        // blocks).
        let ((out, bits), sampled, residual) = match texture {
            Texture::Bc1 => {
                let ((out, bits), (texels, residual)) =
                    with_gpu_features(BC, |ctx| Ok((run(ctx)?, device_bc1_texels(ctx, btf)?)));
                // The device's palette against io::bc1's: within the vendors' spread (and
                // one step for re-encoding the device's sRGB decoding, itself up to 0.35
                // of a step off on NVIDIA), and the texture holds the blocks the CPU
                // decodes (a wrong block or a wrong texel order is tens of steps off).
                let ours = sampled_texels(btf, Texture::Bc1);
                let steps = texels
                    .iter()
                    .zip(&ours)
                    .map(|(&a, &b)| a.abs_diff(b))
                    .max()
                    .unwrap();
                eprintln!(
                    "BC1 as this device decodes it: up to {steps} 8-bit steps from io::bc1, \
                     re-encoding residual {residual:.1e}"
                );
                assert!(
                    steps <= vkshade::io::bc1::PALETTE_TOLERANCE + 1,
                    "the device's BC1 texels differ from io::bc1's by {steps} steps"
                );
                ((out, bits), Sampled::Texels(texels), residual)
            }
            _ => (with_gpu(run), Sampled::of(btf, texture), 0.0),
        };
        let bound = match texture {
            Texture::Rgba8 => gpu_cpu_bound(bits),
            Texture::Bc1 => gpu_cpu_bound_bc1(bits, residual),
            Texture::Block => GPU_CPU_BOUND_BLOCK,
        };
        let (want, ambiguous) = cpu::shade(&sampled.packed(btf.size), &maps, &gbuffer, &frame);
        let mut max: f64 = 0.0;
        let mut compared = 0;
        for (k, (g, c)) in out.iter().zip(&want).enumerate() {
            assert_eq!(g[3] as f64, c[3], "coverage of pixel {k}");
            if ambiguous[k] {
                continue;
            }
            compared += 1;
            for i in 0..3 {
                max = max.max((g[i] as f64 - c[i]).abs());
            }
        }
        let lit = want.iter().filter(|c| c[0] > 0.01).count();
        assert!(lit > 100, "{object:?}: only {lit} lit pixels");
        assert!(
            compared + 20 > gbuffer.covered(),
            "too many ambiguous pixels"
        );
        assert!(max < bound, "{object:?} {texture:?}: |GPU - CPU| = {max}");

        // Against the heightfield ray-cast at each pixel's exact directions.
        let (truth, theta) = vkshade::reference::btf::ray_cast(cfg, &gbuffer, &frame);
        // Split at 75 deg (the largest polar angle of the view and the lights).
        let (mut se, mut n) = ([0.0; 2], [0usize; 2]);
        for k in 0..out.len() {
            if truth[k][3] > 0.0 {
                let band = (theta[k] > 75.0) as usize;
                for i in 0..3 {
                    se[band] += (out[k][i] as f64 - truth[k][i]).powi(2);
                }
                n[band] += 3;
            }
        }
        let psnr = |b: usize| 10.0 * (1.0 / (se[b] / n[b] as f64)).log10();
        eprintln!(
            "{object:?} {texture:?} {layout:?}: |GPU - CPU| max {max:.2e}; PSNR vs ray-cast {:.1} dB ({} px <= 75 deg), {:.1} dB ({} px grazing)",
            psnr(0),
            n[0] / 3,
            psnr(1),
            n[1] / 3
        );
        // Measured 24.4 dB (plane, block, all grazing) to 28.0 dB (sphere, RGBA8); the
        // nearest direction instead of the interpolation gives 21.9 - 24.0 dB.
        let psnr = if n[0] > 300 { psnr(0) } else { psnr(1) };
        assert!(psnr > 23.0, "{object:?}: PSNR {psnr:.1} dB");
    }
}

#[test]
fn eval_tile_at_sample_directions_is_the_stored_image() {
    // Light and view at sampled directions whose map texels hold weight ~1 on them: the
    // interpolated tile is (nearly) the stored image.
    let (_, btf) = weave();
    let maps = Maps::build(&Triangulation::new().unwrap(), 256).unwrap();
    let d = vkshade::kernels::btf::dirs::directions();
    let (li, vi) = (0, 7); // light at the pole, view at theta 30, phi 0
    let frame = Frame {
        camera: Camera::Orthographic(Vec3::from_array(d[vi].vector().map(|x| x as f32))),
        lights: vec![Light {
            direction: Vec3::from_array(d[li].vector().map(|x| x as f32)),
            rgb: [1.0; 3],
        }],
    };
    let gbuffer = GBuffer::tile(btf.size);
    let out = with_gpu(|ctx| {
        run(
            ctx,
            btf,
            &maps,
            &gbuffer,
            &frame,
            (Texture::Rgba8, Layout::Rows),
        )
    });
    let img = btf.image(li, vi);
    let wv = maps.lookup(d[vi].vector());
    let on_self: f64 = (0..3)
        .filter(|&k| wv.index[k] == vi)
        .map(|k| wv.weight[k])
        .sum();
    assert!(on_self > 0.95, "map texel weight on the sample {on_self}");
    let mut max: f32 = 0.0;
    for (o, t) in out.iter().zip(img) {
        for i in 0..3 {
            max = max.max((o[i] - t[i]).abs());
        }
    }
    // The rest of the weight goes to neighbouring samples whose texels differ by < 1.
    assert!(max < (1.0 - on_self as f32) + 0.01, "max {max}");
}

#[test]
fn directories_load_and_bad_ones_fail_clearly() {
    let cfg = SynthConfig::tile(Pattern::Rib, 4);
    let btf = synthesize(&cfg).unwrap();
    let dir = temp_dir("btf-load").join("rib");
    write_dir(&btf, &dir, FileFormat::Png, &cfg, "btf synth").unwrap();
    let loaded = load::load_dir(&dir).unwrap();
    assert_eq!(loaded.size, [4, 4]);
    // PNG holds 8-bit sRGB: the loaded values are the quantised originals.
    for (a, b) in loaded.texels.iter().zip(&btf.texels) {
        for i in 0..3 {
            let q = vkshade::kernels::btf::synth::srgb_decode(
                vkshade::kernels::btf::synth::srgb_encode(b[i]),
            ) as f32;
            assert!((a[i] - q).abs() < 1e-6);
        }
    }
    let name = |tl: u32, pl: u32, tv: u32, pv: u32| {
        dir.join(format!("btf_tl{tl:03}_pl{pl:03}_tv{tv:03}_pv{pv:03}.png"))
    };
    let victim = name(45, 40, 30, 60);
    let saved = std::fs::read(&victim).unwrap();

    // A missing direction names the directory and the missing pair.
    std::fs::remove_file(&victim).unwrap();
    let e = error_naming(&dir, load::load_dir(&dir));
    assert!(
        e.contains("missing") && e.contains("tl045 pl040 tv030 pv060"),
        "{e}"
    );

    // Inconsistent image sizes name the odd file.
    let small = temp_dir("btf-load").join("small");
    write_dir(
        &Btf {
            size: [3, 4],
            texels: vec![[0.2; 3]; 6561 * 12],
        },
        &small,
        FileFormat::Png,
        &"3x4",
        "btf synth",
    )
    .unwrap();
    std::fs::copy(small.join("btf_tl045_pl040_tv030_pv060.png"), &victim).unwrap();
    let e = error_naming(&victim, load::load_dir(&dir));
    assert!(e.contains("3 x 4") && e.contains("same size"), "{e}");

    // An unreadable file names itself.
    std::fs::write(&victim, b"not a png").unwrap();
    let e = error_naming(&victim, load::load_dir(&dir));
    assert!(e.contains("cannot read"), "{e}");
    std::fs::write(&victim, &saved).unwrap();
    assert!(load::load_dir(&dir).is_ok());

    // A direction outside the UBO2003 set, and a duplicate pair, name the file.
    let odd = name(20, 0, 0, 0);
    std::fs::write(&odd, &saved).unwrap();
    let e = error_naming(&odd, load::load_dir(&dir));
    assert!(e.contains("not one of the 81"), "{e}");
    std::fs::remove_file(&odd).unwrap();
    let dup = dir.join("copy tl045 pl040 tv030 pv060.png");
    std::fs::write(&dup, &saved).unwrap();
    let e = load::load_dir(&dir)
        .expect_err("duplicate accepted")
        .to_string();
    assert!(e.contains("same (light, view) pair"), "{e}");
    std::fs::remove_file(&dup).unwrap();

    // The Bonn naming and format: running number, spaces, sRGB JPEG.
    let bonn = temp_dir("btf-load").join("bonn");
    std::fs::create_dir_all(&bonn).unwrap();
    let d = vkshade::kernels::btf::dirs::directions();
    for s in 0..6561 {
        let (l, v) = (d[s % 81], d[s / 81]);
        let rgb: Vec<u8> = btf
            .image(s % 81, s / 81)
            .iter()
            .flat_map(|p| p.map(vkshade::kernels::btf::synth::srgb_encode))
            .collect();
        let name = format!(
            "{s:05} tl{:03} pl{:03} tv{:03} pv{:03}.jpg",
            l.theta, l.phi, v.theta, v.phi
        );
        image::save_buffer(bonn.join(name), &rgb, 4, 4, image::ExtendedColorType::Rgb8).unwrap();
    }
    let jpeg = load::load_dir(&bonn).unwrap();
    let mae: f64 = jpeg
        .texels
        .iter()
        .zip(&btf.texels)
        .map(|(a, b)| (0..3).map(|i| (a[i] - b[i]).abs() as f64).sum::<f64>())
        .sum::<f64>()
        / (3 * btf.texels.len()) as f64;
    assert!(mae < 0.03, "JPEG round trip: mean error {mae}");

    // Not a directory at all.
    let none = temp_dir("btf-load").join("absent");
    error_naming(&none, load::load_dir(&none));
    let _ = std::fs::remove_dir_all(temp_dir("btf-load"));
}

#[test]
fn bad_kernel_inputs_are_errors() {
    let (_, btf) = weave();
    let maps = maps();
    let gbuffer = GBuffer::tile([8, 8]);
    with_gpu(|ctx| {
        let mut rec = ctx.recorder("bad btf")?;
        let short = Btf {
            size: [8, 8],
            texels: btf.texels[..64 * 100].to_vec(),
        };
        let r = BtfKernel::new(
            &mut rec,
            &BtfInputs::new(&short, &maps, &gbuffer, Texture::Rgba8),
        );
        let e = r.err().expect("a BTF of 100 images accepted").to_string();
        assert!(e.contains("not 6561 images"), "{e}");
        // A layer cap needing more than the shader's four arrays is a limit error.
        let r = BtfKernel::new(
            &mut rec,
            &BtfInputs {
                layout: Layout::Layers,
                layer_cap: Some(1000),
                ..BtfInputs::new(btf, &maps, &gbuffer, Texture::Rgba8)
            },
        );
        let e = r.err().expect("7 arrays accepted").to_string();
        assert!(e.contains("maxImageArrayLayers"), "{e}");
        let k = BtfKernel::new(
            &mut rec,
            &BtfInputs::new(btf, &maps, &gbuffer, Texture::Rgba8),
        )?;
        let mut f = frame();
        f.lights.push(f.lights[0]);
        let e = k.record(&mut rec, &f).expect_err("three lights accepted");
        assert!(e.to_string().contains("3 lights"), "{e}");
        f.lights.clear();
        let e = k.record(&mut rec, &f).expect_err("no light accepted");
        assert!(e.to_string().contains("0 lights"), "{e}");
        rec.submit_and_wait()?;
        Ok(())
    });
}

#[test]
fn a_mesh_with_uvs_is_shaded_like_the_cpu_and_one_without_is_refused() {
    let (_, btf) = weave();
    let maps = maps();
    let frame = frame();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let character = vkshade::scene::load(&path).unwrap();
    let gbuffer = vkshade::scene::gbuffer::render_mesh(&character.mesh, 64, 64).unwrap();
    assert!(gbuffer.covered() > 100, "{} px", gbuffer.covered());
    let (out, bits) = with_gpu(|ctx| {
        let out = run(
            ctx,
            btf,
            &maps,
            &gbuffer,
            &frame,
            (Texture::Rgba8, Layout::Rows),
        )?;
        Ok((out, common::sub_texel_bits(ctx)))
    });
    let packed = pack(btf);
    let (want, ambiguous) = cpu::shade(
        &cpu::Packed::new(btf.size, &packed),
        &maps,
        &gbuffer,
        &frame,
    );
    let mut max: f64 = 0.0;
    for k in 0..out.len() {
        assert_eq!(out[k][3] as f64, want[k][3]);
        if !ambiguous[k] {
            for i in 0..3 {
                max = max.max((out[k][i] as f64 - want[k][i]).abs());
            }
        }
    }
    assert!(max < gpu_cpu_bound(bits), "|GPU - CPU| = {max}");
    assert!(want.iter().filter(|c| c[0] > 0.01).count() > 50);
    // The test ball has no texture coordinates.
    let e = vkshade::scene::gbuffer::render_mesh(&common::ball().mesh, 8, 8)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("no texture coordinates"), "{e}");
}

/// Catches: the direction interpolation replaced by the nearest direction (one-hot map
/// weights, planted in `Maps::build`: this fails at the first texel). Barycentric weights
/// in the parabolic plane reproduce any affine function of the projected point exactly, so
/// every map texel whose centre lies inside the sampled range (the 75 deg ring's 24-gon)
/// must return f(p) = a + b . p of its own centre from the 81 samples' values f(p_i) (f32
/// weights: within 1e-6 of values ~1). The nearest sample is off by up to half a ring's
/// spacing times |b|, ~0.1 here.
#[test]
fn map_lookups_between_sample_directions_interpolate_an_affine_function_exactly() {
    use vkshade::kernels::btf::dirs::{COUNT, in_sampled_hull, points, project, unproject};
    let res = 64;
    let maps = Maps::build(&Triangulation::new().unwrap(), res).unwrap();
    let f = |p: [f64; 2]| 0.6 + 0.25 * p[0] - 0.4 * p[1];
    let samples: Vec<f64> = points()[..COUNT].iter().map(|&p| f(p)).collect();
    let (mut checked, mut between) = (0, 0);
    for j in 0..res {
        for i in 0..res {
            let p = Maps::texel_point(res, i, j);
            if !in_sampled_hull(p) {
                continue;
            }
            let d = unproject(p);
            let q = project(d);
            let taps = maps.lookup(d);
            let got: f64 = (0..3)
                .map(|k| taps.weight[k] * samples[taps.index[k]])
                .sum();
            assert!(
                (got - f(q)).abs() < 1e-6,
                "texel ({i}, {j}) at {p:?}: {got} vs {} ({taps:?})",
                f(q)
            );
            checked += 1;
            between += (taps.weight.iter().filter(|&&w| w > 0.01).count() >= 2) as usize;
        }
    }
    // Most texels lie between samples, not on one.
    assert!(
        checked > 1500 && between * 10 > checked * 9,
        "{checked} texels, {between} between"
    );
}

/// Catches: the direction interpolation replaced by the nearest direction (one-hot map
/// weights, planted in `Maps::build`: the maps equal their nearest-direction version). The CPU twin (the
/// GPU's arithmetic in f64, matched by the test above) with the maps against the same with
/// nearest-direction maps, both against the heightfield ray cast of the woven tile on a
/// sphere: interpolating between the 81 directions must be closer to the truth.
#[test]
fn interpolating_directions_beats_the_nearest_direction_against_the_ray_cast() {
    let (cfg, btf) = weave();
    let maps = maps();
    let mut nearest = maps.clone();
    for w in &mut nearest.weight {
        // All of the texel's weight (below 1 towards the horizon) on its largest tap.
        let k = (0..3).max_by(|&a, &b| w[a].total_cmp(&w[b])).unwrap();
        let sum = w[0] + w[1] + w[2];
        *w = [0.0; 4];
        w[k] = sum;
    }
    assert!(
        maps.weight != nearest.weight,
        "the maps do not interpolate: each texel's weight is on one direction already"
    );
    let frame = frame();
    let gbuffer = render_object(Object::Sphere, 48, 40).unwrap();
    let sampled = Sampled::of(btf, Texture::Rgba8);
    let (truth, theta) = vkshade::reference::btf::ray_cast(cfg, &gbuffer, &frame);
    let psnr = |m: &Maps| {
        let (out, _) = cpu::shade(&sampled.packed(btf.size), m, &gbuffer, &frame);
        let (mut se, mut n) = (0.0, 0usize);
        for k in 0..out.len() {
            if truth[k][3] > 0.0 && theta[k] <= 75.0 {
                for i in 0..3 {
                    se += (out[k][i] - truth[k][i]).powi(2);
                }
                n += 3;
            }
        }
        assert!(n > 900, "{} pixels within 75 deg", n / 3);
        10.0 * (1.0 / (se / n as f64)).log10()
    };
    let (interpolated, nearest) = (psnr(&maps), psnr(&nearest));
    eprintln!("PSNR vs ray cast: interpolated {interpolated:.2} dB, nearest {nearest:.2} dB");
    // Measured 27.97 dB against 23.97 dB (48 x 40 pixels, two lights).
    assert!(
        interpolated > nearest + 2.0,
        "interpolated {interpolated:.2} dB, nearest {nearest:.2} dB"
    );
}
