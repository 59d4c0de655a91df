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

/// Most layers (parts) an EXR may declare.
pub const MAX_LAYERS: usize = 64;

/// Most texels a file may declare per byte it holds, beyond a floor of 2^22 texels (a 2048 x
/// 2048 map, 64 MiB as RGBA f32, is always allowed). Real float images compress far less:
/// deflate (ZIP, and the zlib stage of DWA) tops out near 1000:1, a few texels per byte for
/// f16 RGB; only a large flat single-colour map under lossy DWA gets near this. A header
/// claiming more is refused before anything is sized from it, so a small file can never make
/// the reader allocate gigabytes (each input byte can claim at most 16 KiB of texels).
pub const TEXELS_PER_BYTE: usize = 1024;

fn max_texels_for(file_len: usize) -> usize {
    (1usize << 22).max(file_len.saturating_mul(TEXELS_PER_BYTE))
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
    // The exr crate sizes each block's buffer from the headers (a block may be as large as
    // the header's data window allows) before it sees the block: a 1 KiB file whose header
    // claims a 2^30-texel window made it allocate 1.4 GiB (found by the `envmap` fuzz
    // target). Every header is checked first, so no allocation exceeds what a
    // MAX_DIMENSION-square image needs.
    let meta = exr::meta::MetaData::read_from_buffered(bytes.as_slice(), false)
        .map_err(|e| Error::input(path, format!("not a readable OpenEXR header: {e}")))?;
    if meta.headers.len() > MAX_LAYERS {
        return Err(Error::input(
            path,
            format!(
                "{} layers (vkshade reads at most {MAX_LAYERS})",
                meta.headers.len()
            ),
        ));
    }
    let max_texels = max_texels_for(bytes.len());
    for (i, h) in meta.headers.iter().enumerate() {
        let (w, ht) = (h.layer_size.width(), h.layer_size.height());
        if w > MAX_DIMENSION as usize || ht > MAX_DIMENSION as usize {
            return Err(Error::input(
                path,
                format!("layer {i} is {w} x {ht} texels, beyond {MAX_DIMENSION} per side"),
            ));
        }
        if w.saturating_mul(ht) > max_texels {
            return Err(Error::input(
                path,
                format!(
                    "layer {i} claims {w} x {ht} texels in a file of {} bytes (more than \
                     {TEXELS_PER_BYTE} texels per byte: not a real compressed image)",
                    bytes.len()
                ),
            ));
        }
    }
    check_dwa_chunks(path, &bytes)?;
    // The exr crate panics on some corrupt compressed blocks (a fuzzed DWAB file: `Vec::
    // with_capacity` of a length read from the data, "capacity overflow" in its PIZ Huffman
    // decoder). That panic is caught here and becomes an error naming the file; the CLI's
    // panic hook stays quiet inside this scope ([`super::panic_scope`]).
    let decoded = super::panic_scope::catch(|| read_layer(bytes));
    let image = match decoded {
        Ok(r) => {
            r.map_err(|e| Error::input(path, format!("not a readable RGB(A) OpenEXR image: {e}")))?
        }
        Err(why) => {
            return Err(Error::input(
                path,
                format!("not a readable RGB(A) OpenEXR image: the decoder failed ({why})"),
            ));
        }
    };
    let img = image.layer_data.channel_data.pixels;
    if img.width == 0 {
        return Err(Error::input(
            path,
            format!("image size outside 1..={MAX_DIMENSION} per side"),
        ));
    }
    Ok(img)
}

/// Bytes a DWA chunk's leader may claim per sample of its block (f32 samples; the DCT's 8 x 8
/// blocks pad each side by up to 7 samples, counted in [`check_dwa_chunks`]).
const DWA_BYTES_PER_SAMPLE: usize = 4;

/// Checks the leader of every DWAA/DWAB-compressed chunk before the exr crate decodes it.
/// The leader is 11 little-endian u64 counters (version; the unknown section's uncompressed
/// and compressed sizes; the AC, DC and RLE sections' compressed sizes; the RLE section's
/// uncompressed and raw sizes; the AC and DC coefficient counts; the AC coder), and the
/// crate sizes its buffers from them: a fuzzed 64 KiB file whose AC count read 1.2e14 made it
/// ask for 243 TB, and the process aborted (an allocation failure is not a panic that
/// [`super::panic_scope`] could catch). Each size and count is refused beyond what the
/// chunk's block can hold (its samples, padded to the DCT's 8 x 8 blocks, at 4 bytes each),
/// and each compressed size beyond the chunk's own length. A chunk stored raw (its length
/// equal to the block's uncompressed size, as the crate decides it) has no leader.
fn check_dwa_chunks(path: &Path, bytes: &[u8]) -> Result<()> {
    use exr::block::chunk::CompressedBlock;
    use exr::compression::Compression;
    let is_dwa = |c: Compression| matches!(c, Compression::DWAA(_) | Compression::DWAB(_));
    let unreadable =
        |e: exr::error::Error| Error::input(path, format!("not a readable OpenEXR image: {e}"));
    let reader = exr::block::read(std::io::Cursor::new(bytes), false).map_err(unreadable)?;
    if !reader.headers().iter().any(|h| is_dwa(h.compression)) {
        return Ok(());
    }
    let headers = reader.headers().to_vec();
    for (n, chunk) in reader.all_chunks(false).map_err(unreadable)?.enumerate() {
        let chunk = chunk.map_err(unreadable)?;
        let Some(h) = headers.get(chunk.layer_index) else {
            continue; // the crate refuses the chunk itself
        };
        if !is_dwa(h.compression) {
            continue;
        }
        let data = match &chunk.compressed_block {
            CompressedBlock::ScanLine(b) => &b.compressed_pixels_le,
            CompressedBlock::Tile(b) => &b.compressed_pixels_le,
            _ => continue, // deep data: the crate refuses it
        };
        let Ok(rect) = h
            .get_block_data_indices(&chunk.compressed_block)
            .and_then(|i| h.get_absolute_block_pixel_coordinates(i))
        else {
            continue; // the crate refuses a block outside the layer
        };
        let (w, ht) = (rect.size.width(), rect.size.height());
        if data.len() == w * ht * h.channels.bytes_per_pixel || data.len() < 88 {
            continue; // stored raw, or too short for a leader (the crate refuses it)
        }
        let counter = |i: usize| {
            let mut c = [0u8; 8];
            c.copy_from_slice(&data[8 * i..8 * i + 8]);
            u64::from_le_bytes(c)
        };
        let samples = (w + 7) * (ht + 7) * h.channels.list.len();
        let most = (samples * DWA_BYTES_PER_SAMPLE) as u64;
        let sizes = [
            (1, "unknown section's uncompressed size", most),
            (6, "RLE section's uncompressed size", most),
            (7, "RLE section's raw size", most),
            (8, "AC coefficient count", most),
            (9, "DC coefficient count", most),
            (2, "unknown section's compressed size", data.len() as u64),
            (3, "AC section's compressed size", data.len() as u64),
            (4, "DC section's compressed size", data.len() as u64),
            (5, "RLE section's compressed size", data.len() as u64),
        ];
        for (i, what, limit) in sizes {
            let v = counter(i);
            if v > limit {
                return Err(Error::input(
                    path,
                    format!(
                        "DWA chunk {n} (layer {}, a block of {w} x {ht} texels x {} channels, \
                         {} bytes): its {what} is {v}, beyond {limit}: a corrupt file",
                        chunk.layer_index,
                        h.channels.list.len(),
                        data.len()
                    ),
                ));
            }
        }
    }
    Ok(())
}

type RgbaLayer = exr::image::Image<
    exr::image::Layer<
        exr::image::SpecificChannels<
            FloatImage,
            (
                exr::meta::attribute::ChannelDescription,
                exr::meta::attribute::ChannelDescription,
                exr::meta::attribute::ChannelDescription,
                Option<exr::meta::attribute::ChannelDescription>,
            ),
        >,
    >,
>;

/// The exr crate's read of the first RGB(A) layer (sizes outside the bounds give an empty
/// image, refused by the caller).
fn read_layer(bytes: Vec<u8>) -> exr::error::Result<RgbaLayer> {
    read()
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
        // One thread: the crate's parallel decoding builds a thread pool per image read
        // (and leaves its threads running after the read returns); the maps vkshade reads
        // decode in tens of milliseconds on one core.
        .non_parallel()
        .from_buffered(std::io::Cursor::new(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small valid EXR whose header is then made to claim a 4096 x 4096 data window: more
    /// texels than its bytes can hold at TEXELS_PER_BYTE, so it is refused before anything
    /// is sized from the header.
    #[test]
    fn a_header_claiming_more_texels_than_the_file_can_hold_is_refused() {
        let dir = std::env::temp_dir().join(format!("vkshade-exr-claim-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("small.exr");
        let img = FloatImage {
            width: 16,
            height: 8,
            pixels: vec![[0.5, 0.25, 1.0, 1.0]; 128],
        };
        write(&path, &img, Channels::Rgb).unwrap();
        assert_eq!(read_rgba(&path).unwrap().pixels[7], [0.5, 0.25, 1.0, 1.0]);
        let mut bytes = std::fs::read(&path).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        for (i, v) in [0i32, 0, 4095, 4095].iter().enumerate() {
            bytes[at + 4 * i..at + 4 * i + 4].copy_from_slice(&v.to_le_bytes());
        }
        let forged = dir.join("claims.exr");
        std::fs::write(&forged, &bytes).unwrap();
        let e = read_rgba(&forged).unwrap_err().to_string();
        assert!(e.contains("claims.exr") && e.contains("4096 x 4096"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A DWAB file whose first chunk's leader is forged to claim 2^40 AC coefficients (the
    /// shape of the fuzzed file that made the exr crate ask for 243 TB and abort) is refused
    /// before the crate decodes it, naming the file and the counter; the unforged file reads.
    #[test]
    fn a_dwa_chunk_claiming_more_coefficients_than_its_block_holds_is_refused() {
        use exr::prelude::{Blocks, Compression, LineOrder};
        let dir = std::env::temp_dir().join(format!("vkshade-exr-dwa-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let encoding = Encoding {
            compression: Compression::DWAB(None),
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        };
        let mut bytes = std::io::Cursor::new(Vec::new());
        exr::prelude::Image::from_encoded_channels(
            (64, 64),
            encoding,
            SpecificChannels::rgb(|Vec2(x, y)| (x as f32 / 64.0, y as f32 / 64.0, 0.5f32)),
        )
        .write()
        .to_buffered(&mut bytes)
        .unwrap();
        let mut bytes = bytes.into_inner();
        let good = dir.join("good.exr");
        std::fs::write(&good, &bytes).unwrap();
        assert!((read_rgba(&good).unwrap().pixels[64 * 10 + 32][0] - 0.5).abs() < 0.01);
        // One chunk (64 lines of DWAB's 256): the offset table's one entry points just past
        // itself, then the chunk's y (i32) and length (i32), then its 11-counter leader.
        let table = (0..bytes.len() - 8)
            .find(|&p| u64::from_le_bytes(bytes[p..p + 8].try_into().unwrap()) == p as u64 + 8)
            .expect("the offset table");
        let leader = table + 8 + 8;
        let ac_count = leader + 8 * 8;
        bytes[ac_count..ac_count + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let forged = dir.join("forged.exr");
        std::fs::write(&forged, &bytes).unwrap();
        let e = read_rgba(&forged).unwrap_err().to_string();
        assert!(
            e.contains("forged.exr") && e.contains("AC coefficient count is 1099511627776"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
