//! The compute rasteriser: visibility ids and depths against its f64 CPU twin away from
//! edges (defined in `kernels::raster::cpu::Visibility::robust`), on a mesh of thousands of
//! triangles spread over several grid rows and on the BCN_Epileptic cloth far from its bind
//! pose; near-plane clipping and culling; back faces; the resolve pass against its twin; and
//! the BTF pass shading the G-buffer the rasteriser wrote, against the BTF's CPU twin. Every
//! GPU test runs under validation (synchronization validation on).

mod common;

use common::with_gpu_features;
use glam::{Mat4, Vec3};
use vkshade::gpu::{Buffer, BufferDesc, Context, Features};
use vkshade::kernels::Kernel;
use vkshade::kernels::raster::cpu::{self as twin, PosedCpu, Visibility};
use vkshade::kernels::raster::gpu::{
    Camera, Posed, Prepared, RasterKernel, RasterOutput, TILE, Tiling, counter, tile_grid,
};
use vkshade::scene::{Mesh, MeshData};

const INT64: Features = Features {
    shader_float16: false,
    shader_int16: false,
    storage_16bit: false,
    shader_float64: false,
    sampler_anisotropy: false,
    texture_compression_bc: false,
    buffer_int64_atomics: true,
};

/// An open tube (no caps) of radius 1 and height 2 around y, `nu` x `nv` quads, with UVs
/// mirrored across x = 0 (u = |phi| / pi: the half with phi < 0 is left-handed), wavy so
/// that triangles are not all alike.
fn tube(nu: u32, nv: u32) -> Mesh {
    let mut d = MeshData::default();
    let mut uvs = Vec::new();
    for j in 0..=nv {
        for i in 0..=nu {
            let phi = std::f32::consts::TAU * i as f32 / nu as f32 - std::f32::consts::PI;
            let y = 2.0 * j as f32 / nv as f32 - 1.0;
            let r = 1.0 + 0.08 * (3.0 * phi).sin() * (2.0 * y).cos();
            d.positions.push([r * phi.sin(), y, r * phi.cos()]);
            uvs.push([phi.abs() / std::f32::consts::PI, (y + 1.0) * 0.5]);
        }
    }
    let v = |i: u32, j: u32| j * (nu + 1) + i;
    for j in 0..nv {
        for i in 0..nu {
            d.triangles.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            d.triangles.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    d.uvs = Some(uvs);
    Mesh::from_data(d, std::path::Path::new("tube")).unwrap()
}

/// The mesh posed on the CPU by the pose kernel's twin (identity when `matrices` is None):
/// positions, unit normals, unit tangents along +u with w = handedness.
type HostPose = vkshade::kernels::pose::cpu::Posed;

fn host_pose(mesh: &Mesh, matrices: Option<&[Mat4]>) -> HostPose {
    let prep = pose_prep(mesh, matrices.map_or(1, |m| m.len()));
    vkshade::kernels::pose::cpu::pose(&prep, matrices.unwrap_or(&[Mat4::IDENTITY])).unwrap()
}

/// The pose kernel's rest pose of `mesh` (a mesh without skin: on the identity rig).
fn pose_prep(mesh: &Mesh, joints: usize) -> vkshade::kernels::pose::Prepared {
    let mesh = match mesh.skin {
        Some(_) => mesh.clone(),
        None => vkshade::scene::Character::from_static(mesh.clone()).mesh,
    };
    vkshade::kernels::pose::Prepared::new(&mesh, joints).unwrap()
}

struct PosedBuffers {
    positions: Buffer,
    normals: Buffer,
    tangents: Buffer,
}

impl PosedBuffers {
    fn upload(ctx: &Context, p: &HostPose) -> vkshade::Result<PosedBuffers> {
        let n = p.positions.len() as u64 * 16;
        let v4 = |v: &[Vec3], w: f32| -> Vec<[f32; 4]> {
            v.iter().map(|x| x.extend(w).to_array()).collect()
        };
        let t: Vec<[f32; 4]> = p.tangents.iter().map(|x| x.to_array()).collect();
        Ok(PosedBuffers {
            positions: ctx.upload_buffer(
                "posed positions",
                BufferDesc::storage(n),
                &v4(&p.positions, 1.0),
            )?,
            normals: ctx.upload_buffer(
                "posed normals",
                BufferDesc::storage(n),
                &v4(&p.normals, 0.0),
            )?,
            tangents: ctx.upload_buffer("posed tangents", BufferDesc::storage(n), &t)?,
        })
    }

    fn posed(&self) -> Posed<'_> {
        Posed {
            positions: &self.positions,
            normals: &self.normals,
            tangents: &self.tangents,
        }
    }
}

/// One frame of the rasteriser for each camera, on a fresh validated context.
fn raster_frames(pose: &HostPose, prep: &Prepared, cameras: &[Camera]) -> Vec<RasterOutput> {
    with_gpu_features(INT64, |ctx| {
        let bufs = PosedBuffers::upload(ctx, pose)?;
        let mut rec = ctx.recorder("raster setup")?;
        let k = RasterKernel::new(&mut rec, prep, &bufs.posed())?;
        rec.submit_and_wait()?;
        let mut outs = Vec::new();
        for cam in cameras {
            let mut rec = ctx.recorder("raster frame")?;
            k.record(&mut rec, cam)?;
            let rb = k.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            outs.push(k.collect(&rb)?);
        }
        Ok(outs)
    })
}

/// Asserts the GPU's ids equal the twin's and its depths lie within the twin's slack at
/// every pixel away from edges; returns (robust pixels compared, covered among them).
fn assert_matches(what: &str, out: &RasterOutput, want: &Visibility) -> (usize, usize) {
    let (mut robust, mut covered) = (0, 0);
    for k in 0..want.id.len() {
        if !want.robust[k] {
            continue;
        }
        robust += 1;
        match (out.hit(k), want.id[k]) {
            (None, u32::MAX) => {}
            (Some((id, depth)), t) if t != u32::MAX => {
                covered += 1;
                assert_eq!(id, t, "{what}: pixel {k}: triangle");
                let err = (depth as f64 - want.depth[k]).abs();
                assert!(
                    err <= want.slack[k],
                    "{what}: pixel {k}: depth {depth} vs {} (slack {})",
                    want.depth[k],
                    want.slack[k]
                );
            }
            (got, t) => panic!("{what}: pixel {k}: GPU {got:?}, twin {t}"),
        }
    }
    (robust, covered)
}

#[test]
fn ids_and_depths_equal_the_twin_over_many_workgroups_and_grid_rows() {
    // 96 x 48 quads: 9216 triangles = 144 workgroups of 64; rows of 1000 invocations make
    // a 1000 x 10 grid (the last row partly empty).
    let mesh = tube(96, 48);
    let pose = host_pose(&mesh, None);
    let size = [160, 120];
    let prep = Prepared::new(&mesh, &[], size, 4.0).unwrap().with_row(1000);
    assert_eq!(prep.rows(), 10);
    let cams = [
        Camera::framing(Vec3::ZERO, 1.5, Vec3::new(0.3, 0.9, 1.0)),
        Camera::framing(Vec3::new(0.1, 0.2, 0.0), 1.2, Vec3::new(-1.0, -0.4, 0.2)),
    ];
    let outs = raster_frames(&pose, &prep, &cams);
    for (cam, out) in cams.iter().zip(&outs) {
        let want = twin::visibility(&pose.positions, &prep, cam);
        let (robust, covered) = assert_matches("tube", out, &want);
        let all_covered = want.id.iter().filter(|&&i| i != u32::MAX).count();
        // Small triangles (~4 px wide): most pixel centres still lie 1/64 px clear of
        // every edge.
        assert!(
            covered * 10 > all_covered * 7,
            "{covered} of {all_covered} compared"
        );
        assert!(robust > covered, "empty pixels compared too");
        // Pixels nothing covers hold an all-zero first layer (tag 0: empty).
        for k in 0..want.id.len() {
            if out.hit(k).is_none() {
                assert_eq!(out.gbuffer.texels[3 * k], [0.0; 4]);
            }
        }
        assert_eq!(
            out.gbuffer.covered(),
            out.keys.iter().filter(|&&k| k != u64::MAX).count()
        );
        assert_eq!(
            out.counters[counter::BACK_FACING],
            want.counters[counter::BACK_FACING]
        );
        assert_eq!(out.counters[counter::NEAR_CLIPPED], 0);
    }
}

/// The GPU's resolve against the twin's on the same triangle ids, at pixels away from
/// edges: the tags equal, and (position, normal, tangent, uv) each within its bound; returns
/// the largest error / bound of each (all must stay below 1).
///
/// The bound: f32 Moller-Trumbore computes a barycentric from cross and dot products of
/// vectors of length ~|eye - a| and the triangle's edges, so it is off by about
/// db = 16 eps |eye - a| / (e_min |cos|) (eps = 6e-8; e_min the shortest edge, cos the
/// ray's incidence on the triangle): 1e-6 |eye - a| / (e_min |cos|). An attribute is then
/// off by db times its largest difference between the triangle's vertices, plus f32
/// rounding (1e-6 relative); a direction is normalised after, dividing that by the
/// interpolation's length (`resolve_conditioned`).
fn resolve_errors(
    out: &RasterOutput,
    pose: &HostPose,
    prep: &Prepared,
    cam: &Camera,
    robust: &[bool],
) -> [f64; 4] {
    let ids: Vec<u32> = (0..out.keys.len())
        .map(|k| out.hit(k).map_or(u32::MAX, |h| h.0))
        .collect();
    let posed = PosedCpu {
        positions: &pose.positions,
        normals: &pose.normals,
        tangents: &pose.tangents,
    };
    let (want, lengths) = twin::resolve_conditioned(&posed, prep, cam, &ids);
    let eye = cam.eye.as_dvec3();
    let mut ratio = [0f64; 4];
    for k in 0..ids.len() {
        if !robust[k] || ids[k] == u32::MAX {
            continue;
        }
        let (g, c) = (
            &out.gbuffer.texels[3 * k..3 * k + 3],
            &want.texels[3 * k..3 * k + 3],
        );
        assert_eq!(g[0][3], c[0][3], "pixel {k}: tag (handedness, part)");
        let d = |i: usize, n: usize| {
            (0..n)
                .map(|j| (g[i][j] - c[i][j]).abs() as f64)
                .fold(0.0, f64::max)
        };
        let t = prep.triangles[ids[k] as usize];
        let v = [t[0], t[1], t[2]].map(|i| i as usize);
        let p = v.map(|i| pose.positions[i].as_dvec3());
        let edges = [p[1] - p[0], p[2] - p[1], p[0] - p[2]].map(|e| e.length());
        let (e_min, e_max) = (
            edges.iter().copied().fold(f64::MAX, f64::min),
            edges.iter().copied().fold(0.0, f64::max),
        );
        let hit = glam::DVec3::new(c[0][0] as f64, c[0][1] as f64, c[0][2] as f64);
        let ray = (hit - eye).normalize();
        let cos = ray
            .dot((p[1] - p[0]).cross(p[2] - p[0]).normalize())
            .abs()
            .max(1e-3);
        let db = 1e-6 * (eye - p[0]).length() / (e_min * cos);
        let spread = |f: &dyn Fn(usize) -> glam::DVec3| {
            let q = v.map(f);
            [
                (q[0] - q[1]).length(),
                (q[1] - q[2]).length(),
                (q[2] - q[0]).length(),
            ]
            .into_iter()
            .fold(0.0, f64::max)
        };
        let dn = spread(&|i| pose.normals[i].as_dvec3());
        let dt = spread(&|i| pose.tangents[i].truncate().as_dvec3());
        let duv = spread(&|i| {
            glam::DVec3::new(prep.uvs[i][0] as f64, prep.uvs[i][1] as f64, 0.0)
                * prep.uv_scale as f64
        });
        let [ln, lt] = lengths[k];
        let uv_mag = (c[1][3].abs().max(c[2][3].abs())) as f64;
        let bounds = [
            db * e_max + 1e-6 * (hit.length() + 1.0),
            (db * dn + 1e-6) / ln,
            (db * (dn + dt) + 2e-6) / (ln * lt),
            db * duv + 1e-6 * (uv_mag + 1.0),
        ];
        let errs = [
            d(0, 3),
            d(1, 3),
            d(2, 3),
            ((g[1][3] - c[1][3]).abs()).max((g[2][3] - c[2][3]).abs()) as f64,
        ];
        for i in 0..4 {
            ratio[i] = ratio[i].max(errs[i] / bounds[i]);
        }
    }
    ratio
}

#[test]
fn resolve_equals_its_twin_and_back_faces_face_the_camera_with_flipped_handedness() {
    // Seen from above at 50 degrees: the inside of the far wall shows (back faces).
    let mesh = tube(64, 24);
    let pose = host_pose(&mesh, None);
    let prep = Prepared::new(&mesh, &[], [128, 128], 3.0).unwrap();
    let cam = Camera::framing(Vec3::ZERO, 1.5, Vec3::new(0.0, 1.2, 1.0));
    let out = &raster_frames(&pose, &prep, &[cam])[0];
    let want = twin::visibility(&pose.positions, &prep, &cam);
    assert_matches("tube from above", out, &want);
    assert!(
        out.counters[counter::BACK_FACING] > 500,
        "{:?}",
        out.counters
    );
    // f32 against f64 on the same triangle, within the bounds `resolve_errors` derives.
    let ratio = resolve_errors(out, &pose, &prep, &cam, &want.robust);
    assert!(ratio.iter().all(|&r| r < 1.0), "error / bound {ratio:?}");

    // Independent of the twin: every covered pixel's normal faces the camera; where the
    // triangle is a back face (its winding's normal points away), the handedness is the
    // vertices' negated, so the bitangent stays along +v.
    let (mut back, mut mirrored) = (0, 0);
    for k in 0..out.keys.len() {
        let Some((t, _)) = out.hit(k) else { continue };
        let px = out.gbuffer.pixel(k).unwrap();
        let to_eye = cam.eye.as_dvec3() - px.position;
        assert!(px.normal.dot(to_eye) >= 0.0, "pixel {k} faces away");
        let [a, b, c] = mesh.triangles[t as usize].map(|i| i as usize);
        let geo =
            (mesh.positions[b] - mesh.positions[a]).cross(mesh.positions[c] - mesh.positions[a]);
        let w = pose.tangents[a].w as f64;
        if pose.tangents[a].w != pose.tangents[b].w || pose.tangents[a].w != pose.tangents[c].w {
            continue; // a triangle on the mirror seam
        }
        let facing_away = geo.as_dvec3().dot(to_eye) < 0.0;
        let n_interp = mesh.normals[a] + mesh.normals[b] + mesh.normals[c];
        if facing_away && n_interp.as_dvec3().dot(to_eye) < -0.1 {
            back += 1;
            assert_eq!(
                px.handedness, -w,
                "pixel {k}: back face keeps its handedness"
            );
        }
        mirrored += (w < 0.0) as usize;
    }
    assert!(back > 300, "{back} back-face pixels");
    assert!(mirrored > 300, "{mirrored} pixels of the mirrored half");
}

#[test]
fn triangles_crossing_the_near_plane_are_clipped_and_those_behind_culled() {
    // Inside the tube, looking along +z with a near plane at 0.45: the side walls cross it,
    // the wall behind lies wholly in front of the eye's back.
    let mesh = tube(64, 24);
    let pose = host_pose(&mesh, None);
    let prep = Prepared::new(&mesh, &[], [120, 96], 2.0).unwrap();
    let cam = Camera {
        eye: Vec3::new(0.0, 0.1, -0.2),
        target: Vec3::new(0.1, 0.0, 1.0),
        up: Vec3::Y,
        fov_y_deg: 100.0,
        near: 0.45,
    };
    // The same eye with a wider view: there the near plane cuts the walls inside the image
    // (at 100 degrees the cuts lie just past its left and right edges), so pixels of the
    // clipped triangles are compared too. A rasteriser that scanned only the first triangle
    // of each clipped polygon passed the first camera and failed this one (measured when
    // the scan moved into one loop). Both cameras compare the counters with the twin's and
    // account for every piece: a triangle with two vertices in front of the near plane is
    // two pieces, with one or three one piece, and each piece is scanned or counted as
    // culled past the guard band, of zero area or off screen.
    let wide = Camera {
        fov_y_deg: 140.0,
        ..cam
    };
    let outs = raster_frames(&pose, &prep, &[cam, wide]);
    let mut compared = Vec::new();
    for (cam, out) in [cam, wide].iter().zip(&outs) {
        let want = twin::visibility(&pose.positions, &prep, cam);
        let what = format!("inside the tube, {} degrees", cam.fov_y_deg);
        let (_, covered) = assert_matches(&what, out, &want);
        for c in [
            counter::NEAR_CLIPPED,
            counter::NEAR_CULLED,
            counter::BACK_FACING,
        ] {
            assert_eq!(
                out.counters[c], want.counters[c],
                "counter {c}: {:?}",
                out.counters
            );
        }
        // Per triangle, its vertices in front of the near plane.
        let forward = (cam.target - cam.eye).normalize();
        let in_front: Vec<usize> = prep
            .triangles
            .iter()
            .map(|t| {
                t.iter()
                    .filter(|&&i| (pose.positions[i as usize] - cam.eye).dot(forward) >= cam.near)
                    .count()
            })
            .collect();
        let pieces: u32 = in_front.iter().map(|&n| [0, 1, 2, 1][n]).sum();
        let quads = in_front.iter().filter(|&&n| n == 2).count();
        let ended: u32 = [
            counter::SCANNED,
            counter::GUARD_CULLED,
            counter::ZERO_AREA,
            counter::OFF_SCREEN,
        ]
        .iter()
        .map(|&c| out.counters[c])
        .sum();
        assert_eq!(ended, pieces, "{:?}", out.counters);
        assert!(quads > 10, "{quads} triangles clipped into two pieces");
        let clipped_pixels = (0..want.id.len())
            .filter(|&k| {
                want.robust[k] && want.id[k] != u32::MAX && in_front[want.id[k] as usize] < 3
            })
            .count();
        compared.push((covered, clipped_pixels));
    }
    assert!(compared[0].0 > 4000, "{:?} pixels compared", compared[0]);
    assert!(
        compared[1].1 > 500,
        "{:?} compared pixels of clipped triangles",
        compared[1]
    );
    let out = &outs[0];
    assert!(
        out.counters[counter::NEAR_CLIPPED] > 20,
        "{:?}",
        out.counters
    );
    assert!(
        out.counters[counter::NEAR_CULLED] > 100,
        "{:?}",
        out.counters
    );
    // Nothing nearer than the near plane is kept (f32 rounding of the clipped vertices).
    for k in 0..out.keys.len() {
        if let Some((_, d)) = out.hit(k) {
            assert!(d >= cam.near * (1.0 - 1e-5), "pixel {k}: depth {d}");
        }
    }
    // The clipped walls fill the image's left and right edges.
    for y in [10usize, 48, 85] {
        assert!(out.hit(y * 120).is_some() && out.hit(y * 120 + 119).is_some());
    }
}

#[cfg(feature = "gltf")]
#[test]
fn the_cloth_far_from_its_bind_pose_equals_the_twin() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let (ch, parts) = vkshade::scene::gltf_load::load_parts(&path, &["Torso", "Legs"]).unwrap();
    let anim = ch.animation("Epileptisch").unwrap();
    assert!(parts.contains(&0) && parts.contains(&1));
    // The frame farthest from the bind pose among 16 spread over the animation.
    let rest = &ch.mesh;
    let (lo, hi) = vkshade::scene::mesh::bounds(&rest.positions);
    let radius = (hi - lo).length() * 0.5;
    let (mut far, mut far_d, mut far_m) = (None, 0.0, vec![]);
    for i in 0..16 {
        let m = ch
            .rig
            .skinning_matrices(Some(anim), anim.duration * i as f32 / 16.0);
        let p = host_pose(&ch.mesh, Some(&m));
        let d = p
            .positions
            .iter()
            .zip(&rest.positions)
            .map(|(a, b)| a.distance(*b))
            .sum::<f32>()
            / p.positions.len() as f32;
        if d > far_d {
            (far, far_d, far_m) = (Some(p), d, m);
        }
    }
    let pose = far.unwrap();
    // Far: the vertices moved by more than 5% of the cloth's size on average.
    assert!(
        far_d > 0.05 * radius,
        "mean displacement {far_d} of radius {radius}"
    );
    let (lo, hi) = vkshade::scene::mesh::bounds(&pose.positions);
    let centre = (lo + hi) * 0.5;
    let r = (hi - lo).length() * 0.5;
    let prep = Prepared::new(&ch.mesh, &parts, [128, 160], 8.0).unwrap();
    let cams = [
        Camera::framing(centre, r, Vec3::new(0.2, 0.1, 1.0)),
        Camera::framing(centre, r, Vec3::new(-1.0, 0.3, -0.5)),
    ];
    // Posed on the GPU by the pose kernel, rasterised from its buffers in the same
    // recording; the twin rasterises the pose kernel's CPU twin.
    let pose_prep = pose_prep(&ch.mesh, ch.rig.joints.len());
    let outs = with_gpu_features(INT64, |ctx| {
        let mut rec = ctx.recorder("pose + raster setup")?;
        let pk = vkshade::kernels::pose::PoseKernel::new(&mut rec, &pose_prep)?;
        let posed = Posed {
            positions: pk.positions(),
            normals: pk.normals(),
            tangents: pk.tangents(),
        };
        let rk = RasterKernel::new(&mut rec, &prep, &posed)?;
        rec.submit_and_wait()?;
        let mut outs = Vec::new();
        for cam in &cams {
            let mut rec = ctx.recorder("pose + raster frame")?;
            pk.record(&mut rec, &far_m)?;
            rk.record(&mut rec, cam)?;
            let rb = rk.read_back(&mut rec)?;
            let pb = pk.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            outs.push((rk.collect(&rb)?, pb.data()?));
        }
        Ok(outs)
    });
    for (cam, (out, gpu_pose)) in cams.iter().zip(&outs) {
        let want = twin::visibility(&pose.positions, &prep, cam);
        let (_, covered) = assert_matches("cloth", out, &want);
        let all = want.id.iter().filter(|&&i| i != u32::MAX).count();
        assert!(
            covered * 10 > all * 6 && all > 2000,
            "{covered} of {all} compared"
        );
        // Both parts are seen, and the part ids reach the G-buffer.
        let seen: std::collections::BTreeSet<u32> = (0..out.keys.len())
            .filter_map(|k| out.gbuffer.pixel(k).map(|p| p.part))
            .collect();
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), vec![0, 1]);
        // The resolve on the vertices the GPU posed (the pose kernel's own test bounds
        // them against its twin; here the resolve is compared on the same input).
        let ratio = resolve_errors(out, gpu_pose, &prep, cam, &want.robust);
        eprintln!("resolve error / bound: {ratio:?}");
        assert!(ratio.iter().all(|&r| r < 1.0), "error / bound {ratio:?}");
    }
}

#[test]
fn a_device_context_without_64_bit_atomics_is_refused_naming_the_feature() {
    let e = common::with_gpu(|ctx| {
        let mesh = tube(4, 2);
        let pose = host_pose(&mesh, None);
        let bufs = PosedBuffers::upload(ctx, &pose)?;
        let prep = Prepared::new(&mesh, &[], [8, 8], 1.0)?;
        let mut rec = ctx.recorder("raster refused")?;
        let e = RasterKernel::new(&mut rec, &prep, &bufs.posed())
            .err()
            .map(|e| e.to_string());
        drop(rec);
        Ok(e.unwrap_or_default())
    });
    assert!(e.contains("shaderBufferInt64Atomics"), "{e}");
}

#[test]
fn inconsistent_public_fields_are_refused_before_any_gpu_work() {
    // `Prepared`'s fields are public: the shaders index uvs by vertex and divide the grid by
    // its row, so both are checked when the kernel is made.
    let errors = with_gpu_features(INT64, |ctx| {
        let mesh = tube(4, 2);
        let pose = host_pose(&mesh, None);
        let bufs = PosedBuffers::upload(ctx, &pose)?;
        let good = Prepared::new(&mesh, &[], [8, 8], 1.0)?;
        let mut short = good.clone();
        short.uvs.pop();
        let mut row = good.clone();
        row.row = 0;
        let mut rec = ctx.recorder("raster refused")?;
        let errors: Vec<String> = [short, row]
            .iter()
            .map(|p| {
                RasterKernel::new(&mut rec, p, &bufs.posed())
                    .err()
                    .map(|e| e.to_string())
                    .unwrap_or_default()
            })
            .collect();
        drop(rec);
        Ok(errors)
    });
    assert!(errors[0].contains("uvs for"), "{}", errors[0]);
    assert!(errors[1].contains("row"), "{}", errors[1]);
}

/// Largest difference between the GPU's BTF and its f64 CPU twin (as tests/btf.rs
/// `gpu_cpu_bound`): bilinear weights with `bits` sub-texel bits off by 2^-bits of the
/// largest texel, plus 1.1e-3 for the sRGB decode and f32 rounding, per light of strength 1.
fn gpu_cpu_bound(bits: u32) -> f64 {
    2f64.powi(-(bits as i32)) + 1.1e-3
}

/// The rasteriser's G-buffer shaded by the BTF kernel equals the CPU twin, in both packings
/// and both dispatches the library offers: 'rows' over every pixel
/// (`btf/shade_rows`), and 'layers' over the pixels that pass `btf pixels` lists from the
/// rasteriser's tile list (`btf/shade_layers_pixels`, what `btf render --anim --layout
/// layers` runs; the empty pixels of the tiles take the background there). A list that
/// skipped or misplaced a pixel, or a layers packing that indexed the wrong array or layer,
/// fails the per-pixel comparison.
#[test]
fn btf_shades_the_gpu_gbuffer_like_its_cpu_twin() {
    use vkshade::kernels::btf::gpu::Layout;
    use vkshade::kernels::raster::gpu::Tiling;
    btf_on_gbuffer_case(Layout::Rows, Tiling::Full);
    btf_on_gbuffer_case(Layout::Layers, Tiling::Tiles);
}

fn btf_on_gbuffer_case(
    layout: vkshade::kernels::btf::gpu::Layout,
    tiling: vkshade::kernels::raster::gpu::Tiling,
) {
    use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
    use vkshade::kernels::btf::dirs::{Maps, Triangulation};
    use vkshade::kernels::btf::gpu::{
        BtfInputs, BtfKernel, Prepared as BtfPrepared, Texture, pack,
    };
    use vkshade::scene::gbuffer::{Camera as View, Frame, GBuffer, default_lights};
    let btf =
        vkshade::kernels::btf::synth::synthesize(&SynthConfig::tile(Pattern::Weave, 8)).unwrap();
    let maps = Maps::build(&Triangulation::new().unwrap(), 32).unwrap();
    let mesh = tube(48, 16);
    let pose = host_pose(&mesh, None);
    let size = [96, 80];
    let prep = Prepared::new(&mesh, &[], size, 3.0).unwrap();
    let cam = Camera::framing(Vec3::ZERO, 1.5, Vec3::new(0.5, 0.8, 1.0));
    let frame = Frame {
        camera: View::Perspective(cam.eye),
        lights: default_lights(),
    };
    let (raster, shaded, bits) = with_gpu_features(INT64, |ctx| {
        let bufs = PosedBuffers::upload(ctx, &pose)?;
        let mut rec = ctx.recorder("raster + btf setup")?;
        let r = RasterKernel::with_tiling(&mut rec, &prep, &bufs.posed(), tiling)?;
        let l = ctx.limits();
        let unused = GBuffer::tile([1, 1]);
        let inputs = BtfInputs {
            layout,
            ..BtfInputs::new(&btf, &maps, &unused, Texture::Rgba8)
        };
        let bp = BtfPrepared::for_gpu_gbuffer(
            &inputs,
            size,
            l.max_image_dimension_2d,
            l.max_image_array_layers,
        )?;
        assert_eq!(bp.packing().layout, layout);
        let b = match r.tiles() {
            Some(tiles) => BtfKernel::on_gbuffer_tiles(&mut rec, &bp, r.gbuffer(), tiles)?,
            None => BtfKernel::on_gbuffer(&mut rec, &bp, r.gbuffer())?,
        };
        assert_eq!(r.tiles().is_some(), tiling == Tiling::Tiles);
        rec.submit_and_wait()?;
        // One frame: rasterise, shade the G-buffer just written, read both back.
        let mut rec = ctx.recorder("raster + btf frame")?;
        r.record(&mut rec, &cam)?;
        b.record(&mut rec, &frame)?;
        let (rr, rb) = (r.read_back(&mut rec)?, b.read_back(&mut rec)?);
        rec.submit_and_wait()?;
        let h = ctx.external_handles();
        // SAFETY: the context's own instance and physical device, alive while `ctx` is.
        let bits = unsafe { h.instance.get_physical_device_properties(h.physical_device) }
            .limits
            .sub_texel_precision_bits;
        Ok((r.collect(&rr)?, b.collect(&rb)?, bits))
    });
    let packed = pack(&btf);
    let (want, ambiguous) = vkshade::kernels::btf::cpu::shade(
        &vkshade::kernels::btf::cpu::Packed::new(btf.size, &packed),
        &maps,
        &raster.gbuffer,
        &frame,
    );
    let mut max: f64 = 0.0;
    let mut compared = 0;
    for k in 0..want.len() {
        assert_eq!(
            shaded[k][3] as f64, want[k][3],
            "{layout:?}/{tiling:?}: coverage of pixel {k}"
        );
        if !ambiguous[k] {
            compared += 1;
            for i in 0..3 {
                max = max.max((shaded[k][i] as f64 - want[k][i]).abs());
            }
        }
    }
    let covered = raster.gbuffer.covered();
    assert!(
        covered > 2000 && compared + covered / 20 > covered,
        "{compared} of {covered}"
    );
    // Lit pixels on both halves of the mirrored UVs (the handedness reaches the shader).
    let lit = |hand: f64| {
        (0..want.len())
            .filter(|&k| {
                want[k][0] > 0.01
                    && raster
                        .gbuffer
                        .pixel(k)
                        .is_some_and(|p| p.handedness == hand)
            })
            .count()
    };
    assert!(
        lit(1.0) > 200 && lit(-1.0) > 200,
        "{} / {}",
        lit(1.0),
        lit(-1.0)
    );
    assert!(
        max < gpu_cpu_bound(bits),
        "{layout:?}/{tiling:?}: |GPU - CPU| = {max}"
    );
}

/// Triangles given in screen pixels of a 32 x 32 image seen by a 90-degree camera at the
/// origin looking along +z (screen x grows towards -x, y down), all at depth 1.
fn screen_mesh(tris: &[[[f32; 2]; 3]]) -> Mesh {
    let mut d = MeshData::default();
    let mut uvs = Vec::new();
    for t in tris {
        for p in t {
            d.positions
                .push([-(p[0] / 16.0 - 1.0), 1.0 - p[1] / 16.0, 1.0]);
            uvs.push([p[0] / 32.0, p[1] / 32.0]);
        }
        let b = d.positions.len() as u32 - 3;
        d.triangles.push([b, b + 1, b + 2]);
    }
    d.uvs = Some(uvs);
    Mesh::from_data(d, std::path::Path::new("screen")).unwrap()
}

#[test]
fn pixel_centres_on_a_shared_edge_belong_to_one_triangle_by_the_top_left_rule() {
    let cam = Camera {
        eye: Vec3::ZERO,
        target: Vec3::Z,
        up: Vec3::Y,
        fov_y_deg: 90.0,
        near: 0.1,
    };
    // A vertical edge at x = 10.5 through the centres of column 10: it is triangle 0's right
    // edge and triangle 1's left edge, so those centres are triangle 1's. Both triangles lie
    // at the same depth, where atomicMin would keep the lower id 0 if both covered them.
    // Likewise a horizontal edge at y = 20.5 through row 20's centres: triangle 1's bottom
    // edge (not owned) and triangle 2's top edge (owned).
    let mesh = screen_mesh(&[
        [[2.0, 2.0], [10.5, 2.0], [10.5, 20.5]],
        [[10.5, 2.0], [30.0, 20.5], [10.5, 20.5]],
        [[10.5, 20.5], [30.0, 20.5], [20.0, 30.0]],
    ]);
    let pose = host_pose(&mesh, None);
    let prep = Prepared::new(&mesh, &[], [32, 32], 1.0).unwrap();
    let out = &raster_frames(&pose, &prep, &[cam])[0];
    let id = |x: usize, y: usize| out.hit(y * 32 + x).map(|h| h.0);
    for y in 3..20 {
        assert_eq!(
            id(10, y),
            Some(1),
            "column 10, row {y}: the left edge's owner"
        );
    }
    for y in 3..18 {
        assert_eq!(id(9, y), Some(0), "column 9, row {y}");
    }
    for x in 12..28 {
        assert_eq!(
            id(x, 20),
            Some(2),
            "row 20, column {x}: the top edge's owner"
        );
        assert_eq!(id(x, 19), Some(1), "row 19, column {x}");
    }
    // The vertex (10.5, 20.5) of all three: on triangle 0's right edge (not owned), on
    // triangle 1's bottom edge (not owned), on triangle 2's top and left edges (owned).
    assert_eq!(id(10, 20), Some(2));
}

/// The tiles holding a covered pixel of `out` (sorted tile indices `ty * tiles_x + tx`).
fn covered_tiles(out: &RasterOutput, size: [u32; 2]) -> Vec<u32> {
    let tiles_x = tile_grid(size)[0];
    let set: std::collections::BTreeSet<u32> = (0..out.keys.len())
        .filter(|&k| out.hit(k).is_some())
        .map(|k| {
            let (x, y) = (k as u32 % size[0], k as u32 / size[0]);
            (y / TILE[1]) * tiles_x + x / TILE[0]
        })
        .collect();
    set.into_iter().collect()
}

/// Five frames of the tube: the whole tube; from farther away (it shrinks: tiles of frame 0
/// become stale); a camera looking away (nothing covered: an empty list, every tile of frame
/// 1 stale); the tube from another side, twice (the second frame has no stale tile).
fn coverage_cameras() -> [Camera; 5] {
    let away = Camera {
        eye: Vec3::new(0.0, 0.0, 4.0),
        target: Vec3::new(0.0, 0.0, 8.0),
        up: Vec3::Y,
        fov_y_deg: 40.0,
        near: 0.1,
    };
    [
        Camera::framing(Vec3::ZERO, 1.5, Vec3::new(0.5, 0.8, 1.0)),
        Camera::framing(Vec3::new(0.3, 0.2, 0.0), 4.0, Vec3::new(1.0, 0.2, 0.3)),
        away,
        Camera::framing(Vec3::ZERO, 1.4, Vec3::new(-1.0, -0.3, 0.4)),
        Camera::framing(Vec3::ZERO, 1.4, Vec3::new(-1.0, -0.3, 0.4)),
    ]
}

#[test]
fn tile_lists_cover_exactly_the_covered_pixels_and_match_the_full_dispatch_bit_for_bit() {
    use vkshade::kernels::btf::cloth::{Pattern, SynthConfig};
    use vkshade::kernels::btf::dirs::{Maps, Triangulation};
    use vkshade::kernels::btf::gpu::{BtfInputs, BtfKernel, Prepared as BtfPrepared, Texture};
    use vkshade::scene::gbuffer::{Camera as View, Frame, GBuffer, default_lights};
    let btf =
        vkshade::kernels::btf::synth::synthesize(&SynthConfig::tile(Pattern::Weave, 8)).unwrap();
    let maps = Maps::build(&Triangulation::new().unwrap(), 32).unwrap();
    let mesh = tube(48, 16);
    let pose = host_pose(&mesh, None);
    // Neither side a multiple of the 16 x 4 tile: the last tiles of each row and column
    // hang over the image.
    let size = [100, 70];
    let prep = Prepared::new(&mesh, &[], size, 3.0).unwrap();
    let cams = coverage_cameras();
    // Two lights, then one on every other frame: the tiled block shader unrolls its light
    // loop for two lights (glsl/common/btf_shade.glsl), the full one does not, so an unused
    // second light that added anything would differ.
    let lights = default_lights();
    assert_eq!(lights.len(), 2);
    let frames = [lights.clone(), lights[..1].to_vec()].map(|lights| Frame {
        camera: View::Perspective(cams[0].eye),
        lights,
    });
    type FrameOut = (RasterOutput, RasterOutput, Vec<[f32; 4]>, Vec<[f32; 4]>);
    let outs: Vec<FrameOut> = with_gpu_features(INT64, |ctx| {
        let bufs = PosedBuffers::upload(ctx, &pose)?;
        let mut rec = ctx.recorder("tiled + full setup")?;
        let tiled = RasterKernel::new(&mut rec, &prep, &bufs.posed())?;
        let full = RasterKernel::with_tiling(&mut rec, &prep, &bufs.posed(), Tiling::Full)?;
        assert_eq!(tiled.tiling(), Tiling::Tiles);
        assert!(full.tiles().is_none());
        let l = ctx.limits();
        let unused = GBuffer::tile([1, 1]);
        let inputs = BtfInputs::new(&btf, &maps, &unused, Texture::Block);
        let bp = BtfPrepared::for_gpu_gbuffer(
            &inputs,
            size,
            l.max_image_dimension_2d,
            l.max_image_array_layers,
        )?;
        let tiles = tiled.tiles().expect("a tiled rasteriser has a tile list");
        let btf_tiled = BtfKernel::on_gbuffer_tiles(&mut rec, &bp, tiled.gbuffer(), tiles)?;
        let btf_full = BtfKernel::on_gbuffer(&mut rec, &bp, full.gbuffer())?;
        rec.submit_and_wait()?;
        let mut outs = Vec::new();
        for (i, cam) in cams.iter().enumerate() {
            let frame = &frames[i % 2];
            let mut rec = ctx.recorder("tiled + full frame")?;
            tiled.record(&mut rec, cam)?;
            btf_tiled.record(&mut rec, frame)?;
            full.record(&mut rec, cam)?;
            btf_full.record(&mut rec, frame)?;
            let rb = (
                tiled.read_back(&mut rec)?,
                full.read_back(&mut rec)?,
                btf_tiled.read_back(&mut rec)?,
                btf_full.read_back(&mut rec)?,
            );
            rec.submit_and_wait()?;
            outs.push((
                tiled.collect(&rb.0)?,
                full.collect(&rb.1)?,
                btf_tiled.collect(&rb.2)?,
                btf_full.collect(&rb.3)?,
            ));
        }
        Ok(outs)
    });
    let [tx, ty] = tile_grid(size);
    let mut previous: Vec<u32> = Vec::new();
    for (i, (tiled, full, shaded_tiled, shaded_full)) in outs.iter().enumerate() {
        assert!(full.tiles.is_none());
        let list = tiled.tiles.as_ref().expect("tile list read back");
        let want = covered_tiles(full, size);
        assert_eq!(list.covered, want, "frame {i}: covered tiles");
        let stale: Vec<u32> = previous
            .iter()
            .copied()
            .filter(|t| want.binary_search(t).is_err())
            .collect();
        assert_eq!(list.stale, stale, "frame {i}: stale tiles");
        assert_eq!(tiled.keys, full.keys, "frame {i}: visibility keys");
        assert_eq!(tiled.counters, full.counters, "frame {i}: counters");
        let bits =
            |v: &[[f32; 4]]| -> Vec<u32> { v.iter().flatten().map(|x| x.to_bits()).collect() };
        assert!(
            bits(&tiled.gbuffer.texels) == bits(&full.gbuffer.texels),
            "frame {i}: G-buffers differ"
        );
        assert!(
            bits(shaded_tiled) == bits(shaded_full),
            "frame {i}: shaded images differ"
        );
        // What each frame exercises: coverage on a part of the tiles, then stale tiles,
        // then nothing covered.
        match i {
            0 | 3 => assert!(
                !want.is_empty() && want.len() < (tx * ty) as usize,
                "{}",
                want.len()
            ),
            1 => assert!(!want.is_empty() && !stale.is_empty()),
            2 => assert!(want.is_empty() && !stale.is_empty()),
            _ => assert!(!want.is_empty() && stale.is_empty()),
        }
        if i > 0 {
            assert!(
                shaded_full.iter().any(|p| p[3] > 0.0) != want.is_empty(),
                "frame {i}: the shaded image has covered pixels iff the G-buffer does"
            );
        }
        previous = want;
    }
}

/// The vertex list (`kernels::raster::vertices`: passes `vertex mark` and `vertex list` over
/// the rasteriser's keys and tile list) against its twin over frames whose coverage grows,
/// shrinks, vanishes (a camera looking away: only the static set is listed) and repeats
/// (the bitmaps the passes clear as they read them must start each frame empty), listed by
/// id and along a Morton curve (bitmaps indexed by rank); and bad input refused before any
/// GPU work.
#[test]
fn the_vertex_list_is_its_twin_frame_after_frame_and_bad_input_is_refused() {
    use vkshade::kernels::raster::vertices::{VertexListKernel, covered_vertices};
    let mesh = tube(48, 16);
    let pose = host_pose(&mesh, None);
    let prep = Prepared::new(&mesh, &[], [100, 70], 3.0).unwrap();
    let n = mesh.positions.len() as u32;
    // A static set: a few vertices the cameras may or may not see, one named twice.
    let always = [0, 7, 7, n - 1];
    // A subset: every third vertex and the static set's 7.
    let subset: Vec<u32> = (0..n).filter(|v| v % 3 == 0).chain([7]).collect();
    let cams = coverage_cameras();
    let outs = with_gpu_features(INT64, |ctx| {
        let bufs = PosedBuffers::upload(ctx, &pose)?;
        let mut rec = ctx.recorder("vertex list setup")?;
        let raster = RasterKernel::new(&mut rec, &prep, &bufs.posed())?;
        let full = RasterKernel::with_tiling(&mut rec, &prep, &bufs.posed(), Tiling::Full)?;
        let refused = |r: vkshade::Result<VertexListKernel>, what: &str| match r {
            Ok(_) => panic!("{what}: accepted"),
            Err(e) => assert!(e.to_string().contains(what), "{what}: {e}"),
        };
        refused(
            VertexListKernel::new(&mut rec, &full, &mesh.triangles, n, &always, None),
            "no tile list",
        );
        refused(
            VertexListKernel::new(&mut rec, &raster, &mesh.triangles, n, &[n], None),
            &format!("vertex {n} named"),
        );
        refused(
            VertexListKernel::new(&mut rec, &raster, &mesh.triangles, n - 1, &[], None),
            &format!("vertex {} named", n - 1),
        );
        refused(
            VertexListKernel::new(&mut rec, &raster, &mesh.triangles[1..], n, &[], None),
            "triangles given",
        );
        let order = vkshade::geom::spatial_order(&mesh.positions);
        assert_ne!(
            order,
            (0..n).collect::<Vec<_>>(),
            "the test needs an order other than ids"
        );
        let mut twice = order.clone();
        twice[1] = twice[0];
        for bad in [&order[1..], &twice[..]] {
            refused(
                VertexListKernel::new(&mut rec, &raster, &mesh.triangles, n, &[], Some(bad)),
                "not a permutation",
            );
        }
        let list = VertexListKernel::new(&mut rec, &raster, &mesh.triangles, n, &always, None)?;
        let mut ordered =
            VertexListKernel::new(&mut rec, &raster, &mesh.triangles, n, &always, Some(&order))?;
        // The subset's list: the subset's vertices on covered triangles (not its `always`
        // ones elsewhere).
        let e = ordered.set_subset(&mut rec, &[0, n]).unwrap_err();
        assert!(e.to_string().contains(&format!("vertex {n} named")), "{e}");
        ordered.set_subset(&mut rec, &subset)?;
        rec.submit_and_wait()?;
        let mut outs = Vec::new();
        for cam in &cams {
            let mut rec = ctx.recorder("vertex list frame")?;
            raster.record(&mut rec, cam)?;
            list.record(&mut rec, &())?;
            ordered.record(&mut rec, &())?;
            let rb = raster.read_back(&mut rec)?;
            let lb = list.read_back(&mut rec)?;
            let ob = ordered.read_back(&mut rec)?;
            let sb = ordered.read_back_subset(&mut rec)?;
            rec.submit_and_wait()?;
            outs.push((
                raster.collect(&rb)?.keys,
                list.collect(&lb)?,
                ordered.collect(&ob)?,
                ordered.collect(&sb)?,
            ));
        }
        Ok(outs)
    });
    let mut sizes = Vec::new();
    for (i, (keys, listed, ordered, sub)) in outs.iter().enumerate() {
        let twin = covered_vertices(keys, &mesh.triangles, &always);
        assert_eq!(listed, &twin, "frame {i}");
        assert_eq!(ordered, &twin, "frame {i}, listed along the Morton curve");
        let sub_twin: Vec<u32> = covered_vertices(keys, &mesh.triangles, &[])
            .into_iter()
            .filter(|v| subset.contains(v))
            .collect();
        assert_eq!(sub, &sub_twin, "frame {i}, the subset's list");
        assert!(
            i == 2 || sub.len() > 10,
            "frame {i}: {} in the subset",
            sub.len()
        );
        sizes.push(listed.len());
    }
    // The static set alone when nothing is covered; more, and fewer than every vertex, when
    // the tube is in view.
    assert_eq!(sizes[2], 3, "{sizes:?}");
    assert!(
        sizes
            .iter()
            .enumerate()
            .all(|(i, &s)| i == 2 || (s > 50 && s < n as usize)),
        "{sizes:?} of {n}"
    );
    assert_eq!(sizes[3], sizes[4]);
}
