//! Resources at the device's limits: a memory budget smaller than a kernel needs, a 3D
//! texture deeper than `maxImageDimension3D`, a storage buffer longer than
//! `maxStorageBufferRange`, a BTF whose array texture is wider than `maxImageDimension2D`.
//! Each is refused with an error naming the limit and its value, nothing stays allocated,
//! and the same context then runs the AO kernel, checked against its CPU twin.
//!
//! The 3D-image and storage-buffer limits are the device's real ones (lavapipe: 4096 and
//! 128 MiB; the refusal comes before any allocation, so nothing that large is made). The
//! budget is set on the context ([`Context::set_memory_budget`]); the BTF's 2D limit is lowered
//! by a [`LimitOverrides`] (lavapipe's 16384 would need a tile of 200 texels, far past what a
//! test synthesises quickly).
#![cfg(feature = "gltf")]

mod common;

use glam::Mat4;
use vkshade::Error;
use vkshade::gpu::{
    Buffer, BufferDesc, Context, ContextDesc, Features, Image, ImageDesc, LimitOverrides,
};
use vkshade::kernels::ao::cpu::{self, CpuAo};
use vkshade::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use vkshade::kernels::ao::{AoKernel, AoParams, Prepared};
use vkshade::reference::ErrorStats;
use vkshade::scene::Character;
use vkshade::scene::spheretree::{BuildConfig, SphereTree};

fn testwuson() -> Character {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    vkshade::scene::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Testwuson, its sphere tree and the AO inputs.
struct Ao {
    c: Character,
    prep: Prepared,
}

impl Ao {
    fn new() -> Ao {
        let c = testwuson();
        let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
        let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
        Ao { c, prep }
    }

    fn matrices(&self) -> Vec<Mat4> {
        let run = self.c.animation("Run").unwrap();
        self.c.rig.skinning_matrices(Some(run), run.duration * 0.3)
    }

    /// One AO frame on the GPU.
    fn gpu(&self, ctx: &Context) -> vkshade::Result<Vec<f32>> {
        Ok(self.gpu_measured(ctx)?.0)
    }

    /// One AO frame on the GPU, and the device bytes in use once everything it needs is
    /// allocated (before it is submitted).
    fn gpu_measured(&self, ctx: &Context) -> vkshade::Result<(Vec<f32>, u64)> {
        let mut rec = ctx.recorder("limits: ao")?;
        let kernel = AoKernel::new(&mut rec, &self.prep, AoParams::default())?;
        kernel.record(&mut rec, &self.matrices())?;
        let rb = kernel.read_back(&mut rec)?;
        let used = ctx.memory_report().used_bytes;
        rec.submit_and_wait()?;
        Ok((rb.data()?.visibility, used))
    }

    /// One AO frame on the GPU, checked against the CPU twin. Bound: the GPU and the twin
    /// run the same f32 operations, differing only where Vulkan lets acos/sqrt/division
    /// differ by ulps (tests/ao.rs measures MAE 1.3e-5, max 1.3e-4 on Testwuson): MAE < 1e-4
    /// and max < 1e-2 (a refinement comparison tied at that precision may move one vertex
    /// by one sphere's share).
    fn check(&self, ctx: &Context) -> vkshade::Result<()> {
        let gpu = self.gpu(ctx)?;
        let params = AoParams::default();
        let twin = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
        let posed = cpu::skin(&self.prep, &self.matrices());
        let cpu: Vec<f32> = twin
            .frame(&posed, self.prep.shape, &params, None)
            .iter()
            .map(|v| v.visibility)
            .collect();
        let e = ErrorStats::of(&gpu, &cpu);
        assert!(e.mae < 1e-4 && e.max < 1e-2, "GPU vs CPU twin: {e:?}");
        // Not a trivially flat frame: the character occludes itself.
        assert!(cpu.iter().any(|&v| v < 0.9), "no occlusion at all");
        Ok(())
    }
}

fn limit_of(e: &Error) -> (&'static str, u64) {
    match e {
        Error::Limit {
            limit_name, limit, ..
        } => (limit_name, *limit),
        other => panic!("expected a limit error, got: {other}"),
    }
}

#[test]
fn a_memory_budget_smaller_than_the_kernel_needs_is_refused_and_the_context_runs_on() {
    let ao = Ao::new();
    common::with_gpu(|ctx| {
        // What the kernel needs, measured on this context without a budget (after a first
        // run, so the staging ring and pools it leaves behind are in the base).
        ao.check(ctx)?;
        ctx.wait_idle()?;
        let base = ctx.memory_report().used_bytes;
        let (_, used) = ao.gpu_measured(ctx)?;
        ctx.wait_idle()?;
        assert_eq!(ctx.memory_report().used_bytes, base);
        let need = used - base;
        assert!(need > 4096, "the kernel needs {need} bytes");
        let budget = base + need / 2;
        ctx.set_memory_budget(Some(budget));
        let e = ao.gpu(ctx).unwrap_err();
        let text = e.to_string();
        assert_eq!(limit_of(&e), ("memory budget", budget), "{text}");
        assert!(
            text.contains("memory budget") && text.contains(&budget.to_string()),
            "{text}"
        );
        // Nothing of the refused kernel stays allocated once its objects are retired.
        ctx.wait_idle()?;
        assert_eq!(ctx.memory_report().used_bytes, base, "left allocated");
        // A budget the kernel fits in: the same context runs it.
        ctx.set_memory_budget(Some(base + need + (1 << 20)));
        ao.check(ctx)?;
        ctx.set_memory_budget(None);
        assert_eq!(ctx.memory_budget(), None);
        Ok(())
    });
}

#[test]
fn a_3d_texture_deeper_than_max_image_dimension_3d_is_refused() {
    let ao = Ao::new();
    common::with_gpu(|ctx| {
        let max = ctx.limits().max_image_dimension_3d;
        let before = ctx.memory_report();
        let desc = ImageDesc::d3(ash::vk::Format::R8G8B8A8_UNORM, [4, 4, max + 1]);
        let e = Image::new(ctx, "too deep", desc).unwrap_err();
        let text = e.to_string();
        assert_eq!(limit_of(&e), ("maxImageDimension3D", max as u64), "{text}");
        assert!(
            text.contains(&format!("maxImageDimension3D = {max}")),
            "{text}"
        );
        assert!(text.contains("too deep"), "{text}");
        let after = ctx.memory_report();
        assert_eq!(after.allocations, before.allocations, "allocated anyway");
        // At the limit it is made (a thin one: 1 x 1 x max).
        let edge = ImageDesc::d3(ash::vk::Format::R8G8B8A8_UNORM, [1, 1, max]);
        drop(Image::new(ctx, "at the limit", edge)?);
        ao.check(ctx)
    });
}

#[test]
fn a_storage_buffer_longer_than_max_storage_buffer_range_is_refused() {
    let ao = Ao::new();
    common::with_gpu(|ctx| {
        let max = ctx.limits().max_storage_buffer_range;
        let before = ctx.memory_report();
        let e = Buffer::new(ctx, "too long", BufferDesc::storage(max + 4)).unwrap_err();
        let text = e.to_string();
        assert_eq!(limit_of(&e), ("maxStorageBufferRange", max), "{text}");
        assert!(
            text.contains(&format!("maxStorageBufferRange = {max}")),
            "{text}"
        );
        assert!(text.contains("too long"), "{text}");
        assert_eq!(ctx.memory_report().allocations, before.allocations);
        ao.check(ctx)
    });
}

/// A lowered `maxStorageBufferRange` is what the kernels see: the AO kernel's largest
/// storage buffer no longer fits and the kernel is refused naming the lowered value;
/// a context keeps its limits, so the check runs on a second context with the device's.
#[test]
fn lowered_limits_are_what_kernels_are_checked_against() {
    let ao = Ao::new();
    let desc = ContextDesc {
        limits: LimitOverrides {
            max_storage_buffer_range: Some(4096),
            ..LimitOverrides::default()
        },
        features: Features::default(),
        ..ContextDesc::validated()
    };
    common::hold_gpu();
    let low = Context::new(&desc).unwrap();
    assert_eq!(low.limits().max_storage_buffer_range, 4096);
    let before = low.memory_report().used_bytes;
    let e = ao.gpu(&low).unwrap_err();
    assert_eq!(limit_of(&e), ("maxStorageBufferRange", 4096), "{e}");
    low.wait_idle().unwrap();
    assert_eq!(low.memory_report().used_bytes, before, "left allocated");
    common::assert_clean(&common::shutdown(low));
    common::with_gpu(|ctx| ao.check(ctx));
}

/// A BTF whose packed array texture is wider than `maxImageDimension2D` (lowered to 256 on
/// this context: the 81 views of an 8-texel tile side by side with gutters are 648+ texels
/// wide) is refused naming the limit and its value, nothing stays allocated, and the same
/// context runs the AO kernel (its 64 x 64 occlusion table fits the lowered limit).
#[test]
fn a_btf_wider_than_max_image_dimension_2d_is_refused_and_the_context_runs_on() {
    use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
    use vkshade::kernels::btf::dirs::{Maps, Triangulation};
    use vkshade::kernels::btf::gpu::{BtfInputs, BtfKernel, Layout, Texture};
    use vkshade::scene::gbuffer::GBuffer;
    let ao = Ao::new();
    let btf =
        vkshade::kernels::btf::synth::synthesize(&SynthConfig::tile(Pattern::Weave, 8)).unwrap();
    let maps = Maps::build(&Triangulation::new().unwrap(), 32).unwrap();
    let gbuffer = GBuffer::tile([8, 8]);
    let desc = ContextDesc {
        limits: LimitOverrides {
            max_image_dimension_2d: Some(256),
            ..LimitOverrides::default()
        },
        ..ContextDesc::validated()
    };
    common::hold_gpu();
    let ctx = Context::new(&desc).unwrap();
    let result = (|| -> vkshade::Result<()> {
        let before = ctx.memory_report().used_bytes;
        let mut rec = ctx.recorder("limits: btf")?;
        let e = BtfKernel::new(
            &mut rec,
            &BtfInputs {
                layout: Layout::Rows,
                ..BtfInputs::new(&btf, &maps, &gbuffer, Texture::Rgba8)
            },
        )
        .map(|_| ())
        .unwrap_err();
        drop(rec);
        let text = e.to_string();
        assert_eq!(limit_of(&e), ("maxImageDimension2D", 256), "{text}");
        assert!(text.contains("maxImageDimension2D = 256"), "{text}");
        ctx.wait_idle()?;
        assert_eq!(ctx.memory_report().used_bytes, before, "left allocated");
        ao.check(&ctx)
    })();
    let messages = common::shutdown(ctx);
    result.unwrap();
    common::assert_clean(&messages);
}
