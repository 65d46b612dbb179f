//! With the `model-region` feature: chooses the model blob for the MODEL flash region, copies it
//! to `$OUT_DIR/model.bin` (included by `src/model.rs`) and writes the linker fragment
//! `$OUT_DIR/model.x` on the linker search path of every binary that depends on this crate (the
//! binary links with `-Tmodel.x`).
//!
//! Blob, first found: `$SLIPGUARD_MODEL` (a path, relative to the repository root unless
//! absolute), `models/hand-force/hand-force.bin` (the shipped default model), else the golden
//! variant (c) H=128 test blob `firmware/core/tests/fixtures/bench/model.bin` (PyTorch-init
//! weights: right sizes and timing, meaningless predictions).
//!
//! The blob is parsed with the firmware's own parser (`slipguard-core`): one that does not parse,
//! is over the build's bounds or does not fit the region stops the build with one line saying why,
//! unless `SLIPGUARD_ALLOW_BAD_MODEL=1` (then a cargo warning; the firmware boots into a system
//! fault and sends fault frames). Its rate and input unit go to the binary's build script
//! (`DEP_SLIPGUARD_MODEL_RATE_MHZ`, `DEP_SLIPGUARD_MODEL_UNIT`), which checks them against its
//! sensor profile.

use std::path::{Path, PathBuf};
use std::{env, fs};

/// Bytes of the MODEL region on every board (STM32F405RG sector 11, STM32F446RE sector 7); the
/// QEMU map has more, the blob must fit the smallest.
const MODEL_REGION_BYTES: usize = 128 * 1024;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if env::var_os("CARGO_FEATURE_MODEL_REGION").is_none() {
        return;
    }
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let repo_root = manifest.join("..").join("..");
    let blob = select_model_blob(&repo_root);
    println!("cargo:rerun-if-changed={}", blob.display());
    let bytes = fs::read(&blob)
        .unwrap_or_else(|e| refuse(&format!("reading model blob {}: {e}", blob.display())));
    if bytes.len() > MODEL_REGION_BYTES {
        refuse(&format!(
            "model blob {} is {} bytes, more than the {} KiB MODEL region",
            blob.display(),
            bytes.len(),
            MODEL_REGION_BYTES / 1024
        ));
    }
    println!("cargo:rerun-if-env-changed=SLIPGUARD_ALLOW_BAD_MODEL");
    let allow_bad = env::var_os("SLIPGUARD_ALLOW_BAD_MODEL").is_some_and(|v| v == "1");
    match check_blob(&bytes) {
        Ok((rate_mhz, unit)) => {
            println!("cargo:rate_mhz={rate_mhz}");
            println!("cargo:unit={unit}");
        }
        Err(why) if allow_bad => println!(
            "cargo:warning=model blob {}: {why}; embedded anyway (SLIPGUARD_ALLOW_BAD_MODEL=1): \
             the firmware will send fault frames only",
            blob.display()
        ),
        Err(why) => refuse(&format!(
            "model blob {}: {why}. Set SLIPGUARD_MODEL to a blob from `slipguard train` or \
             `slipguard-export` (or SLIPGUARD_ALLOW_BAD_MODEL=1 to embed it anyway)",
            blob.display()
        )),
    }
    fs::write(out.join("model.bin"), &bytes).expect("writing model.bin");
    // The `.model` output section holds the blob at the start of the MODEL region; the firmware
    // reads the region through `__smodel`/`__emodel`, so a blob flashed there separately is what
    // runs (the compiler never sees its contents). EXTERN makes the linker pull the blob's object
    // out of this crate's archive even when nothing references it by name.
    fs::write(
        out.join("model.x"),
        "EXTERN(SLIPGUARD_DEFAULT_MODEL);\n\
         SECTIONS\n{\n  .model ORIGIN(MODEL) : ALIGN(4)\n  {\n    KEEP(*(.model .model.*));\n  } > MODEL\n}\nINSERT AFTER .rodata;\n\
         __smodel = ORIGIN(MODEL);\n__emodel = ORIGIN(MODEL) + LENGTH(MODEL);\n",
    )
    .expect("writing model.x");
    println!("cargo:rustc-link-search={}", out.display());
}

/// The blob the build embeds; `scripts/qemu-replay.sh` applies the same rule.
fn select_model_blob(repo_root: &Path) -> PathBuf {
    println!("cargo:rerun-if-env-changed=SLIPGUARD_MODEL");
    let default = repo_root
        .join("models")
        .join("hand-force")
        .join("hand-force.bin");
    println!("cargo:rerun-if-changed={}", default.display());
    match env::var_os("SLIPGUARD_MODEL") {
        Some(p) => {
            let p = PathBuf::from(p);
            if p.is_absolute() {
                p
            } else {
                repo_root.join(p)
            }
        }
        None if default.exists() => default,
        None => repo_root.join("firmware/core/tests/fixtures/bench/model.bin"),
    }
}

/// Parses the blob as the firmware does at boot; returns its rate (mHz) and input unit name.
fn check_blob(bytes: &[u8]) -> Result<(u32, String), String> {
    // Flash holds the blob 4-byte aligned; so does this copy.
    let mut words = vec![0u32; bytes.len().div_ceil(4)];
    bytemuck::cast_slice_mut::<u32, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
    let aligned = &bytemuck::cast_slice::<u32, u8>(&words)[..bytes.len()];
    let model = slipguard_core::model::Model::from_bytes(aligned)
        .map_err(|e| format!("not a valid model blob: {e}"))?;
    let c = model.config();
    Ok((c.sample_rate_mhz.0, c.input_unit.to_string()))
}

/// Stops the build with one line (no panic backtrace).
fn refuse(msg: &str) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(1)
}
