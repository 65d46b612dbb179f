//! Golden vectors: a paper-sized model (variant (c), H = 128) and a force trace, with the
//! outputs the core must produce bit for bit. The QEMU bench (`firmware/qemu-bench`) runs the
//! same files on the Cortex-M4 and compares; this test pins the host side.
//!
//! `SLIPGUARD_BLESS=1 cargo test -p slipguard-core --test golden_vectors` regenerates them
//! (only when the format or arithmetic changes on purpose).
mod common;

use slipguard_core::blob::{AlignedBlob, CRC32, Variant};
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::quantize::quantize;

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/bench");
/// Steps in the trace.
const STEPS: usize = 200;

/// Per step: p(unstable) Q0.15 (i16), flag (u8), 0 (u8), CRC-32 of h and c of every LSTM (u32).
fn expected(model: &Model<'_>, input: &[i32]) -> Vec<u8> {
    let mut st = ChannelState::new();
    let mut out = Vec::new();
    for &raw in input {
        let o = model.step(&mut st, raw);
        out.extend_from_slice(&o.p_unstable_q15.to_le_bytes());
        out.push(o.unstable as u8);
        out.push(0);
        let mut digest = CRC32.digest();
        for l in &st.lstm {
            for v in l.h.iter().chain(&l.c) {
                digest.update(&v.to_le_bytes());
            }
        }
        out.extend_from_slice(&digest.finalize().to_le_bytes());
    }
    out
}

#[test]
fn host_core_reproduces_the_golden_vectors() {
    let dir = std::path::Path::new(DIR);
    if common::blessing() {
        std::fs::create_dir_all(dir).unwrap();
        let float = common::random_model(Variant::DataStftLstm, 128, false, 2024);
        let calib: Vec<Vec<f32>> = (0..3).map(|i| common::smooth_force(77 + i, 400)).collect();
        let refs: Vec<&[f32]> = calib.iter().map(|c| c.as_slice()).collect();
        let (blob, _) = quantize(&float, &refs, None).unwrap();
        let input: Vec<i32> = common::smooth_force(4242, STEPS)
            .iter()
            .map(|v| v.round() as i32)
            .collect();
        let bytes: Vec<u8> = input.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(dir.join("model.bin"), &blob).unwrap();
        std::fs::write(dir.join("input.bin"), bytes).unwrap();
        let a = AlignedBlob::new(&blob);
        std::fs::write(
            dir.join("expected.bin"),
            expected(&Model::from_bytes(a.as_bytes()).unwrap(), &input),
        )
        .unwrap();
    }
    let blob = AlignedBlob::new(&std::fs::read(dir.join("model.bin")).expect("model.bin"));
    let model = Model::from_bytes(blob.as_bytes()).expect("golden model parses");
    assert_eq!(
        model.config().macs_per_step(),
        4 * 128 * (11 + 128) + 2 * 128
    );
    let input: Vec<i32> = std::fs::read(dir.join("input.bin"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(input.len(), STEPS);
    let want = std::fs::read(dir.join("expected.bin")).unwrap();
    let got = expected(&model, &input);
    let first_diff = got.chunks(8).zip(want.chunks(8)).position(|(a, b)| a != b);
    assert_eq!(
        first_diff, None,
        "host output differs from the golden vectors at step {first_diff:?}"
    );
    assert_eq!(got.len(), want.len());
    // The trace must exercise both flag states, or the check proves little.
    let flags: Vec<u8> = got.chunks(8).map(|c| c[2]).collect();
    assert!(
        flags.contains(&0) && flags.contains(&1),
        "golden trace never changes the flag"
    );
}
