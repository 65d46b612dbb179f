//! Sliding short-time Fourier transform: one force sample in, `n_bins` band magnitudes out.
//!
//! Every step pushes one sample (hop 1, as in the paper, section III.A) and computes
//!
//! ```text
//! X_k = Σ_{n=0}^{N-1} w(n) · x(t-N+1+n) · e^{-j2πkn/N},   out_k = |X_k| / Σ_n w(n)
//! ```
//!
//! over the last `N = window_len` samples, oldest first (samples not yet received since
//! [`StftState::reset`] count as 0), for `k = first_bin .. first_bin + n_bins`. The output is in
//! [0, 1]: a full-scale sinusoid centred on bin k (0 < k < N/2) gives 1/2, a full-scale constant
//! gives 1 in bin 0.
//!
//! # Why bins 1..=10 of a 20-point DFT
//!
//! The paper samples the force at 16.7 Hz and uses a 20-sample rectangular window, so bin k is
//! centred on k · 16.7 / 20 = k · 0.835 Hz. Bins 1..=10 span 0.835..8.35 Hz: they cover the
//! 3–5 Hz band where the paper separates slip from stable grasps (bins 4, 5, 6 = 3.34, 4.18,
//! 5.01 Hz) and bin 10 is the Nyquist frequency, so the 10 bands are every non-redundant bin
//! but DC. DC is left out because it is the (window-averaged) force level itself, which the
//! model already gets as its force input. [`StftConfig::PAPER`] is that setting; other windows,
//! bin ranges and a Hann window are there for experiments.
//!
//! # Why a direct DFT
//!
//! Only `n_bins` bins are needed and `N` is small: 2 · 10 · 20 = 400 multiply-accumulates per
//! step for the paper, next to the LSTM's ~71k. A recursive sliding DFT would be cheaper, but
//! in fixed point its rounding errors accumulate without bound; the direct sum recomputes every
//! bin from the stored window, so the error is bounded and a state never drifts.
//!
//! # Fixed-point formats
//!
//! | quantity | type | format |
//! |---|---|---|
//! | input sample x, ring buffer | `i16` | Q1.15 |
//! | window w(n) | `i32` | Q2.30, 1.0 = 2^30 (rectangular: exact) |
//! | twiddles cos, sin of 2π(m + 1/8)/N | `i16` | Q1.15 (never ±1, see below) |
//! | windowed sample x·w | `i32` | Q2.30, \|x·w\| <= w <= 1 |
//! | accumulators Re, Im | `i64` | Q3.45, \|·\| <= Σw · 2^45 < 2^51 |
//! | reduced Re, Im, magnitude | `i64`, `u32` | Re·2^-`acc_shift`, \|·\| <= 2^30 |
//! | `gain` (1/Σw) | `u32` | 2^(L+30) / Σw_q, in [2^30, 2^31] (see [`StftPlan`]) |
//! | output \|X_k\| / Σw | `i16` | Q1.15, [0, 32767] |
//!
//! Only `step` runs on the target at the sample rate and it is integer-only, so it is bit-exact
//! on the host and on the Cortex-M4. `StftPlan::new` uses f64 through [`crate::const_math`],
//! which is bit-identical everywhere too.
//!
//! # Twiddle phase offset
//!
//! The twiddle table holds e^{j2π(m + 1/8)/N} instead of e^{j2πm/N}. That multiplies every X_k by
//! the same unit phase e^{jπ/(4N)}, which leaves |X_k| unchanged, and keeps every entry off ±1
//! for any N: +1.0 is not a Q1.15 value and would saturate to 32767, a 1-LSB twiddle error that
//! (measured with the plain table) pushed the error to 1.5 LSB at DC and 1 LSB at Nyquist.
//!
//! # Error bound
//!
//! Against the exact value y = |X_k| / Σw (real-valued window and twiddles, inputs taken as the
//! exact Q1.15 values), the output satisfies
//!
//! ```text
//! |out - 2^15 · y| <= max(0.5 + 2^15 · τ + 0.001, 1)  <=  1.18 LSB (Q1.15); 1.06 for N = 20
//! ```
//!
//! where 0.5 is the final rounding and τ is the largest twiddle rounding error
//! |(cos_q, sin_q) - e^{jθ}|. The twiddle errors enter as Σ_n x(n) w(n) δ(n) / Σw with |x| <= 1,
//! so they add at most τ; 2^15 · τ <= √2/2 in general and, for the actual tables, <= 0.677 over
//! N = 4..=48 (0.557 for N = 20). The other roundings (Q2.30 window and x·w,
//! accumulator reduction, floor of the square root, 31-bit `gain`) add up to below 2^-12 LSB.
//! The 1 is saturation: an exact 1.0 = 32768 (a full-scale constant at DC, say) gives 32767.
//!
//! Measured by the tests (f64 DFT reference, 2.4·10^5 steps over windows 4, 16, 20, 21, 32, 48,
//! both shapes, random, small, step, sinusoidal and full-scale inputs): max 1.000 LSB (a
//! saturated full-scale DC), 0.96 LSB unsaturated, 0.69 LSB for the paper setting. Against
//! microfft's f32 FFT (N = 16, 32): max difference 1.004 LSB (tolerance: bound + 0.1 LSB).
//!
//! # Cost per step
//!
//! N products x·w (32×32→64, rounded), 2 · `n_bins` · N multiply-accumulates (32×32→64, one
//! `SMLAL` each on the M4) and per bin one magnitude: 2 squares, an exact integer square root
//! (a 256-entry table plus three 32-bit divides) and one multiply. In the release build for
//! thumbv7em the inner loop is ~14 instructions per (bin, sample): three loads, two `SMLAL`,
//! the index wrap and a bounds test. The paper setting (20 samples, 10 bins: 400 MACs, 10
//! square roots) is thus roughly 4k cycles, ~25 µs at 168 MHz.

use crate::const_math::{cos_sin_turn, round};
use crate::features::MAX_BANDS;
use crate::fixed::{round_shift_i64, sat_i16, sat_i16_wide};
use crate::units::Millihertz;

/// Longest STFT window. The per-channel state is a ring buffer of this many `i16` samples,
/// which must stay within 128 bytes.
pub const MAX_WINDOW: usize = 48;

/// Shortest STFT window (a DFT this short has only DC, one band and Nyquist).
pub const MIN_WINDOW: usize = 4;

// The per-channel state must stay within its 128-byte budget.
const _: () = assert!(core::mem::size_of::<StftState>() <= 128);

/// Window applied to the samples before the DFT.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowShape {
    /// w(n) = 1, as in the paper.
    Rectangular = 0,
    /// Periodic (DFT-even) Hann window, w(n) = (1 - cos(2πn/N)) / 2, Σw = N/2.
    Hann = 1,
}

impl TryFrom<u8> for WindowShape {
    type Error = StftError;

    fn try_from(value: u8) -> Result<Self, StftError> {
        match value {
            0 => Ok(WindowShape::Rectangular),
            1 => Ok(WindowShape::Hann),
            other => Err(StftError::UnknownShape(other)),
        }
    }
}

/// Why an [`StftConfig`] or a window shape byte was rejected.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StftError {
    /// `window_len` is below [`MIN_WINDOW`].
    WindowTooShort(u8),
    /// `window_len` is above [`MAX_WINDOW`].
    WindowTooLong(u8),
    /// `n_bins` is 0.
    NoBins,
    /// `n_bins` is above [`MAX_BANDS`].
    TooManyBins(u8),
    /// The last bin, `first_bin + n_bins - 1`, is above the Nyquist bin `window_len / 2`.
    BinAboveNyquist {
        /// `first_bin + n_bins - 1`.
        last_bin: u16,
        /// `window_len / 2`.
        nyquist_bin: u8,
    },
    /// A window shape byte that is not a [`WindowShape`].
    UnknownShape(u8),
}

impl core::fmt::Display for StftError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            StftError::WindowTooShort(n) => {
                write!(f, "STFT window of {n} samples is shorter than {MIN_WINDOW}")
            }
            StftError::WindowTooLong(n) => {
                write!(f, "STFT window of {n} samples is longer than {MAX_WINDOW}")
            }
            StftError::NoBins => write!(f, "STFT has no bins"),
            StftError::TooManyBins(n) => {
                write!(f, "STFT has {n} bins, more than {MAX_BANDS}")
            }
            StftError::BinAboveNyquist {
                last_bin,
                nyquist_bin,
            } => write!(
                f,
                "STFT bin {last_bin} is above the Nyquist bin {nyquist_bin}"
            ),
            StftError::UnknownShape(b) => write!(f, "unknown STFT window shape {b}"),
        }
    }
}

/// What the STFT computes: window length and shape and which bins come out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StftConfig {
    /// Window length N in samples, [`MIN_WINDOW`]..=[`MAX_WINDOW`].
    pub window_len: u8,
    /// First output bin k (bin k is centred on k · f_s / N; 0 is DC).
    pub first_bin: u8,
    /// Number of consecutive output bins, 1..=[`MAX_BANDS`], all at or below N/2.
    pub n_bins: u8,
    /// Window applied before the DFT.
    pub shape: WindowShape,
}

impl StftConfig {
    /// The paper's setting (section III.A): 20-sample rectangular window, bins 1..=10
    /// (0.835..8.35 Hz at 16.7 Hz; see the module docs).
    pub const PAPER: StftConfig = StftConfig {
        window_len: 20,
        first_bin: 1,
        n_bins: 10,
        shape: WindowShape::Rectangular,
    };

    /// The STFT set-up of a model at `rate_mhz`, the one definition the trainer writes into
    /// the blob header (which the firmware then runs): the paper's 20 samples and bins 1..=10 at
    /// every profile rate (16.7 Hz: 1.2 s, 0.835–8.35 Hz; 40 Hz: 0.5 s, 2–20 Hz; 71 Hz: 0.28 s,
    /// 3.55–35.5 Hz). Same samples rather than same seconds: measured at 40 and 71 Hz, the
    /// 1.2 s (48-sample at 40 Hz) window did not detect better across seeds and costs 2.4× the
    /// DFT work per step, and 1.2 s at 71 Hz (85 samples) is over [`MAX_WINDOW`]
    /// (docs/model-format.md, "STFT per rate").
    pub const fn for_rate_mhz(_rate: Millihertz) -> StftConfig {
        Self::PAPER
    }

    /// No STFT: the setting of a variant without bands (validation does not apply).
    pub const NONE: StftConfig = StftConfig {
        window_len: 0,
        first_bin: 0,
        n_bins: 0,
        shape: WindowShape::Rectangular,
    };

    /// Checks `MIN_WINDOW <= window_len <= MAX_WINDOW`, `1 <= n_bins <= MAX_BANDS` and
    /// `first_bin + n_bins - 1 <= window_len / 2`.
    pub const fn validate(&self) -> Result<(), StftError> {
        let n = self.window_len;
        if (n as usize) < MIN_WINDOW {
            return Err(StftError::WindowTooShort(n));
        }
        if n as usize > MAX_WINDOW {
            return Err(StftError::WindowTooLong(n));
        }
        if self.n_bins == 0 {
            return Err(StftError::NoBins);
        }
        if self.n_bins as usize > MAX_BANDS {
            return Err(StftError::TooManyBins(self.n_bins));
        }
        // In u16 so that first_bin + n_bins cannot overflow.
        let last_bin = self.first_bin as u16 + self.n_bins as u16 - 1;
        if last_bin > (n / 2) as u16 {
            return Err(StftError::BinAboveNyquist {
                last_bin,
                nyquist_bin: n / 2,
            });
        }
        Ok(())
    }
}

/// Tables shared by all channels: validated config, twiddles, window and 1/Σw.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StftPlan {
    config: StftConfig,
    /// (cos, sin) of 2π(m + 1/8)/N for m in 0..N, Q1.15 (the offset keeps them off ±1, see the
    /// module docs). Zero beyond N.
    twiddles: [(i16, i16); MAX_WINDOW],
    /// w(n) for n in 0..N (n = 0 is the oldest sample), Q2.30 (1.0 = 2^30). Zero beyond N.
    window: [i32; MAX_WINDOW],
    /// Right shift taking the Q3.45 accumulators to |·| <= 2^30, so that the sum of their
    /// squares fits a u64: L - 15, where S = Σ window (Q2.30) and L = ⌈log2 S⌉.
    acc_shift: u32,
    /// The 1/Σw factor: 2^(L+30) / S rounded, in [2^30, 2^31] (value 2^L/S in [1, 2], Q2.30
    /// unsigned). The reduced magnitude times `gain` >> 45 is the Q1.15 output.
    gain: u32,
    /// For a rectangular window with `n_bins · N` ≤ [`ROW_WORDS`] (the paper's 10 × 20): bin b's
    /// twiddles in sample order, word `b·N + n` = (cos, sin) of index (k·n) mod N as
    /// `cos as u16 | sin << 16` (k = first_bin + b); zero otherwise. The step then reads them in
    /// a row instead of stepping the index modulo N (see [`StftPlan::step`]).
    rows: [u32; ROW_WORDS],
    /// Whether `rows` holds the bins.
    by_rows: bool,
}

/// Words of [`StftPlan`]'s per-bin twiddle rows (1 KiB).
const ROW_WORDS: usize = 256;

/// `x` rounded to Q1.15 (saturated, which the twiddle offset makes unnecessary).
const fn q15(x: f64) -> i16 {
    // ×2^15: Q1.15 has 15 fractional bits.
    sat_i16(round(x * 32768.0) as i32)
}

impl StftPlan {
    /// Validates `config` and builds the twiddle and window tables (f64, runs once; a `const fn`
    /// so a plan can live in flash).
    pub const fn new(config: StftConfig) -> Result<Self, StftError> {
        if let Err(e) = config.validate() {
            return Err(e);
        }
        let n = config.window_len as usize;
        let mut twiddles = [(0i16, 0i16); MAX_WINDOW];
        let mut window = [0i32; MAX_WINDOW];
        // S = Σ window, in Q2.30 units (<= 48 · 2^30 < 2^36).
        let mut sum: u64 = 0;
        let mut m = 0;
        // Over the whole array so indexing is in bounds by construction; entries past N stay 0.
        while m < MAX_WINDOW {
            if m < n {
                // 2π(8m + 1)/(8N): the 1/8-step phase offset.
                let (c, s) = cos_sin_turn(8 * m as u32 + 1, 8 * n as u32);
                twiddles[m] = (q15(c), q15(s));
                let w = match config.shape {
                    WindowShape::Rectangular => 1.0,
                    WindowShape::Hann => 0.5 - 0.5 * cos_sin_turn(m as u32, n as u32).0,
                };
                // ×2^30: the window is Q2.30; w <= 1 so it fits an i32.
                let wq = round(w * (1u64 << 30) as f64) as i32;
                window[m] = wq;
                sum += wq as u64;
            }
            m += 1;
        }
        // Σw >= 2 for every valid window (rectangular N >= 4, Hann N/2 >= 2), so S >= 2^31 and
        // L >= 31 (acc_shift >= 16); the clamp only makes that explicit.
        let sum = if sum < (1 << 31) { 1 << 31 } else { sum };
        let l = 64 - (sum - 1).leading_zeros();
        // |Re| <= S · 2^15 <= 2^(L+15), so >> (L - 15) leaves |Re| <= 2^30.
        let acc_shift = l - 15;
        // 2^(L+30) / S in [2^30, 2^31] since 2^(L-1) < S <= 2^L; u128 because 2^(L+30) can
        // reach 2^66. The +S/2 rounds to nearest.
        let gain = (((1u128 << (l + 30)) + (sum as u128) / 2) / sum as u128) as u32;
        let bins = config.n_bins as usize;
        let by_rows = matches!(config.shape, WindowShape::Rectangular) && bins * n <= ROW_WORDS;
        let mut rows = [0u32; ROW_WORDS];
        if by_rows {
            let mut b = 0;
            while b < bins {
                let k = config.first_bin as usize + b;
                let mut i = 0;
                while i < n {
                    let (c, s) = twiddles[(k * i) % n];
                    rows[b * n + i] = c as u16 as u32 | (s as u16 as u32) << 16;
                    i += 1;
                }
                b += 1;
            }
        }
        Ok(StftPlan {
            config,
            twiddles,
            window,
            acc_shift,
            gain,
            rows,
            by_rows,
        })
    }

    /// The validated config this plan was built from.
    pub const fn config(&self) -> StftConfig {
        self.config
    }

    /// Pushes one input sample `x` (Q1.15) into `state` and writes the `n_bins` band magnitudes
    /// |X_k| / Σw (Q1.15, bins `first_bin..first_bin + n_bins`) into `out[..n_bins]`.
    ///
    /// If `out` is shorter, only its length of bins is computed; entries past `n_bins` are left
    /// alone. A state belongs to one plan: reset it before using it with another window length
    /// (otherwise the output is meaningless, but nothing panics).
    pub fn step(&self, state: &mut StftState, x: i16, out: &mut [i16]) {
        let n = usize::from(self.config.window_len);
        // head < n for a state used with this plan; a state last used with a longer window
        // restarts its ring instead of indexing past it.
        let mut head = usize::from(state.head);
        if head >= n {
            head = 0;
        }
        if let Some(slot) = state.samples.get_mut(head) {
            *slot = x;
        }
        head += 1;
        if head >= n {
            head = 0;
        }
        // head < n <= MAX_WINDOW < 256.
        state.head = head as u8;

        // The ring from head on holds the oldest samples, before head the newest.
        let Some((newer, older)) = state
            .samples
            .get(..n)
            .and_then(|ring| ring.split_at_checked(head))
        else {
            return;
        };
        let bins = usize::from(self.config.n_bins);
        if self.by_rows {
            // Rectangular window: x·w = x·2^15 exactly (w = 2^30, and x·2^30 / 2^15 needs no
            // rounding), so Re = 2^15 · Σ x·cos and the same for Im: the sums of i16 products
            // (|Σ| < 48 · 2^30 < 2^36, shifted < 2^51), the same i64 numbers as below. Each
            // bin's row pairs its first n − head twiddles with the older samples, the rest
            // with the newer ones (`dsp::stft_bin_sums_rows`, SMLALBB/SMLALBT on the M4).
            let mut sums = [core::mem::MaybeUninit::uninit(); MAX_BANDS];
            let bins = bins.min(out.len()).min(MAX_BANDS);
            let sums = crate::dsp::stft_bin_sums_rows(older, newer, &self.rows, &mut sums[..bins]);
            for (o, &[re, im]) in out.iter_mut().zip(sums.iter()) {
                *o = self.magnitude(re << 15, im << 15);
            }
            return;
        }
        // Windowed samples, oldest first, Q2.30.
        let mut xw = [0i32; MAX_WINDOW];
        for ((d, &s), &w) in xw
            .iter_mut()
            .zip(older.iter().chain(newer))
            .zip(&self.window)
        {
            // Q1.15 × Q2.30 = Q3.45, >> 15 back to Q2.30; |x·w| <= w <= 2^30 fits the i32.
            *d = round_shift_i64(i64::from(s) * i64::from(w), 15) as i32;
        }
        let xw = xw.get(..n).unwrap_or(&[]);

        for (k, o) in (usize::from(self.config.first_bin)..).zip(out.iter_mut().take(bins)) {
            // Q2.30 × Q1.15 = Q3.45; |sum| <= Σ|x·w| · 2^15 < 2^51, no overflow for any input.
            let mut re: i64 = 0;
            // Σ x·w·sin: the negated imaginary part, which leaves |X_k| unchanged.
            let mut im: i64 = 0;
            // Twiddle index k·n mod N, advanced by k per sample; k <= N/2 so one subtraction
            // wraps it.
            let mut m = 0usize;
            for &v in xw {
                if let Some(&(c, s)) = self.twiddles.get(m) {
                    re += i64::from(v) * i64::from(c);
                    im += i64::from(v) * i64::from(s);
                }
                m += k;
                if m >= n {
                    m -= n;
                }
            }
            *o = self.magnitude(re, im);
        }
    }

    /// sqrt(re² + im²) / Σw in Q1.15, for Q3.45 accumulators (a bin's Σ x·w·cos and Σ x·w·sin,
    /// exact in i64: |sum| < 2^51).
    #[inline(always)]
    pub fn magnitude(&self, re: i64, im: i64) -> i16 {
        // Reduce to |·| <= 2^30 (see `acc_shift`) so the squares sum to < 2^61. acc_shift is
        // 16..=21 (L is 31..=36 for N <= 48): the mask changes nothing but tells the compiler
        // that the 64-bit shift is by less than 32 (a few instructions instead of two paths).
        let a = round_shift_i64(re, self.acc_shift & 31).unsigned_abs();
        let b = round_shift_i64(im, self.acc_shift & 31).unsigned_abs();
        let mag = isqrt_u64(a * a + b * b);
        // The reduced magnitude times 2^acc_shift / S is the Q1.15 output, and
        // 2^acc_shift / S = gain / 2^45 because acc_shift = L - 15 and gain = 2^(L+30) / S.
        // mag <= 2^30.5 and gain <= 2^31, so the product fits an i64.
        sat_i16_wide(round_shift_i64(i64::from(mag) * i64::from(self.gain), 45))
    }
}

impl StftPlan {
    /// Pushes `x` (Q1.15) into `state` as [`StftPlan::step`] does and writes the window's
    /// samples times w(n), oldest first, Q2.30, into `xw[..N]` (the windowed samples of
    /// `step`'s general path; a rectangular window gives x·2^15 exactly). Returns N. With
    /// [`StftPlan::twiddle`] and [`StftPlan::magnitude`] this is `step` in pieces, for the
    /// batched host path (`slipguard-batch`), which sums many states' bins at once.
    pub fn push_windowed(
        &self,
        state: &mut StftState,
        x: i16,
        xw: &mut [i32; MAX_WINDOW],
    ) -> usize {
        let n = usize::from(self.config.window_len);
        // The ring as in `step`.
        let mut head = usize::from(state.head);
        if head >= n {
            head = 0;
        }
        if let Some(slot) = state.samples.get_mut(head) {
            *slot = x;
        }
        head += 1;
        if head >= n {
            head = 0;
        }
        // head < n <= MAX_WINDOW < 256.
        state.head = head as u8;
        let (newer, older) = state.samples[..n].split_at(head);
        for (d, (&smp, &w)) in xw
            .iter_mut()
            .zip(older.iter().chain(newer).zip(&self.window))
        {
            // Q1.15 × Q2.30 = Q3.45, >> 15 back to Q2.30; |x·w| <= w <= 2^30 fits the i32.
            *d = round_shift_i64(i64::from(smp) * i64::from(w), 15) as i32;
        }
        n
    }

    /// The twiddle (cos, sin), Q1.15, that DFT bin `k`'s sum pairs with windowed sample `t`
    /// (oldest first): index k·t mod N, the index [`StftPlan::step`] advances by k per sample.
    pub fn twiddle(&self, k: usize, t: usize) -> (i16, i16) {
        let n = usize::from(self.config.window_len).max(1);
        self.twiddles.get((k * t) % n).copied().unwrap_or((0, 0))
    }
}

/// Per-channel STFT state: the last `window_len` input samples.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StftState {
    /// Ring buffer of the last `window_len` samples, Q1.15; zeros after reset.
    samples: [i16; MAX_WINDOW],
    /// Index of the oldest sample in `samples`, which the next sample overwrites.
    head: u8,
}

impl StftState {
    /// An empty window: all samples 0.
    pub const fn new() -> Self {
        StftState {
            samples: [0; MAX_WINDOW],
            head: 0,
        }
    }

    /// Forgets all samples, as after [`StftState::new`].
    pub fn reset(&mut self) {
        *self = StftState::new();
    }
}

impl Default for StftState {
    fn default() -> Self {
        StftState::new()
    }
}

/// ⌊√n⌋, exact, for any `u64`.
///
/// One step of Zimmermann's Karatsuba square root ("Karatsuba Square Root", INRIA RR-3805,
/// 1999) on top of `u32::isqrt` (itself Karatsuba from an 8-bit table), arranged so that its
/// division is 32-bit (`UDIV` on the M4) rather than a 64-bit library call. Small arguments
/// take the 32-bit path alone.
#[inline(always)]
fn isqrt_u64(n: u64) -> u32 {
    if n <= u64::from(u32::MAX) {
        return crate::dsp::isqrt_u32(n as u32);
    }
    // Normalise by an even shift (the root then shifts by half) so that the top 32 bits are
    // >= 2^30, the algorithm's precondition a3 >= b/4 for b = 2^16.
    let shift = n.leading_zeros() & !1;
    let n = n << shift;
    // Top and bottom halves.
    let hi = (n >> 32) as u32;
    let lo = n as u32;
    // s1 in [2^15, 2^16), r1 = hi - s1² in [0, 2·s1].
    let s1 = crate::dsp::isqrt_u32(hi);
    let r1 = hi - s1 * s1;
    // q = ⌊(r1·2^16 + lo>>16) / (2·s1)⌋ (next 16 root bits, with the top 16 bits of lo). The
    // dividend has up to 33 bits, so halve it and divide by s1: ⌊⌊a/2⌋/s⌋ = ⌊a/2s⌋.
    let num = (u64::from(r1) << 16) | u64::from(lo >> 16);
    let q = ((num >> 1) as u32) / s1.max(1);
    let u = num - u64::from(q) * u64::from(2 * s1);
    let s = (u64::from(s1) << 16) + u64::from(q);
    // Remainder n - s² = u·2^16 + (lo & 0xffff) - q²; negative means q was one too big.
    let rem = ((u << 16) | u64::from(lo & 0xffff)) as i64 - i64::from(q) * i64::from(q);
    let s = if rem < 0 { s - 1 } else { s };
    // Undo the normalisation: √(n·2^shift) = √n · 2^(shift/2).
    (s >> (shift / 2)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::collections::VecDeque;
    use std::f64::consts::PI;

    /// The documented bound over all window lengths, in Q1.15 LSBs.
    const BOUND_LSB: f64 = 1.18;

    /// The documented per-window bound max(0.5 + τ + 0.001, 1) (+0.001 for the f64 reference), τ
    /// recomputed here from libm: the largest error of the Q1.15-rounded e^{j2π(m + 1/8)/N}.
    #[test]
    fn the_set_up_per_rate_is_valid_and_its_bands_are_below_nyquist() {
        // The profiles' rates (hand 16.7 and 40 Hz, suction 71 Hz).
        for rate_mhz in [16_700u32, 40_000, 71_000] {
            let c = StftConfig::for_rate_mhz(Millihertz(rate_mhz));
            assert_eq!(c.validate(), Ok(()), "{rate_mhz}");
            // Bin k is centred on k·f_s/N: the last band stays at or below f_s/2.
            let last = (c.first_bin + c.n_bins - 1) as f64 * rate_mhz as f64 / c.window_len as f64;
            assert!(last <= rate_mhz as f64 / 2.0, "{rate_mhz}");
        }
        // At the paper's rate it is the paper's set-up: 20 samples = 1.2 s, bins 1..=10.
        assert_eq!(
            StftConfig::for_rate_mhz(Millihertz(16_700)),
            StftConfig::PAPER
        );
    }

    fn bound_lsb(n: usize) -> f64 {
        let tau = (0..n)
            .map(|m| {
                let th = 2.0 * PI * (m as f64 + 0.125) / n as f64;
                let (c, s) = (th.cos() * 32768.0, th.sin() * 32768.0);
                (c.round() - c).hypot(s.round() - s)
            })
            .fold(0.0, f64::max);
        // Saturation at 32767 of an exact 32768 costs 1 LSB.
        (0.5 + tau + 0.002).max(1.0)
    }

    #[test]
    fn documented_bounds() {
        let worst = (MIN_WINDOW..=MAX_WINDOW).map(bound_lsb).fold(0.0, f64::max);
        println!(
            "bound over N = 4..=48: {worst:.3} LSB, N = 20: {:.3}",
            bound_lsb(20)
        );
        assert!(worst <= BOUND_LSB);
        assert!(bound_lsb(20) <= 1.06);
    }

    fn cfg(window_len: u8, first_bin: u8, n_bins: u8, shape: WindowShape) -> StftConfig {
        StftConfig {
            window_len,
            first_bin,
            n_bins,
            shape,
        }
    }

    /// Windows 4 (minimum), 16, 20 (paper), 21 (odd), 32, 48, both shapes, together covering
    /// DC, Nyquist and the highest bins.
    fn configs() -> Vec<StftConfig> {
        use WindowShape::*;
        vec![
            StftConfig::PAPER,
            cfg(20, 0, 11, Hann),
            cfg(4, 0, 3, Rectangular),
            cfg(4, 0, 3, Hann),
            cfg(16, 0, 9, Rectangular),
            cfg(16, 0, 9, Hann),
            cfg(21, 0, 11, Rectangular),
            cfg(21, 3, 8, Hann),
            cfg(32, 1, 16, Rectangular),
            cfg(32, 0, 16, Hann),
            cfg(48, 9, 16, Rectangular),
            cfg(48, 0, 16, Hann),
        ]
    }

    /// Independent f64 reference: window history, libm twiddles and window, direct DFT.
    struct Reference {
        n: usize,
        bins: Vec<usize>,
        window: Vec<f64>,
        sum_w: f64,
        history: VecDeque<f64>,
    }

    impl Reference {
        fn new(c: StftConfig) -> Self {
            let n = usize::from(c.window_len);
            let window: Vec<f64> = (0..n)
                .map(|i| match c.shape {
                    WindowShape::Rectangular => 1.0,
                    WindowShape::Hann => 0.5 - 0.5 * (2.0 * PI * i as f64 / n as f64).cos(),
                })
                .collect();
            Reference {
                n,
                bins: (0..c.n_bins)
                    .map(|b| usize::from(c.first_bin + b))
                    .collect(),
                sum_w: window.iter().sum(),
                window,
                history: VecDeque::from(vec![0.0; n]),
            }
        }

        /// Pushes a Q1.15 sample; returns |X_k| / Σw in LSBs (×2^15) for each bin.
        fn step(&mut self, x: i16) -> Vec<f64> {
            self.history.pop_front();
            self.history.push_back(f64::from(x) / 32768.0);
            self.bins
                .iter()
                .map(|&k| {
                    let (mut re, mut im) = (0.0, 0.0);
                    for (i, (&v, &w)) in self.history.iter().zip(&self.window).enumerate() {
                        let th = 2.0 * PI * ((k * i) % self.n) as f64 / self.n as f64;
                        re += w * v * th.cos();
                        im -= w * v * th.sin();
                    }
                    re.hypot(im) / self.sum_w * 32768.0
                })
                .collect()
        }
    }

    fn clip(v: f64) -> i16 {
        v.round().clamp(-32768.0, 32767.0) as i16
    }

    /// Named test signals: random full scale, random small, steps, sinusoids, extremes.
    fn signals(rng: &mut ChaCha8Rng) -> Vec<(&'static str, Vec<i16>)> {
        let random: Vec<i16> = (0..6000).map(|_| rng.random()).collect();
        let small: Vec<i16> = (0..3000).map(|_| rng.random_range(-300..=300)).collect();
        let mut steps = Vec::new();
        while steps.len() < 4000 {
            let level: i16 = match rng.random_range(0..4) {
                0 => i16::MIN,
                1 => i16::MAX,
                _ => rng.random(),
            };
            let len = rng.random_range(1..80);
            steps.extend(std::iter::repeat_n(level, len));
        }
        let mut sines = Vec::new();
        while sines.len() < 6000 {
            let f = if rng.random_bool(0.3) {
                // On a bin of a 16/20/32/48-point DFT.
                let n = [16.0, 20.0, 32.0, 48.0][rng.random_range(0..4)];
                f64::from(rng.random_range(0..=24u32)) / n
            } else {
                rng.random_range(0.0..0.5)
            };
            let amp = rng.random_range(0.05..1.0) * 32768.0;
            let dc = rng.random_range(-0.3..0.3) * 32768.0;
            let phase = rng.random_range(0.0..2.0 * PI);
            for t in 0..300 {
                sines.push(clip(dc + amp * (2.0 * PI * f * t as f64 + phase).sin()));
            }
        }
        let alternating: Vec<i16> = (0..500)
            .map(|t| if t % 2 == 0 { i16::MIN } else { i16::MAX })
            .collect();
        let extremes: Vec<i16> = alternating
            .iter()
            .copied()
            .chain(std::iter::repeat_n(i16::MIN, 200))
            .chain(std::iter::repeat_n(i16::MAX, 200))
            .chain(std::iter::repeat_n(0, 100))
            .collect();
        vec![
            ("random", random),
            ("small", small),
            ("steps", steps),
            ("sines", sines),
            ("extremes", extremes),
        ]
    }

    #[test]
    fn matches_f64_dft_within_bound() {
        let mut rng = ChaCha8Rng::seed_from_u64(0x5717_6a4d);
        let signals = signals(&mut rng);
        let mut overall: f64 = 0.0;
        // Excluding outputs saturated at 32767.
        let mut unsaturated: f64 = 0.0;
        let mut total_steps = 0;
        for c in configs() {
            let plan = StftPlan::new(c).unwrap();
            let bound = bound_lsb(usize::from(c.window_len));
            let mut worst: f64 = 0.0;
            for (name, sig) in &signals {
                // Fresh state each signal, so the start-up (zero-filled window) is covered.
                let mut state = StftState::new();
                let mut reference = Reference::new(c);
                let mut out = [0i16; MAX_BANDS];
                for (t, &x) in sig.iter().enumerate() {
                    plan.step(&mut state, x, &mut out);
                    let want = reference.step(x);
                    for (b, (&got, &want)) in out.iter().zip(&want).enumerate() {
                        let err = (f64::from(got) - want).abs();
                        assert!(
                            err <= bound,
                            "{c:?} {name} t={t} bin {}: got {got}, want {want:.3}",
                            usize::from(c.first_bin) + b
                        );
                        worst = worst.max(err);
                        if got < i16::MAX {
                            unsaturated = unsaturated.max(err);
                        }
                    }
                }
                total_steps += sig.len();
            }
            println!("{c:?}: max error {worst:.3} LSB (bound {bound:.3})");
            overall = overall.max(worst);
        }
        println!(
            "{total_steps} steps, max error {overall:.3} LSB, {unsaturated:.3} unsaturated \
             (bound {BOUND_LSB})"
        );
    }

    /// f32 FFT (microfft) of the same windows; tolerance = bound + 0.1 LSB for the f32 FFT.
    #[test]
    fn matches_microfft() {
        const TOL_LSB: f64 = BOUND_LSB + 0.1;
        let mut rng = ChaCha8Rng::seed_from_u64(0xff7);
        let signals = signals(&mut rng);
        let mut overall: f64 = 0.0;
        for n in [16u8, 32] {
            for shape in [WindowShape::Rectangular, WindowShape::Hann] {
                // Two plans for N = 32 so that all 17 bins 0..=16 are checked.
                let plans = if n == 16 {
                    vec![cfg(16, 0, 9, shape)]
                } else {
                    vec![cfg(32, 0, 16, shape), cfg(32, 1, 16, shape)]
                };
                let w: Vec<f32> = (0..n)
                    .map(|i| match shape {
                        WindowShape::Rectangular => 1.0,
                        WindowShape::Hann => {
                            0.5 - 0.5 * (2.0 * PI * f64::from(i) / f64::from(n)).cos() as f32
                        }
                    })
                    .collect();
                let sum_w: f32 = w.iter().sum();
                for c in plans {
                    let plan = StftPlan::new(c).unwrap();
                    let mut worst: f64 = 0.0;
                    for (name, sig) in &signals {
                        let mut state = StftState::new();
                        let mut hist = VecDeque::from(vec![0i16; usize::from(n)]);
                        let mut out = [0i16; MAX_BANDS];
                        for &x in sig {
                            plan.step(&mut state, x, &mut out);
                            hist.pop_front();
                            hist.push_back(x);
                            let mut buf = [0f32; 32];
                            for (d, (&s, &wi)) in buf.iter_mut().zip(hist.iter().zip(&w)) {
                                *d = f32::from(s) / 32768.0 * wi;
                            }
                            let mag: Vec<f32> = if n == 16 {
                                let buf16: &mut [f32; 16] = (&mut buf[..16]).try_into().unwrap();
                                spectrum(microfft::real::rfft_16(buf16))
                            } else {
                                spectrum(microfft::real::rfft_32(&mut buf))
                            };
                            for (b, &got) in out.iter().take(usize::from(c.n_bins)).enumerate() {
                                let k = usize::from(c.first_bin) + b;
                                let want = f64::from(mag[k] / sum_w) * 32768.0;
                                let err = (f64::from(got) - want).abs();
                                assert!(err <= TOL_LSB, "{c:?} {name} bin {k}: {got} vs {want}");
                                worst = worst.max(err);
                            }
                        }
                    }
                    println!("microfft {c:?}: max difference {worst:.3} LSB");
                    overall = overall.max(worst);
                }
            }
        }
        println!("microfft: max difference {overall:.3} LSB (tolerance {TOL_LSB})");
    }

    /// |X_k| for k = 0..=N/2 from microfft's packed output (Nyquist in [0].im).
    fn spectrum(x: &[microfft::Complex32]) -> Vec<f32> {
        let mut m: Vec<f32> = x.iter().map(|c| c.re.hypot(c.im)).collect();
        m[0] = x[0].re.abs();
        m.push(x[0].im.abs());
        m
    }

    #[test]
    fn validation_errors() {
        let ok = StftConfig::PAPER;
        assert_eq!(ok.validate(), Ok(()));
        let plan = StftPlan::new(ok).unwrap();
        assert_eq!(plan.config(), ok);
        // Built at compile time (for flash) it is the same plan as at run time.
        const FLASH: StftPlan = match StftPlan::new(StftConfig::PAPER) {
            Ok(p) => p,
            Err(_) => panic!(),
        };
        assert_eq!(FLASH, plan);
        assert_eq!(
            (ok.window_len, ok.first_bin, ok.n_bins, ok.shape),
            (20, 1, 10, WindowShape::Rectangular)
        );
        let cases = [
            (
                StftConfig {
                    window_len: 3,
                    ..ok
                },
                StftError::WindowTooShort(3),
            ),
            (
                StftConfig {
                    window_len: 0,
                    ..ok
                },
                StftError::WindowTooShort(0),
            ),
            (
                StftConfig {
                    window_len: 49,
                    ..ok
                },
                StftError::WindowTooLong(49),
            ),
            (StftConfig { n_bins: 0, ..ok }, StftError::NoBins),
            (
                cfg(48, 0, 17, WindowShape::Hann),
                StftError::TooManyBins(17),
            ),
            (
                StftConfig { first_bin: 2, ..ok },
                StftError::BinAboveNyquist {
                    last_bin: 11,
                    nyquist_bin: 10,
                },
            ),
            (
                cfg(21, 255, 16, WindowShape::Hann),
                StftError::BinAboveNyquist {
                    last_bin: 270,
                    nyquist_bin: 10,
                },
            ),
        ];
        for (c, e) in cases {
            assert_eq!(c.validate(), Err(e), "{c:?}");
            assert_eq!(StftPlan::new(c), Err(e), "{c:?}");
            assert!(!std::format!("{e}").is_empty());
        }
        // Limits are accepted.
        assert!(cfg(4, 2, 1, WindowShape::Hann).validate().is_ok());
        assert!(cfg(48, 9, 16, WindowShape::Rectangular).validate().is_ok());
        assert_eq!(WindowShape::try_from(0), Ok(WindowShape::Rectangular));
        assert_eq!(WindowShape::try_from(1), Ok(WindowShape::Hann));
        assert_eq!(WindowShape::try_from(2), Err(StftError::UnknownShape(2)));
        assert_eq!(WindowShape::Hann as u8, 1);
    }

    #[test]
    fn reset_and_state_size() {
        let size = core::mem::size_of::<StftState>();
        println!("size_of::<StftState>() = {size}");
        assert!(size <= 128);

        let plan = StftPlan::new(StftConfig::PAPER).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let input: Vec<i16> = (0..100).map(|_| rng.random()).collect();
        let run = |state: &mut StftState| -> Vec<[i16; 10]> {
            input
                .iter()
                .map(|&x| {
                    let mut out = [0; 10];
                    plan.step(state, x, &mut out);
                    out
                })
                .collect()
        };
        let mut used = StftState::new();
        let first = run(&mut used);
        assert_ne!(used, StftState::new());
        used.reset();
        assert_eq!(used, StftState::new());
        assert_eq!(used, StftState::default());
        assert_eq!(run(&mut used), first);

        // Zeros in, zeros out; one impulse after reset shows a flat spectrum of 1/N for
        // exactly N steps, then zeros again.
        used.reset();
        let mut out = [1i16; 10];
        for _ in 0..30 {
            plan.step(&mut used, 0, &mut out);
            assert_eq!(out, [0; 10]);
        }
        used.reset();
        for t in 0..25 {
            plan.step(&mut used, if t == 0 { i16::MIN } else { 0 }, &mut out);
            // 2^15 / 20 = 1638.4.
            let want = if t < 20 { 1638 } else { 0 };
            assert!(out.iter().all(|&o| (o - want).abs() <= 1), "t={t} {out:?}");
        }
    }

    /// The rectangular window's per-bin twiddle rows give the same bits as the general path
    /// (which the bound tests check against f64), on every signal and window that has rows.
    #[test]
    fn twiddle_rows_equal_the_general_path() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut with_rows = 0;
        for c in configs() {
            let fast = StftPlan::new(c).unwrap();
            if !fast.by_rows {
                assert!(
                    c.shape == WindowShape::Hann
                        || usize::from(c.n_bins) * usize::from(c.window_len) > ROW_WORDS
                );
                continue;
            }
            with_rows += 1;
            let mut general = fast.clone();
            general.by_rows = false;
            for (name, sig) in signals(&mut rng) {
                let (mut sa, mut sb) = (StftState::new(), StftState::new());
                let (mut a, mut b) = ([0i16; MAX_BANDS], [0i16; MAX_BANDS]);
                for (t, &x) in sig.iter().enumerate() {
                    fast.step(&mut sa, x, &mut a);
                    general.step(&mut sb, x, &mut b);
                    assert_eq!(a, b, "{c:?} {name} t={t}");
                }
            }
        }
        assert!(with_rows >= 3, "{with_rows}");
    }

    #[test]
    fn odd_buffers_and_mismatched_state_do_not_panic() {
        let long = StftPlan::new(cfg(48, 0, 16, WindowShape::Hann)).unwrap();
        let short = StftPlan::new(StftConfig::PAPER).unwrap();
        let mut state = StftState::new();
        let mut out = [0i16; 16];
        for t in 0..100 {
            long.step(&mut state, (t * 1000) as i16, &mut out);
        }
        // State left with head >= 20, then used with the 20-sample plan without a reset.
        for t in 0..100 {
            short.step(&mut state, (t * 333) as i16, &mut out);
        }
        // Shorter `out`: only that many bins; longer: the rest untouched.
        let mut reference = StftState::new();
        let mut state = StftState::new();
        let mut full = [0i16; 10];
        let mut three = [0i16; 3];
        let mut wide = [-7i16; 20];
        for t in 0..60 {
            let x = ((t * 7919) % 65536 - 32768) as i16;
            short.step(&mut reference, x, &mut full);
            short.step(&mut state, x, &mut three);
            assert_eq!(three, full[..3]);
        }
        short.step(&mut state, 5, &mut wide);
        assert!(wide[10..].iter().all(|&v| v == -7));
        short.step(&mut state, 5, &mut []);
    }

    #[test]
    fn isqrt_is_exact() {
        let check = |n: u64| assert_eq!(u64::from(isqrt_u64(n)), n.isqrt(), "{n}");
        for k in (0..=u64::from(u32::MAX))
            .step_by(9_973)
            .chain([u64::from(u32::MAX)])
        {
            let sq = k * k;
            check(sq);
            check(sq.saturating_sub(1));
            check(sq + 1);
            check(sq + 2 * k); // (k+1)² - 1
        }
        for s in 0..64 {
            check(1 << s);
            check((1 << s) - 1);
        }
        check(u64::MAX);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200_000 {
            let bits = rng.random_range(0..64);
            check(rng.random::<u64>() >> bits);
        }
    }
}
