//! The rasteriser on the GPU: static triangles and UVs uploaded once, the posed buffers
//! bound as they are (any buffers of the pose layout: vec4 per vertex), a visibility buffer
//! of 64-bit keys, the visibility pass's counters and the G-buffer image (three RGBA32F
//! layers, storage for the resolve pass and sampled for the BTF pass).
//!
//! [`Tiling::Tiles`] (the default): the work after the visibility pass is done only where
//! the mesh is. The visibility pass flags every 16 x 4 tile ([`TILE`]) holding a covered
//! pixel; `raster tiles` lists those tiles, followed by the tiles covered last frame and not
//! this one, in a buffer that is also the `VkDispatchIndirectCommand` of `raster resolve`
//! (and of a BTF pass shading the G-buffer: [`RasterKernel::tiles`]); `raster clear` resets
//! only the keys of last frame's covered tiles. Pixels outside every listed tile hold what
//! the kernel's creation cleared them to (empty keys, G-buffer tag 0), so the outputs are
//! those of [`Tiling::Full`], which clears and resolves every pixel, bit for bit.

pub use super::pack::{Camera, Counters, Prepared, TILE, counter, key_triangle, tile_grid};

use super::pack::{resolve_push_mode, visibility_push};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};
use crate::scene::gbuffer::GBuffer;
use ash::vk;

/// Label of the pass clearing the visibility buffer and counters.
pub const PASS_CLEAR: &str = "raster clear";
/// Label of the per-triangle visibility pass.
pub const PASS_VISIBILITY: &str = "raster visibility";
/// Label of the pass listing the tiles the frame covers ([`Tiling::Tiles`] only).
pub const PASS_TILES: &str = "raster tiles";
/// Label of the per-pixel resolve pass writing the G-buffer.
pub const PASS_RESOLVE: &str = "raster resolve";
/// Workgroups of `raster clear` walking the previous frame's tile list.
const CLEAR_GROUPS: u32 = 16;

/// Where the passes after the visibility pass work.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tiling {
    /// Only on the tiles the mesh covers (this frame's and last frame's), dispatched
    /// indirectly over the tile list the GPU writes.
    Tiles,
    /// On every pixel of the image.
    Full,
}

/// The tile list of one frame, read back: tile indices `ty * tiles_x + tx` ([`tile_grid`]; the
/// GPU's list holds `tx | ty << 16`, converted here).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileList {
    /// Tiles holding a covered pixel this frame (sorted).
    pub covered: Vec<u32>,
    /// Tiles covered last frame and not this one, whose pixels this frame made empty
    /// (sorted).
    pub stale: Vec<u32>,
}

/// The posed geometry the rasteriser reads: vec4 per vertex, in the mesh's vertex order
/// (positions w = 1, unit normals w = 0, unit tangents along +u with w = handedness).
pub struct Posed<'a> {
    /// Posed positions.
    pub positions: &'a Buffer,
    /// Posed unit normals.
    pub normals: &'a Buffer,
    /// Posed unit tangents, w = handedness (bitangent = w * cross(normal, tangent)).
    pub tangents: &'a Buffer,
}

/// Host copies of one frame: the G-buffer, the visibility keys and the counters.
pub struct RasterOutput {
    /// The G-buffer as the resolve pass wrote it (all zeros at empty pixels, whose second
    /// and third layers the GPU leaves unwritten).
    pub gbuffer: GBuffer,
    /// Per pixel: (depth bits << 32) | triangle, or `u64::MAX` where nothing is covered.
    pub keys: Vec<u64>,
    /// The visibility pass's counters ([`counter`]).
    pub counters: Counters,
    /// The frame's tile list ([`Tiling::Tiles`]; `None` for [`Tiling::Full`]).
    pub tiles: Option<TileList>,
}

impl RasterOutput {
    /// The triangle and view depth of pixel `k`, if covered.
    pub fn hit(&self, k: usize) -> Option<(u32, f32)> {
        let key = self.keys[k];
        (key != u64::MAX).then(|| (key_triangle(key), f32::from_bits((key >> 32) as u32)))
    }
}

/// The readbacks of one frame.
pub struct RasterReadback {
    gbuffer: Readback,
    keys: Readback,
    counters: Readback,
    tiles: Option<Readback>,
}

/// The GPU kernel. Input: the frame's camera.
pub struct RasterKernel {
    ctx: Context,
    clear: (ComputePipeline, BindGroup),
    visibility: (ComputePipeline, BindGroup),
    resolve: (ComputePipeline, BindGroup),
    list: (ComputePipeline, BindGroup),
    triangles: Buffer,
    uvs: Buffer,
    keys: Buffer,
    counters: Buffer,
    /// One word per tile: set by the visibility pass where a pixel is covered.
    flags: Buffer,
    /// (length, 1, 1, covered) then the list, then as many words of scratch.
    tiles: Buffer,
    gbuffer: Image,
    size: [u32; 2],
    triangle_count: u32,
    row: u32,
    uv_scale: f32,
    tiling: Tiling,
}

/// Checks that `ctx` has 64-bit buffer atomics enabled, naming the feature if not.
pub fn check_device(ctx: &Context) -> Result<()> {
    if ctx.features().buffer_int64_atomics {
        return Ok(());
    }
    let supported = ctx.info().features.buffer_int64_atomics;
    Err(Error::Unsupported {
        device: ctx.info().name.clone(),
        what: if supported {
            "the compute rasteriser without shaderInt64 + shaderBufferInt64Atomics enabled: \
             create the context with Features { buffer_int64_atomics: true, .. }"
                .into()
        } else {
            "shaderInt64 + shaderBufferInt64Atomics (64-bit atomics on storage buffers), \
             which the compute rasteriser's depth + triangle keys need"
                .into()
        },
    })
}

impl RasterKernel {
    /// Uploads `prep`'s triangles and UVs (recorded into `rec`), creates the visibility
    /// buffer, counters and G-buffer, and binds `posed` (whose vertex count must be
    /// `prep.vertex_count`). The passes after the visibility pass work on the tiles the
    /// mesh covers ([`Tiling::Tiles`]).
    pub fn new(rec: &mut Recorder, prep: &Prepared, posed: &Posed<'_>) -> Result<RasterKernel> {
        Self::with_tiling(rec, prep, posed, Tiling::Tiles)
    }

    /// As [`RasterKernel::new`], choosing where the passes after the visibility pass work.
    /// The initial clears of the visibility buffer, tile flags, tile list and G-buffer
    /// are recorded into `rec`.
    pub fn with_tiling(
        rec: &mut Recorder,
        prep: &Prepared,
        posed: &Posed<'_>,
        tiling: Tiling,
    ) -> Result<RasterKernel> {
        let ctx = rec.context();
        check_device(&ctx)?;
        let verts = prep.vertex_count as u64 * 16;
        for b in [posed.positions, posed.normals, posed.tangents] {
            if b.size() < verts {
                return Err(Error::InvalidArgument(format!(
                    "posed buffer '{}' holds {} bytes, {} vertices need {verts}",
                    b.name(),
                    b.size(),
                    prep.vertex_count
                )));
            }
        }
        // The fields are public: every length the shaders index with is checked here.
        if prep.uvs.len() != prep.vertex_count {
            return Err(Error::InvalidArgument(format!(
                "{} uvs for {} vertices",
                prep.uvs.len(),
                prep.vertex_count
            )));
        }
        if prep.row == 0 {
            return Err(Error::InvalidArgument(
                "the visibility grid's row must hold at least one triangle".into(),
            ));
        }
        if let Some(bad) = prep
            .triangles
            .iter()
            .flat_map(|t| &t[..3])
            .find(|&&i| i as usize >= prep.vertex_count)
        {
            return Err(Error::InvalidArgument(format!(
                "triangle index {bad} out of range ({} vertices)",
                prep.vertex_count
            )));
        }
        let [w, h] = prep.size;
        let l = ctx.limits();
        if w.max(h) > l.max_image_dimension_2d {
            return Err(Error::Limit {
                what: "raster G-buffer side".into(),
                requested: w.max(h) as u64,
                limit_name: "maxImageDimension2D",
                limit: l.max_image_dimension_2d as u64,
            });
        }
        let triangles = rec.buffer_with(
            "raster triangles",
            BufferDesc::storage(prep.triangles.len() as u64 * 16),
            &prep.triangles,
        )?;
        let uvs = rec.buffer_with(
            "raster uvs",
            BufferDesc::storage(prep.uvs.len().max(1) as u64 * 8),
            &prep.uvs,
        )?;
        let pixels = w as u64 * h as u64;
        let keys = Buffer::new(&ctx, "raster visibility", BufferDesc::storage(pixels * 8))?;
        let counters = Buffer::new(&ctx, "raster counters", BufferDesc::storage(32))?;
        let [tx, ty] = tile_grid(prep.size);
        let n_tiles = tx as u64 * ty as u64;
        let flags = Buffer::new(&ctx, "raster tile flags", BufferDesc::storage(n_tiles * 4))?;
        let tiles = Buffer::new(
            &ctx,
            "raster tiles",
            BufferDesc::storage(16 + n_tiles * 8).usage(vk::BufferUsageFlags::INDIRECT_BUFFER),
        )?;
        let gb_desc = ImageDesc::d2_array(vk::Format::R32G32B32A32_SFLOAT, [w, h], 3)
            .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST);
        let gbuffer = Image::new(&ctx, "raster gbuffer", gb_desc)?;
        // The state every frame starts from outside the previous frame's tiles: no key, no
        // flag, an empty list, an empty G-buffer.
        rec.fill_buffer(&keys, u32::MAX)?;
        rec.fill_buffer(&flags, 0)?;
        rec.upload(&tiles, 0, &crate::kernels::EMPTY_LIST_HEAD)?;
        rec.clear_image(&gbuffer, gbuffer.all(), [0.0; 4])?;

        let write = AccessSet::from(A::ComputeShaderWrite);
        let p = crate::shaders::pipeline(&ctx, "raster/clear")?;
        let b = p.bind_declared(
            &[
                ("vis", Resource::Buffer(&keys)),
                ("counters", Resource::Buffer(&counters)),
                ("tiles", Resource::Buffer(&tiles)),
            ],
            &[("vis", write), ("counters", write)],
        )?;
        let clear = (p, b);
        let p = crate::shaders::pipeline(&ctx, "raster/visibility")?;
        let b = p.bind(&[
            ("pos", Resource::Buffer(posed.positions)),
            ("tris", Resource::Buffer(&triangles)),
            ("vis", Resource::Buffer(&keys)),
            ("counters", Resource::Buffer(&counters)),
            ("flags", Resource::Buffer(&flags)),
        ])?;
        let visibility = (p, b);
        let p = crate::shaders::pipeline(&ctx, "raster/tiles")?;
        let b = p.bind(&[
            ("flags", Resource::Buffer(&flags)),
            ("tiles", Resource::Buffer(&tiles)),
        ])?;
        let list = (p, b);
        let p = crate::shaders::pipeline(&ctx, "raster/resolve")?;
        let b = p.bind_declared(
            &[
                ("pos", Resource::Buffer(posed.positions)),
                ("nrm", Resource::Buffer(posed.normals)),
                ("tan", Resource::Buffer(posed.tangents)),
                ("uvs", Resource::Buffer(&uvs)),
                ("tris", Resource::Buffer(&triangles)),
                ("vis", Resource::Buffer(&keys)),
                ("gbuffer", Resource::storage_image(&gbuffer)),
                ("tiles", Resource::Buffer(&tiles)),
            ],
            &[("gbuffer", write)],
        )?;
        let resolve = (p, b);
        Ok(RasterKernel {
            ctx,
            clear,
            visibility,
            resolve,
            list,
            triangles,
            uvs,
            keys,
            counters,
            flags,
            tiles,
            gbuffer,
            size: prep.size,
            triangle_count: prep.triangles.len() as u32,
            row: prep.row,
            uv_scale: prep.uv_scale,
            tiling,
        })
    }

    /// Where the passes after the visibility pass work.
    pub fn tiling(&self) -> Tiling {
        self.tiling
    }

    /// The tile list `raster tiles` writes each frame ([`Tiling::Tiles`]; `None` for
    /// [`Tiling::Full`]), for a pass shading the G-buffer over the same tiles. u32 words:
    /// `(length, 1, 1, covered)` (a `VkDispatchIndirectCommand` at offset 0: one workgroup
    /// per listed tile), then `length` tile entries `tx | ty << 16` of [`TILE`]-sized tiles
    /// ([`tile_grid`]; a pass finds a tile's pixels without dividing by the tiles a row,
    /// glsl/common/tiles.glsl): first the tiles covered this frame, then those covered only
    /// last frame (empty in this frame's G-buffer). A pass shading every listed tile each
    /// frame keeps empty pixels empty everywhere, provided it starts from an all-empty
    /// output. INDIRECT_BUFFER usage.
    pub fn tiles(&self) -> Option<&Buffer> {
        (self.tiling == Tiling::Tiles).then_some(&self.tiles)
    }

    /// The G-buffer image the resolve pass writes (bind it as a texture to shade it).
    pub fn gbuffer(&self) -> &Image {
        &self.gbuffer
    }

    /// The triangles (uvec4 per triangle: vertex ids, part id), as uploaded from
    /// [`Prepared::triangles`](super::pack::Prepared::triangles).
    pub fn triangles(&self) -> &Buffer {
        &self.triangles
    }

    /// The visibility buffer (one u64 key per pixel).
    pub fn keys(&self) -> &Buffer {
        &self.keys
    }

    /// Image width and height.
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    /// Triangles rasterised per frame.
    pub fn triangle_count(&self) -> u32 {
        self.triangle_count
    }

    fn visibility_grid(&self) -> [u32; 3] {
        let row = self.row.min(self.triangle_count);
        [row, self.triangle_count.div_ceil(row), 1]
    }
}

impl Kernel for RasterKernel {
    type Input = Camera;
    type Readback = RasterReadback;
    type Output = RasterOutput;

    fn name(&self) -> &'static str {
        "raster"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let (cp, cb) = (&self.clear.0, &self.clear.1);
        let (vp, vb) = (&self.visibility.0, &self.visibility.1);
        let (rp, rb) = (&self.resolve.0, &self.resolve.1);
        let (tp, tb) = (&self.list.0, &self.list.1);
        let clear = Pass::dispatch(PASS_CLEAR, cp, cb, |k: &Self, _| {
            let [w, h] = k.size;
            Ok(match k.tiling {
                // One invocation per pixel on a 2D grid (a 1D one would pass the 65535
                // workgroups Vulkan guarantees at 2048^2).
                Tiling::Full => Dispatch::words(&[w, h, 0, 0], Grid::Invocations([w, h, 1])),
                // A few workgroups walking last frame's covered tiles.
                Tiling::Tiles => {
                    Dispatch::words(&[w, h, 1, CLEAR_GROUPS], Grid::Groups([CLEAR_GROUPS, 1, 1]))
                }
            })
        });
        let visibility = Pass::dispatch(PASS_VISIBILITY, vp, vb, |k: &Self, cam| {
            let grid = k.visibility_grid();
            Ok(Dispatch {
                push: visibility_push(cam, k.size, k.triangle_count, grid[0]),
                grid: Grid::Invocations(grid),
            })
        });
        match self.tiling {
            Tiling::Full => vec![
                clear,
                visibility,
                Pass::dispatch(PASS_RESOLVE, rp, rb, |k, cam| {
                    Ok(Dispatch {
                        push: resolve_push_mode(cam, k.size, k.uv_scale, false),
                        grid: Grid::Invocations([k.size[0], k.size[1], 1]),
                    })
                }),
            ],
            Tiling::Tiles => vec![
                clear,
                visibility,
                Pass::dispatch(PASS_TILES, tp, tb, |k, _| {
                    let [w, h] = k.size;
                    let [tx, ty] = tile_grid(k.size);
                    Ok(Dispatch::words(&[w, h, tx, ty], Grid::Groups([1, 1, 1])))
                }),
                Pass::dispatch_indirect(
                    PASS_RESOLVE,
                    rp,
                    rb,
                    IndirectArgs {
                        buffer: &self.tiles,
                        offset: 0,
                    },
                    |k, cam| Ok(resolve_push_mode(cam, k.size, k.uv_scale, true)),
                ),
            ],
        }
    }

    fn check_input(&self, camera: &Camera) -> Result<()> {
        camera.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<RasterReadback> {
        Ok(RasterReadback {
            gbuffer: rec.read_back_image(&self.gbuffer, ImageRegion::whole(self.gbuffer.desc()))?,
            keys: rec.read_back(&self.keys)?,
            counters: rec.read_back(&self.counters)?,
            tiles: match self.tiling {
                Tiling::Tiles => Some(rec.read_back(&self.tiles)?),
                Tiling::Full => None,
            },
        })
    }

    fn collect(&self, rb: &RasterReadback) -> Result<RasterOutput> {
        let layers: Vec<[f32; 4]> = rb.gbuffer.to_vec()?;
        let n = (self.size[0] * self.size[1]) as usize;
        // The resolve pass writes only the first layer of an empty pixel (tag 0); the host
        // copy holds zeros there, as the CPU G-buffers do.
        let texels = (0..n)
            .flat_map(|k| {
                if layers[k][3] == 0.0 {
                    [[0.0; 4]; 3]
                } else {
                    [layers[k], layers[n + k], layers[2 * n + k]]
                }
            })
            .collect();
        let c: Vec<u32> = rb.counters.to_vec()?;
        let mut counters = [0u32; 8];
        counters.copy_from_slice(&c[..8]);
        Ok(RasterOutput {
            gbuffer: GBuffer {
                width: self.size[0],
                height: self.size[1],
                texels,
            },
            keys: rb.keys.to_vec()?,
            counters,
            tiles: (rb.tiles.as_ref())
                .map(|t| tile_list(t, tile_grid(self.size)[0]))
                .transpose()?,
        })
    }

    fn memory(&self) -> MemoryReport {
        let buffers = [
            &self.triangles,
            &self.uvs,
            &self.keys,
            &self.counters,
            &self.flags,
            &self.tiles,
        ];
        self.ctx.memory_of_resources(
            buffers
                .into_iter()
                .map(Resource::Buffer)
                .chain([Resource::texture(&self.gbuffer)]),
        )
    }
}

/// The covered and stale parts of a read-back tile list, each sorted, as tile indices
/// `ty * tiles_x + tx` (the list holds `tx | ty << 16`).
fn tile_list(rb: &Readback, tiles_x: u32) -> Result<TileList> {
    let words: Vec<u32> = rb.to_vec()?;
    // One workgroup a tile: the length is the head's workgroup count; word 3 the covered.
    let (len, covered) = (words[0] as usize, words[3] as usize);
    let list = crate::kernels::list_entries(&words, len, "raster tiles")?;
    let index = |e: &u32| (e >> 16) * tiles_x + (e & 0xffff);
    let (mut c, mut s): (Vec<u32>, Vec<u32>) = (
        list[..covered.min(len)].iter().map(index).collect(),
        list[covered.min(len)..].iter().map(index).collect(),
    );
    c.sort_unstable();
    s.sort_unstable();
    Ok(TileList {
        covered: c,
        stale: s,
    })
}
