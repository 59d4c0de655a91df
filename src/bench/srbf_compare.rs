//! `vkshade bench srbf --compare`: clustered tensor approximation (CTA, Tsai and Shih 2006)
//! against clustered PCA (CPCA, Sloan et al. 2003) and the uncompressed transfer, on the
//! same mesh, map, lighting lobes and projected transfer, at matched bytes of transfer
//! streamed per vertex, diffuse and glossy: error against the brute-force truth, bytes per
//! vertex (streamed, and with the cluster tables), median GPU time (timestamp queries) where
//! a GPU path exists, the CPU twin's time and the compression time.
//!
//! Matching (`bytes`, each B = 4 + payload: a u32 cluster id and the per-vertex weights):
//! every method streams its per-vertex values in half precision: CTA r_v coefficients
//! (r_v = (B - 4) / 2), diffuse CPCA M weights (M = (B - 4) / 2), glossy CPCA
//! ([`MatrixCpca`], whole V x K matrices per vertex) M weights (M = (B - 4) / 2), each
//! CPU twin rounding them to half precision as a GPU would hold them. CTA reports the bytes
//! its GPU reads (whole texels of eight coefficients, the cluster id inside the last one
//! where it has room: `Cta::bytes_per_vertex`), which are B at the default points. Both
//! methods use the same cluster count. CPCA keeps a mean per cluster;
//! plain Tucker (CTA) has none.
//!
//! Matched streamed bytes alone favour glossy CPCA: each of its clusters holds M + 1 whole
//! V x K matrices, so at the same cluster count its tables are several times CTA's. So each
//! glossy CTA point is also matched in total storage (streamed + tables amortised): CPCA
//! with the same M and as many clusters as CTA's total pays for (`cpca-total`; none when the
//! full cluster count already fits, or one cluster does not).
//!
//! Error: relative L2 over vertices of the shaded linear RGB radiance (albedo 1), all three
//! channels together (`error`) and per channel (`error_rgb`), against
//! [`shade_ground_truth`] / [`shade_glossy_truth`] over the map at `truth_width` (f64, every
//! texel, visibility ray-cast along each rotated direction), averaged over `rotations` (off
//! the direction grid). Each method's error is its CPU twin's (the GPU kernels agree with
//! their twins to ~1e-6, tests/srbf.rs and tests/srbf_glossy.rs). Every lobe goes through
//! the basis (no compact lobes), for every method alike.

use super::{BenchConfig, MachineInfo, time_cpu, time_passes};
use crate::error::{Error, Result};
use crate::geom::brdf::Brdf;
use crate::geom::sg::{self, Lobe};
use crate::gpu::Context;
use crate::kernels::Kernel;
use crate::kernels::srbf::cpca::{Cpca, CpcaConfig};
use crate::kernels::srbf::cpca_matrix::MatrixCpca;
use crate::kernels::srbf::cta::{Cta, CtaConfig};
use crate::kernels::srbf::cta_gpu::{CtaInputs, CtaKernel};
use crate::kernels::srbf::fit::{FitConfig, fit};
use crate::kernels::srbf::glossy::{DEFAULT_VIEW, GlossyTransfer, ViewSpec};
use crate::kernels::srbf::glossy_gpu::{GlossyFrame, GlossyInputs, GlossyKernel};
use crate::kernels::srbf::gpu::{SrbfFrame, SrbfInputs};
use crate::kernels::srbf::transfer::{Basis, Transfer, lighting_coefficients};
use crate::kernels::srbf::{diffuse_transfer, glossy_transfer};
use crate::reference::srbf::{shade_glossy_truth, shade_ground_truth};
use crate::scene::envmap::{EnvMap, texel_visibility};
use glam::{Mat3, Vec3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `bench srbf --compare` measures.
#[derive(Clone, Debug, Serialize)]
pub struct CompareConfig {
    pub mesh: PathBuf,
    pub env: PathBuf,
    pub bench: BenchConfig,
    pub lobes: usize,
    pub basis: usize,
    /// Width of the map the lobes are fitted to.
    pub fit_width: u32,
    /// Width of the direction map the transfer is projected over.
    pub direction_width: u32,
    /// Width of the map the truth integrates (`None`: the map's own resolution).
    pub truth_width: Option<u32>,
    /// The glossy view basis.
    pub view: ViewSpec,
    pub brdf: Brdf,
    /// Storage points: bytes of transfer streamed per vertex (cluster id included).
    pub bytes: Vec<usize>,
    /// Clusters of both methods.
    pub clusters: usize,
    /// CTA's view and light ranks (glossy; diffuse uses (r_v, 1, r_v)).
    pub cta_view_rank: usize,
    pub cta_light_rank: usize,
    pub cta_iterations: usize,
    /// Environment rotations (axis, degrees), off the direction grid.
    pub rotations: Vec<([f32; 3], f32)>,
    pub diffuse: bool,
    pub glossy: bool,
    /// Cache of the projected transfers, and where the JSON, table and plot go.
    pub out: PathBuf,
    pub cpu_runs: usize,
}

impl Default for CompareConfig {
    fn default() -> Self {
        CompareConfig {
            mesh: PathBuf::from("data/testwuson.glb"),
            env: PathBuf::from(crate::kernels::srbf::DEFAULT_ENV),
            bench: BenchConfig::default(),
            lobes: 64,
            basis: 256,
            fit_width: 128,
            direction_width: 64,
            truth_width: Some(256),
            view: DEFAULT_VIEW,
            brdf: Brdf::Phong {
                exponent: 8.0,
                diffuse: 0.3,
                specular: 0.7,
            },
            bytes: vec![20, 36, 68, 132],
            clusters: 16,
            cta_view_rank: 24,
            cta_light_rank: 32,
            cta_iterations: 2,
            rotations: vec![([0.0, 1.0, 0.0], 40.0), ([1.0, 0.0, 0.0], 25.0)],
            diffuse: true,
            glossy: true,
            out: PathBuf::from("out/bench-srbf-compare"),
            cpu_runs: 3,
        }
    }
}

impl CompareConfig {
    pub fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidArgument(format!("bench srbf --compare: {m}")));
        if self.bytes.is_empty()
            || self
                .bytes
                .iter()
                .any(|b| !(8..=4 + 2 * 64).contains(b) || b % 2 != 0)
        {
            return bad(format!(
                "--bytes {:?}: each point must be even and in 8..=132 (4 bytes of cluster id \
                 plus 2 to 64 half-precision coefficients)",
                self.bytes
            ));
        }
        if self.clusters == 0 || self.cta_view_rank == 0 || self.cta_light_rank == 0 {
            return bad("clusters and CTA ranks must be >= 1".into());
        }
        if !(self.diffuse || self.glossy) {
            return bad("nothing to compare (diffuse and glossy both off)".into());
        }
        self.view.check()?;
        self.view.check_for_cta()?;
        self.brdf.check()?;
        if !self.brdf.is_glossy() {
            return bad("the glossy BRDF must be glossy".into());
        }
        Ok(())
    }
}

/// One method at one storage point.
#[derive(Clone, Debug, Serialize)]
pub struct ComparePoint {
    /// diffuse or glossy.
    pub brdf: &'static str,
    /// uncompressed, cpca, cta, or cpca-total (glossy CPCA within CTA's total bytes).
    pub method: &'static str,
    pub settings: String,
    /// Weights per vertex (CPCA's M, CTA's r_v; the basis size x views uncompressed).
    pub per_vertex_values: usize,
    /// Bytes per vertex streamed each frame.
    pub stream_bytes_per_vertex: usize,
    /// The same with the per-cluster tables amortised over the vertices.
    pub amortised_bytes_per_vertex: f64,
    /// Function-space relative L2 of the compressed transfer against the projected one.
    pub transfer_rel_l2: f64,
    /// Relative L2 of the shaded radiance against the truth (all channels), mean over the
    /// rotations.
    pub error: f64,
    pub error_rgb: [f64; 3],
    pub compress_ms: f64,
    /// Median GPU time of one frame (sum of the passes' medians); `None` without a GPU path
    /// (see `gpu_note`).
    pub gpu_ms: Option<f64>,
    pub fps: Option<f64>,
    pub gpu_note: Option<String>,
    /// Median wall time of the CPU twin's frame.
    pub cpu_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct CompareReport {
    pub benchmark: &'static str,
    pub machine: MachineInfo,
    pub config: CompareConfig,
    pub vertices: usize,
    pub fit_rel_l2: f64,
    /// The truth's map size.
    pub truth_size: [u32; 2],
    pub truth_ms: f64,
    pub points: Vec<ComparePoint>,
    pub notes: Vec<String>,
}

/// sqrt(sum |a - b|^2 / sum |b|^2) per channel and over all channels.
fn rel_l2(a: &[[f64; 3]], b: &[[f64; 3]]) -> ([f64; 3], f64) {
    let (mut num, mut den) = ([0f64; 3], [0f64; 3]);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            num[c] += (x[c] - y[c]).powi(2);
            den[c] += y[c].powi(2);
        }
    }
    let r = |n: f64, d: f64| if d > 0.0 { (n / d).sqrt() } else { n.sqrt() };
    (
        [0, 1, 2].map(|c| r(num[c], den[c])),
        r(num.iter().sum(), den.iter().sum()),
    )
}

/// Mean over the rotations of the error of `shade(rotation index)` against `truths`.
fn error_over(
    truths: &[Vec<[f64; 3]>],
    mut shade: impl FnMut(usize) -> Result<Vec<[f64; 3]>>,
) -> Result<([f64; 3], f64)> {
    let (mut rgb, mut all) = ([0f64; 3], 0f64);
    for (i, t) in truths.iter().enumerate() {
        let (e, a) = rel_l2(&shade(i)?, t);
        for c in 0..3 {
            rgb[c] += e[c] / truths.len() as f64;
        }
        all += a / truths.len() as f64;
    }
    Ok((rgb, all))
}

/// Median GPU time of one frame of `kernel` (the passes' medians summed).
fn gpu_ms<K: Kernel>(
    ctx: &Context,
    cfg: &BenchConfig,
    kernel: &K,
    input: &K::Input,
) -> Result<f64> {
    Ok(time_passes(ctx, cfg, kernel, input)?
        .iter()
        .map(|(_, s)| s.median)
        .sum())
}

/// A projected transfer kept in `dir` under `name` beside a key file: reused while the key
/// (mesh, its size and mtime, basis, directions, and `extra`) is the same.
fn cached_transfer(
    dir: &Path,
    name: &str,
    key: String,
    rows: usize,
    basis: usize,
    compute: impl FnOnce() -> Result<Transfer>,
) -> Result<(Transfer, bool, f64)> {
    let path = dir.join(format!("{name}.bin"));
    let key_path = dir.join(format!("{name}.key"));
    if std::fs::read_to_string(&key_path).ok().as_deref() == Some(key.as_str())
        && let Ok(t) = Transfer::load(&path)
        && t.vertices == rows
        && t.basis.len() == basis
    {
        return Ok((t, true, 0.0));
    }
    let t0 = Instant::now();
    let t = compute()?;
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    t.save(&path)?;
    crate::io::write_atomic(&key_path, key.as_bytes())?;
    Ok((t, false, ms))
}

/// Runs the comparison (and writes nothing: see [`write_outputs`]).
pub fn run(
    ctx: &Context,
    cfg: &CompareConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<CompareReport> {
    cfg.check()?;
    crate::io::outdir::claim(&cfg.out, "bench srbf --compare")?;
    let character = crate::scene::load(&cfg.mesh)?;
    let mesh = &character.mesh;
    let nv = mesh.positions.len();
    let env = EnvMap::load(&cfg.env)?;
    progress(&format!(
        "{}: {nv} vertices; {}: {}x{}",
        cfg.mesh.display(),
        cfg.env.display(),
        env.width,
        env.height
    ));
    let fitted = fit(
        &env.downsampled(cfg.fit_width.min(env.width))?.samples(),
        &FitConfig {
            lobes: cfg.lobes,
            ..FitConfig::default()
        },
    )?;
    progress(&format!(
        "fit {} lobes: relative L2 {:.4}",
        cfg.lobes, fitted.rel_l2
    ));
    let lobes: &[Lobe] = &fitted.lobes;
    let dir_env = env.downsampled(cfg.direction_width.min(env.width))?;
    let truth_env = match cfg.truth_width {
        None => env.clone(),
        Some(w) if w == env.width => env.clone(),
        Some(w) => env.downsampled(w)?,
    };
    let vis = texel_visibility(mesh, &dir_env);
    let rotations: Vec<Mat3> = cfg
        .rotations
        .iter()
        .map(|(a, d)| sg::rotation(Vec3::from_array(*a), *d))
        .collect();
    let basis = Basis::fibonacci(cfg.basis);
    let mtime = std::fs::metadata(&cfg.mesh)
        .and_then(|m| m.modified())
        .map(|t| format!("{t:?}"))
        .unwrap_or_default();
    let key = |what: String| {
        format!(
            "{what} {} {nv} {mtime} {} {}",
            cfg.mesh.display(),
            cfg.basis,
            dir_env.width
        )
    };
    let limit = ctx.limits().max_storage_buffer_range;
    let mut points = Vec::new();
    let mut truth_ms = 0.0;
    let mut notes = vec![
        "error: relative L2 of the shaded RGB radiance (albedo 1) over all vertices and \
         channels, mean over the rotations, of each method's CPU twin against the f64 \
         brute-force truth; every lobe through the basis (no compact lobes)"
            .to_string(),
        "bytes: streamed = the compressed methods' per-vertex weights (f16) + a 4-byte \
         cluster id, the uncompressed rows (f32); amortised adds the per-cluster tables \
         (f32) divided by the vertex count"
            .to_string(),
    ];
    if ctx.info().device_type == "CPU" {
        notes.push(
            "the device is a CPU implementation (lavapipe): GPU times measure the CPU".into(),
        );
    }
    if cfg.diffuse {
        let (transfer, cached, ms) = cached_transfer(
            &cfg.out,
            "diffuse",
            key("diffuse".into()),
            nv,
            cfg.basis,
            || diffuse_transfer(&basis, &dir_env, &mesh.normals, &vis),
        )?;
        progress(&format!(
            "diffuse transfer{}",
            if cached {
                " (cached)".to_string()
            } else {
                format!(" ({ms:.0} ms)")
            }
        ));
        let t0 = Instant::now();
        let truths: Vec<Vec<[f64; 3]>> = rotations
            .iter()
            .map(|r| shade_ground_truth(&truth_env, *r, mesh, None, [1.0; 3]))
            .collect::<Result<_>>()?;
        truth_ms += t0.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "diffuse truth over {}x{} texels, {} rotations: {:.0} ms",
            truth_env.width,
            truth_env.height,
            rotations.len(),
            t0.elapsed().as_secs_f64() * 1e3
        ));
        let frames: Vec<SrbfFrame> = rotations
            .iter()
            .map(|&rotation| SrbfFrame {
                rotation,
                albedo: [1.0; 3],
            })
            .collect();
        // Uncompressed and CPCA through the shipped kernel.
        let cpca_point = |c: &Cpca,
                          method: &'static str,
                          settings: String,
                          compress_ms: f64|
         -> Result<ComparePoint> {
            let inputs = SrbfInputs::new(lobes, c);
            let (rgb, all) = error_over(&truths, |i| inputs.cpu_pipeline(&frames[i]))?;
            let cpu = time_cpu(cfg.cpu_runs, || inputs.cpu_pipeline(&frames[0]));
            let compressed = method != "uncompressed";
            let p = super::srbf::measure(ctx, &cfg.bench, lobes, c, None, compressed, f64::NAN)?;
            let stream = c.bytes_per_vertex();
            let tables = if compressed {
                4 * c.clusters * c.rows_per_cluster() * c.basis.len()
            } else {
                0
            };
            Ok(ComparePoint {
                brdf: "diffuse",
                method,
                settings,
                per_vertex_values: c.components,
                stream_bytes_per_vertex: if compressed { stream } else { 4 * cfg.basis },
                amortised_bytes_per_vertex: if compressed {
                    stream as f64 + tables as f64 / nv as f64
                } else {
                    (4 * cfg.basis) as f64
                },
                transfer_rel_l2: c.rel_l2,
                error: all,
                error_rgb: rgb,
                compress_ms,
                gpu_ms: Some(p.total_ms),
                fps: Some(p.fps),
                gpu_note: None,
                cpu_ms: cpu.median,
            })
        };
        let p = cpca_point(
            &Cpca::exact(&transfer),
            "uncompressed",
            format!("{} basis coefficients (f32)", cfg.basis),
            0.0,
        )?;
        progress(&line(&p));
        points.push(p);
        for &b in &cfg.bytes {
            let m = ((b - 4) / 2).min(cfg.basis);
            let settings = CpcaConfig {
                clusters: cfg.clusters,
                components: m,
                ..CpcaConfig::default()
            };
            let t0 = Instant::now();
            let c = Cpca::compress(&transfer, &settings)?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let p = cpca_point(
                &c,
                "cpca",
                format!("{} clusters x {m} components (f16)", c.clusters),
                ms,
            )?;
            progress(&line(&p));
            points.push(p);
        }
        for &b in &cfg.bytes {
            let rv = (b - 4) / 2;
            let ccfg = CtaConfig {
                clusters: cfg.clusters,
                ranks: [rv, 1, rv.min(cfg.basis)],
                iterations: cfg.cta_iterations,
                ..CtaConfig::default()
            };
            let t0 = Instant::now();
            let cta = Cta::compress(&basis, &transfer.coeffs, nv, 1, &ccfg)?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let eval = |rotation: Mat3| -> Result<Vec<[f64; 3]>> {
                let coeffs = lighting_coefficients(lobes, rotation, &basis);
                let m = cta.project(&coeffs)?;
                Ok((0..nv)
                    .map(|v| {
                        let c = cta.cluster_of[v] as usize;
                        let mut out = [0f64; 3];
                        for a in 0..rv {
                            let u = cta.coeff(v, a) as f64;
                            for ch in 0..3 {
                                out[ch] += u * m[c * rv + a][ch];
                            }
                        }
                        out
                    })
                    .collect())
            };
            let (rgb, all) = error_over(&truths, |i| eval(rotations[i]))?;
            let cpu = time_cpu(cfg.cpu_runs, || eval(rotations[0]));
            let (stream, amortised) = cta.bytes_per_vertex();
            let p = ComparePoint {
                brdf: "diffuse",
                method: "cta",
                settings: format!("{} clusters, ranks {:?} (f16 coefficients)", cta.clusters, cta.ranks),
                per_vertex_values: rv,
                stream_bytes_per_vertex: stream,
                amortised_bytes_per_vertex: amortised,
                transfer_rel_l2: cta.rel_l2,
                error: all,
                error_rgb: rgb,
                compress_ms: ms,
                gpu_ms: None,
                fps: None,
                gpu_note: Some(
                    "no diffuse CTA kernel (the CTA kernel shades glossy transfer, V >= 2 view rows)"
                        .into(),
                ),
                cpu_ms: cpu.median,
            };
            progress(&line(&p));
            points.push(p);
        }
    }
    if cfg.glossy {
        let view = cfg.view.build(&cfg.brdf)?;
        let views = view.views();
        let (rows, cached, ms) = cached_transfer(
            &cfg.out,
            "glossy",
            key(format!("glossy {:016x} {:?}", view.fingerprint(), cfg.brdf)),
            nv * views,
            cfg.basis,
            || {
                glossy_transfer(&basis, &cfg.brdf, &view, &dir_env, &mesh.normals, &vis)
                    .map(|g| g.rows)
            },
        )?;
        progress(&format!(
            "glossy transfer, {}{}",
            view.describe(),
            if cached {
                " (cached)".to_string()
            } else {
                format!(" ({ms:.0} ms)")
            }
        ));
        let transfer = GlossyTransfer {
            rows,
            vertices: nv,
            view: view.clone(),
            brdf: cfg.brdf,
        };
        transfer.check()?;
        let (lo, hi) = mesh.bounds();
        let camera = (lo + hi) * 0.5 + Vec3::Z * 1.5 * (hi - lo).length();
        let t0 = Instant::now();
        let truths: Vec<Vec<[f64; 3]>> = rotations
            .iter()
            .map(|r| {
                shade_glossy_truth(
                    &truth_env,
                    *r,
                    mesh,
                    &mesh.positions,
                    &mesh.normals,
                    &cfg.brdf,
                    camera,
                    [1.0; 3],
                )
            })
            .collect::<Result<_>>()?;
        truth_ms += t0.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "glossy truth over {}x{} texels, {} rotations: {:.0} ms",
            truth_env.width,
            truth_env.height,
            rotations.len(),
            t0.elapsed().as_secs_f64() * 1e3
        ));
        let frames: Vec<GlossyFrame> = rotations
            .iter()
            .map(|&rotation| GlossyFrame {
                rotation,
                albedo: [1.0; 3],
                camera,
            })
            .collect();
        let dense = GlossyInputs {
            lobes,
            transfer: &transfer,
            positions: &mesh.positions,
            normals: &mesh.normals,
            compact: None,
        };
        let (rgb, all) = error_over(&truths, |i| dense.cpu_pipeline(&frames[i]))?;
        let cpu = time_cpu(cfg.cpu_runs, || dense.cpu_pipeline(&frames[0]));
        let bytes = (nv * views * cfg.basis * 4) as u64;
        let (gpu, note) = if bytes <= limit {
            let mut setup = ctx.recorder("srbf compare glossy")?;
            let k = GlossyKernel::new(&mut setup, &dense)?;
            setup.submit_and_wait()?;
            (Some(gpu_ms(ctx, &cfg.bench, &k, &frames[0])?), None)
        } else {
            (
                None,
                Some(format!(
                    "{bytes} bytes of transfer exceed maxStorageBufferRange ({limit})"
                )),
            )
        };
        let p = ComparePoint {
            brdf: "glossy",
            method: "uncompressed",
            settings: format!("{views} views x {} basis coefficients (f32)", cfg.basis),
            per_vertex_values: views * cfg.basis,
            stream_bytes_per_vertex: transfer.bytes_per_vertex(),
            amortised_bytes_per_vertex: transfer.bytes_per_vertex() as f64,
            transfer_rel_l2: 0.0,
            error: all,
            error_rgb: rgb,
            compress_ms: 0.0,
            gpu_ms: gpu,
            fps: gpu.map(|ms| 1000.0 / ms),
            gpu_note: note,
            cpu_ms: cpu.median,
        };
        progress(&line(&p));
        points.push(p);
        // Glossy CPCA at M weights and `clusters` clusters (`method` names the series).
        let matrix_cpca_point =
            |m: usize, clusters: usize, method: &'static str| -> Result<ComparePoint> {
                let settings = CpcaConfig {
                    clusters,
                    components: m,
                    ..CpcaConfig::default()
                };
                let t0 = Instant::now();
                let c = MatrixCpca::compress(&basis, &transfer.rows.coeffs, nv, views, &settings)?;
                let ms = t0.elapsed().as_secs_f64() * 1e3;
                let eval = |rotation: Mat3, camera: Vec3| {
                    let coeffs = lighting_coefficients(lobes, rotation, &basis);
                    c.shade(
                        &coeffs,
                        &view,
                        &mesh.positions,
                        &mesh.normals,
                        camera,
                        [1.0; 3],
                    )
                };
                let (rgb, all) = error_over(&truths, |i| eval(rotations[i], camera))?;
                let cpu = time_cpu(cfg.cpu_runs, || eval(rotations[0], camera));
                let (stream, amortised) = c.bytes_per_vertex();
                Ok(ComparePoint {
                    brdf: "glossy",
                    method,
                    settings: format!(
                        "{} clusters x {m} components (f16) of {views} x {} matrices (f32)",
                        c.clusters, cfg.basis
                    ),
                    per_vertex_values: m,
                    stream_bytes_per_vertex: stream,
                    amortised_bytes_per_vertex: amortised,
                    transfer_rel_l2: c.rel_l2,
                    error: all,
                    error_rgb: rgb,
                    compress_ms: ms,
                    gpu_ms: None,
                    fps: None,
                    gpu_note: Some("no GPU path for matrix CPCA: CPU twin only".into()),
                    cpu_ms: cpu.median,
                })
            };
        for &b in &cfg.bytes {
            let p = matrix_cpca_point((b - 4) / 2, cfg.clusters, "cpca")?;
            progress(&line(&p));
            points.push(p);
        }
        // (B, streamed, total bytes per vertex) of each CTA point, for the matched CPCA below.
        let mut cta_totals = Vec::new();
        for &b in &cfg.bytes {
            let rv = (b - 4) / 2;
            let rw = cfg.cta_view_rank.min(views);
            let rl = cfg.cta_light_rank.min(cfg.basis);
            let ccfg = CtaConfig {
                clusters: cfg.clusters,
                ranks: [rv.min(rw * rl), rw, rl],
                iterations: cfg.cta_iterations,
                ..CtaConfig::default()
            };
            let t0 = Instant::now();
            let cta = Cta::compress(&basis, &transfer.rows.coeffs, nv, views, &ccfg)?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let inputs = CtaInputs {
                lobes,
                transfer: &cta,
                view: &view,
                positions: &mesh.positions,
                normals: &mesh.normals,
                compact: None,
            };
            let (rgb, all) = error_over(&truths, |i| inputs.cpu_pipeline(&frames[i]))?;
            let cpu = time_cpu(cfg.cpu_runs, || inputs.cpu_pipeline(&frames[0]));
            let mut setup = ctx.recorder("srbf compare cta")?;
            let k = CtaKernel::new(&mut setup, &inputs)?;
            setup.submit_and_wait()?;
            let gpu = gpu_ms(ctx, &cfg.bench, &k, &frames[0])?;
            let (stream, amortised) = cta.bytes_per_vertex();
            cta_totals.push((b, stream, amortised));
            let p = ComparePoint {
                brdf: "glossy",
                method: "cta",
                settings: format!(
                    "{} clusters, ranks {:?} (f16 coefficients)",
                    cta.clusters, cta.ranks
                ),
                per_vertex_values: cta.ranks[0],
                stream_bytes_per_vertex: stream,
                amortised_bytes_per_vertex: amortised,
                transfer_rel_l2: cta.rel_l2,
                error: all,
                error_rgb: rgb,
                compress_ms: ms,
                gpu_ms: Some(gpu),
                fps: Some(1000.0 / gpu),
                gpu_note: None,
                cpu_ms: cpu.median,
            };
            progress(&line(&p));
            points.push(p);
        }
        // CPCA at CTA's total storage as well as its streamed bytes: the same M, as many
        // clusters as CTA's amortised bytes pay for (a CPCA cluster holds M + 1 whole
        // matrices, so at matched streamed bytes alone its tables are several times CTA's).
        for (b, stream, total) in cta_totals {
            let m = (b - 4) / 2;
            let clusters = matrix_cpca_clusters_within(total, m, views, cfg.basis, nv);
            if clusters == 0 {
                notes.push(format!(
                    "glossy CPCA at CTA's total of {total:.1} B/vertex ({stream} streamed): \
                     one cluster's {} matrices of {views} x {} exceed it; no point",
                    m + 1,
                    cfg.basis
                ));
                continue;
            }
            if clusters >= cfg.clusters {
                notes.push(format!(
                    "glossy CPCA at CTA's total of {total:.1} B/vertex ({stream} streamed): \
                     the {}-cluster point already fits it",
                    cfg.clusters
                ));
                continue;
            }
            let p = matrix_cpca_point(m, clusters, "cpca-total")?;
            progress(&line(&p));
            points.push(p);
        }
    }
    Ok(CompareReport {
        benchmark: "vkshade bench srbf --compare",
        machine: MachineInfo::of(ctx),
        config: cfg.clone(),
        vertices: nv,
        fit_rel_l2: fitted.rel_l2,
        truth_size: [truth_env.width, truth_env.height],
        truth_ms,
        points,
        notes,
    })
}

/// The most clusters a glossy CPCA with `m` weights per vertex ([`MatrixCpca`]: M + 1
/// whole `views` x `basis` f32 matrices per cluster, M half-precision weights and a 4-byte
/// cluster id per vertex) can have while its bytes per vertex, tables amortised over
/// `vertices`, stay within `total` (0 when not even one cluster fits; at most `vertices`).
pub fn matrix_cpca_clusters_within(
    total: f64,
    m: usize,
    views: usize,
    basis: usize,
    vertices: usize,
) -> usize {
    // Bytes per vertex are affine in the cluster count: stream + clusters x one cluster's.
    let (stream, _) = MatrixCpca::storage(m, 0, views, basis, vertices);
    let per_cluster = MatrixCpca::storage(m, 1, views, basis, vertices).1 - stream as f64;
    let room = total - stream as f64;
    if room.is_nan() || room < per_cluster {
        return 0;
    }
    // At most one cluster per vertex (also keeps an infinite total from overflowing).
    let mut clusters = ((room / per_cluster).floor() as usize).min(vertices);
    // Guard the division's rounding: never a count whose bytes exceed the total.
    while clusters > 0 && MatrixCpca::storage(m, clusters, views, basis, vertices).1 > total {
        clusters -= 1;
    }
    clusters
}

/// One progress line.
fn line(p: &ComparePoint) -> String {
    format!(
        "  {} {} ({}): {} B/vertex streamed, {:.1} amortised; transfer error {:.4}; vs truth \
         {:.4} (rgb {:.4} {:.4} {:.4}); {}; CPU twin {:.2} ms; compression {:.0} ms",
        p.brdf,
        p.method,
        p.settings,
        p.stream_bytes_per_vertex,
        p.amortised_bytes_per_vertex,
        p.transfer_rel_l2,
        p.error,
        p.error_rgb[0],
        p.error_rgb[1],
        p.error_rgb[2],
        match (p.gpu_ms, p.fps) {
            (Some(ms), Some(fps)) => format!("GPU {ms:.3} ms = {fps:.0} fps"),
            _ => "no GPU time".to_string(),
        },
        p.cpu_ms,
        p.compress_ms
    )
}

/// The markdown table of the points.
pub fn table(r: &CompareReport) -> String {
    let mut s = format!(
        "# bench srbf --compare\n\n{} ({} vertices), {}, {} lobes, {} basis SGs, truth over \
         {}x{} texels, {} rotations; device {}\n\n| BRDF | method | settings | B/vertex \
         streamed | B/vertex amortised | transfer rel. L2 | rel. L2 vs truth (all) | r | g | \
         b | GPU ms | fps | CPU twin ms | compression ms |\n|---|---|---|---|---|---|---|---|\
         ---|---|---|---|---|---|\n",
        r.config.mesh.display(),
        r.vertices,
        r.config.env.display(),
        r.config.lobes,
        r.config.basis,
        r.truth_size[0],
        r.truth_size[1],
        r.config.rotations.len(),
        r.machine.device
    );
    for p in &r.points {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.1} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {} | {} | \
             {:.2} | {:.0} |\n",
            p.brdf,
            p.method,
            p.settings,
            p.stream_bytes_per_vertex,
            p.amortised_bytes_per_vertex,
            p.transfer_rel_l2,
            p.error,
            p.error_rgb[0],
            p.error_rgb[1],
            p.error_rgb[2],
            p.gpu_ms.map_or("-".into(), |x| format!("{x:.3}")),
            p.fps.map_or("-".into(), |x| format!("{x:.0}")),
            p.cpu_ms,
            p.compress_ms
        ));
    }
    s.push('\n');
    for n in &r.notes {
        s.push_str(&format!("- {n}\n"));
    }
    for p in r.points.iter().filter(|p| p.gpu_note.is_some()) {
        s.push_str(&format!(
            "- {} {} ({}): {}\n",
            p.brdf,
            p.method,
            p.settings,
            p.gpu_note.as_deref().unwrap_or_default()
        ));
    }
    s
}

/// The plot: error against bytes per vertex, streamed (top-level panels first) and with the
/// cluster tables amortised, one panel per BRDF, one curve per method, the uncompressed
/// error as a horizontal line across the points' range.
pub fn panels(r: &CompareReport) -> Vec<super::plot::Panel> {
    use super::plot::{Panel, Series};
    let mut out = Vec::new();
    for amortised in [false, true] {
        let x = |p: &ComparePoint| {
            if amortised {
                p.amortised_bytes_per_vertex
            } else {
                p.stream_bytes_per_vertex as f64
            }
        };
        for brdf in ["diffuse", "glossy"] {
            let pts: Vec<&ComparePoint> = r.points.iter().filter(|p| p.brdf == brdf).collect();
            let xs: Vec<f64> = pts
                .iter()
                .filter(|p| p.method != "uncompressed")
                .map(|p| x(p))
                .collect();
            if xs.is_empty() {
                continue;
            }
            let lo = xs.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = xs.iter().copied().fold(0.0, f64::max);
            let mut series = Vec::new();
            // Every method's series in every panel (empty where it has no points: the plot
            // skips it), so each keeps its colour across panels.
            for (method, name) in [
                ("cpca", format!("CPCA, {} clusters", r.config.clusters)),
                ("cpca-total", "CPCA within CTA's total bytes".to_string()),
                ("cta", format!("CTA, {} clusters", r.config.clusters)),
            ] {
                series.push(Series {
                    name,
                    points: pts
                        .iter()
                        .filter(|p| p.method == method)
                        .map(|p| (x(p), p.error))
                        .collect(),
                });
            }
            if let Some(u) = pts.iter().find(|p| p.method == "uncompressed") {
                series.push(Series {
                    name: format!("uncompressed ({} B)", u.stream_bytes_per_vertex),
                    points: vec![(lo, u.error), (hi, u.error)],
                });
            }
            out.push(Panel {
                title: format!(
                    "{brdf}, {} vertices: error vs bytes/vertex{}",
                    r.vertices,
                    if amortised { " (with tables)" } else { "" }
                ),
                x_label: if amortised {
                    "bytes per vertex, cluster tables amortised".into()
                } else {
                    "bytes of transfer streamed per vertex".into()
                },
                y_label: "relative L2 vs brute-force truth".into(),
                log_x: true,
                log_y: true,
                series,
            });
        }
    }
    out
}

/// Writes `compare.json`, `compare.md` and (with the `plots` feature) `compare.png` into
/// the output directory; returns the paths written.
pub fn write_outputs(r: &CompareReport) -> Result<Vec<PathBuf>> {
    let dir = &r.config.out;
    let json = dir.join("compare.json");
    crate::io::write_json(&json, r)?;
    let md = dir.join("compare.md");
    crate::io::write_atomic(&md, table(r).as_bytes())?;
    let mut written = vec![json, md];
    if super::plot::ensure_available().is_ok() {
        let png = dir.join("compare.png");
        super::plot::draw(&png, &panels(r))?;
        written.push(png);
    }
    Ok(written)
}
