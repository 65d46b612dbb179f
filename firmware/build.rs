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
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x", "-Tmodel.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
