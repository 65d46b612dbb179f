//! What a new user meets first (issue 27): the demo draws its plots with no system font, every
//! tool refuses bad paths and ranges before doing the work, a closed pipe ends quietly, and a
//! silent serial port is an error that says what to check.
use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn slipguard() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("slipguard-fresh-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The demo with an empty font configuration (what a fresh machine without fonts has): it
/// prints its tables and writes readable PNGs (the bundled font draws the text).
#[test]
fn demo_draws_its_plots_without_any_system_font() {
    let dir = tmp("demo");
    let conf = dir.join("fonts.conf");
    std::fs::write(
        &conf,
        "<?xml version=\"1.0\"?>\n<fontconfig></fontconfig>\n",
    )
    .unwrap();
    let out = slipguard()
        .args(["demo", "--sim-count", "6", "--plot-count", "1", "--out"])
        .arg(dir.join("plots"))
        .env("FONTCONFIG_FILE", &conf)
        .env("FONTCONFIG_PATH", &dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    for model in ["hand-force", "hand-force-40hz", "suction"] {
        assert!(
            text.contains(&format!("models/{model}/{model}.bin")),
            "{text}"
        );
    }
    assert!(!text.contains(".."), "a path with `..`: {text}");
    let pngs: Vec<PathBuf> = std::fs::read_dir(dir.join("plots"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(pngs.len(), 4, "one plot per data set: {pngs:?}");
    for p in &pngs {
        let name = p.file_name().unwrap().to_string_lossy();
        assert!(!name.contains(',') && !name.contains(' '), "{name}");
        let bytes = std::fs::read(p).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{name}");
        assert!(bytes.len() > 10_000, "{name}: {} bytes", bytes.len());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// An installed binary (`cargo install --path host-tools` copies it elsewhere) run outside the
/// repository, with neither `$SLIPGUARD_DATA` nor `$SLIPGUARD_MODELS` set: the demo finds the real
/// trials and the three shipped models in the copies built into the binary, not in the source
/// tree.
#[test]
fn an_installed_binary_finds_its_models_and_data_outside_the_repository() {
    let dir = tmp("installed");
    let bin = dir.join("bin/slipguard");
    std::fs::create_dir_all(bin.parent().unwrap()).unwrap();
    std::fs::copy(env!("CARGO_BIN_EXE_slipguard"), &bin).unwrap();
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let out = Command::new(&bin)
        .args([
            "demo",
            "--sim-count",
            "6",
            "--plot-count",
            "0",
            "--out",
            "plots",
        ])
        .current_dir(&work)
        .env_remove("SLIPGUARD_DATA")
        .env_remove("SLIPGUARD_MODELS")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .canonicalize()
        .unwrap();
    assert!(
        !text.contains(&*repo.to_string_lossy()),
        "a path into the source tree: {text}"
    );
    for model in ["hand-force", "hand-force-40hz", "suction"] {
        assert!(
            text.contains(&format!("models/{model}/{model}.bin")),
            "{text}"
        );
    }
    assert!(text.contains("eagle-shoal"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--record` into a folder that does not exist is refused before the stream is read (it used
/// to record the whole grasp and lose it at the end).
#[test]
fn monitor_checks_the_record_path_before_reading() {
    let dir = tmp("record");
    let capture = dir.join("empty.bin");
    std::fs::write(&capture, b"").unwrap();
    let out = slipguard()
        .args(["monitor", "--view", "none", "--capture"])
        .arg(&capture)
        .arg("--record")
        .arg(dir.join("missing/x.csv"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("does not exist") && err.contains("mkdir -p"),
        "{err}"
    );
    assert!(!String::from_utf8_lossy(&out.stdout).contains("summary"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `monitor --info` on a port that sends nothing: an error naming what to check, not exit 0
/// with bytes=0.
#[test]
fn monitor_on_a_silent_port_is_an_error() {
    let (_master, slave) = serialport::TTYPort::pair().expect("openpty");
    let name = serialport::SerialPort::name(&slave).expect("slave path");
    let out = slipguard()
        .args(["monitor", "--port", &name, "--info", "--no-keys"])
        .args(["--view", "none", "--seconds", "0.5"])
        .output()
        .unwrap();
    assert!(!out.status.success(), "exit 0 on a silent port");
    let err = stderr(&out);
    assert!(
        err.contains("no byte received") && err.contains("baud"),
        "{err}"
    );
}

/// Ranges are checked before anything is allocated or simulated; negative numbers reach the
/// check instead of clap's "unexpected argument".
#[test]
fn simulate_checks_its_ranges_before_simulating() {
    for (args, expect) in [
        (&["--rate", "1e9"][..], "allowed range"),
        (&["--rate", "200000"][..], "allowed range"),
        (&["--rate", "-1"][..], "allowed range"),
        (&["--count", "-1"][..], "-1"),
        (&["--failure-share", "-0.5"][..], "allowed range"),
        (
            &["--count", "1000000", "--rate", "500"][..],
            "GB of samples",
        ),
        (&["--sensor", "suction", "--rate", "40"][..], "71 Hz"),
    ] {
        let t0 = Instant::now();
        let out = slipguard().arg("simulate").args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} accepted");
        let err = stderr(&out);
        assert!(err.contains(expect), "{args:?}: {err}");
        assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "{args:?} took {:?} before refusing",
            t0.elapsed()
        );
    }
    let out = slipguard()
        .args(["demo", "--sim-count", "-1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        !stderr(&out).contains("unexpected argument"),
        "{}",
        stderr(&out)
    );
}

/// `slipguard label --stats | head -1`: the reader closes the pipe; the tool ends quietly with
/// exit 0 (it used to panic, exit 101).
#[test]
fn a_closed_stdout_ends_quietly() {
    let mut child = slipguard()
        .args(["label", "--stats"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Closed before the child prints anything: its first write meets a broken pipe.
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let status = child.wait().unwrap();
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(status.code(), Some(0), "{err}");
}
