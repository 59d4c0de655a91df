//! The shared posed geometry (kernels::pose): the GPU skinning pass against its CPU twin on a
//! real character far from its bind pose, tangent frames against the UVs they come from, and
//! bad input refused before anything is recorded.

mod common;

use glam::{Mat4, Vec3};
use vkshade::kernels::pose::{PoseKernel, Prepared, cpu};
use vkshade::scene::{Character, MeshData};

fn bcn() -> Character {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    vkshade::scene::load(&path).unwrap_or_else(|e| {
        panic!("{e}\nThe test character comes from tools/setup.sh (assimp-testmodels converted to glTF).")
    })
}

/// The time of `anim` (of 32 spread over it) whose pose moves the vertices farthest from the
/// bind pose on average, with that mean displacement.
fn farthest_pose(c: &Character, prep: &Prepared, anim: &str) -> (Vec<Mat4>, f32) {
    let a = c.animation(anim).unwrap();
    (0..32)
        .map(|k| {
            let m = c
                .rig
                .skinning_matrices(Some(a), a.duration * k as f32 / 32.0);
            let posed = cpu::pose(prep, &m).unwrap();
            let moved = posed
                .positions
                .iter()
                .zip(&c.mesh.positions)
                .map(|(p, r)| p.distance(*r))
                .sum::<f32>()
                / posed.positions.len() as f32;
            (m, moved)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap()
}

#[test]
fn gpu_skinning_matches_the_cpu_twin_far_from_the_bind_pose() {
    let c = bcn();
    let prep = Prepared::new(&c.mesh, c.rig.joints.len()).unwrap();
    let (matrices, moved) = farthest_pose(&c, &prep, "Epileptisch");
    let (lo, hi) = c.mesh.bounds();
    let size = (hi - lo).length();
    eprintln!(
        "{} vertices; mean displacement from the bind pose {moved:.4} ({:.1}% of the diagonal)",
        prep.vertex_count(),
        100.0 * moved / size
    );
    // Far from the bind pose: the vertices moved on average by more than 1% of the size.
    assert!(moved > 0.01 * size, "pose too close to the bind pose");
    let cpu = cpu::pose(&prep, &matrices).unwrap();
    let gpu = common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("pose test")?;
        let kernel = PoseKernel::new(&mut rec, &prep)?;
        kernel.record(&mut rec, &matrices)?;
        let readback = kernel.read_back(&mut rec)?;
        rec.submit()?.wait()?;
        let posed = readback.data()?;
        // A second frame through the contract's frame runner gives the same result.
        let mut again = None;
        vkshade::kernels::run_frames(ctx, &kernel, [&matrices[..]], 1, |f| {
            again = Some(f.output);
            Ok(())
        })?;
        let again = again.expect("one frame ran");
        assert_eq!(again.positions, posed.positions);
        eprintln!("pose kernel memory: {:?}", kernel.memory());
        Ok(posed)
    });
    // Same f32 operations in the same order; the driver may contract a*b+c into an FMA
    // (Vulkan allows it), which moves a product by <= 1 ulp of the sum: for |p| ~ 2 m, a few
    // 1e-7. Positions within 1e-5 of the size, directions within 1e-5 (unit vectors).
    let pos = gpu
        .positions
        .iter()
        .zip(&cpu.positions)
        .map(|(g, c)| g.distance(*c))
        .fold(0f32, f32::max);
    let nrm = gpu
        .normals
        .iter()
        .zip(&cpu.normals)
        .map(|(g, c)| g.distance(*c))
        .fold(0f32, f32::max);
    let tan = gpu
        .tangents
        .iter()
        .zip(&cpu.tangents)
        .map(|(g, c)| g.truncate().distance(c.truncate()))
        .fold(0f32, f32::max);
    let hand = gpu
        .tangents
        .iter()
        .zip(&cpu.tangents)
        .filter(|(g, c)| g.w != c.w)
        .count();
    eprintln!("max |GPU - CPU|: position {pos:e}, normal {nrm:e}, tangent {tan:e}");
    assert!(pos < 1e-5 * size, "positions differ by {pos}");
    assert!(nrm < 1e-5 && tan < 1e-5, "normal {nrm}, tangent {tan}");
    assert_eq!(hand, 0, "handedness differs");
    // The posed frames are orthonormal.
    for (n, t) in gpu.normals.iter().zip(&gpu.tangents) {
        assert!((n.length() - 1.0).abs() < 1e-5 && (t.truncate().length() - 1.0).abs() < 1e-5);
        assert!(n.dot(t.truncate()).abs() < 1e-5);
        assert!(t.w == 1.0 || t.w == -1.0);
    }
}

/// A flat grid in z = 0, u along +x; `mirror` flips u (u = 1 - x), as a mirrored chart does.
fn grid(mirror: bool) -> Character {
    let n = 4u32;
    let mut d = MeshData::default();
    let mut uvs = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            d.positions.push([x, y, 0.0]);
            uvs.push([if mirror { 1.0 - x } else { x }, y]);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let v = |i: u32, j: u32| j * (n + 1) + i;
            d.triangles.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            d.triangles.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    d.uvs = Some(uvs);
    Character::from_static(
        vkshade::scene::Mesh::from_data(d, std::path::Path::new("grid")).unwrap(),
    )
}

#[test]
fn tangent_frames_follow_the_uvs_and_their_mirroring() {
    for mirror in [false, true] {
        let c = grid(mirror);
        let prep = Prepared::new(&c.mesh, 1).unwrap();
        // A rigid turn: 90 degrees about +z, so +x goes to +y.
        let m = [Mat4::from_rotation_z(std::f32::consts::FRAC_PI_2)];
        let posed = cpu::pose(&prep, &m).unwrap();
        for (k, (n, t)) in posed.normals.iter().zip(&posed.tangents).enumerate() {
            // dP/du is +x (mirror: -x), turned to +y (-y); dP/dv is +y, turned to -x.
            let want_t = if mirror { -Vec3::Y } else { Vec3::Y };
            assert!(
                t.truncate().distance(want_t) < 1e-5,
                "mirror {mirror}, vertex {k}: tangent {t}"
            );
            let bitangent = t.w * n.cross(t.truncate());
            assert!(
                bitangent.distance(-Vec3::X) < 1e-5,
                "mirror {mirror}, vertex {k}: +v along {bitangent}"
            );
            assert_eq!(t.w, if mirror { -1.0 } else { 1.0 });
        }
    }
    // A zero normal (a degenerate vertex) still gets a finite unit tangent.
    assert_eq!(
        vkshade::kernels::pose::pack::perpendicular(Vec3::ZERO),
        Vec3::X
    );
    // Without UVs: a perpendicular of the normal, right-handed.
    let mut c = grid(false);
    c.mesh.uvs = None;
    let prep = Prepared::new(&c.mesh, 1).unwrap();
    for (n, t) in prep.normals.iter().zip(&prep.tangents) {
        let (n, t) = (Vec3::from_slice(n), Vec3::from_slice(t));
        assert!(n.dot(t).abs() < 1e-6 && (t.length() - 1.0).abs() < 1e-6);
    }
}

#[test]
fn bad_frames_and_bad_rest_poses_are_refused() {
    let c = grid(false);
    let prep = Prepared::new(&c.mesh, 1).unwrap();
    let mut nan = prep.clone();
    nan.tangents[3][1] = f32::NAN;
    let e = nan.check().unwrap_err().to_string();
    assert!(e.contains("vertex 3") && e.contains("tangent"), "{e}");
    let mut joint = prep.clone();
    joint.vertex_joints[2] = [1, 0];
    let e = joint.check().unwrap_err().to_string();
    assert!(e.contains("vertex 2") && e.contains("joint"), "{e}");
    let mut short = prep.clone();
    short.normals.pop();
    let n = prep.normals.len();
    let e = short.check().unwrap_err().to_string();
    assert!(
        e.contains(&format!("{} normals for {n} vertices", n - 1)),
        "{e}"
    );
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("pose bad input")?;
        let kernel = PoseKernel::new(&mut rec, &prep)?;
        let e = PoseKernel::new(&mut rec, &nan)
            .err()
            .expect("a NaN tangent is refused");
        assert!(
            e.to_string().contains("vertex 3 has a non-finite tangent"),
            "{e}"
        );
        let e = kernel.record(&mut rec, &[]).unwrap_err().to_string();
        assert!(e.contains("0 joint matrices for a rig of 1"), "{e}");
        let e = kernel
            .record(&mut rec, &[Mat4::from_scale(Vec3::splat(f32::NAN))])
            .unwrap_err()
            .to_string();
        assert!(e.contains("not finite"), "{e}");
        // Nothing was recorded by the refused frames: a good one still runs.
        kernel.record(&mut rec, &[Mat4::IDENTITY])?;
        let r = kernel.read_back(&mut rec)?;
        rec.submit()?.wait()?;
        let posed = r.data()?;
        assert_eq!(posed.positions, c.mesh.positions);
        Ok(())
    });
}

#[test]
fn ao_on_the_shared_pose_equals_ao_posing_its_own() {
    use vkshade::kernels::ao::{AoKernel, AoParams, Prepared as AoPrepared};
    use vkshade::scene::spheretree::{BuildConfig, SphereTree};
    let c = bcn();
    let (tree, _) = SphereTree::build(&c.mesh, &BuildConfig::default()).unwrap();
    let joints = c.rig.joints.len();
    let ao_prep = AoPrepared::new(&c.mesh, &tree, joints).unwrap();
    let pose_prep = Prepared::new(&c.mesh, joints).unwrap();
    let (matrices, _) = farthest_pose(&c, &pose_prep, "Epileptisch");
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("shared pose")?;
        let pose = PoseKernel::new(&mut rec, &pose_prep)?;
        let shared = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &pose)?;
        let own = AoKernel::new(&mut rec, &ao_prep, AoParams::default())?;
        // The shared kernel records no pose of its own: the caller records it first.
        let names: Vec<&str> = vkshade::kernels::Kernel::passes(&shared)
            .iter()
            .map(|p| p.name)
            .collect();
        assert_eq!(names, ["ao skin", "ao occlusion"]);
        // With its occlusion pass off it skins the spheres alone, refuses to read back a
        // visibility it does not compute, and an environment that would scale by it is
        // refused.
        let mut spheres_only = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &pose)?;
        spheres_only.set_occlusion(false);
        let names: Vec<&str> = vkshade::kernels::Kernel::passes(&spheres_only)
            .iter()
            .map(|p| p.name)
            .collect();
        assert_eq!(names, ["ao skin"]);
        let e = spheres_only
            .read_back(&mut rec)
            .err()
            .expect("no visibility to read");
        assert!(e.to_string().contains("occlusion pass is off"), "{e}");
        let lobe = vkshade::geom::sg::Lobe::new(Vec3::Y, 4.0, [1.0; 3]);
        let e = vkshade::kernels::env::EnvKernel::new(&mut rec, &[lobe], &pose, &spheres_only)
            .err()
            .expect("AO's scale without AO's occlusion is refused");
        assert!(e.to_string().contains("occlusion pass is off"), "{e}");
        // A pose of another mesh is refused.
        let g = grid(false);
        let other = PoseKernel::new(&mut rec, &Prepared::new(&g.mesh, 1)?)?;
        let e = AoKernel::on_pose(&mut rec, &ao_prep, AoParams::default(), &other)
            .err()
            .expect("a pose of another mesh is refused")
            .to_string();
        assert!(
            e.contains("the AO input has") && e.contains("the pose"),
            "{e}"
        );
        pose.record(&mut rec, &matrices)?;
        shared.record(&mut rec, &matrices)?;
        own.record(&mut rec, &matrices)?;
        let (a, b) = (shared.read_back(&mut rec)?, own.read_back(&mut rec)?);
        rec.submit_and_wait()?;
        let (a, b) = (a.data()?, b.data()?);
        // The same shaders on the same posed vertices: bit for bit the same visibility.
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.visibility, b.visibility);
        let mean = a.visibility.iter().sum::<f32>() / a.visibility.len() as f32;
        eprintln!(
            "mean visibility {mean:.4} over {} vertices",
            a.visibility.len()
        );
        assert!(
            mean > 0.3 && mean < 0.99,
            "not a real occlusion result: {mean}"
        );
        Ok(())
    });
}
