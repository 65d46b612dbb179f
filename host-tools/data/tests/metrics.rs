//! Metrics on hand-made predictions; every expected number is worked out in the comments.
use slipguard_data::Stability::{Stable as S, Unstable as U};
use slipguard_data::metrics::{EvalSequence, EventConfig, Spread, evaluate};

/// 10 Hz so that one step is exactly 100 ms.
const RATE: f64 = 10.0;

fn seqs() -> Vec<EvalSequence> {
    // A: failure, drop at index 8, labels unstable from 3 (8 - 5 lead, hand-set).
    //   label: S S S U U U U U U U
    //   pred : S S U U S S U U U U
    //   steps: tn tn fp tp fn fn tp tp tp tp -> tp 5, fp 1, tn 2, fn 2
    //   first alarm 2 < 8 -> ahead, lead (8-2)*100 = 600 ms
    //   rising edges at 2 and 6: both within [8-40, 8+5] -> one TP, the second ignored
    let a = EvalSequence::new(
        &[S, S, S, U, U, U, U, U, U, U],
        &[S, S, U, U, S, S, U, U, U, U],
        Some(8),
        true,
        RATE,
    );
    // B: failure, drop at 5, labels all unstable.
    //   pred: S S S S S S U U S S -> tp 2 (6, 7), fn 8
    //   first alarm 6 >= 5 -> not ahead; edge at 6 <= 5+5 -> TP
    let b = EvalSequence::new(
        &[U; 10],
        &[S, S, S, S, S, S, U, U, S, S],
        Some(5),
        true,
        RATE,
    );
    // C: success, one unstable prediction at 4 -> fp 1, tn 9; false alarm; edge 4 -> FP
    let c = EvalSequence::new(&[S; 10], &[S, S, S, S, U, S, S, S, S, S], None, false, RATE);
    // D: success, all stable, step 0 not evaluated -> tn 9
    let mut d = EvalSequence::new(&[S; 10], &[S; 10], None, false, RATE);
    d.labels[0] = None;
    vec![a, b, c, d]
}

#[test]
fn metrics_by_hand() {
    let m = evaluate(&seqs(), EventConfig::default());
    // Confusion: tp 5+2 = 7, fp 1+1 = 2, tn 2+9+9 = 20, fn 2+8 = 10; 39 steps.
    assert_eq!(m.confusion.tp, 7);
    assert_eq!(m.confusion.fp, 2);
    assert_eq!(m.confusion.tn, 20);
    assert_eq!(m.confusion.fn_, 10);
    assert_eq!(m.evaluated_steps, 39);
    // Success rate (7 + 20) / 39.
    assert!((m.success_rate.unwrap() - 27.0 / 39.0).abs() < 1e-12);
    // Ahead-drop: A yes, B no -> 1/2.
    assert_eq!(m.failure_sequences, 2);
    assert_eq!(m.ahead_drop_rate, Some(0.5));
    // False alarms: C yes, D no -> 1/2.
    assert_eq!(m.success_sequences, 2);
    assert_eq!(m.false_alarm_rate, Some(0.5));
    // Lead time: only A, 600 ms.
    assert_eq!(m.lead_times_ms.len(), 1);
    assert!((m.lead_times_ms[0] - 600.0).abs() < 1e-9);
    let lt = m.lead_time.unwrap();
    assert!((lt.median - 600.0).abs() < 1e-9);
    // Events: TP A, B; FP C -> precision 2/3, recall 2/2.
    assert_eq!((m.event_tp, m.event_fp), (2, 1));
    assert!((m.event_precision.unwrap() - 2.0 / 3.0).abs() < 1e-12);
    assert_eq!(m.event_recall, Some(1.0));
    // Per-step precision 7/9, recall 7/17.
    assert!((m.confusion.precision().unwrap() - 7.0 / 9.0).abs() < 1e-12);
    assert!((m.confusion.recall().unwrap() - 7.0 / 17.0).abs() < 1e-12);
    let text = m.to_string();
    assert!(text.contains("50.00%"), "{text}");
}

#[test]
fn narrow_event_window() {
    // max_lead 3, max_lag 0: window of A = [5, 8]: edge 2 -> FP, edge 6 -> TP.
    // B window [2, 5]: edge 6 -> FP. C: FP. -> TP 1, FP 3, precision 1/4, recall 1/2.
    let m = evaluate(
        &seqs(),
        EventConfig {
            max_lead_steps: 3,
            max_lag_steps: 0,
        },
    );
    assert_eq!((m.event_tp, m.event_fp), (1, 3));
    assert_eq!(m.event_precision, Some(0.25));
    assert_eq!(m.event_recall, Some(0.5));
}

#[test]
fn alarm_at_drop_is_not_ahead() {
    // First unstable prediction exactly at the drop index: not "before the drop".
    let s = EvalSequence::new(&[S, S, U, U], &[S, S, S, U], Some(3), true, RATE);
    let m = evaluate(&[s], EventConfig::default());
    assert_eq!(m.ahead_drop_rate, Some(0.0));
    assert!(m.lead_time.is_none());
    // A failure sequence with no prediction at all is not ahead either; a
    // failure whose drop is outside the window is not counted.
    let none = EvalSequence::new(&[S, U], &[S, S], Some(1), true, RATE);
    let outside = EvalSequence::new(&[S, S], &[U, U], Some(7), true, RATE);
    let m = evaluate(&[none, outside], EventConfig::default());
    assert_eq!(m.failure_sequences, 1);
    assert_eq!(m.ahead_drop_rate, Some(0.0));
    assert_eq!(m.false_alarm_rate, None);
}

#[test]
fn lead_time_spread() {
    // Sorted 100, 200, 300, 400: median (200+300)/2 = 250; q25 at position 0.75 ->
    // 100 + 0.75*100 = 175; q75 at 2.25 -> 325.
    let s = Spread::of(&[400.0, 100.0, 300.0, 200.0]).unwrap();
    assert_eq!(
        (s.n, s.median, s.q25, s.q75, s.min, s.max),
        (4, 250.0, 175.0, 325.0, 100.0, 400.0)
    );
    assert!(Spread::of(&[]).is_none());
}

/// A grasp of `n` steps armed from 0: a failure flagged from `flag_from` (None: never) or a
/// success with an alarm or not.
fn grasp(id: usize, failure: bool, flag_from: Option<usize>) -> slipguard_data::armed::ArmedGrasp {
    let n = 20;
    slipguard_data::armed::ArmedGrasp {
        trial: format!("t{id}"),
        failure,
        start: 0,
        end: n,
        flags: (0..n).map(|t| flag_from.is_some_and(|f| t >= f)).collect(),
        step_ms: 60.0,
    }
}

/// The paired difference against counts done by hand: detector b warns 4 more of 10 drops at
/// least 0.3 s ahead and alarms in 1 more of 10 held grasps; identical detectors differ by 0
/// with a zero-width interval.
#[test]
fn paired_difference_counts_the_pairs() {
    use slipguard_data::armed::{ArmedMetrics, paired_difference};
    let mut a = Vec::new();
    let mut b = Vec::new();
    for i in 0..10 {
        // a: 2 of 10 early (lead 10 steps = 600 ms), the rest late (2 steps = 120 ms).
        a.push(grasp(i, true, Some(if i < 2 { 10 } else { 18 })));
        // b: 6 of 10 early.
        b.push(grasp(i, true, Some(if i < 6 { 10 } else { 18 })));
    }
    for i in 10..20 {
        a.push(grasp(i, false, if i == 10 { Some(5) } else { None }));
        b.push(grasp(i, false, if i <= 11 { Some(5) } else { None }));
    }
    let early = paired_difference(&a, &b, 7, |m: &ArmedMetrics| m.detected_early() as f64);
    assert_eq!(early.value, 4.0);
    let ci = early.ci.unwrap();
    assert!(
        ci.lo > 0.0 && ci.lo <= 4.0 && ci.hi >= 4.0 && ci.hi <= 10.0,
        "{ci:?}"
    );
    let fa = paired_difference(&a, &b, 8, |m: &ArmedMetrics| m.false_alarm_grasps as f64);
    assert_eq!(fa.value, 1.0);
    let same = paired_difference(&a, &a, 9, |m: &ArmedMetrics| m.detected_early() as f64);
    assert_eq!(same.value, 0.0);
    let ci = same.ci.unwrap();
    assert_eq!((ci.lo, ci.hi), (0.0, 0.0));
}
