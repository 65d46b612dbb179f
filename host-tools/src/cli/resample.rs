//! `slipguard resample DATA --rate-hz 40 --out DIR`: labelled recordings at another frame rate
//! (band-limited, `slipguard_data::resample`), e.g. the 16.7 Hz real trials at the hand
//! profile's 40 Hz for training a 40 Hz model on real grasps.
use std::path::PathBuf;

use anyhow::Context;
use slipguard_data::labels::{LabelConfig, label_annotated};
use slipguard_data::{Outcome, load_path, recording, resample};

use super::progress::bar;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset root, trial folder, recording or folder of recordings (one rate), e.g.
    /// data/eagle-shoal.
    pub path: PathBuf,
    /// Target frame rate, Hz: at least the data's own (a lower rate would cut the band the
    /// recordings hold; the new rate's Nyquist must cover the source's).
    #[arg(long = "rate-hz", value_parser = super::check::positive_f32)]
    pub rate_hz: f32,
    /// Folder for the resampled recordings (created; existing recordings of the same name are
    /// not overwritten).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    // Everything that can be refused before loading: the output and the rate's bounds.
    anyhow::ensure!(
        !a.out.is_file(),
        "--out {}: is a file; give a folder for the resampled recordings",
        a.out.display()
    );
    anyhow::ensure!(
        (recording::MIN_RATE_HZ..=recording::MAX_RATE_HZ).contains(&a.rate_hz),
        "--rate-hz {}: a recording's rate is {}..={} Hz",
        a.rate_hz,
        recording::MIN_RATE_HZ,
        recording::MAX_RATE_HZ
    );
    let cfg = LabelConfig::default();
    let pb = bar(0, "loading");
    let trials = load_path(&a.path, &cfg, |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })
    .with_context(|| format!("loading {}", a.path.display()))?;
    pb.finish_and_clear();
    let Some(first) = trials.first() else {
        anyhow::bail!("{}: no trials", a.path.display());
    };
    let from = first.rate_hz;
    anyhow::ensure!(
        a.rate_hz >= from * 0.995,
        "--rate-hz {}: below the data's {from} Hz, whose band reaches {} Hz (Nyquist); resample \
         up (e.g. --rate-hz 40) or record at the lower rate",
        a.rate_hz,
        from / 2.0
    );
    let paths: Vec<PathBuf> = trials
        .iter()
        .map(|t| a.out.join(format!("{}.csv", t.id)))
        .collect();
    if let Some(p) = paths.iter().find(|p| p.exists()) {
        anyhow::bail!(
            "{} exists: give an empty --out folder (resample does not overwrite recordings)",
            p.display()
        );
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    // Labels as `slipguard label --out` writes them (the paper's rules at the source rate),
    // then moved to the new time base with the samples and marks.
    let at_source = cfg.scaled_to(from);
    let (mut failures, mut labelled) = (0, 0);
    for (t, p) in trials.iter().zip(&paths) {
        let mut t = t.clone();
        if t.step_labels.is_none() && t.outcome != Outcome::Unknown {
            let l = label_annotated(&t, &at_source);
            if !l.steps.is_empty() {
                let mut v = vec![None; t.n_steps()];
                for (j, s) in l.steps.iter().enumerate() {
                    v[l.seq_start + j] = Some(*s);
                }
                t.step_labels = Some(v);
            }
        }
        labelled += usize::from(t.step_labels.is_some());
        failures += usize::from(t.outcome == Outcome::Failure);
        let r = resample::to_rate(&t, a.rate_hz).with_context(|| t.id.clone())?;
        recording::write_recording(&r, p)?;
    }
    println!(
        "wrote {} recordings ({} failures, {} with step labels) at {} Hz (from {from} Hz) to {}",
        trials.len(),
        failures,
        labelled,
        a.rate_hz,
        a.out.display()
    );
    Ok(())
}
