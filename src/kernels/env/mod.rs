//! Environment light on a moving character: SG-fitted environment lobes, rotated per frame on
//! the GPU, each lobe shadowed per vertex by the caps of the character's own sphere tree (the
//! cut AO walks), summed into per-vertex irradiance.
//!
//! Method (per vertex x with normal n, per lobe j, every frame):
//! - Product lobe P_j = G_j x cosine SG (cosine ~ G(w; n, 2.133, 1.17)): one SG, axis and
//!   sharpness lambda_P from r = lambda_j p_j + 2.133 n.
//! - For every sphere of AO's cut (same refinement, blend weights w_s, inside fade), cap
//!   half-angle a = asin(r / d) at angle g from P_j's axis: O_js = the fraction of P_j inside
//!   the cap, exact as the 1D integral 2 pi int_0^a e^(lambda (cos(g - t) - 1))
//!   i0e(lambda sin g sin t) sin t dt / int P_j, tabulated once over (log2 lambda, a,
//!   (g - a) sqrt(lambda)) ([`pack::CapTable`]); caps smaller than 0.3 lobe widths by the
//!   lobe's value at their centre times their solid angle, blended into the table up to 0.4
//!   ([`cap_occlusion`]). O_js is weighted by the cap's share above the horizon
//!   ([`pack::above_horizon`]): light from below adds nothing, and a sinking cap fades out
//!   instead of dropping out (no jump where AO's I_s reaches 0).
//! - Caps combine by product, and AO's own judgement of the same caps corrects it: with
//!   I_s AO's exact per-sphere cosine-weighted occlusion and AO(x) its blended (cone-mask
//!   union), corrected visibility,
//!   V_j = clamp(AO(x) prod_s ((1 - O_js) / (1 - I_s))^w_s, 0, 1).
//!   Under a uniform environment the lobes' product ~ AO's product, so the lobes' mean
//!   visibility is AO's; a lobe behind a cap loses all of it (a lobe inside a cap has
//!   1 - O_js = 0), one in the open keeps more than AO. The ratio carries AO's overlap handling
//!   and its static correction (mesh detail the spheres miss) to every lobe.
//! - A(x), the visibility the split is scaled by ([`EnvVisibility`]): by default the
//!   fraction of 4 x 4 stratified cosine-weighted rays that escape the posed mesh, cast every
//!   frame through a BVH built once over the rest pose and refitted to the pose (passes
//!   `env bvh leaves`, `env bvh refit`, `env trace`); or AO's own visibility. Measured on
//!   BCN_Epileptic (`vkshade env --reference`): the caps' split scaled by the truth's own
//!   2048-ray visibility errs 7.9 / 9.2 / 8.7% at three poses, by 16 traced rays 8.7 / 9.6 /
//!   9.1%, by AO's 7.9 / 15.1 / 16.4% (AO, exact in its bind-pose bake, errs by MAE 0.04 once
//!   the character moves). The caps give the direction, the rays the amount.
//! - E_j(n): Hill's fitted SG irradiance, the inner product with the cosine SG below
//!   lambda = 1 ([`cpu::irradiance`]); E(x) = sum_j V_j E_j(n) amplitude_j, radiometric (no
//!   1/pi).
//!
//! - [`pack`]: the lobes in the GPU's layout and the cap table, checked.
//! - [`gpu`]: the kernel ([`EnvKernel`]: passes `env rotate`, with traced visibility
//!   `env bvh leaves`, `env bvh refit`, `env trace`, then `env shadow`).
//! - [`cpu`]: the CPU twins (same f32 operations: [`cpu::shadow`],
//!   [`cpu::traced_visibility`]) and the f64 ray-traced truth ([`cpu::ray_traced`]).

#![warn(missing_docs)]

pub mod cpu;
pub mod gpu;
pub mod pack;

pub use gpu::{
    DEFAULT_TRACE_GRID, EnvKernel, EnvReadback, EnvVisibility, MAX_TRACE_GRID, PASS_BVH_LEAVES,
    PASS_BVH_REFIT, PASS_ROTATE, PASS_SHADOW, PASS_TRACE,
};
pub use pack::{CapTable, MAX_LOBES, cap_occlusion, pack_lobes};

/// Sharpness and amplitude of the cosine lobe as an SG: max(0, n . w) ~ 1.17 e^(2.133 (n . w - 1))
/// (Wang et al. 2009).
pub const COSINE_SHARPNESS: f32 = 2.133;
/// See [`COSINE_SHARPNESS`].
pub const COSINE_AMPLITUDE: f32 = 1.17;
/// Below this sharpness a lobe's irradiance is the inner product with the cosine SG (Hill's fit
/// fails there).
pub const HILL_MIN_SHARPNESS: f32 = 1.0;
/// Floor of 1 - O_js and 1 - I_s in the products: a cap that nearly fills the hemisphere (a
/// receiver touching a sphere) would otherwise make the ratio 0/0, amplifying rounding by 1e6.
pub const MIN_TRANSMISSION: f32 = 0.02;

/// Checks a frame's environment rotation: finite and orthonormal (|R^T R - I| < 1e-3).
pub fn check_rotation(r: &glam::Mat3) -> crate::error::Result<()> {
    use crate::error::Error;
    if !r.is_finite() {
        return Err(Error::InvalidArgument(
            "the environment rotation is not finite".into(),
        ));
    }
    let d = r.transpose() * *r - glam::Mat3::IDENTITY;
    let worst = d.to_cols_array().iter().fold(0.0f32, |m, x| m.max(x.abs()));
    if worst > 1e-3 {
        return Err(Error::InvalidArgument(format!(
            "the environment rotation is not orthonormal (|R^T R - I| = {worst})"
        )));
    }
    Ok(())
}
