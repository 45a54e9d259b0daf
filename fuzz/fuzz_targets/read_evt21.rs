//! The Prophesee RAW reader on arbitrary bytes whose header names EVT 2.1 (the seeds' do, in
//! both byte orders; mutated headers reach the byte-order rules and the other encodings):
//! errors are fine, panics and unbounded memory are not.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    evpose_fuzz::read_all(data, Some(evpose_host::io::Format::Raw));
});
