//! Fuzz target `ply`: see `vkshade_fuzz::ply`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::ply(data);
});
