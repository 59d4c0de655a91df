//! vkshade: real-time appearance kernels as hand-written Vulkan compute pipelines.
//!
//! Layers, each using only those above it: [`gpu`] (Vulkan: context, memory, barriers,
//! shaders, pipelines, recording, timing), [`shaders`] (GLSL -> SPIR-V and the embedded
//! modules), [`scene`] (inputs), [`kernels`] (one module per kernel),
//! [`reference`](mod@reference) (CPU ground truths), [`bench`](mod@bench) (the benchmark
//! harness), [`io`] and [`report`] (files and the JSON pieces every command shares),
//! [`render`] (pictures).
//!
//! Cargo features (all on by default): `cli` (the `vkshade` tool and `app`), `glsl` (compiling
//! GLSL with shaderc; without it only the embedded SPIR-V, and neither shaderc nor glslang is
//! needed to build), `plots` (benchmark plots, plotters), `gltf` (glTF characters), `png` (PNG
//! pictures), `exr` (linear float images). A renderer can link the library with
//! `default-features = false`; calling something compiled out is an
//! [`Error::FeatureDisabled`] naming the feature.

#[cfg(feature = "cli")]
pub mod app;
pub mod bench;
pub mod error;
pub mod geom;
pub mod gpu;
pub mod io;
pub mod kernels;
pub mod progress;
pub mod reference;
pub mod render;
pub mod report;
pub mod scene;
pub mod shaders;

pub use error::{Error, Result};
