//! Environment maps (src/scene/envmap.rs) and the SRBF brute-force reference
//! (src/reference/srbf.rs).

mod common;

use glam::{Mat3, Vec3};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use vkshade::geom::visibility::direction_visibility;
use vkshade::geom::{Bvh, Rng};
use vkshade::reference::srbf::shade_brute_force;
use vkshade::scene::EnvMap;
#[cfg(feature = "exr")]
use vkshade::scene::envmap::HdrPolicy;
use vkshade::scene::envmap::MAX_RADIANCE;

fn dir() -> PathBuf {
    common::temp_dir("envmap")
}

fn write(name: &str, bytes: &[u8]) -> PathBuf {
    common::temp_file("envmap", name, bytes)
}

/// The error text of loading `path`; fails if it loaded or if the error does not name it.
fn load_err(path: &Path) -> String {
    common::error_naming(path, EnvMap::load(path))
}

fn random_map(w: u32, seed: u64) -> EnvMap {
    let mut rng = Rng::new(seed);
    let texels = (0..w * w / 2)
        .map(|_| [rng.f32() * 4.0, rng.f32(), rng.f32() * 0.25])
        .collect();
    EnvMap::from_texels(w, w / 2, texels, "random").unwrap()
}

// ---------------------------------------------------------------- geometry of the map

#[test]
fn solid_angles_sum_to_4pi() {
    for w in [2u32, 8, 64, 1024, 4096] {
        let env = EnvMap::from_texels(w, w / 2, vec![[0.0; 3]; (w * w / 2) as usize], "s").unwrap();
        let sum: f64 = (0..env.height).map(|y| env.solid_angle(y) * w as f64).sum();
        assert!((sum - 4.0 * PI).abs() < 1e-9, "{w}: {sum}");
        // Rows are symmetric about the equator and largest there.
        let h = env.height;
        for y in 0..h / 2 {
            let (a, b) = (env.solid_angle(y), env.solid_angle(h - 1 - y));
            assert!((a - b).abs() <= 1e-12 * a, "{w} row {y}");
        }
        assert_eq!(env.solid_angle(h), 0.0);
    }
}

#[test]
fn direction_texel_round_trip() {
    for w in [2u32, 8, 64, 1024] {
        let env = EnvMap::from_texels(w, w / 2, vec![[0.0; 3]; (w * w / 2) as usize], "r").unwrap();
        for y in 0..env.height {
            for x in 0..env.width {
                let d = env.direction(x, y);
                assert!((d.length() - 1.0).abs() < 1e-6);
                assert_eq!(env.texel_of(d), (x, y), "{w}: texel ({x}, {y})");
                // Length does not matter.
                assert_eq!(env.texel_of(d * 7.5), (x, y));
            }
        }
    }
    // Sparse check at 8192 x 4096, the poles and the seam included.
    let env = EnvMap::from_texels(8192, 4096, vec![[0.0; 3]; 8192 * 4096], "big").unwrap();
    for y in [0u32, 1, 2, 100, 2047, 2048, 4000, 4094, 4095] {
        for x in [0u32, 1, 4095, 4096, 8190, 8191] {
            assert_eq!(
                env.texel_of(env.direction(x, y)),
                (x, y),
                "8192: ({x}, {y})"
            );
        }
    }
}

#[test]
fn convention() {
    let env = EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "c").unwrap();
    // (u, v) = (0.5, 0.5) is -Z: the corner shared by texels 31..32 x 15..16.
    assert_eq!(env.texel_of(Vec3::NEG_Z), (32, 16));
    let mid = (env.direction(31, 15)
        + env.direction(32, 15)
        + env.direction(31, 16)
        + env.direction(32, 16))
    .normalize();
    assert!((mid - Vec3::NEG_Z).length() < 1e-6, "{mid}");
    // v = 0 (top row) is +Y, the bottom row -Y.
    assert_eq!(env.texel_of(Vec3::Y).1, 0);
    assert_eq!(env.texel_of(Vec3::NEG_Y).1, 31);
    assert!(env.direction(5, 0).y > 0.99 && env.direction(5, 31).y < -0.99);
    // u = 0.75 is +X, u = 0.25 is -X, u = 0 / 1 (the seam) is +Z.
    assert_eq!(env.texel_of(Vec3::X), (48, 16));
    assert_eq!(env.texel_of(Vec3::NEG_X), (16, 16));
    assert_eq!(env.texel_of(Vec3::Z), (0, 16));
    let d = env.direction(48, 10);
    assert!(d.x > 0.0 && d.z.abs() < 0.05 && d.y > 0.0, "{d}");
    // Right-handed, +Y up: the map's own +X (u = 0.75) cross its +Y (the top) is its +Z
    // (the seam), within the texel centres' half-texel offsets (a mirrored map gives -Z).
    let (mx, my, mz) = (
        env.direction(48, 16),
        env.direction(5, 0),
        env.direction(0, 16),
    );
    let z = mx.cross(my).normalize();
    assert!(
        (z - mz).length() < 0.15,
        "{mx} x {my} = {z}, +Z texel at {mz}"
    );
    // Degenerate directions give some texel, no panic.
    let _ = env.lookup(Vec3::ZERO);
    let _ = env.lookup(Vec3::NAN);
    let _ = env.lookup(Vec3::INFINITY);
}

#[test]
fn rotated_lookup_turns_the_environment() {
    let mut texels = vec![[0.0f32; 3]; 64 * 32];
    let (bx, by) = (10u32, 12u32);
    texels[(by * 64 + bx) as usize] = [5.0, 6.0, 7.0];
    let env = EnvMap::from_texels(64, 32, texels, "spot").unwrap();
    let d0 = env.direction(bx, by);
    for r in [
        Mat3::from_rotation_y(1.0),
        Mat3::from_rotation_x(0.7),
        Mat3::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 2.0),
    ] {
        // L_R(w) = L(R^-1 w): the bright texel now arrives from R d0.
        assert_eq!(env.rotated_lookup(r, r * d0), [5.0, 6.0, 7.0]);
        assert_eq!(
            env.rotated_lookup(r, d0.normalize()),
            env.lookup(r.transpose() * d0)
        );
    }
    assert_eq!(env.rotated_lookup(Mat3::IDENTITY, d0), [5.0, 6.0, 7.0]);
}

#[test]
fn downsampling_preserves_the_integral() {
    let env = random_map(128, 3);
    let full = env.integral();
    for w in [64u32, 32, 16, 8, 2] {
        let small = env.downsampled(w).unwrap();
        assert_eq!((small.width, small.height), (w, w / 2));
        let s = small.integral();
        for c in 0..3 {
            assert!(
                (s[c] - full[c]).abs() <= 1e-6 * full[c],
                "width {w}, channel {c}: {} vs {}",
                s[c],
                full[c]
            );
        }
    }
    // A constant map stays constant; width 128 is the identity.
    let c = EnvMap::from_texels(32, 16, vec![[0.5, 1.5, 2.5]; 32 * 16], "c").unwrap();
    for t in &c.downsampled(8).unwrap().texels {
        for (a, b) in t.iter().zip([0.5, 1.5, 2.5]) {
            assert!((a - b).abs() < 1e-6);
        }
    }
    assert_eq!(env.downsampled(128).unwrap().texels, env.texels);
    for bad in [0u32, 1, 3, 24, 256] {
        let e = env.downsampled(bad).expect_err("width accepted");
        assert!(e.to_string().contains(&format!("to width {bad}")), "{e}");
    }
}

#[test]
fn samples_match_the_accessors() {
    let env = random_map(16, 5);
    let s = env.samples();
    assert_eq!(s.len(), 16 * 8);
    for (i, (w, d, l)) in s.iter().enumerate() {
        let (x, y) = ((i % 16) as u32, (i / 16) as u32);
        assert_eq!(*w, env.direction(x, y));
        assert_eq!(*d, env.solid_angle(y));
        assert_eq!(*l, env.lookup(*w));
    }
}

// ---------------------------------------------------------------- files

/// A Radiance RGBE file: header, then flat pixels or new-style run-length scanlines.
fn rgbe_file(w: usize, h: usize, px: &[[u8; 4]], rle: bool, y_sign: char) -> Vec<u8> {
    let mut out = format!(
        "#?RADIANCE\n# made by the vkshade tests\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n{y_sign}Y {h} +X {w}\n"
    )
    .into_bytes();
    for row in px.chunks(w) {
        if !rle {
            row.iter().for_each(|p| out.extend_from_slice(p));
            continue;
        }
        out.extend_from_slice(&[2, 2, (w >> 8) as u8, (w & 255) as u8]);
        for c in 0..4 {
            let ch: Vec<u8> = row.iter().map(|p| p[c]).collect();
            let mut i = 0;
            while i < w {
                let mut run = 1;
                while i + run < w && run < 127 && ch[i + run] == ch[i] {
                    run += 1;
                }
                if run >= 3 {
                    out.extend_from_slice(&[128 + run as u8, ch[i]]);
                    i += run;
                } else {
                    let mut n = 0;
                    while i + n < w
                        && n < 128
                        && !(i + n + 2 < w
                            && ch[i + n] == ch[i + n + 1]
                            && ch[i + n] == ch[i + n + 2])
                    {
                        n += 1;
                    }
                    let n = n.max(1);
                    out.push(n as u8);
                    out.extend_from_slice(&ch[i..i + n]);
                    i += n;
                }
            }
        }
    }
    out
}

fn rgbe_value(p: [u8; 4]) -> [f32; 3] {
    if p[3] == 0 {
        return [0.0; 3];
    }
    let f = 2f32.powi(p[3] as i32 - 136);
    [p[0] as f32 * f, p[1] as f32 * f, p[2] as f32 * f]
}

fn rgbe_pixels(w: usize, h: usize) -> Vec<[u8; 4]> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if x < w / 2 {
                [128, 64, 32, 129] // 1, 0.5, 0.25: runs
            } else if y == 0 && x == w - 1 {
                [0, 0, 0, 0] // black
            } else {
                [
                    (x * 13 + y) as u8 | 128,
                    (x * 7) as u8,
                    y as u8,
                    120 + (x % 16) as u8,
                ]
            }
        })
        .collect()
}

#[test]
fn radiance_hdr_loads_flat_and_run_length() {
    let (w, h) = (40usize, 20usize);
    let px = rgbe_pixels(w, h);
    let want: Vec<[f32; 3]> = px.iter().map(|&p| rgbe_value(p)).collect();
    assert_eq!(want[0], [1.0, 0.5, 0.25]);
    for (name, rle) in [("flat.hdr", false), ("rle.hdr", true)] {
        let bytes = rgbe_file(w, h, &px, rle, '-');
        let path = write(name, &bytes);
        let env = EnvMap::load(&path).unwrap();
        assert_eq!((env.width, env.height), (40, 20), "{name}");
        assert_eq!(env.texels, want, "{name}");
        assert_eq!(env.source, path);
        // Every proper prefix is truncated.
        let header_end = bytes.windows(2).position(|p| p == b"\n\n").unwrap();
        for cut in [bytes.len() - 1, bytes.len() / 2, header_end + 12, 5] {
            let t = write(&format!("cut{cut}-{name}"), &bytes[..cut]);
            let e = load_err(&t);
            assert!(e.contains("truncated"), "{name} cut at {cut}: {e}");
        }
    }
    // Rows stored bottom-up (+Y) come back top row first.
    let path = write("flipped.hdr", &rgbe_file(w, h, &px, true, '+'));
    let env = EnvMap::load(&path).unwrap();
    for y in 0..h {
        assert_eq!(
            env.texels[y * w..(y + 1) * w],
            want[(h - 1 - y) * w..(h - y) * w]
        );
    }
    // Old-style runs: (1, 1, 1, n) repeats the previous pixel n times.
    let mut bytes = b"#?RGBE\n\n-Y 2 +X 4\n".to_vec();
    bytes.extend_from_slice(&[128, 128, 128, 130, 1, 1, 1, 3]); // row 0: 4 x (2, 2, 2)
    bytes.extend_from_slice(&[0, 0, 0, 0, 128, 0, 0, 128, 1, 1, 1, 2]); // row 1
    let env = EnvMap::load(&write("old.hdr", &bytes)).unwrap();
    assert_eq!(env.texels[..4], [[2.0; 3]; 4]);
    assert_eq!(
        env.texels[4..],
        [[0.0; 3], [0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]
    );
}

#[test]
fn malformed_files_are_errors_naming_them() {
    let missing = dir().join("missing.hdr");
    load_err(&missing);
    #[cfg(feature = "exr")]
    load_err(&dir().join("missing.exr"));

    let e = load_err(&write("map.png", b"\x89PNG\r\n\x1a\n"));
    assert!(e.contains("unknown environment-map format"), "{e}");
    let e = load_err(&write("noext", b"#?RADIANCE\n"));
    assert!(e.contains("unknown environment-map format"), "{e}");

    // Not 2:1.
    let px = rgbe_pixels(16, 16);
    let e = load_err(&write("square.hdr", &rgbe_file(16, 16, &px, true, '-')));
    assert!(e.contains("2:1"), "{e}");
    // Not a Radiance file, bad resolution line, unsupported format, bad runs.
    let e = load_err(&write("text.hdr", b"hello world\n"));
    assert!(e.contains("not a Radiance"), "{e}");
    load_err(&write("res.hdr", b"#?RADIANCE\n\n-Y 2 -X 4\n"));
    load_err(&write("res2.hdr", b"#?RADIANCE\n\n-Y two +X 4\n"));
    load_err(&write(
        "huge.hdr",
        b"#?RADIANCE\n\n-Y 99999999 +X 199999998\n",
    ));
    let e = load_err(&write(
        "xyz.hdr",
        b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 2\n\0\0\0\0\0\0\0\0",
    ));
    assert!(e.contains("xyze"), "{e}");
    let mut bad = b"#?RADIANCE\n\n-Y 1 +X 8\n".to_vec();
    bad.extend_from_slice(&[2, 2, 0, 8, 200, 1]); // a run of 72 in an 8-wide scanline
    load_err(&write("overrun.hdr", &bad));
    let mut bad = b"#?RADIANCE\n\n-Y 1 +X 2\n".to_vec();
    bad.extend_from_slice(&[1, 1, 1, 5, 0, 0, 0, 0]); // a run before any pixel
    load_err(&write("oldrun.hdr", &bad));

    // In-memory maps name their source too.
    for (texels, what) in [
        (vec![[f32::NAN, 0.0, 0.0]], "non-finite"),
        (vec![[0.0, f32::INFINITY, 0.0]], "non-finite"),
        (vec![[0.0, 0.0, -1.0]], "negative"),
    ] {
        let mut t = vec![[1.0f32; 3]; 8];
        t[5] = texels[0];
        let e = EnvMap::from_texels(4, 2, t, "memory-map")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("memory-map") && e.contains(what) && e.contains("(1, 1)"),
            "{e}"
        );
    }
    let err = |r: vkshade::Result<EnvMap>| r.expect_err("a bad map accepted").to_string();
    let e = err(EnvMap::from_texels(4, 2, vec![[0.0; 3]; 7], "m"));
    assert!(e.contains("7 texels given for a 4 x 2 map"), "{e}");
    let e = err(EnvMap::from_texels(0, 0, vec![], "m"));
    assert!(e.contains("must be 2:1") && e.contains("0 x 0"), "{e}");
    let e = err(EnvMap::from_texels(6, 2, vec![[0.0; 3]; 12], "m"));
    assert!(e.contains("must be 2:1") && e.contains("6 x 2"), "{e}");
}

#[cfg(feature = "exr")]
#[test]
fn exr_maps_load_and_bad_ones_are_errors() {
    use vkshade::io::FloatImage;
    use vkshade::io::exr::{Channels, write as write_exr};
    let exr = |name: &str, w: u32, h: u32, f: &dyn Fn(u32, u32) -> [f32; 4], ch| {
        let mut img = FloatImage {
            width: w,
            height: h,
            pixels: vec![[0.0; 4]; (w * h) as usize],
        };
        for y in 0..h {
            for x in 0..w {
                img.pixels[(y * w + x) as usize] = f(x, y);
            }
        }
        let p = dir().join(name);
        write_exr(&p, &img, ch).unwrap();
        p
    };
    let f = |x: u32, y: u32| [x as f32, y as f32 * 0.5, 0.25, 0.75];
    for ch in [Channels::Rgb, Channels::Rgba] {
        let p = exr("good.exr", 8, 4, &f, ch);
        let env = EnvMap::load(&p).unwrap();
        assert_eq!((env.width, env.height), (8, 4));
        assert_eq!(env.texels[3 * 8 + 5], [5.0, 1.5, 0.25]);
    }
    // The project's writer refuses a NaN (issue 21), so this file is written by the exr
    // crate directly, as another program would.
    let nan = dir().join("nan.exr");
    exr::prelude::write_rgb_file(&nan, 8, 4, |x, y| {
        if (x, y) == (2, 1) {
            (f32::NAN, f32::NAN, f32::NAN)
        } else {
            let p = f(x as u32, y as u32);
            (p[0], p[1], p[2])
        }
    })
    .unwrap();
    let e = load_err(&nan);
    assert!(e.contains("non-finite") && e.contains("(2, 1)"), "{e}");
    let neg = exr(
        "neg.exr",
        8,
        4,
        &|x, y| {
            if (x, y) == (7, 3) {
                [-0.5, 0.0, 0.0, 1.0]
            } else {
                f(x, y)
            }
        },
        Channels::Rgb,
    );
    // Strict: -0.5 against a mean sample of ~1.4 is an error; ringing-sized (-0.01) becomes
    // 0. The default repairs both (tests/envmap.rs's ringing test measures how).
    let e = common::error_naming(&neg, EnvMap::load_with(&neg, HdrPolicy::Strict));
    assert!(e.contains("negative") && e.contains("ringing"), "{e}");
    let repaired = EnvMap::load(&neg).unwrap();
    assert_eq!(repaired.texels[3 * 8 + 7], [0.0, 0.0, 0.0]);
    assert_eq!(repaired.repair.as_ref().unwrap().negative_samples, 1);
    let ring = |x, y| {
        if (x, y) == (7, 3) {
            [-0.01, 0.0, 0.0, 1.0]
        } else {
            f(x, y)
        }
    };
    let p = exr("ring.exr", 8, 4, &ring, Channels::Rgb);
    assert_eq!(
        EnvMap::load_with(&p, HdrPolicy::Strict).unwrap().texels[3 * 8 + 7],
        [0.0, 0.0, 0.0]
    );
    let p = exr(
        "allneg.exr",
        8,
        4,
        &|_, _| [-1e-6, 0.0, 0.0, 1.0],
        Channels::Rgb,
    );
    load_err(&p);
    let e = load_err(&exr("tall.exr", 4, 8, &f, Channels::Rgb));
    assert!(e.contains("2:1"), "{e}");
    let p = exr("whole.exr", 64, 32, &f, Channels::Rgba);
    let bytes = std::fs::read(&p).unwrap();
    for cut in [bytes.len() - 10, bytes.len() / 2, 100, 3] {
        load_err(&write(&format!("cut{cut}.exr"), &bytes[..cut]));
    }
    load_err(&write("junk.exr", b"this is not an exr file at all"));
}

/// The Blender studio lights (DWAB-compressed half-float EXRs): the real inputs.
#[cfg(feature = "exr")]
#[test]
fn blender_studio_lights_load() {
    let folder = Path::new("/usr/share/blender/datafiles/studiolights/world");
    assert!(
        folder.is_dir(),
        "{} is missing: install the Blender studio lights with `apt-get install blender-data`",
        folder.display()
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(folder)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 8,
        "only {} maps in {}",
        files.len(),
        folder.display()
    );
    for f in files {
        let t = std::time::Instant::now();
        let env = EnvMap::load(&f).unwrap_or_else(|e| panic!("{e}"));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        assert_eq!((env.width, env.height), (1024, 512), "{}", f.display());
        let i = env.integral();
        let max = env.texels.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
        println!(
            "{}: {}x{} in {ms:.1} ms, integral ({:.3}, {:.3}, {:.3}), max texel {max:.2}",
            f.file_name().unwrap().to_string_lossy(),
            env.width,
            env.height,
            i[0],
            i[1],
            i[2]
        );
        assert!(
            i.iter().all(|c| c.is_finite() && *c > 0.0),
            "{}",
            f.display()
        );
    }
}

// ---------------------------------------------------------------- brute-force reference

/// A closed UV sphere: radius 1, outward normals.
fn uv_sphere(rings: u32, segs: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut pos = vec![Vec3::Y];
    for i in 1..rings {
        let t = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segs {
            let p = 2.0 * std::f32::consts::PI * j as f32 / segs as f32;
            pos.push(Vec3::new(t.sin() * p.cos(), t.cos(), t.sin() * p.sin()));
        }
    }
    pos.push(Vec3::NEG_Y);
    let last = pos.len() as u32 - 1;
    let ring = |i: u32, j: u32| 1 + (i - 1) * segs + j % segs;
    let mut tris = Vec::new();
    for j in 0..segs {
        tris.push([0, ring(1, j + 1), ring(1, j)]);
        tris.push([last, ring(rings - 1, j), ring(rings - 1, j + 1)]);
        for i in 1..rings - 1 {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            tris.push([a, b, d]);
            tris.push([a, d, c]);
        }
    }
    (pos, tris)
}

fn dirs(env: &EnvMap) -> Vec<Vec3> {
    env.samples().iter().map(|s| s.0).collect()
}

#[test]
fn constant_environment_on_an_open_plane() {
    let c = [0.7f32, 1.3, 2.0];
    let albedo = [0.8f32, 0.5, 0.25];
    let env = EnvMap::from_texels(64, 32, vec![c; 64 * 32], "const").unwrap();
    let d = dirs(&env);
    // A ground quad at y = 0; receivers on it facing up, away from it.
    let quad = [
        Vec3::new(-5.0, 0.0, -5.0),
        Vec3::new(5.0, 0.0, -5.0),
        Vec3::new(5.0, 0.0, 5.0),
        Vec3::new(-5.0, 0.0, 5.0),
    ];
    let bvh = Bvh::build(&quad, &[[0, 1, 2], [0, 2, 3]]);
    let pos = vec![Vec3::ZERO, Vec3::new(1.0, 0.0, -2.0)];
    let nrm = vec![Vec3::Y; 2];
    let vis = direction_visibility(&pos, &nrm, &bvh, &d, 1e-4);
    assert_eq!(
        vis.visible_count(0),
        64 * 16,
        "the whole upper hemisphere is open"
    );
    let out = shade_brute_force(&env, Mat3::IDENTITY, &nrm, &vis, albedo).unwrap();
    // The cosine quadrature over the upper hemisphere at 64 x 32.
    let q: f64 = env
        .samples()
        .iter()
        .map(|(w, d, _)| (w.y as f64).max(0.0) * d)
        .sum();
    let qerr = (q - PI).abs() / PI;
    println!("64x32, n = +Y: sum max(0, n.w) dOmega = {q:.9}, relative error {qerr:.3e}");
    assert!(qerr < 1.25e-3, "quadrature error {qerr}");
    for v in &out {
        for ch in 0..3 {
            let exact = albedo[ch] as f64 * c[ch] as f64;
            // The sum is exactly albedo * c * q / pi: only the quadrature differs from exact.
            let want = exact * q / PI;
            assert!((v[ch] - want).abs() <= 1e-12 * want, "{} vs {want}", v[ch]);
            assert!(
                (v[ch] - exact).abs() <= 1.25e-3 * exact,
                "{} vs {exact}",
                v[ch]
            );
        }
    }
    // With no geometry at all, tilted normals: same up to the quadrature error.
    let empty = Bvh::build(&[], &[]);
    let mut rng = Rng::new(11);
    let nrm: Vec<Vec3> = (0..64)
        .map(|_| vkshade::geom::uniform_sphere(rng.f32(), rng.f32()))
        .collect();
    let pos = vec![Vec3::ZERO; nrm.len()];
    let vis = direction_visibility(&pos, &nrm, &empty, &d, 1e-4);
    let out = shade_brute_force(&env, Mat3::IDENTITY, &nrm, &vis, [1.0; 3]).unwrap();
    let worst = out
        .iter()
        .map(|v| (v[0] - c[0] as f64).abs() / c[0] as f64)
        .fold(0.0f64, f64::max);
    println!("64x32, 64 random normals: max relative error {worst:.3e}");
    assert!(worst < 3e-3, "{worst}");
}

#[test]
fn closed_sphere_does_not_shadow_its_own_hemisphere() {
    let (pos, tris) = uv_sphere(16, 32);
    let nrm: Vec<Vec3> = pos.iter().map(|p| p.normalize()).collect();
    let bvh = Bvh::build(&pos, &tris);
    let env = EnvMap::from_texels(64, 32, vec![[1.0; 3]; 64 * 32], "c").unwrap();
    let d = dirs(&env);
    let vis = direction_visibility(&pos, &nrm, &bvh, &d, 1e-4);
    assert_eq!(vis.vertices, pos.len());
    for (v, n) in nrm.iter().enumerate() {
        for (k, w) in d.iter().enumerate() {
            let c = n.dot(*w);
            if c > 0.1 {
                assert!(
                    vis.visible(v, k),
                    "vertex {v} direction {k} (n.w = {c}) blocked"
                );
            }
            if c <= 0.0 {
                assert!(!vis.visible(v, k), "vertex {v} sees below its horizon");
            }
        }
    }
    assert!(!vis.visible(pos.len(), 0) && !vis.visible(0, d.len()));
}

#[test]
fn quad_overhead_occludes_the_sky() {
    let s = 10.0;
    let quad = [
        Vec3::new(-s, 1.0, -s),
        Vec3::new(s, 1.0, -s),
        Vec3::new(s, 1.0, s),
        Vec3::new(-s, 1.0, s),
    ];
    let bvh = Bvh::build(&quad, &[[0, 1, 2], [0, 2, 3]]);
    let env = random_map(64, 9);
    let d = dirs(&env);
    let vis = direction_visibility(&[Vec3::ZERO], &[Vec3::Y], &bvh, &d, 1e-4);
    let mut open = 0;
    for (k, w) in d.iter().enumerate() {
        if w.y > 0.15 {
            assert!(!vis.visible(0, k), "direction {w} should hit the quad");
        }
        if w.y <= 0.0 {
            assert!(!vis.visible(0, k));
        }
        open += vis.visible(0, k) as usize;
    }
    // The grazing row (y = cos 87.2 deg = 0.049) leaves past the quad's edge.
    assert!(open > 0 && open <= 64, "{open} directions open");
    // Fully blocked receiver (quad above, sky only near the horizon) is darker than open.
    let empty = Bvh::build(&[], &[]);
    let free = direction_visibility(&[Vec3::ZERO], &[Vec3::Y], &empty, &d, 1e-4);
    let a = shade_brute_force(&env, Mat3::IDENTITY, &[Vec3::Y], &vis, [1.0; 3]).unwrap();
    let b = shade_brute_force(&env, Mat3::IDENTITY, &[Vec3::Y], &free, [1.0; 3]).unwrap();
    for c in 0..3 {
        assert!(a[0][c] < 0.1 * b[0][c], "{:?} vs {:?}", a[0], b[0]);
    }
}

#[test]
fn rotation_by_whole_texels_and_full_turns() {
    let env = random_map(64, 21);
    let d = dirs(&env);
    let (pos, tris) = uv_sphere(8, 16);
    let nrm: Vec<Vec3> = pos.iter().map(|p| p.normalize()).collect();
    // A ground quad under the sphere, so some directions are occluded.
    let g = [
        Vec3::new(-3.0, -1.2, -3.0),
        Vec3::new(3.0, -1.2, -3.0),
        Vec3::new(3.0, -1.2, 3.0),
        Vec3::new(-3.0, -1.2, 3.0),
    ];
    let mut all = pos.clone();
    all.extend_from_slice(&g);
    let n = pos.len() as u32;
    let mut t = tris.clone();
    t.push([n, n + 1, n + 2]);
    t.push([n, n + 2, n + 3]);
    let bvh = Bvh::build(&all, &t);
    let vis = direction_visibility(&pos, &nrm, &bvh, &d, 1e-4);
    let albedo = [0.9, 0.6, 0.3];
    let base = shade_brute_force(&env, Mat3::IDENTITY, &nrm, &vis, albedo).unwrap();
    let full = std::f32::consts::TAU;
    for r in [
        Mat3::from_rotation_y(full),
        Mat3::from_rotation_y(-2.0 * full),
    ] {
        let turned = shade_brute_force(&env, r, &nrm, &vis, albedo).unwrap();
        assert_eq!(turned, base);
    }
    // Turning about +Y by k columns (k 360/W degrees) equals shading the map with its
    // columns shifted by k: L_R(w) = L(R^-1 w) and R^-1 adds k columns to u.
    for k in [1u32, 5, 32, 63] {
        let r = Mat3::from_rotation_y(full * k as f32 / 64.0);
        let turned = shade_brute_force(&env, r, &nrm, &vis, albedo).unwrap();
        let shifted: Vec<[f32; 3]> = (0..32)
            .flat_map(|y| (0..64).map(move |x| (x, y)))
            .map(|(x, y)| env.texel((x + k) % 64, y))
            .collect();
        let moved = EnvMap::from_texels(64, 32, shifted, "shifted").unwrap();
        let want = shade_brute_force(&moved, Mat3::IDENTITY, &nrm, &vis, albedo).unwrap();
        assert_eq!(turned, want, "k = {k}");
        assert_ne!(turned, base, "k = {k}");
    }
}

#[test]
fn brute_force_rejects_mismatched_inputs() {
    let env = random_map(16, 1);
    let d = dirs(&env);
    let empty = Bvh::build(&[], &[]);
    let vis = direction_visibility(&[Vec3::ZERO], &[Vec3::Y], &empty, &d, 1e-4);
    let other = random_map(32, 1);
    let err = |r: vkshade::Result<Vec<[f64; 3]>>| r.expect_err("bad input accepted").to_string();
    let e = err(shade_brute_force(
        &other,
        Mat3::IDENTITY,
        &[Vec3::Y],
        &vis,
        [1.0; 3],
    ));
    assert!(e.contains("the visibility has"), "{e}");
    let mut wrong = d.clone();
    wrong.swap(0, 1);
    let vis2 = direction_visibility(&[Vec3::ZERO], &[Vec3::Y], &empty, &wrong, 1e-4);
    let e = err(shade_brute_force(
        &env,
        Mat3::IDENTITY,
        &[Vec3::Y],
        &vis2,
        [1.0; 3],
    ));
    assert!(e.contains("visibility direction 0"), "{e}");
    let e = err(shade_brute_force(
        &env,
        Mat3::IDENTITY,
        &[Vec3::Y, Vec3::X],
        &vis,
        [1.0; 3],
    ));
    assert!(
        e.contains("2 normals for a visibility of 1 vertices"),
        "{e}"
    );
    for (name, m) in [
        ("scaled", Mat3::from_diagonal(Vec3::splat(2.0))),
        ("mirrored", Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0))),
    ] {
        let e = err(shade_brute_force(&env, m, &[Vec3::Y], &vis, [1.0; 3]));
        assert!(e.contains("not a rotation matrix"), "{name}: {e}");
    }
    let e = err(shade_brute_force(
        &env,
        Mat3::IDENTITY,
        &[Vec3::Y],
        &vis,
        [f32::NAN, 1.0, 1.0],
    ));
    assert!(e.contains("albedo"), "{e}");
    assert!(shade_brute_force(&env, Mat3::IDENTITY, &[Vec3::Y], &vis, [1.0; 3]).is_ok());
}

/// Texels that would overflow the f32 sums after the loader (issue 21): a 3e38 texel in an
/// EXR or an in-memory map, and an RGBE file whose exponent decodes to ~1.7e38, are refused
/// naming the file and the texel; 1e12 (the bound) loads.
#[test]
fn texels_above_the_radiance_bound_are_refused() {
    let mut t = vec![[1.0f32; 3]; 8 * 4];
    t[9] = [3e38, 1.0, 1.0];
    let e = common::error_naming(
        Path::new("huge"),
        EnvMap::from_texels(8, 4, t.clone(), "huge"),
    );
    assert!(e.contains("texel (1, 1)") && e.contains("1e12"), "{e}");
    t[9] = [MAX_RADIANCE; 3];
    assert!(EnvMap::from_texels(8, 4, t, "edge").is_ok());
    // RGBE (255, 255, 255, 255): 255 x 2^119 ~ 1.7e38.
    let mut px = vec![[128u8, 128, 128, 129]; 8 * 4];
    px[30] = [255, 255, 255, 255];
    let p = write("huge.hdr", &rgbe_file(8, 4, &px, false, '-'));
    let e = load_err(&p);
    assert!(e.contains("texel (6, 3)") && e.contains("above"), "{e}");
    #[cfg(feature = "exr")]
    {
        let img = vkshade::io::FloatImage {
            width: 8,
            height: 4,
            pixels: (0..32)
                .map(|i| {
                    if i == 5 {
                        [3e38, 0.0, 0.0, 1.0]
                    } else {
                        [0.5; 4]
                    }
                })
                .collect(),
        };
        let p = dir().join("huge.exr");
        vkshade::io::exr::write(&p, &img, vkshade::io::exr::Channels::Rgb).unwrap();
        let e = load_err(&p);
        assert!(e.contains("texel (5, 0)") && e.contains("above"), "{e}");
    }
}

/// A sun with DWAB-like ringing (issue 21, point 4): the ring-free map is a dim sky plus a
/// 4 x 4 texel sun of 11,800; the ringing adds, around the sun, a zero-sum oscillation
/// (a damped cosine in the distance from the sun, its mean removed per 8 x 8 block) scaled
/// so its most negative sample is about -2,000. Written as EXR through the project's
/// writer, the map loads by default with no negative texel, and its energy (the integral
/// over the sphere, per channel) is within 1e-4 (relative) of the ring-free map's: the
/// repair moves the negative lobes' energy into the positive ones beside them, and the
/// ringing itself adds (to f32 rounding) no energy; clamping instead would add the
/// negative lobes' whole energy (measured here too, as the figure the repair avoids).
/// Under `HdrPolicy::Strict` the map is refused.
#[cfg(feature = "exr")]
#[test]
fn a_sun_with_codec_ringing_loads_keeping_its_energy_and_strict_refuses_it() {
    let (w, h) = (256usize, 128usize);
    let sun = (100usize, 40usize);
    let clean: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if (sun.0..sun.0 + 4).contains(&x) && (sun.1..sun.1 + 4).contains(&y) {
                [11_800.0, 11_000.0, 9_500.0]
            } else {
                [0.3, 0.4, 0.6]
            }
        })
        .collect();
    // The ringing: damped cosine of the distance to the sun's centre, within 12 texels,
    // zero energy over each 8 x 8 block (its solid-angle-weighted mean removed), so the
    // ringing map's energy is the ring-free map's (to f32 rounding of the texels).
    let clean_map = EnvMap::from_texels(w as u32, h as u32, clean.clone(), "clean").unwrap();
    let omega = |y: usize| clean_map.solid_angle(y as u32);
    let mut ring = vec![0.0f64; w * h];
    let (cx, cy) = (sun.0 as f64 + 2.0, sun.1 as f64 + 2.0);
    for y in 0..h {
        for x in 0..w {
            let d = ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2)).sqrt();
            if d < 12.0 && d > 2.9 {
                ring[y * w + x] = (d * 1.9).cos() * (-d / 6.0).exp();
            }
        }
    }
    for by in (0..h).step_by(8) {
        for bx in (0..w).step_by(8) {
            let idx: Vec<usize> = (by..by + 8)
                .flat_map(|y| (bx..bx + 8).map(move |x| y * w + x))
                .collect();
            if idx.iter().all(|&i| ring[i] == 0.0) {
                continue;
            }
            let e: f64 = idx.iter().map(|&i| ring[i] * omega(i / w)).sum();
            let o: f64 = idx.iter().map(|&i| omega(i / w)).sum();
            idx.iter().for_each(|&i| ring[i] -= e / o);
        }
    }
    let min = ring.iter().cloned().fold(0.0, f64::min);
    let scale = -2_000.0 / min;
    let ringing: Vec<[f32; 3]> = clean
        .iter()
        .zip(&ring)
        .map(|(c, r)| c.map(|v| v + (r * scale) as f32))
        .collect();
    let negatives = ringing.iter().flatten().filter(|v| **v < 0.0).count();
    let most = ringing.iter().flatten().cloned().fold(0.0f32, f32::min);
    assert!(
        negatives > 20 && most < -1_500.0,
        "{negatives} negatives down to {most}"
    );
    let img = vkshade::io::FloatImage {
        width: w as u32,
        height: h as u32,
        pixels: ringing.iter().map(|t| [t[0], t[1], t[2], 1.0]).collect(),
    };
    let path = dir().join("sun-ringing.exr");
    vkshade::io::exr::write(&path, &img, vkshade::io::exr::Channels::Rgb).unwrap();

    let truth = clean_map.integral();
    // The signed ringing map's energy: equal to the truth but for f32 rounding.
    let mut ringing_energy = [0.0f64; 3];
    for (y, row) in ringing.chunks(w).enumerate() {
        for t in row {
            for c in 0..3 {
                ringing_energy[c] += t[c] as f64 * omega(y);
            }
        }
    }
    let loaded = EnvMap::load(&path).unwrap();
    assert!(loaded.texels.iter().flatten().all(|v| *v >= 0.0));
    let repair = loaded.repair.clone().expect("a repair report");
    assert_eq!(repair.negative_samples, negatives);
    assert_eq!(repair.most_negative, most);
    let got = loaded.integral();
    let clamped = {
        let t: Vec<[f32; 3]> = ringing.iter().map(|t| t.map(|v| v.max(0.0))).collect();
        EnvMap::from_texels(w as u32, h as u32, t, "clamped")
            .unwrap()
            .integral()
    };
    for c in 0..3 {
        let rel = (got[c] - truth[c]).abs() / truth[c];
        let ring_rel = (ringing_energy[c] - truth[c]).abs() / truth[c];
        let clamp_rel = (clamped[c] - truth[c]) / truth[c];
        println!(
            "channel {c}: repaired {rel:.2e}, ringing itself {ring_rel:.2e}, clamping {clamp_rel:.2e} \
             (relative to the ring-free energy); {repair}"
        );
        assert!(rel < 1e-4, "channel {c}: {rel:e}");
        // The repair keeps the ringing map's energy, and clamping would not have.
        assert!(
            clamp_rel > 10.0 * rel.max(1e-6),
            "channel {c}: clamp {clamp_rel:e}"
        );
    }
    assert!(repair.energy_change.abs() < 1e-5, "{repair:?}");
    assert!(repair.moved_fraction > 1e-3, "{repair:?}");
    // The sun is still where it was and about as bright.
    let s = loaded.texel(sun.0 as u32 + 1, sun.1 as u32 + 1);
    assert!(s[0] > 10_000.0 && s[0] < 13_000.0, "{s:?}");
    // Strict refuses it, naming the file.
    let e = common::error_naming(&path, EnvMap::load_with(&path, HdrPolicy::Strict));
    assert!(e.contains("negative"), "{e}");
}
