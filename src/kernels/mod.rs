//! One module per kernel. Each owns its GPU resources, exposes `record()` so a caller can put
//! it inside its own command buffer, and has a CPU implementation of the same method.

pub mod ao;
pub mod btf;
pub mod compose;
pub mod contract;
pub mod env;
pub mod pose;
pub mod raster;
pub mod srbf;
pub mod sss;

pub use contract::{
    Dispatch, FrameResult, Grid, IndirectArgs, Kernel, KernelInfo, Pass, PassInfo, Step, UseInfo,
    record_as_graph, run_frames,
};
pub use env::EnvKernel;

pub use crate::shaders::GeneratedInclude;

/// Every kernel's generated GLSL includes; a new kernel adds its list here. The shader tool
/// writes and checks them without knowing any kernel.
pub fn generated_includes() -> impl Iterator<Item = GeneratedInclude> {
    [ao::GENERATED_INCLUDES].into_iter().flatten().copied()
}

/// Texels per row of the images that hold a kernel's long tables (the tree in `ao skin`'s
/// image, the CTA and CPCA tables): 4096, or the device's `maxImageDimension2D` when it is
/// smaller. The shaders take it as a specialization constant (`NODE_ROW`, `CTA_ROW`,
/// `SRBF_ROW`), so texel t at (t % row, t / row) divides by a constant.
pub(crate) fn table_row(ctx: &crate::gpu::Context) -> u32 {
    ctx.limits().max_image_dimension_2d.clamp(1, 4096)
}
