//! BC1 (DXT1) texture compression on the CPU: an encoder and a decoder for the opaque
//! 4-colour mode, for images stored as `BC1_RGB_*_BLOCK`.
//!
//! A block is 4 x 4 texels in 8 bytes: two RGB565 endpoints `c0`, `c1` (little-endian) and
//! sixteen 2-bit indices (texel `i` at bits `2i`, row-major). With `c0 > c1` the palette is
//! `c0`, `c1`, `(2 c0 + c1) / 3`, `(c0 + 2 c1) / 3`; with `c0 <= c1` it is `c0`, `c1`,
//! `(c0 + c1) / 2` and black. The palette is interpolated between the *stored* values: for an
//! sRGB format the endpoints are sRGB-encoded, the palette is formed in encoded space, and the
//! sampler decodes the palette colour to linear before filtering (Vulkan's rule for sRGB
//! block formats), so bilinear filtering stays linear.
//!
//! The encoder therefore works in the encoded space of its input bytes (sRGB-encoded for the
//! BTF): principal axis of the block's colours, endpoints at the extreme projections, then a
//! few rounds of nearest-palette assignment and least-squares endpoint refits, keeping the
//! best block found (it also tries the bounding-box diagonal). It only emits the 4-colour mode
//! (`c0 > c1`) or, for a block whose endpoints quantise to one colour, `c0 == c1` with every
//! index 0 (which decodes to `c0` in either mode), so no texel decodes to the black entry.
//!
//! The decoder expands 5/6-bit endpoints by bit replication and forms the interpolated entries
//! with integer arithmetic truncating toward zero, as Mesa's S3TC decoder does. The BC1
//! definition (Khronos Data Format spec, "S3TC compressed texture image formats") leaves the
//! arithmetic of the 1/3 and 2/3 entries to the implementation, and the vendors differ:
//! entries 2 and 3 may differ from this decoder's by several 8-bit steps
//! ([`PALETTE_TOLERANCE`]); entries 0 and 1 are exact.

/// Bytes per 4 x 4 block.
pub const BLOCK_BYTES: usize = 8;

/// The largest difference, in 8-bit steps of the stored (encoded) value, between this
/// decoder's interpolated palette entries and the decoders of the GPUs we know. Lavapipe's
/// (Mesa 22.3), read back and re-encoded to 8-bit sRGB, is within 1 step of it (tests/btf.rs
/// reads the device's own decoding back and prints the largest difference; the step may be
/// the re-encoding's). NVIDIA's, as published by Castano
/// (2009, "GPU DXT decompression") and Giesen (2021, "GPU BCn decoding"), forms red and blue
/// as (2 a + b) 22 / 8 from the 5-bit values (1 step from this decoder at most) and green
/// with a weight of 80.25 / 256 instead of 1 / 3: up to 6 steps over all 6-bit endpoint
/// pairs (counted exhaustively). A test that compares a GPU's BC1 texels with this decoder
/// allows this; one that needs exactness reads the device's own decoding back.
pub const PALETTE_TOLERANCE: u8 = 6;

fn expand565(c: u16) -> [u8; 3] {
    let r = ((c >> 11) & 31) as u8;
    let g = ((c >> 5) & 63) as u8;
    let b = (c & 31) as u8;
    [
        (r << 3) | (r >> 2),
        (g << 2) | (g >> 4),
        (b << 3) | (b >> 2),
    ]
}

fn pack565(c: [f64; 3]) -> u16 {
    let q = |v: f64, max: f64| (v.clamp(0.0, 255.0) * max / 255.0).round() as u16;
    (q(c[0], 31.0) << 11) | (q(c[1], 63.0) << 5) | q(c[2], 31.0)
}

/// The four palette entries of a block's endpoints (RGB, stored encoding).
pub fn palette(c0: u16, c1: u16) -> [[u8; 3]; 4] {
    let a = expand565(c0);
    let b = expand565(c1);
    let mix = |wa: u16, wb: u16, d: u16| {
        [0, 1, 2].map(|k| ((wa * a[k] as u16 + wb * b[k] as u16) / d) as u8)
    };
    if c0 > c1 {
        [a, b, mix(2, 1, 3), mix(1, 2, 3)]
    } else {
        [a, b, mix(1, 1, 2), [0, 0, 0]]
    }
}

/// Decodes one block to 16 RGBA texels (row-major; alpha 255: the opaque RGB formats).
pub fn decode_block(block: &[u8; BLOCK_BYTES]) -> [[u8; 4]; 16] {
    let c0 = u16::from_le_bytes([block[0], block[1]]);
    let c1 = u16::from_le_bytes([block[2], block[3]]);
    let bits = u32::from_le_bytes([block[4], block[5], block[6], block[7]]);
    let pal = palette(c0, c1);
    std::array::from_fn(|i| {
        let [r, g, b] = pal[((bits >> (2 * i)) & 3) as usize];
        [r, g, b, 255]
    })
}

fn sq_err(a: [f64; 3], b: [u8; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k] as f64).powi(2)).sum()
}

/// The indices and error of `texels` against the palette of (c0, c1).
fn assign(texels: &[[f64; 3]; 16], c0: u16, c1: u16) -> ([u8; 16], f64) {
    let pal = palette(c0, c1);
    let entries = if c0 > c1 { 4 } else { 1 };
    let mut idx = [0u8; 16];
    let mut total = 0.0;
    for (i, t) in texels.iter().enumerate() {
        let (best, e) = (0..entries)
            .map(|j| (j, sq_err(*t, pal[j])))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .unwrap_or((0, 0.0));
        idx[i] = best as u8;
        total += e;
    }
    (idx, total)
}

/// Endpoints in 4-colour order (c0 > c1), or equal endpoints (single colour).
fn order(c0: u16, c1: u16) -> (u16, u16) {
    if c0 >= c1 { (c0, c1) } else { (c1, c0) }
}

/// Least-squares endpoints for fixed indices (weights of c0 per 4-colour index).
fn refit(texels: &[[f64; 3]; 16], idx: &[u8; 16]) -> Option<([f64; 3], [f64; 3])> {
    const W: [f64; 4] = [1.0, 0.0, 2.0 / 3.0, 1.0 / 3.0];
    fit_endpoints(texels, idx.map(|i| W[i as usize]), 1e-9)
}

/// Two endpoints by least squares when texel i is w_i e0 + (1 - w_i) e1 (the normal
/// equations in (e0, e1)); None when their determinant is below `min_det` (all weights
/// alike). Shared by the BC1 encoder and the BTF `block` encoder.
pub fn fit_endpoints(
    texels: &[[f64; 3]; 16],
    w0: [f64; 16],
    min_det: f64,
) -> Option<([f64; 3], [f64; 3])> {
    let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
    let mut ax = [0.0; 3];
    let mut bx = [0.0; 3];
    for (t, a) in texels.iter().zip(w0) {
        let b = 1.0 - a;
        aa += a * a;
        ab += a * b;
        bb += b * b;
        for k in 0..3 {
            ax[k] += a * t[k];
            bx[k] += b * t[k];
        }
    }
    let det = aa * bb - ab * ab;
    if det.abs() < min_det {
        return None;
    }
    let e0 = [0, 1, 2].map(|k| (bb * ax[k] - ab * bx[k]) / det);
    let e1 = [0, 1, 2].map(|k| (aa * bx[k] - ab * ax[k]) / det);
    Some((e0, e1))
}

/// Encodes 16 texels (row-major RGB in their stored encoding) into one block.
pub fn encode_block(texels: &[[u8; 3]; 16]) -> [u8; BLOCK_BYTES] {
    let t: [[f64; 3]; 16] = texels.map(|p| p.map(f64::from));
    let mean = [0, 1, 2].map(|k| t.iter().map(|p| p[k]).sum::<f64>() / 16.0);
    let mut cov = [[0.0; 3]; 3];
    for p in &t {
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += (p[i] - mean[i]) * (p[j] - mean[j]);
            }
        }
    }
    // Principal axis by power iteration from the grey diagonal.
    let mut axis = [1.0, 1.0, 1.0];
    for _ in 0..16 {
        let next = [0, 1, 2].map(|i| (0..3).map(|j| cov[i][j] * axis[j]).sum::<f64>());
        let n = next.iter().map(|v| v * v).sum::<f64>().sqrt();
        if n < 1e-12 {
            break;
        }
        axis = next.map(|v| v / n);
    }
    let proj = |p: &[f64; 3]| (0..3).map(|k| (p[k] - mean[k]) * axis[k]).sum::<f64>();
    let (lo, hi) = t
        .iter()
        .map(proj)
        .fold((f64::MAX, f64::MIN), |(lo, hi), s| (lo.min(s), hi.max(s)));
    let at = |s: f64| [0, 1, 2].map(|k| mean[k] + s * axis[k]);
    let lo_box = [0, 1, 2].map(|k| t.iter().map(|p| p[k]).fold(f64::MAX, f64::min));
    let hi_box = [0, 1, 2].map(|k| t.iter().map(|p| p[k]).fold(f64::MIN, f64::max));
    let mut best: Option<(f64, u16, u16, [u8; 16])> = None;
    for (e0, e1) in [(at(hi), at(lo)), (hi_box, lo_box)] {
        let (mut c0, mut c1) = order(pack565(e0), pack565(e1));
        for _ in 0..4 {
            let (idx, err) = assign(&t, c0, c1);
            if best.as_ref().is_none_or(|b| err < b.0) {
                best = Some((err, c0, c1, idx));
            }
            if c0 == c1 {
                break;
            }
            let Some((f0, f1)) = refit(&t, &idx) else {
                break;
            };
            let next = order(pack565(f0), pack565(f1));
            if next == (c0, c1) {
                break;
            }
            (c0, c1) = next;
        }
    }
    let (_, c0, c1, idx) = best.expect("at least one candidate is evaluated");
    let bits = idx
        .iter()
        .enumerate()
        .fold(0u32, |acc, (i, &v)| acc | ((v as u32) << (2 * i)));
    let mut out = [0u8; BLOCK_BYTES];
    out[..2].copy_from_slice(&c0.to_le_bytes());
    out[2..4].copy_from_slice(&c1.to_le_bytes());
    out[4..].copy_from_slice(&bits.to_le_bytes());
    out
}

/// Bytes of a `width` x `height` image in BC1 (partial edge blocks counted whole).
pub fn encoded_len(width: u32, height: u32) -> usize {
    width.div_ceil(4) as usize * height.div_ceil(4) as usize * BLOCK_BYTES
}

/// Encodes a `width` x `height` RGBA8 image (alpha ignored) into row-major blocks; texels
/// past the edge of a partial block repeat the edge texel.
pub fn encode_image(width: u32, height: u32, rgba: &[u8]) -> Vec<u8> {
    assert_eq!(rgba.len(), width as usize * height as usize * 4);
    let mut out = Vec::with_capacity(encoded_len(width, height));
    for by in 0..height.div_ceil(4) {
        for bx in 0..width.div_ceil(4) {
            let texels: [[u8; 3]; 16] = std::array::from_fn(|i| {
                let x = (bx * 4 + i as u32 % 4).min(width - 1) as usize;
                let y = (by * 4 + i as u32 / 4).min(height - 1) as usize;
                let k = 4 * (y * width as usize + x);
                [rgba[k], rgba[k + 1], rgba[k + 2]]
            });
            out.extend_from_slice(&encode_block(&texels));
        }
    }
    out
}

/// Decodes row-major blocks of a `width` x `height` image to RGBA8 (alpha 255).
pub fn decode_image(width: u32, height: u32, blocks: &[u8]) -> Vec<u8> {
    assert_eq!(blocks.len(), encoded_len(width, height));
    let bw = width.div_ceil(4) as usize;
    let mut out = vec![0u8; width as usize * height as usize * 4];
    for (b, block) in blocks.chunks_exact(BLOCK_BYTES).enumerate() {
        let texels = decode_block(block.try_into().expect("chunks of BLOCK_BYTES"));
        let (bx, by) = (b % bw, b / bw);
        for (i, t) in texels.iter().enumerate() {
            let (x, y) = (bx * 4 + i % 4, by * 4 + i / 4);
            if x < width as usize && y < height as usize {
                let k = 4 * (y * width as usize + x);
                out[k..k + 4].copy_from_slice(t);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rms(a: &[u8], b: &[u8]) -> f64 {
        let (mut s, mut n) = (0.0, 0);
        for (x, y) in a.chunks(4).zip(b.chunks(4)) {
            for k in 0..3 {
                s += (x[k] as f64 - y[k] as f64).powi(2);
                n += 1;
            }
        }
        (s / n as f64).sqrt()
    }

    fn lcg(seed: &mut u64) -> u8 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 56) as u8
    }

    #[test]
    fn decoder_follows_the_spec_palette() {
        // c0 = pure red (31,0,0) > c1 = pure blue (0,0,31).
        let c0: u16 = 31 << 11;
        let c1: u16 = 31;
        let p = palette(c0, c1);
        assert_eq!(p[0], [255, 0, 0]);
        assert_eq!(p[1], [0, 0, 255]);
        assert_eq!(p[2], [170, 0, 85]);
        assert_eq!(p[3], [85, 0, 170]);
        // 3-colour mode: midpoint and black.
        let p = palette(c1, c0);
        assert_eq!(p[2], [127, 0, 127]);
        assert_eq!(p[3], [0, 0, 0]);
        // Indices: texel i at bits 2i.
        let mut block = [0u8; 8];
        block[..2].copy_from_slice(&c0.to_le_bytes());
        block[2..4].copy_from_slice(&c1.to_le_bytes());
        block[4..].copy_from_slice(&0b11_10_01_00u32.to_le_bytes());
        let d = decode_block(&block);
        assert_eq!(d[0], [255, 0, 0, 255]);
        assert_eq!(d[1], [0, 0, 255, 255]);
        assert_eq!(d[2], [170, 0, 85, 255]);
        assert_eq!(d[3], [85, 0, 170, 255]);
        assert_eq!(d[4], [255, 0, 0, 255]);
    }

    #[test]
    fn solid_blocks_round_trip() {
        let mut seed = 7;
        for _ in 0..200 {
            // A colour representable in 565 decodes exactly.
            let c = [
                lcg(&mut seed) >> 3,
                lcg(&mut seed) >> 2,
                lcg(&mut seed) >> 3,
            ];
            let rgb = expand565(((c[0] as u16) << 11) | ((c[1] as u16) << 5) | c[2] as u16);
            let d = decode_block(&encode_block(&[rgb; 16]));
            assert!(d.iter().all(|t| t[..3] == rgb), "{rgb:?} -> {:?}", d[0]);
            // Any solid colour: within half a 565 step (4.2 / 2.1 / 4.2 codes).
            let any = [lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)];
            let d = decode_block(&encode_block(&[any; 16]));
            for t in d {
                for (k, tol) in [4.2, 2.1, 4.2].into_iter().enumerate() {
                    let e = (t[k] as f64 - any[k] as f64).abs();
                    assert!(e <= tol, "{any:?} -> {t:?}");
                }
            }
        }
    }

    #[test]
    fn gradients_and_noise_round_trip_within_bounds() {
        let (w, h) = (32u32, 32u32);
        // A smooth two-colour gradient: BC1's case (one line in colour space per block).
        let grad: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let s = (x + 0.5 * y) / (w as f64 * 1.5);
                [
                    (30.0 + 200.0 * s) as u8,
                    (200.0 - 150.0 * s) as u8,
                    (60.0 + 90.0 * s) as u8,
                    255,
                ]
            })
            .collect();
        let enc = encode_image(w, h, &grad);
        assert_eq!(enc.len(), (w * h / 2) as usize);
        let e = rms(&grad, &decode_image(w, h, &enc));
        eprintln!("gradient RMS {e}");
        assert!(e < 2.5, "gradient RMS {e}");
        // Uniform noise: the worst case; must still beat a flat block per 4 x 4 (RMS ~74).
        let mut seed = 3;
        let noise: Vec<u8> = (0..w * h * 4).map(|_| lcg(&mut seed)).collect();
        let e = rms(&noise, &decode_image(w, h, &encode_image(w, h, &noise)));
        eprintln!("noise RMS {e}");
        assert!(e < 55.0, "noise RMS {e}");
        // Odd sizes: partial edge blocks.
        let small: Vec<u8> = (0..3usize)
            .flat_map(|y| grad[y * 128..y * 128 + 5 * 4].to_vec())
            .collect();
        let enc = encode_image(5, 3, &small);
        assert_eq!(enc.len(), 2 * BLOCK_BYTES);
        let e = rms(&small, &decode_image(5, 3, &enc));
        assert!(e < 2.5, "5 x 3 gradient RMS {e}");
    }

    #[test]
    fn refinement_never_loses_to_the_first_guess() {
        let mut seed = 11;
        for _ in 0..100 {
            let texels: [[u8; 3]; 16] =
                std::array::from_fn(|_| [lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)]);
            let t = texels.map(|p| p.map(f64::from));
            let block = encode_block(&texels);
            let c0 = u16::from_le_bytes([block[0], block[1]]);
            let c1 = u16::from_le_bytes([block[2], block[3]]);
            assert!(c0 >= c1, "4-colour mode or single colour");
            let d = decode_block(&block);
            let err: f64 = (0..16)
                .map(|i| sq_err(t[i], [d[i][0], d[i][1], d[i][2]]))
                .sum();
            // The decoded error is the best the chosen palette gives each texel.
            assert!((err - assign(&t, c0, c1).1).abs() < 1e-9);
        }
    }
}
