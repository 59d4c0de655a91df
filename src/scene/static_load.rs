//! Static meshes: Wavefront OBJ, PLY (ASCII and binary), OFF. Polygons are triangulated as
//! fans. Errors name the file and the line (text formats) or element (binary PLY).

use super::mesh::{MAX_COORDINATE, MeshData};
use crate::error::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

fn text<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|_| Error::input(path, "not a UTF-8 text file"))
}

/// Refuses a position beyond [`MAX_COORDINATE`] at `line` of a text file.
fn check_position(p: &[f32; 3], path: &Path, line: usize) -> Result<()> {
    if p.iter().any(|c| c.abs() > MAX_COORDINATE) {
        return Err(Error::input(
            path,
            format!(
                "line {line}: vertex {p:?} is beyond the coordinate bound \u{b1}{MAX_COORDINATE:e}"
            ),
        ));
    }
    Ok(())
}

fn name_of(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>) {
    for k in 1..poly.len().saturating_sub(1) {
        out.push([poly[0], poly[k], poly[k + 1]]);
    }
}

fn parse_f32s<const N: usize>(
    it: &mut std::str::SplitWhitespace<'_>,
    path: &Path,
    line: usize,
    what: &str,
) -> Result<[f32; N]> {
    let mut out = [0f32; N];
    for o in out.iter_mut() {
        let tok = it
            .next()
            .ok_or_else(|| Error::input(path, format!("line {line}: {what} needs {N} numbers")))?;
        *o = tok.parse().map_err(|_| {
            Error::input(
                path,
                format!("line {line}: '{tok}' is not a number in {what}"),
            )
        })?;
        if !o.is_finite() {
            return Err(Error::input(
                path,
                format!("line {line}: '{tok}' in {what} is not a finite (32-bit) number"),
            ));
        }
    }
    Ok(out)
}

/// Wavefront OBJ: `v`, `vt`, `vn`, `f` (with `v`, `v/t`, `v//n`, `v/t/n` and negative
/// indices). A vertex is a distinct (position, uv, normal) triple.
pub fn load_obj(path: &Path) -> Result<MeshData> {
    parse_obj(path, &read(path)?)
}

/// As [`load_obj`], from memory; `path` only names the source in errors.
pub fn parse_obj(path: &Path, bytes: &[u8]) -> Result<MeshData> {
    let text = text(path, bytes)?;
    let (mut v, mut vt, mut vn) = (Vec::new(), Vec::new(), Vec::new());
    let mut corners: HashMap<(u32, i64, i64), u32> = HashMap::new();
    let mut data = MeshData {
        name: name_of(path),
        ..Default::default()
    };
    let (mut pos, mut uv, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
    let (mut any_uv_missing, mut any_n_missing) = (false, false);
    for (ln, raw) in text.lines().enumerate() {
        let line = ln + 1;
        let mut it = raw.split_whitespace();
        match it.next() {
            Some("v") => {
                let p = parse_f32s::<3>(&mut it, path, line, "vertex")?;
                check_position(&p, path, line)?;
                v.push(p)
            }
            Some("vt") => vt.push(parse_f32s::<2>(&mut it, path, line, "texture coordinate")?),
            Some("vn") => vn.push(parse_f32s::<3>(&mut it, path, line, "normal")?),
            Some("f") => {
                let mut poly = Vec::new();
                for tok in it {
                    let mut parts = tok.split('/');
                    let resolve = |s: Option<&str>, n: usize, what: &str| -> Result<Option<i64>> {
                        match s {
                            None | Some("") => Ok(None),
                            Some(s) => {
                                let i: i64 = s.parse().map_err(|_| {
                                    Error::input(
                                        path,
                                        format!("line {line}: bad {what} index '{s}'"),
                                    )
                                })?;
                                let idx = if i < 0 { n as i64 + i } else { i - 1 };
                                if i == 0 || idx < 0 || idx >= n as i64 {
                                    return Err(Error::input(
                                        path,
                                        format!(
                                            "line {line}: {what} index {i} out of range (1..={n})"
                                        ),
                                    ));
                                }
                                Ok(Some(idx))
                            }
                        }
                    };
                    let pi = resolve(parts.next(), v.len(), "vertex")?.ok_or_else(|| {
                        Error::input(path, format!("line {line}: face corner without a vertex"))
                    })?;
                    let ti = resolve(parts.next(), vt.len(), "texture")?;
                    let ni = resolve(parts.next(), vn.len(), "normal")?;
                    let key = (pi as u32, ti.unwrap_or(-1), ni.unwrap_or(-1));
                    let idx = *corners.entry(key).or_insert_with(|| {
                        pos.push(v[pi as usize]);
                        match ti {
                            Some(t) => uv.push(vt[t as usize]),
                            None => {
                                any_uv_missing = true;
                                uv.push([0.0; 2]);
                            }
                        }
                        match ni {
                            Some(n) => nrm.push(vn[n as usize]),
                            None => {
                                any_n_missing = true;
                                nrm.push([0.0; 3]);
                            }
                        }
                        (pos.len() - 1) as u32
                    });
                    poly.push(idx);
                }
                if poly.len() < 3 {
                    return Err(Error::input(
                        path,
                        format!("line {line}: face with {} corners", poly.len()),
                    ));
                }
                fan(&poly, &mut data.triangles);
            }
            _ => {}
        }
    }
    data.positions = pos;
    data.uvs = (!any_uv_missing).then_some(uv);
    data.normals = (!any_n_missing).then_some(nrm);
    Ok(data)
}

/// Object File Format: `OFF`, counts, vertices, then faces as `n i0 i1 ...`.
pub fn load_off(path: &Path) -> Result<MeshData> {
    parse_off(path, &read(path)?)
}

/// As [`load_off`], from memory; `path` only names the source in errors.
pub fn parse_off(path: &Path, bytes: &[u8]) -> Result<MeshData> {
    let text = text(path, bytes)?;
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.split('#').next().unwrap_or("").trim()))
        .filter(|(_, l)| !l.is_empty());
    let (ln, header) = lines
        .next()
        .ok_or_else(|| Error::input(path, "empty file"))?;
    let rest_of_header = header
        .strip_prefix("OFF")
        .ok_or_else(|| Error::input(path, format!("line {ln}: missing OFF header")))?
        .trim();
    let (ln, counts) = if rest_of_header.is_empty() {
        lines
            .next()
            .ok_or_else(|| Error::input(path, "missing counts line"))?
    } else {
        (ln, rest_of_header)
    };
    let c: Vec<usize> = counts
        .split_whitespace()
        .map(|t| t.parse())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::input(path, format!("line {ln}: bad counts '{counts}'")))?;
    if c.len() < 2 {
        return Err(Error::input(
            path,
            format!("line {ln}: expected 'vertices faces edges'"),
        ));
    }
    let mut data = MeshData {
        name: name_of(path),
        ..Default::default()
    };
    for _ in 0..c[0] {
        let (ln, l) = lines
            .next()
            .ok_or_else(|| Error::input(path, format!("file ends before {} vertices", c[0])))?;
        let p = parse_f32s::<3>(&mut l.split_whitespace(), path, ln, "vertex")?;
        check_position(&p, path, ln)?;
        data.positions.push(p);
    }
    for _ in 0..c[1] {
        let (ln, l) = lines
            .next()
            .ok_or_else(|| Error::input(path, format!("file ends before {} faces", c[1])))?;
        let nums: Vec<u32> = l
            .split_whitespace()
            .map(|t| t.parse())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| Error::input(path, format!("line {ln}: bad face '{l}'")))?;
        let n = *nums.first().unwrap_or(&0) as usize;
        if n < 3 || nums.len() < n + 1 {
            return Err(Error::input(path, format!("line {ln}: bad face '{l}'")));
        }
        fan(&nums[1..=n], &mut data.triangles);
    }
    Ok(data)
}

#[derive(Clone, Copy, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn read(self, b: &[u8], big: bool) -> f64 {
        macro_rules! rd {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().expect("sized");
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => rd!(i16, 2),
            Scalar::U16 => rd!(u16, 2),
            Scalar::I32 => rd!(i32, 4),
            Scalar::U32 => rd!(u32, 4),
            Scalar::F32 => rd!(f32, 4),
            Scalar::F64 => rd!(f64, 8),
        }
    }
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    scalar: Scalar,
    /// Count type of a list property.
    list: Option<Scalar>,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// PLY: `ascii`, `binary_little_endian` or `binary_big_endian`; vertex `x y z` (optional
/// `nx ny nz`, `u v` / `s t`), face `vertex_indices` / `vertex_index` lists.
pub fn load_ply(path: &Path) -> Result<MeshData> {
    Ok(load_ply_with_properties(path)?.0)
}

/// As [`load_ply`], from memory; `path` only names the source in errors.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<MeshData> {
    Ok(parse_ply_with_properties(path, bytes)?.0)
}

/// As [`load_ply`], also returning every scalar vertex property by name (e.g. `ao`).
/// Every scalar vertex property must be finite as a 32-bit float, and `x y z` within
/// [`MAX_COORDINATE`].
pub fn load_ply_with_properties(path: &Path) -> Result<(MeshData, HashMap<String, Vec<f32>>)> {
    parse_ply_with_properties(path, &read(path)?)
}

/// As [`load_ply_with_properties`], from memory; `path` only names the source in errors.
pub fn parse_ply_with_properties(
    path: &Path,
    bytes: &[u8],
) -> Result<(MeshData, HashMap<String, Vec<f32>>)> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| Error::input(path, "no end_header: not a PLY file"))?;
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|_| Error::input(path, "header is not text"))?;
    let mut body_start = end + 10;
    while body_start < bytes.len() && bytes[body_start] != b'\n' {
        body_start += 1;
    }
    body_start += 1;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, l) in header.lines().enumerate() {
        let t: Vec<&str> = l.split_whitespace().collect();
        let bad = || Error::input(path, format!("header line {}: '{l}'", i + 1));
        match t.as_slice() {
            ["ply"] | [] => {}
            ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count.parse().map_err(|_| bad())?,
                props: Vec::new(),
            }),
            ["property", "list", ct, it, name] => {
                elements.last_mut().ok_or_else(bad)?.props.push(Property {
                    name: name.to_string(),
                    scalar: Scalar::parse(it).ok_or_else(bad)?,
                    list: Some(Scalar::parse(ct).ok_or_else(bad)?),
                })
            }
            ["property", ty, name] => elements.last_mut().ok_or_else(bad)?.props.push(Property {
                name: name.to_string(),
                scalar: Scalar::parse(ty).ok_or_else(bad)?,
                list: None,
            }),
            _ => return Err(bad()),
        }
    }
    let format = format.ok_or_else(|| Error::input(path, "header has no format line"))?;
    let (ascii, big) = match format.as_str() {
        "ascii" => (true, false),
        "binary_little_endian" => (false, false),
        "binary_big_endian" => (false, true),
        f => return Err(Error::input(path, format!("unknown PLY format '{f}'"))),
    };
    let body = &bytes[body_start.min(bytes.len())..];
    let text_body = if ascii {
        Some(std::str::from_utf8(body).map_err(|_| Error::input(path, "ASCII body is not text"))?)
    } else {
        None
    };
    // Every element needs at least one token (ASCII) or its fixed bytes (binary): a header
    // declaring more elements than the body can hold is refused before anything is read,
    // and an element with no properties holds no data at all.
    let available = match text_body {
        Some(t) => t.split_whitespace().count() as u128,
        None => body.len() as u128,
    };
    let mut needed: u128 = 0;
    for el in &elements {
        let per_element: u128 = el
            .props
            .iter()
            .map(|p| match (ascii, p.list) {
                (true, _) => 1,
                (false, Some(ct)) => ct.size() as u128,
                (false, None) => p.scalar.size() as u128,
            })
            .sum();
        needed += per_element * el.count as u128;
    }
    if needed > available {
        return Err(Error::input(
            path,
            format!(
                "the header declares elements needing at least {needed} {}, but the body has {available}",
                if ascii { "numbers" } else { "bytes" }
            ),
        ));
    }
    let mut tokens = text_body.map(|t| t.split_whitespace());
    let mut offset = 0usize;
    // Reads one scalar, from text tokens or binary bytes.
    let mut next = |s: Scalar, what: &str| -> Result<f64> {
        if let Some(tok) = tokens.as_mut() {
            let t = tok
                .next()
                .ok_or_else(|| Error::input(path, format!("file ends inside {what}")))?;
            t.parse::<f64>()
                .map_err(|_| Error::input(path, format!("'{t}' is not a number in {what}")))
        } else {
            if offset + s.size() > body.len() {
                return Err(Error::input(path, format!("file ends inside {what}")));
            }
            let v = s.read(&body[offset..], big);
            offset += s.size();
            Ok(v)
        }
    };
    let mut data = MeshData {
        name: name_of(path),
        ..Default::default()
    };
    let (mut normals, mut uvs) = (Vec::new(), Vec::new());
    let mut has_normals = false;
    let mut has_uvs = false;
    let mut vertex_props: HashMap<String, Vec<f32>> = HashMap::new();
    for el in elements.iter().filter(|e| !e.props.is_empty()) {
        let find = |names: &[&str]| {
            el.props
                .iter()
                .position(|p| names.contains(&p.name.as_str()))
        };
        let (xi, yi, zi) = (find(&["x"]), find(&["y"]), find(&["z"]));
        let (nxi, nyi, nzi) = (find(&["nx"]), find(&["ny"]), find(&["nz"]));
        let (ui, vi) = (
            find(&["u", "s", "texture_u"]),
            find(&["v", "t", "texture_v"]),
        );
        let fi = find(&["vertex_indices", "vertex_index"]);
        if el.name == "vertex" {
            if xi.is_none() || yi.is_none() || zi.is_none() {
                return Err(Error::input(path, "vertex element lacks x, y or z"));
            }
            has_normals = nxi.is_some() && nyi.is_some() && nzi.is_some();
            has_uvs = ui.is_some() && vi.is_some();
        }
        for e in 0..el.count {
            let what = format!("{} {e}", el.name);
            let mut vals = vec![0f64; el.props.len()];
            let mut list = Vec::new();
            for (pi, p) in el.props.iter().enumerate() {
                match p.list {
                    None => vals[pi] = next(p.scalar, &what)?,
                    Some(ct) => {
                        let n = next(ct, &what)?;
                        if !(0.0..=1e6).contains(&n) {
                            return Err(Error::input(path, format!("{what}: list length {n}")));
                        }
                        let items: Vec<f64> = (0..n as usize)
                            .map(|_| next(p.scalar, &what))
                            .collect::<Result<_>>()?;
                        if Some(pi) == fi {
                            list = items;
                        }
                    }
                }
            }
            if el.name == "vertex" {
                for (p, v) in el.props.iter().zip(&vals) {
                    if p.list.is_none() && !(*v as f32).is_finite() {
                        return Err(Error::input(
                            path,
                            format!(
                                "{what}: property {} = {v} is not a finite 32-bit number",
                                p.name
                            ),
                        ));
                    }
                }
                for i in [xi, yi, zi].into_iter().flatten() {
                    if (vals[i] as f32).abs() > MAX_COORDINATE {
                        return Err(Error::input(
                            path,
                            format!(
                                "{what}: {} = {} is beyond the coordinate bound \u{b1}{MAX_COORDINATE:e}",
                                el.props[i].name, vals[i]
                            ),
                        ));
                    }
                }
                for (p, v) in el.props.iter().zip(&vals) {
                    if p.list.is_none() {
                        vertex_props
                            .entry(p.name.clone())
                            .or_default()
                            .push(*v as f32);
                    }
                }
                let g = |i: Option<usize>| i.map(|i| vals[i] as f32).unwrap_or(0.0);
                data.positions.push([g(xi), g(yi), g(zi)]);
                normals.push([g(nxi), g(nyi), g(nzi)]);
                uvs.push([g(ui), g(vi)]);
            } else if el.name == "face" {
                if list.len() < 3 {
                    return Err(Error::input(
                        path,
                        format!("{what} has {} corners", list.len()),
                    ));
                }
                if list
                    .iter()
                    .any(|&i| i < 0.0 || i.fract() != 0.0 || i > u32::MAX as f64)
                {
                    return Err(Error::input(
                        path,
                        format!("{what} has a negative, fractional or too large index"),
                    ));
                }
                let poly: Vec<u32> = list.iter().map(|&i| i as u32).collect();
                fan(&poly, &mut data.triangles);
            }
        }
    }
    data.normals = has_normals.then_some(normals);
    data.uvs = has_uvs.then_some(uvs);
    Ok((data, vertex_props))
}
