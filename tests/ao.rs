//! Hierarchical sphere ambient occlusion: GPU against the closed form, against the CPU
//! implementation of the same method, and against the ray-traced mesh of a real character.
//! Every GPU run is under validation (see common/).

mod common;
use common::scratch;

use glam::{Mat4, Vec3, Vec4};
use vkshade::gpu::Context;
use vkshade::kernels::ao::cpu::{self, CpuAo};
use vkshade::kernels::ao::formula::{OcclusionTable, TABLE_SIZE, exact_f64};
use vkshade::kernels::ao::{AoKernel, AoParams, Blend, Correction, FrameData, Occlusion, Prepared};
use vkshade::reference::ErrorStats;
use vkshade::scene::spheretree::{BuildConfig, Sphere, SphereTree};
use vkshade::scene::{Character, Mesh, MeshData};

/// A flat square grid in the y = 0 plane, normals +y.
fn plane(n: u32, half: f32) -> Mesh {
    let mut d = MeshData {
        name: "plane".into(),
        ..Default::default()
    };
    for j in 0..n {
        for i in 0..n {
            let x = -half + 2.0 * half * i as f32 / (n - 1) as f32;
            let z = -half + 2.0 * half * j as f32 / (n - 1) as f32;
            d.positions.push([x, 0.0, z]);
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = j * n + i;
            d.triangles.push([a, a + n, a + 1]);
            d.triangles.push([a + 1, a + n, a + n + 1]);
        }
    }
    Mesh::from_data(d, std::path::Path::new("plane")).unwrap()
}

/// A two-level tree (root + `branch` leaves) holding `leaves`.
fn flat_tree(leaves: &[Sphere], branch: u32) -> SphereTree {
    let n = 1 + branch as usize;
    let mut spheres = vec![
        Sphere {
            center: Vec3::ZERO,
            radius: -1.0
        };
        n
    ];
    spheres[0] = Sphere {
        center: Vec3::ZERO,
        radius: 100.0,
    };
    spheres[1..=leaves.len()].copy_from_slice(leaves);
    SphereTree {
        levels: 2,
        branch,
        spheres,
        importance: vec![0.0; n],
        joints: vec![[0; 4]; n],
        weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
    }
}

/// Runs one frame of the GPU kernel (rest pose) and reads it back.
fn gpu_frame(
    ctx: &Context,
    character: &Character,
    tree: &SphereTree,
    params: AoParams,
    correction: Option<&[f32]>,
    matrices: &[Mat4],
) -> vkshade::Result<FrameData> {
    let prep = Prepared::new(&character.mesh, tree, character.rig.joints.len())?;
    // Construction, correction and the frame go into one recording: the uploads are
    // recorded, not submitted on their own.
    let mut rec = ctx.recorder("ao test frame")?;
    let kernel = AoKernel::new(&mut rec, &prep, params)?;
    if let Some(c) = correction {
        kernel.set_correction(&mut rec, c)?;
    }
    kernel.record(&mut rec, matrices)?;
    let rb = kernel.read_back(&mut rec)?;
    rec.submit_and_wait()?;
    rb.data()
}

fn plain(occlusion: Occlusion, blend: Blend) -> AoParams {
    AoParams {
        tau: 1.0,
        band: 0.0,
        refine: vkshade::kernels::ao::Refine::Radius,
        occlusion,
        blend,
        clamp_inside: false,
        correct: false,
        cut: vkshade::kernels::ao::Cut::Adaptive,
    }
}

#[test]
fn one_sphere_over_a_plane_matches_the_closed_form() {
    let character = Character::from_static(plane(41, 2.0));
    let sphere = Sphere {
        center: Vec3::new(0.3, 0.9, -0.2),
        radius: 0.5,
    };
    let tree = flat_tree(&[sphere], 2);
    let expected: Vec<f64> = character
        .mesh
        .positions
        .iter()
        .map(|p| {
            let dv = sphere.center - *p;
            let d = dv.length() as f64;
            1.0 - exact_f64(dv.y as f64 / d, d / sphere.radius as f64)
        })
        .collect();
    // The plane sees the sphere above, straddling and (none) below its horizon: spread of h.
    let darkest = expected.iter().cloned().fold(1.0, f64::min);
    assert!(
        darkest < 0.75,
        "test geometry too weak: min visibility {darkest}"
    );
    common::with_gpu(|ctx| {
        for (occlusion, bound) in [
            // f32 evaluation of acos/atan/sqrt: a few ulp of 1.
            (Occlusion::Exact, 2e-5),
            // The 64x64 table's worst case is 3.6e-4 (formula.rs test); 1e-3 leaves margin.
            (Occlusion::Table, 1e-3),
        ] {
            for blend in [Blend::Product, Blend::Sum, Blend::Mask] {
                let f = gpu_frame(
                    ctx,
                    &character,
                    &tree,
                    plain(occlusion, blend),
                    None,
                    &[Mat4::IDENTITY],
                )?;
                let worst = f
                    .visibility
                    .iter()
                    .zip(&expected)
                    .map(|(g, e)| (*g as f64 - e).abs())
                    .fold(0.0, f64::max);
                eprintln!(
                    "one sphere, {occlusion:?} {blend:?}: max |GPU - closed form| = {worst:e}"
                );
                assert!(worst < bound, "{occlusion:?} {blend:?}: {worst} >= {bound}");
                assert!(
                    f.stats.iter().all(|s| *s == [1, 1]),
                    "one sphere tested and used per vertex"
                );
            }
        }
        Ok(())
    });
}

#[test]
fn blend_modes_on_coincident_and_disjoint_spheres() {
    let character = Character::from_static(plane(21, 1.0));
    let s = Sphere {
        center: Vec3::new(0.0, 1.2, 0.0),
        radius: 0.4,
    };
    // Two spheres far apart on either side: their caps never overlap from the plane's centre.
    let far_l = Sphere {
        center: Vec3::new(-2.0, 0.6, 0.0),
        radius: 0.3,
    };
    let far_r = Sphere {
        center: Vec3::new(2.0, 0.6, 0.0),
        radius: 0.3,
    };
    common::with_gpu(|ctx| {
        let p = Vec3::ZERO; // the plane's centre vertex
        let centre = character
            .mesh
            .positions
            .iter()
            .position(|q| q.distance(p) < 1e-6)
            .unwrap();
        let i_of = |sp: &Sphere| {
            let dv = sp.center - p;
            exact_f64(
                dv.y as f64 / dv.length() as f64,
                (dv.length() / sp.radius) as f64,
            )
        };
        let one = i_of(&s);
        let (il, ir) = (i_of(&far_l), i_of(&far_r));
        let run = |tree: &SphereTree, blend| -> vkshade::Result<f64> {
            Ok(gpu_frame(
                ctx,
                &character,
                tree,
                plain(Occlusion::Exact, blend),
                None,
                &[Mat4::IDENTITY],
            )?
            .visibility[centre] as f64)
        };
        // Coincident caps: the union is one cap.
        let twice = flat_tree(&[s, s], 2);
        assert!(
            (run(&twice, Blend::Mask)? - (1.0 - one)).abs() < 2e-5,
            "mask is exact for coincident caps"
        );
        assert!((run(&twice, Blend::Product)? - (1.0 - one) * (1.0 - one)).abs() < 2e-5);
        assert!((run(&twice, Blend::Sum)? - (1.0 - 2.0 * one)).abs() < 2e-5);
        // Disjoint caps: the union is the sum.
        let apart = flat_tree(&[far_l, far_r], 2);
        assert!(
            (run(&apart, Blend::Mask)? - (1.0 - il - ir)).abs() < 2e-5,
            "mask is exact for disjoint caps"
        );
        assert!((run(&apart, Blend::Sum)? - (1.0 - il - ir)).abs() < 2e-5);
        assert!((run(&apart, Blend::Product)? - (1.0 - il) * (1.0 - ir)).abs() < 2e-5);
        Ok(())
    });
}

fn testwuson() -> Character {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    vkshade::scene::load(&path).unwrap_or_else(|e| {
        panic!("{e}\nThe test character comes from tools/setup.sh (assimp-testmodels converted to glTF).")
    })
}

#[test]
fn gpu_matches_the_cpu_implementation_on_testwuson() {
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let correction = Correction::bake(&c.mesh, 256);
    let run = c.animation("Run").unwrap();
    common::with_gpu(|ctx| {
        let mut worst = 0f32;
        for (k, (occlusion, blend, tau, correct)) in [
            (Occlusion::Table, Blend::Mask, 0.5, true),
            (Occlusion::Exact, Blend::Mask, 0.3, false),
            (Occlusion::Table, Blend::Product, 0.8, false),
            (Occlusion::Exact, Blend::Sum, 0.5, true),
        ]
        .into_iter()
        .enumerate()
        {
            // Both refinement tests, each with two modes.
            let refine = if k % 2 == 0 {
                vkshade::kernels::ao::Refine::Extent
            } else {
                vkshade::kernels::ao::Refine::Radius
            };
            let params = AoParams {
                tau,
                band: 0.5,
                refine,
                occlusion,
                blend,
                clamp_inside: k == 2,
                correct,
                cut: vkshade::kernels::ao::Cut::Adaptive,
            };
            let factors = correction.factors(&cpu_ao, &prep, &params);
            let m = c
                .rig
                .skinning_matrices(Some(run), run.duration * (0.15 + 0.2 * k as f32));
            let gpu = gpu_frame(ctx, &c, &tree, params, Some(&factors), &m)?;
            let posed = cpu::skin(&prep, &m);
            let cpu = cpu_ao.frame(&posed, prep.shape, &params, Some(&factors));
            let max = common::assert_ao_matches_twin(&gpu, &cpu, &params);
            let pos = gpu
                .positions
                .iter()
                .zip(&posed.positions)
                .map(|(g, c)| Vec4::from_array(*g).truncate().distance(*c))
                .fold(0f32, f32::max);
            eprintln!("max position difference {pos:e}");
            assert!(pos < 1e-5, "skinning differs by {pos}");
            worst = worst.max(max as f32);
        }
        eprintln!("worst |GPU - CPU| over all settings: {worst:e}");
        Ok(())
    });
}

/// A tree of more than 3 levels below the root (5 levels of branch 3): the walk's climbs
/// back to depth 3 or deeper recompute the parent state (`ancestor_state`, compiled in only
/// for such trees), which the 8/64/512 trees of the other tests never reach. With that
/// recomputation compiled out, the mask case errs MAE 0.025, max 0.39 here.
#[test]
fn gpu_matches_the_cpu_implementation_on_a_deep_tree() {
    let c = testwuson();
    let cfg = BuildConfig {
        depth: 5,
        branch: 3,
        ..BuildConfig::default()
    };
    let (tree, _) = SphereTree::build(&c.mesh, &cfg).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    assert_eq!(prep.shape.levels(), 5);
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let run = c.animation("Run").unwrap();
    common::with_gpu(|ctx| {
        for (tau, blend) in [(0.5, Blend::Mask), (0.3, Blend::Product)] {
            let params = AoParams {
                tau,
                band: 0.5,
                blend,
                correct: false,
                ..AoParams::default()
            };
            let m = c.rig.skinning_matrices(Some(run), run.duration * 0.4);
            let gpu = gpu_frame(ctx, &c, &tree, params, None, &m)?;
            let posed = cpu::skin(&prep, &m);
            let cpu = cpu_ao.frame(&posed, prep.shape, &params, None);
            common::assert_ao_matches_twin(&gpu, &cpu, &params);
        }
        Ok(())
    });
}

#[cfg(feature = "cli")]
#[test]
fn method_against_the_ray_traced_mesh_on_testwuson() {
    use vkshade::app::ao::{AoRunConfig, run};
    common::hold_gpu(); // `run` makes its own context
    let mesh = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let _ = testwuson(); // a clear message if setup has not run
    for anim in ["Run", "Walk"] {
        let out = scratch::dir(&format!("ao-{anim}"));
        let cfg = AoRunConfig {
            mesh: mesh.clone(),
            animation: Some(anim.into()),
            frames: 2,
            rays: 1024,
            correction_rays: 1024,
            reference: true,
            out: out.clone(),
            image: (160, 120),
            ..Default::default()
        };
        let report = common::with_gpu(|ctx| run(ctx, &cfg, &mut |l| eprintln!("{l}")));
        let s = &report.summary;
        eprintln!("{anim}: {s:?}");
        // Bounds from measurement (4096-ray truth, 8 frames of Run: MAE 0.014-0.020 per
        // frame, method alone 0.109-0.123, bind-pose AO held static 0.040). The 1024-ray
        // truth used here adds noise of at most 0.5/32 per vertex (less, stratified),
        // ~0.005 of MAE; the bounds leave that plus margin.
        let mae = s.mae_mean.unwrap();
        assert!(mae <= 0.035, "{anim}: MAE {mae}");
        let uncorrected = s.mae_uncorrected_mean.unwrap();
        assert!(
            uncorrected <= 0.16,
            "{anim}: method alone MAE {uncorrected}"
        );
        // The animated method beats the bind-pose AO held static: the spheres carry the motion.
        let stat = s.mae_static_bind_pose_mean.unwrap();
        assert!(
            mae < 0.8 * stat,
            "{anim}: MAE {mae} not below static bind-pose AO {stat}"
        );
        for f in &report.frames {
            let r = f.reference.as_ref().unwrap();
            assert!(
                r.error.mae <= 0.045,
                "{anim} frame {}: {:?}",
                f.index,
                r.error
            );
            let d = r.decomposition.as_ref().unwrap();
            // Which part of the error dominates: the proxy (spheres instead of the mesh).
            assert!(
                d.proxy > d.overlap && d.proxy > d.cut && d.proxy > d.table,
                "{d:?}"
            );
            assert!(d.table < 2e-3 && d.overlap < 0.02, "{d:?}");
            assert!((10.0..100.0).contains(&f.spheres_used_per_vertex.mean));
            assert!(f.gpu.skin_ms > 0.0 && f.gpu.ao_ms > 0.0);
            // The PLY holds the posed mesh with the same per-vertex visibility.
            let (data, props) =
                vkshade::scene::static_load::load_ply_with_properties(std::path::Path::new(&f.ply))
                    .unwrap();
            assert_eq!(data.positions.len(), report.mesh.vertices);
            assert_eq!(data.triangles.len(), report.mesh.triangles);
            let ao = &props["ao"];
            let mean = ao.iter().map(|&v| v as f64).sum::<f64>() / ao.len() as f64;
            assert!((mean - f.mean_visibility).abs() < 1e-6);
            assert!(ao.iter().all(|v| (0.0..=1.0).contains(v)));
            let png = std::fs::read(&f.png).unwrap();
            assert_eq!(&png[1..4], b"PNG");
            // The EXR twin: result | truth | error at the same pixels as the picture, linear.
            let exr = vkshade::io::exr::read_rgba(std::path::Path::new(&f.exr)).unwrap();
            let layout = vkshade::render::SideBySideLayout {
                panel_width: 160,
                panel_height: 120,
            };
            assert_eq!((exr.width, exr.height), layout.size());
            let mut covered = 0;
            for y in 0..120 {
                for x in 0..160 {
                    let at = |k: u32| {
                        let (x0, y0) = layout.panel_origin(k);
                        exr.get(x0 + x, y0 + y).unwrap()
                    };
                    let (r, t, e) = (at(0), at(1), at(2));
                    if r[3] < 1.0 {
                        continue;
                    }
                    covered += 1;
                    assert!((0.0..=1.0).contains(&r[0]) && (0.0..=1.0).contains(&t[0]));
                    // Interpolated |v - t| is at least |interpolated v - interpolated t|.
                    assert!(e[0] >= (r[0] - t[0]).abs() - 1e-5, "{r:?} {t:?} {e:?}");
                }
            }
            assert!(covered > 2000, "{covered} covered pixels");
        }
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        for key in ["machine", "mesh", "tree", "frames", "summary"] {
            assert!(!json[key].is_null(), "report.json lacks {key}");
        }
        assert_eq!(
            json["tree"]["spheres_per_level"],
            serde_json::json!([8, 64, 512])
        );
        std::fs::remove_dir_all(&out).unwrap();
    }
}

#[test]
fn bad_joint_matrices_are_refused() {
    let character = Character::from_static(plane(5, 1.0));
    let tree = flat_tree(
        &[Sphere {
            center: Vec3::Y,
            radius: 0.3,
        }],
        2,
    );
    common::with_gpu(|ctx| {
        let prep = Prepared::new(&character.mesh, &tree, 1)?;
        let mut rec = ctx.recorder("bad matrices")?;
        let kernel = AoKernel::new(&mut rec, &prep, AoParams::default())?;
        let e = kernel
            .record(&mut rec, &[Mat4::IDENTITY, Mat4::IDENTITY])
            .unwrap_err();
        assert!(
            e.to_string().contains("2 joint matrices for a rig of 1"),
            "{e}"
        );
        let mut nan = Mat4::IDENTITY;
        nan.w_axis.x = f32::NAN;
        let e = kernel.record(&mut rec, &[nan]).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
        let e = AoKernel::new(
            &mut rec,
            &prep,
            AoParams {
                tau: 0.0,
                ..AoParams::default()
            },
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("tau"), "{e}");
        drop(rec);
        let e = Prepared::new(&character.mesh, &tree, 0).unwrap_err();
        assert!(e.to_string().contains("joints"), "{e}");
        Ok(())
    });
}

#[test]
fn the_cut_partitions_the_leaves() {
    // For every receiver, each used leaf is covered by exactly one contributing node (itself
    // or one ancestor), so no node counts together with an ancestor or a descendant, also
    // while nodes blend into their children (default band). Checked on the CPU walk, which the GPU matches vertex for
    // vertex (gpu_matches_the_cpu_implementation_on_testwuson compares the counts).
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let run = c.animation("Run").unwrap();
    let posed = cpu::skin(
        &prep,
        &c.rig.skinning_matrices(Some(run), 0.4 * run.duration),
    );
    let (b, first_leaf, n) = (
        prep.shape.branch as usize,
        prep.shape.first_leaf as usize,
        prep.shape.node_count as usize,
    );
    for refine in [
        vkshade::kernels::ao::Refine::Extent,
        vkshade::kernels::ao::Refine::Radius,
    ] {
        for tau in [0.2f32, 0.6, 1.0] {
            let params = AoParams {
                tau,
                refine,
                ..AoParams::default()
            };
            for v in (0..posed.positions.len()).step_by(7) {
                let p = posed.positions[v];
                let mut cut = vec![false; n];
                cpu::walk_cut(
                    p,
                    &posed.spheres,
                    &posed.extents,
                    prep.shape,
                    &params,
                    |node, _, _| {
                        assert!(!cut[node as usize], "node {node} contributes twice");
                        cut[node as usize] = true;
                    },
                );
                for leaf in first_leaf..n {
                    let s = posed.spheres[leaf];
                    if s.w < 0.0 {
                        continue;
                    }
                    let mut covering = 0;
                    let mut node = leaf;
                    loop {
                        covering += cut[node] as usize;
                        if node == 0 {
                            break;
                        }
                        node = (node - 1) / b;
                    }
                    assert_eq!(
                        covering, 1,
                        "vertex {v}, leaf {leaf}, tau {tau}, {refine:?}"
                    );
                    // A leaf holding the receiver is on the cut itself with extent
                    // refinement (its ancestors all reach the receiver); the evaluation then
                    // skips or clamps it. The published radius test may instead keep an
                    // ancestor whose compact sphere looks far away.
                    if s.truncate().distance(p) <= s.w
                        && refine == vkshade::kernels::ao::Refine::Extent
                    {
                        assert!(cut[leaf], "vertex {v}, leaf {leaf}");
                    }
                }
            }
        }
    }
}

#[test]
fn inconsistent_ao_input_is_refused() {
    let c = common::ball();
    let (mut tree, _) = SphereTree::build(
        &c.mesh,
        &BuildConfig {
            samples: 20_000,
            depth: 2,
            ..Default::default()
        },
    )
    .unwrap();
    tree.spheres.truncate(20);
    tree.joints.truncate(20);
    tree.weights.truncate(20);
    tree.importance.truncate(20);
    let e = Prepared::new(&c.mesh, &tree, 1).unwrap_err();
    assert!(e.to_string().contains("complete tree"), "{e}");
    let (tree, _) = SphereTree::build(
        &c.mesh,
        &BuildConfig {
            samples: 20_000,
            depth: 2,
            ..Default::default()
        },
    )
    .unwrap();
    let mut prep = Prepared::new(&c.mesh, &tree, 1).unwrap();
    prep.normals.pop();
    assert!(prep.check().unwrap_err().to_string().contains("normals"));
    let mut prep = Prepared::new(&c.mesh, &tree, 1).unwrap();
    prep.shape.node_count += 1;
    let e = prep.check().unwrap_err().to_string();
    assert!(e.contains("is not a complete tree"), "{e}");
    let mut prep = Prepared::new(&c.mesh, &tree, 1).unwrap();
    prep.sphere_joints[3] = [5, 0];
    assert!(
        prep.check()
            .unwrap_err()
            .to_string()
            .contains("joint index")
    );
}

/// The generic frame runner with three frames in flight, against the CPU twin; then the
/// same kernel driven pass by pass the way a render graph would: barriers planned from the
/// declared accesses and recorded by the caller, vkshade recording none.
#[test]
fn frames_in_flight_and_render_graph_driving_match_the_cpu_twin() {
    use vkshade::kernels::{Kernel, run_frames};
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let params = AoParams {
        correct: false,
        ..AoParams::default()
    };
    let run = c.animation("Run").unwrap();
    let matrices: Vec<Vec<Mat4>> = (0..6)
        .map(|i| {
            c.rig
                .skinning_matrices(Some(run), run.duration * i as f32 / 6.0)
        })
        .collect();
    let twin = |m: &[Mat4]| -> Vec<f32> {
        let posed = cpu::skin(&prep, m);
        cpu_ao
            .frame(&posed, prep.shape, &params, None)
            .iter()
            .map(|v| v.visibility)
            .collect()
    };
    // The bound of `gpu_matches_the_cpu_implementation_on_testwuson` (same method, same data).
    let check = |gpu: &[f32], m: &[Mat4], what: &str| {
        let e = ErrorStats::of(gpu, &twin(m));
        assert!(
            e.mae < 1e-4 && e.p95 < 5e-4 && e.max < 1e-2,
            "{what}: {e:?}"
        );
    };
    common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("ao setup")?;
        let kernel = AoKernel::new(&mut setup, &prep, params)?;
        setup.submit_and_wait()?;
        let names: Vec<&str> = kernel.passes().iter().map(|p| p.name).collect();
        assert_eq!(
            names,
            ["pose joints", "pose skin", "ao skin", "ao occlusion"]
        );
        let mut seen = 0;
        let inputs = matrices.iter().map(Vec::as_slice);
        let most = run_frames(ctx, &kernel, inputs, 3, |r| {
            assert_eq!(r.index, seen, "frames complete in order");
            seen += 1;
            assert!(r.timings.get("ao occlusion").is_some());
            check(&r.output.visibility, &matrices[r.index], "run_frames");
            Ok(())
        })?;
        assert_eq!((seen, most), (6, 3), "six frames, three in flight at once");

        // Render-graph driving: each pass's barriers planned from its declared uses and
        // recorded by the caller; vkshade records none (checked by sync validation).
        let mut rec = ctx.recorder("graph frame")?;
        let mut planned_passes = Vec::new();
        vkshade::kernels::record_as_graph(&mut rec, &kernel, &matrices[4], |pass, planned| {
            planned_passes.push((pass, planned.clone()));
            planned
        })?;
        assert!(rec.take_collected().is_empty(), "every use was planned");
        assert!(
            planned_passes
                .iter()
                .any(|(pass, p)| *pass == "ao occlusion"
                    && p.iter().any(|b| b.resource == "pose positions")),
            "skin -> occlusion needs a barrier on the posed positions: {planned_passes:?}"
        );
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        check(&rb.data()?.visibility, &matrices[4], "render graph");
        Ok(())
    });
}

/// Mean |a - b|.
fn mae(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64)
        .sum::<f64>()
        / a.len().max(1) as f64
}

#[test]
fn error_holds_as_the_cut_refines_on_testwuson() {
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    use vkshade::reference::ao::spheres_visibility;
    // The error used to grow as the cut refined (method alone, 2 frames of Run, every 8th
    // vertex: 0.108 at tau 1.0, 0.124 at 0.3): spheres too small to hold a mask direction
    // were added up even when hidden behind nearer ones, and a finer cut has many of them
    // (the blend minus the exact union of the cut's own spheres: -0.005 at tau 1.0, -0.048
    // at 0.3). Measured after the fix (with the spheres near the receiver shrinking, see
    // cpu::INSIDE_FADE): the method's error 0.109, 0.107, 0.107, 0.112 from tau 1.0 to 0.3.
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let run = c.animation("Run").unwrap();
    let (lo, hi) = c.mesh.bounds();
    let rays = RayConfig {
        rays: 1024,
        ..RayConfig::for_scene((hi - lo).length())
    };
    let taus = [1.0f32, 0.8, 0.5, 0.3];
    let mut method = vec![0.0; taus.len()];
    let mut blend = vec![0.0; taus.len()];
    // With the static correction (the default), baked for each tau as `bench ao` does.
    let mut corrected = vec![0.0; taus.len()];
    let bake = Correction::bake(&c.mesh, 256);
    let factors: Vec<Vec<f32>> = taus
        .iter()
        .map(|&tau| {
            let params = AoParams {
                tau,
                ..AoParams::default()
            };
            bake.factors(&cpu_ao, &prep, &params)
        })
        .collect();
    let frames = 2;
    for f in 0..frames {
        let m = c
            .rig
            .skinning_matrices(Some(run), run.duration * (f as f32 + 0.5) / frames as f32);
        let posed = cpu::skin(&prep, &m);
        let subset: Vec<usize> = (0..posed.positions.len()).step_by(8).collect();
        let bvh = vkshade::geom::Bvh::build(&posed.positions, &c.mesh.triangles);
        let truth = ambient_visibility(&posed.positions, &posed.normals, &bvh, &subset, &rays);
        for (k, &tau) in taus.iter().enumerate() {
            let params = AoParams {
                tau,
                correct: false,
                ..AoParams::default()
            };
            let exact = AoParams {
                occlusion: Occlusion::Exact,
                ..params
            };
            let (mut v, mut e, mut u, mut fv) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for &i in &subset {
                let (p, n) = (posed.positions[i], posed.normals[i]);
                let alone = cpu_ao.vertex(p, n, &posed, prep.shape, &params).visibility;
                v.push(alone);
                fv.push((alone * factors[k][i]).min(1.0));
                e.push(cpu_ao.vertex(p, n, &posed, prep.shape, &exact).visibility);
                let mut cut = Vec::new();
                cpu::walk_cut(
                    p,
                    &posed.spheres,
                    &posed.extents,
                    prep.shape,
                    &exact,
                    |_, s, _| {
                        // The spheres as the method sees them: those holding the receiver
                        // left out, those within INSIDE_FADE radii shrunk.
                        let h = s.truncate().distance(p) / s.w;
                        if h > 1.0 {
                            let t = ((h - 1.0) / cpu::INSIDE_FADE).min(1.0);
                            cut.push(s.truncate().extend(s.w * t))
                        }
                    },
                );
                u.push(spheres_visibility(p, n, i, &cut, &rays));
            }
            method[k] += mae(&v, &truth) / frames as f64;
            corrected[k] += mae(&fv, &truth) / frames as f64;
            blend[k] += mae(&e, &u) / frames as f64;
        }
    }
    eprintln!(
        "tau {taus:?}: method alone MAE {method:?}; corrected {corrected:?}; |blend - union of the cut| {blend:?}"
    );
    // With the correction the sweep must not rise from one tau to the next finer by more
    // than 0.001: the truth and its rays are common to every tau, so a difference is the
    // method's, and 0.001 is a quarter of the rise the bug made in `bench ao` (mask,
    // corrected, tau 1.0 -> 0.3: 0.017 -> 0.021, issue 20).
    for k in 1..taus.len() {
        assert!(
            corrected[k] <= corrected[k - 1] + 0.001,
            "corrected MAE rises from tau {} to {}: {corrected:?}",
            taus[k - 1],
            taus[k]
        );
    }
    // The truth and its rays are the same at every tau, so the differences are the method's.
    // Bounds: the blend stays within 0.02 of the exact union of its spheres at every tau
    // (before the fix 0.049 at 0.3), and no finer cut errs more than 0.006 above the
    // coarsest (measured +0.003 at 0.3; before the fix +0.016).
    for ((tau, b), m) in taus.iter().zip(&blend).zip(&method) {
        assert!(*b < 0.02, "tau {tau}: blend error {b}");
        assert!(
            *m <= method[0] + 0.006,
            "tau {tau}: MAE {m} above tau {}'s {}",
            taus[0],
            method[0]
        );
    }
}

#[test]
fn no_popping_over_consecutive_frames_of_run() {
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    use vkshade::reference::ao::count_jumps;
    // Consecutive frames at the spacing of 60 frames over Run; the method (CPU twin, which
    // the GPU matches to 1e-2 per vertex) against the ray-traced truth with common random
    // rays (each receiver casts the same local directions in every frame). A jump: the
    // method moves by more than 0.1 while the truth moves by less than 0.02. The full count
    // (60 frames, 500 vertices, on the GPU) is `vkshade ao --frames 60 --jumps 500`.
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let run = c.animation("Run").unwrap();
    let (lo, hi) = c.mesh.bounds();
    let rays = RayConfig {
        rays: 256,
        ..RayConfig::for_scene((hi - lo).length())
    };
    let subset: Vec<usize> = (0..prep.vertex_count()).step_by(16).collect();
    let hard = AoParams {
        band: 0.0,
        correct: false,
        ..AoParams::default()
    };
    let blended = AoParams {
        correct: false,
        ..AoParams::default()
    };
    let (mut truth, mut soft, mut sharp) = (Vec::new(), Vec::new(), Vec::new());
    for f in 0..24 {
        let m = c
            .rig
            .skinning_matrices(Some(run), run.duration * f as f32 / 60.0);
        let posed = cpu::skin(&prep, &m);
        let bvh = vkshade::geom::Bvh::build(&posed.positions, &c.mesh.triangles);
        truth.push(ambient_visibility(
            &posed.positions,
            &posed.normals,
            &bvh,
            &subset,
            &rays,
        ));
        let eval = |params: &AoParams| -> Vec<f32> {
            subset
                .iter()
                .map(|&i| {
                    cpu_ao
                        .vertex(
                            posed.positions[i],
                            posed.normals[i],
                            &posed,
                            prep.shape,
                            params,
                        )
                        .visibility
                })
                .collect()
        };
        soft.push(eval(&blended));
        sharp.push(eval(&hard));
    }
    let j_soft = count_jumps(&soft, &truth, 0.1, 0.02);
    let j_hard = count_jumps(&sharp, &truth, 0.1, 0.02);
    eprintln!("blended cut: {j_soft:?}; hard cut: {j_hard:?}");
    assert_eq!(j_soft.jumps, 0, "{j_soft:?}");
}

#[test]
fn no_popping_on_the_gpu_over_60_frames_of_run() {
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    use vkshade::kernels::run_frames;
    use vkshade::reference::ao::count_jumps;
    // Issue 20's count on the GPU path, under validation: 60 consecutive frames of Run (the
    // spacing of `vkshade ao --frames 60`), every 4th vertex, the method alone and with the
    // static correction (the default, whose factors up to 2 could amplify a step), against
    // the ray-traced truth with common random rays (each receiver casts the same local
    // directions in every frame, so the truth's own noise does not move between frames). A
    // jump: the result moves by more than 0.1 while the truth moves by less than 0.02.
    // Before the blended cut and the fading of spheres that come to hold the receiver, the
    // method alone made 45 such jumps in 29,500 vertex-steps.
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let correction = Correction::bake(&c.mesh, 256);
    let run = c.animation("Run").unwrap();
    let (lo, hi) = c.mesh.bounds();
    let rays = RayConfig {
        rays: 256,
        ..RayConfig::for_scene((hi - lo).length())
    };
    let subset: Vec<usize> = (0..prep.vertex_count()).step_by(4).collect();
    let frames = 60;
    let matrices: Vec<Vec<Mat4>> = (0..frames)
        .map(|f| {
            c.rig
                .skinning_matrices(Some(run), run.duration * f as f32 / frames as f32)
        })
        .collect();
    let truth: Vec<Vec<f32>> = matrices
        .iter()
        .map(|m| {
            let posed = cpu::skin(&prep, m);
            let bvh = vkshade::geom::Bvh::build(&posed.positions, &c.mesh.triangles);
            ambient_visibility(&posed.positions, &posed.normals, &bvh, &subset, &rays)
        })
        .collect();
    common::with_gpu(|ctx| {
        for correct in [false, true] {
            let params = AoParams {
                correct,
                ..AoParams::default()
            };
            let mut setup = ctx.recorder("ao jumps setup")?;
            let kernel = AoKernel::new(&mut setup, &prep, params)?;
            if correct {
                let factors = correction.factors(&cpu_ao, &prep, &params);
                kernel.set_correction(&mut setup, &factors)?;
            }
            setup.submit_and_wait()?;
            let mut method = vec![Vec::new(); frames];
            run_frames(ctx, &kernel, matrices.iter().map(Vec::as_slice), 2, |r| {
                method[r.index] = subset.iter().map(|&i| r.output.visibility[i]).collect();
                Ok(())
            })?;
            let j = count_jumps(&method, &truth, 0.1, 0.02);
            eprintln!("GPU, correction {correct}: {j:?}");
            assert_eq!(j.steps, subset.len() * (frames - 1));
            // Measured: 3 of 47,318 (method alone and corrected), e.g. vertex 1072, frames
            // 40 -> 41: 0.355 -> 0.471 while the truth moved 0.004. None is a pop (below):
            // many caps of a deeply buried receiver slide across the mask's 128 directions
            // within one frame. Issue 20's target is 0; this bound holds what is measured.
            assert!(j.jumps <= 4, "correction {correct}: {j:?}");
            // Each counted jump, re-evaluated by the CPU twin (the GPU matches it to 1e-2) at
            // 40 instants between the two frames: a cut or a sphere that switches shows as
            // one sub-step carrying the jump; a continuous change spreads it. Bound: no
            // sub-step above 0.03, under a third of the 0.1 jump (measured <= 0.021).
            let factors = correct.then(|| correction.factors(&cpu_ao, &prep, &params));
            let mut pops = Vec::new();
            for f in 1..frames {
                for (k, &v) in subset.iter().enumerate() {
                    let dm = (method[f][k] - method[f - 1][k]).abs();
                    let dt = (truth[f][k] - truth[f - 1][k]).abs();
                    if !(dm > 0.1 && dt < 0.02) {
                        continue;
                    }
                    let sub = 40;
                    let values: Vec<f32> = (0..=sub)
                        .map(|s| {
                            let t = run.duration * (f as f32 - 1.0 + s as f32 / sub as f32)
                                / frames as f32;
                            let posed = cpu::skin(&prep, &c.rig.skinning_matrices(Some(run), t));
                            let x = cpu_ao.vertex(
                                posed.positions[v],
                                posed.normals[v],
                                &posed,
                                prep.shape,
                                &params,
                            );
                            match &factors {
                                Some(fs) => (x.visibility * fs[v]).min(1.0),
                                None => x.visibility,
                            }
                        })
                        .collect();
                    let step = values
                        .windows(2)
                        .map(|w| (w[1] - w[0]).abs())
                        .fold(0f32, f32::max);
                    eprintln!("  vertex {v}, frame {f}: largest of {sub} sub-steps {step}");
                    pops.push((v, f, step));
                }
            }
            assert!(
                pops.iter().all(|p| p.2 < 0.03),
                "correction {correct}: jumps that switch within a frame (vertex, frame, sub-step): {pops:?}"
            );
        }
        Ok(())
    });
}

#[test]
fn fitted_proxy_per_level_and_sph_round_trip() {
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    use vkshade::kernels::ao::fit::{FitConfig, fit_tree};
    use vkshade::reference::ao::proxy_visibility;
    // A ball: the truth sees the whole sky everywhere (convex), so any occlusion the leaf
    // spheres cast is proxy error: the bumps of spheres poking out of the surface.
    let c = common::ball();
    let build = BuildConfig {
        samples: 40_000,
        depth: 2,
        ..Default::default()
    };
    let (volume, _) = SphereTree::build(&c.mesh, &build).unwrap();
    let cfg = FitConfig {
        cells: 40_000,
        ..Default::default()
    };
    let (fitted, summary) = fit_tree(&c.mesh, &volume, &cfg).unwrap();
    eprintln!("{summary:?}");
    let all: Vec<usize> = (0..c.mesh.positions.len()).collect();
    let rays = RayConfig {
        rays: 256,
        ..RayConfig::for_scene(3.5)
    };
    let bvh = vkshade::geom::Bvh::build(&c.mesh.positions, &c.mesh.triangles);
    let truth = ambient_visibility(&c.mesh.positions, &c.mesh.normals, &bvh, &all, &rays);
    for level in 1..volume.levels {
        let err = |t: &SphereTree| {
            let s: Vec<Vec4> = t.spheres[t.level_range(level)]
                .iter()
                .map(|s| s.center.extend(s.radius))
                .collect();
            mae(
                &proxy_visibility(&c.mesh.positions, &c.mesh.normals, &all, &s, &rays),
                &truth,
            )
        };
        let (ev, ef) = (err(&volume), err(&fitted));
        eprintln!("level {level}: proxy error volume {ev:.4}, fitted {ef:.4}");
        // The fit penalises space outside the mesh: its bumps must not cast more than the
        // volume spheres' do, and little in absolute terms (a ray-traced mean over the
        // ball's receivers; 256 rays add no noise here: the truth is exactly 1).
        assert!(ef <= ev + 1e-3, "level {level}: fitted {ef} > volume {ev}");
        assert!(ef < 0.05, "level {level}: fitted proxy error {ef}");
    }
    // The fitted tree survives the .sph round trip (7 decimals).
    let path = scratch::dir("ao-fit").join("fitted.sph");
    fitted.write_sph(&path).unwrap();
    let back = SphereTree::read_sph(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!((back.levels, back.branch), (fitted.levels, fitted.branch));
    for (a, b) in back.spheres.iter().zip(&fitted.spheres) {
        assert!(a.center.distance(b.center) < 1e-5 && (a.radius - b.radius).abs() < 1e-5);
    }
}

/// Occlusion of a point on a plane by a sphere entirely above its horizon, in closed form
/// (the sphere's projected solid angle over pi): cos(theta) (r / d)^2, theta the angle between
/// the normal and the centre, d the distance to it. Written here from the geometry, not from
/// the method's formula (`kernels::ao::formula`).
fn above_horizon_occlusion(p: Vec3, n: Vec3, centre: Vec3, r: f32) -> f64 {
    let d = centre - p;
    let (len, cos) = (d.length() as f64, (n.dot(d) / d.length()) as f64);
    assert!(
        cos * len >= r as f64,
        "the sphere must lie above the horizon for the closed form"
    );
    cos * (r as f64 / len).powi(2)
}

/// Truths tested against their analytic case: a sphere over a plane. The ray-cast truths
/// (`reference::ao::spheres_visibility` against the exact sphere, and
/// `geom::visibility::ambient_visibility` against a triangle mesh through the BVH) against the
/// closed form at receivers across the plane. Each receiver's estimate (4096 stratified
/// cosine-weighted rays) has a standard error below 0.5 / 64 = 0.0078; the mesh (a UV
/// sphere inscribed in the sphere) occludes between the closed forms of its inscribed and
/// circumscribed spheres. A truth that drops the cosine weight, counts hits behind the ray's
/// origin or misses the sphere's near half fails here.
#[test]
fn ray_cast_truths_match_a_sphere_over_a_plane_in_closed_form() {
    use vkshade::geom::bvh::Bvh;
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    use vkshade::reference::ao::spheres_visibility;
    let (centre, r) = (Vec3::new(0.2, 1.3, -0.1), 1.0f32);
    let ball = common::ball().mesh;
    // The UV sphere's smallest face distance from its centre: its inscribed sphere.
    let r_in = ball
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| ball.positions[i as usize]);
            ((b - a).cross(c - a).normalize().dot(a)).abs()
        })
        .fold(f32::INFINITY, f32::min);
    assert!(r_in > 0.97 && r_in < 1.0, "inscribed radius {r_in}");
    let floor = plane(21, 3.0);
    // One scene: the floor (receivers 0..441) and the ball moved over it.
    let mut positions = floor.positions.clone();
    let mut triangles = floor.triangles.clone();
    let base = positions.len() as u32;
    positions.extend(ball.positions.iter().map(|p| *p * r + centre));
    triangles.extend(ball.triangles.iter().map(|t| t.map(|i| i + base)));
    let normals = vec![Vec3::Y; positions.len()];
    let bvh = Bvh::build(&positions, &triangles);
    // Receivers that see the whole ball above their horizon (cos(theta) d >= r), where the
    // closed form holds.
    let receivers: Vec<usize> = (0..floor.positions.len())
        .filter(|&i| {
            let d = centre - positions[i];
            d.y >= r && d.length() < 3.0
        })
        .collect();
    assert!(receivers.len() > 200, "{} receivers", receivers.len());
    let cfg = RayConfig {
        rays: 4096,
        offset: 1e-4,
        seed: 7,
    };
    let mesh_vis = ambient_visibility(&positions, &normals, &bvh, &receivers, &cfg);
    let (mut sphere_signed, mut worst_sphere, mut worst_mesh) = (0f64, 0f64, 0f64);
    let mut darkest = 1f64;
    for (k, &i) in receivers.iter().enumerate() {
        let p = positions[i];
        let exact = 1.0 - above_horizon_occlusion(p, Vec3::Y, centre, r);
        let exact_in = 1.0 - above_horizon_occlusion(p, Vec3::Y, centre, r * r_in);
        darkest = darkest.min(exact);
        let s = spheres_visibility(p, Vec3::Y, i, &[centre.extend(r)], &cfg) as f64;
        sphere_signed += s - exact;
        worst_sphere = worst_sphere.max((s - exact).abs());
        let m = mesh_vis[k] as f64;
        // Outside [exact, exact_in] by how much.
        worst_mesh = worst_mesh.max((exact - m).max(m - exact_in));
    }
    let bias = sphere_signed / receivers.len() as f64;
    eprintln!(
        "sphere truth: worst {worst_sphere:.4}, mean signed {bias:+.5}; mesh truth: worst {worst_mesh:.4} outside its bracket; darkest {darkest:.3}"
    );
    assert!(darkest < 0.7, "the ball occludes too little: {darkest}");
    // The binomial bound allows 4 x 0.0078 per receiver; stratification (64 x 64 jittered
    // cells) does far better, measured worst 0.0034 (sphere) and 0.0015 beyond the bracket
    // (mesh): bounds of 0.01. The mean over the receivers has no bias beyond 3 binomial
    // standard errors of the mean (measured +0.00009).
    assert!(worst_sphere < 0.01, "sphere truth off by {worst_sphere}");
    assert!(
        bias.abs() < 3.0 * 0.0078 / (receivers.len() as f64).sqrt(),
        "sphere truth biased by {bias}"
    );
    assert!(worst_mesh < 0.01, "mesh truth off by {worst_mesh}");
}

/// The method's accuracy through the library alone (no `cli` feature: a renderer's build
/// keeps this test, where `method_against_the_ray_traced_mesh_on_testwuson` needs the app):
/// Testwuson in two poses of its Run, the default tree and parameters with the bind-pose
/// correction, on the GPU, against the ray-traced posed mesh (1024 stratified rays per vertex,
/// from the CPU's own skinning). Bounds as in that test: MAE <= 0.035 per frame (measured
/// there 0.014-0.020 against a 4096-ray truth; a 1024-ray truth adds ~0.005), and the
/// correction must help (the method alone measured 0.109-0.123).
#[test]
fn method_against_the_ray_traced_mesh_through_the_library() {
    use vkshade::geom::bvh::Bvh;
    use vkshade::geom::visibility::{RayConfig, ambient_visibility};
    let c = testwuson();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let prep = Prepared::new(&c.mesh, &tree, c.rig.joints.len()).unwrap();
    let cpu_ao = CpuAo::new(OcclusionTable::new(TABLE_SIZE, TABLE_SIZE));
    let params = AoParams::default();
    assert!(params.correct, "the default applies the correction");
    let factors = Correction::bake(&c.mesh, 1024).factors(&cpu_ao, &prep, &params);
    let run = c.animation("Run").unwrap();
    let (lo, hi) = c.mesh.bounds();
    let rays = RayConfig {
        rays: 1024,
        ..RayConfig::for_scene((hi - lo).length())
    };
    common::with_gpu(|ctx| {
        for t in [0.3, 0.7] {
            let m = c.rig.skinning_matrices(Some(run), run.duration * t);
            let gpu = gpu_frame(ctx, &c, &tree, params, Some(&factors), &m)?;
            let posed = cpu::skin(&prep, &m);
            let bvh = Bvh::build(&posed.positions, &c.mesh.triangles);
            let all: Vec<usize> = (0..posed.positions.len()).collect();
            let truth = ambient_visibility(&posed.positions, &posed.normals, &bvh, &all, &rays);
            let plain = AoParams {
                correct: false,
                ..params
            };
            let alone: Vec<f32> = cpu_ao
                .frame(&posed, prep.shape, &plain, None)
                .iter()
                .map(|v| v.visibility)
                .collect();
            let (e, e_alone) = (
                ErrorStats::of(&gpu.visibility, &truth),
                ErrorStats::of(&alone, &truth),
            );
            eprintln!(
                "Run at {t}: vs ray-traced MAE {:.4} (method alone {:.4})",
                e.mae, e_alone.mae
            );
            assert!(e.mae <= 0.035, "Run at {t}: {e:?}");
            assert!(
                e.mae < 0.5 * e_alone.mae,
                "Run at {t}: {e:?} vs alone {e_alone:?}"
            );
        }
        Ok(())
    });
}
