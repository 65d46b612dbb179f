//! Puts this crate's mps2-an386 `memory.x` on the linker search path and selects the model blob
//! (`../build-model.rs`).

use std::{env, fs, path::PathBuf};

include!("../build-model.rs");

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    fs::copy(manifest.join("memory.x"), out.join("memory.x")).expect("copying memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=../build-model.rs");
    println!("cargo:rerun-if-changed=build.rs");
    select_model_blob(&manifest.join("../.."), &out);
}
