//! The CPU twin of the rasteriser, in f64: the same camera, near-plane clipping and
//! coverage (pixel centres inside, unsnapped), the same depth (view distance along the
//! axis, 1 / sum b_i / z_i), and the same resolve (the kept triangle intersected with the
//! pixel's ray). It also says which pixels are *away from edges*, where the GPU must agree
//! exactly on the triangle: see [`Visibility::robust`].

use super::pack::{Camera, Counters, GUARD_BAND, Prepared, SUBPIXEL, counter};
use crate::scene::gbuffer::GBuffer;
use glam::{DVec2, DVec3, Vec3, Vec4};

/// A pixel centre closer than this (pixels) to a triangle's edge, on either side, is near
/// that edge. The GPU snaps vertices to 1/256 px (each moves at most 1/512 px per axis) and
/// projects in f32 (~1e-4 px at 8192 px): an edge moves by well under 1/100 px, so coverage
/// can differ from this twin only within this margin.
pub const EDGE_MARGIN: f64 = 1.0 / 64.0;

/// The twin's visibility buffer.
#[derive(Clone, Debug)]
pub struct Visibility {
    /// Image width and height.
    pub size: [u32; 2],
    /// Per pixel: the nearest covering triangle (`u32::MAX`: none).
    pub id: Vec<u32>,
    /// Its view depth (infinite where none).
    pub depth: Vec<f64>,
    /// How far the GPU's f32, snapped depth may lie from `depth`: the depth's change over
    /// 1/128 px along each axis (twice the snapping's reach) plus 1e-5 relative (f32).
    pub slack: Vec<f64>,
    /// Away from edges: no triangle has an edge within [`EDGE_MARGIN`] of the pixel centre
    /// where that edge decides coverage, and the nearest triangle is nearer than any other
    /// covering one by more than both depths' slack. There the GPU must keep the same
    /// triangle, and its depth within the slack.
    pub robust: Vec<bool>,
    /// Triangles crossing the near plane, wholly behind it, and back-facing (as the GPU's
    /// [`counter::NEAR_CLIPPED`], [`counter::NEAR_CULLED`], [`counter::BACK_FACING`]).
    pub counters: Counters,
}

/// The camera basis in f64 from the f32 values the GPU receives.
struct View {
    eye: DVec3,
    forward: DVec3,
    right: DVec3, // right / tan_x
    up: DVec3,    // up / tan_y
    near: f64,
    size: [f64; 2],
}

impl View {
    fn new(camera: &Camera, size: [u32; 2]) -> View {
        let b = camera.basis(size);
        View {
            eye: camera.eye.as_dvec3(),
            forward: b.forward.as_dvec3(),
            right: (b.right / b.tan_x).as_dvec3(),
            up: (b.up / b.tan_y).as_dvec3(),
            near: camera.near as f64,
            size: [size[0] as f64, size[1] as f64],
        }
    }

    fn to_view(&self, p: Vec3) -> DVec3 {
        let q = p.as_dvec3() - self.eye;
        DVec3::new(q.dot(self.right), q.dot(self.up), q.dot(self.forward))
    }

    fn to_screen(&self, v: DVec3) -> DVec3 {
        DVec3::new(
            (v.x / v.z + 1.0) * 0.5 * self.size[0],
            (1.0 - v.y / v.z) * 0.5 * self.size[1],
            v.z,
        )
    }
}

fn edge(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

struct Best {
    id: u32,
    depth: f64,
    slack: f64,
}

/// Rasterises `positions` (posed, the mesh's vertex order) with `prep`'s triangles.
pub fn visibility(positions: &[Vec3], prep: &Prepared, camera: &Camera) -> Visibility {
    let view = View::new(camera, prep.size);
    let [w, h] = prep.size.map(|x| x as usize);
    let mut best: Vec<Option<Best>> = (0..w * h).map(|_| None).collect();
    // Per pixel: the nearest depth (and its slack) of a covering triangle other than the
    // best one; updated as the best changes.
    let mut other: Vec<(f64, f64)> = vec![(f64::INFINITY, 0.0); w * h];
    let mut near_edge = vec![false; w * h];
    let mut counters = [0u32; 8];
    for (id, t) in prep.triangles.iter().enumerate() {
        let v = [t[0], t[1], t[2]].map(|i| view.to_view(positions[i as usize]));
        let inside = v.iter().filter(|p| p.z >= view.near).count();
        if inside == 0 {
            counters[counter::NEAR_CULLED] += 1;
            continue;
        }
        if (v[1] - v[0]).cross(v[2] - v[0]).dot(v[0]) < 0.0 {
            counters[counter::BACK_FACING] += 1;
        }
        let mut poly = Vec::with_capacity(4);
        for i in 0..3 {
            let (a, b) = (v[i], v[(i + 1) % 3]);
            let (ain, bin) = (a.z >= view.near, b.z >= view.near);
            if ain {
                poly.push(a);
            }
            if ain != bin {
                poly.push(a.lerp(b, (view.near - a.z) / (b.z - a.z)));
            }
        }
        if inside < 3 {
            counters[counter::NEAR_CLIPPED] += 1;
        }
        let s: Vec<DVec3> = poly.iter().map(|p| view.to_screen(*p)).collect();
        for k in 1..s.len() - 1 {
            let tri = [s[0], s[k], s[k + 1]];
            if tri
                .iter()
                .any(|p| p.x.abs() > GUARD_BAND || p.y.abs() > GUARD_BAND)
            {
                continue;
            }
            scan(tri, id as u32, prep.size, &mut |px, hit| match hit {
                Hit::NearEdge => near_edge[px] = true,
                Hit::Covered(depth, slack) => {
                    let b = &mut best[px];
                    match b {
                        Some(cur) if cur.id == id as u32 => {
                            if depth < cur.depth {
                                cur.depth = depth;
                                cur.slack = slack;
                            }
                        }
                        Some(cur) if depth < cur.depth => {
                            if cur.depth < other[px].0 {
                                other[px] = (cur.depth, cur.slack);
                            }
                            *cur = Best {
                                id: id as u32,
                                depth,
                                slack,
                            };
                        }
                        Some(_) => {
                            if depth < other[px].0 {
                                other[px] = (depth, slack);
                            }
                        }
                        None => {
                            *b = Some(Best {
                                id: id as u32,
                                depth,
                                slack,
                            })
                        }
                    }
                }
            });
        }
    }
    let mut out = Visibility {
        size: prep.size,
        id: vec![u32::MAX; w * h],
        depth: vec![f64::INFINITY; w * h],
        slack: vec![0.0; w * h],
        robust: vec![false; w * h],
        counters,
    };
    for px in 0..w * h {
        let separated = match &best[px] {
            Some(b) => {
                out.id[px] = b.id;
                out.depth[px] = b.depth;
                out.slack[px] = b.slack;
                other[px].0 - b.depth > b.slack + other[px].1
            }
            None => true,
        };
        out.robust[px] = separated && !near_edge[px];
    }
    out
}

enum Hit {
    NearEdge,
    Covered(f64, f64),
}

/// Visits the pixels of screen triangle `s` (x, y in pixels, z the view depth): those whose
/// centre lies near an edge that decides coverage, and those covered, with depth and slack.
fn scan(s: [DVec3; 3], _id: u32, size: [u32; 2], visit: &mut impl FnMut(usize, Hit)) {
    let p2 = s.map(|p| DVec2::new(p.x, p.y));
    let area = edge(p2[0], p2[1], p2[2]);
    if area == 0.0 {
        return;
    }
    let (p2, iz) = if area < 0.0 {
        (
            [p2[0], p2[2], p2[1]],
            [1.0 / s[0].z, 1.0 / s[2].z, 1.0 / s[1].z],
        )
    } else {
        (p2, [1.0 / s[0].z, 1.0 / s[1].z, 1.0 / s[2].z])
    };
    let area = area.abs();
    let lens = [
        (p2[2] - p2[1]).length(),
        (p2[0] - p2[2]).length(),
        (p2[1] - p2[0]).length(),
    ];
    let lo = p2[0].min(p2[1]).min(p2[2]);
    let hi = p2[0].max(p2[1]).max(p2[2]);
    let x0 = (lo.x - 1.0).floor().max(0.0) as i64;
    let y0 = (lo.y - 1.0).floor().max(0.0) as i64;
    let x1 = ((hi.x + 1.0).ceil() as i64).min(size[0] as i64 - 1);
    let y1 = ((hi.y + 1.0).ceil() as i64).min(size[1] as i64 - 1);
    let bary = |p: DVec2| {
        [
            edge(p2[1], p2[2], p) / area,
            edge(p2[2], p2[0], p) / area,
            edge(p2[0], p2[1], p) / area,
        ]
    };
    let depth = |b: [f64; 3]| 1.0 / (b[0] * iz[0] + b[1] * iz[1] + b[2] * iz[2]);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            let b = bary(p);
            let d: [f64; 3] = std::array::from_fn(|i| b[i] * area / lens[i].max(1e-300));
            let k = y as usize * size[0] as usize + x as usize;
            let deciding = (0..3)
                .any(|i| d[i].abs() < EDGE_MARGIN && (0..3).all(|j| j == i || d[j] > -EDGE_MARGIN));
            if deciding {
                visit(k, Hit::NearEdge);
            }
            if b.iter().all(|&v| v >= 0.0) {
                let z = depth(b);
                let step = 2.0 / SUBPIXEL;
                let zx = depth(bary(p + DVec2::new(step, 0.0)));
                let zy = depth(bary(p + DVec2::new(0.0, step)));
                let slack = (zx - z).abs() + (zy - z).abs() + 1e-5 * z;
                visit(k, Hit::Covered(z, slack));
            }
        }
    }
}

/// The posed geometry on the CPU (the pose kernel's layout): positions, unit normals, unit
/// tangents with w = handedness.
pub struct PosedCpu<'a> {
    /// Posed positions.
    pub positions: &'a [Vec3],
    /// Posed unit normals.
    pub normals: &'a [Vec3],
    /// Posed unit tangents, w = handedness.
    pub tangents: &'a [Vec4],
}

/// The G-buffer the resolve pass writes for triangle ids `id` (per pixel, `u32::MAX` for
/// none), in f64: the same ray, barycentrics (clamped), interpolation, facing and layout.
pub fn resolve(posed: &PosedCpu<'_>, prep: &Prepared, camera: &Camera, id: &[u32]) -> GBuffer {
    resolve_conditioned(posed, prep, camera, id).0
}

/// As [`resolve`], with per pixel the lengths of the interpolated normal and of the
/// interpolated tangent after Gram-Schmidt, before each is normalised (0 where nothing is
/// covered): normalising divides the interpolation's rounding by them, so where they are
/// small (folds, mirror seams) f32 and f64 differ most.
pub fn resolve_conditioned(
    posed: &PosedCpu<'_>,
    prep: &Prepared,
    camera: &Camera,
    id: &[u32],
) -> (GBuffer, Vec<[f64; 2]>) {
    let [w, h] = prep.size;
    let b = camera.basis(prep.size);
    let eye = camera.eye.as_dvec3();
    let (fwd, right, up) = (
        b.forward.as_dvec3(),
        (b.right * b.tan_x).as_dvec3(),
        (b.up * b.tan_y).as_dvec3(),
    );
    let scale = prep.uv_scale as f64;
    let mut texels = Vec::with_capacity(3 * (w * h) as usize);
    let mut lengths = vec![[0.0; 2]; (w * h) as usize];
    for k in 0..(w * h) as usize {
        if id[k] == u32::MAX {
            texels.extend([[0.0f32; 4]; 3]);
            continue;
        }
        let t = prep.triangles[id[k] as usize];
        let [ia, ib, ic] = [t[0], t[1], t[2]].map(|i| i as usize);
        let (x, y) = ((k % w as usize) as f64, (k / w as usize) as f64);
        let s = [
            (x + 0.5) / w as f64 * 2.0 - 1.0,
            (y + 0.5) / h as f64 * 2.0 - 1.0,
        ];
        let d = (fwd + right * s[0] - up * s[1]).normalize();
        let p = |i: usize| posed.positions[i].as_dvec3();
        let (a, e1, e2) = (p(ia), p(ib) - p(ia), p(ic) - p(ia));
        let pv = d.cross(e2);
        let det = e1.dot(pv);
        let inv = if det != 0.0 { 1.0 / det } else { 0.0 };
        let tv = eye - a;
        let u = (tv.dot(pv) * inv).clamp(0.0, 1.0);
        let qv = tv.cross(e1);
        let v = (d.dot(qv) * inv).clamp(0.0, 1.0 - u);
        let w0 = 1.0 - u - v;
        let mix3 = |f: &dyn Fn(usize) -> DVec3| f(ia) * w0 + f(ib) * u + f(ic) * v;
        let pos = mix3(&|i| p(i));
        let mut n = mix3(&|i| posed.normals[i].as_dvec3());
        lengths[k][0] = n.length();
        n = if n.length() > 0.0 {
            n.normalize()
        } else {
            e1.cross(e2).normalize()
        };
        let tg = mix3(&|i| posed.tangents[i].truncate().as_dvec3());
        let tw = posed.tangents[ia].w as f64 * w0
            + posed.tangents[ib].w as f64 * u
            + posed.tangents[ic].w as f64 * v;
        let mut hand = if tw >= 0.0 { 1.0 } else { -1.0 };
        if n.dot(d) > 0.0 {
            n = -n;
            hand = -hand;
        }
        let mut tt = tg - n * n.dot(tg);
        lengths[k][1] = tt.length();
        if tt.length_squared() < 1e-12 {
            tt = if n.x.abs() < 0.9 {
                n.cross(DVec3::X)
            } else {
                n.cross(DVec3::Y)
            };
        }
        let tg = tt.normalize();
        let uv = |c: usize| {
            (prep.uvs[ia][c] as f64 * w0 + prep.uvs[ib][c] as f64 * u + prep.uvs[ic][c] as f64 * v)
                * scale
        };
        let tag = hand * (1.0 + t[3] as f64);
        texels.push([pos.x as f32, pos.y as f32, pos.z as f32, tag as f32]);
        texels.push([n.x as f32, n.y as f32, n.z as f32, uv(0) as f32]);
        texels.push([tg.x as f32, tg.y as f32, tg.z as f32, uv(1) as f32]);
    }
    let gb = GBuffer {
        width: w,
        height: h,
        texels,
    };
    (gb, lengths)
}
