//! Geometry and shared physical models of the CPU parts, used alike by the methods and by
//! the ground truths that judge them: a BVH and ray-cast visibility ([`visibility`]), the
//! spherical-Gaussian algebra ([`sg`]), small dense linear algebra ([`linalg`]), sampling,
//! bilinear texture filtering, a small deterministic RNG.

pub mod brdf;
pub mod bvh;
pub mod cloth;
pub mod linalg;
pub mod profile;
pub mod sg;
pub mod visibility;

pub use bvh::Bvh;
use glam::Vec3;

/// SplitMix64: small, fast, deterministic for a given seed (results are reproducible).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x9e37_79b9_7f4a_7c15)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in [0, n) for n < 2^32 (multiply-shift, no modulo bias worth naming).
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }
}

/// Point indices sorted along a Morton curve through `positions` (10 bits per axis over
/// their bounding box; ties by index). A GPU pass that takes point `order[i]` in invocation
/// `i` gives a subgroup's lanes neighbours, whose walks through a tree or a BVH are alike: a
/// SIMD driver runs every lane's loop as long as the busiest lane's.
pub fn spatial_order(positions: &[Vec3]) -> Vec<u32> {
    let lo = positions.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
    let hi = positions.iter().fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
    let key = |p: Vec3| -> u32 {
        let q: [u32; 3] = std::array::from_fn(|a| {
            let span = (hi[a] - lo[a]).max(f32::MIN_POSITIVE);
            (((p[a] - lo[a]) / span * 1023.0).clamp(0.0, 1023.0)) as u32
        });
        (0..10).rev().fold(0u32, |k, bit| {
            (0..3).fold(k, |k, a| (k << 1) | ((q[a] >> bit) & 1))
        })
    };
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_by_key(|&i| (key(positions[i as usize]), i));
    order
}

/// Uniform direction on the unit sphere from two uniforms.
pub fn uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Cosine-weighted direction on the +Z hemisphere (Malley's method).
pub fn cosine_hemisphere(u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

/// A right-handed orthonormal basis (t, b) completing unit `n` (Duff et al. 2017).
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Bilinear filtering with REPEAT wrapping of the texels given by `texel(c, r)` (texel
/// centres at (i + 0.5) / size), as a sampler with linear filtering does: how the BTF's CPU
/// twin filters the stored images and its ground truth the ray-cast texels.
pub fn bilinear(size: [u32; 2], uv: [f64; 2], texel: impl Fn(u32, u32) -> [f64; 3]) -> [f64; 3] {
    bilinear_n(size, uv, true, texel)
}

/// [`bilinear`] for texels of `N` channels, wrapping with REPEAT (`repeat`) or clamping to
/// the edge.
pub fn bilinear_n<const N: usize>(
    size: [u32; 2],
    uv: [f64; 2],
    repeat: bool,
    texel: impl Fn(u32, u32) -> [f64; N],
) -> [f64; N] {
    let (w, h) = (size[0] as i64, size[1] as i64);
    let x = uv[0] * w as f64 - 0.5;
    let y = uv[1] * h as f64 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let wrap = |c: i64, n: i64| {
        if repeat {
            c.rem_euclid(n)
        } else {
            c.clamp(0, n - 1)
        }
    };
    let mut out = [0.0; N];
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let t = texel(wrap(x0 + dx, w) as u32, wrap(y0 + dy, h) as u32);
            for k in 0..N {
                out[k] += wx * wy * t[k];
            }
        }
    }
    out
}
