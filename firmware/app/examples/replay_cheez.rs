//! Host side of the QEMU byte-for-byte test: replays the Cheez_100_814_top_3 trial with the
//! golden model (or the blob given as the first argument) and the command script, and writes the
//! frames the firmware would send to stdout (binary). `.ci/run` compares them with the QEMU
//! build's output (`scripts/qemu-replay.sh`).
//!
//! `replay_cheez [BLOB] [--expect-fault]`: with `--expect-fault` the exit status is 1 unless the
//! stream holds fault frames and not a single flag frame (the corrupted-blob check).

use std::io::Write;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self, CHEEZ_TRIAL, cheez_script};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{Deframer, Message};

fn main() -> std::io::Result<()> {
    let expect_fault = std::env::args().any(|a| a == "--expect-fault");
    let path = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with("--"))
        .unwrap_or_else(|| {
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../core/tests/fixtures/bench/model.bin"
            )
            .to_string()
        });
    let blob = AlignedBlob::new(&std::fs::read(&path)?);
    let mut out = Vec::new();
    let frames = replay::run(
        Profile::HAND,
        blob.as_bytes(),
        &CHEEZ_TRIAL,
        cheez_script::SCRIPT,
        cheez_script::OPEN_WIRES,
        |b| out.extend_from_slice(b),
    );
    std::io::stdout().write_all(&out)?;
    eprintln!("replay: {frames} frames, {} bytes ({path})", out.len());
    if expect_fault {
        let mut d = Deframer::new();
        let (mut flags, mut faults) = (0, 0);
        for f in out.iter().filter_map(|&b| d.push_decode(b)).flatten() {
            match f.msg {
                Message::Flags(_) => flags += 1,
                Message::Fault(_) => faults += 1,
                _ => {}
            }
        }
        eprintln!("replay: {flags} flag frames, {faults} fault frames");
        if flags != 0 || faults == 0 {
            std::process::exit(1);
        }
    }
    Ok(())
}
