//! The export report: what was imported, how it was quantized, and what quantization cost.
//! Written as JSON (for CI and scripts) and markdown (for people).

use std::collections::BTreeMap;

use serde::Serialize;
use slipguard_core::float::FloatModel;
use slipguard_core::quantize::QuantReport;

use crate::calib::{Agreement, Calibration};
use crate::inspect::BlobInfo;

/// Quantization error of one tensor.
#[derive(Clone, Debug, Serialize)]
pub struct TensorError {
    /// Tensor (core naming: `lstm0.weight_ih_l0`, `dense.weight`, biases).
    pub tensor: String,
    /// Format it is stored in.
    pub format: String,
    /// max |w − dequant(q(w))|.
    pub max_abs_error: f32,
    /// max |w|.
    pub max_abs_value: f32,
    /// max_abs_error / max_abs_value.
    pub relative: f32,
}

/// Everything an export reports.
#[derive(Clone, Debug, Serialize)]
pub struct ExportReport {
    /// Exporter version.
    pub exporter: String,
    /// Input file.
    pub input: String,
    /// Input format.
    pub format: String,
    /// Where the LSTMs came from, in model order.
    pub lstm_sources: Vec<String>,
    /// Where the normalisation came from.
    pub normalisation_source: String,
    /// Settings in force.
    pub settings: BTreeMap<String, String>,
    /// Importer notes and warnings.
    pub notes: Vec<String>,
    /// The blob.
    pub blob: BlobInfo,
    /// Per tensor quantization error.
    pub tensor_errors: Vec<TensorError>,
    /// Calibration data used, if any.
    pub calibration_data: Option<String>,
    /// Calibration statistics.
    pub calibration: Option<Calibration>,
    /// Data the agreement was measured on.
    pub agreement_data: Option<String>,
    /// Quantized vs float.
    pub agreement: Option<Agreement>,
}

/// Per tensor errors: the quantizer's weight errors plus the Q3.12 biases.
pub fn tensor_errors(model: &FloatModel, q: &QuantReport) -> Vec<TensorError> {
    let mut out: Vec<TensorError> = q
        .tensor_errors
        .iter()
        .map(|(t, e, m)| TensorError {
            tensor: t.clone(),
            format: "int8, per-row scale".into(),
            max_abs_error: *e,
            max_abs_value: *m,
            relative: if *m > 0.0 { e / m } else { 0.0 },
        })
        .collect();
    let q12 = |v: f32| ((v as f64 * 4096.0).round() / 4096.0) as f32;
    let mut bias = |name: String, v: Vec<f32>| {
        let e = v.iter().fold(0f32, |a, &x| a.max((x - q12(x)).abs()));
        let m = v.iter().fold(0f32, |a, &x| a.max(x.abs()));
        out.push(TensorError {
            tensor: name,
            format: "Q3.12 in i32".into(),
            max_abs_error: e,
            max_abs_value: m,
            relative: if m > 0.0 { e / m } else { 0.0 },
        });
    };
    for (k, l) in model.lstms.iter().enumerate() {
        bias(
            format!("lstm{k}.bias_ih_l0+bias_hh_l0"),
            l.b_ih.iter().zip(&l.b_hh).map(|(a, b)| a + b).collect(),
        );
    }
    bias("dense.bias".into(), model.dense.b.clone());
    out
}

fn pct(x: Option<f64>) -> String {
    x.map_or("–".into(), |v| format!("{:.2} %", 100.0 * v))
}

impl ExportReport {
    /// The report as markdown.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!(
            "# slipguard model export: `{}`\n\n",
            self.settings.get("name").cloned().unwrap_or_default()
        ));
        s.push_str(&format!(
            "- input: `{}` ({})\n- exporter: {}\n",
            self.input, self.format, self.exporter
        ));
        s.push_str(&format!(
            "- LSTMs (model order): {}\n",
            self.lstm_sources.join(", ")
        ));
        s.push_str(&format!("- normalisation: {}\n", self.normalisation_source));
        s.push_str(&format!(
            "- blob: {} bytes, CRC-32 `{:#010x}`, {} MACs/step (LSTM + dense) + {} (STFT), {} bytes RAM/channel as compiled\n",
            self.blob.total_bytes, self.blob.crc, self.blob.macs_lstm_dense, self.blob.macs_stft, self.blob.ram_channel_state_static
        ));
        for n in &self.notes {
            s.push_str(&format!("- note: {n}\n"));
        }
        s.push_str("\n## Settings\n\n| key | value |\n|---|---|\n");
        for (k, v) in &self.settings {
            s.push_str(&format!("| {k} | {v} |\n"));
        }
        for l in &self.blob.lstms {
            s.push_str(&format!("\n{l}\n"));
        }
        s.push_str("\n## Quantization error per tensor\n\n| tensor | stored as | max \\|Δw\\| | max \\|w\\| | relative |\n|---|---|---:|---:|---:|\n");
        for t in &self.tensor_errors {
            s.push_str(&format!(
                "| {} | {} | {:.3e} | {:.4} | {:.3e} |\n",
                t.tensor, t.format, t.max_abs_error, t.max_abs_value, t.relative
            ));
        }
        s.push_str("\n## Calibration\n\n");
        match (&self.calibration_data, &self.calibration) {
            (Some(d), Some(c)) => {
                s.push_str(&format!(
                    "Data: `{d}`: {} channel sequences, {} steps.\n\n",
                    c.sequences, c.steps
                ));
                s.push_str(
                    "| LSTM | max \\|c\\| | cell format | max \\|h\\| |\n|---:|---:|---|---:|\n",
                );
                for k in 0..c.max_abs_cell.len() {
                    let b = c.cell_frac_bits[k];
                    s.push_str(&format!(
                        "| {k} | {:.3} | Q{}.{} (±{}) | {:.3} |\n",
                        c.max_abs_cell[k],
                        15 - b,
                        b,
                        1u32 << (15 - b),
                        c.max_abs_hidden[k]
                    ));
                }
                s.push_str(&format!(
                    "\nInput: {:.2} % of raw samples saturate the Q1.15 input range.\n\n",
                    100.0 * c.input_saturated
                ));
                s.push_str("| feature | max \\|(v−μ)/σ\\| | clipped at ±8σ |\n|---:|---:|---:|\n");
                for (j, (m, cl)) in c.feature_max_abs.iter().zip(&c.feature_clipped).enumerate() {
                    s.push_str(&format!("| {j} | {m:.2} | {:.3} % |\n", 100.0 * cl));
                }
            }
            _ => s.push_str("No calibration data: default cell format (or `--cell-bits`).\n"),
        }
        s.push_str("\n## Quantized vs float\n\n");
        match (&self.agreement_data, &self.agreement) {
            (Some(d), Some(a)) => {
                s.push_str(&format!(
                    "Data: `{d}`: {} sequences, {} steps.\n\n",
                    a.sequences, a.steps
                ));
                s.push_str(&format!(
                    "| flag agreement | on decisive steps¹ | max \\|Δp\\| | mean \\|Δp\\| | max \\|Δh\\| |\n|---:|---:|---:|---:|---:|\n| {:.3} % ({} steps differ) | {:.3} % of {} | {:.5} | {:.6} | {:.5} |\n\n¹ steps where the float p stays ≥ 0.02 from the threshold over the hysteresis window.\n",
                    100.0 * a.flag_agreement, a.flag_disagreements, 100.0 * a.decisive_flag_agreement, a.decisive_steps, a.max_abs_dp, a.mean_abs_dp, a.max_abs_dh
                ));
                if let (Some(f), Some(q)) = (&a.float_metrics, &a.quant_metrics) {
                    s.push_str("\n| model | success rate | ahead-drop rate | false-alarm rate |\n|---|---:|---:|---:|\n");
                    s.push_str(&format!(
                        "| float | {} | {} | {} |\n",
                        pct(f.success_rate),
                        pct(f.ahead_drop_rate),
                        pct(f.false_alarm_rate)
                    ));
                    s.push_str(&format!(
                        "| quantized | {} | {} | {} |\n",
                        pct(q.success_rate),
                        pct(q.ahead_drop_rate),
                        pct(q.false_alarm_rate)
                    ));
                    s.push_str(&format!(
                        "\nChange: success rate {}, ahead-drop rate {} (percentage points).\n",
                        a.success_rate_change()
                            .map_or("–".into(), |v| format!("{v:+.2}")),
                        a.ahead_drop_change()
                            .map_or("–".into(), |v| format!("{v:+.2}"))
                    ));
                }
            }
            _ => s.push_str("Not measured (no `--data`).\n"),
        }
        s
    }
}
