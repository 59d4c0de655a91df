//! The layer check: which `crate::` paths each module of src/ may use.
//!
//! [`LAYERS`] is the one table of the crate's layers, lowest first. A row names a module (a
//! top-level module of src/, or a submodule with rules of its own) and the paths its code may
//! import; every path a row allows is a row above it, so the layers form an order (checked).
//! A file belongs to the row with the longest name that contains it; it may always use its
//! own row's module. lib.rs's module list must name the top-level rows in the same order.
//!
//! A ground truth (`reference`) may use only the shared layers (`geom`, `scene`, the leaves):
//! the physics a method and its truth share (a BRDF, the diffusion profiles, the synthetic
//! cloth) lives in `geom`, apart from the method itself (its sampling, shaders, GPU glue,
//! CPU twin).
//!
//! Checked: every `crate::` path (use trees expanded, `super::` resolved, `vkshade::` in
//! main.rs) outside comments, strings and `#[cfg(test)]` items: tests may use anything, e.g.
//! a kernel's unit test comparing against its truth. The scanner relies on rustfmt's layout
//! of `#[cfg(test)]` (one attribute, written so).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The layers, lowest first: (module, the paths its code may use). `error` and `progress`
/// are leaves (the error type, the progress line).
const LAYERS: &[(&str, &[&str])] = &[
    ("error", &[]),
    ("progress", &[]),
    ("gpu", &["error"]),
    ("io", &["error"]),
    ("geom", &["error", "progress"]),
    ("shaders", &["error", "gpu", "io"]),
    ("scene", &["error", "progress", "io", "geom"]),
    (
        "kernels",
        &["error", "progress", "gpu", "io", "geom", "shaders", "scene"],
    ),
    (
        "frame",
        &[
            "error", "progress", "gpu", "io", "geom", "shaders", "scene", "kernels",
        ],
    ),
    ("reference", &["error", "progress", "geom", "scene"]),
    ("report", &["error", "gpu", "io"]),
    ("render", &["error", "io"]),
    (
        "bench",
        &[
            "error",
            "progress",
            "gpu",
            "io",
            "geom",
            "shaders",
            "scene",
            "kernels",
            "reference",
            "report",
            "frame",
        ],
    ),
    (
        "app",
        &[
            "error",
            "progress",
            "gpu",
            "io",
            "geom",
            "shaders",
            "scene",
            "kernels",
            "reference",
            "report",
            "render",
            "bench",
            "frame",
        ],
    ),
    // src/main.rs, the `vkshade` binary (it names the library `vkshade::`).
    (
        "main",
        &[
            "error",
            "progress",
            "gpu",
            "io",
            "geom",
            "shaders",
            "scene",
            "kernels",
            "reference",
            "report",
            "render",
            "bench",
            "frame",
            "app",
        ],
    ),
];

/// Imports the table does not allow that are being removed in parallel work: (file, path).
/// Each must still occur (the check says when one can be deleted).
const PENDING: &[(&str, &str)] = &[];

fn segments(path: &str) -> Vec<&str> {
    path.split("::").collect()
}

fn starts_with(path: &[String], prefix: &str) -> bool {
    let p = segments(prefix);
    path.len() >= p.len() && path.iter().zip(&p).all(|(a, b)| a == b)
}

/// One import a row does not allow.
#[derive(Debug, Clone, PartialEq)]
struct Violation {
    file: String,
    line: usize,
    path: String,
    layer: String,
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}:{}: imports crate::{}, which layer `{}` may not use",
            self.file, self.line, self.path, self.layer
        )
    }
}

/// The module path of a source file (`src/kernels/ao/mod.rs` -> [kernels, ao]); main.rs is
/// [main]; None for lib.rs and non-Rust files.
fn module_of(rel: &str) -> Option<Vec<String>> {
    let rest = rel.strip_prefix("src/")?.strip_suffix(".rs")?;
    if rest == "lib" {
        return None;
    }
    let mut parts: Vec<String> = rest.split('/').map(str::to_owned).collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    Some(parts)
}

/// The row a module belongs to: the longest row name that is a prefix of it.
fn row_of(module: &[String]) -> Option<&'static (&'static str, &'static [&'static str])> {
    LAYERS
        .iter()
        .filter(|(name, _)| starts_with(module, name))
        .max_by_key(|(name, _)| segments(name).len())
}

/// `src` with comments and the insides of string and character literals blanked (newlines
/// kept, so offsets and line numbers stay).
fn strip(src: &str) -> Vec<u8> {
    let s = src.as_bytes();
    let mut out = s.to_vec();
    let blank = |out: &mut Vec<u8>, a: usize, b: usize| {
        for c in &mut out[a..b.min(s.len())] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
    };
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        let next = s.get(i + 1).copied();
        if c == b'/' && next == Some(b'/') {
            let end = s[i..]
                .iter()
                .position(|&c| c == b'\n')
                .map_or(s.len(), |p| i + p);
            blank(&mut out, i, end);
            i = end;
        } else if c == b'/' && next == Some(b'*') {
            let (mut depth, mut j) = (1, i + 2);
            while j < s.len() && depth > 0 {
                if s[j] == b'/' && s.get(j + 1) == Some(&b'*') {
                    depth += 1;
                    j += 2;
                } else if s[j] == b'*' && s.get(j + 1) == Some(&b'/') {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if c == b'r' && (i == 0 || !ident(s[i - 1])) && matches!(next, Some(b'"' | b'#')) {
            // A raw string r"..." or r#"..."# (b before r is an identifier character: br"").
            let hashes = s[i + 1..].iter().take_while(|&&c| c == b'#').count();
            if s.get(i + 1 + hashes) != Some(&b'"') {
                i += 1;
                continue;
            }
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            let from = i + 2 + hashes;
            let end = s[from..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(s.len(), |p| from + p + close.len());
            blank(&mut out, i + 1, end);
            i = end;
        } else if c == b'"' {
            let mut j = i + 1;
            while j < s.len() && s[j] != b'"' {
                j += if s[j] == b'\\' { 2 } else { 1 };
            }
            blank(&mut out, i + 1, j);
            i = j + 1;
        } else if c == b'\'' {
            // A character literal ('x', '\n', '\'', 'é') or a lifetime ('a).
            if next == Some(b'\\') {
                let mut j = i + 3;
                while j < s.len() && s[j] != b'\'' {
                    j += 1;
                }
                blank(&mut out, i + 1, j);
                i = j + 1;
            } else {
                let len = src[i + 1..].chars().next().map_or(1, char::len_utf8);
                if s.get(i + 1 + len) == Some(&b'\'') {
                    blank(&mut out, i + 1, i + 1 + len);
                    i += 2 + len;
                } else {
                    i += 1;
                }
            }
        } else {
            i += 1;
        }
    }
    out
}

/// The end of the bracketed group opening at `s[i]` (one past its closing bracket).
fn close_of(s: &[u8], i: usize) -> usize {
    let mut depth = 0usize;
    for (j, &c) in s.iter().enumerate().skip(i) {
        match c {
            b'{' | b'[' | b'(' => depth += 1,
            b'}' | b']' | b')' => {
                depth -= 1;
                if depth == 0 {
                    return j + 1;
                }
            }
            _ => {}
        }
    }
    s.len()
}

/// Blanks every item marked `#[cfg(test)]` (its attributes and its body).
fn drop_tests(s: &mut [u8]) {
    const MARK: &[u8] = b"#[cfg(test)]";
    let mut from = 0;
    while let Some(p) = s[from..].windows(MARK.len()).position(|w| w == MARK) {
        let start = from + p;
        let mut i = start + MARK.len();
        // Further attributes, then the item up to its `;` or its braced body.
        loop {
            while i < s.len() && s[i].is_ascii_whitespace() {
                i += 1;
            }
            if s.get(i) == Some(&b'#') {
                i = close_of(s, i + 1);
            } else {
                break;
            }
        }
        let mut end = s.len();
        let mut j = i;
        while j < s.len() {
            match s[j] {
                b';' => {
                    end = j + 1;
                    break;
                }
                b'(' | b'[' => j = close_of(s, j),
                b'{' => {
                    // `use a::{b, c};` ends at its `;`, an item with a body at its `}`.
                    let item = String::from_utf8_lossy(&s[i..j]);
                    let words: Vec<&str> = item.split_whitespace().collect();
                    if words.contains(&"use") {
                        j = close_of(s, j);
                        continue;
                    }
                    end = close_of(s, j);
                    break;
                }
                _ => j += 1,
            }
        }
        for c in &mut s[start..end] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
        from = end;
    }
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// Whether the word `w` (not a longer identifier) starts at `s[i]`.
fn word_at(s: &[u8], i: usize, w: &[u8]) -> bool {
    s[i..].starts_with(w) && s.get(i + w.len()).is_none_or(|c| !is_ident(*c))
}

fn skip_ws(s: &[u8], mut i: usize) -> usize {
    while i < s.len() && s[i].is_ascii_whitespace() {
        i += 1;
    }
    i
}

fn ident_at(s: &[u8], i: usize) -> Option<(String, usize)> {
    let end = s[i..]
        .iter()
        .position(|&c| !is_ident(c))
        .map_or(s.len(), |p| i + p);
    (end > i).then(|| (String::from_utf8_lossy(&s[i..end]).into_owned(), end))
}

/// Parses the path or use tree at `s[i..]` below `prefix`: every path it names goes to
/// `out` (`a::{b, c::*}` gives a::b and a::c). Returns the index after it.
fn tree(s: &[u8], i: usize, prefix: &[String], out: &mut Vec<Vec<String>>) -> usize {
    let i = skip_ws(s, i);
    match s.get(i) {
        Some(b'{') => {
            let mut j = i + 1;
            loop {
                j = skip_ws(s, j);
                match s.get(j) {
                    Some(b'}') => return j + 1,
                    Some(b',') => j += 1,
                    None => return j,
                    _ => {
                        let k = tree(s, j, prefix, out);
                        if k == j {
                            return close_of(s, i);
                        }
                        j = k;
                    }
                }
            }
        }
        Some(b'*') => {
            out.push(prefix.to_vec());
            i + 1
        }
        _ => {
            let Some((seg, end)) = ident_at(s, i) else {
                return i;
            };
            let j = skip_ws(s, end);
            let mut path = prefix.to_vec();
            if seg != "self" {
                path.push(seg);
            }
            if s[j..].starts_with(b"::") {
                let k = skip_ws(s, j + 2);
                if s.get(k) != Some(&b'<') {
                    return tree(s, k, &path, out);
                }
            }
            out.push(path);
            // `as alias`
            let k = skip_ws(s, end);
            if s[k..].starts_with(b"as") && s.get(k + 2).is_some_and(|c| !is_ident(*c)) {
                return ident_at(s, skip_ws(s, k + 2)).map_or(k + 2, |(_, e)| e);
            }
            end
        }
    }
}

/// Every absolute path the code of `src` names (relative to the crate root), with its line:
/// `crate::` paths (`vkshade::` in main.rs) and `super::` paths, use trees expanded.
fn imports(rel: &str, src: &str) -> Vec<(usize, Vec<String>)> {
    let Some(module) = module_of(rel) else {
        return Vec::new();
    };
    let mut s = strip(src);
    drop_tests(&mut s);
    let root: &[u8] = if rel == "src/main.rs" {
        b"vkshade"
    } else {
        b"crate"
    };
    // The file's module, then inline `mod NAME {` blocks with the brace depth they opened at.
    let mut inline: Vec<(String, usize)> = Vec::new();
    let mut depth = 0usize;
    let mut out = Vec::new();
    let line_of = |i: usize| s[..i].iter().filter(|&&c| c == b'\n').count() + 1;
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        let boundary = i == 0 || !(is_ident(s[i - 1]) || s[i - 1] == b'$' || s[i - 1] == b':');
        if c == b'{' {
            depth += 1;
            i += 1;
        } else if c == b'}' {
            depth = depth.saturating_sub(1);
            while inline.last().is_some_and(|(_, d)| *d > depth) {
                inline.pop();
            }
            i += 1;
        } else if boundary && word_at(&s, i, b"mod") {
            let j = skip_ws(&s, i + 3);
            if let Some((name, end)) = ident_at(&s, j) {
                let k = skip_ws(&s, end);
                if s.get(k) == Some(&b'{') {
                    depth += 1;
                    inline.push((name, depth));
                    i = k + 1;
                    continue;
                }
            }
            i += 3;
        } else if boundary && (word_at(&s, i, root) || word_at(&s, i, b"super")) {
            let here: Vec<String> = module
                .iter()
                .cloned()
                .chain(inline.iter().map(|(n, _)| n.clone()))
                .collect();
            // The path's base (the crate root, or the module `super::`s lead to) and where the
            // rest of it starts.
            let (base, start) = if word_at(&s, i, root) {
                // `pub(in crate::x)` is a visibility, not a use.
                let before = s[..i].trim_ascii_end();
                let j = skip_ws(&s, i + root.len());
                if before.ends_with(b"(in") || !s[j..].starts_with(b"::") {
                    i += root.len();
                    continue;
                }
                (Vec::new(), j + 2)
            } else {
                let (mut up, mut j) = (0, i);
                while word_at(&s, j, b"super") {
                    let k = skip_ws(&s, j + 5);
                    if !s[k..].starts_with(b"::") {
                        break;
                    }
                    up += 1;
                    j = skip_ws(&s, k + 2);
                }
                if up == 0 || up > here.len() {
                    i += 5;
                    continue;
                }
                (here[..here.len() - up].to_vec(), j)
            };
            let mut paths = Vec::new();
            let end = tree(&s, start, &base, &mut paths);
            let line = line_of(i);
            out.extend(paths.into_iter().map(|p| (line, p)));
            i = end.max(i + 1);
        } else {
            i += 1;
        }
    }
    out
}

/// The names lib.rs re-exports at the root (`pub use error::{Error, Result}`), with the
/// paths they stand for.
fn root_reexports(lib: &str) -> BTreeMap<String, Vec<String>> {
    let s = strip(lib);
    let mut map = BTreeMap::new();
    let mut from = 0;
    while let Some(p) = s[from..].windows(8).position(|w| w == b"pub use ") {
        let at = from + p + 8;
        let mut paths = Vec::new();
        from = tree(&s, at, &[], &mut paths).max(at);
        for path in paths {
            if let Some(last) = path.last() {
                map.insert(last.clone(), path.clone());
            }
        }
    }
    map
}

/// The imports of `src` (file `rel`) that its row does not allow.
fn check_source(rel: &str, src: &str, reexports: &BTreeMap<String, Vec<String>>) -> Vec<Violation> {
    let Some(module) = module_of(rel) else {
        return Vec::new();
    };
    let Some((layer, allowed)) = row_of(&module) else {
        return vec![Violation {
            file: rel.to_owned(),
            line: 1,
            path: module.join("::"),
            layer: "(no row in LAYERS)".to_owned(),
        }];
    };
    let mut out = Vec::new();
    for (line, mut path) in imports(rel, src) {
        if path.is_empty() {
            continue;
        }
        if !LAYERS.iter().any(|(name, _)| *name == path[0])
            && let Some(full) = reexports.get(&path[0])
        {
            path.splice(0..1, full.iter().cloned());
        }
        let ok = starts_with(&path, layer) || allowed.iter().any(|a| starts_with(&path, a));
        if !ok {
            out.push(Violation {
                file: rel.to_owned(),
                line,
                path: path.join("::"),
                layer: (*layer).to_owned(),
            });
        }
    }
    out
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// The top-level rows (no `::`), in table order.
fn top_rows() -> Vec<&'static str> {
    LAYERS
        .iter()
        .map(|(name, _)| *name)
        .filter(|n| !n.contains("::"))
        .collect()
}

#[test]
fn every_import_is_allowed_by_its_layer() {
    let reexports = root_reexports(&read("src/lib.rs"));
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    let mut violations = Vec::new();
    for path in &files {
        let rel = path
            .strip_prefix(root())
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        violations.extend(check_source(&rel, &read(&rel), &reexports));
    }
    // Whether violation `v` is the pending import (file, path).
    let is = |v: &Violation, (file, path): &(&str, &str)| {
        v.file == *file && (v.path == *path || v.path.starts_with(&format!("{path}::")))
    };
    let stale: Vec<String> = PENDING
        .iter()
        .filter(|p| !violations.iter().any(|v| is(v, p)))
        .map(|(f, p)| format!("{f}: crate::{p}"))
        .collect();
    let bad: Vec<String> = violations
        .iter()
        .filter(|v| !PENDING.iter().any(|p| is(v, p)))
        .map(Violation::to_string)
        .collect();
    assert!(
        bad.is_empty(),
        "imports across layers (the table is LAYERS in tests/layers.rs):\n{}",
        bad.join("\n")
    );
    assert!(
        stale.is_empty(),
        "PENDING lists imports that no longer occur; delete them from tests/layers.rs: {}",
        stale.join(", ")
    );
}

#[test]
fn the_table_is_an_order() {
    let mut seen: Vec<&str> = Vec::new();
    for (name, allowed) in LAYERS {
        assert!(!seen.contains(name), "{name} has two rows");
        for a in *allowed {
            assert!(
                seen.contains(a),
                "`{name}` may use `{a}`, which is not a row above it"
            );
        }
        seen.push(name);
    }
}

#[test]
fn every_module_has_a_row_and_lib_lists_them_in_order() {
    // The top-level modules: src/*.rs and src/*/ (main.rs is the binary, lib.rs the root).
    let mut on_disk: Vec<String> = std::fs::read_dir(root().join("src"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter_map(|p| {
            let name = p.file_name()?.to_string_lossy().into_owned();
            if p.is_dir() {
                Some(name)
            } else {
                name.strip_suffix(".rs").map(str::to_owned)
            }
        })
        .filter(|n| n != "lib")
        .collect();
    on_disk.sort();
    let mut rows: Vec<String> = top_rows().iter().map(|s| s.to_string()).collect();
    rows.sort();
    assert_eq!(
        on_disk, rows,
        "the modules of src/ and the rows of LAYERS differ"
    );

    let lib = read("src/lib.rs");
    let mut declared: Vec<String> = lib
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';').to_owned())
        .collect();
    declared.sort();
    let mut want: Vec<String> = rows.iter().filter(|r| *r != "main").cloned().collect();
    want.sort();
    assert_eq!(
        declared, want,
        "lib.rs's `pub mod`s and the rows of LAYERS differ"
    );

    // The module-list paragraph of lib.rs's documentation: the modules in backticks, in
    // table order (main.rs, the binary, is not a module of the library).
    let paragraph: Vec<&str> = lib
        .lines()
        .skip_while(|l| !l.starts_with("//! Modules, lowest layer first"))
        .take_while(|l| l.trim() != "//!" && l.starts_with("//!"))
        .collect();
    assert!(
        !paragraph.is_empty(),
        "lib.rs has no paragraph starting \"//! Modules, lowest layer first\""
    );
    let text = paragraph.join(" ");
    let named: Vec<&str> = text
        .split('`')
        .skip(1)
        .step_by(2)
        .filter(|w| w.chars().all(|c| c.is_ascii_lowercase() || c == '_'))
        .collect();
    let order: Vec<&str> = top_rows().into_iter().filter(|r| *r != "main").collect();
    assert_eq!(
        named, order,
        "lib.rs's module list is not the order of LAYERS in tests/layers.rs"
    );
}

// The checker itself, on sources that break each rule.

fn check(rel: &str, src: &str) -> Vec<String> {
    let reexports = root_reexports("pub use error::{Error, Result};");
    check_source(rel, src, &reexports)
        .iter()
        .map(Violation::to_string)
        .collect()
}

#[test]
fn a_kernel_using_its_truth_is_caught() {
    // Correction::bake once called the AO truth; the SRBF kernel took its visibility type.
    let src = "use crate::error::Result;\n\
               fn bake() {\n    let c = crate::reference::ao::RayConfig::for_scene(1.0);\n}\n";
    assert_eq!(
        check("src/kernels/ao/mod.rs", src),
        [
            "src/kernels/ao/mod.rs:3: imports crate::reference::ao::RayConfig::for_scene, \
             which layer `kernels` may not use"
        ]
    );
    let src = "use crate::{gpu::Context, reference::srbf::Visibility};\n";
    assert_eq!(
        check("src/kernels/srbf/gpu.rs", src),
        [
            "src/kernels/srbf/gpu.rs:1: imports crate::reference::srbf::Visibility, which layer \
             `kernels` may not use"
        ]
    );
    // From kernels::ao, super::super is the crate root.
    let src = "use super::super::reference::ErrorStats;\n";
    assert_eq!(check("src/kernels/ao/mod.rs", src).len(), 1);
    // In a test, a kernel may compare against its truth.
    let src = "fn f() {}\n#[cfg(test)]\nmod tests {\n    \
               use crate::reference::sss::brute_force;\n}\n\
               #[cfg(test)]\nuse crate::reference::ErrorStats;\n";
    assert!(check("src/kernels/sss/contact.rs", src).is_empty());
    // Comments, documentation and strings are not imports.
    let src = "/// See [`crate::reference::ao`].\n// crate::bench::x\n\
               const S: &str = \"crate::bench::x\";\nconst R: &str = r#\"crate::bench\"#;\n\
               fn f<'a>(c: char) -> bool { c == '{' }\n";
    assert!(check("src/kernels/ao/mod.rs", src).is_empty());
}

#[test]
fn a_truth_using_a_method_is_caught() {
    // The truths once took the profile through the kernel's re-export, the texture-space
    // geometry, the SG algebra, the CPU twin's filter, the G-buffer and the synthesiser.
    let src = "use crate::kernels::sss::Profile;\n\
               use crate::kernels::sss::texspace::{COVERED, TexGeometry};\n\
               use crate::kernels::srbf::sg::{Lobe, integral};\n\
               use crate::kernels::btf::{cpu::bilinear, gbuffer::Frame, synth::SynthConfig};\n";
    let got = check("src/reference/sss.rs", src);
    let paths: Vec<&str> = got
        .iter()
        .map(|v| {
            v.split(" imports ")
                .nth(1)
                .unwrap()
                .split(',')
                .next()
                .unwrap()
        })
        .collect();
    assert_eq!(
        paths,
        [
            "crate::kernels::sss::Profile",
            "crate::kernels::sss::texspace::COVERED",
            "crate::kernels::sss::texspace::TexGeometry",
            "crate::kernels::srbf::sg::Lobe",
            "crate::kernels::srbf::sg::integral",
            "crate::kernels::btf::cpu::bilinear",
            "crate::kernels::btf::gbuffer::Frame",
            "crate::kernels::btf::synth::SynthConfig",
        ]
    );
    assert!(
        got.iter()
            .all(|v| v.ends_with("which layer `reference` may not use"))
    );
    // Through the shared layers it may, the models a method and its truth share included.
    let src = "use crate::geom::profile::{Profile, ProfileKind};\n\
               use crate::geom::cloth::SynthConfig;\nuse crate::geom::sg::Lobe;\n\
               use crate::scene::texspace::TexGeometry;\nuse crate::Result;\n";
    assert!(check("src/reference/btf.rs", src).is_empty());
    // Not through the kernels' re-export of a shared model: the path names the method.
    assert_eq!(
        check(
            "src/reference/sss.rs",
            "use crate::kernels::sss::profile::Profile;\n"
        )
        .len(),
        1
    );
    // A shared model may not reach into the method either.
    assert_eq!(
        check(
            "src/geom/cloth.rs",
            "use crate::kernels::btf::dirs::Angles;\n"
        ),
        [
            "src/geom/cloth.rs:1: imports crate::kernels::btf::dirs::Angles, which layer \
             `geom` may not use"
        ]
    );
    assert_eq!(
        check(
            "src/geom/profile.rs",
            "use crate::kernels::sss::sampler::TABLE_SIZE;\n"
        )
        .len(),
        1
    );
}

#[test]
fn lower_layers_using_higher_ones_are_caught() {
    assert_eq!(
        check(
            "src/shaders.rs",
            "fn f() {\n    for x in crate::kernels::generated_includes() {}\n}\n"
        ),
        [
            "src/shaders.rs:2: imports crate::kernels::generated_includes, which layer `shaders` \
             may not use"
        ]
    );
    // A kernel timing its passes through the benchmark harness.
    assert_eq!(
        check(
            "src/kernels/shape.rs",
            "pub fn time_passes() { crate::bench::median(&[]); }\n"
        ),
        [
            "src/kernels/shape.rs:1: imports crate::bench::median, which layer `kernels` may not \
             use"
        ]
    );
    assert_eq!(
        check("src/gpu/record.rs", "use crate::io::write_atomic;\n").len(),
        1
    );
    assert_eq!(
        check("src/geom/bvh.rs", "use crate::scene::Mesh;\n").len(),
        1
    );
    // An inline module is one more level for super::, and pub(in crate::x) is not a use.
    let src = "pub mod model {\n    use super::super::super::kernels::Kernel;\n}\n\
               pub(in crate::reference) fn f() {}\n";
    assert_eq!(
        check("src/reference/ao.rs", src),
        [
            "src/reference/ao.rs:2: imports crate::kernels::Kernel, which layer `reference` may \
             not use"
        ]
    );
    // main.rs names the library vkshade::, and may use anything.
    assert!(check("src/main.rs", "use vkshade::app::srbf::AxisAngle;\n").is_empty());
}
