//! The CPU twin of the skinning pass: the same linear blend skinning, renormalisation and
//! Gram-Schmidt in f32, in the shader's order.

use super::Prepared;
use super::pack::perpendicular;
use crate::error::Result;
use crate::scene::rig::blend_matrix;
use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;

/// Posed vertices.
#[derive(Clone, Debug)]
pub struct Posed {
    /// Model units.
    pub positions: Vec<Vec3>,
    /// Unit normals.
    pub normals: Vec<Vec3>,
    /// Unit tangents (+u) orthogonal to the normals; w = handedness.
    pub tangents: Vec<Vec4>,
}

fn unpack(p: [u32; 2]) -> [u16; 4] {
    [
        (p[0] & 0xffff) as u16,
        (p[0] >> 16) as u16,
        (p[1] & 0xffff) as u16,
        (p[1] >> 16) as u16,
    ]
}

/// Poses `prep` with the frame's skinning matrices (one per joint, checked).
pub fn pose(prep: &Prepared, matrices: &[Mat4]) -> Result<Posed> {
    super::check_matrices(matrices, prep.joint_count)?;
    prep.check()?;
    let frames: Vec<(Vec3, Vec3, Vec4)> = (0..prep.vertex_count())
        .into_par_iter()
        .map(|i| {
            let m = blend_matrix(
                matrices,
                unpack(prep.vertex_joints[i]),
                prep.vertex_weights[i],
            );
            let p = m.transform_point3(Vec4::from_array(prep.positions[i]).truncate());
            let rest_n = Vec4::from_array(prep.normals[i]).truncate();
            let n = m.transform_vector3(rest_n);
            let len = n.length();
            let n = if len > 0.0 { n / len } else { rest_n };
            let rest_t = Vec4::from_array(prep.tangents[i]);
            let t = m.transform_vector3(rest_t.truncate());
            let t = t - n * n.dot(t);
            let tl = t.length();
            let t = if tl > 1e-20 { t / tl } else { perpendicular(n) };
            (p, n, t.extend(rest_t.w))
        })
        .collect();
    Ok(Posed {
        positions: frames.iter().map(|f| f.0).collect(),
        normals: frames.iter().map(|f| f.1).collect(),
        tangents: frames.iter().map(|f| f.2).collect(),
    })
}
