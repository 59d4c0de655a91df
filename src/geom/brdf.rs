//! The surface model the SRBF kernel shades and its ground truth integrates (shared
//! geometry-level math, so the truth needs nothing of the kernel): a BRDF rho(w, o) times the clamped cosine max(0, n . w), for
//! light direction w and view direction o (both unit, pointing away from the surface).
//!
//! - [`Brdf::Diffuse`]: rho = 1 / pi (the albedo multiplies the result outside the model).
//! - [`Brdf::Phong`]: the energy-normalised modified Phong BRDF (Lafortune and Willems 1994),
//!   rho = kd / pi + ks (n + 2) / (2 pi) max(0, w . r)^n, r = 2 (n . o) n - o the mirror
//!   direction of o. kd + ks <= 1 keeps it energy-conserving; the view direction enters only
//!   through r, so the specular lobe seen from o is a lobe of exponent n about r.

use crate::error::{Error, Result};
use glam::DVec3;

/// A BRDF with its parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "model", rename_all = "lowercase")]
pub enum Brdf {
    /// Lambertian: rho = 1 / pi.
    Diffuse,
    /// Modified Phong: rho = kd / pi + ks (n + 2) / (2 pi) max(0, w . r)^n.
    Phong {
        exponent: f32,
        diffuse: f32,
        specular: f32,
    },
}

/// The largest Phong exponent accepted: beyond ~SG-basis sharpness the transfer basis cannot
/// follow the lobe anyway, and n + 2 must stay exactly representable.
pub const MAX_EXPONENT: f32 = 10_000.0;

impl Brdf {
    /// Checks the parameters: a finite exponent in 0..=MAX_EXPONENT, kd and ks finite, >= 0,
    /// kd + ks <= 1 (energy conservation) and kd + ks > 0.
    pub fn check(&self) -> Result<()> {
        match *self {
            Brdf::Diffuse => Ok(()),
            Brdf::Phong {
                exponent,
                diffuse,
                specular,
            } => {
                if !(exponent.is_finite() && (0.0..=MAX_EXPONENT).contains(&exponent)) {
                    return Err(Error::InvalidArgument(format!(
                        "Phong exponent {exponent} must be in 0..={MAX_EXPONENT}"
                    )));
                }
                let ok = |x: f32| x.is_finite() && x >= 0.0;
                if !ok(diffuse) || !ok(specular) || diffuse + specular > 1.0 + 1e-6 {
                    return Err(Error::InvalidArgument(format!(
                        "Phong diffuse {diffuse} and specular {specular} must be >= 0 with a sum \
                         <= 1 (energy conservation)"
                    )));
                }
                if diffuse + specular <= 0.0 {
                    return Err(Error::InvalidArgument(
                        "Phong diffuse + specular is 0: the surface reflects nothing".into(),
                    ));
                }
                Ok(())
            }
        }
    }

    /// Whether the result depends on the view direction.
    pub fn is_glossy(&self) -> bool {
        matches!(self, Brdf::Phong { specular, .. } if *specular > 0.0)
    }

    /// rho(w, o) max(0, n . w) for unit n, w, o (0 for w below the surface). A view below
    /// the surface (n . o < 0, a silhouette of interpolated normals) is clamped to the
    /// horizon by the callers, not here: this is the model at the given o.
    pub fn cosine_weighted(&self, n: DVec3, w: DVec3, o: DVec3) -> f64 {
        let cos = n.dot(w);
        if cos <= 0.0 {
            return 0.0;
        }
        cos * self.rho(n, w, o)
    }

    /// The unit view direction at a surface point `x` with unit normal `n` for a camera at
    /// `camera`: o = camera - x, clamped onto the horizon when below it (a silhouette of
    /// interpolated normals: o - min(0, n . o) n), n itself at the camera or when o is -n.
    /// Part of the model: the method's view lookup and the truth both shade this o.
    pub fn view_direction(n: DVec3, x: DVec3, camera: DVec3) -> DVec3 {
        let o = camera - x;
        let o = o - o.dot(n).min(0.0) * n;
        if o.length_squared() > 0.0 {
            o.normalize()
        } else {
            n
        }
    }

    /// rho(w, o) alone.
    pub fn rho(&self, n: DVec3, w: DVec3, o: DVec3) -> f64 {
        use std::f64::consts::PI;
        match *self {
            Brdf::Diffuse => 1.0 / PI,
            Brdf::Phong {
                exponent,
                diffuse,
                specular,
            } => {
                let r = 2.0 * n.dot(o) * n - o;
                let e = exponent as f64;
                let lobe = w.dot(r).max(0.0).powf(e);
                diffuse as f64 / PI + specular as f64 * (e + 2.0) / (2.0 * PI) * lobe
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Directional albedo int rho cos dw by quadrature on a fine (theta, phi) grid.
    fn albedo(b: &Brdf, o: DVec3) -> f64 {
        let (nt, np) = (2000, 400);
        let mut sum = 0.0;
        for i in 0..nt {
            let theta = (i as f64 + 0.5) / nt as f64 * std::f64::consts::FRAC_PI_2;
            for j in 0..np {
                let phi = (j as f64 + 0.5) / np as f64 * std::f64::consts::TAU;
                let w = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                let d = theta.sin()
                    * (std::f64::consts::FRAC_PI_2 / nt as f64)
                    * (std::f64::consts::TAU / np as f64);
                sum += b.cosine_weighted(DVec3::Z, w, o) * d;
            }
        }
        sum
    }

    /// The normalisation: at normal view the specular lobe (about r = n) integrates to ks
    /// exactly ((n + 2) / 2pi int cos^n cos = 1), the diffuse part to kd; so the directional
    /// albedo is kd + ks to the quadrature's error (2000 x 400 midpoint: < 1e-4 here).
    #[test]
    fn phong_is_normalised_at_normal_view() {
        for e in [1.0, 8.0, 32.0] {
            let b = Brdf::Phong {
                exponent: e,
                diffuse: 0.3,
                specular: 0.6,
            };
            let a = albedo(&b, DVec3::Z);
            assert!((a - 0.9).abs() < 1e-3, "exponent {e}: albedo {a}");
            // At a grazing view part of the lobe is below the horizon: less, never more.
            let grazing = albedo(&b, DVec3::new(0.8, 0.0, 0.6));
            assert!(grazing < a && grazing > 0.3, "{grazing}");
        }
        assert!((albedo(&Brdf::Diffuse, DVec3::Z) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn bad_parameters_are_refused() {
        let p = |exponent, diffuse, specular| Brdf::Phong {
            exponent,
            diffuse,
            specular,
        };
        assert!(p(16.0, 0.5, 0.5).check().is_ok());
        for (b, what) in [
            (p(f32::NAN, 0.5, 0.5), "exponent"),
            (p(-1.0, 0.5, 0.5), "exponent"),
            (p(16.0, 0.7, 0.5), "sum"),
            (p(16.0, -0.1, 0.5), "sum"),
            (p(16.0, 0.0, 0.0), "reflects nothing"),
        ] {
            let e = b.check().unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
    }
}
