//! The glossy SRBF kernel on the GPU: pass `srbf lighting` (the diffuse kernel's: the
//! rotated lobes' coefficients on the transfer basis), then pass `srbf glossy shade`: every
//! vertex's radiance toward the camera from its transfer matrix (glsl/srbf/glossy.comp;
//! [`GlossyTransfer::shade`] is its CPU twin), then with compact lobes
//! ([`super::glossy_sharp`]) pass `srbf glossy sharp`, which adds them onto that radiance.

use super::glossy::{GlossyTransfer, ViewBasis};
use super::glossy_sharp::{CompactStage, GlossyCompact};
use super::inputs::SrbfFrame;
use super::pack::MAX_BASIS;
use crate::error::{Error, Result};
use crate::geom::sg::Lobe;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::{Mat3, Vec3};

pub const PASS_LIGHTING: &str = "srbf lighting";
pub const PASS_GLOSSY: &str = "srbf glossy shade";

/// One frame: the environment's rotation, the albedo and the camera position (model units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlossyFrame {
    pub rotation: Mat3,
    pub albedo: [f32; 3],
    pub camera: Vec3,
}

impl GlossyFrame {
    pub fn check(&self) -> Result<()> {
        SrbfFrame {
            rotation: self.rotation,
            albedo: self.albedo,
        }
        .check()?;
        if !self.camera.is_finite() {
            return Err(Error::InvalidArgument(format!(
                "camera position {} is not finite",
                self.camera
            )));
        }
        Ok(())
    }
}

/// What the glossy kernel is built from: the lobes through the transfer basis and, shaded
/// directly, the compact ones.
pub struct GlossyInputs<'a> {
    pub lobes: &'a [Lobe],
    pub transfer: &'a GlossyTransfer,
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    pub compact: Option<GlossyCompact<'a>>,
}

impl GlossyInputs<'_> {
    /// Checks sizes and values (the shader indexes with them).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("glossy SRBF input: {what}")));
        if self.lobes.is_empty() || self.lobes.len() > 65_536 {
            return bad(format!("{} lighting lobes (1..=65536)", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        let t = self.transfer;
        t.check()?;
        if t.rows.basis.len() > MAX_BASIS {
            return bad(format!(
                "{} basis functions (1..={MAX_BASIS})",
                t.rows.basis.len()
            ));
        }
        if self.positions.len() != t.vertices || self.normals.len() != t.vertices {
            return bad(format!(
                "{} positions and {} normals for a transfer of {} vertices",
                self.positions.len(),
                self.normals.len(),
                t.vertices
            ));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return bad(format!("position {i} is not finite"));
        }
        if let Some(i) = self
            .normals
            .iter()
            .position(|n| !n.is_finite() || (n.length() - 1.0).abs() > 1e-3)
        {
            return bad(format!("normal {i} is not a unit vector"));
        }
        if let Some(c) = &self.compact {
            c.check_for(t.vertices, Some(self.positions))?;
            if c.brdf != t.brdf {
                return bad(format!(
                    "compact lobes shaded with {:?} for a transfer of {:?}",
                    c.brdf, t.brdf
                ));
            }
        }
        Ok(())
    }

    /// The CPU twin of one frame (f32 lighting coefficients as the GPU's, f64 sums).
    pub fn cpu_pipeline(&self, frame: &GlossyFrame) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        frame.check()?;
        let basis = &self.transfer.rows.basis;
        let coeffs = super::transfer::lighting_coefficients(self.lobes, frame.rotation, basis);
        let mut out = self.transfer.shade(
            &coeffs,
            self.positions,
            self.normals,
            frame.camera,
            frame.albedo,
        )?;
        if let Some(c) = &self.compact {
            c.add(frame, self.positions, self.normals, &mut out)?;
        }
        Ok(out)
    }
}

/// The lobes as the shaders read them: (axis xyz, sharpness) and (amplitude rgb, 0).
pub(crate) fn lobe_arrays(lobes: &[Lobe]) -> (Vec<[f32; 4]>, Vec<[f32; 4]>) {
    let axes = lobes
        .iter()
        .map(|l| [l.axis[0], l.axis[1], l.axis[2], l.sharpness])
        .collect();
    let amps = lobes
        .iter()
        .map(|l| [l.amplitude[0], l.amplitude[1], l.amplitude[2], 0.0])
        .collect();
    (axes, amps)
}

/// The dispatch `args` gives for one of the compact stage's passes (an error when the kernel
/// has no such stage).
pub(crate) fn compact_args(
    stage: &Option<CompactStage>,
    frame: &GlossyFrame,
    args: fn(&CompactStage, &GlossyFrame) -> Dispatch,
) -> Result<Dispatch> {
    stage
        .as_ref()
        .map(|c| args(c, frame))
        .ok_or_else(|| Error::InvalidArgument("the kernel has no compact lobes".into()))
}

/// The view table the shading passes read: a factored basis' g_j at the table's nodes
/// (N^2 x m), or one unread zero for a view grid (a binding needs a buffer).
pub(crate) fn view_table(view: &ViewBasis) -> Vec<f32> {
    match view {
        ViewBasis::Grid(_) => vec![0.0],
        ViewBasis::Brdf(f) => f.view.clone(),
    }
}

/// The GPU kernel of glossy transfer.
pub struct GlossyKernel {
    ctx: Context,
    lighting: (ComputePipeline, BindGroup),
    shade: (ComputePipeline, BindGroup),
    /// Pass `srbf glossy sharp` (None without compact lobes).
    compact: Option<CompactStage>,
    buffers: [Buffer; 9],
    vertices: u32,
    grid: u32,
    terms: u32,
    basis: u32,
    lobes: u32,
    sharpness: f32,
}

// Indices into `GlossyKernel::buffers`.
const LOBE_AXES: usize = 0;
const LOBE_AMPS: usize = 1;
const BASIS_AXES: usize = 2;
const COEFFS: usize = 3;
const ROWS: usize = 4;
const POINTS: usize = 5;
const NORMALS: usize = 6;
const RADIANCE: usize = 7;
const TABLE: usize = 8;

impl GlossyKernel {
    /// Checks `inputs` (and the transfer's size against maxStorageBufferRange), creates the
    /// buffers and pipelines and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &GlossyInputs<'_>) -> Result<GlossyKernel> {
        inputs.check()?;
        let ctx = rec.context();
        let t = inputs.transfer;
        let bytes = t.rows.coeffs.len() as u64 * 4;
        let limit = ctx.limits().max_storage_buffer_range;
        if bytes > limit || t.rows.coeffs.len() > u32::MAX as usize {
            return Err(Error::InvalidArgument(format!(
                "glossy SRBF: the uncompressed transfer of {} vertices x {} views x {} basis \
                 functions is {bytes} bytes; the device's storage buffers hold {limit} \
                 (maxStorageBufferRange): fewer views or basis functions, or a smaller mesh",
                t.vertices,
                t.views(),
                t.rows.basis.len()
            )));
        }
        fn storage<T: bytemuck::Pod>(rec: &mut Recorder, name: &str, data: &[T]) -> Result<Buffer> {
            let bytes: &[u8] = bytemuck::cast_slice(data);
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        }
        let vec4 =
            |v: &[Vec3]| -> Vec<[f32; 4]> { v.iter().map(|x| x.extend(0.0).into()).collect() };
        let (lobe_axes, lobe_amps) = lobe_arrays(inputs.lobes);
        let basis = &t.rows.basis;
        let buffers = [
            storage(rec, "srbf glossy lobe axes", &lobe_axes)?,
            storage(rec, "srbf glossy lobe amplitudes", &lobe_amps)?,
            storage(rec, "srbf glossy basis axes", &vec4(&basis.axes))?,
            rec.buffer_with(
                "srbf glossy coefficients",
                BufferDesc::storage(MAX_BASIS as u64 * 16)
                    .usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
                &vec![[0f32; 4]; MAX_BASIS],
            )?,
            storage(rec, "srbf glossy transfer rows", &t.rows.coeffs)?,
            storage(rec, "srbf glossy positions", &vec4(inputs.positions))?,
            storage(rec, "srbf glossy normals", &vec4(inputs.normals))?,
            Buffer::new(
                &ctx,
                "srbf glossy radiance",
                BufferDesc::storage(t.vertices as u64 * 16)
                    .usage(vk::BufferUsageFlags::VERTEX_BUFFER),
            )?,
            storage(rec, "srbf glossy view table", &view_table(&t.view))?,
        ];
        let lighting = crate::shaders::pipeline(&ctx, "srbf/lighting")?;
        let shade = crate::shaders::pipeline(&ctx, "srbf/glossy")?;
        let (b, w) = (Resource::Buffer, AccessSet::from(A::ComputeShaderWrite));
        let lighting_bind = lighting.bind_declared(
            &[
                ("lobe_axes", b(&buffers[LOBE_AXES])),
                ("lobe_amps", b(&buffers[LOBE_AMPS])),
                ("basis_axes", b(&buffers[BASIS_AXES])),
                ("coeffs", b(&buffers[COEFFS])),
            ],
            &[("coeffs", w)],
        )?;
        let shade_bind = shade.bind_declared(
            &[
                ("rows", b(&buffers[ROWS])),
                ("points", b(&buffers[POINTS])),
                ("normals", b(&buffers[NORMALS])),
                ("coeffs", b(&buffers[COEFFS])),
                ("radiance", b(&buffers[RADIANCE])),
                ("table", b(&buffers[TABLE])),
            ],
            &[("radiance", w)],
        )?;
        let compact = match &inputs.compact {
            Some(c) => {
                CompactStage::new(rec, c, inputs.positions, inputs.normals, &buffers[RADIANCE])?
            }
            None => None,
        };
        Ok(GlossyKernel {
            ctx,
            lighting: (lighting, lighting_bind),
            shade: (shade, shade_bind),
            compact,
            buffers,
            vertices: t.vertices as u32,
            grid: t.view.grid().n,
            terms: t.view.terms() as u32,
            basis: basis.len() as u32,
            lobes: inputs.lobes.len() as u32,
            sharpness: basis.sharpness,
        })
    }

    /// Per-vertex RGB radiance toward the camera (vec4, alpha 1).
    pub fn radiance(&self) -> &Buffer {
        &self.buffers[RADIANCE]
    }

    /// The compact lobes pass `srbf glossy sharp` adds (0: no such pass).
    pub fn compact_count(&self) -> usize {
        self.compact.as_ref().map_or(0, CompactStage::lobes)
    }

    fn compact_taps_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        compact_args(&self.compact, frame, CompactStage::taps_args)
    }

    fn compact_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        compact_args(&self.compact, frame, CompactStage::add_args)
    }

    fn lighting_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        let mut push = super::gpu::rotation_push(frame.rotation);
        push.extend_from_slice(&self.lobes.to_le_bytes());
        push.extend_from_slice(&self.basis.to_le_bytes());
        push.extend_from_slice(&self.sharpness.to_le_bytes());
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.basis, 1, 1]),
        })
    }

    fn shade_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        let (c, a) = (frame.camera, frame.albedo);
        let push: Vec<u8> = [c.x, c.y, c.z, 0.0, a[0], a[1], a[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .chain(
                [self.vertices, self.grid, self.basis, self.terms]
                    .iter()
                    .flat_map(|x| x.to_le_bytes()),
            )
            .collect();
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.vertices, 1, 1]),
        })
    }
}

impl Kernel for GlossyKernel {
    type Input = GlossyFrame;
    type Readback = Readback;
    type Output = Vec<[f32; 3]>;

    fn name(&self) -> &'static str {
        "srbf glossy"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let mut passes = vec![
            Pass::dispatch(
                PASS_LIGHTING,
                &self.lighting.0,
                &self.lighting.1,
                Self::lighting_args,
            ),
            Pass::dispatch(PASS_GLOSSY, &self.shade.0, &self.shade.1, Self::shade_args),
        ];
        if let Some(c) = &self.compact {
            passes.extend(c.passes(Self::compact_taps_args, Self::compact_args));
        }
        passes
    }

    fn check_input(&self, frame: &GlossyFrame) -> Result<()> {
        frame.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.buffers[RADIANCE])
    }

    fn collect(&self, readback: &Readback) -> Result<Vec<[f32; 3]>> {
        let v: Vec<[f32; 4]> = readback.to_vec()?;
        Ok(v.iter().map(|x| [x[0], x[1], x[2]]).collect())
    }

    fn memory(&self) -> MemoryReport {
        self.ctx.memory_of_resources(
            self.buffers
                .iter()
                .map(Resource::Buffer)
                .chain(self.compact.iter().flat_map(CompactStage::resources)),
        )
    }
}
