//! The model's non-tensor settings: variant, d(t) flag, sample rate, input scaling, STFT,
//! decision, normalisation and name.
//!
//! They travel as a string map with the keys below: the safetensors `__metadata__` of our
//! trainer's checkpoints, a `--settings FILE.json` object for ONNX and Keras models, and the
//! individual CLI options (`--variant`, `--sample-rate`, …). Later sources override earlier ones:
//! defaults (the paper's fingertip set-up) < checkpoint metadata < settings file < CLI options.

use std::collections::BTreeMap;

use slipguard_core::blob::{InputUnit, ModelConfig, Variant};
use slipguard_core::decision::{FusedHand, LOAD_WINDOW_MAX, LoadRule, Q15};
use slipguard_core::features::stft::{StftConfig, WindowShape};
use slipguard_core::units::Millihertz;
use slipguard_data::checkpoint_keys as keys;

use crate::error::{ExportError, Result};

/// Every key the exporter understands, with its default and meaning (printed by `--help` and
/// documented in docs/export.md).
pub const KEYS: &[(&str, &str, &str)] = &[
    (
        keys::FORMAT,
        "1",
        "settings format version; must be 1 when present",
    ),
    (
        keys::VARIANT,
        "data-stft-lstm",
        "a|lstm, b|stft-lstm, c|data-stft-lstm, d|lstm-stft-lstm",
    ),
    (
        keys::FORCE_DIFF,
        "false",
        "true: d(t) = x(t) - x(t-1) is an input after the force",
    ),
    (
        keys::SAMPLE_RATE_HZ,
        "16.7",
        "sample rate the model was trained at, Hz (stored in mHz)",
    ),
    (keys::INPUT_UNIT, "mN", "mN or counts"),
    (
        keys::INPUT_OFFSET,
        "0",
        "raw value mapped to 0.0 (integer, input unit)",
    ),
    (
        keys::INPUT_FULL_SCALE,
        "10000",
        "raw span mapped to +1.0 (integer > 0, input unit)",
    ),
    (
        keys::STFT_WINDOW_LEN,
        "20",
        "STFT window N (4..=48); ignored by variant a",
    ),
    (keys::STFT_FIRST_BIN, "1", "first DFT bin"),
    (
        keys::STFT_N_BINS,
        "10",
        "number of bins (1..=16, last bin <= N/2)",
    ),
    (keys::STFT_WINDOW, "rectangular", "rectangular or hann"),
    (keys::THRESHOLD, "0.5", "p(unstable) threshold in (0, 1)"),
    (
        keys::RAISE_AFTER,
        "1",
        "steps >= threshold before the flag rises (1..=255)",
    ),
    (
        keys::CLEAR_AFTER,
        "1",
        "steps < threshold before the flag clears (1..=255)",
    ),
    (
        keys::NORM_MEAN,
        "",
        "JSON array: mean of each raw feature [force, d(t), bands...]",
    ),
    (
        keys::NORM_STD,
        "",
        "JSON array: standard deviation of each raw feature (> 0)",
    ),
    (
        keys::NAME,
        "",
        "model name, ASCII, at most 12 bytes (default: the input file's stem)",
    ),
    (
        "model_id",
        "",
        "u32 (decimal or 0x hex); default: CRC-32 of the float weights",
    ),
    (
        "dual_order",
        "",
        "variant d: order of the hidden states the dense layer sees, force,bands or bands,force (needed when the file does not say)",
    ),
    (
        keys::HAND_RULE_FRACTION,
        "",
        "hand rule fused with the hand flag (blob format v2; all three hand_rule_* keys or none): the rule alone flags under this fraction of the hand load's recent peak, 0..=1 (0 = never)",
    ),
    (
        keys::HAND_RULE_GUARD,
        "",
        "hand rule: the model's hand flag counts while the load is under this fraction of the peak, 0..=1 (1 = no guard)",
    ),
    (
        keys::HAND_RULE_WINDOW_S,
        "",
        "hand rule: seconds the peak looks back over (1 to 64 frames at the model's rate)",
    ),
    (
        HAND_RULE,
        "",
        "FRACTION,GUARD,WINDOW_S: the three hand_rule_* keys at once (overrides them; --hand-rule)",
    ),
];

/// The three hand-rule keys at once, `FRACTION,GUARD,WINDOW_S` (the `--hand-rule` option).
pub const HAND_RULE: &str = "hand_rule";

/// Provenance keys `slipguard train` writes into its checkpoints' metadata (docs/checkpoint.md):
/// not settings of the blob, so the exporter knows and skips them without a warning.
pub const TRAINER_PROVENANCE_KEYS: &[&str] = &[
    "train_command",
    "best_epoch",
    "seconds_per_epoch",
    "val_trials",
    "fold",
    "heldout_trials",
    "qat",
    "cv_by",
    "lift_jitter",
];

/// Order in which a dual model's dense layer sees the two hidden states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DualOrder {
    /// Columns [h_force, h_bands] (our trainer's order).
    ForceBands,
    /// Columns [h_bands, h_force].
    BandsForce,
}

/// Merged settings, as strings, before parsing.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Settings {
    map: BTreeMap<String, String>,
    /// Keys nobody understands (reported as warnings).
    pub unknown: Vec<String>,
}

/// Parsed settings.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    /// Header fields (hidden sizes, cell bits and model id are filled in later).
    pub config: ModelConfig,
    /// Normalisation mean, when given.
    pub norm_mean: Option<Vec<f32>>,
    /// Normalisation standard deviation, when given.
    pub norm_std: Option<Vec<f32>>,
    /// Model id, when given.
    pub model_id: Option<u32>,
    /// Whether a name was given.
    pub named: bool,
    /// `dual_order`, when given.
    pub dual_order: Option<DualOrder>,
}

impl Settings {
    /// The paper's defaults.
    pub fn defaults() -> Self {
        let mut s = Self::default();
        for (k, v, _) in KEYS {
            if !v.is_empty() {
                s.map.insert((*k).into(), (*v).into());
            }
        }
        s
    }

    /// Overrides with every entry of `other` (a checkpoint's metadata, a settings file).
    /// Keys the exporter does not know are remembered for a warning.
    pub fn merge(&mut self, other: &BTreeMap<String, String>) {
        for (k, v) in other {
            if KEYS.iter().any(|(key, _, _)| key == k) {
                self.map.insert(k.clone(), v.clone());
            } else if TRAINER_PROVENANCE_KEYS.contains(&k.as_str()) || k == keys::HIDDEN {
                // The trainer's record of how the weights were made, and the LSTM sizes the
                // exporter reads from the tensors' shapes: nothing to convert.
            } else if !self.unknown.contains(k) {
                self.unknown.push(k.clone());
            }
        }
    }

    /// Sets one key (a CLI option).
    pub fn set(&mut self, key: &str, value: impl Into<String>) {
        self.map.insert(key.into(), value.into());
    }

    /// Current value of a key.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.map.get(key).map(String::as_str)
    }

    /// The merged map (for the report and `--write-settings`).
    pub fn map(&self) -> &BTreeMap<String, String> {
        &self.map
    }

    /// Reads a settings JSON file: an object of strings (numbers and booleans are accepted and
    /// turned into strings; arrays are kept as JSON text).
    pub fn read_json_file(path: &std::path::Path) -> Result<BTreeMap<String, String>> {
        let text = std::fs::read_to_string(path).map_err(|e| ExportError::io(path, e))?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| ExportError::format(path, format!("not JSON: {e}")))?;
        let obj = v
            .as_object()
            .ok_or_else(|| ExportError::format(path, "settings must be a JSON object"))?;
        Ok(obj
            .iter()
            .map(|(k, v)| {
                let s = match v {
                    serde_json::Value::String(s) => s.clone(),
                    other => other.to_string(),
                };
                (k.clone(), s)
            })
            .collect())
    }

    fn req(&self, key: &str) -> Result<&str> {
        self.get(key)
            .ok_or_else(|| ExportError::settings(key, "missing"))
    }

    fn parse<T: std::str::FromStr>(&self, key: &str) -> Result<T> {
        let v = self.req(key)?;
        v.trim()
            .parse()
            .map_err(|_| ExportError::settings(key, format!("cannot parse `{v}`")))
    }

    fn floats(&self, key: &str) -> Result<Option<Vec<f32>>> {
        let Some(v) = self.get(key) else {
            return Ok(None);
        };
        let parsed: Vec<f64> = serde_json::from_str(v).map_err(|_| {
            ExportError::settings(key, format!("expected a JSON array of numbers, got `{v}`"))
        })?;
        let out: Vec<f32> = parsed.iter().map(|&x| x as f32).collect();
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Err(ExportError::settings(
                key,
                format!("entry {i} is not finite"),
            ));
        }
        Ok(Some(out))
    }

    /// The hand rule of the `hand_rule_*` keys (or of [`HAND_RULE`], which overrides them) at
    /// `rate_mhz`: `None` when none is given; a missing key, a fraction outside 0..=1 or a
    /// window outside 1..=64 frames is refused, naming the key.
    fn hand_rule(&self, rate_mhz: Millihertz) -> Result<Option<FusedHand>> {
        let keys3 = [
            keys::HAND_RULE_FRACTION,
            keys::HAND_RULE_GUARD,
            keys::HAND_RULE_WINDOW_S,
        ];
        let values: [Option<String>; 3] = match self.get(HAND_RULE).map(str::trim) {
            Some(v) if !v.is_empty() => {
                let parts: Vec<&str> = v.split(',').map(str::trim).collect();
                let [f, g, w] = parts[..] else {
                    return Err(ExportError::settings(
                        HAND_RULE,
                        format!("`{v}` is not FRACTION,GUARD,WINDOW_S (e.g. 0.4,0.8,0.6)"),
                    ));
                };
                [Some(f.into()), Some(g.into()), Some(w.into())]
            }
            _ => keys3.map(|k| {
                self.get(k)
                    .map(str::to_string)
                    .filter(|v| !v.trim().is_empty())
            }),
        };
        if values.iter().all(Option::is_none) {
            return Ok(None);
        }
        let mut x = [0f64; 3];
        for ((&k, v), x) in keys3.iter().zip(&values).zip(&mut x) {
            let v = v.as_deref().ok_or_else(|| {
                ExportError::settings(k, "missing (a hand rule needs all three hand_rule_* keys)")
            })?;
            *x = v
                .trim()
                .parse()
                .map_err(|_| ExportError::settings(k, format!("cannot parse `{v}`")))?;
        }
        let [fraction, guard, window_s] = x;
        for (k, f) in [(keys3[0], fraction), (keys3[1], guard)] {
            if !(0.0..=1.0).contains(&f) {
                return Err(ExportError::settings(k, format!("{f} is not in 0..=1")));
            }
        }
        let frames = (window_s * rate_mhz.0 as f64 / 1000.0).round();
        if !(1.0..=LOAD_WINDOW_MAX as f64).contains(&frames) {
            return Err(ExportError::settings(
                keys3[2],
                format!(
                    "{window_s} s is {frames} frames at {} Hz; the rule looks back 1 to {LOAD_WINDOW_MAX} frames",
                    rate_mhz.hz()
                ),
            ));
        }
        let rule = FusedHand {
            strict: LoadRule {
                fraction_q15: Q15::from_f64(fraction).0,
                window: frames as u8,
            },
            guard_q15: if guard >= 1.0 {
                FusedHand::NO_GUARD
            } else {
                Q15::from_f64(guard).0
            },
        };
        slipguard_core::blob::hand_rule_record(&rule)
            .map_err(|e| ExportError::settings(HAND_RULE, e.to_string()))?;
        Ok(Some(rule))
    }

    /// Parses and checks every setting.
    pub fn resolve(&self) -> Result<Resolved> {
        if let Some(f) = self.get(keys::FORMAT)
            && f.trim() != "1"
        {
            return Err(ExportError::settings(
                keys::FORMAT,
                format!("format `{f}` is not supported (this exporter reads 1)"),
            ));
        }
        let variant = parse_variant(self.req(keys::VARIANT)?)?;
        let force_diff = match self.req(keys::FORCE_DIFF)?.trim() {
            "true" | "1" | "yes" => true,
            "false" | "0" | "no" => false,
            other => {
                return Err(ExportError::settings(
                    keys::FORCE_DIFF,
                    format!("`{other}` is not true/false"),
                ));
            }
        };
        let rate: f64 = self.parse(keys::SAMPLE_RATE_HZ)?;
        if !(rate > 0.0 && rate < 4.0e6) {
            return Err(ExportError::settings(
                keys::SAMPLE_RATE_HZ,
                format!("{rate} Hz is out of range"),
            ));
        }
        let input_unit = match self.req(keys::INPUT_UNIT)?.trim() {
            "mN" | "mn" | "millinewton" => InputUnit::MilliNewton,
            "counts" | "count" => InputUnit::Counts,
            other => {
                return Err(ExportError::settings(
                    keys::INPUT_UNIT,
                    format!("`{other}` is not mN or counts"),
                ));
            }
        };
        let input_offset: i32 = self.parse(keys::INPUT_OFFSET)?;
        let input_full_scale: i32 = self.parse(keys::INPUT_FULL_SCALE)?;
        if input_full_scale <= 0 {
            return Err(ExportError::settings(keys::INPUT_FULL_SCALE, "must be > 0"));
        }
        let stft = if variant.uses_bands() {
            let shape = match self.req(keys::STFT_WINDOW)?.trim() {
                "rectangular" | "rect" => WindowShape::Rectangular,
                "hann" => WindowShape::Hann,
                other => {
                    return Err(ExportError::settings(
                        keys::STFT_WINDOW,
                        format!("`{other}` is not rectangular or hann"),
                    ));
                }
            };
            let s = StftConfig {
                window_len: self.parse(keys::STFT_WINDOW_LEN)?,
                first_bin: self.parse(keys::STFT_FIRST_BIN)?,
                n_bins: self.parse(keys::STFT_N_BINS)?,
                shape,
            };
            s.validate().map_err(|e| {
                ExportError::settings("stft_window/stft_first_bin/stft_bins", e.to_string())
            })?;
            s
        } else {
            StftConfig::NONE
        };
        let threshold: f64 = self.parse(keys::THRESHOLD)?;
        if !(threshold > 0.0 && threshold < 1.0) {
            return Err(ExportError::settings(
                keys::THRESHOLD,
                format!("{threshold} is not in (0, 1)"),
            ));
        }
        let raise_after: u8 = self.parse(keys::RAISE_AFTER)?;
        let clear_after: u8 = self.parse(keys::CLEAR_AFTER)?;
        if raise_after == 0 || clear_after == 0 {
            return Err(ExportError::settings(
                "raise_after/clear_after",
                "must be >= 1",
            ));
        }
        let mut name = [0u8; 12];
        let named = match self.get(keys::NAME) {
            Some(n) if !n.is_empty() => {
                if !n.is_ascii() || n.len() > 12 {
                    return Err(ExportError::settings(
                        keys::NAME,
                        format!("`{n}` is not ASCII of at most 12 bytes"),
                    ));
                }
                name[..n.len()].copy_from_slice(n.as_bytes());
                true
            }
            _ => false,
        };
        let model_id = match self.get("model_id") {
            Some(v) if !v.is_empty() => {
                let v = v.trim();
                let parsed = match v.strip_prefix("0x") {
                    Some(h) => u32::from_str_radix(h, 16).ok(),
                    None => v.parse().ok(),
                };
                Some(parsed.ok_or_else(|| {
                    ExportError::settings("model_id", format!("`{v}` is not a u32"))
                })?)
            }
            _ => None,
        };
        let sample_rate_mhz = Millihertz::from_hz(rate);
        let hand_rule = self.hand_rule(sample_rate_mhz)?;
        let config = ModelConfig {
            model_id: model_id.unwrap_or(0),
            name,
            variant,
            force_diff,
            sample_rate_mhz,
            input_unit,
            input_offset,
            input_full_scale,
            stft,
            hidden: [0, 0],
            cell_frac_bits: [0, 0],
            threshold_q15: Q15::from_f64(threshold).header_threshold(),
            raise_after,
            clear_after,
            hand_rule,
        };
        let dual_order = match self.get("dual_order").map(str::trim) {
            None | Some("") => None,
            Some(v) => Some(match v.replace(' ', "").as_str() {
                "force,bands" => DualOrder::ForceBands,
                "bands,force" => DualOrder::BandsForce,
                _ => {
                    return Err(ExportError::settings(
                        "dual_order",
                        format!("`{v}` is not force,bands or bands,force"),
                    ));
                }
            }),
        };
        Ok(Resolved {
            dual_order,
            config,
            norm_mean: self.floats(keys::NORM_MEAN)?,
            norm_std: self.floats(keys::NORM_STD)?,
            model_id,
            named,
        })
    }
}

/// Parses a variant by name or, as `--variant` and settings files give it, by the paper's
/// letter (Fig. 5).
pub fn parse_variant(v: &str) -> Result<Variant> {
    Variant::from_cli(v).map_err(|e| {
        ExportError::settings(
            keys::VARIANT,
            format!("`{}` is not one of {}", v.trim(), e.expected),
        )
    })
}

/// Writes a config back into settings strings (for the report and round trips).
pub fn describe(config: &ModelConfig) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    m.insert(keys::VARIANT.into(), config.variant.name().into());
    m.insert(keys::FORCE_DIFF.into(), config.force_diff.to_string());
    m.insert(
        keys::SAMPLE_RATE_HZ.into(),
        format!("{}", config.sample_rate_mhz.hz()),
    );
    m.insert(keys::INPUT_UNIT.into(), config.input_unit.to_string());
    m.insert(keys::INPUT_OFFSET.into(), config.input_offset.to_string());
    m.insert(
        keys::INPUT_FULL_SCALE.into(),
        config.input_full_scale.to_string(),
    );
    if config.variant.uses_bands() {
        m.insert(
            keys::STFT_WINDOW_LEN.into(),
            config.stft.window_len.to_string(),
        );
        m.insert(
            keys::STFT_FIRST_BIN.into(),
            config.stft.first_bin.to_string(),
        );
        m.insert(keys::STFT_N_BINS.into(), config.stft.n_bins.to_string());
        m.insert(keys::STFT_WINDOW.into(), config.stft.shape.to_string());
    }
    m.insert(
        keys::THRESHOLD.into(),
        format!("{}", Q15(config.threshold_q15 as i16).to_f64()),
    );
    m.insert(keys::RAISE_AFTER.into(), config.raise_after.to_string());
    m.insert(keys::CLEAR_AFTER.into(), config.clear_after.to_string());
    m.insert(keys::NAME.into(), config.name_str().into());
    m.insert("model_id".into(), format!("{:#010x}", config.model_id));
    if let Some(r) = &config.hand_rule {
        m.insert(
            keys::HAND_RULE_FRACTION.into(),
            // 5 decimals: within a third of a Q0.15 step, so it reads back as the same value.
            format!("{:.5}", Q15(r.strict.fraction_q15).to_f64()),
        );
        let guard = if r.guard_q15 == FusedHand::NO_GUARD {
            1.0
        } else {
            Q15(r.guard_q15).to_f64()
        };
        m.insert(keys::HAND_RULE_GUARD.into(), format!("{guard:.5}"));
        m.insert(
            keys::HAND_RULE_WINDOW_S.into(),
            // 4 decimals: far under half a frame at any rate, so it reads back as the same frames.
            format!(
                "{:.4}",
                r.strict.window as f64 * 1000.0 / config.sample_rate_mhz.0.max(1) as f64
            ),
        );
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_paper_fingertip_setup() {
        let r = Settings::defaults().resolve().unwrap();
        let c = r.config;
        assert_eq!(c.variant, Variant::DataStftLstm);
        assert_eq!(c.sample_rate_mhz, slipguard_core::sample::PAPER_RATE_MHZ);
        assert_eq!((c.input_offset, c.input_full_scale), (0, 10_000));
        assert_eq!(c.stft, StftConfig::PAPER);
        assert_eq!(c.threshold_q15, 16_384);
        assert!(!c.force_diff && r.norm_mean.is_none());
    }

    #[test]
    fn a_hand_rule_from_keys_or_the_option_and_each_bad_one_named() {
        let want = FusedHand {
            strict: LoadRule {
                fraction_q15: 13_107,
                window: 10,
            },
            guard_q15: 26_214,
        };
        // Unset: no rule (a v1 blob).
        assert_eq!(
            Settings::defaults().resolve().unwrap().config.hand_rule,
            None
        );
        // The three keys (checkpoint metadata); 0.6 s at 16.7 Hz = 10.02 → 10 frames.
        let mut s = Settings::defaults();
        let meta: BTreeMap<String, String> = [
            (keys::HAND_RULE_FRACTION.to_string(), "0.4".to_string()),
            (keys::HAND_RULE_GUARD.to_string(), "0.8".to_string()),
            (keys::HAND_RULE_WINDOW_S.to_string(), "0.6".to_string()),
        ]
        .into();
        s.merge(&meta);
        assert!(s.unknown.is_empty());
        assert_eq!(s.resolve().unwrap().config.hand_rule, Some(want));
        // The option overrides them; guard 1 = no guard; at 40 Hz 0.6 s is 24 frames.
        s.set(HAND_RULE, "0.25, 1, 0.6");
        s.set(keys::SAMPLE_RATE_HZ, "40");
        let r = s.resolve().unwrap().config.hand_rule.unwrap();
        assert_eq!(
            (r.strict.fraction_q15, r.strict.window, r.guard_q15),
            (8192, 24, FusedHand::NO_GUARD)
        );
        // The round trip through describe keeps it.
        let c = s.resolve().unwrap().config;
        let mut back = Settings::defaults();
        back.merge(&describe(&c));
        assert_eq!(back.resolve().unwrap().config.hand_rule, c.hand_rule);
        // Each bad value names its key.
        for (k, v, key) in [
            (HAND_RULE, "0.4,0.8", HAND_RULE),
            (HAND_RULE, "1.5,0.8,0.6", keys::HAND_RULE_FRACTION),
            (HAND_RULE, "0.4,-0.1,0.6", keys::HAND_RULE_GUARD),
            (HAND_RULE, "0.4,0.8,0.01", keys::HAND_RULE_WINDOW_S),
            (HAND_RULE, "0.4,0.8,4", keys::HAND_RULE_WINDOW_S),
            (HAND_RULE, "0.4,x,0.6", keys::HAND_RULE_GUARD),
            (keys::HAND_RULE_FRACTION, "0.4", keys::HAND_RULE_GUARD),
        ] {
            let mut s = Settings::defaults();
            s.set(k, v);
            match s.resolve() {
                Err(ExportError::Settings { key: got, msg }) => {
                    assert_eq!(got, key, "{k}={v}: {msg}");
                    assert!(!msg.contains('\n'), "one line: {msg}");
                }
                other => panic!("{k}={v}: {other:?}"),
            }
        }
    }

    #[test]
    fn describe_round_trips_through_resolve() {
        let mut s = Settings::defaults();
        s.set(keys::VARIANT, "d");
        s.set(keys::FORCE_DIFF, "true");
        s.set(keys::STFT_WINDOW, "hann");
        s.set(keys::THRESHOLD, "0.625");
        s.set(keys::NAME, "rt");
        let c = s.resolve().unwrap().config;
        let mut back = Settings::defaults();
        back.merge(&describe(&c));
        let mut c2 = back.resolve().unwrap().config;
        c2.model_id = c.model_id;
        assert_eq!(c, c2);
    }

    /// The shipped checkpoints' metadata, as `slipguard train` wrote it, holds no key the
    /// exporter would call unknown (it used to note five).
    #[test]
    fn the_trainers_checkpoint_metadata_has_no_unknown_key() {
        for m in ["hand-force", "hand-force-40hz", "suction"] {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .parent()
                .unwrap()
                .join(format!("models/{m}/{m}.safetensors"));
            let bytes = std::fs::read(&path).unwrap();
            let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
            let meta: BTreeMap<String, String> =
                meta.metadata().clone().unwrap().into_iter().collect();
            assert!(
                meta.contains_key("train_command"),
                "{m}: not a trainer checkpoint"
            );
            let mut s = Settings::defaults();
            s.merge(&meta);
            assert!(s.unknown.is_empty(), "{m}: unknown {:?}", s.unknown);
        }
    }

    #[test]
    fn later_sources_win_and_unknown_keys_are_kept_for_a_warning() {
        let mut s = Settings::defaults();
        let file: BTreeMap<String, String> = [
            (keys::VARIANT.to_string(), "a".to_string()),
            ("lr".to_string(), "0.0006".to_string()),
        ]
        .into();
        s.merge(&file);
        s.set(keys::VARIANT, "b");
        assert_eq!(s.resolve().unwrap().config.variant, Variant::StftLstm);
        assert_eq!(s.unknown, vec!["lr".to_string()]);
    }

    #[test]
    fn each_bad_value_names_its_key() {
        for (k, v) in [
            (keys::VARIANT, "x"),
            (keys::THRESHOLD, "0"),
            (keys::INPUT_FULL_SCALE, "-3"),
            (keys::STFT_WINDOW_LEN, "2"),
            (keys::RAISE_AFTER, "0"),
            (keys::NORM_MEAN, "[1, \"a\"]"),
            (keys::FORMAT, "2"),
        ] {
            let mut s = Settings::defaults();
            s.set(k, v);
            match s.resolve() {
                Err(ExportError::Settings { key, .. }) => {
                    assert!(key.contains(k.split('_').next().unwrap_or(k)), "{k}: {key}")
                }
                other => panic!("{k}={v}: {other:?}"),
            }
        }
    }
}
