//! The Vulkan layer. Nothing here knows about ambient occlusion, skin or BTFs.

pub mod context;
pub mod memory;
pub mod pipeline;
pub mod record;
pub mod shader;
pub mod sync;
pub mod validation;

pub use context::{
    Context, ContextDesc, DeviceInfo, DeviceLimits, DeviceSelector, ExternalDevice, SystemInfo,
    ValidationConfig, enumerate_devices,
};
pub use memory::{Buffer, BufferDesc, Image, ImageDesc, MemoryUsage, Sampler, SamplerDesc};
pub use pipeline::{BindGroup, ComputePipeline, Resource};
pub use record::{Barrier, PassTiming, Readback, Recorded, Recorder, Submission, Timings};
pub use shader::{BindingInfo, DescriptorKind, Shader};
pub use sync::{AccessSet, AccessType};
pub use validation::{MessageSink, Severity, ValidationMessage};
