//! Texture-space importance-sampled subsurface diffusion for skin (kernels.md section 2).
//!
//! - [`profile`]: diffusion profiles (dipole, Burley), truncation radius, sampling tables.
//! - [`texspace`]: the mesh rasterised into its UV layout (position, normal, Jacobian per
//!   texel; overlap repair; gutters), on the CPU.
//! - [`gpu`]: the kernel (passes `sss lights`, `sss irradiance`, `sss diffusion`).
//! - [`cpu`]: the CPU twin of both passes (same rays, same sample sequence).
//! - The brute-force ground truth is `reference::sss`.
//!
//! Conventions: model units are scaled to mm (`mm_per_unit`); scattering coefficients are
//! per mm; `diffuse` holds B(xo) = int E(xi) Rd(|xi - xo|) dA(xi) before the exit Fresnel
//! and 1/pi factors, so a uniformly lit plane gives B = E K(R) (E R_tot untruncated).
//! Transmission through thin parts (ears): in the irradiance pass, the thickness along -n
//! and the back surface's irradiance give E_b (R_tot - F(t)) per channel (a locally flat
//! slab lit from behind; [`cpu::transmission`]), written to its own buffer.
//! Skinned meshes: posed and re-rasterised on the CPU each frame, uploaded with
//! [`SssKernel::update_geometry`] (`vkshade sss --anim`).

pub mod cpu;
pub mod gpu;
pub mod profile;
pub mod texspace;

pub use cpu::{Light, SamplerParams};
pub use gpu::{SssKernel, SssOutput};
pub use profile::{Material, Profile, ProfileKind};
pub use texspace::TexGeometry;
