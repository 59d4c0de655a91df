//! Output directories are never destroyed (issue 21, point 2): every command that writes a
//! directory writes into a new or empty one, or one it made before (its `.vkshade-output`
//! marker), and refuses anything else, leaving what is there byte for byte.

mod scratch;
use std::path::{Path, PathBuf};
use std::process::Command;

fn vkshade(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_vkshade"))
        .args(args)
        .output()
        .expect("run vkshade");
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

fn scratch(tag: &str) -> PathBuf {
    scratch::fresh(&format!("outputs-{tag}"))
}

/// Every entry under `dir` (relative path -> bytes; folders as None), sorted.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Option<Vec<u8>>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(dir).unwrap().to_path_buf();
            if p.is_dir() {
                stack.push(p.clone());
                out.push((rel, None));
            } else {
                out.push((rel, Some(std::fs::read(&p).unwrap())));
            }
        }
    }
    out.sort();
    out
}

fn synth(out: &Path) -> (bool, String) {
    vkshade(&[
        "btf",
        "synth",
        "--pattern",
        "weave",
        "--size",
        "4",
        "-o",
        out.to_str().unwrap(),
    ])
}

#[test]
fn btf_synth_refuses_an_existing_file_and_leaves_it() {
    let d = scratch("file");
    let f = d.join("notes.txt");
    std::fs::write(&f, b"my notes\n").unwrap();
    let before = snapshot(&d);
    let (ok, text) = synth(&f);
    assert!(!ok, "{text}");
    assert!(
        text.contains("notes.txt") && text.contains("not a directory"),
        "{text}"
    );
    // No hidden `.notes.txt.old<PID>`, no temporary folder: the folder is as it was.
    assert_eq!(snapshot(&d), before);
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn btf_synth_and_tile_refuse_a_foreign_directory_and_leave_its_files() {
    let d = scratch("foreign");
    let foreign = d.join("photos");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("a.jpg"), [0u8, 1, 2, 255]).unwrap();
    std::fs::create_dir(foreign.join("sub")).unwrap();
    std::fs::write(foreign.join("sub/b.txt"), b"keep me").unwrap();
    let before = snapshot(&d);
    let (ok, text) = synth(&foreign);
    assert!(!ok, "{text}");
    assert!(
        text.contains("photos") && text.contains(".vkshade-output"),
        "{text}"
    );
    assert_eq!(snapshot(&d), before);

    // `btf tile` from a real sample into the same foreign folder: refused the same way.
    let sample = d.join("sample");
    let (ok, text) = vkshade(&[
        "btf",
        "synth",
        "--pattern",
        "rib",
        "--size",
        "8",
        "--period",
        "4",
        "-o",
        sample.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let (ok, text) = vkshade(&[
        "btf",
        "tile",
        "--btf",
        sample.to_str().unwrap(),
        "-o",
        foreign.to_str().unwrap(),
    ]);
    assert!(!ok, "{text}");
    assert!(text.contains("photos"), "{text}");
    assert_eq!(
        snapshot(&foreign),
        before
            .iter()
            .filter_map(|(p, b)| p
                .strip_prefix("photos")
                .ok()
                .filter(|r| !r.as_os_str().is_empty())
                .map(|r| (r.to_path_buf(), b.clone())))
            .collect::<Vec<_>>()
    );
    // A tile into a new folder works and is marked as the tile's.
    let tile = d.join("tile");
    let (ok, text) = vkshade(&[
        "btf",
        "tile",
        "--btf",
        sample.to_str().unwrap(),
        "-o",
        tile.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let marker = std::fs::read_to_string(tile.join(".vkshade-output")).unwrap();
    assert!(marker.contains("command: btf tile"), "{marker}");
    // The sample made by `btf synth` is not the tile's to replace.
    let (ok, text) = vkshade(&[
        "btf",
        "tile",
        "--btf",
        sample.to_str().unwrap(),
        "-o",
        sample.to_str().unwrap(),
    ]);
    assert!(!ok, "{text}");
    assert!(text.contains("vkshade btf synth"), "{text}");
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn btf_synth_writes_an_empty_directory_and_replaces_its_own_output() {
    let d = scratch("own");
    let out = d.join("weave");
    std::fs::create_dir(&out).unwrap();
    let (ok, text) = synth(&out);
    assert!(ok, "{text}");
    let marker = std::fs::read_to_string(out.join(".vkshade-output")).unwrap();
    assert!(marker.contains("command: btf synth"), "{marker}");
    let images = |dir: &Path| {
        std::fs::read_dir(dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .starts_with("btf_")
            })
            .count()
    };
    assert_eq!(images(&out), 6561);
    // A rerun replaces the set whole (a stale file of the old set goes), and leaves no
    // temporary or old folder beside it.
    std::fs::write(out.join("stale.txt"), b"from the first run").unwrap();
    let (ok, text) = synth(&out);
    assert!(ok, "{text}");
    assert!(!out.join("stale.txt").exists());
    assert_eq!(images(&out), 6561);
    let siblings: Vec<String> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(siblings, vec!["weave".to_string()]);
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn run_directories_follow_the_same_rule() {
    let d = scratch("run");
    // An existing file as `ao --out`: refused, untouched.
    let f = d.join("report");
    std::fs::write(&f, b"not a folder").unwrap();
    let foreign = d.join("mine");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("report.json"), b"{\"mine\": true}").unwrap();
    let before = snapshot(&d);
    for out in [&f, &foreign] {
        let (ok, text) = vkshade(&[
            "ao",
            "--frames",
            "1",
            "--correction-rays",
            "16",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(!ok, "{text}");
        assert!(text.contains(out.to_str().unwrap()), "{text}");
    }
    assert_eq!(snapshot(&d), before);
    // A fresh folder, then the same command again into it: both run.
    let run = d.join("ao");
    for _ in 0..2 {
        let (ok, text) = vkshade(&[
            "ao",
            "--frames",
            "1",
            "--correction-rays",
            "16",
            "--out",
            run.to_str().unwrap(),
        ]);
        assert!(ok, "{text}");
    }
    assert!(run.join("report.json").is_file());
    // Another command is refused there.
    let (ok, text) = vkshade(&["sss", "--frames", "1", "--out", run.to_str().unwrap()]);
    assert!(!ok, "{text}");
    assert!(text.contains("vkshade ao"), "{text}");
    let _ = std::fs::remove_dir_all(d);
}
