//! One module per kernel. Each owns its GPU resources, exposes `record()` so a caller can put
//! it inside its own command buffer, and has a CPU implementation of the same method.

pub mod ao;

/// Every kernel's GLSL includes generated from Rust: (path under glsl/, generator). The
/// shader tool writes and checks them without knowing any kernel.
pub fn generated_includes() -> impl Iterator<Item = (&'static str, fn() -> String)> {
    [ao::GENERATED_INCLUDES].into_iter().flatten().copied()
}
