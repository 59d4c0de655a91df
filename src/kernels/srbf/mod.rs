//! SRBF environment lighting with GPU rotation and precomputed transfer (all-frequency PRT):
//! the environment as a sum of spherical Gaussians (`fit`), each vertex's visibility x
//! cosine projected onto a fixed SG basis (`transfer`), and per frame on the GPU: rotate the
//! lighting lobes, compute the lighting's coefficients in the transfer basis from the
//! closed-form SG inner products, shade every vertex.

pub mod fit;
pub mod gpu;
pub mod sg;
pub mod transfer;

/// The built-in mesh of `vkshade srbf shade` and `bench srbf` (Debian package glmark2-data).
pub const DEFAULT_MESH: &str = "/usr/share/glmark2/models/bunny.obj";
/// The built-in environment (Debian package blender-data).
pub const DEFAULT_ENV: &str = "/usr/share/blender/datafiles/studiolights/world/forest.exr";
