//! Runs examples/character_frame.rs: a renderer's loop driving the character frame with two
//! frames in flight under validation, every frame checked against the compose pass's CPU twin.
#![cfg(feature = "gltf")]

#[path = "../examples/character_frame.rs"]
#[allow(dead_code)] // the example's `main` is not called here
mod character_frame;

#[test]
fn a_renderers_loop_runs_the_character_frame_two_in_flight() {
    let s = character_frame::run().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        s.validation_messages, 0,
        "validation messages (listed above)"
    );
    assert_eq!(s.frames, character_frame::FRAMES);
    assert!(
        s.max_in_flight >= 2,
        "at most {} in flight",
        s.max_in_flight
    );
    assert!(
        s.worst_rel <= character_frame::MAX_REL,
        "worst relative difference {:e}",
        s.worst_rel
    );
    assert!(s.gpu_ms.iter().all(|&ms| ms > 0.0));
}
