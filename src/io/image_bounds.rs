//! How large a PNG or JPEG may decode, decided from its header before a decoder allocates:
//! a header claiming more than its file could hold (deflate and JPEG stay far below 1000:1
//! on real images) is a decompression bomb or a corrupt file. Shared by the BTF image
//! loader and the glTF base-colour textures.

/// Longest side of a PNG or JPEG image vkshade decodes.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Decoded bytes always allowed (32 MiB); above it, at most 1024 bytes per byte of file,
/// and never more than [`MAX_DECODE_BYTES`].
pub const MIN_DECODE_BYTES: u64 = 32 << 20;
/// See [`MIN_DECODE_BYTES`] (1 GiB).
pub const MAX_DECODE_BYTES: u64 = 1 << 30;

/// Decoded bytes a file of `file_bytes` may take.
pub fn decode_budget(file_bytes: u64) -> u64 {
    file_bytes
        .saturating_mul(1024)
        .clamp(MIN_DECODE_BYTES, MAX_DECODE_BYTES)
}

/// The decoder limits for a file of `file_bytes`.
pub fn limits(file_bytes: u64) -> image::Limits {
    let mut l = image::Limits::default();
    l.max_image_width = Some(MAX_IMAGE_SIDE);
    l.max_image_height = Some(MAX_IMAGE_SIDE);
    l.max_alloc = Some(decode_budget(file_bytes));
    l
}

/// Checks the header of the encoded image `bytes` (format guessed from its content) against
/// [`limits`] without decoding it: `Ok((width, height))`, or what is wrong.
pub fn check_header(bytes: &[u8]) -> Result<(u32, u32), String> {
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot be decoded (its header): {e}"))?;
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| format!("cannot be decoded (its header): {e}"))?;
    let budget = decode_budget(bytes.len() as u64);
    // 8 bytes a texel: 16-bit RGBA, the widest PNG texel.
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || w as u64 * h as u64 * 8 > budget {
        return Err(format!(
            "its header claims {w} x {h} texels, more than {} bytes of image can hold (at \
             most {MAX_IMAGE_SIDE} texels a side and {} MiB decoded)",
            bytes.len(),
            budget >> 20
        ));
    }
    Ok((w, h))
}
