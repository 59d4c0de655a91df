//! SRBF environment lighting with GPU rotation and precomputed transfer (all-frequency PRT):
//! the environment as a sum of spherical Gaussians (`fit`), each vertex's visibility x
//! cosine projected onto a fixed SG basis (`transfer`), and per frame on the GPU: rotate the
//! lighting lobes, compute the lighting's coefficients in the transfer basis from the
//! closed-form SG inner products, shade every vertex.

pub mod fit;
pub mod sg;
pub mod transfer;
