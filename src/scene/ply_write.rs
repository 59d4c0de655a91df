//! Writing meshes with per-vertex scalar properties as binary PLY (atomically).

use crate::error::Result;
use glam::Vec3;
use std::path::Path;

/// Writes positions, normals and one float property per vertex named `property`.
pub fn write_ply(
    path: &Path,
    comment: &str,
    positions: &[Vec3],
    normals: &[Vec3],
    triangles: &[[u32; 3]],
    property: &str,
    values: &[f32],
) -> Result<()> {
    write_ply_properties(
        path,
        comment,
        positions,
        normals,
        triangles,
        &[(property, values)],
    )
}

/// Writes positions, normals and several float properties per vertex, in order (e.g. `r`,
/// `g`, `b`).
pub fn write_ply_properties(
    path: &Path,
    comment: &str,
    positions: &[Vec3],
    normals: &[Vec3],
    triangles: &[[u32; 3]],
    properties: &[(&str, &[f32])],
) -> Result<()> {
    let mut out = Vec::with_capacity(64 + positions.len() * 28 + triangles.len() * 13);
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {}\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         {}element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        comment.replace('\n', " "),
        positions.len(),
        properties
            .iter()
            .map(|(name, _)| format!("property float {name}\n"))
            .collect::<String>(),
        triangles.len()
    );
    out.extend_from_slice(header.as_bytes());
    for (i, p) in positions.iter().enumerate() {
        let n = normals.get(i).copied().unwrap_or(Vec3::ZERO);
        for f in [p.x, p.y, p.z, n.x, n.y, n.z] {
            out.extend_from_slice(&f.to_le_bytes());
        }
        for (_, values) in properties {
            let v = values.get(i).copied().unwrap_or(0.0);
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    crate::io::write_atomic(path, &out)
}
