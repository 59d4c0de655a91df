//! What safe code cannot break (core v3), each under validation with synchronization checks:
//! - tracked state follows submissions, not recordings: a recording dropped unsubmitted
//!   leaves no trace, recordings submitted in another order than they were recorded are
//!   joined to the true state at submission, and a recording into a caller's command buffer
//!   that would commit a stale join is refused (on the core-v2 tracker, which changed state
//!   at record time, the first two raised `InvalidImageLayout` and read wrong values);
//! - every resource belongs to one context: using it with another (even one sharing the
//!   device) is an error naming both (core v2 crashed inside the validation layer, or read
//!   the other device's memory);
//! - a steady frame loop creates no Vulkan object after its first frame (core v2 created a
//!   command pool, a query pool and a readback buffer per recording).

mod common;

use ash::vk;
use common::{assert_clean, context, shutdown, with_gpu};
use vkshade::gpu::{
    AccessType as A, AliasGroup, AliasMember, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, Location, Resource,
};
use vkshade::shaders::spirv;

const W: u32 = 16;

fn rgba32f(ctx: &Context, name: &str) -> vkshade::Result<Image> {
    Image::new(
        ctx,
        name,
        ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [W, W]).usage(
            vk::ImageUsageFlags::TRANSFER_DST
                | vk::ImageUsageFlags::TRANSFER_SRC
                | vk::ImageUsageFlags::SAMPLED,
        ),
    )
}

/// Clears `img` to `v`, submits and waits.
fn clear(ctx: &Context, img: &Image, v: f32) -> vkshade::Result<()> {
    let mut rec = ctx.recorder("clear")?;
    rec.clear_image(img, img.all(), [v; 4])?;
    rec.submit_and_wait()?;
    Ok(())
}

/// The first texel's red channel, read back by its own recording.
fn read(ctx: &Context, img: &Image) -> vkshade::Result<f32> {
    let mut rec = ctx.recorder("read")?;
    let rb = rec.read_back_image(img, ImageRegion::whole(img.desc()))?;
    rec.submit_and_wait()?;
    Ok(rb.to_vec::<f32>()?[0])
}

/// A frame that fails half-way (a `?` after some uses) drops its recorder: the image's
/// tracked layout must stay what the GPU last saw. Core v2 kept the dropped recording's
/// SHADER_READ_ONLY layout, so the next readback transitioned from the wrong layout.
#[test]
fn a_dropped_recording_leaves_the_tracked_state_as_it_was() {
    with_gpu(|ctx| {
        let img = rgba32f(ctx, "img")?;
        clear(ctx, &img, 1.0)?;
        assert_eq!(read(ctx, &img)?, 1.0);
        for _ in 0..3 {
            let mut aborted = ctx.recorder("aborted frame")?;
            aborted.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
            aborted.clear_image(&img, img.all(), [5.0; 4])?;
            aborted.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
            drop(aborted);
        }
        assert_eq!(read(ctx, &img)?, 1.0, "the dropped clears never ran");
        clear(ctx, &img, 2.0)?;
        assert_eq!(read(ctx, &img)?, 2.0);
        Ok(())
    });
}

/// Recording A (clear) then B (read back), submitting B first: B runs on the state the
/// submissions before it left (the old contents), A after it; then a third recording sees
/// A's clear. Core v2 tracked B after A and read with a layout error.
#[test]
fn recordings_submitted_out_of_order_are_joined_at_submission() {
    with_gpu(|ctx| {
        let img = rgba32f(ctx, "img")?;
        clear(ctx, &img, 1.0)?;
        let mut a = ctx.recorder("A clear")?;
        a.clear_image(&img, img.all(), [3.0; 4])?;
        let mut b = ctx.recorder("B read")?;
        let rb = b.read_back_image(&img, ImageRegion::whole(img.desc()))?;
        b.submit_and_wait()?;
        assert_eq!(rb.to_vec::<f32>()?[0], 1.0, "B ran before A's clear");
        a.submit_and_wait()?;
        assert_eq!(read(ctx, &img)?, 3.0, "A's clear is visible after it");

        // Buffers: A fills, B reads, B submitted first without waiting, then A.
        let buf = Buffer::new(
            ctx,
            "buf",
            BufferDesc::storage(256)
                .usage(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC),
        )?;
        let mut init = ctx.recorder("init")?;
        init.fill_buffer(&buf, 7)?;
        init.submit()?;
        let mut a = ctx.recorder("A fill")?;
        a.fill_buffer(&buf, 9)?;
        let mut b = ctx.recorder("B read")?;
        let rb = b.read_back(&buf)?;
        let sb = b.submit()?;
        let sa = a.submit()?;
        let mut c = ctx.recorder("C read")?;
        let rc = c.read_back(&buf)?;
        c.submit_and_wait()?;
        sb.wait()?;
        sa.wait()?;
        assert_eq!(rb.to_vec::<u32>()?[0], 7);
        assert_eq!(rc.to_vec::<u32>()?[63], 9);
        Ok(())
    });
}

/// Many interleaved recordings on one image, submitted in a shuffled order: every readback
/// sees the clear submitted last before it.
#[test]
fn shuffled_submissions_read_what_was_submitted_before_them() {
    with_gpu(|ctx| {
        let img = rgba32f(ctx, "img")?;
        clear(ctx, &img, 0.0)?;
        // (is a clear, value): recorded in this order, submitted in `order`.
        let plan: Vec<(bool, f32)> = (0..12).map(|i| (i % 3 != 2, i as f32)).collect();
        let mut recs = Vec::new();
        for &(is_clear, v) in &plan {
            let mut r = ctx.recorder("step")?;
            let rb = if is_clear {
                r.clear_image(&img, img.all(), [v; 4])?;
                None
            } else {
                Some(r.read_back_image(&img, ImageRegion::whole(img.desc()))?)
            };
            recs.push((Some(r), rb));
        }
        let order = [5, 0, 11, 2, 7, 1, 9, 3, 10, 4, 8, 6];
        let mut last = 0.0f32;
        let mut subs = Vec::new();
        for &i in &order {
            let r = recs[i].0.take().expect("submitted once");
            subs.push(r.submit()?);
            if plan[i].0 {
                last = plan[i].1;
            } else {
                subs.pop().expect("just pushed").wait()?;
                let got = recs[i].1.as_ref().expect("a readback").to_vec::<f32>()?[0];
                assert_eq!(
                    got, last,
                    "readback {i} sees the last clear submitted before it"
                );
            }
        }
        for s in subs {
            s.wait()?;
        }
        Ok(())
    });
}

/// A recording into a caller's command buffer joins at first use and commits at finish;
/// if another recording commits the same image in between, finish refuses, naming it, and
/// the tracked state stays the other recording's.
#[test]
fn a_stale_join_into_a_callers_command_buffer_is_refused() {
    let ctx = context();
    let result = (|| -> vkshade::Result<()> {
        let img = rgba32f(&ctx, "shared image")?;
        clear(&ctx, &img, 1.0)?;
        let device = ctx.raw_device().clone();
        // SAFETY: plain object creation; the command buffer is never submitted (the
        // recording is refused) and the pool is destroyed after the recorder is gone.
        unsafe {
            let pool = device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family()),
                    None,
                )
                .expect("command pool");
            let cmd = device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(pool)
                        .command_buffer_count(1),
                )
                .expect("command buffer")[0];
            device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
                .expect("begin");
            let mut ext = ctx.record_into(cmd, "renderer frame")?;
            ext.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
            // Another recording commits the image meanwhile.
            clear(&ctx, &img, 2.0)?;
            let e = ext.finish().expect_err("a stale join is refused");
            assert!(e.to_string().contains("shared image"), "{e}");
            device.end_command_buffer(cmd).expect("end");
            device.destroy_command_pool(pool, None);
        }
        assert_eq!(read(&ctx, &img)?, 2.0, "the clear's state stands");
        Ok(())
    })();
    let messages = shutdown(ctx);
    result.unwrap();
    assert_clean(&messages);
}

fn scale_push(a: f32, b: f32, n: u32) -> Vec<u8> {
    [a.to_le_bytes(), b.to_le_bytes(), n.to_le_bytes()].concat()
}

/// Asserts `e` is the wrong-context error and names both contexts and the resource.
fn assert_wrong_context(e: vkshade::Error, resource: &str, a: &Context, b: &Context) {
    let text = e.to_string();
    assert!(
        matches!(e, vkshade::Error::WrongContext { .. }),
        "not a WrongContext error: {text}"
    );
    for want in [
        resource.to_string(),
        format!("context #{}", a.id()),
        format!("context #{}", b.id()),
    ] {
        assert!(text.contains(&want), "'{want}' missing from: {text}");
    }
}

/// A buffer of context A bound into B's pipeline, copied, filled or read back by B's
/// recorder, named in B's barrier, or placed in A's alias group by B: each an error naming
/// both contexts, and nothing is recorded (both shut down clean).
#[test]
fn resources_of_another_context_are_refused() {
    let a = context();
    let b = context();
    let result = (|| -> vkshade::Result<()> {
        let n = 256u32;
        let xa = a.upload_buffer(
            "x of A",
            BufferDesc::storage(n as u64 * 4),
            &vec![1.0f32; n as usize],
        )?;
        let ya = Buffer::new(&a, "y of A", BufferDesc::storage(n as u64 * 4))?;
        let yb = Buffer::new(
            &b,
            "y of B",
            BufferDesc::storage(n as u64 * 4).usage(vk::BufferUsageFlags::TRANSFER_DST),
        )?;
        let scale_b =
            ComputePipeline::from_spirv(&b, "test/chain_scale", spirv("test/chain_scale")?)?;
        let e = scale_b
            .bind(&[
                ("src", Resource::Buffer(&xa)),
                ("dst", Resource::Buffer(&yb)),
            ])
            .expect_err("a buffer of A in B's pipeline");
        assert_wrong_context(e, "x of A", &a, &b);

        let mut rec = b.recorder("B")?;
        let e = rec
            .copy_buffer(&xa, 0, &yb, 0, 64)
            .expect_err("copy from A's buffer");
        assert_wrong_context(e, "x of A", &a, &b);
        let e = rec.fill_buffer(&ya, 0).expect_err("fill of A's buffer");
        assert_wrong_context(e, "y of A", &a, &b);
        let e = rec.read_back(&xa).expect_err("readback of A's buffer");
        assert_wrong_context(e, "x of A", &a, &b);
        let e = rec
            .use_buffer(&xa, A::ComputeShaderReadOther)
            .expect_err("declared use of A's buffer");
        assert_wrong_context(e, "x of A", &a, &b);
        let img = rgba32f(&a, "image of A")?;
        let e = rec
            .clear_image(&img, img.all(), [0.0; 4])
            .expect_err("clear of A's image");
        assert_wrong_context(e, "image of A", &a, &b);
        let e = rec
            .barrier(&[vkshade::gpu::Barrier::image(
                &img,
                A::TransferWrite,
                A::TransferRead,
            )])
            .expect_err("barrier on A's image");
        assert_wrong_context(e, "image of A", &a, &b);
        // B's recorder still works for B's resources.
        rec.fill_buffer(&yb, 3)?;
        rec.submit_and_wait()?;

        let member = BufferDesc::storage(1024);
        let group = AliasGroup::new(
            &a,
            "group of A",
            Location::Device,
            &[AliasMember::Buffer(&member)],
        )?;
        let e = Buffer::in_group(&b, "member", member, &group)
            .expect_err("B's buffer in A's alias group");
        assert_wrong_context(e, "group of A", &b, &a);
        drop(group);
        drop((xa, ya, yb, scale_b, img));
        Ok(())
    })();
    let (ma, mb) = (shutdown(a), shutdown(b));
    result.unwrap();
    assert_clean(&ma);
    assert_clean(&mb);
}

/// Two contexts on one device (`external_handles` + `from_external`) have separate
/// timelines: core v2 let B's submission use A's buffer and compared A's timeline with B's
/// value when the buffer was dropped (destroyed in use, VUID-vkDestroyBuffer-buffer-00922).
/// Now B refuses A's buffer.
#[test]
fn contexts_sharing_a_device_refuse_each_others_resources() {
    let a = context();
    let result = (|| -> vkshade::Result<()> {
        // SAFETY: A's handles outlive B (B is shut down below, before A).
        let b = unsafe { Context::from_external(a.external_handles())? };
        let xa = a.upload_buffer("x of A", BufferDesc::storage(4096), &vec![2.0f32; 1024])?;
        let scale_b =
            ComputePipeline::from_spirv(&b, "test/chain_scale", spirv("test/chain_scale")?)?;
        let yb = Buffer::new(&b, "y of B", BufferDesc::storage(4096))?;
        let e = scale_b
            .bind(&[
                ("src", Resource::Buffer(&xa)),
                ("dst", Resource::Buffer(&yb)),
            ])
            .expect_err("A's buffer in B's pipeline");
        assert_wrong_context(e, "x of A", &a, &b);
        let xb = b.upload_buffer("x of B", BufferDesc::storage(4096), &vec![2.0f32; 1024])?;
        let bind = scale_b.bind(&[
            ("src", Resource::Buffer(&xb)),
            ("dst", Resource::Buffer(&yb)),
        ])?;
        let mut rec = b.recorder("B")?;
        rec.dispatch_invocations_tracked(
            &scale_b,
            &bind,
            &scale_push(2.0, 0.0, 1024),
            [1024, 1, 1],
        )?;
        let rb = rec.read_back(&yb)?;
        rec.submit_and_wait()?;
        assert_eq!(rb.to_vec::<f32>()?[1023], 4.0);
        drop((xa, xb, yb, bind, scale_b, rb));
        let leftover = b.shutdown()?;
        assert!(leftover.is_empty(), "{leftover:?}");
        Ok(())
    })();
    let messages = shutdown(a);
    result.unwrap();
    assert_clean(&messages);
}

/// A renderer's frame loop (upload, dispatch, readback, timestamps, a fresh recorder per
/// frame, two frames in flight) creates no Vulkan object and no memory after its first
/// frames: command pools, query pools and readback buffers are reused. Core v2 created a
/// command pool, a query pool and a readback buffer (with its memory) per frame.
#[test]
fn a_steady_frame_loop_creates_nothing_after_warm_up() {
    with_gpu(|ctx| {
        let n = 4096u32;
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let x = Buffer::new(
            ctx,
            "x",
            BufferDesc::storage(n as u64 * 4).usage(vk::BufferUsageFlags::TRANSFER_DST),
        )?;
        let y = Buffer::new(ctx, "y", BufferDesc::storage(n as u64 * 4))?;
        let bind = scale.bind(&[("src", Resource::Buffer(&x)), ("dst", Resource::Buffer(&y))])?;
        let mut in_flight = std::collections::VecDeque::new();
        let mut frame = |i: u32| -> vkshade::Result<()> {
            let mut rec = ctx.recorder("frame")?;
            rec.begin_pass("frame");
            rec.upload(&x, 0, &vec![i as f32; n as usize])?;
            rec.dispatch_invocations_tracked(&scale, &bind, &scale_push(2.0, 1.0, n), [n, 1, 1])?;
            let rb = rec.read_back_range(&y, 0, 64)?;
            rec.end_pass();
            in_flight.push_back((rec.submit()?, rb, i));
            if in_flight.len() > 2 {
                let (s, rb, j) = in_flight.pop_front().expect("in flight");
                let t = s.wait()?;
                assert!(t.get("frame").is_some_and(|ms| ms >= 0.0));
                assert_eq!(rb.to_vec::<f32>()?[3], 2.0 * j as f32 + 1.0);
            }
            Ok(())
        };
        for i in 0..6 {
            frame(i)?;
        }
        let warm = ctx.creation_counts();
        let memory = ctx.memory_report();
        for i in 6..40 {
            frame(i)?;
        }
        assert_eq!(ctx.creation_counts(), warm, "objects created after warm-up");
        assert_eq!(ctx.memory_report().allocations, memory.allocations);
        assert!(warm.command_pools <= 4 && warm.query_pools <= 4, "{warm:?}");
        Ok(())
    });
}

/// Found by tests/fuzz_api.rs: a sampled read of an image nothing had written transitioned it
/// from UNDEFINED to SHADER_READ_ONLY (UNASSIGNED-BestPractices-TransitionUndefinedToReadOnly,
/// and the read sees garbage). The submission is refused, changing no tracked state; after a
/// clear the same read is clean.
#[test]
fn reading_an_image_nothing_wrote_is_refused_at_submission() {
    with_gpu(|ctx| {
        let img = rgba32f(ctx, "never written")?;
        let mut rec = ctx.recorder("reads garbage")?;
        rec.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
        let e = rec.submit().expect_err("a read of undefined contents");
        assert!(e.to_string().contains("'never written'"), "{e}");
        let mut rec = ctx.recorder("discards for a read")?;
        rec.discard_image(&img, img.all(), A::ComputeShaderReadSampledImage)
            .expect_err("discarding for a read");
        drop(rec);
        clear(ctx, &img, 4.0)?;
        let mut rec = ctx.recorder("reads the clear")?;
        rec.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
        rec.submit_and_wait()?;
        assert_eq!(read(ctx, &img)?, 4.0);
        Ok(())
    });
}

/// Found by tests/fuzz_api.rs: write, read, write of one buffer in one recording. The second
/// write waited for the read with an execution-only barrier, so the first write was never
/// made visible to it: SYNC-HAZARD-WRITE-AFTER-WRITE. The barrier now carries the memory
/// dependency along the chain.
#[test]
fn write_read_write_of_a_buffer_is_hazard_free() {
    with_gpu(|ctx| {
        let buf = Buffer::new(
            ctx,
            "buf",
            BufferDesc::storage(1024)
                .usage(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC),
        )?;
        let mut rec = ctx.recorder("w r w")?;
        rec.fill_buffer(&buf, 1)?;
        let first = rec.read_back(&buf)?;
        rec.fill_buffer(&buf, 2)?;
        let second = rec.read_back(&buf)?;
        rec.submit_and_wait()?;
        assert_eq!(first.to_vec::<u32>()?[0], 1);
        assert_eq!(second.to_vec::<u32>()?[255], 2);
        Ok(())
    });
}

/// Found by tests/fuzz_api.rs: two declared uses of one image with no command between them
/// (a storage write by a dispatch, then a sampled read, then a storage read) queued both
/// barriers into one vkCmdPipelineBarrier2, where barriers do not chain: the second
/// transition did not wait for the first (SYNC-HAZARD-WRITE-AFTER-WRITE on the layout
/// transition). A second barrier on a resource now starts a new barrier command.
#[test]
fn back_to_back_uses_of_one_image_are_chained() {
    with_gpu(|ctx| {
        let img = rgba32f(ctx, "img")?;
        let mut rec = ctx.recorder("back to back")?;
        rec.clear_image(&img, img.all(), [1.0; 4])?;
        rec.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
        rec.use_image(&img, img.all(), A::TransferRead)?;
        rec.use_image(&img, img.all(), A::ComputeShaderReadSampledImage)?;
        let rb = rec.read_back_image(&img, ImageRegion::whole(img.desc()))?;
        rec.submit_and_wait()?;
        assert_eq!(rb.to_vec::<f32>()?[0], 1.0);
        Ok(())
    });
}

/// Found by tests/fuzz_api.rs (seeds 90 and 194): a dispatch writes a storage image, a
/// declared read follows with no command that reads, then a readback transitions the image.
/// The tracker had dropped the write from the state after the read's barrier, so the
/// transition's barrier named only the read as its source, and synchronization validation
/// reported SYNC-HAZARD-WRITE-AFTER-WRITE on the transition. The last write now stays a
/// source until the next write.
#[test]
fn a_transition_after_a_declared_read_still_waits_for_the_write() {
    with_gpu(|ctx| {
        let storage = |name: &str| {
            Image::new(
                ctx,
                name,
                ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [W, W]).usage(
                    vk::ImageUsageFlags::STORAGE
                        | vk::ImageUsageFlags::SAMPLED
                        | vk::ImageUsageFlags::TRANSFER_SRC
                        | vk::ImageUsageFlags::TRANSFER_DST,
                ),
            )
        };
        let a = storage("a")?;
        let b = storage("b")?;
        let c = storage("c")?;
        clear(ctx, &a, 1.0)?;
        clear(ctx, &c, 1.0)?;
        let p = ComputePipeline::from_spirv(ctx, "test/pingpong", spirv("test/pingpong")?)?;
        let bind = p.bind(&[
            ("src", Resource::StorageImage((&a).into())),
            ("dst", Resource::StorageImage((&b).into())),
        ])?;
        let push = [
            W.to_le_bytes(),
            W.to_le_bytes(),
            0.5f32.to_le_bytes(),
            0.25f32.to_le_bytes(),
        ]
        .concat();
        let mut rec = ctx.recorder("write, declared read, transition")?;
        rec.begin_pass("p");
        rec.dispatch_invocations_tracked(&p, &bind, &push, [W, W, 1])?;
        rec.end_pass();
        rec.use_image(&b, b.all(), A::ComputeShaderReadOther)?;
        rec.clear_image(&c, c.all(), [0.5; 4])?;
        let rb = rec.read_back_image(&b, ImageRegion::whole(b.desc()))?;
        rec.submit_and_wait()?;
        assert_eq!(rb.to_vec::<f32>()?[0], 0.75);
        Ok(())
    });
}

/// One buffer bound to a write binding and then to a read binding of one dispatch (an
/// in-place kernel) is one use that writes. Applied binding by binding, the read's barrier
/// was queued before the dispatch and the tracker took the read for the last access, so a
/// later dispatch reading the buffer the same way got no barrier after the write
/// (SYNC-HAZARD-READ-AFTER-WRITE).
#[test]
fn a_buffer_bound_twice_is_one_use() {
    with_gpu(|ctx| {
        let n = 256u32;
        let desc = BufferDesc::storage(4 * n as u64)
            .usage(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC);
        let buf = Buffer::new(ctx, "in place", desc)?;
        let out = Buffer::new(ctx, "out", desc)?;
        let in_place = ComputePipeline::from_spirv(ctx, "test/in_place", spirv("test/in_place")?)?;
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let twice = in_place.bind(&[
            ("dst", Resource::Buffer(&buf)),
            ("src", Resource::Buffer(&buf)),
        ])?;
        let read = scale.bind(&[
            ("src", Resource::Buffer(&buf)),
            ("dst", Resource::Buffer(&out)),
        ])?;
        let x: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let mut rec = ctx.recorder("bound twice")?;
        rec.upload(&buf, 0, &x)?;
        rec.dispatch_invocations_tracked(&in_place, &twice, &scale_push(2.0, 1.0, n), [n, 1, 1])?;
        rec.dispatch_invocations_tracked(&scale, &read, &scale_push(3.0, 0.0, n), [n, 1, 1])?;
        let rb = rec.read_back(&out)?;
        rec.submit_and_wait()?;
        let y = rb.to_vec::<f32>()?;
        for (i, v) in y.iter().enumerate() {
            assert_eq!(*v, 3.0 * (2.0 * i as f32 + 1.0), "element {i}");
        }
        Ok(())
    });
}
