//! The published variant of sphere AO (`Cut::Fixed`): per-vertex node lists chosen in the
//! bind pose, pairwise overlap from the 3D table. GPU against its CPU twin, the method
//! against the ray-traced mesh beside the default (adaptive) cut, and refused misuse. Every
//! GPU run is under validation (see common/).

mod common;

use glam::Mat4;
use vkshade::geom::bvh::Bvh;
use vkshade::geom::visibility::{RayConfig, ambient_visibility};
use vkshade::gpu::Context;
use vkshade::kernels::ao::cpu::{self, CpuAo};
use vkshade::kernels::ao::fixed::{FIXED_SLOTS, NO_NODE};
use vkshade::kernels::ao::formula::{OcclusionTable, TABLE_SIZE};
use vkshade::kernels::ao::{
    AoKernel, AoParams, Correction, Cut, FixedCut, FrameData, Occlusion, Prepared,
};
use vkshade::reference::ErrorStats;
use vkshade::scene::Character;
use vkshade::scene::spheretree::{BuildConfig, SphereTree};

fn testwuson() -> Character {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    vkshade::scene::load(&path).unwrap_or_else(|e| {
        panic!("{e}\nThe test character comes from tools/setup.sh (assimp-testmodels converted to glTF).")
    })
}

/// One GPU frame; also hands back the lists the kernel chose.
fn gpu_frame(
    ctx: &Context,
    prep: &Prepared,
    params: AoParams,
    correction: Option<&[f32]>,
    matrices: &[Mat4],
) -> vkshade::Result<(FrameData, Option<FixedCut>)> {
    let mut rec = ctx.recorder("ao fixed test frame")?;
    let kernel = AoKernel::new(&mut rec, prep, params)?;
    if let Some(c) = correction {
        kernel.set_correction(&mut rec, c)?;
    }
    kernel.record(&mut rec, matrices)?;
    let rb = kernel.read_back(&mut rec)?;
    rec.submit_and_wait()?;
    Ok((rb.data()?, kernel.fixed_cut().cloned()))
}

fn visibility(v: &[cpu::VertexAo]) -> Vec<f32> {
    v.iter().map(|v| v.visibility).collect()
}

#[test]
fn fixed_cut_gpu_matches_its_cpu_twin_on_testwuson() {
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let correction = Correction::bake(&c.mesh, 256);
    let run = c.animation("Run").unwrap();
    common::with_gpu(|ctx| {
        for (k, (occlusion, tau, correct, clamp_inside)) in [
            (Occlusion::Table, 0.8, true, false),
            (Occlusion::Exact, 0.5, false, true),
        ]
        .into_iter()
        .enumerate()
        {
            let params = AoParams {
                tau,
                occlusion,
                correct,
                clamp_inside,
                cut: Cut::Fixed,
                ..AoParams::default()
            };
            let fixed = FixedCut::select(&prep, &params, FIXED_SLOTS)?;
            let factors = correction.fixed_factors(&cpu_ao, &prep, &fixed, &params);
            let m = c
                .rig
                .skinning_matrices(Some(run), run.duration * (0.2 + 0.45 * k as f32));
            let (gpu, chosen) = gpu_frame(ctx, &prep, params, Some(&factors), &m)?;
            // The kernel chose the same lists (selection is deterministic).
            let chosen = chosen.expect("a fixed-cut kernel exposes its lists");
            assert_eq!(chosen.nodes, fixed.nodes, "{params:?}: lists differ");
            let posed = cpu::skin(&prep, &m);
            let twin = cpu_ao.fixed_frame(&posed, &fixed, &params, Some(&factors));
            common::assert_ao_matches_twin(&gpu, &twin, &params);
        }
        Ok(())
    });
}

/// Testwuson's Run at two animated poses: the fixed cut against the ray-traced posed mesh
/// (1024 stratified rays per vertex from the CPU's own skinning), with the default cut's
/// error beside it; both with and without the bind-pose correction.
#[test]
fn fixed_cut_against_the_ray_traced_mesh_beside_the_default() {
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let adaptive = AoParams::default();
    let fixed_params = AoParams {
        cut: Cut::Fixed,
        ..adaptive
    };
    let fixed = FixedCut::select(&prep, &fixed_params, FIXED_SLOTS).unwrap();
    let bake = Correction::bake(&c.mesh, 1024);
    let f_adaptive = bake.factors(&cpu_ao, &prep, &adaptive);
    let f_fixed = bake.fixed_factors(&cpu_ao, &prep, &fixed, &fixed_params);
    let run = c.animation("Run").unwrap();
    let (lo, hi) = c.mesh.bounds();
    let rays = RayConfig {
        rays: 1024,
        ..RayConfig::for_scene((hi - lo).length())
    };
    common::with_gpu(|ctx| {
        for t in [0.3, 0.7] {
            let m = c.rig.skinning_matrices(Some(run), run.duration * t);
            let (gpu_fixed, _) = gpu_frame(ctx, &prep, fixed_params, Some(&f_fixed), &m)?;
            let (gpu_adaptive, _) = gpu_frame(ctx, &prep, adaptive, Some(&f_adaptive), &m)?;
            let posed = cpu::skin(&prep, &m);
            let bvh = Bvh::build(&posed.positions, &c.mesh.triangles);
            let all: Vec<usize> = (0..posed.positions.len()).collect();
            let truth = ambient_visibility(&posed.positions, &posed.normals, &bvh, &all, &rays);
            let plain = |p: AoParams| AoParams {
                correct: false,
                ..p
            };
            let fixed_alone =
                visibility(&cpu_ao.fixed_frame(&posed, &fixed, &plain(fixed_params), None));
            let adaptive_alone =
                visibility(&cpu_ao.frame(&posed, prep.shape, &plain(adaptive), None));
            let e = |v: &[f32]| ErrorStats::of(v, &truth);
            let (ef, ea, efa, eaa) = (
                e(&gpu_fixed.visibility),
                e(&gpu_adaptive.visibility),
                e(&fixed_alone),
                e(&adaptive_alone),
            );
            eprintln!(
                "Run at {t}: MAE vs ray-traced mesh: fixed {:.4} (p95 {:.3}), adaptive {:.4} (p95 {:.3}); \
                 without the correction fixed {:.4}, adaptive {:.4}",
                ef.mae, ef.p95, ea.mae, ea.p95, efa.mae, eaa.mae
            );
            // The default cut's bound in tests/ao.rs (MAE <= 0.035 with the correction at a
            // 1024-ray truth): the published variant is held to it. Measured here 0.0129 /
            // 0.0169 (adaptive 0.0131 / 0.0156); over 8 frames of Run against a 4096-ray
            // truth 0.011-0.021 (`vkshade ao --cut fixed --reference`).
            assert!(ef.mae <= 0.035, "fixed cut, Run at {t}: {ef:?}");
            // Chosen in the bind pose, its lists miss refinement the pose would ask for, but
            // the proxy dominates the error (~0.11 for either cut): the method alone must
            // stay within 0.02 of the adaptive cut's (measured within 0.0012).
            assert!(
                efa.mae <= eaa.mae + 0.02,
                "Run at {t}: fixed alone {efa:?}, adaptive alone {eaa:?}"
            );
            assert!(ef.mae < 0.5 * efa.mae, "the correction must help: {ef:?}");
        }
        Ok(())
    });
}

#[test]
fn fixed_cut_misuse_is_refused() {
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let params = AoParams {
        cut: Cut::Fixed,
        ..AoParams::default()
    };
    let e = FixedCut::select(&prep, &params, 0).unwrap_err();
    assert!(e.to_string().contains("0 fixed-cut slots"), "{e}");
    let e = FixedCut::select(&prep, &params, FIXED_SLOTS + 1).unwrap_err();
    assert!(e.to_string().contains("slots per vertex"), "{e}");
    let good = FixedCut::select(&prep, &params, 8).unwrap();
    good.check(&prep).unwrap();
    assert!(good.list(0).count() <= 8);
    // A node beyond the tree, and an unused slot of it.
    let mut bad = good.clone();
    bad.nodes[5] = prep.shape.node_count;
    let e = bad.check(&prep).unwrap_err();
    assert!(e.to_string().contains("entry 5"), "{e}");
    if let Some(unused) = prep.spheres.iter().position(|s| s[3] < 0.0) {
        let mut bad = good.clone();
        bad.nodes[0] = unused as u32;
        assert!(bad.check(&prep).is_err());
    }
    let mut short = good.clone();
    short.nodes.pop();
    assert!(
        short
            .check(&prep)
            .unwrap_err()
            .to_string()
            .contains("nodes for")
    );
    assert!(good.nodes.contains(&NO_NODE) || good.list(0).count() == 8);
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("ao fixed misuse")?;
        let mut kernel = AoKernel::new(&mut rec, &prep, params)?;
        // The cut, and with the fixed cut the tau its lists were chosen with, are fixed at
        // construction; the per-sphere modes may change.
        let e = kernel
            .set_params(AoParams {
                cut: Cut::Adaptive,
                ..params
            })
            .unwrap_err();
        assert!(e.to_string().contains("built with the Fixed cut"), "{e}");
        let e = kernel
            .set_params(AoParams { tau: 0.5, ..params })
            .unwrap_err();
        assert!(e.to_string().contains("chosen with tau 0.8"), "{e}");
        kernel.set_params(AoParams {
            occlusion: Occlusion::Exact,
            ..params
        })?;
        let mut adaptive = AoKernel::new(&mut rec, &prep, AoParams::default())?;
        assert!(adaptive.fixed_cut().is_none());
        assert!(adaptive.set_params(params).is_err());
        rec.submit_and_wait()?;
        Ok(())
    });
}
