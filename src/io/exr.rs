//! Linear float RGB(A) images in OpenEXR (32-bit float samples, ZIP compression, lossless).
//! Writes are atomic; every error names the file.

use super::FloatImage;
use crate::error::{Error, Result};
use exr::prelude::{
    Encoding, ReadChannels, ReadLayers, SpecificChannels, Vec2, WritableImage, read,
};
use std::path::Path;

/// Largest width or height accepted (both when writing and when reading).
pub const MAX_DIMENSION: u32 = 1 << 15;

/// Whether the alpha channel is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channels {
    Rgb,
    Rgba,
}

fn check_shape(path: &Path, img: &FloatImage) -> Result<()> {
    if img.width == 0 || img.height == 0 || img.width > MAX_DIMENSION || img.height > MAX_DIMENSION
    {
        return Err(Error::input(
            path,
            format!(
                "image size {} x {} outside 1..={MAX_DIMENSION}",
                img.width, img.height
            ),
        ));
    }
    let want = img.width as usize * img.height as usize;
    if img.pixels.len() != want {
        return Err(Error::input(
            path,
            format!(
                "{} pixels given for a {} x {} image ({want})",
                img.pixels.len(),
                img.width,
                img.height
            ),
        ));
    }
    Ok(())
}

/// Writes `img` as a linear 32-bit float EXR at `path`, atomically (a temporary file in the
/// same folder, renamed when complete).
/// A NaN or infinite channel is refused, naming the file, the pixel and the channel, and
/// nothing is written.
pub fn write(path: &Path, img: &FloatImage, channels: Channels) -> Result<()> {
    check_shape(path, img)?;
    let used = match channels {
        Channels::Rgb => 3,
        Channels::Rgba => 4,
    };
    if let Some(i) = img
        .pixels
        .iter()
        .position(|p| p[..used].iter().any(|c| !c.is_finite()))
    {
        let p = img.pixels[i];
        let c = p[..used].iter().position(|c| !c.is_finite()).unwrap_or(0);
        let w = img.width as usize;
        return Err(Error::input(
            path,
            format!(
                "not written: pixel ({}, {}) channel {} is {}",
                i % w,
                i / w,
                ["R", "G", "B", "A"][c],
                p[c]
            ),
        ));
    }
    let size = (img.width as usize, img.height as usize);
    let w = img.width as usize;
    let px = |x: usize, y: usize| img.pixels[y * w + x];
    let mut bytes = std::io::Cursor::new(Vec::new());
    let encoded = match channels {
        Channels::Rgba => exr::prelude::Image::from_encoded_channels(
            size,
            Encoding::SMALL_LOSSLESS,
            SpecificChannels::rgba(|Vec2(x, y)| {
                let p = px(x, y);
                (p[0], p[1], p[2], p[3])
            }),
        )
        .write()
        .to_buffered(&mut bytes),
        Channels::Rgb => exr::prelude::Image::from_encoded_channels(
            size,
            Encoding::SMALL_LOSSLESS,
            SpecificChannels::rgb(|Vec2(x, y)| {
                let p = px(x, y);
                (p[0], p[1], p[2])
            }),
        )
        .write()
        .to_buffered(&mut bytes),
    };
    encoded.map_err(|e| Error::input(path, format!("EXR encoding failed: {e}")))?;
    super::write_atomic(path, bytes.get_ref())
}

/// Reads the first RGB(A) layer of the EXR at `path` as linear f32 (alpha 1 where the file
/// has none). An unreadable file, or one that is not an RGB(A) EXR, is an error naming it.
pub fn read_rgba(path: &Path) -> Result<FloatImage> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if bytes.len() < 4 || bytes[..4] != [0x76, 0x2f, 0x31, 0x01] {
        return Err(Error::input(
            path,
            "not an OpenEXR file (no EXR magic number at its start)",
        ));
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |size, _| {
                let (w, h) = (size.width(), size.height());
                let ok = (1..=MAX_DIMENSION as usize).contains(&w)
                    && (1..=MAX_DIMENSION as usize).contains(&h);
                FloatImage {
                    width: if ok { w as u32 } else { 0 },
                    height: if ok { h as u32 } else { 0 },
                    pixels: if ok {
                        vec![[0.0; 4]; w * h]
                    } else {
                        Vec::new()
                    },
                }
            },
            |img: &mut FloatImage, pos, (r, g, b, a): (f32, f32, f32, f32)| {
                img.set(pos.x() as u32, pos.y() as u32, [r, g, b, a]);
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| Error::input(path, format!("not a readable RGB(A) OpenEXR image: {e}")))?;
    let img = image.layer_data.channel_data.pixels;
    if img.width == 0 {
        return Err(Error::input(
            path,
            format!("image size outside 1..={MAX_DIMENSION} per side"),
        ));
    }
    Ok(img)
}
