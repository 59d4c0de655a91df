//! End-to-end compute on the GPU under validation: upload, a chain of dependent dispatches
//! with barriers, readback, compared with the CPU; plus the harness's own negative tests
//! (a deliberate validation error must be caught) and bad-input handling.

mod common;

use ash::vk;
use common::{assert_clean, context, shutdown, with_gpu};
use vkshade::Error;
use vkshade::gpu::{
    AccessType as A, Barrier, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, Recorder, Resource, Shader,
};
use vkshade::shaders::spirv;

const N: u32 = 100_003; // not a multiple of the workgroup size: exercises the bounds check

fn scale_push(a: f32, b: f32, n: u32) -> Vec<u8> {
    [a.to_le_bytes(), b.to_le_bytes(), n.to_le_bytes()].concat()
}

fn add_push(c: f32, n: u32) -> Vec<u8> {
    [c.to_le_bytes(), n.to_le_bytes()].concat()
}

fn inputs() -> (Vec<f32>, Vec<f32>) {
    let x = (0..N).map(|i| ((i as f32) * 0.37).sin()).collect();
    let acc = (0..N).map(|i| (i % 17) as f32 * 0.25 - 2.0).collect();
    (x, acc)
}

/// CPU version of the chain: y = a1 x + b1; acc = acc c + y; y = a2 x + b2; acc = acc c + y.
fn cpu_chain(x: &[f32], acc: &[f32]) -> Vec<f32> {
    x.iter()
        .zip(acc)
        .map(|(&x, &acc)| {
            let y1 = 1.5 * x + 0.25;
            let acc = acc * 0.5 + y1;
            let y2 = -2.0 * x + 1.0;
            acc * 0.5 + y2
        })
        .collect()
}

struct Chain {
    scale: ComputePipeline,
    add: ComputePipeline,
    scale_bind: BindGroup,
    add_bind: BindGroup,
    acc: Buffer,
    // Kept alive for the bind groups that reference them.
    _x: Buffer,
    _y: Buffer,
}

impl Chain {
    fn new(ctx: &Context) -> vkshade::Result<Chain> {
        let (x, acc) = inputs();
        let bytes = N as u64 * 4;
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let add = ComputePipeline::from_spirv(ctx, "test/chain_add", spirv("test/chain_add")?)?;
        let x = ctx.upload_buffer("x", BufferDesc::storage(bytes), &x)?;
        let y = Buffer::new(ctx, "y", BufferDesc::storage(bytes))?;
        let acc = ctx.upload_buffer("acc", BufferDesc::storage(bytes), &acc)?;
        let scale_bind =
            scale.bind(&[("src", Resource::Buffer(&x)), ("dst", Resource::Buffer(&y))])?;
        let add_bind = add.bind(&[
            ("ybuf", Resource::Buffer(&y)),
            ("accbuf", Resource::Buffer(&acc)),
        ])?;
        Ok(Chain {
            scale,
            add,
            scale_bind,
            add_bind,
            acc,
            _x: x,
            _y: y,
        })
    }

    /// Records the four dispatches; `raw_barrier` controls the read-after-write barrier on
    /// `y` between the first scale and the first add (the negative test leaves it out).
    fn record(&self, rec: &mut Recorder, raw_barrier: bool) -> vkshade::Result<()> {
        let y = &self._y;
        rec.begin_pass("chain");
        rec.begin_pass("scale 1");
        rec.dispatch_invocations(
            &self.scale,
            &self.scale_bind,
            &scale_push(1.5, 0.25, N),
            [N, 1, 1],
        )?;
        rec.end_pass();
        if raw_barrier {
            rec.barrier(&[Barrier::buffer(
                y,
                A::ComputeShaderWrite,
                A::ComputeShaderReadOther,
            )])?;
        }
        rec.begin_pass("add 1");
        rec.dispatch_invocations(&self.add, &self.add_bind, &add_push(0.5, N), [N, 1, 1])?;
        rec.end_pass();
        // y: read by add 1, written by scale 2 (WAR); acc: read-modify-write twice (RAW+WAW).
        rec.barrier(&[
            Barrier::buffer(y, A::ComputeShaderReadOther, A::ComputeShaderWrite),
            Barrier::buffer(
                &self.acc,
                A::ComputeShaderWrite,
                A::ComputeShaderReadOther | A::ComputeShaderWrite,
            ),
        ])?;
        rec.begin_pass("scale 2");
        rec.dispatch_invocations(
            &self.scale,
            &self.scale_bind,
            &scale_push(-2.0, 1.0, N),
            [N, 1, 1],
        )?;
        rec.end_pass();
        rec.barrier(&[Barrier::buffer(
            y,
            A::ComputeShaderWrite,
            A::ComputeShaderReadOther,
        )])?;
        rec.begin_pass("add 2");
        rec.dispatch_invocations(&self.add, &self.add_bind, &add_push(0.5, N), [N, 1, 1])?;
        rec.end_pass();
        rec.end_pass();
        Ok(())
    }
}

#[test]
fn dispatch_chain_matches_cpu_and_is_validation_clean() {
    let (x, acc0) = inputs();
    let expected = cpu_chain(&x, &acc0);
    let (got, timings) = with_gpu(|ctx| {
        let chain = Chain::new(ctx)?;
        let mut rec = ctx.recorder("chain")?;
        chain.record(&mut rec, true)?;
        let readback = rec.read_back(&chain.acc)?;
        let timings = rec.submit_and_wait()?;
        Ok((readback.to_vec::<f32>()?, timings))
    });
    assert_eq!(got.len(), expected.len());
    // The GPU may fuse a*x+b into one FMA; each of the four steps then differs from the CPU by
    // at most one rounding (~6e-8 relative), far inside this bound.
    let mut worst = 0f32;
    for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
        let err = (g - e).abs() / e.abs().max(1.0);
        assert!(err < 1e-5, "element {i}: GPU {g} vs CPU {e}");
        worst = worst.max(err);
    }
    eprintln!("dispatch chain: {N} elements, max relative error {worst:e}");
    for name in ["chain", "scale 1", "add 1", "scale 2", "add 2"] {
        let ms = timings
            .get(name)
            .unwrap_or_else(|| panic!("pass '{name}' has no timing"));
        assert!(ms > 0.0 && ms < 10_000.0, "pass '{name}' took {ms} ms");
    }
    let outer = timings.get("chain").unwrap();
    let inner: f64 = ["scale 1", "add 1", "scale 2", "add 2"]
        .iter()
        .map(|n| timings.get(n).unwrap())
        .sum();
    assert!(
        inner <= outer * 1.01,
        "nested passes ({inner} ms) exceed their parent ({outer} ms)"
    );
}

#[test]
fn missing_barrier_is_caught_by_synchronization_validation() {
    let ctx = context();
    let result = (|| {
        let chain = Chain::new(&ctx)?;
        let mut rec = ctx.recorder("chain without barrier")?;
        chain.record(&mut rec, false)?;
        rec.submit_and_wait()
    })();
    let messages = shutdown(ctx);
    result.expect("the run itself succeeds; only validation objects");
    assert!(
        messages
            .iter()
            .any(|m| m.id_name.contains("SYNC-HAZARD-READ-AFTER-WRITE") && m.text.contains("y")),
        "expected a read-after-write hazard on buffer y, got: {messages:#?}"
    );
    // The message names the pass it happened in (debug labels) and the buffer (object names).
    let m = messages
        .iter()
        .find(|m| m.id_name.contains("READ-AFTER-WRITE"))
        .unwrap();
    assert!(
        m.to_string().contains("add 1") || m.to_string().contains("'y'"),
        "message lacks pass or object names: {m}"
    );
}

#[test]
fn core_validation_error_is_caught() {
    let ctx = context();
    let device = ctx.raw_device().clone();
    // A zero-sized buffer violates VUID-VkBufferCreateInfo-size-00912.
    let info = vk::BufferCreateInfo::default()
        .size(0)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER);
    // SAFETY: deliberately invalid usage that the layer reports; the handle (if any) is
    // destroyed right away.
    unsafe {
        if let Ok(b) = device.create_buffer(&info, None) {
            device.destroy_buffer(b, None);
        }
    }
    let messages = shutdown(ctx);
    assert!(
        messages
            .iter()
            .any(|m| m.text.contains("VUID-VkBufferCreateInfo-size-00912")),
        "expected VUID-VkBufferCreateInfo-size-00912, got: {messages:#?}"
    );
}

#[test]
fn undestroyed_object_is_reported_at_shutdown() {
    let ctx = context();
    let info = vk::BufferCreateInfo::default()
        .size(64)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER);
    // SAFETY: valid create info; the buffer is leaked on purpose.
    let _leaked = unsafe { ctx.raw_device().create_buffer(&info, None) }.expect("create");
    let messages = shutdown(ctx);
    assert!(
        messages.iter().any(
            |m| m.id_name == "VUID-vkDestroyDevice-device-00378" && m.text.contains("VkBuffer")
        ),
        "expected an undestroyed-object report, got: {messages:#?}"
    );
}

#[test]
fn live_resource_blocks_shutdown() {
    let ctx = context();
    let buffer = Buffer::new(&ctx, "kept", BufferDesc::storage(256)).expect("buffer");
    let err = ctx
        .shutdown()
        .expect_err("a live buffer must block shutdown");
    assert!(matches!(err, Error::Leak(_)), "{err}");
    drop(buffer); // the last owner destroys the device now
}

#[test]
fn garbage_spirv_is_rejected_with_its_name() {
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty.spv", vec![]),
        ("odd-length.spv", vec![3, 2, 0x23, 7, 1]),
        ("text.spv", b"#version 450\nvoid main() {}\n....".to_vec()),
        (
            "random.spv",
            (0..400u32)
                .flat_map(|i| (i.wrapping_mul(2654435761)).to_le_bytes())
                .collect(),
        ),
        (
            "truncated.spv",
            spirv("test/chain_add").unwrap()[..200].to_vec(),
        ),
        ("bad-word.spv", {
            let mut v = spirv("test/chain_add").unwrap().to_vec();
            let mid = v.len() / 2 / 4 * 4;
            v[mid..mid + 4].copy_from_slice(&0xffff_ffffu32.to_le_bytes());
            v
        }),
    ];
    for (name, bytes) in cases {
        match Shader::from_spirv(name, &bytes) {
            Err(Error::Spirv { name: n, reason }) => {
                assert_eq!(n, name);
                assert!(!reason.is_empty());
                eprintln!("{name}: {reason}");
            }
            Err(e) => panic!("{name}: wrong error kind: {e}"),
            Ok(_) => panic!("{name}: garbage accepted"),
        }
    }
}

#[cfg(feature = "glsl")]
#[test]
fn non_compute_shader_is_rejected() {
    use vkshade::shaders::{compile_options, shaderc};
    let compiler = shaderc::Compiler::new().unwrap();
    let frag = compiler
        .compile_into_spirv(
            "#version 450\nlayout(location=0) out vec4 c; void main() { c = vec4(1); }",
            shaderc::ShaderKind::Fragment,
            "f.frag",
            "main",
            Some(&compile_options().unwrap()),
        )
        .unwrap();
    let err = Shader::from_spirv("f.frag", frag.as_binary_u8()).unwrap_err();
    assert!(err.to_string().contains("not GLCompute"), "{err}");
}

#[test]
fn interface_mismatches_are_clear_errors() {
    with_gpu(|ctx| {
        let add = ComputePipeline::from_spirv(ctx, "test/chain_add", spirv("test/chain_add")?)?;
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let y = Buffer::new(ctx, "y", BufferDesc::storage(4096))?;
        let acc = Buffer::new(ctx, "acc", BufferDesc::storage(4096))?;
        let uniform_only = Buffer::new(ctx, "uniform-only", BufferDesc::uniform(4096))?;
        let image = Image::new(
            ctx,
            "img",
            ImageDesc::d2(vk::Format::R32_SFLOAT, [4, 4]).usage(vk::ImageUsageFlags::STORAGE),
        )?;
        let expect_err = |r: vkshade::Result<vkshade::gpu::BindGroup>, needle: &str| match r {
            Err(e @ Error::Interface { .. }) => {
                assert!(
                    e.to_string().contains(needle),
                    "'{e}' should mention '{needle}'"
                );
                assert!(
                    e.to_string().contains("test/chain_add"),
                    "'{e}' should name the pipeline"
                );
            }
            Err(e) => panic!("wrong error kind: {e}"),
            Ok(_) => panic!("accepted a mismatched interface (expected '{needle}')"),
        };
        expect_err(add.bind(&[("ybuf", Resource::Buffer(&y))]), "accbuf");
        expect_err(
            add.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                ("nonexistent", Resource::Buffer(&acc)),
            ]),
            "no binding named 'nonexistent'",
        );
        expect_err(
            add.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                ("accbuf", Resource::storage_image(&image)),
            ]),
            "StorageBuffer but was given a storage image",
        );
        expect_err(
            add.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                ("accbuf", Resource::Buffer(&uniform_only)),
            ]),
            "lacks usage",
        );
        expect_err(
            add.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                (
                    "accbuf",
                    Resource::BufferRange {
                        buffer: &acc,
                        offset: 4000,
                        size: 200,
                    },
                ),
            ]),
            "outside buffer",
        );
        expect_err(
            add.bind(&[
                ("ybuf", Resource::Buffer(&y)),
                ("ybuf", Resource::Buffer(&acc)),
                ("accbuf", Resource::Buffer(&acc)),
            ]),
            "given twice",
        );
        let good = add.bind(&[
            ("ybuf", Resource::Buffer(&y)),
            ("accbuf", Resource::Buffer(&acc)),
        ])?;
        let mut rec = ctx.recorder("bad dispatches")?;
        let e = rec.dispatch(&add, &good, &[0u8; 4], [1, 1, 1]).unwrap_err();
        assert!(
            e.to_string()
                .contains("push constants are 4 bytes, the shader declares 8"),
            "{e}"
        );
        let e = rec
            .dispatch(&scale, &good, &scale_push(1.0, 0.0, 1), [1, 1, 1])
            .unwrap_err();
        assert!(e.to_string().contains("different pipeline"), "{e}");
        // One group more than this device allows (65535 on lavapipe, 2^31 - 1 on NVIDIA).
        let max = ctx.limits().max_compute_work_group_count[0];
        if let Some(over) = max.checked_add(1) {
            let e = rec
                .dispatch(&add, &good, &add_push(1.0, 1), [over, 1, 1])
                .unwrap_err();
            assert!(e.to_string().contains("maxComputeWorkGroupCount"), "{e}");
        }
        drop(rec); // never submitted: nothing was recorded that needs to run
        Ok(())
    });
}

#[test]
fn buffers_beyond_device_limits_are_refused() {
    with_gpu(|ctx| {
        let max = ctx.limits().max_storage_buffer_range;
        match Buffer::new(ctx, "too big", BufferDesc::storage(max + 16)) {
            Err(e @ Error::Limit { .. }) => {
                let s = e.to_string();
                assert!(
                    s.contains("maxStorageBufferRange") && s.contains("too big"),
                    "{s}"
                );
            }
            Err(e) => panic!("wrong error: {e}"),
            Ok(_) => panic!("a storage buffer beyond maxStorageBufferRange was created"),
        }
        let max_alloc = ctx.limits().max_memory_allocation_size;
        let staging = BufferDesc {
            usage: vk::BufferUsageFlags::TRANSFER_SRC,
            ..BufferDesc::upload(max_alloc + 1)
        };
        let e = Buffer::new(ctx, "huge staging", staging).unwrap_err();
        assert!(e.to_string().contains("maxMemoryAllocationSize"), "{e}");
        let e = Buffer::new(ctx, "empty", BufferDesc::storage(0)).unwrap_err();
        assert!(e.to_string().contains("size 0"), "{e}");
        Ok(())
    });
}

#[test]
fn images_round_trip_through_staging() {
    with_gpu(|ctx| {
        for (name, format, extent, texel) in [
            ("rgba8 2d", vk::Format::R8G8B8A8_UNORM, [37, 19, 1], 4usize),
            ("r32f 3d", vk::Format::R32_SFLOAT, [8, 5, 6], 4),
        ] {
            let desc = if extent[2] > 1 {
                ImageDesc::d3(format, extent)
            } else {
                ImageDesc::d2(format, [extent[0], extent[1]])
            };
            let image = Image::new(ctx, name, desc)?;
            let n = extent.iter().product::<u32>() as usize * texel;
            let data: Vec<u8> = (0..n).map(|i| (i * 7 % 251) as u8).collect();
            let mut rec = ctx.recorder("image round trip")?;
            rec.upload_image(&image, ImageRegion::whole(image.desc()), &data)?;
            rec.barrier(&[Barrier::image(
                &image,
                A::TransferWrite,
                A::ComputeShaderReadSampledImage,
            )])?;
            let rb = rec.read_back_image(&image, ImageRegion::whole(image.desc()))?;
            rec.submit_and_wait()?;
            assert_eq!(rb.bytes()?, &data[..], "{name}");
        }
        let too_big = ImageDesc::d3(
            vk::Format::R8G8B8A8_UNORM,
            [4, 4, ctx.limits().max_image_dimension_3d + 1],
        );
        let e = Image::new(ctx, "too deep", too_big).unwrap_err();
        assert!(e.to_string().contains("maxImageDimension3D"), "{e}");
        Ok(())
    });
}

#[test]
fn readback_before_submit_is_an_error() {
    with_gpu(|ctx| {
        let b = ctx.upload_buffer("b", BufferDesc::storage(16), &[1u32, 2, 3, 4])?;
        let mut rec = ctx.recorder("early read")?;
        let rb = rec.read_back(&b)?;
        let e = rb.bytes().expect_err("read before submit");
        assert!(
            e.to_string().contains("before its recording was submitted"),
            "{e}"
        );
        rec.submit_and_wait()?;
        assert_eq!(rb.to_vec::<u32>()?, vec![1, 2, 3, 4]);
        Ok(())
    });
}

#[test]
fn unknown_device_selector_names_the_devices_present() {
    let desc = vkshade::gpu::ContextDesc {
        device: vkshade::gpu::DeviceSelector::Name("no-such-gpu-xyz".into()),
        validation: None,
        ..Default::default()
    };
    common::hold_gpu();
    let e = Context::new(&desc).unwrap_err();
    let s = e.to_string();
    assert!(s.contains("no-such-gpu-xyz") && s.contains("0:"), "{s}");
}

#[cfg(feature = "cli")] // runs the vkshade binary
#[test]
fn missing_driver_fails_with_install_hint() {
    // In a child process, so the environment change cannot affect other tests.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vkshade"))
        .args(["bench", "peak", "--samples", "1"])
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .output()
        .expect("run vkshade");
    assert!(!out.status.success(), "must fail without a driver");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("mesa-vulkan-drivers"),
        "the error must say how to install lavapipe; stderr was:\n{stderr}"
    );
}

#[test]
fn validation_harness_reports_messages() {
    // The assertion helper itself must fail on a message.
    let fake = vkshade::gpu::ValidationMessage {
        severity: vkshade::gpu::Severity::Error,
        kind: "VALIDATION".into(),
        id_number: 1,
        id_name: "X".into(),
        text: "t".into(),
        objects: vec![],
        labels: vec![],
    };
    assert!(std::panic::catch_unwind(|| assert_clean(&[fake])).is_err());
}

#[test]
fn specialization_constants_by_name() {
    with_gpu(|ctx| {
        let shader = Shader::from_spirv("test/spec", spirv("test/spec")?)?;
        let ids: Vec<(u32, &str)> = shader
            .spec_constants
            .iter()
            .map(|c| (c.id, c.name.as_str()))
            .collect();
        // The workgroup size's constant has no name in the module: it is called id3.
        assert_eq!(ids, vec![(0, "FACTOR"), (3, "id3"), (7, "OFFSET")]);
        assert_eq!(
            (shader.local_size, shader.local_size_spec),
            ([64, 1, 1], [Some(3), None, None])
        );
        let n = 1000u32;
        let out = Buffer::new(ctx, "spec out", BufferDesc::storage(4 * n as u64))?;
        for (constants, factor, offset, group) in [
            (vec![], 2.0f32, 0.5f32, 64),
            (
                vec![("FACTOR", 5u32), ("OFFSET", 1.25f32.to_bits()), ("id3", 16)],
                5.0,
                1.25,
                16,
            ),
        ] {
            let p = ComputePipeline::specialized(ctx, &shader, &constants)?;
            assert_eq!(
                p.local_size(),
                [group, 1, 1],
                "the specialised workgroup size is used"
            );
            let bind = p.bind(&[("outbuf", Resource::Buffer(&out))])?;
            let mut rec = ctx.recorder("spec")?;
            rec.barrier(&[Barrier::buffer(
                &out,
                A::TransferRead,
                A::ComputeShaderWrite,
            )])?;
            rec.dispatch_invocations(&p, &bind, &n.to_le_bytes(), [n, 1, 1])?;
            let rb = rec.read_back(&out)?;
            rec.submit_and_wait()?;
            let v: Vec<f32> = rb.to_vec()?;
            for (i, x) in v.iter().enumerate() {
                assert_eq!(*x, factor * i as f32 + offset, "element {i}");
            }
        }
        let e = ComputePipeline::specialized(ctx, &shader, &[("id3", 0)]).unwrap_err();
        assert!(e.to_string().contains("zero dimension"), "{e}");
        let e = ComputePipeline::specialized(ctx, &shader, &[("id3", 1 << 20)]).unwrap_err();
        assert!(e.to_string().contains("maxComputeWorkGroup"), "{e}");
        let e = ComputePipeline::specialized(ctx, &shader, &[("SCALE", 1)]).unwrap_err();
        assert!(
            e.to_string()
                .contains("no specialization constant named 'SCALE'")
                && e.to_string().contains("FACTOR"),
            "{e}"
        );
        Ok(())
    });
}

#[test]
fn readback_dropped_before_submit_is_harmless() {
    with_gpu(|ctx| {
        let b = ctx.upload_buffer("b", BufferDesc::storage(1 << 16), &vec![7u32; 1 << 14])?;
        let mut rec = ctx.recorder("dropped readback")?;
        let rb = rec.read_back(&b)?;
        drop(rb); // the recorded copy still has its staging buffer
        rec.submit_and_wait()?;
        Ok(())
    });
}

#[test]
fn bind_group_keeps_its_buffers_alive() {
    let (x, _) = inputs();
    with_gpu(|ctx| {
        let scale =
            ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
        let xb = ctx.upload_buffer("x", BufferDesc::storage(N as u64 * 4), &x)?;
        let y = Buffer::new(ctx, "y", BufferDesc::storage(N as u64 * 4))?;
        let bind = scale.bind(&[
            ("src", Resource::Buffer(&xb)),
            ("dst", Resource::Buffer(&y)),
        ])?;
        drop(xb); // the bind group still holds the buffer it reads
        let mut rec = ctx.recorder("after drop")?;
        rec.dispatch_invocations(&scale, &bind, &scale_push(3.0, -1.0, N), [N, 1, 1])?;
        let rb = rec.read_back(&y)?;
        rec.submit_and_wait()?;
        let got: Vec<f32> = rb.to_vec()?;
        for i in [0, 1, 777, N as usize - 1] {
            assert!((got[i] - (3.0 * x[i] - 1.0)).abs() < 1e-6, "element {i}");
        }
        Ok(())
    });
}

#[test]
fn copies_out_of_bounds_or_empty_are_refused() {
    with_gpu(|ctx| {
        let a = Buffer::new(ctx, "a", BufferDesc::storage(64))?;
        let b = Buffer::new(ctx, "b", BufferDesc::storage(64))?;
        let mut rec = ctx.recorder("bad copies")?;
        for (so, d, size) in [
            (0u64, 0u64, 0u64),
            (u64::MAX - 4, 0, 8),
            (0, 60, 8),
            (32, 0, 64),
        ] {
            let e = rec.copy_buffer(&a, so, &b, d, size).unwrap_err();
            assert!(e.to_string().contains("empty or out of bounds"), "{e}");
        }
        Ok(())
    });
}

#[test]
fn external_device_command_buffer_and_semaphores() {
    // A renderer's device: here, the handles of a validated context, which stays the owner
    // and reports every message and leak at its shutdown.
    let owner = context();
    let result = (|| -> vkshade::Result<()> {
        // SAFETY: the owner's handles stay valid until `ext` and everything made from it is
        // dropped (below, before the owner's shutdown); nothing else submits meanwhile.
        let ext = unsafe { Context::from_external(owner.external_handles())? };
        let (x, acc) = inputs();
        let chain = Chain::new(&ext)?;
        let device = ext.raw_device().clone();

        // 1. Non-blocking submissions chained by a semaphore of the caller's.
        // SAFETY: valid device; destroyed below after both submissions completed.
        let sem = unsafe { device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }
            .map_err(|result| vkshade::Error::Vk {
                call: "vkCreateSemaphore",
                result,
            })?;
        let signal = [vk::SemaphoreSubmitInfo::default()
            .semaphore(sem)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let wait = [vk::SemaphoreSubmitInfo::default()
            .semaphore(sem)
            .stage_mask(vk::PipelineStageFlags2::COMPUTE_SHADER)];
        let mut first = ext.recorder("first half")?;
        first.begin_pass("scale 1");
        first.dispatch_invocations(
            &chain.scale,
            &chain.scale_bind,
            &scale_push(1.5, 0.25, N),
            [N, 1, 1],
        )?;
        first.end_pass();
        // SAFETY: `sem` is a fresh binary semaphore of this device, signalled once here and
        // waited once below; it is destroyed after both submissions completed.
        let first = unsafe { first.submit_with(&[], &signal)? };
        let mut second = ext.recorder("second half")?;
        second.barrier(&[Barrier::buffer(
            &chain._y,
            A::ComputeShaderWrite,
            A::ComputeShaderReadOther,
        )])?;
        second.dispatch_invocations(&chain.add, &chain.add_bind, &add_push(0.5, N), [N, 1, 1])?;
        let rb = second.read_back(&chain.acc)?;
        // SAFETY: as above: the wait pairs with the signal submitted just before.
        let second = unsafe { second.submit_with(&wait, &[])? };
        second.wait()?;
        assert!(first.is_complete());
        first.wait()?;
        // SAFETY: both submissions completed.
        unsafe { device.destroy_semaphore(sem, None) };
        let got: Vec<f32> = rb.to_vec()?;
        let want = acc[5] * 0.5 + (1.5 * x[5] + 0.25);
        assert!((got[5] - want).abs() < 1e-5, "{} vs {want}", got[5]);

        // 2. Recording into the caller's command buffer, which the caller submits.
        // SAFETY: plain object creation and a one-time submission, all waited for; the
        // Recorded is kept until the fence has signalled.
        unsafe {
            let pool = device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default().queue_family_index(ext.queue_family()),
                    None,
                )
                .unwrap();
            let cmds = device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(pool)
                        .command_buffer_count(2),
                )
                .unwrap();
            let (cmd, spare) = (cmds[0], cmds[1]);
            let begin = vk::CommandBufferBeginInfo::default();
            device.begin_command_buffer(cmd, &begin).unwrap();
            let mut rec = ext.record_into(cmd, "renderer frame")?;
            rec.barrier(&[Barrier::buffer(
                &chain.acc,
                A::TransferRead,
                A::ComputeShaderWrite,
            )])?;
            rec.begin_pass("add in renderer frame");
            rec.dispatch_invocations(&chain.add, &chain.add_bind, &add_push(1.0, N), [N, 1, 1])?;
            rec.end_pass();
            let rb2 = rec.read_back(&chain.acc)?;
            let mut recorded = rec.finish()?;
            device.end_command_buffer(cmd).unwrap();
            let fence = device
                .create_fence(&vk::FenceCreateInfo::default(), None)
                .unwrap();
            let infos = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
            let signals = [recorded.signal()];
            let queue = owner.external_handles().queue;
            device
                .queue_submit2(
                    *queue.lock().unwrap(),
                    &[vk::SubmitInfo2::default()
                        .command_buffer_infos(&infos)
                        .signal_semaphore_infos(&signals)],
                    fence,
                )
                .unwrap();
            device.wait_for_fences(&[fence], true, u64::MAX).unwrap();
            let timings = recorded.wait(u64::MAX)?;
            assert!(
                timings
                    .get("add in renderer frame")
                    .is_some_and(|ms| ms > 0.0)
            );
            let again: Vec<f32> = rb2.to_vec()?;
            let want = got[5] + (1.5 * x[5] + 0.25);
            assert!((again[5] - want).abs() < 1e-5, "{} vs {want}", again[5]);
            // An external recorder cannot submit itself (checked on a spare command buffer
            // that is never submitted).
            device.begin_command_buffer(spare, &begin).unwrap();
            let e = ext.record_into(spare, "spare")?.submit().err().unwrap();
            assert!(e.to_string().contains("finish()"), "{e}");
            device.destroy_fence(fence, None);
            device.destroy_command_pool(pool, None);
        }
        drop((chain, rb));
        let leftover = ext.shutdown()?;
        assert!(
            leftover.is_empty(),
            "an external context collects no messages: {leftover:?}"
        );
        Ok(())
    })();
    let messages = shutdown(owner);
    result.unwrap();
    assert_clean(&messages);
}

/// GPU-assisted validation (instrumented shaders) as far as it completes here: a context with
/// it starts, makes and frees a buffer and shuts down clean. Known problem of the layer, not
/// of vkshade: with the Khronos layer 1.3.239 (Debian 12) on lavapipe, an early submission
/// under GPU-assisted validation never returns (a buffer upload here; the AO, SSS and SRBF
/// tests hang in their first wait; BTF ran for minutes and the layer reported
/// `UNASSIGNED-VkSemaphore-state-timeout`, "This is most likely a validation bug"), so no
/// kernel test runs under it. Where it hangs (gdb, re-checked for issue 23, with and without
/// synchronization validation): vkWaitSemaphores on vkshade's timeline returns, then the
/// layer's own vkGetSemaphoreCounterValue (from `Shared::completed`, retiring the submission)
/// blocks forever on the layer's semaphore-state future, which its queue thread never
/// fulfils: no shader has run yet when it hangs on the upload, so it is the layer's
/// semaphore tracking under GPU-AV, not an out-of-bounds access it found. `VKSHADE_GPU_AV_SUBMIT=1` adds a dispatch to this test, to try
/// a newer layer; `common::with_gpu_assisted` is ready for the kernels' tests then.
#[test]
fn gpu_assisted_validation_starts_and_shuts_down_clean() {
    common::with_gpu_assisted(|ctx| {
        let (x, _) = inputs();
        let dst = Buffer::new(ctx, "y", BufferDesc::storage(N as u64 * 4))?;
        if std::env::var_os("VKSHADE_GPU_AV_SUBMIT").is_some() {
            let src = ctx.upload_buffer("x", BufferDesc::storage(N as u64 * 4), &x)?;
            let scale =
                ComputePipeline::from_spirv(ctx, "test/chain_scale", spirv("test/chain_scale")?)?;
            let bind = scale.bind(&[
                ("src", Resource::Buffer(&src)),
                ("dst", Resource::Buffer(&dst)),
            ])?;
            let mut rec = ctx.recorder("scale under GPU-AV")?;
            rec.dispatch_invocations_tracked(&scale, &bind, &scale_push(2.0, 1.0, N), [N, 1, 1])?;
            let rb = rec.read_back(&dst)?;
            rec.submit_and_wait()?;
            let y: Vec<f32> = rb.to_vec()?;
            assert!((y[5] - (2.0 * x[5] + 1.0)).abs() < 1e-6);
        }
        Ok(())
    });
}

/// The lines of the test file `name` (source `src`) that make a context without
/// `common::hold_gpu()` first (see there for the layer's race): a `Context::new(` whose line
/// before is not `common::hold_gpu();`, and, in a file of more than one test, an app run or
/// `Gpu` (which makes its own contexts) with no `hold_gpu` in the three lines after it.
fn contexts_made_without_the_gpu_lock(name: &str, src: &str) -> Vec<String> {
    let lines: Vec<&str> = src.lines().collect();
    let tests = lines.iter().filter(|l| l.trim() == "#[test]").count();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        // Code before any comment or string (so this checker does not find itself).
        let code = line.split(['/', '"']).next().unwrap_or("");
        let before = if i > 0 { lines[i - 1].trim() } else { "" };
        if code.contains("Context::new(") && before != "common::hold_gpu();" {
            found.push(format!("{name}:{}: {}", i + 1, line.trim()));
        }
        let makes_its_own = (code.contains("use vkshade::app::") && code.contains(" run}"))
            || code.contains("Gpu {");
        let locks_after = lines[i + 1..(i + 4).min(lines.len())]
            .iter()
            .any(|l| l.contains("hold_gpu()"));
        if tests > 1 && makes_its_own && !locks_after {
            found.push(format!("{name}:{}: {}", i + 1, line.trim()));
        }
    }
    found
}

/// Every context a test makes is made under the GPU lock, so no two tests' contexts overlap
/// the layer's unlocked create and destroy (tests/common, `hold_gpu`). The check itself
/// catches a planted unlocked context and an unlocked app run.
#[test]
fn every_test_context_is_made_under_the_gpu_lock() {
    // One line per string, so this file's own scan sees a quote before each pattern.
    let planted = [
        "#[test]",
        "fn a() {",
        "    let ctx = Context::new(&desc).unwrap();",
        "}",
        "#[test]",
        "fn b() {",
        "    use vkshade::app::ao::{AoRunConfig, run};",
        "    run(&cfg);",
        "}",
    ]
    .join("\n");
    assert_eq!(
        contexts_made_without_the_gpu_lock("planted.rs", &planted).len(),
        2
    );
    let fixed = planted
        .replace("    let ctx", "    common::hold_gpu();\n    let ctx")
        .replace("    run(&cfg)", "    common::hold_gpu();\n    run(&cfg)");
    assert!(contexts_made_without_the_gpu_lock("fixed.rs", &fixed).is_empty());

    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let mut found = Vec::new();
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "rs") {
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            let src = std::fs::read_to_string(&path).unwrap();
            found.extend(contexts_made_without_the_gpu_lock(&name, &src));
            files += 1;
        }
    }
    assert!(
        files > 20,
        "only {files} test files found in {}",
        dir.display()
    );
    assert!(
        found.is_empty(),
        "contexts made without common::hold_gpu():\n{}",
        found.join("\n")
    );
}
