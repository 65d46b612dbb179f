//! Training of the paper's four LSTM variants with candle (CPU).
//!
//! * Data: single-channel sequences from grasp start (contact channels only, see
//!   [`slipguard_data::labels::channel_sequences`]). Features come from the core's float reference
//!   ([`slipguard_core::float::raw_feature_sequence`]) and are normalised with the model's
//!   μ/σ and ±8σ clamp ([`FloatModel::normalise`]), exactly as the firmware computes them.
//! * Network: `candle_nn::rnn::LSTM` (PyTorch's equations and gate order i, f, g, o) and a
//!   2-way `Linear` at every step; the dual variant runs a force LSTM and a band LSTM and
//!   concatenates their hidden states. Tensor names are PyTorch's (`lstm.weight_ih_l0`, …,
//!   `dense.weight`; dual: `lstm_force.*`, `lstm_bands.*`).
//! * Loss: 2-class cross-entropy at every step, optional class weights (PyTorch's weighted
//!   mean: Σ wᵧ·nll / Σ wᵧ). Optimiser: Adam (candle's AdamW with weight decay 0, eps 1e-8).
//! * Fixed seeds: weights start from [`FloatModel::init_like_pytorch`] with the seed, batches
//!   are shuffled by a ChaCha8 stream of the same seed. With `RAYON_NUM_THREADS=1` a run is
//!   bit-for-bit repeatable.
//! * Early stopping on the validation loss (validation trials are split by trial, never by
//!   channel), keeping the best epoch's weights.

use std::time::Instant;

use candle_core::{D, DType, Device, Tensor};
use candle_nn::rnn::{LSTM, LSTMConfig, RNN};
use candle_nn::{AdamW, Linear, Module, Optimizer, ParamsAdamW, VarBuilder, VarMap};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use slipguard_core::blob::ModelConfig;
use slipguard_core::float::{FloatModel, raw_feature_sequence};

use crate::error::{LearnError, Result};
use slipguard_data::labels::ChannelSequence;
use slipguard_data::trial::{Outcome, Stability};

/// Hyper-parameters of one training run (paper defaults in [`Default`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TrainConfig {
    /// Adam learning rate (paper: 6e-4).
    pub lr: f64,
    /// Most epochs.
    pub epochs: usize,
    /// Sequences per batch.
    pub batch: usize,
    /// Stop after this many epochs without a better validation loss.
    pub patience: usize,
    /// Seed of the initial weights and of the batch order.
    pub seed: u64,
    /// Loss weight of the stable and of the unstable class.
    pub class_weights: [f32; 2],
    /// Training labels: unstable from this many steps before the drop (paper: 20). Evaluation
    /// always uses the paper's labels; this is the "label shift".
    pub label_lead: usize,
    /// Loss weight multiplier of the first [`Self::start_steps`] steps of every sequence (1 = none).
    /// The LSTM starts from a zero state on a near-zero force, which looks like the time after a
    /// drop; weighting the start teaches it not to raise start-up alarms.
    pub start_weight: f32,
    /// Steps from grasp start that get [`Self::start_weight`].
    pub start_steps: usize,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            lr: 6e-4,
            epochs: 60,
            batch: 32,
            patience: 10,
            seed: 1,
            class_weights: [1.0, 1.0],
            label_lead: 20,
            start_weight: 1.0,
            start_steps: 0,
        }
    }
}

/// One epoch's numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochLog {
    pub epoch: usize,
    pub train_loss: f64,
    /// Validation loss (the training loss if there is no validation set).
    pub val_loss: f64,
    pub seconds: f64,
}

/// What [`train`] reports as it goes: after every batch, and after every epoch.
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// One optimiser step done.
    Batch {
        /// Epoch (1-based).
        epoch: usize,
        /// Batches done in this epoch.
        batch: usize,
        /// Batches per epoch.
        batches: usize,
        /// The epoch's running training loss (weighted mean over its batches so far).
        train_loss: f64,
    },
    /// An epoch done, with its validation loss.
    Epoch(&'a EpochLog),
}

/// What [`train`] returns.
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    /// The weights of the best epoch.
    pub model: FloatModel,
    pub history: Vec<EpochLog>,
    /// 1-based epoch whose weights were kept (0 = the initial weights).
    pub best_epoch: usize,
}

/// Training labels (0 stable, 1 unstable) of a sequence with the unstable region starting
/// `lead` steps before the drop (the sequence's own labels if it has no drop inside).
pub fn train_labels(s: &ChannelSequence, lead: usize) -> Vec<u32> {
    match (s.outcome, s.drop_index) {
        (Outcome::Failure, Some(d)) => (0..s.samples.len())
            .map(|t| u32::from(t + lead >= d))
            .collect(),
        _ => s.labels.iter().map(|l| l.code() as u32).collect(),
    }
}

/// Normalised features of one sequence, one row per step.
pub fn features(model: &FloatModel, samples: &[f32]) -> Vec<Vec<f32>> {
    let mut v = raw_feature_sequence(&model.config, samples);
    for row in &mut v {
        model.normalise(row);
    }
    v
}

/// Features and training labels of a set of sequences.
pub(crate) struct Prepared {
    pub(crate) feats: Vec<Vec<Vec<f32>>>,
    pub(crate) labels: Vec<Vec<u32>>,
}

fn prepare(model: &FloatModel, seqs: &[&ChannelSequence], lead: usize) -> Prepared {
    Prepared::of(seqs, lead, |x| features(model, x))
}

impl Prepared {
    /// The features (`feats` of a raw sequence) and training labels of `seqs`.
    pub(crate) fn of(
        seqs: &[&ChannelSequence],
        lead: usize,
        feats: impl Fn(&[f32]) -> Vec<Vec<f32>>,
    ) -> Self {
        Prepared {
            feats: seqs.iter().map(|s| feats(&s.samples)).collect(),
            labels: seqs.iter().map(|s| train_labels(s, lead)).collect(),
        }
    }
}

/// Weighted mean of `loss` over `batches` (NaN without batches).
pub(crate) fn mean_loss(
    batches: &[Batch],
    loss: impl Fn(&Batch) -> candle_core::Result<Tensor>,
) -> Result<f64> {
    let (mut s, mut n) = (0f64, 0f64);
    for b in batches {
        let l = loss(b).and_then(|t| t.to_scalar::<f32>())?;
        s += l as f64 * b.wsum;
        n += b.wsum;
    }
    Ok(if n > 0.0 { s / n } else { f64::NAN })
}

/// One epoch of either trainer (float or quantization-aware): shuffles `order`, takes an
/// optimiser step per batch of `train` on `loss`, reports progress per batch and the epoch's
/// log (training loss, and the validation loss on `val`, or the training loss without it).
/// A non-finite training loss is an error.
#[allow(clippy::too_many_arguments)]
pub(crate) fn train_epoch(
    epoch: usize,
    order: &mut [usize],
    rng: &mut rand_chacha::ChaCha8Rng,
    train: &Prepared,
    val: &[Batch],
    (nf, cfg, dev): (usize, &TrainConfig, &Device),
    opt: &mut impl Optimizer,
    loss: impl Fn(&Batch) -> candle_core::Result<Tensor>,
    progress: &mut impl FnMut(Progress<'_>),
) -> Result<EpochLog> {
    let t0 = Instant::now();
    order.shuffle(rng);
    let (mut s, mut n) = (0f64, 0f64);
    let batches = order.len().div_ceil(cfg.batch.max(1));
    for (k, chunk) in order.chunks(cfg.batch.max(1)).enumerate() {
        let b = make_batch(train, chunk, nf, cfg, dev)?;
        let l = loss(&b)?;
        opt.backward_step(&l)?;
        s += l.to_scalar::<f32>()? as f64 * b.wsum;
        n += b.wsum;
        progress(Progress::Batch {
            epoch,
            batch: k + 1,
            batches,
            train_loss: s / n.max(1e-9),
        });
    }
    let train_loss = s / n.max(1e-9);
    let val_loss = if val.is_empty() {
        train_loss
    } else {
        mean_loss(val, &loss)?
    };
    let log = EpochLog {
        epoch,
        train_loss,
        val_loss,
        seconds: t0.elapsed().as_secs_f64(),
    };
    progress(Progress::Epoch(&log));
    if !train_loss.is_finite() {
        return Err(LearnError::Training(format!(
            "training diverged at epoch {epoch}"
        )));
    }
    Ok(log)
}

/// The candle network.
struct Net {
    lstms: Vec<LSTM>,
    dense: Linear,
    split: usize,
    n_features: usize,
}

pub use crate::checkpoint::lstm_prefixes;

impl Net {
    fn new(init: &FloatModel, varmap: &mut VarMap, dev: &Device) -> Result<Self> {
        let vb = VarBuilder::from_varmap(varmap, DType::F32, dev);
        let prefixes = lstm_prefixes(init.config.variant);
        let mut lstms = Vec::new();
        for (l, p) in init.lstms.iter().zip(prefixes) {
            lstms.push(candle_nn::rnn::lstm(
                l.input,
                l.hidden,
                LSTMConfig::default(),
                vb.pp(*p),
            )?);
        }
        let dense = candle_nn::linear(init.dense.inputs, 2, vb.pp("dense"))?;
        // Overwrite candle's initialisation with the seeded PyTorch-like one (or a checkpoint).
        for (l, p) in init.lstms.iter().zip(prefixes) {
            let (i, h) = (l.input, l.hidden);
            let set = |vm: &mut VarMap, n: &str, v: &[f32], shape: &[usize]| {
                let t = Tensor::from_slice(v, shape, dev)?;
                vm.set_one(format!("{p}.{n}"), t)
            };
            set(varmap, "weight_ih_l0", &l.w_ih, &[4 * h, i])?;
            set(varmap, "weight_hh_l0", &l.w_hh, &[4 * h, h])?;
            set(varmap, "bias_ih_l0", &l.b_ih, &[4 * h])?;
            set(varmap, "bias_hh_l0", &l.b_hh, &[4 * h])?;
        }
        let k = init.dense.inputs;
        varmap.set_one(
            "dense.weight",
            Tensor::from_slice(&init.dense.w, (2, k), dev)?,
        )?;
        varmap.set_one("dense.bias", Tensor::from_slice(&init.dense.b, 2, dev)?)?;
        Ok(Self {
            lstms,
            dense,
            split: init.config.lstm_inputs(0),
            n_features: init.config.feature_count(),
        })
    }

    /// Logits [B, T, 2] of features [B, T, F].
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let hs = if self.lstms.len() == 1 {
            let st = self.lstms[0].seq(x)?;
            self.lstms[0].states_to_tensor(&st)?
        } else {
            let xf = x.narrow(2, 0, self.split)?.contiguous()?;
            let xb = x
                .narrow(2, self.split, self.n_features - self.split)?
                .contiguous()?;
            let a = self.lstms[0].seq(&xf)?;
            let b = self.lstms[1].seq(&xb)?;
            Tensor::cat(
                &[
                    self.lstms[0].states_to_tensor(&a)?,
                    self.lstms[1].states_to_tensor(&b)?,
                ],
                2,
            )?
        };
        self.dense.forward(&hs)
    }
}

/// Reads the trained tensors back into a float model (normalisation and config from `base`).
fn extract(base: &FloatModel, varmap: &VarMap) -> Result<FloatModel> {
    let data = varmap.data().lock().expect("varmap lock");
    let get = |n: &str| -> Result<Vec<f32>> {
        let v = data
            .get(n)
            .ok_or_else(|| LearnError::Training(format!("missing variable {n}")))?;
        v.as_tensor()
            .flatten_all()
            .and_then(|t| t.to_vec1::<f32>())
            .map_err(LearnError::from)
    };
    let mut m = base.clone();
    for (l, p) in m.lstms.iter_mut().zip(lstm_prefixes(base.config.variant)) {
        l.w_ih = get(&format!("{p}.weight_ih_l0"))?;
        l.w_hh = get(&format!("{p}.weight_hh_l0"))?;
        l.b_ih = get(&format!("{p}.bias_ih_l0"))?;
        l.b_hh = get(&format!("{p}.bias_hh_l0"))?;
    }
    m.dense.w = get("dense.weight")?;
    m.dense.b = get("dense.bias")?;
    Ok(m)
}

/// One batch: features [B, T, F], labels and loss weights [B, T] (0 past a sequence's end).
pub(crate) struct Batch {
    pub(crate) x: Tensor,
    pub(crate) y: Tensor,
    pub(crate) w: Tensor,
    pub(crate) wsum: f64,
}

pub(crate) fn make_batch(
    p: &Prepared,
    idx: &[usize],
    nf: usize,
    cfg: &TrainConfig,
    dev: &Device,
) -> Result<Batch> {
    let cw = cfg.class_weights;
    let t_max = idx.iter().map(|&i| p.feats[i].len()).max().unwrap_or(0);
    let b = idx.len();
    let mut x = vec![0f32; b * t_max * nf];
    let mut y = vec![0u32; b * t_max];
    let mut w = vec![0f32; b * t_max];
    for (bi, &i) in idx.iter().enumerate() {
        for (t, row) in p.feats[i].iter().enumerate() {
            let o = (bi * t_max + t) * nf;
            x[o..o + nf].copy_from_slice(row);
            let lab = p.labels[i][t];
            y[bi * t_max + t] = lab;
            let start = if t < cfg.start_steps {
                cfg.start_weight
            } else {
                1.0
            };
            w[bi * t_max + t] = cw[lab as usize] * start;
        }
    }
    let wsum: f64 = w.iter().map(|&v| v as f64).sum();
    Ok(Batch {
        x: Tensor::from_vec(x, (b, t_max, nf), dev)?,
        y: Tensor::from_vec(y, (b, t_max), dev)?,
        w: Tensor::from_vec(w, (b, t_max), dev)?,
        wsum,
    })
}

fn batch_loss(net: &Net, b: &Batch) -> candle_core::Result<Tensor> {
    let logits = net.forward(&b.x)?;
    let logp = candle_nn::ops::log_softmax(&logits, D::Minus1)?;
    let picked = logp.gather(&b.y.unsqueeze(2)?, 2)?.squeeze(2)?;
    (picked * &b.w)?
        .sum_all()?
        .affine(-1.0 / b.wsum.max(1e-9), 0.0)
}

/// A fresh model for `config` (PyTorch-like init with `seed`) with normalisation fitted on
/// `seqs`.
pub fn init_model(config: ModelConfig, seed: u64, seqs: &[&ChannelSequence]) -> FloatModel {
    let mut m = FloatModel::init_like_pytorch(config, seed);
    let samples: Vec<&[f32]> = seqs.iter().map(|s| s.samples.as_slice()).collect();
    m.fit_normalisation(&samples);
    m
}

/// Trains `init` (weights and normalisation as given) on `train`, early-stopping on `val`.
/// `progress` sees every batch and every epoch.
pub fn train(
    init: &FloatModel,
    train: &[&ChannelSequence],
    val: &[&ChannelSequence],
    cfg: &TrainConfig,
    progress: impl FnMut(Progress<'_>),
) -> Result<TrainOutcome> {
    if train.is_empty() {
        return Err(LearnError::Training("no training sequences".into()));
    }
    init.validate()?;
    let ptrain = prepare(init, train, cfg.label_lead);
    let pval = prepare(init, val, cfg.label_lead);
    train_prepared(init, &ptrain, &pval, cfg, progress)
}

/// [`train`] on sequences already turned into normalised features and training labels (the
/// hand-level model's rows, [`crate::hand`]).
pub(crate) fn train_prepared(
    init: &FloatModel,
    ptrain: &Prepared,
    pval: &Prepared,
    cfg: &TrainConfig,
    mut progress: impl FnMut(Progress<'_>),
) -> Result<TrainOutcome> {
    if ptrain.feats.is_empty() {
        return Err(LearnError::Training("no training sequences".into()));
    }
    init.validate()?;
    let dev = Device::Cpu;
    let mut varmap = VarMap::new();
    let net = Net::new(init, &mut varmap, &dev)?;
    let nf = init.config.feature_count();
    let params = ParamsAdamW {
        lr: cfg.lr,
        beta1: 0.9,
        beta2: 0.999,
        eps: 1e-8,
        weight_decay: 0.0,
    };
    let mut opt = AdamW::new(varmap.all_vars(), params)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5eed_7a1e);
    let val_batches: Vec<Batch> = (0..pval.feats.len())
        .collect::<Vec<_>>()
        .chunks(cfg.batch.max(1))
        .map(|c| make_batch(pval, c, nf, cfg, &dev))
        .collect::<Result<_>>()?;
    let mut best = (f64::INFINITY, 0usize, init.clone());
    if !val_batches.is_empty() {
        best.0 = mean_loss(&val_batches, |b| batch_loss(&net, b))?;
    }
    let mut history = Vec::new();
    let mut order: Vec<usize> = (0..ptrain.feats.len()).collect();
    for epoch in 1..=cfg.epochs {
        let log = train_epoch(
            epoch,
            &mut order,
            &mut rng,
            ptrain,
            &val_batches,
            (nf, cfg, &dev),
            &mut opt,
            |b| batch_loss(&net, b),
            &mut progress,
        )?;
        let val_loss = log.val_loss;
        history.push(log);
        if val_loss < best.0 {
            best = (val_loss, epoch, extract(init, &varmap)?);
        } else if epoch - best.1 >= cfg.patience {
            break;
        }
    }
    Ok(TrainOutcome {
        model: best.2,
        history,
        best_epoch: best.1,
    })
}

/// Per-step p(unstable) of the float model over one sequence (fresh state).
pub fn float_probabilities(model: &FloatModel, samples: &[f32]) -> Vec<f32> {
    let mut st = model.new_channel();
    samples
        .iter()
        .map(|&x| model.step(&mut st, x).p_unstable)
        .collect()
}

/// Splits sequences into (train, validation) by trial: about `share` of the failure trials
/// and of the success trials (at least one failure if there are two or more) go to
/// validation, picked by a seeded shuffle.
pub fn split_by_trial<'a>(
    seqs: &[&'a ChannelSequence],
    share: f64,
    seed: u64,
) -> (Vec<&'a ChannelSequence>, Vec<&'a ChannelSequence>) {
    let mut fail: Vec<&str> = Vec::new();
    let mut succ: Vec<&str> = Vec::new();
    for s in seqs {
        let v = if s.outcome == Outcome::Failure {
            &mut fail
        } else {
            &mut succ
        };
        if !v.contains(&s.trial_id.as_str()) {
            v.push(&s.trial_id);
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x0a11_da7a);
    fail.sort();
    succ.sort();
    fail.shuffle(&mut rng);
    succ.shuffle(&mut rng);
    let take = |v: &[&str], min1: bool| {
        let mut k = (v.len() as f64 * share).round() as usize;
        if min1 && v.len() >= 2 {
            k = k.max(1);
        }
        v[..k.min(v.len())]
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
    };
    let mut val_ids = take(&fail, true);
    val_ids.extend(take(&succ, share > 0.0));
    seqs.iter()
        .partition(|s| !val_ids.iter().any(|v| v == &s.trial_id))
}

/// Labels of a stable/unstable flag sequence as [`Stability`].
pub fn flags_to_stability(flags: impl IntoIterator<Item = bool>) -> Vec<Stability> {
    flags
        .into_iter()
        .map(|u| {
            if u {
                Stability::Unstable
            } else {
                Stability::Stable
            }
        })
        .collect()
}
