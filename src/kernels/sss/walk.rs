//! Where a diffusion sample lands when its tangent-plane offset leaves the receiver's triangle.
//!
//! The texture-space sampler draws an offset r (cos phi, sin phi) in the plane of the
//! receiver's triangle T and reads the irradiance where it lands. Inside T the UV map is
//! affine, so the landing point's atlas position follows from T's own map. Outside T the
//! surface goes on in a neighbour whose UV map differs: its Jacobian differs (the atlas
//! stretches differently from one triangle to the next), it may lie in another chart (a seam:
//! the neighbour is somewhere else in the atlas), or there may be no neighbour at all (an
//! open border: the neck cut, the eye holes). Extrapolating T's map there reads the wrong
//! texel or none; measured on the BCN_Epileptic head, that costs more than a third of the
//! error against the brute-force truth.
//!
//! So a sample leaving T is followed across the edge it leaves through: the neighbour N is
//! unfolded about the shared edge into T's plane (a rigid 2D map, lengths kept; a reflection
//! where the two are wound inconsistently) and the landing point is read through N's UV map.
//! Composed, that is one affine map from T's barycentrics to the atlas per edge of T,
//! precomputed ([`SurfaceWalk::records`]): a sample leaving T costs one more texel load on
//! the GPU. A sample that goes on beyond N is read through N's map extrapolated (one crossing
//! is followed, not more). Past an open edge there is no surface: the sample counts with no
//! light. Edges shared by more than two triangles are not crossed (the sample is dropped and
//! the rest renormalise).
//!
//! Adjacency is found from 3D positions (vertices are welded by position, since meshes split
//! vertices along UV seams), so seams of the layout and of the overlap repair are crossed
//! like any other edge. The unit tests check the one-crossing maps against a walk across any
//! number of triangles.
//!
//! The arithmetic is f32 and written as the shader does it (`glsl/common/sss_diffusion.glsl`).

use crate::scene::texspace::TexGeometry;
use glam::{DVec2, Vec2, Vec3};
use std::collections::HashMap;

/// Neighbour code: the edge is an open border of the mesh.
pub const OPEN: u32 = u32::MAX;
/// Neighbour code: the edge is shared by more than two triangles (not crossed).
pub const NON_MANIFOLD: u32 = u32::MAX - 1;
/// Texels per triangle record in [`SurfaceWalk::records`].
pub const RECORD_TEXELS: usize = 9;

/// Edge kinds in a record's flags (two bits per edge).
pub const EDGE_SHARED: u32 = 0;
pub const EDGE_OPEN: u32 = 1;
pub const EDGE_LOST: u32 = 2;

/// One triangle as the walk reads it.
#[derive(Clone, Copy, Debug)]
pub struct WalkTri {
    /// Corners (mm).
    pub p: [Vec3; 3],
    /// Across the edge opposite corner i: the neighbour triangle, or [`OPEN`] /
    /// [`NON_MANIFOLD`].
    pub nbr: [u32; 3],
    /// Atlas UV of the corners in texel units with texel centres at integers (u N - 0.5).
    pub uv: [Vec2; 3],
    /// The 2D frame: corner 0 at the origin, corner 1 at (l1, 0), corner 2 at (x2, y2) with
    /// y2 > 0 (all 0 when degenerate).
    pub shape: [f32; 3],
    /// Per edge, the map from this frame to the neighbour's: q' = F(R q) + t with R the
    /// rotation (cos, sin), t = (tx, ty), F = diag(1, -1) where `flip` has bit i set.
    pub map: [[f32; 4]; 3],
    pub flip: u32,
    /// Per edge, this triangle's barycentrics (b1, b2) to the atlas through the neighbour:
    /// uv = s + V (b1, b2), V row-major.
    pub cross_v: [[f32; 4]; 3],
    pub cross_s: [Vec2; 3],
}

/// Where a sample lands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Landing {
    /// On the surface, at this atlas position (texel units, centres at integers).
    Atlas(Vec2),
    /// Past an open border: no surface there (no light).
    Off,
    /// Not followed (a non-manifold edge or a degenerate triangle).
    Lost,
}

/// The mesh as the sampler reads it.
#[derive(Clone, Debug)]
pub struct SurfaceWalk {
    pub tris: Vec<WalkTri>,
    /// Edges by kind: open, shared by two triangles, shared by more.
    pub open_edges: usize,
    pub shared_edges: usize,
    pub non_manifold_edges: usize,
}

/// One id per distinct position (bitwise; -0.0 and 0.0 are the same point) for each vertex,
/// and the number of ids: vertices split along UV seams get the same id.
pub fn weld(positions: &[Vec3]) -> (Vec<u32>, usize) {
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let weld = positions
        .iter()
        .map(|p| {
            let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
            let next = ids.len() as u32;
            *ids.entry(key).or_insert(next)
        })
        .collect();
    (weld, ids.len())
}

/// 1 / l1 and 1 / y2 of a shape (0 for a degenerate one).
fn inverses(shape: [f32; 3]) -> (f32, f32) {
    if shape[0] > 0.0 && shape[2] > 0.0 {
        (1.0 / shape[0], 1.0 / shape[2])
    } else {
        (0.0, 0.0)
    }
}

/// A triangle's frame: the x and y axes (3D) and its shape (l1, x2, y2); zeros when
/// degenerate.
fn frame(p: [Vec3; 3]) -> ([Vec3; 2], [f32; 3]) {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let l1 = e1.length();
    let n = e1.cross(e2);
    if l1.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
        || n.length().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    {
        return ([Vec3::ZERO; 2], [0.0; 3]);
    }
    let x = e1 / l1;
    let y = n.normalize().cross(x);
    ([x, y], [l1, e2.dot(x), e2.dot(y)])
}

/// Applies an edge map (see [`WalkTri::map`]) to a point (`translate`) or a vector.
fn apply(m: [f32; 4], flip: bool, q: Vec2, translate: bool) -> Vec2 {
    let [c, sn, tx, ty] = m;
    let f = if flip { -1.0 } else { 1.0 };
    let (tx, ty) = if translate { (tx, ty) } else { (0.0, 0.0) };
    Vec2::new(c * q.x - sn * q.y + tx, f * (sn * q.x + c * q.y) + ty)
}

/// The map across edge k of triangle `pa` into neighbour `pb`'s frame, and whether it is a
/// reflection.
fn unfold_map(pa: [Vec3; 3], k: usize, pb: [Vec3; 3]) -> ([f32; 4], bool) {
    let (fa, _) = frame(pa);
    let (fb, _) = frame(pb);
    let to2 = |f: &[Vec3; 2], o: Vec3, x: Vec3| Vec2::new((x - o).dot(f[0]), (x - o).dot(f[1]));
    let (ea, eb) = (pa[(k + 1) % 3], pa[(k + 2) % 3]);
    let a_t = to2(&fa, pa[0], ea);
    let b_t = to2(&fa, pa[0], eb);
    let c_t = to2(&fa, pa[0], pa[k]);
    let a_n = to2(&fb, pb[0], ea);
    let b_n = to2(&fb, pb[0], eb);
    // The neighbour's corner off the shared edge (the one farthest from both ends).
    let off = (0..3)
        .map(|i| pb[i])
        .max_by(|x, y| {
            let dx = (*x - ea).length_squared().min((*x - eb).length_squared());
            let dy = (*y - ea).length_squared().min((*y - eb).length_squared());
            dx.total_cmp(&dy)
        })
        .unwrap_or(pb[0]);
    let c_n = to2(&fb, pb[0], off);
    let dt = b_t - a_t;
    let dn = b_n - a_n;
    let cross = |u: Vec2, w: Vec2| u.x * w.y - u.y * w.x;
    for flip in [false, true] {
        let f = if flip { -1.0 } else { 1.0 };
        let target = Vec2::new(dn.x, f * dn.y);
        let ang = target.y.atan2(target.x) - dt.y.atan2(dt.x);
        let (sn, c) = ang.sin_cos();
        let m = [c, sn, 0.0, 0.0];
        let t = a_n - apply(m, flip, a_t, false);
        let m = [c, sn, t.x, t.y];
        // This triangle's third corner must land on the far side of the edge from the
        // neighbour's.
        if cross(dn, apply(m, flip, c_t, true) - a_n) * cross(dn, c_n - a_n) <= 0.0 {
            return (m, flip);
        }
    }
    // Degenerate (a corner on the edge line): the proper rotation.
    let ang = dn.y.atan2(dn.x) - dt.y.atan2(dt.x);
    let (sn, c) = ang.sin_cos();
    let t = a_n - apply([c, sn, 0.0, 0.0], false, a_t, false);
    ([c, sn, t.x, t.y], false)
}

impl SurfaceWalk {
    /// Adjacency, frames and crossing maps of `geo`'s triangles (positions welded exactly).
    pub fn build(geo: &TexGeometry) -> SurfaceWalk {
        let nf = geo.size as f32;
        let (weld, _) = weld(&geo.positions);
        let mut tris: Vec<WalkTri> = geo
            .triangles
            .iter()
            .zip(&geo.corner_uvs)
            .map(|(tri, uv)| {
                let p = tri.map(|i| geo.positions[i as usize]);
                WalkTri {
                    p,
                    nbr: [OPEN; 3],
                    uv: uv.map(|u| u * nf - Vec2::splat(0.5)),
                    shape: frame(p).1,
                    map: [[0.0; 4]; 3],
                    flip: 0,
                    cross_v: [[0.0; 4]; 3],
                    cross_s: [Vec2::ZERO; 3],
                }
            })
            .collect();
        let mut edges: HashMap<(u32, u32), Vec<(u32, u32)>> = HashMap::new();
        for (t, tri) in geo.triangles.iter().enumerate() {
            for i in 0..3 {
                let a = weld[tri[(i + 1) % 3] as usize];
                let b = weld[tri[(i + 2) % 3] as usize];
                edges
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push((t as u32, i as u32));
            }
        }
        let (mut open, mut shared, mut non_manifold) = (0, 0, 0);
        for list in edges.values() {
            match list[..] {
                [_] => open += 1,
                [(t0, i0), (t1, i1)] => {
                    shared += 1;
                    tris[t0 as usize].nbr[i0 as usize] = t1;
                    tris[t1 as usize].nbr[i1 as usize] = t0;
                }
                _ => {
                    non_manifold += 1;
                    for &(t, i) in list {
                        tris[t as usize].nbr[i as usize] = NON_MANIFOLD;
                    }
                }
            }
        }
        for t in 0..tris.len() {
            for k in 0..3 {
                let nb = tris[t].nbr[k];
                if nb >= NON_MANIFOLD {
                    continue;
                }
                let (m, f) = unfold_map(tris[t].p, k, tris[nb as usize].p);
                tris[t].map[k] = m;
                tris[t].flip |= (f as u32) << k;
                let (v, s) = crossing(&tris[t], k, &tris[nb as usize]);
                tris[t].cross_v[k] = v;
                tris[t].cross_s[k] = s;
            }
        }
        SurfaceWalk {
            tris,
            open_edges: open,
            shared_edges: shared,
            non_manifold_edges: non_manifold,
        }
    }

    /// The kind of edge k of triangle `tri` ([`EDGE_SHARED`], [`EDGE_OPEN`], [`EDGE_LOST`]).
    pub fn edge_kind(&self, tri: u32, k: usize) -> u32 {
        let t = &self.tris[tri as usize];
        match t.nbr[k] {
            OPEN => EDGE_OPEN,
            NON_MANIFOLD => EDGE_LOST,
            nb if self.tris[nb as usize].shape[0] > 0.0
                && self.tris[nb as usize].shape[2] > 0.0 =>
            {
                EDGE_SHARED
            }
            _ => EDGE_LOST,
        }
    }

    /// The sampler of a receiver at barycentrics (1 - w1 - w2, w1, w2) of triangle `tri`,
    /// with its pattern turned by `phi0` (radians) in the triangle's frame.
    pub fn texel(&self, tri: u32, w1: f32, w2: f32, phi0: f32) -> TexelSampler<'_> {
        let t = &self.tris[tri as usize];
        let x2 = t.shape[1];
        let (il1, iy2) = inverses(t.shape);
        let (c0, s0) = (phi0.cos(), phi0.sin());
        let a = s0 * iy2;
        let b = c0 * iy2;
        let c = (c0 - x2 * a) * il1;
        let d = (-s0 - x2 * b) * il1;
        let du1 = t.uv[1] - t.uv[0];
        let du2 = t.uv[2] - t.uv[0];
        TexelSampler {
            walk: self,
            tri,
            w: [1.0 - w1 - w2, w1, w2],
            rate: [a, b, c, d],
            uvt: t.uv[0] + du1 * w1 + du2 * w2,
            ux: du1 * c + du2 * a,
            uy: du1 * d + du2 * b,
        }
    }

    /// Whether edge k of triangle `tri` ends its UV chart: an open or non-manifold edge, or
    /// a seam (the neighbour's UVs at the shared corners differ from this triangle's).
    pub fn is_seam(&self, tri: u32, k: usize) -> bool {
        let t = &self.tris[tri as usize];
        let nb = t.nbr[k];
        if nb >= NON_MANIFOLD {
            return true;
        }
        let n = &self.tris[nb as usize];
        [(k + 1) % 3, (k + 2) % 3]
            .iter()
            .any(|&c| match (0..3).find(|&j| n.p[j] == t.p[c]) {
                Some(j) => n.uv[j] != t.uv[c],
                None => true,
            })
    }

    /// The records the shader reads, [`RECORD_TEXELS`] RGBA32UI texels per triangle:
    /// (1 / l1, x2, 1 / y2, edge kinds: 2 bits per edge), (uv0, uv1 - uv0), (uv2 - uv0, 0, 0)
    /// (z: the triangle's skin region, written by `pack::region_records`), then per edge the
    /// crossing map (V row-major), (s, 0, 0); floats as bits.
    pub fn records(&self) -> Vec<[u32; 4]> {
        let mut out = Vec::with_capacity(self.tris.len() * RECORD_TEXELS);
        for (i, t) in self.tris.iter().enumerate() {
            let b = |x: f32| x.to_bits();
            let (il1, iy2) = inverses(t.shape);
            let kinds = (0..3).fold(0, |acc, k| acc | self.edge_kind(i as u32, k) << (2 * k));
            let du1 = t.uv[1] - t.uv[0];
            let du2 = t.uv[2] - t.uv[0];
            out.push([b(il1), b(t.shape[1]), b(iy2), kinds]);
            out.push([b(t.uv[0].x), b(t.uv[0].y), b(du1.x), b(du1.y)]);
            out.push([b(du2.x), b(du2.y), 0, 0]);
            for k in 0..3 {
                out.push(t.cross_v[k].map(b));
                out.push([b(t.cross_s[k].x), b(t.cross_s[k].y), 0, 0]);
            }
        }
        out
    }
}

/// The crossing map of edge k of `t` into neighbour `n`: this triangle's barycentrics
/// (b1, b2) -> atlas through `n` unfolded, uv = s + V (b1, b2).
fn crossing(t: &WalkTri, k: usize, n: &WalkTri) -> ([f32; 4], Vec2) {
    let [l1, x2, y2] = t.shape.map(|x| x as f64);
    let [m1, mx2, my2] = n.shape.map(|x| x as f64);
    if !(m1 > 0.0 && my2 > 0.0) {
        return ([0.0; 4], Vec2::ZERO);
    }
    let [c, sn, tx, ty] = t.map[k].map(|x| x as f64);
    let f = if t.flip >> k & 1 == 1 { -1.0 } else { 1.0 };
    let uv0 = n.uv[0].as_dvec2();
    let du1 = n.uv[1].as_dvec2() - uv0;
    let du2 = n.uv[2].as_dvec2() - uv0;
    let at = |b1: f64, b2: f64| {
        let q = DVec2::new(b1 * l1 + b2 * x2, b2 * y2);
        let qn = DVec2::new(c * q.x - sn * q.y + tx, f * (sn * q.x + c * q.y) + ty);
        let g2 = qn.y / my2;
        let g1 = (qn.x - mx2 * g2) / m1;
        uv0 + du1 * g1 + du2 * g2
    };
    let s = at(0.0, 0.0);
    let e1 = at(1.0, 0.0) - s;
    let e2 = at(0.0, 1.0) - s;
    ([e1.x, e2.x, e1.y, e2.y].map(|x| x as f32), s.as_vec2())
}

/// One receiver's sampler ([`SurfaceWalk::texel`]): the barycentric rates and the atlas map of
/// its triangle folded with the pattern's rotation, as the shader sets them up per texel.
pub struct TexelSampler<'a> {
    walk: &'a SurfaceWalk,
    tri: u32,
    /// The receiver's barycentrics.
    w: [f32; 3],
    /// d2 = a ux + b uy, d1 = c ux + d uy for a pattern offset (ux, uy).
    rate: [f32; 4],
    /// The receiver's atlas position and the atlas offsets per unit ux and uy.
    uvt: Vec2,
    ux: Vec2,
    uy: Vec2,
}

impl TexelSampler<'_> {
    /// The receiver's triangle.
    pub fn triangle(&self) -> u32 {
        self.tri
    }

    /// The edge of the receiver's triangle that the pattern offset (ux, uy) leaves by; None
    /// when it stays in the triangle.
    pub fn exit(&self, ux: f32, uy: f32) -> Option<usize> {
        self.step(ux, uy).0
    }

    /// The exit edge (if any) and the end point's barycentrics (b1, b2) in the receiver's
    /// triangle (the shader's arithmetic).
    fn step(&self, ux: f32, uy: f32) -> (Option<usize>, f32, f32) {
        let [a, b, c, d] = self.rate;
        let d2 = a * ux + b * uy;
        let d1 = c * ux + d * uy;
        let [w0, w1, w2] = self.w;
        let b1 = w1 + d1;
        let b2 = w2 + d2;
        let b0 = 1.0 - b1 - b2;
        if b0.min(b1).min(b2) >= 0.0 {
            return (None, b1, b2);
        }
        // The first edge whose barycentric reaches 0 along the way. Barycentrics are linear
        // along the offset, so it is one the end point lies beyond (b_k < 0); of two such,
        // edge i comes first when w_i / -d_i < w_j / -d_j, i.e. w_i d_j > w_j d_i.
        let d0 = -(d1 + d2);
        let exit =
            if b0 < 0.0 && (b1 >= 0.0 || w0 * d1 > w1 * d0) && (b2 >= 0.0 || w0 * d2 > w2 * d0) {
                0
            } else if b1 < 0.0 && (b2 >= 0.0 || w1 * d2 > w2 * d1) {
                1
            } else {
                2
            };
        (Some(exit), b1, b2)
    }

    /// Where the pattern offset (ux, uy) (mm, before the receiver's rotation) lands.
    pub fn land(&self, ux: f32, uy: f32) -> Landing {
        let (exit, b1, b2) = self.step(ux, uy);
        let Some(exit) = exit else {
            return Landing::Atlas(self.uvt + self.ux * ux + self.uy * uy);
        };
        match self.walk.edge_kind(self.tri, exit) {
            EDGE_OPEN => Landing::Off,
            EDGE_LOST => Landing::Lost,
            _ => {
                let t = &self.walk.tris[self.tri as usize];
                let v = t.cross_v[exit];
                let s = t.cross_s[exit];
                Landing::Atlas(Vec2::new(
                    s.x + v[0] * b1 + v[1] * b2,
                    s.y + v[2] * b1 + v[3] * b2,
                ))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Mesh;
    use crate::scene::mesh::MeshData;

    /// Triangles [`SurfaceWalk::walk`] may cross before it gives up.
    const MAX_STEPS: u32 = 64;

    /// Where [`SurfaceWalk::walk`] ends.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum WalkEnd {
        /// On triangle `tri` at barycentrics (1 - b1 - b2, b1, b2).
        Surface {
            tri: u32,
            b1: f32,
            b2: f32,
        },
        Off,
        Lost,
    }

    /// The reference the one-crossing sampler is checked against: a walk across as many
    /// triangles as it takes.
    impl SurfaceWalk {
        /// Follows the offset `v` (mm, in the frame of `tri`) from barycentrics (w1, w2) across
        /// as many triangles as it takes (a reference for [`TexelSampler::land`], which follows
        /// one crossing).
        fn walk(&self, mut tri: u32, w1: f32, w2: f32, mut v: Vec2) -> WalkEnd {
            let [l1, x2, y2] = self.tris[tri as usize].shape;
            let mut p = Vec2::new(w1 * l1 + w2 * x2, w2 * y2);
            for _ in 0..MAX_STEPS {
                let t = &self.tris[tri as usize];
                let x2 = t.shape[1];
                let (il1, iy2) = inverses(t.shape);
                if !(il1 > 0.0 && iy2 > 0.0) {
                    return WalkEnd::Lost;
                }
                let b2 = p.y * iy2;
                let b1 = (p.x - x2 * b2) * il1;
                let b = [1.0 - b1 - b2, b1, b2];
                let d2 = v.y * iy2;
                let d1 = (v.x - x2 * d2) * il1;
                let d = [-(d1 + d2), d1, d2];
                let mut s = 1.0f32;
                let mut exit = 3usize;
                for k in 0..3 {
                    if d[k] < 0.0 {
                        let sk = b[k].max(0.0) / -d[k];
                        if sk < s {
                            s = sk;
                            exit = k;
                        }
                    }
                }
                if exit == 3 {
                    let q = p + v;
                    let b2 = q.y * iy2;
                    let b1 = (q.x - x2 * b2) * il1;
                    return WalkEnd::Surface { tri, b1, b2 };
                }
                let nb = t.nbr[exit];
                if nb == OPEN {
                    return WalkEnd::Off;
                }
                if nb == NON_MANIFOLD {
                    return WalkEnd::Lost;
                }
                let flip = t.flip >> exit & 1 == 1;
                p = apply(t.map[exit], flip, p + v * s, true);
                v = apply(t.map[exit], flip, v * (1.0 - s), false);
                tri = nb;
            }
            WalkEnd::Lost
        }

        /// The atlas position (texel units, centres at integers) of barycentrics (b1, b2) of
        /// triangle `tri`.
        fn atlas(&self, tri: u32, b1: f32, b2: f32) -> Vec2 {
            let t = &self.tris[tri as usize];
            t.uv[0] + (t.uv[1] - t.uv[0]) * b1 + (t.uv[2] - t.uv[0]) * b2
        }

        /// The 3D point at barycentrics (b1, b2) of triangle `tri`.
        fn point(&self, tri: u32, b1: f32, b2: f32) -> Vec3 {
            let p = self.tris[tri as usize].p;
            p[0] + (p[1] - p[0]) * b1 + (p[2] - p[0]) * b2
        }
    }

    /// Two 10 x 10 mm squares side by side (x in [0, 10] and [10, 20]), the second bent about
    /// x = 10 by `bend` radians (rising in z), its vertices duplicated along the shared edge;
    /// the first square at UV [0.05, 0.45] x [0.3, 0.7], the second (a seam) at
    /// [0.55, 0.95] x [0.3, 0.7].
    fn two_squares(bend: f32) -> TexGeometry {
        let (c, s) = (bend.cos(), bend.sin());
        let far = |x: f32, y: f32| [10.0 + (x - 10.0) * c, y, (x - 10.0) * s];
        let mut data = MeshData {
            name: "two squares".into(),
            ..Default::default()
        };
        let mut uvs = Vec::new();
        for (p, uv) in [
            ([0.0, 0.0, 0.0], [0.05, 0.3]),
            ([10.0, 0.0, 0.0], [0.45, 0.3]),
            ([10.0, 10.0, 0.0], [0.45, 0.7]),
            ([0.0, 10.0, 0.0], [0.05, 0.7]),
            (far(10.0, 0.0), [0.55, 0.3]),
            (far(20.0, 0.0), [0.95, 0.3]),
            (far(20.0, 10.0), [0.95, 0.7]),
            (far(10.0, 10.0), [0.55, 0.7]),
        ] {
            data.positions.push(p);
            uvs.push(uv);
        }
        data.triangles = vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]];
        data.uvs = Some(uvs);
        let mesh = Mesh::from_data(data, std::path::Path::new("<two squares>")).unwrap();
        TexGeometry::build(&mesh, 64, 1.0).unwrap()
    }

    /// The covered texel nearest the 3D point `at`, its triangle and barycentrics.
    fn texel_at(geo: &TexGeometry, at: Vec3) -> (usize, u32, f32, f32) {
        let i = (0..geo.texels())
            .filter(|&i| geo.pos[i][3] == crate::scene::texspace::COVERED)
            .min_by(|&a, &b| {
                let d = |i: usize| (Vec3::from_slice(&geo.pos[i][..3]) - at).length();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        let t = geo.texel_tri[i];
        (i, t[0], f32::from_bits(t[1]), f32::from_bits(t[2]))
    }

    #[test]
    fn adjacency_is_welded_across_the_seam() {
        let geo = two_squares(0.0);
        let walk = SurfaceWalk::build(&geo);
        // 4 triangles: 2 diagonals, the seam edge shared; 6 border edges open.
        assert_eq!(walk.shared_edges, 3);
        assert_eq!(walk.open_edges, 6);
        assert_eq!(walk.non_manifold_edges, 0);
        let seams: usize = (0..4u32)
            .map(|t| (0..3).filter(|&k| walk.is_seam(t, k)).count())
            .sum();
        // 6 open edges and the seam seen from both sides; the diagonals are not seams.
        assert_eq!(seams, 8);
    }

    #[test]
    fn a_sample_crossing_the_seam_lands_where_the_neighbour_maps_it() {
        for bend in [0.0f32, 0.5, std::f32::consts::FRAC_PI_2] {
            let geo = two_squares(bend);
            let walk = SurfaceWalk::build(&geo);
            let (i, tri, w1, w2) = texel_at(&geo, Vec3::new(8.0, 5.0, 0.0));
            let po = walk.point(tri, w1, w2);
            let n = geo.size as f32;
            let mut crossed = 0;
            // Offsets in every direction, 1 to 5 mm: the one-crossing map against the full
            // walk, and against where the unfolded surface puts the point.
            for step in 0..24 {
                let phi = step as f32 * 0.2618;
                for r in [1.0f32, 3.0, 5.0] {
                    let texel = walk.texel(tri, w1, w2, phi);
                    let landing = texel.land(r, 0.0);
                    let full = walk.walk(tri, w1, w2, {
                        let (s, c) = phi.sin_cos();
                        Vec2::new(c * r, s * r)
                    });
                    match (landing, full) {
                        (Landing::Atlas(uv), WalkEnd::Surface { tri: t, b1, b2 }) => {
                            let want = walk.atlas(t, b1, b2);
                            assert!(
                                (uv - want).length() < 1e-3,
                                "bend {bend} phi {phi} r {r}: {uv} vs {want}"
                            );
                            // Geodesic distance r on the (developable) strip: the point lies
                            // r from the start once the bend is unrolled.
                            let q = walk.point(t, b1, b2);
                            let unrolled = |p: Vec3| {
                                if p.x <= 10.0 + 1e-4 && p.z.abs() < 1e-4 {
                                    Vec2::new(p.x, p.y)
                                } else {
                                    let d = Vec2::new(p.x - 10.0, p.z).length();
                                    Vec2::new(10.0 + d, p.y)
                                }
                            };
                            let dist = (unrolled(q) - unrolled(po)).length();
                            assert!((dist - r).abs() < 1e-3, "bend {bend}: {dist} vs {r}");
                            // The atlas position is that point's UV on its square.
                            let u = unrolled(q);
                            crossed += (u.x > 10.0) as usize;
                            let want_uv = if u.x <= 10.0 {
                                Vec2::new(0.05 + 0.04 * u.x, 0.3 + 0.04 * u.y)
                            } else {
                                Vec2::new(0.55 + 0.04 * (u.x - 10.0), 0.3 + 0.04 * u.y)
                            } * n
                                - Vec2::splat(0.5);
                            assert!((uv - want_uv).length() < 1e-2, "{uv} vs {want_uv}");
                        }
                        (Landing::Off, WalkEnd::Off) => {}
                        other => panic!("texel {i} phi {phi} r {r}: {other:?}"),
                    }
                }
            }
            assert!(
                crossed >= 10,
                "bend {bend}: only {crossed} samples crossed the seam"
            );
        }
    }

    #[test]
    fn a_sample_past_an_open_edge_is_off_the_surface() {
        let geo = two_squares(0.0);
        let walk = SurfaceWalk::build(&geo);
        let (_, tri, w1, w2) = texel_at(&geo, Vec3::new(1.0, 5.0, 0.0));
        // Toward -x (in the world) is the open edge x = 0, 1 mm away.
        let off = (0..64)
            .map(|k| k as f32 * std::f32::consts::TAU / 64.0)
            .filter(|&phi| walk.texel(tri, w1, w2, phi).land(3.0, 0.0) == Landing::Off)
            .count();
        // Offsets of 3 mm leave through x = 0 over an arc of 2 acos(1/3) = 141 degrees.
        assert!(
            (22..=28).contains(&off),
            "{off} of 64 directions off the surface"
        );
    }
}
