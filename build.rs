//! 1. Links the static glslang and SPIRV-Tools archives that Debian's `libshaderc_combined.a`
//!    leaves undefined (order matters for static linking; see README "Building").
//! 2. Embeds every committed SPIR-V module under spv/ into the library (`shaders::EMBEDDED`).

use std::path::{Path, PathBuf};

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            walk(&path, out);
        } else if path.extension().is_some_and(|e| e == "spv") {
            out.push(path);
        }
    }
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=VKSHADE_SHADERC_LIB_DIR");
    let dir = std::env::var("VKSHADE_SHADERC_LIB_DIR")
        .unwrap_or_else(|_| "/usr/lib/x86_64-linux-gnu".to_string());
    println!("cargo:rustc-link-search=native={dir}");
    for lib in [
        "SPIRV",
        "glslang",
        "MachineIndependent",
        "GenericCodeGen",
        "OSDependent",
        "OGLCompiler",
        "glslang-default-resource-limits",
        "SPIRV-Tools-opt",
        "SPIRV-Tools",
    ] {
        println!("cargo:rustc-link-lib=static={lib}");
    }

    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("set by cargo"));
    let spv = root.join("spv");
    println!("cargo:rerun-if-changed={}", spv.display());
    let mut files = Vec::new();
    walk(&spv, &mut files);
    files.sort();
    let mut code =
        String::from("/// Every SPIR-V module under spv/, by name (path without extension).\n");
    code.push_str("pub const EMBEDDED: &[(&str, &[u8])] = &[\n");
    for f in &files {
        let name = f
            .strip_prefix(&spv)
            .expect("under spv/")
            .with_extension("")
            .to_string_lossy()
            .replace('\\', "/");
        code.push_str(&format!(
            "    ({name:?}, include_bytes!({:?})),\n",
            f.display().to_string()
        ));
    }
    code.push_str("];\n");
    let out =
        PathBuf::from(std::env::var("OUT_DIR").expect("set by cargo")).join("embedded_spv.rs");
    std::fs::write(out, code).expect("write embedded_spv.rs");
}
