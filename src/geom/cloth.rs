//! The material model of the synthetic BTFs, shared by `btf synth` and the ground truth
//! (`reference::btf`): periodic heightfields (woven, knitted, ribbed cloth) with a known BRDF
//! (Lambert + a normalised Blinn-Phong lobe), ray-cast with self-shadowing and masking at
//! any light and view direction.
//!
//! Geometry: the tile is the unit square in x (texture u, tangent) and y (texture v,
//! bitangent), heights in the same unit above z = 0. A texel (c, r) of an image sees the
//! surface point hit by the ray that leaves the reference plane at its centre
//! ((c + 0.5) / P, (r + 0.5) / P) towards the viewer (P texels per period), i.e. the image
//! is rectified to the reference plane as measured BTFs are. A texel's value is the radiance
//! towards the viewer under a directional light of irradiance pi at normal incidence, so a
//! flat white Lambertian surface gives cos(theta_l); values are linear.

use crate::error::{Error, Result};

/// The cloth patterns `btf synth` knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    /// Plain weave: two warp and two weft threads per tile, alternating over and under.
    Weave,
    /// Stockinette knit: 2 x 2 stitches per tile, each a V of two slanted loop legs.
    Knit,
    /// Corduroy: three wales (ridges along v) per tile with a fine pile across them.
    Rib,
}

impl Pattern {
    pub fn name(self) -> &'static str {
        match self {
            Pattern::Weave => "weave",
            Pattern::Knit => "knit",
            Pattern::Rib => "rib",
        }
    }

    /// Upper bound of the height.
    pub fn max_height(self) -> f64 {
        match self {
            Pattern::Weave => 0.07 + 2.0 * 0.035,
            Pattern::Knit => 0.08,
            Pattern::Rib => 0.1 + 0.008,
        }
    }

    /// Height and linear albedo at (x, y) (periodic with period 1).
    pub fn surface(self, x: f64, y: f64) -> (f64, [f64; 3]) {
        let (x, y) = (x.rem_euclid(1.0), y.rem_euclid(1.0));
        let profile = |d: f64, w: f64| {
            let q = 1.0 - (d / w) * (d / w);
            if q > 0.0 { Some(q.sqrt()) } else { None }
        };
        match self {
            Pattern::Weave => {
                const R: f64 = 0.07;
                const W: f64 = 0.2;
                const A: f64 = 0.035;
                let tau = std::f64::consts::TAU;
                let (j, i) = ((y >= 0.5) as u32 as f64, (x >= 0.5) as u32 as f64);
                let mut best = (0.0, [0.03, 0.03, 0.03]);
                if let Some(p) = profile(y - 0.25 - 0.5 * j, W) {
                    let h = R * p + A + A * (tau * (x - 0.25 - 0.5 * j)).cos();
                    if h > best.0 {
                        best = (h, [0.55, 0.08, 0.06]);
                    }
                }
                if let Some(p) = profile(x - 0.25 - 0.5 * i, W) {
                    let h = R * p + A - A * (tau * (y - 0.25 - 0.5 * i)).cos();
                    if h > best.0 {
                        best = (h, [0.75, 0.7, 0.5]);
                    }
                }
                best
            }
            Pattern::Knit => {
                const R: f64 = 0.08;
                let (u, v) = ((x * 2.0).fract() * 0.5, (y * 2.0).fract() * 0.5);
                let mut best = (0.0, [0.02, 0.02, 0.03]);
                for (cx, tilt, tint) in [(0.16, 0.45f64, 1.0), (0.34, -0.45f64, 0.85)] {
                    let (dx, dy) = (u - cx, v - 0.25);
                    let (c, s) = (tilt.cos(), tilt.sin());
                    let along = dx * s + dy * c;
                    let across = dx * c - dy * s;
                    let q = 1.0 - (along / 0.2).powi(2) - (across / 0.075).powi(2);
                    if q > 0.0 {
                        let h = R * q.sqrt();
                        if h > best.0 {
                            best = (h, [0.15 * tint, 0.3 * tint, 0.55 * tint]);
                        }
                    }
                }
                best
            }
            Pattern::Rib => {
                const R: f64 = 0.1;
                let k = (x * 3.0).floor();
                let d = x - (k + 0.5) / 3.0;
                match profile(d, 0.15) {
                    Some(p) => (
                        R * p + 0.004 * (1.0 + (std::f64::consts::TAU * 12.0 * y).cos()),
                        [0.4, 0.25, 0.12],
                    ),
                    None => (0.0, [0.05, 0.03, 0.02]),
                }
            }
        }
    }

    fn height(self, x: f64, y: f64) -> f64 {
        self.surface(x, y).0
    }
}

/// Diffuse fraction of the albedo, specular strength and Blinn-Phong exponent of the BRDF.
pub const KD: f64 = 0.9;
pub const KS: f64 = 0.06;
pub const EXPONENT: f64 = 30.0;
const STEP: f64 = 0.01;

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Radiance towards `v` of the surface seen through reference-plane point (x, y), lit from
/// `l` (unit vectors, tangent space; zero when either is at or below the horizon).
pub fn radiance(pattern: Pattern, x: f64, y: f64, l: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    if l[2] <= 1e-6 || v[2] <= 1e-6 {
        return [0.0; 3];
    }
    let hmax = pattern.max_height();
    let at = |t: f64| [x + v[0] * t, y + v[1] * t, v[2] * t];
    let f = |t: f64| {
        let p = at(t);
        p[2] - pattern.height(p[0], p[1])
    };
    // March from the top of the height range down the view ray to the first point below
    // the surface, then bisect.
    let vxy = v[0].hypot(v[1]);
    let dt = (STEP / vxy.max(1e-9)).min(STEP / v[2]);
    let mut t = hmax / v[2] + 1e-9;
    let mut hit = 0.0;
    while t > 0.0 {
        let next = (t - dt).max(0.0);
        if f(next) <= 0.0 {
            let (mut hi, mut lo) = (t, next);
            for _ in 0..30 {
                let m = 0.5 * (hi + lo);
                if f(m) <= 0.0 {
                    lo = m;
                } else {
                    hi = m;
                }
            }
            hit = lo;
            break;
        }
        t = next;
    }
    let p = at(hit);
    let (h, albedo) = pattern.surface(p[0], p[1]);
    let e = 1e-5;
    let hx = (pattern.height(p[0] + e, p[1]) - pattern.height(p[0] - e, p[1])) / (2.0 * e);
    let hy = (pattern.height(p[0], p[1] + e) - pattern.height(p[0], p[1] - e)) / (2.0 * e);
    let n = normalize([-hx, -hy, 1.0]);
    let cos = dot(n, l);
    if cos <= 0.0 {
        return [0.0; 3];
    }
    // Shadow ray towards the light, until it leaves the height range.
    let lxy = l[0].hypot(l[1]);
    let ds = (STEP / lxy.max(1e-9)).min(STEP / l[2]);
    let top = (hmax - h) / l[2];
    let mut s = ds.min(top) * 0.5;
    while s < top {
        let q = [p[0] + l[0] * s, p[1] + l[1] * s, h + l[2] * s];
        if q[2] < pattern.height(q[0], q[1]) - 1e-7 {
            return [0.0; 3];
        }
        s += ds;
    }
    let half = normalize([l[0] + v[0], l[1] + v[1], l[2] + v[2]]);
    let spec = KS * (EXPONENT + 8.0) / 8.0 * dot(n, half).max(0.0).powf(EXPONENT);
    albedo.map(|a| (KD * a + spec) * cos)
}

/// What to synthesise.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SynthConfig {
    pub pattern: Pattern,
    /// Image width and height in texels.
    pub size: [u32; 2],
    /// Texels per pattern period (= the size for one tile).
    pub period: u32,
    /// Rays per texel along each axis (the texel value is their mean).
    pub samples: u32,
}

impl SynthConfig {
    /// One tile of `size` x `size` texels, one ray per texel.
    pub fn tile(pattern: Pattern, size: u32) -> SynthConfig {
        SynthConfig {
            pattern,
            size: [size, size],
            period: size,
            samples: 1,
        }
    }

    pub fn check(&self) -> Result<()> {
        if !(1..=1024).contains(&self.size[0])
            || !(1..=1024).contains(&self.size[1])
            || !(1..=1024).contains(&self.period)
            || !(1..=8).contains(&self.samples)
        {
            return Err(Error::InvalidArgument(format!(
                "BTF synthesis: size {:?} and period {} must be in 1..=1024, samples {} in 1..=8",
                self.size, self.period, self.samples
            )));
        }
        Ok(())
    }

    /// The value of texel (c, r) for light `l` and view `v`.
    pub fn texel(&self, c: u32, r: u32, l: [f64; 3], v: [f64; 3]) -> [f64; 3] {
        let n = self.samples;
        let mut sum = [0.0; 3];
        for sy in 0..n {
            for sx in 0..n {
                let x = (c as f64 + (sx as f64 + 0.5) / n as f64) / self.period as f64;
                let y = (r as f64 + (sy as f64 + 0.5) / n as f64) / self.period as f64;
                let q = radiance(self.pattern, x, y, l, v);
                for k in 0..3 {
                    sum[k] += q[k];
                }
            }
        }
        sum.map(|s| s / (n * n) as f64)
    }

    /// One image (row-major) for light `l` and view `v`.
    pub fn image(&self, l: [f64; 3], v: [f64; 3]) -> Vec<[f32; 3]> {
        let [w, h] = self.size;
        (0..w * h)
            .map(|k| self.texel(k % w, k / w, l, v).map(|x| x as f32))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::btf::dirs::Angles;

    #[test]
    fn flat_parts_are_lambertian_and_shadows_appear() {
        // Rib on a wale's ridge line (x = 0.5 / 3), lit from straight above: the specular
        // lobe is white, so red - blue is the Lambert term KD (0.4 - 0.12) cos, with cos in
        // [0.95, 1] (the pile tilts the normal by at most 17 deg).
        let v = Angles { theta: 60, phi: 90 }.vector();
        let l = [0.0, 0.0, 1.0];
        let q = radiance(Pattern::Rib, 0.5 / 3.0 - 0.3 * v[0], 0.0, l, v);
        let diffuse = (q[0] - q[2]) / (KD * (0.4 - 0.12));
        assert!((0.95..=1.0).contains(&diffuse), "{q:?}");
        // Grazing light across the ridges leaves the grooves in shadow.
        let lg = Angles { theta: 75, phi: 0 }.vector();
        let top = [0.0, 0.0, 1.0];
        let groove = radiance(Pattern::Rib, 1.0 / 3.0 + 0.001, 0.0, lg, top);
        assert_eq!(groove, [0.0; 3]);
        let crest = radiance(Pattern::Rib, 0.5 / 3.0 + 0.05, 0.0, lg, top);
        assert!(crest[0] > 0.0);
    }

    #[test]
    fn images_repeat_with_the_period() {
        let cfg = SynthConfig {
            pattern: Pattern::Weave,
            size: [12, 12],
            period: 6,
            samples: 1,
        };
        let img = cfg.image(
            Angles { theta: 45, phi: 40 }.vector(),
            Angles { theta: 30, phi: 0 }.vector(),
        );
        for r in 0..6 {
            for c in 0..6 {
                let a = img[r * 12 + c];
                for b in [img[r * 12 + c + 6], img[(r + 6) * 12 + c]] {
                    for k in 0..3 {
                        assert!((a[k] - b[k]).abs() < 1e-4);
                    }
                }
            }
        }
    }
}
