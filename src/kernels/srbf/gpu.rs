//! The SRBF kernel on the GPU: pass `srbf lighting` rotates the lighting lobes and computes
//! their coefficients in the transfer basis; pass `srbf shade` shades every vertex. The
//! per-vertex result is an RGB radiance buffer that can also feed a renderer's vertex input.

use super::sg::Lobe;
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, PlannedBarrier, Readback, Recorder, Resource,
};
use crate::kernels::{Kernel, PassInfo, UseInfo};
use ash::vk;
use glam::{Mat3, Vec3};

pub const PASS_LIGHTING: &str = "srbf lighting";
/// Most transfer basis functions (the size of `srbf shade`'s uniform coefficient array; a
/// 16 KiB uniform buffer, the smallest maxUniformBufferRange Vulkan allows).
pub const MAX_BASIS: usize = 1024;
pub const PASS_SHADE: &str = "srbf shade";

/// One frame's input: the environment's rotation and the surface albedo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SrbfFrame {
    /// L_R(w) = L(R^-1 w).
    pub rotation: Mat3,
    pub albedo: [f32; 3],
}

/// What the kernel is built from: the lighting lobes and the per-vertex transfer in a basis
/// of spherical Gaussians of common sharpness.
pub struct SrbfInputs<'a> {
    pub lobes: &'a [Lobe],
    pub basis_axes: &'a [Vec3],
    pub basis_sharpness: f32,
    /// Vertex-major: `basis_axes.len()` coefficients per vertex.
    pub coeffs: &'a [f32],
    pub vertices: usize,
}

impl<'a> SrbfInputs<'a> {
    /// The lobes with a projected transfer.
    pub fn new(lobes: &'a [Lobe], transfer: &'a super::transfer::Transfer) -> Self {
        SrbfInputs {
            lobes,
            basis_axes: &transfer.basis.axes,
            basis_sharpness: transfer.basis.sharpness,
            coeffs: &transfer.coeffs,
            vertices: transfer.vertices,
        }
    }

    /// Checks sizes and values (the shaders index with them; the GPU must never read out of
    /// bounds or produce NaN from bad input).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        let k = self.basis_axes.len();
        if self.lobes.is_empty() || self.lobes.len() > 65_536 {
            return bad(format!("{} lighting lobes (1..=65536)", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        if k == 0 || k > MAX_BASIS {
            return bad(format!("{k} basis functions (1..={MAX_BASIS})"));
        }
        if let Some(i) = self
            .basis_axes
            .iter()
            .position(|a| !a.is_finite() || (a.length() - 1.0).abs() > 1e-3)
        {
            return bad(format!("basis axis {i} is not a unit vector"));
        }
        if !(self.basis_sharpness.is_finite() && self.basis_sharpness > 0.0) {
            return bad(format!("basis sharpness {}", self.basis_sharpness));
        }
        if self.vertices == 0 || self.coeffs.len() != self.vertices * k {
            return bad(format!(
                "{} transfer coefficients for {} vertices x {k} basis functions",
                self.coeffs.len(),
                self.vertices
            ));
        }
        if let Some(i) = self.coeffs.iter().position(|c| !c.is_finite()) {
            return bad(format!("transfer coefficient {i} is not finite"));
        }
        Ok(())
    }
}

/// Host copy of one frame: RGB radiance per vertex.
pub type SrbfOutput = Vec<[f32; 3]>;

/// The GPU kernel: pipelines, the lobes, the transfer and the outputs of one mesh.
pub struct SrbfKernel {
    ctx: Context,
    lighting: ComputePipeline,
    lighting_bind: BindGroup,
    shade: ComputePipeline,
    shade_bind: BindGroup,
    buffers: Vec<Buffer>,
    radiance: Buffer,
    lobes: u32,
    basis: u32,
    basis_sharpness: f32,
    vertices: u32,
}

impl SrbfKernel {
    /// Creates the buffers and pipelines and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &SrbfInputs<'_>) -> Result<SrbfKernel> {
        inputs.check()?;
        let ctx = rec.context();
        let spv = |name| crate::shaders::spirv(name);
        let lighting = ComputePipeline::from_spirv(&ctx, "srbf/lighting", spv("srbf/lighting")?)?;
        let shade = ComputePipeline::from_spirv(&ctx, "srbf/shade", spv("srbf/shade")?)?;
        let axes: Vec<[f32; 4]> = inputs
            .lobes
            .iter()
            .map(|l| [l.axis[0], l.axis[1], l.axis[2], l.sharpness])
            .collect();
        let amps: Vec<[f32; 4]> = inputs
            .lobes
            .iter()
            .map(|l| [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0])
            .collect();
        let basis: Vec<[f32; 4]> = inputs
            .basis_axes
            .iter()
            .map(|a| a.extend(0.0).to_array())
            .collect();
        let k = basis.len() as u64;
        // On the GPU: groups of four basis functions, group-major
        // (t4[g * vertices + v]), zero-padded, so neighbouring invocations read neighbouring
        // vec4s; the coefficient buffer is padded to whole groups (zeros).
        let nv = inputs.vertices;
        let groups = (k as usize).div_ceil(4);
        let mut grouped = vec![0f32; groups * 4 * nv];
        for (v, row) in inputs.coeffs.chunks_exact(k as usize).enumerate() {
            for (i, &t) in row.iter().enumerate() {
                grouped[((i / 4) * nv + v) * 4 + i % 4] = t;
            }
        }
        let mut upload = |name: &str, bytes: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        };
        let lobe_axes = upload("srbf lobe axes", bytemuck::cast_slice(&axes))?;
        let lobe_amps = upload("srbf lobe amplitudes", bytemuck::cast_slice(&amps))?;
        let basis_axes = upload("srbf basis axes", bytemuck::cast_slice(&basis))?;
        let transfer = upload("srbf transfer", bytemuck::cast_slice(&grouped))?;
        // Written as storage by `srbf lighting`, read as a uniform buffer by `srbf shade`
        // (sized for its fixed array of MAX_BASIS vec4s, zero-padded).
        let coeffs = rec.buffer_with(
            "srbf coefficients",
            BufferDesc::storage(MAX_BASIS as u64 * 16).usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
            &vec![[0f32; 4]; MAX_BASIS],
        )?;
        let radiance = Buffer::new(
            &ctx,
            "srbf radiance",
            BufferDesc::storage(inputs.vertices as u64 * 16)
                .usage(vk::BufferUsageFlags::VERTEX_BUFFER),
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
        let shade_bind = shade.bind_declared(
            &[
                ("transfer", Resource::Buffer(&transfer)),
                ("coeffs", Resource::Buffer(&coeffs)),
                ("radiance", Resource::Buffer(&radiance)),
            ],
            &[("radiance", w)],
        )?;
        Ok(SrbfKernel {
            ctx,
            lighting,
            lighting_bind,
            shade,
            shade_bind,
            buffers: vec![lobe_axes, lobe_amps, basis_axes, transfer, coeffs],
            radiance,
            lobes: inputs.lobes.len() as u32,
            basis: k as u32,
            basis_sharpness: inputs.basis_sharpness,
            vertices: inputs.vertices as u32,
        })
    }

    /// Per-vertex RGB radiance (vec4, alpha 1), written by pass `srbf shade`.
    pub fn radiance(&self) -> &Buffer {
        &self.radiance
    }

    pub fn vertex_count(&self) -> usize {
        self.vertices as usize
    }

    pub fn lobe_count(&self) -> usize {
        self.lobes as usize
    }

    pub fn basis_count(&self) -> usize {
        self.basis as usize
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

    fn record_lighting(&self, rec: &mut Recorder, frame: &SrbfFrame) -> Result<()> {
        let mut push: Vec<u8> = Vec::with_capacity(64);
        for c in 0..3 {
            let col = frame.rotation.col(c);
            for x in [col.x, col.y, col.z, 0.0] {
                push.extend_from_slice(&x.to_le_bytes());
            }
        }
        push.extend_from_slice(&self.lobes.to_le_bytes());
        push.extend_from_slice(&self.basis.to_le_bytes());
        push.extend_from_slice(&self.basis_sharpness.to_le_bytes());
        rec.dispatch_invocations_tracked(
            &self.lighting,
            &self.lighting_bind,
            &push,
            [self.basis, 1, 1],
        )
    }

    fn record_shade(&self, rec: &mut Recorder, frame: &SrbfFrame) -> Result<()> {
        let a = frame.albedo;
        let push: Vec<u8> = [a[0], a[1], a[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .chain(self.vertices.to_le_bytes())
            .chain(self.basis.div_ceil(4).to_le_bytes())
            .collect();
        rec.dispatch_invocations_tracked(
            &self.shade,
            &self.shade_bind,
            &push,
            [self.vertices, 1, 1],
        )
    }
}

impl Kernel for SrbfKernel {
    type Input = SrbfFrame;
    type Readback = Readback;
    type Output = SrbfOutput;

    fn name(&self) -> &'static str {
        "srbf"
    }

    fn passes(&self) -> Vec<PassInfo> {
        let uses = |b: &BindGroup| b.accesses().into_iter().map(UseInfo::from).collect();
        vec![
            PassInfo {
                name: PASS_LIGHTING,
                uses: uses(&self.lighting_bind),
            },
            PassInfo {
                name: PASS_SHADE,
                uses: uses(&self.shade_bind),
            },
        ]
    }

    fn record_pass(&self, rec: &mut Recorder, pass: usize, input: &SrbfFrame) -> Result<()> {
        Self::check_frame(input)?;
        let name = [PASS_LIGHTING, PASS_SHADE].get(pass).ok_or_else(|| {
            Error::InvalidArgument(format!("SRBF has 2 passes, not {}", pass + 1))
        })?;
        rec.begin_pass(name);
        let r = match pass {
            0 => self.record_lighting(rec, input),
            _ => self.record_shade(rec, input),
        };
        rec.end_pass();
        r
    }

    fn plan_pass(&self, rec: &mut Recorder, pass: usize) -> Result<Vec<PlannedBarrier>> {
        match pass {
            0 => Ok(rec.plan_dispatch(&self.lighting_bind)),
            1 => Ok(rec.plan_dispatch(&self.shade_bind)),
            _ => Err(Error::InvalidArgument(format!(
                "SRBF has 2 passes, not {}",
                pass + 1
            ))),
        }
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
