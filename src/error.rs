//! The one error type of the crate: every failure names what failed and why.

use ash::vk;
use std::path::{Path, PathBuf};

/// Installation hint printed whenever no usable Vulkan driver is found.
pub const INSTALL_HINT: &str = "install a Vulkan driver and loader; on Debian 12 the software \
driver lavapipe is `apt-get install mesa-vulkan-drivers libvulkan1` (or run tools/setup.sh). \
To force lavapipe, set VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json";

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{call} failed: {result}")]
    Vk {
        call: &'static str,
        result: vk::Result,
    },

    #[error("could not load the Vulkan loader (libvulkan.so.1): {0}; {INSTALL_HINT}")]
    Loader(String),

    #[error("no usable Vulkan device: {reason}; {INSTALL_HINT}")]
    NoDevice { reason: String },

    #[error("no Vulkan device matches '{selector}'; devices present: {available}")]
    DeviceNotFound { selector: String, available: String },

    #[error(
        "validation was requested but the layer VK_LAYER_KHRONOS_validation is not installed \
         (apt-get install vulkan-validationlayers)"
    )]
    NoValidationLayer,

    #[error("device '{device}' does not support {what}")]
    Unsupported { device: String, what: String },

    #[error("GPU memory allocation for '{name}' failed: {source}")]
    Alloc {
        name: String,
        #[source]
        source: gpu_allocator::AllocationError,
    },

    #[error("{what}: {requested} exceeds the device limit {limit_name} = {limit}")]
    Limit {
        what: String,
        requested: u64,
        limit_name: &'static str,
        limit: u64,
    },

    #[error("invalid SPIR-V '{name}': {reason}")]
    Spirv { name: String, reason: String },

    #[error("compiling {path} failed:\n{message}")]
    ShaderCompile { path: PathBuf, message: String },

    #[error("pipeline '{pipeline}': {reason}")]
    Interface { pipeline: String, reason: String },

    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// Malformed or unusable input data; `path` names the file (or the in-memory source).
    #[error("{}: {message}", path.display())]
    Input { path: PathBuf, message: String },

    #[error("invalid argument: {0}")]
    InvalidArgument(String),

    /// A resource used with a context other than the one that created it (contexts never
    /// share resources, even on one device: each has its own lifetime timeline).
    #[error("{resource} belongs to {owner}, but {user} is of {context}")]
    WrongContext {
        resource: String,
        owner: String,
        user: String,
        context: String,
    },

    #[error("shutdown found leaks: {0}")]
    Leak(String),

    /// A capability compiled out of this build (see the `[features]` of Cargo.toml).
    #[error(
        "{what} needs vkshade's cargo feature `{feature}`, which this build leaves out; \
         rebuild with it (`--features {feature}`, or the default features)"
    )]
    FeatureDisabled { what: String, feature: &'static str },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An input error naming `path`.
    pub fn input(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Error::Input {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }

    /// An error saying that `what` needs the cargo feature `feature`.
    pub fn feature(what: impl Into<String>, feature: &'static str) -> Self {
        Error::FeatureDisabled {
            what: what.into(),
            feature,
        }
    }

    /// An I/O error naming `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
}

/// Attaches the name of the Vulkan call to a raw `vk::Result`.
pub(crate) trait VkResultExt<T> {
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkResultExt<T> for std::result::Result<T, vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| Error::Vk { call, result })
    }
}
