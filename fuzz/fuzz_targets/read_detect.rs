//! Format detection, then whichever reader it picks, on arbitrary bytes.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    evpose_fuzz::read_all(data, None);
});
