//! The rasteriser on the GPU: static triangles and UVs uploaded once, the posed buffers
//! bound as they are (any buffers of the pose layout: vec4 per vertex), a visibility buffer
//! of 64-bit keys, the visibility pass's counters and the G-buffer image (three RGBA32F
//! layers, storage for the resolve pass and sampled for the BTF pass).

pub use super::pack::{Camera, Counters, Prepared, counter};

use super::pack::{resolve_push, visibility_push};
use crate::error::{Error, Result};
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use crate::scene::gbuffer::GBuffer;
use ash::vk;

/// Label of the pass clearing the visibility buffer and counters.
pub const PASS_CLEAR: &str = "raster clear";
/// Label of the per-triangle visibility pass.
pub const PASS_VISIBILITY: &str = "raster visibility";
/// Label of the per-pixel resolve pass writing the G-buffer.
pub const PASS_RESOLVE: &str = "raster resolve";

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
}

impl RasterOutput {
    /// The triangle and view depth of pixel `k`, if covered.
    pub fn hit(&self, k: usize) -> Option<(u32, f32)> {
        let key = self.keys[k];
        (key != u64::MAX).then(|| (key as u32, f32::from_bits((key >> 32) as u32)))
    }
}

/// The readbacks of one frame.
pub struct RasterReadback {
    gbuffer: Readback,
    keys: Readback,
    counters: Readback,
}

/// The GPU kernel. Input: the frame's camera.
pub struct RasterKernel {
    ctx: Context,
    clear: (ComputePipeline, BindGroup),
    visibility: (ComputePipeline, BindGroup),
    resolve: (ComputePipeline, BindGroup),
    triangles: Buffer,
    uvs: Buffer,
    keys: Buffer,
    counters: Buffer,
    gbuffer: Image,
    size: [u32; 2],
    triangle_count: u32,
    row: u32,
    uv_scale: f32,
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
    /// `prep.vertex_count`).
    pub fn new(rec: &mut Recorder, prep: &Prepared, posed: &Posed<'_>) -> Result<RasterKernel> {
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
        let gb_desc = ImageDesc::d2_array(vk::Format::R32G32B32A32_SFLOAT, [w, h], 3)
            .usage(vk::ImageUsageFlags::STORAGE);
        let gbuffer = Image::new(&ctx, "raster gbuffer", gb_desc)?;

        let write = AccessSet::from(A::ComputeShaderWrite);
        let p = crate::shaders::pipeline(&ctx, "raster/clear")?;
        let b = p.bind_declared(
            &[
                ("vis", Resource::Buffer(&keys)),
                ("counters", Resource::Buffer(&counters)),
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
        ])?;
        let visibility = (p, b);
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
            ],
            &[("gbuffer", write)],
        )?;
        let resolve = (p, b);
        Ok(RasterKernel {
            ctx,
            clear,
            visibility,
            resolve,
            triangles,
            uvs,
            keys,
            counters,
            gbuffer,
            size: prep.size,
            triangle_count: prep.triangles.len() as u32,
            row: prep.row,
            uv_scale: prep.uv_scale,
        })
    }

    /// The G-buffer image the resolve pass writes (bind it as a texture to shade it).
    pub fn gbuffer(&self) -> &Image {
        &self.gbuffer
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
        vec![
            Pass::dispatch(PASS_CLEAR, cp, cb, |k, _| {
                // One invocation per pixel on a 2D grid (a 1D one would pass the 65535
                // workgroups Vulkan guarantees at 2048^2); row 0 also clears the counters.
                let [w, h] = k.size;
                Ok(Dispatch::words(
                    &[w, h],
                    Grid::Invocations([w.max(8), h, 1]),
                ))
            }),
            Pass::dispatch(PASS_VISIBILITY, vp, vb, |k, cam| {
                let grid = k.visibility_grid();
                Ok(Dispatch {
                    push: visibility_push(cam, k.size, k.triangle_count, grid[0]),
                    grid: Grid::Invocations(grid),
                })
            }),
            Pass::dispatch(PASS_RESOLVE, rp, rb, |k, cam| {
                Ok(Dispatch {
                    push: resolve_push(cam, k.size, k.uv_scale),
                    grid: Grid::Invocations([k.size[0], k.size[1], 1]),
                })
            }),
        ]
    }

    fn check_input(&self, camera: &Camera) -> Result<()> {
        camera.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<RasterReadback> {
        Ok(RasterReadback {
            gbuffer: rec.read_back_image(&self.gbuffer, ImageRegion::whole(self.gbuffer.desc()))?,
            keys: rec.read_back(&self.keys)?,
            counters: rec.read_back(&self.counters)?,
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
        })
    }

    fn memory(&self) -> MemoryReport {
        let buffers = [&self.triangles, &self.uvs, &self.keys, &self.counters];
        self.ctx.memory_of_resources(
            buffers
                .into_iter()
                .map(Resource::Buffer)
                .chain([Resource::texture(&self.gbuffer)]),
        )
    }
}
