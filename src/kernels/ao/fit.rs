//! The fitted proxy: a sphere tree's spheres refitted to the mesh, so that rays against the
//! spheres see what rays against the mesh see.
//!
//! The volume builder (`scene::spheretree`) puts volume-equivalent spheres at cluster
//! centroids: about half of each sphere's cap pokes out of the surface, and a receiver beside
//! its own body part sees those bumps above its tangent plane as occluders. The finer the
//! level, the more bumps sit within a few radii of every receiver, which is why the method's
//! error grew as the cut refined. This fit keeps the builder's clusters (the tree's shape and
//! skinning stay meaningful) and chooses each node's centre and radius to minimise a weighted
//! symmetric volume difference against the voxelised mesh:
//!
//! cost(c, r) = |cluster matter outside the sphere| + w_out * |space outside the mesh inside
//! the sphere|
//!
//! over centres at the cluster's own cells (the deepest ones and a spread of the rest) and
//! every radius (one sorted sweep per centre). `w_out` > 1 penalises protrusion more than a
//! gap: a bump beside a receiver costs more occlusion error than a gap does. Inside and
//! outside come from the same ray-parity voxelisation as the builder's; distances are exact
//! Euclidean distance transforms of the grid.

use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::scene::Mesh;
use crate::scene::spheretree::{Sphere, SphereTree};
use glam::Vec3;
use rayon::prelude::*;

/// Which proxy the AO method uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Proxy {
    /// The builder's volume-equivalent spheres at cluster centroids.
    Volume,
    /// Those clusters' spheres refitted to the mesh ([`fit_tree`]).
    Fitted,
}

/// Settings of the fit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitConfig {
    /// About how many interior cells the voxelisation has.
    pub cells: usize,
    /// Weight of a covered cell of outside space against a covered cell of the node's own
    /// matter, per level below the root (the last value holds for deeper levels).
    pub outside_weight: Vec<f32>,
    /// Centre candidates tried per node.
    pub candidates: usize,
}

impl Default for FitConfig {
    fn default() -> Self {
        FitConfig {
            cells: 150_000,
            outside_weight: vec![1.0, 1.5, 2.0],
            candidates: 64,
        }
    }
}

/// What the fit did, per level below the root.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitSummary {
    pub cell_size: f32,
    pub interior_cells: usize,
    /// Per level: fraction of the level's matter (its clusters' cells) inside its spheres.
    pub matter_covered: Vec<f64>,
    /// Per level: outside space inside its spheres, as a fraction of the mesh's volume.
    pub space_covered: Vec<f64>,
}

/// A regular grid of cells over a box, classified inside/outside a closed mesh.
struct Voxels {
    lo: Vec3,
    h: f32,
    dims: [usize; 3],
    inside: Vec<bool>,
}

impl Voxels {
    fn new(mesh: &Mesh, bvh: &Bvh, cells: usize) -> Voxels {
        let (lo, hi) = mesh.bounds();
        let e = (hi - lo).max(Vec3::splat(1e-6));
        // Interior is roughly a third of the box for a character.
        let h = (e.x * e.y * e.z / (3.0 * cells.max(1000) as f32))
            .cbrt()
            .max(e.max_element() / 500.0);
        let lo = lo - Vec3::splat(2.0 * h);
        let d = ((e + Vec3::splat(4.0 * h)) / h).ceil();
        let dims = [d.x as usize, d.y as usize, d.z as usize];
        let mut v = Voxels {
            lo,
            h,
            dims,
            inside: Vec::new(),
        };
        v.inside = v.classify(bvh);
        v
    }

    fn len(&self) -> usize {
        self.dims.iter().product()
    }

    fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    fn coords(&self, i: usize) -> [usize; 3] {
        let x = i % self.dims[0];
        let y = (i / self.dims[0]) % self.dims[1];
        [x, y, i / (self.dims[0] * self.dims[1])]
    }

    fn center(&self, i: usize) -> Vec3 {
        let [x, y, z] = self.coords(i);
        self.lo + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * self.h
    }

    /// Ray parity along each axis through the cell centres, majority of three.
    fn classify(&self, bvh: &Bvh) -> Vec<bool> {
        let mut votes = vec![0u8; self.len()];
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let lines: Vec<Vec<f32>> = (0..self.dims[u] * self.dims[v])
                .into_par_iter()
                .map(|k| {
                    let mut o = self.lo;
                    // Slightly off the centres' plane, so rays miss shared edges.
                    o[u] += ((k % self.dims[u]) as f32 + 0.5 + 1.7e-4) * self.h;
                    o[v] += ((k / self.dims[u]) as f32 + 0.5 + 0.9e-4) * self.h;
                    let mut d = Vec3::ZERO;
                    d[axis] = 1.0;
                    let mut hits = Vec::new();
                    bvh.all_hits(o, d, &mut hits);
                    hits.sort_by(f32::total_cmp);
                    hits
                })
                .collect();
            for (k, hits) in lines.iter().enumerate() {
                let (iu, iv) = (k % self.dims[u], k / self.dims[u]);
                for s in 0..self.dims[axis] {
                    let t = (s as f32 + 0.5) * self.h;
                    if hits.partition_point(|&x| x < t) % 2 == 1 {
                        let mut c = [0; 3];
                        c[axis] = s;
                        c[u] = iu;
                        c[v] = iv;
                        votes[self.index(c[0], c[1], c[2])] += 1;
                    }
                }
            }
        }
        votes.into_iter().map(|v| v >= 2).collect()
    }

    /// Per inside cell: distance from its centre to the nearest outside cell centre, less
    /// half a cell (about the distance to the surface); 0 outside. Exact Euclidean distance
    /// transform of the grid (Felzenszwalb & Huttenlocher's separable lower envelope).
    fn depth(&self) -> Vec<f32> {
        let big = 1e20f32;
        let mut f: Vec<f32> = self
            .inside
            .iter()
            .map(|&i| if i { big } else { 0.0 })
            .collect();
        let [nx, ny, _] = self.dims;
        let strides = [1, nx, nx * ny];
        for (axis, &stride) in strides.iter().enumerate() {
            let n = self.dims[axis];
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let lines: Vec<usize> = (0..self.dims[a] * self.dims[b])
                .map(|k| {
                    let mut c = [0; 3];
                    c[a] = k % self.dims[a];
                    c[b] = k / self.dims[a];
                    self.index(c[0], c[1], c[2])
                })
                .collect();
            let out: Vec<(usize, Vec<f32>)> = lines
                .par_iter()
                .map(|&start| {
                    let line: Vec<f32> = (0..n).map(|s| f[start + s * stride]).collect();
                    (start, edt_1d(&line))
                })
                .collect();
            for (start, line) in out {
                for (s, v) in line.into_iter().enumerate() {
                    f[start + s * stride] = v;
                }
            }
        }
        f.iter()
            .zip(&self.inside)
            .map(|(&d2, &i)| {
                if i {
                    (d2.sqrt() - 0.5).max(0.0) * self.h
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// Squared distance transform of one line of sampled values (0 at sites, large elsewhere):
/// the lower envelope of the parabolas (q - p)^2 + f(p).
fn edt_1d(f: &[f32]) -> Vec<f32> {
    let n = f.len();
    let f: Vec<f64> = f.iter().map(|&x| x as f64).collect();
    let mut v = vec![0usize; n];
    let mut z = vec![0f64; n + 1];
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let meet = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64))
    };
    for q in 1..n {
        let mut s = meet(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = meet(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    (0..n)
        .map(|q| {
            while z[k + 1] < q as f64 {
                k += 1;
            }
            let dq = q as f64 - v[k] as f64;
            (dq * dq + f[v[k]]) as f32
        })
        .collect()
}

/// The best sphere for one node: (centre, radius, matter covered, space covered), the
/// covered amounts in cells.
fn fit_node(
    vox: &Voxels,
    depth: &[f32],
    members: &[u32],
    outside_weight: f32,
    candidates: usize,
) -> Option<(Vec3, f32, f64, f64)> {
    if members.is_empty() {
        return None;
    }
    let h = vox.h;
    // Matter: a strided sample of the cluster's cells, each standing for `stride` cells.
    let stride = members.len().div_ceil(4000).max(1);
    let matter: Vec<Vec3> = members
        .iter()
        .step_by(stride)
        .map(|&m| vox.center(m as usize))
        .collect();
    let w_in = members.len() as f64 / matter.len() as f64;
    // Candidate centres: the deepest cells and an even spread of the rest.
    let mut by_depth: Vec<u32> = members.to_vec();
    by_depth.sort_by(|a, b| depth[*b as usize].total_cmp(&depth[*a as usize]));
    let deep = (candidates / 4).max(1).min(by_depth.len());
    let spread = (candidates - deep).max(1);
    let mut centres: Vec<u32> = by_depth[..deep].to_vec();
    let step = members.len().div_ceil(spread).max(1);
    centres.extend(members.iter().step_by(step).copied());
    centres.sort_unstable();
    centres.dedup();
    centres
        .par_iter()
        .map(|&ci| {
            let c = vox.center(ci as usize);
            let reach = matter.iter().map(|p| p.distance(c)).fold(0f32, f32::max) + h;
            // Events along the radius: +matter, -outside space.
            let mut events: Vec<(f32, f64, f64)> =
                matter.iter().map(|p| (p.distance(c), w_in, 0.0)).collect();
            let cells = (2.0 * reach / h).powi(3);
            let s = ((cells / 60_000.0).cbrt().ceil() as usize).max(1);
            let w_out = (s * s * s) as f64;
            let [c0, c1, c2] = vox.coords(ci as usize);
            let rc = (reach / h).ceil() as usize + 1;
            let range = |c: usize, k: usize| (c.saturating_sub(rc), (c + rc).min(vox.dims[k] - 1));
            let (x0, x1) = range(c0, 0);
            let (y0, y1) = range(c1, 1);
            let (z0, z1) = range(c2, 2);
            for z in (z0..=z1).step_by(s) {
                for y in (y0..=y1).step_by(s) {
                    for x in (x0..=x1).step_by(s) {
                        let i = vox.index(x, y, z);
                        if !vox.inside[i] {
                            let d = vox.center(i).distance(c);
                            if d <= reach {
                                events.push((d, 0.0, w_out));
                            }
                        }
                    }
                }
            }
            events.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (mut matter_in, mut space_in) = (0.0, 0.0);
            let mut best = (f64::NEG_INFINITY, 0.5 * h, 0.0, 0.0);
            for &(d, m, o) in &events {
                matter_in += m;
                space_in += o;
                let score = matter_in - outside_weight as f64 * space_in;
                if score > best.0 {
                    best = (score, d + 0.5 * h, matter_in, space_in);
                }
            }
            (best.0, c, best.1.max(0.5 * h), best.2, best.3)
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, c, r, m, o)| (c, r, m, o))
}

/// Refits every used node below the root of `tree` (built for `mesh`'s bind pose) and
/// gives the spheres skin weights again.
pub fn fit_tree(
    mesh: &Mesh,
    tree: &SphereTree,
    cfg: &FitConfig,
) -> Result<(SphereTree, FitSummary)> {
    tree.check_shape()?;
    if cfg.outside_weight.is_empty() || cfg.outside_weight.iter().any(|w| w.is_nan() || *w < 0.0) {
        return Err(Error::InvalidArgument(
            "proxy fit: outside weights must be one or more non-negative numbers".into(),
        ));
    }
    let bvh = Bvh::build(&mesh.positions, &mesh.triangles);
    let vox = Voxels::new(mesh, &bvh, cfg.cells);
    let depth = vox.depth();
    let interior: Vec<u32> = (0..vox.len() as u32)
        .filter(|&i| vox.inside[i as usize])
        .collect();
    if interior.len() < 8 * tree.branch as usize {
        return Err(Error::InvalidArgument(format!(
            "proxy fit: mesh '{}' has only {} interior cells (is it closed?)",
            mesh.name,
            interior.len()
        )));
    }
    let b = tree.branch as usize;
    let leaves = tree.level_range(tree.levels - 1);
    let used: Vec<usize> = leaves.clone().filter(|&l| tree.spheres[l].used()).collect();
    // Every interior cell joins the nearest leaf's cluster; inner nodes hold their leaves'.
    let owner: Vec<usize> = interior
        .par_iter()
        .map(|&i| {
            let p = vox.center(i as usize);
            *used
                .iter()
                .min_by(|&&a, &&c| {
                    p.distance_squared(tree.spheres[a].center)
                        .total_cmp(&p.distance_squared(tree.spheres[c].center))
                })
                .expect("a used leaf")
        })
        .collect();
    let n = tree.spheres.len();
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (&cell, &leaf) in interior.iter().zip(&owner) {
        let mut node = leaf;
        while node != 0 {
            members[node].push(cell);
            node = (node - 1) / b;
        }
    }
    let mut out = tree.clone();
    let total = interior.len() as f64;
    let mut matter_covered = Vec::new();
    let mut space_covered = Vec::new();
    for level in 1..tree.levels {
        let w = cfg.outside_weight[(level as usize - 1).min(cfg.outside_weight.len() - 1)];
        let (mut m_in, mut m_all, mut o_in) = (0.0, 0.0, 0.0);
        for node in tree.level_range(level) {
            if !tree.spheres[node].used() {
                continue;
            }
            match fit_node(&vox, &depth, &members[node], w, cfg.candidates) {
                Some((c, r, m, o)) => {
                    out.spheres[node] = Sphere {
                        center: c,
                        radius: r,
                    };
                    out.importance[node] = members[node].len() as f32 / total as f32;
                    m_in += m;
                    m_all += members[node].len() as f64;
                    o_in += o;
                }
                // A cluster with no cells (a filled-in copy): it keeps its parent's sphere.
                None => {
                    let parent = (node - 1) / b;
                    out.spheres[node] = out.spheres[parent];
                }
            }
        }
        matter_covered.push(m_in / m_all.max(1.0));
        space_covered.push(o_in / total);
    }
    out.assign_skin(mesh, vox.h);
    Ok((
        out,
        FitSummary {
            cell_size: vox.h,
            interior_cells: interior.len(),
            matter_covered,
            space_covered,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::edt_1d;

    #[test]
    fn distance_transform_of_a_line() {
        let big = 1e20;
        let d = edt_1d(&[big, 0.0, big, big, big, 0.0, big]);
        assert_eq!(d, vec![1.0, 0.0, 1.0, 4.0, 1.0, 0.0, 1.0]);
        let d = edt_1d(&[0.0, big, big]);
        assert_eq!(d, vec![0.0, 1.0, 4.0]);
    }
}
