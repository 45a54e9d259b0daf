//! The Event Stream reader on arbitrary bytes: errors are fine, panics and unbounded memory are not.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    evpose_fuzz::read_all(data, Some(evpose_host::io::Format::Es));
});
