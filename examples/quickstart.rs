//! The README's library example: y = a * x + b on the GPU, under validation.
//! Run with `cargo run --release --example quickstart`.

use vkshade::gpu::{Buffer, BufferDesc, ComputePipeline, Context, ContextDesc, Resource};

fn main() -> vkshade::Result<()> {
    let n = 1u32 << 20;
    let data: Vec<f32> = (0..n).map(|i| i as f32).collect();

    let ctx = Context::new(&ContextDesc::validated())?; // validation + sync validation
    // Resources keep the device alive: they are dropped at the end of this block.
    let (values, ms) = {
        let spirv = vkshade::shaders::spirv("test/chain_scale")?; // any compute SPIR-V
        let pipeline = ComputePipeline::from_spirv(&ctx, "scale", spirv)?; // layout from reflection
        let x = ctx.upload_buffer("x", BufferDesc::storage(4 * n as u64), &data)?; // staged, waited
        let y = Buffer::new(&ctx, "y", BufferDesc::storage(4 * n as u64))?; // device-local
        let bind =
            pipeline.bind(&[("src", Resource::Buffer(&x)), ("dst", Resource::Buffer(&y))])?;
        let push = [2.0f32.to_le_bytes(), 1.0f32.to_le_bytes(), n.to_le_bytes()].concat();

        let mut rec = ctx.recorder("frame")?;
        rec.begin_pass("scale"); // debug label + timestamps
        rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])?; // barriers from uses
        rec.end_pass();
        let out = rec.read_back(&y)?; // tracked barrier + copy to the host
        let timings = rec.submit_and_wait()?; // GPU milliseconds per pass
        let values: Vec<f32> = out.to_vec()?;
        (values, timings.get("scale").unwrap_or(f64::NAN))
    };
    println!(
        "y[12345] = {} ({} elements in {:.3} ms of GPU time)",
        values[12345], n, ms
    );
    let messages = ctx.shutdown()?; // leaks and late validation messages too
    for m in &messages {
        eprintln!("{m}");
    }
    assert!(messages.is_empty(), "validation messages");
    Ok(())
}
