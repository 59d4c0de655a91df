//! Compact lobes on the glossy path: a sun or a lamp shaded directly, not through the
//! transfer basis (the diffuse path's [`super::sharp`], with the BRDF toward the camera).
//!
//! A 256-Gaussian transfer basis is smooth; a light much narrower than its functions samples
//! the projected transfer where it ripples and cannot cast a sharp shadow. On the diffuse
//! path that was 3-5% of error; on the glossy path, where each vertex's rows are products of
//! the visibility with a BRDF factor, the bunny under Blender's sunrise erred 7-20% (CTA,
//! 8 rotations, the transfer's share 4-12%) with every lobe in the basis. So, as for diffuse,
//! the lobes [`super::sharp::split`] finds compact leave the basis, each as one tap or more:
//!
//! ```text
//! B_v += albedo * sum_t E_t V_v(w_t) rho(w_t, o_v) max(0, n_v . w_t)
//! ```
//!
//! E_t the tap's share of its lobe's integral (amplitude x 2 pi (1 - e^(-2 lambda)) /
//! lambda), o_v the view direction of [`Brdf::view_direction`] and rho the BRDF itself,
//! evaluated exactly per vertex (no view basis: a tap is one light direction). The taps'
//! directions w_t and visibility are the diffuse path's ([`CompactShadow`]): grid texel
//! centres with their bits, one texel for a point source and the 2 x 2 around the rotated
//! axis for a lobe the fit resolved ([`super::sharp::taps`]), or one tap at the exact rotated
//! axis and a shadow ray against the static mesh's BVH ([`super::sharp::ray_taps`],
//! [`super::sharp::ray_bits`]).
//!
//! The GPU adds the taps in pass `srbf glossy sharp` (glsl/srbf/glossy_sharp.comp, or
//! glossy_sharp_rays.comp for rays), after the glossy or CTA shade pass, onto its radiance
//! buffer: one invocation per vertex in the vertices' own order. Grid taps are placed once
//! per frame before it by pass `srbf sharp` (the diffuse path's glsl/srbf/sharp.comp) and
//! read from a uniform buffer; placing them per vertex (two atan and four sin/cos per lane)
//! had cost 2.0 ms a frame on the bunny. [`GlossyCompact::add`] is the CPU twin.

use super::glossy_gpu::GlossyFrame;
use super::inputs::SunRays;
use super::pack::MAX_TAPS;
use super::sharp::{self, MAX_LOBES};
use crate::error::{Error, Result};
use crate::geom::brdf::Brdf;
use crate::geom::sg::Lobe;
use crate::geom::visibility::Visibility;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Image, Recorder,
    Resource,
};
use crate::kernels::contract::DispatchArgs;
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::{Mat3, Vec3};
use rayon::prelude::*;

pub const PASS_GLOSSY_SHARP: &str = "srbf glossy sharp";
/// The taps pass (grid taps only): the diffuse path's `srbf sharp` shader.
pub use super::gpu::PASS_SHARP;

/// How compact lobes are shadowed.
#[derive(Clone, Copy)]
pub enum CompactShadow<'a> {
    /// The bits of the visibility grid's texels of each lobe's taps ([`sharp::taps`]); `visibility` was
    /// cast for the texel centres of the `width` x `height` grid ([`sharp::check_grid`]).
    Grid {
        visibility: &'a Visibility,
        width: u32,
        height: u32,
    },
    /// A shadow ray per vertex and lobe at its exact rotated axis; `positions` are the
    /// shaded vertices'.
    Rays(SunRays<'a>),
}

/// The compact lobes of a glossy run and how they are shadowed.
#[derive(Clone, Copy)]
pub struct GlossyCompact<'a> {
    /// The compact lobes ([`sharp::split`]'s second part), at most [`MAX_LOBES`].
    pub lobes: &'a [Lobe],
    pub shadow: CompactShadow<'a>,
    /// The surface's BRDF (the transfer's).
    pub brdf: Brdf,
    /// Width of the map the lobes were fitted to: which are point sources
    /// ([`sharp::is_point`]; grid taps only).
    pub fit_width: u32,
}

impl GlossyCompact<'_> {
    /// Checks the lobes, the BRDF and the shadowing's sizes against `vertices`.
    pub fn check(&self, vertices: usize) -> Result<()> {
        self.check_for(vertices, None)
    }

    /// [`GlossyCompact::check`], and with `positions` (the shaded vertices) that shadow
    /// rays start from them.
    pub fn check_for(&self, vertices: usize, positions: Option<&[Vec3]>) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("compact lobes: {what}")));
        if self.lobes.len() > MAX_LOBES {
            return bad(format!("{} lobes (at most {MAX_LOBES})", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        self.brdf.check()?;
        sharp::check_fit_width(self.fit_width)?;
        match self.shadow {
            CompactShadow::Grid {
                visibility,
                width,
                height,
            } => {
                sharp::check_grid(visibility, width, height)?;
                if visibility.vertices != vertices {
                    return bad(format!(
                        "a visibility of {} vertices for {vertices} vertices",
                        visibility.vertices
                    ));
                }
            }
            CompactShadow::Rays(r) => {
                if r.positions.len() != vertices {
                    return bad(format!(
                        "{} ray origins for {vertices} vertices",
                        r.positions.len()
                    ));
                }
                if let Some(p) =
                    positions.and_then(|p| p.iter().zip(r.positions).position(|(a, b)| a != b))
                {
                    return bad(format!(
                        "ray origin {p} ({}) is not the shaded vertex's position (the GPU casts \
                         from the vertices)",
                        r.positions[p]
                    ));
                }
                if !(r.offset.is_finite() && r.offset >= 0.0) {
                    return bad(format!("ray offset {} (finite, >= 0)", r.offset));
                }
            }
        }
        Ok(())
    }

    /// The taps of one frame: (direction, E_j / pi per channel), as the shaders place them.
    fn taps(&self, rotation: Mat3) -> Vec<sharp::Tap> {
        match self.shadow {
            CompactShadow::Grid { width, height, .. } => sharp::taps(
                self.lobes,
                &sharp::points(self.lobes, self.fit_width),
                rotation,
                width,
                height,
            ),
            CompactShadow::Rays(_) => sharp::ray_taps(self.lobes, rotation),
        }
    }

    /// The CPU twin of pass `srbf glossy sharp`: adds every compact lobe's radiance toward
    /// `frame.camera` to `out` (one entry per vertex: `positions`, `normals`).
    pub fn add(
        &self,
        frame: &GlossyFrame,
        positions: &[Vec3],
        normals: &[Vec3],
        out: &mut [[f64; 3]],
    ) -> Result<()> {
        let n = out.len();
        if positions.len() != n || normals.len() != n {
            return Err(Error::InvalidArgument(format!(
                "compact lobes: {} positions and {} normals for {n} radiances",
                positions.len(),
                normals.len()
            )));
        }
        self.check_for(n, Some(positions))?;
        if self.lobes.is_empty() {
            return Ok(());
        }
        let taps = self.taps(frame.rotation);
        let bits = match self.shadow {
            CompactShadow::Rays(r) => Some(sharp::ray_bits(
                &taps,
                r.positions,
                normals,
                r.bvh,
                r.offset,
            )),
            CompactShadow::Grid { .. } => None,
        };
        let seen = |v: usize, t: &sharp::Tap| match (&bits, self.shadow) {
            (Some(b), _) => b[v] >> t.texel & 1 == 1,
            (None, CompactShadow::Grid { visibility, .. }) => {
                visibility.visible(v, t.texel as usize)
            }
            (None, CompactShadow::Rays(_)) => false,
        };
        let camera = frame.camera.as_dvec3();
        out.par_iter_mut().enumerate().for_each(|(v, b)| {
            let nv = normals[v].as_dvec3();
            let o = Brdf::view_direction(nv, positions[v].as_dvec3(), camera);
            for t in &taps {
                if !seen(v, t) {
                    continue;
                }
                let w = t.dir.as_dvec3();
                let f = std::f64::consts::PI * self.brdf.cosine_weighted(nv, w, o);
                for ((x, a), w) in b.iter_mut().zip(frame.albedo).zip(t.weight) {
                    *x += a as f64 * w as f64 * f;
                }
            }
        });
        Ok(())
    }
}

/// Pass `srbf glossy sharp` on the GPU: its pipeline, bindings and buffers, added to a glossy
/// kernel's radiance buffer (bound read-write); with grid taps, pass `srbf sharp` before it
/// (glsl/srbf/sharp.comp, the diffuse path's) writes the frame's taps once.
pub(crate) struct CompactStage {
    /// Pass `srbf sharp` (grid taps only).
    taps: Option<(ComputePipeline, BindGroup)>,
    add: (ComputePipeline, BindGroup),
    buffers: Vec<Buffer>,
    images: Vec<Image>,
    lobes: u32,
    /// Taps pass `srbf glossy sharp` adds: [`sharp::tap_count`] on the grid, one a lobe with
    /// rays.
    added: u32,
    vertices: u32,
    grid: [u32; 2],
    offset: f32,
    brdf: [f32; 4],
}

impl CompactStage {
    /// Checks `compact`, creates the stage's buffers (the lobes, the vertices' positions and
    /// normals in their own order, the taps and the grid's bits, or the BVH) and records
    /// their uploads. None when there are no compact lobes.
    pub(crate) fn new(
        rec: &mut Recorder,
        compact: &GlossyCompact<'_>,
        positions: &[Vec3],
        normals: &[Vec3],
        radiance: &Buffer,
    ) -> Result<Option<CompactStage>> {
        let vertices = positions.len();
        compact.check_for(vertices, Some(positions))?;
        if normals.len() != vertices {
            return Err(Error::InvalidArgument(format!(
                "compact lobes: {vertices} positions and {} normals",
                normals.len()
            )));
        }
        if compact.lobes.is_empty() {
            return Ok(None);
        }
        let ctx = rec.context();
        fn storage<T: bytemuck::Pod>(rec: &mut Recorder, name: &str, data: &[T]) -> Result<Buffer> {
            let bytes: &[u8] = bytemuck::cast_slice(data);
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        }
        let vec4 =
            |v: &[Vec3]| -> Vec<[f32; 4]> { v.iter().map(|x| x.extend(0.0).into()).collect() };
        let (axes, amps) = super::glossy_gpu::lobe_arrays(compact.lobes);
        let points = sharp::points(compact.lobes, compact.fit_width);
        let amps = sharp::flag_resolved(amps, &points);
        // 0, 1: the lobes; 2, 3: the vertices; grid taps: 4 the taps, 5 the bits.
        let mut buffers = vec![
            storage(rec, "srbf glossy compact axes", &axes)?,
            storage(rec, "srbf glossy compact amplitudes", &amps)?,
            storage(rec, "srbf glossy compact positions", &vec4(positions))?,
            storage(rec, "srbf glossy compact normals", &vec4(normals))?,
        ];
        let b = Resource::Buffer;
        let mut images = Vec::new();
        let (taps, add, grid, offset) = match compact.shadow {
            CompactShadow::Grid {
                visibility,
                width,
                height,
            } => {
                let words = (width as usize * height as usize).div_ceil(32);
                let bits: Vec<u32> = (0..vertices)
                    .flat_map(|v| (0..words).map(move |w| visibility.word32(v, w)))
                    .collect();
                buffers.push(
                    rec.buffer_with(
                        "srbf glossy compact taps",
                        BufferDesc::storage(2 * MAX_TAPS as u64 * 16)
                            .usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
                        &vec![[0f32; 4]; 2 * MAX_TAPS],
                    )?,
                );
                buffers.push(storage(rec, "srbf glossy compact visibility", &bits)?);
                let taps = crate::shaders::pipeline(&ctx, "srbf/sharp")?;
                let taps_bind = taps.bind_declared(
                    &[
                        ("lobe_axes", b(&buffers[0])),
                        ("lobe_amps", b(&buffers[1])),
                        ("taps", b(&buffers[4])),
                    ],
                    &[("taps", AccessSet::from(A::ComputeShaderWrite))],
                )?;
                let add = crate::shaders::pipeline(&ctx, "srbf/glossy_sharp")?;
                let add_bind = add.bind_declared(
                    &[
                        ("points", b(&buffers[2])),
                        ("normals", b(&buffers[3])),
                        ("radiance", b(radiance)),
                        ("taps", b(&buffers[4])),
                        ("visible", b(&buffers[5])),
                    ],
                    &[(
                        "radiance",
                        A::ComputeShaderReadOther | A::ComputeShaderWrite,
                    )],
                )?;
                (
                    Some((taps, taps_bind)),
                    (add, add_bind),
                    [width, height],
                    0.0,
                )
            }
            CompactShadow::Rays(r) => {
                let (nodes, tris) = r.bvh.flat();
                let nodes = crate::geom::bvh::with_links(nodes)?;
                let (table, tri_base) =
                    super::gpu::bvh_table(rec, "srbf glossy compact", &nodes, &tris)?;
                images.push(table);
                let add = crate::shaders::pipeline_specialized(
                    &ctx,
                    "srbf/glossy_sharp_rays",
                    &[("TRI_BASE", tri_base)],
                )?;
                let add_bind = add.bind_declared(
                    &[
                        ("points", b(&buffers[2])),
                        ("normals", b(&buffers[3])),
                        ("radiance", b(radiance)),
                        ("lobe_axes", b(&buffers[0])),
                        ("lobe_amps", b(&buffers[1])),
                        ("nodes", Resource::storage_image(&images[0])),
                    ],
                    &[(
                        "radiance",
                        A::ComputeShaderReadOther | A::ComputeShaderWrite,
                    )],
                )?;
                (None, (add, add_bind), [1, 1], r.offset)
            }
        };
        let brdf = match compact.brdf {
            Brdf::Diffuse => [0.0, 1.0, 0.0, 0.0],
            Brdf::Phong {
                exponent,
                diffuse,
                specular,
            } => [exponent, diffuse, specular, 0.0],
        };
        Ok(Some(CompactStage {
            taps,
            add,
            buffers,
            images,
            lobes: compact.lobes.len() as u32,
            added: match compact.shadow {
                CompactShadow::Grid { .. } => sharp::tap_count(&points) as u32,
                CompactShadow::Rays(_) => compact.lobes.len() as u32,
            },
            vertices: vertices as u32,
            grid,
            offset,
            brdf,
        }))
    }

    /// The compact lobes this stage adds.
    pub(crate) fn lobes(&self) -> usize {
        self.lobes as usize
    }

    /// The stage's passes for kernel `K`: `srbf sharp` (grid taps only), then
    /// `srbf glossy sharp`, dispatched by `taps_args` and `add_args` (which call
    /// [`CompactStage::taps_args`] and [`CompactStage::add_args`]).
    pub(crate) fn passes<K: Kernel>(
        &self,
        taps_args: DispatchArgs<K>,
        add_args: DispatchArgs<K>,
    ) -> Vec<Pass<'_, K>> {
        let mut passes = Vec::with_capacity(2);
        if let Some((p, b)) = &self.taps {
            passes.push(Pass::dispatch(PASS_SHARP, p, b, taps_args));
        }
        passes.push(Pass::dispatch(
            PASS_GLOSSY_SHARP,
            &self.add.0,
            &self.add.1,
            add_args,
        ));
        passes
    }

    /// Pass `srbf sharp`'s dispatch of one frame (glsl/srbf/sharp.comp's push constants).
    pub(crate) fn taps_args(&self, frame: &GlossyFrame) -> Dispatch {
        let mut push = super::gpu::rotation_push(frame.rotation);
        for x in [self.lobes, self.grid[0], self.grid[1]] {
            push.extend_from_slice(&x.to_le_bytes());
        }
        Dispatch {
            push,
            grid: Grid::Invocations([self.lobes, 1, 1]),
        }
    }

    /// Pass `srbf glossy sharp`'s dispatch of one frame.
    pub(crate) fn add_args(&self, frame: &GlossyFrame) -> Dispatch {
        let mut push = super::gpu::rotation_push(frame.rotation);
        let mut f32s = Vec::with_capacity(12);
        f32s.extend(frame.camera.extend(0.0).to_array());
        f32s.extend([frame.albedo[0], frame.albedo[1], frame.albedo[2], 0.0]);
        f32s.extend(self.brdf);
        for x in f32s {
            push.extend_from_slice(&x.to_le_bytes());
        }
        let words = (self.grid[0] as usize * self.grid[1] as usize).div_ceil(32) as u32;
        for x in [self.added, self.vertices, words] {
            push.extend_from_slice(&x.to_le_bytes());
        }
        push.extend_from_slice(&self.offset.to_le_bytes());
        Dispatch {
            push,
            grid: Grid::Invocations([self.vertices, 1, 1]),
        }
    }

    /// The stage's buffers and images, for the kernel's memory report.
    pub(crate) fn resources(&self) -> impl Iterator<Item = Resource<'_>> {
        self.buffers
            .iter()
            .map(Resource::Buffer)
            .chain(self.images.iter().map(Resource::storage_image))
    }
}
