//! The export pipeline shared by the CLI and the tests: import → settings → float model →
//! calibration → quantization → agreement → report.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use slipguard_core::blob::{AlignedBlob, ModelBlob, ModelConfig};
use slipguard_core::float::FloatModel;
use slipguard_core::quantize::quantize;

use crate::calib::{self, Agreement, Calibration, DataSet};
use crate::error::{ExportError, Result};
use crate::import::{self, Format, Imported};
use crate::inspect::describe_blob;
use crate::report::{ExportReport, tensor_errors};
use crate::settings::{Resolved, Settings, describe};

/// Where the model comes from and which settings apply.
#[derive(Clone, Debug, Default)]
pub struct ModelSource {
    /// The checkpoint / model file.
    pub path: PathBuf,
    /// Format, when not detected from the name.
    pub format: Option<Format>,
    /// Keras config for a bare `.weights.h5`.
    pub keras_config: Option<PathBuf>,
    /// `--settings FILE.json`.
    pub settings_file: Option<PathBuf>,
    /// Individual options (`--variant` …) as settings keys.
    pub overrides: Vec<(String, String)>,
}

/// A float model and how it was made.
#[derive(Clone, Debug)]
pub struct Loaded {
    /// The model (normalisation filled in unless `norm_given` is false).
    pub model: FloatModel,
    /// What the importer read.
    pub imported: Imported,
    /// Merged settings.
    pub settings: Settings,
    /// Whether the normalisation came from the settings.
    pub norm_given: bool,
}

/// Imports a model file and applies the settings (defaults < file metadata < settings file < options).
pub fn load_float(src: &ModelSource) -> Result<Loaded> {
    let imported = import::import(&src.path, src.format, src.keras_config.as_deref())?;
    let mut settings = Settings::defaults();
    settings.merge(&imported.metadata);
    if let Some(f) = &src.settings_file {
        settings.merge(&Settings::read_json_file(f)?);
    }
    for (k, v) in &src.overrides {
        settings.set(k, v.clone());
    }
    let mut res: Resolved = settings.resolve()?;
    if !res.named {
        let stem = src
            .path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        let stem = stem.trim_end_matches(".weights");
        let n: String = stem
            .chars()
            .filter(|c| c.is_ascii() && !c.is_ascii_control())
            .take(12)
            .collect();
        res.config.name = [0; 12];
        res.config.name[..n.len()].copy_from_slice(n.as_bytes());
    }
    let (model, norm_given) = import::assemble(&imported, &res)?;
    Ok(Loaded {
        model,
        imported,
        settings,
        norm_given,
    })
}

/// Quantizes with calibration on raw sample sequences; returns the blob and the statistics.
pub fn quantize_calibrated(
    model: &FloatModel,
    seqs: &[&[f32]],
    cell_bits: Option<[u8; 2]>,
    quiet: bool,
) -> Result<(Vec<u8>, slipguard_core::quantize::QuantReport, Calibration)> {
    let cal = calib::calibrate(model, seqs, cell_bits, quiet);
    let mut bits = [0u8; 2];
    for (b, c) in bits.iter_mut().zip(&cal.cell_frac_bits) {
        *b = *c;
    }
    let (blob, mut q) = quantize(model, &[], Some(bits))
        .map_err(|e| ExportError::unsupported("model", e.to_string()))?;
    q.max_abs_cell = cal.max_abs_cell.clone();
    Ok((blob, q, cal))
}

/// Options of one export.
#[derive(Clone, Debug, Default)]
pub struct ExportOptions {
    /// The model.
    pub source: ModelSource,
    /// Calibration data (recording file/folder or eagle-shoal folder).
    pub data: Option<PathBuf>,
    /// Separate validation data for the agreement (else the calibration data).
    pub validation: Option<PathBuf>,
    /// Use only the first N trials of each data set.
    pub max_trials: Option<usize>,
    /// Fit the normalisation on the calibration data (when the model has none).
    pub fit_norm: bool,
    /// Fixed cell formats instead of calibrated ones.
    pub cell_bits: Option<[u8; 2]>,
    /// No progress bars.
    pub quiet: bool,
    /// Measure the agreement on the calibration data itself instead of holding out every
    /// [`HOLDOUT_EVERY`]th trial (when there is no separate validation set).
    pub no_holdout: bool,
}

/// Without `--validation`, every this-many-th trial of `--data` is held out of calibration and
/// the agreement is measured on those trials.
pub const HOLDOUT_EVERY: usize = 5;

/// The result of an export (nothing written yet).
#[derive(Clone, Debug)]
pub struct Exported {
    /// The float model.
    pub model: FloatModel,
    /// The blob.
    pub blob: Vec<u8>,
    /// The report.
    pub report: ExportReport,
}

/// Runs an export.
pub fn export(opts: &ExportOptions) -> Result<Exported> {
    let mut loaded = load_float(&opts.source)?;
    let config = loaded.model.config;
    let data = match &opts.data {
        Some(d) => Some(calib::load_data(d, &config, opts.max_trials, opts.quiet)?),
        None => None,
    };
    let mut norm_source = match loaded.imported.format {
        Format::Safetensors if loaded.imported.metadata.contains_key("norm_mean") => {
            "checkpoint metadata".to_string()
        }
        _ => "settings".to_string(),
    };
    if !loaded.norm_given {
        match (&data, opts.fit_norm) {
            (Some(d), true) => {
                let seqs: Vec<&[f32]> = d.sequences.iter().map(|s| s.samples.as_slice()).collect();
                loaded.model.fit_normalisation(&seqs);
                norm_source = format!(
                    "fitted on {} ({} sequences); it must equal the training normalisation",
                    d.source,
                    seqs.len()
                );
            }
            (None, true) => return Err(ExportError::Usage("--fit-norm needs --data".into())),
            _ => {
                return Err(ExportError::settings(
                    "norm_mean",
                    "the model has no normalisation: give norm_mean/norm_std (checkpoint metadata, --settings, --norm-mean/--norm-std) or --fit-norm with --data",
                ));
            }
        }
    } else if opts.fit_norm {
        loaded
            .imported
            .notes
            .push("--fit-norm ignored: the model carries its normalisation".into());
    }
    let model = loaded.model;
    let validation = match &opts.validation {
        Some(v) => Some(calib::load_data(v, &config, opts.max_trials, opts.quiet)?),
        None => None,
    };
    // Without a validation set, every HOLDOUT_EVERY-th trial is held out of calibration and
    // the agreement is measured on it (unless --no-holdout).
    let split = match (&data, &validation, opts.no_holdout) {
        (Some(d), None, false) => d.split_holdout(HOLDOUT_EVERY),
        _ => None,
    };
    // The written blob is calibrated on all of --data, over the whole recordings: the cell
    // state a device reaches after the release is outside the labelled windows.
    let recordings =
        |d: &DataSet| -> Vec<Vec<f32>> { d.recordings.iter().map(|s| s.samples.clone()).collect() };
    let all: Vec<Vec<f32>> = data.as_ref().map(recordings).unwrap_or_default();
    let seqs: Vec<&[f32]> = all.iter().map(Vec::as_slice).collect();
    let hand = model.config.variant.is_hand();
    // A hand-level model calibrates on whole grasps (every channel together), not channels.
    let hands = |d: Option<&DataSet>| d.map_or(Vec::new(), |d| d.hands.clone());
    let (blob, q, cal) = if hand {
        crate::hand::quantize(&model, &hands(data.as_ref()), opts.cell_bits)?
    } else {
        quantize_calibrated(&model, &seqs, opts.cell_bits, opts.quiet)?
    };
    // With a held-out split the agreement is that of the same procedure with the held-out
    // trials left out of calibration: a blob calibrated on the other trials, measured on them.
    let held_blob = match &split {
        Some((rest, _)) if hand => {
            let (b, _, c) = crate::hand::quantize(&model, &rest.hands, opts.cell_bits)?;
            Some((b, c.cell_frac_bits))
        }
        Some((rest, _)) => {
            let r = recordings(rest);
            let seqs: Vec<&[f32]> = r.iter().map(Vec::as_slice).collect();
            let (b, _, c) = quantize_calibrated(&model, &seqs, opts.cell_bits, true)?;
            Some((b, c.cell_frac_bits))
        }
        None => None,
    };
    let mut agree_set: Option<&DataSet> = validation
        .as_ref()
        .or(split.as_ref().map(|(_, h)| h))
        .or(data.as_ref());
    let measured: &[u8] = held_blob.as_ref().map_or(&blob, |(b, _)| b);
    let mut agreement: Option<Agreement> = match agree_set {
        Some(d) => Some(calib::agreement(&model, measured, d, opts.quiet)?),
        None => None,
    };
    // The held-out trials are a fifth of --data: too few to see every recording where the
    // blob strays. The written blob is also measured on all of --data, and the report keeps
    // whichever measurement has the larger |Δp| (the bound is checked against it).
    let mut coverage_note = None;
    // Whether the agreement shown is the held-out blob's.
    let mut held_used = held_blob.is_some();
    if let (Some((_, held)), Some(all_data), Some(held_ag)) = (&split, &data, &agreement) {
        let all = calib::agreement(&model, &blob, all_data, opts.quiet)?;
        let use_all = all.max_abs_dp > held_ag.max_abs_dp;
        coverage_note = Some(format!(
            "quantization loss measured twice: on the {} held-out trials with a blob calibrated without them (max |Δp| {:.4}), and with the written blob on all {} trials of --data (max |Δp| {:.4}); the report shows the {} one",
            held.trials,
            held_ag.max_abs_dp,
            all_data.trials,
            all.max_abs_dp,
            if use_all { "all-trials" } else { "held-out" }
        ));
        if use_all {
            agreement = Some(all);
            agree_set = Some(all_data);
            held_used = false;
        }
    }
    let aligned = AlignedBlob::new(&blob);
    let parsed = ModelBlob::parse(aligned.as_bytes()).map_err(|e| ExportError::Blob {
        path: "(exported blob)".into(),
        source: e,
    })?;
    let weight_loss = match (&agreement, agree_set) {
        // The weight-loss split runs one channel at a time: not for a hand-level model.
        _ if hand => None,
        (Some(a), Some(d)) => {
            let seqs: Vec<&[f32]> = d.recordings.iter().map(|s| s.samples.as_slice()).collect();
            Some(crate::report::weight_loss(
                &model,
                &parsed,
                &seqs,
                a.max_abs_dp,
                match &held_blob {
                    Some((_, c)) if held_used => c,
                    _ => &cal.cell_frac_bits,
                },
            ))
        }
        _ => None,
    };
    let written_bits = cal.cell_frac_bits.clone();
    let mut notes = loaded.imported.notes.clone();
    for k in &loaded.settings.unknown {
        notes.push(format!("unknown setting `{k}` ignored"));
    }
    if let Some(d) = &data {
        notes.extend(d.warnings.iter().cloned());
    }
    notes.extend(coverage_note);
    if let (true, Some(d)) = (hand, &data) {
        // The agreement of a hand-level model spans the grasp start to the drop or release;
        // past that the same comparison, for the record.
        let w = crate::hand::agreement_whole(&model, &blob, &d.hands)?;
        notes.push(format!(
            "hand-level model: agreement measured from each grasp start to its drop or release \
             (the span a hand flag can matter in); over the whole recordings, past it, max |Δp| \
             {:.4}, flag agreement {:.3} % ({} steps)",
            w.max_abs_dp,
            100.0 * w.flag_agreement,
            w.steps
        ));
    }
    let mut settings = describe(&parsed.config);
    settings.insert(
        "norm_mean".into(),
        serde_json::to_string(&model.norm_mean).unwrap_or_default(),
    );
    settings.insert(
        "norm_std".into(),
        serde_json::to_string(&model.norm_std).unwrap_or_default(),
    );
    let report = ExportReport {
        exporter: format!("slipguard-export {}", env!("CARGO_PKG_VERSION")),
        input: opts.source.path.display().to_string(),
        format: loaded.imported.format.name().into(),
        lstm_sources: lstm_sources(&loaded.imported, &model.config),
        normalisation_source: norm_source,
        settings,
        notes,
        blob: describe_blob(&parsed),
        tensor_errors: tensor_errors(&model, &q),
        calibration_data: data.as_ref().map(|d| {
            format!(
                "{} ({} trials, {} unlabelled; whole recordings)",
                d.source, d.trials, d.unlabelled
            )
        }),
        calibration: data.as_ref().map(|_| cal),
        agreement_data: agree_set.map(|d| {
            let how = if validation.is_some() {
                ", validation set".to_string()
            } else if let Some((_, bits)) = held_blob.as_ref().filter(|_| held_used) {
                format!(
                    ", measured with a blob calibrated without them (cell bits {bits:?}; the written blob, calibrated on all: {:?})",
                    written_bits
                )
            } else if held_blob.is_some() {
                ", all of --data with the written blob (larger |Δp| than on the held-out trials)"
                    .to_string()
            } else {
                ", the calibration set".to_string()
            };
            format!("{} ({} trials; whole recordings){how}", d.source, d.trials)
        }),
        agreement,
        weight_loss,
    };
    Ok(Exported {
        model,
        blob,
        report,
    })
}

fn lstm_sources(imp: &Imported, config: &ModelConfig) -> Vec<String> {
    let mut v: Vec<String> = imp
        .lstms
        .iter()
        .map(|l| format!("`{}` ({} → {})", l.name, l.lstm.input, l.lstm.hidden))
        .collect();
    if config.variant.lstm_count() == 2 && v.len() == 2 {
        // Report in model order: force path first.
        let force_first = imp.lstms[0].lstm.input == config.lstm_inputs(0);
        if !force_first {
            v.swap(0, 1);
        }
        v[0] = format!("force: {}", v[0]);
        v[1] = format!("bands: {}", v[1]);
    }
    v
}

/// A float model for `verify`: weights from the checkpoint; settings and, when the checkpoint
/// has none, normalisation from the blob's header (the blob is what runs).
pub fn float_for_blob(
    src: &ModelSource,
    blob: &ModelBlob<'_>,
) -> Result<(FloatModel, Vec<String>)> {
    // The checkpoint read with its own settings first: a checkpoint of another variant or size
    // is a failed verification (exit 13), not a shape error of the blob's settings.
    if let Ok(own) = load_float(src) {
        let (f, b) = (&own.model.config, &blob.config);
        if f.hidden != b.hidden || f.variant != b.variant {
            return Err(ExportError::VerifyFailed(format!(
                "the checkpoint is {} with hidden {:?}, the blob {} with hidden {:?}",
                f.variant.name(),
                &f.hidden[..own.model.lstms.len()],
                b.variant.name(),
                &b.hidden[..b.variant.lstm_count()]
            )));
        }
    }
    let mut src = src.clone();
    let header: BTreeMap<String, String> = describe(&blob.config);
    let mut notes = Vec::new();
    let mut overrides: Vec<(String, String)> = header
        .into_iter()
        .filter(|(k, _)| k != "model_id")
        .collect();
    overrides.append(&mut src.overrides);
    src.overrides = overrides;
    let mut loaded = load_float(&src)?;
    if !loaded.norm_given {
        notes.push("normalisation taken from the blob (the checkpoint has none)".into());
        for (j, n) in blob.norm.iter().enumerate() {
            loaded.model.norm_mean[j] = n.mean_q15 as f32 / 32768.0;
            loaded.model.norm_std[j] = (2f64.powi(n.shift) / (8.0 * n.gain as f64)) as f32;
        }
    }
    let (f, b) = (&loaded.model.config, &blob.config);
    if f.hidden != b.hidden || f.variant != b.variant {
        return Err(ExportError::VerifyFailed(format!(
            "the checkpoint is {} with hidden {:?}, the blob {} with hidden {:?}",
            f.variant.name(),
            f.hidden,
            b.variant.name(),
            b.hidden
        )));
    }
    Ok((loaded.model, notes))
}

/// Reads a whole file.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| ExportError::io(path, e))
}
