#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| kin_fuzz::measurement_csv(data));
