//! Misuse of the GPU layer from safe code: wrong buffer or image usage, barriers outside an
//! image, conflicting bindings and view types, the context's own timeline. Each case once
//! reached the driver (a validation error, a panic, or use-after-free; found by the core v2
//! review) and must now be a clear error, or run clean under validation.

mod common;

use ash::vk;
use common::with_gpu;
use vkshade::gpu::{
    AccessType as A, Barrier, Buffer, BufferDesc, Image, ImageDesc, Subresources, Use,
};
#[cfg(feature = "glsl")]
use vkshade::gpu::{ComputePipeline, Context, Resource, Sampler, SamplerDesc, ViewDesc};

const RGBA32F: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

#[cfg(feature = "glsl")]
fn compile(ctx: &Context, name: &str, src: &str) -> vkshade::Result<ComputePipeline> {
    let spirv = vkshade::shaders::compile_source(src, name)?;
    ComputePipeline::from_spirv(ctx, name, &spirv)
}

fn expect_err<T>(r: vkshade::Result<T>, needle: &str) {
    match r {
        Ok(_) => panic!("accepted; expected an error mentioning '{needle}'"),
        Err(e) => assert!(e.to_string().contains(needle), "'{e}' lacks '{needle}'"),
    }
}

#[test]
fn transfers_check_usage_and_stock_descriptions_have_what_they_need() {
    with_gpu(|ctx| {
        // A uniform buffer can be read back; an upload buffer can be filled.
        let u = ctx.upload_buffer("u", BufferDesc::uniform(256), &[1u32; 64])?;
        assert_eq!(ctx.read_buffer::<u32>(&u)?[3], 1);
        let up = Buffer::new(ctx, "up", BufferDesc::upload(64))?;
        let mut rec = ctx.recorder("fill upload")?;
        rec.fill_buffer(&up, 9)?;
        rec.submit_and_wait()?;
        assert_eq!(up.read::<u32>()?[0], 9);
        // A buffer without TRANSFER_SRC cannot be read back.
        let storage_only = Buffer::new(
            ctx,
            "storage only",
            BufferDesc {
                usage: vk::BufferUsageFlags::STORAGE_BUFFER,
                ..BufferDesc::storage(64)
            },
        )?;
        let mut rec = ctx.recorder("bad readback")?;
        expect_err(rec.read_back(&storage_only), "TRANSFER_SRC");
        expect_err(rec.fill_buffer(&storage_only, 0), "TRANSFER_DST");
        // Zero-sized element types are refused, not a panic.
        expect_err(up.read::<()>(), "zero-sized");
        Ok(())
    });
}

#[test]
fn image_barriers_and_uses_are_checked() {
    with_gpu(|ctx| {
        let img = Image::new(ctx, "img", ImageDesc::d2_array(RGBA32F, [4, 4], 2).mips(2))?;
        let mut rec = ctx.recorder("bad barriers")?;
        for range in [
            Subresources {
                base_mip: 2,
                mip_count: 1,
                base_layer: 0,
                layer_count: 1,
            },
            Subresources {
                base_mip: 0,
                mip_count: 1,
                base_layer: 3,
                layer_count: 1,
            },
        ] {
            expect_err(
                rec.barrier(&[Barrier::image(&img, A::Nothing, A::TransferWrite).range(range)]),
                "outside image 'img'",
            );
        }
        expect_err(
            rec.use_image(&img, img.all(), A::ComputeShaderReadUniformBuffer),
            "not image accesses",
        );
        let no_storage = Image::new(ctx, "no storage", ImageDesc::d2(RGBA32F, [4, 4]))?;
        expect_err(
            rec.use_image(&no_storage, no_storage.all(), A::ComputeShaderWrite),
            "STORAGE",
        );
        Ok(())
    });
}

#[cfg(feature = "glsl")]
const TEX_AND_STORE: &str = r#"#version 450
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform texture2D tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D img;
void main() { imageStore(img, ivec2(1, 1), textureLod(sampler2D(tex, smp), vec2(0.5), 0.0)); }"#;

#[cfg(feature = "glsl")]
#[test]
fn conflicting_bindings_overrides_and_view_types_are_refused() {
    with_gpu(|ctx| {
        let p = compile(ctx, "texstore", TEX_AND_STORE)?;
        let img = Image::new(
            ctx,
            "img",
            ImageDesc::d2(RGBA32F, [4, 4]).usage(vk::ImageUsageFlags::STORAGE),
        )?;
        let src = Image::new(ctx, "src", ImageDesc::d2(RGBA32F, [4, 4]))?;
        let smp = Sampler::new(ctx, "smp", SamplerDesc::nearest())?;
        // One mip as a texture and a storage image at once: two layouts.
        expect_err(
            p.bind(&[
                ("tex", Resource::texture(&img)),
                ("smp", Resource::Sampler(&smp)),
                ("img", Resource::storage_image(&img)),
            ]),
            "same subresources",
        );
        // An override whose layout contradicts the descriptor's, or that writes a texture.
        for access in [
            A::ComputeShaderReadOther.into(),
            A::ComputeShaderReadSampledImage | A::ComputeShaderWrite,
        ] {
            expect_err(
                p.bind_declared(
                    &[
                        ("tex", Resource::texture(&src)),
                        ("smp", Resource::Sampler(&smp)),
                        ("img", Resource::storage_image(&img)),
                    ],
                    &[("tex", access)],
                ),
                "tex",
            );
        }
        // A two-layer image for an `image2D`: the view type comes from the shader.
        let arr = Image::new(
            ctx,
            "arr",
            ImageDesc::d2_array(RGBA32F, [4, 4], 2).usage(vk::ImageUsageFlags::STORAGE),
        )?;
        expect_err(
            p.bind(&[
                ("tex", Resource::texture(&src)),
                ("smp", Resource::Sampler(&smp)),
                ("img", Resource::storage_image(&arr)),
            ]),
            "TYPE_2D",
        );
        // View types that do not fit the image; depth formats.
        let six = Image::new(ctx, "six", ImageDesc::d2_array(RGBA32F, [4, 4], 6))?;
        expect_err(
            six.view_with(&ViewDesc::default().view_type(vk::ImageViewType::CUBE)),
            "not possible",
        );
        expect_err(
            Image::new(ctx, "depth", ImageDesc::d2(vk::Format::D32_SFLOAT, [4, 4])),
            "depth/stencil",
        );
        // The good binding still works.
        let good = p.bind(&[
            ("tex", Resource::texture(&src)),
            ("smp", Resource::Sampler(&smp)),
            ("img", Resource::storage_image(&img)),
        ])?;
        let mut rec = ctx.recorder("good")?;
        rec.clear_image(&src, src.all(), [0.5; 4])?;
        rec.dispatch_tracked(&p, &good, &[], [1, 1, 1])?;
        rec.submit_and_wait()?;
        Ok(())
    });
}

#[test]
fn the_timeline_stays_vkshades_and_planned_barriers_keep_their_resource() {
    with_gpu(|ctx| {
        let rec = ctx.recorder("timeline")?;
        let sig = [vk::SemaphoreSubmitInfo::default()
            .semaphore(ctx.timeline())
            .value(1000)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        // SAFETY: the only semaphore given is the context's timeline, which submit_with
        // refuses before anything reaches the driver.
        expect_err(unsafe { rec.submit_with(&[], &sig) }, "own timeline");
        expect_err(ctx.wait_for(u64::MAX), "never handed out");

        let b = Buffer::new(ctx, "b", BufferDesc::storage(256))?;
        let mut planner = ctx.recorder("planner")?;
        planner.plan(&[Use::Buffer(&b, A::TransferWrite.into())])?;
        let planned = planner.plan(&[Use::Buffer(&b, A::TransferRead.into())])?;
        drop(planner);
        drop(b); // the planned barrier still holds it
        let mut r = ctx.recorder("replayer")?;
        r.record_planned(&planned)?;
        drop(planned);
        r.submit_and_wait()?;
        Ok(())
    });
}
