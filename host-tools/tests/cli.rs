//! The `slipguard` binary: exit codes and error messages.
use std::process::Command;

fn slipguard() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard"))
}

#[test]
fn malformed_file_gives_location_and_nonzero_exit() {
    let dir = std::env::temp_dir().join(format!("slipguard-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("bad.csv");
    std::fs::write(
        &p,
        "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,1\n0.1,zz\n",
    )
    .unwrap();
    let out = slipguard()
        .args(["dataset", "info"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.csv:6:2 (column `c0`)"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn simulate_writes_readable_recordings() {
    let dir = std::env::temp_dir().join(format!("slipguard-sim-{}", std::process::id()));
    let out = slipguard()
        .args(["simulate", "--count", "2", "--seed", "5", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info = slipguard()
        .args(["dataset", "info"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(info.status.success());
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        text.contains("sim-force-5-0000") && text.contains("2 trials"),
        "{text}"
    );
    let bad = slipguard()
        .args(["simulate", "--rate", "-1"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn train_refuses_a_closed_loop_policy_it_cannot_use() {
    // The golden blob runs at 16.7 Hz: refused for a 40 Hz model, before any training.
    let golden = slipguard::replay::golden_model_path();
    let out = slipguard()
        .args([
            "train",
            "--rate-hz",
            "40",
            "--closed-loop-mix",
            "4",
            "--epochs",
            "1",
        ])
        .arg("--closed-loop-policy")
        .arg(&golden)
        .args(["--out", "/nonexistent/never-written"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("runs at 16.7 Hz, not the --rate-hz 40 Hz"),
        "{err}"
    );
    // A corrupt blob: the parse error, naming the option.
    let dir = std::env::temp_dir().join(format!("slipguard-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.bin");
    let mut b = std::fs::read(&golden).unwrap();
    b.truncate(100);
    std::fs::write(&bad, b).unwrap();
    let out = slipguard()
        .args(["train", "--closed-loop-mix", "4", "--epochs", "1"])
        .arg("--closed-loop-policy")
        .arg(&bad)
        .args(["--out", "/nonexistent/never-written"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--closed-loop-policy") && err.contains("bad.bin"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
