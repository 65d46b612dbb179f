//! Float model → blob v1 (host only, `std`). The exporter adds importers, calibration data
//! handling and reports around this; the arithmetic of quantization lives only here.
//!
//! - Weights: int8 symmetric, one scale per row, separately for W_ih and W_hh
//!   (s = max|row| / 127), rows zero-padded to a multiple of 4.
//! - Row requantisation: the largest shift ≤ 62 that keeps both multipliers in `i32`.
//! - Biases: b_ih + b_hh in Q3.12.
//! - Normalisation: μ in Q1.15, 1/(8σ) as gain·2^-shift.
//! - Cell state: the finest Q(15-C).C whose range covers 1.25 × the largest |c| the float model
//!   reaches on the calibration sequences (C = 11, ±16, without calibration data).
//! - Model id: when the header's is 0, [`crate::float::weights_id`] of the weights.

use crate::blob::{BlobTensors, DenseRowParams, FeatureNorm, LstmRowParams, pad4, write_blob};
use crate::float::{FloatLstm, FloatModel, FloatModelError};

/// Cell format used when no calibration data is given: Q4.11, range ±16.
pub const DEFAULT_CELL_FRAC_BITS: u8 = 11;
/// Headroom over the largest calibrated |c|.
pub const CELL_HEADROOM: f32 = 1.25;

/// What the quantizer measured.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct QuantReport {
    /// Largest |c| seen per LSTM on the calibration data.
    pub max_abs_cell: Vec<f32>,
    /// Chosen cell fractional bits per LSTM.
    pub cell_frac_bits: Vec<u8>,
    /// Per tensor: name, max |w - dequant(q)|, max |w|.
    pub tensor_errors: Vec<(String, f32, f32)>,
}

/// Quantizes `model`, choosing each LSTM's cell format from `calibration` (raw sample
/// sequences, one channel each, run from a reset state) or from `cell_frac_bits` when given.
/// A hand-level model cannot run on one channel's samples: it ignores them (the default cell
/// format unless given; calibrate it with [`quantize_rows`]).
pub fn quantize(
    model: &FloatModel,
    calibration: &[&[f32]],
    cell_frac_bits: Option<[u8; 2]>,
) -> Result<(Vec<u8>, QuantReport), FloatModelError> {
    model.validate()?;
    if model.config.variant.is_hand() {
        return quantize_rows(model, &[], cell_frac_bits);
    }
    let mut max_c = vec![0f32; model.lstms.len()];
    for seq in calibration {
        let mut st = model.new_channel();
        for &raw in *seq {
            model.step(&mut st, raw);
            for (m, s) in max_c.iter_mut().zip(&st.lstm) {
                *m = s.c.iter().fold(*m, |a, c| a.max(c.abs()));
            }
        }
    }
    quantize_calibrated(model, max_c, !calibration.is_empty(), cell_frac_bits)
}

/// [`quantize`] for a model that runs on rows of raw features (a hand-level model's hand
/// feature rows, [`crate::features::hand`]): the calibration sequences are rows, one slice per
/// sequence from a reset state.
pub fn quantize_rows(
    model: &FloatModel,
    calibration: &[&[Vec<f32>]],
    cell_frac_bits: Option<[u8; 2]>,
) -> Result<(Vec<u8>, QuantReport), FloatModelError> {
    model.validate()?;
    let mut max_c = vec![0f32; model.lstms.len()];
    for seq in calibration {
        let mut st = model.new_channel();
        for row in *seq {
            model.step_row(&mut st, row);
            for (m, s) in max_c.iter_mut().zip(&st.lstm) {
                *m = s.c.iter().fold(*m, |a, c| a.max(c.abs()));
            }
        }
    }
    quantize_calibrated(model, max_c, !calibration.is_empty(), cell_frac_bits)
}

/// The rest of [`quantize`] once the calibration's largest |c| per LSTM (`max_c`) is known.
fn quantize_calibrated(
    model: &FloatModel,
    max_c: Vec<f32>,
    calibrated: bool,
    cell_frac_bits: Option<[u8; 2]>,
) -> Result<(Vec<u8>, QuantReport), FloatModelError> {
    let mut report = QuantReport::default();
    let n_lstm = model.lstms.len();
    let mut config = model.config;
    if config.model_id == 0 {
        config.model_id = crate::float::weights_id(&model.lstms, &model.dense);
    }
    config.cell_frac_bits = [0, 0];
    for k in 0..n_lstm {
        let bits = match cell_frac_bits {
            Some(b) => b[k].clamp(1, 15),
            None if !calibrated => DEFAULT_CELL_FRAC_BITS,
            None => cell_bits_for(max_c[k] * CELL_HEADROOM),
        };
        config.cell_frac_bits[k] = bits;
        report.cell_frac_bits.push(bits);
    }
    report.max_abs_cell = max_c;

    let norm = model
        .norm_mean
        .iter()
        .zip(&model.norm_std)
        .map(|(&m, &s)| feature_norm(m, s))
        .collect();
    let mut lstm = Vec::new();
    for (k, l) in model.lstms.iter().enumerate() {
        lstm.push(quantize_lstm(l, k, &mut report));
    }
    let dense = quantize_dense(model, &mut report);
    let tensors = BlobTensors { norm, lstm, dense };
    Ok((write_blob(&config, &tensors), report))
}

/// Finest C in 1..=15 with 2^(15-C) > `range`.
pub fn cell_bits_for(range: f32) -> u8 {
    let mut c = 15u8;
    while c > 1 && (1u32 << (15 - c)) as f32 <= range {
        c -= 1;
    }
    c
}

/// μ, σ (Q1.15 input units as reals) → Q1.15 mean and gain·2^-shift = 1/(8σ).
pub fn feature_norm(mean: f32, std: f32) -> FeatureNorm {
    let r = 1.0 / (8.0 * std.max(1e-9) as f64);
    let (gain, shift) = mantissa_shift(r, 1 << 30);
    FeatureNorm {
        mean_q15: (mean as f64 * 32768.0)
            .round()
            .clamp(-(1 << 30) as f64, (1 << 30) as f64) as i32,
        gain,
        shift,
    }
}

/// Largest shift in 1..=62 with |x·2^shift| < `limit`, and the rounded mantissa.
fn mantissa_shift(x: f64, limit: i64) -> (i32, i32) {
    let mut shift = 62;
    while shift > 1 && (x.abs() * 2f64.powi(shift)).round() >= limit as f64 {
        shift -= 1;
    }
    ((x * 2f64.powi(shift)).round() as i32, shift)
}

/// Symmetric int8 quantization of one row: (q, scale), scale = max|row| / 127 (1 for a zero
/// row); the blob stores q and the row's scale, so `q · scale` is the weight the core computes
/// with. The one home of the weight rounding rule (the trainer's quantization-aware fine-tuning
/// fakes the rounding with it).
pub fn quantize_row(row: &[f32]) -> (Vec<i8>, f32) {
    let max = row.iter().fold(0f32, |a, w| a.max(w.abs()));
    let scale = if max > 0.0 { max / 127.0 } else { 1.0 };
    (
        row.iter()
            .map(|w| (w / scale).round().clamp(-127.0, 127.0) as i8)
            .collect(),
        scale,
    )
}

fn note_error(report: &mut QuantReport, name: String, pairs: &[(f32, f32)]) {
    let err = pairs.iter().fold(0f32, |a, (w, d)| a.max((w - d).abs()));
    let max = pairs.iter().fold(0f32, |a, (w, _)| a.max(w.abs()));
    report.tensor_errors.push((name, err, max));
}

fn quantize_lstm(
    l: &FloatLstm,
    k: usize,
    report: &mut QuantReport,
) -> (Vec<i8>, Vec<LstmRowParams>) {
    let (ni, nh) = (l.input, l.hidden);
    let hh_offset = pad4(ni);
    let row_len = hh_offset + pad4(nh);
    let mut w = vec![0i8; 4 * nh * row_len];
    let mut rows = Vec::with_capacity(4 * nh);
    let (mut e_ih, mut e_hh) = (Vec::new(), Vec::new());
    for r in 0..4 * nh {
        let (qi, si) = quantize_row(&l.w_ih[r * ni..(r + 1) * ni]);
        let (qh, sh) = quantize_row(&l.w_hh[r * nh..(r + 1) * nh]);
        w[r * row_len..r * row_len + ni].copy_from_slice(&qi);
        w[r * row_len + hh_offset..r * row_len + hh_offset + nh].copy_from_slice(&qh);
        e_ih.extend(
            l.w_ih[r * ni..(r + 1) * ni]
                .iter()
                .zip(&qi)
                .map(|(&f, &q)| (f, q as f32 * si)),
        );
        e_hh.extend(
            l.w_hh[r * nh..(r + 1) * nh]
                .iter()
                .zip(&qh)
                .map(|(&f, &q)| (f, q as f32 * sh)),
        );
        // mx = s_ih·2^shift, mh = s_hh·2^(shift-3): x is Q3.12 and h Q0.15, 3 bits apart.
        let big = (si as f64).max(sh as f64 / 8.0);
        let (_, shift) = mantissa_shift(big, i32::MAX as i64);
        let mx = (si as f64 * 2f64.powi(shift)).round() as i32;
        let mh = (sh as f64 * 2f64.powi(shift - 3)).round() as i32;
        let bias = (l.b_ih[r] + l.b_hh[r]) as f64 * 4096.0;
        rows.push(LstmRowParams {
            mx,
            mh,
            bias_q12: bias.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32,
            shift,
        });
    }
    note_error(report, format!("lstm{k}.weight_ih_l0"), &e_ih);
    note_error(report, format!("lstm{k}.weight_hh_l0"), &e_hh);
    (w, rows)
}

fn quantize_dense(model: &FloatModel, report: &mut QuantReport) -> (Vec<i8>, Vec<DenseRowParams>) {
    let k = model.dense.inputs;
    let row_len: usize = model.lstms.iter().map(|l| pad4(l.hidden)).sum();
    let mut w = vec![0i8; 2 * row_len];
    let mut rows = Vec::new();
    let mut errs = Vec::new();
    for r in 0..2 {
        let src = &model.dense.w[r * k..(r + 1) * k];
        let (q, s) = quantize_row(src);
        errs.extend(src.iter().zip(&q).map(|(&f, &q)| (f, q as f32 * s)));
        // Place each LSTM's part at its padded offset.
        let (mut src_off, mut dst_off) = (0, 0);
        for l in &model.lstms {
            w[r * row_len + dst_off..r * row_len + dst_off + l.hidden]
                .copy_from_slice(&q[src_off..src_off + l.hidden]);
            src_off += l.hidden;
            dst_off += pad4(l.hidden);
        }
        // logit·2^12 = s·acc·2^-3 (h is Q0.15): m = s·2^(shift-3).
        let (m, shift) = mantissa_shift(s as f64 / 8.0, i32::MAX as i64);
        let shift = shift.max(1);
        rows.push(DenseRowParams {
            m,
            bias_q12: (model.dense.b[r] as f64 * 4096.0).round() as i32,
            shift,
        });
    }
    note_error(report, "dense.weight".into(), &errs);
    (w, rows)
}
