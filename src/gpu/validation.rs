//! Collection of validation-layer messages through VK_EXT_debug_utils.
//!
//! Every WARNING or ERROR message is stored in a [`MessageSink`]; nothing is printed and
//! nothing is lost, so tests can assert that a run was clean. Known false positives are
//! filtered by `messageIdNumber`, never by text.

use ash::vk;
use std::ffi::{CStr, c_void};
use std::fmt;
use std::sync::{Arc, Mutex};

/// Severity of a collected message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub enum Severity {
    /// A warning, performance and best-practices warnings included.
    Warning,
    /// An error: invalid Vulkan use reported by a layer, or a leak vkshade reports at shutdown.
    Error,
}

/// One message from the validation layers or the loader.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ValidationMessage {
    /// Warning or error.
    pub severity: Severity,
    /// GENERAL / VALIDATION / PERFORMANCE, as reported by the layer.
    pub kind: String,
    /// `messageIdNumber`: stable across runs; the key for filtering.
    pub id_number: i32,
    /// `pMessageIdName`, e.g. `SYNC-HAZARD-READ-AFTER-WRITE`.
    pub id_name: String,
    /// The message text as the layer wrote it.
    pub text: String,
    /// Debug-utils names of the objects involved, where they were named.
    pub objects: Vec<String>,
    /// Debug labels open on the command buffer / queue when the message was raised.
    pub labels: Vec<String>,
}

impl fmt::Display for ValidationMessage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "[{:?} {} {} (id {:#x})]",
            self.severity, self.kind, self.id_name, self.id_number as u32
        )?;
        if !self.labels.is_empty() {
            write!(f, " in pass {}", self.labels.join(" > "))?;
        }
        if !self.objects.is_empty() {
            write!(f, " objects [{}]", self.objects.join(", "))?;
        }
        write!(f, ": {}", self.text)
    }
}

/// Thread-safe store of validation messages, shared with the debug callback.
#[derive(Debug, Default)]
pub struct MessageSink {
    messages: Mutex<Vec<ValidationMessage>>,
    ignored_ids: Vec<i32>,
    ignored_count: Mutex<u64>,
    /// A second sink every kept message is copied to (see [`ValidationConfig::tee`](crate::gpu::ValidationConfig::tee)).
    tee: Option<Arc<MessageSink>>,
}

impl MessageSink {
    /// A sink that drops messages whose `messageIdNumber` is in `ignored_ids`.
    pub fn new(ignored_ids: Vec<i32>) -> Arc<Self> {
        MessageSink::teed(ignored_ids, None)
    }

    /// As [`MessageSink::new`], copying every message to `tee` as well, ignored ones included
    /// (the tee applies its own ignore list; a caller
    /// collecting the messages of contexts it does not hold, e.g. `vkshade validate`).
    pub fn teed(ignored_ids: Vec<i32>, tee: Option<Arc<MessageSink>>) -> Arc<Self> {
        Arc::new(MessageSink {
            messages: Mutex::new(Vec::new()),
            ignored_ids,
            ignored_count: Mutex::new(0),
            tee,
        })
    }

    /// Copies a message to the tee (if any), then stores it unless its id is ignored.
    pub fn push(&self, message: ValidationMessage) {
        if let Some(tee) = &self.tee {
            tee.push(message.clone());
        }
        if self.ignored_ids.contains(&message.id_number) {
            *lock(&self.ignored_count) += 1;
            return;
        }
        lock(&self.messages).push(message);
    }

    /// Removes and returns every message collected so far.
    pub fn take(&self) -> Vec<ValidationMessage> {
        std::mem::take(&mut *lock(&self.messages))
    }

    /// Number of messages currently stored.
    pub fn len(&self) -> usize {
        lock(&self.messages).len()
    }

    /// Whether no message is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// How many messages were dropped because their id is on the ignore list.
    pub fn ignored(&self) -> u64 {
        *lock(&self.ignored_count)
    }
}

/// Locks a mutex, recovering the data if another thread panicked while holding it.
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn cstr_lossy(p: *const std::ffi::c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: the layer passes NUL-terminated strings valid for the callback's duration.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}

fn labels_of(p: *const vk::DebugUtilsLabelEXT<'_>, n: u32) -> Vec<String> {
    if p.is_null() {
        return Vec::new();
    }
    // SAFETY: the layer passes `n` valid labels.
    let labels = unsafe { std::slice::from_raw_parts(p, n as usize) };
    labels.iter().map(|l| cstr_lossy(l.p_label_name)).collect()
}

/// The debug-utils callback. `user_data` is `Arc::as_ptr` of the context's sink, which
/// outlives the messenger and the instance. It never panics across the FFI boundary.
pub(crate) unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    let _ = std::panic::catch_unwind(|| {
        if data.is_null() || user_data.is_null() {
            return;
        }
        let severity = if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
            Severity::Error
        } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
            Severity::Warning
        } else {
            return;
        };
        // SAFETY: non-null, provided by the layer for the duration of the call.
        let data = unsafe { &*data };
        // SAFETY: `user_data` is the pointer registered at messenger creation (see context/instance.rs).
        let sink = unsafe { &*(user_data as *const MessageSink) };
        let objects = if data.p_objects.is_null() {
            Vec::new()
        } else {
            // SAFETY: the layer passes `object_count` valid entries.
            unsafe { std::slice::from_raw_parts(data.p_objects, data.object_count as usize) }
                .iter()
                .map(|o| {
                    let name = cstr_lossy(o.p_object_name);
                    if name.is_empty() {
                        format!("{:?} {:#x}", o.object_type, o.object_handle)
                    } else {
                        format!("{:?} '{name}'", o.object_type)
                    }
                })
                .collect()
        };
        let mut labels = labels_of(data.p_queue_labels, data.queue_label_count);
        labels.extend(labels_of(data.p_cmd_buf_labels, data.cmd_buf_label_count));
        sink.push(ValidationMessage {
            severity,
            kind: format!("{types:?}"),
            id_number: data.message_id_number,
            id_name: cstr_lossy(data.p_message_id_name),
            text: cstr_lossy(data.p_message),
            objects,
            labels,
        });
    });
    vk::FALSE
}
