//! The ONNX importer on arbitrary bytes (external data is looked up beside a path that does
//! not exist, so only embedded tensors are read).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use slipguard_export::import::onnx;

fuzz_target!(|data: &[u8]| {
    let _ = onnx::import(Path::new("/nonexistent/fuzz.onnx"), data);
});
