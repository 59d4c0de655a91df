//! `vkshade srbf fit` and `vkshade srbf shade`: environment lighting by spherical Gaussians,
//! rotated on the GPU and combined with per-vertex precomputed transfer; PLY, PNG and a JSON
//! report per run, and (optionally) the brute-force ground truth with the error split by
//! stage.

use super::Gpu;
use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::brdf::Brdf;
use crate::geom::sg::{self, Lobe};
use crate::geom::visibility::Visibility;
use crate::gpu::Context;
use crate::kernels::srbf::cpca::{Cpca, CpcaConfig};
use crate::kernels::srbf::cta::{Cta, CtaConfig};
use crate::kernels::srbf::cta_gpu::{
    CtaInputs, CtaKernel, PASS_CTA_LIGHT, PASS_CTA_PROJECT, PASS_CTA_SHADE,
};
use crate::kernels::srbf::diffuse_transfer;
use crate::kernels::srbf::fit::{FitConfig, fit};
use crate::kernels::srbf::glossy::{DEFAULT_VIEW, GlossyTransfer, ViewBasis, ViewSpec};
use crate::kernels::srbf::glossy_gpu::{GlossyFrame, GlossyInputs, GlossyKernel, PASS_GLOSSY};
use crate::kernels::srbf::glossy_sharp::{CompactShadow, GlossyCompact, PASS_GLOSSY_SHARP};
use crate::kernels::srbf::gpu::{
    CompactInputs, PASS_LIGHTING, PASS_PROJECT, PASS_SHADE, PASS_SHARP, SrbfFrame, SrbfInputs,
    SrbfKernel, SrbfOutput, SunRays, sun_offset,
};
use crate::kernels::srbf::transfer::{self, Basis, Transfer};
use crate::kernels::{FrameResult, KernelInfo, run_frames};
use crate::reference::srbf::{
    rasterise_lobes, shade_brute_force_radiance, shade_glossy_truth, shade_ground_truth,
};
use crate::report::MachineInfo;
use crate::scene::envmap::EnvMap;
use crate::scene::{self, Mesh};
use glam::{Mat3, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use crate::kernels::srbf::{DEFAULT_ENV, DEFAULT_MESH};

/// A rotation given on the command line: `y:30` (axis x, y or z; degrees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisAngle {
    pub axis: Vec3,
    pub degrees: f32,
}

impl std::str::FromStr for AxisAngle {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (axis, deg) = s
            .split_once(':')
            .ok_or_else(|| format!("'{s}': expected AXIS:DEGREES, e.g. y:30"))?;
        let axis = match axis.trim() {
            "x" | "X" => Vec3::X,
            "y" | "Y" => Vec3::Y,
            "z" | "Z" => Vec3::Z,
            other => return Err(format!("axis '{other}' is not x, y or z")),
        };
        let degrees: f32 = deg
            .trim()
            .parse()
            .map_err(|_| format!("'{deg}' is not a number of degrees"))?;
        if !degrees.is_finite() {
            return Err(format!("{degrees} degrees"));
        }
        Ok(AxisAngle { axis, degrees })
    }
}

pub use crate::reference::srbf::ReferenceWidth;

/// What `--reference` integrated (report.json `reference`).
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceInfo {
    /// `--reference-width` as given: full, directions or a width.
    pub requested: String,
    /// The integrated map's size and texel count (every texel is a quadrature node; black
    /// texels are skipped, which is exact).
    pub width: u32,
    pub height: u32,
    pub texels: usize,
    /// Whether that is the map at its own resolution (no downsampling).
    pub full_resolution: bool,
    /// Median wall time of one frame's truth (ms, CPU, f64, one ray per (vertex, texel)
    /// where the grid's own visibility cannot be reused).
    pub ms_median: f64,
}

/// Everything `vkshade srbf shade` can be told.
#[derive(Clone, Debug)]
pub struct ShadeConfig {
    pub mesh: PathBuf,
    pub env: PathBuf,
    /// Lighting lobes fitted to the environment.
    pub lobes: usize,
    /// Transfer basis functions.
    pub basis: usize,
    /// Clustered PCA of the transfer: clusters x principal components per cluster;
    /// `components` 0 keeps the transfer uncompressed.
    pub clusters: usize,
    pub components: usize,
    /// One frame at this rotation, or (with `frames` > 1) a spin about this axis.
    pub rotate: Option<AxisAngle>,
    /// Frames of a continuous spin (360 degrees over the frames) about `rotate`'s axis (+Y
    /// by default).
    pub frames: usize,
    pub albedo: [f32; 3],
    pub reference: bool,
    /// The resolution of the `--reference` truth.
    pub reference_width: ReferenceWidth,
    /// Width of the environment the lobes are fitted to (a downsampled copy).
    pub fit_width: u32,
    /// Width of the environment whose texel directions the transfer and the ground truth
    /// use (visibility is ray-cast for each of them).
    pub direction_width: u32,
    pub out: PathBuf,
    /// How negative samples of the map (codec ringing) are treated.
    pub hdr: crate::scene::envmap::HdrPolicy,
    pub image: (u32, u32),
    /// Relative error at the top of the heat map.
    pub error_scale: f32,
    pub in_flight: usize,
    /// Lobes sharper than this factor x the basis sharpness are shaded from the visibility
    /// instead of through the basis ([`crate::kernels::srbf::sharp`]); 0 turns it off.
    pub sharp_factor: f32,
    /// The most compact lobes shaded directly (the strongest; 0 turns it off).
    pub compact_lobes: usize,
    /// How compact lobes are shadowed: rays at their exact rotated directions, or the
    /// visibility grid's texel holding their axis ([`crate::kernels::srbf::sharp`]).
    pub sun: SunMode,
    /// The surface's BRDF; a glossy one shades toward `camera` through per-vertex transfer
    /// matrices over the view basis `view` ([`crate::kernels::srbf::glossy`]).
    pub brdf: Brdf,
    /// The camera position in model units (glossy only); `None`: the default camera,
    /// [`default_camera`].
    pub camera: Option<Vec3>,
    pub view: ViewSpec,
    /// Glossy: compress the transfer by clustered tensor approximation with these settings
    /// ([`crate::kernels::srbf::cta`]) and shade it with the CTA kernel; `None`: uncompressed.
    pub cta: Option<CtaConfig>,
}

/// The camera of a glossy run without `--camera`: on +Z of the mesh's bounding-box centre,
/// 1.5 bounding-box diagonals away.
pub fn default_camera(mesh: &Mesh) -> Vec3 {
    let (lo, hi) = mesh.bounds();
    (lo + hi) * 0.5 + Vec3::Z * 1.5 * (hi - lo).length()
}

impl Default for ShadeConfig {
    fn default() -> Self {
        ShadeConfig {
            mesh: PathBuf::from(DEFAULT_MESH),
            env: PathBuf::from(DEFAULT_ENV),
            lobes: 64,
            basis: 256,
            clusters: CpcaConfig::default().clusters,
            components: CpcaConfig::default().components,
            rotate: None,
            frames: 1,
            albedo: [1.0; 3],
            reference: false,
            reference_width: ReferenceWidth::Directions,
            fit_width: 128,
            direction_width: 64,
            out: PathBuf::from("out/srbf"),
            hdr: Default::default(),
            image: (640, 480),
            error_scale: 0.1,
            in_flight: 2,
            sharp_factor: crate::kernels::srbf::sharp::DEFAULT_FACTOR,
            compact_lobes: crate::kernels::srbf::sharp::DEFAULT_MAX_LOBES,
            sun: SunMode::Grid,
            brdf: Brdf::Diffuse,
            camera: None,
            view: DEFAULT_VIEW,
            cta: None,
        }
    }
}

impl ShadeConfig {
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidArgument(m));
        if !(1..=4096).contains(&self.lobes) {
            return bad(format!("--lobes must be in 1..=4096, not {}", self.lobes));
        }
        let max_basis = crate::kernels::srbf::gpu::MAX_BASIS;
        if !(1..=max_basis).contains(&self.basis) {
            return bad(format!(
                "--basis must be in 1..={max_basis}, not {}",
                self.basis
            ));
        }
        if self.components > self.basis {
            return bad(format!(
                "--components {} exceeds --basis {}",
                self.components, self.basis
            ));
        }
        let max_rows = crate::kernels::srbf::gpu::MAX_ROWS;
        let rows = crate::kernels::srbf::gpu::rows_needed(self.clusters, self.components);
        if self.clusters == 0 {
            return bad(
                "--clusters must be at least 1 (--components 0 keeps the transfer \
                 uncompressed)"
                    .into(),
            );
        }
        if self.components > 0 && rows > max_rows {
            return bad(format!(
                "--clusters {} x --components {} need {rows} projected rows; the GPU path \
                 holds {max_rows} (fewer clusters or components)",
                self.clusters, self.components
            ));
        }
        if !(1..=100_000).contains(&self.frames) {
            return bad(format!(
                "--frames must be in 1..=100000, not {}",
                self.frames
            ));
        }
        if self.albedo.iter().any(|a| !a.is_finite() || *a < 0.0) {
            return bad(format!(
                "--albedo {:?} must be finite and >= 0",
                self.albedo
            ));
        }
        if !(1..=16).contains(&self.in_flight) {
            return bad(format!(
                "--in-flight must be in 1..=16, not {}",
                self.in_flight
            ));
        }
        if !(self.sharp_factor.is_finite() && self.sharp_factor >= 0.0) {
            return bad(format!(
                "--sharp-factor must be finite and >= 0 (0: off), not {}",
                self.sharp_factor
            ));
        }
        let max_compact = crate::kernels::srbf::sharp::MAX_LOBES;
        if self.compact_lobes > max_compact {
            return bad(format!(
                "--compact-lobes must be in 0..={max_compact}, not {}",
                self.compact_lobes
            ));
        }
        if !(self.error_scale.is_finite() && self.error_scale > 0.0) {
            return bad(format!(
                "--error-scale must be > 0, not {}",
                self.error_scale
            ));
        }
        self.brdf
            .check()
            .map_err(|e| Error::InvalidArgument(format!("--brdf: {e}")))?;
        if let Some(c) = self.camera
            && !c.is_finite()
        {
            return bad(format!("--camera {c} is not finite"));
        }
        if self.cta.is_some() && !self.brdf.is_glossy() {
            return bad(
                "--cta compresses the glossy transfer (--brdf phong); the diffuse transfer is \
                 compressed by clustered PCA (--clusters, --components)"
                    .into(),
            );
        }
        if self.brdf.is_glossy() {
            self.view
                .check()
                .map_err(|e| Error::InvalidArgument(format!("--views / --terms: {e}")))?;
            if self.cta.is_some() {
                self.view.check_for_cta()?;
            }
        }
        for (name, w) in [
            ("fit width", self.fit_width),
            ("direction width", self.direction_width),
        ] {
            if !(8..=4096).contains(&w) || w % 2 != 0 {
                return bad(format!("{name} {w} must be even and in 8..=4096"));
            }
        }
        Ok(())
    }

    /// The environment rotation of each frame.
    pub fn rotations(&self) -> Vec<Mat3> {
        let axis = self.rotate.map(|r| r.axis).unwrap_or(Vec3::Y);
        let start = self.rotate.map(|r| r.degrees).unwrap_or(0.0);
        if self.frames <= 1 {
            return vec![sg::rotation(axis, start)];
        }
        (0..self.frames)
            .map(|i| sg::rotation(axis, start + 360.0 * i as f32 / self.frames as f32))
            .collect()
    }
}

/// Relative L2 errors per channel (sqrt(sum |a - b|^2 / sum |b|^2)) and over all channels.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RelL2 {
    pub rgb: [f64; 3],
    pub all: f64,
}

impl RelL2 {
    pub fn of(a: &[[f64; 3]], b: &[[f64; 3]]) -> RelL2 {
        let mut num = [0f64; 3];
        let mut den = [0f64; 3];
        for (x, y) in a.iter().zip(b) {
            for c in 0..3 {
                num[c] += (x[c] - y[c]).powi(2);
                den[c] += y[c].powi(2);
            }
        }
        let ratio = |n: f64, d: f64| if d > 0.0 { (n / d).sqrt() } else { n.sqrt() };
        RelL2 {
            rgb: [0, 1, 2].map(|c| ratio(num[c], den[c])),
            all: ratio(num.iter().sum(), den.iter().sum()),
        }
    }
}

/// One frame of the report.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub index: usize,
    /// Column-major rotation matrix of the environment.
    pub rotation: [f32; 9],
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_lighting: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_project: f64,
    /// Pass `srbf sharp` (diffuse: the compact lobes' taps, and with `--sun rays` their
    /// shadow rays) or `srbf glossy sharp` (glossy: the compact lobes added to the radiance).
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_sharp: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_shade: f64,
    /// CTA: passes `srbf cta light`, `srbf cta project` and `srbf cta shade` (ms), whose sum
    /// is `gpu_ms_shade`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_ms_cta: Option<[f64; 3]>,
    /// GPU against the same pipeline on the CPU (f64).
    pub gpu_vs_cpu: RelL2,
    /// With --reference: the method against the brute-force ground truth (at
    /// `reference.width`, see report.json's `reference`).
    pub vs_ground_truth: Option<RelL2>,
    /// With --reference at a resolution other than the direction map's: the truth over the
    /// direction map's texels against the reference truth (the share of the error that the
    /// direction map's coarser texels cause, e.g. a sun blurred into one 5.6-degree texel).
    /// The fit and transfer shares below are measured against the direction map's truth.
    pub direction_map_vs_ground_truth: Option<RelL2>,
    /// With --reference: the same lobes with the uncompressed transfer (CPU) against the
    /// ground truth; the difference to `vs_ground_truth` is the compression's share.
    pub uncompressed_vs_ground_truth: Option<RelL2>,
    /// With --reference, the error split by stage. Fit: the brute-force sum with the fitted
    /// lobes (rotated, rasterised into the same texels) in place of the map, against the
    /// ground truth.
    pub fit_share: Option<RelL2>,
    /// Transfer projection: the method with the uncompressed transfer against that same
    /// brute-force sum over the fitted lobes (the lighting is then the same on both sides).
    pub transfer_share: Option<RelL2>,
    pub ply: String,
    pub png: String,
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct ShadeReport {
    pub tool: &'static str,
    pub machine: MachineInfo,
    pub mesh: String,
    pub vertices: usize,
    pub env: String,
    pub env_size: [u32; 2],
    pub lobes: usize,
    /// Of the lobes, those sharper than `sharp_factor` x the basis sharpness (holding >= 2% of
    /// the energy): shaded directly at their rotated directions, shadowed as `sun` says, not
    /// through the basis.
    pub compact_lobes: usize,
    pub sharp_factor: f32,
    /// How compact lobes were shadowed: "rays" (a ray per vertex and compact lobe at its
    /// exact rotated direction, every frame) or "grid" (its taps' grid texels: the one
    /// holding its axis, or the 2 x 2 around it for a lobe the fit resolved).
    pub sun: SunMode,
    pub basis: usize,
    pub basis_sharpness: f32,
    pub albedo: [f32; 3],
    /// Fit of the lobes to the environment (at `fit_width`): solid-angle-weighted relative L2.
    pub fit_rel_l2: f64,
    pub fit_ms: f64,
    /// The mesh's visibility toward the direction map's texels: ray-casting time (0 when
    /// read from `visibility.bin`).
    pub visibility_ms: f64,
    pub visibility_cached: bool,
    /// Mean over vertices of the transfer projection's relative L2.
    pub transfer_rel_l2: f64,
    pub transfer_ms: f64,
    pub transfer_cached: bool,
    /// Clustered PCA (0 components: uncompressed).
    pub clusters: usize,
    pub components: usize,
    /// Function-space relative L2 of the compressed transfer against the projected one.
    pub cpca_rel_l2: f64,
    pub cpca_ms: f64,
    pub cpca_cached: bool,
    /// Transfer bytes streamed per vertex per frame.
    pub transfer_bytes_per_vertex: usize,
    pub directions: usize,
    pub kernel: KernelInfo,
    pub frames: Vec<FrameReport>,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_lighting_median: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_project_median: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_sharp_median: f64,
    #[serde(serialize_with = "crate::io::finite::nan_as_null")]
    pub gpu_ms_shade_median: f64,
    pub fps: f64,
    /// The BRDF and its parameters.
    pub brdf: Brdf,
    /// Glossy runs: the camera position (model units) every frame is shaded toward, and the
    /// view basis of the transfer matrices: the side N of an N x N view grid, or the number
    /// of BRDF terms and their truncation error (relative L2 of the kernel).
    pub camera: Option<[f32; 3]>,
    pub view_grid: Option<u32>,
    pub view_terms: Option<usize>,
    pub view_truncation: Option<f64>,
    /// With --reference: the map the truth integrated.
    pub reference: Option<ReferenceInfo>,
    pub notes: Vec<String>,
}

/// The transfer of a mesh, computed once and cached beside the outputs (reused when the
/// mesh, basis and direction set are the same).
fn transfer_for(
    cfg: &ShadeConfig,
    mesh: &Mesh,
    dir_env: &EnvMap,
    vis: &Visibility,
) -> Result<(Transfer, bool, f64)> {
    let path = cfg.out.join("transfer.bin");
    let key_path = cfg.out.join("transfer.key");
    let key = format!(
        "{} {} {} {} {}",
        cfg.mesh.display(),
        mesh.positions.len(),
        cfg.basis,
        dir_env.width,
        modified_stamp(&cfg.mesh)
    );
    cached(
        &key_path,
        &key,
        || {
            Transfer::load(&path)
                .inspect_err(|e| log::warn!("{e}; recomputing the transfer"))
                .ok()
                .filter(|t| t.vertices == mesh.positions.len() && t.basis.len() == cfg.basis)
        },
        || diffuse_transfer(&Basis::fibonacci(cfg.basis), dir_env, &mesh.normals, vis),
        |t| t.save(&path),
    )
}

/// `path`'s modification time as the cache keys hold it (empty when it cannot be read).
fn modified_stamp(path: &Path) -> String {
    std::fs::metadata(path)
        .and_then(|m| m.modified())
        .map(|t| format!("{t:?}"))
        .unwrap_or_default()
}

/// The mesh's visibility toward the direction map's texels (a ray per vertex and texel),
/// cached beside the outputs as `visibility.bin` (reused when the mesh and the direction
/// map's size are the same, and the file's directions are the map's). Every later result,
/// the truth's included, is computed from it.
fn visibility_for(
    cfg_out: &Path,
    mesh_path: &Path,
    mesh: &Mesh,
    dir_env: &EnvMap,
) -> Result<(Visibility, bool, f64)> {
    let path = cfg_out.join("visibility.bin");
    let key = format!(
        "visibility {} {} {} {}x{} {}",
        mesh_path.display(),
        mesh.positions.len(),
        mesh.triangles.len(),
        dir_env.width,
        dir_env.height,
        modified_stamp(mesh_path)
    );
    let directions: Vec<Vec3> = dir_env.samples().iter().map(|s| s.0).collect();
    cached(
        &cfg_out.join("visibility.key"),
        &key,
        || {
            crate::io::transfer_cache::VisibilityFile::load(&path)
                .inspect_err(|e| log::warn!("{e}; casting the visibility again"))
                .ok()
                .filter(|f| f.vertices == mesh.positions.len() && *f.directions == *directions)
                .and_then(|f| {
                    Visibility::from_bits(
                        f.directions.into_owned(),
                        f.vertices,
                        f.bits.into_owned(),
                    )
                })
        },
        || Ok(crate::scene::envmap::texel_visibility(mesh, dir_env)),
        |v| {
            crate::io::transfer_cache::VisibilityFile {
                directions: std::borrow::Cow::Borrowed(&v.directions),
                vertices: v.vertices,
                bits: std::borrow::Cow::Borrowed(v.bits()),
            }
            .save(&path)
        },
    )
}

/// A result kept in a file beside a key file: `load` is tried when the stored key equals
/// `key`, else `compute` runs and `save` stores its result, then the key. The old key is
/// removed before the result is saved, so a run stopped between the two writes leaves no
/// key that names another result. A cache that cannot be written is a warning, not an
/// error: the computed value is used. Returns the value, whether it came from the cache,
/// and the compute time in ms (0 when cached).
fn cached<T>(
    key_path: &Path,
    key: &str,
    load: impl FnOnce() -> Option<T>,
    compute: impl FnOnce() -> Result<T>,
    save: impl FnOnce(&T) -> Result<()>,
) -> Result<(T, bool, f64)> {
    if std::fs::read_to_string(key_path).ok().as_deref() == Some(key)
        && let Some(v) = load()
    {
        return Ok((v, true, 0.0));
    }
    let t0 = Instant::now();
    let v = compute()?;
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let _ = std::fs::remove_file(key_path);
    if let Err(e) = save(&v).and_then(|()| crate::io::write_atomic(key_path, key.as_bytes())) {
        log::warn!("{e}; the result is used but not cached");
    }
    Ok((v, false, ms))
}

/// The transfer in the form the GPU runs (clustered PCA, or uncompressed with
/// `components` 0), cached beside the transfer (reused while the transfer and the
/// compression settings are the same).
fn cpca_for(
    cfg: &ShadeConfig,
    transfer: &Transfer,
    transfer_cached: bool,
) -> Result<(Cpca, bool, f64)> {
    if cfg.components == 0 {
        return Ok((Cpca::exact(transfer), false, 0.0));
    }
    let path = cfg.out.join("transfer.cpca");
    let key_path = cfg.out.join("transfer.cpca.key");
    let settings = CpcaConfig {
        clusters: cfg.clusters,
        components: cfg.components,
        ..CpcaConfig::default()
    };
    let key = format!("{settings:?}");
    cached(
        &key_path,
        &key,
        || {
            // A recomputed transfer invalidates its compression.
            Cpca::load(&path)
                .inspect_err(|e| log::warn!("{e}; recomputing the compression"))
                .ok()
                .filter(|c| {
                    transfer_cached && c.vertices == transfer.vertices && c.basis == transfer.basis
                })
        },
        || Cpca::compress(transfer, &settings),
        |c| c.save(&path),
    )
}

/// Runs `vkshade srbf shade`.
pub fn shade(
    ctx: &Context,
    cfg: &ShadeConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<ShadeReport> {
    cfg.validate()?;
    crate::io::outdir::claim(&cfg.out, "srbf shade")?;
    let character = scene::load(&cfg.mesh)?;
    let mesh = &character.mesh;
    let env = super::load_env(&cfg.env, cfg.hdr, progress)?;
    progress(&format!(
        "{}: {} vertices; {}: {}x{}",
        cfg.mesh.display(),
        mesh.positions.len(),
        cfg.env.display(),
        env.width,
        env.height
    ));
    if cfg.brdf.is_glossy() {
        return shade_glossy(ctx, cfg, mesh, &env, progress);
    }
    let pre = Precomputed::new(cfg, mesh, &env, progress)?;
    let session = Session::new(ctx, cfg, mesh, &pre, progress)?;
    let frames_in: Vec<SrbfFrame> = cfg
        .rotations()
        .iter()
        .map(|&rotation| SrbfFrame {
            rotation,
            albedo: cfg.albedo,
        })
        .collect();
    let mut frames = Vec::with_capacity(frames_in.len());
    let in_flight = run_frames(ctx, &session.kernel, &frames_in, cfg.in_flight, |r| {
        let report = session.frame(&frames_in[r.index], r)?;
        progress(&frame_line(&report));
        frames.push(report);
        Ok(())
    })?;
    let report = session.report(&env, frames, in_flight);
    crate::io::write_json(&cfg.out.join("report.json"), &report)?;
    Ok(report)
}

/// What a run's lighting and transfer are made of, computed (or read from the cache) once
/// before any frame.
struct Precomputed {
    /// The lobes fitted to the environment.
    fitted: crate::kernels::srbf::fit::Fit,
    fit_ms: f64,
    /// The environment at the direction width: its texel directions carry the transfer, the
    /// compact lobes' visibility and the ground truth.
    dir_env: EnvMap,
    vis: Visibility,
    vis_cached: bool,
    vis_ms: f64,
    /// The static mesh's BVH for the compact lobes' shadow rays (`--sun rays` only).
    bvh: Option<Bvh>,
    transfer: Transfer,
    transfer_cached: bool,
    transfer_ms: f64,
    cpca: Cpca,
    cpca_cached: bool,
    cpca_ms: f64,
    /// With --reference at another resolution than the direction map's: the map the truth
    /// integrates.
    reference_env: Option<EnvMap>,
    /// The loaded map's width.
    reference_width_of_env: u32,
    /// Width of the map the lobes were fitted to.
    fit_width: u32,
}

impl Precomputed {
    /// Fits the lobes, casts the visibility, projects and compresses the transfer.
    fn new(
        cfg: &ShadeConfig,
        mesh: &Mesh,
        env: &EnvMap,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Precomputed> {
        let t = Instant::now();
        let fit_env = env.downsampled(cfg.fit_width.min(env.width))?;
        let fit_cfg = FitConfig {
            lobes: cfg.lobes,
            ..FitConfig::default()
        };
        let fitted = fit(&fit_env.samples(), &fit_cfg)?;
        let fit_ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "fit {} lobes to {}x{}: relative L2 {:.4} ({fit_ms:.0} ms)",
            cfg.lobes, fit_env.width, fit_env.height, fitted.rel_l2
        ));
        let dir_env = env.downsampled(cfg.direction_width.min(env.width))?;
        let (vis, vis_cached, vis_ms) = visibility_for(&cfg.out, &cfg.mesh, mesh, &dir_env)?;
        progress(&visibility_line(&vis, vis_cached, vis_ms));
        let (transfer, cached, transfer_ms) = transfer_for(cfg, mesh, &dir_env, &vis)?;
        progress(&format!(
            "transfer: {} basis SGs (sharpness {:.1}), projection relative L2 {:.4}{}",
            transfer.basis.axes.len(),
            transfer.basis.sharpness,
            transfer.projection_rel_l2,
            cost(cached, transfer_ms)
        ));
        let (cpca, cpca_cached, cpca_ms) = cpca_for(cfg, &transfer, cached)?;
        if cfg.components > 0 {
            progress(&format!(
                "clustered PCA: {} clusters x {} components, relative L2 {:.4}{}",
                cpca.clusters,
                cpca.components,
                cpca.rel_l2,
                cost(cpca_cached, cpca_ms)
            ));
        }
        let reference_env = if cfg.reference {
            cfg.reference_width.map(env, cfg.direction_width)?
        } else {
            None
        };
        Ok(Precomputed {
            reference_env,
            reference_width_of_env: env.width,
            fit_width: fit_env.width,
            fitted,
            fit_ms,
            dir_env,
            vis,
            vis_cached,
            vis_ms,
            bvh: (cfg.sun == SunMode::Rays).then(|| Bvh::build(&mesh.positions, &mesh.triangles)),
            transfer,
            transfer_cached: cached,
            transfer_ms,
            cpca,
            cpca_cached,
            cpca_ms,
        })
    }
}

/// `vkshade srbf shade` with a glossy BRDF: the lobes fitted as for diffuse, the glossy
/// transfer projected once and cached (`glossy.bin` beside the outputs), every frame shaded
/// on the GPU toward the camera and compared with the CPU twin, and with `--reference` with
/// the glossy brute-force truth over the direction map's texels (the fit's share apart).
/// Compact lobes (a sun, lamps) are shaded directly as on the diffuse path
/// ([`crate::kernels::srbf::glossy_sharp`]), shadowed by the grid or by rays (`--sun`). The
/// transfer is uncompressed (vertices x view rows x basis f32, refused before the projection
/// when it exceeds the device's maxStorageBufferRange) or CTA-compressed.
fn shade_glossy(
    ctx: &Context,
    cfg: &ShadeConfig,
    mesh: &Mesh,
    env: &EnvMap,
    progress: &mut dyn FnMut(&str),
) -> Result<ShadeReport> {
    let rows = cfg.view.rows();
    let bytes = mesh.positions.len() as u64 * rows as u64 * cfg.basis as u64 * 4;
    let limit = ctx.limits().max_storage_buffer_range;
    if bytes > limit && cfg.cta.is_none() {
        return Err(Error::InvalidArgument(format!(
            "glossy transfer of {}: {} vertices x {} view rows x {} basis functions = {bytes} \
             bytes uncompressed; the device's storage buffers hold {limit} \
             (maxStorageBufferRange): use --cta, fewer --terms / --views or --basis, or a \
             smaller mesh",
            cfg.mesh.display(),
            mesh.positions.len(),
            rows,
            cfg.basis
        )));
    }
    let t = Instant::now();
    let fit_env = env.downsampled(cfg.fit_width.min(env.width))?;
    let fitted = fit(
        &fit_env.samples(),
        &FitConfig {
            lobes: cfg.lobes,
            ..FitConfig::default()
        },
    )?;
    let fit_ms = t.elapsed().as_secs_f64() * 1e3;
    progress(&format!(
        "fit {} lobes to {}x{}: relative L2 {:.4} ({fit_ms:.0} ms)",
        cfg.lobes, fit_env.width, fit_env.height, fitted.rel_l2
    ));
    let t = Instant::now();
    let view = cfg.view.build(&cfg.brdf)?;
    progress(&format!(
        "view basis: {} ({:.0} ms)",
        view.describe(),
        t.elapsed().as_secs_f64() * 1e3
    ));
    let dir_env = env.downsampled(cfg.direction_width.min(env.width))?;
    let (vis, vis_cached, vis_ms) = visibility_for(&cfg.out, &cfg.mesh, mesh, &dir_env)?;
    progress(&visibility_line(&vis, vis_cached, vis_ms));
    let path = cfg.out.join("glossy.bin");
    let key = format!(
        "glossy {} {} {} {} {:016x} {:?} {}",
        cfg.mesh.display(),
        mesh.positions.len(),
        cfg.basis,
        dir_env.width,
        view.fingerprint(),
        cfg.brdf,
        modified_stamp(&cfg.mesh)
    );
    let vertices = mesh.positions.len();
    let wrap = |rows: Transfer| GlossyTransfer {
        rows,
        vertices,
        view: view.clone(),
        brdf: cfg.brdf,
    };
    let (transfer, transfer_cached, transfer_ms) = cached(
        &cfg.out.join("glossy.key"),
        &key,
        || {
            Transfer::load(&path)
                .ok()
                .map(wrap)
                .filter(|t| t.check().is_ok() && t.rows.basis.len() == cfg.basis)
        },
        || {
            crate::kernels::srbf::glossy_transfer(
                &Basis::fibonacci(cfg.basis),
                &cfg.brdf,
                &view,
                &dir_env,
                &mesh.normals,
                &vis,
            )
        },
        |t| t.rows.save(&path),
    )?;
    progress(&format!(
        "glossy transfer: {} view rows x {} basis SGs per vertex, projection relative L2 \
         ~{:.4}{}",
        rows,
        cfg.basis,
        transfer.rows.projection_rel_l2,
        cost(transfer_cached, transfer_ms)
    ));
    let camera = cfg.camera.unwrap_or_else(|| default_camera(mesh));
    let (smooth, compact_lobes) = match crate::kernels::srbf::sharp::split(
        &fitted.lobes,
        transfer.rows.basis.sharpness,
        cfg.sharp_factor,
        cfg.compact_lobes,
    ) {
        // Every lobe compact (e.g. --lobes 1 under a sun): the basis path needs one.
        (smooth, _) if smooth.is_empty() => (fitted.lobes.clone(), Vec::new()),
        split => split,
    };
    let bvh = (cfg.sun == SunMode::Rays && !compact_lobes.is_empty())
        .then(|| Bvh::build(&mesh.positions, &mesh.triangles));
    let compact = (!compact_lobes.is_empty()).then(|| GlossyCompact {
        lobes: &compact_lobes,
        shadow: match &bvh {
            Some(bvh) => CompactShadow::Rays(SunRays {
                positions: &mesh.positions,
                bvh,
                offset: sun_offset(&mesh.positions),
            }),
            None => CompactShadow::Grid {
                visibility: &vis,
                width: dir_env.width,
                height: dir_env.height,
            },
        },
        brdf: cfg.brdf,
        fit_width: fit_env.width,
    });
    if !compact_lobes.is_empty() {
        progress(&compact_note(
            cfg,
            &crate::kernels::srbf::sharp::points(&compact_lobes, fit_env.width),
            transfer.rows.basis.sharpness,
            " with the BRDF toward the camera",
        ));
    }
    let inputs = GlossyInputs {
        lobes: &smooth,
        transfer: &transfer,
        positions: &mesh.positions,
        normals: &mesh.normals,
        compact,
    };
    let (cta, cta_cached, cta_ms) = match &cfg.cta {
        None => (None, false, 0.0),
        Some(c) => {
            let mut c = *c;
            if c.ranks[1] > rows {
                progress(&format!(
                    "CTA: view rank {} capped at the view basis' {rows} rows",
                    c.ranks[1]
                ));
                c.ranks[1] = rows;
            }
            let c = &c;
            // Cached beside the transfer while the transfer (its key) and the settings are
            // the same.
            let cta_path = cfg.out.join("glossy.cta");
            let (cta, cached_cta, ms) = cached(
                &cfg.out.join("glossy.cta.key"),
                &format!("{key} {c:?}"),
                || {
                    Cta::load(&cta_path).ok().filter(|t| {
                        t.vertices == vertices
                            && t.views == rows
                            && t.clusters == c.clusters
                            && t.ranks == c.ranks
                            && t.basis.axes == transfer.rows.basis.axes
                            && t.basis.sharpness == transfer.rows.basis.sharpness
                    })
                },
                || {
                    Cta::compress(
                        &transfer.rows.basis,
                        &transfer.rows.coeffs,
                        vertices,
                        rows,
                        c,
                    )
                },
                |t| t.save(&cta_path),
            )?;
            let (stream, amortised) = cta.bytes_per_vertex();
            progress(&format!(
                "CTA: {} clusters, ranks {:?}: relative L2 {:.4} (history {:?}); {stream} B per \
                 vertex streamed, {amortised:.1} B amortised{}",
                cta.clusters,
                cta.ranks,
                cta.rel_l2,
                cta.history,
                cost(cached_cta, ms)
            ));
            (Some(cta), cached_cta, ms)
        }
    };
    let cta_inputs = cta.as_ref().map(|t| CtaInputs {
        lobes: &smooth,
        transfer: t,
        view: &view,
        positions: &mesh.positions,
        normals: &mesh.normals,
        compact,
    });
    let mut setup = ctx.recorder("srbf glossy setup")?;
    let kernel = match &cta_inputs {
        None => GlossyOrCta::Glossy(GlossyKernel::new(&mut setup, &inputs)?),
        Some(i) => GlossyOrCta::Cta(CtaKernel::new(&mut setup, i)?),
    };
    setup.submit_and_wait()?;
    let frames_in: Vec<GlossyFrame> = cfg
        .rotations()
        .iter()
        .map(|&rotation| GlossyFrame {
            rotation,
            albedo: cfg.albedo,
            camera,
        })
        .collect();
    let pictures = Pictures::new(cfg, mesh);
    let reference_env = if cfg.reference {
        cfg.reference_width.map(env, cfg.direction_width)?
    } else {
        None
    };
    let mut truth_ms = Vec::new();
    let mut frames = Vec::with_capacity(frames_in.len());
    let mut on_frame = |r: FrameResult<Vec<[f32; 3]>>, shade_ms: f64| -> Result<()> {
        // `srbf sharp` (the taps; grid taps only) and `srbf glossy sharp`.
        let sharp_ms = match compact_lobes.len() {
            0 => 0.0,
            _ => {
                r.timings.get(PASS_SHARP).unwrap_or(0.0)
                    + r.timings.get(PASS_GLOSSY_SHARP).unwrap_or(f64::NAN)
            }
        };
        let frame = &frames_in[r.index];
        let dense = inputs.cpu_pipeline(frame)?;
        let cpu = match &cta_inputs {
            None => dense.clone(),
            Some(i) => i.cpu_pipeline(frame)?,
        };
        let gpu: Vec<[f64; 3]> = r.output.iter().map(|c| c.map(|x| x as f64)).collect();
        let truth_of = |map: &EnvMap, rotation: Mat3| {
            shade_glossy_truth(
                map,
                rotation,
                mesh,
                &mesh.positions,
                &mesh.normals,
                &cfg.brdf,
                camera,
                cfg.albedo,
            )
        };
        let (truth, fit_share, grid_share) = if cfg.reference {
            let t0 = Instant::now();
            let grid_truth = truth_of(&dir_env, frame.rotation)?;
            let full_truth = match &reference_env {
                Some(e) => Some(truth_of(e, frame.rotation)?),
                None => None,
            };
            truth_ms.push(t0.elapsed().as_secs_f64() * 1e3);
            let raster = rasterise_lobes(&fitted.lobes, frame.rotation, &dir_env);
            let lobe_map = EnvMap::from_texels(
                dir_env.width,
                dir_env.height,
                raster.iter().map(|c| c.map(|x| x as f32)).collect(),
                "the fitted lobes",
            )?;
            let sg_truth = truth_of(&lobe_map, Mat3::IDENTITY)?;
            let fit_share = RelL2::of(&sg_truth, &grid_truth);
            let grid_share = full_truth.as_ref().map(|t| RelL2::of(&grid_truth, t));
            (
                Some(full_truth.unwrap_or(grid_truth)),
                Some((fit_share, RelL2::of(&dense, &sg_truth))),
                grid_share,
            )
        } else {
            (None, None, None)
        };
        let report = FrameReport {
            index: r.index,
            rotation: frame.rotation.to_cols_array(),
            gpu_ms_lighting: r.timings.get(PASS_LIGHTING).unwrap_or(f64::NAN),
            gpu_ms_project: 0.0,
            gpu_ms_sharp: sharp_ms,
            gpu_ms_shade: shade_ms,
            gpu_ms_cta: cta_inputs.as_ref().map(|_| {
                [PASS_CTA_LIGHT, PASS_CTA_PROJECT, PASS_CTA_SHADE]
                    .map(|p| r.timings.get(p).unwrap_or(f64::NAN))
            }),
            gpu_vs_cpu: RelL2::of(&gpu, &cpu),
            vs_ground_truth: truth.as_ref().map(|t| RelL2::of(&gpu, t)),
            direction_map_vs_ground_truth: grid_share,
            uncompressed_vs_ground_truth: truth.as_ref().map(|t| RelL2::of(&dense, t)),
            fit_share: fit_share.map(|f| f.0),
            transfer_share: fit_share.map(|f| f.1),
            ply: String::new(),
            png: String::new(),
        };
        let report = pictures.write(report, mesh, &gpu, truth.as_deref())?;
        progress(&frame_line(&report));
        frames.push(report);
        Ok(())
    };
    let in_flight = match &kernel {
        GlossyOrCta::Glossy(k) => run_frames(ctx, k, &frames_in, cfg.in_flight, |r| {
            let ms = r.timings.get(PASS_GLOSSY).unwrap_or(f64::NAN);
            on_frame(r, ms)
        })?,
        GlossyOrCta::Cta(k) => run_frames(ctx, k, &frames_in, cfg.in_flight, |r| {
            let ms = [PASS_CTA_LIGHT, PASS_CTA_PROJECT, PASS_CTA_SHADE]
                .iter()
                .map(|p| r.timings.get(p).unwrap_or(f64::NAN))
                .sum();
            on_frame(r, ms)
        })?,
    };
    let median = |f: &dyn Fn(&FrameReport) -> f64| {
        let mut v: Vec<f64> = frames.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let lighting = median(&|f| f.gpu_ms_lighting);
    let shade_ms = median(&|f| f.gpu_ms_shade);
    let sharp_ms = median(&|f| f.gpu_ms_sharp);
    let mut notes = Vec::new();
    if ctx.info().device_type == "CPU" {
        notes.push("the device is a CPU implementation (lavapipe): times measure the CPU".into());
    }
    let truth_env = reference_env.as_ref().unwrap_or(&dir_env);
    notes.push(format!(
        "glossy: radiance toward the camera; ground truth over the {}x{} texel directions \
         ({}), visibility ray-cast along every rotated direction, f64; fit and transfer \
         shares against the {}x{} direction map's truth; {} compact lobes shaded directly \
         (passes srbf sharp and srbf glossy sharp, gpu_ms_sharp)",
        truth_env.width,
        truth_env.height,
        if truth_env.width == env.width {
            "the map at its own resolution"
        } else {
            "solid-angle-weighted downsampling"
        },
        dir_env.width,
        dir_env.height,
        compact_lobes.len()
    ));
    if let Some(c) = &cta {
        let (stream, amortised) = c.bytes_per_vertex();
        notes.push(format!(
            "CTA: {} clusters, ranks (vertex, view, light) {:?}, {} iterations; {stream} B per \
             vertex streamed (f16 coefficients + cluster id), {amortised:.1} B per vertex with \
             the cluster tables; relative L2 (function space) {:.4}; history of the squared \
             error {:?}; compression {cta_ms:.0} ms{}; gpu_ms_shade sums the \
             cta light, project and shade passes; uncompressed_vs_ground_truth is the \
             uncompressed transfer (CPU)",
            c.clusters,
            c.ranks,
            cfg.cta.map_or(0, |x| x.iterations),
            c.rel_l2,
            c.history,
            if cta_cached {
                " (cached: glossy.cta)"
            } else {
                ""
            }
        ));
    }
    let report = ShadeReport {
        tool: "vkshade srbf shade",
        machine: MachineInfo::of(ctx),
        mesh: cfg.mesh.display().to_string(),
        vertices,
        env: cfg.env.display().to_string(),
        env_size: [env.width, env.height],
        lobes: cfg.lobes,
        compact_lobes: compact_lobes.len(),
        sharp_factor: cfg.sharp_factor,
        sun: cfg.sun,
        basis: cfg.basis,
        basis_sharpness: transfer.rows.basis.sharpness,
        albedo: cfg.albedo,
        fit_rel_l2: fitted.rel_l2,
        fit_ms,
        visibility_ms: vis_ms,
        visibility_cached: vis_cached,
        transfer_rel_l2: transfer.rows.projection_rel_l2,
        transfer_ms,
        transfer_cached,
        clusters: cta.as_ref().map_or(0, |c| c.clusters),
        components: 0,
        cpca_rel_l2: cta.as_ref().map_or(0.0, |c| c.rel_l2),
        cpca_ms: cta_ms,
        cpca_cached: cta_cached,
        transfer_bytes_per_vertex: cta
            .as_ref()
            .map_or(transfer.bytes_per_vertex(), |c| c.bytes_per_vertex().0),
        directions: vis.directions.len(),
        kernel: match &kernel {
            GlossyOrCta::Glossy(k) => KernelInfo::of(k, in_flight),
            GlossyOrCta::Cta(k) => KernelInfo::of(k, in_flight),
        },
        gpu_ms_lighting_median: lighting,
        gpu_ms_project_median: 0.0,
        gpu_ms_sharp_median: sharp_ms,
        gpu_ms_shade_median: shade_ms,
        fps: 1000.0 / (lighting + shade_ms + sharp_ms),
        brdf: cfg.brdf,
        camera: Some(camera.to_array()),
        view_grid: match &view {
            ViewBasis::Grid(g) => Some(g.n),
            ViewBasis::Brdf(_) => None,
        },
        view_terms: (view.terms() > 0).then_some(view.terms()),
        view_truncation: match &view {
            ViewBasis::Grid(_) => None,
            ViewBasis::Brdf(f) => Some(f.truncation),
        },
        reference: cfg
            .reference
            .then(|| reference_info(cfg.reference_width, truth_env, env, &truth_ms)),
        frames,
        notes,
    };
    crate::io::write_json(&cfg.out.join("report.json"), &report)?;
    Ok(report)
}

/// The kernel of a glossy run: uncompressed or CTA-compressed transfer.
enum GlossyOrCta {
    Glossy(GlossyKernel),
    Cta(CtaKernel),
}

/// The progress line saying how many compact lobes are shaded directly (`how`: e.g. " with
/// the BRDF toward the camera") and how they are shadowed.
fn compact_note(cfg: &ShadeConfig, points: &[bool], basis_sharpness: f32, how: &str) -> String {
    let count = points.len();
    let resolved = points.iter().filter(|p| !**p).count();
    format!(
        "{count} compact lobes (sharpness > {} x {basis_sharpness:.1}, >= {}% of the energy) \
         shaded directly{how}, {}",
        cfg.sharp_factor,
        crate::kernels::srbf::sharp::MIN_SHARE * 100.0,
        match cfg.sun {
            SunMode::Rays => "each at its rotated axis, shadowed by a ray per vertex".to_string(),
            SunMode::Grid => format!(
                "shadowed from the visibility grid: {} point sources (one tap at the texel \
                 holding the axis), {resolved} resolved by the fit (spread over the 2 x 2 \
                 texels around the axis)",
                count - resolved
            ),
        }
    )
}

/// The progress line of [`visibility_for`].
fn visibility_line(vis: &Visibility, cached: bool, ms: f64) -> String {
    format!(
        "visibility: {} vertices x {} directions{}",
        vis.vertices,
        vis.directions.len(),
        cost(cached, ms)
    )
}

/// " (cached)" or " (N ms)": where a precomputed result came from.
fn cost(cached: bool, ms: f64) -> String {
    if cached {
        " (cached)".to_string()
    } else {
        format!(" ({ms:.0} ms)")
    }
}

/// The kernel over a run's precomputed inputs, and what each frame needs besides.
struct Session<'a> {
    ctx: &'a Context,
    cfg: &'a ShadeConfig,
    mesh: &'a Mesh,
    pre: &'a Precomputed,
    inputs: SrbfInputs<'a>,
    /// The lobes shaded through the basis (the others are compact).
    smooth: Vec<Lobe>,
    kernel: SrbfKernel,
    pictures: Pictures,
    /// Wall time of each frame's truth (ms).
    truth_ms: std::sync::Mutex<Vec<f64>>,
}

impl<'a> Session<'a> {
    /// Uploads the kernel's inputs (one submission).
    fn new(
        ctx: &'a Context,
        cfg: &'a ShadeConfig,
        mesh: &'a Mesh,
        pre: &'a Precomputed,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Session<'a>> {
        let mut setup = ctx.recorder("srbf setup")?;
        let compact = CompactInputs {
            visibility: &pre.vis,
            normals: &mesh.normals,
            width: pre.dir_env.width,
            height: pre.dir_env.height,
            factor: cfg.sharp_factor,
            max_lobes: cfg.compact_lobes,
            fit_width: pre.fit_width,
        };
        let mut inputs = SrbfInputs::new(&pre.fitted.lobes, &pre.cpca).with_compact(compact);
        if let Some(bvh) = &pre.bvh {
            inputs = inputs.with_rays(SunRays {
                positions: &mesh.positions,
                bvh,
                offset: sun_offset(&mesh.positions),
            });
        }
        let (smooth, compact) = inputs.split();
        let kernel = SrbfKernel::new(&mut setup, &inputs)?;
        if kernel.compact_count() > 0 {
            progress(&compact_note(
                cfg,
                &inputs.compact_points(&compact),
                pre.transfer.basis.sharpness,
                "",
            ));
        }
        setup.submit_and_wait()?;
        Ok(Session {
            ctx,
            cfg,
            mesh,
            pre,
            inputs,
            smooth,
            kernel,
            pictures: Pictures::new(cfg, mesh),
            truth_ms: std::sync::Mutex::new(Vec::new()),
        })
    }

    /// One frame the GPU completed: against the CPU pipeline and (with `--reference`) the
    /// ground truth split by stage; PLY and picture written.
    fn frame(&self, frame: &SrbfFrame, r: FrameResult<SrbfOutput>) -> Result<FrameReport> {
        let cfg = self.cfg;
        let cpu = self.inputs.cpu_pipeline(frame)?;
        let gpu: Vec<[f64; 3]> = r.output.iter().map(|c| c.map(|x| x as f64)).collect();
        // The truth over the direction map's texels (the stages are split against it), and
        // with --reference-width the truth over the reference map.
        let t0 = Instant::now();
        let grid_truth = if cfg.reference {
            Some(shade_ground_truth(
                &self.pre.dir_env,
                frame.rotation,
                self.mesh,
                Some(&self.pre.vis),
                cfg.albedo,
            )?)
        } else {
            None
        };
        let full_truth = match (&grid_truth, &self.pre.reference_env) {
            (Some(_), Some(e)) => Some(shade_ground_truth(
                e,
                frame.rotation,
                self.mesh,
                None,
                cfg.albedo,
            )?),
            _ => None,
        };
        if grid_truth.is_some() {
            self.truth_ms
                .lock()
                .map_err(|_| Error::InvalidArgument("truth timing lock poisoned".into()))?
                .push(t0.elapsed().as_secs_f64() * 1e3);
        }
        let stages = match &grid_truth {
            Some(t) => Some(self.stage_errors(frame, t)?),
            None => None,
        };
        let truth = full_truth.or(grid_truth.clone());
        let report = FrameReport {
            index: r.index,
            rotation: frame.rotation.to_cols_array(),
            gpu_ms_lighting: r.timings.get(PASS_LIGHTING).unwrap_or(f64::NAN),
            gpu_ms_project: r.timings.get(PASS_PROJECT).unwrap_or(f64::NAN),
            gpu_ms_sharp: r.timings.get(PASS_SHARP).unwrap_or(f64::NAN),
            gpu_ms_shade: r.timings.get(PASS_SHADE).unwrap_or(f64::NAN),
            gpu_ms_cta: None,
            gpu_vs_cpu: RelL2::of(&gpu, &cpu),
            vs_ground_truth: truth.as_ref().map(|t| RelL2::of(&gpu, t)),
            direction_map_vs_ground_truth: match (&self.pre.reference_env, &grid_truth, &truth) {
                (Some(_), Some(g), Some(t)) => Some(RelL2::of(g, t)),
                _ => None,
            },
            uncompressed_vs_ground_truth: match (&stages, &truth) {
                (Some(s), Some(t)) => Some(RelL2::of(&s.exact, t)),
                _ => None,
            },
            fit_share: stages.as_ref().map(|s| s.fit),
            transfer_share: stages.as_ref().map(|s| s.transfer),
            ply: String::new(),
            png: String::new(),
        };
        self.pictures
            .write(report, self.mesh, &gpu, truth.as_deref())
    }

    /// The error against the ground truth `truth` split by stage: the fit (the brute-force
    /// sum over the fitted lobes), the transfer projection and the compression.
    fn stage_errors(&self, frame: &SrbfFrame, truth: &[[f64; 3]]) -> Result<StageErrors> {
        let (pre, cfg) = (self.pre, self.cfg);
        // The uncompressed transfer: the basis path in f32, plus the compact lobes.
        let coeffs =
            transfer::lighting_coefficients(&self.smooth, frame.rotation, &pre.transfer.basis);
        let mut exact: Vec<[f64; 3]> = transfer::shade(&pre.transfer, &coeffs, frame.albedo)?
            .iter()
            .map(|c| c.map(|x| x as f64))
            .collect();
        self.inputs.add_compact(frame, &mut exact)?;
        let lobes = rasterise_lobes(&pre.fitted.lobes, frame.rotation, &pre.dir_env);
        let sg_truth = shade_brute_force_radiance(
            &pre.dir_env,
            &lobes,
            &self.mesh.normals,
            &pre.vis,
            cfg.albedo,
        )?;
        Ok(StageErrors {
            fit: RelL2::of(&sg_truth, truth),
            transfer: RelL2::of(&exact, &sg_truth),
            exact,
        })
    }

    /// The report of the run: inputs, precomputation, per-frame results and their medians.
    fn report(&self, env: &EnvMap, frames: Vec<FrameReport>, in_flight: usize) -> ShadeReport {
        let (cfg, pre) = (self.cfg, self.pre);
        let median = |f: &dyn Fn(&FrameReport) -> f64| {
            let mut v: Vec<f64> = frames.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let lighting = median(&|f| f.gpu_ms_lighting);
        let project_ms = median(&|f| f.gpu_ms_project);
        let sharp_ms = median(&|f| f.gpu_ms_sharp);
        let shade_ms = median(&|f| f.gpu_ms_shade);
        ShadeReport {
            tool: "vkshade srbf shade",
            machine: MachineInfo::of(self.ctx),
            mesh: cfg.mesh.display().to_string(),
            vertices: self.mesh.positions.len(),
            env: cfg.env.display().to_string(),
            env_size: [env.width, env.height],
            lobes: cfg.lobes,
            compact_lobes: self.kernel.compact_count(),
            sharp_factor: cfg.sharp_factor,
            sun: cfg.sun,
            basis: pre.transfer.basis.axes.len(),
            basis_sharpness: pre.transfer.basis.sharpness,
            albedo: cfg.albedo,
            fit_rel_l2: pre.fitted.rel_l2,
            fit_ms: pre.fit_ms,
            visibility_ms: pre.vis_ms,
            visibility_cached: pre.vis_cached,
            transfer_rel_l2: pre.transfer.projection_rel_l2,
            transfer_ms: pre.transfer_ms,
            transfer_cached: pre.transfer_cached,
            clusters: if cfg.components > 0 {
                pre.cpca.clusters
            } else {
                0
            },
            components: cfg.components,
            cpca_rel_l2: pre.cpca.rel_l2,
            cpca_ms: pre.cpca_ms,
            cpca_cached: pre.cpca_cached,
            transfer_bytes_per_vertex: pre.cpca.bytes_per_vertex(),
            directions: pre.vis.directions.len(),
            kernel: KernelInfo::of(&self.kernel, in_flight),
            gpu_ms_lighting_median: lighting,
            gpu_ms_project_median: project_ms,
            gpu_ms_sharp_median: sharp_ms,
            gpu_ms_shade_median: shade_ms,
            fps: 1000.0 / (lighting + project_ms + sharp_ms + shade_ms),
            brdf: Brdf::Diffuse,
            camera: None,
            view_grid: None,
            view_terms: None,
            view_truncation: None,
            reference: cfg.reference.then(|| {
                reference_info(
                    cfg.reference_width,
                    pre.reference_env.as_ref().unwrap_or(&pre.dir_env),
                    env,
                    &self.truth_ms.lock().map(|v| v.clone()).unwrap_or_default(),
                )
            }),
            frames,
            notes: self.notes(),
        }
    }

    fn notes(&self) -> Vec<String> {
        let dir_env = &self.pre.dir_env;
        let mut notes = Vec::new();
        if self.ctx.info().device_type == "CPU" {
            notes.push(
                "the device is a CPU implementation (lavapipe): times measure the CPU".into(),
            );
        }
        match &self.pre.reference_env {
            Some(e) if self.cfg.reference => notes.push(format!(
                "ground truth: every texel of the {}x{} map{} as a quadrature node (its                  direction rotated, its exact solid angle), visibility ray-cast per (vertex,                  texel), f64; the fit and transfer shares are measured against the {}x{}                  direction map's truth, direction_map_vs_ground_truth is that truth against                  this one",
                e.width,
                e.height,
                if e.width == self.pre.reference_width_of_env {
                    " (its own resolution)"
                } else {
                    " (solid-angle-weighted downsampling)"
                },
                dir_env.width,
                dir_env.height
            )),
            _ => notes.push(format!(
                "ground truth: {}x{} texel directions of the environment (solid-angle-weighted                  downsampling of the original, --reference-width directions), visibility                  ray-cast per direction, f64",
                dir_env.width, dir_env.height
            )),
        }
        notes
    }
}

/// report.json's `reference`: the map `truth_env` the truth integrated (`env` is the
/// loaded map) and the median of the frames' truth times.
fn reference_info(
    requested: ReferenceWidth,
    truth_env: &EnvMap,
    env: &EnvMap,
    ms: &[f64],
) -> ReferenceInfo {
    let mut v = ms.to_vec();
    v.sort_by(f64::total_cmp);
    ReferenceInfo {
        requested: requested.to_string(),
        width: truth_env.width,
        height: truth_env.height,
        texels: truth_env.texels.len(),
        full_resolution: truth_env.width == env.width,
        ms_median: v.get(v.len() / 2).copied().unwrap_or(f64::NAN),
    }
}

/// A frame's error against the direction map's ground truth by stage (see
/// [`FrameReport`]), and the uncompressed transfer's radiance.
struct StageErrors {
    exact: Vec<[f64; 3]>,
    fit: RelL2,
    transfer: RelL2,
}

/// The progress line of a frame: GPU times, GPU against CPU, and the errors against the
/// ground truth where there is one.
fn frame_line(report: &FrameReport) -> String {
    format!(
        "frame {}: lighting {:.3} + project {:.3} + sharp {:.3} + shade {:.3} ms GPU{}; GPU \
         vs CPU {:.1e}{}{}",
        report.index,
        report.gpu_ms_lighting,
        report.gpu_ms_project,
        report.gpu_ms_sharp,
        report.gpu_ms_shade,
        match report.gpu_ms_cta {
            Some([l, p, s]) => format!(" (cta light {l:.3} + project {p:.3} + shade {s:.3})"),
            None => String::new(),
        },
        report.gpu_vs_cpu.all,
        match (
            report.vs_ground_truth,
            report.fit_share,
            report.transfer_share,
            report.uncompressed_vs_ground_truth
        ) {
            (Some(e), Some(f), Some(t), Some(u)) => format!(
                ", vs ground truth {:.4} (rgb {:.4} {:.4} {:.4}; by stage: fit {:.4}, \
                 transfer {:.4}, uncompressed {:.4})",
                e.all, e.rgb[0], e.rgb[1], e.rgb[2], f.all, t.all, u.all
            ),
            _ => String::new(),
        },
        match report.direction_map_vs_ground_truth {
            Some(g) => format!(
                "; direction-map truth vs this one {:.4} (rgb {:.4} {:.4} {:.4})",
                g.all, g.rgb[0], g.rgb[1], g.rgb[2]
            ),
            None => String::new(),
        }
    )
}

/// Writes each frame's PLY and PNG (result, or result | truth | relative error).
struct Pictures {
    out: PathBuf,
    view: crate::render::View,
    frame_points: Vec<Vec3>,
    error_scale: f32,
}

impl Pictures {
    /// Diffuse radiance is the same from every side: the fixed three-quarter view. Glossy
    /// radiance is computed toward the camera, so the picture looks along the camera's
    /// direction to the mesh's centre (the renderer is orthographic: a distant camera's view,
    /// with the radiance still toward the camera's position).
    fn new(cfg: &ShadeConfig, mesh: &Mesh) -> Pictures {
        let mut view = crate::render::View {
            width: cfg.image.0,
            height: cfg.image.1,
            ..Default::default()
        };
        if cfg.brdf.is_glossy() {
            let (lo, hi) = mesh.bounds();
            let camera = cfg.camera.unwrap_or_else(|| default_camera(mesh));
            if let Some(d) = ((lo + hi) * 0.5 - camera).try_normalize() {
                view.direction = d;
                // Looking straight up or down: the image's up is -Z instead of +Y.
                if d.cross(view.up).length() < 1e-3 {
                    view.up = Vec3::NEG_Z;
                }
            }
        }
        Pictures {
            out: cfg.out.clone(),
            view,
            frame_points: mesh.positions.clone(),
            error_scale: cfg.error_scale,
        }
    }

    fn write(
        &self,
        mut report: FrameReport,
        mesh: &Mesh,
        gpu: &[[f64; 3]],
        truth: Option<&[[f64; 3]]>,
    ) -> Result<FrameReport> {
        use crate::render::{rasterize, shade_rgb, side_by_side};
        let png = self.out.join(format!("shade_{:04}.png", report.index));
        let ply = png.with_extension("ply");
        let channel =
            |v: &[[f64; 3]], c: usize| -> Vec<f32> { v.iter().map(|x| x[c] as f32).collect() };
        let (r, g, b) = (channel(gpu, 0), channel(gpu, 1), channel(gpu, 2));
        crate::scene::ply_write::write_ply_properties(
            &ply,
            "vkshade srbf shade: linear RGB outgoing radiance per vertex",
            &mesh.positions,
            &mesh.normals,
            &mesh.triangles,
            &[("r", &r), ("g", &g), ("b", &b)],
        )?;
        // Exposure: the 99th percentile of the luminance maps to 0.9.
        let exposure = {
            let mut lum: Vec<f64> = gpu
                .iter()
                .map(|c| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
                .collect();
            lum.sort_by(f64::total_cmp);
            let p99 = lum
                .get(lum.len() * 99 / 100)
                .copied()
                .unwrap_or(1.0)
                .max(1e-9);
            (0.9 / p99) as f32
        };
        let raster = |v: &[f32]| {
            rasterize(
                &mesh.positions,
                &mesh.triangles,
                v,
                &self.frame_points,
                &self.view,
            )
        };
        let picture_of = |v: &[[f64; 3]]| {
            let (r, g, b) = (channel(v, 0), channel(v, 1), channel(v, 2));
            shade_rgb([&raster(&r), &raster(&g), &raster(&b)], exposure)
        };
        let picture = match truth {
            None => picture_of(gpu)?,
            Some(truth) => {
                let scale = truth
                    .iter()
                    .map(|c| c[0].max(c[1]).max(c[2]))
                    .fold(0f64, f64::max)
                    .max(1e-12);
                // Error relative to the brightest truth value (a per-vertex relative error
                // explodes in the shadows, where both are near zero).
                let err: Vec<f32> = gpu
                    .iter()
                    .zip(truth)
                    .map(|(a, t)| {
                        ((0..3).map(|c| (a[c] - t[c]).abs()).fold(0f64, f64::max) / scale) as f32
                    })
                    .collect();
                side_by_side(
                    &picture_of(gpu)?,
                    &picture_of(truth)?,
                    &raster(&err).value,
                    self.error_scale,
                )?
            }
        };
        crate::render::write_png(&png, picture.width, picture.height, &picture.rgb)?;
        report.ply = ply.display().to_string();
        report.png = png.display().to_string();
        Ok(report)
    }
}

/// What `vkshade srbf fit` writes.
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    pub tool: &'static str,
    pub env: String,
    /// What loading the map changed (codec ringing removed), if anything.
    pub hdr_repair: Option<crate::scene::envmap::RingingRepair>,
    pub fit_size: [u32; 2],
    /// (lobes, solid-angle-weighted relative L2, per channel, ms) for each lobe count tried.
    pub errors: Vec<(usize, f64, [f64; 3], f64)>,
    pub lobes: Vec<Lobe>,
}

/// Runs `vkshade srbf fit`: fits 8, 16, ... up to `lobes` lobes (reporting each error) and
/// writes the largest fit to `out`.
pub fn fit_command(
    env: &Path,
    hdr: crate::scene::envmap::HdrPolicy,
    lobes: usize,
    fit_width: u32,
    out: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<FitReport> {
    if !(1..=4096).contains(&lobes) {
        return Err(Error::InvalidArgument(format!(
            "--lobes must be in 1..=4096, not {lobes}"
        )));
    }
    if fit_width < 2 || !fit_width.is_multiple_of(2) {
        return Err(Error::InvalidArgument(format!(
            "--fit-width must be even and at least 2, not {fit_width}"
        )));
    }
    crate::io::check_writable(out)?;
    let map = super::load_env(env, hdr, progress)?;
    let small = map.downsampled(fit_width.min(map.width))?;
    let samples = small.samples();
    let mut counts: Vec<usize> = std::iter::successors(Some(8usize), |n| Some(n * 2))
        .take_while(|&n| n < lobes)
        .collect();
    counts.push(lobes);
    let mut errors = Vec::new();
    let mut last = None;
    for n in counts {
        let t = Instant::now();
        let f = fit(
            &samples,
            &FitConfig {
                lobes: n,
                ..FitConfig::default()
            },
        )?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "{n} lobes: relative L2 {:.4} ({ms:.0} ms)",
            f.rel_l2
        ));
        errors.push((n, f.rel_l2, f.rel_l2_per_channel, ms));
        last = Some(f);
    }
    let report = FitReport {
        tool: "vkshade srbf fit",
        env: env.display().to_string(),
        hdr_repair: map.repair.clone(),
        fit_size: [small.width, small.height],
        errors,
        lobes: last.map(|f| f.lobes).unwrap_or_default(),
    };
    // JSON has no NaN (serde writes null): refuse rather than write a fit nobody can use.
    let bad_lobe = report.lobes.iter().enumerate().find_map(|(i, l)| {
        let values = l.axis.iter().chain([&l.sharpness]).chain(&l.amplitude);
        values.clone().position(|x| !x.is_finite()).map(|c| {
            format!(
                "lobe {i}, value {c} (axis x, y, z, sharpness, amplitude r, g, b) is {}",
                values.clone().nth(c).copied().unwrap_or(f32::NAN)
            )
        })
    });
    let bad_error = report
        .errors
        .iter()
        .find(|e| !(e.1.is_finite() && e.2.iter().all(|c| c.is_finite())))
        .map(|e| format!("the {}-lobe fit's relative L2 is {}", e.0, e.1));
    if let Some(m) = bad_lobe.or(bad_error) {
        return Err(Error::input(
            out,
            format!(
                "not written: the fit to {} is not finite: {m}",
                env.display()
            ),
        ));
    }
    crate::io::write_json(out, &report)?;
    Ok(report)
}

/// The subcommands of `vkshade srbf`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum Command {
    /// Fit spherical Gaussians to an equirectangular HDR environment (EXR or .hdr); reports
    /// the fit error for 8, 16, ... up to --lobes lobes and writes the largest fit as JSON.
    Fit {
        #[arg(long, default_value = DEFAULT_ENV)]
        env: PathBuf,
        #[arg(long, default_value_t = 64)]
        lobes: usize,
        /// Width of the downsampled map the lobes are fitted to.
        #[arg(long, default_value_t = 128)]
        fit_width: u32,
        #[arg(short = 'o', long, default_value = "out/srbf-fit.json")]
        out: PathBuf,
        #[command(flatten)]
        hdr: super::Hdr,
    },
    /// Shade a mesh under a rotated environment: per frame DIR/shade_NNNN.ply (per-vertex
    /// linear RGB radiance r, g, b) and DIR/shade_NNNN.png (with --reference: result |
    /// brute-force truth | error), and DIR/report.json.
    Shade(Box<ShadeArgs>),
}

/// The arguments of `vkshade srbf shade`.
#[derive(clap::Args, Clone, Debug)]
pub struct ShadeArgs {
    /// Mesh (.obj .ply .off .glb/.gltf; a skinned mesh is shaded in its bind pose).
    #[arg(long, default_value = DEFAULT_MESH)]
    pub mesh: PathBuf,
    /// Equirectangular environment (EXR, including DWAB, or Radiance .hdr).
    #[arg(long, default_value = DEFAULT_ENV)]
    pub env: PathBuf,
    #[arg(long, default_value_t = 64)]
    pub lobes: usize,
    /// Transfer basis functions (spherical Gaussians on a Fibonacci lattice).
    #[arg(long, default_value_t = 256)]
    pub basis: usize,
    /// Clusters of the clustered-PCA transfer compression (at least 1).
    #[arg(long, default_value_t = 64, value_parser = super::at_least_one)]
    pub clusters: usize,
    /// Principal components per cluster (0: the uncompressed transfer).
    #[arg(long, default_value_t = 16)]
    pub components: usize,
    /// Rotate the environment, e.g. y:30 (L_R(w) = L(R^-1 w)); with --frames, the start of a
    /// spin about that axis.
    #[arg(long)]
    pub rotate: Option<AxisAngle>,
    /// Frames of a continuous 360-degree spin (about +Y, or --rotate's axis).
    #[arg(long, default_value_t = 1)]
    pub frames: usize,
    /// Diffuse albedo R,G,B (default 1,1,1).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 1.0, 1.0])]
    pub albedo: Vec<f32>,
    /// Compare each frame with the brute-force integration of the rotated map (f64).
    #[arg(long)]
    pub reference: bool,
    /// Resolution of --reference's truth: `directions` (the --directions map, 64 x 32 by
    /// default: cheap, but a sun becomes a 5.6-degree texel), `full` (every texel of the map
    /// at its own resolution: one ray per vertex and texel, 256x the rays of 64 x 32 at
    /// 1024 x 512), or a width that divides the map's.
    #[arg(long, default_value = "directions")]
    pub reference_width: ReferenceWidth,
    /// Width of the map whose texel directions carry the transfer and the ground truth.
    #[arg(long, default_value_t = 64)]
    pub directions: u32,
    /// Width of the downsampled map the lobes are fitted to.
    #[arg(long, default_value_t = 128)]
    pub fit_width: u32,
    /// Lobes sharper than this factor x the basis sharpness (a sun, a lamp) are shaded from
    /// the ray-cast visibility instead of through the smooth transfer basis (0: off).
    #[arg(long, default_value_t = crate::kernels::srbf::sharp::DEFAULT_FACTOR)]
    pub sharp_factor: f32,
    /// The most compact lobes shaded from the visibility, the strongest first (0: off).
    #[arg(long, default_value_t = crate::kernels::srbf::sharp::DEFAULT_MAX_LOBES)]
    pub compact_lobes: usize,
    /// How compact lobes are shadowed: grid (the precomputed visibility of the
    /// --directions grid's texel holding the lobe's rotated axis: a sun between grid
    /// directions takes its neighbour's shadow) or rays (a shadow ray per vertex and compact
    /// lobe at its exact rotated direction, every frame, against a BVH of the mesh: exact
    /// at any rotation, ~15 ms a frame for the bunny on lavapipe).
    #[arg(long, value_enum, default_value_t = SunMode::Grid)]
    pub sun: SunMode,
    #[arg(long, default_value_t = 2)]
    pub in_flight: usize,
    #[arg(long, default_value = "out/srbf")]
    pub out: PathBuf,
    #[command(flatten)]
    pub hdr: super::Hdr,
    /// The surface's BRDF: diffuse, or phong (kd / pi + ks (n + 2) / (2 pi) cos^n of the
    /// angle to the mirror direction; --exponent, --kd, --ks): glossy, shaded toward
    /// --camera through per-vertex transfer matrices over a view basis (--terms or --views).
    #[arg(long, value_enum, default_value_t = BrdfKind::Diffuse)]
    pub brdf: BrdfKind,
    /// Phong exponent n.
    #[arg(long, default_value_t = 8.0)]
    pub exponent: f32,
    /// Phong diffuse part kd (kd + ks <= 1).
    #[arg(long, default_value_t = 0.3)]
    pub kd: f32,
    /// Phong specular part ks.
    #[arg(long, default_value_t = 0.7)]
    pub ks: f32,
    /// Camera position X,Y,Z in model units (glossy; default: 1.5 bounding-box diagonals
    /// along +Z from the box's centre).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub camera: Option<Vec<f32>>,
    /// Glossy view basis: the first M terms of the BRDF's separable factorisation (SVD of
    /// rho cos over view and light hemispheres; default 24).
    #[arg(long, conflicts_with = "views")]
    pub terms: Option<usize>,
    /// Glossy view basis: an N x N parabolic grid of view directions, interpolated
    /// bilinearly (instead of --terms).
    #[arg(long)]
    pub views: Option<u32>,
    /// Glossy: compress the transfer by clustered tensor approximation (Tsai and Shih 2006)
    /// and reconstruct it per vertex on the GPU each frame.
    #[arg(long)]
    pub cta: bool,
    /// CTA clusters.
    #[arg(long, default_value_t = 64)]
    pub cta_clusters: usize,
    /// CTA core ranks VERTEX,VIEW,LIGHT (the view rank is capped at the view basis' rows:
    /// 24 keeps every BRDF term of the default basis).
    #[arg(long, value_delimiter = ',', default_values_t = [8usize, 24, 32])]
    pub cta_ranks: Vec<usize>,
    /// CTA reassignment + refit rounds.
    #[arg(long, default_value_t = 2)]
    pub cta_iterations: usize,
}

/// `--sun`: how compact lobes (a sun) are shadowed.
#[derive(clap::ValueEnum, serde::Serialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum SunMode {
    /// A shadow ray per vertex and compact lobe at its exact rotated direction, each frame.
    Rays,
    /// The visibility grid's texel holding the lobe's rotated axis.
    Grid,
}

/// `--brdf`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BrdfKind {
    Diffuse,
    Phong,
}

impl Command {
    /// Runs `vkshade srbf fit|shade` and prints its summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        match self {
            Command::Fit {
                env,
                lobes,
                fit_width,
                out,
                hdr,
            } => {
                let r = fit_command(env, hdr.policy(), *lobes, *fit_width, out, &mut |l| {
                    super::progress(l)
                })?;
                println!(
                    "fitted {} lobes to {} ({}x{}): relative L2 {:.4}; wrote {}",
                    r.lobes.len(),
                    r.env,
                    r.fit_size[0],
                    r.fit_size[1],
                    r.errors.last().map(|e| e.1).unwrap_or(f64::NAN),
                    out.display()
                );
                Ok(())
            }
            Command::Shade(a) => a.run(gpu),
        }
    }
}

impl ShadeArgs {
    /// The run these arguments describe.
    pub fn config(&self) -> Result<ShadeConfig> {
        let albedo: [f32; 3] = self
            .albedo
            .as_slice()
            .try_into()
            .map_err(|_| Error::InvalidArgument("--albedo takes three values R,G,B".into()))?;
        // Checked whatever --brdf says: a NaN given to a flag the diffuse BRDF does not
        // read is still a mistake in the command line.
        for (flag, v) in [
            ("--exponent", self.exponent),
            ("--kd", self.kd),
            ("--ks", self.ks),
        ] {
            if !v.is_finite() {
                return Err(Error::InvalidArgument(format!(
                    "{flag} {v} is not a finite number"
                )));
            }
        }
        Ok(ShadeConfig {
            mesh: self.mesh.clone(),
            env: self.env.clone(),
            lobes: self.lobes,
            basis: self.basis,
            clusters: self.clusters,
            components: self.components,
            rotate: self.rotate,
            frames: self.frames,
            albedo,
            reference: self.reference,
            reference_width: self.reference_width,
            direction_width: self.directions,
            fit_width: self.fit_width,
            sharp_factor: self.sharp_factor,
            compact_lobes: self.compact_lobes,
            sun: self.sun,
            in_flight: self.in_flight,
            out: self.out.clone(),
            hdr: self.hdr.policy(),
            brdf: match self.brdf {
                BrdfKind::Diffuse => Brdf::Diffuse,
                BrdfKind::Phong => Brdf::Phong {
                    exponent: self.exponent,
                    diffuse: self.kd,
                    specular: self.ks,
                },
            },
            camera: match &self.camera {
                None => None,
                Some(c) => Some(Vec3::from_slice(c.as_slice().get(..3).ok_or_else(
                    || Error::InvalidArgument("--camera takes three values X,Y,Z".into()),
                )?)),
            },
            view: ViewSpec::from_args(self.views, self.terms),
            cta: if self.cta {
                Some(CtaConfig {
                    clusters: self.cta_clusters,
                    ranks: self.cta_ranks.as_slice().try_into().map_err(|_| {
                        Error::InvalidArgument(
                            "--cta-ranks takes three values VERTEX,VIEW,LIGHT".into(),
                        )
                    })?,
                    iterations: self.cta_iterations,
                    ..CtaConfig::default()
                })
            } else {
                None
            },
            ..Default::default()
        })
    }

    /// `vkshade srbf shade`: shades the frames and prints the summary.
    pub fn run(&self, gpu: &Gpu) -> Result<()> {
        let cfg = self.config()?;
        let ctx = gpu.context()?;
        eprintln!("vkshade srbf shade on {}", ctx.info().name);
        let r = shade(&ctx, &cfg, &mut |l| super::progress(l))?;
        display(&r, &cfg);
        super::finish(ctx)
    }
}

/// The summary `vkshade srbf shade` prints: timings, the error of each stage, the worst
/// frame against the ground truth (with `--reference`) and what was written.
pub fn display(r: &ShadeReport, cfg: &ShadeConfig) {
    println!(
        "{} frames of {} ({} vertices), {} lobes ({} compact) x {} basis ({} clusters x {} components): lighting {:.3} + project {:.3} + sharp {:.3} + shade {:.3} ms GPU (median) = {:.0} fps; fit error {:.4}, transfer projection error {:.4}, compression error {:.4}",
        r.frames.len(),
        r.mesh,
        r.vertices,
        r.lobes,
        r.compact_lobes,
        r.basis,
        r.clusters,
        r.components,
        r.gpu_ms_lighting_median,
        r.gpu_ms_project_median,
        r.gpu_ms_sharp_median,
        r.gpu_ms_shade_median,
        r.fps,
        r.fit_rel_l2,
        r.transfer_rel_l2,
        r.cpca_rel_l2
    );
    if let Some(c) = r.camera {
        let basis = match (r.view_grid, r.view_terms) {
            (Some(n), _) => format!("a {n} x {n} view grid"),
            (None, Some(m)) => format!(
                "{m} BRDF terms (truncation {:.4})",
                r.view_truncation.unwrap_or(f64::NAN)
            ),
            (None, None) => "?".into(),
        };
        println!(
            "glossy {:?}: shaded toward the camera at {c:?} (model units) through {basis}",
            r.brdf
        );
    }
    if let Some(worst) = r
        .frames
        .iter()
        .filter_map(|f| f.vs_ground_truth.map(|e| e.all))
        .reduce(f64::max)
    {
        let at = r.reference.as_ref().map_or(String::new(), |i| {
            format!(
                " ({}x{}{})",
                i.width,
                i.height,
                if i.full_resolution {
                    ", the map's own resolution"
                } else {
                    ""
                }
            )
        });
        println!("vs brute-force ground truth{at}: relative L2 at most {worst:.4} over the frames");
    }
    println!(
        "wrote shade_NNNN.ply, shade_NNNN.png and report.json to {}",
        cfg.out.display()
    );
}
