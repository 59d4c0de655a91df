//! Throwaway comparison (deleted with the spirv-reflect dependency): the old reflection
//! through spirv-reflect against vkshade's own, field by field, over every module in spv/ and
//! the GLSL test shaders. Run with
//! `cargo test --release --lib shader::compare_old -- --nocapture`.

use super::*;

const OP_TYPE_POINTER: u32 = 32;
const OP_VARIABLE: u32 = 59;
const DECORATION_BLOCK: u32 = 2;
const DECORATION_BUFFER_BLOCK: u32 = 3;
const DECORATION_BINDING: u32 = 33;
const DECORATION_DESCRIPTOR_SET: u32 = 34;
const STORAGE_CLASS_UNIFORM: u32 = 2;
const STORAGE_CLASS_STORAGE_BUFFER: u32 = 12;

/// The view type an image binding needs, from its reflected dimension and arrayed flag.
fn image_view_type(
    kind: DescriptorKind,
    image: &spirv_reflect::types::ReflectImageTraits,
) -> Option<vk::ImageViewType> {
    use spirv_reflect::types::ReflectDimension as D;
    if !matches!(
        kind,
        DescriptorKind::StorageImage
            | DescriptorKind::SampledImage
            | DescriptorKind::CombinedImageSampler
    ) {
        return None;
    }
    let arrayed = image.arrayed != 0;
    Some(match (image.dim, arrayed) {
        (D::Type1d, false) => vk::ImageViewType::TYPE_1D,
        (D::Type1d, true) => vk::ImageViewType::TYPE_1D_ARRAY,
        (D::Type2d, false) => vk::ImageViewType::TYPE_2D,
        (D::Type2d, true) => vk::ImageViewType::TYPE_2D_ARRAY,
        (D::Type3d, _) => vk::ImageViewType::TYPE_3D,
        (D::Cube, false) => vk::ImageViewType::CUBE,
        (D::Cube, true) => vk::ImageViewType::CUBE_ARRAY,
        _ => return None,
    })
}

/// One reflected binding as vkshade describes it; an error for a descriptor type vkshade
/// does not bind.
fn binding_info(
    b: spirv_reflect::types::ReflectDescriptorBinding,
) -> std::result::Result<BindingInfo, String> {
    use spirv_reflect::types::ReflectDescriptorType as R;
    let kind = match b.descriptor_type {
        R::StorageBuffer => DescriptorKind::StorageBuffer,
        R::UniformBuffer => DescriptorKind::UniformBuffer,
        R::StorageImage => DescriptorKind::StorageImage,
        R::SampledImage => DescriptorKind::SampledImage,
        R::CombinedImageSampler => DescriptorKind::CombinedImageSampler,
        R::Sampler => DescriptorKind::Sampler,
        other => {
            return Err(format!(
                "binding {}.{} '{}' has descriptor type {other:?}, which vkshade does not bind",
                b.set, b.binding, b.name
            ));
        }
    };
    let type_name = b
        .type_description
        .as_ref()
        .map(|t| t.type_name.clone())
        .unwrap_or_default();
    let non_writable = |f: spirv_reflect::types::ReflectDecorationFlags| {
        f.contains(spirv_reflect::types::ReflectDecorationFlags::NON_WRITABLE)
    };
    let members = &b.block.members;
    let read_only = non_writable(b.block.decoration_flags)
        || (!members.is_empty() && members.iter().all(|m| non_writable(m.decoration_flags)));
    Ok(BindingInfo {
        set: b.set,
        binding: b.binding,
        name: match (b.name.is_empty(), type_name.is_empty()) {
            (false, _) => b.name,
            (true, false) => type_name,
            (true, true) => format!("set{}_binding{}", b.set, b.binding),
        },
        kind,
        count: b.count.max(1),
        min_size: b.block.size as u64,
        read_only,
        view_type: image_view_type(kind, &b.image),
        sampled_type: None,
        sampled_with: Vec::new(),
    })
}

/// A copy of a validated module in the form the SPIRV-Reflect C code of spirv-reflect 0.2
/// understands (it predates SPIR-V 1.3's StorageBuffer storage class):
/// - OpEntryPoint lists no interface variables (SPIR-V 1.4+ lists every global there, and
///   the C code aborts the process with an `assert` on storage buffers);
/// - StorageBuffer-class pointers and variables become Uniform-class with the struct
///   decorated BufferBlock, the SPIR-V 1.0 spelling of the same storage buffer.
///
/// Only descriptor bindings and push constants are reflected from the copy; it never reaches
/// the driver.
fn normalize_for_reflection(words: &[u32]) -> Vec<u32> {
    let ssbo_structs: Vec<u32> = instructions(words)
        .filter(|(op, ops)| {
            *op == OP_TYPE_POINTER && ops.len() == 3 && ops[1] == STORAGE_CLASS_STORAGE_BUFFER
        })
        .map(|(_, ops)| ops[2])
        .collect();
    let mut out = words[..5].to_vec();
    for (op, ops) in instructions(words) {
        let mut ops = ops.to_vec();
        match op {
            OP_ENTRY_POINT if ops.len() > 2 => {
                // Operands: execution model, function id, then the NUL-terminated name.
                let name_words = ops[2..]
                    .iter()
                    .position(|w| w.to_le_bytes().contains(&0))
                    .map_or(ops.len() - 2, |p| p + 1);
                ops.truncate(2 + name_words);
            }
            OP_TYPE_POINTER if ops.len() == 3 && ops[1] == STORAGE_CLASS_STORAGE_BUFFER => {
                ops[1] = STORAGE_CLASS_UNIFORM;
            }
            OP_VARIABLE if ops.len() >= 3 && ops[2] == STORAGE_CLASS_STORAGE_BUFFER => {
                ops[2] = STORAGE_CLASS_UNIFORM;
            }
            OP_DECORATE
                if ops.len() == 2
                    && ops[1] == DECORATION_BLOCK
                    && ssbo_structs.contains(&ops[0]) =>
            {
                ops[1] = DECORATION_BUFFER_BLOCK;
            }
            _ => {}
        }
        out.push((((ops.len() + 1) as u32) << 16) | op);
        out.extend_from_slice(&ops);
    }
    out
}

/// (set, binding) of every variable decorated with both, found by a plain scan of the module:
/// the independent check that reflection saw every resource.
fn decorated_bindings(words: &[u32]) -> Vec<(u32, u32)> {
    let mut sets = std::collections::HashMap::new();
    let mut bindings = std::collections::HashMap::new();
    for (op, ops) in instructions(words) {
        if op == OP_DECORATE && ops.len() == 3 {
            match ops[1] {
                DECORATION_DESCRIPTOR_SET => {
                    sets.insert(ops[0], ops[2]);
                }
                DECORATION_BINDING => {
                    bindings.insert(ops[0], ops[2]);
                }
                _ => {}
            }
        }
    }
    let mut out: Vec<(u32, u32)> = bindings
        .iter()
        .filter_map(|(id, b)| sets.get(id).map(|s| (*s, *b)))
        .collect();
    out.sort();
    out
}

/// The old `Shader::from_spirv` reflection steps.
fn old_reflect(words: &[u32]) -> std::result::Result<(Vec<BindingInfo>, u32), String> {
    let module = spirv_reflect::ShaderModule::load_u32_data(&normalize_for_reflection(words))
        .map_err(|e| format!("reflection failed: {e}"))?;
    let reflected = module
        .enumerate_descriptor_bindings(None)
        .map_err(|e| format!("reflection of bindings failed: {e}"))?;
    let mut bindings = reflected
        .into_iter()
        .map(binding_info)
        .collect::<std::result::Result<Vec<_>, String>>()?;
    bindings.sort_by_key(|b| (b.set, b.binding));
    let reflected: Vec<(u32, u32)> = bindings.iter().map(|b| (b.set, b.binding)).collect();
    let declared = decorated_bindings(words);
    if reflected != declared {
        return Err(format!(
            "reflection found bindings {reflected:?} but the module declares {declared:?}"
        ));
    }
    let push_constant_size = module
        .enumerate_push_constant_blocks(None)
        .map_err(|e| format!("reflection of push constants failed: {e}"))?
        .iter()
        .map(|p| {
            let end = p
                .members
                .iter()
                .map(|m| m.offset + m.size)
                .max()
                .unwrap_or(p.size);
            (p.offset + end).next_multiple_of(4)
        })
        .max()
        .unwrap_or(0);
    Ok((bindings, push_constant_size))
}

fn spv_files(dir: &std::path::Path, out: &mut Vec<(String, Vec<u8>)>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            spv_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "spv") {
            out.push((p.display().to_string(), std::fs::read(&p).unwrap()));
        }
    }
}

/// The GLSL test shaders (tests/misuse.rs) and shapes the kernels do not use.
#[cfg(feature = "glsl")]
const GLSL: &[(&str, &str)] = &[
    (
        "tests/misuse.rs TEX_AND_STORE",
        r#"#version 450
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform texture2D tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D img;
void main() { imageStore(img, ivec2(1, 1), textureLod(sampler2D(tex, smp), vec2(0.5), 0.0)); }"#,
    ),
    (
        "edge: nested structs, matrices, runtime array, arrays of textures",
        r#"#version 450
layout(local_size_x = 1) in;
struct Inner { vec3 a; float b; mat3 m; };
struct Outer { Inner i[2]; vec2 c; };
layout(std430, set = 0, binding = 0) readonly buffer Data { Outer head; uint n; float tail[]; } data;
layout(std140, set = 0, binding = 1) uniform Params { mat4 xf; vec3 v; Outer o; } params;
layout(set = 0, binding = 2) uniform texture2D texs[3];
layout(set = 0, binding = 3) uniform sampler smp;
layout(set = 0, binding = 4) uniform texture3D vol;
layout(set = 0, binding = 5) uniform utexture3D uvol;
layout(set = 1, binding = 0, r32f) uniform readonly image2DArray img;
layout(set = 1, binding = 1) uniform isampler2D combined;
layout(set = 1, binding = 2) buffer Partial { readonly float x; float y; } partial;
layout(set = 1, binding = 3) uniform samplerCube cube;
layout(set = 1, binding = 4) uniform sampler1DArray line;
layout(std430, set = 2, binding = 0) buffer Many { vec4 v[4]; } many[2];
layout(std140, set = 2, binding = 1) uniform Rows { layout(row_major) mat3x2 r; float after; } rows;
layout(push_constant) uniform Push { vec3 p; uint q; mat2 r; } pc;
void main() {
    vec4 s = texture(sampler2D(texs[1], smp), vec2(0.5)) + texture(sampler3D(vol, smp), vec3(0.5));
    s += vec4(texture(usampler3D(uvol, smp), vec3(0.5)));
    s += imageLoad(img, ivec3(0)) + vec4(texture(combined, vec2(0.5)));
    s += texture(cube, vec3(1.0)) + texture(line, vec2(0.5));
    s += data.head.i[1].m[0].xyzx + vec4(data.tail[data.n]) + params.xf[0] + params.o.c.xyxy;
    s += vec4(pc.p, float(pc.q)) + pc.r[0].xyxy + many[1].v[2] + vec4(rows.r[0], rows.after, 0.0);
    partial.y = s.x + partial.x;
}"#,
    ),
    (
        "edge: one sampler, two textures",
        r#"#version 450
layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform texture2D a;
layout(set = 0, binding = 1) uniform texture2D b;
layout(set = 0, binding = 2) uniform sampler s;
layout(set = 0, binding = 3) uniform sampler unused_sampler;
layout(set = 0, binding = 4) buffer Out { vec4 o; };
vec4 fetch(texture2D t, sampler k) { return texture(sampler2D(t, k), vec2(0.5)); }
void main() { o = fetch(a, s) + texture(sampler2D(b, s), vec2(0.5)); }"#,
    ),
];

#[test]
fn own_reflection_agrees_with_spirv_reflect() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut modules = Vec::new();
    spv_files(&root.join("spv"), &mut modules);
    #[cfg(feature = "glsl")]
    for (name, src) in GLSL {
        modules.push((
            name.to_string(),
            crate::shaders::compile_source(src, "t.comp").unwrap(),
        ));
    }
    modules.push((
        "hand-written EDGES".into(),
        super::tests::assemble(super::tests::EDGES, "vulkan1.3"),
    ));
    modules.push((
        "hand-written BUFFER_BLOCK".into(),
        super::tests::assemble(super::tests::BUFFER_BLOCK, "vulkan1.0"),
    ));
    let mut differences = Vec::new();
    let (mut n_bindings, mut n_modules) = (0, 0);
    for (name, bytes) in &modules {
        let words: Vec<u32> = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        validate_spirv(&words).unwrap();
        let new = reflect::reflect(&words);
        let old = old_reflect(&words);
        let ((new, new_push), (old, old_push)) = match (new, old) {
            (Ok(n), Ok(o)) => (n, o),
            (n, o) => {
                differences.push(format!("{name}: new {n:?}\n  old {o:?}"));
                continue;
            }
        };
        n_modules += 1;
        println!("{name}: push constants {new_push} (old {old_push})");
        if new_push != old_push {
            differences.push(format!(
                "{name}: push constants new {new_push} old {old_push}"
            ));
        }
        if new.len() != old.len() {
            differences.push(format!("{name}: {} bindings, old {}", new.len(), old.len()));
        }
        for (n, o) in new.iter().zip(&old) {
            n_bindings += 1;
            println!(
                "  {}.{} '{}' {:?} x{} min_size {} read_only {} view {:?} sampled {:?} with {:?}",
                n.set,
                n.binding,
                n.name,
                n.kind,
                n.count,
                n.min_size,
                n.read_only,
                n.view_type,
                n.sampled_type,
                n.sampled_with
            );
            let fields = [
                ("set", n.set.to_string(), o.set.to_string()),
                ("binding", n.binding.to_string(), o.binding.to_string()),
                ("name", n.name.clone(), o.name.clone()),
                ("kind", format!("{:?}", n.kind), format!("{:?}", o.kind)),
                ("count", n.count.to_string(), o.count.to_string()),
                ("min_size", n.min_size.to_string(), o.min_size.to_string()),
                (
                    "read_only",
                    n.read_only.to_string(),
                    o.read_only.to_string(),
                ),
                (
                    "view_type",
                    format!("{:?}", n.view_type),
                    format!("{:?}", o.view_type),
                ),
            ];
            for (field, a, b) in fields {
                if a != b {
                    differences.push(format!(
                        "{name}: binding {}.{} '{}' {field}: new {a}, old {b}",
                        n.set, n.binding, n.name
                    ));
                }
            }
        }
    }
    println!(
        "compared {n_modules} of {} modules, {n_bindings} bindings; {} differences:",
        modules.len(),
        differences.len()
    );
    for d in &differences {
        println!("  {d}");
    }
}
