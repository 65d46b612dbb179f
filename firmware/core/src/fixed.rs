//! Fixed-point formats and the few integer operations every stage shares.
//!
//! Notation: `Qm.n` is a signed integer with `n` fractional bits (value = raw / 2^n) and `m`
//! integer bits including the sign, so an `i16` in Q1.15 covers [-1, 1) and one in Q3.12
//! covers [-8, 8). Every integer in this crate that carries a real value names its format
//! where it is declared.
//!
//! | quantity | type | format | range |
//! |---|---|---|---|
//! | model input sample (normalised force or pressure) | `i16` | Q1.15 | [-1, 1) of the blob's input full scale |
//! | STFT band magnitude, \|X_k\| / Σw | `i16` | Q1.15 | [0, 1) |
//! | force difference d(t) | `i16` | Q1.15 | saturated to [-1, 1) |
//! | LSTM input (features after per-feature normalisation) | `i16` | Q3.12 | ±8 standard deviations |
//! | gate pre-activation | `i16` | Q3.12 | [-8, 8), where σ and tanh are flat to < 4e-4 |
//! | gate activation σ, tanh; hidden state h | `i16` | Q0.15 | [-1, 1) |
//! | cell state c | `i16` | Q(15-C).C, C from the blob | ±2^(15-C) |
//! | p(unstable), threshold | `i16` / `u16` | Q0.15 | [0, 1) |

/// Saturates a wide value to `i16`.
#[inline(always)]
pub const fn sat_i16(x: i32) -> i16 {
    if x > i16::MAX as i32 {
        i16::MAX
    } else if x < i16::MIN as i32 {
        i16::MIN
    } else {
        x as i16
    }
}

/// Saturates an `i64` to `i16`.
#[inline(always)]
pub const fn sat_i16_wide(x: i64) -> i16 {
    if x > i16::MAX as i64 {
        i16::MAX
    } else if x < i16::MIN as i64 {
        i16::MIN
    } else {
        x as i16
    }
}

/// `x / 2^shift` rounded to nearest, ties toward +∞ (add half, arithmetic shift).
/// `shift` must be in 1..=62; every caller passes a constant or a blob field validated to that range.
#[inline(always)]
pub const fn round_shift_i64(x: i64, shift: u32) -> i64 {
    (x + (1i64 << (shift - 1))) >> shift
}

/// `x / 2^shift` rounded to nearest, ties toward +∞, for 32-bit values (`shift` in 1..=30).
#[inline(always)]
pub const fn round_shift_i32(x: i32, shift: u32) -> i32 {
    // Widened so that x near i32::MAX cannot overflow when the half is added.
    round_shift_i64(x as i64, shift) as i32
}

/// Converts a real value to a fixed-point integer with `frac_bits` fractional bits, rounded to
/// nearest and saturated to `i16` (host-side helper for tests, the quantizer and the exporter).
#[cfg(any(test, feature = "std"))]
pub fn to_q_i16(x: f64, frac_bits: u32) -> i16 {
    let v = (x * (1u64 << frac_bits) as f64).round();
    v.clamp(i16::MIN as f64, i16::MAX as f64) as i16
}

/// Converts a fixed-point integer with `frac_bits` fractional bits to a real value.
pub fn from_q(x: i32, frac_bits: u32) -> f32 {
    x as f32 / (1u64 << frac_bits) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_and_saturation() {
        assert_eq!(round_shift_i64(3, 1), 2); // 1.5 -> 2
        assert_eq!(round_shift_i64(-3, 1), -1); // -1.5 -> -1 (ties toward +inf)
        assert_eq!(round_shift_i64(-5, 2), -1); // -1.25 -> -1
        assert_eq!(round_shift_i32(i32::MAX, 1), 1 << 30);
        assert_eq!(sat_i16(40_000), i16::MAX);
        assert_eq!(sat_i16(-40_000), i16::MIN);
        assert_eq!(sat_i16_wide(-1 << 40), i16::MIN);
        assert_eq!(to_q_i16(0.5, 15), 16384);
        assert_eq!(to_q_i16(1.0, 15), i16::MAX);
        assert_eq!(from_q(-4096, 12), -1.0);
    }
}
