#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| h4_fuzz::targets::experiment_config(data));
