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
    /// Draw a PNG per trial (or per --trial) into this folder.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Only these trial ids (repeatable) for --plot and --out.
    #[arg(long = "trial")]
    pub trials: Vec<String>,
    /// Write labelled trials as slipguard recordings into this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Steps before the drop from which steps are unstable.
    #[arg(long, default_value_t = 20, value_parser = super::check::usize_in!(0..=100_000))]
    pub lead: usize,
    /// Sequence length from grasp start.
    #[arg(long, default_value_t = 160, value_parser = super::check::usize_in!(1..=1_000_000))]
    pub seq_len: usize,
    /// Drop when the contact sum is below this fraction of its lift-window peak...
    #[arg(long, default_value_t = 0.05, value_parser = super::check::open_unit_f32)]
    pub drop_fraction: f32,
    /// ... for this many steps.
    #[arg(long, default_value_t = 10, value_parser = super::check::usize_in!(1..=100_000))]
    pub drop_hold: usize,
    /// Contact threshold (mN above baseline) for force channels.
    #[arg(long, default_value_t = 500.0, value_parser = super::check::positive_f32)]
    pub contact_mn: f32,
    /// Trials of unknown outcome (the monitor's recordings): failure if the force shows a
    /// lasting drop after the lift, else success (printed per trial; check it against what you
    /// saw, and fix a wrong one with `# outcome:` in the recording).
    #[arg(long)]
    pub outcome_from_drop: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let cfg = LabelConfig {
        unstable_lead_steps: a.lead,
        sequence_len: a.seq_len,
        drop_fraction: a.drop_fraction,
        drop_hold_steps: a.drop_hold,
        contact_threshold_mn: a.contact_mn,
        ..LabelConfig::default()
    };
    cfg.check().map_err(anyhow::Error::msg)?;
    let path = a.path.clone().unwrap_or_else(eagle::default_data_dir);
    let pb = bar(0, "loading");
    let trials = load_path(&path, &cfg, |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })
    .with_context(|| format!("loading {}", path.display()))?;
    pb.finish_and_clear();
    let mut trials = trials;
    if a.outcome_from_drop {
        for t in trials.iter_mut().filter(|t| t.outcome == Outcome::Unknown) {
            // `load_path` annotated the trial: the drop step is set when the force drops.
            t.outcome = match t.drop_step {
                Some(d) => {
                    println!("{}: outcome failure (lasting drop from step {d})", t.id);
                    Outcome::Failure
                }
                None => {
                    println!("{}: outcome success (no lasting drop)", t.id);
                    Outcome::Success
                }
            };
            annotate(t, &cfg);
        }
    }
    let labels: Vec<_> = trials.iter().map(|t| label_annotated(t, &cfg)).collect();
    let selected = |id: &str| a.trials.is_empty() || a.trials.iter().any(|t| t == id);

    if a.stats || (a.plot.is_none() && a.out.is_none()) {
        println!(
            "{:<28} {:>8} {:>12} {:>5} {:>5} {:>9} {:>6} {:>8}  contact / excluded",
            "trial", "outcome", "l0/l1/l2", "dip", "drop", "unst.from", "stable", "unstable"
        );
        for (t, l) in trials.iter().zip(&labels) {
            let d = detect_drop(t, &cfg);
            let m = |x: Option<usize>| x.map_or("-".to_string(), |v| v.to_string());
            let status = match l.status {
                LabelStatus::Labelled => String::new(),
                LabelStatus::NoDrop => "  [skipped: failure without a lasting drop]".into(),
                LabelStatus::UnknownOutcome => "  [skipped: outcome unknown]".into(),
            };
            let nc = l.contact.iter().filter(|&&c| c).count();
            println!(
                "{:<28} {:>8} {:>12} {:>5} {:>5} {:>9} {:>6} {:>8}  {} / {}{}",
                t.id,
                t.outcome.to_string(),
                format!(
                    "{}/{}/{}",
                    m(t.marks.grasp_start),
                    m(t.marks.lift_start),
                    m(t.marks.open_start)
                ),
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
        let s = LabelStats::from_labels(&labels);
        println!();
        println!(
            "trials {} (labelled {}, skipped {}), failures with a drop {}",
            s.trials, s.labelled, s.skipped, s.failures_with_drop
        );
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
            "config: lead {} steps, sequence {} steps, drop < {} x lift peak for {} steps, contact >= {} mN for {} steps",
            cfg.unstable_lead_steps,
            cfg.sequence_len,
            cfg.drop_fraction,
            cfg.drop_hold_steps,
            cfg.contact_threshold_mn,
            cfg.contact_min_run
        );
    }
    if let Some(dir) = &a.plot {
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
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for (t, l) in trials.iter().zip(&labels) {
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
    }
    Ok(())
}
