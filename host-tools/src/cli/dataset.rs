//! `slipguard dataset info PATH`.
use std::path::PathBuf;

use clap::Subcommand;
use slipguard_data::labels::LabelConfig;
use slipguard_data::{Outcome, eagle, load_path};

use super::progress::bar;

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Summarise every trial: size, rate, unit, marks, outcome, drop step, contact channels.
    #[command(after_help = "Examples:\n  slipguard dataset info\n  slipguard dataset info out/sim")]
    Info {
        /// Dataset root, trial folder, recording file or folder of recordings
        /// (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
        path: Option<PathBuf>,
    },
}

pub fn run(cmd: DatasetCommand) -> anyhow::Result<()> {
    match cmd {
        DatasetCommand::Info { path } => info(path),
    }
}

fn info(path: Option<PathBuf>) -> anyhow::Result<()> {
    let path = path.unwrap_or_else(eagle::default_data_dir);
    let pb = bar(0, "loading");
    let trials = load_path(&path, &LabelConfig::default(), |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })?;
    pb.finish_and_clear();
    println!("{}: {} trials", path.display(), trials.len());
    println!(
        "{:<28} {:>5} {:>3} {:>6} {:>6} {:>13} {:>8} {:>5} {:>8}  contact channels",
        "trial", "steps", "ch", "Hz", "unit", "marks l0/l1/l2", "outcome", "drop", "max"
    );
    for t in &trials {
        let m = |x: Option<usize>| x.map_or("-".to_string(), |v| v.to_string());
        let max = t.samples.iter().flatten().copied().fold(f32::MIN, f32::max);
        let contact: Vec<&str> = t
            .contact_channels()
            .iter()
            .map(|&c| t.channel_names[c].as_str())
            .collect();
        println!(
            "{:<28} {:>5} {:>3} {:>6} {:>6} {:>13} {:>8} {:>5} {:>8}  {}",
            t.id,
            t.n_steps(),
            t.n_channels(),
            t.rate_hz,
            t.unit.to_string(),
            t.marks.to_string(),
            t.outcome.to_string(),
            m(t.drop_step),
            max,
            if contact.is_empty() {
                "none".to_string()
            } else {
                contact.join(",")
            }
        );
    }
    let count = |o: Outcome| trials.iter().filter(|t| t.outcome == o).count();
    println!(
        "outcomes: {} success, {} failure, {} unknown",
        count(Outcome::Success),
        count(Outcome::Failure),
        count(Outcome::Unknown)
    );
    Ok(())
}
