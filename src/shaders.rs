//! GLSL sources (glsl/) compiled by shaderc into committed SPIR-V (spv/), and the modules
//! embedded in the library.
//!
//! `vkshade shaders build` regenerates spv/; `vkshade shaders check` (and the test suite)
//! fails when any module is missing, stale or orphaned.
//!
//! Compiling GLSL needs the cargo feature `glsl` (on by default, and part of `cli`). Without
//! it the library uses only the embedded modules and links neither shaderc nor glslang;
//! [`compile_glsl`], [`compile_source`] and [`build_all`] return [`Error::FeatureDisabled`].

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The shaderc crate vkshade compiles with, for [`compile_options`] and its types.
#[cfg(feature = "glsl")]
pub use shaderc;

/// A GLSL include generated from Rust: (path under glsl/, generator of its text). The kernels
/// list theirs (`kernels::generated_includes`); [`build_all`] writes and checks them.
pub type GeneratedInclude = (&'static str, fn() -> String);

/// The source tree this crate was built from (the default root for the shader tool).
pub fn source_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

include!(concat!(env!("OUT_DIR"), "/embedded_spv.rs"));

/// The embedded SPIR-V module `name` (e.g. `"bench/fma"`).
pub fn spirv(name: &str) -> Result<&'static [u8]> {
    EMBEDDED
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, b)| *b)
        .ok_or_else(|| {
            Error::InvalidArgument(format!(
                "no SPIR-V module '{name}' was embedded at build time (spv/{name}.spv missing); \
                 run `vkshade shaders build`"
            ))
        })
}

/// The compute pipeline of the embedded module `name` (e.g. `"srbf/shade"`), its bindings
/// and push constants reflected; the pipeline carries `name` as its debug name.
pub fn pipeline(ctx: &crate::gpu::Context, name: &str) -> Result<crate::gpu::ComputePipeline> {
    crate::gpu::ComputePipeline::from_spirv(ctx, name, spirv(name)?)
}

/// As [`pipeline`], with the module's specialization constants set by name
/// ([`crate::gpu::ComputePipeline::specialized`]).
pub fn pipeline_specialized(
    ctx: &crate::gpu::Context,
    name: &str,
    constants: &[(&str, u32)],
) -> Result<crate::gpu::ComputePipeline> {
    let shader = crate::gpu::Shader::from_spirv(name, spirv(name)?)?;
    crate::gpu::ComputePipeline::specialized(ctx, &shader, constants)
}

/// As [`pipeline_specialized`], setting only the constants of `constants` that the module
/// declares: for a kernel whose modules share values that only some of them use (SSS: the
/// BVH table's `TRI_BASE`, declared by the modules that include glsl/common/bvh.glsl, and
/// the atlas's `ROW_SEGMENTS`, by the segment lists').
pub fn pipeline_declaring(
    ctx: &crate::gpu::Context,
    name: &str,
    constants: &[(&str, u32)],
) -> Result<crate::gpu::ComputePipeline> {
    let shader = crate::gpu::Shader::from_spirv(name, spirv(name)?)?;
    let declared: Vec<(&str, u32)> = constants
        .iter()
        .filter(|(c, _)| shader.spec_constants.iter().any(|s| s.name == *c))
        .copied()
        .collect();
    crate::gpu::ComputePipeline::specialized(ctx, &shader, &declared)
}

/// The cargo feature that compiling GLSL needs.
const GLSL: &str = "glsl";

/// The shaderc settings of every GLSL compile in vkshade: the spv/ build and its freshness
/// check, [`compile_glsl`], [`compile_source`], the tests. A renderer compiling its own compute
/// shaders for vkshade's pipelines can start from these too.
#[cfg(feature = "glsl")]
pub fn compile_options<'a>() -> shaderc::Result<shaderc::CompileOptions<'a>> {
    let mut o = shaderc::CompileOptions::new()?;
    // Vulkan 1.3 is what vkshade requires; SPIR-V 1.6 also drops the WorkgroupSize built-in
    // that glslang otherwise emits (deprecated; flagged by best-practices validation).
    o.set_target_env(
        shaderc::TargetEnv::Vulkan,
        shaderc::EnvVersion::Vulkan1_3 as u32,
    );
    o.set_target_spirv(shaderc::SpirvVersion::V1_6);
    o.set_source_language(shaderc::SourceLanguage::GLSL);
    // No SPIR-V optimisation: it strips the variable names that pipelines bind by, and every
    // driver optimises the module again anyway.
    o.set_optimization_level(shaderc::OptimizationLevel::Zero);
    o.set_warnings_as_errors();
    Ok(o)
}

/// [`compile_options`] resolving `#include`s under `root` (`<...>`) or beside the includer
/// (`"..."`).
#[cfg(feature = "glsl")]
fn options_with_includes<'a>(root: &Path) -> Result<shaderc::CompileOptions<'a>> {
    let mut o = compile_options().map_err(|e| Error::ShaderCompile {
        path: root.to_path_buf(),
        message: format!("shaderc options: {e}"),
    })?;
    let root = root.to_path_buf();
    o.set_include_callback(move |requested, kind, requester, _depth| {
        let base = match kind {
            shaderc::IncludeType::Standard => root.clone(),
            shaderc::IncludeType::Relative => Path::new(requester)
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| root.clone()),
        };
        let path = base.join(requested);
        let content = std::fs::read_to_string(&path)
            .map_err(|e| format!("cannot include {}: {e}", path.display()))?;
        Ok(shaderc::ResolvedInclude {
            resolved_name: path.to_string_lossy().into_owned(),
            content,
        })
    });
    Ok(o)
}

/// Compiles the compute shader `source` with `opts`; `path` names it in errors.
#[cfg(feature = "glsl")]
fn compile_compute(
    source: &str,
    path: &Path,
    opts: &shaderc::CompileOptions<'_>,
) -> Result<Vec<u8>> {
    let compiler = shaderc::Compiler::new().map_err(|e| Error::ShaderCompile {
        path: path.to_path_buf(),
        message: format!("shaderc unavailable: {e}"),
    })?;
    let artifact = compiler
        .compile_into_spirv(
            source,
            shaderc::ShaderKind::Compute,
            &path.to_string_lossy(),
            "main",
            Some(opts),
        )
        .map_err(|e| Error::ShaderCompile {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    Ok(artifact.as_binary_u8().to_vec())
}

/// Compiles one compute shader; `root` is the glsl/ directory (for `#include <...>`).
/// Without the `glsl` feature: [`Error::FeatureDisabled`].
pub fn compile_glsl(path: &Path, root: &Path) -> Result<Vec<u8>> {
    #[cfg(feature = "glsl")]
    {
        let source = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let opts = options_with_includes(root)?;
        compile_compute(&source, path, &opts)
    }
    #[cfg(not(feature = "glsl"))]
    {
        let _ = root;
        Err(Error::feature(
            format!("compiling {}", path.display()),
            GLSL,
        ))
    }
}

/// Compiles the compute shader `source` (no `#include`s); `name` names it in errors.
/// Without the `glsl` feature: [`Error::FeatureDisabled`].
pub fn compile_source(source: &str, name: &str) -> Result<Vec<u8>> {
    #[cfg(feature = "glsl")]
    {
        let opts = compile_options().map_err(|e| Error::ShaderCompile {
            path: PathBuf::from(name),
            message: format!("shaderc options: {e}"),
        })?;
        compile_compute(source, Path::new(name), &opts)
    }
    #[cfg(not(feature = "glsl"))]
    {
        let _ = source;
        Err(Error::feature(format!("compiling {name}"), GLSL))
    }
}

/// State of one module after a build or check.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ModuleState {
    Fresh,
    /// Rewritten by `build`.
    Updated,
    /// Differs from what its source compiles to (check mode).
    Stale,
    /// No .spv for this source (check mode).
    Missing,
    /// A .spv whose source no longer exists.
    Orphan,
}

/// One module of the spv/ tree.
#[derive(Clone, Debug)]
pub struct ModuleStatus {
    /// Path under glsl/ without extension, e.g. `bench/fma`.
    pub name: String,
    pub state: ModuleState,
}

fn walk(dir: &Path, ext: &str, out: &mut Vec<PathBuf>) -> Result<()> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        if path.is_dir() {
            walk(&path, ext, out)?;
        } else if path.extension().is_some_and(|e| e == ext) {
            out.push(path);
        }
    }
    Ok(())
}

/// Module names (paths under glsl/ without `.comp`) of every compute shader source.
pub fn source_modules(root: &Path) -> Result<Vec<String>> {
    let glsl = root.join("glsl");
    let mut files = Vec::new();
    walk(&glsl, "comp", &mut files)?;
    let mut names: Vec<String> = files
        .iter()
        .filter_map(|p| p.strip_prefix(&glsl).ok())
        .map(|p| p.with_extension("").to_string_lossy().replace('\\', "/"))
        .collect();
    names.sort();
    Ok(names)
}

/// Compares `path` with `wanted`; with `write`, rewrites it when it differs.
fn sync_file(path: &Path, wanted: &[u8], write: bool) -> Result<ModuleState> {
    Ok(match std::fs::read(path) {
        Ok(existing) if existing == wanted => ModuleState::Fresh,
        existing => {
            if write {
                crate::io::write_atomic(path, wanted)?;
                ModuleState::Updated
            } else if existing.is_ok() {
                ModuleState::Stale
            } else {
                ModuleState::Missing
            }
        }
    })
}

/// Compiles every glsl/**/*.comp under `root` and compares with spv/; first writes or checks
/// the `generated` includes (the caller passes `kernels::generated_includes()`). With `write`,
/// stale or missing modules are rewritten and orphans deleted; otherwise they are only
/// reported. Without the `glsl` feature: [`Error::FeatureDisabled`], before touching anything.
pub fn build_all(
    root: &Path,
    write: bool,
    generated: impl IntoIterator<Item = GeneratedInclude>,
) -> Result<Vec<ModuleStatus>> {
    if !cfg!(feature = "glsl") {
        let what = if write {
            "building spv/"
        } else {
            "checking spv/"
        };
        return Err(Error::feature(what, GLSL));
    }
    let glsl = root.join("glsl");
    let spv = root.join("spv");
    let mut statuses = Vec::new();
    for (rel, generate) in generated {
        statuses.push(ModuleStatus {
            name: format!("glsl/{rel} (generated)"),
            state: sync_file(&glsl.join(rel), generate().as_bytes(), write)?,
        });
    }
    let names = source_modules(root)?;
    for name in &names {
        let src = glsl.join(format!("{name}.comp"));
        let out = spv.join(format!("{name}.spv"));
        let compiled = compile_glsl(&src, &glsl)?;
        statuses.push(ModuleStatus {
            name: name.clone(),
            state: sync_file(&out, &compiled, write)?,
        });
    }
    if write && statuses.iter().any(|s| s.state == ModuleState::Updated) {
        // Rewrites go through renames in subfolders; mark spv/ itself as regenerated too,
        // for tools that compare its time with glsl/'s.
        let _ =
            std::fs::File::open(&spv).and_then(|f| f.set_modified(std::time::SystemTime::now()));
    }
    let mut spv_files = Vec::new();
    if spv.is_dir() {
        walk(&spv, "spv", &mut spv_files)?;
    }
    for f in spv_files {
        let name = f
            .strip_prefix(&spv)
            .map(|p| p.with_extension("").to_string_lossy().replace('\\', "/"))
            .unwrap_or_default();
        if !names.contains(&name) {
            if write {
                std::fs::remove_file(&f).map_err(|e| Error::io(&f, e))?;
            }
            statuses.push(ModuleStatus {
                name,
                state: ModuleState::Orphan,
            });
        }
    }
    Ok(statuses)
}
