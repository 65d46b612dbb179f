//! The batched path (`slipguard_batch`) against the single-channel path, bit for bit.
//!
//! The reference is `Model::step` / `Model::step_in_contact`, one channel at a time: the path
//! the firmware runs, itself checked against independent references (the f64 DFT and
//! microfft for the STFT, the f32 model and PyTorch fixtures for the network, f64 σ/tanh for
//! the tables; `quantized_vs_float.rs`, `torch_reference.rs`, the kernels' unit tests). Here
//! every output (p(unstable) and flag) of every lane at every step, and every lane's whole
//! state (STFT window, previous sample, h, c, hysteresis, contact), must be identical.
//!
//! Random models of every variant, with and without d(t), hidden sizes odd and even (a half
//! pair of h) up to 128; 70 lanes (two chunks, padding lanes), 700 steps with lane resets,
//! contact-gated restarts and ragged (masked) lanes. The shipped models on the real trials
//! are checked in `tests/tests/batch_real_trials.rs` (the workspace's cross-crate tests).
// The core's test helpers (random float models, smooth force traces), shared, not copied.
#[path = "../../../firmware/core/tests/common/mod.rs"]
mod common;

use slipguard_batch::{BatchModel, BatchState};
use slipguard_core::blob::{AlignedBlob, Variant};
use slipguard_core::decision::{ContactConfig, ContactEdge};
use slipguard_core::model::{ChannelState, GatedOutput, Model, StepOutput};
use slipguard_core::quantize::quantize;

const LANES: usize = 70;
const STEPS: usize = 700;

fn blob_of(variant: Variant, hidden: u16, diff: bool, seed: u64) -> Vec<u8> {
    let float = common::random_model(variant, hidden, diff, seed);
    let calib = [common::smooth_force(seed ^ 77, 300)];
    let refs: Vec<&[f32]> = calib.iter().map(|c| c.as_slice()).collect();
    quantize(&float, &refs, None).unwrap().0
}

/// Lane `l`'s raw samples: a smooth force trace, for odd lanes with unloaded stretches (so
/// that contact ends and begins again) and past full scale now and then.
fn traces(seed: u64) -> Vec<Vec<i32>> {
    (0..LANES)
        .map(|l| {
            let f = common::smooth_force(seed * 1000 + l as u64, STEPS);
            f.iter()
                .enumerate()
                .map(|(t, v)| {
                    let off = l % 2 == 1 && (t / (40 + l)) % 3 == 2;
                    if off {
                        20
                    } else {
                        v.round() as i32 * (1 + (l % 5 == 0) as i32)
                    }
                })
                .collect()
        })
        .collect()
}

fn assert_same_state(b: &BatchState, single: &[ChannelState], what: &str) {
    for (l, s) in single.iter().enumerate() {
        let got = b.channel(l).unwrap();
        assert_eq!(got.lstm, s.lstm, "{what}: lane {l} LSTM state");
        assert_eq!(got.decision, s.decision, "{what}: lane {l} hysteresis");
        assert_eq!(got.contact, s.contact, "{what}: lane {l} contact");
        assert_eq!(
            got.features.prev, s.features.prev,
            "{what}: lane {l} previous sample"
        );
        assert_eq!(
            got.features.stft, s.features.stft,
            "{what}: lane {l} STFT window"
        );
    }
}

/// Plain steps with resets of some lanes mid-sequence, and lanes that skip steps (masked).
fn check_steps(model: &Model<'_>, what: &str, x: &[Vec<i32>]) {
    let bm = BatchModel::new(model).unwrap();
    let mut bs = bm.state(LANES);
    let mut single = vec![ChannelState::new(); LANES];
    let mut out = vec![
        StepOutput {
            p_unstable_q15: -1,
            unstable: false
        };
        LANES
    ];
    for t in 0..STEPS {
        // Lane l resets at steps that are multiples of 97 + 13·l (several per lane).
        for (l, s) in single.iter_mut().enumerate() {
            if t > 0 && t % (97 + 13 * l) == 0 {
                s.reset();
                bs.reset_lane(l);
            }
        }
        let raw: Vec<i32> = x.iter().map(|v| v[t]).collect();
        // Every third lane skips a step now and then (a shorter or paused sequence).
        let active: Vec<bool> = (0..LANES).map(|l| l % 3 != 0 || (t + l) % 7 != 0).collect();
        if t % 2 == 0 {
            bm.step(&mut bs, &raw, &mut out);
            for l in 0..LANES {
                let want = model.step(&mut single[l], raw[l]);
                assert_eq!(out[l], want, "{what}: step {t} lane {l}");
            }
        } else {
            bm.step_masked(&mut bs, &raw, &active, &mut out);
            for l in (0..LANES).filter(|&l| active[l]) {
                let want = model.step(&mut single[l], raw[l]);
                assert_eq!(out[l], want, "{what}: masked step {t} lane {l}");
            }
        }
        if t % 50 == 0 || t == STEPS - 1 {
            assert_same_state(&bs, &single, what);
        }
    }
}

/// Contact-gated steps: onsets restart the lane's model, the steps out of contact run nothing.
fn check_gated(model: &Model<'_>, what: &str, x: &[Vec<i32>]) {
    let bm = BatchModel::new(model).unwrap();
    let contact = ContactConfig::of(model.config());
    let mut bs = bm.state(LANES);
    let mut single = vec![ChannelState::new(); LANES];
    let idle = GatedOutput {
        contact: ContactEdge::Idle,
        step: None,
    };
    let mut out = vec![idle; LANES];
    let mut onsets = 0;
    for t in 0..STEPS {
        let raw: Vec<i32> = x.iter().map(|v| v[t]).collect();
        bm.step_in_contact(&mut bs, &contact, &raw, None, &mut out);
        for l in 0..LANES {
            let want = model.step_in_contact(&mut single[l], &contact, raw[l]);
            assert_eq!(out[l], want, "{what}: gated step {t} lane {l}");
            onsets += (want.contact == ContactEdge::Began) as usize;
        }
        if t % 50 == 0 || t == STEPS - 1 {
            assert_same_state(&bs, &single, what);
        }
    }
    assert!(
        onsets > 2 * LANES,
        "{what}: the traces restart the lanes often ({onsets} onsets)"
    );
}

#[test]
fn batch_steps_equal_single_steps_every_variant() {
    let mut seed = 11;
    for variant in Variant::PER_CHANNEL {
        for diff in [false, true] {
            for hidden in [7, 32] {
                seed += 1;
                let blob = blob_of(variant, hidden, diff, seed);
                let blob = AlignedBlob::new(&blob);
                let model = Model::from_bytes(blob.as_bytes()).unwrap();
                let what = format!("{variant:?} d(t)={diff} H={hidden}");
                check_steps(&model, &what, &traces(seed));
            }
        }
    }
}

#[test]
fn batch_gated_steps_equal_single_gated_steps_every_variant() {
    let mut seed = 41;
    for variant in Variant::PER_CHANNEL {
        for diff in [false, true] {
            seed += 1;
            let blob = blob_of(variant, 9, diff, seed);
            let blob = AlignedBlob::new(&blob);
            let model = Model::from_bytes(blob.as_bytes()).unwrap();
            let what = format!("{variant:?} d(t)={diff} H=9");
            check_gated(&model, &what, &traces(seed));
        }
    }
}

/// The benchmark's shape: variant (c), hidden 128, with d(t) (all AVX2 tiles full).
#[test]
fn batch_equals_single_variant_c_hidden_128() {
    let blob = blob_of(Variant::DataStftLstm, 128, true, 5);
    let blob = AlignedBlob::new(&blob);
    let model = Model::from_bytes(blob.as_bytes()).unwrap();
    let x = traces(5);
    check_steps(&model, "ForceStft d(t) H=128", &x);
    check_gated(&model, "ForceStft d(t) H=128 gated", &x);
}

/// The batch state is the single state: lanes of a fresh batch and resets give what a fresh
/// ChannelState holds, and a RAM image is refused with an error, not run.
#[test]
fn batch_refuses_ram_images_and_starts_from_zero() {
    let blob = blob_of(Variant::Lstm, 8, true, 3);
    let aligned = AlignedBlob::new(&blob);
    let model = Model::from_bytes(aligned.as_bytes()).unwrap();
    let bm = BatchModel::new(&model).unwrap();
    let bs = bm.state(3);
    assert_eq!(bs.lanes(), 3);
    assert_eq!(bs.channel(2).unwrap().lstm, ChannelState::new().lstm);
    assert!(bs.channel(3).is_none());
    let mut ram = slipguard_core::model_ram::ModelRam::<{ 80 * 1024 }>::new();
    if let Ok(image) = ram.load(&blob) {
        let image = AlignedBlob::new(image);
        let m = Model::from_bytes(image.as_bytes()).unwrap();
        let err = BatchModel::new(&m).unwrap_err();
        assert!(err.to_string().contains("RAM image"), "{err}");
    }
}
