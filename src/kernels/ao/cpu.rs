//! The same method on the CPU (rayon): skinning, the cut through the tree, per-sphere
//! occlusion and blending, step for step as `glsl/ao/*.comp` do it. It is the reference the
//! GPU is tested against (tight bound) and the CPU baseline of `bench ao`.

use super::fixed::{FixedCut, sphere_view};
use super::formula::{
    OcclusionTable, mask_directions, nearest_cell, nearest_direction_table, overlap_table,
    pair_overlap, sphere_occlusion,
};
use super::{AoParams, Blend, Occlusion, Prepared, Refine};
use crate::geom::orthonormal_basis;
use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;

/// Posed mesh and spheres.
#[derive(Clone, Debug)]
pub struct Posed {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// (centre, radius); radius < 0: unused.
    pub spheres: Vec<Vec4>,
    /// Per node: the farthest reach of its leaf spheres from its centre (leaves: radius).
    pub extents: Vec<f32>,
}

fn blend(matrices: &[Mat4], packed: [u32; 2], w: [f32; 4]) -> Mat4 {
    let j = [
        packed[0] & 0xffff,
        packed[0] >> 16,
        packed[1] & 0xffff,
        packed[1] >> 16,
    ];
    let mut m = Mat4::ZERO;
    for k in 0..4 {
        if w[k] != 0.0 {
            m += matrices[j[k] as usize] * w[k];
        }
    }
    m
}

/// Linear-blend skinning of vertices and sphere centres.
pub fn skin(prep: &Prepared, matrices: &[Mat4]) -> Posed {
    let (positions, normals): (Vec<Vec3>, Vec<Vec3>) = (0..prep.positions.len())
        .into_par_iter()
        .map(|i| {
            let m = blend(matrices, prep.vertex_joints[i], prep.vertex_weights[i]);
            let p = m.transform_point3(Vec4::from_array(prep.positions[i]).truncate());
            let rest_n = Vec4::from_array(prep.normals[i]).truncate();
            let n = m.transform_vector3(rest_n);
            let len = n.length();
            (p, if len > 0.0 { n / len } else { rest_n })
        })
        .unzip();
    let skin_centre = |s: usize| {
        let rest = Vec4::from_array(prep.spheres[s]);
        blend(matrices, prep.sphere_joints[s], prep.sphere_weights[s])
            .transform_point3(rest.truncate())
    };
    let (b, first_leaf) = (prep.shape.branch as usize, prep.shape.first_leaf as usize);
    let (spheres, extents): (Vec<Vec4>, Vec<f32>) = (0..prep.spheres.len())
        .map(|s| {
            let rest = Vec4::from_array(prep.spheres[s]);
            if rest.w < 0.0 {
                return (rest, rest.w);
            }
            let c = skin_centre(s);
            let mut extent = rest.w;
            if s < first_leaf {
                // Leaf descendants of s, as the shader finds them.
                let (mut first, mut count) = (s, 1usize);
                while first < first_leaf {
                    first = first * b + 1;
                    count *= b;
                }
                for l in first..first + count {
                    let leaf = Vec4::from_array(prep.spheres[l]);
                    if leaf.w >= 0.0 {
                        extent = extent.max(skin_centre(l).distance(c) + leaf.w);
                    }
                }
            }
            (c.extend(rest.w), extent)
        })
        .unzip();
    Posed {
        positions,
        normals,
        spheres,
        extents,
    }
}

/// Tree shape needed by the traversal.
#[derive(Clone, Copy, Debug)]
pub struct TreeShape {
    pub node_count: u32,
    pub branch: u32,
    pub first_leaf: u32,
}

impl TreeShape {
    /// Levels below the root: the depth of `first_leaf` in the implicit `branch`-ary tree
    /// (3 for 8/64/512).
    pub fn levels(&self) -> u32 {
        let (mut first, mut levels) = (0u64, 0u32);
        while first < u64::from(self.first_leaf) && levels <= MAX_DEPTH as u32 {
            first = first * u64::from(self.branch) + 1;
            levels += 1;
        }
        levels
    }
}

/// Without `clamp_inside`, a sphere's radius grows from 0 to its own as the receiver's
/// distance from its centre goes from 1 to 1 + INSIDE_FADE radii (no jump when it starts or
/// stops holding the receiver).
pub const INSIDE_FADE: f32 = 0.25;

/// Deepest tree the walk handles (levels below the root); `Prepared::check` refuses deeper.
pub const MAX_DEPTH: usize = 8;

/// How far a node is refined, in [0, 1]: 0 = the node itself, 1 = its children. A node is
/// fully refined when size >= tau * d (the published test) and starts to blend into its
/// children `band` (as a fraction of that distance) farther out, so the cut changes
/// continuously as a receiver moves: alpha = clamp((1 + band - tau * d / size) / band, 0, 1).
pub fn refinement(size: f32, d: f32, tau: f32, band: f32) -> f32 {
    if size <= 0.0 {
        return 0.0;
    }
    let t = tau * d / size;
    if band > 0.0 {
        ((1.0 + band - t) / band).clamp(0.0, 1.0)
    } else if t < 1.0 {
        1.0
    } else {
        0.0
    }
}

/// Walks the cut for receiver `p`: calls `contribute(node, sphere, weight)` for every
/// contributing node (in the shader's order) and returns the number of nodes tested.
///
/// A node that is partly refined (0 < alpha < 1, see [`refinement`]) is replaced by its used
/// children, each morphed from the node's (effective) sphere towards its own by alpha and
/// weighted by `mix(1 / used children, 1, alpha)`: at alpha = 0 the children coincide with
/// the node and together weigh what it weighs, so every blend mode gives the node's own
/// occlusion, and at alpha = 1 they are themselves. A child's alpha never exceeds its
/// parent's, so a whole subtree folds back continuously. No node counts together with an
/// ancestor or a descendant.
pub fn walk_cut(
    p: Vec3,
    spheres: &[Vec4],
    extents: &[f32],
    shape: TreeShape,
    params: &AoParams,
    mut contribute: impl FnMut(u32, Vec4, f32),
) -> u32 {
    let b = shape.branch;
    let mut tested = 0;
    // Per depth (1 = the root's children): the parent's effective sphere, its weight, its
    // alpha and the weight share of one of its children at alpha = 0.
    let mut parent = [Vec4::ZERO; MAX_DEPTH + 1];
    let mut weight = [1.0f32; MAX_DEPTH + 1];
    let mut alpha = [1.0f32; MAX_DEPTH + 1];
    let mut share = [1.0f32; MAX_DEPTH + 1];
    let mut depth = 1usize;
    let mut node = 1u32;
    while node != 0 && node < shape.node_count {
        let s = spheres[node as usize];
        let mut descend = false;
        if s.w >= 0.0 {
            tested += 1;
            let a_p = alpha[depth];
            let (eff, w) = if a_p >= 1.0 {
                (s, weight[depth])
            } else {
                (
                    parent[depth] + (s - parent[depth]) * a_p,
                    weight[depth] * (share[depth] + (1.0 - share[depth]) * a_p),
                )
            };
            let leaf = node >= shape.first_leaf;
            let mut a = 0.0;
            if !leaf {
                let d = (s.truncate() - p).length();
                let size = match params.refine {
                    Refine::Radius => s.w,
                    Refine::Extent => extents[node as usize],
                };
                a = refinement(size, d, params.tau, params.band).min(a_p);
            }
            if a > 0.0 {
                descend = true;
                let first = node * b + 1;
                let used = (first..first + b)
                    .filter(|&c| spheres[c as usize].w >= 0.0)
                    .count()
                    .max(1);
                depth += 1;
                parent[depth] = eff;
                weight[depth] = w;
                alpha[depth] = a;
                share[depth] = 1.0 / used as f32;
            } else {
                contribute(node, eff, w);
            }
        }
        if descend {
            node = node * b + 1;
        } else {
            while node != 0 && (node - 1) % b == b - 1 {
                node = (node - 1) / b;
                depth -= 1;
            }
            if node != 0 {
                node += 1;
            }
        }
    }
    tested
}

/// Result for one vertex.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VertexAo {
    /// Ambient visibility in [0, 1] (1 = unoccluded).
    pub visibility: f32,
    pub tested: u32,
    pub used: u32,
}

/// Evaluator holding the table and direction set.
pub struct CpuAo {
    pub table: OcclusionTable,
    dirs: Vec<Vec3>,
    /// [`nearest_direction_table`].
    nearest: Vec<u8>,
}

impl CpuAo {
    pub fn new(table: OcclusionTable) -> CpuAo {
        CpuAo {
            table,
            dirs: mask_directions()
                .iter()
                .map(|d| Vec3::new(d[0], d[1], d[2]))
                .collect(),
            nearest: nearest_direction_table(),
        }
    }

    /// Visibility of one receiver, as the shader computes it.
    pub fn vertex(
        &self,
        p: Vec3,
        n: Vec3,
        posed: &Posed,
        shape: TreeShape,
        params: &AoParams,
    ) -> VertexAo {
        let spheres = &posed.spheres;
        let (t, b) = orthonormal_basis(n);
        let mut product = 1.0f32;
        let mut sum_all = 0.0f32;
        let mut sum_masked = 0.0f32;
        let mut uni = [0u32; 4];
        // Caps too small to hold a direction: the directions they took, and the occlusion
        // of those hidden behind others (left out of the mask blend).
        let mut small = [0u32; 4];
        let mut hidden = 0.0f32;
        let mut used = 0;
        let mut count_sum = 0.0f32;
        let tested = walk_cut(p, spheres, &posed.extents, shape, params, |_, s, w| {
            let dv = s.truncate() - p;
            let d = dv.length();
            if !(d > s.w || params.clamp_inside) {
                return;
            }
            let mut h = d / s.w;
            // Skipping a sphere the moment it holds the receiver would pop: it shrinks to
            // nothing over the first INSIDE_FADE radii outside it instead.
            if !params.clamp_inside && h < 1.0 + INSIDE_FADE {
                h /= ((h - 1.0) / INSIDE_FADE).max(1e-6);
            }
            let cos_t = if d > 0.0 { n.dot(dv) / d } else { 1.0 };
            let occ = match params.occlusion {
                Occlusion::Exact => sphere_occlusion(cos_t, h),
                Occlusion::Table => self.table.lookup(cos_t, h),
            };
            used += 1;
            product *= if w >= 1.0 {
                1.0 - occ
            } else {
                (1.0 - occ).powf(w)
            };
            sum_all += w * occ;
            if params.blend == Blend::Mask && occ > 0.0 {
                let wd = if d > 0.0 { dv / d } else { n };
                let wl = Vec3::new(wd.dot(t), wd.dot(b), wd.dot(n));
                let cos_a = (1.0 - 1.0 / (h * h).max(1.0)).max(0.0).sqrt();
                let mut m = [0u32; 4];
                for (k, dir) in self.dirs.iter().enumerate() {
                    if dir.dot(wl) >= cos_a {
                        m[k >> 5] |= 1 << (k & 31);
                    }
                }
                let c: u32 = m.iter().map(|x| x.count_ones()).sum();
                if c > 0 {
                    sum_masked += w * occ;
                    count_sum += w * c as f32;
                    for k in 0..4 {
                        uni[k] |= m[k];
                    }
                } else {
                    // A cap between the directions: hidden when its nearest direction (looked
                    // up by its centre, nearest_direction_table) is already covered (by the union so far or an earlier such cap), else it
                    // counts as it is and covers that direction for the next.
                    let k = self.nearest[nearest_cell(wl.to_array())] as usize;
                    let (word, bit) = (k >> 5, 1u32 << (k & 31));
                    if (uni[word] | small[word]) & bit == 0 {
                        small[word] |= bit;
                    } else {
                        hidden += w * occ;
                    }
                }
            }
        });
        let occlusion = match params.blend {
            Blend::Product => 1.0 - product,
            Blend::Sum => sum_all,
            Blend::Mask => {
                let u: u32 = uni.iter().map(|x| x.count_ones()).sum();
                let scale = if count_sum > 0.0 {
                    u as f32 / count_sum
                } else {
                    1.0
                };
                (sum_all - sum_masked - hidden) + sum_masked * scale
            }
        };
        VertexAo {
            visibility: (1.0 - occlusion).clamp(0.0, 1.0),
            tested,
            used,
        }
    }

    /// Visibility of vertex `v` (at `p`, normal `n`) under the published variant: the nodes
    /// of its fixed list at their posed centres, each adding its occlusion less its overlap
    /// with the earlier caps of the list, as `glsl/ao/fixed.comp` does it. Pairwise overlaps
    /// are F * min(I_i, I_j) (F from the 3D table, [`super::formula::OverlapTable`]); a cap's
    /// overlap with the union of the earlier ones lies between the largest of them and their
    /// sum (capped at I_i), and the midpoint is taken. On Testwuson and BCN_Epileptic that
    /// halved the gap to the exact union of the list's spheres against the largest alone
    /// (0.021-0.042 -> 0.014-0.026 mean over 3 frames each; the sum alone 0.015-0.029).
    pub fn fixed_vertex(
        &self,
        v: usize,
        p: Vec3,
        n: Vec3,
        posed: &Posed,
        fixed: &FixedCut,
        params: &AoParams,
    ) -> VertexAo {
        let overlap = overlap_table();
        // The caps counted so far: direction, cos and sin of the half-angle, occlusion.
        let mut caps = [(Vec3::ZERO, 0.0f32, 0.0f32, 0.0f32); super::fixed::FIXED_SLOTS as usize];
        let mut count = 0usize;
        let (mut total, mut tested, mut used) = (0.0f32, 0u32, 0u32);
        for node in fixed.list(v) {
            tested += 1;
            let s = posed.spheres[node as usize];
            let Some((h, cos_t, wd)) = sphere_view(p, n, s, params.clamp_inside) else {
                continue;
            };
            let occ = match params.occlusion {
                Occlusion::Exact => sphere_occlusion(cos_t, h),
                Occlusion::Table => self.table.lookup(cos_t, h),
            };
            used += 1;
            if occ <= 0.0 {
                continue;
            }
            let cos_a = (1.0 - 1.0 / (h * h).max(1.0)).max(0.0).sqrt();
            let sin_a = 1.0 / h.max(1.0);
            // The cap's overlap with the union of the earlier ones lies between the largest
            // pairwise overlap and their sum (capped at its occlusion): take the midpoint.
            let (mut largest, mut sum) = (0.0f32, 0.0f32);
            for &(wj, cos_aj, sin_aj, occ_j) in &caps[..count] {
                let cos_g = wd.dot(wj);
                let o = pair_overlap(overlap, occ, cos_a, sin_a, occ_j, cos_aj, sin_aj, cos_g);
                largest = largest.max(o);
                sum += o;
            }
            let over = 0.5 * (largest + sum.min(occ));
            total += occ - over;
            caps[count] = (wd, cos_a, sin_a, occ);
            count += 1;
        }
        VertexAo {
            visibility: (1.0 - total).clamp(0.0, 1.0),
            tested,
            used,
        }
    }

    /// [`CpuAo::fixed_vertex`] for every vertex of a posed mesh (rayon), with the static
    /// correction applied when `params.correct` is set and `correction` is given.
    pub fn fixed_frame(
        &self,
        posed: &Posed,
        fixed: &FixedCut,
        params: &AoParams,
        correction: Option<&[f32]>,
    ) -> Vec<VertexAo> {
        corrected_frame(posed, params, correction, |i, p, n| {
            self.fixed_vertex(i, p, n, posed, fixed, params)
        })
    }

    /// Visibility of every vertex of a posed mesh (rayon) under the adaptive cut
    /// (`params.cut` is not read: the fixed cut is [`CpuAo::fixed_frame`]), with the static
    /// correction factors applied when `params.correct` is set and `correction` is given.
    pub fn frame(
        &self,
        posed: &Posed,
        shape: TreeShape,
        params: &AoParams,
        correction: Option<&[f32]>,
    ) -> Vec<VertexAo> {
        corrected_frame(posed, params, correction, |_, p, n| {
            self.vertex(p, n, posed, shape, params)
        })
    }
}

/// `vertex(i, position, normal)` for every vertex of a posed mesh (rayon), times the static
/// correction factor (capped at 1) when `params.correct` is set and `correction` is given.
fn corrected_frame(
    posed: &Posed,
    params: &AoParams,
    correction: Option<&[f32]>,
    vertex: impl Fn(usize, Vec3, Vec3) -> VertexAo + Sync,
) -> Vec<VertexAo> {
    posed
        .positions
        .par_iter()
        .zip(&posed.normals)
        .enumerate()
        .map(|(i, (&p, &n))| {
            let mut v = vertex(i, p, n);
            if params.correct
                && let Some(c) = correction
            {
                v.visibility = (v.visibility * c[i]).min(1.0);
            }
            v
        })
        .collect()
}

/// Fast tests of the cut and the blend on hand-made trees (milliseconds, so a mutation run
/// over `refinement`, `walk_cut` and `CpuAo::vertex` can use the library's tests alone). The
/// whole-character tests are in tests/ao.rs.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-5 * (1.0 + a.abs().max(b.abs()))
    }

    fn params(tau: f32, band: f32, refine: Refine) -> AoParams {
        AoParams {
            tau,
            band,
            refine,
            ..AoParams::default()
        }
    }

    /// Planted bugs this catches: `size <= 0` flipped, `tau * d` as `tau + d`, a wrong sign
    /// in `1 + band - t`, the hard cut's `t < 1` as `<=` or `>`.
    #[test]
    fn refinement_is_its_formula_and_the_hard_cut_at_band_zero() {
        assert_eq!(refinement(0.0, 1.0, 0.5, 0.5), 0.0);
        assert_eq!(refinement(-1.0, 0.1, 0.5, 0.0), 0.0);
        // Hard cut: refined exactly when size > tau * d.
        assert_eq!(refinement(1.0, 1.0, 0.5, 0.0), 1.0);
        assert_eq!(
            refinement(1.0, 2.0, 0.5, 0.0),
            0.0,
            "size == tau * d is not refined"
        );
        assert_eq!(refinement(1.0, 4.0, 0.5, 0.0), 0.0);
        // Band: alpha = clamp((1 + band - tau d / size) / band, 0, 1), here tau = 0.5,
        // size = 2, band = 0.5, so t = d / 4.
        for (d, want) in [
            (2.0, 1.0),
            (4.0, 1.0),
            (5.0, 0.5),
            (5.6, 0.2),
            (6.0, 0.0),
            (9.0, 0.0),
        ] {
            let a = refinement(2.0, d, 0.5, 0.5);
            assert!(close(a, want), "d = {d}: alpha {a}, want {want}");
        }
        // Continuous in d over the band.
        let mut last = 1.0;
        for k in 0..=200 {
            let a = refinement(2.0, 3.5 + k as f32 * 0.015, 0.5, 0.5);
            assert!(a <= last && last - a <= 0.061, "step {k}: {last} -> {a}");
            last = a;
        }
    }

    /// A tree of `levels` levels below the root (node 0; children of n are b n + 1 ..
    /// b n + b): spheres along x, narrowing by b per level, every extent twice the radius.
    fn tree(b: u32, levels: u32) -> (Vec<Vec4>, Vec<f32>, TreeShape) {
        let mut spheres = Vec::new();
        let (mut first_leaf, mut per_level) = (0, 1u32);
        for level in 0..=levels {
            let width = 16.0 / per_level as f32;
            for i in 0..per_level {
                let x = -8.0 + width * (i as f32 + 0.5);
                spheres.push(Vec4::new(x, 0.0, 0.0, width * 0.5));
            }
            if level < levels {
                first_leaf += per_level;
            }
            per_level *= b;
        }
        let extents = spheres.iter().map(|s| s.w * 2.0).collect();
        let shape = TreeShape {
            node_count: spheres.len() as u32,
            branch: b,
            first_leaf,
        };
        (spheres, extents, shape)
    }

    fn binary_tree(levels: u32) -> (Vec<Vec4>, Vec<f32>, TreeShape) {
        tree(2, levels)
    }

    type Contribution = (u32, Vec4, f32);

    fn walk(
        p: Vec3,
        spheres: &[Vec4],
        extents: &[f32],
        shape: TreeShape,
        params: &AoParams,
    ) -> (Vec<Contribution>, u32) {
        let mut out = Vec::new();
        let tested = walk_cut(p, spheres, extents, shape, params, |n, s, w| {
            out.push((n, s, w))
        });
        (out, tested)
    }

    /// The cut written as a recursion over the tree (the definition the iterative walk with
    /// its per-depth arrays must equal).
    #[allow(clippy::too_many_arguments)]
    fn recurse(
        p: Vec3,
        spheres: &[Vec4],
        extents: &[f32],
        shape: TreeShape,
        params: &AoParams,
        node: u32,
        (parent, w_parent, a_parent, share): (Vec4, f32, f32, f32),
        out: &mut Vec<Contribution>,
        tested: &mut u32,
    ) {
        let s = spheres[node as usize];
        if s.w < 0.0 {
            return;
        }
        *tested += 1;
        let (eff, w) = if a_parent >= 1.0 {
            (s, w_parent)
        } else {
            (
                parent + (s - parent) * a_parent,
                w_parent * (share + (1.0 - share) * a_parent),
            )
        };
        let a = if node >= shape.first_leaf {
            0.0
        } else {
            let size = match params.refine {
                Refine::Radius => s.w,
                Refine::Extent => extents[node as usize],
            };
            let d = (s.truncate() - p).length();
            refinement(size, d, params.tau, params.band).min(a_parent)
        };
        if a > 0.0 {
            let first = node * shape.branch + 1;
            let children = first..first + shape.branch;
            let used = children
                .clone()
                .filter(|&c| spheres[c as usize].w >= 0.0)
                .count()
                .max(1);
            for c in children {
                let state = (eff, w, a, 1.0 / used as f32);
                recurse(p, spheres, extents, shape, params, c, state, out, tested);
            }
        } else {
            out.push((node, eff, w));
        }
    }

    fn reference(
        p: Vec3,
        spheres: &[Vec4],
        extents: &[f32],
        shape: TreeShape,
        params: &AoParams,
    ) -> (Vec<Contribution>, u32) {
        let (mut out, mut tested) = (Vec::new(), 0);
        for c in 1..=shape.branch {
            let state = (Vec4::ZERO, 1.0, 1.0, 1.0);
            recurse(
                p,
                spheres,
                extents,
                shape,
                params,
                c,
                state,
                &mut out,
                &mut tested,
            );
        }
        (out, tested)
    }

    fn same(a: &[Contribution], b: &[Contribution]) -> bool {
        a.len() == b.len()
            && a.iter().zip(b).all(|(x, y)| {
                x.0 == y.0 && (0..4).all(|k| close(x.1[k], y.1[k])) && close(x.2, y.2)
            })
    }

    /// Hand-computed cuts: none refined (far), all refined (tau tiny), and one node half
    /// refined, whose children are morphed halfway from it and weigh 3/4 each. Planted bugs
    /// this catches: the walk's child / sibling / parent index arithmetic, the depth
    /// bookkeeping, the morph `parent + (s - parent) * a`, the weight share
    /// `share + (1 - share) * a`, the count of used children, an unused node tested.
    #[test]
    fn the_cut_is_the_hand_computed_one() {
        let (spheres, extents, shape) = binary_tree(2);
        // Far away: the two level-1 spheres, whole.
        let far = params(1.0, 0.0, Refine::Radius);
        let (cut, tested) = walk(Vec3::new(0.0, 100.0, 0.0), &spheres, &extents, shape, &far);
        assert_eq!(tested, 2);
        assert!(
            same(&cut, &[(1, spheres[1], 1.0), (2, spheres[2], 1.0)]),
            "{cut:?}"
        );
        // tau tiny: every leaf, whole, in order.
        let near = params(0.01, 0.0, Refine::Radius);
        let (cut, tested) = walk(Vec3::new(0.0, 10.0, 0.0), &spheres, &extents, shape, &near);
        assert_eq!(tested, 6);
        let leaves: Vec<_> = (3..7).map(|n| (n, spheres[n as usize], 1.0)).collect();
        assert!(same(&cut, &leaves), "{cut:?}");
        // Node 1 (centre -4, radius 4) half refined: d = 6, t = d / 4 = 1.5 with tau 1,
        // band 1: alpha = (2 - 1.5) / 1 = 0.5. Node 2 (centre 4): d = 10, alpha 0.
        let half = params(1.0, 1.0, Refine::Radius);
        let p = Vec3::new(-4.0, 6.0, 0.0);
        let (cut, tested) = walk(p, &spheres, &extents, shape, &half);
        let morph = |n: usize| spheres[1] + (spheres[n] - spheres[1]) * 0.5;
        let want = [
            (3, morph(3), 0.75),
            (4, morph(4), 0.75),
            (2, spheres[2], 1.0),
        ];
        assert_eq!(tested, 4);
        assert!(same(&cut, &want), "{cut:?}");
        // One child of node 1 unused: the other carries the whole weight as it morphs.
        let mut one = spheres.clone();
        one[4].w = -1.0;
        let (cut, tested) = walk(p, &one, &extents, shape, &half);
        assert_eq!(tested, 3);
        assert!(
            same(&cut, &[(3, morph(3), 1.0), (2, one[2], 1.0)]),
            "{cut:?}"
        );
        // Refining by extent (twice the radius here) refines where the radius would not.
        let by_extent = params(1.0, 0.0, Refine::Extent);
        let by_radius = params(1.0, 0.0, Refine::Radius);
        let q = Vec3::new(-4.0, 6.0, 0.0); // d = 6: radius 4 < 6 < extent 8
        assert_eq!(walk(q, &spheres, &extents, shape, &by_radius).0.len(), 2);
        let (cut, _) = walk(q, &spheres, &extents, shape, &by_extent);
        assert_eq!(cut.iter().map(|c| c.0).collect::<Vec<_>>(), [3, 4, 2]);
    }

    /// The deepest tree the walk accepts (MAX_DEPTH levels below the root) walked to its
    /// leaves: every leaf, once, whole. Planted bugs this catches: the per-depth arrays
    /// sized MAX_DEPTH - 1 (a panic at the last level).
    #[test]
    fn the_deepest_tree_walks_to_every_leaf() {
        let (spheres, extents, shape) = binary_tree(MAX_DEPTH as u32);
        let all = params(0.001, 0.0, Refine::Radius);
        let (cut, tested) = walk(Vec3::new(0.0, 1.0, 0.0), &spheres, &extents, shape, &all);
        assert_eq!(tested, shape.node_count - 1);
        let leaves: Vec<u32> = (shape.first_leaf..shape.node_count).collect();
        assert_eq!(cut.iter().map(|c| c.0).collect::<Vec<_>>(), leaves);
        assert!(
            cut.iter()
                .all(|c| c.2 == 1.0 && c.1 == spheres[c.0 as usize])
        );
        // Half refined at every level: the weights multiply down to the leaves.
        let half = params(1.0, 4.0, Refine::Radius);
        let (cut, _) = walk(Vec3::new(0.0, 1.0, 0.0), &spheres, &extents, shape, &half);
        let (want, _) = reference(Vec3::new(0.0, 1.0, 0.0), &spheres, &extents, shape, &half);
        assert!(same(&cut, &want));
    }

    /// A deeper tree's cut equals the recursion's at random receivers and settings, covers
    /// every used leaf exactly once, and blends nested nodes with the parent's alpha as a
    /// ceiling (a child of a half-refined node is at most half refined). Planted bugs this
    /// catches: the climb back to a parent (`(node - 1) % b == b - 1`), `depth` off by one,
    /// `.min(a_p)` dropped, a leaf refined.
    #[test]
    fn the_cut_equals_its_recursion_and_partitions_the_leaves() {
        // Branch 2, 3 and 8 (the shipped trees' branch): `(node - 1) % b` and `(node + 1) % b`
        // agree for b = 2 only.
        for (b, levels, unused) in [
            (2, 4, [6u32, 20, 23]),
            (3, 3, [5, 17, 30]),
            (8, 2, [3, 20, 70]),
        ] {
            cut_against_recursion(b, levels, &unused);
        }
    }

    fn cut_against_recursion(b: u32, levels: u32, unused: &[u32]) {
        let (mut spheres, extents, shape) = tree(b, levels);
        let mut rng = Rng::new(7);
        // A few unused subtrees' roots and leaves.
        for &n in unused {
            spheres[n as usize].w = -1.0;
        }
        let mut partial = 0;
        for k in 0..400 {
            let p = Vec3::new(
                rng.f32() * 24.0 - 12.0,
                rng.f32() * 8.0 + 0.5,
                rng.f32() * 4.0 - 2.0,
            );
            let refine = if k % 2 == 0 {
                Refine::Radius
            } else {
                Refine::Extent
            };
            let prm = params(0.2 + 0.8 * rng.f32(), [0.0, 0.5, 2.0][k % 3], refine);
            let (cut, tested) = walk(p, &spheres, &extents, shape, &prm);
            let (want, want_tested) = reference(p, &spheres, &extents, shape, &prm);
            assert!(
                same(&cut, &want),
                "receiver {p}, {prm:?}:\n{cut:?}\n{want:?}"
            );
            assert_eq!(tested, want_tested);
            partial += cut.iter().filter(|c| c.2 < 1.0).count();
            // Every used leaf lies under exactly one contributing node (unused subtrees
            // aside), and no contributing node is unused.
            for leaf in shape.first_leaf..shape.node_count {
                let mut chain = vec![leaf];
                while *chain.last().unwrap() > 0 {
                    let n = *chain.last().unwrap();
                    chain.push((n - 1) / b);
                }
                // Below an unused node nothing counts; above it, at most one node.
                let covering = |nodes: &[u32]| cut.iter().filter(|c| nodes.contains(&c.0)).count();
                match chain.iter().rposition(|&n| spheres[n as usize].w < 0.0) {
                    Some(k) => {
                        assert_eq!(covering(&chain[..=k]), 0, "leaf {leaf} at {p}");
                        assert!(covering(&chain[k + 1..]) <= 1, "leaf {leaf} at {p}");
                    }
                    None => assert_eq!(covering(&chain), 1, "leaf {leaf} at receiver {p}"),
                }
            }
        }
        assert!(
            partial > 100,
            "branch {b}: only {partial} blended contributions"
        );
    }

    /// Two caps seen from a receiver at the origin with normal +z, alone in a tree of two
    /// leaves (branch 2, first_leaf 1).
    fn two_leaves(a: Vec4, b: Vec4) -> Posed {
        Posed {
            positions: Vec::new(),
            normals: Vec::new(),
            spheres: vec![Vec4::ZERO, a, b],
            extents: vec![0.0, a.w, b.w],
        }
    }

    const LEAVES: TreeShape = TreeShape {
        node_count: 3,
        branch: 2,
        first_leaf: 1,
    };

    fn occ(s: Vec4) -> f32 {
        let d = s.truncate().length();
        sphere_occlusion(s.z / d, d / s.w)
    }

    fn vis(ao: &CpuAo, posed: &Posed, prm: &AoParams) -> VertexAo {
        ao.vertex(Vec3::ZERO, Vec3::Z, posed, LEAVES, prm)
    }

    /// Each blend mode is its formula on two caps: product of (1 - I), 1 - sum I, and the
    /// mask union (disjoint caps: the sum; coincident caps: one of them). Planted bugs this
    /// catches: the cosine taken against another axis, h inverted, the blends swapped or
    /// their sums mis-weighted, the union's scale inverted.
    #[test]
    fn each_blend_is_its_formula_on_two_caps() {
        let ao = CpuAo::new(OcclusionTable::new(64, 64));
        let a = Vec4::new(3.0, 0.5, 4.0, 1.5);
        let b = Vec4::new(-2.0, -2.0, 1.0, 1.0);
        let (ia, ib) = (occ(a), occ(b));
        assert!(
            ia > 0.02 && ib > 0.02 && (ia - ib).abs() > 0.01,
            "{ia} {ib}"
        );
        let exact = |blend| AoParams {
            occlusion: Occlusion::Exact,
            blend,
            ..AoParams::default()
        };
        let posed = two_leaves(a, b);
        let r = vis(&ao, &posed, &exact(Blend::Product));
        assert_eq!((r.tested, r.used), (2, 2));
        assert!(close(r.visibility, (1.0 - ia) * (1.0 - ib)), "{r:?}");
        let r = vis(&ao, &posed, &exact(Blend::Sum));
        assert!(close(r.visibility, 1.0 - ia - ib), "{r:?}");
        // Disjoint caps (a towards +x, b towards -x -y): the mask union is their sum.
        let r = vis(&ao, &posed, &exact(Blend::Mask));
        assert!(close(r.visibility, 1.0 - ia - ib), "{r:?}");
        // Coincident caps: the union is one of them.
        let r = vis(&ao, &two_leaves(a, a), &exact(Blend::Mask));
        assert!(close(r.visibility, 1.0 - ia), "{r:?}");
        // Half-overlapping caps: between the larger and the sum.
        let c = Vec4::new(3.6, 0.5, 3.2, 1.5);
        let r = vis(&ao, &two_leaves(a, c), &exact(Blend::Mask));
        let (lo, hi) = (1.0 - ia - occ(c), 1.0 - ia.max(occ(c)));
        assert!(
            r.visibility > lo + 0.01 && r.visibility < hi - 0.01,
            "{r:?} in ({lo}, {hi})"
        );
        // The table lookup agrees with the closed form to its interpolation error.
        let table = AoParams {
            occlusion: Occlusion::Table,
            blend: Blend::Sum,
            ..AoParams::default()
        };
        let r = vis(&ao, &posed, &table);
        assert!((r.visibility - (1.0 - ia - ib)).abs() < 0.01, "{r:?}");
    }

    /// A sphere the receiver is close to or inside: without clamp_inside its radius fades
    /// from nothing at its surface to whole at 1.25 radii (h / ((h - 1) / 0.25)) and a sphere
    /// holding the receiver is skipped; with clamp_inside h is clamped to the surface.
    /// Blended weights below 1 enter the product as powers. Planted bugs this catches: the
    /// fade's test or formula, the skip of a sphere holding the receiver, `powf(w)` dropped.
    #[test]
    fn spheres_near_the_receiver_fade_and_weights_enter_as_powers() {
        let ao = CpuAo::new(OcclusionTable::new(64, 64));
        let exact = |clamp_inside| AoParams {
            occlusion: Occlusion::Exact,
            blend: Blend::Sum,
            clamp_inside,
            ..AoParams::default()
        };
        let far = Vec4::new(0.0, 0.0, 100.0, 1.0); // occludes ~1e-4
        // h = 1.125: faded to h = 1.125 / 0.5 = 2.25.
        let s = Vec4::new(0.0, 1.8, 2.4, 3.0 / 1.125);
        let r = vis(&ao, &two_leaves(s, far), &exact(false));
        let want = 1.0 - sphere_occlusion(0.8, 2.25) - occ(far);
        assert!(close(r.visibility, want), "{r:?} want {want}");
        // h = 2: no fade.
        let s2 = Vec4::new(0.0, 1.8, 2.4, 1.5);
        let r = vis(&ao, &two_leaves(s2, far), &exact(false));
        assert!(close(
            r.visibility,
            1.0 - sphere_occlusion(0.8, 2.0) - occ(far)
        ));
        // Inside (h = 0.5): skipped, or clamped to its surface (the whole hemisphere above
        // the tangent plane it touches).
        let inside = Vec4::new(0.0, 1.8, 2.4, 6.0);
        let r = vis(&ao, &two_leaves(inside, far), &exact(false));
        assert_eq!(r.used, 1);
        assert!(close(r.visibility, 1.0 - occ(far)));
        let r = vis(&ao, &two_leaves(inside, far), &exact(true));
        assert_eq!(r.used, 2);
        let want = 1.0 - sphere_occlusion(0.8, 1.0) - occ(far);
        assert!(close(r.visibility, want.max(0.0)), "{r:?} want {want}");
        // The receiver at a sphere's centre (d = 0) with clamp_inside: the sphere counts as
        // touching it along the normal, finite in every blend (a 0 / 0 direction would be
        // NaN).
        let centred = Vec4::new(0.0, 0.0, 0.0, 2.0);
        for blend in [Blend::Sum, Blend::Mask] {
            let prm = AoParams {
                blend,
                ..exact(true)
            };
            let r = vis(&ao, &two_leaves(centred, far), &prm);
            let want = (1.0 - sphere_occlusion(1.0, 0.0) - occ(far)).clamp(0.0, 1.0);
            assert!(
                r.visibility.is_finite() && close(r.visibility, want),
                "{blend:?}: {r:?}"
            );
        }
        // Weights below 1 (a half-refined parent over two children) in the product.
        let (spheres, extents, shape) = binary_tree(2);
        let mut spheres = spheres;
        for s in &mut spheres {
            s.z += 3.0; // above the receiver's plane
        }
        let posed = Posed {
            positions: Vec::new(),
            normals: Vec::new(),
            spheres: spheres.clone(),
            extents,
        };
        let prm = AoParams {
            occlusion: Occlusion::Exact,
            blend: Blend::Product,
            ..params(0.5, 1.0, Refine::Radius)
        };
        let p = Vec3::new(0.0, 0.0, -9.0);
        let mut want = 1.0f32;
        let mut weights = Vec::new();
        walk_cut(p, &spheres, &posed.extents, shape, &prm, |_, s, w| {
            let dv = s.truncate() - p;
            want *= (1.0 - sphere_occlusion(dv.z / dv.length(), dv.length() / s.w)).powf(w);
            weights.push(w);
        });
        assert!(weights.iter().all(|&w| w > 0.55 && w < 0.95), "{weights:?}");
        let r = ao.vertex(p, Vec3::Z, &posed, shape, &prm);
        assert!(close(r.visibility, want), "{r:?} want {want}");
    }

    /// Caps too small to hold any of the 128 mask directions: one alone counts, a second in
    /// the same direction is hidden behind the first (left out of the mask blend), one in
    /// another direction counts. Planted bugs this catches: the hidden test inverted, the
    /// small caps' bit never set, hidden occlusion added instead of removed.
    #[test]
    fn caps_between_mask_directions_count_once_per_direction() {
        let ao = CpuAo::new(OcclusionTable::new(64, 64));
        let mask = AoParams {
            occlusion: Occlusion::Exact,
            blend: Blend::Mask,
            ..AoParams::default()
        };
        let tiny = |x: f32, y: f32| {
            let d = Vec3::new(x, y, 1.0).normalize() * 50.0;
            d.extend(0.2)
        };
        let (a, b, c) = (tiny(0.3, 0.2), tiny(0.3, 0.2), tiny(-0.6, 0.5));
        let (ia, ic) = (occ(a), occ(c));
        assert!(ia > 0.0 && ic > 0.0);
        let r = vis(&ao, &two_leaves(a, b), &mask);
        assert!(close(r.visibility, 1.0 - ia), "same direction: {r:?}");
        let r = vis(&ao, &two_leaves(a, c), &mask);
        assert!(close(r.visibility, 1.0 - ia - ic), "two directions: {r:?}");
        // Behind a large cap that holds its direction, a tiny cap is hidden.
        let big = Vec3::new(0.3, 0.2, 1.0).normalize().extend(0.0) * 4.0 + Vec4::W * 2.0;
        let r = vis(&ao, &two_leaves(big, a), &mask);
        assert!(close(r.visibility, 1.0 - occ(big)), "behind: {r:?}");
    }

    /// The mask blend over many caps, large and too small to hold a direction, equals the
    /// same rule written with sets (directions as indices, not bit words): large caps add
    /// I scaled by |union| / sum of counts, a small cap adds I unless its nearest direction
    /// is in the union or taken by an earlier small cap. Planted bugs this catches: the bit
    /// of direction k (`k >> 5`, `1 << (k & 31)`) miscomputed, the union or the small caps'
    /// words combined with `&` or `^`, a small cap's bit never recorded.
    #[test]
    fn the_mask_blend_equals_its_set_rewrite() {
        use std::collections::BTreeSet;
        let ao = CpuAo::new(OcclusionTable::new(64, 64));
        let prm = AoParams {
            occlusion: Occlusion::Exact,
            blend: Blend::Mask,
            ..AoParams::default()
        };
        let mut rng = Rng::new(11);
        for trial in 0..60 {
            let n = 12;
            let mut spheres = vec![Vec4::ZERO];
            for k in 0..n {
                let dir = Vec3::new(
                    rng.f32() * 2.0 - 1.0,
                    rng.f32() * 2.0 - 1.0,
                    0.3 + rng.f32(),
                )
                .normalize();
                // Some small caps repeat an earlier one's direction.
                let dir = if k > 2 && k % 4 == 0 {
                    spheres[k - 2].truncate().normalize()
                } else {
                    dir
                };
                let (dist, r) = if rng.f32() < 0.5 {
                    (50.0, 0.1 + 0.2 * rng.f32())
                } else {
                    (4.0 + 4.0 * rng.f32(), 0.8 + 1.5 * rng.f32())
                };
                spheres.push((dir * dist).extend(r));
            }
            let posed = Posed {
                positions: Vec::new(),
                normals: Vec::new(),
                extents: spheres.iter().map(|s| s.w).collect(),
                spheres: spheres.clone(),
            };
            let shape = TreeShape {
                node_count: n as u32 + 1,
                branch: n as u32,
                first_leaf: 1,
            };
            let got = ao.vertex(Vec3::ZERO, Vec3::Z, &posed, shape, &prm);
            let (t, b) = orthonormal_basis(Vec3::Z);
            let (mut union, mut small) = (BTreeSet::new(), BTreeSet::new());
            let (mut sum_all, mut sum_masked, mut hidden, mut counts) = (0.0, 0.0, 0.0, 0usize);
            let mut n_small = 0;
            for s in &spheres[1..] {
                let i = occ(*s);
                sum_all += i;
                if i <= 0.0 {
                    continue;
                }
                let c = s.truncate();
                let h = c.length() / s.w;
                let wd = c / c.length();
                let wl = Vec3::new(wd.dot(t), wd.dot(b), wd.dot(Vec3::Z));
                let cos_a = (1.0 - 1.0 / (h * h)).sqrt();
                let held: Vec<usize> = (0..ao.dirs.len())
                    .filter(|&k| ao.dirs[k].dot(wl) >= cos_a)
                    .collect();
                if held.is_empty() {
                    n_small += 1;
                    let k = ao.nearest[nearest_cell(wl.to_array())] as usize;
                    if union.contains(&k) || !small.insert(k) {
                        hidden += i;
                    }
                } else {
                    sum_masked += i;
                    counts += held.len();
                    union.extend(held);
                }
            }
            let scale = if counts > 0 {
                union.len() as f32 / counts as f32
            } else {
                1.0
            };
            let want =
                (1.0 - ((sum_all - sum_masked - hidden) + sum_masked * scale)).clamp(0.0, 1.0);
            assert!(n_small > 0 && counts > 0, "trial {trial}");
            assert!(
                (got.visibility - want).abs() < 1e-5,
                "trial {trial}: {} against {want}",
                got.visibility
            );
        }
    }
}
