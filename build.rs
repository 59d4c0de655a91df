//! 1. Links the static SPIRV-Tools archive (`gpu::shader` validates every module in-process
//!    with it; Debian package spirv-tools) and, with the `glsl` feature only, the glslang and
//!    SPIRV-Tools-opt archives that Debian's `libshaderc_combined.a` leaves undefined (order
//!    matters for static linking; see README "Building notes"). The folder holding them:
//!    `VKSHADE_SHADERC_LIB_DIR` if set; else pkg-config's libdir for SPIRV-Tools / glslang /
//!    shaderc; else the first of the target's multiarch folder (`/usr/lib/<arch>-linux-gnu`),
//!    /usr/lib64, /usr/lib, /usr/local/lib holding `libSPIRV-Tools.a` (and, with `glsl`,
//!    `libglslang.a`). None: the build fails saying what to install. Without `glsl` neither
//!    shaderc nor glslang is needed: the library uses only the embedded SPIR-V.
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

/// Archives that must be present in the chosen folder (the rest come with them).
fn required(glsl: bool) -> &'static [&'static str] {
    if glsl {
        &["libglslang.a", "libSPIRV-Tools.a"]
    } else {
        &["libSPIRV-Tools.a"]
    }
}

/// The static archives to link, in link order (each resolves only what those before it need).
fn archives(glsl: bool) -> &'static [&'static str] {
    if glsl {
        &[
            "SPIRV",
            "glslang",
            "MachineIndependent",
            "GenericCodeGen",
            "OSDependent",
            "OGLCompiler",
            "glslang-default-resource-limits",
            "SPIRV-Tools-opt",
            "SPIRV-Tools",
        ]
    } else {
        &["SPIRV-Tools"]
    }
}

fn has_archives(dir: &Path, required: &[&str]) -> bool {
    required.iter().all(|a| dir.join(a).is_file())
}

/// `pkg-config --variable=libdir PKG`, if pkg-config is installed and knows PKG.
fn pkg_config_libdir(pkg: &str) -> Option<PathBuf> {
    let out = std::process::Command::new("pkg-config")
        .args(["--variable=libdir", pkg])
        .output()
        .ok()?;
    let dir = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (out.status.success() && !dir.is_empty()).then(|| PathBuf::from(dir))
}

/// The Debian multiarch triplet of the target (`x86_64-linux-gnu`, `aarch64-linux-gnu`, ...).
fn multiarch() -> Option<String> {
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").ok()?;
    let os = std::env::var("CARGO_CFG_TARGET_OS").ok()?;
    if os != "linux" {
        return None;
    }
    let env = std::env::var("CARGO_CFG_TARGET_ENV").unwrap_or_default();
    let abi = std::env::var("TARGET").unwrap_or_default();
    let arch = match arch.as_str() {
        "x86" => "i386".to_string(),
        "arm" if abi.ends_with("hf") => return Some("arm-linux-gnueabihf".into()),
        "arm" => return Some("arm-linux-gnueabi".into()),
        "powerpc64" if abi.starts_with("powerpc64le") => "powerpc64le".to_string(),
        other => other.to_string(),
    };
    Some(format!(
        "{arch}-linux-{}",
        if env.is_empty() { "gnu" } else { &env }
    ))
}

/// Finds the folder holding the `required` static archives, or says where it looked.
fn find_lib_dir(required: &[&str]) -> Result<PathBuf, String> {
    if let Ok(dir) = std::env::var("VKSHADE_SHADERC_LIB_DIR") {
        let dir = PathBuf::from(dir);
        return if has_archives(&dir, required) {
            Ok(dir)
        } else {
            Err(format!(
                "VKSHADE_SHADERC_LIB_DIR={} does not hold {}",
                dir.display(),
                required.join(" and ")
            ))
        };
    }
    let mut tried: Vec<PathBuf> = Vec::new();
    let pkg = ["SPIRV-Tools", "glslang", "shaderc"]
        .iter()
        .filter_map(|p| pkg_config_libdir(p));
    let multi = multiarch().map(|m| PathBuf::from(format!("/usr/lib/{m}")));
    let fixed = ["/usr/lib64", "/usr/lib", "/usr/local/lib"].map(PathBuf::from);
    for dir in pkg.chain(multi).chain(fixed) {
        if tried.contains(&dir) {
            continue;
        }
        if has_archives(&dir, required) {
            return Ok(dir);
        }
        tried.push(dir);
    }
    Err(format!(
        "none of {} holds {}",
        tried
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
        required.join(" and ")
    ))
}

/// The C++ runtime the static archives need, if the target names one.
fn cxx_runtime() -> Option<&'static str> {
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let env = std::env::var("CARGO_CFG_TARGET_ENV").unwrap_or_default();
    match (os.as_str(), env.as_str()) {
        (_, "msvc") => None,
        ("macos" | "ios" | "freebsd" | "openbsd", _) => Some("c++"),
        _ => Some("stdc++"),
    }
}

/// Links the static SPIRV-Tools (and with `glsl` the glslang) archives, or exits explaining
/// what to install.
fn link_archives(glsl: bool) {
    println!("cargo:rerun-if-env-changed=VKSHADE_SHADERC_LIB_DIR");
    println!("cargo:rerun-if-env-changed=PKG_CONFIG_PATH");
    let dir = match find_lib_dir(required(glsl)) {
        Ok(dir) => dir,
        Err(why) if glsl => {
            eprintln!(
                "vkshade needs the static glslang and SPIRV-Tools libraries ({why}).\n\
                 On Debian/Ubuntu: apt-get install libshaderc-dev glslang-dev spirv-tools \
                 (libglslang.a is in glslang-dev, libSPIRV-Tools.a in spirv-tools, \
                 libshaderc_combined.a in libshaderc-dev; tools/setup.sh installs them).\n\
                 Elsewhere: set VKSHADE_SHADERC_LIB_DIR to the folder holding them.\n\
                 A renderer using only the embedded SPIR-V can leave out the `glsl` feature \
                 (`default-features = false`): then only SPIRV-Tools is needed."
            );
            std::process::exit(1);
        }
        Err(why) => {
            eprintln!(
                "vkshade needs the static SPIRV-Tools library, which validates every SPIR-V \
                 module ({why}).\n\
                 On Debian/Ubuntu: apt-get install spirv-tools (libSPIRV-Tools.a).\n\
                 Elsewhere: set VKSHADE_SHADERC_LIB_DIR to the folder holding it."
            );
            std::process::exit(1);
        }
    };
    println!("cargo:rustc-link-search=native={}", dir.display());
    for lib in archives(glsl) {
        println!("cargo:rustc-link-lib=static={lib}");
    }
    if let Some(cxx) = cxx_runtime() {
        println!("cargo:rustc-link-lib={cxx}");
    }
}

/// Writes `embedded_spv.rs`: every committed module under spv/, included as bytes.
fn embed_spirv() {
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

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    link_archives(std::env::var_os("CARGO_FEATURE_GLSL").is_some());
    embed_spirv();
}
