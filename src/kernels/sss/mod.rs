//! Texture-space importance-sampled subsurface diffusion for skin (kernels.md section 2).
//!
//! - [`profile`]: the material model, diffusion profiles Rd(r) (dipole, Burley) and their
//!   truncation radii; it lives in [`crate::geom`] because the brute-force truth reads it too.
//! - [`sampler`]: how the method samples a profile (the mixture sequence, inverse-CDF
//!   tables) and the profile's parameters as the shader gets them.
//! - [`crate::scene::texspace`]: the mesh rasterised into its UV layout (position, normal,
//!   Jacobian per texel; overlap repair; gutters), on the CPU; a scene input the brute-force
//!   truth reads too.
//! - [`walk`]: where a sample lands when it leaves the receiver's triangle (across the edge
//!   it leaves by, seams included; off the surface past an open edge).
//! - [`regions`]: multi-region skin, a profile per region of the mesh (the exit point's).
//! - [`contact`]: light between separate pieces of the mesh that touch (eyeballs, mouth).
//! - [`pack`]: what the kernel uploads, packed and checked on the CPU.
//! - [`posed`]: what a skinned mesh's UV layout fixes (built once), and the CPU twins of
//!   the BVH refit.
//! - [`gpu`]: the kernel (passes `sss lights`, `sss vertex light`, `sss ray list`,
//!   `sss irradiance`, `sss irradiance rays` (the shadow rays of the texels it listed),
//!   `sss diffusion`; posed: `sss pose vertices`, `sss pose triangles`, `sss bvh leaves`,
//!   `sss bvh refit` first, and the irradiance computes the texel geometry itself). An
//!   optional per-vertex rgb irradiance (e.g. the environment shadowed by the character) is
//!   added before the diffusion ([`SssKernel::set_vertex_irradiance`]).
//! - [`cpu`]: the CPU twin of both passes (same rays, same sample pattern).
//! - The brute-force ground truth is `reference::sss`.
//!
//! Conventions: model units are scaled to mm (`mm_per_unit`); scattering coefficients are
//! per mm; `diffuse` holds B(xo) = int E(xi) Rd(|xi - xo|) dA(xi) before the exit Fresnel
//! and 1/pi factors, so a uniformly lit plane gives B = E R_tot (samples reach the radius
//! holding `energy` of each channel's reflectance, K(R); the rest is taken at their mean).
//! Transmission through thin parts (ears): per mesh vertex, the thickness along -n and the
//! back surface's irradiance give E_b (R_tot - F(t)) per channel (a locally flat slab lit
//! from behind; [`cpu::transmission`]), interpolated per texel into its own image.
//! Skinned meshes ([`SssKernel::new_posed`], `vkshade sss --anim`): what the UV layout fixes
//! is built once ([`posed`]); each frame the GPU computes the vertex frames, the texel
//! geometry, the walk's records and a refit of the rest pose's BVH from the posed buffers of
//! `kernels::pose` (passes `sss pose *`, `sss bvh *`, the texel geometry inside `sss
//! irradiance`); the contact entries are the rest
//! pose's. [`SssKernel::update_geometry`] uploads a CPU-rasterised pose to a kernel made
//! with [`SssKernel::new`] (one made on posed buffers refuses it).

pub mod contact;
pub mod cpu;
pub mod gpu;
pub mod pack;
pub mod posed;
pub use crate::geom::profile;
pub mod regions;
pub mod sampler;
pub mod walk;

pub use crate::scene::texspace::TexGeometry;
pub use cpu::{Light, SamplerParams};
pub use gpu::{PosedBuffers, PosedSource, SssKernel, SssOutput};
pub use profile::{Material, Profile, ProfileKind};
pub use regions::Regions;

/// The head of BCN_Epileptic (assimp-testmodels, converted to glTF), in metres.
pub const DEFAULT_MESH: &str = "data/bcn_epileptic.glb";
/// Millimetres per unit of [`DEFAULT_MESH`] (it is modelled in metres).
pub const DEFAULT_MESH_MM_PER_UNIT: f64 = 1000.0;

/// The scale to use when none is given: [`DEFAULT_MESH_MM_PER_UNIT`] for the built-in mesh,
/// 1 (millimetres) for any other.
pub fn default_mm_per_unit(mesh: &std::path::Path) -> f64 {
    if mesh == std::path::Path::new(DEFAULT_MESH) {
        DEFAULT_MESH_MM_PER_UNIT
    } else {
        1.0
    }
}
pub const DEFAULT_PART: &str = "Head";

/// Loads `mesh` (the glTF part `part` alone when given).
pub fn load_mesh(
    mesh: &std::path::Path,
    part: Option<&str>,
) -> crate::error::Result<crate::scene::Mesh> {
    Ok(load_character(mesh, part)?.mesh)
}

/// Loads `mesh` with its rig and animations (the glTF part `part` alone when given).
pub fn load_character(
    mesh: &std::path::Path,
    part: Option<&str>,
) -> crate::error::Result<crate::scene::Character> {
    let ext = mesh
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    if let Some(name) = part
        && ext != "glb"
        && ext != "gltf"
    {
        let kind = match ext.as_str() {
            "" => "a file without an extension".to_string(),
            e => format!("an {} file", e.to_uppercase()),
        };
        return Err(crate::error::Error::input(
            mesh,
            format!(
                "is {kind}, which has no parts: --part '{name}' selects a node or mesh of a \
                 glTF file (.glb/.gltf); leave --part out to use the whole mesh"
            ),
        ));
    }
    match part {
        #[cfg(feature = "gltf")]
        Some(name) => crate::scene::gltf_load::load_named(mesh, name),
        #[cfg(not(feature = "gltf"))]
        Some(_) => Err(crate::error::Error::feature(
            format!("selecting a part of {}", mesh.display()),
            "gltf",
        )),
        None => crate::scene::load(mesh),
    }
}
