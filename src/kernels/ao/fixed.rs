//! The published variant's cut (`Cut::Fixed`): per vertex, a fixed list of tree nodes chosen
//! once in the neutral (bind) pose and reused in every pose with the skinned centres; their
//! overlap is handled pairwise with the 3D table of [`super::formula::OverlapTable`].
//!
//! The choice: the nodes of the default walk's *hard* cut (band 0: a node or its children,
//! never a blend) at the bind pose, with the kernel's tau and refinement test, ranked by
//! their bind-pose occlusion (exact formula) and capped at [`FIXED_SLOTS`]. The hard cut is
//! what "per level, the spheres the cut refines to" means for a vertex: near spheres at a
//! fine level, far ones coarse, never a node with its ancestor. Ranking keeps what matters
//! when the cap bites: on Testwuson (default tree and tau) the bind-pose cut holds 38.5 nodes
//! per vertex on average and 1898 of the 3205 vertices exceed 32, but the nodes past the cap
//! are the faintest: their bind-pose occlusion sums to 0.001 per vertex on average. The list is
//! slot-major (`nodes[slot * vertices + vertex]`), so the lanes of a GPU subgroup read
//! neighbouring words in each slot; an empty slot holds [`NO_NODE`] and ends the list.

use super::cpu::{self, INSIDE_FADE};
use super::formula::sphere_occlusion;
use super::{AoParams, Prepared, Refine};
use crate::error::{Error, Result};
use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;

/// Nodes kept per vertex (the dense vertex x slots array the GPU reads).
pub const FIXED_SLOTS: u32 = 32;

/// An empty slot (and the end of a vertex's list).
pub const NO_NODE: u32 = u32::MAX;

/// Per vertex, the fixed list of nodes the published variant sums.
#[derive(Clone, Debug)]
pub struct FixedCut {
    /// Slots per vertex.
    pub slots: u32,
    pub vertex_count: u32,
    /// Slot-major: `nodes[slot * vertex_count + vertex]`, [`NO_NODE`] past a vertex's list.
    /// Each list is ordered by bind-pose occlusion, largest first.
    pub nodes: Vec<u32>,
    /// The tau and refinement test the lists were chosen with.
    pub tau: f32,
    pub refine: Refine,
    /// Mean nodes of the bind-pose hard cut per vertex, before the cap.
    pub mean_cut: f64,
    /// Vertices whose cut held more than `slots` nodes.
    pub truncated: usize,
    /// Mean over vertices of the bind-pose occlusion (summed, exact formula) of the nodes
    /// left out by the cap.
    pub dropped_occlusion: f64,
}

/// The occlusion and cap of one sphere `s` seen from (p, n), as both cuts evaluate it
/// (`cpu::CpuAo::vertex`): `None` when the sphere holds the receiver and is skipped;
/// otherwise (h after the inside fade, cos theta, unit direction to the centre).
pub fn sphere_view(p: Vec3, n: Vec3, s: Vec4, clamp_inside: bool) -> Option<(f32, f32, Vec3)> {
    let dv = s.truncate() - p;
    let d = dv.length();
    if !(d > s.w || clamp_inside) {
        return None;
    }
    let mut h = d / s.w;
    if !clamp_inside && h < 1.0 + INSIDE_FADE {
        h /= ((h - 1.0) / INSIDE_FADE).max(1e-6);
    }
    let cos_t = if d > 0.0 { n.dot(dv) / d } else { 1.0 };
    let wd = if d > 0.0 { dv / d } else { n };
    Some((h, cos_t, wd))
}

impl FixedCut {
    /// Chooses the lists in the bind pose of `prep` (identity joint matrices) with
    /// `params.tau` and `params.refine` (see the module doc), `slots` per vertex.
    pub fn select(prep: &Prepared, params: &AoParams, slots: u32) -> Result<FixedCut> {
        params.validate()?;
        prep.check()?;
        if slots == 0 || slots > FIXED_SLOTS {
            return Err(Error::InvalidArgument(format!(
                "{slots} fixed-cut slots per vertex; 1..={FIXED_SLOTS} are supported"
            )));
        }
        let bind = cpu::skin(prep, &vec![Mat4::IDENTITY; prep.joint_count]);
        let hard = AoParams {
            band: 0.0,
            ..*params
        };
        let lists: Vec<(Vec<u32>, usize, f64)> = bind
            .positions
            .par_iter()
            .zip(&bind.normals)
            .map(|(&p, &n)| {
                let mut cut: Vec<(u32, f32)> = Vec::new();
                cpu::walk_cut(
                    p,
                    &bind.spheres,
                    &bind.extents,
                    prep.shape,
                    &hard,
                    |node, s, _| {
                        let occ = sphere_view(p, n, s, params.clamp_inside)
                            .map(|(h, cos_t, _)| sphere_occlusion(cos_t, h))
                            .unwrap_or(0.0);
                        cut.push((node, occ));
                    },
                );
                // Largest bind-pose occlusion first; ties in tree order.
                cut.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
                let size = cut.len();
                let dropped: f64 = cut.iter().skip(slots as usize).map(|c| c.1 as f64).sum();
                cut.truncate(slots as usize);
                (cut.into_iter().map(|c| c.0).collect(), size, dropped)
            })
            .collect();
        let nv = lists.len();
        let mut nodes = vec![NO_NODE; nv * slots as usize];
        for (v, (list, _, _)) in lists.iter().enumerate() {
            for (s, &node) in list.iter().enumerate() {
                nodes[s * nv + v] = node;
            }
        }
        Ok(FixedCut {
            slots,
            vertex_count: nv as u32,
            nodes,
            tau: params.tau,
            refine: params.refine,
            mean_cut: lists.iter().map(|l| l.1 as f64).sum::<f64>() / nv.max(1) as f64,
            truncated: lists.iter().filter(|l| l.1 > slots as usize).count(),
            dropped_occlusion: lists.iter().map(|l| l.2).sum::<f64>() / nv.max(1) as f64,
        })
    }

    /// Checks the lists fit `prep` (the fields are public; the GPU must never read out of
    /// bounds): one list per vertex, every node a used node of the tree.
    pub fn check(&self, prep: &Prepared) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("fixed cut: {what}")));
        if self.vertex_count as usize != prep.vertex_count() {
            return bad(format!(
                "{} vertices for an input of {}",
                self.vertex_count,
                prep.vertex_count()
            ));
        }
        if self.slots == 0 || self.slots > FIXED_SLOTS {
            return bad(format!("{} slots (1..={FIXED_SLOTS})", self.slots));
        }
        if self.nodes.len() != (self.slots * self.vertex_count) as usize {
            return bad(format!(
                "{} nodes for {} vertices x {} slots",
                self.nodes.len(),
                self.vertex_count,
                self.slots
            ));
        }
        let nodes = prep.shape.node_count;
        if let Some(i) = self
            .nodes
            .iter()
            .position(|&k| k != NO_NODE && (k >= nodes || prep.spheres[k as usize][3] < 0.0))
        {
            return bad(format!(
                "entry {i} names node {}, not a used node of the {nodes}-node tree",
                self.nodes[i]
            ));
        }
        Ok(())
    }

    /// The nodes of vertex `v`'s list, in order.
    pub fn list(&self, v: usize) -> impl Iterator<Item = u32> + '_ {
        let nv = self.vertex_count as usize;
        (0..self.slots as usize)
            .map(move |s| self.nodes[s * nv + v])
            .take_while(|&k| k != NO_NODE)
    }
}
