//! Evaluation of float and quantized models on labelled channel sequences: data sets (real
//! trials, simulated force and suction), cross-validation folds by trial and the decision sweep.
//! Metrics come from [`slipguard_data::metrics`]; the Fig. 8 plots are the CLI's.

use slipguard_batch::BatchModel;
use slipguard_core::blob::{AlignedBlob, InputUnit, ModelConfig, Variant};
use slipguard_core::decision::{DecisionConfig, DecisionState, Q15};
use slipguard_core::features::stft::StftConfig;
use slipguard_core::float::FloatModel;
use slipguard_core::model::{ChannelState, Model, StepOutput};
use slipguard_core::quantize::quantize;
use slipguard_core::units::Millihertz;

use crate::error::Result;
use slipguard_data::labels::{ChannelSequence, LabelConfig, channel_sequences, label_annotated};
use slipguard_data::metrics::{EvalSequence, EventConfig, Metrics, evaluate};
use slipguard_data::trial::{Outcome, Stability, Trial};
use slipguard_sim::force::{ForceSimConfig, simulate_trial as sim_force};
use slipguard_sim::suction::{SuctionSimConfig, simulate_trial as sim_suction};

/// A labelled single-channel sequence with what the plots and reports need.
#[derive(Debug, Clone)]
pub struct Sequence {
    pub cs: ChannelSequence,
    /// Lift start relative to the sequence start.
    pub lift: Option<usize>,
    pub rate_hz: f32,
}

impl Sequence {
    pub fn failure(&self) -> bool {
        self.cs.outcome == Outcome::Failure
    }
}

/// Labelled contact-channel sequences of annotated trials (`cfg` gives length and lead).
pub fn sequences_of(trials: &[Trial], cfg: &LabelConfig) -> Vec<Sequence> {
    let mut out = Vec::new();
    for t in trials {
        let l = label_annotated(t, cfg);
        let lift = t.marks.lift_start.and_then(|s| s.checked_sub(l.seq_start));
        for cs in channel_sequences(t, &l) {
            out.push(Sequence {
                cs,
                lift,
                rate_hz: t.rate_hz,
            });
        }
    }
    out
}

/// Simulated 16-pad force trials at `rate_hz` (trial `i` of `seed`), as sequences (labels with
/// the paper's durations, [`LabelConfig::scaled_to`]).
pub fn sim_force_sequences(
    seed: u64,
    count: usize,
    failure_share: f64,
    rate_hz: f32,
) -> Vec<Sequence> {
    let cfg = ForceSimConfig::at_rate(rate_hz as f64);
    let trials: Vec<Trial> = (0..count)
        .map(|i| sim_force(seed, i as u64, None, failure_share, &cfg))
        .collect();
    sequences_of(&trials, &LabelConfig::default().scaled_to(rate_hz))
}

/// Simulated suction trials at 71 Hz (4 cups), 160-step sequences from attach with the
/// paper's 20-step lead (the paper's Table V set-up).
pub fn sim_suction_sequences(seed: u64, count: usize, failure_share: f64) -> Vec<Sequence> {
    let cfg = SuctionSimConfig::default();
    let trials: Vec<Trial> = (0..count)
        .map(|i| sim_suction(seed, i as u64, None, failure_share, &cfg).0)
        .collect();
    sequences_of(&trials, &LabelConfig::default())
}

/// Header settings of a hand-force model at `rate_mhz` (0…32,768 mN → Q1.15).
pub fn force_config(
    variant: Variant,
    force_diff: bool,
    hidden: u16,
    name: &str,
    rate_mhz: Millihertz,
) -> ModelConfig {
    base_config(
        variant,
        force_diff,
        hidden,
        name,
        rate_mhz,
        InputUnit::MilliNewton,
        0,
        32_768,
    )
}

/// Header settings of a suction model at 71 Hz (counts 6,400 ± 40,960 → Q1.15).
pub fn suction_config(variant: Variant, force_diff: bool, hidden: u16, name: &str) -> ModelConfig {
    base_config(
        variant,
        force_diff,
        hidden,
        name,
        Millihertz(71_000),
        InputUnit::Counts,
        6_400,
        40_960,
    )
}

#[allow(clippy::too_many_arguments)]
fn base_config(
    variant: Variant,
    force_diff: bool,
    hidden: u16,
    name: &str,
    rate_mhz: Millihertz,
    unit: InputUnit,
    offset: i32,
    full_scale: i32,
) -> ModelConfig {
    ModelConfig {
        model_id: 0,
        name: crate::checkpoint::name_bytes(name),
        variant,
        force_diff,
        sample_rate_mhz: Millihertz(rate_mhz.0),
        input_unit: unit,
        input_offset: offset,
        input_full_scale: full_scale,
        stft: if variant.uses_bands() {
            StftConfig::for_rate_mhz(Millihertz(rate_mhz.0))
        } else {
            StftConfig::NONE
        },
        hidden: [hidden, if variant.lstm_count() == 2 { hidden } else { 0 }],
        cell_frac_bits: [0, 0],
        threshold_q15: 16_384,
        raise_after: 1,
        clear_after: 1,
        hand_rule: None,
    }
}

/// Quantizes a float model with the core's quantizer (cell range calibrated on `calib`).
pub fn quantize_model(model: &FloatModel, calib: &[&[f32]]) -> Result<Vec<u8>> {
    Ok(quantize(model, calib, None)?.0)
}

/// Quantizes `model` as [`quantize_model`] does and hands the bit-exact core model of that blob
/// (what the firmware runs) to `f`.
pub fn with_quantized_model<R>(
    model: &FloatModel,
    calib: &[&[f32]],
    f: impl FnOnce(&Model<'_>) -> R,
) -> Result<R> {
    let blob = quantize_model(model, calib)?;
    let aligned = AlignedBlob::new(&blob);
    let m = Model::from_bytes(aligned.as_bytes()).map_err(|e| {
        crate::error::LearnError::Training(format!("the quantized model does not parse: {e}"))
    })?;
    Ok(f(&m))
}

/// Per-step p(unstable) in Q0.15 of the float model (fresh state per sequence).
pub fn float_p_q15(model: &FloatModel, samples: &[f32]) -> Vec<i16> {
    let mut st = model.new_channel();
    samples
        .iter()
        .map(|&x| {
            let p = model.step(&mut st, x).p_unstable;
            Q15::from_f64(p as f64).0
        })
        .collect()
}

/// Per-step p(unstable) in Q0.15 of the bit-exact quantized core.
pub fn quant_p_q15(model: &Model<'_>, samples: &[f32]) -> Vec<i16> {
    let mut st = ChannelState::new();
    samples
        .iter()
        .map(|&x| model.step(&mut st, x.round() as i32).p_unstable_q15)
        .collect()
}

/// Sequences per batch of [`quant_p_q15_many`] (one rayon task each).
pub const BATCH_SEQUENCES: usize = 256;

/// [`quant_p_q15`] of every sequence (each from a fresh state), the same numbers: the
/// sequences run as the lanes of the batched core ([`slipguard_batch`], bit-exact with
/// [`Model::step`]), [`BATCH_SEQUENCES`] per batch, the batches in parallel (rayon; the
/// result in the sequences' order whatever the thread count). Shorter sequences of a batch
/// stop stepping at their end. A model the batch cannot take (a RAM image) runs sequence by
/// sequence.
pub fn quant_p_q15_many(model: &Model<'_>, seqs: &[&[f32]]) -> Vec<Vec<i16>> {
    use rayon::prelude::*;
    let Ok(batch) = BatchModel::new(model) else {
        return seqs.par_iter().map(|s| quant_p_q15(model, s)).collect();
    };
    seqs.par_chunks(BATCH_SEQUENCES)
        .flat_map_iter(|chunk| {
            let lanes = chunk.len();
            let mut st = batch.state(lanes);
            let steps = chunk.iter().map(|s| s.len()).max().unwrap_or(0);
            let mut p: Vec<Vec<i16>> = chunk.iter().map(|s| Vec::with_capacity(s.len())).collect();
            let (mut raw, mut active) = (vec![0i32; lanes], vec![false; lanes]);
            let mut out = vec![
                StepOutput {
                    p_unstable_q15: 0,
                    unstable: false
                };
                lanes
            ];
            for t in 0..steps {
                for (l, s) in chunk.iter().enumerate() {
                    active[l] = t < s.len();
                    raw[l] = s.get(t).map_or(0, |x| x.round() as i32);
                }
                batch.step_masked(&mut st, &raw, &active, &mut out);
                for (l, o) in out.iter().enumerate() {
                    if active[l] {
                        p[l].push(o.p_unstable_q15);
                    }
                }
            }
            p
        })
        .collect()
}

/// Flags after threshold and hysteresis.
pub fn decide(d: DecisionConfig, p: &[i16]) -> Vec<Stability> {
    let mut s = DecisionState::default();
    p.iter()
        .map(|&p| {
            if d.update(&mut s, p) {
                Stability::Unstable
            } else {
                Stability::Stable
            }
        })
        .collect()
}

/// Metrics of predictions (one per sequence) against the sequences' labels.
pub fn metrics_of(seqs: &[&Sequence], preds: &[Vec<Stability>]) -> Metrics {
    let ev: Vec<EvalSequence> = seqs
        .iter()
        .zip(preds)
        .map(|(s, p)| {
            EvalSequence::new(
                &s.cs.labels,
                p,
                s.cs.drop_index,
                s.failure(),
                s.rate_hz as f64,
            )
        })
        .collect();
    evaluate(&ev, EventConfig::default())
}

/// Which implementation produced the predictions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Float,
    Quantized,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Float => "float",
            Kind::Quantized => "quantized",
        }
    }
}

/// p(unstable) sequences of a model, float or quantized (`blob` = the quantized blob); the
/// quantized ones through [`quant_p_q15_many`], the float ones sequence by sequence in
/// parallel (rayon; in the sequences' order).
pub fn probabilities(
    model: &FloatModel,
    blob: &[u8],
    kind: Kind,
    seqs: &[&Sequence],
) -> Result<Vec<Vec<i16>>> {
    Ok(match kind {
        Kind::Float => {
            use rayon::prelude::*;
            seqs.par_iter()
                .map(|s| float_p_q15(model, &s.cs.samples))
                .collect()
        }
        Kind::Quantized => {
            let aligned = AlignedBlob::new(blob);
            let m = Model::from_bytes(aligned.as_bytes())?;
            let samples: Vec<&[f32]> = seqs.iter().map(|s| s.cs.samples.as_slice()).collect();
            quant_p_q15_many(&m, &samples)
        }
    })
}

/// Cross-validation folds by trial: failure trials and success trials (sorted by id) are dealt
/// round-robin into `k` folds, so every fold has failures. Returns trial ids per fold.
pub fn cv_folds<'a>(seqs: impl IntoIterator<Item = &'a Sequence>, k: usize) -> Vec<Vec<String>> {
    cv_folds_of(&trial_outcomes(seqs), k)
}

/// How cross-validation folds hold trials out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CvGrouping {
    /// By trial ([`cv_folds`]): repeats of one grasp setting can sit on both sides.
    #[default]
    Trial,
    /// By grasp setting ([`cv_folds_by_setting`]): every trial of a setting (object, force,
    /// weight) in one fold, what a user's new object or weight looks like.
    Setting,
}

impl CvGrouping {
    /// The name the command line and checkpoints use.
    pub fn name(self) -> &'static str {
        match self {
            CvGrouping::Trial => "trial",
            CvGrouping::Setting => "setting",
        }
    }

    /// The folds of `trials` ((id, failure) pairs) with `k` folds.
    pub fn folds(self, trials: &[(String, bool)], k: usize) -> Vec<Vec<String>> {
        match self {
            CvGrouping::Trial => cv_folds_of(trials, k),
            CvGrouping::Setting => cv_folds_by_setting(trials, k),
        }
    }
}

impl std::fmt::Display for CvGrouping {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for CvGrouping {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "trial" => Ok(CvGrouping::Trial),
            "setting" => Ok(CvGrouping::Setting),
            other => Err(format!("`{other}`: folds group by trial or setting")),
        }
    }
}

/// The distinct (trial id, failure) pairs of `seqs`, in first-seen order.
pub fn trial_outcomes<'a>(seqs: impl IntoIterator<Item = &'a Sequence>) -> Vec<(String, bool)> {
    let mut out: Vec<(String, bool)> = Vec::new();
    for s in seqs {
        if !out.iter().any(|(id, _)| id == &s.cs.trial_id) {
            out.push((s.cs.trial_id.clone(), s.failure()));
        }
    }
    out
}

/// [`cv_folds`] over (trial id, failure) pairs.
pub fn cv_folds_of(trials: &[(String, bool)], k: usize) -> Vec<Vec<String>> {
    let mut fail: Vec<String> = trials.iter().filter(|t| t.1).map(|t| t.0.clone()).collect();
    let mut succ: Vec<String> = trials
        .iter()
        .filter(|t| !t.1)
        .map(|t| t.0.clone())
        .collect();
    fail.sort();
    fail.dedup();
    succ.sort();
    succ.dedup();
    let mut folds = vec![Vec::new(); k.max(1)];
    for (i, id) in fail.into_iter().enumerate() {
        folds[i % k.max(1)].push(id);
    }
    let off = folds.iter().map(Vec::len).sum::<usize>();
    for (i, id) in succ.into_iter().enumerate() {
        folds[(off + i) % k.max(1)].push(id);
    }
    folds
}

/// Cross-validation folds by grasp setting ([`slipguard_data::trial::setting_of_id`]): every
/// trial of a setting in the same fold. Settings go, most failures first (then most trials,
/// then by name), each to the fold with the fewest failures so far (then the fewest trials,
/// then the lowest index), so the failures spread over the folds as evenly as whole settings
/// allow. Deterministic: the same folds for every training seed. Returns trial ids per fold,
/// sorted.
pub fn cv_folds_by_setting(trials: &[(String, bool)], k: usize) -> Vec<Vec<String>> {
    use std::collections::BTreeMap;
    let k = k.max(1);
    let mut settings: BTreeMap<String, (usize, Vec<String>)> = BTreeMap::new();
    for (id, failure) in trials {
        let e = settings
            .entry(slipguard_data::trial::setting_of_id(id))
            .or_default();
        if !e.1.contains(id) {
            e.0 += *failure as usize;
            e.1.push(id.clone());
        }
    }
    let mut order: Vec<(String, usize, Vec<String>)> = settings
        .into_iter()
        .map(|(s, (f, ids))| (s, f, ids))
        .collect();
    order.sort_by(|a, b| {
        b.1.cmp(&a.1)
            .then(b.2.len().cmp(&a.2.len()))
            .then(a.0.cmp(&b.0))
    });
    let mut folds = vec![Vec::new(); k];
    let mut fails = vec![0usize; k];
    for (_, f, ids) in order {
        let i = (0..k)
            .min_by_key(|&i| (fails[i], folds[i].len(), i))
            .unwrap_or(0);
        fails[i] += f;
        folds[i].extend(ids);
    }
    for f in &mut folds {
        f.sort();
    }
    folds
}

/// Score used to pick a decision rule on validation data: the smaller of the two margins over
/// the paper's best figures (success 80.09 %, ahead-drop 84.63 %), plus a small share of their
/// sum to break ties, minus a small penalty for the false-alarm rate (an alarm anywhere before
/// the drop counts as "ahead", so a rule that fires in every sequence would otherwise win).
pub fn goal_score(m: &Metrics) -> f64 {
    let s = m.success_rate.unwrap_or(0.0);
    let a = m.ahead_drop_rate.unwrap_or(0.0);
    let fa = m.false_alarm_rate.unwrap_or(0.0);
    (s - 0.8009).min(a - 0.8463) + 0.01 * (s + a) - 0.03 * fa
}

/// Chooses threshold and hysteresis on validation sequences (float p), maximising
/// [`goal_score`]. Returns the rule and its metrics.
/// `raise_after` is at least `min_raise`.
pub fn tune_decision(
    p: &[Vec<i16>],
    seqs: &[&Sequence],
    min_raise: u8,
) -> (DecisionConfig, Metrics) {
    let mut best: Option<(f64, DecisionConfig, Metrics)> = None;
    for thr in [0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8] {
        for raise in [1u8, 2, 3, 4, 5]
            .into_iter()
            .filter(|&r| r >= min_raise.min(5))
        {
            for clear in [1u8, 3, 10] {
                let d = DecisionConfig {
                    threshold_q15: Q15::from_f64(thr).0,
                    raise_after: raise,
                    clear_after: clear,
                };
                let preds: Vec<_> = p.iter().map(|q| decide(d, q)).collect();
                let m = metrics_of(seqs, &preds);
                let sc = goal_score(&m);
                if best.as_ref().is_none_or(|b| sc > b.0 + 1e-12) {
                    best = Some((sc, d, m));
                }
            }
        }
    }
    let (_, d, m) = best.expect("grid is not empty");
    (d, m)
}

/// Writes the decision rule into a config.
pub fn set_decision(c: &mut ModelConfig, d: DecisionConfig) {
    c.threshold_q15 = Q15(d.threshold_q15).header_threshold();
    c.raise_after = d.raise_after;
    c.clear_after = d.clear_after;
}

/// One table row.
#[derive(Debug, Clone)]
pub struct Row {
    pub model: String,
    pub data: String,
    pub kind: Kind,
    pub metrics: Metrics,
}

/// Markdown header of [`row_markdown`].
pub const TABLE_HEADER: &str = "| model | data | kind | seqs (fail) | success rate | ahead-drop | false alarms | lead median (ms) | event P / R |\n|---|---|---|---|---|---|---|---|---|";

/// One markdown table row.
pub fn row_markdown(r: &Row) -> String {
    let pct = |v: Option<f64>| v.map_or("n/a".into(), |v| format!("{:.2}%", 100.0 * v));
    let m = &r.metrics;
    format!(
        "| {} | {} | {} | {} ({}) | {} | {} | {} | {} | {} / {} |",
        r.model,
        r.data,
        r.kind.name(),
        m.success_sequences + m.failure_sequences,
        m.failure_sequences,
        pct(m.success_rate),
        pct(m.ahead_drop_rate),
        pct(m.false_alarm_rate),
        m.lead_time
            .map_or("n/a".into(), |l| format!("{:.0}", l.median)),
        pct(m.event_precision),
        pct(m.event_recall),
    )
}

/// The blob of a checkpoint: `blob` (the one exported beside it) when given, else the
/// checkpoint quantized with up to 64 of the `real` sequences outside its held-out trials as
/// calibration (what `slipguard eval` does).
pub fn blob_or_quantized(
    ck: &crate::checkpoint::Checkpoint,
    blob: Option<&Vec<u8>>,
    real: &[Sequence],
) -> Result<Vec<u8>> {
    if let Some(b) = blob {
        return Ok(b.clone());
    }
    let h = ck.heldout_trials().unwrap_or_default();
    let c: Vec<&[f32]> = real
        .iter()
        .filter(|s| !h.contains(&s.cs.trial_id))
        .take(64)
        .map(|s| s.cs.samples.as_slice())
        .collect();
    quantize_model(&ck.model, &c)
}
