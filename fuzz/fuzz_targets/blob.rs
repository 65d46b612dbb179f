//! The model blob parser, and a few model steps on every blob that parses. The length field and
//! the CRC are fixed up after mutation, so that the input reaches the header and tensor checks
//! instead of stopping at the CRC.
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_core::blob::{AlignedBlob, CRC_LEN, CRC32, HEADER_LEN};
use slipguard_core::model::{ChannelState, Model};

fuzz_target!(|data: &[u8]| {
    let mut b = data.to_vec();
    // The first byte picks whether the length and CRC are fixed up (most inputs) or left as
    // they are (the length and CRC checks themselves).
    let fix = b.first().is_none_or(|&x| x & 0x0F != 0);
    if fix && b.len() >= HEADER_LEN + CRC_LEN {
        let total = b.len() as u32;
        b[8..12].copy_from_slice(&total.to_le_bytes());
        let body = b.len() - CRC_LEN;
        let crc = CRC32.checksum(&b[..body]);
        b[body..].copy_from_slice(&crc.to_le_bytes());
    }
    let blob = AlignedBlob::new(&b);
    let Ok(model) = Model::from_bytes(blob.as_bytes()) else {
        return;
    };
    let mut state = ChannelState::new();
    for (k, raw) in [0, 1_000, -1_000, i32::MAX, i32::MIN, 40_000, 0, 7]
        .into_iter()
        .enumerate()
    {
        let out = model.step(&mut state, raw);
        assert!(out.p_unstable_q15 >= 0, "step {k}: p {}", out.p_unstable_q15);
    }
});
