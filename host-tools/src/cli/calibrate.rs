//! `slipguard calibrate RECORDINGS --false-alarm-budget R`: the hand flag's threshold and
//! raise_after picked from held (successful) grasps only, since recording held grasps is cheap
//! and recording drops is not. The pick is the most sensitive decision (lowest threshold, then
//! least raise_after) whose share of held grasps with a false alarm in the armed window stays
//! within the budget. `--cv K` measures it: the pick on the held grasps of K−1 folds, the
//! false-alarm share on the unseen fold's held grasps and the detection on every failure (no
//! failure is ever used for the pick).
use std::path::PathBuf;

use anyhow::Context;
use slipguard_core::decision::{HandConfig, Q15};
use slipguard_core::model::Model;
use slipguard_data::armed::{ArmedGrasp, ArmedReport};
use slipguard_data::labels::LabelConfig;
use slipguard_data::{Outcome, Trial};
use slipguard_learn::product::{self, CurvePoint, WindowedRun};

use super::check;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Labelled recordings (a folder or eagle-shoal data): the held grasps (outcome success)
    /// set the decision; failures, if any, are only scored.
    pub path: PathBuf,
    /// Model blob the decision is for (default: the shipped model for the recordings' rate and
    /// sensor).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Largest share of held grasps with a false alarm in their armed window, 0…1 (e.g. 0.1).
    #[arg(long, allow_negative_numbers = true, value_parser = check::unit)]
    pub false_alarm_budget: f64,
    /// Largest raise_after (steps above the threshold before the flag rises) the pick may use,
    /// 1…16.
    #[arg(long, default_value_t = 4, allow_negative_numbers = true, value_parser = clap::value_parser!(u8).range(1..=16))]
    pub max_raise: u8,
    /// Measure the pick by K-fold cross-validation over the held grasps (0 = off, else 2 to the
    /// number of held grasps).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = check::usize_in!(0..=1000))]
    pub cv: usize,
    /// Write the pick as one line `threshold P RAISE CLEAR`, the monitor's command syntax:
    /// `slipguard monitor --port PORT --send "$(cat FILE)"` sets it on the board.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Thresholds swept: 0.01 … 0.99 by 0.01.
fn thresholds() -> Vec<f64> {
    (1..100).map(|i| i as f64 / 100.0).collect()
}

/// The pick on `held` runs: the lowest threshold (then the least raise_after) whose
/// false-alarm share on them is within `budget`.
pub fn pick(
    held: &[&WindowedRun],
    base: &HandConfig,
    budget: f64,
    max_raise: u8,
) -> Option<CurvePoint> {
    let runs: Vec<WindowedRun> = held.iter().map(|r| (*r).clone()).collect();
    let raises: Vec<u8> = (1..=max_raise).collect();
    let curve = product::operating_curve(&runs, base, &thresholds(), &raises);
    curve
        .into_iter()
        .filter(|p| p.successes > 0 && p.false_alarm_grasp_rate <= budget + 1e-12)
        .min_by(|a, b| {
            a.threshold
                .total_cmp(&b.threshold)
                .then(a.raise_after.cmp(&b.raise_after))
        })
}

fn pct(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{:.0} %", 100.0 * v))
}

/// A 95 % bootstrap interval in percent.
fn ci(i: Option<slipguard_data::armed::Interval>) -> String {
    i.map_or("[-]".into(), |i| {
        format!("[{:.0}–{:.0} %]", 100.0 * i.lo, 100.0 * i.hi)
    })
}

fn with(base: &HandConfig, p: &CurvePoint) -> HandConfig {
    let mut h = *base;
    h.decision.threshold_q15 = Q15::from_f64(p.threshold).header_threshold() as i16;
    h.decision.raise_after = p.raise_after;
    h
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let (path, trials) = super::load_real_trials(Some(&a.path))?;
    let first = trials
        .first()
        .ok_or_else(|| anyhow::anyhow!("{}: no recordings", path.display()))?;
    let profile = slipguard::replay::profile_for(first, &path.display().to_string())?;
    let rate_mhz = first.rate_mhz();
    let model_path = a
        .model
        .clone()
        .unwrap_or_else(|| slipguard::replay::default_model_for(&profile, rate_mhz));
    let (blob, _) = check::load_model("calibrate", &model_path, &profile, false)?;
    let model = Model::from_bytes(blob.as_bytes())
        .map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    let c = model.config();
    anyhow::ensure!(
        c.sample_rate_mhz == rate_mhz,
        "{}: the model runs at {} Hz, but {} is recorded at {} Hz ({}): give the model for that rate (--model)",
        model_path.display(),
        c.sample_rate_mhz.hz(),
        path.display(),
        first.rate_hz,
        first.id
    );
    let held_n = trials
        .iter()
        .filter(|t| t.outcome == Outcome::Success)
        .count();
    anyhow::ensure!(
        held_n > 0,
        "{}: no held grasp (outcome success) to calibrate on: label the recordings first \
         (slipguard label {} --outcome-from-drop --out LABELLED)",
        path.display(),
        path.display()
    );
    anyhow::ensure!(
        a.cv == 0 || (2..=held_n).contains(&a.cv),
        "--cv {}: 0 (off) or 2 to the {held_n} held grasps",
        a.cv
    );
    let cfg = LabelConfig::default().scaled_to(first.rate_hz);
    let refs: Vec<&Trial> = trials.iter().collect();
    let runs = product::windowed_runs(&model, &refs, &cfg)
        .with_context(|| format!("running {} over {}", model_path.display(), path.display()))?;
    let base = HandConfig::of(c);
    let held: Vec<&WindowedRun> = runs.iter().filter(|r| !r.failure).collect();
    let failures: Vec<&WindowedRun> = runs.iter().filter(|r| r.failure).collect();
    let p = pick(&held, &base, a.false_alarm_budget, a.max_raise).ok_or_else(|| {
        anyhow::anyhow!(
            "no threshold up to 0.99 with raise_after up to {} keeps the false alarms on {} held grasps within {}: raise --max-raise or the budget",
            a.max_raise,
            held.len(),
            a.false_alarm_budget
        )
    })?;
    let clear = base.decision.clear_after;
    println!(
        "{}: {} held grasps with contact (of {held_n}) at {} Hz, model {}",
        path.display(),
        held.len(),
        first.rate_hz,
        model_path.display()
    );
    println!(
        "pick: threshold {:.2}, raise_after {}, clear_after {clear} (the model's): {}/{} held grasps with a false alarm (budget {})",
        p.threshold, p.raise_after, p.false_alarm_grasps, p.successes, a.false_alarm_budget
    );
    if !failures.is_empty() {
        let g: Vec<ArmedGrasp> = failures
            .iter()
            .map(|r| r.grasp_with(&with(&base, &p)))
            .collect();
        println!(
            "on the {} failures in the data (not used for the pick): {}",
            failures.len(),
            ArmedReport::of(&g).summary()
        );
    }
    let line = format!("threshold {:.4} {} {clear}", p.threshold, p.raise_after);
    println!("set it on the board: slipguard monitor --port PORT --send \"{line}\"");
    if let Some(o) = &a.out {
        std::fs::write(o, format!("{line}\n"))
            .with_context(|| format!("writing {}", o.display()))?;
        println!("wrote {}", o.display());
    }
    if a.cv > 0 {
        cross_validate(&a, &held, &failures, &base)?;
    }
    Ok(())
}

/// `--cv K`: held grasps in K folds (round-robin in trial order); each fold's pick is made on
/// the other folds' held grasps and scored on its own held grasps and on every failure.
fn cross_validate(
    a: &Args,
    held: &[&WindowedRun],
    failures: &[&WindowedRun],
    base: &HandConfig,
) -> anyhow::Result<()> {
    let mut unseen: Vec<ArmedGrasp> = Vec::new();
    let mut detected: Vec<ArmedGrasp> = Vec::new();
    for k in 0..a.cv {
        let train: Vec<&WindowedRun> = held
            .iter()
            .enumerate()
            .filter(|(i, _)| i % a.cv != k)
            .map(|(_, r)| *r)
            .collect();
        let test: Vec<&WindowedRun> = held
            .iter()
            .enumerate()
            .filter(|(i, _)| i % a.cv == k)
            .map(|(_, r)| *r)
            .collect();
        let Some(p) = pick(&train, base, a.false_alarm_budget, a.max_raise) else {
            anyhow::bail!("fold {k}: no decision within the budget on its training held grasps");
        };
        let h = with(base, &p);
        let t: Vec<ArmedGrasp> = test.iter().map(|r| r.grasp_with(&h)).collect();
        let f: Vec<ArmedGrasp> = failures.iter().map(|r| r.grasp_with(&h)).collect();
        let fa = t.iter().filter(|g| g.first_flag().is_some()).count();
        let det = ArmedReport::of(&f).metrics;
        println!(
            "fold {k}: pick threshold {:.2} raise {} on {} held grasps; unseen held grasps with a false alarm {fa}/{}; failures detected {}/{}",
            p.threshold,
            p.raise_after,
            train.len(),
            t.len(),
            det.detected,
            det.failures
        );
        unseen.extend(t);
        detected.extend(f);
    }
    let fa = ArmedReport::of(&unseen);
    let det = ArmedReport::of(&detected);
    println!(
        "{}-fold CV, budget {}: unseen held grasps with a false alarm {}/{} = {} {}; failures detected (each scored with every fold's pick) {}/{} = {} {} (≥ 300 ms ahead: {})",
        a.cv,
        a.false_alarm_budget,
        fa.metrics.false_alarm_grasps,
        fa.metrics.successes,
        pct(fa.metrics.false_alarm_grasp_rate()),
        ci(fa.false_alarm_grasp_rate_ci),
        det.metrics.detected,
        det.metrics.failures,
        pct(det.metrics.detected_rate()),
        ci(det.detected_rate_ci),
        det.metrics.detected_early()
    );
    Ok(())
}
