//! The SSS kernel on the GPU: pass `sss lights` uploads the frame's lights, `sss irradiance`
//! computes E per texel with BVH shadow rays, `sss diffusion` importance-samples the
//! profile in texture space. The irradiance buffer can also be filled by the caller
//! ([`SssKernel::upload_irradiance`], e.g. from another kernel) and diffused alone
//! ([`SssKernel::record_diffusion`]).

use super::cpu::{Light, MAX_LIGHTS, SamplerParams, check_lights, shadow_bias, vertex_frames};
use super::profile::{Profile, ProfileKind};
use super::texspace::TexGeometry;
use crate::error::{Error, Result};
use crate::geom::bvh::Bvh;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, MemoryReport, PlannedBarrier, Readback, Recorder, Resource,
};
use ash::vk;
use crate::kernels::{Kernel, PassInfo, UseInfo};

pub const PASS_LIGHTS: &str = "sss lights";
pub const PASS_VERTEX: &str = "sss vertex light";
pub const PASS_IRRADIANCE: &str = "sss irradiance";
pub const PASS_DIFFUSION: &str = "sss diffusion";
const PASSES: [&str; 4] = [PASS_LIGHTS, PASS_VERTEX, PASS_IRRADIANCE, PASS_DIFFUSION];
/// Most samples per texel (the shader's uniform sample sequence: 64 KiB, the
/// maxUniformBufferRange of lavapipe and of most desktop GPUs; checked at run time).
pub const MAX_SAMPLES: u32 = 4096;
const SEQUENCE_BYTES: u64 = MAX_SAMPLES as u64 * 16;

/// Host copies of a frame: irradiance, diffuse (rgba per texel; diffuse alpha is the
/// accepted fraction of the samples) and transmission (rgb; alpha the thickness in mm, 0
/// where nothing transmits).
#[derive(Clone, Debug)]
pub struct SssOutput {
    pub irradiance: Vec<[f32; 4]>,
    pub diffuse: Vec<[f32; 4]>,
    pub transmission: Vec<[f32; 4]>,
}

pub struct SssReadback {
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
    inputs: Vec<Buffer>,
    /// The shared sample sequence ([`Profile::mixture_sequence`]), a uniform buffer.
    seq: Buffer,
    /// Copies of the positions and the irradiance as RGBA32F storage images (the
    /// diffusion's gathers).
    pos_img: Image,
    irr_img: Image,
    lights: Buffer,
    irr: Buffer,
    diffuse: Buffer,
    trans: Buffer,
    size: u32,
    bias: f32,
    profile: Profile,
    params: SamplerParams,
}

impl SssKernel {
    /// Creates buffers and pipelines for `geo` and records the uploads into `rec`.
    pub fn new(
        rec: &mut Recorder,
        geo: &TexGeometry,
        profile: &Profile,
        params: SamplerParams,
    ) -> Result<SssKernel> {
        params.check()?;
        let ctx = rec.context();
        let spv = |name| crate::shaders::spirv(name);
        let vertex =
            ComputePipeline::from_spirv(&ctx, "sss/vertex_light", spv("sss/vertex_light")?)?;
        let irradiance =
            ComputePipeline::from_spirv(&ctx, "sss/irradiance", spv("sss/irradiance")?)?;
        let diffusion = ComputePipeline::from_spirv(&ctx, "sss/diffusion", spv("sss/diffusion")?)?;
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let (nodes, tris) = bvh.flat();
        let ubo_limit = ctx.limits().max_uniform_buffer_range;
        if ubo_limit < SEQUENCE_BYTES {
            return Err(Error::InvalidArgument(format!(
                "the SSS sampler needs a uniform buffer of {SEQUENCE_BYTES} bytes; the device \
                 allows {ubo_limit} (maxUniformBufferRange)"
            )));
        }
        let mut upload = |name: &str, bytes: &[u8]| {
            rec.buffer_with(name, BufferDesc::storage(bytes.len() as u64), bytes)
        };
        let pos = upload("sss positions", bytemuck::cast_slice(&geo.pos))?;
        let nrm = upload("sss normals", bytemuck::cast_slice(&geo.nrm))?;
        let dpdu = upload("sss dP/du", bytemuck::cast_slice(&geo.dpdu))?;
        let dpdv = upload("sss dP/dv", bytemuck::cast_slice(&geo.dpdv))?;
        let texel_tri = upload("sss texel triangles", bytemuck::cast_slice(&geo.texel_tri))?;
        let verts = upload("sss vertices", bytemuck::cast_slice(&vertex_frames(geo)))?;
        let tri_idx: Vec<[u32; 4]> = geo.triangles.iter().map(|t| [t[0], t[1], t[2], 0]).collect();
        let tri_idx = upload("sss triangle corners", bytemuck::cast_slice(&tri_idx))?;
        // Room for any hierarchy over this many triangles (a rebuilt one may have more
        // nodes): at most 2 n - 1.
        let mut node_room = nodes.clone();
        node_room.resize((2 * geo.triangles.len()).max(nodes.len()), [0.0; 8]);
        let nodes = upload("sss bvh nodes", bytemuck::cast_slice(&node_room))?;
        let tris = upload("sss bvh triangles", bytemuck::cast_slice(&tris))?;
        let seq = rec.buffer_with(
            "sss sample sequence",
            BufferDesc::uniform(SEQUENCE_BYTES),
            &profile.mixture_sequence(params.samples),
        )?;
        let lights = Buffer::new(
            &ctx,
            "sss lights",
            BufferDesc::storage(MAX_LIGHTS as u64 * 32),
        )?;
        let texels = geo.texels() as u64;
        // The diffusion's gathers read positions and irradiance from RGBA32F storage images
        // (lavapipe fetches a texel's four channels at once; a storage-buffer load at a
        // per-lane index runs a loop over the lanes for every component).
        let img_desc = ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [geo.size, geo.size])
            .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST);
        let pos_img = Image::new(&ctx, "sss position image", img_desc)?;
        rec.upload_image(&pos_img, ImageRegion::whole(&img_desc), bytemuck::cast_slice(&geo.pos))?;
        let irr_img = Image::new(&ctx, "sss irradiance image", img_desc)?;
        let nv = geo.positions.len() as u64;
        let vis = Buffer::new(&ctx, "sss vertex visibility", BufferDesc::storage(nv * 4))?;
        let vtrans = Buffer::new(&ctx, "sss vertex transmission", BufferDesc::storage(nv * 16))?;
        let irr = Buffer::new(&ctx, "sss irradiance", BufferDesc::storage(texels * 16))?;
        let diffuse = Buffer::new(&ctx, "sss diffuse", BufferDesc::storage(texels * 16))?;
        let trans = Buffer::new(&ctx, "sss transmission", BufferDesc::storage(texels * 16))?;
        let w = AccessSet::from(A::ComputeShaderWrite);
        let vertex_bind = vertex.bind_declared(
            &[
                ("verts", Resource::Buffer(&verts)),
                ("nodes", Resource::Buffer(&nodes)),
                ("tris", Resource::Buffer(&tris)),
                ("lights", Resource::Buffer(&lights)),
                ("vis", Resource::Buffer(&vis)),
                ("vtrans", Resource::Buffer(&vtrans)),
            ],
            &[("vis", w), ("vtrans", w)],
        )?;
        let irradiance_bind = irradiance.bind_declared(
            &[
                ("pos", Resource::Buffer(&pos)),
                ("nrm", Resource::Buffer(&nrm)),
                ("texel_tri", Resource::Buffer(&texel_tri)),
                ("tri_idx", Resource::Buffer(&tri_idx)),
                ("lights", Resource::Buffer(&lights)),
                ("vis", Resource::Buffer(&vis)),
                ("vtrans", Resource::Buffer(&vtrans)),
                ("irr", Resource::Buffer(&irr)),
                ("trans", Resource::Buffer(&trans)),
                ("irr_img", Resource::storage_image(&irr_img)),
            ],
            &[("irr", w), ("trans", w), ("irr_img", w)],
        )?;
        let diffusion_bind = diffusion.bind_declared(
            &[
                ("pos", Resource::Buffer(&pos)),
                ("nrm", Resource::Buffer(&nrm)),
                ("dpdu", Resource::Buffer(&dpdu)),
                ("dpdv", Resource::Buffer(&dpdv)),
                ("irr", Resource::Buffer(&irr)),
                ("seq", Resource::Buffer(&seq)),
                ("pos_img", Resource::storage_image(&pos_img)),
                ("irr_img", Resource::storage_image(&irr_img)),
                ("diffuse", Resource::Buffer(&diffuse)),
            ],
            &[("diffuse", w)],
        )?;
        Ok(SssKernel {
            ctx,
            vertex,
            vertex_bind,
            vertices: nv as u32,
            irradiance,
            irradiance_bind,
            diffusion,
            diffusion_bind,
            inputs: vec![
                pos, nrm, dpdu, dpdv, nodes, tris, texel_tri, verts, tri_idx, vis, vtrans,
            ],
            seq,
            pos_img,
            irr_img,
            lights,
            irr,
            diffuse,
            trans,
            size: geo.size,
            bias: shadow_bias(geo.extent_mm()),
            profile: profile.clone(),
            params,
        })
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// Records the upload of a new pose of the same mesh (same texture size, same triangles
    /// and UV layout; e.g. the skinned mesh of the next frame re-rasterised): the texel
    /// geometry and a rebuilt BVH.
    pub fn update_geometry(&self, rec: &mut Recorder, geo: &TexGeometry) -> Result<()> {
        let [pos, nrm, dpdu, dpdv, nodes, tris, texel_tri, verts, ..] = &self.inputs[..] else {
            return Err(Error::InvalidArgument(
                "SSS kernel without its inputs".into(),
            ));
        };
        if geo.size != self.size
            || (tris.size() as usize) != geo.triangles.len() * 48
            || geo.positions.len() != self.vertices as usize
        {
            return Err(Error::InvalidArgument(format!(
                "new geometry ({}^2, {} triangles) does not match the kernel's ({}^2, {} \
                 triangles)",
                geo.size,
                geo.triangles.len(),
                self.size,
                tris.size() / 48
            )));
        }
        let bvh = Bvh::build(&geo.positions, &geo.triangles);
        let (n, t) = bvh.flat();
        if (n.len() * 32) as u64 > nodes.size() {
            return Err(Error::InvalidArgument("BVH larger than its buffer".into()));
        }
        rec.upload(pos, 0, &geo.pos)?;
        rec.upload(nrm, 0, &geo.nrm)?;
        rec.upload(dpdu, 0, &geo.dpdu)?;
        rec.upload(dpdv, 0, &geo.dpdv)?;
        rec.upload_image(
            &self.pos_img,
            ImageRegion::whole(self.pos_img.desc()),
            bytemuck::cast_slice(&geo.pos),
        )?;
        rec.upload(texel_tri, 0, &geo.texel_tri)?;
        rec.upload(verts, 0, &vertex_frames(geo))?;
        rec.upload(nodes, 0, &n)?;
        rec.upload(tris, 0, &t)
    }

    pub fn params(&self) -> &SamplerParams {
        &self.params
    }

    /// Changes the sampler settings: records the upload of the new sample sequence.
    pub fn set_params(&mut self, rec: &mut Recorder, params: SamplerParams) -> Result<()> {
        params.check()?;
        rec.upload(&self.seq, 0, &self.profile.mixture_sequence(params.samples))?;
        self.params = params;
        Ok(())
    }

    /// The irradiance buffer (rgba per texel, row-major), written by `sss irradiance`.
    pub fn irradiance(&self) -> &Buffer {
        &self.irr
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
        rec.upload(&self.irr, 0, e)?;
        rec.upload_image(
            &self.irr_img,
            ImageRegion::whole(self.irr_img.desc()),
            bytemuck::cast_slice(e),
        )
    }

    /// The transmission buffer (rgb, alpha thickness), written by `sss irradiance`.
    pub fn transmission(&self) -> &Buffer {
        &self.trans
    }

    fn record_vertex_light(&self, rec: &mut Recorder, lights: usize) -> Result<()> {
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
        let push: Vec<u8> = words.iter().flat_map(|x| x.to_le_bytes()).collect();
        rec.dispatch_invocations_tracked(
            &self.vertex,
            &self.vertex_bind,
            &push,
            [self.vertices, 1, 1],
        )
    }

    fn record_irradiance(&self, rec: &mut Recorder, lights: usize) -> Result<()> {
        let words = [self.size, lights as u32, self.params.transmission as u32];
        let push: Vec<u8> = words.iter().flat_map(|x| x.to_le_bytes()).collect();
        rec.dispatch_invocations_tracked(
            &self.irradiance,
            &self.irradiance_bind,
            &push,
            [self.size, self.size, 1],
        )
    }

    /// Records the diffusion dispatch alone (barriers from the declared accesses).
    pub fn record_diffusion(&self, rec: &mut Recorder) -> Result<()> {
        let k = self.profile.k.map(|k| k as f32);
        let mut push: Vec<u8> = [k[0], k[1], k[2], 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        for u in [
            self.size,
            self.params.samples,
            self.params.seam_rel.to_bits(),
            self.params.seam_texels.to_bits(),
        ] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        rec.dispatch_invocations_tracked(
            &self.diffusion,
            &self.diffusion_bind,
            &push,
            [self.size, self.size, 1],
        )
    }
}

impl Kernel for SssKernel {
    type Input = [Light];
    type Readback = SssReadback;
    type Output = SssOutput;

    fn name(&self) -> &'static str {
        "sss"
    }

    fn passes(&self) -> Vec<PassInfo> {
        let uses = |b: &BindGroup| b.accesses().into_iter().map(UseInfo::from).collect();
        vec![
            PassInfo {
                name: PASS_LIGHTS,
                uses: vec![UseInfo {
                    binding: "(upload)".into(),
                    resource: self.lights.name().to_string(),
                    access: format!("{:?}", AccessSet::from(A::TransferWrite)),
                }],
            },
            PassInfo {
                name: PASS_VERTEX,
                uses: uses(&self.vertex_bind),
            },
            PassInfo {
                name: PASS_IRRADIANCE,
                uses: uses(&self.irradiance_bind),
            },
            PassInfo {
                name: PASS_DIFFUSION,
                uses: uses(&self.diffusion_bind),
            },
        ]
    }

    fn record_pass(&self, rec: &mut Recorder, pass: usize, lights: &[Light]) -> Result<()> {
        check_lights(lights)?;
        let name = PASSES
            .get(pass)
            .ok_or_else(|| Error::InvalidArgument(format!("SSS has 4 passes, not {}", pass + 1)))?;
        rec.begin_pass(name);
        let r = match pass {
            0 => {
                let data: Vec<[[f32; 4]; 2]> = lights.iter().map(|l| l.gpu()).collect();
                if data.is_empty() {
                    Ok(())
                } else {
                    rec.upload(&self.lights, 0, &data)
                }
            }
            1 => self.record_vertex_light(rec, lights.len()),
            2 => self.record_irradiance(rec, lights.len()),
            _ => self.record_diffusion(rec),
        };
        rec.end_pass();
        r
    }

    fn plan_pass(&self, rec: &mut Recorder, pass: usize) -> Result<Vec<PlannedBarrier>> {
        match pass {
            0 => rec.plan(&[crate::gpu::Use::Buffer(
                &self.lights,
                A::TransferWrite.into(),
            )]),
            1 => Ok(rec.plan_dispatch(&self.vertex_bind)),
            2 => Ok(rec.plan_dispatch(&self.irradiance_bind)),
            3 => Ok(rec.plan_dispatch(&self.diffusion_bind)),
            _ => Err(Error::InvalidArgument(format!(
                "SSS has 4 passes, not {}",
                pass + 1
            ))),
        }
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<SssReadback> {
        Ok(SssReadback {
            irradiance: rec.read_back(&self.irr)?,
            diffuse: rec.read_back(&self.diffuse)?,
            transmission: rec.read_back(&self.trans)?,
        })
    }

    fn collect(&self, rb: &SssReadback) -> Result<SssOutput> {
        Ok(SssOutput {
            irradiance: rb.irradiance.to_vec()?,
            diffuse: rb.diffuse.to_vec()?,
            transmission: rb.transmission.to_vec()?,
        })
    }

    fn memory(&self) -> MemoryReport {
        let all: Vec<&Buffer> = self
            .inputs
            .iter()
            .chain([&self.seq, &self.lights, &self.irr, &self.diffuse, &self.trans])
            .collect();
        let buffers = self.ctx.memory_of(&all);
        MemoryReport {
            used_bytes: buffers.used_bytes
                + self.pos_img.allocation_size()
                + self.irr_img.allocation_size(),
            allocations: buffers.allocations + 2,
            ..buffers
        }
    }
}
