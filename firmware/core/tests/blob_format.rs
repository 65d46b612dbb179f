//! Model blob v1 and v2: golden bytes, and one specific error for each kind of damage.
mod common;

use slipguard_core::blob::{
    AlignedBlob, BlobError, BlobTensors, CRC32, DenseRowParams, FeatureNorm, HEADER_LEN,
    LstmRowParams, ModelBlob, TensorKind, Variant, write_blob,
};
use slipguard_core::decision::{FusedHand, LoadRule};
use slipguard_core::model::{ChannelState, Model};

const GOLDEN: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/golden_blob_v1.hex"
);
const GOLDEN_V2: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/golden_blob_v2.hex"
);

/// The fused hand decision of the v2 golden blob: the rule alone under 0.4 of the peak over 10
/// frames, the model's flag while the load is under 0.8 of it.
fn rule() -> FusedHand {
    FusedHand {
        strict: LoadRule {
            fraction_q15: 13_107,
            window: 10,
        },
        guard_q15: 26_214,
    }
}

/// [`small`] with the hand rule: a v2 blob.
fn small_v2() -> (slipguard_core::blob::ModelConfig, BlobTensors) {
    let (mut config, tensors) = small();
    config.name = *b"golden-v2\0\0\0";
    config.hand_rule = Some(rule());
    (config, tensors)
}

/// A small variant (a) model, H = 3, force + d(t), with hand-picked integer tensors.
fn small() -> (slipguard_core::blob::ModelConfig, BlobTensors) {
    let mut config = common::config(Variant::Lstm, 3, true);
    config.cell_frac_bits = [11, 0];
    config.name = *b"golden-v1\0\0\0";
    config.threshold_q15 = 19_661; // 0.6
    config.raise_after = 2;
    // Rows: 4H = 12, row = pad4(2 inputs) + pad4(3 hidden) = 8 bytes.
    let mut w = vec![0i8; 12 * 8];
    for r in 0..12 {
        for c in [0usize, 1, 4, 5, 6] {
            w[r * 8 + c] = ((r as i32 * 37 + c as i32 * 11) % 255 - 127) as i8;
        }
    }
    let rows = (0..12)
        .map(|r| LstmRowParams {
            mx: 1_000_000 + r,
            mh: -2_000_000 - r,
            bias_q12: 100 * r - 600,
            shift: 31,
        })
        .collect();
    let tensors = BlobTensors {
        norm: vec![
            FeatureNorm {
                mean_q15: 9830,
                gain: 27_306,
                shift: 16,
            },
            FeatureNorm {
                mean_q15: 0,
                gain: 20_480,
                shift: 12,
            },
        ],
        lstm: vec![(w, rows)],
        dense: (
            vec![10, -20, 30, 0, -40, 50, -60, 0],
            vec![
                DenseRowParams {
                    m: 123_456,
                    bias_q12: 0,
                    shift: 24,
                },
                DenseRowParams {
                    m: 654_321,
                    bias_q12: -409,
                    shift: 24,
                },
            ],
        ),
    };
    (config, tensors)
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .chunks(32)
        .map(|c| c.iter().map(|b| format!("{b:02x}")).collect::<String>() + "\n")
        .collect()
}

#[test]
fn golden_bytes_of_a_small_blob() {
    let (config, tensors) = small();
    let bytes = write_blob(&config, &tensors);
    if common::blessing() {
        std::fs::write(GOLDEN, hex(&bytes)).unwrap();
    }
    let want = std::fs::read_to_string(GOLDEN).expect("golden file (SLIPGUARD_BLESS=1 writes it)");
    assert_eq!(
        hex(&bytes),
        want,
        "blob bytes changed: a format change needs a new version"
    );
    // Independent spot checks of the documented layout (docs/model-format.md).
    assert_eq!(&bytes[0..4], b"SGMB");
    assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), 1);
    assert_eq!(
        u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
        bytes.len()
    );
    assert_eq!(bytes[16], 0); // variant (a)
    assert_eq!(bytes[17], 1); // d(t) flag
    assert_eq!(
        u32::from_le_bytes(bytes[20..24].try_into().unwrap()),
        16_700
    );
    assert_eq!(u16::from_le_bytes([bytes[36], bytes[37]]), 19_661);
    assert_eq!(&bytes[52..61], b"golden-v1");
    // CRC-32/ISO-HDLC is zlib's crc32: check value of "123456789" is 0xCBF43926.
    assert_eq!(CRC32.checksum(b"123456789"), 0xCBF4_3926);
    let n = bytes.len();
    assert_eq!(
        u32::from_le_bytes(bytes[n - 4..].try_into().unwrap()),
        CRC32.checksum(&bytes[..n - 4])
    );

    let blob = AlignedBlob::new(&bytes);
    let parsed = blob.parse().expect("golden blob parses");
    assert_eq!(parsed.config, config);
    assert_eq!(parsed.norm, tensors.norm.as_slice());
    assert_eq!(parsed.lstm[0].weights, tensors.lstm[0].0.as_slice());
    assert_eq!(parsed.lstm[0].rows, tensors.lstm[0].1.as_slice());
    assert_eq!(parsed.dense.rows, tensors.dense.1.as_slice());
    assert_eq!(parsed.config.macs_per_step(), 4 * 3 * (2 + 3) + 2 * 3);
}

/// Rewrites the CRC after a deliberate change, so the parser reaches the check under test.
fn recrc(bytes: &mut [u8]) {
    let n = bytes.len();
    let crc = CRC32.checksum(&bytes[..n - 4]);
    bytes[n - 4..].copy_from_slice(&crc.to_le_bytes());
}

fn parse(bytes: &[u8]) -> Result<(), BlobError> {
    AlignedBlob::new(bytes).parse().map(|_| ())
}

fn patched(f: impl FnOnce(&mut Vec<u8>)) -> Result<(), BlobError> {
    let (config, tensors) = small();
    let mut b = write_blob(&config, &tensors);
    f(&mut b);
    recrc(&mut b);
    parse(&b)
}

#[test]
fn each_kind_of_damage_has_its_own_error() {
    let (config, tensors) = small();
    let good = write_blob(&config, &tensors);
    let n = good.len();

    assert!(matches!(
        parse(&good[..10]),
        Err(BlobError::Truncated {
            needed: 64,
            present: 10
        })
    ));
    assert_eq!(
        parse(&good[..n - 1]),
        Err(BlobError::Truncated {
            needed: n as u32,
            present: n as u32 - 1
        })
    );
    let mut bad = good.clone();
    bad[0] = b'X';
    assert_eq!(parse(&bad), Err(BlobError::BadMagic));
    let mut bad = good.clone();
    bad[4] = 4;
    assert_eq!(parse(&bad), Err(BlobError::UnsupportedVersion(4)));
    // A per-channel blob relabelled v3 (the hand-level variant's version) is refused, and so is
    // the hand-level variant's byte in a v1 blob (v1 and v2 do not define it).
    assert_eq!(patched(|b| b[4] = 3), Err(BlobError::InconsistentSizes));
    assert_eq!(patched(|b| b[16] = 4), Err(BlobError::UnknownVariant(4)));
    let mut bad = good.clone();
    bad[4..6].copy_from_slice(&0u16.to_le_bytes());
    assert_eq!(parse(&bad), Err(BlobError::UnsupportedVersion(0)));
    // A v1 blob relabelled v2 lacks the hand-rule record v2 requires.
    assert_eq!(
        patched(|b| b[4] = 2),
        Err(BlobError::MissingTensor(TensorKind::HandRule))
    );
    let mut bad = good.clone();
    bad[200] ^= 0x10;
    assert!(matches!(parse(&bad), Err(BlobError::BadCrc { .. })));

    // Misaligned: the same bytes one byte into an aligned buffer.
    let aligned = AlignedBlob::new(&[&[0u8][..], &good].concat());
    assert_eq!(
        ModelBlob::parse(&aligned.as_bytes()[1..]).err(),
        Some(BlobError::Misaligned)
    );
    // A tensor offset that is not 4-aligned (first directory entry's offset + 2).
    assert_eq!(
        patched(|b| {
            let o = u32::from_le_bytes(b[HEADER_LEN + 8..HEADER_LEN + 12].try_into().unwrap()) + 2;
            b[HEADER_LEN + 8..HEADER_LEN + 12].copy_from_slice(&o.to_le_bytes());
        }),
        Err(BlobError::Misaligned)
    );

    assert_eq!(patched(|b| b[16] = 9), Err(BlobError::UnknownVariant(9)));
    assert_eq!(patched(|b| b[17] = 0x80), Err(BlobError::UnknownField));
    assert_eq!(patched(|b| b[19] = 7), Err(BlobError::UnknownField));
    assert_eq!(
        patched(|b| b[40..42].copy_from_slice(&129u16.to_le_bytes())),
        Err(BlobError::OverBounds)
    );
    assert_eq!(patched(|b| b[44] = 40), Err(BlobError::OverBounds));
    assert_eq!(
        patched(|b| b[40..42].copy_from_slice(&4u16.to_le_bytes())),
        Err(BlobError::TensorShape(TensorKind::LstmWeights))
    );
    assert_eq!(
        patched(|b| b[42..44].copy_from_slice(&4u16.to_le_bytes())),
        Err(BlobError::InconsistentSizes)
    );
    assert_eq!(patched(|b| b[18] = 2), Err(BlobError::InconsistentSizes));
    assert_eq!(
        patched(|b| b[46] = 0),
        Err(BlobError::QuantParam(TensorKind::LstmRowParams))
    );
    assert_eq!(
        patched(|b| b[36..38].copy_from_slice(&0u16.to_le_bytes())),
        Err(BlobError::BadSetting)
    );
    assert_eq!(
        patched(|b| b[28..32].copy_from_slice(&0i32.to_le_bytes())),
        Err(BlobError::BadSetting)
    );
    assert_eq!(patched(|b| b[32] = 20), Err(BlobError::InconsistentSizes)); // STFT settings in a force-only model

    // Directory damage: entry 1 is the LSTM weights, entry 2 its row parameters.
    let e = |i: usize| HEADER_LEN + 16 * i;
    assert_eq!(patched(|b| b[e(1)] = 9), Err(BlobError::UnknownTensor));
    assert_eq!(
        patched(|b| b[e(2)] = 2),
        Err(BlobError::DuplicateTensor(TensorKind::LstmWeights))
    );
    assert_eq!(
        patched(|b| b[e(1) + 4] = 11),
        Err(BlobError::TensorShape(TensorKind::LstmWeights))
    );
    assert_eq!(
        patched(|b| b[e(1) + 15] = 0xff),
        Err(BlobError::TensorOutOfBounds(TensorKind::LstmWeights))
    );
    assert_eq!(
        patched(|b| b[48..50].copy_from_slice(&4u16.to_le_bytes())),
        Err(BlobError::MissingTensor(TensorKind::DenseRowParams))
    );
    // A requantisation shift of 0 would make the rounding shift undefined.
    assert_eq!(
        patched(|b| {
            let o = u32::from_le_bytes(b[e(2) + 8..e(2) + 12].try_into().unwrap()) as usize;
            b[o + 12..o + 16].copy_from_slice(&0i32.to_le_bytes());
        }),
        Err(BlobError::QuantParam(TensorKind::LstmRowParams))
    );
}

#[test]
fn no_truncation_or_mutation_panics() {
    let float = common::random_model(Variant::LstmStftLstm, 8, true, 3);
    let (good, _) = slipguard_core::quantize::quantize(&float, &[], None).unwrap();
    for len in 0..good.len() {
        assert!(
            parse(&good[..len]).is_err(),
            "prefix of {len} bytes accepted"
        );
    }
    // Every single-byte change in the header and directory, with the CRC made valid again:
    // the parser either refuses it or gives a model that runs without panicking.
    let mut accepted = 0;
    for pos in 0..HEADER_LEN + 7 * 16 {
        for val in [0u8, 1, 2, 3, 0x7f, 0x80, 0xff] {
            let mut b = good.clone();
            if b[pos] == val {
                continue;
            }
            b[pos] = val;
            recrc(&mut b);
            let a = AlignedBlob::new(&b);
            if let Ok(m) = Model::from_bytes(a.as_bytes()) {
                accepted += 1;
                let mut st = ChannelState::new();
                for raw in [0, 5000, -70_000, i32::MAX, i32::MIN, 12] {
                    m.step(&mut st, raw);
                }
            }
        }
    }
    println!(
        "{accepted} harmless single-byte header changes accepted (ids, names, thresholds, offsets)"
    );
}

#[test]
fn golden_bytes_of_a_small_v2_blob() {
    let (config, tensors) = small_v2();
    let bytes = write_blob(&config, &tensors);
    if common::blessing() {
        std::fs::write(GOLDEN_V2, hex(&bytes)).unwrap();
    }
    let want =
        std::fs::read_to_string(GOLDEN_V2).expect("golden file (SLIPGUARD_BLESS=1 writes it)");
    assert_eq!(
        hex(&bytes),
        want,
        "blob bytes changed: a format change needs a new version"
    );
    // Independent spot checks of the documented layout (docs/model-format.md, version 2).
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    assert_eq!(&bytes[0..4], b"SGMB");
    assert_eq!(u16_at(4), 2, "version");
    assert_eq!(u32_at(8) as usize, bytes.len());
    assert_eq!(u16_at(48), 6, "tensor count: v1's 5 and the hand rule");
    // The sixth directory entry: kind 6, index 0, i32, 1 × 3, 12 bytes, at a 4-aligned offset.
    let e = HEADER_LEN + 5 * 16;
    assert_eq!(&bytes[e..e + 4], &[6, 0, 2, 0]);
    assert_eq!((u16_at(e + 4), u16_at(e + 6)), (1, 3));
    assert_eq!(u32_at(e + 12), 12);
    let o = u32_at(e + 8) as usize;
    assert_eq!(o % 4, 0);
    let record: Vec<i32> = (0..3).map(|k| u32_at(o + 4 * k) as i32).collect();
    assert_eq!(record, [13_107, 26_214, 10]);
    assert_eq!(
        o + 12 + 4,
        bytes.len(),
        "the record is the last tensor, the CRC follows"
    );
    assert_eq!(
        u32_at(bytes.len() - 4),
        CRC32.checksum(&bytes[..bytes.len() - 4])
    );

    let blob = AlignedBlob::new(&bytes);
    let parsed = blob.parse().expect("golden v2 blob parses");
    assert_eq!(parsed.config, config);
    assert_eq!(parsed.config.hand_rule, Some(rule()));
    assert_eq!(parsed.lstm[0].weights, tensors.lstm[0].0.as_slice());
    assert_eq!(parsed.dense.rows, tensors.dense.1.as_slice());

    // The v1 writer is unchanged without a rule, and the same tensors in v1 give the same
    // model steps (the rule is not part of the network).
    let (c1, t1) = small();
    let v1 = AlignedBlob::new(&write_blob(&c1, &t1));
    let (m1, m2) = (
        Model::from_bytes(v1.as_bytes()).unwrap(),
        Model::from_bytes(blob.as_bytes()).unwrap(),
    );
    let (mut s1, mut s2) = (ChannelState::new(), ChannelState::new());
    for raw in [0, 3000, 5000, 4000, 200, 9000] {
        assert_eq!(m1.step(&mut s1, raw), m2.step(&mut s2, raw));
    }

    // The RAM image keeps the rule (a quantized model: the golden rows cannot be folded, so
    // the golden blob would be copied plainly).
    let mut float = common::random_model(Variant::Lstm, 8, true, 5);
    float.config.hand_rule = Some(rule());
    let (q, _) = slipguard_core::quantize::quantize(&float, &[], None).unwrap();
    assert_eq!(u16::from_le_bytes([q[4], q[5]]), 2);
    let q = AlignedBlob::new(&q);
    let mut ram = slipguard_core::model_ram::ModelRam::<8192>::new();
    let image = ram.load(q.as_bytes()).unwrap();
    assert_eq!(&image[..4], b"SGMI", "a RAM image, not the plain copy");
    assert_eq!(
        ModelBlob::parse(image).unwrap().config.hand_rule,
        Some(rule())
    );
}

fn patched_v2(f: impl FnOnce(&mut Vec<u8>)) -> Result<(), BlobError> {
    let (config, tensors) = small_v2();
    let mut b = write_blob(&config, &tensors);
    f(&mut b);
    recrc(&mut b);
    parse(&b)
}

#[test]
fn a_bad_hand_rule_record_has_its_own_error() {
    assert_eq!(patched_v2(|_| ()), Ok(()));
    let entry = HEADER_LEN + 5 * 16;
    let at = |b: &[u8], k: usize| {
        u32::from_le_bytes(b[entry + 8..entry + 12].try_into().unwrap()) as usize + 4 * k
    };
    let set = |k: usize, v: i32| {
        move |b: &mut Vec<u8>| {
            let o = at(b, k);
            b[o..o + 4].copy_from_slice(&v.to_le_bytes());
        }
    };
    // Fractions 0..=32 767, window 1..=64: the edges pass, one past them is refused.
    for (k, ok, bad) in [
        (0, [0, 32_767], [-1, 32_768]),
        (1, [0, 32_767], [-1, 32_768]),
        (2, [1, 64], [0, 65]),
    ] {
        for v in ok {
            assert_eq!(patched_v2(set(k, v)), Ok(()), "field {k} = {v}");
        }
        for v in bad {
            assert_eq!(
                patched_v2(set(k, v)),
                Err(BlobError::BadHandRule),
                "field {k} = {v}"
            );
        }
    }
    assert_eq!(patched_v2(set(2, i32::MIN)), Err(BlobError::BadHandRule));
    // Shape: two rows, or i8 elements.
    assert_eq!(
        patched_v2(|b| b[entry + 4] = 2),
        Err(BlobError::TensorShape(TensorKind::HandRule))
    );
    assert_eq!(
        patched_v2(|b| b[entry + 2] = 1),
        Err(BlobError::TensorShape(TensorKind::HandRule))
    );
    // Listed twice, or in a v1 blob.
    assert_eq!(
        patched_v2(|b| b[entry - 16] = 6),
        Err(BlobError::DuplicateTensor(TensorKind::HandRule))
    );
    assert_eq!(patched_v2(|b| b[4] = 1), Err(BlobError::UnknownTensor));
    // A v2 blob whose count leaves the record out.
    assert_eq!(
        patched_v2(|b| b[48] = 5),
        Err(BlobError::MissingTensor(TensorKind::HandRule))
    );
    // The writer's check names the same error.
    let mut r = rule();
    r.strict.window = 0;
    assert_eq!(
        slipguard_core::blob::hand_rule_record(&r),
        Err(BlobError::BadHandRule)
    );
    assert_eq!(
        slipguard_core::blob::hand_rule_record(&rule()),
        Ok([13_107, 26_214, 10])
    );
    assert!(
        BlobError::BadHandRule
            .to_string()
            .contains("hand-rule record")
    );
}
