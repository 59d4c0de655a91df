//! Shared harness for GPU tests: every test runs on a validated context (synchronization
//! validation on), and any validation message, leaked resource or undestroyed object fails it.
//! A missing Vulkan device fails too, with the message saying what to install.
#![allow(dead_code)]

use vkshade::gpu::{Context, ContextDesc, ValidationMessage};

/// A validated context, or a panic explaining how to get one.
pub fn context() -> Context {
    match Context::new(&ContextDesc::validated()) {
        Ok(ctx) => ctx,
        Err(e) => panic!(
            "cannot create a validated Vulkan context: {e}\n\
             These tests need a Vulkan device and the Khronos validation layer: on Debian 12 run \
             `sudo tools/setup.sh`, or `apt-get install mesa-vulkan-drivers vulkan-validationlayers`."
        ),
    }
}

/// Shuts `ctx` down and returns every message collected, including those raised while
/// destroying the device. Panics if resources are still alive.
pub fn shutdown(ctx: Context) -> Vec<ValidationMessage> {
    match ctx.shutdown() {
        Ok(messages) => messages,
        Err(e) => panic!("unclean shutdown: {e}"),
    }
}

/// Runs `f` on a validated context with optional device `features` (which the device must
/// support); fails on any error, validation message or leak.
pub fn with_gpu_features<T>(
    features: vkshade::gpu::Features,
    f: impl FnOnce(&Context) -> vkshade::Result<T>,
) -> T {
    let ctx = match Context::new(&ContextDesc {
        features,
        ..ContextDesc::validated()
    }) {
        Ok(ctx) => ctx,
        Err(e) => panic!("cannot create a validated context with {features:?}: {e}"),
    };
    run_checked(ctx, f)
}

/// Runs `f` on a validated context; fails on any error, validation message or leak.
pub fn with_gpu<T>(f: impl FnOnce(&Context) -> vkshade::Result<T>) -> T {
    run_checked(context(), f)
}

/// Runs `f` on `ctx`, shuts it down and fails on any error, validation message or leak.
fn run_checked<T>(ctx: Context, f: impl FnOnce(&Context) -> vkshade::Result<T>) -> T {
    let result = f(&ctx);
    let messages = shutdown(ctx);
    let value = match result {
        Ok(v) => v,
        Err(e) => panic!("GPU test failed: {e}"),
    };
    assert_clean(&messages);
    value
}

/// Fails with every message listed, if there are any.
pub fn assert_clean(messages: &[ValidationMessage]) {
    if !messages.is_empty() {
        let list: Vec<String> = messages.iter().map(|m| format!("  {m}")).collect();
        panic!(
            "{} validation message(s):\n{}",
            messages.len(),
            list.join("\n")
        );
    }
}

/// A closed UV sphere of radius 1.
pub fn ball() -> vkshade::scene::Character {
    let (nu, nv) = (32u32, 16u32);
    let mut d = vkshade::scene::MeshData::default();
    d.positions.push([0.0, 1.0, 0.0]);
    for j in 1..nv {
        let th = std::f32::consts::PI * j as f32 / nv as f32;
        for i in 0..nu {
            let ph = std::f32::consts::TAU * i as f32 / nu as f32;
            d.positions
                .push([th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
        }
    }
    d.positions.push([0.0, -1.0, 0.0]);
    let ring = |j: u32, i: u32| 1 + (j - 1) * nu + i % nu;
    for i in 0..nu {
        d.triangles.push([0, ring(1, i + 1), ring(1, i)]);
        d.triangles
            .push([nu * (nv - 1) + 1, ring(nv - 1, i), ring(nv - 1, i + 1)]);
    }
    for j in 1..nv - 1 {
        for i in 0..nu {
            d.triangles
                .push([ring(j, i), ring(j, i + 1), ring(j + 1, i)]);
            d.triangles
                .push([ring(j, i + 1), ring(j + 1, i + 1), ring(j + 1, i)]);
        }
    }
    vkshade::scene::Character::from_static(
        vkshade::scene::Mesh::from_data(d, std::path::Path::new("ball")).unwrap(),
    )
}

/// A scratch folder for the test file `tag`, unique to this process.
pub fn temp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("vkshade-{tag}-test-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes `bytes` to `name` in [`temp_dir`]`(tag)`.
pub fn temp_file(tag: &str, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = temp_dir(tag).join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// The error text of a load of `path`; fails if it loaded or if the error does not name it.
pub fn error_naming<T>(path: &std::path::Path, result: vkshade::Result<T>) -> String {
    match result {
        Ok(_) => panic!("{} loaded, but it is malformed", path.display()),
        Err(e) => {
            let s = e.to_string();
            assert!(
                s.contains(&path.display().to_string()),
                "error does not name the file: {s}"
            );
            s
        }
    }
}

/// Runs `f` on a validated context with GPU-assisted validation on as well (shaders
/// instrumented to report out-of-bounds descriptor and buffer accesses; slow, so for small
/// cases); fails on any error, validation message or leak. With the layer 1.3.239 on lavapipe
/// the first submission under it never completes (see tests/pipeline.rs,
/// `gpu_assisted_validation_starts_and_shuts_down_clean`).
pub fn with_gpu_assisted<T>(f: impl FnOnce(&Context) -> vkshade::Result<T>) -> T {
    with_gpu_assisted_features(vkshade::gpu::Features::default(), f)
}

/// [`with_gpu_assisted`] with optional device `features`.
pub fn with_gpu_assisted_features<T>(
    features: vkshade::gpu::Features,
    f: impl FnOnce(&Context) -> vkshade::Result<T>,
) -> T {
    let desc = ContextDesc {
        features,
        validation: Some(vkshade::gpu::ValidationConfig {
            gpu_assisted: true,
            ..Default::default()
        }),
        ..ContextDesc::validated()
    };
    let ctx = match Context::new(&desc) {
        Ok(ctx) => ctx,
        Err(e) => panic!("cannot create a context with GPU-assisted validation: {e}"),
    };
    run_checked(ctx, f)
}

/// The subTexelPrecisionBits of the device `ctx` selected.
pub fn sub_texel_bits(ctx: &vkshade::gpu::Context) -> u32 {
    let h = ctx.external_handles();
    // SAFETY: the context's own instance and physical device, alive while `ctx` is.
    unsafe { h.instance.get_physical_device_properties(h.physical_device) }
        .limits
        .sub_texel_precision_bits
}
