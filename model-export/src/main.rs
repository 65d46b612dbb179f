//! `slipguard-export`: trained float weights (PyTorch/safetensors, ONNX, Keras 3) → the
//! firmware's quantized model blob, with calibration, a report, `inspect` and `verify`.
//! Exit codes: docs/export.md.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use slipguard_core::blob::AlignedBlob;
use slipguard_export::calib;
use slipguard_export::error::{ExportError, Result};
use slipguard_export::import::Format;
use slipguard_export::inspect;
use slipguard_export::pipeline::{self, ExportOptions, ModelSource};
use slipguard_export::write::{atomic_write, rust_snippet};

const EXAMPLES: &str = "\
Examples, one per input format:
  # our trainer / any PyTorch nn.LSTM + nn.Linear state_dict saved as safetensors (settings in its metadata)
  slipguard-export export runs/c.safetensors --data data/eagle-shoal -o model.bin --rust-snippet model_blob.rs

  # ONNX from torch.onnx.export (settings from a JSON file and options)
  slipguard-export export slip.onnx --settings slip.settings.json --variant c --data rec/ -o model.bin

  # Keras 3 archive (activations are checked from its config)
  slipguard-export export slip.keras --variant d --norm-mean '[...]' --norm-std '[...]' --data rec/ -o model.bin

  # Keras 3 weights only (add --keras-config config.json to check the activations)
  slipguard-export export slip.weights.h5 --variant c --fit-norm --data rec/ -o model.bin

  slipguard-export inspect model.bin
  slipguard-export verify model.bin --float runs/c.safetensors --data data/eagle-shoal

Exit codes: 0 ok, 2 usage, 3 I/O, 4 unreadable/truncated file, 5 missing or misnamed tensor,
6 wrong shape, 7 NaN/Inf weight, 8 unsupported construct, 9 over the firmware's bounds,
10 bad setting, 11 data, 12 invalid blob, 13 verification failed.";

#[derive(Parser)]
#[command(name = "slipguard-export", version, about = "Trained float LSTM → slipguard's quantized model blob (format v1, v2 with a hand rule)", after_help = EXAMPLES)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Import a model, calibrate, quantize, write the blob, report and optional Rust snippet.
    #[command(after_help = EXAMPLES)]
    Export(ExportArgs),
    /// Print a blob's header, tensor sizes, MACs per step, flash and RAM needed, and CRC.
    #[command(
        after_help = "Examples:\n  slipguard-export inspect model.bin\n  slipguard-export inspect model.bin --json > model.json"
    )]
    Inspect {
        /// The blob.
        blob: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Rerun the quantized-vs-float comparison of a blob against its float checkpoint.
    #[command(after_help = EXAMPLES)]
    Verify(VerifyArgs),
    /// Send a blob to the board over its serial link; it becomes the active model once the
    /// board has checked it (docs/protocol.md, "Model upload"). Exit codes: 3 port or no reply,
    /// 12 invalid blob, 13 not active after commit, 14 refused by the board (the message says
    /// what to fix).
    #[command(after_help = "Example:\n  slipguard-export upload model.bin --port /dev/ttyUSB0")]
    Upload(UploadArgs),
    /// Run a blob over a raw trace (or a feature file) and print p(unstable) and the flag per
    /// step, as the device computes them; `--check-features` compares a feature file with the
    /// blob's front end.
    #[command(after_help = RUN_EXAMPLES)]
    Run(RunArgs),
}

#[derive(Args)]
struct UploadArgs {
    /// The blob.
    blob: PathBuf,
    /// Serial port of the board's UART (e.g. /dev/ttyUSB0, COM3).
    #[arg(long)]
    port: String,
    /// Baud rate, bit/s (≥ 1).
    #[arg(long, default_value_t = 921_600, value_parser = clap::value_parser!(u32).range(1..), allow_negative_numbers = true)]
    baud: u32,
    /// Send release first (the board refuses an upload while flagging is armed); only when
    /// the hand is open.
    #[arg(long)]
    release: bool,
    /// Seconds to wait while the board refuses begin or commit because flagging is armed (a
    /// grasp in progress), asking again every 0.5 s; 0: give up at once.
    #[arg(long, default_value_t = 10.0, value_parser = wait_seconds)]
    wait_armed: f64,
}

/// clap parser: a wait in seconds, 0 ≤ x ≤ 3600.
fn wait_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=3600.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} s is not in the allowed range 0 ≤ x ≤ 3600 s")),
        Err(_) => Err(format!("`{s}` is not a number of seconds")),
    }
}

/// clap parser: a share, 0 ≤ x ≤ 1.
fn share(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} is not in the allowed range 0 ≤ x ≤ 1")),
        Err(_) => Err(format!("`{s}` is not a number")),
    }
}

/// clap parser: a bound on |Δp|, 0 ≤ x ≤ 1 (0: any difference fails).
fn dp_bound(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} is not in the allowed range 0 ≤ x ≤ 1")),
        Err(_) => Err(format!("`{s}` is not a number")),
    }
}

const RUN_EXAMPLES: &str = "\
Examples:
  # p and flag per step for each column of raw samples (sensor units, e.g. mN), from a reset state
  slipguard-export run model.bin trace.csv > p.csv
  # the same from normalised features (one row per step, the model's feature order)
  slipguard-export run model.bin features.csv --features
  # compare your normalised features with the blob's front end on the same raw trace
  slipguard-export run model.bin trace.csv --check-features features.csv

Input files: numbers separated by commas or spaces, one row per step, an optional header row.";

#[derive(Args)]
struct RunArgs {
    /// The blob.
    blob: PathBuf,
    /// Raw samples, one column per channel (or, with --features, normalised features).
    input: PathBuf,
    /// The input holds normalised features (T × F, order [force, d(t), bands…]), not raw samples.
    #[arg(long)]
    features: bool,
    /// A file of normalised features (T × F) to compare with the blob's own features computed
    /// from the raw trace (its first column, or --column); exits 13 when a feature differs by
    /// more than 0.01.
    #[arg(long)]
    check_features: Option<PathBuf>,
    /// Column of the raw trace to use with --check-features (0-based index).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    column: usize,
}

/// How to read the model and its settings (later sources win: defaults < file metadata <
/// --settings < options).
#[derive(Args, Clone, Default)]
struct ModelArgs {
    /// Input format (default: from the file name, then the first bytes).
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Keras model config (config.json) for a bare .weights.h5, to check its activations.
    #[arg(long)]
    keras_config: Option<PathBuf>,
    /// JSON object of settings (same keys as the safetensors metadata, docs/export.md).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Variant: a|lstm, b|stft-lstm, c|data-stft-lstm (default), d|lstm-stft-lstm.
    #[arg(long)]
    variant: Option<String>,
    /// d(t) = x(t) - x(t-1) is an input (true/false; default false).
    #[arg(long)]
    force_diff: Option<String>,
    /// Sample rate the model was trained at, Hz (> 0; default 16.7).
    #[arg(long, allow_negative_numbers = true)]
    sample_rate: Option<String>,
    /// Unit of raw samples: mN (default) or counts.
    #[arg(long)]
    input_unit: Option<String>,
    /// Raw value mapped to 0, in the input unit (mN or counts; integer, may be negative;
    /// default 0).
    #[arg(long, allow_hyphen_values = true)]
    input_offset: Option<String>,
    /// Raw span mapped to +1.0, in the input unit (mN or counts; integer > 0; default 10000).
    #[arg(long, allow_negative_numbers = true)]
    input_full_scale: Option<String>,
    /// STFT window length N, samples (4 to 48; default 20).
    #[arg(long, allow_negative_numbers = true)]
    stft_window: Option<String>,
    /// First STFT bin, DFT bin index (default 1: the DC bin 0 left out).
    #[arg(long, allow_negative_numbers = true)]
    stft_first_bin: Option<String>,
    /// Number of STFT bins, count (default 10).
    #[arg(long, allow_negative_numbers = true)]
    stft_bins: Option<String>,
    /// STFT window shape: rectangular (default) or hann.
    #[arg(long)]
    stft_shape: Option<String>,
    /// p(unstable) threshold, probability (0 < p < 1; default 0.5).
    #[arg(long, allow_negative_numbers = true)]
    threshold: Option<String>,
    /// Consecutive steps at/above the threshold before the flag rises, steps (1 to 255; default 1).
    #[arg(long, allow_negative_numbers = true)]
    raise_after: Option<String>,
    /// Consecutive steps below the threshold before the flag clears, steps (1 to 255; default 1).
    #[arg(long, allow_negative_numbers = true)]
    clear_after: Option<String>,
    /// Model name (ASCII, ≤ 12 bytes; default: the file's stem).
    #[arg(long)]
    name: Option<String>,
    /// Model id, integer 0 to 4 294 967 295 (default: CRC-32 of the float weights).
    #[arg(long, allow_negative_numbers = true)]
    model_id: Option<String>,
    /// Normalisation means, JSON array in feature order [force, d(t), bands...].
    #[arg(long, allow_hyphen_values = true)]
    norm_mean: Option<String>,
    /// Normalisation standard deviations, JSON array.
    #[arg(long)]
    norm_std: Option<String>,
    /// Dual variant (d): the order in which the dense layer sees the hidden states,
    /// force,bands or bands,force; needed when the file does not say (a state_dict not named
    /// as our trainer's, a bare .weights.h5, an ONNX graph without the Concat).
    #[arg(long)]
    dual_order: Option<String>,
    /// Put a hand rule into the blob (format v2), fused with the model's hand flag in the
    /// firmware: FRACTION,GUARD,WINDOW_S = the rule alone flags under FRACTION of the hand
    /// load's peak over WINDOW_S seconds (0 = never), the model's flag counts under GUARD of it
    /// (1 = no guard); e.g. 0.4,0.8,0.6. Overrides the hand_rule_* metadata keys.
    #[arg(long, allow_negative_numbers = true)]
    hand_rule: Option<String>,
}

impl ModelArgs {
    fn source(&self, path: PathBuf) -> ModelSource {
        let pairs = [
            ("variant", &self.variant),
            ("force_diff", &self.force_diff),
            ("sample_rate_hz", &self.sample_rate),
            ("input_unit", &self.input_unit),
            ("input_offset", &self.input_offset),
            ("input_full_scale", &self.input_full_scale),
            ("stft_window", &self.stft_window),
            ("stft_first_bin", &self.stft_first_bin),
            ("stft_bins", &self.stft_bins),
            ("stft_shape", &self.stft_shape),
            ("threshold", &self.threshold),
            ("raise_after", &self.raise_after),
            ("clear_after", &self.clear_after),
            ("name", &self.name),
            ("model_id", &self.model_id),
            ("norm_mean", &self.norm_mean),
            ("norm_std", &self.norm_std),
            ("dual_order", &self.dual_order),
            (slipguard_export::settings::HAND_RULE, &self.hand_rule),
        ];
        ModelSource {
            path,
            format: self.format,
            keras_config: self.keras_config.clone(),
            settings_file: self.settings.clone(),
            overrides: pairs
                .iter()
                .filter_map(|(k, v)| v.as_ref().map(|v| (k.to_string(), v.clone())))
                .collect(),
        }
    }
}

#[derive(Args)]
struct ExportArgs {
    /// The trained model: .safetensors, .onnx, .keras or .weights.h5.
    model: PathBuf,
    #[command(flatten)]
    m: ModelArgs,
    /// Output blob.
    #[arg(short, long, default_value = "model.bin")]
    output: PathBuf,
    /// Calibration data: a recording (.csv), a folder of recordings, or an eagle-shoal folder.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Validation data for the quantized-vs-float agreement (default: the calibration data).
    #[arg(long)]
    validation: Option<PathBuf>,
    /// Use at most this many trials of each data set (count ≥ 1).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..), allow_negative_numbers = true)]
    max_trials: Option<usize>,
    /// Fit the normalisation on --data when the model carries none (must match training).
    #[arg(long)]
    fit_norm: bool,
    /// Fixed cell fractional bits C, bits (1 to 15; c is Q(15-C).C), e.g. 11 or 11,10, instead
    /// of calibrating.
    #[arg(long, allow_negative_numbers = true)]
    cell_bits: Option<String>,
    /// Also write a Rust source file that places the blob in the firmware's `.model` section.
    #[arg(long)]
    rust_snippet: Option<PathBuf>,
    /// Report path prefix: writes PREFIX.md and PREFIX.json (default: the output's name with
    /// `.report` added, e.g. `-o mine.bin` writes mine.bin.report.md and mine.bin.report.json).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Do not write the report files.
    #[arg(long)]
    no_report: bool,
    /// Measure the agreement on the calibration data itself (default without --validation:
    /// every 5th trial of --data is held out of calibration and measured on).
    #[arg(long)]
    no_holdout: bool,
    /// No progress bars.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Args)]
struct VerifyArgs {
    /// The blob to check.
    blob: PathBuf,
    /// The float checkpoint it was exported from.
    #[arg(long = "float")]
    float: PathBuf,
    /// Data to compare on (recording, folder, eagle-shoal folder).
    #[arg(long)]
    data: PathBuf,
    #[command(flatten)]
    m: ModelArgs,
    /// Use at most this many trials (count ≥ 1).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..), allow_negative_numbers = true)]
    max_trials: Option<usize>,
    /// Fail (exit 13) below this flag agreement on decisive steps (float p at least 0.02 from
    /// the threshold over the hysteresis window); 0 ≤ x ≤ 1.
    #[arg(long, default_value_t = calib::MIN_DECISIVE_AGREEMENT, value_parser = share, allow_negative_numbers = true)]
    min_flag_agreement: f64,
    /// Fail (exit 13) above this max |Δp| over every step of every whole recording; 0 ≤ x ≤ 1.
    #[arg(long, default_value_t = calib::MAX_DP, value_parser = dp_bound, allow_negative_numbers = true)]
    max_dp: f32,
    /// Write the agreement as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// No progress bars.
    #[arg(short, long)]
    quiet: bool,
}

fn cell_bits(s: &str) -> Result<[u8; 2]> {
    let parts: Vec<&str> = s.split(',').collect();
    let parse = |p: &str| -> Result<u8> {
        p.trim()
            .parse::<u8>()
            .ok()
            .filter(|b| (1..=15).contains(b))
            .ok_or_else(|| ExportError::Usage(format!("--cell-bits: `{p}` is not in 1..=15")))
    };
    match parts.as_slice() {
        [a] => Ok([parse(a)?, parse(a)?]),
        [a, b] => Ok([parse(a)?, parse(b)?]),
        _ => Err(ExportError::Usage("--cell-bits takes C or C0,C1".into())),
    }
}

fn run_export(a: ExportArgs) -> Result<()> {
    let opts = ExportOptions {
        source: a.m.source(a.model.clone()),
        data: a.data.clone(),
        validation: a.validation.clone(),
        max_trials: a.max_trials,
        fit_norm: a.fit_norm,
        cell_bits: a.cell_bits.as_deref().map(cell_bits).transpose()?,
        quiet: a.quiet,
        no_holdout: a.no_holdout,
    };
    let ex = pipeline::export(&opts)?;
    // Everything is computed before the first byte is written; each file goes through a rename.
    atomic_write(&a.output, &ex.blob)?;
    let name = ex.model.config.name_str().to_string();
    if let Some(p) = &a.rust_snippet {
        atomic_write(
            p,
            rust_snippet(
                &ex.blob,
                &a.model.display().to_string(),
                &name,
                ex.report.blob.crc,
            )
            .as_bytes(),
        )?;
    }
    if !a.no_report {
        let prefix = a.report.clone().unwrap_or_else(|| {
            let mut p = a.output.clone().into_os_string();
            p.push(".report");
            PathBuf::from(p)
        });
        let with = |ext: &str| {
            let mut p = prefix.clone().into_os_string();
            p.push(ext);
            PathBuf::from(p)
        };
        let (md, js) = (with(".md"), with(".json"));
        atomic_write(&md, ex.report.markdown().as_bytes())?;
        let json = serde_json::to_string_pretty(&ex.report).unwrap_or_default();
        atomic_write(&js, json.as_bytes())?;
        eprintln!("report: {} and {}", md.display(), js.display());
    }
    let r = &ex.report;
    println!(
        "wrote {} ({} bytes, CRC-32 {:#010x}): {} `{}`, hidden {:?}, {} MACs/step",
        a.output.display(),
        ex.blob.len(),
        r.blob.crc,
        ex.model.config.variant.name(),
        name,
        &ex.model.config.hidden[..ex.model.lstms.len()],
        r.blob.macs_lstm_dense + r.blob.macs_stft
    );
    for n in &r.notes {
        eprintln!("note: {n}");
    }
    if let Some(c) = &r.calibration {
        println!(
            "calibration: {} sequences, {} steps, max|c| {:?} → cell bits {:?}",
            c.sequences, c.steps, c.max_abs_cell, c.cell_frac_bits
        );
    }
    if let Some(ag) = &r.agreement {
        if let Some(d) = &r.agreement_data {
            println!("agreement data: {d}");
        }
        print_agreement(ag);
        if let Some(over) = ag.over_bounds(calib::MAX_DP, calib::MIN_DECISIVE_AGREEMENT) {
            eprintln!(
                "warning: the blob does not follow the float model closely enough: {over}; see the per-tensor errors in the report"
            );
            if let Some(w) = &r.weight_loss {
                eprintln!("hint: {}", w.remedy);
                for t in w.tensors.iter().filter(|t| !t.remedy.is_empty()) {
                    let rows: Vec<String> = t
                        .dominant_rows
                        .iter()
                        .map(|r| format!("{} ({})", r.row, r.role))
                        .collect();
                    eprintln!(
                        "hint: {} (max |Δp| {:.3} alone; rows {} carry {:.0} % of its error): {}",
                        t.tensor,
                        t.max_abs_dp,
                        rows.join(", "),
                        100.0 * t.dominant_share,
                        t.remedy
                    );
                }
            }
        }
    } else {
        eprintln!("warning: no --data: quantized-vs-float agreement not measured");
    }
    if a.data.is_none() && a.cell_bits.is_none() {
        let c = slipguard_core::quantize::DEFAULT_CELL_FRAC_BITS;
        eprintln!(
            "warning: no --data: the cell state uses the default format Q{}.{c} (±{}) without calibration; a larger |c| saturates, a smaller one loses precision: pass --data (recordings) or --cell-bits",
            15 - c,
            1u32 << (15 - c)
        );
    }
    Ok(())
}

fn print_agreement(ag: &calib::Agreement) {
    println!(
        "quantized vs float over {} whole recordings: flag agreement {:.3} % ({} of {} steps differ; {:.3} % on the {} decisive steps), max |Δp| {:.5}, mean |Δp| {:.6}",
        ag.sequences,
        100.0 * ag.flag_agreement,
        ag.flag_disagreements,
        ag.steps,
        100.0 * ag.decisive_flag_agreement,
        ag.decisive_steps,
        ag.max_abs_dp,
        ag.mean_abs_dp
    );
    if let Some(w) = &ag.worst {
        println!(
            "worst step: trial {} channel {} step {} (float p {:.4}, blob p {:.4})",
            w.trial, w.channel, w.step, w.p_float, w.p_quantized
        );
    }
    if let (Some(f), Some(q)) = (&ag.float_metrics, &ag.quant_metrics) {
        let p = |x: Option<f64>| x.map_or("–".to_string(), |v| format!("{:.2} %", 100.0 * v));
        println!(
            "success rate float {} → quantized {}; ahead-drop rate float {} → quantized {}",
            p(f.success_rate),
            p(q.success_rate),
            p(f.ahead_drop_rate),
            p(q.ahead_drop_rate)
        );
    }
}

/// A checkpoint of our trainer lists the validation trials of its training set (`val_trials`) and,
/// for a cross-validation fold, its held-out trials (`heldout_trials`): data that holds one of its
/// validation trials and none held out is the data it was trained on.
fn in_sample_note(float: &std::path::Path, data: &calib::DataSet) -> Option<String> {
    let bytes = std::fs::read(float).ok()?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).ok()?;
    let meta = meta.metadata().as_ref()?;
    let list = |k: &str| -> Vec<&str> {
        meta.get(k)
            .map(|v| v.split(',').filter(|s| !s.is_empty()).collect())
            .unwrap_or_default()
    };
    let (val, held) = (list("val_trials"), list("heldout_trials"));
    let has = |ids: &[&str]| {
        data.sequences
            .iter()
            .any(|s| ids.contains(&s.trial_id.as_str()))
    };
    (has(&val) && !has(&held)).then(|| {
        format!(
            "{} was trained on these trials (in-sample): the agreement is measured on its own \
             training data",
            float.display()
        )
    })
}

fn run_verify(a: VerifyArgs) -> Result<()> {
    let bytes = pipeline::read(&a.blob)?;
    let aligned = AlignedBlob::new(&bytes);
    let blob = aligned.parse().map_err(|e| ExportError::Blob {
        path: a.blob.clone(),
        source: e,
    })?;
    let (float, notes) = pipeline::float_for_blob(&a.m.source(a.float.clone()), &blob)?;
    for n in notes {
        eprintln!("note: {n}");
    }
    let data = calib::load_data(&a.data, &blob.config, a.max_trials, a.quiet)?;
    if let Some(note) = in_sample_note(&a.float, &data) {
        eprintln!("note: {note}");
    }
    let ag = calib::agreement(&float, &bytes, &data, a.quiet)?;
    if float.config.variant.is_hand() {
        let w = slipguard_export::hand::agreement_whole(&float, &bytes, &data.hands)?;
        eprintln!(
            "note: hand-level model: compared from each grasp start to its drop or release; over \
             the whole recordings max |Δp| {:.4}, flag agreement {:.3} %",
            w.max_abs_dp,
            100.0 * w.flag_agreement
        );
    }
    print_agreement(&ag);
    if let Some(j) = &a.json {
        atomic_write(
            j,
            serde_json::to_string_pretty(&ag)
                .unwrap_or_default()
                .as_bytes(),
        )?;
    }
    if let Some(over) = ag.over_bounds(a.max_dp, a.min_flag_agreement) {
        return Err(ExportError::VerifyFailed(format!(
            "{over} (over every step of {} whole recordings)",
            ag.sequences
        )));
    }
    println!("verify: OK");
    Ok(())
}

/// The board's serial port (the `upload` feature's serial stack).
#[cfg(feature = "upload")]
fn open_port(
    port: &str,
    baud: u32,
) -> Result<Box<dyn serialport::SerialPort>, slipguard_export::upload::UploadError> {
    use slipguard_export::upload::UploadError;
    serialport::new(port, baud)
        .timeout(std::time::Duration::from_millis(20))
        .open()
        .map_err(|e| UploadError::Io(std::io::Error::other(format!("{port}: {e}"))))
}

/// Without the `upload` feature there is no serial stack: say how to get one.
#[cfg(not(feature = "upload"))]
fn open_port(
    _port: &str,
    _baud: u32,
) -> Result<std::fs::File, slipguard_export::upload::UploadError> {
    Err(slipguard_export::upload::UploadError::Io(
        std::io::Error::other(
            "this slipguard-export was built without serial support: rebuild it with \
         `--features upload` (e.g. `cargo run --release -p slipguard-export --features upload -- upload ...`)",
        ),
    ))
}

fn run_upload(a: UploadArgs) -> ExitCode {
    use slipguard_export::upload::{Link, Options, UploadError};
    let run = || -> Result<slipguard_export::upload::Uploaded, UploadError> {
        let blob = std::fs::read(&a.blob)
            .map_err(|e| UploadError::Blob(format!("reading {}: {e}", a.blob.display())))?;
        // The file first: a bad blob never opens (or resets) the port.
        slipguard_export::upload::check_blob(&blob).map_err(|e| match e {
            UploadError::Blob(m) => UploadError::Blob(format!("{}: {m}", a.blob.display())),
            e => e,
        })?;
        let port = open_port(&a.port, a.baud)?;
        let mut link = Link::new(port);
        let bar = indicatif::ProgressBar::new(blob.len() as u64);
        let opt = Options {
            release: a.release,
            wait_armed: std::time::Duration::from_secs_f64(a.wait_armed),
            ..Options::default()
        };
        let r = link.upload(&blob, &opt, |done, _| bar.set_position(done as u64));
        bar.finish_and_clear();
        r
    };
    match run() {
        Ok(u) => {
            let name: String = u
                .info
                .name
                .iter()
                .take_while(|&&b| b != 0)
                .map(|&b| b as char)
                .collect();
            println!(
                "upload: OK, model '{name}' {:#010x} at {:.1} Hz active in slot {} (sequence {}) after the board's restart, {} frames resent, {:.1} s waited for release",
                u.info.model_crc,
                u.info.sample_rate_mhz.hz(),
                u.slot,
                u.seq,
                u.resent,
                u.waited_armed.as_secs_f64()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn run_trace(a: RunArgs) -> Result<()> {
    use slipguard_export::run::{FEATURE_TOL, Runner, check_features, read_table};
    let bytes = pipeline::read(&a.blob)?;
    let aligned = AlignedBlob::new(&bytes);
    let parse = || {
        aligned.parse().map_err(|e| ExportError::Blob {
            path: a.blob.clone(),
            source: e,
        })
    };
    let (names, rows) = read_table(&a.input)?;
    if let Some(ff) = &a.check_features {
        let (_, user) = read_table(ff)?;
        if a.column >= names.len() {
            return Err(ExportError::Usage(format!(
                "--column {}: {} has {} columns",
                a.column,
                a.input.display(),
                names.len()
            )));
        }
        let raw: Vec<f32> = rows.iter().map(|r| r[a.column]).collect();
        let checks = check_features(parse()?, &raw, &user)?;
        println!("feature,max_abs_diff,worst_step,first_step_over_{FEATURE_TOL}");
        for c in &checks {
            println!(
                "{},{:.6},{},{}",
                c.feature,
                c.max_abs_diff,
                c.worst_step,
                c.first_over.map_or("-".into(), |s| s.to_string())
            );
        }
        if let Some(c) = checks.iter().find(|c| c.first_over.is_some()) {
            return Err(ExportError::VerifyFailed(format!(
                "feature {} of {} differs from the blob's front end by up to {:.4} (first at step {}); check the units in docs/export.md (raw / full scale, STFT |X_k| / N, μ and σ of those)",
                c.feature,
                ff.display(),
                c.max_abs_diff,
                c.first_over.unwrap_or(0)
            )));
        }
        eprintln!("features agree within {FEATURE_TOL} ({} steps)", raw.len());
        return Ok(());
    }
    let columns = if a.features { 1 } else { names.len() };
    let mut runners = (0..columns)
        .map(|_| Runner::new(parse()?))
        .collect::<Result<Vec<_>>>()?;
    let mut out = String::from("step");
    for n in names.iter().take(columns) {
        if a.features {
            out.push_str(",p,flag");
        } else {
            out.push_str(&format!(",p_{n},flag_{n}"));
        }
    }
    out.push('\n');
    if a.features && rows[0].len() != runners[0].feature_count() {
        return Err(ExportError::Data(format!(
            "{} has {} columns, the blob's model takes {} features [force, d(t), bands]",
            a.input.display(),
            rows[0].len(),
            runners[0].feature_count()
        )));
    }
    for (t, row) in rows.iter().enumerate() {
        out.push_str(&t.to_string());
        for (c, r) in runners.iter_mut().enumerate() {
            let s = if a.features {
                r.step_features(row)
            } else {
                r.step_raw(row[c])
            };
            out.push_str(&format!(
                ",{:.5},{}",
                s.p_q15 as f32 / 32768.0,
                s.unstable as u8
            ));
        }
        out.push('\n');
    }
    print!("{out}");
    Ok(())
}

fn main() -> ExitCode {
    slipguard_data::pipe::exit_quietly_on_broken_pipe();
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Export(a) => run_export(a),
        Cmd::Inspect { blob, json } => pipeline::read(&blob).and_then(|b| {
            let info = inspect::inspect(&blob, &b)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&info).unwrap_or_default()
                );
            } else {
                println!("{info}");
            }
            Ok(())
        }),
        Cmd::Verify(a) => run_verify(a),
        Cmd::Upload(a) => return run_upload(a),
        Cmd::Run(a) => run_trace(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
