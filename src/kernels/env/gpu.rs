//! The environment kernel on the GPU: `env rotate` rotates the fitted lobes by the frame's
//! rotation into the `lobes` buffer, `env shadow` computes per vertex each lobe's visibility
//! from the caps of AO's sphere-tree cut and the shadowed irradiance. Built once on a
//! character's [`PoseKernel`] (posed positions, normals) and [`AoKernel`] (posed spheres and
//! extents, visibility); the caller records the pose and AO before this kernel each frame
//! (barriers follow from the declared accesses).

use super::cpu::{Shadowed, TraceConfig};
use super::pack::{CapTable, pack_lobes};
use super::{CV_SHARPNESS, MIN_TRANSMISSION, check_rotation};
use crate::error::{Error, Result};
use crate::geom::bvh::BvhTopology;
use crate::geom::sg::Lobe;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, MemoryReport, Readback, Recorder, Resource, Subresources,
};
use crate::kernels::ao::{AoKernel, AoParams, Refine, cpu::TreeShape};
use crate::kernels::pose::PoseKernel;
use crate::kernels::sss::pack::{BVH_ROW, rows};
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};
use ash::vk;
use glam::{Mat3, Vec3};

/// The rotation of the lobes (label and timing name).
pub const PASS_ROTATE: &str = "env rotate";
/// The per-vertex shadowing and irradiance.
pub const PASS_SHADOW: &str = "env shadow";
/// With traced visibility: the posed character's BVH leaves (triangles and boxes).
pub const PASS_BVH_LEAVES: &str = "env bvh leaves";
/// With traced visibility: the BVH's inner boxes, level by level.
pub const PASS_BVH_REFIT: &str = "env bvh refit";
/// With traced visibility: the rays per vertex through the refitted BVH.
pub const PASS_TRACE: &str = "env trace";

/// What turns the caps' split of the light into each lobe's visibility
/// (src/kernels/env/mod.rs): AO's visibility as a scale, or rays traced through the posed
/// mesh as a per-lobe correction.
#[derive(Clone, Copy, Debug)]
pub enum EnvVisibility<'a> {
    /// V_j = AO(x) prod_s ((1 - O_js) / (1 - I_s))^w_s, AO(x) AO's (blended, corrected)
    /// visibility (module `env/shadow`).
    Ao,
    /// `grid` x `grid` stratified cosine-weighted rays per vertex, cast each frame through
    /// a BVH built once over the rest pose (`rest`, `triangles`: the mesh the pose kernel
    /// skins) and refitted to the pose (passes [`PASS_BVH_LEAVES`], [`PASS_BVH_REFIT`],
    /// [`PASS_TRACE`]); ray origins move 1e-4 of the rest pose's bounding-box diagonal along
    /// the normal. Each lobe's caps' visibility is corrected by the rays' residuals, weighed
    /// by the lobe (module `env/shadow_rays`; [`super::CV_SHARPNESS`]).
    Traced {
        /// Rest-pose positions.
        rest: &'a [Vec3],
        /// The mesh's triangles.
        triangles: &'a [[u32; 3]],
        /// Strata per axis (rays per vertex = grid^2), 1..=[`MAX_TRACE_GRID`].
        grid: u32,
    },
}

/// Strata per axis of the traced visibility by default: 16 rays per vertex. On BCN_Epileptic's
/// three poses (`vkshade env --reference --trace-grid N`, 1024-ray truth) 4 / 9 / 16 / 36 / 64
/// rays correcting each lobe gave 13.0 / 10.2 / 7.9 / 6.8 / 6.1% at the worst pose; the same
/// rays as one scale per vertex on the same cut 14.0 / 10.9 / 10.6 / 10.1 / 10.0% (the caps'
/// split limits a scale, the rays' noise the correction), AO's visibility 15.1%. 16 is the
/// fewest within 10% with a margin.
pub const DEFAULT_TRACE_GRID: u32 = 4;

/// Most strata per axis of [`EnvVisibility::Traced`] (256 rays per vertex).
pub const MAX_TRACE_GRID: u32 = 16;

/// The seed of the traced visibility's jitter.
const TRACE_SEED: u32 = 0xe4f1_7ace;

/// The traced visibility's passes and resources.
struct Trace {
    leaves: ComputePipeline,
    leaves_bind: BindGroup,
    refit: ComputePipeline,
    refit_bind: BindGroup,
    trace: ComputePipeline,
    trace_bind: BindGroup,
    topology: BvhTopology,
    config: TraceConfig,
}

/// One frame's outputs recorded for readback.
pub struct EnvReadback {
    lobes: Readback,
    visibility: Readback,
    irradiance: Readback,
}

/// Host copies of one frame's outputs.
#[derive(Clone, Debug)]
pub struct EnvFrame {
    /// The rotated lobes (the `lobes` buffer).
    pub lobes: Vec<Lobe>,
    /// V_j and irradiance per vertex.
    pub shadowed: Shadowed,
}

impl EnvReadback {
    /// The data, once the submission holding the readback is complete.
    pub fn data(&self) -> Result<EnvFrame> {
        let packed: Vec<[f32; 4]> = self.lobes.to_vec()?;
        Ok(EnvFrame {
            lobes: packed
                .chunks(2)
                .map(|c| Lobe {
                    axis: [c[0][0], c[0][1], c[0][2]],
                    sharpness: c[0][3],
                    amplitude: [c[1][0], c[1][1], c[1][2]],
                })
                .collect(),
            shadowed: Shadowed {
                visibility: self.visibility.to_vec()?,
                irradiance: self.irradiance.to_vec()?,
            },
        })
    }
}

/// Environment lighting shadowed by the character, per frame on the GPU.
pub struct EnvKernel {
    ctx: Context,
    rotate: ComputePipeline,
    rotate_bind: BindGroup,
    shadow: ComputePipeline,
    shadow_bind: BindGroup,
    /// (binding name, buffer): the kernel's own and those it reads from the pose and AO.
    buffers: Vec<(&'static str, Buffer)>,
    base: Vec<Lobe>,
    table: CapTable,
    /// (binding name, image): the cap table as the shadow pass reads it ([`CapTable::quads`],
    /// N_S - 1 a row) and, with traced visibility, the BVH's nodes and triangles (rgba32ui,
    /// BVH_ROW texels a row, rewritten every frame).
    images: Vec<(&'static str, Image)>,
    vertex_count: u32,
    shape: TreeShape,
    params: AoParams,
    trace: Option<Trace>,
    /// The vertex list `env trace` and `env shadow` are dispatched over, when given.
    listed: Option<Buffer>,
}

/// The kernel's own buffers (the memory report counts these, its images, and the traced
/// visibility's buffers).
const OWN: [&str; 4] = ["base", "lobes", "vis", "irr"];
/// The traced visibility's own buffers.
const OWN_TRACED: [&str; 4] = ["traced", "escaped", "bvh_topo", "bvh_slots"];

impl EnvKernel {
    /// Creates the buffers and pipelines and records the uploads of the lobes (fitted once,
    /// unrotated) and the cap table into `rec` (nothing is submitted here). `pose` and `ao`
    /// are the character's (AO built [`AoKernel::on_pose`] on `pose`); their buffers are
    /// bound, not copied, and AO's cut parameters are taken now (build again after
    /// [`AoKernel::set_params`]). Refuses 0 or more than [`super::MAX_LOBES`] lobes, invalid
    /// lobes, an AO of another vertex count, and (AO's visibility as the scale) an AO whose
    /// occlusion pass is off ([`AoKernel::set_occlusion`]; it must stay on while this kernel
    /// is in use).
    pub fn new(
        rec: &mut Recorder,
        lobes: &[Lobe],
        pose: &PoseKernel,
        ao: &AoKernel,
    ) -> Result<EnvKernel> {
        Self::with_visibility(rec, lobes, pose, ao, EnvVisibility::Ao)
    }

    /// As [`EnvKernel::new`], the caps' split turned into visibility by `visibility` (AO's
    /// as a scale, or rays traced through the posed mesh every frame correcting each lobe).
    /// Refuses, besides, a traced mesh whose vertex count is not the pose's, a triangle
    /// naming a vertex it lacks, and a grid outside 1..=[`MAX_TRACE_GRID`].
    pub fn with_visibility(
        rec: &mut Recorder,
        lobes: &[Lobe],
        pose: &PoseKernel,
        ao: &AoKernel,
        visibility: EnvVisibility<'_>,
    ) -> Result<EnvKernel> {
        Self::with_vertex_list(rec, lobes, pose, ao, visibility, None)
    }

    /// As [`EnvKernel::with_visibility`], with `env trace` and `env shadow` shading only the
    /// vertices of `list` when given: a buffer in the layout of
    /// [`VertexListKernel::list`](crate::kernels::raster::vertices::VertexListKernel::list)
    /// (a `VkDispatchIndirectCommand` of 64-lane workgroups, the count, then the vertex ids;
    /// INDIRECT_BUFFER usage), written before this kernel's passes each frame. Both passes
    /// are then dispatched indirectly over it, and the visibility and irradiance of the
    /// vertices it leaves out keep an older frame's values (or none: read only listed
    /// vertices). Refuses, besides, a list too small for every vertex.
    pub fn with_vertex_list(
        rec: &mut Recorder,
        lobes: &[Lobe],
        pose: &PoseKernel,
        ao: &AoKernel,
        visibility: EnvVisibility<'_>,
        list: Option<&Buffer>,
    ) -> Result<EnvKernel> {
        if let Some(l) = list {
            let need = 16 + 4 * pose.vertex_count() as u64;
            if l.size() < need {
                return Err(Error::InvalidArgument(format!(
                    "env vertex list '{}': {} bytes, a list of {} vertices needs {need}",
                    l.name(),
                    l.size(),
                    pose.vertex_count()
                )));
            }
        }
        let packed = pack_lobes(lobes)?;
        if ao.vertex_count() != pose.vertex_count() {
            return Err(Error::InvalidArgument(format!(
                "the AO kernel has {} vertices, the pose {}",
                ao.vertex_count(),
                pose.vertex_count()
            )));
        }
        let ctx = rec.context();
        let table = CapTable::new();
        let (nv, nj) = (pose.vertex_count() as u64, lobes.len() as u64);
        let base = rec.buffer_with("env base lobes", BufferDesc::storage(nj * 32), &packed[..])?;
        // The cap table as an rgba32f image, one (lambda, alpha) cell's N_S - 1 quads a row:
        // lavapipe loads an image texel's four channels at once, where a storage buffer's
        // vec4 at a per-lane index is four gathers.
        let quads = table.quads();
        let table_desc = ImageDesc::d2(
            vk::Format::R32G32B32A32_SFLOAT,
            [
                super::pack::N_S - 1,
                super::pack::N_LAMBDA * (super::pack::N_ALPHA - 1),
            ],
        )
        .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST);
        let table_image = Image::new(&ctx, "env cap table", table_desc)?;
        rec.upload_image(
            &table_image,
            crate::gpu::ImageRegion::whole(&table_desc),
            bytemuck::cast_slice(&quads[..]),
        )?;
        let output = |name: &str, size: u64| {
            let desc = BufferDesc::storage(size)
                .usage(vk::BufferUsageFlags::VERTEX_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC);
            Buffer::new(&ctx, name, desc)
        };
        let mut buffers: Vec<(&'static str, Buffer)> = vec![
            ("base", base),
            ("lobes", output("env lobes", nj * 32)?),
            ("vis", output("env visibility", nv * nj * 4)?),
            ("irr", output("env irradiance", nv * 16)?),
            ("pos", pose.positions().clone()),
            ("nrm", pose.normals().clone()),
        ];
        if let Some(l) = list {
            buffers.push(("listed", l.clone()));
        }
        let mut images: Vec<(&'static str, Image)> =
            vec![("table", table_image), ("tree", ao.tree_image().clone())];
        let mut traced = None;
        // With traced visibility: where the BVH's table holds the triangles (the leaf and
        // trace modules' `TRI_BASE`).
        let mut tri_base = 0;
        match visibility {
            EnvVisibility::Ao => {
                if !ao.occlusion() {
                    return Err(Error::InvalidArgument(
                        "the environment takes AO's visibility as its scale, but the AO \
                         kernel's occlusion pass is off (AoKernel::set_occlusion)"
                            .into(),
                    ));
                }
                buffers.push(("ao", ao.visibility().clone()))
            }
            EnvVisibility::Traced {
                rest,
                triangles,
                grid,
            } => {
                if !(1..=MAX_TRACE_GRID).contains(&grid) {
                    return Err(Error::InvalidArgument(format!(
                        "traced visibility: {grid} strata per axis; must be 1..={MAX_TRACE_GRID}"
                    )));
                }
                if rest.len() != pose.vertex_count() {
                    return Err(Error::InvalidArgument(format!(
                        "traced visibility: the mesh has {} vertices, the pose {}",
                        rest.len(),
                        pose.vertex_count()
                    )));
                }
                if let Some((t, tri)) = triangles
                    .iter()
                    .enumerate()
                    .find(|(_, t)| t.iter().any(|&v| v as usize >= rest.len()))
                {
                    return Err(Error::InvalidArgument(format!(
                        "traced visibility: triangle {t} names vertex {} of {}",
                        tri.iter().max().copied().unwrap_or(0),
                        rest.len()
                    )));
                }
                if rest.iter().any(|p| !p.is_finite()) {
                    return Err(Error::InvalidArgument(
                        "traced visibility: a rest position is not finite".into(),
                    ));
                }
                let topology = BvhTopology::build(rest, triangles)?;
                let (lo, hi) = rest.iter().fold(
                    (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                    |(lo, hi), p| (lo.min(*p), hi.max(*p)),
                );
                let config = TraceConfig {
                    grid,
                    offset: 1e-4 * (hi - lo).length(),
                    seed: TRACE_SEED,
                };
                let topo = topology.gpu();
                let storage =
                    |name: &str, bytes: u64| Buffer::new(&ctx, name, BufferDesc::storage(bytes));
                let topo_buf = storage("env bvh topology", topo.len() as u64 * 4)?;
                let slots = topology.slots.len().max(1);
                let slots_buf = storage("env bvh slots", slots as u64 * 16)?;
                rec.upload(&topo_buf, 0, &topo)?;
                if !topology.slots.is_empty() {
                    rec.upload(&slots_buf, 0, &topology.slots)?;
                }
                let uint_image = |name: &str, texels: usize| {
                    let desc = ImageDesc::d2(
                        vk::Format::R32G32B32A32_UINT,
                        [BVH_ROW, rows(texels, BVH_ROW)],
                    )
                    .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST);
                    Image::new(&ctx, name, desc)
                };
                // The table of glsl/common/bvh.glsl: the nodes, then the triangles' slots.
                tri_base = crate::geom::bvh::tri_base(topology.nodes, BVH_ROW);
                let nodes = uint_image("env bvh", tri_base as usize + 3 * slots)?;
                // Every frame writes the texels the traversal reads; cleared once so that the
                // rows' tails hold defined data too.
                rec.clear_image(&nodes, Subresources::mip(nodes.desc(), 0), [0.0; 4])?;
                images.push(("nodes", nodes));
                let traced_buf = output("env traced visibility", nv.max(1) * 4)?;
                let words = u64::from(grid * grid).div_ceil(32);
                let escaped = output("env traced rays", nv.max(1) * words * 4)?;
                buffers.push(("ao", traced_buf.clone()));
                buffers.push(("traced", traced_buf));
                buffers.push(("escaped", escaped));
                buffers.push(("bvh_topo", topo_buf));
                buffers.push(("bvh_slots", slots_buf));
                traced = Some((topology, config));
            }
        }
        let bind = |pipeline: &ComputePipeline, writes: &[&str]| {
            let lookup = |b: &str| {
                buffers
                    .iter()
                    .find(|(n, _)| *n == b)
                    .map(|(_, r)| Resource::Buffer(r))
                    .or_else(|| {
                        images
                            .iter()
                            .find(|(n, _)| *n == b)
                            .map(|(_, i)| Resource::storage_image(i))
                    })
            };
            let w = AccessSet::from(A::ComputeShaderWrite);
            let writes: Vec<(&str, AccessSet)> = writes.iter().map(|&b| (b, w)).collect();
            pipeline.bind_from(lookup, &writes)
        };
        let rotate = crate::shaders::pipeline(&ctx, "env/rotate")?;
        // The passes over the vertex list are the same shaders built with ENV_LISTED
        // (glsl/env/listed.glsl).
        let variant = |name: &'static str, listed: &'static str| match list {
            Some(_) => listed,
            None => name,
        };
        // The lobe count sizes the shadow pass's per-lobe arrays and unrolled loops, the rays'
        // count its per-ray ones (specialization constants).
        let lobe_count = ("LOBES", nj as u32);
        // The row width of AO's tree image (`NODE_ROW`).
        let node_row = ("NODE_ROW", crate::kernels::table_row(&ctx));
        // The tree's levels below the root: the depths the walk's parent state takes.
        let levels = (
            "LEVELS",
            ao.tree_shape()
                .levels()
                .min(crate::kernels::ao::cpu::MAX_DEPTH as u32),
        );
        let branch = ("BRANCH", ao.tree_shape().branch);
        let shadow = match &traced {
            Some((_, config)) => crate::shaders::pipeline_specialized(
                &ctx,
                variant("env/shadow_rays", "env/shadow_rays_listed"),
                &[
                    ("RAYS", config.grid * config.grid),
                    lobe_count,
                    node_row,
                    levels,
                    branch,
                ],
            )?,
            None => crate::shaders::pipeline_specialized(
                &ctx,
                variant("env/shadow", "env/shadow_listed"),
                &[lobe_count, node_row, levels, branch],
            )?,
        };
        let rotate_bind = bind(&rotate, &["lobes"])?;
        let shadow_bind = bind(&shadow, &["vis", "irr"])?;
        let trace_parts = match &traced {
            None => None,
            Some(_) => {
                let tri_base = ("TRI_BASE", tri_base);
                let leaves =
                    crate::shaders::pipeline_specialized(&ctx, "env/bvh_leaves", &[tri_base])?;
                let refit = crate::shaders::pipeline(&ctx, "sss/bvh_refit")?;
                let trace = crate::shaders::pipeline_specialized(
                    &ctx,
                    variant("env/trace", "env/trace_listed"),
                    &[tri_base],
                )?;
                let leaves_bind = bind(&leaves, &["nodes"])?;
                let refit_bind = bind(&refit, &[])?;
                let trace_bind = bind(&trace, &["traced", "escaped"])?;
                Some((leaves, leaves_bind, refit, refit_bind, trace, trace_bind))
            }
        };
        let trace = match (traced, trace_parts) {
            (
                Some((topology, config)),
                Some((leaves, leaves_bind, refit, refit_bind, trace, trace_bind)),
            ) => Some(Trace {
                leaves,
                leaves_bind,
                refit,
                refit_bind,
                trace,
                trace_bind,
                topology,
                config,
            }),
            _ => None,
        };
        Ok(EnvKernel {
            ctx,
            rotate,
            rotate_bind,
            shadow,
            shadow_bind,
            buffers,
            base: lobes.to_vec(),
            table,
            images,
            vertex_count: nv as u32,
            shape: ao.tree_shape(),
            params: super::shadow_cut(ao.params(), trace.is_some()),
            trace,
            listed: list.cloned(),
        })
    }

    /// With traced visibility: the BVH topology (built over the rest pose) and the rays'
    /// settings, for the CPU twin ([`super::cpu::traced_visibility`]); `None` with AO's.
    pub fn traced(&self) -> Option<(&BvhTopology, &TraceConfig)> {
        self.trace.as_ref().map(|t| (&t.topology, &t.config))
    }

    /// The per-vertex visibility: AO's visibility buffer (which `env shadow` scales the
    /// caps' split by), or with traced visibility the fraction of the rays that escaped (f32
    /// per vertex, written by `env trace`).
    pub fn scale_visibility(&self) -> &Buffer {
        self.buffer("ao")
    }

    /// With traced visibility: which rays escaped, ceil(grid^2 / 32) u32 words per vertex
    /// (bit k % 32 of word k / 32: ray k; [`super::cpu::RayBits`]), written by `env trace`
    /// and read by `env shadow`.
    pub fn escaped_rays(&self) -> Option<&Buffer> {
        self.trace.as_ref().map(|_| self.buffer("escaped"))
    }

    fn buffer(&self, binding: &str) -> &Buffer {
        &self
            .buffers
            .iter()
            .find(|(n, _)| *n == binding)
            .expect("every binding name is created in EnvKernel::new")
            .1
    }

    /// The frame's rotated lobes: per lobe two vec4, (axis.xyz world, sharpness),
    /// (amplitude.rgb, 0); written by `env rotate`.
    pub fn lobes(&self) -> &Buffer {
        self.buffer("lobes")
    }

    /// Number of lobes.
    pub fn lobe_count(&self) -> usize {
        self.base.len()
    }

    /// The lobes as fitted (unrotated), as given to [`EnvKernel::new`].
    pub fn base_lobes(&self) -> &[Lobe] {
        &self.base
    }

    /// V_j per vertex and lobe, f32 [vertex * lobe_count + j], in [0, 1]: the visibility of
    /// lobe j weighted by the cosine; written by `env shadow`.
    pub fn visibility(&self) -> &Buffer {
        self.buffer("vis")
    }

    /// Shadowed irradiance per vertex: vec4 (sum_j V_j E_j(n) amplitude_j rgb, 0),
    /// radiometric (no 1/pi); written by `env shadow`.
    pub fn irradiance(&self) -> &Buffer {
        self.buffer("irr")
    }

    /// The vertex list the kernel shades, when built with one
    /// ([`EnvKernel::with_vertex_list`]).
    pub fn vertex_list(&self) -> Option<&Buffer> {
        self.listed.as_ref()
    }

    /// Vertices of the mesh (all shaded per frame, or those of the vertex list).
    pub fn vertex_count(&self) -> usize {
        self.vertex_count as usize
    }

    /// The cap table the shadow pass looks up (the CPU twin uses the same).
    pub fn table(&self) -> &CapTable {
        &self.table
    }

    /// The cut parameters the shadow pass walks: AO's, as taken at construction, with traced
    /// visibility coarsened to tau >= [`super::CV_TAU`] (the CPU twin takes these).
    pub fn ao_params(&self) -> &AoParams {
        &self.params
    }

    /// Records one frame (`env rotate`, `env shadow`) for the environment rotated by
    /// `rotation` (finite, orthonormal); barriers from the declared accesses.
    pub fn record(&self, rec: &mut Recorder, rotation: &Mat3) -> Result<()> {
        Kernel::record(self, rec, rotation)
    }

    /// Records copies of the outputs back to the host (tests and tools).
    pub fn read_back(&self, rec: &mut Recorder) -> Result<EnvReadback> {
        Ok(EnvReadback {
            lobes: rec.read_back(self.lobes())?,
            visibility: rec.read_back(self.visibility())?,
            irradiance: rec.read_back(self.irradiance())?,
        })
    }

    /// Device memory of the kernel's own buffers.
    pub fn memory(&self) -> MemoryReport {
        let mut own: Vec<Resource<'_>> = OWN
            .iter()
            .map(|b| Resource::Buffer(self.buffer(b)))
            .chain(self.images.iter().map(|(_, i)| Resource::storage_image(i)))
            .collect();
        if self.trace.is_some() {
            own.extend(OWN_TRACED.iter().map(|b| Resource::Buffer(self.buffer(b))));
        }
        self.ctx.memory_of_resources(own)
    }

    fn bvh_leaves_args(&self, _r: &Mat3) -> Result<Dispatch> {
        let n = self.trace.as_ref().map_or(0, |t| t.topology.leaves.len()) as u32;
        Ok(Dispatch::words(&[], Grid::Invocations([n.max(1), 1, 1])))
    }

    fn bvh_refit_args(&self, _r: &Mat3) -> Result<Dispatch> {
        Ok(Dispatch::words(&[], Grid::Groups([1, 1, 1])))
    }

    fn trace_args(&self, _r: &Mat3) -> Result<Dispatch> {
        let c =
            self.trace.as_ref().map(|t| t.config).ok_or_else(|| {
                Error::InvalidArgument("env trace without traced visibility".into())
            })?;
        let words = [self.vertex_count, c.grid, c.offset.to_bits(), c.seed];
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.vertex_count, 1, 1]),
        ))
    }

    fn rotate_args(&self, r: &Mat3) -> Result<Dispatch> {
        let c = r.to_cols_array();
        let mut words = Vec::with_capacity(13);
        for col in 0..3 {
            words.extend((0..3).map(|k| c[col * 3 + k].to_bits()));
            words.push(0);
        }
        words.push(self.base.len() as u32);
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.base.len() as u32, 1, 1]),
        ))
    }

    fn shadow_args(&self, _r: &Mat3) -> Result<Dispatch> {
        let s = self.shape;
        let p = &self.params;
        let words = [
            self.vertex_count,
            self.base.len() as u32,
            s.node_count,
            s.first_leaf,
            p.tau.to_bits(),
            p.band.to_bits(),
            (p.refine == Refine::Extent) as u32,
            p.clamp_inside as u32,
            MIN_TRANSMISSION.to_bits(),
        ];
        let mut words = words.to_vec();
        if let Some(t) = &self.trace {
            words.extend([t.config.grid, t.config.seed, CV_SHARPNESS.to_bits()]);
        }
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.vertex_count, 1, 1]),
        ))
    }
}

impl Kernel for EnvKernel {
    type Input = Mat3;
    type Readback = EnvReadback;
    type Output = EnvFrame;

    fn name(&self) -> &'static str {
        "env"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let mut passes = vec![Pass::dispatch(
            PASS_ROTATE,
            &self.rotate,
            &self.rotate_bind,
            Self::rotate_args,
        )];
        if let Some(t) = &self.trace {
            passes.extend([
                Pass::dispatch(
                    PASS_BVH_LEAVES,
                    &t.leaves,
                    &t.leaves_bind,
                    Self::bvh_leaves_args,
                ),
                Pass::dispatch(
                    PASS_BVH_REFIT,
                    &t.refit,
                    &t.refit_bind,
                    Self::bvh_refit_args,
                ),
                match &self.listed {
                    Some(list) => Pass::dispatch_indirect(
                        PASS_TRACE,
                        &t.trace,
                        &t.trace_bind,
                        IndirectArgs {
                            buffer: list,
                            offset: 0,
                        },
                        |k, r| Ok(k.trace_args(r)?.push),
                    ),
                    None => Pass::dispatch(PASS_TRACE, &t.trace, &t.trace_bind, Self::trace_args),
                },
            ]);
        }
        passes.push(match &self.listed {
            Some(list) => Pass::dispatch_indirect(
                PASS_SHADOW,
                &self.shadow,
                &self.shadow_bind,
                IndirectArgs {
                    buffer: list,
                    offset: 0,
                },
                |k, r| Ok(k.shadow_args(r)?.push),
            ),
            None => Pass::dispatch(
                PASS_SHADOW,
                &self.shadow,
                &self.shadow_bind,
                Self::shadow_args,
            ),
        });
        passes
    }

    fn check_input(&self, r: &Mat3) -> Result<()> {
        check_rotation(r)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<EnvReadback> {
        EnvKernel::read_back(self, rec)
    }

    fn collect(&self, readback: &EnvReadback) -> Result<EnvFrame> {
        readback.data()
    }

    fn memory(&self) -> MemoryReport {
        EnvKernel::memory(self)
    }
}
