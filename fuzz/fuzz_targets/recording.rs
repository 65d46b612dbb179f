//! The recording reader (docs/data-format.md) on arbitrary text; what it accepts, the writer
//! writes back to text the reader accepts again, with the same shape.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use slipguard_data::recording::{parse_recording, to_string};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.csv");
    let Ok(t) = parse_recording(text, path) else {
        return;
    };
    let again = parse_recording(&to_string(&t), path)
        .unwrap_or_else(|e| panic!("the writer's text does not read back: {e}"));
    assert_eq!(again.n_channels(), t.n_channels());
    assert_eq!(again.n_steps(), t.n_steps());
});
