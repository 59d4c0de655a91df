//! The AO kernel on the GPU: `ao skin` skins the sphere centres, `ao occlusion` evaluates each
//! vertex's visibility over a cut through the skinned sphere tree. The posed vertices (and the
//! frame's joint matrices) come from a [`PoseKernel`]: the character's own, shared with the
//! other kernels ([`AoKernel::on_pose`]; the caller records it), or one the AO kernel owns and
//! records first ([`AoKernel::new`]: passes `pose joints`, `pose skin`). Created from a
//! [`Prepared`] (packed and checked on the CPU, `pack.rs`).

use super::fixed::{FIXED_SLOTS, FixedCut};
use super::formula::{OcclusionTable, TABLE_SIZE, overlap_table};
use super::pack::{check_correction, check_matrices};
use super::{AoParams, Cut, Prepared, cpu};
use crate::error::Result;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource, Shader,
};
use crate::kernels::pose::{self, PoseKernel};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::{Mat4, Vec3};

/// Pass names, as they appear in timings and debug labels: the joint matrices' upload and the
/// vertex skinning are the pose kernel's (recorded by the AO kernel when it owns its pose).
pub const PASS_JOINTS: &str = pose::PASS_JOINTS;
/// The vertex skinning (the pose kernel's pass).
pub const PASS_POSE: &str = pose::PASS_SKIN;
/// The skinning of the sphere centres.
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
    /// The sphere-tree nodes (centre and radius, joints and weights; [`Prepared`]).
    rest_spheres: Buffer,
    sphere_joints: Buffer,
    sphere_weights: Buffer,
    /// Per node: 1 / its used children ([`child_shares`]).
    shares: Buffer,
    /// The vertices in the order the occlusion pass takes them
    /// ([`crate::geom::spatial_order`]; on Testwuson the mean of the subgroups' longest walks
    /// fell from 102.8 to 96.6 nodes, against 83.0 per vertex).
    order: Buffer,
    /// Per-vertex static correction factors ([`super::Correction`]; 1 until set).
    correction: Buffer,
    /// The pose kernel's: the frame's joint matrices, posed positions and normals.
    joint_matrices: Buffer,
    posed_positions: Buffer,
    posed_normals: Buffer,
    /// Posed spheres (and each node's extent), visibility and stats per vertex: storage
    /// buffers that can also feed a renderer's vertex input directly.
    posed_spheres: Buffer,
    posed_extents: Buffer,
    /// The posed tree as `ao occlusion` walks it, written by `ao skin` (glsl/ao/skin.comp).
    nodes: Image,
    /// The occlusion table as bilinear quads and [`super::formula::nearest_direction_table`]
    /// four indices a word, as `ao occlusion` reads them (glsl/ao/occlusion.comp).
    table_quads: Image,
    nearest_image: Image,
    visibility: Buffer,
    stats: Buffer,
    /// The fixed cut's lists and the pairwise overlap table ([`Cut::Fixed`] only).
    fixed: Option<FixedBuffers>,
}

/// What the fixed cut reads besides the shared resources (images, as glsl/ao/fixed.comp
/// reads them).
struct FixedBuffers {
    /// [`FixedCut::nodes`], slot-major, [`crate::kernels::table_row`] texels a row.
    nodes: Image,
    /// [`super::formula::OverlapTable`] as bilinear quads per slice.
    overlap: Image,
}

impl Buffers {
    /// Creates the buffers and records the uploads of the tree and table into `rec`; the
    /// posed vertices and joint matrices are `pose`'s.
    fn new(
        rec: &mut Recorder,
        prep: &Prepared,
        table: &OcclusionTable,
        pose: &PoseKernel,
        fixed: Option<&FixedCut>,
    ) -> Result<Buffers> {
        use bytemuck::cast_slice as bytes;
        let ctx = rec.context();
        // The tree's, the words' and the lists' images are `row_image`s (`NODE_ROW` wide).
        let table_quads = {
            let (w, h) = (table.n_psi, table.n_theta);
            let quads = table.quads();
            let image = Image::new(
                &ctx,
                "ao table quads",
                ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [w - 1, h - 1])
                    .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST),
            )?;
            rec.upload_image_rows(&image, &quads)?;
            image
        };
        let nearest_image = {
            let words = nearest_words();
            let image = crate::kernels::row_image(
                &ctx,
                "ao nearest directions",
                vk::Format::R32_UINT,
                words.len() as u64,
                vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST,
                "",
            )?;
            rec.upload_image_rows(&image, &words)?;
            image
        };
        let fixed = match fixed {
            Some(f) => Some(FixedBuffers {
                nodes: {
                    let image = crate::kernels::row_image(
                        &ctx,
                        "ao fixed cut",
                        vk::Format::R32_UINT,
                        f.nodes.len() as u64,
                        vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST,
                        "",
                    )?;
                    rec.upload_image_rows(&image, &f.nodes)?;
                    image
                },
                overlap: {
                    let t = overlap_table();
                    let quads = t.quads();
                    let image = Image::new(
                        &ctx,
                        "ao overlap table",
                        ImageDesc::d3(vk::Format::R32G32B32A32_SFLOAT, [t.n - 1, t.n - 1, t.n])
                            .usage(
                                vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST,
                            ),
                    )?;
                    let region = ImageRegion::whole(image.desc());
                    rec.upload_image(&image, region, bytemuck::cast_slice(&quads))?;
                    image
                },
            }),
            None => None,
        };
        let mut upload = |name: &str, data: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(data.len() as u64), data)
        };
        let (nv, ns) = (prep.positions.len() as u64, prep.spheres.len() as u64);
        let output = |name: &str, size: u64| {
            let desc = BufferDesc::storage(size).usage(vk::BufferUsageFlags::VERTEX_BUFFER);
            Buffer::new(&ctx, name, desc)
        };
        Ok(Buffers {
            rest_spheres: upload("ao rest spheres", bytes(&prep.spheres))?,
            sphere_joints: upload("ao sphere joints", bytes(&prep.sphere_joints))?,
            sphere_weights: upload("ao sphere weights", bytes(&prep.sphere_weights))?,
            shares: upload("ao child shares", bytes(&child_shares(prep)))?,
            order: upload(
                "ao vertex order",
                bytes(&crate::geom::spatial_order(
                    &prep
                        .positions
                        .iter()
                        .map(|p| Vec3::from_slice(&p[..3]))
                        .collect::<Vec<_>>(),
                )),
            )?,
            correction: upload("ao correction", bytes(&vec![1.0f32; nv as usize]))?,
            joint_matrices: pose.joint_matrices().clone(),
            posed_positions: pose.positions().clone(),
            posed_normals: pose.normals().clone(),
            posed_spheres: output("ao posed spheres", ns * 16)?,
            posed_extents: output("ao posed extents", ns * 4)?,
            nodes: crate::kernels::row_image(
                &ctx,
                "ao tree nodes",
                vk::Format::R32G32B32A32_SFLOAT,
                2 * ns,
                vk::ImageUsageFlags::STORAGE,
                "",
            )?,
            table_quads,
            nearest_image,
            visibility: output("ao visibility", nv * 4)?,
            stats: output("ao stats", nv * 8)?,
            fixed,
        })
    }

    /// Every buffer, with the name the shaders bind it by: the passes bind by these names.
    fn by_binding(&self) -> Vec<(&'static str, &Buffer)> {
        let all = vec![
            ("order", &self.order),
            ("share", &self.shares),
            ("rest_sph", &self.rest_spheres),
            ("sjoints", &self.sphere_joints),
            ("sweights", &self.sphere_weights),
            ("correction", &self.correction),
            ("joints", &self.joint_matrices),
            ("pos", &self.posed_positions),
            ("nrm", &self.posed_normals),
            ("sph", &self.posed_spheres),
            ("ext", &self.posed_extents),
            ("ao", &self.visibility),
            ("stats", &self.stats),
        ];
        all
    }

    /// The buffers the AO kernel owns (the memory report counts these; the pose's are the
    /// pose kernel's).
    fn own(&self) -> Vec<&Buffer> {
        let own = vec![
            &self.order,
            &self.rest_spheres,
            &self.shares,
            &self.sphere_joints,
            &self.sphere_weights,
            &self.correction,
            &self.posed_spheres,
            &self.posed_extents,
            &self.visibility,
            &self.stats,
        ];
        own
    }

    /// Binds each binding of `pipeline` to the buffer of that name; those in `writes` are
    /// declared as written only (`writeonly` in GLSL).
    fn bind(&self, pipeline: &ComputePipeline, writes: &[&str]) -> Result<BindGroup> {
        let table = self.by_binding();
        let lookup = |b: &str| {
            match b {
                "nodes" => return Some(Resource::storage_image(&self.nodes)),
                "table_quads" => return Some(Resource::storage_image(&self.table_quads)),
                "nearest" => return Some(Resource::storage_image(&self.nearest_image)),
                "fixed_nodes" => {
                    return self
                        .fixed
                        .as_ref()
                        .map(|f| Resource::storage_image(&f.nodes));
                }
                "overlap_quads" => {
                    return self
                        .fixed
                        .as_ref()
                        .map(|f| Resource::storage_image(&f.overlap));
                }
                _ => {}
            }
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

/// The occlusion pipeline's specialization constants: the modes, and the tree's branch
/// factor (the walk divides by it; a divisor known when the pipeline is built compiles to
/// shifts or multiplications where a push constant is divided lane by lane on SIMD drivers).
/// The fixed cut's pipeline (`ao/fixed`) takes the per-sphere modes only.
fn occlusion_constants(
    params: &AoParams,
    shape: cpu::TreeShape,
    row: u32,
) -> Vec<(&'static str, u32)> {
    let spec = params.specialization();
    let mut c: Vec<(&'static str, u32)> = match params.cut {
        Cut::Adaptive => {
            let mut c = spec.to_vec();
            c.push(("BRANCH", shape.branch));
            c.push(("LEVELS", shape.levels()));
            c
        }
        Cut::Fixed => spec
            .into_iter()
            .filter(|(name, _)| ["EXACT", "CLAMP_INSIDE", "CORRECT"].contains(name))
            .collect(),
    };
    c.push(("NODE_ROW", row));
    c
}

/// The occlusion pass's shader for a cut.
fn occlusion_shader_name(cut: Cut) -> &'static str {
    match cut {
        Cut::Adaptive => "ao/occlusion",
        Cut::Fixed => "ao/fixed",
    }
}

/// Per node, a child's weight share at alpha = 0 in the blended cut: 1 / the node's used
/// children (as `cpu::walk_cut` counts them; leaves and unused slots get 1, never read).
fn child_shares(prep: &Prepared) -> Vec<f32> {
    let (b, first_leaf) = (prep.shape.branch as usize, prep.shape.first_leaf as usize);
    (0..prep.spheres.len())
        .map(|n| {
            if n >= first_leaf {
                return 1.0;
            }
            let first = n * b + 1;
            let used = (first..first + b)
                .filter(|&c| prep.spheres.get(c).is_some_and(|s| s[3] >= 0.0))
                .count()
                .max(1);
            1.0 / used as f32
        })
        .collect()
}

/// [`super::formula::nearest_direction_table`] packed four 8-bit indices a word, as the
/// shader unpacks it.
fn nearest_words() -> Vec<u32> {
    super::formula::nearest_direction_table()
        .chunks(4)
        .map(|c| {
            c.iter()
                .enumerate()
                .fold(0u32, |w, (i, &k)| w | (k as u32) << (8 * i))
        })
        .collect()
}

/// The skinning pass writes the posed spheres and extents.
const SKIN_WRITES: [&str; 3] = ["sph", "ext", "nodes"];
/// The occlusion pass writes the visibility and stats.
const OCCLUSION_WRITES: [&str; 2] = ["ao", "stats"];

/// The GPU kernel: pipelines, inputs and outputs of one character.
pub struct AoKernel {
    ctx: Context,
    /// The pose this kernel owns and records first ([`AoKernel::new`]); `None` when the
    /// caller shares its character's pose and records it ([`AoKernel::on_pose`]).
    own_pose: Option<PoseKernel>,
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
    /// The fixed cut's lists ([`Cut::Fixed`]), chosen at construction.
    fixed: Option<FixedCut>,
    /// Whether a frame records pass `ao occlusion` ([`AoKernel::set_occlusion`]).
    occlusion_on: bool,
}

impl AoKernel {
    /// Creates the buffers and pipelines, and records the uploads of the mesh, tree and
    /// table into `rec` (they run when the caller submits it; nothing is submitted here).
    /// The kernel owns the pose of its vertices: its frames record `pose joints` and
    /// `pose skin` before `ao skin` and `ao occlusion`.
    pub fn new(rec: &mut Recorder, prep: &Prepared, params: AoParams) -> Result<AoKernel> {
        params.validate()?;
        prep.check()?;
        let pose_prep = pose::Prepared {
            positions: prep.positions.clone(),
            normals: prep.normals.clone(),
            tangents: pose::tangent_frames(
                &prep
                    .positions
                    .iter()
                    .map(|p| glam::Vec4::from_array(*p).truncate())
                    .collect::<Vec<_>>(),
                &prep
                    .normals
                    .iter()
                    .map(|n| glam::Vec4::from_array(*n).truncate())
                    .collect::<Vec<_>>(),
                None,
                &[],
            )
            .iter()
            .map(|t| t.to_array())
            .collect(),
            vertex_joints: prep.vertex_joints.clone(),
            vertex_weights: prep.vertex_weights.clone(),
            joint_count: prep.joint_count,
        };
        let pose = PoseKernel::new(rec, &pose_prep)?;
        let mut kernel = Self::build(rec, prep, params, &pose)?;
        kernel.own_pose = Some(pose);
        Ok(kernel)
    }

    /// As [`AoKernel::new`], on a character's shared pose: the occlusion reads `pose`'s posed
    /// vertices and the sphere skinning its joint matrices, and the caller records `pose`
    /// before this kernel each frame (barriers follow from the declared accesses). `prep`
    /// must describe the same vertices (its positions are the pose's rest positions).
    pub fn on_pose(
        rec: &mut Recorder,
        prep: &Prepared,
        params: AoParams,
        pose: &PoseKernel,
    ) -> Result<AoKernel> {
        params.validate()?;
        prep.check()?;
        if pose.vertex_count() != prep.vertex_count() || pose.joint_count() != prep.joint_count {
            return Err(crate::error::Error::InvalidArgument(format!(
                "the AO input has {} vertices and {} joints, the pose {} and {}",
                prep.vertex_count(),
                prep.joint_count,
                pose.vertex_count(),
                pose.joint_count()
            )));
        }
        Self::build(rec, prep, params, pose)
    }

    fn build(
        rec: &mut Recorder,
        prep: &Prepared,
        params: AoParams,
        pose: &PoseKernel,
    ) -> Result<AoKernel> {
        let ctx = rec.context();
        let skin = crate::shaders::pipeline_specialized(
            &ctx,
            "ao/skin",
            &[("NODE_ROW", crate::kernels::table_row(&ctx))],
        )?;
        let name = occlusion_shader_name(params.cut);
        let occlusion_shader = Shader::from_spirv(name, crate::shaders::spirv(name)?)?;
        let table = OcclusionTable::new(TABLE_SIZE, TABLE_SIZE);
        let fixed = match params.cut {
            Cut::Fixed => Some(FixedCut::select(prep, &params, FIXED_SLOTS)?),
            Cut::Adaptive => None,
        };
        let buffers = Buffers::new(rec, prep, &table, pose, fixed.as_ref())?;
        let skin_bind = buffers.bind(&skin, &SKIN_WRITES)?;
        let occlusion = ComputePipeline::specialized(
            &ctx,
            &occlusion_shader,
            &occlusion_constants(&params, prep.shape, crate::kernels::table_row(&ctx)),
        )?;
        Ok(AoKernel {
            own_pose: None,
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
            fixed,
            occlusion_on: true,
        })
    }

    /// The posed tree as an image, written by `ao skin` each frame beside
    /// [`AoKernel::posed_spheres`] and [`AoKernel::posed_extents`]: rgba32f,
    /// 4096 texels a row (fewer where `maxImageDimension2D` is smaller), texel 2n node n's
    /// sphere (centre, radius), texel 2n + 1 (its extent, 1 / its used children, 0, 0).
    /// What `ao occlusion` and the
    /// environment's shadow pass walk: on lavapipe an image load is one vector gather, a
    /// storage-buffer load at a per-lane address a loop over the lanes.
    pub fn tree_image(&self) -> &Image {
        &self.buffers.nodes
    }

    /// Whether a frame ([`AoKernel::record`], [`Kernel::record`]) computes the per-vertex
    /// visibility (pass `ao occlusion`; on by default). Off, a frame records `ao skin` alone:
    /// for a caller that reads only the posed sphere tree ([`AoKernel::posed_spheres`],
    /// [`AoKernel::posed_extents`]), such as the character frame whose environment is
    /// shadowed by the tree's caps and traced rays and reads no AO visibility. The
    /// visibility buffer is then not written, and [`AoKernel::read_back`] refuses (its
    /// contents would be another frame's, or none).
    pub fn set_occlusion(&mut self, on: bool) {
        self.occlusion_on = on;
    }

    /// Whether a frame computes the visibility ([`AoKernel::set_occlusion`]).
    pub fn occlusion(&self) -> bool {
        self.occlusion_on
    }

    /// The fixed cut's per-vertex lists, when the kernel was built with [`Cut::Fixed`] (the
    /// CPU twin evaluates the same lists: `cpu::CpuAo::fixed_frame`).
    pub fn fixed_cut(&self) -> Option<&FixedCut> {
        self.fixed.as_ref()
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
    ///
    /// The cut is chosen at construction: changing it is refused, and so, with the fixed
    /// cut, is changing tau or the refinement test its lists were chosen with.
    pub fn set_params(&mut self, params: AoParams) -> Result<()> {
        params.validate()?;
        if params.cut != self.params.cut {
            return Err(crate::error::Error::InvalidArgument(format!(
                "the AO kernel was built with the {:?} cut; build another for the {:?} cut",
                self.params.cut, params.cut
            )));
        }
        if params.cut == Cut::Fixed
            && (params.tau != self.params.tau || params.refine != self.params.refine)
        {
            return Err(crate::error::Error::InvalidArgument(format!(
                "the fixed cut's lists were chosen with tau {} and {:?} refinement; build \
                 another kernel for tau {} and {:?}",
                self.params.tau, self.params.refine, params.tau, params.refine
            )));
        }
        if params.specialization() != self.params.specialization() {
            let constants =
                occlusion_constants(&params, self.shape, crate::kernels::table_row(&self.ctx));
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

    /// Posed positions (vec4), written by the pose's skinning pass.
    pub fn posed_positions(&self) -> &Buffer {
        &self.buffers.posed_positions
    }

    /// The posed spheres buffer (vec4 centre + radius per node).
    pub fn posed_spheres(&self) -> &Buffer {
        &self.buffers.posed_spheres
    }

    /// The posed extents buffer (f32 per node: the farthest reach of its skinned leaves from
    /// its centre), written by `ao skin`; the cut's refinement reads it.
    pub fn posed_extents(&self) -> &Buffer {
        &self.buffers.posed_extents
    }

    /// The sphere tree's shape (node count, branch, first leaf), as the cut walks it.
    pub fn tree_shape(&self) -> cpu::TreeShape {
        self.shape
    }

    /// Records one frame: with its own pose `pose joints` (the joint matrices' upload) and
    /// `pose skin`, then `ao skin` and (unless [`AoKernel::set_occlusion`] turned it off)
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
        if !self.occlusion_on {
            return Err(crate::error::Error::InvalidArgument(
                "the AO kernel's occlusion pass is off (AoKernel::set_occlusion(false)): its \
                 frames compute no visibility to read back"
                    .into(),
            ));
        }
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

    /// Device memory held by the kernel's buffers (with its own pose's, when it owns one):
    /// `used_bytes` and `allocations` are the kernel's own; `reserved_bytes` is the
    /// context's (blocks are shared).
    pub fn memory(&self) -> MemoryReport {
        let b = &self.buffers;
        let own = self.ctx.memory_of_resources(
            self.buffers
                .own()
                .into_iter()
                .map(Resource::Buffer)
                .chain([&b.nodes, &b.table_quads, &b.nearest_image].map(Resource::storage_image))
                .chain(
                    b.fixed
                        .iter()
                        .flat_map(|f| [&f.nodes, &f.overlap].map(Resource::storage_image)),
                ),
        );
        match &self.own_pose {
            Some(p) => {
                let pose = p.memory();
                MemoryReport {
                    used_bytes: own.used_bytes + pose.used_bytes,
                    allocations: own.allocations + pose.allocations,
                    ..own
                }
            }
            None => own,
        }
    }

    /// Bytes of the kernel's buffers (their allocations).
    pub fn memory_bytes(&self) -> u64 {
        self.memory().used_bytes
    }

    fn pose_joint_bytes(&self, matrices: &[Mat4]) -> Result<Vec<u8>> {
        match &self.own_pose {
            Some(p) => p.joint_bytes(matrices),
            None => Ok(Vec::new()),
        }
    }

    fn pose_skin_args(&self, matrices: &[Mat4]) -> Result<Dispatch> {
        match &self.own_pose {
            Some(p) => p.skin_args(matrices),
            None => Err(crate::error::Error::InvalidArgument(
                "the AO kernel records no pose of its own".into(),
            )),
        }
    }

    fn skin_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        let s = self.shape;
        let words = [s.node_count, s.branch, s.first_leaf];
        let grid = Grid::Invocations([s.node_count, 1, 1]);
        Ok(Dispatch::words(&words, grid))
    }

    fn occlusion_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        self.params.validate()?;
        if let Some(f) = &self.fixed {
            let words = [
                self.vertex_count,
                f.slots,
                self.table.n_psi,
                self.table.n_theta,
                overlap_table().n,
            ];
            let grid = Grid::Invocations([self.vertex_count, 1, 1]);
            return Ok(Dispatch::words(&words, grid));
        }
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
        let mut passes = Vec::with_capacity(4);
        if let Some(p) = &self.own_pose {
            let (pipeline, bind) = p.skin_pass();
            passes.push(Pass::upload(
                PASS_JOINTS,
                p.joint_matrices(),
                Self::pose_joint_bytes,
            ));
            passes.push(Pass::dispatch(
                PASS_POSE,
                pipeline,
                bind,
                Self::pose_skin_args,
            ));
        }
        passes.push(Pass::dispatch(
            PASS_SKIN,
            &self.skin,
            &self.skin_bind,
            Self::skin_args,
        ));
        if self.occlusion_on {
            passes.push(Pass::dispatch(
                PASS_OCCLUSION,
                &self.occlusion,
                &self.occlusion_bind,
                Self::occlusion_args,
            ));
        }
        passes
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
