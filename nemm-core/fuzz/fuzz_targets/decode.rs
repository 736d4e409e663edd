//! Raw blobs into the decoder: any byte string must give a typed error or a valid model,
//! never a panic, hang or sanitizer report. A decoded model must validate, re-encode to a
//! blob that decodes to the same model, and run in the estimator with finite output.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nemm_core_fuzz::check_blob;

fuzz_target!(|data: &[u8]| {
    check_blob(data);
});
