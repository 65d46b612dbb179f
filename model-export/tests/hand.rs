//! The exporter's hand-level path: calibration on whole grasps and the blob run as the
//! firmware runs it, against the float model on the same hand feature rows.
use slipguard_core::blob::{AlignedBlob, InputUnit, ModelConfig, Variant};
use slipguard_core::features::stft::StftConfig;
use slipguard_core::float::FloatModel;
use slipguard_core::units::Millihertz;
use slipguard_export::hand::{HandRecording, agreement, quantize};

fn config() -> ModelConfig {
    ModelConfig {
        model_id: 0,
        name: *b"hand\0\0\0\0\0\0\0\0",
        variant: Variant::HandLstm,
        force_diff: false,
        sample_rate_mhz: Millihertz(16_700),
        input_unit: InputUnit::MilliNewton,
        input_offset: 0,
        input_full_scale: 32_768,
        stft: StftConfig::PAPER,
        hidden: [12, 0],
        cell_frac_bits: [0, 0],
        threshold_q15: 16_384,
        raise_after: 1,
        clear_after: 1,
        hand_rule: None,
    }
}

/// Three pads that close, lift at 40, wobble, and let go at 90 (pad 1 earlier).
fn recording(k: u64) -> HandRecording {
    let n = 130;
    let samples = (0..3)
        .map(|c| {
            (0..n)
                .map(|t| {
                    let ramp = ((t as f32 - 10.0) / 20.0).clamp(0.0, 1.0);
                    let wob = 800.0 * ((t as f32) * (0.9 + 0.2 * k as f32 + c as f32)).sin();
                    let gone = if c == 1 { 70 } else { 90 };
                    if t >= gone {
                        0.0
                    } else {
                        (3000.0 + 2000.0 * c as f32) * ramp + wob * ramp
                    }
                })
                .collect()
        })
        .collect();
    HandRecording {
        trial_id: format!("t{k}"),
        samples,
        start: 5,
        lift: Some(40),
        end: n,
    }
}

#[test]
fn hand_blob_calibrates_on_grasps_and_agrees_with_its_float_model() {
    let recs: Vec<HandRecording> = (0..5).map(recording).collect();
    let mut m = FloatModel::init_like_pytorch(config(), 3);
    let rows: Vec<Vec<Vec<f32>>> = recs.iter().map(|r| r.rows(&m)).collect();
    let refs: Vec<&[Vec<f32>]> = rows.iter().map(Vec::as_slice).collect();
    m.fit_normalisation_rows(&refs);
    let (blob, _, cal) = quantize(&m, &recs, None).unwrap();
    assert_eq!(cal.sequences, 5);
    assert_eq!(cal.steps, 5 * 125);
    let a = AlignedBlob::new(&blob);
    let parsed = a.parse().unwrap();
    assert!(parsed.config.variant.is_hand());
    assert_eq!(u16::from_le_bytes([blob[4], blob[5]]), 3);
    let ag = agreement(&m, &blob, &recs).unwrap();
    assert_eq!(ag.steps, 5 * 125);
    eprintln!(
        "max |dp| {} flag agreement {}",
        ag.max_abs_dp, ag.flag_agreement
    );
    // Measured 0.0006 and 100 %; bound about twice.
    assert!(ag.max_abs_dp < 0.0012, "{}", ag.max_abs_dp);
    assert!(ag.decisive_flag_agreement > 0.99);
    // A blob of other weights does not agree: the comparison can fail.
    let mut other = FloatModel::init_like_pytorch(config(), 4);
    other.fit_normalisation_rows(&refs);
    let (b2, _, _) = quantize(&other, &recs, None).unwrap();
    assert!(agreement(&m, &b2, &recs).unwrap().max_abs_dp > 0.01);
}
