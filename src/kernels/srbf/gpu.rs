//! The SRBF kernel on the GPU: pass `srbf lighting` rotates the lighting lobes and computes
//! their coefficients in the transfer basis; pass `srbf project` projects them onto every
//! row of the clustered-PCA transfer (each cluster's mean and principal axes); pass
//! `srbf shade` shades every vertex from its cluster's projected rows and its weights. The
//! per-vertex result is an RGB radiance buffer that can also feed a renderer's vertex input.
//! The data is packed on the CPU ([`super::pack`]); this is the glue that creates the
//! buffers from it and records the passes. With shadow rays ([`super::inputs::SunRays`]),
//! pass `srbf sharp` runs glsl/srbf/sharp_rays.comp instead of sharp.comp: the taps at the
//! compact lobes' exact rotated axes and a shadow ray per slot and compact lobe against the
//! static mesh's BVH (one table image, uploaded once), whose bits `srbf shade` reads in place
//! of the grid's visibility.

pub use super::inputs::{CompactInputs, SrbfFrame, SrbfInputs, SunRays, sun_offset};
pub use super::pack::{
    MAX_BASIS, MAX_ROWS, MAX_SHADE_GROUPS, MAX_TAPS, Prepared, Shape, rows_needed, stride,
};

use crate::error::Result;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::contract::DispatchArgs;
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::Mat3;

pub const PASS_LIGHTING: &str = "srbf lighting";
pub const PASS_PROJECT: &str = "srbf project";
pub const PASS_SHARP: &str = "srbf sharp";
pub const PASS_SHADE: &str = "srbf shade";

/// Host copy of one frame: RGB radiance per vertex.
pub type SrbfOutput = Vec<[f32; 3]>;

/// The GPU kernel: pipelines, the lobes, the transfer and the outputs of one mesh.
pub struct SrbfKernel {
    ctx: Context,
    lighting: Stage,
    project: Stage,
    shade: Stage,
    sharp: Stage,
    buffers: Buffers,
    /// The shadow rays' BVH and buffers (None: the grid tap).
    sun: Option<SunResources>,
    shape: Shape,
}

/// What pass `srbf sharp` casts shadow rays with: the static mesh's BVH as the table
/// glsl/common/bvh.glsl traverses, the slots' positions and the bits it writes.
struct SunResources {
    /// The BVH's table (nodes, then triangles from texel `tri_base`: `srbf sharp`'s
    /// `TRI_BASE`).
    nodes: Image,
    tri_base: u32,
    positions: Buffer,
    /// Per slot: bit j set when compact lobe j is seen (written by `srbf sharp`, read by
    /// `srbf shade`).
    bits: Buffer,
}

/// Width of the BVH's table (glsl/srbf/sharp_rays.comp's BVH_ROW).
const BVH_ROW: u32 = 1024;

impl SunResources {
    /// Creates the images and buffers for `prep` and records their uploads.
    fn new(rec: &mut Recorder, prep: &Prepared) -> Result<SunResources> {
        let ctx = rec.context();
        let (nodes, tri_base) = bvh_table(rec, "srbf sun", &prep.bvh_nodes, &prep.bvh_triangles)?;
        let bytes: &[u8] = bytemuck::cast_slice(&prep.positions);
        let positions = rec.buffer_with(
            "srbf sun positions",
            BufferDesc::storage(bytes.len() as u64),
            bytes,
        )?;
        let bits = Buffer::new(
            &ctx,
            "srbf sun bits",
            BufferDesc::storage(prep.shape.slots as u64 * 4)
                .usage(vk::BufferUsageFlags::TRANSFER_SRC),
        )?;
        Ok(SunResources {
            nodes,
            tri_base,
            positions,
            bits,
        })
    }
}

/// The BVH of glsl/common/bvh.glsl as its table, `BVH_ROW` texels wide (nodes with links,
/// [`crate::geom::bvh::with_links`], then triangles, [`crate::geom::Bvh::flat`], from texel
/// [`crate::geom::bvh::tri_base`], the second value: the pipelines' `TRI_BASE`), its upload
/// recorded into `rec`.
pub(super) fn bvh_table(
    rec: &mut Recorder,
    prefix: &str,
    nodes: &[[f32; 8]],
    triangles: &[[f32; 12]],
) -> Result<(Image, u32)> {
    let ctx = rec.context();
    let tri_base = crate::geom::bvh::tri_base(nodes.len(), BVH_ROW);
    let texels = crate::geom::bvh::table_texels(nodes, triangles, tri_base)?;
    let rows = (texels.len() as u32).div_ceil(BVH_ROW).max(1);
    let image = Image::new(
        &ctx,
        &format!("{prefix} bvh"),
        ImageDesc::d2(vk::Format::R32G32B32A32_UINT, [BVH_ROW, rows])
            .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST),
    )?;
    rec.upload_image_rows(&image, &texels)?;
    Ok((image, tri_base))
}

/// A pass's pipeline and its bindings.
struct Stage {
    pipeline: ComputePipeline,
    bind: BindGroup,
}

impl Stage {
    fn pass(&self, name: &'static str, args: DispatchArgs<SrbfKernel>) -> Pass<'_, SrbfKernel> {
        Pass::dispatch(name, &self.pipeline, &self.bind, args)
    }
}

/// The kernel's buffers: the inputs, the intermediates one pass writes for the next, and
/// the per-vertex radiance.
struct Buffers {
    /// Lighting lobes through the basis: axes and amplitudes.
    lobe_axes: Buffer,
    lobe_amps: Buffer,
    /// Compact lobes (shaded from the visibility): axes and amplitudes.
    compact_axes: Buffer,
    compact_amps: Buffer,
    /// Per shade slot: normal and visibility.
    normals: Buffer,
    visible: Buffer,
    basis_axes: Buffer,
    /// The clustered-PCA transfer: rows and weights.
    rows: Image,
    weights: Buffer,
    slot_vertex: Buffer,
    /// The cluster of each shade workgroup (a uniform buffer).
    group_cluster: Buffer,
    /// Written by one pass, read as a uniform buffer by the next: the lighting
    /// coefficients, the projected rows and the compact taps.
    coeffs: Buffer,
    projected: Image,
    taps: Buffer,
    /// Per-vertex RGB radiance, written by `srbf shade`.
    radiance: Buffer,
}

impl Buffers {
    /// Every buffer (for the memory report).
    fn all(&self) -> [&Buffer; 13] {
        [
            &self.lobe_axes,
            &self.lobe_amps,
            &self.compact_axes,
            &self.compact_amps,
            &self.normals,
            &self.visible,
            &self.basis_axes,
            &self.weights,
            &self.slot_vertex,
            &self.group_cluster,
            &self.coeffs,
            &self.taps,
            &self.radiance,
        ]
    }
}

impl SrbfKernel {
    /// Checks and packs `inputs` ([`Prepared::new`]), creates the buffers and pipelines
    /// and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &SrbfInputs<'_>) -> Result<SrbfKernel> {
        Self::from_prepared(rec, &Prepared::new(inputs)?)
    }

    /// Creates the buffers and pipelines for `prep` (checked against this device) and
    /// records the uploads into `rec` (they run when the caller submits it).
    pub fn from_prepared(rec: &mut Recorder, prep: &Prepared) -> Result<SrbfKernel> {
        let ctx = rec.context();
        let l = ctx.limits();
        prep.check_device(
            l.max_uniform_buffer_range,
            l.max_compute_work_group_count[0],
        )?;
        let pipeline = |name| crate::shaders::pipeline(&ctx, name);
        let lighting = pipeline("srbf/lighting")?;
        // The rows' and projected rows' images, `row` texels a row (`SRBF_ROW`).
        let row = crate::kernels::table_row(&ctx);
        let project =
            crate::shaders::pipeline_specialized(&ctx, "srbf/project", &[("SRBF_ROW", row)])?;
        let shade = crate::shaders::pipeline_specialized(
            &ctx,
            "srbf/shade",
            &[
                ("SRBF_ROW", row),
                ("GROUPS", prep.shape.components.div_ceil(8)),
                ("TAPS", prep.shape.taps),
            ],
        )?;
        let buffers = Self::buffers(rec, prep)?;
        let sun = match prep.shape.rays {
            true => Some(SunResources::new(rec, prep)?),
            false => None,
        };
        let sharp = match &sun {
            Some(s) => crate::shaders::pipeline_specialized(
                &ctx,
                "srbf/sharp_rays",
                &[("TRI_BASE", s.tri_base)],
            )?,
            None => pipeline("srbf/sharp")?,
        };
        let [lighting_bind, project_bind, sharp_bind, shade_bind] = Self::binds(
            [&lighting, &project, &sharp, &shade],
            &buffers,
            sun.as_ref(),
        )?;
        let stage = |pipeline, bind| Stage { pipeline, bind };
        Ok(SrbfKernel {
            ctx,
            lighting: stage(lighting, lighting_bind),
            project: stage(project, project_bind),
            shade: stage(shade, shade_bind),
            sharp: stage(sharp, sharp_bind),
            buffers,
            sun,
            shape: prep.shape,
        })
    }

    /// The bind groups of `srbf lighting`, `srbf project`, `srbf sharp` and `srbf shade`
    /// (pipelines in that order) over the kernel's buffers; with `sun`, `srbf sharp` casts
    /// the shadow rays and `srbf shade` reads their bits as its visibility.
    fn binds(
        [lighting, project, sharp, shade]: [&ComputePipeline; 4],
        buffers: &Buffers,
        sun: Option<&SunResources>,
    ) -> Result<[BindGroup; 4]> {
        let (b, w) = (Resource::Buffer, AccessSet::from(A::ComputeShaderWrite));
        let lighting = lighting.bind_declared(
            &[
                ("lobe_axes", b(&buffers.lobe_axes)),
                ("lobe_amps", b(&buffers.lobe_amps)),
                ("basis_axes", b(&buffers.basis_axes)),
                ("coeffs", b(&buffers.coeffs)),
            ],
            &[("coeffs", w)],
        )?;
        let project = project.bind_declared(
            &[
                ("rows", Resource::storage_image(&buffers.rows)),
                ("coeffs", b(&buffers.coeffs)),
                ("projected", Resource::storage_image(&buffers.projected)),
            ],
            &[("projected", w)],
        )?;
        let sharp = match sun {
            None => sharp.bind_declared(
                &[
                    ("lobe_axes", b(&buffers.compact_axes)),
                    ("lobe_amps", b(&buffers.compact_amps)),
                    ("taps", b(&buffers.taps)),
                ],
                &[("taps", w)],
            )?,
            Some(sun) => sharp.bind_declared(
                &[
                    ("lobe_axes", b(&buffers.compact_axes)),
                    ("lobe_amps", b(&buffers.compact_amps)),
                    ("taps", b(&buffers.taps)),
                    ("positions", b(&sun.positions)),
                    ("normals", b(&buffers.normals)),
                    ("sun_bits", b(&sun.bits)),
                    ("nodes", Resource::storage_image(&sun.nodes)),
                ],
                &[("taps", w), ("sun_bits", w)],
            )?,
        };
        let visible = sun.map_or(&buffers.visible, |s| &s.bits);
        let shade = shade.bind_declared(
            &[
                ("weights", b(&buffers.weights)),
                ("slot_vertex", b(&buffers.slot_vertex)),
                ("group_cluster", b(&buffers.group_cluster)),
                ("projected", Resource::storage_image(&buffers.projected)),
                ("radiance", b(&buffers.radiance)),
                ("normals", b(&buffers.normals)),
                ("visible", b(visible)),
                ("taps", b(&buffers.taps)),
            ],
            &[("radiance", w)],
        )?;
        Ok([lighting, project, sharp, shade])
    }

    /// The kernel's buffers, the uploads of the inputs recorded and the intermediates
    /// zeroed.
    fn buffers(rec: &mut Recorder, prep: &Prepared) -> Result<Buffers> {
        fn storage<T: bytemuck::Pod>(rec: &mut Recorder, name: &str, data: &[T]) -> Result<Buffer> {
            let bytes: &[u8] = bytemuck::cast_slice(data);
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        }
        // Written as storage by one pass and read as a uniform buffer by the next (sized for
        // the reader's fixed array, zero-padded).
        let ubo = |rec: &mut Recorder, name: &str, vec4s: usize| {
            rec.buffer_with(
                name,
                BufferDesc::storage(vec4s as u64 * 16).usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
                &vec![[0f32; 4]; vec4s],
            )
        };
        let layout = &prep.layout;
        let groups = prep.group_table();
        Ok(Buffers {
            lobe_axes: storage(rec, "srbf lobe axes", &prep.lobe_axes)?,
            lobe_amps: storage(rec, "srbf lobe amplitudes", &prep.lobe_amps)?,
            compact_axes: storage(rec, "srbf compact axes", &prep.compact_axes)?,
            compact_amps: storage(rec, "srbf compact amplitudes", &prep.compact_amps)?,
            normals: storage(rec, "srbf slot normals", &prep.normals)?,
            visible: storage(rec, "srbf slot visibility", &prep.visible)?,
            basis_axes: storage(rec, "srbf basis axes", &prep.basis_axes)?,
            rows: {
                let image = crate::kernels::row_image(
                    &rec.context(),
                    "srbf cpca rows",
                    vk::Format::R32G32B32A32_SFLOAT,
                    layout.rows.len() as u64,
                    vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST,
                    "",
                )?;
                rec.upload_image_rows(&image, &layout.rows)?;
                image
            },
            weights: storage(rec, "srbf cpca weights", &layout.weights)?,
            slot_vertex: storage(rec, "srbf slot vertices", &layout.slot_vertex)?,
            // A uniform buffer sized for shade.comp's fixed array.
            group_cluster: rec.buffer_with(
                "srbf workgroup clusters",
                BufferDesc::uniform(groups.len() as u64 * 4),
                &groups,
            )?,
            coeffs: ubo(rec, "srbf coefficients", MAX_BASIS)?,
            projected: crate::kernels::row_image(
                &rec.context(),
                "srbf projected rows",
                vk::Format::R32G32B32A32_SFLOAT,
                MAX_ROWS as u64,
                vk::ImageUsageFlags::STORAGE,
                "",
            )?,
            taps: ubo(rec, "srbf compact taps", 2 * MAX_TAPS)?,
            radiance: Buffer::new(
                &rec.context(),
                "srbf radiance",
                BufferDesc::storage(prep.shape.vertices as u64 * 16)
                    .usage(vk::BufferUsageFlags::VERTEX_BUFFER),
            )?,
        })
    }

    /// Per-vertex RGB radiance (vec4, alpha 1), written by pass `srbf shade`.
    pub fn radiance(&self) -> &Buffer {
        &self.buffers.radiance
    }

    pub fn vertex_count(&self) -> usize {
        self.shape.vertices as usize
    }

    /// Lighting lobes: through the basis plus compact.
    pub fn lobe_count(&self) -> usize {
        (self.shape.lobes + self.shape.compact) as usize
    }

    /// Compact lobes (shaded from the visibility, not through the basis).
    pub fn compact_count(&self) -> usize {
        self.shape.compact as usize
    }

    /// With shadow rays: per shade slot, the bits pass `srbf sharp` wrote (bit j: compact
    /// lobe j seen); [`Self::slot_vertices`] maps slots to vertices. None: the grid tap.
    pub fn sun_bits(&self) -> Option<&Buffer> {
        self.sun.as_ref().map(|s| &s.bits)
    }

    /// The vertex of each shade slot ([`super::pack::NO_VERTEX`] for padding).
    pub fn slot_vertices(&self) -> &Buffer {
        &self.buffers.slot_vertex
    }

    pub fn basis_count(&self) -> usize {
        self.shape.basis as usize
    }

    /// (clusters, principal components per cluster) of the transfer.
    pub fn cpca_shape(&self) -> (usize, usize) {
        (self.shape.clusters as usize, self.shape.components as usize)
    }

    /// Shade slots (vertices padded so that every workgroup holds one cluster).
    pub fn slot_count(&self) -> usize {
        self.shape.slots as usize
    }

    fn lighting_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        let s = &self.shape;
        let mut push = rotation_push(frame.rotation);
        push.extend_from_slice(&s.lobes.to_le_bytes());
        push.extend_from_slice(&s.basis.to_le_bytes());
        push.extend_from_slice(&s.basis_sharpness.to_le_bytes());
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([s.basis, 1, 1]),
        })
    }

    fn sharp_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        // With no compact lobes one invocation runs and writes nothing, so the declared uses
        // are the same either way and a render graph's plan holds.
        let s = &self.shape;
        let mut push = rotation_push(frame.rotation);
        if s.rays {
            // One invocation per slot (the first `compact` also write the taps).
            push.extend_from_slice(&s.compact.to_le_bytes());
            push.extend_from_slice(&s.slots.to_le_bytes());
            push.extend_from_slice(&s.ray_offset.to_le_bytes());
            return Ok(Dispatch {
                push,
                grid: Grid::Invocations([s.slots.max(s.compact).max(1), 1, 1]),
            });
        }
        for x in [s.compact, s.grid[0], s.grid[1]] {
            push.extend_from_slice(&x.to_le_bytes());
        }
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([s.compact.max(1), 1, 1]),
        })
    }

    fn project_args(&self, _frame: &SrbfFrame) -> Result<Dispatch> {
        let s = &self.shape;
        Ok(Dispatch::words(
            &[s.rows, s.basis.div_ceil(4)],
            Grid::Invocations([s.rows, 1, 1]),
        ))
    }

    fn shade_args(&self, frame: &SrbfFrame) -> Result<Dispatch> {
        let (s, a) = (&self.shape, frame.albedo);
        let push: Vec<u8> = [a[0], a[1], a[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .chain(s.slots.to_le_bytes())
            .chain(s.stride.to_le_bytes())
            .collect();
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([s.slots, 1, 1]),
        })
    }
}

/// The columns of a rotation as three vec4 (push-constant layout of `srbf lighting` and
/// `srbf sharp`, and the first 48 bytes of the glossy passes' `srbf glossy sharp`).
pub(super) fn rotation_push(r: Mat3) -> Vec<u8> {
    let mut push: Vec<u8> = Vec::with_capacity(64);
    for c in 0..3 {
        let col = r.col(c);
        for x in [col.x, col.y, col.z, 0.0] {
            push.extend_from_slice(&x.to_le_bytes());
        }
    }
    push
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
            self.lighting.pass(PASS_LIGHTING, Self::lighting_args),
            self.project.pass(PASS_PROJECT, Self::project_args),
            self.sharp.pass(PASS_SHARP, Self::sharp_args),
            self.shade.pass(PASS_SHADE, Self::shade_args),
        ]
    }

    fn check_input(&self, frame: &SrbfFrame) -> Result<()> {
        frame.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.buffers.radiance)
    }

    fn collect(&self, readback: &Readback) -> Result<SrbfOutput> {
        let v: Vec<[f32; 4]> = readback.to_vec()?;
        Ok(v.iter().map(|x| [x[0], x[1], x[2]]).collect())
    }

    fn memory(&self) -> MemoryReport {
        let sun = self.sun.iter().flat_map(|s| {
            [
                Resource::storage_image(&s.nodes),
                Resource::Buffer(&s.positions),
                Resource::Buffer(&s.bits),
            ]
        });
        self.ctx.memory_of_resources(
            self.buffers
                .all()
                .into_iter()
                .map(Resource::Buffer)
                .chain([&self.buffers.rows, &self.buffers.projected].map(Resource::storage_image))
                .chain(sun),
        )
    }
}
