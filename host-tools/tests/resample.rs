//! `slipguard resample`: recordings at a new rate, checked against analytically sampled sines
//! and the real trial's own marks in seconds; bad input refused in one line.
use std::path::{Path, PathBuf};
use std::process::Command;

use slipguard_data::labels::LabelConfig;
use slipguard_data::{Outcome, Trial, Unit, eagle, recording};

fn slipguard() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard"))
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("slipguard-resample-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn resample(input: &Path, rate: &str, out: &Path) -> std::process::Output {
    slipguard()
        .arg("resample")
        .arg(input)
        .args(["--rate-hz", rate, "--out"])
        .arg(out)
        .output()
        .unwrap()
}

fn sine(rate: f64, n: usize, f: f64) -> Vec<f32> {
    (0..n)
        .map(|k| {
            (3000.0 + 2000.0 * (2.0 * std::f64::consts::PI * f * k as f64 / rate).sin()) as f32
        })
        .collect()
}

#[test]
fn a_recorded_sine_comes_back_as_the_sine_sampled_at_40_hz() {
    let dir = temp("sine");
    let rec = dir.join("in");
    std::fs::create_dir_all(&rec).unwrap();
    // 2 Hz and 4 Hz at 16.7 Hz: well inside the source's 8.35 Hz Nyquist.
    let mut t = Trial::new(
        "sine",
        Unit::MilliNewton,
        16.7,
        vec![sine(16.7, 300, 2.0), sine(16.7, 300, 4.0)],
    );
    t.outcome = Outcome::Success;
    t.marks.grasp_start = Some(20);
    t.marks.lift_start = Some(100);
    recording::write_recording(&t, &rec.join("sine.csv")).unwrap();
    let out = dir.join("out");
    let o = resample(&rec, "40", &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = recording::read_recording(&out.join("sine.csv"), &LabelConfig::default()).unwrap();
    assert_eq!(r.rate_hz, 40.0);
    // 299 steps of 1/16.7 s = 17.90 s: steps 0..=716 at 40 Hz.
    assert_eq!(r.n_steps(), 717);
    // 20 / 16.7 = 1.198 s = 47.9 steps at 40 Hz; 100 / 16.7 = 5.988 s = 239.5 steps: the first
    // 40 Hz steps at or after them.
    assert_eq!(r.marks.grasp_start, Some(48));
    assert_eq!(r.marks.lift_start, Some(240));
    for (c, f) in [(0, 2.0), (1, 4.0)] {
        let want = sine(40.0, r.n_steps(), f);
        // The kernel reaches 16 zero crossings of the 7.5 Hz cut-off (1.07 s) either side.
        let err = r.samples[c][50..r.n_steps() - 50]
            .iter()
            .zip(&want[50..])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // Measured 0.026 mN (2 Hz), 0.073 mN (4 Hz) of 2 000, through the file and back.
        assert!(
            err < 0.15,
            "{f} Hz: {err} mN from the sine sampled at 40 Hz"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_real_trial_keeps_its_marks_drop_and_outcome_in_seconds() {
    let src = eagle::default_data_dir().join("trials/Cheez_100_814_top_3");
    let cfg = LabelConfig::default();
    let t = eagle::load_eagle_trial(&src, &cfg).unwrap();
    let dir = temp("real");
    let o = resample(&src, "40", &dir);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = recording::read_recording(&dir.join("Cheez_100_814_top_3.csv"), &cfg).unwrap();
    assert_eq!(
        (r.rate_hz, r.outcome, r.n_channels()),
        (40.0, Outcome::Failure, 16)
    );
    let s = |step: Option<usize>, rate: f32| step.unwrap() as f32 / rate;
    for (a, b) in [
        (t.marks.grasp_start, r.marks.grasp_start),
        (t.marks.lift_start, r.marks.lift_start),
        (t.marks.open_start, r.marks.open_start),
        (t.drop_step, r.drop_step),
    ] {
        // The first 40 Hz step at or after the same second.
        let late = s(b, 40.0) - s(a, 16.7);
        assert!(
            (-1e-4..1.0 / 40.0).contains(&late),
            "{a:?} at 16.7 Hz, {b:?} at 40 Hz"
        );
    }
    // The drop the labeller finds at 16.7 Hz (step 121, docs/labels.md) is step 290 at 40 Hz.
    assert_eq!((t.drop_step, r.drop_step), (Some(121), Some(290)));
    // Labelled as `label --out` would: unstable from 1.2 s (20 steps) before the drop.
    let labels = r.step_labels.as_ref().expect("labels");
    let first_unstable = labels
        .iter()
        .position(|l| l.is_some_and(|l| l.is_unstable()))
        .unwrap();
    let late = first_unstable as f32 / 40.0 - 101.0 / 16.7;
    assert!((-1e-4..1.0 / 40.0).contains(&late), "{first_unstable}");
    assert_eq!(
        r.extra.get("resampled_from_hz").map(String::as_str),
        Some("16.7")
    );
    // The tools take the folder as 40 Hz data: `label` finds the same drop at 40 Hz.
    let l = slipguard()
        .arg("label")
        .arg(&dir)
        .arg("--stats")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&l.stdout);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    assert!(text.contains("config at 40 Hz: lead 48 steps"), "{text}");
    assert!(text.contains("failures with a drop 1"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_input_is_refused_in_one_line() {
    let src = eagle::default_data_dir().join("trials/Cheez_100_814_top_3");
    let dir = temp("bad");
    let one_line = |o: &std::process::Output, want: &str| {
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(want), "{e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    };
    // A rate below the source's: its band would not fit.
    one_line(
        &resample(&src, "10", &dir.join("a")),
        "below the data's 16.7 Hz",
    );
    assert!(
        !dir.join("a").exists(),
        "nothing written before the refusal"
    );
    // --out is a file.
    let f = dir.join("file");
    std::fs::write(&f, "x").unwrap();
    one_line(&resample(&src, "40", &f), "is a file");
    // A recording of that name exists already.
    let o = resample(&src, "40", &dir.join("b"));
    assert!(o.status.success());
    one_line(
        &resample(&src, "40", &dir.join("b")),
        "Cheez_100_814_top_3.csv exists",
    );
    // Not a rate.
    assert!(!resample(&src, "-40", &dir.join("c")).status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn help_has_an_example_and_describes_every_option() {
    let out = slipguard().args(["resample", "--help"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("Example:\n  slipguard resample "), "{text}");
    let lines: Vec<&str> = text.lines().collect();
    for opt in ["--rate-hz <RATE_HZ>", "--out <OUT>"] {
        // The option's line in the options list, its description on it or on the next line.
        let i = lines
            .iter()
            .position(|l| l.trim_start().starts_with(opt))
            .unwrap_or_else(|| panic!("{opt} not listed: {text}"));
        let described = lines[i].trim_start()[opt.len()..].trim().len() > 10
            || lines.get(i + 1).is_some_and(|n| n.trim().len() > 10);
        assert!(described, "{opt} has no description: {text}");
    }
}
