//! Bindings the device would refuse at dispatch are refused when bound, with an error naming
//! the pipeline, the binding and the resource: an image format whose numeric class is not
//! the one the shader reads, a linear sampler combined in the shader with a texture whose
//! format cannot be filtered linearly, and buffer ranges that are empty, outside their
//! buffer or misaligned.
//!
//! Each case once reached the driver (found by a renderer author's probes): where a binding
//! is accepted, the test dispatches it, so on code without the check the validation layer's
//! report (the VUID named beside each case) is what fails the test.

mod common;

#[cfg(feature = "glsl")]
use ash::vk;
use common::with_gpu;
use vkshade::gpu::{BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Resource};
#[cfg(feature = "glsl")]
use vkshade::gpu::{Image, ImageDesc, Sampler, SamplerDesc};

/// The error of a refused binding; an accepted one is dispatched and submitted (so that
/// validation reports what the device makes of it) and gives an empty message.
fn refused(
    ctx: &Context,
    p: &ComputePipeline,
    bound: vkshade::Result<BindGroup>,
    push: &[u8],
) -> vkshade::Result<String> {
    match bound {
        Err(e) => Ok(e.to_string()),
        Ok(group) => {
            let mut rec = ctx.recorder("accepted binding")?;
            rec.dispatch_tracked(p, &group, push, [1, 1, 1])?;
            rec.submit_and_wait()?;
            Ok(String::new())
        }
    }
}

fn assert_mentions(message: &str, needles: &[&str]) {
    for needle in needles {
        assert!(
            message.contains(needle),
            "'{message}' should mention '{needle}'"
        );
    }
}

#[test]
fn buffer_ranges_empty_outside_or_misaligned_are_refused() {
    let errors = with_gpu(|ctx| {
        let p = vkshade::shaders::pipeline(ctx, "test/chain_add")?;
        let y = Buffer::new(ctx, "y", BufferDesc::storage(256))?;
        let acc = Buffer::new(ctx, "acc", BufferDesc::storage(1024))?;
        let align = ctx.limits().min_storage_buffer_offset_alignment;
        let mut errors = Vec::new();
        for (offset, size) in [
            // The case: an empty range at the very end
            // (VUID-VkDescriptorBufferInfo-range-00341, -offset-00340).
            (256, 0),
            // An empty range inside the buffer (-range-00341).
            (0, 0),
            // An offset past the end (-offset-00340).
            (512, 4),
            // A range running past the end (-range-00342).
            (128, 256),
        ] {
            let bound = p.bind(&[
                (
                    "ybuf",
                    Resource::BufferRange {
                        buffer: &y,
                        offset,
                        size,
                    },
                ),
                ("accbuf", Resource::Buffer(&acc)),
            ]);
            // One element: the shader reads and writes only index 0.
            let push = [1.0f32.to_bits(), 1u32];
            errors.push(refused(ctx, &p, bound, bytemuck::cast_slice(&push))?);
        }
        // An offset that is not a multiple of minStorageBufferOffsetAlignment
        // (VUID-VkWriteDescriptorSet-descriptorType-00328), where the device has one.
        if align > 1 {
            let bound = p.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                (
                    "accbuf",
                    Resource::BufferRange {
                        buffer: &acc,
                        offset: align / 2,
                        size: 64,
                    },
                ),
            ]);
            let push = [1.0f32.to_bits(), 1u32];
            errors.push(refused(ctx, &p, bound, bytemuck::cast_slice(&push))?);
        }
        // A valid range next to them still binds and runs.
        let good = p.bind(&[
            (
                "ybuf",
                Resource::BufferRange {
                    buffer: &y,
                    offset: 0,
                    size: 256,
                },
            ),
            ("accbuf", Resource::Buffer(&acc)),
        ])?;
        let mut rec = ctx.recorder("good range")?;
        rec.fill_buffer(&y, 0)?;
        rec.fill_buffer(&acc, 0)?;
        let push = [1.0f32.to_bits(), 1u32];
        rec.dispatch_tracked(&p, &good, bytemuck::cast_slice(&push), [1, 1, 1])?;
        rec.submit_and_wait()?;
        Ok(errors)
    });
    let binding = "'ybuf' (set 0 binding 0)";
    assert_mentions(&errors[0], &["test/chain_add", binding, "'y'", "empty"]);
    assert_mentions(&errors[1], &[binding, "'y'", "empty"]);
    assert_mentions(&errors[2], &[binding, "512+4 is outside buffer 'y'"]);
    assert_mentions(&errors[3], &[binding, "128+256 is outside buffer 'y'"]);
    if let Some(misaligned) = errors.get(4) {
        assert_mentions(
            misaligned,
            &[
                "'accbuf' (set 0 binding 1)",
                "'acc'",
                "minStorageBufferOffsetAlignment",
            ],
        );
    }
}

#[cfg(feature = "glsl")]
fn compile(ctx: &Context, name: &str, src: &str) -> vkshade::Result<ComputePipeline> {
    let spirv = vkshade::shaders::compile_source(src, name)?;
    ComputePipeline::from_spirv(ctx, name, &spirv)
}

/// A separate 3D texture of `prefix` (``, `u`, `i`) sampled at the centre with sampler `smp`;
/// a second sampler is bound but samples nothing.
#[cfg(feature = "glsl")]
fn sample_3d_source(prefix: &str) -> String {
    format!(
        "#version 450
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform {prefix}texture3D vol;
layout(set = 0, binding = 1) uniform sampler smp;
layout(set = 0, binding = 2) uniform sampler unused;
layout(set = 0, binding = 3) buffer Out {{ {prefix}vec4 o; }};
void main() {{ o = textureLod({prefix}sampler3D(vol, smp), vec3(0.5), 0.0); }}"
    )
}

#[cfg(feature = "glsl")]
#[test]
fn image_formats_of_another_numeric_class_are_refused() {
    let errors = with_gpu(|ctx| {
        let float_tex = compile(ctx, "float texture3D", &sample_3d_source(""))?;
        let uint_tex = compile(ctx, "utexture3D", &sample_3d_source("u"))?;
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        let ids = Image::new(ctx, "ids", ImageDesc::d3(vk::Format::R32_UINT, [2, 2, 2]))?;
        let density = Image::new(
            ctx,
            "density",
            ImageDesc::d3(vk::Format::R32_SFLOAT, [2, 2, 2]),
        )?;
        let out = Buffer::new(ctx, "out", BufferDesc::storage(16))?;
        let bind = |p: &ComputePipeline, img| {
            p.bind(&[
                ("vol", Resource::texture(img)),
                ("smp", Resource::Sampler(&nearest)),
                ("unused", Resource::Sampler(&nearest)),
                ("Out", Resource::Buffer(&out)),
            ])
        };
        // The case: a float texture3D on R32_UINT
        // (VUID-vkCmdDispatch-format-07753); and the other way round.
        let errors = vec![
            refused(ctx, &float_tex, bind(&float_tex, &ids), &[])?,
            refused(ctx, &uint_tex, bind(&uint_tex, &density), &[])?,
        ];
        // Matching classes bind and sample.
        let mut rec = ctx.recorder("matching classes")?;
        rec.clear_image(&density, density.all(), [0.25; 4])?;
        rec.dispatch_tracked(&float_tex, &bind(&float_tex, &density)?, &[], [1, 1, 1])?;
        let got = rec.read_back(&out)?;
        rec.clear_image(&ids, ids.all(), [0.0; 4])?;
        rec.dispatch_tracked(&uint_tex, &bind(&uint_tex, &ids)?, &[], [1, 1, 1])?;
        rec.submit_and_wait()?;
        // R32_SFLOAT reads as (r, 0, 0, 1).
        assert_eq!(got.to_vec::<f32>()?, [0.25, 0.0, 0.0, 1.0]);
        Ok(errors)
    });
    assert_mentions(
        &errors[0],
        &[
            "float texture3D",
            "'vol' (set 0 binding 0)",
            "'ids'",
            "R32_UINT",
            "reads float texels",
            "`u`",
        ],
    );
    assert_mentions(
        &errors[1],
        &[
            "utexture3D",
            "'vol' (set 0 binding 0)",
            "'density'",
            "R32_SFLOAT",
            "reads unsigned integer texels",
        ],
    );
}

#[cfg(feature = "glsl")]
#[test]
fn linear_samplers_on_formats_without_linear_filtering_are_refused() {
    let errors = with_gpu(|ctx| {
        let uint_tex = compile(ctx, "utexture3D", &sample_3d_source("u"))?;
        let float_tex = compile(ctx, "float texture3D", &sample_3d_source(""))?;
        let nearest = Sampler::new(ctx, "nearest", SamplerDesc::nearest())?;
        let linear = Sampler::new(ctx, "linear", SamplerDesc::linear())?;
        // Nearest texels, linear between mips: also needs linear filtering
        // (VUID-vkCmdDispatch-mipmapMode-04770).
        let mip_linear = Sampler::new(
            ctx,
            "mip linear",
            SamplerDesc {
                mipmap_mode: vk::SamplerMipmapMode::LINEAR,
                ..SamplerDesc::nearest()
            },
        )?;
        let ids = Image::new(ctx, "ids", ImageDesc::d3(vk::Format::R32_UINT, [2, 2, 2]))?;
        let density = Image::new(
            ctx,
            "density",
            ImageDesc::d3(vk::Format::R32_SFLOAT, [2, 2, 2]),
        )?;
        let out = Buffer::new(ctx, "out", BufferDesc::storage(16))?;
        let bind = |p: &ComputePipeline, img, smp, unused| {
            p.bind(&[
                ("vol", Resource::texture(img)),
                ("smp", Resource::Sampler(smp)),
                ("unused", Resource::Sampler(unused)),
                ("Out", Resource::Buffer(&out)),
            ])
        };
        let mut errors = Vec::new();
        // The case: a utexture3D sampled linearly on R32_UINT
        // (VUID-vkCmdDispatch-magFilter-04553).
        for smp in [&linear, &mip_linear] {
            let bound = bind(&uint_tex, &ids, smp, &nearest);
            errors.push(refused(ctx, &uint_tex, bound, &[])?);
        }
        // A linear sampler the shader never combines with the texture is no concern, and
        // a float format the device filters linearly binds.
        let mut rec = ctx.recorder("allowed")?;
        rec.clear_image(&ids, ids.all(), [0.0; 4])?;
        rec.clear_image(&density, density.all(), [0.5; 4])?;
        let unused_linear = bind(&uint_tex, &ids, &nearest, &linear)?;
        rec.dispatch_tracked(&uint_tex, &unused_linear, &[], [1, 1, 1])?;
        let filtered = bind(&float_tex, &density, &linear, &linear)?;
        rec.dispatch_tracked(&float_tex, &filtered, &[], [1, 1, 1])?;
        let got = rec.read_back(&out)?;
        rec.submit_and_wait()?;
        assert_eq!(got.to_vec::<f32>()?, [0.5, 0.0, 0.0, 1.0]);
        Ok(errors)
    });
    for (error, sampler) in errors.iter().zip(["'linear'", "'mip linear'"]) {
        assert_mentions(
            error,
            &[
                "utexture3D",
                "'vol' (set 0 binding 0)",
                sampler,
                "'smp' (set 0 binding 1)",
                "'ids'",
                "R32_UINT",
                "SAMPLED_IMAGE_FILTER_LINEAR",
            ],
        );
    }
}
