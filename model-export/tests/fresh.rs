//! `slipguard-export inspect … | head` and `slipguard-export run … | true`: the reader closes the
//! pipe; the exporter ends quietly with exit 0 (it used to panic, exit 101). And the help of
//! every numeric model option names its unit; negative numbers reach the range checks.
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn exporter() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard-export"))
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Runs with stdout closed before the child writes; returns (exit code, stderr).
fn with_closed_stdout(args: &[&str]) -> (Option<i32>, String) {
    let mut child = exporter()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (child.wait().unwrap().code(), err)
}

#[test]
fn a_closed_stdout_ends_quietly() {
    let blob = repo().join("models/hand-force/hand-force.bin");
    let blob = blob.to_str().unwrap();
    let dir = std::env::temp_dir().join(format!("slipguard-export-pipe-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A raw trace long enough that `run` prints many lines.
    let trace = dir.join("trace.csv");
    let rows: String = (0..2000)
        .map(|i| format!("{}\n", 1000 + (i % 97) * 10))
        .collect();
    std::fs::write(&trace, format!("force_mN\n{rows}")).unwrap();
    for args in [
        vec!["inspect", blob],
        vec!["inspect", blob, "--json"],
        vec!["run", blob, trace.to_str().unwrap()],
    ] {
        let (code, err) = with_closed_stdout(&args);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert_eq!(code, Some(0), "{args:?}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn numeric_options_name_their_unit_and_take_negative_numbers_to_the_check() {
    let help = exporter().args(["export", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout).replace('\n', " ");
    for (option, unit) in [
        ("--sample-rate", "Hz"),
        ("--input-offset", "input unit"),
        ("--input-full-scale", "input unit"),
        ("--stft-window", "samples"),
        ("--raise-after", "steps"),
        ("--clear-after", "steps"),
        ("--threshold", "probability"),
        ("--cell-bits", "bits"),
        ("--max-trials", "count"),
    ] {
        let at = help
            .find(option)
            .unwrap_or_else(|| panic!("{option} not in the help"));
        let text: String = help[at..].chars().take(260).collect();
        assert!(text.contains(unit), "{option}: no `{unit}` in `{text}`");
    }
    let out = exporter()
        .args(["verify", "m.bin", "--float", "m.safetensors", "--data", "d"])
        .args(["--max-dp", "-0.1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("allowed range"), "{err}");
}

/// The field guide names the report the exporter writes (`-o mine.bin` → `mine.bin.report.md`).
#[test]
fn the_guide_names_the_report_file_the_exporter_writes() {
    let guide = std::fs::read_to_string(repo().join("docs/field-guide.md")).unwrap();
    assert!(
        guide.contains("`mine.bin.report.md`"),
        "the guide names another report file"
    );
    assert!(!guide.contains("`mine.report.md`"));
    let dir = std::env::temp_dir().join(format!("slipguard-export-report-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fixture = repo().join("model-export/tests/fixtures/torch_c.safetensors");
    let out = exporter()
        .arg("export")
        .arg(&fixture)
        .args(["--cell-bits", "10", "-q", "-o"])
        .arg(dir.join("mine.bin"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.join("mine.bin.report.md").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
