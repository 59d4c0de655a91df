//! Fuzz target `obj`: see `vkshade_fuzz::obj`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = vkshade_fuzz::obj(data);
});
