//! Images on lavapipe against CPU expectations, under validation: mips, 2D arrays and 3D
//! images, region uploads and readbacks, copies, clears, blits, views with other formats,
//! separate textures and samplers, descriptor arrays, and the checks that refuse what a
//! device cannot do.

mod common;

use ash::vk;
use common::with_gpu;
use vkshade::gpu::{
    Buffer, BufferDesc, ComputePipeline, Context, ContextDesc, Features, Image, ImageDesc,
    ImageRef, ImageRegion, Resource, Sampler, SamplerDesc, Subresources, ViewDesc,
};
use vkshade::shaders::spirv;

const RGBA32F: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

/// The selected device's subTexelPrecisionBits: the spec allows as few as 4, so bounds on
/// filtered results are derived from it, not from lavapipe's 8.
fn sub_texel_bits(ctx: &Context) -> u32 {
    let h = ctx.external_handles();
    // SAFETY: the context's own instance and physical device, alive while `ctx` is.
    unsafe { h.instance.get_physical_device_properties(h.physical_device) }
        .limits
        .sub_texel_precision_bits
}

/// Whether the selected device can make storage images of `format` (optimal tiling).
fn storage_supported(ctx: &Context, format: vk::Format) -> bool {
    let h = ctx.external_handles();
    // SAFETY: as in `sub_texel_bits`.
    unsafe {
        h.instance
            .get_physical_device_format_properties(h.physical_device, format)
    }
    .optimal_tiling_features
    .contains(vk::FormatFeatureFlags::STORAGE_IMAGE)
}

fn pipeline(ctx: &Context, name: &str) -> vkshade::Result<ComputePipeline> {
    ComputePipeline::from_spirv(ctx, name, spirv(name)?)
}

/// A distinct RGBA value per (layer, mip, x, y).
fn texel(layer: u32, mip: u32, x: u32, y: u32) -> [f32; 4] {
    [
        layer as f32,
        mip as f32,
        x as f32 * 0.5 + y as f32 * 0.25,
        (x * 7 + y * 3 + mip * 11 + layer * 13) as f32 * 0.01,
    ]
}

fn mip_texels(desc: &ImageDesc, layer: u32, mip: u32) -> Vec<[f32; 4]> {
    let [w, h, _] = desc.mip_extent(mip);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| texel(layer, mip, x, y)))
        .collect()
}

/// Samples mip `lod` of `layer` at every texel centre through a texture + sampler pair.
fn sample_mip(
    ctx: &Context,
    image: ImageRef<'_>,
    sampler: &Sampler,
    size: [u32; 2],
    layer: u32,
    lod: f32,
) -> vkshade::Result<Vec<[f32; 4]>> {
    let p = pipeline(ctx, "test/sample_array")?;
    let n = (size[0] * size[1]) as u64;
    let out = Buffer::new(ctx, "samples", BufferDesc::storage(n * 16))?;
    let bind = p.bind(&[
        ("tex", Resource::Texture(image)),
        ("smp", Resource::Sampler(sampler)),
        ("out_texels", Resource::Buffer(&out)),
    ])?;
    let push: Vec<u8> = [size[0], size[1], layer, lod.to_bits()]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let mut rec = ctx.recorder("sample mip")?;
    rec.dispatch_invocations_tracked(&p, &bind, &push, [size[0], size[1], 1])?;
    let rb = rec.read_back(&out)?;
    rec.submit_and_wait()?;
    rb.to_vec()
}

#[test]
fn mips_layers_and_regions_round_trip_and_sample_exactly() {
    with_gpu(|ctx| {
        let desc = ImageDesc::d2_array(RGBA32F, [16, 8], 3).mips(0);
        assert_eq!(desc.mips, 5, "full chain of 16x8");
        let image = Image::new(ctx, "mipped array", desc)?;
        let mut rec = ctx.recorder("upload every mip of every layer")?;
        for layer in 0..3 {
            for mip in 0..desc.mips {
                let region = ImageRegion {
                    base_layer: layer,
                    layers: 1,
                    ..ImageRegion::mip(&desc, mip)
                };
                let data = mip_texels(&desc, layer, mip);
                rec.upload_image(&image, region, bytemuck::cast_slice(&data))?;
            }
        }
        // A sub-region of mip 1, layer 2.
        let region = ImageRegion {
            mip: 1,
            base_layer: 2,
            layers: 1,
            offset: [2, 1, 0],
            extent: [3, 2, 1],
        };
        let rb = rec.read_back_image(&image, region)?;
        rec.submit_and_wait()?;
        let got: Vec<[f32; 4]> = rb.to_vec()?;
        let want: Vec<[f32; 4]> = (1..3)
            .flat_map(|y| (2..5).map(move |x| texel(2, 1, x, y)))
            .collect();
        assert_eq!(got, want, "region readback");

        // Nearest filtering and nearest mips at texel centres give each texel exactly.
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        for layer in [0, 2] {
            for mip in [0, 2, 4] {
                let [w, h, _] = desc.mip_extent(mip);
                let got = sample_mip(ctx, (&image).into(), &nearest, [w, h], layer, mip as f32)?;
                assert_eq!(
                    got,
                    mip_texels(&desc, layer, mip),
                    "layer {layer} mip {mip}"
                );
            }
        }
        // A view of mips 2.. only: its level 0 is the image's mip 2.
        let view = ViewDesc::default().subresources(Subresources {
            base_mip: 2,
            mip_count: 3,
            base_layer: 0,
            layer_count: 3,
        });
        let [w, h, _] = desc.mip_extent(2);
        let got = sample_mip(
            ctx,
            ImageRef::new(&image).view(view),
            &nearest,
            [w, h],
            1,
            0.0,
        )?;
        assert_eq!(got, mip_texels(&desc, 1, 2), "view of mips 2..");
        Ok(())
    });
}

/// CPU box filter: each texel of the next mip is the mean of a 2x2 block.
fn box_down(src: &[[f32; 4]], w: usize, h: usize) -> Vec<[f32; 4]> {
    let (dw, dh) = (w / 2, h / 2);
    let mut out = Vec::with_capacity(dw * dh);
    for y in 0..dh {
        for x in 0..dw {
            let mut s = [0f32; 4];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let t = src[(2 * y + dy) * w + 2 * x + dx];
                for c in 0..4 {
                    s[c] += 0.25 * t[c];
                }
            }
            out.push(s);
        }
    }
    out
}

fn close(a: &[[f32; 4]], b: &[[f32; 4]], tol: f32) -> Result<(), String> {
    if a.len() != b.len() {
        return Err(format!("{} vs {} texels", a.len(), b.len()));
    }
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        for c in 0..4 {
            if (x[c] - y[c]).abs() > tol {
                return Err(format!("texel {i} channel {c}: {} vs {}", x[c], y[c]));
            }
        }
    }
    Ok(())
}

#[test]
fn mip_chains_by_blit_and_by_per_mip_compute_match_a_cpu_box_filter() {
    with_gpu(|ctx| {
        let size = 16u32;
        let base: Vec<[f32; 4]> = (0..size * size)
            .map(|i| {
                let (x, y) = ((i % size) as f32, (i / size) as f32);
                [x, y, (x * 0.3).sin(), (x * y * 0.01).cos()]
            })
            .collect();
        let mut cpu = vec![base.clone()];
        for m in 1..5 {
            let w = (size >> (m - 1)) as usize;
            cpu.push(box_down(&cpu[m - 1], w, w));
        }
        let desc = ImageDesc::d2(RGBA32F, [size, size])
            .mips(0)
            .usage(vk::ImageUsageFlags::STORAGE);
        let blitted = Image::new(ctx, "blitted", desc)?;
        let computed = Image::new(ctx, "computed", desc)?;
        let down = pipeline(ctx, "test/downsample")?;
        let mip_view = |m: u32| {
            ViewDesc::default().subresources(Subresources {
                base_mip: m,
                mip_count: 1,
                base_layer: 0,
                layer_count: 1,
            })
        };
        let binds: Vec<_> = (1..desc.mips)
            .map(|m| {
                down.bind(&[
                    (
                        "src",
                        Resource::StorageImage(ImageRef::new(&computed).view(mip_view(m - 1))),
                    ),
                    (
                        "dst",
                        Resource::StorageImage(ImageRef::new(&computed).view(mip_view(m))),
                    ),
                ])
            })
            .collect::<vkshade::Result<_>>()?;
        let mut rec = ctx.recorder("mip chains")?;
        let bytes: &[u8] = bytemuck::cast_slice(&base);
        rec.upload_image(&blitted, ImageRegion::whole(&desc), bytes)?;
        rec.upload_image(&computed, ImageRegion::whole(&desc), bytes)?;
        rec.generate_mips(&blitted)?;
        for (i, bind) in binds.iter().enumerate() {
            let m = i as u32 + 1;
            let dst = size >> m;
            rec.dispatch_invocations_tracked(
                &down,
                bind,
                &[dst.to_le_bytes(), dst.to_le_bytes()].concat(),
                [dst, dst, 1],
            )?;
        }
        let rbs: Vec<_> = (0..desc.mips)
            .map(|m| {
                Ok((
                    rec.read_back_image(&blitted, ImageRegion::mip(&desc, m))?,
                    rec.read_back_image(&computed, ImageRegion::mip(&desc, m))?,
                ))
            })
            .collect::<vkshade::Result<_>>()?;
        rec.submit_and_wait()?;
        let bits = sub_texel_bits(ctx);
        for (m, (b, c)) in rbs.iter().enumerate() {
            // Blits of 2:1 with linear filtering average 2x2 blocks; the sub-texel
            // precision of the filter (the device's subTexelPrecisionBits) bounds the
            // difference: values up to 16, weights within 2^-bits.
            let tol = 1e-5 + 16.0 * 2f32.powi(-(bits as i32)) * 2f32.powi(-(m as i32));
            close(&b.to_vec::<[f32; 4]>()?, &cpu[m], tol)
                .map_err(|e| vkshade::Error::InvalidArgument(format!("blit mip {m}: {e}")))?;
            close(&c.to_vec::<[f32; 4]>()?, &cpu[m], 1e-4)
                .map_err(|e| vkshade::Error::InvalidArgument(format!("compute mip {m}: {e}")))?;
        }
        Ok(())
    });
}

#[test]
fn volumes_clears_and_copies() {
    with_gpu(|ctx| {
        let extent = [8u32, 6, 4];
        let desc = ImageDesc::d3(vk::Format::R32_SFLOAT, extent);
        let vol = Image::new(ctx, "volume", desc)?;
        let n = (extent[0] * extent[1] * extent[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let at = |x: usize, y: usize, z: usize| data[(z * 6 + y) * 8 + x];
        // Points at texel centres (exact with a nearest sampler) and in between (trilinear).
        let mut points = Vec::new();
        let mut want_nearest = Vec::new();
        for (x, y, z) in [(0, 0, 0), (7, 5, 3), (3, 2, 1), (5, 1, 2)] {
            points.push([
                (x as f32 + 0.5) / 8.0,
                (y as f32 + 0.5) / 6.0,
                (z as f32 + 0.5) / 4.0,
                0.0,
            ]);
            want_nearest.push(at(x, y, z));
        }
        let p = pipeline(ctx, "test/sample_3d")?;
        let pts = ctx.upload_buffer("points", BufferDesc::storage(16 * 4), &points)?;
        let values = Buffer::new(ctx, "values", BufferDesc::storage(16))?;
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        let bind = p.bind(&[
            ("vol", Resource::sampled(&vol, &nearest)),
            ("points", Resource::Buffer(&pts)),
            ("values", Resource::Buffer(&values)),
        ])?;
        // A cleared image, then a region copied from the volume's slice 2 into it.
        let slab = Image::new(
            ctx,
            "slab",
            ImageDesc::d3(vk::Format::R32_SFLOAT, [8, 6, 2]),
        )?;
        let mut rec = ctx.recorder("volume")?;
        rec.upload_image(&vol, ImageRegion::whole(&desc), bytemuck::cast_slice(&data))?;
        rec.dispatch_tracked(&p, &bind, &4u32.to_le_bytes(), [1, 1, 1])?;
        let sampled = rec.read_back(&values)?;
        rec.clear_image(&slab, slab.all(), [0.5, 0.0, 0.0, 0.0])?;
        rec.copy_image(
            &vol,
            ImageRegion {
                offset: [2, 1, 2],
                extent: [4, 3, 1],
                ..ImageRegion::whole(&desc)
            },
            &slab,
            ImageRegion {
                offset: [1, 1, 1],
                extent: [4, 3, 1],
                ..ImageRegion::whole(slab.desc())
            },
        )?;
        let copied = rec.read_back_image(&slab, ImageRegion::whole(slab.desc()))?;
        rec.submit_and_wait()?;
        assert_eq!(sampled.to_vec::<f32>()?, want_nearest);
        let got: Vec<f32> = copied.to_vec()?;
        for z in 0..2 {
            for y in 0..6 {
                for x in 0..8 {
                    let inside = z == 1 && (1..4).contains(&y) && (1..5).contains(&x);
                    let want = if inside { at(x + 1, y, 2) } else { 0.5 };
                    assert_eq!(got[(z * 6 + y) * 8 + x], want, "slab ({x},{y},{z})");
                }
            }
        }
        Ok(())
    });
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

#[test]
fn srgb_and_unorm_views_of_one_image() {
    with_gpu(|ctx| {
        let desc = ImageDesc::d2(vk::Format::R8G8B8A8_UNORM, [8, 4]).mutable_format();
        let image = Image::new(ctx, "rgba8", desc)?;
        let bytes: Vec<u8> = (0..8 * 4 * 4).map(|i| (i * 37 % 256) as u8).collect();
        let mut rec = ctx.recorder("upload rgba8")?;
        rec.upload_image(&image, ImageRegion::whole(&desc), &bytes)?;
        rec.submit_and_wait()?;
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        let array = ViewDesc::default().view_type(vk::ImageViewType::TYPE_2D_ARRAY);
        let unorm = sample_mip(
            ctx,
            ImageRef::new(&image).view(array),
            &nearest,
            [8, 4],
            0,
            0.0,
        )?;
        let srgb = sample_mip(
            ctx,
            ImageRef::new(&image).view(array.format(vk::Format::R8G8B8A8_SRGB)),
            &nearest,
            [8, 4],
            0,
            0.0,
        )?;
        for (i, (u, s)) in unorm.iter().zip(&srgb).enumerate() {
            for c in 0..4 {
                let b = bytes[4 * i + c] as f32 / 255.0;
                assert!(
                    (u[c] - b).abs() < 1e-6,
                    "unorm texel {i}.{c}: {} vs {b}",
                    u[c]
                );
                // Alpha is linear in sRGB formats. The decoding of the colour is the exact
                // curve within one 8-bit step on the devices we know: lavapipe within 1e-3 of
                // it, NVIDIA (H200, driver 580.159) returned 0.9765625 for 252 (exact
                // 0.97345, 0.35 of a step toward 253).
                let (lo, hi) = if c == 3 {
                    (b - 1e-6, b + 1e-6)
                } else {
                    (
                        srgb_to_linear((b - 1.0 / 255.0).max(0.0)) - 1e-6,
                        srgb_to_linear((b + 1.0 / 255.0).min(1.0)) + 1e-6,
                    )
                };
                assert!(
                    s[c] >= lo && s[c] <= hi,
                    "srgb texel {i}.{c}: {} outside [{lo}, {hi}] (byte {})",
                    s[c],
                    bytes[4 * i + c]
                );
            }
        }
        // A view in another format needs mutable_format().
        let fixed = Image::new(
            ctx,
            "fixed",
            ImageDesc::d2(vk::Format::R8G8B8A8_UNORM, [4, 4]),
        )?;
        let e = fixed
            .view_with(&ViewDesc::default().format(vk::Format::R8G8B8A8_SRGB))
            .unwrap_err();
        assert!(e.to_string().contains("mutable_format"), "{e}");
        Ok(())
    });
}

#[test]
fn descriptor_arrays_of_textures() {
    with_gpu(|ctx| {
        let n = 5u32;
        let desc = ImageDesc::d2(RGBA32F, [n, 1]);
        let images: Vec<Image> = (0..3)
            .map(|i| Image::new(ctx, &format!("tex{i}"), desc))
            .collect::<vkshade::Result<_>>()?;
        let p = pipeline(ctx, "test/texture_array")?;
        let out = Buffer::new(ctx, "out", BufferDesc::storage(3 * n as u64 * 16))?;
        let e = p
            .bind(&[
                ("texs", Resource::Array(vec![Resource::texture(&images[0])])),
                ("out_texels", Resource::Buffer(&out)),
            ])
            .err()
            .unwrap();
        assert!(e.to_string().contains("array of 3, given 1"), "{e}");
        let bind = p.bind(&[
            (
                "texs",
                Resource::Array(images.iter().map(Resource::texture).collect()),
            ),
            ("out_texels", Resource::Buffer(&out)),
        ])?;
        let mut rec = ctx.recorder("texture array")?;
        for (i, img) in images.iter().enumerate() {
            let row: Vec<[f32; 4]> = (0..n).map(|j| [i as f32, j as f32, 1.0, 2.0]).collect();
            rec.upload_image(img, ImageRegion::whole(&desc), bytemuck::cast_slice(&row))?;
        }
        rec.dispatch_tracked(&p, &bind, &n.to_le_bytes(), [1, 1, 1])?;
        let rb = rec.read_back(&out)?;
        rec.submit_and_wait()?;
        let got: Vec<[f32; 4]> = rb.to_vec()?;
        for i in 0..3 {
            for j in 0..n as usize {
                assert_eq!(got[i * n as usize + j], [i as f32, j as f32, 1.0, 2.0]);
            }
        }
        Ok(())
    });
}

#[test]
fn unsupported_formats_samplers_and_features_are_clear_errors() {
    with_gpu(|ctx| {
        // sRGB storage images: unsupported on lavapipe and most GPUs, where the error names
        // the missing feature; a device that has them makes one (asked of the device the
        // context selected, not assumed).
        let srgb = Image::new(
            ctx,
            "srgb storage",
            ImageDesc::d2(vk::Format::R8G8B8A8_SRGB, [4, 4]).usage(vk::ImageUsageFlags::STORAGE),
        );
        if storage_supported(ctx, vk::Format::R8G8B8A8_SRGB) {
            srgb?;
        } else {
            let s = srgb.unwrap_err().to_string();
            assert!(
                s.contains("STORAGE_IMAGE") && s.contains("srgb storage"),
                "{s}"
            );
        }
        // Linear filtering of an integer format.
        let uint = Image::new(
            ctx,
            "uint volume",
            ImageDesc::d3(vk::Format::R32_UINT, [2, 2, 2]),
        )?;
        let linear = Sampler::new(ctx, "linear", SamplerDesc::linear())?;
        let p = pipeline(ctx, "test/sample_3d")?;
        let b = Buffer::new(ctx, "b", BufferDesc::storage(64))?;
        let e = p
            .bind(&[
                ("vol", Resource::sampled(&uint, &linear)),
                ("points", Resource::Buffer(&b)),
                ("values", Resource::Buffer(&b)),
            ])
            .err()
            .unwrap();
        assert!(e.to_string().contains("SAMPLED_IMAGE_FILTER_LINEAR"), "{e}");
        // Samplers: anisotropy needs the feature; LOD ranges must be ordered.
        let e = Sampler::new(ctx, "aniso", SamplerDesc::linear().anisotropy(4.0)).unwrap_err();
        assert!(e.to_string().contains("sampler_anisotropy"), "{e}");
        let e = Sampler::new(ctx, "lod", SamplerDesc::linear().lod(3.0, 1.0)).unwrap_err();
        assert!(e.to_string().contains("LOD range"), "{e}");
        // Extents, mips and cube shapes.
        let e = Image::new(ctx, "mips", ImageDesc::d2(RGBA32F, [4, 4]).mips(7)).unwrap_err();
        assert!(e.to_string().contains("at most 3"), "{e}");
        let mut cube = ImageDesc::cube(RGBA32F, 8, 1);
        cube.layers = 5;
        let e = Image::new(ctx, "cube", cube).unwrap_err();
        assert!(e.to_string().contains("multiple of 6"), "{e}");
        Ok(())
    });
    // Features and extensions the device lacks are named.
    common::hold_gpu();
    let e = Context::new(&ContextDesc {
        extensions: vec!["VK_VKSHADE_not_an_extension".into()],
        ..ContextDesc::validated()
    })
    .unwrap_err();
    assert!(e.to_string().contains("VK_VKSHADE_not_an_extension"), "{e}");
    // The features of the device a validated context selects (not the first enumerated).
    let probe = common::context();
    let supported = probe.info().features;
    common::assert_clean(&common::shutdown(probe));
    let all = Features {
        shader_float16: true,
        shader_int16: true,
        storage_16bit: true,
        shader_float64: true,
        sampler_anisotropy: true,
        texture_compression_bc: true,
        buffer_int64_atomics: true,
    };
    let missing = all.missing_from(&supported);
    common::hold_gpu();
    match Context::new(&ContextDesc {
        features: all,
        ..ContextDesc::validated()
    }) {
        Ok(ctx) => {
            assert!(missing.is_empty());
            assert_eq!(ctx.features(), &all);
            common::assert_clean(&common::shutdown(ctx));
        }
        Err(e) => {
            assert!(!missing.is_empty());
            assert!(
                e.to_string().contains(missing[0]),
                "{e} should name {missing:?}"
            );
        }
    }
}

#[test]
fn pingpong_and_layout_changing_write_after_read_are_tracked() {
    with_gpu(|ctx| {
        let size = [8u32, 8];
        let desc = ImageDesc::d2(RGBA32F, size).usage(vk::ImageUsageFlags::STORAGE);
        let a = Image::new(ctx, "ping", desc)?;
        let b = Image::new(ctx, "pong", desc)?;
        let pp = pipeline(ctx, "test/pingpong")?;
        let ab = pp.bind(&[
            ("src", Resource::storage_image(&a)),
            ("dst", Resource::storage_image(&b)),
        ])?;
        let ba = pp.bind(&[
            ("src", Resource::storage_image(&b)),
            ("dst", Resource::storage_image(&a)),
        ])?;
        let push = |s: f32, o: f32| -> Vec<u8> {
            [size[0], size[1], s.to_bits(), o.to_bits()]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect()
        };
        let init: Vec<[f32; 4]> = (0..64).map(|i| [i as f32, 1.0, -1.0, 0.5]).collect();
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        let sampler_pipe = pipeline(ctx, "test/sample_array")?;
        let sampled = Buffer::new(ctx, "sampled", BufferDesc::storage(64 * 16))?;
        let array = ViewDesc::default().view_type(vk::ImageViewType::TYPE_2D_ARRAY);
        let sample_a = sampler_pipe.bind(&[
            ("tex", Resource::Texture(ImageRef::new(&a).view(array))),
            ("smp", Resource::Sampler(&nearest)),
            ("out_texels", Resource::Buffer(&sampled)),
        ])?;
        let mut rec = ctx.recorder("ping-pong")?;
        rec.upload_image(&a, ImageRegion::whole(&desc), bytemuck::cast_slice(&init))?;
        // Six passes a -> b -> a ..., each y = 2x + 1.
        for i in 0..6 {
            let bind = if i % 2 == 0 { &ab } else { &ba };
            rec.dispatch_invocations_tracked(&pp, bind, &push(2.0, 1.0), [8, 8, 1])?;
        }
        // a is sampled (SHADER_READ_ONLY), then written again as storage (GENERAL): a
        // write-after-read with a layout change.
        rec.dispatch_invocations_tracked(
            &sampler_pipe,
            &sample_a,
            &[
                8u32.to_le_bytes(),
                8u32.to_le_bytes(),
                0u32.to_le_bytes(),
                0f32.to_le_bytes(),
            ]
            .concat(),
            [8, 8, 1],
        )?;
        rec.dispatch_invocations_tracked(&pp, &ba, &push(0.5, 0.0), [8, 8, 1])?;
        let final_a = rec.read_back_image(&a, ImageRegion::whole(&desc))?;
        let sampled_rb = rec.read_back(&sampled)?;
        rec.submit_and_wait()?;
        let f = |x: f32| (0..6).fold(x, |v, _| 2.0 * v + 1.0);
        let after6: Vec<[f32; 4]> = init.iter().map(|t| t.map(f)).collect();
        assert_eq!(
            sampled_rb.to_vec::<[f32; 4]>()?,
            after6,
            "sampled after 6 passes"
        );
        // Pass 7 wrote b -> a with y = x/2 + 0; b holds pass 5's output.
        let after5: Vec<[f32; 4]> = init
            .iter()
            .map(|t| t.map(|x| (0..5).fold(x, |v, _| 2.0 * v + 1.0) * 0.5))
            .collect();
        assert_eq!(
            final_a.to_vec::<[f32; 4]>()?,
            after5,
            "after the layout-changing WAR"
        );
        Ok(())
    });
}

#[test]
fn sampler_addressing_border_and_lod_range_match_the_cpu() {
    with_gpu(|ctx| {
        // A 4x1x1 volume: values 1, 2, 3, 4 along x; sampled with nearest filtering at
        // x outside [0, 1] under each address mode.
        let desc = ImageDesc::d3(vk::Format::R32_SFLOAT, [4, 1, 1]);
        let vol = Image::new(ctx, "row", desc)?;
        let values = [1.0f32, 2.0, 3.0, 4.0];
        let xs = [0.125f32, 1.125, -0.125, 1.875, 2.375];
        let points: Vec<[f32; 4]> = xs.iter().map(|&x| [x, 0.5, 0.5, 0.0]).collect();
        let pts = ctx.upload_buffer("points", BufferDesc::storage(16 * 5), &points)?;
        let out = Buffer::new(ctx, "values", BufferDesc::storage(4 * 5))?;
        let p = pipeline(ctx, "test/sample_3d")?;
        let texel = |i: i64| values[i as usize];
        // CPU expectations per mode for each x (texel index floor(x * 4)).
        let cpu = |mode: vk::SamplerAddressMode, x: f32| -> f32 {
            let i = (x * 4.0).floor() as i64;
            match mode {
                vk::SamplerAddressMode::REPEAT => texel(i.rem_euclid(4)),
                vk::SamplerAddressMode::MIRRORED_REPEAT => {
                    let m = i.rem_euclid(8);
                    texel(if m < 4 { m } else { 7 - m })
                }
                vk::SamplerAddressMode::CLAMP_TO_EDGE => texel(i.clamp(0, 3)),
                _ => {
                    if (0..4).contains(&i) {
                        texel(i)
                    } else {
                        1.0 // FLOAT_OPAQUE_WHITE's red channel
                    }
                }
            }
        };
        let mut rec = ctx.recorder("upload row")?;
        rec.upload_image(
            &vol,
            ImageRegion::whole(&desc),
            bytemuck::cast_slice(&values),
        )?;
        rec.submit_and_wait()?;
        for mode in [
            vk::SamplerAddressMode::REPEAT,
            vk::SamplerAddressMode::MIRRORED_REPEAT,
            vk::SamplerAddressMode::CLAMP_TO_EDGE,
            vk::SamplerAddressMode::CLAMP_TO_BORDER,
        ] {
            let s = Sampler::new(
                ctx,
                "addressing",
                SamplerDesc::nearest()
                    .address(mode)
                    .border(vk::BorderColor::FLOAT_OPAQUE_WHITE),
            )?;
            let bind = p.bind(&[
                ("vol", Resource::sampled(&vol, &s)),
                ("points", Resource::Buffer(&pts)),
                ("values", Resource::Buffer(&out)),
            ])?;
            let mut rec = ctx.recorder("addressing")?;
            rec.dispatch_tracked(&p, &bind, &5u32.to_le_bytes(), [1, 1, 1])?;
            let rb = rec.read_back(&out)?;
            rec.submit_and_wait()?;
            let want: Vec<f32> = xs.iter().map(|&x| cpu(mode, x)).collect();
            assert_eq!(rb.to_vec::<f32>()?, want, "{mode:?}");
        }
        // The LOD range clamps: min_lod 1 samples mip 1 even when asked for mip 0.
        let mdesc = ImageDesc::d2_array(RGBA32F, [8, 8], 1).mips(0);
        let mipped = Image::new(ctx, "mipped", mdesc)?;
        let mut rec = ctx.recorder("mips")?;
        for mip in 0..mdesc.mips {
            let data = mip_texels(&mdesc, 0, mip);
            rec.upload_image(
                &mipped,
                ImageRegion::mip(&mdesc, mip),
                bytemuck::cast_slice(&data),
            )?;
        }
        rec.submit_and_wait()?;
        let clamped = Sampler::new(ctx, "lod 1..", SamplerDesc::nearest().lod(1.0, 8.0))?;
        let got = sample_mip(ctx, (&mipped).into(), &clamped, [4, 4], 0, 0.0)?;
        assert_eq!(got, mip_texels(&mdesc, 0, 1), "min_lod clamps to mip 1");
        Ok(())
    });
}

/// BC1 images: block-sized staging, region alignment, the textureCompressionBC feature, and
/// texels read back through a nearest sampler at texel centres (what texelFetch returns)
/// against the CPU decoder of `io::bc1`, in UNORM and sRGB.
#[test]
fn bc1_images_upload_and_sample_like_the_cpu_decoder() {
    use vkshade::io::bc1;
    // Without the feature enabled, a BC1 image is refused by name.
    with_gpu(|ctx| {
        let e = Image::new(
            ctx,
            "bc1 without feature",
            ImageDesc::d2(vk::Format::BC1_RGB_SRGB_BLOCK, [8, 8]),
        )
        .unwrap_err();
        assert!(e.to_string().contains("textureCompressionBC"), "{e}");
        Ok(())
    });
    common::hold_gpu();
    let ctx = Context::new(&ContextDesc {
        features: Features {
            texture_compression_bc: true,
            ..Features::default()
        },
        ..ContextDesc::validated()
    })
    .expect("lavapipe supports textureCompressionBC");
    let run = |ctx: &Context| -> vkshade::Result<()> {
        // 10 x 6: partial blocks at the right and bottom edges; two layers.
        let (w, h) = (10u32, 6u32);
        let rgba: Vec<Vec<u8>> = (0..2u32)
            .map(|layer| {
                (0..w * h)
                    .flat_map(|i| {
                        let (x, y) = (i % w, i / w);
                        [
                            (x * 23 + layer * 40) as u8,
                            (200 - y * 30) as u8,
                            ((x * y * 13 + layer * 7) % 256) as u8,
                            255,
                        ]
                    })
                    .collect()
            })
            .collect();
        let blocks: Vec<Vec<u8>> = rgba.iter().map(|t| bc1::encode_image(w, h, t)).collect();
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        for format in [
            vk::Format::BC1_RGB_UNORM_BLOCK,
            vk::Format::BC1_RGB_SRGB_BLOCK,
        ] {
            let desc = ImageDesc::d2_array(format, [w, h], 2);
            assert_eq!(desc.byte_size()?, 2 * 3 * 2 * 8);
            let image = Image::new(ctx, "bc1", desc)?;
            let mut rec = ctx.recorder("upload bc1")?;
            // Layer 0 whole; layer 1 in two regions: the left block column, then the rest
            // (which ends at the mip edge, not on a block boundary).
            rec.upload_image(
                &image,
                ImageRegion {
                    layers: 1,
                    ..ImageRegion::whole(&desc)
                },
                &blocks[0],
            )?;
            let left: Vec<u8> = [0usize, 3]
                .iter()
                .flat_map(|&b| blocks[1][b * 8..b * 8 + 8].to_vec())
                .collect();
            let right: Vec<u8> = [1usize, 2, 4, 5]
                .iter()
                .flat_map(|&b| blocks[1][b * 8..b * 8 + 8].to_vec())
                .collect();
            let region = |x: u32, width: u32| ImageRegion {
                mip: 0,
                base_layer: 1,
                layers: 1,
                offset: [x, 0, 0],
                extent: [width, h, 1],
            };
            rec.upload_image(&image, region(0, 4), &left)?;
            rec.upload_image(&image, region(4, 6), &right)?;
            // A region that starts inside a block, or ends inside one short of the edge.
            for bad in [region(2, 8), region(0, 6)] {
                let e = rec.upload_image(&image, bad, &[0; 32]).unwrap_err();
                assert!(e.to_string().contains("aligned"), "{e}");
            }
            rec.submit_and_wait()?;
            for layer in 0..2 {
                let got = sample_mip(ctx, ImageRef::new(&image), &nearest, [w, h], layer, 0.0)?;
                let want = bc1::decode_image(w, h, &blocks[layer as usize]);
                for (i, g) in got.iter().enumerate() {
                    for c in 0..3 {
                        // The vendors' palettes differ in entries 2 and 3 by up to
                        // bc1::PALETTE_TOLERANCE steps; sRGB decoding adds up to 3.1e-3
                        // (NVIDIA, above; lavapipe 1e-3).
                        let step = bc1::PALETTE_TOLERANCE as f32 / 255.0;
                        let b = want[4 * i + c] as f32 / 255.0;
                        let (lo, hi, slack) = if format == vk::Format::BC1_RGB_SRGB_BLOCK {
                            (
                                srgb_to_linear((b - step).max(0.0)),
                                srgb_to_linear((b + step).min(1.0)),
                                3.5e-3,
                            )
                        } else {
                            (b - step, b + step, 1e-5)
                        };
                        assert!(
                            g[c] >= lo - slack && g[c] <= hi + slack,
                            "{format:?} layer {layer} texel {i}.{c}: {} outside [{lo}, {hi}]",
                            g[c]
                        );
                    }
                    assert_eq!(g[3], 1.0);
                }
            }
        }
        Ok(())
    };
    let result = run(&ctx);
    let messages = common::shutdown(ctx);
    if let Err(e) = result {
        panic!("GPU test failed: {e}");
    }
    common::assert_clean(&messages);
}
