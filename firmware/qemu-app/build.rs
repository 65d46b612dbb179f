//! Puts this crate's mps2-an386 `memory.x` (with its MODEL region) on the linker search path and
//! gives the binary its linker scripts: cortex-m-rt's `link.x` and `model.x` (the MODEL region,
//! written by `slipguard-support`). No `defmt.x`: this build logs over semihosting.

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    fs::copy(manifest.join("memory.x"), out.join("memory.x")).expect("copying memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    for arg in ["--nmagic", "-Tlink.x", "-Tmodel.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
