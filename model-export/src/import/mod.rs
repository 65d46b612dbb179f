//! Importers: a trained network from PyTorch/safetensors, ONNX or Keras 3 → one internal float
//! model ([`FloatModel`], PyTorch layout and gate order i, f, g, o) of one of the four variants.
//!
//! Each importer reads its file into an [`Imported`] (the LSTMs in the order their hidden states
//! are concatenated into the dense layer, the dense layer, the file's own metadata); [`assemble`]
//! then checks it against the declared variant and settings and builds the [`FloatModel`].

pub mod keras;
pub mod onnx;
mod onnx_fold;
mod onnx_proto;
pub mod torch;

use std::collections::BTreeMap;
use std::path::Path;

use slipguard_core::MAX_HIDDEN;
use slipguard_core::blob::Variant;
use slipguard_core::float::{FloatDense, FloatLstm, FloatModel, FloatModelError};

use crate::error::{ExportError, Result, check_finite};
use crate::settings::{DualOrder, Resolved};

/// Input formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// safetensors with PyTorch names (our trainer's checkpoints, any `nn.LSTM`/`nn.Linear` state_dict).
    Safetensors,
    /// ONNX `LSTM` followed by `Gemm` or `MatMul` + `Add`.
    Onnx,
    /// Keras 3 `.keras` archive (config + weights).
    Keras,
    /// Keras 3 `.weights.h5` (weights only; activations cannot be checked).
    KerasH5,
}

impl Format {
    /// Guesses the format from the file name, then from the first bytes.
    pub fn detect(path: &Path, head: &[u8]) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".safetensors") {
            return Some(Self::Safetensors);
        }
        if name.ends_with(".onnx") {
            return Some(Self::Onnx);
        }
        if name.ends_with(".keras") {
            return Some(Self::Keras);
        }
        if name.ends_with(".h5") || name.ends_with(".hdf5") {
            return Some(Self::KerasH5);
        }
        if head.starts_with(b"\x89HDF\r\n\x1a\n") {
            return Some(Self::KerasH5);
        }
        if head.starts_with(b"PK\x03\x04") {
            return Some(Self::Keras);
        }
        if head.len() >= 9 && head[8] == b'{' {
            return Some(Self::Safetensors);
        }
        None
    }
    /// Name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Safetensors => "safetensors (PyTorch names)",
            Self::Onnx => "ONNX",
            Self::Keras => "Keras 3 .keras",
            Self::KerasH5 => "Keras 3 .weights.h5",
        }
    }
}

/// One imported LSTM, already in PyTorch layout and gate order.
#[derive(Clone, Debug)]
pub struct NamedLstm {
    /// Where it came from (tensor prefix, ONNX node or Keras layer).
    pub name: String,
    /// The names of W_ih, W_hh, b_ih, b_hh in the file (for messages).
    pub tensors: [String; 4],
    /// The weights.
    pub lstm: FloatLstm,
}

/// The imported dense layer (1 or 2 outputs over the concatenated hidden states).
#[derive(Clone, Debug)]
pub struct NamedDense {
    /// Weight tensor name in the file.
    pub weight: String,
    /// Bias tensor name in the file.
    pub bias: String,
    /// Outputs (1 = a single logit for p(unstable) = σ(logit); 2 = softmax logits).
    pub outputs: usize,
    /// Inputs K.
    pub inputs: usize,
    /// outputs × K, row-major.
    pub w: Vec<f32>,
    /// outputs.
    pub b: Vec<f32>,
}

/// What an importer read.
#[derive(Clone, Debug)]
pub struct Imported {
    /// The file's format.
    pub format: Format,
    /// The LSTMs. When `concat_order_known`, in the order their hidden states enter the dense
    /// layer; otherwise the dense layer is taken to see [force LSTM, band LSTM].
    pub lstms: Vec<NamedLstm>,
    /// Whether the graph told us the concatenation order.
    pub concat_order_known: bool,
    /// The dense layer.
    pub dense: NamedDense,
    /// Settings stored in the file (safetensors `__metadata__`).
    pub metadata: BTreeMap<String, String>,
    /// Notes for the report (conversions made, tensors ignored).
    pub notes: Vec<String>,
}

/// Reads a model file of the given (or detected) format.
pub fn import(
    path: &Path,
    format: Option<Format>,
    keras_config: Option<&Path>,
) -> Result<Imported> {
    let bytes = std::fs::read(path).map_err(|e| ExportError::io(path, e))?;
    if is_torch_pickle(path, &bytes) {
        return Err(ExportError::format(
            path,
            "a PyTorch pickle (torch.save), which the exporter does not read (unpickling runs arbitrary code); save the weights as safetensors instead: `from safetensors.torch import save_file; save_file(model.state_dict(), \"model.safetensors\")`",
        ));
    }
    let format = match format.or_else(|| Format::detect(path, &bytes)) {
        Some(f) => f,
        None => {
            return Err(ExportError::format(
                path,
                "unknown model format (expected .safetensors, .onnx, .keras or .weights.h5; or pass --format)",
            ));
        }
    };
    match format {
        Format::Safetensors => torch::import(path, &bytes),
        Format::Onnx => onnx::import(path, &bytes),
        Format::Keras => keras::import_keras(path, &bytes),
        Format::KerasH5 => keras::import_h5(path, bytes, keras_config),
    }
}

/// Whether a file is what `torch.save` writes: a zip archive holding `…/data.pkl` (the format
/// since torch 1.6), or a bare pickle (protocol 2+ starts with 0x80) named `.pt`/`.pth`.
fn is_torch_pickle(path: &Path, bytes: &[u8]) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let torch_name = [".pt", ".pth", ".ckpt", ".tar"]
        .iter()
        .any(|e| name.ends_with(e));
    if bytes.starts_with(b"PK\x03\x04") {
        return zip::ZipArchive::new(std::io::Cursor::new(bytes)).is_ok_and(|z| {
            z.file_names()
                .any(|n| n.is_ok_and(|n| n.ends_with("data.pkl")))
        });
    }
    torch_name && bytes.first() == Some(&0x80)
}

fn shape_str(dims: &[usize]) -> String {
    format!(
        "[{}]",
        dims.iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// `[a, b]` as text.
pub fn dims(d: &[usize]) -> String {
    shape_str(d)
}

/// Largest element count of one tensor an importer reads from a file: 16 Mi values (64 MiB as
/// f32), far above the firmware's largest tensor (4 · 128 × (128 + 12) = 71 680 weights of
/// W_ih | W_hh), so that any model the firmware could run is read and then refused by size with
/// its own message, while a malformed file cannot make the importer allocate gigabytes.
pub const MAX_TENSOR_ELEMENTS: usize = 1 << 24;

/// The element count of a tensor of shape `shape` read from a file: the product with checked
/// arithmetic, refused (exit 9) when it overflows or is over [`MAX_TENSOR_ELEMENTS`]; every
/// dimension is bounded too, so that later `4 * H` and `rows * cols` cannot overflow even when
/// another dimension is 0.
pub fn element_count(tensor: &str, shape: &[u64]) -> Result<usize> {
    let over = |what: String| ExportError::OverBounds {
        tensor: tensor.into(),
        msg: format!(
            "shape [{}] {what}, over the importer's bound of {MAX_TENSOR_ELEMENTS} elements per tensor (malformed file?)",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut n: u64 = 1;
    for &d in shape {
        if d > MAX_TENSOR_ELEMENTS as u64 {
            return Err(over(format!("has a dimension of {d}")));
        }
        n = n
            .checked_mul(d)
            .ok_or_else(|| over("overflows 64 bits".to_string()))?;
    }
    if n > MAX_TENSOR_ELEMENTS as u64 {
        return Err(over(format!("has {n} elements")));
    }
    // n ≤ 2^24 fits every usize the exporter builds for.
    Ok(n as usize)
}

/// Role of each imported LSTM for a dual model: index of the force LSTM and of the band LSTM.
fn dual_roles(lstms: &[NamedLstm], force_in: usize, band_in: usize) -> Result<(usize, usize)> {
    let has = |i: usize, words: &[&str]| {
        let n = lstms[i].name.to_ascii_lowercase();
        words.iter().any(|w| n.contains(w))
    };
    let force_words = ["force", "data"];
    let band_words = ["band", "stft", "freq"];
    for (f, b) in [(0, 1), (1, 0)] {
        if has(f, &force_words) && has(b, &band_words) {
            return Ok((f, b));
        }
    }
    let fits = |i: usize, n: usize| lstms[i].lstm.input == n;
    match (
        fits(0, force_in) && fits(1, band_in),
        fits(1, force_in) && fits(0, band_in),
    ) {
        (true, false) => Ok((0, 1)),
        (false, true) => Ok((1, 0)),
        (true, true) => Err(ExportError::missing(
            format!("{} / {}", lstms[0].tensors[0], lstms[1].tensors[0]),
            format!(
                "both LSTMs take {force_in} inputs and their names (`{}`, `{}`) do not say which is the force path; name them with `force` and `bands` (e.g. lstm_force, lstm_bands)",
                lstms[0].name, lstms[1].name
            ),
        )),
        (false, false) => Err(ExportError::shape(
            format!("{} / {}", lstms[0].tensors[0], lstms[1].tensors[0]),
            format!("one LSTM with {force_in} inputs (force path) and one with {band_in} (bands)"),
            format!("inputs {} and {}", lstms[0].lstm.input, lstms[1].lstm.input),
        )),
    }
}

/// Checks an import against the declared variant and settings and builds the float model.
/// Returns the model and whether the normalisation came from the settings (else it is the
/// identity and the caller must fit it or refuse).
pub fn assemble(imp: &Imported, res: &Resolved) -> Result<(FloatModel, bool)> {
    let mut config = res.config;
    let variant = config.variant;
    let need = variant.lstm_count();
    let names: Vec<String> = imp.lstms.iter().map(|l| l.name.clone()).collect();
    if imp.lstms.len() > need {
        return Err(ExportError::unsupported(
            names.join(", "),
            format!(
                "the file has {} LSTMs but variant {} has {need}; only the dual variant (d, lstm-stft-lstm) has two, and stacked LSTM layers are not supported",
                imp.lstms.len(),
                variant.name()
            ),
        ));
    }
    if imp.lstms.len() < need {
        return Err(ExportError::missing(
            "second LSTM",
            format!(
                "variant {} needs {need} LSTMs, the file has {} ({})",
                variant.name(),
                imp.lstms.len(),
                names.join(", ")
            ),
        ));
    }
    for l in &imp.lstms {
        if l.lstm.hidden > MAX_HIDDEN || l.lstm.hidden == 0 {
            return Err(ExportError::OverBounds {
                tensor: l.tensors[1].clone(),
                msg: format!(
                    "hidden size {} is outside the firmware's static bound 1..={MAX_HIDDEN}",
                    l.lstm.hidden
                ),
            });
        }
        for (t, v) in l
            .tensors
            .iter()
            .zip([&l.lstm.w_ih, &l.lstm.w_hh, &l.lstm.b_ih, &l.lstm.b_hh])
        {
            check_finite(t, v)?;
        }
    }
    check_finite(&imp.dense.weight, &imp.dense.w)?;
    check_finite(&imp.dense.bias, &imp.dense.b)?;

    // Model order: [force, bands] for the dual variant.
    let order: Vec<usize> = if need == 2 {
        let (f, b) = dual_roles(&imp.lstms, config.lstm_inputs(0), config.lstm_inputs(1))?;
        vec![f, b]
    } else {
        vec![0]
    };
    let mut lstms = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        let l = &imp.lstms[i];
        let want = config.lstm_inputs(k);
        if l.lstm.input != want {
            let what = match (variant, k) {
                (Variant::LstmStftLstm, 0) => "the force path".to_string(),
                (Variant::LstmStftLstm, _) => "the STFT bands".to_string(),
                _ => format!("variant {}", variant.name()),
            };
            return Err(ExportError::shape(
                l.tensors[0].clone(),
                format!(
                    "[{}, {want}] ({what}{} needs {want} inputs)",
                    4 * l.lstm.hidden,
                    if config.force_diff { " with d(t)" } else { "" }
                ),
                format!("[{}, {}]", 4 * l.lstm.hidden, l.lstm.input),
            ));
        }
        config.hidden[k] = l.lstm.hidden as u16;
        lstms.push(l.lstm.clone());
    }

    // Dense layer: 2 × K over [h_force, h_bands].
    let d = &imp.dense;
    let k_total: usize = lstms.iter().map(|l| l.hidden).sum();
    if d.inputs != k_total || !(d.outputs == 1 || d.outputs == 2) {
        return Err(ExportError::shape(
            d.weight.clone(),
            format!(
                "[2, {k_total}] (2 logits over the {k_total} concatenated hidden states; [1, {k_total}] for a single sigmoid logit)"
            ),
            format!("[{}, {}]", d.outputs, d.inputs),
        ));
    }
    // Columns of each imported LSTM in the file's concatenation order.
    let file_order: Vec<usize> = if need == 1 {
        vec![0]
    } else {
        let given = res.dual_order.map(|o| match o {
            DualOrder::ForceBands => order.clone(),
            DualOrder::BandsForce => vec![order[1], order[0]],
        });
        match (imp.concat_order_known, given) {
            (true, None) => (0..imp.lstms.len()).collect(),
            (true, Some(g)) => {
                let read: Vec<usize> = (0..imp.lstms.len()).collect();
                if g != read {
                    return Err(ExportError::settings(
                        "dual_order",
                        format!(
                            "the file concatenates [{}, {}], but --dual-order says otherwise",
                            imp.lstms[0].name, imp.lstms[1].name
                        ),
                    ));
                }
                read
            }
            (false, Some(g)) => g,
            (false, None) => {
                return Err(ExportError::settings(
                    "dual_order",
                    format!(
                        "the {} file does not say in which order the dense layer `{}` sees the hidden states of `{}` (force) and `{}` (bands); pass --dual-order force,bands or --dual-order bands,force",
                        imp.format.name(),
                        d.weight,
                        imp.lstms[order[0]].name,
                        imp.lstms[order[1]].name
                    ),
                ));
            }
        }
    };
    let mut col_start = vec![0usize; imp.lstms.len()];
    let mut off = 0;
    for &i in &file_order {
        col_start[i] = off;
        off += imp.lstms[i].lstm.hidden;
    }
    let mut w = vec![0f32; 2 * k_total];
    let mut b = [0f32; 2];
    for r in 0..d.outputs {
        let dst_r = if d.outputs == 1 { 1 } else { r };
        let mut dst = 0;
        for &i in &order {
            let h = imp.lstms[i].lstm.hidden;
            let src = r * d.inputs + col_start[i];
            w[dst_r * k_total + dst..dst_r * k_total + dst + h].copy_from_slice(&d.w[src..src + h]);
            dst += h;
        }
        b[dst_r] = d.b[r];
    }

    let nf = config.feature_count();
    let (norm_mean, norm_std, given) = match (&res.norm_mean, &res.norm_std) {
        (Some(m), Some(s)) => {
            for (key, v) in [("norm_mean", m), ("norm_std", s)] {
                if v.len() != nf {
                    return Err(ExportError::settings(
                        key,
                        format!(
                            "has {} entries, variant {}{} has {nf} features [force, d(t), bands]",
                            v.len(),
                            variant.name(),
                            if config.force_diff { " with d(t)" } else { "" }
                        ),
                    ));
                }
            }
            if let Some(i) = s.iter().position(|&x| x <= 0.0) {
                return Err(ExportError::settings(
                    "norm_std",
                    format!("entry {i} must be > 0"),
                ));
            }
            (m.clone(), s.clone(), true)
        }
        (None, None) => (vec![0.0; nf], vec![1.0; nf], false),
        (Some(_), None) => {
            return Err(ExportError::settings(
                "norm_std",
                "norm_mean is given but norm_std is not",
            ));
        }
        (None, Some(_)) => {
            return Err(ExportError::settings(
                "norm_mean",
                "norm_std is given but norm_mean is not",
            ));
        }
    };

    let dense = FloatDense {
        inputs: k_total,
        w,
        b: b.to_vec(),
    };
    config.model_id = res.model_id.unwrap_or_else(|| weights_id(&lstms, &dense));
    let model = FloatModel {
        config,
        norm_mean,
        norm_std,
        lstms,
        dense,
    };
    model.validate().map_err(|e| match e {
        FloatModelError::Shape {
            tensor,
            expected,
            found,
        } => ExportError::shape(
            tensor,
            format!("{expected} elements"),
            format!("{found} elements"),
        ),
        FloatModelError::NotFinite { tensor, index } => ExportError::NotFinite {
            tensor,
            index,
            at: String::new(),
        },
        other => ExportError::unsupported("model", other.to_string()),
    })?;
    Ok((model, given))
}

pub use slipguard_core::float::weights_id;

/// Reorders the four gate blocks of a 4H-row tensor (`cols` values per row).
/// `src_block[k]` is the block of the source that becomes PyTorch's block k (i, f, g, o).
pub fn reorder_gates(v: &[f32], hidden: usize, cols: usize, src_block: [usize; 4]) -> Vec<f32> {
    let blk = hidden * cols;
    let mut out = Vec::with_capacity(v.len());
    for &s in &src_block {
        out.extend_from_slice(&v[s * blk..(s + 1) * blk]);
    }
    out
}

/// Transposes a rows × cols row-major matrix.
pub fn transpose(v: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0f32; v.len()];
    for r in 0..rows {
        for c in 0..cols {
            out[c * rows + r] = v[r * cols + c];
        }
    }
    out
}
