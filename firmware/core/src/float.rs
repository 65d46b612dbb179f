//! The f32 reference of exactly the network the quantized core runs (host only, `std`).
//!
//! Same stages, same clamps, no quantization: input scaling clamped to [-1, 1), d(t) clamped to
//! [-1, 1), STFT magnitudes by an f64 DFT over the same zero-started window, normalisation
//! clamped to ±8σ, LSTM with PyTorch's equations and gate order (i, f, g, o), dense layer, and
//! p(unstable) = softmax(logits)[1]. Tensors use PyTorch's layouts (`weight_ih_l0` is 4H × I,
//! row-major), so PyTorch checkpoints load without reordering.
//! The trainer computes its features here, so training and firmware see the same STFT.

use std::collections::VecDeque;

use crate::blob::ModelConfig;
use crate::decision::{DecisionConfig, DecisionState};
use crate::features::stft::WindowShape;
use crate::sample::InputScale;

/// Why float weights do not form a model the core can run.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum FloatModelError {
    /// A tensor has the wrong number of elements.
    Shape {
        /// Tensor name (PyTorch's).
        tensor: String,
        /// Elements expected.
        expected: usize,
        /// Elements found.
        found: usize,
    },
    /// A weight is NaN or infinite.
    NotFinite {
        /// Tensor name.
        tensor: String,
        /// Flat index of the first bad value.
        index: usize,
    },
    /// The number of LSTMs, sizes or normalisation do not match the variant.
    Structure(String),
}

impl std::fmt::Display for FloatModelError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Shape {
                tensor,
                expected,
                found,
            } => {
                write!(
                    f,
                    "tensor `{tensor}` has {found} elements, expected {expected}"
                )
            }
            Self::NotFinite { tensor, index } => write!(
                f,
                "tensor `{tensor}` has a NaN or infinite value at index {index}"
            ),
            Self::Structure(s) => write!(f, "{s}"),
        }
    }
}

impl std::error::Error for FloatModelError {}

/// One LSTM layer in PyTorch's layout and gate order (i, f, g, o).
#[derive(Clone, Debug, PartialEq)]
pub struct FloatLstm {
    /// Input size I.
    pub input: usize,
    /// Hidden size H.
    pub hidden: usize,
    /// `weight_ih_l0`, 4H × I row-major.
    pub w_ih: Vec<f32>,
    /// `weight_hh_l0`, 4H × H row-major.
    pub w_hh: Vec<f32>,
    /// `bias_ih_l0`, 4H.
    pub b_ih: Vec<f32>,
    /// `bias_hh_l0`, 4H.
    pub b_hh: Vec<f32>,
}

/// h and c of one float LSTM.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatLstmState {
    /// Hidden state.
    pub h: Vec<f32>,
    /// Cell state.
    pub c: Vec<f32>,
}

fn check(name: &str, v: &[f32], expected: usize) -> Result<(), FloatModelError> {
    if v.len() != expected {
        return Err(FloatModelError::Shape {
            tensor: name.into(),
            expected,
            found: v.len(),
        });
    }
    if let Some(index) = v.iter().position(|x| !x.is_finite()) {
        return Err(FloatModelError::NotFinite {
            tensor: name.into(),
            index,
        });
    }
    Ok(())
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl FloatLstm {
    /// Checks shapes and finiteness.
    pub fn validate(&self) -> Result<(), FloatModelError> {
        let (i, h) = (self.input, self.hidden);
        check("weight_ih_l0", &self.w_ih, 4 * h * i)?;
        check("weight_hh_l0", &self.w_hh, 4 * h * h)?;
        check("bias_ih_l0", &self.b_ih, 4 * h)?;
        check("bias_hh_l0", &self.b_hh, 4 * h)
    }

    /// Zero state.
    pub fn zero_state(&self) -> FloatLstmState {
        FloatLstmState {
            h: vec![0.0; self.hidden],
            c: vec![0.0; self.hidden],
        }
    }

    /// One step: PyTorch's `nn.LSTM` equations.
    pub fn step(&self, s: &mut FloatLstmState, x: &[f32]) {
        let (ni, nh) = (self.input, self.hidden);
        let mut z = vec![0f32; 4 * nh];
        for (r, zr) in z.iter_mut().enumerate() {
            let wi = &self.w_ih[r * ni..(r + 1) * ni];
            let wh = &self.w_hh[r * nh..(r + 1) * nh];
            let mut acc = self.b_ih[r] + self.b_hh[r];
            acc += wi.iter().zip(x).map(|(w, v)| w * v).sum::<f32>();
            acc += wh.iter().zip(&s.h).map(|(w, v)| w * v).sum::<f32>();
            *zr = acc;
        }
        for j in 0..nh {
            let i = sigmoid(z[j]);
            let f = sigmoid(z[nh + j]);
            let g = z[2 * nh + j].tanh();
            let o = sigmoid(z[3 * nh + j]);
            s.c[j] = f * s.c[j] + i * g;
            s.h[j] = o * s.c[j].tanh();
        }
    }
}

/// Dense layer to the two logits (class 0 stable, class 1 unstable), PyTorch `nn.Linear` layout.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatDense {
    /// Input size K (sum of the hidden sizes).
    pub inputs: usize,
    /// `weight`, 2 × K row-major.
    pub w: Vec<f32>,
    /// `bias`, 2.
    pub b: Vec<f32>,
}

impl FloatDense {
    /// Checks shapes and finiteness.
    pub fn validate(&self) -> Result<(), FloatModelError> {
        check("weight", &self.w, 2 * self.inputs)?;
        check("bias", &self.b, 2)
    }
    /// Logits for the concatenated hidden state.
    pub fn logits(&self, h: &[f32]) -> [f32; 2] {
        let k = self.inputs;
        let mut out = [0f32; 2];
        for (r, o) in out.iter_mut().enumerate() {
            *o = self.b[r]
                + self.w[r * k..(r + 1) * k]
                    .iter()
                    .zip(h)
                    .map(|(w, v)| w * v)
                    .sum::<f32>();
        }
        out
    }
}

/// The model id the exporter and the trainer give a blob when none is set: CRC-32 of the
/// weights' f32 bytes (LSTMs in order, each W_ih, W_hh, b_ih, b_hh, then the dense layer).
pub fn weights_id(lstms: &[FloatLstm], dense: &FloatDense) -> u32 {
    let mut d = crate::blob::CRC32.digest();
    for l in lstms {
        for v in [&l.w_ih, &l.w_hh, &l.b_ih, &l.b_hh] {
            for x in v.iter() {
                d.update(&x.to_le_bytes());
            }
        }
    }
    for x in dense.w.iter().chain(&dense.b) {
        d.update(&x.to_le_bytes());
    }
    d.finalize()
}

/// p(class 1) = softmax(logits)[1].
pub fn p_from_logits(l: [f32; 2]) -> f32 {
    sigmoid(l[1] - l[0])
}

/// A float model of one of the four variants.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatModel {
    /// Header fields (`hidden` must match `lstms`; `cell_frac_bits` is set by the quantizer).
    pub config: ModelConfig,
    /// μ of each raw feature (Q1.15 units as reals: force in [-1, 1)), feature order [force, d(t), bands].
    pub norm_mean: Vec<f32>,
    /// σ of each raw feature, > 0.
    pub norm_std: Vec<f32>,
    /// One LSTM, or two for the dual variant (force path first).
    pub lstms: Vec<FloatLstm>,
    /// The dense layer over the concatenated hidden states.
    pub dense: FloatDense,
}

/// Per-channel state of the float model.
#[derive(Clone, Debug)]
pub struct FloatChannelState {
    window: VecDeque<f32>,
    prev: f32,
    /// LSTM states.
    pub lstm: Vec<FloatLstmState>,
    /// Flag hysteresis.
    pub decision: DecisionState,
}

/// One step of the float model.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatStep {
    /// Logits (stable, unstable).
    pub logits: [f32; 2],
    /// p(unstable).
    pub p_unstable: f32,
    /// Flag after threshold and hysteresis (threshold applied to p in Q0.15 terms).
    pub unstable: bool,
}

/// Raw features of a whole sequence (one channel), without normalisation, as the trainer
/// needs them for its statistics: one `Vec` per step in feature order [force, d(t), bands].
pub fn raw_feature_sequence(config: &ModelConfig, samples: &[f32]) -> Vec<Vec<f32>> {
    let mut st = FeatureWindow::new(config);
    samples.iter().map(|&raw| st.push(config, raw)).collect()
}

/// A hand-level model's raw hand feature rows over a whole recording, as the firmware
/// computes them ([`crate::model::Model::hand_feature_row`]): every channel through the
/// model's default contact gate ([`crate::decision::ContactConfig::of`]) from `start` (the
/// grasp start, where the firmware resets), the lift command at step `lift`, samples rounded
/// to whole sensor units as the front end delivers them. One row per step from `start` to the
/// end, each feature's `i16` as value / 2^15 (how the float model and the normalisation read
/// it). `samples` is channel-major; empty for a per-channel variant.
pub fn hand_feature_rows(
    config: &ModelConfig,
    samples: &[Vec<f32>],
    start: usize,
    lift: Option<usize>,
) -> Vec<Vec<f32>> {
    use crate::decision::{ContactConfig, ContactState};
    use crate::features::hand::{HAND_FEATURES, HandFeatureState, hand_features};
    use crate::features::stft::StftPlan;
    let (Some(cfg), Ok(plan)) = (
        crate::model::hand_feature_config(config),
        StftPlan::new(config.stft),
    ) else {
        return Vec::new();
    };
    let contact = ContactConfig::of(config);
    let scale = InputScale::of(config);
    let n = samples.first().map_or(0, Vec::len);
    let mut gates = vec![ContactState::new(); samples.len()];
    let mut st = HandFeatureState::new();
    let mut x = vec![None; samples.len()];
    (start.min(n)..n)
        .map(|t| {
            for ((xc, g), ch) in x.iter_mut().zip(&mut gates).zip(samples) {
                let v = scale.to_q15(ch[t].round() as i32);
                *xc = contact.update(g, v).in_contact().then_some(v);
            }
            let mut out = [0i16; HAND_FEATURES];
            hand_features(
                &cfg,
                &plan,
                &mut st,
                &x,
                lift.is_some_and(|l| t >= l),
                &mut out,
            );
            out.iter().map(|&v| v as f32 / 32768.0).collect()
        })
        .collect()
}

/// The float feature path's state: window of inputs and previous input.
#[derive(Clone, Debug)]
struct FeatureWindow {
    window: VecDeque<f32>,
    prev: f32,
}

impl FeatureWindow {
    fn new(config: &ModelConfig) -> Self {
        let n = config.stft.window_len as usize;
        Self {
            window: VecDeque::from(vec![0.0; n]),
            prev: 0.0,
        }
    }

    fn push(&mut self, config: &ModelConfig, raw: f32) -> Vec<f32> {
        if config.variant.is_hand() {
            // A hand-level model has no per-channel features (its rows come from every channel
            // together, [`hand_feature_rows`]): a zero row of the right length.
            return vec![0.0; config.feature_count()];
        }
        let x = InputScale::of(config).to_real(raw);
        let mut out = Vec::with_capacity(config.feature_count());
        if config.variant.uses_force() {
            out.push(x);
        }
        if config.force_diff {
            out.push((x - self.prev).clamp(-1.0, 32767.0 / 32768.0));
        }
        self.prev = x;
        if config.variant.uses_bands() {
            self.window.pop_front();
            self.window.push_back(x);
            out.extend(stft_magnitudes(config, &self.window));
        }
        out
    }
}

/// Window coefficient n of N (periodic Hann, as the fixed-point STFT).
pub fn window_coefficient(shape: WindowShape, n: usize, len: usize) -> f64 {
    match shape {
        WindowShape::Rectangular => 1.0,
        WindowShape::Hann => 0.5 - 0.5 * (2.0 * std::f64::consts::PI * n as f64 / len as f64).cos(),
    }
}

/// |X_k| / Σw for the configured bins, by an f64 DFT over the window (oldest sample first).
pub fn stft_magnitudes(config: &ModelConfig, window: &VecDeque<f32>) -> Vec<f32> {
    let s = config.stft;
    let n = s.window_len as usize;
    let wsum: f64 = (0..n).map(|i| window_coefficient(s.shape, i, n)).sum();
    (0..s.n_bins as usize)
        .map(|b| {
            let k = s.first_bin as usize + b;
            let (mut re, mut im) = (0f64, 0f64);
            for (i, &v) in window.iter().enumerate() {
                let a = 2.0 * std::f64::consts::PI * (k * i % n) as f64 / n as f64;
                let wv = window_coefficient(s.shape, i, n) * v as f64;
                re += wv * a.cos();
                im -= wv * a.sin();
            }
            ((re * re + im * im).sqrt() / wsum) as f32
        })
        .collect()
}

impl FloatModel {
    /// Checks that the tensors and normalisation fit the header's variant and sizes.
    pub fn validate(&self) -> Result<(), FloatModelError> {
        let c = &self.config;
        let nf = c.feature_count();
        if self.norm_mean.len() != nf || self.norm_std.len() != nf {
            return Err(FloatModelError::Structure(format!(
                "normalisation has {} means and {} deviations, the variant needs {nf}",
                self.norm_mean.len(),
                self.norm_std.len()
            )));
        }
        check("norm_mean", &self.norm_mean, nf)?;
        check("norm_std", &self.norm_std, nf)?;
        if let Some(i) = self.norm_std.iter().position(|&s| s <= 0.0) {
            return Err(FloatModelError::Structure(format!(
                "norm_std[{i}] must be > 0"
            )));
        }
        if self.lstms.len() != c.variant.lstm_count() {
            return Err(FloatModelError::Structure(format!(
                "variant {} needs {} LSTM(s), found {}",
                c.variant.name(),
                c.variant.lstm_count(),
                self.lstms.len()
            )));
        }
        let mut k_total = 0;
        for (k, l) in self.lstms.iter().enumerate() {
            l.validate()?;
            if l.input != c.lstm_inputs(k) || l.hidden != c.hidden[k] as usize {
                return Err(FloatModelError::Structure(format!(
                    "LSTM {k} is {}→{}, the header says {}→{}",
                    l.input,
                    l.hidden,
                    c.lstm_inputs(k),
                    c.hidden[k]
                )));
            }
            k_total += l.hidden;
        }
        if self.dense.inputs != k_total {
            return Err(FloatModelError::Structure(format!(
                "dense layer takes {} inputs, the LSTMs give {k_total}",
                self.dense.inputs
            )));
        }
        self.dense.validate()
    }

    /// A fresh channel state.
    pub fn new_channel(&self) -> FloatChannelState {
        let fw = FeatureWindow::new(&self.config);
        FloatChannelState {
            window: fw.window,
            prev: fw.prev,
            lstm: self.lstms.iter().map(FloatLstm::zero_state).collect(),
            decision: DecisionState::default(),
        }
    }

    /// Normalised features (clamped to ±8σ) of one raw sample.
    pub fn features(&self, st: &mut FloatChannelState, raw: f32) -> Vec<f32> {
        let mut fw = FeatureWindow {
            window: std::mem::take(&mut st.window),
            prev: st.prev,
        };
        let mut v = fw.push(&self.config, raw);
        st.window = fw.window;
        st.prev = fw.prev;
        self.normalise(&mut v);
        v
    }

    /// Applies the model's normalisation to raw features in place.
    pub fn normalise(&self, v: &mut [f32]) {
        for ((x, m), s) in v.iter_mut().zip(&self.norm_mean).zip(&self.norm_std) {
            *x = ((*x - m) / s).clamp(-8.0, 8.0);
        }
    }

    /// LSTM(s) and dense layer on one normalised feature vector.
    pub fn logits(&self, st: &mut FloatChannelState, v: &[f32]) -> [f32; 2] {
        let mut hcat = Vec::with_capacity(self.dense.inputs);
        let mut off = 0;
        for (l, s) in self.lstms.iter().zip(st.lstm.iter_mut()) {
            l.step(s, &v[off..off + l.input]);
            off += l.input;
            hcat.extend_from_slice(&s.h);
        }
        self.dense.logits(&hcat)
    }

    /// One frame of raw features (a hand-level model's row of
    /// [`crate::features::hand`], each `i16` read as value / 2^15) through normalisation,
    /// LSTM, dense layer and decision.
    pub fn step_row(&self, st: &mut FloatChannelState, raw_row: &[f32]) -> FloatStep {
        let mut v = raw_row.to_vec();
        self.normalise(&mut v);
        let logits = self.logits(st, &v);
        let p = p_from_logits(logits);
        let p_q15 = (p * 32768.0).round().min(32767.0) as i16;
        let unstable = DecisionConfig::of(&self.config).update(&mut st.decision, p_q15);
        FloatStep {
            logits,
            p_unstable: p,
            unstable,
        }
    }

    /// One raw sample through the whole float pipeline.
    pub fn step(&self, st: &mut FloatChannelState, raw: f32) -> FloatStep {
        let v = self.features(st, raw);
        let logits = self.logits(st, &v);
        let p = p_from_logits(logits);
        // The same decision rule as the firmware, on p rounded to Q0.15.
        let p_q15 = (p * 32768.0).round().min(32767.0) as i16;
        let unstable = DecisionConfig::of(&self.config).update(&mut st.decision, p_q15);
        FloatStep {
            logits,
            p_unstable: p,
            unstable,
        }
    }
}

impl FloatModel {
    /// A model with PyTorch's default initialisation (LSTM: U(-1/√H, 1/√H) for every weight
    /// and bias; Linear: U(-1/√K, 1/√K)), seeded, with identity normalisation. The trainer
    /// starts from it; tests and benches use it as a "random model at init scale".
    pub fn init_like_pytorch(config: ModelConfig, seed: u64) -> Self {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut uniform = |n: usize, bound: f32| -> Vec<f32> {
            (0..n).map(|_| rng.random_range(-bound..bound)).collect()
        };
        let mut lstms = Vec::new();
        for k in 0..config.variant.lstm_count() {
            let (i, h) = (config.lstm_inputs(k), config.hidden[k] as usize);
            let b = 1.0 / (h as f32).sqrt();
            lstms.push(FloatLstm {
                input: i,
                hidden: h,
                w_ih: uniform(4 * h * i, b),
                w_hh: uniform(4 * h * h, b),
                b_ih: uniform(4 * h, b),
                b_hh: uniform(4 * h, b),
            });
        }
        let k: usize = lstms.iter().map(|l| l.hidden).sum();
        let b = 1.0 / (k as f32).sqrt();
        let dense = FloatDense {
            inputs: k,
            w: uniform(2 * k, b),
            b: uniform(2, b),
        };
        let nf = config.feature_count();
        Self {
            config,
            norm_mean: vec![0.0; nf],
            norm_std: vec![1.0; nf],
            lstms,
            dense,
        }
    }

    /// Sets the normalisation to the mean and standard deviation of the raw features over
    /// `sequences` (raw samples, one channel each, each run from a reset state).
    pub fn fit_normalisation(&mut self, sequences: &[&[f32]]) {
        let rows: Vec<Vec<Vec<f32>>> = sequences
            .iter()
            .map(|s| raw_feature_sequence(&self.config, s))
            .collect();
        let refs: Vec<&[Vec<f32>]> = rows.iter().map(Vec::as_slice).collect();
        self.fit_normalisation_rows(&refs);
    }

    /// Sets the normalisation to the mean and standard deviation of raw feature rows (one
    /// slice of rows per sequence): a hand-level model's hand feature rows, or any variant's
    /// rows from [`raw_feature_sequence`].
    pub fn fit_normalisation_rows(&mut self, sequences: &[&[Vec<f32>]]) {
        let nf = self.config.feature_count();
        let (mut sum, mut sq, mut n) = (vec![0f64; nf], vec![0f64; nf], 0usize);
        for seq in sequences {
            for v in seq.iter() {
                for (j, x) in v.iter().enumerate().take(nf) {
                    sum[j] += *x as f64;
                    sq[j] += (*x as f64) * (*x as f64);
                }
                n += 1;
            }
        }
        if n == 0 {
            return;
        }
        for j in 0..nf {
            let m = sum[j] / n as f64;
            let var = (sq[j] / n as f64 - m * m).max(0.0);
            self.norm_mean[j] = m as f32;
            // A constant feature keeps σ = 1e-3 of full scale rather than dividing by zero.
            self.norm_std[j] = var.sqrt().max(1e-3) as f32;
        }
    }
}
