//! Writing meshes with per-vertex scalar properties as binary PLY (atomically).

use crate::error::{Error, Result};
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
/// `g`, `b`). A NaN or infinite value is refused (nothing is written), naming the file,
/// the vertex and the property.
pub fn write_ply_properties(
    path: &Path,
    comment: &str,
    positions: &[Vec3],
    normals: &[Vec3],
    triangles: &[[u32; 3]],
    properties: &[(&str, &[f32])],
) -> Result<()> {
    let bad = |vertex: usize, what: &str, v: f32| {
        Error::input(
            path,
            format!("not written: vertex {vertex} has a non-finite {what} ({v})"),
        )
    };
    for (i, p) in positions.iter().enumerate() {
        let n = normals.get(i).copied().unwrap_or(Vec3::ZERO);
        let fields = [
            ("x", p.x),
            ("y", p.y),
            ("z", p.z),
            ("nx", n.x),
            ("ny", n.y),
            ("nz", n.z),
        ];
        if let Some((what, v)) = fields.into_iter().find(|(_, v)| !v.is_finite()) {
            return Err(bad(i, what, v));
        }
    }
    for (name, values) in properties {
        if let Some(i) = values
            .iter()
            .take(positions.len())
            .position(|v| !v.is_finite())
        {
            return Err(bad(i, name, values[i]));
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_values_are_refused_and_nothing_is_written() {
        let dir = std::env::temp_dir().join(format!("vkshade-ply-write-{}", std::process::id()));
        let path = dir.join("bad.ply");
        let tri = [[0u32, 1, 2]];
        let pos = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let e = write_ply(
            &path,
            "t",
            &pos,
            &[Vec3::Z; 3],
            &tri,
            "ao",
            &[0.5, f32::NAN, 1.0],
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("bad.ply") && e.contains("vertex 1") && e.contains("ao"),
            "{e}"
        );
        let far = [Vec3::ZERO, Vec3::X, Vec3::new(0.0, f32::INFINITY, 0.0)];
        let e = write_ply(&path, "t", &far, &[Vec3::Z; 3], &tri, "ao", &[0.5; 3])
            .unwrap_err()
            .to_string();
        assert!(e.contains("vertex 2") && e.contains("non-finite y"), "{e}");
        assert!(!path.exists());
        write_ply(&path, "t", &pos, &[Vec3::Z; 3], &tri, "ao", &[0.5; 3]).unwrap();
        assert!(path.is_file());
        let _ = std::fs::remove_dir_all(dir);
    }
}
