//! Sigmoid and tanh by lookup table with linear interpolation, as the 16x8 LSTM uses them.
//!
//! Input: `i16` in Q3.12 (a gate pre-activation, [-8, 8)). Output: `i16` in Q0.15.
//! Each table has 513 entries, one per 1/32 of the input range [-8, 8], generated at compile
//! time by `const fn` from [`crate::const_math`]. Between entries the value is interpolated
//! linearly on the low 7 bits of the input. The lookup tables store each interval as one word,
//! lo in the high halfword and hi - lo (≥ 0: both functions rise) in the low one (2 KiB a
//! table, so both fit the M4's SRAM: one LDR, one SMLABB, two shifts); a test checks every input
//! against the plain interpolation between the 513 values.
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

/// σ(x) on [-8, 8] in steps of 1/32, Q0.15 (the values the interpolation is defined on).
const SIGMOID_VALUES: [i16; ENTRIES] = build(false);
/// tanh(x) on [-8, 8] in steps of 1/32, Q0.15.
const TANH_VALUES: [i16; ENTRIES] = build(true);

/// One interpolation interval k as the lookup uses it: `lo << 16 | (hi - lo)` with
/// lo = values[k], hi = values[k + 1]. One 4-byte load per lookup gives both. The steps are
/// checked at compile time: within 0..=32767 (a non-negative i16, as SMLABB reads the low
/// halfword), and 0 in the first and the last interval (the functions are flat there to the
/// Q0.15 LSB), which lets the assembly take the interval from an unsaturated input: every
/// input beyond the range falls into an end interval, whose value does not depend on the
/// position (see [`crate::dsp::lstm_gate_rows_folded`]).
const fn pairs(v: &[i16; ENTRIES]) -> [u32; ENTRIES - 1] {
    let mut t = [0u32; ENTRIES - 1];
    let mut k = 0;
    while k < ENTRIES - 1 {
        let (lo, step) = (v[k] as i32, v[k + 1] as i32 - v[k] as i32);
        assert!(
            step >= 0 && step <= i16::MAX as i32,
            "interval step out of range"
        );
        assert!(
            step == 0 || (k > 0 && k < ENTRIES - 2),
            "end interval not flat"
        );
        t[k] = ((lo as u32) << 16) | step as u32;
        k += 1;
    }
    t
}

/// An activation's interval table: 512 words `lo << 16 | (hi - lo)`, lo and hi the Q0.15
/// values at the interval's ends (lo an i16 in the high halfword, the Q0.15 step hi - lo in
/// 0..=32767 in the low one; the first and last steps are 0).
pub type IntervalTable = [u32; ENTRIES - 1];

/// σ intervals (see [`pairs`]); the kernels read them from a static in [`crate::dsp`]
/// (in RAM on the target, [`crate::dsp::interval_table`]).
pub(crate) const SIGMOID_INTERVALS: IntervalTable = pairs(&SIGMOID_VALUES);
/// tanh intervals (see [`pairs`]).
pub(crate) const TANH_INTERVALS: IntervalTable = pairs(&TANH_VALUES);

/// f(x) by the interval table of f ([`crate::dsp::sigmoid`] and [`crate::dsp::tanh`] with the
/// kernels' tables).
#[inline(always)]
pub fn lookup(table: &IntervalTable, x: i16) -> i16 {
    interpolate(table, x)
}

/// Rounded linear interpolation between values[k] and values[k + 1] (`lo`, `hi`), k the top 9
/// bits of `x + 32768`, at the position f = the low 7 bits: `lo + ((hi - lo)·f + 2^6) >> 7`.
/// The result lies between lo and hi, so it fits in i16.
#[inline(always)]
fn interpolate(table: &IntervalTable, x: i16) -> i16 {
    // (x + 32768) >> 7 = (x >> 7) + 256, in 0..=511 for every i16.
    let k = ((x as i32 >> FRAC_BITS) + 256) as usize;
    let frac = x as i32 & ((1 << FRAC_BITS) - 1); // position in the interval, 0..127 of 128
    let w = table[k & (ENTRIES - 2)];
    // lo is the high halfword (arithmetic shift), the step the low one.
    let (lo, step) = ((w as i32) >> 16, (w & 0xFFFF) as i32);
    // The 2^6 rounds the step's share to nearest (ties up), 7 bits of position.
    (lo + ((step * frac + (1 << (FRAC_BITS - 1))) >> FRAC_BITS)) as i16
}

#[cfg(test)]
mod tests {
    use super::*;

    // The const tables the kernels' statics are made from.
    fn sigmoid(x: i16) -> i16 {
        lookup(&SIGMOID_INTERVALS, x)
    }
    fn tanh(x: i16) -> i16 {
        lookup(&TANH_INTERVALS, x)
    }

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

    /// The definition: interpolation on the i16 value tables, `lo + (((hi - lo)·f + 64) >> 7)`.
    fn reference(values: &[i16; ENTRIES], x: i16) -> i16 {
        let u = (x as i32 + 32768) as u32;
        let idx = (u >> FRAC_BITS) as usize;
        let frac = (u & ((1 << FRAC_BITS) - 1)) as i32;
        let lo = values[idx] as i32;
        let hi = values[idx + 1] as i32;
        (lo + (((hi - lo) * frac + (1 << (FRAC_BITS - 1))) >> FRAC_BITS)) as i16
    }

    #[test]
    fn pair_tables_equal_value_table_interpolation() {
        for x in i16::MIN..=i16::MAX {
            assert_eq!(sigmoid(x), reference(&SIGMOID_VALUES, x), "sigmoid({x})");
            assert_eq!(tanh(x), reference(&TANH_VALUES, x), "tanh({x})");
        }
    }

    /// What the assembly relies on: the interval and position taken from an input that has not
    /// been saturated to i16 (interval ⌊t / 2^7⌋ clamped to -256..=255, position t & 127) give
    /// the lookup of the saturated input, because the end intervals are flat.
    #[test]
    fn unsaturated_inputs_give_the_saturated_lookup() {
        for table in [&SIGMOID_INTERVALS, &TANH_INTERVALS] {
            for t in (-(1 << 20)..(1 << 20))
                .step_by(7)
                .chain([i32::MIN, i32::MAX, -32769, 32768])
            {
                let k = ((t >> FRAC_BITS).clamp(-256, 255) + 256) as usize;
                let w = table[k];
                let (lo, step) = ((w as i32) >> 16, (w & 0xFFFF) as i32);
                let got = lo + ((step * (t & 127) + 64) >> 7);
                let want = lookup(table, t.clamp(-32768, 32767) as i16) as i32;
                assert_eq!(got, want, "t = {t}");
            }
        }
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
