//! Sigmoid and tanh by lookup table with linear interpolation, as the 16x8 LSTM uses them.
//!
//! Input: `i16` in Q3.12 (a gate pre-activation, [-8, 8)). Output: `i16` in Q0.15.
//! Each table has 513 entries, one per 1/32 of the input range [-8, 8], generated at compile
//! time by `const fn` from [`crate::const_math`]. Between entries the value is interpolated
//! linearly on the low 7 bits of the input.
//!
//! Error against f64 at the exact Q3.12 input (over all 65 536 inputs, test
//! `activation::tests::max_error_against_f64`): sigmoid at most [`SIGMOID_MAX_ERR_LSB`] LSB
//! (Q0.15), tanh at most [`TANH_MAX_ERR_LSB`] LSB. The interpolation error bound h²/8·max|f''|
//! with h = 1/32 is 1.2e-5 for σ and 9.4e-5 for tanh (0.4 and 3.1 LSB), plus rounding. Beyond the
//! ±8 input range σ and tanh differ from their saturated values by less than 3.4e-4.

use crate::const_math;

/// Table entries: 512 intervals over [-8, 8] plus the closing point.
const ENTRIES: usize = 513;
/// Low bits of a Q3.12 input that select the position inside one table interval
/// (16-bit input range / 512 intervals = 128 = 2^7 input LSBs per interval).
const FRAC_BITS: u32 = 7;

/// Bound on the error of [`sigmoid`] against f64, in Q0.15 LSB (measured: 1.26 LSB, 3.9e-5).
pub const SIGMOID_MAX_ERR_LSB: i32 = 2;
/// Bound on the error of [`tanh`] against f64, in Q0.15 LSB (measured: 3.80 LSB, 1.2e-4).
pub const TANH_MAX_ERR_LSB: i32 = 4;

/// Table of f on [-8, 8] at step 1/32, rounded to Q0.15 and saturated to i16.
const fn build(tanh: bool) -> [i16; ENTRIES] {
    let mut t = [0i16; ENTRIES];
    let mut k = 0;
    while k < ENTRIES {
        let x = -8.0 + k as f64 / 32.0;
        let y = if tanh {
            const_math::tanh(x)
        } else {
            const_math::sigmoid(x)
        };
        let q = const_math::round(y * 32768.0);
        t[k] = if q > 32767.0 {
            32767
        } else if q < -32768.0 {
            -32768
        } else {
            q as i16
        };
        k += 1;
    }
    t
}

/// σ(x) on [-8, 8] in steps of 1/32, Q0.15.
static SIGMOID_TABLE: [i16; ENTRIES] = build(false);
/// tanh(x) on [-8, 8] in steps of 1/32, Q0.15.
static TANH_TABLE: [i16; ENTRIES] = build(true);

#[inline(always)]
fn interpolate(table: &[i16; ENTRIES], x: i16) -> i16 {
    // Offset the input to 0..=65535 so its top 9 bits index the table.
    let u = (x as i32 + 32768) as u32;
    let idx = (u >> FRAC_BITS) as usize; // 0..=511, so idx + 1 <= 512 stays in the table
    let frac = (u & ((1 << FRAC_BITS) - 1)) as i32; // position in the interval, 0..127 of 128
    let lo = table[idx & 511] as i32;
    let hi = table[(idx & 511) + 1] as i32;
    // Rounded linear interpolation; the result lies between lo and hi, so it fits in i16.
    (lo + (((hi - lo) * frac + (1 << (FRAC_BITS - 1))) >> FRAC_BITS)) as i16
}

/// σ(x): Q3.12 in, Q0.15 out (0..=32767).
#[inline]
pub fn sigmoid(x: i16) -> i16 {
    interpolate(&SIGMOID_TABLE, x)
}

/// tanh(x): Q3.12 in, Q0.15 out (-32768..=32767).
#[inline]
pub fn tanh(x: i16) -> i16 {
    interpolate(&TANH_TABLE, x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every Q3.12 input against f64, independent of the tables' generator (std's exp/tanh).
    #[test]
    fn max_error_against_f64() {
        let (mut es, mut et) = (0f64, 0f64);
        for x in i16::MIN..=i16::MAX {
            let xr = x as f64 / 4096.0;
            let s = 1.0 / (1.0 + (-xr).exp());
            let t = xr.tanh();
            es = es.max((sigmoid(x) as f64 / 32768.0 - s).abs());
            et = et.max((tanh(x) as f64 / 32768.0 - t).abs());
        }
        println!(
            "sigmoid max err {:.3e} ({:.2} LSB), tanh max err {:.3e} ({:.2} LSB)",
            es,
            es * 32768.0,
            et,
            et * 32768.0
        );
        assert!(es * 32768.0 <= SIGMOID_MAX_ERR_LSB as f64, "sigmoid {es}");
        assert!(et * 32768.0 <= TANH_MAX_ERR_LSB as f64, "tanh {et}");
    }

    #[test]
    fn monotone_and_symmetric() {
        let mut prev = (i16::MIN, i16::MIN);
        for x in i16::MIN..=i16::MAX {
            let (s, t) = (sigmoid(x), tanh(x));
            assert!(s >= prev.0 && t >= prev.1, "not monotone at {x}");
            prev = (s, t);
        }
        assert_eq!(sigmoid(0), 16384);
        assert_eq!(tanh(0), 0);
        assert_eq!(tanh(4096), -tanh(-4096));
    }
}
