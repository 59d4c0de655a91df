//! The SRBF kernel on the GPU: pass `srbf lighting` rotates the lighting lobes and computes
//! their coefficients in the transfer basis; pass `srbf project` projects them onto every
//! row of the clustered-PCA transfer (each cluster's mean and principal axes); pass
//! `srbf shade` shades every vertex from its cluster's projected rows and its weights. The
//! per-vertex result is an RGB radiance buffer that can also feed a renderer's vertex input.

use super::cpca::Cpca;
use super::sg::Lobe;
use super::{sharp, transfer};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use crate::reference::srbf::Visibility;
use ash::vk;
use glam::{Mat3, Vec3};

pub const PASS_LIGHTING: &str = "srbf lighting";
pub const PASS_PROJECT: &str = "srbf project";
pub const PASS_SHARP: &str = "srbf sharp";
pub const PASS_SHADE: &str = "srbf shade";
/// Most transfer basis functions (the size of the uniform coefficient array that `srbf
/// project` reads; a 16 KiB uniform buffer, the smallest maxUniformBufferRange Vulkan allows).
pub const MAX_BASIS: usize = 1024;
/// Most projected rows, [`rows_needed`] (`srbf shade`'s uniform array: 64 KiB,
/// the maxUniformBufferRange of lavapipe and of most desktop GPUs; checked at run time).
pub const MAX_ROWS: usize = 4096;
/// Invocations per workgroup of `srbf shade` (its local_size_x): one cluster per workgroup.
const SHADE_GROUP: usize = 64;
/// Most workgroups of `srbf shade` (its uniform workgroup-to-cluster table: 64 KiB).
pub const MAX_SHADE_GROUPS: usize = 16384;
/// Projected rows per cluster on the GPU: the mean, then the axes padded to whole groups of
/// eight (one uvec4 of half weights).
pub fn stride(components: usize) -> usize {
    1 + 8 * components.div_ceil(8)
}

/// Projected rows the GPU needs for `clusters` x `components`.
pub fn rows_needed(clusters: usize, components: usize) -> usize {
    clusters * stride(components)
}

/// A padding slot of `srbf shade`.
const NO_VERTEX: u32 = u32::MAX;

/// One frame's input: the environment's rotation and the surface albedo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SrbfFrame {
    /// L_R(w) = L(R^-1 w).
    pub rotation: Mat3,
    pub albedo: [f32; 3],
}

/// Most compact-lobe taps (`srbf shade`'s uniform array).
pub const MAX_TAPS: usize = 32;
const _: () = assert!(sharp::MAX_LOBES <= MAX_TAPS);

/// What the kernel is built from: the lighting lobes and the per-vertex transfer in
/// clustered-PCA form on a basis of spherical Gaussians ([`Cpca::exact`] for the
/// uncompressed transfer), and optionally the visibility that compact lobes are shaded from
/// ([`super::sharp`]).
pub struct SrbfInputs<'a> {
    pub lobes: &'a [Lobe],
    pub transfer: &'a Cpca,
    pub compact: Option<CompactInputs<'a>>,
}

/// The per-vertex data for shading compact lobes directly: the visibility cast for the
/// texel centres of a `width` x `height` equirectangular grid, the vertex normals, and the
/// sharpness factor and the most lobes to shade directly ([`super::sharp::split`]).
#[derive(Clone, Copy)]
pub struct CompactInputs<'a> {
    pub visibility: &'a Visibility,
    pub normals: &'a [Vec3],
    pub width: u32,
    pub height: u32,
    pub factor: f32,
    pub max_lobes: usize,
}

impl<'a> SrbfInputs<'a> {
    pub fn new(lobes: &'a [Lobe], transfer: &'a Cpca) -> Self {
        SrbfInputs {
            lobes,
            transfer,
            compact: None,
        }
    }

    /// The same, with compact lobes shaded from `compact`'s visibility.
    pub fn with_compact(mut self, compact: CompactInputs<'a>) -> Self {
        self.compact = Some(compact);
        self
    }

    /// (lobes through the basis, compact lobes).
    pub fn split(&self) -> (Vec<Lobe>, Vec<Lobe>) {
        match &self.compact {
            Some(c) => sharp::split(
                self.lobes,
                self.transfer.basis.sharpness,
                c.factor,
                c.max_lobes,
            ),
            None => (self.lobes.to_vec(), Vec::new()),
        }
    }

    /// The CPU twin of the whole GPU pipeline for one frame (f32 inputs, f64 results).
    pub fn cpu_pipeline(&self, frame: &SrbfFrame) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        let (smooth, compact) = self.split();
        let coeffs = transfer::lighting_coefficients(&smooth, frame.rotation, &self.transfer.basis);
        let mut out: Vec<[f64; 3]> = self
            .transfer
            .shade(&coeffs, frame.albedo)?
            .iter()
            .map(|c| c.map(|x| x as f64))
            .collect();
        self.add_taps(&compact, frame, &mut out)?;
        Ok(out)
    }

    /// Adds the compact lobes' radiance (albedo included) to `out` (one entry per vertex);
    /// nothing when there are none.
    pub fn add_compact(&self, frame: &SrbfFrame, out: &mut [[f64; 3]]) -> Result<()> {
        self.check_compact()?;
        let (_, compact) = self.split();
        self.add_taps(&compact, frame, out)
    }

    /// [`Self::add_compact`] for the compact lobes `compact` of checked inputs.
    fn add_taps(&self, compact: &[Lobe], frame: &SrbfFrame, out: &mut [[f64; 3]]) -> Result<()> {
        if let (Some(c), false) = (&self.compact, compact.is_empty()) {
            let taps = sharp::taps(compact, frame.rotation, c.width, c.height);
            let direct = sharp::shade(&taps, c.normals, c.visibility)?;
            for (o, d) in out.iter_mut().zip(direct) {
                for ch in 0..3 {
                    o[ch] += (frame.albedo[ch] * d[ch]) as f64;
                }
            }
        }
        Ok(())
    }

    /// Checks the compact-lobe inputs, if any (part of [`Self::check`]).
    fn check_compact(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        let Some(c) = &self.compact else {
            return Ok(());
        };
        sharp::check_grid(c.visibility, c.width, c.height)?;
        if c.width as u64 * c.height as u64 > 1 << 24 {
            return bad(format!(
                "compact lobes: a {} x {} grid has more texels than a float holds exactly",
                c.width, c.height
            ));
        }
        let vertices = self.transfer.vertices;
        if c.visibility.vertices != vertices || c.normals.len() != vertices {
            return bad(format!(
                "compact lobes: visibility of {} vertices and {} normals for a transfer of \
                 {vertices}",
                c.visibility.vertices,
                c.normals.len(),
            ));
        }
        if let Some(i) = c.normals.iter().position(|n| !n.is_finite()) {
            return bad(format!("normal {i} is not finite"));
        }
        if c.factor.is_nan() || c.factor < 0.0 {
            return bad(format!("sharpness factor {} must be >= 0", c.factor));
        }
        Ok(())
    }

    /// Checks sizes and values (the shaders index with them; the GPU must never read out of
    /// bounds or produce NaN from bad input).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        if self.lobes.is_empty() || self.lobes.len() > 65_536 {
            return bad(format!("{} lighting lobes (1..=65536)", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        let t = self.transfer;
        t.check()?;
        let k = t.basis.len();
        if k > MAX_BASIS {
            return bad(format!("{k} basis functions (1..={MAX_BASIS})"));
        }
        self.check_compact()?;
        let rows = rows_needed(t.clusters, t.components);
        if rows > MAX_ROWS {
            return bad(format!(
                "{} clusters x {} components need {rows} projected rows; the GPU path holds \
                 {MAX_ROWS} (fewer clusters or components)",
                t.clusters, t.components
            ));
        }
        Ok(())
    }
}

/// Host copy of one frame: RGB radiance per vertex.
pub type SrbfOutput = Vec<[f32; 3]>;

/// The GPU layout of a [`Cpca`] transfer (see glsl/srbf/shade.comp and project.comp).
struct Layout {
    /// Shade slots (a multiple of SHADE_GROUP): vertices sorted by cluster, each cluster
    /// padded to whole workgroups.
    slot_vertex: Vec<u32>,
    group_cluster: Vec<u32>,
    /// Weights in half precision, eight per uvec4, group-major over slots.
    weights: Vec<[u32; 4]>,
    /// Rows per cluster in `projected`: [`stride`].
    stride: usize,
    /// Rows, group-major vec4s over clusters x stride rows.
    rows: Vec<[f32; 4]>,
}

impl Layout {
    fn of(t: &Cpca) -> Layout {
        let (k, m) = (t.basis.len(), t.components);
        let m_groups = m.div_ceil(8);
        let stride = stride(m);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); t.clusters];
        for (v, &c) in t.cluster_of.iter().enumerate() {
            members[c as usize].push(v as u32);
        }
        let mut slot_vertex = Vec::new();
        let mut group_cluster = Vec::new();
        for (c, list) in members.iter().enumerate() {
            for chunk in list.chunks(SHADE_GROUP) {
                group_cluster.push(c as u32);
                slot_vertex.extend_from_slice(chunk);
                slot_vertex.resize(group_cluster.len() * SHADE_GROUP, NO_VERTEX);
            }
        }
        let slots = slot_vertex.len();
        let mut weights = vec![[0u32; 4]; m_groups * slots];
        for (slot, &v) in slot_vertex.iter().enumerate() {
            if v == NO_VERTEX {
                continue;
            }
            let w = &t.weights[v as usize * m..(v as usize + 1) * m];
            for (i, x) in w.iter().enumerate() {
                // unpackHalf2x16: the first of a pair in the low 16 bits.
                let word = &mut weights[(i / 8) * slots + slot][(i % 8) / 2];
                *word |= (crate::io::f16::f16_bits(*x) as u32) << (16 * (i % 2));
            }
        }
        let k_groups = k.div_ceil(4);
        let n_rows = t.clusters * stride;
        let mut rows = vec![[0f32; 4]; k_groups * n_rows];
        for c in 0..t.clusters {
            for i in 0..=m {
                let src = &t.rows[(c * (m + 1) + i) * k..(c * (m + 1) + i + 1) * k];
                let r = c * stride + i;
                for (j, x) in src.iter().enumerate() {
                    rows[(j / 4) * n_rows + r][j % 4] = *x;
                }
            }
        }
        Layout {
            slot_vertex,
            group_cluster,
            weights,
            stride,
            rows,
        }
    }
}

/// The columns of a rotation as three vec4 (push-constant layout of `srbf lighting` and
/// `srbf sharp`).
fn rotation_push(r: Mat3) -> Vec<u8> {
    let mut push: Vec<u8> = Vec::with_capacity(64);
    for c in 0..3 {
        let col = r.col(c);
        for x in [col.x, col.y, col.z, 0.0] {
            push.extend_from_slice(&x.to_le_bytes());
        }
    }
    push
}

/// The GPU kernel: pipelines, the lobes, the transfer and the outputs of one mesh.
pub struct SrbfKernel {
    ctx: Context,
    lighting: ComputePipeline,
    lighting_bind: BindGroup,
    project: ComputePipeline,
    project_bind: BindGroup,
    shade: ComputePipeline,
    shade_bind: BindGroup,
    sharp: ComputePipeline,
    sharp_bind: BindGroup,
    buffers: Vec<Buffer>,
    radiance: Buffer,
    /// Lobes through the basis.
    lobes: u32,
    /// Compact lobes (shaded from the visibility) and the visibility grid.
    compact: u32,
    grid: [u32; 2],
    basis: u32,
    basis_sharpness: f32,
    vertices: u32,
    clusters: u32,
    components: u32,
    rows: u32,
    stride: u32,
    slots: u32,
}

impl SrbfKernel {
    /// Creates the buffers and pipelines and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &SrbfInputs<'_>) -> Result<SrbfKernel> {
        inputs.check()?;
        let ctx = rec.context();
        let ubo_limit = ctx.limits().max_uniform_buffer_range as usize;
        if ubo_limit < MAX_ROWS * 16 {
            return Err(Error::InvalidArgument(format!(
                "SRBF needs uniform buffers of {} bytes; the device allows {ubo_limit} \
                 (maxUniformBufferRange)",
                MAX_ROWS * 16
            )));
        }
        let spv = |name| crate::shaders::spirv(name);
        let lighting = ComputePipeline::from_spirv(&ctx, "srbf/lighting", spv("srbf/lighting")?)?;
        let project = ComputePipeline::from_spirv(&ctx, "srbf/project", spv("srbf/project")?)?;
        let shade = ComputePipeline::from_spirv(&ctx, "srbf/shade", spv("srbf/shade")?)?;
        let sharp_pipe = ComputePipeline::from_spirv(&ctx, "srbf/sharp", spv("srbf/sharp")?)?;
        let t = inputs.transfer;
        let (smooth, compact) = inputs.split();
        // Zero-amplitude padding keeps every buffer non-empty.
        let pad = |l: &[Lobe]| {
            let mut v = l.to_vec();
            if v.is_empty() {
                v.push(Lobe {
                    axis: [0.0, 1.0, 0.0],
                    sharpness: 1.0,
                    amplitude: [0.0; 3],
                });
            }
            v
        };
        let axes_of = |l: &[Lobe]| -> Vec<[f32; 4]> {
            pad(l)
                .iter()
                .map(|l| [l.axis[0], l.axis[1], l.axis[2], l.sharpness])
                .collect()
        };
        let amps_of = |l: &[Lobe]| -> Vec<[f32; 4]> {
            pad(l)
                .iter()
                .map(|l| [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0])
                .collect()
        };
        let axes = axes_of(&smooth);
        let amps = amps_of(&smooth);
        let basis: Vec<[f32; 4]> = t
            .basis
            .axes
            .iter()
            .map(|a| a.extend(0.0).to_array())
            .collect();
        let layout = Layout::of(t);
        let slots = layout.slot_vertex.len();
        let max_groups =
            (ctx.limits().max_compute_work_group_count[0] as usize).min(MAX_SHADE_GROUPS);
        if slots / SHADE_GROUP > max_groups {
            return Err(Error::InvalidArgument(format!(
                "SRBF: {} vertices need {} workgroups; the device dispatches {max_groups}",
                t.vertices,
                slots / SHADE_GROUP
            )));
        }
        let mut upload = |name: &str, bytes: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        };
        let lobe_axes = upload("srbf lobe axes", bytemuck::cast_slice(&axes))?;
        let lobe_amps = upload("srbf lobe amplitudes", bytemuck::cast_slice(&amps))?;
        let compact_axes = upload(
            "srbf compact axes",
            bytemuck::cast_slice(&axes_of(&compact)),
        )?;
        let compact_amps = upload(
            "srbf compact amplitudes",
            bytemuck::cast_slice(&amps_of(&compact)),
        )?;
        // Per slot: the normal and the visibility words (word-major); one zero word each
        // when there are no compact lobes.
        let (normals, visible, grid) = match (&inputs.compact, compact.is_empty()) {
            (Some(c), false) => {
                let words = c.visibility.directions.len().div_ceil(32);
                let mut normals = vec![[0f32; 4]; slots];
                let mut visible = vec![0u32; words * slots];
                for (slot, &v) in layout.slot_vertex.iter().enumerate() {
                    if v == NO_VERTEX {
                        continue;
                    }
                    normals[slot] = c.normals[v as usize].extend(0.0).to_array();
                    for w in 0..words {
                        visible[w * slots + slot] = c.visibility.word32(v as usize, w);
                    }
                }
                (normals, visible, [c.width, c.height])
            }
            _ => (vec![[0f32; 4]], vec![0u32; 4], [1, 1]),
        };
        let normals = upload("srbf slot normals", bytemuck::cast_slice(&normals))?;
        let visible = upload("srbf slot visibility", bytemuck::cast_slice(&visible))?;
        let basis_axes = upload("srbf basis axes", bytemuck::cast_slice(&basis))?;
        let rows = upload("srbf cpca rows", bytemuck::cast_slice(&layout.rows))?;
        let weights = upload("srbf cpca weights", bytemuck::cast_slice(&layout.weights))?;
        let slot_vertex = upload(
            "srbf slot vertices",
            bytemuck::cast_slice(&layout.slot_vertex),
        )?;
        // A uniform buffer sized for shade.comp's fixed array (zero-padded).
        let mut groups = layout.group_cluster.clone();
        groups.resize(MAX_SHADE_GROUPS, 0);
        let group_cluster = rec.buffer_with(
            "srbf workgroup clusters",
            BufferDesc::uniform(groups.len() as u64 * 4),
            &groups,
        )?;
        // Written as storage by one pass and read as a uniform buffer by the next (sized for
        // the reader's fixed array, zero-padded).
        let ubo = |rec: &mut Recorder, name: &str, vec4s: usize| {
            rec.buffer_with(
                name,
                BufferDesc::storage(vec4s as u64 * 16).usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
                &vec![[0f32; 4]; vec4s],
            )
        };
        let coeffs = ubo(rec, "srbf coefficients", MAX_BASIS)?;
        let projected = ubo(rec, "srbf projected rows", MAX_ROWS)?;
        let taps = ubo(rec, "srbf compact taps", 2 * MAX_TAPS)?;
        let radiance = Buffer::new(
            &ctx,
            "srbf radiance",
            BufferDesc::storage(t.vertices as u64 * 16).usage(vk::BufferUsageFlags::VERTEX_BUFFER),
        )?;
        let w = AccessSet::from(A::ComputeShaderWrite);
        let lighting_bind = lighting.bind_declared(
            &[
                ("lobe_axes", Resource::Buffer(&lobe_axes)),
                ("lobe_amps", Resource::Buffer(&lobe_amps)),
                ("basis_axes", Resource::Buffer(&basis_axes)),
                ("coeffs", Resource::Buffer(&coeffs)),
            ],
            &[("coeffs", w)],
        )?;
        let project_bind = project.bind_declared(
            &[
                ("rows", Resource::Buffer(&rows)),
                ("coeffs", Resource::Buffer(&coeffs)),
                ("projected", Resource::Buffer(&projected)),
            ],
            &[("projected", w)],
        )?;
        let sharp_bind = sharp_pipe.bind_declared(
            &[
                ("lobe_axes", Resource::Buffer(&compact_axes)),
                ("lobe_amps", Resource::Buffer(&compact_amps)),
                ("taps", Resource::Buffer(&taps)),
            ],
            &[("taps", w)],
        )?;
        let shade_bind = shade.bind_declared(
            &[
                ("weights", Resource::Buffer(&weights)),
                ("slot_vertex", Resource::Buffer(&slot_vertex)),
                ("group_cluster", Resource::Buffer(&group_cluster)),
                ("projected", Resource::Buffer(&projected)),
                ("radiance", Resource::Buffer(&radiance)),
                ("normals", Resource::Buffer(&normals)),
                ("visible", Resource::Buffer(&visible)),
                ("taps", Resource::Buffer(&taps)),
            ],
            &[("radiance", w)],
        )?;
        Ok(SrbfKernel {
            ctx,
            lighting,
            lighting_bind,
            project,
            project_bind,
            shade,
            shade_bind,
            sharp: sharp_pipe,
            sharp_bind,
            buffers: vec![
                compact_axes,
                compact_amps,
                normals,
                visible,
                taps,
                lobe_axes,
                lobe_amps,
                basis_axes,
                rows,
                weights,
                slot_vertex,
                group_cluster,
                coeffs,
                projected,
            ],
            radiance,
            lobes: smooth.len() as u32,
            compact: compact.len() as u32,
            grid,
            basis: t.basis.len() as u32,
            basis_sharpness: t.basis.sharpness,
            vertices: t.vertices as u32,
            clusters: t.clusters as u32,
            components: t.components as u32,
            rows: (t.clusters * layout.stride) as u32,
            stride: layout.stride as u32,
            slots: slots as u32,
        })
    }

    /// Per-vertex RGB radiance (vec4, alpha 1), written by pass `srbf shade`.
    pub fn radiance(&self) -> &Buffer {
        &self.radiance
    }

    pub fn vertex_count(&self) -> usize {
        self.vertices as usize
    }

    /// Lighting lobes: through the basis plus compact.
    pub fn lobe_count(&self) -> usize {
        (self.lobes + self.compact) as usize
    }

    /// Compact lobes (shaded from the visibility, not through the basis).
    pub fn compact_count(&self) -> usize {
        self.compact as usize
    }

    pub fn basis_count(&self) -> usize {
        self.basis as usize
    }

    /// (clusters, principal components per cluster) of the transfer.
    pub fn cpca_shape(&self) -> (usize, usize) {
        (self.clusters as usize, self.components as usize)
    }

    /// Shade slots (vertices padded so that every workgroup holds one cluster).
    pub fn slot_count(&self) -> usize {
        self.slots as usize
    }

    fn check_frame(frame: &SrbfFrame) -> Result<()> {
        let r = frame.rotation;
        let orthonormal = (r.transpose() * r - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-4);
        if !r.is_finite() || !orthonormal || r.determinant() < 0.0 {
            return Err(Error::InvalidArgument(format!(
                "the environment rotation is not a rotation matrix: {r:?}"
            )));
        }
        if frame.albedo.iter().any(|a| !a.is_finite() || *a < 0.0) {
            return Err(Error::InvalidArgument(format!(
                "albedo {:?} must be finite and >= 0",
                frame.albedo
            )));
        }
        Ok(())
    }

    fn lighting_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        let mut push = rotation_push(frame.rotation);
        push.extend_from_slice(&self.lobes.to_le_bytes());
        push.extend_from_slice(&self.basis.to_le_bytes());
        push.extend_from_slice(&self.basis_sharpness.to_le_bytes());
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.basis, 1, 1]),
        })
    }

    fn sharp_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        // With no compact lobes one invocation runs and writes nothing, so the declared uses
        // are the same either way and a render graph's plan holds.
        let mut push = rotation_push(frame.rotation);
        for x in [self.compact, self.grid[0], self.grid[1]] {
            push.extend_from_slice(&x.to_le_bytes());
        }
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.compact.max(1), 1, 1]),
        })
    }

    fn project_args(&self, _frame: &SrbfFrame) -> Result<Dispatch> {
        Ok(Dispatch::words(
            &[self.rows, self.basis.div_ceil(4)],
            Grid::Invocations([self.rows, 1, 1]),
        ))
    }

    fn shade_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        let a = frame.albedo;
        let push: Vec<u8> = [a[0], a[1], a[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .chain(self.slots.to_le_bytes())
            .chain(self.components.div_ceil(8).to_le_bytes())
            .chain(self.stride.to_le_bytes())
            .chain(self.compact.to_le_bytes())
            .collect();
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.slots, 1, 1]),
        })
    }
}

impl Kernel for SrbfKernel {
    type Input = SrbfFrame;
    type Readback = Readback;
    type Output = SrbfOutput;

    fn name(&self) -> &'static str {
        "srbf"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::dispatch(
                PASS_LIGHTING,
                &self.lighting,
                &self.lighting_bind,
                Self::lighting_args,
            ),
            Pass::dispatch(
                PASS_PROJECT,
                &self.project,
                &self.project_bind,
                Self::project_args,
            ),
            Pass::dispatch(PASS_SHARP, &self.sharp, &self.sharp_bind, Self::sharp_args),
            Pass::dispatch(PASS_SHADE, &self.shade, &self.shade_bind, Self::shade_args),
        ]
    }

    fn check_input(&self, frame: &SrbfFrame) -> Result<()> {
        Self::check_frame(frame)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.radiance)
    }

    fn collect(&self, readback: &Readback) -> Result<SrbfOutput> {
        let v: Vec<[f32; 4]> = readback.to_vec()?;
        Ok(v.iter().map(|x| [x[0], x[1], x[2]]).collect())
    }

    fn memory(&self) -> MemoryReport {
        let all: Vec<&Buffer> = self.buffers.iter().chain([&self.radiance]).collect();
        self.ctx.memory_of(&all)
    }
}
