//! Fuzz target `transfer`: see `vkshade_fuzz::transfer`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::transfer(data);
});
