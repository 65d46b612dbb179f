//! Sets `cfg(slipguard_dsp)` when the target has the Armv7E-M DSP extension (SXTB16, SMLAD), so
//! that `dsp` builds its assembly kernel. On stable Rust `cfg(target_feature = "dsp")` is never
//! set (Arm target features are unstable), so the target triple decides: every `thumbv7em-*`
//! core (Cortex-M4/M7) has the extension. A toolchain that does report the feature counts too.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(slipguard_dsp)");
    println!("cargo::rerun-if-changed=build.rs");
    let var = |k: &str| std::env::var(k).unwrap_or_default();
    let arm = var("CARGO_CFG_TARGET_ARCH") == "arm";
    let v7em = var("TARGET").starts_with("thumbv7em-");
    let reported = var("CARGO_CFG_TARGET_FEATURE")
        .split(',')
        .any(|f| f == "dsp");
    if arm && (v7em || reported) {
        println!("cargo::rustc-cfg=slipguard_dsp");
    }
}
