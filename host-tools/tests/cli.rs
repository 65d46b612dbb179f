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
