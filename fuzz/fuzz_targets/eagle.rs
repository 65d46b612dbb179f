//! The eagle-shoal `tactile.csv` reader on arbitrary text.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use slipguard_data::eagle::parse_tactile_csv;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data)
        && let Ok((names, samples)) = parse_tactile_csv(text, Path::new("tactile.csv"))
    {
        assert_eq!(names.len(), samples.len());
        let n = samples[0].len();
        assert!(samples.iter().all(|c| c.len() == n));
    }
});
