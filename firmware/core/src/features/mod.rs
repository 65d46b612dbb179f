//! Features: what the LSTM sees at each step, in feature order `[force, d(t), bands…]`.
//!
//! - force x(t): the sample in Q1.15;
//! - d(t) = x(t) - x(t-1) (paper eq. 3), Q1.15 saturated to [-1, 1), optional;
//! - STFT band magnitudes |X_k| / Σw, Q1.15 ([`stft`]).
//!
//! Each feature is then normalised, `(v - μ) / σ` in Q3.12 (saturated at ±8σ), with μ and σ
//! from training; the normalisation is part of the model so that int16 inputs keep their
//! resolution whatever the feature's natural scale (band magnitudes are ~100× smaller than the
//! force). [`Variant::LstmStftLstm`](crate::blob::Variant) feeds `[force, d(t)]` to its first LSTM
//! and the bands to its second.

pub mod hand;
pub mod stft;

use crate::MAX_INPUT;
use crate::fixed::{round_shift_i64, sat_i16, sat_i16_wide};
use bytemuck::{Pod, Zeroable};
use stft::{StftPlan, StftState};

/// Most STFT bands a model may use.
pub const MAX_BANDS: usize = 16;

/// Which features a model uses, derived from its header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FeatureLayout {
    /// The force sample is a feature.
    pub force: bool,
    /// d(t) is a feature.
    pub diff: bool,
    /// Number of STFT bands.
    pub bands: usize,
}

impl FeatureLayout {
    /// Features per step.
    pub fn len(&self) -> usize {
        self.force as usize + self.diff as usize + self.bands
    }
    /// Whether there are no features at all (never for a valid model).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Per-channel feature state: the STFT window and the previous sample for d(t).
#[derive(Clone, Debug)]
pub struct FeatureState {
    /// STFT ring buffer.
    pub stft: StftState,
    /// x(t-1), Q1.15; 0 after reset.
    pub prev: i16,
}

impl FeatureState {
    /// A state as after `reset`.
    pub const fn new() -> Self {
        Self {
            stft: StftState::new(),
            prev: 0,
        }
    }
    /// Forgets the past (grasp start).
    pub fn reset(&mut self) {
        self.stft.reset();
        self.prev = 0;
    }
}

impl Default for FeatureState {
    fn default() -> Self {
        Self::new()
    }
}

/// Computes the raw features of one step (Q1.15 each) into `raw[..layout.len()]`.
/// `plan` is `None` when the layout has no bands.
#[inline]
pub fn raw_features(
    layout: FeatureLayout,
    plan: Option<&StftPlan>,
    state: &mut FeatureState,
    x_q15: i16,
    raw: &mut [i16; MAX_INPUT],
) {
    let mut n = 0;
    if layout.force {
        raw[n] = x_q15;
        n += 1;
    }
    if layout.diff {
        raw[n] = sat_i16(x_q15 as i32 - state.prev as i32);
        n += 1;
    }
    state.prev = x_q15;
    if let Some(plan) = plan {
        let end = (n + layout.bands).min(MAX_INPUT);
        plan.step(&mut state.stft, x_q15, &mut raw[n..end]);
    }
}

/// Per-feature normalisation: `norm_q12 = sat16(round((x_q15 - mean_q15) · gain / 2^shift))`,
/// i.e. (x - μ) / σ in Q3.12 with gain / 2^shift = 1 / (8σ) (σ in Q1.15 input units).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct FeatureNorm {
    /// μ, Q1.15 (an `i32` so that the subtraction cannot overflow).
    pub mean_q15: i32,
    /// Mantissa of 1 / (8σ).
    pub gain: i32,
    /// Exponent of 1 / (8σ), 1..=62.
    pub shift: i32,
}

/// Normalises features in place: Q1.15 → Q3.12 `(v - μ) / σ`, saturated: the numbers of
/// [`normalise_portable`], without 64-bit shifts by a variable amount (a library-free but long
/// sequence on the M4, about 60 instructions a feature).
#[inline]
pub fn normalise(norm: &[FeatureNorm], v: &mut [i16]) {
    for (x, n) in v.iter_mut().zip(norm) {
        *x = normalise_one(n, *x);
    }
}

/// One feature of [`normalise`]: `sat16(⌊(d + 2^(s-1)) / 2^s⌋)` with d = (x − μ)·gain and
/// s = `shift` (1..=62, validated at parse), as ⌊q / 2⌋ plus q's lowest bit with
/// q = ⌊d / 2^(s-1)⌋ (adding 2^(s-1) carries into bit s exactly when bit s − 1 is set): for
/// s ≥ 33 from d's high word alone (⌊d / 2^(s-1)⌋ = ⌊⌊d / 2^32⌋ / 2^(s-33)⌋), else from the
/// 64-bit d shifted by less than 32. |d| < 2^63 (the difference within 33 bits, the gain 32),
/// so nothing overflows.
#[inline(always)]
fn normalise_one(n: &FeatureNorm, x: i16) -> i16 {
    let d = (x as i64 - n.mean_q15 as i64) * n.gain as i64;
    let s = n.shift as u32;
    // q = ⌊d / 2^(s-1)⌋, clamped to i32 (beyond it the result saturates either way: |q / 2| ≥
    // 2^30); the result ⌊q / 2⌋ + (q & 1).
    let q = if s > 32 && s <= 62 {
        ((d >> 32) as i32) >> ((s - 33) & 31)
    } else if (1..=32).contains(&s) {
        let q = d >> ((s - 1) & 31);
        q.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    } else {
        return sat_i16_wide(round_shift_i64(d, s));
    };
    sat_i16((q >> 1) + (q & 1))
}

/// The definition of [`normalise`]: round, shift and saturate in `i64`.
pub fn normalise_portable(norm: &[FeatureNorm], v: &mut [i16]) {
    for (x, n) in v.iter_mut().zip(norm) {
        // i64: the difference spans 33 bits and the gain up to 32; shift validated 1..=62 at parse.
        let d = (*x as i64 - n.mean_q15 as i64) * n.gain as i64;
        *x = sat_i16_wide(round_shift_i64(d, n.shift as u32));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`normalise`] against its definition over every shift, random and extreme means,
    /// gains and inputs.
    #[test]
    fn normalise_equals_its_definition() {
        let mut r = 0x243F_6A88u32;
        let mut next = move || {
            r ^= r << 13;
            r ^= r >> 17;
            r ^= r << 5;
            r
        };
        let edges = [
            0,
            1,
            -1,
            i32::MAX,
            i32::MIN,
            1 << 15,
            -(1 << 15),
            32767,
            -32768,
        ];
        let mut count = 0;
        for shift in 1..=62 {
            for k in 0..3000 {
                let pick = |r: u32, bits: u32| -> i32 {
                    if k < 81 {
                        edges[(r % 9) as usize]
                    } else {
                        (r as i32) >> (32 - bits)
                    }
                };
                let norm = [FeatureNorm {
                    mean_q15: pick(next(), 1 + next() % 32),
                    gain: pick(next(), 1 + next() % 32),
                    shift,
                }];
                let x = pick(next(), 16) as i16;
                let (mut a, mut b) = ([x], [x]);
                normalise(&norm, &mut a);
                normalise_portable(&norm, &mut b);
                assert_eq!(a, b, "{norm:?} x = {x}");
                count += 1;
            }
        }
        assert_eq!(count, 62 * 3000);
    }
}
