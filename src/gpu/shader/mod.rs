//! SPIR-V loading: structural validation (SPIRV-Tools, linked statically), workgroup size and
//! reflection of descriptor bindings and push constants.
//!
//! Reflection is vkshade's own (`shader/reflect.rs`), read from the validated words: the
//! spirv-reflect crate (0.2.3, its newest release) builds slices from null pointers in its C
//! bindings, undefined behaviour that debug builds abort on at the first pipeline, and
//! rspirv-reflect does not report an image's dimension or sampled type, which view types and
//! the binding checks need.

use crate::error::{Error, Result};
use ash::vk;
use std::ffi::{CStr, c_char, c_int, c_void};

mod reflect;
#[cfg(test)]
mod tests;

const SPIRV_MAGIC: u32 = 0x0723_0203;

#[repr(C)]
struct SpvPosition {
    line: usize,
    column: usize,
    index: usize,
}

#[repr(C)]
struct SpvDiagnostic {
    position: SpvPosition,
    error: *mut c_char,
    is_text_source: bool,
}

// The C API of SPIRV-Tools (libspirv.h), from the static archives build.rs links.
unsafe extern "C" {
    fn spvParseTargetEnv(s: *const c_char, env: *mut c_int) -> bool;
    fn spvContextCreate(env: c_int) -> *mut c_void;
    fn spvContextDestroy(context: *mut c_void);
    fn spvValidateBinary(
        context: *const c_void,
        words: *const u32,
        num_words: usize,
        diagnostic: *mut *mut SpvDiagnostic,
    ) -> c_int;
    fn spvDiagnosticDestroy(diagnostic: *mut SpvDiagnostic);
}

/// Runs the SPIRV-Tools validator (as `spirv-val --target-env vulkan1.3`) in-process.
pub fn validate_spirv(words: &[u32]) -> std::result::Result<(), String> {
    let mut env: c_int = 0;
    // SAFETY: NUL-terminated string, valid out pointer.
    if !unsafe { spvParseTargetEnv(c"vulkan1.3".as_ptr(), &mut env) } {
        return Err("SPIRV-Tools does not know target env vulkan1.3".into());
    }
    // SAFETY: create/validate/destroy in sequence; the diagnostic is freed by its destroy call.
    unsafe {
        let context = spvContextCreate(env);
        if context.is_null() {
            return Err("spvContextCreate failed".into());
        }
        let mut diagnostic: *mut SpvDiagnostic = std::ptr::null_mut();
        let rc = spvValidateBinary(context, words.as_ptr(), words.len(), &mut diagnostic);
        let message = if diagnostic.is_null() || (*diagnostic).error.is_null() {
            format!("validator result code {rc}")
        } else {
            let d = &*diagnostic;
            format!(
                "{} (at word {})",
                CStr::from_ptr(d.error).to_string_lossy().trim(),
                d.position.index
            )
        };
        spvDiagnosticDestroy(diagnostic);
        spvContextDestroy(context);
        if rc == 0 { Ok(()) } else { Err(message) }
    }
}

/// The kind of a descriptor binding, as a pipeline expects it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DescriptorKind {
    /// A storage buffer (`buffer` block).
    StorageBuffer,
    /// A uniform buffer (`uniform` block).
    UniformBuffer,
    /// A storage image (`image2D`...).
    StorageImage,
    /// A sampled image without sampler (`texture2D`...).
    SampledImage,
    /// A sampled image with its sampler (`sampler2D`...).
    CombinedImageSampler,
    /// A sampler alone (`sampler`).
    Sampler,
}

impl DescriptorKind {
    /// The Vulkan descriptor type.
    pub fn vk(self) -> vk::DescriptorType {
        match self {
            DescriptorKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            DescriptorKind::UniformBuffer => vk::DescriptorType::UNIFORM_BUFFER,
            DescriptorKind::StorageImage => vk::DescriptorType::STORAGE_IMAGE,
            DescriptorKind::SampledImage => vk::DescriptorType::SAMPLED_IMAGE,
            DescriptorKind::CombinedImageSampler => vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            DescriptorKind::Sampler => vk::DescriptorType::SAMPLER,
        }
    }
}

/// One descriptor binding of a shader, as reflected.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BindingInfo {
    /// Descriptor set index.
    pub set: u32,
    /// Binding index within the set.
    pub binding: u32,
    /// Variable name, or the block's type name when the variable has none.
    pub name: String,
    /// What kind of descriptor the shader expects.
    pub kind: DescriptorKind,
    /// Array size (1 for a single descriptor; 0 for a runtime-sized array, which pipelines
    /// refuse).
    pub count: u32,
    /// Minimum byte size a buffer must have: the fixed part of the block, up to the end of
    /// its furthest member (a trailing runtime array counts up to its offset). 0 for images
    /// and samplers.
    pub min_size: u64,
    /// Whether the shader declares the binding `readonly` (storage buffers/images).
    pub read_only: bool,
    /// For images: the view type the shader's image type needs (`image2D` -> 2D,
    /// `texture2DArray` -> 2D_ARRAY, `samplerCube` -> CUBE, ...).
    pub view_type: Option<vk::ImageViewType>,
    /// For images: the numeric class of the image type's sampled type (`texture2D`,
    /// `image2D` -> float, `itexture3D` -> signed, `usampler2D` -> unsigned), which the
    /// bound view's format must share.
    pub sampled_type: Option<SampledType>,
    /// For a sampled image without sampler (`texture2D`): the (set, binding) of every
    /// sampler binding the shader combines it with (`sampler2D(tex, smp)`), sorted. Empty for
    /// other kinds.
    pub sampled_with: Vec<(u32, u32)>,
}

/// The numeric class of an image's texels as a shader reads them, and of a format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampledType {
    /// Floating point, and the normalized, scaled and sRGB formats read as floats.
    Float,
    /// Signed integer (`itexture`, `iimage`; `*_SINT` formats).
    SignedInt,
    /// Unsigned integer (`utexture`, `uimage`; `*_UINT` formats).
    UnsignedInt,
}

impl SampledType {
    /// The class a view of `format` reads as, from the numeric type the format's name
    /// spells (`R32_UINT` -> unsigned, `R8G8B8A8_SRGB` -> float; a depth/stencil format by
    /// its depth part); `None` for a format whose name has none (an extension's without a
    /// name in ash), which the binding checks then leave alone.
    pub fn of_format(format: vk::Format) -> Option<SampledType> {
        let name = format!("{format:?}");
        name.split('_').find_map(|part| match part {
            "UNORM" | "SNORM" | "USCALED" | "SSCALED" | "UFLOAT" | "SFLOAT" | "SRGB" => {
                Some(SampledType::Float)
            }
            "UINT" => Some(SampledType::UnsignedInt),
            "SINT" => Some(SampledType::SignedInt),
            _ => None,
        })
    }
}

/// A specialization constant of a shader (32-bit: bool, int, uint or float).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecConstant {
    /// `constant_id` in GLSL, `SpecId` in SPIR-V.
    pub id: u32,
    /// The constant's name in the shader (`id<N>` for an unnamed one, e.g. `local_size_x_id`).
    pub name: String,
    /// The default value's bits (VkBool32 0/1 for booleans).
    pub default: u32,
}

/// A compute shader: SPIR-V words plus everything needed to build its pipeline.
#[derive(Clone, Debug)]
pub struct Shader {
    /// The name given to [`Shader::from_spirv`] (used in error messages and debug names).
    pub name: String,
    /// The SPIR-V module, as 32-bit words.
    pub words: Vec<u32>,
    /// The compute entry point's name.
    pub entry_point: String,
    /// Workgroup size with the specialization constants' defaults.
    pub local_size: [u32; 3],
    /// Per axis, the SpecId of the specialization constant that sets the size, if any.
    pub local_size_spec: [Option<u32>; 3],
    /// Sorted by (set, binding).
    pub bindings: Vec<BindingInfo>,
    /// Bytes of push constants (0 when the shader has none).
    pub push_constant_size: u32,
    /// Specialization constants, sorted by id.
    pub spec_constants: Vec<SpecConstant>,
}

impl Shader {
    /// Parses, validates and reflects a compute shader. Garbage, truncated, non-compute or
    /// invalid SPIR-V is rejected with a message naming `name`.
    pub fn from_spirv(name: &str, bytes: &[u8]) -> Result<Shader> {
        let err = |reason: String| Error::Spirv {
            name: name.to_string(),
            reason,
        };
        if bytes.len() < 20 || !bytes.len().is_multiple_of(4) {
            return Err(err(format!(
                "{} bytes is not a SPIR-V module (needs a 5-word header and whole 32-bit words)",
                bytes.len()
            )));
        }
        let words: Vec<u32> = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if words[0] != SPIRV_MAGIC {
            return Err(err(format!(
                "bad magic number {:#010x} (expected {SPIRV_MAGIC:#010x})",
                words[0]
            )));
        }
        validate_spirv(&words).map_err(|e| err(format!("spirv-val: {e}")))?;
        let (entry_point, local_size, local_size_spec) = compute_entry(&words).map_err(err)?;

        let (bindings, push_constant_size) = reflect::reflect(&words).map_err(err)?;
        let spec_constants = spec_constants(&words).map_err(err)?;
        Ok(Shader {
            name: name.to_string(),
            words,
            entry_point,
            local_size,
            local_size_spec,
            bindings,
            push_constant_size,
            spec_constants,
        })
    }

    /// Invocations per workgroup.
    pub fn invocations(&self) -> u32 {
        // Saturating: a module may declare any size; the device limits refuse it later.
        self.local_size
            .iter()
            .fold(1u32, |n, &s| n.saturating_mul(s))
    }
}

/// The entry point's name, its workgroup size (default values), and per axis the SpecId of
/// the specialization constant that sets it, if any. The size comes from, in order of
/// precedence: a constant decorated `BuiltIn WorkgroupSize`, `LocalSizeId` (SPIR-V 1.6), or
/// `LocalSize`.
type EntryInfo = (String, [u32; 3], [Option<u32>; 3]);

fn compute_entry(words: &[u32]) -> std::result::Result<EntryInfo, String> {
    const OP_EXECUTION_MODE: u32 = 16;
    const OP_EXECUTION_MODE_ID: u32 = 331;
    const OP_CONSTANT: u32 = 43;
    const OP_CONSTANT_COMPOSITE: u32 = 44;
    const OP_SPEC_CONSTANT: u32 = 50;
    const OP_SPEC_CONSTANT_COMPOSITE: u32 = 51;
    const EXECUTION_MODEL_GLCOMPUTE: u32 = 5;
    const MODE_LOCAL_SIZE: u32 = 17;
    const MODE_LOCAL_SIZE_ID: u32 = 38;
    const DECORATION_SPEC_ID: u32 = 1;
    const DECORATION_BUILTIN: u32 = 11;
    const BUILTIN_WORKGROUP_SIZE: u32 = 25;
    let mut entry: Option<String> = None;
    let mut local_size = None;
    let mut local_size_ids = None;
    let mut workgroup_size_id = None;
    let mut constants = std::collections::HashMap::new();
    let mut composites = std::collections::HashMap::new();
    let mut spec_ids = std::collections::HashMap::new();
    for (op, ops) in instructions(words) {
        match op {
            OP_ENTRY_POINT if ops.len() >= 3 => {
                if ops[0] != EXECUTION_MODEL_GLCOMPUTE {
                    return Err(format!(
                        "entry point has execution model {}, not GLCompute",
                        ops[0]
                    ));
                }
                if entry.is_some() {
                    return Err("more than one entry point".into());
                }
                let bytes: Vec<u8> = ops[2..].iter().flat_map(|w| w.to_le_bytes()).collect();
                let name = bytes.split(|&b| b == 0).next().unwrap_or(&[]);
                entry = Some(String::from_utf8_lossy(name).into_owned());
            }
            OP_EXECUTION_MODE if ops.len() >= 5 && ops[1] == MODE_LOCAL_SIZE => {
                local_size = Some([ops[2], ops[3], ops[4]]);
            }
            OP_EXECUTION_MODE_ID if ops.len() >= 5 && ops[1] == MODE_LOCAL_SIZE_ID => {
                local_size_ids = Some([ops[2], ops[3], ops[4]]);
            }
            OP_DECORATE if ops.len() == 3 && ops[1] == DECORATION_SPEC_ID => {
                spec_ids.insert(ops[0], ops[2]);
            }
            OP_DECORATE
                if ops.len() == 3
                    && ops[1] == DECORATION_BUILTIN
                    && ops[2] == BUILTIN_WORKGROUP_SIZE =>
            {
                workgroup_size_id = Some(ops[0]);
            }
            OP_CONSTANT | OP_SPEC_CONSTANT if ops.len() == 3 => {
                constants.insert(ops[1], ops[2]);
            }
            OP_CONSTANT_COMPOSITE | OP_SPEC_CONSTANT_COMPOSITE if ops.len() == 5 => {
                composites.insert(ops[1], [ops[2], ops[3], ops[4]]);
            }
            _ => {}
        }
    }
    let name = entry.ok_or("no entry point")?;
    let ids = match workgroup_size_id {
        Some(id) => Some(
            *composites
                .get(&id)
                .ok_or("the WorkgroupSize built-in is not a 3-component constant")?,
        ),
        None => local_size_ids,
    };
    let mut spec = [None; 3];
    if let Some(ids) = ids {
        let mut size = [0; 3];
        for axis in 0..3 {
            let id = ids[axis];
            size[axis] = *constants.get(&id).ok_or_else(|| {
                format!("workgroup size names %{id}, which is not a 32-bit constant")
            })?;
            spec[axis] = spec_ids.get(&id).copied();
        }
        local_size = Some(size);
    }
    let local_size = local_size.ok_or("compute entry point has no LocalSize")?;
    if local_size.contains(&0) {
        return Err(format!(
            "workgroup size {local_size:?} has a zero dimension"
        ));
    }
    Ok((name, local_size, spec))
}

/// Decoded instructions of a module: (opcode, operands).
fn instructions(words: &[u32]) -> impl Iterator<Item = (u32, &[u32])> {
    let mut i = 5;
    std::iter::from_fn(move || {
        if i >= words.len() {
            return None;
        }
        let count = ((words[i] >> 16) as usize).max(1);
        let end = (i + count).min(words.len());
        let item = (words[i] & 0xffff, &words[i + 1..end]);
        i = end;
        Some(item)
    })
}

const OP_ENTRY_POINT: u32 = 15;
const OP_DECORATE: u32 = 71;

/// Specialization constants: `SpecId` decorations with their OpSpecConstant* defaults.
fn spec_constants(words: &[u32]) -> std::result::Result<Vec<SpecConstant>, String> {
    const OP_NAME: u32 = 5;
    const OP_SPEC_CONSTANT_TRUE: u32 = 48;
    const OP_SPEC_CONSTANT_FALSE: u32 = 49;
    const OP_SPEC_CONSTANT: u32 = 50;
    const DECORATION_SPEC_ID: u32 = 1;
    let mut ids = std::collections::HashMap::new();
    let mut names = std::collections::HashMap::new();
    let mut defaults = std::collections::HashMap::new();
    for (op, ops) in instructions(words) {
        match op {
            OP_DECORATE if ops.len() == 3 && ops[1] == DECORATION_SPEC_ID => {
                ids.insert(ops[0], ops[2]);
            }
            OP_NAME if ops.len() >= 2 => {
                let bytes: Vec<u8> = ops[1..].iter().flat_map(|w| w.to_le_bytes()).collect();
                let name = bytes.split(|&b| b == 0).next().unwrap_or(&[]);
                names.insert(ops[0], String::from_utf8_lossy(name).into_owned());
            }
            OP_SPEC_CONSTANT_TRUE if ops.len() == 2 => {
                defaults.insert(ops[1], 1);
            }
            OP_SPEC_CONSTANT_FALSE if ops.len() == 2 => {
                defaults.insert(ops[1], 0);
            }
            OP_SPEC_CONSTANT if ops.len() == 3 => {
                defaults.insert(ops[1], ops[2]);
            }
            // Decorations precede constants in a module, so `ids` is complete here.
            OP_SPEC_CONSTANT if ops.len() > 3 && ids.contains_key(&ops[1]) => {
                return Err("64-bit specialization constants are not supported".into());
            }
            _ => {}
        }
    }
    let mut out: Vec<SpecConstant> = ids
        .iter()
        .filter_map(|(result, &id)| {
            defaults.get(result).map(|&d| SpecConstant {
                id,
                // Unnamed constants (e.g. `local_size_x_id`) are called `id<N>`.
                name: names
                    .get(result)
                    .filter(|n| !n.is_empty())
                    .cloned()
                    .unwrap_or_else(|| format!("id{id}")),
                default: d,
            })
        })
        .collect();
    // One SpecId is one constant, though a module may decorate several results with it
    // (glslang does for a specialised workgroup size); prefer a result that has a name.
    out.sort_by_key(|c| (c.id, c.name.starts_with("id")));
    out.dedup_by_key(|c| c.id);
    Ok(out)
}
