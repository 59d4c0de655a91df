//! vkshade: real-time appearance kernels as hand-written Vulkan compute pipelines.
//!
//! Modules, lowest layer first; each uses only layers below it (the table in tests/layers.rs
//! says which, and checks every import): [`error`] and [`progress`] (leaves: the error type,
//! the progress line), [`gpu`] (Vulkan: context, memory, barriers, shaders, pipelines,
//! recording, timing), [`io`] (files), [`geom`] (CPU geometry and the physics methods and
//! truths share: BVH, ray-cast visibility, spherical Gaussians), [`shaders`] (GLSL -> SPIR-V
//! and the embedded modules), [`scene`] (inputs), [`kernels`] (one module per kernel),
//! [`reference`](mod@reference) (CPU ground truths, independent of the methods: they use
//! geom, scene and the kernels' model modules alone), [`report`] (the JSON pieces every
//! command shares), [`render`] (pictures), [`bench`](mod@bench) (the benchmark harness),
//! `app` (the runs behind the CLI); the binary, main.rs, on top.
//!
//! Cargo features (all on by default): `cli` (the `vkshade` tool and `app`), `plots`
//! (benchmark plots, plotters), `gltf` (glTF characters), `png` (PNG pictures), `exr` (linear
//! float images). A renderer can link the library with `default-features = false`; calling
//! something compiled out is an [`Error::FeatureDisabled`] naming the feature.

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
