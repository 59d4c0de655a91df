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
    Dispatch, EMPTY_LIST_HEAD, FrameResult, Grid, IndirectArgs, Kernel, KernelInfo, Pass, PassInfo,
    Step, UseInfo, list_entries, record_as_graph, run_frames,
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

/// A 2D image for a table of `texels` texels laid out in rows of [`table_row`] texels
/// (texel t at (t % row, t / row)). More rows than the device's `maxImageDimension2D` is
/// an error naming the table (`name`) and what to change (`advice`, may be empty).
pub(crate) fn row_image(
    ctx: &crate::gpu::Context,
    name: &str,
    format: ash::vk::Format,
    texels: u64,
    usage: ash::vk::ImageUsageFlags,
    advice: &str,
) -> crate::error::Result<crate::gpu::Image> {
    let row = table_row(ctx);
    let rows = texels.div_ceil(u64::from(row)).max(1);
    let max = ctx.limits().max_image_dimension_2d;
    if rows > u64::from(max) {
        return Err(crate::error::Error::InvalidArgument(format!(
            "{name}: {texels} texels need {rows} image rows of {row}, more than the device's \
             maxImageDimension2D ({max}){advice}"
        )));
    }
    crate::gpu::Image::new(
        ctx,
        name,
        crate::gpu::ImageDesc::d2(format, [row, rows as u32]).usage(usage),
    )
}
