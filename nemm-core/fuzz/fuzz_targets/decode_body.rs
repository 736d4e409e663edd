//! Past the CRC: the input is `[kind, max_scaler_params (u16 LE)] ++ body`, wrapped
//! into a header announcing that body and a correct CRC-32, so that the fuzzer explores the
//! postcard body parser, the header/body agreement checks and model validation (a raw blob
//! fuzzer almost never gets past the CRC).
#![no_main]

use libfuzzer_sys::fuzz_target;
use nemm_core_fuzz::{check_blob, wrap_body};

fuzz_target!(|data: &[u8]| {
    if let Some(blob) = wrap_body(data) {
        check_blob(&blob);
    }
});
