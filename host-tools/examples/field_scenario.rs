//! Writes a field scenario (`slipguard_app::replay::scenario`) for the QEMU build and the host
//! replay (`scripts/qemu-replay.sh` step 6): a recording's grasp, repeated until the field
//! script's second grasp start (frame `field_script::GRASP_AGAIN_AT`) has a trial behind it, on
//! the profile its unit implies, with the blob the field script uploads. Prints the shipped
//! model for the recording's rate and profile (the one the board runs before the upload).
//!
//! `field_scenario RECORDING UPLOAD OUT`

use anyhow::{Context, bail};
use slipguard::replay;
use slipguard_app::replay::{field_script, scenario};

/// The QEMU build's SCENARIO region (`firmware/qemu-app/memory.x`), bytes.
const REGION: usize = 1 << 20;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [recording, upload, out] = args.as_slice() else {
        bail!("usage: field_scenario RECORDING UPLOAD OUT");
    };
    let trial = slipguard_data::load_path(
        recording.as_ref(),
        &slipguard_data::labels::LabelConfig::default(),
        |_, _| {},
    )?
    .remove(0);
    let profile = replay::profile_for(&trial, recording)?;
    let rate_mhz = trial.rate_mhz();
    let once = replay::trial_bytes(&trial, &profile);
    let steps = trial.n_steps().max(1);
    // At least twice (a grasp after the upload like the first), and 100 frames past the
    // second grasp start.
    let repeats = 2.max((field_script::GRASP_AGAIN_AT as usize + 100).div_ceil(steps));
    let bytes = once.repeat(repeats);
    let blob = std::fs::read(upload).with_context(|| format!("reading {upload}"))?;
    let mut file = scenario::header(&profile, bytes.len(), blob.len()).to_vec();
    file.extend_from_slice(&bytes);
    file.extend_from_slice(&blob);
    if file.len() > REGION {
        bail!(
            "{recording}: the scenario is {} bytes, more than the QEMU build's {} KiB SCENARIO region: use a shorter recording",
            file.len(),
            REGION / 1024
        );
    }
    std::fs::write(out, &file).with_context(|| format!("writing {out}"))?;
    eprintln!(
        "field_scenario: {} profile at {} Hz, {steps} steps × {repeats}, {}-byte blob: {out} ({} bytes)",
        profile.name,
        rate_mhz.hz(),
        blob.len(),
        file.len()
    );
    println!(
        "{}",
        replay::default_model_for(&profile, rate_mhz).display()
    );
    Ok(())
}
