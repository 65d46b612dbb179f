//! `slipguard label [PATH] --stats [--plot DIR] [--out DIR]`.
use std::path::PathBuf;

use anyhow::Context;
use slipguard::plot;
use slipguard_data::labels::{
    LabelConfig, LabelStats, LabelStatus, annotate, detect_drop, label_annotated,
};
use slipguard_data::{Outcome, eagle, load_path, recording};

use super::progress::bar;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset root, trial folder, recording or folder of recordings
    /// (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    pub path: Option<PathBuf>,
    /// Print per-trial drop steps and the label balance.
    #[arg(long)]
    pub stats: bool,
    /// Draw a PNG per trial (or per --trial) into this folder; a path ending in `.png` is the
    /// one file for the one selected trial.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Only these trial ids (repeatable) for --plot and --out.
    #[arg(long = "trial")]
    pub trials: Vec<String>,
    /// Write labelled trials as slipguard recordings into this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seconds before the drop from which steps are unstable (paper: 1.2 s = 20 steps at
    /// 16.7 Hz; the same duration at every rate).
    #[arg(long, default_value_t = 1.2, allow_negative_numbers = true, value_parser = super::check::seconds_in(0.0, 600.0))]
    pub lead_s: f32,
    /// Sequence length from grasp start, seconds (paper: 160 steps at 16.7 Hz).
    #[arg(long, default_value_t = 9.58, allow_negative_numbers = true, value_parser = super::check::seconds_in(0.1, 3600.0))]
    pub seq_s: f32,
    /// Drop when the contact sum is below this fraction of its lift-window peak...
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true, value_parser = super::check::open_unit_f32)]
    pub drop_fraction: f32,
    /// ... for this many seconds (paper set-up: 0.6 s = 10 steps at 16.7 Hz).
    #[arg(long, default_value_t = 0.6, allow_negative_numbers = true, value_parser = super::check::seconds_in(0.01, 600.0))]
    pub drop_hold_s: f32,
    /// Contact threshold for force channels, mN above the pre-grasp baseline.
    #[arg(long, default_value_t = 500.0, allow_negative_numbers = true, value_parser = super::check::positive_f32)]
    pub contact_mn: f32,
    /// Contact threshold for pressure channels (suction), 1/16 ADC counts from the baseline.
    #[arg(long, default_value_t = 1500.0, allow_negative_numbers = true, value_parser = super::check::positive_f32)]
    pub contact_counts: f32,
    /// Trials of unknown outcome (the monitor's recordings): failure if the force shows a
    /// lasting drop after the lift, else success (printed per trial; check it against what you
    /// saw, and fix a wrong one with `# outcome:` in the recording).
    #[arg(long)]
    pub outcome_from_drop: bool,
}

/// Steps at the paper's rate (what [`LabelConfig`] counts in) for `seconds`.
fn paper_steps(seconds: f32) -> usize {
    super::check::steps_at(seconds, slipguard_core::sample::PAPER_RATE_HZ).max(1)
}

/// `slipguard label`: the label settings, the trials (their outcomes decided from the drop with
/// `--outcome-from-drop`), the labels, then the table, the plots and the labelled recordings.
pub fn run(a: Args) -> anyhow::Result<()> {
    let paper = label_config(&a)?;
    // Outputs checked before any work.
    let single_png = a
        .plot
        .as_ref()
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")));
    if let Some(p) = single_png {
        anyhow::ensure!(
            a.trials.len() == 1,
            "--plot {}: one PNG file draws one trial: add --trial ID (or give a folder for one PNG per trial)",
            p.display()
        );
    }
    let path = a.path.clone().unwrap_or_else(eagle::default_data_dir);
    let pb = bar(0, "loading");
    let mut trials = load_path(&path, &paper, |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })
    .with_context(|| format!("loading {}", path.display()))?;
    pb.finish_and_clear();
    let rate_hz = trials.first().map_or(
        slipguard_core::sample::PAPER_RATE_HZ,
        |t: &slipguard_data::Trial| t.rate_hz,
    );
    let cfg = paper.scaled_to(rate_hz);
    check_outcomes(&trials, &a)?;
    if a.outcome_from_drop {
        outcomes_from_drop(&mut trials, &cfg);
    }
    let labels: Vec<_> = trials.iter().map(|t| label_annotated(t, &cfg)).collect();
    let selected = |id: &str| a.trials.is_empty() || a.trials.iter().any(|t| t == id);
    if a.stats || (a.plot.is_none() && a.out.is_none()) {
        print_stats(&trials, &labels, &cfg);
    }
    if let Some(file) = single_png {
        let (t, l) = trials
            .iter()
            .zip(&labels)
            .find(|(t, _)| selected(&t.id))
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "--trial {}: no such trial in {}",
                    a.trials[0],
                    path.display()
                )
            })?;
        if let Some(dir) = file.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        plot::plot_trial(t, Some(l), file)?;
        println!("wrote {}", file.display());
    } else if let Some(dir) = &a.plot {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let pairs: Vec<_> = trials
            .iter()
            .zip(&labels)
            .filter(|(t, _)| selected(&t.id))
            .collect();
        let pb = bar(pairs.len() as u64, "plotting");
        for (t, l) in pairs {
            let p = dir.join(format!("real-{}.png", t.id));
            plot::plot_trial(t, Some(l), &p)?;
            println!("wrote {}", p.display());
            pb.inc(1);
        }
        pb.finish_and_clear();
    }
    if let Some(dir) = &a.out {
        write_labelled(dir, &trials, &labels, selected)?;
    }
    Ok(())
}

/// The label settings of the options, in steps at the paper's 16.7 Hz (what [`LabelConfig`]
/// counts in; the loader and `scaled_to` keep these durations at each recording's rate).
fn label_config(a: &Args) -> anyhow::Result<LabelConfig> {
    let paper = LabelConfig {
        unstable_lead_steps: if a.lead_s == 0.0 {
            0
        } else {
            paper_steps(a.lead_s)
        },
        sequence_len: paper_steps(a.seq_s),
        drop_fraction: a.drop_fraction,
        drop_hold_steps: paper_steps(a.drop_hold_s),
        contact_threshold_mn: a.contact_mn,
        contact_threshold_counts: a.contact_counts,
        ..LabelConfig::default()
    };
    paper.check().map_err(anyhow::Error::msg)?;
    Ok(paper)
}

/// Refuses `--out` for recordings without an outcome unless `--outcome-from-drop` decides it.
fn check_outcomes(trials: &[slipguard_data::Trial], a: &Args) -> anyhow::Result<()> {
    let unknown: Vec<&str> = trials
        .iter()
        .filter(|t| t.outcome == Outcome::Unknown)
        .map(|t| t.id.as_str())
        .collect();
    if a.out.is_some() && !a.outcome_from_drop && !unknown.is_empty() {
        anyhow::bail!(
            "{} of {} recordings have no outcome ({}{}), so they would get no labels: add \
             --outcome-from-drop (or put `# outcome: success|failure` into each recording)",
            unknown.len(),
            trials.len(),
            unknown[..unknown.len().min(3)].join(", "),
            if unknown.len() > 3 { ", ..." } else { "" }
        );
    }
    Ok(())
}

/// `--outcome-from-drop`: a trial of unknown outcome is a failure if its force drops for good
/// after the lift, else a success (printed per trial), and is annotated again.
fn outcomes_from_drop(trials: &mut [slipguard_data::Trial], cfg: &LabelConfig) {
    for t in trials.iter_mut().filter(|t| t.outcome == Outcome::Unknown) {
        // `load_path` annotated the trial: the drop step is set when the signal drops.
        t.outcome = match t.drop_step {
            Some(d) => {
                println!(
                    "{}: outcome failure (lasting drop from step {d}, {:.2} s)",
                    t.id,
                    d as f32 / t.rate_hz
                );
                Outcome::Failure
            }
            None => {
                println!("{}: outcome success (no lasting drop)", t.id);
                Outcome::Success
            }
        };
        annotate(t, cfg);
    }
}

/// `--stats`: per trial its marks, drop and label counts, then the label balance and the
/// settings at the recordings' rate.
fn print_stats(
    trials: &[slipguard_data::Trial],
    labels: &[slipguard_data::labels::TrialLabels],
    cfg: &LabelConfig,
) {
    let rate_hz = trials.first().map_or(
        slipguard_core::sample::PAPER_RATE_HZ,
        |t: &slipguard_data::Trial| t.rate_hz,
    );
    let unit = trials
        .first()
        .map_or(slipguard_data::Unit::MilliNewton, |t| t.unit.clone());
    println!(
        "{:<28} {:>8} {:>12} {:>5} {:>5} {:>9} {:>6} {:>8}  contact / excluded",
        "trial", "outcome", "l0/l1/l2", "dip", "drop", "unst.from", "stable", "unstable"
    );
    for (t, l) in trials.iter().zip(labels) {
        let d = detect_drop(t, cfg);
        let m = |x: Option<usize>| x.map_or("-".to_string(), |v| v.to_string());
        let status = match l.status {
            LabelStatus::Labelled => String::new(),
            LabelStatus::NoDrop => "  [skipped: failure without a lasting drop]".into(),
            LabelStatus::UnknownOutcome => "  [skipped: outcome unknown]".into(),
        };
        let nc = l.contact.iter().filter(|&&c| c).count();
        let status = if t.label_estimated() {
            format!("{status}  [marks estimated]")
        } else {
            status
        };
        println!(
            "{:<28} {:>8} {:>12} {:>5} {:>5} {:>9} {:>6} {:>8}  {} / {}{}",
            t.id,
            t.outcome.to_string(),
            t.marks.to_string(),
            m(d.first_dip
                .filter(|_| t.outcome != slipguard_data::Outcome::Success)),
            m(l.drop_step),
            m(l.unstable_from),
            l.n_stable(),
            l.n_unstable(),
            nc,
            l.contact.len() - nc,
            status
        );
    }
    let s = LabelStats::from_labels(labels);
    println!();
    println!(
        "trials {} (labelled {}, skipped {}), failures with a drop {}",
        s.trials, s.labelled, s.skipped, s.failures_with_drop
    );
    let estimated: Vec<bool> = trials.iter().map(|t| t.label_estimated()).collect();
    if estimated.iter().any(|&e| e) {
        // The same counts on each part: marks estimated from the force, and recorded (label.txt).
        for (want, what) in [
            (true, "marks estimated from the force (docs/labels.md)"),
            (false, "recorded marks (label.txt)"),
        ] {
            let part: Vec<slipguard_data::labels::TrialLabels> = labels
                .iter()
                .zip(&estimated)
                .filter(|(_, e)| **e == want)
                .map(|(l, _)| l.clone())
                .collect();
            let p = LabelStats::from_labels(&part);
            println!(
                "  {what}: trials {} (labelled {}, skipped {}), failures with a drop {}, trial-level steps {:.2}% stable, {} per-channel sequences",
                p.trials,
                p.labelled,
                p.skipped,
                p.failures_with_drop,
                100.0 * p.stable_share(),
                p.channel_sequences
            );
        }
    }
    println!(
        "trial-level steps: {} stable / {} unstable = {:.2}% stable",
        s.stable_steps,
        s.unstable_steps,
        100.0 * s.stable_share()
    );
    println!(
        "per-channel sequences: {} (contact channels), {} channels excluded (no contact)",
        s.channel_sequences, s.excluded_channels
    );
    println!(
        "per-channel steps: {} stable / {} unstable = {:.2}% stable",
        s.channel_stable_steps,
        s.channel_unstable_steps,
        100.0 * s.channel_stable_share()
    );
    println!(
        "config at {rate_hz} Hz: lead {} steps ({:.2} s), sequence {} steps ({:.2} s), drop < {} x lift peak for {} steps ({:.2} s), contact >= {} {unit} for {} steps",
        cfg.unstable_lead_steps,
        cfg.unstable_lead_steps as f32 / rate_hz,
        cfg.sequence_len,
        cfg.sequence_len as f32 / rate_hz,
        cfg.drop_fraction,
        cfg.drop_hold_steps,
        cfg.drop_hold_steps as f32 / rate_hz,
        cfg.contact_threshold(&unit),
        cfg.contact_min_run
    );
}

/// `--out`: the selected trials as slipguard recordings with their step labels.
fn write_labelled(
    dir: &std::path::Path,
    trials: &[slipguard_data::Trial],
    labels: &[slipguard_data::labels::TrialLabels],
    selected: impl Fn(&str) -> bool,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (t, l) in trials.iter().zip(labels) {
        if !selected(&t.id) {
            continue;
        }
        let mut t = t.clone();
        if !l.steps.is_empty() {
            let mut v = vec![None; t.n_steps()];
            for (j, s) in l.steps.iter().enumerate() {
                v[l.seq_start + j] = Some(*s);
            }
            t.step_labels = Some(v);
        }
        let p = dir.join(format!("{}.csv", t.id));
        recording::write_recording(&t, &p)?;
    }
    println!("wrote labelled recordings to {}", dir.display());
    Ok(())
}
