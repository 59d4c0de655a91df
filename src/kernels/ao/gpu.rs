//! The AO kernel on the GPU: pass `ao joints` uploads the frame's joint matrices, `ao skin`
//! skins the vertices and sphere centres, `ao occlusion` evaluates each vertex's visibility
//! over a cut through the skinned sphere tree. Created from a [`Prepared`] (packed and
//! checked on the CPU, `pack.rs`).

use super::formula::{OcclusionTable, TABLE_SIZE};
use super::pack::{check_correction, check_matrices};
use super::{AoParams, Prepared, cpu};
use crate::error::Result;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, Readback, Recorder, Resource, Shader,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::Mat4;

/// Pass names, as they appear in timings and debug labels.
pub const PASS_JOINTS: &str = "ao joints";
pub const PASS_SKIN: &str = "ao skin";
pub const PASS_OCCLUSION: &str = "ao occlusion";

/// GPU outputs of one frame, read back to the host.
pub struct FrameReadback {
    visibility: Readback,
    stats: Readback,
    positions: Readback,
    normals: Readback,
}

/// Host copies of one frame's outputs.
#[derive(Clone, Debug)]
pub struct FrameData {
    pub visibility: Vec<f32>,
    /// (spheres tested, spheres contributing) per vertex.
    pub stats: Vec<[u32; 2]>,
    pub positions: Vec<[f32; 4]>,
    pub normals: Vec<[f32; 4]>,
}

impl FrameReadback {
    /// The data, once the recorder that read it back has been submitted.
    pub fn data(&self) -> Result<FrameData> {
        Ok(FrameData {
            visibility: self.visibility.to_vec()?,
            stats: self.stats.to_vec()?,
            positions: self.positions.to_vec()?,
            normals: self.normals.to_vec()?,
        })
    }
}

/// The kernel's buffers.
struct Buffers {
    /// The rest pose and skin weights ([`Prepared`]): vertices (position, normal, four joints
    /// and weights) and sphere-tree nodes (centre and radius, joints and weights).
    rest_positions: Buffer,
    rest_normals: Buffer,
    vertex_joints: Buffer,
    vertex_weights: Buffer,
    rest_spheres: Buffer,
    sphere_joints: Buffer,
    sphere_weights: Buffer,
    /// The occlusion table ([`OcclusionTable`]).
    table: Buffer,
    /// Per-vertex static correction factors ([`super::Correction`]; 1 until set).
    correction: Buffer,
    /// The frame's joint matrices.
    joint_matrices: Buffer,
    /// Posed vertices and spheres (and each node's extent), visibility and stats per vertex:
    /// storage buffers that can also feed a renderer's vertex input directly.
    posed_positions: Buffer,
    posed_normals: Buffer,
    posed_spheres: Buffer,
    posed_extents: Buffer,
    visibility: Buffer,
    stats: Buffer,
}

impl Buffers {
    /// Creates the buffers and records the uploads of the mesh, tree and table into `rec`.
    fn new(rec: &mut Recorder, prep: &Prepared, table: &OcclusionTable) -> Result<Buffers> {
        use bytemuck::cast_slice as bytes;
        let ctx = rec.context();
        let mut upload = |name: &str, data: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(data.len() as u64), data)
        };
        let (nv, ns) = (prep.positions.len() as u64, prep.spheres.len() as u64);
        let output = |name: &str, size: u64| {
            let desc = BufferDesc::storage(size).usage(vk::BufferUsageFlags::VERTEX_BUFFER);
            Buffer::new(&ctx, name, desc)
        };
        let joints = BufferDesc::storage(prep.joint_count as u64 * 64);
        Ok(Buffers {
            rest_positions: upload("ao rest positions", bytes(&prep.positions))?,
            rest_normals: upload("ao rest normals", bytes(&prep.normals))?,
            vertex_joints: upload("ao vertex joints", bytes(&prep.vertex_joints))?,
            vertex_weights: upload("ao vertex weights", bytes(&prep.vertex_weights))?,
            rest_spheres: upload("ao rest spheres", bytes(&prep.spheres))?,
            sphere_joints: upload("ao sphere joints", bytes(&prep.sphere_joints))?,
            sphere_weights: upload("ao sphere weights", bytes(&prep.sphere_weights))?,
            table: upload("ao table", bytes(&table.values))?,
            correction: upload("ao correction", bytes(&vec![1.0f32; nv as usize]))?,
            joint_matrices: Buffer::new(&ctx, "ao joint matrices", joints)?,
            posed_positions: output("ao posed positions", nv * 16)?,
            posed_normals: output("ao posed normals", nv * 16)?,
            posed_spheres: output("ao posed spheres", ns * 16)?,
            posed_extents: output("ao posed extents", ns * 4)?,
            visibility: output("ao visibility", nv * 4)?,
            stats: output("ao stats", nv * 8)?,
        })
    }

    /// Every buffer, with the name the shaders bind it by: the passes bind by these names,
    /// and the memory report counts them all.
    fn by_binding(&self) -> [(&'static str, &Buffer); 16] {
        [
            ("rest_pos", &self.rest_positions),
            ("rest_nrm", &self.rest_normals),
            ("vjoints", &self.vertex_joints),
            ("vweights", &self.vertex_weights),
            ("rest_sph", &self.rest_spheres),
            ("sjoints", &self.sphere_joints),
            ("sweights", &self.sphere_weights),
            ("table", &self.table),
            ("correction", &self.correction),
            ("joints", &self.joint_matrices),
            ("pos", &self.posed_positions),
            ("nrm", &self.posed_normals),
            ("sph", &self.posed_spheres),
            ("ext", &self.posed_extents),
            ("ao", &self.visibility),
            ("stats", &self.stats),
        ]
    }

    /// Binds each binding of `pipeline` to the buffer of that name; those in `writes` are
    /// declared as written only (`writeonly` in GLSL).
    fn bind(&self, pipeline: &ComputePipeline, writes: &[&str]) -> Result<BindGroup> {
        let table = self.by_binding();
        let lookup = |b: &str| {
            table
                .iter()
                .find(|(n, _)| *n == b)
                .map(|(_, r)| Resource::Buffer(r))
        };
        let w = AccessSet::from(A::ComputeShaderWrite);
        let writes: Vec<(&str, AccessSet)> = writes.iter().map(|&b| (b, w)).collect();
        pipeline.bind_from(lookup, &writes)
    }
}

/// The skinning pass writes the posed vertices and spheres.
const SKIN_WRITES: [&str; 4] = ["pos", "nrm", "sph", "ext"];
/// The occlusion pass writes the visibility and stats.
const OCCLUSION_WRITES: [&str; 2] = ["ao", "stats"];

/// The GPU kernel: pipelines, inputs and outputs of one character.
pub struct AoKernel {
    ctx: Context,
    skin: ComputePipeline,
    skin_bind: BindGroup,
    /// The occlusion shader, specialised again when a mode changes ([`AoKernel::set_params`]).
    occlusion_shader: Shader,
    occlusion: ComputePipeline,
    occlusion_bind: BindGroup,
    buffers: Buffers,
    vertex_count: u32,
    shape: cpu::TreeShape,
    joint_count: usize,
    table: OcclusionTable,
    params: AoParams,
}

impl AoKernel {
    /// Creates the buffers and pipelines, and records the uploads of the mesh, tree and
    /// table into `rec` (they run when the caller submits it; nothing is submitted here).
    pub fn new(rec: &mut Recorder, prep: &Prepared, params: AoParams) -> Result<AoKernel> {
        params.validate()?;
        prep.check()?;
        let ctx = rec.context();
        let skin = crate::shaders::pipeline(&ctx, "ao/skin")?;
        let occlusion_shader =
            Shader::from_spirv("ao/occlusion", crate::shaders::spirv("ao/occlusion")?)?;
        let table = OcclusionTable::new(TABLE_SIZE, TABLE_SIZE);
        let buffers = Buffers::new(rec, prep, &table)?;
        let skin_bind = buffers.bind(&skin, &SKIN_WRITES)?;
        let occlusion =
            ComputePipeline::specialized(&ctx, &occlusion_shader, &params.specialization())?;
        Ok(AoKernel {
            skin,
            skin_bind,
            occlusion_bind: buffers.bind(&occlusion, &OCCLUSION_WRITES)?,
            occlusion,
            occlusion_shader,
            ctx,
            buffers,
            vertex_count: prep.positions.len() as u32,
            shape: prep.shape,
            joint_count: prep.joint_count,
            table,
            params,
        })
    }

    /// The method parameters in use.
    pub fn params(&self) -> &AoParams {
        &self.params
    }

    /// The occlusion table in use.
    pub fn table(&self) -> &OcclusionTable {
        &self.table
    }

    /// Changes the parameters. Modes (occlusion, blend, clamp, correction) are
    /// specialization constants: changing one builds the pipeline for it (the old one is
    /// retired once the work using it completes); tau is a push constant and costs nothing.
    pub fn set_params(&mut self, params: AoParams) -> Result<()> {
        params.validate()?;
        if params.specialization() != self.params.specialization() {
            let constants = params.specialization();
            let occlusion =
                ComputePipeline::specialized(&self.ctx, &self.occlusion_shader, &constants)?;
            self.occlusion_bind = self.buffers.bind(&occlusion, &OCCLUSION_WRITES)?;
            self.occlusion = occlusion;
        }
        self.params = params;
        Ok(())
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count as usize
    }

    /// Per-vertex visibility (f32), written by [`AoKernel::record`]. A caller that reads it
    /// (e.g. as a vertex buffer) declares that with `Recorder::use_buffer`, so the next
    /// frame's write waits for it.
    pub fn visibility(&self) -> &Buffer {
        &self.buffers.visibility
    }

    /// Posed positions (vec4), written by the skinning pass.
    pub fn posed_positions(&self) -> &Buffer {
        &self.buffers.posed_positions
    }

    /// The posed spheres buffer (vec4 centre + radius per node).
    pub fn posed_spheres(&self) -> &Buffer {
        &self.buffers.posed_spheres
    }

    /// Records one frame: passes `ao joints` (the joint matrices' upload), `ao skin` and
    /// `ao occlusion`. Barriers come from the declared accesses through the recorder's
    /// tracking (or are planned by the caller, see [`Kernel::plan_pass`]). The matrices are
    /// staged through the context's ring, so frames in flight never overwrite each other's.
    pub fn record(&self, rec: &mut Recorder, matrices: &[Mat4]) -> Result<()> {
        Kernel::record(self, rec, matrices)
    }

    /// Records the occlusion dispatch alone (no labelled pass), e.g. to re-evaluate with
    /// other parameters after a frame was skinned (barriers from the declared accesses).
    pub fn record_occlusion(&self, rec: &mut Recorder) -> Result<()> {
        self.occlusion_args(&[])?
            .record(rec, &self.occlusion, &self.occlusion_bind)
    }

    /// Records copies of the outputs back to the host (after [`AoKernel::record`]).
    pub fn read_back(&self, rec: &mut Recorder) -> Result<FrameReadback> {
        let b = &self.buffers;
        Ok(FrameReadback {
            visibility: rec.read_back(&b.visibility)?,
            stats: rec.read_back(&b.stats)?,
            positions: rec.read_back(&b.posed_positions)?,
            normals: rec.read_back(&b.posed_normals)?,
        })
    }

    /// Records the upload of per-vertex static correction factors (used when
    /// `params.correct` is set; until then they are all 1).
    pub fn set_correction(&self, rec: &mut Recorder, factors: &[f32]) -> Result<()> {
        check_correction(factors, self.vertex_count as usize)?;
        rec.upload(&self.buffers.correction, 0, factors)
    }

    /// Device memory held by the kernel's buffers: `used_bytes` and `allocations` are the
    /// kernel's own; `reserved_bytes` is the context's (blocks are shared).
    pub fn memory(&self) -> MemoryReport {
        self.ctx
            .memory_of(&self.buffers.by_binding().map(|(_, b)| b))
    }

    /// Bytes of the kernel's buffers (their allocations).
    pub fn memory_bytes(&self) -> u64 {
        self.memory().used_bytes
    }

    fn joint_bytes(&self, matrices: &[Mat4]) -> Result<Vec<u8>> {
        let cols: Vec<[f32; 16]> = matrices.iter().map(|m| m.to_cols_array()).collect();
        Ok(bytemuck::cast_slice(&cols).to_vec())
    }

    fn skin_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        let s = self.shape;
        let words = [self.vertex_count, s.node_count, s.branch, s.first_leaf];
        let grid = Grid::Invocations([self.vertex_count + s.node_count, 1, 1]);
        Ok(Dispatch::words(&words, grid))
    }

    fn occlusion_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        self.params.validate()?;
        let s = self.shape;
        let words = [
            self.vertex_count,
            s.node_count,
            s.branch,
            s.first_leaf,
            self.params.tau.to_bits(),
            self.table.n_psi,
            self.table.n_theta,
            self.params.band.to_bits(),
        ];
        let grid = Grid::Invocations([self.vertex_count, 1, 1]);
        Ok(Dispatch::words(&words, grid))
    }
}

impl Kernel for AoKernel {
    type Input = [Mat4];
    type Readback = FrameReadback;
    type Output = FrameData;

    fn name(&self) -> &'static str {
        "ao"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::upload(PASS_JOINTS, &self.buffers.joint_matrices, Self::joint_bytes),
            Pass::dispatch(PASS_SKIN, &self.skin, &self.skin_bind, Self::skin_args),
            Pass::dispatch(
                PASS_OCCLUSION,
                &self.occlusion,
                &self.occlusion_bind,
                Self::occlusion_args,
            ),
        ]
    }

    fn check_input(&self, matrices: &[Mat4]) -> Result<()> {
        check_matrices(matrices, self.joint_count)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<FrameReadback> {
        AoKernel::read_back(self, rec)
    }

    fn collect(&self, readback: &FrameReadback) -> Result<FrameData> {
        readback.data()
    }

    fn memory(&self) -> MemoryReport {
        AoKernel::memory(self)
    }
}
