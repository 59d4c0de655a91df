//! Clustered PCA of per-vertex glossy transfer *matrices*, the baseline CTA is compared
//! against (`vkshade bench srbf --compare`): as in Sloan et al. 2003's glossy CPCA, each
//! vertex's whole V x K matrix (V view nodes x K basis functions) is one vector, and within
//! a cluster it is the cluster's mean matrix plus M weighted principal matrices:
//! T_v ~ A_c0 + sum_i w_vi A_ci. CPU only (there is no GPU path for it): per frame each
//! cluster's M + 1 matrices are applied to the lighting coefficients (V values per matrix
//! and channel), and each vertex combines M of them at its four view taps.
//!
//! As in [`super::cpca`], distances are between the functions the coefficients stand for:
//! every row is mapped to y = L^T t (G = L L^T the basis's Gram matrix), so the error PCA
//! minimises is the function-space L2 error summed over the view nodes. The principal axes
//! come from the members' Gram matrix (n_c x n_c, not the D x D covariance: D = V K is
//! 9,216 at 36 views x 256 functions).

use super::cpca::{CpcaConfig, dist2, kmeans};
use super::glossy::{ViewBasis, local_view};
use super::transfer::Basis;
use crate::error::{Error, Result};
use crate::geom::Rng;
use crate::geom::linalg::{jacobi_eigen, orthonormalise, solve_upper_transposed};
use crate::io::f16::{HALF_MAX, first_beyond_half, half_round};
use glam::Vec3;
use rayon::prelude::*;

/// Subspace iterations on a cluster's Gram matrix before the Rayleigh-Ritz step.
const SUBSPACE_ITERATIONS: usize = 40;
/// Clusters considered per vertex in a refinement (the nearest by mean).
const REFINE_CANDIDATES: usize = 4;

/// Glossy transfer in clustered-PCA form (f32 as stored).
#[derive(Clone, Debug)]
pub struct MatrixCpca {
    pub basis: Basis,
    pub vertices: usize,
    /// V: view nodes per vertex.
    pub views: usize,
    pub clusters: usize,
    /// M: weights per vertex.
    pub components: usize,
    pub cluster_of: Vec<u32>,
    /// Per cluster, M + 1 matrices of V x K coefficients (row-major): the mean, then the
    /// axes.
    pub matrices: Vec<f32>,
    /// Vertex-major, M per vertex (the model's f32; [`MatrixCpca::shade`] rounds them to
    /// half precision).
    pub weights: Vec<f32>,
    /// sqrt(sum_v |T~_v - T^_v|^2 / sum_v |T~_v|^2), function-space L2 summed over the views.
    pub rel_l2: f64,
}

/// One cluster's model in y space.
struct Model {
    mean: Vec<f32>,
    /// M rows of D, orthonormal.
    axes: Vec<f32>,
}

impl Model {
    fn weights(&self, y: &[f32]) -> Vec<f32> {
        let d = self.mean.len();
        let c: Vec<f32> = y.iter().zip(&self.mean).map(|(a, b)| a - b).collect();
        self.axes
            .chunks_exact(d)
            .map(|a| {
                a.iter()
                    .zip(&c)
                    .map(|(x, y)| *x as f64 * *y as f64)
                    .sum::<f64>() as f32
            })
            .collect()
    }

    fn residual(&self, y: &[f32]) -> f64 {
        let d2 = dist2(y, &self.mean) as f64;
        let w: f64 = self.weights(y).iter().map(|w| (*w as f64).powi(2)).sum();
        (d2 - w).max(0.0)
    }
}

/// Mean and top `m` principal axes (rows of `y`, dimension `d`, the members `idx`): the
/// centred Gram matrix, its top eigenvectors by subspace iteration and a Rayleigh-Ritz
/// step, the axes X^T e_i orthonormalised in y space.
fn pca(y: &[f32], d: usize, idx: &[usize], m: usize, seed: u64) -> Model {
    let n = idx.len();
    let mut mean = vec![0f64; d];
    for &i in idx {
        for (s, v) in mean.iter_mut().zip(&y[i * d..(i + 1) * d]) {
            *s += *v as f64;
        }
    }
    if n > 0 {
        mean.iter_mut().for_each(|s| *s /= n as f64);
    }
    let mean: Vec<f32> = mean.into_iter().map(|s| s as f32).collect();
    let centred: Vec<Vec<f32>> = idx
        .par_iter()
        .map(|&i| {
            y[i * d..(i + 1) * d]
                .iter()
                .zip(&mean)
                .map(|(a, b)| a - b)
                .collect()
        })
        .collect();
    // Gram matrix (upper triangle, mirrored).
    let rows: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .map(|a| {
            (0..n)
                .map(|b| {
                    if b < a {
                        0.0
                    } else {
                        centred[a]
                            .iter()
                            .zip(&centred[b])
                            .map(|(x, y)| *x as f64 * *y as f64)
                            .sum()
                    }
                })
                .collect()
        })
        .collect();
    let mut gram = vec![0f64; n * n];
    for a in 0..n {
        for b in a..n {
            gram[a * n + b] = rows[a][b];
            gram[b * n + a] = rows[a][b];
        }
    }
    // Top eigenvectors of the Gram matrix (rows of `e`, n each).
    let r = (m + 4).min(n);
    let e: Vec<f64> = if n <= r {
        let (vals, vecs) = jacobi_eigen(gram, n);
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|a, b| vals[*b].total_cmp(&vals[*a]));
        order
            .iter()
            .flat_map(|&c| (0..n).map(move |row| (row, c)))
            .map(|(row, c)| vecs[row * n + c])
            .collect()
    } else {
        let mut rng = Rng::new(seed);
        let mut q: Vec<f64> = (0..r * n).map(|_| rng.f32() as f64 - 0.5).collect();
        orthonormalise(&mut q, n);
        for _ in 0..SUBSPACE_ITERATIONS {
            let z: Vec<f64> = q
                .par_chunks(n)
                .flat_map_iter(|qi| {
                    let gram = &gram;
                    (0..n).map(move |a| {
                        gram[a * n..(a + 1) * n]
                            .iter()
                            .zip(qi)
                            .map(|(g, x)| g * x)
                            .sum::<f64>()
                    })
                })
                .collect();
            q = z;
            orthonormalise(&mut q, n);
        }
        // Rayleigh-Ritz: H = Q G Q^T (r x r), rotate Q by H's eigenvectors.
        let gq: Vec<Vec<f64>> = q
            .chunks(n)
            .map(|qi| {
                (0..n)
                    .map(|a| {
                        gram[a * n..(a + 1) * n]
                            .iter()
                            .zip(qi)
                            .map(|(g, x)| g * x)
                            .sum()
                    })
                    .collect()
            })
            .collect();
        let mut h = vec![0f64; r * r];
        for i in 0..r {
            for j in 0..r {
                h[i * r + j] = q[i * n..(i + 1) * n]
                    .iter()
                    .zip(&gq[j])
                    .map(|(a, b)| a * b)
                    .sum();
            }
        }
        let (vals, vecs) = jacobi_eigen(h, r);
        let mut order: Vec<usize> = (0..r).collect();
        order.sort_by(|a, b| vals[*b].total_cmp(&vals[*a]));
        order
            .iter()
            .flat_map(|&c| {
                let (q, vecs) = (&q, &vecs);
                (0..n).map(move |row| (0..r).map(|i| vecs[i * r + c] * q[i * n + row]).sum())
            })
            .collect()
    };
    // Axes in y space: X^T e_i for the m leading ones, orthonormalised.
    let mut axes: Vec<f64> = (0..m)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut a = vec![0f64; d];
            if i * n < e.len() {
                for (row, c) in centred.iter().enumerate() {
                    let w = e[i * n + row];
                    for (s, x) in a.iter_mut().zip(c) {
                        *s += w * *x as f64;
                    }
                }
            }
            a
        })
        .collect();
    orthonormalise(&mut axes, d);
    Model {
        mean,
        axes: axes.into_iter().map(|x| x as f32).collect(),
    }
}

fn fit(y: &[f32], d: usize, assign: &[u32], clusters: usize, m: usize, seed: u64) -> Vec<Model> {
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for (i, &c) in assign.iter().enumerate() {
        members[c as usize].push(i);
    }
    members
        .iter()
        .enumerate()
        .map(|(c, idx)| pca(y, d, idx, m, seed ^ (c as u64 + 1)))
        .collect()
}

impl MatrixCpca {
    /// Compresses per-vertex transfer matrices `rows` (vertex-major, `views` x K per vertex,
    /// on `basis`) with `cfg`'s clusters, components, k-means iterations and refinements.
    /// Deterministic for a given config.
    pub fn compress(
        basis: &Basis,
        rows: &[f32],
        vertices: usize,
        views: usize,
        cfg: &CpcaConfig,
    ) -> Result<MatrixCpca> {
        basis.check()?;
        let k = basis.len();
        let d = views * k;
        if vertices == 0 || views == 0 || rows.len() != vertices * d {
            return Err(Error::InvalidArgument(format!(
                "matrix CPCA: {} coefficients for {vertices} vertices x {views} views x {k}",
                rows.len()
            )));
        }
        if cfg.clusters == 0 || cfg.components == 0 || cfg.components > d {
            return Err(Error::InvalidArgument(format!(
                "matrix CPCA: {} clusters x {} components (need >= 1 cluster and 1..={d} \
                 components)",
                cfg.clusters, cfg.components
            )));
        }
        let clusters = cfg.clusters.min(vertices);
        let m = cfg.components;
        let l = basis.gram_factor().ok_or_else(|| {
            Error::InvalidArgument(format!(
                "matrix CPCA: the Gram matrix of the {k}-function basis is not positive definite"
            ))
        })?;
        let l = &l;
        let lt: Vec<f64> = (0..k * k).map(|x| l[(x % k) * k + x / k]).collect();
        let y: Vec<f32> = rows
            .par_chunks(k)
            .flat_map_iter(|tv| {
                let lt = &lt;
                (0..k).map(move |i| {
                    lt[i * k + i..(i + 1) * k]
                        .iter()
                        .zip(&tv[i..])
                        .map(|(a, b)| a * *b as f64)
                        .sum::<f64>() as f32
                })
            })
            .collect();
        let mut assign = kmeans(&y, d, clusters, cfg.kmeans_iterations, cfg.seed);
        let mut models = fit(&y, d, &assign, clusters, m, cfg.seed);
        for _ in 0..cfg.refinements {
            let next: Vec<u32> = y
                .par_chunks(d)
                .map(|yv| {
                    let mut near: Vec<(f32, usize)> = models
                        .iter()
                        .enumerate()
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
            models = fit(&y, d, &assign, clusters, m, cfg.seed);
        }
        let per_vertex: Vec<(Vec<f32>, f64, f64)> = y
            .par_chunks(d)
            .zip(assign.par_iter())
            .map(|(yv, &c)| {
                let model = &models[c as usize];
                let norm2: f64 = yv.iter().map(|x| (*x as f64).powi(2)).sum();
                (model.weights(yv), model.residual(yv), norm2)
            })
            .collect();
        let (err2, norm2) = per_vertex
            .iter()
            .fold((0.0, 0.0), |(e, n), (_, ev, nv)| (e + ev, n + nv));
        let weights: Vec<f32> = per_vertex.into_iter().flat_map(|(w, _, _)| w).collect();
        if let Some(i) = first_beyond_half(&weights) {
            return Err(Error::InvalidArgument(format!(
                "matrix CPCA: vertex {} weight {} ({}) is beyond half precision's range \
                 (+-{HALF_MAX}), in which the weights are held (as a GPU would stream them)",
                i / m,
                i % m,
                weights[i]
            )));
        }
        // Back to coefficient space, row by row: t = L^-T y.
        let mut matrices = vec![0f32; clusters * (m + 1) * d];
        matrices.par_chunks_mut(k).enumerate().for_each(|(r, out)| {
            let (matrix, row) = (r / views, r % views);
            let model = &models[matrix / (m + 1)];
            let i = matrix % (m + 1);
            let src = if i == 0 {
                &model.mean[row * k..(row + 1) * k]
            } else {
                &model.axes[(i - 1) * d + row * k..(i - 1) * d + (row + 1) * k]
            };
            for (o, v) in out.iter_mut().zip(solve_upper_transposed(l, k, src)) {
                *o = v as f32;
            }
        });
        Ok(MatrixCpca {
            basis: basis.clone(),
            vertices,
            views,
            clusters,
            components: m,
            cluster_of: assign,
            matrices,
            weights,
            rel_l2: if norm2 > 0.0 {
                (err2 / norm2).sqrt()
            } else {
                0.0
            },
        })
    }

    /// Vertex v's reconstructed V x K matrix (coefficient space, f64 sums).
    pub fn reconstruct(&self, v: usize) -> Vec<f64> {
        let d = self.views * self.basis.len();
        let m = self.components;
        let c = self.cluster_of[v] as usize;
        let base = c * (m + 1) * d;
        (0..d)
            .map(|x| {
                let mut s = self.matrices[base + x] as f64;
                for i in 0..m {
                    s += self.weights[v * m + i] as f64
                        * self.matrices[base + (i + 1) * d + x] as f64;
                }
                s
            })
            .collect()
    }

    /// One frame on the CPU: radiance toward `camera` for lighting coefficients `coeffs`
    /// (one per basis function): per cluster, `P_ci(j) = A_ci(j, :) . c^` for its M + 1
    /// matrices; per vertex, `B = albedo sum_taps w_t (P_c0(j_t) + sum_i w_vi P_ci(j_t))`.
    pub fn shade(
        &self,
        coeffs: &[[f32; 3]],
        view: &ViewBasis,
        positions: &[Vec3],
        normals: &[Vec3],
        camera: Vec3,
        albedo: [f32; 3],
    ) -> Result<Vec<[f64; 3]>> {
        let k = self.basis.len();
        if coeffs.len() != k
            || view.views() != self.views
            || positions.len() != self.vertices
            || normals.len() != self.vertices
        {
            return Err(Error::InvalidArgument(format!(
                "matrix CPCA shade: {} coefficients, a view basis of {} rows, {} positions, {} \
                 normals for {} vertices x {} views x {k}",
                coeffs.len(),
                view.views(),
                positions.len(),
                normals.len(),
                self.vertices,
                self.views
            )));
        }
        let m = self.components;
        let projected: Vec<[f64; 3]> = self
            .matrices
            .par_chunks(k)
            .map(|row| {
                let mut s = [0f64; 3];
                for (t, c) in row.iter().zip(coeffs) {
                    for ch in 0..3 {
                        s[ch] += *t as f64 * c[ch] as f64;
                    }
                }
                s
            })
            .collect();
        let views = self.views;
        Ok((0..self.vertices)
            .into_par_iter()
            .map(|v| {
                let c = self.cluster_of[v] as usize;
                let p = &projected[c * (m + 1) * views..(c + 1) * (m + 1) * views];
                let taps = view.weights(local_view(positions[v], normals[v], camera));
                // The mean's row, then each weighted axis's, at the view's taps.
                let mut out = [0f64; 3];
                let mut add = |weight: f64, matrix: usize| {
                    for &(j, tw) in &taps {
                        for ch in 0..3 {
                            out[ch] += tw as f64 * weight * p[matrix * views + j][ch];
                        }
                    }
                };
                add(1.0, 0);
                for (i, w) in self.weights[v * m..(v + 1) * m].iter().enumerate() {
                    // Half precision, as a runtime would stream them (and CTA's are).
                    add(half_round(*w) as f64, i + 1);
                }
                [0, 1, 2].map(|ch| out[ch] * albedo[ch] as f64)
            })
            .collect())
    }

    /// Bytes per vertex as a runtime would stream them (M half-precision weights, as
    /// [`MatrixCpca::shade`] uses them, and a u32 cluster id) and with the per-cluster
    /// matrices (f32) amortised over the vertices.
    pub fn bytes_per_vertex(&self) -> (usize, f64) {
        Self::storage(
            self.components,
            self.clusters,
            self.views,
            self.basis.len(),
            self.vertices,
        )
    }

    /// [`MatrixCpca::bytes_per_vertex`] of a compression with `m` weights, `clusters`
    /// clusters of `views` x `basis` matrices over `vertices` vertices: (streamed, with the
    /// tables amortised).
    pub fn storage(
        m: usize,
        clusters: usize,
        views: usize,
        basis: usize,
        vertices: usize,
    ) -> (usize, f64) {
        let stream = 2 * m + 4;
        let tables = 4 * clusters * (m + 1) * views * basis;
        (stream, stream as f64 + tables as f64 / vertices as f64)
    }
}
