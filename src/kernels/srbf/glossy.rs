//! Glossy (view-dependent) transfer: per vertex a transfer *matrix* from the lighting's
//! coefficients on the SG basis to outgoing radiance at V view directions.
//!
//! For a view direction o, the integrand V_v(w) rho(w, o) max(0, n . w) ([`Brdf`]) is
//! projected on the same fixed SG basis as the diffuse transfer, so with the per-frame
//! lighting coefficients c^ (the closed-form inner products, [`super::transfer`]) the
//! radiance toward o is B_v(o) = sum_k T_v[o, k] c^_k. The view dependence is carried by a
//! [`ViewBasis`] of V rows per vertex, two kinds:
//!
//! **The default: the BRDF's separable factorisation** ([`BrdfFactors`], m terms g_j(o)
//! h_j(w) of rho cos in the tangent frame). Row j projects V_v(w) h_j(w); a view weights the
//! rows by g_j(o), looked up in one table shared by every vertex. The view then enters only
//! through the BRDF, which is exactly where it enters the integral, so there is no
//! cross-fading between view samples; what is lost is the kernel's truncation, set by the
//! BRDF and reported. On the bunny (Phong 8, forest; tests/srbf_glossy.rs) 24 terms err
//! 2.4-2.6% against the truth, below the 12 x 12 grid's 3.0-3.4% with a sixth of its rows.
//!
//! **A view grid: an N x N parabolic grid of view directions, bilinear (4 taps).** o_local = (x, y, z) maps to
//! p = (x, y) / (1 + z) in the unit disk; the nodes are a regular grid over [-1, 1]^2, nodes
//! outside the disk standing for the horizon direction p / |p| (so the bilinear interpolant
//! is continuous up to and at the horizon, and a view below the horizon, a silhouette of
//! interpolated normals, is clamped onto it). Why: it is the BTF kernel's parameterisation
//! (one lookup scheme in the project), the whole hemisphere including grazing views is
//! covered with a fixed 4-tap, branch-free lookup, and a grid row is exactly what a Tucker
//! view factor interpolates (CTA's view mode, [`super::cta`]). Its known artefact is linear
//! cross-fading of highlights sharper than the node spacing (2 / (N - 1) in p, i.e. about
//! 4 / (N - 1) rad at normal view): the interpolation error of a lobe of sharpness lambda
//! grows as h^2 lambda / 8, so N is a parameter and the error is measured at views that are
//! not nodes (tests/srbf_glossy.rs). The specular lobe's sharpness is also bounded by what
//! the SG basis resolves (mu = 1.5 K / (4 pi): 30.6 for K = 256): a Phong exponent far above
//! mu is smoothed by the basis whatever N is.
//!
//! The tangent frame is the branchless orthonormal basis of Duff et al. (2017) from the
//! normal alone; the GPU builds the same one (glsl/srbf/glossy.comp).

use super::brdf_factors::BrdfFactors;
use super::transfer::{Basis, Transfer};
use crate::error::{Error, Result};
use crate::geom::brdf::Brdf;
use crate::geom::sg;
use crate::geom::visibility::Visibility;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Most nodes per side of a [`ViewGrid`].
pub const MAX_GRID: u32 = 64;

/// N x N nodes over the parabolic disk of the local hemisphere (see the module).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ViewGrid {
    pub n: u32,
}

impl ViewGrid {
    pub fn check(&self) -> Result<()> {
        if !(2..=MAX_GRID).contains(&self.n) {
            return Err(Error::InvalidArgument(format!(
                "view grid {0} x {0}: the side must be in 2..={MAX_GRID}",
                self.n
            )));
        }
        Ok(())
    }

    /// V = N^2 view samples.
    pub fn views(&self) -> usize {
        (self.n * self.n) as usize
    }

    /// The local direction of node (i, j) (row j, column i): p = (-1 + 2i/(N-1),
    /// -1 + 2j/(N-1)), projected onto the unit circle when outside it.
    pub fn node_direction(&self, i: u32, j: u32) -> DVec3 {
        let s = (self.n - 1) as f64;
        let mut p = glam::DVec2::new(-1.0 + 2.0 * i as f64 / s, -1.0 + 2.0 * j as f64 / s);
        let r2 = p.length_squared();
        if r2 > 1.0 {
            p /= r2.sqrt();
        }
        let r2 = p.length_squared();
        DVec3::new(2.0 * p.x, 2.0 * p.y, 1.0 - r2) / (1.0 + r2)
    }

    /// The four (node index j N + i, weight) taps of the local view direction `o` (any
    /// length > 0; below the horizon it is clamped onto it). f32 as on the GPU.
    pub fn taps(&self, o: Vec3) -> [(usize, f32); 4] {
        let mut o = Vec3::new(o.x, o.y, o.z.max(0.0));
        if o.x == 0.0 && o.y == 0.0 && o.z == 0.0 {
            o = Vec3::X;
        }
        let o = o.normalize();
        let s = (self.n - 1) as f32;
        let p = [o.x / (1.0 + o.z), o.y / (1.0 + o.z)];
        let mut cell = [0u32; 2];
        let mut frac = [0f32; 2];
        for a in 0..2 {
            let u = ((p[a] + 1.0) * 0.5 * s).clamp(0.0, s);
            let c = (u.floor() as u32).min(self.n - 2);
            cell[a] = c;
            frac[a] = u - c as f32;
        }
        let idx = |di: u32, dj: u32| ((cell[1] + dj) * self.n + cell[0] + di) as usize;
        let (fx, fy) = (frac[0], frac[1]);
        [
            (idx(0, 0), (1.0 - fx) * (1.0 - fy)),
            (idx(1, 0), fx * (1.0 - fy)),
            (idx(0, 1), (1.0 - fx) * fy),
            (idx(1, 1), fx * fy),
        ]
    }
}

/// The tangent frame (t, b, n) of a unit normal: Duff et al. 2017, "Building an
/// orthonormal basis, revisited" (sign taken as +1 at n.z = 0, as glossy.comp does).
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// The local view direction at a vertex (position `x`, unit normal `n`) for a camera at
/// `camera`: (t . o, b . o, n . o), o = camera - x (unnormalised; [`ViewGrid::taps`]
/// normalises). At the camera itself, o = n.
pub fn local_view(x: Vec3, n: Vec3, camera: Vec3) -> Vec3 {
    let o = camera - x;
    let o = if o.length_squared() > 0.0 { o } else { n };
    let (t, b) = tangent_frame(n);
    Vec3::new(t.dot(o), b.dot(o), n.dot(o))
}

/// The view basis a glossy run asks for (`--terms` / `--views`): built by [`ViewSpec::build`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ViewSpec {
    /// m terms of the BRDF's factorisation on the default table grid.
    Brdf(usize),
    /// An N x N view grid.
    Grid(u32),
}

/// The default view basis: 24 BRDF terms (on the bunny under forest, Phong 8: 2.4-2.6%
/// against the truth, below a 12 x 12 grid's 144 rows at 3.0-3.4%; tests/srbf_glossy.rs).
pub const DEFAULT_VIEW: ViewSpec = ViewSpec::Brdf(24);

impl ViewSpec {
    /// The basis of the CLI's `--views N` / `--terms M` (at most one given; neither: the
    /// default).
    pub fn from_args(views: Option<u32>, terms: Option<usize>) -> ViewSpec {
        match (views, terms) {
            (Some(n), _) => ViewSpec::Grid(n),
            (None, Some(m)) => ViewSpec::Brdf(m),
            (None, None) => DEFAULT_VIEW,
        }
    }

    /// Checks that CTA can shade this basis on the GPU: its shading pass holds at most
    /// [`super::cta_gpu::MAX_VIEW_RANK`] view values per vertex, and a factored basis folds
    /// all m terms in (a grid is limited by the view rank instead). Called before any work.
    pub fn check_for_cta(&self) -> Result<()> {
        if let ViewSpec::Brdf(m) = *self
            && m > super::cta_gpu::MAX_VIEW_RANK
        {
            return Err(Error::InvalidArgument(format!(
                "--cta shades at most {} BRDF terms on the GPU (--terms {m})",
                super::cta_gpu::MAX_VIEW_RANK
            )));
        }
        Ok(())
    }

    /// Rows per vertex.
    pub fn rows(&self) -> usize {
        match *self {
            ViewSpec::Brdf(m) => m,
            ViewSpec::Grid(n) => (n as usize) * (n as usize),
        }
    }

    /// Checks the numbers without building anything.
    pub fn check(&self) -> Result<()> {
        match *self {
            ViewSpec::Brdf(m) => {
                if !(1..=super::brdf_factors::MAX_TERMS).contains(&m) {
                    return Err(Error::InvalidArgument(format!(
                        "{m} BRDF terms: need 1..={}",
                        super::brdf_factors::MAX_TERMS
                    )));
                }
                Ok(())
            }
            ViewSpec::Grid(n) => ViewGrid { n }.check(),
        }
    }

    /// The basis for `brdf` (the factorisation takes ~1 s at 24 terms).
    pub fn build(&self, brdf: &Brdf) -> Result<ViewBasis> {
        match *self {
            ViewSpec::Brdf(m) => Ok(ViewBasis::Brdf(Box::new(BrdfFactors::new(
                brdf,
                m,
                ViewGrid {
                    n: super::brdf_factors::DEFAULT_GRID,
                },
            )?))),
            ViewSpec::Grid(n) => {
                let g = ViewGrid { n };
                g.check()?;
                Ok(ViewBasis::Grid(g))
            }
        }
    }
}

/// The view basis of a glossy transfer: what its V rows per vertex stand for and how a view
/// direction weights them.
#[derive(Clone, Debug, PartialEq)]
pub enum ViewBasis {
    /// V = N^2 view directions at the nodes of a parabolic grid, 4 bilinear taps.
    Grid(ViewGrid),
    /// V = m terms of the BRDF's separable factorisation ([`BrdfFactors`]): row j is the
    /// projection of `V_v(w) h_j(w)`, weighted by `g_j(o)`.
    Brdf(Box<BrdfFactors>),
}

impl ViewBasis {
    /// V: rows per vertex.
    pub fn views(&self) -> usize {
        match self {
            ViewBasis::Grid(g) => g.views(),
            ViewBasis::Brdf(f) => f.terms,
        }
    }

    /// The parabolic grid the lookup runs on (the view nodes, or the factor tables').
    pub fn grid(&self) -> ViewGrid {
        match self {
            ViewBasis::Grid(g) => *g,
            ViewBasis::Brdf(f) => f.grid,
        }
    }

    /// m for a factored basis, 0 for a grid (the shaders' switch).
    pub fn terms(&self) -> usize {
        match self {
            ViewBasis::Grid(_) => 0,
            ViewBasis::Brdf(f) => f.terms,
        }
    }

    pub fn check(&self) -> Result<()> {
        match self {
            ViewBasis::Grid(g) => g.check(),
            ViewBasis::Brdf(f) => {
                f.grid.check()?;
                let nodes = f.grid.views();
                if f.terms == 0
                    || f.terms > super::brdf_factors::MAX_TERMS
                    || f.view.len() != nodes * f.terms
                    || f.light.len() != nodes * f.terms
                    || f.view.iter().chain(&f.light).any(|x| !x.is_finite())
                {
                    return Err(Error::InvalidArgument(format!(
                        "BRDF factors: {} terms with tables of {} and {} values for a {} x {} \
                         grid (need 1..={} terms, finite)",
                        f.terms,
                        f.view.len(),
                        f.light.len(),
                        f.grid.n,
                        f.grid.n,
                        super::brdf_factors::MAX_TERMS
                    )));
                }
                Ok(())
            }
        }
    }

    /// [`ViewBasis::check`] for a transfer of `brdf` (checked too): a factored basis must be
    /// that BRDF's factorisation.
    pub fn check_for(&self, brdf: &Brdf) -> Result<()> {
        self.check()?;
        brdf.check()?;
        if let ViewBasis::Brdf(f) = self
            && f.brdf != *brdf
        {
            return Err(Error::InvalidArgument(format!(
                "glossy transfer: factors of {:?} for a transfer of {brdf:?}",
                f.brdf
            )));
        }
        Ok(())
    }

    /// The (row, weight) pairs of a local view direction `o` (any length > 0; below the
    /// horizon it is clamped onto it): the grid's 4 taps, or every term j with g_j(o).
    pub fn weights(&self, o: Vec3) -> Vec<(usize, f32)> {
        match self {
            ViewBasis::Grid(g) => g.taps(o).to_vec(),
            ViewBasis::Brdf(f) => {
                let mut g = vec![0f32; f.terms];
                f.view_weights(o, &mut g);
                g.into_iter().enumerate().collect()
            }
        }
    }

    /// A fingerprint of what the rows stand for (FNV-1a over the grid side and the factor
    /// tables' bits): a cache of projected rows is keyed by it, so rows projected on other
    /// factors (another BRDF, another build of the factorisation) are never reused.
    pub fn fingerprint(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |x: u32| {
            for byte in x.to_le_bytes() {
                h = (h ^ byte as u64).wrapping_mul(0x0100_0000_01b3);
            }
        };
        match self {
            ViewBasis::Grid(g) => eat(g.n),
            ViewBasis::Brdf(f) => {
                eat(f.grid.n);
                eat(f.terms as u32);
                f.light.iter().chain(&f.view).for_each(|x| eat(x.to_bits()));
            }
        }
        h
    }

    /// A short description for reports.
    pub fn describe(&self) -> String {
        match self {
            ViewBasis::Grid(g) => format!("{0} x {0} view grid", g.n),
            ViewBasis::Brdf(f) => format!(
                "{} BRDF terms on a {1} x {1} table (truncation {2:.4})",
                f.terms, f.grid.n, f.truncation
            ),
        }
    }
}

/// Glossy transfer: V x K coefficients per vertex on `rows.basis`.
#[derive(Clone, Debug, PartialEq)]
pub struct GlossyTransfer {
    /// One row per (vertex, view row), vertex-major: row v V + j is vertex v's row j (a
    /// [`Transfer`] of `vertices` x V rows, so that it is cached by the same file format).
    pub rows: Transfer,
    pub vertices: usize,
    pub view: ViewBasis,
    pub brdf: Brdf,
}

impl GlossyTransfer {
    pub fn views(&self) -> usize {
        self.view.views()
    }

    /// Checks sizes and values (the GPU indexes with them).
    pub fn check(&self) -> Result<()> {
        self.view.check_for(&self.brdf)?;
        self.rows.basis.check()?;
        let k = self.rows.basis.len();
        if self.vertices == 0
            || self.rows.vertices != self.vertices * self.views()
            || self.rows.coeffs.len() != self.rows.vertices * k
        {
            return Err(Error::InvalidArgument(format!(
                "glossy transfer: {} rows of {} coefficients for {} vertices x {} views x {k}",
                self.rows.vertices,
                self.rows.coeffs.len(),
                self.vertices,
                self.views()
            )));
        }
        if self.rows.coeffs.iter().any(|c| !c.is_finite()) {
            return Err(Error::InvalidArgument(
                "glossy transfer: a coefficient is not finite".into(),
            ));
        }
        Ok(())
    }

    /// Vertex v's row toward node j.
    pub fn row(&self, v: usize, j: usize) -> &[f32] {
        let k = self.rows.basis.len();
        let r = v * self.views() + j;
        &self.rows.coeffs[r * k..(r + 1) * k]
    }

    /// The CPU twin of `srbf glossy shade`: per vertex the radiance toward `camera`,
    /// `B = albedo * sum_taps w_t (T_v[j_t] . c^)`, for lighting coefficients `coeffs` (one
    /// per basis function), positions and normals (those the transfer was projected for).
    pub fn shade(
        &self,
        coeffs: &[[f32; 3]],
        positions: &[Vec3],
        normals: &[Vec3],
        camera: Vec3,
        albedo: [f32; 3],
    ) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        let k = self.rows.basis.len();
        if coeffs.len() != k || positions.len() != self.vertices || normals.len() != self.vertices {
            return Err(Error::InvalidArgument(format!(
                "glossy shade: {} coefficients, {} positions, {} normals for {} vertices of a \
                 {k}-function basis",
                coeffs.len(),
                positions.len(),
                normals.len(),
                self.vertices
            )));
        }
        Ok((0..self.vertices)
            .into_par_iter()
            .map(|v| {
                let taps = self
                    .view
                    .weights(local_view(positions[v], normals[v], camera));
                let mut out = [0f64; 3];
                for (j, w) in taps {
                    let row = self.row(v, j);
                    for (t, c) in row.iter().zip(coeffs) {
                        for ch in 0..3 {
                            out[ch] += w as f64 * *t as f64 * c[ch] as f64;
                        }
                    }
                }
                [0, 1, 2].map(|ch| out[ch] * albedo[ch] as f64)
            })
            .collect())
    }

    /// Transfer bytes per vertex in the uncompressed GPU layout (f32).
    pub fn bytes_per_vertex(&self) -> usize {
        self.views() * self.rows.basis.len() * 4
    }
}

/// Projects every vertex's V_v(w) rho(w, o_j) max(0, n . w) onto `basis` for each view
/// node o_j of a grid view basis, or V_v(w) h_j(w) for each term of a factored one
/// (`view`; its BRDF must be `brdf`), from the quadrature `directions` / `solid_angles` (the texel
/// directions `vis` was cast for). Regularised least squares with the closed-form Gram
/// matrix (as [`super::transfer::project`]): the right-hand sides of all V views of a
/// vertex are accumulated in one pass over its visible directions (f32; every term is >= 0,
/// so there is no cancellation) and solved together with the Cholesky factor in f64.
///
/// The projection error reported is estimated per vertex from the normal equations,
/// |f - Gt|^2 ~ |f|^2 - t . rhs (exact for an unregularised least-squares fit whose Gram
/// matrix equals the quadrature's), averaged as sqrt(sum_j res_j / sum_j |f_j|^2).
#[allow(clippy::too_many_arguments)]
pub fn project(
    basis: &Basis,
    brdf: &Brdf,
    view: &ViewBasis,
    directions: &[Vec3],
    solid_angles: &[f64],
    normals: &[Vec3],
    vis: &Visibility,
) -> Result<GlossyTransfer> {
    basis.check()?;
    view.check_for(brdf)?;
    let n_dirs = directions.len();
    if n_dirs == 0 || solid_angles.len() != n_dirs || vis.directions.len() != n_dirs {
        return Err(Error::InvalidArgument(format!(
            "glossy projection: {n_dirs} directions, {} solid angles, a visibility of {} \
             directions (need the same, > 0)",
            solid_angles.len(),
            vis.directions.len()
        )));
    }
    if normals.len() != vis.vertices || normals.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "glossy projection: {} normals for a visibility of {} vertices",
            normals.len(),
            vis.vertices
        )));
    }
    if let Some(i) = normals
        .iter()
        .position(|n| !n.is_finite() || (n.length() - 1.0).abs() > 1e-3)
    {
        return Err(Error::InvalidArgument(format!(
            "glossy projection: normal {i} ({}) is not a unit vector",
            normals[i]
        )));
    }
    let k = basis.len();
    let views = view.views();
    let vertices = normals.len();
    if vertices
        .checked_mul(views)
        .and_then(|x| x.checked_mul(k))
        .is_none_or(|x| x > isize::MAX as usize / 8)
    {
        return Err(Error::InvalidArgument(format!(
            "glossy projection: {vertices} vertices x {views} views x {k} is too large"
        )));
    }
    let factor = basis.gram_factor().ok_or_else(|| {
        Error::InvalidArgument("glossy projection: the basis Gram matrix is singular".into())
    })?;
    let mu = basis.sharpness;
    // The directions x basis kernel table (f32): n_dirs x K.
    let table: Vec<f32> = {
        let mut t = vec![0f32; n_dirs * k];
        t.par_chunks_mut(k).enumerate().for_each(|(p, row)| {
            for (v, axis) in row.iter_mut().zip(&basis.axes) {
                *v = sg::kernel(*axis, mu, directions[p]);
            }
        });
        t
    };
    let nodes: Vec<DVec3> = match view {
        ViewBasis::Grid(grid) => (0..grid.n)
            .flat_map(|j| (0..grid.n).map(move |i| (i, j)))
            .map(|(i, j)| grid.node_direction(i, j))
            .collect(),
        ViewBasis::Brdf(_) => Vec::new(),
    };
    let mut coeffs = vec![0f32; vertices * views * k];
    let errors: Vec<f64> = coeffs
        .par_chunks_mut(views * k)
        .enumerate()
        .map(|(v, out)| {
            let n = normals[v].as_dvec3();
            let (t, b) = tangent_frame(normals[v]);
            let (t, b) = (t.as_dvec3(), b.as_dvec3());
            let o: Vec<DVec3> = nodes.iter().map(|l| t * l.x + b * l.y + n * l.z).collect();
            // rhs, K x V (view-contiguous), f32.
            let mut rhs = vec![0f32; k * views];
            let mut w = vec![0f32; views];
            let mut norm2 = 0f64;
            for p in 0..n_dirs {
                let d = directions[p].as_dvec3();
                if solid_angles[p] <= 0.0 || n.dot(d) <= 0.0 || !vis.visible(v, p) {
                    continue;
                }
                match view {
                    ViewBasis::Grid(_) => {
                        for (wj, oj) in w.iter_mut().zip(&o) {
                            let f = brdf.cosine_weighted(n, d, *oj);
                            norm2 += solid_angles[p] * f * f;
                            *wj = (solid_angles[p] * f) as f32;
                        }
                    }
                    ViewBasis::Brdf(fac) => {
                        let local = Vec3::new(t.dot(d) as f32, b.dot(d) as f32, n.dot(d) as f32);
                        fac.light_values(local, &mut w);
                        for wj in w.iter_mut() {
                            norm2 += solid_angles[p] * (*wj as f64).powi(2);
                            *wj *= solid_angles[p] as f32;
                        }
                    }
                }
                for (g, r) in table[p * k..(p + 1) * k]
                    .iter()
                    .zip(rhs.chunks_exact_mut(views))
                {
                    for (r, wj) in r.iter_mut().zip(&w) {
                        *r += g * wj;
                    }
                }
            }
            // Solve L L^T t = rhs for all views at once (f64).
            let mut x: Vec<f64> = rhs.iter().map(|r| *r as f64).collect();
            let rhs64 = x.clone();
            solve_many(&factor, k, views, &mut x);
            let mut dot = 0f64;
            for (a, r) in x.iter().zip(&rhs64) {
                dot += a * r;
            }
            for j in 0..views {
                for kk in 0..k {
                    out[j * k + kk] = x[kk * views + j] as f32;
                }
            }
            if norm2 > 0.0 {
                ((norm2 - dot).max(0.0) / norm2).sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let projection_rel_l2 = errors.iter().sum::<f64>() / vertices as f64;
    Ok(GlossyTransfer {
        rows: Transfer {
            basis: basis.clone(),
            vertices: vertices * views,
            coeffs,
            projection_rel_l2,
        },
        vertices,
        view: view.clone(),
        brdf: *brdf,
    })
}

/// Solves L L^T X = B in place for `m` right-hand sides, B stored K x m (row i holds the
/// m values of unknown i): forward then backward substitution, the inner loops over the m
/// columns (contiguous, so they vectorise).
fn solve_many(l: &[f64], k: usize, m: usize, x: &mut [f64]) {
    for i in 0..k {
        let (done, rest) = x.split_at_mut(i * m);
        let row = &mut rest[..m];
        for (kk, prev) in done.chunks_exact(m).enumerate() {
            let a = l[i * k + kk];
            if a != 0.0 {
                for (r, p) in row.iter_mut().zip(prev) {
                    *r -= a * p;
                }
            }
        }
        let d = l[i * k + i];
        for r in row.iter_mut() {
            *r /= d;
        }
    }
    for i in (0..k).rev() {
        let (head, tail) = x.split_at_mut((i + 1) * m);
        let row = &mut head[i * m..];
        for (off, next) in tail.chunks_exact(m).enumerate() {
            let a = l[(i + 1 + off) * k + i];
            if a != 0.0 {
                for (r, p) in row.iter_mut().zip(next) {
                    *r -= a * p;
                }
            }
        }
        let d = l[i * k + i];
        for r in row.iter_mut() {
            *r /= d;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve_many_equals_one_at_a_time() {
        let k = 7;
        let mut a = vec![0f64; k * k];
        for i in 0..k {
            for j in 0..k {
                a[i * k + j] =
                    1.0 / (1.0 + (i as f64 - j as f64).abs()) + if i == j { 2.0 } else { 0.0 };
            }
        }
        crate::geom::linalg::cholesky(&mut a, k).unwrap();
        let l = a;
        let m = 3;
        let b: Vec<f64> = (0..k * m).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut x = b.clone();
        solve_many(&l, k, m, &mut x);
        for c in 0..m {
            let mut one: Vec<f64> = (0..k).map(|i| b[i * m + c]).collect();
            crate::geom::linalg::cholesky_solve(&l, k, &mut one);
            for i in 0..k {
                assert!((one[i] - x[i * m + c]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn frame_is_orthonormal_and_taps_interpolate_nodes() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.8, 0.1).normalize(),
            Vec3::new(0.0, 0.0, -1.0),
        ] {
            let (t, b) = tangent_frame(n);
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5);
            assert!((t.cross(b) - n).length() < 1e-5, "{n}: right-handed");
        }
        let g = ViewGrid { n: 7 };
        // At a node the taps put all weight on that node.
        for (i, j) in [(3u32, 3u32), (1, 2), (5, 4)] {
            let d = g.node_direction(i, j).as_vec3();
            let taps = g.taps(d);
            let on: f32 = taps
                .iter()
                .filter(|(idx, _)| *idx == (j * 7 + i) as usize)
                .map(|t| t.1)
                .sum();
            assert!((on - 1.0).abs() < 1e-5, "node ({i}, {j}): {taps:?}");
        }
        // Weights sum to 1 anywhere, below the horizon too.
        for o in [
            Vec3::new(0.3, 0.2, -0.5),
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::Y,
        ] {
            let s: f32 = g.taps(o).iter().map(|t| t.1).sum();
            assert!((s - 1.0).abs() < 1e-5);
        }
    }
}
