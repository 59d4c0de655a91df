//! The test binaries' scratch folders: `vkshade-scratch-NAME-PID` under the temp folder, one
//! per name and process (tests of one binary run in parallel threads of one process). The
//! first call in a process sweeps away the scratch folders of earlier runs whose process has
//! ended (where the OS lists its processes in /proc), so that repeated `cargo test` runs do
//! not pile folders up; the last run's stay for a look until the next run.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::Once;

const PREFIX: &str = "vkshade-scratch-";

static SWEEP: Once = Once::new();

/// The scratch folder `name` of this process (created; kept as it is if it exists).
pub fn dir(name: &str) -> PathBuf {
    SWEEP.call_once(sweep);
    let d = path(name);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// As [`dir`], emptied first.
pub fn fresh(name: &str) -> PathBuf {
    SWEEP.call_once(sweep);
    let d = path(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("{PREFIX}{name}-{}", std::process::id()))
}

/// Removes `vkshade-scratch-*-PID` folders whose process PID no longer runs.
fn sweep() {
    let procs = Path::new("/proc");
    if !procs.join("self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(PREFIX)) else {
            continue;
        };
        let Some(pid) = rest.rsplit('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        let stale = pid != std::process::id() && !procs.join(pid.to_string()).exists();
        if stale && entry.path().is_dir() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}
