//! Fuzz target `btf_dir`: see `vkshade_fuzz::btf_dir`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::btf_dir(data);
});
