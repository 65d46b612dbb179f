//! With the `model-region` feature: chooses the model blob for the MODEL flash region, copies it
//! to `$OUT_DIR/model.bin` (included by `src/model.rs`) and writes the linker fragment
//! `$OUT_DIR/model.x` on the linker search path of every binary that depends on this crate (the
//! binary links with `-Tmodel.x`).
//!
//! Blob, first found: `$SLIPGUARD_MODEL` (a path, relative to the repository root unless
//! absolute), `models/hand-force/hand-force.bin` (the shipped default model), else the golden
//! variant (c) H=128 test blob `firmware/core/tests/fixtures/bench/model.bin` (PyTorch-init
//! weights: right sizes and timing, meaningless predictions).

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
    let bytes =
        fs::read(&blob).unwrap_or_else(|e| panic!("reading model blob {}: {e}", blob.display()));
    assert!(
        bytes.len() <= MODEL_REGION_BYTES,
        "model blob {} is {} bytes, more than the {} KiB MODEL region",
        blob.display(),
        bytes.len(),
        MODEL_REGION_BYTES / 1024
    );
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
