//! Fuzz target `btf_json`: see `vkshade_fuzz::btf_json`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::btf_json(data);
});
