//! `slipguard replay`: the CLI wraps the firmware's replay (the function the QEMU build is
//! compared with byte for byte), so on the recorded trial and scenario it must give exactly the
//! stream of `slipguard_app::replay::run` on the firmware's own copy of the trial.
use std::process::Command;

use slipguard::replay::{decode_stream, golden_model_path, load_blob};
use slipguard_app::profile::Profile;
use slipguard_app::replay::{self as fw, CHEEZ_TRIAL, cheez_script};
use slipguard_core::protocol::{Message, ReplyBody};

fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("slipguard-replay-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn cli_replay_equals_the_firmware_replay_byte_for_byte() {
    let out = tmp("cheez.bin");
    let png = tmp("cheez.png");
    let st = Command::new(env!("CARGO_BIN_EXE_slipguard"))
        .arg("replay")
        .arg(root().join("firmware/app/fixtures/Cheez_100_814_top_3.csv"))
        .arg("--model")
        .arg(golden_model_path())
        .args(["--script", "cheez", "--out"])
        .arg(&out)
        .arg("--png")
        .arg(&png)
        .status()
        .unwrap();
    assert!(st.success());
    let cli = std::fs::read(&out).unwrap();
    let blob = load_blob(&golden_model_path()).unwrap();
    let mut want = Vec::new();
    let n = fw::run(
        Profile::HAND,
        blob.as_bytes(),
        &CHEEZ_TRIAL,
        cheez_script::SCRIPT,
        cheez_script::OPEN_WIRES,
        |b| want.extend_from_slice(b),
    );
    // docs/protocol.md: 408 frames, 22 555 bytes.
    assert_eq!((n, want.len()), (408, 22_555));
    assert!(cli == want, "CLI replay differs from the firmware replay");
    let png = std::fs::read(&png).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

#[test]
fn marks_script_open_wire_and_bad_blob() {
    let trial = root().join("firmware/app/fixtures/Cheez_100_814_top_3.csv");
    let out = tmp("marks.bin");
    let st = Command::new(env!("CARGO_BIN_EXE_slipguard"))
        .arg("replay")
        .arg(&trial)
        .args([
            "--script",
            "marks",
            "--release-at",
            "200",
            "--open-wire",
            "3:100:130",
        ])
        .arg("--out")
        .arg(&out)
        .arg("--model")
        .arg(golden_model_path())
        .status()
        .unwrap();
    assert!(st.success());
    let frames = decode_stream(&std::fs::read(&out).unwrap());
    // 400 flag frames + 2 replies; grasp start (the trial's mark, 52) answered just before
    // flag frame 52, release just before 200.
    assert_eq!(frames.len(), 402);
    let pos = |want: fn(&ReplyBody) -> bool| {
        frames
            .iter()
            .position(|f| matches!(f.msg, Message::Reply(r) if want(&r.body)))
            .unwrap()
    };
    assert_eq!(pos(|b| matches!(b, ReplyBody::GraspStarted)), 52);
    assert_eq!(pos(|b| matches!(b, ReplyBody::Released)), 201);
    let flags: Vec<_> = frames
        .iter()
        .filter_map(|f| match f.msg {
            Message::Flags(f) => Some(f),
            _ => None,
        })
        .collect();
    // Open wire on channel 3: faulted within a few frames (debounce), cleared after the hold.
    assert!(flags[105].fault & (1 << 3) != 0);
    assert!(flags[99].fault == 0 && flags[160].fault == 0);
    // Disarmed after the release: no flag.
    assert!(flags[210..].iter().all(|f| f.unstable == 0));

    // A corrupted blob: refused before the replay; with --allow-bad-model, fault frames only.
    let mut b = std::fs::read(golden_model_path()).unwrap();
    b[5000] ^= 0x10;
    let bad = tmp("bad.bin");
    std::fs::write(&bad, &b).unwrap();
    let replay_bad = |allow: bool| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_slipguard"));
        c.arg("replay").arg(&trial).arg("--model").arg(&bad);
        if allow {
            c.arg("--allow-bad-model");
        }
        c.args(["--out", "-"]).output().unwrap()
    };
    let o = replay_bad(false);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && o.stdout.is_empty(), "{err}");
    assert!(
        err.contains("CRC") && err.contains("--allow-bad-model"),
        "{err}"
    );
    let o = replay_bad(true);
    assert!(o.status.success());
    let frames = decode_stream(&o.stdout);
    assert!(!frames.is_empty());
    assert!(frames.iter().all(|f| matches!(f.msg, Message::Fault(_))));
}
