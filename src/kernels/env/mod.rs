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
//!   (g - a) sqrt(max(lambda, 4))) ([`pack::CapTable`]: bilinear in (a, s), the nearest of 8
//!   samples an octave in lambda, the values over the cap's size against the lobe's so that
//!   small caps and large take the same lookup; [`cap_occlusion`]). O_js is weighted by the
//!   cap's share above the horizon ([`pack::above_horizon`]): light from below adds nothing,
//!   and a sinking cap fades out instead of dropping out (no jump where AO's I_s reaches 0).
//! - Caps combine by product: the caps' visibility of lobe j is C_j = prod_s (1 - O_js)^w_s
//!   (each factor floored at [`MIN_TRANSMISSION`]); with traced rays each weighted factor is
//!   taken linear in w_s, 1 - w_s (1 - (1 - O_js)), exact at w_s = 0 and 1 (the weights are
//!   fractional only across AO's refinement band), so the pass multiplies instead of taking a
//!   log per cap and lobe.
//! - What turns C_j into the lobe's visibility V_j ([`EnvVisibility`]):
//!   - **Traced rays, per lobe (the default; module `env/shadow_rays`).** Every frame the
//!     kernel refits a BVH of the posed character (built once over the rest pose) and casts
//!     4 x 4 stratified cosine-weighted rays a vertex (passes `env bvh leaves`,
//!     `env bvh refit`, `env trace`). Each ray k has a residual e_k - c_k: whether it escaped
//!     the mesh, less the caps' own transmission along it (prod over the caps holding the
//!     ray of [`MIN_TRANSMISSION`]^w_s). The residuals are a control variate for the caps: a
//!     lobe takes the mean residual of the rays near it,
//!     V_j = clamp(C_j + sum_k K_jk (e_k - c_k) / sum_k K_jk, 0, 1), with
//!     K_jk = exp(min(lambda_j, [`CV_SHARPNESS`]) (axis_j . d_k - 1)). Where the caps miss the
//!     mesh (a gap they close, a part they lack), only the lobes on that side move, so the
//!     pass walks a coarser cut than AO's ([`CV_TAU`]: fewer caps). On BCN_Epileptic
//!     (`vkshade env --reference`, 32 lobes, 2048-ray truth): 8.3 / 8.0 / 8.2% at three
//!     poses (at tau 1.2: 7.5 / 7.7 / 7.9%, against 9.1 / 9.6 / 10.6% for the same caps
//!     scaled by the same rays' escaped fraction), and at the character frame's three
//!     reference poses (16 lobes) 7.9 / 8.0 / 8.7% (at tau 1.2: 7.6 / 7.9 / 8.3%, against
//!     8.2 / 13.4 / 11.1% for this kernel's method before: that scale, AO's cut).
//!   - **AO's visibility as a scale (module `env/shadow`).** With I_s AO's exact per-sphere
//!     cosine-weighted occlusion and AO(x) its blended (cone-mask union), corrected
//!     visibility, V_j = clamp(AO(x) C_j / prod_s (1 - I_s)^w_s, 0, 1). Under a uniform
//!     environment the lobes' product ~ AO's product, so the lobes' mean visibility is AO's.
//!     The ratio carries AO's overlap handling and its static correction to every lobe, but
//!     AO, exact in its bind-pose bake, errs by MAE 0.04 once the character moves: 7.9 /
//!     15.1 / 16.4% at the same three poses.
//! - E_j(n): Hill's fitted SG irradiance, the inner product with the cosine SG below
//!   lambda = 1 ([`cpu::irradiance`]); E(x) = sum_j V_j E_j(n) amplitude_j, radiometric (no
//!   1/pi).
//!
//! - [`pack`]: the lobes in the GPU's layout and the cap table, checked.
//! - [`gpu`]: the kernel ([`EnvKernel`]: passes `env rotate`, with traced visibility
//!   `env bvh leaves`, `env bvh refit`, `env trace`, then `env shadow`).
//! - [`cpu`]: the CPU twins (same f32 operations: [`cpu::shadow`], [`cpu::traced_rays`])
//!   and the f64 ray-traced truth ([`cpu::ray_traced`]).

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
/// Sharpest kernel the traced rays' residuals are weighed by per lobe (module
/// `env/shadow_rays`): K_jk = exp(min(lambda_j, CV_SHARPNESS) (axis_j . d_k - 1)). With 16
/// cosine-weighted rays (~0.4 sr each) a kernel of sharpness 8 (~0.8 sr) spans about two
/// rays; sharper lobes would lean on one ray's residual.
pub const CV_SHARPNESS: f32 = 8.0;
/// The coarsest refinement threshold of the cut the shadow pass walks with traced rays
/// (AO's tau if coarser): the rays correct what a coarser cut's caps get wrong, so the pass
/// evaluates fewer caps. On BCN_Epileptic (1024-ray truths, the worst of three poses; caps
/// per vertex at that pose, CPU twin) tau 0.8 / 1.0 / 1.2 / 1.6 gave 8.8 / 8.7 / 8.8 / 9.5%
/// at the frame's poses (16 lobes; 47 / 39 / 34 / 26 caps) and 7.8 / 8.1 / 8.6 / 9.0% at
/// `vkshade env`'s (32 lobes; 46 / 37 / 31 / 21 caps), before later changes to the method.
/// Measured again on 2026-12-05 (GPU, `vkshade frame --reference` and `vkshade env
/// --reference`, their defaults; per pose): tau 1.2 / 1.4 / 1.6 give 7.62 / 7.94 / 8.29%,
/// 7.88 / 7.97 / 8.65% and 7.95 / 8.29 / 9.15% at the frame's poses, and 7.53 / 7.72 /
/// 7.87%, 8.27 / 7.98 / 8.18% and 8.33 / 8.16 / 8.40% at `vkshade env`'s; the frame's
/// `env shadow` took 11.8-12.2 / 9.2-9.3 / 8.6-10.1 ms in `bench frame` (alternating runs
/// on one 2-core VM; the whole frame's median 62.3 -> 59.6 ms from 1.2 to 1.4). 1.4 keeps
/// most of the time saved for under half the error added.
pub const CV_TAU: f32 = 1.4;

/// The cut the shadow pass walks: AO's, coarsened to tau >= [`CV_TAU`] when traced rays
/// correct the caps (`traced`).
pub fn shadow_cut(ao: &crate::kernels::ao::AoParams, traced: bool) -> crate::kernels::ao::AoParams {
    if traced {
        crate::kernels::ao::AoParams {
            tau: ao.tau.max(CV_TAU),
            ..*ao
        }
    } else {
        *ao
    }
}
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
