//! Hierarchical sphere ambient occlusion for skinned characters.
//!
//! Per frame, on the GPU: the pose kernel (`kernels::pose`) skins the vertices (positions,
//! normals), pass `ao skin` the sphere
//! centres with linear blend skinning; pass `ao occlusion` computes each vertex's ambient
//! visibility from a cut through the skinned sphere tree (see `glsl/ao/occlusion.comp`).
//! [`AoKernel::record`] puts both into a caller's command buffer; outputs stay on the GPU
//! (`visibility()` is usable as a vertex buffer) until read back.
//!
//! - [`pack`]: the mesh and sphere tree in the GPU's layout ([`Prepared`], also what the CPU
//!   twin reads), checked on the CPU.
//! - [`gpu`]: the kernel ([`AoKernel`]: passes `pose joints` and `pose skin` when it owns
//!   its pose, `ao skin`, `ao occlusion`).
//! - [`cpu`]: the CPU twin; [`formula`]: the per-sphere occlusion and its table.
//! - The ray-traced ground truth is `reference::ao`.

pub mod cpu;
pub mod fit;
pub mod fixed;
pub mod formula;
pub mod gpu;
pub mod pack;
mod registry;

pub use fixed::FixedCut;
pub use gpu::{
    AoKernel, FrameData, FrameReadback, PASS_JOINTS, PASS_OCCLUSION, PASS_POSE, PASS_SKIN,
};
pub use pack::Prepared;
pub use registry::{DEFAULT_ANIMATION, DEFAULT_MESH, GENERATED_INCLUDES};

use crate::error::{Error, Result};
use crate::scene::Mesh;

/// How each sphere's occlusion is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Occlusion {
    /// Bilinear lookup in the precomputed (solid angle, angle to normal) table.
    Table,
    /// The closed form, evaluated per sphere.
    Exact,
}

/// How the occlusion of several spheres combines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Blend {
    /// V = prod(1 - I_i): right for independent caps, wrong for overlapping ones.
    Product,
    /// V = 1 - sum I_i: exact for disjoint caps, overcounts overlap.
    Sum,
    /// Cone-mask union: sum I_i scaled by |union of cap masks| / sum of mask counts over 128
    /// cosine-distributed directions; exact for disjoint and for coincident caps.
    Mask,
}

/// How the cut decides to refine an inner node: when size > tau * distance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Refine {
    /// size = the node's radius (the published test).
    Radius,
    /// size = the node's extent: the farthest reach of its skinned leaves from its centre.
    /// An elongated cluster (an arm) is refined when its leaves come near, not only when its
    /// compact sphere does.
    Extent,
}

/// Which spheres a vertex sums.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Cut {
    /// A cut through the skinned tree walked anew every frame (refined where size > tau *
    /// distance, blended over `band`), overlap by the blend mode.
    #[default]
    Adaptive,
    /// The published variant: per vertex a fixed list of nodes chosen once in the bind pose
    /// ([`fixed::FixedCut`]) and reused in every pose, overlap by the pairwise 3D table
    /// ([`formula::OverlapTable`]); `band` and `blend` are not used.
    Fixed,
}

/// Method parameters. tau is a push constant; the modes are specialization constants of
/// the occlusion pipeline (see [`AoKernel::set_params`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct AoParams {
    /// Refine an inner node when size / distance > tau; in (0, 1].
    pub tau: f32,
    /// Width of the blend of a node into its children, as a fraction of the refinement
    /// distance (see [`cpu::refinement`]); 0 = the hard cut, which pops when it changes.
    pub band: f32,
    pub refine: Refine,
    pub occlusion: Occlusion,
    pub blend: Blend,
    /// A receiver inside a leaf sphere: clamp h to 1 (true) or skip that sphere (false).
    pub clamp_inside: bool,
    /// Multiply by the static correction factors (see [`Correction`]).
    pub correct: bool,
    /// The adaptive cut (walked per frame) or the published fixed one.
    pub cut: Cut,
}

impl Default for AoParams {
    fn default() -> Self {
        AoParams {
            tau: 0.8,
            band: 0.5,
            refine: Refine::Extent,
            occlusion: Occlusion::Table,
            blend: Blend::Mask,
            clamp_inside: false,
            correct: true,
            cut: Cut::Adaptive,
        }
    }
}

impl AoParams {
    pub fn validate(&self) -> Result<()> {
        if !(self.tau > 0.0 && self.tau <= 1.0) {
            return Err(Error::InvalidArgument(format!(
                "tau = {} is outside (0, 1]",
                self.tau
            )));
        }
        if !(0.0..=4.0).contains(&self.band) {
            return Err(Error::InvalidArgument(format!(
                "band = {} is outside [0, 4]",
                self.band
            )));
        }
        Ok(())
    }

    /// The occlusion pipeline's specialization constants for these parameters.
    fn specialization(&self) -> [(&'static str, u32); 5] {
        [
            ("EXACT", (self.occlusion == Occlusion::Exact) as u32),
            (
                "BLEND",
                match self.blend {
                    Blend::Product => 0,
                    Blend::Sum => 1,
                    Blend::Mask => 2,
                },
            ),
            ("CLAMP_INSIDE", self.clamp_inside as u32),
            ("CORRECT", self.correct as u32),
            ("REFINE", (self.refine == Refine::Extent) as u32),
        ]
    }
}

/// The static correction: per-vertex factors baked once in the bind pose that restore the
/// detail a sphere set cannot represent (geometry buried under overlapping shells, thin
/// folds, grooves between tight parts).
///
/// factor = V_mesh / V_method in the bind pose, capped at [`Correction::cap`]; V_mesh is
/// ray-traced against the bind-pose mesh, V_method is this method's own result there with
/// the same parameters. In the bind pose the corrected method thus equals the ray-traced
/// mesh; in other poses the spheres carry the change. It is an addition to the published
/// method; `correct: false` gives the method alone.
#[derive(Clone, Debug)]
pub struct Correction {
    /// Ray-traced visibility of every vertex in the bind pose.
    pub bind_visibility: Vec<f32>,
    /// Upper bound of a factor (factors > 1 brighten where the spheres over-occlude).
    pub cap: f32,
}

impl Correction {
    /// Ray-traces the bind pose (`rays` per vertex; its own seed, independent of any
    /// reference the result is later compared with).
    pub fn bake(mesh: &Mesh, rays: usize) -> Correction {
        let (lo, hi) = mesh.bounds();
        let cfg = crate::geom::visibility::RayConfig {
            rays,
            seed: 0xba4e_d0ff,
            ..crate::geom::visibility::RayConfig::for_scene((hi - lo).length())
        };
        let bvh = crate::geom::Bvh::build(&mesh.positions, &mesh.triangles);
        let all: Vec<usize> = (0..mesh.positions.len()).collect();
        Correction {
            bind_visibility: crate::geom::visibility::ambient_visibility(
                &mesh.positions,
                &mesh.normals,
                &bvh,
                &all,
                &cfg,
            ),
            cap: 2.0,
        }
    }

    /// Factors for `params`: the method evaluated (on the CPU) in the bind pose.
    pub fn factors(&self, cpu_ao: &cpu::CpuAo, prep: &Prepared, params: &AoParams) -> Vec<f32> {
        // The bind pose: identity joint matrices (weights sum to 1).
        let bind = cpu::skin(prep, &vec![glam::Mat4::IDENTITY; prep.joint_count]);
        let plain = AoParams {
            correct: false,
            ..*params
        };
        self.ratio(&cpu_ao.frame(&bind, prep.shape, &plain, None))
    }

    /// Factors for the fixed cut (`params.cut` = [`Cut::Fixed`]) with the lists `fixed`: the
    /// fixed-cut method evaluated (on the CPU) in the bind pose.
    pub fn fixed_factors(
        &self,
        cpu_ao: &cpu::CpuAo,
        prep: &Prepared,
        fixed: &FixedCut,
        params: &AoParams,
    ) -> Vec<f32> {
        let bind = cpu::skin(prep, &vec![glam::Mat4::IDENTITY; prep.joint_count]);
        let plain = AoParams {
            correct: false,
            ..*params
        };
        self.ratio(&cpu_ao.fixed_frame(&bind, fixed, &plain, None))
    }

    /// The truth over the method per vertex, capped (1 where the method sees no light).
    fn ratio(&self, method: &[cpu::VertexAo]) -> Vec<f32> {
        method
            .iter()
            .zip(&self.bind_visibility)
            .map(|(m, t)| {
                if m.visibility > 1e-3 {
                    (t / m.visibility).min(self.cap)
                } else {
                    1.0
                }
            })
            .collect()
    }
}
