//! The instance: the Vulkan loader, the validation layer with its features, and the
//! messenger that turns validation messages into [`ValidationMessage`](crate::gpu::ValidationMessage)s.

use super::REQUIRED_API;
use crate::error::{Error, Result, VkResultExt};
use crate::gpu::validation::{MessageSink, debug_callback};
use ash::vk;
use std::ffi::{CStr, c_char};
use std::sync::Arc;

pub(super) const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// What the Khronos validation layer checks.
#[derive(Clone, Debug)]
pub struct ValidationConfig {
    /// Synchronization validation (hazards between accesses); on by default.
    pub synchronization: bool,
    /// Best-practices warnings.
    pub best_practices: bool,
    /// GPU-assisted validation (instrumented shaders; slow).
    pub gpu_assisted: bool,
    /// `messageIdNumber`s to drop (documented false positives only).
    pub ignored_ids: Vec<i32>,
    /// A sink that receives a copy of every message, `ignored_ids` included (besides the
    /// context's own sink, which
    /// [`Context::shutdown`](crate::gpu::Context::shutdown) returns): lets a caller count the
    /// messages of contexts made deep inside a command (`vkshade validate`).
    pub tee: Option<Arc<MessageSink>>,
}

/// Message ids ignored by default, each a documented false positive for vkshade.
pub const DEFAULT_IGNORED_IDS: &[(i32, &str)] = &[(
    0x822806fa_u32 as i32,
    "BestPractices-vkCreateInstance-specialuse-extension-debugging: warns that \
     VK_EXT_debug_utils / VK_EXT_validation_features are debugging extensions; enabling them \
     for debugging is exactly what a validated context does",
)];

impl Default for ValidationConfig {
    fn default() -> Self {
        ValidationConfig {
            synchronization: true,
            best_practices: true,
            gpu_assisted: false,
            ignored_ids: DEFAULT_IGNORED_IDS.iter().map(|(id, _)| *id).collect(),
            tee: None,
        }
    }
}

pub(super) fn load_entry() -> Result<ash::Entry> {
    // SAFETY: loading the system Vulkan loader; its initialisation has no preconditions.
    unsafe { ash::Entry::load() }.map_err(|e| Error::Loader(e.to_string()))
}

pub(super) fn layer_present(entry: &ash::Entry, name: &CStr) -> Result<bool> {
    // SAFETY: plain enumeration.
    let layers = unsafe { entry.enumerate_instance_layer_properties() }
        .vk("vkEnumerateInstanceLayerProperties")?;
    Ok(layers
        .iter()
        .any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == name)))
}

fn extension_present(entry: &ash::Entry, layer: Option<&CStr>, name: &CStr) -> Result<bool> {
    // SAFETY: plain enumeration.
    let exts = unsafe { entry.enumerate_instance_extension_properties(layer) }
        .vk("vkEnumerateInstanceExtensionProperties")?;
    Ok(exts
        .iter()
        .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name)))
}

/// An instance with validation and messenger, before a device exists.
///
/// Fields drop in declaration order: `partial` (which destroys the instance on failure)
/// must go before the sink its messenger writes to and the loader (`entry`).
pub(super) struct InstanceParts {
    /// Destroys the instance if a later step fails.
    pub(super) partial: Partial,
    pub(super) sink: Arc<MessageSink>,
    pub(super) instance: ash::Instance,
    pub(super) debug_instance: Option<ash::ext::debug_utils::Instance>,
    pub(super) messenger: vk::DebugUtilsMessengerEXT,
    pub(super) entry: ash::Entry,
}

/// Creates the instance, with the validation layer, its features and the messenger chained
/// in when `validation` is given.
pub(super) fn create_instance(validation: Option<&ValidationConfig>) -> Result<InstanceParts> {
    let entry = load_entry()?;
    if validation.is_some() && !layer_present(&entry, VALIDATION_LAYER)? {
        return Err(Error::NoValidationLayer);
    }
    let has_debug_utils = extension_present(&entry, None, ash::ext::debug_utils::NAME)?
        || (validation.is_some()
            && extension_present(&entry, Some(VALIDATION_LAYER), ash::ext::debug_utils::NAME)?);
    if validation.is_some() && !has_debug_utils {
        return Err(Error::Unsupported {
            device: "instance".into(),
            what: "VK_EXT_debug_utils, needed to collect validation messages".into(),
        });
    }
    let has_validation_features = match validation {
        Some(_) => extension_present(
            &entry,
            Some(VALIDATION_LAYER),
            ash::ext::validation_features::NAME,
        )?,
        None => false,
    };
    let sink = MessageSink::teed(
        validation
            .map(|v| v.ignored_ids.clone())
            .unwrap_or_default(),
        validation.and_then(|v| v.tee.clone()),
    );
    let user_data = Arc::as_ptr(&sink) as *mut std::ffi::c_void;
    let mut layers: Vec<*const c_char> = Vec::new();
    let mut extensions: Vec<*const c_char> = Vec::new();
    if validation.is_some() {
        layers.push(VALIDATION_LAYER.as_ptr());
    }
    if has_debug_utils {
        extensions.push(ash::ext::debug_utils::NAME.as_ptr());
    }
    if has_validation_features {
        extensions.push(ash::ext::validation_features::NAME.as_ptr());
    }
    let enables = validation_enables(validation, has_validation_features)?;
    let mut messenger_info = messenger_info(user_data);
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let app = vk::ApplicationInfo::default()
        .application_name(c"vkshade")
        .engine_name(c"vkshade")
        .api_version(REQUIRED_API);
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions);
    if has_debug_utils {
        info = info.push_next(&mut messenger_info);
    }
    if has_validation_features && !enables.is_empty() {
        info = info.push_next(&mut features);
    }
    // SAFETY: all pointers in `info` outlive the call.
    let instance = match unsafe { entry.create_instance(&info, None) } {
        Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
            return Err(Error::NoDevice {
                reason: "the Vulkan loader found no driver (VK_ERROR_INCOMPATIBLE_DRIVER)".into(),
            });
        }
        other => other.vk("vkCreateInstance")?,
    };
    let (partial, debug_instance, messenger) =
        attach_messenger(&entry, &instance, has_debug_utils, &messenger_info)?;
    Ok(InstanceParts {
        entry,
        instance,
        debug_instance,
        messenger,
        sink,
        partial,
    })
}

/// The validation features `validation` turns on; an error if some are wanted but the
/// layer lacks VK_EXT_validation_features.
fn validation_enables(
    validation: Option<&ValidationConfig>,
    has_validation_features: bool,
) -> Result<Vec<vk::ValidationFeatureEnableEXT>> {
    let mut enables = Vec::new();
    if let Some(v) = validation {
        if v.synchronization {
            enables.push(vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION);
        }
        if v.best_practices {
            enables.push(vk::ValidationFeatureEnableEXT::BEST_PRACTICES);
        }
        if v.gpu_assisted {
            enables.push(vk::ValidationFeatureEnableEXT::GPU_ASSISTED);
        }
        if !enables.is_empty() && !has_validation_features {
            return Err(Error::Unsupported {
                device: "validation layer".into(),
                what: "VK_EXT_validation_features (synchronization validation)".into(),
            });
        }
    }
    Ok(enables)
}

/// The messenger vkshade installs: warnings and errors of every type, delivered to
/// `debug_callback` with the message sink at `user_data`.
fn messenger_info(
    user_data: *mut std::ffi::c_void,
) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(user_data)
}

/// Creates the messenger on a fresh `instance` (with debug-utils), and the guard that
/// destroys both if a later step fails (or at once, should this one fail).
fn attach_messenger(
    entry: &ash::Entry,
    instance: &ash::Instance,
    has_debug_utils: bool,
    messenger_info: &vk::DebugUtilsMessengerCreateInfoEXT<'_>,
) -> Result<(
    Partial,
    Option<ash::ext::debug_utils::Instance>,
    vk::DebugUtilsMessengerEXT,
)> {
    // From here on, failures must destroy what was created: `Partial` does that.
    let mut partial = Partial {
        instance: Some(instance.clone()),
        debug: None,
        messenger: vk::DebugUtilsMessengerEXT::null(),
    };
    let debug_instance =
        has_debug_utils.then(|| ash::ext::debug_utils::Instance::new(entry, instance));
    let messenger = match &debug_instance {
        Some(di) => {
            // SAFETY: valid create info; destroyed in Shared::drop or Partial::drop.
            unsafe { di.create_debug_utils_messenger(messenger_info, None) }
                .vk("vkCreateDebugUtilsMessengerEXT")?
        }
        None => vk::DebugUtilsMessengerEXT::null(),
    };
    partial.debug = debug_instance.clone();
    partial.messenger = messenger;
    Ok((partial, debug_instance, messenger))
}

/// Destroys a half-built instance when `Context::new` fails part-way.
pub(super) struct Partial {
    pub(super) instance: Option<ash::Instance>,
    pub(super) debug: Option<ash::ext::debug_utils::Instance>,
    pub(super) messenger: vk::DebugUtilsMessengerEXT,
}

impl Drop for Partial {
    fn drop(&mut self) {
        if let Some(instance) = self.instance.take() {
            // SAFETY: only the messenger may have been created on this instance.
            unsafe {
                if let Some(d) = &self.debug
                    && self.messenger != vk::DebugUtilsMessengerEXT::null()
                {
                    d.destroy_debug_utils_messenger(self.messenger, None);
                }
                instance.destroy_instance(None);
            }
        }
    }
}
