//! Quantization-aware fine-tuning (QAT): a few epochs after float training in which the forward
//! pass computes what the blob computes, so that the weights learn to live with int8 rounding
//! and the core's fixed-point arithmetic.
//!
//! The forward pass, per step and channel (the core's `slipguard_core::lstm` in reals):
//!
//! * inputs: the blob's own front end (`slipguard_core::features`: fixed-point STFT, d(t),
//!   normalisation with the blob's μ and 1/(8σ) multipliers), Q3.12 as reals;
//! * weights: int8 fake-quantised by the quantizer's own rule
//!   ([`slipguard_core::quantize::quantize_row`], one scale per row of W_ih, W_hh and the dense
//!   layer), biases b_ih + b_hh rounded to Q3.12;
//! * gate pre-activations rounded to Q3.12 and saturated to [-8, 8), σ and tanh read from the
//!   core's interpolated tables ([`slipguard_core::activation`], evaluated at every Q3.12 input);
//! * cell c' = sat(round(f·c) + round(i·g)) in the blob's cell format Q(15-C).C, tanh of c' in
//!   Q3.12 by the table, h = round(o·tanh(c')) in Q0.15.
//!
//! Every rounding is straight-through (candle has no custom gradients): the forward value is
//! `x + (q(x) - x).detach()`, the gradient that of x, with σ'/tanh' of the exact functions.
//! The float weights are kept and trained; the result is snapped to what the blob stores
//! ([`snap_to_blob_grid`]: each weight q·s, the biases summed in Q3.12), so that the float
//! checkpoint *is* the network the blob runs, in float arithmetic, and re-quantizing it gives
//! the same int8 weights.

use candle_core::{D, DType, Device, Tensor, Var};
use rand::SeedableRng;
use slipguard_core::MAX_INPUT;
use slipguard_core::float::FloatModel;
use slipguard_core::quantize::{feature_norm, quantize_row};

use crate::error::{LearnError, Result};
use crate::train::{
    Batch, Prepared, Progress, TrainConfig, TrainOutcome, make_batch, mean_loss, train_epoch,
};
use slipguard_data::labels::ChannelSequence;

/// Settings of the fine-tuning (the rest comes from the [`TrainConfig`]: batch, seed, class
/// and start weights, label lead, patience).
#[derive(Debug, Clone, PartialEq)]
pub struct QatConfig {
    /// Epochs of fine-tuning.
    pub epochs: usize,
    /// Adam learning rate.
    pub lr: f64,
    /// Cell format C per LSTM (the blob's `cell_frac_bits`; the quantizer picks it from the
    /// calibration data, [`slipguard_core::quantize::QuantReport::cell_frac_bits`]).
    pub cell_frac_bits: Vec<u8>,
    /// Whole recordings (raw samples, unlabelled) on which each epoch's blob is compared with
    /// its float checkpoint ([`max_dp_blob_vs_float`]): the epoch kept is the one with the lowest
    /// validation loss among those within `max_dp` there (else the one closest to it). Empty: by
    /// validation loss alone.
    pub agreement: Vec<Vec<f32>>,
    /// Bound on max |Δp| over [`Self::agreement`] for an epoch to be kept.
    pub max_dp: f32,
    /// Cell-state bound: the loss adds the mean over units of relu(|c| − cell_max)², averaged
    /// over steps, so that the cell stays in a range a finer cell format covers (0 = none).
    pub cell_max: f32,
}

/// max |Δp| between the blob of `model` with cell formats `cell_frac_bits` (the bit-exact
/// core) and the float model, over every step of `seqs` from a reset state: what
/// `slipguard-export verify` measures.
pub fn max_dp_blob_vs_float(
    model: &FloatModel,
    cell_frac_bits: &[u8],
    seqs: &[Vec<f32>],
) -> Result<f32> {
    let bits = [
        cell_frac_bits.first().copied().unwrap_or(11),
        cell_frac_bits.get(1).copied().unwrap_or(11),
    ];
    let (blob, _) = slipguard_core::quantize::quantize(model, &[], Some(bits))?;
    let aligned = slipguard_core::blob::AlignedBlob::new(&blob);
    let q = slipguard_core::model::Model::from_bytes(aligned.as_bytes())
        .map_err(|e| LearnError::Training(format!("the quantized model does not parse: {e}")))?;
    let mut worst = 0f32;
    for s in seqs {
        let pq = crate::evaluation::quant_p_q15(&q, s);
        let pf = crate::train::float_probabilities(model, s);
        for (&q, f) in pq.iter().zip(pf) {
            worst = worst.max((q as f32 / 32768.0 - f).abs());
        }
    }
    Ok(worst)
}

/// The features the blob's front end computes for one raw sequence (Q3.12 as reals, one row per
/// step): the integer path of `slipguard_core::model::Model::p_unstable` up to the LSTM input.
pub fn blob_features(model: &FloatModel, samples: &[f32]) -> Vec<Vec<f32>> {
    use slipguard_core::features::{FeatureState, normalise, raw_features};
    let config = &model.config;
    let layout = config.feature_layout();
    let plan = if config.variant.uses_bands() {
        slipguard_core::features::stft::StftPlan::new(config.stft).ok()
    } else {
        None
    };
    let norm: Vec<_> = model
        .norm_mean
        .iter()
        .zip(&model.norm_std)
        .map(|(&m, &s)| feature_norm(m, s))
        .collect();
    let scale = slipguard_core::sample::InputScale::of(config);
    let n = layout.len().min(MAX_INPUT);
    let mut st = FeatureState::new();
    samples
        .iter()
        .map(|&raw| {
            let mut v = [0i16; MAX_INPUT];
            // As the evaluation feeds the core: the raw reading rounded to an integer.
            raw_features(
                layout,
                plan.as_ref(),
                &mut st,
                scale.to_q15(raw.round() as i32),
                &mut v,
            );
            normalise(&norm, &mut v[..n]);
            v[..n].iter().map(|&q| q as f32 / 4096.0).collect()
        })
        .collect()
}

/// One activation evaluated by the core at every Q3.12 input (index = input + 32 768), Q0.15
/// as reals: the table lookup as a gather.
fn activation_table(tanh: bool, dev: &Device) -> candle_core::Result<Tensor> {
    let v: Vec<f32> = (i16::MIN..=i16::MAX)
        .map(|x| {
            let y = if tanh {
                slipguard_core::dsp::tanh(x)
            } else {
                slipguard_core::dsp::sigmoid(x)
            };
            y as f32 / 32768.0
        })
        .collect();
    Tensor::from_vec(v, 65_536, dev)
}

/// `x` on the grid 2^-frac: ⌊x·2^frac + ½⌋ (the core's rounding right shifts), saturated to
/// the i16 range of that format. Detached: a forward value only.
fn grid(x: &Tensor, frac: u32) -> candle_core::Result<Tensor> {
    let s = (1u32 << frac) as f64;
    x.detach()
        .affine(s, 0.5)?
        .floor()?
        .clamp(-32768f32, 32767f32)?
        .affine(1.0 / s, 0.0)
}

/// Straight-through: the forward value `q`, the gradient of `x`.
fn ste(x: &Tensor, q: &Tensor) -> candle_core::Result<Tensor> {
    x + (q - x)?.detach()
}

struct Lstm {
    w_ih: Var,
    w_hh: Var,
    b_ih: Var,
    b_hh: Var,
    input: usize,
    hidden: usize,
    cell_frac_bits: u32,
}

/// The network with the blob's arithmetic in its forward pass.
struct QatNet {
    lstms: Vec<Lstm>,
    dense_w: Var,
    dense_b: Var,
    sigmoid: Tensor,
    tanh: Tensor,
    /// Bound on |c| the loss penalises beyond (0 = none).
    cell_max: f32,
}

/// Int8 fake quantisation of a [rows, cols] weight by the quantizer's row rule, straight-through.
fn fake_quant_rows(w: &Var) -> candle_core::Result<Tensor> {
    let t = w.as_tensor();
    let (rows, cols) = t.dims2()?;
    let v = t.flatten_all()?.to_vec1::<f32>()?;
    let mut q = Vec::with_capacity(v.len());
    for row in v.chunks(cols.max(1)) {
        let (qi, s) = quantize_row(row);
        q.extend(qi.iter().map(|&x| x as f32 * s));
    }
    let q = Tensor::from_vec(q, (rows, cols), t.device())?;
    ste(t, &q)
}

impl QatNet {
    fn new(m: &FloatModel, cell_frac_bits: &[u8], dev: &Device) -> Result<Self> {
        let var = |v: &[f32], shape: &[usize]| -> Result<Var> {
            Ok(Var::from_tensor(&Tensor::from_slice(v, shape, dev)?)?)
        };
        let mut lstms = Vec::new();
        for (k, l) in m.lstms.iter().enumerate() {
            let (i, h) = (l.input, l.hidden);
            let c = *cell_frac_bits
                .get(k)
                .ok_or_else(|| LearnError::Training(format!("QAT: no cell format for LSTM {k}")))?;
            lstms.push(Lstm {
                w_ih: var(&l.w_ih, &[4 * h, i])?,
                w_hh: var(&l.w_hh, &[4 * h, h])?,
                b_ih: var(&l.b_ih, &[4 * h])?,
                b_hh: var(&l.b_hh, &[4 * h])?,
                input: i,
                hidden: h,
                cell_frac_bits: u32::from(c.clamp(1, 15)),
            });
        }
        Ok(Self {
            lstms,
            dense_w: var(&m.dense.w, &[2, m.dense.inputs])?,
            dense_b: var(&m.dense.b, &[2])?,
            sigmoid: activation_table(false, dev)?,
            tanh: activation_table(true, dev)?,
            cell_max: 0.0,
        })
    }

    fn vars(&self) -> Vec<Var> {
        let mut v = Vec::new();
        for l in &self.lstms {
            v.extend([
                l.w_ih.clone(),
                l.w_hh.clone(),
                l.b_ih.clone(),
                l.b_hh.clone(),
            ]);
        }
        v.extend([self.dense_w.clone(), self.dense_b.clone()]);
        v
    }

    /// f(z) with the forward value of the core's table at z rounded to Q3.12, the gradient of
    /// the exact f.
    fn act(&self, z: &Tensor, tanh: bool) -> candle_core::Result<Tensor> {
        let exact = if tanh {
            z.tanh()?
        } else {
            candle_nn::ops::sigmoid(z)?
        };
        let idx = z
            .detach()
            .affine(4096.0, 0.5)?
            .floor()?
            .clamp(-32768f32, 32767f32)?
            .affine(1.0, 32768.0)?
            .to_dtype(DType::U32)?;
        let table = if tanh { &self.tanh } else { &self.sigmoid };
        let q = table
            .index_select(&idx.flatten_all()?, 0)?
            .reshape(z.shape())?;
        ste(&exact, &q)
    }

    /// Hidden states [B, T, H] of one LSTM over inputs [B, T, I].
    /// Also returns Σ over steps of the mean over batch and units of relu(|c| − cell_max)²
    /// (0 without a bound).
    fn lstm(&self, l: &Lstm, x: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let (b, t, i) = x.dims3()?;
        let h_n = l.hidden;
        let w_ih = fake_quant_rows(&l.w_ih)?;
        let w_hh = fake_quant_rows(&l.w_hh)?.t()?;
        let bias = (l.b_ih.as_tensor() + l.b_hh.as_tensor())?;
        let bias = ste(&bias, &grid(&bias, 12)?)?;
        // All steps' input terms at once: [B·T, I] × [I, 4H] + b.
        let xw = x
            .reshape((b * t, i))?
            .matmul(&w_ih.t()?)?
            .broadcast_add(&bias)?
            .reshape((b, t, 4 * h_n))?;
        let cb = l.cell_frac_bits;
        let dev = x.device();
        let mut h = Tensor::zeros((b, h_n), DType::F32, dev)?;
        let mut c = Tensor::zeros((b, h_n), DType::F32, dev)?;
        let mut hs = Vec::with_capacity(t);
        let mut penalty = Tensor::zeros((), DType::F32, dev)?;
        for s in 0..t {
            let z = (xw.narrow(1, s, 1)?.squeeze(1)? + h.matmul(&w_hh)?)?;
            let g = z.chunk(4, 1)?;
            let (ig, fg, gg, og) = (
                self.act(&g[0], false)?,
                self.act(&g[1], false)?,
                self.act(&g[2], true)?,
                self.act(&g[3], false)?,
            );
            let fc = (&fg * &c)?;
            let ic = (&ig * &gg)?;
            // sat16(round(f·c) + round(i·g)) on the cell grid 2^-C.
            let cq = (grid(&fc, cb)? + grid(&ic, cb)?)?.clamp(
                -32768f32 / (1u32 << cb) as f32,
                32767f32 / (1u32 << cb) as f32,
            )?;
            c = ste(&(fc + ic)?, &cq)?;
            if self.cell_max > 0.0 {
                let over = (c.abs()? - self.cell_max as f64)?.relu()?;
                penalty = (penalty + over.sqr()?.mean_all()?)?;
            }
            // tanh of the cell in Q3.12 (saturated), then h = round(o·tanh(c')) in Q0.15.
            let hv = (&og * self.act(&c, true)?)?;
            h = ste(&hv, &grid(&hv, 15)?)?;
            hs.push(h.clone());
        }
        Ok((Tensor::stack(&hs, 1)?, penalty))
    }

    /// Logits [B, T, 2] of blob features [B, T, F], and the cell penalty (see [`Self::lstm`]).
    fn forward(&self, x: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let (hs, pen) = if self.lstms.len() == 1 {
            self.lstm(&self.lstms[0], x)?
        } else {
            let split = self.lstms[0].input;
            let nb = self.lstms[1].input;
            let xf = x.narrow(2, 0, split)?.contiguous()?;
            let xb = x.narrow(2, split, nb)?.contiguous()?;
            let (a, pa) = self.lstm(&self.lstms[0], &xf)?;
            let (b, pb) = self.lstm(&self.lstms[1], &xb)?;
            (Tensor::cat(&[a, b], 2)?, (pa + pb)?)
        };
        let w = fake_quant_rows(&self.dense_w)?;
        let logits = hs
            .broadcast_matmul(&w.t()?)?
            .broadcast_add(self.dense_b.as_tensor())?;
        Ok((logits, pen))
    }

    fn loss(&self, b: &Batch) -> candle_core::Result<Tensor> {
        let (logits, pen) = self.forward(&b.x)?;
        let logp = candle_nn::ops::log_softmax(&logits, D::Minus1)?;
        let picked = logp.gather(&b.y.unsqueeze(2)?, 2)?.squeeze(2)?;
        let ce = (picked * &b.w)?
            .sum_all()?
            .affine(-1.0 / b.wsum.max(1e-9), 0.0)?;
        let steps = b.x.dim(1)?.max(1) as f64;
        ce + pen.affine(1.0 / steps, 0.0)?
    }

    /// The trained weights back into a float model (normalisation and config from `base`).
    fn extract(&self, base: &FloatModel) -> Result<FloatModel> {
        let get =
            |v: &Var| -> Result<Vec<f32>> { Ok(v.as_tensor().flatten_all()?.to_vec1::<f32>()?) };
        let mut m = base.clone();
        for (l, q) in m.lstms.iter_mut().zip(&self.lstms) {
            l.w_ih = get(&q.w_ih)?;
            l.w_hh = get(&q.w_hh)?;
            l.b_ih = get(&q.b_ih)?;
            l.b_hh = get(&q.b_hh)?;
        }
        m.dense.w = get(&self.dense_w)?;
        m.dense.b = get(&self.dense_b)?;
        Ok(m)
    }
}

/// `model` with every weight replaced by the value the blob stores for it (int8 q times its
/// row's scale, [`quantize_row`]) and b_ih by Q3.12(b_ih + b_hh) − b_hh (the blob stores the sum
/// in Q3.12). Quantizing the result gives the same int8 weights and biases again.
pub fn snap_to_blob_grid(model: &FloatModel) -> FloatModel {
    fn rows(w: &mut [f32], cols: usize) {
        for row in w.chunks_mut(cols.max(1)) {
            let (q, s) = quantize_row(row);
            for (x, q) in row.iter_mut().zip(q) {
                *x = q as f32 * s;
            }
        }
    }
    let mut m = model.clone();
    for l in &mut m.lstms {
        let (i, h) = (l.input, l.hidden);
        rows(&mut l.w_ih, i);
        rows(&mut l.w_hh, h);
        for (bi, &bh) in l.b_ih.iter_mut().zip(&l.b_hh) {
            let sum = ((*bi + bh) as f64 * 4096.0).round() / 4096.0;
            *bi = (sum - bh as f64) as f32;
        }
    }
    let k = m.dense.inputs;
    rows(&mut m.dense.w, k);
    m
}

fn prepare(model: &FloatModel, seqs: &[&ChannelSequence], lead: usize) -> Prepared {
    Prepared::of(seqs, lead, |x| blob_features(model, x))
}

/// Per-step p(unstable) of `model` through the QAT forward pass (what the fine-tuning sees;
/// the blob's arithmetic simulated in f32) over one raw sequence from a reset state.
pub fn fake_quant_probabilities(
    model: &FloatModel,
    cell_frac_bits: &[u8],
    samples: &[f32],
) -> Result<Vec<f32>> {
    let dev = Device::Cpu;
    let net = QatNet::new(model, cell_frac_bits, &dev)?;
    let f = blob_features(model, samples);
    let nf = model.config.feature_count();
    let flat: Vec<f32> = f.into_iter().flatten().collect();
    let x = Tensor::from_vec(flat, (1, samples.len(), nf), &dev)?;
    let (logits, _) = net.forward(&x)?;
    let p = candle_nn::ops::softmax(&logits, D::Minus1)?
        .narrow(2, 1, 1)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    Ok(p)
}

/// Fine-tunes `init` with the blob's arithmetic in the forward pass ([`QatConfig`]), early
/// stopping on the validation loss of that forward pass; epoch 0 (the weights as given, under
/// fake quantisation) counts, so the result is never worse on validation than the input; with
/// agreement recordings the pick is among the epochs whose blob follows their float checkpoint
/// ([`QatConfig::agreement`]). The returned model is snapped to the blob's grid
/// ([`snap_to_blob_grid`]).
pub fn qat_finetune(
    init: &FloatModel,
    train: &[&ChannelSequence],
    val: &[&ChannelSequence],
    cfg: &TrainConfig,
    qat: &QatConfig,
    mut progress: impl FnMut(Progress<'_>),
) -> Result<QatOutcome> {
    if train.is_empty() {
        return Err(LearnError::Training("no training sequences".into()));
    }
    init.validate()?;
    let dev = Device::Cpu;
    let mut net = QatNet::new(init, &qat.cell_frac_bits, &dev)?;
    net.cell_max = qat.cell_max;
    let nf = init.config.feature_count();
    let ptrain = prepare(init, train, cfg.label_lead);
    let pval = prepare(init, val, cfg.label_lead);
    let params = candle_nn::ParamsAdamW {
        lr: qat.lr,
        beta1: 0.9,
        beta2: 0.999,
        eps: 1e-8,
        weight_decay: 0.0,
    };
    let mut opt = candle_nn::AdamW::new(net.vars(), params)?;
    use candle_nn::Optimizer;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x0a7f_1e55);
    let val_batches: Vec<Batch> = (0..val.len())
        .collect::<Vec<_>>()
        .chunks(cfg.batch.max(1))
        .map(|c| make_batch(&pval, c, nf, cfg, &dev))
        .collect::<Result<_>>()?;
    // (validation loss, epoch, model, max |Δp| on the agreement recordings).
    type Pick = (f64, usize, FloatModel, f32);
    let agree = |m: &FloatModel| -> Result<f32> {
        if qat.agreement.is_empty() {
            Ok(0.0)
        } else {
            max_dp_blob_vs_float(m, &qat.cell_frac_bits, &qat.agreement)
        }
    };
    let m0 = snap_to_blob_grid(init);
    let v0 = if val_batches.is_empty() {
        f64::INFINITY
    } else {
        mean_loss(&val_batches, |b| net.loss(b))?
    };
    let d0 = agree(&m0)?;
    // The best epoch within the bound, and the one closest to the bound.
    let mut best: Option<Pick> = (d0 <= qat.max_dp).then(|| (v0, 0, m0.clone(), d0));
    let mut closest: Pick = (v0, 0, m0, d0);
    let mut agreement_log = vec![d0];
    let mut history = Vec::new();
    let mut order: Vec<usize> = (0..train.len()).collect();
    for epoch in 1..=qat.epochs {
        let log = train_epoch(
            epoch,
            &mut order,
            &mut rng,
            &ptrain,
            &val_batches,
            (nf, cfg, &dev),
            &mut opt,
            |b| net.loss(b),
            &mut progress,
        )?;
        let val_loss = log.val_loss;
        history.push(log);
        let m = snap_to_blob_grid(&net.extract(init)?);
        let d = agree(&m)?;
        agreement_log.push(d);
        let better = |b: &Option<Pick>| match b {
            None => true,
            Some(b) => val_loss < b.0 || val_batches.is_empty(),
        };
        if d <= qat.max_dp && better(&best) {
            best = Some((val_loss, epoch, m.clone(), d));
        }
        if d < closest.3 {
            closest = (val_loss, epoch, m, d);
        }
        let last_good = best.as_ref().map_or(closest.1, |b| b.1);
        if epoch - last_good >= cfg.patience {
            break;
        }
    }
    let best = best.unwrap_or(closest);
    Ok(QatOutcome {
        trained: TrainOutcome {
            model: best.2,
            history,
            best_epoch: best.1,
        },
        agreement: agreement_log,
    })
}

/// What [`qat_finetune`] returns.
#[derive(Debug, Clone)]
pub struct QatOutcome {
    /// The kept epoch's model (snapped), the epochs' log and the kept epoch (0 = the input).
    pub trained: TrainOutcome,
    /// max |Δp| of each epoch's blob against its float checkpoint on
    /// [`QatConfig::agreement`] (epoch 0 first; zeros without agreement recordings).
    pub agreement: Vec<f32>,
}

/// max |Δp| over some raw sequences of the blob [`crate::evaluation::quantize_model`] makes of
/// `model` (calibrated on `calib`), run through the bit-exact core, against the float model and
/// against the QAT forward pass (with the blob's cell formats).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Agreement {
    /// Blob against the float model.
    pub float: f32,
    /// Blob against [`fake_quant_probabilities`].
    pub fake_quant: f32,
}

/// Measures [`Agreement`] (fresh state per sequence).
pub fn blob_agreement(model: &FloatModel, calib: &[&[f32]], seqs: &[&[f32]]) -> Result<Agreement> {
    let (blob, rep) = slipguard_core::quantize::quantize(model, calib, None)?;
    let aligned = slipguard_core::blob::AlignedBlob::new(&blob);
    let q = slipguard_core::model::Model::from_bytes(aligned.as_bytes())
        .map_err(|e| LearnError::Training(format!("the quantized model does not parse: {e}")))?;
    let mut a = Agreement {
        float: 0.0,
        fake_quant: 0.0,
    };
    for s in seqs {
        let pq = crate::evaluation::quant_p_q15(&q, s);
        let pf = crate::train::float_probabilities(model, s);
        let pk = fake_quant_probabilities(model, &rep.cell_frac_bits, s)?;
        for ((&q, f), k) in pq.iter().zip(pf).zip(pk) {
            let q = q as f32 / 32768.0;
            a.float = a.float.max((q - f).abs());
            a.fake_quant = a.fake_quant.max((q - k).abs());
        }
    }
    Ok(a)
}
