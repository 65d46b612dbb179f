//! Host side of the QEMU field-script comparison: replays the Cheez_100_814_top_3 trial with
//! `slipguard_app::replay::field_script` (sample stream, grasp start, lift, release, an upload
//! of SECOND into a RAM-backed flash slot, grasp start on it) and writes the frames the firmware
//! would send to stdout (binary). `scripts/qemu-replay.sh` compares them with the QEMU build's.
//!
//! `replay_field MODEL SECOND`: MODEL is the blob in the factory slot (the image's default).

use std::io::Write;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self, CHEEZ_TRIAL};
use slipguard_app::upload::{FACTORY_SLOT, SimFlash};
use slipguard_core::blob::AlignedBlob;

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model, second] = args.as_slice() else {
        eprintln!("usage: replay_field MODEL SECOND");
        std::process::exit(2);
    };
    let model = AlignedBlob::new(&std::fs::read(model)?);
    let second = AlignedBlob::new(&std::fs::read(second)?);
    // Two 128 KiB slots, the model in the factory slot (as the QEMU build's RAM flash).
    let mut slots = [
        vec![u32::MAX; 128 * 1024 / 4],
        vec![u32::MAX; 128 * 1024 / 4],
    ];
    let words: &[u32] = bytemuck::cast_slice(model.as_bytes());
    slots[FACTORY_SLOT as usize][..words.len()].copy_from_slice(words);
    let [s0, s1] = &mut slots;
    let mut flash = SimFlash::new(s0, s1);
    let mut out = Vec::new();
    let (frames, reloaded) = replay::run_field(
        Profile::HAND,
        model.as_bytes(),
        second.as_bytes(),
        &mut flash,
        &CHEEZ_TRIAL,
        |b| out.extend_from_slice(b),
    );
    std::io::stdout().write_all(&out)?;
    eprintln!(
        "replay_field: {frames} frames, {} bytes, new model from frame {reloaded:?}",
        out.len()
    );
    if reloaded.is_none() {
        std::process::exit(1);
    }
    Ok(())
}
