//! vkshade: real-time appearance kernels as hand-written Vulkan compute pipelines.
//!
//! Modules, lowest layer first; each uses only layers below it (the table in tests/layers.rs
//! says which, and checks every import): [`error`] and [`progress`] (leaves: the error type,
//! the progress line), [`gpu`] (Vulkan: context, memory, barriers, shaders, pipelines,
//! recording, timing), [`io`] (files), [`geom`] (CPU geometry and the physics methods and
//! truths share: BVH, ray-cast visibility, spherical Gaussians), [`shaders`] (GLSL -> SPIR-V
//! and the embedded modules), [`scene`] (inputs), [`kernels`] (one module per kernel),
//! [`frame`] (the character frame: every kernel of one animated character per frame),
//! [`reference`](mod@reference) (CPU ground truths, independent of the methods: they use
//! geom, scene and the kernels' model modules alone), [`report`] (the JSON pieces every
//! command shares), [`render`] (pictures), [`bench`](mod@bench) (the benchmark harness),
//! `app` (the runs behind the CLI); the binary, main.rs, on top.
//!
//! Cargo features (all on by default): `cli` (the `vkshade` tool and `app`), `glsl` (compiling
//! GLSL with shaderc; without it only the embedded SPIR-V, and neither shaderc nor glslang is
//! needed to build), `plots` (benchmark plots, plotters), `gltf` (glTF characters), `png` (PNG
//! pictures), `exr` (linear float images). A renderer can link the library with
//! `default-features = false`; calling something compiled out is an
//! [`Error::FeatureDisabled`] naming the feature.
//!
//! # A guide for a renderer author
//!
//! vkshade records into *your* recording: you choose the device, when to submit, how many
//! frames are in flight and where each kernel's outputs go next. The steps below are the
//! whole life of a kernel; every example here runs under the Khronos validation layers on
//! lavapipe in the test suite (`cargo test --doc`), and fails on any validation message.
//!
//! ## 1. A context, a pipeline, a dispatch, a readback
//!
//! A [`gpu::Context`] is the instance, device, queue, allocator and timeline semaphore
//! ([`gpu::ContextDesc::validated`] turns on validation with synchronization checks). To wrap
//! a device you created yourself, use [`gpu::Context::from_external`]
//! (`examples/byo_device.rs` does it with plain ash and gpu-allocator, and records into its
//! own command buffers). Bindings are by the shader's variable names, checked against
//! its reflection; barriers come from declared uses.
//!
//! ```
//! use vkshade::gpu::{Buffer, BufferDesc, Context, ContextDesc, Resource};
//!
//! let ctx = Context::new(&ContextDesc::validated())?;
//! let values = {
//!     let n = 1024u32;
//!     let x: Vec<f32> = (0..n).map(|i| i as f32).collect();
//!     // An embedded module: dst[i] = a * src[i] + b (push constants a, b, n).
//!     let pipeline = vkshade::shaders::pipeline(&ctx, "test/chain_scale")?;
//!     let src = ctx.upload_buffer("x", BufferDesc::storage(4 * n as u64), &x)?;
//!     let dst = Buffer::new(&ctx, "y", BufferDesc::storage(4 * n as u64))?;
//!     let bind = pipeline.bind(&[("src", Resource::Buffer(&src)), ("dst", Resource::Buffer(&dst))])?;
//!     let push = [2.0f32.to_le_bytes(), 1.0f32.to_le_bytes(), n.to_le_bytes()].concat();
//!
//!     let mut rec = ctx.recorder("frame")?;
//!     rec.begin_pass("scale"); // a debug label and timestamps
//!     rec.dispatch_invocations_tracked(&pipeline, &bind, &push, [n, 1, 1])?;
//!     rec.end_pass();
//!     let readback = rec.read_back(&dst)?; // the barrier and the copy are recorded
//!     let timings = rec.submit_and_wait()?;
//!     assert!(timings.get("scale").is_some());
//!     readback.to_vec::<f32>()?
//! };
//! assert_eq!(values[10], 21.0);
//! // Shutting down reports leaks and late validation messages too.
//! assert!(ctx.shutdown()?.is_empty());
//! # Ok::<(), vkshade::Error>(())
//! ```
//!
//! ## 2. A kernel inside your recording
//!
//! Every kernel has the same shape ([`kernels::Kernel`], `docs/architecture.md`): its scene
//! is packed on the CPU and created on the GPU with the uploads *recorded* into your
//! recording; each frame is recorded with [`kernels::Kernel::record`] (or pass by pass, with
//! [`kernels::Kernel::plan_pass`] giving the barriers a render graph merges with its own,
//! [`kernels::record_as_graph`]); outputs are read back when you choose and collected once
//! the submission is complete. Here texture-space subsurface diffusion on a uniformly lit
//! 40 mm square: far from its edges, the diffuse light is E x R_tot, the profile's total
//! diffuse reflectance.
//!
//! ```
//! use glam::Vec3;
//! use vkshade::gpu::{Context, ContextDesc};
//! use vkshade::kernels::Kernel;
//! use vkshade::kernels::sss::{Light, Material, Profile, ProfileKind, SamplerParams, SssKernel};
//! use vkshade::scene::texspace::{TexGeometry, plane_mesh};
//!
//! let ctx = Context::new(&ContextDesc::validated())?;
//! let profile = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.99)?;
//! let geometry = TexGeometry::build(&plane_mesh(40.0, 40.0, 4)?, 64, 1.0)?;
//! let lights = [Light::Directional { toward: Vec3::Z, e: 2.0 }];
//! let output = {
//!     let mut rec = ctx.recorder("sss")?;
//!     let kernel = SssKernel::new(&mut rec, &geometry, &profile, SamplerParams::default())?;
//!     for pass in kernel.passes() {
//!         println!("{}: {} declared uses", pass.name, pass.uses.len());
//!     }
//!     kernel.record(&mut rec, &lights)?;
//!     let readback = kernel.read_back(&mut rec)?;
//!     rec.submit()?.wait()?;
//!     kernel.collect(&readback)?
//! };
//! let centre = 32 * 64 + 32;
//! let want = 2.0 * profile.r_tot[0] as f32;
//! assert!((output.diffuse[centre][0] - want).abs() < 1e-4 * want);
//! assert!(ctx.shutdown()?.is_empty());
//! # Ok::<(), vkshade::Error>(())
//! ```
//!
//! ## 3. Frames in flight, timing, memory
//!
//! [`kernels::run_frames`] keeps several frames submitted at once and hands each completed
//! one back in order; `bench::time_passes` gives the median GPU time of each pass from
//! timestamp queries; `Kernel::memory` and [`gpu::Context::memory_report`] give the device
//! memory in use. Resources stay alive while recorded work uses them: dropping a handle
//! retires it behind the last submission that used it, and a leaked handle only leaks.

#[cfg(feature = "cli")]
pub mod app;
pub mod bench;
pub mod error;
pub mod frame;
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
