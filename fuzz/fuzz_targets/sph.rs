//! Fuzz target `sph`: see `vkshade_fuzz::sph`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::sph(data);
});
