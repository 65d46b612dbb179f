//! Trainer, checkpoints, evaluation and the shipped models.
use slipguard_core::units::Millihertz;
use std::path::Path;

use slipguard_core::blob::{AlignedBlob, Variant};
use slipguard_core::float::FloatModel;
use slipguard_core::model::Model;
use slipguard_data::labels::{ChannelSequence, LabelConfig};
use slipguard_data::trial::{Outcome, Stability};
use slipguard_learn::checkpoint::{self, Checkpoint};
use slipguard_learn::evaluation::{
    Kind, Sequence, decide, force_config, metrics_of, probabilities, quantize_model, sequences_of,
    suction_config,
};
use slipguard_learn::train::{TrainConfig, init_model, train, train_labels};

/// A toy set: successes hold a level, failures collapse to 0 at the drop.
fn toy(n: usize, len: usize) -> Vec<ChannelSequence> {
    (0..n)
        .map(|i| {
            let fail = i % 2 == 1;
            let drop = len * 2 / 3;
            let samples: Vec<f32> = (0..len)
                .map(|t| {
                    let base = 4000.0 + 300.0 * (i as f32);
                    if fail && t >= drop {
                        0.0
                    } else if fail && t + 6 >= drop {
                        base + 900.0 * ((t % 2) as f32 - 0.5)
                    } else {
                        base
                    }
                })
                .collect();
            let labels = (0..len)
                .map(|t| {
                    if fail && t + 6 >= drop {
                        Stability::Unstable
                    } else {
                        Stability::Stable
                    }
                })
                .collect();
            ChannelSequence {
                trial_id: format!("toy{i}"),
                channel: 0,
                samples,
                labels,
                drop_index: fail.then_some(drop),
                outcome: if fail {
                    Outcome::Failure
                } else {
                    Outcome::Success
                },
            }
        })
        .collect()
}

#[test]
fn a_few_epochs_reduce_the_loss() {
    let data = toy(8, 40);
    let refs: Vec<&ChannelSequence> = data.iter().collect();
    let config = force_config(Variant::DataStftLstm, true, 8, "toy", Millihertz(16_700));
    let init = init_model(config, 3, &refs);
    let cfg = TrainConfig {
        epochs: 8,
        batch: 4,
        lr: 1e-2,
        patience: 100,
        ..TrainConfig::default()
    };
    let out = train(&init, &refs, &[], &cfg, |_| {}).unwrap();
    let first = out.history[0].train_loss;
    let last = out.history.last().unwrap().train_loss;
    assert!(last < 0.8 * first, "loss {first} -> {last}");
    // Same seed, same result.
    let again = train(&init, &refs, &[], &cfg, |_| {}).unwrap();
    assert_eq!(again.history.last().unwrap().train_loss, last);
}

#[test]
fn label_shift_moves_the_unstable_region() {
    let data = toy(2, 40);
    let l20 = train_labels(&data[1], 6);
    let l10 = train_labels(&data[1], 10);
    assert_eq!(l20.iter().sum::<u32>() + 4, l10.iter().sum::<u32>());
    assert_eq!(train_labels(&data[0], 10).iter().sum::<u32>(), 0);
}

#[test]
fn checkpoint_round_trip_every_variant() {
    for v in Variant::PER_CHANNEL {
        for cfg in [
            force_config(v, true, 12, "rt", Millihertz(16_700)),
            suction_config(v, false, 8, "s"),
        ] {
            let mut model = FloatModel::init_like_pytorch(cfg, 7);
            model.norm_mean.iter_mut().for_each(|m| *m = 0.125);
            model.config.threshold_q15 = 12_000;
            model.config.raise_after = 2;
            let mut extra = std::collections::BTreeMap::new();
            extra.insert("heldout_trials".to_string(), "a,b".to_string());
            let ck = Checkpoint { model, extra };
            let bytes = checkpoint::to_bytes(&ck).unwrap();
            let back = checkpoint::from_bytes(&bytes).unwrap();
            assert_eq!(back.model.lstms, ck.model.lstms, "{v:?}");
            assert_eq!(back.model.dense, ck.model.dense);
            assert_eq!(back.model.norm_mean, ck.model.norm_mean);
            assert_eq!(back.model.norm_std, ck.model.norm_std);
            let (mut a, mut b) = (back.model.config, ck.model.config);
            a.cell_frac_bits = [0, 0];
            b.cell_frac_bits = [0, 0];
            assert_eq!(a, b);
            assert_eq!(back.extra, ck.extra);
        }
    }
    // PyTorch names.
    let ck = Checkpoint {
        model: FloatModel::init_like_pytorch(
            force_config(Variant::LstmStftLstm, false, 4, "d", Millihertz(16_700)),
            1,
        ),
        extra: Default::default(),
    };
    let bytes = checkpoint::to_bytes(&ck).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut names: Vec<String> = st.names().into_iter().map(String::from).collect();
    names.sort();
    assert_eq!(
        names,
        [
            "dense.bias",
            "dense.weight",
            "lstm_bands.bias_hh_l0",
            "lstm_bands.bias_ih_l0",
            "lstm_bands.weight_hh_l0",
            "lstm_bands.weight_ih_l0",
            "lstm_force.bias_hh_l0",
            "lstm_force.bias_ih_l0",
            "lstm_force.weight_hh_l0",
            "lstm_force.weight_ih_l0",
        ]
    );
}

#[test]
fn metrics_of_a_hand_made_always_unstable_model() {
    // Zero weights, dense bias favouring "unstable": p = σ(2) ≈ 0.88 at every step.
    let mut m = FloatModel::init_like_pytorch(
        force_config(Variant::Lstm, false, 4, "hm", Millihertz(16_700)),
        1,
    );
    for l in &mut m.lstms {
        l.w_ih.iter_mut().for_each(|w| *w = 0.0);
        l.w_hh.iter_mut().for_each(|w| *w = 0.0);
        l.b_ih.iter_mut().for_each(|w| *w = 0.0);
        l.b_hh.iter_mut().for_each(|w| *w = 0.0);
    }
    m.dense.w.iter_mut().for_each(|w| *w = 0.0);
    m.dense.b = vec![-1.0, 1.0];
    let data: Vec<Sequence> = toy(4, 30)
        .into_iter()
        .map(|cs| Sequence {
            cs,
            lift: Some(5),
            rate_hz: 16.7,
        })
        .collect();
    let seqs: Vec<&Sequence> = data.iter().collect();
    let calib: Vec<&[f32]> = data.iter().map(|s| s.cs.samples.as_slice()).collect();
    let blob = quantize_model(&m, &calib).unwrap();
    for kind in [Kind::Float, Kind::Quantized] {
        let p = probabilities(&m, &blob, kind, &seqs).unwrap();
        let d = slipguard_core::decision::DecisionConfig::of(&m.config);
        let preds: Vec<_> = p.iter().map(|q| decide(d, q)).collect();
        let r = metrics_of(&seqs, &preds);
        // 2 failures × 16 unstable steps (14..30) of 4 × 30 steps are right.
        assert_eq!(r.success_rate, Some(32.0 / 120.0), "{kind:?}");
        assert_eq!(r.ahead_drop_rate, Some(1.0));
        assert_eq!(r.false_alarm_rate, Some(1.0));
        assert_eq!(r.failure_sequences, 2);
    }
}

/// Parses `<!-- check: key value ... -->` from a model card.
fn card_figures(card: &str) -> Vec<(String, f64)> {
    let line = card
        .lines()
        .find(|l| l.starts_with("<!-- check:"))
        .expect("card has a check line");
    let body = line
        .trim_start_matches("<!-- check:")
        .trim_end_matches("-->");
    let t: Vec<&str> = body.split_whitespace().collect();
    t.chunks(2)
        .map(|c| (c[0].to_string(), c[1].parse().unwrap()))
        .collect()
}

fn shipped(name: &str) -> (Vec<u8>, String) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../models")
        .join(name);
    (
        std::fs::read(dir.join(format!("{name}.bin"))).unwrap(),
        std::fs::read_to_string(dir.join("README.md")).unwrap(),
    )
}

#[test]
fn shipped_blobs_parse_and_match_their_cards() {
    for name in ["hand-force", "hand-force-40hz", "suction"] {
        let (blob, card) = shipped(name);
        let a = AlignedBlob::new(&blob);
        let m = Model::from_bytes(a.as_bytes()).expect("shipped blob parses");
        let c = m.config();
        let figs = card_figures(&card);
        let get = |k: &str| figs.iter().find(|f| f.0 == k).map(|f| f.1).unwrap();
        assert_eq!(get("blob_bytes") as usize, blob.len(), "{name}");
        assert_eq!(get("macs") as usize, c.macs_per_step(), "{name}");
        assert!(card.contains(c.variant.name()));
    }
    // The hand-force card's real-data figure, recomputed on the real trials it was measured on
    // (the 25 with the dataset's label.txt).
    let data = slipguard_data::eagle::default_data_dir();
    assert!(
        data.join("trials").is_dir(),
        "real data not found at {} (the repository ships it in data/eagle-shoal; \
         SLIPGUARD_DATA overrides)",
        data.display()
    );
    let (blob, card) = shipped("hand-force");
    let cfg = LabelConfig::default();
    let trials = slipguard_data::load_path(&data, &cfg, |_, _| {}).unwrap();
    let trials: Vec<_> = trials
        .into_iter()
        .filter(|t| !t.label_estimated())
        .collect();
    let a = AlignedBlob::new(&blob);
    let m = Model::from_bytes(a.as_bytes()).unwrap();
    // From each channel's contact onset, where the firmware's model state starts (as
    // `slipguard eval` computes the paper's metrics).
    let rule = slipguard_learn::product::OnsetRule::of(m.config());
    let seqs = slipguard_learn::product::cut_to_contact(sequences_of(&trials, &cfg), &rule);
    let refs: Vec<&Sequence> = seqs.iter().collect();
    let preds: Vec<_> = refs
        .iter()
        .map(|s| {
            decide(
                m.decision(),
                &slipguard_learn::evaluation::quant_p_q15(&m, &s.cs.samples),
            )
        })
        .collect();
    let r = metrics_of(&refs, &preds);
    let figs = card_figures(&card);
    let get = |k: &str| figs.iter().find(|f| f.0 == k).map(|f| f.1).unwrap();
    println!(
        "hand-force, all real trials from the contact onset: success {:.2} %, ahead-drop {:.2} %",
        100.0 * r.success_rate.unwrap(),
        100.0 * r.ahead_drop_rate.unwrap()
    );
    assert!((100.0 * r.success_rate.unwrap() - get("real_success")).abs() < 0.01);
    assert!((100.0 * r.ahead_drop_rate.unwrap() - get("real_ahead")).abs() < 0.01);
}
