//! SRBF environment lighting with GPU rotation and precomputed transfer (all-frequency PRT):
//! the environment as a sum of spherical Gaussians (`fit`), each vertex's visibility x
//! cosine projected onto a fixed SG basis (`transfer`), and per frame on the GPU: rotate the
//! lighting lobes, compute the lighting's coefficients in the transfer basis from the
//! closed-form SG inner products, shade every vertex. `inputs`: what the kernel is built
//! from and checks; `pack`: its data as the GPU holds it; `gpu`: the kernel; `cpu`: its twin.

pub mod brdf_factors;
pub mod cpca;
pub mod cpca_matrix;
pub mod cpu;
pub mod cta;
pub mod cta_gpu;
pub mod fit;
pub mod glossy;
pub mod glossy_gpu;
pub mod glossy_sharp;
pub mod gpu;
pub mod inputs;
pub mod pack;
pub mod sharp;
pub mod transfer;

use crate::error::Result;
use crate::geom::visibility::Visibility;
use crate::scene::EnvMap;
use transfer::{Basis, Transfer};

/// The diffuse transfer of a mesh: each vertex's V(w) max(0, n . w) / pi, sampled at the
/// texel directions of `dir_env` (the directions `vis` was cast for), projected onto
/// `basis`.
pub fn diffuse_transfer(
    basis: &Basis,
    dir_env: &EnvMap,
    normals: &[glam::Vec3],
    vis: &Visibility,
) -> Result<Transfer> {
    let samples = dir_env.samples();
    let directions: Vec<glam::Vec3> = samples.iter().map(|s| s.0).collect();
    let solid_angles: Vec<f64> = samples.iter().map(|s| s.1).collect();
    transfer::project(basis, &directions, &solid_angles, vis.vertices, |v, d| {
        if vis.visible(v, d) {
            normals[v].dot(directions[d]).max(0.0) / std::f32::consts::PI
        } else {
            0.0
        }
    })
}

/// The glossy transfer of a mesh ([`glossy::project`]): V_v(w) rho(w, o_j) max(0, n . w)
/// for every row of `view` (a view node o_j, or a term of the BRDF's factorisation), at the texel directions of `dir_env` (those `vis` was
/// cast for), projected onto `basis`.
pub fn glossy_transfer(
    basis: &Basis,
    brdf: &crate::geom::brdf::Brdf,
    view: &glossy::ViewBasis,
    dir_env: &EnvMap,
    normals: &[glam::Vec3],
    vis: &Visibility,
) -> Result<glossy::GlossyTransfer> {
    let samples = dir_env.samples();
    let directions: Vec<glam::Vec3> = samples.iter().map(|s| s.0).collect();
    let solid_angles: Vec<f64> = samples.iter().map(|s| s.1).collect();
    glossy::project(basis, brdf, view, &directions, &solid_angles, normals, vis)
}

/// The built-in mesh of `vkshade srbf shade` and `bench srbf` (Debian package glmark2-data).
pub const DEFAULT_MESH: &str = "/usr/share/glmark2/models/bunny.obj";
/// The built-in environment (Debian package blender-data).
pub const DEFAULT_ENV: &str = "/usr/share/blender/datafiles/studiolights/world/forest.exr";
