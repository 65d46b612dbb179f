//! The wire protocol: the deframer on raw bytes, and the payload decoder on payloads whose CRC is
//! fixed up after mutation (so that the header, type and field checks are reached). Every payload
//! that decodes re-encodes to a frame that decodes to the same message.
#![no_main]

use libfuzzer_sys::fuzz_target;
use slipguard_core::blob::CRC32;
use slipguard_core::protocol::{self, Deframer, MAX_WIRE};

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if mode & 1 == 0 {
        let mut d = Deframer::new();
        for &b in rest {
            let _ = d.push_decode(b);
        }
        let _ = protocol::decode(rest);
        return;
    }
    let mut p = rest.to_vec();
    if p.len() >= 4 {
        let body = p.len() - 4;
        let crc = CRC32.checksum(&p[..body]);
        p[body..].copy_from_slice(&crc.to_le_bytes());
    }
    if let Ok(frame) = protocol::decode_payload(&p) {
        let mut wire = [0u8; MAX_WIRE];
        let n = protocol::encode(&frame, &mut wire);
        assert!(n > 0, "a decoded frame does not encode: {frame:?}");
        assert_eq!(protocol::decode(&wire[..n]), Ok(frame));
    }
});
