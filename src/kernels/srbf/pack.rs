//! The SRBF kernel's data as the GPU holds it, packed on the CPU with no device: the
//! lighting lobes (zero-amplitude padding keeps every buffer non-empty), the basis axes,
//! the clustered-PCA transfer in its GPU layout (shade slots grouped by cluster, half
//! weights, group-major rows) and the per-slot normals and visibility of compact lobes (with
//! shadow rays: the per-slot positions and the static mesh's BVH instead of the visibility).

use super::cpca::Cpca;
use super::inputs::SrbfInputs;
use super::sharp;
use crate::error::{Error, Result};
use crate::geom::sg::Lobe;

/// Most transfer basis functions (the size of the uniform coefficient array that `srbf
/// project` reads; a 16 KiB uniform buffer, the smallest maxUniformBufferRange Vulkan allows).
pub const MAX_BASIS: usize = 1024;
/// Most projected rows, [`rows_needed`]: the width of the image `srbf project` writes and
/// `srbf shade` reads (4096, the smallest maxImageDimension2D Vulkan allows).
pub const MAX_ROWS: usize = 4096;
/// Invocations per workgroup of `srbf shade` (its local_size_x): one cluster per workgroup.
pub const SHADE_GROUP: usize = 64;
/// Most workgroups of `srbf shade` (its uniform workgroup-to-cluster table: 64 KiB).
pub const MAX_SHADE_GROUPS: usize = 16384;
/// Projected rows per cluster on the GPU: the mean, then the axes padded to whole groups of
/// eight (one uvec4 of half weights).
pub fn stride(components: usize) -> usize {
    1 + 8 * components.div_ceil(8)
}

/// Projected rows the GPU needs for `clusters` x `components`.
pub fn rows_needed(clusters: usize, components: usize) -> usize {
    clusters * stride(components)
}

/// A padding slot of `srbf shade`.
pub const NO_VERTEX: u32 = u32::MAX;

/// Most compact-lobe taps (`srbf shade`'s uniform array): four a resolved lobe on the grid.
pub const MAX_TAPS: usize = sharp::MAX_LOBES * sharp::SPREAD_TAPS;

/// The sizes the passes' push constants and grids carry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    /// Lobes through the basis, and compact lobes (shaded from the visibility).
    pub lobes: u32,
    pub compact: u32,
    /// The visibility grid of the compact lobes (1 x 1 without).
    pub grid: [u32; 2],
    pub basis: u32,
    pub basis_sharpness: f32,
    pub vertices: u32,
    pub clusters: u32,
    pub components: u32,
    /// Projected rows ([`rows_needed`]) and rows per cluster ([`stride`]).
    pub rows: u32,
    pub stride: u32,
    /// Shade slots: vertices padded so that every workgroup holds one cluster.
    pub slots: u32,
    /// Compact lobes shadowed by rays at their exact directions (pass `srbf sharp` casts
    /// them), and the rays' origin offset along the normal; false: the grid tap.
    pub rays: bool,
    pub ray_offset: f32,
    /// The compact taps `srbf shade` adds: one a lobe with rays, [`sharp::tap_count`] on the
    /// grid.
    pub taps: u32,
}

/// Everything the SRBF passes read, checked and packed (see the module documentation).
pub struct Prepared {
    pub(super) shape: Shape,
    /// (axis, sharpness) and (amplitude, 0) of each lobe through the basis, then of each
    /// compact lobe; one zero-amplitude lobe where there are none.
    pub(super) lobe_axes: Vec<[f32; 4]>,
    pub(super) lobe_amps: Vec<[f32; 4]>,
    pub(super) compact_axes: Vec<[f32; 4]>,
    pub(super) compact_amps: Vec<[f32; 4]>,
    pub(super) basis_axes: Vec<[f32; 4]>,
    pub(super) layout: Layout,
    /// Per slot: the normal and the visibility words (word-major); one zero word each
    /// when there are no compact lobes.
    pub(super) normals: Vec<[f32; 4]>,
    pub(super) visible: Vec<u32>,
    /// With shadow rays: per slot the vertex position (w 0), and the BVH as the shaders
    /// traverse it ([`crate::geom::bvh::Bvh::flat`] with [`crate::geom::bvh::with_links`]);
    /// one zero entry each without.
    pub(super) positions: Vec<[f32; 4]>,
    pub(super) bvh_nodes: Vec<[f32; 8]>,
    pub(super) bvh_triangles: Vec<[f32; 12]>,
}

impl Prepared {
    /// Checks `inputs` ([`SrbfInputs::check`]) and packs them.
    pub fn new(inputs: &SrbfInputs<'_>) -> Result<Prepared> {
        inputs.check()?;
        let t = inputs.transfer;
        let (smooth, compact) = inputs.split();
        let points = inputs.compact_points(&compact);
        let layout = Layout::of(t);
        let slots = layout.slot_vertex.len();
        let rays = inputs.rays.filter(|_| !compact.is_empty());
        let (normals, visible, grid) = match (&inputs.compact, compact.is_empty()) {
            (Some(c), false) => {
                // With shadow rays the grid's bits are not read: one zero word.
                let words = if rays.is_some() {
                    0
                } else {
                    c.visibility.directions.len().div_ceil(32)
                };
                let mut normals = vec![[0f32; 4]; slots];
                let mut visible = vec![0u32; (words * slots).max(4)];
                for (slot, &v) in layout.slot_vertex.iter().enumerate() {
                    if v == NO_VERTEX {
                        continue;
                    }
                    normals[slot] = c.normals[v as usize].extend(0.0).to_array();
                    for w in 0..words {
                        visible[w * slots + slot] = c.visibility.word32(v as usize, w);
                    }
                }
                (normals, visible, [c.width, c.height])
            }
            _ => (vec![[0f32; 4]], vec![0u32; 4], [1, 1]),
        };
        let (positions, bvh_nodes, bvh_triangles) = match &rays {
            Some(r) => {
                // A padding slot keeps a zero normal: it casts no ray.
                let positions = layout
                    .slot_vertex
                    .iter()
                    .map(|&v| match v {
                        NO_VERTEX => [0.0; 4],
                        v => r.positions[v as usize].extend(0.0).to_array(),
                    })
                    .collect();
                let (nodes, tris) = r.bvh.flat();
                (positions, crate::geom::bvh::with_links(nodes)?, tris)
            }
            None => (vec![[0f32; 4]], vec![[0f32; 8]], vec![[0f32; 12]]),
        };
        Ok(Prepared {
            shape: Shape {
                lobes: smooth.len() as u32,
                compact: compact.len() as u32,
                grid,
                basis: t.basis.len() as u32,
                basis_sharpness: t.basis.sharpness,
                vertices: t.vertices as u32,
                clusters: t.clusters as u32,
                components: t.components as u32,
                rows: (t.clusters * layout.stride) as u32,
                stride: layout.stride as u32,
                slots: slots as u32,
                rays: rays.is_some(),
                ray_offset: rays.map_or(0.0, |r| r.offset),
                taps: match rays {
                    Some(_) => compact.len() as u32,
                    None => sharp::tap_count(&points) as u32,
                },
            },
            lobe_axes: axes_of(&smooth),
            lobe_amps: amps_of(&smooth),
            compact_axes: axes_of(&compact),
            compact_amps: sharp::flag_resolved(amps_of(&compact), &points),
            basis_axes: t
                .basis
                .axes
                .iter()
                .map(|a| a.extend(0.0).to_array())
                .collect(),
            layout,
            normals,
            visible,
            positions,
            bvh_nodes,
            bvh_triangles,
        })
    }

    /// Checks that a device with maxUniformBufferRange `max_uniform_range` and
    /// `maxComputeWorkGroupCount[0]` `max_group_count` holds the uniform arrays and
    /// dispatches the shade slots.
    pub fn check_device(&self, max_uniform_range: u64, max_group_count: u32) -> Result<()> {
        let ubo_limit = max_uniform_range as usize;
        // `srbf shade`'s workgroup-to-cluster table is the largest uniform array.
        if ubo_limit < MAX_SHADE_GROUPS * 4 {
            return Err(Error::InvalidArgument(format!(
                "SRBF needs uniform buffers of {} bytes; the device allows {ubo_limit} \
                 (maxUniformBufferRange)",
                MAX_SHADE_GROUPS * 4
            )));
        }
        let max_groups = (max_group_count as usize).min(MAX_SHADE_GROUPS);
        let groups = self.shape.slots as usize / SHADE_GROUP;
        if groups > max_groups {
            return Err(Error::InvalidArgument(format!(
                "SRBF: {} vertices need {groups} workgroups; the device dispatches {max_groups}",
                self.shape.vertices
            )));
        }
        Ok(())
    }

    /// The sizes the passes carry.
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// The workgroup-to-cluster table as `srbf shade` reads it: its fixed uniform array,
    /// zero-padded.
    pub fn group_table(&self) -> Vec<u32> {
        let mut groups = self.layout.group_cluster.clone();
        groups.resize(MAX_SHADE_GROUPS, 0);
        groups
    }
}

/// Lobes padded to one: a zero-amplitude lobe where there are none.
fn pad(l: &[Lobe]) -> Vec<Lobe> {
    let mut v = l.to_vec();
    if v.is_empty() {
        v.push(Lobe {
            axis: [0.0, 1.0, 0.0],
            sharpness: 1.0,
            amplitude: [0.0; 3],
        });
    }
    v
}

/// (axis, sharpness) per lobe, padded ([`pad`]).
fn axes_of(l: &[Lobe]) -> Vec<[f32; 4]> {
    pad(l)
        .iter()
        .map(|l| [l.axis[0], l.axis[1], l.axis[2], l.sharpness])
        .collect()
}

/// (amplitude, 0) per lobe, padded ([`pad`]).
fn amps_of(l: &[Lobe]) -> Vec<[f32; 4]> {
    pad(l)
        .iter()
        .map(|l| [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0])
        .collect()
}

/// The GPU layout of a [`Cpca`] transfer (see glsl/srbf/shade.comp and project.comp).
pub(super) struct Layout {
    /// Shade slots (a multiple of SHADE_GROUP): vertices sorted by cluster, each cluster
    /// padded to whole workgroups.
    pub(super) slot_vertex: Vec<u32>,
    pub(super) group_cluster: Vec<u32>,
    /// Weights in half precision, eight per uvec4, group-major over slots.
    pub(super) weights: Vec<[u32; 4]>,
    /// Rows per cluster in `projected`: [`stride`].
    pub(super) stride: usize,
    /// Rows, group-major vec4s over clusters x stride rows.
    pub(super) rows: Vec<[f32; 4]>,
}

impl Layout {
    fn of(t: &Cpca) -> Layout {
        let (k, m) = (t.basis.len(), t.components);
        let m_groups = m.div_ceil(8);
        let stride = stride(m);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); t.clusters];
        for (v, &c) in t.cluster_of.iter().enumerate() {
            members[c as usize].push(v as u32);
        }
        let mut slot_vertex = Vec::new();
        let mut group_cluster = Vec::new();
        for (c, list) in members.iter().enumerate() {
            for chunk in list.chunks(SHADE_GROUP) {
                group_cluster.push(c as u32);
                slot_vertex.extend_from_slice(chunk);
                slot_vertex.resize(group_cluster.len() * SHADE_GROUP, NO_VERTEX);
            }
        }
        let slots = slot_vertex.len();
        let mut weights = vec![[0u32; 4]; m_groups * slots];
        for (slot, &v) in slot_vertex.iter().enumerate() {
            if v == NO_VERTEX {
                continue;
            }
            let w = &t.weights[v as usize * m..(v as usize + 1) * m];
            for (i, x) in w.iter().enumerate() {
                // unpackHalf2x16: the first of a pair in the low 16 bits.
                let word = &mut weights[(i / 8) * slots + slot][(i % 8) / 2];
                *word |= (crate::io::f16::f16_bits(*x) as u32) << (16 * (i % 2));
            }
        }
        let k_groups = k.div_ceil(4);
        let n_rows = t.clusters * stride;
        let mut rows = vec![[0f32; 4]; k_groups * n_rows];
        for c in 0..t.clusters {
            for i in 0..=m {
                let src = &t.rows[(c * (m + 1) + i) * k..(c * (m + 1) + i + 1) * k];
                let r = c * stride + i;
                for (j, x) in src.iter().enumerate() {
                    rows[(j / 4) * n_rows + r][j % 4] = *x;
                }
            }
        }
        Layout {
            slot_vertex,
            group_cluster,
            weights,
            stride,
            rows,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::f16::f16_bits;
    use crate::kernels::srbf::inputs::CompactInputs;
    use crate::kernels::srbf::transfer::Basis;
    use glam::Vec3;

    /// 150 vertices in clusters 0 (90: two workgroups), 1 and 2 (30 each); cluster 3 empty.
    /// K = 5 basis functions, M = 3 components.
    fn transfer() -> Cpca {
        let (k, m, n, clusters) = (5, 3, 150, 4);
        Cpca {
            basis: Basis::fibonacci(k),
            vertices: n,
            clusters,
            components: m,
            cluster_of: (0..n).map(|v| [0, 0, 0, 1, 2][v % 5]).collect(),
            rows: (0..clusters * (m + 1) * k)
                .map(|i| i as f32 * 0.01)
                .collect(),
            weights: (0..n * m).map(|i| i as f32 * 0.001 - 0.2).collect(),
            rel_l2: 0.0,
        }
    }

    fn lobes() -> Vec<Lobe> {
        vec![
            Lobe::new(Vec3::Y, 2.0, [1.0, 0.5, 0.25]),
            Lobe::new(Vec3::new(0.6, 0.0, 0.8), 3000.0, [9000.0; 3]),
        ]
    }

    #[test]
    fn slots_group_vertices_by_cluster_and_pad_with_no_vertex() {
        let (t, lobes) = (transfer(), lobes());
        let p = Prepared::new(&SrbfInputs::new(&lobes, &t)).unwrap();
        let l = &p.layout;
        let slots = l.slot_vertex.len();
        assert_eq!(
            (slots, l.group_cluster.clone()),
            (4 * SHADE_GROUP, vec![0, 0, 1, 2])
        );
        assert_eq!(p.shape.slots as usize, slots);
        let mut seen = vec![false; t.vertices];
        for (g, group) in l.slot_vertex.chunks(SHADE_GROUP).enumerate() {
            // Real vertices of the group's cluster first, then padding.
            let real = group.iter().take_while(|&&v| v != NO_VERTEX).count();
            assert!(group[real..].iter().all(|&v| v == NO_VERTEX));
            for &v in &group[..real] {
                assert_eq!(t.cluster_of[v as usize], l.group_cluster[g]);
                assert!(!std::mem::replace(&mut seen[v as usize], true));
            }
        }
        assert!(seen.iter().all(|&s| s));
        // Half weights, eight per uvec4, group-major over slots; zero for padding.
        let m = t.components;
        for (slot, &v) in l.slot_vertex.iter().enumerate() {
            for i in 0..m {
                let word = l.weights[(i / 8) * slots + slot][(i % 8) / 2];
                let half = (word >> (16 * (i % 2))) & 0xffff;
                let want = match v {
                    NO_VERTEX => 0,
                    v => f16_bits(t.weights[v as usize * m + i]) as u32,
                };
                assert_eq!(half, want, "slot {slot} weight {i}");
            }
        }
        // Rows: vec4 groups of the K coefficients, each cluster padded to `stride` rows.
        let (k, stride) = (t.basis.len(), stride(m));
        assert_eq!((l.stride, p.shape.rows as usize), (stride, 4 * stride));
        let n_rows = 4 * stride;
        assert_eq!(l.rows.len(), k.div_ceil(4) * n_rows);
        for c in 0..t.clusters {
            for i in 0..stride {
                for j in 0..k {
                    let want = if i <= m {
                        t.rows[(c * (m + 1) + i) * k + j]
                    } else {
                        0.0
                    };
                    assert_eq!(l.rows[(j / 4) * n_rows + c * stride + i][j % 4], want);
                }
            }
        }
        let table = p.group_table();
        assert_eq!(table.len(), MAX_SHADE_GROUPS);
        assert!(table[..4] == [0, 0, 1, 2] && table[4..].iter().all(|&c| c == 0));
        // Without compact lobes: every lobe goes through the basis, the compact buffers
        // hold one zero-amplitude lobe and the slot data one zero word.
        assert_eq!(
            (p.shape.lobes, p.shape.compact, p.shape.grid),
            (2, 0, [1, 1])
        );
        assert_eq!(p.lobe_axes[1], [0.6, 0.0, 0.8, 3000.0]);
        assert_eq!(p.compact_amps, vec![[0.0; 4]]);
        assert_eq!(
            (p.normals.clone(), p.visible.clone()),
            (vec![[0.0; 4]], vec![0; 4])
        );
        assert_eq!(p.basis_axes.len(), k);
    }

    #[test]
    fn compact_lobes_get_each_slots_normal_and_visibility() {
        let (t, lobes) = (transfer(), lobes());
        let grid = crate::scene::EnvMap::from_texels(8, 4, vec![[0.0; 3]; 32], "grid").unwrap();
        let dirs: Vec<Vec3> = grid.samples().iter().map(|s| s.0).collect();
        let normals: Vec<Vec3> = (0..t.vertices)
            .map(|v| Vec3::new((v % 7) as f32 - 3.0, 1.0, (v % 3) as f32).normalize())
            .collect();
        let positions = vec![Vec3::ZERO; t.vertices];
        let tri = [
            Vec3::new(-1.0, 0.5, -1.0),
            Vec3::new(1.0, 0.5, -1.0),
            Vec3::Y,
        ];
        let bvh = crate::geom::Bvh::build(&tri, &[[0, 1, 2]]);
        let vis =
            crate::geom::visibility::direction_visibility(&positions, &normals, &bvh, &dirs, 1e-4);
        let compact = CompactInputs {
            visibility: &vis,
            normals: &normals,
            width: 8,
            height: 4,
            factor: sharp::DEFAULT_FACTOR,
            max_lobes: 4,
            fit_width: super::sharp::DEFAULT_FIT_WIDTH,
        };
        let p = Prepared::new(&SrbfInputs::new(&lobes, &t).with_compact(compact)).unwrap();
        assert_eq!(
            (p.shape.lobes, p.shape.compact, p.shape.grid),
            (1, 1, [8, 4])
        );
        assert_eq!(p.compact_axes, vec![[0.6, 0.0, 0.8, 3000.0]]);
        // At the equator a lobe of sharpness 3000 is past the 128-wide fit's cap: a point,
        // one grid tap, flagged 0 for glsl/srbf/sharp.comp.
        assert_eq!((p.shape.taps, p.compact_amps[0][3]), (1, 0.0));
        let slots = p.shape.slots as usize;
        assert_eq!((p.normals.len(), p.visible.len()), (slots, slots));
        for (slot, &v) in p.layout.slot_vertex.iter().enumerate() {
            let (n, w) = match v {
                NO_VERTEX => ([0.0; 4], 0),
                v => (
                    normals[v as usize].extend(0.0).to_array(),
                    vis.word32(v as usize, 0),
                ),
            };
            assert_eq!((p.normals[slot], p.visible[slot]), (n, w), "slot {slot}");
        }
        assert!(p.visible.iter().any(|&w| w != 0));
    }

    #[test]
    fn devices_too_small_are_refused() {
        let (t, lobes) = (transfer(), lobes());
        let p = Prepared::new(&SrbfInputs::new(&lobes, &t)).unwrap();
        assert!(p.check_device(65536, 65535).is_ok());
        let e = p.check_device(16384, 65535).unwrap_err().to_string();
        assert!(e.contains("maxUniformBufferRange"), "{e}");
        let e = p.check_device(65536, 3).unwrap_err().to_string();
        assert!(e.contains("need 4 workgroups"), "{e}");
    }
}
