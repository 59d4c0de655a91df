//! The SRBF transfer cache files that `vkshade srbf shade` keeps beside its outputs: the
//! projected transfer (`transfer.bin`, and `glossy.bin` for a glossy BRDF), its clustered-PCA
//! form (`transfer.cpca`) and the glossy transfer's clustered tensor approximation
//! (`glossy.cta`), and the mesh's visibility toward the direction map's texels
//! (`visibility.bin`), which all of them and the ground truth are computed from.
//!
//! All are little endian: an 8-byte magic, a version (u32), a fixed header, the arrays as
//! 32-bit words (the visibility's rows as 64-bit words), then an FNV-1a 64 checksum of
//! everything before it. Writes are atomic; a read checks the magic, version, size and
//! checksum, and every error names the file. What the values mean (unit axes, cluster ids in
//! range, finite numbers) is checked by the types that own them
//! (`kernels::srbf::transfer::Transfer`, `kernels::srbf::cpca::Cpca`, `kernels::srbf::cta::Cta`).

use crate::error::{Error, Result};
use glam::Vec3;
use std::borrow::Cow;
use std::path::Path;

/// A projected transfer as `transfer.bin` holds it: magic "VKSGTRF\0", version u32, K u32,
/// sharpness f32, vertices u64, projection_rel_l2 f64, K axes (3 f32 each), vertices x K
/// coefficients f32, checksum.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFile<'a> {
    /// The K axes of the SG basis.
    pub axes: Cow<'a, [Vec3]>,
    /// The basis's one sharpness.
    pub sharpness: f32,
    pub vertices: usize,
    /// Vertex-major, K per vertex.
    pub coeffs: Cow<'a, [f32]>,
    pub projection_rel_l2: f64,
}

/// A clustered-PCA transfer as `transfer.cpca` holds it: magic "VKSGCPC\0", version u32,
/// K u32, M u32, clusters u32, sharpness f32, vertices u64, rel_l2 f64, K axes (3 f32 each),
/// a u32 cluster per vertex, clusters x (M + 1) x K rows and vertices x M weights (f32),
/// checksum.
#[derive(Clone, Debug, PartialEq)]
pub struct CpcaFile<'a> {
    /// The K axes of the SG basis.
    pub axes: Cow<'a, [Vec3]>,
    /// The basis's one sharpness.
    pub sharpness: f32,
    pub vertices: usize,
    /// M: weights per vertex.
    pub components: usize,
    pub clusters: usize,
    pub cluster_of: Cow<'a, [u32]>,
    pub rows: Cow<'a, [f32]>,
    pub weights: Cow<'a, [f32]>,
    pub rel_l2: f64,
}

/// A clustered tensor approximation as `glossy.cta` holds it: magic "VKSGCTA\0", version
/// u32, K u32, views V u32, clusters C u32, ranks r_v, r_w, r_l u32, sharpness f32, history
/// length H u32, vertices n u64, rel_l2 f64, K axes (3 f32 each), a u32 cluster per vertex,
/// C x V x r_w view factors, C x K x r_l light factors, C x r_v x r_w x r_l cores, n x r_v
/// coefficients (f32), H history values (f64), checksum.
#[derive(Clone, Debug, PartialEq)]
pub struct CtaFile<'a> {
    pub axes: Cow<'a, [Vec3]>,
    pub sharpness: f32,
    pub vertices: usize,
    pub views: usize,
    pub clusters: usize,
    pub ranks: [usize; 3],
    pub cluster_of: Cow<'a, [u32]>,
    pub view_factors: Cow<'a, [f32]>,
    pub light_factors: Cow<'a, [f32]>,
    pub cores: Cow<'a, [f32]>,
    pub coeffs: Cow<'a, [f32]>,
    pub rel_l2: f64,
    pub history: Cow<'a, [f64]>,
}

/// A mesh's visibility toward D directions as `visibility.bin` holds it: magic
/// "VKSGVIS\0", version u32, D u32, vertices u64, D directions (3 f32 each), then per vertex
/// ceil(D / 64) u64 words of bits (direction d is bit d % 64 of word d / 64; the bits past D
/// are 0), checksum.
#[derive(Clone, Debug, PartialEq)]
pub struct VisibilityFile<'a> {
    pub directions: Cow<'a, [Vec3]>,
    pub vertices: usize,
    /// Vertex-major, ceil(D / 64) words per vertex.
    pub bits: Cow<'a, [u64]>,
}

const CTA_MAGIC: &[u8; 8] = b"VKSGCTA\0";
const CTA_VERSION: u32 = 1;
/// magic, version, K, V, C, r_v, r_w, r_l, sharpness, H, vertices (u64), rel_l2 (f64).
const CTA_HEADER: usize = 8 + 4 * 9 + 8 + 8;

const TRANSFER_MAGIC: &[u8; 8] = b"VKSGTRF\0";
const TRANSFER_VERSION: u32 = 1;
/// magic, version, K, sharpness, vertices (u64), projection_rel_l2 (f64).
const TRANSFER_HEADER: usize = 8 + 4 + 4 + 4 + 8 + 8;

const VISIBILITY_MAGIC: &[u8; 8] = b"VKSGVIS\0";
const VISIBILITY_VERSION: u32 = 1;
/// magic, version, D, vertices (u64).
const VISIBILITY_HEADER: usize = 8 + 4 + 4 + 8;

const CPCA_MAGIC: &[u8; 8] = b"VKSGCPC\0";
const CPCA_VERSION: u32 = 1;
/// magic, version, K, M, clusters, sharpness, vertices (u64), rel_l2 (f64).
pub(crate) const CPCA_HEADER: usize = 8 + 4 * 5 + 8 + 8;

/// Largest magnitude a cached value (axis component, sharpness, coefficient, CPCA row or
/// weight) may have; a file holding a larger one, or a NaN or infinity, is refused even
/// with a valid checksum, and the writers refuse to store one.
///
/// Why 1e6: the cached values are a clamped cosine (at most 1/pi) times visibility,
/// projected onto unit-peak SG lobes and compressed by PCA, so their magnitude is O(1) to
/// O(100) for any basis the fit solves (the Gram matrix's condition limits the rest). The
/// shading sums K of them times the light's coefficients: with |x| <= 1e6, radiance at most
/// [`crate::scene::envmap::MAX_RADIANCE`] = 1e12 over 4 pi steradians and K <= 65536 terms,
/// the sum stays below 1e6 x 1e12 x 4 pi x 65536 ~ 8e23, far from f32's 3.4e38; a forged
/// 3e38 would overflow the first product.
pub const MAX_MAGNITUDE: f32 = 1e6;

/// The first value of `values` (named `what`) that is not finite or exceeds
/// [`MAX_MAGNITUDE`], as a message naming its index.
fn out_of_bounds(what: &str, values: impl IntoIterator<Item = f32>) -> Option<String> {
    values
        .into_iter()
        .enumerate()
        .find(|(_, x)| !(x.is_finite() && x.abs() <= MAX_MAGNITUDE))
        .map(|(i, x)| {
            format!("{what} {i} is {x:e}: cached values must be finite with magnitude <= {MAX_MAGNITUDE:e}")
        })
}

/// FNV-1a, 64 bit: the files' trailing checksum.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ *b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// `n` as a u32 header field; an error naming `path` if it does not fit.
fn header_u32(path: &Path, n: usize, what: &str) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::input(path, format!("{n} {what} do not fit the file")))
}

/// Appends the checksum of `b` and writes it to `path` atomically.
fn seal_and_write(path: &Path, mut b: Vec<u8>) -> Result<()> {
    let sum = fnv1a(&b);
    b.extend_from_slice(&sum.to_le_bytes());
    super::write_atomic(path, &b)
}

/// A file read whole, its magic and version checked; the size and checksum are checked by
/// [`Sealed::check_size`] once the header says what the size must be.
struct Sealed<'p> {
    path: &'p Path,
    /// What the file holds, for messages ("SG transfer").
    what: &'static str,
    bytes: Vec<u8>,
}

impl<'p> Sealed<'p> {
    fn open(
        path: &'p Path,
        what: &'static str,
        magic: &[u8; 8],
        version: u32,
        header: usize,
    ) -> Result<Sealed<'p>> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let file = Sealed { path, what, bytes };
        if file.bytes.len() < header + 8 || &file.bytes[..8] != magic {
            return Err(file.bad(format!(
                "not a vkshade {what} file (bad magic or too short)"
            )));
        }
        let found = file.u32_at(8);
        if found != version {
            return Err(file.bad(format!("version {found}, this build reads {version}")));
        }
        Ok(file)
    }

    fn bad(&self, m: String) -> Error {
        Error::input(self.path, format!("{} file: {m}", self.what))
    }

    fn u32_at(&self, o: usize) -> u32 {
        u32::from_le_bytes(self.bytes[o..o + 4].try_into().unwrap_or([0; 4]))
    }

    fn u64_at(&self, o: usize) -> u64 {
        u64::from_le_bytes(self.bytes[o..o + 8].try_into().unwrap_or([0; 8]))
    }

    /// Checks that the file is `expected` bytes long (else the error says `needs`, which
    /// names the header's counts) and that its checksum matches.
    fn check_size(&self, expected: u128, needs: impl FnOnce() -> String) -> Result<()> {
        if expected != self.bytes.len() as u128 {
            return Err(self.bad(format!(
                "{} bytes, but {} need {expected}",
                self.bytes.len(),
                needs()
            )));
        }
        let body = self.bytes.len() - 8;
        if fnv1a(&self.bytes[..body]) != self.u64_at(body) {
            return Err(self.bad("checksum mismatch (the file is corrupted)".into()));
        }
        Ok(())
    }

    /// `count` words from byte `from`.
    fn words(&self, from: usize, count: usize) -> Vec<u32> {
        (0..count).map(|i| self.u32_at(from + 4 * i)).collect()
    }

    fn floats(&self, from: usize, count: usize) -> Vec<f32> {
        self.bytes[from..from + 4 * count]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    }

    fn axes(&self, from: usize, k: usize) -> Vec<Vec3> {
        self.floats(from, 3 * k)
            .chunks_exact(3)
            .map(|a| Vec3::new(a[0], a[1], a[2]))
            .collect()
    }
}

impl TransferFile<'_> {
    /// Writes the file (see the type), atomically: readers see the old file or the whole
    /// new one. An error if the coefficients are not `vertices` x K.
    pub fn save(&self, path: &Path) -> Result<()> {
        let k = self.axes.len();
        if self.coeffs.len() != self.vertices.saturating_mul(k) {
            return Err(Error::input(
                path,
                format!(
                    "transfer to save has {} coefficients for {} vertices x {k}",
                    self.coeffs.len(),
                    self.vertices
                ),
            ));
        }
        if let Some(m) = self.bad_value() {
            return Err(Error::input(path, format!("not written: SG transfer: {m}")));
        }
        let k32 = header_u32(path, k, "basis functions")?;
        let mut b = Vec::with_capacity(TRANSFER_HEADER + 12 * k + 4 * self.coeffs.len() + 8);
        b.extend_from_slice(TRANSFER_MAGIC);
        b.extend_from_slice(&TRANSFER_VERSION.to_le_bytes());
        b.extend_from_slice(&k32.to_le_bytes());
        b.extend_from_slice(&self.sharpness.to_le_bytes());
        b.extend_from_slice(&(self.vertices as u64).to_le_bytes());
        b.extend_from_slice(&self.projection_rel_l2.to_le_bytes());
        for a in self.axes.iter() {
            for c in a.to_array() {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        for c in self.coeffs.iter() {
            b.extend_from_slice(&c.to_le_bytes());
        }
        seal_and_write(path, b)
    }

    /// The first value out of [`MAX_MAGNITUDE`] (or non-finite), named.
    fn bad_value(&self) -> Option<String> {
        out_of_bounds(
            "axis component",
            self.axes.iter().flat_map(|a| a.to_array()),
        )
        .or_else(|| out_of_bounds("sharpness", [self.sharpness]))
        .or_else(|| out_of_bounds("coefficient", self.coeffs.iter().copied()))
        .or_else(|| {
            (!self.projection_rel_l2.is_finite())
                .then(|| format!("projection error {}", self.projection_rel_l2))
        })
    }
}

impl TransferFile<'static> {
    /// Reads a file written by [`TransferFile::save`], checking magic, version, size and
    /// checksum; every error names the file.
    pub fn load(path: &Path) -> Result<TransferFile<'static>> {
        let file = Sealed::open(
            path,
            "SG transfer",
            TRANSFER_MAGIC,
            TRANSFER_VERSION,
            TRANSFER_HEADER,
        )?;
        let k = file.u32_at(12) as usize;
        let sharpness = f32::from_bits(file.u32_at(16));
        let vertices = file.u64_at(20);
        let projection_rel_l2 = f64::from_bits(file.u64_at(28));
        let expected =
            (vertices as u128) * (k as u128) * 4 + (k as u128) * 12 + TRANSFER_HEADER as u128 + 8;
        file.check_size(expected, || format!("K = {k} and {vertices} vertices"))?;
        let vertices = vertices as usize;
        let t = TransferFile {
            axes: file.axes(TRANSFER_HEADER, k).into(),
            sharpness,
            vertices,
            coeffs: file.floats(TRANSFER_HEADER + 12 * k, vertices * k).into(),
            projection_rel_l2,
        };
        match t.bad_value() {
            Some(m) => Err(file.bad(m)),
            None => Ok(t),
        }
    }
}

impl VisibilityFile<'_> {
    /// Writes the file (see the type), atomically. An error if the bits are not
    /// `vertices` x ceil(D / 64) words, a bit past D is set, or a direction is not finite.
    pub fn save(&self, path: &Path) -> Result<()> {
        let words = self.directions.len().div_ceil(64);
        if self.bits.len() != self.vertices.saturating_mul(words) {
            return Err(Error::input(
                path,
                format!(
                    "visibility to save has {} words for {} vertices x {words}",
                    self.bits.len(),
                    self.vertices
                ),
            ));
        }
        if let Some(m) = self.bad_value() {
            return Err(Error::input(path, format!("not written: visibility: {m}")));
        }
        let d32 = header_u32(path, self.directions.len(), "directions")?;
        let mut b = Vec::with_capacity(
            VISIBILITY_HEADER + 12 * self.directions.len() + 8 * self.bits.len() + 8,
        );
        b.extend_from_slice(VISIBILITY_MAGIC);
        b.extend_from_slice(&VISIBILITY_VERSION.to_le_bytes());
        b.extend_from_slice(&d32.to_le_bytes());
        b.extend_from_slice(&(self.vertices as u64).to_le_bytes());
        for a in self.directions.iter() {
            for c in a.to_array() {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        for w in self.bits.iter() {
            b.extend_from_slice(&w.to_le_bytes());
        }
        seal_and_write(path, b)
    }

    /// A direction component that is not finite or beyond 1 in magnitude, or a bit set past
    /// the last direction, named.
    fn bad_value(&self) -> Option<String> {
        let d = self.directions.len();
        if let Some((i, x)) = self
            .directions
            .iter()
            .flat_map(|a| a.to_array())
            .enumerate()
            .find(|(_, x)| !(x.is_finite() && x.abs() <= 1.0))
        {
            return Some(format!("direction component {i} is {x:e}"));
        }
        if d.is_multiple_of(64) {
            return None;
        }
        let words = d.div_ceil(64);
        let spare = !0u64 << (d % 64);
        self.bits
            .chunks_exact(words)
            .position(|row| row[words - 1] & spare != 0)
            .map(|v| format!("vertex {v} has a bit set past direction {d}"))
    }
}

impl VisibilityFile<'static> {
    /// Reads a file written by [`VisibilityFile::save`], checking magic, version, size,
    /// checksum and values; every error names the file.
    pub fn load(path: &Path) -> Result<VisibilityFile<'static>> {
        let file = Sealed::open(
            path,
            "visibility",
            VISIBILITY_MAGIC,
            VISIBILITY_VERSION,
            VISIBILITY_HEADER,
        )?;
        let d = file.u32_at(12) as usize;
        let vertices = file.u64_at(16);
        let words = d.div_ceil(64) as u128;
        let expected =
            (vertices as u128) * words * 8 + (d as u128) * 12 + VISIBILITY_HEADER as u128 + 8;
        file.check_size(expected, || {
            format!("{d} directions and {vertices} vertices")
        })?;
        let vertices = vertices as usize;
        let from = VISIBILITY_HEADER + 12 * d;
        let v = VisibilityFile {
            directions: file.axes(VISIBILITY_HEADER, d).into(),
            vertices,
            bits: (0..vertices * words as usize)
                .map(|i| file.u64_at(from + 8 * i))
                .collect::<Vec<u64>>()
                .into(),
        };
        match v.bad_value() {
            Some(m) => Err(file.bad(m)),
            None => Ok(v),
        }
    }
}

impl CpcaFile<'_> {
    /// Writes the file (see the type), atomically. An error if the arrays' lengths do not
    /// match the counts.
    pub fn save(&self, path: &Path) -> Result<()> {
        let (k, m) = (self.axes.len(), self.components);
        let rows = self
            .clusters
            .checked_mul(m + 1)
            .and_then(|r| r.checked_mul(k));
        if rows != Some(self.rows.len())
            || Some(self.weights.len()) != self.vertices.checked_mul(m)
            || self.cluster_of.len() != self.vertices
        {
            return Err(Error::input(
                path,
                format!(
                    "CPCA transfer to save has {} rows, {} weights and {} cluster ids for {} \
                     vertices x {} clusters x {m} components x {k}",
                    self.rows.len(),
                    self.weights.len(),
                    self.cluster_of.len(),
                    self.vertices,
                    self.clusters
                ),
            ));
        }
        if let Some(m) = self.bad_value() {
            return Err(Error::input(
                path,
                format!("not written: CPCA transfer: {m}"),
            ));
        }
        let header = [
            CPCA_VERSION,
            header_u32(path, k, "basis functions")?,
            header_u32(path, m, "components")?,
            header_u32(path, self.clusters, "clusters")?,
            self.sharpness.to_bits(),
        ];
        let words = 3 * k + self.vertices + self.rows.len() + self.weights.len();
        let mut b = Vec::with_capacity(CPCA_HEADER + 4 * words + 8);
        b.extend_from_slice(CPCA_MAGIC);
        for x in header {
            b.extend_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(&(self.vertices as u64).to_le_bytes());
        b.extend_from_slice(&self.rel_l2.to_le_bytes());
        let floats = self.axes.iter().flat_map(|a| a.to_array());
        let words = floats
            .map(f32::to_bits)
            .chain(self.cluster_of.iter().copied())
            .chain(self.rows.iter().map(|x| x.to_bits()))
            .chain(self.weights.iter().map(|x| x.to_bits()));
        for w in words {
            b.extend_from_slice(&w.to_le_bytes());
        }
        seal_and_write(path, b)
    }

    /// The first value out of [`MAX_MAGNITUDE`] (or non-finite), named.
    fn bad_value(&self) -> Option<String> {
        out_of_bounds(
            "axis component",
            self.axes.iter().flat_map(|a| a.to_array()),
        )
        .or_else(|| out_of_bounds("sharpness", [self.sharpness]))
        .or_else(|| out_of_bounds("row value", self.rows.iter().copied()))
        .or_else(|| out_of_bounds("weight", self.weights.iter().copied()))
        .or_else(|| (!self.rel_l2.is_finite()).then(|| format!("error {}", self.rel_l2)))
    }
}

impl CpcaFile<'static> {
    /// Reads a file written by [`CpcaFile::save`], checking magic, version, size and
    /// checksum; every error names the file.
    pub fn load(path: &Path) -> Result<CpcaFile<'static>> {
        let file = Sealed::open(path, "CPCA transfer", CPCA_MAGIC, CPCA_VERSION, CPCA_HEADER)?;
        let (k, m, clusters) = (
            file.u32_at(12) as u128,
            file.u32_at(16) as u128,
            file.u32_at(20) as u128,
        );
        let sharpness = f32::from_bits(file.u32_at(24));
        let vertices = file.u64_at(28) as u128;
        let rel_l2 = f64::from_bits(file.u64_at(36));
        let words = 3 * k + vertices + clusters * (m + 1) * k + vertices * m;
        let expected = CPCA_HEADER as u128 + 4 * words + 8;
        file.check_size(expected, || {
            format!("K = {k}, M = {m}, {clusters} clusters and {vertices} vertices")
        })?;
        let (k, m, clusters, vertices) =
            (k as usize, m as usize, clusters as usize, vertices as usize);
        let mut at = CPCA_HEADER;
        let mut take = |count: usize| {
            let from = at;
            at += 4 * count;
            from
        };
        let axes = file.axes(take(3 * k), k);
        let cluster_of = file.words(take(vertices), vertices);
        let rows = file.floats(take(clusters * (m + 1) * k), clusters * (m + 1) * k);
        let weights = file.floats(take(vertices * m), vertices * m);
        let c = CpcaFile {
            axes: axes.into(),
            sharpness,
            vertices,
            components: m,
            clusters,
            cluster_of: cluster_of.into(),
            rows: rows.into(),
            weights: weights.into(),
            rel_l2,
        };
        match c.bad_value() {
            Some(m) => Err(file.bad(m)),
            None => Ok(c),
        }
    }
}

impl CtaFile<'_> {
    /// The array lengths the counts call for: (view factors, light factors, cores,
    /// coefficients), None on overflow.
    fn lengths(k: u128, v: u128, c: u128, n: u128, r: [u128; 3]) -> Option<[u128; 4]> {
        let [rv, rw, rl] = r;
        Some([
            c.checked_mul(v)?.checked_mul(rw)?,
            c.checked_mul(k)?.checked_mul(rl)?,
            c.checked_mul(rv)?.checked_mul(rw)?.checked_mul(rl)?,
            n.checked_mul(rv)?,
        ])
    }

    /// Writes the file (see the type), atomically. An error if the arrays' lengths do not
    /// match the counts or a value is out of bounds.
    pub fn save(&self, path: &Path) -> Result<()> {
        let k = self.axes.len();
        let r = self.ranks.map(|x| x as u128);
        let want = Self::lengths(
            k as u128,
            self.views as u128,
            self.clusters as u128,
            self.vertices as u128,
            r,
        );
        let have = [
            self.view_factors.len(),
            self.light_factors.len(),
            self.cores.len(),
            self.coeffs.len(),
        ]
        .map(|x| x as u128);
        if want != Some(have) || self.cluster_of.len() != self.vertices {
            return Err(Error::input(
                path,
                format!(
                    "CTA transfer to save has arrays of {have:?} values and {} cluster ids for \
                     {} vertices, {} views, {} clusters, K = {k} and ranks {:?}",
                    self.cluster_of.len(),
                    self.vertices,
                    self.views,
                    self.clusters,
                    self.ranks
                ),
            ));
        }
        if let Some(m) = self.bad_value() {
            return Err(Error::input(
                path,
                format!("not written: CTA transfer: {m}"),
            ));
        }
        let header = [
            CTA_VERSION,
            header_u32(path, k, "basis functions")?,
            header_u32(path, self.views, "views")?,
            header_u32(path, self.clusters, "clusters")?,
            header_u32(path, self.ranks[0], "vertex ranks")?,
            header_u32(path, self.ranks[1], "view ranks")?,
            header_u32(path, self.ranks[2], "light ranks")?,
            self.sharpness.to_bits(),
            header_u32(path, self.history.len(), "history values")?,
        ];
        let mut b = Vec::new();
        b.extend_from_slice(CTA_MAGIC);
        for x in header {
            b.extend_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(&(self.vertices as u64).to_le_bytes());
        b.extend_from_slice(&self.rel_l2.to_le_bytes());
        let words = self
            .axes
            .iter()
            .flat_map(|a| a.to_array())
            .map(f32::to_bits)
            .chain(self.cluster_of.iter().copied())
            .chain(
                [
                    &self.view_factors,
                    &self.light_factors,
                    &self.cores,
                    &self.coeffs,
                ]
                .into_iter()
                .flat_map(|a| a.iter().map(|x| x.to_bits())),
            );
        for w in words {
            b.extend_from_slice(&w.to_le_bytes());
        }
        for h in self.history.iter() {
            b.extend_from_slice(&h.to_le_bytes());
        }
        seal_and_write(path, b)
    }

    /// The first value out of [`MAX_MAGNITUDE`] (or non-finite), named.
    fn bad_value(&self) -> Option<String> {
        out_of_bounds(
            "axis component",
            self.axes.iter().flat_map(|a| a.to_array()),
        )
        .or_else(|| out_of_bounds("sharpness", [self.sharpness]))
        .or_else(|| out_of_bounds("view factor", self.view_factors.iter().copied()))
        .or_else(|| out_of_bounds("light factor", self.light_factors.iter().copied()))
        .or_else(|| out_of_bounds("core value", self.cores.iter().copied()))
        .or_else(|| out_of_bounds("coefficient", self.coeffs.iter().copied()))
        .or_else(|| (!self.rel_l2.is_finite()).then(|| format!("error {}", self.rel_l2)))
        .or_else(|| {
            self.history
                .iter()
                .position(|h| !h.is_finite())
                .map(|i| format!("history value {i} is {}", self.history[i]))
        })
    }
}

impl CtaFile<'static> {
    /// Reads a file written by [`CtaFile::save`], checking magic, version, size and
    /// checksum; every error names the file.
    pub fn load(path: &Path) -> Result<CtaFile<'static>> {
        let file = Sealed::open(path, "CTA transfer", CTA_MAGIC, CTA_VERSION, CTA_HEADER)?;
        let field = |i: usize| file.u32_at(12 + 4 * i) as u128;
        let (k, v, c) = (field(0), field(1), field(2));
        let r = [field(3), field(4), field(5)];
        let sharpness = f32::from_bits(file.u32_at(12 + 4 * 6));
        let h = field(7);
        let n = file.u64_at(12 + 4 * 8) as u128;
        let rel_l2 = f64::from_bits(file.u64_at(12 + 4 * 8 + 8));
        let needs = || {
            format!(
                "K = {k}, {v} views, {c} clusters, ranks {r:?}, {h} history values and {n} \
                 vertices"
            )
        };
        let overflow = || file.bad(format!("{} overflow the file's size", needs()));
        let lengths = Self::lengths(k, v, c, n, r).ok_or_else(overflow)?;
        let expected = lengths
            .iter()
            .try_fold(3 * k + n, |sum, x| sum.checked_add(*x))
            .and_then(|words| words.checked_mul(4))
            .and_then(|bytes| bytes.checked_add(8 * h + CTA_HEADER as u128 + 8))
            .ok_or_else(overflow)?;
        file.check_size(expected, needs)?;
        let [lv, ll, lc, lu] = lengths.map(|x| x as usize);
        let (k, n, h) = (k as usize, n as usize, h as usize);
        let mut at = CTA_HEADER;
        let mut take = |count: usize| {
            let from = at;
            at += 4 * count;
            from
        };
        let axes = file.axes(take(3 * k), k);
        let cluster_of = file.words(take(n), n);
        let view_factors = file.floats(take(lv), lv);
        let light_factors = file.floats(take(ll), ll);
        let cores = file.floats(take(lc), lc);
        let coeffs = file.floats(take(lu), lu);
        let from = take(2 * h);
        let history: Vec<f64> = (0..h)
            .map(|i| f64::from_bits(file.u64_at(from + 8 * i)))
            .collect();
        let t = CtaFile {
            axes: axes.into(),
            sharpness,
            vertices: n,
            views: v as usize,
            clusters: c as usize,
            ranks: r.map(|x| x as usize),
            cluster_of: cluster_of.into(),
            view_factors: view_factors.into(),
            light_factors: light_factors.into(),
            cores: cores.into(),
            coeffs: coeffs.into(),
            rel_l2,
            history: history.into(),
        };
        match t.bad_value() {
            Some(m) => Err(file.bad(m)),
            None => Ok(t),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `name` in a folder of its own (the tests run in parallel and each removes its folder).
    fn temp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir()
            .join(format!(
                "vkshade-transfer-cache-{}-{name}",
                std::process::id()
            ))
            .join(name)
    }

    #[test]
    fn fnv1a_known_answers() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x8594_4171_f739_67e8);
    }

    fn le(words: &[u32]) -> Vec<u8> {
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }

    /// The bytes of a small transfer, assembled field by field from the documented layout
    /// (what every cache written so far holds) with its checksum: the writer produces them
    /// and the reader takes them back.
    #[test]
    fn transfer_file_layout() {
        let file = TransferFile {
            axes: vec![Vec3::Y, Vec3::new(0.6, 0.0, -0.8)].into(),
            sharpness: 1.5,
            vertices: 3,
            coeffs: vec![1.0, -2.0, 0.25, 3.5, 0.0, -0.125].into(),
            projection_rel_l2: 0.0625,
        };
        let mut want = b"VKSGTRF\0".to_vec();
        want.extend(le(&[1, 2, 1.5f32.to_bits()]));
        want.extend(3u64.to_le_bytes());
        want.extend(0.0625f64.to_le_bytes());
        let floats = [
            0.0f32, 1.0, 0.0, 0.6, 0.0, -0.8, 1.0, -2.0, 0.25, 3.5, 0.0, -0.125,
        ];
        want.extend(le(&floats.map(f32::to_bits)));
        // FNV-1a 64 of the bytes above (computed independently).
        want.extend(0x041d_b115_458f_e975u64.to_le_bytes());
        let path = temp("t.bin");
        file.save(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), want);
        assert_eq!(TransferFile::load(&path).unwrap(), file);
        // Coefficients that are not vertices x K are refused.
        let short = TransferFile {
            vertices: 4,
            ..file.clone()
        };
        assert!(short.save(&path).is_err());
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    #[test]
    fn cpca_file_layout() {
        // K = 2, M = 1, 1 cluster, 2 vertices.
        let file = CpcaFile {
            axes: vec![Vec3::X, Vec3::Z].into(),
            sharpness: 0.75,
            vertices: 2,
            components: 1,
            clusters: 1,
            cluster_of: vec![0, 0].into(),
            rows: vec![0.5, -0.5, 1.0, 2.0].into(),
            weights: vec![3.0, -4.0].into(),
            rel_l2: 0.01,
        };
        let mut want = b"VKSGCPC\0".to_vec();
        want.extend(le(&[1, 2, 1, 1, 0.75f32.to_bits()]));
        want.extend(2u64.to_le_bytes());
        want.extend(0.01f64.to_le_bytes());
        let axes = [1.0f32, 0.0, 0.0, 0.0, 0.0, 1.0];
        want.extend(le(&axes.map(f32::to_bits)));
        want.extend(le(&[0, 0]));
        let floats = [0.5f32, -0.5, 1.0, 2.0, 3.0, -4.0];
        want.extend(le(&floats.map(f32::to_bits)));
        want.extend(0x9f24_43b9_9567_a623u64.to_le_bytes());
        assert_eq!(want.len(), CPCA_HEADER + 4 * (6 + 2 + 4 + 2) + 8);
        let path = temp("t.cpca");
        file.save(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), want);
        assert_eq!(CpcaFile::load(&path).unwrap(), file);
        let wrong = CpcaFile {
            components: 2,
            ..file.clone()
        };
        assert!(wrong.save(&path).is_err());
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// The bytes of a small visibility (3 directions, 2 vertices), from the documented
    /// layout: written and read back; a bit past the last direction, or a row of the wrong
    /// length, is refused by the writer, and by the reader under a valid checksum.
    #[test]
    fn visibility_file_layout_and_refusals() {
        let file = VisibilityFile {
            directions: vec![Vec3::X, Vec3::Y, Vec3::new(0.0, -0.6, 0.8)].into(),
            vertices: 2,
            bits: vec![0b101, 0b010].into(),
        };
        let mut want = b"VKSGVIS\0".to_vec();
        want.extend(le(&[1, 3]));
        want.extend(2u64.to_le_bytes());
        let floats = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, -0.6, 0.8];
        want.extend(le(&floats.map(f32::to_bits)));
        want.extend(5u64.to_le_bytes());
        want.extend(2u64.to_le_bytes());
        want.extend(fnv1a(&want).to_le_bytes());
        let path = temp("visibility.bin");
        file.save(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), want);
        assert_eq!(VisibilityFile::load(&path).unwrap(), file);
        let stray = VisibilityFile {
            bits: vec![0b1000, 0].into(),
            ..file.clone()
        };
        let e = stray.save(&path).unwrap_err().to_string();
        assert!(e.contains("vertex 0 has a bit set past direction 3"), "{e}");
        let short = VisibilityFile {
            vertices: 3,
            ..file.clone()
        };
        assert!(short.save(&path).is_err());
        // The stray bit forged under a valid checksum.
        let mut forged = want.clone();
        forged.truncate(forged.len() - 8);
        let at = forged.len() - 16;
        forged[at] |= 0b1000;
        forged.extend(fnv1a(&forged).to_le_bytes());
        std::fs::write(&path, &forged).unwrap();
        let e = VisibilityFile::load(&path).unwrap_err().to_string();
        assert!(
            e.contains(&path.display().to_string()) && e.contains("past direction 3"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// A wrong version, a wrong magic, a flipped bit, a truncated or a longer file: errors
    /// that name the file and say what is wrong.
    #[test]
    fn damaged_files_are_refused() {
        let path = temp("damaged.bin");
        let file = TransferFile {
            axes: vec![Vec3::Y].into(),
            sharpness: 2.0,
            vertices: 2,
            coeffs: vec![1.0, 2.0].into(),
            projection_rel_l2: 0.0,
        };
        file.save(&path).unwrap();
        let good = std::fs::read(&path).unwrap();
        let name = path.display().to_string();
        let mut version = good.clone();
        version[8] = 2;
        let mut magic = good.clone();
        magic[3] = b'X';
        let mut flipped = good.clone();
        flipped[TRANSFER_HEADER + 13] ^= 0x04;
        let truncated = good[..good.len() - 4].to_vec();
        let mut longer = good.clone();
        longer.extend([0; 4]);
        for (bytes, says) in [
            (version, "version 2, this build reads 1"),
            (magic, "bad magic"),
            (flipped, "checksum mismatch"),
            (truncated, "bytes, but K = 1 and 2 vertices need"),
            (longer, "bytes, but K = 1 and 2 vertices need"),
        ] {
            std::fs::write(&path, &bytes).unwrap();
            let e = TransferFile::load(&path).unwrap_err().to_string();
            assert!(e.contains(&name) && e.contains(says), "{e}");
            // The CPCA reader refuses a transfer file for its magic.
            let e = CpcaFile::load(&path).unwrap_err().to_string();
            assert!(e.contains("not a vkshade CPCA transfer file"), "{e}");
        }
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// A forged cache: a valid checksum over a 3e38 or NaN weight (or coefficient) is
    /// refused naming the file and the element; the writers refuse such values too.
    #[test]
    fn forged_values_with_a_valid_checksum_are_refused() {
        let cpca = CpcaFile {
            axes: vec![Vec3::X, Vec3::Z].into(),
            sharpness: 0.75,
            vertices: 2,
            components: 1,
            clusters: 1,
            cluster_of: vec![0, 0].into(),
            rows: vec![0.5, -0.5, 1.0, 2.0].into(),
            weights: vec![3.0, -4.0].into(),
            rel_l2: 0.01,
        };
        let path = temp("forged.cpca");
        cpca.save(&path).unwrap();
        let good = std::fs::read(&path).unwrap();
        let name = path.display().to_string();
        // The second weight is the last float before the checksum.
        let at = good.len() - 8 - 4;
        for (bad, says) in [(3e38f32, "weight 1 is 3e38"), (f32::NAN, "weight 1 is NaN")] {
            let mut b = good[..good.len() - 8].to_vec();
            b[at..at + 4].copy_from_slice(&bad.to_le_bytes());
            let sum = fnv1a(&b);
            b.extend(sum.to_le_bytes());
            std::fs::write(&path, &b).unwrap();
            let e = CpcaFile::load(&path).unwrap_err().to_string();
            assert!(e.contains(&name) && e.contains(says), "{e}");
            let forged = CpcaFile {
                weights: vec![3.0, bad].into(),
                ..cpca.clone()
            };
            let e = forged.save(&temp("w.cpca")).unwrap_err().to_string();
            assert!(e.contains("not written") && e.contains("weight 1"), "{e}");
        }
        let t = TransferFile {
            axes: vec![Vec3::Y].into(),
            sharpness: 2.0,
            vertices: 2,
            coeffs: vec![1.0, 2.0].into(),
            projection_rel_l2: 0.0,
        };
        let tpath = temp("forged.bin");
        t.save(&tpath).unwrap();
        let mut b = std::fs::read(&tpath).unwrap();
        b.truncate(b.len() - 8);
        let at = b.len() - 4;
        b[at..].copy_from_slice(&3e38f32.to_le_bytes());
        let sum = fnv1a(&b);
        b.extend(sum.to_le_bytes());
        std::fs::write(&tpath, &b).unwrap();
        let e = TransferFile::load(&tpath).unwrap_err().to_string();
        assert!(e.contains("coefficient 1 is 3e38"), "{e}");
        // Just inside the bound is kept.
        let edge = TransferFile {
            coeffs: vec![MAX_MAGNITUDE, -MAX_MAGNITUDE].into(),
            ..t
        };
        edge.save(&tpath).unwrap();
        assert_eq!(TransferFile::load(&tpath).unwrap(), edge);
        for p in [&path, &tpath] {
            let _ = std::fs::remove_dir_all(p.parent().unwrap());
        }
        let _ = std::fs::remove_dir_all(temp("w.cpca").parent().unwrap());
    }

    /// A CTA file round-trips; a truncated one, a flipped bit, a forged NaN core value under
    /// a valid checksum and arrays that do not match the counts are refused naming the file.
    #[test]
    fn cta_file_round_trip_and_refusals() {
        let cta = CtaFile {
            axes: vec![Vec3::X, Vec3::Z].into(),
            sharpness: 3.5,
            vertices: 3,
            views: 2,
            clusters: 1,
            ranks: [2, 1, 2],
            cluster_of: vec![0, 0, 0].into(),
            view_factors: vec![0.6, 0.8].into(),
            light_factors: vec![1.0, 0.0, 0.0, 1.0].into(),
            cores: vec![1.5, -0.5, 0.25, 2.0].into(),
            coeffs: vec![1.0, 0.0, 0.0, 1.0, 0.5, 0.5].into(),
            rel_l2: 0.02,
            history: vec![3.0, 2.5].into(),
        };
        let path = temp("t.cta");
        let name = path.display().to_string();
        cta.save(&path).unwrap();
        assert_eq!(CtaFile::load(&path).unwrap(), cta);
        let good = std::fs::read(&path).unwrap();
        assert_eq!(
            good.len(),
            CTA_HEADER + 4 * (6 + 3 + 2 + 4 + 4 + 6) + 16 + 8
        );
        let mut flipped = good.clone();
        flipped[CTA_HEADER + 5] ^= 0x10;
        let truncated = good[..good.len() - 8].to_vec();
        // The first core value, forged to NaN under a valid checksum.
        let mut forged = good[..good.len() - 8].to_vec();
        let at = CTA_HEADER + 4 * (6 + 3 + 2 + 4);
        forged[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let sum = fnv1a(&forged);
        forged.extend(sum.to_le_bytes());
        // Counts whose arrays would overflow any size: C and the three ranks at u32::MAX.
        let mut huge = good.clone();
        for field in 2..6 {
            huge[12 + 4 * field..16 + 4 * field].copy_from_slice(&u32::MAX.to_le_bytes());
        }
        for (bytes, says) in [
            (huge, "overflow the file's size"),
            (flipped, "checksum mismatch"),
            (truncated, "2 history values and 3 vertices need"),
            (forged, "core value 0 is NaN"),
        ] {
            std::fs::write(&path, &bytes).unwrap();
            let e = CtaFile::load(&path).unwrap_err().to_string();
            assert!(e.contains(&name) && e.contains(says), "{e}");
        }
        let short = CtaFile {
            cores: vec![1.0; 3].into(),
            ..cta.clone()
        };
        let e = short.save(&path).unwrap_err().to_string();
        assert!(e.contains(&name) && e.contains("arrays of"), "{e}");
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }
}
