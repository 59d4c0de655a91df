//! Equirectangular environment maps (latitude-longitude radiance), the lighting of the SRBF
//! kernel and of its brute-force reference.
//!
//! Conventions (issue 8): +Y up, right-handed. Texel coordinates (u, v) in [0, 1]^2, v = 0 at
//! the top row, hold the radiance arriving from the direction (x, y, z) with
//!
//! ```text
//! u = 0.5 + atan2(x, -z) / (2 pi),   v = acos(y) / pi
//! ```
//!
//! so the centre of the map (u, v) = (0.5, 0.5) is the direction (0, 0, -1), the top row is
//! +Y, and u grows towards +X. Inverting: theta = pi v, phi = 2 pi (u - 0.5),
//! w = (sin theta sin phi, cos theta, -sin theta cos phi).
//!
//! A rotated environment is L_R(w) = L(R^-1 w) ([`EnvMap::rotated_lookup`]).
//!
//! Files: OpenEXR (`.exr`, cargo feature `exr`: RGB(A) half or float, any compression the
//! `exr` crate decodes, DWAA/DWAB included; alpha is ignored) and Radiance RGBE (`.hdr`,
//! `.pic`: flat, old-style and new-style run-length scanlines, read here). Every map must be
//! 2:1 with finite, non-negative texels no brighter than [`MAX_RADIANCE`]; every error names
//! the file. EXR files may carry negative samples from lossy compression (DWAA/DWAB ringing
//! beside a bright sun): by default they are filtered out locally, keeping the energy
//! ([`HdrPolicy::Repair`], reported in [`EnvMap::repair`]); [`HdrPolicy::Strict`] refuses
//! all but tiny ones ([`NEGATIVE_TOLERANCE`]).

use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::visibility::{Visibility, direction_visibility};
use glam::{Mat3, Vec3};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// Largest accepted width (the height is half of it).
pub const MAX_WIDTH: u32 = 1 << 15;

/// Largest radiance a texel may hold; a brighter one is refused on loading (it is an
/// overflow, not a sun).
///
/// Why 1e12: what follows the loader sums and squares radiance in f32 (the SRBF fit's
/// least squares and its relative L2, the shading sums on the GPU): with L <= 1e12 and at
/// most [`MAX_WIDTH`] x [`MAX_WIDTH`] / 2 = 2^29 texels, a sum of squares stays below
/// 1e24 x 5.4e8 = 5.4e32, under f32's 3.4e38 with a margin of ~6e5 for the weights. Real
/// maps stay far below: an unclipped sun in a calibrated HDRI is ~1e5 to 1e9. A texel of
/// 3e38 (or an RGBE exponent decoding to ~1.7e38) made the fit print "relative L2 NaN".
pub const MAX_RADIANCE: f32 = 1e12;

/// How negative samples of a loaded EXR map (lossy-codec ringing) are treated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum HdrPolicy {
    /// The default: each negative sample is set to 0 and its (negative) energy taken from
    /// the positive samples around it, in proportion to their energy, so every
    /// neighbourhood keeps its sum ([`repair_ringing`]); reported in [`EnvMap::repair`].
    #[default]
    Repair,
    /// Refuse the map when a sample is below -[`NEGATIVE_TOLERANCE`] x the mean sample
    /// (smaller negatives still become 0): the behaviour before the repair existed.
    Strict,
}

/// What [`repair_ringing`] changed in a map.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RingingRepair {
    /// Negative samples (texel channels) set to 0.
    pub negative_samples: usize,
    /// The most negative sample.
    pub most_negative: f32,
    /// Energy moved (the negative samples' |L| x solid angle, summed over channels) over
    /// the map's total energy after the repair.
    pub moved_fraction: f64,
    /// Change of the map's total energy (after - before) over the total after: the part
    /// of the negative energy no positive neighbourhood within [`REPAIR_RADIUS`] could
    /// absorb, which was clamped instead.
    pub energy_change: f64,
}

impl std::fmt::Display for RingingRepair {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} negative samples (codec ringing, down to {:.3e}) moved into their positive \
             neighbours: {:.2e} of the map's energy moved, total energy changed by {:+.2e}",
            self.negative_samples, self.most_negative, self.moved_fraction, self.energy_change
        )
    }
}

/// How far (in texels, each way) [`repair_ringing`] looks for positive samples to take a
/// negative sample's energy from: two DWA blocks (8 x 8 DCT), where its ringing lives.
pub const REPAIR_RADIUS: usize = 16;

/// The largest share of a map's energy that [`repair_ringing`] may fail to absorb locally
/// (and clamp) before the map is refused as not ringing but wrong data.
pub const MAX_UNABSORBED: f64 = 0.01;

/// Removes negative samples from a `width` x `height` equirectangular map, keeping the
/// energy of every neighbourhood.
///
/// Why this policy: lossy EXR codecs (DWAA/DWAB, an 8 x 8 DCT) quantise the sharp edge of a
/// bright sun into ringing, an oscillation around the true values whose local sum is
/// about zero: samples down to about -2,000 beside +11,800. Clamping the negatives to 0
/// would keep the positive overshoot and add energy (the map gets brighter near the sun);
/// refusing would refuse common maps. So each negative sample is set to 0 and its energy
/// (L x solid angle, per channel) is taken from the positive samples within the smallest
/// window of radius 1, 2, 4, ... [`REPAIR_RADIUS`] texels (wrapping in longitude) that
/// holds enough of it, each giving in proportion to its energy: the overshoot cancels the
/// undershoot, the neighbourhood's sum and the sun's energy are kept (to f32 rounding), and
/// the sun's shape is only scaled. Energy no window could supply is clamped and reported as
/// [`RingingRepair::energy_change`]; more than [`MAX_UNABSORBED`] of the map is an error.
// `c` is the channel of every texel the window touches, not an index into one array.
#[allow(clippy::needless_range_loop)]
pub fn repair_ringing(
    width: usize,
    height: usize,
    texels: &mut [[f32; 3]],
    solid_angle: impl Fn(usize) -> f64,
) -> std::result::Result<Option<RingingRepair>, String> {
    let omega: Vec<f64> = (0..height).map(&solid_angle).collect();
    let energy_of = |t: &[[f32; 3]]| -> f64 {
        t.chunks(width)
            .zip(&omega)
            .map(|(row, w)| row.iter().flatten().map(|&c| c as f64).sum::<f64>() * w)
            .sum()
    };
    let before = energy_of(texels);
    let (mut count, mut most, mut moved, mut unabsorbed) = (0usize, 0.0f32, 0.0f64, 0.0f64);
    for i in 0..texels.len() {
        for c in 0..3 {
            let v = texels[i][c];
            if v >= 0.0 {
                continue;
            }
            count += 1;
            most = most.min(v);
            let (x0, y0) = (i % width, i / width);
            let mut deficit = -(v as f64) * omega[y0];
            moved += deficit;
            texels[i][c] = 0.0;
            let mut r = 1;
            loop {
                let r_eff = r.min(REPAIR_RADIUS);
                let ys = y0.saturating_sub(r_eff)..(y0 + r_eff + 1).min(height);
                let xr = r_eff.min((width - 1) / 2);
                let column = |dx: isize| (x0 as isize + dx).rem_euclid(width as isize) as usize;
                let mut available = 0.0f64;
                for y in ys.clone() {
                    for dx in -(xr as isize)..=xr as isize {
                        let t = texels[y * width + column(dx)][c];
                        if t > 0.0 {
                            available += t as f64 * omega[y];
                        }
                    }
                }
                if available >= deficit || r_eff == REPAIR_RADIUS {
                    let take = deficit.min(available);
                    if take > 0.0 {
                        let keep = 1.0 - take / available;
                        for y in ys {
                            for dx in -(xr as isize)..=xr as isize {
                                let t = &mut texels[y * width + column(dx)][c];
                                if *t > 0.0 {
                                    *t = (*t as f64 * keep) as f32;
                                }
                            }
                        }
                    }
                    deficit -= take;
                    unabsorbed += deficit;
                    break;
                }
                r *= 2;
            }
        }
    }
    if count == 0 {
        return Ok(None);
    }
    let after = energy_of(texels);
    if after.is_nan() || after <= 0.0 || unabsorbed > MAX_UNABSORBED * after {
        return Err(format!(
            "{count} negative samples down to {most:e} whose energy the positive samples \
             within {REPAIR_RADIUS} texels cannot absorb ({:.3e} of a total {after:.3e} left \
             over, more than {MAX_UNABSORBED} of it): too negative to be codec ringing",
            unabsorbed
        ));
    }
    Ok(Some(RingingRepair {
        negative_samples: count,
        most_negative: most,
        moved_fraction: moved / after,
        energy_change: (after - before) / after,
    }))
}

/// The unit direction at map coordinates (u, v) in [0, 1]^2 (v = 0 at the top row):
/// the inverse of u = 0.5 + atan2(x, -z) / (2 pi), v = acos(y) / pi.
pub fn direction_of(u: f64, v: f64) -> glam::DVec3 {
    let (theta, phi) = (PI * v, 2.0 * PI * (u - 0.5));
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    glam::DVec3::new(st * sp, ct, -st * cp)
}

/// An equirectangular radiance map, linear RGB.
#[derive(Clone, Debug)]
pub struct EnvMap {
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 = top (v = 0, direction +Y).
    pub texels: Vec<[f32; 3]>,
    /// The file it came from (or a name for an in-memory map), for error messages.
    pub source: PathBuf,
    /// What loading changed under [`HdrPolicy::Repair`] (None: nothing, or not loaded
    /// from a file); the commands print it.
    pub repair: Option<RingingRepair>,
}

impl EnvMap {
    /// Loads an equirectangular map from an `.exr` or `.hdr`/`.pic` file (by extension),
    /// repairing codec ringing ([`HdrPolicy::Repair`], the default).
    pub fn load(path: &Path) -> Result<EnvMap> {
        EnvMap::load_with(path, HdrPolicy::default())
    }

    /// Loads an equirectangular map as [`EnvMap::load`], treating negative EXR samples as
    /// `policy` says.
    pub fn load_with(path: &Path, policy: HdrPolicy) -> Result<EnvMap> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "exr" => load_exr(path, policy),
            "hdr" | "pic" => {
                let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
                let (w, h, texels) = decode_rgbe(&bytes).map_err(|m| Error::input(path, m))?;
                EnvMap::from_texels(w, h, texels, path)
            }
            _ => Err(Error::input(
                path,
                format!(
                    "unknown environment-map format '{}' (supported: .exr, .hdr, .pic)",
                    if ext.is_empty() {
                        "no extension".to_string()
                    } else {
                        format!(".{ext}")
                    }
                ),
            )),
        }
    }

    /// A map from texels (row-major, row 0 = top), validated like a loaded file: 2:1,
    /// `width * height` texels, all finite and non-negative.
    pub fn from_texels(
        width: u32,
        height: u32,
        texels: Vec<[f32; 3]>,
        source: impl Into<PathBuf>,
    ) -> Result<EnvMap> {
        let source = source.into();
        if width == 0 || height == 0 || width != 2 * height {
            return Err(Error::input(
                &source,
                format!(
                    "an equirectangular map must be 2:1 (width = 2 x height); this one is \
                     {width} x {height}"
                ),
            ));
        }
        if width > MAX_WIDTH {
            return Err(Error::input(
                &source,
                format!("width {width} exceeds the limit {MAX_WIDTH}"),
            ));
        }
        let want = width as usize * height as usize;
        if texels.len() != want {
            return Err(Error::input(
                &source,
                format!(
                    "{} texels given for a {width} x {height} map ({want})",
                    texels.len()
                ),
            ));
        }
        if let Some(i) = texels.iter().position(|t| {
            t.iter()
                .any(|c| !c.is_finite() || *c < 0.0 || *c > MAX_RADIANCE)
        }) {
            let (x, y) = (i % width as usize, i / width as usize);
            let t = texels[i];
            let what = if !t.iter().all(|c| c.is_finite()) {
                "non-finite"
            } else if t.iter().any(|c| *c > MAX_RADIANCE) {
                return Err(Error::input(
                    &source,
                    format!(
                        "texel ({x}, {y}) is ({}, {}, {}): above {MAX_RADIANCE:e}, the largest \
                         radiance accepted (brighter values overflow the f32 sums that follow; \
                         a real sun is ~1e5 to 1e9)",
                        t[0], t[1], t[2]
                    ),
                ));
            } else {
                "negative"
            };
            return Err(Error::input(
                &source,
                format!(
                    "texel ({x}, {y}) is {what}: ({}, {}, {}); radiance must be finite and >= 0",
                    t[0], t[1], t[2]
                ),
            ));
        }
        Ok(EnvMap {
            width,
            height,
            texels,
            source,
            repair: None,
        })
    }

    /// The texel at column `x`, row `y` (clamped to the map).
    pub fn texel(&self, x: u32, y: u32) -> [f32; 3] {
        let x = x.min(self.width - 1) as usize;
        let y = y.min(self.height - 1) as usize;
        self.texels[y * self.width as usize + x]
    }

    /// Unit direction of the centre of texel (x, y).
    pub fn direction(&self, x: u32, y: u32) -> Vec3 {
        let u = (x as f64 + 0.5) / self.width as f64;
        let v = (y as f64 + 0.5) / self.height as f64;
        direction_of(u, v).as_vec3()
    }

    /// The texel containing direction `dir` (need not be unit length). Directions on a
    /// texel border go to the texel below/right of it; u = 1 (phi = pi) wraps to column 0.
    /// A zero or non-finite direction gives some texel, never a panic.
    pub fn texel_of(&self, dir: Vec3) -> (u32, u32) {
        let d = dir.as_dvec3();
        // atan2 forms stay accurate near the poles (acos does not).
        let theta = d.x.hypot(d.z).atan2(d.y); // in [0, pi]
        let phi = d.x.atan2(-d.z); // in [-pi, pi]
        let u = 0.5 + phi / (2.0 * PI);
        let v = theta / PI;
        let x = ((u * self.width as f64).floor().max(0.0) as u32) % self.width;
        let y = ((v * self.height as f64).floor().max(0.0) as u32).min(self.height - 1);
        (x, y)
    }

    /// Radiance arriving from `dir`: the nearest texel (no filtering).
    pub fn lookup(&self, dir: Vec3) -> [f32; 3] {
        let (x, y) = self.texel_of(dir);
        self.texel(x, y)
    }

    /// Radiance of the environment turned by the rotation `r`: L_R(w) = L(R^-1 w), nearest
    /// texel. `r` must be a rotation (orthonormal, det +1): its transpose is used as R^-1.
    pub fn rotated_lookup(&self, r: Mat3, w: Vec3) -> [f32; 3] {
        self.lookup(r.transpose() * w)
    }

    /// The exact solid angle of every texel in row `y` (all texels of a row are equal):
    /// (2 pi / W) (cos theta_top - cos theta_bottom). Rows outside the map have 0.
    pub fn solid_angle(&self, y: u32) -> f64 {
        if y >= self.height {
            return 0.0;
        }
        let h = self.height as f64;
        let top = PI * y as f64 / h;
        let bottom = PI * (y as f64 + 1.0) / h;
        // cos a - cos b = 2 sin((a + b) / 2) sin((b - a) / 2): no cancellation near the poles.
        2.0 * PI / self.width as f64
            * 2.0
            * ((top + bottom) / 2.0).sin()
            * ((bottom - top) / 2.0).sin()
    }

    /// The map box-filtered down to `width` x `width / 2`: each output texel is the
    /// solid-angle-weighted mean of the f x f block it covers (f = self.width / width), so
    /// the integral of L over the sphere is preserved (output rows cover exactly the input
    /// rows of their block, so their solid angles add up). `width` must be even and divide
    /// `self.width`.
    pub fn downsampled(&self, width: u32) -> Result<EnvMap> {
        if width < 2
            || !width.is_multiple_of(2)
            || width > self.width
            || !self.width.is_multiple_of(width)
        {
            return Err(Error::InvalidArgument(format!(
                "cannot downsample {} ({} x {}) to width {width}: the width must be even and \
                 divide {}",
                self.source.display(),
                self.width,
                self.height,
                self.width
            )));
        }
        let f = (self.width / width) as usize;
        let (w, h) = (width as usize, width as usize / 2);
        let mut out = vec![[0.0f32; 3]; w * h];
        for (oy, row) in out.chunks_mut(w).enumerate() {
            let mut acc = vec![[0.0f64; 3]; w];
            let mut omega = 0.0f64;
            for iy in oy * f..(oy + 1) * f {
                let d = self.solid_angle(iy as u32);
                omega += d * f as f64;
                let src = &self.texels[iy * self.width as usize..(iy + 1) * self.width as usize];
                for (ox, a) in acc.iter_mut().enumerate() {
                    for t in &src[ox * f..(ox + 1) * f] {
                        for c in 0..3 {
                            a[c] += t[c] as f64 * d;
                        }
                    }
                }
            }
            for (o, a) in row.iter_mut().zip(&acc) {
                *o = a.map(|s| (s / omega) as f32);
            }
        }
        EnvMap::from_texels(width, width / 2, out, self.source.clone())
    }

    /// (direction, solid angle, radiance) of every texel, row-major from the top.
    pub fn samples(&self) -> Vec<(Vec3, f64, [f32; 3])> {
        let mut out = Vec::with_capacity(self.texels.len());
        for y in 0..self.height {
            let d = self.solid_angle(y);
            for x in 0..self.width {
                out.push((self.direction(x, y), d, self.texel(x, y)));
            }
        }
        out
    }

    /// The integral of L over the sphere, per channel (f64, exact solid angles).
    pub fn integral(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for (y, row) in self.texels.chunks(self.width as usize).enumerate() {
            let d = self.solid_angle(y as u32);
            let mut r = [0.0f64; 3];
            for t in row {
                for c in 0..3 {
                    r[c] += t[c] as f64;
                }
            }
            for c in 0..3 {
                sum[c] += r[c] * d;
            }
        }
        sum
    }
}

/// Visibility of every texel direction of `dir_env` from every vertex of `mesh` (BVH built
/// here; rays start 1e-4 of the mesh's diagonal along the normal). What the transfer
/// projection and the brute-force ground truth both read.
pub fn texel_visibility(mesh: &super::Mesh, dir_env: &EnvMap) -> Visibility {
    let directions: Vec<Vec3> = dir_env.samples().iter().map(|s| s.0).collect();
    let (lo, hi) = mesh.bounds();
    let bvh = Bvh::build(&mesh.positions, &mesh.triangles);
    direction_visibility(
        &mesh.positions,
        &mesh.normals,
        &bvh,
        &directions,
        1e-4 * (hi - lo).length(),
    )
}

/// Under [`HdrPolicy::Strict`], negative samples of an EXR map down to
/// `-NEGATIVE_TOLERANCE` times the map's mean sample are set to 0 on loading; more negative
/// ones are an error.
pub const NEGATIVE_TOLERANCE: f32 = 0.05;

/// Reads an EXR map. Real maps carry negative samples: the Blender studio lights have 3 to
/// ~9000 per map, down to -3.9e-3 (at most 2.5 % of the map's mean sample), and lossy HDRI
/// collections down to about -2,000 beside a +11,800 sun. They are R, G, B channels under
/// DWAB, whose DCT is lossy, so this is codec ringing (filter ringing from resampling looks
/// the same). [`HdrPolicy::Repair`] removes them keeping each neighbourhood's energy
/// ([`repair_ringing`], reported by a `log` warning and in [`EnvMap::repair`]);
/// [`HdrPolicy::Strict`] sets samples in [-NEGATIVE_TOLERANCE * mean, 0) to 0 and refuses a
/// sample below that like a NaN.
#[cfg(feature = "exr")]
fn load_exr(path: &Path, policy: HdrPolicy) -> Result<EnvMap> {
    let img = crate::io::exr::read_rgba(path)?;
    let mut texels: Vec<[f32; 3]> = img.pixels.iter().map(|p| [p[0], p[1], p[2]]).collect();
    if policy == HdrPolicy::Repair {
        // Shape, finiteness and the radiance bound first: the repair sums energies.
        let shaped = EnvMap::from_texels(
            img.width,
            img.height,
            texels.iter().map(|t| t.map(f32::abs)).collect(),
            path,
        )?;
        let repair = repair_ringing(img.width as usize, img.height as usize, &mut texels, |y| {
            shaped.solid_angle(y as u32)
        })
        .map_err(|m| Error::input(path, m))?;
        // What the repair changed is the map's `repair`, which the commands print.
        let mut map = EnvMap::from_texels(img.width, img.height, texels, path)?;
        map.repair = repair;
        return Ok(map);
    }
    let n = texels.len().max(1) as f64 * 3.0;
    let mean = texels.iter().flatten().map(|&c| c as f64).sum::<f64>() / n;
    let floor = -(NEGATIVE_TOLERANCE as f64 * mean.max(0.0)) as f32;
    let (mut count, mut min) = (0usize, 0.0f32);
    for c in texels.iter_mut().flatten() {
        if *c < 0.0 && *c >= floor {
            count += 1;
            min = min.min(*c);
            *c = 0.0;
        }
    }
    if count > 0 {
        log::warn!(
            "{}: set {count} small negative samples (down to {min:e}, mean sample {mean:e}) to 0",
            path.display()
        );
    }
    EnvMap::from_texels(img.width, img.height, texels, path).map_err(|e| match e {
        Error::Input { path, message } if message.contains("negative") => Error::Input {
            path,
            message: format!(
                "{message} (below -{NEGATIVE_TOLERANCE} x the mean sample {mean:e}, too \
                 negative to be filter ringing; --hdr-strict refuses it, the default policy \
                 repairs codec ringing)"
            ),
        },
        e => e,
    })
}

#[cfg(not(feature = "exr"))]
fn load_exr(path: &Path, _policy: HdrPolicy) -> Result<EnvMap> {
    Err(Error::feature(
        format!("loading the OpenEXR environment map {}", path.display()),
        "exr",
    ))
}

/// One RGBE pixel as linear RGB: mantissa * 2^(e - 136) (as Greg Ward's rgbe.c, stb_image
/// and the `image` crate; Radiance's own reader adds 0.5 to the mantissa).
fn rgbe_to_rgb(p: [u8; 4]) -> [f32; 3] {
    if p[3] == 0 {
        return [0.0; 3];
    }
    let f = 2f32.powi(p[3] as i32 - 136);
    [p[0] as f32 * f, p[1] as f32 * f, p[2] as f32 * f]
}

/// Decodes a Radiance RGBE picture: header, `-Y H +X W` (or `+Y H +X W`, stored bottom-up)
/// resolution line, then flat, old-style run-length or new-style run-length scanlines.
/// `EXPOSURE=` lines are ignored (as most readers do). Errors are messages for
/// [`Error::input`].
fn decode_rgbe(bytes: &[u8]) -> std::result::Result<(u32, u32, Vec<[f32; 3]>), String> {
    if !bytes.starts_with(b"#?") {
        return Err("not a Radiance .hdr file (no '#?' signature at its start)".into());
    }
    let mut pos = 0usize;
    let line = |pos: &mut usize| -> std::result::Result<String, String> {
        let rest = &bytes[*pos..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or("truncated header (a line without its newline)")?;
        if end > 4096 {
            return Err("header line longer than 4096 bytes".into());
        }
        *pos += end + 1;
        Ok(String::from_utf8_lossy(&rest[..end]).trim_end().to_string())
    };
    line(&mut pos)?; // signature
    loop {
        let l = line(&mut pos)?;
        if l.is_empty() {
            break;
        }
        if let Some(fmt) = l.strip_prefix("FORMAT=")
            && fmt.trim() != "32-bit_rle_rgbe"
        {
            return Err(format!(
                "unsupported pixel format '{}' (only 32-bit_rle_rgbe)",
                fmt.trim()
            ));
        }
    }
    let res = line(&mut pos)?;
    let parts: Vec<&str> = res.split_whitespace().collect();
    let (flip, h, w) = match parts.as_slice() {
        [ya, h, "+X", w] if *ya == "-Y" || *ya == "+Y" => {
            let parse = |s: &str| {
                s.parse::<u32>()
                    .map_err(|_| format!("bad resolution line '{res}'"))
            };
            (*ya == "+Y", parse(h)?, parse(w)?)
        }
        _ => {
            return Err(format!(
                "unsupported resolution line '{res}' (expected '-Y <height> +X <width>')"
            ));
        }
    };
    if w == 0 || h == 0 || w > MAX_WIDTH || h > MAX_WIDTH {
        return Err(format!("image size {w} x {h} outside 1..={MAX_WIDTH}"));
    }
    let (wu, hu) = (w as usize, h as usize);
    // Grow as scanlines decode, so a lying header cannot make us allocate its claimed size.
    let mut pixels: Vec<[f32; 3]> = Vec::with_capacity(wu.min(1 << 12) * hu.min(1 << 12));
    let mut scan = vec![[0u8; 4]; wu];
    let mut data = &bytes[pos..];
    for row in 0..hu {
        let truncated = || format!("truncated pixel data (scanline {row} of {h})");
        let new_rle = (8..=0x7fff).contains(&w)
            && data.len() >= 4
            && data[0] == 2
            && data[1] == 2
            && data[2] & 0x80 == 0;
        if new_rle {
            let len = ((data[2] as usize) << 8) | data[3] as usize;
            if len != wu {
                return Err(format!(
                    "scanline {row}: run-length scanline of width {len}, image width {w}"
                ));
            }
            data = &data[4..];
            for c in 0..4 {
                let mut x = 0;
                while x < wu {
                    let (&count, rest) = data.split_first().ok_or_else(truncated)?;
                    data = rest;
                    if count > 128 {
                        let n = count as usize - 128;
                        let (&v, rest) = data.split_first().ok_or_else(truncated)?;
                        data = rest;
                        if x + n > wu {
                            return Err(format!("scanline {row}: run overruns the scanline"));
                        }
                        scan[x..x + n].iter_mut().for_each(|p| p[c] = v);
                        x += n;
                    } else {
                        let n = count as usize;
                        if n == 0 || x + n > wu {
                            return Err(format!("scanline {row}: bad literal run of {n}"));
                        }
                        if data.len() < n {
                            return Err(truncated());
                        }
                        for (p, &v) in scan[x..x + n].iter_mut().zip(&data[..n]) {
                            p[c] = v;
                        }
                        data = &data[n..];
                        x += n;
                    }
                }
            }
        } else {
            // Flat pixels; (1, 1, 1, n) repeats the previous pixel (old-style run length,
            // consecutive runs shift the count by 8 bits each).
            let mut x = 0;
            let mut shift = 0u32;
            while x < wu {
                if data.len() < 4 {
                    return Err(truncated());
                }
                let p = [data[0], data[1], data[2], data[3]];
                data = &data[4..];
                if p[0] == 1 && p[1] == 1 && p[2] == 1 {
                    if x == 0 || shift > 16 {
                        return Err(format!("scanline {row}: bad old-style run"));
                    }
                    let n = (p[3] as usize) << shift;
                    if x + n > wu {
                        return Err(format!("scanline {row}: run overruns the scanline"));
                    }
                    let prev = scan[x - 1];
                    scan[x..x + n].iter_mut().for_each(|q| *q = prev);
                    x += n;
                    shift += 8;
                } else {
                    scan[x] = p;
                    x += 1;
                    shift = 0;
                }
            }
        }
        pixels.extend(scan.iter().map(|&p| rgbe_to_rgb(p)));
    }
    if flip {
        let rows: Vec<&[[f32; 3]]> = pixels.chunks(wu).rev().collect();
        pixels = rows.concat();
    }
    Ok((w, h, pixels))
}
