//! Texture-space geometry: a mesh rasterised into its UV layout on the CPU.
//!
//! Per texel (row-major, v down the rows, texel (x, y) centred at ((x + 0.5)/N, (y + 0.5)/N)):
//! surface position (mm), interpolated unit normal, and the Jacobian J = [dP/du dP/dv]
//! (mm per UV unit, constant over a triangle, exact from the triangle's edges), from which
//! the texel's surface area |dP/du x dP/dv| / N^2 follows. A texel belongs to the triangle
//! whose UV footprint contains its centre (top-left fill rule, so neighbouring triangles of
//! one chart never both claim a texel).
//!
//! Errors (naming the mesh): no UVs, a UV outside [0, 1], a triangle of zero UV area (it has
//! surface but no texels).
//!
//! A unique atlas (counted in [`TexReport`]): texture-space passes need one texel per surface
//! point, and real meshes reuse UV space (mirrored halves, stacked copies, folds). Triangles
//! are grouped into charts (connected through shared vertices, split by the sign of their UV
//! winding, so a mirrored half is its own chart). A chart that overlaps itself at more than 1%
//! of its texels is split into pieces that do not (breadth-first, each triangle joining the
//! first piece it does not overlap); up to 1% (one texel of a folded sliver) is counted and
//! the texel keeps the first triangle. Where charts overlap, two layouts are considered: the
//! charts placed greedily, largest first, into the first of L layers where their texels are
//! free, the layers side by side (u' = (layer + u) / L: 1/L of the texel density, along u),
//! or the charts' UV boxes packed at one scale s into the square (s^2 of the density,
//! isotropic; boxes 3 texels apart); the packing is used where it keeps [`PACK_GAIN`] times
//! the density of the layers
//! ([`TexReport::layout`], [`TexReport::density`]). Without overlap the layout is the mesh's
//! own. The Jacobian carries any anisotropy. Results map back to the mesh's own UVs with
//! [`TexGeometry::to_source_layout`].
//!
//! Gutters: texels within [`GUTTER`] texels of a covered one copy the geometry of the nearest
//! covered texel (ring by ring), flagged as gutter (area 0): irradiance computed there
//! repeats the chart's border, so bilinear lookups at chart borders stay on the surface.
//!
//! Computed on the CPU: once for a static mesh, and once for a skinned mesh's rest pose (the
//! UV layout, and so the overlap repair, is the same in every pose): the SSS kernel computes
//! each pose's texel positions, normals and areas on the GPU from this layout
//! (`kernels::sss::posed`); this rasterisation of a mesh posed by [`posed`] is their CPU
//! twin.

use crate::error::{Error, Result};
use crate::scene::Mesh;
use glam::{DVec2, DVec3, Vec2, Vec3};
use std::collections::HashMap;

/// [`TexGeometry::texel_tri`] of an empty texel.
pub const NO_TRIANGLE: u32 = u32::MAX;
/// Gutter width in texels.
pub const GUTTER: u32 = 4;

/// Flag in `pos.w`.
pub const COVERED: f32 = 1.0;
pub const GUTTER_FLAG: f32 = 0.5;

/// The texture-space layout of a mesh's surface (see [`TexReport::layout`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum Layout {
    /// The mesh's own UVs (they do not overlap).
    #[default]
    Original,
    /// Overlapping charts moved into L layers laid side by side (u' = (layer + u) / L).
    Layers,
    /// Overlapping charts packed at one scale into a unique atlas (each chart's UV box moved,
    /// not rotated; split charts first where a chart overlaps itself).
    Packed,
}

#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct TexReport {
    pub size: u32,
    pub triangles: usize,
    pub charts: usize,
    /// Charts that overlapped themselves beyond 1% of their texels (folded or stacked UVs in
    /// one connected piece) and were split into pieces that do not (counted in `charts`).
    pub split_charts: usize,
    /// Charts whose UV winding is negative (mirrored).
    pub mirrored_charts: usize,
    /// Texel centres claimed by more than one triangle in the original layout.
    pub overlapping_texels: usize,
    /// Texel centres claimed twice inside one chart (a fold; up to 1% of the chart's texels
    /// is accepted: the first triangle keeps the texel, the other loses that sample).
    pub self_overlap_texels: usize,
    /// Texel centres of the layout used that a second triangle also covers (it loses the
    /// sample): what the accepted self-overlap costs; 0 in a perfectly unique atlas.
    pub lost_texels: usize,
    /// Layers a side-by-side repair needs (1: the UVs do not overlap).
    pub layers: usize,
    /// The layout the texture-space passes use.
    pub layout: Layout,
    /// Texels per unit of the original UV area in that layout, relative to the original
    /// (1: unchanged; 1/L for L layers side by side; s^2 for charts packed at scale s).
    pub density: f64,
    pub covered_texels: usize,
    pub gutter_texels: usize,
    /// Total surface area of the mesh (mm^2) and the area the covered texels account for.
    pub mesh_area_mm2: f64,
    pub texel_area_mm2: f64,
}

/// The rasterised texture-space geometry.
#[derive(Clone, Debug)]
pub struct TexGeometry {
    pub size: u32,
    /// xyz position (mm), w: [`COVERED`], [`GUTTER_FLAG`] or 0 (empty).
    pub pos: Vec<[f32; 4]>,
    /// xyz unit normal, w: texel surface area (mm^2; 0 in gutters and empty texels).
    pub nrm: Vec<[f32; 4]>,
    /// dP/du (mm per UV unit), w 0.
    pub dpdu: Vec<[f32; 4]>,
    /// dP/dv.
    pub dpdv: Vec<[f32; 4]>,
    /// The triangle under the texel and the barycentrics of its centre: (triangle, w1 bits,
    /// w2 bits, 0) with w0 = 1 - w1 - w2; [`NO_TRIANGLE`] in empty texels; gutters copy
    /// their source texel's. The irradiance pass interpolates per-vertex shadowing with it.
    pub texel_tri: Vec<[u32; 4]>,
    /// The atlas UV of each triangle corner (after any repair).
    pub corner_uvs: Vec<[Vec2; 3]>,
    /// The mesh's own UV of each triangle corner (what a renderer textures with; equal to
    /// `corner_uvs` in the original layout).
    pub source_uvs: Vec<[Vec2; 3]>,
    /// Positions (mm) and triangles the geometry was made from (for shadow rays and views).
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub report: TexReport,
}

fn edge(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

/// [`edge`] evaluated with the endpoints in a canonical order, so the two triangles sharing
/// an edge get exactly opposite values (and the fill rule gives each centre one owner).
fn edge_exact(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    if (a.x, a.y) <= (b.x, b.y) {
        edge(a, b, p)
    } else {
        -edge(b, a, p)
    }
}

/// Top-left rule for a counter-clockwise (positive-area) triangle in a y-down raster: an
/// edge owns the centres exactly on it if it is a top edge or a left edge.
fn owns(a: DVec2, b: DVec2) -> bool {
    let d = b - a;
    (d.y == 0.0 && d.x < 0.0) || d.y > 0.0
}

/// Texel centres (index, barycentrics) covered by the UV triangle `t` (in texel units).
fn raster(t: [DVec2; 3], n: u32, mut out: impl FnMut(usize, [f64; 3])) {
    let area = edge(t[0], t[1], t[2]);
    // Orient counter-clockwise (positive area) for one fill rule.
    let (t, flip) = if area < 0.0 {
        ([t[0], t[2], t[1]], true)
    } else {
        (t, false)
    };
    let area = area.abs();
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    let x0 = (lo.x - 0.5).ceil().max(0.0) as i64;
    let y0 = (lo.y - 0.5).ceil().max(0.0) as i64;
    let x1 = ((hi.x - 0.5).floor() as i64).min(n as i64 - 1);
    let y1 = ((hi.y - 0.5).floor() as i64).min(n as i64 - 1);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            let w = [
                edge_exact(t[1], t[2], p),
                edge_exact(t[2], t[0], p),
                edge_exact(t[0], t[1], p),
            ];
            let inside = w
                .iter()
                .zip([(t[1], t[2]), (t[2], t[0]), (t[0], t[1])])
                .all(|(&wi, (a, b))| wi > 0.0 || (wi == 0.0 && owns(a, b)));
            if inside {
                let mut b = w.map(|wi| wi / area);
                if flip {
                    b.swap(1, 2);
                }
                out((y as usize) * n as usize + x as usize, b);
            }
        }
    }
}

/// How much more texel density a packed atlas must keep than layers side by side to be
/// used. Packing moves every chart apart (more chart borders, gutters between charts 3
/// texels apart): on BCN_Epileptic's head (0.615 packed against 0.5 in two layers) the
/// vertex-shadow interpolation errs 0.045 against a ray per texel instead of 0.020, more than
/// the density buys; on Testwuson (0.087 against 0.020 in 49 layers) packing wins clearly.
pub const PACK_GAIN: f32 = 2.0;

/// Disjoint sets (union-find with path compression) over 0..n.
pub(crate) struct Dsu(pub(crate) Vec<usize>);
impl Dsu {
    pub(crate) fn new(n: usize) -> Dsu {
        Dsu((0..n).collect())
    }

    pub(crate) fn find(&mut self, i: usize) -> usize {
        let mut r = i;
        while self.0[r] != r {
            r = self.0[r];
        }
        let mut i = i;
        while self.0[i] != r {
            let next = self.0[i];
            self.0[i] = r;
            i = next;
        }
        r
    }
    pub(crate) fn union(&mut self, a: usize, b: usize) {
        let (a, b) = (self.find(a), self.find(b));
        if a != b {
            self.0[a.max(b)] = a.min(b);
        }
    }
}

/// Packs boxes (min, max in UV) into the unit square at the largest common scale found (a
/// shelf packer, tallest first, `pad` between boxes and at the borders), by bisection on
/// the scale. Returns the scale and each box's new minimum corner; `None` if nothing fits.
fn pack_boxes(boxes: &[(Vec2, Vec2)], pad: f32) -> Option<(f32, Vec<Vec2>)> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| {
        let (ha, hb) = (boxes[a].1.y - boxes[a].0.y, boxes[b].1.y - boxes[b].0.y);
        hb.total_cmp(&ha).then(a.cmp(&b))
    });
    let place = |scale: f32| -> Option<Vec<Vec2>> {
        let mut out = vec![Vec2::ZERO; boxes.len()];
        let (mut x, mut y, mut shelf) = (pad, pad, 0f32);
        for &b in &order {
            let size = (boxes[b].1 - boxes[b].0) * scale;
            if x + size.x + pad > 1.0 {
                x = pad;
                y += shelf + pad;
                shelf = 0.0;
            }
            if x + size.x + pad > 1.0 || y + size.y + pad > 1.0 {
                return None;
            }
            out[b] = Vec2::new(x, y);
            x += size.x + pad;
            shelf = shelf.max(size.y);
        }
        Some(out)
    };
    let (mut lo, mut hi) = (0f32, 4f32);
    let mut best = None;
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        match place(mid) {
            Some(p) => {
                best = Some((mid, p));
                lo = mid;
            }
            None => hi = mid,
        }
    }
    best
}

/// Splits a chart that overlaps itself into pieces that do not: its triangles are visited
/// breadth-first through shared vertices (so pieces stay connected where the layout allows)
/// and each joins the first piece none of whose texels it claims. A fold puts the triangles
/// past it into a second piece, a stack of copies one piece per copy.
fn split_folded(
    chart: &[usize],
    triangles: &[[u32; 3]],
    tri_texels: &dyn Fn(usize) -> Vec<usize>,
) -> Vec<Vec<usize>> {
    let mut by_vertex: HashMap<u32, Vec<usize>> = HashMap::new();
    for &t in chart {
        for v in triangles[t] {
            by_vertex.entry(v).or_default().push(t);
        }
    }
    let mut seen: std::collections::HashSet<usize> = std::collections::HashSet::new();
    let mut order = Vec::with_capacity(chart.len());
    for &start in chart {
        if !seen.insert(start) {
            continue;
        }
        let mut queue = std::collections::VecDeque::from([start]);
        while let Some(t) = queue.pop_front() {
            order.push(t);
            for v in triangles[t] {
                for &u in &by_vertex[&v] {
                    if seen.insert(u) {
                        queue.push_back(u);
                    }
                }
            }
        }
    }
    let mut pieces: Vec<(Vec<usize>, std::collections::HashSet<usize>)> = Vec::new();
    for t in order {
        let texels = tri_texels(t);
        let k = match pieces
            .iter()
            .position(|(_, used)| texels.iter().all(|i| !used.contains(i)))
        {
            Some(k) => k,
            None => {
                pieces.push((Vec::new(), Default::default()));
                pieces.len() - 1
            }
        };
        pieces[k].0.push(t);
        pieces[k].1.extend(texels);
    }
    pieces.into_iter().map(|(p, _)| p).collect()
}

impl TexGeometry {
    /// Rasterises `mesh` (positions scaled by `mm_per_unit`) into an N x N layout.
    pub fn build(mesh: &Mesh, size: u32, mm_per_unit: f64) -> Result<TexGeometry> {
        let src = std::path::Path::new(&mesh.report.source);
        let err = |m: String| Error::input(src, format!("mesh '{}': {m}", mesh.name));
        if !(16..=8192).contains(&size) {
            return Err(Error::InvalidArgument(format!(
                "texture size {size} is not in 16..=8192"
            )));
        }
        if !(mm_per_unit.is_finite() && mm_per_unit > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "mm per model unit {mm_per_unit} must be finite and > 0"
            )));
        }
        let uvs = mesh.uvs.as_ref().ok_or_else(|| {
            err("has no texture coordinates (UVs); texture-space diffusion needs them".into())
        })?;
        if let Some(i) = uvs
            .iter()
            .position(|u| !u.is_finite() || u.x < 0.0 || u.x > 1.0 || u.y < 0.0 || u.y > 1.0)
        {
            return Err(err(format!(
                "vertex {i} has UV {:?} outside [0, 1]^2 (wrapping UVs are not supported)",
                uvs[i]
            )));
        }
        let nt = mesh.triangles.len();
        let nf = size as f64;
        let tri_uv = |t: usize| mesh.triangles[t].map(|i| uvs[i as usize].as_dvec2() * nf);
        let mut signs = vec![0i8; nt];
        for (t, s) in signs.iter_mut().enumerate() {
            let u = tri_uv(t);
            let a = edge(u[0], u[1], u[2]);
            if a.abs() < 1e-12 * nf * nf {
                return Err(err(format!(
                    "triangle {t} has zero area in UV space (it has surface but no texels)"
                )));
            }
            *s = if a > 0.0 { 1 } else { -1 };
        }
        // Charts: triangles sharing a vertex (same index => same UV) with the same winding.
        let mut dsu = Dsu::new(nt);
        let mut first_of: HashMap<(u32, i8), usize> = HashMap::new();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &v in tri {
                match first_of.get(&(v, signs[t])) {
                    Some(&o) => dsu.union(o, t),
                    None => {
                        first_of.insert((v, signs[t]), t);
                    }
                }
            }
        }
        let mut charts: HashMap<usize, Vec<usize>> = HashMap::new();
        for t in 0..nt {
            charts.entry(dsu.find(t)).or_default().push(t);
        }
        let mut charts: Vec<Vec<usize>> = charts.into_values().collect();
        charts.sort_by_key(|c| c[0]);
        // Each chart's texels; a chart claiming a texel twice overlaps itself (folded or
        // stacked UVs inside one connected piece). Up to 1% is accepted (the first triangle
        // keeps the texel); beyond, the chart is split into pieces that do not overlap
        // themselves ([`split_folded`]), which the layering then places like any chart.
        let tri_texels = |t: usize| {
            let mut texels = Vec::new();
            raster(tri_uv(t), size, |i, _| texels.push(i));
            texels
        };
        let mut chart_texels: Vec<Vec<usize>> = Vec::with_capacity(charts.len());
        let mut count = vec![0u8; (size * size) as usize];
        let mut self_overlap = 0;
        let mut split_charts = 0;
        let mut pieces: Vec<Vec<usize>> = Vec::with_capacity(charts.len());
        for chart in charts {
            let texels: Vec<usize> = chart.iter().flat_map(|&t| tri_texels(t)).collect();
            let mut sorted = texels.clone();
            sorted.sort_unstable();
            let twice = sorted.windows(2).filter(|w| w[0] == w[1]).count();
            if twice * 100 > texels.len() {
                split_charts += 1;
                for piece in split_folded(&chart, &mesh.triangles, &tri_texels) {
                    let texels: Vec<usize> = piece.iter().flat_map(|&t| tri_texels(t)).collect();
                    pieces.push(piece);
                    chart_texels.push(texels);
                }
                continue;
            }
            self_overlap += twice;
            pieces.push(chart);
            chart_texels.push(texels);
        }
        let mut charts = pieces;
        for texels in &chart_texels {
            for &i in texels {
                count[i] = count[i].saturating_add(1);
            }
        }
        let overlapping_texels = count.iter().filter(|&&c| c > 1).count();
        // Greedy layering, largest chart first.
        let mut order: Vec<usize> = (0..charts.len()).collect();
        order.sort_by_key(|&c| (std::cmp::Reverse(chart_texels[c].len()), charts[c][0]));
        let mut layers: Vec<Vec<bool>> = Vec::new();
        let mut chart_layer = vec![0usize; charts.len()];
        for &c in &order {
            let l = (0..)
                .find(|&l| l >= layers.len() || chart_texels[c].iter().all(|&i| !layers[l][i]))
                .expect("unbounded search");
            if l == layers.len() {
                layers.push(vec![false; (size * size) as usize]);
            }
            for &i in &chart_texels[c] {
                layers[l][i] = true;
            }
            chart_layer[c] = l;
        }
        let nl = layers.len().max(1);
        // With overlap, the layers side by side keep 1/L of the texel density (along u); a
        // packing of the charts' boxes at one scale s keeps s^2 (isotropic). Take the packing
        // where it keeps at least PACK_GAIN times more.
        let packed = if nl > 1 {
            let boxes: Vec<(Vec2, Vec2)> = charts
                .iter()
                .map(|chart| {
                    let mut lo = Vec2::splat(f32::MAX);
                    let mut hi = Vec2::splat(f32::MIN);
                    for &t in chart {
                        for i in mesh.triangles[t] {
                            lo = lo.min(uvs[i as usize]);
                            hi = hi.max(uvs[i as usize]);
                        }
                    }
                    (lo, hi)
                })
                .collect();
            let pad = 3.0 / size as f32;
            pack_boxes(&boxes, pad)
                .filter(|(scale, _)| scale * scale > PACK_GAIN / nl as f32)
                .map(|(scale, offsets)| (scale, offsets, boxes))
        } else {
            None
        };
        let mut corner_uvs = vec![[Vec2::ZERO; 3]; nt];
        for (c, chart) in charts.iter_mut().enumerate() {
            chart.sort_unstable();
            for &t in chart.iter() {
                corner_uvs[t] = mesh.triangles[t].map(|i| {
                    let u = uvs[i as usize];
                    match &packed {
                        Some((scale, offsets, boxes)) => (u - boxes[c].0) * *scale + offsets[c],
                        None => Vec2::new((chart_layer[c] as f32 + u.x) / nl as f32, u.y),
                    }
                });
            }
        }
        let (layout, density) = match &packed {
            Some((scale, _, _)) => (Layout::Packed, (*scale as f64).powi(2)),
            None if nl > 1 => (Layout::Layers, 1.0 / nl as f64),
            None => (Layout::Original, 1.0),
        };
        let mirrored_charts = charts.iter().filter(|c| signs[c[0]] < 0).count();

        // Rasterise the (repaired) layout.
        let positions: Vec<Vec3> = mesh
            .positions
            .iter()
            .map(|p| (p.as_dvec3() * mm_per_unit).as_vec3())
            .collect();
        let npx = (size * size) as usize;
        let mut pos = vec![[0f32; 4]; npx];
        let mut nrm = vec![[0f32; 4]; npx];
        let mut dpdu = vec![[0f32; 4]; npx];
        let mut dpdv = vec![[0f32; 4]; npx];
        let mut texel_tri = vec![[NO_TRIANGLE, 0, 0, 0]; npx];
        let mut mesh_area = 0.0;
        let mut texel_area = 0.0;
        let mut lost_texels = 0;
        for (t, (&tri, corners)) in mesh.triangles.iter().zip(&corner_uvs).enumerate() {
            let p = tri.map(|i| positions[i as usize].as_dvec3());
            let nv = tri.map(|i| mesh.normals[i as usize].as_dvec3());
            let uv = corners.map(|u| u.as_dvec2());
            let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
            let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
            let det = d1.x * d2.y - d2.x * d1.y;
            let a = (e1 * d2.y - e2 * d1.y) / det;
            let b = (e2 * d1.x - e1 * d2.x) / det;
            let area = a.cross(b).length() / (nf * nf);
            mesh_area += 0.5 * e1.cross(e2).length();
            let face_n = e1.cross(e2).normalize_or_zero();
            raster(uv.map(|u| u * nf), size, |i, w| {
                if pos[i][3] == COVERED {
                    lost_texels += 1;
                    return; // a chart's small self-overlap: the first triangle keeps it
                }
                let pp = p[0] * w[0] + p[1] * w[1] + p[2] * w[2];
                let mut n = (nv[0] * w[0] + nv[1] * w[1] + nv[2] * w[2]).normalize_or_zero();
                if n == DVec3::ZERO {
                    n = face_n;
                }
                pos[i] = [pp.x as f32, pp.y as f32, pp.z as f32, COVERED];
                nrm[i] = [n.x as f32, n.y as f32, n.z as f32, area as f32];
                dpdu[i] = [a.x as f32, a.y as f32, a.z as f32, 0.0];
                dpdv[i] = [b.x as f32, b.y as f32, b.z as f32, 0.0];
                texel_tri[i] = [
                    t as u32,
                    (w[1] as f32).to_bits(),
                    (w[2] as f32).to_bits(),
                    0,
                ];
                texel_area += area;
            });
        }
        let covered_texels = pos.iter().filter(|p| p[3] == COVERED).count();
        if covered_texels == 0 {
            return Err(err(format!(
                "no texel centre of the {size}^2 layout falls inside a triangle"
            )));
        }
        let mut geo = TexGeometry {
            size,
            pos,
            nrm,
            dpdu,
            dpdv,
            texel_tri,
            source_uvs: mesh
                .triangles
                .iter()
                .map(|t| t.map(|i| uvs[i as usize]))
                .collect(),
            corner_uvs,
            positions,
            normals: mesh.normals.clone(),
            triangles: mesh.triangles.clone(),
            report: TexReport {
                size,
                triangles: nt,
                charts: charts.len(),
                split_charts,
                mirrored_charts,
                overlapping_texels,
                self_overlap_texels: self_overlap,
                lost_texels,
                layers: nl,
                layout,
                density,
                covered_texels,
                gutter_texels: 0,
                mesh_area_mm2: mesh_area,
                texel_area_mm2: texel_area,
            },
        };
        geo.dilate();
        Ok(geo)
    }

    /// The texel centres of an N x N image in the mesh's own UV layout that a triangle covers,
    /// with that triangle and the barycentrics of the centre. Where the mesh's UVs overlap
    /// (mirrored halves, stacked copies) the lowest-numbered triangle keeps the texel: an
    /// image in overlapping UVs can hold only one of the surface points sharing it.
    pub fn source_texels(&self, size: u32) -> Vec<(usize, u32, [f64; 3])> {
        let mut owner = vec![u32::MAX; (size * size) as usize];
        let mut out = Vec::new();
        for (t, uv) in self.source_uvs.iter().enumerate() {
            raster(uv.map(|u| u.as_dvec2() * size as f64), size, |i, w| {
                if owner[i] == u32::MAX {
                    owner[i] = t as u32;
                    out.push((i, t as u32, w));
                }
            });
        }
        out
    }

    /// Resamples `values` (one per texel of this layout, row-major) into the mesh's own UV
    /// layout at `size` x `size`, for outputs a renderer applies with the mesh's UVs: each
    /// covered texel ([`TexGeometry::source_texels`]) takes the bilinear sample of `values`
    /// at the same surface point in this layout (gutters keep the taps at chart borders on
    /// the surface); texels no triangle covers are 0. In the original layout at the same size
    /// the values come back unchanged.
    pub fn to_source_layout(&self, values: &[[f32; 4]], size: u32) -> Vec<[f32; 4]> {
        if self.report.layout == Layout::Original && size == self.size {
            return values.to_vec();
        }
        let n = self.size as i64;
        let at = |x: i64, y: i64| {
            let (x, y) = (x.clamp(0, n - 1), y.clamp(0, n - 1));
            glam::Vec4::from_array(values[(y * n + x) as usize])
        };
        let mut out = vec![[0f32; 4]; (size * size) as usize];
        for (i, t, w) in self.source_texels(size) {
            let c = self.corner_uvs[t as usize];
            let uv = c[0].as_dvec2() * w[0] + c[1].as_dvec2() * w[1] + c[2].as_dvec2() * w[2];
            let (fx, fy) = (uv.x * n as f64 - 0.5, uv.y * n as f64 - 0.5);
            let (x0, y0) = (fx.floor(), fy.floor());
            let (ax, ay) = ((fx - x0) as f32, (fy - y0) as f32);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let top = at(x0, y0).lerp(at(x0 + 1, y0), ax);
            let bottom = at(x0, y0 + 1).lerp(at(x0 + 1, y0 + 1), ax);
            out[i] = top.lerp(bottom, ay).to_array();
        }
        out
    }

    /// Fills the gutters ring by ring from covered texels (see the module documentation).
    fn dilate(&mut self) {
        let n = self.size as i64;
        let mut gutter = 0;
        for _ in 0..GUTTER {
            let mut fills = Vec::new();
            for y in 0..n {
                for x in 0..n {
                    let i = (y * n + x) as usize;
                    if self.pos[i][3] != 0.0 {
                        continue;
                    }
                    let src = [
                        (-1, 0),
                        (1, 0),
                        (0, -1),
                        (0, 1),
                        (-1, -1),
                        (1, -1),
                        (-1, 1),
                        (1, 1),
                    ]
                    .iter()
                    .map(|(dx, dy)| (x + dx, y + dy))
                    .filter(|&(a, b)| a >= 0 && b >= 0 && a < n && b < n)
                    .map(|(a, b)| (b * n + a) as usize)
                    .find(|&j| self.pos[j][3] != 0.0);
                    if let Some(j) = src {
                        fills.push((i, j));
                    }
                }
            }
            for &(i, j) in &fills {
                self.pos[i] = self.pos[j];
                self.pos[i][3] = GUTTER_FLAG;
                self.nrm[i] = self.nrm[j];
                self.nrm[i][3] = 0.0;
                self.dpdu[i] = self.dpdu[j];
                self.dpdv[i] = self.dpdv[j];
                self.texel_tri[i] = self.texel_tri[j];
            }
            gutter += fills.len();
        }
        self.report.gutter_texels = gutter;
    }

    /// Texel count.
    pub fn texels(&self) -> usize {
        (self.size * self.size) as usize
    }

    /// Length of the bounding-box diagonal of the mesh (mm).
    pub fn extent_mm(&self) -> f32 {
        let (lo, hi) = crate::scene::mesh::bounds(&self.positions);
        (hi - lo).length()
    }
}

/// `mesh` posed by linear blend skinning with `matrices` (one per joint of its skin):
/// positions and normals move, triangles and UVs stay (so the UV layout, and with it the
/// overlap repair, is the same in every pose).
pub fn posed(mesh: &Mesh, matrices: &[glam::Mat4]) -> Result<Mesh> {
    let skin = mesh.skin.as_ref().ok_or_else(|| {
        Error::InvalidArgument(format!("mesh '{}' has no skin weights to pose", mesh.name))
    })?;
    let mut out = mesh.clone();
    for (v, (j, w)) in skin.joints.iter().zip(&skin.weights).enumerate() {
        let mut m = glam::Mat4::ZERO;
        for k in 0..4 {
            if w[k] > 0.0 {
                let mat = matrices.get(j[k] as usize).ok_or_else(|| {
                    Error::InvalidArgument(format!(
                        "vertex {v} uses joint {} of {} skinning matrices",
                        j[k],
                        matrices.len()
                    ))
                })?;
                m += *mat * w[k];
            }
        }
        out.positions[v] = m.transform_point3(mesh.positions[v]);
        out.normals[v] = m
            .transform_vector3(mesh.normals[v])
            .try_normalize()
            .unwrap_or(mesh.normals[v]);
    }
    // Vertices that share a position at rest (split along UV seams) share it posed: the
    // diffusion welds by position, and copies skinned with their weights in another order
    // could differ in the last bit (the seam would open).
    let mut first: HashMap<[u32; 3], usize> = HashMap::new();
    for (v, p) in mesh.positions.iter().enumerate() {
        let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
        let f = *first.entry(key).or_insert(v);
        out.positions[v] = out.positions[f];
    }
    Ok(out)
}

/// A flat rectangle of `w` x `h` mm in the z = 0 plane, normal +z, UV (0,0)-(1,1) spanning
/// it (a `w`:`h` stretch when w != h), split into `cells` x `cells` quads. For the analytic
/// plane tests.
pub fn plane_mesh(w: f32, h: f32, cells: u32) -> Result<Mesh> {
    use crate::scene::mesh::MeshData;
    let n = cells + 1;
    let mut data = MeshData {
        name: format!("plane {w}x{h} mm"),
        ..Default::default()
    };
    let mut uvs = Vec::new();
    let mut normals = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (u, v) = (i as f32 / cells as f32, j as f32 / cells as f32);
            data.positions.push([(u - 0.5) * w, (v - 0.5) * h, 0.0]);
            uvs.push([u, v]);
            normals.push([0.0, 0.0, 1.0]);
        }
    }
    for j in 0..cells {
        for i in 0..cells {
            let a = j * n + i;
            data.triangles.push([a, a + 1, a + n + 1]);
            data.triangles.push([a, a + n + 1, a + n]);
        }
    }
    data.uvs = Some(uvs);
    data.normals = Some(normals);
    Mesh::from_data(data, std::path::Path::new("<plane>"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_covers_every_texel_once_with_the_right_jacobian() {
        let m = plane_mesh(40.0, 20.0, 7).unwrap();
        let g = TexGeometry::build(&m, 64, 1.0).unwrap();
        assert_eq!(g.report.covered_texels, 64 * 64);
        assert_eq!(g.report.overlapping_texels, 0);
        assert_eq!(g.report.layers, 1);
        assert!((g.report.texel_area_mm2 - 800.0).abs() < 1e-3);
        for i in 0..g.texels() {
            assert!((g.dpdu[i][0] - 40.0).abs() < 1e-4 && (g.dpdv[i][1] - 20.0).abs() < 1e-4);
            let (x, y) = (i % 64, i / 64);
            assert!((g.pos[i][0] - ((x as f32 + 0.5) / 64.0 - 0.5) * 40.0).abs() < 1e-4);
            assert!((g.pos[i][1] - ((y as f32 + 0.5) / 64.0 - 0.5) * 20.0).abs() < 1e-4);
        }
    }

    #[test]
    fn mirrored_overlap_is_repaired_into_layers() {
        // Two squares side by side in 3D sharing one UV square, the second mirrored.
        use crate::scene::mesh::MeshData;
        let mut d = MeshData {
            name: "mirror".into(),
            ..Default::default()
        };
        for (ox, mirror) in [(0.0, false), (20.0, true)] {
            let b = d.positions.len() as u32;
            for (x, y) in [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)] {
                d.positions.push([ox + x, y, 0.0]);
                let u = x / 10.0;
                d.uvs
                    .get_or_insert_with(Vec::new)
                    .push([if mirror { 1.0 - u } else { u }, y / 10.0]);
            }
            d.triangles.push([b, b + 1, b + 2]);
            d.triangles.push([b, b + 2, b + 3]);
        }
        let m = Mesh::from_data(d, std::path::Path::new("<mirror>")).unwrap();
        let g = TexGeometry::build(&m, 32, 1.0).unwrap();
        assert_eq!(g.report.charts, 2);
        assert_eq!(g.report.mirrored_charts, 1);
        assert_eq!(g.report.overlapping_texels, 32 * 32);
        assert_eq!(g.report.layers, 2);
        assert_eq!(g.report.covered_texels, 32 * 32);
        assert!((g.report.texel_area_mm2 - 200.0).abs() < 1e-3);
    }

    #[test]
    fn posing_moves_positions_and_keeps_the_layout() {
        let mut m = plane_mesh(10.0, 10.0, 2).unwrap();
        let n = m.positions.len();
        m.skin = Some(crate::scene::mesh::SkinWeights {
            joints: vec![[0, 1, 0, 0]; n],
            weights: vec![[0.5, 0.5, 0.0, 0.0]; n],
        });
        let t = glam::Mat4::from_translation(Vec3::new(0.0, 0.0, 4.0));
        let p = posed(&m, &[glam::Mat4::IDENTITY, t]).unwrap();
        for (a, b) in p.positions.iter().zip(&m.positions) {
            assert!((*a - *b - Vec3::new(0.0, 0.0, 2.0)).length() < 1e-6);
        }
        let g0 = TexGeometry::build(&m, 32, 1.0).unwrap();
        let g1 = TexGeometry::build(&p, 32, 1.0).unwrap();
        assert_eq!(g0.corner_uvs, g1.corner_uvs);
        assert!(posed(&m, &[glam::Mat4::IDENTITY]).is_err());
    }

    #[test]
    fn bad_uvs_are_errors_naming_the_mesh() {
        let mut m = plane_mesh(10.0, 10.0, 2).unwrap();
        m.uvs = None;
        let e = TexGeometry::build(&m, 32, 1.0).unwrap_err().to_string();
        assert!(
            e.contains("no texture coordinates") && e.contains("plane"),
            "{e}"
        );
        let mut m = plane_mesh(10.0, 10.0, 2).unwrap();
        m.uvs.as_mut().unwrap()[4] = Vec2::new(0.0, 0.0);
        m.uvs.as_mut().unwrap()[0] = Vec2::new(0.0, 0.0);
        m.uvs.as_mut().unwrap()[1] = Vec2::new(0.0, 0.0);
        let e = TexGeometry::build(&m, 32, 1.0).unwrap_err().to_string();
        assert!(e.contains("zero area in UV space"), "{e}");
        let mut m = plane_mesh(10.0, 10.0, 2).unwrap();
        m.uvs.as_mut().unwrap()[3] = Vec2::new(1.5, 0.0);
        let e = TexGeometry::build(&m, 32, 1.0).unwrap_err().to_string();
        assert!(e.contains("outside [0, 1]"), "{e}");
    }
}
