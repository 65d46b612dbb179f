//! Instruction-count benchmark and bit-exact check of slipguard-core on a Cortex-M4F emulated by
//! QEMU (`-M mps2-an386 -icount shift=0`). Output goes to the host through semihosting; the exit
//! code is 0 when every check passed, 1 on a mismatch, 101 on a panic.
//!
//! It runs the golden vectors of `firmware/core/tests/fixtures/bench/` (a paper-sized variant
//! (c) model, hidden 128, and a 200-step force trace): every step's p(unstable), flag and a CRC
//! of the LSTM state must equal what the host core produced (`expected.bin`, pinned by the
//! host test `golden_vectors`). Then it counts instructions per channel step and per part.
//!
//! Last, the cycle model's fetch-bandwidth probe ([`fetch`]).
//!
//! Modules: [`insns`] (SysTick instruction counter), [`harness`] (output, checks, exit codes) and
//! [`fetch`] (the fetch-bandwidth probe).
#![no_std]
#![no_main]

mod fetch;
mod harness;
mod insns;

use core::hint::black_box;
use core::mem::MaybeUninit;
use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use slipguard_core::blob::{CRC32, LstmRowParams};
use slipguard_core::const_math;
use slipguard_core::decision::p_unstable;
use slipguard_core::dsp::{
    BLOCK_ROWS, MAX_ASM_H_WORDS, MAX_ASM_VALUES, MAX_ASM_X_WORDS, MAX_BLOCK_H_CHUNKS,
    MAX_BLOCK_X_CHUNKS, dot_i8_i16, dot_i8_i16_fast, lstm_block_sums, lstm_gate_sums,
    lstm_gate_sums_portable, pack_lstm_blocks, permute_q15, permute_q15_uninit,
};
use slipguard_core::features::stft::{StftConfig, StftPlan, StftState};
use slipguard_core::lstm::{self, LstmState};
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::model_ram::{MODEL_RAM_BYTES, ModelRam};
use slipguard_core::sample::PAPER_RATE_HZ;

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

/// xorshift32: deterministic test data.
struct Rng(u32);

impl Rng {
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.0 = x;
        x
    }

    /// One i16 input of a check's `pattern`: 0 random, 1 all `i16::MIN`, else `i16::MIN` or
    /// `i16::MAX` by the random word's `bit` (the extremes the kernels' saturation must take).
    fn i16_pattern(&mut self, pattern: u32, bit: u32) -> i16 {
        let r = self.next();
        match pattern {
            0 => r as i16,
            1 => i16::MIN,
            _ if r & bit == 0 => i16::MIN,
            _ => i16::MAX,
        }
    }
}

/// Longest vector the kernel checks cover (every length 0..=MAX_N, odd ones included).
const MAX_N: usize = 136;
/// Rows per kernel call in the checks (several, so the row loop is exercised).
const ROWS: usize = 3;
/// Longest row stride in the checks: longer than the longest vector, a multiple of 4.
const STRIDE: usize = MAX_N + 8;

/// Weight rows, word-aligned like the blob (the kernels load them by words), plus 4 spare
/// bytes so that a misaligned view of the same rows can test the portable fallback.
#[repr(C, align(4))]
struct Rows([i8; ROWS * STRIDE + 4]);

/// The LSTM kernel's h part in assembly (on this target; no x part, so rows are contiguous at
/// a stride of 4·words) against the plain dot product `dot_i8_i16`, an independent reference,
/// for every length 0..=MAX_N on random and on extreme data. Weights past a vector's length in
/// its last word are random junk (they meet the zero padding of the permuted activations).
fn check_dsp_kernel() {
    hprintln!(
        "dsp kernel: assembly up to {} values per row",
        MAX_ASM_VALUES
    );
    let mut rng = Rng(0x1234_5678);
    // Weight and activation patterns: random, and the extremes whose products are largest.
    type Pattern = fn(&mut Rng, usize) -> (i8, i16);
    let patterns: [(&str, Pattern); 5] = [
        ("random", |r, _| (r.next() as i8, (r.next() >> 7) as i16)),
        ("-128 x -32768", |_, _| (-128, i16::MIN)),
        ("127 x 32767", |_, _| (127, i16::MAX)),
        ("-128 x 32767 / 127 x -32768", |_, i| {
            if i % 2 == 0 {
                (-128, i16::MAX)
            } else {
                (127, i16::MIN)
            }
        }),
        ("random extremes", |r, _| {
            let x = r.next();
            (
                if x & 1 == 0 { -128 } else { 127 },
                if x & 2 == 0 { i16::MIN } else { i16::MAX },
            )
        }),
    ];
    for (name, pattern) in patterns {
        let mut vs_plain = None;
        for n in 0..=MAX_N {
            let stride = 4 * n.div_ceil(4);
            let mut w = Rows([0; ROWS * STRIDE + 4]);
            let mut v = [0i16; MAX_N];
            for (i, x) in w.0[..ROWS * stride].iter_mut().enumerate() {
                *x = if i % stride.max(1) < n {
                    pattern(&mut rng, i).0
                } else {
                    rng.next() as i8
                };
            }
            for (i, x) in v[..n].iter_mut().enumerate() {
                *x = pattern(&mut rng, i).1;
            }
            let mut act = [0u32; MAX_N / 2];
            let words = permute_q15(&v[..n], &mut act);
            let rows = &w.0[..ROWS * stride];
            let mut buf = [core::mem::MaybeUninit::uninit(); ROWS];
            let got = lstm_gate_sums(black_box(rows), stride, 0, &[], &act[..words], &mut buf);
            let fast: [i32; ROWS] = core::array::from_fn(|r| got[r][1]);
            let plain: [i32; ROWS] =
                core::array::from_fn(|r| dot_i8_i16(&rows[r * stride..][..n], &v[..n]));
            if fast != plain && vs_plain.is_none() {
                vs_plain = Some((n, fast, plain));
            }
        }
        hprintln!("dsp kernel, {}:", name);
        harness::check_equal("  asm == dot_i8_i16 (first n, got, want)", &vs_plain, &None);
    }
}

/// Rows per call in the LSTM kernel checks.
const LSTM_ROWS: usize = 3;
/// Largest row (bytes) in the LSTM kernel checks: both parts at their assembly maximum.
const LSTM_MAX_ROW: usize = 4 * (MAX_ASM_X_WORDS + MAX_ASM_H_WORDS);

/// LSTM gate rows, word-aligned, plus 4 spare bytes for a misaligned view.
#[repr(C, align(4))]
struct LstmRows([i8; LSTM_ROWS * LSTM_MAX_ROW + 4]);

/// The fused LSTM kernel (`lstm_gate_sums`, assembly on this target) against its portable
/// reference for every x length 0..=MAX_ASM_X_WORDS words and h length 0..=MAX_ASM_H_WORDS
/// words, on random and extreme data; also the layouts it must leave to the portable code
/// (gaps between the parts, misaligned weights, too few weights).
fn check_lstm_kernel() {
    let mut rng = Rng(0x0bad_cafe);
    let mut first_bad: Option<(&str, usize, usize)> = None;
    let mut cases = 0u32;
    for pattern in 0..3u32 {
        for xw in 0..=MAX_ASM_X_WORDS {
            for hw in 0..=MAX_ASM_H_WORDS {
                let mut w = LstmRows([0; LSTM_ROWS * LSTM_MAX_ROW + 4]);
                for b in w.0.iter_mut() {
                    let r = rng.next();
                    *b = match pattern {
                        0 => r as i8,
                        1 => -128,
                        _ => {
                            if r & 1 == 0 {
                                -128
                            } else {
                                127
                            }
                        }
                    };
                }
                let mut act = [0u32; 2 * (MAX_ASM_X_WORDS + MAX_ASM_H_WORDS)];
                for a in act.iter_mut() {
                    let r = rng.next();
                    *a = match pattern {
                        0 => r,
                        1 => 0x8000_8000,
                        _ => {
                            (if r & 1 == 0 { 0x8000 } else { 0x7fff })
                                | (if r & 2 == 0 { 0x8000_0000 } else { 0x7fff_0000 })
                        }
                    };
                }
                let (x, h) = act.split_at(2 * xw);
                let h = &h[..2 * hw];
                let hh = 4 * xw;
                let stride = hh + 4 * hw;
                // Contiguous rows (the assembly path), a gap after each part, a misaligned view
                // and a weight slice one byte too short (both portable).
                let layouts: [(&str, usize, usize, usize, usize); 4] = [
                    ("contiguous", 0, stride, hh, LSTM_ROWS * stride),
                    ("gaps", 0, stride + 4, hh + 4, LSTM_ROWS * (stride + 4)),
                    ("misaligned", 1, stride, hh, LSTM_ROWS * stride),
                    (
                        "short",
                        0,
                        stride,
                        hh,
                        (LSTM_ROWS * stride).saturating_sub(1),
                    ),
                ];
                for (name, start, stride, hh, len) in layouts {
                    let len = len.min(LSTM_ROWS * LSTM_MAX_ROW);
                    let wv = &w.0[start..start + len];
                    let mut buf = [MaybeUninit::<[i32; 2]>::uninit(); LSTM_ROWS];
                    let got = lstm_gate_sums(black_box(wv), stride, hh, x, h, &mut buf);
                    let mut want = [[0i32; 2]; LSTM_ROWS];
                    lstm_gate_sums_portable(wv, stride, hh, x, h, &mut want);
                    cases += 1;
                    if got[..] != want[..] && first_bad.is_none() {
                        first_bad = Some((name, xw, hw));
                    }
                }
            }
        }
    }
    hprintln!("lstm kernel: {} cases", cases);
    harness::check_equal(
        "lstm kernel == portable (first layout, x words, h words)",
        &first_bad,
        &None,
    );
}

/// Rows per call in the blocked-kernel checks: two blocks.
const BLOCK_CHECK_ROWS: usize = 2 * BLOCK_ROWS;
/// Largest row (bytes) in the blocked-kernel checks: both parts at their assembly maximum.
const BLOCK_MAX_ROW: usize = 4 * (MAX_BLOCK_X_CHUNKS + MAX_BLOCK_H_CHUNKS);

/// Weights for the blocked-kernel checks, word-aligned, plus 4 spare bytes for a misaligned view.
#[repr(C, align(4))]
struct BlockRows([i8; BLOCK_CHECK_ROWS * BLOCK_MAX_ROW + 4]);

/// The register-blocked LSTM kernel (`lstm_block_sums`, assembly on this target) on weights
/// packed by `pack_lstm_blocks` against the row-major portable kernel on the original weights
/// (`lstm_gate_sums_portable`, an independent path: other layout, other activation order), for
/// every x part of 0..=MAX_BLOCK_X_CHUNKS chunks and h part of 0..=MAX_BLOCK_H_CHUNKS chunks, on
/// random and extreme data; the full h part (the full-h kernel's block loop, every x entry)
/// with 8 more random rounds; plus a misaligned view (the portable fallback).
fn check_block_kernel() {
    let mut rng = Rng(0xb10c_0001);
    let mut first_bad: Option<(&str, u32, usize, usize)> = None;
    let mut cases = 0u32;
    for round in 0..12u32 {
        // Rounds 0..4: the four data patterns; from 4 on, random data for the full h part.
        let pattern = if round < 4 { round } else { 0 };
        for xc in 0..=MAX_BLOCK_X_CHUNKS {
            for hc in 0..=MAX_BLOCK_H_CHUNKS {
                if round >= 4 && hc != MAX_BLOCK_H_CHUNKS {
                    continue;
                }
                let (hh, stride) = (4 * xc, 4 * (xc + hc));
                let len = BLOCK_CHECK_ROWS * stride;
                // Row-major weights in [-127, 127] (the exporter's range), -128 in a rows too.
                let mut w = BlockRows([0; BLOCK_CHECK_ROWS * BLOCK_MAX_ROW + 4]);
                for (i, b) in w.0[..len].iter_mut().enumerate() {
                    let r = rng.next();
                    let a_row = (i / stride.max(1)) % 2 == 0;
                    *b = match pattern {
                        0 => ((r % 255) as i32 - 127) as i8,
                        1 => {
                            if a_row {
                                -128
                            } else {
                                -127
                            }
                        }
                        2 => {
                            if r & 1 == 0 {
                                -127
                            } else {
                                127
                            }
                        }
                        _ => {
                            if a_row && r & 2 == 0 {
                                -128
                            } else if r & 1 == 0 {
                                -127
                            } else {
                                127
                            }
                        }
                    };
                }
                let mut v = [0i16; 4 * (MAX_BLOCK_X_CHUNKS + MAX_BLOCK_H_CHUNKS)];
                for x in v[..stride].iter_mut() {
                    *x = rng.i16_pattern(pattern, 4);
                }
                let (xv, hv) = v[..stride].split_at(hh);
                let natural = |v: &[i16], out: &mut [u32]| {
                    for (o, p) in out.iter_mut().zip(v.chunks(2)) {
                        *o = p[0] as u16 as u32 | (p[1] as u16 as u32) << 16;
                    }
                };
                let (mut xn, mut hn) = (
                    [0u32; 2 * MAX_BLOCK_X_CHUNKS],
                    [0u32; 2 * MAX_BLOCK_H_CHUNKS],
                );
                natural(xv, &mut xn);
                natural(hv, &mut hn);
                let (mut xp, mut hp) = (
                    [0u32; 2 * MAX_BLOCK_X_CHUNKS],
                    [0u32; 2 * MAX_BLOCK_H_CHUNKS],
                );
                let xpn = permute_q15(xv, &mut xp);
                let hpn = permute_q15(hv, &mut hp);
                let mut want = [[0i32; 2]; BLOCK_CHECK_ROWS];
                lstm_gate_sums_portable(&w.0[..len], stride, hh, &xp[..xpn], &hp[..hpn], &mut want);
                let mut packed = BlockRows([0; BLOCK_CHECK_ROWS * BLOCK_MAX_ROW + 4]);
                if !pack_lstm_blocks(&w.0[..len], stride, &mut packed.0[..len]) && stride > 0 {
                    first_bad.get_or_insert(("pack refused", round, xc, hc));
                    continue;
                }
                // Aligned (assembly), then one byte off (portable fallback, after a copy).
                for (name, start) in [("aligned", 0), ("misaligned", 1)] {
                    if start == 1 {
                        packed.0.copy_within(0..len, 1);
                    }
                    let wv = &packed.0[start..start + len];
                    let mut buf = [MaybeUninit::<[i32; 2]>::uninit(); BLOCK_CHECK_ROWS];
                    let got = lstm_block_sums(
                        black_box(wv),
                        stride,
                        hh,
                        &xn[..xc * 2],
                        &hn[..hc * 2],
                        &mut buf,
                    );
                    cases += 1;
                    if got[..] != want[..] {
                        first_bad.get_or_insert((name, round, xc, hc));
                    }
                }
            }
        }
    }
    hprintln!("lstm blocked kernel: {} cases", cases);
    harness::check_equal(
        "lstm blocked kernel == row-major portable (first layout, round, x chunks, h chunks)",
        &first_bad,
        &None,
    );
}

/// The assembly gate pass (`lstm::gate_activations`) against the Rust one, σ and tanh, on
/// random sums and parameters: shifts 33..=62 (assembly) mixed with 1..=32 (the rows the
/// assembly leaves to Rust), extreme sums, biases and multipliers; and the folded gate pass of a
/// RAM image (`lstm::gate_activations_folded`) on the rows that fold, against the blob rows.
fn check_gate_pass() {
    let mut rng = Rng(0x5eed_1234);
    let mut first_bad = None;
    let (mut first_folded_bad, mut folded_rows) = (None, 0usize);
    for round in 0..40u32 {
        let mut acc = [[0i32; 2]; 64];
        let mut params = [LstmRowParams {
            mx: 0,
            mh: 0,
            bias_q12: 0,
            shift: 33,
        }; 64];
        for (i, (a, p)) in acc.iter_mut().zip(params.iter_mut()).enumerate() {
            let edge = |r: u32, bits: u32| -> i32 {
                match r % 5 {
                    0 => (1 << (bits - 1)) - 1,
                    1 => -(1 << (bits - 1)),
                    _ => (rng_bits(r) as i32) >> (32 - bits),
                }
            };
            *a = [edge(rng.next(), 26), edge(rng.next(), 29)];
            p.mx = (rng.next() >> 1) as i32;
            p.mh = (rng.next() >> 1) as i32;
            p.bias_q12 = if i % 7 == 0 {
                rng.next() as i32
            } else {
                (rng.next() as i32) >> 17
            };
            // Mostly the assembly's range; every few rows (more in later rounds) a small shift.
            p.shift = if rng.next() % 8 < round % 4 {
                1 + (rng.next() % 32) as i32
            } else {
                33 + (rng.next() % 30) as i32
            };
        }
        for tanh in [false, true] {
            let mut got = acc;
            let mut want = acc;
            lstm::gate_activations(black_box(&mut got), &params, tanh);
            lstm::gate_activations_portable(&mut want, &params, tanh);
            if got != want && first_bad.is_none() {
                first_bad = Some((round, tanh));
            }
        }
        // The folded rows of a RAM image (`lstm::fold_row`), assembly and Rust, against the
        // blob rows' Rust gate pass: every row of the round that folds, 1..=64 of them (every
        // loop entry), the count varied by round.
        let mut fa = [[0i32; 2]; 64];
        let mut fp = [params[0]; 64];
        let mut op = [params[0]; 64];
        let mut m = 0;
        for (a, p) in acc.iter().zip(&params) {
            if let (Some(f), true) = (lstm::fold_row(p), m < 64 - (round as usize % 4)) {
                (fa[m], fp[m], op[m]) = (*a, f, *p);
                m += 1;
            }
        }
        // All of them (8-row passes and single rows), and short counts (single rows only).
        for (len, tanh) in [(m, false), (m, true), (m.min(1), false), (m.min(7), true)] {
            let (mut got, mut port, mut want) = (fa, fa, fa);
            lstm::gate_activations_folded(black_box(&mut got[..len]), &fp[..len], tanh);
            lstm::gate_activations_folded_portable(&mut port[..len], &fp[..len], tanh);
            lstm::gate_activations_portable(&mut want[..len], &op[..len], tanh);
            if (got != want || port != want) && first_folded_bad.is_none() {
                first_folded_bad = Some((round, tanh));
            }
            folded_rows += len;
        }
    }
    hprintln!("lstm gate pass, folded rows: {} rows", folded_rows);
    harness::check_equal(
        "lstm folded gate pass asm == portable == blob rows (first round, tanh)",
        &first_folded_bad,
        &None,
    );
    harness::check_equal(
        "lstm gate pass asm == portable (first round, tanh)",
        &first_bad,
        &None,
    );
}

/// Spreads a random word's bits (a helper for [`check_gate_pass`]).
fn rng_bits(r: u32) -> u32 {
    r.wrapping_mul(0x9E37_79B9)
}

/// The assembly cell update (`lstm::cell_update`) against the Rust one for every cell format
/// 1..=15 and hidden sizes 1..=128, on random and extreme gates and cell states.
fn check_cell_update() {
    let mut rng = Rng(0xce11_0001);
    let mut first_bad = None;
    for cb in 1..=15u32 {
        for hn in [1usize, 2, 7, 64, 127, 128] {
            let mut gates = [[0i32; 2]; 4 * 128];
            for (r, g) in gates.iter_mut().enumerate() {
                let x = rng.next();
                let v = match (x >> 20) % 4 {
                    0 => i16::MIN,
                    1 => i16::MAX,
                    _ => x as i16,
                };
                // Sigmoid gates are 0..=32767 in the model; any i16 must still agree.
                g[0] = if r % 3 == 0 {
                    v as i32
                } else {
                    (v as i32).abs().min(32767)
                };
                g[1] = rng.next() as i32;
            }
            let mut st = LstmState::new();
            for (c, h) in st.c.iter_mut().zip(st.h.iter_mut()) {
                let x = rng.next();
                *c = match x % 5 {
                    0 => i16::MIN,
                    1 => i16::MAX,
                    _ => (x >> 8) as i16,
                };
                *h = (x >> 3) as i16;
            }
            let k = lstm::CellShifts::new(cb);
            let mut got = st.clone();
            lstm::cell_update(black_box(&gates[..4 * hn]), hn, &mut got, k);
            let mut want = st;
            lstm::cell_update_portable(&gates[..4 * hn], hn, &mut want, k);
            if got != want && first_bad.is_none() {
                first_bad = Some((cb, hn));
            }
        }
    }
    harness::check_equal(
        "lstm cell update asm == portable (first C, H)",
        &first_bad,
        &None,
    );
}

/// Activations, word-aligned (the natural-order kernel loads them by words), plus a spare one
/// for a misaligned view.
#[repr(C, align(4))]
struct Acts([i16; MAX_N + 2]);

/// `dsp::isqrt_u32` (VSQRT.F32 and a correction on this target) against `u32::isqrt`: the
/// ends, every k² − 1, k², k² + 1 for k = 0..=65535, and 20 000 random values.
fn check_isqrt() {
    let mut rng = Rng(0x5a27_0001);
    let mut first_bad = None;
    let mut check = |n: u32| {
        if slipguard_core::dsp::isqrt_u32(black_box(n)) != n.isqrt() && first_bad.is_none() {
            first_bad = Some(n);
        }
    };
    for n in [0, 1, 2, 3, u32::MAX, u32::MAX - 1, 1 << 31, (1 << 24) + 1] {
        check(n);
    }
    for k in 0..=65535u32 {
        let sq = k * k;
        check(sq);
        check(sq.wrapping_sub(1));
        check(sq.saturating_add(1));
        check(sq.saturating_add(2 * k));
    }
    for _ in 0..20_000 {
        let r = rng.next();
        check(r);
        check(r >> (r % 32));
    }
    harness::check_equal("isqrt_u32 == u32::isqrt (first n)", &first_bad, &None);
}

/// `dsp::stft_bin_sums_rows` (SMLALBB/SMLALBT on this target) against
/// `stft_row_sums_portable` per bin, for every split of windows up to 48 samples (odd and even
/// segment lengths, odd start addresses), 1 to 5 bins, random and extreme samples and twiddles.
fn check_stft_rows() {
    use core::mem::MaybeUninit;
    let mut rng = Rng(0x57f7_0001);
    let mut first_bad = None;
    let mut x = [0i16; 49];
    let mut rows = [0u32; 5 * 48 + 3];
    for pattern in 0..3u32 {
        for n in 0..=48usize {
            for v in x.iter_mut() {
                *v = rng.i16_pattern(pattern, 1);
            }
            for w in rows.iter_mut() {
                let r = rng.next();
                *w = match pattern {
                    0 => r,
                    1 => 0x8000_8000,
                    _ => [0x8000_8000, 0x7fff_7fff, 0x8000_7fff, 0x7fff_8000][(r % 4) as usize],
                };
            }
            for head in 0..=n {
                // Start at x[1] for odd addresses half of the time.
                let at = (head + n) % 2;
                let (newer, older) = x[at..at + n].split_at(head);
                let bins = 1 + head % 5;
                let mut out = [MaybeUninit::uninit(); 5];
                let got = slipguard_core::dsp::stft_bin_sums_rows(
                    black_box(older),
                    black_box(newer),
                    &rows[..bins * n + head % 3],
                    &mut out[..bins],
                );
                for (b, g) in got.iter().enumerate() {
                    let row = &rows[b * n..(b + 1) * n];
                    let want = slipguard_core::dsp::stft_row_sums_portable(older, newer, row);
                    if *g != want && first_bad.is_none() {
                        first_bad = Some((pattern, n, head, b));
                    }
                }
            }
        }
    }
    harness::check_equal(
        "stft_bin_sums_rows asm == portable (first pattern, n, head, bin)",
        &first_bad,
        &None,
    );
}

/// `dot_i8_i16_fast` (assembly for whole groups of 8 on this target) against `dot_i8_i16`
/// for every length 0..=MAX_N, random and extreme data, aligned and misaligned.
fn check_dense_kernel() {
    let mut rng = Rng(0xde25_e000);
    let mut first_bad = None;
    for pattern in 0..3u32 {
        for n in 0..=MAX_N {
            let mut w = Rows([0; ROWS * STRIDE + 4]);
            let mut v = Acts([0; MAX_N + 2]);
            for b in w.0.iter_mut() {
                let r = rng.next();
                *b = match pattern {
                    0 => r as i8,
                    1 => -128,
                    _ => {
                        if r & 1 == 0 {
                            -128
                        } else {
                            127
                        }
                    }
                };
            }
            for x in v.0.iter_mut() {
                *x = rng.i16_pattern(pattern, 1);
            }
            for (wo, vo) in [(0, 0), (1, 0), (0, 1)] {
                let (ws, vs) = (&w.0[wo..wo + n], &v.0[vo..vo + n]);
                let got = dot_i8_i16_fast(black_box(ws), vs);
                let want = dot_i8_i16(ws, vs);
                if got != want && first_bad.is_none() {
                    first_bad = Some((pattern, n, wo, vo));
                }
            }
        }
    }
    // The permutation's assembly (groups of 8 values, aligned) against the portable one.
    let mut bad_perm = None;
    for n in 0..=MAX_N {
        for off in [0, 1] {
            let v = Acts(core::array::from_fn(|i| {
                (i as i16).wrapping_mul(-3217) ^ 0x5a5a
            }));
            let vs = &v.0[off..off + n];
            let mut want = [0u32; MAX_N / 2 + 2];
            let k = permute_q15(vs, &mut want);
            let mut buf = [MaybeUninit::<u32>::uninit(); MAX_N / 2 + 2];
            let got = permute_q15_uninit(black_box(vs), &mut buf);
            if got != &want[..k] && bad_perm.is_none() {
                bad_perm = Some((n, off));
            }
        }
    }
    harness::check_equal(
        "permute_q15_uninit == permute_q15 (first n, offset)",
        &bad_perm,
        &None,
    );
    harness::check_equal(
        "dense kernel dot_i8_i16_fast == dot_i8_i16 (first pattern, n, offsets)",
        &first_bad,
        &None,
    );
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

    check_dsp_kernel();
    check_lstm_kernel();
    check_block_kernel();
    check_gate_pass();
    check_cell_update();
    check_dense_kernel();
    check_isqrt();
    check_stft_rows();

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

    // The blob copied into RAM, as the firmware does at boot: the kernels then read their
    // weights without flash wait states. Every figure below uses the copy but the first.
    let mut ram = ModelRam::<MODEL_RAM_BYTES>::new();
    let ram_model = match ram.load(&BLOB.0).map(Model::from_bytes) {
        Ok(Ok(m)) => m,
        _ => {
            hprintln!("golden model not copied to RAM");
            harness::check_equal("golden model copied to RAM", &false, &true);
            harness::finish()
        }
    };

    // A plain copy in RAM (row-major weights, the row kernel): what the RAM image adds beyond
    // taking the weights out of flash. A buffer of exactly the blob's size leaves no room for
    // the image's CRC, so `load` makes a plain copy.
    let mut plain = ModelRam::<80_432>::new();
    let plain_model = match plain.load(&BLOB.0).map(Model::from_bytes) {
        Ok(Ok(m)) if !m.blob().lstm[0].blocked => m,
        _ => {
            hprintln!("golden model not copied to RAM as a plain copy");
            harness::check_equal("golden model copied to RAM (plain)", &false, &true);
            harness::finish()
        }
    };

    // 1. Bit-exact check: every step against the host's record, from flash and from RAM.
    for (name, model) in [
        ("flash", &model),
        ("RAM (image)", &ram_model),
        ("RAM (plain copy)", &plain_model),
    ] {
        let mut st = ChannelState::new();
        let mut first_bad = None;
        for i in 0..steps {
            let got = record(model.step(&mut st, input(i)), &st);
            if got[..] != EXPECTED[RECORD * i..RECORD * (i + 1)] && first_bad.is_none() {
                first_bad = Some(i);
            }
        }
        hprintln!("model in {}:", name);
        harness::check_equal(
            "  all steps equal the host (first differing step)",
            &first_bad,
            &None,
        );
    }

    // 2. Whole channel step: sample → STFT → normalise → LSTM → dense → decision.
    let step_bench = |name: &str, model: &Model<'_>| {
        let mut st = ChannelState::new();
        let mut i = 0;
        harness::bench(name, steps as u32, || {
            black_box(model.step(&mut st, black_box(input(i % steps))));
            i += 1;
        })
    };
    let (step_flash, span_flash) = step_bench("channel step, weights in flash", &model);
    let (_, span_plain) = step_bench("channel step, plain RAM copy (row kernel)", &plain_model);
    let (step, span_step) = step_bench("channel step (variant c, H=128)", &ram_model);

    // 3. Parts, on the same model (in RAM) and inputs.
    let blob = ram_model.blob();
    let lstm_t = blob.lstm[0];
    let mut ls = LstmState::new();
    let x = [
        1234i16, -2345, 345, 456, -567, 678, 789, -890, 901, 120, -230,
    ];
    let (lstm_insns, span_lstm) = harness::bench("LSTM cell step (11 -> 128)", 50, || {
        lstm::step(black_box(&lstm_t), &mut ls, black_box(&x));
    });
    let h = ls.h;
    let (_, span_dense) = harness::bench("dense + softmax (128 -> p)", 200, || {
        black_box(p_unstable(black_box(&blob.dense), &[black_box(&h[..128])]));
    });
    let plan = match StftPlan::new(StftConfig::PAPER) {
        Ok(p) => p,
        Err(_) => harness::finish(),
    };
    let mut ss = StftState::new();
    let mut out = [0i16; 10];
    let mut j = 0u32;
    let (_, span_stft) = harness::bench("STFT step (N=20, 10 bands)", 200, || {
        j += 1;
        plan.step(
            &mut ss,
            black_box((j.wrapping_mul(2_654_435_761) >> 17) as i16),
            &mut out,
        );
        black_box(&out);
    });

    // 4. A 16-channel frame: every channel of the hand through the model, as `App::infer`
    //    does (without its fault and decision bookkeeping).
    let mut frame_states = [const { ChannelState::new() }; 16];
    let mut k = 0;
    let (frame, span_frame) = harness::bench("16-channel frame", steps as u32 / 4, || {
        for (c, st) in frame_states.iter_mut().enumerate() {
            black_box(ram_model.step(st, black_box(input((k + 7 * c) % steps))));
        }
        k += 1;
    });

    let lstm_macs = macs - 2 * 128;
    hprintln!(
        "summary: {} insns per channel step = {:.3} insns per MAC ({} MACs); LSTM cell alone {:.3} insns per MAC; from flash {} insns",
        step,
        step as f32 / macs as f32,
        macs,
        lstm_insns as f32 / lstm_macs as f32,
        step_flash
    );
    // Instructions only; `scripts/qemu-bench.sh` adds the cycle plugin's estimate per span.
    hprintln!(
        "summary: 16-channel frame {} insns; at 168 MHz, 1 insn/cycle: {} Hz -> {:.2} % CPU, 40 Hz -> {:.2} % CPU",
        frame,
        PAPER_RATE_HZ,
        frame as f32 * PAPER_RATE_HZ / 168e6 * 100.0,
        frame as f32 * 40.0 / 168e6 * 100.0
    );
    hprintln!(
        "parts: step={} step_flash={} step_plain={} lstm={} stft={} dense={} frame={} calibration={} calibration_iters={} macs={} lstm_macs={}",
        span_step,
        span_flash,
        span_plain,
        span_lstm,
        span_stft,
        span_dense,
        span_frame,
        insns::CALIBRATION_SPAN,
        insns::CALIBRATION_ITERATIONS,
        macs,
        lstm_macs
    );
    fetch::probe();
    harness::finish()
}
