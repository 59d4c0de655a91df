//! Output files: linear EXR images (round trip, bad files named in errors), atomic writes,
//! and the side-by-side reference picture every kernel uses.

mod scratch;
use vkshade::io::FloatImage;
use vkshade::io::exr::{self, Channels};
use vkshade::render::{Picture, SideBySideLayout, heat, label, side_by_side, side_by_side_linear};

/// A scratch folder of its own for test `test` (tests run in parallel: a shared one let one
/// test see another's temporary files, as the leftover check below did).
fn dir(test: &str) -> std::path::PathBuf {
    scratch::dir(&format!("io-{test}"))
}

fn gradient(w: u32, h: u32) -> FloatImage {
    let mut img = FloatImage::new(w, h, [0.0; 4]);
    for y in 0..h {
        for x in 0..w {
            // Values a display could not hold: negative, above 1, tiny, huge.
            let v = (x as f32 - 3.0) * 0.37 + y as f32 * 1e-3;
            img.set(x, y, [v, v * 1e4, 1e-7 * x as f32, (y as f32) / h as f32]);
        }
    }
    img
}

#[test]
fn exr_round_trips_linear_floats_exactly() {
    let img = gradient(37, 11);
    let d = dir("round-trip");
    let path = d.join("round.exr");
    exr::write(&path, &img, Channels::Rgba).unwrap();
    assert_eq!(exr::read_rgba(&path).unwrap(), img);
    // RGB only: alpha reads back as 1.
    let rgb = d.join("round_rgb.exr");
    exr::write(&rgb, &img, Channels::Rgb).unwrap();
    let back = exr::read_rgba(&rgb).unwrap();
    for (a, b) in img.pixels.iter().zip(&back.pixels) {
        assert_eq!((a[0], a[1], a[2], b[3]), (b[0], b[1], b[2], 1.0));
    }
    // No temporary files are left beside the outputs.
    let leftovers: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn bad_exr_files_and_shapes_give_errors_naming_the_file() {
    let d = dir("bad-files");
    let missing = d.join("missing.exr");
    let e = exr::read_rgba(&missing).unwrap_err().to_string();
    assert!(e.contains("missing.exr"), "{e}");

    let png = d.join("not_exr.exr");
    std::fs::write(&png, b"\x89PNG\r\n\x1a\nnot an exr at all").unwrap();
    let e = exr::read_rgba(&png).unwrap_err().to_string();
    assert!(
        e.contains("not_exr.exr") && e.contains("not an OpenEXR"),
        "{e}"
    );

    // The right magic number, then garbage: the decoder's complaint, with the file's name.
    let truncated = d.join("truncated.exr");
    let good = d.join("good.exr");
    exr::write(&good, &gradient(8, 8), Channels::Rgba).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 3]).unwrap();
    let e = exr::read_rgba(&truncated).unwrap_err().to_string();
    assert!(e.contains("truncated.exr"), "{e}");

    let bad = FloatImage {
        width: 4,
        height: 4,
        pixels: vec![[0.0; 4]; 3],
    };
    let out = d.join("bad_shape.exr");
    let e = exr::write(&out, &bad, Channels::Rgba)
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad_shape.exr") && e.contains("3 pixels"), "{e}");
    assert!(!out.exists(), "a refused image must not leave a file");

    // A folder that cannot be created: the error names it.
    let blocker = d.join("blocker");
    std::fs::write(&blocker, b"a file").unwrap();
    let e = exr::write(&blocker.join("x.exr"), &gradient(2, 2), Channels::Rgb)
        .unwrap_err()
        .to_string();
    assert!(e.contains("blocker"), "{e}");
}

fn flat(w: u32, h: u32, c: u8) -> Picture {
    Picture {
        width: w,
        height: h,
        rgb: vec![c; (w * h * 3) as usize],
    }
}

#[test]
fn side_by_side_places_result_truth_and_error_with_a_colour_bar() {
    let (w, h) = (50, 40);
    let mut error = vec![f32::NAN; (w * h) as usize];
    error[(20 * w + 25) as usize] = 0.1; // half the scale
    error[(21 * w + 25) as usize] = 5.0; // saturates
    let p = side_by_side(&flat(w, h, 200), &flat(w, h, 100), &error, 0.2).unwrap();
    let layout = SideBySideLayout {
        panel_width: w,
        panel_height: h,
    };
    assert_eq!((p.width, p.height), layout.size());
    let px = |x: u32, y: u32| {
        let o = 3 * (y * p.width + x) as usize;
        [p.rgb[o], p.rgb[o + 1], p.rgb[o + 2]]
    };
    let (rx, ry) = layout.panel_origin(0);
    let (tx, ty) = layout.panel_origin(1);
    let (ex, ey) = layout.panel_origin(2);
    assert_eq!(px(rx + 10, ry + 10), [200; 3]);
    assert_eq!(px(tx + 10, ty + 10), [100; 3]);
    assert_eq!(px(ex + 25, ey + 20), heat(0.5));
    assert_eq!(px(ex + 25, ey + 21), heat(1.0));
    // The bar runs from the hottest colour at the top to the coldest at the bottom.
    let bar: Vec<[u8; 3]> = (0..p.height).map(|y| px(3 * w + 15, y)).collect();
    assert!(bar.contains(&heat(1.0)) && bar.contains(&heat(0.0)));
    // Text was drawn in the title strip.
    assert!((0..SideBySideLayout::TITLE_HEIGHT).any(|y| px(rx + 10, y) != [255; 3]));

    // The linear twin has the same layout and the panels' values.
    let lin = side_by_side_linear(
        &FloatImage::new(w, h, [0.25, 0.25, 0.25, 1.0]),
        &FloatImage::new(w, h, [0.5; 4]),
        &FloatImage::new(w, h, [0.75; 4]),
    )
    .unwrap();
    assert_eq!((lin.width, lin.height), layout.size());
    assert_eq!(lin.get(rx + 1, ry + 1), Some([0.25, 0.25, 0.25, 1.0]));
    assert_eq!(lin.get(ex + 1, ey + 1), Some([0.75; 4]));
    assert_eq!(lin.get(3 * w + 5, 5), Some([0.0; 4]));
}

#[test]
fn side_by_side_refuses_mismatched_inputs() {
    let e = side_by_side(&flat(10, 10, 0), &flat(10, 9, 0), &[0.0; 100], 1.0).unwrap_err();
    assert!(e.to_string().contains("same image"), "{e}");
    let e = side_by_side(&flat(10, 10, 0), &flat(10, 10, 0), &[0.0; 99], 1.0).unwrap_err();
    assert!(e.to_string().contains("99 error"), "{e}");
    let e = side_by_side(&flat(10, 10, 0), &flat(10, 10, 0), &[0.0; 100], 0.0).unwrap_err();
    assert!(e.to_string().contains("scale"), "{e}");
    assert_eq!(label(0.2), "0.2");
    assert_eq!(label(0.15), "0.15");
    assert_eq!(label(0.0), "0");
    assert_eq!(label(1.5e-4), "1.5E-4");
}

/// A report holding a NaN or an infinity is refused naming the file and the value's path,
/// and nothing is written (serde_json alone would write `null`). An existing file of that
/// name is left as it was.
#[test]
fn json_reports_with_non_finite_numbers_are_refused_by_path() {
    #[derive(serde::Serialize)]
    struct Pass {
        name: &'static str,
        median_ms: f64,
    }
    #[derive(serde::Serialize)]
    struct Report {
        passes: Vec<Pass>,
        fps: Option<f32>,
    }
    let d = dir("json_non_finite");
    let path = d.join("report.json");
    let good = Report {
        passes: vec![Pass {
            name: "skin",
            median_ms: 1.5,
        }],
        fps: None,
    };
    vkshade::io::write_json(&path, &good).unwrap();
    let before = std::fs::read(&path).unwrap();
    for (report, at, value) in [
        (
            Report {
                passes: vec![
                    Pass {
                        name: "a",
                        median_ms: 1.0,
                    },
                    Pass {
                        name: "b",
                        median_ms: f64::NAN,
                    },
                ],
                fps: None,
            },
            "passes[1].median_ms",
            "NaN",
        ),
        (
            Report {
                passes: Vec::new(),
                fps: Some(f32::INFINITY),
            },
            "fps",
            "inf",
        ),
    ] {
        let e = vkshade::io::write_json(&path, &report)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("report.json") && e.contains(at) && e.contains(value),
            "{e}"
        );
        assert_eq!(std::fs::read(&path).unwrap(), before, "{at}: file changed");
    }
    let left: Vec<_> = std::fs::read_dir(&d).unwrap().collect();
    assert_eq!(left.len(), 1, "a temporary file was left: {left:?}");
}
