//! Runs examples/byo_device.rs: vkshade's AO kernel on a device, queue, allocator and
//! command buffers the caller created and submits itself, two frames in flight, under
//! validation (synchronization and best practices), checked against the CPU twin.

#[path = "../examples/byo_device.rs"]
#[allow(dead_code)] // the example's `main` is not called here
mod byo_device;

#[test]
fn bring_your_own_device_runs_ao_frames_in_flight() {
    let summary = byo_device::run().unwrap_or_else(|e| panic!("{e}"));
    byo_device::print(&summary);
    assert!(summary.frames.len() >= 6, "{} frames", summary.frames.len());
    assert!(
        summary.max_in_flight >= 2,
        "at most {} frame(s) in flight",
        summary.max_in_flight
    );
    // The bound of tests/ao.rs (see MAX_ABS_BOUND in the example for why).
    assert!(
        summary.max_abs_error < byo_device::MAX_ABS_BOUND,
        "max |GPU - CPU| = {}",
        summary.max_abs_error
    );
    assert!(
        summary.within_bound,
        "a frame is outside the GPU-vs-CPU bounds"
    );
    assert!(
        summary.frames.iter().all(|f| f.gpu_ms > 0.0),
        "every frame has GPU timings"
    );
    // No assertion on `summary.validation_messages`: `run()` returns an error on any
    // message, so the list is empty by construction whenever this line is reached (the
    // unwrap above is the check).
}
