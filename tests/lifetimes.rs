//! The holes the core-v2 review found, each as a test under validation, plus memory
//! placement, alias groups, wrapped handles, the staging ring and declared accesses:
//! - a leaked (`mem::forget`) submission must not let its resources be destroyed early;
//! - host reads of mapped memory see device writes (copy-out, after the last use);
//! - host writes wait for submitted work that uses the buffer;
//! - a wrong declared use is caught by synchronization validation; collected barriers
//!   recorded by the caller are enough.

mod common;

use ash::vk;
use common::{assert_clean, context, shutdown, with_gpu};
use vkshade::gpu::{
    AccessSet, AccessType as A, AliasGroup, AliasMember, AliasUse, BarrierMode, Buffer, BufferDesc,
    ComputePipeline, Context, ContextDesc, Dedicated, Image, ImageDesc, ImageRegion, Location,
    MemoryConfig, Placement, Resource,
};
use vkshade::shaders::spirv;

const N: u32 = 4096;

fn scale_push(a: f32, b: f32, n: u32) -> Vec<u8> {
    [a.to_le_bytes(), b.to_le_bytes(), n.to_le_bytes()].concat()
}

fn add_push(c: f32, n: u32) -> Vec<u8> {
    [c.to_le_bytes(), n.to_le_bytes()].concat()
}

#[test]
fn forgotten_submission_keeps_what_it_uses_alive() {
    let ctx = context();
    let value = (|| -> vkshade::Result<u64> {
        let scale =
            ComputePipeline::from_spirv(&ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let x: Vec<f32> = (0..N).map(|i| i as f32).collect();
        let src = ctx.upload_buffer("x", BufferDesc::storage(N as u64 * 4), &x)?;
        let dst = Buffer::new(&ctx, "y", BufferDesc::storage(N as u64 * 4))?;
        let bind = scale.bind(&[
            ("src", Resource::Buffer(&src)),
            ("dst", Resource::Buffer(&dst)),
        ])?;
        let mut rec = ctx.recorder("forgotten")?;
        for _ in 0..50 {
            rec.dispatch_invocations_tracked(&scale, &bind, &scale_push(2.0, 1.0, N), [N, 1, 1])?;
        }
        let submission = rec.submit()?;
        let value = submission.value();
        std::mem::forget(submission);
        // The review measured VUID-vkDestroyDescriptorPool-descriptorPool-00303 and
        // VUID-vkDestroyPipeline-pipeline-00765 here: objects destroyed while in use.
        drop(bind);
        drop(scale);
        drop((src, dst));
        assert!(ctx.maintain() > 0 || ctx.completed_value() >= value);
        ctx.wait_for(value)?;
        assert_eq!(
            ctx.maintain(),
            0,
            "everything retired once the work completed"
        );
        Ok(value)
    })()
    .unwrap();
    assert!(value > 0);
    let messages = ctx.messages().take();
    assert_clean(&messages);
    // The forgotten submission still holds the context: shutdown reports it, frees nothing.
    let e = ctx.shutdown().unwrap_err();
    assert!(e.to_string().contains("still alive"), "{e}");
}

#[test]
fn dropping_everything_before_the_work_completes_is_safe() {
    with_gpu(|ctx| {
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let src = Buffer::new(ctx, "x", BufferDesc::storage(N as u64 * 4))?;
        let dst = Buffer::new(ctx, "y", BufferDesc::storage(N as u64 * 4))?;
        let bind = scale.bind(&[
            ("src", Resource::Buffer(&src)),
            ("dst", Resource::Buffer(&dst)),
        ])?;
        let mut rec = ctx.recorder("dropped early")?;
        rec.fill_buffer(&src, 0)?;
        rec.dispatch_invocations_tracked(&scale, &bind, &scale_push(2.0, 1.0, N), [N, 1, 1])?;
        let submission = rec.submit()?;
        drop((bind, scale, src, dst, submission)); // the submission's drop does not wait
        ctx.wait_idle()?;
        assert_eq!(ctx.maintain(), 0);
        Ok(())
    });
}

#[test]
fn mapped_reads_see_every_device_write() {
    with_gpu(|ctx| {
        let buf = Buffer::new(ctx, "readback", BufferDesc::readback(1024))?;
        for value in [0xdead_beefu32, 7, 0x1234_5678] {
            let mut rec = ctx.recorder("fill")?;
            rec.fill_buffer(&buf, value)?;
            rec.submit_and_wait()?;
            // Copy-out after the last use: never a slice aliasing memory the device writes.
            let got: Vec<u32> = buf.read()?;
            assert!(
                got.iter().all(|&v| v == value),
                "{:#x} vs {value:#x}",
                got[0]
            );
        }
        // A device-local buffer has no mapping: a clear error, not a panic.
        let local = Buffer::new(ctx, "local", BufferDesc::storage(64))?;
        let e = local.read::<u32>().unwrap_err();
        assert!(e.to_string().contains("not host-visible"), "{e}");
        Ok(())
    });
}

/// The work that reads the buffer is held back by a timeline semaphore that only the host
/// signals, so it cannot have finished when `write` is called: a `write` that does not wait
/// returns while the gate is still closed and fails here (before, on a fast device the
/// dispatches finished before the write and the check held whether or not it waited).
/// Catches: `Buffer::write` without its wait (planted: "write returned before the work that
/// reads the buffer").
#[test]
fn host_writes_wait_for_submitted_work_that_uses_the_buffer() {
    with_gpu(|ctx| {
        let n = 1u32 << 16;
        let upload = Buffer::new(ctx, "upload", BufferDesc::upload(n as u64 * 4))?;
        let a: Vec<f32> = (0..n).map(|i| i as f32).collect();
        upload.write(0, &a)?;
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let out = Buffer::new(ctx, "out", BufferDesc::storage(n as u64 * 4))?;
        let bind = scale.bind(&[
            ("src", Resource::Buffer(&upload)),
            ("dst", Resource::Buffer(&out)),
        ])?;
        let device = ctx.raw_device().clone();
        let mut kind = vk::SemaphoreTypeCreateInfo::default()
            .semaphore_type(vk::SemaphoreType::TIMELINE)
            .initial_value(0);
        // SAFETY: a valid device; the semaphore is destroyed below, after the work that
        // waits on it has completed.
        let gate = unsafe {
            device.create_semaphore(
                &vk::SemaphoreCreateInfo::default().push_next(&mut kind),
                None,
            )
        }
        .map_err(|result| vkshade::Error::Vk {
            call: "vkCreateSemaphore",
            result,
        })?;
        let wait = [vk::SemaphoreSubmitInfo::default()
            .semaphore(gate)
            .value(1)
            .stage_mask(vk::PipelineStageFlags2::COMPUTE_SHADER)];
        let mut rec = ctx.recorder("reads the upload buffer")?;
        rec.dispatch_invocations_tracked(&scale, &bind, &scale_push(1.0, 0.0, n), [n, 1, 1])?;
        let rb = rec.read_back(&out)?;
        // SAFETY: `gate` is a live timeline semaphore of this device, not the context's;
        // its value 1 is signalled from the host below (wait-before-signal is allowed for
        // timeline semaphores), and it outlives the submission.
        let submission = unsafe { rec.submit_with(&wait, &[])? };
        let written = std::sync::atomic::AtomicBool::new(false);
        std::thread::scope(|scope| -> vkshade::Result<()> {
            let writer = scope.spawn(|| {
                let r = upload.write(0, &vec![-1.0f32; n as usize]);
                written.store(true, std::sync::atomic::Ordering::SeqCst);
                r
            });
            // The writer has had ample time to copy 256 KiB if it does not wait; the gate is
            // still closed, so the work cannot have run and a waiting write cannot be done.
            std::thread::sleep(std::time::Duration::from_millis(200));
            let early = written.load(std::sync::atomic::Ordering::SeqCst);
            assert!(
                !submission.is_complete(),
                "the gated work ran before the gate opened"
            );
            // SAFETY: signals our own timeline semaphore from 0 to 1.
            unsafe {
                device
                    .signal_semaphore(&vk::SemaphoreSignalInfo::default().semaphore(gate).value(1))
            }
            .map_err(|result| vkshade::Error::Vk {
                call: "vkSignalSemaphore",
                result,
            })?;
            writer.join().expect("writer thread")?;
            assert!(
                !early,
                "write returned before the work that reads the buffer"
            );
            Ok(())
        })?;
        assert!(
            submission.is_complete(),
            "write returned before the work completed"
        );
        submission.wait()?;
        // SAFETY: the only submission waiting on `gate` has completed.
        unsafe { device.destroy_semaphore(gate, None) };
        let got: Vec<f32> = rb.to_vec()?;
        assert_eq!(got, a, "the dispatch saw the new contents");
        Ok(())
    });
}

#[test]
fn placement_block_sizes_and_memory_reports() {
    let desc = ContextDesc {
        memory: MemoryConfig {
            device_block_bytes: 4 << 20,
            host_block_bytes: 4 << 20,
            staging_ring_bytes: 1 << 20,
        },
        ..ContextDesc::validated()
    };
    common::hold_gpu();
    let ctx = Context::new(&desc).unwrap();
    (|| -> vkshade::Result<()> {
        let before = ctx.memory_report();
        let small = Buffer::new(&ctx, "small", BufferDesc::storage(4096))?;
        let r1 = ctx.memory_report();
        assert_eq!(r1.allocations, before.allocations + 1);
        assert!(r1.used_bytes >= before.used_bytes + 4096);
        assert!(
            r1.reserved_bytes >= 4 << 20 && r1.reserved_bytes < 64 << 20,
            "a 4 MiB block, not gpu-allocator's 256 MiB default: {r1:?}"
        );
        let dedicated = Buffer::new(
            &ctx,
            "dedicated",
            BufferDesc::storage(3 << 20).placement(Placement::DEVICE.dedicated(Dedicated::Always)),
        )?;
        let r2 = ctx.memory_report();
        assert!(
            r2.reserved_bytes >= r1.reserved_bytes + (3 << 20),
            "a dedicated allocation is a block of its own: {r1:?} -> {r2:?}"
        );
        let upload = Buffer::new(&ctx, "upload", BufferDesc::upload(256))?;
        assert_eq!(upload.placement().location, Location::Upload);
        upload.write(0, &[1u32, 2, 3])?;
        let mut back = [0u32; 3];
        upload.read_into(0, &mut back)?;
        assert_eq!(back, [1, 2, 3]);
        assert!(r2.peak_used_bytes >= r2.used_bytes);
        drop((small, dedicated, upload));
        ctx.maintain();
        let after = ctx.memory_report();
        assert_eq!(after.allocations, before.allocations);
        assert_eq!(after.used_bytes, before.used_bytes);
        Ok(())
    })()
    .unwrap();
    assert_clean(&shutdown(ctx));
}

#[test]
fn alias_group_members_share_memory_with_the_barrier_aliasing_needs() {
    with_gpu(|ctx| {
        let a_desc = ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [64, 64]);
        let b_desc = ImageDesc::d2(vk::Format::R32_SFLOAT, [128, 32]);
        let c_desc = BufferDesc::storage(16 * 1024);
        let group = AliasGroup::new(
            ctx,
            "transient",
            Location::Device,
            &[
                AliasMember::Image(&a_desc),
                AliasMember::Image(&b_desc),
                AliasMember::Buffer(&c_desc),
            ],
        )?;
        assert!(group.size() >= 64 * 64 * 16, "sized for the largest member");
        let before = ctx.memory_report().allocations;
        let a = Image::in_group(ctx, "a", a_desc, &group)?;
        let b = Image::in_group(ctx, "b", b_desc, &group)?;
        let c = Buffer::in_group(ctx, "c", c_desc, &group)?;
        assert_eq!(
            ctx.memory_report().allocations,
            before,
            "members allocate nothing"
        );
        let mut rec = ctx.recorder("aliasing")?;
        rec.clear_image(&a, a.all(), [1.0, 2.0, 3.0, 4.0])?;
        let ra = rec.read_back_image(&a, ImageRegion::whole(&a_desc))?;
        rec.alias_switch(
            A::TransferRead,
            AliasUse::Image(&b, A::TransferWrite.into()),
        )?;
        rec.clear_image(&b, b.all(), [0.25, 0.0, 0.0, 0.0])?;
        let rb = rec.read_back_image(&b, ImageRegion::whole(&b_desc))?;
        rec.alias_switch(
            A::TransferRead,
            AliasUse::Buffer(&c, A::TransferWrite.into()),
        )?;
        rec.fill_buffer(&c, 5)?;
        let rc = rec.read_back(&c)?;
        rec.submit_and_wait()?;
        assert!(
            ra.to_vec::<[f32; 4]>()?
                .iter()
                .all(|t| *t == [1.0, 2.0, 3.0, 4.0])
        );
        assert!(rb.to_vec::<f32>()?.iter().all(|&v| v == 0.25));
        assert!(rc.to_vec::<u32>()?.iter().all(|&v| v == 5));
        // A member the group was not sized for is refused.
        let e = Buffer::in_group(ctx, "too big", BufferDesc::storage(1 << 22), &group).unwrap_err();
        assert!(e.to_string().contains("does not fit alias group"), "{e}");
        Ok(())
    });
}

#[test]
fn wrapped_raw_handles_are_bound_and_never_destroyed_by_vkshade() {
    with_gpu(|ctx| {
        // Stand-ins for a renderer's own objects: vkshade handles whose raw handles are
        // wrapped a second time (the owners outlive the wrappers' use).
        let owner_buf = Buffer::new(ctx, "renderer buffer", BufferDesc::storage(256))?;
        let owner_img = Image::new(
            ctx,
            "renderer image",
            ImageDesc::d2(vk::Format::R32_SFLOAT, [8, 8]),
        )?;
        // SAFETY: same device, same description; the owners stay alive past the last use.
        let (wrapped_buf, wrapped_img) = unsafe {
            (
                Buffer::from_raw(ctx, "wrapped buffer", owner_buf.raw(), *owner_buf.desc())?,
                Image::from_raw(ctx, "wrapped image", owner_img.raw(), *owner_img.desc())?,
            )
        };
        let mut rec = ctx.recorder("wrapped")?;
        rec.upload(&wrapped_buf, 0, &[9u32; 64])?;
        rec.clear_image(&wrapped_img, wrapped_img.all(), [3.5, 0.0, 0.0, 0.0])?;
        let value = rec.submit()?.value();
        ctx.wait_for(value)?;
        drop((wrapped_buf, wrapped_img)); // destroys nothing
        owner_img.assume_access(owner_img.all(), A::TransferWrite)?;
        let got_buf: Vec<u32> = ctx.read_buffer(&owner_buf)?;
        assert!(got_buf.iter().all(|&v| v == 9));
        let mut rec = ctx.recorder("read owner image")?;
        let rb = rec.read_back_image(&owner_img, ImageRegion::whole(owner_img.desc()))?;
        rec.submit_and_wait()?;
        assert!(rb.to_vec::<f32>()?.iter().all(|&v| v == 3.5));
        Ok(())
    });
}

#[test]
fn a_large_volume_streams_through_a_small_staging_ring() {
    let ring = 8u64 << 20;
    let desc = ContextDesc {
        memory: MemoryConfig {
            staging_ring_bytes: ring,
            ..MemoryConfig::default()
        },
        ..ContextDesc::validated()
    };
    common::hold_gpu();
    let ctx = Context::new(&desc).unwrap();
    (|| -> vkshade::Result<()> {
        // 128 x 128 x 400 R32F = 25 MiB.
        let extent = [128u32, 128, 400];
        let vdesc = ImageDesc::d3(vk::Format::R32_SFLOAT, extent);
        let vol = Image::new(&ctx, "volume", vdesc)?;
        let n = (extent[0] * extent[1] * extent[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| (i % 9973) as f32).collect();
        let last = ctx.upload_image_streamed(&vol, bytemuck::cast_slice(&data), 2 << 20)?;
        ctx.wait_for(last)?;
        let peak = ctx.staging_ring_peak();
        assert!(peak <= ring && peak > 0, "ring peak {peak} bytes");
        assert_eq!(ctx.memory_report().staging_ring_bytes, ring);
        for z in [0u32, 217, 399] {
            let mut rec = ctx.recorder("read slice")?;
            let rb = rec.read_back_image(
                &vol,
                ImageRegion {
                    offset: [0, 0, z],
                    extent: [128, 128, 1],
                    ..ImageRegion::whole(&vdesc)
                },
            )?;
            rec.submit_and_wait()?;
            let slice = 128 * 128;
            assert_eq!(
                rb.to_vec::<f32>()?,
                data[z as usize * slice..(z as usize + 1) * slice],
                "slice {z}"
            );
        }
        // Small per-frame uploads reuse the ring: no growth in allocations.
        let target = Buffer::new(&ctx, "per-frame", BufferDesc::storage(64 * 1024))?;
        let allocations = ctx.memory_report().allocations;
        for frame in 0..64u32 {
            let mut rec = ctx.recorder("frame")?;
            rec.upload(&target, 0, &vec![frame; 16 * 1024])?;
            rec.submit()?;
        }
        ctx.wait_idle()?;
        assert_eq!(ctx.memory_report().allocations, allocations);
        assert_eq!(ctx.read_buffer::<u32>(&target)?[5], 63);
        Ok(())
    })()
    .unwrap();
    assert_clean(&shutdown(ctx));
}

/// Two dispatches: scale writes y, add reads it. `declare_y` is the access declared for y
/// in the scale dispatch. Returns the add's output (3.0 everywhere when the chain is
/// synchronised; a race on a real GPU otherwise).
fn chain_with_declared(
    ctx: &Context,
    declare_y: AccessSet,
    collect: bool,
) -> vkshade::Result<Vec<f32>> {
    let scale = ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
    let add = ComputePipeline::from_spirv(ctx, "test/chain_add", spirv("test/chain_add")?)?;
    let x = ctx.upload_buffer(
        "x",
        BufferDesc::storage(N as u64 * 4),
        &vec![1.0f32; N as usize],
    )?;
    let y = Buffer::new(ctx, "y", BufferDesc::storage(N as u64 * 4))?;
    let acc = ctx.upload_buffer(
        "acc",
        BufferDesc::storage(N as u64 * 4),
        &vec![0.0f32; N as usize],
    )?;
    let sb = scale.bind_declared(
        &[("src", Resource::Buffer(&x)), ("dst", Resource::Buffer(&y))],
        &[("dst", declare_y)],
    )?;
    let ab = add.bind(&[
        ("ybuf", Resource::Buffer(&y)),
        ("accbuf", Resource::Buffer(&acc)),
    ])?;
    assert!(
        sb.accesses()
            .iter()
            .any(|u| u.binding == "src" && u.access == A::ComputeShaderReadOther.into()),
        "readonly in GLSL gives a read by default: {:?}",
        sb.accesses()
    );
    let mut rec = ctx.recorder("declared chain")?;
    if collect {
        // A render graph: plan each pass from its declared uses, record the barriers,
        // then record the pass with vkshade emitting none.
        rec.set_barrier_mode(BarrierMode::Collect);
        let planned = rec.plan_dispatch(&sb)?;
        rec.record_planned(&planned)?;
        rec.dispatch_invocations_tracked(&scale, &sb, &scale_push(2.0, 1.0, N), [N, 1, 1])?;
        let planned = rec.plan_dispatch(&ab)?;
        assert!(
            planned
                .iter()
                .any(|p| p.resource == "y" && p.prev.contains(A::ComputeShaderWrite)),
            "the read-after-write on y is planned: {planned:?}"
        );
        rec.record_planned(&planned)?;
        rec.dispatch_invocations_tracked(&add, &ab, &add_push(1.0, N), [N, 1, 1])?;
        let unplanned = rec.take_collected();
        assert!(unplanned.is_empty(), "nothing unplanned: {unplanned:?}");
        rec.set_barrier_mode(BarrierMode::Emit);
    } else {
        rec.dispatch_invocations_tracked(&scale, &sb, &scale_push(2.0, 1.0, N), [N, 1, 1])?;
        rec.dispatch_invocations_tracked(&add, &ab, &add_push(1.0, N), [N, 1, 1])?;
    }
    let rb = rec.read_back(&acc)?;
    rec.submit_and_wait()?;
    rb.to_vec::<f32>()
}

#[test]
fn barriers_collected_for_the_caller_are_enough() {
    with_gpu(|ctx| {
        let out = chain_with_declared(ctx, A::ComputeShaderWrite.into(), true)?;
        assert!(out.iter().all(|&v| v == 3.0));
        Ok(())
    });
}

#[test]
fn a_wrong_declared_use_is_caught_by_synchronization_validation() {
    let ctx = context();
    // y declared as only read by the dispatch that writes it: no barrier before the add.
    let result = chain_with_declared(&ctx, A::ComputeShaderReadOther.into(), false);
    let messages = shutdown(ctx);
    let _ = result; // the values may or may not be right; the layer must object
    assert!(
        messages
            .iter()
            .any(|m| m.id_name.contains("SYNC-HAZARD-READ-AFTER-WRITE") && m.text.contains("[y]")),
        "expected a hazard on y: {messages:#?}"
    );
}

/// An indirect dispatch over a command a dispatch of the same recording writes:
/// `indirect_args` writes (groups, 1, 1), `indirect_fill` (dispatched over it, and reading
/// it as storage too) writes `groups + 7` to the first `groups` x 64 words of `out`.
/// `mode`: 0 tracked barriers, 1 planned and collected (a render graph), 2 the caller's
/// barriers and none recorded (a hazard).
fn indirect_chain(ctx: &Context, groups: u32, mode: u32) -> vkshade::Result<Vec<u32>> {
    let write =
        ComputePipeline::from_spirv(ctx, "test/indirect_args", spirv("test/indirect_args")?)?;
    let fill =
        ComputePipeline::from_spirv(ctx, "test/indirect_fill", spirv("test/indirect_fill")?)?;
    let args = Buffer::new(
        ctx,
        "args",
        BufferDesc::storage(16).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
    )?;
    let out = ctx.upload_buffer("out", BufferDesc::storage(4 * 256), &[u32::MAX; 256])?;
    let wb = write.bind(&[("args", Resource::Buffer(&args))])?;
    let fb = fill.bind(&[
        ("args", Resource::Buffer(&args)),
        ("dst", Resource::Buffer(&out)),
    ])?;
    let mut rec = ctx.recorder("indirect chain")?;
    let push = 7u32.to_le_bytes();
    match mode {
        0 => {
            rec.dispatch_tracked(&write, &wb, &groups.to_le_bytes(), [1, 1, 1])?;
            rec.dispatch_indirect_tracked(&fill, &fb, &push, &args, 0)?;
        }
        1 => {
            rec.set_barrier_mode(BarrierMode::Collect);
            let planned = rec.plan_dispatch(&wb)?;
            rec.record_planned(&planned)?;
            rec.dispatch_tracked(&write, &wb, &groups.to_le_bytes(), [1, 1, 1])?;
            let planned = rec.plan_dispatch_indirect(&fb, &args, 0)?;
            // One barrier on args for both of its reads (the command and the storage read).
            let on_args: Vec<_> = planned.iter().filter(|p| p.resource == "args").collect();
            assert_eq!(on_args.len(), 1, "{planned:?}");
            assert!(
                on_args[0].prev.contains(A::ComputeShaderWrite)
                    && on_args[0].next.contains(A::IndirectBuffer)
                    && on_args[0].next.contains(A::ComputeShaderReadOther),
                "{planned:?}"
            );
            rec.record_planned(&planned)?;
            rec.dispatch_indirect_tracked(&fill, &fb, &push, &args, 0)?;
            let unplanned = rec.take_collected();
            assert!(unplanned.is_empty(), "nothing unplanned: {unplanned:?}");
            rec.set_barrier_mode(BarrierMode::Emit);
        }
        _ => {
            rec.dispatch(&write, &wb, &groups.to_le_bytes(), [1, 1, 1])?;
            rec.dispatch_indirect(&fill, &fb, &push, &args, 0)?;
        }
    }
    let rb = rec.read_back(&out)?;
    rec.submit_and_wait()?;
    rb.to_vec::<u32>()
}

fn expect_filled(out: &[u32], groups: u32) {
    for (i, &v) in out.iter().enumerate() {
        let want = if (i as u32) < groups * 64 {
            groups + 7
        } else {
            u32::MAX
        };
        assert_eq!(v, want, "word {i}");
    }
}

#[test]
fn an_indirect_dispatch_waits_for_the_pass_that_writes_its_command() {
    with_gpu(|ctx| {
        // Three workgroups, none (a zero count dispatches nothing), then all four.
        for groups in [3, 0, 4] {
            expect_filled(&indirect_chain(ctx, groups, 0)?, groups);
        }
        Ok(())
    });
}

#[test]
fn an_indirect_dispatch_planned_by_a_render_graph_needs_nothing_more() {
    with_gpu(|ctx| {
        expect_filled(&indirect_chain(ctx, 2, 1)?, 2);
        Ok(())
    });
}

#[test]
fn an_indirect_read_without_a_barrier_is_caught_by_synchronization_validation() {
    let ctx = context();
    // The caller's barriers: none, so the command is read while the shader may still write it.
    let result = indirect_chain(&ctx, 2, 2);
    let messages = shutdown(ctx);
    let _ = result; // the values may or may not be right; the layer must object
    assert!(
        messages
            .iter()
            .any(|m| m.id_name.contains("SYNC-HAZARD-READ-AFTER-WRITE")
                && m.text.contains("[args]")
                && m.text.contains("INDIRECT_COMMAND_READ")),
        "expected a hazard on the indirect read of args: {messages:#?}"
    );
}

#[test]
fn indirect_arguments_outside_the_buffer_or_without_indirect_usage_are_refused() {
    let errors = with_gpu(|ctx| {
        let fill =
            ComputePipeline::from_spirv(ctx, "test/indirect_fill", spirv("test/indirect_fill")?)?;
        let indirect = BufferDesc::storage(16).usage(vk::BufferUsageFlags::INDIRECT_BUFFER);
        let args = Buffer::new(ctx, "args", indirect)?;
        let plain = Buffer::new(ctx, "plain", BufferDesc::storage(16))?;
        let out = Buffer::new(ctx, "out", BufferDesc::storage(4 * 256))?;
        let fb = fill.bind(&[
            ("args", Resource::Buffer(&args)),
            ("dst", Resource::Buffer(&out)),
        ])?;
        let push = 0u32.to_le_bytes();
        let mut rec = ctx.recorder("indirect refused")?;
        let mut errors = Vec::new();
        for (buffer, offset) in [(&plain, 0), (&args, 2), (&args, 8)] {
            let e = rec.dispatch_indirect_tracked(&fill, &fb, &push, buffer, offset);
            errors.push(e.err().map(|e| e.to_string()).unwrap_or_default());
        }
        let e = rec.plan_dispatch_indirect(&fb, &args, 16);
        errors.push(e.err().map(|e| e.to_string()).unwrap_or_default());
        // The last whole command in the buffer is accepted.
        rec.dispatch_indirect_tracked(&fill, &fb, &push, &args, 4)
            .map(|_| ())
            .unwrap_or_else(|e| errors.push(format!("offset 4 refused: {e}")));
        drop(rec);
        Ok(errors)
    });
    assert_eq!(errors.len(), 4, "{errors:?}");
    assert!(errors[0].contains("INDIRECT_BUFFER"), "{}", errors[0]);
    for e in &errors[1..] {
        assert!(e.contains("offset") && e.contains("'args'"), "{e}");
    }
}
