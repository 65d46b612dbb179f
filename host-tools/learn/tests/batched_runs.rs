//! The evaluation's batched, parallel runs: the same numbers as the one-channel-at-a-time
//! path, and the same output on 1 and 2 threads (the shipped hand-force model on the real
//! trials).
use std::path::Path;

use slipguard_core::blob::AlignedBlob;
use slipguard_core::decision::{ContactConfig, HandConfig};
use slipguard_core::model::Model;
use slipguard_data::labels::LabelConfig;
use slipguard_data::trial::Trial;
use slipguard_learn::evaluation::{quant_p_q15, quant_p_q15_many};
use slipguard_learn::product::{WindowedRun, run_trial, run_trial_single, windowed_runs};

fn setup() -> (Vec<u8>, Vec<Trial>) {
    let blob = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/hand-force/hand-force.bin"),
    )
    .unwrap();
    let trials = slipguard_data::load_path(
        &slipguard_data::eagle::default_data_dir(),
        &LabelConfig::default(),
        |_, _| {},
    )
    .unwrap();
    (blob, trials)
}

fn on_threads<R: Send>(n: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn batched_trial_runs_equal_single_runs_and_any_thread_count() {
    let (bytes, trials) = setup();
    let blob = AlignedBlob::new(&bytes);
    let model = Model::from_bytes(blob.as_bytes()).unwrap();
    let contact = ContactConfig::of(model.config());
    let hand = HandConfig::of(model.config());
    for t in &trials {
        assert_eq!(
            run_trial(&model, t, &contact, &hand),
            run_trial_single(&model, t, &contact, &hand),
            "{}",
            t.id
        );
    }
    let refs: Vec<&Trial> = trials.iter().collect();
    let cfg = LabelConfig::default();
    let key = |w: &[WindowedRun]| -> Vec<(String, (usize, usize), Vec<i16>)> {
        w.iter()
            .map(|w| (w.trial.clone(), w.window, w.run.hand_p.clone()))
            .collect()
    };
    let one = on_threads(1, || windowed_runs(&model, &refs, &cfg).unwrap());
    let two = on_threads(2, || windowed_runs(&model, &refs, &cfg).unwrap());
    assert!(one.len() >= 20, "{} runs", one.len());
    assert_eq!(key(&one), key(&two));
    for (a, b) in one.iter().zip(&two) {
        assert_eq!(a.run, b.run, "{}", a.trial);
    }
}

#[test]
fn batched_sequences_equal_single_sequences_and_any_thread_count() {
    let (bytes, trials) = setup();
    let blob = AlignedBlob::new(&bytes);
    let model = Model::from_bytes(blob.as_bytes()).unwrap();
    // Every channel of every trial, whole: ragged lengths, more than one batch of 256.
    let seqs: Vec<&[f32]> = trials
        .iter()
        .flat_map(|t| t.samples.iter().map(Vec::as_slice))
        .collect();
    assert!(seqs.len() > 256, "{} sequences", seqs.len());
    let single: Vec<Vec<i16>> = seqs.iter().map(|s| quant_p_q15(&model, s)).collect();
    let one = on_threads(1, || quant_p_q15_many(&model, &seqs));
    let two = on_threads(2, || quant_p_q15_many(&model, &seqs));
    assert_eq!(one, single);
    assert_eq!(two, single);
}
