//! Benchmark harness: semihosting output, result checks and the exit code.
//!
//! - [`bench`] measures a closure with [`crate::insns::measure`] inside a span of the cycle
//!   plugin and prints one line
//!   `bench <name>: <n> insns/iter (<iterations> iterations, <total> insns) [span <id>]`;
//!   `scripts/qemu-bench.sh` joins it with the plugin's cycles of that span.
//! - [`check_equal`] compares a result with its expected value, prints `ok`/`MISMATCH` and records
//!   mismatches; [`finish`] exits QEMU with 0 if there were none and 1 otherwise.
//! - The panic handler (`slipguard_support::semihosting`) prints the panic and exits with 101
//!   (like a failing Rust test).
//!
//! Exit codes go to the host through semihosting (`-semihosting-config enable=on,target=native`)
//! and become `qemu-system-arm`'s own exit status.

use core::fmt::Debug;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m_semihosting::hprintln;

use crate::insns;
use slipguard_support::semihosting::exit;

static CHECKS: AtomicU32 = AtomicU32::new(0);
/// Next cycle-plugin span (0 is the calibration's).
static NEXT_SPAN: AtomicU32 = AtomicU32::new(insns::CALIBRATION_SPAN + 1);
static MISMATCHES: AtomicU32 = AtomicU32::new(0);

/// Measures `iterations` calls of `f` and prints `insns/iter`. Returns the instructions per
/// iteration (rounded down) and the cycle plugin's span id of the measurement. Keep `f`'s
/// inputs and outputs behind `core::hint::black_box` so the compiler cannot hoist or drop the
/// work.
pub fn bench<F: FnMut()>(name: &str, iterations: u32, f: F) -> (u64, u32) {
    let span = next_span();
    insns::span_marker(span, false);
    let total = insns::measure(iterations, f);
    insns::span_marker(span, true);
    let per_iter = total / u64::from(iterations.max(1));
    hprintln!(
        "bench {}: {} insns/iter ({} iterations, {} insns) [span {}]",
        name,
        per_iter,
        iterations,
        total,
        span
    );
    (per_iter, span)
}

/// A fresh span id of the cycle plugin, for a measurement outside [`bench`].
pub fn next_span() -> u32 {
    NEXT_SPAN.fetch_add(1, Ordering::Relaxed)
}

/// Records and prints whether `got == want`. A mismatch makes [`finish`] exit with 1.
pub fn check_equal<T: PartialEq + Debug + ?Sized>(name: &str, got: &T, want: &T) -> bool {
    CHECKS.fetch_add(1, Ordering::Relaxed);
    if got == want {
        hprintln!("check {}: ok", name);
        true
    } else {
        MISMATCHES.fetch_add(1, Ordering::Relaxed);
        hprintln!(
            "check {}: MISMATCH\n  got:  {:?}\n  want: {:?}",
            name,
            got,
            want
        );
        false
    }
}

/// Number of mismatches recorded so far by [`check_equal`].
pub fn mismatches() -> u32 {
    MISMATCHES.load(Ordering::Relaxed)
}

/// Prints a summary and ends the QEMU run: exit 0 if every check passed, 1 otherwise.
pub fn finish() -> ! {
    let checks = CHECKS.load(Ordering::Relaxed);
    let bad = mismatches();
    if bad == 0 {
        hprintln!("result: ok ({} checks)", checks);
        exit(0)
    } else {
        hprintln!("result: FAILED ({} of {} checks mismatched)", bad, checks);
        exit(1)
    }
}
