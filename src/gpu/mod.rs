//! The Vulkan layer. Nothing here knows about ambient occlusion, skin or BTFs.
//!
//! - [`context`]: instance, device, queue, allocator, validation, the timeline.
//! - [`memory`]: buffers, placement, alias groups, memory reports.
//! - [`image`]: images, views, samplers.
//! - [`sync`]: access types mapped to synchronization2 barriers.
//! - [`track`]: per-resource (and per-subresource) state tracking for declared uses.
//! - [`shader`], [`pipeline`]: reflection, pipelines, bind groups with declared accesses.
//! - [`record`]: recordings, submissions, staged uploads and readbacks, timestamps.
//! - `lifetime`, `staging`, `recycle`: deferred destruction, the staging ring, and reuse of
//!   per-frame objects (command pools, query pools, readback buffers).

#![warn(missing_docs)]

pub mod context;
pub mod image;
mod lifetime;
pub mod memory;
pub mod pipeline;
pub mod record;
mod recycle;
pub mod shader;
mod staging;
pub mod sync;
pub mod track;
pub mod validation;

pub use context::{
    Context, ContextDesc, DeviceInfo, DeviceLimits, DeviceSelector, ExternalDevice, Features,
    LimitOverrides, MemoryConfig, SystemInfo, ValidationConfig, enumerate_devices,
};
pub use image::{
    FormatBlock, Image, ImageDesc, ImageDim, ImageRegion, Sampler, SamplerDesc, Subresources,
    ViewDesc, format_block, is_bc,
};
pub use memory::{
    AliasGroup, AliasMember, Buffer, BufferDesc, Dedicated, Location, MemoryReport, Placement,
};
pub use pipeline::{BindGroup, ComputePipeline, DeclaredUse, ImageRef, Resource, default_access};
pub use record::{
    AliasUse, Barrier, BarrierMode, DISPATCH_INDIRECT_SIZE, PassTiming, PlannedBarrier, Readback,
    Recorded, Recorder, Submission, Timings, Use, dispatched_pipelines,
};
pub use recycle::CreationCounts;
pub use shader::{BindingInfo, DescriptorKind, SampledType, Shader};
pub use sync::{AccessSet, AccessType};
pub use validation::{MessageSink, Severity, ValidationMessage};
