//! Host side of the QEMU field-script comparison: replays a trial with
//! `slipguard_app::replay::field_script` (sample stream, grasp start, lift, release, an upload
//! of a second blob into a RAM-backed flash slot, grasp start on it) and writes the frames the
//! firmware would send to stdout (binary). `scripts/qemu-replay.sh` compares them with the QEMU
//! build's.
//!
//! `replay_field MODEL SECOND`: the Cheez_100_814_top_3 trial on the hand profile, uploading
//! SECOND. `replay_field --scenario SCENARIO MODEL`: the profile, trial and uploaded blob of a
//! scenario file (`slipguard_app::replay::scenario`, the bytes QEMU loads into the SCENARIO
//! region); then also checks that the flags from the second grasp start on are the uploaded
//! model's (equal to a run on it from boot) and not MODEL's (a run on it throughout), exit
//! status 1 if not. MODEL is the blob in the factory slot (the image's default).

use std::io::Write;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self, CHEEZ_TRIAL, Trial, field_script, scenario};
use slipguard_app::upload::{FACTORY_SLOT, SimFlash};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{Deframer, Message};

/// The frames of the field script on `trial` with `model` in the factory slot, uploading
/// `second`: (wire bytes, frame index of the reload).
fn run(profile: Profile, model: &[u8], second: &[u8], trial: &Trial<'_>) -> (Vec<u8>, Option<u32>) {
    // Two 128 KiB slots, the model in the factory slot (as the QEMU build's RAM flash).
    let mut slots = [
        vec![u32::MAX; 128 * 1024 / 4],
        vec![u32::MAX; 128 * 1024 / 4],
    ];
    for (w, b) in slots[FACTORY_SLOT as usize]
        .iter_mut()
        .zip(model.chunks_exact(4))
    {
        *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    let [s0, s1] = &mut slots;
    let mut flash = SimFlash::new(s0, s1);
    let mut out = Vec::new();
    let (_, reloaded) = replay::run_field(profile, model, second, &mut flash, trial, |b| {
        out.extend_from_slice(b)
    });
    (out, reloaded)
}

/// The flag frames' probabilities from the second grasp start on.
fn flags_after_upload(wire: &[u8]) -> Vec<[slipguard_core::protocol::PUnstable; 16]> {
    let mut d = Deframer::new();
    wire.iter()
        .filter_map(|&b| d.push_decode(b))
        .filter_map(|r| match r {
            Ok(f) => match f.msg {
                Message::Flags(x) => Some(x.p),
                _ => None,
            },
            Err(_) => None,
        })
        .skip(field_script::GRASP_AGAIN_AT as usize)
        .collect()
}

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = match args.as_slice() {
        [flag, scen, model] if flag == "--scenario" => {
            let file = AlignedBlob::new(&std::fs::read(scen)?);
            let s = match scenario::parse(file.as_bytes()) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("replay_field: {scen}: {e}");
                    std::process::exit(2);
                }
            };
            let model = AlignedBlob::new(&std::fs::read(model)?);
            let upload = AlignedBlob::new(s.upload);
            let (p, (old, new)) = (s.profile, (model.as_bytes(), upload.as_bytes()));
            let (out, reloaded) = run(p, old, new, &s.trial);
            let field = flags_after_upload(&out);
            let on_new = flags_after_upload(&run(p, new, new, &s.trial).0);
            let on_old = flags_after_upload(&run(p, old, old, &s.trial).0);
            let fine =
                reloaded.is_some() && !field.is_empty() && field == on_new && field != on_old;
            eprintln!(
                "replay_field: {} profile, {} steps: {} flag frames after the upload, {} the new model's, {} the old one's",
                p.name,
                s.trial.steps(),
                field.len(),
                if field == on_new { "equal to" } else { "NOT" },
                if field == on_old { "EQUAL to" } else { "not" },
            );
            if !fine {
                std::process::exit(1);
            }
            out
        }
        [model, second] => {
            let model = AlignedBlob::new(&std::fs::read(model)?);
            let second = AlignedBlob::new(&std::fs::read(second)?);
            let (out, reloaded) = run(
                Profile::HAND,
                model.as_bytes(),
                second.as_bytes(),
                &CHEEZ_TRIAL,
            );
            if reloaded.is_none() {
                std::process::exit(1);
            }
            out
        }
        _ => {
            eprintln!("usage: replay_field MODEL SECOND | replay_field --scenario SCENARIO MODEL");
            std::process::exit(2);
        }
    };
    eprintln!("replay_field: {} bytes of frames", out.len());
    std::io::stdout().write_all(&out)
}
