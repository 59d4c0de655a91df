//! The SSS kernel on the GPU: pass `sss lights` uploads the frame's lights, `sss vertex light`
//! casts shadow and thickness rays per mesh vertex through the BVH, `sss irradiance` computes
//! E per texel (the vertices' shadowing, refined by a ray per texel where a triangle's corners
//! disagree) and the transmission, `sss diffusion` importance-samples the profile in texture
//! space with one sample set shared by the three channels. Per-texel data and the BVH live in
//! storage images: on lavapipe an image load at a per-lane coordinate fetches the texel's four
//! channels at once, while a storage-buffer load at a per-lane index loops over the lanes for
//! every component (measured: the diffusion 3.7x faster, the irradiance 1.6x). The lights are a
//! uniform buffer (read as scalars at the light loop's uniform index). The irradiance pass
//! writes the grey E into a one-channel image, so the diffusion gathers one channel per
//! sample. Both passes run over the atlas's occupied 8x1 row segments only (a list built once
//! per UV layout; about half a head's atlas is empty), the outputs cleared once in the empty
//! ones. The irradiance can also be filled by the caller
//! ([`SssKernel::upload_irradiance`], e.g. from another kernel, rgb) and diffused alone
//! ([`SssKernel::record_diffusion`], then with the two-gather rgb pipeline).
//!
//! The data is packed and checked on the CPU ([`super::pack`]); this module creates the images
//! and buffers from it, records their uploads, binds the pipelines and declares the passes.
//!
//! A skinned mesh ([`SssKernel::new_posed`]) binds the posed vertex buffers of the skinning
//! pass and starts each frame with four more passes that compute from them what the upload
//! held for a static mesh: `sss pose vertices` (vertex frames in mm, as a buffer for the
//! vertex-light pass and an image for the irradiance), `sss pose triangles` (the surface
//! walk's records, face normals, texel areas), `sss bvh leaves` and `sss bvh refit` (the rest
//! pose's BVH topology with this pose's triangles and boxes). Its irradiance pass computes
//! each texel's position and normal from its triangle and barycentrics (glsl/sss/
//! irradiance_posed.comp) rather than reading them from images another pass wrote: nothing
//! else in a frame reads them, and on lavapipe a store per texel costs more than the few
//! loads that recompute them. `sss pose texels` stores them for a diagnostic readback only
//! ([`SssKernel::read_back_geometry`]). What the UV layout fixes is uploaded once
//! ([`super::posed::Layout`]), as are the contact entries (the rest pose's).
//!
//! A per-vertex rgb irradiance ([`SssKernel::set_vertex_irradiance`], e.g. the environment
//! shadowed by the character, written by another kernel into a buffer) is interpolated per
//! texel by the irradiance pass and added to the lights' E; the irradiance is then rgb, in
//! one rgba image whose alpha marks the surface, and the diffusion gathers it with one load
//! per sample (glsl/sss/irradiance*_env.comp, diffusion_env.comp).
//!
//! A caller that reads only part of the atlas marks the segments it needs
//! ([`SssKernel::set_needed_segments`]): the diffusion runs over a list of them. The reach
//! ([`SssKernel::set_reach`]) restricts the irradiance of a posed kernel the same way, to
//! the segments that diffusion can read, bounded each frame from the posed walk records
//! (passes `sss reach *`, before the lights; [`SssKernel::record_front`]); it can also mark
//! the triangles whose per-vertex irradiance those segments interpolate, so that the
//! caller computes that irradiance at their corners only.

use super::TexGeometry;
use super::cpu::{Light, MAX_LIGHTS, SamplerParams, check_lights, shadow_bias};
use super::pack::{
    self, BVH_ROW, PATTERN_WIDTH, Packed, Pattern, Room, Settings, VERTEX_ROW, tile_groups,
};
use super::posed;
use super::regions::{MAX_REGIONS, Regions};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource, Subresources,
};
use crate::kernels::contract::DispatchArgs;
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};
use ash::vk;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU8, Ordering};

pub const PASS_LIGHTS: &str = "sss lights";
pub const PASS_VERTEX: &str = "sss vertex light";
pub const PASS_IRRADIANCE: &str = "sss irradiance";
/// The shadow rays of the texels `sss irradiance` lists (where a shadow boundary crosses the
/// texel's triangle), dispatched indirectly over the list.
pub const PASS_IRRADIANCE_RAYS: &str = "sss irradiance rays";
/// The reset of that list before `sss irradiance` appends to it.
pub const PASS_RAY_LIST: &str = "sss ray list";
pub const PASS_DIFFUSION: &str = "sss diffusion";
/// With needed segments set ([`SssKernel::set_needed_segments`]): the occupied segments the
/// caller's bitmap marks, listed for the diffusion (dispatched indirectly over the list).
pub const PASS_NEEDED_LIST: &str = "sss needed list";
/// With the reach set ([`SssKernel::set_reach`]): the atlas blocks where the diffusion
/// samples of the needed segments' triangles can land, and their contact entries' sources.
pub const PASS_REACH_BOXES: &str = "sss reach boxes";
/// With triangle marks: the triangles with a texel in the reach, into the caller's bitmap.
pub const PASS_REACH_TRIANGLES: &str = "sss reach triangles";
/// The occupied segments in the reach, listed for the irradiance.
pub const PASS_REACH_LIST: &str = "sss reach list";
/// Per-frame geometry of a skinned mesh ([`SssKernel::new_posed`]): the vertex frames (mm)
/// from the posed buffers.
pub const PASS_POSE_VERTICES: &str = "sss pose vertices";
/// Per triangle: the surface walk's records, the face normal and texel area.
pub const PASS_POSE_TRIANGLES: &str = "sss pose triangles";
/// Per texel: position, normal, area into images (not a pass of a frame: the posed irradiance
/// computes them itself; [`SssKernel::read_back_geometry`] records it).
pub const PASS_POSE_TEXELS: &str = "sss pose texels";
/// The BVH's leaves (triangles and boxes) from the posed vertices.
pub const PASS_BVH_LEAVES: &str = "sss bvh leaves";
/// The BVH's inner boxes, level by level.
pub const PASS_BVH_REFIT: &str = "sss bvh refit";
/// With a per-vertex irradiance set ([`SssKernel::set_vertex_irradiance`]): the caller's
/// buffer copied into an image for the irradiance pass.
pub const PASS_VERTEX_IRRADIANCE: &str = "sss vertex irradiance";
/// Most samples per texel (the width of the pattern image; Vulkan guarantees 4096 texels,
/// checked at run time).
pub const MAX_SAMPLES: u32 = PATTERN_WIDTH;

/// The irradiance last recorded: the irradiance pass's grey E (lights only).
const IRR_GREY: u8 = 0;
/// The irradiance pass's rgb E (lights plus the per-vertex irradiance of
/// [`SssKernel::set_vertex_irradiance`]).
const IRR_ENV: u8 = 1;
/// A caller's upload ([`SssKernel::upload_irradiance`]).
const IRR_UPLOAD: u8 = 2;

/// Host copies of a frame: irradiance, diffuse (rgba per texel; diffuse alpha is the
/// fraction of the samples not lost) and transmission (rgb; alpha the thickness in mm, 0
/// where nothing transmits).
#[derive(Clone, Debug)]
pub struct SssOutput {
    pub irradiance: Vec<[f32; 4]>,
    pub diffuse: Vec<[f32; 4]>,
    pub transmission: Vec<[f32; 4]>,
}

pub struct SssReadback {
    /// What `irradiance` holds ([`IRR_GREY`], [`IRR_ENV`], [`IRR_UPLOAD`]).
    irradiance_kind: u8,
    irradiance: Readback,
    diffuse: Readback,
    transmission: Readback,
}

/// The kernel's images and buffers. Per-texel data, the BVH and the per-vertex results are
/// storage images: lavapipe fetches a texel's four channels at once, while a storage-buffer
/// load at a per-lane index loops over the lanes for each component.
struct Resources {
    /// Per mesh vertex: position, normal (two vec4).
    vertex_frames: Buffer,
    /// The BVH's table (glsl/common/bvh.glsl), RGBA32UI, [`BVH_ROW`] texels a row (float
    /// bits): the nodes, 2 texels each, then from texel [`Resources::tri_base`] the
    /// triangles, 3 each.
    bvh: Image,
    /// The specialization constants the kernel's stages take where they declare them: the
    /// BVH table's `TRI_BASE` (the room's node rows, whole) and `ROW_SEGMENTS`
    /// ([`Room::row_segments`]).
    constants: [(&'static str, u32); 2],
    /// The diffusion's specialization constants from the sample pattern
    /// ([`Pattern::constants`]), besides those.
    pattern_constants: Vec<(String, u32)>,
    /// The skin regions' sample patterns, RGBA32F, one texel per sample, two rows a region
    /// ([`Pattern::texels`]; lavapipe loads a uniform buffer at a loop index lane by lane: a
    /// vec4 from it cost more than the irradiance gather of a sample). Where the diffusion
    /// holds the pattern as constants (one region, at most [`pack::MAX_UNIFORM_SAMPLES`]
    /// samples) it reads only the region's R_tot and weight totals here.
    sample_pattern: Image,
    /// The regions' transmission tails ([`pack::region_tails`]), a uniform buffer, and each
    /// vertex's region ([`Regions::of_vertices`], a u32 each).
    region_tails: Buffer,
    vertex_regions: Buffer,
    /// The frame's lights: a uniform buffer (the shaders' MAX_LIGHTS x 2 vec4), which
    /// lavapipe loads at the light loop's uniform index as a scalar.
    lights: Buffer,
    /// Per texel: position and flag, normal and area (RGBA32F), triangle corners and
    /// barycentrics, where the diffusion starts (RGBA32UI).
    texel_positions: Image,
    texel_normals: Image,
    texel_corners: Image,
    diffusion_start: Image,
    /// The surface walk's triangle records and the contact entries, RGBA32UI, [`BVH_ROW`]
    /// texels a row.
    walk_records: Image,
    contact_entries: Image,
    /// Per vertex (vertex v at (v % VERTEX_ROW, v / VERTEX_ROW)), written by `sss vertex
    /// light`: a bit per unshadowed light (R32UI), transmission rgb and thickness (RGBA32F).
    vertex_visibility: Image,
    vertex_transmission: Image,
    /// Per texel: a caller's rgb irradiance ([`SssKernel::upload_irradiance`]), the
    /// transmission and the grey E of the irradiance pass (R32F; -1 where no surface).
    irradiance_rgb: Image,
    transmission: Image,
    irradiance_grey: Image,
    /// The diffusion's output, rgba per texel.
    diffuse: Buffer,
    /// The occupied tiles ([`pack::occupied_tiles`]), with room for every tile, and the
    /// list on the host (compared on a geometry update).
    occupied_tiles: Buffer,
    tile_list: Mutex<Vec<u32>>,
    /// The occupied tiles as a bitmap of [`pack::needed_segment`]s (uploaded with the list),
    /// and the list `sss needed list` writes: its head (the diffusion's
    /// VkDispatchIndirectCommand, then the count) and room for every tile.
    occupied_segments: Buffer,
    needed_list: Buffer,
    /// The texels whose lights need their own shadow rays, appended by `sss irradiance`: a
    /// (texel, light bits) pair of u32 per listed texel, room for every texel; and its head,
    /// u32 (ceil(count / 256), 1, 1, count), the indirect command of `sss irradiance rays`
    /// (64 lanes a workgroup, 4 entries a lane).
    rays: Buffer,
    ray_head: Buffer,
    /// The reach ([`SssKernel::set_reach`]): a bit per atlas block
    /// ([`pack::reach_block_words`]; cleared by `sss reach list`), per triangle what the UV
    /// layout fixes ([`pack::reach_static`]), and the list of the reached occupied segments
    /// (the irradiance's VkDispatchIndirectCommand, the count, room for every tile).
    reach_blocks: Buffer,
    /// An image (BVH_ROW texels a row): the reach passes read it at per-lane addresses, where
    /// lavapipe loads a storage buffer's uvec4 as a loop over the lanes per component.
    reach_static: Image,
    reach_list: Buffer,
}

/// An RGBA32UI storage image the host fills (and can read back, for the tests of the
/// per-frame geometry).
fn uint_image(size: [u32; 2]) -> ImageDesc {
    ImageDesc::d2(vk::Format::R32G32B32A32_UINT, size).usage(
        vk::ImageUsageFlags::STORAGE
            | vk::ImageUsageFlags::TRANSFER_DST
            | vk::ImageUsageFlags::TRANSFER_SRC,
    )
}

/// A float storage image the host can fill and read back.
fn float_image(format: vk::Format, size: [u32; 2]) -> ImageDesc {
    ImageDesc::d2(format, size).usage(
        vk::ImageUsageFlags::STORAGE
            | vk::ImageUsageFlags::TRANSFER_DST
            | vk::ImageUsageFlags::TRANSFER_SRC,
    )
}

fn rgba32f(size: [u32; 2]) -> ImageDesc {
    float_image(vk::Format::R32G32B32A32_SFLOAT, size)
}

/// The specialization constants of the diffusion's stages: the kernel's (`base`) and those of
/// a sample pattern ([`Pattern::constants`]).
fn diffusion_constants<'a>(
    base: &[(&'static str, u32)],
    pattern: &'a [(String, u32)],
) -> Vec<(&'a str, u32)> {
    let own = pattern.iter().map(|(n, v)| (n.as_str(), *v));
    base.iter().copied().chain(own).collect()
}

/// The diffusion's stages over every occupied segment, with `constants`
/// ([`diffusion_constants`]): of a caller's rgb irradiance (two gathers a sample) and of the
/// irradiance pass's grey E (one).
fn diffusion_stages(
    ctx: &Context,
    res: &Resources,
    constants: &[(&str, u32)],
) -> Result<(Stage, Stage)> {
    let table = res.by_binding();
    let stage = |name| Stage::from_table(ctx, name, &table, &["diffuse"], constants);
    Ok((stage("sss/diffusion")?, stage("sss/diffusion_grey")?))
}

impl Resources {
    /// The first texel of the BVH table's triangles.
    fn tri_base(&self) -> u32 {
        self.constants[0].1
    }

    /// The specialization constants of the diffusion's stages for the pattern uploaded.
    fn diffusion_constants(&self) -> Vec<(&str, u32)> {
        diffusion_constants(&self.constants, &self.pattern_constants)
    }

    /// Creates the images and buffers `room` asks for, the pattern image with rows for
    /// `regions` skin regions (nothing uploaded).
    /// `reach_entries`: of the reach's per-triangle data ([`pack::reach_static`]).
    fn new(ctx: &Context, room: &Room, regions: usize, reach_entries: usize) -> Result<Resources> {
        let image = |name: &str, desc: ImageDesc| Image::new(ctx, name, desc);
        let buffer = |name: &str, desc: BufferDesc| Buffer::new(ctx, name, desc);
        let rows = |rows: u32| uint_image([BVH_ROW, rows]);
        let texels = [room.size, room.size];
        let per_vertex = [VERTEX_ROW, pack::rows(room.vertices as usize, VERTEX_ROW)];
        let visibility =
            ImageDesc::d2(vk::Format::R32_UINT, per_vertex).usage(vk::ImageUsageFlags::STORAGE);
        let walk_rows = pack::rows(room.walk_records, BVH_ROW);
        let tiles = (room.size as u64).div_ceil(8) * room.size as u64;
        let texel_bytes = room.size as u64 * room.size as u64 * 16;
        Ok(Resources {
            vertex_frames: buffer(
                "sss vertices",
                BufferDesc::storage(room.vertices as u64 * 32),
            )?,
            bvh: image("sss bvh", rows(room.bvh_node_rows + room.bvh_triangle_rows))?,
            constants: [
                ("TRI_BASE", room.bvh_node_rows * BVH_ROW),
                ("ROW_SEGMENTS", room.row_segments()),
            ],
            pattern_constants: Vec::new(),
            sample_pattern: image(
                "sss sample pattern",
                rgba32f([PATTERN_WIDTH, 2 * regions.clamp(1, MAX_REGIONS) as u32]),
            )?,
            region_tails: buffer(
                "sss region tails",
                BufferDesc::uniform(MAX_REGIONS as u64 * 64),
            )?,
            vertex_regions: buffer(
                "sss vertex regions",
                BufferDesc::storage(room.vertices.max(1) as u64 * 4),
            )?,
            lights: buffer("sss lights", BufferDesc::uniform(MAX_LIGHTS as u64 * 32))?,
            texel_positions: image("sss position", rgba32f(texels))?,
            texel_normals: image("sss normal", rgba32f(texels))?,
            texel_corners: image("sss texel corners", uint_image(texels))?,
            diffusion_start: image("sss diffusion start", uint_image(texels))?,
            walk_records: image("sss walk", rows(walk_rows))?,
            contact_entries: image("sss contact", rows(room.contact_rows))?,
            vertex_visibility: image("sss vertex visibility", visibility)?,
            vertex_transmission: image("sss vertex transmission", rgba32f(per_vertex))?,
            irradiance_rgb: image("sss irradiance", rgba32f(texels))?,
            transmission: image("sss transmission", rgba32f(texels))?,
            irradiance_grey: image("sss grey E", float_image(vk::Format::R32_SFLOAT, texels))?,
            diffuse: buffer("sss diffuse", BufferDesc::storage(texel_bytes))?,
            occupied_tiles: buffer("sss tiles", BufferDesc::storage(tiles * 4))?,
            tile_list: Mutex::new(Vec::new()),
            occupied_segments: buffer(
                "sss occupied segments",
                BufferDesc::storage(pack::needed_segment_words(room.size) * 4),
            )?,
            needed_list: buffer(
                "sss needed segments",
                BufferDesc::storage(16 + tiles * 4).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
            )?,
            rays: buffer("sss shadow rays", BufferDesc::storage(texel_bytes / 2))?,
            ray_head: buffer(
                "sss shadow ray count",
                BufferDesc::storage(16).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
            )?,
            reach_blocks: buffer(
                "sss reach blocks",
                BufferDesc::storage(pack::reach_block_words(room.size) * 4),
            )?,
            reach_static: image("sss reach layout", rows(pack::rows(reach_entries, BVH_ROW)))?,
            reach_list: buffer(
                "sss reach segments",
                BufferDesc::storage(16 + tiles * 4).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
            )?,
        })
    }

    /// Every resource, with the name the shaders bind it by: the passes bind by these names,
    /// and the memory report counts them all.
    fn by_binding(&self) -> [(&'static str, Resource<'_>); 26] {
        let image = Resource::storage_image;
        [
            ("verts", Resource::Buffer(&self.vertex_frames)),
            ("nodes", image(&self.bvh)),
            ("seq", image(&self.sample_pattern)),
            ("tails", Resource::Buffer(&self.region_tails)),
            ("vregion", Resource::Buffer(&self.vertex_regions)),
            ("lights", Resource::Buffer(&self.lights)),
            ("pos", image(&self.texel_positions)),
            ("nrm", image(&self.texel_normals)),
            ("corners", image(&self.texel_corners)),
            ("start", image(&self.diffusion_start)),
            ("walk", image(&self.walk_records)),
            ("contact", image(&self.contact_entries)),
            ("vis", image(&self.vertex_visibility)),
            ("vtrans", image(&self.vertex_transmission)),
            ("irr", image(&self.irradiance_rgb)),
            ("trans", image(&self.transmission)),
            ("pe", image(&self.irradiance_grey)),
            ("diffuse", Resource::Buffer(&self.diffuse)),
            ("tiles", Resource::Buffer(&self.occupied_tiles)),
            ("rays", Resource::Buffer(&self.rays)),
            ("ray_head", Resource::Buffer(&self.ray_head)),
            ("occupied", Resource::Buffer(&self.occupied_segments)),
            ("needed_list", Resource::Buffer(&self.needed_list)),
            ("reach_blocks", Resource::Buffer(&self.reach_blocks)),
            ("reach_static", Resource::storage_image(&self.reach_static)),
            ("reach_list", Resource::Buffer(&self.reach_list)),
        ]
    }

    /// Records the upload of a packed pose: per texel, the walk, the contact entries, the
    /// occupied tiles ([`Resources::set_tiles`]), the vertices and the BVH.
    fn upload(&self, rec: &mut Recorder, p: Packed) -> Result<()> {
        rec.upload_image_rows(&self.texel_positions, p.texel_positions)?;
        rec.upload_image_rows(&self.texel_normals, p.texel_normals)?;
        rec.upload_image_rows(&self.texel_corners, &p.texel_corners)?;
        rec.upload_image_rows(&self.diffusion_start, &p.diffusion_start)?;
        rec.upload_image_rows(&self.walk_records, &at_least_one(&p.walk_records))?;
        rec.upload_image_rows(&self.contact_entries, &at_least_one(&p.contact_entries))?;
        self.set_tiles(rec, p.tiles)?;
        rec.upload(&self.vertex_frames, 0, &p.vertex_frames)?;
        let table =
            crate::geom::bvh::table_texels(&p.bvh_nodes, &p.bvh_triangles, self.tri_base())?;
        rec.upload_image_rows(&self.bvh, &table)
    }

    /// Records the clearing of the transmission image (the irradiance pass leaves it alone
    /// while transmission is off, and in empty tiles).
    fn clear_transmission(&self, rec: &mut Recorder) -> Result<()> {
        let all = Subresources::mip(self.transmission.desc(), 0);
        rec.clear_image(&self.transmission, all, [0.0; 4])
    }

    /// Records the upload of the occupied tiles and the clearing of the outputs the passes
    /// do not write in empty tiles (grey E: -1, no surface; diffuse and transmission:
    /// 0), unless the list is the one already in use.
    fn set_tiles(&self, rec: &mut Recorder, list: Vec<u32>) -> Result<()> {
        let mut current = self
            .tile_list
            .lock()
            .map_err(|_| Error::InvalidArgument("SSS tile list lock poisoned".into()))?;
        if *current == list && !list.is_empty() {
            return Ok(());
        }
        if !list.is_empty() {
            rec.upload(&self.occupied_tiles, 0, &list)?;
        }
        let size = self.irradiance_grey.desc().extent[0];
        rec.upload(&self.occupied_segments, 0, &pack::tile_bitmap(&list, size))?;
        let grey = Subresources::mip(self.irradiance_grey.desc(), 0);
        rec.clear_image(&self.irradiance_grey, grey, [-1.0, 0.0, 0.0, 0.0])?;
        rec.fill_buffer(&self.diffuse, 0)?;
        self.clear_transmission(rec)?;
        *current = list;
        Ok(())
    }

    /// The number of occupied tiles.
    fn tile_count(&self) -> u32 {
        self.tile_list.lock().map(|l| l.len() as u32).unwrap_or(0)
    }
}

/// A compute pipeline built from an embedded shader, and its bindings.
struct Stage {
    pipeline: ComputePipeline,
    bind: BindGroup,
}

impl Stage {
    /// The embedded shader `name`, each of its bindings bound to the kernel's resource of
    /// that name; those in `writes` are declared as written only (`writeonly` in GLSL).
    fn new(ctx: &Context, name: &str, res: &Resources, writes: &[&str]) -> Result<Stage> {
        Stage::from_table(ctx, name, &res.by_binding(), writes, &res.constants)
    }

    /// As [`Stage::new`], the resources looked up by name in `table`; of `constants`
    /// ([`Resources::constants`]), those the shader declares are set.
    fn from_table(
        ctx: &Context,
        name: &str,
        table: &[(&'static str, Resource<'_>)],
        writes: &[&str],
        constants: &[(&str, u32)],
    ) -> Result<Stage> {
        let pipeline = crate::shaders::pipeline_declaring(ctx, name, constants)?;
        let lookup = |b: &str| table.iter().find(|(n, _)| *n == b).map(|(_, r)| r.clone());
        let w = AccessSet::from(A::ComputeShaderWrite);
        let writes: Vec<(&str, AccessSet)> = writes.iter().map(|&b| (b, w)).collect();
        let bind = pipeline.bind_from(lookup, &writes)?;
        Ok(Stage { pipeline, bind })
    }

    fn pass(&self, name: &'static str, args: DispatchArgs<SssKernel>) -> Pass<'_, SssKernel> {
        Pass::dispatch(name, &self.pipeline, &self.bind, args)
    }
}

/// A stage whose shader reads the specialization constant `TRANSMISSION`
/// (glsl/sss/transmission.glsl), built both ways: the stage the params ask for is recorded
/// ([`SamplerParams::transmission`]), and without transmission its code is compiled out
/// (lavapipe runs the body of an `if` on a push word even when no lane takes it).
struct Switched {
    off: Stage,
    on: Stage,
}

impl Switched {
    fn from_table(
        ctx: &Context,
        name: &str,
        table: &[(&'static str, Resource<'_>)],
        writes: &[&str],
        constants: &[(&str, u32)],
    ) -> Result<Switched> {
        let with = |on: bool| {
            let mut c = constants.to_vec();
            c.push(("TRANSMISSION", u32::from(on)));
            Stage::from_table(ctx, name, table, writes, &c)
        };
        Ok(Switched {
            off: with(false)?,
            on: with(true)?,
        })
    }

    fn get(&self, transmission: bool) -> &Stage {
        if transmission { &self.on } else { &self.off }
    }
}

/// An irradiance shader (glsl/sss/irradiance.glsl) and its ray pass (`NAME_rays`).
struct Irradiance {
    shade: Switched,
    rays: Stage,
}

impl Irradiance {
    /// The shader `name` and `name`_rays, their resources looked up in `table`; `writes`:
    /// the shading pass's write-only bindings (the ray pass reads and writes its output).
    fn from_table(
        ctx: &Context,
        name: &str,
        table: &[(&'static str, Resource<'_>)],
        writes: &[&str],
        constants: &[(&str, u32)],
    ) -> Result<Irradiance> {
        let shade_writes = [writes, &["rays"]].concat();
        Ok(Irradiance {
            shade: Switched::from_table(ctx, name, table, &shade_writes, constants)?,
            rays: Stage::from_table(ctx, &format!("{name}_rays"), table, &[], constants)?,
        })
    }

    /// The shading pass and, with `refine`, the list's reset before it and the ray pass over
    /// the list after it (`head`: the list's head; without `refine` nothing is listed).
    /// `listed`: the shading stage over a list of segments and the list (its head the
    /// dispatch's command), in place of the shading over every occupied segment.
    /// `transmission`: the shading stages' variant ([`Switched`]).
    fn passes<'k>(
        &'k self,
        head: &'k Buffer,
        refine: bool,
        listed: Option<(&'k Switched, &'k Buffer)>,
        transmission: bool,
    ) -> Vec<Pass<'k, SssKernel>> {
        let shade = match listed.map(|(s, list)| (s.get(transmission), list)) {
            Some((stage, list)) => Pass::dispatch_indirect(
                PASS_IRRADIANCE,
                &stage.pipeline,
                &stage.bind,
                IndirectArgs {
                    buffer: list,
                    offset: 0,
                },
                SssKernel::irradiance_listed_push,
            ),
            None => {
                (self.shade.get(transmission)).pass(PASS_IRRADIANCE, SssKernel::irradiance_args)
            }
        };
        if !refine {
            return vec![shade];
        }
        vec![
            Pass::list_reset(PASS_RAY_LIST, head),
            shade,
            Pass::dispatch_indirect(
                PASS_IRRADIANCE_RAYS,
                &self.rays.pipeline,
                &self.rays.bind,
                IndirectArgs {
                    buffer: head,
                    offset: 0,
                },
                SssKernel::irradiance_rays_push,
            ),
        ]
    }
}

pub struct SssKernel {
    ctx: Context,
    res: Resources,
    vertex_light: Switched,
    irradiance: Irradiance,
    /// The diffusion of a caller's rgb irradiance: two gathers a sample.
    diffusion_rgb: Stage,
    /// The diffusion of the irradiance pass's grey E: one gather a sample.
    diffusion_grey: Stage,
    /// What the irradiance last recorded is ([`IRR_GREY`]: the irradiance pass's grey E in
    /// `irradiance_grey`; [`IRR_ENV`]: its rgb E in the [`Env`] image; [`IRR_UPLOAD`]: a
    /// caller's upload in `irradiance_rgb`): picks the pipeline of
    /// [`SssKernel::record_diffusion`] and the image [`Kernel::read_back`] reads. A frame's
    /// own diffusion pass always gathers what its irradiance pass wrote.
    irradiance_kind: AtomicU8,
    /// The per-vertex irradiance added by the irradiance pass, when set.
    env: Option<Env>,
    /// The caller's bitmap of the atlas segments its diffusion must fill
    /// ([`SssKernel::set_needed_segments`]), when set: the diffusion then runs over their
    /// list.
    needed: Option<Needed>,
    /// The reach of the needed segments ([`SssKernel::set_reach`]), when set.
    reach: Option<Reach>,
    settings: Settings,
    /// The per-frame geometry passes of a skinned mesh ([`SssKernel::new_posed`]).
    posed: Option<Posed>,
}

/// The posed vertex buffers a skinned mesh's frame starts from: vec4 per vertex in model
/// units, positions (xyz, 1) and unit normals (xyz, 0), in the mesh's own vertex order (the
/// layout of `kernels::pose`, whose `PoseKernel::positions` / `normals` a caller passes). The
/// kernel's bind group holds them, so a pass that writes them earlier in the same recording
/// is ordered before the geometry passes by the recorder's tracking.
#[derive(Clone, Copy)]
pub struct PosedBuffers<'a> {
    pub positions: &'a Buffer,
    pub normals: &'a Buffer,
    /// Millimetres per model unit.
    pub mm_per_unit: f32,
}

/// Buffers of the [`PosedBuffers`] layout filled from the host: a pose computed on the CPU
/// (`kernels::pose::cpu`, `scene::texspace::posed`), the tests' stand-in for the skinning
/// pass.
pub struct PosedSource {
    pub positions: Buffer,
    pub normals: Buffer,
}

impl PosedSource {
    /// Creates the buffers and records the upload of `positions`, `normals`.
    pub fn upload(
        rec: &mut Recorder,
        positions: &[glam::Vec3],
        normals: &[glam::Vec3],
    ) -> Result<PosedSource> {
        let ctx = rec.context();
        let bytes = positions.len().max(1) as u64 * 16;
        let src = PosedSource {
            positions: Buffer::new(&ctx, "sss posed positions", BufferDesc::storage(bytes))?,
            normals: Buffer::new(&ctx, "sss posed normals", BufferDesc::storage(bytes))?,
        };
        src.write(rec, positions, normals)?;
        Ok(src)
    }

    /// Records the upload of another pose into the buffers.
    pub fn write(
        &self,
        rec: &mut Recorder,
        positions: &[glam::Vec3],
        normals: &[glam::Vec3],
    ) -> Result<()> {
        let p: Vec<[f32; 4]> = positions.iter().map(|p| p.extend(1.0).into()).collect();
        let n: Vec<[f32; 4]> = normals.iter().map(|n| n.extend(0.0).into()).collect();
        rec.upload(&self.positions, 0, &p)?;
        rec.upload(&self.normals, 0, &n)
    }

    /// The buffers as a [`PosedBuffers`].
    pub fn buffers(&self, mm_per_unit: f32) -> PosedBuffers<'_> {
        PosedBuffers {
            positions: &self.positions,
            normals: &self.normals,
            mm_per_unit,
        }
    }
}

/// The per-frame geometry of a skinned mesh: what the UV layout fixes ([`posed::Layout`])
/// and the passes (their bind groups hold the posed buffers they read).
struct Posed {
    mm_per_unit: f32,
    /// Per vertex: the vertex whose posed position it takes.
    weld: Buffer,
    /// Per triangle: the surface walk's topology ([`posed::walk_topology`]), TOPOLOGY_TEXELS
    /// texels from texel TOPOLOGY_TEXELS t, BVH_ROW a row.
    walk_topo: Image,
    /// Per triangle (BVH_ROW a row): face normal and texel area, written each frame.
    trirec: Image,
    /// The vertex frames as an image (vertex v at texels 2v, 2v + 1, BVH_ROW a row), written
    /// each frame beside the `verts` buffer.
    vframes: Image,
    /// Per texel: triangle, barycentrics, flag (fixed).
    texel_source: Image,
    /// The BVH's fixed topology ([`posed::BvhTopology::gpu`]) and its triangle slots.
    bvh_topo: Buffer,
    bvh_slots: Buffer,
    vertices: Stage,
    triangles: Stage,
    /// The texel geometry of this pose into the `pos`, `nrm` images: not a pass of the frame
    /// (the posed irradiance computes it where it needs it), recorded by
    /// [`SssKernel::read_back_geometry`] for diagnostics.
    texels: Stage,
    /// The irradiance of a posed frame (glsl/sss/irradiance_posed.comp).
    irradiance: Irradiance,
    bvh_leaves: Stage,
    bvh_refit: Stage,
    triangle_count: u32,
    leaf_count: u32,
    nodes: usize,
}

impl Posed {
    /// The kernel's own resources of the posed passes (the posed buffers are the caller's).
    fn by_binding(&self) -> [(&'static str, Resource<'_>); 7] {
        [
            ("vframes", Resource::storage_image(&self.vframes)),
            ("weld", Resource::Buffer(&self.weld)),
            ("walk_topo", Resource::storage_image(&self.walk_topo)),
            ("trirec", Resource::storage_image(&self.trirec)),
            ("source", Resource::storage_image(&self.texel_source)),
            ("bvh_topo", Resource::Buffer(&self.bvh_topo)),
            ("bvh_slots", Resource::Buffer(&self.bvh_slots)),
        ]
    }
}

/// A per-vertex rgb irradiance added to the lights' ([`SssKernel::set_vertex_irradiance`]):
/// the rgb E image and the passes that write and diffuse it (their bind groups hold the
/// caller's buffer).
struct Env {
    /// Per texel: rgb E, alpha 1 on the surface and -1 where none (RGBA32F).
    image: Image,
    /// The caller's per-vertex irradiance as an image (vertex v at (v % VERTEX_ROW,
    /// v / VERTEX_ROW)), written by `sss vertex irradiance`.
    vertex_texels: Image,
    /// The caller's per-vertex buffer.
    venv: Buffer,
    copy: Stage,
    irradiance: Irradiance,
    diffusion: Stage,
    /// With the reach set: the shading pass over the reach's list
    /// (glsl/sss/irradiance_posed_env_listed.comp).
    listed: Option<Switched>,
}

/// The passes of a pass table before the lights ([`SssKernel::front_passes`]).
fn front_len(table: &[Pass<'_, SssKernel>]) -> usize {
    table
        .iter()
        .position(|p| p.name == PASS_LIGHTS)
        .unwrap_or(0)
}

/// The needed segments ([`SssKernel::set_needed_segments`]).
struct Needed {
    /// Pass `sss needed list` (its bind group holds the bitmap).
    list: Stage,
    /// The caller's bitmap (the reach reads it too).
    bitmap: Buffer,
}

/// The passes of the reach ([`SssKernel::set_reach`]).
struct Reach {
    /// `sss reach boxes` (its bind group holds the caller's needed bitmap).
    boxes: Stage,
    /// With triangle marks: the pass and the bit of triangle 0 in the caller's bitmap.
    triangles: Option<(Stage, u32)>,
    list: Stage,
}

/// Where [`SssKernel::set_reach`] marks the triangles whose irradiance the reach needs: a
/// caller's bitmap (bit i % 32 of u32 word i / 32), triangle t at bit `first + t`.
#[derive(Clone, Copy)]
pub struct ReachMarks<'a> {
    pub bitmap: &'a Buffer,
    pub first: u32,
}

/// The per-frame geometry as the GPU computed it, read back (tests and diagnostics; not part
/// of a frame).
#[derive(Clone, Debug)]
pub struct PosedGeometry {
    /// Per vertex: position (mm), unit normal.
    pub vertex_frames: Vec<[[f32; 4]; 2]>,
    /// Per texel: position and flag, normal and area.
    pub pos: Vec<[f32; 4]>,
    pub nrm: Vec<[f32; 4]>,
    /// The surface walk's records ([`super::walk::SurfaceWalk::records`]).
    pub walk_records: Vec<[u32; 4]>,
    /// The BVH as [`crate::geom::bvh::Bvh::flat`] lays it out.
    pub bvh_nodes: Vec<[f32; 8]>,
    pub bvh_triangles: Vec<[f32; 12]>,
}

/// The readbacks of [`SssKernel::read_back_geometry`].
pub struct GeometryReadback {
    verts: Readback,
    pos: Readback,
    nrm: Readback,
    walk: Readback,
    bvh: Readback,
}

impl SssKernel {
    /// Creates buffers, images and pipelines for `geo` and records the uploads into `rec`.
    /// `regions`: one [`super::Profile`] for the whole mesh (`&profile`), or a profile per
    /// region of its triangles ([`Regions`], multi-region skin).
    pub fn new(
        rec: &mut Recorder,
        geo: &TexGeometry,
        regions: impl Into<Regions>,
        params: SamplerParams,
    ) -> Result<SssKernel> {
        params.check()?;
        let regions: Regions = regions.into();
        let packed = Packed::new(geo, &regions)?;
        let ctx = rec.context();
        let width_limit = ctx.limits().max_image_dimension_2d;
        if width_limit < MAX_SAMPLES {
            return Err(Error::InvalidArgument(format!(
                "the SSS sampler keeps its pattern in an image {MAX_SAMPLES} texels wide; the \
                 device allows {width_limit} (maxImageDimension2D)"
            )));
        }
        let room = Room::of(&packed);
        // The reach's data ([`SssKernel::set_reach`], posed kernels only: their UV layout and
        // contact entries are those of this first pose for good).
        let reach = pack::reach_static(
            &packed.diffusion_start,
            &packed.contact_entries,
            packed.size,
            packed.triangles,
        );
        let mut res = Resources::new(&ctx, &room, regions.len(), reach.len())?;
        let pattern = Pattern::new(&regions, params.samples);
        rec.upload_image_rows(&res.sample_pattern, &pattern.texels(&regions))?;
        res.pattern_constants = pattern.constants();
        let vertex_light = Switched::from_table(
            &ctx,
            "sss/vertex_light",
            &res.by_binding(),
            &["vis", "vtrans"],
            &res.constants,
        )?;
        let irradiance = Irradiance::from_table(
            &ctx,
            "sss/irradiance",
            &res.by_binding(),
            &["trans", "pe"],
            &res.constants,
        )?;
        let (diffusion_rgb, diffusion_grey) =
            diffusion_stages(&ctx, &res, &res.diffusion_constants())?;
        rec.upload(&res.region_tails, 0, &pack::region_tails(&regions))?;
        let vertex_regions: Vec<u32> = regions
            .of_vertices(&geo.triangles, geo.positions.len())
            .into_iter()
            .map(u32::from)
            .collect();
        rec.upload(&res.vertex_regions, 0, &at_least_one(&vertex_regions))?;
        // The reach's data, its empty block bitmap and list.
        rec.upload_image_rows(&res.reach_static, &reach)?;
        rec.fill_buffer(&res.reach_blocks, 0)?;
        rec.upload(&res.reach_list, 0, &crate::kernels::EMPTY_LIST_HEAD)?;
        res.upload(rec, packed)?;
        Ok(SssKernel {
            ctx,
            res,
            vertex_light,
            irradiance,
            diffusion_rgb,
            diffusion_grey,
            // The frame path (irradiance pass, then the grey diffusion) until a caller uploads
            // an irradiance.
            irradiance_kind: AtomicU8::new(IRR_GREY),
            env: None,
            needed: None,
            reach: None,
            settings: Settings {
                regions,
                params,
                shadow_bias: shadow_bias(geo.extent_mm()),
                room,
                reach_radius: pattern.radius(),
            },
            posed: None,
        })
    }

    /// The kernel for a skinned mesh whose pose is computed on the GPU: `geo` is its rest
    /// pose (mm) and `rest` its rest positions in model units; each frame starts from the
    /// posed buffers `src` and computes the vertex frames, the surface walk's records, the
    /// texel geometry and the BVH (a refit of the rest pose's topology) on the GPU (passes
    /// `sss pose *`, `sss bvh *`), before the lights. What only the UV layout fixes is
    /// uploaded here, once; so are the contact entries, built for the rest pose and reused in
    /// every pose (their cost in error: `vkshade sss --anim`, report `contact_reuse`).
    pub fn new_posed(
        rec: &mut Recorder,
        geo: &TexGeometry,
        rest: &[glam::Vec3],
        regions: impl Into<Regions>,
        params: SamplerParams,
        src: PosedBuffers<'_>,
    ) -> Result<SssKernel> {
        let regions: Regions = regions.into();
        regions.check_mesh(geo.triangles.len())?;
        let mut layout = posed::Layout::new(geo, rest)?;
        posed::topology_regions(&mut layout.walk_topology, &regions);
        let vertices = geo.positions.len();
        for (name, b) in [("positions", src.positions), ("normals", src.normals)] {
            if b.size() < vertices as u64 * 16 {
                return Err(Error::InvalidArgument(format!(
                    "posed {name} buffer of {} bytes for {vertices} vertices (vec4 each)",
                    b.size()
                )));
            }
        }
        if !(src.mm_per_unit.is_finite() && src.mm_per_unit > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "mm per unit {} must be finite and > 0",
                src.mm_per_unit
            )));
        }
        let mut kernel = SssKernel::new(rec, geo, &regions, params)?;
        let ctx = kernel.ctx.clone();
        let buffer = |name: &str, bytes: u64| Buffer::new(&ctx, name, BufferDesc::storage(bytes));
        let weld = buffer("sss weld", layout.weld.len().max(1) as u64 * 4)?;
        // An image, not a buffer: `sss pose triangles` reads 13 texels per triangle (its own
        // four, three of each neighbour's), at per-lane addresses (lavapipe loads a storage
        // buffer's uvec4 there as a loop over the lanes per component, an image texel as one
        // gather).
        let walk_topo = Image::new(
            &ctx,
            "sss walk topology",
            uint_image([BVH_ROW, pack::rows(layout.walk_topology.len(), BVH_ROW)]),
        )?;
        let topo = layout.bvh.gpu();
        let bvh_topo = buffer("sss bvh topology", topo.len() as u64 * 4)?;
        let bvh_slots = buffer("sss bvh slots", layout.bvh.slots.len().max(1) as u64 * 16)?;
        let triangles = geo.triangles.len();
        let trirec = Image::new(
            &ctx,
            "sss triangle records",
            rgba32f([BVH_ROW, pack::rows(triangles, BVH_ROW)]),
        )?;
        let vframes = Image::new(
            &ctx,
            "sss vertex frames",
            rgba32f([BVH_ROW, pack::rows(2 * vertices, BVH_ROW)]),
        )?;
        let size = geo.size;
        let texel_source = Image::new(&ctx, "sss texel source", uint_image([size, size]))?;
        rec.upload(&weld, 0, &at_least_one(&layout.weld))?;
        rec.upload_image_rows(&walk_topo, &at_least_one(&layout.walk_topology))?;
        rec.upload(&bvh_topo, 0, &topo)?;
        rec.upload(&bvh_slots, 0, &at_least_one(&layout.bvh.slots))?;
        rec.upload_image_rows(&texel_source, &layout.texel_source)?;
        // The triangle records are written by every frame before they are read; cleared
        // once so that rows past the last triangle hold defined data too.
        rec.clear_image(&trirec, Subresources::mip(trirec.desc(), 0), [0.0; 4])?;
        rec.clear_image(&vframes, Subresources::mip(vframes.desc(), 0), [0.0; 4])?;
        let table: Vec<(&'static str, Resource<'_>)> = kernel
            .res
            .by_binding()
            .into_iter()
            .chain([
                ("posed_pos", Resource::Buffer(src.positions)),
                ("posed_nrm", Resource::Buffer(src.normals)),
                ("weld", Resource::Buffer(&weld)),
                ("walk_topo", Resource::storage_image(&walk_topo)),
                ("trirec", Resource::storage_image(&trirec)),
                ("vframes", Resource::storage_image(&vframes)),
                ("source", Resource::storage_image(&texel_source)),
                ("bvh_topo", Resource::Buffer(&bvh_topo)),
                ("bvh_slots", Resource::Buffer(&bvh_slots)),
            ])
            .collect();
        let constants = kernel.res.constants;
        let stage =
            |name: &str, writes: &[&str]| Stage::from_table(&ctx, name, &table, writes, &constants);
        let vertices_stage = stage("sss/pose_vertices", &["verts", "vframes"])?;
        let triangles_stage = stage("sss/pose_triangles", &["walk", "trirec"])?;
        let texels = stage("sss/pose_texels", &["pos", "nrm"])?;
        let irradiance = Irradiance::from_table(
            &ctx,
            "sss/irradiance_posed",
            &table,
            &["trans", "pe"],
            &constants,
        )?;
        let bvh_leaves = stage("sss/bvh_leaves", &["nodes"])?;
        let bvh_refit = stage("sss/bvh_refit", &[])?;
        drop(table);
        kernel.posed = Some(Posed {
            triangle_count: triangles as u32,
            leaf_count: layout.bvh.leaves.len() as u32,
            nodes: layout.bvh.nodes,
            mm_per_unit: src.mm_per_unit,
            weld,
            walk_topo,
            trirec,
            vframes,
            texel_source,
            bvh_topo,
            bvh_slots,
            vertices: vertices_stage,
            triangles: triangles_stage,
            texels,
            irradiance,
            bvh_leaves,
            bvh_refit,
        });
        Ok(kernel)
    }

    /// Whether the kernel computes its geometry per frame from posed buffers.
    pub fn is_posed(&self) -> bool {
        self.posed.is_some()
    }

    /// Records the readback of the geometry the GPU holds: vertex frames, texel position and
    /// normal, walk records, BVH (for tests and diagnostics, not in a frame). A posed kernel
    /// first records `sss pose texels`, which computes the texel position and normal of the
    /// pose the frame's passes last computed (a frame's irradiance computes them where it
    /// needs them and stores none).
    pub fn read_back_geometry(&self, rec: &mut Recorder) -> Result<GeometryReadback> {
        if let Some(p) = &self.posed {
            self.pose_texels_args(&[])?
                .record(rec, &p.texels.pipeline, &p.texels.bind)?;
        }
        let r = &self.res;
        let whole = |image: &Image| ImageRegion::whole(image.desc());
        Ok(GeometryReadback {
            verts: rec.read_back(&r.vertex_frames)?,
            pos: rec.read_back_image(&r.texel_positions, whole(&r.texel_positions))?,
            nrm: rec.read_back_image(&r.texel_normals, whole(&r.texel_normals))?,
            walk: rec.read_back_image(&r.walk_records, whole(&r.walk_records))?,
            bvh: rec.read_back_image(&r.bvh, whole(&r.bvh))?,
        })
    }

    /// The geometry of [`SssKernel::read_back_geometry`], once its submission is complete.
    pub fn collect_geometry(&self, rb: &GeometryReadback) -> Result<PosedGeometry> {
        let room = &self.settings.room;
        let walk_texels = room.walk_records;
        let nodes = match &self.posed {
            Some(p) => p.nodes,
            None => room.triangles.max(1) * 2 - 1,
        };
        let mut walk_records: Vec<[u32; 4]> = rb.walk.to_vec()?;
        walk_records.truncate(walk_texels);
        let texels: Vec<[u32; 4]> = rb.bvh.to_vec()?;
        let (node_texels, tri_texels) = texels.split_at(self.res.tri_base() as usize);
        let bvh_nodes = node_texels
            .chunks_exact(2)
            .take(nodes)
            .map(|c| {
                let mut n = [0f32; 8];
                for k in 0..4 {
                    n[k] = f32::from_bits(c[0][k]);
                    n[4 + k] = f32::from_bits(c[1][k]);
                }
                n
            })
            .collect();
        let bvh_triangles = tri_texels
            .chunks_exact(3)
            .take(room.triangles)
            .map(|c| {
                let mut t = [0f32; 12];
                for (r, row) in c.iter().enumerate() {
                    for k in 0..4 {
                        t[4 * r + k] = f32::from_bits(row[k]);
                    }
                }
                t
            })
            .collect();
        Ok(PosedGeometry {
            vertex_frames: rb.verts.to_vec()?,
            pos: rb.pos.to_vec()?,
            nrm: rb.nrm.to_vec()?,
            walk_records,
            bvh_nodes,
            bvh_triangles,
        })
    }

    /// Vertices of the mesh (a per-vertex irradiance holds at least this many vec4).
    pub fn vertex_count(&self) -> u32 {
        self.settings.room.vertices
    }

    pub fn size(&self) -> u32 {
        self.settings.room.size
    }

    /// Records the upload of a new pose of the same mesh (same texture size, same triangles
    /// and UV layout; e.g. the skinned mesh of the next frame re-rasterised): the texel
    /// geometry, the vertices and a rebuilt BVH.
    pub fn update_geometry(&self, rec: &mut Recorder, geo: &TexGeometry) -> Result<()> {
        if self.posed.is_some() {
            return Err(Error::InvalidArgument(
                "this SSS kernel computes its geometry from the posed buffers every frame; \
                 update_geometry would be overwritten (use SssKernel::new for uploaded geometry)"
                    .into(),
            ));
        }
        let s = &self.settings;
        self.res.upload(rec, s.room.pack(geo, &s.regions)?)
    }

    /// The skin regions' profiles the kernel diffuses with (one region for a single
    /// profile).
    pub fn regions(&self) -> &Regions {
        &self.settings.regions
    }

    pub fn params(&self) -> &SamplerParams {
        &self.settings.params
    }

    /// Changes the sampler settings: records the upload of the new sample sequence. Where
    /// the diffusion holds the pattern as constants (one region, at most
    /// [`pack::MAX_UNIFORM_SAMPLES`] samples, before or after), a new pattern also builds the
    /// diffusion's pipelines again.
    pub fn set_params(&mut self, rec: &mut Recorder, params: SamplerParams) -> Result<()> {
        params.check()?;
        let pattern = Pattern::new(&self.settings.regions, params.samples);
        // The diffusion's stages hold the pattern's constants: built again where they change,
        // before anything is recorded, so that a pipeline that fails to build leaves the
        // kernel as it was.
        let pattern_constants = pattern.constants();
        let rebuilt = if pattern_constants != self.res.pattern_constants {
            let constants = diffusion_constants(&self.res.constants, &pattern_constants);
            let (rgb, grey) = diffusion_stages(&self.ctx, &self.res, &constants)?;
            let env = match &self.env {
                Some(env) => {
                    Some(self.env_diffusion(&env.image, self.needed.is_some(), &constants)?)
                }
                None => None,
            };
            Some((rgb, grey, env))
        } else {
            None
        };
        if self.settings.params.transmission && !params.transmission {
            self.res.clear_transmission(rec)?;
        }
        rec.upload_image_rows(
            &self.res.sample_pattern,
            &pattern.texels(&self.settings.regions),
        )?;
        if let Some((rgb, grey, env)) = rebuilt {
            self.diffusion_rgb = rgb;
            self.diffusion_grey = grey;
            if let (Some(e), Some(d)) = (&mut self.env, env) {
                e.diffusion = d;
            }
        }
        self.res.pattern_constants = pattern_constants;
        let s = &mut self.settings;
        s.reach_radius = pattern.radius();
        s.params = params;
        Ok(())
    }

    /// The irradiance image of [`SssKernel::upload_irradiance`] (RGBA32F, rgb E). The
    /// irradiance pass writes [`SssKernel::grey_irradiance`] instead.
    pub fn irradiance(&self) -> &Image {
        &self.res.irradiance_rgb
    }

    /// The grey irradiance per texel (R32F: E of the white lights, -1 where no surface),
    /// written by `sss irradiance`.
    pub fn grey_irradiance(&self) -> &Image {
        &self.res.irradiance_grey
    }

    /// The diffuse buffer, written by `sss diffusion`.
    pub fn diffuse(&self) -> &Buffer {
        &self.res.diffuse
    }

    /// The transmission image (rgb, alpha thickness), written by `sss irradiance`.
    pub fn transmission(&self) -> &Image {
        &self.res.transmission
    }

    /// Records the upload of a caller's irradiance (rgba per texel; alpha ignored) in place of
    /// the irradiance pass.
    pub fn upload_irradiance(&self, rec: &mut Recorder, e: &[[f32; 4]]) -> Result<()> {
        pack::check_irradiance(self.size(), e)?;
        rec.upload_image_rows(&self.res.irradiance_rgb, e)?;
        self.irradiance_kind.store(IRR_UPLOAD, Ordering::Relaxed);
        Ok(())
    }

    /// Sets (or with `None` removes) a per-vertex rgb irradiance that the irradiance pass adds
    /// to the lights' E before the diffusion: `irradiance` holds a vec4 per vertex of the
    /// (posed) mesh, (E_r, E_g, E_b, -) radiometric (no 1/pi, the lights' units), e.g. the
    /// environment shadowed by the character (another kernel's output; vertices past this
    /// mesh's are not read). Per texel it is interpolated with the texel's barycentrics over
    /// its triangle, as the transmission is. The buffer is bound by the passes, so a pass
    /// that writes it earlier in the same recording is ordered before the irradiance by the
    /// recorder's tracking. With it the irradiance is rgb (one rgba gather per diffusion
    /// sample instead of one channel); without it the grey path is unchanged. Records the
    /// clearing of the rgb image (its empty texels say "no surface").
    pub fn set_vertex_irradiance(
        &mut self,
        rec: &mut Recorder,
        irradiance: Option<&Buffer>,
    ) -> Result<()> {
        let Some(buffer) = irradiance else {
            self.env = None;
            return Ok(());
        };
        let vertices = self.settings.room.vertices as u64;
        if buffer.size() < vertices * 16 {
            return Err(Error::InvalidArgument(format!(
                "per-vertex irradiance buffer of {} bytes for {vertices} vertices (vec4 each)",
                buffer.size()
            )));
        }
        let ctx = rec.context();
        let size = self.settings.room.size;
        let image = Image::new(&ctx, "sss rgb E", rgba32f([size, size]))?;
        rec.clear_image(
            &image,
            Subresources::mip(image.desc(), 0),
            [0.0, 0.0, 0.0, -1.0],
        )?;
        let per_vertex = [VERTEX_ROW, pack::rows(vertices as usize, VERTEX_ROW)];
        let vertex_texels = Image::new(&ctx, "sss vertex E", rgba32f(per_vertex))?;
        let table = self.env_table(buffer, &vertex_texels, &image);
        let shader = if self.posed.is_some() {
            "sss/irradiance_posed_env"
        } else {
            "sss/irradiance_env"
        };
        let constants = self.res.constants;
        let copy = Stage::from_table(&ctx, "sss/vertex_env", &table, &["venv_texels"], &constants)?;
        let irradiance =
            Irradiance::from_table(&ctx, shader, &table, &["trans", "penv"], &constants)?;
        drop(table);
        let diffusion = self.env_diffusion(
            &image,
            self.needed.is_some(),
            &self.res.diffusion_constants(),
        )?;
        let listed = match &self.reach {
            Some(_) => Some(self.listed_irradiance(buffer, &vertex_texels, &image)?),
            None => None,
        };
        self.env = Some(Env {
            image,
            vertex_texels,
            venv: buffer.clone(),
            copy,
            irradiance,
            diffusion,
            listed,
        });
        Ok(())
    }

    /// The resources of the per-vertex irradiance's passes (`venv`: the caller's per-vertex
    /// buffer, `vertex_texels` and `image` the [`Env`]'s).
    fn env_table<'a>(
        &'a self,
        venv: &'a Buffer,
        vertex_texels: &'a Image,
        image: &'a Image,
    ) -> Vec<(&'static str, Resource<'a>)> {
        self.table_with([
            ("venv", Resource::Buffer(venv)),
            ("venv_texels", Resource::storage_image(vertex_texels)),
            ("penv", Resource::storage_image(image)),
        ])
    }

    /// The env irradiance's shading pass over the reach's list ([`SssKernel::env_table`]).
    fn listed_irradiance(
        &self,
        venv: &Buffer,
        vertex_texels: &Image,
        image: &Image,
    ) -> Result<Switched> {
        let table = self.env_table(venv, vertex_texels, image);
        Switched::from_table(
            &self.ctx,
            "sss/irradiance_posed_env_listed",
            &table,
            &["trans", "penv"],
            &self.res.constants,
        )
    }

    /// Restricts the irradiance to the reach of the needed segments: the texels the
    /// diffusion of the needed segments can read. Needs a posed kernel
    /// ([`SssKernel::new_posed`]) with a per-vertex irradiance and needed segments set
    /// ([`SssKernel::set_vertex_irradiance`], [`SssKernel::set_needed_segments`]); `None`
    /// computes the irradiance of every occupied segment again.
    ///
    /// Each frame, after the geometry passes and `sss needed list`: `sss reach boxes` bounds,
    /// per triangle with a texel in a needed segment, where its samples land through its own
    /// UV map and through the maps of its shared edges (every landing of a texel at most the
    /// patterns' longest offset from its centre, glsl/sss/reach_boxes.comp) and where its
    /// contact entries read, in blocks of 8 x [`pack::REACH_BLOCK_ROWS`] texels; `sss reach
    /// list` lists the occupied segments of those blocks, and the
    /// irradiance runs over that list (the other segments keep what they held: the
    /// diffusion of the needed segments reads none of them). The diffusion's output is the
    /// same as without the reach, bit for bit.
    ///
    /// With `marks`, `sss reach triangles` also marks every triangle with a texel in a
    /// reached block in the caller's bitmap, so that a pass before the irradiance (the
    /// character frame's vertex list) can compute the per-vertex irradiance of those
    /// triangles' corners only. The passes that write the marks come before the lights:
    /// [`SssKernel::record_front`] records them, [`SssKernel::record_back`] the rest.
    pub fn set_reach(&mut self, reach: Option<Option<ReachMarks<'_>>>) -> Result<()> {
        let Some(marks) = reach else {
            self.reach = None;
            if let Some(env) = &mut self.env {
                env.listed = None;
            }
            return Ok(());
        };
        let (env, needed) = match (&self.env, &self.needed, &self.posed) {
            (Some(env), Some(needed), Some(_)) => (env, &needed.bitmap),
            _ => {
                return Err(Error::InvalidArgument(
                    "the reach restricts the irradiance of a posed kernel with a per-vertex \
                     irradiance and needed segments: set them first (new_posed, \
                     set_vertex_irradiance, set_needed_segments)"
                        .into(),
                ));
            }
        };
        let triangles = self.settings.room.triangles as u64;
        let triangles = match marks {
            Some(m) => {
                let bits = m.first as u64 + triangles;
                if m.bitmap.size() < bits.div_ceil(32) * 4 {
                    return Err(Error::InvalidArgument(format!(
                        "reach marks: a bitmap of {} bytes for bits {}..{bits}",
                        m.bitmap.size(),
                        m.first
                    )));
                }
                let table = self.table_with([("reach_marks", Resource::Buffer(m.bitmap))]);
                let stage = Stage::from_table(
                    &self.ctx,
                    "sss/reach_triangles",
                    &table,
                    &[],
                    &self.res.constants,
                )?;
                Some((stage, m.first))
            }
            None => None,
        };
        let listed = self.listed_irradiance(&env.venv, &env.vertex_texels, &env.image)?;
        self.reach = Some(Reach {
            boxes: self.reach_boxes(needed)?,
            triangles,
            list: Stage::new(&self.ctx, "sss/reach_list", &self.res, &["reach_list"])?,
        });
        if let Some(env) = &mut self.env {
            env.listed = Some(listed);
        }
        Ok(())
    }

    /// The kernel's resources by binding name (the posed geometry's too), then `extra`.
    fn table_with<'a>(
        &'a self,
        extra: impl IntoIterator<Item = (&'static str, Resource<'a>)>,
    ) -> Vec<(&'static str, Resource<'a>)> {
        let posed = self.posed.as_ref().map(|p| p.by_binding());
        self.res
            .by_binding()
            .into_iter()
            .chain(posed.into_iter().flatten())
            .chain(extra)
            .collect()
    }

    /// The diffusion stage of the per-vertex irradiance's rgb E (`image`), on every occupied
    /// segment or, `listed`, on those of the needed list (`sss needed list`).
    fn env_diffusion(
        &self,
        image: &Image,
        listed: bool,
        constants: &[(&str, u32)],
    ) -> Result<Stage> {
        let table = self.table_with([("penv", Resource::storage_image(image))]);
        let shader = if listed {
            "sss/diffusion_env_listed"
        } else {
            "sss/diffusion_env"
        };
        Stage::from_table(&self.ctx, shader, &table, &["diffuse"], constants)
    }

    /// Bytes of a needed-segment bitmap for this kernel's atlas
    /// ([`SssKernel::set_needed_segments`]): one bit per 8x1 row segment, segment
    /// `y * ceil(size / 8) + x / 8`, in u32 words (at least one).
    pub fn needed_segment_bytes(&self) -> u64 {
        pack::needed_segment_words(self.size()) * 4
    }

    /// Restricts the diffusion of a per-vertex irradiance ([`SssKernel::set_vertex_irradiance`],
    /// set first) to the atlas segments a caller needs each frame: `needed` is a bitmap of
    /// [`SssKernel::needed_segment_bytes`] bytes, bit s of word s / 32 for the 8x1 row segment
    /// s = y * ceil(size / 8) + x / 8, written by an earlier pass of the same recording (the
    /// character frame marks the segments its compose pass reads: `compose need`). A pass
    /// (`sss needed list`) lists the occupied segments it marks and the diffusion is
    /// dispatched indirectly over that list; the other segments' texels keep what they held:
    /// only the marked ones are this frame's. `None` diffuses every segment again.
    pub fn set_needed_segments(&mut self, needed: Option<&Buffer>) -> Result<()> {
        let Some(env) = &self.env else {
            return Err(Error::InvalidArgument(
                "needed segments restrict the diffusion of a per-vertex irradiance: set one \
                 first (set_vertex_irradiance)"
                    .into(),
            ));
        };
        if let Some(b) = needed
            && b.size() < self.needed_segment_bytes()
        {
            return Err(Error::InvalidArgument(format!(
                "needed-segment bitmap of {} bytes for a {}^2 atlas ({} bytes)",
                b.size(),
                self.size(),
                self.needed_segment_bytes()
            )));
        }
        let diffusion = self.env_diffusion(
            &env.image,
            needed.is_some(),
            &self.res.diffusion_constants(),
        )?;
        self.needed = match needed {
            Some(bitmap) => {
                let table = self.table_with([("needed", Resource::Buffer(bitmap))]);
                Some(Needed {
                    list: Stage::from_table(
                        &self.ctx,
                        "sss/needed_list",
                        &table,
                        &["needed_list"],
                        &self.res.constants,
                    )?,
                    bitmap: bitmap.clone(),
                })
            }
            None => None,
        };
        if let Some(env) = &mut self.env {
            env.diffusion = diffusion;
        }
        if let (Some(bitmap), Some(_)) = (needed, &self.reach) {
            let boxes = self.reach_boxes(bitmap)?;
            if let Some(r) = &mut self.reach {
                r.boxes = boxes;
            }
        }
        Ok(())
    }

    /// Pass `sss reach boxes` over the needed bitmap `needed`.
    fn reach_boxes(&self, needed: &Buffer) -> Result<Stage> {
        let table = self.table_with([("needed", Resource::Buffer(needed))]);
        Stage::from_table(
            &self.ctx,
            "sss/reach_boxes",
            &table,
            &[],
            &self.res.constants,
        )
    }

    /// The passes of a frame before the lights ([`Kernel::passes`] up to `sss lights`): the
    /// geometry of a posed kernel and, with the reach set ([`SssKernel::set_reach`]), the
    /// needed list and the reach. They read neither the lights nor the per-vertex
    /// irradiance, so a caller can record them earlier ([`SssKernel::record_front`]), e.g.
    /// before the passes that compute the per-vertex irradiance of the triangles the reach
    /// marks.
    pub fn front_passes(&self) -> usize {
        front_len(&self.pass_table())
    }

    /// Records the passes before the lights ([`SssKernel::front_passes`]).
    pub fn record_front(&self, rec: &mut Recorder) -> Result<()> {
        let table = self.pass_table();
        for pass in &table[..front_len(&table)] {
            pass.record(self, rec, &[])?;
        }
        Ok(())
    }

    /// Records the rest of a frame after [`SssKernel::record_front`]: [`Kernel::record`]
    /// is the two in a row.
    pub fn record_back(&self, rec: &mut Recorder, lights: &[Light]) -> Result<()> {
        self.check_input(lights)?;
        let table = self.pass_table();
        for pass in &table[front_len(&table)..] {
            pass.record(self, rec, lights)?;
        }
        Ok(())
    }

    /// Records the readback of the reach's list of segments (what `sss reach list` last
    /// wrote; [`SssKernel::reach_segments`] reads it).
    pub fn read_back_reach(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.res.reach_list)
    }

    /// The reached occupied segments (x / 8 | y << 16, in no set order) of a
    /// [`SssKernel::read_back_reach`], once its submission is complete.
    pub fn reach_segments(&self, rb: &Readback) -> Result<Vec<u32>> {
        let words: Vec<u32> = rb.to_vec()?;
        let n = words.get(3).copied().unwrap_or(0) as usize;
        Ok(crate::kernels::list_entries(&words, n, "the reach list")?.to_vec())
    }

    /// Whether a per-vertex irradiance is set ([`SssKernel::set_vertex_irradiance`]).
    pub fn has_vertex_irradiance(&self) -> bool {
        self.env.is_some()
    }

    /// Records the diffusion dispatch alone (barriers from the declared accesses), of the
    /// irradiance last recorded: the grey one (one gather per sample) after the irradiance
    /// pass, the rgb one with a per-vertex irradiance set (one rgba gather; with needed
    /// segments set, `sss needed list` and the diffusion over its list), the rgb one of an
    /// upload (two gathers).
    pub fn record_diffusion(&self, rec: &mut Recorder) -> Result<()> {
        let stage = match (self.irradiance_kind.load(Ordering::Relaxed), &self.env) {
            (IRR_UPLOAD, _) => &self.diffusion_rgb,
            (IRR_ENV, Some(env)) => {
                if let Some(Needed { list, .. }) = &self.needed {
                    // The needed segments listed, then the diffusion over the list.
                    self.needed_list_args(&[])?
                        .record(rec, &list.pipeline, &list.bind)?;
                    let push = self.diffusion_push(&[])?;
                    return rec.dispatch_indirect_tracked(
                        &env.diffusion.pipeline,
                        &env.diffusion.bind,
                        &push,
                        &self.res.needed_list,
                        0,
                    );
                }
                &env.diffusion
            }
            _ => &self.diffusion_grey,
        };
        self.diffusion_args(&[])?
            .record(rec, &stage.pipeline, &stage.bind)
    }

    fn light_bytes(&self, lights: &[Light]) -> Result<Vec<u8>> {
        let data: Vec<[[f32; 4]; 2]> = lights.iter().map(|l| l.gpu()).collect();
        Ok(bytemuck::cast_slice(&data).to_vec())
    }

    fn vertex_light_args(&self, lights: &[Light]) -> Result<Dispatch> {
        let words = self.settings.vertex_light_push(lights.len() as u32);
        let grid = Grid::Invocations([self.settings.room.vertices, 1, 1]);
        Ok(Dispatch::words(&words, grid))
    }

    /// The irradiance pass's arguments; the diffusion that follows it in a frame reads the
    /// grey E it writes.
    fn irradiance_args(&self, lights: &[Light]) -> Result<Dispatch> {
        let tiles = self.res.tile_count();
        let words = self.settings.irradiance_push(lights.len() as u32, tiles);
        let kind = if self.env.is_some() {
            IRR_ENV
        } else {
            IRR_GREY
        };
        self.irradiance_kind.store(kind, Ordering::Relaxed);
        Ok(Dispatch::words(&words, Grid::Groups(tile_groups(tiles))))
    }

    /// The shading pass's push constants over the reach's list (its workgroups: the list's
    /// head).
    fn irradiance_listed_push(&self, lights: &[Light]) -> Result<Vec<u8>> {
        Ok(self.irradiance_args(lights)?.push)
    }

    /// `sss reach boxes`: a lane per triangle.
    fn reach_boxes_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let n = self.settings.room.triangles as u32;
        Ok(Dispatch::words(
            &self.settings.reach_push(),
            Grid::Invocations([n.max(1), 1, 1]),
        ))
    }

    /// `sss reach triangles`: a lane per triangle.
    fn reach_triangles_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let first = match self.reach.as_ref().and_then(|r| r.triangles.as_ref()) {
            Some((_, first)) => *first,
            None => 0,
        };
        let n = self.settings.room.triangles as u32;
        Ok(Dispatch::words(
            &self.settings.reach_triangles_push(first),
            Grid::Invocations([n.max(1), 1, 1]),
        ))
    }

    /// `sss reach list`: one workgroup.
    fn reach_list_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        Ok(Dispatch::words(
            &self.settings.reach_list_push(),
            Grid::Groups([1, 1, 1]),
        ))
    }

    /// The ray pass's push constants: the shading pass's.
    fn irradiance_rays_push(&self, lights: &[Light]) -> Result<Vec<u8>> {
        let words = self
            .settings
            .irradiance_push(lights.len() as u32, self.res.tile_count());
        Ok(bytemuck::cast_slice(&words).to_vec())
    }

    fn posed(&self) -> Result<&Posed> {
        self.posed
            .as_ref()
            .ok_or_else(|| Error::InvalidArgument("the SSS kernel is not posed".into()))
    }

    fn pose_vertices_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let p = self.posed()?;
        let n = self.settings.room.vertices;
        Ok(Dispatch::words(
            &[n, p.mm_per_unit.to_bits()],
            Grid::Invocations([n, 1, 1]),
        ))
    }

    fn pose_triangles_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let n = self.posed()?.triangle_count;
        Ok(Dispatch::words(&[n], Grid::Invocations([n.max(1), 1, 1])))
    }

    fn pose_texels_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let tiles = self.res.tile_count();
        let words = [self.settings.room.size, tiles];
        Ok(Dispatch::words(&words, Grid::Groups(tile_groups(tiles))))
    }

    fn bvh_leaves_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let n = self.posed()?.leaf_count;
        Ok(Dispatch::words(&[], Grid::Invocations([n.max(1), 1, 1])))
    }

    fn vertex_irradiance_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let n = self.settings.room.vertices;
        Ok(Dispatch::words(&[n], Grid::Invocations([n.max(1), 1, 1])))
    }

    fn bvh_refit_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        Ok(Dispatch::words(&[], Grid::Groups([1, 1, 1])))
    }

    fn diffusion_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let tiles = self.res.tile_count();
        let words = self.settings.diffusion_push(tiles);
        Ok(Dispatch::words(&words, Grid::Groups(tile_groups(tiles))))
    }

    /// The diffusion's push constants over the needed list (its workgroups: the list's head).
    fn diffusion_push(&self, lights: &[Light]) -> Result<Vec<u8>> {
        Ok(self.diffusion_args(lights)?.push)
    }

    /// `sss needed list`: one workgroup.
    fn needed_list_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let words = self.settings.needed_list_push();
        Ok(Dispatch::words(&words, Grid::Groups([1, 1, 1])))
    }
}

impl Kernel for SssKernel {
    type Input = [Light];
    type Readback = SssReadback;
    type Output = SssOutput;

    fn name(&self) -> &'static str {
        "sss"
    }

    /// A frame: the lights' upload, per-vertex light, texture-space irradiance (grey E; rgb
    /// with a per-vertex irradiance set), then the diffusion of that E. A posed kernel starts
    /// with the vertex frames, the triangle records and the BVH; its irradiance computes the
    /// texel geometry from them (no `sss pose texels` pass: the texels' positions and normals
    /// are not stored).
    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let transmission = self.settings.params.transmission;
        let mut passes = Vec::with_capacity(16);
        let mut irradiance = &self.irradiance;
        if let Some(p) = &self.posed {
            passes.extend([
                p.vertices
                    .pass(PASS_POSE_VERTICES, Self::pose_vertices_args),
                p.triangles
                    .pass(PASS_POSE_TRIANGLES, Self::pose_triangles_args),
                p.bvh_leaves.pass(PASS_BVH_LEAVES, Self::bvh_leaves_args),
                p.bvh_refit.pass(PASS_BVH_REFIT, Self::bvh_refit_args),
            ]);
            irradiance = &p.irradiance;
        }
        // The reach, before the lights: the needed list, then the reach's passes.
        let reach = match (&self.env, &self.needed, &self.reach) {
            (Some(env), Some(n), Some(r)) => env.listed.as_ref().map(|l| (&n.list, r, l)),
            _ => None,
        };
        if let Some((list, r, _)) = reach {
            passes.extend([
                list.pass(PASS_NEEDED_LIST, Self::needed_list_args),
                r.boxes.pass(PASS_REACH_BOXES, Self::reach_boxes_args),
            ]);
            if let Some((t, _)) = &r.triangles {
                passes.push(t.pass(PASS_REACH_TRIANGLES, Self::reach_triangles_args));
            }
            passes.push(r.list.pass(PASS_REACH_LIST, Self::reach_list_args));
        }
        let mut diffusion = &self.diffusion_grey;
        passes.extend([
            Pass::upload(PASS_LIGHTS, &self.res.lights, Self::light_bytes),
            (self.vertex_light.get(transmission)).pass(PASS_VERTEX, Self::vertex_light_args),
        ]);
        if let Some(env) = &self.env {
            passes.push(
                env.copy
                    .pass(PASS_VERTEX_IRRADIANCE, Self::vertex_irradiance_args),
            );
            irradiance = &env.irradiance;
            diffusion = &env.diffusion;
        }
        passes.extend(irradiance.passes(
            &self.res.ray_head,
            self.settings.params.shadow_refine,
            reach.map(|(_, _, l)| (l, &self.res.reach_list)),
            transmission,
        ));
        match (&self.env, &self.needed) {
            (Some(env), Some(Needed { list, .. })) => {
                if reach.is_none() {
                    passes.push(list.pass(PASS_NEEDED_LIST, Self::needed_list_args));
                }
                passes.push(Pass::dispatch_indirect(
                    PASS_DIFFUSION,
                    &env.diffusion.pipeline,
                    &env.diffusion.bind,
                    IndirectArgs {
                        buffer: &self.res.needed_list,
                        offset: 0,
                    },
                    Self::diffusion_push,
                ));
            }
            _ => passes.push(diffusion.pass(PASS_DIFFUSION, Self::diffusion_args)),
        }
        passes
    }

    fn check_input(&self, lights: &[Light]) -> Result<()> {
        check_lights(lights)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<SssReadback> {
        let mut kind = self.irradiance_kind.load(Ordering::Relaxed);
        let r = &self.res;
        let e = match (kind, &self.env) {
            (IRR_UPLOAD, _) => &r.irradiance_rgb,
            (IRR_ENV, Some(env)) => &env.image,
            _ => {
                kind = IRR_GREY;
                &r.irradiance_grey
            }
        };
        let whole = |image: &Image| ImageRegion::whole(image.desc());
        Ok(SssReadback {
            irradiance_kind: kind,
            irradiance: rec.read_back_image(e, whole(e))?,
            diffuse: rec.read_back(&r.diffuse)?,
            transmission: rec.read_back_image(&r.transmission, whole(&r.transmission))?,
        })
    }

    fn collect(&self, rb: &SssReadback) -> Result<SssOutput> {
        Ok(SssOutput {
            irradiance: match rb.irradiance_kind {
                IRR_GREY => pack::grey_to_rgba(&rb.irradiance.to_vec()?),
                IRR_ENV => pack::rgb_to_rgba(&rb.irradiance.to_vec()?),
                _ => rb.irradiance.to_vec()?,
            },
            diffuse: rb.diffuse.to_vec()?,
            transmission: rb.transmission.to_vec()?,
        })
    }

    fn memory(&self) -> MemoryReport {
        let posed = self.posed.as_ref().map(|p| p.by_binding());
        let env = self.env.as_ref().map(|e| {
            [
                Resource::storage_image(&e.image),
                Resource::storage_image(&e.vertex_texels),
            ]
        });
        let extra = posed
            .iter()
            .flatten()
            .map(|(_, r)| r.clone())
            .chain(env.into_iter().flatten());
        self.ctx.memory_of_resources(
            self.res
                .by_binding()
                .map(|(_, r)| r)
                .into_iter()
                .chain(extra),
        )
    }
}

/// `v`, or one zero texel when it is empty: an image bound to a pass must hold defined data
/// (a plane has no contact entries, but the pass still binds the image).
fn at_least_one<T: bytemuck::Pod>(v: &[T]) -> std::borrow::Cow<'_, [T]> {
    if v.is_empty() {
        std::borrow::Cow::Owned(vec![T::zeroed()])
    } else {
        std::borrow::Cow::Borrowed(v)
    }
}
