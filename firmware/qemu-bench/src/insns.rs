//! Executed-instruction counter built on SysTick, exact under `qemu-system-arm -icount shift=0`.
//!
//! With `-icount shift=0` QEMU advances its virtual clock by exactly 1 ns per executed guest
//! instruction. mps2-an386's core clock is 25 MHz, so SysTick clocked from the core
//! (`SYST_CSR = 0b101`: ENABLE | CLKSOURCE, no interrupt) decrements once per 40 instructions,
//! the same on every run and every host. `SYST_RVR = 0xFF_FFFF` gives the full 24-bit range,
//! i.e. one wrap every 2^24 · 40 ≈ 671 M instructions.
//!
//! [`measure`] reads `SYST_CVR` after every iteration and sums the (mod 2^24) differences; the
//! sum telescopes to the exact tick count over the whole span, however many times the counter
//! wraps, as long as a single iteration stays under ~671 M instructions. The fixed cost of that
//! bookkeeping per iteration (calibrated once with an empty body, so it includes a bare call and
//! return) is subtracted, so the result is the instructions of `f`'s body (with its own prologue
//! and epilogue), within ±40 over the whole span (the tick
//! quantum): ±40 / iterations per iteration.
//!
//! On hardware use the DWT cycle counter instead; under QEMU it reads 0. Instructions are not
//! cycles (QEMU models no pipeline, wait states or stalls); compare versions and kernels with them.

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;

/// Executed instructions per SysTick decrement: 1 ns per instruction, 25 MHz core clock.
pub const INSNS_PER_TICK: u64 = 40;
/// SysTick reload value: the whole 24-bit counter.
pub const RELOAD: u32 = 0x00FF_FFFF;
/// Address the instruction-count and cycle plugins watch (`-plugin …,addr=0x20300000`): a
/// store to `MARKER_ADDR + 8·id` opens span `id` of the cycle plugin (`plugin/m4cycles.c`),
/// one to `MARKER_ADDR + 8·id + 4` closes it. Inside RAM, far from `.bss` and the stack.
pub const MARKER_ADDR: usize = 0x2030_0000;
/// The span of the bookkeeping calibration (an empty body), subtracted per iteration.
pub const CALIBRATION_SPAN: u32 = 0;

const UNCALIBRATED: u32 = u32::MAX;
static OVERHEAD_PER_ITER: AtomicU32 = AtomicU32::new(UNCALIBRATED);

/// Starts SysTick as a free-running down-counter on the core clock (SYST_CSR = 0b101,
/// SYST_RVR = 0xFF_FFFF, CVR cleared), then calibrates [`measure`]'s per-iteration overhead.
pub fn init(mut syst: SYST) {
    syst.disable_interrupt();
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(RELOAD);
    syst.clear_current();
    syst.enable_counter();
    calibrate();
}

/// Current SysTick value (SYST_CVR; counts down).
#[inline(always)]
pub fn now() -> u32 {
    SYST::get_current()
}

/// Ticks from `earlier` to `later` readings of [`now`], assuming at most one wrap in between.
#[inline(always)]
pub fn ticks_between(earlier: u32, later: u32) -> u32 {
    earlier.wrapping_sub(later) & RELOAD
}

/// Opens (`end = false`) or closes span `id` of the cycle plugin (if loaded); one store, about
/// 2 instructions. Ids past the plugin's 63 are ignored.
#[inline(always)]
pub fn span_marker(id: u32, end: bool) {
    let addr = MARKER_ADDR + 8 * id as usize + if end { 4 } else { 0 };
    // SAFETY: MARKER_ADDR..+8·64 (the plugin's 64 spans) is in the board's RAM and used by nothing else (see
    // memory.x); the plugin only watches the stores.
    unsafe { core::ptr::write_volatile(addr as *mut u32, id) }
}

/// Runs `f` `iterations` times with the per-iteration SysTick sampling of [`measure`] and
/// returns the raw instruction count, bookkeeping included. One compiled copy (the body is
/// called through `dyn`) so the bookkeeping costs the same for every `f`.
#[inline(never)]
pub fn measure_raw(iterations: u32, f: &mut dyn FnMut()) -> u64 {
    let mut ticks: u64 = 0;
    let mut prev = now();
    for _ in 0..iterations {
        f();
        let t = now();
        ticks += u64::from(ticks_between(prev, t));
        prev = t;
    }
    ticks * INSNS_PER_TICK
}

/// Iterations of the calibration (an empty body).
pub const CALIBRATION_ITERATIONS: u32 = 4000;

fn calibrate() {
    const N: u32 = CALIBRATION_ITERATIONS;
    span_marker(CALIBRATION_SPAN, false);
    let raw = measure_raw(N, &mut || {});
    span_marker(CALIBRATION_SPAN, true);
    // The per-iteration cost is a whole number of instructions; N · 40-insn quantisation and
    // the fixed entry/exit cost amount to well under half an instruction per iteration.
    let per_iter = (raw + u64::from(N) / 2) / u64::from(N);
    OVERHEAD_PER_ITER.store(per_iter as u32, Ordering::Relaxed);
}

/// Per-iteration bookkeeping cost that [`measure`] subtracts (an empty `f`, call included).
pub fn overhead_per_iter() -> u32 {
    let o = OVERHEAD_PER_ITER.load(Ordering::Relaxed);
    assert!(o != UNCALIBRATED, "insns::init has not run");
    o
}

/// Instructions executed by `iterations` calls of `f` (a `dyn` call each), bookkeeping
/// subtracted. Divide by `iterations` for instructions per call. Deterministic under
/// `-icount shift=0`; exact to ±40 over the whole span.
pub fn measure<F: FnMut()>(iterations: u32, mut f: F) -> u64 {
    let overhead = u64::from(overhead_per_iter()) * u64::from(iterations);
    measure_raw(iterations, &mut f).saturating_sub(overhead)
}
