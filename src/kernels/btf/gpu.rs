//! The BTF kernel on the GPU: the 6561 images packed into 2D array textures sized to the
//! device's limits, the parabolic index/weight maps, a G-buffer, and one pass `btf shade`
//! writing linear RGB per pixel. The packing is done on the CPU ([`super::pack`]); this is
//! the glue that creates the textures from it and records the pass.

pub use super::pack::{
    BC1_FORMAT, BLOCK_FORMAT, BtfInputs, FORMAT, GPU_CPU_BOUND_BLOCK, Layout, MAX_ARRAYS, Packing,
    Prepared, Sampled, Texture, encode_bc1, encode_blocks, map_texels, pack, sampled_texels,
};

use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource, Sampler, SamplerDesc,
};
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};
use crate::scene::gbuffer::{Frame, MAX_LIGHTS};
use ash::vk;

pub const PASS_SHADE: &str = "btf shade";
/// Over a tile list ([`BtfKernel::on_gbuffer_tiles`]): the reset of the pixel list, then its
/// filling from the tiles (the masked parts' pixels; glsl/btf/pixels.comp), which `btf shade`
/// and `btf env basis` run over.
pub const PASS_PIXEL_LIST: &str = "btf pixel list";
pub const PASS_PIXELS: &str = "btf pixels";
/// The environment pass ([`BtfKernel::on_gbuffer_env`]), recorded after [`PASS_SHADE`].
pub const PASS_ENV: &str = "btf env";

/// The environment pass through the light basis ([`BtfKernel::add_env_basis`]), recorded
/// after [`PASS_SHADE`] (and [`PASS_ENV`] if both are built).
pub const PASS_ENV_BASIS: &str = "btf env basis";

/// The per-vertex light pass of [`BasisVisibility::PerVertexLight`], recorded before
/// [`PASS_ENV_BASIS`].
pub const PASS_ENV_VERTICES: &str = "btf env vertices";

/// RGBA32F texels per vertex of the per-vertex light image
/// ([`BasisVisibility::PerVertexLight`]; glsl/btf/basis_light.glsl has the layout): the front
/// face's 24 light factors, the back face's, the unit normal.
pub const LIGHT_TEXELS: u32 = 13;

/// Vertices a row of the per-vertex light image holds (the row is
/// `LIGHT_TEXELS * LIGHT_VERTICES` texels wide).
pub const LIGHT_VERTICES: u32 = 256;

/// Host copy of one frame: linear RGBA per pixel (alpha 0 where the G-buffer is empty).
pub type BtfOutput = Vec<[f32; 4]>;

/// The GPU kernel.
pub struct BtfKernel {
    ctx: Context,
    pipeline: ComputePipeline,
    bind: BindGroup,
    arrays: Vec<Image>,
    packing: Packing,
    _sampler: Option<Sampler>,
    map: Image,
    /// The G-buffer when the kernel owns it (uploaded from the CPU); a GPU-written one is
    /// kept alive by the bind group.
    gbuffer: Option<Image>,
    result: Buffer,
    /// Over the rasteriser's tile list ([`BtfKernel::on_gbuffer_tiles`]): the masked parts'
    /// pixels, listed from the tiles each frame.
    pixels: Option<PixelList>,
    size: [u32; 2],
    /// Bit p: `btf shade` shades part p of the G-buffer (all ones: every part).
    part_mask: u32,
    /// The environment pass, when built with [`BtfKernel::on_gbuffer_env`].
    env: Option<EnvPass>,
    /// The light-basis environment pass ([`BtfKernel::add_env_basis`]).
    env_basis: Option<EnvBasisPass>,
}

impl BtfKernel {
    /// Packs `inputs` for this device ([`Prepared::new`]), creates the textures, buffers
    /// and pipeline and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &BtfInputs<'_>) -> Result<BtfKernel> {
        let ctx = rec.context();
        let l = ctx.limits();
        let prep = Prepared::new(inputs, l.max_image_dimension_2d, l.max_image_array_layers)?;
        Self::from_prepared(rec, &prep)
    }

    /// Creates the textures, buffers and pipeline for `prep` and records the uploads into
    /// `rec` (they run when the caller submits it).
    pub fn from_prepared(rec: &mut Recorder, prep: &Prepared) -> Result<BtfKernel> {
        let Some(layers) = &prep.gbuffer else {
            return Err(Error::InvalidArgument(
                "BTF prepared for a GPU G-buffer: create it with BtfKernel::on_gbuffer".into(),
            ));
        };
        let [w, h] = prep.size;
        let gb_desc = ImageDesc::d2_array(vk::Format::R32G32B32A32_SFLOAT, [w, h], 3);
        let gbuffer = image_with(rec, "btf gbuffer", gb_desc, layers)?;
        let mut k = Self::with_gbuffer(rec, prep, &gbuffer, None, None)?;
        k.gbuffer = Some(gbuffer);
        Ok(k)
    }

    /// As [`BtfKernel::from_prepared`], shading `gbuffer` (RGBA32F, three layers of
    /// `prep`'s size, sampled usage), which another kernel writes on the GPU (the
    /// rasteriser's [`crate::kernels::raster::gpu::RasterKernel::gbuffer`]): the pass
    /// declares a sampled read of it, so the tracker orders it after that write.
    pub fn on_gbuffer(rec: &mut Recorder, prep: &Prepared, gbuffer: &Image) -> Result<BtfKernel> {
        Self::check_gbuffer(prep, gbuffer)?;
        Self::with_gbuffer(rec, prep, gbuffer, None, None)
    }

    /// As [`BtfKernel::on_gbuffer`], shading only the tiles of the rasteriser's tile list
    /// `tiles` ([`crate::kernels::raster::gpu::RasterKernel::tiles`]: this frame's covered
    /// tiles and last frame's), which a pass of the same frame writes before this one. Pass
    /// `btf pixels` (one workgroup a tile, dispatched indirectly) lists the tiles' covered
    /// pixels and gives their empty ones the background; `btf shade` (and `btf env basis`)
    /// then run over that list, dispatched indirectly: on lavapipe a lane that returns early
    /// still runs the rest of a shader, so the tiles' empty pixels cost as much as shaded
    /// ones. Every pixel outside the tiles keeps the background (0) it is cleared to here
    /// (recorded into `rec`), so the output equals [`BtfKernel::on_gbuffer`]'s as long as
    /// the passes run after every frame of the rasteriser that wrote the list.
    pub fn on_gbuffer_tiles(
        rec: &mut Recorder,
        prep: &Prepared,
        gbuffer: &Image,
        tiles: &Buffer,
    ) -> Result<BtfKernel> {
        Self::check_gbuffer(prep, gbuffer)?;
        Self::check_tiles(prep, tiles)?;
        let k = Self::with_gbuffer(rec, prep, gbuffer, Some(tiles.clone()), None)?;
        rec.fill_buffer(&k.result, 0)?;
        Ok(k)
    }

    /// [`BtfKernel::on_gbuffer_tiles`] for the parts in `part_mask` only (bit p: part p of
    /// the G-buffer's tags), written into `result`, a buffer the caller owns and shares:
    /// several kernels, one BTF each, shade their own parts of one image. `btf shade` writes
    /// the masked parts' pixels and zero where the G-buffer is empty, and leaves the other
    /// parts' pixels as they are; each kernel's passes declare their writes of `result`, so
    /// a graph orders them. `result` must hold a vec4 per pixel (storage usage); the caller
    /// clears it once.
    pub fn on_gbuffer_tiles_into(
        rec: &mut Recorder,
        prep: &Prepared,
        gbuffer: &Image,
        tiles: &Buffer,
        result: &Buffer,
        part_mask: u32,
    ) -> Result<BtfKernel> {
        Self::check_gbuffer(prep, gbuffer)?;
        Self::check_tiles(prep, tiles)?;
        let need = prep.size[0] as u64 * prep.size[1] as u64 * 16;
        if result.size() < need
            || !result
                .usage()
                .contains(vk::BufferUsageFlags::STORAGE_BUFFER)
        {
            return Err(Error::InvalidArgument(format!(
                "BTF result '{}' ({} bytes, usage {:?}): a {} x {} image needs {need} bytes with \
                 STORAGE_BUFFER usage",
                result.name(),
                result.size(),
                result.usage(),
                prep.size[0],
                prep.size[1]
            )));
        }
        if part_mask == 0 {
            return Err(Error::InvalidArgument(
                "a BTF kernel over no part (part mask 0)".into(),
            ));
        }
        let mut k = Self::with_gbuffer(rec, prep, gbuffer, Some(tiles.clone()), Some(result))?;
        k.part_mask = part_mask;
        Ok(k)
    }

    fn check_tiles(prep: &Prepared, tiles: &Buffer) -> Result<()> {
        if prep.size.iter().any(|&s| s > 1 << 16) {
            return Err(Error::InvalidArgument(format!(
                "a {} x {} image over a tile list: the pixel list holds x | y << 16, so at most \
                 65536 pixels a side",
                prep.size[0], prep.size[1]
            )));
        }
        let [tx, ty] = crate::kernels::raster::pack::tile_grid(prep.size);
        let need = 16 + 4 * tx as u64 * ty as u64;
        if tiles.size() < need
            || !tiles
                .usage()
                .contains(vk::BufferUsageFlags::INDIRECT_BUFFER)
        {
            return Err(Error::InvalidArgument(format!(
                "tile list '{}' ({} bytes, usage {:?}): a {} x {} image needs {need} bytes with \
                 INDIRECT_BUFFER usage",
                tiles.name(),
                tiles.size(),
                tiles.usage(),
                prep.size[0],
                prep.size[1]
            )));
        }
        Ok(())
    }

    fn check_gbuffer(prep: &Prepared, gbuffer: &Image) -> Result<()> {
        let d = gbuffer.desc();
        let [w, h] = prep.size;
        if d.format != vk::Format::R32G32B32A32_SFLOAT
            || d.extent != [w, h, 1]
            || d.layers != 3
            || !d.usage.contains(vk::ImageUsageFlags::SAMPLED)
        {
            return Err(Error::InvalidArgument(format!(
                "G-buffer image '{}' is {:?} {:?} x {} layers (usage {:?}); the BTF pass reads \
                 sampled RGBA32F {w} x {h} x 3",
                gbuffer.name(),
                d.format,
                d.extent,
                d.layers,
                d.usage
            )));
        }
        Ok(())
    }

    fn with_gbuffer(
        rec: &mut Recorder,
        prep: &Prepared,
        gbuffer: &Image,
        tiles: Option<Buffer>,
        shared_result: Option<&Buffer>,
    ) -> Result<BtfKernel> {
        let ctx = rec.context();
        let packing = prep.packing;
        // One module per layout (not a specialization constant: lavapipe 22.3.6 ignored the
        // constant's value in this shader; and a runtime branch keeps all five sampling call
        // sites, which lavapipe inlines each: 3x slower); `_pixels`: over the pixel list
        // that pass `btf pixels` fills from a tile list.
        let name = match (packing.layout, packing.texture, tiles.is_some()) {
            (_, Texture::Block, false) => "btf/shade_block",
            (Layout::Rows, _, false) => "btf/shade_rows",
            (Layout::Layers, _, false) => "btf/shade_layers",
            (_, Texture::Block, true) => "btf/shade_block_pixels",
            (Layout::Rows, _, true) => "btf/shade_rows_pixels",
            (Layout::Layers, _, true) => "btf/shade_layers_pixels",
        };
        let pipeline = crate::shaders::pipeline(&ctx, name)?;
        let arrays = Self::arrays_of(rec, prep)?;
        let res = prep.map_res;
        let map_desc = ImageDesc::d2(vk::Format::R32G32B32A32_UINT, [res, res]);
        let map = image_with(rec, "btf direction map", map_desc, &prep.map)?;
        let [w, h] = prep.size;
        let result = match shared_result {
            Some(r) => r.clone(),
            None => Buffer::new(
                &ctx,
                "btf result",
                BufferDesc::storage(w as u64 * h as u64 * 16),
            )?,
        };
        let pixels = match tiles {
            Some(t) => Some(PixelList::new(&ctx, prep.size, gbuffer, &result, t)?),
            None => None,
        };
        let images = (&map, gbuffer, &result, pixels.as_ref());
        let (bind, _sampler) = Self::bind(&ctx, &pipeline, packing.texture, &arrays, images)?;
        Ok(BtfKernel {
            ctx,
            pipeline,
            bind,
            arrays,
            packing,
            _sampler,
            map,
            gbuffer: None,
            result,
            pixels,
            size: prep.size,
            part_mask: u32::MAX,
            env: None,
            env_basis: None,
        })
    }

    /// The array textures the shader binds, their layers' uploads recorded; bindings past
    /// the packing's arrays get a 1 x 1 black placeholder (never read).
    fn arrays_of(rec: &mut Recorder, prep: &Prepared) -> Result<Vec<Image>> {
        let (p, format) = (prep.packing, prep.packing.texture.format());
        (0..p.texture.bound_arrays())
            .map(|a| {
                if a < p.arrays {
                    let desc = ImageDesc::d2_array(format, p.layer_extent, p.layers(a));
                    image_with(rec, &format!("btf array {a}"), desc, prep.array_bytes(a))
                } else {
                    let desc = ImageDesc::d2_array(format, [1, 1], 1);
                    let name = format!("btf array {a} (unused)");
                    image_with(rec, &name, desc, p.texture.black())
                }
            })
            .collect()
    }

    /// The bind group of `btf shade` (and the tile sampler of the sampled formats) over the
    /// arrays, then the direction map, G-buffer, result and pixel list.
    fn bind(
        ctx: &Context,
        pipeline: &ComputePipeline,
        texture: Texture,
        arrays: &[Image],
        (map, gbuffer, result, pixels): (&Image, &Image, &Buffer, Option<&PixelList>),
    ) -> Result<(BindGroup, Option<Sampler>)> {
        let mut common = vec![
            ("dir_map", Resource::texture(map)),
            ("gbuffer", Resource::texture(gbuffer)),
            ("result", Resource::Buffer(result)),
        ];
        if let Some(p) = pixels {
            common.push(("pixel_head", Resource::Buffer(&p.head)));
            common.push(("pixels", Resource::Buffer(&p.list)));
        }
        let writes = [("result", AccessSet::from(A::ComputeShaderWrite))];
        if texture == Texture::Block {
            let mut res = vec![("btf_blocks", Resource::texture(&arrays[0]))];
            res.extend(common);
            return Ok((pipeline.bind_declared(&res, &writes)?, None));
        }
        let sampler = Sampler::new(
            ctx,
            "btf tile sampler",
            SamplerDesc::linear()
                .address(vk::SamplerAddressMode::REPEAT)
                .lod(0.0, 0.0),
        )?;
        let mut res = vec![
            (
                "btf",
                Resource::Array(arrays.iter().map(Resource::texture).collect()),
            ),
            ("tile_sampler", Resource::Sampler(&sampler)),
        ];
        res.extend(common);
        let bind = pipeline.bind_declared(&res, &writes)?;
        Ok((bind, Some(sampler)))
    }

    /// The packing chosen for this device.
    pub fn packing(&self) -> Packing {
        self.packing
    }

    /// The shaded radiance, vec4 per pixel (alpha 0 where the G-buffer is empty), written by
    /// `btf shade`: a later pass (the character frame's compose) reads it.
    pub fn result(&self) -> &Buffer {
        &self.result
    }

    /// The array textures holding the BTF (the first `packing().arrays`).
    pub fn arrays(&self) -> &[Image] {
        &self.arrays[..self.packing.arrays as usize]
    }

    /// The texel format the BTF is stored in.
    pub fn texture(&self) -> Texture {
        self.packing.texture
    }

    /// Device bytes of the packed BTF textures alone.
    pub fn texture_bytes(&self) -> u64 {
        self.arrays().iter().map(|i| i.allocation_size()).sum()
    }

    /// Device bytes of the two maps.
    pub fn map_bytes(&self) -> u64 {
        self.map.allocation_size()
    }

    /// Output width and height.
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    /// Pass `btf pixels`' push constants: width, height, part mask.
    fn pixels_push(&self) -> Vec<u8> {
        let words = [self.size[0], self.size[1], self.part_mask, 0];
        bytemuck::cast_slice(&words).to_vec()
    }

    fn push(&self, frame: &Frame) -> Result<Vec<u8>> {
        frame.check()?;
        let mut f = Vec::with_capacity(24);
        let cam = frame.camera.push();
        f.extend_from_slice(&cam);
        let mut dirs = [[0f32; 4]; MAX_LIGHTS];
        let mut rgb = [[0f32; 4]; MAX_LIGHTS];
        for (i, l) in frame.lights.iter().enumerate() {
            let d = l.direction.normalize();
            dirs[i] = [d.x, d.y, d.z, 0.0];
            rgb[i] = [l.rgb[0], l.rgb[1], l.rgb[2], 0.0];
        }
        f.extend(dirs.iter().flatten());
        f.extend(rgb.iter().flatten());
        let mut push: Vec<u8> = f.iter().flat_map(|x| x.to_le_bytes()).collect();
        let p = &self.packing;
        for u in [
            self.size[0],
            self.size[1],
            frame.lights.len() as u32,
            p.layers_per_array,
            p.gutter,
            p.tile[0],
            p.layer_extent[0],
            p.tile[1],
            self.part_mask,
            0,
            0,
            0,
        ] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        Ok(push)
    }
}

/// The pixels `btf shade` and `btf env basis` run over when the kernel shades a tile list,
/// filled each frame by pass `btf pixels` (glsl/btf/pixels.comp).
struct PixelList {
    /// The rasteriser's tile list the pixels are listed from.
    tiles: Buffer,
    /// (ceil(count / 64), 1, 1, count): the shading passes' indirect command.
    head: Buffer,
    /// The pixels (x | y << 16: the shading passes find a pixel without dividing by the
    /// width), room for every pixel.
    list: Buffer,
    pipeline: ComputePipeline,
    bind: BindGroup,
}

impl PixelList {
    fn new(
        ctx: &Context,
        [w, h]: [u32; 2],
        gbuffer: &Image,
        result: &Buffer,
        tiles: Buffer,
    ) -> Result<PixelList> {
        let head = Buffer::new(
            ctx,
            "btf pixel count",
            BufferDesc::storage(16).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
        )?;
        let list = Buffer::new(
            ctx,
            "btf pixel list",
            BufferDesc::storage(4 * w as u64 * h as u64),
        )?;
        let pipeline = crate::shaders::pipeline(ctx, "btf/pixels")?;
        let bind = pipeline.bind_declared(
            &[
                ("gbuffer", Resource::texture(gbuffer)),
                ("result", Resource::Buffer(result)),
                ("tiles", Resource::Buffer(&tiles)),
                ("pixel_head", Resource::Buffer(&head)),
                ("pixels", Resource::Buffer(&list)),
            ],
            &[
                ("result", AccessSet::from(A::ComputeShaderWrite)),
                ("pixels", AccessSet::from(A::ComputeShaderWrite)),
            ],
        )?;
        Ok(PixelList {
            tiles,
            head,
            list,
            pipeline,
            bind,
        })
    }
}

/// A new image `name` with `data` (its whole extent) uploaded through `rec`.
fn image_with<T: bytemuck::Pod>(
    rec: &mut Recorder,
    name: &str,
    desc: ImageDesc,
    data: &[T],
) -> Result<Image> {
    let image = Image::new(&rec.context(), name, desc)?;
    rec.upload_image(
        &image,
        ImageRegion::whole(&desc),
        bytemuck::cast_slice(data),
    )?;
    Ok(image)
}

impl Kernel for BtfKernel {
    type Input = Frame;
    type Readback = Readback;
    type Output = BtfOutput;

    fn name(&self) -> &'static str {
        "btf"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let mut passes: Vec<Pass<'_, Self>> = match &self.pixels {
            Some(px) => vec![
                Pass::list_reset(PASS_PIXEL_LIST, &px.head),
                Pass::dispatch_indirect(
                    PASS_PIXELS,
                    &px.pipeline,
                    &px.bind,
                    IndirectArgs {
                        buffer: &px.tiles,
                        offset: 0,
                    },
                    |k, _| Ok(k.pixels_push()),
                ),
                Pass::dispatch_indirect(
                    PASS_SHADE,
                    &self.pipeline,
                    &self.bind,
                    IndirectArgs {
                        buffer: &px.head,
                        offset: 0,
                    },
                    |k, frame| k.push(frame),
                ),
            ],
            None => vec![Pass::dispatch(
                PASS_SHADE,
                &self.pipeline,
                &self.bind,
                |k, frame| {
                    Ok(Dispatch {
                        push: k.push(frame)?,
                        grid: Grid::Invocations([k.size[0], k.size[1], 1]),
                    })
                },
            )],
        };
        if let Some(env) = &self.env {
            passes.push(Pass::dispatch(
                PASS_ENV,
                &env.pipeline,
                &env.bind,
                |k, frame| k.env_dispatch(frame),
            ));
        }
        if let Some(eb) = &self.env_basis {
            if let Some(ev) = &eb.vertices {
                passes.push(if ev.listed {
                    Pass::dispatch_indirect(
                        PASS_ENV_VERTICES,
                        &ev.pipeline,
                        &ev.bind,
                        IndirectArgs {
                            buffer: &ev.list,
                            offset: 0,
                        },
                        |k, _| Ok(k.env_vertices_dispatch()?.push),
                    )
                } else {
                    Pass::dispatch(PASS_ENV_VERTICES, &ev.pipeline, &ev.bind, |k, _| {
                        k.env_vertices_dispatch()
                    })
                });
            }
            let list = self.pixels.as_ref().filter(|_| eb.over_pixels);
            passes.push(match list {
                Some(px) => Pass::dispatch_indirect(
                    PASS_ENV_BASIS,
                    &eb.pipeline,
                    &eb.bind,
                    IndirectArgs {
                        buffer: &px.head,
                        offset: 0,
                    },
                    |k, frame| Ok(k.env_basis_dispatch(frame)?.push),
                ),
                None => Pass::dispatch(PASS_ENV_BASIS, &eb.pipeline, &eb.bind, |k, frame| {
                    k.env_basis_dispatch(frame)
                }),
            });
        }
        passes
    }

    fn check_input(&self, frame: &Frame) -> Result<()> {
        frame.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.result)
    }

    fn collect(&self, readback: &Readback) -> Result<BtfOutput> {
        readback.to_vec()
    }

    fn memory(&self) -> MemoryReport {
        let images = self
            .arrays
            .iter()
            .chain([&self.map])
            .chain(self.gbuffer.as_ref());
        let result = Resource::Buffer(&self.result);
        let pixel_list = self.pixels.iter().flat_map(|p| [&p.head, &p.list]);
        let env = self.env.iter().flat_map(|e| [&e.cells, &e.placeholder]);
        let basis_images = self
            .env_basis
            .iter()
            .flat_map(|e| e.coefficients.iter().chain([&e.table]));
        let light = self
            .env_basis
            .iter()
            .map(|e| Resource::storage_image(&e.light));
        let basis_buffers = self.env_basis.iter().flat_map(|e| {
            [&e.placeholder, &e.pixel_lobes]
                .into_iter()
                .chain(e.vertices.iter().flat_map(|v| {
                    // (a caller's list is counted by its owner)
                    (!v.listed).then_some(&v.list).into_iter().chain([&v.lobes])
                }))
        });
        self.ctx.memory_of_resources(
            images
                .chain(basis_images)
                .map(Resource::texture)
                .chain(light)
                .chain([result])
                .chain(
                    env.chain(basis_buffers)
                        .chain(pixel_list)
                        .map(Resource::Buffer),
                ),
        )
    }
}

/// What the environment pass `btf env` reads besides the kernel's own textures: buffers
/// another kernel writes on the GPU (e.g. the environment kernel's rotated lobes and
/// per-pixel visibility) or the caller uploads. The pass declares a read of each.
#[derive(Clone, Copy)]
pub struct EnvInputs<'a> {
    /// Two vec4 per lobe, world space: (axis xyz, sharpness), (amplitude rgb, 0) (radiance;
    /// [`super::env::lobe_texels`] packs host lobes so).
    pub lobes: &'a Buffer,
    /// Lobes the pass reads from `lobes` (at least 1).
    pub lobe_count: u32,
    /// Per-lobe visibility per pixel, f32 `[pixel * lobe_count + j]` (pixel = y * width + x
    /// of the G-buffer); `None`: every lobe fully visible.
    pub visibility: Option<&'a Buffer>,
}

/// The pipeline and bindings of `btf env`.
struct EnvPass {
    pipeline: ComputePipeline,
    bind: BindGroup,
    /// The midpoint rule's sub-cells ([`super::env::cell_texels`]).
    cells: Buffer,
    /// Bound as `visibility` when there is none (never read).
    placeholder: Buffer,
    lobe_count: u32,
    has_visibility: bool,
}

impl BtfKernel {
    /// As [`BtfKernel::on_gbuffer`], plus the pass `btf env` after `btf shade`: the cloth lit
    /// by the SG environment in `env` (rotated lobes, optional per-pixel visibility), added
    /// to the directional lights' result ([`super::env`] has the quadrature).
    pub fn on_gbuffer_env(
        rec: &mut Recorder,
        prep: &Prepared,
        gbuffer: &Image,
        env: EnvInputs<'_>,
    ) -> Result<BtfKernel> {
        let mut k = Self::on_gbuffer(rec, prep, gbuffer)?;
        k.env = Some(k.env_pass(rec, gbuffer, env)?);
        Ok(k)
    }

    /// As [`BtfKernel::from_prepared`] (G-buffer uploaded from `prep`) with the pass `btf
    /// env` of [`BtfKernel::on_gbuffer_env`].
    pub fn from_prepared_env(
        rec: &mut Recorder,
        prep: &Prepared,
        env: EnvInputs<'_>,
    ) -> Result<BtfKernel> {
        let mut k = Self::from_prepared(rec, prep)?;
        let gbuffer = k
            .gbuffer
            .take()
            .ok_or_else(|| Error::InvalidArgument("BTF prepared without a G-buffer".into()))?;
        k.env = Some(k.env_pass(rec, &gbuffer, env)?);
        k.gbuffer = Some(gbuffer);
        Ok(k)
    }

    fn env_pass(&self, rec: &mut Recorder, gbuffer: &Image, env: EnvInputs<'_>) -> Result<EnvPass> {
        let j = env.lobe_count as u64;
        let px = self.size[0] as u64 * self.size[1] as u64;
        if j == 0 || env.lobes.size() < 32 * j {
            return Err(Error::InvalidArgument(format!(
                "btf env: {j} lobes need {} bytes of lobes; '{}' holds {}",
                32 * j,
                env.lobes.name(),
                env.lobes.size()
            )));
        }
        if let Some(v) = env.visibility
            && v.size() < 4 * j * px
        {
            return Err(Error::InvalidArgument(format!(
                "btf env: visibility '{}' holds {} bytes; {px} pixels x {j} lobes need {}",
                v.name(),
                v.size(),
                4 * j * px
            )));
        }
        let ctx = rec.context();
        let name = match (self.packing.layout, self.packing.texture) {
            (_, Texture::Block) => "btf/shade_env_block",
            (Layout::Rows, _) => "btf/shade_env_rows",
            (Layout::Layers, _) => "btf/shade_env_layers",
        };
        let pipeline = crate::shaders::pipeline(&ctx, name)?;
        let texels = super::env::cell_texels();
        let cells = rec.buffer_with(
            "btf env cells",
            BufferDesc::storage(16 * texels.len() as u64),
            &texels,
        )?;
        let placeholder =
            rec.buffer_with("btf env no visibility", BufferDesc::storage(16), &[0f32; 4])?;
        let mut res = vec![
            ("dir_map", Resource::texture(&self.map)),
            ("gbuffer", Resource::texture(gbuffer)),
            ("result", Resource::Buffer(&self.result)),
            ("lobes", Resource::Buffer(env.lobes)),
            (
                "visibility",
                Resource::Buffer(env.visibility.unwrap_or(&placeholder)),
            ),
            ("cells", Resource::Buffer(&cells)),
        ];
        if self.packing.texture == Texture::Block {
            res.push(("btf_blocks", Resource::texture(&self.arrays[0])));
        } else {
            let sampler = self._sampler.as_ref().ok_or_else(|| {
                Error::InvalidArgument("btf env: sampled BTF without its sampler".into())
            })?;
            res.push((
                "btf",
                Resource::Array(self.arrays.iter().map(Resource::texture).collect()),
            ));
            res.push(("tile_sampler", Resource::Sampler(sampler)));
        }
        // `result` is read (the directional lights' sum) and written (plus the environment).
        let bind = pipeline.bind_declared(
            &res,
            &[("result", A::ComputeShaderReadOther | A::ComputeShaderWrite)],
        )?;
        Ok(EnvPass {
            pipeline,
            bind,
            cells,
            placeholder,
            lobe_count: env.lobe_count,
            has_visibility: env.visibility.is_some(),
        })
    }

    /// Whether the kernel records `btf env`, and how many lobes it reads.
    pub fn env_lobes(&self) -> Option<u32> {
        self.env.as_ref().map(|e| e.lobe_count)
    }

    fn env_dispatch(&self, frame: &Frame) -> Result<Dispatch> {
        frame.check()?;
        let env = self.env.as_ref().expect("btf env pass without its state");
        let mut push: Vec<u8> = frame
            .camera
            .push()
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let p = &self.packing;
        for u in [
            self.size[0],
            self.size[1],
            env.lobe_count,
            p.layers_per_array,
            p.gutter,
            p.tile[0],
            p.layer_extent[0],
            p.tile[1],
            env.has_visibility as u32,
            0,
            0,
            0,
        ] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.size[0], self.size[1], 1]),
        })
    }
}

/// Per-lobe visibility of `btf env basis`.
#[derive(Clone, Copy)]
pub enum BasisVisibility<'a> {
    /// Every lobe fully visible.
    None,
    /// f32 `[pixel * J + j]` (pixel = y * width + x of the G-buffer).
    PerPixel(&'a Buffer),
    /// f32 `[vertex * J + j]` (the environment kernel's
    /// [`crate::kernels::env::EnvKernel::visibility`]), interpolated at each pixel by the
    /// barycentrics of its G-buffer position on its triangle: `keys` the rasteriser's
    /// visibility buffer (u64 per pixel, triangle id in the low word), `triangles` its
    /// triangles (uvec4: vertex ids, part), `positions` the posed vertices (vec4).
    PerVertex {
        keys: &'a Buffer,
        positions: &'a Buffer,
        triangles: &'a Buffer,
        visibility: &'a Buffer,
    },
    /// As [`BasisVisibility::PerVertex`], with the light factors L_k themselves computed per
    /// vertex (pass [`PASS_ENV_VERTICES`], at the `vertices` listed: those of the shaded
    /// parts' triangles) in the vertex's tangent frame (`normals` and `tangents` of the pose,
    /// vec4, handedness in the tangent's w), for the front and the back face, and
    /// interpolated at each pixel by the same barycentrics: a vertex's lobes are fetched
    /// once instead of at every pixel of its triangles (bi-scale radiance transfer's
    /// per-vertex light factor). Twin: [`super::basis::BasisData::shade`] with
    /// [`super::basis::Visibility::PerVertexLight`].
    ///
    /// `listed`: a list written on the GPU each frame before the pass (e.g.
    /// [`crate::kernels::raster::vertices::VertexListKernel::subset_list`]: those of
    /// `vertices` on triangles covering a pixel), in that list's layout (u32 words
    /// `(ceil(count / 64), 1, 1, count)`, then the ids; INDIRECT_BUFFER usage): the pass is
    /// dispatched indirectly over it instead of over `vertices`, and the other vertices keep
    /// an older frame's factors. It must hold every vertex of every triangle the pass's
    /// pixels lie on.
    PerVertexLight {
        keys: &'a Buffer,
        positions: &'a Buffer,
        triangles: &'a Buffer,
        visibility: &'a Buffer,
        normals: &'a Buffer,
        tangents: &'a Buffer,
        vertices: &'a [u32],
        listed: Option<&'a Buffer>,
    },
}

impl BasisVisibility<'_> {
    /// The pass's visibility mode (glsl/btf/env_basis.glsl `dims.w`).
    fn mode(&self) -> u32 {
        match self {
            BasisVisibility::None => 0,
            BasisVisibility::PerPixel(_) => 1,
            BasisVisibility::PerVertex { .. } => 2,
            BasisVisibility::PerVertexLight { .. } => 3,
        }
    }
}

/// What `btf env basis` reads besides the kernel's own G-buffer and direction map.
#[derive(Clone, Copy)]
pub struct EnvBasisInputs<'a> {
    /// Two vec4 per lobe, world space: (axis xyz, sharpness), (amplitude rgb, 0); the
    /// lobes `data` was tabulated for, in the same order (rotated freely).
    pub lobes: &'a Buffer,
    /// The BTF's light basis and the lobes' tables ([`super::basis::BasisData::new`]).
    pub data: &'a super::basis::BasisData,
    /// Per-lobe visibility.
    pub visibility: BasisVisibility<'a>,
    /// Bit p: shade the pixels of part p (the G-buffer's part id).
    pub part_mask: u32,
}

/// Pass [`PASS_ENV_VERTICES`].
struct EnvVerticesPass {
    pipeline: ComputePipeline,
    bind: BindGroup,
    /// The vertices it runs over: the kernel's own static list, or (`listed`) the caller's
    /// GPU-written list, dispatched indirectly (its memory is the caller's).
    list: Buffer,
    listed: bool,
    /// The lobes it sums (those not in [`super::basis::BasisData::pixel_lobes`]).
    lobes: Buffer,
    lobe_count: u32,
    count: u32,
    vertex_count: u32,
}

struct EnvBasisPass {
    pipeline: ComputePipeline,
    bind: BindGroup,
    /// Dispatched over the kernel's pixel list (else over every pixel).
    over_pixels: bool,
    /// The per-vertex light factors (a 1 x 1 placeholder unless mode 3).
    light: Image,
    /// Mode 3: the lobes looked up per pixel ([`super::basis::BasisData::pixel_lobes`]).
    pixel_lobes: Buffer,
    pixel_lobe_count: u32,
    vertices: Option<EnvVerticesPass>,
    coefficients: Vec<Image>,
    table: Image,
    _samplers: [Sampler; 2],
    placeholder: Buffer,
    lobe_count: u32,
    mode: u32,
    part_mask: u32,
}

/// A storage buffer of u32 indices (one entry 0 when `indices` is empty: the pass then
/// reads none of it).
fn index_list(rec: &mut Recorder, name: &str, indices: &[u32]) -> Result<Buffer> {
    let list = if indices.is_empty() {
        &[0][..]
    } else {
        indices
    };
    rec.buffer_with(name, BufferDesc::storage(4 * list.len() as u64), list)
}

/// The lobes among the first `count` that `keep` keeps.
fn lobes_where(count: u64, keep: impl Fn(u32) -> bool) -> Vec<u32> {
    (0..count as u32).filter(|&j| keep(j)).collect()
}

/// f32 values (already rounded to f16) as RGBA16F texel words.
fn half_words(texels: &[[f32; 4]]) -> Vec<u16> {
    texels
        .iter()
        .flatten()
        .map(|&x| half::f16::from_f32(x).to_bits())
        .collect()
}

impl BtfKernel {
    /// Adds the pass `btf env basis` after this kernel's passes: the cloth lit by the SG
    /// environment through the BTF's light basis ([`super::basis`]), added to the result.
    /// `gbuffer`: the image the kernel shades (`None`: the one it uploaded itself). Its
    /// textures' uploads are recorded into `rec`.
    pub fn add_env_basis<'a>(
        &mut self,
        rec: &mut Recorder,
        gbuffer: Option<&Image>,
        env: EnvBasisInputs<'a>,
    ) -> Result<()> {
        use super::basis::{GROUPS, TABLE_LAYERS_PER_LOBE, TABLE_SIDE};
        let data = env.data;
        let j = data.lobe_count as u64;
        let px = self.size[0] as u64 * self.size[1] as u64;
        let bad = |m: String| Err(Error::InvalidArgument(format!("btf env basis: {m}")));
        if j == 0 || j > crate::kernels::env::MAX_LOBES as u64 {
            return bad(format!("{j} lobes; 1..={}", crate::kernels::env::MAX_LOBES));
        }
        if env.lobes.size() < 32 * j {
            return bad(format!(
                "{j} lobes need {} bytes; '{}' holds {}",
                32 * j,
                env.lobes.name(),
                env.lobes.size()
            ));
        }
        let texels = data.size[0] as usize * data.size[1] as usize;
        let layers = data.table.len() / (TABLE_SIDE * TABLE_SIDE) as usize;
        if data.coefficients.len() != GROUPS
            || data
                .coefficients
                .iter()
                .any(|c| c.len() != texels * super::dirs::COUNT)
            || layers != TABLE_LAYERS_PER_LOBE * j as usize
        {
            return bad("the basis data's sizes do not match its tile and lobes".into());
        }
        let placeholder = rec.buffer_with(
            "btf env basis placeholder",
            BufferDesc::storage(16),
            &[0f32; 4],
        )?;
        let mode = env.visibility.mode();
        let (pixel_vis, keys, positions, triangles, vertex_vis) = match env.visibility {
            BasisVisibility::None => (None, None, None, None, None),
            BasisVisibility::PerPixel(v) => {
                if v.size() < 4 * j * px {
                    return bad(format!(
                        "visibility '{}' holds {} bytes; {px} pixels x {j} lobes need {}",
                        v.name(),
                        v.size(),
                        4 * j * px
                    ));
                }
                (Some(v), None, None, None, None)
            }
            BasisVisibility::PerVertex {
                keys,
                positions,
                triangles,
                visibility,
            }
            | BasisVisibility::PerVertexLight {
                keys,
                positions,
                triangles,
                visibility,
                ..
            } => {
                let vertices = positions.size() / 16;
                if keys.size() < 8 * px || visibility.size() < 4 * j * vertices {
                    return bad(format!(
                        "keys '{}' ({} bytes) and visibility '{}' ({} bytes): {px} pixels need \
                         {} bytes of keys, {vertices} vertices x {j} lobes {} of visibility",
                        keys.name(),
                        keys.size(),
                        visibility.name(),
                        visibility.size(),
                        8 * px,
                        4 * j * vertices
                    ));
                }
                (
                    None,
                    Some(keys),
                    Some(positions),
                    Some(triangles),
                    Some(visibility),
                )
            }
        };
        let Some(gbuffer) = gbuffer.or(self.gbuffer.as_ref()) else {
            return bad("no G-buffer given and none uploaded".into());
        };
        let format = vk::Format::R16G16B16A16_SFLOAT;
        let coefficients = data
            .coefficients
            .iter()
            .enumerate()
            .map(|(g, texels)| {
                let desc = ImageDesc::d2_array(format, data.size, super::dirs::COUNT as u32);
                image_with(
                    rec,
                    &format!("btf env basis coefficients {g}"),
                    desc,
                    &half_words(texels),
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let table_desc = ImageDesc::d2_array(format, [TABLE_SIDE; 2], layers as u32);
        let table = image_with(
            rec,
            "btf env basis lobe table",
            table_desc,
            &half_words(&data.table),
        )?;
        let ctx = rec.context();
        let linear = SamplerDesc::linear().lod(0.0, 0.0);
        let samplers = [
            Sampler::new(
                &ctx,
                "btf env basis repeat",
                linear.address(vk::SamplerAddressMode::REPEAT),
            )?,
            Sampler::new(&ctx, "btf env basis clamp", linear)?,
        ];
        let light_desc = |size: [u32; 2]| {
            ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, size)
                .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST)
        };
        let (light, vertices) = match env.visibility {
            BasisVisibility::PerVertexLight {
                positions,
                visibility,
                normals,
                tangents,
                vertices,
                listed,
                ..
            } => {
                let nv = positions.size() / 16;
                if let Some(l) = listed
                    && (l.size() < 16 || !l.usage().contains(vk::BufferUsageFlags::INDIRECT_BUFFER))
                {
                    return bad(format!(
                        "vertex list '{}' ({} bytes, usage {:?}): a list needs its 16-byte head \
                         and INDIRECT_BUFFER usage",
                        l.name(),
                        l.size(),
                        l.usage()
                    ));
                }
                if normals.size() < 16 * nv || tangents.size() < 16 * nv {
                    return bad(format!(
                        "normals '{}' ({} bytes) and tangents '{}' ({} bytes): {nv} vertices \
                         need {} bytes each",
                        normals.name(),
                        normals.size(),
                        tangents.name(),
                        tangents.size(),
                        16 * nv
                    ));
                }
                if let Some(v) = vertices.iter().find(|&&v| u64::from(v) >= nv) {
                    return bad(format!("listed vertex {v} of {nv}"));
                }
                let rows = nv.div_ceil(u64::from(LIGHT_VERTICES)).max(1);
                let max = u64::from(rec.context().limits().max_image_dimension_2d);
                if rows > max {
                    return bad(format!(
                        "{nv} vertices need {rows} rows of per-vertex light; the device \
                         allows {max}"
                    ));
                }
                let light = Image::new(
                    &rec.context(),
                    "btf env vertex light",
                    light_desc([LIGHT_TEXELS * LIGHT_VERTICES, rows as u32]),
                )?;
                // Over the caller's list when given (no static list to upload then).
                let list = match listed {
                    Some(l) => l.clone(),
                    None => index_list(rec, "btf env vertices list", vertices)?,
                };
                let vertex_lobes = lobes_where(j, |jj| data.pixel_lobes & (1 << jj) == 0);
                let vlobes = index_list(rec, "btf env vertices lobes", &vertex_lobes)?;
                let shader = match listed {
                    Some(_) => "btf/env_vertices_listed",
                    None => "btf/env_vertices",
                };
                let pipeline = crate::shaders::pipeline(&rec.context(), shader)?;
                let bind = pipeline.bind_declared(
                    &[
                        ("table", Resource::texture(&table)),
                        ("table_sampler", Resource::Sampler(&samplers[1])),
                        ("lobes", Resource::Buffer(env.lobes)),
                        ("nrm", Resource::Buffer(normals)),
                        ("tan", Resource::Buffer(tangents)),
                        ("vertex_vis", Resource::Buffer(visibility)),
                        ("list", Resource::Buffer(&list)),
                        ("light", Resource::storage_image(&light)),
                        ("vlobes", Resource::Buffer(&vlobes)),
                    ],
                    &[("light", AccessSet::from(A::ComputeShaderWrite))],
                )?;
                let pass = EnvVerticesPass {
                    pipeline,
                    bind,
                    list,
                    lobes: vlobes,
                    lobe_count: vertex_lobes.len() as u32,
                    count: vertices.len() as u32,
                    vertex_count: nv as u32,
                    listed: listed.is_some(),
                };
                (light, Some(pass))
            }
            _ => {
                // Never read outside mode 3; cleared so that nothing reads undefined texels.
                let light = Image::new(
                    &rec.context(),
                    "btf env light placeholder",
                    light_desc([1, 1]),
                )?;
                rec.clear_image(
                    &light,
                    crate::gpu::Subresources::mip(light.desc(), 0),
                    [0.0; 4],
                )?;
                (light, None)
            }
        };
        let pixel_lobe_list = match mode {
            3 => lobes_where(j, |jj| data.pixel_lobes & (1 << jj) != 0),
            _ => Vec::new(),
        };
        let pixel_lobes = index_list(rec, "btf env basis pixel lobes", &pixel_lobe_list)?;
        // Over the pixel list when `btf shade` runs over it and it holds every part this
        // pass shades; else over every pixel (the pass only adds where the G-buffer is
        // covered by one of its parts, so the pixels `btf shade` leaves empty stay empty).
        let over_pixels = self
            .pixels
            .as_ref()
            .filter(|_| env.part_mask & !self.part_mask == 0);
        let name = match over_pixels {
            Some(_) => "btf/env_basis_pixels",
            None => "btf/env_basis",
        };
        // The per-pixel lobe loop is compiled out where it would count 0 (see the shader).
        let per_pixel_lobes = mode != 3 || !pixel_lobe_list.is_empty();
        let pipeline = crate::shaders::pipeline_specialized(
            &ctx,
            name,
            &[("PER_PIXEL_LOBES", u32::from(per_pixel_lobes))],
        )?;
        let ph = &placeholder;
        let or = |b: Option<&'a Buffer>| Resource::Buffer(b.unwrap_or(ph));
        let mut res = vec![
            (
                "coeffs",
                Resource::Array(coefficients.iter().map(Resource::texture).collect()),
            ),
            ("coeff_sampler", Resource::Sampler(&samplers[0])),
            ("table", Resource::texture(&table)),
            ("table_sampler", Resource::Sampler(&samplers[1])),
            ("dir_map", Resource::texture(&self.map)),
            ("gbuffer", Resource::texture(gbuffer)),
            ("result", Resource::Buffer(&self.result)),
            ("lobes", Resource::Buffer(env.lobes)),
            ("pixel_vis", or(pixel_vis)),
            ("keys", or(keys)),
            ("pos", or(positions)),
            ("tris", or(triangles)),
            ("vertex_vis", or(vertex_vis)),
            ("vertex_light", Resource::storage_image(&light)),
            ("plobes", Resource::Buffer(&pixel_lobes)),
        ];
        if let Some(px) = over_pixels {
            res.push(("pixel_head", Resource::Buffer(&px.head)));
            res.push(("pixels", Resource::Buffer(&px.list)));
        }
        let bind = pipeline.bind_declared(
            &res,
            &[("result", A::ComputeShaderReadOther | A::ComputeShaderWrite)],
        )?;
        self.env_basis = Some(EnvBasisPass {
            pipeline,
            bind,
            over_pixels: over_pixels.is_some(),
            light,
            vertices,
            pixel_lobe_count: pixel_lobe_list.len() as u32,
            pixel_lobes,
            coefficients,
            table,
            _samplers: samplers,
            placeholder,
            lobe_count: j as u32,
            mode,
            part_mask: env.part_mask,
        });
        Ok(())
    }

    /// Whether the kernel records `btf env basis`, and how many lobes it reads.
    pub fn env_basis_lobes(&self) -> Option<u32> {
        self.env_basis.as_ref().map(|e| e.lobe_count)
    }

    fn env_vertices_dispatch(&self) -> Result<Dispatch> {
        let ev = self
            .env_basis
            .as_ref()
            .and_then(|e| e.vertices.as_ref())
            .expect("btf env vertices pass without its state");
        let eb = self.env_basis.as_ref().expect("checked above");
        Ok(Dispatch::words(
            &[ev.count, eb.lobe_count, ev.vertex_count, ev.lobe_count],
            Grid::Invocations([ev.count, 1, 1]),
        ))
    }

    fn env_basis_dispatch(&self, frame: &Frame) -> Result<Dispatch> {
        frame.check()?;
        let eb = self
            .env_basis
            .as_ref()
            .expect("btf env basis pass without its state");
        let mut push: Vec<u8> = frame
            .camera
            .push()
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        for u in [
            self.size[0],
            self.size[1],
            eb.lobe_count,
            eb.mode,
            eb.part_mask,
            eb.pixel_lobe_count,
            0,
            0,
        ] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.size[0], self.size[1], 1]),
        })
    }
}
