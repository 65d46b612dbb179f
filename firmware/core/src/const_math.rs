//! `const fn` elementary functions in f64, used to generate tables (twiddles, sigmoid, tanh,
//! the decimator's windowed-sinc taps) at compile time instead of pasting them.
//!
//! They only use IEEE-754 `+ - * /`, which are correctly rounded on every target, so a table
//! built at run time on the Cortex-M4 (soft-float f64) is bit-identical to one built on the host.
//! Accuracy is about 1e-15 relative, far below the Q1.15 resolution the tables are rounded to.

/// π to f64 precision.
pub const PI: f64 = core::f64::consts::PI;

/// e^x for |x| < 700: x = k·ln2 + r with |r| <= ln2/2 (Cody–Waite split of ln2, so k·ln2 is
/// exact), a Taylor series for e^r, then an exact scaling by 2^k.
pub const fn exp(x: f64) -> f64 {
    // ln2 split into a high part with trailing zero bits (k·LN2_HI is exact for |k| < 2^11)
    // and the remainder (fdlibm's constants).
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    let kf = round(x / core::f64::consts::LN_2);
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    // 22 terms of the series reach f64 epsilon for |r| <= 0.35.
    let mut sum = 1.0;
    let mut term = 1.0;
    let mut n = 1;
    while n < 22 {
        term = term * r / n as f64;
        sum += term;
        n += 1;
    }
    let mut k = kf as i64;
    while k > 0 {
        sum *= 2.0;
        k -= 1;
    }
    while k < 0 {
        sum /= 2.0;
        k += 1;
    }
    sum
}

/// Logistic sigmoid 1 / (1 + e^-x).
pub const fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + exp(-x))
    } else {
        let e = exp(x);
        e / (1.0 + e)
    }
}

/// e^x - 1, accurate near 0 where `exp(x) - 1` would cancel.
pub const fn expm1(x: f64) -> f64 {
    if x > 0.5 || x < -0.5 {
        return exp(x) - 1.0;
    }
    // Taylor series without the leading 1; 24 terms reach f64 epsilon for |x| <= 1/2.
    let mut sum = 0.0;
    let mut term = 1.0;
    let mut n = 1;
    while n < 24 {
        term = term * x / n as f64;
        sum += term;
        n += 1;
    }
    sum
}

/// Hyperbolic tangent, as -expm1(-2x) / (2 + expm1(-2x)), which stays accurate near 0.
pub const fn tanh(x: f64) -> f64 {
    if x < 0.0 {
        return -tanh(-x);
    }
    if x > 20.0 {
        return 1.0;
    }
    let e = expm1(-2.0 * x);
    -e / (2.0 + e)
}

/// (cos θ, sin θ) for θ = 2π·m/n, reduced to the first octant so the series converges fast.
pub const fn cos_sin_turn(m: u32, n: u32) -> (f64, f64) {
    // Exact integer reduction of the angle m/n turns into [0, 1) turns, then by symmetry to
    // [0, 1/8] turns, where the Taylor series below is accurate to f64 precision.
    let m = m % n;
    // Work in units of 1/(8n) turn: a = 8m, octant = a / n, remainder r in [0, n).
    let a = 8 * m as u64;
    let octant = a / n as u64;
    let r = a % n as u64;
    // θ' in [0, π/4): the angle within the octant.
    let t = (r as f64) / (n as f64) * (PI / 4.0);
    let (c, s) = cos_sin_small(t);
    // Angle within the octant counted from the octant's start; for odd octants, mirror.
    let (c2, s2) = cos_sin_small(PI / 4.0 - t);
    match octant {
        0 => (c, s),
        1 => (s2, c2),
        2 => (-s, c),
        3 => (-c2, s2),
        4 => (-c, -s),
        5 => (-s2, -c2),
        6 => (s, -c),
        _ => (c2, -s2),
    }
}

/// Taylor series of cos and sin for |t| <= π/4.
const fn cos_sin_small(t: f64) -> (f64, f64) {
    let t2 = t * t;
    let mut c = 1.0;
    let mut s = t;
    let mut tc = 1.0;
    let mut ts = t;
    let mut k = 1;
    while k < 12 {
        tc = -tc * t2 / ((2 * k - 1) as f64 * (2 * k) as f64);
        ts = -ts * t2 / ((2 * k) as f64 * (2 * k + 1) as f64);
        c += tc;
        s += ts;
        k += 1;
    }
    (c, s)
}

/// sinc(m/d) = sin(π·m/d) / (π·m/d), the normalised sinc at a rational argument (the angle is
/// reduced exactly, in integers, by [`cos_sin_turn`]); sinc(0) = 1.
pub const fn sinc_ratio(m: i64, d: u32) -> f64 {
    if m == 0 {
        return 1.0;
    }
    // sinc is even; sin(π·|m|/d) is the sine of |m| / (2d) turns.
    let a = m.unsigned_abs();
    let (_, s) = cos_sin_turn((a % (2 * d as u64)) as u32, 2 * d);
    s / (PI * a as f64 / d as f64)
}

/// I0(z), the modified Bessel function of the first kind of order 0, given z²/4: the series
/// Σ_k (z²/4)^k / (k!)², summed until a term no longer changes the sum. Taking z²/4 lets the
/// Kaiser window avoid a square root.
pub const fn bessel_i0_from_quarter_square(q: f64) -> f64 {
    let mut sum = 1.0;
    let mut term = 1.0;
    let mut k = 1;
    // For q <= 100 (β up to 20) the terms fall below 1e-17 of the sum before k = 100.
    while k < 100 {
        term = term * q / (k as f64 * k as f64);
        sum += term;
        if term < sum * 1e-17 {
            break;
        }
        k += 1;
    }
    sum
}

/// The Kaiser window of length `len` and shape β at sample `n` (0..len):
/// I0(β·√(1 − r²)) / I0(β) with r = (2n − (len − 1)) / (len − 1), symmetric to the last bit
/// (r is computed from an integer numerator, so w[n] and w[len − 1 − n] are the same number).
pub const fn kaiser(n: usize, len: usize, beta: f64) -> f64 {
    if len < 2 {
        return 1.0;
    }
    let r = (2 * n as i64 - (len as i64 - 1)) as f64 / (len - 1) as f64;
    let quarter_beta_sq = beta * beta / 4.0;
    bessel_i0_from_quarter_square(quarter_beta_sq * (1.0 - r * r))
        / bessel_i0_from_quarter_square(quarter_beta_sq)
}

/// Round half away from zero to the nearest integer, as `f64::round` does, in a `const fn`.
pub const fn round(x: f64) -> f64 {
    let t = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    // Truncation toward zero through an integer: every value rounded here fits in i64.
    (t as i64) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_libm_to_1e_13() {
        for i in -400..=400 {
            let x = i as f64 * 0.05;
            assert!(
                (exp(x) - x.exp()).abs() <= 1e-13 * x.exp().max(1.0),
                "exp {x}"
            );
            assert!(
                (sigmoid(x) - 1.0 / (1.0 + (-x).exp())).abs() < 1e-14,
                "sigmoid {x}"
            );
            assert!((tanh(x) - x.tanh()).abs() < 1e-14, "tanh {x}");
        }
        for n in 1..=64u32 {
            for m in 0..2 * n {
                let th = 2.0 * std::f64::consts::PI * m as f64 / n as f64;
                let (c, s) = cos_sin_turn(m, n);
                assert!(
                    (c - th.cos()).abs() < 1e-14 && (s - th.sin()).abs() < 1e-14,
                    "{m}/{n}"
                );
            }
        }
        for m in -700i64..=700 {
            let x = m as f64 / 320.0;
            let want = if m == 0 {
                1.0
            } else {
                (std::f64::consts::PI * x).sin() / (std::f64::consts::PI * x)
            };
            assert!((sinc_ratio(m, 320) - want).abs() < 1e-14, "sinc {m}/320");
        }
        // I0 against its integral form (1/π)∫₀^π e^(z·cos θ) dθ, by the trapezoidal rule,
        // which converges geometrically for a periodic integrand.
        for i in 0..=40 {
            let z = i as f64 * 0.5;
            let steps = 4000;
            let mut acc = 0.0;
            for j in 0..=steps {
                let w = if j == 0 || j == steps { 0.5 } else { 1.0 };
                acc += w * (z * (std::f64::consts::PI * j as f64 / steps as f64).cos()).exp();
            }
            let want = acc / steps as f64;
            let got = bessel_i0_from_quarter_square(z * z / 4.0);
            assert!(
                (got - want).abs() <= 1e-13 * want,
                "I0({z}) {got} vs {want}"
            );
        }
        for n in 0..64 {
            assert_eq!(kaiser(n, 64, 5.0), kaiser(63 - n, 64, 5.0));
        }
        assert_eq!(round(2.5), 3.0);
        assert_eq!(round(-2.5), -3.0);
        assert_eq!(round(-0.4), 0.0);
    }
}
