//! Reflection over hand-written SPIR-V (assembled in-process by SPIRV-Tools): the shapes
//! glslang emits for vkshade's kernels and the ones it does not, each field checked by hand,
//! and garbage that must be an error, never a panic.

use super::*;
use std::ffi::{CString, c_char, c_int, c_void};

#[repr(C)]
struct SpvBinary {
    code: *mut u32,
    word_count: usize,
}

// SPIRV-Tools' assembler (libspirv.h), from the archive build.rs links.
unsafe extern "C" {
    fn spvTextToBinary(
        context: *const c_void,
        text: *const c_char,
        length: usize,
        binary: *mut *mut SpvBinary,
        diagnostic: *mut *mut SpvDiagnostic,
    ) -> c_int;
    fn spvBinaryDestroy(binary: *mut SpvBinary);
}

/// Assembles `text` for target environment `env` (e.g. "vulkan1.0" gives a SPIR-V 1.0
/// header) into the bytes `Shader::from_spirv` takes.
fn assemble(text: &str, env: &str) -> Vec<u8> {
    let env_name = CString::new(env).unwrap();
    let mut target: c_int = 0;
    // SAFETY: NUL-terminated string, valid out pointer.
    assert!(unsafe { spvParseTargetEnv(env_name.as_ptr(), &mut target) });
    // SAFETY: create, assemble, copy the words out, then free binary, diagnostic and context.
    unsafe {
        let context = spvContextCreate(target);
        assert!(!context.is_null());
        let mut binary: *mut SpvBinary = std::ptr::null_mut();
        let mut diagnostic: *mut SpvDiagnostic = std::ptr::null_mut();
        let rc = spvTextToBinary(
            context,
            text.as_ptr().cast(),
            text.len(),
            &mut binary,
            &mut diagnostic,
        );
        let error = (!diagnostic.is_null() && !(*diagnostic).error.is_null()).then(|| {
            CStr::from_ptr((*diagnostic).error)
                .to_string_lossy()
                .into_owned()
        });
        let words = if rc == 0 && !binary.is_null() && !(*binary).code.is_null() {
            std::slice::from_raw_parts((*binary).code, (*binary).word_count).to_vec()
        } else {
            Vec::new()
        };
        spvBinaryDestroy(binary);
        spvDiagnosticDestroy(diagnostic);
        spvContextDestroy(context);
        assert_eq!(rc, 0, "assembly failed: {error:?}");
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }
}

fn words(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// SPIR-V 1.6: a runtime array after a nested struct with a matrix, a row-major matrix in a
/// uniform block, a runtime and a sized array of textures, one sampler used with three
/// textures (one through a function's parameters) and a second with a fourth, NonWritable
/// on every member, on one member and on an image variable, an array of storage buffers,
/// set numbers from a decoration group, unnamed variables.
const EDGES: &str = r#"               OpCapability Shader
               OpCapability RuntimeDescriptorArray
               OpMemoryModel Logical GLSL450
               OpEntryPoint GLCompute %main "main" %data %params %texs %smp %a %b %pair %smp2 %img %many %comb %partial %anon %pc
               OpExecutionMode %main LocalSize 1 1 1
               OpName %data "data"
               OpName %Params "Params"
               OpName %texs "texs"
               OpName %smp "smp"
               OpName %a "a"
               OpName %b "b"
               OpName %pair "pair"
               OpName %smp2 "smp2"
               OpName %img "img"
               OpName %many "many"
               OpName %comb "comb"
               OpName %partial "partial"
               OpMemberDecorate %Inner 0 Offset 0
               OpMemberDecorate %Inner 1 Offset 12
               OpMemberDecorate %Inner 2 Offset 16
               OpMemberDecorate %Inner 2 ColMajor
               OpMemberDecorate %Inner 2 MatrixStride 16
               OpDecorate %Inner2 ArrayStride 64
               OpDecorate %floats ArrayStride 4
               OpDecorate %Data Block
               OpMemberDecorate %Data 0 Offset 0
               OpMemberDecorate %Data 1 Offset 128
               OpMemberDecorate %Data 2 Offset 144
               OpMemberDecorate %Data 0 NonWritable
               OpMemberDecorate %Data 1 NonWritable
               OpMemberDecorate %Data 2 NonWritable
               OpDecorate %data DescriptorSet 0
               OpDecorate %data Binding 0
               OpDecorate %Params Block
               OpMemberDecorate %Params 0 Offset 0
               OpMemberDecorate %Params 1 Offset 16
               OpMemberDecorate %Params 1 RowMajor
               OpMemberDecorate %Params 1 MatrixStride 16
               OpMemberDecorate %Params 2 Offset 48
               OpDecorate %params DescriptorSet 0
               OpDecorate %params Binding 1
               OpDecorate %texs DescriptorSet 0
               OpDecorate %texs Binding 2
               OpDecorate %smp DescriptorSet 0
               OpDecorate %smp Binding 3
               OpDecorate %a DescriptorSet 0
               OpDecorate %a Binding 4
               OpDecorate %b DescriptorSet 0
               OpDecorate %b Binding 5
               OpDecorate %pair DescriptorSet 0
               OpDecorate %pair Binding 6
               OpDecorate %smp2 DescriptorSet 0
               OpDecorate %smp2 Binding 7
               OpDecorate %set1 DescriptorSet 1
       %set1 = OpDecorationGroup
               OpGroupDecorate %set1 %img %many %comb %partial %anon
               OpDecorate %img Binding 0
               OpDecorate %img NonWritable
               OpDecorate %v4s ArrayStride 16
               OpDecorate %Many Block
               OpMemberDecorate %Many 0 Offset 0
               OpDecorate %many Binding 1
               OpDecorate %comb Binding 2
               OpDecorate %Partial Block
               OpMemberDecorate %Partial 0 Offset 0
               OpMemberDecorate %Partial 0 NonWritable
               OpMemberDecorate %Partial 1 Offset 4
               OpDecorate %partial Binding 3
               OpDecorate %Anon Block
               OpMemberDecorate %Anon 0 Offset 0
               OpDecorate %anon Binding 4
               OpDecorate %Push Block
               OpMemberDecorate %Push 0 Offset 0
               OpMemberDecorate %Push 1 Offset 16
       %void = OpTypeVoid
       %fnty = OpTypeFunction %void
      %float = OpTypeFloat 32
       %uint = OpTypeInt 32 0
        %int = OpTypeInt 32 1
        %v2f = OpTypeVector %float 2
        %v3f = OpTypeVector %float 3
        %v4f = OpTypeVector %float 4
        %v4u = OpTypeVector %uint 4
         %m3 = OpTypeMatrix %v3f 3
       %m3x2 = OpTypeMatrix %v2f 3
     %uint_0 = OpConstant %uint 0
     %uint_1 = OpConstant %uint 1
     %uint_2 = OpConstant %uint 2
     %uint_4 = OpConstant %uint 4
    %float_0 = OpConstant %float 0
    %float_h = OpConstant %float 0.5
     %v2half = OpConstantComposite %v2f %float_h %float_h
     %v3half = OpConstantComposite %v3f %float_h %float_h %float_h
      %Inner = OpTypeStruct %v3f %float %m3
     %Inner2 = OpTypeArray %Inner %uint_2
     %floats = OpTypeRuntimeArray %float
       %Data = OpTypeStruct %Inner2 %v2f %floats
   %Data_ptr = OpTypePointer StorageBuffer %Data
       %data = OpVariable %Data_ptr StorageBuffer
     %Params = OpTypeStruct %v4f %m3x2 %float
 %Params_ptr = OpTypePointer Uniform %Params
     %params = OpVariable %Params_ptr Uniform
      %tex2d = OpTypeImage %float 2D 0 0 0 1 Unknown
  %tex2d_ptr = OpTypePointer UniformConstant %tex2d
       %texn = OpTypeRuntimeArray %tex2d
   %texn_ptr = OpTypePointer UniformConstant %texn
       %texs = OpVariable %texn_ptr UniformConstant
    %sampler = OpTypeSampler
%sampler_ptr = OpTypePointer UniformConstant %sampler
        %smp = OpVariable %sampler_ptr UniformConstant
       %smp2 = OpVariable %sampler_ptr UniformConstant
      %tex3d = OpTypeImage %float 3D 0 0 0 1 Unknown
  %tex3d_ptr = OpTypePointer UniformConstant %tex3d
          %a = OpVariable %tex3d_ptr UniformConstant
    %utex2da = OpTypeImage %uint 2D 0 1 0 1 Unknown
%utex2da_ptr = OpTypePointer UniformConstant %utex2da
          %b = OpVariable %utex2da_ptr UniformConstant
     %tex2d2 = OpTypeArray %tex2d %uint_2
 %tex2d2_ptr = OpTypePointer UniformConstant %tex2d2
       %pair = OpVariable %tex2d2_ptr UniformConstant
     %img2df = OpTypeImage %float 2D 0 0 0 2 R32f
 %img2df_ptr = OpTypePointer UniformConstant %img2df
        %img = OpVariable %img2df_ptr UniformConstant
        %v4s = OpTypeArray %v4f %uint_4
       %Many = OpTypeStruct %v4s
      %Many2 = OpTypeArray %Many %uint_2
  %Many2_ptr = OpTypePointer StorageBuffer %Many2
       %many = OpVariable %Many2_ptr StorageBuffer
      %icube = OpTypeImage %int Cube 0 0 0 1 Unknown
     %sicube = OpTypeSampledImage %icube
 %sicube_ptr = OpTypePointer UniformConstant %sicube
       %comb = OpVariable %sicube_ptr UniformConstant
    %Partial = OpTypeStruct %float %float
%Partial_ptr = OpTypePointer StorageBuffer %Partial
    %partial = OpVariable %Partial_ptr StorageBuffer
       %Anon = OpTypeStruct %uint
   %Anon_ptr = OpTypePointer StorageBuffer %Anon
       %anon = OpVariable %Anon_ptr StorageBuffer
       %Push = OpTypeStruct %v4f %v3f
   %Push_ptr = OpTypePointer PushConstant %Push
         %pc = OpVariable %Push_ptr PushConstant
       %si2d = OpTypeSampledImage %tex2d
       %si3d = OpTypeSampledImage %tex3d
    %siu2da = OpTypeSampledImage %utex2da
     %fetchty = OpTypeFunction %v4f %tex3d_ptr %sampler_ptr
       %main = OpFunction %void None %fnty
      %entry = OpLabel
          %s = OpLoad %sampler %smp
        %t0p = OpAccessChain %tex2d_ptr %texs %uint_1
         %t0 = OpLoad %tex2d %t0p
        %si0 = OpSampledImage %si2d %t0 %s
         %c0 = OpImageSampleExplicitLod %v4f %si0 %v2half Lod %float_0
         %c1 = OpFunctionCall %v4f %fetch %a %smp
         %tb = OpLoad %utex2da %b
        %sib = OpSampledImage %siu2da %tb %s
         %c2 = OpImageSampleExplicitLod %v4u %sib %v3half Lod %float_0
         %pp = OpAccessChain %tex2d_ptr %pair %uint_0
         %pt = OpLoad %tex2d %pp
         %s2 = OpLoad %sampler %smp2
        %sip = OpSampledImage %si2d %pt %s2
         %c3 = OpImageSampleExplicitLod %v4f %sip %v2half Lod %float_0
               OpReturn
               OpFunctionEnd
      %fetch = OpFunction %v4f None %fetchty
         %ft = OpFunctionParameter %tex3d_ptr
         %fs = OpFunctionParameter %sampler_ptr
         %fl = OpLabel
        %ftv = OpLoad %tex3d %ft
        %fsv = OpLoad %sampler %fs
        %fsi = OpSampledImage %si3d %ftv %fsv
         %fr = OpImageSampleExplicitLod %v4f %fsi %v3half Lod %float_0
               OpReturnValue %fr
               OpFunctionEnd
"#;

/// SPIR-V 1.0's spelling of a storage buffer: Uniform storage class, BufferBlock.
const BUFFER_BLOCK: &str = r#"               OpCapability Shader
               OpMemoryModel Logical GLSL450
               OpEntryPoint GLCompute %main "main"
               OpExecutionMode %main LocalSize 8 8 1
               OpName %Old "Old"
               OpDecorate %Old BufferBlock
               OpMemberDecorate %Old 0 Offset 0
               OpMemberDecorate %Old 0 NonWritable
               OpMemberDecorate %Old 1 Offset 16
               OpMemberDecorate %Old 1 NonWritable
               OpDecorate %rt ArrayStride 4
               OpDecorate %old DescriptorSet 0
               OpDecorate %old Binding 0
               OpDecorate %U Block
               OpMemberDecorate %U 0 Offset 0
               OpDecorate %u DescriptorSet 0
               OpDecorate %u Binding 1
       %void = OpTypeVoid
       %fnty = OpTypeFunction %void
      %float = OpTypeFloat 32
        %v3f = OpTypeVector %float 3
         %rt = OpTypeRuntimeArray %float
        %Old = OpTypeStruct %v3f %rt
    %Old_ptr = OpTypePointer Uniform %Old
        %old = OpVariable %Old_ptr Uniform
          %U = OpTypeStruct %v3f
      %U_ptr = OpTypePointer Uniform %U
          %u = OpVariable %U_ptr Uniform
       %main = OpFunction %void None %fnty
      %entry = OpLabel
               OpReturn
               OpFunctionEnd
"#;

fn binding(shader: &Shader, set: u32, binding: u32) -> &BindingInfo {
    shader
        .bindings
        .iter()
        .find(|b| (b.set, b.binding) == (set, binding))
        .unwrap_or_else(|| panic!("no binding {set}.{binding}: {:?}", shader.bindings))
}

#[test]
fn reflection_of_hand_written_edge_cases() {
    use DescriptorKind as K;
    use SampledType as T;
    use vk::ImageViewType as V;
    let shader = Shader::from_spirv("edges", &assemble(EDGES, "vulkan1.3")).unwrap();
    let sets: Vec<(u32, u32)> = shader.bindings.iter().map(|b| (b.set, b.binding)).collect();
    assert_eq!(
        sets,
        [
            (0, 0),
            (0, 1),
            (0, 2),
            (0, 3),
            (0, 4),
            (0, 5),
            (0, 6),
            (0, 7)
        ]
        .into_iter()
        .chain((0..5).map(|b| (1, b)))
        .collect::<Vec<_>>(),
        "sorted by set and binding; set 1 from the decoration group"
    );
    // (set, binding, name, kind, count, min_size, read_only, view type, sampled type,
    // samplers combined with).
    type Row = (
        u32,
        u32,
        &'static str,
        DescriptorKind,
        u32,
        u64,
        bool,
        Option<V>,
        Option<T>,
        &'static [(u32, u32)],
    );
    let expected: [Row; 13] = [
        // Inner[2] (stride 64) ends at 128, a vec2 at 128 ends at 136; the runtime array's
        // offset, 144, is the end of the fixed part. Every member NonWritable.
        (
            0,
            0,
            "data",
            K::StorageBuffer,
            1,
            144,
            true,
            None,
            None,
            &[],
        ),
        // Unnamed variable: the block's name. Row-major mat3x2 (2 rows of stride 16) at 16
        // ends at 48 (column-major would end at 64); a float at 48 ends at 52.
        (
            0,
            1,
            "Params",
            K::UniformBuffer,
            1,
            52,
            false,
            None,
            None,
            &[],
        ),
        // A runtime array of textures counts 0 (pipelines refuse it).
        (
            0,
            2,
            "texs",
            K::SampledImage,
            0,
            0,
            false,
            Some(V::TYPE_2D),
            Some(T::Float),
            &[(0, 3)],
        ),
        (0, 3, "smp", K::Sampler, 1, 0, false, None, None, &[]),
        // Sampled inside a function that takes the texture and sampler as parameters.
        (
            0,
            4,
            "a",
            K::SampledImage,
            1,
            0,
            false,
            Some(V::TYPE_3D),
            Some(T::Float),
            &[(0, 3)],
        ),
        (
            0,
            5,
            "b",
            K::SampledImage,
            1,
            0,
            false,
            Some(V::TYPE_2D_ARRAY),
            Some(T::UnsignedInt),
            &[(0, 3)],
        ),
        (
            0,
            6,
            "pair",
            K::SampledImage,
            2,
            0,
            false,
            Some(V::TYPE_2D),
            Some(T::Float),
            &[(0, 7)],
        ),
        (0, 7, "smp2", K::Sampler, 1, 0, false, None, None, &[]),
        // NonWritable on the variable.
        (
            1,
            0,
            "img",
            K::StorageImage,
            1,
            0,
            true,
            Some(V::TYPE_2D),
            Some(T::Float),
            &[],
        ),
        (
            1,
            1,
            "many",
            K::StorageBuffer,
            2,
            64,
            false,
            None,
            None,
            &[],
        ),
        (
            1,
            2,
            "comb",
            K::CombinedImageSampler,
            1,
            0,
            false,
            Some(V::CUBE),
            Some(T::SignedInt),
            &[],
        ),
        // NonWritable on one member of two: written through the other.
        (
            1,
            3,
            "partial",
            K::StorageBuffer,
            1,
            8,
            false,
            None,
            None,
            &[],
        ),
        // Neither the variable nor its block has a name.
        (
            1,
            4,
            "set1_binding4",
            K::StorageBuffer,
            1,
            4,
            false,
            None,
            None,
            &[],
        ),
    ];
    for (set, b, name, kind, count, min_size, read_only, view_type, sampled_type, with) in expected
    {
        assert_eq!(
            binding(&shader, set, b),
            &BindingInfo {
                set,
                binding: b,
                name: name.into(),
                kind,
                count,
                min_size,
                read_only,
                view_type,
                sampled_type,
                sampled_with: with.to_vec(),
            }
        );
    }
    // vec4 at 0, vec3 at 16: 28 bytes.
    assert_eq!(shader.push_constant_size, 28);
}

#[test]
fn reflection_of_spirv_1_0_buffer_blocks() {
    let bytes = assemble(BUFFER_BLOCK, "vulkan1.0");
    assert_eq!(words(&bytes)[1], 0x0001_0000, "a SPIR-V 1.0 module");
    let shader = Shader::from_spirv("buffer block", &bytes).unwrap();
    assert_eq!(shader.local_size, [8, 8, 1]);
    assert_eq!(shader.push_constant_size, 0);
    let old = binding(&shader, 0, 0);
    assert_eq!(
        (old.name.as_str(), old.kind, old.min_size, old.read_only),
        ("Old", DescriptorKind::StorageBuffer, 16, true),
        "BufferBlock is a storage buffer; a vec3 then a runtime array at 16"
    );
    let u = binding(&shader, 0, 1);
    assert_eq!(
        (u.name.as_str(), u.kind, u.min_size),
        ("set0_binding1", DescriptorKind::UniformBuffer, 12)
    );
}

/// A minimal module around `decls` (types and variables) and `decorations`.
fn module_with(decorations: &str, decls: &str) -> Vec<u8> {
    assemble(
        &format!(
            "OpCapability Shader\nOpCapability SampledBuffer\n\
             OpMemoryModel Logical GLSL450\nOpEntryPoint GLCompute %main \"main\"\n\
             OpExecutionMode %main LocalSize 1 1 1\n{decorations}\n\
             %void = OpTypeVoid\n%fnty = OpTypeFunction %void\n%float = OpTypeFloat 32\n\
             {decls}\n%main = OpFunction %void None %fnty\n%l = OpLabel\nOpReturn\n\
             OpFunctionEnd\n"
        ),
        "vulkan1.3",
    )
}

#[test]
fn descriptors_vkshade_does_not_bind_are_refused_by_name() {
    let texel = module_with(
        "OpName %tb \"texels\"\nOpDecorate %tb DescriptorSet 0\nOpDecorate %tb Binding 3",
        "%ti = OpTypeImage %float Buffer 0 0 0 1 Unknown\n\
         %tp = OpTypePointer UniformConstant %ti\n%tb = OpVariable %tp UniformConstant",
    );
    let err = Shader::from_spirv("texel", &texel).unwrap_err().to_string();
    assert!(
        err.contains("binding 0.3 'texels' has descriptor type UniformTexelBuffer"),
        "{err}"
    );
    let shared = module_with(
        "OpName %x \"x\"\nOpName %y \"y\"\nOpDecorate %S Block\nOpMemberDecorate %S 0 Offset 0\n\
         OpDecorate %x DescriptorSet 0\nOpDecorate %x Binding 0\n\
         OpDecorate %y DescriptorSet 0\nOpDecorate %y Binding 0",
        "%S = OpTypeStruct %float\n%sp = OpTypePointer StorageBuffer %S\n\
         %x = OpVariable %sp StorageBuffer\n%y = OpVariable %sp StorageBuffer",
    );
    let err = Shader::from_spirv("shared", &shared)
        .unwrap_err()
        .to_string();
    assert!(err.contains("'x' and 'y' share set 0 binding 0"), "{err}");
}

#[test]
fn garbage_after_the_header_never_panics() {
    // Reflection reads modules spirv-val has passed, but must not panic or index out of
    // bounds on anything: every truncation and many random word changes of the edge-case
    // modules go straight to the reflector, which may answer anything but a panic.
    for bytes in [
        assemble(EDGES, "vulkan1.3"),
        assemble(BUFFER_BLOCK, "vulkan1.0"),
    ] {
        let good = words(&bytes);
        for len in 0..good.len() {
            let _ = reflect::reflect(&good[..len]);
            let _ = compute_entry(&good[..len]);
            let _ = spec_constants(&good[..len]);
        }
        // A fixed-seed xorshift: reproducible.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..4000 {
            let mut w = good.clone();
            for _ in 0..1 + next() % 4 {
                let i = 5 + (next() as usize) % (w.len() - 5);
                w[i] = match next() % 4 {
                    // Small values hit ids, opcodes and enumerants; others anything.
                    0 => (next() % 64) as u32,
                    1 => w[i] ^ (1 << (next() % 32)),
                    2 => (next() as u32 & 0xffff) | (((next() % 8) as u32) << 16),
                    _ => next() as u32,
                };
            }
            let _ = reflect::reflect(&w);
            let _ = compute_entry(&w);
            let _ = spec_constants(&w);
        }
    }
}

#[test]
fn formats_have_the_class_a_shader_reads_them_as() {
    use vk::Format as F;
    for (format, class) in [
        (F::R32_UINT, Some(SampledType::UnsignedInt)),
        (F::R8G8B8A8_SINT, Some(SampledType::SignedInt)),
        (F::A2B10G10R10_UINT_PACK32, Some(SampledType::UnsignedInt)),
        (F::R32G32B32A32_SFLOAT, Some(SampledType::Float)),
        (F::R8G8B8A8_SRGB, Some(SampledType::Float)),
        (F::R16_UNORM, Some(SampledType::Float)),
        (F::B10G11R11_UFLOAT_PACK32, Some(SampledType::Float)),
        (F::BC1_RGB_UNORM_BLOCK, Some(SampledType::Float)),
        (F::D24_UNORM_S8_UINT, Some(SampledType::Float)),
        (F::S8_UINT, Some(SampledType::UnsignedInt)),
        (F::UNDEFINED, None),
    ] {
        assert_eq!(SampledType::of_format(format), class, "{format:?}");
    }
}
