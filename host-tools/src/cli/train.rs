//! `slipguard train`: the paper's four variants with candle; cross-validation by trial,
//! simulated pre-training and mixing, float checkpoints and quantized blobs.
use slipguard_app::profile::{Profile, ProfileId, ProfileQuery};
use slipguard_core::units::Millihertz;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use slipguard_core::blob::Variant;
use slipguard_core::decision::{ContactConfig, DecisionConfig, Q15};
use slipguard_core::float::FloatModel;
use slipguard_core::sample::PAPER_RATE_HZ;
use slipguard_data::Trial;
use slipguard_data::labels::{ChannelSequence, LabelConfig};
use slipguard_learn::checkpoint::{self, Checkpoint};
use slipguard_learn::closed_loop::{TrainingConfig as ClosedLoopTraining, training_sequences};
use slipguard_learn::evaluation::{
    self as ev, Kind, Sequence, decide, metrics_of, probabilities, quantize_model, set_decision,
    tune_decision, with_quantized_model,
};
use slipguard_learn::product::{self, OnsetRule};
use slipguard_learn::qat::{QatConfig, blob_agreement, qat_finetune};
use slipguard_learn::train::{EpochLog, Progress, TrainConfig, init_model, split_by_trial, train};
use slipguard_learn::training_data::{self, SimRecipe, TrainingSets};

use super::progress::bar;
use super::{check, load_real_trials};

mod hand;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Labelled recordings or real data (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal);
    /// their rate and unit decide the model's (one rate and one unit per folder).
    pub path: Option<PathBuf>,
    /// Output folder (checkpoints, blobs, logs).
    #[arg(long)]
    pub out: PathBuf,
    /// Sensor: force (the hand profile: fingertip force in mN, 16.7 or 40 Hz; recordings or the
    /// real eagle-shoal trials, + simulated force) or suction (the suction profile: cup pressure
    /// in 1/16 ADC counts, 71 Hz; recordings + simulated suction). Default: the profile of the
    /// data's unit; a value that differs from the data's is refused.
    #[arg(long = "sensor", value_parser = check::sensor())]
    pub sensor_arg: Option<ProfileId>,
    /// The profile trained for (--sensor, else the data's).
    #[arg(skip = ProfileId::Hand)]
    pub sensor: ProfileId,
    /// Variants, comma separated: lstm, stft-lstm, data-stft-lstm, lstm-stft-lstm (the paper's,
    /// per channel), or all of those; or hand-lstm alone (one LSTM over the hand features of
    /// every contact channel together, blob format v3).
    #[arg(long, default_value = "all")]
    pub variant: String,
    /// Add the force difference d(t) = x(t) - x(t-1) (paper eq. 3) as an input.
    #[arg(long)]
    pub force_diff: bool,
    /// LSTM hidden size (each LSTM of the dual variant), 1…128 (the firmware's bound).
    #[arg(long, allow_negative_numbers = true, default_value_t = 128, value_parser = clap::value_parser!(u16).range(1..=slipguard_core::MAX_HIDDEN as i64))]
    pub hidden: u16,
    /// Learning rate (Adam), > 0.
    #[arg(long, allow_negative_numbers = true, default_value_t = 6e-4, value_parser = check::positive)]
    pub lr: f64,
    /// Training epochs (≥ 1; 0 with --init: no float training, e.g. QAT alone).
    #[arg(long, allow_negative_numbers = true, default_value_t = 60, value_parser = check::usize_in!(0..))]
    pub epochs: usize,
    /// Start the (fine-)tuning from this checkpoint's weights and normalisation instead of a
    /// fresh or pre-trained model (pre-training is skipped).
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Early stopping: epochs without a better validation loss.
    #[arg(long, allow_negative_numbers = true, default_value_t = 10, value_parser = check::usize_in!(0..))]
    pub patience: usize,
    /// Sequences per batch (≥ 1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 32, value_parser = check::usize_in!(1..))]
    pub batch: usize,
    /// Seed of the weight initialisation and the batch order.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub seed: u64,
    /// Loss weights of the stable and unstable class, e.g. 1,2.
    #[arg(long, default_value = "1,1")]
    pub class_weights: String,
    /// Training labels are unstable from this many seconds before the drop, at every rate
    /// (paper: 1.2 s = 20 steps at 16.7 Hz; evaluation keeps the paper's 1.2 s).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.2, value_parser = check::seconds_in(0.0, 60.0))]
    pub label_lead_s: f32,
    /// Loss weight of the first --start-s seconds of every sequence (against start-up alarms).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0, value_parser = check::non_negative_f32)]
    pub start_weight: f32,
    /// Seconds at the start of every sequence that get --start-weight (0 = none).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0, value_parser = check::seconds_in(0.0, 60.0))]
    pub start_s: f32,
    /// Simulated trials for pre-training (0 = none); the model is then fine-tuned on real data.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub sim_pretrain: usize,
    /// Epochs of the pre-training (≥ 1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 15, value_parser = check::usize_in!(1..))]
    pub pretrain_epochs: usize,
    /// Simulated trials mixed into the (fine-)tuning set (suction: the whole training set).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub sim_mix: usize,
    /// Share of simulated trials drawn as drops (0…1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.3, value_parser = check::unit)]
    pub sim_failure_share: f64,
    /// Seed of the simulated training trials (pre-training uses it, mixing it + 1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 11)]
    pub sim_seed: u64,
    /// Simulated closed-loop trials (the four DoraHand situations, labelled with the true slip
    /// state, `slipguard_learn::closed_loop::training_sequences`) added to the pre-training.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub closed_loop_pretrain: usize,
    /// Simulated closed-loop trials mixed into the (fine-)tuning set (split by trial for early
    /// stopping like the real trials; the decision is still tuned on real trials only).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub closed_loop_mix: usize,
    /// Seed of the closed-loop training trials (pre-training uses it, mixing it + 1); keep it
    /// apart from the seeds `slipguard closed-loop` reports on.
    #[arg(long, allow_negative_numbers = true, default_value_t = 101)]
    pub closed_loop_seed: u64,
    /// Model frame rate, Hz: the data's (a value that differs from it is refused); without a
    /// data folder, force 16.7 (the real trials) or 40 (the hand profile's fast rate: simulated
    /// trials only), suction 71.
    #[arg(long = "rate-hz", allow_negative_numbers = true, value_parser = check::positive_f32)]
    pub rate_arg: Option<f32>,
    /// The rate trained at (--rate-hz, else the data's).
    #[arg(skip = PAPER_RATE_HZ)]
    pub rate_hz: f32,
    /// Closed-loop training labels: unstable when the object slips within this many seconds.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.3, value_parser = check::non_negative)]
    pub closed_loop_lead: f64,
    /// Closed-loop training trials: the teacher also raises the grip on false alarms, at a rate
    /// drawn per trial from 0 to this (per s), so the model learns that the pad force rising
    /// under its controller's raises is not slip (0 = none).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0, value_parser = check::non_negative)]
    pub closed_loop_false_alarms: f64,
    /// Closed-loop training trials: put this trained model blob in the loop instead of the
    /// teacher for --closed-loop-policy-share of the trials, so the data holds the states its
    /// own flags lead to (labels still come from the physics).
    #[arg(long)]
    pub closed_loop_policy: Option<PathBuf>,
    /// Share of the closed-loop training trials run with --closed-loop-policy (0…1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.5, value_parser = check::unit)]
    pub closed_loop_policy_share: f64,
    /// Cross-validation by trial with this many folds (0 = train one model on every trial;
    /// else 2 to the number of real trials).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub cv: usize,
    /// How --cv (and --tune-decision-cv) folds hold trials out: `trial`, or `setting` (every
    /// trial of a grasp setting, object + force + weight, in one fold: what to expect on a new
    /// object or weight).
    #[arg(long, default_value_t = ev::CvGrouping::Trial)]
    pub cv_by: ev::CvGrouping,
    /// hand-lstm: every training grasp is also taken with its lift mark moved by each of these
    /// frames (comma-separated, e.g. -2,-1,1,2; none by default): the estimated marks' error.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub lift_jitter: Vec<i64>,
    /// Share of the training trials held out (by trial) for early stopping (0 ≤ x < 1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.2, value_parser = check::share_below_one)]
    pub val_share: f64,
    /// Decision threshold on p(unstable), 0 < threshold < 1.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.5, value_parser = check::open_unit)]
    pub threshold: f64,
    /// Steps at or above the threshold before the flag rises (1…255).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..))]
    pub raise_after: u8,
    /// Steps below the threshold before the flag clears (1…255).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..))]
    pub clear_after: u8,
    /// Pick threshold and hysteresis on the validation trials (overrides the three above).
    #[arg(long)]
    pub tune_decision: bool,
    /// With --tune-decision: smallest raise_after the sweep may pick (suppresses start-up blips).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..))]
    pub min_raise: u8,
    /// With --tune-decision on real trials: the decision maximises (validation failures detected
    /// ≥ 300 ms ahead) − (validation successes with a hand flag in their armed window), shares,
    /// with a further penalty on a false-alarm share over this bound.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.125, value_parser = check::unit)]
    pub max_false_alarm_rate: f64,
    /// With --tune-decision on real trials: pick the decision on the held-out trials of an inner
    /// cross-validation over the training trials with this many folds (each inner fold trains its
    /// own model with the same recipe) instead of on the few validation trials (0 = off, else
    /// 2…20). With --cv the inner folds run inside each outer fold's training trials, so the
    /// outer held-out trials stay unseen; without it this is the pooled CV over all real trials.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0, requires = "tune_decision", value_parser = check::usize_in!(0..=20))]
    pub tune_decision_cv: usize,
    /// Train on sequences from the grasp start instead of from each channel's contact onset
    /// (the firmware's model state starts at the onset; this is for comparison only).
    #[arg(long)]
    pub from_grasp_start: bool,
    /// Quantization-aware fine-tuning after the float training: this many epochs with the
    /// blob's arithmetic in the forward pass (int8 weights by the quantizer's row rule, σ/tanh
    /// tables, Q3.12/Q0.15 rounding, the calibrated cell format), straight-through gradients,
    /// early stopping on the same validation set (0 = off).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub qat_epochs: usize,
    /// Learning rate (Adam) of the quantization-aware fine-tuning, > 0.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1e-4, value_parser = check::positive)]
    pub qat_lr: f64,
    /// QAT keeps the epoch with the lowest validation loss among those whose blob stays within
    /// this max |Δp| of its float checkpoint over every step of the whole agreement recordings
    /// (what `slipguard-export verify` measures; else the epoch closest to it), 0…1.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.025, value_parser = check::unit)]
    pub qat_max_dp: f64,
    /// Recordings (unlabelled use: whole contact channels) for the QAT agreement check (default:
    /// the real force trials, without the held-out ones in cross-validation; `none` = by
    /// validation loss alone).
    #[arg(long)]
    pub qat_agreement_data: Option<PathBuf>,
    /// QAT: penalise |c| beyond this bound in the loss and fine-tune in the cell format that
    /// covers 1.25× it, so that the blob gets a finer cell format (0 = off: the calibrated one).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0, value_parser = check::non_negative)]
    pub qat_cell_max: f64,
    /// STFT window length in samples for the variants with bands, 4…48 (bins 1…10 kept; default:
    /// the rate's set-up, `StftConfig::for_rate_mhz`, docs/model-format.md).
    #[arg(long, allow_negative_numbers = true, value_parser = check::usize_in!(4..=48))]
    pub stft_window: Option<usize>,
    /// Name prefix of the models (default: the variant's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Short name written into the blob header (1 to 12 printable ASCII characters).
    #[arg(long, value_parser = check::blob_name)]
    pub blob_name: Option<String>,
}

pub fn parse_variants(s: &str) -> anyhow::Result<Vec<Variant>> {
    if s == "all" {
        return Ok(Variant::PER_CHANNEL.to_vec());
    }
    s.split(',')
        .map(|v| Variant::from_cli(v).with_context(|| format!("--variant `{}`", v.trim())))
        .collect()
}

fn class_weights(s: &str) -> anyhow::Result<[f32; 2]> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .context("--class-weights: two numbers, e.g. 1,2")?;
    anyhow::ensure!(v.len() == 2, "--class-weights needs two numbers");
    Ok([v[0], v[1]])
}

/// What [`Run::qat`] returns.
struct QatRun {
    model: FloatModel,
    /// The checkpoint's `qat` note.
    note: String,
    /// The kept QAT epoch (0 = the input weights, snapped).
    best_epoch: usize,
    seconds_per_epoch: f64,
    history: Vec<EpochLog>,
}

/// What every fold's training draws on.
struct FoldData<'d> {
    sets: &'d TrainingSets,
    /// The pre-trained model all folds start from, if any.
    pre: Option<&'d FloatModel>,
    config: slipguard_core::blob::ModelConfig,
    /// Whole recordings for the QAT agreement check.
    agreement: &'d [Trial],
    real_trials: &'d [Trial],
}

/// One fold's trained model and what it was trained on.
struct FoldFit<'d> {
    model: FloatModel,
    best_epoch: usize,
    spe: f64,
    history: Vec<EpochLog>,
    qat_note: Option<String>,
    tr: Vec<&'d ChannelSequence>,
    val: Vec<&'d ChannelSequence>,
    timing: Vec<String>,
}

struct Run<'a> {
    a: &'a Args,
    tc: TrainConfig,
    command: String,
}

impl Run<'_> {
    fn fit(
        &self,
        what: &str,
        init: &FloatModel,
        tr: &[&ChannelSequence],
        val: &[&ChannelSequence],
        tc: &TrainConfig,
    ) -> anyhow::Result<(FloatModel, usize, f64, Vec<EpochLog>)> {
        let pb = bar(tc.epochs as u64, what);
        pb.enable_steady_tick(std::time::Duration::from_millis(500));
        let t0 = Instant::now();
        let mut last_val = String::new();
        let out = train(init, tr, val, tc, |p| match p {
            Progress::Batch {
                epoch,
                batch,
                batches,
                train_loss,
            } => pb.set_message(format!(
                "{what} epoch {epoch} batch {batch}/{batches} train loss {train_loss:.4}{last_val}"
            )),
            Progress::Epoch(l) => {
                pb.set_position(l.epoch as u64);
                last_val = format!(
                    " (epoch {}: val loss {:.4}, {:.1} s)",
                    l.epoch, l.val_loss, l.seconds
                );
                pb.set_message(format!("{what} train loss {:.4}{last_val}", l.train_loss));
            }
        })?;
        pb.finish_and_clear();
        let n = out.history.len();
        let spe = out.history.iter().map(|l| l.seconds).sum::<f64>() / n.max(1) as f64;
        eprintln!(
            "  {what}: {} train / {} val sequences, {n} epochs ({:.2} s/epoch, {:.0} s), best epoch {} (val loss {:.4})",
            tr.len(),
            val.len(),
            spe,
            t0.elapsed().as_secs_f64(),
            out.best_epoch,
            out.history
                .get(out.best_epoch.saturating_sub(1))
                .map_or(f64::NAN, |l| l.val_loss)
        );
        Ok((out.model, out.best_epoch, spe, out.history))
    }

    /// Quantization-aware fine-tuning of `model` (`--qat-epochs`), with the cell format the
    /// blob gets from `calib` (or from `--qat-cell-max`); prints max |Δp| of the blob against the
    /// float model before and after on the validation sequences.
    fn qat(
        &self,
        what: &str,
        model: &FloatModel,
        tr: &[&ChannelSequence],
        val: &[&ChannelSequence],
        calib: &[&[f32]],
        agreement: Vec<Vec<f32>>,
    ) -> anyhow::Result<QatRun> {
        let bits = self.qat_cell_bits(model, calib)?;
        let qc = QatConfig {
            epochs: self.a.qat_epochs,
            lr: self.a.qat_lr,
            cell_frac_bits: bits.clone(),
            max_dp: self.a.qat_max_dp as f32,
            cell_max: self.a.qat_cell_max as f32,
            agreement,
        };
        let n_agree = qc.agreement.len();
        let seqs: Vec<&[f32]> = val.iter().map(|s| s.samples.as_slice()).collect();
        let before = blob_agreement(model, calib, &seqs)?;
        let what = format!("{what} QAT");
        let out = self.qat_fit(&what, model, tr, val, &qc)?;
        let dps = out.agreement.clone();
        let out = out.trained;
        let after = blob_agreement(&out.model, calib, &seqs)?;
        let n = out.history.len();
        let spe = out.history.iter().map(|l| l.seconds).sum::<f64>() / n.max(1) as f64;
        let bits_after = slipguard_core::quantize::quantize(&out.model, calib, None)?
            .1
            .cell_frac_bits;
        let dps: Vec<String> = dps.iter().map(|d| format!("{d:.4}")).collect();
        let note = format!(
            "{n} epochs, lr {}, cell bits {bits:?}, kept epoch {}; max |dp| blob vs float checkpoint over {n_agree} whole agreement recordings per epoch (0 = before QAT) [{}], bound {}; on {} validation sequences {:.4} -> {:.4} (blob vs the QAT forward {:.4} -> {:.4})",
            qc.lr,
            out.best_epoch,
            dps.join(", "),
            qc.max_dp,
            seqs.len(),
            before.float,
            after.float,
            before.fake_quant,
            after.fake_quant
        );
        eprintln!("  {what}: {note} ({spe:.2} s/epoch)");
        if bits_after != bits {
            eprintln!(
                "  {what}: note: after QAT the calibration picks cell bits {bits_after:?}, not the {bits:?} fine-tuned with"
            );
        }
        Ok(QatRun {
            model: out.model,
            note,
            best_epoch: out.best_epoch,
            seconds_per_epoch: spe,
            history: out.history,
        })
    }

    /// The cell format QAT fine-tunes in: the one covering 1.25× --qat-cell-max, else the
    /// one the quantizer calibrates from `calib`.
    fn qat_cell_bits(&self, model: &FloatModel, calib: &[&[f32]]) -> anyhow::Result<Vec<u8>> {
        Ok(if self.a.qat_cell_max > 0.0 {
            let c = slipguard_core::quantize::cell_bits_for(
                self.a.qat_cell_max as f32 * slipguard_core::quantize::CELL_HEADROOM,
            );
            vec![c; model.lstms.len()]
        } else {
            slipguard_core::quantize::quantize(model, calib, None)?
                .1
                .cell_frac_bits
        })
    }

    /// `qat_finetune` with a progress bar.
    fn qat_fit(
        &self,
        what: &str,
        model: &FloatModel,
        tr: &[&ChannelSequence],
        val: &[&ChannelSequence],
        qc: &QatConfig,
    ) -> anyhow::Result<slipguard_learn::qat::QatOutcome> {
        let pb = bar(qc.epochs as u64, what);
        pb.enable_steady_tick(std::time::Duration::from_millis(500));
        let out = qat_finetune(model, tr, val, &self.tc, qc, |p| match p {
            Progress::Batch {
                epoch,
                batch,
                batches,
                train_loss,
            } => pb.set_message(format!(
                "{what} epoch {epoch} batch {batch}/{batches} train loss {train_loss:.4}"
            )),
            Progress::Epoch(l) => {
                pb.set_position(l.epoch as u64);
                pb.set_message(format!(
                    "{what} (epoch {}: val loss {:.4}, {:.1} s)",
                    l.epoch, l.val_loss, l.seconds
                ));
            }
        })?;
        pb.finish_and_clear();
        Ok(out)
    }

    /// Trains one model on `train_real` (split by trial with `split_seed` for early stopping)
    /// plus the simulated mixes, from the pre-trained model, then QAT if asked for; the QAT
    /// agreement recordings leave out the trials in `excluded`.
    fn fit_fold<'d>(
        &self,
        d: &FoldData<'d>,
        train_real: &[&'d Sequence],
        excluded: &[String],
        split_seed: u64,
        what: &str,
    ) -> anyhow::Result<FoldFit<'d>> {
        let a = self.a;
        let mut timing = Vec::new();
        let (tr, val) =
            training_data::fold_split(train_real, d.sets, a.val_share, split_seed, a.seed);
        let init = match d.pre {
            Some(m) => m.clone(),
            None => init_model(d.config, a.seed, &tr),
        };
        let (mut model, mut best_epoch, spe, mut history) = if a.epochs == 0 {
            (init.clone(), 0, 0.0, Vec::new())
        } else {
            self.fit(what, &init, &tr, &val, &self.tc)?
        };
        timing.push(format!("{what} {spe:.2} s/epoch ({} seqs)", tr.len()));
        let calib = training_data::calibration_inputs(&tr);
        let mut qat_note = None;
        if a.qat_epochs > 0 {
            let agreement = training_data::agreement_channels(d.agreement, excluded);
            let q = self.qat(what, &model, &tr, &val, &calib, agreement)?;
            timing.push(format!("{what} QAT {:.2} s/epoch", q.seconds_per_epoch));
            if q.best_epoch > 0 {
                best_epoch = history.len() + q.best_epoch;
            }
            let n_float = history.len();
            history.extend(q.history.iter().map(|l| EpochLog {
                epoch: n_float + l.epoch,
                ..*l
            }));
            model = q.model;
            qat_note = Some(q.note);
        }
        Ok(FoldFit {
            model,
            best_epoch,
            spe,
            history,
            qat_note,
            tr,
            val,
            timing,
        })
    }

    /// `--tune-decision-cv`: an inner cross-validation over `train_real` (the trials in
    /// `excluded` are already out), each inner fold's quantized model run over its inner
    /// held-out trials; returns those runs, pooled, for the decision sweep.
    fn inner_cv_runs(
        &self,
        d: &FoldData<'_>,
        train_real: &[&Sequence],
        excluded: &[String],
        k: usize,
        what: &str,
    ) -> anyhow::Result<Vec<product::WindowedRun>> {
        let folds = self.a.cv_by.folds(
            &ev::trial_outcomes(train_real.iter().copied()),
            self.a.tune_decision_cv,
        );
        let mut runs = Vec::new();
        for (j, held) in folds.iter().enumerate().filter(|(_, h)| !h.is_empty()) {
            let inner_train: Vec<&Sequence> = train_real
                .iter()
                .copied()
                .filter(|s| !held.contains(&s.cs.trial_id))
                .collect();
            let out: Vec<String> = excluded.iter().chain(held).cloned().collect();
            // Seeds of the inner splits apart from the outer folds' (seed + k).
            let split_seed = self.a.seed + 1000 * (k as u64 + 1) + j as u64;
            let f = self.fit_fold(
                d,
                &inner_train,
                &out,
                split_seed,
                &format!("{what} inner {j}"),
            )?;
            let calib = training_data::calibration_inputs(&f.tr);
            let trials: Vec<&Trial> = d
                .real_trials
                .iter()
                .filter(|t| held.contains(&t.id))
                .collect();
            runs.extend(with_quantized_model(&f.model, &calib, |m| {
                product::windowed_runs(
                    m,
                    &trials,
                    &LabelConfig::default().scaled_to(self.a.rate_hz),
                )
            })??);
        }
        Ok(runs)
    }

    /// Sets the model's decision: with --tune-decision tuned on the validation trials (or
    /// the inner cross-validation's runs `inner`) in the armed window, else on the validation
    /// sequences; without it, the options' threshold and hysteresis.
    fn decision(
        &self,
        model: &mut FloatModel,
        val: &[&Sequence],
        val_trials: &[&Trial],
        calib: &[&[f32]],
        inner: Option<&[product::WindowedRun]>,
    ) -> anyhow::Result<()> {
        let d = if self.a.tune_decision && (inner.is_some() || !val_trials.is_empty()) {
            self.decision_on_armed_window(model, val_trials, calib, inner)?
        } else if self.a.tune_decision && !val.is_empty() {
            self.decision_on_sequences(model, val)?
        } else {
            DecisionConfig {
                threshold_q15: Q15::from_f64(self.a.threshold).header_threshold() as i16,
                raise_after: self.a.raise_after.max(1),
                clear_after: self.a.clear_after.max(1),
            }
        };
        set_decision(&mut model.config, d);
        Ok(())
    }

    /// The product's decision: the hand flag in the armed window of the validation trials (or
    /// of the inner cross-validation's held-out trials), with the quantized model the firmware
    /// runs; picked on the operating curve by --max-false-alarm-rate, raise ≥ --min-raise.
    fn decision_on_armed_window(
        &self,
        model: &FloatModel,
        val_trials: &[&Trial],
        calib: &[&[f32]],
        inner: Option<&[product::WindowedRun]>,
    ) -> anyhow::Result<DecisionConfig> {
        let (runs, base) = with_quantized_model(model, calib, |m| {
            let runs = match inner {
                Some(r) => r.to_vec(),
                None => product::windowed_runs(
                    m,
                    val_trials,
                    &LabelConfig::default().scaled_to(self.a.rate_hz),
                )?,
            };
            anyhow::Ok((runs, slipguard_core::decision::HandConfig::of(m.config())))
        })??;
        let on = match inner {
            Some(_) => format!("{}-fold inner CV held-out", self.a.tune_decision_cv),
            None => "validation".to_string(),
        };
        let curve = product::operating_curve(
            &runs,
            &base,
            &product::CURVE_THRESHOLDS,
            &product::CURVE_RAISE_AFTER
                .iter()
                .copied()
                .filter(|&r| r >= self.a.min_raise)
                .collect::<Vec<_>>(),
        );
        let pick = product::pick_decision(&curve, self.a.max_false_alarm_rate)
            .ok_or_else(|| anyhow::anyhow!("no validation trial with contact"))?;
        eprintln!(
            "  decision tuned on {} {on} trials (hand level, armed window): threshold {:.2}, raise {}: {}/{} failures ≥ 300 ms ahead, {}/{} successes with a false alarm",
            runs.len(),
            pick.threshold,
            pick.raise_after,
            pick.detected_300ms,
            pick.failures,
            pick.false_alarm_grasps,
            pick.successes
        );
        Ok(DecisionConfig {
            threshold_q15: Q15::from_f64(pick.threshold).header_threshold() as i16,
            raise_after: pick.raise_after,
            clear_after: base.decision.clear_after,
        })
    }

    /// The decision tuned on the float model's validation sequences (no validation trials:
    /// simulated data only).
    fn decision_on_sequences(
        &self,
        model: &FloatModel,
        val: &[&Sequence],
    ) -> anyhow::Result<DecisionConfig> {
        let p = probabilities(model, &[], Kind::Float, val)?;
        let (d, m) = tune_decision(&p, val, self.a.min_raise);
        eprintln!(
            "  decision tuned on validation sequences: threshold {:.2}, raise {}, clear {} (val success {:.2}%, ahead {:.2}%)",
            Q15(d.threshold_q15).to_f64(),
            d.raise_after,
            d.clear_after,
            100.0 * m.success_rate.unwrap_or(0.0),
            100.0 * m.ahead_drop_rate.unwrap_or(0.0)
        );
        Ok(d)
    }
}

/// Beside a checkpoint: `<stem>.epochs.csv` (epoch, train and validation loss, seconds) and
/// `<stem>.metrics.json` (best epoch and its losses, epochs run, total seconds, sequences).
fn write_train_log(
    checkpoint: &Path,
    history: &[EpochLog],
    best_epoch: usize,
    n_train: usize,
    n_val: usize,
) -> anyhow::Result<()> {
    let mut csv = String::from("epoch,train_loss,val_loss,seconds\n");
    for l in history {
        csv += &format!(
            "{},{:.6},{:.6},{:.3}\n",
            l.epoch, l.train_loss, l.val_loss, l.seconds
        );
    }
    let log = checkpoint.with_extension("epochs.csv");
    std::fs::write(&log, csv).with_context(|| format!("writing {}", log.display()))?;
    let best = history.get(best_epoch.saturating_sub(1));
    let finite = |v: Option<f64>| v.filter(|v| v.is_finite());
    let metrics = serde_json::json!({
        "best_epoch": best_epoch,
        "best_train_loss": finite(best.map(|l| l.train_loss)),
        "best_val_loss": finite(best.map(|l| l.val_loss)),
        "epochs_run": history.len(),
        "seconds": history.iter().map(|l| l.seconds).sum::<f64>(),
        "train_sequences": n_train,
        "val_sequences": n_val,
    });
    let json = checkpoint.with_extension("metrics.json");
    std::fs::write(&json, serde_json::to_string_pretty(&metrics)? + "\n")
        .with_context(|| format!("writing {}", json.display()))?;
    Ok(())
}

/// The data's sensor, rate and trials, or `None` for simulated trials only (no folder given and
/// a rate or sensor the shipped real trials are not at). Everything a data set can get wrong
/// (rate or unit against the options and the profiles, no labels) is refused here, before any
/// output is written.
fn resolve_data(a: &mut Args) -> anyhow::Result<Option<(PathBuf, Vec<Trial>)>> {
    let not_paper = a
        .rate_arg
        .is_some_and(|r| (r - PAPER_RATE_HZ).abs() > 0.005 * PAPER_RATE_HZ);
    if a.path.is_none() && (not_paper || a.sensor_arg == Some(ProfileId::Suction)) {
        simulated_only(a)?;
        return Ok(None);
    }
    let (path, trials) = load_real_trials(a.path.as_deref())?;
    let Some(first) = trials.first() else {
        anyhow::bail!("{}: no recordings", path.display());
    };
    let sensor = sensor_of_data(&path, first)?;
    check_against_data(a, &path, first, sensor)?;
    a.sensor = sensor;
    a.rate_hz = first.rate_hz;
    check::profile_rate(
        &format!("{}: recorded at", path.display()),
        first.rate_hz as f64,
        &[sensor.profile()],
    )
    .map_err(|e| anyhow::anyhow!("{e}: record at a rate the board runs"))?;
    check_labels(&path, &trials)?;
    Ok(Some((path, trials)))
}

/// No data folder and a rate or sensor the shipped real trials are not at: the sensor
/// (--sensor, else force) and rate (--rate-hz, else the profile's) of simulated trials only,
/// checked against the profile.
fn simulated_only(a: &mut Args) -> anyhow::Result<()> {
    a.sensor = a.sensor_arg.unwrap_or(ProfileId::Hand);
    let profile = a.sensor.profile();
    a.rate_hz = match (a.rate_arg, a.sensor) {
        (Some(r), _) => r,
        (None, ProfileId::Suction) => profile.default_rate_mhz().hz_f32(),
        (None, ProfileId::Hand) => PAPER_RATE_HZ,
    };
    check::profile_rate("--rate-hz", a.rate_hz as f64, &[profile])?;
    Ok(())
}

/// The sensor of the recordings in `path` from their unit (`first`: the first recording).
fn sensor_of_data(path: &Path, first: &Trial) -> anyhow::Result<ProfileId> {
    let unit = first.unit.input_unit().ok_or_else(|| {
        anyhow::anyhow!(
            "{}: recordings in {}: train takes force in mN or suction pressure in counts",
            path.display(),
            first.unit
        )
    })?;
    let q = ProfileQuery {
        unit: Some(unit),
        ..ProfileQuery::default()
    };
    Ok(Profile::lookup(q)
        .with_context(|| format!("{}", path.display()))?
        .id)
}

/// --sensor and --rate-hz, when given, must be the data's (`sensor`, `first`'s rate).
fn check_against_data(
    a: &Args,
    path: &Path,
    first: &Trial,
    sensor: ProfileId,
) -> anyhow::Result<()> {
    let rate = first.rate_hz;
    let name = |s: ProfileId| format!("{} ({})", check::sensor_word(s), s.profile().unit);
    if let Some(s) = a.sensor_arg.filter(|&s| s != sensor) {
        anyhow::bail!(
            "--sensor {}: {} holds {} recordings ({}): drop --sensor, or give {} recordings",
            name(s),
            path.display(),
            name(sensor),
            first.id,
            name(s)
        );
    }
    if let Some(r) = a.rate_arg.filter(|r| (r - rate).abs() > 0.005 * rate) {
        anyhow::bail!(
            "--rate-hz {r}: {} is recorded at {rate} Hz ({}): drop --rate-hz (the data's rate \
             decides the model's), or record at {r} Hz",
            path.display(),
            first.id
        );
    }
    Ok(())
}

/// Refuses recordings none of which has an outcome; names those skipped for having none, and
/// the failures without a lasting drop.
fn check_labels(path: &Path, trials: &[Trial]) -> anyhow::Result<()> {
    let unknown: Vec<&str> = trials
        .iter()
        .filter(|t| t.outcome == slipguard_data::Outcome::Unknown)
        .map(|t| t.id.as_str())
        .collect();
    if unknown.len() == trials.len() {
        anyhow::bail!(
            "{}: none of the {} recordings has an outcome, so there is nothing to train on: \
             label them first (slipguard label {} --outcome-from-drop --out LABELLED) and train on LABELLED",
            path.display(),
            trials.len(),
            path.display()
        );
    }
    if !unknown.is_empty() {
        eprintln!(
            "{}: skipped, no outcome (run `slipguard label --outcome-from-drop` on them): {}",
            path.display(),
            unknown.join(", ")
        );
    }
    let no_drop: Vec<&str> = trials
        .iter()
        .filter(|t| t.outcome == slipguard_data::Outcome::Failure && t.drop_step.is_none())
        .map(|t| t.id.as_str())
        .collect();
    if !no_drop.is_empty() {
        eprintln!(
            "{}: skipped, failure without a lasting drop (no step labels; check them with `slipguard label --stats`): {}",
            path.display(),
            no_drop.join(", ")
        );
    }
    Ok(())
}

/// The blob header's name: --blob-name, else --name when it fits the field, else the variant by
/// its letter, `variant (c)`.
fn blob_name_of(a: &Args, name: &str, v: Variant) -> String {
    if let Some(b) = &a.blob_name {
        return b.clone();
    }
    if a.name.is_some() {
        if let Ok(n) = check::blob_name(name) {
            return n;
        }
        let short: String = name
            .chars()
            .filter(|c| c.is_ascii_graphic() || *c == ' ')
            .take(12)
            .collect();
        if !short.is_empty() {
            return short;
        }
    }
    // The variant by the paper's letter: its name (up to 14 characters) does not fit the
    // header's 12.
    format!("variant ({})", v.letter())
}

/// `slipguard train`, step by step: check the options against the data, set up the run, build
/// the training sets, pick the QAT agreement recordings, then train every variant and write the
/// summary.
pub fn run(mut a: Args) -> anyhow::Result<()> {
    let variants = parse_variants(&a.variant)?;
    let data = resolve_data(&mut a)?;
    check_options(&a)?;
    let run = Run::new(&a)?;
    let t_all = Instant::now();
    if variants.contains(&Variant::HandLstm) {
        anyhow::ensure!(
            variants.len() == 1,
            "--variant {}: hand-lstm trains alone (its data are whole grasps, not channels)",
            a.variant
        );
        let Some((path, trials)) = &data else {
            anyhow::bail!(
                "--variant hand-lstm trains on recorded grasps: give a folder of labelled recordings (simulated trials alone are not supported)"
            );
        };
        anyhow::ensure!(
            a.sensor == ProfileId::Hand,
            "{}: hand-lstm is for the hand profile's force pads, not {}",
            path.display(),
            a.sensor
        );
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
        let summary = hand::run(&a, trials, &run.tc, &run.command)?;
        return write_summary(&a.out, &run.command, &summary, t_all);
    }
    let cl_cfg = closed_loop_config(&a)?;
    let (real_trials, sets) = training_sets(&a, data, &cl_cfg)?;
    let agreement_trials = agreement_trials(&a, &real_trials)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut summary = Vec::new();
    for v in variants {
        let inputs = VariantInputs {
            sets: &sets,
            real_trials: &real_trials,
            agreement: &agreement_trials,
            rate_mhz: cl_cfg.rate_mhz,
        };
        summary.extend(run.variant(v, &inputs)?);
    }
    write_summary(&a.out, &run.command, &summary, t_all)
}

/// The option combinations clap cannot refuse on its own.
fn check_options(a: &Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.epochs > 0 || a.init.is_some(),
        "--epochs 0 trains nothing: give --init CKPT (e.g. for QAT alone) or at least 1 epoch"
    );
    anyhow::ensure!(
        a.cv != 1,
        "--cv 1: cross-validation needs 0 (off) or 2 to the number of real trials folds"
    );
    anyhow::ensure!(
        a.tune_decision_cv != 1,
        "--tune-decision-cv 1: the inner cross-validation needs 0 (off) or 2 to 20 folds"
    );
    Ok(())
}

/// The simulated closed-loop training trials' settings, with the --closed-loop-policy blob
/// loaded and checked.
fn closed_loop_config(a: &Args) -> anyhow::Result<ClosedLoopTraining> {
    let rate_mhz = Millihertz::from_hz(a.rate_hz as f64);
    Ok(ClosedLoopTraining {
        rate_mhz,
        lead_s: a.closed_loop_lead,
        false_alarm_hz: a.closed_loop_false_alarms,
        policy: match &a.closed_loop_policy {
            Some(p) => Some(policy_blob(p, rate_mhz)?),
            None => None,
        },
        policy_share: a.closed_loop_policy_share,
        ..Default::default()
    })
}

/// The training sets: the recorded trials' sequences, the simulated and closed-loop ones, cut
/// to each channel's contact onset (unless --from-grasp-start); also returns the recorded
/// trials.
fn training_sets(
    a: &Args,
    data: Option<(PathBuf, Vec<Trial>)>,
    cl_cfg: &ClosedLoopTraining,
) -> anyhow::Result<(Vec<Trial>, TrainingSets)> {
    let (real_trials, real) = recorded(a, data)?;
    let recipe = SimRecipe {
        seed: a.sim_seed,
        pretrain: a.sim_pretrain,
        mix: a.sim_mix,
        failure_share: a.sim_failure_share,
        rate_hz: a.rate_hz,
    };
    let (sim_pre, sim_mix) = match a.sensor {
        ProfileId::Hand => {
            let (mut pre, mix) = recipe.force();
            pre.extend(training_sequences(
                a.closed_loop_seed,
                a.closed_loop_pretrain,
                cl_cfg,
            ));
            (pre, mix)
        }
        ProfileId::Suction => (Vec::new(), recipe.suction_mix()),
    };
    anyhow::ensure!(
        a.sensor == ProfileId::Hand || a.closed_loop_pretrain + a.closed_loop_mix == 0,
        "--closed-loop-pretrain/--closed-loop-mix simulate the hand's force pads: use --sensor force"
    );
    let cl_mix = training_sequences(a.closed_loop_seed + 1, a.closed_loop_mix, cl_cfg);
    let sets = TrainingSets {
        real,
        sim_pre,
        sim_mix,
        cl_mix,
    };
    let sets = if a.from_grasp_start {
        sets
    } else {
        from_contact_onset(a, sets, cl_cfg.rate_mhz)
    };
    if sets.has_simulated() {
        eprintln!(
            "simulated: {} pre-training and {} mixed sequences, {} closed-loop mixed sequences",
            sets.sim_pre.len(),
            sets.sim_mix.len(),
            sets.cl_mix.len()
        );
    }
    Ok((real_trials, sets))
}

/// The recorded trials and their sequences (none without a data folder: simulated trials
/// only).
fn recorded(
    a: &Args,
    data: Option<(PathBuf, Vec<Trial>)>,
) -> anyhow::Result<(Vec<Trial>, Vec<Sequence>)> {
    let Some((path, trials)) = data else {
        anyhow::ensure!(
            a.cv == 0,
            "--cv needs recorded trials: give a folder of labelled recordings at {} Hz",
            a.rate_hz
        );
        eprintln!(
            "{} Hz {}: simulated trials only (give a folder of labelled recordings to train on them)",
            a.rate_hz,
            check::sensor_word(a.sensor)
        );
        return Ok((Vec::new(), Vec::new()));
    };
    let real = training_data::recorded_sequences(&trials, a.rate_hz);
    eprintln!(
        "recorded: {} sequences from {} at {} Hz ({} failure sequences)",
        real.len(),
        path.display(),
        a.rate_hz,
        real.iter().filter(|s| s.failure()).count()
    );
    anyhow::ensure!(
        !real.is_empty() || a.sim_mix + a.closed_loop_mix > 0,
        "{}: no training sequences (no labelled channel in contact): check the recordings \
         with `slipguard label {} --stats`",
        path.display(),
        path.display()
    );
    Ok((trials, real))
}

/// Every sequence cut to start where the firmware's model state starts: at the channel's
/// contact onset (the rule depends on the sensor's unit, scale and rate only, not on the
/// variant).
fn from_contact_onset(a: &Args, sets: TrainingSets, rate_mhz: Millihertz) -> TrainingSets {
    let probe = match a.sensor {
        ProfileId::Hand => ev::force_config(Variant::Lstm, false, 1, "", rate_mhz),
        ProfileId::Suction => ev::suction_config(Variant::Lstm, false, 1, ""),
    };
    let rule = OnsetRule::of(&probe);
    let n0 = sets.len();
    let cut = sets.cut_to_contact(&rule);
    eprintln!(
        "sequences start at each channel's contact onset ({} mN-equivalent Q1.15 {}, {} steps on, {} off): {} of {} kept",
        ContactConfig::FORCE_ON_MN,
        rule.contact.on_q15,
        rule.contact.on_after,
        rule.contact.off_after,
        cut.len(),
        n0
    );
    cut
}

/// Whole recordings for the QAT agreement check (unlabelled use): --qat-agreement-data, else
/// the recorded trials, else the real force trials; none without QAT or with `none`.
fn agreement_trials(a: &Args, real_trials: &[Trial]) -> anyhow::Result<Vec<Trial>> {
    let trials = match (&a.qat_agreement_data, a.sensor) {
        _ if a.qat_epochs == 0 => Vec::new(),
        (Some(p), _) if p.as_os_str() == "none" => Vec::new(),
        (Some(p), _) => load_real_trials(Some(p))?.1,
        (None, _) if !real_trials.is_empty() => real_trials.to_vec(),
        (None, ProfileId::Hand) => load_real_trials(a.path.as_deref())?.1,
        (None, ProfileId::Suction) => Vec::new(),
    };
    if !trials.is_empty() {
        eprintln!(
            "QAT agreement check on the whole contact channels of {} recorded trials",
            trials.len()
        );
    }
    Ok(trials)
}

/// `train-summary.txt` in `out` (the command, one line per model, the total time); the lines
/// also go to stdout.
fn write_summary(
    out: &Path,
    command: &str,
    summary: &[String],
    t_all: Instant,
) -> anyhow::Result<()> {
    let log = out.join("train-summary.txt");
    std::fs::write(
        &log,
        format!(
            "{}\n{}\ntotal {:.0} s\n",
            command,
            summary.join("\n"),
            t_all.elapsed().as_secs_f64()
        ),
    )?;
    println!("{}", summary.join("\n"));
    eprintln!("total {:.0} s", t_all.elapsed().as_secs_f64());
    Ok(())
}

/// What every variant's training draws on.
struct VariantInputs<'d> {
    sets: &'d TrainingSets,
    real_trials: &'d [Trial],
    agreement: &'d [Trial],
    rate_mhz: Millihertz,
}

/// One fold's checkpoint, with what its logs and blob need.
struct TrainedFold<'d> {
    ck: Checkpoint,
    history: Vec<EpochLog>,
    best_epoch: usize,
    n_train: usize,
    n_val: usize,
    calib: Vec<&'d [f32]>,
}

/// The cross-validation's held-out results of one variant, pooled over its folds.
#[derive(Default)]
struct CvPool<'d> {
    /// The quantized model's hand-level grasps in the armed window.
    armed_hand: Vec<slipguard_data::armed::ArmedGrasp>,
    /// The float model's held-out sequences…
    seqs: Vec<&'d Sequence>,
    /// … with the model's decision …
    preds: Vec<Vec<slipguard_data::trial::Stability>>,
    /// … and with p ≥ 0.5 alone.
    plain: Vec<Vec<slipguard_data::trial::Stability>>,
}

impl Run<'_> {
    fn new(a: &Args) -> anyhow::Result<Run<'_>> {
        let tc = TrainConfig {
            lr: a.lr,
            epochs: a.epochs,
            batch: a.batch,
            patience: a.patience,
            seed: a.seed,
            class_weights: class_weights(&a.class_weights)?,
            // Durations in seconds become steps at the training rate (the data's, or --rate-hz).
            label_lead: check::steps_at(a.label_lead_s, a.rate_hz),
            start_weight: a.start_weight,
            start_steps: check::steps_at(a.start_s, a.rate_hz),
        };
        let command = std::env::args().collect::<Vec<_>>().join(" ");
        Ok(Run { a, tc, command })
    }

    /// Trains variant `v`: its model settings, the starting model, then every fold (or the one
    /// model) trained, its decision set and written; returns its summary lines.
    fn variant(&self, v: Variant, d: &VariantInputs<'_>) -> anyhow::Result<Vec<String>> {
        let a = self.a;
        let (name, config) = self.model_config(v, d.rate_mhz)?;
        let mut timing = Vec::new();
        let pre = self.starting_model(v, &config, &d.sets.sim_pre, &mut timing)?;
        let folds = self.folds(&d.sets.real, d.real_trials.len())?;
        let data = FoldData {
            sets: d.sets,
            pre: pre.as_ref(),
            config,
            agreement: d.agreement,
            real_trials: d.real_trials,
        };
        let mut pool = CvPool::default();
        for (k, held) in folds.iter().enumerate() {
            let fold = self.train_fold(&data, k, held, &mut timing)?;
            if a.cv > 0 {
                self.write_fold(&data, &name, k, held, &fold, &mut pool)?;
            } else {
                self.write_model(&name, &fold)?;
            }
        }
        Ok(if a.cv > 0 {
            self.cv_summary(&name, &pool, &timing)
        } else {
            vec![format!("{name}: {}", timing.join(", "))]
        })
    }

    /// The model's name and header settings for variant `v` (--stft-window applied).
    fn model_config(
        &self,
        v: Variant,
        rate_mhz: Millihertz,
    ) -> anyhow::Result<(String, slipguard_core::blob::ModelConfig)> {
        let a = self.a;
        let name = match &a.name {
            Some(n) if n.contains("{variant}") => n.replace("{variant}", v.name()),
            Some(n) => n.clone(),
            None => v.name().to_string(),
        };
        let blob_name = blob_name_of(a, &name, v);
        let mut config = match a.sensor {
            ProfileId::Hand => ev::force_config(v, a.force_diff, a.hidden, &blob_name, rate_mhz),
            ProfileId::Suction => ev::suction_config(v, a.force_diff, a.hidden, &blob_name),
        };
        if let Some(n) = a.stft_window.filter(|_| v.uses_bands()) {
            config.stft.window_len = n as u8;
            config
                .stft
                .validate()
                .map_err(|e| anyhow::anyhow!("--stft-window {n}: {e}"))?;
        }
        eprintln!(
            "== {name}: {} (d(t) {}, hidden {}, {} MACs/step)",
            v.name(),
            a.force_diff,
            a.hidden,
            config.macs_per_step()
        );
        Ok((name, config))
    }

    /// The model every fold starts from: --init's weights, else a model pre-trained on the
    /// simulated sequences `sim_pre` (shared by all folds), else none (each fold starts
    /// afresh).
    fn starting_model(
        &self,
        v: Variant,
        config: &slipguard_core::blob::ModelConfig,
        sim_pre: &[Sequence],
        timing: &mut Vec<String>,
    ) -> anyhow::Result<Option<FloatModel>> {
        let a = self.a;
        if let Some(p) = &a.init {
            let ck = checkpoint::read(p).with_context(|| format!("--init {}", p.display()))?;
            anyhow::ensure!(
                ck.model.config.variant == v
                    && ck.model.config.sample_rate_mhz == config.sample_rate_mhz
                    && ck.model.config.input_unit == config.input_unit,
                "--init {}: a {} model at {} Hz in {}, not the {} at {} Hz in {} being trained",
                p.display(),
                ck.model.config.variant.name(),
                ck.model.config.sample_rate_mhz.hz(),
                ck.model.config.input_unit,
                v.name(),
                config.sample_rate_mhz.hz(),
                config.input_unit
            );
            let mut m = ck.model;
            m.config.name = config.name;
            return Ok(Some(m));
        }
        if sim_pre.is_empty() {
            return Ok(None);
        }
        let all = training_data::channel_refs(sim_pre);
        let init = init_model(*config, a.seed, &all);
        let (tr, val) = split_by_trial(&all, a.val_share, a.seed);
        let tc = TrainConfig {
            epochs: a.pretrain_epochs,
            ..self.tc.clone()
        };
        let (m, _, spe, _) = self.fit("pretrain", &init, &tr, &val, &tc)?;
        timing.push(format!("pretrain {spe:.2} s/epoch ({} seqs)", tr.len()));
        Ok(Some(m))
    }

    /// Each fold's held-out trials (--cv), or one fold holding out nothing.
    fn folds(&self, real: &[Sequence], n_trials: usize) -> anyhow::Result<Vec<Vec<String>>> {
        let a = self.a;
        if a.cv == 0 {
            return Ok(vec![Vec::new()]);
        }
        anyhow::ensure!(
            a.cv <= n_trials,
            "--cv {}: at most the number of real trials ({n_trials}) folds",
            a.cv
        );
        Ok(a.cv_by.folds(&ev::trial_outcomes(real), a.cv))
    }

    /// Fold `k` (holding out the trials in `held`): trained ([`Run::fit_fold`]), its decision
    /// set ([`Run::decision`]), as a checkpoint with the run's notes.
    fn train_fold<'d>(
        &self,
        d: &FoldData<'d>,
        k: usize,
        held: &[String],
        timing: &mut Vec<String>,
    ) -> anyhow::Result<TrainedFold<'d>> {
        let a = self.a;
        let real = &d.sets.real;
        let train_real: Vec<&Sequence> = real
            .iter()
            .filter(|s| !held.contains(&s.cs.trial_id))
            .collect();
        let what = if a.cv > 0 {
            format!("fold {k}")
        } else {
            "train".to_string()
        };
        let FoldFit {
            mut model,
            best_epoch,
            spe,
            history,
            qat_note,
            tr,
            val,
            timing: t,
        } = self.fit_fold(d, &train_real, held, a.seed + k as u64, &what)?;
        timing.extend(t);
        let calib = training_data::calibration_inputs(&tr);
        let val_seqs: Vec<&Sequence> = real
            .iter()
            .chain(&d.sets.sim_mix)
            .filter(|s| val.iter().any(|v| std::ptr::eq(*v, &s.cs)))
            .collect();
        let val_ids: std::collections::BTreeSet<&str> =
            val.iter().map(|v| v.trial_id.as_str()).collect();
        let val_trials: Vec<&Trial> = d
            .real_trials
            .iter()
            .filter(|t| val_ids.contains(t.id.as_str()))
            .collect();
        let inner = if a.tune_decision && a.tune_decision_cv > 0 && !d.real_trials.is_empty() {
            Some(self.inner_cv_runs(d, &train_real, held, k, &what)?)
        } else {
            None
        };
        self.decision(&mut model, &val_seqs, &val_trials, &calib, inner.as_deref())?;
        let mut extra = std::collections::BTreeMap::new();
        extra.insert("train_command".into(), self.command.clone());
        extra.insert("best_epoch".into(), best_epoch.to_string());
        extra.insert("seconds_per_epoch".into(), format!("{spe:.3}"));
        if let Some(n) = qat_note {
            extra.insert("qat".into(), n);
        }
        let ids = |v: &[&ChannelSequence]| {
            let mut ids: Vec<String> = v.iter().map(|s| s.trial_id.clone()).collect();
            ids.sort();
            ids.dedup();
            ids.join(",")
        };
        extra.insert("val_trials".into(), ids(&val));
        if a.cv > 0 {
            extra.insert("heldout_trials".into(), held.join(","));
            extra.insert("fold".into(), format!("{k}/{}", a.cv));
        }
        Ok(TrainedFold {
            ck: Checkpoint { model, extra },
            history,
            best_epoch,
            n_train: tr.len(),
            n_val: val.len(),
            calib,
        })
    }

    /// A cross-validation fold: its checkpoint and logs written, its held-out trials scored
    /// (float sequences, and the quantized model hand level in the armed window) into `pool`.
    fn write_fold<'d>(
        &self,
        d: &FoldData<'d>,
        name: &str,
        k: usize,
        held: &[String],
        fold: &TrainedFold<'_>,
        pool: &mut CvPool<'d>,
    ) -> anyhow::Result<()> {
        let a = self.a;
        let ck = &fold.ck;
        let p = a.out.join(name).join(format!("fold{k}.safetensors"));
        checkpoint::write(&p, ck)?;
        write_train_log(&p, &fold.history, fold.best_epoch, fold.n_train, fold.n_val)?;
        let test: Vec<&Sequence> = d
            .sets
            .real
            .iter()
            .filter(|s| held.contains(&s.cs.trial_id))
            .collect();
        let p = probabilities(&ck.model, &[], Kind::Float, &test)?;
        let dc = DecisionConfig::of(&ck.model.config);
        let preds: Vec<_> = p.iter().map(|q| decide(dc, q)).collect();
        let m = metrics_of(&test, &preds);
        eprintln!(
            "  fold {k} held out {}: success {:.2}%, ahead-drop {:?}",
            held.join(" "),
            100.0 * m.success_rate.unwrap_or(0.0),
            m.ahead_drop_rate.map(|x| format!("{:.2}%", 100.0 * x))
        );
        let plain = DecisionConfig {
            threshold_q15: 16384,
            raise_after: 1,
            clear_after: 1,
        };
        pool.plain.extend(p.iter().map(|q| decide(plain, q)));
        // The product's figures: the fold's quantized model over its held-out trials,
        // hand level, armed window.
        let held_trials: Vec<&Trial> = d
            .real_trials
            .iter()
            .filter(|t| held.contains(&t.id))
            .collect();
        let grasps = with_quantized_model(&ck.model, &fold.calib, |qm| {
            let hand = slipguard_core::decision::HandConfig::of(qm.config());
            product::windowed_runs(
                qm,
                &held_trials,
                &LabelConfig::default().scaled_to(a.rate_hz),
            )
            .map(|runs| runs.iter().map(|w| w.grasp_with(&hand)).collect::<Vec<_>>())
        })??;
        pool.armed_hand.extend(grasps);
        pool.seqs.extend(test);
        pool.preds.extend(preds);
        Ok(())
    }

    /// The one model (no --cv): checkpoint, logs and quantized blob written.
    fn write_model(&self, name: &str, fold: &TrainedFold<'_>) -> anyhow::Result<()> {
        let a = self.a;
        let p = a.out.join(format!("{name}.safetensors"));
        checkpoint::write(&p, &fold.ck)?;
        write_train_log(&p, &fold.history, fold.best_epoch, fold.n_train, fold.n_val)?;
        let blob = quantize_model(&fold.ck.model, &fold.calib)?;
        let bp = a.out.join(format!("{name}.bin"));
        std::fs::write(&bp, &blob).with_context(|| format!("writing {}", bp.display()))?;
        eprintln!(
            "  wrote {} and {} ({} bytes)",
            p.display(),
            bp.display(),
            blob.len()
        );
        Ok(())
    }

    /// The cross-validation's two summary lines (quantized hand level in the armed window;
    /// float), also printed.
    fn cv_summary(&self, name: &str, pool: &CvPool<'_>, timing: &[String]) -> Vec<String> {
        let a = self.a;
        let mut summary = Vec::new();
        let r = slipguard_data::armed::ArmedReport::of(&pool.armed_hand);
        let line = format!(
            "{name}: {}-fold CV quantized, hand level, armed window: {}",
            a.cv,
            r.summary()
        );
        eprintln!("{line}");
        summary.push(line);
        let m = metrics_of(&pool.seqs, &pool.preds);
        let m0 = metrics_of(&pool.seqs, &pool.plain);
        let line = format!(
            "{name}: {}-fold CV float: success {:.2}%, ahead-drop {:.2}%, false alarms {:.2}% (p>=0.5 alone: {:.2}% / {:.2}%) ({} seqs, {} failures); {}",
            a.cv,
            100.0 * m.success_rate.unwrap_or(0.0),
            100.0 * m.ahead_drop_rate.unwrap_or(0.0),
            100.0 * m.false_alarm_rate.unwrap_or(0.0),
            100.0 * m0.success_rate.unwrap_or(0.0),
            100.0 * m0.ahead_drop_rate.unwrap_or(0.0),
            pool.seqs.len(),
            m.failure_sequences,
            timing.join(", ")
        );
        eprintln!("{line}");
        summary.push(line);
        summary
    }
}

/// The --closed-loop-policy blob, checked: a blob that does not parse would only send fault
/// frames and one at another rate would see other signals, either giving useless data.
fn policy_blob(
    path: &Path,
    rate_mhz: Millihertz,
) -> anyhow::Result<slipguard_core::blob::AlignedBlob> {
    let blob = slipguard::replay::load_blob(path)?;
    let model = slipguard_core::model::Model::from_bytes(blob.as_bytes())
        .map_err(|e| anyhow::anyhow!("--closed-loop-policy {}: {e}", path.display()))?;
    let got = model.config().sample_rate_mhz;
    anyhow::ensure!(
        got == rate_mhz,
        "--closed-loop-policy {} runs at {} Hz, not the --rate-hz {} Hz being trained",
        path.display(),
        got.hz(),
        rate_mhz.hz()
    );
    Ok(blob)
}
