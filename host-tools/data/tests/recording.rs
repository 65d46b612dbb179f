//! The recording format: round trip and malformed files.
use std::path::Path;

use slipguard_data::error::DataError;
use slipguard_data::labels::LabelConfig;
use slipguard_data::recording::{parse_recording, read_recording, to_string, write_recording};
use slipguard_data::{Outcome, PhaseMarks, Stability, Trial, Unit};

fn sample_trial() -> Trial {
    let mut t = Trial::new(
        "demo",
        Unit::MilliNewton,
        16.7,
        vec![vec![0.0, 12.0, 1500.0, 1510.5, 0.0], vec![0.0; 5]],
    );
    t.marks = PhaseMarks {
        grasp_start: Some(1),
        lift_start: Some(2),
        open_start: Some(4),
        release: None,
    };
    t.outcome = Outcome::Failure;
    t.drop_step = Some(4);
    t.source = "hand-made".into();
    t.step_labels = Some(vec![
        None,
        Some(Stability::Stable),
        Some(Stability::Unstable),
        Some(Stability::Unstable),
        Some(Stability::Unstable),
    ]);
    t.extra.insert("operator".into(), "test".into());
    t
}

/// The exact bytes of the example in docs/data-format.md.
const EXPECTED: &str = "# slipguard-recording v1
# id: demo
# sensor: force
# unit: mN
# rate_hz: 16.7
# outcome: failure
# grasp_start: 1
# lift_start: 2
# open_start: 4
# drop_step: 4
# source: hand-made
# operator: test
time_s,c0,c1,phase,label
0.000000,0,0,pre,
0.059880,12,0,grasp,0
0.119760,1500,0,lift,1
0.179641,1510.5,0,lift,1
0.239521,0,0,open,1
";

#[test]
fn writes_the_documented_bytes_and_reads_them_back() {
    let t = sample_trial();
    assert_eq!(to_string(&t), EXPECTED);
    let doc = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/data-format.md"),
    )
    .unwrap();
    assert!(
        doc.contains(EXPECTED),
        "docs/data-format.md example differs from the writer"
    );
    let back = parse_recording(EXPECTED, Path::new("x.csv")).unwrap();
    assert_eq!(back.samples, t.samples);
    assert_eq!(back.marks, t.marks);
    assert_eq!(back.outcome, Outcome::Failure);
    assert_eq!(back.drop_step, Some(4));
    assert_eq!(back.step_labels, t.step_labels);
    assert_eq!(back.extra.get("operator").map(String::as_str), Some("test"));
    assert_eq!(back.rate_hz, 16.7);
    // And through a file, with annotation.
    let dir = std::env::temp_dir().join(format!("slipguard-rec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("demo.csv");
    write_recording(&t, &p).unwrap();
    // c0 is >= 500 mN on steps 2 and 3 (before the drop at 4): contact with a 2-step run,
    // not with the default 3-step run.
    let r = read_recording(&p, &LabelConfig::default()).unwrap();
    assert_eq!(r.samples, t.samples);
    assert_eq!(r.contact, vec![false, false]);
    let cfg = LabelConfig {
        contact_min_run: 2,
        ..LabelConfig::default()
    };
    assert_eq!(read_recording(&p, &cfg).unwrap().contact, vec![true, false]);
    std::fs::remove_dir_all(&dir).unwrap();
}

fn err(text: &str) -> DataError {
    parse_recording(text, Path::new("bad.csv")).expect_err("must fail")
}

fn loc(e: &DataError) -> (usize, Option<usize>) {
    let l = e.location().unwrap_or_else(|| panic!("no location in {e}"));
    assert_eq!(l.path, Path::new("bad.csv"));
    (l.line, l.column)
}

#[test]
fn malformed_files_name_line_and_column() {
    // A bad number on line 4, column 3 (`c1`).
    let e = err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0,c1\n0,1,x\n");
    assert_eq!(loc(&e), (5, Some(3)));
    assert!(
        e.to_string().starts_with("bad.csv:5:3 (column `c1`)"),
        "{e}"
    );
    // Too few fields: the first missing one is column 3.
    let e =
        err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0,c1\n0,1,2\n0.1,1\n");
    assert_eq!(loc(&e), (6, Some(3)));
    // Empty value.
    let e = err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,\n");
    assert_eq!(loc(&e), (5, Some(2)));
    // Bad label and phase values.
    let e = err(
        "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0,phase,label\n0,1,pre,2\n",
    );
    assert_eq!(loc(&e), (5, Some(4)));
    let e = err(
        "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0,phase\n0,1,lift\n0.1,1,grasp\n",
    );
    assert_eq!(loc(&e), (6, Some(3)));
    // Time not increasing.
    let e = err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,1\n0,1\n");
    assert_eq!(loc(&e), (6, Some(1)));
    // Stated rate does not match the time column (reported on the rate line).
    let e = err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,1\n1,1\n");
    assert_eq!(loc(&e), (2, None));
    // Wrong magic line.
    let e = err("time_s,c0\n0,1\n");
    assert_eq!(loc(&e), (1, None));
    // Metadata disagreeing with the phase column.
    let e = err(
        "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\n# lift_start: 0\ntime_s,c0,phase\n0,1,pre\n0.1,1,lift\n",
    );
    assert_eq!(loc(&e), (4, None));
}

#[test]
fn missing_columns_and_metadata() {
    match err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\nc0,c1\n0,1\n") {
        DataError::MissingColumn { line, column, .. } => {
            assert_eq!(line, 4);
            assert!(column.contains("time_s"));
        }
        e => panic!("{e}"),
    }
    match err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,phase\n0,pre\n") {
        DataError::MissingColumn { .. } => {}
        e => panic!("{e}"),
    }
    match err("# slipguard-recording v1\n# unit: mN\ntime_s,c0\n0,1\n") {
        DataError::MissingMetadata { key, .. } => assert_eq!(key, "rate_hz"),
        e => panic!("{e}"),
    }
}

#[test]
fn eagle_csv_errors_name_the_file() {
    let dir = std::env::temp_dir().join(format!("slipguard-eagle-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("tactile.csv"), "c0,c1\n1,2\n3,oops\n").unwrap();
    std::fs::write(dir.join("meta.json"), r#"{"label":[0,1,1,0]}"#).unwrap();
    let e = slipguard_data::eagle::load_eagle_trial(&dir, &LabelConfig::default()).unwrap_err();
    let l = e.location().unwrap();
    assert!(l.path.ends_with("tactile.csv"));
    assert_eq!((l.line, l.column), (3, Some(2)));
    std::fs::write(dir.join("tactile.csv"), "c0,c1\n1,2\n3,4\n").unwrap();
    std::fs::write(dir.join("meta.json"), r#"{"label":[0,1,7,0]}"#).unwrap();
    let e = slipguard_data::eagle::load_eagle_trial(&dir, &LabelConfig::default()).unwrap_err();
    assert!(e.to_string().contains("l2 = 7"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_byte_order_mark_is_accepted_by_both_readers() {
    // Recordings: a BOM before the magic line, CRLF line ends; the same trial as without.
    let plain = parse_recording(EXPECTED, Path::new("plain.csv")).unwrap();
    let bom = format!("\u{feff}{}", EXPECTED.replace('\n', "\r\n"));
    let with_bom = parse_recording(&bom, Path::new("bom.csv")).unwrap();
    assert_eq!(to_string(&with_bom), to_string(&plain));
    // The same through a file, and a `tactile.csv` with a BOM before its header.
    let dir = std::env::temp_dir().join(format!("slipguard-bom-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("r.csv"), &bom).unwrap();
    let read = read_recording(&dir.join("r.csv"), &LabelConfig::default()).unwrap();
    assert_eq!(read.samples, plain.samples);
    std::fs::write(dir.join("tactile.csv"), "\u{feff}c0,c1\r\n1,2\r\n3,4\r\n").unwrap();
    let (names, samples) =
        slipguard_data::eagle::read_tactile_csv(&dir.join("tactile.csv")).unwrap();
    assert_eq!(names, ["c0", "c1"]);
    assert_eq!(samples, [vec![1.0, 3.0], vec![2.0, 4.0]]);
    // A BOM anywhere else is data, and refused with its place.
    std::fs::write(dir.join("tactile.csv"), "c0,c1\n1,\u{feff}2\n").unwrap();
    let e = slipguard_data::eagle::read_tactile_csv(&dir.join("tactile.csv")).unwrap_err();
    assert_eq!(e.location().map(|l| (l.line, l.column)), Some((2, Some(2))));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn body_lines_are_file_lines_after_blank_lines() {
    // Blank lines in the body are skipped; errors still name the line of the file.
    let e = err("# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,1\n\n\n0.1,x\n");
    assert_eq!(loc(&e), (8, Some(2)));
}

#[test]
fn a_very_high_rate_recording_reads_back() {
    // Six decimals would write 0.000000 twice at 10 MHz… the writer widens the time column.
    for rate in [
        16.7f32,
        1000.0,
        71_000.0,
        slipguard_data::recording::MAX_RATE_HZ,
    ] {
        let t = Trial::new(
            "fast",
            Unit::MilliNewton,
            rate,
            vec![vec![1.0, 2.0, 3.0, 4.0]],
        );
        let back = parse_recording(&to_string(&t), Path::new("fast.csv"))
            .unwrap_or_else(|e| panic!("{rate} Hz: {e}"));
        assert_eq!(back.samples, t.samples, "{rate} Hz");
        assert_eq!(back.rate_hz, rate);
    }
    // Rates the reader refuses, the writer refuses too.
    let dir = std::env::temp_dir().join(format!("sg-rate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for rate in [1e6f32, 1e-4] {
        let t = Trial::new("x", Unit::MilliNewton, rate, vec![vec![1.0, 2.0]]);
        let e = write_recording(&t, &dir.join("x.csv")).unwrap_err();
        assert!(e.to_string().contains("outside"), "{e}");
        let text = to_string(&t);
        assert!(parse_recording(&text, Path::new("x.csv")).is_err());
    }
    let mut t = Trial::new("x", Unit::MilliNewton, 16.7, vec![vec![f32::NAN, 2.0]]);
    assert!(write_recording(&t, &dir.join("x.csv")).is_err());
    t.samples[0][0] = 1.0;
    t.extra.insert("id".into(), "twice".into());
    assert!(write_recording(&t, &dir.join("x.csv")).is_err());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_release_mark_round_trips_through_metadata_and_the_phase_column() {
    let mut t = Trial::new("rel", Unit::MilliNewton, 40.0, vec![vec![0.0; 8]]);
    t.marks = PhaseMarks {
        grasp_start: Some(1),
        lift_start: Some(3),
        open_start: None,
        release: Some(6),
    };
    let text = to_string(&t);
    assert!(text.contains("# release: 6\n"), "{text}");
    assert!(text.contains(",release\n"), "{text}");
    let back = parse_recording(&text, Path::new("rel.csv")).unwrap();
    assert_eq!(back.marks, t.marks);
    // From the phase column alone (the monitor's file before its summary): no open mark.
    let no_meta: String = text
        .lines()
        .filter(|l| {
            !l.starts_with("# release") && !l.starts_with("# grasp") && !l.starts_with("# lift")
        })
        .map(|l| format!("{l}\n"))
        .collect();
    let back = parse_recording(&no_meta, Path::new("rel.csv")).unwrap();
    assert_eq!(back.marks, t.marks);
    // Release before lift is refused with the marks named.
    t.marks.release = Some(2);
    assert!(t.validate().unwrap_err().contains("out of order"));
    assert!(parse_recording(&to_string(&t), Path::new("rel.csv")).is_err());
}

#[test]
fn a_gap_in_the_time_column_is_refused_with_its_line() {
    // 40 steps at 10 Hz, step 3 lost: the mean step is within 5 % but one step is 2 periods.
    let mut text = "# slipguard-recording v1\n# unit: mN\n# rate_hz: 10\ntime_s,c0\n".to_string();
    for i in (0..41).filter(|&i| i != 3) {
        text.push_str(&format!("{},1\n", i as f64 / 10.0));
    }
    let e = err(&text);
    assert_eq!(loc(&e), (8, Some(1)), "{e}");
    assert!(e.to_string().contains("rows are missing"), "{e}");
}

#[test]
fn the_appender_writes_what_the_reader_reads() {
    use slipguard_data::Phase;
    use slipguard_data::recording::Appender;
    let dir = std::env::temp_dir().join(format!("sg-append-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("a.csv");
    let meta = Trial::new("a", Unit::MilliNewton, 16.7, vec![vec![], vec![]]);
    let mut w = Appender::create(&p, &meta).unwrap();
    let phases = [
        Phase::Pre,
        Phase::Grasp,
        Phase::Grasp,
        Phase::Lift,
        Phase::Release,
    ];
    for (i, ph) in phases.iter().enumerate() {
        w.push(&[i as f32, 0.5], *ph).unwrap();
    }
    assert!(w.push(&[1.0], Phase::Release).is_err(), "channel count");
    assert!(w.push(&[1.0, 1.0], Phase::Lift).is_err(), "phase back");
    w.flush().unwrap();
    let t = parse_recording(&std::fs::read_to_string(&p).unwrap(), &p).unwrap();
    assert_eq!(t.samples, vec![vec![0.0, 1.0, 2.0, 3.0, 4.0], vec![0.5; 5]]);
    assert_eq!(
        t.marks,
        PhaseMarks {
            grasp_start: Some(1),
            lift_start: Some(3),
            open_start: None,
            release: Some(4)
        }
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_file_over_the_size_limit_is_refused_before_reading() {
    let dir = std::env::temp_dir().join(format!("sg-big-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("big.csv");
    let f = std::fs::File::create(&p).unwrap();
    // A sparse file: no disk space, but its length is over the limit.
    f.set_len(slipguard_data::recording::MAX_BYTES + 1).unwrap();
    let e = read_recording(&p, &LabelConfig::default()).unwrap_err();
    assert!(e.to_string().contains("at most"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
