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

/// The shipped blob with another hand rule: the same tensors written as format v2 with `rule`,
/// or as format v1 without one.
fn with_rule(bytes: &[u8], rule: Option<slipguard_core::decision::FusedHand>) -> Vec<u8> {
    use slipguard_core::blob::{BlobTensors, write_blob};
    let aligned = AlignedBlob::new(bytes);
    let b = aligned.parse().unwrap();
    let tensors = BlobTensors {
        norm: b.norm.to_vec(),
        lstm: b
            .lstms()
            .iter()
            .map(|l| (l.weights.to_vec(), l.rows.to_vec()))
            .collect(),
        dense: (b.dense.weights.to_vec(), b.dense.rows.to_vec()),
    };
    let mut config = b.config;
    config.hand_rule = rule;
    write_blob(&config, &tensors)
}

/// A v2 blob's runs carry the firmware's fused hand flag: the model's own flag is the v1
/// blob's hand flag, and the fused flag follows the rule computed by hand in f64 from the
/// trial's samples (steps within 0.1 % of a fraction's edge, where Q1.15 rounding decides,
/// are left out); the batched and the single path agree, and the curve sweep recomputes it.
#[test]
fn a_v2_blobs_runs_fuse_the_hand_flag_with_its_rule() {
    use slipguard_core::decision::{FusedHand, LoadRule};
    let (bytes, trials) = setup();
    let rule = FusedHand {
        strict: LoadRule {
            fraction_q15: 13_107, // 0.4
            window: 10,
        },
        guard_q15: 26_214, // 0.8
    };
    // The shipped blob carries a rule (format v2); v1 is its model without one.
    let v2 = AlignedBlob::new(&with_rule(&bytes, Some(rule)));
    let v1 = AlignedBlob::new(&with_rule(&bytes, None));
    let (m1, m2) = (
        Model::from_bytes(v1.as_bytes()).unwrap(),
        Model::from_bytes(v2.as_bytes()).unwrap(),
    );
    assert_eq!(m2.config().hand_rule, Some(rule));
    assert_eq!(m1.config().hand_rule, None);
    let contact = ContactConfig::of(m1.config());
    let hand = HandConfig::of(m1.config());
    let full_scale = m1.config().input_full_scale as f64;
    let (mut changed, mut edge, mut steps) = (0, 0, 0);
    for t in &trials {
        let r1 = run_trial(&m1, t, &contact, &hand);
        let r2 = run_trial(&m2, t, &contact, &hand);
        assert_eq!(r2, run_trial_single(&m2, t, &contact, &hand), "{}", t.id);
        assert_eq!(r1.rule, None);
        assert_eq!(
            r1.hand_flag, r1.model_flag,
            "{}: v1 is the model's flag",
            t.id
        );
        assert_eq!(r2.model_flag, r1.hand_flag, "{}", t.id);
        assert_eq!(r2.hand_flag_with(&hand), r2.hand_flag, "{}", t.id);
        // The reference: loads in f64 from the samples of the channels in contact.
        let load: Vec<f64> = (0..t.n_steps())
            .map(|s| {
                (0..t.n_channels())
                    .filter(|&c| r1.channel_p[c][s].is_some())
                    .map(|c| (t.samples[c][s].round() as f64 / full_scale).abs())
                    .sum()
            })
            .collect();
        for s in r2.start..t.n_steps() {
            let lo = s.saturating_sub(9).max(r2.start);
            let peak = load[lo..=s].iter().copied().fold(0.0, f64::max);
            let near = |f: f64| (load[s] - f * peak).abs() <= 1e-3 * peak;
            if peak > 0.0 && (near(0.4) || near(0.8)) {
                edge += 1;
                continue;
            }
            let below = |f: f64| peak > 0.0 && load[s] < f * peak;
            let want = below(0.4) || (r2.model_flag[s] && below(0.8));
            assert_eq!(r2.hand_flag[s], want, "{} step {s}", t.id);
            steps += 1;
            changed += (r2.hand_flag[s] != r2.model_flag[s]) as usize;
        }
    }
    println!("{steps} steps checked, {edge} at an edge, {changed} where the rule changed the flag");
    assert!(changed >= 10, "the rule changed only {changed} steps");
    assert!(edge * 100 <= steps, "{edge} edge steps of {steps}");
}
