//! Fuzz target `envmap`: see `vkshade_fuzz::envmap`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::envmap(data);
});
