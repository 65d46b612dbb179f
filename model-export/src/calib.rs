//! Calibration and agreement: runs the float and the quantized model over recorded data (the
//! data layer's trials, labelled as for training) and measures what quantization costs.
//!
//! - calibration: the largest |c| of each LSTM (→ the cell's power-of-two scale, through the
//!   core's `cell_bits_for` with its headroom), the share of raw samples that saturate the
//!   Q1.15 input, the share of normalised features clipped at ±8σ (the Q3.12 input range) and
//!   the largest |h| (Q0.15 covers tanh's range exactly);
//! - agreement on the same (or validation) data: flag agreement, max and mean |Δp|, and the
//!   paper's success rate and ahead-drop rate of both models (the data layer's metrics).

use std::path::Path;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use slipguard_batch::BatchModel;
use slipguard_core::blob::{AlignedBlob, ModelConfig};
use slipguard_core::float::FloatModel;
use slipguard_core::model::{Model, StepOutput};
use slipguard_core::quantize::{CELL_HEADROOM, DEFAULT_CELL_FRAC_BITS, cell_bits_for};
use slipguard_core::sample::InputScale;
use slipguard_data::labels::{self, ChannelSequence, LabelConfig};
use slipguard_data::metrics::{EvalSequence, EventConfig, Metrics, evaluate};
use slipguard_data::trial::{Outcome, Stability};

use crate::error::{ExportError, Result};

/// Channel sequences of a data set, as the trainer sees them.
#[derive(Clone, Debug)]
pub struct DataSet {
    /// Where it came from.
    pub source: String,
    /// Trials loaded.
    pub trials: usize,
    /// Trials without labels (no drop found, unknown outcome), used for calibration only.
    pub unlabelled: usize,
    /// Per contact channel: samples of the labelled window and labels.
    pub sequences: Vec<ChannelSequence>,
    /// Per contact channel: the whole recording, every step from the first to the last (no
    /// labels). Calibration and agreement run on these: what the device sees when it streams.
    pub recordings: Vec<ChannelSequence>,
    /// Per trial: every channel from the grasp start on, with the lift mark: what a hand-level
    /// model (`hand-lstm`) calibrates and is compared on ([`crate::hand`]).
    pub hands: Vec<crate::hand::HandRecording>,
    /// Sample rate of the data, Hz.
    pub rate_hz: f32,
    /// Warnings (rate or unit different from the model's).
    pub warnings: Vec<String>,
}

/// A bar on stderr for `n` items (hidden when stderr is not a terminal or `quiet`).
pub fn bar(n: usize, what: &str, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(n as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// Loads a data set (a recording file, a folder of recordings or an eagle-shoal folder) with
/// the data layer, labels it and cuts the per-channel sequences. `max_trials` keeps the first N.
pub fn load_data(
    path: &Path,
    config: &ModelConfig,
    max_trials: Option<usize>,
    quiet: bool,
) -> Result<DataSet> {
    let cfg = LabelConfig::default();
    let pb = bar(0, "loading", quiet);
    let trials = slipguard_data::load_path(path, &cfg, |done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    })
    .map_err(|e| ExportError::Data(format!("{}: {e}", path.display())))?;
    pb.finish_and_clear();
    let trials: Vec<_> = trials
        .into_iter()
        .take(max_trials.unwrap_or(usize::MAX))
        .collect();
    if trials.is_empty() {
        return Err(ExportError::Data(format!("{}: no trials", path.display())));
    }
    let mut out = DataSet {
        source: path.display().to_string(),
        trials: trials.len(),
        unlabelled: 0,
        sequences: Vec::new(),
        recordings: Vec::new(),
        hands: Vec::new(),
        rate_hz: trials[0].rate_hz,
        warnings: Vec::new(),
    };
    let model_rate = config.sample_rate_hz();
    // The data's rate and unit must be the model's: calibrating on other signals gives formats
    // (and a verification) for data the model never sees.
    let first = &trials[0];
    let unit_ok = match config.input_unit {
        slipguard_core::blob::InputUnit::Counts => first.unit == slipguard_data::Unit::Counts,
        _ => first.unit == slipguard_data::Unit::MilliNewton,
    };
    if (first.rate_hz - model_rate).abs() > 0.01 * model_rate || !unit_ok {
        return Err(ExportError::Data(format!(
            "{}: recordings at {} Hz in {} ({}), the model runs at {model_rate} Hz in {}: give recordings at the model's rate and unit",
            path.display(),
            first.rate_hz,
            first.unit,
            first.id,
            config.input_unit
        )));
    }
    for t in &trials {
        if t.contact.iter().any(|&c| c) {
            out.hands.push(crate::hand::HandRecording {
                trial_id: t.id.clone(),
                samples: t.samples.clone(),
                start: t.marks.grasp_start.unwrap_or(0).min(t.n_steps()),
                lift: t.marks.lift_start,
                end: match t.outcome {
                    Outcome::Failure => t.drop_step,
                    Outcome::Success => labels::detect_release(t, &cfg),
                    Outcome::Unknown => None,
                }
                .unwrap_or(t.n_steps()),
            });
        }
        for (c, samples) in t.samples.iter().enumerate() {
            if t.contact.get(c) == Some(&true) && !samples.is_empty() {
                out.recordings.push(ChannelSequence {
                    trial_id: t.id.clone(),
                    channel: c,
                    samples: samples.clone(),
                    labels: Vec::new(),
                    drop_index: None,
                    outcome: t.outcome,
                });
            }
        }
        let l = labels::label_annotated(t, &cfg);
        let seqs = labels::channel_sequences(t, &l);
        if seqs.is_empty() {
            out.unlabelled += 1;
            // Unlabelled trials still calibrate: their contact channels over the window.
            let start = t.marks.grasp_start.unwrap_or(0).min(t.n_steps());
            let end = (start + cfg.sequence_len).min(t.n_steps());
            for (c, s) in t.samples.iter().enumerate() {
                if t.contact.get(c) == Some(&true) {
                    out.sequences.push(ChannelSequence {
                        trial_id: t.id.clone(),
                        channel: c,
                        samples: s[start..end].to_vec(),
                        labels: Vec::new(),
                        drop_index: None,
                        outcome: Outcome::Unknown,
                    });
                }
            }
        }
        out.sequences.extend(seqs);
    }
    if out.sequences.is_empty() {
        return Err(ExportError::Data(format!(
            "{}: {} trials but no channel with contact to calibrate on",
            path.display(),
            out.trials
        )));
    }
    Ok(out)
}

impl DataSet {
    /// Splits off every `every`-th trial as a held-out part: (the rest, the held-out part).
    /// Failures and the other trials are counted separately (in load order, the last of each
    /// group of `every`), so that both kinds are held out when there are enough of them; with
    /// fewer than `every` trials in all, the last one is held out. `None` with fewer than 2.
    pub fn split_holdout(&self, every: usize) -> Option<(DataSet, DataSet)> {
        let mut ids: Vec<(&str, bool)> = Vec::new();
        for s in self.recordings.iter().chain(&self.sequences) {
            if !ids.iter().any(|(id, _)| *id == s.trial_id) {
                ids.push((&s.trial_id, s.outcome == Outcome::Failure));
            }
        }
        if ids.len() < 2 || every < 2 {
            return None;
        }
        let mut held: Vec<&str> = Vec::new();
        for failure in [true, false] {
            let group: Vec<&str> = ids
                .iter()
                .filter(|(_, f)| *f == failure)
                .map(|(id, _)| *id)
                .collect();
            held.extend(
                group
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| i % every == every - 1)
                    .map(|(_, id)| *id),
            );
        }
        if held.is_empty() {
            held.push(ids[ids.len() - 1].0);
        }
        let ids: Vec<&str> = ids.iter().map(|(id, _)| *id).collect();
        let part = |keep: bool, what: &str| {
            let pick = |v: &[ChannelSequence]| -> Vec<ChannelSequence> {
                v.iter()
                    .filter(|s| held.contains(&s.trial_id.as_str()) == keep)
                    .cloned()
                    .collect()
            };
            let n = if keep {
                held.len()
            } else {
                ids.len() - held.len()
            };
            DataSet {
                source: format!("{}, {what}", self.source),
                trials: n,
                unlabelled: 0,
                sequences: pick(&self.sequences),
                recordings: pick(&self.recordings),
                hands: self
                    .hands
                    .iter()
                    .filter(|h| held.contains(&h.trial_id.as_str()) == keep)
                    .cloned()
                    .collect(),
                rate_hz: self.rate_hz,
                warnings: self.warnings.clone(),
            }
        };
        let rest = part(
            false,
            &format!(
                "all but every {every}th trial ({} trials)",
                ids.len() - held.len()
            ),
        );
        let held_out = part(
            true,
            &format!(
                "held out: every {every}th trial ({} trials: {})",
                held.len(),
                held.join(", ")
            ),
        );
        Some((rest, held_out))
    }
}

/// What the float model does on the calibration data.
#[derive(Clone, Debug, Serialize)]
pub struct Calibration {
    /// Sequences and steps run.
    pub sequences: usize,
    /// Steps run.
    pub steps: usize,
    /// Largest |c| per LSTM.
    pub max_abs_cell: Vec<f32>,
    /// Chosen cell fractional bits per LSTM (c is Q(15-C).C).
    pub cell_frac_bits: Vec<u8>,
    /// Largest |h| per LSTM (Q0.15 holds up to 1).
    pub max_abs_hidden: Vec<f32>,
    /// Share of raw samples outside the Q1.15 input range (saturated).
    pub input_saturated: f64,
    /// Per feature: share of normalised values clipped at ±8σ (Q3.12 range).
    pub feature_clipped: Vec<f64>,
    /// Per feature: largest |normalised value|.
    pub feature_max_abs: Vec<f32>,
}

/// Runs the float model over the sequences and picks the cell formats (unless `fixed`).
pub fn calibrate(
    model: &FloatModel,
    seqs: &[&[f32]],
    fixed: Option<[u8; 2]>,
    quiet: bool,
) -> Calibration {
    let n_lstm = model.lstms.len();
    let nf = model.config.feature_count();
    let mut max_c = vec![0f32; n_lstm];
    let mut max_h = vec![0f32; n_lstm];
    let mut clipped = vec![0usize; nf];
    let mut fmax = vec![0f32; nf];
    let (mut steps, mut saturated) = (0usize, 0usize);
    let scale = InputScale::of(&model.config);
    let pb = bar(seqs.len(), "calibrating", quiet);
    for seq in seqs {
        let mut st = model.new_channel();
        for &raw in *seq {
            let x = (raw - scale.offset as f32) / scale.full_scale as f32;
            if !(-1.0..32767.0 / 32768.0).contains(&x) {
                saturated += 1;
            }
            let v = model.features(&mut st, raw);
            for (j, &f) in v.iter().enumerate() {
                fmax[j] = fmax[j].max(f.abs());
                if f.abs() >= 8.0 {
                    clipped[j] += 1;
                }
            }
            model.logits(&mut st, &v);
            for (k, s) in st.lstm.iter().enumerate() {
                max_c[k] = s.c.iter().fold(max_c[k], |a, c| a.max(c.abs()));
                max_h[k] = s.h.iter().fold(max_h[k], |a, h| a.max(h.abs()));
            }
            steps += 1;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let bits = (0..n_lstm)
        .map(|k| match fixed {
            Some(b) => b[k].clamp(1, 15),
            None if steps == 0 => DEFAULT_CELL_FRAC_BITS,
            None => cell_bits_for(max_c[k] * CELL_HEADROOM),
        })
        .collect();
    let share = |n: usize| {
        if steps == 0 {
            0.0
        } else {
            n as f64 / steps as f64
        }
    };
    Calibration {
        sequences: seqs.len(),
        steps,
        max_abs_cell: max_c,
        cell_frac_bits: bits,
        max_abs_hidden: max_h,
        input_saturated: share(saturated),
        feature_clipped: clipped.into_iter().map(share).collect(),
        feature_max_abs: fmax,
    }
}

/// Paper metrics of one model on the labelled sequences.
#[derive(Clone, Debug, Serialize)]
pub struct PaperMetrics {
    /// Evaluated steps.
    pub evaluated_steps: usize,
    /// Success rate (correct steps / evaluated steps).
    pub success_rate: Option<f64>,
    /// Ahead-drop rate (failure sequences flagged before the drop).
    pub ahead_drop_rate: Option<f64>,
    /// False-alarm rate (success sequences with any unstable flag).
    pub false_alarm_rate: Option<f64>,
    /// Failure sequences with a drop inside the window.
    pub failure_sequences: usize,
}

impl From<&Metrics> for PaperMetrics {
    fn from(m: &Metrics) -> Self {
        Self {
            evaluated_steps: m.evaluated_steps,
            success_rate: m.success_rate,
            ahead_drop_rate: m.ahead_drop_rate,
            false_alarm_rate: m.false_alarm_rate,
            failure_sequences: m.failure_sequences,
        }
    }
}

/// Agreement of the quantized blob with the float model.
#[derive(Clone, Debug, Serialize)]
pub struct Agreement {
    /// Sequences compared.
    pub sequences: usize,
    /// Steps compared.
    pub steps: usize,
    /// Share of steps whose flag (threshold + hysteresis) is the same.
    pub flag_agreement: f64,
    /// Steps whose flags differ.
    pub flag_disagreements: usize,
    /// Steps at which the float p, over the hysteresis window ending there, stays at least
    /// [`DECISIVE_MARGIN`] from the threshold (a flag there does not hinge on rounding).
    pub decisive_steps: usize,
    /// Flag agreement over the decisive steps (what `verify` checks).
    pub decisive_flag_agreement: f64,
    /// Largest |p_q − p_f|.
    pub max_abs_dp: f32,
    /// Where it is: trial, channel and step (0 = the recording's first sample).
    pub worst: Option<WorstStep>,
    /// Mean |p_q − p_f|.
    pub mean_abs_dp: f32,
    /// Largest |h_q − h_f| over every hidden unit.
    pub max_abs_dh: f32,
    /// Paper metrics of the float model (labelled sequences only).
    pub float_metrics: Option<PaperMetrics>,
    /// Paper metrics of the quantized model.
    pub quant_metrics: Option<PaperMetrics>,
}

impl Agreement {
    /// Change in success rate (quantized − float), percentage points.
    pub fn success_rate_change(&self) -> Option<f64> {
        Some(
            100.0
                * (self.quant_metrics.as_ref()?.success_rate?
                    - self.float_metrics.as_ref()?.success_rate?),
        )
    }
    /// Change in ahead-drop rate (quantized − float), percentage points.
    pub fn ahead_drop_change(&self) -> Option<f64> {
        Some(
            100.0
                * (self.quant_metrics.as_ref()?.ahead_drop_rate?
                    - self.float_metrics.as_ref()?.ahead_drop_rate?),
        )
    }
}

/// Distance of p from the threshold below which a flag difference is a rounding tie.
pub const DECISIVE_MARGIN: f32 = 0.02;

/// `export` warns and `verify` fails (exit 13) above this max |Δp| over the data.
pub const MAX_DP: f32 = 0.05;
/// `export` warns and `verify` fails (exit 13) below this flag agreement on decisive steps.
pub const MIN_DECISIVE_AGREEMENT: f64 = 0.995;

/// The step with the largest |Δp|.
#[derive(Clone, Debug, Serialize)]
pub struct WorstStep {
    /// Trial id.
    pub trial: String,
    /// Channel.
    pub channel: usize,
    /// Step in the compared sequence (for whole recordings: from the recording's first sample).
    pub step: usize,
    /// The float model's p there.
    pub p_float: f32,
    /// The blob's p there.
    pub p_quantized: f32,
}

impl Agreement {
    /// The bounds `export` warns at and `verify` fails at: `None` when within them, else what
    /// is over.
    pub fn over_bounds(&self, max_dp: f32, min_decisive: f64) -> Option<String> {
        let mut over = Vec::new();
        if self.max_abs_dp > max_dp {
            let at = self.worst.as_ref().map_or(String::new(), |w| {
                format!(
                    " at trial {} channel {} step {} (float p {:.3}, blob p {:.3})",
                    w.trial, w.channel, w.step, w.p_float, w.p_quantized
                )
            });
            over.push(format!("max |Δp| {:.4} > {max_dp}{at}", self.max_abs_dp));
        }
        if self.decisive_flag_agreement < min_decisive {
            over.push(format!(
                "flag agreement on steps ≥ {DECISIVE_MARGIN} from the threshold {:.3} % < {:.1} %",
                100.0 * self.decisive_flag_agreement,
                100.0 * min_decisive
            ));
        }
        (!over.is_empty()).then(|| over.join("; "))
    }
}

/// Runs both models over every step of every whole recording of `data` (from a reset state
/// each) and compares them; the paper's metrics come from the labelled windows.
pub fn agreement(
    float: &FloatModel,
    blob: &[u8],
    data: &DataSet,
    quiet: bool,
) -> Result<Agreement> {
    if float.config.variant.is_hand() {
        return crate::hand::agreement(float, blob, &data.hands);
    }
    let mut a = compare(float, blob, &data.recordings, quiet)?;
    let windows = compare(float, blob, &data.sequences, true)?;
    a.float_metrics = windows.float_metrics;
    a.quant_metrics = windows.quant_metrics;
    Ok(a)
}

/// One sequence's part of [`compare`], combined in the sequences' order.
struct SeqCompare {
    /// |Δp| per step, in step order (summed in order, so the mean is the sequential one).
    dps: Vec<f32>,
    /// The sequence's largest |Δp| and the first step that reaches it.
    max_dp: f32,
    worst: Option<WorstStep>,
    max_dh: f32,
    disagree: usize,
    decisive: usize,
    decisive_disagree: usize,
    ev: Option<(EvalSequence, EvalSequence)>,
}

/// Sequences per batch of the quantized model in [`compare`] (one rayon task each).
const COMPARE_BATCH: usize = 64;

/// Runs both models over every sequence (from a reset state each) and compares them. The
/// quantized model runs batched ([`slipguard_batch`], bit-exact with `Model::step`),
/// [`COMPARE_BATCH`] sequences at a time, the batches in parallel (rayon); the float model
/// steps beside it, and the per-sequence results are combined in the sequences' order, so the
/// agreement is the same for any thread count.
pub fn compare(
    float: &FloatModel,
    blob: &[u8],
    seqs: &[ChannelSequence],
    quiet: bool,
) -> Result<Agreement> {
    use rayon::prelude::*;
    let aligned = AlignedBlob::new(blob);
    let model = Model::from_bytes(aligned.as_bytes()).map_err(|e| ExportError::Blob {
        path: "(exported blob)".into(),
        source: e,
    })?;
    let batch = BatchModel::new(&model).map_err(|e| ExportError::Data(e.to_string()))?;
    let rate = float.config.sample_rate_hz() as f64;
    let th = float.config.threshold_q15 as f32 / 32768.0;
    let window = float
        .config
        .raise_after
        .max(float.config.clear_after)
        .max(1) as usize;
    let pb = bar(seqs.len(), "comparing", quiet);
    let parts: Vec<SeqCompare> = seqs
        .par_chunks(COMPARE_BATCH)
        .flat_map_iter(|chunk| {
            let r = compare_chunk(float, &batch, chunk, th, window, rate);
            pb.inc(chunk.len() as u64);
            r
        })
        .collect();
    pb.finish_and_clear();
    let (mut steps, mut disagree) = (0usize, 0usize);
    let (mut decisive, mut decisive_disagree) = (0usize, 0usize);
    let (mut max_dp, mut sum_dp, mut max_dh) = (0f32, 0f64, 0f32);
    let mut worst = None;
    let (mut ev_f, mut ev_q) = (Vec::new(), Vec::new());
    for p in parts {
        // The first step (in sequence order) that reaches the largest |Δp|, as one pass
        // over all steps finds it.
        if p.worst.is_some() && (p.max_dp > max_dp || worst.is_none()) {
            worst = p.worst;
        }
        max_dp = max_dp.max(p.max_dp);
        for &d in &p.dps {
            sum_dp += d as f64;
        }
        steps += p.dps.len();
        max_dh = max_dh.max(p.max_dh);
        disagree += p.disagree;
        decisive += p.decisive;
        decisive_disagree += p.decisive_disagree;
        if let Some((f, q)) = p.ev {
            ev_f.push(f);
            ev_q.push(q);
        }
    }
    if steps == 0 {
        return Err(ExportError::Data("no steps to compare".into()));
    }
    let (fm, qm) = if ev_f.is_empty() {
        (None, None)
    } else {
        let ec = EventConfig::default();
        (
            Some(PaperMetrics::from(&evaluate(&ev_f, ec))),
            Some(PaperMetrics::from(&evaluate(&ev_q, ec))),
        )
    };
    Ok(Agreement {
        sequences: seqs.len(),
        steps,
        flag_agreement: 1.0 - disagree as f64 / steps as f64,
        flag_disagreements: disagree,
        decisive_steps: decisive,
        decisive_flag_agreement: if decisive == 0 {
            1.0
        } else {
            1.0 - decisive_disagree as f64 / decisive as f64
        },
        max_abs_dp: max_dp,
        worst,
        mean_abs_dp: (sum_dp / steps as f64) as f32,
        max_abs_dh: max_dh,
        float_metrics: fm,
        quant_metrics: qm,
    })
}

/// [`compare`] of one batch of sequences: the quantized lanes step together, each lane's
/// float model beside it.
fn compare_chunk(
    float: &FloatModel,
    batch: &BatchModel<'_>,
    seqs: &[ChannelSequence],
    th: f32,
    window: usize,
    rate: f64,
) -> Vec<SeqCompare> {
    let lanes = seqs.len();
    let mut qs = batch.state(lanes);
    let mut fs: Vec<_> = seqs.iter().map(|_| float.new_channel()).collect();
    let mut parts: Vec<SeqCompare> = seqs
        .iter()
        .map(|s| SeqCompare {
            dps: Vec::with_capacity(s.samples.len()),
            max_dp: 0.0,
            worst: None,
            max_dh: 0.0,
            disagree: 0,
            decisive: 0,
            decisive_disagree: 0,
            ev: None,
        })
        .collect();
    let mut pf: Vec<Vec<Stability>> = seqs.iter().map(|_| Vec::new()).collect();
    let mut pq = pf.clone();
    // Steps since p was last within the margin, per lane.
    let mut close_run = vec![usize::MAX; lanes];
    let steps = seqs.iter().map(|s| s.samples.len()).max().unwrap_or(0);
    let (mut raw, mut active) = (vec![0i32; lanes], vec![false; lanes]);
    let mut out = vec![
        StepOutput {
            p_unstable_q15: 0,
            unstable: false
        };
        lanes
    ];
    let st = |u: bool| {
        if u {
            Stability::Unstable
        } else {
            Stability::Stable
        }
    };
    for i in 0..steps {
        for (l, s) in seqs.iter().enumerate() {
            active[l] = i < s.samples.len();
            raw[l] = s.samples.get(i).map_or(0, |x| x.round() as i32);
        }
        batch.step_masked(&mut qs, &raw, &active, &mut out);
        for (l, s) in seqs.iter().enumerate().filter(|(l, _)| active[*l]) {
            let part = &mut parts[l];
            let f = float.step(&mut fs[l], s.samples[i]);
            let q = out[l];
            let p = q.p_unstable_q15 as f32 / 32768.0;
            let dp = (p - f.p_unstable).abs();
            if dp > part.max_dp || part.worst.is_none() {
                part.worst = Some(WorstStep {
                    trial: s.trial_id.clone(),
                    channel: s.channel,
                    step: i,
                    p_float: f.p_unstable,
                    p_quantized: p,
                });
            }
            part.max_dp = part.max_dp.max(dp);
            part.dps.push(dp);
            for (k, fl) in float.lstms.iter().enumerate() {
                for j in 0..fl.hidden {
                    let dh = (qs.h(l, k, j) as f32 / 32768.0 - fs[l].lstm[k].h[j]).abs();
                    part.max_dh = part.max_dh.max(dh);
                }
            }
            if f.unstable != q.unstable {
                part.disagree += 1;
            }
            close_run[l] = if (f.p_unstable - th).abs() < DECISIVE_MARGIN {
                0
            } else {
                close_run[l].saturating_add(1)
            };
            if close_run[l] >= window {
                part.decisive += 1;
                if f.unstable != q.unstable {
                    part.decisive_disagree += 1;
                }
            }
            pf[l].push(st(f.unstable));
            pq[l].push(st(q.unstable));
        }
    }
    for (l, s) in seqs.iter().enumerate() {
        if !s.labels.is_empty() && s.labels.len() == pf[l].len() {
            let failure = s.outcome == Outcome::Failure;
            parts[l].ev = Some((
                EvalSequence::new(&s.labels, &pf[l], s.drop_index, failure, rate),
                EvalSequence::new(&s.labels, &pq[l], s.drop_index, failure, rate),
            ));
        }
    }
    parts
}

/// Wraps raw sample sequences (no labels) for [`agreement`].
pub fn unlabelled(seqs: &[Vec<f32>]) -> Vec<ChannelSequence> {
    seqs.iter()
        .enumerate()
        .map(|(i, s)| ChannelSequence {
            trial_id: format!("seq{i}"),
            channel: 0,
            samples: s.clone(),
            labels: Vec::new(),
            drop_index: None,
            outcome: Outcome::Unknown,
        })
        .collect()
}
