//! The lobes in the GPU's layout and the cap-occlusion table, built and checked on the CPU (no
//! Vulkan here).

use crate::error::{Error, Result};
use crate::geom::sg::{self, Lobe};
use rayon::prelude::*;

/// The most lobes the shadow pass holds per vertex (its per-lobe accumulators live in
/// registers / private memory): a device-independent limit of the shader, checked here.
pub const MAX_LOBES: usize = 64;

/// Checks the lobes (1..=[`MAX_LOBES`], each valid: unit axis, finite positive sharpness,
/// finite amplitude) and packs them as the `lobes` buffer holds them: per lobe two vec4,
/// (axis.xyz, sharpness), (amplitude.rgb, 0).
pub fn pack_lobes(lobes: &[Lobe]) -> Result<Vec<[f32; 4]>> {
    if lobes.is_empty() || lobes.len() > MAX_LOBES {
        return Err(Error::InvalidArgument(format!(
            "{} environment lobes; the shadow pass takes 1..={MAX_LOBES}",
            lobes.len()
        )));
    }
    if let Some(i) = lobes.iter().position(|l| !l.is_valid()) {
        return Err(Error::InvalidArgument(format!(
            "environment lobe {i} is not valid (unit axis, finite sharpness > 0, finite amplitude)"
        )));
    }
    Ok(lobes
        .iter()
        .flat_map(|l| {
            let a = l.axis().normalize();
            [
                [a.x, a.y, a.z, l.sharpness],
                [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0],
            ]
        })
        .collect())
}

/// log2(sharpness) of the table's first sample.
pub const LOG_MIN: f32 = -4.0;
/// log2(sharpness) of the table's last sample (the fit's sharpness cap is 10^4 ~ 2^13.3; the
/// product with the cosine adds at most 2.133).
pub const LOG_MAX: f32 = 14.0;
/// Samples along log2(sharpness) (step 1/8). A lookup takes the nearest, so that it reads one
/// quad of (a, s) corners instead of two: `env shadow` in `bench frame` 9.1-10.5 -> 7.6-9.5
/// ms (alternated runs, 2-core VM), for a worst lookup error of 0.0147 instead of 0.0085
/// (trilinear over steps of 0.5; [`CapTable`]'s test); 0.0122 since the values are divided by
/// the cap's size ([`CapTable`]).
pub const N_LAMBDA: u32 = 145;
/// Samples of the cap's half-angle over [0, pi/2], uniform in sqrt(a / (pi/2)) (small caps of
/// sharp lobes need the finer steps).
pub const N_ALPHA: u32 = 49;
/// Samples of s = (g - a) sqrt(max(lambda, 4)) over [-S_MAX, S_MAX].
pub const N_S: u32 = 65;
/// Beyond s = S_MAX the lobe lies > 8 widths outside the cap: nothing is occluded (e^-32).
pub const S_MAX: f32 = 8.0;

/// The fraction of a unit SG (sharpness lambda) inside a cap of half-angle `a` whose axis is at
/// angle `g` from the lobe's, tabulated over (log2 lambda, a, s = (g - a) sqrt(max(lambda,
/// 4))): the last coordinate measures the lobe's distance from the cap's edge in lobe widths,
/// so sharp lobes are resolved where they cross the edge. Values from [`cap_fraction`] (f64),
/// divided by the cap's size against the lobe's, m = x / (1 + x) with x = (1 - cos a)
/// max(lambda, 1) (for lambda >= 1 the cap's solid angle over ~ the lobe's, 2 pi / lambda): a
/// small cap's fraction grows as x, the lobe's value at its centre times its solid angle, and
/// x grows as the fourth power of the a axis' coordinate (uniform in sqrt a), which bilinear
/// steps misfit; m divides it out. For a cap larger than the lobe m nears 1 and leaves the
/// fraction, a function of the lobe's distance from the edge, as it is. So one lookup serves
/// every cap size. Lookups bilinear in (a, s) at the nearest lambda sample, times m
/// ([`CapTable::lookup`], as the shader does it).
#[derive(Clone, Debug)]
pub struct CapTable {
    /// [(l * N_ALPHA + a) * N_S + s].
    pub values: Vec<f32>,
}

impl Default for CapTable {
    fn default() -> Self {
        Self::new()
    }
}

impl CapTable {
    /// Computes the table (rayon; ~460 k entries, 24-node quadrature each).
    pub fn new() -> CapTable {
        let (nl, na, ns) = (N_LAMBDA as usize, N_ALPHA as usize, N_S as usize);
        let values = (0..nl * na * ns)
            .into_par_iter()
            .map(|k| {
                let (lambda, alpha, g) = Self::sample(k / (na * ns), (k / ns) % na, k % ns);
                let x = (1.0 - alpha.cos()) * lambda.max(1.0);
                if x > 0.0 {
                    (cap_fraction(lambda, g, alpha) * (1.0 + x) / x) as f32
                } else {
                    // A vanishing cap's limit: its fraction e^(-2 lambda sin^2(g / 2)) 2 pi
                    // (1 - cos a) / (2 pi (1 - e^(-2 lambda)) / lambda) (the lobe's value at
                    // the cap times its solid angle over the lobe's integral) over x.
                    ((-2.0 * lambda * (g * 0.5).sin().powi(2)).exp() / -(-2.0 * lambda).exp_m1()
                        * lambda
                        / lambda.max(1.0)) as f32
                }
            })
            .collect();
        CapTable { values }
    }

    /// The sample (lambda, alpha, gamma) of table entry (l, a, s): lambda over log2 from
    /// [`LOG_MIN`] to [`LOG_MAX`], alpha uniform in sqrt(alpha / (pi/2)), s = (gamma - alpha)
    /// sqrt(max(lambda, 4)) from -[`S_MAX`] to [`S_MAX`] (gamma clamped into [0, pi]).
    fn sample(l: usize, a: usize, s: usize) -> (f64, f64, f64) {
        let (nl, na, ns) = (N_LAMBDA as usize, N_ALPHA as usize, N_S as usize);
        let lambda =
            2f64.powf(LOG_MIN as f64 + (LOG_MAX - LOG_MIN) as f64 * l as f64 / (nl - 1) as f64);
        let alpha = std::f64::consts::FRAC_PI_2 * (a as f64 / (na - 1) as f64).powi(2);
        let s = -(S_MAX as f64) + 2.0 * S_MAX as f64 * s as f64 / (ns - 1) as f64;
        let g = (alpha + s / lambda.max(4.0).sqrt()).clamp(0.0, std::f64::consts::PI);
        (lambda, alpha, g)
    }

    /// The table as the shadow pass reads it: per cell (l, a, s) with a < N_ALPHA - 1 and
    /// s < N_S - 1, the vec4 of its corners `(T(l, a, s), T(l, a, s + 1), T(l, a + 1, s),
    /// T(l, a + 1, s + 1))` at `[(l * (N_ALPHA - 1) + a) * (N_S - 1) + s]`: a lookup is one
    /// vec4 load instead of four scalar ones (on lavapipe every load at a per-lane index is a
    /// gather, and the gathers bound the pass), with the same values and the same arithmetic.
    pub fn quads(&self) -> Vec<[f32; 4]> {
        let at = |i: u32, j: u32, k: u32| self.values[((i * N_ALPHA + j) * N_S + k) as usize];
        let mut out = Vec::with_capacity((N_LAMBDA * (N_ALPHA - 1) * (N_S - 1)) as usize);
        for i in 0..N_LAMBDA {
            for j in 0..N_ALPHA - 1 {
                for k in 0..N_S - 1 {
                    out.push([
                        at(i, j, k),
                        at(i, j, k + 1),
                        at(i, j + 1, k),
                        at(i, j + 1, k + 1),
                    ]);
                }
            }
        }
        out
    }

    /// The lookup (the nearest lambda sample, bilinear in (alpha, s), times m of the cap's
    /// `one_minus_cos_a`), operation for operation as `glsl/env/shadow.glsl`'s `cap_occlusion`
    /// (lambda > 0, gamma in [0, pi], alpha in [0, pi/2]).
    pub fn lookup(&self, lambda: f32, gamma: f32, alpha: f32, one_minus_cos_a: f32) -> f32 {
        let s = (gamma - alpha) * lambda.max(4.0).sqrt();
        if s >= S_MAX {
            return 0.0;
        }
        let x = ((lambda.log2() - LOG_MIN) / (LOG_MAX - LOG_MIN)).clamp(0.0, 1.0)
            * (N_LAMBDA - 1) as f32;
        let y = (alpha * std::f32::consts::FRAC_2_PI).clamp(0.0, 1.0).sqrt() * (N_ALPHA - 1) as f32;
        let z = ((s + S_MAX) / (2.0 * S_MAX)).clamp(0.0, 1.0) * (N_S - 1) as f32;
        let (i, j, k) = (
            ((x + 0.5) as u32).min(N_LAMBDA - 1),
            (y as u32).min(N_ALPHA - 2),
            (z as u32).min(N_S - 2),
        );
        let (fy, fz) = (y - j as f32, z - k as f32);
        let at = |i: u32, j: u32, k: u32| self.values[((i * N_ALPHA + j) * N_S + k) as usize];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let row = |i: u32, j: u32| lerp(at(i, j, k), at(i, j, k + 1), fz);
        let plane = |i: u32| lerp(row(i, j), row(i, j + 1), fy);
        let m = one_minus_cos_a * lambda.max(1.0);
        plane(i) * (m / (1.0 + m))
    }
}

/// The fraction of a unit SG (sharpness `lambda`) inside a cap of half-angle `alpha`
/// (`1 - cos(alpha)` = `one_minus_cos_a`) at cos(gamma) = `cos_g` from its axis, as the shadow
/// pass evaluates it: the table at gamma = [`acos_fast`]`(cos_g)`, for caps of every size. As
/// `glsl/env/shadow.glsl`'s `cap_occlusion`.
///
/// Until 2026-12-07 caps under 0.3 lobe widths took the lobe's value at their centre times
/// their solid angle, blended into the table up to 0.4; the table divided by m is nearer the
/// exact form for them, and cheaper (README, "One lookup for every cap").
pub fn cap_occlusion(
    table: &CapTable,
    lambda: f32,
    cos_g: f32,
    alpha: f32,
    one_minus_cos_a: f32,
) -> f32 {
    table.lookup(
        lambda,
        acos_fast(cos_g.clamp(-1.0, 1.0)),
        alpha,
        one_minus_cos_a,
    )
}

/// acos(x) within 6.7e-5 rad (Abramowitz and Stegun 4.4.45: sqrt(1 - |x|) times a cubic,
/// mirrored for x < 0), for the cap table's s axis, where a cell is a quarter lobe width (the
/// error moves s by at most 0.009 at the sharpest lobes). As `glsl/env/shadow.glsl`'s
/// `acos_fast`: lavapipe's acos cost 1.3 of `env shadow`'s 9.2 ms.
pub fn acos_fast(x: f32) -> f32 {
    let a = x.abs();
    let r = (1.0 - a).max(0.0).sqrt()
        * (1.570_728_8 + a * (-0.212_114_4 + a * (0.074_261 + a * -0.018_729_3)));
    if x < 0.0 { std::f32::consts::PI - r } else { r }
}

/// The share of a cap of half-angle `alpha` above the horizon, its centre at `cos_t` = n . w
/// (a disc cut by a line at signed distance x = elevation / alpha from its centre:
/// (acos(-x) + x sqrt(1 - x^2)) / pi). Light below the horizon adds nothing to E_j, so a cap
/// occludes a lobe only with its share above it: the cap's effect fades to 0 as it sinks.
pub fn above_horizon(cos_t: f32, alpha: f32) -> f32 {
    let x = (cos_t.clamp(-1.0, 1.0).asin() / alpha.max(1e-6)).clamp(-1.0, 1.0);
    ((-x).acos() + x * (1.0 - x * x).max(0.0).sqrt()) / std::f32::consts::PI
}

/// Gauss-Legendre nodes and weights on [-1, 1] (Newton on P_n).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 { 1.0 } else { p1 };
            let pm = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (z * pn - pm) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                break;
            }
        }
        x[i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
    }
    (x, w)
}

/// e^-x I0(x), x >= 0 (Abramowitz & Stegun 9.8.1 / 9.8.2; relative error < 2e-7).
pub fn i0e(x: f64) -> f64 {
    let x = x.abs();
    if x < 3.75 {
        let t = (x / 3.75).powi(2);
        let i0 = 1.0
            + t * (3.5156229
                + t * (3.0899424
                    + t * (1.2067492 + t * (0.2659732 + t * (0.0360768 + t * 0.0045813)))));
        i0 * (-x).exp()
    } else {
        let t = 3.75 / x;
        let p = 0.39894228
            + t * (0.01328592
                + t * (0.00225319
                    + t * (-0.00157565
                        + t * (0.00916281
                            + t * (-0.02057706
                                + t * (0.02635537 + t * (-0.01647633 + t * 0.00392377)))))));
        p / x.sqrt()
    }
}

/// Exact fraction (f64) of a unit SG of sharpness `lambda` inside a cap of half-angle `a`
/// whose axis is `g` from the lobe's: 2 pi int_0^a e^(lambda (cos(g - t) - 1))
/// i0e(lambda sin g sin t) sin t dt / (2 pi (1 - e^(-2 lambda)) / lambda), t the polar angle
/// about the cap's axis. 24-node Gauss-Legendre on [g - 7 w, g + 7 w] within [0, a], w =
/// 1/sqrt(lambda) the lobe's width (the note measured <= 6e-6 of the lobe with 16 nodes and 6
/// widths).
pub fn cap_fraction(lambda: f64, g: f64, a: f64) -> f64 {
    thread_local! {
        static GL: (Vec<f64>, Vec<f64>) = gauss_legendre(24);
    }
    if a <= 0.0 || lambda <= 0.0 {
        return 0.0;
    }
    let w = 7.0 / lambda.sqrt();
    let (lo, hi) = ((g - w).max(0.0), (g + w).min(a));
    if lo >= hi {
        return 0.0;
    }
    let sin_g = g.sin();
    let f = |t: f64| {
        let st = t.sin();
        // cos(g - t) - 1 as -2 sin^2((g - t) / 2): no cancellation for sharp lobes.
        let e = -2.0 * ((g - t) * 0.5).sin().powi(2);
        (lambda * e).exp() * i0e(lambda * sin_g * st) * st
    };
    let sum = GL.with(|(x, wt)| {
        x.iter()
            .zip(wt)
            .map(|(&x, &wt)| wt * f(lo + (hi - lo) * 0.5 * (x + 1.0)))
            .sum::<f64>()
    });
    let inside = 2.0 * std::f64::consts::PI * (hi - lo) * 0.5 * sum;
    (inside / sg::integral(lambda)).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    /// The table, built once for the tests that read it (~460 k quadratures).
    fn table() -> &'static CapTable {
        static TABLE: std::sync::OnceLock<CapTable> = std::sync::OnceLock::new();
        TABLE.get_or_init(CapTable::new)
    }

    /// Brute force: midpoint rule in (t, phi) over the cap, f64.
    fn brute(lambda: f64, g: f64, a: f64) -> f64 {
        let (nt, np) = (2000, 256);
        let mut sum = 0.0;
        for i in 0..nt {
            let t = a * (i as f64 + 0.5) / nt as f64;
            for k in 0..np {
                let ph = std::f64::consts::TAU * (k as f64 + 0.5) / np as f64;
                let c = g.cos() * t.cos() + g.sin() * t.sin() * ph.cos();
                sum += (lambda * (c - 1.0)).exp() * t.sin();
            }
        }
        sum * a / nt as f64 * std::f64::consts::TAU / np as f64 / sg::integral(lambda)
    }

    #[test]
    fn the_1d_form_matches_brute_force() {
        for &(l, g, a) in &[
            (0.5, 1.0, 0.7),
            (2.0, 0.3, 0.4),
            (8.0, 0.9, 0.5),
            (32.0, 0.2, 0.3),
            (128.0, 0.35, 0.3),
        ] {
            let (x, y) = (cap_fraction(l, g, a), brute(l, g, a));
            // The brute force's midpoint rule errs ~1e-5 here (2000 x 256 cells).
            assert!((x - y).abs() < 1e-4, "lambda {l} g {g} a {a}: {x} vs {y}");
        }
        // A lobe at the cap's centre, in closed form: (1 - e^(-lambda (1 - cos a))) / (1 - e^-2lambda).
        for &(l, a) in &[(0.3f64, 1.2f64), (5.0, 0.4), (900.0, 0.05)] {
            let exact = -(-l * (1.0 - a.cos())).exp_m1() / -(-2.0 * l).exp_m1();
            assert!(
                (cap_fraction(l, 0.0, a) - exact).abs() < 1e-6,
                "lambda {l} a {a}"
            );
        }
    }

    #[test]
    fn table_lookups_stay_near_the_exact_form() {
        let table = table();
        let mut rng = Rng::new(7);
        let mut worst: f64 = 0.0;
        let mut at = (0.0, 0.0, 0.0);
        for _ in 0..20000 {
            let lambda = 2f64.powf(-3.0 + 16.0 * rng.f32() as f64);
            let a = 1.5 * rng.f32() as f64;
            let g = std::f64::consts::PI * rng.f32() as f64;
            let t = table.lookup(lambda as f32, g as f32, a as f32, (1.0 - a.cos()) as f32) as f64;
            let e = (t - cap_fraction(lambda, g, a)).abs();
            if e > worst {
                worst = e;
                at = (lambda, g, a);
            }
        }
        eprintln!(
            "cap table: worst |lookup - exact| over 20000 samples {worst:.5} at (lambda, g, a) = {at:.3?}"
        );
        // The nearest of 8 samples an octave in lambda, bilinear over steps of 1/48 in
        // sqrt(a / (pi/2)) and a quarter lobe width in s (1/8 rad below lambda 4): measured
        // 0.0122 (a lobe of sharpness 1.1 opposite a cap of 1.43 rad; 0.0147 before the
        // values were divided by m, at sharpness 7 well inside a cap of 0.55 rad; trilinear
        // over half octaves measured 0.0085); a regression (a wrong index, a swapped axis, m
        // left out) errs by O(0.1-1).
        assert!(worst < 0.02, "{worst}");
    }

    /// The a = 0 row holds the vanishing cap's limit, which no lookup of a cap above 0 reads
    /// alone: against the exact form of a cap of 1e-4 rad, divided by its m.
    #[test]
    fn the_vanishing_caps_row_is_the_limit_of_small_caps() {
        let table = table();
        let (nl, na, ns) = (N_LAMBDA as usize, N_ALPHA as usize, N_S as usize);
        let a = 1e-4f64;
        let mut compared = 0;
        for l in (0..nl).step_by(9) {
            for k in (0..ns).step_by(4) {
                let (lambda, _, g) = CapTable::sample(l, 0, k);
                let x = (1.0 - a.cos()) * lambda.max(1.0);
                let exact = cap_fraction(lambda, g, a) * (1.0 + x) / x;
                let row = table.values[l * na * ns + k] as f64;
                // The limit and a cap of 1e-4 rad differ by the lobe's change across the cap,
                // second order in a sqrt(lambda) <= 0.013 (its linear part averages out over
                // the cap): under 1e-3 of the value near the lobe; 1e-5 absolute in the far
                // tail (which [`cap_fraction`]'s window of 7 lobe widths leaves out). A row of
                // zeros, or doubled, errs by O(1).
                assert!(
                    (row - exact).abs() <= 1e-3 * exact + 1e-5,
                    "lambda {lambda:.3} g {g:.4}: row {row} vs exact {exact}"
                );
                compared += usize::from(exact > 1e-3);
            }
        }
        assert!(compared > 40, "{compared} values above 1e-3 compared");
    }

    #[test]
    fn small_caps_stay_near_the_exact_form() {
        let table = table();
        let mut rng = Rng::new(11);
        let (mut worst, mut at) = (0.0f64, (0.0, 0.0, 0.0));
        for _ in 0..20000 {
            let lambda = 2f64.powf(-3.0 + 16.0 * rng.f32() as f64);
            // Caps up to 0.4 lobe widths, spread over the lobe (g up to 6 widths + a).
            let a = (0.4 / lambda.sqrt()).min(1.5) * rng.f32() as f64;
            let g = ((a + 6.0 / lambda.sqrt()) * rng.f32() as f64).min(std::f64::consts::PI);
            let omc = (1.0 - a.cos()) as f32;
            let o = cap_occlusion(table, lambda as f32, g.cos() as f32, a as f32, omc);
            let e = (o as f64 - cap_fraction(lambda, g, a)).abs();
            if e > worst {
                worst = e;
                at = (lambda, g, a);
            }
        }
        eprintln!("small caps: worst |lookup - exact| {worst:.5} at {at:.3?}");
        // Measured 0.0015 (a lobe of sharpness 1.1, a cap of 0.37 rad). The forms small caps
        // took before measured 0.0085 (the lobe's value at the centre times the solid angle:
        // it ignores the lobe's change across the cap) and 0.0119 (the table of undivided
        // fractions); the divided table looked up without the factor m errs by ~1.
        assert!(worst < 0.005, "{worst}");
    }

    #[test]
    fn lobes_are_checked_and_packed() {
        let l = Lobe::new(glam::Vec3::Z, 3.0, [1.0, 2.0, 3.0]);
        let p = pack_lobes(&[l]).unwrap();
        assert_eq!(p, vec![[0.0, 0.0, 1.0, 3.0], [1.0, 2.0, 3.0, 0.0]]);
        assert!(pack_lobes(&[]).is_err());
        assert!(pack_lobes(&vec![l; MAX_LOBES + 1]).is_err());
        let bad = Lobe {
            sharpness: f32::NAN,
            ..l
        };
        assert!(
            pack_lobes(&[l, bad])
                .unwrap_err()
                .to_string()
                .contains("lobe 1")
        );
    }
}
