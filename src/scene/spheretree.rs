//! Sphere trees: the Dublin Sphere-Tree Construction Toolkit's `.sph` format, a builder, and
//! per-sphere skin weights.
//!
//! Layout (as in `.sph`): a flat array over all levels, root first; the children of node `n`
//! are `n*B+1 ..= n*B+B`; a negative radius marks an unused slot.
//!
//! The builder approximates the *volume* of the mesh (ambient occlusion is cast by solid
//! matter, so a sphere should stand for the matter it replaces):
//! 1. voxelise the bind-pose mesh: cell centres classified inside/outside by ray parity along
//!    the three axes, majority vote (robust to small holes and non-manifold edges);
//! 2. split the interior cells hierarchically with k-means (k = branch factor per node);
//! 3. fit one sphere per cluster at its centroid. `Fit::Volume` (default): the radius of the
//!    sphere with the cluster's volume. `Fit::Bounding`: the smallest radius around the
//!    centroid that covers the cluster's cells (and, for parents, the children), the
//!    conservative collision-detection choice of the Dublin toolkit.
//!
//! A mesh with no interior (open surfaces) falls back to clustering surface samples with
//! bounding spheres, which the report states.

use super::mesh::{MAX_COORDINATE, Mesh, four_largest};
use crate::error::{Error, Result};
use crate::geom::{Bvh, Rng};
use glam::Vec3;
use rayon::prelude::*;
use std::path::Path;

/// One node of a tree. A negative radius marks an unused slot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub center: Vec3,
    pub radius: f32,
}

impl Sphere {
    pub fn used(&self) -> bool {
        self.radius >= 0.0
    }
}

/// A complete B-ary sphere tree with skin weights per sphere.
#[derive(Clone, Debug)]
pub struct SphereTree {
    /// Levels including the root (the report's 8/64/512 tree has 4).
    pub levels: u32,
    pub branch: u32,
    pub spheres: Vec<Sphere>,
    /// The `.sph` importance column (the builder writes each cluster's share of the volume).
    pub importance: Vec<f32>,
    /// Skin influences per sphere (from the vertices it covers); filled by `assign_skin`.
    pub joints: Vec<[u16; 4]>,
    pub weights: Vec<[f32; 4]>,
}

/// How spheres are fitted to clusters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Fit {
    /// Same volume as the cluster: approximates the matter (default, best for occlusion).
    Volume,
    /// Covers the cluster: conservative, over-occludes.
    Bounding,
}

/// Most interior samples [`SphereTree::build`] clusters (the grid holds about three times
/// as many cells, 4 bytes each, and the clustering keeps the samples).
pub const MAX_BUILD_SAMPLES: usize = 20_000_000;

/// Builder settings.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BuildConfig {
    /// Levels below the root (3 gives 8/64/512).
    pub depth: u32,
    pub branch: u32,
    pub fit: Fit,
    /// Approximate number of interior cells to cluster, 1000 to [`MAX_BUILD_SAMPLES`].
    pub samples: usize,
    pub seed: u64,
}

impl Default for BuildConfig {
    fn default() -> Self {
        BuildConfig {
            depth: 3,
            branch: 8,
            fit: Fit::Volume,
            samples: 200_000,
            seed: 1,
        }
    }
}

/// How well one level of the tree fits the mesh.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelFit {
    pub level: u32,
    pub spheres: usize,
    /// Fraction of the mesh's volume inside the union of the level's spheres.
    pub volume_coverage: f64,
    /// Volume of the union outside the mesh, as a fraction of the mesh's volume.
    pub volume_excess: f64,
    /// Fraction of the mesh's vertices inside (or within one cell of) the union.
    pub surface_coverage: f64,
}

/// What `spheretree build` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitReport {
    pub config: BuildConfig,
    /// "volume" (interior cells) or "surface" (open mesh fallback).
    pub samples_from: &'static str,
    pub interior_cells: usize,
    pub cell_size: f32,
    pub mesh_volume: f64,
    pub levels: Vec<LevelFit>,
}

fn node_count(levels: u32, branch: u32) -> Option<usize> {
    let mut total = 0usize;
    let mut width = 1usize;
    for _ in 0..levels {
        total = total.checked_add(width)?;
        width = width.checked_mul(branch as usize)?;
    }
    Some(total)
}

impl SphereTree {
    /// Index range of the nodes at `level` (0 = root).
    pub fn level_range(&self, level: u32) -> std::ops::Range<usize> {
        let b = self.branch as usize;
        let start = node_count(level, self.branch).unwrap_or(0);
        start..start + b.pow(level)
    }

    /// Index range of the children of node `n` (empty at the last level).
    pub fn children(&self, n: usize) -> std::ops::Range<usize> {
        let b = self.branch as usize;
        let first = n * b + 1;
        if first >= self.spheres.len() {
            first..first
        } else {
            first..first + b
        }
    }

    /// Checks that the arrays form a complete tree of `levels` levels (two or more).
    pub fn check_shape(&self) -> Result<()> {
        let n = node_count(self.levels, self.branch);
        if self.levels < 2 || self.branch < 2 || n != Some(self.spheres.len()) {
            return Err(Error::InvalidArgument(format!(
                "sphere tree of {} levels, branch {}, has {} nodes; a complete tree of two or more levels needs {:?}",
                self.levels,
                self.branch,
                self.spheres.len(),
                n
            )));
        }
        if self.importance.len() != self.spheres.len() {
            return Err(Error::InvalidArgument(
                "sphere tree importance column has the wrong length".into(),
            ));
        }
        Ok(())
    }

    /// Makes every used inner node have a used child: where all children of a used node are
    /// unused, its sphere is copied into its first child (down to the leaves), so a cut that
    /// refines the node still sees it. Returns how many nodes were filled in.
    pub fn fill_empty_children(&mut self) -> usize {
        let b = self.branch as usize;
        let first_leaf = node_count(self.levels - 1, self.branch).unwrap_or(0);
        let mut filled = 0;
        for n in 0..first_leaf {
            let kids = n * b + 1..n * b + 1 + b;
            if self.spheres[n].used() && !self.spheres[kids.clone()].iter().any(Sphere::used) {
                self.spheres[kids.start] = self.spheres[n];
                self.importance[kids.start] = self.importance[n];
                filled += 1;
            }
        }
        filled
    }

    /// Number of used spheres at `level`.
    pub fn used_at(&self, level: u32) -> usize {
        self.spheres[self.level_range(level)]
            .iter()
            .filter(|s| s.used())
            .count()
    }

    /// Largest accepted |centre coordinate| and radius of a sphere: the mesh bound
    /// [`MAX_COORDINATE`] with room for a bounding sphere around a box of that size
    /// (radius up to sqrt(3) x its half-diagonal), so squared distances stay finite in f32.
    pub const MAX_EXTENT: f32 = 4.0 * MAX_COORDINATE;

    /// The first used sphere whose centre or radius is not finite or beyond
    /// [`SphereTree::MAX_EXTENT`], as an error message.
    fn check_values(&self) -> std::result::Result<(), String> {
        for (i, s) in self.spheres.iter().enumerate() {
            let bad = !s.center.is_finite()
                || !s.radius.is_finite()
                || s.center.abs().max_element() > Self::MAX_EXTENT
                || s.radius > Self::MAX_EXTENT;
            if bad {
                return Err(format!(
                    "node {i} has centre {:?} and radius {}: not finite or beyond the bound {:e}",
                    s.center.to_array(),
                    s.radius,
                    Self::MAX_EXTENT
                ));
            }
        }
        if let Some(i) = self.importance.iter().position(|x| !x.is_finite()) {
            return Err(format!("node {i} has a non-finite importance"));
        }
        Ok(())
    }

    /// Reads a `.sph` file: `levels branch`, then `x y z r importance` per node.
    pub fn read_sph(path: &Path) -> Result<SphereTree> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::parse_sph(path, &bytes)
    }

    /// As [`SphereTree::read_sph`], from memory; `path` only names the source in errors.
    /// Every number must be finite, centres and radii within [`SphereTree::MAX_EXTENT`].
    pub fn parse_sph(path: &Path, bytes: &[u8]) -> Result<SphereTree> {
        let text =
            std::str::from_utf8(bytes).map_err(|_| Error::input(path, "not a UTF-8 text file"))?;
        let mut tokens = text.split_whitespace();
        let mut header = |what: &str| -> Result<u32> {
            let t = tokens
                .next()
                .ok_or_else(|| Error::input(path, format!("missing {what} in the header")))?;
            t.parse()
                .map_err(|_| Error::input(path, format!("{what} '{t}' is not a whole number")))
        };
        let levels = header("level count")?;
        let branch = header("branch factor")?;
        if !(2..=8).contains(&levels) || !(2..=16).contains(&branch) {
            return Err(Error::input(
                path,
                format!(
                    "{levels} levels with branch factor {branch}: expected 2..=8 levels, branch 2..=16"
                ),
            ));
        }
        let n = node_count(levels, branch)
            .filter(|&n| n <= 1 << 22)
            .ok_or_else(|| Error::input(path, "tree too large"))?;
        // Counted before collecting: a tree's size is bounded above, the file's is not.
        let values: Vec<&str> = tokens.by_ref().take(n * 5 + 1).collect();
        if values.len() != n * 5 {
            return Err(Error::input(
                path,
                format!(
                    "{levels} levels x branch {branch} need exactly {n} nodes (5 numbers each), the file has {}",
                    if values.len() > n * 5 {
                        format!("more than {} numbers", n * 5)
                    } else {
                        format!("{} numbers", values.len())
                    }
                ),
            ));
        }
        let mut spheres = Vec::with_capacity(n);
        let mut importance = Vec::with_capacity(n);
        for i in 0..n {
            let mut f = [0f32; 5];
            for (k, v) in f.iter_mut().enumerate() {
                let t = values[i * 5 + k];
                *v = t
                    .parse()
                    .ok()
                    .filter(|x: &f32| x.is_finite())
                    .ok_or_else(|| {
                        Error::input(path, format!("node {i}: '{t}' is not a finite number"))
                    })?;
            }
            spheres.push(Sphere {
                center: Vec3::new(f[0], f[1], f[2]),
                radius: f[3],
            });
            importance.push(f[4]);
        }
        if !spheres[0].used() {
            return Err(Error::input(
                path,
                "the root sphere is unused (negative radius)",
            ));
        }
        let mut tree = SphereTree {
            levels,
            branch,
            spheres,
            importance,
            joints: vec![[0; 4]; n],
            weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
        };
        // Children of an unused node are unused, whatever the file says; a used node whose
        // children are all unused gets its own sphere as a child (documented repair).
        for i in 1..n {
            let parent = (i - 1) / branch as usize;
            if !tree.spheres[parent].used() {
                tree.spheres[i].radius = -1.0;
            }
        }
        tree.fill_empty_children();
        tree.check_values().map_err(|m| Error::input(path, m))?;
        Ok(tree)
    }

    /// Writes the `.sph` format (atomically). A non-finite or out-of-bound sphere is an
    /// error naming the file and the node; nothing is written then.
    pub fn write_sph(&self, path: &Path) -> Result<()> {
        self.check_values()
            .map_err(|m| Error::input(path, format!("not written: {m}")))?;
        let mut s = format!("{} {}\n", self.levels, self.branch);
        for (sp, imp) in self.spheres.iter().zip(&self.importance) {
            s.push_str(&format!(
                "{:.7} {:.7} {:.7} {:.7} {:.7}\n",
                sp.center.x, sp.center.y, sp.center.z, sp.radius, imp
            ));
        }
        crate::io::write_atomic(path, s.as_bytes())
    }

    /// Gives each sphere the skin weights of the bind-pose vertices it covers (within its
    /// radius plus `slack`); a sphere covering none takes its eight nearest vertices.
    pub fn assign_skin(&mut self, mesh: &Mesh, slack: f32) {
        let Some(skin) = &mesh.skin else {
            return;
        };
        let result: Vec<([u16; 4], [f32; 4])> =
            self.spheres
                .par_iter()
                .map(|s| {
                    if !s.used() {
                        return ([0; 4], [1.0, 0.0, 0.0, 0.0]);
                    }
                    let mut covered: Vec<usize> = mesh
                        .positions
                        .iter()
                        .enumerate()
                        .filter(|(_, p)| p.distance(s.center) <= s.radius + slack)
                        .map(|(i, _)| i)
                        .collect();
                    if covered.is_empty() {
                        let mut by_dist: Vec<(f32, usize)> = mesh
                            .positions
                            .iter()
                            .enumerate()
                            .map(|(i, p)| (p.distance_squared(s.center), i))
                            .collect();
                        let k = 8.min(by_dist.len());
                        by_dist.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
                        covered = by_dist[..k].iter().map(|e| e.1).collect();
                    }
                    let top = four_largest(covered.iter().flat_map(|&v| {
                        (0..4).map(move |k| (skin.joints[v][k], skin.weights[v][k]))
                    }));
                    (top.joints, top.weights)
                })
                .collect();
        self.joints = result.iter().map(|r| r.0).collect();
        self.weights = result.iter().map(|r| r.1).collect();
    }

    /// Builds a tree for `mesh` (bind pose) and reports how well each level fits.
    pub fn build(mesh: &Mesh, cfg: &BuildConfig) -> Result<(SphereTree, FitReport)> {
        if !(1..=6).contains(&cfg.depth) || !(2..=16).contains(&cfg.branch) {
            return Err(Error::InvalidArgument(format!(
                "depth {} / branch {}: expected depth 1..=6 and branch 2..=16",
                cfg.depth, cfg.branch
            )));
        }
        if !(1000..=MAX_BUILD_SAMPLES).contains(&cfg.samples) {
            return Err(Error::InvalidArgument(format!(
                "--samples {}: a tree is fitted to 1000 to {MAX_BUILD_SAMPLES} interior samples",
                cfg.samples
            )));
        }
        let levels = cfg.depth + 1;
        let n = node_count(levels, cfg.branch)
            .filter(|&n| n <= 1 << 20)
            .ok_or_else(|| Error::InvalidArgument("tree too large".into()))?;
        let bvh = Bvh::build(&mesh.positions, &mesh.triangles);
        let (lo, hi) = mesh.bounds();
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        // Cell size so that the bounding box holds ~3x the requested samples (the volume in
        // f64: three extents of a large mesh multiply beyond f32).
        let e64 = extent.as_dvec3();
        let h = ((e64.x * e64.y * e64.z / (3.0 * cfg.samples as f64)).cbrt() as f32)
            .max(extent.max_element() / 400.0);
        let grid = Grid::new(lo - Vec3::splat(h), hi + Vec3::splat(h), h);
        let inside = grid.classify(&bvh);
        let mut points: Vec<Vec3> = inside
            .iter()
            .enumerate()
            .filter(|(_, inn)| **inn)
            .map(|(i, _)| grid.center(i))
            .collect();
        let interior_cells = points.len();
        let from_volume = interior_cells >= 8 * cfg.branch as usize;
        let fit = if from_volume { cfg.fit } else { Fit::Bounding };
        if !from_volume {
            points = surface_samples(mesh, cfg.samples, cfg.seed);
        }
        let cell_volume = if from_volume { (h as f64).powi(3) } else { 0.0 };

        let mut spheres = vec![
            Sphere {
                center: Vec3::ZERO,
                radius: -1.0
            };
            n
        ];
        let mut importance = vec![0f32; n];
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); n];
        members[0] = (0..points.len() as u32).collect();
        let total = points.len() as f32;
        let branch = cfg.branch as usize;
        for level in 0..levels {
            let first = node_count(level, cfg.branch).expect("bounded above");
            let count = branch.pow(level);
            // Split this level's clusters into the next level's (in parallel per node).
            let children: Vec<(usize, Vec<Vec<u32>>)> = (first..first + count)
                .into_par_iter()
                .filter(|&i| !members[i].is_empty() && level + 1 < levels)
                .map(|i| {
                    (
                        i,
                        kmeans(&points, &members[i], branch, cfg.seed ^ (i as u64) << 8),
                    )
                })
                .collect();
            for i in first..first + count {
                let m = &members[i];
                if m.is_empty() {
                    continue;
                }
                let c = m.iter().map(|&p| points[p as usize]).sum::<Vec3>() / m.len() as f32;
                let r = match fit {
                    Fit::Volume => (3.0 * m.len() as f64 * cell_volume
                        / (4.0 * std::f64::consts::PI))
                        .cbrt() as f32,
                    Fit::Bounding => {
                        m.iter()
                            .map(|&p| points[p as usize].distance(c))
                            .fold(0.0, f32::max)
                            + if from_volume {
                                0.5 * 3f32.sqrt() * h
                            } else {
                                0.0
                            }
                    }
                };
                spheres[i] = Sphere {
                    center: c,
                    radius: r,
                };
                importance[i] = m.len() as f32 / total;
            }
            for (i, kids) in children {
                for (k, kid) in kids.into_iter().enumerate() {
                    members[i * branch + 1 + k] = kid;
                }
            }
        }
        if fit == Fit::Bounding {
            // Parents cover their children.
            for i in (0..n).rev() {
                let parent = if i == 0 { continue } else { (i - 1) / branch };
                if spheres[i].used() {
                    let need =
                        spheres[i].center.distance(spheres[parent].center) + spheres[i].radius;
                    spheres[parent].radius = spheres[parent].radius.max(need);
                }
            }
        }
        let mut tree = SphereTree {
            levels,
            branch: cfg.branch,
            spheres,
            importance,
            joints: vec![[0; 4]; n],
            weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
        };
        tree.fill_empty_children();
        tree.check_values().map_err(|m| {
            Error::input(
                &mesh.report.source,
                format!("the sphere tree built for this mesh is unusable: {m}"),
            )
        })?;
        tree.assign_skin(mesh, h);
        let report = FitReport {
            config: cfg.clone(),
            samples_from: if from_volume { "volume" } else { "surface" },
            interior_cells,
            cell_size: h,
            mesh_volume: interior_cells as f64 * (h as f64).powi(3),
            levels: tree.fit_levels(mesh, &bvh, h),
        };
        Ok((tree, report))
    }

    /// Per-level fit of this tree to `mesh` (bind pose), measured on a grid of cell size `h`
    /// covering the mesh and every sphere.
    pub fn fit_levels(&self, mesh: &Mesh, bvh: &Bvh, h: f32) -> Vec<LevelFit> {
        let (mut lo, mut hi) = mesh.bounds();
        for s in self.spheres.iter().filter(|s| s.used()) {
            lo = lo.min(s.center - Vec3::splat(s.radius));
            hi = hi.max(s.center + Vec3::splat(s.radius));
        }
        // Cap the grid at ~8M cells (the volume in f64, as in the builder).
        let e = (hi - lo).as_dvec3();
        let h = h.max((e.x * e.y * e.z / 8.0e6).cbrt() as f32);
        let grid = Grid::new(lo - Vec3::splat(h), hi + Vec3::splat(h), h);
        let inside = grid.classify(bvh);
        let volume_cells = inside.iter().filter(|&&b| b).count().max(1) as f64;
        (1..self.levels)
            .map(|level| {
                let spheres: Vec<Sphere> = self.spheres[self.level_range(level)]
                    .iter()
                    .copied()
                    .filter(Sphere::used)
                    .collect();
                let mut in_union = vec![false; inside.len()];
                for s in &spheres {
                    grid.mark_sphere(s, &mut in_union);
                }
                let covered = inside
                    .iter()
                    .zip(&in_union)
                    .filter(|(a, b)| **a && **b)
                    .count();
                let excess = inside
                    .iter()
                    .zip(&in_union)
                    .filter(|(a, b)| !**a && **b)
                    .count();
                let near = mesh
                    .positions
                    .par_iter()
                    .filter(|p| spheres.iter().any(|s| p.distance(s.center) <= s.radius + h))
                    .count();
                LevelFit {
                    level,
                    spheres: spheres.len(),
                    volume_coverage: covered as f64 / volume_cells,
                    volume_excess: excess as f64 / volume_cells,
                    surface_coverage: near as f64 / mesh.positions.len() as f64,
                }
            })
            .collect()
    }
}

/// A regular grid of cell centres.
struct Grid {
    lo: Vec3,
    h: f32,
    dims: [usize; 3],
}

impl Grid {
    fn new(lo: Vec3, hi: Vec3, h: f32) -> Grid {
        let d = ((hi - lo) / h).ceil();
        Grid {
            lo,
            h,
            dims: [
                d.x.max(1.0) as usize,
                d.y.max(1.0) as usize,
                d.z.max(1.0) as usize,
            ],
        }
    }

    fn len(&self) -> usize {
        self.dims.iter().product()
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    fn center(&self, i: usize) -> Vec3 {
        let x = i % self.dims[0];
        let y = (i / self.dims[0]) % self.dims[1];
        let z = i / (self.dims[0] * self.dims[1]);
        self.lo + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * self.h
    }

    /// Inside/outside per cell: ray parity along each axis, majority of three votes.
    fn classify(&self, bvh: &Bvh) -> Vec<bool> {
        let mut votes = vec![0u8; self.len()];
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let lines: Vec<(usize, usize, Vec<f32>)> = (0..self.dims[u] * self.dims[v])
                .into_par_iter()
                .map_init(Vec::new, |hits, k| {
                    let (iu, iv) = (k % self.dims[u], k / self.dims[u]);
                    let mut o = self.lo;
                    o[u] += (iu as f32 + 0.5) * self.h;
                    o[v] += (iv as f32 + 0.5) * self.h;
                    // Slightly off the cell centres' plane to avoid grazing shared edges.
                    o[u] += 1.3e-4 * self.h;
                    o[v] += 0.7e-4 * self.h;
                    let mut d = Vec3::ZERO;
                    d[axis] = 1.0;
                    bvh.all_hits(o, d, hits);
                    hits.sort_by(f32::total_cmp);
                    (iu, iv, hits.clone())
                })
                .collect();
            for (iu, iv, hits) in lines {
                for s in 0..self.dims[axis] {
                    let t = (s as f32 + 0.5) * self.h;
                    let crossings = hits.partition_point(|&x| x < t);
                    if crossings % 2 == 1 {
                        let mut c = [0; 3];
                        c[axis] = s;
                        c[u] = iu;
                        c[v] = iv;
                        votes[self.index(c)] += 1;
                    }
                }
            }
        }
        votes.into_iter().map(|v| v >= 2).collect()
    }

    /// Sets the cells whose centres lie inside `s`.
    fn mark_sphere(&self, s: &Sphere, cells: &mut [bool]) {
        let lo = ((s.center - Vec3::splat(s.radius) - self.lo) / self.h - 0.5).floor();
        let hi = ((s.center + Vec3::splat(s.radius) - self.lo) / self.h - 0.5).ceil();
        let clamp = |v: f32, k: usize| (v.max(0.0) as usize).min(self.dims[k] - 1);
        let r2 = s.radius * s.radius;
        for z in clamp(lo.z, 2)..=clamp(hi.z, 2) {
            for y in clamp(lo.y, 1)..=clamp(hi.y, 1) {
                for x in clamp(lo.x, 0)..=clamp(hi.x, 0) {
                    let i = self.index([x, y, z]);
                    if self.center(i).distance_squared(s.center) <= r2 {
                        cells[i] = true;
                    }
                }
            }
        }
    }
}

/// Area-weighted random points on the mesh surface.
fn surface_samples(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3> {
    let areas: Vec<f32> = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let mut cdf = Vec::with_capacity(areas.len());
    let mut acc = 0.0;
    for a in &areas {
        acc += a;
        cdf.push(acc);
    }
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let x = rng.f32() * acc;
            let t = cdf.partition_point(|&c| c < x).min(areas.len() - 1);
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
            let (mut u, mut v) = (rng.f32(), rng.f32());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            a + (b - a) * u + (c - a) * v
        })
        .collect()
}

/// k-means (k-means++ seeding, Lloyd iterations) of `points[members]` into at most `k`
/// non-empty clusters.
fn kmeans(points: &[Vec3], members: &[u32], k: usize, seed: u64) -> Vec<Vec<u32>> {
    let k = k.min(members.len());
    let mut rng = Rng::new(seed);
    let p = |i: u32| points[i as usize];
    let mut centres = vec![p(members[rng.below(members.len())])];
    let mut d2: Vec<f32> = members
        .iter()
        .map(|&m| p(m).distance_squared(centres[0]))
        .collect();
    while centres.len() < k {
        let sum: f32 = d2.iter().sum();
        let next = if sum > 0.0 {
            let mut x = rng.f32() * sum;
            let mut pick = members.len() - 1;
            for (i, d) in d2.iter().enumerate() {
                if x < *d {
                    pick = i;
                    break;
                }
                x -= d;
            }
            pick
        } else {
            rng.below(members.len())
        };
        let c = p(members[next]);
        centres.push(c);
        for (d, &m) in d2.iter_mut().zip(members) {
            *d = d.min(p(m).distance_squared(c));
        }
    }
    let mut assign = vec![0usize; members.len()];
    for _ in 0..30 {
        let mut changed = false;
        for (a, &m) in assign.iter_mut().zip(members) {
            let q = p(m);
            let best = (0..centres.len())
                .min_by(|&i, &j| {
                    q.distance_squared(centres[i])
                        .total_cmp(&q.distance_squared(centres[j]))
                })
                .expect("k >= 1");
            if best != *a {
                *a = best;
                changed = true;
            }
        }
        let mut sums = vec![(Vec3::ZERO, 0usize); centres.len()];
        for (&a, &m) in assign.iter().zip(members) {
            sums[a].0 += p(m);
            sums[a].1 += 1;
        }
        for (c, (s, n)) in centres.iter_mut().zip(&sums) {
            if *n > 0 {
                *c = *s / *n as f32;
            }
        }
        if !changed {
            break;
        }
    }
    let mut clusters = vec![Vec::new(); centres.len()];
    for (&a, &m) in assign.iter().zip(members) {
        clusters[a].push(m);
    }
    clusters.retain(|c| !c.is_empty());
    clusters
}
