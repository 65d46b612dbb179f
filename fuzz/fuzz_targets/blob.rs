//! The model blob parser, the RAM copy the board runs and the model steps. The length field and
//! the CRCs are fixed up after mutation, as a blob (`SGMB`: total = the input's length) or as a
//! RAM image (`SGMI`: total = the length − 4, the blob CRC and the image CRC behind it), so that
//! inputs reach the header and tensor checks of both branches instead of stopping at a CRC.
//!
//! Every blob that parses is loaded as the board loads it (`ModelRam::load`: the weights re-laid
//! for the blocked kernel, the row parameters folded); the copy must parse as the same model and
//! step bit for bit like the blob (p, flag and LSTM state at every step). An image that parses
//! is stepped, and `ModelRam::load` refuses it (an image is never loaded again).
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_core::blob::{AlignedBlob, CRC_LEN, CRC32, HEADER_LEN, IMAGE_MAGIC, MAGIC};
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::model_ram::{LoadError, MODEL_RAM_BYTES, ModelRam};

const INPUTS: [i32; 10] = [
    0,
    1_000,
    -1_000,
    i32::MAX,
    i32::MIN,
    40_000,
    0,
    7,
    123_456,
    -5,
];

fn set_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

fuzz_target!(|data: &[u8]| {
    let mut b = data.to_vec();
    // The first byte's low bits pick the fix-up: none (the length and CRC checks themselves),
    // a blob, or a RAM image.
    let mode = b.first().map_or(1, |&x| x & 0x0F);
    if b.len() >= HEADER_LEN + 2 * CRC_LEN {
        match mode {
            0 => {}
            1..=11 => {
                b[..4].copy_from_slice(&MAGIC);
                let total = b.len();
                set_u32(&mut b, 8, total as u32);
                let crc = CRC32.checksum(&b[..total - CRC_LEN]);
                set_u32(&mut b, total - CRC_LEN, crc);
            }
            _ => {
                b[..4].copy_from_slice(&IMAGE_MAGIC);
                let total = b.len() - CRC_LEN;
                set_u32(&mut b, 8, total as u32);
                let crc = CRC32.checksum(&b[..total - CRC_LEN]);
                set_u32(&mut b, total - CRC_LEN, crc);
                let image_crc = CRC32.checksum(&b[..total]);
                set_u32(&mut b, total, image_crc);
            }
        }
    }
    let blob = AlignedBlob::new(&b);
    let Ok(model) = Model::from_bytes(blob.as_bytes()) else {
        return;
    };
    let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
    if blob.as_bytes()[..4] == IMAGE_MAGIC {
        let mut state = ChannelState::new();
        for raw in INPUTS {
            let out = model.step(&mut state, raw);
            assert!(out.p_unstable_q15 >= 0);
        }
        assert_eq!(
            ram.load(blob.as_bytes()),
            Err(LoadError::Blob(slipguard_core::blob::BlobError::BadMagic))
        );
        return;
    }
    let copy = match ram.load(blob.as_bytes()) {
        Ok(c) => c,
        Err(LoadError::TooLarge { len, capacity }) => {
            assert!(len as usize > capacity as usize);
            return;
        }
        Err(e) => panic!("a blob that parses is not loaded: {e}"),
    };
    let run =
        Model::from_bytes(copy).unwrap_or_else(|e| panic!("the RAM copy does not parse: {e}"));
    assert_eq!(run.blob().crc, model.blob().crc);
    assert_eq!(run.config(), model.config());
    let (mut sa, mut sb) = (ChannelState::new(), ChannelState::new());
    for (k, raw) in INPUTS.into_iter().enumerate() {
        let (x, y) = (model.step(&mut sa, raw), run.step(&mut sb, raw));
        assert!(x.p_unstable_q15 >= 0, "step {k}: p {}", x.p_unstable_q15);
        assert_eq!(x, y, "step {k}: the RAM copy steps unlike the blob");
        assert_eq!(sa.lstm, sb.lstm, "step {k}: LSTM state");
    }
});
