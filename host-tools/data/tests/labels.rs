//! Labelling on hand-made trials.
use slipguard_data::labels::{
    LabelConfig, LabelStats, LabelStatus, annotate, channel_sequences, detect_drop, label_trial,
};
use slipguard_data::{Outcome, PhaseMarks, Stability, Trial, Unit};

/// 200 steps, 3 channels. c0 and c1 hold the object from step 10 to 59 (2000 and
/// 1000 mN) with a 2-step dip to 0 at 40-41, then read 0 from 60 on (the drop).
/// c2 is idle with a single 700 mN spike at 20 (not contact: < 3 steps).
/// After the drop and after l2 (80), from 85 to 100, c2 reads 8000 (fingers
/// pressing each other, as in the real failures).
fn failure_trial() -> Trial {
    let n = 200;
    let mut c0 = vec![0.0f32; n];
    let mut c1 = vec![0.0f32; n];
    let mut c2 = vec![0.0f32; n];
    for t in 10..60 {
        c0[t] = 2000.0;
        c1[t] = 1000.0;
    }
    c0[40] = 0.0;
    c0[41] = 0.0;
    c1[40] = 0.0;
    c1[41] = 0.0;
    c2[20] = 700.0;
    for v in &mut c2[85..100] {
        *v = 8000.0;
    }
    let mut t = Trial::new("hand-failure", Unit::MilliNewton, 16.7, vec![c0, c1, c2]);
    t.marks = PhaseMarks {
        grasp_start: Some(5),
        lift_start: Some(30),
        open_start: Some(80),
        release: None,
    };
    t.outcome = Outcome::Failure;
    t
}

#[test]
fn drop_skips_brief_dip_and_labels_20_before() {
    let cfg = LabelConfig::default();
    let t = failure_trial();
    let d = detect_drop(&t, &cfg);
    assert_eq!(d.channels, vec![0, 1]);
    assert_eq!(d.peak, 3000.0);
    assert_eq!(d.first_dip, Some(40));
    assert_eq!(d.step, Some(60));
    let l = label_trial(&t, &cfg);
    assert_eq!(l.status, LabelStatus::Labelled);
    assert_eq!(l.drop_step, Some(60));
    assert_eq!(l.unstable_from, Some(40));
    // Sequence 5..165 (160 steps): stable 5..40 = 35 steps, unstable 40..165 = 125.
    assert_eq!((l.seq_start, l.seq_len), (5, 160));
    assert_eq!((l.n_stable(), l.n_unstable()), (35, 125));
    assert_eq!(l.steps[34], Stability::Stable);
    assert_eq!(l.steps[35], Stability::Unstable);
    assert_eq!(l.drop_index(), Some(55));
    // The idle channel (and the post-drop squeeze on it) is marked, not labelled.
    assert_eq!(l.contact, vec![true, true, false]);
    assert!(l.channel(2).is_none());
    assert_eq!(l.channel(0).unwrap().len(), 160);
    let seqs = channel_sequences(
        &{
            let mut a = t.clone();
            annotate(&mut a, &cfg);
            a
        },
        &l,
    );
    assert_eq!(seqs.len(), 2);
    assert_eq!(seqs[0].samples[5], 2000.0); // step 10
}

#[test]
fn thresholds_are_configurable() {
    let t = failure_trial();
    // A 1-step hold accepts the brief dip as the drop.
    let cfg = LabelConfig {
        drop_hold_steps: 1,
        unstable_lead_steps: 5,
        ..LabelConfig::default()
    };
    let l = label_trial(&t, &cfg);
    assert_eq!(l.drop_step, Some(40));
    assert_eq!(l.unstable_from, Some(35));
    // A contact threshold above 2000 mN leaves no contact channel: nothing held, no drop.
    let cfg = LabelConfig {
        contact_threshold_mn: 2500.0,
        ..LabelConfig::default()
    };
    let l = label_trial(&t, &cfg);
    assert_eq!(l.drop_step, None);
    assert_eq!(l.status, LabelStatus::NoDrop);
    // The lead cannot reach before the sequence start.
    let cfg = LabelConfig {
        unstable_lead_steps: 100,
        ..LabelConfig::default()
    };
    let l = label_trial(&t, &cfg);
    assert_eq!(l.unstable_from, Some(5));
    assert_eq!(l.n_stable(), 0);
}

#[test]
fn success_is_stable_and_short_trials_clip() {
    let mut t = failure_trial();
    t.outcome = Outcome::Success;
    let l = label_trial(&t, &LabelConfig::default());
    assert_eq!(l.drop_step, None, "no drop search for successes");
    assert_eq!(l.n_unstable(), 0);
    assert_eq!(l.n_stable(), 160);
    // Success contact window is the sequence: c2's later squeeze counts as contact here.
    assert_eq!(l.contact, vec![true, true, true]);
    // A trial shorter than grasp start + 160 gives a shorter sequence.
    let mut short = t.clone();
    for c in &mut short.samples {
        c.truncate(100);
    }
    let l = label_trial(&short, &LabelConfig::default());
    assert_eq!(l.seq_len, 95);
}

#[test]
fn unknown_outcome_and_stats() {
    let cfg = LabelConfig::default();
    let mut u = failure_trial();
    u.outcome = Outcome::Unknown;
    let lu = label_trial(&u, &cfg);
    assert_eq!(lu.status, LabelStatus::UnknownOutcome);
    assert_eq!(lu.drop_step, Some(60), "drop is still detected");
    let lf = label_trial(&failure_trial(), &cfg);
    let mut s = failure_trial();
    s.outcome = Outcome::Success;
    let ls = label_trial(&s, &cfg);
    let st = LabelStats::from_labels(&[lf, ls, lu]);
    assert_eq!((st.trials, st.labelled, st.skipped), (3, 2, 1));
    // Trial level: failure 35 stable + 125 unstable, success 160 stable.
    assert_eq!((st.stable_steps, st.unstable_steps), (195, 125));
    // Channels: failure 2 contact (1 excluded), success 3 contact.
    assert_eq!((st.channel_sequences, st.excluded_channels), (5, 1));
    assert_eq!(st.channel_unstable_steps, 250);
    assert_eq!(st.channel_stable_steps, 2 * 35 + 3 * 160);
}

#[test]
fn pressure_units_use_deviation_from_baseline() {
    // Baseline 6400 counts; vacuum raises c0 to 30000 from 10 to 50, then it vents.
    let n = 120;
    let mut c0 = vec![6400.0f32; n];
    for v in &mut c0[10..50] {
        *v = 30000.0;
    }
    let c1 = vec![6300.0f32; n];
    let mut t = Trial::new("hand-suction", Unit::Counts, 71.0, vec![c0, c1]);
    t.marks = PhaseMarks {
        grasp_start: Some(8),
        lift_start: Some(20),
        open_start: Some(100),
        release: None,
    };
    t.outcome = Outcome::Failure;
    let l = label_trial(&t, &LabelConfig::default());
    assert_eq!(l.drop_step, Some(50));
    assert_eq!(l.contact, vec![true, false]);
}
