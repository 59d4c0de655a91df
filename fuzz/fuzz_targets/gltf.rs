//! Fuzz target `gltf`: see `vkshade_fuzz::gltf`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::gltf(data);
});
