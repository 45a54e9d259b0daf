//! The rasterizer with an arbitrary configuration and arbitrary events.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    evpose_fuzz::raster(data);
});
