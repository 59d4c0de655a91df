//! Ground truth for the BTF kernel: the synthetic heightfield ray-cast directly at each
//! pixel's exact light and view directions (no angular interpolation), filtered over the
//! tile texels the way the GPU filters the stored images, so the difference to the GPU is
//! the interpolation error (plus the 8-bit storage).

use crate::geom::bilinear;
use crate::geom::cloth::SynthConfig;
use crate::scene::gbuffer::{Frame, GBuffer, frame_of, to_tangent};
use rayon::prelude::*;

/// Per pixel: linear RGBA (alpha 0 outside the object) and the larger polar angle (degrees)
/// of its view and lights, for splitting errors at 75 deg.
pub fn ray_cast(cfg: &SynthConfig, gbuffer: &GBuffer, frame: &Frame) -> (Vec<[f64; 4]>, Vec<f64>) {
    let n = gbuffer.width as usize * gbuffer.height as usize;
    (0..n)
        .into_par_iter()
        .map(|k| {
            let Some(px) = gbuffer.pixel(k) else {
                return ([0.0; 4], 0.0);
            };
            let tbn = frame_of(&px);
            let v = to_tangent(frame.camera.view(px.position), tbn);
            let mut theta = v[2].clamp(-1.0, 1.0).acos().to_degrees();
            let mut sum = [0.0; 3];
            for light in &frame.lights {
                let l = to_tangent(light.direction.as_dvec3().normalize(), tbn);
                if l[2] > 0.0 {
                    theta = theta.max(l[2].clamp(-1.0, 1.0).acos().to_degrees());
                }
                if l[2] <= 0.0 || v[2] <= 0.0 {
                    continue;
                }
                // The stored images clip at 1 (8-bit PNG); so does the truth.
                let t = bilinear(cfg.size, px.uv, |c, r| {
                    cfg.texel(c, r, l, v).map(|x| x.min(1.0))
                });
                for i in 0..3 {
                    sum[i] += light.rgb[i] as f64 * t[i];
                }
            }
            ([sum[0], sum[1], sum[2], 1.0], theta)
        })
        .unzip()
}
