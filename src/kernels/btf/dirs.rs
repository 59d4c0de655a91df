//! The UBO2003 direction set, the parabolic (paraboloid) projection, the Delaunay
//! triangulation of the projected sample directions and the index/weight maps built from it.
//!
//! Directions are in the tangent frame (x along the tangent = texture u, y along the
//! bitangent = texture v, z along the normal); theta is measured from z, phi from x towards y.
//!
//! Below the lowest sampled ring (theta > 75 deg) the rule is btflib's: 24 virtual
//! directions at parabolic radius 1/cos(pi/24) (the 24-gon through them contains the unit
//! disk) join the triangulation with weight 0, so a lookup between the 75 deg ring and the
//! horizon fades linearly towards 0; the weights there sum to less than 1. Inside the sampled
//! range (theta <= 75 deg) the weights are barycentric and sum to 1. Directions below the
//! horizon (z <= 0) are not looked up at all (the shading gives them no light).

use crate::error::{Error, Result};

/// Sampled directions per hemisphere (light and view use the same set).
pub const COUNT: usize = 81;
/// (theta in degrees, number of azimuths) per ring; phi steps 360 / n from 0.
pub const RINGS: [(u32, u32); 6] = [(0, 1), (15, 6), (30, 12), (45, 18), (60, 20), (75, 24)];
/// The largest sampled polar angle (degrees).
pub const MAX_THETA_DEG: f64 = 75.0;
/// Virtual zero-weight directions outside the horizon.
pub const VIRTUAL: usize = 24;

/// One sampled direction: angles in whole degrees (as in the UBO2003 file names).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
pub struct Angles {
    pub theta: u32,
    pub phi: u32,
}

impl Angles {
    /// The unit vector of these angles.
    pub fn vector(self) -> [f64; 3] {
        let (t, p) = (
            (self.theta as f64).to_radians(),
            (self.phi as f64).to_radians(),
        );
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    }
}

/// The 81 sampled directions in UBO2003 order (ring by ring, phi increasing).
pub fn directions() -> Vec<Angles> {
    let mut v = Vec::with_capacity(COUNT);
    for (theta, n) in RINGS {
        for k in 0..n {
            v.push(Angles {
                theta,
                phi: k * 360 / n,
            });
        }
    }
    v
}

/// Index of `a` in [`directions`], if it is a sampled direction (phi taken modulo 360; at
/// theta 0 every phi names the pole).
pub fn index_of(a: Angles) -> Option<usize> {
    let phi = a.phi % 360;
    let mut base = 0usize;
    for (theta, n) in RINGS {
        if a.theta == theta {
            if theta == 0 {
                return Some(0);
            }
            let step = 360 / n;
            return phi
                .is_multiple_of(step)
                .then_some(base + (phi / step) as usize);
        }
        base += n as usize;
    }
    None
}

/// Parabolic projection of a unit direction with z > -1: p = (x, y) / (1 + z).
pub fn project(d: [f64; 3]) -> [f64; 2] {
    let s = 1.0 + d[2];
    [d[0] / s, d[1] / s]
}

/// Inverse of [`project`]: with l = px^2 + py^2, d = (2 px, 2 py, 1 - l) / (1 + l).
pub fn unproject(p: [f64; 2]) -> [f64; 3] {
    let l = p[0] * p[0] + p[1] * p[1];
    [
        2.0 * p[0] / (1.0 + l),
        2.0 * p[1] / (1.0 + l),
        (1.0 - l) / (1.0 + l),
    ]
}

/// The projected points of the triangulation: the 81 samples, then the 24 virtual ones.
pub fn points() -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = directions().iter().map(|a| project(a.vector())).collect();
    let r = 1.0 / (std::f64::consts::PI / 24.0).cos();
    for k in 0..VIRTUAL {
        let phi = (k as f64 * 15.0).to_radians();
        p.push([r * phi.cos(), r * phi.sin()]);
    }
    p
}

/// Whether the parabolic point `p` lies inside the hull of the real samples (the 24-gon of
/// the 75 deg ring): there the weights are barycentric among real samples and sum to 1.
pub fn in_sampled_hull(p: [f64; 2]) -> bool {
    let big_r = (MAX_THETA_DEG.to_radians() / 2.0).tan();
    let step = std::f64::consts::TAU / 24.0;
    let phi = p[1].atan2(p[0]).rem_euclid(std::f64::consts::TAU);
    // Normal of the edge of the sector holding phi, at its middle angle.
    let mid = ((phi / step).floor() + 0.5) * step;
    p[0] * mid.cos() + p[1] * mid.sin() <= big_r * (step / 2.0).cos()
}

/// Interpolation weights of the triangle enclosing a point: three point indices (into
/// [`points`]) and their barycentric weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taps {
    pub index: [usize; 3],
    pub weight: [f64; 3],
}

/// A Delaunay triangulation of the projected sample directions (Bowyer-Watson).
#[derive(Clone, Debug)]
pub struct Triangulation {
    pub points: Vec<[f64; 2]>,
    /// Counter-clockwise triangles.
    pub triangles: Vec<[usize; 3]>,
}

fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Whether `d` is strictly inside the circumcircle of the counter-clockwise (a, b, c).
fn in_circle(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let (ax, ay) = (a[0] - d[0], a[1] - d[1]);
    let (bx, by) = (b[0] - d[0], b[1] - d[1]);
    let (cx, cy) = (c[0] - d[0], c[1] - d[1]);
    let det = (ax * ax + ay * ay) * (bx * cy - cx * by) - (bx * bx + by * by) * (ax * cy - cx * ay)
        + (cx * cx + cy * cy) * (ax * by - bx * ay);
    det > 0.0
}

impl Triangulation {
    /// Triangulates the sample directions and the virtual ring.
    pub fn new() -> Result<Triangulation> {
        Self::of(points())
    }

    /// Bowyer-Watson over `points`. The rings are co-circular by construction, which makes
    /// the Delaunay triangulation ambiguous; the points are perturbed by a tiny fixed
    /// pseudo-random amount (1e-9) for the in-circle decisions only, so ties are broken
    /// consistently. Barycentric weights use the exact points.
    pub fn of(points: Vec<[f64; 2]>) -> Result<Triangulation> {
        let n = points.len();
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut jitter = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut q: Vec<[f64; 2]> = points
            .iter()
            .map(|p| [p[0] + 1e-9 * jitter(), p[1] + 1e-9 * jitter()])
            .collect();
        // Super-triangle far outside every point.
        q.push([-100.0, -100.0]);
        q.push([100.0, -100.0]);
        q.push([0.0, 100.0]);
        let mut tris: Vec<[usize; 3]> = vec![[n, n + 1, n + 2]];
        for i in 0..n {
            let p = q[i];
            let (bad, keep): (Vec<[usize; 3]>, Vec<[usize; 3]>) = tris
                .into_iter()
                .partition(|t| in_circle(q[t[0]], q[t[1]], q[t[2]], p));
            // Boundary of the cavity: edges of bad triangles not shared by another bad one.
            let mut edges: Vec<[usize; 2]> = Vec::new();
            for t in &bad {
                for e in [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]] {
                    let shared = bad.iter().any(|u| {
                        u != t && [[u[0], u[1]], [u[1], u[2]], [u[2], u[0]]].contains(&[e[1], e[0]])
                    });
                    if !shared {
                        edges.push(e);
                    }
                }
            }
            tris = keep;
            for e in edges {
                let t = [e[0], e[1], i];
                if orient(q[t[0]], q[t[1]], q[t[2]]) <= 0.0 {
                    return Err(Error::InvalidArgument(format!(
                        "Delaunay triangulation: degenerate cavity at point {i}"
                    )));
                }
                tris.push(t);
            }
        }
        tris.retain(|t| t.iter().all(|&v| v < n));
        Ok(Triangulation {
            points,
            triangles: tris,
        })
    }

    /// The enclosing triangle of `p` and its barycentric weights (clamped to >= 0 and
    /// renormalised against rounding at edges); `None` outside the triangulated hull.
    pub fn locate(&self, p: [f64; 2]) -> Option<Taps> {
        let mut best: Option<(f64, Taps)> = None;
        for t in &self.triangles {
            let [a, b, c] = [self.points[t[0]], self.points[t[1]], self.points[t[2]]];
            let area = orient(a, b, c);
            let w = [
                orient(p, b, c) / area,
                orient(a, p, c) / area,
                orient(a, b, p) / area,
            ];
            let worst = w.iter().cloned().fold(f64::INFINITY, f64::min);
            if best.as_ref().is_none_or(|(m, _)| worst > *m) {
                best = Some((
                    worst,
                    Taps {
                        index: *t,
                        weight: w,
                    },
                ));
            }
            if worst >= 0.0 {
                break;
            }
        }
        let (worst, mut taps) = best?;
        if worst < -1e-9 {
            return None;
        }
        for w in &mut taps.weight {
            *w = w.max(0.0);
        }
        let s: f64 = taps.weight.iter().sum();
        for w in &mut taps.weight {
            *w /= s;
        }
        Some(taps)
    }

    /// The interpolation of direction `d` (tangent space, z > 0): sample indices (< 81) and
    /// weights, virtual directions given weight 0 (their index set to the first real tap).
    pub fn weights(&self, d: [f64; 3]) -> Taps {
        let mut p = project(d);
        let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
        if r > 1.0 {
            p = [p[0] / r, p[1] / r];
        }
        // The hull (the virtual 24-gon) contains the unit disk, so this always succeeds.
        let mut t = self.locate(p).unwrap_or(Taps {
            index: [0; 3],
            weight: [0.0; 3],
        });
        let real = t.index.iter().copied().find(|&i| i < COUNT).unwrap_or(0);
        for k in 0..3 {
            if t.index[k] >= COUNT {
                t.index[k] = real;
                t.weight[k] = 0.0;
            }
        }
        t
    }
}

/// The index and weight maps: `res` x `res` texels over the parabolic square [-1, 1]^2
/// (texel (i, j) at p = ((i + 0.5) / res * 2 - 1, (j + 0.5) / res * 2 - 1)); texels outside
/// the unit disk hold the horizon's value in their direction.
#[derive(Clone, Debug)]
pub struct Maps {
    pub res: u32,
    /// Per texel, row-major: three sample indices (< 81) and 0.
    pub index: Vec<[u8; 4]>,
    /// Per texel: three weights and 0.
    pub weight: Vec<[f32; 4]>,
}

/// Smallest and largest map resolution accepted.
pub const MAP_RES: std::ops::RangeInclusive<u32> = 4..=4096;

impl Maps {
    /// Checks what the shader indexes with: `res` in [`MAP_RES`], res^2 texels of each map,
    /// sample indices < 81, finite non-negative weights (the fields are public, so a
    /// hand-built map must not make the GPU fetch outside the packed BTF).
    pub fn check(&self) -> Result<()> {
        let n = self.res as usize * self.res as usize;
        if !MAP_RES.contains(&self.res) || self.index.len() != n || self.weight.len() != n {
            return Err(Error::InvalidArgument(format!(
                "BTF maps: resolution {} ({:?}) with {} index and {} weight texels (need res^2)",
                self.res,
                MAP_RES,
                self.index.len(),
                self.weight.len()
            )));
        }
        if let Some(t) = self
            .index
            .iter()
            .position(|i| i[..3].iter().any(|&k| k >= 81))
        {
            return Err(Error::InvalidArgument(format!(
                "BTF maps: texel {t} names sample {:?}; there are 81 directions",
                self.index[t]
            )));
        }
        if let Some(t) = self
            .weight
            .iter()
            .position(|w| w.iter().any(|x| !x.is_finite() || *x < 0.0))
        {
            return Err(Error::InvalidArgument(format!(
                "BTF maps: texel {t} has weights {:?} (need finite, >= 0)",
                self.weight[t]
            )));
        }
        Ok(())
    }

    /// Builds the maps at `res` x `res` from `tri`.
    pub fn build(tri: &Triangulation, res: u32) -> Result<Maps> {
        if !MAP_RES.contains(&res) {
            return Err(Error::InvalidArgument(format!(
                "map resolution {res} outside {}..={}",
                MAP_RES.start(),
                MAP_RES.end()
            )));
        }
        use rayon::prelude::*;
        let texels: Vec<([u8; 4], [f32; 4])> = (0..res * res)
            .into_par_iter()
            .map(|k| {
                let p = Self::texel_point(res, k % res, k / res);
                let t = tri.weights(unproject(p));
                (
                    [t.index[0] as u8, t.index[1] as u8, t.index[2] as u8, 0],
                    [
                        t.weight[0] as f32,
                        t.weight[1] as f32,
                        t.weight[2] as f32,
                        0.0,
                    ],
                )
            })
            .collect();
        let (index, weight) = texels.into_iter().unzip();
        Ok(Maps { res, index, weight })
    }

    /// The parabolic point at the centre of texel (i, j).
    pub fn texel_point(res: u32, i: u32, j: u32) -> [f64; 2] {
        [
            (i as f64 + 0.5) / res as f64 * 2.0 - 1.0,
            (j as f64 + 0.5) / res as f64 * 2.0 - 1.0,
        ]
    }

    /// The texel a tangent-space direction (z > 0) is looked up in, and the distance of its
    /// continuous texel coordinate to the nearest texel border (in texels).
    pub fn texel_of(&self, d: [f64; 3]) -> ([u32; 2], f64) {
        let p = project(d);
        let n = self.res as f64;
        let mut ij = [0u32; 2];
        let mut margin = f64::INFINITY;
        for a in 0..2 {
            let x = ((p[a] + 1.0) * 0.5 * n).clamp(0.0, n - 1e-9);
            ij[a] = x.floor() as u32;
            let f = x - x.floor();
            margin = margin.min(f.min(1.0 - f));
        }
        (ij, margin)
    }

    /// The map lookup of direction `d` (nearest texel).
    pub fn lookup(&self, d: [f64; 3]) -> Taps {
        let ([i, j], _) = self.texel_of(d);
        let k = (j * self.res + i) as usize;
        let (ix, w) = (self.index[k], self.weight[k]);
        Taps {
            index: [ix[0] as usize, ix[1] as usize, ix[2] as usize],
            weight: [w[0] as f64, w[1] as f64, w[2] as f64],
        }
    }

    /// Device bytes of both maps (RGBA8 indices + RGBA32F weights).
    pub fn bytes(&self) -> u64 {
        self.res as u64 * self.res as u64 * (4 + 16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_the_shader_could_misread_are_refused() {
        let ok = Maps {
            res: 4,
            index: vec![[0, 1, 80, 0]; 16],
            weight: vec![[0.5, 0.25, 0.25, 0.0]; 16],
        };
        ok.check().unwrap();
        let mut bad = ok.clone();
        bad.index[5][2] = 81;
        assert!(bad.check().unwrap_err().to_string().contains("texel 5"));
        let mut bad = ok.clone();
        bad.weight[3][0] = f32::NAN;
        assert!(bad.check().unwrap_err().to_string().contains("texel 3"));
        let mut bad = ok.clone();
        bad.weight.pop();
        assert!(bad.check().unwrap_err().to_string().contains("15 weight"));
    }

    /// `texel_of` names the texel a direction falls in and its distance to the nearest
    /// border, whichever side that is (the environment's and the basis's truths skip
    /// directions closer than a bound to a border). Catches cargo-mutants' survivor
    /// `1.0 - f` -> `1.0 + f` (issue 23), which measured only to the lower border.
    #[test]
    fn texel_of_gives_the_texel_and_the_distance_to_its_nearest_border() {
        let maps = Maps {
            res: 8,
            index: vec![[0, 0, 0, 0]; 64],
            weight: vec![[1.0, 0.0, 0.0, 0.0]; 64],
        };
        // Continuous texel coordinate x = (p + 1) / 2 * 8, so p = x / 4 - 1.
        for (x, y, want_ij, want_margin) in [
            (2.9, 5.5, [2, 5], 0.1),
            (2.1, 5.5, [2, 5], 0.1),
            (6.5, 0.75, [6, 0], 0.25),
            (3.5, 4.5, [3, 4], 0.5),
        ] {
            let d = unproject([x / 4.0 - 1.0, y / 4.0 - 1.0]);
            let (ij, margin) = maps.texel_of(d);
            assert_eq!(ij, want_ij, "texel of ({x}, {y})");
            assert!(
                (margin - want_margin).abs() < 1e-9,
                "margin at ({x}, {y}): {margin}, want {want_margin}"
            );
        }
    }

    #[test]
    fn directions_are_the_ubo2003_set() {
        let d = directions();
        assert_eq!(d.len(), COUNT);
        for (i, a) in d.iter().enumerate() {
            assert_eq!(index_of(*a), Some(i));
        }
        assert_eq!(index_of(Angles { theta: 0, phi: 90 }), Some(0));
        assert_eq!(index_of(Angles { theta: 15, phi: 30 }), None);
        assert_eq!(index_of(Angles { theta: 20, phi: 0 }), None);
        // Ring radii tan(theta / 2).
        let p = project(Angles { theta: 60, phi: 0 }.vector());
        assert!((p[0] - 30f64.to_radians().tan()).abs() < 1e-12);
    }

    #[test]
    fn projection_round_trip() {
        for i in 0..50 {
            for j in 0..50 {
                let th = (i as f64 + 0.5) / 50.0 * 89.0f64.to_radians();
                let ph = j as f64 / 50.0 * std::f64::consts::TAU;
                let d = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
                let e = unproject(project(d));
                for k in 0..3 {
                    assert!((d[k] - e[k]).abs() < 1e-12, "{d:?} -> {e:?}");
                }
                let p = project(d);
                let q = project(unproject(p));
                assert!((p[0] - q[0]).abs() < 1e-12 && (p[1] - q[1]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn triangulation_covers_the_hull_once() {
        let t = Triangulation::new().unwrap();
        // Euler: a triangulation of n points with h on the convex hull has 2n - h - 2 triangles.
        let n = COUNT + VIRTUAL;
        assert_eq!(t.triangles.len(), 2 * n - VIRTUAL - 2);
        let area: f64 = t
            .triangles
            .iter()
            .map(|x| orient(t.points[x[0]], t.points[x[1]], t.points[x[2]]) / 2.0)
            .sum();
        let r = 1.0 / (std::f64::consts::PI / 24.0).cos();
        let hull = 0.5 * 24.0 * r * r * (std::f64::consts::TAU / 24.0).sin();
        assert!((area - hull).abs() < 1e-9, "{area} vs {hull}");
        // Delaunay: no point strictly inside any circumcircle (beyond the tie tolerance).
        for x in &t.triangles {
            let [a, b, c] = [t.points[x[0]], t.points[x[1]], t.points[x[2]]];
            for (i, &p) in t.points.iter().enumerate() {
                if x.contains(&i) {
                    continue;
                }
                let (ax, ay) = (a[0] - p[0], a[1] - p[1]);
                let (bx, by) = (b[0] - p[0], b[1] - p[1]);
                let (cx, cy) = (c[0] - p[0], c[1] - p[1]);
                let det = (ax * ax + ay * ay) * (bx * cy - cx * by)
                    - (bx * bx + by * by) * (ax * cy - cx * ay)
                    + (cx * cx + cy * cy) * (ax * by - bx * ay);
                assert!(det < 1e-7, "point {i} inside circumcircle of {x:?}: {det}");
            }
        }
    }

    #[test]
    fn a_sample_direction_gets_weight_one_on_itself() {
        let t = Triangulation::new().unwrap();
        for (i, a) in directions().iter().enumerate() {
            let taps = t.weights(a.vector());
            let mut on_self = 0.0;
            for k in 0..3 {
                if taps.index[k] == i {
                    on_self += taps.weight[k];
                }
            }
            assert!((on_self - 1.0).abs() < 1e-9, "{a:?}: {taps:?}");
        }
    }

    #[test]
    fn weights_are_non_negative_and_sum_to_one_inside_the_sampled_range() {
        let t = Triangulation::new().unwrap();
        let check = |p: [f64; 2], taps: Taps| {
            let s: f64 = taps.weight.iter().sum();
            assert!(taps.weight.iter().all(|&w| w >= 0.0), "{p:?}: {taps:?}");
            assert!(taps.index.iter().all(|&i| i < COUNT));
            if in_sampled_hull(p) {
                assert!((s - 1.0).abs() < 1e-6, "{p:?}: sum {s}");
                true
            } else {
                // The fade towards the horizon.
                assert!((0.0..=1.0 + 1e-6).contains(&s), "{p:?}: sum {s}");
                false
            }
        };
        let mut inside = 0;
        for th in 0..=90 {
            for ph in (0..360).step_by(7) {
                let (th_r, ph_r) = ((th as f64).to_radians(), (ph as f64).to_radians());
                let d = [th_r.sin() * ph_r.cos(), th_r.sin() * ph_r.sin(), th_r.cos()];
                inside += check(project(d), t.weights(d)) as usize;
            }
        }
        assert!(inside > 3000, "{inside}");
        // Every texel of a map, at its centre's direction.
        let maps = Maps::build(&t, 48).unwrap();
        for j in 0..48 {
            for i in 0..48 {
                let p = Maps::texel_point(48, i, j);
                let k = (j * 48 + i) as usize;
                let taps = Taps {
                    index: maps.index[k].map(|x| x as usize)[..3].try_into().unwrap(),
                    weight: [0, 1, 2].map(|c| maps.weight[k][c] as f64),
                };
                check(p, taps);
                if p[0] * p[0] + p[1] * p[1] < 1.0 {
                    assert_eq!(maps.lookup(unproject(p)), taps);
                }
            }
        }
        // At the horizon almost nothing is left.
        let h = t.weights([1.0, 0.0, 0.0]).weight.iter().sum::<f64>();
        assert!(h < 0.05, "horizon weight {h}");
    }

    /// A direction at the horizon (z > 0 but below f64's resolution of 1 + z) projects to
    /// p = 1 exactly: its texel must still lie inside the map. Catches the clamp's upper end
    /// `n - 1e-9` loosened to `n + 1e-9` (cargo-mutants' survivor in `texel_of`, issue 23):
    /// texel `res`, and `lookup` indexes past the map.
    #[test]
    fn grazing_directions_stay_inside_the_map() {
        let maps = Maps::build(&Triangulation::new().unwrap(), 32).unwrap();
        for d in [[1.0, 0.0, 1e-18], [0.0, 1.0, 1e-18], [-1.0, 0.0, 1e-18]] {
            let ([i, j], margin) = maps.texel_of(d);
            assert!(
                i < 32 && j < 32 && margin >= 0.0,
                "{d:?}: ({i}, {j}), {margin}"
            );
            let taps = maps.lookup(d);
            assert!(taps.index.iter().all(|&k| k < COUNT), "{taps:?}");
        }
    }

    /// The maps' texels reproduce an affine function of the parabolic point from the 81
    /// samples' values (barycentric weights do so exactly; f32 weights: 1e-6 on values ~1).
    /// The library-level twin of `tests/btf.rs`'
    /// `map_lookups_between_sample_directions_interpolate_an_affine_function_exactly`, at a
    /// coarse map, so that CI's mutation smoke (tools/mutants-smoke.sh) plants the issue-23
    /// bug in the library's own tests: catches the direction interpolation replaced by the
    /// nearest direction (one-hot weights in `Maps::build`; the nearest sample is off by up
    /// to ~0.1 here).
    #[test]
    fn map_texels_interpolate_an_affine_function_of_the_samples() {
        let res = 32;
        let maps = Maps::build(&Triangulation::new().unwrap(), res).unwrap();
        let f = |p: [f64; 2]| 0.6 + 0.25 * p[0] - 0.4 * p[1];
        let samples: Vec<f64> = points()[..COUNT].iter().map(|&p| f(p)).collect();
        let mut checked = 0;
        for j in 0..res {
            for i in 0..res {
                let p = Maps::texel_point(res, i, j);
                if !in_sampled_hull(p) {
                    continue;
                }
                let d = unproject(p);
                let taps = maps.lookup(d);
                let got: f64 = (0..3)
                    .map(|k| taps.weight[k] * samples[taps.index[k]])
                    .sum();
                let want = f(project(d));
                assert!(
                    (got - want).abs() < 1e-6,
                    "texel ({i}, {j}): {got} vs {want} ({taps:?})"
                );
                checked += 1;
            }
        }
        // The 75 degree ring's hull has parabolic radius tan(37.5 deg) = 0.77: pi 0.77^2 / 4
        // of the map's 32^2 texels, ~470, lie inside it.
        assert!(checked > 400, "{checked} texels inside the sampled range");
    }

    #[test]
    fn interpolation_is_continuous() {
        // Neighbouring directions get nearly the same interpolated value of a smooth
        // function of the samples (no triangle gaps or flips).
        let t = Triangulation::new().unwrap();
        let f: Vec<f64> = directions()
            .iter()
            .map(|a| {
                let v = a.vector();
                v[0] + 2.0 * v[1] + v[2]
            })
            .collect();
        let eval = |d: [f64; 3]| {
            let w = t.weights(d);
            (0..3).map(|k| w.weight[k] * f[w.index[k]]).sum::<f64>()
        };
        for k in 0..2000 {
            let a = k as f64 * 0.0031;
            let th = 70f64.to_radians() * (0.5 + 0.5 * (a * 3.0).sin());
            let (d0, d1) = (
                [th.sin() * a.cos(), th.sin() * a.sin(), th.cos()],
                [
                    (th + 1e-5).sin() * (a + 1e-5).cos(),
                    (th + 1e-5).sin() * (a + 1e-5).sin(),
                    (th + 1e-5).cos(),
                ],
            );
            assert!((eval(d0) - eval(d1)).abs() < 1e-3);
        }
    }
}
