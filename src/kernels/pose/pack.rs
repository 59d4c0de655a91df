//! The rest pose in the GPU's layout ([`Prepared`]), with the tangent frames derived from the
//! UVs, checked on the CPU (no Vulkan here).

use crate::error::{Error, Result};
use crate::scene::Mesh;
use glam::{Vec3, Vec4};

/// The rest pose and skin weights as the skinning pass reads them (also the CPU twin's input).
#[derive(Clone, Debug)]
pub struct Prepared {
    /// xyz in model units, w = 1.
    pub positions: Vec<[f32; 4]>,
    /// Unit normal, w = 0.
    pub normals: Vec<[f32; 4]>,
    /// Unit tangent along +u of the UVs, orthogonal to the normal; w = handedness (+1 or -1):
    /// the direction of +v is `w * normal x tangent`. Without UVs: any perpendicular, w = 1.
    pub tangents: Vec<[f32; 4]>,
    /// Four u16 joint indices packed in two u32.
    pub vertex_joints: Vec<[u32; 2]>,
    /// The four joints' weights (summing to 1, as the mesh loaders normalise them).
    pub vertex_weights: Vec<[f32; 4]>,
    /// Joints of the rig (the number of matrices a frame takes).
    pub joint_count: usize,
}

/// A unit vector perpendicular to the unit vector `n` (the shader's `perpendicular`); +x
/// for a zero `n` (a degenerate vertex, whose frame nothing can use).
pub fn perpendicular(n: Vec3) -> Vec3 {
    let a = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let p = n.cross(a);
    if p.length_squared() > 0.0 {
        p.normalize()
    } else {
        Vec3::X
    }
}

/// Per-vertex tangent frames from the UVs: each triangle's dP/du and dP/dv, summed over the
/// triangles of a vertex weighted by their surface area, then made orthogonal to the vertex
/// normal; the handedness is the sign of (n x t) . dP/dv. Triangles whose UV area vanishes
/// contribute nothing; a vertex that gets nothing takes a perpendicular of its normal.
pub fn tangent_frames(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: Option<&[glam::Vec2]>,
    triangles: &[[u32; 3]],
) -> Vec<Vec4> {
    let mut t_sum = vec![Vec3::ZERO; positions.len()];
    let mut b_sum = vec![Vec3::ZERO; positions.len()];
    if let Some(uvs) = uvs {
        for tri in triangles {
            let [a, b, c] = tri.map(|i| i as usize);
            let (e1, e2) = (positions[b] - positions[a], positions[c] - positions[a]);
            let (d1, d2) = (uvs[b] - uvs[a], uvs[c] - uvs[a]);
            let r = d1.x * d2.y - d2.x * d1.y;
            let area = 0.5 * e1.cross(e2).length();
            if r.abs() < 1e-20 || area.is_nan() || area <= 0.0 {
                continue;
            }
            let t = (e1 * d2.y - e2 * d1.y) / r;
            let bt = (e2 * d1.x - e1 * d2.x) / r;
            let (t, bt) = (t.normalize_or_zero() * area, bt.normalize_or_zero() * area);
            for v in [a, b, c] {
                t_sum[v] += t;
                b_sum[v] += bt;
            }
        }
    }
    normals
        .iter()
        .enumerate()
        .map(|(v, &n)| {
            let t = t_sum[v] - n * n.dot(t_sum[v]);
            let t = if t.length() > 1e-12 * (1.0 + t_sum[v].length()) {
                t.normalize()
            } else {
                perpendicular(n)
            };
            let w = if n.cross(t).dot(b_sum[v]) < 0.0 {
                -1.0
            } else {
                1.0
            };
            t.extend(w)
        })
        .collect()
}

/// Four u16 joint indices packed in two u32, as the skinning shaders read them (AO's spheres
/// use the same layout).
pub fn pack_joints(j: [u16; 4]) -> [u32; 2] {
    [
        j[0] as u32 | (j[1] as u32) << 16,
        j[2] as u32 | (j[3] as u32) << 16,
    ]
}

impl Prepared {
    /// Lays out `mesh` (with its skin weights) for the skinning pass, for a rig of
    /// `joint_count` joints, and checks it.
    pub fn new(mesh: &Mesh, joint_count: usize) -> Result<Prepared> {
        let skin = mesh.skin.as_ref().ok_or_else(|| {
            Error::InvalidArgument(format!("mesh '{}' has no skin weights", mesh.name))
        })?;
        let tangents = tangent_frames(
            &mesh.positions,
            &mesh.normals,
            mesh.uvs.as_deref(),
            &mesh.triangles,
        );
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
            tangents: tangents.iter().map(|t| t.to_array()).collect(),
            vertex_joints: skin.joints.iter().map(|&j| pack_joints(j)).collect(),
            vertex_weights: skin.weights.clone(),
            joint_count,
        };
        prep.check()
            .map_err(|e| Error::InvalidArgument(format!("mesh '{}': {e}", mesh.name)))?;
        Ok(prep)
    }

    /// Vertices posed per frame.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Checks that every array has one entry per vertex, every joint index is inside the
    /// rig, and every value is finite (the fields are public; the GPU must never read out of
    /// bounds or write NaN).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("posed geometry: {what}")));
        let nv = self.positions.len();
        if nv == 0 || nv > u32::MAX as usize / 2 {
            return bad(format!("{nv} vertices"));
        }
        for (name, len) in [
            ("normals", self.normals.len()),
            ("tangents", self.tangents.len()),
            ("vertex joints", self.vertex_joints.len()),
            ("vertex weights", self.vertex_weights.len()),
        ] {
            if len != nv {
                return bad(format!("{len} {name} for {nv} vertices"));
            }
        }
        if self.joint_count == 0 || self.joint_count > u16::MAX as usize + 1 {
            return bad(format!("a rig of {} joints", self.joint_count));
        }
        let unpack = |p: &[u32; 2]| [p[0] & 0xffff, p[0] >> 16, p[1] & 0xffff, p[1] >> 16];
        if let Some(v) = self
            .vertex_joints
            .iter()
            .position(|j| unpack(j).iter().any(|&j| j as usize >= self.joint_count))
        {
            return bad(format!(
                "vertex {v} names a joint beyond the rig's {} joints",
                self.joint_count
            ));
        }
        let finite = |v: &[[f32; 4]]| v.iter().position(|x| !x.iter().all(|c| c.is_finite()));
        for (name, values) in [
            ("position", &self.positions),
            ("normal", &self.normals),
            ("tangent", &self.tangents),
            ("skin weight", &self.vertex_weights),
        ] {
            if let Some(v) = finite(values) {
                return bad(format!("vertex {v} has a non-finite {name}"));
            }
        }
        Ok(())
    }
}
