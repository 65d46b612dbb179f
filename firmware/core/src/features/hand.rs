//! Hand-level features: what the hand-level LSTM ([`Variant::HandLstm`](crate::blob::Variant))
//! sees at each frame, computed from every contact channel of the hand together rather than
//! from one channel.
//!
//! The per-channel variants see one pad's force; a drop shows first in how the *hand's* load
//! builds during the lift: how fast and how far it grows against the grasp level at the lift,
//! which pad carries it, one pad losing its load while the others still rise, the vibration of
//! the summed load in the 3–5 Hz band (the paper's premise, on the hand's load). Each feature is
//! a ratio of loads, so it does not depend on the object's weight or the sensors' gain.
//!
//! # Inputs
//!
//! Per frame: each channel's model input x_c (Q1.15 in the model's input scale, [`crate::sample`];
//! 1 LSB = 1 mN for the force profile), `None` for a channel out of contact (the contact gate
//! of [`crate::decision::ContactConfig`], as for the per-channel models), and whether the
//! controller's lift command has come since the grasp start. The state restarts at the grasp
//! start. The hand load is L = Σ |x_c| over the channels in contact (i32, at most 16 · 2^15).
//!
//! # Features (feature order; each `i16` Q3.12, +1.0 = 4 096, saturated to [-8, 8))
//!
//! | # | feature | meaning |
//! |---|---|---|
//! | 0 | L / P | load against its peak P since the grasp start |
//! | 1 | L / R | load against the reference R: the load at the lift command (once lifted), else P |
//! | 2 | L / P_w | load against its peak over the last `recent` frames (the load rule's ratio) |
//! | 3–5 | (L − L₋ₖ) / R | change over `diff[i]` frames, against the reference |
//! | 6 | min_c x_c / P_c | the weakest pad against its own peak (pads that ever reached the floor) |
//! | 7 | Σ_c \|s_c − s_c(lift)\| | how far the pads' shares s_c = x_c / L moved since the lift (0 before) |
//! | 8 | n / 16 | channels in contact |
//! | 9 | P / R | peak against the reference (how far the load grew after the lift) |
//! | 10 | mean \|ΔL\| / R | mean absolute frame-to-frame change over the last `vib` frames |
//! | 11–13 | L / L₋ₖ | growth over `growth[i]` frames (denominator at least the floor) |
//! | 14 | max_c x_c / L | the largest pad's share |
//! | 15 | Σ_band \|X_k\| / Σ \|X_k\| | share of the 3–5 Hz bins in the STFT of L (the blob's STFT setting) |
//! | 16 | lifted | 1.0 once the lift command came, else 0 |
//!
//! Denominators below the *floor* (the model's contact threshold in Q1.15 units: 500 mN on the
//! force profile) are raised to it, so a ratio never divides by noise; a ratio whose numerator
//! and denominator are both 0 is 0. Frames before the first one since the grasp start count as
//! the oldest frame seen (the change over 6 frames on the third frame is over 2).
//!
//! The normalisation that follows ([`crate::features::normalise`]) reads every raw feature's
//! `i16` as it stands (a Q1.15 value to the float reference, which sees each feature as
//! value / 2^15: one eighth of the ratio; the normalisation undoes any scale).
//!
//! Integer-only and bit-exact on the host and the Cortex-M4: ratios in `i64` with truncating
//! division, the STFT by [`StftPlan`]. The same function computes the training features on the
//! host, so the float and the quantized model see the same numbers.

use crate::features::stft::{StftPlan, StftState};
use crate::fixed::sat_i16_wide;
use crate::units::Millihertz;

/// Features per frame of the hand-level model.
pub const HAND_FEATURES: usize = 17;
/// Most channels of a hand.
pub const HAND_CHANNELS: usize = 16;
/// Frames of hand load the state keeps (the longest window at 71 Hz is 43 frames).
pub const HAND_RING: usize = 64;
/// Q3.12 one: ratios are stored with 12 fractional bits.
const ONE_Q12: i64 = 1 << 12;

/// The windows of the hand features, in frames at the model's rate: the same durations at every
/// rate (16.7 Hz: change over 1, 3, 6 frames; growth over 3, 6, 10; recent peak 10; vibration
/// 8), derived from the blob's sample rate ([`HandFeatureConfig::for_rate_mhz`]), so the blob
/// stores no extra record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HandFeatureConfig {
    /// Frames of the three load changes (features 3–5): 0.06, 0.18, 0.36 s.
    pub diff: [u8; 3],
    /// Frames of the three growth ratios (features 11–13): 0.18, 0.36, 0.6 s.
    pub growth: [u8; 3],
    /// Frames of the recent peak (feature 2): 0.6 s, the load rule's default window.
    pub recent: u8,
    /// Frame-to-frame changes averaged by feature 10: 0.48 s.
    pub vib: u8,
    /// Floor of every denominator, Q1.15 input units (the contact threshold; ≥ 1).
    pub floor_q15: i32,
    /// STFT output bins (indices into the plan's `n_bins` outputs) in the 3–5 Hz band:
    /// `band.0..band.1`, possibly empty (then feature 15 is 0).
    pub band: (u8, u8),
}

/// `seconds` at `rate` in whole frames, rounded, 1..=[`HAND_RING`] − 1.
const fn frames(seconds_ms: u32, rate: Millihertz) -> u8 {
    // rate.0 mHz · ms / 10^6 = frames; + 500 000 rounds to nearest.
    let f = (seconds_ms as u64 * rate.0 as u64 + 500_000) / 1_000_000;
    let max = (HAND_RING - 1) as u64;
    (if f < 1 {
        1
    } else if f > max {
        max
    } else {
        f
    }) as u8
}

impl HandFeatureConfig {
    /// The windows at `rate`, the floor `floor_q15` and the 3–5 Hz bins of an STFT with
    /// `window_len` samples whose outputs start at bin `first_bin` (`n_bins` of them).
    pub const fn for_rate_mhz(
        rate: Millihertz,
        floor_q15: i32,
        window_len: u8,
        first_bin: u8,
        n_bins: u8,
    ) -> Self {
        // Bin k is centred on k · rate / N; the band is the bins with 3 000 ≤ centre ≤ 5 000 mHz.
        let n = if window_len == 0 {
            1
        } else {
            window_len as u64
        };
        let (mut lo, mut hi) = (n_bins, n_bins);
        let mut b = 0u8;
        while b < n_bins {
            let centre = (first_bin as u64 + b as u64) * rate.0 as u64 / n;
            if centre >= 3_000 && centre <= 5_000 {
                if lo == n_bins {
                    lo = b;
                }
                hi = b + 1;
            }
            b += 1;
        }
        if lo == n_bins {
            hi = lo;
        }
        Self {
            diff: [frames(60, rate), frames(180, rate), frames(360, rate)],
            growth: [frames(180, rate), frames(360, rate), frames(600, rate)],
            recent: frames(600, rate),
            vib: frames(480, rate),
            floor_q15: if floor_q15 < 1 { 1 } else { floor_q15 },
            band: (lo, hi),
        }
    }
}

/// What the hand features remember between frames (about 0.3 KiB; no heap).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HandFeatureState {
    /// The last [`HAND_RING`] hand loads L (Q1.15 units), a ring.
    loads: [i32; HAND_RING],
    /// Ring index of the next load.
    next: u8,
    /// Loads stored since the grasp start (saturates at [`HAND_RING`]).
    filled: u8,
    /// Peak of L since the grasp start.
    peak: i32,
    /// Each pad's peak |x_c| since the grasp start.
    pad_peak: [i32; HAND_CHANNELS],
    /// L at the lift command (at least the floor); 0 before it.
    lift_load: i32,
    /// Each pad's share x_c / L at the lift command, Q0.15.
    lift_share_q15: [i32; HAND_CHANNELS],
    /// The STFT window of L / 16 (Q1.15).
    stft: StftState,
}

impl HandFeatureState {
    /// The state at grasp start: nothing seen.
    pub const fn new() -> Self {
        Self {
            loads: [0; HAND_RING],
            next: 0,
            filled: 0,
            peak: 0,
            pad_peak: [0; HAND_CHANNELS],
            lift_load: 0,
            lift_share_q15: [0; HAND_CHANNELS],
            stft: StftState::new(),
        }
    }

    /// The load `back` frames ago (0 = this frame), or the oldest one stored.
    fn load_back(&self, back: usize) -> i32 {
        let filled = self.filled as usize;
        if filled == 0 {
            return 0;
        }
        let back = back.min(filled - 1);
        let newest = (self.next as usize + HAND_RING - 1) % HAND_RING;
        self.loads[(newest + HAND_RING - back) % HAND_RING]
    }
}

impl Default for HandFeatureState {
    fn default() -> Self {
        Self::new()
    }
}

/// a / b in Q3.12, truncated toward zero and saturated (b ≥ 1: callers floor it).
fn ratio_q12(a: i64, b: i64) -> i16 {
    // a·2^12 < 2^19 · 2^12 · 2^6 (sums of 64 loads at most): far inside i64.
    sat_i16_wide(a * ONE_Q12 / b.max(1))
}

/// One frame's hand features into `out` (Q3.12, feature order of the module docs).
///
/// `x[c]` is channel c's model input (Q1.15), `None` out of contact; channels past
/// [`HAND_CHANNELS`] are ignored. `lifted` says whether the lift command has come since the
/// grasp start (the first frame with it fixes the lift reference). `plan` is the blob's STFT.
pub fn hand_features(
    cfg: &HandFeatureConfig,
    plan: &StftPlan,
    st: &mut HandFeatureState,
    x: &[Option<i16>],
    lifted: bool,
    out: &mut [i16; HAND_FEATURES],
) {
    let floor = cfg.floor_q15.max(1) as i64;
    let mut pad = [0i32; HAND_CHANNELS];
    let mut n_contact = 0i64;
    for (p, v) in pad.iter_mut().zip(x) {
        if let Some(v) = v {
            *p = (*v as i32).abs();
            n_contact += 1;
        }
    }
    // At most 16 · 2^15 = 2^19: fits an i32.
    let load: i32 = pad.iter().sum();
    let i = st.next as usize % HAND_RING;
    st.loads[i] = load;
    st.next = ((i + 1) % HAND_RING) as u8;
    st.filled = st.filled.saturating_add(1).min(HAND_RING as u8);
    st.peak = st.peak.max(load);
    for (pp, &p) in st.pad_peak.iter_mut().zip(&pad) {
        *pp = (*pp).max(p);
    }
    if lifted && st.lift_load == 0 {
        st.lift_load = (load as i64).max(floor) as i32;
        for (s, &p) in st.lift_share_q15.iter_mut().zip(&pad) {
            // x_c / L in Q0.15 (≤ 2^15: x_c ≤ L); 0 with no load.
            *s = if load > 0 {
                ((p as i64) << 15) as i32 / load
            } else {
                0
            };
        }
    }
    let l = load as i64;
    let peak = (st.peak as i64).max(floor);
    let reference = if st.lift_load > 0 {
        st.lift_load as i64
    } else {
        peak
    };
    let recent = (0..cfg.recent.max(1) as usize)
        .map(|k| st.load_back(k))
        .max()
        .unwrap_or(0) as i64;

    out[0] = ratio_q12(l, peak);
    out[1] = ratio_q12(l, reference);
    out[2] = ratio_q12(l, recent.max(floor));
    for (o, &k) in out[3..6].iter_mut().zip(&cfg.diff) {
        *o = ratio_q12(l - st.load_back(k as usize) as i64, reference);
    }
    // The weakest pad among those that ever carried the floor: 1.0 when there is none.
    out[6] = pad
        .iter()
        .zip(&st.pad_peak)
        .filter(|&(_, &pp)| pp as i64 >= floor)
        .map(|(&p, &pp)| ratio_q12(p as i64, pp as i64))
        .min()
        .unwrap_or(ONE_Q12 as i16);
    out[7] = if st.lift_load > 0 {
        // Σ |share − share at lift| in Q0.15 (≤ 2 · 2^15), >> 3 to Q3.12.
        let moved: i64 = pad
            .iter()
            .zip(&st.lift_share_q15)
            .map(|(&p, &s0)| {
                let s = if load > 0 { ((p as i64) << 15) / l } else { 0 };
                (s - s0 as i64).abs()
            })
            .sum();
        sat_i16_wide(moved >> 3)
    } else {
        0
    };
    // n / 16 in Q3.12: n · 2^12 / 2^4 = n << 8.
    out[8] = sat_i16_wide(n_contact << 8);
    out[9] = ratio_q12(peak, reference);
    let vib = cfg.vib.max(1) as usize;
    let change: i64 = (0..vib)
        .map(|k| (st.load_back(k) as i64 - st.load_back(k + 1) as i64).abs())
        .sum();
    out[10] = ratio_q12(change / vib as i64, reference);
    for (o, &k) in out[11..14].iter_mut().zip(&cfg.growth) {
        *o = ratio_q12(l, (st.load_back(k as usize) as i64).max(floor));
    }
    let largest = pad.iter().copied().max().unwrap_or(0) as i64;
    out[14] = if load > 0 { ratio_q12(largest, l) } else { 0 };
    // The STFT of L / 16 (16 channels of Q1.15 sum to < 2^19: >> 4 keeps it in an i16).
    let mut bins = [0i16; crate::features::MAX_BANDS];
    let n_bins = (plan.config().n_bins as usize).min(bins.len());
    plan.step(&mut st.stft, sat_i16_wide(l >> 4), &mut bins[..n_bins]);
    let all: i64 = bins[..n_bins].iter().map(|&b| b as i64).sum();
    let (lo, hi) = (cfg.band.0 as usize, (cfg.band.1 as usize).min(n_bins));
    let band: i64 = bins
        .get(lo..hi)
        .map_or(0, |b| b.iter().map(|&v| v as i64).sum());
    out[15] = if all > 0 { ratio_q12(band, all) } else { 0 };
    out[16] = if lifted { ONE_Q12 as i16 } else { 0 };
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::stft::StftConfig;

    const RATE: Millihertz = Millihertz(16_700);

    fn cfg() -> HandFeatureConfig {
        HandFeatureConfig::for_rate_mhz(RATE, 500, 20, 1, 10)
    }

    #[test]
    fn windows_keep_their_durations_at_every_rate() {
        let c = cfg();
        assert_eq!(c.diff, [1, 3, 6]);
        assert_eq!(c.growth, [3, 6, 10]);
        assert_eq!((c.recent, c.vib), (10, 8));
        // 16.7 Hz, 20 samples: bins 1..=10 at 0.835 k Hz; 3–5 Hz is bins 4 and 5 (outputs 3, 4).
        assert_eq!(c.band, (3, 5));
        let c40 = HandFeatureConfig::for_rate_mhz(Millihertz(40_000), 500, 20, 1, 10);
        assert_eq!(c40.diff, [2, 7, 14]);
        assert_eq!((c40.recent, c40.band), (24, (1, 2)));
        let c71 = HandFeatureConfig::for_rate_mhz(Millihertz(71_000), 500, 20, 1, 10);
        assert_eq!((c71.recent, c71.band), (43, (0, 1)));
        // A band no bin falls in is empty.
        let none = HandFeatureConfig::for_rate_mhz(Millihertz(200_000), 500, 20, 1, 10);
        assert_eq!(none.band.0, none.band.1);
    }

    /// Against a reference written from the table above in f64 over a whole made-up grasp:
    /// three pads load up, the lift comes, one pad lets go while the others rise.
    #[test]
    fn features_are_the_ratios_of_the_table() {
        let c = cfg();
        let plan = StftPlan::new(StftConfig::PAPER).unwrap();
        let mut st = HandFeatureState::new();
        let mut loads: std::vec::Vec<f64> = std::vec::Vec::new();
        let mut pads_seen: std::vec::Vec<[f64; 3]> = std::vec::Vec::new();
        let lift_at = 12;
        let mut lift_ref = None;
        let mut lift_share = [0.0; 3];
        for t in 0..30usize {
            let a = (400 * t) as i16;
            let b = if t < 20 { (300 * t) as i16 } else { 200 };
            let cc = (150 * t) as i16;
            let x = [Some(a), None, Some(-b), Some(cc)];
            let lifted = t >= lift_at;
            let mut out = [0i16; HAND_FEATURES];
            hand_features(&c, &plan, &mut st, &x, lifted, &mut out);
            let p = [a as f64, b as f64, cc as f64];
            let l: f64 = p.iter().sum();
            loads.push(l);
            pads_seen.push(p);
            let floor = 500.0;
            let peak = loads.iter().copied().fold(0.0, f64::max).max(floor);
            if lifted && lift_ref.is_none() {
                lift_ref = Some(l.max(floor));
                for k in 0..3 {
                    lift_share[k] = ((p[k] * 32768.0) / l).floor();
                }
            }
            let r = lift_ref.unwrap_or(peak);
            let back = |k: usize| loads[t.saturating_sub(k)];
            let q = |v: f64| (v * 4096.0).trunc().clamp(-32768.0, 32767.0) as i16;
            let recent = (0..10).map(back).fold(0.0, f64::max).max(floor);
            assert_eq!(out[0], q(l / peak), "t {t} f0");
            assert_eq!(out[1], q(l / r), "t {t} f1");
            assert_eq!(out[2], q(l / recent), "t {t} f2");
            for (i, k) in [1, 3, 6].into_iter().enumerate() {
                assert_eq!(out[3 + i], q((l - back(k)) / r), "t {t} f{}", 3 + i);
            }
            let weakest = (0..3)
                .filter(|&k| pads_seen.iter().map(|s| s[k]).fold(0.0, f64::max) >= floor)
                .map(|k| p[k] / pads_seen.iter().map(|s| s[k]).fold(0.0, f64::max))
                .fold(f64::INFINITY, f64::min);
            let want6 = if weakest.is_finite() {
                q(weakest)
            } else {
                4096
            };
            assert_eq!(out[6], want6, "t {t} f6");
            if lift_ref.is_some() {
                let moved: f64 = (0..3)
                    .map(|k| (((p[k] * 32768.0) / l).floor() - lift_share[k]).abs())
                    .sum();
                assert_eq!(out[7], (moved / 8.0).floor() as i16, "t {t} f7");
            } else {
                assert_eq!(out[7], 0);
            }
            // Three channels in contact: 3/16 = 768 in Q3.12.
            assert_eq!(out[8], 3 * 256);
            assert_eq!(out[9], q(peak / r), "t {t} f9");
            let change: f64 = (0..8).map(|k| (back(k) - back(k + 1)).abs()).sum();
            assert_eq!(out[10], q((change / 8.0).trunc() / r), "t {t} f10");
            for (i, k) in [3, 6, 10].into_iter().enumerate() {
                assert_eq!(out[11 + i], q(l / back(k).max(floor)), "t {t} f{}", 11 + i);
            }
            let largest = p.iter().copied().fold(0.0, f64::max);
            let want14 = if l > 0.0 { q(largest / l) } else { 0 };
            assert_eq!(out[14], want14, "t {t} f14");
            assert_eq!(out[16], if lifted { 4096 } else { 0 });
        }
    }

    /// The band share against an f64 DFT of the hand load: a 4.2 Hz wobble on a steady load puts
    /// most of the non-DC energy into the 3–5 Hz bins, a slow ramp puts little there.
    #[test]
    fn band_share_follows_the_load_spectrum() {
        let c = cfg();
        let plan = StftPlan::new(StftConfig::PAPER).unwrap();
        let run = |f: &dyn Fn(usize) -> f64| {
            let mut st = HandFeatureState::new();
            let mut out = [0i16; HAND_FEATURES];
            let mut hist = std::vec::Vec::new();
            for t in 0..40 {
                let v = f(t);
                hist.push((v / 16.0).floor());
                hand_features(&c, &plan, &mut st, &[Some(v as i16)], true, &mut out);
            }
            // Reference: |X_k| of the last 20 values (L / 16) for k = 1..=10.
            let w = &hist[hist.len() - 20..];
            let mag = |k: usize| {
                let (mut re, mut im) = (0.0, 0.0);
                for (n, &x) in w.iter().enumerate() {
                    let a = 2.0 * std::f64::consts::PI * (k * n) as f64 / 20.0;
                    re += x * a.cos();
                    im += x * a.sin();
                }
                (re * re + im * im).sqrt()
            };
            let all: f64 = (1..=10).map(mag).sum();
            let band = mag(4) + mag(5);
            (out[15] as f64 / 4096.0, band / all)
        };
        let wobble = |t: usize| {
            12_000.0 + 3_000.0 * (2.0 * std::f64::consts::PI * 4.175 * t as f64 / 16.7).sin()
        };
        let (got, want) = run(&wobble);
        assert!(want > 0.7, "{want}");
        assert!((got - want).abs() < 0.02, "wobble: {got} vs {want}");
        let (got, want) = run(&|t| 400.0 * t as f64);
        assert!(want < 0.3, "{want}");
        assert!((got - want).abs() < 0.02, "ramp: {got} vs {want}");
    }

    #[test]
    fn nothing_in_contact_gives_zero_loads_and_no_division_by_zero() {
        let c = cfg();
        let plan = StftPlan::new(StftConfig::PAPER).unwrap();
        let mut st = HandFeatureState::new();
        let mut out = [1i16; HAND_FEATURES];
        for _ in 0..5 {
            hand_features(&c, &plan, &mut st, &[None; 16], true, &mut out);
        }
        assert_eq!(out[0], 0);
        assert_eq!(out[6], 4096);
        assert_eq!(out[14], 0);
        assert_eq!(out[15], 0);
        // Full-scale pads on all 16 channels saturate ratios instead of overflowing.
        let full = [Some(i16::MIN); 16];
        hand_features(&c, &plan, &mut st, &full, true, &mut out);
        assert_eq!(out[13], i16::MAX);
    }
}
