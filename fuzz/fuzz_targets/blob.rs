//! The `.evq` model blob parser on arbitrary bytes, and one inference on what it accepts.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    evpose_fuzz::blob(data);
});
