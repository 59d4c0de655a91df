//! What the SSS kernel uploads, packed and checked on the CPU (no Vulkan here): per texel the
//! geometry and where the diffusion starts, per vertex its frame, the BVH, the surface walk's
//! records, the contact entries, the occupied tiles ([`Packed`]); the room the kernel makes
//! for them ([`Room`]); the shared sample pattern ([`Pattern`]) and the push constants
//! ([`Settings`]). The GPU wrapper (`gpu.rs`) creates its images and buffers from these and
//! records their uploads; a later pose of the mesh is packed the same way ([`Room::pack`]).

use super::contact::Contact;
use super::cpu::{
    DiffusionGeometry, SamplerParams, pattern_totals, sample_pattern, texel_corners_packed,
    vertex_frames,
};
use super::regions::{MAX_REGIONS, Regions};
use super::{ProfileKind, TexGeometry};
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;

/// Vertices per row of the per-vertex images (the shaders' VERTEX_ROW).
pub const VERTEX_ROW: u32 = 1024;
/// Texels per row of the BVH, walk, contact, walk-topology and reach-layout images (the
/// shaders' BVH_ROW, WALK_ROW and REACH_ROW).
pub const BVH_ROW: u32 = 1024;
/// Workgroups (8 x 8 invocations: 8 row segments) per row of the irradiance and diffusion
/// dispatches (the shaders' TILE_ROW).
pub const TILE_ROW: u32 = 256;

/// One pose of a mesh in the layout the shaders read, checked so that they never index out
/// of bounds.
pub struct Packed<'g> {
    /// Texture size (size x size texels).
    pub size: u32,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Per texel: position and coverage flag, normal and area (the geometry's own arrays).
    pub texel_positions: &'g [[f32; 4]],
    pub texel_normals: &'g [[f32; 4]],
    /// Per texel: its triangle's corners and barycentrics ([`texel_corners_packed`]).
    pub texel_corners: Vec<[u32; 4]>,
    /// Per texel: where the diffusion starts ([`start_texels`]).
    pub diffusion_start: Vec<[u32; 4]>,
    /// Per vertex: position and unit normal ([`vertex_frames`]).
    pub vertex_frames: Vec<[[f32; 4]; 2]>,
    /// The BVH over the posed mesh ([`Bvh::flat`] with [`super::posed::link_words`] in place
    /// of the counts): 2 texels a node, 3 a triangle.
    pub bvh_nodes: Vec<[f32; 8]>,
    pub bvh_triangles: Vec<[f32; 12]>,
    /// The surface walk's triangle records ([`super::walk::SurfaceWalk::records`]).
    pub walk_records: Vec<[u32; 4]>,
    /// The contact entries ([`contact_entries`]).
    pub contact_entries: Vec<[u32; 4]>,
    /// The occupied 8 x 1 row segments ([`occupied_tiles`]).
    pub tiles: Vec<u32>,
}

impl<'g> Packed<'g> {
    /// Checks `geo` ([`check_geometry`]) and packs it, building the BVH, the surface walk and
    /// the contact sums for the regions' profiles. Each triangle's region rides in its walk
    /// record (texel 2, z: [`region_records`]).
    pub fn new(geo: &'g TexGeometry, regions: &Regions) -> Result<Packed<'g>> {
        check_geometry(geo)?;
        regions.check_mesh(geo.triangles.len())?;
        let (bvh_nodes, bvh_triangles) = Bvh::build(&geo.positions, &geo.triangles).flat();
        // The shaders traverse without a stack: each node's count carries its skip link.
        let bvh_nodes = super::posed::with_links(bvh_nodes)?;
        let dg = DiffusionGeometry::build(geo, regions);
        let mut walk_records = dg.walk.records();
        region_records(&mut walk_records, regions);
        Ok(Packed {
            size: geo.size,
            triangles: geo.triangles.len(),
            texel_positions: &geo.pos,
            texel_normals: &geo.nrm,
            texel_corners: texel_corners_packed(geo),
            diffusion_start: start_texels(geo, &dg.contact)?,
            vertex_frames: vertex_frames(geo),
            bvh_nodes,
            bvh_triangles,
            walk_records,
            contact_entries: contact_entries(&dg.contact),
            tiles: occupied_tiles(geo),
        })
    }

    /// Vertices of the mesh.
    pub fn vertices(&self) -> u32 {
        self.vertex_frames.len() as u32
    }
}

/// The texels the kernel's images and buffers make room for, fixed by the first pose of the
/// mesh: a later pose ([`Room::pack`]) must fit them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Room {
    /// Texture size, mesh vertices and triangles, surface-walk records: a later pose has the
    /// same.
    pub size: u32,
    pub vertices: u32,
    pub triangles: usize,
    pub walk_records: usize,
    /// Rows of [`BVH_ROW`] texels of the BVH's table (its node rows, then its triangle
    /// rows) and of the contact entries.
    pub bvh_node_rows: u32,
    pub bvh_triangle_rows: u32,
    pub contact_rows: u32,
}

/// Writes each triangle's region into its walk record (texel 2 of
/// [`super::walk::RECORD_TEXELS`], z, which the walk leaves 0): the diffusion reads it with
/// the record it loads anyway. The per-frame records of a skinned mesh carry it the same way
/// (glsl/sss/pose_triangles.comp copies it from the topology, [`super::posed::walk_topology`]).
pub fn region_records(records: &mut [[u32; 4]], regions: &Regions) {
    for (t, rec) in records
        .chunks_exact_mut(super::walk::RECORD_TEXELS)
        .enumerate()
    {
        rec[2][2] = regions.of_triangle(t) as u32;
    }
}

/// Rows of `row` texels that hold `texels` (at least one).
pub fn rows(texels: usize, row: u32) -> u32 {
    (texels as u32).div_ceil(row).max(1)
}

impl Room {
    /// Segments (8 texels) a row of the atlas: the `ROW_SEGMENTS` of the stages that
    /// address the segment and block bitmaps.
    pub fn row_segments(&self) -> u32 {
        self.size.div_ceil(8)
    }

    /// The room for the first pose `p`, with some for other poses.
    pub fn of(p: &Packed) -> Room {
        // Any hierarchy over this many triangles (a rebuilt one may have more nodes): at
        // most 2 n - 1 nodes.
        let nodes = (2 * p.triangles).max(p.bvh_nodes.len());
        // The contact entries of other poses of the mesh.
        let contact = (2 * p.contact_entries.len()).max(4096);
        Room {
            size: p.size,
            vertices: p.vertices(),
            triangles: p.triangles,
            walk_records: p.walk_records.len(),
            bvh_node_rows: rows(2 * nodes, BVH_ROW),
            bvh_triangle_rows: rows(3 * p.bvh_triangles.len(), BVH_ROW),
            contact_rows: rows(contact, BVH_ROW),
        }
    }

    /// Checks and packs `geo`, a later pose of the mesh (same texture size, same triangles
    /// and UV layout), refusing one that does not fit.
    pub fn pack<'g>(&self, geo: &'g TexGeometry, regions: &Regions) -> Result<Packed<'g>> {
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
        let p = Packed::new(geo, regions)?;
        if 2 * p.bvh_nodes.len() > (self.bvh_node_rows * BVH_ROW) as usize {
            return Err(Error::InvalidArgument("BVH larger than its image".into()));
        }
        if p.walk_records.len() != self.walk_records {
            return Err(Error::InvalidArgument(format!(
                "the surface walk of the new geometry has {} records, the kernel's {} (a \
                 different mesh?)",
                p.walk_records.len(),
                self.walk_records
            )));
        }
        let room = (self.contact_rows * BVH_ROW) as usize;
        if p.contact_entries.len() > room {
            return Err(Error::InvalidArgument(format!(
                "this pose has {} contact entries (pieces of the mesh within reach of each \
                 other), more than the {room} the kernel made room for at its first pose",
                p.contact_entries.len()
            )));
        }
        Ok(p)
    }
}

/// The sample patterns of every region ([`sample_pattern`]) as the shaders read them from one
/// image [`PATTERN_WIDTH`] texels wide: region r's pattern in row 2 r, one texel per sample;
/// in row 2 r + 1, texel 0 its R_tot (rgb) and texel 1 its pattern's weight totals
/// ([`pattern_totals`]); the diffusion of a texel reads its region's rows. Row 0 and its
/// totals are region 0's, so one region is the old single pattern.
pub struct Pattern {
    /// Per region: its pattern and its totals.
    pub regions: Vec<(Vec<[f32; 4]>, [f32; 3])>,
}

/// Texels per row of the pattern image (the most samples a texel takes).
pub const PATTERN_WIDTH: u32 = 4096;

/// The most samples whose pattern the diffusion takes as specialization constants
/// (glsl/common/sss_diffusion.glsl `MAX_UNIFORM_SAMPLES`): with one region and at most this
/// many samples the loop over them is unrolled ([`Pattern::constants`]).
pub const MAX_UNIFORM_SAMPLES: usize = 32;

impl Pattern {
    pub fn new(regions: &Regions, samples: u32) -> Pattern {
        Pattern {
            regions: regions
                .profiles()
                .iter()
                .map(|p| {
                    let texels = sample_pattern(p, samples);
                    let totals = pattern_totals(&texels);
                    (texels, totals)
                })
                .collect(),
        }
    }

    /// The longest sample offset of any region's pattern (mm): how far from its texel's
    /// centre a diffusion sample lands in the plane of the texel's triangle (the bound of
    /// `sss reach boxes`, [`Settings::reach_push`]).
    pub fn radius(&self) -> f32 {
        self.regions
            .iter()
            .flat_map(|(texels, _)| texels)
            .map(|t| t[0].hypot(t[1]))
            .fold(0.0, f32::max)
    }

    /// The diffusion's specialization constant `UNIFORM_SAMPLES`: the sample count where the
    /// pattern is one region's of at most [`MAX_UNIFORM_SAMPLES`] samples (the shader then
    /// takes the pattern as constants, [`Pattern::constants`], in a loop it unrolls), else 0
    /// (it reads the image's rows at the texel's region).
    pub fn uniform_samples(&self) -> u32 {
        match self.regions.as_slice() {
            [(texels, _)] if (1..=MAX_UNIFORM_SAMPLES).contains(&texels.len()) => {
                texels.len() as u32
            }
            _ => 0,
        }
    }

    /// The diffusion's specialization constants for this pattern
    /// (glsl/common/sss_diffusion.glsl): `UNIFORM_SAMPLES` ([`Pattern::uniform_samples`]) and,
    /// where that is set, sample s's entry as `PAT_Xs`, `PAT_Ys`, `PAT_Zs`, `PAT_Ws` (f32 bits).
    pub fn constants(&self) -> Vec<(String, u32)> {
        let n = self.uniform_samples();
        let mut out = vec![("UNIFORM_SAMPLES".to_string(), n)];
        if n > 0 {
            for (s, texel) in self.regions[0].0.iter().enumerate() {
                for (c, v) in ["X", "Y", "Z", "W"].iter().zip(texel) {
                    out.push((format!("PAT_{c}{s}"), v.to_bits()));
                }
            }
        }
        out
    }

    /// The image's texels, rows [`PATTERN_WIDTH`] wide, for `regions` (R_tot per region).
    pub fn texels(&self, regions: &Regions) -> Vec<[f32; 4]> {
        let w = PATTERN_WIDTH as usize;
        let mut out = vec![[0f32; 4]; 2 * w * self.regions.len()];
        for (r, (texels, totals)) in self.regions.iter().enumerate() {
            out[2 * r * w..2 * r * w + texels.len()].copy_from_slice(texels);
            let k = regions.profile(r).r_tot.map(|k| k as f32);
            out[(2 * r + 1) * w] = [k[0], k[1], k[2], 0.0];
            out[(2 * r + 1) * w + 1] = [totals[0], totals[1], totals[2], 0.0];
        }
        out
    }
}

/// The transmission's profile tails per region as `glsl/sss/vertex_light.comp`'s `Regions`
/// block reads them: per region four vec4, the tails of the three channels
/// ([`super::Profile::tail_gpu`]) and (the thickest part that transmits, mm; 0, 0, 0).
pub fn region_tails(regions: &Regions) -> Vec<[f32; 4]> {
    let mut out = vec![[0f32; 4]; 4 * MAX_REGIONS];
    for (r, p) in regions.profiles().iter().enumerate() {
        for c in 0..3 {
            out[4 * r + c] = p.tail_gpu(c);
        }
        out[4 * r + 3] = [p.max_radius() as f32, 0.0, 0.0, 0.0];
    }
    out
}

/// The sampler's settings for one mesh, and the push constants they give each pass (word by
/// word as the shaders' `Push` blocks lay them out).
#[derive(Clone, Debug)]
pub struct Settings {
    /// The profiles of the mesh's skin regions.
    pub regions: Regions,
    pub params: SamplerParams,
    /// Shadow-ray origin offset along the normal (mm), from the first pose's extent.
    pub shadow_bias: f32,
    /// The texture and mesh the kernel was made for.
    pub room: Room,
    /// The longest offset of the sample patterns (mm, [`Pattern::radius`]).
    pub reach_radius: f32,
}

impl Settings {
    /// `glsl/sss/vertex_light.comp`: vertices, lights, bias, the transmission mode (0 off,
    /// 1 dipole, 2 Burley); the tails are in the regions' block ([`region_tails`]).
    pub fn vertex_light_push(&self, lights: u32) -> Vec<u32> {
        let mode = match (self.params.transmission, self.regions.kind()) {
            (false, _) => 0u32,
            (true, ProfileKind::Dipole) => 1,
            (true, ProfileKind::Burley) => 2,
        };
        vec![self.room.vertices, lights, self.shadow_bias.to_bits(), mode]
    }

    /// `glsl/sss/irradiance.comp`: size, lights, transmission, shadow refinement, bias,
    /// occupied tiles.
    pub fn irradiance_push(&self, lights: u32, tiles: u32) -> Vec<u32> {
        vec![
            self.room.size,
            lights,
            self.params.transmission as u32,
            self.params.shadow_refine as u32,
            self.shadow_bias.to_bits(),
            tiles,
        ]
    }

    /// `glsl/common/sss_diffusion.glsl`: size, samples, occupied tiles (each region's R_tot
    /// and totals are in the pattern image, [`Pattern::texels`]).
    pub fn diffusion_push(&self, tiles: u32) -> Vec<u32> {
        vec![self.room.size, self.params.samples, tiles]
    }

    /// `sss needed list`'s push constants: the bitmap's words (segments a row are the
    /// stage's `ROW_SEGMENTS`, [`Room::row_segments`]).
    pub fn needed_list_push(&self) -> Vec<u32> {
        let size = self.room.size;
        vec![needed_segment_words(size) as u32]
    }

    /// `sss reach boxes`: size, triangles, the samples' longest offset (mm) with a margin
    /// of 1e-4 for its rounding.
    pub fn reach_push(&self) -> Vec<u32> {
        let size = self.room.size;
        let radius = self.reach_radius * (1.0 + 1e-4);
        vec![size, self.room.triangles as u32, radius.to_bits()]
    }

    /// `sss reach triangles`: triangles, the bit of triangle 0 in the caller's bitmap.
    pub fn reach_triangles_push(&self, first: u32) -> Vec<u32> {
        vec![self.room.triangles as u32, first]
    }

    /// `sss reach list`: the segment bitmap's words, the block bitmap's words.
    pub fn reach_list_push(&self) -> Vec<u32> {
        let size = self.room.size;
        vec![
            needed_segment_words(size) as u32,
            reach_block_words(size) as u32,
        ]
    }
}

/// u32 words of the reach's block bitmap of a `size`^2 atlas (at least one): a bit per block
/// of 8 x [`REACH_BLOCK_ROWS`] texels, block (x / 8, y / REACH_BLOCK_ROWS) at bit
/// (y / REACH_BLOCK_ROWS) ceil(size / 8) + x / 8.
pub fn reach_block_words(size: u32) -> u64 {
    let (size, rows) = (size as u64, REACH_BLOCK_ROWS as u64);
    (size.div_ceil(8) * size.div_ceil(rows)).div_ceil(32).max(1)
}

/// Texel rows of a block of the reach (8 texels wide: a block row holds whole segments).
pub const REACH_BLOCK_ROWS: u32 = 4;

/// What the reach passes know of each triangle from the UV layout and the contact entries
/// (`start`: per texel its triangle, centre's barycentrics and contact range,
/// [`start_texels`]; `contact`: [`contact_entries`]; `triangles` of them). Two entries a
/// triangle: (m1, m2, m0 as f32 bits, n), m the least barycentrics of the centres of the
/// texels that start from it (w0 = 1 - w1 - w2 in f32, as the diffusion computes it);
/// (own, k, j, 0). From entry `own`: the k distinct blocks of those texels, the j distinct
/// 8 x 1 segments they lie in ([`needed_segment`] numbers them), then the n distinct blocks
/// of the sources of those texels' contact entries; one an entry, (index, 0, 0, 0). A
/// triangle no texel starts from has two zero entries. Blocks are 8 x [`REACH_BLOCK_ROWS`]
/// texels, block (x / 8, y / REACH_BLOCK_ROWS) numbered (y / REACH_BLOCK_ROWS)
/// ceil(size / 8) + x / 8.
pub fn reach_static(
    start: &[[u32; 4]],
    contact: &[[u32; 4]],
    size: u32,
    triangles: usize,
) -> Vec<[u32; 4]> {
    let row = size.div_ceil(8);
    let block = |i: u32| (i / size / REACH_BLOCK_ROWS) * row + (i % size) / 8;
    let mut mins = vec![[f32::INFINITY; 3]; triangles];
    let mut own: Vec<Vec<u32>> = vec![Vec::new(); triangles];
    let mut segments: Vec<Vec<u32>> = vec![Vec::new(); triangles];
    let mut touched: Vec<Vec<u32>> = vec![Vec::new(); triangles];
    for (i, s) in start.iter().enumerate() {
        let t = s[0] as usize;
        if t >= triangles {
            continue;
        }
        let (w1, w2) = (f32::from_bits(s[1]), f32::from_bits(s[2]));
        let w0 = 1.0 - w1 - w2;
        let m = &mut mins[t];
        for (k, w) in [w1, w2, w0].into_iter().enumerate() {
            m[k] = m[k].min(w);
        }
        own[t].push(block(i as u32));
        segments[t].push(needed_segment(i as u32 % size, i as u32 / size, size) as u32);
        let (first, count) = ((s[3] >> 5) as usize, (s[3] & 31) as usize);
        for e in contact.iter().skip(first).take(count) {
            touched[t].push(block(e[0]));
        }
    }
    let mut out = Vec::with_capacity(2 * triangles.max(1));
    out.resize(2 * triangles, [0; 4]);
    for (t, m) in mins.iter().enumerate() {
        if !m[0].is_finite() {
            continue;
        }
        let lists = [&mut own[t], &mut segments[t], &mut touched[t]];
        for list in lists {
            list.sort_unstable();
            list.dedup();
        }
        let (mine, segs, blocks) = (&own[t], &segments[t], &touched[t]);
        out[2 * t] = [
            m[0].to_bits(),
            m[1].to_bits(),
            m[2].to_bits(),
            blocks.len() as u32,
        ];
        out[2 * t + 1] = [out.len() as u32, mine.len() as u32, segs.len() as u32, 0];
        out.extend(mine.iter().chain(segs).chain(blocks).map(|&k| [k, 0, 0, 0]));
    }
    if out.is_empty() {
        out.resize(2, [0; 4]);
    }
    out
}

/// Checks a caller's irradiance for a `size`^2 texture: one finite rgba per texel.
pub fn check_irradiance(size: u32, e: &[[f32; 4]]) -> Result<()> {
    if e.len() != (size * size) as usize {
        return Err(Error::InvalidArgument(format!(
            "{} irradiance texels for a {size}^2 texture",
            e.len()
        )));
    }
    if let Some(i) = e.iter().position(|t| t.iter().any(|x| !x.is_finite())) {
        return Err(Error::InvalidArgument(format!(
            "irradiance texel {i} is not finite"
        )));
    }
    Ok(())
}

/// The irradiance pass's grey E as rgba: (E, E, E, 1), 0 where no surface (E < 0).
pub fn grey_to_rgba(grey: &[f32]) -> Vec<[f32; 4]> {
    grey.iter()
        .map(|&e| if e < 0.0 { [0.0; 4] } else { [e, e, e, 1.0] })
        .collect()
}

/// The irradiance pass's rgb E (with a per-vertex irradiance added) as rgba: (E, 1), 0 where
/// no surface (alpha < 0).
pub fn rgb_to_rgba(rgb: &[[f32; 4]]) -> Vec<[f32; 4]> {
    rgb.iter()
        .map(|&e| {
            if e[3] < 0.0 {
                [0.0; 4]
            } else {
                [e[0], e[1], e[2], 1.0]
            }
        })
        .collect()
}

/// Checks what the shaders index with (TexGeometry's fields are public): a texel on the
/// surface names a triangle of the mesh, a triangle names vertices of the mesh, and the
/// per-texel arrays have size^2 entries.
pub fn check_geometry(geo: &TexGeometry) -> Result<()> {
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
    if geo.corner_uvs.len() != geo.triangles.len() || geo.normals.len() != geo.positions.len() {
        return Err(Error::InvalidArgument(format!(
            "texture-space geometry has {} triangles but {} UV corner triples, {} vertices but \
             {} normals (the walk and vertex passes index them together)",
            geo.triangles.len(),
            geo.corner_uvs.len(),
            geo.positions.len(),
            geo.normals.len()
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

/// The 8 x 1 row segments of the atlas with at least one texel on the surface (covered or
/// gutter), as x / 8 | y << 16: the irradiance and diffusion passes run over these only
/// (about half of a head's atlas is empty; a segment is one 8-lane SIMD step on lavapipe).
pub fn occupied_tiles(geo: &TexGeometry) -> Vec<u32> {
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
pub fn tile_groups(tiles: u32) -> [u32; 3] {
    let groups = tiles.div_ceil(8);
    [
        groups.clamp(1, TILE_ROW),
        groups.div_ceil(TILE_ROW).max(1),
        1,
    ]
}

/// Per texel, what the diffusion starts from: (triangle, w1 bits, w2 bits, first contact
/// entry << 5 | entry count).
pub fn start_texels(geo: &TexGeometry, contact: &Contact) -> Result<Vec<[u32; 4]>> {
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

/// The contact entries as the diffusion reads them: (source texel, factor per channel as
/// bits).
pub fn contact_entries(contact: &Contact) -> Vec<[u32; 4]> {
    contact
        .entries
        .iter()
        .map(|(j, f)| [*j, f[0].to_bits(), f[1].to_bits(), f[2].to_bits()])
        .collect()
}

/// u32 words of a needed-segment bitmap for a `size`^2 atlas (`SssKernel::set_needed_segments`;
/// at least one): one bit per 8x1 row segment, [`needed_segment`] numbers them.
pub fn needed_segment_words(size: u32) -> u64 {
    (size as u64 * (size as u64).div_ceil(8))
        .div_ceil(32)
        .max(1)
}

/// The segment of texel (x, y) of a `size`^2 atlas in a needed-segment bitmap: bit s % 32 of
/// word s / 32 for s = y * ceil(size / 8) + x / 8.
pub fn needed_segment(x: u32, y: u32, size: u32) -> u64 {
    y as u64 * (size as u64).div_ceil(8) + (x / 8) as u64
}

/// The segments of a tile list ([`occupied_tiles`]'s `x / 8 | y << 16`) as a
/// needed-segment bitmap of a `size`^2 atlas ([`needed_segment_words`] words).
pub fn tile_bitmap(tiles: &[u32], size: u32) -> Vec<u32> {
    let mut words = vec![0u32; needed_segment_words(size) as usize];
    for &t in tiles {
        let s = needed_segment((t & 0xffff) * 8, t >> 16, size);
        if let Some(w) = words.get_mut((s / 32) as usize) {
            *w |= 1 << (s % 32);
        }
    }
    words
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::sss::{Material, Profile, ProfileKind, walk};
    use crate::scene::texspace::plane_mesh;

    fn plane(size: u32) -> TexGeometry {
        TexGeometry::build(&plane_mesh(10.0, 10.0, 2).unwrap(), size, 1.0).unwrap()
    }

    fn profile() -> Regions {
        Regions::single(Profile::new(ProfileKind::Burley, Material::SKIN1, 0.99).unwrap())
    }

    /// The diffusion shader's layout constants are the ones the host writes with.
    #[test]
    fn diffusion_shader_agrees_with_the_host() {
        // (with the walk records' include)
        let src = [
            include_str!("../../../glsl/common/sss_diffusion.glsl"),
            include_str!("../../../glsl/sss/walk_record.glsl"),
        ]
        .concat();
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
                "glsl/common/sss_diffusion.glsl with glsl/sss/walk_record.glsl lacks `{line}`"
            );
        }
    }

    /// Every constant of a pattern the diffusion takes as constants is declared, under its
    /// name, by the four diffusion shaders (the pipelines set only the constants a shader
    /// declares, so a name the shaders lack would be dropped without a word); more samples
    /// than that, or two regions, keep the pattern image (`UNIFORM_SAMPLES` 0).
    #[test]
    fn pattern_constants_are_the_diffusion_shaders_own() {
        let one = profile();
        let p = Pattern::new(&one, MAX_UNIFORM_SAMPLES as u32);
        let constants = p.constants();
        assert_eq!(constants.len(), 1 + 4 * MAX_UNIFORM_SAMPLES);
        assert_eq!(
            constants[0],
            ("UNIFORM_SAMPLES".into(), MAX_UNIFORM_SAMPLES as u32)
        );
        for name in [
            "sss/diffusion",
            "sss/diffusion_grey",
            "sss/diffusion_env",
            "sss/diffusion_env_listed",
        ] {
            let spirv = crate::shaders::spirv(name).unwrap();
            let shader = crate::gpu::Shader::from_spirv(name, spirv).unwrap();
            for (c, _) in &constants {
                assert!(
                    shader.spec_constants.iter().any(|s| &s.name == c),
                    "{name} does not declare {c}"
                );
            }
        }
        let more = Pattern::new(&one, MAX_UNIFORM_SAMPLES as u32 + 1);
        assert_eq!(more.constants(), vec![("UNIFORM_SAMPLES".into(), 0)]);
        let p2 = one.profile(0).clone();
        let two = Regions::new(vec![p2.clone(), p2], vec![0, 1]).unwrap();
        let regions = Pattern::new(&two, 8);
        assert_eq!(regions.constants(), vec![("UNIFORM_SAMPLES".into(), 0)]);
    }

    /// The reach's shaders number the blocks as the host does.
    #[test]
    fn reach_shaders_agree_with_the_host() {
        for src in [
            include_str!("../../../glsl/sss/reach_boxes.comp"),
            include_str!("../../../glsl/sss/reach_list.comp"),
        ] {
            let line = format!("const uint BLOCK_ROWS = {REACH_BLOCK_ROWS}u;");
            assert!(src.contains(&line), "a reach shader lacks `{line}`");
        }
        // The layout's image (SssKernel: `reach_static`, BVH_ROW texels a row).
        for src in [
            include_str!("../../../glsl/sss/reach_boxes.comp"),
            include_str!("../../../glsl/sss/reach_triangles.comp"),
        ] {
            let line = format!("const uint REACH_ROW = {BVH_ROW}u;");
            assert!(src.contains(&line), "a reach shader lacks `{line}`");
        }
        let src = include_str!("../../../glsl/sss/walk_record.glsl");
        assert!(
            include_str!("../../../glsl/sss/reach_boxes.comp")
                .contains("#include <sss/walk_record.glsl>")
        );
        for line in [
            format!("const uint WALK_RECORD = {}u;", walk::RECORD_TEXELS),
            format!("const uint WALK_ROW = {BVH_ROW}u;"),
            format!("const uint EDGE_SHARED = {}u;", walk::EDGE_SHARED),
        ] {
            assert!(
                src.contains(&line),
                "glsl/sss/walk_record.glsl lacks `{line}`"
            );
        }
    }

    /// The reach's per-triangle data: the least barycentrics, the distinct blocks of a
    /// triangle's texels and of its contact entries' sources.
    #[test]
    fn reach_static_lists_each_triangles_blocks_once() {
        let size = 32;
        let b = |x: f32| x.to_bits();
        // Triangle 1: texels (0, 0), (1, 0) (one block), (9, 5) (another); triangle 0 none.
        // Contact ranges: first << 5 | count.
        let mut start = vec![[u32::MAX, 0, 0, 0]; (size * size) as usize];
        start[0] = [1, b(0.25), b(0.5), 2];
        start[1] = [1, b(-0.125), b(0.5), 1];
        start[(5 * size + 9) as usize] = [1, b(0.5), b(0.25), 2 << 5 | 1];
        // Contact sources: texel (31, 31), (30, 31) (one block), (0, 0).
        let contact = vec![
            [31 * size + 31, 0, 0, 0],
            [31 * size + 30, 0, 0, 0],
            [0, 0, 0, 0],
        ];
        let r = reach_static(&start, &contact, size, 2);
        assert_eq!(r[0], [0; 4]);
        assert_eq!(r[1], [0; 4]);
        let m = r[2];
        let (m1, m2, m0) = (
            f32::from_bits(m[0]),
            f32::from_bits(m[1]),
            f32::from_bits(m[2]),
        );
        assert_eq!((m1, m2, m0), (-0.125, 0.25, 0.25));
        let [own, k, j, _] = r[3];
        let block = |x: u32, y: u32| (y / REACH_BLOCK_ROWS) * size.div_ceil(8) + x / 8;
        let list = |from: u32, n: u32| -> Vec<u32> {
            r[from as usize..(from + n) as usize]
                .iter()
                .map(|e| e[0])
                .collect()
        };
        assert_eq!(list(own, k), vec![block(0, 0), block(9, 5)]);
        let seg = |x, y| needed_segment(x, y, size) as u32;
        assert_eq!(list(own + k, j), vec![seg(0, 0), seg(9, 5)]);
        assert_eq!(list(own + k + j, m[3]), vec![block(0, 0), block(31, 31)]);
        assert_eq!(r.len(), 4 + 2 + 2 + 2);
    }

    /// The transmission's block of region tails is the size the host writes.
    #[test]
    fn vertex_light_shader_takes_every_region() {
        for src in [
            include_str!("../../../glsl/sss/vertex_light.comp"),
            include_str!("../../../glsl/common/sss_diffusion.glsl"),
        ] {
            let line = format!("const uint MAX_REGIONS = {MAX_REGIONS}u;");
            assert!(src.contains(&line), "a region shader lacks `{line}`");
        }
        assert_eq!(region_tails(&profile()).len(), 4 * MAX_REGIONS);
    }

    /// The per-vertex and BVH shaders read with the same rows as the host writes.
    #[test]
    fn texel_shaders_agree_with_the_host() {
        for (path, src) in [
            (
                "irradiance",
                include_str!("../../../glsl/sss/irradiance.glsl"),
            ),
            (
                "vertex_light",
                include_str!("../../../glsl/sss/vertex_light.comp"),
            ),
            (
                "vertex_env",
                include_str!("../../../glsl/sss/vertex_env.comp"),
            ),
        ] {
            for (name, value) in [("VERTEX_ROW", VERTEX_ROW), ("BVH_ROW", BVH_ROW)] {
                let line = format!("const uint {name} = {value}u;");
                if name == "BVH_ROW" && !src.contains("const uint BVH_ROW") {
                    continue;
                }
                assert!(src.contains(&line), "glsl/sss/{path} lacks `{line}`");
            }
        }
    }

    #[test]
    fn a_plane_packs_every_array_at_its_length() {
        let geo = plane(32);
        let p = Packed::new(&geo, &profile()).unwrap();
        assert_eq!(p.size, 32);
        assert_eq!(p.triangles, geo.triangles.len());
        assert_eq!(p.vertices() as usize, geo.positions.len());
        for len in [
            p.texel_positions.len(),
            p.texel_normals.len(),
            p.texel_corners.len(),
            p.diffusion_start.len(),
        ] {
            assert_eq!(len, geo.texels());
        }
        assert_eq!(p.bvh_triangles.len(), geo.triangles.len());
        assert_eq!(
            p.walk_records.len(),
            geo.triangles.len() * walk::RECORD_TEXELS
        );
        // A start texel carries its triangle and barycentrics; the contact range of a single
        // plane is empty.
        for (s, t) in p.diffusion_start.iter().zip(&geo.texel_tri) {
            assert_eq!(s[..3], t[..3]);
            assert_eq!(s[3], 0);
        }
        assert!(p.contact_entries.is_empty());
    }

    #[test]
    fn tiles_are_the_occupied_row_segments() {
        let geo = plane(32);
        let tiles = occupied_tiles(&geo);
        let n = geo.size as usize;
        for y in 0..n {
            for tx in 0..n / 8 {
                let occupied = (tx * 8..tx * 8 + 8).any(|x| geo.pos[y * n + x][3] != 0.0);
                let listed = tiles.contains(&(tx as u32 | (y as u32) << 16));
                assert_eq!(occupied, listed, "segment {tx} of row {y}");
            }
        }
        assert_eq!(tile_groups(0), [1, 1, 1]);
        assert_eq!(tile_groups(8 * TILE_ROW + 1), [TILE_ROW, 2, 1]);
    }

    #[test]
    fn a_broken_geometry_is_refused_before_anything_is_built() {
        let geo = plane(32);
        let on = (0..geo.texels()).find(|&i| geo.pos[i][3] != 0.0).unwrap();
        let mut broken = geo.clone();
        broken.texel_tri[on][0] = 99;
        let e = Packed::new(&broken, &profile()).err().unwrap();
        assert!(e.to_string().contains("triangle 99"), "{e}");
        let mut broken = geo.clone();
        broken.triangles[1][2] = 1000;
        let e = Packed::new(&broken, &profile()).err().unwrap();
        assert!(e.to_string().contains("triangle 1 names a vertex"), "{e}");
        let mut broken = geo;
        broken.nrm.pop();
        assert!(check_geometry(&broken).is_err());
    }

    /// The push constants have the size of each shader's reflected `Push` block.
    #[test]
    fn push_constants_match_the_shaders() {
        let geo = plane(32);
        let packed = Packed::new(&geo, &profile()).unwrap();
        let s = Settings {
            regions: profile(),
            params: SamplerParams::default(),
            shadow_bias: 0.01,
            room: Room::of(&packed),
            reach_radius: 1.0,
        };
        for (name, words) in [
            ("sss/vertex_light", s.vertex_light_push(2)),
            ("sss/irradiance", s.irradiance_push(2, 7)),
            ("sss/irradiance_env", s.irradiance_push(2, 7)),
            ("sss/irradiance_posed", s.irradiance_push(2, 7)),
            ("sss/irradiance_posed_env", s.irradiance_push(2, 7)),
            ("sss/diffusion_env", s.diffusion_push(7)),
            ("sss/diffusion_env_listed", s.diffusion_push(7)),
            ("sss/needed_list", s.needed_list_push()),
            ("sss/irradiance_posed_env_listed", s.irradiance_push(2, 7)),
            ("sss/reach_boxes", s.reach_push()),
            ("sss/reach_triangles", s.reach_triangles_push(3)),
            ("sss/reach_list", s.reach_list_push()),
            ("sss/vertex_env", vec![7]),
            ("sss/diffusion", s.diffusion_push(7)),
            ("sss/diffusion_grey", s.diffusion_push(7)),
        ] {
            let spirv = crate::shaders::spirv(name).unwrap();
            let shader = crate::gpu::Shader::from_spirv(name, spirv).unwrap();
            assert_eq!(
                shader.push_constant_size as usize,
                4 * words.len(),
                "{name}"
            );
        }
    }

    /// A later pose must be of the same mesh and texture, and fit the room of the first.
    #[test]
    fn a_later_pose_must_fit_the_room_of_the_first() {
        let geo = plane(32);
        let room = Room::of(&Packed::new(&geo, &profile()).unwrap());
        assert_eq!(room.size, 32);
        assert!(room.pack(&geo, &profile()).is_ok());
        let e = room.pack(&plane(64), &profile()).err().unwrap();
        assert!(e.to_string().contains("does not match"), "{e}");
        let tight = Room {
            contact_rows: 0,
            ..room
        };
        assert!(
            tight.pack(&geo, &profile()).is_ok(),
            "no contact entries fit no room"
        );
        let tight = Room {
            bvh_node_rows: 0,
            ..room
        };
        let e = tight.pack(&geo, &profile()).err().unwrap();
        assert!(e.to_string().contains("BVH larger"), "{e}");
        let other = Room {
            walk_records: room.walk_records + 1,
            ..room
        };
        let e = other.pack(&geo, &profile()).err().unwrap();
        assert!(e.to_string().contains("surface walk"), "{e}");
    }

    #[test]
    fn irradiance_is_checked_and_grey_widened() {
        assert!(check_irradiance(2, &[[1.0; 4]; 4]).is_ok());
        let e = check_irradiance(2, &[[1.0; 4]; 3]).unwrap_err();
        assert!(e.to_string().contains("3 irradiance texels"), "{e}");
        let mut nan = [[1.0; 4]; 4];
        nan[2][0] = f32::INFINITY;
        let e = check_irradiance(2, &nan).unwrap_err();
        assert!(e.to_string().contains("texel 2"), "{e}");
        assert_eq!(
            grey_to_rgba(&[-1.0, 0.5]),
            vec![[0.0; 4], [0.5, 0.5, 0.5, 1.0]]
        );
    }

    /// Two regions' patterns land in their own rows, with R_tot and the totals in the row
    /// below each; the walk records carry each triangle's region.
    #[test]
    fn each_region_has_its_rows_and_each_record_its_region() {
        let skin1 = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.99).unwrap();
        let skin2 = Profile::new(ProfileKind::Dipole, Material::SKIN2, 0.99).unwrap();
        let geo = plane(32);
        let tris = geo.triangles.len();
        let of_tri: Vec<u8> = (0..tris).map(|t| (t % 2) as u8).collect();
        let regions = Regions::new(vec![skin1.clone(), skin2.clone()], of_tri).unwrap();
        let pattern = Pattern::new(&regions, 16);
        let texels = pattern.texels(&regions);
        let w = PATTERN_WIDTH as usize;
        assert_eq!(texels.len(), 4 * w);
        for (r, p) in [&skin1, &skin2].into_iter().enumerate() {
            let own = sample_pattern(p, 16);
            assert_eq!(texels[2 * r * w..2 * r * w + 16], own[..]);
            assert!(
                texels[2 * r * w + 16..(2 * r + 1) * w]
                    .iter()
                    .all(|t| *t == [0.0; 4])
            );
            let k = p.r_tot.map(|k| k as f32);
            assert_eq!(texels[(2 * r + 1) * w], [k[0], k[1], k[2], 0.0]);
            let t = pattern_totals(&own);
            assert_eq!(texels[(2 * r + 1) * w + 1], [t[0], t[1], t[2], 0.0]);
        }
        assert_ne!(texels[0], texels[2 * w], "the two profiles sample alike");
        let packed = Packed::new(&geo, &regions).unwrap();
        for t in 0..tris {
            assert_eq!(
                packed.walk_records[t * walk::RECORD_TEXELS + 2][2],
                (t % 2) as u32
            );
        }
        let e = Packed::new(&plane(16), &Regions::new(vec![skin1], vec![0; 3]).unwrap())
            .err()
            .unwrap();
        assert!(e.to_string().contains("for 3 triangles"), "{e}");
    }
}
