//! Command-line edge: clap parsing, progress bars, `anyhow` errors.
//! To add a subcommand (`train`, `eval`, `replay`, `monitor`): add a module with
//! an `Args` struct and `run(args) -> anyhow::Result<()>`, and one variant below.

mod dataset;
mod demo;
mod eval;
mod label;
mod progress;
mod simulate;
mod train;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

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
    Dataset(dataset::DatasetCommand),
    /// Detect drops and contact, label trials as the paper does, print statistics.
    Label(label::Args),
    /// Simulate force or suction trials, or validate the simulator against real data.
    Simulate(simulate::Args),
    /// Train the paper's four LSTM variants (candle), with cross-validation by trial.
    Train(train::Args),
    /// Evaluate checkpoints (float and quantized) on real held-out and simulated data.
    Eval(eval::Args),
    /// Run the shipped models through the bit-exact core on real and simulated data (README's main command).
    Demo(demo::Args),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Dataset(c) => dataset::run(c),
        Command::Label(a) => label::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Train(a) => train::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Demo(a) => demo::run(a),
    }
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
