//! Clustered PCA of the transfer (after Sloan et al. 2003, "Clustered principal components
//! for precomputed radiance transfer"): the vertices are clustered, and within a cluster each
//! vertex's transfer vector is the cluster's mean plus a few weighted principal axes:
//! t_v ~ m_c + sum_i w_vi a_ci. Shading is linear in t, so per frame the GPU projects the
//! lighting once per cluster row (m_c . c, a_ci . c) and each vertex only combines M of
//! them: the per-vertex work and the bytes streamed drop from K to M + 1.
//!
//! Distances are measured between the *functions* the coefficients stand for: with the
//! basis's Gram matrix G = L L^T, ||T~||^2 = t^T G t = |L^T t|^2. Clustering and PCA run on
//! y = L^T t, so the error that PCA minimises is the transfer's L2 error over the sphere, not
//! an error in coefficients (which for overlapping SGs would spend components on cancelling
//! coefficient patterns that hardly change the function). The rows are mapped back to
//! coefficient space (L^-T) for the runtime.
//!
//! [`Cpca::exact`] is the uncompressed transfer in the same form (one cluster, zero mean, the
//! identity as its axes), so the GPU has one code path.

use super::transfer::{Basis, Transfer};
use crate::error::{Error, Result};
use crate::geom::Rng;
use crate::geom::linalg::{dot, jacobi_eigen, orthonormalise, solve_upper_transposed};
use crate::io::f16::{HALF_MAX, first_beyond_half, half_round};
use crate::io::transfer_cache::CpcaFile;
use rayon::prelude::*;
use std::borrow::Cow;
use std::path::Path;

/// How to compress.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct CpcaConfig {
    pub clusters: usize,
    /// Principal axes per cluster (M).
    pub components: usize,
    /// Lloyd (k-means) iterations before the PCA.
    pub kmeans_iterations: usize,
    /// CPCA refinements after it: every vertex moves to the cluster that reconstructs it
    /// best, then each cluster's PCA is recomputed.
    pub refinements: usize,
    pub seed: u64,
}

impl Default for CpcaConfig {
    fn default() -> Self {
        CpcaConfig {
            clusters: 64,
            components: 16,
            kmeans_iterations: 8,
            refinements: 2,
            seed: 1,
        }
    }
}

/// Clusters considered per vertex in a refinement (the nearest by mean).
const REFINE_CANDIDATES: usize = 6;

/// A transfer in clustered-PCA form.
#[derive(Clone, Debug, PartialEq)]
pub struct Cpca {
    /// The transfer basis (K functions): every row holds K coefficients on it.
    pub basis: Basis,
    pub vertices: usize,
    pub clusters: usize,
    /// M: weights per vertex.
    pub components: usize,
    /// The cluster of each vertex.
    pub cluster_of: Vec<u32>,
    /// Per cluster, M + 1 rows of K coefficients: the mean, then the axes.
    pub rows: Vec<f32>,
    /// Vertex-major, M per vertex.
    pub weights: Vec<f32>,
    /// sqrt(sum_v |T~_v - T^_v|^2 / sum_v |T~_v|^2) in the function-space L2 norm, T~ the
    /// projected transfer and T^ its reconstruction (0 for [`Cpca::exact`]).
    pub rel_l2: f64,
}

impl Cpca {
    /// The uncompressed transfer: one cluster, zero mean, identity axes, weights = t.
    pub fn exact(t: &Transfer) -> Cpca {
        let k = t.basis.len();
        let mut rows = vec![0f32; (k + 1) * k];
        for i in 0..k {
            rows[(i + 1) * k + i] = 1.0;
        }
        Cpca {
            basis: t.basis.clone(),
            vertices: t.vertices,
            clusters: 1,
            components: k,
            cluster_of: vec![0; t.vertices],
            rows,
            weights: t.coeffs.clone(),
            rel_l2: 0.0,
        }
    }

    /// Rows per cluster (M + 1).
    pub fn rows_per_cluster(&self) -> usize {
        self.components + 1
    }

    /// Compresses `t`. Deterministic for a given config.
    pub fn compress(t: &Transfer, cfg: &CpcaConfig) -> Result<Cpca> {
        let k = t.basis.len();
        let n = t.vertices;
        if cfg.clusters == 0 || cfg.components == 0 || cfg.components > k {
            return Err(Error::InvalidArgument(format!(
                "CPCA: {} clusters x {} components for a {k}-function basis (need >= 1 \
                 cluster and 1..={k} components)",
                cfg.clusters, cfg.components
            )));
        }
        if n == 0 || t.coeffs.len() != n * k {
            return Err(Error::InvalidArgument(format!(
                "CPCA: {} transfer coefficients for {n} vertices x {k}",
                t.coeffs.len()
            )));
        }
        let clusters = cfg.clusters.min(n);
        let l = t.basis.gram_factor().ok_or_else(|| {
            Error::InvalidArgument(format!(
                "CPCA: the Gram matrix of the {k}-function basis is not positive definite"
            ))
        })?;
        let l = &l;
        // y_v = L^T t_v (L lower triangular, row-major): row i of L^T, contiguous.
        let lt: Vec<f64> = (0..k * k).map(|x| l[(x % k) * k + x / k]).collect();
        let y: Vec<f32> = t
            .coeffs
            .par_chunks(k)
            .flat_map_iter(|tv| {
                let lt = &lt;
                (0..k).map(move |i| {
                    let s: f64 = lt[i * k + i..(i + 1) * k]
                        .iter()
                        .zip(&tv[i..])
                        .map(|(a, b)| a * *b as f64)
                        .sum();
                    s as f32
                })
            })
            .collect();
        let mut assign = kmeans(&y, k, clusters, cfg.kmeans_iterations, cfg.seed);
        let m = cfg.components;
        let mut models = fit_clusters(&y, k, &assign, clusters, m, cfg.seed);
        for _ in 0..cfg.refinements {
            let next: Vec<u32> = y
                .par_chunks(k)
                .map(|yv| {
                    // Candidates: the clusters with the nearest means (a cluster far from
                    // the vertex cannot reconstruct it well with a few axes); the residual
                    // decides among them.
                    let mut near: Vec<(f32, usize)> = models
                        .iter()
                        .enumerate()
                        .filter(|(_, model)| model.members > 0)
                        .map(|(c, model)| (dist2(yv, &model.mean), c))
                        .collect();
                    let take = REFINE_CANDIDATES.min(near.len());
                    near.select_nth_unstable_by(take - 1, |a, b| a.0.total_cmp(&b.0));
                    let mut best = (f64::INFINITY, 0u32);
                    for &(_, c) in &near[..take] {
                        let e = models[c].residual(yv);
                        if e < best.0 {
                            best = (e, c as u32);
                        }
                    }
                    best.1
                })
                .collect();
            if next == assign {
                break;
            }
            assign = next;
            models = fit_clusters(&y, k, &assign, clusters, m, cfg.seed);
        }
        // Weights and the error, in y space (the axes are orthonormal there).
        let per_vertex: Vec<(Vec<f32>, f64, f64)> = y
            .par_chunks(k)
            .zip(assign.par_iter())
            .map(|(yv, &c)| {
                let model = &models[c as usize];
                let w = model.weights(yv);
                let norm2: f64 = yv.iter().map(|x| (*x as f64).powi(2)).sum();
                (w, model.residual(yv), norm2)
            })
            .collect();
        let (err2, norm2) = per_vertex
            .iter()
            .fold((0.0, 0.0), |(e, n), (_, ev, nv)| (e + ev, n + nv));
        let weights: Vec<f32> = per_vertex.into_iter().flat_map(|(w, _, _)| w).collect();
        // Rows back to coefficient space: r_t = L^-T r_y.
        let mut rows = vec![0f32; clusters * (m + 1) * k];
        rows.par_chunks_mut(k).enumerate().for_each(|(r, out)| {
            let model = &models[r / (m + 1)];
            let i = r % (m + 1);
            let src = if i == 0 {
                &model.mean[..]
            } else {
                &model.axes[(i - 1) * k..i * k]
            };
            let x = solve_upper_transposed(l, k, src);
            for (o, v) in out.iter_mut().zip(x) {
                *o = v as f32;
            }
        });
        Ok(Cpca {
            basis: t.basis.clone(),
            vertices: n,
            clusters,
            components: m,
            cluster_of: assign,
            rows,
            weights,
            rel_l2: if norm2 > 0.0 {
                (err2.max(0.0) / norm2).sqrt()
            } else {
                0.0
            },
        })
    }

    /// Checks sizes, ranges and values (the GPU indexes with them).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("CPCA transfer: {what}")));
        let (k, m) = (self.basis.len(), self.components);
        if k == 0 || m == 0 || self.clusters == 0 || self.vertices == 0 {
            return bad(format!(
                "{} vertices, {} clusters, {m} components, {k} basis functions (all must be > 0)",
                self.vertices, self.clusters
            ));
        }
        if self.rows.len() != self.clusters * (m + 1) * k
            || self.weights.len() != self.vertices * m
            || self.cluster_of.len() != self.vertices
        {
            return bad(format!(
                "{} rows, {} weights, {} cluster ids for {} vertices x {} clusters x {m} \
                 components x {k}",
                self.rows.len(),
                self.weights.len(),
                self.cluster_of.len(),
                self.vertices,
                self.clusters
            ));
        }
        if let Some(v) = self
            .cluster_of
            .iter()
            .position(|&c| c as usize >= self.clusters)
        {
            return bad(format!(
                "vertex {v} is in cluster {} of {}",
                self.cluster_of[v], self.clusters
            ));
        }
        self.basis.check()?;
        if let Some(i) = self.rows.iter().position(|x| !x.is_finite()) {
            return bad(format!("row value {i} is not finite"));
        }
        if let Some(i) = self.weights.iter().position(|x| !x.is_finite()) {
            return bad(format!("weight {i} is not finite"));
        }
        if let Some(i) = first_beyond_half(&self.weights) {
            return bad(format!(
                "weight {i} (vertex {} component {}: {}) is beyond half precision's range \
                 (+-{HALF_MAX}), in which the GPU streams the weights",
                i / m,
                i % m,
                self.weights[i]
            ));
        }
        Ok(())
    }

    /// The transfer coefficients of vertex `v` as reconstructed.
    pub fn reconstruct(&self, v: usize) -> Vec<f32> {
        let (k, m) = (self.basis.len(), self.components);
        let base = self.cluster_of[v] as usize * (m + 1) * k;
        let mut t: Vec<f64> = self.rows[base..base + k]
            .iter()
            .map(|x| *x as f64)
            .collect();
        for (i, w) in self.weights[v * m..(v + 1) * m].iter().enumerate() {
            let row = &self.rows[base + (i + 1) * k..base + (i + 2) * k];
            for (ti, r) in t.iter_mut().zip(row) {
                *ti += *w as f64 * *r as f64;
            }
        }
        t.into_iter().map(|x| x as f32).collect()
    }

    /// CPU version of the runtime's projection step: every row against the lighting's
    /// coefficients, `clusters * (M + 1)` RGB values.
    pub fn project(&self, coeffs: &[[f32; 3]]) -> Result<Vec<[f32; 3]>> {
        let k = self.basis.len();
        if coeffs.len() != k {
            return Err(Error::InvalidArgument(format!(
                "CPCA projection: {} lighting coefficients for a {k}-function basis",
                coeffs.len()
            )));
        }
        Ok(self
            .rows
            .par_chunks(k)
            .map(|row| {
                let mut s = [0.0f64; 3];
                for (r, c) in row.iter().zip(coeffs) {
                    for ch in 0..3 {
                        s[ch] += *r as f64 * c[ch] as f64;
                    }
                }
                s.map(|x| x as f32)
            })
            .collect())
    }

    /// CPU version of the runtime: L_o,v = albedo * (p_c0 + sum_i w_vi p_ci) with p the
    /// projected rows of the vertex's cluster c. The weights are used in half precision, as
    /// the GPU stores them ([`half_round`]).
    pub fn shade(&self, coeffs: &[[f32; 3]], albedo: [f32; 3]) -> Result<Vec<[f32; 3]>> {
        self.check()?;
        let p = self.project(coeffs)?;
        let m = self.components;
        Ok((0..self.vertices)
            .into_par_iter()
            .map(|v| {
                let base = self.cluster_of[v] as usize * (m + 1);
                let mut s = p[base].map(|x| x as f64);
                for (i, w) in self.weights[v * m..(v + 1) * m].iter().enumerate() {
                    let w = half_round(*w) as f64;
                    for ch in 0..3 {
                        s[ch] += w * p[base + 1 + i][ch] as f64;
                    }
                }
                [0, 1, 2].map(|ch| (albedo[ch] as f64 * s[ch]) as f32)
            })
            .collect())
    }

    /// Bytes the runtime streams per vertex (its slot's vertex index + M half weights).
    pub fn bytes_per_vertex(&self) -> usize {
        4 + 2 * self.components
    }
}

impl Cpca {
    /// Writes the compressed transfer as a cache file ([`CpcaFile`]), atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.check()
            .map_err(|e| Error::input(path, e.to_string()))?;
        CpcaFile {
            axes: Cow::Borrowed(&self.basis.axes),
            sharpness: self.basis.sharpness,
            vertices: self.vertices,
            components: self.components,
            clusters: self.clusters,
            cluster_of: Cow::Borrowed(&self.cluster_of),
            rows: Cow::Borrowed(&self.rows),
            weights: Cow::Borrowed(&self.weights),
            rel_l2: self.rel_l2,
        }
        .save(path)
    }

    /// Reads a file written by [`Cpca::save`], checking the file ([`CpcaFile::load`]) and
    /// the values; every error names the file.
    pub fn load(path: &Path) -> Result<Cpca> {
        let file = CpcaFile::load(path)?;
        let bad = |m: String| Error::input(path, format!("CPCA transfer file: {m}"));
        let c = Cpca {
            basis: Basis {
                axes: file.axes.into_owned(),
                sharpness: file.sharpness,
            },
            vertices: file.vertices,
            clusters: file.clusters,
            components: file.components,
            cluster_of: file.cluster_of.into_owned(),
            rows: file.rows.into_owned(),
            weights: file.weights.into_owned(),
            rel_l2: file.rel_l2,
        };
        c.check().map_err(|e| bad(e.to_string()))?;
        if !c.rel_l2.is_finite() {
            return Err(bad(format!("error {}", c.rel_l2)));
        }
        Ok(c)
    }
}

/// sum_i term(a_i, b_i) in eight independent partial sums, so that it vectorises (a single
/// running sum would have to keep the order of the additions).
fn sum8(a: &[f32], b: &[f32], term: impl Fn(f32, f32) -> f32) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| term(*x, *y))
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += term(x[i], y[i]);
        }
    }
    acc.iter().sum::<f32>() + tail
}

pub(super) fn dist2(a: &[f32], b: &[f32]) -> f32 {
    sum8(a, b, |x, y| (x - y) * (x - y))
}

fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    sum8(a, b, |x, y| x * y)
}

/// k-means (k-means++ seeding, Lloyd iterations) of the rows of `y` (dimension `k`).
pub(super) fn kmeans(
    y: &[f32],
    k: usize,
    clusters: usize,
    iterations: usize,
    seed: u64,
) -> Vec<u32> {
    let n = y.len() / k;
    let row = |i: usize| &y[i * k..(i + 1) * k];
    let mut rng = Rng::new(seed);
    let mut centres: Vec<f32> = row(rng.below(n)).to_vec();
    let mut d2: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|i| dist2(row(i), &centres[..k]))
        .collect();
    for _ in 1..clusters {
        let total: f64 = d2.iter().map(|d| *d as f64).sum();
        let pick = if total > 0.0 {
            let mut target = rng.f32() as f64 * total;
            let mut pick = n - 1;
            for (i, d) in d2.iter().enumerate() {
                target -= *d as f64;
                if target <= 0.0 {
                    pick = i;
                    break;
                }
            }
            pick
        } else {
            rng.below(n)
        };
        let c = row(pick).to_vec();
        d2.par_iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = d.min(dist2(row(i), &c)));
        centres.extend_from_slice(&c);
    }
    let mut assign = vec![0u32; n];
    for _ in 0..iterations.max(1) {
        assign = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut best = (f32::INFINITY, 0u32);
                for c in 0..clusters {
                    let d = dist2(row(i), &centres[c * k..(c + 1) * k]);
                    if d < best.0 {
                        best = (d, c as u32);
                    }
                }
                best.1
            })
            .collect();
        let mut sums = vec![0f64; clusters * k];
        let mut counts = vec![0usize; clusters];
        for (i, &c) in assign.iter().enumerate() {
            counts[c as usize] += 1;
            for (s, v) in sums[c as usize * k..(c as usize + 1) * k]
                .iter_mut()
                .zip(row(i))
            {
                *s += *v as f64;
            }
        }
        for c in 0..clusters {
            if counts[c] > 0 {
                for j in 0..k {
                    centres[c * k + j] = (sums[c * k + j] / counts[c] as f64) as f32;
                }
            }
            // An empty cluster keeps its centre (a data point); it may win members back.
        }
    }
    assign
}

/// One cluster's mean and orthonormal principal axes (in y space).
struct ClusterModel {
    members: usize,
    mean: Vec<f32>,
    /// M rows of K, orthonormal.
    axes: Vec<f32>,
    k: usize,
}

impl ClusterModel {
    fn weights(&self, yv: &[f32]) -> Vec<f32> {
        let d: Vec<f32> = yv.iter().zip(&self.mean).map(|(y, m)| y - m).collect();
        self.axes
            .chunks_exact(self.k)
            .map(|a| dot_f32(&d, a))
            .collect()
    }

    /// |y - mean - A^T A (y - mean)|^2 = |y - mean|^2 - |A (y - mean)|^2.
    fn residual(&self, yv: &[f32]) -> f64 {
        let d = dist2(yv, &self.mean) as f64;
        let w: f64 = self.weights(yv).iter().map(|w| (*w as f64).powi(2)).sum();
        (d - w).max(0.0)
    }
}

fn fit_clusters(
    y: &[f32],
    k: usize,
    assign: &[u32],
    clusters: usize,
    m: usize,
    seed: u64,
) -> Vec<ClusterModel> {
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for (i, &c) in assign.iter().enumerate() {
        members[c as usize].push(i);
    }
    members
        .into_par_iter()
        .enumerate()
        .map(|(c, idx)| {
            let rows: Vec<&[f32]> = idx.iter().map(|&i| &y[i * k..(i + 1) * k]).collect();
            pca(&rows, k, m, seed ^ (c as u64 + 1))
        })
        .collect()
}

/// Subspace iterations of the PCA (the residual changes by < 0.1% beyond 20 on the bunny).
const SUBSPACE_ITERATIONS: usize = 24;

/// Mean and the top `m` principal axes of `rows` by subspace iteration on the covariance
/// with a Rayleigh-Ritz step (exact when the rows span at most `m` dimensions: the axes then
/// include that span).
fn pca(rows: &[&[f32]], k: usize, m: usize, seed: u64) -> ClusterModel {
    let n = rows.len();
    let mut mean = vec![0f64; k];
    for r in rows {
        for (s, v) in mean.iter_mut().zip(r.iter()) {
            *s += *v as f64;
        }
    }
    if n > 0 {
        mean.iter_mut().for_each(|s| *s /= n as f64);
    }
    // Covariance (upper triangle, mirrored).
    let mut cov = vec![0f64; k * k];
    let mut centred = vec![0f64; k];
    for r in rows {
        for (c, (v, mu)) in centred.iter_mut().zip(r.iter().zip(&mean)) {
            *c = *v as f64 - mu;
        }
        for i in 0..k {
            let ci = centred[i];
            if ci == 0.0 {
                continue;
            }
            let line = &mut cov[i * k..(i + 1) * k];
            for j in i..k {
                line[j] += ci * centred[j];
            }
        }
    }
    for i in 0..k {
        for j in 0..i {
            cov[i * k + j] = cov[j * k + i];
        }
    }
    // Subspace iteration with p extra vectors, then Rayleigh-Ritz to keep the best m.
    let b = (m + 4).min(k);
    let mut rng = Rng::new(seed);
    let mut q: Vec<f64> = (0..b * k).map(|_| rng.f32() as f64 - 0.5).collect();
    orthonormalise(&mut q, k);
    // The rows of `q` times the (symmetric) covariance.
    let times_cov = |q: &[f64], out: &mut [f64]| {
        for (zi, qi) in out.chunks_exact_mut(k).zip(q.chunks_exact(k)) {
            for (r, o) in zi.iter_mut().enumerate() {
                *o = dot(&cov[r * k..(r + 1) * k], qi);
            }
        }
    };
    let mut z = vec![0f64; b * k];
    for _ in 0..SUBSPACE_ITERATIONS {
        times_cov(&q, &mut z);
        std::mem::swap(&mut q, &mut z);
        orthonormalise(&mut q, k);
    }
    // Rayleigh-Ritz: H = Q C Q^T (b x b), its eigenvectors rotate Q.
    times_cov(&q, &mut z);
    let mut h = vec![0f64; b * b];
    for i in 0..b {
        for j in 0..b {
            h[i * b + j] = dot(&q[i * k..(i + 1) * k], &z[j * k..(j + 1) * k]);
        }
    }
    let (values, vectors) = jacobi_eigen(h, b);
    let mut order: Vec<usize> = (0..b).collect();
    order.sort_by(|&a, &c| values[c].total_cmp(&values[a]));
    let mut axes = vec![0f32; m * k];
    for (slot, &e) in order.iter().take(m).enumerate() {
        for j in 0..b {
            let coef = vectors[j * b + e];
            for (a, qv) in axes[slot * k..(slot + 1) * k]
                .iter_mut()
                .zip(&q[j * k..(j + 1) * k])
            {
                *a += (coef * qv) as f32;
            }
        }
    }
    ClusterModel {
        members: n,
        mean: mean.into_iter().map(|x| x as f32).collect(),
        axes,
        k,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::srbf::transfer::Basis;

    fn transfer(k: usize, n: usize, seed: u64) -> Transfer {
        // Vertices drawn from a few low-dimensional families, plus noise.
        let mut rng = Rng::new(seed);
        let bases: Vec<Vec<f32>> = (0..6)
            .map(|_| (0..k).map(|_| rng.f32() - 0.5).collect())
            .collect();
        let mut coeffs = Vec::with_capacity(n * k);
        for v in 0..n {
            let fam = v % 3;
            let (a, b) = (rng.f32(), rng.f32());
            for (p, q) in bases[2 * fam].iter().zip(&bases[2 * fam + 1]) {
                coeffs.push(p * a + q * b + fam as f32 - 1.0 + (rng.f32() - 0.5) * 1e-4);
            }
        }
        Transfer {
            basis: Basis::fibonacci(k),
            vertices: n,
            coeffs,
            projection_rel_l2: 0.0,
        }
    }

    #[test]
    fn exact_form_reproduces_the_transfer() {
        let t = transfer(16, 30, 2);
        let c = Cpca::exact(&t);
        c.check().unwrap();
        for v in 0..t.vertices {
            assert_eq!(c.reconstruct(v), t.coeffs[v * 16..(v + 1) * 16]);
        }
    }

    #[test]
    fn recovers_low_rank_families() {
        // Three families, each an affine 2D subspace: 3 clusters x 2 components reconstruct
        // them up to the noise.
        let t = transfer(32, 600, 3);
        let c = Cpca::compress(
            &t,
            &CpcaConfig {
                clusters: 3,
                components: 2,
                ..CpcaConfig::default()
            },
        )
        .unwrap();
        assert!(c.rel_l2 < 1e-3, "rel L2 {}", c.rel_l2);
        let mut worst = 0f32;
        for v in 0..t.vertices {
            for (a, b) in c.reconstruct(v).iter().zip(&t.coeffs[v * 32..(v + 1) * 32]) {
                worst = worst.max((a - b).abs());
            }
        }
        assert!(worst < 5e-3, "worst coefficient error {worst}");
        // Fewer components than the families need: a real error, reported.
        let one = Cpca::compress(
            &t,
            &CpcaConfig {
                clusters: 3,
                components: 1,
                ..CpcaConfig::default()
            },
        )
        .unwrap();
        assert!(
            one.rel_l2 > 10.0 * c.rel_l2,
            "{} vs {}",
            one.rel_l2,
            c.rel_l2
        );
    }

    #[test]
    fn shading_through_the_rows_equals_shading_the_reconstruction() {
        let t = transfer(24, 200, 4);
        let c = Cpca::compress(
            &t,
            &CpcaConfig {
                clusters: 5,
                components: 3,
                ..CpcaConfig::default()
            },
        )
        .unwrap();
        // Weights already at half precision (shade uses them so), for an exact comparison.
        let mut c = c;
        c.weights.iter_mut().for_each(|w| *w = half_round(*w));
        let mut rng = Rng::new(9);
        let coeffs: Vec<[f32; 3]> = (0..24).map(|_| [rng.f32(), rng.f32(), rng.f32()]).collect();
        let fast = c.shade(&coeffs, [0.5, 1.0, 2.0]).unwrap();
        for (v, f) in fast.iter().enumerate() {
            let t = c.reconstruct(v);
            for ch in 0..3 {
                let direct: f64 = t
                    .iter()
                    .zip(&coeffs)
                    .map(|(a, b)| *a as f64 * b[ch] as f64)
                    .sum::<f64>()
                    * [0.5, 1.0, 2.0][ch];
                assert!(
                    (f[ch] as f64 - direct).abs() <= 1e-4 * direct.abs().max(1.0),
                    "vertex {v} channel {ch}: {} vs {direct}",
                    f[ch]
                );
            }
        }
    }

    #[test]
    fn save_load_round_trip_and_corruption() {
        let t = transfer(12, 40, 6);
        let c = Cpca::compress(
            &t,
            &CpcaConfig {
                clusters: 3,
                components: 2,
                ..CpcaConfig::default()
            },
        )
        .unwrap();
        let dir = std::env::temp_dir().join(format!("vkshade-cpca-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.cpca");
        c.save(&path).unwrap();
        assert_eq!(Cpca::load(&path).unwrap(), c);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[crate::io::transfer_cache::CPCA_HEADER + 5] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let e = Cpca::load(&path).unwrap_err().to_string();
        assert!(e.contains("checksum") && e.contains("t.cpca"), "{e}");
        bytes.truncate(bytes.len() - 4);
        std::fs::write(&path, &bytes).unwrap();
        assert!(Cpca::load(&path).unwrap_err().to_string().contains("bytes"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_configurations_are_errors() {
        let t = transfer(8, 10, 5);
        for (clusters, components) in [(0, 2), (2, 0), (2, 9)] {
            assert!(
                Cpca::compress(
                    &t,
                    &CpcaConfig {
                        clusters,
                        components,
                        ..CpcaConfig::default()
                    }
                )
                .is_err()
            );
        }
        let mut c = Cpca::exact(&t);
        c.cluster_of[3] = 1;
        assert!(c.check().is_err());
        let mut c = Cpca::exact(&t);
        c.weights[0] = f32::NAN;
        assert!(c.check().is_err());
    }
}
