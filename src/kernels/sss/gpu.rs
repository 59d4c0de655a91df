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

use super::contact::Contact;
use super::cpu::{
    DiffusionGeometry, Light, MAX_LIGHTS, SamplerParams, check_lights, pattern_totals,
    sample_pattern, shadow_bias, texel_corners_packed, vertex_frames,
};
use super::profile::{Profile, ProfileKind};
use super::texspace::TexGeometry;
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource, Subresources,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

pub const PASS_LIGHTS: &str = "sss lights";
pub const PASS_VERTEX: &str = "sss vertex light";
pub const PASS_IRRADIANCE: &str = "sss irradiance";
pub const PASS_DIFFUSION: &str = "sss diffusion";
/// Most samples per texel (the width of the pattern image; Vulkan guarantees 4096 texels,
/// checked at run time).
pub const MAX_SAMPLES: u32 = 4096;

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
    /// `irradiance` is the `pe` image (xyz, grey E) rather than a caller's rgb upload.
    grey: bool,
    irradiance: Readback,
    diffuse: Readback,
    transmission: Readback,
}

pub struct SssKernel {
    ctx: Context,
    vertex: ComputePipeline,
    vertex_bind: BindGroup,
    vertices: u32,
    irradiance: ComputePipeline,
    irradiance_bind: BindGroup,
    diffusion: ComputePipeline,
    diffusion_bind: BindGroup,
    /// The diffusion of the irradiance pass's grey E: one gather per sample from `pe`.
    diffusion_grey: ComputePipeline,
    diffusion_grey_bind: BindGroup,
    /// Whether the irradiance image last recorded came from the irradiance pass (grey, also
    /// in `pe`: the diffusion uses `diffusion_grey`) rather than [`SssKernel::upload_irradiance`].
    grey: AtomicBool,
    /// Mesh vertices (position, normal) and the BVH (nodes, triangles): storage buffers.
    verts: Buffer,
    /// The BVH as RGBA32UI images of [`BVH_ROW`] texels a row (float bits; nodes 2 texels,
    /// triangles 3): the traversal's loads fetch a texel at once (see `geometry`).
    nodes: Image,
    tris: Image,
    triangles: usize,
    walk_records: usize,
    /// The pattern's weight totals ([`pattern_totals`]), pushed with each diffusion.
    totals: [f32; 3],
    /// The shared sample pattern ([`sample_pattern`]), an RGBA32F image one texel per sample
    /// (lavapipe loads a uniform buffer at a loop index lane by lane: a vec4 from it cost
    /// more than the irradiance gather of a sample).
    seq: Image,
    /// Per texel: position, normal (RGBA32F), triangle corners (RGBA32UI,
    /// [`texel_corners_packed`]) and the diffusion's start ([`start_texels`]), storage images:
    /// lavapipe fetches a texel's four channels at once, while a storage-buffer load at a
    /// per-lane index loops over the lanes for each component, and the passes gather per
    /// sample.
    geometry: [Image; 4],
    /// The surface walk's triangle records ([`super::walk::SurfaceWalk::records`]) and the contact entries
    /// ([`Contact`]), RGBA32UI, [`BVH_ROW`] texels a row.
    walk: Image,
    contact: Image,
    /// Per vertex (vertex v at (v % VERTEX_ROW, v / VERTEX_ROW)): visibility bits (R32UI) and
    /// transmission (RGBA32F).
    vis: Image,
    vtrans: Image,
    lights: Buffer,
    irr: Image,
    /// Grey E per texel (R32F; -1 where no surface), written by the
    /// irradiance pass for the grey diffusion's gathers.
    pe: Image,
    trans: Image,
    diffuse: Buffer,
    /// The occupied tiles ([`occupied_tiles`]), a storage buffer with room for every tile,
    /// and the list on the host (compared on a geometry update).
    tiles: Buffer,
    tile_list: Mutex<Vec<u32>>,
    size: u32,
    bias: f32,
    profile: Profile,
    params: SamplerParams,
}

/// Workgroups (8 x 8 invocations: 8 row segments) per row of the irradiance and diffusion
/// dispatches (the shaders' TILE_ROW).
const TILE_ROW: u32 = 256;

/// The 8 x 1 row segments of the atlas with at least one texel on the surface (covered or
/// gutter), as x / 8 | y << 16: the irradiance and diffusion passes run over these only
/// (about half of a head's atlas is empty; a segment is one 8-lane SIMD step on lavapipe).
fn occupied_tiles(geo: &TexGeometry) -> Vec<u32> {
    let n = geo.size as usize;
    let mut tiles = Vec::new();
    for y in 0..n {
        for tx in 0..n.div_ceil(8) {
            if (tx * 8..(tx * 8 + 8).min(n)).any(|x| geo.pos[y * n + x][3] != 0.0) {
                tiles.push(tx as u32 | (y as u32) << 16);
            }
        }
    }
    tiles
}

/// Workgroups for `tiles` row segments (8 a workgroup, [`TILE_ROW`] workgroups a row; at
/// least one, which returns at once when there are none).
fn tile_groups(tiles: u32) -> [u32; 3] {
    let groups = tiles.div_ceil(8);
    [
        groups.clamp(1, TILE_ROW),
        groups.div_ceil(TILE_ROW).max(1),
        1,
    ]
}

/// Vertices per row of the per-vertex images (the shaders' VERTEX_ROW).
const VERTEX_ROW: u32 = 1024;
/// Texels per row of the BVH images (the shaders' BVH_ROW).
const BVH_ROW: u32 = 1024;

/// An RGBA32UI image of at least `texels` texels, [`BVH_ROW`] a row.
fn bvh_desc(texels: usize) -> ImageDesc {
    let rows = (texels as u32).div_ceil(BVH_ROW).max(1);
    ImageDesc::d2(vk::Format::R32G32B32A32_UINT, [BVH_ROW, rows])
        .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST)
}

/// Records the upload of `data` (16-byte texels, row-major) into the first rows of `image`
/// (zero-padded to whole rows).
fn upload_rows(rec: &mut Recorder, image: &Image, data: &[[f32; 4]]) -> Result<()> {
    let [w, h, _] = image.desc().extent;
    let rows = (data.len() as u32).div_ceil(w).max(1);
    if rows > h {
        return Err(Error::InvalidArgument(format!(
            "{} texels do not fit image '{}' ({w} x {h})",
            data.len(),
            image.name()
        )));
    }
    let mut padded = data.to_vec();
    padded.resize((rows * w) as usize, [0.0; 4]);
    let region = ImageRegion {
        extent: [w, rows, 1],
        ..ImageRegion::whole(image.desc())
    };
    rec.upload_image(image, region, bytemuck::cast_slice(&padded))
}

/// Checks what the shaders index with (TexGeometry's fields are public): a texel on the
/// surface names a triangle of the mesh, a triangle names vertices of the mesh, and the
/// per-texel arrays have size^2 entries.
fn check_geometry(geo: &TexGeometry) -> Result<()> {
    let n = geo.texels();
    if [geo.pos.len(), geo.nrm.len(), geo.texel_tri.len()]
        .iter()
        .any(|&l| l != n)
    {
        return Err(Error::InvalidArgument(format!(
            "texture-space geometry of {}^2 texels has per-texel arrays of other lengths",
            geo.size
        )));
    }
    let triangles = geo.triangles.len() as u32;
    if let Some(i) = (0..n).find(|&i| geo.pos[i][3] != 0.0 && geo.texel_tri[i][0] >= triangles) {
        return Err(Error::InvalidArgument(format!(
            "texel {i} is on the surface but names triangle {} of {triangles}",
            geo.texel_tri[i][0]
        )));
    }
    let vertices = geo.positions.len() as u32;
    if let Some(t) = geo
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v >= vertices))
    {
        return Err(Error::InvalidArgument(format!(
            "triangle {t} names a vertex beyond the mesh's {vertices}"
        )));
    }
    Ok(())
}

/// Per texel, what the diffusion starts from: (triangle, w1 bits, w2 bits, first contact
/// entry << 5 | entry count).
fn start_texels(geo: &TexGeometry, contact: &Contact) -> Result<Vec<[u32; 4]>> {
    if contact.entries.len() >= 1 << 27 {
        return Err(Error::InvalidArgument(format!(
            "{} contact entries: more than the 2^27 the diffusion can index",
            contact.entries.len()
        )));
    }
    Ok(geo
        .texel_tri
        .iter()
        .zip(&contact.range)
        .map(|(t, &[first, count])| [t[0], t[1], t[2], first << 5 | count])
        .collect())
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

impl SssKernel {
    /// Creates buffers, images and pipelines for `geo` and records the uploads into `rec`.
    pub fn new(
        rec: &mut Recorder,
        geo: &TexGeometry,
        profile: &Profile,
        params: SamplerParams,
    ) -> Result<SssKernel> {
        params.check()?;
        check_geometry(geo)?;
        let ctx = rec.context();
        let spv = |name| crate::shaders::spirv(name);
        let vertex =
            ComputePipeline::from_spirv(&ctx, "sss/vertex_light", spv("sss/vertex_light")?)?;
        let irradiance =
            ComputePipeline::from_spirv(&ctx, "sss/irradiance", spv("sss/irradiance")?)?;
        let diffusion = ComputePipeline::from_spirv(&ctx, "sss/diffusion", spv("sss/diffusion")?)?;
        let diffusion_grey =
            ComputePipeline::from_spirv(&ctx, "sss/diffusion_grey", spv("sss/diffusion_grey")?)?;
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let (nodes, tris) = bvh.flat();
        let width_limit = ctx.limits().max_image_dimension_2d;
        if width_limit < MAX_SAMPLES {
            return Err(Error::InvalidArgument(format!(
                "the SSS sampler keeps its pattern in an image {MAX_SAMPLES} texels wide; the \
                 device allows {width_limit} (maxImageDimension2D)"
            )));
        }
        let mut upload = |name: &str, bytes: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        };
        let verts = upload("sss vertices", bytemuck::cast_slice(&vertex_frames(geo)))?;
        // Room for any hierarchy over this many triangles (a rebuilt one may have more
        // nodes): at most 2 n - 1.
        let node_room = (2 * geo.triangles.len()).max(nodes.len());
        let nodes_img = Image::new(&ctx, "sss bvh nodes", bvh_desc(2 * node_room))?;
        let tris_img = Image::new(&ctx, "sss bvh triangles", bvh_desc(3 * tris.len()))?;
        upload_rows(rec, &nodes_img, bytemuck::cast_slice(&nodes))?;
        upload_rows(rec, &tris_img, bytemuck::cast_slice(&tris))?;
        let (nodes, tris) = (nodes_img, tris_img);
        let seq = Image::new(&ctx, "sss sample pattern", rgba32f([MAX_SAMPLES, 1]))?;
        let pattern = sample_pattern(profile, params.samples);
        upload_rows(rec, &seq, &pattern)?;
        // A uniform buffer (the shaders' MAX_LIGHTS x 2 vec4): lavapipe loads it at the
        // light loop's uniform index as a scalar.
        let lights = Buffer::new(
            &ctx,
            "sss lights",
            BufferDesc::uniform(MAX_LIGHTS as u64 * 32),
        )?;
        let texels = geo.texels() as u64;
        let sz = [geo.size, geo.size];
        let corners_desc = ImageDesc::d2(vk::Format::R32G32B32A32_UINT, sz)
            .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST);
        let geometry = [
            Image::new(&ctx, "sss position", rgba32f(sz))?,
            Image::new(&ctx, "sss normal", rgba32f(sz))?,
            Image::new(&ctx, "sss texel corners", corners_desc)?,
            Image::new(&ctx, "sss diffusion start", corners_desc)?,
        ];
        let dg = DiffusionGeometry::build(geo, profile);
        let records = dg.walk.records();
        let walk = Image::new(&ctx, "sss walk", bvh_desc(records.len()))?;
        // Room for the contact entries of other poses of the mesh.
        let contact_room = (2 * dg.contact.entries.len()).max(4096);
        let contact = Image::new(&ctx, "sss contact", bvh_desc(contact_room))?;
        let nv = geo.positions.len() as u32;
        let vsz = [VERTEX_ROW, nv.div_ceil(VERTEX_ROW).max(1)];
        let vis_desc = ImageDesc::d2(vk::Format::R32_UINT, vsz).usage(vk::ImageUsageFlags::STORAGE);
        let vis = Image::new(&ctx, "sss vertex visibility", vis_desc)?;
        let vtrans = Image::new(&ctx, "sss vertex transmission", rgba32f(vsz))?;
        let irr = Image::new(&ctx, "sss irradiance", rgba32f(sz))?;
        let trans = Image::new(&ctx, "sss transmission", rgba32f(sz))?;
        let pe = Image::new(&ctx, "sss grey E", float_image(vk::Format::R32_SFLOAT, sz))?;
        let diffuse = Buffer::new(&ctx, "sss diffuse", BufferDesc::storage(texels * 16))?;
        let all_tiles = (geo.size as u64).div_ceil(8) * geo.size as u64;
        let tiles = Buffer::new(&ctx, "sss tiles", BufferDesc::storage(all_tiles * 4))?;
        let w = AccessSet::from(A::ComputeShaderWrite);
        let vertex_bind = vertex.bind_declared(
            &[
                ("verts", Resource::Buffer(&verts)),
                ("nodes", Resource::storage_image(&nodes)),
                ("tris", Resource::storage_image(&tris)),
                ("lights", Resource::Buffer(&lights)),
                ("vis", Resource::storage_image(&vis)),
                ("vtrans", Resource::storage_image(&vtrans)),
            ],
            &[("vis", w), ("vtrans", w)],
        )?;
        let [g_pos, g_nrm, g_corners, g_start] = &geometry;
        let irradiance_bind = irradiance.bind_declared(
            &[
                ("pos", Resource::storage_image(g_pos)),
                ("nrm", Resource::storage_image(g_nrm)),
                ("corners", Resource::storage_image(g_corners)),
                ("lights", Resource::Buffer(&lights)),
                ("vis", Resource::storage_image(&vis)),
                ("vtrans", Resource::storage_image(&vtrans)),
                ("trans", Resource::storage_image(&trans)),
                ("nodes", Resource::storage_image(&nodes)),
                ("tris", Resource::storage_image(&tris)),
                ("pe", Resource::storage_image(&pe)),
                ("tiles", Resource::Buffer(&tiles)),
            ],
            &[("trans", w), ("pe", w)],
        )?;
        let diffusion_bind = diffusion.bind_declared(
            &[
                ("pos", Resource::storage_image(g_pos)),
                ("start", Resource::storage_image(g_start)),
                ("walk", Resource::storage_image(&walk)),
                ("contact", Resource::storage_image(&contact)),
                ("irr", Resource::storage_image(&irr)),
                ("seq", Resource::storage_image(&seq)),
                ("diffuse", Resource::Buffer(&diffuse)),
                ("tiles", Resource::Buffer(&tiles)),
            ],
            &[("diffuse", w)],
        )?;
        let diffusion_grey_bind = diffusion_grey.bind_declared(
            &[
                ("pe", Resource::storage_image(&pe)),
                ("start", Resource::storage_image(g_start)),
                ("walk", Resource::storage_image(&walk)),
                ("contact", Resource::storage_image(&contact)),
                ("seq", Resource::storage_image(&seq)),
                ("diffuse", Resource::Buffer(&diffuse)),
                ("tiles", Resource::Buffer(&tiles)),
            ],
            &[("diffuse", w)],
        )?;
        let kernel = SssKernel {
            ctx,
            vertex,
            vertex_bind,
            vertices: nv,
            irradiance,
            irradiance_bind,
            diffusion,
            diffusion_bind,
            diffusion_grey,
            diffusion_grey_bind,
            // The frame path (irradiance pass, then the grey diffusion) until a caller uploads
            // an irradiance: so that `passes` and `plan_pass` describe it before the first
            // frame is recorded, and a graph planned then has the barrier for `pe`.
            grey: AtomicBool::new(true),
            verts,
            nodes,
            tris,
            triangles: geo.triangles.len(),
            seq,
            geometry,
            walk,
            contact,
            walk_records: records.len(),
            totals: pattern_totals(&pattern),
            vis,
            vtrans,
            lights,
            irr,
            pe,
            trans,
            diffuse,
            tiles,
            tile_list: Mutex::new(Vec::new()),
            size: geo.size,
            bias: shadow_bias(geo.extent_mm()),
            profile: profile.clone(),
            params,
        };
        kernel.upload_texels(rec, geo, &dg)?;
        kernel.set_tiles(rec, occupied_tiles(geo))?;
        Ok(kernel)
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// Records the clearing of the transmission image (the irradiance pass leaves it alone
    /// while transmission is off, and in empty tiles).
    fn clear_transmission(&self, rec: &mut Recorder) -> Result<()> {
        rec.clear_image(
            &self.trans,
            Subresources::mip(self.trans.desc(), 0),
            [0.0; 4],
        )
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
            rec.upload(&self.tiles, 0, &list)?;
        }
        let pe = Subresources::mip(self.pe.desc(), 0);
        rec.clear_image(&self.pe, pe, [-1.0, 0.0, 0.0, 0.0])?;
        rec.fill_buffer(&self.diffuse, 0)?;
        self.clear_transmission(rec)?;
        *current = list;
        Ok(())
    }

    /// The number of occupied tiles.
    fn tile_count(&self) -> u32 {
        self.tile_list.lock().map(|l| l.len() as u32).unwrap_or(0)
    }

    /// Records the upload of the per-texel geometry images, the walk and the contact entries.
    fn upload_texels(
        &self,
        rec: &mut Recorder,
        geo: &TexGeometry,
        dg: &DiffusionGeometry,
    ) -> Result<()> {
        // (the geometry was checked by the caller, before anything was built from it)
        let records = dg.walk.records();
        if records.len() != self.walk_records {
            return Err(Error::InvalidArgument(format!(
                "the surface walk of the new geometry has {} records, the kernel's {} (a \
                 different mesh?)",
                records.len(),
                self.walk_records
            )));
        }
        let room = self.contact.desc().extent[0] as usize * self.contact.desc().extent[1] as usize;
        if dg.contact.entries.len() > room {
            return Err(Error::InvalidArgument(format!(
                "this pose has {} contact entries (pieces of the mesh within reach of each \
                 other), more than the {room} the kernel made room for at its first pose",
                dg.contact.entries.len()
            )));
        }
        let corners = texel_corners_packed(geo);
        let start = start_texels(geo, &dg.contact)?;
        let data: [&[u8]; 4] = [
            bytemuck::cast_slice(&geo.pos),
            bytemuck::cast_slice(&geo.nrm),
            bytemuck::cast_slice(&corners),
            bytemuck::cast_slice(&start),
        ];
        for (img, bytes) in self.geometry.iter().zip(data) {
            rec.upload_image(img, ImageRegion::whole(img.desc()), bytes)?;
        }
        upload_rows(rec, &self.walk, bytemuck::cast_slice(&records))?;
        let entries: Vec<[u32; 4]> = dg
            .contact
            .entries
            .iter()
            .map(|(j, f)| [*j, f[0].to_bits(), f[1].to_bits(), f[2].to_bits()])
            .collect();
        if !entries.is_empty() {
            upload_rows(rec, &self.contact, bytemuck::cast_slice(&entries))?;
        }
        Ok(())
    }

    /// Records the upload of a new pose of the same mesh (same texture size, same triangles
    /// and UV layout; e.g. the skinned mesh of the next frame re-rasterised): the texel
    /// geometry, the vertices and a rebuilt BVH.
    pub fn update_geometry(&self, rec: &mut Recorder, geo: &TexGeometry) -> Result<()> {
        if geo.size != self.size
            || self.triangles != geo.triangles.len()
            || geo.positions.len() != self.vertices as usize
        {
            return Err(Error::InvalidArgument(format!(
                "new geometry ({}^2, {} triangles, {} vertices) does not match the kernel's \
                 ({}^2, {} triangles, {} vertices)",
                geo.size,
                geo.triangles.len(),
                geo.positions.len(),
                self.size,
                self.triangles,
                self.vertices
            )));
        }
        check_geometry(geo)?;
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let (n, t) = bvh.flat();
        let room = self.nodes.desc().extent[0] as usize * self.nodes.desc().extent[1] as usize;
        if 2 * n.len() > room {
            return Err(Error::InvalidArgument("BVH larger than its image".into()));
        }
        self.upload_texels(rec, geo, &DiffusionGeometry::build(geo, &self.profile))?;
        self.set_tiles(rec, occupied_tiles(geo))?;
        rec.upload(&self.verts, 0, &vertex_frames(geo))?;
        upload_rows(rec, &self.nodes, bytemuck::cast_slice(&n))?;
        upload_rows(rec, &self.tris, bytemuck::cast_slice(&t))
    }

    pub fn params(&self) -> &SamplerParams {
        &self.params
    }

    /// Changes the sampler settings: records the upload of the new sample sequence.
    pub fn set_params(&mut self, rec: &mut Recorder, params: SamplerParams) -> Result<()> {
        params.check()?;
        let pattern = sample_pattern(&self.profile, params.samples);
        upload_rows(rec, &self.seq, &pattern)?;
        self.totals = pattern_totals(&pattern);
        if self.params.transmission && !params.transmission {
            self.clear_transmission(rec)?;
        }
        self.params = params;
        Ok(())
    }

    /// The irradiance image of [`SssKernel::upload_irradiance`] (RGBA32F, rgb E). The
    /// irradiance pass writes [`SssKernel::grey_irradiance`] instead.
    pub fn irradiance(&self) -> &Image {
        &self.irr
    }

    /// The grey irradiance per texel (R32F: E of the white lights, -1 where no surface),
    /// written by `sss irradiance`.
    pub fn grey_irradiance(&self) -> &Image {
        &self.pe
    }

    /// The diffuse buffer, written by `sss diffusion`.
    pub fn diffuse(&self) -> &Buffer {
        &self.diffuse
    }

    /// Records the upload of a caller's irradiance (rgba per texel; alpha ignored) in place of
    /// the irradiance pass.
    pub fn upload_irradiance(&self, rec: &mut Recorder, e: &[[f32; 4]]) -> Result<()> {
        if e.len() != (self.size * self.size) as usize {
            return Err(Error::InvalidArgument(format!(
                "{} irradiance texels for a {}^2 texture",
                e.len(),
                self.size
            )));
        }
        if let Some(i) = e.iter().position(|t| t.iter().any(|x| !x.is_finite())) {
            return Err(Error::InvalidArgument(format!(
                "irradiance texel {i} is not finite"
            )));
        }
        rec.upload_image(
            &self.irr,
            ImageRegion::whole(self.irr.desc()),
            bytemuck::cast_slice(e),
        )?;
        self.grey.store(false, Ordering::Relaxed);
        Ok(())
    }

    /// The transmission image (rgb, alpha thickness), written by `sss irradiance`.
    pub fn transmission(&self) -> &Image {
        &self.trans
    }

    fn light_bytes(&self, lights: &[Light]) -> Result<Vec<u8>> {
        let data: Vec<[[f32; 4]; 2]> = lights.iter().map(|l| l.gpu()).collect();
        Ok(bytemuck::cast_slice(&data).to_vec())
    }

    fn vertex_light_args(&self, lights: &[Light]) -> Result<Dispatch> {
        let lights = lights.len();
        let p = &self.profile;
        let mode = match (self.params.transmission, p.kind) {
            (false, _) => 0u32,
            (true, ProfileKind::Dipole) => 1,
            (true, ProfileKind::Burley) => 2,
        };
        let mut words: Vec<u32> = (0..3)
            .flat_map(|c| p.tail_gpu(c).map(f32::to_bits))
            .collect();
        words.extend([
            self.vertices,
            lights as u32,
            self.bias.to_bits(),
            mode,
            (p.max_radius() as f32).to_bits(),
        ]);
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.vertices, 1, 1]),
        ))
    }

    /// The irradiance pass's arguments; the diffusion that follows it in a frame reads the
    /// grey E it writes.
    fn irradiance_args(&self, lights: &[Light]) -> Result<Dispatch> {
        let lights = lights.len();
        let words = [
            self.size,
            lights as u32,
            self.params.transmission as u32,
            self.params.shadow_refine as u32,
            self.bias.to_bits(),
            self.tile_count(),
        ];
        self.grey.store(true, Ordering::Relaxed);
        Ok(Dispatch::words(
            &words,
            Grid::Groups(tile_groups(self.tile_count())),
        ))
    }

    /// The diffusion pipeline and bindings for the irradiance last recorded: the grey one
    /// (one gather per sample) after the irradiance pass, the rgb one after an upload.
    fn diffusion_pipeline(&self) -> (&ComputePipeline, &BindGroup) {
        if self.grey.load(Ordering::Relaxed) {
            (&self.diffusion_grey, &self.diffusion_grey_bind)
        } else {
            (&self.diffusion, &self.diffusion_bind)
        }
    }

    /// Records the diffusion dispatch alone (barriers from the declared accesses).
    pub fn record_diffusion(&self, rec: &mut Recorder) -> Result<()> {
        let (pipeline, bind) = self.diffusion_pipeline();
        self.diffusion_args(&[])?.record(rec, pipeline, bind)
    }

    fn diffusion_args(&self, _lights: &[Light]) -> Result<Dispatch> {
        let k = self.profile.r_tot.map(|k| k as f32);
        let total = self.totals;
        let mut push: Vec<u8> = [k[0], k[1], k[2], 0.0, total[0], total[1], total[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        for u in [self.size, self.params.samples, self.tile_count()] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        Ok(Dispatch {
            push,
            grid: Grid::Groups(tile_groups(self.tile_count())),
        })
    }
}

impl Kernel for SssKernel {
    type Input = [Light];
    type Readback = SssReadback;
    type Output = SssOutput;

    fn name(&self) -> &'static str {
        "sss"
    }

    /// A frame: the lights' upload, per-vertex light, texture-space irradiance (grey E),
    /// then the diffusion of that grey E.
    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::upload(PASS_LIGHTS, &self.lights, Self::light_bytes),
            Pass::dispatch(
                PASS_VERTEX,
                &self.vertex,
                &self.vertex_bind,
                Self::vertex_light_args,
            ),
            Pass::dispatch(
                PASS_IRRADIANCE,
                &self.irradiance,
                &self.irradiance_bind,
                Self::irradiance_args,
            ),
            Pass::dispatch(
                PASS_DIFFUSION,
                &self.diffusion_grey,
                &self.diffusion_grey_bind,
                Self::diffusion_args,
            ),
        ]
    }

    fn check_input(&self, lights: &[Light]) -> Result<()> {
        check_lights(lights)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<SssReadback> {
        let grey = self.grey.load(Ordering::Relaxed);
        let e = if grey { &self.pe } else { &self.irr };
        Ok(SssReadback {
            grey,
            irradiance: rec.read_back_image(e, ImageRegion::whole(e.desc()))?,
            diffuse: rec.read_back(&self.diffuse)?,
            transmission: rec
                .read_back_image(&self.trans, ImageRegion::whole(self.trans.desc()))?,
        })
    }

    fn collect(&self, rb: &SssReadback) -> Result<SssOutput> {
        let irradiance: Vec<[f32; 4]> = if rb.grey {
            // E -> (E, E, E, 1); -1 marks no surface.
            let grey: Vec<f32> = rb.irradiance.to_vec()?;
            grey.iter()
                .map(|&e| if e < 0.0 { [0.0; 4] } else { [e, e, e, 1.0] })
                .collect()
        } else {
            rb.irradiance.to_vec()?
        };
        Ok(SssOutput {
            irradiance,
            diffuse: rb.diffuse.to_vec()?,
            transmission: rb.transmission.to_vec()?,
        })
    }

    fn memory(&self) -> MemoryReport {
        let buffers = self
            .ctx
            .memory_of(&[&self.verts, &self.lights, &self.diffuse, &self.tiles]);
        let images: Vec<&Image> = self
            .geometry
            .iter()
            .chain([
                &self.vis,
                &self.vtrans,
                &self.irr,
                &self.pe,
                &self.trans,
                &self.nodes,
                &self.tris,
                &self.walk,
                &self.contact,
                &self.seq,
            ])
            .collect();
        MemoryReport {
            used_bytes: buffers.used_bytes
                + images.iter().map(|i| i.allocation_size()).sum::<u64>(),
            allocations: buffers.allocations + images.len() as u64,
            ..buffers
        }
    }
}

#[cfg(test)]
mod shader_constants {
    use super::*;
    use crate::kernels::sss::walk;

    /// The diffusion shader's layout constants are the ones the host writes with.
    #[test]
    fn diffusion_shader_agrees_with_the_host() {
        let src = include_str!("../../../glsl/common/sss_diffusion.glsl");
        for (name, value) in [
            ("WALK_RECORD", walk::RECORD_TEXELS as u32),
            ("WALK_ROW", BVH_ROW),
            ("TILE_ROW", TILE_ROW),
            ("EDGE_SHARED", walk::EDGE_SHARED),
            ("EDGE_OPEN", walk::EDGE_OPEN),
        ] {
            let line = format!("const uint {name} = {value}u;");
            assert!(
                src.contains(&line),
                "glsl/common/sss_diffusion.glsl lacks `{line}`"
            );
        }
    }
}
