//! The SSS kernel on a skinned mesh: what depends only on the UV layout, built once on the
//! CPU ([`Layout`]), and the CPU twins of what the GPU computes from the posed vertices each
//! frame (no Vulkan here).
//!
//! Once per mesh (the UV layout and the triangles do not change when it is skinned):
//! - the weld: each vertex reads the posed position of the first vertex at its rest position
//!   (vertices split along UV seams must stay bitwise together, as [`posed`] keeps them;
//!   skinned with their weights in another order they could differ in the last bit);
//! - per texel: its triangle, the barycentrics of its centre and its flag (covered, gutter;
//!   gutters repeat their source texel's);
//! - per triangle: its corners, its UV edges, and per edge the neighbour across it and the
//!   neighbour's corner off that edge (the surface walk's topology, [`super::walk`]);
//! - the BVH's topology: built over the rest pose (binned SAH, [`Bvh::build`]); its leaves
//!   keep their triangles and its inner nodes their children in every pose, and the boxes are
//!   refitted per frame, bottom-up, one level of the tree after the other ([`refit`]).
//!
//! Each frame (glsl/sss/pose_*.comp, bvh_*.comp): the vertex frames (mm), per triangle the
//! walk records and the face normal and texel area, per texel the position, normal and area,
//! the BVH's triangles and boxes.
//!
//! [`posed`]: crate::scene::texspace::posed

use super::walk::{self, NON_MANIFOLD, OPEN, SurfaceWalk};
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;
use crate::scene::texspace::{NO_TRIANGLE, TexGeometry};
use glam::{DVec2, Vec3};
use std::collections::HashMap;

/// Texels (uvec4) per triangle of the walk topology ([`Layout::walk_topology`]).
pub const TOPOLOGY_TEXELS: usize = 4;

/// What the per-frame geometry passes read, fixed by the UV layout and the triangles.
#[derive(Clone, Debug)]
pub struct Layout {
    /// Per vertex, the vertex whose posed position it takes (the first at its rest position).
    pub weld: Vec<u32>,
    /// Per texel: (triangle, w1 bits, w2 bits, flag bits) ([`TexGeometry::texel_tri`] and the
    /// flag of `pos.w`); zeros in empty texels.
    pub texel_source: Vec<[u32; 4]>,
    /// Per triangle, [`TOPOLOGY_TEXELS`] uvec4 ([`walk_topology`]); edge classes are
    /// [`walk::EDGE_SHARED`], [`walk::EDGE_OPEN`] or [`walk::EDGE_LOST`] (non-manifold).
    pub walk_topology: Vec<[u32; 4]>,
    /// The BVH's fixed topology ([`BvhTopology`]).
    pub bvh: BvhTopology,
}

/// A BVH whose topology is fixed and whose boxes are refitted per pose.
#[derive(Clone, Debug)]
pub struct BvhTopology {
    /// Per triangle slot of the flat BVH (leaf order): the mesh's vertex indices (v0, v1, v2,
    /// 0) of the triangle stored there.
    pub slots: Vec<[u32; 4]>,
    /// Leaves: (node, first slot, link word: slot count | skip << 8, [`link_words`]).
    pub leaves: Vec<[u32; 3]>,
    /// Inner nodes, deepest level first: (node, left child; the right child is left + 1,
    /// link word: skip << 8).
    pub inner: Vec<[u32; 3]>,
    /// Where each level starts in `inner` (levels + 1 entries, the last = inner.len()).
    pub level_starts: Vec<u32>,
    /// Nodes of the flat BVH.
    pub nodes: usize,
}

impl BvhTopology {
    /// The topology of [`Bvh::build`] over the rest pose `positions`, `triangles`.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Result<BvhTopology> {
        let (nodes, tris) = Bvh::build(positions, triangles).flat();
        // The flat BVH stores (a, b - a, c - a) per slot; the same arithmetic on each mesh
        // triangle finds the triangle of each slot (bitwise; identical triangles are
        // interchangeable).
        let key = |t: &[u32; 3]| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let (e1, e2) = (b - a, c - a);
            [a.x, a.y, a.z, e1.x, e1.y, e1.z, e2.x, e2.y, e2.z].map(f32::to_bits)
        };
        let mut by_key: HashMap<[u32; 9], Vec<u32>> = HashMap::new();
        for (t, tri) in triangles.iter().enumerate().rev() {
            by_key.entry(key(tri)).or_default().push(t as u32);
        }
        let mut slots = Vec::with_capacity(tris.len());
        for (s, r) in tris.iter().enumerate() {
            let k = [r[0], r[1], r[2], r[4], r[5], r[6], r[8], r[9], r[10]].map(f32::to_bits);
            let t = by_key.get_mut(&k).and_then(|v| v.pop()).ok_or_else(|| {
                Error::InvalidArgument(format!("BVH slot {s} matches no triangle of the mesh"))
            })?;
            let v = triangles[t as usize];
            slots.push([v[0], v[1], v[2], 0]);
        }
        let links = link_words(&nodes)?;
        // Depth of every node (children follow their parent in the flat order).
        let mut depth = vec![0u32; nodes.len()];
        let mut leaves = Vec::new();
        let mut inner_at: Vec<(u32, u32, u32)> = Vec::new();
        for (i, n) in nodes.iter().enumerate() {
            let (first, count) = (n[3].to_bits(), n[7].to_bits());
            if count > 0 {
                leaves.push([i as u32, first, links[i]]);
            } else {
                let d = depth[i] + 1;
                for c in [first, first + 1] {
                    *depth.get_mut(c as usize).ok_or_else(|| {
                        Error::InvalidArgument(format!("BVH node {i} names child {c}"))
                    })? = d;
                }
                inner_at.push((depth[i], i as u32, first));
            }
        }
        inner_at.sort_by_key(|&(d, i, _)| (std::cmp::Reverse(d), i));
        let mut level_starts = Vec::new();
        let mut last = None;
        for (k, &(d, _, _)) in inner_at.iter().enumerate() {
            if last != Some(d) {
                level_starts.push(k as u32);
                last = Some(d);
            }
        }
        level_starts.push(inner_at.len() as u32);
        Ok(BvhTopology {
            slots,
            leaves,
            inner: inner_at
                .iter()
                .map(|&(_, i, c)| [i, c, links[i as usize]])
                .collect(),
            level_starts,
            nodes: nodes.len(),
        })
    }

    /// Levels of inner nodes.
    pub fn levels(&self) -> usize {
        self.level_starts.len() - 1
    }

    /// The buffer the refit shaders read (glsl/sss/bvh_leaves.comp, bvh_refit.comp): leaves,
    /// inner-node levels, then per leaf (node, first, link word), then per inner node
    /// (node, left child, link word), then the level starts.
    pub fn gpu(&self) -> Vec<u32> {
        let mut out = vec![
            self.leaves.len() as u32,
            self.levels() as u32,
            self.inner.len() as u32,
            0,
        ];
        out.extend(self.leaves.iter().flatten());
        out.extend(self.inner.iter().flatten());
        out.extend(&self.level_starts);
        out
    }
}

/// The BVH over `positions` (mm) refitted on the CPU, as the refit passes compute it (the
/// CPU twin): triangles (a, b - a, c - a) per slot and per node (lo, first; hi, link word) as
/// [`Bvh::flat`] lays them out, with [`link_words`] in place of the counts.
pub fn refit(top: &BvhTopology, positions: &[Vec3]) -> (Vec<[f32; 8]>, Vec<[f32; 12]>) {
    let tris: Vec<[f32; 12]> = top
        .slots
        .iter()
        .map(|s| {
            let [a, b, c] = [s[0], s[1], s[2]].map(|i| positions[i as usize]);
            let (e1, e2) = (b - a, c - a);
            [
                a.x, a.y, a.z, 0.0, e1.x, e1.y, e1.z, 0.0, e2.x, e2.y, e2.z, 0.0,
            ]
        })
        .collect();
    let mut nodes = vec![[0f32; 8]; top.nodes];
    for &[node, first, link] in &top.leaves {
        let count = link & LINK_COUNT;
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for s in &top.slots[first as usize..(first + count) as usize] {
            for &v in &s[..3] {
                lo = lo.min(positions[v as usize]);
                hi = hi.max(positions[v as usize]);
            }
        }
        nodes[node as usize] = [
            lo.x,
            lo.y,
            lo.z,
            f32::from_bits(first),
            hi.x,
            hi.y,
            hi.z,
            f32::from_bits(link),
        ];
    }
    for &[node, left, link] in &top.inner {
        let (l, r) = (nodes[left as usize], nodes[left as usize + 1]);
        nodes[node as usize] = [
            l[0].min(r[0]),
            l[1].min(r[1]),
            l[2].min(r[2]),
            f32::from_bits(left),
            l[4].max(r[4]),
            l[5].max(r[5]),
            l[6].max(r[6]),
            f32::from_bits(link),
        ];
    }
    (nodes, tris)
}

// The link words moved to `crate::geom::bvh` (SRBF's shadow rays traverse the same table);
// re-exported here for the SSS code and tests that name them.
pub use crate::geom::bvh::{LINK_COUNT, LINK_END, link_words, with_links};

/// The SAH-like quality figure of a flat BVH: the sum of its inner nodes' box areas over the
/// root's plus the leaves' areas times their triangle counts over the root's (the expected
/// box and triangle tests of a ray through the root's box, up to constants). A refitted tree
/// grows it as limbs move; compare with a tree built for the pose.
pub fn sah_cost(nodes: &[[f32; 8]]) -> f64 {
    let area = |n: &[f32; 8]| {
        let d = [n[4] - n[0], n[5] - n[1], n[6] - n[2]].map(|x| x.max(0.0) as f64);
        d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    };
    let Some(root) = nodes.first() else {
        return 0.0;
    };
    let ra = area(root).max(1e-30);
    nodes
        .iter()
        .map(|n| {
            let count = n[7].to_bits() & LINK_COUNT;
            if count > 0 {
                area(n) * count as f64
            } else {
                area(n)
            }
        })
        .sum::<f64>()
        / ra
}

/// Whether a ray from `o` along `d` hits a triangle of the flat BVH in (0, tmax]: the
/// shaders' stackless traversal (glsl/sss/vertex_light.comp) on the CPU, over nodes whose
/// counts are [`link_words`], to check a refitted BVH against one built for the pose.
pub fn flat_any_hit(nodes: &[[f32; 8]], tris: &[[f32; 12]], o: Vec3, d: Vec3, tmax: f32) -> bool {
    if tris.is_empty() || nodes.is_empty() {
        return false;
    }
    let inv = d.recip();
    let mut i = 0u32;
    // Every step moves forward in the depth-first order, so the walk ends; the bound only
    // guards a malformed table.
    for _ in 0..2 * nodes.len() + 1 {
        let Some(n) = nodes.get(i as usize) else {
            return false;
        };
        let (lo, hi) = (Vec3::new(n[0], n[1], n[2]), Vec3::new(n[4], n[5], n[6]));
        let t0 = (lo - o) * inv;
        let t1 = (hi - o) * inv;
        let tnear = t0.min(t1).max_element().max(0.0);
        let tfar = t0.max(t1).min_element().min(tmax);
        let (first, link) = (n[3].to_bits(), n[7].to_bits());
        let (count, skip) = (link & LINK_COUNT, link >> 8);
        if tnear > tfar {
            i = skip;
            continue;
        }
        if count == 0 {
            i = first;
            continue;
        }
        for t in &tris[first as usize..(first + count) as usize] {
            let a = Vec3::new(t[0], t[1], t[2]);
            let e1 = Vec3::new(t[4], t[5], t[6]);
            let e2 = Vec3::new(t[8], t[9], t[10]);
            let p = d.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-12 {
                continue;
            }
            let inv_det = 1.0 / det;
            let s = o - a;
            let u = s.dot(p) * inv_det;
            if !(0.0..=1.0).contains(&u) {
                continue;
            }
            let q = s.cross(e1);
            let v = d.dot(q) * inv_det;
            if v < 0.0 || u + v > 1.0 {
                continue;
            }
            let th = e2.dot(q) * inv_det;
            if th > 0.0 && th <= tmax {
                return true;
            }
        }
        i = skip;
    }
    false
}

/// The first vertex at each vertex's position (bitwise; -0.0 and 0.0 are one point), as
/// [`crate::scene::texspace::posed`] welds.
pub fn weld_first(positions: &[Vec3]) -> Vec<u32> {
    let mut first: HashMap<[u32; 3], u32> = HashMap::new();
    positions
        .iter()
        .enumerate()
        .map(|(v, p)| {
            let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
            *first.entry(key).or_insert(v as u32)
        })
        .collect()
}

impl Layout {
    /// The layout of `geo` (the rest pose, mm) for a mesh whose rest positions in model
    /// units are `rest` (the weld is taken there, as [`crate::scene::texspace::posed`] does).
    pub fn new(geo: &TexGeometry, rest: &[Vec3]) -> Result<Layout> {
        super::pack::check_geometry(geo)?;
        if rest.len() != geo.positions.len() {
            return Err(Error::InvalidArgument(format!(
                "{} rest positions for a geometry of {} vertices",
                rest.len(),
                geo.positions.len()
            )));
        }
        let texel_source = geo
            .texel_tri
            .iter()
            .zip(&geo.pos)
            .map(|(t, p)| {
                if p[3] == 0.0 || t[0] == NO_TRIANGLE {
                    [0; 4]
                } else {
                    [t[0], t[1], t[2], p[3].to_bits()]
                }
            })
            .collect();
        Ok(Layout {
            weld: weld_first(rest),
            texel_source,
            walk_topology: walk_topology(geo),
            bvh: BvhTopology::build(&geo.positions, &geo.triangles)?,
        })
    }
}

/// The walk's topology per triangle, [`TOPOLOGY_TEXELS`] uvec4 (floats as bits):
/// (v0, v1, v2, edge classes: 2 bits per edge), (the neighbours across edges 0, 1, 2, their
/// corners off the shared edge: 2 bits per edge), (uv0, uv1 - uv0), (uv2 - uv0, det, 0):
/// the UVs in the walk's texel units as [`SurfaceWalk::records`] has them, and det the
/// signed UV area (uv1 - uv0) x (uv2 - uv0) N^2 (f64, rounded once), which the texel area
/// |dP/du x dP/dv| / N^2 = |e1 x e2| / |det| divides by.
pub fn walk_topology(geo: &TexGeometry) -> Vec<[u32; 4]> {
    let w = SurfaceWalk::build(geo);
    let nf = geo.size as f64;
    let mut out = Vec::with_capacity(w.tris.len() * TOPOLOGY_TEXELS);
    for (t, wt) in w.tris.iter().enumerate() {
        let v = geo.triangles[t];
        let class = (0..3).fold(0u32, |acc, k| {
            let c = match wt.nbr[k] {
                OPEN => walk::EDGE_OPEN,
                NON_MANIFOLD => walk::EDGE_LOST,
                _ => walk::EDGE_SHARED,
            };
            acc | c << (2 * k)
        });
        let nbr = wt.nbr;
        let mut off = 0u32;
        for (k, &nb) in nbr.iter().enumerate() {
            if nb >= NON_MANIFOLD {
                continue;
            }
            // The neighbour's corner farthest from both ends of the shared edge (as
            // walk::unfold_map picks it).
            let pb = w.tris[nb as usize].p;
            let (ea, eb) = (wt.p[(k + 1) % 3], wt.p[(k + 2) % 3]);
            let j = (0..3)
                .max_by(|&x, &y| {
                    let d = |i: usize| {
                        (pb[i] - ea)
                            .length_squared()
                            .min((pb[i] - eb).length_squared())
                    };
                    d(x).total_cmp(&d(y))
                })
                .unwrap_or(0);
            off |= (j as u32) << (2 * k);
        }
        let b = f32::to_bits;
        let du1 = wt.uv[1] - wt.uv[0];
        let du2 = wt.uv[2] - wt.uv[0];
        let c = geo.corner_uvs[t].map(|u| u.as_dvec2() * nf);
        let (d1, d2): (DVec2, DVec2) = (c[1] - c[0], c[2] - c[0]);
        let det = d1.x * d2.y - d2.x * d1.y;
        out.push([v[0], v[1], v[2], class]);
        out.push([nbr[0], nbr[1], nbr[2], off]);
        out.push([b(wt.uv[0].x), b(wt.uv[0].y), b(du1.x), b(du1.y)]);
        out.push([b(du2.x), b(du2.y), b(det as f32), 0]);
    }
    out
}

/// Writes each triangle's skin region into its topology (texel 3, w, 0 from
/// [`walk_topology`]): glsl/sss/pose_triangles.comp copies it into the walk record each frame,
/// where the diffusion reads it (`pack::region_records` for uploaded geometry).
pub fn topology_regions(topology: &mut [[u32; 4]], regions: &super::Regions) {
    for (t, topo) in topology.chunks_exact_mut(TOPOLOGY_TEXELS).enumerate() {
        topo[3][3] = regions.of_triangle(t) as u32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::texspace::plane_mesh;

    #[test]
    fn a_refit_of_the_rest_pose_is_the_built_bvh() {
        let m = plane_mesh(30.0, 20.0, 9).unwrap();
        let geo = TexGeometry::build(&m, 64, 1.0).unwrap();
        let top = BvhTopology::build(&geo.positions, &geo.triangles).unwrap();
        let built = Bvh::build(&geo.positions, &geo.triangles).flat();
        let refitted = refit(&top, &geo.positions);
        assert_eq!(built.1, refitted.1);
        for (a, b) in with_links(built.0).unwrap().iter().zip(&refitted.0) {
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        }
        assert!(top.levels() >= 3, "{} levels", top.levels());
        assert_eq!(top.leaves.len() + top.inner.len(), top.nodes);
        // The header of the GPU buffer.
        let g = top.gpu();
        assert_eq!(
            g[..3],
            [
                top.leaves.len() as u32,
                top.levels() as u32,
                top.inner.len() as u32
            ]
        );
    }

    #[test]
    fn a_refitted_bvh_casts_the_shadows_of_a_built_one() {
        // A plane bent into a fold: the refit of the flat topology against a BVH built for
        // the bent pose, over rays from above.
        let m = plane_mesh(30.0, 30.0, 12).unwrap();
        let geo = TexGeometry::build(&m, 64, 1.0).unwrap();
        let top = BvhTopology::build(&geo.positions, &geo.triangles).unwrap();
        let bent: Vec<Vec3> = geo
            .positions
            .iter()
            .map(|p| Vec3::new(p.x, p.y, 8.0 * (p.x * 0.2).sin() + 0.1 * p.y))
            .collect();
        let (nodes, tris) = refit(&top, &bent);
        let fresh = Bvh::build(&bent, &geo.triangles);
        let mut differ = 0;
        let n = 4000;
        for i in 0..n {
            let x = (i % 63) as f32 / 62.0 * 34.0 - 17.0;
            let y = (i / 63) as f32 / 64.0 * 34.0 - 17.0;
            let o = Vec3::new(x, y, 20.0);
            let d = Vec3::new(0.3 * ((i % 7) as f32 - 3.0) / 3.0, 0.2, -1.0).normalize();
            differ +=
                (flat_any_hit(&nodes, &tris, o, d, 100.0) != fresh.any_hit(o, d, 100.0)) as usize;
        }
        // Same triangles, same intersection arithmetic: only the order of the tests differs,
        // which an any-hit answer does not depend on.
        assert_eq!(differ, 0);
        assert!(sah_cost(&nodes) >= sah_cost(&fresh.flat().0) * 0.5);
    }

    /// The per-frame geometry shaders read with the layouts the host writes.
    #[test]
    fn the_geometry_shaders_agree_with_the_host() {
        use crate::kernels::sss::pack::{BVH_ROW, TILE_ROW};
        let shaders = [
            (
                "pose_texels",
                include_str!("../../../glsl/sss/pose_texels.comp"),
            ),
            (
                "pose_triangles",
                include_str!("../../../glsl/sss/pose_triangles.comp"),
            ),
            (
                "bvh_leaves",
                include_str!("../../../glsl/sss/bvh_leaves.comp"),
            ),
            (
                "bvh_refit",
                include_str!("../../../glsl/sss/bvh_refit.comp"),
            ),
        ];
        let consts = [
            ("BVH_ROW", BVH_ROW),
            ("WALK_ROW", BVH_ROW),
            ("TILE_ROW", TILE_ROW),
            ("WALK_RECORD", walk::RECORD_TEXELS as u32),
            ("TOPOLOGY", TOPOLOGY_TEXELS as u32),
            ("EDGE_SHARED", walk::EDGE_SHARED),
            ("EDGE_LOST", walk::EDGE_LOST),
        ];
        for (path, src) in shaders {
            for (name, value) in consts {
                let decl = format!("const uint {name} =");
                if src.contains(&decl) {
                    let line = format!("const uint {name} = {value}u;");
                    assert!(src.contains(&line), "glsl/sss/{path}.comp lacks `{line}`");
                }
            }
        }
        assert!(shaders[1].1.contains("const uint TOPOLOGY = 4u;"));
    }

    #[test]
    fn the_weld_names_the_first_vertex_at_a_position() {
        let p = [
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(-0.0, 0.0, 0.0),
        ];
        assert_eq!(weld_first(&p), vec![0, 1, 0, 1]);
    }
}
