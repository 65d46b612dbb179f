//! `inspect`: what a blob holds and what it costs on the target.

use serde::Serialize;
use slipguard_core::blob::{AlignedBlob, ModelBlob};
use slipguard_core::model::ChannelState;
use slipguard_core::{MAX_HIDDEN, MAX_INPUT};

use crate::error::{ExportError, Result};
use crate::settings::describe;

/// Size of the MODEL flash region (sector 11 of the STM32F405RG, memory.x).
pub const MODEL_REGION_BYTES: usize = 128 * 1024;

/// One tensor of the blob.
#[derive(Clone, Debug, Serialize)]
pub struct TensorInfo {
    /// What it is.
    pub name: String,
    /// Rows × columns.
    pub shape: [usize; 2],
    /// Bytes.
    pub bytes: usize,
}

/// Everything `inspect` reports.
#[derive(Clone, Debug, Serialize)]
pub struct BlobInfo {
    /// Header fields as settings strings.
    pub header: std::collections::BTreeMap<String, String>,
    /// Hidden sizes and cell formats.
    pub lstms: Vec<String>,
    /// Tensors.
    pub tensors: Vec<TensorInfo>,
    /// Total bytes (flash needed).
    pub total_bytes: usize,
    /// Fits the 128 KiB MODEL region.
    pub fits_model_region: bool,
    /// CRC-32 stored in the blob.
    pub crc: u32,
    /// LSTM + dense multiply-accumulates per channel step.
    pub macs_lstm_dense: usize,
    /// STFT multiply-accumulates per channel step (2 · bins · N).
    pub macs_stft: usize,
    /// RAM of one channel's state as compiled (static bounds: H ≤ 128, two LSTMs).
    pub ram_channel_state_static: usize,
    /// RAM of one channel's state this model actually uses (h, c, STFT window, d(t), flag).
    pub ram_channel_state_used: usize,
    /// Transient stack of one LSTM step (gate buffer of 4 · MAX_HIDDEN i16 + features).
    pub stack_per_step: usize,
    /// Float parameters the blob encodes.
    pub parameters: usize,
}

/// Parses a blob and describes it.
pub fn inspect(path: &std::path::Path, bytes: &[u8]) -> Result<BlobInfo> {
    let aligned = AlignedBlob::new(bytes);
    let blob = ModelBlob::parse(aligned.as_bytes()).map_err(|e| ExportError::Blob {
        path: path.into(),
        source: e,
    })?;
    Ok(describe_blob(&blob))
}

/// Describes a parsed blob.
pub fn describe_blob(blob: &ModelBlob<'_>) -> BlobInfo {
    let c = blob.config;
    let mut header = describe(&c);
    // The version the writer picks for this header (blob::write_blob): v3 for the hand-level
    // variant, v2 with a hand rule, else v1.
    let version = if c.variant.is_hand() {
        "3"
    } else if c.hand_rule.is_some() {
        "2"
    } else {
        "1"
    };
    header.insert("format_version".into(), version.into());
    if let Some(r) = &c.hand_rule {
        header.insert(
            "hand_rule".into(),
            format!(
                "{} (strict_q15 {}, guard_q15 {}, {} frames)",
                r, r.strict.fraction_q15, r.guard_q15, r.strict.window
            ),
        );
    }
    header.insert("input_unit".into(), c.input_unit.to_string());
    header.insert("threshold_q15".into(), c.threshold_q15.to_string());
    header.insert("features".into(), c.feature_count().to_string());
    let mut tensors = vec![TensorInfo {
        name: "feature norm (i32 μ, gain, shift)".into(),
        shape: [blob.norm.len(), 3],
        bytes: blob.norm.len() * 12,
    }];
    let mut lstms = Vec::new();
    let mut params = 2 * c.feature_count();
    let mut used = 0usize;
    for (k, l) in blob.lstms().iter().enumerate() {
        lstms.push(format!(
            "LSTM {k}: {} → {}, cell Q{}.{}, rows 4·{} × {} bytes (W_ih {} + pad, W_hh {} + pad)",
            l.inputs,
            l.hidden,
            15 - l.cell_frac_bits,
            l.cell_frac_bits,
            l.hidden,
            l.row_len,
            l.inputs,
            l.hidden
        ));
        tensors.push(TensorInfo {
            name: format!("LSTM {k} weights (i8)"),
            shape: [4 * l.hidden, l.row_len],
            bytes: l.weights.len(),
        });
        tensors.push(TensorInfo {
            name: format!("LSTM {k} row params (i32 mx, mh, bias, shift)"),
            shape: [4 * l.hidden, 4],
            bytes: l.rows.len() * 16,
        });
        params += 4 * l.hidden * (l.inputs + l.hidden + 2);
        used += 2 * 2 * l.hidden;
    }
    tensors.push(TensorInfo {
        name: "dense weights (i8)".into(),
        shape: [2, blob.dense.row_len],
        bytes: blob.dense.weights.len(),
    });
    tensors.push(TensorInfo {
        name: "dense row params (i32 m, bias, shift)".into(),
        shape: [2, 3],
        bytes: 24,
    });
    let k: usize = blob.lstms().iter().map(|l| l.hidden).sum();
    params += 2 * k + 2;
    let bands = c.variant.uses_bands();
    let macs_stft = if bands {
        2 * c.stft.n_bins as usize * c.stft.window_len as usize
    } else {
        0
    };
    // STFT ring buffer (i16 per sample), previous sample, decision state.
    used += if bands {
        2 * c.stft.window_len as usize
    } else {
        0
    } + 2
        + 3;
    BlobInfo {
        header,
        lstms,
        tensors,
        total_bytes: blob.len,
        fits_model_region: blob.len <= MODEL_REGION_BYTES,
        crc: blob.crc,
        macs_lstm_dense: c.macs_per_step(),
        macs_stft,
        ram_channel_state_static: std::mem::size_of::<ChannelState>(),
        ram_channel_state_used: used,
        stack_per_step: 2 * 4 * MAX_HIDDEN + 2 * MAX_INPUT,
        parameters: params,
    }
}

impl std::fmt::Display for BlobInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self
            .header
            .get("format_version")
            .map_or("1", String::as_str);
        writeln!(f, "slipguard model blob, format v{v}")?;
        writeln!(f, "header:")?;
        for (k, v) in &self.header {
            writeln!(f, "  {k:<18} {v}")?;
        }
        for l in &self.lstms {
            writeln!(f, "{l}")?;
        }
        writeln!(f, "tensors:")?;
        for t in &self.tensors {
            writeln!(
                f,
                "  {:<46} {:>4} × {:<4} {:>7} bytes",
                t.name, t.shape[0], t.shape[1], t.bytes
            )?;
        }
        writeln!(f, "parameters:        {}", self.parameters)?;
        let per = if self.header.get("variant").is_some_and(|v| v == "hand-lstm") {
            "per frame (one network per hand)"
        } else {
            "per channel"
        };
        writeln!(
            f,
            "MACs per step:     {} (LSTM + dense) + {} (STFT) {per}",
            self.macs_lstm_dense, self.macs_stft
        )?;
        writeln!(
            f,
            "flash:             {} bytes ({:.1} % of the 128 KiB MODEL region{})",
            self.total_bytes,
            100.0 * self.total_bytes as f64 / MODEL_REGION_BYTES as f64,
            if self.fits_model_region {
                ""
            } else {
                ": DOES NOT FIT"
            }
        )?;
        writeln!(
            f,
            "RAM per channel:   {} bytes as compiled (static bounds), {} bytes used by this model; {} bytes stack per step",
            self.ram_channel_state_static, self.ram_channel_state_used, self.stack_per_step
        )?;
        writeln!(
            f,
            "RAM for 16 ch:     {} bytes as compiled",
            16 * self.ram_channel_state_static
        )?;
        write!(f, "CRC-32:            {:#010x} (valid)", self.crc)
    }
}
