//! The application's command handling (`App::handle`) on arbitrary wire bytes, interleaved with
//! a few frames of arbitrary sensor values, over the golden model: it never panics and every frame it
//! sends encodes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_app::app::App;
use slipguard_app::frontend::FrameInput;
use slipguard_app::profile::Profile;
use slipguard_app::MAX_CHANNELS;
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{self, Deframer, MAX_WIRE};

static GOLDEN: &[u8] = include_bytes!("../../firmware/core/tests/fixtures/bench/model.bin");

fuzz_target!(|data: &[u8]| {
    let blob = AlignedBlob::new(GOLDEN);
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
