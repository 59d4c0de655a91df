//! CPU-side inputs: meshes, skeletons and animations, sphere trees, environment maps, and
//! what is derived from them alone: a mesh rasterised into its UV layout ([`texspace`]), the
//! G-buffer of an object seen by a camera under lights ([`gbuffer`]).
//! Loaders validate their input and name the file in every error.

pub mod envmap;
pub mod gbuffer;
#[cfg(feature = "gltf")]
pub mod gltf_access;
#[cfg(feature = "gltf")]
pub mod gltf_load;
pub mod material;
pub mod mesh;
pub mod ply_write;
pub mod rig;
pub mod spheretree;
pub mod static_load;
pub mod texspace;

pub use envmap::EnvMap;
pub use mesh::{Mesh, MeshData, MeshReport, SkinWeights};
pub use rig::{Animation, Rig};
pub use spheretree::SphereTree;

use crate::error::{Error, Result};
use std::path::Path;

/// A mesh with its rig and animations. Static meshes get a rig of one identity joint and
/// every vertex weighted 1 to it, so every mesh goes through the same skinning path.
#[derive(Clone, Debug)]
pub struct Character {
    pub mesh: Mesh,
    pub rig: Rig,
    pub animations: Vec<Animation>,
    /// Whether the file had a skin (false: static mesh on the identity rig).
    pub skinned: bool,
}

impl Character {
    /// A static mesh on the identity rig.
    pub fn from_static(mut mesh: Mesh) -> Character {
        let n = mesh.positions.len();
        mesh.skin = Some(SkinWeights {
            joints: vec![[0; 4]; n],
            weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
        });
        Character {
            mesh,
            rig: Rig::identity(),
            animations: Vec::new(),
            skinned: false,
        }
    }

    /// The animation to play: the one called `name` (as [`Character::animation`]), or with no
    /// name the first animation that moves (`None` for a static mesh: play the rest pose).
    pub fn pick_animation(&self, name: Option<&str>) -> Result<Option<&Animation>> {
        match name {
            Some(n) => self.animation(n).map(Some),
            None => Ok(self.animations.iter().find(|a| a.duration > 0.0)),
        }
    }

    /// The animation called `name` (case-insensitive; a unique substring is enough).
    pub fn animation(&self, name: &str) -> Result<&Animation> {
        let lower = name.to_lowercase();
        if let Some(a) = self
            .animations
            .iter()
            .find(|a| a.name.to_lowercase() == lower)
        {
            return Ok(a);
        }
        let matches: Vec<&Animation> = self
            .animations
            .iter()
            .filter(|a| a.name.to_lowercase().contains(&lower))
            .collect();
        match matches.as_slice() {
            [one] => Ok(one),
            _ => Err(Error::InvalidArgument(format!(
                "no single animation matches '{name}'; the mesh has: {}",
                if self.animations.is_empty() {
                    "none".to_string()
                } else {
                    self.animations
                        .iter()
                        .map(|a| a.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ))),
        }
    }
}

/// Loads a character (.glb/.gltf) or a static mesh (.obj, .ply, .off), by extension.
pub fn load(path: &Path) -> Result<Character> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    if !path.exists() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "file not found"),
        ));
    }
    let data = match ext.as_str() {
        #[cfg(feature = "gltf")]
        "glb" | "gltf" => {
            let mut c = gltf_load::load(path)?;
            if !c.skinned {
                c = Character::from_static(c.mesh);
            }
            return Ok(c);
        }
        #[cfg(not(feature = "gltf"))]
        "glb" | "gltf" => {
            return Err(Error::feature(
                format!("loading the glTF file {}", path.display()),
                "gltf",
            ));
        }
        "obj" => static_load::load_obj(path)?,
        "ply" => static_load::load_ply(path)?,
        "off" => static_load::load_off(path)?,
        _ => {
            return Err(Error::input(
                path,
                format!("unknown mesh format '.{ext}' (supported: .glb .gltf .obj .ply .off)"),
            ));
        }
    };
    Ok(Character::from_static(Mesh::from_data(data, path)?))
}

/// Loads a mesh from memory, as [`load`] does from a file: the format is chosen by the
/// extension of `name`, which also names the source in every error. glTF buffers must be
/// embedded (GLB or data URIs). The path-free entry point for fuzzing every mesh format.
pub fn load_bytes(name: &Path, bytes: &[u8]) -> Result<Character> {
    let ext = name
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let data = match ext.as_str() {
        #[cfg(feature = "gltf")]
        "glb" | "gltf" => {
            let mut c = gltf_load::load_bytes(name, bytes)?;
            if !c.skinned {
                c = Character::from_static(c.mesh);
            }
            return Ok(c);
        }
        #[cfg(not(feature = "gltf"))]
        "glb" | "gltf" => {
            return Err(Error::feature(
                format!("loading the glTF file {}", name.display()),
                "gltf",
            ));
        }
        "obj" => static_load::parse_obj(name, bytes)?,
        "ply" => static_load::parse_ply(name, bytes)?,
        "off" => static_load::parse_off(name, bytes)?,
        _ => {
            return Err(Error::input(
                name,
                format!("unknown mesh format '.{ext}' (supported: .glb .gltf .obj .ply .off)"),
            ));
        }
    };
    Ok(Character::from_static(Mesh::from_data(data, name)?))
}
