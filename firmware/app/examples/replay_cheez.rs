//! Host side of the QEMU byte-for-byte test: replays the Cheez_100_814_top_3 trial with the
//! golden model (or the blob given as the first argument) and the command script, and writes the
//! frames the firmware would send to stdout (binary). `.ci/run` compares them with the QEMU
//! build's output (`scripts/qemu-replay.sh`).

use std::io::Write;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self, CHEEZ_TRIAL, cheez_script};
use slipguard_core::blob::AlignedBlob;

fn main() -> std::io::Result<()> {
    let path = std::env::args().nth(1).unwrap_or_else(|| {
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
        |b| out.extend_from_slice(b),
    );
    std::io::stdout().write_all(&out)?;
    eprintln!("replay: {frames} frames, {} bytes ({path})", out.len());
    Ok(())
}
