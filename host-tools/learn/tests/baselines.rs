//! Table I baselines: classifiers on hand-made data whose answers are known, folds, the
//! feature builders and the metrics plumbing (the CLI on three real trials: the `slipguard`
//! crate's `baselines_cli` test).
use ndarray::{Array2, array};
use slipguard_core::float::raw_feature_sequence;
use slipguard_data::Stability::{Stable as S, Unstable as U};
use slipguard_data::labels::{LabelConfig, label_trial};
use slipguard_data::metrics::{EventConfig, evaluate};
use slipguard_data::{Outcome, PhaseMarks, Stability, Trial, Unit};
use slipguard_learn::baselines::{
    Classifier, FeatureSequence, FeatureSet, FoldPlan, PAPER_TABLE_I, Standardizer, SvmSettings,
    build_sequences, cross_validate, evenly_spaced, feature_config, fit, make_folds,
    multichannel_sequence, single_channel_sequences, trial_outcomes,
};

fn col(v: &[f64]) -> Array2<f64> {
    Array2::from_shape_vec((v.len(), 1), v.to_vec()).unwrap()
}

fn svm() -> Classifier {
    Classifier::Svm(SvmSettings::default())
}

#[test]
fn knn_votes_among_three_neighbours() {
    // Training points on a line. Around 0: 0 is unstable but 1 and 2 are stable, so k = 3
    // outvotes the nearest neighbour; k = 1 follows it.
    let x = col(&[0.0, 1.0, 2.0, 10.0, 11.0, 12.0]);
    let y = [true, false, false, true, true, true];
    let q = col(&[0.0, 1.4, 11.2, 30.0]);
    let k3 = fit(&Classifier::Knn { k: 3 }, x.clone(), &y).unwrap();
    assert_eq!(k3.predict(&q).unwrap(), [false, false, true, true]);
    let k1 = fit(&Classifier::Knn { k: 1 }, x, &y).unwrap();
    assert_eq!(k1.predict(&q).unwrap(), [true, false, true, true]);
}

#[test]
fn naive_bayes_uses_class_variances() {
    // Both classes are centred on 0; stable is narrow (σ ≈ 0.08), unstable wide (σ ≈ 8.2).
    // A nearest-mean rule cannot tell them apart; the Gaussian likelihoods can:
    // x = 0 → stable, |x| = 5 or 12 → unstable.
    let x = col(&[-0.1, 0.0, 0.1, -10.0, 0.0, 10.0]);
    let y = [false, false, false, true, true, true];
    let m = fit(&Classifier::NaiveBayes, x, &y).unwrap();
    assert_eq!(
        m.predict(&col(&[0.0, 5.0, -5.0, 12.0])).unwrap(),
        [false, true, true, true]
    );
}

#[test]
fn svm_separates_a_ring_with_the_rbf_kernel() {
    // Stable: a small cluster at the origin; unstable: a ring of radius 3 around it. No line
    // separates them; the RBF SVM does.
    let mut rows = vec![[0.0, 0.0], [0.3, 0.0], [-0.3, 0.0], [0.0, 0.3], [0.0, -0.3]];
    let mut y = vec![false; rows.len()];
    for i in 0..12 {
        let a = i as f64 * std::f64::consts::TAU / 12.0;
        rows.push([3.0 * a.cos(), 3.0 * a.sin()]);
        y.push(true);
    }
    let x = Array2::from_shape_vec((rows.len(), 2), rows.concat()).unwrap();
    let m = fit(&svm(), x.clone(), &y).unwrap();
    assert_eq!(m.predict(&x).unwrap(), y, "training points");
    let q = array![[0.1, 0.1], [-3.2, 0.0], [0.0, 2.9], [2.0, 2.0]];
    assert_eq!(m.predict(&q).unwrap(), [false, true, true, true]);
}

#[test]
fn one_class_training_sets_and_all_stable_are_constant() {
    let x = col(&[1.0, 2.0, 3.0]);
    for c in [Classifier::NaiveBayes, Classifier::Knn { k: 3 }, svm()] {
        let m = fit(&c, x.clone(), &[true, true, true]).unwrap();
        assert_eq!(
            m.predict(&col(&[-5.0, 9.0])).unwrap(),
            [true, true],
            "{c:?}"
        );
    }
    let m = fit(&Classifier::AllStable, x, &[true, false, true]).unwrap();
    assert_eq!(m.predict(&col(&[2.0])).unwrap(), [false]);
}

#[test]
fn standardizer_and_svm_subsampling() {
    // Column 0: 1, 2, 3 → mean 2, σ = sqrt(2/3); column 1 constant → σ taken as 1.
    let x = array![[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]];
    let s = Standardizer::fit(x.view());
    assert_eq!(s.mean, array![2.0, 5.0]);
    assert!((s.std[0] - (2.0f64 / 3.0).sqrt()).abs() < 1e-12);
    assert_eq!(s.std[1], 1.0);
    let z = s.apply(x.view());
    assert!((z[[2, 0]] - 1.0 / (2.0f64 / 3.0).sqrt()).abs() < 1e-12);
    assert_eq!(z.column(1).to_vec(), [0.0; 3]);

    // 10 rows cut to 4: indices ⌊i·10/4⌋ = 0, 2, 5, 7.
    let x = col(&(0..10).map(f64::from).collect::<Vec<_>>());
    let y: Vec<bool> = (0..10).map(|i| i >= 5).collect();
    let (xs, ys) = evenly_spaced(x.clone(), &y, 4);
    assert_eq!(xs.column(0).to_vec(), [0.0, 2.0, 5.0, 7.0]);
    assert_eq!(ys, [false, false, true, true]);
    assert_eq!(evenly_spaced(x, &y, 0).0.nrows(), 10);
}

#[test]
fn folds_are_by_trial_and_stratified() {
    let t = |id: &str, f: bool| (id.to_string(), f);
    let trials = [
        t("s3", false),
        t("f1", true),
        t("s1", false),
        t("f2", true),
        t("s2", false),
        t("s1", false),
    ];
    // Failures first (f1, f2), then successes (s1, s2, s3), dealt round-robin over 2 folds.
    assert_eq!(
        make_folds(&trials, FoldPlan::KFold(2)),
        [vec!["f1", "s1", "s3"], vec!["f2", "s2"]]
    );
    assert_eq!(
        make_folds(&trials, FoldPlan::LeaveOneTrialOut),
        [["f1"], ["f2"], ["s1"], ["s2"], ["s3"]]
    );
    // More folds than trials: one trial each.
    assert_eq!(make_folds(&trials, FoldPlan::KFold(9)).len(), 5);
}

/// A sequence of `n` steps whose one feature is 0 on stable and 1 on unstable steps.
fn seq(id: &str, labels: &[Stability], drop: Option<usize>) -> FeatureSequence {
    FeatureSequence {
        trial_id: id.into(),
        channel: None,
        features: labels
            .iter()
            .map(|l| vec![if l.is_unstable() { 1.0 } else { 0.0 }])
            .collect(),
        labels: labels.to_vec(),
        drop_index: drop,
        failure: drop.is_some(),
        rate_hz: 10.0,
    }
}

#[test]
fn cross_validation_feeds_the_shared_metrics() {
    // Two failures (unstable from 6, drop at 8) and two successes, 10 steps each at 10 Hz.
    let fail = [S, S, S, S, S, S, U, U, U, U];
    let seqs = vec![
        seq("a", &fail, Some(8)),
        seq("b", &fail, Some(8)),
        seq("c", &[S; 10], None),
        seq("d", &[S; 10], None),
    ];
    let folds = make_folds(&trial_outcomes(&seqs), FoldPlan::KFold(2));
    assert_eq!(folds, [vec!["a", "c"], vec!["b", "d"]]);
    let ev = EventConfig::default();

    // The feature is the label, so KNN is exact: success 100 %, both failures ahead by
    // (8 − 6) × 100 ms = 200 ms, no false alarm, both drops hit, no false event.
    let r = cross_validate(
        &seqs,
        FeatureSet::MultiChannel,
        &Classifier::Knn { k: 3 },
        &folds,
        ev,
        |_, _| {},
    )
    .unwrap();
    let m = &r.metrics;
    assert_eq!(m.evaluated_steps, 40);
    assert_eq!(m.success_rate, Some(1.0));
    assert_eq!((m.ahead_drop_rate, m.failure_sequences), (Some(1.0), 2));
    assert_eq!((m.false_alarm_rate, m.success_sequences), (Some(0.0), 2));
    assert_eq!(m.lead_times_ms, [200.0, 200.0]);
    assert_eq!((m.event_tp, m.event_fp, m.event_recall), (2, 0, Some(1.0)));
    assert_eq!((m.confusion.tp, m.confusion.tn), (8, 32));
    // The predictions equal the labels and the metrics are exactly `evaluate`'s.
    let expected: Vec<_> = seqs.iter().map(|s| s.eval(&s.labels)).collect();
    assert_eq!(r.sequences, expected);
    assert_eq!(*m, evaluate(&expected, ev));
    assert_eq!(
        r.sequence_ids,
        [("a", None), ("b", None), ("c", None), ("d", None)].map(|(a, b)| (a.to_string(), b))
    );
    // Each fold trains on the other fold's 20 steps and predicts its own 20.
    assert!(
        r.folds
            .iter()
            .all(|f| f.train_steps == 20 && f.test_steps == 20)
    );

    // All stable: success = 32/40 stable steps, no failure ahead, no alarm.
    let r = cross_validate(
        &seqs,
        FeatureSet::MultiChannel,
        &Classifier::AllStable,
        &folds,
        ev,
        |_, _| {},
    )
    .unwrap();
    assert_eq!(r.metrics.success_rate, Some(0.8));
    assert_eq!(r.metrics.ahead_drop_rate, Some(0.0));
    assert_eq!(r.metrics.false_alarm_rate, Some(0.0));
    assert_eq!(r.metrics.event_recall, Some(0.0));

    // NB and SVM separate 0 from 1 as well.
    for c in [Classifier::NaiveBayes, svm()] {
        let r = cross_validate(&seqs, FeatureSet::MultiChannel, &c, &folds, ev, |_, _| {}).unwrap();
        assert_eq!(r.metrics.success_rate, Some(1.0), "{c:?}");
    }

    // A fold holding out every trial leaves nothing to train on.
    let all = vec![
        vec!["a", "b", "c", "d"]
            .into_iter()
            .map(String::from)
            .collect(),
    ];
    assert!(cross_validate(&seqs, FeatureSet::MultiChannel, &svm(), &all, ev, |_, _| {}).is_err());
}

/// A 3-channel failure trial: grasp at 5, lift at 10, channels 0 and 1 hold ~5 N until the
/// drop at 25, channel 2 never touches.
fn toy_trial() -> Trial {
    let n = 40;
    let c = |amp: f32| -> Vec<f32> {
        (0..n)
            .map(|t| {
                if (7..25).contains(&t) {
                    amp + 100.0 * (t as f32).sin()
                } else {
                    0.0
                }
            })
            .collect()
    };
    let mut t = Trial::new(
        "toy",
        Unit::MilliNewton,
        16.7,
        vec![c(5000.0), c(4000.0), c(0.0)],
    );
    t.marks = PhaseMarks {
        grasp_start: Some(5),
        lift_start: Some(10),
        open_start: Some(35),
        release: None,
    };
    t.outcome = Outcome::Failure;
    t
}

#[test]
fn features_are_the_channel_rows_or_the_core_float_path() {
    let cfg = LabelConfig {
        sequence_len: 30,
        ..LabelConfig::default()
    };
    let trial = toy_trial();
    let labels = label_trial(&trial, &cfg);
    assert_eq!(labels.drop_step, Some(25));
    assert_eq!(labels.contact, [true, true, false]);

    let m = multichannel_sequence(&trial, &labels).unwrap();
    assert_eq!((m.features.len(), m.width()), (30, 3));
    assert_eq!(
        m.features[3],
        trial
            .row(8)
            .iter()
            .map(|&v| f64::from(v))
            .collect::<Vec<_>>()
    );
    assert_eq!(m.labels, labels.steps);
    assert_eq!((m.drop_index, m.failure), (Some(20), true));

    // Single channel: contact channels only, [force, d(t), 10 bands] from the core.
    let fc = feature_config(40_000, 16.7);
    assert_eq!(fc.feature_count(), 12);
    let s = single_channel_sequences(&trial, &labels, &fc);
    assert_eq!(
        s.iter().map(|s| s.channel).collect::<Vec<_>>(),
        [Some(0), Some(1)]
    );
    let core = raw_feature_sequence(&fc, &trial.samples[1][5..35]);
    assert_eq!(s[1].features.len(), 30);
    for (a, b) in s[1].features.iter().zip(&core) {
        assert_eq!(a, &b.iter().map(|&v| f64::from(v)).collect::<Vec<_>>());
    }
    // Force scaled by the full scale: 4000 + 100 sin(8) mN at step 8 (index 3).
    assert!(
        (s[1].features[3][0] - f64::from((4000.0 + 100.0 * 8f32.sin()) / 40_000.0)).abs() < 1e-6
    );

    // An unlabelled trial (failure without a drop) gives no sequences.
    let mut nodrop = toy_trial();
    nodrop.samples = vec![vec![0.0; 40]; 3];
    let l = label_trial(&nodrop, &cfg);
    assert!(multichannel_sequence(&nodrop, &l).is_none());
    assert!(build_sequences(&[nodrop], &[l], FeatureSet::SingleChannel, 40_000).is_empty());
}

#[test]
fn paper_table_i_figures() {
    let f: Vec<_> = PAPER_TABLE_I
        .iter()
        .map(|r| (r.model, r.success_rate_pct, r.ahead_drop_pct))
        .collect();
    assert_eq!(
        f,
        [
            ("NB", 68.81, 65.69),
            ("KNN (k=3)", 79.70, 81.76),
            ("SVM", 84.67, 66.67),
            ("LSTM", 84.60, 85.88)
        ]
    );
    assert_eq!(
        Classifier::Knn { k: 3 }.paper_row().map(|r| r.model),
        Some("KNN (k=3)")
    );
    assert_eq!(Classifier::Knn { k: 5 }.paper_row(), None);
}
