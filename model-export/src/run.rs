//! `slipguard-export run`: the blob's per-step output for a raw trace or a feature file, and
//! `--check-features`: a user's normalised feature file against the blob's own front end.
//!
//! The blob runs exactly as on the device (`slipguard_core`): raw samples (sensor units) →
//! Q1.15 input → features → Q3.12 normalisation → LSTM(s) → dense → p(unstable) Q0.15 → flag.
//! From a feature file the front end is skipped: each value (normalised, what the user's network
//! consumes) is rounded to Q3.12 and fed to the LSTM(s).

use std::path::Path;

use slipguard_core::MAX_INPUT;
use slipguard_core::blob::ModelBlob;
use slipguard_core::decision::{DecisionConfig, DecisionState, p_unstable};
use slipguard_core::features::stft::StftPlan;
use slipguard_core::features::{FeatureLayout, FeatureState, normalise, raw_features};
use slipguard_core::fixed::sat_i16_wide;
use slipguard_core::lstm::{self, LstmState};
use slipguard_core::sample::InputScale;

use crate::error::{ExportError, Result};

/// One step of the blob.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    /// Normalised features as the LSTM sees them (Q3.12 dequantised).
    pub features: Vec<f32>,
    /// p(unstable), Q0.15.
    pub p_q15: i16,
    /// The flag after threshold and hysteresis.
    pub unstable: bool,
}

/// Q3.12: 4096 = 1.0 (the normalised features' format, ±8).
const Q12: f32 = 4096.0;

/// The blob's per-channel pipeline, step by step, with the features exposed.
pub struct Runner<'a> {
    blob: ModelBlob<'a>,
    plan: Option<StftPlan>,
    layout: FeatureLayout,
    scale: InputScale,
    decision: DecisionConfig,
    features: FeatureState,
    lstm: [LstmState; 2],
    dstate: DecisionState,
}

impl<'a> Runner<'a> {
    /// Prepares a parsed blob (state as after reset).
    pub fn new(blob: ModelBlob<'a>) -> Result<Self> {
        let config = blob.config;
        let plan = if config.variant.uses_bands() {
            Some(
                StftPlan::new(config.stft)
                    .map_err(|e| ExportError::settings("stft", format!("{e:?}")))?,
            )
        } else {
            None
        };
        Ok(Self {
            plan,
            layout: config.feature_layout(),
            scale: InputScale::of(&config),
            decision: DecisionConfig::of(&config),
            features: FeatureState::new(),
            lstm: [LstmState::new(), LstmState::new()],
            dstate: DecisionState {
                unstable: false,
                run_above: 0,
                run_below: 0,
            },
            blob,
        })
    }

    /// Features per step.
    pub fn feature_count(&self) -> usize {
        self.layout.len().min(MAX_INPUT)
    }

    /// One raw sample (sensor units, rounded to an integer as the ADC delivers it).
    pub fn step_raw(&mut self, raw: f32) -> Step {
        let mut v = [0i16; MAX_INPUT];
        let x = self.scale.to_q15(raw.round() as i32);
        raw_features(
            self.layout,
            self.plan.as_ref(),
            &mut self.features,
            x,
            &mut v,
        );
        let n = self.feature_count();
        normalise(self.blob.norm, &mut v[..n]);
        self.step_q12(&v[..n])
    }

    /// One step from normalised features (reals, the user's network's input).
    pub fn step_features(&mut self, f: &[f32]) -> Step {
        let n = self.feature_count().min(f.len());
        let mut v = [0i16; MAX_INPUT];
        for (q, &x) in v.iter_mut().zip(&f[..n]) {
            *q = sat_i16_wide((x as f64 * Q12 as f64).round() as i64);
        }
        self.step_q12(&v[..n])
    }

    fn step_q12(&mut self, v: &[i16]) -> Step {
        let n = v.len();
        let p = match self.blob.lstms() {
            [only] => {
                lstm::step(only, &mut self.lstm[0], v);
                p_unstable(&self.blob.dense, &[&self.lstm[0].h[..only.hidden]])
            }
            [a, b] => {
                let split = a.inputs.min(n);
                let [sa, sb] = &mut self.lstm;
                lstm::step(a, sa, &v[..split]);
                lstm::step(b, sb, &v[split..]);
                p_unstable(&self.blob.dense, &[&sa.h[..a.hidden], &sb.h[..b.hidden]])
            }
            _ => 0,
        };
        let unstable = self.decision.update(&mut self.dstate, p);
        Step {
            features: v.iter().map(|&q| q as f32 / Q12).collect(),
            p_q15: p,
            unstable,
        }
    }
}

/// A numeric CSV (or whitespace-separated) table: an optional header row, then rows of numbers.
/// Returns (column names, rows). Every row must have the header's (or the first row's) width.
pub fn read_table(path: &Path) -> Result<(Vec<String>, Vec<Vec<f32>>)> {
    let text = std::fs::read_to_string(path).map_err(|e| ExportError::io(path, e))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut names = Vec::new();
    let mut rows: Vec<Vec<f32>> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = line
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|c| !c.is_empty())
            .collect();
        let parsed: std::result::Result<Vec<f32>, _> =
            cells.iter().map(|c| c.parse::<f32>()).collect();
        match parsed {
            Ok(v) => {
                let width = if names.is_empty() {
                    rows.first().map_or(v.len(), Vec::len)
                } else {
                    names.len()
                };
                if v.len() != width {
                    return Err(ExportError::Data(format!(
                        "{}:{}: {} values, expected {width}",
                        path.display(),
                        i + 1,
                        v.len()
                    )));
                }
                if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                    return Err(ExportError::Data(format!(
                        "{}:{}: column {} is not a finite number",
                        path.display(),
                        i + 1,
                        k + 1
                    )));
                }
                rows.push(v);
            }
            Err(_) if rows.is_empty() && names.is_empty() => {
                names = cells.iter().map(|c| c.to_string()).collect();
            }
            Err(_) => {
                return Err(ExportError::Data(format!(
                    "{}:{}: not a row of numbers: `{line}`",
                    path.display(),
                    i + 1
                )));
            }
        }
    }
    if rows.is_empty() {
        return Err(ExportError::Data(format!(
            "{}: no rows of numbers",
            path.display()
        )));
    }
    if names.is_empty() {
        names = (0..rows[0].len()).map(|k| format!("c{k}")).collect();
    }
    Ok((names, rows))
}

/// Per feature: largest |user − blob| and the first step where it exceeds `tol`.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureCheck {
    /// Feature index (order [force, d(t), bands…]).
    pub feature: usize,
    /// Largest absolute difference (normalised units).
    pub max_abs_diff: f32,
    /// Step of the largest difference.
    pub worst_step: usize,
    /// First step where the difference exceeds the tolerance.
    pub first_over: Option<usize>,
}

/// Tolerance of `--check-features`, normalised units: a few Q3.12 steps (1/4096) plus the
/// rounding of the blob's μ and 1/σ, far below a unit mistake (|X_k| vs |X_k|/N, mN vs N).
pub const FEATURE_TOL: f32 = 0.01;

/// Compares a user's normalised features (T × F) with the blob's front end on the raw trace.
pub fn check_features(
    blob: ModelBlob<'_>,
    raw: &[f32],
    user: &[Vec<f32>],
) -> Result<Vec<FeatureCheck>> {
    let mut r = Runner::new(blob)?;
    let nf = r.feature_count();
    if let Some(row) = user.iter().find(|row| row.len() != nf) {
        return Err(ExportError::Data(format!(
            "the feature file has {} columns, the blob's model takes {nf} features [force, d(t), bands]",
            row.len()
        )));
    }
    if user.len() != raw.len() {
        return Err(ExportError::Data(format!(
            "the feature file has {} rows, the trace {} samples (one row per sample from the first)",
            user.len(),
            raw.len()
        )));
    }
    let mut out: Vec<FeatureCheck> = (0..nf)
        .map(|feature| FeatureCheck {
            feature,
            max_abs_diff: 0.0,
            worst_step: 0,
            first_over: None,
        })
        .collect();
    for (t, (&x, u)) in raw.iter().zip(user).enumerate() {
        let s = r.step_raw(x);
        for (c, (&ours, &theirs)) in out.iter_mut().zip(s.features.iter().zip(u)) {
            let d = (ours - theirs).abs();
            if d > c.max_abs_diff {
                c.max_abs_diff = d;
                c.worst_step = t;
            }
            if d > FEATURE_TOL && c.first_over.is_none() {
                c.first_over = Some(t);
            }
        }
    }
    Ok(out)
}
