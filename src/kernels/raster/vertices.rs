//! The vertices a frame must shade: every vertex of a triangle that covers a pixel of the
//! rasteriser's visibility buffer this frame, plus a static set given at creation (e.g. the
//! skin's vertices, which a texture-space pass reads wherever the camera looks). Per-vertex
//! passes whose results are read only at covered triangles (the environment's rays and
//! shadowing in the character frame) are then dispatched indirectly over the list instead
//! of over every vertex; their outputs at the other vertices keep an older frame's values.
//!
//! Two passes, recorded after the rasteriser's (they read its keys and tile list):
//! `vertex mark` (per pixel of the covered tiles: the key's triangle into a bitmap) and
//! `vertex list` (one workgroup: the marked triangles' vertices and the static set, as a
//! list headed by its own `VkDispatchIndirectCommand` of one 64-lane workgroup per 64
//! vertices). Both bitmaps are cleared by the pass that reads them, so no clear is recorded.
//! Another kernel's pass recorded before `vertex list` may mark more triangles in the same
//! bitmap ([`VertexListKernel::covered`]; the character frame's SSS reach marks the skin
//! triangles whose texture-space irradiance its diffusion reads).
//! With a subset set ([`VertexListKernel::set_subset`], e.g. the cloth's vertices), the list
//! pass also writes a second list: the vertices of covered triangles in that subset
//! ([`VertexListKernel::subset_list`]), for a pass that reads them only at covered
//! triangles.
//! The twin is [`covered_vertices`] (of the subset's list: with nothing `always`,
//! intersected with the subset).

use super::gpu::RasterKernel;
use crate::error::{Error, Result};
use crate::gpu::{
    BindGroup, Buffer, BufferDesc, ComputePipeline, Context, MemoryReport, Readback, Recorder,
    Resource,
};
use crate::kernels::{Dispatch, Grid, IndirectArgs, Kernel, Pass};
use ash::vk;

/// Label of the pass marking the covered triangles.
pub const PASS_MARK: &str = "vertex mark";
/// Label of the pass writing the vertex list.
pub const PASS_LIST: &str = "vertex list";

/// Lanes of a workgroup of a pass dispatched over the list (the command's group count is
/// ceil(count / LIST_GROUP)).
pub const LIST_GROUP: u32 = 64;

/// Builds, each frame, the list of the vertices of the rasteriser's covered triangles and a
/// static set ([`VertexListKernel::list`]).
pub struct VertexListKernel {
    ctx: Context,
    mark: (ComputePipeline, BindGroup),
    list_pass: (ComputePipeline, BindGroup),
    tiles: Buffer,
    covered: Buffer,
    marked: Buffer,
    always: Buffer,
    order: Buffer,
    rank: Buffer,
    list: Buffer,
    /// The rank of each vertex (host copy of `rank`).
    rank_host: Vec<u32>,
    /// The subset's mask (by rank) and its list.
    subset: Buffer,
    sub_list: Buffer,
    size: [u32; 2],
    triangle_count: u32,
    vertex_count: u32,
}

/// A finished [`VertexListKernel`] readback.
pub struct VertexListReadback(Readback);

impl VertexListKernel {
    /// Creates the bitmaps, the list and both passes over `raster`'s outputs (which must
    /// have a tile list, `Tiling::Tiles`) for a mesh of `vertex_count` vertices, with the
    /// vertices `always` listed every frame; records the initial clears into `rec`. The list
    /// holds its vertices in the order of `order` (a permutation of the vertex ids, e.g.
    /// [`crate::geom::spatial_order`] of the rest positions, so that the lanes of a pass over
    /// the list are neighbours), or by id without one. Refuses a rasteriser without a tile
    /// list, a vertex id of `always` or of a triangle at or above `vertex_count`, an `order`
    /// that is not a permutation of `0..vertex_count`.
    pub fn new(
        rec: &mut Recorder,
        raster: &RasterKernel,
        triangles: &[[u32; 3]],
        vertex_count: u32,
        always: &[u32],
        order: Option<&[u32]>,
    ) -> Result<VertexListKernel> {
        let ctx = rec.context();
        let tiles = raster.tiles().ok_or_else(|| {
            Error::InvalidArgument(
                "vertex list: the rasteriser has no tile list (Tiling::Full)".into(),
            )
        })?;
        if triangles.len() != raster.triangle_count() as usize {
            return Err(Error::InvalidArgument(format!(
                "vertex list: {} triangles given, the rasteriser has {}",
                triangles.len(),
                raster.triangle_count()
            )));
        }
        let mut named = triangles.iter().flatten().chain(always);
        if let Some(&v) = named.find(|&&v| v >= vertex_count) {
            return Err(Error::InvalidArgument(format!(
                "vertex list: vertex {v} named, the mesh has {vertex_count}"
            )));
        }
        let order: Vec<u32> = match order {
            Some(o) => o.to_vec(),
            None => (0..vertex_count).collect(),
        };
        let mut rank = vec![u32::MAX; vertex_count as usize];
        let permutation = order.len() == vertex_count as usize
            && order.iter().enumerate().all(|(r, &v)| {
                rank.get_mut(v as usize)
                    .is_some_and(|slot| std::mem::replace(slot, r as u32) == u32::MAX)
            });
        if !permutation {
            return Err(Error::InvalidArgument(format!(
                "vertex list: the order ({} ids) is not a permutation of the mesh's \
                 {vertex_count} vertices",
                order.len()
            )));
        }
        let words = |n: u32| u64::from(n.div_ceil(32).max(1));
        let storage = |name: &str, w: u64| Buffer::new(&ctx, name, BufferDesc::storage(w * 4));
        let covered = storage(
            "vertex list covered triangles",
            words(raster.triangle_count()),
        )?;
        let marked = storage("vertex list marked vertices", words(vertex_count))?;
        // The bitmaps are indexed by rank (a vertex's place in `order`); `always` was
        // checked against the vertex count above.
        let mask = rank_mask(&rank, always)?;
        let order_buf = rec.buffer_with(
            "vertex list order",
            BufferDesc::storage(u64::from(vertex_count.max(1)) * 4),
            &order[..],
        )?;
        let rank_buf = rec.buffer_with(
            "vertex list rank",
            BufferDesc::storage(u64::from(vertex_count.max(1)) * 4),
            &rank[..],
        )?;
        let always_buf = rec.buffer_with(
            "vertex list always",
            BufferDesc::storage(mask.len() as u64 * 4),
            &mask[..],
        )?;
        let list_buffer = |name: &str| {
            Buffer::new(
                &ctx,
                name,
                BufferDesc::storage(16 + u64::from(vertex_count.max(1)) * 4).usage(
                    vk::BufferUsageFlags::INDIRECT_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC,
                ),
            )
        };
        let list = list_buffer("vertex list")?;
        let sub_list = list_buffer("vertex list subset")?;
        let subset = storage("vertex list subset mask", words(vertex_count))?;
        // Every frame starts from empty bitmaps (the list pass leaves them so); no subset.
        rec.fill_buffer(&covered, 0)?;
        rec.fill_buffer(&marked, 0)?;
        rec.fill_buffer(&subset, 0)?;
        rec.upload(&list, 0, &crate::kernels::EMPTY_LIST_HEAD)?;
        rec.upload(&sub_list, 0, &crate::kernels::EMPTY_LIST_HEAD)?;
        let p = crate::shaders::pipeline(&ctx, "raster/vertex_mark")?;
        let b = p.bind(&[
            ("keys", Resource::Buffer(raster.keys())),
            ("tiles", Resource::Buffer(tiles)),
            ("covered", Resource::Buffer(&covered)),
        ])?;
        let mark = (p, b);
        let p = crate::shaders::pipeline(&ctx, "raster/vertex_list")?;
        let b = p.bind(&[
            ("covered", Resource::Buffer(&covered)),
            ("triangles", Resource::Buffer(raster.triangles())),
            ("marked", Resource::Buffer(&marked)),
            ("always", Resource::Buffer(&always_buf)),
            ("listed", Resource::Buffer(&list)),
            ("order", Resource::Buffer(&order_buf)),
            ("rank", Resource::Buffer(&rank_buf)),
            ("subset", Resource::Buffer(&subset)),
            ("sub_listed", Resource::Buffer(&sub_list)),
        ])?;
        Ok(VertexListKernel {
            ctx,
            mark,
            list_pass: (p, b),
            tiles: tiles.clone(),
            covered,
            marked,
            always: always_buf,
            order: order_buf,
            rank: rank_buf,
            list,
            rank_host: rank,
            subset,
            sub_list,
            size: raster.size(),
            triangle_count: raster.triangle_count(),
            vertex_count,
        })
    }

    /// The list, written by `vertex list` each frame: u32 words `(ceil(count / 64), 1, 1,
    /// count)` (a `VkDispatchIndirectCommand` at offset 0 of [`LIST_GROUP`]-lane
    /// workgroups, and the count), then `count` distinct vertex ids in no particular order.
    /// INDIRECT_BUFFER usage.
    pub fn list(&self) -> &Buffer {
        &self.list
    }

    /// The bitmap of this frame's covered triangles (bit t % 32 of u32 word t / 32) that
    /// `vertex mark` writes and `vertex list` reads and clears: a pass recorded between the
    /// two may mark more triangles (atomically), whose vertices are then listed too (the
    /// SSS reach marks the skin triangles its irradiance needs: `SssKernel::set_reach`).
    pub fn covered(&self) -> &Buffer {
        &self.covered
    }

    /// Sets the subset whose covered vertices the list pass also lists
    /// ([`VertexListKernel::subset_list`]), for the frames recorded after `rec`: vertex ids
    /// below the mesh's vertex count (refused otherwise), in any order, repeats allowed;
    /// empty for none.
    pub fn set_subset(&mut self, rec: &mut Recorder, subset: &[u32]) -> Result<()> {
        rec.upload(&self.subset, 0, &rank_mask(&self.rank_host, subset)?)
    }

    /// The subset's list ([`VertexListKernel::set_subset`]), written by `vertex list` each
    /// frame in the layout of [`VertexListKernel::list`]: the vertices of the triangles
    /// covering a pixel that the subset holds. INDIRECT_BUFFER usage.
    pub fn subset_list(&self) -> &Buffer {
        &self.sub_list
    }

    /// Records the readback of the subset's list ([`Kernel::collect`] reads it as the
    /// list's: its ids, sorted).
    pub fn read_back_subset(&self, rec: &mut Recorder) -> Result<VertexListReadback> {
        Ok(VertexListReadback(rec.read_back(&self.sub_list)?))
    }

    /// Vertices of the mesh.
    pub fn vertex_count(&self) -> u32 {
        self.vertex_count
    }

    fn mark_push(&self, _: &()) -> Result<Vec<u8>> {
        let [w, h] = self.size;
        let words = [w, h, self.triangle_count, 0];
        Ok(words.iter().flat_map(|x| x.to_le_bytes()).collect())
    }

    fn list_args(&self, _: &()) -> Result<Dispatch> {
        Ok(Dispatch::words(
            &[self.triangle_count, self.vertex_count],
            Grid::Groups([1, 1, 1]),
        ))
    }
}

impl Kernel for VertexListKernel {
    type Input = ();
    type Readback = VertexListReadback;
    type Output = Vec<u32>;

    fn name(&self) -> &'static str {
        "vertex list"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::dispatch_indirect(
                PASS_MARK,
                &self.mark.0,
                &self.mark.1,
                IndirectArgs {
                    buffer: &self.tiles,
                    offset: 0,
                },
                Self::mark_push,
            ),
            Pass::dispatch(
                PASS_LIST,
                &self.list_pass.0,
                &self.list_pass.1,
                Self::list_args,
            ),
        ]
    }

    fn check_input(&self, _: &()) -> Result<()> {
        Ok(())
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<VertexListReadback> {
        Ok(VertexListReadback(rec.read_back(&self.list)?))
    }

    /// The listed vertex ids, sorted.
    fn collect(&self, rb: &VertexListReadback) -> Result<Vec<u32>> {
        let words: Vec<u32> = rb.0.to_vec()?;
        let count = words.get(3).copied().unwrap_or(0) as usize;
        let mut ids = crate::kernels::list_entries(&words, count, "vertex list")?.to_vec();
        ids.sort_unstable();
        Ok(ids)
    }

    fn memory(&self) -> MemoryReport {
        self.ctx.memory_of(&[
            &self.covered,
            &self.marked,
            &self.always,
            &self.order,
            &self.rank,
            &self.list,
            &self.subset,
            &self.sub_list,
        ])
    }
}

/// The bitmap (bit r % 32 of word r / 32, at least one word) of the ranks of `ids`
/// (`rank[v]`: vertex v's place in the list's order); refuses an id past `rank`.
fn rank_mask(rank: &[u32], ids: &[u32]) -> Result<Vec<u32>> {
    let mut mask = vec![0u32; rank.len().div_ceil(32).max(1)];
    for &v in ids {
        let r = *rank.get(v as usize).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "vertex list: vertex {v} named, the mesh has {}",
                rank.len()
            ))
        })?;
        mask[r as usize / 32] |= 1 << (r % 32);
    }
    Ok(mask)
}

/// The twin of one frame's list: the sorted distinct vertices of the triangles named by the
/// keys ([`key_triangle`](super::pack::key_triangle) below the triangle count; an empty key
/// names none) and of
/// `always`.
pub fn covered_vertices(keys: &[u64], triangles: &[[u32; 3]], always: &[u32]) -> Vec<u32> {
    let mut v: Vec<u32> = keys
        .iter()
        .filter_map(|&k| triangles.get(super::pack::key_triangle(k) as usize))
        .flatten()
        .chain(always)
        .copied()
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}
