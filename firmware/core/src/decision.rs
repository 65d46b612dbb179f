//! Decision: dense layer to two logits, p(unstable) in Q0.15, and the flag with hysteresis.

use crate::activation::sigmoid;
use crate::blob::{DenseTensors, ModelConfig};
use crate::dsp::dot_i8_i16_fast;
use crate::fixed::{round_shift_i64, sat_i16_wide};

/// p(unstable) = softmax(logits)[1] = σ(l1 - l0), Q0.15, from the concatenated hidden states
/// `hs` (each Q0.15, one slice per LSTM, of the LSTM's true hidden size).
pub fn p_unstable(dense: &DenseTensors<'_>, hs: &[&[i16]]) -> i16 {
    let mut logit = [0i64; 2];
    for (l, (row, p)) in logit.iter_mut().zip(
        dense
            .weights
            .chunks_exact(dense.row_len.max(1))
            .zip(dense.rows),
    ) {
        let mut acc = 0i64;
        let mut off = 0;
        for h in hs {
            // Each LSTM's slice of the row starts at a multiple of 4 (rows are padded per LSTM).
            let seg = row.get(off..).unwrap_or(&[]);
            acc += dot_i8_i16_fast(seg, h) as i64;
            off += crate::blob::pad4(h.len());
        }
        // acc·m: acc < 2^30 (256 terms of 2^22), m < 2^31; shift validated 1..=62 at parse.
        *l = round_shift_i64(acc * p.m as i64, p.shift as u32) + p.bias_q12 as i64;
    }
    // Logit difference in Q3.12, saturated to ±8 where σ is within 3.4e-4 of 0 or 1.
    sigmoid(sat_i16_wide(logit[1] - logit[0]))
}

/// A probability or threshold in Q0.15: `/// Q0.15, +1.0 = 32 768` (so the largest value, 32 767,
/// is 1 − 2⁻¹⁵). The one converter between f64 and the fixed-point p(unstable) and thresholds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Q15(pub i16);

impl Q15 {
    /// +1.0 in Q0.15.
    pub const ONE: f64 = 32_768.0;

    /// `x` rounded to the nearest Q0.15 value (halves away from zero), saturated to the i16 range
    /// (so 1.0 becomes 32 767).
    pub const fn from_f64(x: f64) -> Self {
        let v = crate::const_math::round(x * Self::ONE);
        Q15(if v >= i16::MAX as f64 {
            i16::MAX
        } else if v <= i16::MIN as f64 {
            i16::MIN
        } else {
            v as i16
        })
    }

    /// The value as f64 (exact).
    pub const fn to_f64(self) -> f64 {
        self.0 as f64 / Self::ONE
    }

    /// The model header's threshold field: clamped to 1…32 767, the range a blob's threshold must
    /// have to parse (0 would flag every step).
    pub const fn header_threshold(self) -> u16 {
        if self.0 < 1 { 1 } else { self.0 as u16 }
    }
}

/// Threshold and hysteresis of the unstable flag.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecisionConfig {
    /// p(unstable) at or above which a step counts as unstable, Q0.15.
    pub threshold_q15: i16,
    /// Consecutive unstable steps before the flag rises (1 = no hysteresis).
    pub raise_after: u8,
    /// Consecutive stable steps before the flag clears (1 = no hysteresis).
    pub clear_after: u8,
}

impl DecisionConfig {
    /// The decision settings of a model's header.
    pub fn of(config: &ModelConfig) -> Self {
        Self {
            threshold_q15: config.threshold_q15.min(i16::MAX as u16) as i16,
            raise_after: config.raise_after.max(1),
            clear_after: config.clear_after.max(1),
        }
    }

    /// Feeds one step's p(unstable) and returns the flag.
    pub fn update(&self, s: &mut DecisionState, p_q15: i16) -> bool {
        if p_q15 >= self.threshold_q15 {
            s.run_below = 0;
            s.run_above = s.run_above.saturating_add(1);
            if s.run_above >= self.raise_after {
                s.unstable = true;
            }
        } else {
            s.run_above = 0;
            s.run_below = s.run_below.saturating_add(1);
            if s.run_below >= self.clear_after {
                s.unstable = false;
            }
        }
        s.unstable
    }
}

/// The flag's per-channel state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecisionState {
    /// Current flag.
    pub unstable: bool,
    /// Consecutive steps at or above the threshold.
    pub run_above: u8,
    /// Consecutive steps below the threshold.
    pub run_below: u8,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hysteresis_counts_consecutive_steps() {
        let d = DecisionConfig {
            threshold_q15: 16384,
            raise_after: 3,
            clear_after: 2,
        };
        let mut s = DecisionState::default();
        let p = [
            20000, 20000, 10000, 20000, 20000, 20000, 10000, 20000, 10000, 10000,
        ];
        let want = [
            false, false, false, false, false, true, true, true, true, false,
        ];
        for (i, (&p, &w)) in p.iter().zip(&want).enumerate() {
            assert_eq!(d.update(&mut s, p), w, "step {i}");
        }
        // Exactly at the threshold counts as unstable.
        let d1 = DecisionConfig {
            threshold_q15: 16384,
            raise_after: 1,
            clear_after: 1,
        };
        let mut s = DecisionState::default();
        assert!(d1.update(&mut s, 16384));
        assert!(!d1.update(&mut s, 16383));
    }
}
