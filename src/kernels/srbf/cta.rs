//! Clustered tensor approximation (CTA, after Tsai and Shih 2006) of per-vertex transfer
//! matrices: the vertices are clustered, and each cluster's 3-way tensor (vertex x view x
//! light basis) is approximated by a Tucker model, a small core and a factor per mode:
//!
//! ```text
//! T_v[j, k] ~ sum_abc u_v[a] G_c[a, b, c] W_c[j, b] L_c[k, c]
//! ```
//!
//! (ranks r_v, r_w, r_l; W_c: V x r_w view factor, L_c: K x r_l light factor, u_v the vertex's
//! r_v coefficients). The diffuse transfer is the case V = 1.
//!
//! As in [`super::cpca`], errors are measured between the functions the coefficients stand
//! for: the light mode is fitted on y = L^T t (G = L L^T the basis's Gram matrix), so the
//! error minimised is the transfer's L2 error over the sphere; the light factor is mapped back
//! to coefficient space (L^-T) at the end.
//!
//! The fit is HOOI (higher-order orthogonal iteration) per cluster: each step replaces one
//! factor by the best one given the others (leading singular vectors of the tensor projected
//! on the other two factors), so the captured energy sum_v |Q^T p_v|^2 never decreases and
//! the error never increases. The vertex factor is kept in its "dual" form (the thesis'
//! dual mode basis): Q_c, an orthonormal basis of r_v vectors in R^(r_w r_l), with
//! p_v = vec(W_c^T Y_v L_c), u_v = Q_c^T p_v and the error |Y_v|^2 - |Q_c^T p_v|^2; the core
//! is Q_c reshaped (G_c[a, b, c] = Q_c[b r_l + c, a]).
//!
//! Clustering: k-means++ / Lloyd ([`super::cpca`]'s) on each vertex's view-averaged
//! transfer (y space), then alternation: every vertex moves to the cluster (among its
//! nearest by that feature, and its own) whose factors represent it with the least error,
//! then each cluster's model is refitted by HOOI sweeps started from its current factors.
//! Both stages lower the total error or keep it, so [`Cta::history`] is non-increasing.

use super::transfer::Basis;
use crate::error::{Error, Result};
use crate::geom::Rng;
use crate::geom::linalg::{jacobi_eigen, orthonormalise, solve_upper_transposed, subspace_eigen};
use crate::io::f16::{HALF_MAX, first_beyond_half, half_round};
use crate::io::transfer_cache::CtaFile;
use rayon::prelude::*;
use std::borrow::Cow;
use std::path::Path;

/// How to compress.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct CtaConfig {
    pub clusters: usize,
    /// Core ranks (vertex, view, light).
    pub ranks: [usize; 3],
    /// Reassignment + refit rounds after the initial fit.
    pub iterations: usize,
    /// HOOI sweeps per refit.
    pub sweeps: usize,
    pub seed: u64,
}

impl Default for CtaConfig {
    fn default() -> Self {
        CtaConfig {
            clusters: 64,
            ranks: [8, 24, 32],
            iterations: 3,
            sweeps: 2,
            seed: 1,
        }
    }
}

/// Clusters a vertex may move to in a reassignment: its own and the nearest by feature.
const CANDIDATES: usize = 6;

/// A transfer in CTA form (f32 as the GPU holds it).
#[derive(Clone, Debug, PartialEq)]
pub struct Cta {
    pub basis: Basis,
    pub vertices: usize,
    /// V: views per vertex (1 for diffuse transfer).
    pub views: usize,
    pub clusters: usize,
    /// (r_v, r_w, r_l).
    pub ranks: [usize; 3],
    pub cluster_of: Vec<u32>,
    /// Per cluster: V x r_w, row-major.
    pub view_factors: Vec<f32>,
    /// Per cluster: K x r_l, row-major, in coefficient space.
    pub light_factors: Vec<f32>,
    /// Per cluster: r_v x r_w x r_l.
    pub cores: Vec<f32>,
    /// Per vertex: r_v, the model's (f32). The runtime streams them in half precision
    /// ([`Cta::coeff`]): the GPU reads f16 and the CPU twin rounds alike.
    pub coeffs: Vec<f32>,
    /// Function-space relative L2 of the reconstruction against the input, over all vertices.
    pub rel_l2: f64,
    /// The total squared function-space error after the initial fit and after each
    /// reassignment and each refit (non-increasing).
    pub history: Vec<f64>,
}

/// One cluster's model while fitting (f64, y space).
#[derive(Clone)]
struct Model {
    /// V x r_w.
    w: Vec<f64>,
    /// K x r_l.
    l: Vec<f64>,
    /// (r_w r_l) x r_v, orthonormal columns.
    q: Vec<f64>,
}

/// The data being compressed, y space: per vertex V x K (row-major), and the sizes.
struct Data<'a> {
    /// f32 (half the memory of the f64 the sums run in: the bunny's 64-view transfer is
    /// 2.3 GB in f32).
    y: &'a [f32],
    views: usize,
    k: usize,
    ranks: [usize; 3],
}

impl Data<'_> {
    fn slice(&self, v: usize) -> &[f32] {
        let n = self.views * self.k;
        &self.y[v * n..(v + 1) * n]
    }

    /// p_v = vec(W^T Y_v L) (r_w x r_l), contracted in the cheaper order: (Y_v L) first
    /// (V K r_l + V r_w r_l multiply-adds) or (W^T Y_v) first (r_w V K + r_w K r_l). The
    /// second wins when the view rank is well below V (e.g. 114 k against 202 k at V 24, K
    /// 256, view rank 8, light rank 32); at the default view rank (all 24 rows of the
    /// factored basis) the first is used.
    fn project(&self, m: &Model, v: usize) -> Vec<f64> {
        let [_, rw, rl] = self.ranks;
        let (vv, k) = (self.views, self.k);
        let y = self.slice(v);
        if rw * vv * k + rw * k * rl < vv * k * rl + vv * rw * rl {
            // Z = W^T Y_v: r_w x K.
            let mut z = vec![0f64; rw * k];
            for j in 0..vv {
                let row = &y[j * k..(j + 1) * k];
                for b in 0..rw {
                    let wjb = m.w[j * rw + b];
                    if wjb != 0.0 {
                        for (zc, yv) in z[b * k..(b + 1) * k].iter_mut().zip(row) {
                            *zc += wjb * *yv as f64;
                        }
                    }
                }
            }
            let mut p = vec![0f64; rw * rl];
            for b in 0..rw {
                let pb = &mut p[b * rl..(b + 1) * rl];
                for (kk, zv) in z[b * k..(b + 1) * k].iter().enumerate() {
                    if *zv != 0.0 {
                        for (pc, lc) in pb.iter_mut().zip(&m.l[kk * rl..(kk + 1) * rl]) {
                            *pc += zv * lc;
                        }
                    }
                }
            }
            return p;
        }
        // H = Y_v L: V x r_l.
        let mut h = vec![0f64; vv * rl];
        for j in 0..vv {
            let row = &y[j * k..(j + 1) * k];
            let hj = &mut h[j * rl..(j + 1) * rl];
            for (kk, yv) in row.iter().enumerate() {
                let yv = *yv as f64;
                if yv != 0.0 {
                    for (hc, lc) in hj.iter_mut().zip(&m.l[kk * rl..(kk + 1) * rl]) {
                        *hc += yv * lc;
                    }
                }
            }
        }
        let mut p = vec![0f64; rw * rl];
        for j in 0..vv {
            for b in 0..rw {
                let wjb = m.w[j * rw + b];
                for c in 0..rl {
                    p[b * rl + c] += wjb * h[j * rl + c];
                }
            }
        }
        p
    }

    /// (|Y_v|^2, |Q^T p_v|^2, Q^T p_v).
    fn captured(&self, m: &Model, v: usize) -> (f64, f64, Vec<f64>) {
        let rv = self.ranks[0];
        let p = self.project(m, v);
        let r = p.len();
        let u: Vec<f64> = (0..rv)
            .map(|a| (0..r).map(|i| m.q[i * rv + a] * p[i]).sum())
            .collect();
        let norm2 = self.slice(v).iter().map(|x| (*x as f64).powi(2)).sum();
        (norm2, u.iter().map(|x| x * x).sum(), u)
    }

    fn error(&self, m: &Model, v: usize) -> f64 {
        let (n, c, _) = self.captured(m, v);
        (n - c).max(0.0)
    }
}

/// The `r` leading eigenvectors (columns, n x r row-major) and eigenvalues of a symmetric
/// positive semi-definite n x n matrix, eigenvalues in decreasing order.
///
/// Cyclic Jacobi costs ~n^3 per sweep, which made the vertex step's Gram (n = r_w r_l: 768 at
/// the default view and light ranks 24 and 32) most of a fit's time; above 64 rows and when r is small against n, the
/// leading subspace is found by block subspace iteration instead (n^2 (r + 8) per step, to
/// a relative change of the captured trace below 1e-10, at most 40 steps from a random
/// start and 12 from a warm one; [`subspace_eigen`]), and only the small Rayleigh-Ritz matrix
/// goes to Jacobi. For a positive semi-definite matrix the Ritz values of subspace iteration
/// never fall, so a block started from the previous HOOI step's factor ([`leading_from`])
/// captures at least what that factor did even when the step cap ends it early: the fit's
/// error still never increases.
fn leading(a: Vec<f64>, n: usize, r: usize) -> (Vec<f64>, Vec<f64>) {
    leading_from(a, n, r, None)
}

/// [`leading`] started (when it iterates) from `init`, n x r columns (row-major) such as the
/// previous step's result: HOOI's factors move little between steps, so a warm start
/// converges in a few iterations.
fn leading_from(a: Vec<f64>, n: usize, r: usize, init: Option<&[f64]>) -> (Vec<f64>, Vec<f64>) {
    let p = (r + 8).min(n);
    if n <= 64 || 2 * p > n {
        return leading_jacobi(a, n, r);
    }
    let warm = init.is_some_and(|i| i.len() == n * r && i.iter().any(|v| *v != 0.0));
    // The warm start as rows.
    let start: Vec<f64> = match init.filter(|_| warm) {
        Some(init) => (0..r)
            .flat_map(|c| (0..n).map(move |row| init[row * r + c]))
            .collect(),
        None => Vec::new(),
    };
    // Y = X A, row i of A read once for all p rows of X (A is n^2 f64: 4.7 MB at n = 768,
    // so one pass per row of X would stream it p times).
    let apply = |x: &[f64]| -> Vec<f64> {
        let mut y = vec![0f64; p * n];
        for i in 0..n {
            let ai = &a[i * n..(i + 1) * n];
            for c in 0..p {
                y[c * n + i] = ai
                    .iter()
                    .zip(&x[c * n..(c + 1) * n])
                    .map(|(u, v)| u * v)
                    .sum();
            }
        }
        y
    };
    let trace: f64 = (0..n).map(|i| a[i * n + i].abs()).sum::<f64>().max(1e-300);
    let (vals, rows) = subspace_eigen(
        n,
        p,
        &start,
        0x1ead_1e55 ^ n as u64,
        if warm { 12 } else { 40 },
        1e-10 * trace,
        apply,
    );
    let mut out = vec![0f64; n * r];
    for c in 0..r {
        for row in 0..n {
            out[row * r + c] = rows[c * n + row];
        }
    }
    (out, vals[..r].iter().map(|v| v.max(0.0)).collect())
}

/// [`leading`] by a full Jacobi eigen-decomposition.
fn leading_jacobi(a: Vec<f64>, n: usize, r: usize) -> (Vec<f64>, Vec<f64>) {
    let (vals, vecs) = jacobi_eigen(a, n);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| vals[j].total_cmp(&vals[i]).then(i.cmp(&j)));
    let mut out = vec![0f64; n * r];
    for (c, &i) in order.iter().take(r).enumerate() {
        // A deterministic sign: the largest entry positive.
        let col: Vec<f64> = (0..n).map(|row| vecs[row * n + i]).collect();
        let big = col
            .iter()
            .cloned()
            .fold(0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        let s = if big < 0.0 { -1.0 } else { 1.0 };
        for row in 0..n {
            out[row * r + c] = s * col[row];
        }
    }
    (
        out,
        order.iter().take(r).map(|&i| vals[i].max(0.0)).collect(),
    )
}

/// The best Q given W and L: the r_v leading right singular vectors of P (members x
/// r_w r_l), from P^T P. Returns Q and the vertex factor U = P Q / sigma (0 where sigma
/// vanishes), members x r_v.
fn vertex_step(d: &Data, m: &mut Model, members: &[usize]) -> Vec<f64> {
    let [rv, rw, rl] = d.ranks;
    let r = rw * rl;
    let ps: Vec<Vec<f64>> = members.par_iter().map(|&v| d.project(m, v)).collect();
    // The upper triangle of P^T P (half the multiply-adds), then mirrored.
    let mut gram = vec![0f64; r * r];
    for p in &ps {
        for i in 0..r {
            if p[i] != 0.0 {
                for (g, pj) in gram[i * r + i..(i + 1) * r].iter_mut().zip(&p[i..]) {
                    *g += p[i] * pj;
                }
            }
        }
    }
    for i in 0..r {
        for j in 0..i {
            gram[i * r + j] = gram[j * r + i];
        }
    }
    let (q, vals) = leading_from(gram, r, rv, Some(&m.q));
    m.q = q;
    let mut u = vec![0f64; members.len() * rv];
    for (i, p) in ps.iter().enumerate() {
        for a in 0..rv {
            let s = vals[a].sqrt();
            if s > 1e-12 * vals[0].sqrt().max(1e-300) {
                let x: f64 = (0..r).map(|t| m.q[t * rv + a] * p[t]).sum();
                u[i * rv + a] = x / s;
            }
        }
    }
    u
}

/// The best L given the vertex factor `u` and W: the r_l leading left singular vectors of
/// the light-mode unfolding M (K x r_v r_w), M[:, a r_w + b] = sum_v u[v, a] Y_v^T W[:, b],
/// through the small Gram M^T M; directions of vanishing singular value are completed to an
/// orthonormal set.
fn light_step(d: &Data, m: &mut Model, members: &[usize], u: &[f64]) {
    let [rv, rw, rl] = d.ranks;
    let (vv, k) = (d.views, d.k);
    let cols = rv * rw;
    let mm = members
        .par_iter()
        .enumerate()
        .fold(
            || vec![0f64; k * cols],
            |mut acc, (i, &v)| {
                let y = d.slice(v);
                // Y_v^T W: K x r_w.
                let mut yw = vec![0f64; k * rw];
                for j in 0..vv {
                    for kk in 0..k {
                        let yv = y[j * k + kk] as f64;
                        if yv != 0.0 {
                            for b in 0..rw {
                                yw[kk * rw + b] += yv * m.w[j * rw + b];
                            }
                        }
                    }
                }
                for a in 0..rv {
                    let ua = u[i * rv + a];
                    if ua != 0.0 {
                        for kk in 0..k {
                            for b in 0..rw {
                                acc[kk * cols + a * rw + b] += ua * yw[kk * rw + b];
                            }
                        }
                    }
                }
                acc
            },
        )
        .reduce(
            || vec![0f64; k * cols],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let mut gram = vec![0f64; cols * cols];
    for kk in 0..k {
        let row = &mm[kk * cols..(kk + 1) * cols];
        for i in 0..cols {
            for j in 0..cols {
                gram[i * cols + j] += row[i] * row[j];
            }
        }
    }
    let take = rl.min(cols);
    let (e, vals) = leading(gram, cols, take);
    // Rows of L^T (r_l rows of dimension K), then orthonormalised (completing the null part).
    let mut lt = vec![0f64; rl * k];
    for c in 0..take {
        let s = vals[c].sqrt();
        if s > 1e-12 * vals[0].sqrt().max(1e-300) {
            for kk in 0..k {
                let x: f64 = (0..cols).map(|t| mm[kk * cols + t] * e[t * take + c]).sum();
                lt[c * k + kk] = x / s;
            }
        }
    }
    orthonormalise(&mut lt, k);
    for c in 0..rl {
        for kk in 0..k {
            m.l[kk * rl + c] = lt[c * k + kk];
        }
    }
}

/// The best W given `u` and L: the r_w leading eigenvectors of Z Z^T (V x V), Z the view-mode
/// unfolding, Z[:, a r_l + c] = sum_v u[v, a] Y_v L[:, c].
fn view_step(d: &Data, m: &mut Model, members: &[usize], u: &[f64]) {
    let [rv, rw, rl] = d.ranks;
    let (vv, k) = (d.views, d.k);
    let cols = rv * rl;
    let z = members
        .par_iter()
        .enumerate()
        .fold(
            || vec![0f64; vv * cols],
            |mut acc, (i, &v)| {
                let y = d.slice(v);
                for j in 0..vv {
                    let mut h = vec![0f64; rl];
                    for kk in 0..k {
                        let yv = y[j * k + kk] as f64;
                        if yv != 0.0 {
                            for (hc, lc) in h.iter_mut().zip(&m.l[kk * rl..(kk + 1) * rl]) {
                                *hc += yv * lc;
                            }
                        }
                    }
                    for a in 0..rv {
                        let ua = u[i * rv + a];
                        for c in 0..rl {
                            acc[j * cols + a * rl + c] += ua * h[c];
                        }
                    }
                }
                acc
            },
        )
        .reduce(
            || vec![0f64; vv * cols],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let mut zz = vec![0f64; vv * vv];
    for i in 0..vv {
        for j in 0..vv {
            zz[i * vv + j] = (0..cols).map(|t| z[i * cols + t] * z[j * cols + t]).sum();
        }
    }
    m.w = leading(zz, vv, rw).0;
}

/// HOOI sweeps on one cluster from the model's current W and L.
fn hooi(d: &Data, m: &mut Model, members: &[usize], sweeps: usize) {
    if members.is_empty() {
        return;
    }
    for _ in 0..sweeps {
        let u = vertex_step(d, m, members);
        light_step(d, m, members, &u);
        view_step(d, m, members, &u);
    }
    vertex_step(d, m, members);
}

/// A first model of a cluster: L from a random sketch of the light-mode unfolding (its
/// range, orthonormalised), W from the view-mode energy given L, then HOOI.
fn initial_model(d: &Data, members: &[usize], sweeps: usize, seed: u64) -> Model {
    let [rv, rw, rl] = d.ranks;
    let (vv, k) = (d.views, d.k);
    let mut rng = Rng::new(seed);
    // L^T rows: sum over members and views of random +-1 weights times the rows of Y_v.
    let mut lt = vec![0f64; rl * k];
    for &v in members {
        let y = d.slice(v);
        for j in 0..vv {
            for c in 0..rl {
                let s = if rng.f32() < 0.5 { -1.0 } else { 1.0 };
                for (x, yv) in lt[c * k..(c + 1) * k]
                    .iter_mut()
                    .zip(&y[j * k..(j + 1) * k])
                {
                    *x += s * *yv as f64;
                }
            }
        }
    }
    orthonormalise(&mut lt, k);
    let mut l = vec![0f64; k * rl];
    for c in 0..rl {
        for kk in 0..k {
            l[kk * rl + c] = lt[c * k + kk];
        }
    }
    let mut m = Model {
        w: vec![0f64; vv * rw],
        l,
        q: vec![0f64; rw * rl * rv],
    };
    // W from Z Z^T with every member weighted 1 in each vertex component.
    let ones = vec![1f64; members.len() * rv];
    view_step(d, &mut m, members, &ones);
    hooi(d, &mut m, members, sweeps);
    m
}

impl Cta {
    /// Compresses per-vertex transfer matrices `rows` (vertex-major, V x K per vertex, on
    /// `basis`). Deterministic for a given config.
    pub fn compress(
        basis: &Basis,
        rows: &[f32],
        vertices: usize,
        views: usize,
        cfg: &CtaConfig,
    ) -> Result<Cta> {
        Self::compress_from(basis, rows, vertices, views, cfg, None)
    }

    /// [`Cta::compress`] started from a given clustering (`initial[v]`, a cluster below
    /// `cfg.clusters` for each vertex, e.g. a previous run's `cluster_of`) instead of k-means.
    pub fn compress_from(
        basis: &Basis,
        rows: &[f32],
        vertices: usize,
        views: usize,
        cfg: &CtaConfig,
        initial: Option<&[u32]>,
    ) -> Result<Cta> {
        basis.check()?;
        let k = basis.len();
        let [rv, rw, rl] = cfg.ranks;
        if vertices == 0 || views == 0 || rows.len() != vertices * views * k {
            return Err(Error::InvalidArgument(format!(
                "CTA: {} transfer coefficients for {vertices} vertices x {views} views x {k}",
                rows.len()
            )));
        }
        if cfg.clusters == 0
            || rv == 0
            || rw == 0
            || rl == 0
            || rw > views
            || rl > k
            || rv > rw * rl
        {
            return Err(Error::InvalidArgument(format!(
                "CTA: {} clusters with ranks (vertex {rv}, view {rw}, light {rl}) for {views} \
                 views x {k} basis functions (need >= 1 cluster, view rank 1..={views}, light \
                 rank 1..={k}, vertex rank 1..=view x light rank)",
                cfg.clusters
            )));
        }
        if let Some(i) = rows.iter().position(|x| !x.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "CTA: transfer coefficient {i} is not finite"
            )));
        }
        let factor = basis.gram_factor().ok_or_else(|| {
            Error::InvalidArgument(format!(
                "CTA: the Gram matrix of the {k}-function basis is not positive definite"
            ))
        })?;
        let clusters = cfg.clusters.min(vertices);
        // y = L^T t per row (L lower, row-major): y_i = sum_{j >= i} L[j][i] t_j.
        let mut y = vec![0f32; rows.len()];
        y.par_chunks_mut(k)
            .zip(rows.par_chunks(k))
            .for_each(|(out, t)| {
                let mut acc = vec![0f64; k];
                for (j, tj) in t.iter().enumerate() {
                    let tj = *tj as f64;
                    if tj != 0.0 {
                        for (i, o) in acc.iter_mut().enumerate().take(j + 1) {
                            *o += factor[j * k + i] * tj;
                        }
                    }
                }
                for (o, a) in out.iter_mut().zip(&acc) {
                    *o = *a as f32;
                }
            });
        let d = Data {
            y: &y,
            views,
            k,
            ranks: cfg.ranks,
        };
        // Features: the view-averaged y rows.
        let feature: Vec<f32> = (0..vertices)
            .into_par_iter()
            .flat_map_iter(|v| {
                let s = d.slice(v);
                (0..k).map(move |i| {
                    ((0..views).map(|j| s[j * k + i] as f64).sum::<f64>() / views as f64) as f32
                })
            })
            .collect();
        let mut assign = match initial {
            None => super::cpca::kmeans(&feature, k, clusters, 8, cfg.seed),
            Some(a) => {
                if a.len() != vertices || a.iter().any(|&c| c as usize >= clusters) {
                    return Err(Error::InvalidArgument(format!(
                        "CTA: an initial clustering of {} entries for {vertices} vertices in \
                         {clusters} clusters",
                        a.len()
                    )));
                }
                a.to_vec()
            }
        };
        let members_of = |assign: &[u32]| {
            let mut m: Vec<Vec<usize>> = vec![Vec::new(); clusters];
            for (v, &c) in assign.iter().enumerate() {
                m[c as usize].push(v);
            }
            m
        };
        let mut members = members_of(&assign);
        let mut models: Vec<Model> = members
            .par_iter()
            .enumerate()
            .map(|(c, list)| initial_model(&d, list, cfg.sweeps, cfg.seed ^ (c as u64 + 1)))
            .collect();
        let total = |assign: &[u32], models: &[Model]| -> f64 {
            (0..vertices)
                .into_par_iter()
                .map(|v| d.error(&models[assign[v] as usize], v))
                .sum()
        };
        let mut history = vec![total(&assign, &models)];
        for _ in 0..cfg.iterations {
            // Centroids of the features, for the candidate lists.
            let mut centres = vec![0f32; clusters * k];
            for (c, list) in members.iter().enumerate() {
                for &v in list {
                    for i in 0..k {
                        centres[c * k + i] += feature[v * k + i] / list.len() as f32;
                    }
                }
            }
            let next: Vec<u32> = (0..vertices)
                .into_par_iter()
                .map(|v| {
                    let f = &feature[v * k..(v + 1) * k];
                    let own = assign[v] as usize;
                    let mut near: Vec<(f32, usize)> = (0..clusters)
                        .filter(|&c| !members[c].is_empty() && c != own)
                        .map(|c| (super::cpca::dist2(f, &centres[c * k..(c + 1) * k]), c))
                        .collect();
                    let take = CANDIDATES.min(near.len());
                    if take > 0 {
                        near.select_nth_unstable_by(take - 1, |a, b| a.0.total_cmp(&b.0));
                    }
                    let mut best = (d.error(&models[own], v), own);
                    for &(_, c) in &near[..take] {
                        let e = d.error(&models[c], v);
                        if e < best.0 {
                            best = (e, c);
                        }
                    }
                    best.1 as u32
                })
                .collect();
            if next == assign {
                break;
            }
            assign = next;
            members = members_of(&assign);
            history.push(total(&assign, &models));
            models
                .par_iter_mut()
                .zip(members.par_iter())
                .for_each(|(m, list)| hooi(&d, m, list, cfg.sweeps));
            history.push(total(&assign, &models));
        }
        // Output: coefficients, cores, factors (the light factor back to coefficient space).
        let norm2: f64 = y.iter().map(|x| (*x as f64).powi(2)).sum();
        let coeffs: Vec<f32> = (0..vertices)
            .into_par_iter()
            .flat_map_iter(|v| {
                d.captured(&models[assign[v] as usize], v)
                    .2
                    .into_iter()
                    .map(|x| x as f32)
            })
            .collect();
        let mut cores = vec![0f32; clusters * rv * rw * rl];
        let mut view_factors = vec![0f32; clusters * views * rw];
        let mut light_factors = vec![0f32; clusters * k * rl];
        for (c, m) in models.iter().enumerate() {
            for a in 0..rv {
                for bc in 0..rw * rl {
                    cores[c * rv * rw * rl + a * rw * rl + bc] = m.q[bc * rv + a] as f32;
                }
            }
            for (o, x) in view_factors[c * views * rw..(c + 1) * views * rw]
                .iter_mut()
                .zip(&m.w)
            {
                *o = *x as f32;
            }
            for col in 0..rl {
                let b: Vec<f32> = (0..k).map(|kk| m.l[kk * rl + col] as f32).collect();
                let x = solve_upper_transposed(&factor, k, &b);
                for kk in 0..k {
                    light_factors[c * k * rl + kk * rl + col] = x[kk] as f32;
                }
            }
        }
        let err = *history.last().unwrap_or(&0.0);
        Ok(Cta {
            basis: basis.clone(),
            vertices,
            views,
            clusters,
            ranks: cfg.ranks,
            cluster_of: assign,
            view_factors,
            light_factors,
            cores,
            coeffs,
            rel_l2: if norm2 > 0.0 {
                (err / norm2).sqrt()
            } else {
                0.0
            },
            history,
        })
    }

    /// Checks sizes, ranges and values (the GPU indexes with them).
    pub fn check(&self) -> Result<()> {
        let [rv, rw, rl] = self.ranks;
        let (k, c, n, vv) = (self.basis.len(), self.clusters, self.vertices, self.views);
        let ok = n > 0
            && c > 0
            && vv > 0
            && rv > 0
            && rw > 0
            && rl > 0
            && self.cluster_of.len() == n
            && self.coeffs.len() == n * rv
            && self.cores.len() == c * rv * rw * rl
            && self.view_factors.len() == c * vv * rw
            && self.light_factors.len() == c * k * rl;
        if !ok {
            return Err(Error::InvalidArgument(format!(
                "CTA transfer: array sizes do not match {n} vertices, {c} clusters, {vv} views, \
                 {k} basis functions and ranks ({rv}, {rw}, {rl})"
            )));
        }
        if let Some(v) = self.cluster_of.iter().position(|&x| x as usize >= c) {
            return Err(Error::InvalidArgument(format!(
                "CTA transfer: vertex {v} is in cluster {} of {c}",
                self.cluster_of[v]
            )));
        }
        let finite = |x: &[f32]| x.iter().all(|v| v.is_finite());
        if !(finite(&self.coeffs)
            && finite(&self.cores)
            && finite(&self.view_factors)
            && finite(&self.light_factors))
        {
            return Err(Error::InvalidArgument(
                "CTA transfer: a value is not finite".into(),
            ));
        }
        if let Some(i) = first_beyond_half(&self.coeffs) {
            return Err(Error::InvalidArgument(format!(
                "CTA transfer: vertex coefficient {i} ({}) is beyond half precision's range \
                 (+-{HALF_MAX}), in which the GPU streams the coefficients",
                self.coeffs[i]
            )));
        }
        Ok(())
    }

    /// Writes the compressed transfer as a cache file ([`CtaFile`]), atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.check()
            .map_err(|e| Error::input(path, e.to_string()))?;
        CtaFile {
            axes: Cow::Borrowed(&self.basis.axes),
            sharpness: self.basis.sharpness,
            vertices: self.vertices,
            views: self.views,
            clusters: self.clusters,
            ranks: self.ranks,
            cluster_of: Cow::Borrowed(&self.cluster_of),
            view_factors: Cow::Borrowed(&self.view_factors),
            light_factors: Cow::Borrowed(&self.light_factors),
            cores: Cow::Borrowed(&self.cores),
            coeffs: Cow::Borrowed(&self.coeffs),
            rel_l2: self.rel_l2,
            history: Cow::Borrowed(&self.history),
        }
        .save(path)
    }

    /// Reads a file written by [`Cta::save`], checking the file ([`CtaFile::load`]) and the
    /// values ([`Cta::check`]); every error names the file.
    pub fn load(path: &Path) -> Result<Cta> {
        let f = CtaFile::load(path)?;
        let c = Cta {
            basis: Basis {
                axes: f.axes.into_owned(),
                sharpness: f.sharpness,
            },
            vertices: f.vertices,
            views: f.views,
            clusters: f.clusters,
            ranks: f.ranks,
            cluster_of: f.cluster_of.into_owned(),
            view_factors: f.view_factors.into_owned(),
            light_factors: f.light_factors.into_owned(),
            cores: f.cores.into_owned(),
            coeffs: f.coeffs.into_owned(),
            rel_l2: f.rel_l2,
            history: f.history.into_owned(),
        };
        c.check()
            .map_err(|e| Error::input(path, format!("CTA transfer file: {e}")))?;
        Ok(c)
    }

    /// Vertex v's coefficient a as the runtime holds it: half precision (the GPU's
    /// coefficient image is f16; [`Cta::check`] keeps the model's values in its range).
    pub fn coeff(&self, v: usize, a: usize) -> f32 {
        half_round(self.coeffs[v * self.ranks[0] + a])
    }

    /// Vertex v's reconstructed V x K transfer matrix (f64 sums of the f32 factors and the
    /// model's f32 coefficients, before their rounding to half precision).
    pub fn reconstruct(&self, v: usize) -> Vec<f64> {
        let [rv, rw, rl] = self.ranks;
        let (k, vv) = (self.basis.len(), self.views);
        let c = self.cluster_of[v] as usize;
        let core = &self.cores[c * rv * rw * rl..(c + 1) * rv * rw * rl];
        let u = &self.coeffs[v * rv..(v + 1) * rv];
        // S = sum_a u_a G[a]: r_w x r_l.
        let mut s = vec![0f64; rw * rl];
        for a in 0..rv {
            for (x, g) in s.iter_mut().zip(&core[a * rw * rl..(a + 1) * rw * rl]) {
                *x += u[a] as f64 * *g as f64;
            }
        }
        let w = &self.view_factors[c * vv * rw..(c + 1) * vv * rw];
        let l = &self.light_factors[c * k * rl..(c + 1) * k * rl];
        let mut out = vec![0f64; vv * k];
        for j in 0..vv {
            // r = W[j] S: r_l.
            let r: Vec<f64> = (0..rl)
                .map(|cc| (0..rw).map(|b| w[j * rw + b] as f64 * s[b * rl + cc]).sum())
                .collect();
            for kk in 0..k {
                out[j * k + kk] = (0..rl).map(|cc| l[kk * rl + cc] as f64 * r[cc]).sum();
            }
        }
        out
    }

    /// The per-frame cluster tables the GPU computes in pass `srbf cta project`:
    /// M_c[a, b] = sum_c' G_c[a, b, c'] (L_c^T c^)[c'], per channel (clusters x r_v x r_w RGB).
    pub fn project(&self, coeffs: &[[f32; 3]]) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        let [rv, rw, rl] = self.ranks;
        let k = self.basis.len();
        if coeffs.len() != k {
            return Err(Error::InvalidArgument(format!(
                "CTA project: {} lighting coefficients for a {k}-function basis",
                coeffs.len()
            )));
        }
        let mut out = vec![[0f64; 3]; self.clusters * rv * rw];
        for c in 0..self.clusters {
            let l = &self.light_factors[c * k * rl..(c + 1) * k * rl];
            let mut y = vec![[0f64; 3]; rl];
            for (kk, cf) in coeffs.iter().enumerate() {
                for cc in 0..rl {
                    for ch in 0..3 {
                        y[cc][ch] += l[kk * rl + cc] as f64 * cf[ch] as f64;
                    }
                }
            }
            let core = &self.cores[c * rv * rw * rl..];
            for ab in 0..rv * rw {
                let o = &mut out[c * rv * rw + ab];
                for cc in 0..rl {
                    let g = core[ab * rl + cc] as f64;
                    for ch in 0..3 {
                        o[ch] += g * y[cc][ch];
                    }
                }
            }
        }
        Ok(out)
    }

    /// Whether the GPU keeps a vertex's u32 cluster id in its last coefficient texel: eight
    /// half-precision coefficients fill a texel, and r_v % 8 in 1..=6 leaves its last
    /// component free (glsl/srbf/cta_shade.comp, `PACKED_CLUSTER`).
    pub fn cluster_in_texel(&self) -> bool {
        (1..=6).contains(&(self.ranks[0] % 8))
    }

    /// Transfer bytes per vertex as the GPU reads them each frame (the f16 coefficients in
    /// whole 16-byte texels of eight, and the u32 cluster id unless it fits in the last
    /// texel: 2 r_v + 4 when r_v % 8 is 0 or 6, more otherwise) and with the per-cluster
    /// tables (f32) amortised over the vertices.
    pub fn bytes_per_vertex(&self) -> (usize, f64) {
        let [rv, rw, rl] = self.ranks;
        let stream = 16 * rv.div_ceil(8) + if self.cluster_in_texel() { 0 } else { 4 };
        let tables = 4 * self.clusters * (rv * rw * rl + self.views * rw + self.basis.len() * rl);
        (stream, stream as f64 + tables as f64 / self.vertices as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Subspace iteration finds the same leading eigenpairs as Jacobi (a PSD matrix of 120
    /// rows with a decaying spectrum).
    #[test]
    fn leading_by_iteration_matches_jacobi() {
        let (n, r) = (120, 6);
        let mut rng = Rng::new(11);
        let b: Vec<f64> = (0..n * n).map(|_| rng.f32() as f64 - 0.5).collect();
        // A = B D B^T with D decaying.
        let mut a = vec![0f64; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n)
                    .map(|t| b[i * n + t] * b[j * n + t] * 0.8f64.powi(t as i32))
                    .sum();
            }
        }
        let (v1, e1) = leading(a.clone(), n, r);
        let (v2, e2) = leading_jacobi(a, n, r);
        for c in 0..r {
            assert!(
                (e1[c] - e2[c]).abs() <= 1e-9 * e2[0],
                "{c}: {} vs {}",
                e1[c],
                e2[c]
            );
            let dot: f64 = (0..n).map(|i| v1[i * r + c] * v2[i * r + c]).sum();
            assert!(dot > 1.0 - 1e-8, "{c}: {dot}");
        }
    }

    /// p_v = vec(W^T Y_v L) by a direct triple sum, against both contraction orders of
    /// `Data::project` (light rank below and above the view rank).
    #[test]
    fn both_contraction_orders_project_alike() {
        let mut rng = Rng::new(3);
        let (vv, k) = (7, 30);
        let y: Vec<f32> = (0..vv * k).map(|_| rng.f32() - 0.5).collect();
        for ranks in [[2, 5, 2], [2, 2, 12]] {
            let [_, rw, rl] = ranks;
            let m = Model {
                w: (0..vv * rw).map(|_| rng.f32() as f64 - 0.5).collect(),
                l: (0..k * rl).map(|_| rng.f32() as f64 - 0.5).collect(),
                q: Vec::new(),
            };
            let d = Data {
                y: &y,
                views: vv,
                k,
                ranks,
            };
            let p = d.project(&m, 0);
            for b in 0..rw {
                for c in 0..rl {
                    let mut want = 0f64;
                    for j in 0..vv {
                        for kk in 0..k {
                            want += m.w[j * rw + b] * y[j * k + kk] as f64 * m.l[kk * rl + c];
                        }
                    }
                    assert!((p[b * rl + c] - want).abs() < 1e-12, "{ranks:?} ({b}, {c})");
                }
            }
        }
    }

    /// Two groups of vertices (alternating), each exactly a Tucker model of ranks (2, 3, 4) with random
    /// factors (plus `noise`), V = 6 views, K = 20 functions.
    pub(crate) fn synthetic(noise: f32, seed: u64) -> (Basis, Vec<f32>, usize, usize) {
        let (k, vv, n) = (20, 6, 120);
        let basis = Basis::fibonacci(k);
        let mut rng = Rng::new(seed);
        let mut g = || rng.f32() * 2.0 - 1.0;
        let models: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = (0..2)
            .map(|_| {
                (
                    (0..2 * 3 * 4).map(|_| g()).collect(),
                    (0..vv * 3).map(|_| g()).collect(),
                    (0..k * 4).map(|_| g()).collect(),
                )
            })
            .collect();
        let mut rows = vec![0f32; n * vv * k];
        for v in 0..n {
            let (core, w, l) = &models[v % 2];
            // Coefficients around (2, 0): each group's vertices sit away from the origin, as
            // real transfer does (it is mostly positive), so k-means can tell the groups
            // apart (it cannot separate subspaces through the origin).
            let u = [2.0 + g(), g()];
            for j in 0..vv {
                for kk in 0..k {
                    let mut x = 0f32;
                    for a in 0..2 {
                        for b in 0..3 {
                            for c in 0..4 {
                                x += u[a] * core[a * 12 + b * 4 + c] * w[j * 3 + b] * l[kk * 4 + c];
                            }
                        }
                    }
                    rows[(v * vv + j) * k + kk] = x + noise * g();
                }
            }
        }
        (basis, rows, n, vv)
    }

    /// [`synthetic`] data compressed into 2 clusters at ranks (2, 3, 4).
    fn two_groups(noise: f32, seed: u64) -> (Cta, Basis, Vec<f32>, usize, usize) {
        let (basis, rows, n, vv) = synthetic(noise, seed);
        let cfg = CtaConfig {
            clusters: 2,
            ranks: [2, 3, 4],
            ..CtaConfig::default()
        };
        let cta = Cta::compress(&basis, &rows, n, vv, &cfg).unwrap();
        (cta, basis, rows, n, vv)
    }

    #[test]
    fn exact_tucker_data_is_reconstructed() {
        let (cta, basis, rows, n, vv) = two_groups(0.0, 3);
        cta.check().unwrap();
        // The groups alternate; each cluster ends holding one group.
        for v in 2..n {
            assert_eq!(cta.cluster_of[v], cta.cluster_of[v % 2], "vertex {v}");
        }
        // f32 storage of the factors: ~1e-6 relative per entry, summed over 24 core terms.
        assert!(cta.rel_l2 < 1e-5, "{}", cta.rel_l2);
        let k = basis.len();
        let (mut num, mut den) = (0f64, 0f64);
        for v in 0..n {
            let r = cta.reconstruct(v);
            for (a, b) in r.iter().zip(&rows[v * vv * k..(v + 1) * vv * k]) {
                num += (a - *b as f64).powi(2);
                den += (*b as f64).powi(2);
            }
        }
        // In coefficient space the Gram metric's conditioning (K = 20, mu = 1.2) amplifies the
        // f32 rounding: 1e-3 still fails any wrong factor or index (those are O(1)).
        assert!((num / den).sqrt() < 1e-3, "{}", (num / den).sqrt());
    }

    /// Reassignment and refits never raise the error: on noisy two-group data started from a
    /// clustering that puts a fifth of each group in the wrong cluster, the history is non-increasing at every
    /// stage (each reassignment and each HOOI refit), something moved, and the error fell
    /// to the noise's level.
    #[test]
    fn reassignment_lowers_the_error_monotonically() {
        for seed in [3, 4, 5] {
            let (basis, rows, n, vv) = synthetic(0.02, seed);
            // Groups alternate with v; this puts a fifth of each group in the other's cluster
            // (a half-and-half start is a symmetric fixed point: both models fit the mixture).
            let mixed: Vec<u32> = (0..n as u32)
                .map(|v| if v % 5 == 0 { 1 - v % 2 } else { v % 2 })
                .collect();
            let cta = Cta::compress_from(
                &basis,
                &rows,
                n,
                vv,
                &CtaConfig {
                    clusters: 2,
                    ranks: [2, 3, 4],
                    iterations: 6,
                    ..CtaConfig::default()
                },
                Some(&mixed),
            )
            .unwrap();
            let h = &cta.history;
            eprintln!("seed {seed}: {h:?}");
            assert!(h.len() >= 3, "no reassignment happened: {h:?}");
            for pair in h.windows(2) {
                // Equal up to the rounding of a sum over 120 x 6 x 20 entries.
                assert!(pair[1] <= pair[0] * (1.0 + 1e-9), "{h:?}");
            }
            assert!(h[h.len() - 1] < 0.1 * h[0], "{h:?}");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let (basis, rows, n, vv) = synthetic(0.0, 3);
        let cfg = CtaConfig {
            clusters: 2,
            ranks: [2, 3, 4],
            ..CtaConfig::default()
        };
        for (ranks, what) in [
            ([0, 3, 4], "vertex 0"),
            ([2, 7, 4], "view 7"),
            ([13, 3, 4], "vertex 13"),
        ] {
            let e = Cta::compress(&basis, &rows, n, vv, &CtaConfig { ranks, ..cfg })
                .unwrap_err()
                .to_string();
            assert!(e.contains(what), "{e}");
        }
        let e = Cta::compress(&basis, &rows[1..], n, vv, &cfg)
            .unwrap_err()
            .to_string();
        assert!(e.contains("transfer coefficients"), "{e}");
        let mut nan = rows.clone();
        nan[7] = f32::NAN;
        let e = Cta::compress(&basis, &nan, n, vv, &cfg)
            .unwrap_err()
            .to_string();
        assert!(e.contains("coefficient 7"), "{e}");
        let mut cta = Cta::compress(&basis, &rows, n, vv, &cfg).unwrap();
        cta.cluster_of[5] = 9;
        assert!(cta.check().unwrap_err().to_string().contains("vertex 5"));
        // A coefficient half precision cannot hold (the GPU streams them as f16).
        let mut cta = Cta::compress(&basis, &rows, n, vv, &cfg).unwrap();
        cta.coeffs[3] = 7.0e4;
        let e = cta.check().unwrap_err().to_string();
        assert!(e.contains("coefficient 3") && e.contains("half"), "{e}");
    }

    /// The runtime's coefficients are the model's rounded to half precision: within half an
    /// f16 ulp (2^-11 relative) and exactly representable.
    #[test]
    fn streamed_coefficients_are_the_model_in_half_precision() {
        let (cta, _, _, n, _) = two_groups(0.01, 4);
        for v in 0..n {
            for a in 0..2 {
                let (model, streamed) = (cta.coeffs[v * 2 + a], cta.coeff(v, a));
                assert!(
                    (model - streamed).abs() <= model.abs() * 2f32.powi(-11) + 3e-8,
                    "{model} {streamed}"
                );
                assert_eq!(half_round(streamed), streamed);
            }
        }
        assert!(
            (0..n * 2).any(|i| cta.coeff(i / 2, i % 2) != cta.coeffs[i]),
            "no coefficient was rounded"
        );
        // Bytes read per vertex: whole texels of eight halves, plus the cluster id unless
        // the last texel has room for it.
        for (rv, bytes) in [
            (2, 16),
            (6, 16),
            (7, 20),
            (8, 20),
            (15, 36),
            (30, 64),
            (32, 68),
        ] {
            let mut c = cta.clone();
            c.ranks[0] = rv;
            assert_eq!(c.bytes_per_vertex().0, bytes, "r_v {rv}");
        }
    }
}
