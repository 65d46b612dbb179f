//! Values a sensor cannot report (1e30 mN) are refused with the file, line and column, and the
//! writer refuses them too, so every file written reads back.
use std::path::Path;

use slipguard_data::error::DataError;
use slipguard_data::recording::{parse_recording, write_recording};
use slipguard_data::{Trial, Unit};

fn trial(unit: Unit, v: f32) -> Trial {
    Trial::new(
        "range".to_string(),
        unit,
        16.7,
        vec![vec![100.0, v, 120.0], vec![5.0, 6.0, 7.0]],
    )
}

#[test]
fn a_force_of_1e30_mn_is_refused_with_its_line_and_column() {
    let head = "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0,c1\n0,1,2\n";
    assert!(parse_recording(&format!("{head}0.1,900000,2\n"), Path::new("ok.csv")).is_ok());
    let bad = format!("{head}0.1,1e30,2\n");
    match parse_recording(&bad, Path::new("bad.csv")).expect_err("1e30 mN accepted") {
        DataError::Parse { loc, message } => {
            assert_eq!((loc.line, loc.column), (6, Some(2)), "{message}");
            assert!(message.contains("physical range"), "{message}");
        }
        e => panic!("not a parse error: {e}"),
    }
}

#[test]
fn counts_beyond_16_bits_are_refused_and_not_written() {
    let dir = std::env::temp_dir().join(format!("slipguard-range-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let e = write_recording(&trial(Unit::Counts, 70_000.0), &dir.join("c.csv"))
        .expect_err("70 000 counts written");
    assert!(e.to_string().contains("physical range"), "{e}");
    // Other units carry no range: any finite value.
    write_recording(&trial(Unit::Other("V".into()), 1e30), &dir.join("v.csv")).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
