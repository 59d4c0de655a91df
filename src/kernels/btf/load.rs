//! Loading UBO2003-style BTF directories (one image per (light, view) pair, the angles in
//! the file name as `tlTTT plPPP tvTTT pvPPP` in any separators, e.g.
//! `00042 tl015 pl060 tv030 pv000.png` or `btf_tl015_pl060_tv030_pv000.exr`), and the
//! repeating-tile finder that cuts one period out of a larger sample.
//!
//! PNG and JPEG images (UBO2003 ships sRGB JPEG) are taken as sRGB-encoded and decoded to
//! linear; EXR images are linear.

use super::dirs::{self, Angles};
use super::synth::Btf;
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The number after `key` in `name` (the last occurrence whose next character is a digit).
fn number_after(name: &str, key: &str) -> Option<u32> {
    let lower = name.to_ascii_lowercase();
    let mut found = None;
    let mut from = 0;
    while let Some(i) = lower[from..].find(key) {
        let start = from + i + key.len();
        let digits: String = lower[start..]
            .chars()
            .take_while(|c| c.is_ascii_digit())
            .collect();
        if !digits.is_empty() {
            found = digits.parse().ok();
        }
        from = start;
    }
    found
}

/// The (light, view) angles in a file name, if it names all four.
pub fn parse_name(name: &str) -> Option<(Angles, Angles)> {
    let stem = name.rsplit_once('.').map(|s| s.0).unwrap_or(name);
    Some((
        Angles {
            theta: number_after(stem, "tl")?,
            phi: number_after(stem, "pl")?,
        },
        Angles {
            theta: number_after(stem, "tv")?,
            phi: number_after(stem, "pv")?,
        },
    ))
}

fn is_image(path: &Path) -> bool {
    path.extension()
        .map(|e| {
            let e = e.to_string_lossy().to_ascii_lowercase();
            e == "png" || e == "exr" || e == "jpg" || e == "jpeg"
        })
        .unwrap_or(false)
}

/// Reads one BTF image (PNG/JPEG as sRGB, EXR as linear) as linear RGB: its size and texels.
/// What [`load_dir`] does with each file; an error names the file.
pub fn read_image(path: &Path) -> Result<([u32; 2], Vec<[f32; 3]>)> {
    let exr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if exr {
        #[cfg(feature = "exr")]
        {
            let img = crate::io::exr::read_rgba(path)?;
            return Ok((
                [img.width, img.height],
                img.pixels.iter().map(|p| [p[0], p[1], p[2]]).collect(),
            ));
        }
        #[cfg(not(feature = "exr"))]
        return Err(Error::feature(
            format!("reading the EXR {}", path.display()),
            "exr",
        ));
    }
    #[cfg(feature = "png")]
    {
        // The decoder sizes its buffer from the header: bound it by what the file could
        // hold before it allocates (`io::image_bounds`).
        use crate::io::image_bounds::{MAX_IMAGE_SIDE, decode_budget, limits};
        let file_bytes = std::fs::metadata(path)
            .map_err(|e| Error::io(path, e))?
            .len();
        let mut reader = image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
        reader.limits(limits(file_bytes));
        let img = reader
            .decode()
            .map_err(|e| match e {
                image::ImageError::Limits(_) => Error::input(
                    path,
                    format!(
                        "its header claims an image larger than a {file_bytes}-byte file can \
                         hold (at most {MAX_IMAGE_SIDE} texels a side and {} MiB decoded): {e}",
                        decode_budget(file_bytes) >> 20
                    ),
                ),
                e => Error::input(path, format!("cannot read the image: {e}")),
            })?
            .to_rgb8();
        let lut: Vec<f32> = (0..=255u8)
            .map(|b| super::synth::srgb_decode(b) as f32)
            .collect();
        Ok((
            [img.width(), img.height()],
            img.pixels().map(|p| p.0.map(|b| lut[b as usize])).collect(),
        ))
    }
    #[cfg(not(feature = "png"))]
    Err(Error::feature(
        format!("reading the PNG {}", path.display()),
        "png",
    ))
}

/// Largest data set [`load_dir`] accepts, in bytes of linear f32 texels.
pub const MAX_BYTES: u64 = 8 << 30;

/// Loads the BTF in directory `dir`. Every one of the 81 x 81 (light, view) pairs must be
/// present exactly once, all images the same size; files whose names carry no angles are
/// ignored. Errors name the directory or the file and what is wrong.
pub fn load_dir(dir: &Path) -> Result<Btf> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut slots: Vec<Option<PathBuf>> = vec![None; dirs::COUNT * dirs::COUNT];
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        if !is_image(&path) {
            continue;
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some((l, v)) = parse_name(&name) else {
            continue;
        };
        let (Some(li), Some(vi)) = (dirs::index_of(l), dirs::index_of(v)) else {
            return Err(Error::input(
                &path,
                format!(
                    "light (theta {}, phi {}) / view (theta {}, phi {}) is not one of the 81 UBO2003 directions",
                    l.theta, l.phi, v.theta, v.phi
                ),
            ));
        };
        let slot = &mut slots[vi * dirs::COUNT + li];
        if let Some(other) = slot {
            return Err(Error::input(
                &path,
                format!("names the same (light, view) pair as {}", other.display()),
            ));
        }
        *slot = Some(path);
    }
    let d = dirs::directions();
    let missing: Vec<String> = slots
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_none())
        .map(|(s, _)| {
            let (l, v) = (d[s % dirs::COUNT], d[s / dirs::COUNT]);
            format!(
                "tl{:03} pl{:03} tv{:03} pv{:03}",
                l.theta, l.phi, v.theta, v.phi
            )
        })
        .collect();
    if !missing.is_empty() {
        return Err(Error::input(
            dir,
            format!(
                "{} of the 6561 (light, view) images are missing, e.g. {}",
                missing.len(),
                missing[..missing.len().min(4)].join(", ")
            ),
        ));
    }
    let paths: Vec<PathBuf> = slots.into_iter().flatten().collect();
    // The first image tells the size: refuse a data set that would not fit in memory as
    // linear f32 before decoding all of it.
    let first = read_image(&paths[0])?;
    let bytes = 6561 * first.1.len() as u64 * 12;
    if bytes > MAX_BYTES {
        return Err(Error::input(
            &paths[0],
            format!(
                "{} x {} texels per image: 6561 of them take {:.1} GiB as linear f32 (at most {} GiB); cut a repeating tile from a few images first",
                first.0[0],
                first.0[1],
                bytes as f64 / (1u64 << 30) as f64,
                MAX_BYTES >> 30
            ),
        ));
    }
    let mut images: Vec<([u32; 2], Vec<[f32; 3]>)> = vec![first];
    images.extend(
        paths[1..]
            .par_iter()
            .map(|p| read_image(p))
            .collect::<Result<Vec<_>>>()?,
    );
    let size = images[0].0;
    for (p, (s, _)) in paths.iter().zip(&images) {
        if *s != size {
            return Err(Error::input(
                p,
                format!(
                    "image is {} x {} but {} is {} x {}: all images of a BTF must be the same size",
                    s[0],
                    s[1],
                    paths[0].display(),
                    size[0],
                    size[1]
                ),
            ));
        }
    }
    if size[0] > 1024 || size[1] > 1024 {
        return Err(Error::input(
            &paths[0],
            format!(
                "{} x {} texels per image: at most 1024 x 1024 (cut a tile first)",
                size[0], size[1]
            ),
        ));
    }
    if let Some((p, _)) = paths.iter().zip(&images).find(|(_, (_, px))| {
        px.iter()
            .any(|t| t.iter().any(|x| !x.is_finite() || *x < 0.0))
    }) {
        return Err(Error::input(p, "holds negative or non-finite values"));
    }
    Ok(Btf {
        size,
        texels: images.into_iter().flat_map(|i| i.1).collect(),
    })
}

/// The repeat period found by [`find_period`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct Period {
    /// Repeat width and height in texels.
    pub period: [u32; 2],
    /// Cost (mean squared difference) at the period, and the median cost over all offsets.
    pub cost: f64,
    pub median_cost: f64,
}

/// The 2D cost C(dx, dy) = mean over the overlap of |I(x + dx, y + dy) - I(x, y)|^2 summed
/// over `images` (each `size`, row-major), for dx in [-W/2, W/2], dy in [0, H/2].
pub fn cost_map(images: &[&[[f32; 3]]], size: [u32; 2]) -> (Vec<f64>, [i64; 2]) {
    let (w, h) = (size[0] as i64, size[1] as i64);
    let (mx, my) = (w / 2, h / 2);
    let cols = 2 * mx + 1;
    let cost: Vec<f64> = (0..cols * (my + 1))
        .into_par_iter()
        .map(|k| {
            let (dx, dy) = (k % cols - mx, k / cols);
            let mut sum = 0.0;
            let mut n = 0usize;
            for img in images {
                for y in 0..h - dy {
                    for x in (-dx).max(0)..(w - dx).min(w) {
                        let a = img[(y * w + x) as usize];
                        let b = img[((y + dy) * w + x + dx) as usize];
                        sum += (0..3).map(|c| ((a[c] - b[c]) as f64).powi(2)).sum::<f64>();
                        n += 1;
                    }
                }
            }
            if n == 0 {
                f64::INFINITY
            } else {
                sum / n as f64
            }
        })
        .collect();
    (cost, [mx, my])
}

/// The (light, view) index pairs whose images [`find_period`] compares.
pub const PERIOD_PAIRS: [(usize, usize); 4] = [(0, 0), (10, 3), (40, 20), (25, 60)];

/// Finds the repeat period of a BTF sample from the local minima of [`cost_map`] over a few
/// of its images (view and light near the pole, and oblique ones): the smallest offset along
/// each axis that is a local minimum of the 2D cost and below a quarter of its median.
pub fn find_period(btf: &Btf) -> Result<Period> {
    let [w, h] = btf.size;
    if w < 8 || h < 8 {
        return Err(Error::InvalidArgument(format!(
            "a {w} x {h} sample is too small to find a repeat in"
        )));
    }
    let images: Vec<&[[f32; 3]]> = PERIOD_PAIRS.iter().map(|&(l, v)| btf.image(l, v)).collect();
    let (cost, [mx, my]) = cost_map(&images, btf.size);
    let cols = 2 * mx + 1;
    let at = |dx: i64, dy: i64| -> f64 {
        if dx < -mx || dx > mx || dy < 0 || dy > my {
            f64::INFINITY
        } else {
            cost[(dy * cols + dx + mx) as usize]
        }
    };
    let mut sorted: Vec<f64> = cost.iter().copied().filter(|c| c.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let is_min = |dx: i64, dy: i64| {
        let c = at(dx, dy);
        c < 0.25 * median
            && (-1..=1).all(|a| {
                (-1..=1).all(|b| {
                    (a == 0 && b == 0) || {
                        // dy < 0 mirrors to (-dx, -dy).
                        let (x, y) = if dy + b < 0 {
                            (-(dx + a), -(dy + b))
                        } else {
                            (dx + a, dy + b)
                        };
                        c <= at(x, y)
                    }
                })
            })
    };
    let px = (1..=mx).find(|&dx| is_min(dx, 0));
    let py = (1..=my).find(|&dy| is_min(0, dy));
    match (px, py) {
        (Some(px), Some(py)) => Ok(Period {
            period: [px as u32, py as u32],
            cost: at(px, 0).max(at(0, py)),
            median_cost: median,
        }),
        _ => Err(Error::InvalidArgument(format!(
            "no repeat found in the {w} x {h} sample (the cost has no clear minimum within half its size along {})",
            if px.is_none() { "x" } else { "y" }
        ))),
    }
}

/// Cuts the `period` tile at texel `origin` out of every image of `btf`.
pub fn cut_tile(btf: &Btf, origin: [u32; 2], period: [u32; 2]) -> Result<Btf> {
    let [w, h] = btf.size;
    if origin[0] + period[0] > w || origin[1] + period[1] > h || period[0] == 0 || period[1] == 0 {
        return Err(Error::InvalidArgument(format!(
            "tile {period:?} at {origin:?} does not fit in the {w} x {h} sample"
        )));
    }
    let mut texels =
        Vec::with_capacity(dirs::COUNT * dirs::COUNT * (period[0] * period[1]) as usize);
    for s in 0..dirs::COUNT * dirs::COUNT {
        let img = btf.image(s % dirs::COUNT, s / dirs::COUNT);
        for y in origin[1]..origin[1] + period[1] {
            let row = (y * w) as usize;
            texels.extend_from_slice(
                &img[row + origin[0] as usize..row + (origin[0] + period[0]) as usize],
            );
        }
    }
    Ok(Btf {
        size: period,
        texels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 58-byte PNG (found by the `btf_image` fuzz target) whose header claimed an image
    /// that made the decoder allocate 512 MiB before failing: refused before that, naming
    /// the file and the bound. Also a header of 16385 x 1.
    #[cfg(feature = "png")]
    #[test]
    fn a_header_claiming_more_than_the_file_holds_is_refused_before_decoding() {
        let dir = std::env::temp_dir().join(format!("vkshade-btf-bomb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let png = |w: u32, h: u32| {
            let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
            let mut ihdr = b"IHDR".to_vec();
            ihdr.extend(w.to_be_bytes());
            ihdr.extend(h.to_be_bytes());
            ihdr.extend([16, 6, 0, 0, 0]); // 16-bit RGBA
            b.extend(13u32.to_be_bytes());
            b.extend(&ihdr);
            b.extend(crc32(&ihdr).to_be_bytes());
            let idat = b"IDAT\x78\x9c\x03\x00\x00\x00\x00\x01";
            b.extend(8u32.to_be_bytes());
            b.extend(idat);
            b.extend(crc32(idat).to_be_bytes());
            b
        };
        for (w, h, what) in [
            (8192, 8192, "MiB decoded"),
            (16385, 1, "16384 texels a side"),
        ] {
            let path = dir.join(format!("bomb_{w}x{h}.png"));
            std::fs::write(&path, png(w, h)).unwrap();
            let e = read_image(&path).unwrap_err().to_string();
            assert!(
                e.contains(&format!("bomb_{w}x{h}.png")) && e.contains(what),
                "{e}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[cfg(feature = "png")]
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    #[test]
    fn names_parse_whatever_the_separators() {
        let (l, v) = parse_name("00042 tl015 pl060 tv030 pv000.png").unwrap();
        assert_eq!((l.theta, l.phi, v.theta, v.phi), (15, 60, 30, 0));
        let (l, v) = parse_name("btf_tl075_pl345_tv000_pv000.exr").unwrap();
        assert_eq!((l.theta, l.phi, v.theta, v.phi), (75, 345, 0, 0));
        assert!(parse_name("readme.png").is_none());
        assert!(parse_name("tl015_pl060_tv030.png").is_none());
    }

    #[test]
    fn the_tile_finder_recovers_the_period_of_a_larger_sample() {
        use super::super::cloth::{Pattern, SynthConfig};
        // The knit tile holds 2 x 2 stitches: its true period is half the tile.
        for (pattern, period, expect) in [(Pattern::Weave, 7, 7), (Pattern::Knit, 12, 6)] {
            // Only the images the finder and the check below read are rendered (the full
            // 6561 take seconds); the rest stay black, which the cut must carry over too.
            let cfg = SynthConfig {
                pattern,
                size: [17, 15],
                period,
                samples: 1,
            };
            let d = crate::kernels::btf::dirs::directions();
            let mut sample = crate::kernels::btf::synth::Btf {
                size: cfg.size,
                texels: vec![[0.0; 3]; 6561 * 255],
            };
            for (l, v) in PERIOD_PAIRS.into_iter().chain([(19, 1), (80, 80)]) {
                let img = cfg.image(d[l].vector(), d[v].vector());
                let s = v * 81 + l;
                sample.texels[s * 255..(s + 1) * 255].copy_from_slice(&img);
            }
            let p = find_period(&sample).unwrap();
            assert_eq!(p.period, [expect, expect], "{pattern:?}: {p:?}");
            let period = expect;
            let tile = cut_tile(&sample, [2, 3], p.period).unwrap();
            // The cut tile, repeated, is the sample.
            for s in [0, 100, 81 + 19, 6560] {
                let (l, v) = (s % 81, s / 81);
                let (a, b) = (sample.image(l, v), tile.image(l, v));
                for y in 3..15 {
                    for x in 2..17 {
                        let t = b[(((y - 3) % period) * period + (x - 2) % period) as usize];
                        let q = a[(y * 17 + x) as usize];
                        assert!((0..3).all(|c| (t[c] - q[c]).abs() < 1e-3));
                    }
                }
            }
        }
    }
}
