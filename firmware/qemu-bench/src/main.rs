//! Instruction-count benchmark and bit-exact check of slipguard-core on a Cortex-M4F emulated by
//! QEMU (`-M mps2-an386 -icount shift=0`). Output goes to the host through semihosting; the exit
//! code is 0 when every check passed, 1 on a mismatch, 101 on a panic.
//!
//! It runs the golden vectors of `firmware/core/tests/fixtures/bench/` (a paper-sized variant
//! (c) model, hidden 128, and a 200-step force trace): every step's p(unstable), flag and a CRC
//! of the LSTM state must equal what the host core produced (`expected.bin`, pinned by the
//! host test `golden_vectors`). Then it counts instructions per channel step and per part.
//!
//! Modules: [`insns`] (SysTick instruction counter) and [`harness`] (output, checks, exit codes).
#![no_std]
#![no_main]

mod harness;
mod insns;

use core::hint::black_box;
use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use slipguard_core::blob::CRC32;
use slipguard_core::const_math;
use slipguard_core::decision::p_unstable;
use slipguard_core::features::stft::{StftConfig, StftPlan, StftState};
use slipguard_core::lstm::{self, LstmState};
use slipguard_core::model::{ChannelState, Model};

/// The blob must be 4-byte aligned to be read in place, as in the firmware's flash section.
#[repr(C, align(4))]
struct Aligned<T: ?Sized>(T);

static BLOB: &Aligned<[u8]> =
    &Aligned(*include_bytes!("../../core/tests/fixtures/bench/model.bin"));
static INPUT: &[u8] = include_bytes!("../../core/tests/fixtures/bench/input.bin");
static EXPECTED: &[u8] = include_bytes!("../../core/tests/fixtures/bench/expected.bin");

/// Bytes per step in `expected.bin`: p (i16), flag (u8), 0 (u8), CRC-32 of h and c (u32).
const RECORD: usize = 8;

fn input(i: usize) -> i32 {
    let b = &INPUT[4 * i..4 * i + 4];
    i32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// The same per-step record the host test writes.
fn record(out: slipguard_core::model::StepOutput, st: &ChannelState) -> [u8; RECORD] {
    let mut digest = CRC32.digest();
    for l in &st.lstm {
        for v in l.h.iter().chain(&l.c) {
            digest.update(&v.to_le_bytes());
        }
    }
    let p = out.p_unstable_q15.to_le_bytes();
    let c = digest.finalize().to_le_bytes();
    [p[0], p[1], out.unstable as u8, 0, c[0], c[1], c[2], c[3]]
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

    // Tables built at run time with soft-float f64 must equal the compiler's const evaluation.
    const EXP_CONST: f64 = const_math::exp(0.731_25);
    harness::check_equal(
        "const_math::exp run time == const eval",
        &const_math::exp(black_box(0.731_25)).to_bits(),
        &EXP_CONST.to_bits(),
    );

    let model = match Model::from_bytes(&BLOB.0) {
        Ok(m) => m,
        Err(e) => {
            hprintln!("golden model refused: {}", e);
            harness::check_equal("golden model parses", &false, &true);
            harness::finish()
        }
    };
    let steps = INPUT.len() / 4;
    let macs = model.config().macs_per_step() as u64;
    hprintln!(
        "model: variant {}, hidden {}, {} MACs per channel step, blob {} bytes",
        model.config().variant.name(),
        model.config().hidden[0],
        macs,
        BLOB.0.len()
    );

    // 1. Bit-exact check: every step against the host's record.
    let mut st = ChannelState::new();
    let mut first_bad = None;
    for i in 0..steps {
        let got = record(model.step(&mut st, input(i)), &st);
        if got[..] != EXPECTED[RECORD * i..RECORD * (i + 1)] && first_bad.is_none() {
            first_bad = Some(i);
        }
    }
    harness::check_equal(
        "all steps equal the host (first differing step)",
        &first_bad,
        &None,
    );

    // 2. Whole channel step: sample → STFT → normalise → LSTM → dense → decision.
    let mut st = ChannelState::new();
    let mut i = 0;
    // Markers #1/#2 bracket this span for the exact insncount plugin (../shared/tools/qemu-plugins).
    insns::marker(1);
    let step = harness::bench("channel step (variant c, H=128)", steps as u32, || {
        black_box(model.step(&mut st, black_box(input(i % steps))));
        i += 1;
    });
    insns::marker(2);

    // 3. Parts, on the same model and inputs.
    let blob = model.blob();
    let lstm_t = blob.lstm[0];
    let mut ls = LstmState::new();
    let x = [
        1234i16, -2345, 345, 456, -567, 678, 789, -890, 901, 120, -230,
    ];
    let lstm_insns = harness::bench("LSTM cell step (11 -> 128)", 50, || {
        lstm::step(black_box(&lstm_t), &mut ls, black_box(&x));
    });
    let h = ls.h;
    harness::bench("dense + softmax (128 -> p)", 200, || {
        black_box(p_unstable(black_box(&blob.dense), &[black_box(&h[..128])]));
    });
    let plan = match StftPlan::new(StftConfig::PAPER) {
        Ok(p) => p,
        Err(_) => harness::finish(),
    };
    let mut ss = StftState::new();
    let mut out = [0i16; 10];
    let mut j = 0u32;
    harness::bench("STFT step (N=20, 10 bands)", 200, || {
        j += 1;
        plan.step(
            &mut ss,
            black_box((j.wrapping_mul(2_654_435_761) >> 17) as i16),
            &mut out,
        );
        black_box(&out);
    });

    let lstm_macs = macs - 2 * 128;
    hprintln!(
        "summary: {} insns per channel step = {:.3} insns per MAC ({} MACs); LSTM cell alone {:.3} insns per MAC",
        step,
        step as f32 / macs as f32,
        macs,
        lstm_insns as f32 / lstm_macs as f32
    );
    // 16 channels at 16.7 Hz and 40 Hz on a 168 MHz M4, counting one instruction as one cycle
    // (a lower bound: QEMU models no wait states or pipeline stalls).
    let frame = (step * 16) as f32;
    hprintln!(
        "summary: 16-channel frame {} insns; at 168 MHz: 16.7 Hz -> {:.2} % CPU, 40 Hz -> {:.2} % CPU",
        step * 16,
        frame * 16.7 / 168e6 * 100.0,
        frame * 40.0 / 168e6 * 100.0
    );
    harness::finish()
}
