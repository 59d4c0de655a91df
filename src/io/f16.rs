//! IEEE 754 binary16 ("half") encoding: the SRBF transfer's per-vertex weights are stored
//! on the GPU in half precision, and the CPU twin rounds through the same codec.

/// The largest finite half-precision value.
pub const HALF_MAX: f32 = 65504.0;

/// The index of the first value of `xs` beyond +-[`HALF_MAX`] or not finite: values that a
/// half-precision weight may not represent (those up to 65520 still round to 65504, so the
/// check is conservative).
pub fn first_beyond_half(xs: &[f32]) -> Option<usize> {
    xs.iter().position(|x| x.is_nan() || x.abs() > HALF_MAX)
}

/// IEEE binary16 bits of `x`, rounded to nearest even (overflow to infinity, NaN kept).
pub fn f16_bits(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal (or zero): the implicit bit joins the mantissa, shifted into place.
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = 1u32 << (shift - 1);
        let rest = m & ((1u32 << shift) - 1);
        let mut h = m >> shift;
        if rest > half || (rest == half && h & 1 == 1) {
            h += 1;
        }
        return sign | h as u16;
    }
    let rest = man & 0x1fff;
    let mut h = ((e as u32) << 10) | (man >> 13);
    if rest > 0x1000 || (rest == 0x1000 && h & 1 == 1) {
        h += 1; // may carry into the exponent, which is the correct rounding
    }
    sign | h as u16
}

/// The f32 value of binary16 bits (exact).
pub fn f16_value(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    match exp {
        // Subnormal: man x 2^-24, exact in f32.
        0 => f32::from_bits(sign) + (man as f32) * f32::from_bits(0x3380_0000) * sign_of(sign),
        0x1f => f32::from_bits(sign | 0x7f80_0000 | (man << 13)),
        _ => f32::from_bits(sign | ((exp + 127 - 15) << 23) | (man << 13)),
    }
}

fn sign_of(sign_bit: u32) -> f32 {
    if sign_bit != 0 { -1.0 } else { 1.0 }
}

/// `x` rounded to the nearest half-precision value (what the GPU's weights hold).
pub fn half_round(x: f32) -> f32 {
    f16_value(f16_bits(x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rng;

    #[test]
    fn half_precision_round_trip() {
        // Exact values survive; others land on the nearest half (ties to even).
        for x in [
            0.0f32,
            -0.0,
            1.0,
            -2.5,
            65504.0,
            6.1035156e-5,
            5.9604645e-8,
            0.33325195,
        ] {
            assert_eq!(half_round(x), x, "{x}");
        }
        assert_eq!(f16_bits(1.0), 0x3c00);
        assert_eq!(f16_bits(-2.0), 0xc000);
        assert_eq!(f16_bits(1.0 + 1.0 / 2048.0), 0x3c00); // tie: to even
        assert_eq!(f16_bits(1.0 + 3.0 / 2048.0), 0x3c02); // tie: to even (up)
        assert_eq!(f16_bits(70000.0), 0x7c00);
        assert!(half_round(f32::NAN).is_nan());
        // What half precision cannot hold: beyond +-HALF_MAX (infinite there) or not finite.
        assert_eq!(half_round(HALF_MAX), HALF_MAX);
        assert_eq!(first_beyond_half(&[1.0, -HALF_MAX, HALF_MAX]), None);
        assert_eq!(first_beyond_half(&[1.0, -65600.0, 0.0]), Some(1));
        assert_eq!(first_beyond_half(&[0.5, f32::NAN]), Some(1));
        assert_eq!(first_beyond_half(&[f32::INFINITY]), Some(0));
        let mut rng = Rng::new(3);
        for _ in 0..10_000 {
            let x = (rng.f32() - 0.5) * 10f32.powi((rng.f32() * 8.0) as i32 - 4);
            let r = half_round(x);
            // Within half an ulp of binary16 (relative 2^-11) for normal values.
            if x.abs() > 6.2e-5 {
                assert!((r - x).abs() <= x.abs() * 4.9e-4 + 1e-12, "{x} -> {r}");
            } else {
                assert!((r - x).abs() <= 3.0e-8, "{x} -> {r}");
            }
        }
    }

    /// Every finite binary16 value decodes exactly and encodes back to its own bits; NaNs
    /// stay NaN with their sign.
    #[test]
    fn every_half_round_trips() {
        for h in 0..=u16::MAX {
            let x = f16_value(h);
            if x.is_nan() {
                assert_eq!(h & 0x7c00, 0x7c00, "{h:#06x}");
                assert!(f16_bits(x) & 0x7fff > 0x7c00, "{h:#06x}");
                assert_eq!(f16_bits(x) & 0x8000, h & 0x8000, "{h:#06x}");
            } else {
                assert_eq!(f16_bits(x), h, "{h:#06x} -> {x}");
            }
        }
        // The largest subnormal and the smallest normal, by value.
        assert_eq!(f16_value(0x03ff), 1023.0 * 2f32.powi(-24));
        assert_eq!(f16_value(0x0400), 2f32.powi(-14));
    }
}
