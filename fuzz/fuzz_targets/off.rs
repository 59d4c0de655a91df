//! Fuzz target `off`: see `vkshade_fuzz::off`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::off(data);
});
