//! Triangle meshes with optional skin weights, validated on construction.
//!
//! Repairs, each counted in [`MeshReport`] (and printed in `report.json`):
//! - degenerate triangles (a repeated index or zero area) are removed;
//! - skin weights that do not sum to 1 are renormalised; more than four influences keep the
//!   four largest, renormalised;
//! - missing or zero-length normals are recomputed (area-weighted face normals).
//!
//! Errors (naming the file and the element): no triangles, a non-finite position, normal or
//! weight, a coordinate beyond [`MAX_COORDINATE`], an index out of range, a negative weight
//! or one above [`MAX_SKIN_WEIGHT`], a vertex whose weights sum to zero, a joint index beyond
//! the skeleton.
//!
//! Non-manifold edges (used by more than two triangles) and boundary edges are counted, not
//! repaired: per-vertex occlusion does not need a manifold, and the sphere-tree builder's
//! inside test takes a majority over three ray directions.

use crate::error::{Error, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

/// Largest accepted |coordinate| of a vertex, in model units (and of a sphere tree's
/// centres; of glTF node translations and scales).
///
/// Why 1e12: everything downstream works in f32 (max 3.4e38). With |x| <= 1e12 a bounding
/// box has extents <= 2e12, so squared distances (<= 1.2e25), their sums over a million
/// points (the k-means of the sphere-tree builder, <= 1.2e31), the cross products of
/// triangle areas (<= 1.6e25) and the product of three extents (<= 8e36, a bounding-box
/// volume) all stay finite with a margin; at 1e13 the box volume already overflows. The
/// bound is far beyond any real model (1e12 m is seven times the Earth-Sun distance), so it
/// only refuses corrupt or absurdly scaled files, which would otherwise turn into infinite
/// sphere radii or NaN occlusion far from the loader.
pub const MAX_COORDINATE: f32 = 1e12;

/// Largest accepted single skin weight before renormalisation. Weights are fractions that
/// should sum to 1; the loader renormalises any positive sum (exporters round, or store
/// percentages), but a weight above this is corrupt data: renormalising it in f32 would
/// overflow the sum (3e38 + 3e38 = inf) and give NaN or zero weights.
pub const MAX_SKIN_WEIGHT: f32 = 1e3;

/// Up to four joint influences per vertex.
#[derive(Clone, Debug, Default)]
pub struct SkinWeights {
    pub joints: Vec<[u16; 4]>,
    /// Non-negative, summing to 1 per vertex.
    pub weights: Vec<[f32; 4]>,
}

/// What validation found and repaired.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MeshReport {
    pub source: String,
    pub vertices: usize,
    pub triangles: usize,
    pub degenerate_triangles_removed: usize,
    pub weights_renormalised: usize,
    pub influences_truncated: usize,
    pub normals_recomputed: usize,
    pub boundary_edges: usize,
    pub non_manifold_edges: usize,
    /// Vertices used by no triangle (kept; they get occlusion like any other).
    pub unreferenced_vertices: usize,
}

/// A validated triangle mesh.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    /// Unit length.
    pub normals: Vec<Vec3>,
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
    pub skin: Option<SkinWeights>,
    pub report: MeshReport,
}

/// Raw mesh data as a loader reads it, before validation.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    pub name: String,
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub triangles: Vec<[u32; 3]>,
    /// Per vertex, any number of (joint, weight) influences.
    pub influences: Option<Vec<Vec<(u32, f32)>>>,
    /// Number of joints that influences may refer to.
    pub joint_count: usize,
}

impl Mesh {
    /// Validates and repairs `data` read from `source` (named in every error).
    pub fn from_data(data: MeshData, source: &Path) -> Result<Mesh> {
        let err = |msg: String| Error::input(source, msg);
        let n = data.positions.len();
        let mut report = MeshReport {
            source: source.display().to_string(),
            vertices: n,
            ..Default::default()
        };
        if n == 0 || data.triangles.is_empty() {
            return Err(err(format!(
                "mesh '{}' has {n} vertices and {} triangles; need at least one triangle",
                data.name,
                data.triangles.len()
            )));
        }
        if n > u32::MAX as usize {
            return Err(err(format!("{n} vertices exceed the 32-bit index range")));
        }
        let mut positions = Vec::with_capacity(n);
        for (i, p) in data.positions.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(err(format!("vertex {i} has a non-finite position {p:?}")));
            }
            if p.iter().any(|c| c.abs() > MAX_COORDINATE) {
                return Err(err(format!(
                    "vertex {i} has position {p:?}, beyond the coordinate bound \u{b1}{MAX_COORDINATE:e} \
                     (rescale the model)"
                )));
            }
            positions.push(Vec3::from_array(*p));
        }
        let mut triangles = Vec::with_capacity(data.triangles.len());
        for (t, tri) in data.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&v| v as usize >= n) {
                return Err(err(format!(
                    "triangle {t} refers to vertex {bad}, but there are only {n} vertices"
                )));
            }
            let [a, b, c] = tri.map(|v| positions[v as usize]);
            let area2 = (b - a).cross(c - a).length();
            let scale = (b - a).length().max((c - a).length()).max(1e-30);
            if tri[0] == tri[1]
                || tri[1] == tri[2]
                || tri[0] == tri[2]
                || area2 <= 1e-12 * scale * scale
            {
                report.degenerate_triangles_removed += 1;
            } else {
                triangles.push(*tri);
            }
        }
        if triangles.is_empty() {
            return Err(err("every triangle is degenerate (zero area)".into()));
        }
        report.triangles = triangles.len();

        // Normals: given ones checked, missing or zero-length ones recomputed.
        let face_normals = area_weighted_normals(&positions, &triangles);
        let mut normals = Vec::with_capacity(n);
        match &data.normals {
            Some(given) if given.len() != n => {
                return Err(err(format!("{} normals for {n} vertices", given.len())));
            }
            Some(given) => {
                for (i, nrm) in given.iter().enumerate() {
                    if !nrm.iter().all(|c| c.is_finite()) {
                        return Err(err(format!("vertex {i} has a non-finite normal {nrm:?}")));
                    }
                    let v = Vec3::from_array(*nrm);
                    if v.length() > 1e-6 {
                        // Scaled first: the length of a huge finite normal overflows.
                        normals.push((v / v.abs().max_element()).normalize());
                    } else {
                        report.normals_recomputed += 1;
                        normals.push(face_normals[i]);
                    }
                }
            }
            None => {
                report.normals_recomputed = n;
                normals = face_normals;
            }
        }

        let uvs = match data.uvs {
            Some(uv) if uv.len() != n => {
                return Err(err(format!(
                    "{} texture coordinates for {n} vertices",
                    uv.len()
                )));
            }
            Some(uv) => {
                if let Some(i) = uv.iter().position(|t| !t.iter().all(|c| c.is_finite())) {
                    return Err(err(format!(
                        "vertex {i} has non-finite texture coordinates"
                    )));
                }
                Some(uv.into_iter().map(Vec2::from_array).collect())
            }
            None => None,
        };

        let skin = match data.influences {
            None => None,
            Some(inf) if inf.len() != n => {
                return Err(err(format!(
                    "skin weights for {} of {n} vertices",
                    inf.len()
                )));
            }
            Some(inf) => {
                Some(normalise_influences(&inf, data.joint_count, &mut report).map_err(err)?)
            }
        };

        let (boundary, non_manifold) = edge_counts(&triangles);
        report.boundary_edges = boundary;
        report.non_manifold_edges = non_manifold;
        let mut used = vec![false; n];
        for t in &triangles {
            for &v in t {
                used[v as usize] = true;
            }
        }
        report.unreferenced_vertices = used.iter().filter(|u| !**u).count();

        Ok(Mesh {
            name: data.name,
            positions,
            normals,
            uvs,
            triangles,
            skin,
            report,
        })
    }

    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds(&self.positions)
    }
}

/// Axis-aligned bounds of a point set.
pub fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}

/// Unit vertex normals from area-weighted face normals (+Z where a vertex has no area).
pub fn area_weighted_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let n = (b - a).cross(c - a); // length = twice the area
        for &v in t {
            acc[v as usize] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(Vec3::Z))
        .collect()
}

/// The result of [`four_largest`].
#[derive(Clone, Copy, Debug)]
pub struct FourLargest {
    pub joints: [u16; 4],
    /// Summing to 1.
    pub weights: [f32; 4],
    /// Distinct joints with positive weight before truncation.
    pub distinct: usize,
    /// Sum of the kept weights before renormalisation.
    pub kept_sum: f32,
}

/// The four largest influences (repeated joints merged, non-positive weights ignored),
/// renormalised to sum to 1. With no positive weight: joint 0 with weight 1.
pub fn four_largest(influences: impl IntoIterator<Item = (u16, f32)>) -> FourLargest {
    let mut merged: Vec<(u16, f32)> = Vec::new();
    for (j, w) in influences {
        if w > 0.0 {
            match merged.iter_mut().find(|e| e.0 == j) {
                Some(e) => e.1 += w,
                None => merged.push((j, w)),
            }
        }
    }
    let distinct = merged.len();
    merged.sort_by(|a, b| b.1.total_cmp(&a.1));
    merged.truncate(4);
    let kept_sum: f32 = merged.iter().map(|e| e.1).sum();
    let mut out = FourLargest {
        joints: [0; 4],
        weights: [1.0, 0.0, 0.0, 0.0],
        distinct,
        kept_sum,
    };
    if kept_sum > 0.0 {
        out.weights = [0.0; 4];
        for (k, (j, w)) in merged.iter().enumerate() {
            out.joints[k] = *j;
            out.weights[k] = w / kept_sum;
        }
    }
    out
}

fn normalise_influences(
    inf: &[Vec<(u32, f32)>],
    joint_count: usize,
    report: &mut MeshReport,
) -> std::result::Result<SkinWeights, String> {
    if joint_count > u16::MAX as usize {
        return Err(format!("{joint_count} joints exceed the supported 65535"));
    }
    let mut joints = Vec::with_capacity(inf.len());
    let mut weights = Vec::with_capacity(inf.len());
    for (v, list) in inf.iter().enumerate() {
        let mut valid: Vec<(u16, f32)> = Vec::with_capacity(list.len());
        for &(j, w) in list {
            if !w.is_finite() {
                return Err(format!("vertex {v} has a non-finite skin weight"));
            }
            if w < 0.0 {
                return Err(format!("vertex {v} has a negative skin weight {w}"));
            }
            if w > MAX_SKIN_WEIGHT {
                return Err(format!(
                    "vertex {v} has skin weight {w:e}, above the bound {MAX_SKIN_WEIGHT} \
                     (weights are fractions summing to 1)"
                ));
            }
            if w == 0.0 {
                continue;
            }
            if j as usize >= joint_count {
                return Err(format!(
                    "vertex {v} is weighted to joint {j}, but the skin has {joint_count} joints"
                ));
            }
            valid.push((j as u16, w));
        }
        if valid.is_empty() {
            return Err(format!(
                "vertex {v} has no skin weight (all weights are zero)"
            ));
        }
        let top = four_largest(valid);
        if top.distinct > 4 {
            report.influences_truncated += 1;
        }
        if (top.kept_sum - 1.0).abs() > 1e-4 {
            report.weights_renormalised += 1;
        }
        let (j4, w4) = (top.joints, top.weights);
        let sum: f32 = w4.iter().sum();
        if !w4.iter().all(|w| w.is_finite() && *w >= 0.0) || (sum - 1.0).abs() > 1e-4 {
            return Err(format!(
                "vertex {v}: its skin weights do not normalise (got {w4:?})"
            ));
        }
        joints.push(j4);
        weights.push(w4);
    }
    Ok(SkinWeights { joints, weights })
}

/// (boundary edges, non-manifold edges).
fn edge_counts(triangles: &[[u32; 3]]) -> (usize, usize) {
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(triangles.len() * 3);
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let boundary = edges.values().filter(|&&c| c == 1).count();
    let non_manifold = edges.values().filter(|&&c| c > 2).count();
    (boundary, non_manifold)
}

impl Mesh {
    /// Midpoint subdivision: every triangle becomes four; new vertices average the endpoints'
    /// positions, normals, UVs and skin influences (merged, four largest kept, renormalised).
    /// The shape is unchanged; it makes denser meshes for the vertex-count benchmarks.
    pub fn subdivide(&self) -> Mesh {
        let mut positions = self.positions.clone();
        let mut normals = self.normals.clone();
        let mut uvs = self.uvs.clone();
        let mut skin = self.skin.clone();
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut triangles = Vec::with_capacity(self.triangles.len() * 4);
        let mut midpoint = |a: u32, b: u32| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                let (ia, ib) = (a as usize, b as usize);
                positions.push((positions[ia] + positions[ib]) * 0.5);
                normals.push(
                    (normals[ia] + normals[ib])
                        .try_normalize()
                        .unwrap_or(normals[ia]),
                );
                if let Some(uv) = uvs.as_mut() {
                    uv.push((uv[ia] + uv[ib]) * 0.5);
                }
                if let Some(s) = skin.as_mut() {
                    let sk: &SkinWeights = s;
                    let top = four_largest([ia, ib].into_iter().flat_map(|v| {
                        (0..4).map(move |k| (sk.joints[v][k], 0.5 * sk.weights[v][k]))
                    }));
                    let (j4, w4) = (top.joints, top.weights);
                    s.joints.push(j4);
                    s.weights.push(w4);
                }
                (positions.len() - 1) as u32
            })
        };
        for &[a, b, c] in &self.triangles {
            let (ab, bc, ca) = (midpoint(a, b), midpoint(b, c), midpoint(c, a));
            triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        let mut report = self.report.clone();
        report.vertices = positions.len();
        report.triangles = triangles.len();
        Mesh {
            name: format!("{} (subdivided)", self.name),
            positions,
            normals,
            uvs,
            triangles,
            skin,
            report,
        }
    }
}
