//! The hand-load rule and the fused hand decision: the rule alone, and the rule as a guard
//! beside the model's hand flag. Its own module because the model blob carries a rule (format
//! v2, [`crate::blob`]) and the decision stage runs it ([`crate::decision`] re-exports it):
//! it needs neither.

/// Largest window of [`LoadRule`], in frames (1.6 s at 40 Hz).
pub const LOAD_WINDOW_MAX: usize = 64;

/// The hand-load rule, a detector that learns nothing: the hand flag is up while the summed
/// load of the channels in contact falls below `fraction` of its peak over the last `window`
/// frames (the current frame included). It is the baseline every learned hand flag is
/// measured against (a threshold on force is today's practice), and it runs in the same
/// decision stage, on the same Q1.15 model inputs and the same contact gate, so that it can
/// be fused with the model's p(unstable).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoadRule {
    /// Share of the recent peak below which the hand flag rises: Q0.15, +1.0 = 32 768
    /// (0.4 = 13 107).
    pub fraction_q15: i16,
    /// Frames the peak looks back over, current frame included (1..=[`LOAD_WINDOW_MAX`];
    /// 10 frames = 0.6 s at 16.7 Hz).
    pub window: u8,
}

impl LoadRule {
    /// The hand's summed load: Σ |x| over the channels in contact (`None` = not in contact),
    /// each Q1.15 in the model's input scale. 16 channels of at most 2^15 fit an i32.
    pub fn hand_load(x: impl IntoIterator<Item = Option<i16>>) -> i32 {
        x.into_iter()
            .flatten()
            .map(|v| (v as i32).saturating_abs())
            .fold(0i32, i32::saturating_add)
    }

    /// Feeds one frame's hand load ([`Self::hand_load`]) and returns the rule's flag: up when
    /// `load < fraction · peak`, the peak being the largest load of the last `window` frames
    /// (this one included); down while the peak is 0 (nothing in contact).
    pub fn update(&self, s: &mut LoadRuleState, load: i32) -> bool {
        let i = s.next as usize % LOAD_WINDOW_MAX;
        s.loads[i] = load.max(0);
        s.next = ((i + 1) % LOAD_WINDOW_MAX) as u8;
        s.filled = s.filled.saturating_add(1).min(LOAD_WINDOW_MAX as u8);
        self.below_peak(s)
    }

    /// Whether the newest load of `s` is below `fraction` of the peak over `window` frames.
    fn below_peak(&self, s: &LoadRuleState) -> bool {
        if s.filled == 0 {
            return false;
        }
        let w = (self.window.max(1) as usize).min(LOAD_WINDOW_MAX);
        let i = (s.next as usize + LOAD_WINDOW_MAX - 1) % LOAD_WINDOW_MAX;
        let n = w.min(s.filled as usize);
        // The last n entries of the ring, ending at i.
        let peak = (0..n)
            .map(|k| s.loads[(i + LOAD_WINDOW_MAX - k) % LOAD_WINDOW_MAX])
            .max()
            .unwrap_or(0);
        // load < f·peak  ⇔  load·2^15 < f_q15·peak (f in Q0.15); both sides < 2^35: i64.
        peak > 0 && ((s.loads[i] as i64) << 15) < self.fraction_q15 as i64 * peak as i64
    }
}

/// The state of [`LoadRule`]: the last [`LOAD_WINDOW_MAX`] hand loads (a ring, no heap).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadRuleState {
    loads: [i32; LOAD_WINDOW_MAX],
    /// Ring index the next load goes to.
    next: u8,
    /// Loads stored so far (saturates at [`LOAD_WINDOW_MAX`]).
    filled: u8,
}

impl LoadRuleState {
    /// No load seen (the state at grasp start).
    pub const fn new() -> Self {
        Self {
            loads: [0; LOAD_WINDOW_MAX],
            next: 0,
            filled: 0,
        }
    }
}

impl Default for LoadRuleState {
    fn default() -> Self {
        Self::new()
    }
}

/// A fused hand decision: the hand-load rule at a strict fraction, OR the model's hand flag
/// while the hand load is below a looser fraction of the same peak (the rule as a guard
/// beside the model: the model's flag counts only while the hand is losing load).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FusedHand {
    /// The rule alone raises the flag below this fraction and window (Q0.15 fraction; 0 =
    /// never).
    pub strict: LoadRule,
    /// The model's flag counts while the load is below this fraction of the peak over
    /// `strict.window` frames: Q0.15, +1.0 = 32 768 (32 767 = any load under the peak, and a
    /// load at the peak is never under it; use [`FusedHand::NO_GUARD`] to let every model
    /// flag through).
    pub guard_q15: i16,
}

impl FusedHand {
    /// `guard_q15` that lets every model flag through.
    pub const NO_GUARD: i16 = i16::MAX;

    /// The model's hand flag alone: no rule (strict fraction 0 never flags), no guard.
    pub const MODEL_ONLY: FusedHand = FusedHand {
        strict: LoadRule {
            fraction_q15: 0,
            window: 1,
        },
        guard_q15: Self::NO_GUARD,
    };

    /// A fraction in Q0.15 as a real (+1.0 = 32 768).
    fn real(q15: i16) -> f64 {
        q15 as f64 / 32_768.0
    }

    /// Feeds one frame: the model's hand flag and the hand load ([`LoadRule::hand_load`]) →
    /// the fused hand flag. One peak serves both fractions.
    pub fn update(&self, s: &mut LoadRuleState, model_flag: bool, load: i32) -> bool {
        let strict = self.strict.update(s, load);
        let guard = self.guard_q15 == Self::NO_GUARD
            || LoadRule {
                fraction_q15: self.guard_q15,
                window: self.strict.window,
            }
            .below_peak(s);
        strict || (model_flag && guard)
    }
}

impl core::fmt::Display for FusedHand {
    /// "rule < 0.40·peak OR (model flag AND load < 0.80·peak), peak over 10 frames" (the guard
    /// reads "any load" for [`FusedHand::NO_GUARD`]).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "rule < {:.2}·peak OR (model flag AND ",
            Self::real(self.strict.fraction_q15)
        )?;
        if self.guard_q15 == Self::NO_GUARD {
            f.write_str("any load")?;
        } else {
            write!(f, "load < {:.2}·peak", Self::real(self.guard_q15))?;
        }
        write!(f, "), peak over {} frames", self.strict.window)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decision::Q15;

    #[test]
    fn load_rule_flags_a_fall_below_the_recent_peak() {
        let r = LoadRule {
            fraction_q15: Q15::from_f64(0.4).0,
            window: 3,
        };
        assert_eq!(
            LoadRule::hand_load([Some(100), None, Some(-50), Some(i16::MIN)]),
            100 + 50 + 32_768
        );
        assert_eq!(LoadRule::hand_load([None, None]), 0);
        let mut s = LoadRuleState::new();
        // An independent reference: the float rule over a slice.
        let loads = [
            0, 0, 1000, 1000, 500, 399, 399, 100, 100, 100, 0, 2000, 801, 800,
        ];
        let mut want = std::vec::Vec::new();
        for t in 0..loads.len() {
            let lo = t.saturating_sub(2);
            let peak = *loads[lo..=t].iter().max().unwrap();
            want.push(peak > 0 && (loads[t] as f64) < 0.4 * peak as f64);
        }
        // By hand: 399 under the peak 1000 flags; 399 under 500 does not; 100 flags while a
        // 399 is in the window and not once only 100s are.
        assert_eq!(&want[4..10], &[false, true, false, true, true, false]);
        for (t, &l) in loads.iter().enumerate() {
            assert_eq!(r.update(&mut s, l), want[t], "step {t}");
        }
        // Strictly below: a load equal to half its peak does not flag.
        let half = LoadRule {
            fraction_q15: 16_384,
            window: 1,
        };
        let mut s = LoadRuleState::new();
        assert!(!half.update(&mut s, 10));
        // A window longer than the ring is the ring.
        let long = LoadRule {
            fraction_q15: 16_384,
            window: 255,
        };
        let mut s = LoadRuleState::new();
        assert!(!long.update(&mut s, 1000));
        for _ in 0..LOAD_WINDOW_MAX - 1 {
            assert!(long.update(&mut s, 499));
        }
        // The 1000 has now left the 64-frame ring.
        assert!(!long.update(&mut s, 499));
    }
    #[test]
    fn fused_hand_is_the_rule_or_a_guarded_model_flag() {
        let f = FusedHand {
            strict: LoadRule {
                fraction_q15: Q15::from_f64(0.4).0,
                window: 4,
            },
            guard_q15: Q15::from_f64(0.8).0,
        };
        let mut s = LoadRuleState::new();
        // (model flag, load) → want: the model's flag passes only under 0.8 of the peak 1000;
        // the rule alone flags under 400.
        let steps = [
            (true, 1000, false),
            (true, 900, false),
            (true, 700, true),
            (false, 700, false),
            (false, 300, true),
            (true, 1000, false),
        ];
        for (t, &(m, l, want)) in steps.iter().enumerate() {
            assert_eq!(f.update(&mut s, m, l), want, "step {t}");
        }
        let open = FusedHand {
            guard_q15: FusedHand::NO_GUARD,
            ..f
        };
        let mut s = LoadRuleState::new();
        assert!(open.update(&mut s, true, 1000));
        assert_eq!(
            f.to_string(),
            "rule < 0.40·peak OR (model flag AND load < 0.80·peak), peak over 4 frames"
        );
        assert_eq!(
            open.to_string(),
            "rule < 0.40·peak OR (model flag AND any load), peak over 4 frames"
        );
    }
}
