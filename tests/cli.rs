//! The command-line tool, run as a user would.

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

fn temp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("vkshade-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn info_lists_devices_limits_and_validation_layer() {
    let (ok, stdout, stderr) = vkshade(&["info"]);
    assert!(ok, "{stderr}");
    for needle in [
        "validation layer VK_LAYER_KHRONOS_validation: installed",
        "maxStorageBufferRange",
        "maxImageDimension2D / 3D",
        "timestamps",
        "usable by vkshade: yes",
    ] {
        assert!(stdout.contains(needle), "missing '{needle}' in:\n{stdout}");
    }
}

#[test]
fn bench_peak_writes_json_and_plot_under_validation() {
    let json = temp("peak.json");
    let png = temp("peak.png");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "bench",
        "peak",
        "--json",
        json.to_str().unwrap(),
        "--plot",
        png.to_str().unwrap(),
        "--samples",
        "2",
        "--warmup",
        "0",
        "--min-ms",
        "5",
    ]);
    assert!(ok, "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let fma = v["fma_gflops"].as_f64().expect("fma_gflops");
    let bw = v["bandwidth_gb_s"].as_f64().expect("bandwidth_gb_s");
    assert!(fma.is_finite() && fma > 0.0, "fma_gflops = {fma}");
    assert!(bw.is_finite() && bw > 0.0, "bandwidth_gb_s = {bw}");
    assert!(!v["machine"]["device"].as_str().unwrap_or("").is_empty());
    assert_eq!(v["fma"]["gpu_ms"]["n"].as_u64(), Some(2));
    let png_bytes = std::fs::read(&png).unwrap();
    assert_eq!(&png_bytes[1..4], b"PNG");
}

#[test]
fn bad_options_fail_with_a_message() {
    let (ok, _, stderr) = vkshade(&["bench", "peak", "--samples", "0"]);
    assert!(!ok);
    assert!(stderr.contains("--samples"), "{stderr}");
    let (ok, _, stderr) = vkshade(&["--device", "no-such-device-xyz", "bench", "peak"]);
    assert!(!ok);
    assert!(stderr.contains("no-such-device-xyz"), "{stderr}");
    let (ok, _, stderr) = vkshade(&[
        "bench",
        "peak",
        "--json",
        "/dev/null/x/y.json",
        "--samples",
        "1",
        "--min-ms",
        "1",
        "--warmup",
        "0",
    ]);
    assert!(!ok);
    assert!(stderr.contains("/dev/null/x"), "{stderr}");
    assert!(
        !stderr.contains("stream:"),
        "output paths must be checked before the run: {stderr}"
    );
}
