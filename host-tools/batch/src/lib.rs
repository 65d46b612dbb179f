//! # slipguard-batch
//!
//! Many channels at once, on the host: the bit-exact model of the core's
//! [`Model::step`](slipguard_core::model::Model::step) over a batch of channels stepped
//! together, for evaluation, calibration and replay at dataset scale. The board never runs it;
//! it lives outside the `no_std` core, which keeps the board's kernels and the portable
//! references they are checked against.
//!
//! Per step the single path does, for each channel, one matrix-vector product per LSTM
//! (4H rows × (I + H) int8 weights × int16 activations); here one [`BatchModel::step`] does the
//! same products for every lane (channel) of a [`BatchState`] as one matrix product,
//! `gates[4H × lanes] = W[4H × K] · X[K × lanes]` ([`kernels::batch_pair_sums`]), so each
//! weight, loaded once, meets 16 lanes. The layout is structure of arrays: a lane's h is
//! spread over `h[pair][lane]` words (two units per word, the kernel's i16 pairs), c over
//! `c[unit][lane]`; the weights are widened to i16 pairs and laid out per row at construction.
//!
//! Bit-exact by construction, not by tolerance: the sums are exact integer sums (no partial
//! sum can overflow, see [`kernels::batch_pair_sums`]), so the summation order does not
//! change them, and everything after the sums is the single path's own code, lane by lane:
//! the front end ([`raw_features`], [`normalise`], the STFT's pieces in [`stft`]), the row
//! requantisation and the table activations, the cell update and the decision (the test
//! `batch_vs_single` checks every variant, with and without d(t), against [`Model::step`] and
//! [`Model::step_in_contact`]).
//!
//! Lanes are processed [`CHUNK_LANES`] at a time (the chunk's sums stay in L2); the lane count
//! is padded to whole [`BATCH_TILE_LANES`] tiles, the padding lanes computed and never read.
//!
//! `unsafe` is denied outside [`kernels`] (the x86-64 intrinsics), where every block has a
//! `// SAFETY:` line.

pub mod kernels;
pub mod stft;

use std::fmt;

use slipguard_core::MAX_INPUT;
use slipguard_core::activation;
use slipguard_core::blob::{DenseRowParams, LstmTensors, pad4};
use slipguard_core::decision::{
    ContactConfig, ContactEdge, ContactState, DecisionConfig, DecisionState,
};
use slipguard_core::dsp::{LstmRowParams, interval_table, sigmoid};
use slipguard_core::features::stft::{StftPlan, StftState};
use slipguard_core::features::{FeatureLayout, FeatureState, normalise, raw_features};
use slipguard_core::fixed::{round_shift_i64, sat_i16_wide};
use slipguard_core::lstm::{CellShifts, LstmState, cell_unit, requant};
use slipguard_core::model::{ChannelState, GatedOutput, Model, StepOutput};

pub use kernels::{BATCH_TILE_LANES, BATCH_TILE_ROWS};
use kernels::{batch_cell_update, batch_gate_row_fast, batch_gate_rows, batch_pair_sums};
use stft::{StftLanes, step_lanes};

/// Lanes per pass of a step: the chunk's gate sums (2 × 4H × 64 `i32`, 128 KiB for H = 128)
/// stay in L2 while the weights (143 KiB as i16 pairs for variant (c), H = 128) are reused
/// across the chunk. A multiple of [`BATCH_TILE_LANES`].
pub const CHUNK_LANES: usize = 64;

const _: () = assert!(CHUNK_LANES.is_multiple_of(BATCH_TILE_LANES));

/// Why a model cannot run batched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum BatchError {
    /// The model is a RAM image (blocked weights, folded rows): batch the blob it came from.
    RamImage,
    /// An LSTM's tensors do not have 4H rows of weights and parameters.
    Shape,
    /// A hand-level model (`hand-lstm`): one network per hand, not per channel; run it with
    /// `Model::hand_p`.
    HandLevel,
}

impl fmt::Display for BatchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BatchError::RamImage => {
                f.write_str("the batched path takes a model blob, not a RAM image (SGMI)")
            }
            BatchError::Shape => {
                f.write_str("an LSTM's weights or row parameters are not 4 x hidden rows")
            }
            BatchError::HandLevel => f.write_str(
                "a hand-level model runs one network per hand (Model::hand_p), not per channel",
            ),
        }
    }
}

impl std::error::Error for BatchError {}

/// Two i16 values as one word, `lo | hi << 16` (the pair kernels' operand).
#[inline(always)]
fn pair(lo: i16, hi: i16) -> u32 {
    lo as u16 as u32 | (hi as u16 as u32) << 16
}

/// One LSTM in the batch layout.
#[derive(Clone, Debug)]
struct PackedLstm {
    /// Index of its first feature in the model's feature vector.
    first: usize,
    /// Features it takes (I, or fewer if the feature vector is shorter: the rest count 0).
    take: usize,
    /// H.
    hidden: usize,
    /// Input pairs ⌈I / 2⌉ and hidden pairs ⌈H / 2⌉.
    px: usize,
    ph: usize,
    /// W_ih and W_hh as i16 pairs: `wx[r·px + p]`, `wh[r·ph + p]`, 4H rows.
    wx: Vec<u32>,
    wh: Vec<u32>,
    /// Row requantisation, 4H rows (the blob's).
    rows: Vec<LstmRowParams>,
    shifts: CellShifts,
    /// The dense layer's weights on this LSTM's h, as pairs: 2 class rows padded with zero
    /// rows to [`BATCH_TILE_ROWS`], `dense[c·ph + p]`.
    dense: Vec<u32>,
}

impl PackedLstm {
    fn new(
        t: &LstmTensors<'_>,
        first: usize,
        take: usize,
        dense_w: &[i8],
        dense_row_len: usize,
        dense_off: usize,
    ) -> Result<Self, BatchError> {
        if t.blocked {
            return Err(BatchError::RamImage);
        }
        let hidden = t.hidden.min(slipguard_core::MAX_HIDDEN);
        let take = take.min(t.inputs);
        let (px, ph) = (t.inputs.div_ceil(2), hidden.div_ceil(2));
        let rows = 4 * hidden;
        let stride = t.row_len;
        if t.rows.len() < rows || t.weights.len() < rows * stride || t.hh_offset + hidden > stride {
            return Err(BatchError::Shape);
        }
        let at = |r: usize, off: usize, k: usize, n: usize| -> i16 {
            if k < n {
                t.weights[r * stride + off + k] as i16
            } else {
                0
            }
        };
        let mut wx = Vec::with_capacity(rows * px);
        let mut wh = Vec::with_capacity(rows * ph);
        for r in 0..rows {
            wx.extend((0..px).map(|p| pair(at(r, 0, 2 * p, take), at(r, 0, 2 * p + 1, take))));
            let off = t.hh_offset;
            wh.extend(
                (0..ph).map(|p| pair(at(r, off, 2 * p, hidden), at(r, off, 2 * p + 1, hidden))),
            );
        }
        // decision::p_unstable: this LSTM's slice of each class row starts at `dense_off`.
        let mut dense = vec![0u32; BATCH_TILE_ROWS * ph];
        for c in 0..2 {
            let row = dense_w
                .get(c * dense_row_len..(c + 1) * dense_row_len)
                .and_then(|r| r.get(dense_off..))
                .unwrap_or(&[]);
            let w = |k: usize| {
                if k < hidden {
                    row.get(k).map_or(0, |&v| v as i16)
                } else {
                    0
                }
            };
            for p in 0..ph {
                dense[c * ph + p] = pair(w(2 * p), w(2 * p + 1));
            }
        }
        Ok(Self {
            first,
            take,
            hidden,
            px,
            ph,
            wx,
            wh,
            rows: t.rows[..rows].to_vec(),
            shifts: CellShifts::new(t.cell_frac_bits),
            dense,
        })
    }
}

/// A model prepared for many channels at once: the [`Model`] plus its weights in the batch
/// layout (built once; about 2 × the blob's LSTM bytes).
#[derive(Clone, Debug)]
pub struct BatchModel<'a> {
    model: Model<'a>,
    plan: Option<StftPlan>,
    layout: FeatureLayout,
    decision: DecisionConfig,
    lstms: Vec<PackedLstm>,
    dense_rows: [DenseRowParams; 2],
}

impl<'a> BatchModel<'a> {
    /// Lays out `model`'s weights for the batch (the decision settings are `model`'s).
    pub fn new(model: &Model<'a>) -> Result<Self, BatchError> {
        let blob = model.blob();
        let config = blob.config;
        if config.variant.is_hand() {
            return Err(BatchError::HandLevel);
        }
        let layout = config.feature_layout();
        let plan = if config.variant.uses_bands() {
            StftPlan::new(config.stft).ok()
        } else {
            None
        };
        let n = layout.len().min(MAX_INPUT);
        let dense = &blob.dense;
        let mut lstms = Vec::new();
        // The same split of the feature vector as `Model::p_unstable`.
        let (mut first, mut dense_off) = (0, 0);
        let count = blob.lstms().len();
        for (k, t) in blob.lstms().iter().enumerate() {
            let take = if count == 2 && k == 0 {
                t.inputs.min(n)
            } else {
                n - first
            };
            lstms.push(PackedLstm::new(
                t,
                first,
                take,
                dense.weights,
                dense.row_len,
                dense_off,
            )?);
            first += take;
            dense_off += pad4(t.hidden);
        }
        let dense_rows = [
            dense.rows.first().copied().ok_or(BatchError::Shape)?,
            dense.rows.get(1).copied().ok_or(BatchError::Shape)?,
        ];
        Ok(Self {
            model: model.clone(),
            plan,
            layout,
            decision: model.decision(),
            lstms,
            dense_rows,
        })
    }

    /// The single-channel model this batches.
    pub fn model(&self) -> &Model<'a> {
        &self.model
    }

    /// The decision settings in force.
    pub fn decision(&self) -> DecisionConfig {
        self.decision
    }

    /// Replaces the decision settings (as [`Model::set_decision`]).
    pub fn set_decision(&mut self, decision: DecisionConfig) {
        self.decision = decision;
    }

    /// A state of `lanes` channels, all as after reset.
    pub fn state(&self, lanes: usize) -> BatchState {
        let stride = lanes.div_ceil(BATCH_TILE_LANES) * BATCH_TILE_LANES;
        let lstm = self
            .lstms
            .iter()
            .map(|l| LaneLstm {
                h: vec![0; l.ph * stride],
                c: vec![0; l.hidden * stride],
            })
            .collect();
        let rows = self.lstms.iter().map(|l| 4 * l.hidden).max().unwrap_or(0);
        let px = self.lstms.iter().map(|l| l.px).max().unwrap_or(0);
        BatchState {
            lanes,
            stride,
            features: vec![FeatureState::new(); lanes],
            stft: vec![StftState::new(); lanes],
            decision: vec![DecisionState::default(); lanes],
            contact: vec![ContactState::new(); lanes],
            lstm,
            x_q15: vec![0; lanes],
            active: vec![true; lanes],
            out: vec![
                StepOutput {
                    p_unstable_q15: 0,
                    unstable: false
                };
                lanes
            ],
            scratch: Scratch {
                feats: vec![[0; MAX_INPUT]; CHUNK_LANES],
                x: vec![0; px * CHUNK_LANES],
                acc_x: vec![0; rows * CHUNK_LANES],
                acc_h: vec![0; rows * CHUNK_LANES],
                gates: vec![0; rows * CHUNK_LANES],
                on: vec![false; CHUNK_LANES],
                stft: StftLanes::new(CHUNK_LANES),
                bands: vec![0; slipguard_core::features::MAX_BANDS * CHUNK_LANES],
                dense: vec![0; BATCH_TILE_ROWS * CHUNK_LANES],
                logits: vec![[0; 2]; CHUNK_LANES],
            },
        }
    }

    /// [`Model::step`] for every lane: lane `l` takes the raw sample `raw[l]` and its output
    /// goes to `out[l]`. Lanes past `raw.len()` or `out.len()` are not stepped.
    pub fn step(&self, st: &mut BatchState, raw: &[i32], out: &mut [StepOutput]) {
        let scale = self.model.scale();
        let n = st.lanes.min(raw.len()).min(out.len());
        for l in 0..st.lanes {
            st.active[l] = l < n;
            st.x_q15[l] = raw.get(l).map_or(0, |&r| scale.to_q15(r));
        }
        self.step_active(st);
        out[..n].copy_from_slice(&st.out[..n]);
    }

    /// [`Model::step`] for the lanes with `active[l]` (the others keep their state and their
    /// `out` entry): sequences of different lengths in one batch.
    pub fn step_masked(
        &self,
        st: &mut BatchState,
        raw: &[i32],
        active: &[bool],
        out: &mut [StepOutput],
    ) {
        let scale = self.model.scale();
        for l in 0..st.lanes {
            let on = active.get(l).copied().unwrap_or(false) && l < raw.len() && l < out.len();
            st.active[l] = on;
            st.x_q15[l] = if on { scale.to_q15(raw[l]) } else { 0 };
        }
        self.step_active(st);
        for l in 0..st.lanes.min(out.len()) {
            if st.active[l] {
                out[l] = st.out[l];
            }
        }
    }

    /// [`Model::step_in_contact`] for every lane (`raw[l]`, `out[l]`; lanes past either slice
    /// are not stepped), or only the lanes with `active[l]` if `active` is given.
    pub fn step_in_contact(
        &self,
        st: &mut BatchState,
        contact: &ContactConfig,
        raw: &[i32],
        active: Option<&[bool]>,
        out: &mut [GatedOutput],
    ) {
        let scale = self.model.scale();
        let n = st.lanes.min(raw.len()).min(out.len());
        for l in 0..st.lanes {
            let on = l < n && active.is_none_or(|a| a.get(l).copied().unwrap_or(false));
            st.active[l] = false;
            st.x_q15[l] = 0;
            if !on {
                continue;
            }
            let x = scale.to_q15(raw[l]);
            let edge = contact.update(&mut st.contact[l], x);
            if edge == ContactEdge::Began {
                st.restart_lane(l);
            }
            st.active[l] = edge.in_contact();
            st.x_q15[l] = x;
            out[l] = GatedOutput {
                contact: edge,
                step: None,
            };
        }
        self.step_active(st);
        for ((o, &on), s) in out.iter_mut().zip(&st.active).zip(&st.out).take(n) {
            if on {
                o.step = Some(*s);
            }
        }
    }

    /// One step of the lanes with `st.active` on the Q1.15 samples `st.x_q15`, into `st.out`.
    fn step_active(&self, st: &mut BatchState) {
        let BatchState {
            lanes,
            stride,
            features,
            stft,
            decision,
            lstm,
            x_q15,
            active,
            out,
            scratch: s,
            ..
        } = st;
        let (lanes, stride) = (*lanes, *stride);
        if !active.iter().any(|&a| a) {
            return;
        }
        let n = self.layout.len().min(MAX_INPUT);
        let norm = self.model.blob().norm;
        for c0 in (0..stride).step_by(CHUNK_LANES) {
            let cl = CHUNK_LANES.min(stride - c0);
            for i in 0..cl {
                s.on[i] = c0 + i < lanes && active[c0 + i];
            }
            if !s.on[..cl].iter().any(|&a| a) {
                continue;
            }
            // The front end: force and d(t) lane by lane (the single path's code), the STFT
            // bands of the chunk's lanes at once (`stft::step_lanes`, the same numbers),
            // then the normalisation lane by lane.
            for i in 0..cl {
                s.feats[i] = [0; MAX_INPUT];
                if s.on[i] {
                    let g = c0 + i;
                    raw_features(
                        self.layout,
                        None,
                        &mut features[g],
                        x_q15[g],
                        &mut s.feats[i],
                    );
                }
            }
            if let Some(plan) = &self.plan {
                // Lanes past the batch's (padding) are off: m ≤ cl lanes take part.
                let m = lanes.min(c0 + cl).saturating_sub(c0);
                let first = self.layout.force as usize + self.layout.diff as usize;
                let bands = &mut s.bands[..self.layout.bands * m];
                let (st, x) = (&mut stft[c0..c0 + m], &x_q15[c0..c0 + m]);
                step_lanes(plan, &mut s.stft, st, x, &s.on[..m], bands);
                for b in 0..self.layout.bands.min(MAX_INPUT.saturating_sub(first)) {
                    for i in 0..m {
                        s.feats[i][first + b] = bands[b * m + i];
                    }
                }
            }
            for i in 0..cl {
                if s.on[i] {
                    normalise(norm, &mut s.feats[i][..n]);
                }
            }
            s.logits[..cl].fill([0; 2]);
            for (pk, lk) in self.lstms.iter().zip(lstm.iter_mut()) {
                self.lstm_chunk(pk, lk, s, stride, c0, cl);
                // The dense layer's two sums on this LSTM's new h (rows 2, 3 are padding).
                let d = &mut s.dense[..BATCH_TILE_ROWS * cl];
                batch_pair_sums(&pk.dense, pk.ph, &lk.h[c0..], stride, cl, d);
                for (i, l) in s.logits[..cl].iter_mut().enumerate() {
                    l[0] += d[i] as i64;
                    l[1] += d[cl + i] as i64;
                }
            }
            // decision::p_unstable and the decision, per lane.
            let [r0, r1] = &self.dense_rows;
            for i in (0..cl).filter(|&i| s.on[i]) {
                let [a0, a1] = s.logits[i];
                let l0 = round_shift_i64(a0 * r0.m as i64, r0.shift as u32) + r0.bias_q12 as i64;
                let l1 = round_shift_i64(a1 * r1.m as i64, r1.shift as u32) + r1.bias_q12 as i64;
                let p = sigmoid(sat_i16_wide(l1 - l0));
                let g = c0 + i;
                let unstable = self.decision.update(&mut decision[g], p);
                out[g] = StepOutput {
                    p_unstable_q15: p,
                    unstable,
                };
            }
        }
    }

    /// One LSTM over lanes `c0..c0 + cl`: the two matrix products, the gate rows, the cell
    /// update of the lanes `on`.
    #[allow(clippy::too_many_arguments)]
    fn lstm_chunk(
        &self,
        pk: &PackedLstm,
        lk: &mut LaneLstm,
        s: &mut Scratch,
        stride: usize,
        c0: usize,
        cl: usize,
    ) {
        let (hn, rows) = (pk.hidden, 4 * pk.hidden);
        // x as pairs of features, lane-contiguous: x[p·cl + i].
        let x = &mut s.x[..pk.px * cl];
        for p in 0..pk.px {
            for i in 0..cl {
                let v = &s.feats[i];
                let (a, b) = (2 * p, 2 * p + 1);
                let get = |k: usize| if k < pk.take { v[pk.first + k] } else { 0 };
                x[p * cl + i] = pair(get(a), get(b));
            }
        }
        let (ax, ah) = (&mut s.acc_x[..rows * cl], &mut s.acc_h[..rows * cl]);
        batch_pair_sums(&pk.wx, pk.px, x, cl, cl, ax);
        batch_pair_sums(&pk.wh, pk.ph, &lk.h[c0..], stride, cl, ah);
        // Gate rows: requantisation and σ (rows i, f, o) or tanh (rows g, 2H..3H), Q0.15.
        let gates = &mut s.gates[..rows * cl];
        gate_rows(ax, ah, &pk.rows, hn, cl, gates);
        // Cell update, unit by unit (lstm::cell_unit), the lanes `on` only.
        cell_update(
            gates,
            hn,
            cl,
            pk.shifts,
            &s.on[..cl],
            &mut lk.h,
            &mut lk.c,
            stride,
            c0,
        );
    }
}

/// The batched gate pass over `lanes` lanes: for row r and lane l,
/// `gates[r·lanes + l] = f(requant(rows[r], acc_x[r·lanes + l], acc_h[r·lanes + l]))`, f = tanh
/// for the cell-candidate rows `2·hn..3·hn` and σ for the others: the single path's gate pass
/// (`lstm::gate_activations_portable`) with the lanes innermost, in
/// [`kernels::batch_gate_rows`] where it runs and here for the rest.
pub fn gate_rows(
    acc_x: &[i32],
    acc_h: &[i32],
    rows: &[LstmRowParams],
    hn: usize,
    lanes: usize,
    gates: &mut [i16],
) {
    let done = batch_gate_rows(acc_x, acc_h, rows, hn, lanes, gates);
    gate_rows_from(acc_x, acc_h, rows, hn, lanes, gates, done);
}

/// [`gate_rows`] all in Rust (what other targets run).
pub fn gate_rows_portable(
    acc_x: &[i32],
    acc_h: &[i32],
    rows: &[LstmRowParams],
    hn: usize,
    lanes: usize,
    gates: &mut [i16],
) {
    gate_rows_from(acc_x, acc_h, rows, hn, lanes, gates, 0);
}

/// [`gate_rows`] for the lanes from `done` on in the fast rows, every lane in the others.
fn gate_rows_from(
    acc_x: &[i32],
    acc_h: &[i32],
    rows: &[LstmRowParams],
    hn: usize,
    lanes: usize,
    gates: &mut [i16],
    done: usize,
) {
    let (sig, tanh) = (interval_table(false), interval_table(true));
    for (r, p) in rows.iter().enumerate() {
        let table = if (2 * hn..3 * hn).contains(&r) {
            tanh
        } else {
            sig
        };
        let from = if batch_gate_row_fast(p) { done } else { 0 };
        let span = r * lanes + from..(r + 1) * lanes;
        let (Some(g), Some(a), Some(b)) = (
            gates.get_mut(span.clone()),
            acc_x.get(span.clone()),
            acc_h.get(span),
        ) else {
            return;
        };
        for ((g, &a), &b) in g.iter_mut().zip(a).zip(b) {
            *g = activation::lookup(table, requant(p, a, b));
        }
    }
}

/// The batched cell update of the `lanes` lanes from lane `c0` of a state with row stride
/// `stride`: for each unit j < `hn` and lane i, `lstm::cell_unit` from the gates
/// `gates[(g·hn + j)·lanes + i]` (i, f, g, o) on `c[j·stride + c0 + i]`, c' written there and h'
/// into the low (j even) or high (j odd) half of `h[(j / 2)·stride + c0 + i]`; lanes with
/// `on[i]` false keep their c and h. In [`kernels::batch_cell_update`] where it runs, here
/// for the rest.
#[allow(clippy::too_many_arguments)]
pub fn cell_update(
    gates: &[i16],
    hn: usize,
    lanes: usize,
    k: CellShifts,
    on: &[bool],
    h: &mut [u32],
    c: &mut [i16],
    stride: usize,
    c0: usize,
) {
    let done = batch_cell_update(gates, hn, lanes, k.kernel(), on, h, c, stride, c0);
    cell_update_from(gates, hn, lanes, k, on, h, c, stride, c0, done);
}

/// [`cell_update`] all in Rust (what other targets run).
#[allow(clippy::too_many_arguments)]
pub fn cell_update_portable(
    gates: &[i16],
    hn: usize,
    lanes: usize,
    k: CellShifts,
    on: &[bool],
    h: &mut [u32],
    c: &mut [i16],
    stride: usize,
    c0: usize,
) {
    cell_update_from(gates, hn, lanes, k, on, h, c, stride, c0, 0);
}

/// [`cell_update`] of the lanes from `done` on.
#[allow(clippy::too_many_arguments)]
fn cell_update_from(
    gates: &[i16],
    hn: usize,
    lanes: usize,
    k: CellShifts,
    on: &[bool],
    h: &mut [u32],
    c: &mut [i16],
    stride: usize,
    c0: usize,
    done: usize,
) {
    let gate = |g: usize, j: usize| gates.get((g * hn + j) * lanes..(g * hn + j + 1) * lanes);
    for p in 0..hn.div_ceil(2) {
        let Some(hw) = h.get_mut(p * stride + c0..p * stride + c0 + lanes) else {
            return;
        };
        for u in 0..2 {
            let j = 2 * p + u;
            if j >= hn {
                break;
            }
            let (Some(gi), Some(gf), Some(gg), Some(go), Some(cj), Some(on)) = (
                gate(0, j),
                gate(1, j),
                gate(2, j),
                gate(3, j),
                c.get_mut(j * stride + c0..j * stride + c0 + lanes),
                on.get(..lanes),
            ) else {
                return;
            };
            let shift = 16 * u as u32;
            for i in done..lanes {
                if on[i] {
                    let mut hv = 0i16;
                    cell_unit(k, [gi[i], gf[i], gg[i], go[i]], &mut cj[i], &mut hv);
                    hw[i] = (hw[i] & !(0xffff << shift)) | (hv as u16 as u32) << shift;
                }
            }
        }
    }
}

/// One LSTM's state for all lanes: `h[p·stride + lane]` holds units 2p and 2p + 1 (Q0.15,
/// low and high half), `c[j·stride + lane]` unit j (Q(15-C).C).
#[derive(Clone, Debug)]
struct LaneLstm {
    h: Vec<u32>,
    c: Vec<i16>,
}

/// Working buffers of one chunk.
#[derive(Clone, Debug)]
struct Scratch {
    /// Each lane's normalised features, Q3.12 (as `Model::step` feeds the LSTM).
    feats: Vec<[i16; MAX_INPUT]>,
    /// The LSTM input as pairs, `x[p·lanes + i]` = features 2p (low half) and 2p + 1 (high
    /// half) of lane i, Q3.12, for the pair-sum kernel.
    x: Vec<u32>,
    /// Σ w_ih·x per gate row and lane: int8 weights × Q3.12, an exact i32 sum (the row's
    /// scale is applied at requantisation, `LstmRowParams`).
    acc_x: Vec<i32>,
    /// Σ w_hh·h per gate row and lane: int8 weights × Q0.15 h, an exact i32 sum.
    acc_h: Vec<i32>,
    /// Gate activations per row and lane, Q0.15 (σ for i, f, o; tanh for g).
    gates: Vec<i16>,
    /// The chunk's lanes that step.
    on: Vec<bool>,
    stft: StftLanes,
    /// The chunk's band magnitudes, `bands[b·lanes + i]`, Q1.15 (|X_k| / Σw, the STFT's output).
    bands: Vec<i16>,
    /// Σ w·h of the two dense rows per lane: int8 × Q0.15 h, an exact i32 sum.
    dense: Vec<i32>,
    /// The dense layer's two sums per lane over every LSTM's h (int8 × Q0.15), before the
    /// row requantisation; i64 as in `decision::p_unstable`, where acc·m needs up to 63 bits.
    logits: Vec<[i64; 2]>,
}

/// The state of a batch of channels (lanes) of one [`BatchModel`]: what a [`ChannelState`]
/// holds, for every lane, plus the step's working buffers.
#[derive(Clone, Debug)]
pub struct BatchState {
    lanes: usize,
    /// Lanes rounded up to whole kernel tiles: the row stride of the lane arrays.
    stride: usize,
    /// Previous samples (the STFT part of each is unused: see `stft`).
    features: Vec<FeatureState>,
    /// The STFT windows, apart so that a chunk's lanes are one slice.
    stft: Vec<StftState>,
    decision: Vec<DecisionState>,
    contact: Vec<ContactState>,
    lstm: Vec<LaneLstm>,
    x_q15: Vec<i16>,
    active: Vec<bool>,
    out: Vec<StepOutput>,
    scratch: Scratch,
}

impl BatchState {
    /// Number of lanes (channels).
    pub fn lanes(&self) -> usize {
        self.lanes
    }

    /// Forgets everything of lane `l` ([`ChannelState::reset`]).
    pub fn reset_lane(&mut self, l: usize) {
        if l < self.lanes {
            self.restart_lane(l);
            self.contact[l] = ContactState::new();
        }
    }

    /// Restarts lane `l`'s model state and keeps its contact state ([`ChannelState::restart`]).
    pub fn restart_lane(&mut self, l: usize) {
        if l >= self.lanes {
            return;
        }
        self.features[l] = FeatureState::new();
        self.stft[l] = StftState::new();
        self.decision[l] = DecisionState::default();
        let stride = self.stride;
        for k in &mut self.lstm {
            k.h.iter_mut().skip(l).step_by(stride).for_each(|w| *w = 0);
            k.c.iter_mut().skip(l).step_by(stride).for_each(|c| *c = 0);
        }
    }

    /// Forgets every lane.
    pub fn reset(&mut self) {
        for l in 0..self.lanes {
            self.reset_lane(l);
        }
    }

    /// Hidden unit `j` of LSTM `k` of lane `l` (Q0.15; 0 outside the model's sizes): what
    /// `ChannelState::lstm[k].h[j]` holds after the same steps.
    pub fn h(&self, l: usize, k: usize, j: usize) -> i16 {
        if l >= self.lanes {
            return 0;
        }
        self.lstm
            .get(k)
            .and_then(|s| s.h.get(j / 2 * self.stride + l))
            .map_or(0, |&w| (w >> (16 * (j % 2))) as u16 as i16)
    }

    /// Lane `l` as a [`ChannelState`] (what [`Model::step`] would hold), `None` past the lanes.
    pub fn channel(&self, l: usize) -> Option<ChannelState> {
        if l >= self.lanes {
            return None;
        }
        let mut st = ChannelState::new();
        st.features = self.features[l].clone();
        st.features.stft = self.stft[l].clone();
        st.decision = self.decision[l];
        st.contact = self.contact[l];
        for (k, s) in self.lstm.iter().zip(st.lstm.iter_mut()) {
            *s = LstmState::new();
            for (j, c) in s.c.iter_mut().enumerate() {
                if let Some(&v) = k.c.get(j * self.stride + l) {
                    *c = v;
                }
            }
            for (j, h) in s.h.iter_mut().enumerate() {
                if let Some(&w) = k.h.get(j / 2 * self.stride + l) {
                    *h = (w >> (16 * (j % 2))) as u16 as i16;
                }
            }
        }
        Some(st)
    }
}
