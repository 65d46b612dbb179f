//! Anti-alias filter and decimation by [`RATIO`]: a 64-tap linear-phase FIR low-pass (Kaiser
//! window, β = 5, cut-off 0.45 × the output rate; the taps are designed at compile time by
//! [`design_lowpass_q15`]), evaluated in polyphase form so that each channel keeps only
//! [`PHASES`] accumulators instead of a 64-sample history.
//!
//! Response, relative to the output (model) rate f_out, computed by the tests in this module:
//! gain 0 dB at DC exactly (taps sum to 2^15), −0.6 dB at 0.18 f_out (3 Hz at 16.7 Hz),
//! −2.0 dB at 0.3 f_out (5 Hz), −8 dB at 0.5 f_out (Nyquist); everything that would fold onto
//! 0…0.18 f_out (input above 0.82 f_out) is attenuated by at least 40 dB, everything folding onto
//! 0…0.3 f_out by at least 22 dB. Group delay (64 − 1) / 2 input samples = 1.97 output periods
//! (118 ms at 16.7 Hz, 49 ms at 40 Hz): a deliberate trade of alias rejection for latency in a
//! slip detector. Output unit: 1/16 ADC count (the oversampling buys the 4 extra bits).

use slipguard_core::const_math;

/// Input samples per output sample (ADC scan rate / model rate).
pub const RATIO: usize = 16;
/// Filter length.
pub const TAPS: usize = 64;
/// Outputs each input contributes to (TAPS / RATIO).
pub const PHASES: usize = TAPS / RATIO;
/// Fractional bits of the taps.
pub const TAP_BITS: u32 = 15;
/// Fractional bits of the output relative to the input (output = counts · 2^OUT_FRAC_BITS).
pub const OUT_FRAC_BITS: u32 = 4;

/// Shape parameter β of the Kaiser window the taps are designed with.
pub const KAISER_BETA: f64 = 5.0;
/// Cut-off of the windowed sinc (its −6 dB point), as the fraction
/// `CUTOFF_NUM / CUTOFF_DEN` = 0.45 of the output rate f_out.
pub const CUTOFF_NUM: u32 = 9;
/// See [`CUTOFF_NUM`].
pub const CUTOFF_DEN: u32 = 20;

/// The taps, Q0.15, symmetric, summing to exactly 32768 (unity DC gain), computed at compile
/// time by [`design_lowpass_q15`] from [`TAPS`], [`RATIO`], [`KAISER_BETA`] and the cut-off.
pub const FIR: [i32; TAPS] = design_lowpass_q15();

/// Windowed-sinc low-pass: h[n] = sinc(2·f_c·(n − (TAPS − 1)/2)) · kaiser(n, β) with
/// f_c = (CUTOFF_NUM / CUTOFF_DEN) / RATIO cycles per input sample, normalised to unit sum,
/// rounded to Q0.15; the rounding residue (if any) goes to the two centre taps, half each, so the
/// taps still sum to exactly 2^15 and stay symmetric.
pub const fn design_lowpass_q15() -> [i32; TAPS] {
    // The sinc's argument, 2·f_c·(n − (TAPS − 1)/2) = CUTOFF_NUM·(2n − (TAPS − 1)) /
    // (CUTOFF_DEN·RATIO): a ratio of integers, so the angle is reduced exactly.
    let den = CUTOFF_DEN * RATIO as u32;
    let mut h = [0f64; TAPS];
    let mut sum = 0.0;
    let mut n = 0;
    while n < TAPS {
        let m = CUTOFF_NUM as i64 * (2 * n as i64 - (TAPS as i64 - 1));
        h[n] = const_math::sinc_ratio(m, den) * const_math::kaiser(n, TAPS, KAISER_BETA);
        sum += h[n];
        n += 1;
    }
    let one = (1i32 << TAP_BITS) as f64;
    let mut q = [0i32; TAPS];
    let mut total = 0i32;
    let mut n = 0;
    while n < TAPS {
        q[n] = const_math::round(h[n] / sum * one) as i32;
        total += q[n];
        n += 1;
    }
    // A symmetric even-length filter sums pairs, so the residue is even: half on each centre tap.
    let residue = (1i32 << TAP_BITS) - total;
    q[TAPS / 2 - 1] += residue / 2;
    q[TAPS / 2] += residue - residue / 2;
    q
}

/// One channel's polyphase decimator state (36 bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Decimator {
    /// Partial sums of the next [`PHASES`] outputs; `acc[(m + j) % PHASES]` is output m + j.
    acc: [i64; PHASES],
    /// Position of the next input inside its output block, 0..RATIO.
    phase: u8,
    /// Index (mod PHASES) of the output the current block completes.
    slot: u8,
}

impl Decimator {
    /// A decimator whose history is all zeros.
    pub const fn new() -> Self {
        Self {
            acc: [0; PHASES],
            phase: 0,
            slot: 0,
        }
    }

    /// Sets the history to a constant `x` (as if `x` had been sampled forever), so that the
    /// first outputs are not a ramp from zero.
    pub fn prime(&mut self, x: i32) {
        *self = Self::new();
        for _ in 0..(PHASES - 1) * RATIO {
            let _ = self.push(x);
        }
    }

    /// Feeds one input sample; returns an output (1/16 counts) every [`RATIO`] inputs.
    /// y[m] = Σ_k h[k]·x[(m+1)·R − 1 − k].
    #[inline]
    pub fn push(&mut self, x: i32) -> Option<i32> {
        let p = self.phase as usize;
        let x = x as i64;
        for j in 0..PHASES {
            let k = (j + 1) * RATIO - 1 - p;
            let slot = (self.slot as usize + j) % PHASES;
            self.acc[slot] += FIR[k] as i64 * x;
        }
        if p + 1 < RATIO {
            self.phase += 1;
            return None;
        }
        self.phase = 0;
        let s = self.slot as usize;
        let acc = core::mem::take(&mut self.acc[s]);
        self.slot = ((s + 1) % PHASES) as u8;
        let shift = TAP_BITS - OUT_FRAC_BITS;
        // Round half up; |acc| < 2^16·2^15·1.1, so the result fits i32 by far.
        Some(((acc + (1 << (shift - 1))) >> shift) as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gain_db(f_over_fout: f64) -> f64 {
        let w = 2.0 * core::f64::consts::PI * f_over_fout / RATIO as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for (k, &h) in FIR.iter().enumerate() {
            re += h as f64 * (w * k as f64).cos();
            im -= h as f64 * (w * k as f64).sin();
        }
        20.0 * ((re * re + im * im).sqrt() / 32768.0).log10()
    }

    /// The same design computed independently: `f64::sin` for the sinc, the Kaiser window's
    /// I0 by numerical integration of (1/π)∫₀^π e^(z·cos θ) dθ.
    fn reference_taps() -> (Vec<f64>, Vec<i32>) {
        use std::f64::consts::PI;
        let i0 = |z: f64| {
            let steps = 4000;
            let mut acc = 0.0;
            for j in 0..=steps {
                let w = if j == 0 || j == steps { 0.5 } else { 1.0 };
                acc += w * (z * (PI * j as f64 / steps as f64).cos()).exp();
            }
            acc / steps as f64
        };
        let fc = CUTOFF_NUM as f64 / CUTOFF_DEN as f64 / RATIO as f64;
        let mid = (TAPS - 1) as f64 / 2.0;
        let h: Vec<f64> = (0..TAPS)
            .map(|n| {
                let x = 2.0 * fc * (n as f64 - mid);
                let sinc = if x == 0.0 {
                    1.0
                } else {
                    (PI * x).sin() / (PI * x)
                };
                let r = (n as f64 - mid) / mid;
                sinc * i0(KAISER_BETA * (1.0 - r * r).sqrt()) / i0(KAISER_BETA)
            })
            .collect();
        let sum: f64 = h.iter().sum();
        let scaled: Vec<f64> = h.iter().map(|v| v / sum * 32768.0).collect();
        let rounded = scaled.iter().map(|v| v.round() as i32).collect();
        (scaled, rounded)
    }

    #[test]
    fn taps_match_an_independent_design() {
        let (scaled, rounded) = reference_taps();
        // No tap sits near a rounding boundary, so the two computations must round alike.
        let margin = scaled
            .iter()
            .map(|v| ((v - v.floor()) - 0.5).abs())
            .fold(f64::MAX, f64::min);
        println!("decimator taps: closest to a rounding boundary by {margin:.3} LSB");
        assert!(margin > 0.01, "{margin}");
        assert_eq!(
            rounded.iter().sum::<i32>(),
            1 << TAP_BITS,
            "no residue expected"
        );
        assert_eq!(FIR.to_vec(), rounded);
    }

    #[test]
    fn taps_are_symmetric_with_unity_dc_gain() {
        assert_eq!(FIR.iter().sum::<i32>(), 1 << TAP_BITS);
        for k in 0..TAPS {
            assert_eq!(FIR[k], FIR[TAPS - 1 - k]);
        }
    }

    #[test]
    fn response_meets_the_documented_figures() {
        let g3 = gain_db(0.18);
        let g5 = gain_db(0.3);
        let gn = gain_db(0.5);
        // Worst gain of frequencies folding onto 0..0.18 and 0..0.3 of f_out.
        let worst = |from: f64| {
            (0..=8000)
                .map(|i| from + (RATIO as f64 / 2.0 - from) * i as f64 / 8000.0)
                .map(gain_db)
                .fold(f64::MIN, f64::max)
        };
        let a18 = worst(1.0 - 0.18);
        let a30 = worst(1.0 - 0.3);
        println!(
            "decimator: {g3:.2} dB @0.18 f_out, {g5:.2} dB @0.3, {gn:.2} dB @0.5; \
             folding onto 0..0.18 ≤ {a18:.1} dB, onto 0..0.3 ≤ {a30:.1} dB"
        );
        assert!(gain_db(0.0).abs() < 1e-9);
        assert!(g3 > -0.7 && g5 > -2.1 && gn < -6.0);
        assert!(a18 < -40.0, "{a18}");
        assert!(a30 < -22.0, "{a30}");
    }

    #[test]
    fn polyphase_equals_direct_convolution_and_dc_is_exact() {
        let mut x: u32 = 99;
        let input: Vec<i32> = (0..RATIO * 40)
            .map(|_| {
                x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
                ((x >> 16) % 4096) as i32
            })
            .collect();
        let mut d = Decimator::new();
        let out: Vec<i32> = input.iter().filter_map(|&v| d.push(v)).collect();
        assert_eq!(out.len(), 40);
        for (m, &y) in out.iter().enumerate() {
            let mut acc = 0i64;
            for (k, &h) in FIR.iter().enumerate() {
                let i = (m as i64 + 1) * RATIO as i64 - 1 - k as i64;
                if i >= 0 {
                    acc += h as i64 * input[i as usize] as i64;
                }
            }
            assert_eq!(y as i64, (acc + 1024) >> 11, "output {m}");
        }
        let mut d = Decimator::new();
        d.prime(3000);
        for _ in 0..5 {
            let y: Vec<i32> = (0..RATIO).filter_map(|_| d.push(3000)).collect();
            assert_eq!(y, [3000 << OUT_FRAC_BITS]);
        }
    }
}
