//! The BRDF's separable factorisation, the glossy transfer's view basis:
//!
//! ```text
//! rho(w, o) max(0, w_z) ~ sum_{j < m} g_j(o) h_j(w)      (w, o in the tangent frame)
//! ```
//!
//! the m leading terms of the singular value decomposition of the kernel over the view
//! hemisphere (o) and the light hemisphere (w), both with the solid-angle measure (Kautz and
//! McCool 1999 factor BRDFs this way; Liu et al. 2004 use it for glossy PRT). The view enters
//! the transfer only through the BRDF, so with this split vertex v's transfer toward any view
//! is `B_v(o) = sum_j g_j(o) (T_v[j] . c^)`, T_v\[j\] the projection of `V_v(w) h_j(w)` on the
//! SG basis: m rows per vertex, whatever the view's direction, instead of one row per node
//! of a view grid. The error this adds is the kernel's truncation ([`BrdfFactors::truncation`],
//! set by the BRDF, not by the mesh) plus the tables' interpolation; the view grid's
//! cross-fading of highlights between nodes is gone, and the view factor is shared by every
//! vertex.
//!
//! Both factors are tabulated at the nodes of one N x N parabolic grid ([`ViewGrid`], the
//! same map as the view grid's) and looked up bilinearly (4 taps, on the GPU too). `g_j` is
//! orthonormal over the view hemisphere and `h_j` carries the singular value sigma_j, so a
//! vertex's row j has the weight its term has in the radiance over all views: |B_v|^2 over
//! the view hemisphere is sum_j (T_v\[j\] . c)^2, and a compression that treats the rows
//! alike ([`super::cta`]) minimises the error of the radiance, as it does for a view grid's
//! rows (one view each). The SVD is a block
//! subspace iteration on the solid-angle-weighted kernel matrix at the grid's nodes inside the
//! disk (f64), then a Rayleigh-Ritz step; `g_j` at any view is then the kernel's projection
//! on `h_j` / sigma_j^2 (so the horizon nodes outside the disk get their exact value too).

use super::glossy::ViewGrid;
use crate::error::{Error, Result};
use crate::geom::brdf::Brdf;
use crate::geom::linalg::subspace_eigen;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Most terms of a factorisation.
pub const MAX_TERMS: usize = 64;
/// The tables' default grid side: 48 nodes, 0.085 rad apart at the pole (half that at the
/// horizon), about a third of a Phong-16 lobe's width (1 / sqrt(16) rad).
pub const DEFAULT_GRID: u32 = 48;

/// m separable terms of a BRDF times the cosine, tabulated (see the module).
#[derive(Clone, Debug, PartialEq)]
pub struct BrdfFactors {
    pub brdf: Brdf,
    /// m.
    pub terms: usize,
    /// The tables' grid.
    pub grid: ViewGrid,
    /// g_j at each node (row-major node j N + i, m values per node; orthonormal over the
    /// view hemisphere).
    pub view: Vec<f32>,
    /// h_j at each node (m values per node, sigma_j included; 0 at the horizon).
    pub light: Vec<f32>,
    /// The leading singular values found (at least m of them, decreasing).
    pub sigma: Vec<f64>,
    /// Relative L2 of the truncation over both hemispheres: sqrt(1 - sum_{j<m} sigma_j^2 /
    /// |k|^2).
    pub truncation: f64,
}

/// The grid's nodes inside the unit disk (the interior of the hemisphere) with their solid
/// angles: (node index, local direction, weight).
fn disk_nodes(grid: ViewGrid) -> Vec<(usize, DVec3, f64)> {
    let n = grid.n;
    let h = 2.0 / (n - 1) as f64;
    let mut out = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let p = glam::DVec2::new(-1.0 + i as f64 * h, -1.0 + j as f64 * h);
            let r2 = p.length_squared();
            if r2 < 1.0 {
                // dw = 4 / (1 + r^2)^2 dp.
                let w = 4.0 / (1.0 + r2).powi(2) * h * h;
                out.push(((j * n + i) as usize, grid.node_direction(i, j), w));
            }
        }
    }
    out
}

impl BrdfFactors {
    /// Factors `brdf` into `terms` terms tabulated on `grid`. Deterministic.
    pub fn new(brdf: &Brdf, terms: usize, grid: ViewGrid) -> Result<BrdfFactors> {
        brdf.check()?;
        grid.check()?;
        if grid.n < 8 {
            return Err(Error::InvalidArgument(format!(
                "BRDF factor tables of {0} x {0} nodes: need at least 8 x 8",
                grid.n
            )));
        }
        let nodes = disk_nodes(grid);
        let count = nodes.len();
        if !(1..=MAX_TERMS).contains(&terms) || terms > count / 4 {
            return Err(Error::InvalidArgument(format!(
                "{terms} BRDF terms: need 1..={} for a {1} x {1} table",
                MAX_TERMS.min(count / 4),
                grid.n
            )));
        }
        let z = DVec3::Z;
        // A[i][l] = sqrt(w_i) k(o_i, w_l) sqrt(w_l): rows views, columns lights.
        let a: Vec<f64> = nodes
            .par_iter()
            .flat_map_iter(|(_, o, wo)| {
                nodes
                    .iter()
                    .map(move |(_, l, wl)| (wo * wl).sqrt() * brdf.cosine_weighted(z, *l, *o))
            })
            .collect();
        let total: f64 = a.iter().map(|x| x * x).sum();
        // Block subspace iteration on A A^T: p rows of length `count`.
        let p = (terms + terms / 2 + 8).min(count);
        let a = &a;
        let apply = |x: &[f64]| -> Vec<f64> {
            // y = A (A^T x) per row of x.
            x.par_chunks(count)
                .flat_map_iter(|row| {
                    let mut t = vec![0f64; count];
                    for (i, xi) in row.iter().enumerate() {
                        if *xi != 0.0 {
                            for (tl, al) in t.iter_mut().zip(&a[i * count..(i + 1) * count]) {
                                *tl += xi * al;
                            }
                        }
                    }
                    (0..count).map(move |i| {
                        a[i * count..(i + 1) * count]
                            .iter()
                            .zip(&t)
                            .map(|(al, tl)| al * tl)
                            .sum::<f64>()
                    })
                })
                .collect()
        };
        // The captured energy sum |A^T x_c|^2 converges from below to the top p sigma^2.
        let (vals, u) = subspace_eigen(count, p, &[], 0x5eed_b4df, 200, 1e-13 * total, apply);
        let sigma: Vec<f64> = vals.iter().map(|v| v.max(0.0).sqrt()).collect();
        if sigma[0] <= 0.0 {
            return Err(Error::InvalidArgument(
                "BRDF factorisation: the kernel is zero".into(),
            ));
        }
        // A term of (numerically) zero weight has no direction to tabulate (g_j divides by
        // sigma_j): a BRDF of lower rank than asked for, e.g. Phong exponent 0 (one term), is
        // refused rather than tabulated from rounding noise.
        let significant = sigma.iter().filter(|s| **s > 1e-6 * sigma[0]).count();
        if significant < terms {
            return Err(Error::InvalidArgument(format!(
                "{brdf:?} has {significant} significant separable term(s) (singular values \
                 above 1e-6 of the largest); ask for at most that many (--terms {significant})"
            )));
        }
        // Right singular vectors v_j = A^T u_j / sigma_j (u_j's sign: its largest entry
        // positive).
        let light_vecs: Vec<Vec<f64>> = u
            .chunks_exact(count)
            .take(terms)
            .zip(&sigma)
            .map(|(u, s)| {
                let mut v = vec![0f64; count];
                for (i, ui) in u.iter().enumerate() {
                    for (vl, al) in v.iter_mut().zip(&a[i * count..(i + 1) * count]) {
                        *vl += ui * al;
                    }
                }
                v.iter_mut().for_each(|vl| *vl /= s.max(1e-300));
                v
            })
            .collect();
        let captured: f64 = sigma.iter().take(terms).map(|s| s * s).sum();
        let truncation = (1.0 - captured / total).max(0.0).sqrt();
        // h_j at the nodes: sigma_j v_j / sqrt(w); 0 outside the disk (the horizon, where the
        // cosine vanishes).
        let side = (grid.n * grid.n) as usize;
        let mut light = vec![0f32; side * terms];
        for (q, (node, _, w)) in nodes.iter().enumerate() {
            for j in 0..terms {
                light[node * terms + j] = (sigma[j] * light_vecs[j][q] / w.sqrt()) as f32;
            }
        }
        // g_j(o) = int k(o, w) v_j(w) dw / sigma_j by the same quadrature, at every node
        // (horizon ones included).
        let view: Vec<f32> = (0..side)
            .into_par_iter()
            .flat_map_iter(|node| {
                let (i, j) = (node as u32 % grid.n, node as u32 / grid.n);
                let o = grid.node_direction(i, j);
                let mut g = vec![0f64; terms];
                for (q, (_, l, w)) in nodes.iter().enumerate() {
                    let k = brdf.cosine_weighted(z, *l, o) * w.sqrt();
                    if k != 0.0 {
                        for (gj, v) in g.iter_mut().zip(&light_vecs) {
                            *gj += k * v[q];
                        }
                    }
                }
                g.into_iter()
                    .zip(&sigma)
                    .map(|(x, s)| (x / s.max(1e-300)) as f32)
            })
            .collect();
        Ok(BrdfFactors {
            brdf: *brdf,
            terms,
            grid,
            view,
            light,
            sigma,
            truncation,
        })
    }

    fn lookup(&self, table: &[f32], d: Vec3, out: &mut [f32]) {
        out.iter_mut().for_each(|x| *x = 0.0);
        for (node, w) in self.grid.taps(d) {
            if w != 0.0 {
                for (o, t) in out
                    .iter_mut()
                    .zip(&table[node * self.terms..(node + 1) * self.terms])
                {
                    *o += w * t;
                }
            }
        }
    }

    /// g_j(o) for a local view direction (any length > 0; below the horizon clamped onto
    /// it, as the view grid does): `out` has m entries.
    pub fn view_weights(&self, o: Vec3, out: &mut [f32]) {
        self.lookup(&self.view, o, out)
    }

    /// h_j(w) for a local light direction (0 below the horizon): `out` has m entries.
    pub fn light_values(&self, w: Vec3, out: &mut [f32]) {
        if w.z <= 0.0 {
            out.iter_mut().for_each(|x| *x = 0.0);
        } else {
            self.lookup(&self.light, w, out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    const PHONG8: Brdf = Brdf::Phong {
        exponent: 8.0,
        diffuse: 0.3,
        specular: 0.7,
    };

    /// Relative L2 of sum_j g_j(o) h_j(w) against rho(w, o) cos over random (o, w) pairs in
    /// the upper hemisphere (not nodes: the tables' interpolation counts too).
    fn reconstruction_error(f: &BrdfFactors, samples: usize) -> f64 {
        let mut rng = Rng::new(7);
        let mut hemi = || {
            let d = crate::geom::uniform_sphere(rng.f32(), rng.f32());
            Vec3::new(d.x, d.y, d.z.abs().max(1e-3)).normalize()
        };
        let (mut num, mut den) = (0f64, 0f64);
        let (mut g, mut h) = (vec![0f32; f.terms], vec![0f32; f.terms]);
        for _ in 0..samples {
            let (o, w) = (hemi(), hemi());
            let k = f.brdf.cosine_weighted(DVec3::Z, w.as_dvec3(), o.as_dvec3());
            f.view_weights(o, &mut g);
            f.light_values(w, &mut h);
            let approx: f64 = g.iter().zip(&h).map(|(a, b)| *a as f64 * *b as f64).sum();
            num += (approx - k).powi(2);
            den += k * k;
        }
        (num / den).sqrt()
    }

    /// More terms, less error: the reported truncation falls with m, and the tabulated
    /// factors reproduce the kernel at random off-node pairs to within it plus the tables'
    /// bilinear error (measured on 48^2 tables, Phong 8: 0.165 / 0.101 / 0.040 against
    /// truncations 0.161 / 0.098 / 0.037 at m = 12 / 16 / 24).
    #[test]
    fn phong_truncation_falls_with_terms_and_the_tables_reproduce_the_kernel() {
        let mut last = 1.0;
        for m in [12, 16, 24] {
            let f = BrdfFactors::new(&PHONG8, m, ViewGrid { n: DEFAULT_GRID }).unwrap();
            let e = reconstruction_error(&f, 20_000);
            eprintln!(
                "m {m}: truncation {:.4}, off-node error {e:.4}",
                f.truncation
            );
            assert!(f.truncation < last, "m {m}: {} after {last}", f.truncation);
            assert!(e <= f.truncation + 0.015, "m {m}: {e} vs {}", f.truncation);
            assert!(f.sigma.windows(2).all(|w| w[0] >= w[1]));
            last = f.truncation;
        }
        assert!(last < 0.05, "24 terms: truncation {last}");
    }

    /// A Lambertian kernel cos / pi is one product: one term captures it (the table's
    /// interpolation of the cosine is all that is left), and g_0 is orthonormal and h_0 of
    /// norm sigma_0 under the nodes' quadrature.
    #[test]
    fn diffuse_is_one_term() {
        let f = BrdfFactors::new(&Brdf::Diffuse, 1, ViewGrid { n: 32 }).unwrap();
        assert!(f.truncation < 1e-6, "{}", f.truncation);
        let e = reconstruction_error(&f, 5_000);
        assert!(e < 0.01, "{e}");
        let norm = |t: &[f32]| -> f64 {
            disk_nodes(f.grid)
                .iter()
                .map(|(node, _, w)| w * (t[*node] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        assert!((norm(&f.view) - 1.0).abs() < 1e-4, "{}", norm(&f.view));
        let h = norm(&f.light);
        assert!((h - f.sigma[0]).abs() < 1e-4 * f.sigma[0], "{h}");
        // Below the horizon h is 0.
        let mut h = [1f32];
        f.light_values(Vec3::new(0.3, 0.1, -0.2), &mut h);
        assert_eq!(h[0], 0.0);
    }

    /// Phong exponent 0 is constant x cosine, one term: asking for more is refused with the
    /// count, one is exact.
    #[test]
    fn a_brdf_of_lower_rank_than_asked_is_refused() {
        let flat = Brdf::Phong {
            exponent: 0.0,
            diffuse: 0.3,
            specular: 0.7,
        };
        let e = BrdfFactors::new(&flat, 4, ViewGrid { n: 16 })
            .unwrap_err()
            .to_string();
        assert!(e.contains("1 significant"), "{e}");
        let one = BrdfFactors::new(&flat, 1, ViewGrid { n: 16 }).unwrap();
        assert!(one.truncation < 1e-6, "{}", one.truncation);
    }

    #[test]
    fn bad_factorisations_are_refused() {
        for (brdf, m, n) in [
            (PHONG8, 0, 48),
            (PHONG8, MAX_TERMS + 1, 48),
            (PHONG8, 24, 4),
            (PHONG8, 40, 8),
            (
                Brdf::Phong {
                    exponent: f32::NAN,
                    diffuse: 0.3,
                    specular: 0.7,
                },
                8,
                32,
            ),
        ] {
            assert!(
                BrdfFactors::new(&brdf, m, ViewGrid { n }).is_err(),
                "{brdf:?} {m} {n}"
            );
        }
    }
}
