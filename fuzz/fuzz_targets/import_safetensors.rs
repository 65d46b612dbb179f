//! The safetensors importer (our checkpoints, PyTorch state dicts) on arbitrary bytes.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use slipguard_export::import::torch;

fuzz_target!(|data: &[u8]| {
    let _ = torch::import(Path::new("fuzz.safetensors"), data);
});
