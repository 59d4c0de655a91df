//! The command-line tool, run as a user would.

mod scratch;
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
    scratch::dir("cli").join(name)
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
    // Every probe either ran (a positive rate with its quartiles) or says why not; lavapipe
    // runs all 34 (it filters every format it samples).
    let probes = v["probes"].as_array().expect("probes");
    let skipped = v["skipped_probes"].as_array().expect("skipped_probes");
    assert_eq!(probes.len() + skipped.len(), 34, "{skipped:?}");
    for p in probes {
        let rate = p["rate_per_s"].as_f64().unwrap_or(f64::NAN);
        assert!(rate.is_finite() && rate > 0.0, "{p}");
        assert!(
            p["gpu_ms"]["q1"].as_f64() <= p["gpu_ms"]["q3"].as_f64(),
            "{p}"
        );
    }
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

#[test]
fn ao_writes_frames_and_report_under_validation() {
    let out = temp("ao");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "ao",
        "--frames",
        "2",
        "--reference",
        "--rays",
        "256",
        "--correction-rays",
        "256",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    assert!(stdout.contains("vs ray-traced mesh: MAE"), "{stdout}");
    for f in [
        "ao_0000.ply",
        "ao_0000.png",
        "ao_0000.exr",
        "ao_0001.ply",
        "ao_0001.png",
        "ao_0001.exr",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["mesh"]["vertices"], 3205);
    assert_eq!(v["tree"]["spheres_total"], 585);
    assert_eq!(v["animation"], "Wuson_Run");
    let f0 = &v["frames"][0];
    for key in ["skin_ms", "ao_ms"] {
        assert!(f0["gpu"][key].as_f64().unwrap() > 0.0, "{key}");
    }
    assert!(f0["spheres_used_per_vertex"]["mean"].as_f64().unwrap() > 1.0);
    for key in ["mae", "rmse", "p95", "max"] {
        assert!(f0["reference"]["error"][key].as_f64().is_some(), "{key}");
    }
    assert!(!v["machine"]["device"].as_str().unwrap().is_empty());
}

#[test]
fn ao_with_a_prebuilt_tree_and_a_static_mesh() {
    let sph = temp("wuson.sph");
    let (ok, stdout, stderr) = vkshade(&[
        "spheretree",
        "build",
        "data/testwuson.glb",
        "-o",
        sph.to_str().unwrap(),
        "--depth",
        "2",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("volume coverage") && stdout.contains("surface coverage"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&sph).unwrap();
    assert!(
        text.starts_with("3 8\n"),
        "Dublin .sph header: levels incl. root, branch"
    );
    let out = temp("ao-tree");
    let (ok, _, stderr) = vkshade(&[
        "--validate",
        "ao",
        "--tree",
        sph.to_str().unwrap(),
        "--frames",
        "1",
        "--correction-rays",
        "64",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["tree"]["spheres_per_level"], serde_json::json!([8, 64]));
    // A static OBJ (no skin, no animation): one frame in the rest pose.
    let obj = temp("tetra.obj");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let out = temp("ao-static");
    let (ok, _, stderr) = vkshade(&[
        "--validate",
        "ao",
        "--mesh",
        obj.to_str().unwrap(),
        "--frames",
        "5",
        "--correction-rays",
        "64",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    assert!(out.join("ao_0000.ply").is_file() && !out.join("ao_0001.ply").exists());
}

#[test]
fn ao_bad_input_fails_cleanly_without_output() {
    let out = temp("ao-bad");
    for (args, needle) in [
        (
            vec!["ao", "--mesh", "/nonexistent/thing.glb"],
            "/nonexistent/thing.glb",
        ),
        (vec!["ao", "--tau", "2"], "tau"),
        (vec!["ao", "--anim", "Gallop"], "Wuson_Run"),
        (
            vec!["ao", "--tree", "/nonexistent/t.sph"],
            "/nonexistent/t.sph",
        ),
        (vec!["ao", "--blend", "max"], "unknown blend"),
        (vec!["ao", "--frames", "0"], "--frames"),
        (vec!["ao", "--frames", "100000000000"], "--frames"),
        (vec!["ao", "--rays", "0", "--reference"], "--rays"),
    ] {
        let mut a = args.clone();
        a.extend(["--out", out.to_str().unwrap()]);
        let (ok, _, stderr) = vkshade(&a);
        assert!(!ok, "{args:?} succeeded");
        assert!(
            stderr.contains(needle),
            "{args:?}: stderr lacks '{needle}':\n{stderr}"
        );
        assert!(
            !out.join("report.json").exists(),
            "{args:?} left output behind"
        );
    }
    let (ok, stdout, _) = vkshade(&["mesh", "info", "data/testwuson.glb"]);
    assert!(
        ok && stdout.contains("Wuson_Run") && stdout.contains("\"vertices\": 3205"),
        "{stdout}"
    );
}

#[test]
fn bench_ao_reports_sweeps_baselines_and_targets() {
    let json = temp("ao-bench.json");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "bench",
        "ao",
        "--quick",
        "--samples",
        "1",
        "--warmup",
        "0",
        "--min-ms",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stderr.contains("validation: clean (0 messages)"),
        "{stderr}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let h = &v["headline"];
    for key in [
        "fps",
        "gflops",
        "fraction_of_peak",
        "spheres_used_per_vertex",
    ] {
        let x = h[key].as_f64().unwrap_or(f64::NAN);
        assert!(x.is_finite() && x > 0.0, "headline {key} = {x}");
    }
    assert!(v["peak_fma_gflops"].as_f64().unwrap() > 0.0);
    assert!(v["speedup_vs_cpu"].as_f64().unwrap() > 0.0);
    assert!(v["speedup_vs_raytrace"].as_f64().unwrap() > 0.0);
    assert_eq!(v["vertex_sweep"].as_array().unwrap().len(), 2);
    assert_eq!(v["sphere_sweep"].as_array().unwrap().len(), 2);
    let taus = v["tau_sweep"].as_array().unwrap();
    assert_eq!(taus.len(), 6);
    assert!(taus.iter().all(|p| p["mae"].as_f64().is_some()));
    // More vertices cost more; a deeper tree means more spheres per vertex.
    let vs = v["vertex_sweep"].as_array().unwrap();
    assert!(vs[1]["vertices"].as_u64() > vs[0]["vertices"].as_u64());
    let ss = v["sphere_sweep"].as_array().unwrap();
    assert!(ss[1]["spheres_used_per_vertex"].as_f64() > ss[0]["spheres_used_per_vertex"].as_f64());
    // fps, MAE, memory and the speed-up over the CPU twin (the last two timed in one run).
    let targets = v["targets"].as_array().unwrap();
    assert_eq!(targets.len(), 4);
    assert!(
        targets.iter().any(|t| t.to_string().contains("CPU twin")),
        "{targets:?}"
    );
}

/// `srbf shade` on the bunny (the default mesh) under Blender's studio light `light`, from
/// `x:START` about +X for `frames` frames, under validation, with the ray-cast truth: each
/// frame's relative L2 error against it, whether the run read its visibility, its
/// transfer and that transfer's compression from the cache in `dir`, and its stderr.
fn srbf_bunny_spun_about_x(
    dir: &std::path::Path,
    light: &str,
    start_deg: u32,
    frames: u32,
) -> (Vec<f64>, bool, String) {
    let env = format!("/usr/share/blender/datafiles/studiolights/world/{light}.exr");
    let rotate = format!("x:{start_deg}");
    let frames_arg = frames.to_string();
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "srbf",
        "shade",
        "--env",
        &env,
        "--rotate",
        &rotate,
        "--frames",
        &frames_arg,
        "--reference",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok, "{light}: {stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{light}: {stderr}");
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert!(
        v["mesh"]
            .as_str()
            .unwrap_or_default()
            .ends_with("bunny.obj"),
        "{}",
        v["mesh"]
    );
    let errors: Vec<f64> = v["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["vs_ground_truth"]["all"].as_f64().unwrap())
        .collect();
    assert_eq!(errors.len(), frames as usize);
    let cached =
        v["visibility_cached"] == true && v["transfer_cached"] == true && v["cpca_cached"] == true;
    (errors, cached, stderr)
}

/// The README's off-grid figures spun about +X on its own mesh, the bunny, with defaults
/// otherwise. One test, so that the eight runs share an output folder: the visibility, the
/// transfer and its compression (the mesh's alone) are computed by the first run and read
/// from the cache by the six after it, as a user's next run would (which is checked too);
/// the last run finds the visibility damaged, warns and casts it again.
///
/// First its claim "<= 4.6% spun about +X": Blender's night (the worst of the eight lights
/// there) at 90 and 270 degrees, the rotations that do not map the 64 x 32 directions onto
/// themselves (the README's `--rotate x:0 --frames 4`: 0.013, 0.035, 0.014, 0.046).
/// Measured 0.0347 and 0.0458. The fit, the transfer and its compression are deterministic
/// and the GPU matches the CPU to 3e-7, so the README's 4.6% is the bound (a rounding margin
/// only): past it the README is wrong. Catches: an error that grows off the grid past the
/// claim (a sun between the directions whose visibility the method holds), which the
/// Testwuson tests only bound at 13%.
///
/// Then its per-light figures for the other seven lights (its "worst frame per light" of
/// `--rotate x:0 --frames 4`), each at the rotation where it is reached: 270 degrees, or 90
/// for courtyard (measured 0.0269, 0.0276, 0.0180, 0.0400, 0.0334, 0.0430, 0.0108). Bound:
/// the README's figure plus half its last digit (deterministic, as above), and every one
/// within the 5% target. Catches: a light-dependent regression (a sun's compact-lobe path, a
/// dim map's negative-sample repair) that night alone would not show.
#[test]
fn srbf_spun_about_x_keeps_the_readmes_figures_on_the_bunny() {
    let dir = temp("srbf-spin-x");
    let (errors, _, _) = srbf_bunny_spun_about_x(&dir, "night", 90, 2);
    eprintln!("bunny, night, x:90 and x:270 vs ground truth: {errors:?}");
    assert!(
        errors.iter().all(|&e| e <= 0.0465),
        "README claims <= 4.6%: {errors:?}"
    );
    let mut worse = Vec::new();
    for (light, start_deg, readme) in [
        ("city", 270, 0.027),
        ("courtyard", 90, 0.028),
        ("forest", 270, 0.018),
        ("interior", 270, 0.040),
        ("studio", 270, 0.033),
        ("sunrise", 270, 0.043),
        ("sunset", 270, 0.011),
    ] {
        // Before the last run the cached visibility is damaged (one byte flipped): that run
        // says so on stderr (the binary's logger), casts the visibility again and keeps
        // its figure.
        let damaged = light == "sunset";
        if damaged {
            let path = dir.join("visibility.bin");
            let mut bytes = std::fs::read(&path).unwrap();
            let mid = bytes.len() / 2;
            bytes[mid] ^= 0x10;
            std::fs::write(&path, bytes).unwrap();
        }
        let (e, cached, stderr) = srbf_bunny_spun_about_x(&dir, light, start_deg, 1);
        if damaged {
            assert!(!cached, "{light}: a damaged visibility read from the cache");
            assert!(
                stderr.contains("warning:") && stderr.contains("casting the visibility again"),
                "{light}: no warning for the damaged cache: {stderr}"
            );
        } else {
            assert!(
                cached,
                "{light}: the visibility, transfer or compression the first run cached was not \
                 reused"
            );
        }
        let e = e[0];
        eprintln!("bunny, {light}, x:{start_deg} vs ground truth: {e:.4} (README {readme})");
        if e > readme + 0.0005 || e > 0.05 {
            worse.push(format!(
                "{light} at x:{start_deg}: {e:.4} (README {readme})"
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(worse.is_empty(), "past the README: {worse:?}");
}

#[test]
fn srbf_shade_writes_ply_png_and_report_and_refuses_bad_input() {
    let dir = temp("srbf-cli");
    let mesh = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "srbf",
        "shade",
        "--mesh",
        mesh.to_str().unwrap(),
        "--lobes",
        "16",
        "--basis",
        "64",
        "--directions",
        "32",
        "--frames",
        "2",
        "--reference",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    for f in [
        "shade_0000.ply",
        "shade_0001.png",
        "report.json",
        "transfer.bin",
        "transfer.cpca",
    ] {
        assert!(dir.join(f).exists(), "{f} missing");
    }
    let ply = std::fs::read(dir.join("shade_0001.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..400.min(ply.len())]).into_owned();
    assert!(
        header.contains("property float r\nproperty float g\nproperty float b"),
        "{header}"
    );
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["frames"].as_array().map(Vec::len), Some(2));
    eprintln!(
        "srbf vs ground truth: {}",
        v["frames"][1]["vs_ground_truth"]
    );
    // Measured 0.030 (0.024 / 0.022 / 0.039 per channel): the fit, the transfer and its
    // compression are deterministic, so the margin only covers the GPU's f32 shading and a
    // changed default; the old bound (0.1) let the error triple unnoticed.
    assert!(v["frames"][1]["vs_ground_truth"]["all"].as_f64().unwrap() < 0.04);
    assert!(v["frames"][0]["gpu_ms_shade"].as_f64().unwrap() > 0.0);
    assert_eq!(v["kernel"]["passes"][0]["name"], "srbf lighting");
    assert_eq!(v["kernel"]["passes"][1]["name"], "srbf project");
    assert_eq!(v["kernel"]["passes"][2]["name"], "srbf sharp");
    assert!(v["frames"][0]["gpu_ms_project"].as_f64().unwrap() > 0.0);
    assert!(v["frames"][0]["gpu_ms_sharp"].as_f64().unwrap() > 0.0);
    assert_eq!(
        v["sun"], "grid",
        "the default shadows compact lobes from the grid"
    );
    // Forest's strongest compact lobe holds 6% of its energy: it is shaded directly.
    assert!(
        v["compact_lobes"].as_u64().unwrap() >= 1,
        "{}",
        v["compact_lobes"]
    );
    // The compressed transfer (64 clusters x 16 components by default) and the share of the
    // error it adds, against the same lobes with the uncompressed transfer.
    assert_eq!(v["components"], 16);
    let (c, u) = (
        v["frames"][1]["vs_ground_truth"]["all"].as_f64().unwrap(),
        v["frames"][1]["uncompressed_vs_ground_truth"]["all"]
            .as_f64()
            .unwrap(),
    );
    assert!(
        v["cpca_rel_l2"].as_f64().unwrap() > 0.0 && c < u + 0.02,
        "{c} vs {u}"
    );
    // A more compact transfer than the GPU path holds is refused with the reason.
    let (ok, _, stderr) = vkshade(&[
        "srbf",
        "shade",
        "--mesh",
        mesh.to_str().unwrap(),
        "--basis",
        "64",
        "--clusters",
        "1000",
        "--components",
        "8",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(!ok && stderr.contains("projected rows"), "{stderr}");
    let (ok, _, stderr) = vkshade(&["srbf", "shade", "--compact-lobes", "99"]);
    assert!(!ok && stderr.contains("--compact-lobes"), "{stderr}");
    // Bad input: a missing map, a bad rotation, a non-2:1 map.
    let (ok, _, stderr) = vkshade(&["srbf", "fit", "--env", "/nonexistent/map.exr"]);
    assert!(!ok && stderr.contains("/nonexistent/map.exr"), "{stderr}");
    let (ok, _, stderr) = vkshade(&["srbf", "shade", "--rotate", "w:30"]);
    assert!(!ok && stderr.contains("axis 'w'"), "{stderr}");
    let not_2_1 = dir.join("square.hdr");
    let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 4\n".to_vec();
    hdr.extend(std::iter::repeat_n([128u8, 128, 128, 129], 16).flatten());
    std::fs::write(&not_2_1, hdr).unwrap();
    let (ok, _, stderr) = vkshade(&["srbf", "fit", "--env", not_2_1.to_str().unwrap()]);
    assert!(!ok && stderr.contains("square.hdr"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Glossy shading toward a camera, uncompressed and CTA-compressed, under validation: the
/// report states the BRDF, its parameters, the camera and the view grid; the GPU matches
/// its CPU twin; bad glossy options are refused before anything is computed.
/// `--sun rays`: compact lobes shadowed by a ray per vertex at their rotated direction; the
/// report says so, the run is clean under validation and the GPU matches its CPU twin (the
/// same rays through the CPU BVH: ~1e-7 on the bunny, 1e-4 allows a grazing ray or two).
#[test]
fn srbf_shade_with_sun_rays() {
    let dir = temp("srbf-cli-sun");
    let mesh = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "srbf",
        "shade",
        "--mesh",
        mesh.to_str().unwrap(),
        "--env",
        "/usr/share/blender/datafiles/studiolights/world/sunrise.exr",
        "--lobes",
        "16",
        "--basis",
        "64",
        "--directions",
        "32",
        "--rotate",
        "y:42",
        "--sun",
        "rays",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["sun"], "rays");
    assert!(
        v["compact_lobes"].as_u64().unwrap() >= 1,
        "{}",
        v["compact_lobes"]
    );
    let gc = v["frames"][0]["gpu_vs_cpu"]["all"].as_f64().unwrap();
    assert!(gc < 1e-4, "GPU vs CPU twin {gc}");
    let (ok, _, stderr) = vkshade(&["srbf", "shade", "--sun", "sideways"]);
    assert!(!ok && stderr.contains("sideways"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A glossy Testwuson under Blender's sunrise against the brute-force truth: the sun is a
/// compact lobe shaded directly with the BRDF toward the camera (pass `srbf glossy sharp`).
/// Through the 256-SG basis it erred 6.3-12.5% over these rotations (`--compact-lobes 0`);
/// directly 0.5-0.7%. Bound 2%: a sun lost, doubled or shaded with the wrong BRDF or
/// shadow costs several times that.
#[test]
fn srbf_glossy_sun_is_shaded_directly() {
    let dir = temp("srbf-glossy-sun");
    let mesh = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "srbf",
        "shade",
        "--mesh",
        mesh.to_str().unwrap(),
        "--env",
        "/usr/share/blender/datafiles/studiolights/world/sunrise.exr",
        "--brdf",
        "phong",
        "--reference",
        "--frames",
        "4",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["compact_lobes"].as_u64(), Some(1));
    for f in v["frames"].as_array().unwrap() {
        let e = f["vs_ground_truth"]["all"].as_f64().unwrap();
        assert!(e < 0.02, "frame {}: vs truth {e}", f["index"]);
        assert!(f["gpu_vs_cpu"]["all"].as_f64().unwrap() < 1e-5, "{f}");
        assert!(f["gpu_ms_sharp"].as_f64().unwrap() > 0.0, "{f}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn srbf_glossy_and_cta_write_their_report_and_refuse_bad_input() {
    let dir = temp("srbf-glossy-cli");
    let mesh = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let base = [
        "--validate",
        "srbf",
        "shade",
        "--mesh",
        mesh.to_str().unwrap(),
        "--lobes",
        "16",
        "--basis",
        "64",
        "--directions",
        "32",
        "--brdf",
        "phong",
        "--exponent",
        "6",
        "--kd",
        "0.4",
        "--ks",
        "0.5",
        "--camera",
        "0.5,-1,6",
        "--rotate",
        "x:30",
        "--reference",
        "--out",
        dir.to_str().unwrap(),
    ];
    let cta = [
        "srbf lighting",
        "srbf cta light",
        "srbf cta project",
        "srbf cta shade",
    ];
    // Each view basis, uncompressed and through CTA.
    for (view, extra, passes) in [
        (
            ["--views", "6"],
            &[][..],
            &["srbf lighting", "srbf glossy shade"][..],
        ),
        (
            ["--views", "6"],
            &["--cta", "--cta-clusters", "8", "--cta-ranks", "4,4,8"][..],
            &cta[..],
        ),
        (
            ["--terms", "8"],
            &[][..],
            &["srbf lighting", "srbf glossy shade"][..],
        ),
        (
            ["--terms", "8"],
            &["--cta", "--cta-clusters", "8", "--cta-ranks", "4,4,8"][..],
            &cta[..],
        ),
    ] {
        let args: Vec<&str> = base.iter().chain(&view).chain(extra).copied().collect();
        let (ok, stdout, stderr) = vkshade(&args);
        assert!(ok, "{stdout}\n{stderr}");
        assert!(stderr.contains("validation: clean"), "{stderr}");
        for f in [
            "shade_0000.ply",
            "shade_0000.png",
            "report.json",
            "glossy.bin",
        ] {
            assert!(dir.join(f).exists(), "{f} missing");
        }
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
        assert_eq!(v["brdf"]["model"], "phong");
        assert_eq!(v["brdf"]["exponent"].as_f64(), Some(6.0));
        assert_eq!(v["brdf"]["specular"].as_f64(), Some(0.5));
        assert_eq!(v["camera"], serde_json::json!([0.5, -1.0, 6.0]));
        if view[0] == "--views" {
            assert_eq!(v["view_grid"].as_u64(), Some(6));
            assert!(v["view_terms"].is_null());
        } else {
            assert!(v["view_grid"].is_null());
            assert_eq!(v["view_terms"].as_u64(), Some(8));
            // Phong 6 (kd 0.4, ks 0.5) in 8 terms: a truncation between 0 and 1 (0.2 for
            // Phong 8 with more specular, brdf_factors' tests).
            let t = v["view_truncation"].as_f64().unwrap();
            assert!(t > 0.0 && t < 0.4, "truncation {t}");
        }
        let names: Vec<&str> = v["kernel"]["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap())
            .collect();
        // forest's sun (with 64 basis SGs, two more lobes) is compact, added by its own
        // passes after the shading.
        assert!(
            v["compact_lobes"].as_u64().unwrap() >= 1,
            "{}",
            v["compact_lobes"]
        );
        // Grid taps: `srbf sharp` places them once per frame, `srbf glossy sharp` adds them.
        assert_eq!(names[..names.len() - 2], *passes);
        assert_eq!(
            names[names.len() - 2..],
            ["srbf sharp", "srbf glossy sharp"]
        );
        let f = &v["frames"][0];
        // GPU against its CPU twin: f32 sums (see tests/srbf_glossy.rs), 1e-5 relative L2.
        assert!(f["gpu_vs_cpu"]["all"].as_f64().unwrap() < 1e-5, "{f}");
        // Against the truth: a 6 x 6 view grid (or 8 terms) and 64 basis functions are
        // coarse for Phong 6, so this only catches a broken path (a wrong view or frame gives
        // O(1) errors); tests/srbf_glossy.rs holds the accurate setting to 5%.
        let e = f["vs_ground_truth"]["all"].as_f64().unwrap();
        assert!(e < 0.5, "vs truth {e}");
        if extra.contains(&"--cta") {
            // The compression is cached beside the transfer: the same run again reads it
            // and shades the same radiance.
            let first = f["gpu_vs_cpu"].clone();
            let (ok, stdout, stderr) = vkshade(&args);
            assert!(ok, "{stdout}\n{stderr}");
            assert!(stderr.contains("amortised (cached)"), "{stderr}");
            let again: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
            assert_eq!(again["cpca_cached"], true);
            assert_eq!(again["cpca_rel_l2"], v["cpca_rel_l2"]);
            assert_eq!(again["frames"][0]["gpu_vs_cpu"], first);
        }
    }
    for (args, what) in [
        (
            &["--brdf", "phong", "--kd", "0.8", "--ks", "0.5"][..],
            "energy",
        ),
        (&["--cta"][..], "--cta compresses the glossy transfer"),
        (&["--brdf", "phong", "--views", "1"][..], "--views"),
        (&["--brdf", "phong", "--terms", "0"][..], "--terms"),
        (
            &["--brdf", "phong", "--terms", "40", "--cta"][..],
            "at most 32 BRDF terms",
        ),
        (
            &["--brdf", "phong", "--terms", "8", "--views", "6"][..],
            "cannot be used with",
        ),
        (&["--brdf", "phong", "--camera", "1,2"][..], "--camera"),
        // Refused even where the diffuse BRDF would not read them.
        (&["--kd", "nan"][..], "--kd NaN is not a finite number"),
        (
            &["--brdf", "phong", "--exponent", "inf"][..],
            "--exponent inf",
        ),
    ] {
        let all: Vec<&str> = ["srbf", "shade"].iter().chain(args).copied().collect();
        let (ok, _, stderr) = vkshade(&all);
        assert!(!ok && stderr.contains(what), "{args:?}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn btf_synth_eval_render_write_their_files_and_refuse_bad_input() {
    let dir = temp("btf-cli");
    let btf = dir.join("rib4");
    let (ok, stdout, stderr) = vkshade(&[
        "btf",
        "synth",
        "--pattern",
        "rib",
        "--size",
        "4",
        "-o",
        btf.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(btf.join("btf_tl075_pl345_tv075_pv345.png").exists());
    assert!(btf.join("btf.json").exists());
    let tile = dir.join("tile.exr");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "btf",
        "eval",
        "--btf",
        btf.to_str().unwrap(),
        "--light",
        "30,40",
        "--view",
        "10,200",
        "--map-res",
        "32",
        "-o",
        tile.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    let img = vkshade::io::exr::read_rgba(&tile).unwrap();
    assert_eq!((img.width, img.height), (4, 4));
    assert!(img.pixels.iter().any(|p| p[0] > 0.01));
    let out = dir.join("render");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "btf",
        "render",
        "--btf",
        btf.to_str().unwrap(),
        "--object",
        "cylinder",
        "--width",
        "48",
        "--height",
        "40",
        "--map-res",
        "32",
        "--reference",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    for f in ["render.png", "render.exr", "report.json"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert!(v["gpu_ms"]["median"].as_f64().unwrap() > 0.0);
    // The default texture is `block`: a 4 x 4 tile takes 2 x 2 overlapping blocks of 16
    // bytes per image; texture_bytes is what the device allocated, which pads and aligns
    // small layers as it likes (lavapipe 2 x, to 4 rows; NVIDIA H200 4.05 x). The upper
    // bound, 8 x, only checks the
    // unit (bytes, not bits) and that nothing is counted several times over.
    assert_eq!(v["texture"], "block");
    let bytes = v["texture_bytes"].as_u64().unwrap();
    eprintln!("btf block texture: {bytes} bytes allocated for 6561 x 64 bytes of blocks");
    assert!(bytes >= 6561 * 4 * 16);
    assert!(bytes < 6561 * 4 * 16 * 8, "{bytes} bytes");
    assert_eq!(v["map_resolution"], 32);
    assert!(v["vs_cpu"]["max_abs"].as_f64().unwrap() < v["vs_cpu"]["bound"].as_f64().unwrap());
    assert!(v["vs_cpu"]["bound"].as_f64().unwrap() <= 1.4e-2);
    eprintln!("btf vs ray cast: {}", v["vs_ray_cast"]);
    // Measured 30.0 dB (rib 4 x 4 on a cylinder, 32^2 maps, deterministic synthesis); the
    // old bound of 15 dB allowed an error 5.6 times larger.
    assert!(v["vs_ray_cast"]["all"]["psnr_db"].as_f64().unwrap() > 27.0);
    // Bad input: a light below the horizon, a missing directory, a bad pattern.
    let (ok, _, stderr) = vkshade(&[
        "btf", "eval", "--btf", "x", "--light", "95,0", "--view", "0,0", "-o", "t.exr",
    ]);
    assert!(!ok && stderr.contains("THETA"), "{stderr}");
    let (ok, _, stderr) = vkshade(&[
        "btf",
        "render",
        "--btf",
        "/nonexistent/btf",
        "--out",
        dir.join("none").to_str().unwrap(),
    ]);
    assert!(!ok && stderr.contains("/nonexistent/btf"), "{stderr}");
    assert!(!dir.join("none").join("report.json").exists());
    // A larger sample repeating every 6 texels: `btf tile` finds the period and cuts a tile.
    let sample = dir.join("weave12");
    let (ok, stdout, stderr) = vkshade(&[
        "btf",
        "synth",
        "--pattern",
        "weave",
        "--size",
        "12",
        "--period",
        "6",
        "-o",
        sample.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    let tile = dir.join("weave-tile");
    let (ok, stdout, stderr) = vkshade(&[
        "btf",
        "tile",
        "--btf",
        sample.to_str().unwrap(),
        "--origin",
        "3,1",
        "-o",
        tile.to_str().unwrap(),
    ]);
    assert!(
        ok && stdout.contains("repeat period 6 x 6"),
        "{stdout}\n{stderr}"
    );
    let cut = vkshade::kernels::btf::load::load_dir(&tile).unwrap();
    assert_eq!(cut.size, [6, 6]);
    let (ok, _, stderr) = vkshade(&["btf", "synth", "--pattern", "tweed", "-o", "x"]);
    assert!(!ok && stderr.contains("tweed"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sss_writes_texture_space_exrs_render_and_report_and_refuses_bad_input() {
    let dir = temp("sss-cli");
    // The built-in head (BCN_Epileptic, in metres: the default scale is 1000 mm per unit).
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "sss",
        "--size",
        "64",
        "--samples",
        "4",
        "--reference",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    for f in ["irradiance.exr", "diffuse.exr", "render.png", "report.json"] {
        assert!(dir.join(f).exists(), "{f} missing");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(v["mm_per_unit"], 1000.0);
    assert_eq!(v["samples"], 4);
    assert!(v["gpu_ms_diffusion"].as_f64().unwrap() > 0.0);
    assert!(v["reference"].is_object(), "{}", v["reference"]);
    // A scale that makes the head 0.3 mm across is reported, not silently used.
    let (ok, _, stderr) = vkshade(&[
        "--validate",
        "sss",
        "--size",
        "32",
        "--samples",
        "2",
        "--mm-per-unit",
        "1",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(ok && stderr.contains("check the model's units"), "{stderr}");
    assert!(stderr.contains("validation: clean"), "{stderr}");
    // Bad input names the file or the option.
    let (ok, _, stderr) = vkshade(&["sss", "--mesh", "/nonexistent/head.glb"]);
    assert!(!ok && stderr.contains("/nonexistent/head.glb"), "{stderr}");
    let (ok, _, stderr) = vkshade(&["sss", "--light", "dir:0,0,0"]);
    assert!(!ok && stderr.contains("light"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `vkshade frame --reference` under validation, small: three poses, each stage against its
/// truth in report.json and a PLY per pose. The compose pass must equal its CPU twin (per
/// pixel 2e-3 in tests/frame.rs, so the relative RMS here too), and the environment
/// shadowed by the character must be closer to the ray-traced truth than the unshadowed
/// light (measured 12-24% against 47-54% at 512 x 512 with 1024 rays; a planted bug that
/// drops the shadowing or rotates the lobes the wrong way makes the two meet).
#[test]
fn frame_reference_compares_the_stages_with_their_truths_under_validation() {
    let dir = temp("frame-reference");
    let out = dir.to_str().unwrap();
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "frame",
        "--frames",
        "1",
        "--size",
        "128",
        "--atlas",
        "128",
        "--samples",
        "8",
        "--reference",
        "--rays",
        "256",
        "--out",
        out,
    ]);
    assert!(ok, "frame --reference failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("stages against their truths"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    let poses = v["reference"].as_array().expect("reference poses");
    assert_eq!(poses.len(), 3);
    for p in poses {
        // As an RMS over the image this is dominated by its brightest pixel: at the second
        // pose a skin specular highlight at radiance ~60 holds most of the energy, where the
        // sharp lobe amplifies exp / pow ulp differences: lavapipe 8.7e-5, NVIDIA H200
        // (driver 580.159) 6.7e-4 (report.json's compose_worst names the pixel). A missing
        // Fresnel or specular term moves skin pixels by > 2%.
        let compose = p["compose_rel_rms"].as_f64().unwrap();
        assert!(
            compose < 2e-3,
            "compose against its twin: {compose}, worst pixel {}",
            p["compose_worst"]
        );
        let (env, open, floor) = (
            p["env"]["rel_l2"].as_f64().unwrap(),
            p["env"]["unshadowed_rel_l2"].as_f64().unwrap(),
            p["env"]["floor_rel_l2"].as_f64().unwrap(),
        );
        assert!(
            env.is_finite() && env < open,
            "env {env} vs unshadowed {open}"
        );
        // Issue 18's 10% at every pose, and below the AO-weighted floor. Measured with this
        // 256-ray truth: 8.39 / 8.47 / 9.03% on the shadow cut of `CV_TAU` 1.4 (8.07 / 8.42 /
        // 8.68% on tau 1.2's; floor 12.9 / 16.9 / 19.3%). The caps' split
        // scaled by the rays' escaped fraction instead of corrected per lobe read 13.4% at the
        // second pose (1024 rays), so this fails if the per-lobe correction is lost.
        assert!(env <= 0.10 && env < floor, "env {env} (floor {floor})");
        let ply = std::fs::read(p["ply"].as_str().unwrap()).unwrap();
        let header = String::from_utf8_lossy(&ply[..ply.len().min(2000)]).into_owned();
        assert!(header.starts_with("ply\n") && header.contains("property float truth_r"));
    }
}

/// `vkshade bench env --quick` under validation names the roofline that binds `env shadow`
/// (its work model: FLOP and cap-table reads) and its fraction of it, as every kernel's bench
/// does (issue 22). The fraction is a model's estimate: finite and positive is what holds on
/// any device; its value is in the closing notes, not asserted.
#[test]
fn bench_env_names_its_binding_roofline_under_validation() {
    let json = temp("bench-env.json");
    let (ok, stdout, stderr) = vkshade(&[
        "--validate",
        "bench",
        "env",
        "--quick",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "bench env failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("roofline: binds: "), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let r = &v["roofline"];
    let binding = r["binding"].as_str().unwrap();
    assert!(
        ["fma", "image_gather_coherent"].contains(&binding),
        "binding {binding}"
    );
    let f = r["fraction"].as_f64().unwrap();
    assert!(f.is_finite() && f > 0.0, "fraction {f}");
    assert!(r["fma_fraction"].as_f64().unwrap() > 0.0);
    // The traced visibility's passes, timed beside their CPU twin (under validation too).
    assert!(stdout.contains("traced visibility, 16 rays"), "{stdout}");
    let t = &v["trace"];
    assert_eq!(t["grid"].as_u64(), Some(4), "{t}");
    for k in ["rays_per_s", "cpu_ms"] {
        let x = t[k].as_f64().unwrap();
        assert!(x.is_finite() && x > 0.0, "{k} {x}");
    }
    assert!(t["gpu"]["median"].as_f64().unwrap() >= t["trace"]["median"].as_f64().unwrap());
}

/// `vkshade frame --part-btf / --part-tile-scale / --part-skin / --skin-material`: malformed
/// entries and a part of the wrong kind are refused before any GPU work, each error naming
/// the flag's value or the part.
#[test]
fn frame_part_flags_refuse_bad_entries() {
    for (args, want) in [
        (
            &["frame", "--part-btf", "Legs"][..],
            "--part-btf 'Legs': expected PART=VALUE",
        ),
        (
            &["frame", "--part-tile-scale", "Legs=x"][..],
            "'x' is not a number",
        ),
        (
            &["frame", "--part-btf", "Cape=rib"][..],
            "cloth part 'Cape' has a BTF or tile scale but is not one of the cloth parts",
        ),
        (
            &["frame", "--part-btf", "Legs=rib", "--part-btf", "Legs=knit"][..],
            "--part-btf names part 'Legs' twice",
        ),
        (
            &["frame", "--part-tile-scale", "Torso=-2"][..],
            "tile scale -2 must be > 0",
        ),
        (
            &["frame", "--part-skin", "Head=marble"][..],
            "--part-skin 'Head=marble': unknown material 'marble'",
        ),
        (
            &["frame", "--part-skin", "Legs=skin2"][..],
            "skin part 'Legs' has a scattering material but is not one of the skin parts",
        ),
        (
            &["frame", "--skin-material", "1,2/3,4,5"][..],
            "--skin-material: skin material '1,2/3,4,5': sigma_a has 2 values, not 3",
        ),
    ] {
        let (ok, _, stderr) = vkshade(args);
        assert!(!ok && stderr.contains(want), "{args:?}: {stderr}");
    }
}

/// Issue 21, point 5: `--part`'s default applies to the built-in character only. An OBJ
/// without `--part` loads as OBJ (it used to be forced through the glTF loader: "not valid
/// glTF: expected value at line 1 column 1"); an explicit `--part` with an OBJ is refused,
/// saying OBJ has no parts.
#[test]
fn sss_part_default_applies_to_the_built_in_character_only() {
    // A tetrahedron with UVs (each face its own corner of the unit square).
    let obj = temp("face.obj");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n\
         vt 0.05 0.05\nvt 0.45 0.05\nvt 0.05 0.45\nvt 0.55 0.55\nvt 0.95 0.55\nvt 0.55 0.95\n\
         f 1/1 3/2 2/3\nf 1/4 2/5 4/6\nf 1/1 4/2 3/3\nf 2/4 3/5 4/6\n",
    )
    .unwrap();
    let out = temp("sss-obj");
    let (ok, stdout, stderr) = vkshade(&[
        "sss",
        "--mesh",
        obj.to_str().unwrap(),
        "--size",
        "32",
        "--samples",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!stderr.contains("glTF"), "{stderr}");
    assert!(ok, "stdout:\n{stdout}\nstderr:\n{stderr}");
    let (ok, _, stderr) = vkshade(&["sss", "--mesh", obj.to_str().unwrap(), "--part", "Head"]);
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("face.obj") && stderr.contains("an OBJ file, which has no parts"),
        "{stderr}"
    );
}

/// Issue 21, point 5: numeric flags out of range are refused naming the flag and the
/// bound, never with an internal message ("need 0 projected rows") or a struct dump.
#[test]
fn numeric_flags_out_of_range_name_the_flag_and_the_bound() {
    let (ok, _, stderr) = vkshade(&["srbf", "shade", "--clusters", "0"]);
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("--clusters") && stderr.contains("at least 1"),
        "{stderr}"
    );
    assert!(!stderr.contains("projected rows"), "{stderr}");
    for (args, want) in [
        (
            &["sss", "--light", "dir:1e30,1e30,1e30"][..],
            "--light 'dir:1e30,1e30,1e30': a coordinate is beyond +-1e18",
        ),
        (
            &[
                "sss",
                "--light",
                "point:1e17,0,0:1",
                "--mesh",
                "x.glb",
                "--mm-per-unit",
                "1000",
            ][..],
            "position in mm",
        ),
        (
            &["sss", "--light", "dir:0,1,0:1e30"][..],
            "strength must be finite and in 0..=1e12",
        ),
        (
            &["btf", "render", "--btf", "x", "--light", "1e30,1e30,1e30"][..],
            "--light '1e30,1e30,1e30': the direction's coordinates must be finite within +-1e18",
        ),
        (
            &["btf", "render", "--btf", "x", "--light", "0,1,0,inf,1,1"][..],
            "R,G,B must be finite",
        ),
        (
            &["env", "--lobes", "0"][..],
            "--lobes must be in 1..=64, not 0",
        ),
        (&["env", "--rotate", "nan"][..], "--rotate must be finite"),
        (&["env", "--trace-grid", "17"][..], "--trace-grid must be 0"),
        (
            &["srbf", "fit", "--fit-width", "0"][..],
            "--fit-width must be even",
        ),
        (
            &["frame", "--size", "0"][..],
            "--size 0 must be in 16..=8192",
        ),
        (
            &["frame", "--samples", "0"][..],
            "--samples 0 must be in 1..=4096",
        ),
        (
            &["frame", "--exposure", "nan"][..],
            "--exposure NaN must be finite",
        ),
        (
            &["frame", "--in-flight", "0"][..],
            "--in-flight 0 must be in 1..=16",
        ),
    ] {
        let (ok, _, stderr) = vkshade(args);
        assert!(!ok && stderr.contains(want), "{args:?}: {stderr}");
        assert!(!stderr.contains("Directional {"), "{args:?}: {stderr}");
    }
}

/// Issue 21, point 3: a map whose texel (or RGBE exponent) overflows the fit's arithmetic
/// is refused naming the file and the texel, instead of "relative L2 NaN" and null
/// amplitudes with exit 0; and a fit is never written with a non-finite value.
#[test]
fn srbf_fit_refuses_an_overflowing_map_instead_of_printing_nan() {
    // RGBE 8 x 4, every pixel 1.0 but one (255, 255, 255, e = 255): 255 x 2^119 ~ 1.7e38.
    let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n".to_vec();
    for i in 0..32 {
        bytes.extend(if i == 13 {
            [255u8, 255, 255, 255]
        } else {
            [128, 128, 128, 129]
        });
    }
    let hdr = temp("huge.hdr");
    std::fs::write(&hdr, &bytes).unwrap();
    let out = temp("huge-fit.json");
    let (ok, stdout, stderr) = vkshade(&[
        "srbf",
        "fit",
        "--env",
        hdr.to_str().unwrap(),
        "--lobes",
        "8",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(!ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("huge.hdr") && stderr.contains("texel (5, 1)") && stderr.contains("above"),
        "{stderr}"
    );
    assert!(
        !stdout.contains("NaN") && !stderr.contains("NaN"),
        "{stdout}\n{stderr}"
    );
    assert!(!out.exists());
}

/// Issue 21, point 4 through the CLI: a map with DWAB-like ringing beside a sun loads by
/// default (the repair reported in the command's output and in the fit's JSON), and
/// `--hdr-strict` refuses it.
#[test]
fn srbf_fit_repairs_codec_ringing_by_default_and_hdr_strict_refuses_it() {
    use vkshade::io::{FloatImage, exr};
    let mut img = FloatImage::new(64, 32, [0.5, 0.6, 0.8, 1.0]);
    for y in 10..12 {
        for x in 30..32 {
            img.set(x, y, [11_800.0, 11_000.0, 9_500.0, 1.0]);
        }
    }
    // A negative lobe beside the sun and a positive one next to it (zero sum).
    img.set(33, 10, [-2_000.0, -1_900.0, -1_600.0, 1.0]);
    img.set(34, 10, [2_000.5, 1_900.5, 1_600.5, 1.0]);
    let map = temp("ringing.exr");
    exr::write(&map, &img, exr::Channels::Rgb).unwrap();
    let out = temp("ringing-fit.json");
    let args = |strict: bool| {
        let mut a = vec![
            "srbf",
            "fit",
            "--env",
            map.to_str().unwrap(),
            "--lobes",
            "8",
            "--fit-width",
            "32",
            "-o",
            out.to_str().unwrap(),
        ];
        if strict {
            a.push("--hdr-strict");
        }
        a
    };
    let (ok, stdout, stderr) = vkshade(&args(false));
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("ringing.exr") && stderr.contains("3 negative samples"),
        "{stderr}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(v["hdr_repair"]["negative_samples"].as_u64(), Some(3), "{v}");
    assert!(
        v["hdr_repair"]["energy_change"].as_f64().unwrap().abs() < 1e-6,
        "{v}"
    );
    std::fs::remove_file(&out).unwrap();
    let (ok, _, stderr) = vkshade(&args(true));
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("ringing.exr") && stderr.contains("negative"),
        "{stderr}"
    );
    assert!(!out.exists());
}
