//! Instruction-count benchmarks of slipguard-core on a Cortex-M4F emulated by QEMU
//! (`-M mps2-an386 -icount shift=0`). Output goes to the host through semihosting; the exit code
//! is 0 when every `check_equal` passed, 1 on a mismatch, 101 on a panic.
//!
//! Modules: [`insns`] (SysTick instruction counter, `measure`) and [`harness`] (output, checks,
//! exit codes, panic handler). Add kernels as `harness::bench(...)` + `harness::check_equal(...)`.
#![no_std]
#![no_main]

mod harness;
mod insns;

use core::hint::black_box;
use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use slipguard_core::const_math;

/// Length of the dot products: one row of an LSTM gate matrix at the largest hidden size.
const N: usize = slipguard_core::MAX_HIDDEN;

/// Q15 × Q15 dot product with a 32-bit accumulator, the inner loop of a quantised matrix-vector
/// product (a stand-in until the LSTM cell can be benchmarked).
#[inline(never)]
fn dot_q15(a: &[i16; N], b: &[i16; N]) -> i32 {
    a.iter().zip(b).fold(0i32, |acc, (&x, &y)| {
        acc.wrapping_add(i32::from(x) * i32::from(y))
    })
}

/// f32 dot product (hardware FPU, sequential accumulation).
#[inline(never)]
fn dot_f32(a: &[f32; N], b: &[f32; N]) -> f32 {
    a.iter().zip(b).fold(0.0, |acc, (&x, &y)| acc + x * y)
}

/// Deterministic test vectors from a small LCG, the same on every target: values in ±2^11 so
/// that 128 products cannot overflow the i32 accumulator (|sum| <= 2^29).
fn fill_q15(seed: u32) -> [i16; N] {
    let mut s = seed;
    core::array::from_fn(|_| {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        ((s >> 20) as i16) - 2048
    })
}

#[entry]
fn main() -> ! {
    let cp = cortex_m::Peripherals::take().expect("core peripherals taken twice");
    insns::init(cp.SYST);
    hprintln!(
        "slipguard-qemu-bench: SysTick counter, {} insns/tick, bookkeeping {} insns/iter subtracted",
        insns::INSNS_PER_TICK,
        insns::overhead_per_iter()
    );

    // Cross-check span for the insncount plugin: markers #1 and #2 bracket a raw measurement,
    // so the plugin's delta and this SysTick count describe (almost) the same instructions.
    let mut x = 0u32;
    insns::marker(1);
    let raw = insns::measure_raw(10_000, &mut || {
        x = black_box(x).wrapping_mul(3).wrapping_add(1)
    });
    insns::marker(2);
    hprintln!(
        "span markers #1..#2: {} insns by SysTick (raw, bookkeeping included)",
        raw
    );

    // `--features wrap-check`: a span of ~1.1 G instructions, past the 24-bit counter's wrap at
    // ~671 M, must cost exactly as much per iteration as the short span above (±40 in total).
    #[cfg(feature = "wrap-check")]
    {
        const LONG: u32 = 50_000_000;
        let long = insns::measure_raw(LONG, &mut || {
            x = black_box(x).wrapping_mul(3).wrapping_add(1)
        });
        let want = raw / 10_000 * u64::from(LONG);
        hprintln!(
            "wrap-check: {} insns over {} iterations, expected {} (±40)",
            long,
            LONG,
            want
        );
        harness::check_equal(
            "wrap-check within one tick",
            &(long.abs_diff(want) <= 40),
            &true,
        );
    }

    // const_math::exp: soft-float f64 (the M4F FPU is single precision), used for table builds.
    let mut y = 0.0;
    harness::bench("const_math::exp(f64)", 100, || {
        y = const_math::exp(black_box(0.731_25))
    });
    harness::check_equal("const_math::exp(0)", &const_math::exp(black_box(0.0)), &1.0);
    // Evaluated by the compiler (const eval on the host) vs. soft-float on the M4: must be
    // bit-identical, which is what lets tables be built either way.
    const EXP_CONST: f64 = const_math::exp(0.731_25);
    harness::check_equal(
        "const_math::exp(0.73125) run time == const eval",
        &y.to_bits(),
        &EXP_CONST.to_bits(),
    );

    let a = fill_q15(1);
    let b = fill_q15(2);
    let want = a
        .iter()
        .zip(&b)
        .map(|(&x, &y)| i64::from(x) * i64::from(y))
        .sum::<i64>();
    let mut acc = 0;
    harness::bench("dot_q15[128] (i32 acc)", 1000, || {
        acc = dot_q15(black_box(&a), black_box(&b))
    });
    harness::check_equal("dot_q15[128]", &i64::from(acc), &want);

    let af: [f32; N] = core::array::from_fn(|i| f32::from(a[i]) / 32768.0);
    let bf: [f32; N] = core::array::from_fn(|i| f32::from(b[i]) / 32768.0);
    let mut accf = 0.0;
    harness::bench("dot_f32[128]", 1000, || {
        accf = dot_f32(black_box(&af), black_box(&bf))
    });
    // f32 rounding makes this inexact: compare with the exact value within a tolerance.
    let reff = want as f64 / (32768.0 * 32768.0);
    harness::check_equal(
        "dot_f32[128] ~ f64 reference",
        &((accf as f64 - reff).abs() < 1e-4),
        &true,
    );

    harness::finish()
}
