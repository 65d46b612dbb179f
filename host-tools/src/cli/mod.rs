//! Command-line edge: clap parsing, progress bars, `anyhow` errors.
//! To add a subcommand (`train`, `eval`, `replay`, `monitor`): add a module with
//! an `Args` struct and `run(args) -> anyhow::Result<()>`, and one variant below.

#[cfg(feature = "train")]
mod baselines;
mod bench_host;
mod calibrate;
// The blob and range checks; some serve only `train`.
#[cfg_attr(not(feature = "train"), allow(dead_code))]
mod check;
mod closed_loop;
mod compare;
mod dataset;
mod demo;
mod eval;
mod label;
mod monitor;
mod progress;
mod replay;
mod resample;
mod simulate;
#[cfg(feature = "train")]
mod train;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use slipguard_data::labels::LabelConfig;
use slipguard_data::{Trial, eagle, load_path};

/// slipguard host tools: grasp data, labels, simulator.
#[derive(Debug, Parser)]
#[command(name = "slipguard", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Inspect trial data (eagle-shoal folders or slipguard recordings).
    #[command(subcommand)]
    #[command(after_help = "Example:\n  slipguard dataset info data/eagle-shoal")]
    Dataset(dataset::DatasetCommand),
    /// Detect drops and contact, label trials as the paper does, print statistics.
    #[command(
        after_help = "Examples:\n  slipguard label --stats\n  slipguard label data/eagle-shoal --trial Cheez_100_814_top_3 --plot out/label.png"
    )]
    Label(label::Args),
    /// Simulate force or suction trials, or validate the simulator against real data.
    #[command(
        after_help = "Examples:\n  slipguard simulate --count 20 --seed 5 --out out/sim\n  slipguard simulate --validate --report-dir out/sim-validation"
    )]
    Simulate(simulate::Args),
    /// The paper's Table I baselines (NB, KNN, SVM), cross-validated by trial.
    #[cfg(feature = "train")]
    #[command(after_help = "Example:\n  slipguard baselines --folds 5 --models nb,knn")]
    Baselines(baselines::Args),
    /// Watch the firmware's flag stream (serial port or capture): live view, loss counts, recording.
    #[command(
        after_help = "Examples:\n  slipguard monitor --port /dev/ttyUSB0 --info --grasp-start\n  slipguard monitor --capture frames.bin --view lines --record out/trial.csv"
    )]
    Monitor(monitor::Args),
    /// Run a trial through the firmware's exact path; write the frames it would send and a Fig. 8 plot.
    #[command(
        after_help = "Examples:\n  slipguard replay data/eagle-shoal/trials/Cheez_100_814_top_3 --script marks --png out/fig8.png\n  slipguard replay trial.csv --model models/hand-force/hand-force.bin --out frames.bin"
    )]
    Replay(replay::Args),
    /// Recordings at another frame rate (band-limited), marks and labels moved by time.
    #[command(
        after_help = "Example:\n  slipguard resample data/eagle-shoal --rate-hz 40 --out out/real40"
    )]
    Resample(resample::Args),
    /// Simulated hand lifting objects with a light grip: drop rate with slip prediction off vs on.
    #[command(
        after_help = "Example:\n  slipguard closed-loop --trials 20 --oracle --out out/closed-loop"
    )]
    ClosedLoop(closed_loop::Args),
    /// Train the paper's four LSTM variants (candle), with cross-validation by trial.
    #[cfg(feature = "train")]
    #[command(
        after_help = "Examples:\n  slipguard train --variant lstm --hidden 32 --epochs 5 --out runs/quick\n  slipguard train --variant all --cv 5 --tune-decision --out runs/cv"
    )]
    Train(Box<train::Args>),
    /// Evaluate checkpoints (float and quantized) on real held-out and simulated data.
    #[command(
        after_help = "Example:\n  slipguard eval models/hand-force/hand-force.safetensors runs/cv/lstm"
    )]
    Eval(eval::Args),
    /// The hand flag against the hand-load rule over repeated cross-validation (seeds): mean and
    /// range, and paired per grasp.
    #[command(after_help = "Examples:
  slipguard compare runs/s1/hf runs/s2/hf runs/s3/hf
  slipguard compare --seeds 1,2,3 --out runs/compare -- --variant data-stft-lstm --force-diff --cv 5 --tune-decision")]
    Compare(compare::Args),
    /// Threshold and hysteresis from held grasps only, within a false-alarm budget.
    #[command(
        after_help = "Examples:\n  slipguard calibrate labelled --false-alarm-budget 0.1 --out calibration.txt\n  slipguard calibrate data/eagle-shoal --false-alarm-budget 0.1 --cv 4"
    )]
    Calibrate(calibrate::Args),
    /// Run the shipped models through the bit-exact core on real and simulated data (README's main command).
    #[command(after_help = "Example:\n  slipguard demo --out out/demo")]
    Demo(demo::Args),
    /// Host throughput of the bit-exact core: batched vs single-step path (and PyTorch), in channel-steps/s.
    #[command(
        after_help = "Examples:\n  slipguard bench-host\n  slipguard bench-host --run-torch\n  slipguard bench-host --seconds 0.2 --batch 16,256 --torch out/torch.json"
    )]
    BenchHost(bench_host::Args),
    /// `train` and `baselines` in a build without the `train` feature: a clear error.
    #[cfg(not(feature = "train"))]
    #[command(external_subcommand)]
    NotBuilt(Vec<String>),
}

/// The real trials (default: `$SLIPGUARD_DATA` or the repository's `data/eagle-shoal`),
/// annotated with the default labelling rules; a clear message when the folder is missing.
pub fn load_real_trials(path: Option<&Path>) -> anyhow::Result<(PathBuf, Vec<Trial>)> {
    let path = path.map_or_else(eagle::default_data_dir, Path::to_path_buf);
    anyhow::ensure!(
        path.exists(),
        "data folder {} not found: set SLIPGUARD_DATA or pass the eagle-shoal folder \
         (the repository ships the trials in data/eagle-shoal)",
        path.display()
    );
    let cfg = LabelConfig::default();
    let trials =
        load_path(&path, &cfg, |_, _| {}).with_context(|| format!("loading {}", path.display()))?;
    Ok((path, trials))
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Dataset(c) => dataset::run(c),
        Command::Label(a) => label::run(a),
        Command::Simulate(a) => simulate::run(a),
        #[cfg(feature = "train")]
        Command::Baselines(a) => baselines::run(a),
        Command::Monitor(a) => monitor::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Resample(a) => resample::run(a),
        Command::ClosedLoop(a) => closed_loop::run(a),
        #[cfg(feature = "train")]
        Command::Train(a) => train::run(*a),
        Command::Eval(a) => eval::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Demo(a) => demo::run(a),
        Command::BenchHost(a) => bench_host::run(a),
        #[cfg(not(feature = "train"))]
        Command::NotBuilt(args) => {
            let name = args.first().map_or("", String::as_str);
            anyhow::bail!(
                "`{name}` is not a subcommand of this build: `train` and `baselines` need the \
                 default feature `train` (this binary was built with --no-default-features); \
                 run it as `cargo run --release -p slipguard -- {name} ...`"
            )
        }
    }
}

pub fn main() -> ExitCode {
    slipguard_data::pipe::exit_quietly_on_broken_pipe();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
