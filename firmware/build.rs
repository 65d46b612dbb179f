//! Puts the chip's `memory.x` on the linker search path, where cortex-m-rt's `link.x` includes
//! it (the repository's root `memory.x` for the STM32F405RG, `memory-f446re.x` beside this file
//! for the STM32F446RE), and gives the binary its linker scripts: cortex-m-rt's `link.x`,
//! defmt's `defmt.x` and `model.x` (the MODEL region, written by `slipguard-support`).

use std::{env, fs, path::PathBuf};

fn main() {
    let manifest_dir =
        PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let memory_x = if env::var_os("CARGO_FEATURE_STM32F446RE").is_some() {
        manifest_dir.join("memory-f446re.x")
    } else {
        manifest_dir.join("..").join("memory.x")
    };
    fs::copy(&memory_x, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {}: {e}", memory_x.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");
    check_model_profile();
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x", "-Tmodel.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}

/// The embedded blob's rate and input unit (from `slipguard-support`'s build script) against this
/// build's sensor profile: a blob the firmware would answer with fault frames only stops the build,
/// unless `SLIPGUARD_ALLOW_BAD_MODEL=1` (then a cargo warning).
fn check_model_profile() {
    use slipguard_app::profile::Profile;
    println!("cargo:rerun-if-env-changed=SLIPGUARD_ALLOW_BAD_MODEL");
    let profile = if env::var_os("CARGO_FEATURE_PROFILE_SUCTION").is_some() {
        Profile::SUCTION
    } else {
        Profile::HAND
    };
    // Absent when the blob did not parse (already refused or allowed by the support crate).
    let (Some(rate), Some(unit)) = (
        env::var("DEP_SLIPGUARD_MODEL_RATE_MHZ").ok(),
        env::var("DEP_SLIPGUARD_MODEL_UNIT").ok(),
    ) else {
        return;
    };
    let rate_mhz = slipguard_core::units::Millihertz(rate.parse().unwrap_or(0));
    let why = if !profile.check_rate(rate_mhz) {
        let rates: Vec<String> = profile
            .rates_mhz
            .iter()
            .map(|r| format!("{}", r.hz()))
            .collect();
        Some(format!(
            "the model runs at {} Hz, the {} profile at {} Hz",
            rate_mhz.hz(),
            profile.name,
            rates.join(" or ")
        ))
    } else if unit != profile.unit.to_string() {
        Some(format!(
            "the model takes {unit} input, the {} profile delivers {}",
            profile.name, profile.unit
        ))
    } else {
        None
    };
    let Some(why) = why else { return };
    if env::var_os("SLIPGUARD_ALLOW_BAD_MODEL").is_some_and(|v| v == "1") {
        println!(
            "cargo:warning=model blob: {why}; embedded anyway (SLIPGUARD_ALLOW_BAD_MODEL=1): the \
             firmware will send fault frames only"
        );
    } else {
        eprintln!(
            "error: model blob (SLIPGUARD_MODEL): {why}. Build with the matching profile feature \
             or another blob (or SLIPGUARD_ALLOW_BAD_MODEL=1 to embed it anyway)"
        );
        std::process::exit(1);
    }
}
