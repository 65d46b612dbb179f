//! The board's command path on fuzzed frames: `upload::receive` (deframer, `Uploader`, `App`)
//! over a simulated flash, interleaved with frames of arbitrary sensor values, over a small model
//! with the golden model's settings. Most frames get their CRC fixed up and are COBS-encoded
//! here, so that mutated commands reach the dispatcher (phase commands, thresholds, stream
//! modes, uploads) instead of stopping at the CRC; raw bytes test the deframer. It never panics,
//! every frame it sends encodes, and after a commit the board reboots onto a model.
//!
//! Input: byte 0 picks the profile; then records `tag, len, bytes…`: tag % 4 = 0 raw wire bytes,
//! 1 a payload whose CRC is fixed up (then COBS and the delimiter), 2 a frame of sensor values,
//! 3 a wire frame (COBS, without its delimiter) whose CRC is fixed up after decoding (the seeds:
//! the wire examples of docs/protocol.md).
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_app::MAX_CHANNELS;
use slipguard_app::app::App;
use slipguard_app::frontend::FrameInput;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{self, SimFlash, Uploader};
use std::sync::OnceLock;

use slipguard_core::blob::{AlignedBlob, CRC32};
use slipguard_core::float::FloatModel;
use slipguard_core::model::Model;
use slipguard_core::model_ram::ModelRam;
use slipguard_core::protocol::{self, Deframer, MAX_WIRE};
use slipguard_core::quantize::quantize;

static GOLDEN: &[u8] = include_bytes!("../../firmware/core/tests/fixtures/bench/model.bin");

/// Slot size of the simulated flash: one F405 sector, so that the upload begin of the protocol
/// examples (an 80 444-byte blob) is accepted and its chunks are written.
const SLOT_WORDS: usize = 128 * 1024 / 4;

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

/// `payload` with its last 4 bytes replaced by the CRC of the rest, COBS-encoded and delimited.
fn fixed_frame(payload: &[u8], out: &mut Vec<u8>) {
    let mut p = payload.to_vec();
    if p.len() >= 4 {
        let body = p.len() - 4;
        let crc = CRC32.checksum(&p[..body]);
        p[body..].copy_from_slice(&crc.to_le_bytes());
    }
    out.extend_from_slice(&cobs::encode_vec(&p));
    out.push(0);
}

fuzz_target!(|data: &[u8]| {
    let blob = small_blob();
    let Some((&first, mut rest)) = data.split_first() else {
        return;
    };
    let profile = if first & 1 == 1 {
        Profile::SUCTION
    } else {
        Profile::HAND
    };
    let mut s0 = vec![u32::MAX; SLOT_WORDS];
    let mut s1 = vec![u32::MAX; SLOT_WORDS];
    for (w, b) in s1.iter_mut().zip(blob.as_bytes().chunks_exact(4)) {
        *w = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
    }
    let mut ram = Box::new(ModelRam::<{ 8 * 1024 }>::new());
    let mut index = 0u32;
    let mut wire = [0u8; MAX_WIRE];
    'boot: loop {
        let mut flash = SimFlash::new(&mut s0, &mut s1);
        let active = upload::select(&flash, &profile);
        let bytes: &[u8] = ram.load(upload::blob(&flash, active)).unwrap_or(&[]);
        let mut app = App::new(profile, bytes);
        let mut up = Uploader::new(active);
        let mut d = Deframer::new();
        while let [tag, len, tail @ ..] = rest {
            let n = (*len as usize).min(tail.len());
            let (chunk, after) = tail.split_at(n);
            rest = after;
            let mut bytes = Vec::new();
            match tag % 4 {
                0 => bytes.extend_from_slice(chunk),
                1 => fixed_frame(chunk, &mut bytes),
                3 => match cobs::decode_vec(chunk) {
                    Ok(payload) => fixed_frame(&payload, &mut bytes),
                    Err(_) => bytes.extend_from_slice(chunk),
                },
                2 if index < 4 => {
                    // A frame with values from the record (up to 4 frames per input: 16 channels
                    // each).
                    let mut input = FrameInput {
                        index,
                        value_q4: [0; MAX_CHANNELS],
                        fault: u16::from(*len) << 8 & 0x8000,
                        kinds: [0; MAX_CHANNELS],
                    };
                    for (c, v) in input.value_q4.iter_mut().enumerate() {
                        let x = chunk.get(c).copied().unwrap_or(0);
                        *v = (i32::from(x) - 64) * 1_000;
                    }
                    index = index.wrapping_add(1);
                    app.frames(&input, tag & 0x10 != 0, |f| {
                        assert!(protocol::encode(f, &mut wire) > 0);
                    });
                    continue;
                }
                _ => continue,
            }
            let reload = upload::receive(&mut up, &mut app, &mut flash, &mut d, &bytes, |f| {
                assert!(
                    protocol::encode(f, &mut wire) > 0,
                    "a reply does not encode"
                );
            });
            if let Some(a) = reload {
                // The board restarts onto the committed slot: it must boot a model.
                drop(app);
                let mut ram2 = Box::new(ModelRam::<{ 8 * 1024 }>::new());
                let (booted, app2) = upload::boot(&flash, profile, &mut ram2);
                assert_eq!(booted, Some(a));
                assert!(app2.model().is_ok(), "the committed model does not boot");
                continue 'boot;
            }
        }
        break;
    }
});
