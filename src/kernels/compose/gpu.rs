//! The compose kernel on the GPU: `compose params` uploads the frame's parameters,
//! `compose shade` shades every pixel (glsl/compose/shade.comp), or, with the rasteriser's
//! tile list, the listed tiles; with the list split by [`TileClassKernel`] (`compose
//! classify`: the tiles holding a skin pixel and the others), `compose shade` shades the
//! others in a pipeline without the skin's path and `compose shade skin` the skin's tiles
//! (glsl/compose/classify.comp has why).

use super::pack::{Environment, FrameParams, Prepared};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::raster::pack::Camera;
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};

/// The upload of the frame's parameters.
pub const PASS_PARAMS: &str = "compose params";
/// The per-pixel shading, tone mapping and encoding.
pub const PASS_SHADE: &str = "compose shade";
/// With a tile list: the background pixel, tone-mapped once, and the indirect arguments of
/// `compose background` (no pixel unless the background pixel changed).
pub const PASS_BACKGROUND_VALUE: &str = "compose background value";
/// With a tile list, on a frame whose background pixel changed: every pixel takes the
/// background before `compose shade` (and `compose shade skin`) shade the listed tiles
/// (glsl/compose/background.comp).
pub const PASS_BACKGROUND: &str = "compose background";
/// With the tile list split ([`Inputs::classes`]): the shading of the tiles holding a skin
/// pixel (the others are [`PASS_SHADE`]'s, in a pipeline without the skin's path).
pub const PASS_SHADE_SKIN: &str = "compose shade skin";

/// Bytes of the parameter block (std430 `Params`).
const PARAMS_BYTES: u64 = 192;
/// Bytes of the background's state (std430 `Background`, glsl/compose/output.glsl).
const BACKGROUND_BYTES: u64 = 48;

/// The buffers and image the pass reads that other kernels write.
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    /// The screen G-buffer (3 layers, rgba32f; `kernels::raster`).
    pub gbuffer: &'a Image,
    /// The rasteriser's per-pixel (depth, triangle) keys, 8 bytes a pixel.
    pub keys: &'a Buffer,
    /// Posed positions, vec4 per vertex (`kernels::pose`).
    pub positions: &'a Buffer,
    /// The skin's diffusion, vec4 per atlas texel (`SssKernel::diffuse`); None without skin.
    pub diffuse: Option<&'a Buffer>,
    /// The cloth's radiance, vec4 per pixel (`BtfKernel::result`); None without cloth.
    pub cloth: Option<&'a Buffer>,
    /// The rotated environment lobes (two vec4 each) and their count; None: no environment.
    pub lobes: Option<(&'a Buffer, u32)>,
    /// Per vertex and lobe, the lobe's visibility (f32, vertex-major); None: unshadowed.
    pub lobe_visibility: Option<&'a Buffer>,
    /// The background behind the character (linear rgb).
    pub background: [f32; 3],
    /// The rasteriser's list of covered tiles (`RasterKernel::tiles`): with it, `compose
    /// shade` is dispatched indirectly over the listed tiles only (lavapipe pays the whole
    /// shader for every pixel it runs, background included), and the pixels outside them
    /// keep the background this kernel stored: pass `compose background` stores it in every
    /// pixel, but only on the first frame and on a frame whose background pixel differs
    /// from the previous frame's (e.g. a new exposure). So the list must hold every
    /// tile covered at the previous frame as well as this frame's, as the rasteriser's does
    /// (its stale tiles) when both kernels record every frame; the images are then those of
    /// `compose shade` over every pixel. None: `compose shade` over every pixel.
    pub tiles: Option<&'a Buffer>,
    /// With `tiles`: that list split by a [`TileClassKernel`] made for the same frame size,
    /// skin triangles and tile list and recorded earlier in the same frame, so that only the
    /// tiles holding a skin pixel run the skin's shading (`compose shade skin`; the others,
    /// `compose shade`, in a pipeline without it: a skin pixel there would be shaded as
    /// cloth). None: every listed tile runs it. Refused without `tiles`.
    pub classes: Option<TileClasses<'a>>,
}

/// One frame's images, read back.
#[derive(Clone, Debug)]
pub struct ComposeOutput {
    /// Width and height.
    pub size: [u32; 2],
    /// Linear radiance per pixel; alpha 1 where the character covers the pixel.
    pub hdr: Vec<[f32; 4]>,
    /// Tone-mapped sRGB, RGBA8 per pixel (red in the low byte).
    pub ldr: Vec<u32>,
}

impl ComposeOutput {
    /// The sRGB image as bytes, RGBA row-major.
    pub fn rgba8(&self) -> Vec<u8> {
        self.ldr.iter().flat_map(|w| w.to_le_bytes()).collect()
    }
}

/// Passes `compose background value` and `compose background`, and the rasteriser's tile
/// list (`compose shade` is dispatched over it, or over its plain part with `classes`).
struct Tiled {
    value: ComputePipeline,
    value_bind: BindGroup,
    background: ComputePipeline,
    background_bind: BindGroup,
    tiles: Buffer,
    /// The background's state (glsl/compose/output.glsl `Background`), zero when made.
    state: Buffer,
    /// With [`Inputs::classes`]: the split list's buffers and the pass over the skin's
    /// tiles (the kernel's own pipeline, built without the skin's path, shades the others).
    classes: Option<Classes>,
}

/// [`Inputs::classes`], held, and pass `compose shade skin`.
struct Classes {
    plain: Buffer,
    skin: Buffer,
    skin_pipeline: ComputePipeline,
    skin_bind: BindGroup,
}

/// The readbacks of a frame's images.
pub struct ComposeReadback {
    hdr: Readback,
    ldr: Readback,
}

/// The compose pass of a character frame.
pub struct ComposeKernel {
    ctx: Context,
    pipeline: ComputePipeline,
    bind: BindGroup,
    /// With a tile list: pass `compose background` and the list.
    tiled: Option<Tiled>,
    params: Buffer,
    hdr: Buffer,
    ldr: Buffer,
    own: Vec<Buffer>,
    /// Zero buffers bound in place of absent inputs.
    spare: Vec<Buffer>,
    size: [u32; 2],
    env: Environment,
    /// Atlas size, skin triangles, visibility mode, surface count.
    atlas: [u32; 4],
}

fn too_small(what: &str, have: u64, need: u64) -> Error {
    Error::InvalidArgument(format!(
        "compose: {what} holds {have} bytes; the frame needs {need}"
    ))
}

/// The rasteriser's key buffer holds a key (8 bytes) for every pixel of a `size` frame.
fn check_keys(keys: &Buffer, size: [u32; 2]) -> Result<()> {
    let need = size[0] as u64 * size[1] as u64 * 8;
    if keys.size() < need {
        return Err(too_small("the key buffer", keys.size(), need));
    }
    Ok(())
}

/// The skin triangles' vertex ids and atlas corners of `prep`, uploaded (`what` names them).
fn skin_buffers(rec: &mut Recorder, prep: &Prepared, what: &str) -> Result<[Buffer; 2]> {
    let storage = BufferDesc::storage;
    let tris = rec.buffer_with(
        &format!("{what} skin triangles"),
        storage(prep.skin_tris.len() as u64 * 16),
        &prep.skin_tris,
    )?;
    let uvs = rec.buffer_with(
        &format!("{what} skin uvs"),
        storage(prep.skin_uvs.len() as u64 * 16),
        &prep.skin_uvs,
    )?;
    Ok([tris, uvs])
}

impl ComposeKernel {
    /// Creates the kernel's buffers and pipeline and records the uploads of `prep` into
    /// `rec`. The inputs are bound once: each frame reads what the kernels writing them
    /// wrote earlier in the same recording (ordered by their declared accesses).
    pub fn new<'a>(
        rec: &mut Recorder,
        prep: &Prepared,
        inputs: &Inputs<'a>,
    ) -> Result<ComposeKernel> {
        let ctx = rec.context();
        let [w, h] = prep.size;
        let pixels = w as u64 * h as u64;
        let d = inputs.gbuffer.desc();
        if d.extent[0] != w || d.extent[1] != h || d.layers < 3 {
            return Err(Error::InvalidArgument(format!(
                "compose: G-buffer of {} x {} x {} layers for a {w} x {h} frame (3 layers)",
                d.extent[0], d.extent[1], d.layers
            )));
        }
        check_keys(inputs.keys, prep.size)?;
        let vertices = inputs.positions.size() / 16;
        let atlas_texels = prep.atlas_size as u64 * prep.atlas_size as u64;
        if prep.mask.len() as u64 != atlas_texels {
            return Err(Error::InvalidArgument(format!(
                "compose: atlas mask of {} texels for a {0}^2 atlas",
                prep.mask.len()
            )));
        }
        if prep.skin_triangles > 0 {
            let diffuse = inputs.diffuse.ok_or_else(|| {
                Error::InvalidArgument("compose: skin triangles but no diffusion buffer".into())
            })?;
            if diffuse.size() < atlas_texels * 16 {
                return Err(too_small(
                    "the diffusion",
                    diffuse.size(),
                    atlas_texels * 16,
                ));
            }
            let max_vertex = prep.skin_tris.iter().flat_map(|t| &t[..3]).max();
            if max_vertex.is_some_and(|&v| v as u64 >= vertices) {
                return Err(Error::InvalidArgument(format!(
                    "compose: a skin triangle names vertex {} of {vertices} posed",
                    max_vertex.copied().unwrap_or(0)
                )));
            }
        }
        if let Some(c) = inputs.cloth
            && c.size() < pixels * 16
        {
            return Err(too_small("the cloth radiance", c.size(), pixels * 16));
        }
        let lobe_count = inputs.lobes.map_or(0, |l| l.1);
        if let Some((b, n)) = inputs.lobes
            && (n == 0 || b.size() < n as u64 * 32)
        {
            return Err(too_small("the lobe buffer", b.size(), n.max(1) as u64 * 32));
        }
        if let Some(v) = inputs.lobe_visibility {
            if inputs.lobes.is_none() {
                return Err(Error::InvalidArgument(
                    "compose: lobe visibility without lobes".into(),
                ));
            }
            if v.size() < vertices * lobe_count as u64 * 4 {
                return Err(too_small(
                    "the lobe visibility",
                    v.size(),
                    vertices * lobe_count as u64 * 4,
                ));
            }
        }
        if let Some(c) = inputs.classes {
            if inputs.tiles.is_none() {
                return Err(Error::InvalidArgument(
                    "compose: tile classes without the tile list they split".into(),
                ));
            }
            let need = tile_list_bytes(prep.size);
            for (what, b) in [
                ("the plain tile list", c.plain),
                ("the skin tile list", c.skin),
            ] {
                if b.size() < need {
                    return Err(too_small(what, b.size(), need));
                }
            }
        }
        use bytemuck::cast_slice as bytes;
        let storage = BufferDesc::storage;
        let [skin_tris, skin_uvs] = skin_buffers(rec, prep, "compose")?;
        let mask = rec.buffer_with(
            "compose atlas mask",
            storage(prep.mask.len() as u64 * 4),
            &prep.mask,
        )?;
        let (surface_table, surface_texels) = super::pack::pack_surfaces(&prep.surfaces);
        let surfaces = rec.buffer_with(
            "compose surfaces",
            storage(surface_table.len() as u64 * 16),
            &surface_table,
        )?;
        let texels = rec.buffer_with(
            "compose surface texels",
            storage(surface_texels.len() as u64 * 4),
            &surface_texels,
        )?;
        let params = Buffer::new(&ctx, "compose params", storage(PARAMS_BYTES))?;
        let hdr = Buffer::new(&ctx, "compose hdr", storage(pixels * 16))?;
        let ldr = Buffer::new(&ctx, "compose ldr", storage(ldr_bytes(pixels)))?;
        // Stand-ins for absent inputs: zeros, never read where the input is absent (no skin
        // triangle, no cloth triangle, no lobe) but bound because the layout is fixed.
        let small = |rec: &mut Recorder, name: &str| {
            rec.buffer_with(name, storage(32), bytes::<f32, u8>(&[0.0; 8]))
        };
        let mut spare = Vec::new();
        let diffuse = match inputs.diffuse {
            Some(b) => b.clone(),
            None => small(rec, "compose no diffusion")?,
        };
        if inputs.diffuse.is_none() {
            spare.push(diffuse.clone());
        }
        let cloth = match inputs.cloth {
            Some(b) => b.clone(),
            None => {
                let zero = Buffer::new(&ctx, "compose no cloth", storage(pixels * 16))?;
                rec.fill_buffer(&zero, 0)?;
                spare.push(zero.clone());
                zero
            }
        };
        let lobes = match inputs.lobes {
            Some((b, _)) => b.clone(),
            None => {
                let b = small(rec, "compose no lobes")?;
                spare.push(b.clone());
                b
            }
        };
        let lobe_vis = match inputs.lobe_visibility {
            Some(b) => b.clone(),
            None => {
                let b = small(rec, "compose no lobe visibility")?;
                spare.push(b.clone());
                b
            }
        };
        let own = vec![skin_tris, skin_uvs, mask, surfaces, texels];
        // With a tile list: the background's state, zero when made.
        let background_state = match inputs.tiles {
            Some(_) => {
                let state = Buffer::new(
                    &ctx,
                    "compose background state",
                    storage(BACKGROUND_BYTES).usage(ash::vk::BufferUsageFlags::INDIRECT_BUFFER),
                )?;
                rec.fill_buffer(&state, 0)?;
                Some(state)
            }
            None => None,
        };
        // Without a textured part the shader's textured path compiles away; so does the
        // skin's without skin, and over the tile list, in the pipeline of the tiles without
        // a skin pixel (`compose classify` splits the list).
        let textured = prep.surfaces.iter().any(|s| s.texture.is_some()) as u32;
        let skin = prep.skin_triangles > 0;
        let specialized = |name: &str, skin: bool| {
            crate::shaders::pipeline_specialized(
                &ctx,
                name,
                &[("TEXTURED", textured), ("SKIN", skin as u32)],
            )
        };
        let classes = inputs.classes;
        let pipeline = match (inputs.tiles, classes) {
            (Some(_), Some(_)) => specialized("compose/shade_tiles", false)?,
            (Some(_), None) => specialized("compose/shade_tiles", skin)?,
            (None, _) => specialized("compose/shade", skin)?,
        };
        let lookup = |name: &str| -> Option<Resource<'_>> {
            Some(match name {
                "gbuffer" => Resource::texture(inputs.gbuffer),
                "keys" => Resource::Buffer(inputs.keys),
                "pos" => Resource::Buffer(inputs.positions),
                "skin_tris" => Resource::Buffer(&own[0]),
                "skin_uvs" => Resource::Buffer(&own[1]),
                "mask" => Resource::Buffer(&own[2]),
                "surfaces" => Resource::Buffer(&own[3]),
                "texels" => Resource::Buffer(&own[4]),
                "diffuse" => Resource::Buffer(&diffuse),
                "cloth" => Resource::Buffer(&cloth),
                "lobes" => Resource::Buffer(&lobes),
                "lobe_vis" => Resource::Buffer(&lobe_vis),
                "params" => Resource::Buffer(&params),
                "hdr" => Resource::Buffer(&hdr),
                "ldr" => Resource::Buffer(&ldr),
                "tiles" => Resource::Buffer(inputs.tiles?),
                "bg" => Resource::Buffer(background_state.as_ref()?),
                _ => return None,
            })
        };
        // The shading pipelines over a split list read their part in place of the
        // rasteriser's list.
        let over = |part: fn(TileClasses<'a>) -> &'a Buffer| {
            move |name: &str| match (name, classes) {
                ("tiles", Some(c)) => Some(Resource::Buffer(part(c))),
                _ => lookup(name),
            }
        };
        let w = AccessSet::from(A::ComputeShaderWrite);
        let bind = pipeline.bind_from(over(|c| c.plain), &[("hdr", w), ("ldr", w)])?;
        let tiled = match inputs.tiles.zip(background_state.as_ref()) {
            Some((t, state)) => {
                let value = crate::shaders::pipeline(&ctx, "compose/background_value")?;
                let value_bind = value.bind_from(lookup, &[])?;
                let background = crate::shaders::pipeline(&ctx, "compose/background")?;
                let background_bind = background.bind_from(lookup, &[("hdr", w), ("ldr", w)])?;
                let classes = match classes {
                    Some(c) => {
                        let skin_pipeline = specialized("compose/shade_tiles", true)?;
                        let skin_bind =
                            skin_pipeline.bind_from(over(|c| c.skin), &[("hdr", w), ("ldr", w)])?;
                        Some(Classes {
                            plain: c.plain.clone(),
                            skin: c.skin.clone(),
                            skin_pipeline,
                            skin_bind,
                        })
                    }
                    None => None,
                };
                Some(Tiled {
                    value,
                    value_bind,
                    background,
                    background_bind,
                    tiles: t.clone(),
                    state: state.clone(),
                    classes,
                })
            }
            None => None,
        };
        let env = match inputs.lobes {
            Some((_, n)) => Environment::Lobes(n, inputs.background),
            None => Environment::None(inputs.background),
        };
        let visibility_mode = u32::from(inputs.lobe_visibility.is_some());
        Ok(ComposeKernel {
            ctx,
            pipeline,
            bind,
            tiled,
            params,
            hdr,
            ldr,
            own,
            spare,
            size: prep.size,
            env,
            atlas: [
                prep.atlas_size,
                prep.skin_triangles,
                visibility_mode,
                prep.surfaces.len() as u32,
            ],
        })
    }

    /// Linear radiance per pixel (vec4; alpha 1 where the character covers it).
    pub fn hdr(&self) -> &Buffer {
        &self.hdr
    }

    /// Tone-mapped sRGB per pixel (one RGBA8 word).
    pub fn ldr(&self) -> &Buffer {
        &self.ldr
    }

    /// Output width and height.
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    fn params_bytes(&self, p: &FrameParams) -> Result<Vec<u8>> {
        p.check()?;
        Ok(p.bytes(self.size, self.env, self.atlas))
    }

    fn shade_args(&self, _p: &FrameParams) -> Result<Dispatch> {
        Ok(Dispatch {
            push: Vec::new(),
            grid: Grid::Invocations([self.size[0], self.size[1], 1]),
        })
    }
}

impl Kernel for ComposeKernel {
    type Input = FrameParams;
    type Readback = ComposeReadback;
    type Output = ComposeOutput;

    fn name(&self) -> &'static str {
        "compose"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let mut passes = vec![Pass::upload(PASS_PARAMS, &self.params, Self::params_bytes)];
        match &self.tiled {
            Some(t) => {
                passes.extend([
                    Pass::dispatch(PASS_BACKGROUND_VALUE, &t.value, &t.value_bind, |_, _| {
                        Ok(Dispatch {
                            push: Vec::new(),
                            grid: Grid::Groups([1, 1, 1]),
                        })
                    }),
                    // Every pixel or none, as the value pass wrote: at most ceil(pixels / 2^14)
                    // groups along y, under the 65,535 every device allows while the HDR buffer
                    // (16 bytes a pixel) fits a storage-buffer binding (at most 4 GiB).
                    Pass::dispatch_indirect(
                        PASS_BACKGROUND,
                        &t.background,
                        &t.background_bind,
                        IndirectArgs {
                            buffer: &t.state,
                            offset: 0,
                        },
                        |k: &ComposeKernel, _| Ok(bytemuck::cast_slice(&k.size).to_vec()),
                    ),
                    Pass::dispatch_indirect(
                        PASS_SHADE,
                        &self.pipeline,
                        &self.bind,
                        IndirectArgs {
                            buffer: t.classes.as_ref().map_or(&t.tiles, |c| &c.plain),
                            offset: 0,
                        },
                        |_, _| Ok(Vec::new()),
                    ),
                ]);
                if let Some(c) = &t.classes {
                    passes.push(Pass::dispatch_indirect(
                        PASS_SHADE_SKIN,
                        &c.skin_pipeline,
                        &c.skin_bind,
                        IndirectArgs {
                            buffer: &c.skin,
                            offset: 0,
                        },
                        |_, _| Ok(Vec::new()),
                    ));
                }
            }
            None => passes.push(Pass::dispatch(
                PASS_SHADE,
                &self.pipeline,
                &self.bind,
                Self::shade_args,
            )),
        }
        passes
    }

    fn check_input(&self, p: &FrameParams) -> Result<()> {
        p.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<ComposeReadback> {
        Ok(ComposeReadback {
            hdr: rec.read_back(&self.hdr)?,
            // The pixels' words, not the padding after them.
            ldr: rec.read_back_range(
                &self.ldr,
                0,
                4 * self.size[0] as u64 * self.size[1] as u64,
            )?,
        })
    }

    fn collect(&self, rb: &ComposeReadback) -> Result<ComposeOutput> {
        Ok(ComposeOutput {
            size: self.size,
            hdr: rb.hdr.to_vec()?,
            ldr: rb.ldr.to_vec()?,
        })
    }

    fn memory(&self) -> MemoryReport {
        let mut all: Vec<&Buffer> = vec![&self.params, &self.hdr, &self.ldr];
        all.extend(self.own.iter());
        if let Some(t) = &self.tiled {
            all.push(&t.state);
        }
        all.extend(self.spare.iter());
        self.ctx.memory_of(&all)
    }
}

/// Bytes of the LDR output for `pixels` pixels: one word each, padded to whole 16-byte
/// quads (pass `compose background` stores 4 words at once; the padding is never read).
fn ldr_bytes(pixels: u64) -> u64 {
    pixels.div_ceil(4) * 16
}

/// The clearing of the needed-segment bitmap (an upload of zeros).
pub const PASS_NEED_CLEAR: &str = "compose need clear";
/// The marking of the atlas segments the compose pass reads (glsl/compose/need.comp).
pub const PASS_NEED: &str = "compose need";

/// Pass `compose need`: per frame, the bitmap of the skin atlas's 8x1 row segments that
/// [`ComposeKernel`]'s shade passes will read the diffusion at (every skin pixel's bilinear
/// footprint, a texel of margin around it), for `SssKernel::set_needed_segments`, so that the
/// texture-space diffusion runs only where the frame looks. Recorded after the raster and
/// pose passes and before the diffusion; its input is the camera the G-buffer was rasterised
/// with. The twin is [`super::cpu::needed_segments`].
pub struct NeedKernel {
    ctx: Context,
    pipeline: ComputePipeline,
    bind: BindGroup,
    needed: Buffer,
    tiles: Buffer,
    own: Vec<Buffer>,
    size: [u32; 2],
    atlas: u32,
    skin_triangles: u32,
}

/// What [`NeedKernel`] reads that other kernels write.
#[derive(Clone, Copy)]
pub struct NeedInputs<'a> {
    /// The rasteriser's per-pixel (depth, triangle) keys, 8 bytes a pixel (an empty key
    /// names no triangle).
    pub keys: &'a Buffer,
    /// Posed positions, vec4 per vertex (`kernels::pose`).
    pub positions: &'a Buffer,
    /// A tile list holding every tile with a skin pixel, the pass dispatched indirectly over
    /// it: the rasteriser's list of covered tiles (`RasterKernel::tiles`) or, cheaper, the
    /// skin's tiles of that list ([`TileClasses::skin`], as the character frame passes).
    pub tiles: &'a Buffer,
}

/// A finished [`NeedKernel`] readback.
pub struct NeedReadback(Readback);

impl NeedKernel {
    /// Creates the bitmap and the pass for `prep`'s skin (its triangles' atlas corners) and
    /// records the uploads. `prep` must have skin triangles.
    pub fn new(rec: &mut Recorder, prep: &Prepared, inputs: &NeedInputs<'_>) -> Result<NeedKernel> {
        let ctx = rec.context();
        if prep.skin_triangles == 0 || prep.atlas_size == 0 {
            return Err(Error::InvalidArgument(
                "compose need: no skin triangles, so no diffusion to restrict".into(),
            ));
        }
        check_keys(inputs.keys, prep.size)?;
        let vertices = inputs.positions.size() / 16;
        let max_vertex = prep.skin_tris.iter().flat_map(|t| &t[..3]).max();
        if max_vertex.is_some_and(|&v| v as u64 >= vertices) {
            return Err(Error::InvalidArgument(format!(
                "compose need: a skin triangle names vertex {} of {vertices} posed",
                max_vertex.copied().unwrap_or(0)
            )));
        }
        let storage = BufferDesc::storage;
        let [skin_tris, skin_uvs] = skin_buffers(rec, prep, "compose need")?;
        let words = crate::kernels::sss::pack::needed_segment_words(prep.atlas_size);
        let needed = Buffer::new(&ctx, "compose needed segments", storage(words * 4))?;
        let pipeline = crate::shaders::pipeline(&ctx, "compose/need")?;
        let own = vec![skin_tris, skin_uvs];
        let lookup = |name: &str| -> Option<Resource<'_>> {
            Some(match name {
                "keys" => Resource::Buffer(inputs.keys),
                "pos" => Resource::Buffer(inputs.positions),
                "skin_tris" => Resource::Buffer(&own[0]),
                "skin_uvs" => Resource::Buffer(&own[1]),
                "needed" => Resource::Buffer(&needed),
                "tiles" => Resource::Buffer(inputs.tiles),
                _ => return None,
            })
        };
        // Atomic ORs into the cleared bitmap: a read and a write.
        let rw = A::ComputeShaderReadOther | A::ComputeShaderWrite;
        let bind = pipeline.bind_from(lookup, &[("needed", rw)])?;
        Ok(NeedKernel {
            ctx,
            pipeline,
            bind,
            needed,
            tiles: inputs.tiles.clone(),
            own,
            size: prep.size,
            atlas: prep.atlas_size,
            skin_triangles: prep.skin_triangles,
        })
    }

    /// The bitmap (`kernels::sss::pack::needed_segment` numbers its bits), written by
    /// `compose need` each frame.
    pub fn needed(&self) -> &Buffer {
        &self.needed
    }

    fn clear_bytes(&self, _camera: &Camera) -> Result<Vec<u8>> {
        Ok(vec![0u8; self.needed.size() as usize])
    }

    fn need_push(&self, camera: &Camera) -> Result<Vec<u8>> {
        let b = camera.basis(self.size);
        let v4 = |v: glam::Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits(), 0];
        let mut words = Vec::with_capacity(20);
        words.extend(v4(camera.eye));
        words.extend(v4(b.forward));
        words.extend(v4(b.right * b.tan_x));
        words.extend(v4(b.up * b.tan_y));
        words.extend([self.size[0], self.size[1], self.atlas, self.skin_triangles]);
        Ok(words.iter().flat_map(|w| w.to_le_bytes()).collect())
    }
}

impl Kernel for NeedKernel {
    type Input = Camera;
    type Readback = NeedReadback;
    type Output = Vec<u32>;

    fn name(&self) -> &'static str {
        "compose need"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::upload(PASS_NEED_CLEAR, &self.needed, Self::clear_bytes),
            Pass::dispatch_indirect(
                PASS_NEED,
                &self.pipeline,
                &self.bind,
                IndirectArgs {
                    buffer: &self.tiles,
                    offset: 0,
                },
                Self::need_push,
            ),
        ]
    }

    fn check_input(&self, camera: &Camera) -> Result<()> {
        camera.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<NeedReadback> {
        Ok(NeedReadback(rec.read_back(&self.needed)?))
    }

    fn collect(&self, rb: &NeedReadback) -> Result<Vec<u32>> {
        rb.0.to_vec()
    }

    fn memory(&self) -> MemoryReport {
        let mut all: Vec<&Buffer> = vec![&self.needed];
        all.extend(self.own.iter());
        self.ctx.memory_of(&all)
    }
}

/// Resetting the list of tiles without a skin pixel, before [`PASS_CLASSIFY`] appends to it.
pub const PASS_PLAIN_RESET: &str = "compose plain tiles reset";
/// Resetting the list of tiles holding a skin pixel.
pub const PASS_SKIN_RESET: &str = "compose skin tiles reset";
/// The rasteriser's listed tiles split by whether they hold a skin pixel
/// (glsl/compose/classify.comp).
pub const PASS_CLASSIFY: &str = "compose classify";

/// The two lists [`TileClassKernel`] writes each frame. Each is a head, the indirect command
/// of one workgroup a tile followed by the entry count, `(count, 1, 1, count)` (as
/// [`crate::kernels::EMPTY_LIST_HEAD`] lays out every GPU-appended list), then `count` tile
/// entries `tx | ty << 16` (the rasteriser's, glsl/common/tiles.glsl) in no fixed order.
#[derive(Clone, Copy)]
pub struct TileClasses<'a> {
    /// The listed tiles without a skin pixel.
    pub plain: &'a Buffer,
    /// The listed tiles holding a skin pixel (a key naming a triangle below
    /// [`Prepared::skin_triangles`]).
    pub skin: &'a Buffer,
}

/// What [`TileClassKernel`] reads that other kernels write.
#[derive(Clone, Copy)]
pub struct TileClassInputs<'a> {
    /// The rasteriser's per-pixel (depth, triangle) keys, 8 bytes a pixel.
    pub keys: &'a Buffer,
    /// The rasteriser's list of covered tiles (`RasterKernel::tiles`), the list it splits.
    pub tiles: &'a Buffer,
}

/// The two lists, read back: tile entries `tx | ty << 16`, each list sorted.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileClassOutput {
    pub plain: Vec<u32>,
    pub skin: Vec<u32>,
}

/// A finished [`TileClassKernel`] readback.
pub struct TileClassReadback([Readback; 2]);

/// Pass `compose classify` (glsl/compose/classify.comp): each frame, the rasteriser's listed
/// tiles split into those holding a skin pixel and the others ([`TileClasses`]), so that
/// [`ComposeKernel`] runs the skin's shading only where a pixel needs it and [`NeedKernel`]
/// marks the atlas from the skin's tiles only (lavapipe runs a shader's skin path, masked,
/// at every pixel it is dispatched over). Recorded after the raster passes, before the
/// kernels that read the lists. The twin is [`super::cpu::tile_classes`].
pub struct TileClassKernel {
    ctx: Context,
    pipeline: ComputePipeline,
    bind: BindGroup,
    plain: Buffer,
    skin: Buffer,
    size: [u32; 2],
    skin_triangles: u32,
    /// Tiles in the image: the pass's grid, one invocation a tile.
    tiles: u32,
}

impl TileClassKernel {
    /// Creates the two lists (empty) and the pass for `prep`'s frame size and skin triangles,
    /// and records the lists' first reset.
    pub fn new(
        rec: &mut Recorder,
        prep: &Prepared,
        inputs: &TileClassInputs<'_>,
    ) -> Result<TileClassKernel> {
        let ctx = rec.context();
        check_keys(inputs.keys, prep.size)?;
        let tiles = tile_count(prep.size);
        let tiles_u32 = u32::try_from(tiles)
            .map_err(|_| Error::InvalidArgument(format!("compose classify: {tiles} tiles")))?;
        let bytes = tile_list_bytes(prep.size);
        if inputs.tiles.size() < bytes {
            return Err(too_small("the tile list", inputs.tiles.size(), bytes));
        }
        let list = |rec: &mut Recorder, name: &str| -> Result<Buffer> {
            let desc = BufferDesc::storage(bytes).usage(ash::vk::BufferUsageFlags::INDIRECT_BUFFER);
            let b = Buffer::new(&ctx, name, desc)?;
            rec.upload(&b, 0, &crate::kernels::EMPTY_LIST_HEAD)?;
            Ok(b)
        };
        let plain = list(rec, "compose plain tiles")?;
        let skin = list(rec, "compose skin tiles")?;
        let pipeline = crate::shaders::pipeline(&ctx, "compose/classify")?;
        let lookup = |name: &str| -> Option<Resource<'_>> {
            Some(match name {
                "keys" => Resource::Buffer(inputs.keys),
                "tiles" => Resource::Buffer(inputs.tiles),
                "plain" => Resource::Buffer(&plain),
                "skin" => Resource::Buffer(&skin),
                _ => return None,
            })
        };
        // Appended by atomics: a read and a write.
        let rw = A::ComputeShaderReadOther | A::ComputeShaderWrite;
        let bind = pipeline.bind_from(lookup, &[("plain", rw), ("skin", rw)])?;
        Ok(TileClassKernel {
            ctx,
            pipeline,
            bind,
            plain,
            skin,
            size: prep.size,
            skin_triangles: prep.skin_triangles,
            tiles: tiles_u32,
        })
    }

    /// The lists the pass writes, for [`Inputs::classes`] and [`NeedInputs::tiles`].
    pub fn classes(&self) -> TileClasses<'_> {
        TileClasses {
            plain: &self.plain,
            skin: &self.skin,
        }
    }

    fn classify_args(&self, _: &()) -> Result<Dispatch> {
        Ok(Dispatch {
            push: bytemuck::cast_slice(&[self.size[0], self.size[1], self.skin_triangles, 0])
                .to_vec(),
            grid: Grid::Invocations([self.tiles, 1, 1]),
        })
    }
}

impl Kernel for TileClassKernel {
    type Input = ();
    type Readback = TileClassReadback;
    type Output = TileClassOutput;

    fn name(&self) -> &'static str {
        "compose classify"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::list_reset(PASS_PLAIN_RESET, &self.plain),
            Pass::list_reset(PASS_SKIN_RESET, &self.skin),
            Pass::dispatch(
                PASS_CLASSIFY,
                &self.pipeline,
                &self.bind,
                Self::classify_args,
            ),
        ]
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<TileClassReadback> {
        Ok(TileClassReadback([
            rec.read_back(&self.plain)?,
            rec.read_back(&self.skin)?,
        ]))
    }

    fn collect(&self, rb: &TileClassReadback) -> Result<TileClassOutput> {
        let sorted = |r: &Readback, what: &str| -> Result<Vec<u32>> {
            let words: Vec<u32> = r.to_vec()?;
            let count = words.get(3).copied().unwrap_or(0) as usize;
            let mut v = crate::kernels::list_entries(&words, count, what)?.to_vec();
            v.sort_unstable();
            Ok(v)
        };
        Ok(TileClassOutput {
            plain: sorted(&rb.0[0], "compose plain tiles")?,
            skin: sorted(&rb.0[1], "compose skin tiles")?,
        })
    }

    fn memory(&self) -> MemoryReport {
        self.ctx.memory_of(&[&self.plain, &self.skin])
    }
}

/// Tiles of the rasteriser's tile grid for a `size` frame.
fn tile_count(size: [u32; 2]) -> u64 {
    let [tx, ty] = crate::kernels::raster::pack::tile_grid(size);
    tx as u64 * ty as u64
}

/// Bytes of a list holding every tile of a `size` frame: the four-word head, a word a tile.
fn tile_list_bytes(size: [u32; 2]) -> u64 {
    16 + tile_count(size) * 4
}
