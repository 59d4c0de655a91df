//! A bounding-volume hierarchy over triangles (binned SAH), for ray casting on the CPU: the
//! ambient-occlusion ground truth and the sphere-tree builder's inside test. Its flat layout
//! with link words is the table the shaders traverse (glsl/common/bvh.glsl); over a skinned
//! mesh, [`BvhTopology`] keeps the rest pose's tree and [`refit`] refits its boxes per pose
//! (the CPU twin of the refit passes that SSS and the environment's traced visibility run).

use crate::error::{Error, Result};
use glam::Vec3;
use std::collections::HashMap;

#[derive(Clone, Copy, Debug)]
struct Node {
    min: Vec3,
    max: Vec3,
    /// Leaf: first triangle in `order`; inner: index of the left child (right = left + 1).
    first: u32,
    /// Leaf: triangle count (> 0); inner: 0.
    count: u32,
}

/// A BVH over a triangle list; triangles are referenced, not copied.
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle vertices in leaf order: (a, b - a, c - a).
    tris: Vec<[Vec3; 3]>,
}

const LEAF_SIZE: usize = 4;
const BINS: usize = 12;

fn grow(min: &mut Vec3, max: &mut Vec3, p: Vec3) {
    *min = min.min(p);
    *max = max.max(p);
}

fn area(min: Vec3, max: Vec3) -> f32 {
    let d = (max - min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

impl Bvh {
    /// Builds the hierarchy over `triangles` of `positions`.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Bvh {
        let prims: Vec<[Vec3; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| positions[i as usize]))
            .collect();
        let centroids: Vec<Vec3> = prims.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..prims.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * prims.len().max(1));
        nodes.push(Node {
            min: Vec3::ZERO,
            max: Vec3::ZERO,
            first: 0,
            count: prims.len() as u32,
        });
        let mut stack = vec![0usize];
        while let Some(ni) = stack.pop() {
            let (first, count) = (nodes[ni].first as usize, nodes[ni].count as usize);
            let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            let (mut cmin, mut cmax) = (min, max);
            for &t in &order[first..first + count] {
                for v in prims[t as usize] {
                    grow(&mut min, &mut max, v);
                }
                grow(&mut cmin, &mut cmax, centroids[t as usize]);
            }
            nodes[ni].min = min;
            nodes[ni].max = max;
            if count <= LEAF_SIZE {
                continue;
            }
            // Binned SAH over the widest centroid axis.
            let extent = cmax - cmin;
            let axis = if extent.x >= extent.y && extent.x >= extent.z {
                0
            } else if extent.y >= extent.z {
                1
            } else {
                2
            };
            if extent[axis] <= 0.0 {
                continue; // all centroids coincide: keep as a (large) leaf
            }
            let bin_of = |t: u32| {
                let c = centroids[t as usize][axis];
                (((c - cmin[axis]) / extent[axis] * BINS as f32) as usize).min(BINS - 1)
            };
            let mut bins = [(
                Vec3::splat(f32::INFINITY),
                Vec3::splat(f32::NEG_INFINITY),
                0usize,
            ); BINS];
            for &t in &order[first..first + count] {
                let b = &mut bins[bin_of(t)];
                for v in prims[t as usize] {
                    grow(&mut b.0, &mut b.1, v);
                }
                b.2 += 1;
            }
            let mut best = (f32::INFINITY, 0usize);
            for split in 1..BINS {
                let side = |r: std::ops::Range<usize>| {
                    bins[r].iter().fold(
                        (
                            Vec3::splat(f32::INFINITY),
                            Vec3::splat(f32::NEG_INFINITY),
                            0usize,
                        ),
                        |(a, b, n), bin| (a.min(bin.0), b.max(bin.1), n + bin.2),
                    )
                };
                let (l, r) = (side(0..split), side(split..BINS));
                if l.2 == 0 || r.2 == 0 {
                    continue;
                }
                let cost = area(l.0, l.1) * l.2 as f32 + area(r.0, r.1) * r.2 as f32;
                if cost < best.0 {
                    best = (cost, split);
                }
            }
            if best.1 == 0 || best.0 >= area(min, max) * count as f32 {
                if count <= 4 * LEAF_SIZE {
                    continue; // splitting does not pay
                }
                best.1 = BINS / 2;
            }
            let slice = &mut order[first..first + count];
            let mut left = 0;
            for i in 0..slice.len() {
                if bin_of(slice[i]) < best.1 {
                    slice.swap(i, left);
                    left += 1;
                }
            }
            if left == 0 || left == count {
                left = count / 2; // degenerate binning: split the range in half
            }
            let l = nodes.len();
            nodes.push(Node {
                min: Vec3::ZERO,
                max: Vec3::ZERO,
                first: first as u32,
                count: left as u32,
            });
            nodes.push(Node {
                min: Vec3::ZERO,
                max: Vec3::ZERO,
                first: (first + left) as u32,
                count: (count - left) as u32,
            });
            nodes[ni].first = l as u32;
            nodes[ni].count = 0;
            stack.push(l);
            stack.push(l + 1);
        }
        let tris = order
            .iter()
            .map(|&t| {
                let [a, b, c] = prims[t as usize];
                [a, b - a, c - a]
            })
            .collect();
        Bvh { nodes, tris }
    }

    /// Visits every triangle whose leaf box the ray segment [0, tmax] touches; `hit` gets the
    /// ray parameter of each intersection and returns true to stop.
    fn traverse(&self, o: Vec3, d: Vec3, tmax: f32, mut hit: impl FnMut(f32, usize) -> bool) {
        if self.tris.is_empty() {
            return;
        }
        let inv = d.recip();
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            let t0 = (node.min - o) * inv;
            let t1 = (node.max - o) * inv;
            let tnear = t0.min(t1).max_element().max(0.0);
            let tfar = t0.max(t1).min_element().min(tmax);
            if tnear > tfar {
                continue;
            }
            if node.count > 0 {
                let range = node.first as usize..(node.first + node.count) as usize;
                for (k, tri) in self.tris[range.clone()].iter().enumerate() {
                    if let Some(t) = intersect(o, d, tri)
                        && t <= tmax
                        && hit(t, range.start + k)
                    {
                        return;
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = node.first;
                stack[sp + 1] = node.first + 1;
                sp += 2;
            }
        }
    }

    /// Whether the ray hits any triangle at a parameter in (0, tmax].
    pub fn any_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let mut found = false;
        self.traverse(origin, dir, tmax, |_, _| {
            found = true;
            true
        });
        found
    }

    /// Parameters of every intersection along the ray (unsorted).
    pub fn all_hits(&self, origin: Vec3, dir: Vec3, out: &mut Vec<f32>) {
        out.clear();
        self.traverse(origin, dir, f32::INFINITY, |t, _| {
            out.push(t);
            false
        });
    }

    /// The hierarchy as flat arrays for a GPU traversal: per node two vec4s
    /// (min.xyz, first as bits), (max.xyz, count as bits) with the meaning of the CPU nodes
    /// (leaf: `count` > 0 triangles from `first`; inner: children `first`, `first + 1`), and
    /// per triangle three vec4s (a, b - a, c - a) in leaf order.
    pub fn flat(&self) -> (Vec<[f32; 8]>, Vec<[f32; 12]>) {
        let nodes = self
            .nodes
            .iter()
            .map(|n| {
                [
                    n.min.x,
                    n.min.y,
                    n.min.z,
                    f32::from_bits(n.first),
                    n.max.x,
                    n.max.y,
                    n.max.z,
                    f32::from_bits(n.count),
                ]
            })
            .collect();
        let tris = self
            .tris
            .iter()
            .map(|t| {
                [
                    t[0].x, t[0].y, t[0].z, 0.0, t[1].x, t[1].y, t[1].z, 0.0, t[2].x, t[2].y,
                    t[2].z, 0.0,
                ]
            })
            .collect();
        (nodes, tris)
    }

    /// The nearest hit along the ray in (0, tmax]: its parameter and the unit geometric
    /// normal (e1 x e2 of the triangle as stored, i.e. its winding) of the triangle hit.
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(f32, Vec3)> {
        let mut best: Option<(f32, usize)> = None;
        self.traverse(origin, dir, tmax, |t, k| {
            if best.is_none_or(|(b, _)| t < b) {
                best = Some((t, k));
            }
            false
        });
        best.map(|(t, k)| {
            (
                t,
                self.tris[k][1].cross(self.tris[k][2]).normalize_or_zero(),
            )
        })
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }
}

/// The low bits of a node's link word: its triangle count (0: an inner node).
pub const LINK_COUNT: u32 = 0xff;
/// The skip of the last node of a traversal: past the end (the root's skip).
pub const LINK_END: u32 = 0x00ff_ffff;

/// Per node of a flat BVH ([`Bvh::flat`]: an inner node's children at `first`, `first + 1`),
/// the word the shaders keep in place of its count: count | skip << 8, where skip is the
/// node a depth-first traversal visits next when it does not enter this one (its right
/// sibling, else its parent's skip; [`LINK_END`] for the root). The traversal is then a
/// loop without a stack: enter a node whose box the ray meets (its left child, or its
/// triangles and then its skip), else go to its skip. lavapipe runs a per-lane stack as
/// scattered loads and stores for every push and pop; the link costs a word already loaded.
pub fn link_words(nodes: &[[f32; 8]]) -> Result<Vec<u32>> {
    if nodes.len() as u64 >= LINK_END as u64 {
        return Err(Error::InvalidArgument(format!(
            "a BVH of {} nodes (the shaders' traversal holds fewer than {LINK_END})",
            nodes.len()
        )));
    }
    let mut skip = vec![LINK_END; nodes.len()];
    let mut seen = vec![false; nodes.len()];
    let mut todo = Vec::new();
    if !nodes.is_empty() {
        todo.push(0usize);
        seen[0] = true;
    }
    while let Some(i) = todo.pop() {
        let (first, count) = (nodes[i][3].to_bits(), nodes[i][7].to_bits());
        if count > LINK_COUNT {
            return Err(Error::InvalidArgument(format!(
                "BVH leaf {i} holds {count} triangles (at most {LINK_COUNT})"
            )));
        }
        if count > 0 {
            continue;
        }
        let (l, r) = (first as usize, first as usize + 1);
        if r >= nodes.len() || seen[l] || seen[r] {
            return Err(Error::InvalidArgument(format!(
                "BVH node {i} names children {l}, {r} (of {} nodes, each child once)",
                nodes.len()
            )));
        }
        seen[l] = true;
        seen[r] = true;
        skip[l] = r as u32;
        skip[r] = skip[i];
        todo.extend([l, r]);
    }
    Ok(nodes
        .iter()
        .zip(&skip)
        .map(|(n, &k)| (n[7].to_bits() & LINK_COUNT) | k << 8)
        .collect())
}

/// [`Bvh::flat`]'s nodes with [`link_words`] in place of the counts: the layout the
/// shaders traverse.
pub fn with_links(mut nodes: Vec<[f32; 8]>) -> Result<Vec<[f32; 8]>> {
    let links = link_words(&nodes)?;
    for (n, l) in nodes.iter_mut().zip(links) {
        n[7] = f32::from_bits(l);
    }
    Ok(nodes)
}

/// Möller-Trumbore; two-sided. Returns t > 0 of the hit.
#[inline]
fn intersect(o: Vec3, d: Vec3, tri: &[Vec3; 3]) -> Option<f32> {
    let [a, e1, e2] = *tri;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
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

/// The first texel of the triangles in the GPU table of glsl/common/bvh.glsl (every
/// pipeline's specialization constant `TRI_BASE`): after room for `nodes` nodes (2 texels
/// each), rounded up to whole rows of `row` texels (at least one row).
pub fn tri_base(nodes: usize, row: u32) -> u32 {
    (2 * nodes as u32).div_ceil(row).max(1) * row
}

/// The GPU table of glsl/common/bvh.glsl (texels of four 32-bit words, float bits): `nodes`
/// ([`with_links`]) 2 texels each from texel 0, then `tris` 3 texels each from texel
/// `tri_base` (room for one zeroed triangle at least: a node step reads the texel after its
/// two). One table rather than an image of each: a traversal step reads three texels at one
/// address, whichever kind it is (the shader's header says why).
pub fn table_texels(
    nodes: &[[f32; 8]],
    tris: &[[f32; 12]],
    tri_base: u32,
) -> Result<Vec<[f32; 4]>> {
    let base = tri_base as usize;
    if 2 * nodes.len() > base {
        return Err(Error::InvalidArgument(format!(
            "BVH table: {} nodes do not fit before the triangles at texel {base}",
            nodes.len()
        )));
    }
    let mut texels = vec![[0f32; 4]; base + 3 * tris.len().max(1)];
    for (k, n) in nodes.iter().enumerate() {
        texels[2 * k].copy_from_slice(&n[..4]);
        texels[2 * k + 1].copy_from_slice(&n[4..]);
    }
    for (k, t) in tris.iter().enumerate() {
        for r in 0..3 {
            texels[base + 3 * k + r].copy_from_slice(&t[4 * r..4 * r + 4]);
        }
    }
    Ok(texels)
}

/// Whether a ray from `o` along `d` hits a triangle of the flat BVH in (0, tmax]: the
/// shaders' stackless traversal (glsl/common/bvh.glsl) on the CPU, over nodes whose
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

#[cfg(test)]
mod tests {
    #[test]
    fn the_gpu_table_puts_triangles_after_the_node_rows() {
        let node = |k: f32| [k, k, k, f32::from_bits(7), k + 1.0, k + 1.0, k + 1.0, 0.0];
        let nodes = [node(1.0), node(2.0), node(3.0)];
        let tris = [[5.0; 12], [6.0; 12]];
        let base = tri_base(nodes.len(), 4);
        assert_eq!(base, 8, "6 node texels in rows of 4: two rows");
        let t = table_texels(&nodes, &tris, base).unwrap();
        assert_eq!(t.len(), 8 + 6);
        assert_eq!(
            table_texels(&nodes, &[], base).unwrap().len(),
            8 + 3,
            "one zeroed triangle"
        );
        assert_eq!(t[2], [2.0, 2.0, 2.0, f32::from_bits(7)]);
        assert_eq!(t[5], [3.0 + 1.0, 4.0, 4.0, 0.0]);
        assert_eq!(t[6], [0.0; 4], "the node rows' tail");
        assert_eq!(t[8 + 3], [6.0; 4]);
        assert!(
            table_texels(&nodes, &tris, 4).is_err(),
            "nodes past the base"
        );
        assert_eq!(tri_base(0, 4), 4, "at least one row");
    }

    use super::*;
    use crate::scene::texspace::{TexGeometry, plane_mesh};

    fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let p: Vec<Vec3> = (0..8)
            .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
            .collect();
        let quads = [
            [0, 1, 3, 2],
            [4, 6, 7, 5],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 5, 7, 3],
        ];
        let mut t = Vec::new();
        for q in quads {
            t.push([q[0], q[1], q[2]]);
            t.push([q[0], q[2], q[3]]);
        }
        (p, t)
    }

    #[test]
    fn rays_through_a_cube() {
        let (p, t) = cube();
        let bvh = Bvh::build(&p, &t);
        let o = Vec3::new(0.3, 0.4, -1.0);
        assert!(bvh.any_hit(o, Vec3::Z, 10.0));
        assert!(!bvh.any_hit(o, Vec3::Z, 0.5));
        assert!(!bvh.any_hit(o, -Vec3::Z, 10.0));
        let mut hits = Vec::new();
        bvh.all_hits(o, Vec3::Z, &mut hits);
        hits.sort_by(f32::total_cmp);
        assert_eq!(hits.len(), 2);
        assert!((hits[0] - 1.0).abs() < 1e-6 && (hits[1] - 2.0).abs() < 1e-6);
        // From inside, one crossing in every direction.
        bvh.all_hits(
            Vec3::splat(0.5),
            Vec3::new(0.3, -0.8, 0.52).normalize(),
            &mut hits,
        );
        assert_eq!(hits.len(), 1);
    }

    #[test]
    fn many_triangles_agree_with_brute_force() {
        // A grid of 2048 small triangles in random orientations.
        let mut rng = crate::geom::Rng::new(7);
        let mut p = Vec::new();
        let mut t = Vec::new();
        for i in 0..2048u32 {
            let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 10.0;
            for _ in 0..3 {
                p.push(c + Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 0.6);
            }
            t.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        let bvh = Bvh::build(&p, &t);
        let brute = Bvh {
            nodes: vec![Node {
                min: Vec3::splat(-1.0),
                max: Vec3::splat(12.0),
                first: 0,
                count: t.len() as u32,
            }],
            tris: t
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| p[i as usize]);
                    [a, b - a, c - a]
                })
                .collect(),
        };
        let (mut h1, mut h2) = (Vec::new(), Vec::new());
        for _ in 0..500 {
            let o = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 10.0;
            let d = crate::geom::uniform_sphere(rng.f32(), rng.f32());
            bvh.all_hits(o, d, &mut h1);
            brute.all_hits(o, d, &mut h2);
            assert_eq!(h1.len(), h2.len());
            assert_eq!(bvh.any_hit(o, d, 3.0), brute.any_hit(o, d, 3.0));
        }
    }

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
}
