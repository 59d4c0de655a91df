//! Reflection of a compute module's descriptor bindings and push constants, read from the
//! SPIR-V words themselves.
//!
//! vkshade reflects on its own rather than through a crate: spirv-reflect 0.2.3, the newest
//! release, converts the C library's results with `slice::from_raw_parts` on null pointers
//! (undefined behaviour, which debug builds abort on at the first pipeline), and
//! rspirv-reflect does not report an image's dimension or sampled type, which the view types
//! and the binding checks need. What is needed is small: the types of the resource variables,
//! their decorations and names, and which samplers each texture is combined with.
//!
//! The module has passed spirv-val before it gets here, so the reader relies on a valid module
//! for its answers (e.g. explicit offsets in every block); on any input it still never panics
//! or indexes out of bounds, and answers an error where something it needs is missing.

use super::{BindingInfo, DescriptorKind, SampledType};
use ash::vk;
use std::collections::{BTreeSet, HashMap, HashSet};

/// Opcodes read here.
mod op {
    pub const NAME: u32 = 5;
    pub const TYPE_VOID: u32 = 19;
    pub const TYPE_BOOL: u32 = 20;
    pub const TYPE_INT: u32 = 21;
    pub const TYPE_FLOAT: u32 = 22;
    pub const TYPE_VECTOR: u32 = 23;
    pub const TYPE_MATRIX: u32 = 24;
    pub const TYPE_IMAGE: u32 = 25;
    pub const TYPE_SAMPLER: u32 = 26;
    pub const TYPE_SAMPLED_IMAGE: u32 = 27;
    pub const TYPE_ARRAY: u32 = 28;
    pub const TYPE_RUNTIME_ARRAY: u32 = 29;
    pub const TYPE_STRUCT: u32 = 30;
    pub const TYPE_POINTER: u32 = 32;
    pub const CONSTANT: u32 = 43;
    pub const SPEC_CONSTANT: u32 = 50;
    pub const FUNCTION: u32 = 54;
    pub const FUNCTION_PARAMETER: u32 = 55;
    pub const FUNCTION_CALL: u32 = 57;
    pub const VARIABLE: u32 = 59;
    pub const LOAD: u32 = 61;
    pub const STORE: u32 = 62;
    pub const ACCESS_CHAIN: u32 = 65;
    pub const IN_BOUNDS_ACCESS_CHAIN: u32 = 66;
    pub const PTR_ACCESS_CHAIN: u32 = 67;
    pub const DECORATE: u32 = 71;
    pub const MEMBER_DECORATE: u32 = 72;
    pub const GROUP_DECORATE: u32 = 74;
    pub const GROUP_MEMBER_DECORATE: u32 = 75;
    pub const COPY_OBJECT: u32 = 83;
    pub const SAMPLED_IMAGE: u32 = 86;
    pub const IMAGE: u32 = 100;
    pub const SELECT: u32 = 169;
    pub const PHI: u32 = 245;
    pub const TYPE_ACCELERATION_STRUCTURE: u32 = 5341;
}

/// Decorations read here.
mod deco {
    pub const BUFFER_BLOCK: u32 = 3;
    pub const ROW_MAJOR: u32 = 4;
    pub const ARRAY_STRIDE: u32 = 6;
    pub const MATRIX_STRIDE: u32 = 7;
    pub const NON_WRITABLE: u32 = 24;
    pub const BINDING: u32 = 33;
    pub const DESCRIPTOR_SET: u32 = 34;
    pub const OFFSET: u32 = 35;
}

const CLASS_UNIFORM_CONSTANT: u32 = 0;
const CLASS_UNIFORM: u32 = 2;
const CLASS_PUSH_CONSTANT: u32 = 9;
const CLASS_STORAGE_BUFFER: u32 = 12;

const DIM_1D: u32 = 0;
const DIM_2D: u32 = 1;
const DIM_3D: u32 = 2;
const DIM_CUBE: u32 = 3;
const DIM_BUFFER: u32 = 5;
const DIM_SUBPASS_DATA: u32 = 6;

/// Types nest at most this deep here (a guard against cycles in an invalid module).
const MAX_DEPTH: u32 = 64;

/// A type, as far as reflection needs it.
#[derive(Clone, Debug)]
enum Ty {
    Void,
    Bool,
    Int { width: u32, signed: bool },
    Float { width: u32 },
    Vector { component: u32, count: u32 },
    Matrix { column: u32, columns: u32 },
    Image(ImageTy),
    Sampler,
    SampledImage { image: u32 },
    Array { element: u32, length: u32 },
    RuntimeArray { element: u32 },
    Struct { members: Vec<u32> },
    Pointer { pointee: u32 },
    AccelerationStructure,
}

/// The operands of OpTypeImage reflection uses.
#[derive(Clone, Copy, Debug)]
struct ImageTy {
    sampled_type: u32,
    dim: u32,
    arrayed: bool,
    /// 1: sampled, 2: storage (0: known at run time only, which Vulkan forbids).
    sampled: u32,
}

/// A module-scope variable.
struct Variable {
    id: u32,
    class: u32,
    pointee: u32,
}

/// (decoration, its first literal or 0) pairs.
type Decorations = Vec<(u32, u32)>;

/// What a scan of the module collected.
#[derive(Default)]
struct Module {
    names: HashMap<u32, String>,
    decorations: HashMap<u32, Decorations>,
    member_decorations: HashMap<(u32, u32), Decorations>,
    types: HashMap<u32, Ty>,
    constants: HashMap<u32, u64>,
    variables: Vec<Variable>,
    /// For each value: the values it may have come from (loads, access chains, copies,
    /// function arguments, phis), to follow a sampled image back to its variables.
    sources: HashMap<u32, Vec<u32>>,
    /// (image, sampler) operands of every OpSampledImage.
    sampled_images: Vec<(u32, u32)>,
}

/// A NUL-terminated literal string from words (lossy UTF-8; the rest if no NUL).
fn literal_string(words: &[u32]) -> String {
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let name = bytes.split(|&b| b == 0).next().unwrap_or(&[]);
    String::from_utf8_lossy(name).into_owned()
}

impl Module {
    fn scan(words: &[u32]) -> Module {
        let mut m = Module::default();
        let mut params: HashMap<u32, Vec<u32>> = HashMap::new();
        let mut calls: Vec<(u32, Vec<u32>)> = Vec::new();
        let mut function = None;
        for (opcode, ops) in super::instructions(words) {
            let at = |i: usize| ops.get(i).copied().unwrap_or(0);
            let ty = match opcode {
                op::TYPE_VOID => Some(Ty::Void),
                op::TYPE_BOOL => Some(Ty::Bool),
                op::TYPE_INT => Some(Ty::Int {
                    width: at(1),
                    signed: at(2) != 0,
                }),
                op::TYPE_FLOAT => Some(Ty::Float { width: at(1) }),
                op::TYPE_VECTOR => Some(Ty::Vector {
                    component: at(1),
                    count: at(2),
                }),
                op::TYPE_MATRIX => Some(Ty::Matrix {
                    column: at(1),
                    columns: at(2),
                }),
                op::TYPE_IMAGE => Some(Ty::Image(ImageTy {
                    sampled_type: at(1),
                    dim: at(2),
                    arrayed: at(4) != 0,
                    sampled: at(6),
                })),
                op::TYPE_SAMPLER => Some(Ty::Sampler),
                op::TYPE_SAMPLED_IMAGE => Some(Ty::SampledImage { image: at(1) }),
                op::TYPE_ARRAY => Some(Ty::Array {
                    element: at(1),
                    length: at(2),
                }),
                op::TYPE_RUNTIME_ARRAY => Some(Ty::RuntimeArray { element: at(1) }),
                op::TYPE_STRUCT => Some(Ty::Struct {
                    members: ops.get(1..).unwrap_or(&[]).to_vec(),
                }),
                op::TYPE_POINTER => Some(Ty::Pointer { pointee: at(2) }),
                op::TYPE_ACCELERATION_STRUCTURE => Some(Ty::AccelerationStructure),
                _ => None,
            };
            if let Some(ty) = ty {
                m.types.insert(at(0), ty);
                continue;
            }
            match opcode {
                op::NAME if !ops.is_empty() => {
                    m.names.insert(ops[0], literal_string(&ops[1..]));
                }
                op::DECORATE if ops.len() >= 2 => {
                    let d = (ops[1], at(2));
                    m.decorations.entry(ops[0]).or_default().push(d);
                }
                op::MEMBER_DECORATE if ops.len() >= 3 => {
                    let d = (ops[2], at(3));
                    m.member_decorations
                        .entry((ops[0], ops[1]))
                        .or_default()
                        .push(d);
                }
                // A decoration group's decorations precede the OpGroupDecorate that applies
                // them (the module's layout rules), so they are known here.
                op::GROUP_DECORATE if !ops.is_empty() => {
                    let group = m.decorations.get(&ops[0]).cloned().unwrap_or_default();
                    for &target in &ops[1..] {
                        m.decorations
                            .entry(target)
                            .or_default()
                            .extend(group.iter().copied());
                    }
                }
                op::GROUP_MEMBER_DECORATE if !ops.is_empty() => {
                    let group = m.decorations.get(&ops[0]).cloned().unwrap_or_default();
                    for pair in ops[1..].chunks_exact(2) {
                        m.member_decorations
                            .entry((pair[0], pair[1]))
                            .or_default()
                            .extend(group.iter().copied());
                    }
                }
                op::CONSTANT | op::SPEC_CONSTANT if ops.len() >= 3 => {
                    let high = ops.get(3).map_or(0, |&w| (w as u64) << 32);
                    m.constants.insert(ops[1], ops[2] as u64 | high);
                }
                // Module-scope variables only (function-local ones hold no descriptors).
                op::VARIABLE if ops.len() >= 3 && function.is_none() => {
                    m.variables.push(Variable {
                        id: ops[1],
                        class: ops[2],
                        pointee: m.pointee(ops[0]),
                    });
                }
                op::FUNCTION if ops.len() >= 2 => function = Some(ops[1]),
                op::FUNCTION_PARAMETER if ops.len() >= 2 => {
                    if let Some(f) = function {
                        params.entry(f).or_default().push(ops[1]);
                    }
                }
                op::FUNCTION_CALL if ops.len() >= 3 => {
                    calls.push((ops[2], ops[3..].to_vec()));
                }
                op::LOAD
                | op::ACCESS_CHAIN
                | op::IN_BOUNDS_ACCESS_CHAIN
                | op::PTR_ACCESS_CHAIN
                | op::COPY_OBJECT
                | op::IMAGE
                    if ops.len() >= 3 =>
                {
                    m.source(ops[1], ops[2]);
                }
                op::STORE if ops.len() >= 2 => m.source(ops[0], ops[1]),
                op::SAMPLED_IMAGE if ops.len() >= 4 => {
                    m.source(ops[1], ops[2]);
                    m.sampled_images.push((ops[2], ops[3]));
                }
                op::SELECT if ops.len() >= 5 => {
                    m.source(ops[1], ops[3]);
                    m.source(ops[1], ops[4]);
                }
                op::PHI if ops.len() >= 2 => {
                    for pair in ops[2..].chunks_exact(2) {
                        m.source(ops[1], pair[0]);
                    }
                }
                _ => {}
            }
        }
        for (f, args) in calls {
            if let Some(ps) = params.get(&f) {
                for (&p, &a) in ps.iter().zip(&args) {
                    m.source(p, a);
                }
            }
        }
        m
    }

    /// What a pointer type points to (0, which no id is, for anything else).
    fn pointee(&self, pointer: u32) -> u32 {
        match self.types.get(&pointer) {
            Some(Ty::Pointer { pointee }) => *pointee,
            _ => 0,
        }
    }

    fn source(&mut self, value: u32, from: u32) {
        self.sources.entry(value).or_default().push(from);
    }

    /// The first literal of decoration `d` on `id`, if it has it (0 for one without literal).
    fn decoration(&self, id: u32, d: u32) -> Option<u32> {
        let list = self.decorations.get(&id)?;
        list.iter().find(|(k, _)| *k == d).map(|(_, v)| *v)
    }

    fn member_decoration(&self, ty: u32, member: u32, d: u32) -> Option<u32> {
        let list = self.member_decorations.get(&(ty, member))?;
        list.iter().find(|(k, _)| *k == d).map(|(_, v)| *v)
    }

    fn name(&self, id: u32) -> Option<&str> {
        self.names
            .get(&id)
            .map(String::as_str)
            .filter(|n| !n.is_empty())
    }

    fn ty(&self, id: u32) -> Result<&Ty, String> {
        self.types
            .get(&id)
            .ok_or_else(|| format!("%{id} is used as a type but is not one"))
    }

    /// The module-scope variables `value` may have come from.
    fn origins(&self, value: u32, variables: &HashSet<u32>) -> BTreeSet<u32> {
        let mut found = BTreeSet::new();
        let mut seen = HashSet::new();
        let mut stack = vec![value];
        while let Some(v) = stack.pop() {
            if !seen.insert(v) {
                continue;
            }
            if variables.contains(&v) {
                found.insert(v);
            }
            if let Some(from) = self.sources.get(&v) {
                stack.extend(from.iter().copied());
            }
        }
        found
    }

    /// The element count of array type `length`'s constant (a specialization constant's
    /// default).
    fn array_length(&self, length: u32) -> Result<u64, String> {
        self.constants
            .get(&length)
            .copied()
            .ok_or_else(|| format!("array length %{length} is not a constant"))
    }

    /// Bytes type `ty` takes in an explicitly laid-out block, as members are placed: a
    /// runtime array counts 0 (only its offset matters), a matrix `stride` per column (per
    /// row when row-major), an array `ArrayStride` per element, a struct up to the end of
    /// its furthest member. `matrix` is the (MatrixStride, row-major) of the member that
    /// holds `ty`, passed through arrays to the matrices in them.
    fn size(&self, ty: u32, matrix: Option<(u32, bool)>, depth: u32) -> Result<u64, String> {
        if depth > MAX_DEPTH {
            return Err(format!("type %{ty} nests deeper than {MAX_DEPTH}"));
        }
        Ok(match self.ty(ty)? {
            Ty::Bool => 4,
            Ty::Int { width, .. } | Ty::Float { width } => (*width as u64).div_ceil(8),
            Ty::Vector { component, count } => {
                (*count as u64).saturating_mul(self.size(*component, None, depth + 1)?)
            }
            Ty::Matrix { column, columns } => match matrix {
                Some((stride, row_major)) => {
                    let lines = if row_major {
                        match self.ty(*column)? {
                            Ty::Vector { count, .. } => *count,
                            _ => return Err(format!("matrix %{ty} has a non-vector column")),
                        }
                    } else {
                        *columns
                    };
                    (lines as u64).saturating_mul(stride as u64)
                }
                None => (*columns as u64).saturating_mul(self.size(*column, None, depth + 1)?),
            },
            Ty::Array { element, length } => {
                let n = self.array_length(*length)?;
                let stride = match self.decoration(ty, deco::ARRAY_STRIDE) {
                    Some(s) => s as u64,
                    None => self.size(*element, matrix, depth + 1)?,
                };
                n.saturating_mul(stride)
            }
            Ty::RuntimeArray { .. } => 0,
            Ty::Struct { members } => {
                let mut end = 0u64;
                for (i, &member) in members.iter().enumerate() {
                    let i = i as u32;
                    let offset = self
                        .member_decoration(ty, i, deco::OFFSET)
                        .ok_or_else(|| format!("member {i} of struct %{ty} has no Offset"))?;
                    let matrix = self.member_decoration(ty, i, deco::MATRIX_STRIDE).map(|s| {
                        let row_major = self.member_decoration(ty, i, deco::ROW_MAJOR).is_some();
                        (s, row_major)
                    });
                    let size = self.size(member, matrix, depth + 1)?;
                    end = end.max((offset as u64).saturating_add(size));
                }
                end
            }
            // A physical storage buffer address.
            Ty::Pointer { .. } => 8,
            other => return Err(format!("type %{ty} ({other:?}) has no size in a block")),
        })
    }

    /// The descriptor kind of a resource variable whose arrays are unwrapped to `ty`, or
    /// the name of a descriptor type vkshade does not bind.
    fn kind(&self, class: u32, ty: u32) -> Result<DescriptorKind, String> {
        Ok(match self.ty(ty)? {
            Ty::Struct { .. } => match class {
                CLASS_STORAGE_BUFFER => DescriptorKind::StorageBuffer,
                CLASS_UNIFORM if self.decoration(ty, deco::BUFFER_BLOCK).is_some() => {
                    DescriptorKind::StorageBuffer
                }
                CLASS_UNIFORM => DescriptorKind::UniformBuffer,
                _ => return Err(format!("a block in storage class {class}")),
            },
            Ty::Image(i) => match (i.dim, i.sampled) {
                (DIM_BUFFER, 2) => return Err("StorageTexelBuffer".into()),
                (DIM_BUFFER, _) => return Err("UniformTexelBuffer".into()),
                (DIM_SUBPASS_DATA, _) => return Err("InputAttachment".into()),
                (_, 2) => DescriptorKind::StorageImage,
                _ => DescriptorKind::SampledImage,
            },
            Ty::SampledImage { image } => match self.ty(*image)? {
                Ty::Image(i) if i.dim == DIM_BUFFER => {
                    return Err("UniformTexelBuffer".into());
                }
                _ => DescriptorKind::CombinedImageSampler,
            },
            Ty::Sampler => DescriptorKind::Sampler,
            Ty::AccelerationStructure => return Err("AccelerationStructure".into()),
            other => return Err(format!("{other:?}")),
        })
    }

    /// The image type of an image or combined image sampler type.
    fn image(&self, ty: u32) -> Option<ImageTy> {
        match self.types.get(&ty)? {
            Ty::Image(i) => Some(*i),
            Ty::SampledImage { image } => match self.types.get(image)? {
                Ty::Image(i) => Some(*i),
                _ => None,
            },
            _ => None,
        }
    }

    /// One resource variable as a binding (without `sampled_with`).
    fn binding(&self, v: &Variable) -> Result<BindingInfo, String> {
        let (Some(set), Some(binding)) = (
            self.decoration(v.id, deco::DESCRIPTOR_SET),
            self.decoration(v.id, deco::BINDING),
        ) else {
            return Err(format!(
                "resource variable '{}' lacks a DescriptorSet or Binding decoration",
                self.name(v.id).unwrap_or("(unnamed)")
            ));
        };
        // Arrays of descriptors: their element counts multiply; a runtime array counts 0.
        let mut ty = v.pointee;
        let mut count = 1u64;
        for _ in 0..MAX_DEPTH {
            match self.ty(ty)? {
                Ty::Array { element, length } => {
                    count = count.saturating_mul(self.array_length(*length)?);
                    ty = *element;
                }
                Ty::RuntimeArray { element } => {
                    count = 0;
                    ty = *element;
                }
                _ => break,
            }
        }
        let name = match (self.name(v.id), self.name(ty)) {
            (Some(n), _) | (None, Some(n)) => n.to_string(),
            (None, None) => format!("set{set}_binding{binding}"),
        };
        let kind = self.kind(v.class, ty).map_err(|what| {
            format!(
                "binding {set}.{binding} '{name}' has descriptor type {what}, which vkshade \
                 does not bind"
            )
        })?;
        let block = matches!(
            kind,
            DescriptorKind::StorageBuffer | DescriptorKind::UniformBuffer
        );
        let min_size = if block {
            self.size(ty, None, 0)
                .map_err(|e| format!("binding {set}.{binding} '{name}': {e}"))?
        } else {
            0
        };
        let members_non_writable = match self.types.get(&ty) {
            Some(Ty::Struct { members }) if !members.is_empty() => (0..members.len() as u32)
                .all(|i| self.member_decoration(ty, i, deco::NON_WRITABLE).is_some()),
            _ => false,
        };
        let read_only = self.decoration(v.id, deco::NON_WRITABLE).is_some() || members_non_writable;
        let image = self.image(ty);
        let view_type = image.and_then(|i| {
            Some(match (i.dim, i.arrayed) {
                (DIM_1D, false) => vk::ImageViewType::TYPE_1D,
                (DIM_1D, true) => vk::ImageViewType::TYPE_1D_ARRAY,
                (DIM_2D, false) => vk::ImageViewType::TYPE_2D,
                (DIM_2D, true) => vk::ImageViewType::TYPE_2D_ARRAY,
                (DIM_3D, _) => vk::ImageViewType::TYPE_3D,
                (DIM_CUBE, false) => vk::ImageViewType::CUBE,
                (DIM_CUBE, true) => vk::ImageViewType::CUBE_ARRAY,
                _ => return None,
            })
        });
        let sampled_type = image.and_then(|i| match self.types.get(&i.sampled_type)? {
            Ty::Float { .. } => Some(SampledType::Float),
            Ty::Int { signed: true, .. } => Some(SampledType::SignedInt),
            Ty::Int { signed: false, .. } => Some(SampledType::UnsignedInt),
            _ => None,
        });
        Ok(BindingInfo {
            set,
            binding,
            name,
            kind,
            count: u32::try_from(count).map_err(|_| {
                format!("binding {set}.{binding} is an array of {count} descriptors")
            })?,
            min_size,
            read_only,
            view_type,
            sampled_type,
            sampled_with: Vec::new(),
        })
    }
}

/// Descriptor bindings (sorted by set and binding) and push-constant bytes of a validated
/// module.
pub(super) fn reflect(words: &[u32]) -> Result<(Vec<BindingInfo>, u32), String> {
    let m = Module::scan(words);
    let mut bindings = Vec::new();
    let mut ids = Vec::new();
    let mut push_constant_size = 0u64;
    for v in &m.variables {
        match v.class {
            CLASS_UNIFORM_CONSTANT | CLASS_UNIFORM | CLASS_STORAGE_BUFFER => {
                bindings.push(m.binding(v)?);
                ids.push(v.id);
            }
            CLASS_PUSH_CONSTANT => {
                let end = m
                    .size(v.pointee, None, 0)
                    .map_err(|e| format!("push constants: {e}"))?;
                // Rounded up to whole words (saturating: a garbage size is refused below).
                push_constant_size = push_constant_size.max(end.saturating_add(3) & !3);
            }
            _ => {}
        }
    }
    // Which sampler bindings each separate texture is sampled with.
    let variables: HashSet<u32> = ids.iter().copied().collect();
    let index: HashMap<u32, usize> = ids.iter().enumerate().map(|(i, &v)| (v, i)).collect();
    for &(image, sampler) in &m.sampled_images {
        let samplers: Vec<(u32, u32)> = m
            .origins(sampler, &variables)
            .iter()
            .filter_map(|v| index.get(v).map(|&i| &bindings[i]))
            .filter(|b| b.kind == DescriptorKind::Sampler)
            .map(|b| (b.set, b.binding))
            .collect();
        for v in m.origins(image, &variables) {
            if let Some(&i) = index.get(&v)
                && bindings[i].kind == DescriptorKind::SampledImage
            {
                bindings[i].sampled_with.extend(samplers.iter().copied());
            }
        }
    }
    for b in &mut bindings {
        b.sampled_with.sort_unstable();
        b.sampled_with.dedup();
    }
    bindings.sort_by_key(|b| (b.set, b.binding));
    if let Some(w) = bindings
        .windows(2)
        .find(|w| (w[0].set, w[0].binding) == (w[1].set, w[1].binding))
    {
        return Err(format!(
            "bindings '{}' and '{}' share set {} binding {}, which vkshade does not bind",
            w[0].name, w[1].name, w[0].set, w[0].binding
        ));
    }
    let push_constant_size = u32::try_from(push_constant_size)
        .map_err(|_| format!("{push_constant_size} bytes of push constants"))?;
    Ok((bindings, push_constant_size))
}
