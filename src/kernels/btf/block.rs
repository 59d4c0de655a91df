//! The `block` texel format of the packed BTF: overlapping 4 x 4 blocks, each a colour line
//! with 16 levels, decoded and filtered by the shader itself from one `texelFetch` per tap.
//!
//! Why: on lavapipe a filtered fetch from an sRGB or BC1 texture runs the sampler's
//! software sRGB/BC1 decode on each of the 4 texels it blends, and that made the 9 taps of
//! `btf shade` cost ~90% of the frame. Here a tap is one integer fetch plus a few vector
//! instructions, and the bilinear weights and bit positions are computed once per pixel
//! (the 9 taps of a pixel share its uv).
//!
//! A block is one RGBA32UI texel (16 bytes):
//! - x, y: endpoints `e0`, `e1`, linear RGB as 11:11:10-bit unorm (r in bits 0-10, g in
//!   11-21, b in 22-31);
//! - z, w: 16 indices of 4 bits, texel (c, r) of the block at bit `16 (r & 1) + 4 c` of
//!   z (rows 0, 1) or w (rows 2, 3).
//!
//! Texel (c, r) decodes to `e0 + (e1 - e0) i / 15` (i its index), so a bilinear blend of 4
//! texels of one block with weights b_k (sum 1) is `e0 + (e1 - e0) sum b_k i_k / 15`.
//!
//! Blocks overlap by one texel so that every bilinear footprint lies inside one block. With
//! extended texel coordinate x_e = x + 1 (x = -1 .. w - 1, the left texel of the
//! footprint, wrapped), block bx covers x_e = 3 bx .. 3 bx + 3, i.e. tile texels
//! (3 bx - 1 + c) mod w for c = 0..3; the footprint at x_e lies in block x_e / 3 at column
//! x_e mod 3 and the next. An image of w x h texels takes (w / 3 + 1) x (h / 3 + 1) blocks
//! (11 x 11 for 32 x 32: 1.89 bytes per texel). A texel shared by two blocks is encoded
//! in each; the two decodings differ by at most the encoding error, so the result may step
//! by that much where a pixel's footprint moves from one block to the next.

/// Blocks along an image side of `n` texels.
pub fn blocks(n: u32) -> u32 {
    n / 3 + 1
}

/// The tile texel (wrapped) of column or row `c` (0..4) of block `b` along a side of `n`.
pub fn texel_of(b: u32, c: u32, n: u32) -> u32 {
    (3 * b + c + n - 1) % n
}

const MAX: [f64; 3] = [2047.0, 2047.0, 1023.0];
const SHIFT: [u32; 3] = [0, 11, 22];

fn pack_endpoint(q: [u32; 3]) -> u32 {
    q[0] | (q[1] << 11) | (q[2] << 22)
}

/// The linear RGB of an endpoint word.
pub fn endpoint(e: u32) -> [f64; 3] {
    [0, 1, 2].map(|i| ((e >> SHIFT[i]) & MAX[i] as u32) as f64 / MAX[i])
}

/// The 4-bit index of texel (c, r) of `block`.
pub fn index(block: &[u32; 4], c: u32, r: u32) -> u32 {
    let word = if r < 2 { block[2] } else { block[3] };
    (word >> (16 * (r & 1) + 4 * c)) & 15
}

/// Linear RGB of texel (c, r) of `block`.
pub fn decode(block: &[u32; 4], c: u32, r: u32) -> [f64; 3] {
    let (e0, e1) = (endpoint(block[0]), endpoint(block[1]));
    let t = index(block, c, r) as f64 / 15.0;
    [0, 1, 2].map(|i| e0[i] + (e1[i] - e0[i]) * t)
}

fn quantise(p: [f64; 3]) -> [u32; 3] {
    [0, 1, 2].map(|i| (p[i].clamp(0.0, 1.0) * MAX[i]).round() as u32)
}

fn dequantise(q: [u32; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| q[i] as f64 / MAX[i])
}

/// Indices of the nearest of the 16 levels between quantised endpoints, and the squared error.
fn assign(px: &[[f64; 3]; 16], q0: [u32; 3], q1: [u32; 3]) -> ([u32; 16], f64) {
    let (a, b) = (dequantise(q0), dequantise(q1));
    let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let mut idx = [0u32; 16];
    let mut err = 0.0;
    for (k, p) in px.iter().enumerate() {
        let i = if dd > 0.0 {
            let t = ((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1] + (p[2] - a[2]) * d[2]) / dd;
            (t * 15.0).round().clamp(0.0, 15.0) as u32
        } else {
            0
        };
        idx[k] = i;
        let t = i as f64 / 15.0;
        for c in 0..3 {
            let e = a[c] + d[c] * t - p[c];
            err += e * e;
        }
    }
    (idx, err)
}

/// Endpoints by least squares for fixed indices (None when all indices are equal):
/// p = e0 (1 - t) + e1 t with t = index / 15.
fn refit(px: &[[f64; 3]; 16], idx: &[u32; 16]) -> Option<([f64; 3], [f64; 3])> {
    crate::io::bc1::fit_endpoints(px, idx.map(|i| 1.0 - i as f64 / 15.0), 1e-12)
}

/// Encodes 16 linear RGB texels (row-major 4 x 4, values clamped to [0, 1]).
pub fn encode_block(px: &[[f64; 3]; 16]) -> [u32; 4] {
    let mut mean = [0.0; 3];
    for p in px {
        for c in 0..3 {
            mean[c] += p[c] / 16.0;
        }
    }
    let mut cov = [[0.0; 3]; 3];
    for p in px {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += d[i] * d[j];
            }
        }
    }
    // Principal axis by power iteration, started from the largest-variance channel.
    let start = (0..3)
        .max_by(|&a, &b| cov[a][a].total_cmp(&cov[b][b]))
        .unwrap_or(0);
    let mut axis = cov[start];
    for _ in 0..8 {
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        if n < 1e-30 {
            break;
        }
        let a = axis.map(|x| x / n);
        axis = [0, 1, 2].map(|i| cov[i][0] * a[0] + cov[i][1] * a[1] + cov[i][2] * a[2]);
    }
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let axis = if n < 1e-30 {
        [1.0, 1.0, 1.0].map(|x: f64| x / 3f64.sqrt())
    } else {
        axis.map(|x| x / n)
    };
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for p in px {
        let t =
            (p[0] - mean[0]) * axis[0] + (p[1] - mean[1]) * axis[1] + (p[2] - mean[2]) * axis[2];
        lo = lo.min(t);
        hi = hi.max(t);
    }
    let at = |t: f64| [0, 1, 2].map(|c| mean[c] + axis[c] * t);
    let mut q = (quantise(at(lo)), quantise(at(hi)));
    let (mut idx, mut err) = assign(px, q.0, q.1);
    // A few rounds of least-squares refits, keeping the best.
    for _ in 0..3 {
        let Some((e0, e1)) = refit(px, &idx) else {
            break;
        };
        let cand = (quantise(e0), quantise(e1));
        let (ci, ce) = assign(px, cand.0, cand.1);
        if ce >= err {
            break;
        }
        (q, idx, err) = (cand, ci, ce);
    }
    let mut words = [0u32; 2];
    for (k, &i) in idx.iter().enumerate() {
        let (c, r) = (k as u32 % 4, k as u32 / 4);
        words[(r / 2) as usize] |= i << (16 * (r & 1) + 4 * c);
    }
    [pack_endpoint(q.0), pack_endpoint(q.1), words[0], words[1]]
}

/// The blocks of one `w` x `h` image of linear RGB texels (row-major), row-major blocks.
pub fn encode_image(w: u32, h: u32, texels: &[[f32; 3]]) -> Vec<[u32; 4]> {
    let (bw, bh) = (blocks(w), blocks(h));
    let mut out = Vec::with_capacity((bw * bh) as usize);
    for by in 0..bh {
        for bx in 0..bw {
            let mut px = [[0.0; 3]; 16];
            for r in 0..4 {
                for c in 0..4 {
                    let (x, y) = (texel_of(bx, c, w), texel_of(by, r, h));
                    let t = texels[(y * w + x) as usize];
                    px[(r * 4 + c) as usize] = t.map(|v| (v as f64).clamp(0.0, 1.0));
                }
            }
            out.push(encode_block(&px));
        }
    }
    out
}

/// Bilinear filtering with REPEAT wrapping at `uv` of an image stored as `blocks` (w x h
/// texels), as the shader does it: the footprint's block, then its 4 texels decoded.
pub fn bilinear(size: [u32; 2], blocks_of: &[[u32; 4]], uv: [f64; 2]) -> [f64; 3] {
    let [w, h] = size;
    let x = uv[0].rem_euclid(1.0) * w as f64 - 0.5;
    let y = uv[1].rem_euclid(1.0) * h as f64 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (xe, ye) = ((x0 as i64 + 1) as u32, (y0 as i64 + 1) as u32);
    let (bx, by) = (xe / 3, ye / 3);
    let (ox, oy) = (xe % 3, ye % 3);
    let b = &blocks_of[(by * blocks(w) + bx) as usize];
    let mut out = [0.0; 3];
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let t = decode(b, ox + dx, oy + dy);
            for k in 0..3 {
                out[k] += wx * wy * t[k];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_cover_every_footprint() {
        for n in [1u32, 2, 3, 4, 8, 31, 32, 33] {
            let nb = blocks(n);
            // Footprint left texel x = -1 .. n - 1 (x_e = 0 .. n): block x_e / 3 holds
            // texels x and x + 1 (wrapped) at columns x_e % 3 and x_e % 3 + 1.
            for xe in 0..=n {
                let b = xe / 3;
                assert!(b < nb, "n {n} xe {xe}");
                let x = (xe + n - 1) % n;
                assert_eq!(texel_of(b, xe % 3, n), x);
                assert_eq!(texel_of(b, xe % 3 + 1, n), (x + 1) % n);
            }
        }
    }

    #[test]
    fn a_line_of_colours_encodes_almost_exactly() {
        let px: [[f64; 3]; 16] =
            std::array::from_fn(|k| [0.1 + 0.05 * k as f64, 0.05 + 0.02 * k as f64, 0.3]);
        let b = encode_block(&px);
        for k in 0..16u32 {
            let d = decode(&b, k % 4, k / 4);
            for c in 0..3 {
                assert!((d[c] - px[k as usize][c]).abs() < 2e-3, "{k} {d:?}");
            }
        }
        // A flat block decodes to its colour within endpoint quantisation.
        let flat = encode_block(&[[0.25, 0.5, 0.75]; 16]);
        let d = decode(&flat, 2, 3);
        assert!(
            (d[0] - 0.25).abs() < 3e-4 && (d[2] - 0.75).abs() < 6e-4,
            "{d:?}"
        );
    }

    #[test]
    fn bilinear_matches_plain_filtering_of_the_decoded_texels_where_blocks_agree() {
        // A tile whose every 4 x 4 neighbourhood is exactly representable (a line of
        // colours along x only changes with x: each block holds 4 distinct levels).
        let (w, h) = (8u32, 8u32);
        let texels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let g = (i % w) as f32 / 16.0;
                [g, 0.5 * g, 0.25]
            })
            .collect();
        let blocks_of = encode_image(w, h, &texels);
        for uv in [[0.01, 0.5], [0.5, 0.99], [0.3, 0.7], [0.999, 0.001]] {
            let want = crate::geom::bilinear([w, h], uv, |c, r| {
                texels[(r * w + c) as usize].map(|v| v as f64)
            });
            let got = bilinear([w, h], &blocks_of, uv);
            for c in 0..3 {
                assert!(
                    (got[c] - want[c]).abs() < 5e-3,
                    "{uv:?}: {got:?} vs {want:?}"
                );
            }
        }
    }
}
