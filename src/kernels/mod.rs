//! One module per kernel. Each owns its GPU resources, exposes `record()` so a caller can put
//! it inside its own command buffer, and has a CPU implementation of the same method.

pub mod ao;
