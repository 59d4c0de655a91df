//! Shared harness for GPU tests: every test runs on a validated context (synchronization
//! validation on), and any validation message, leaked resource or undestroyed object fails it.
//! A missing Vulkan device fails too, with the message saying what to install.
#![allow(dead_code)]

#[path = "../scratch/mod.rs"]
pub mod scratch;

use std::cell::RefCell;
use std::sync::{Mutex, MutexGuard, PoisonError};
use vkshade::gpu::{Context, ContextDesc, ValidationMessage};

/// Held by the test thread that made a context until the thread ends (see [`hold_gpu`]).
static GPU: Mutex<()> = Mutex::new(());

thread_local! {
    static HELD: RefCell<Option<MutexGuard<'static, ()>>> = const { RefCell::new(None) };
}

/// Makes the calling test the only one in this process using Vulkan until its thread ends;
/// CPU-only tests still run beside it. Call it before making a context (the helpers here
/// do). Reentrant: a test may make several contexts.
///
/// Why: the Khronos validation layer 1.3.239 (Debian 12's) finds each device's state in a
/// global map that it writes without a lock when an instance or device is made or destroyed
/// (KhronosGroup/Vulkan-ValidationLayers#4391). One test's context shutting down while
/// another test's context makes a call can crash the process: seen once in 600 runs of
/// tests/pipeline.rs, `vkGetSemaphoreCounterValue` in one test against `vkDestroyInstance`
/// in another, and once in CI. Two contexts on one thread are not affected.
pub fn hold_gpu() {
    HELD.with(|held| {
        let mut held = held.borrow_mut();
        if held.is_none() {
            // A test that panicked while holding the lock poisons nothing we rely on.
            *held = Some(GPU.lock().unwrap_or_else(PoisonError::into_inner));
        }
    });
}

/// A validated context, or a panic explaining how to get one.
pub fn context() -> Context {
    hold_gpu();
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
    hold_gpu();
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
    scratch::dir(tag)
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
    hold_gpu();
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

/// CRC-32 (the PNG chunk checksum) of `data`.
pub fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// An 8-bit RGBA PNG of `w` x `h` texels (row-major words r | g << 8 | b << 16 | a << 24),
/// written with stored (uncompressed) deflate blocks: test images without an encoder.
pub fn png_rgba(w: u32, h: u32, texels: &[u32]) -> Vec<u8> {
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend_from_slice(data);
        out.extend_from_slice(&body);
        out.extend_from_slice(&crc32(&body).to_be_bytes());
    }
    assert_eq!(texels.len(), (w * h) as usize);
    let mut raw = Vec::new();
    for y in 0..h {
        raw.push(0u8); // filter: none
        for x in 0..w {
            raw.extend_from_slice(&texels[(y * w + x) as usize].to_le_bytes());
        }
    }
    let mut z = vec![0x78, 0x01];
    for (i, block) in raw.chunks(65535).enumerate() {
        let last = (i + 1) * 65535 >= raw.len();
        z.push(u8::from(last));
        z.extend_from_slice(&(block.len() as u16).to_le_bytes());
        z.extend_from_slice(&(!(block.len() as u16)).to_le_bytes());
        z.extend_from_slice(block);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in &raw {
        a = (a + x as u32) % 65521;
        b = (b + a) % 65521;
    }
    z.extend_from_slice(&((b << 16) | a).to_be_bytes());
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 6, 0, 0, 0]);
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(&mut out, b"IDAT", &z);
    chunk(&mut out, b"IEND", &[]);
    out
}

/// The built-in character (BCN_Epileptic) with textured materials: `pngs` appended to its
/// binary chunk as embedded images, then `edit` given the JSON (images 0.. are the PNGs,
/// in order, with buffer views already added) to add samplers, textures and materials and
/// point the primitives at them. Written as `name` in [`temp_dir`]`(tag)`.
pub fn edited_bcn(
    tag: &str,
    name: &str,
    pngs: &[Vec<u8>],
    edit: impl FnOnce(&mut serde_json::Value),
) -> std::path::PathBuf {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let glb = std::fs::read(&src).unwrap();
    let u32_at = |o: usize| u32::from_le_bytes(glb[o..o + 4].try_into().unwrap()) as usize;
    let json_len = u32_at(12);
    let mut json: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let bin_at = 20 + json_len;
    let bin_len = u32_at(bin_at);
    let mut bin = glb[bin_at + 8..bin_at + 8 + bin_len].to_vec();
    for png in pngs {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let views = json["bufferViews"].as_array_mut().unwrap();
        views.push(serde_json::json!({
            "buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()
        }));
        let view = views.len() - 1;
        bin.extend_from_slice(png);
        if json.get("images").is_none() {
            json["images"] = serde_json::json!([]);
        }
        json["images"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({"bufferView": view, "mimeType": "image/png"}));
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    json["buffers"][0]["byteLength"] = serde_json::json!(bin.len());
    edit(&mut json);
    let mut text = serde_json::to_vec(&json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + text.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    temp_file(tag, name, &out)
}

/// A 32 x 32 test texture of 8-texel squares in four saturated colours (sRGB words).
pub fn checker_texels() -> Vec<u32> {
    let colours = [0xFF2020E0u32, 0xFF20E020, 0xFFE02020, 0xFFF0F0F0];
    (0..32u32)
        .flat_map(|y| (0..32u32).map(move |x| colours[((x / 8 + y / 8) % 4) as usize]))
        .collect()
}

/// BCN_Epileptic with the checker as its Head's base colour (factor 1) and its Torso's
/// (factor 0.9, 0.6, 0.3; mirrored repeat along u), Legs keeping the file's grey.
pub fn textured_bcn(tag: &str) -> std::path::PathBuf {
    let png = png_rgba(32, 32, &checker_texels());
    edited_bcn(tag, "textured.glb", &[png], |j| {
        j["samplers"] = serde_json::json!([{"wrapS": 33648, "wrapT": 10497}]);
        j["textures"] = serde_json::json!([{"source": 0}, {"source": 0, "sampler": 0}]);
        let mats = j["materials"].as_array_mut().unwrap();
        mats.push(serde_json::json!({"name": "face",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}));
        mats.push(serde_json::json!({"name": "shirt",
            "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.6, 0.3, 1.0],
                                     "baseColorTexture": {"index": 1}}}));
        for m in j["meshes"].as_array_mut().unwrap() {
            let mat = match m["name"].as_str() {
                Some("Head") => 1,
                Some("Torso") => 2,
                _ => 0,
            };
            for p in m["primitives"].as_array_mut().unwrap() {
                p["material"] = serde_json::json!(mat);
            }
        }
    })
}

/// An AO frame from the GPU against the CPU twin's: visibility within the bounds below and
/// the same cut (spheres tested and used) on >= 99.5% of vertices (the adaptive and the fixed
/// cut alike: tests/ao.rs, tests/ao_fixed.rs). Returns the largest difference.
///
/// GPU and CPU run the same f32 operations in the same order. They differ where Vulkan
/// allows it: acos/atan need only be exact to 4096 ulp (~5e-4 near 1; Mesa uses polynomial
/// approximations; the fixed cut's overlap lookups take three arc cosines), sqrt and
/// division to a few ulp, and FMA contraction is the driver's choice. Per sphere that is
/// ~1e-4; over ~35 spheres (and their overlaps) of random sign, a few 1e-4. A comparison tied
/// at that precision (refinement, a mask bit, the inside or disjoint-caps test) can flip,
/// moving one vertex by at most one sphere's share. Measured on lavapipe: MAE 1.3e-5, p95
/// 4.3e-5, max 1.3e-4, identical cuts. Bounds: MAE < 1e-4, p95 < 5e-4, max < 1e-2.
pub fn assert_ao_matches_twin(
    gpu: &vkshade::kernels::ao::FrameData,
    cpu: &[vkshade::kernels::ao::cpu::VertexAo],
    label: &dyn std::fmt::Debug,
) -> f64 {
    let cpu_vis: Vec<f32> = cpu.iter().map(|v| v.visibility).collect();
    let e = vkshade::reference::ErrorStats::of(&gpu.visibility, &cpu_vis);
    let same_cut = gpu
        .stats
        .iter()
        .zip(cpu)
        .filter(|(g, c)| **g == [c.tested, c.used])
        .count();
    eprintln!(
        "{label:?}: GPU vs CPU {e:?}; same cut on {same_cut}/{} vertices",
        cpu.len()
    );
    assert!(
        e.mae < 1e-4 && e.p95 < 5e-4 && e.max < 1e-2,
        "{label:?}: {e:?}"
    );
    assert!(
        same_cut as f64 >= 0.995 * cpu.len() as f64,
        "{label:?}: cut differs on {} vertices",
        cpu.len() - same_cut
    );
    e.max
}
