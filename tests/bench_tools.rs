//! `vkshade bench compare` and `bench table` on synthetic `bench all` JSONs with known noise
//! (no GPU), and a smoke run of `bench all` under the validation layer.

mod scratch;
use std::path::{Path, PathBuf};
use std::process::Command;

fn vkshade(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_vkshade"))
        .args(args)
        .output()
        .expect("run vkshade");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn temp(name: &str) -> PathBuf {
    scratch::dir("bench-tools").join(name)
}

/// Median, type-7 quartiles and relative IQR of `values`, as `bench all` writes them.
fn figure(name: &str, higher_is_better: bool, values: &[f64]) -> serde_json::Value {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let q = |p: f64| {
        let x = p * (v.len() - 1) as f64;
        let i = x.floor() as usize;
        v[i] + (v[(i + 1).min(v.len() - 1)] - v[i]) * x.fract()
    };
    let (q1, m, q3) = (q(0.25), q(0.5), q(0.75));
    serde_json::json!({
        "name": name, "unit": "u", "higher_is_better": higher_is_better,
        "values": values, "median": m, "q1": q1, "q3": q3,
        "iqr_rel": (q3 - q1) / m, "noisy": (q3 - q1) / m > 0.1,
    })
}

/// A `bench all` JSON with an `ao.fps` figure of `fps` and a steady FMA peak.
fn run_json(name: &str, fps: &[f64]) -> PathBuf {
    let v = serde_json::json!({
        "benchmark": "all",
        "date": "2026-12-02T00:00:00Z",
        "machine": {"device": "synthetic", "driver": "none", "host_cpus": 2},
        "config": {"rounds": fps.len()},
        "peak_before": {"fma_gflops": 50.0, "bandwidth_gb_s": 2.0},
        "peak_after": {"fma_gflops": 50.0, "bandwidth_gb_s": 2.0},
        "kernels": [{
            "kernel": "ao", "headline": "synthetic",
            "fps": figure("ao.fps", true, fps),
            "roofline": {"binding": "buffer_gather_coherent", "fma_fraction": 0.1},
            "binding_fraction": figure("ao.binding_fraction", true, &[0.5, 0.5, 0.5]),
            "vs_cpu": figure("ao.vs_cpu", true, &[1.0, 1.0, 1.0]),
            "target": "MISS", "target_fps": 143.0,
        }],
        "figures": [
            figure("ao.fps", true, fps),
            figure("peak.fma", true, &[50e9, 50e9]),
        ],
    });
    let path = temp(name);
    std::fs::write(&path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    path
}

fn compare(a: &Path, b: &Path, threshold: &str) -> (bool, String, String) {
    vkshade(&[
        "bench",
        "compare",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--threshold",
        threshold,
    ])
}

fn verdict_of(stdout: &str) -> &str {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("ao.fps"))
        .unwrap_or_else(|| panic!("no ao.fps line in:\n{stdout}"));
    line.split("  ").last().unwrap().trim()
}

#[test]
fn compare_flags_a_regression_beyond_noise_and_threshold_and_exits_non_zero() {
    // A: 100 fps +-1% (IQR 1%); B: 90 fps +-1%: 10% slower, far beyond both spreads and a
    // 5% threshold.
    let a = run_json("a.json", &[99.0, 100.0, 100.5, 101.0, 99.5]);
    let b = run_json("b_slow.json", &[89.0, 90.0, 90.5, 91.0, 89.5]);
    let (ok, stdout, stderr) = compare(&a, &b, "5");
    assert!(!ok, "a 10% regression must fail:\n{stdout}");
    assert_eq!(verdict_of(&stdout), "REGRESSION", "{stdout}");
    assert!(stderr.contains("ao.fps"), "{stderr}");
    // The same change under a 20% threshold: worse, beyond noise, not a failure.
    let (ok, stdout, _) = compare(&a, &b, "20");
    assert!(ok, "{stdout}");
    assert_eq!(verdict_of(&stdout), "worse (within threshold)");
    // Reversed: an improvement.
    let (ok, stdout, _) = compare(&b, &a, "5");
    assert!(ok, "{stdout}");
    assert_eq!(verdict_of(&stdout), "better");
}

#[test]
fn compare_does_not_call_a_change_inside_either_runs_noise_a_regression() {
    // B's median is 8% lower, but B's own rounds spread 40% (IQR / median): not evidence.
    let a = run_json("a2.json", &[99.0, 100.0, 100.5, 101.0, 99.5]);
    let b = run_json("b_noisy.json", &[60.0, 75.0, 92.0, 105.0, 120.0]);
    let (ok, stdout, stderr) = compare(&a, &b, "5");
    assert!(ok, "{stdout}\n{stderr}");
    assert_eq!(verdict_of(&stdout), "within noise");
    // Same run against itself: every figure within noise, the peaks too.
    let (ok, stdout, _) = compare(&a, &a, "0");
    assert!(ok, "{stdout}");
    assert!(stdout.contains("0 regression(s)"), "{stdout}");
}

#[test]
fn compare_and_table_refuse_bad_files_naming_them() {
    let bad = temp("not_all.json");
    std::fs::write(&bad, r#"{"benchmark": "peak"}"#).unwrap();
    let a = run_json("a3.json", &[100.0, 100.0, 100.0]);
    let (ok, _, stderr) = compare(&a, &bad, "5");
    assert!(!ok);
    assert!(
        stderr.contains("not_all.json") && stderr.contains("figures"),
        "{stderr}"
    );
    let missing = temp("missing.json");
    let (ok, _, stderr) = compare(&missing, &a, "5");
    assert!(!ok);
    assert!(stderr.contains("missing.json"), "{stderr}");
    let (ok, _, stderr) = compare(&a, &a, "nan");
    assert!(!ok);
    assert!(stderr.contains("--threshold"), "{stderr}");
    let (ok, _, stderr) = vkshade(&["bench", "table", bad.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("not_all.json"), "{stderr}");
}

#[test]
fn table_is_generated_from_the_json() {
    let a = run_json("t.json", &[99.0, 100.0, 101.0]);
    let (ok, stdout, stderr) = vkshade(&["bench", "table", a.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("**synthetic**"), "{stdout}");
    assert!(stdout.contains("FMA 50.0 / 50.0 GFLOP/s"), "{stdout}");
    assert!(
        stdout.contains("| ao | synthetic | 100.0 (1.0%) | buffer_gather_coherent | 50.0% | 10.0% | 1.00x | MISS (>= 143) |"),
        "{stdout}"
    );
}

#[test]
fn bench_all_quick_runs_two_kernels_under_validation() {
    let dir = temp("all");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "bench",
        "all",
        "--json",
        dir.to_str().unwrap(),
        "--quick",
        "--kernels",
        "ao,btf",
    ]);
    assert!(ok, "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("all.json")).unwrap()).unwrap();
    let kernels = v["kernels"].as_array().unwrap();
    assert_eq!(kernels.len(), 2);
    for k in kernels {
        let fps = k["fps"]["median"].as_f64().unwrap();
        assert!(fps.is_finite() && fps > 0.0, "{k}");
        let binding = k["roofline"]["binding"].as_str().unwrap();
        assert_ne!(binding, "none", "{k}");
        let f = k["binding_fraction"]["median"].as_f64().unwrap();
        // A fraction of a measured peak: positive; a kernel cannot beat the roofline by
        // more than the probes' own noise, but --quick probes are too short to bound it.
        assert!(f.is_finite() && f > 0.0, "{k}");
    }
    // Peaks before and after, every probe in both.
    let probes = v["peak_before"]["probes"].as_array().unwrap().len();
    assert!(probes >= 30, "{probes} probes");
    assert_eq!(v["peak_after"]["probes"].as_array().unwrap().len(), probes);
    // The table and the figures bench compare reads.
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(
        summary.contains("| ao |") && summary.contains("| btf |"),
        "{summary}"
    );
    let (ok, stdout, _) = vkshade(&[
        "bench",
        "compare",
        dir.join("all.json").to_str().unwrap(),
        dir.join("all.json").to_str().unwrap(),
    ]);
    assert!(ok && stdout.contains("0 regression(s)"), "{stdout}");
}
