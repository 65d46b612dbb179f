//! The cycle model's fetch-bandwidth probe: a straight-line block of 32-bit instructions four
//! times the size of the STM32F4 ART accelerator's instruction cache (64 lines of 16 bytes), and
//! a small loop that stays in that cache. Both run inside spans of the cycle plugin;
//! `cycles-report.awk` checks that the block runs at no better than 4 instructions per 6 cycles
//! (one 16-byte flash line per ws + 1 = 6 cycles: the model's fetch bandwidth) and that the
//! resident loop runs at close to 1 cycle per instruction (the cache hides the flash).

use cortex_m_semihosting::hprintln;

use crate::{harness, insns};

/// Instructions in the straight-line block (32-bit each: 4 KiB, 4 × the 1 KiB cache).
const STRAIGHT_INSNS: usize = 1024;
/// Runs of each probe inside its span.
const RUNS: u32 = 4;
/// Passes of the resident loop per run (18 instructions each: 16 ADDs, SUBS, BNE).
const LOOP_PASSES: u32 = 256;

/// 1024 single-cycle `add.w` (32-bit encodings), 16-byte aligned: 256 flash lines in a row.
#[inline(never)]
fn straight_block() {
    // SAFETY: only r0 changes (declared); no memory, no stack, no flags.
    unsafe {
        core::arch::asm!(
            ".p2align 4",
            ".rept {n}",
            "add.w r0, r0, #1",
            ".endr",
            n = const STRAIGHT_INSNS,
            out("r0") _,
            options(nomem, nostack, preserves_flags),
        );
    }
}

/// A loop of 16 `add.w`, SUBS and BNE (72 bytes), `passes` times.
#[inline(never)]
fn resident_loop(passes: u32) {
    // SAFETY: only r0, r1 and the flags change (declared); no memory, no stack.
    unsafe {
        core::arch::asm!(
            ".p2align 4",
            "2:",
            ".rept 16",
            "add.w r0, r0, #1",
            ".endr",
            "subs r1, r1, #1",
            "bne 2b",
            out("r0") _,
            inout("r1") passes => _,
            options(nomem, nostack),
        );
    }
}

/// Runs both probes in their own spans and prints
/// `fetch probe: straight=SPAN loop=SPAN bytes=B` for the cycle report.
pub fn probe() {
    let straight = harness::next_span();
    insns::span_marker(straight, false);
    for _ in 0..RUNS {
        straight_block();
    }
    insns::span_marker(straight, true);
    let looped = harness::next_span();
    insns::span_marker(looped, false);
    for _ in 0..RUNS {
        resident_loop(core::hint::black_box(LOOP_PASSES));
    }
    insns::span_marker(looped, true);
    hprintln!(
        "fetch probe: straight={} loop={} bytes={}",
        straight,
        looped,
        4 * STRAIGHT_INSNS
    );
}
