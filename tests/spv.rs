//! spv/ is generated from glsl/ by `vkshade shaders build` and committed. These tests fail when
//! any module is missing, stale, orphaned, invalid, or differs from what the library embeds.

mod common;

use vkshade::gpu::{ComputePipeline, Shader};
use vkshade::kernels::generated_includes;
#[cfg(feature = "glsl")]
use vkshade::shaders::ModuleState;
use vkshade::shaders::{EMBEDDED, build_all, source_modules, source_root};

#[cfg(feature = "glsl")]
#[test]
fn spv_is_fresh_against_glsl() {
    let statuses = build_all(&source_root(), false, generated_includes()).expect("compile glsl/");
    assert!(!statuses.is_empty(), "no shaders found under glsl/");
    let bad: Vec<_> = statuses
        .iter()
        .filter(|s| s.state != ModuleState::Fresh)
        .map(|s| format!("{} is {:?}", s.name, s.state))
        .collect();
    assert!(
        bad.is_empty(),
        "spv/ is out of date: {}; run `cargo run --release -- shaders build` and commit spv/",
        bad.join(", ")
    );
}

#[test]
fn every_module_passes_spirv_val() {
    let root = source_root();
    for name in source_modules(&root).unwrap() {
        let path = root.join("spv").join(format!("{name}.spv"));
        let out = std::process::Command::new("spirv-val")
            .args(["--target-env", "vulkan1.3"])
            .arg(&path)
            .output()
            .unwrap_or_else(|e| {
                panic!(
                    "cannot run spirv-val ({e}): apt-get install spirv-tools (tools/setup.sh does)"
                )
            });
        assert!(
            out.status.success(),
            "spirv-val rejects {}:\n{}{}",
            path.display(),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn embedded_modules_are_the_committed_ones() {
    let root = source_root();
    let sources = source_modules(&root).unwrap();
    let embedded: Vec<&str> = EMBEDDED.iter().map(|(n, _)| *n).collect();
    assert_eq!(
        embedded, sources,
        "embedded modules differ from glsl/ sources"
    );
    for (name, bytes) in EMBEDDED {
        let on_disk = std::fs::read(root.join("spv").join(format!("{name}.spv"))).unwrap();
        assert_eq!(
            &on_disk[..],
            *bytes,
            "{name}: the library embeds an older spv"
        );
    }
}

#[test]
fn every_module_reflects_and_builds_a_pipeline() {
    // The rasteriser's modules declare Int64 and Int64Atomics: the context enables the
    // feature they need (as RasterKernel::new requires).
    let int64 = vkshade::gpu::Features {
        buffer_int64_atomics: true,
        ..Default::default()
    };
    common::with_gpu_features(int64, |ctx| {
        for (name, bytes) in EMBEDDED {
            let shader = Shader::from_spirv(name, bytes)?;
            assert!(shader.invocations() > 0, "{name}");
            assert!(
                shader.bindings.iter().all(|b| !b.name.starts_with("set")),
                "{name}: reflection lost binding names: {:?}",
                shader.bindings
            );
            ComputePipeline::new(ctx, &shader)?;
        }
        Ok(())
    });
}

#[cfg(feature = "glsl")]
fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

#[cfg(feature = "glsl")]
#[test]
fn build_tool_detects_and_repairs_stale_missing_and_orphaned_modules() {
    let root = common::scratch::fresh("spv");
    copy_dir(&source_root().join("glsl"), &root.join("glsl"));
    copy_dir(&source_root().join("spv"), &root.join("spv"));
    // A semantic change (a comment alone compiles to identical SPIR-V), a deleted module and
    // an orphan.
    let src = root.join("glsl/test/chain_scale.comp");
    let text = std::fs::read_to_string(&src).unwrap();
    std::fs::write(
        &src,
        text.replace("pc.a * src.x[i] + pc.b", "pc.a * src.x[i] - pc.b"),
    )
    .unwrap();
    std::fs::remove_file(root.join("spv/test/chain_add.spv")).unwrap();
    std::fs::write(root.join("spv/test/gone.spv"), [0u8; 8]).unwrap();

    let state = |statuses: &[vkshade::shaders::ModuleStatus], name: &str| {
        statuses
            .iter()
            .find(|s| s.name == name)
            .map(|s| s.state.clone())
    };
    let checked = build_all(&root, false, generated_includes()).unwrap();
    assert_eq!(
        state(&checked, "test/chain_scale"),
        Some(ModuleState::Stale)
    );
    assert_eq!(
        state(&checked, "test/chain_add"),
        Some(ModuleState::Missing)
    );
    assert_eq!(state(&checked, "test/gone"), Some(ModuleState::Orphan));
    assert_eq!(state(&checked, "bench/fma"), Some(ModuleState::Fresh));

    let built = build_all(&root, true, generated_includes()).unwrap();
    assert_eq!(
        state(&built, "test/chain_scale"),
        Some(ModuleState::Updated)
    );
    assert_eq!(state(&built, "test/chain_add"), Some(ModuleState::Updated));
    assert!(!root.join("spv/test/gone.spv").exists());
    let again = build_all(&root, false, generated_includes()).unwrap();
    assert!(
        again.iter().all(|s| s.state == ModuleState::Fresh),
        "{again:?}"
    );

    // A compile error names the file.
    std::fs::write(
        &src,
        "#version 450\nlayout(local_size_x=1) in;\nvoid main() { nope(); }\n",
    )
    .unwrap();
    let e = build_all(&root, false, generated_includes())
        .unwrap_err()
        .to_string();
    assert!(e.contains("chain_scale.comp") && e.contains("nope"), "{e}");
    std::fs::remove_dir_all(&root).unwrap();
}

#[cfg(not(feature = "glsl"))]
#[test]
fn without_glsl_compiling_is_a_feature_error_and_nothing_is_written() {
    use vkshade::Error;
    let root = source_root();
    for write in [false, true] {
        match build_all(&root, write, generated_includes()) {
            Err(Error::FeatureDisabled {
                feature: "glsl", ..
            }) => {}
            other => panic!("expected FeatureDisabled(glsl), got {other:?}"),
        }
    }
    let src = root.join("glsl/test/chain_add.comp");
    for r in [
        vkshade::shaders::compile_glsl(&src, &root.join("glsl")),
        vkshade::shaders::compile_source("#version 450\nvoid main() {}\n", "t.comp"),
    ] {
        let e = r.unwrap_err();
        assert!(e.to_string().contains("`glsl`"), "{e}");
    }
}
