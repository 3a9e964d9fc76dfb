#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| kin_fuzz::lsp(data));
