//! Loader for the visual-tactile grasp dataset ("eagle-shoal") trial layout:
//! `trials/<Object>_<A>_<B>_<direction>_<index>/{tactile.csv, meta.json}`.
//!
//! `tactile.csv`: header `c0,…,c15`, then one row per step (400 rows, 16.7 Hz) of
//! forces in mN. `meta.json`: `label` = `[l0, l1, l2, l3]` (grasp start, lift
//! start, end of the lift window, outcome 1 = success / 0 = failure).
//! The drop step and contact flags are filled by [`crate::labels::annotate`]
//! with the configuration passed in.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::csvtext::{check_width, parse_error, parse_number, read_text, records};
use crate::error::{DataError, Result};
use crate::labels::{LabelConfig, annotate};
use crate::trial::{Outcome, PhaseMarks, SensorKind, Trial, Unit};

/// The dataset's sample rate: the paper's (60 ms a step, stated as 16.7 Hz).
pub const EAGLE_RATE_HZ: f32 = slipguard_core::sample::PAPER_RATE_HZ;
/// [`EAGLE_RATE_HZ`] in mHz, the blob header's unit.
pub const EAGLE_RATE_MHZ: u32 = slipguard_core::sample::PAPER_RATE_MHZ.0;

#[derive(Debug, Deserialize)]
struct Meta {
    label: Vec<i64>,
    #[serde(default)]
    object: Option<String>,
    #[serde(default)]
    a: Option<i64>,
    #[serde(default)]
    b: Option<i64>,
    #[serde(default)]
    direction: Option<String>,
    #[serde(default)]
    index: Option<i64>,
    #[serde(default)]
    source_path: Option<String>,
    #[serde(default)]
    source_commit: Option<String>,
    /// The marks and outcome were estimated from the force (no `label.txt` in the dataset).
    #[serde(default)]
    label_estimated: bool,
}

/// Read a `tactile.csv`: header of channel names, then rows of numbers.
/// Returns (channel names, channel-major samples).
pub fn read_tactile_csv(path: &Path) -> Result<(Vec<String>, Vec<Vec<f32>>)> {
    parse_tactile_csv(&read_text(path)?, path)
}

/// [`read_tactile_csv`] on text already read (`path` names it in errors).
pub fn parse_tactile_csv(text: &str, path: &Path) -> Result<(Vec<String>, Vec<Vec<f32>>)> {
    let mut it = records(path, text, 1)?.into_iter();
    let header = it
        .next()
        .ok_or_else(|| parse_error(path, 1, None, None, "empty file: no header"))?;
    let names = header.fields;
    for (i, n) in names.iter().enumerate() {
        if n.is_empty() {
            return Err(parse_error(
                path,
                header.number,
                Some(i + 1),
                None,
                "empty column name",
            ));
        }
        if n.parse::<f64>().is_ok() {
            return Err(parse_error(
                path,
                header.number,
                Some(i + 1),
                None,
                format!("header expected, found the number `{n}`"),
            ));
        }
    }
    let mut samples = vec![Vec::new(); names.len()];
    for r in it {
        check_width(path, r.number, &r.fields, names.len())?;
        for (c, f) in r.fields.iter().enumerate() {
            samples[c].push(parse_number(path, r.number, c + 1, &names[c], f)?);
        }
    }
    if samples[0].is_empty() {
        return Err(parse_error(
            path,
            header.number + 1,
            None,
            None,
            "no data rows",
        ));
    }
    Ok((names, samples))
}

/// Load one trial folder (with `tactile.csv` and `meta.json`) and annotate it.
pub fn load_eagle_trial(dir: &Path, cfg: &LabelConfig) -> Result<Trial> {
    let csv_path = dir.join("tactile.csv");
    let meta_path = dir.join("meta.json");
    let (names, samples) = read_tactile_csv(&csv_path)?;
    let meta_text = read_text(&meta_path)?;
    let meta: Meta = serde_json::from_str(&meta_text).map_err(|e| DataError::Json {
        path: meta_path.clone(),
        message: format!("line {} column {}: {e}", e.line(), e.column()),
    })?;
    let n = samples[0].len();
    let shape = |message: String| DataError::Shape {
        path: meta_path.clone(),
        message,
    };
    if meta.label.len() != 4 {
        return Err(shape(format!(
            "`label` must have 4 numbers [l0, l1, l2, l3], has {}",
            meta.label.len()
        )));
    }
    let step = |i: usize| -> Result<usize> {
        let v = meta.label[i];
        if v < 0 || v as usize >= n {
            return Err(shape(format!("label l{i} = {v} is outside 0..{n}")));
        }
        Ok(v as usize)
    };
    let marks = PhaseMarks {
        grasp_start: Some(step(0)?),
        lift_start: Some(step(1)?),
        open_start: Some(step(2)?),
        release: None,
    };
    let outcome = match meta.label[3] {
        1 => Outcome::Success,
        0 => Outcome::Failure,
        v => return Err(shape(format!("label l3 = {v}: outcome must be 0 or 1"))),
    };
    let id = dir
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| dir.display().to_string());
    let mut trial = Trial::new(id, Unit::MilliNewton, EAGLE_RATE_HZ, samples);
    trial.sensor = SensorKind::Force;
    trial.channel_names = names;
    trial.marks = marks;
    trial.outcome = outcome;
    trial.source = match (&meta.source_path, &meta.source_commit) {
        (Some(p), Some(c)) => format!("eagle-shoal {} ({p} @ {c})", dir.display()),
        _ => format!("eagle-shoal {}", dir.display()),
    };
    let extra = [
        ("object", meta.object.clone()),
        ("a", meta.a.map(|v| v.to_string())),
        ("b", meta.b.map(|v| v.to_string())),
        ("direction", meta.direction.clone()),
        ("index", meta.index.map(|v| v.to_string())),
        ("label", Some(format!("{:?}", meta.label))),
        (
            crate::trial::LABEL_ESTIMATED_KEY,
            meta.label_estimated.then(|| "true".to_string()),
        ),
    ];
    for (k, v) in extra {
        if let Some(v) = v {
            trial.extra.insert(k.to_string(), v);
        }
    }
    trial.validate().map_err(shape)?;
    annotate(&mut trial, cfg);
    Ok(trial)
}

/// The trial folders under `root` (either the dataset root with `trials/`, a
/// folder of trial folders, or a single trial folder), sorted by name.
pub fn trial_dirs(root: &Path) -> Result<Vec<PathBuf>> {
    if root.join("tactile.csv").is_file() {
        return Ok(vec![root.to_path_buf()]);
    }
    let base = if root.join("trials").is_dir() {
        root.join("trials")
    } else {
        root.to_path_buf()
    };
    let rd = std::fs::read_dir(&base).map_err(|e| DataError::io(&base, e))?;
    let mut dirs = Vec::new();
    for entry in rd {
        let entry = entry.map_err(|e| DataError::io(&base, e))?;
        let p = entry.path();
        if p.join("tactile.csv").is_file() {
            dirs.push(p);
        }
    }
    dirs.sort();
    if dirs.is_empty() {
        return Err(DataError::NoTrials { path: base });
    }
    Ok(dirs)
}

/// Load every trial under `root` (see [`trial_dirs`]), calling `progress` after each.
pub fn load_eagle_dataset(
    root: &Path,
    cfg: &LabelConfig,
    mut progress: impl FnMut(usize, usize),
) -> Result<Vec<Trial>> {
    let dirs = trial_dirs(root)?;
    let mut out = Vec::with_capacity(dirs.len());
    for (i, d) in dirs.iter().enumerate() {
        out.push(load_eagle_trial(d, cfg)?);
        progress(i + 1, dirs.len());
    }
    Ok(out)
}

/// Where the real trials live: [`crate::shipped::data_dir`] (`$SLIPGUARD_DATA`, the checkout's
/// `data/eagle-shoal`, or the copy embedded in the binary).
pub fn default_data_dir() -> PathBuf {
    crate::shipped::data_dir()
}
