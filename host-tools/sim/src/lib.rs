//! Seeded, deterministic simulators of grasp trials; see docs/simulator.md.
//!
//! Every trial `i` of seed `s` uses its own ChaCha8 stream (`seed = s`,
//! `stream = i`), so a trial does not depend on how many others are generated.

pub mod dsp;
pub mod force;
pub mod suction;
pub mod validate;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The random generator of trial `index` under `seed`.
pub fn trial_rng(seed: u64, index: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(index);
    r
}

/// Standard normal sample (Box–Muller).
pub fn normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-12);
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Uniform sample in `[lo, hi)` (returns `lo` if `hi <= lo`).
pub fn uniform(rng: &mut impl Rng, lo: f64, hi: f64) -> f64 {
    if hi <= lo {
        lo
    } else {
        rng.random_range(lo..hi)
    }
}

/// ADC model: clamp to `[0, full_scale]`, quantise to `bits`, return the value
/// of the code in the input unit rounded to a whole number (as the real files).
pub fn adc(x: f64, full_scale: f64, bits: u32) -> f32 {
    let max_code = ((1u64 << bits) - 1) as f64;
    let lsb = full_scale / max_code;
    let code = (x.clamp(0.0, full_scale) / lsb).round();
    (code * lsb).round() as f32
}
