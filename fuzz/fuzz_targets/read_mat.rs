//! The DHP19 Vicon ground-truth reader (MATLAB Level 5 MAT-files, zlib-compressed elements
//! included) on arbitrary bytes: errors are fine, panics and unbounded memory are not.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = evpose_host::dhp19::mat::read_variables(data);
    let _ = evpose_host::dhp19::mat::read_xyzpos(data);
});
