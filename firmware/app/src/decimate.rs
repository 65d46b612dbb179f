//! Anti-alias filter and decimation by [`RATIO`]: a 64-tap linear-phase FIR low-pass (Kaiser
//! window, β = 5, cut-off 0.45 × the output rate), evaluated in polyphase form so that each
//! channel keeps only [`PHASES`] accumulators instead of a 64-sample history.
//!
//! Response, relative to the output (model) rate f_out, computed by the tests in this module:
//! gain 0 dB at DC exactly (taps sum to 2^15), −0.6 dB at 0.18 f_out (3 Hz at 16.7 Hz),
//! −2.0 dB at 0.3 f_out (5 Hz), −8 dB at 0.5 f_out (Nyquist); everything that would fold onto
//! 0…0.18 f_out (input above 0.82 f_out) is attenuated by at least 40 dB, everything folding onto
//! 0…0.3 f_out by at least 22 dB. Group delay (64 − 1) / 2 input samples = 1.97 output periods
//! (118 ms at 16.7 Hz, 49 ms at 40 Hz): a deliberate trade of alias rejection for latency in a
//! slip detector. Output unit: 1/16 ADC count (the oversampling buys the 4 extra bits).

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

/// The taps, Q0.15, symmetric, summing to exactly 32768 (unity DC gain). Generated with numpy:
/// `h = sinc(2·0.45/16·(n − 31.5))·kaiser(64, 5)`, normalised, rounded, centre taps adjusted.
pub const FIR: [i32; TAPS] = [
    -8, -14, -22, -32, -43, -55, -68, -79, -88, -93, -91, -82, -62, -31, 14, 73, 148, 239, 344,
    464, 596, 737, 885, 1035, 1183, 1326, 1459, 1577, 1676, 1754, 1807, 1835, 1835, 1807, 1754,
    1676, 1577, 1459, 1326, 1183, 1035, 885, 737, 596, 464, 344, 239, 148, 73, 14, -31, -62, -82,
    -91, -93, -88, -79, -68, -55, -43, -32, -22, -14, -8,
];

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
