//! Float checkpoints: safetensors with PyTorch's tensor names and the model settings in
//! `__metadata__` (docs/checkpoint.md).
//!
//! Tensors (f32, PyTorch layouts and gate order i, f, g, o):
//! `lstm.weight_ih_l0` [4H, I], `lstm.weight_hh_l0` [4H, H], `lstm.bias_ih_l0` [4H],
//! `lstm.bias_hh_l0` [4H] (dual variant: `lstm_force.*` and `lstm_bands.*`),
//! `dense.weight` [2, K], `dense.bias` [2]. A `torch.nn.LSTM(I, H, batch_first=True)` named
//! `lstm` and a `torch.nn.Linear(K, 2)` named `dense` save exactly these names.
//!
//! Metadata (all strings): see [`keys`]; the same keys as the exporter's settings
//! (docs/export.md), so `slipguard-export` reads these checkpoints directly.

use slipguard_core::units::Millihertz;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};
use slipguard_core::blob::{InputUnit, ModelConfig, UnknownName, Variant};
use slipguard_core::decision::Q15;
use slipguard_core::features::stft::{StftConfig, WindowShape};
use slipguard_core::float::{FloatDense, FloatLstm, FloatModel};

use crate::error::{LearnError, Result};

/// `__metadata__` keys: the data crate's, shared with the exporter's settings.
pub use slipguard_data::checkpoint_keys as keys;

/// PyTorch prefixes of the LSTMs of a variant (the checkpoint's tensor names).
pub fn lstm_prefixes(variant: Variant) -> &'static [&'static str] {
    match variant {
        Variant::Lstm | Variant::StftLstm | Variant::DataStftLstm | Variant::HandLstm => &["lstm"],
        Variant::LstmStftLstm => &["lstm_force", "lstm_bands"],
    }
}

/// The settings format version written by this module (the exporter's `slipguard.format`).
pub const FORMAT: &str = "1";

/// A float model plus free-form provenance metadata (training command, held-out trials, …).
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub model: FloatModel,
    /// Everything in `__metadata__` that is not a model setting.
    pub extra: BTreeMap<String, String>,
}

impl Checkpoint {
    /// A cross-validation fold's held-out trials (its `heldout_trials` note, as `slipguard
    /// train --cv` writes it); `None` for a model trained on every trial.
    pub fn heldout_trials(&self) -> Option<Vec<String>> {
        self.extra
            .get("heldout_trials")
            .map(|s| s.split(',').map(str::to_string).collect())
    }
}

/// The model settings as metadata strings.
pub fn config_metadata(m: &FloatModel) -> BTreeMap<String, String> {
    let c = &m.config;
    let mut md = BTreeMap::new();
    let mut put = |k: &str, v: String| {
        md.insert(k.to_string(), v);
    };
    put(keys::FORMAT, FORMAT.into());
    put(keys::NAME, c.name_str().into());
    put(keys::VARIANT, c.variant.to_string());
    put(keys::FORCE_DIFF, c.force_diff.to_string());
    put(keys::SAMPLE_RATE_HZ, format!("{}", c.sample_rate_hz()));
    put(keys::INPUT_UNIT, c.input_unit.to_string());
    put(keys::INPUT_OFFSET, c.input_offset.to_string());
    put(keys::INPUT_FULL_SCALE, c.input_full_scale.to_string());
    put(keys::STFT_WINDOW_LEN, c.stft.window_len.to_string());
    put(keys::STFT_FIRST_BIN, c.stft.first_bin.to_string());
    put(keys::STFT_N_BINS, c.stft.n_bins.to_string());
    put(keys::STFT_WINDOW, c.stft.shape.to_string());
    let hidden: Vec<String> = (0..c.variant.lstm_count())
        .map(|k| c.hidden[k].to_string())
        .collect();
    put(keys::HIDDEN, hidden.join(","));
    put(
        keys::THRESHOLD,
        format!("{}", Q15(c.threshold_q15 as i16).to_f64()),
    );
    put(keys::RAISE_AFTER, c.raise_after.to_string());
    put(keys::CLEAR_AFTER, c.clear_after.to_string());
    put(
        keys::NORM_MEAN,
        serde_json::to_string(&m.norm_mean).expect("json"),
    );
    put(
        keys::NORM_STD,
        serde_json::to_string(&m.norm_std).expect("json"),
    );
    md
}

/// Name bytes for the blob header (ASCII, truncated to 12).
pub fn name_bytes(name: &str) -> [u8; 12] {
    let mut b = [0u8; 12];
    for (d, s) in b
        .iter_mut()
        .zip(name.bytes().filter(|c| c.is_ascii_graphic()))
    {
        *d = s;
    }
    b
}

/// Parses the model settings from metadata.
pub fn config_from_metadata(md: &HashMap<String, String>) -> Result<ModelConfig> {
    let get = |k: &str| -> Result<&str> {
        md.get(k)
            .map(String::as_str)
            .ok_or_else(|| bad(format!("metadata key `{k}` missing")))
    };
    fn num<T: std::str::FromStr>(k: &str, v: &str) -> Result<T> {
        v.trim()
            .parse()
            .map_err(|_| bad(format!("metadata `{k}` = `{v}` is not a number")))
    }
    fn name<T: std::str::FromStr<Err = UnknownName>>(k: &str, v: &str) -> Result<T> {
        v.parse()
            .map_err(|e: UnknownName| bad(format!("metadata `{k}` = `{v}`: {e}")))
    }
    let variant: Variant = name(keys::VARIANT, get(keys::VARIANT)?)?;
    let input_unit: InputUnit = name(keys::INPUT_UNIT, get(keys::INPUT_UNIT)?)?;
    let shape: WindowShape = match md.get(keys::STFT_WINDOW) {
        None => WindowShape::Rectangular,
        Some(s) => name(keys::STFT_WINDOW, s)?,
    };
    let stft = if variant.uses_bands() {
        StftConfig {
            window_len: num(keys::STFT_WINDOW_LEN, get(keys::STFT_WINDOW_LEN)?)?,
            first_bin: num(keys::STFT_FIRST_BIN, get(keys::STFT_FIRST_BIN)?)?,
            n_bins: num(keys::STFT_N_BINS, get(keys::STFT_N_BINS)?)?,
            shape,
        }
    } else {
        StftConfig::NONE
    };
    let hs: Vec<u16> = match md.get(keys::HIDDEN) {
        Some(h) => h
            .split(',')
            .map(|h| num(keys::HIDDEN, h))
            .collect::<Result<_>>()?,
        None => Vec::new(),
    };
    let mut hidden = [0u16; 2];
    for (d, h) in hidden.iter_mut().zip(&hs) {
        *d = *h;
    }
    if variant.lstm_count() == 2 && hs.len() == 1 {
        hidden[1] = hidden[0];
    }
    let rate: f64 = num(keys::SAMPLE_RATE_HZ, get(keys::SAMPLE_RATE_HZ)?)?;
    let thr: f64 = md
        .get(keys::THRESHOLD)
        .map(|v| num(keys::THRESHOLD, v))
        .transpose()?
        .unwrap_or(0.5);
    let small = |k: &str| -> Result<u8> {
        md.get(k)
            .map(|v| num(k, v))
            .transpose()
            .map(|v| v.unwrap_or(1))
    };
    Ok(ModelConfig {
        model_id: 0,
        name: name_bytes(md.get(keys::NAME).map(String::as_str).unwrap_or("")),
        variant,
        force_diff: md.get(keys::FORCE_DIFF).is_some_and(|v| v == "true"),
        sample_rate_mhz: Millihertz::from_hz(rate as f64),
        input_unit,
        input_offset: num(keys::INPUT_OFFSET, get(keys::INPUT_OFFSET)?)?,
        input_full_scale: num(keys::INPUT_FULL_SCALE, get(keys::INPUT_FULL_SCALE)?)?,
        stft,
        hidden,
        cell_frac_bits: [0, 0],
        threshold_q15: Q15::from_f64(thr).header_threshold(),
        raise_after: small(keys::RAISE_AFTER)?,
        clear_after: small(keys::CLEAR_AFTER)?,
        hand_rule: None,
    })
}

/// Serialises a checkpoint to safetensors bytes.
pub fn to_bytes(ck: &Checkpoint) -> Result<Vec<u8>> {
    ck.model.validate()?;
    let m = &ck.model;
    let mut md: HashMap<String, String> = ck.extra.clone().into_iter().collect();
    md.extend(config_metadata(m));
    let mut owned: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    let bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    for (l, p) in m.lstms.iter().zip(lstm_prefixes(m.config.variant)) {
        let (i, h) = (l.input, l.hidden);
        owned.push((format!("{p}.weight_ih_l0"), bytes(&l.w_ih), vec![4 * h, i]));
        owned.push((format!("{p}.weight_hh_l0"), bytes(&l.w_hh), vec![4 * h, h]));
        owned.push((format!("{p}.bias_ih_l0"), bytes(&l.b_ih), vec![4 * h]));
        owned.push((format!("{p}.bias_hh_l0"), bytes(&l.b_hh), vec![4 * h]));
    }
    owned.push((
        "dense.weight".into(),
        bytes(&m.dense.w),
        vec![2, m.dense.inputs],
    ));
    owned.push(("dense.bias".into(), bytes(&m.dense.b), vec![2]));
    let views: Vec<(String, TensorView<'_>)> = owned
        .iter()
        .map(|(n, b, s)| Ok((n.clone(), TensorView::new(Dtype::F32, s.clone(), b)?)))
        .collect::<std::result::Result<_, safetensors::SafeTensorError>>()?;
    Ok(safetensors::serialize(views, Some(md))?)
}

/// Writes a checkpoint file.
pub fn write(path: &Path, ck: &Checkpoint) -> Result<()> {
    let io = |p: &Path| {
        let path = p.to_path_buf();
        move |source| LearnError::Io { path, source }
    };
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(io(d))?;
    }
    std::fs::write(path, to_bytes(ck)?).map_err(io(path))
}

/// Parses safetensors bytes into a checkpoint.
pub fn from_bytes(bytes: &[u8]) -> Result<Checkpoint> {
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)?;
    let md: HashMap<String, String> = meta.metadata().clone().unwrap_or_default();
    let st = safetensors::SafeTensors::deserialize(bytes)?;
    let mut config = config_from_metadata(&md)?;
    if let Some(v) = md.get(keys::FORMAT).filter(|v| v.as_str() != FORMAT) {
        return Err(bad(format!(
            "settings format `{v}` is not supported (expected {FORMAT})"
        )));
    }
    let tensor = |n: &str| -> Result<(Vec<f32>, Vec<usize>)> {
        let t = st
            .tensor(n)
            .map_err(|_| bad(format!("tensor `{n}` missing")))?;
        if t.dtype() != Dtype::F32 {
            return Err(bad(format!(
                "tensor `{n}` is {:?}, expected F32",
                t.dtype()
            )));
        }
        let v = t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Ok((v, t.shape().to_vec()))
    };
    let mut lstms = Vec::new();
    for (k, p) in lstm_prefixes(config.variant).iter().enumerate() {
        let (w_ih, s_ih) = tensor(&format!("{p}.weight_ih_l0"))?;
        let (w_hh, _) = tensor(&format!("{p}.weight_hh_l0"))?;
        let (b_ih, _) = tensor(&format!("{p}.bias_ih_l0"))?;
        let (b_hh, _) = tensor(&format!("{p}.bias_hh_l0"))?;
        // Sizes come from the tensor shapes ([4H, I]).
        let hidden = s_ih.first().copied().unwrap_or(0) / 4;
        config.hidden[k] = hidden as u16;
        let input = s_ih.get(1).copied().unwrap_or(0);
        lstms.push(FloatLstm {
            input,
            hidden,
            w_ih,
            w_hh,
            b_ih,
            b_hh,
        });
    }
    let (w, s) = tensor("dense.weight")?;
    let (b, _) = tensor("dense.bias")?;
    let parse_vec = |k: &str| -> Result<Vec<f32>> {
        let v = md
            .get(k)
            .ok_or_else(|| bad(format!("metadata key `{k}` missing")))?;
        serde_json::from_str(v).map_err(|_| bad(format!("metadata `{k}` is not a JSON array")))
    };
    let model = FloatModel {
        config,
        norm_mean: parse_vec(keys::NORM_MEAN)?,
        norm_std: parse_vec(keys::NORM_STD)?,
        lstms,
        dense: FloatDense {
            inputs: s.get(1).copied().unwrap_or(0),
            w,
            b,
        },
    };
    model.validate()?;
    let model_keys = config_metadata(&model);
    let extra = md
        .into_iter()
        .filter(|(k, _)| !model_keys.contains_key(k))
        .collect();
    Ok(Checkpoint { model, extra })
}

/// Reads a checkpoint file.
pub fn read(path: &Path) -> Result<Checkpoint> {
    let b = std::fs::read(path).map_err(|source| LearnError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_bytes(&b).map_err(|e| LearnError::File {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

fn bad(message: String) -> LearnError {
    LearnError::Checkpoint(message)
}
