//! Output directories that never destroy anything they did not make.
//!
//! The rule every command that writes a directory follows: it writes into a directory that
//! is missing (made here), empty, or one the same command made before, recognised by the
//! marker file [`MARKER`] it left there naming the command. Anything else (a regular file at
//! the path, a directory holding files but no marker, or one marked by another command) is
//! refused with an error naming the path, before any work runs, and nothing there is touched.
//!
//! Two ways of writing: [`claim`] for commands that write their files one by one into the
//! directory (each file atomically, as [`super::write_atomic`] does), and [`replace`] for
//! commands whose directory is one data set (a BTF): it is built complete in a temporary
//! sibling and renamed into place, so readers see the old set or the whole new one.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The marker file a command leaves in a directory it writes: its first line says what made
/// the directory, its second line the command (`command: <name>`).
pub const MARKER: &str = ".vkshade-output";

/// The marker's text for `command`.
fn marker_text(command: &str) -> String {
    format!(
        "vkshade output directory (safe to overwrite by vkshade {command})\ncommand: {command}\n"
    )
}

/// The command named by the marker in `dir`, if there is one.
fn marked_by(dir: &Path) -> Option<String> {
    let text = std::fs::read_to_string(dir.join(MARKER)).ok()?;
    text.lines()
        .find_map(|l| l.strip_prefix("command: "))
        .map(|c| c.trim().to_string())
}

/// What is at an output path.
#[derive(Clone, Debug, PartialEq, Eq)]
enum State {
    Missing,
    Empty,
    Marked,
}

/// Checks that `command` may write the directory `dir` (see the module doc); refuses with
/// an error naming `dir` otherwise.
fn check(dir: &Path, command: &str) -> Result<State> {
    let meta = match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(State::Missing),
        Err(e) => return Err(Error::io(dir, e)),
        Ok(m) => m,
    };
    // A symlink to a directory is followed (a user may link out/ elsewhere).
    let is_dir = meta.is_dir() || (meta.is_symlink() && dir.is_dir());
    if !is_dir {
        return Err(Error::input(
            dir,
            "exists and is not a directory; refusing to replace it with the output directory \
             (choose another --out, or move the file away)",
        ));
    }
    let mut entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    if entries.next().is_none() {
        return Ok(State::Empty);
    }
    match marked_by(dir) {
        Some(c) if c == command => Ok(State::Marked),
        Some(c) => Err(Error::input(
            dir,
            format!(
                "is the output of `vkshade {c}`, not of `vkshade {command}`; refusing to write \
                 over it (choose another --out, or remove it)"
            ),
        )),
        None => Err(Error::input(
            dir,
            format!(
                "is a directory holding files that vkshade did not write (no {MARKER} marker); \
                 refusing to write into it (choose a new or empty directory for --out)"
            ),
        )),
    }
}

/// Makes `dir` ready for `command` to write its files into: creates it if missing, accepts
/// it if empty or marked by `command`, refuses anything else; leaves the marker in it.
pub fn claim(dir: &Path, command: &str) -> Result<()> {
    if check(dir, command)? == State::Missing {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    super::write_atomic(&dir.join(MARKER), marker_text(command).as_bytes())
}

/// Checks, without changing anything, that [`claim`] or [`replace`] by `command` would
/// accept `dir` (to refuse before a long run).
pub fn check_claimable(dir: &Path, command: &str) -> Result<()> {
    check(dir, command).map(|_| ())
}

/// Writes the directory `dir` as one piece: checks it as [`claim`] does, calls `build` on a
/// fresh temporary sibling, adds the marker, then swaps the finished sibling into place
/// (the old directory, empty or marked by `command`, is removed only after that). On any
/// failure the temporary sibling is removed and `dir` is as it was.
pub fn replace(dir: &Path, command: &str, build: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    check(dir, command)?;
    let name = dir
        .file_name()
        .ok_or_else(|| Error::input(dir, "not a directory name"))?
        .to_string_lossy()
        .into_owned();
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    let tmp = fresh_sibling(&parent, &name, "tmp")?;
    let built = build(&tmp)
        .and_then(|()| super::write_atomic(&tmp.join(MARKER), marker_text(command).as_bytes()))
        // Checked again: files may have appeared in `dir` while `build` ran.
        .and_then(|()| check(dir, command));
    let state = match built {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    let old = if state == State::Missing {
        None
    } else {
        let old = parent.join(format!(".{name}.old{}-{}", std::process::id(), unique()));
        if let Err(e) = std::fs::rename(dir, &old) {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(Error::io(dir, e));
        }
        Some(old)
    };
    if let Err(e) = std::fs::rename(&tmp, dir) {
        // Put the old one back; the new one is dropped.
        if let Some(old) = &old {
            let _ = std::fs::rename(old, dir);
        }
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(Error::io(dir, e));
    }
    if let Some(old) = old {
        // Only vkshade's own files (or nothing) were in it: `check` said so.
        let _ = std::fs::remove_dir_all(old);
    }
    Ok(())
}

/// A counter making temporary names unique within the process.
fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    COUNTER.fetch_add(1, Ordering::Relaxed)
}

/// A new, empty directory `.{name}.{tag}<pid>-<n>` in `parent`, made with `create_dir` (so
/// an existing path of that name is never reused or removed).
fn fresh_sibling(parent: &Path, name: &str, tag: &str) -> Result<PathBuf> {
    for _ in 0..64 {
        let p = parent.join(format!(".{name}.{tag}{}-{}", std::process::id(), unique()));
        match std::fs::create_dir(&p) {
            Ok(()) => return Ok(p),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(Error::io(&p, e)),
        }
    }
    Err(Error::input(
        parent,
        format!("could not make a temporary directory for '{name}'"),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("vkshade-outdir-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn claim_accepts_missing_empty_and_own_and_refuses_the_rest() {
        let d = scratch("claim");
        let fresh = d.join("fresh");
        claim(&fresh, "ao").unwrap();
        assert!(fresh.join(MARKER).is_file());
        claim(&fresh, "ao").unwrap();
        let e = claim(&fresh, "sss").unwrap_err().to_string();
        assert!(e.contains("vkshade ao") && e.contains("fresh"), "{e}");
        let empty = d.join("empty");
        std::fs::create_dir(&empty).unwrap();
        claim(&empty, "ao").unwrap();
        let foreign = d.join("foreign");
        std::fs::create_dir(&foreign).unwrap();
        std::fs::write(foreign.join("notes.txt"), b"mine").unwrap();
        let e = claim(&foreign, "ao").unwrap_err().to_string();
        assert!(e.contains("foreign") && e.contains("did not write"), "{e}");
        assert!(!foreign.join(MARKER).exists());
        let file = d.join("file");
        std::fs::write(&file, b"data").unwrap();
        let e = claim(&file, "ao").unwrap_err().to_string();
        assert!(e.contains("not a directory"), "{e}");
        assert_eq!(std::fs::read(&file).unwrap(), b"data");
        let _ = std::fs::remove_dir_all(d);
    }

    #[test]
    fn replace_swaps_only_when_complete_and_keeps_the_old_on_failure() {
        let d = scratch("replace");
        let out = d.join("set");
        replace(&out, "btf synth", |t| {
            std::fs::write(t.join("a"), b"1").map_err(|e| Error::io(t, e))
        })
        .unwrap();
        assert_eq!(std::fs::read(out.join("a")).unwrap(), b"1");
        // A failing rebuild leaves the first set and no temporary folder.
        let e = replace(&out, "btf synth", |_| {
            Err(Error::InvalidArgument("boom".into()))
        });
        assert!(e.is_err());
        assert_eq!(std::fs::read(out.join("a")).unwrap(), b"1");
        let names: Vec<_> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("set")], "{names:?}");
        // A rebuild replaces it whole.
        replace(&out, "btf synth", |t| {
            std::fs::write(t.join("b"), b"2").map_err(|e| Error::io(t, e))
        })
        .unwrap();
        assert!(!out.join("a").exists());
        assert_eq!(std::fs::read(out.join("b")).unwrap(), b"2");
        let _ = std::fs::remove_dir_all(d);
    }
}
