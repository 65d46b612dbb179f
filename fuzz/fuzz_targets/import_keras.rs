//! The Keras importers on arbitrary bytes: a `.keras` archive (first byte even) or a bare
//! `.weights.h5` (first byte odd).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use slipguard_export::import::keras;

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if mode & 1 == 0 {
        let _ = keras::import_keras(Path::new("fuzz.keras"), rest);
    } else {
        let _ = keras::import_h5(Path::new("fuzz.weights.h5"), rest.to_vec(), None);
    }
});
