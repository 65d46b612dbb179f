//! `slipguard train --variant hand-lstm`: the hand-level model, one sequence per grasp
//! (`slipguard_learn::hand`), cross-validation by trial or by grasp setting (`--cv-by`), the
//! decision picked per fold at hand level in the armed window with the quantized model the
//! firmware runs, every fold's checkpoint and blob written (blob format v3).
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use slipguard_core::blob::{AlignedBlob, ModelConfig, Variant};
use slipguard_core::decision::{DecisionConfig, HandConfig, Q15};
use slipguard_core::float::FloatModel;
use slipguard_core::model::Model;
use slipguard_data::Trial;
use slipguard_data::armed::{ArmedGrasp, ArmedReport};
use slipguard_data::labels::LabelConfig;
use slipguard_learn::checkpoint::{self, Checkpoint};
use slipguard_learn::evaluation::{self as ev, set_decision};
use slipguard_learn::hand::{
    HandSequence, HandTarget, hand_sequences, init_hand_model, quantize_hand, split_hand_by_trial,
    train_hand,
};
use slipguard_learn::product::{self, WindowedRun};
use slipguard_learn::train::{Progress, TrainConfig};

use super::super::check;
use super::super::progress::bar;
use super::Args;

/// A trained fold: its model (decision set), blob and what it was trained on.
struct Fold {
    ck: Checkpoint,
    blob: Vec<u8>,
    n_train: usize,
    n_val: usize,
    history: Vec<slipguard_learn::train::EpochLog>,
    best_epoch: usize,
}

/// Trains the hand-level model on `trials` (recorded, labelled): the one model, or `--cv`
/// folds grouped by `--cv-by`. Returns the summary lines.
pub fn run(
    a: &Args,
    trials: &[Trial],
    tc: &TrainConfig,
    command: &str,
) -> anyhow::Result<Vec<String>> {
    let t0 = Instant::now();
    let rate_mhz = slipguard_core::units::Millihertz::from_hz(a.rate_hz as f64);
    let name = a
        .name
        .clone()
        .unwrap_or_else(|| Variant::HandLstm.name().to_string());
    let blob_name = super::blob_name_of(a, &name, Variant::HandLstm);
    let config = ev::force_config(Variant::HandLstm, false, a.hidden, &blob_name, rate_mhz);
    eprintln!(
        "== {name}: {} (hidden {}, {} MACs/frame, {} hand features)",
        Variant::HandLstm.name(),
        a.hidden,
        config.macs_per_step(),
        config.feature_count()
    );
    let cfg = LabelConfig::default().scaled_to(a.rate_hz);
    let target = HandTarget {
        lead: check::steps_at(a.label_lead_s, a.rate_hz),
        lift_jitter: a.lift_jitter.clone(),
    };
    let refs: Vec<&Trial> = trials.iter().collect();
    let (seqs, skipped) = hand_sequences(&config, &refs, &cfg, &target)?;
    for e in &skipped {
        eprintln!("  skipped: {e}");
    }
    let originals: Vec<(String, bool)> = {
        let mut v: Vec<(String, bool)> = Vec::new();
        for s in &seqs {
            if !v.iter().any(|(id, _)| id == &s.trial_id) {
                v.push((s.trial_id.clone(), s.failure));
            }
        }
        v
    };
    anyhow::ensure!(
        !originals.is_empty(),
        "no recorded grasp with contact and an armed window to train the hand model on"
    );
    eprintln!(
        "  {} grasps ({} drops) from grasp start to the armed window's end, {} sequences with {} lift shifts; unstable from {} frames before the drop",
        originals.len(),
        originals.iter().filter(|t| t.1).count(),
        seqs.len(),
        target.lift_jitter.len(),
        target.lead
    );
    let folds = if a.cv == 0 {
        vec![Vec::new()]
    } else {
        anyhow::ensure!(
            a.cv <= originals.len(),
            "--cv {}: at most the number of grasps ({}) folds",
            a.cv,
            originals.len()
        );
        a.cv_by.folds(&originals, a.cv)
    };
    std::fs::create_dir_all(a.out.join(if a.cv > 0 { name.as_str() } else { "" }))
        .with_context(|| format!("creating {}", a.out.display()))?;
    let mut pooled: Vec<ArmedGrasp> = Vec::new();
    for (k, held) in folds.iter().enumerate() {
        let what = if a.cv > 0 {
            format!("fold {k}")
        } else {
            "train".to_string()
        };
        let train: Vec<&HandSequence> = seqs
            .iter()
            .filter(|s| !held.contains(&s.trial_id))
            .collect();
        let fold = train_fold(a, tc, &config, trials, &train, held, k, &what, command)?;
        if a.cv > 0 {
            let stem = a.out.join(&name).join(format!("fold{k}"));
            write(&stem, &fold)?;
            let held_trials: Vec<&Trial> = trials.iter().filter(|t| held.contains(&t.id)).collect();
            let runs = runs_of(&fold.blob, &held_trials, &cfg)?;
            let hand = HandConfig::of(&fold.ck.model.config);
            let grasps: Vec<ArmedGrasp> = runs.iter().map(|w| w.grasp_with(&hand)).collect();
            eprintln!(
                "  fold {k} held out {} ({} grasps): {}",
                held.join(" "),
                grasps.len(),
                ArmedReport::of(&grasps).summary()
            );
            pooled.extend(grasps);
        } else {
            write(&a.out.join(&name), &fold)?;
        }
    }
    let line = if a.cv > 0 {
        format!(
            "{name}: {}-fold CV by {} quantized, hand level, armed window: {} ({:.0} s)",
            a.cv,
            a.cv_by,
            ArmedReport::of(&pooled).summary(),
            t0.elapsed().as_secs_f64()
        )
    } else {
        format!(
            "{name}: trained on {} grasps ({:.0} s)",
            originals.len(),
            t0.elapsed().as_secs_f64()
        )
    };
    eprintln!("{line}");
    Ok(vec![line])
}

/// The quantized model of `blob` run over `trials` in their armed windows.
fn runs_of(blob: &[u8], trials: &[&Trial], cfg: &LabelConfig) -> anyhow::Result<Vec<WindowedRun>> {
    let a = AlignedBlob::new(blob);
    let m = Model::from_bytes(a.as_bytes())
        .map_err(|e| anyhow::anyhow!("the hand blob does not parse: {e}"))?;
    Ok(product::windowed_runs(&m, trials, cfg)?)
}

/// One fold: trained on `train` (split by trial for early stopping), its decision picked, its
/// blob made.
#[allow(clippy::too_many_arguments)]
fn train_fold(
    a: &Args,
    tc: &TrainConfig,
    config: &ModelConfig,
    trials: &[Trial],
    train: &[&HandSequence],
    held: &[String],
    k: usize,
    what: &str,
    command: &str,
) -> anyhow::Result<Fold> {
    let cfg = LabelConfig::default().scaled_to(a.rate_hz);
    let (tr, val) = split_hand_by_trial(train, a.val_share, a.seed + k as u64);
    // Validation on each trial's own lift mark only (its shifted copies train nothing here).
    let val: Vec<&HandSequence> = val.into_iter().filter(|s| s.jitter == 0).collect();
    let mut model = fit(what, config, a.seed, &tr, &val, tc)?;
    let val_ids: Vec<String> = {
        let mut v: Vec<String> = val.iter().map(|s| s.trial_id.clone()).collect();
        v.sort();
        v.dedup();
        v
    };
    // The decision: on the held-out trials of an inner CV over the training trials, else on
    // the validation trials, at hand level in the armed window with the quantized model.
    let runs = if a.tune_decision && a.tune_decision_cv > 0 {
        inner_runs(a, tc, config, trials, train, k, what)?
    } else {
        let blob = quantize_hand(&model.0, &tr)?;
        let vt: Vec<&Trial> = trials.iter().filter(|t| val_ids.contains(&t.id)).collect();
        runs_of(&blob, &vt, &cfg)?
    };
    let d = if a.tune_decision {
        pick(a, &model.0.config, &runs)?
    } else {
        DecisionConfig {
            threshold_q15: Q15::from_f64(a.threshold).header_threshold() as i16,
            raise_after: a.raise_after,
            clear_after: a.clear_after,
        }
    };
    set_decision(&mut model.0.config, d);
    let blob = quantize_hand(&model.0, &tr)?;
    let mut extra = std::collections::BTreeMap::new();
    extra.insert("train_command".into(), command.to_string());
    extra.insert("best_epoch".into(), model.1.to_string());
    extra.insert("val_trials".into(), val_ids.join(","));
    extra.insert("lift_jitter".into(), format!("{:?}", a.lift_jitter));
    if a.cv > 0 {
        extra.insert("heldout_trials".into(), held.join(","));
        extra.insert("fold".into(), format!("{k}/{}", a.cv));
        extra.insert("cv_by".into(), a.cv_by.to_string());
    }
    Ok(Fold {
        ck: Checkpoint {
            model: model.0,
            extra,
        },
        blob,
        n_train: tr.len(),
        n_val: val.len(),
        history: model.2,
        best_epoch: model.1,
    })
}

/// `--tune-decision-cv`: the training trials' inner CV (grouped as the outer folds), each
/// inner model's blob over its inner held-out trials, pooled.
fn inner_runs(
    a: &Args,
    tc: &TrainConfig,
    config: &ModelConfig,
    trials: &[Trial],
    train: &[&HandSequence],
    k: usize,
    what: &str,
) -> anyhow::Result<Vec<WindowedRun>> {
    let cfg = LabelConfig::default().scaled_to(a.rate_hz);
    let mut ids: Vec<(String, bool)> = Vec::new();
    for s in train {
        if !ids.iter().any(|(id, _)| id == &s.trial_id) {
            ids.push((s.trial_id.clone(), s.failure));
        }
    }
    let inner = a.cv_by.folds(&ids, a.tune_decision_cv);
    let mut runs = Vec::new();
    for (j, held) in inner.iter().enumerate().filter(|(_, h)| !h.is_empty()) {
        let sub: Vec<&HandSequence> = train
            .iter()
            .copied()
            .filter(|s| !held.contains(&s.trial_id))
            .collect();
        let seed = a.seed + 1000 * (k as u64 + 1) + j as u64;
        let (tr, val) = split_hand_by_trial(&sub, a.val_share, seed);
        let val: Vec<&HandSequence> = val.into_iter().filter(|s| s.jitter == 0).collect();
        let (m, _, _) = fit(&format!("{what} inner {j}"), config, a.seed, &tr, &val, tc)?;
        let blob = quantize_hand(&m, &tr)?;
        let ht: Vec<&Trial> = trials.iter().filter(|t| held.contains(&t.id)).collect();
        runs.extend(runs_of(&blob, &ht, &cfg)?);
    }
    Ok(runs)
}

/// The decision on `runs` (the quantized model's hand p): the operating curve's pick by
/// `--max-false-alarm-rate`, raise ≥ `--min-raise`.
fn pick(a: &Args, config: &ModelConfig, runs: &[WindowedRun]) -> anyhow::Result<DecisionConfig> {
    let base = HandConfig::of(config);
    let raise: Vec<u8> = product::CURVE_RAISE_AFTER
        .iter()
        .copied()
        .filter(|&r| r >= a.min_raise)
        .collect();
    let curve = product::operating_curve(runs, &base, &product::CURVE_THRESHOLDS, &raise);
    let p = product::pick_decision(&curve, a.max_false_alarm_rate)
        .ok_or_else(|| anyhow::anyhow!("no trial with contact to pick the decision on"))?;
    eprintln!(
        "  decision tuned on {} trials (hand level, armed window): threshold {:.2}, raise {}: {}/{} failures ≥ 300 ms ahead, {}/{} successes with a false alarm",
        runs.len(),
        p.threshold,
        p.raise_after,
        p.detected_300ms,
        p.failures,
        p.false_alarm_grasps,
        p.successes
    );
    Ok(DecisionConfig {
        threshold_q15: Q15::from_f64(p.threshold).header_threshold() as i16,
        raise_after: p.raise_after,
        clear_after: base.decision.clear_after,
    })
}

/// A fresh hand model trained on `tr`, early-stopped on `val`, with a progress bar: (model,
/// best epoch, history).
fn fit(
    what: &str,
    config: &ModelConfig,
    seed: u64,
    tr: &[&HandSequence],
    val: &[&HandSequence],
    tc: &TrainConfig,
) -> anyhow::Result<(FloatModel, usize, Vec<slipguard_learn::train::EpochLog>)> {
    let init = init_hand_model(*config, seed, tr);
    let pb = bar(tc.epochs as u64, what);
    let t0 = Instant::now();
    let out = train_hand(&init, tr, val, tc, |p| {
        if let Progress::Epoch(l) = p {
            pb.set_position(l.epoch as u64);
            pb.set_message(format!("{what} val loss {:.4}", l.val_loss));
        }
    })?;
    pb.finish_and_clear();
    let n = out.history.len();
    eprintln!(
        "  {what}: {} train / {} val sequences, {n} epochs ({:.1} s), best epoch {} (val loss {:.4})",
        tr.len(),
        val.len(),
        t0.elapsed().as_secs_f64(),
        out.best_epoch,
        out.history
            .get(out.best_epoch.saturating_sub(1))
            .map_or(f64::NAN, |l| l.val_loss)
    );
    Ok((out.model, out.best_epoch, out.history))
}

/// `<stem>.safetensors`, `<stem>.bin` and the training logs.
fn write(stem: &Path, f: &Fold) -> anyhow::Result<()> {
    let p = stem.with_extension("safetensors");
    checkpoint::write(&p, &f.ck)?;
    super::write_train_log(&p, &f.history, f.best_epoch, f.n_train, f.n_val)?;
    let bp = stem.with_extension("bin");
    std::fs::write(&bp, &f.blob).with_context(|| format!("writing {}", bp.display()))?;
    eprintln!(
        "  wrote {} and {} ({} bytes)",
        p.display(),
        bp.display(),
        f.blob.len()
    );
    Ok(())
}
