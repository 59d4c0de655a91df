//! The glossy SRBF kernel with CTA-compressed transfer ([`super::cta`]) on the GPU, each
//! frame: `srbf lighting` (the lighting's coefficients on the basis), `srbf cta light`
//! (per cluster y_c = L_c^T c^), `srbf cta project` (per cluster M_c = G_c x_3 y_c, an
//! r_v x r_w RGB table) and `srbf cta shade` (per vertex: the view taps, the interpolated
//! view-factor row u_w and B = albedo u_v^T M_c u_w), then with compact lobes
//! ([`super::glossy_sharp`]) `srbf glossy sharp`, which adds them onto that radiance.
//! [`CtaInputs::cpu_pipeline`] is the CPU twin of them all.

use super::cta::Cta;
use super::glossy::{ViewBasis, local_view};
use super::glossy_gpu::{GlossyFrame, compact_args};
use super::glossy_sharp::{CompactStage, GlossyCompact};
use super::pack::MAX_BASIS;
use crate::error::{Error, Result};
use crate::geom::sg::Lobe;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::io::f16::f16_bits;
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::Vec3;
use rayon::prelude::*;

pub const PASS_LIGHTING: &str = "srbf lighting";
pub const PASS_CTA_LIGHT: &str = "srbf cta light";
pub const PASS_CTA_PROJECT: &str = "srbf cta project";
pub const PASS_CTA_SHADE: &str = "srbf cta shade";

/// The largest view rank `srbf cta shade` holds (its local array).
pub const MAX_VIEW_RANK: usize = 32;

/// What the CTA kernel is built from: the transfer's view rows are those of `view`.
pub struct CtaInputs<'a> {
    pub lobes: &'a [Lobe],
    pub transfer: &'a Cta,
    pub view: &'a ViewBasis,
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    /// The lobes shaded directly (`lobes` are those through the basis).
    pub compact: Option<GlossyCompact<'a>>,
}

impl CtaInputs<'_> {
    /// Checks sizes and values (the shaders index with them).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("CTA SRBF input: {what}")));
        if self.lobes.is_empty() || self.lobes.len() > 65_536 {
            return bad(format!("{} lighting lobes (1..=65536)", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        let t = self.transfer;
        t.check()?;
        self.view.check()?;
        if t.views != self.view.views() {
            return bad(format!(
                "a transfer of {} view rows for a view basis of {} ({})",
                t.views,
                self.view.views(),
                self.view.describe()
            ));
        }
        // The shader's view row: r_w, or the m terms a factored basis folds in.
        let rw = match self.view {
            ViewBasis::Grid(_) => t.ranks[1],
            ViewBasis::Brdf(f) => f.terms,
        };
        if t.basis.len() > MAX_BASIS || rw > MAX_VIEW_RANK {
            return bad(format!(
                "{} basis functions (1..={MAX_BASIS}), view rank (or BRDF terms) {rw} \
                 (1..={MAX_VIEW_RANK})",
                t.basis.len(),
            ));
        }
        if self.positions.len() != t.vertices || self.normals.len() != t.vertices {
            return bad(format!(
                "{} positions and {} normals for a transfer of {} vertices",
                self.positions.len(),
                self.normals.len(),
                t.vertices
            ));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return bad(format!("position {i} is not finite"));
        }
        if let Some(i) = self
            .normals
            .iter()
            .position(|n| !n.is_finite() || (n.length() - 1.0).abs() > 1e-3)
        {
            return bad(format!("normal {i} is not a unit vector"));
        }
        if let Some(c) = &self.compact {
            c.check_for(t.vertices, Some(self.positions))?;
        }
        Ok(())
    }

    /// The CPU twin of one frame (f32 lighting coefficients, f64 sums).
    pub fn cpu_pipeline(&self, frame: &GlossyFrame) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        frame.check()?;
        let t = self.transfer;
        let coeffs = super::transfer::lighting_coefficients(self.lobes, frame.rotation, &t.basis);
        let m = t.project(&coeffs)?;
        let [rv, rw, _] = t.ranks;
        let views = t.views;
        let mut out: Vec<[f64; 3]> = (0..t.vertices)
            .into_par_iter()
            .map(|v| {
                let c = t.cluster_of[v] as usize;
                let taps =
                    self.view
                        .weights(local_view(self.positions[v], self.normals[v], frame.camera));
                let mut uw = vec![0f64; rw];
                for (j, w) in taps {
                    for (b, x) in uw.iter_mut().enumerate() {
                        *x += w as f64 * t.view_factors[(c * views + j) * rw + b] as f64;
                    }
                }
                let mut out = [0f64; 3];
                for a in 0..rv {
                    let u = t.coeff(v, a) as f64;
                    for (b, x) in uw.iter().enumerate() {
                        let mm = m[(c * rv + a) * rw + b];
                        for ch in 0..3 {
                            out[ch] += u * mm[ch] * x;
                        }
                    }
                }
                [0, 1, 2].map(|ch| out[ch] * frame.albedo[ch] as f64)
            })
            .collect();
        if let Some(c) = &self.compact {
            c.add(frame, self.positions, self.normals, &mut out)?;
        }
        Ok(out)
    }
}

/// What `srbf cta project` and `srbf cta shade` read for a view basis: (cores, view table,
/// view rank, whether the table is shared by all clusters). A view grid's are the model's
/// own (C cores of r_v x r_w x r_l, C view factors of N^2 x r_w). For the BRDF's
/// factorisation the view factor is folded into the core once here,
/// G'_c[a, j, l] = sum_b G_c[a, b, l] W_c[j, b] (r_w becomes m), and the view table is the
/// factor table g_j(o) that every cluster shares: a vertex's view lookup then reads 4 m values
/// of one 48 x 48 x m table instead of a per-cluster table (expanded at the nodes it would be
/// 14 MB for 64 clusters at m = r_w = 24, and its gathers missed the cache: 22 ms a frame on
/// the bunny). The result is what the CPU twin computes, summed in another order.
fn gpu_view_model(t: &Cta, view: &ViewBasis) -> (Vec<f32>, Vec<f32>, usize, bool) {
    let [rv, rw, rl] = t.ranks;
    match view {
        ViewBasis::Grid(_) => (t.cores.clone(), t.view_factors.clone(), rw, false),
        ViewBasis::Brdf(f) => {
            let m = f.terms;
            let mut cores = vec![0f32; t.clusters * rv * m * rl];
            cores
                .par_chunks_mut(rv * m * rl)
                .enumerate()
                .for_each(|(c, out)| {
                    let g = &t.cores[c * rv * rw * rl..(c + 1) * rv * rw * rl];
                    let w = &t.view_factors[c * m * rw..(c + 1) * m * rw];
                    for a in 0..rv {
                        for j in 0..m {
                            for l in 0..rl {
                                out[(a * m + j) * rl + l] = (0..rw)
                                    .map(|b| g[(a * rw + b) * rl + l] as f64 * w[j * rw + b] as f64)
                                    .sum::<f64>()
                                    as f32;
                            }
                        }
                    }
                });
            (cores, f.view.clone(), m, true)
        }
    }
}

/// `rows` of `width` values as texels of four, each row zero-padded to ceil(width / 4)
/// texels (the layout of the view table, the light factors and the cores).
fn quads(rows: &[f32], width: usize) -> Vec<[f32; 4]> {
    rows.chunks_exact(width)
        .flat_map(|r| {
            r.chunks(4)
                .map(|c| std::array::from_fn(|j| c.get(j).copied().unwrap_or(0.0)))
        })
        .collect()
}

/// The GPU kernel of CTA-compressed glossy transfer.
pub struct CtaKernel {
    ctx: Context,
    stages: [(ComputePipeline, BindGroup); 4],
    /// Pass `srbf glossy sharp` (None without compact lobes).
    compact: Option<CompactStage>,
    buffers: Vec<Buffer>,
    /// The view table, the per-cluster tables M_c and the vertex coefficients
    /// (glsl/srbf/cta_shade.comp); the light factors, the cores and the projected light
    /// (cta_light.comp, cta_project.comp).
    images: [Image; 6],
    vertices: u32,
    grid: u32,
    /// (r_v, r_w, r_l) as the GPU holds them (r_w = m for a factored view basis).
    ranks: [u32; 3],
    shared: u32,
    clusters: u32,
    basis: u32,
    lobes: u32,
    sharpness: f32,
}

const RADIANCE: usize = 0;

impl CtaKernel {
    /// Checks `inputs`, creates the buffers and pipelines and records the uploads into `rec`.
    pub fn new(rec: &mut Recorder, inputs: &CtaInputs<'_>) -> Result<CtaKernel> {
        inputs.check()?;
        let ctx = rec.context();
        let t = inputs.transfer;
        let (cores, view_table, rw, shared) = gpu_view_model(t, inputs.view);
        let [rv, _, rl] = t.ranks;
        fn storage<T: bytemuck::Pod>(rec: &mut Recorder, name: &str, data: &[T]) -> Result<Buffer> {
            let bytes: &[u8] = bytemuck::cast_slice(data);
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        }
        let vec4 =
            |v: &[Vec3]| -> Vec<[f32; 4]> { v.iter().map(|x| x.extend(0.0).into()).collect() };
        let radiance = Buffer::new(
            &ctx,
            "srbf cta radiance",
            BufferDesc::storage(t.vertices as u64 * 16).usage(vk::BufferUsageFlags::VERTEX_BUFFER),
        )?;
        let (lobe_axes, lobe_amps) = super::glossy_gpu::lobe_arrays(inputs.lobes);
        // The shading order: by cluster, then along a Morton curve of the positions.
        let mut order = crate::geom::spatial_order(inputs.positions);
        order.sort_by_key(|&v| t.cluster_of[v as usize]);
        let gather = |rows: &[f32], width: usize| -> Vec<f32> {
            order
                .iter()
                .flat_map(|&v| {
                    rows[v as usize * width..(v as usize + 1) * width]
                        .iter()
                        .copied()
                })
                .collect()
        };
        let sorted = |v: &[Vec3]| -> Vec<Vec3> { order.iter().map(|&i| v[i as usize]).collect() };
        let buffers = vec![
            radiance,
            storage(rec, "srbf cta lobe axes", &lobe_axes)?,
            storage(rec, "srbf cta lobe amplitudes", &lobe_amps)?,
            storage(rec, "srbf cta basis axes", &vec4(&t.basis.axes))?,
            rec.buffer_with(
                "srbf cta coefficients",
                BufferDesc::storage(MAX_BASIS as u64 * 16)
                    .usage(vk::BufferUsageFlags::UNIFORM_BUFFER),
                &vec![[0f32; 4]; MAX_BASIS],
            )?,
            // With the cluster id packed into the coefficient texels the shader never reads
            // this buffer (PACKED_CLUSTER is a specialization constant), so one placeholder
            // word fills the binding.
            storage(
                rec,
                "srbf cta clusters",
                &if t.cluster_in_texel() {
                    vec![0u32]
                } else {
                    order
                        .iter()
                        .map(|&v| t.cluster_of[v as usize])
                        .collect::<Vec<u32>>()
                },
            )?,
            storage(rec, "srbf cta positions", &vec4(&sorted(inputs.positions)))?,
            storage(rec, "srbf cta normals", &vec4(&sorted(inputs.normals)))?,
            storage(rec, "srbf cta order", &order)?,
        ];
        let [
            _,
            axes,
            amps,
            basis_axes,
            coeffs,
            clusters,
            points,
            normals,
            shade_order,
        ] = std::array::from_fn(|i| &buffers[i]);
        // The view table, KW = ceil(r_w / 4) texels a node (zero-padded), and M_c: images
        // `row` texels wide (`CTA_ROW` in glsl/srbf/cta_shade.comp).
        let row = crate::kernels::table_row(&ctx);
        let kw = rw.div_ceil(4);
        let view_texels = quads(&view_table, rw);
        let image_of = |name: &str, format: vk::Format, texels: usize, hint: &str| {
            crate::kernels::row_image(
                &ctx,
                name,
                format,
                texels as u64,
                vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST,
                hint,
            )
        };
        let image = |name: &str, texels: usize| -> Result<Image> {
            image_of(
                name,
                vk::Format::R32G32B32A32_SFLOAT,
                texels,
                "; use fewer clusters or lower ranks",
            )
        };
        let view_image = image("srbf cta view factors", view_texels.len())?;
        rec.upload_image_rows(&view_image, &view_texels)?;
        let m_image = image("srbf cta cluster tables", t.clusters * rv * 3 * kw)?;
        // The light factor (C x K x KL texels) and the core (C x r_v x 4 KW x KL texels),
        // four light ranks a texel, zero-padded in r_l and (the core) in r_w; y, the lighting
        // on each cluster's light factor, C x 3 x KL texels (glsl/srbf/cta_light.comp,
        // cta_project.comp).
        let kl = rl.div_ceil(4);
        let light_texels = quads(&t.light_factors, rl);
        let light_image = image("srbf cta light factors", light_texels.len())?;
        rec.upload_image_rows(&light_image, &light_texels)?;
        let padded_cores: Vec<f32> = cores
            .chunks_exact(rw * rl)
            .flat_map(|g| {
                g.iter()
                    .copied()
                    .chain(std::iter::repeat_n(0.0, (4 * kw - rw) * rl))
            })
            .collect();
        let core_texels = quads(&padded_cores, rl);
        let core_image = image("srbf cta cores", core_texels.len())?;
        rec.upload_image_rows(&core_image, &core_texels)?;
        let y_image = image("srbf cta projected light", t.clusters * 3 * kl)?;
        // Half precision, eight coefficients a texel (u32 j of texel q holds coefficients
        // 8q + 2j, low half, and 8q + 2j + 1): the image loads per vertex stay those of
        // four f32 a texel at half the ranks. Where the last texel's w is free it holds the
        // vertex's cluster id (`Cta::cluster_in_texel`).
        let kv = rv.div_ceil(8);
        let packed = t.cluster_in_texel();
        let half = |u: &[f32], i: usize| u.get(i).map_or(0, |x| f16_bits(*x) as u32);
        let coeff_texels: Vec<[u32; 4]> = gather(&t.coeffs, rv)
            .chunks_exact(rv)
            .zip(&order)
            .flat_map(|(u, &v)| {
                let cluster = t.cluster_of[v as usize];
                (0..kv).map(move |q| {
                    std::array::from_fn(|j| {
                        if packed && q == kv - 1 && j == 3 {
                            cluster
                        } else {
                            half(u, 8 * q + 2 * j) | half(u, 8 * q + 2 * j + 1) << 16
                        }
                    })
                })
            })
            .collect();
        let coeff_image = image_of(
            "srbf cta vertex coefficients",
            vk::Format::R32G32B32A32_UINT,
            coeff_texels.len(),
            "; use fewer vertices or a lower vertex rank",
        )?;
        rec.upload_image_rows(&coeff_image, &coeff_texels)?;
        let (b, w) = (Resource::Buffer, AccessSet::from(A::ComputeShaderWrite));
        let (view, m) = (
            Resource::storage_image(&view_image),
            Resource::storage_image(&m_image),
        );
        let pipeline = |name| crate::shaders::pipeline(&ctx, name);
        let lighting = pipeline("srbf/lighting")?;
        let lighting_bind = lighting.bind_declared(
            &[
                ("lobe_axes", b(axes)),
                ("lobe_amps", b(amps)),
                ("basis_axes", b(basis_axes)),
                ("coeffs", b(coeffs)),
            ],
            &[("coeffs", w)],
        )?;
        let light_p =
            crate::shaders::pipeline_specialized(&ctx, "srbf/cta_light", &[("CTA_ROW", row)])?;
        let y = Resource::storage_image(&y_image);
        let light_bind = light_p.bind_declared(
            &[
                ("light", Resource::storage_image(&light_image)),
                ("coeffs", b(coeffs)),
                ("y", y.clone()),
            ],
            &[("y", w)],
        )?;
        let project =
            crate::shaders::pipeline_specialized(&ctx, "srbf/cta_project", &[("CTA_ROW", row)])?;
        let project_bind = project.bind_declared(
            &[
                ("cores", Resource::storage_image(&core_image)),
                ("y", y),
                ("m", m.clone()),
            ],
            &[("m", w)],
        )?;
        let shade = crate::shaders::pipeline_specialized(
            &ctx,
            "srbf/cta_shade",
            &[
                ("RV", rv as u32),
                ("RW", rw as u32),
                ("CTA_ROW", row),
                ("PACKED_CLUSTER", packed as u32),
            ],
        )?;
        let shade_bind = shade.bind_declared(
            &[
                ("vcoeffs", Resource::storage_image(&coeff_image)),
                ("cluster", b(clusters)),
                ("view", view),
                ("m", m),
                ("points", b(points)),
                ("normals", b(normals)),
                ("radiance", b(&buffers[RADIANCE])),
                ("order", b(shade_order)),
            ],
            &[("radiance", w)],
        )?;
        let compact = match &inputs.compact {
            Some(c) => {
                CompactStage::new(rec, c, inputs.positions, inputs.normals, &buffers[RADIANCE])?
            }
            None => None,
        };
        Ok(CtaKernel {
            ctx,
            compact,
            stages: [
                (lighting, lighting_bind),
                (light_p, light_bind),
                (project, project_bind),
                (shade, shade_bind),
            ],
            vertices: t.vertices as u32,
            grid: inputs.view.grid().n,
            ranks: [rv, rw, rl].map(|r| r as u32),
            shared: shared as u32,
            clusters: t.clusters as u32,
            basis: t.basis.len() as u32,
            lobes: inputs.lobes.len() as u32,
            sharpness: t.basis.sharpness,
            buffers,
            images: [
                view_image,
                m_image,
                coeff_image,
                light_image,
                core_image,
                y_image,
            ],
        })
    }

    /// Per-vertex RGB radiance toward the camera (vec4, alpha 1).
    pub fn radiance(&self) -> &Buffer {
        &self.buffers[RADIANCE]
    }

    fn lighting_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        let mut push = super::gpu::rotation_push(frame.rotation);
        push.extend_from_slice(&self.lobes.to_le_bytes());
        push.extend_from_slice(&self.basis.to_le_bytes());
        push.extend_from_slice(&self.sharpness.to_le_bytes());
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.basis, 1, 1]),
        })
    }

    fn light_args(&self, _frame: &GlossyFrame) -> Result<Dispatch> {
        let kl = self.ranks[2].div_ceil(4);
        let entries = self.clusters * kl;
        Ok(Dispatch::words(
            &[entries, kl, self.basis],
            Grid::Invocations([entries, 1, 1]),
        ))
    }

    fn project_args(&self, _frame: &GlossyFrame) -> Result<Dispatch> {
        let [rv, rw, rl] = self.ranks;
        let kw = rw.div_ceil(4);
        let entries = self.clusters * rv * kw;
        Ok(Dispatch::words(
            &[entries, kw, rv, rl.div_ceil(4)],
            Grid::Invocations([entries, 1, 1]),
        ))
    }

    fn compact_taps_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        compact_args(&self.compact, frame, CompactStage::taps_args)
    }

    fn compact_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        compact_args(&self.compact, frame, CompactStage::add_args)
    }

    /// The compact lobes pass `srbf glossy sharp` adds (0: no such pass).
    pub fn compact_count(&self) -> usize {
        self.compact.as_ref().map_or(0, CompactStage::lobes)
    }

    fn shade_args(&self, frame: &GlossyFrame) -> Result<Dispatch> {
        let (c, a) = (frame.camera, frame.albedo);
        let push: Vec<u8> = [c.x, c.y, c.z, 0.0, a[0], a[1], a[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .chain(
                [self.vertices, self.grid, self.shared]
                    .iter()
                    .flat_map(|x| x.to_le_bytes()),
            )
            .collect();
        Ok(Dispatch {
            push,
            grid: Grid::Invocations([self.vertices, 1, 1]),
        })
    }
}

impl Kernel for CtaKernel {
    type Input = GlossyFrame;
    type Readback = Readback;
    type Output = Vec<[f32; 3]>;

    fn name(&self) -> &'static str {
        "srbf cta"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        let [l, y, m, s] = &self.stages;
        let mut passes = vec![
            Pass::dispatch(PASS_LIGHTING, &l.0, &l.1, Self::lighting_args),
            Pass::dispatch(PASS_CTA_LIGHT, &y.0, &y.1, Self::light_args),
            Pass::dispatch(PASS_CTA_PROJECT, &m.0, &m.1, Self::project_args),
            Pass::dispatch(PASS_CTA_SHADE, &s.0, &s.1, Self::shade_args),
        ];
        if let Some(c) = &self.compact {
            passes.extend(c.passes(Self::compact_taps_args, Self::compact_args));
        }
        passes
    }

    fn check_input(&self, frame: &GlossyFrame) -> Result<()> {
        frame.check()
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<Readback> {
        rec.read_back(&self.buffers[RADIANCE])
    }

    fn collect(&self, readback: &Readback) -> Result<Vec<[f32; 3]>> {
        let v: Vec<[f32; 4]> = readback.to_vec()?;
        Ok(v.iter().map(|x| [x[0], x[1], x[2]]).collect())
    }

    fn memory(&self) -> MemoryReport {
        self.ctx.memory_of_resources(
            self.buffers
                .iter()
                .map(Resource::Buffer)
                .chain(self.images.iter().map(Resource::storage_image))
                .chain(self.compact.iter().flat_map(CompactStage::resources)),
        )
    }
}
