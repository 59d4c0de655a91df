//! The fuzz targets' bodies, one function per input format. `fuzz_targets/*.rs` hand
//! libFuzzer's input to them; the main crate's `tests/fuzz_corpus.rs` includes this file and
//! replays the committed seeds and regression inputs through the same functions on stable
//! Rust, so every input that ever crashed stays a test.
//!
//! The loaders read paths, so each input is written to a scratch file (on tmpfs where there
//! is one), named per process and thread, and the loader reads it back.

use std::path::{Path, PathBuf};
use vkshade::io::transfer_cache::VisibilityFile;
use vkshade::kernels::btf::{cloth::SynthConfig, dirs, load, synth::Btf};
use vkshade::kernels::srbf::{cpca::Cpca, transfer::Transfer};
use vkshade::scene::static_load;
use vkshade::scene::{envmap::EnvMap, gltf_load, mesh::Mesh, rig, spheretree::SphereTree};

/// A scratch directory of this process and thread, made on first use.
pub fn scratch() -> PathBuf {
    thread_local! {
        static DIR: PathBuf = {
            let base = if Path::new("/dev/shm").is_dir() {
                PathBuf::from("/dev/shm")
            } else {
                std::env::temp_dir()
            };
            let thread = format!("{:?}", std::thread::current().id());
            let thread: String = thread.chars().filter(char::is_ascii_digit).collect();
            let dir = base.join(format!("vkshade-fuzz-{}-{thread}", std::process::id()));
            std::fs::create_dir_all(&dir).expect("scratch directory");
            dir
        };
    }
    DIR.with(Clone::clone)
}

/// Removes this thread's scratch directory.
pub fn clean_scratch() {
    let _ = std::fs::remove_dir_all(scratch());
}

/// Writes `bytes` to the scratch file `name` and returns its path.
pub fn file(name: &str, bytes: &[u8]) -> PathBuf {
    let path = scratch().join(name);
    std::fs::write(&path, bytes).expect("scratch file");
    path
}

/// FNV-1a 64, the transfer caches' trailing checksum.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ *b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// What a target's input did: loaded, or refused with this message.
pub type Outcome = Result<(), String>;

fn done<T>(r: vkshade::error::Result<T>) -> Outcome {
    r.map(|_| ()).map_err(|e| e.to_string())
}

/// glTF 2.0, binary or JSON (the crate tells them apart by the magic): the character, every
/// animation sampled and blended into skinning matrices, the materials, two named parts.
pub fn gltf(data: &[u8]) -> Outcome {
    let path = file("in.glb", data);
    let c = gltf_load::load(&path).map_err(|e| e.to_string())?;
    let mut anims: Vec<Option<&rig::Animation>> = vec![None];
    anims.extend(c.animations.iter().map(Some));
    for a in anims {
        for t in [0.0f32, 0.37, 1e3] {
            let m = c.rig.skinning_matrices(a, t);
            if let Some(skin) = &c.mesh.skin {
                for (j, w) in skin.joints.iter().zip(&skin.weights).take(64) {
                    let _ = rig::blend_matrix(&m, *j, *w);
                }
            }
        }
    }
    let _ = gltf_load::load_materials(&path, &["Head"]);
    let _ = gltf_load::load_parts(&path, &["Head", "Torso"]);
    Ok(())
}

fn mesh(path: &Path, d: vkshade::error::Result<vkshade::scene::mesh::MeshData>) -> Outcome {
    let m = Mesh::from_data(d.map_err(|e| e.to_string())?, path).map_err(|e| e.to_string())?;
    let _ = m.bounds();
    let _ = vkshade::scene::mesh::area_weighted_normals(&m.positions, &m.triangles);
    Ok(())
}

/// Wavefront OBJ, then the checks every mesh passes (`Mesh::from_data`).
pub fn obj(data: &[u8]) -> Outcome {
    let path = file("in.obj", data);
    mesh(&path, static_load::load_obj(&path))
}

/// OFF, then `Mesh::from_data`.
pub fn off(data: &[u8]) -> Outcome {
    let path = file("in.off", data);
    mesh(&path, static_load::load_off(&path))
}

/// PLY (ascii, binary little or big endian, extra per-vertex properties), then
/// `Mesh::from_data`.
pub fn ply(data: &[u8]) -> Outcome {
    let path = file("in.ply", data);
    mesh(
        &path,
        static_load::load_ply_with_properties(&path).map(|(d, _)| d),
    )
}

/// `.sph` sphere trees.
pub fn sph(data: &[u8]) -> Outcome {
    done(SphereTree::read_sph(&file("in.sph", data)))
}

/// Environment maps through `EnvMap::load`: OpenEXR (first byte odd; read by
/// `io::exr::read_rgba`) or Radiance RGBE `.hdr` (even).
pub fn envmap(data: &[u8]) -> Outcome {
    let Some((&sel, body)) = data.split_first() else {
        return Err("empty".into());
    };
    if sel & 1 == 1 {
        // `EnvMap::load` reads an EXR through `io::exr::read_rgba`, so this covers the raw
        // reader too; calling it separately as well halved the target's speed.
        done(EnvMap::load(&file("in.exr", body)))
    } else {
        done(EnvMap::load(&file("in.hdr", body)))
    }
}

/// The SRBF transfer caches (and the visibility cached beside them). The input is the file
/// without its FNV-1a checksum, which is appended here, so that mutations reach the header
/// and value checks behind it (a forged file with a valid checksum is what those checks are
/// for).
pub fn transfer(data: &[u8]) -> Outcome {
    let mut bytes = data.to_vec();
    bytes.extend_from_slice(&fnv1a(data).to_le_bytes());
    if data.starts_with(b"VKSGCPC") {
        done(Cpca::load(&file("transfer.cpca", &bytes)))
    } else if data.starts_with(b"VKSGVIS") {
        done(VisibilityFile::load(&file("visibility.bin", &bytes)))
    } else {
        done(Transfer::load(&file("transfer.bin", &bytes)))
    }
}

/// `btf.json`'s synthesis description, parsed and checked as `app::btf::read_meta` does.
pub fn btf_json(data: &[u8]) -> Outcome {
    #[derive(serde::Deserialize)]
    struct Meta {
        synth: SynthConfig,
    }
    let m: Meta = serde_json::from_slice(data).map_err(|e| e.to_string())?;
    done(m.synth.check())
}

/// A directory of 81 x 81 one-texel PNGs, made once per thread.
fn btf_base() -> PathBuf {
    let dir = scratch().join("btf");
    if !dir.join("complete").exists() {
        std::fs::create_dir_all(&dir).expect("btf scratch directory");
        let d = dirs::directions();
        for &l in &d {
            for &v in &d {
                let p = dir.join(Btf::file_name(l, v, "png"));
                vkshade::render::write_png(&p, 1, 1, &[128, 100, 90]).expect("base BTF image");
            }
        }
        std::fs::write(dir.join("complete"), b"").expect("marker");
    }
    dir
}

/// BTF directories (`load_dir`): each input replaces one image of a valid one-texel BTF
/// (bytes 0-1: which (light, view) pair; byte 2: png, exr or jpg; the rest: the image).
/// Slow (6561 files per input): [`btf_image`] fuzzes the image decoding alone.
/// Inputs starting "btf_" are file names for `parse_name` instead.
pub fn btf_dir(data: &[u8]) -> Outcome {
    if data.starts_with(b"btf_") {
        let s = String::from_utf8_lossy(data);
        return load::parse_name(&s)
            .map(|_| ())
            .ok_or_else(|| "no angles".into());
    }
    let [a, b, e, image @ ..] = data else {
        return Err("too short".into());
    };
    let ext = ["png", "exr", "jpg"][*e as usize % 3];
    let dir = btf_base();
    let d = dirs::directions();
    let slot = u16::from_le_bytes([*a, *b]) as usize % (d.len() * d.len());
    let (l, v) = (d[slot % d.len()], d[slot / d.len()]);
    let original = dir.join(Btf::file_name(l, v, "png"));
    let replaced = dir.join(Btf::file_name(l, v, ext));
    let saved = std::fs::read(&original).expect("base image");
    std::fs::remove_file(&original).expect("base image");
    std::fs::write(&replaced, image).expect("scratch image");
    let result = done(load::load_dir(&dir));
    std::fs::remove_file(&replaced).expect("scratch image");
    std::fs::write(&original, saved).expect("base image");
    result
}

/// One BTF image, as `load_dir` reads each (`load::read_image`): byte 0 picks png, exr or
/// jpg, the rest is the file.
pub fn btf_image(data: &[u8]) -> Outcome {
    let Some((&e, image)) = data.split_first() else {
        return Err("empty".into());
    };
    let ext = ["png", "exr", "jpg"][e as usize % 3];
    done(load::read_image(&file(&format!("image.{ext}"), image)))
}

/// A target's body.
pub type Target = fn(&[u8]) -> Outcome;

/// Every target by name, for the corpus replay.
pub const TARGETS: [(&str, Target); 10] = [
    ("gltf", gltf),
    ("obj", obj),
    ("off", off),
    ("ply", ply),
    ("sph", sph),
    ("envmap", envmap),
    ("transfer", transfer),
    ("btf_json", btf_json),
    ("btf_dir", btf_dir),
    ("btf_image", btf_image),
];
