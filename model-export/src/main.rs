//! `slipguard-export`: float weights → quantized model blob. The importers and calibration
//! arrive with the export issue; today it can inspect a blob.
fn main() {
    println!("slipguard-export: see `slipguard-export --help`");
}
