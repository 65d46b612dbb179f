//! The hand-level model (`hand-lstm`): its training sequences, training and quantization.
//!
//! One sequence per grasp, not per channel: the hand feature rows the firmware computes
//! ([`slipguard_core::float::hand_feature_rows`]: every channel through the contact gate from
//! the grasp start, the lift command at the trial's lift mark) from the grasp start to the end
//! of the armed window: the drop of a failure, the release of a success (the trial's end when
//! the grip holds to it). After that the hand opens or the object is gone, and nothing there
//! is scored, so nothing there is trained on.
//!
//! The target rewards an early warning in the armed window: a failure's frames from `lead`
//! frames before the drop on are unstable, everything else stable; the loss weighs the two
//! classes by [`crate::train::TrainConfig::class_weights`].
//!
//! Augmentation of the real drops: the lift mark of a recording with estimated marks is within
//! 2 frames of the true one in half of the trials (data/eagle-shoal/README.md), so every
//! training grasp is also taken with its lift mark moved by each of `lift_jitter` frames (the
//! rows change where the hand's lift reference and the `lifted` input do).

use slipguard_core::blob::ModelConfig;
use slipguard_core::float::{FloatModel, hand_feature_rows};
use slipguard_data::Trial;
use slipguard_data::labels::LabelConfig;
use slipguard_data::trial::Outcome;

use crate::error::{LearnError, Result};
use crate::product::{ArmedError, armed_window};

/// One grasp's training sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct HandSequence {
    /// Trial id.
    pub trial_id: String,
    /// The grasp setting (object, force, weight) the trial repeats.
    pub setting: String,
    /// The object was dropped.
    pub failure: bool,
    /// Lift mark used, frames after the sequence start (`None`: no lift mark).
    pub lift: Option<usize>,
    /// Its shift from the trial's own lift mark, frames (0: the trial as recorded).
    pub jitter: i64,
    /// Raw hand feature rows from the grasp start to the armed window's end.
    pub rows: Vec<Vec<f32>>,
    /// Training label per row: 1 from `lead` frames before the drop, else 0.
    pub labels: Vec<u32>,
}

/// How the training sequences are cut and labelled.
#[derive(Clone, Debug, PartialEq)]
pub struct HandTarget {
    /// A failure's frames from this many before the drop on are unstable.
    pub lead: usize,
    /// Lift-mark shifts (frames, ≠ 0) each training grasp is also taken with.
    pub lift_jitter: Vec<i64>,
}

/// The hand-level sequences of `trials` for `config` (a hand-lstm header), and the trials that
/// cannot be scored (a failure without a drop, named; trials without contact are left out
/// silently, as the armed window does). Each trial once with its own lift mark, then once per
/// shift of `target.lift_jitter`.
pub fn hand_sequences(
    config: &ModelConfig,
    trials: &[&Trial],
    cfg: &LabelConfig,
    target: &HandTarget,
) -> Result<(Vec<HandSequence>, Vec<ArmedError>)> {
    if !config.variant.is_hand() {
        return Err(LearnError::Training(format!(
            "hand sequences need a hand-level model, not {}",
            config.variant
        )));
    }
    let (mut out, mut skipped) = (Vec::new(), Vec::new());
    for t in trials {
        let (_, end) = match armed_window(t, cfg) {
            Ok(Some(w)) => w,
            Ok(None) => continue,
            Err(e @ (ArmedError::NoDrop { .. } | ArmedError::DropBeforeLift { .. })) => {
                skipped.push(e);
                continue;
            }
            Err(e) => return Err(LearnError::Training(e.to_string())),
        };
        let start = t.marks.grasp_start.unwrap_or(0).min(t.n_steps());
        let shifts = std::iter::once(0).chain(target.lift_jitter.iter().copied());
        for shift in shifts {
            let lift = t
                .marks
                .lift_start
                .map(|l| (l as i64 + shift).clamp(start as i64, end.max(start) as i64) as usize);
            let mut rows = hand_feature_rows(config, &t.samples, start, lift);
            rows.truncate(end.saturating_sub(start));
            if rows.is_empty() {
                continue;
            }
            let failure = t.outcome == Outcome::Failure;
            let drop = end - start;
            let labels = (0..rows.len())
                .map(|i| u32::from(failure && i + target.lead >= drop))
                .collect();
            out.push(HandSequence {
                trial_id: t.id.clone(),
                setting: t.grasp_setting(),
                failure,
                lift: lift.map(|l| l - start),
                jitter: shift,
                rows,
                labels,
            });
        }
    }
    Ok((out, skipped))
}

/// A fresh hand model for `config` (PyTorch-like init with `seed`) with its normalisation
/// fitted on the rows of `seqs`.
pub fn init_hand_model(config: ModelConfig, seed: u64, seqs: &[&HandSequence]) -> FloatModel {
    let mut m = FloatModel::init_like_pytorch(config, seed);
    let rows: Vec<&[Vec<f32>]> = seqs.iter().map(|s| s.rows.as_slice()).collect();
    m.fit_normalisation_rows(&rows);
    m
}

/// Normalised rows and labels of `seqs` for the trainer.
#[cfg(feature = "train")]
fn prepared(model: &FloatModel, seqs: &[&HandSequence]) -> crate::train::Prepared {
    crate::train::Prepared {
        feats: seqs
            .iter()
            .map(|s| {
                s.rows
                    .iter()
                    .map(|r| {
                        let mut v = r.clone();
                        model.normalise(&mut v);
                        v
                    })
                    .collect()
            })
            .collect(),
        labels: seqs.iter().map(|s| s.labels.clone()).collect(),
    }
}

/// Trains `init` on the hand sequences `train`, early-stopping on `val` (the trainer of the
/// per-channel variants on hand rows: same loss, optimiser and stopping).
#[cfg(feature = "train")]
pub fn train_hand(
    init: &FloatModel,
    train: &[&HandSequence],
    val: &[&HandSequence],
    cfg: &crate::train::TrainConfig,
    progress: impl FnMut(crate::train::Progress<'_>),
) -> Result<crate::train::TrainOutcome> {
    let pt = prepared(init, train);
    let pv = prepared(init, val);
    crate::train::train_prepared(init, &pt, &pv, cfg, progress)
}

/// Sequences of calibration rows the quantizer sees (the first of the training set).
pub const CALIBRATION_SEQUENCES: usize = 64;

/// The blob of a hand model, its cell format calibrated on the first
/// [`CALIBRATION_SEQUENCES`] of `calib`.
pub fn quantize_hand(model: &FloatModel, calib: &[&HandSequence]) -> Result<Vec<u8>> {
    let rows: Vec<&[Vec<f32>]> = calib
        .iter()
        .take(CALIBRATION_SEQUENCES)
        .map(|s| s.rows.as_slice())
        .collect();
    Ok(slipguard_core::quantize::quantize_rows(model, &rows, None)?.0)
}

/// Splits hand sequences into (train, validation) by trial: about `share` of the failure
/// trials and of the success trials go to validation (at least one failure if there are two
/// or more), by a seeded shuffle; every copy of a trial goes with it.
pub fn split_hand_by_trial<'a>(
    seqs: &[&'a HandSequence],
    share: f64,
    seed: u64,
) -> (Vec<&'a HandSequence>, Vec<&'a HandSequence>) {
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    let ids = |failure: bool| {
        let mut v: Vec<&str> = seqs
            .iter()
            .filter(|s| s.failure == failure)
            .map(|s| s.trial_id.as_str())
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let (mut fail, mut succ) = (ids(true), ids(false));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x0a11_da7a);
    fail.shuffle(&mut rng);
    succ.shuffle(&mut rng);
    let take = |v: &[&str], min1: bool| -> Vec<String> {
        let mut k = (v.len() as f64 * share).round() as usize;
        if min1 && v.len() >= 2 {
            k = k.max(1);
        }
        v[..k.min(v.len())].iter().map(|s| s.to_string()).collect()
    };
    let mut val_ids = take(&fail, share > 0.0);
    val_ids.extend(take(&succ, share > 0.0));
    seqs.iter()
        .partition(|s| !val_ids.iter().any(|v| v == &s.trial_id))
}

/// The paper's per-step metrics for a hand-level model: one sequence per grasp, from the
/// grasp start over the paper's window ([`slipguard_data::labels::label_annotated`]: the
/// trial-level labels, unstable from 1.2 s before the drop), its flag per step the model's own
/// hand decision (threshold and hysteresis, no rule): the quantized blob as the firmware runs
/// it ([`crate::product::run_trial`]) when `quantized` is given, else the float model on the
/// same hand feature rows. Trials without labels or contact are left out.
pub fn paper_sequences(
    float: &FloatModel,
    quantized: Option<&slipguard_core::model::Model<'_>>,
    trials: &[&Trial],
    cfg: &LabelConfig,
) -> Vec<slipguard_data::metrics::EvalSequence> {
    use slipguard_core::decision::{ContactConfig, DecisionConfig, DecisionState, HandConfig};
    use slipguard_data::labels::{LabelStatus, label_annotated};
    use slipguard_data::trial::Stability;
    let stab = |u: bool| {
        if u {
            Stability::Unstable
        } else {
            Stability::Stable
        }
    };
    trials
        .iter()
        .filter(|t| t.contact.iter().any(|&c| c))
        .filter_map(|t| {
            let l = label_annotated(t, cfg);
            if l.status != LabelStatus::Labelled || l.steps.is_empty() {
                return None;
            }
            let (s0, n) = (l.seq_start, l.seq_len);
            let flags: Vec<bool> = match quantized {
                Some(m) => {
                    let run = crate::product::run_trial(
                        m,
                        t,
                        &ContactConfig::of(m.config()),
                        &HandConfig::of(m.config()),
                    );
                    run.model_flag[s0..s0 + n].to_vec()
                }
                None => {
                    let rows = hand_feature_rows(&float.config, &t.samples, s0, t.marks.lift_start);
                    let d = DecisionConfig::of(&float.config);
                    let mut st = float.new_channel();
                    let mut ds = DecisionState::default();
                    rows.iter()
                        .take(n)
                        .map(|r| {
                            let p = float.step_row(&mut st, r).p_unstable;
                            d.update(&mut ds, (p * 32768.0).round().min(32767.0) as i16)
                        })
                        .collect()
                }
            };
            let preds: Vec<Stability> = flags.into_iter().map(stab).collect();
            Some(slipguard_data::metrics::EvalSequence::new(
                &l.steps,
                &preds,
                l.drop_index(),
                t.outcome == Outcome::Failure,
                t.rate_hz as f64,
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use slipguard_core::blob::{InputUnit, Variant};
    use slipguard_core::features::stft::StftConfig;
    use slipguard_core::units::Millihertz;
    use slipguard_data::trial::{PhaseMarks, Unit};

    fn config() -> ModelConfig {
        ModelConfig {
            model_id: 0,
            name: [0; 12],
            variant: Variant::HandLstm,
            force_diff: false,
            sample_rate_mhz: Millihertz(16_700),
            input_unit: InputUnit::MilliNewton,
            input_offset: 0,
            input_full_scale: 32_768,
            stft: StftConfig::PAPER,
            hidden: [8, 0],
            cell_frac_bits: [0, 0],
            threshold_q15: 16_384,
            raise_after: 1,
            clear_after: 1,
            hand_rule: None,
        }
    }

    /// Two pads: load from 10, lift at 20, drop (failure) or hold (success).
    fn trial(id: &str, failure: bool) -> Trial {
        let n = 80;
        let pad = |k: f32| -> Vec<f32> {
            (0..n)
                .map(|t| {
                    if t < 10 || (failure && t >= 45) {
                        0.0
                    } else {
                        k * (t as f32).min(30.0) * 100.0
                    }
                })
                .collect()
        };
        let mut t = Trial::new(id, Unit::MilliNewton, 16.7, vec![pad(1.0), pad(0.5)]);
        t.marks = PhaseMarks {
            grasp_start: Some(5),
            lift_start: Some(20),
            open_start: Some(70),
            release: None,
        };
        t.outcome = if failure {
            Outcome::Failure
        } else {
            Outcome::Success
        };
        slipguard_data::labels::annotate(&mut t, &LabelConfig::default());
        t
    }

    #[test]
    fn a_failure_is_cut_at_its_drop_and_unstable_for_lead_frames_before_it() {
        let f = trial("Cheez_1_2_top_0", true);
        let s = trial("Cheez_1_2_top_1", false);
        let drop = f.drop_step.unwrap();
        assert_eq!(drop, 45);
        let target = HandTarget {
            lead: 10,
            lift_jitter: vec![-2, 2],
        };
        let (seqs, skipped) =
            hand_sequences(&config(), &[&f, &s], &LabelConfig::default(), &target).unwrap();
        assert!(skipped.is_empty());
        // Each trial with its lift mark and the two shifts.
        assert_eq!(seqs.len(), 6);
        let fs = &seqs[0];
        assert_eq!(fs.rows.len(), drop - 5);
        assert_eq!(fs.labels.iter().filter(|&&l| l == 1).count(), 10);
        assert_eq!(fs.labels[drop - 5 - 11], 0);
        assert_eq!(fs.lift, Some(15));
        assert_eq!((seqs[1].lift, seqs[2].lift), (Some(13), Some(17)));
        assert_eq!(fs.setting, "Cheez_1_2");
        // The success: no unstable label, rows up to the end (the grip holds to it).
        let ss = &seqs[3];
        assert!(ss.labels.iter().all(|&l| l == 0));
        assert_eq!(ss.rows.len(), 80 - 5);
        // The rows are the firmware's: the lifted input rises at the lift mark.
        assert_eq!(fs.rows[14][16], 0.0);
        assert_eq!(fs.rows[15][16], 4096.0 / 32768.0);
        // Split by trial keeps a trial's copies together.
        let refs: Vec<&HandSequence> = seqs.iter().collect();
        let (tr, val) = split_hand_by_trial(&refs, 0.5, 1);
        for v in &val {
            assert!(tr.iter().all(|t| t.trial_id != v.trial_id));
        }
        assert_eq!(tr.len() + val.len(), 6);
    }
}
