//! The character frame's final pass (`compose shade`): per pixel of the screen G-buffer, skin
//! shading from the texture-space diffusion (Fresnel at exit, a Kelemen/Szirmay-Kalos
//! specular layer for the directional lights and, through the warped-NDF spherical
//! Gaussian, for every environment lobe weighted by its per-vertex visibility), the cloth's
//! BTF radiance, a background colour; then exposure, tone mapping and sRGB
//! encoding. Linear HDR radiance and 8-bit sRGB come out side by side.
//!
//! `pack`: what is fixed per character (the skin triangles' atlas corners, the atlas's valid
//! texels) and the per-frame parameters; `gpu`: the kernel; `cpu`: its twin.
//!
//! Conventions (see docs/architecture.md, "The character frame"): the skin parts come first
//! in the character's mesh, so triangle ids below [`pack::Prepared::skin_triangles`] are skin;
//! every radiance is radiometric (irradiance E with no 1/pi; the 1/pi of the diffuse exit is
//! applied here, once); the diffusion already holds the entry transmission and any
//! environment visibility, so no ambient occlusion is applied again here.

pub mod cpu;
pub mod gpu;
pub mod pack;

pub use gpu::{
    ComposeKernel, ComposeOutput, NeedKernel, PASS_BACKGROUND, PASS_CLASSIFY, PASS_NEED,
    PASS_NEED_CLEAR, PASS_PARAMS, PASS_SHADE, PASS_SHADE_SKIN, TileClassKernel, TileClasses,
};
pub use pack::{Environment, FrameParams, Prepared, SkinSpecular};
