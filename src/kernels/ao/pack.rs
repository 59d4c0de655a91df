//! The mesh and sphere tree in the GPU's layout ([`Prepared`]), checked and packed on the CPU
//! (no Vulkan here): the AO kernel (`gpu.rs`) creates its buffers from it, and the CPU twin
//! reads it as it is. Also the checks of what a caller hands the kernel later (a frame's joint
//! matrices, the correction factors).

use super::cpu;
use crate::error::{Error, Result};
use crate::scene::{Mesh, SphereTree};

/// Mesh and tree in the GPU's layout (also what the CPU implementation reads).
#[derive(Clone, Debug)]
pub struct Prepared {
    pub positions: Vec<[f32; 4]>,
    pub normals: Vec<[f32; 4]>,
    /// Four u16 joint indices packed in two u32.
    pub vertex_joints: Vec<[u32; 2]>,
    pub vertex_weights: Vec<[f32; 4]>,
    /// (centre, radius) of every tree node, root first; radius < 0 = unused.
    pub spheres: Vec<[f32; 4]>,
    pub sphere_joints: Vec<[u32; 2]>,
    pub sphere_weights: Vec<[f32; 4]>,
    pub shape: cpu::TreeShape,
    pub joint_count: usize,
}

use crate::kernels::pose::pack::pack_joints as pack;

impl Prepared {
    /// Checks the mesh, tree and rig agree and lays them out for the GPU.
    pub fn new(mesh: &Mesh, tree: &SphereTree, joint_count: usize) -> Result<Prepared> {
        let skin = mesh.skin.as_ref().ok_or_else(|| {
            Error::InvalidArgument(format!("mesh '{}' has no skin weights", mesh.name))
        })?;
        if tree.spheres.len() != tree.joints.len() || tree.spheres.len() != tree.weights.len() {
            return Err(Error::InvalidArgument(
                "sphere tree lacks skin weights (call assign_skin)".into(),
            ));
        }
        tree.check_shape()?;
        let first_leaf = tree.level_range(tree.levels - 1).start as u32;
        let prep = Prepared {
            positions: mesh
                .positions
                .iter()
                .map(|p| p.extend(1.0).to_array())
                .collect(),
            normals: mesh
                .normals
                .iter()
                .map(|n| n.extend(0.0).to_array())
                .collect(),
            vertex_joints: skin.joints.iter().map(|&j| pack(j)).collect(),
            vertex_weights: skin.weights.clone(),
            spheres: tree
                .spheres
                .iter()
                .map(|s| s.center.extend(s.radius).to_array())
                .collect(),
            sphere_joints: tree.joints.iter().map(|&j| pack(j)).collect(),
            sphere_weights: tree.weights.clone(),
            shape: cpu::TreeShape {
                node_count: tree.spheres.len() as u32,
                branch: tree.branch,
                first_leaf,
            },
            joint_count,
        };
        prep.check()?;
        Ok(prep)
    }

    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Checks that every array has the length the shaders index it with (the fields are
    /// public, so a caller can break this; the GPU must never read out of bounds).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| {
            Err(Error::InvalidArgument(format!(
                "inconsistent AO input: {what}"
            )))
        };
        let nv = self.positions.len();
        if nv == 0 || nv > u32::MAX as usize / 2 {
            return bad(format!("{nv} vertices"));
        }
        for (name, len) in [
            ("normals", self.normals.len()),
            ("vertex joints", self.vertex_joints.len()),
            ("vertex weights", self.vertex_weights.len()),
        ] {
            if len != nv {
                return bad(format!("{len} {name} for {nv} vertices"));
            }
        }
        let shape = self.shape;
        let mut expected = 0u64;
        let mut width = 1u64;
        let mut first_leaf = 0u64;
        let mut levels = 0usize;
        while expected < shape.node_count as u64 {
            first_leaf = expected;
            expected += width;
            width *= shape.branch.max(1) as u64;
            levels += 1;
        }
        if levels > cpu::MAX_DEPTH + 1 {
            return bad(format!(
                "{levels} levels; the cut walks at most {} below the root",
                cpu::MAX_DEPTH
            ));
        }
        if shape.branch < 2
            || expected != shape.node_count as u64
            || first_leaf != shape.first_leaf as u64
            || shape.first_leaf == 0
        {
            return bad(format!(
                "{} nodes with branch {} and first leaf {} is not a complete tree of two or more levels",
                shape.node_count, shape.branch, shape.first_leaf
            ));
        }
        for (name, len) in [
            ("spheres", self.spheres.len()),
            ("sphere joints", self.sphere_joints.len()),
            ("sphere weights", self.sphere_weights.len()),
        ] {
            if len != shape.node_count as usize {
                return bad(format!("{len} {name} for {} nodes", shape.node_count));
            }
        }
        let unpack = |p: &[u32; 2]| [p[0] & 0xffff, p[0] >> 16, p[1] & 0xffff, p[1] >> 16];
        if self
            .vertex_joints
            .iter()
            .chain(&self.sphere_joints)
            .flat_map(unpack)
            .any(|j| j as usize >= self.joint_count)
        {
            return bad(format!(
                "a joint index beyond the rig's {} joints",
                self.joint_count
            ));
        }
        let finite = |v: &[[f32; 4]]| v.iter().flatten().all(|x| x.is_finite());
        if !finite(&self.positions) || !finite(&self.normals) || !finite(&self.spheres) {
            return bad("non-finite positions, normals or spheres".into());
        }
        Ok(())
    }
}

/// Checks one frame's joint matrices: one per joint of the rig, finite (the pose kernel's
/// check: AO skins its spheres with the same matrices).
pub use crate::kernels::pose::check_matrices;

/// Checks static correction factors: one per vertex, finite and not negative.
pub fn check_correction(factors: &[f32], vertices: usize) -> Result<()> {
    if factors.len() != vertices {
        return Err(Error::InvalidArgument(format!(
            "{} correction factors for {vertices} vertices",
            factors.len()
        )));
    }
    if let Some(i) = factors.iter().position(|f| !f.is_finite() || *f < 0.0) {
        return Err(Error::InvalidArgument(format!(
            "correction factor {i} is negative or not finite"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Mat4;

    #[test]
    fn matrices_are_one_finite_per_joint() {
        assert!(check_matrices(&[Mat4::IDENTITY; 3], 3).is_ok());
        let e = check_matrices(&[Mat4::IDENTITY; 2], 3).unwrap_err();
        assert!(
            e.to_string().contains("2 joint matrices for a rig of 3"),
            "{e}"
        );
        let mut m = [Mat4::IDENTITY; 3];
        m[1].x_axis.y = f32::NAN;
        let e = check_matrices(&m, 3).unwrap_err();
        assert!(e.to_string().contains("joint matrix 1"), "{e}");
    }

    #[test]
    fn correction_factors_are_one_finite_non_negative_per_vertex() {
        assert!(check_correction(&[1.0, 0.0, 2.5], 3).is_ok());
        let e = check_correction(&[1.0; 2], 3).unwrap_err();
        assert!(e.to_string().contains("2 correction factors for 3"), "{e}");
        let e = check_correction(&[1.0, -0.5, 1.0], 3).unwrap_err();
        assert!(e.to_string().contains("factor 1"), "{e}");
        let e = check_correction(&[f32::NAN, 1.0, 1.0], 3).unwrap_err();
        assert!(e.to_string().contains("factor 0"), "{e}");
    }
}
