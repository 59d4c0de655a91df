//! Shared harness for GPU tests: every test runs on a validated context (synchronization
//! validation on), and any validation message, leaked resource or undestroyed object fails it.
//! A missing Vulkan device fails too, with the message saying what to install.
#![allow(dead_code)]

use vkshade::gpu::{Context, ContextDesc, ValidationMessage};

/// A validated context, or a panic explaining how to get one.
pub fn context() -> Context {
    match Context::new(&ContextDesc::validated()) {
        Ok(ctx) => ctx,
        Err(e) => panic!(
            "cannot create a validated Vulkan context: {e}\n\
             These tests need a Vulkan device and the Khronos validation layer: on Debian 12 run \
             `sudo tools/setup.sh`, or `apt-get install mesa-vulkan-drivers vulkan-validationlayers`."
        ),
    }
}

/// Shuts `ctx` down and returns every message collected, including those raised while
/// destroying the device. Panics if resources are still alive.
pub fn shutdown(ctx: Context) -> Vec<ValidationMessage> {
    match ctx.shutdown() {
        Ok(messages) => messages,
        Err(e) => panic!("unclean shutdown: {e}"),
    }
}

/// Runs `f` on a validated context; fails on any error, validation message or leak.
pub fn with_gpu<T>(f: impl FnOnce(&Context) -> vkshade::Result<T>) -> T {
    let ctx = context();
    let result = f(&ctx);
    let messages = shutdown(ctx);
    let value = match result {
        Ok(v) => v,
        Err(e) => panic!("GPU test failed: {e}"),
    };
    assert_clean(&messages);
    value
}

/// Fails with every message listed, if there are any.
pub fn assert_clean(messages: &[ValidationMessage]) {
    if !messages.is_empty() {
        let list: Vec<String> = messages.iter().map(|m| format!("  {m}")).collect();
        panic!(
            "{} validation message(s):\n{}",
            messages.len(),
            list.join("\n")
        );
    }
}
