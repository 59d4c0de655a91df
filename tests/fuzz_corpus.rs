//! The fuzz targets' committed inputs, replayed on stable Rust through the same functions the
//! cargo-fuzz targets call (fuzz/src/lib.rs): the seeds (small valid files of every format,
//! which must load) and every input a fuzzer ever crashed on (fuzz/regressions/TARGET/),
//! which must be refused with a message naming the file, without a panic.

#[path = "../fuzz/src/lib.rs"]
mod targets;

use std::path::{Path, PathBuf};

fn inputs(kind: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(kind)
        .join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = entries.map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// Runs `f` on the file's bytes, failing the test (with the file named) on a panic.
fn replay(f: targets::Target, path: &Path) -> targets::Outcome {
    let bytes = std::fs::read(path).unwrap();
    std::panic::catch_unwind(|| f(&bytes))
        .unwrap_or_else(|_| panic!("{} panicked the loader", path.display()))
}

#[test]
fn every_seed_loads() {
    for (name, f) in targets::TARGETS {
        let seeds = inputs("seeds", name);
        assert!(!seeds.is_empty(), "target {name} has no seeds");
        for s in seeds {
            if let Err(e) = replay(f, &s) {
                panic!("seed {} is refused: {e}", s.display());
            }
        }
    }
    targets::clean_scratch();
}

/// Scratch file names the targets write their input to (the error must name it).
fn scratch_names(target: &str) -> &'static [&'static str] {
    match target {
        "gltf" => &["in.glb"],
        "obj" => &["in.obj"],
        "off" => &["in.off"],
        "ply" => &["in.ply"],
        "sph" => &["in.sph"],
        "envmap" => &["in.exr", "in.hdr"],
        "transfer" => &["transfer.bin", "transfer.cpca", "visibility.bin"],
        "btf_json" => &[""], // parsed from bytes: no file
        "btf_image" => &["image."],
        _ => &["btf"],
    }
}

#[test]
fn every_crash_input_is_refused_naming_the_file() {
    let mut count = 0;
    for (name, f) in targets::TARGETS {
        for r in inputs("regressions", name) {
            count += 1;
            match replay(f, &r) {
                Ok(()) => {} // a loader may accept it now that it is read right
                Err(e) => assert!(
                    scratch_names(name).iter().any(|n| e.contains(n)),
                    "{}: the message does not name the file: {e}",
                    r.display()
                ),
            }
        }
    }
    targets::clean_scratch();
    eprintln!("{count} regression inputs replayed");
}

/// A small deterministic generator (xorshift64*), so a failure names a case that reruns.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Values that break arithmetic: as 4-byte words (f32 3e38, NaN, inf, -1, u32::MAX, 1e9) and
/// as text for the text formats.
const WORDS: [u32; 7] = [
    0x7f61_7c2f, // 3e38
    0x7fc0_0000, // NaN
    0x7f80_0000, // inf
    0xbf80_0000, // -1.0
    u32::MAX,
    1_000_000_000,
    0,
];
const TEXT: [&str; 8] = [
    "1e39",
    "nan",
    "inf",
    "-1",
    "0",
    "4294967296",
    "1e20",
    "99999999999",
];

/// One random mutation of `b`: a bit flip, an extreme word, an extreme number in text, a
/// truncation, a deleted or duplicated chunk (the kinds the campaign used).
fn mutate(rng: &mut Rng, b: &mut Vec<u8>) {
    if b.is_empty() {
        b.push(rng.next() as u8);
        return;
    }
    let at = rng.below(b.len());
    match rng.below(6) {
        0 => b[at] ^= 1 << rng.below(8),
        1 => {
            let w = WORDS[rng.below(WORDS.len())].to_le_bytes();
            for (i, x) in w.iter().enumerate() {
                if let Some(y) = b.get_mut(at + i) {
                    *y = *x;
                }
            }
        }
        2 => {
            // Replace the run of digits at or after `at` with an extreme number.
            let Some(s) = (at..b.len()).find(|&i| b[i].is_ascii_digit()) else {
                return;
            };
            let e = (s..b.len())
                .find(|&i| !b[i].is_ascii_digit() && b[i] != b'.')
                .unwrap_or(b.len());
            let t = TEXT[rng.below(TEXT.len())].as_bytes();
            b.splice(s..e, t.iter().copied());
        }
        3 => b.truncate(at),
        4 => {
            let n = rng.below(64).min(b.len() - at);
            b.drain(at..at + n);
        }
        _ => {
            let n = rng.below(256).min(b.len() - at);
            let chunk: Vec<u8> = b[at..at + n].to_vec();
            let to = rng.below(b.len());
            b.splice(to..to, chunk);
        }
    }
}

/// The fuzz smoke run every CI run affords (coverage-guided runs are `tools/fuzz.sh`'s, on
/// nightly): each seed mutated `VKSHADE_FUZZ_SMOKE` times (default 150; one to four
/// mutations each, seeded so that a failure reruns), through every target. Nothing may panic,
/// and every refusal names the file. A case that fails here belongs in fuzz/regressions/.
#[test]
fn mutated_seeds_never_panic() {
    let per_seed: usize = std::env::var("VKSHADE_FUZZ_SMOKE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(150);
    // VKSHADE_FUZZ_SMOKE_TARGETS=a,b runs only those targets.
    let only = std::env::var("VKSHADE_FUZZ_SMOKE_TARGETS").unwrap_or_default();
    let mut runs = 0;
    for (name, f) in targets::TARGETS {
        if !only.is_empty() && !only.split(',').any(|t| t == name) {
            continue;
        }
        for s in inputs("seeds", name) {
            let seed = std::fs::read(&s).unwrap();
            let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ seed.len() as u64);
            // The BTF directory target rereads 6561 images per case: a tenth as many.
            let n = if name == "btf_dir" {
                per_seed / 10
            } else {
                per_seed
            };
            for case in 0..n {
                let mut b = seed.clone();
                for _ in 0..1 + rng.below(4) {
                    mutate(&mut rng, &mut b);
                }
                runs += 1;
                let out = std::panic::catch_unwind(|| f(&b)).unwrap_or_else(|_| {
                    let keep = std::env::temp_dir().join(format!("vkshade-smoke-{name}-{case}"));
                    let _ = std::fs::write(&keep, &b);
                    panic!(
                        "{name}: mutation {case} of {} panicked; input kept at {}",
                        s.display(),
                        keep.display()
                    )
                });
                if let Err(e) = out {
                    let named = scratch_names(name).iter().any(|n| e.contains(n));
                    let short = name == "btf_dir" && (b.len() < 3 || b.starts_with(b"btf_"));
                    assert!(
                        named || short || name == "btf_json",
                        "{name}: mutation {case} of {}: the message does not name the file: {e}",
                        s.display()
                    );
                }
            }
        }
    }
    targets::clean_scratch();
    eprintln!("{runs} mutated inputs, no panic");
}
