//! Writing results to disk, shared by every layer that writes files (the CLI runs, the
//! benchmark harness, the shader tool, the scene writers): atomic writes, an up-front
//! writability check, JSON, (feature `exr`) linear float images, and the encodings and
//! cache formats behind them (BC1 textures, half floats, the SRBF transfer cache).

pub mod bc1;
#[cfg(feature = "exr")]
pub mod exr;
pub mod f16;
pub mod finite;
#[cfg(feature = "png")]
pub mod image_bounds;
pub mod outdir;
pub mod panic_scope;
pub mod transfer_cache;

use crate::error::{Error, Result};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The temporary name `write_atomic` uses for `path`: same folder (so the rename stays on
/// one file system), unique per process and call.
fn temp_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(
        ".{name}.tmp{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ))
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed to
/// disk, then renamed over `path`. Readers see the old file or the whole new one, never a
/// part; on failure the temporary file is removed. The folder is created if missing.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    let tmp = temp_path(path);
    let written = std::fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(&tmp, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Checks up front that a file can be created at `path` (its folder is made if missing), so
/// a long run does not fail at the end.
pub fn check_writable(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let probe = dir.join(format!(".vkshade-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|e| Error::io(dir, e))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Writes `value` as pretty JSON (with a final newline), atomically. A NaN or infinity
/// anywhere in it is refused, naming its path in the value (JSON has no such numbers, and
/// `serde_json` would write `null`); nothing is written then.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    if let Some((at, v)) = finite::first_non_finite(value) {
        let at = if at.is_empty() {
            "the value".into()
        } else {
            at
        };
        return Err(Error::input(
            path,
            format!("not written: {at} is {v}, not a finite number"),
        ));
    }
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::input(path, format!("JSON encoding failed: {e}")))?;
    write_atomic(path, format!("{text}\n").as_bytes())
}

/// A linear floating-point RGBA image, rows top to bottom (what `io::exr` reads and writes,
/// with the `exr` feature).
#[derive(Clone, Debug, PartialEq)]
pub struct FloatImage {
    pub width: u32,
    pub height: u32,
    /// `width * height` pixels, row-major.
    pub pixels: Vec<[f32; 4]>,
}

impl FloatImage {
    /// A `width` x `height` image filled with `value`.
    pub fn new(width: u32, height: u32, value: [f32; 4]) -> FloatImage {
        FloatImage {
            width,
            height,
            pixels: vec![value; width as usize * height as usize],
        }
    }

    /// The pixel at (x, y), if inside.
    pub fn get(&self, x: u32, y: u32) -> Option<[f32; 4]> {
        (x < self.width && y < self.height).then(|| self.pixels[(y * self.width + x) as usize])
    }

    /// Sets the pixel at (x, y); outside the image, nothing happens.
    pub fn set(&mut self, x: u32, y: u32, value: [f32; 4]) {
        if x < self.width && y < self.height {
            self.pixels[(y * self.width + x) as usize] = value;
        }
    }
}
