// Shared by `build.rs` of the firmware and of `qemu-app` (`include!`d): chooses the model blob
// that goes into the `.model` section (the MODEL flash region) and writes the linker fragment.
//
// Blob, first found: `$SLIPGUARD_MODEL` (a path, relative to the repository root unless
// absolute), `models/hand-force/hand-force.bin` (the shipped default model, issue 4),
// else the golden variant (c) H=128 test blob `firmware/core/tests/fixtures/bench/model.bin`
// (PyTorch-init weights: right sizes and timing, meaningless predictions).

/// Copies the chosen blob to `$OUT_DIR/model.bin`, writes `$OUT_DIR/model.x` and tells cargo.
fn select_model_blob(repo_root: &std::path::Path, out: &std::path::Path) {
    println!("cargo:rerun-if-env-changed=SLIPGUARD_MODEL");
    let default = repo_root.join("models").join("hand-force").join("hand-force.bin");
    println!("cargo:rerun-if-changed={}", default.display());
    let blob = match std::env::var_os("SLIPGUARD_MODEL") {
        Some(p) => {
            let p = std::path::PathBuf::from(p);
            if p.is_absolute() { p } else { repo_root.join(p) }
        }
        None if default.exists() => default,
        None => repo_root
            .join("firmware/core/tests/fixtures/bench/model.bin"),
    };
    println!("cargo:rerun-if-changed={}", blob.display());
    let bytes = std::fs::read(&blob)
        .unwrap_or_else(|e| panic!("reading model blob {}: {e}", blob.display()));
    assert!(
        bytes.len() <= 128 * 1024,
        "model blob {} is {} bytes, more than the 128 KiB MODEL region",
        blob.display(),
        bytes.len()
    );
    std::fs::write(out.join("model.bin"), &bytes).expect("writing model.bin");
    println!("cargo:rustc-env=SLIPGUARD_MODEL_PATH={}", blob.display());
    // The `.model` output section holds the blob at the start of the MODEL region; the firmware
    // reads the region through `__smodel`/`__emodel`, so a blob flashed there separately is what
    // runs (the compiler never sees its contents).
    std::fs::write(
        out.join("model.x"),
        "SECTIONS\n{\n  .model ORIGIN(MODEL) : ALIGN(4)\n  {\n    KEEP(*(.model .model.*));\n  } > MODEL\n}\nINSERT AFTER .rodata;\n\
         __smodel = ORIGIN(MODEL);\n__emodel = ORIGIN(MODEL) + LENGTH(MODEL);\n",
    )
    .expect("writing model.x");
    println!("cargo:rustc-link-arg=-Tmodel.x");
}
