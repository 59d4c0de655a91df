//! Hierarchical sphere ambient occlusion for skinned characters.
//!
//! Per frame, on the GPU: pass `ao skin` skins the vertices (positions, normals) and the sphere
//! centres with linear blend skinning; pass `ao occlusion` computes each vertex's ambient
//! visibility from a cut through the skinned sphere tree (see `glsl/ao/occlusion.comp`).
//! [`AoKernel::record`] puts both into a caller's command buffer; outputs stay on the GPU
//! (`visibility()` is usable as a vertex buffer) until read back.

pub mod cpu;
pub mod formula;
mod registry;

pub use registry::{DEFAULT_ANIMATION, DEFAULT_MESH, GENERATED_INCLUDES};

use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Readback,
    Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use crate::scene::{Mesh, SphereTree};
use ash::vk;
use formula::{OcclusionTable, TABLE_SIZE};
use glam::Mat4;

/// How each sphere's occlusion is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Occlusion {
    /// Bilinear lookup in the precomputed (solid angle, angle to normal) table.
    Table,
    /// The closed form, evaluated per sphere.
    Exact,
}

/// How the occlusion of several spheres combines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Blend {
    /// V = prod(1 - I_i): right for independent caps, wrong for overlapping ones.
    Product,
    /// V = 1 - sum I_i: exact for disjoint caps, overcounts overlap.
    Sum,
    /// Cone-mask union: sum I_i scaled by |union of cap masks| / sum of mask counts over 128
    /// cosine-distributed directions; exact for disjoint and for coincident caps.
    Mask,
}

/// How the cut decides to refine an inner node: when size > tau * distance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Refine {
    /// size = the node's radius (the published test).
    Radius,
    /// size = the node's extent: the farthest reach of its skinned leaves from its centre.
    /// An elongated cluster (an arm) is refined when its leaves come near, not only when its
    /// compact sphere does.
    Extent,
}

/// Method parameters. tau is a push constant; the modes are specialization constants of
/// the occlusion pipeline (see [`AoKernel::set_params`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct AoParams {
    /// Refine an inner node when size / distance > tau; in (0, 1].
    pub tau: f32,
    pub refine: Refine,
    pub occlusion: Occlusion,
    pub blend: Blend,
    /// A receiver inside a leaf sphere: clamp h to 1 (true) or skip that sphere (false).
    pub clamp_inside: bool,
    /// Multiply by the static correction factors (see [`Correction`]).
    pub correct: bool,
}

impl Default for AoParams {
    fn default() -> Self {
        AoParams {
            tau: 0.8,
            refine: Refine::Extent,
            occlusion: Occlusion::Table,
            blend: Blend::Mask,
            clamp_inside: false,
            correct: true,
        }
    }
}

impl AoParams {
    pub fn validate(&self) -> Result<()> {
        if !(self.tau > 0.0 && self.tau <= 1.0) {
            return Err(Error::InvalidArgument(format!(
                "tau = {} is outside (0, 1]",
                self.tau
            )));
        }
        Ok(())
    }

    /// The occlusion pipeline's specialization constants for these parameters.
    fn specialization(&self) -> [(&'static str, u32); 5] {
        [
            ("EXACT", (self.occlusion == Occlusion::Exact) as u32),
            (
                "BLEND",
                match self.blend {
                    Blend::Product => 0,
                    Blend::Sum => 1,
                    Blend::Mask => 2,
                },
            ),
            ("CLAMP_INSIDE", self.clamp_inside as u32),
            ("CORRECT", self.correct as u32),
            ("REFINE", (self.refine == Refine::Extent) as u32),
        ]
    }
}

/// Mesh and tree in the GPU's layout (also what the CPU implementation reads).
#[derive(Clone, Debug)]
pub struct Prepared {
    pub positions: Vec<[f32; 4]>,
    pub normals: Vec<[f32; 4]>,
    /// Four u16 joint indices packed in two u32.
    pub vertex_joints: Vec<[u32; 2]>,
    pub vertex_weights: Vec<[f32; 4]>,
    /// (centre, radius) of every tree node, root first; radius < 0 = unused.
    pub spheres: Vec<[f32; 4]>,
    pub sphere_joints: Vec<[u32; 2]>,
    pub sphere_weights: Vec<[f32; 4]>,
    pub shape: cpu::TreeShape,
    pub joint_count: usize,
}

fn pack(j: [u16; 4]) -> [u32; 2] {
    [
        j[0] as u32 | (j[1] as u32) << 16,
        j[2] as u32 | (j[3] as u32) << 16,
    ]
}

impl Prepared {
    /// Checks the mesh, tree and rig agree and lays them out for the GPU.
    pub fn new(mesh: &Mesh, tree: &SphereTree, joint_count: usize) -> Result<Prepared> {
        let skin = mesh.skin.as_ref().ok_or_else(|| {
            Error::InvalidArgument(format!("mesh '{}' has no skin weights", mesh.name))
        })?;
        if tree.spheres.len() != tree.joints.len() || tree.spheres.len() != tree.weights.len() {
            return Err(Error::InvalidArgument(
                "sphere tree lacks skin weights (call assign_skin)".into(),
            ));
        }
        tree.check_shape()?;
        let first_leaf = tree.level_range(tree.levels - 1).start as u32;
        let prep = Prepared {
            positions: mesh
                .positions
                .iter()
                .map(|p| p.extend(1.0).to_array())
                .collect(),
            normals: mesh
                .normals
                .iter()
                .map(|n| n.extend(0.0).to_array())
                .collect(),
            vertex_joints: skin.joints.iter().map(|&j| pack(j)).collect(),
            vertex_weights: skin.weights.clone(),
            spheres: tree
                .spheres
                .iter()
                .map(|s| s.center.extend(s.radius).to_array())
                .collect(),
            sphere_joints: tree.joints.iter().map(|&j| pack(j)).collect(),
            sphere_weights: tree.weights.clone(),
            shape: cpu::TreeShape {
                node_count: tree.spheres.len() as u32,
                branch: tree.branch,
                first_leaf,
            },
            joint_count,
        };
        prep.check()?;
        Ok(prep)
    }

    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Checks that every array has the length the shaders index it with (the fields are
    /// public, so a caller can break this; the GPU must never read out of bounds).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| {
            Err(Error::InvalidArgument(format!(
                "inconsistent AO input: {what}"
            )))
        };
        let nv = self.positions.len();
        if nv == 0 || nv > u32::MAX as usize / 2 {
            return bad(format!("{nv} vertices"));
        }
        for (name, len) in [
            ("normals", self.normals.len()),
            ("vertex joints", self.vertex_joints.len()),
            ("vertex weights", self.vertex_weights.len()),
        ] {
            if len != nv {
                return bad(format!("{len} {name} for {nv} vertices"));
            }
        }
        let shape = self.shape;
        let mut expected = 0u64;
        let mut width = 1u64;
        let mut first_leaf = 0u64;
        while expected < shape.node_count as u64 {
            first_leaf = expected;
            expected += width;
            width *= shape.branch.max(1) as u64;
        }
        if shape.branch < 2
            || expected != shape.node_count as u64
            || first_leaf != shape.first_leaf as u64
            || shape.first_leaf == 0
        {
            return bad(format!(
                "{} nodes with branch {} and first leaf {} is not a complete tree of two or more levels",
                shape.node_count, shape.branch, shape.first_leaf
            ));
        }
        for (name, len) in [
            ("spheres", self.spheres.len()),
            ("sphere joints", self.sphere_joints.len()),
            ("sphere weights", self.sphere_weights.len()),
        ] {
            if len != shape.node_count as usize {
                return bad(format!("{len} {name} for {} nodes", shape.node_count));
            }
        }
        let unpack = |p: &[u32; 2]| [p[0] & 0xffff, p[0] >> 16, p[1] & 0xffff, p[1] >> 16];
        if self
            .vertex_joints
            .iter()
            .chain(&self.sphere_joints)
            .flat_map(unpack)
            .any(|j| j as usize >= self.joint_count)
        {
            return bad(format!(
                "a joint index beyond the rig's {} joints",
                self.joint_count
            ));
        }
        let finite = |v: &[[f32; 4]]| v.iter().flatten().all(|x| x.is_finite());
        if !finite(&self.positions) || !finite(&self.normals) || !finite(&self.spheres) {
            return bad("non-finite positions, normals or spheres".into());
        }
        Ok(())
    }
}

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

/// The GPU kernel: pipelines, inputs and outputs of one character.
pub struct AoKernel {
    ctx: Context,
    skin: ComputePipeline,
    skin_bind: BindGroup,
    occlusion_shader: crate::gpu::Shader,
    occlusion: ComputePipeline,
    occlusion_bind: BindGroup,
    table_buf: Buffer,
    joints: Buffer,
    correction: Buffer,
    // Inputs, kept alive for the bind groups.
    inputs: Vec<Buffer>,
    positions: Buffer,
    normals: Buffer,
    spheres: Buffer,
    extents: Buffer,
    visibility: Buffer,
    stats: Buffer,
    vertex_count: u32,
    shape: cpu::TreeShape,
    joint_count: usize,
    table: OcclusionTable,
    params: AoParams,
}

/// Pass names, as they appear in timings and debug labels.
pub const PASS_JOINTS: &str = "ao joints";
pub const PASS_SKIN: &str = "ao skin";
pub const PASS_OCCLUSION: &str = "ao occlusion";

impl AoKernel {
    /// Creates the buffers and pipelines, and records the uploads of the mesh, tree and
    /// table into `rec` (they run when the caller submits it; nothing is submitted here).
    pub fn new(rec: &mut Recorder, prep: &Prepared, params: AoParams) -> Result<AoKernel> {
        params.validate()?;
        prep.check()?;
        let ctx = rec.context();
        let spv = |name| crate::shaders::spirv(name);
        let skin = ComputePipeline::from_spirv(&ctx, "ao/skin", spv("ao/skin")?)?;
        let occlusion_shader =
            crate::gpu::Shader::from_spirv("ao/occlusion", spv("ao/occlusion")?)?;
        let table = OcclusionTable::new(TABLE_SIZE, TABLE_SIZE);
        let nv = prep.positions.len() as u64;
        let ns = prep.spheres.len() as u64;
        let mut upload = |name: &str, data: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(data.len() as u64), data)
        };
        let rest_pos = upload("ao rest positions", bytemuck::cast_slice(&prep.positions))?;
        let rest_nrm = upload("ao rest normals", bytemuck::cast_slice(&prep.normals))?;
        let vjoints = upload(
            "ao vertex joints",
            bytemuck::cast_slice(&prep.vertex_joints),
        )?;
        let vweights = upload(
            "ao vertex weights",
            bytemuck::cast_slice(&prep.vertex_weights),
        )?;
        let rest_sph = upload("ao rest spheres", bytemuck::cast_slice(&prep.spheres))?;
        let sjoints = upload(
            "ao sphere joints",
            bytemuck::cast_slice(&prep.sphere_joints),
        )?;
        let sweights = upload(
            "ao sphere weights",
            bytemuck::cast_slice(&prep.sphere_weights),
        )?;
        let table_buf = upload("ao table", bytemuck::cast_slice(&table.values))?;
        let correction = upload(
            "ao correction",
            bytemuck::cast_slice(&vec![1.0f32; nv as usize]),
        )?;
        let joints = Buffer::new(
            &ctx,
            "ao joint matrices",
            BufferDesc::storage(prep.joint_count as u64 * 64),
        )?;
        // Outputs can also feed a renderer's vertex input directly.
        let output = |name: &str, size: u64| {
            Buffer::new(
                &ctx,
                name,
                BufferDesc::storage(size).usage(vk::BufferUsageFlags::VERTEX_BUFFER),
            )
        };
        let positions = output("ao posed positions", nv * 16)?;
        let normals = output("ao posed normals", nv * 16)?;
        let spheres = output("ao posed spheres", ns * 16)?;
        let extents = output("ao posed extents", ns * 4)?;
        let visibility = output("ao visibility", nv * 4)?;
        let stats = output("ao stats", nv * 8)?;
        // The outputs are `writeonly` in GLSL: declared as writes only.
        let w = AccessSet::from(A::ComputeShaderWrite);
        let skin_bind = skin.bind_declared(
            &[
                ("joints", Resource::Buffer(&joints)),
                ("rest_pos", Resource::Buffer(&rest_pos)),
                ("rest_nrm", Resource::Buffer(&rest_nrm)),
                ("vjoints", Resource::Buffer(&vjoints)),
                ("vweights", Resource::Buffer(&vweights)),
                ("rest_sph", Resource::Buffer(&rest_sph)),
                ("sjoints", Resource::Buffer(&sjoints)),
                ("sweights", Resource::Buffer(&sweights)),
                ("pos", Resource::Buffer(&positions)),
                ("nrm", Resource::Buffer(&normals)),
                ("sph", Resource::Buffer(&spheres)),
                ("ext", Resource::Buffer(&extents)),
            ],
            &[("pos", w), ("nrm", w), ("sph", w), ("ext", w)],
        )?;
        let (occlusion, occlusion_bind) = Self::occlusion_pipeline(
            &ctx,
            &occlusion_shader,
            &params,
            [
                &positions,
                &normals,
                &spheres,
                &table_buf,
                &correction,
                &visibility,
                &stats,
                &extents,
            ],
        )?;
        Ok(AoKernel {
            ctx,
            skin,
            skin_bind,
            occlusion_shader,
            occlusion,
            occlusion_bind,
            table_buf,
            joints,
            correction,
            inputs: vec![
                rest_pos, rest_nrm, vjoints, vweights, rest_sph, sjoints, sweights,
            ],
            positions,
            normals,
            spheres,
            extents,
            visibility,
            stats,
            vertex_count: nv as u32,
            shape: prep.shape,
            joint_count: prep.joint_count,
            table,
            params,
        })
    }

    /// The occlusion pipeline specialised for `params`, and its bindings (in the order
    /// positions, normals, spheres, table, correction, visibility, stats, extents).
    fn occlusion_pipeline(
        ctx: &Context,
        shader: &crate::gpu::Shader,
        params: &AoParams,
        b: [&Buffer; 8],
    ) -> Result<(ComputePipeline, BindGroup)> {
        let pipeline = ComputePipeline::specialized(ctx, shader, &params.specialization())?;
        let w = AccessSet::from(A::ComputeShaderWrite);
        let bind = pipeline.bind_declared(
            &[
                ("pos", Resource::Buffer(b[0])),
                ("nrm", Resource::Buffer(b[1])),
                ("sph", Resource::Buffer(b[2])),
                ("table", Resource::Buffer(b[3])),
                ("correction", Resource::Buffer(b[4])),
                ("ao", Resource::Buffer(b[5])),
                ("stats", Resource::Buffer(b[6])),
                ("ext", Resource::Buffer(b[7])),
            ],
            &[("ao", w), ("stats", w)],
        )?;
        Ok((pipeline, bind))
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
            let (p, b) = Self::occlusion_pipeline(
                &self.ctx,
                &self.occlusion_shader,
                &params,
                [
                    &self.positions,
                    &self.normals,
                    &self.spheres,
                    &self.table_buf,
                    &self.correction,
                    &self.visibility,
                    &self.stats,
                    &self.extents,
                ],
            )?;
            self.occlusion = p;
            self.occlusion_bind = b;
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
        &self.visibility
    }

    /// Posed positions (vec4), written by the skinning pass.
    pub fn posed_positions(&self) -> &Buffer {
        &self.positions
    }

    /// The posed spheres buffer (vec4 centre + radius per node).
    pub fn posed_spheres(&self) -> &Buffer {
        &self.spheres
    }

    /// Records one frame: passes `ao joints` (the joint matrices' upload), `ao skin` and
    /// `ao occlusion`. Barriers come from the declared accesses through the recorder's
    /// tracking (or are planned by the caller, see [`Kernel::plan_pass`]). The matrices are
    /// staged through the context's ring, so frames in flight never overwrite each other's.
    pub fn record(&self, rec: &mut Recorder, matrices: &[Mat4]) -> Result<()> {
        Kernel::record(self, rec, matrices)
    }

    fn check_matrices(&self, matrices: &[Mat4]) -> Result<()> {
        if matrices.len() != self.joint_count {
            return Err(Error::InvalidArgument(format!(
                "{} joint matrices for a rig of {} joints",
                matrices.len(),
                self.joint_count
            )));
        }
        if let Some(i) = matrices.iter().position(|m| !m.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "joint matrix {i} is not finite"
            )));
        }
        Ok(())
    }

    fn joint_bytes(&self, matrices: &[Mat4]) -> Result<Vec<u8>> {
        let cols: Vec<[f32; 16]> = matrices.iter().map(|m| m.to_cols_array()).collect();
        Ok(bytemuck::cast_slice(&cols).to_vec())
    }

    fn skin_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        let ns = self.shape.node_count;
        Ok(Dispatch::words(
            &[
                self.vertex_count,
                ns,
                self.shape.branch,
                self.shape.first_leaf,
            ],
            Grid::Invocations([self.vertex_count + ns, 1, 1]),
        ))
    }

    fn occlusion_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        self.params.validate()?;
        let p = &self.params;
        Ok(Dispatch::words(
            &[
                self.vertex_count,
                self.shape.node_count,
                self.shape.branch,
                self.shape.first_leaf,
                p.tau.to_bits(),
                self.table.n_psi,
                self.table.n_theta,
            ],
            Grid::Invocations([self.vertex_count, 1, 1]),
        ))
    }

    /// Records the occlusion dispatch alone (no labelled pass), e.g. to re-evaluate with
    /// other parameters after a frame was skinned (barriers from the declared accesses).
    pub fn record_occlusion(&self, rec: &mut Recorder) -> Result<()> {
        self.occlusion_args(&[])?
            .record(rec, &self.occlusion, &self.occlusion_bind)
    }

    /// Records copies of the outputs back to the host (after [`AoKernel::record`]).
    pub fn read_back(&self, rec: &mut Recorder) -> Result<FrameReadback> {
        Ok(FrameReadback {
            visibility: rec.read_back(&self.visibility)?,
            stats: rec.read_back(&self.stats)?,
            positions: rec.read_back(&self.positions)?,
            normals: rec.read_back(&self.normals)?,
        })
    }

    /// Records the upload of per-vertex static correction factors (used when
    /// `params.correct` is set; until then they are all 1).
    pub fn set_correction(&self, rec: &mut Recorder, factors: &[f32]) -> Result<()> {
        if factors.len() != self.vertex_count as usize {
            return Err(Error::InvalidArgument(format!(
                "{} correction factors for {} vertices",
                factors.len(),
                self.vertex_count
            )));
        }
        if let Some(i) = factors.iter().position(|f| !f.is_finite() || *f < 0.0) {
            return Err(Error::InvalidArgument(format!(
                "correction factor {i} is negative or not finite"
            )));
        }
        rec.upload(&self.correction, 0, factors)
    }

    /// Device memory held by the kernel's buffers: `used_bytes` and `allocations` are the
    /// kernel's own; `reserved_bytes` is the context's (blocks are shared).
    pub fn memory(&self) -> crate::gpu::MemoryReport {
        let own = [
            &self.joints,
            &self.correction,
            &self.table_buf,
            &self.positions,
            &self.normals,
            &self.spheres,
            &self.extents,
            &self.visibility,
            &self.stats,
        ];
        let all: Vec<&Buffer> = own.into_iter().chain(self.inputs.iter()).collect();
        self.ctx.memory_of(&all)
    }

    /// Bytes of the kernel's buffers (their allocations).
    pub fn memory_bytes(&self) -> u64 {
        self.memory().used_bytes
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
            Pass::upload(PASS_JOINTS, &self.joints, Self::joint_bytes),
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
        self.check_matrices(matrices)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<FrameReadback> {
        AoKernel::read_back(self, rec)
    }

    fn collect(&self, readback: &FrameReadback) -> Result<FrameData> {
        readback.data()
    }

    fn memory(&self) -> crate::gpu::MemoryReport {
        AoKernel::memory(self)
    }
}

/// The static correction: per-vertex factors baked once in the bind pose that restore the
/// detail a sphere set cannot represent (geometry buried under overlapping shells, thin
/// folds, grooves between tight parts).
///
/// factor = V_mesh / V_method in the bind pose, capped at [`Correction::cap`]; V_mesh is
/// ray-traced against the bind-pose mesh, V_method is this method's own result there with
/// the same parameters. In the bind pose the corrected method thus equals the ray-traced
/// mesh; in other poses the spheres carry the change. It is an addition to the published
/// method; `correct: false` gives the method alone.
#[derive(Clone, Debug)]
pub struct Correction {
    /// Ray-traced visibility of every vertex in the bind pose.
    pub bind_visibility: Vec<f32>,
    /// Upper bound of a factor (factors > 1 brighten where the spheres over-occlude).
    pub cap: f32,
}

impl Correction {
    /// Ray-traces the bind pose (`rays` per vertex; its own seed, independent of any
    /// reference the result is later compared with).
    pub fn bake(mesh: &Mesh, rays: usize) -> Correction {
        let (lo, hi) = mesh.bounds();
        let cfg = crate::reference::ao::RayConfig {
            rays,
            seed: 0xba4e_d0ff,
            ..crate::reference::ao::RayConfig::for_scene((hi - lo).length())
        };
        let bvh = crate::geom::Bvh::build(&mesh.positions, &mesh.triangles);
        let all: Vec<usize> = (0..mesh.positions.len()).collect();
        Correction {
            bind_visibility: crate::reference::ao::mesh_visibility(
                &mesh.positions,
                &mesh.normals,
                &bvh,
                &all,
                &cfg,
            ),
            cap: 2.0,
        }
    }

    /// Factors for `params`: the method evaluated (on the CPU) in the bind pose.
    pub fn factors(&self, cpu_ao: &cpu::CpuAo, prep: &Prepared, params: &AoParams) -> Vec<f32> {
        // The bind pose: identity joint matrices (weights sum to 1).
        let bind = cpu::skin(prep, &vec![glam::Mat4::IDENTITY; prep.joint_count]);
        let plain = AoParams {
            correct: false,
            ..*params
        };
        cpu_ao
            .frame(&bind, prep.shape, &plain, None)
            .iter()
            .zip(&self.bind_visibility)
            .map(|(m, t)| {
                if m.visibility > 1e-3 {
                    (t / m.visibility).min(self.cap)
                } else {
                    1.0
                }
            })
            .collect()
    }
}
