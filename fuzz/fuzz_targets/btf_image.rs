//! Fuzz target `btf_image`: see `vkshade_fuzz::btf_image`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::btf_image(data);
});
