//! The method's side of the diffusion profile: how the sampler draws radii and what the
//! shader gets. The profile itself (the material model, which the brute-force truth reads
//! too) is [`super::profile`].
//!
//! The diffusion sampler draws from the mixture of the three channels
//! ([`Profile::mixture_sequence`], closed-form CDFs). Single-channel sampling
//! ([`RadiusSampler`], checked by the tests): the dipole has no analytic inverse CDF, so the
//! radial CDF of 2 pi r Rd(r) is integrated numerically on log-spaced radii and inverted into
//! a table of [`TABLE_SIZE`] radii r_j with F(r_j) = t_j^2 K(R), t_j = j / (TABLE_SIZE - 1);
//! a uniform u in [0, 1) maps to r = lerp over t = sqrt(u) (the square root follows F ~ r^2
//! near 0, so the lookup is accurate at small radii). Burley is sampled analytically instead.

use super::profile::{Dipole, Profile, ProfileKind, bisect};
use std::f64::consts::PI;

/// Entries of each channel's inverse-CDF table.
pub const TABLE_SIZE: usize = 1024;

/// Single-channel radius sampling of a profile: the dipole through its inverse-CDF table,
/// Burley in closed form.
pub struct RadiusSampler<'a> {
    profile: &'a Profile,
    /// Inverse-CDF tables, [`TABLE_SIZE`] radii per channel (dipole only; empty for Burley).
    table: Vec<[f32; 3]>,
}

impl<'a> RadiusSampler<'a> {
    pub fn new(profile: &'a Profile) -> RadiusSampler<'a> {
        let table = match profile.kind {
            ProfileKind::Dipole => dipole_table(&profile.dipole, &profile.radius),
            ProfileKind::Burley => Vec::new(),
        };
        RadiusSampler { profile, table }
    }

    /// The radius of channel `c` for a uniform `u` in [0, 1), in f32 exactly as the shader
    /// computes it (the CPU twin's sampler).
    pub fn sample_radius(&self, c: usize, u: f32) -> f32 {
        match self.profile.kind {
            ProfileKind::Dipole => {
                let t = u.max(0.0).sqrt() * (TABLE_SIZE - 1) as f32;
                let j = (t as usize).min(TABLE_SIZE - 2);
                let f = t - j as f32;
                let a = self.table[j][c];
                let b = self.table[j + 1][c];
                a + (b - a) * f
            }
            ProfileKind::Burley => {
                let g = self.profile.burley_gpu(c);
                burley_sample_f32(g[0], g[1], u)
            }
        }
    }
}

impl Profile {
    /// (d, P(R)) of Burley channel `c` as f32 (what the shader gets).
    pub fn burley_gpu(&self, c: usize) -> [f32; 2] {
        let b = &self.burley[c];
        [b.d as f32, b.p(self.radius[c]) as f32]
    }

    /// The transmission parameters of channel `c` as the shader gets them: dipole
    /// (alpha'/2, sigma_tr, z_r, z_v), Burley (A, d, 0, 0).
    pub fn tail_gpu(&self, c: usize) -> [f32; 4] {
        match self.kind {
            ProfileKind::Dipole => {
                let d = &self.dipole[c];
                [
                    (d.alpha_prime / 2.0) as f32,
                    d.sigma_tr as f32,
                    d.z_r as f32,
                    d.z_v as f32,
                ]
            }
            ProfileKind::Burley => [self.burley[c].a as f32, self.burley[c].d as f32, 0.0, 0.0],
        }
    }

    /// R_tot - F(t) = int_t^inf 2 pi s Rd(s) ds of channel `c` in f32, as the shader computes
    /// it: the diffuse transmission of a locally flat slab of thickness t lit uniformly on
    /// the other side (int over the plane of Rd(sqrt(r^2 + t^2))). Dipole:
    /// alpha'/2 sum_z z e^(-sigma_tr d)/d, d = sqrt(t^2 + z^2); Burley: A (e^(-t/d)/4 +
    /// 3 e^(-t/3d)/4).
    pub fn tail_f32(&self, c: usize, t: f32) -> f32 {
        let p = self.tail_gpu(c);
        match self.kind {
            ProfileKind::Dipole => {
                let dr = (t * t + p[2] * p[2]).sqrt();
                let dv = (t * t + p[3] * p[3]).sqrt();
                p[0] * (p[2] * (-p[1] * dr).exp() / dr + p[3] * (-p[1] * dv).exp() / dv)
            }
            ProfileKind::Burley => {
                p[0] * (0.25 * (-t / p[1]).exp() + 0.75 * (-t / (3.0 * p[1])).exp())
            }
        }
    }

    /// The sample sequence of the diffusion sampler: `n` samples shared by the three channels
    /// (one-sample MIS over channels, as pbrt-v3's BSSRDF sampling). Radii are drawn from the
    /// mixture of the channels' radial pdfs, F(r) = mean_c F_c(r) ([`Profile::cdf_normalised`]),
    /// stratified: r_s = F^-1((s + 1/2) / n) (bisection in f64). Each sample carries the
    /// weights w_c = p_c(r_s) / p(r_s) (radial pdfs; the 2 pi r cancels, so w_c = (Rd_c / K_c)
    /// / mean_j (Rd_j / K_j) over the channels whose radius R_j >= r_s); `E_p[w_c] = 1`, and the
    /// sampler's self-normalised estimate sum w_c E / sum w_c is exact on uniform E.
    /// Rows (r_s mm, w_r, w_g, w_b) as f32 (what the shader and the CPU twin read).
    pub fn mixture_sequence(&self, n: u32) -> Vec<[f32; 4]> {
        let rmax = self.max_radius();
        let mix = |r: f64| (0..3).map(|c| self.cdf_normalised(c, r)).sum::<f64>() / 3.0;
        (0..n)
            .map(|s| {
                let u = (s as f64 + 0.5) / n as f64;
                let r = bisect(|r| mix(r) - u, 0.0, rmax);
                let q = [0, 1, 2].map(|c| {
                    if r <= self.radius[c] {
                        self.rd(c, r) / self.k[c]
                    } else {
                        0.0
                    }
                });
                let mean = (q[0] + q[1] + q[2]) / 3.0;
                [
                    r as f32,
                    (q[0] / mean) as f32,
                    (q[1] / mean) as f32,
                    (q[2] / mean) as f32,
                ]
            })
            .collect()
    }
}

/// Burley's truncated inverse CDF in f32, the shader's arithmetic: r = P^-1(u P(R)).
pub fn burley_sample_f32(d: f32, p_r: f32, u: f32) -> f32 {
    let uu = 1.0 - u * p_r;
    let g = 1.0 + 4.0 * uu * (2.0 * uu + (1.0 + 4.0 * uu * uu).sqrt());
    let c = g.powf(1.0 / 3.0);
    // Rounding can give -1e-8 at u = 0.
    (d * 3.0 * ((1.0 + 1.0 / c + c) / (4.0 * uu)).ln()).max(0.0)
}

/// Radial CDF of 2 pi r Rd(r) integrated numerically (Simpson on log-spaced radii, from
/// r_min where the CDF is ~ pi r^2 Rd(0)), inverted at F = t_j^2 K(R) by bisection on the
/// tabulated CDF and interpolation. The closed-form CDF ([`Dipole::cdf`]) is used only to
/// check this integration in the tests.
fn dipole_table(dipole: &[Dipole; 3], radius: &[f64; 3]) -> Vec<[f32; 3]> {
    let mut table = vec![[0f32; 3]; TABLE_SIZE];
    for c in 0..3 {
        let (rs, fs) = numeric_cdf(|r| dipole[c].rd(r), radius[c], 8192);
        for (j, row) in table.iter_mut().enumerate() {
            let t = j as f64 / (TABLE_SIZE - 1) as f64;
            let target = t * t * fs[fs.len() - 1];
            // First grid index with F >= target.
            let i = fs.partition_point(|&f| f < target).clamp(1, fs.len() - 1);
            let (f0, f1) = (fs[i - 1], fs[i]);
            let w = if f1 > f0 {
                (target - f0) / (f1 - f0)
            } else {
                0.0
            };
            row[c] = (rs[i - 1] + w * (rs[i] - rs[i - 1])) as f32;
        }
        table[0][c] = 0.0;
        table[TABLE_SIZE - 1][c] = radius[c] as f32;
    }
    table
}

/// (radii, F(radii)) with F(r) = int_0^r 2 pi s rd(s) ds on `n` log-spaced radii up to
/// `r_max` (plus 0).
pub fn numeric_cdf(rd: impl Fn(f64) -> f64, r_max: f64, n: usize) -> (Vec<f64>, Vec<f64>) {
    let r_min = r_max * 1e-7;
    let mut rs = vec![0.0];
    let mut fs = vec![0.0];
    let g = |r: f64| 2.0 * PI * r * rd(r);
    // [0, r_min]: 2 pi r Rd(r) ~ linear, trapezoid from 0 (Rd finite at 0 for the dipole;
    // for Burley r Rd(r) is finite at 0 too).
    let mut f = 0.5 * r_min * g(r_min);
    rs.push(r_min);
    fs.push(f);
    let ratio = (r_max / r_min).powf(1.0 / (n - 1) as f64);
    let mut a = r_min;
    for i in 1..n {
        let b = if i == n - 1 { r_max } else { a * ratio };
        let m = 0.5 * (a + b);
        f += (b - a) / 6.0 * (g(a) + 4.0 * g(m) + g(b));
        rs.push(b);
        fs.push(f);
        a = b;
    }
    (rs, fs)
}

#[cfg(test)]
mod tests {
    use super::super::profile::{DEFAULT_ENERGY, Material};
    use super::*;
    use crate::geom::profile::tests::integrate;

    #[test]
    fn inverse_cdf_table_inverts_the_numeric_integral() {
        for m in [Material::SKIN1, Material::SKIN2] {
            let p = Profile::new(ProfileKind::Dipole, m, DEFAULT_ENERGY).unwrap();
            let sampler = RadiusSampler::new(&p);
            for c in 0..3 {
                // K(R) from the table's radius, integrated independently.
                let k = integrate(|r| 2.0 * PI * r * p.rd(c, r), 0.0, p.radius[c], 4000);
                assert!((k - p.k[c]).abs() / p.k[c] < 1e-6);
                for i in 1..40 {
                    let u = i as f32 / 40.0;
                    let r = sampler.sample_radius(c, u) as f64;
                    let f = integrate(|s| 2.0 * PI * s * p.rd(c, s), 0.0, r, 400) / p.k[c];
                    assert!(
                        (f - u as f64).abs() < 2e-4,
                        "{} ch {c}: F(r({u})) = {f}",
                        m.name
                    );
                }
            }
        }
    }

    #[test]
    fn burley_inverse_and_normalisation() {
        let p = Profile::new(ProfileKind::Burley, Material::SKIN1, DEFAULT_ENERGY).unwrap();
        let sampler = RadiusSampler::new(&p);
        for c in 0..3 {
            let b = p.burley[c];
            let total = integrate(|r| 2.0 * PI * r * b.rd(r), 0.0, 200.0 * b.d, 20000);
            assert!((total - b.a).abs() / b.a < 1e-6, "{total} vs {}", b.a);
            for i in 1..50 {
                let q = i as f64 / 50.0;
                let r = b.p_inverse(q);
                assert!((b.p(r) - q).abs() < 1e-12);
                let rf = sampler.sample_radius(c, q as f32) as f64;
                let f = integrate(|s| 2.0 * PI * s * b.rd(s), 0.0, rf, 400) / p.k[c];
                assert!((f - q).abs() < 1e-4, "ch {c} u {q}: {f}");
            }
            assert!((p.k[c] / p.r_tot[c] - DEFAULT_ENERGY).abs() < 1e-9);
        }
    }

    #[test]
    fn mixture_sequence_reweights_to_each_channel() {
        // The weighted radii of the shared sequence follow each channel's own truncated CDF:
        // (1/n) sum_s w_c(r_s) [r_s <= x] ~ F_c(x), and the weights average to 1.
        for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
            let p = Profile::new(kind, Material::SKIN1, DEFAULT_ENERGY).unwrap();
            let n = 4096;
            let seq = p.mixture_sequence(n);
            assert!(
                seq.windows(2).all(|w| w[0][0] < w[1][0]),
                "radii not increasing"
            );
            assert!(seq[n as usize - 1][0] as f64 <= p.max_radius());
            for c in 0..3 {
                let mean = seq.iter().map(|q| q[c + 1] as f64).sum::<f64>() / n as f64;
                assert!(
                    (mean - 1.0).abs() < 2e-3,
                    "{kind:?} ch {c}: mean weight {mean}"
                );
                for frac in [0.1, 0.3, 0.5, 0.8] {
                    let x = frac * p.radius[c];
                    let got = seq
                        .iter()
                        .filter(|q| (q[0] as f64) <= x)
                        .map(|q| q[c + 1] as f64)
                        .sum::<f64>()
                        / n as f64;
                    let want = p.cdf_normalised(c, x);
                    assert!(
                        (got - want).abs() < 3e-3,
                        "{kind:?} ch {c} x {x}: {got} vs {want}"
                    );
                }
                // Beyond its radius a channel has no weight.
                assert!(
                    seq.iter()
                        .all(|q| q[0] as f64 <= p.radius[c] || q[c + 1] == 0.0)
                );
            }
        }
    }

    /// At the sample counts the kernel uses (tens, not the 4096 above, where half a stratum
    /// hides under the tolerance), each radius is the mixture's quantile at the middle of its
    /// stratum: mean_c F_c(r_s) = (s + 1/2) / n, to the f32 rounding of r_s (~1e-7 relative;
    /// bound 1e-5), and every weight is finite. Catches cargo-mutants' survivor in
    /// `mixture_sequence` (issue 23): `s + 0.5` -> `s - 0.5` (every sample one stratum early,
    /// the first at r = 0, where Burley's Rd is infinite, and the outermost stratum never
    /// sampled).
    #[test]
    fn mixture_radii_are_the_stratum_midpoints_at_small_counts() {
        for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
            let p = Profile::new(kind, Material::SKIN1, DEFAULT_ENERGY).unwrap();
            for n in [8u32, 32] {
                for (s, q) in p.mixture_sequence(n).iter().enumerate() {
                    let r = q[0] as f64;
                    let mix = (0..3).map(|c| p.cdf_normalised(c, r)).sum::<f64>() / 3.0;
                    let want = (s as f64 + 0.5) / n as f64;
                    assert!(
                        (mix - want).abs() < 1e-5,
                        "{kind:?} n {n} s {s}: F(r) {mix} vs {want}"
                    );
                    assert!(
                        q.iter().all(|v| v.is_finite()),
                        "{kind:?} n {n} s {s}: {q:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn transmission_tail_is_the_profile_beyond_t() {
        for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
            let p = Profile::new(kind, Material::SKIN1, DEFAULT_ENERGY).unwrap();
            for c in 0..3 {
                assert!((p.tail_f32(c, 0.0) as f64 - p.r_tot[c]).abs() < 1e-6 * p.r_tot[c]);
                for t in [0.5, 2.0, 5.0] {
                    let num = integrate(|s| 2.0 * PI * s * p.rd(c, s), t, 400.0, 20000);
                    let got = p.tail_f32(c, t as f32) as f64;
                    assert!(
                        (got - num).abs() < 1e-5 * p.r_tot[c],
                        "{kind:?} {c} {t}: {got} vs {num}"
                    );
                }
            }
            // Thin skin transmits red far more than blue.
            assert!(p.tail_f32(0, 4.0) > 5.0 * p.tail_f32(2, 4.0));
        }
    }
}
