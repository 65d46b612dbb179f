//! Decision: dense layer to two logits, p(unstable) in Q0.15, and the flag with hysteresis.

use crate::blob::{DenseTensors, ModelConfig};
use crate::dsp::dot_i8_i16_fast;
use crate::dsp::sigmoid;
use crate::fixed::{round_shift_i64, sat_i16_wide};
use crate::units::Millihertz;

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

/// Contact detection on a channel's model input: a channel is in contact once its load
/// |x| has stayed at or above `on_q15` for `on_after` consecutive steps, and leaves contact
/// once it has stayed below for `off_after` consecutive steps. Only channels in contact are
/// run through the model and may raise the hand flag; the model's state restarts from zero
/// at each contact onset, so the first step the LSTM sees is the onset step (training
/// sequences start at the same step: `slipguard-data`'s sequences use this detector).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ContactConfig {
    /// Load at or above which a step counts as loaded: Q1.15 in the model's input scale
    /// (x = (raw − offset)/full_scale; 500 mN at full scale 32 768 mN is 500).
    pub on_q15: i16,
    /// Consecutive loaded steps before contact begins (≥ 1).
    pub on_after: u8,
    /// Consecutive unloaded steps before contact ends (≥ 1).
    pub off_after: u8,
}

impl ContactConfig {
    /// Contact threshold for force sensors, mN above the input offset (the labelling rule's).
    pub const FORCE_ON_MN: i32 = 500;
    /// Contact threshold for pressure sensors, converter counts away from the input offset.
    pub const PRESSURE_ON_COUNTS: i32 = 1500;
    /// Loaded steps before contact begins at the paper's rate (0.18 s at 16.7 Hz).
    pub const ON_SECONDS: f32 = 0.18;
    /// Unloaded steps before contact ends (0.6 s: a one-step dip while regripping keeps it).
    pub const OFF_SECONDS: f32 = 0.6;

    /// The contact rule for `scale` with a threshold of `on_raw` sensor units away from the
    /// offset and the run lengths in steps.
    pub fn new(
        scale: &crate::sample::InputScale,
        on_raw: i32,
        on_after: u8,
        off_after: u8,
    ) -> Self {
        let on = scale.to_q15(scale.offset.saturating_add(on_raw.saturating_abs()));
        Self {
            on_q15: on.max(1),
            on_after: on_after.max(1),
            off_after: off_after.max(1),
        }
    }

    /// The default rule of a model: [`Self::FORCE_ON_MN`] or [`Self::PRESSURE_ON_COUNTS`] by the
    /// model's input unit, run lengths [`Self::ON_SECONDS`] and [`Self::OFF_SECONDS`] at its rate.
    pub fn of(config: &ModelConfig) -> Self {
        let on_raw = match config.input_unit {
            crate::blob::InputUnit::MilliNewton => Self::FORCE_ON_MN,
            _ => Self::PRESSURE_ON_COUNTS,
        };
        Self::new(
            &crate::sample::InputScale::of(config),
            on_raw,
            steps_for(Self::ON_SECONDS, config.sample_rate_mhz),
            steps_for(Self::OFF_SECONDS, config.sample_rate_mhz),
        )
    }

    /// Feeds one step's input (Q1.15) and says whether the channel is in contact, and whether
    /// contact began at this step.
    pub fn update(&self, s: &mut ContactState, x_q15: i16) -> ContactEdge {
        let loaded = x_q15.saturating_abs() >= self.on_q15;
        if loaded {
            s.run_off = 0;
            s.run_on = s.run_on.saturating_add(1);
        } else {
            s.run_on = 0;
            s.run_off = s.run_off.saturating_add(1);
        }
        match (s.contact, loaded) {
            (false, true) if s.run_on >= self.on_after => {
                s.contact = true;
                ContactEdge::Began
            }
            (true, false) if s.run_off >= self.off_after => {
                s.contact = false;
                ContactEdge::Ended
            }
            (true, _) => ContactEdge::Holding,
            _ => ContactEdge::Idle,
        }
    }
}

/// `seconds` at `rate` in whole steps, rounded, 1..=255.
fn steps_for(seconds: f32, rate: Millihertz) -> u8 {
    // rate.0 / 1000 = steps per second; + 0.5 rounds to nearest.
    let steps = seconds * rate.0 as f32 / 1000.0 + 0.5;
    (steps as u32).clamp(1, u8::MAX as u32) as u8
}

/// What [`ContactConfig::update`] saw at one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ContactEdge {
    /// No contact.
    Idle,
    /// Contact began at this step (the model's state restarts here).
    Began,
    /// In contact (also the steps of a dip shorter than `off_after`).
    Holding,
    /// Contact ended at this step.
    Ended,
}

impl ContactEdge {
    /// Whether the channel is in contact at this step (and so runs the model).
    pub fn in_contact(self) -> bool {
        matches!(self, ContactEdge::Began | ContactEdge::Holding)
    }
}

/// A channel's contact state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ContactState {
    /// In contact.
    pub contact: bool,
    /// Consecutive loaded steps.
    pub run_on: u8,
    /// Consecutive unloaded steps.
    pub run_off: u8,
}

impl ContactState {
    /// No contact, no runs.
    pub const fn new() -> Self {
        Self {
            contact: false,
            run_on: 0,
            run_off: 0,
        }
    }
}

/// The hand-level decision: one flag per frame from the channels in contact. The hand's
/// p(unstable) is the `k`-th largest p among the channels in contact (k = 1: the largest;
/// with fewer than `k` channels in contact, the smallest of them), 0 with no channel in
/// contact, and the hand flag is that p through threshold and hysteresis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HandConfig {
    /// Which largest p among the contact channels counts (1..=16).
    pub k: u8,
    /// Threshold and hysteresis of the hand flag.
    pub decision: DecisionConfig,
}

impl HandConfig {
    /// The hand decision of a model: k = 1 and the model's own threshold and hysteresis.
    pub fn of(config: &ModelConfig) -> Self {
        Self {
            k: 1,
            decision: DecisionConfig::of(config),
        }
    }

    /// The hand's p(unstable), Q0.15, from each channel's p (`None` = not in contact).
    pub fn hand_p(&self, p: impl IntoIterator<Item = Option<i16>>) -> i16 {
        // The k largest values seen so far, largest first (k ≤ 16: a fixed array, no heap).
        let k = (self.k.max(1) as usize).min(TOP_K_MAX);
        let mut top = [i16::MIN; TOP_K_MAX];
        let mut n = 0usize;
        for v in p.into_iter().flatten() {
            let v = v.max(0);
            n += 1;
            // Insert v into top[..k], keeping it sorted descending.
            let mut i = k.min(n) - 1;
            if n > k && v <= top[k - 1] {
                continue;
            }
            while i > 0 && top[i - 1] < v {
                top[i] = top[i - 1];
                i -= 1;
            }
            top[i] = v;
        }
        match n {
            0 => 0,
            n => top[k.min(n) - 1],
        }
    }

    /// Feeds one frame: each channel's p (`None` = not in contact) → the hand output.
    pub fn update(
        &self,
        s: &mut DecisionState,
        p: impl IntoIterator<Item = Option<i16>>,
    ) -> HandOutput {
        let p_q15 = self.hand_p(p);
        HandOutput {
            p_unstable_q15: p_q15,
            unstable: self.decision.update(s, p_q15),
        }
    }
}

/// Largest `k` of [`HandConfig`].
pub const TOP_K_MAX: usize = 16;

/// The hand decision of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HandOutput {
    /// The hand's p(unstable), Q0.15.
    pub p_unstable_q15: i16,
    /// The hand flag after threshold and hysteresis.
    pub unstable: bool,
}

pub use crate::load_rule::{FusedHand, LOAD_WINDOW_MAX, LoadRule, LoadRuleState};

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

    #[test]
    fn contact_needs_a_run_and_survives_a_short_dip() {
        let c = ContactConfig {
            on_q15: 500,
            on_after: 3,
            off_after: 2,
        };
        let mut s = ContactState::new();
        let x = [0, 600, 700, -800, 100, 900, 0, 0, 0, 700];
        use ContactEdge::*;
        let want = [
            Idle, Idle, Idle, Began, Holding, Holding, Holding, Ended, Idle, Idle,
        ];
        for (i, (&x, &w)) in x.iter().zip(&want).enumerate() {
            assert_eq!(c.update(&mut s, x), w, "step {i}");
        }
    }

    #[test]
    fn contact_threshold_in_sensor_units() {
        let scale = crate::sample::InputScale {
            offset: 0,
            full_scale: 32_768,
        };
        assert_eq!(ContactConfig::new(&scale, 500, 3, 10).on_q15, 500);
        let p = crate::sample::InputScale {
            offset: 6400,
            full_scale: 4096,
        };
        // 1500 counts of 4096 → 1500·8 = 12 000 in Q1.15.
        assert_eq!(ContactConfig::new(&p, -1500, 3, 10).on_q15, 12_000);
        assert_eq!(steps_for(0.18, Millihertz(16_667)), 3);
        assert_eq!(steps_for(0.6, Millihertz(16_667)), 10);
        assert_eq!(steps_for(0.6, Millihertz(40_000)), 24);
        assert_eq!(steps_for(1000.0, Millihertz(40_000)), 255);
    }

    #[test]
    fn hand_p_is_the_kth_largest_of_the_contact_channels() {
        let d = DecisionConfig {
            threshold_q15: 10_000,
            raise_after: 1,
            clear_after: 1,
        };
        let p = [
            Some(3000),
            None,
            Some(20_000),
            Some(9000),
            None,
            Some(12_000),
        ];
        // An independent reference: sort the contact channels' p descending.
        let mut sorted: std::vec::Vec<i16> = p.iter().flatten().copied().collect();
        sorted.sort_by(|a, b| b.cmp(a));
        for k in 1..=6u8 {
            let h = HandConfig { k, decision: d };
            let want = sorted[(k as usize).min(sorted.len()) - 1];
            assert_eq!(h.hand_p(p), want, "k {k}");
        }
        let h = HandConfig { k: 1, decision: d };
        assert_eq!(h.hand_p([None, None]), 0);
        assert_eq!(h.hand_p([]), 0);
        // Without contact, a high p cannot raise the hand flag.
        let mut s = DecisionState::default();
        assert!(!h.update(&mut s, [None, None]).unstable);
        assert!(h.update(&mut s, [None, Some(10_000)]).unstable);
        assert!(!h.update(&mut s, [Some(9999)]).unstable);
    }
}
