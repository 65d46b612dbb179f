//! Evaluation metrics, implemented once for every tool (training, eval, replay).
//!
//! Conventions: the positive class is **unstable**. A sequence is one trial (or
//! one channel of a trial) cut to the labelled window, index 0 = grasp start.
//! Steps whose label is `None` are not evaluated.
//!
//! * **success rate** (paper): correct steps / evaluated steps, over all sequences.
//! * **ahead-drop rate** (paper, made exact): among failure sequences whose drop
//!   lies inside the sequence, the share whose *first* unstable prediction
//!   (searching from index 0, the grasp start) comes at an index strictly
//!   smaller than the drop index. A sequence with no unstable prediction counts
//!   as not ahead.
//! * **false-alarm rate**: among success sequences, the share with at least one
//!   unstable prediction.
//! * **lead time**: for the failure sequences that were ahead, (drop index −
//!   first unstable index) × step duration, in ms; median, quartiles, min, max.
//! * **event-level precision / recall**: an *alarm* is a rising edge of the
//!   prediction (an unstable step whose previous step was stable, or index 0 if
//!   unstable). An alarm in a failure sequence at index `a` with
//!   `drop − max_lead ≤ a ≤ drop + max_lag` is a hit; only the first hit per
//!   drop counts as a true positive, later alarms inside that window are ignored;
//!   every other alarm is a false positive. Precision = TP / (TP + FP);
//!   recall = drops with a hit / drops.
//! * **confusion matrix**: per step over evaluated steps.

use crate::trial::Stability;

/// One evaluated sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalSequence {
    /// Labels per step (`None` = not evaluated).
    pub labels: Vec<Option<Stability>>,
    /// Predictions per step (same length as `labels`).
    pub predictions: Vec<Stability>,
    /// Drop index relative to the sequence start (failures only).
    pub drop_index: Option<usize>,
    /// Whether the trial was a failure (object dropped).
    pub failure: bool,
    /// Duration of one step in ms (≈ 59.88 ms at 16.7 Hz).
    pub step_ms: f64,
}

impl EvalSequence {
    /// A sequence with every step evaluated.
    pub fn new(
        labels: &[Stability],
        predictions: &[Stability],
        drop_index: Option<usize>,
        failure: bool,
        rate_hz: f64,
    ) -> Self {
        EvalSequence {
            labels: labels.iter().copied().map(Some).collect(),
            predictions: predictions.to_vec(),
            drop_index,
            failure,
            step_ms: 1000.0 / rate_hz,
        }
    }

    /// Index of the first unstable prediction, if any.
    pub fn first_alarm(&self) -> Option<usize> {
        self.predictions.iter().position(|p| p.is_unstable())
    }

    /// Rising edges of the prediction.
    pub fn alarms(&self) -> Vec<usize> {
        let p = &self.predictions;
        (0..p.len())
            .filter(|&i| p[i].is_unstable() && (i == 0 || !p[i - 1].is_unstable()))
            .collect()
    }
}

/// Per-step confusion matrix (positive = unstable).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Confusion {
    /// Labelled unstable, predicted unstable.
    pub tp: usize,
    /// Labelled stable, predicted unstable.
    pub fp: usize,
    /// Labelled stable, predicted stable.
    pub tn: usize,
    /// Labelled unstable, predicted stable.
    pub fn_: usize,
}

impl Confusion {
    pub fn total(&self) -> usize {
        self.tp + self.fp + self.tn + self.fn_
    }
    pub fn accuracy(&self) -> Option<f64> {
        ratio(self.tp + self.tn, self.total())
    }
    pub fn precision(&self) -> Option<f64> {
        ratio(self.tp, self.tp + self.fp)
    }
    pub fn recall(&self) -> Option<f64> {
        ratio(self.tp, self.tp + self.fn_)
    }
}

/// Event matching windows, in steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EventConfig {
    /// How many steps before the drop an alarm may come and still count (default 40).
    pub max_lead_steps: usize,
    /// How many steps after the drop an alarm may come and still count (default 5).
    pub max_lag_steps: usize,
}

impl Default for EventConfig {
    fn default() -> Self {
        EventConfig {
            max_lead_steps: 40,
            max_lag_steps: 5,
        }
    }
}

/// Summary of a distribution of lead times (ms).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub n: usize,
    pub median: f64,
    pub q25: f64,
    pub q75: f64,
    pub min: f64,
    pub max: f64,
}

/// Linear-interpolated quantile (`q` in [0, 1]) of sorted values.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 1 {
        return sorted[0];
    }
    let pos = q * (n - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

impl Spread {
    pub fn of(values: &[f64]) -> Option<Spread> {
        if values.is_empty() {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        Some(Spread {
            n: v.len(),
            median: quantile(&v, 0.5),
            q25: quantile(&v, 0.25),
            q75: quantile(&v, 0.75),
            min: v[0],
            max: v[v.len() - 1],
        })
    }
}

/// All metrics of a set of sequences. Rates are `None` when their denominator is 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Metrics {
    pub evaluated_steps: usize,
    pub success_rate: Option<f64>,
    /// Failure sequences with the drop inside the window.
    pub failure_sequences: usize,
    pub ahead_drop_rate: Option<f64>,
    pub success_sequences: usize,
    pub false_alarm_rate: Option<f64>,
    /// Lead times (ms) of the failure sequences that were ahead.
    pub lead_times_ms: Vec<f64>,
    pub lead_time: Option<Spread>,
    pub event_tp: usize,
    pub event_fp: usize,
    pub event_precision: Option<f64>,
    pub event_recall: Option<f64>,
    pub confusion: Confusion,
}

fn ratio(a: usize, b: usize) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

/// Compute every metric over `seqs`.
///
/// # Panics
/// If a sequence's labels and predictions differ in length.
pub fn evaluate(seqs: &[EvalSequence], ev: EventConfig) -> Metrics {
    let mut c = Confusion::default();
    let (mut fail_n, mut ahead_n, mut succ_n, mut fa_n) = (0, 0, 0, 0);
    let mut leads = Vec::new();
    let (mut tp, mut fp, mut drops_hit, mut drops) = (0, 0, 0, 0);
    for s in seqs {
        assert_eq!(
            s.labels.len(),
            s.predictions.len(),
            "labels and predictions differ in length"
        );
        for (l, p) in s.labels.iter().zip(&s.predictions) {
            match (l, p.is_unstable()) {
                (None, _) => {}
                (Some(Stability::Unstable), true) => c.tp += 1,
                (Some(Stability::Unstable), false) => c.fn_ += 1,
                (Some(Stability::Stable), true) => c.fp += 1,
                (Some(Stability::Stable), false) => c.tn += 1,
            }
        }
        let drop = s
            .drop_index
            .filter(|&d| s.failure && d < s.predictions.len());
        if let Some(d) = drop {
            fail_n += 1;
            if let Some(a) = s.first_alarm()
                && a < d
            {
                ahead_n += 1;
                leads.push((d - a) as f64 * s.step_ms);
            }
        } else if !s.failure {
            succ_n += 1;
            if s.first_alarm().is_some() {
                fa_n += 1;
            }
        }
        // Events.
        let mut hit = false;
        if drop.is_some() {
            drops += 1;
        }
        for a in s.alarms() {
            let in_window =
                drop.is_some_and(|d| a + ev.max_lead_steps >= d && a <= d + ev.max_lag_steps);
            if in_window {
                if !hit {
                    hit = true;
                    tp += 1;
                }
            } else {
                fp += 1;
            }
        }
        if hit {
            drops_hit += 1;
        }
    }
    Metrics {
        evaluated_steps: c.total(),
        success_rate: c.accuracy(),
        failure_sequences: fail_n,
        ahead_drop_rate: ratio(ahead_n, fail_n),
        success_sequences: succ_n,
        false_alarm_rate: ratio(fa_n, succ_n),
        lead_time: Spread::of(&leads),
        lead_times_ms: leads,
        event_tp: tp,
        event_fp: fp,
        event_precision: ratio(tp, tp + fp),
        event_recall: ratio(drops_hit, drops),
        confusion: c,
    }
}

impl std::fmt::Display for Metrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{:.2}%", 100.0 * v));
        writeln!(f, "evaluated steps      {}", self.evaluated_steps)?;
        writeln!(f, "success rate         {}", pct(self.success_rate))?;
        writeln!(
            f,
            "ahead-drop rate      {} of {} failure sequences",
            pct(self.ahead_drop_rate),
            self.failure_sequences
        )?;
        writeln!(
            f,
            "false-alarm rate     {} of {} success sequences",
            pct(self.false_alarm_rate),
            self.success_sequences
        )?;
        match self.lead_time {
            Some(s) => writeln!(
                f,
                "lead time            median {:.0} ms, IQR {:.0}-{:.0} ms, range {:.0}-{:.0} ms (n={})",
                s.median, s.q25, s.q75, s.min, s.max, s.n
            )?,
            None => writeln!(f, "lead time            n/a")?,
        }
        writeln!(
            f,
            "events               precision {} (TP {}, FP {}), recall {}",
            pct(self.event_precision),
            self.event_tp,
            self.event_fp,
            pct(self.event_recall)
        )?;
        let c = self.confusion;
        writeln!(f, "confusion            label\\pred  stable  unstable")?;
        writeln!(
            f,
            "                     stable     {:>6}  {:>8}",
            c.tn, c.fp
        )?;
        write!(
            f,
            "                     unstable   {:>6}  {:>8}",
            c.fn_, c.tp
        )
    }
}
