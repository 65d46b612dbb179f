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

use crate::activation::{sigmoid, tanh};
use crate::blob::{LstmRowParams, LstmTensors};
use crate::dsp::{dot_rows_i8_q15, permute_q15};
use crate::fixed::{round_shift_i32, round_shift_i64, sat_i16, sat_i16_wide};
use crate::{MAX_HIDDEN, MAX_INPUT};

/// One LSTM's recurrent state for one channel.
#[derive(Clone, Debug, PartialEq, Eq)]
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

impl Default for LstmState {
    fn default() -> Self {
        Self::new()
    }
}

/// Gate pre-activation of one row, Q3.12.
#[inline(always)]
fn requant(p: &LstmRowParams, acc_x: i32, acc_h: i32) -> i16 {
    // i64: acc_x < 2^26 and acc_h < 2^29 times a multiplier < 2^31 stay below 2^61.
    let z = acc_x as i64 * p.mx as i64 + acc_h as i64 * p.mh as i64;
    let shift = p.shift as u32;
    if (33..=62).contains(&shift) {
        // The same bits in 32-bit arithmetic (no variable 64-bit shift on the M4):
        // ⌊(z + 2^(s-1)) / 2^s⌋ = ⌊(⌊z / 2^(s-1)⌋ + 1) / 2⌋, and as s - 1 ≥ 32,
        // ⌊z / 2^(s-1)⌋ = ⌊hi / 2^(s-33)⌋ with hi = ⌊z / 2^32⌋. (t >> 1) + (t & 1) is
        // ⌊(t + 1) / 2⌋ without overflow; a saturating add before the i16 saturation gives the
        // same result as the wide add.
        let t = ((z >> 32) as i32) >> (shift - 33);
        sat_i16(((t >> 1) + (t & 1)).saturating_add(p.bias_q12))
    } else {
        requant_wide(p, z)
    }
}

/// [`requant`]'s definition: round, add the bias and saturate in `i64`.
#[inline(always)]
fn requant_wide(p: &LstmRowParams, z: i64) -> i16 {
    sat_i16_wide(round_shift_i64(z, p.shift as u32) + p.bias_q12 as i64)
}

/// Cell state Q(15-C).C → Q3.12 for tanh, saturated (tanh is flat beyond ±8 anyway).
#[inline(always)]
fn cell_to_q12(c: i16, cell_frac_bits: u32) -> i16 {
    if cell_frac_bits > 12 {
        // Drop the extra fractional bits, rounded.
        round_shift_i32(c as i32, cell_frac_bits - 12) as i16
    } else {
        // Fewer fractional bits: scale up; C >= 1 so the shift is at most 11 and fits i32.
        sat_i16((c as i32) << (12 - cell_frac_bits))
    }
}

/// Advances `state` by one step with input `x` (Q3.12, `t.inputs` values).
///
/// `t` comes from a validated [`crate::blob::ModelBlob`], so its sizes are within the static
/// bounds; slices are still taken with checked ranges, so a wrong size can only give wrong
/// numbers, never a panic.
pub fn step(t: &LstmTensors<'_>, state: &mut LstmState, x: &[i16]) {
    let hn = t.hidden.min(MAX_HIDDEN);
    let x = &x[..t.inputs.min(x.len())];
    // x and h in the dot kernel's lane order, zero-padded to whole groups of 4 (the weights'
    // padding meets zeros, so the sums equal the plain dot products over I and H terms).
    let mut xp = [0u32; MAX_INPUT.div_ceil(4) * 2];
    let xw = permute_q15(x, &mut xp);
    let mut hp = [0u32; MAX_HIDDEN / 2];
    let hw = permute_q15(&state.h[..hn], &mut hp);
    let stride = t.row_len.max(1);
    let rows = (4 * hn).min(t.rows.len()).min(t.weights.len() / stride);
    let w_hh = t.weights.get(t.hh_offset..).unwrap_or(&[]);
    // Gate activations, Q0.15, in order i, f, g, o.
    let mut gates = [0i16; 4 * MAX_HIDDEN];
    // One gate (H rows) at a time keeps the accumulators small on the stack.
    let chunk = hn.max(1);
    let mut acc_x = [0i32; MAX_HIDDEN];
    let mut acc_h = [0i32; MAX_HIDDEN];
    let mut r0 = 0;
    while r0 < rows {
        let n = chunk.min(rows - r0);
        let off = r0 * stride;
        dot_rows_i8_q15(
            t.weights.get(off..).unwrap_or(&[]),
            stride,
            &xp[..xw],
            &mut acc_x[..n],
        );
        dot_rows_i8_q15(
            w_hh.get(off..).unwrap_or(&[]),
            stride,
            &hp[..hw],
            &mut acc_h[..n],
        );
        // Rows 2H..3H are the cell candidate g (tanh); the others are sigmoid gates.
        let is_g = r0 / chunk == 2;
        for (((g, p), &ax), &ah) in gates[r0..r0 + n]
            .iter_mut()
            .zip(&t.rows[r0..r0 + n])
            .zip(&acc_x[..n])
            .zip(&acc_h[..n])
        {
            let z = requant(p, ax, ah);
            *g = if is_g { tanh(z) } else { sigmoid(z) };
        }
        r0 += n;
    }
    let cb = t.cell_frac_bits;
    // i·g is Q0.30; shifting by 30 - C puts it in the cell's Q(15-C).C.
    let ig_shift = 30 - cb.clamp(1, 15);
    for j in 0..hn {
        let (i, f, g, o) = (
            gates[j],
            gates[hn + j],
            gates[2 * hn + j],
            gates[3 * hn + j],
        );
        // f·c: Q0.15 × Q(15-C).C, >> 15 keeps the cell's format.
        let fc = round_shift_i32(f as i32 * state.c[j] as i32, 15);
        let ig = round_shift_i32(i as i32 * g as i32, ig_shift);
        let c = sat_i16(fc + ig);
        state.c[j] = c;
        // o·tanh(c): Q0.15 × Q0.15 >> 15 = Q0.15.
        state.h[j] = sat_i16(round_shift_i32(
            o as i32 * tanh(cell_to_q12(c, cb)) as i32,
            15,
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
