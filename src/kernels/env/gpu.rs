//! The environment kernel on the GPU: `env rotate` rotates the fitted lobes by the frame's
//! rotation into the `lobes` buffer, `env shadow` computes per vertex each lobe's visibility
//! from the caps of AO's sphere-tree cut and the shadowed irradiance. Built once on a
//! character's [`PoseKernel`] (posed positions, normals) and [`AoKernel`] (posed spheres and
//! extents, visibility); the caller records the pose and AO before this kernel each frame
//! (barriers follow from the declared accesses).

use super::cpu::Shadowed;
use super::pack::{CapTable, pack_lobes};
use super::{MIN_TRANSMISSION, check_rotation};
use crate::error::{Error, Result};
use crate::geom::sg::Lobe;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::ao::{AoKernel, AoParams, Refine, cpu::TreeShape};
use crate::kernels::pose::PoseKernel;
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::Mat3;

/// The rotation of the lobes (label and timing name).
pub const PASS_ROTATE: &str = "env rotate";
/// The per-vertex shadowing and irradiance.
pub const PASS_SHADOW: &str = "env shadow";

/// One frame's outputs recorded for readback.
pub struct EnvReadback {
    lobes: Readback,
    visibility: Readback,
    irradiance: Readback,
}

/// Host copies of one frame's outputs.
#[derive(Clone, Debug)]
pub struct EnvFrame {
    /// The rotated lobes (the `lobes` buffer).
    pub lobes: Vec<Lobe>,
    /// V_j and irradiance per vertex.
    pub shadowed: Shadowed,
}

impl EnvReadback {
    /// The data, once the submission holding the readback is complete.
    pub fn data(&self) -> Result<EnvFrame> {
        let packed: Vec<[f32; 4]> = self.lobes.to_vec()?;
        Ok(EnvFrame {
            lobes: packed
                .chunks(2)
                .map(|c| Lobe {
                    axis: [c[0][0], c[0][1], c[0][2]],
                    sharpness: c[0][3],
                    amplitude: [c[1][0], c[1][1], c[1][2]],
                })
                .collect(),
            shadowed: Shadowed {
                visibility: self.visibility.to_vec()?,
                irradiance: self.irradiance.to_vec()?,
            },
        })
    }
}

/// Environment lighting shadowed by the character, per frame on the GPU.
pub struct EnvKernel {
    ctx: Context,
    rotate: ComputePipeline,
    rotate_bind: BindGroup,
    shadow: ComputePipeline,
    shadow_bind: BindGroup,
    /// (binding name, buffer): the kernel's own and those it reads from the pose and AO.
    buffers: Vec<(&'static str, Buffer)>,
    base: Vec<Lobe>,
    table: CapTable,
    vertex_count: u32,
    shape: TreeShape,
    params: AoParams,
}

/// The kernel's own buffers (the memory report counts these).
const OWN: [&str; 5] = ["base", "lobes", "table", "vis", "irr"];

impl EnvKernel {
    /// Creates the buffers and pipelines and records the uploads of the lobes (fitted once,
    /// unrotated) and the cap table into `rec` (nothing is submitted here). `pose` and `ao`
    /// are the character's (AO built [`AoKernel::on_pose`] on `pose`); their buffers are
    /// bound, not copied, and AO's cut parameters are taken now (build again after
    /// [`AoKernel::set_params`]). Refuses 0 or more than [`super::MAX_LOBES`] lobes, invalid
    /// lobes, and an AO of another vertex count.
    pub fn new(
        rec: &mut Recorder,
        lobes: &[Lobe],
        pose: &PoseKernel,
        ao: &AoKernel,
    ) -> Result<EnvKernel> {
        let packed = pack_lobes(lobes)?;
        if ao.vertex_count() != pose.vertex_count() {
            return Err(Error::InvalidArgument(format!(
                "the AO kernel has {} vertices, the pose {}",
                ao.vertex_count(),
                pose.vertex_count()
            )));
        }
        let ctx = rec.context();
        let table = CapTable::new();
        let (nv, nj) = (pose.vertex_count() as u64, lobes.len() as u64);
        let base = rec.buffer_with("env base lobes", BufferDesc::storage(nj * 32), &packed[..])?;
        let quads = table.quads();
        let table_buf = rec.buffer_with(
            "env cap table",
            BufferDesc::storage(quads.len() as u64 * 16),
            &quads[..],
        )?;
        let output = |name: &str, size: u64| {
            let desc = BufferDesc::storage(size)
                .usage(vk::BufferUsageFlags::VERTEX_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC);
            Buffer::new(&ctx, name, desc)
        };
        let buffers: Vec<(&'static str, Buffer)> = vec![
            ("base", base),
            ("lobes", output("env lobes", nj * 32)?),
            ("table", table_buf),
            ("vis", output("env visibility", nv * nj * 4)?),
            ("irr", output("env irradiance", nv * 16)?),
            ("pos", pose.positions().clone()),
            ("nrm", pose.normals().clone()),
            ("sph", ao.posed_spheres().clone()),
            ("ext", ao.posed_extents().clone()),
            ("ao", ao.visibility().clone()),
        ];
        let bind = |pipeline: &ComputePipeline, writes: &[&str]| {
            let lookup = |b: &str| {
                buffers
                    .iter()
                    .find(|(n, _)| *n == b)
                    .map(|(_, r)| Resource::Buffer(r))
            };
            let w = AccessSet::from(A::ComputeShaderWrite);
            let writes: Vec<(&str, AccessSet)> = writes.iter().map(|&b| (b, w)).collect();
            pipeline.bind_from(lookup, &writes)
        };
        let rotate = crate::shaders::pipeline(&ctx, "env/rotate")?;
        let shadow = crate::shaders::pipeline(&ctx, "env/shadow")?;
        let rotate_bind = bind(&rotate, &["lobes"])?;
        let shadow_bind = bind(&shadow, &["vis", "irr"])?;
        Ok(EnvKernel {
            ctx,
            rotate,
            rotate_bind,
            shadow,
            shadow_bind,
            buffers,
            base: lobes.to_vec(),
            table,
            vertex_count: nv as u32,
            shape: ao.tree_shape(),
            params: *ao.params(),
        })
    }

    fn buffer(&self, binding: &str) -> &Buffer {
        &self
            .buffers
            .iter()
            .find(|(n, _)| *n == binding)
            .expect("every binding name is created in EnvKernel::new")
            .1
    }

    /// The frame's rotated lobes: per lobe two vec4, (axis.xyz world, sharpness),
    /// (amplitude.rgb, 0); written by `env rotate`.
    pub fn lobes(&self) -> &Buffer {
        self.buffer("lobes")
    }

    /// Number of lobes.
    pub fn lobe_count(&self) -> usize {
        self.base.len()
    }

    /// The lobes as fitted (unrotated), as given to [`EnvKernel::new`].
    pub fn base_lobes(&self) -> &[Lobe] {
        &self.base
    }

    /// V_j per vertex and lobe, f32 [vertex * lobe_count + j], in [0, 1]: the visibility of
    /// lobe j weighted by the cosine; written by `env shadow`.
    pub fn visibility(&self) -> &Buffer {
        self.buffer("vis")
    }

    /// Shadowed irradiance per vertex: vec4 (sum_j V_j E_j(n) amplitude_j rgb, 0),
    /// radiometric (no 1/pi); written by `env shadow`.
    pub fn irradiance(&self) -> &Buffer {
        self.buffer("irr")
    }

    /// Vertices shaded per frame.
    pub fn vertex_count(&self) -> usize {
        self.vertex_count as usize
    }

    /// The cap table the shadow pass looks up (the CPU twin uses the same).
    pub fn table(&self) -> &CapTable {
        &self.table
    }

    /// AO's cut parameters, as taken at construction.
    pub fn ao_params(&self) -> &AoParams {
        &self.params
    }

    /// Records one frame (`env rotate`, `env shadow`) for the environment rotated by
    /// `rotation` (finite, orthonormal); barriers from the declared accesses.
    pub fn record(&self, rec: &mut Recorder, rotation: &Mat3) -> Result<()> {
        Kernel::record(self, rec, rotation)
    }

    /// Records copies of the outputs back to the host (tests and tools).
    pub fn read_back(&self, rec: &mut Recorder) -> Result<EnvReadback> {
        Ok(EnvReadback {
            lobes: rec.read_back(self.lobes())?,
            visibility: rec.read_back(self.visibility())?,
            irradiance: rec.read_back(self.irradiance())?,
        })
    }

    /// Device memory of the kernel's own buffers.
    pub fn memory(&self) -> MemoryReport {
        let own: Vec<&Buffer> = OWN.iter().map(|b| self.buffer(b)).collect();
        self.ctx.memory_of(&own)
    }

    fn rotate_args(&self, r: &Mat3) -> Result<Dispatch> {
        let c = r.to_cols_array();
        let mut words = Vec::with_capacity(13);
        for col in 0..3 {
            words.extend((0..3).map(|k| c[col * 3 + k].to_bits()));
            words.push(0);
        }
        words.push(self.base.len() as u32);
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.base.len() as u32, 1, 1]),
        ))
    }

    fn shadow_args(&self, _r: &Mat3) -> Result<Dispatch> {
        let s = self.shape;
        let p = &self.params;
        let words = [
            self.vertex_count,
            self.base.len() as u32,
            s.node_count,
            s.branch,
            s.first_leaf,
            p.tau.to_bits(),
            p.band.to_bits(),
            (p.refine == Refine::Extent) as u32,
            p.clamp_inside as u32,
            MIN_TRANSMISSION.to_bits(),
        ];
        Ok(Dispatch::words(
            &words,
            Grid::Invocations([self.vertex_count, 1, 1]),
        ))
    }
}

impl Kernel for EnvKernel {
    type Input = Mat3;
    type Readback = EnvReadback;
    type Output = EnvFrame;

    fn name(&self) -> &'static str {
        "env"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::dispatch(
                PASS_ROTATE,
                &self.rotate,
                &self.rotate_bind,
                Self::rotate_args,
            ),
            Pass::dispatch(
                PASS_SHADOW,
                &self.shadow,
                &self.shadow_bind,
                Self::shadow_args,
            ),
        ]
    }

    fn check_input(&self, r: &Mat3) -> Result<()> {
        check_rotation(r)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<EnvReadback> {
        EnvKernel::read_back(self, rec)
    }

    fn collect(&self, readback: &EnvReadback) -> Result<EnvFrame> {
        readback.data()
    }

    fn memory(&self) -> MemoryReport {
        EnvKernel::memory(self)
    }
}
