//! Environment light on a moving character (kernels::env): the GPU against its CPU twin far
//! from the bind pose, the method against the ray-traced truth at three poses (and below the
//! AO-weighted floor), rotation of the environment, and bad input refused.
// Without `gltf` the tests that load the character are left out, and with them the uses of
// some imports and helpers.
#![cfg_attr(not(feature = "gltf"), allow(unused_imports, dead_code))]

mod common;

use glam::{Mat3, Vec3, Vec4};
use vkshade::geom::sg::{Lobe, fibonacci_sphere};
use vkshade::kernels::Kernel;
use vkshade::kernels::ao::{AoKernel, AoParams, Prepared as AoPrepared, cpu::TreeShape};
use vkshade::kernels::env::{EnvKernel, EnvVisibility, MAX_LOBES, MAX_TRACE_GRID, cpu};
use vkshade::kernels::pose::{PoseKernel, Prepared as PosePrepared};
#[cfg(feature = "gltf")]
use vkshade::scene::spheretree::BuildConfig;

/// 32 lobes over the sphere with sharpness from 0.5 to ~5000 (the whole cap table) and
/// coloured amplitudes.
fn synthetic_lobes() -> Vec<Lobe> {
    fibonacci_sphere(32)
        .iter()
        .enumerate()
        .map(|(k, &a)| {
            let lambda = 0.5 * 2f32.powf(13.3 * k as f32 / 31.0);
            let amp = 1.0 + (k % 5) as f32;
            Lobe::new(a, lambda, [amp, 0.5 * amp, 0.25 * amp + 0.1])
        })
        .collect()
}

/// The largest |GPU - twin| over the irradiance's rgb channels, and the twin's peak.
fn irradiance_gap(gpu: &[[f32; 4]], twin: &[[f32; 4]]) -> (f32, f32) {
    let (mut gap, mut peak) = (0.0f32, 0.0f32);
    for (a, b) in gpu.iter().zip(twin) {
        for c in 0..3 {
            gap = gap.max((a[c] - b[c]).abs());
            peak = peak.max(b[c].abs());
        }
    }
    (gap, peak)
}

fn v3(v: &[[f32; 4]]) -> Vec<Vec3> {
    v.iter().map(|p| Vec4::from_array(*p).truncate()).collect()
}

/// BCN_Epileptic with its sphere tree built by `tree`, and the skinning matrices of the
/// Epileptisch frame (of 16) that moves its vertices farthest from the bind pose.
#[cfg(feature = "gltf")]
fn far_pose(
    tree: &BuildConfig,
) -> (
    vkshade::scene::Character,
    AoPrepared,
    PosePrepared,
    Vec<glam::Mat4>,
) {
    use vkshade::scene::spheretree::SphereTree;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let c = vkshade::scene::load(&path)
        .unwrap_or_else(|e| panic!("{e}\nThe test character comes from tools/setup.sh."));
    let joints = c.rig.joints.len();
    let (tree, _) = SphereTree::build(&c.mesh, tree).unwrap();
    let ao_prep = AoPrepared::new(&c.mesh, &tree, joints).unwrap();
    let pose_prep = PosePrepared::new(&c.mesh, joints).unwrap();
    let anim = c.animation("Epileptisch").unwrap();
    // A pose far from the bind pose: the frame of 16 that moves the vertices farthest.
    let matrices = (0..16)
        .map(|k| {
            c.rig
                .skinning_matrices(Some(anim), anim.duration * k as f32 / 16.0)
        })
        .max_by(|a, b| {
            let moved = |m: &Vec<glam::Mat4>| {
                let p = vkshade::kernels::pose::cpu::pose(&pose_prep, m).unwrap();
                p.positions
                    .iter()
                    .zip(&c.mesh.positions)
                    .map(|(x, y)| x.distance(*y))
                    .sum::<f32>()
            };
            moved(a).total_cmp(&moved(b))
        })
        .unwrap();
    (c, ao_prep, pose_prep, matrices)
}

#[cfg(feature = "gltf")]
#[test]
fn gpu_matches_the_cpu_twin_far_from_the_bind_pose() {
    shadow_matches_its_twin(&BuildConfig::default(), AoParams::default(), 2e-2);
}

/// As gpu_matches_the_cpu_twin_far_from_the_bind_pose with a cut refined nearly to the
/// leaves (tau 0.05): about four times the caps of the default cut, so that the walk's
/// rounds (`env shadow` shades the caps it buffers 8 a round, glsl/env/shadow.glsl) resume
/// over and over, more than sixteen times at most vertices (with the default cut: median 40
/// caps, five rounds, at most 166 caps), and must give the twin's products. Median 163
/// caps, each with its asin/acos ulps (see the bounds there): measured max |dV_j| 2.6e-2,
/// 99.9th percentile 1.6e-3, max |dE| 2.3e-4 of the peak, the same to the digit as
/// the pass that shaded each cap where its walk found it. Bound on any V_j 4e-2; the
/// percentile and E bounds as there (a skipped or repeated round errs by O(0.1-1)).
#[cfg(feature = "gltf")]
#[test]
fn caps_shaded_over_several_rounds_match_the_twin() {
    let median = shadow_matches_its_twin(
        &BuildConfig::default(),
        AoParams {
            tau: 0.05,
            ..AoParams::default()
        },
        4e-2,
    );
    assert!(
        median > 16 * 8,
        "the median vertex shades {median} caps: sixteen rounds or fewer"
    );
}

/// Trees of other depths than 8/64/512 (3 levels): the walk keeps its parent state in
/// registers, one slot per level (the shadow modules' LEVELS), selected by the lane's depth.
/// A tree of 5 levels of branch 3, refined through a band so that the parent blend is taken
/// at the depths below, and a tree of 1 level (no descent at all), against the twin with the
/// bounds of gpu_matches_the_cpu_twin_far_from_the_bind_pose. Measured: max |dV_j| 1.6e-2
/// on the 5-level tree (median 30 caps), 7.8e-3 on the 1-level tree (median 4); with the
/// slots cut to 3 levels the 5-level tree errs by 0.66.
#[cfg(feature = "gltf")]
#[test]
fn gpu_matches_the_cpu_twin_on_deeper_and_shallower_trees() {
    for (depth, branch) in [(5, 3), (1, 8)] {
        let tree = BuildConfig {
            depth,
            branch,
            ..BuildConfig::default()
        };
        let params = AoParams {
            tau: 0.5,
            band: 0.5,
            ..AoParams::default()
        };
        let median = shadow_matches_its_twin(&tree, params, 2e-2);
        eprintln!("{depth} levels of branch {branch}: median {median} caps");
        assert!(median > 0);
    }
}

/// The shadow pass against its twin far from the bind pose, with these AO parameters, no V_j
/// off by `max_dv` or more; the median count of the caps the pass shades per vertex there.
#[cfg(feature = "gltf")]
fn shadow_matches_its_twin(tree: &BuildConfig, ao_params: AoParams, max_dv: f32) -> usize {
    let (_, ao_prep, pose_prep, matrices) = far_pose(tree);
    let lobes = synthetic_lobes();
    let r = vkshade::geom::sg::rotation(Vec3::new(0.3, 1.0, -0.2), 73.0);
    let (frame, spheres, extents, ao, table, params, shape) = common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("env twin")?;
        let pose = PoseKernel::new(&mut rec, &pose_prep)?;
        let ao = AoKernel::on_pose(&mut rec, &ao_prep, ao_params, &pose)?;
        let env = EnvKernel::new(&mut rec, &lobes, &pose, &ao)?;
        let names: Vec<&str> = env.passes().iter().map(|p| p.name).collect();
        assert_eq!(names, ["env rotate", "env shadow"]);
        pose.record(&mut rec, &matrices)?;
        ao.record(&mut rec, &matrices)?;
        env.record(&mut rec, &r)?;
        let out = env.read_back(&mut rec)?;
        let aor = ao.read_back(&mut rec)?;
        let sph = rec.read_back(ao.posed_spheres())?;
        let ext = rec.read_back(ao.posed_extents())?;
        rec.submit_and_wait()?;
        eprintln!("env kernel memory: {:?}", env.memory());
        Ok((
            out.data()?,
            sph.to_vec::<[f32; 4]>()?,
            ext.to_vec::<f32>()?,
            aor.data()?,
            env.table().clone(),
            *env.ao_params(),
            ao.tree_shape(),
        ))
    });
    // The rotated lobes: the same normalize(R axis).
    let rotated = cpu::rotate(&lobes, r);
    for (g, c) in frame.lobes.iter().zip(&rotated) {
        let d = Vec3::from_array(g.axis).distance(c.axis());
        // One f32 matrix product and normalisation: a few ulp of a unit vector.
        assert!(d < 1e-6, "rotated axis off by {d}");
        assert_eq!((g.sharpness, g.amplitude), (c.sharpness, c.amplitude));
    }
    // The twin on the very buffers the shader read (posed vertices, spheres, AO), so only the
    // shadow pass itself is compared.
    let (positions, normals) = (v3(&ao.positions), v3(&ao.normals));
    let spheres: Vec<Vec4> = spheres.iter().map(|s| Vec4::from_array(*s)).collect();
    let twin = cpu::shadow(
        &frame.lobes,
        &table,
        &cpu::ShadowInputs {
            positions: &positions,
            normals: &normals,
            spheres: &spheres,
            extents: &extents,
            shape: TreeShape { ..shape },
            params: &params,
            ao: Some(&ao.visibility),
            rays: None,
        },
    );
    let gpu = &frame.shadowed;
    assert_eq!(gpu.visibility.len(), twin.visibility.len());
    let mut dv: Vec<f32> = gpu
        .visibility
        .iter()
        .zip(&twin.visibility)
        .map(|(a, b)| (a - b).abs())
        .collect();
    dv.sort_by(f32::total_cmp);
    let vis = *dv.last().unwrap();
    let p999 = dv[dv.len() * 999 / 1000];
    let over = dv.iter().filter(|&&d| d > 1e-4).count();
    let (irr, peak) = irradiance_gap(&gpu.irradiance, &twin.irradiance);
    let occluded = twin.visibility.iter().filter(|&&v| v < 0.9).count();
    eprintln!(
        "GPU vs twin: max |dV_j| {vis:.2e} (99.9% {p999:.2e}, {over} over 1e-4), max |dE| {irr:.2e} of peak {peak:.3}; {occluded} of {} V_j < 0.9",
        twin.visibility.len()
    );
    // A real shadowing result, not all ones.
    assert!(occluded > twin.visibility.len() / 50, "{occluded}");
    // Same f32 operations in the same order, but Vulkan lets asin/acos err by 4096 ulp
    // (inherited from atan; ~2.4e-4 of an angle near 1 rad) where the host's are exact to an
    // ulp. The cap table's slope in the lobe-to-cap angle is at most ~0.4 per quarter lobe
    // width, i.e. 1.6 sqrt(lambda) ~ 110 per radian for the sharpest lobe here (lambda ~5000):
    // one cap moves O_js, hence V_j, by up to ~0.03 there, far less for the broad lobes that
    // carry most of the light. Measured (default cut): max |dV_j| 7.3e-3, 99.9th percentile
    // 1.2e-3, max |dE| 2.0e-4 of the peak irradiance. Bounds: max_dv (2e-2) on any V_j, 5e-3
    // on the 99.9th percentile, 1e-3 of the peak on E (a wrong index or a skipped cap errs by
    // O(0.1-1)).
    assert!(vis < max_dv, "V_j differ by {vis}");
    assert!(p999 < 5e-3, "99.9th percentile of |dV_j| {p999}");
    assert!(
        irr < 1e-3 * peak,
        "irradiance differs by {irr} (peak {peak})"
    );
    // The caps `env shadow` shades per vertex: the cut's contributing spheres with the
    // receiver outside (clamp_inside off) and some of the sphere above its horizon, as the
    // shader decides (glsl/env/shadow.glsl).
    assert!(!params.clamp_inside);
    let mut caps: Vec<usize> = positions
        .iter()
        .zip(&normals)
        .map(|(&p, &n)| {
            let mut count = 0;
            vkshade::kernels::ao::cpu::walk_cut(
                p,
                &spheres,
                &extents,
                shape,
                &params,
                |_, s, _| {
                    let dv = s.truncate() - p;
                    let d = dv.length();
                    if d > s.w {
                        let mut h = d / s.w;
                        let fade = vkshade::kernels::ao::cpu::INSIDE_FADE;
                        if h < 1.0 + fade {
                            h /= ((h - 1.0) / fade).max(1e-6);
                        }
                        let cos_t = n.dot(dv) / d;
                        if vkshade::kernels::ao::formula::sphere_occlusion(cos_t, h) > 0.0 {
                            count += 1;
                        }
                    }
                },
            );
            count
        })
        .collect();
    caps.sort_unstable();
    eprintln!(
        "caps shaded per vertex: median {}, most {}",
        caps[caps.len() / 2],
        caps[caps.len() - 1]
    );
    caps[caps.len() / 2]
}

/// The traced visibility (passes `env bvh leaves`, `env bvh refit`, `env trace`) far from the
/// bind pose against its twin [`cpu::traced_visibility`], which refits the same topology on
/// the host and casts the same rays; and the shadow pass scaled by it against the twin of
/// `env shadow` given the GPU's visibility. The rays come from the same integer hash and f32
/// operations, but a device's sin and cos may differ in the last bits, so a ray grazing an
/// edge may decide the other way: one ray is 1/16 of a vertex's visibility. Measured: 0 of 3014
/// vertices differ. Bounds: at most 1% of the vertices differ, none by more than 2 rays, the
/// mean by < 1e-3. A BVH left in the rest pose (no refit), a wrong basis or a wrong stratum
/// moves hundreds of vertices by several rays.
#[cfg(feature = "gltf")]
#[test]
fn traced_visibility_matches_its_twin_far_from_the_bind_pose() {
    traced_visibility_matches_its_twin(4);
}

/// As traced_visibility_matches_its_twin_far_from_the_bind_pose with 49 rays per vertex:
/// `env trace` walks the BVH 4 rays at a time, so these are twelve walks of 4 rays (some
/// across two azimuth columns of 7) and one of a single ray, whose escape bits fill the
/// vertex's first word and start its second.
#[cfg(feature = "gltf")]
#[test]
fn traced_visibility_in_several_ray_packets_matches_its_twin() {
    traced_visibility_matches_its_twin(7);
}

#[cfg(feature = "gltf")]
fn traced_visibility_matches_its_twin(grid: u32) {
    let (c, ao_prep, pose_prep, matrices) = far_pose(&BuildConfig::default());
    let lobes = synthetic_lobes();
    let r = vkshade::geom::sg::rotation(Vec3::new(-0.4, 1.0, 0.1), 31.0);
    let (frame, scale, bits, ao, spheres, extents, table, params, shape, topology, cfg) =
        common::with_gpu(|ctx| {
            let mut rec = ctx.recorder("env traced twin")?;
            let pose = PoseKernel::new(&mut rec, &pose_prep)?;
            let ao = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &pose)?;
            let env = EnvKernel::with_visibility(
                &mut rec,
                &lobes,
                &pose,
                &ao,
                EnvVisibility::Traced {
                    rest: &c.mesh.positions,
                    triangles: &c.mesh.triangles,
                    grid,
                },
            )?;
            let names: Vec<&str> = env.passes().iter().map(|p| p.name).collect();
            assert_eq!(
                names,
                [
                    "env rotate",
                    "env bvh leaves",
                    "env bvh refit",
                    "env trace",
                    "env shadow"
                ]
            );
            pose.record(&mut rec, &matrices)?;
            ao.record(&mut rec, &matrices)?;
            env.record(&mut rec, &r)?;
            let out = env.read_back(&mut rec)?;
            let scale = rec.read_back(env.scale_visibility())?;
            let bits = rec.read_back(env.escaped_rays().expect("traced"))?;
            let aor = ao.read_back(&mut rec)?;
            let sph = rec.read_back(ao.posed_spheres())?;
            let ext = rec.read_back(ao.posed_extents())?;
            rec.submit_and_wait()?;
            eprintln!("env kernel memory (traced): {:?}", env.memory());
            let (top, cfg) = env.traced().expect("built with traced visibility");
            Ok((
                out.data()?,
                scale.to_vec::<f32>()?,
                bits.to_vec::<u32>()?,
                aor.data()?,
                sph.to_vec::<[f32; 4]>()?,
                ext.to_vec::<f32>()?,
                env.table().clone(),
                *env.ao_params(),
                ao.tree_shape(),
                top.clone(),
                *cfg,
            ))
        });
    let (positions, normals) = (v3(&ao.positions), v3(&ao.normals));
    let (twin, twin_bits) = cpu::traced_rays(&topology, &positions, &normals, &cfg);
    // The escape bits say the same as the fractions: as many set per vertex, and the same
    // rays on (nearly) every vertex.
    assert_eq!(bits.len(), twin_bits.len());
    let words = twin_bits.len() / twin.len();
    for (v, f) in scale.iter().enumerate() {
        let set: u32 = bits[v * words..(v + 1) * words]
            .iter()
            .map(|w| w.count_ones())
            .sum();
        assert_eq!(set as f32 / (grid * grid) as f32, *f, "vertex {v}");
    }
    let rays_differ: u32 = bits
        .iter()
        .zip(&twin_bits)
        .map(|(a, b)| (a ^ b).count_ones())
        .sum();
    let step = 1.0 / (grid * grid) as f32;
    let differ = scale.iter().zip(&twin).filter(|(a, b)| a != b).count();
    let worst = scale
        .iter()
        .zip(&twin)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    let mean = scale
        .iter()
        .zip(&twin)
        .map(|(a, b)| (a - b).abs() as f64)
        .sum::<f64>()
        / twin.len() as f64;
    let shaded = twin.iter().filter(|&&v| v < 0.75).count();
    eprintln!(
        "traced visibility GPU vs twin: {differ} of {} vertices differ, worst {worst} ({} rays), mean {mean:.2e}; {shaded} below 0.75; {rays_differ} rays differ",
        twin.len(),
        worst / step
    );
    assert!(
        rays_differ as usize <= twin.len() / 50,
        "{rays_differ} rays differ"
    );
    // A real visibility, not all ones (the character shades itself far from the bind pose).
    assert!(shaded > twin.len() / 20, "{shaded}");
    assert!(differ <= twin.len() / 100, "{differ} vertices differ");
    assert!(worst <= 2.0 * step + 1e-6, "a vertex differs by {worst}");
    assert!(mean < 1e-3, "mean difference {mean}");
    // The shadow pass (module env/shadow_rays) against its twin given the GPU's rays.
    let spheres: Vec<Vec4> = spheres.iter().map(|s| Vec4::from_array(*s)).collect();
    let shadow = cpu::shadow(
        &frame.lobes,
        &table,
        &cpu::ShadowInputs {
            positions: &positions,
            normals: &normals,
            spheres: &spheres,
            extents: &extents,
            shape,
            params: &params,
            ao: None,
            rays: Some(cpu::RayBits {
                bits: &bits,
                grid,
                seed: cfg.seed,
            }),
        },
    );
    let (irr, peak) = irradiance_gap(&frame.shadowed.irradiance, &shadow.irradiance);
    let mut dv: Vec<f32> = frame
        .shadowed
        .visibility
        .iter()
        .zip(&shadow.visibility)
        .map(|(a, b)| (a - b).abs())
        .collect();
    dv.sort_by(f32::total_cmp);
    let (vis, p999) = (*dv.last().unwrap(), dv[dv.len() * 999 / 1000]);
    eprintln!(
        "shadow_rays GPU vs twin: max |dV_j| {vis:.2e} (99.9% {p999:.2e}), max |dE| {irr:.2e} of peak {peak:.3}"
    );
    // The caps' part errs as in gpu_matches_the_cpu_twin_far_from_the_bind_pose (asin/acos
    // within 4096 ulp on a device); the rays' residuals add the device's exp and the
    // directions' sin and cos, so a ray on a cap's rim may fall on the other side there: one
    // residual of 16, weighed by the lobe, moves that V_j by up to ~0.5 for a lobe that sees
    // few rays. Measured on lavapipe: max |dV_j| 4.9e-3, 99.9th percentile 1.3e-3, no flip.
    // Bounds: 5e-3 on the 99.9th percentile (as there) and under 0.1% of the V_j off by more
    // than 2e-2; a wrong ray, bit or kernel moves most V_j of a vertex.
    assert!(p999 < 5e-3, "99.9th percentile of |dV_j| {p999}");
    let off = dv.iter().filter(|&&d| d > 2e-2).count();
    assert!(off * 1000 < dv.len(), "{off} V_j differ by more than 2e-2");
    // As in gpu_matches_the_cpu_twin_far_from_the_bind_pose: 1e-3 of the peak.
    assert!(
        irr < 1e-3 * peak,
        "irradiance differs by {irr} (peak {peak})"
    );
}

/// A sphere tree with every node unused: no caps; AO's visibility is 1.
fn no_occluder_scene() -> (AoPrepared, PosePrepared) {
    let ball = common::ball();
    let m = &ball.mesh;
    let (tree, _) = vkshade::scene::spheretree::SphereTree::build(
        m,
        &vkshade::scene::spheretree::BuildConfig::default(),
    )
    .unwrap();
    let mut ao = AoPrepared::new(m, &tree, 1).unwrap();
    for s in ao.spheres.iter_mut() {
        s[3] = -1.0;
    }
    (ao, PosePrepared::new(m, 1).unwrap())
}

/// Exact irradiance of a unit SG (the note's 1D form, f64 midpoint rule).
fn exact_irradiance(theta: f64, lambda: f64) -> f64 {
    let nt = 8000;
    let mut sum = 0.0;
    for i in 0..nt {
        let t = std::f64::consts::PI * (i as f64 + 0.5) / nt as f64;
        let (a, b) = (theta.cos() * t.cos(), theta.sin() * t.sin());
        let g = if a >= b.abs() {
            std::f64::consts::TAU * a
        } else if a <= -b.abs() {
            0.0
        } else {
            2.0 * (a * (-a / b.abs()).acos() + (b * b - a * a).sqrt())
        };
        sum += (lambda * (t.cos() - 1.0)).exp() * t.sin() * g;
    }
    sum * std::f64::consts::PI / nt as f64
}

#[test]
fn rotating_the_environment_rotates_the_irradiance() {
    let (ao_prep, pose_prep) = no_occluder_scene();
    let normals: Vec<Vec3> = ao_prep
        .normals
        .iter()
        .map(|n| Vec4::from_array(*n).truncate())
        .collect();
    for lambda in [0.7f32, 6.0, 60.0] {
        let lobe = Lobe::new(Vec3::new(0.2, 0.9, 0.1), lambda, [2.0, 1.0, 0.5]);
        let rotations = [
            Mat3::IDENTITY,
            vkshade::geom::sg::rotation(Vec3::Y, 90.0),
            vkshade::geom::sg::rotation(Vec3::new(1.0, 0.4, -0.3), 140.0),
        ];
        common::with_gpu(|ctx| {
            let mut rec = ctx.recorder("env rotation")?;
            let pose = PoseKernel::new(&mut rec, &pose_prep)?;
            let ao = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &pose)?;
            let env = EnvKernel::new(&mut rec, &[lobe], &pose, &ao)?;
            // The pose and AO once (rest pose; AO = 1 without spheres): the frames below
            // record the environment alone.
            pose.record(&mut rec, &[glam::Mat4::IDENTITY])?;
            ao.record(&mut rec, &[glam::Mat4::IDENTITY])?;
            rec.submit_and_wait()?;
            let total = vkshade::geom::sg::integral(lambda as f64);
            vkshade::kernels::run_frames(ctx, &env, rotations.iter(), 2, |f| {
                let r = rotations[f.index];
                let axis = (r * lobe.axis()).normalize();
                assert!(f.output.lobes[0].axis().distance(axis) < 1e-6);
                let mut worst: f64 = 0.0;
                for (v, e) in f.output.shadowed.irradiance.iter().enumerate() {
                    // No occluders: V = 1 exactly.
                    assert_eq!(f.output.shadowed.visibility[v], 1.0);
                    let theta = (normals[v].dot(axis) as f64).clamp(-1.0, 1.0).acos();
                    let want = exact_irradiance(theta, lambda as f64);
                    for (x, a) in e.iter().zip(lobe.amplitude) {
                        let got = *x as f64 / a as f64;
                        worst = worst.max((got - want).abs() / total);
                    }
                }
                eprintln!(
                    "lambda {lambda}, rotation {}: worst |E - exact| {worst:.4} of the lobe's integral",
                    f.index
                );
                // The irradiance fits' own error (the note's measured maxima: inner product
                // <= 0.032 below lambda 1, Hill <= 0.020); a wrong rotation (the axis not
                // turned, or turned by R^T) errs by O(1) of the integral.
                assert!(worst < 0.035, "{worst}");
                Ok(())
            })?;
            Ok(())
        });
    }
}

#[test]
fn bad_input_is_refused() {
    let (ao_prep, pose_prep) = no_occluder_scene();
    let lobe = Lobe::new(Vec3::Z, 4.0, [1.0; 3]);
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("env refusals")?;
        let pose = PoseKernel::new(&mut rec, &pose_prep)?;
        let ao = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &pose)?;
        let msg = |r: vkshade::Result<EnvKernel>| match r {
            Ok(_) => panic!("accepted"),
            Err(e) => e.to_string(),
        };
        assert!(msg(EnvKernel::new(&mut rec, &[], &pose, &ao)).contains("0 environment lobes"));
        let many = vec![lobe; MAX_LOBES + 1];
        assert!(msg(EnvKernel::new(&mut rec, &many, &pose, &ao)).contains("1..=64"));
        let nan = Lobe {
            axis: [f32::NAN, 0.0, 1.0],
            ..lobe
        };
        assert!(msg(EnvKernel::new(&mut rec, &[lobe, nan], &pose, &ao)).contains("lobe 1"));
        // A pose of another mesh.
        let other = PosePrepared::new(&common::ball().mesh, 1)?;
        let mut small = other.clone();
        small.positions.truncate(10);
        small.normals.truncate(10);
        small.tangents.truncate(10);
        small.vertex_joints.truncate(10);
        small.vertex_weights.truncate(10);
        let small_pose = PoseKernel::new(&mut rec, &small)?;
        assert!(msg(EnvKernel::new(&mut rec, &[lobe], &small_pose, &ao)).contains("vertices"));
        // Traced visibility: the grid's range, the mesh's vertex count and its triangles.
        let ball = common::ball();
        fn traced<'a>(grid: u32, rest: &'a [Vec3], triangles: &'a [[u32; 3]]) -> EnvVisibility<'a> {
            EnvVisibility::Traced {
                rest,
                triangles,
                grid,
            }
        }
        let (rest, tris) = (&ball.mesh.positions, &ball.mesh.triangles);
        for grid in [0, MAX_TRACE_GRID + 1] {
            let e = msg(EnvKernel::with_visibility(
                &mut rec,
                &[lobe],
                &pose,
                &ao,
                traced(grid, rest, tris),
            ));
            assert!(e.contains("strata per axis") && e.contains("1..=16"), "{e}");
        }
        let e = msg(EnvKernel::with_visibility(
            &mut rec,
            &[lobe],
            &pose,
            &ao,
            traced(4, &rest[..10], tris),
        ));
        assert!(e.contains("the mesh has 10 vertices"), "{e}");
        let mut bad_tris = tris.clone();
        bad_tris[3] = [0, 1, rest.len() as u32];
        let e = msg(EnvKernel::with_visibility(
            &mut rec,
            &[lobe],
            &pose,
            &ao,
            traced(4, rest, &bad_tris),
        ));
        assert!(e.contains("triangle 3 names vertex"), "{e}");
        let env = EnvKernel::new(&mut rec, &[lobe; MAX_LOBES], &pose, &ao)?;
        let mut bad = Mat3::IDENTITY;
        bad.x_axis.y = f32::NAN;
        let e = env.record(&mut rec, &bad).unwrap_err().to_string();
        assert!(e.contains("not finite"), "{e}");
        let e = env
            .record(&mut rec, &Mat3::from_diagonal(Vec3::splat(2.0)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("orthonormal"), "{e}");
        // Nothing was recorded by the refusals: a good frame still runs.
        pose.record(&mut rec, &[glam::Mat4::IDENTITY])?;
        ao.record(&mut rec, &[glam::Mat4::IDENTITY])?;
        env.record(&mut rec, &Mat3::IDENTITY)?;
        let out = env.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        let f = out.data()?;
        assert_eq!(f.lobes.len(), MAX_LOBES);
        assert!(f.shadowed.irradiance.iter().all(|e| e[0].is_finite()));
        Ok(())
    });
}

/// `vkshade env --frames 3 --reference` on BCN_Epileptic's Epileptisch under the forest map's
/// 32-lobe fit, the caps' split corrected per lobe by 16 rays a vertex traced through the
/// posed mesh (the default): at each pose the relative L2 over vertices vs the ray-traced
/// truth is within the issue's 10% and below the AO-weighted floor's (measured with 1024
/// rays on the cut of `CV_TAU` 1.4: 8.37 / 8.02 / 8.23% vs the floor's 11.1 / 16.3 / 18.6%;
/// 7.63 / 7.77 / 7.92% on tau 1.2's). The same caps scaled by the same rays' escaped
/// fraction (one number per vertex, the method before the per-lobe correction) read 9.81 /
/// 10.10 / 10.45% (tau 1.2: 9.17 / 9.64 / 10.60%), and must stay worse at every pose, so a
/// correction that does nothing fails. With the truth's own 1024-ray visibility as the scale
/// the caps of the shadow pass's cut (coarser than AO's, `CV_TAU`) give 8.8 / 9.4 / 10.2%
/// (tau 1.2: 8.4 / 9.1 / 10.0%), bounded here by 11%, so a bug in the split (a cap's
/// occlusion: the caps alone err 21-25%) fails even where the rays are right.
#[cfg(all(feature = "cli", feature = "gltf"))]
#[test]
fn beats_the_ao_floor_against_the_ray_traced_truth_at_three_poses() {
    use vkshade::app::env::{EnvRunConfig, run};
    common::hold_gpu(); // `run` makes its own context
    let out = common::temp_dir("env");
    let cfg = EnvRunConfig {
        mesh: std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb"),
        frames: 3,
        reference: true,
        rays: 1024,
        out: out.clone(),
        ..EnvRunConfig::default()
    };
    let report = common::with_gpu(|ctx| run(ctx, &cfg, &mut |l| eprintln!("{l}")));
    assert_eq!(report.frames.len(), 3);
    for f in &report.frames {
        let (mine, floor) = (f.rel_l2.unwrap(), f.floor_rel_l2.unwrap());
        eprintln!(
            "frame {}: env shadow {:.2}%, AO floor {:.2}%, unshadowed {:.2}%",
            f.frame,
            100.0 * mine,
            100.0 * floor,
            100.0 * f.unshadowed_rel_l2.unwrap()
        );
        assert!(mine < floor, "frame {}: {mine} >= floor {floor}", f.frame);
        // The issue's target at every pose (the truth's noise at 1024 rays included).
        assert!(mine <= 0.10, "frame {}: {mine}", f.frame);
        let split = f.traced_ao_rel_l2.unwrap();
        eprintln!(
            "frame {}: with traced AO {:.2}%, AO MAE {:.4}",
            f.frame,
            100.0 * split,
            f.ao_mae.unwrap()
        );
        assert!(split <= 0.11, "frame {}: the split alone {split}", f.frame);
        let scaled = f.traced_scale_rel_l2.unwrap();
        eprintln!(
            "frame {}: scaled by the rays {:.2}%",
            f.frame,
            100.0 * scaled
        );
        assert!(
            mine < scaled,
            "frame {}: corrected per lobe {mine} vs scaled {scaled}",
            f.frame
        );
        let ply = std::fs::read(f.ply.as_ref().unwrap()).unwrap();
        let head = String::from_utf8_lossy(&ply[..400.min(ply.len())]).to_string();
        for p in ["property float r", "property float g", "property float b"] {
            assert!(head.contains(p), "{head}");
        }
    }
    let _ = std::fs::remove_dir_all(out);
}

/// Module `env/shadow_rays`'s per-lobe correction on the CPU twin, with no caps (every
/// sphere unused, so the caps' visibility is 1 and each ray's residual is e_k - 1): all 16
/// rays escaped give V_j = 1, none V_j = 0, and when only the rays on the +x side of the
/// normal escape, a lobe leaning to +x sees most of them and one leaning to -x few. A sign
/// slip in the residual, the kernel weighing the far rays, or the bits read for the wrong
/// rays fails it. Measured: 0.99 and 0.01 for the two leaning lobes (sharpness 20, kernel 8).
#[test]
fn traced_rays_correct_each_lobe_toward_the_rays_that_escape_on_its_side() {
    let n = Vec3::Z;
    let (t, b) = vkshade::geom::orthonormal_basis(n);
    let (grid, seed) = (4, 0x1234);
    let dirs: Vec<Vec3> = (0..grid * grid)
        .map(|k| cpu::ray_direction(0, k, grid, seed, t, b, n))
        .collect();
    let lobe = |x: f32| Lobe {
        axis: Vec3::new(x, 0.0, 1.0).normalize().to_array(),
        sharpness: 20.0,
        amplitude: [1.0; 3],
    };
    let lobes = [lobe(1.0), lobe(-1.0)];
    let spheres = vec![Vec4::new(0.0, 0.0, 0.0, -1.0); 9];
    let extents = vec![0.0f32; 9];
    let params = AoParams::default();
    let run = |escaped: &dyn Fn(Vec3) -> bool| {
        let bits = [dirs
            .iter()
            .enumerate()
            .filter(|(_, d)| escaped(**d))
            .fold(0u32, |w, (k, _)| w | 1 << k)];
        cpu::shadow(
            &lobes,
            &vkshade::kernels::env::CapTable::new(),
            &cpu::ShadowInputs {
                positions: &[Vec3::ZERO],
                normals: &[n],
                spheres: &spheres,
                extents: &extents,
                shape: TreeShape {
                    node_count: 9,
                    branch: 8,
                    first_leaf: 1,
                },
                params: &params,
                ao: None,
                rays: Some(cpu::RayBits {
                    bits: &bits,
                    grid,
                    seed,
                }),
            },
        )
        .visibility
    };
    assert_eq!(run(&|_| true), [1.0, 1.0]);
    assert_eq!(run(&|_| false), [0.0, 0.0]);
    let half = run(&|d| d.x > 0.0);
    eprintln!("+x half open: V = {half:?}");
    assert!(dirs.iter().filter(|d| d.x > 0.0).count() >= 4);
    assert!(half[0] > 0.8 && half[1] < 0.2, "{half:?}");
}
