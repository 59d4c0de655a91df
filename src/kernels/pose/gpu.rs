//! The posed-geometry kernel on the GPU: pass `pose joints` uploads the frame's skinning
//! matrices, `pose skin` writes posed positions, normals and tangents. Created from a
//! [`Prepared`] (packed and checked on the CPU, `pack.rs`).

use super::{Prepared, check_matrices};
use crate::error::Result;
use crate::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context,
    MemoryReport, Readback, Recorder, Resource,
};
use crate::kernels::{Dispatch, Grid, Kernel, Pass};
use ash::vk;
use glam::Mat4;

/// The upload of the frame's skinning matrices (its label and timing name).
pub const PASS_JOINTS: &str = "pose joints";
/// The skinning dispatch.
pub const PASS_SKIN: &str = "pose skin";

/// The posed vertices of a frame, read back (for tests and tools; a frame itself never
/// reads them back).
pub struct PoseReadback {
    positions: Readback,
    normals: Readback,
    tangents: Readback,
}

impl PoseReadback {
    /// The posed vertices, once the submission holding the readback is complete.
    pub fn data(&self) -> Result<super::cpu::Posed> {
        let v3 = |v: Vec<[f32; 4]>| -> Vec<glam::Vec3> {
            v.iter()
                .map(|p| glam::Vec4::from_array(*p).truncate())
                .collect()
        };
        Ok(super::cpu::Posed {
            positions: v3(self.positions.to_vec()?),
            normals: v3(self.normals.to_vec()?),
            tangents: self
                .tangents
                .to_vec::<[f32; 4]>()?
                .into_iter()
                .map(glam::Vec4::from_array)
                .collect(),
        })
    }
}

/// One skinning pass per frame for a character; other kernels bind its output buffers.
pub struct PoseKernel {
    ctx: Context,
    skin: ComputePipeline,
    skin_bind: BindGroup,
    /// (binding name, buffer) of every buffer, in the shader's binding names.
    buffers: Vec<(&'static str, Buffer)>,
    vertex_count: u32,
    joint_count: usize,
}

/// The bindings the skinning pass writes.
const WRITES: [&str; 3] = ["pos", "nrm", "tan"];

impl PoseKernel {
    /// Creates the buffers and the pipeline, and records the uploads of the rest pose into
    /// `rec` (they run when the caller submits it; nothing is submitted here).
    pub fn new(rec: &mut Recorder, prep: &Prepared) -> Result<PoseKernel> {
        use bytemuck::cast_slice as bytes;
        prep.check()?;
        let ctx = rec.context();
        let nv = prep.vertex_count() as u64;
        let output = |name: &str| {
            let desc = BufferDesc::storage(nv * 16)
                .usage(vk::BufferUsageFlags::VERTEX_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC);
            Buffer::new(&ctx, name, desc)
        };
        let mut buffers = Vec::new();
        let rest: [(&'static str, &str, &[u8]); 5] = [
            ("rest_pos", "pose rest positions", bytes(&prep.positions)),
            ("rest_nrm", "pose rest normals", bytes(&prep.normals)),
            ("rest_tan", "pose rest tangents", bytes(&prep.tangents)),
            ("vjoints", "pose vertex joints", bytes(&prep.vertex_joints)),
            (
                "vweights",
                "pose vertex weights",
                bytes(&prep.vertex_weights),
            ),
        ];
        for (binding, name, data) in rest {
            let desc = BufferDesc::storage(data.len() as u64);
            buffers.push((binding, rec.buffer_with(name, desc, data)?));
        }
        let joints = BufferDesc::storage(prep.joint_count as u64 * 64);
        buffers.push(("joints", Buffer::new(&ctx, "pose joint matrices", joints)?));
        buffers.push(("pos", output("pose positions")?));
        buffers.push(("nrm", output("pose normals")?));
        buffers.push(("tan", output("pose tangents")?));
        let skin = crate::shaders::pipeline(&ctx, "pose/skin")?;
        let lookup = |b: &str| {
            buffers
                .iter()
                .find(|(n, _)| *n == b)
                .map(|(_, r)| Resource::Buffer(r))
        };
        let w = AccessSet::from(A::ComputeShaderWrite);
        let writes: Vec<(&str, AccessSet)> = WRITES.iter().map(|&b| (b, w)).collect();
        let skin_bind = skin.bind_from(lookup, &writes)?;
        Ok(PoseKernel {
            ctx,
            skin,
            skin_bind,
            buffers,
            vertex_count: nv as u32,
            joint_count: prep.joint_count,
        })
    }

    fn buffer(&self, binding: &str) -> &Buffer {
        // The names are this module's constants; every one is created in `new`.
        &self
            .buffers
            .iter()
            .find(|(n, _)| *n == binding)
            .expect("every binding name is created in PoseKernel::new")
            .1
    }

    /// Posed positions: vec4 per vertex, xyz in model units, w = 1.
    pub fn positions(&self) -> &Buffer {
        self.buffer("pos")
    }

    /// Posed unit normals: vec4 per vertex, w = 0.
    pub fn normals(&self) -> &Buffer {
        self.buffer("nrm")
    }

    /// Posed unit tangents (+u, orthogonal to the normal): vec4 per vertex, w = handedness
    /// (+v runs along `w * normal x tangent`).
    pub fn tangents(&self) -> &Buffer {
        self.buffer("tan")
    }

    /// The frame's skinning matrices (mat4 per joint, column-major), written by `pose joints`:
    /// a kernel that skins something else with the same rig (AO's spheres) reads them.
    pub fn joint_matrices(&self) -> &Buffer {
        self.buffer("joints")
    }

    /// Vertices posed per frame.
    pub fn vertex_count(&self) -> usize {
        self.vertex_count as usize
    }

    /// Joints of the rig (matrices per frame).
    pub fn joint_count(&self) -> usize {
        self.joint_count
    }

    /// Records one frame's passes (`pose joints`, `pose skin`); barriers come from the
    /// declared accesses. The matrices are staged through the context's ring, so frames in
    /// flight never overwrite each other's.
    pub fn record(&self, rec: &mut Recorder, matrices: &[Mat4]) -> Result<()> {
        Kernel::record(self, rec, matrices)
    }

    /// Records copies of the posed vertices back to the host (tests and tools).
    pub fn read_back(&self, rec: &mut Recorder) -> Result<PoseReadback> {
        Ok(PoseReadback {
            positions: rec.read_back(self.positions())?,
            normals: rec.read_back(self.normals())?,
            tangents: rec.read_back(self.tangents())?,
        })
    }

    /// Device memory of the kernel's buffers.
    pub fn memory(&self) -> MemoryReport {
        let all: Vec<&Buffer> = self.buffers.iter().map(|(_, b)| b).collect();
        self.ctx.memory_of(&all)
    }

    fn joint_bytes(&self, matrices: &[Mat4]) -> Result<Vec<u8>> {
        let cols: Vec<[f32; 16]> = matrices.iter().map(|m| m.to_cols_array()).collect();
        Ok(bytemuck::cast_slice(&cols).to_vec())
    }

    fn skin_args(&self, _matrices: &[Mat4]) -> Result<Dispatch> {
        Ok(Dispatch::words(
            &[self.vertex_count],
            Grid::Invocations([self.vertex_count, 1, 1]),
        ))
    }
}

impl Kernel for PoseKernel {
    type Input = [Mat4];
    type Readback = PoseReadback;
    type Output = super::cpu::Posed;

    fn name(&self) -> &'static str {
        "pose"
    }

    fn pass_table(&self) -> Vec<Pass<'_, Self>> {
        vec![
            Pass::upload(PASS_JOINTS, self.joint_matrices(), Self::joint_bytes),
            Pass::dispatch(PASS_SKIN, &self.skin, &self.skin_bind, Self::skin_args),
        ]
    }

    fn check_input(&self, matrices: &[Mat4]) -> Result<()> {
        check_matrices(matrices, self.joint_count)
    }

    fn read_back(&self, rec: &mut Recorder) -> Result<PoseReadback> {
        PoseKernel::read_back(self, rec)
    }

    fn collect(&self, readback: &PoseReadback) -> Result<super::cpu::Posed> {
        readback.data()
    }

    fn memory(&self) -> MemoryReport {
        PoseKernel::memory(self)
    }
}
