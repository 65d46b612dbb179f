//! The model vocabulary: names of variants, input units and window shapes, `StftConfig::NONE`
//! and the Q0.15 converter for p(unstable) and thresholds.
use slipguard_core::blob::{InputUnit, Variant};
use slipguard_core::decision::Q15;
use slipguard_core::features::stft::{StftConfig, WindowShape};
use slipguard_core::units::Millihertz;

#[test]
fn names_round_trip_and_unknown_names_say_what_is_accepted() {
    let names: Vec<String> = Variant::ALL.iter().map(|v| v.to_string()).collect();
    assert_eq!(
        names,
        [
            "lstm",
            "stft-lstm",
            "data-stft-lstm",
            "lstm-stft-lstm",
            "hand-lstm"
        ]
    );
    for v in Variant::ALL {
        assert_eq!(v.to_string().parse::<Variant>(), Ok(v));
    }
    for u in [InputUnit::MilliNewton, InputUnit::Counts] {
        assert_eq!(u.to_string().parse::<InputUnit>(), Ok(u));
    }
    assert_eq!(InputUnit::MilliNewton.to_string(), "mN");
    for w in [WindowShape::Rectangular, WindowShape::Hann] {
        assert_eq!(w.to_string().parse::<WindowShape>(), Ok(w));
    }
    let e = "gru".parse::<Variant>().unwrap_err();
    assert_eq!(
        e.to_string(),
        "unknown variant (expected lstm, stft-lstm, data-stft-lstm, lstm-stft-lstm, hand-lstm (on a command line also a, b, c, d, h))"
    );
    for bad in ["", "e", "(c", "cc", "()", "LSTM"] {
        assert!(bad.parse::<Variant>().is_err(), "`{bad}` parsed");
    }
    assert!("newton".parse::<InputUnit>().is_err());
    assert!("hamming".parse::<WindowShape>().is_err());
}

#[test]
fn one_name_per_variant_and_the_papers_letters_only_on_a_command_line() {
    let accepted = [
        (Variant::Lstm, "lstm", ["a", "(a)"]),
        (Variant::StftLstm, "stft-lstm", ["b", "(b)"]),
        (Variant::DataStftLstm, "data-stft-lstm", ["c", " (c) "]),
        (Variant::LstmStftLstm, "lstm-stft-lstm", ["d", "(d)"]),
        (Variant::HandLstm, "hand-lstm", ["h", "(h)"]),
    ];
    for (v, name, letters) in accepted {
        assert_eq!(name.parse::<Variant>(), Ok(v));
        assert_eq!(Variant::from_cli(name), Ok(v));
        for l in letters {
            assert_eq!(Variant::from_cli(l), Ok(v), "`{l}`");
            assert!(l.parse::<Variant>().is_err(), "`{l}` is not a name");
        }
    }
    // The older spellings are gone: one name each.
    for old in ["force", "stft", "force-stft", "dual"] {
        assert!(Variant::from_cli(old).is_err(), "`{old}` still parses");
    }
}

#[test]
fn paper_rate_is_the_papers_16_7_hz() {
    use slipguard_core::sample::{PAPER_RATE_HZ, PAPER_RATE_MHZ};
    // The paper's Fig. 8 caption: "data frequency at 16.7 Hz" (one step every 60 ms).
    assert_eq!(PAPER_RATE_MHZ, Millihertz(16_700));
    assert_eq!(PAPER_RATE_HZ, 16.7);
    assert!((1.0 / 0.06 - f64::from(PAPER_RATE_HZ)).abs() < 0.05);
}

#[test]
fn no_stft_is_all_zero_and_rectangular() {
    let n = StftConfig::NONE;
    assert_eq!((n.window_len, n.first_bin, n.n_bins), (0, 0, 0));
    assert_eq!(n.shape, WindowShape::Rectangular);
    assert!(
        n.validate().is_err(),
        "NONE is not an STFT a band variant can use"
    );
}

#[test]
fn q15_rounds_to_nearest_and_saturates() {
    // 0.2 · 32768 = 6553.6: rounds up (truncation would give 6553).
    assert_eq!(Q15::from_f64(0.2), Q15(6554));
    assert_eq!(Q15::from_f64(0.15), Q15(4915));
    assert_eq!(Q15::from_f64(0.5), Q15(16_384));
    // Halves away from zero; 1.0 and above saturate to the largest value.
    assert_eq!(Q15::from_f64(2.5 / 32768.0), Q15(3));
    assert_eq!(Q15::from_f64(1.0), Q15(i16::MAX));
    assert_eq!(Q15::from_f64(-2.0), Q15(i16::MIN));
    assert_eq!(Q15(16_384).to_f64(), 0.5);
    // Every Q0.15 value survives the round trip.
    for v in [0i16, 1, 4915, 16_383, 32_767] {
        assert_eq!(Q15::from_f64(Q15(v).to_f64()), Q15(v));
    }
    // The header's threshold field never holds 0 (it would flag every step).
    assert_eq!(Q15::from_f64(0.0).header_threshold(), 1);
    assert_eq!(Q15::from_f64(0.9).header_threshold(), 29_491);
}

#[test]
fn blob_errors_keep_their_wire_detail_codes() {
    use slipguard_core::blob::{BlobError, TensorKind};
    use slipguard_core::features::stft::StftError;
    // Pinned: controllers decode these (docs/protocol.md); a code never changes meaning.
    let cases = [
        (
            BlobError::Truncated {
                needed: 80,
                present: 3,
            },
            (1, 80),
        ),
        (BlobError::BadMagic, (2, 0)),
        (BlobError::UnsupportedVersion(7), (3, 7)),
        (BlobError::BadLength, (4, 0)),
        (
            BlobError::BadCrc {
                stored: 1,
                computed: 0xDEAD_BEEF,
            },
            (5, 0xDEAD_BEEF),
        ),
        (BlobError::Misaligned, (6, 0)),
        (BlobError::UnknownVariant(9), (7, 9)),
        (BlobError::UnknownField, (8, 0)),
        (BlobError::OverBounds, (9, 0)),
        (BlobError::InconsistentSizes, (10, 0)),
        (BlobError::Stft(StftError::WindowTooShort(2)), (11, 0)),
        (BlobError::BadSetting, (12, 0)),
        (BlobError::UnknownTensor, (13, 0)),
        (BlobError::DuplicateTensor(TensorKind::FeatureNorm), (14, 1)),
        (BlobError::MissingTensor(TensorKind::FeatureNorm), (15, 1)),
        (BlobError::TensorShape(TensorKind::FeatureNorm), (16, 1)),
        (
            BlobError::TensorOutOfBounds(TensorKind::FeatureNorm),
            (17, 1),
        ),
        (BlobError::QuantParam(TensorKind::FeatureNorm), (18, 1)),
        (BlobError::BadHandRule, (19, 0)),
    ];
    for (e, want) in cases {
        assert_eq!(e.wire_detail(), want, "{e:?}");
    }
}
