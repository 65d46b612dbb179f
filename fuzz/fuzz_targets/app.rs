//! The application's command handling (`App::handle`) on arbitrary wire bytes, interleaved with
//! a few frames of arbitrary sensor values, over a small model with the golden model's settings: it never panics and every frame it
//! sends encodes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_app::app::App;
use slipguard_app::frontend::FrameInput;
use slipguard_app::profile::Profile;
use slipguard_app::MAX_CHANNELS;
use std::sync::OnceLock;

use slipguard_core::blob::AlignedBlob;
use slipguard_core::float::FloatModel;
use slipguard_core::model::Model;
use slipguard_core::quantize::quantize;
use slipguard_core::protocol::{self, Deframer, MAX_WIRE};

static GOLDEN: &[u8] = include_bytes!("../../firmware/core/tests/fixtures/bench/model.bin");

/// The golden blob's settings with hidden size 8 (PyTorch-style init, seed 1), quantized once:
/// the same code paths as the H=128 golden model at a fraction of the cost per input.
fn small_blob() -> &'static AlignedBlob {
    static BLOB: OnceLock<AlignedBlob> = OnceLock::new();
    BLOB.get_or_init(|| {
        let golden = AlignedBlob::new(GOLDEN);
        let mut config = *Model::from_bytes(golden.as_bytes())
            .expect("golden blob")
            .config();
        config.hidden = [8, if config.hidden[1] > 0 { 8 } else { 0 }];
        let m = FloatModel::init_like_pytorch(config, 1);
        let (bytes, _) = quantize(&m, &[], None).expect("quantize");
        AlignedBlob::new(&bytes)
    })
}

fuzz_target!(|data: &[u8]| {
    let blob = small_blob();
    let profile = if data.first().is_some_and(|b| b & 1 == 1) {
        Profile::SUCTION
    } else {
        Profile::HAND
    };
    let mut app = App::new(profile, blob.as_bytes());
    let mut d = Deframer::new();
    let mut wire = [0u8; MAX_WIRE];
    let mut index = 0u32;
    for (i, &b) in data.iter().enumerate().skip(1) {
        if let Some(r) = d.push_decode(b) {
            let reply = app.handle(r);
            assert!(protocol::encode(&reply, &mut wire) > 0);
        }
        // Every 16th byte, up to 4 frames per input (16 channels of the H=128 model each): a
        // frame with values from the input.
        if i % 16 == 0 && index < 4 {
            let mut input = FrameInput {
                index,
                value_q4: [0; MAX_CHANNELS],
                fault: u16::from(b) << 8 & 0x8000,
                kinds: [0; MAX_CHANNELS],
            };
            for (c, v) in input.value_q4.iter_mut().enumerate() {
                let x = data.get(i.saturating_sub(c + 1)).copied().unwrap_or(0);
                *v = (i32::from(x) - 64) * 1_000;
            }
            index = index.wrapping_add(1);
            app.frames(&input, b & 0x10 != 0, |f| {
                assert!(protocol::encode(f, &mut wire) > 0);
            });
        }
    }
});
