//! The compute rasteriser: visibility ids and depths against its f64 CPU twin away from
//! edges (defined in `kernels::raster::cpu::Visibility::robust`), on a mesh of thousands of
//! triangles spread over several grid rows and on the BCN_Epileptic cloth far from its bind
//! pose; near-plane clipping and culling; back faces; the resolve pass against its twin; and
//! the BTF pass shading the G-buffer the rasteriser wrote, against the BTF's CPU twin. Every
//! GPU test runs under validation (synchronization validation on).

mod common;

use common::with_gpu_features;
use glam::{Mat4, Vec3, Vec4};
use vkshade::gpu::{Buffer, BufferDesc, Context, Features};
use vkshade::kernels::Kernel;
use vkshade::kernels::raster::cpu::{self as twin, PosedCpu, Visibility};
use vkshade::kernels::raster::gpu::{Camera, Posed, Prepared, RasterKernel, RasterOutput, counter};
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

/// Rest tangents along +u with handedness (w = sign of (n x t) . dP/dv), per vertex from
/// the UV gradients of the triangles around it.
fn rest_tangents(mesh: &Mesh) -> Vec<Vec4> {
    let uv = mesh.uvs.as_ref().unwrap();
    let (mut du, mut dv) = (vec![Vec3::ZERO; uv.len()], vec![Vec3::ZERO; uv.len()]);
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let (e1, e2) = (
            mesh.positions[b] - mesh.positions[a],
            mesh.positions[c] - mesh.positions[a],
        );
        let (s1, s2) = (uv[b] - uv[a], uv[c] - uv[a]);
        let det = s1.x * s2.y - s2.x * s1.y;
        if det.abs() < 1e-12 {
            continue;
        }
        for v in [a, b, c] {
            du[v] += (e1 * s2.y - e2 * s1.y) / det;
            dv[v] += (e2 * s1.x - e1 * s2.x) / det;
        }
    }
    (0..uv.len())
        .map(|v| {
            let n = mesh.normals[v];
            let t = (du[v] - n * n.dot(du[v]))
                .try_normalize()
                .unwrap_or_else(|| n.any_orthonormal_vector());
            let w = if n.cross(t).dot(dv[v]) < 0.0 {
                -1.0
            } else {
                1.0
            };
            t.extend(w)
        })
        .collect()
}

/// The mesh posed by linear blend skinning on the CPU (identity when `matrices` is None):
/// positions, unit normals, unit tangents (Gram-Schmidt against the normal) with w kept.
struct HostPose {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    tangents: Vec<Vec4>,
}

fn host_pose(mesh: &Mesh, matrices: Option<&[Mat4]>) -> HostPose {
    let rest = rest_tangents(mesh);
    let mut out = HostPose {
        positions: mesh.positions.clone(),
        normals: mesh.normals.clone(),
        tangents: rest.clone(),
    };
    let (Some(m), Some(skin)) = (matrices, &mesh.skin) else {
        return out;
    };
    for v in 0..mesh.positions.len() {
        let b = vkshade::scene::rig::blend_matrix(m, skin.joints[v], skin.weights[v]);
        out.positions[v] = b.transform_point3(mesh.positions[v]);
        let n = b.transform_vector3(mesh.normals[v]).normalize();
        let t = b.transform_vector3(rest[v].truncate());
        let t = (t - n * n.dot(t)).normalize();
        out.normals[v] = n;
        out.tangents[v] = t.extend(rest[v].w);
    }
    out
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
        // Pixels nothing covers hold an all-zero G-buffer texel.
        for k in 0..want.id.len() {
            if out.hit(k).is_none() {
                assert!(
                    out.gbuffer.texels[3 * k..3 * k + 3]
                        .iter()
                        .flatten()
                        .all(|&x| x == 0.0)
                );
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
