//! The quantized LSTM cell, "16x8" as in TFLite Micro / CMSIS-NN, with per-row weight scales.
//!
//! Per step, for gate rows in PyTorch's order i, f, g, o (rows r = gate·H + j):
//!
//! ```text
//! z_r   = requant_r(Σ W_ih[r]·x, Σ W_hh[r]·h) + b_r     Q3.12, saturated to [-8, 8)
//! i,f,o = σ(z)                                          Q0.15 (lookup + interpolation)
//! g     = tanh(z)                                       Q0.15
//! c'    = f·c + i·g                                     Q(15-C).C, C from the blob
//! h'    = o·tanh(c')                                    Q0.15
//! ```
//!
//! Weights are int8, symmetric, one scale per row for W_ih and one for W_hh; x is int16 Q3.12,
//! h is int16 Q0.15; the two dot products accumulate in `i32` and meet in `i64` at the row's
//! requantisation ([`LstmRowParams`]). All rounding is to nearest, so the host and the
//! Cortex-M4 compute the same bits.

use crate::activation;
use crate::blob::{LstmRowParams, LstmTensors};
use crate::dsp::{
    CellParams, lstm_block_sums, lstm_cell_update, lstm_gate_rows, lstm_gate_rows_folded,
    lstm_gate_sums, permute_q15_uninit,
};
use crate::dsp::{interval_table, sigmoid, tanh};
use crate::fixed::{round_shift_i64, sat_i16, sat_i16_wide};
use crate::{MAX_HIDDEN, MAX_INPUT};
use core::mem::MaybeUninit;

/// One LSTM's recurrent state for one channel. `repr(C)`: the assembly cell update
/// ([`crate::dsp::lstm_cell_update`]) needs c directly after h; aligned to 4
/// bytes so that the kernels ([`crate::dsp::dot_i8_i16_fast`], [`crate::dsp::lstm_block_sums`])
/// can load h by words.
#[derive(Clone, Debug, PartialEq, Eq)]
#[repr(C, align(4))]
pub struct LstmState {
    /// Hidden state h, Q0.15. Entries past the model's H stay 0 (the padded kernel relies on it).
    pub h: [i16; MAX_HIDDEN],
    /// Cell state c, Q(15-C).C with C = the blob's `cell_frac_bits`.
    pub c: [i16; MAX_HIDDEN],
}

impl LstmState {
    /// Zero state (the state PyTorch starts from).
    pub const fn new() -> Self {
        Self {
            h: [0; MAX_HIDDEN],
            c: [0; MAX_HIDDEN],
        }
    }
    /// Back to zero (grasp start).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

const _: () = assert!(core::mem::offset_of!(LstmState, c) == 2 * MAX_HIDDEN);

impl Default for LstmState {
    fn default() -> Self {
        Self::new()
    }
}

/// Gate pre-activation of one row, Q3.12: the row requantisation of [`LstmRowParams`] from
/// the two exact sums. Public for the batched host path (`slipguard-batch`), which runs this
/// same code lane by lane.
#[inline(always)]
pub fn requant(p: &LstmRowParams, acc_x: i32, acc_h: i32) -> i16 {
    let shift = p.shift as u32;
    let k = shift.wrapping_sub(33);
    if k < 30 {
        // shift in 33..=62: the same bits as [`requant_wide`] from the high word alone (no
        // variable 64-bit shift on the M4). The rounding half 2^(shift-1) = 2^k · 2^32 goes
        // into the 64-bit accumulator's high word first (SMLAL accumulates onto it), and as
        // shift ≥ 32, ⌊Z / 2^shift⌋ = ⌊⌊Z / 2^32⌋ / 2^(shift-32)⌋. No overflow: |acc_x·mx| <
        // 2^57, |acc_h·mh| < 2^60, half ≤ 2^61. The bias is added with saturation before the
        // i16 saturation: the same result as the wide add.
        let half = ((1i32 << (k & 31)) as i64) << 32;
        let z = half + acc_x as i64 * p.mx as i64 + acc_h as i64 * p.mh as i64;
        let t = ((z >> 32) as i32) >> (k + 1);
        sat_i16(t.saturating_add(p.bias_q12))
    } else {
        // i64: acc_x < 2^26 and acc_h < 2^29 times a multiplier < 2^31 stay below 2^61.
        requant_wide(p, acc_x as i64 * p.mx as i64 + acc_h as i64 * p.mh as i64)
    }
}

pub use crate::blob::FOLDED_ADDEND_MAX;

/// A row's parameters in the *folded* form of a RAM image ([`crate::model_ram`]), or `None` if
/// the row has none (a shift outside 33..=62, or an addend over [`FOLDED_ADDEND_MAX`]): mx and mh
/// as they are, `bias_q12` = C = 2^k + bias·2^(k+1) and `shift` = d = k + 1 (1..=30), with
/// k = shift − 33. [`requant_folded`] of the result is [`requant`] of `p`.
pub fn fold_row(p: &LstmRowParams) -> Option<LstmRowParams> {
    let k = p.shift.checked_sub(33).filter(|k| (0..30).contains(k))?;
    let c = (1i64 << k) + (p.bias_q12 as i64) * (1i64 << (k + 1));
    if c.abs() > FOLDED_ADDEND_MAX {
        return None;
    }
    Some(LstmRowParams {
        mx: p.mx,
        mh: p.mh,
        bias_q12: c as i32,
        shift: k + 1,
    })
}

/// [`requant`] from a folded row ([`fold_row`]):
/// `sat16(⌊(C·2^32 + acc_x·mx + acc_h·mh) / 2^32⌋ >> d)`. The same number: with shift = d + 32 and k = d − 1, ⌊(z + 2^(shift−1)) / 2^shift⌋ =
/// ⌊(⌊z / 2^32⌋ + 2^k) / 2^(k+1)⌋ (nested floors), and adding the bias inside the floor as
/// bias·2^(k+1) gives ⌊(⌊z / 2^32⌋ + C) / 2^d⌋; ⌊z / 2^32⌋ + C is the high word of
/// z + C·2^32. No overflow: |z| < 2^61 (see [`requant`]) so |⌊z / 2^32⌋| ≤ 2^29, and
/// |C| ≤ 2^30: the high word stays within i32, and sat16 of the exact sum t + bias is what the
/// saturating add and the saturation give. One SMLAL pair, ASR, SSAT on the M4.
#[inline(always)]
fn requant_folded(p: &LstmRowParams, acc_x: i32, acc_h: i32) -> i16 {
    let z = ((p.bias_q12 as i64) << 32)
        .wrapping_add(acc_x as i64 * p.mx as i64)
        .wrapping_add(acc_h as i64 * p.mh as i64);
    sat_i16(((z >> 32) as i32) >> (p.shift as u32 & 31))
}

/// [`requant`]'s definition: round, add the bias and saturate in `i64`.
#[inline(always)]
fn requant_wide(p: &LstmRowParams, z: i64) -> i16 {
    sat_i16_wide(round_shift_i64(z, p.shift as u32) + p.bias_q12 as i64)
}

/// Loop-invariant shifts of the cell update, from the cell format C (clamped to 1..=15, the
/// range the blob parser admits).
#[derive(Clone, Copy, Debug)]
pub struct CellShifts {
    /// i·g is Q0.30; shifting it right by 30 - C (15..=29), rounded, gives Q(15-C).C.
    pub ig_shift: u32,
    /// 2^(ig_shift - 1).
    pub ig_half: i32,
    /// Cell → Q3.12 for tanh: `sat16(((c << up) + half) >> down)`; for C > 12 that is a
    /// rounded right shift by C - 12 (up = 0), for C ≤ 12 a saturated left shift by 12 - C
    /// (down = 0, half = 0).
    up: u32,
    half: i32,
    down: u32,
    /// The same conversion as `sat16((c·q_mul + q_add) >> 3)` (the assembly's form): for C > 12,
    /// q_mul = 2^(3 - down), q_add = 4, since ⌊(c·2^(3-d) + 2^2) / 2^3⌋ = ⌊(c + 2^(d-1)) / 2^d⌋;
    /// for C ≤ 12, q_mul = 2^(up + 3) ≤ 2^14, q_add = 0. |c·q_mul| ≤ 2^29.
    pub q_mul: i32,
    /// See `q_mul`.
    pub q_add: i32,
}

impl CellShifts {
    /// The constants the assembly cell update takes.
    pub fn kernel(&self) -> CellParams {
        CellParams {
            ig_shift: self.ig_shift,
            ig_half: self.ig_half,
            q_mul: self.q_mul,
            q_add: self.q_add,
        }
    }

    /// The shifts for cell format C = `cell_frac_bits`.
    pub fn new(cell_frac_bits: u32) -> Self {
        let cb = cell_frac_bits.clamp(1, 15);
        let ig_shift = 30 - cb;
        let (up, down) = if cb > 12 { (0, cb - 12) } else { (12 - cb, 0) };
        Self {
            ig_shift,
            ig_half: 1 << (ig_shift - 1),
            up,
            half: if down > 0 { 1 << (down - 1) } else { 0 },
            down,
            q_mul: 1 << (up + 3 - down),
            q_add: if down > 0 { 4 } else { 0 },
        }
    }
}

/// One unit's cell update from its four gate activations (Q0.15):
/// `c' = sat(round(f·c / 2^15) + round(i·g / 2^(30-C)))`, `h' = sat(round(o·tanh(c') / 2^15))`.
///
/// Every product of two i16 lies in [-2^30 + 2^15, 2^30]; with a rounding half of at most
/// 2^28 it stays below 2^31, so these `i32` sums equal the wide ones. Public for the batched
/// host path (`slipguard-batch`), which runs this same code lane by lane.
#[inline(always)]
pub fn cell_unit(k: CellShifts, [i, f, g, o]: [i16; 4], c: &mut i16, h: &mut i16) {
    // f·c: Q0.15 × Q(15-C).C, >> 15 keeps the cell's format.
    let fc = (f as i32 * *c as i32 + (1 << 14)) >> 15;
    let ig = (i as i32 * g as i32 + k.ig_half) >> k.ig_shift;
    let cn = sat_i16(fc + ig);
    *c = cn;
    // Q(15-C).C → Q3.12, saturated (tanh is flat beyond ±8 anyway). c << up ≤ 2^26.
    let cq = sat_i16((((cn as i32) << k.up) + k.half) >> k.down);
    // o·tanh(c): Q0.15 × Q0.15 >> 15 = Q0.15.
    *h = sat_i16((o as i32 * tanh(cq) as i32 + (1 << 14)) >> 15);
}

/// Advances `state` by one step with input `x` (Q3.12, `t.inputs` values).
///
/// `t` comes from a validated [`crate::blob::ModelBlob`], so its sizes are within the static
/// bounds; slices are still taken with checked ranges, so a wrong size can only give wrong
/// numbers, never a panic.
pub fn step(t: &LstmTensors<'_>, state: &mut LstmState, x: &[i16]) {
    let hn = t.hidden.min(MAX_HIDDEN);
    let x = &x[..t.inputs.min(x.len())];
    let stride = t.row_len.max(1);
    let rows = (4 * hn).min(t.rows.len()).min(t.weights.len() / stride);
    // Rows in PyTorch's gate order i, f, g, o: row g·H + j belongs to gate g of unit j.
    // acc[r] = [Σ W_ih[r]·x, Σ W_hh[r]·h]; written by the kernel, so not zeroed first.
    let mut acc = [MaybeUninit::<[i32; 2]>::uninit(); 4 * MAX_HIDDEN];
    let acc = if t.blocked {
        // Blocked weights (a RAM image): x and h in natural order, as words of value pairs.
        let lo = |v: i16| v as u16 as u32;
        let mut xw = [0u32; MAX_INPUT.div_ceil(4) * 2];
        for (w, p) in xw.iter_mut().zip(x.chunks(2)) {
            *w = lo(p[0]) | lo(p.get(1).copied().unwrap_or(0)) << 16;
        }
        let xn = (t.hh_offset / 2).min(xw.len());
        let hv = t.row_len.saturating_sub(t.hh_offset).min(MAX_HIDDEN);
        // h is word-aligned in the repr(C, align(4)) state; entries past H are 0. The copy
        // (never needed for the aligned state) is initialised only where it is used: zeroing
        // it every step cost about 270 cycles on the M4.
        let hcopy: [u32; MAX_HIDDEN / 2];
        let hw: &[u32] = match bytemuck::try_cast_slice(&state.h[..hv]) {
            Ok(w) => w,
            Err(_) => {
                let h = &state.h[..hv];
                hcopy = core::array::from_fn(|i| {
                    let at = |k: usize| h.get(k).copied().unwrap_or(0);
                    lo(at(2 * i)) | lo(at(2 * i + 1)) << 16
                });
                &hcopy[..hv / 2]
            }
        };
        lstm_block_sums(
            t.weights,
            stride,
            t.hh_offset,
            &xw[..xn],
            hw,
            &mut acc[..rows],
        )
    } else {
        // x and h in the dot kernel's lane order, zero-padded to whole groups of 4 (the
        // weights' padding meets zeros, so the sums equal the plain dot products over I and H
        // terms). Written by the permutation, so not zeroed first.
        let mut xbuf = [MaybeUninit::<u32>::uninit(); MAX_INPUT.div_ceil(4) * 2];
        let xp = permute_q15_uninit(x, &mut xbuf);
        let mut hbuf = [MaybeUninit::<u32>::uninit(); MAX_HIDDEN / 2];
        let hp = permute_q15_uninit(&state.h[..hn], &mut hbuf);
        lstm_gate_sums(t.weights, stride, t.hh_offset, xp, hp, &mut acc[..rows])
    };
    // Pass 1, row by row: each gate's activation (Q0.15) replaces its x sum. Rows 2H..3H are
    // the cell candidate g (tanh); the others are sigmoid gates.
    let (sig_if, rest) = acc.split_at_mut((2 * hn).min(rows));
    let (cand, sig_o) = rest.split_at_mut(hn.min(rest.len()));
    let params = |from: usize| t.rows.get(from..).unwrap_or(&[]);
    // A RAM image's rows are folded (validated by the blob parser).
    let gates = if t.blocked {
        gate_activations_folded
    } else {
        gate_activations
    };
    gates(sig_if, params(0), false);
    gates(cand, params(2 * hn), true);
    gates(sig_o, params(3 * hn), false);
    // Pass 2, unit by unit: the cell update from the four gates i, f, g, o.
    let k = CellShifts::new(t.cell_frac_bits);
    if rows == 4 * hn {
        // Every row present (always, for a validated blob).
        cell_update(acc, hn, state, k);
    } else {
        // Some rows missing (inconsistent tensors): their gates are 0.
        let (c, h) = (&mut state.c[..hn], &mut state.h[..hn]);
        for (j, (c, h)) in c.iter_mut().zip(h.iter_mut()).enumerate() {
            let g = |n: usize| acc.get(n * hn + j).map_or(0, |a| a[0] as i16);
            cell_unit(k, [g(0), g(1), g(2), g(3)], c, h);
        }
    }
}

/// The cell update of units 0..hn (at most [`MAX_HIDDEN`]) from the gate activations
/// `gates[g·hn + j][0]` (gate order i, f, g, o; the low 16 bits count): in assembly
/// ([`crate::dsp::lstm_cell_update`]) where it runs, else [`cell_update_portable`].
pub fn cell_update(gates: &[[i32; 2]], hn: usize, state: &mut LstmState, k: CellShifts) {
    let table = interval_table(true);
    if !lstm_cell_update(gates, hn, &mut state.h, &mut state.c, k.kernel(), table) {
        cell_update_portable(gates, hn, state, k);
    }
}

/// The reference of [`cell_update`], all in Rust. Units without four gates are left alone.
pub fn cell_update_portable(gates: &[[i32; 2]], hn: usize, state: &mut LstmState, k: CellShifts) {
    let hn = hn.min(MAX_HIDDEN);
    let g = |n: usize| gates.get(n * hn..).unwrap_or(&[]);
    let (ai, af, ag, ao) = (g(0), g(1), g(2), g(3));
    let units = ai.iter().zip(af).zip(ag).zip(ao);
    let (c, h) = (&mut state.c[..hn], &mut state.h[..hn]);
    for ((((i, f), g), o), (c, h)) in units.zip(c.iter_mut().zip(h.iter_mut())) {
        cell_unit(k, [i[0], f[0], g[0], o[0]].map(|v| v as i16), c, h);
    }
}

/// `a[0] = f(requant(p, a[0], a[1]))` for each row's sums `a` and parameters `p`, f = σ or
/// tanh (`tanh`): a gate's activations (Q0.15) from its rows' dot products. Runs in assembly
/// ([`crate::dsp::lstm_gate_rows`]) where it can; the rows it leaves (a requantisation shift
/// outside 33..=62, or every row on other targets) are done here, one at a time.
pub fn gate_activations(acc: &mut [[i32; 2]], p: &[LstmRowParams], tanh: bool) {
    let table = interval_table(tanh);
    let mut r = 0;
    loop {
        let (a, q) = (
            acc.get_mut(r..).unwrap_or(&mut []),
            p.get(r..).unwrap_or(&[]),
        );
        r += lstm_gate_rows(a, q, table);
        let (Some(a), Some(q)) = (acc.get_mut(r), p.get(r)) else {
            break;
        };
        a[0] = activation::lookup(table, requant(q, a[0], a[1])) as i32;
        r += 1;
    }
}

/// [`gate_activations`] for folded rows ([`fold_row`]: a RAM image's): `a[0] =
/// f(requant_folded(p, a[0], a[1]))`, in assembly ([`crate::dsp::lstm_gate_rows_folded`]) where
/// it runs, else [`gate_activations_folded_portable`]. Rows not in the folded form (d outside
/// 1..=30, |C| over [`FOLDED_ADDEND_MAX`]) give unspecified activations.
pub fn gate_activations_folded(acc: &mut [[i32; 2]], p: &[LstmRowParams], tanh: bool) {
    if !lstm_gate_rows_folded(acc, p, interval_table(tanh)) {
        gate_activations_folded_portable(acc, p, tanh);
    }
}

/// The reference of [`gate_activations_folded`], all in Rust.
pub fn gate_activations_folded_portable(acc: &mut [[i32; 2]], p: &[LstmRowParams], tanh: bool) {
    let f = if tanh { self::tanh } else { sigmoid };
    for (a, p) in acc.iter_mut().zip(p) {
        a[0] = f(requant_folded(p, a[0], a[1])) as i32;
    }
}

/// The reference of [`gate_activations`], all in Rust.
pub fn gate_activations_portable(acc: &mut [[i32; 2]], p: &[LstmRowParams], tanh: bool) {
    let f = if tanh { self::tanh } else { sigmoid };
    for (a, p) in acc.iter_mut().zip(p) {
        a[0] = f(requant(p, a[0], a[1])) as i32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_to_q12_forms_agree() {
        for cb in 1..=15 {
            let k = CellShifts::new(cb);
            for c in i16::MIN..=i16::MAX {
                let shifts = sat_i16((((c as i32) << k.up) + k.half) >> k.down);
                let asm_form = sat_i16((c as i32 * k.q_mul + k.q_add) >> 3);
                assert_eq!(shifts, asm_form, "C = {cb}, c = {c}");
            }
        }
    }

    #[test]
    fn folded_rows_requantise_as_the_blob_rows() {
        let mut x = 0x2545_F491u32;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let edges = [0, 1, -1, i32::MAX, i32::MIN, 1 << 28, -(1 << 28)];
        let (mut folded, mut refused) = (0, 0);
        for shift in 1..=62 {
            for k in 0..4000 {
                let pick = |r: u32, bits: u32| -> i32 {
                    let v = if k < 49 {
                        edges[(r % 7) as usize]
                    } else {
                        r as i32
                    };
                    v >> (32 - bits)
                };
                let p = LstmRowParams {
                    mx: pick(next(), 32),
                    mh: pick(next(), 32),
                    bias_q12: pick(next(), 1 + next() % 32),
                    shift,
                };
                let Some(f) = fold_row(&p) else {
                    refused += 1;
                    let k = shift - 33;
                    let c = (1i64 << k.clamp(0, 40)) + p.bias_q12 as i64 * (2i64 << k.clamp(0, 40));
                    assert!(
                        !(0..30).contains(&k) || c.abs() > FOLDED_ADDEND_MAX,
                        "{p:?}"
                    );
                    continue;
                };
                folded += 1;
                assert!((1..=30).contains(&f.shift), "{p:?}");
                let (ax, ah) = (pick(next(), 27), pick(next(), 30));
                let z = ax as i64 * p.mx as i64 + ah as i64 * p.mh as i64;
                assert_eq!(
                    requant_folded(&f, ax, ah),
                    requant_wide(&p, z),
                    "{p:?} {ax} {ah}"
                );
            }
        }
        assert!(folded > 50_000 && refused > 100_000, "{folded} {refused}");
    }

    #[test]
    fn requant_fast_path_equals_wide_definition() {
        let mut x = 0x9E37_79B9u32;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let edges = [0, 1, -1, i32::MAX, i32::MIN, 1 << 28, -(1 << 28)];
        for shift in 1..=62 {
            for k in 0..4000 {
                // A random or an edge value, within `bits` bits (the admitted ranges).
                let pick = |r: u32, bits: u32| -> i32 {
                    let v = if k < 49 {
                        edges[(r % 7) as usize]
                    } else {
                        r as i32
                    };
                    v >> (32 - bits)
                };
                let p = LstmRowParams {
                    mx: pick(next(), 31).wrapping_abs(),
                    mh: pick(next(), 31).wrapping_abs(),
                    bias_q12: pick(next(), 1 + next() % 32),
                    shift,
                };
                let (ax, ah) = (pick(next(), 27), pick(next(), 30));
                let z = ax as i64 * p.mx as i64 + ah as i64 * p.mh as i64;
                assert_eq!(requant(&p, ax, ah), requant_wide(&p, z), "{p:?} {ax} {ah}");
            }
        }
    }
}
