//! glTF buffers and accessors read without trusting the file.
//!
//! The gltf crate's readers assume a spec-valid file: an accessor whose component type its
//! semantic forbids (indices as FLOAT, JOINTS_0 as FLOAT, ...) reaches `unreachable!()`, and
//! a view or stride that points past its buffer panics on a slice. So vkshade reads the JSON
//! itself: every accessor's component type, type and `normalized` flag are checked against
//! what the glTF 2.0 specification allows for the semantic that uses it, and its count,
//! offset, stride, view and buffer against the bytes that are really there, before anything
//! is read or allocated (an element count can only pass if the view holds that many
//! elements, so no allocation exceeds a small multiple of the file's size). Sparse
//! substitutions are checked too (indices in range and strictly increasing).
//!
//! Errors are plain strings; the loader prefixes the file and what uses the accessor.

use gltf::json;
use gltf::json::accessor::{ComponentType as Ct, Type};
use gltf::json::validation::Checked;
use std::path::Path;

/// Most elements an accessor without a buffer view (all zeros plus sparse substitutions)
/// may declare: such an accessor costs memory without costing file bytes.
pub const MAX_IMPLICIT_ELEMENTS: u64 = 1 << 24;

/// One allowed combination of component type, accessor type and `normalized` flag.
pub type Form = (Ct, Type, bool);

pub const POSITION: &[Form] = &[(Ct::F32, Type::Vec3, false)];
pub const NORMAL: &[Form] = &[(Ct::F32, Type::Vec3, false)];
pub const TEXCOORD: &[Form] = &[
    (Ct::F32, Type::Vec2, false),
    (Ct::U8, Type::Vec2, true),
    (Ct::U16, Type::Vec2, true),
];
pub const JOINTS: &[Form] = &[(Ct::U8, Type::Vec4, false), (Ct::U16, Type::Vec4, false)];
pub const WEIGHTS: &[Form] = &[
    (Ct::F32, Type::Vec4, false),
    (Ct::U8, Type::Vec4, true),
    (Ct::U16, Type::Vec4, true),
];
pub const INDICES: &[Form] = &[
    (Ct::U8, Type::Scalar, false),
    (Ct::U16, Type::Scalar, false),
    (Ct::U32, Type::Scalar, false),
];
pub const INVERSE_BIND: &[Form] = &[(Ct::F32, Type::Mat4, false)];
pub const TIMES: &[Form] = &[(Ct::F32, Type::Scalar, false)];
pub const VEC3_KEYS: &[Form] = &[(Ct::F32, Type::Vec3, false)];
pub const ROTATION_KEYS: &[Form] = &[
    (Ct::F32, Type::Vec4, false),
    (Ct::I8, Type::Vec4, true),
    (Ct::U8, Type::Vec4, true),
    (Ct::I16, Type::Vec4, true),
    (Ct::U16, Type::Vec4, true),
];

fn ct_name(c: Ct) -> &'static str {
    match c {
        Ct::I8 => "BYTE",
        Ct::U8 => "UNSIGNED_BYTE",
        Ct::I16 => "SHORT",
        Ct::U16 => "UNSIGNED_SHORT",
        Ct::U32 => "UNSIGNED_INT",
        Ct::F32 => "FLOAT",
    }
}

fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

fn form_name((c, t, n): Form) -> String {
    format!(
        "{} of {}{}",
        type_name(t),
        if n { "normalized " } else { "" },
        ct_name(c)
    )
}

fn ct_size(c: Ct) -> u64 {
    match c {
        Ct::I8 | Ct::U8 => 1,
        Ct::I16 | Ct::U16 => 2,
        Ct::U32 | Ct::F32 => 4,
    }
}

/// (columns, rows) of an accessor type.
fn shape(t: Type) -> (u64, u64) {
    match t {
        Type::Scalar => (1, 1),
        Type::Vec2 => (1, 2),
        Type::Vec3 => (1, 3),
        Type::Vec4 => (1, 4),
        Type::Mat2 => (2, 2),
        Type::Mat3 => (3, 3),
        Type::Mat4 => (4, 4),
    }
}

/// Bytes between matrix columns (columns start on 4-byte boundaries) and bytes per element.
fn layout(c: Ct, t: Type) -> (u64, u64) {
    let (cols, rows) = shape(t);
    let col = rows * ct_size(c);
    let col_stride = if cols > 1 { col.div_ceil(4) * 4 } else { col };
    (col_stride, cols * col_stride)
}

fn decode(b: &[u8], c: Ct) -> f64 {
    // `b` is at least `ct_size(c)` long: every caller slices inside a checked span.
    let a2 = || [b[0], b[1]];
    let a4 = || [b[0], b[1], b[2], b[3]];
    match c {
        Ct::I8 => b[0] as i8 as f64,
        Ct::U8 => b[0] as f64,
        Ct::I16 => i16::from_le_bytes(a2()) as f64,
        Ct::U16 => u16::from_le_bytes(a2()) as f64,
        Ct::U32 => u32::from_le_bytes(a4()) as f64,
        Ct::F32 => f32::from_le_bytes(a4()) as f64,
    }
}

/// A component as a float: normalized integers per the glTF specification (signed ones
/// clamped at -1), others as they are.
pub fn to_f32(v: f64, c: Ct, normalized: bool) -> f32 {
    if !normalized {
        return v as f32;
    }
    (match c {
        Ct::I8 => (v / 127.0).max(-1.0),
        Ct::U8 => v / 255.0,
        Ct::I16 => (v / 32767.0).max(-1.0),
        Ct::U16 => v / 65535.0,
        Ct::U32 | Ct::F32 => v,
    }) as f32
}

/// A component as an integer (only called for integer component types).
pub fn to_u32(v: f64, _c: Ct, _normalized: bool) -> u32 {
    v as u32
}

/// The buffers of a document, each cut to its declared `byteLength`.
pub struct Buffers(pub Vec<gltf::buffer::Data>);

pub fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            let hex = std::str::from_utf8(&b[i + 1..i + 3])
                .ok()
                .and_then(|h| u8::from_str_radix(h, 16).ok());
            if let Some(v) = hex {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Loads every buffer: the GLB BIN chunk, a base64 data URI, or an external file beside the
/// glTF (`base`; `None` when loading from memory, where an external file is an error). A
/// buffer must hold its declared `byteLength` and no more than that rounded up to 4 bytes
/// (the GLB chunk padding); views are then checked against the declared length.
pub fn load_buffers(
    doc: &gltf::Document,
    mut blob: Option<Vec<u8>>,
    base: Option<&Path>,
) -> Result<Buffers, String> {
    let root = doc.as_json();
    let mut out = Vec::with_capacity(root.buffers.len());
    for (b, buffer) in root.buffers.iter().enumerate() {
        let declared = buffer.byte_length.0;
        let data: Vec<u8> = match buffer.uri.as_deref() {
            None => blob.take().ok_or_else(|| {
                format!("buffer {b} has no uri and the file has no (unused) GLB BIN chunk for it")
            })?,
            Some(uri) if uri.starts_with("data:") => {
                gltf::buffer::Data::from_source_and_blob(
                    gltf::buffer::Source::Uri(uri),
                    None,
                    &mut None,
                )
                .map_err(|e| format!("buffer {b}: its data URI cannot be decoded: {e}"))?
                .0
            }
            Some(uri) if uri.contains("://") || uri.starts_with('/') => {
                return Err(format!(
                    "buffer {b} has uri '{uri}': only data URIs and paths relative to the \
                     glTF file are read"
                ));
            }
            Some(uri) => {
                let Some(dir) = base else {
                    return Err(format!(
                        "buffer {b} is the external file '{uri}', which cannot be read when \
                         loading from memory (load the file from its path)"
                    ));
                };
                let file = dir.join(percent_decode(uri));
                std::fs::read(&file).map_err(|e| {
                    format!(
                        "buffer {b}: its external file {} cannot be read: {e}",
                        file.display()
                    )
                })?
            }
        };
        let actual = data.len() as u64;
        if actual < declared {
            return Err(format!(
                "buffer {b} declares byteLength {declared}, but its data has only {actual} bytes"
            ));
        }
        if actual > declared.div_ceil(4) * 4 {
            return Err(format!(
                "buffer {b} declares byteLength {declared}, but its data has {actual} bytes: \
                 the declared length does not describe the data"
            ));
        }
        let mut data = data;
        data.truncate(declared as usize);
        out.push(gltf::buffer::Data(data));
    }
    Ok(Buffers(out))
}

/// The bytes of buffer view `vi`, checked to lie inside its buffer.
pub fn view_bytes<'b>(
    root: &json::Root,
    buffers: &'b Buffers,
    vi: usize,
) -> Result<(&'b [u8], Option<u64>), String> {
    let view = root
        .buffer_views
        .get(vi)
        .ok_or_else(|| format!("buffer view {vi} does not exist"))?;
    let b = view.buffer.value();
    let buf = buffers
        .0
        .get(b)
        .ok_or_else(|| format!("buffer view {vi} refers to buffer {b}, which does not exist"))?;
    let (vo, vl) = (view.byte_offset.map_or(0, |o| o.0), view.byte_length.0);
    let end = vo.checked_add(vl).filter(|&e| e <= buf.0.len() as u64);
    let Some(end) = end else {
        return Err(format!(
            "buffer view {vi} (byteOffset {vo}, byteLength {vl}) points past the end of \
             buffer {b} ({} bytes)",
            buf.0.len()
        ));
    };
    Ok((
        &buf.0[vo as usize..end as usize],
        view.byte_stride.map(|s| s.0 as u64),
    ))
}

/// The span of `count` elements of `elem` bytes from `offset` in view `vi`, with the view's
/// stride (or tightly packed): (bytes from the first element, stride).
#[allow(clippy::too_many_arguments)]
fn span<'b>(
    root: &json::Root,
    buffers: &'b Buffers,
    vi: usize,
    offset: u64,
    count: u64,
    elem: u64,
    align: u64,
    tight: bool,
) -> Result<(&'b [u8], u64), String> {
    let (bytes, view_stride) = view_bytes(root, buffers, vi)?;
    let stride = if tight {
        elem
    } else {
        view_stride.unwrap_or(elem)
    };
    if stride < elem {
        return Err(format!(
            "buffer view {vi} has byteStride {stride}, less than the element size {elem}"
        ));
    }
    let view_start = root.buffer_views[vi].byte_offset.map_or(0, |o| o.0);
    if !(view_start + offset).is_multiple_of(align) || !stride.is_multiple_of(align) {
        return Err(format!(
            "data at byte {} of its buffer (stride {stride}) is not aligned to its \
             {align}-byte components",
            view_start + offset
        ));
    }
    let need = (offset as u128) + (stride as u128) * (count as u128 - 1) + elem as u128;
    if need > bytes.len() as u128 {
        return Err(format!(
            "{count} elements of {elem} bytes (stride {stride}) from byteOffset {offset} need \
             {need} bytes, but buffer view {vi} has {}: the accessor points past its buffer view",
            bytes.len()
        ));
    }
    Ok((&bytes[offset as usize..], stride))
}

/// Reads accessor `ai` as `N` components per element, after checking that its form is one
/// of `allowed` and that its data lies inside its view and buffer. `conv` turns a decoded
/// component into the output type ([`to_f32`] or [`to_u32`]).
pub fn read<T: Copy, const N: usize>(
    root: &json::Root,
    buffers: &Buffers,
    ai: usize,
    allowed: &[Form],
    conv: fn(f64, Ct, bool) -> T,
) -> Result<Vec<[T; N]>, String> {
    let at = |m: String| format!("accessor {ai}: {m}");
    let acc = root
        .accessors
        .get(ai)
        .ok_or_else(|| format!("accessor {ai} does not exist"))?;
    let (Checked::Valid(ct), Checked::Valid(ty)) = (&acc.component_type, &acc.type_) else {
        return Err(at("unknown componentType or type".into()));
    };
    let form = (ct.0, *ty, acc.normalized);
    if !allowed.contains(&form) {
        let names: Vec<String> = allowed.iter().map(|f| form_name(*f)).collect();
        return Err(at(format!(
            "is {}; glTF allows here only {}",
            form_name(form),
            names.join(" or ")
        )));
    }
    let (c, rows) = (ct.0, shape(*ty).1);
    let (col_stride, elem) = layout(c, *ty);
    if (shape(*ty).0 * rows) as usize != N {
        return Err(at(format!(
            "{} components per element, expected {N}",
            shape(*ty).0 * rows
        )));
    }
    let cs = ct_size(c);
    let comp_offset = |k: usize| (k as u64 / rows) * col_stride + (k as u64 % rows) * cs;
    let count = acc.count.0;
    if count == 0 {
        return Err(at("count is 0 (glTF requires at least 1)".into()));
    }
    let zero = conv(0.0, c, acc.normalized);
    let mut out: Vec<[T; N]> = match acc.buffer_view {
        Some(vi) => {
            let offset = acc.byte_offset.map_or(0, |o| o.0);
            let (bytes, stride) =
                span(root, buffers, vi.value(), offset, count, elem, cs, false).map_err(at)?;
            (0..count)
                .map(|i| {
                    let e = &bytes[(i * stride) as usize..];
                    std::array::from_fn(|k| {
                        conv(decode(&e[comp_offset(k) as usize..], c), c, acc.normalized)
                    })
                })
                .collect()
        }
        None => {
            if count > MAX_IMPLICIT_ELEMENTS {
                return Err(at(format!(
                    "has no buffer view and count {count}; at most {MAX_IMPLICIT_ELEMENTS} \
                     implicit (zero) elements are accepted"
                )));
            }
            if acc.sparse.is_none() {
                return Err(at("has neither a buffer view nor sparse values".into()));
            }
            vec![[zero; N]; count as usize]
        }
    };
    if let Some(sp) = &acc.sparse {
        let sc = sp.count.0;
        if sc == 0 || sc > count {
            return Err(at(format!(
                "sparse count {sc} is not in 1..={count} (the accessor's count)"
            )));
        }
        let ic = match &sp.indices.component_type {
            Checked::Valid(t) if matches!(t.0, Ct::U8 | Ct::U16 | Ct::U32) => t.0,
            Checked::Valid(t) => {
                return Err(at(format!(
                    "sparse indices are {}; glTF allows UNSIGNED_BYTE, UNSIGNED_SHORT or \
                     UNSIGNED_INT",
                    ct_name(t.0)
                )));
            }
            Checked::Invalid => return Err(at("sparse indices have an unknown type".into())),
        };
        let ics = ct_size(ic);
        let (ib, _) = span(
            root,
            buffers,
            sp.indices.buffer_view.value(),
            sp.indices.byte_offset.0,
            sc,
            ics,
            ics,
            true,
        )
        .map_err(|m| at(format!("sparse indices: {m}")))?;
        let (vb, _) = span(
            root,
            buffers,
            sp.values.buffer_view.value(),
            sp.values.byte_offset.0,
            sc,
            elem,
            cs,
            true,
        )
        .map_err(|m| at(format!("sparse values: {m}")))?;
        let mut prev: Option<u64> = None;
        for j in 0..sc {
            let idx = decode(&ib[(j * ics) as usize..], ic) as u64;
            if idx >= count {
                return Err(at(format!(
                    "sparse index {j} is {idx}, beyond the accessor's {count} elements"
                )));
            }
            if let Some(p) = prev.filter(|&p| idx <= p) {
                return Err(at(format!(
                    "sparse indices are not strictly increasing ({idx} follows {p})"
                )));
            }
            prev = Some(idx);
            let e = &vb[(j * elem) as usize..];
            out[idx as usize] = std::array::from_fn(|k| {
                conv(decode(&e[comp_offset(k) as usize..], c), c, acc.normalized)
            });
        }
    }
    Ok(out)
}

/// The element count of accessor `ai` (0 if it does not exist).
pub fn count(root: &json::Root, ai: usize) -> u64 {
    root.accessors.get(ai).map_or(0, |a| a.count.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_columns_are_padded_to_four_bytes() {
        assert_eq!(layout(Ct::U8, Type::Mat2), (4, 8));
        assert_eq!(layout(Ct::U8, Type::Mat3), (4, 12));
        assert_eq!(layout(Ct::I16, Type::Mat3), (8, 24));
        assert_eq!(layout(Ct::F32, Type::Mat4), (16, 64));
        assert_eq!(layout(Ct::U16, Type::Vec3), (6, 6));
    }

    #[test]
    fn normalized_integers_follow_the_spec() {
        assert_eq!(to_f32(255.0, Ct::U8, true), 1.0);
        assert_eq!(to_f32(-128.0, Ct::I8, true), -1.0);
        assert_eq!(to_f32(-32768.0, Ct::I16, true), -1.0);
        assert_eq!(to_f32(65535.0, Ct::U16, true), 1.0);
        assert_eq!(to_f32(7.0, Ct::U8, false), 7.0);
    }

    #[test]
    fn uris_are_percent_decoded() {
        assert_eq!(percent_decode("a%20b.bin"), "a b.bin");
        assert_eq!(percent_decode("100%"), "100%");
        assert_eq!(percent_decode("x%2"), "x%2");
        assert_eq!(percent_decode("%zz"), "%zz");
    }
}
