//! The paper's Table I baselines (section III.B): Gaussian Naive Bayes, KNN (k = 3) and an
//! RBF SVM, plus an "always stable" reference, cross-validated by trial on the same labels
//! and scored with the same [`slipguard_data::metrics::evaluate`] as the LSTM models.
//!
//! Every classifier labels one time step at a time (no memory), from one of two feature sets:
//!
//! * [`FeatureSet::MultiChannel`] (the paper's Table I set-up): the 16 channel forces (mN) of
//!   one step of the 160-step window from grasp start; target = the trial-level label of that
//!   step. One evaluated sequence per trial.
//! * [`FeatureSet::SingleChannel`]: one contact channel at a time with exactly the LSTM's
//!   input, the core's float feature path [`slipguard_core::float::raw_feature_sequence`] with
//!   [`feature_config`] (variant ForceStft, d(t) on, the paper's STFT: 20-step rectangular
//!   window, bins 1..=10) over the same 160-step window: [force, d(t), 10 bands]. One evaluated
//!   sequence per (trial, contact channel), as for the single-channel LSTMs.
//!
//! Features are standardised with the training fold's mean and σ (σ = 0 → 1) before fitting.
//! Folds are by trial ([`make_folds`]); nothing of a held-out trial is seen in training.
//! Everything is deterministic: no random numbers are drawn.
//!
//! Classifier settings follow scikit-learn's defaults, which the paper's reference used:
//! GaussianNB with `var_smoothing` 1e-9; KNN k = 3, uniform majority vote, Euclidean distance
//! (linfa-nn k-d tree); SVC with C = 1, RBF kernel, γ = 1 / n_features on standardised
//! features ("scale"), tolerance 1e-3, no shrinking (linfa-svm 0.8.1's shrinking heuristic
//! panics with an index of −1 on the 16-channel folds). The SVM's kernel matrix is dense, so its training set
//! is cut to at most `max_train` evenly spaced steps (a fixed stride, no sampling).

use slipguard_core::units::Millihertz;
use std::fmt;
use std::time::Instant;

use linfa::prelude::*;
use linfa_bayes::GaussianNb;
use linfa_nn::distance::L2Dist;
use linfa_nn::{CommonNearestNeighbour, NearestNeighbour};
use linfa_svm::Svm;
use ndarray::{Array1, Array2, ArrayView2, Axis};
use serde::Serialize;
use slipguard_core::blob::{InputUnit, ModelConfig, Variant};
use slipguard_core::features::stft::StftConfig;
use slipguard_core::float::raw_feature_sequence;

use slipguard_data::labels::{LabelStatus, TrialLabels, channel_sequences};
use slipguard_data::metrics::{EvalSequence, EventConfig, Metrics, evaluate};
use slipguard_data::trial::{Outcome, Stability, Trial};

/// One row of the paper's Table I: (model, success rate %, ahead-drop rate %).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperRow {
    pub model: &'static str,
    pub success_rate_pct: f64,
    pub ahead_drop_pct: f64,
}

/// The paper's Table I ("Comparison among different solutions", 16-channel input).
pub const PAPER_TABLE_I: [PaperRow; 4] = [
    PaperRow {
        model: "NB",
        success_rate_pct: 68.81,
        ahead_drop_pct: 65.69,
    },
    PaperRow {
        model: "KNN (k=3)",
        success_rate_pct: 79.70,
        ahead_drop_pct: 81.76,
    },
    PaperRow {
        model: "SVM",
        success_rate_pct: 84.67,
        ahead_drop_pct: 66.67,
    },
    PaperRow {
        model: "LSTM",
        success_rate_pct: 84.60,
        ahead_drop_pct: 85.88,
    },
];

/// Default input full scale (mN) for the single-channel features: above the largest reading
/// in eagle-shoal (38,089 mN), so that nothing saturates.
pub const DEFAULT_FULL_SCALE_MN: i32 = 40_000;

/// Which inputs a baseline sees at each step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeatureSet {
    /// All channels' forces at one step (the paper's Table I).
    MultiChannel,
    /// One contact channel: [force, d(t), STFT bands] from the core's float feature path.
    SingleChannel,
}

impl FeatureSet {
    pub fn name(self) -> &'static str {
        match self {
            FeatureSet::MultiChannel => "16-channel",
            FeatureSet::SingleChannel => "single-channel",
        }
    }
}

/// SVM settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SvmSettings {
    /// Soft-margin C (both classes).
    pub c: f64,
    /// RBF γ in exp(−γ‖x − y‖²); `None` = 1 / n_features (scikit-learn's "scale" on
    /// standardised features).
    pub gamma: Option<f64>,
    /// Most training steps used (evenly spaced); the dense kernel matrix grows with its square.
    pub max_train: usize,
    /// Solver stopping tolerance.
    pub tol: f64,
}

impl Default for SvmSettings {
    fn default() -> Self {
        SvmSettings {
            c: 1.0,
            gamma: None,
            max_train: 4000,
            tol: 1e-3,
        }
    }
}

/// A per-step classifier.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Classifier {
    /// Predicts stable everywhere: the floor every model has to beat.
    AllStable,
    /// Gaussian Naive Bayes (linfa-bayes).
    NaiveBayes,
    /// k nearest neighbours, majority vote (linfa-nn k-d tree).
    Knn { k: usize },
    /// C-SVM with an RBF kernel (linfa-svm).
    Svm(SvmSettings),
}

impl Classifier {
    /// Name as in the paper's Table I.
    pub fn name(&self) -> String {
        match self {
            Classifier::AllStable => "all stable".into(),
            Classifier::NaiveBayes => "NB".into(),
            Classifier::Knn { k } => format!("KNN (k={k})"),
            Classifier::Svm(_) => "SVM".into(),
        }
    }

    /// The paper's Table I row for this classifier, if it has one.
    pub fn paper_row(&self) -> Option<PaperRow> {
        let key = match self {
            Classifier::NaiveBayes => "NB",
            Classifier::Knn { k: 3 } => "KNN (k=3)",
            Classifier::Svm(_) => "SVM",
            _ => return None,
        };
        PAPER_TABLE_I.iter().copied().find(|r| r.model == key)
    }
}

/// Why a baseline could not be trained or evaluated.
#[derive(Debug, Clone, PartialEq)]
pub enum BaselineError {
    /// No labelled sequence to train or test on.
    NoData(String),
    /// Sequences of one run have different feature widths.
    Shape(String),
    /// The classifier crate refused the data.
    Fit { classifier: String, message: String },
}

impl fmt::Display for BaselineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BaselineError::NoData(s) => write!(f, "no data: {s}"),
            BaselineError::Shape(s) => write!(f, "feature shape: {s}"),
            BaselineError::Fit {
                classifier,
                message,
            } => write!(f, "fitting {classifier}: {message}"),
        }
    }
}

impl std::error::Error for BaselineError {}

/// One labelled sequence of per-step feature vectors.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSequence {
    pub trial_id: String,
    /// The channel (single-channel features), `None` for all channels.
    pub channel: Option<usize>,
    /// `features[step][feature]`.
    pub features: Vec<Vec<f64>>,
    pub labels: Vec<Stability>,
    /// Drop index relative to the sequence start.
    pub drop_index: Option<usize>,
    pub failure: bool,
    pub rate_hz: f64,
}

impl FeatureSequence {
    /// Width of a feature vector (0 if empty).
    pub fn width(&self) -> usize {
        self.features.first().map_or(0, Vec::len)
    }

    /// The metrics' view of this sequence with the given predictions.
    pub fn eval(&self, predictions: &[Stability]) -> EvalSequence {
        EvalSequence::new(
            &self.labels,
            predictions,
            self.drop_index,
            self.failure,
            self.rate_hz,
        )
    }
}

/// The core feature configuration of the single-channel baselines: what the
/// (Data + STFT) & LSTM variant sees with d(t) on (force, d(t), the paper's 10 STFT bands),
/// for a force sensor read in mN with `full_scale_mn` mapping to 1.0.
pub fn feature_config(full_scale_mn: i32, rate_hz: f32) -> ModelConfig {
    ModelConfig {
        model_id: 0,
        name: *b"baselines\0\0\0",
        variant: Variant::DataStftLstm,
        force_diff: true,
        sample_rate_mhz: Millihertz::from_hz(rate_hz as f64),
        input_unit: InputUnit::MilliNewton,
        input_offset: 0,
        input_full_scale: full_scale_mn.max(1),
        stft: StftConfig::PAPER,
        hidden: [128, 0],
        cell_frac_bits: [0, 0],
        threshold_q15: 16_384,
        raise_after: 1,
        clear_after: 1,
        hand_rule: None,
    }
}

/// The trial-level sequence of all channels (the paper's Table I input), or `None` if the
/// trial carries no labels.
pub fn multichannel_sequence(trial: &Trial, labels: &TrialLabels) -> Option<FeatureSequence> {
    if labels.status != LabelStatus::Labelled {
        return None;
    }
    let features = (labels.seq_start..labels.seq_start + labels.seq_len)
        .map(|t| trial.row(t).into_iter().map(f64::from).collect())
        .collect();
    Some(FeatureSequence {
        trial_id: trial.id.clone(),
        channel: None,
        features,
        labels: labels.steps.clone(),
        drop_index: labels.drop_index(),
        failure: labels.outcome == Outcome::Failure,
        rate_hz: f64::from(trial.rate_hz),
    })
}

/// One sequence per contact channel with the core's float features (see [`feature_config`]).
pub fn single_channel_sequences(
    trial: &Trial,
    labels: &TrialLabels,
    config: &ModelConfig,
) -> Vec<FeatureSequence> {
    channel_sequences(trial, labels)
        .into_iter()
        .map(|cs| FeatureSequence {
            trial_id: cs.trial_id,
            channel: Some(cs.channel),
            features: raw_feature_sequence(config, &cs.samples)
                .into_iter()
                .map(|v| v.into_iter().map(f64::from).collect())
                .collect(),
            labels: cs.labels,
            drop_index: cs.drop_index,
            failure: cs.outcome == Outcome::Failure,
            rate_hz: f64::from(trial.rate_hz),
        })
        .collect()
}

/// The sequences of `set` for labelled trials (`labels[i]` belongs to `trials[i]`).
pub fn build_sequences(
    trials: &[Trial],
    labels: &[TrialLabels],
    set: FeatureSet,
    full_scale_mn: i32,
) -> Vec<FeatureSequence> {
    trials
        .iter()
        .zip(labels)
        .flat_map(|(t, l)| match set {
            FeatureSet::MultiChannel => multichannel_sequence(t, l).into_iter().collect(),
            FeatureSet::SingleChannel => {
                single_channel_sequences(t, l, &feature_config(full_scale_mn, t.rate_hz))
            }
        })
        .collect()
}

/// How trials are split into folds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FoldPlan {
    /// One fold per trial.
    LeaveOneTrialOut,
    /// `k` folds: failures (sorted by id) then successes (sorted by id), dealt round-robin,
    /// so that every fold gets its share of failures.
    KFold(usize),
}

/// Held-out trial ids of each fold. `trials` are (id, failure) pairs; duplicates are ignored.
pub fn make_folds(trials: &[(String, bool)], plan: FoldPlan) -> Vec<Vec<String>> {
    let mut fail: Vec<&String> = trials.iter().filter(|t| t.1).map(|t| &t.0).collect();
    let mut succ: Vec<&String> = trials.iter().filter(|t| !t.1).map(|t| &t.0).collect();
    fail.sort();
    fail.dedup();
    succ.sort();
    succ.dedup();
    let n = fail.len() + succ.len();
    let k = match plan {
        FoldPlan::LeaveOneTrialOut => n,
        FoldPlan::KFold(k) => k.clamp(1, n.max(1)),
    };
    let mut folds = vec![Vec::new(); k];
    for (i, id) in fail.into_iter().chain(succ).enumerate() {
        folds[i % k].push(id.clone());
    }
    folds.retain(|f| !f.is_empty());
    for f in &mut folds {
        f.sort();
    }
    folds
}

/// The (trial id, failure) pairs of some sequences, one per trial.
pub fn trial_outcomes(seqs: &[FeatureSequence]) -> Vec<(String, bool)> {
    let mut v: Vec<(String, bool)> = seqs
        .iter()
        .map(|s| (s.trial_id.clone(), s.failure))
        .collect();
    v.sort();
    v.dedup();
    v
}

/// Per-feature mean and σ of a training set.
#[derive(Debug, Clone, PartialEq)]
pub struct Standardizer {
    pub mean: Array1<f64>,
    pub std: Array1<f64>,
}

impl Standardizer {
    /// Fit on the rows of `x` (σ = 0 → 1, so constant features stay 0).
    pub fn fit(x: ArrayView2<f64>) -> Self {
        let n = x.nrows().max(1) as f64;
        let mean = x.sum_axis(Axis(0)) / n;
        let var = x
            .rows()
            .into_iter()
            .fold(Array1::zeros(x.ncols()), |acc: Array1<f64>, r| {
                let d = &r - &mean;
                acc + &d * &d
            })
            / n;
        let std = var.mapv(|v| if v > 0.0 { v.sqrt() } else { 1.0 });
        Standardizer { mean, std }
    }

    pub fn apply(&self, x: ArrayView2<f64>) -> Array2<f64> {
        (&x - &self.mean) / &self.std
    }
}

/// A classifier fitted on standardised features.
pub enum Fitted {
    Constant(bool),
    NaiveBayes(GaussianNb<f64, usize>),
    Knn {
        points: Array2<f64>,
        targets: Vec<bool>,
        k: usize,
    },
    Svm(Svm<f64, bool>),
}

/// Fit `classifier` on rows `x` (already standardised) with targets `y` (true = unstable).
/// A training set of one class gives a constant predictor of that class.
pub fn fit(classifier: &Classifier, x: Array2<f64>, y: &[bool]) -> Result<Fitted, BaselineError> {
    if x.nrows() == 0 || x.nrows() != y.len() {
        return Err(BaselineError::NoData(format!(
            "{} training rows, {} targets",
            x.nrows(),
            y.len()
        )));
    }
    let err = |e: &dyn fmt::Display| BaselineError::Fit {
        classifier: classifier.name(),
        message: e.to_string(),
    };
    let n_unstable = y.iter().filter(|&&b| b).count();
    if matches!(classifier, Classifier::AllStable) {
        return Ok(Fitted::Constant(false));
    }
    if n_unstable == 0 || n_unstable == y.len() {
        return Ok(Fitted::Constant(n_unstable > 0));
    }
    match *classifier {
        Classifier::AllStable => unreachable!("handled above"),
        Classifier::NaiveBayes => {
            let targets: Array1<usize> = y.iter().map(|&b| usize::from(b)).collect();
            let ds = Dataset::new(x, targets);
            let m = GaussianNb::params().fit(&ds).map_err(|e| err(&e))?;
            Ok(Fitted::NaiveBayes(m))
        }
        Classifier::Knn { k } => {
            if k == 0 {
                return Err(err(&"k must be at least 1"));
            }
            Ok(Fitted::Knn {
                points: x,
                targets: y.to_vec(),
                k,
            })
        }
        Classifier::Svm(s) => {
            let (x, y) = evenly_spaced(x, y, s.max_train);
            let gamma = s.gamma.unwrap_or(1.0 / x.ncols().max(1) as f64);
            if !(gamma > 0.0 && s.c > 0.0) {
                return Err(err(&"C and gamma must be positive"));
            }
            let targets = Array1::from_vec(y);
            let ds = Dataset::new(x, targets);
            let m = Svm::<f64, bool>::params()
                .pos_neg_weights(s.c, s.c)
                .gaussian_kernel(1.0 / gamma)
                .eps(s.tol)
                .shrinking(false)
                .fit(&ds)
                .map_err(|e| err(&e))?;
            Ok(Fitted::Svm(m))
        }
    }
}

/// At most `max` rows at evenly spaced indices `⌊i·n/max⌋` (all rows if `n <= max`).
pub fn evenly_spaced(x: Array2<f64>, y: &[bool], max: usize) -> (Array2<f64>, Vec<bool>) {
    let n = x.nrows();
    if max == 0 || n <= max {
        return (x, y.to_vec());
    }
    let idx: Vec<usize> = (0..max).map(|i| i * n / max).collect();
    (x.select(Axis(0), &idx), idx.iter().map(|&i| y[i]).collect())
}

impl Fitted {
    /// Predictions (true = unstable) for standardised rows.
    pub fn predict(&self, x: &Array2<f64>) -> Result<Vec<bool>, BaselineError> {
        Ok(match self {
            Fitted::Constant(b) => vec![*b; x.nrows()],
            Fitted::NaiveBayes(m) => m.predict(x).iter().map(|&c| c == 1).collect(),
            Fitted::Svm(m) => m.predict(x).to_vec(),
            Fitted::Knn { points, targets, k } => {
                let err = |e: &dyn fmt::Display| BaselineError::Fit {
                    classifier: format!("KNN (k={k})"),
                    message: e.to_string(),
                };
                let index = CommonNearestNeighbour::KdTree
                    .from_batch(points, L2Dist)
                    .map_err(|e| err(&e))?;
                let mut out = Vec::with_capacity(x.nrows());
                for row in x.rows() {
                    let nn = index.k_nearest(row, *k).map_err(|e| err(&e))?;
                    let votes = nn.iter().filter(|(_, i)| targets[*i]).count();
                    out.push(2 * votes > nn.len());
                }
                out
            }
        })
    }
}

/// One fold of a cross-validation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FoldReport {
    pub held_out: Vec<String>,
    /// Training steps the classifier saw (after the SVM's cut).
    pub train_steps: usize,
    pub test_steps: usize,
}

/// Result of cross-validating one classifier on one feature set.
#[derive(Debug, Clone)]
pub struct CvResult {
    pub classifier: Classifier,
    pub features: FeatureSet,
    pub folds: Vec<FoldReport>,
    /// Held-out predictions of every sequence, in input order.
    pub sequences: Vec<EvalSequence>,
    /// (trial id, channel) of each entry of `sequences`.
    pub sequence_ids: Vec<(String, Option<usize>)>,
    pub metrics: Metrics,
    /// Wall time of fitting and predicting, seconds.
    pub seconds: f64,
}

fn stack(rows: &[&[f64]], width: usize) -> Array2<f64> {
    let mut a = Array2::zeros((rows.len(), width));
    for (mut dst, src) in a.rows_mut().into_iter().zip(rows) {
        dst.assign(&ndarray::ArrayView1::from(*src));
    }
    a
}

/// Cross-validate `classifier` over `folds` (held-out trial ids; see [`make_folds`]): for
/// each fold, standardise with and fit on every step of the other trials' sequences, predict
/// every step of the held-out ones. Trials in no fold are never predicted. `progress(done,
/// total)` is called after each fold.
pub fn cross_validate(
    seqs: &[FeatureSequence],
    features: FeatureSet,
    classifier: &Classifier,
    folds: &[Vec<String>],
    ev: EventConfig,
    mut progress: impl FnMut(usize, usize),
) -> Result<CvResult, BaselineError> {
    let start = Instant::now();
    let width = seqs.first().map_or(0, FeatureSequence::width);
    if width == 0 {
        return Err(BaselineError::NoData("no labelled sequences".into()));
    }
    if let Some(s) = seqs
        .iter()
        .find(|s| s.features.iter().any(|f| f.len() != width))
    {
        return Err(BaselineError::Shape(format!(
            "{} has features of a width other than {width}",
            s.trial_id
        )));
    }
    let mut preds: Vec<Option<Vec<Stability>>> = vec![None; seqs.len()];
    let mut reports = Vec::with_capacity(folds.len());
    for (fi, held) in folds.iter().enumerate() {
        let is_held = |s: &FeatureSequence| held.contains(&s.trial_id);
        let (mut xr, mut yr) = (Vec::new(), Vec::new());
        for s in seqs.iter().filter(|s| !is_held(s)) {
            for (f, l) in s.features.iter().zip(&s.labels) {
                xr.push(f.as_slice());
                yr.push(l.is_unstable());
            }
        }
        if xr.is_empty() {
            return Err(BaselineError::NoData(format!(
                "fold {} holds out every trial ({})",
                fi + 1,
                held.join(", ")
            )));
        }
        let x = stack(&xr, width);
        let scaler = Standardizer::fit(x.view());
        let x = scaler.apply(x.view());
        let train_steps = match classifier {
            Classifier::Svm(s) if s.max_train > 0 => x.nrows().min(s.max_train),
            _ => x.nrows(),
        };
        let model = fit(classifier, x, &yr)?;
        let held_idx: Vec<usize> = (0..seqs.len()).filter(|&i| is_held(&seqs[i])).collect();
        let rows: Vec<&[f64]> = held_idx
            .iter()
            .flat_map(|&i| seqs[i].features.iter().map(Vec::as_slice))
            .collect();
        let test_steps = rows.len();
        let p = if rows.is_empty() {
            Vec::new()
        } else {
            model.predict(&scaler.apply(stack(&rows, width).view()))?
        };
        let mut it = p.into_iter();
        for &i in &held_idx {
            preds[i] = Some(
                it.by_ref()
                    .take(seqs[i].features.len())
                    .map(|u| {
                        if u {
                            Stability::Unstable
                        } else {
                            Stability::Stable
                        }
                    })
                    .collect(),
            );
        }
        reports.push(FoldReport {
            held_out: held.clone(),
            train_steps,
            test_steps,
        });
        progress(fi + 1, folds.len());
    }
    let mut sequences = Vec::new();
    let mut sequence_ids = Vec::new();
    for (s, p) in seqs.iter().zip(preds) {
        if let Some(p) = p {
            sequences.push(s.eval(&p));
            sequence_ids.push((s.trial_id.clone(), s.channel));
        }
    }
    if sequences.is_empty() {
        return Err(BaselineError::NoData(
            "no sequence belongs to a held-out trial".into(),
        ));
    }
    let metrics = evaluate(&sequences, ev);
    Ok(CvResult {
        classifier: *classifier,
        features,
        folds: reports,
        sequences,
        sequence_ids,
        metrics,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The metrics of one row as JSON-friendly numbers (rates in [0, 1], `null` when undefined).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MetricsRow {
    pub evaluated_steps: usize,
    pub success_rate: Option<f64>,
    pub ahead_drop_rate: Option<f64>,
    pub failure_sequences: usize,
    pub false_alarm_rate: Option<f64>,
    pub success_sequences: usize,
    pub lead_time_median_ms: Option<f64>,
    pub lead_time_q25_ms: Option<f64>,
    pub lead_time_q75_ms: Option<f64>,
    pub event_tp: usize,
    pub event_fp: usize,
    pub event_precision: Option<f64>,
    pub event_recall: Option<f64>,
    pub tp: usize,
    pub fp: usize,
    pub tn: usize,
    #[serde(rename = "fn")]
    pub fn_: usize,
}

impl From<&Metrics> for MetricsRow {
    fn from(m: &Metrics) -> Self {
        MetricsRow {
            evaluated_steps: m.evaluated_steps,
            success_rate: m.success_rate,
            ahead_drop_rate: m.ahead_drop_rate,
            failure_sequences: m.failure_sequences,
            false_alarm_rate: m.false_alarm_rate,
            success_sequences: m.success_sequences,
            lead_time_median_ms: m.lead_time.map(|s| s.median),
            lead_time_q25_ms: m.lead_time.map(|s| s.q25),
            lead_time_q75_ms: m.lead_time.map(|s| s.q75),
            event_tp: m.event_tp,
            event_fp: m.event_fp,
            event_precision: m.event_precision,
            event_recall: m.event_recall,
            tp: m.confusion.tp,
            fp: m.confusion.fp,
            tn: m.confusion.tn,
            fn_: m.confusion.fn_,
        }
    }
}

/// One row of the JSON report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportRow {
    pub features: FeatureSet,
    pub model: String,
    pub classifier: Classifier,
    pub metrics: MetricsRow,
    /// The paper's Table I figures for this model (16-channel rows only).
    pub paper: Option<PaperRow>,
    pub folds: Vec<FoldReport>,
    pub seconds: f64,
}

impl ReportRow {
    pub fn of(r: &CvResult) -> Self {
        ReportRow {
            features: r.features,
            model: r.classifier.name(),
            classifier: r.classifier,
            metrics: MetricsRow::from(&r.metrics),
            paper: (r.features == FeatureSet::MultiChannel)
                .then(|| r.classifier.paper_row())
                .flatten(),
            folds: r.folds.clone(),
            seconds: r.seconds,
        }
    }
}
