//! vkshade: real-time appearance kernels as hand-written Vulkan compute pipelines.
//!
//! Layers, each using only those above it: [`gpu`] (Vulkan: context, memory, barriers,
//! shaders, pipelines, recording, timing), [`shaders`] (GLSL -> SPIR-V and the embedded
//! modules), [`bench`] (the benchmark harness).

pub mod app;
pub mod bench;
pub mod error;
pub mod geom;
pub mod gpu;
pub mod kernels;
pub mod reference;
pub mod render;
pub mod scene;
pub mod shaders;

pub use error::{Error, Result};
