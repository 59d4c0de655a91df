//! The same method on the CPU (rayon): skinning, the cut through the tree, per-sphere
//! occlusion and blending, step for step as `glsl/ao/*.comp` do it. It is the reference the
//! GPU is tested against (tight bound) and the CPU baseline of `bench ao`.

use super::formula::{OcclusionTable, mask_directions, sphere_occlusion};
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

/// Walks the cut for receiver `p`: calls `contribute(node, d)` for every contributing sphere
/// (in the shader's order) and returns the number of spheres tested.
pub fn walk_cut(
    p: Vec3,
    spheres: &[Vec4],
    extents: &[f32],
    shape: TreeShape,
    params: &AoParams,
    mut contribute: impl FnMut(u32, Vec3, f32),
) -> u32 {
    let b = shape.branch;
    let mut tested = 0;
    let mut node = 1u32;
    while node != 0 && node < shape.node_count {
        let s = spheres[node as usize];
        let mut descend = false;
        if s.w >= 0.0 {
            tested += 1;
            let dv = s.truncate() - p;
            let d = dv.length();
            let leaf = node >= shape.first_leaf;
            let size = match params.refine {
                Refine::Radius => s.w,
                Refine::Extent => extents[node as usize],
            };
            if !leaf && size > params.tau * d {
                descend = true;
            } else if d > s.w || params.clamp_inside {
                contribute(node, dv, d);
            }
        }
        if descend {
            node = node * b + 1;
        } else {
            while node != 0 && (node - 1) % b == b - 1 {
                node = (node - 1) / b;
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
}

impl CpuAo {
    pub fn new(table: OcclusionTable) -> CpuAo {
        CpuAo {
            table,
            dirs: mask_directions()
                .iter()
                .map(|d| Vec3::new(d[0], d[1], d[2]))
                .collect(),
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
        let mut count_sum = 0u32;
        let mut uni = [0u32; 4];
        let mut used = 0;
        let tested = walk_cut(p, spheres, &posed.extents, shape, params, |node, dv, d| {
            let r = spheres[node as usize].w;
            let h = d / r;
            let cos_t = if d > 0.0 { n.dot(dv) / d } else { 1.0 };
            let occ = match params.occlusion {
                Occlusion::Exact => sphere_occlusion(cos_t, h),
                Occlusion::Table => self.table.lookup(cos_t, h),
            };
            used += 1;
            product *= 1.0 - occ;
            sum_all += occ;
            if params.blend == Blend::Mask && occ > 0.0 {
                let w = if d > 0.0 { dv / d } else { n };
                let wl = Vec3::new(w.dot(t), w.dot(b), w.dot(n));
                let cos_a = (1.0 - 1.0 / (h * h).max(1.0)).max(0.0).sqrt();
                let mut m = [0u32; 4];
                for (k, dir) in self.dirs.iter().enumerate() {
                    if dir.dot(wl) >= cos_a {
                        m[k >> 5] |= 1 << (k & 31);
                    }
                }
                let c: u32 = m.iter().map(|x| x.count_ones()).sum();
                if c > 0 {
                    sum_masked += occ;
                    count_sum += c;
                    for k in 0..4 {
                        uni[k] |= m[k];
                    }
                }
            }
        });
        let occlusion = match params.blend {
            Blend::Product => 1.0 - product,
            Blend::Sum => sum_all,
            Blend::Mask => {
                let u: u32 = uni.iter().map(|x| x.count_ones()).sum();
                let scale = if count_sum > 0 {
                    u as f32 / count_sum as f32
                } else {
                    1.0
                };
                (sum_all - sum_masked) + sum_masked * scale
            }
        };
        VertexAo {
            visibility: (1.0 - occlusion).clamp(0.0, 1.0),
            tested,
            used,
        }
    }

    /// Visibility of every vertex of a posed mesh (rayon), with the static correction
    /// factors applied when `params.correct` is set and `correction` is given.
    pub fn frame(
        &self,
        posed: &Posed,
        shape: TreeShape,
        params: &AoParams,
        correction: Option<&[f32]>,
    ) -> Vec<VertexAo> {
        posed
            .positions
            .par_iter()
            .zip(&posed.normals)
            .enumerate()
            .map(|(i, (&p, &n))| {
                let mut v = self.vertex(p, n, posed, shape, params);
                if params.correct
                    && let Some(c) = correction
                {
                    v.visibility = (v.visibility * c[i]).min(1.0);
                }
                v
            })
            .collect()
    }
}
