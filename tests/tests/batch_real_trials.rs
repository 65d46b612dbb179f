//! The batched path (`slipguard_batch`) on the real trials, bit for bit against the
//! single-channel path `Model::step` / `Model::step_in_contact` (the firmware's path, tested
//! against independent references in the core's own tests: f64 DFT, microfft, the f32 model,
//! PyTorch fixtures). Every channel of every eagle-shoal trial is one lane; the trials'
//! different lengths make the batch ragged (lanes stop at their trial's end).
//!
//! Models: the shipped hand-force blobs (16.7 Hz and 40 Hz, variant (c) with d(t)) and random
//! models of every variant, with and without d(t), quantized by the core's quantizer with
//! their normalisation fitted on the trials. The core's `tests/batch_vs_single.rs` adds random
//! traces, resets and masks.
use std::path::Path;

use slipguard_batch::BatchModel;
use slipguard_core::blob::{AlignedBlob, ModelConfig, Variant};
use slipguard_core::decision::{ContactConfig, ContactEdge};
use slipguard_core::float::FloatModel;
use slipguard_core::model::{ChannelState, GatedOutput, Model, StepOutput};
use slipguard_core::quantize::quantize;
use slipguard_data::eagle::default_data_dir;
use slipguard_data::labels::LabelConfig;
use slipguard_data::trial::Trial;

fn trials() -> Vec<Trial> {
    let t = slipguard_data::load_path(&default_data_dir(), &LabelConfig::default(), |_, _| {})
        .expect("the eagle-shoal trials");
    assert!(t.len() >= 20, "{} trials", t.len());
    t
}

/// Every channel of every trial as one lane of one batch, against `Model::step` per channel.
fn check_plain(model: &Model<'_>, trials: &[Trial], what: &str) {
    let lanes: Vec<Vec<i32>> = trials
        .iter()
        .flat_map(|t| t.samples.iter())
        .map(|s| s.iter().map(|x| x.round() as i32).collect())
        .collect();
    let batch = BatchModel::new(model).unwrap();
    let mut st = batch.state(lanes.len());
    let mut single = vec![ChannelState::new(); lanes.len()];
    let steps = lanes.iter().map(Vec::len).max().unwrap();
    let zero = StepOutput {
        p_unstable_q15: 0,
        unstable: false,
    };
    let mut out = vec![zero; lanes.len()];
    let mut compared = 0usize;
    for t in 0..steps {
        let active: Vec<bool> = lanes.iter().map(|s| t < s.len()).collect();
        let raw: Vec<i32> = lanes
            .iter()
            .map(|s| s.get(t).copied().unwrap_or(0))
            .collect();
        batch.step_masked(&mut st, &raw, &active, &mut out);
        for l in (0..lanes.len()).filter(|&l| active[l]) {
            let want = model.step(&mut single[l], raw[l]);
            assert_eq!(out[l], want, "{what}: lane {l} step {t}");
            compared += 1;
        }
    }
    for (l, s) in single.iter().enumerate() {
        assert_eq!(
            st.channel(l).unwrap().lstm,
            s.lstm,
            "{what}: lane {l} final state"
        );
    }
    assert!(compared > 50_000, "{what}: {compared} steps");
}

/// Each trial's channels as one batch through contact gating, against
/// `Model::step_in_contact` per channel.
fn check_gated(model: &Model<'_>, trials: &[Trial], what: &str) {
    let batch = BatchModel::new(model).unwrap();
    let contact = ContactConfig::of(model.config());
    let mut onsets = 0;
    for trial in trials {
        let nc = trial.n_channels();
        let mut st = batch.state(nc);
        let mut single = vec![ChannelState::new(); nc];
        let idle = GatedOutput {
            contact: ContactEdge::Idle,
            step: None,
        };
        let mut out = vec![idle; nc];
        for t in 0..trial.n_steps() {
            let raw: Vec<i32> = (0..nc)
                .map(|c| trial.samples[c][t].round() as i32)
                .collect();
            batch.step_in_contact(&mut st, &contact, &raw, None, &mut out);
            for c in 0..nc {
                let want = model.step_in_contact(&mut single[c], &contact, raw[c]);
                assert_eq!(out[c], want, "{what}: {} channel {c} step {t}", trial.id);
                onsets += usize::from(want.contact == ContactEdge::Began);
            }
        }
    }
    assert!(onsets >= trials.len(), "{what}: {onsets} contact onsets");
}

#[test]
fn shipped_models_batched_equal_single_on_the_real_trials() {
    let trials = trials();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    for name in [
        "hand-force/hand-force.bin",
        "hand-force-40hz/hand-force-40hz.bin",
    ] {
        let bytes = std::fs::read(root.join(name)).unwrap();
        let blob = AlignedBlob::new(&bytes);
        let model = Model::from_bytes(blob.as_bytes()).unwrap();
        check_plain(&model, &trials, name);
        check_gated(&model, &trials, name);
    }
}

/// A force model's header at the trials' rate (16.7 Hz, 0…32 768 mN): the trainer's.
fn config(variant: Variant, diff: bool, hidden: u16) -> ModelConfig {
    slipguard_learn::evaluation::force_config(
        variant,
        diff,
        hidden,
        "batch",
        slipguard_core::sample::PAPER_RATE_MHZ,
    )
}

#[test]
fn random_models_batched_equal_single_on_the_real_trials() {
    let trials = trials();
    let calib: Vec<&[f32]> = trials
        .iter()
        .flat_map(|t| t.samples.iter().map(Vec::as_slice))
        .collect();
    let mut seed = 0;
    for variant in Variant::PER_CHANNEL {
        for diff in [false, true] {
            seed += 1;
            let mut float = FloatModel::init_like_pytorch(config(variant, diff, 20), seed);
            float.fit_normalisation(&calib);
            let (bytes, _) = quantize(&float, &calib[..40], None).unwrap();
            let blob = AlignedBlob::new(&bytes);
            let model = Model::from_bytes(blob.as_bytes()).unwrap();
            let what = format!("random {variant:?} d(t)={diff}");
            check_plain(&model, &trials, &what);
            check_gated(&model, &trials, &what);
        }
    }
}
