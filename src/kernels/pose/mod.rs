//! The character's posed geometry, once per frame on the GPU: one skinning pass writes posed
//! positions, normals and tangent frames (from the UVs) into device buffers that every other
//! kernel reads through its own declared accesses (AO, SSS, the G-buffer rasteriser), so no
//! kernel skins again and no posed vertex crosses to the host inside a frame.
//!
//! - [`pack`]: the rest pose and tangent frames in the GPU's layout ([`Prepared`]), checked.
//! - [`gpu`]: the kernel ([`PoseKernel`]: passes `pose joints`, `pose skin`).
//! - [`cpu`]: the CPU twin (the same f32 operations).
//!
//! Conventions: positions in model units (w = 1), unit normals (w = 0), unit tangents along
//! +u orthogonal to the normal with the handedness in w (+v runs along `w * n x t`).

#![warn(missing_docs)]

pub mod cpu;
pub mod gpu;
pub mod pack;

pub use gpu::{PASS_JOINTS, PASS_SKIN, PoseKernel, PoseReadback};
pub use pack::{Prepared, tangent_frames};

/// Checks one frame's skinning matrices: one per joint of the rig, finite.
pub fn check_matrices(matrices: &[glam::Mat4], joint_count: usize) -> crate::error::Result<()> {
    use crate::error::Error;
    if matrices.len() != joint_count {
        return Err(Error::InvalidArgument(format!(
            "{} joint matrices for a rig of {joint_count} joints",
            matrices.len()
        )));
    }
    if let Some(i) = matrices.iter().position(|m| !m.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "joint matrix {i} is not finite"
        )));
    }
    Ok(())
}
