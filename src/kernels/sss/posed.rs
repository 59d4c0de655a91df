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
//! - the BVH's topology ([`BvhTopology`], in `geom::bvh`): built over the rest pose (binned
//!   SAH); its leaves keep their triangles and its inner nodes their children in every pose,
//!   and the boxes are refitted per frame, bottom-up, one level of the tree after the other
//!   ([`refit`]).
//!
//! Each frame (glsl/sss/pose_*.comp, bvh_*.comp): the vertex frames (mm), per triangle the
//! walk records and the face normal and texel area, per texel the position, normal and area,
//! the BVH's triangles and boxes.
//!
//! [`posed`]: crate::scene::texspace::posed

use super::walk::{self, NON_MANIFOLD, OPEN, SurfaceWalk};
use crate::error::{Error, Result};
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

// The link words and the refitted BVH moved to `crate::geom::bvh` (SRBF's shadow rays and the
// environment's traced visibility use them too); re-exported here for the SSS code and for
// callers that name them by their old paths.
pub use crate::geom::bvh::{
    BvhTopology, LINK_COUNT, LINK_END, flat_any_hit, link_words, refit, sah_cost, with_links,
};

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
