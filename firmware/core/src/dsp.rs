//! The hot kernels: int8 × int16 dot products, the LSTM's and the dense layer's only inner loop.
//!
//! `#![allow(unsafe_code)]`: this module is the crate's one documented exception to
//! `#![deny(unsafe_code)]` (lib.rs, Cargo.toml), for the Cortex-M4 DSP kernel written in `asm!`.
//! Every `unsafe` block states why it is sound; everything else in the crate stays safe.
//!
//! # Kernels
//!
//! - [`dot_i8_i16`]: one portable dot product (the reference); [`dot_i8_i16_fast`] the same
//!   number with SXTB16/PKHBT/SMLAD over activations in natural order (the dense layer).
//! - [`lstm_gate_sums`]: the LSTM's two dot products of every gate row (x part and h part of
//!   the blob's contiguous rows) against activations that [`permute_q15`] has put in *SXTB16
//!   lane order*, in one assembly pass on `thumbv7em` with the DSP extension, into
//!   uninitialised memory; elsewhere (the host, and any argument the kernel cannot take)
//!   [`lstm_gate_sums_portable`], built on [`dot_i8_q15_permuted`], which defines the result.
//! - [`lstm_block_sums`]: the same two dot products from weights in the *blocked layout* of
//!   [`pack_lstm_blocks`] (the model's RAM image, [`crate::model_ram`]): register-blocked, 4 rows
//!   per pass reusing each activation word (x and h in natural order) held in registers, about
//!   1.2 cycles per MAC with a full h part (H = 128: activations read from a stack copy at fixed
//!   offsets, pipelined loads), 1.25 otherwise; reference [`lstm_block_sums_portable`].
//! - [`lstm_gate_rows`]: the gate pass (requantisation, σ/tanh by interval table) in assembly;
//!   [`lstm_cell_update`]: the cell update. Their references are `lstm::gate_activations_portable`
//!   and `lstm::cell_update_portable`; `lstm` falls back to them wherever these do not run.
//! - [`permute_q15_uninit`]: [`permute_q15`] into uninitialised memory (PKHBT/PKHTB).
//! - [`stft_bin_sums_rows`]: the STFT's bin sums for a rectangular window (SMLALBB/SMLALBT);
//!   reference [`stft_row_sums_portable`].
//!
//! The batched host path (many channels at once, with the host CPU's SIMD kernels) is not
//! here: it is the host crate `slipguard-batch` (`host-tools/batch`), checked bit for bit
//! against `Model::step`.
//!
//! The QEMU bench (`firmware/qemu-bench`) checks every assembly path against its reference.
//!
//! # The lane trick
//!
//! A little-endian word of four int8 weights `[b0 b1 b2 b3]` becomes two pairs of int16 lanes
//! with one instruction each: `SXTB16 e, w` gives `(b0, b2)` and `SXTB16 o, w, ROR #8` gives
//! `(b1, b3)`. `SMLAD acc, e, A, acc` then adds `b0·A.lo + b2·A.hi`, so if the activations are
//! stored as the words `(v0 | v2 << 16)` and `(v1 | v3 << 16)` (that is [`permute_q15`]: once
//! per step, 64 words for H = 128) no packing (`PKHBT`/`PKHTB`) is needed in the inner loop.
//! Per 4 MACs the kernel spends 2 `SXTB16` + 2 `SMLAD` + its share of the loads: `LDM` brings
//! 3 weight words and `LDM` 6 activation words per 12 MACs, so a block of 12 MACs is
//! 14 instructions (1.17 per MAC), fully unrolled (entered at a computed address, no loop
//! counter). Integer sums are exact and no partial sum can overflow for the admitted sizes,
//! so the order of summation does not change the `i32` result: the kernel is bit-exact with
//! the portable code.

#![allow(unsafe_code)]

use bytemuck::{Pod, Zeroable};

use crate::activation::IntervalTable;

/// Per-row requantisation of one LSTM gate row r:
/// `z_q12 = sat16(round((acc_x·mx + acc_h·mh) / 2^shift) + bias_q12)` where
/// `acc_x = Σ w_ih·x` (x Q3.12) and `acc_h = Σ w_hh·h` (h Q0.15).
/// With per-row weight scales s_ih, s_hh: mx = s_ih·2^shift, mh = s_hh·2^(shift-3)
/// (the 2^-3 aligns h's 15 fractional bits with x's 12).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct LstmRowParams {
    /// Input-weight multiplier.
    pub mx: i32,
    /// Recurrent-weight multiplier.
    pub mh: i32,
    /// b_ih + b_hh of the row, Q3.12 (an `i32`, added before saturation).
    pub bias_q12: i32,
    /// Shared exponent of mx and mh, 1..=62.
    pub shift: i32,
}

/// σ's interval table ([`interval_table`]). On the bare-metal target it is placed in
/// `.data`, copied to SRAM by the runtime at boot: the gate pass reads it 384 times per channel
/// step (rows i, f, o), and from flash nearly every read would miss the ART accelerator's 8
/// data lines (5 wait states). 2 KiB of RAM.
#[cfg_attr(
    all(target_arch = "arm", target_os = "none"),
    unsafe(link_section = ".data.slipguard_sigmoid")
)]
// SAFETY: a plain read-only static in an ordinary data section (the runtime initialises .data
// before main); nothing else is placed there.
static SIGMOID_TABLE: IntervalTable = crate::activation::SIGMOID_INTERVALS;
/// tanh's interval table, in SRAM on the target as [`SIGMOID_TABLE`] (256 reads per channel
/// step: rows g and the cell update). 2 KiB; both tables together take the 4 KiB that σ's
/// alone took in the earlier two-word format.
#[cfg_attr(
    all(target_arch = "arm", target_os = "none"),
    unsafe(link_section = ".data.slipguard_tanh")
)]
// SAFETY: as SIGMOID_TABLE.
static TANH_TABLE: IntervalTable = crate::activation::TANH_INTERVALS;

/// The interval table of tanh (`true`) or σ (`false`) (see [`SIGMOID_TABLE`]), for
/// [`crate::activation::lookup`] and the assembly gate pass.
pub fn interval_table(tanh: bool) -> &'static IntervalTable {
    if tanh { &TANH_TABLE } else { &SIGMOID_TABLE }
}

/// σ(x): Q3.12 in, Q0.15 out (0..=32767), by its interval table.
#[inline]
pub fn sigmoid(x: i16) -> i16 {
    crate::activation::lookup(interval_table(false), x)
}

/// tanh(x): Q3.12 in, Q0.15 out (-32768..=32767), by its interval table.
#[inline]
pub fn tanh(x: i16) -> i16 {
    crate::activation::lookup(interval_table(true), x)
}

/// ⌊√n⌋, the number `u32::isqrt` gives (the STFT magnitude's square root). On a Cortex-M4F
/// (hard-float ABI, the FPU enabled by the runtime) from VCVT + VSQRT.F32 + VCVT (about 18
/// cycles, against about 80 for the integer loop) and one correction: n as f32 is within
/// 2^-24 relative of n and the square root is correctly rounded, so the truncated estimate is
/// within 2^-8 of √n ≤ 2^16 and at most 1 away from ⌊√n⌋; one comparison of s² and (s + 1)²
/// with n (in 64 bits) fixes it. Elsewhere `u32::isqrt`.
#[inline]
pub fn isqrt_u32(n: u32) -> u32 {
    #[cfg(all(slipguard_dsp, target_abi = "eabihf"))]
    {
        let s: u32;
        // SAFETY: FPU register arithmetic only (no memory, no stack); s0 is declared clobbered.
        unsafe {
            core::arch::asm!(
                "vmov s0, {n}",
                "vcvt.f32.u32 s0, s0",
                "vsqrt.f32 s0, s0",
                "vcvt.u32.f32 s0, s0",
                "vmov {s}, s0",
                n = in(reg) n,
                s = lateout(reg) s,
                out("s0") _,
                options(pure, nomem, nostack),
            );
        }
        let sq = |s: u32| u64::from(s) * u64::from(s);
        if sq(s) > u64::from(n) {
            s - 1
        } else if sq(s + 1) <= u64::from(n) {
            s + 1
        } else {
            s
        }
    }
    #[cfg(not(all(slipguard_dsp, target_abi = "eabihf")))]
    {
        n.isqrt()
    }
}

/// The cell format's constants for [`lstm_cell_update`] (from `lstm::CellShifts`):
/// c' = sat16(((f·c + 2^14) >> 15) + ((i·g + ig_half) >> ig_shift)), then
/// q = sat16((c'·q_mul + q_add) >> 3) in Q3.12 for tanh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellParams {
    /// i·g (Q0.30) → Q(15-C).C: shift right by 30 − C.
    pub ig_shift: u32,
    /// 2^(ig_shift − 1).
    pub ig_half: i32,
    /// Cell → Q3.12 multiplier (before a shift right by 3).
    pub q_mul: i32,
    /// Cell → Q3.12 rounding addend (before a shift right by 3).
    pub q_add: i32,
}

/// Σ w[i]·v[i] over `min(w.len(), v.len())` elements: int8 weights × int16 activations,
/// accumulated in `i32`.
///
/// Overflow cannot happen for the sizes the blob parser admits: |w·v| ≤ 127·32768 and at most
/// `MAX_HIDDEN` (128) terms give < 2^29.
#[inline]
pub fn dot_i8_i16(w: &[i8], v: &[i16]) -> i32 {
    // Four independent partial sums let LLVM schedule loads and MACs in parallel.
    let n = w.len().min(v.len());
    let (w, v) = (&w[..n], &v[..n]);
    let mut acc = [0i32; 4];
    let mut wc = w.chunks_exact(4);
    let mut vc = v.chunks_exact(4);
    for (a, b) in (&mut wc).zip(&mut vc) {
        acc[0] += a[0] as i32 * b[0] as i32;
        acc[1] += a[1] as i32 * b[1] as i32;
        acc[2] += a[2] as i32 * b[2] as i32;
        acc[3] += a[3] as i32 * b[3] as i32;
    }
    let mut tail = 0;
    for (a, b) in wc.remainder().iter().zip(vc.remainder()) {
        tail += *a as i32 * *b as i32;
    }
    acc[0] + acc[1] + acc[2] + acc[3] + tail
}

/// [`dot_i8_i16`] (the same result), with the largest multiple of 8 terms in assembly on a
/// Cortex-M with the DSP extension when `w` and `v` are 4-byte aligned: per 8 terms two LDMs,
/// SXTB16 ×2, PKHBT/PKHTB (weight pairs in the activations' natural order) and SMLAD ×2 per
/// weight word. The dense layer uses it; the rest of the terms go through [`dot_i8_i16`].
#[inline]
pub fn dot_i8_i16_fast(w: &[i8], v: &[i16]) -> i32 {
    #[cfg(slipguard_dsp)]
    let sum = {
        let n = w.len().min(v.len());
        let (w, v) = (&w[..n], &v[..n]);
        // The assembly's part: `done` terms (a multiple of 8, ≤ n; 0 if it cannot run).
        let (done, head) = arm::dot_natural(w, v);
        let rest = dot_i8_i16(w.get(done..).unwrap_or(&[]), v.get(done..).unwrap_or(&[]));
        // Exact: the whole sum fits in i32 (see `dot_i8_i16`), so does every partial sum.
        head.wrapping_add(rest)
    };
    #[cfg(not(slipguard_dsp))]
    let sum = dot_i8_i16(w, v);
    sum
}

/// Longest activation vector (in values) the h part of [`lstm_gate_sums`] runs in assembly
/// (= 4·[`MAX_ASM_H_WORDS`]); longer ones take the portable path. 140 ≥ MAX_HIDDEN.
pub const MAX_ASM_VALUES: usize = 4 * (3 * ASM_BLOCKS + 2);
/// Unrolled 3-word blocks in the assembly kernel.
const ASM_BLOCKS: usize = 11;

/// Writes `v` in SXTB16 lane order into `out`: each group of four values `(v0, v1, v2, v3)`
/// becomes the words `v0 | v2 << 16` and `v1 | v3 << 16`, the last group zero-padded.
/// Returns the number of words written, `2·ceil(v.len() / 4)`, less if `out` is too short
/// (whole groups only).
pub fn permute_q15(v: &[i16], out: &mut [u32]) -> usize {
    let lo = |x: i16| x as u16 as u32;
    let mut n = 0;
    let mut groups = v.chunks_exact(4);
    let mut words = out.chunks_exact_mut(2);
    // Whole groups: two PKHBT/PKHTB-like merges each.
    for (g, o) in (&mut groups).zip(&mut words) {
        o[0] = lo(g[0]) | lo(g[2]) << 16;
        o[1] = lo(g[1]) | lo(g[3]) << 16;
        n += 2;
    }
    // A short last group, zero-padded (if `out` still has room).
    let g = groups.remainder();
    if let (false, Some(o)) = (g.is_empty(), words.next()) {
        let at = |i: usize| g.get(i).map_or(0, |&x| lo(x));
        o[0] = at(0) | at(2) << 16;
        o[1] = at(1) | at(3) << 16;
        n += 2;
    }
    n
}

/// [`permute_q15`] into uninitialised memory (the same words): returns the words written, the
/// initialised prefix of `out`, so the caller's buffer needs no zeroing. With `v` 4-byte aligned,
/// on a Cortex-M with the DSP extension, groups of 8 values go through PKHBT/PKHTB in assembly.
pub fn permute_q15_uninit<'o>(v: &[i16], out: &'o mut [core::mem::MaybeUninit<u32>]) -> &'o [u32] {
    let groups = (v.len() / 4).min(out.len() / 2);
    #[cfg(slipguard_dsp)]
    let done = arm::permute_pairs_of_groups(v, out, groups / 2);
    #[cfg(not(slipguard_dsp))]
    let done = 0;
    let lo = |x: i16| x as u16 as u32;
    for (g, o) in v
        .chunks_exact(4)
        .zip(out.chunks_exact_mut(2))
        .take(groups)
        .skip(done)
    {
        o[0].write(lo(g[0]) | lo(g[2]) << 16);
        o[1].write(lo(g[1]) | lo(g[3]) << 16);
    }
    let mut n = 2 * groups;
    // A short last group, zero-padded, if it is the next one and `out` has room.
    let tail = v.get(4 * groups..).unwrap_or(&[]);
    if let (1..=3, Some(o)) = (tail.len(), out.get_mut(n..n + 2)) {
        let at = |i: usize| tail.get(i).map_or(0, |&x| lo(x));
        o[0].write(at(0) | at(2) << 16);
        o[1].write(at(1) | at(3) << 16);
        n += 2;
    }
    // SAFETY: out[..2·groups] is written (the first `done` groups by the assembly, which
    // writes exactly those, the others by the loop), and out[2·groups..n] by the tail; a
    // MaybeUninit<u32> has the layout of u32 and the result keeps `out` borrowed.
    unsafe { core::slice::from_raw_parts(out.as_ptr().cast::<u32>(), n) }
}

/// Σ w[k]·v[k] with v given in [`permute_q15`]'s lane order (`act`, two words per 4 values):
/// `4·(act.len() / 2)` terms, or fewer if `w` is shorter (like [`dot_i8_i16`]).
#[inline]
pub fn dot_i8_q15_permuted(w: &[i8], act: &[u32]) -> i32 {
    let mut acc = 0i32;
    let mut wc = w.chunks_exact(4);
    let mut ac = act.chunks_exact(2);
    for (b, a) in (&mut wc).zip(&mut ac) {
        let (e, o) = (a[0], a[1]);
        acc += b[0] as i32 * (e as i16) as i32
            + b[1] as i32 * (o as i16) as i32
            + b[2] as i32 * ((e >> 16) as i16) as i32
            + b[3] as i32 * ((o >> 16) as i16) as i32;
    }
    // A short last group of weights.
    if let Some(a) = ac.next() {
        let v = [a[0] as i16, a[1] as i16, (a[0] >> 16) as i16];
        for (b, v) in wc.remainder().iter().zip(v) {
            acc += *b as i32 * v as i32;
        }
    }
    acc
}

/// Weight words per LSTM row that [`lstm_gate_sums`] runs in assembly: x part (≥ MAX_INPUT / 4)
/// and h part (≥ MAX_HIDDEN / 4).
pub const MAX_ASM_X_WORDS: usize = 3 * ASM_X_BLOCKS + 2;
/// See [`MAX_ASM_X_WORDS`].
pub const MAX_ASM_H_WORDS: usize = 3 * ASM_BLOCKS + 2;
/// 3-word blocks of the x part in the LSTM kernel: one (a SMUAD copy entered first, when
/// there is no remainder, and a SMLAD copy after a remainder stub).
const ASM_X_BLOCKS: usize = 1;

/// The reference of [`lstm_gate_sums`]: `out[r] = [Σ_k w[r·stride + k]·x[k],
/// Σ_k w[hh_offset + r·stride + k]·h[k]]`, x and h in [`permute_q15`]'s order, each sum a
/// [`dot_i8_q15_permuted`] of the row (a row that runs past the end of `w` uses the weights
/// that exist; one starting past it gives 0).
pub fn lstm_gate_sums_portable(
    w: &[i8],
    stride: usize,
    hh_offset: usize,
    x: &[u32],
    h: &[u32],
    out: &mut [[i32; 2]],
) {
    for (r, o) in out.iter_mut().enumerate() {
        *o = gate_row(w, stride, hh_offset, x, h, r);
    }
}

/// Row `r` of [`lstm_gate_sums_portable`].
#[inline]
fn gate_row(w: &[i8], stride: usize, hh_offset: usize, x: &[u32], h: &[u32], r: usize) -> [i32; 2] {
    fn row(w: &[i8], r: usize, stride: usize) -> &[i8] {
        r.checked_mul(stride)
            .and_then(|s| w.get(s..))
            .unwrap_or(&[])
    }
    let w_hh = w.get(hh_offset..).unwrap_or(&[]);
    [
        dot_i8_q15_permuted(row(w, r, stride), x),
        dot_i8_q15_permuted(row(w_hh, r, stride), h),
    ]
}

/// Both dot products of every LSTM gate row in one pass, into uninitialised memory: the same
/// numbers as [`lstm_gate_sums_portable`], returned as the initialised `out`.
///
/// A blob's LSTM row is `[W_ih row (hh_offset bytes) | W_hh row]` and rows follow each other,
/// so when `hh_offset = 4·(x.len() / 2)` and `stride = hh_offset + 4·(h.len() / 2)` the weights
/// are one contiguous stream. Then, on a Cortex-M with the DSP extension, with `w` 4-byte aligned,
/// every row inside `w`, at most [`MAX_ASM_X_WORDS`] and [`MAX_ASM_H_WORDS`] weight words per
/// part, the assembly kernel runs (one call for all rows: per row the x part, then the h part,
/// each a computed jump into unrolled SXTB16/SMLAD blocks); otherwise the portable code.
pub fn lstm_gate_sums<'o>(
    w: &[i8],
    stride: usize,
    hh_offset: usize,
    x: &[u32],
    h: &[u32],
    out: &'o mut [core::mem::MaybeUninit<[i32; 2]>],
) -> &'o mut [[i32; 2]] {
    #[cfg(slipguard_dsp)]
    let done = arm::lstm_rows(w, stride, hh_offset, x, h, out);
    #[cfg(not(slipguard_dsp))]
    let done = false;
    finish_rows(out, done, |r| gate_row(w, stride, hh_offset, x, h, r))
}

/// Rows per block of the blocked LSTM weight layout ([`pack_lstm_blocks`]).
pub const BLOCK_ROWS: usize = 4;
/// Chunks (2 value pairs = 4 values of x or h) of the x part that [`lstm_block_sums`] runs in
/// assembly: all of MAX_INPUT.
pub const MAX_BLOCK_X_CHUNKS: usize = crate::MAX_INPUT.div_ceil(4);
/// Chunks of the h part that [`lstm_block_sums`] runs in assembly: all of MAX_HIDDEN.
pub const MAX_BLOCK_H_CHUNKS: usize = crate::MAX_HIDDEN.div_ceil(4);

/// Re-lays row-major LSTM gate weights (`w`: rows of `stride` bytes, as in the blob) into the
/// *blocked layout* of [`lstm_block_sums`], into `out` (the same length). Returns false,
/// leaving `out` unspecified, if the weights cannot be represented (a pair's `b` weight is
/// -128 with a negative `a` weight; the exporter never writes -128) or the shape does not suit
/// (rows not a multiple of 4, `stride` not a multiple of 4, lengths differ).
///
/// The layout: rows in blocks of 4; rows 4m and 4m+1 form pair 0 (a, b), rows 4m+2 and 4m+3
/// pair 1. A row is `stride / 2` value pairs j (values 2j, 2j+1). For pair (a, b) and value
/// pair j one word holds the halfwords `256·b[2j] + a[2j]` and `256·b[2j+1] + a[2j+1]` (each fits
/// an i16 unless b = -128 and a < 0): its low bytes are a's weights, so SXTB16 extracts them,
/// while SMLALD with the activation word (v_2j, v_2j+1) adds 256·(b·v) + a·v in 64 bits. Block m
/// is `4·stride` bytes at `m·4·stride`: chunk c (value pairs 2c, 2c+1) is four words, pair 0 at
/// j = 2c and 2c+1, then pair 1 at j = 2c and 2c+1. The same size as the row-major rows.
pub fn pack_lstm_blocks(w: &[i8], stride: usize, out: &mut [i8]) -> bool {
    if stride == 0
        || !stride.is_multiple_of(4)
        || w.len() != out.len()
        || !w.len().is_multiple_of(BLOCK_ROWS * stride)
    {
        return false;
    }
    for (blk, dst) in w
        .chunks_exact(BLOCK_ROWS * stride)
        .zip(out.chunks_exact_mut(BLOCK_ROWS * stride))
    {
        for (c, words) in dst.chunks_exact_mut(16).enumerate() {
            for (k, word) in words.chunks_exact_mut(4).enumerate() {
                let (pair, j) = (k / 2, 2 * c + k % 2);
                let a = &blk[2 * pair * stride..][..stride];
                let b = &blk[(2 * pair + 1) * stride..][..stride];
                for (half, i) in word.chunks_exact_mut(2).zip([2 * j, 2 * j + 1]) {
                    let v = 256 * b[i] as i32 + a[i] as i32;
                    let Ok(v) = i16::try_from(v) else {
                        return false;
                    };
                    let [lo, hi] = v.to_le_bytes();
                    half[0] = lo as i8;
                    half[1] = hi as i8;
                }
            }
        }
    }
    true
}

/// The weight of row q (0..4) of a block at value pair j, half `i` (0 or 1), from the blocked
/// layout: the inverse of [`pack_lstm_blocks`]. 0 where `blk` has no such bytes.
#[inline]
fn block_weight(blk: &[i8], q: usize, j: usize, i: usize) -> i32 {
    let at = 16 * (j / 2) + 8 * (q / 2) + 4 * (j % 2) + 2 * i;
    let (Some(&lo), Some(&hi)) = (blk.get(at), blk.get(at + 1)) else {
        return 0;
    };
    let a = lo as i32;
    let v = i16::from_le_bytes([lo as u8, hi as u8]) as i32;
    if q.is_multiple_of(2) { a } else { (v - a) >> 8 }
}

/// The reference of [`lstm_block_sums`]: `out[r] = [Σ_k W[r][k]·x[k], Σ_k W[r][hh_offset + k]·h[k]]`
/// with W the row-major weights that [`pack_lstm_blocks`] packed into `wb`, and x, h in natural
/// order as words of value pairs (`v_2j | v_2j+1 << 16`): the same numbers as
/// [`lstm_gate_sums_portable`] on the row-major weights. Missing weights or activations count
/// as 0.
pub fn lstm_block_sums_portable(
    wb: &[i8],
    stride: usize,
    hh_offset: usize,
    x: &[u32],
    h: &[u32],
    out: &mut [[i32; 2]],
) {
    for (r, o) in out.iter_mut().enumerate() {
        *o = block_row(wb, stride, hh_offset, x, h, r);
    }
}

/// Row `r` of [`lstm_block_sums_portable`].
fn block_row(
    wb: &[i8],
    stride: usize,
    hh_offset: usize,
    x: &[u32],
    h: &[u32],
    r: usize,
) -> [i32; 2] {
    let blk = (r / BLOCK_ROWS)
        .checked_mul(BLOCK_ROWS * stride)
        .and_then(|s| wb.get(s..))
        .unwrap_or(&[]);
    let q = r % BLOCK_ROWS;
    let xp = hh_offset / 2;
    let mut sums = [0i32; 2];
    for j in 0..stride / 2 {
        let (part, act) = if j < xp {
            (0, x.get(j))
        } else {
            (1, h.get(j - xp))
        };
        let Some(&act) = act else { continue };
        let (v0, v1) = (act as i16 as i32, (act >> 16) as i16 as i32);
        sums[part] += block_weight(blk, q, j, 0) * v0 + block_weight(blk, q, j, 1) * v1;
    }
    sums
}

/// Both dot products of every LSTM gate row, from weights in the blocked layout of
/// [`pack_lstm_blocks`] (`wb`, rows of `stride` bytes whose first `hh_offset` are the x part)
/// and activations in natural order as words of value pairs, into uninitialised memory: the
/// numbers of [`lstm_block_sums_portable`], returned as the initialised `out`.
///
/// On a Cortex-M with the DSP extension, for whole blocks of 4 rows inside `wb` (4-byte
/// aligned), `stride` and `hh_offset` multiples of 4, `x` holding `hh_offset / 2` words and `h`
/// `(stride - hh_offset) / 2`, at most [`MAX_BLOCK_X_CHUNKS`] and [`MAX_BLOCK_H_CHUNKS`]
/// chunks: the register-blocked assembly kernel. Per chunk of 4 rows × 4 values it loads 2
/// activation words and 4 weight words (LDM) and runs 4 × (SMLALD, SXTB16, SMLAD): 16 MACs in
/// 14 instructions, about 20 cycles, each activation word used by 4 rows; a's sum is the
/// SMLAD accumulator, b's is (SMLALD − SMLAD) / 256, exact in 64 bits. With exactly
/// [`MAX_BLOCK_H_CHUNKS`] h chunks (H = 128) a variant laid out for the STM32F4's flash runs
/// instead: the activations copied once to the stack, a block loop of 0.9 KiB that stays in the
/// ART accelerator's 1 KiB instruction cache (h in 4 passes of 8 chunks), the chunk's 6 words
/// by single pipelined LDRs with 16-bit encodings (18 instructions, 19 cycles). Otherwise the
/// portable code.
pub fn lstm_block_sums<'o>(
    wb: &[i8],
    stride: usize,
    hh_offset: usize,
    x: &[u32],
    h: &[u32],
    out: &'o mut [core::mem::MaybeUninit<[i32; 2]>],
) -> &'o mut [[i32; 2]] {
    #[cfg(slipguard_dsp)]
    let done = arm::lstm_blocks(wb, stride, hh_offset, x, h, out);
    #[cfg(not(slipguard_dsp))]
    let done = false;
    finish_rows(out, done, |r| block_row(wb, stride, hh_offset, x, h, r))
}

/// The portable rows where the kernel did not run (`done` false: it writes all rows or none),
/// then `out` as initialised sums.
fn finish_rows(
    out: &mut [core::mem::MaybeUninit<[i32; 2]>],
    done: bool,
    row: impl Fn(usize) -> [i32; 2],
) -> &mut [[i32; 2]] {
    if !done {
        for (r, o) in out.iter_mut().enumerate() {
            o.write(row(r));
        }
    }
    // SAFETY: every element of `out` has been written, by the kernel (`arm::lstm_blocks` and
    // `arm::lstm_rows` return true only after writing all of them) or by the loop above;
    // `MaybeUninit<T>` has the layout of `T`, and the returned borrow keeps `out` (exclusively)
    // borrowed.
    unsafe { core::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<[i32; 2]>(), out.len()) }
}

/// The gate pass of the LSTM in assembly. From the first row on, while a row's requantisation
/// shift is in 33..=62: `acc[r][0] = f(z)` with z = `sat16(round((acc[r][0]·mx + acc[r][1]·mh)
/// / 2^shift) + bias)` and f given by its interval `table` ([`crate::activation::lookup`]).
/// Returns the number of rows done (0 on targets without the DSP extension); the caller,
/// `lstm::gate_activations`, does the rest. The same bits as `lstm::gate_activations_portable`:
/// the rounding is that of `lstm::requant`, t = ⌊z / 2^(shift-1)⌋ from the high word of the
/// 64-bit sum, then ⌊(t + 1) / 2⌋.
#[inline]
pub fn lstm_gate_rows(
    acc: &mut [[i32; 2]],
    params: &[LstmRowParams],
    table: &IntervalTable,
) -> usize {
    #[cfg(slipguard_dsp)]
    return arm::gate_rows(acc, params, table);
    #[cfg(not(slipguard_dsp))]
    {
        let _ = (acc, params, table);
        0
    }
}

/// The gate pass of a RAM image's folded rows (`lstm::fold_row`) in assembly: for every row
/// `acc[r][0] = f(sat16(⌊(C·2^32 + acc[r][0]·mx + acc[r][1]·mh) / 2^32⌋ >> d))` with C =
/// `bias_q12`, d = `shift` (1..=30) and f by its interval `table`: the numbers of
/// `lstm::gate_activations_folded_portable`. Per row 18 instructions, about 21 cycles (no
/// range check: the blob parser admits only folded rows in an image). Returns false, changing
/// nothing, where it does not run (targets without the DSP extension); true after every row
/// of `min(acc.len(), params.len())`. Rows outside the folded form give unspecified values
/// (never an access outside `acc`, `params` or `table`).
#[inline]
pub fn lstm_gate_rows_folded(
    acc: &mut [[i32; 2]],
    params: &[LstmRowParams],
    table: &IntervalTable,
) -> bool {
    #[cfg(slipguard_dsp)]
    {
        arm::gate_rows_folded(acc, params, table);
        true
    }
    #[cfg(not(slipguard_dsp))]
    {
        let _ = (acc, params, table);
        false
    }
}

/// The LSTM cell update in assembly, for units 0..hn from the gate activations
/// `gates[g·hn + j][0]` (gate order i, f, g, o, low 16 bits): the same bits as
/// `lstm::cell_update_portable` (the cell → Q3.12 conversion in its `q_mul`/`q_add` form, tanh
/// by its interval `table`). Returns false, changing nothing, where it does not run (other
/// targets, `hn` > MAX_HIDDEN, fewer than 4·hn gates, or `c` not directly after `h` in
/// memory); true after updating every unit.
#[inline]
pub fn lstm_cell_update(
    gates: &[[i32; 2]],
    hn: usize,
    h: &mut [i16; crate::MAX_HIDDEN],
    c: &mut [i16; crate::MAX_HIDDEN],
    k: CellParams,
    table: &IntervalTable,
) -> bool {
    #[cfg(slipguard_dsp)]
    return arm::cell_update(gates, hn, h, c, k, table);
    #[cfg(not(slipguard_dsp))]
    {
        let _ = (gates, hn, h, c, k, table);
        false
    }
}

/// The sums of the STFT's rectangular-window bins ([`crate::features::stft`]): for bin b,
/// `[Σ x·cos, Σ x·sin]` over the samples `older` then `newer` (n of them together) paired with
/// row b of the plan's twiddle rows, `rows[b·n..(b + 1)·n]`, each word `cos as u16 | sin << 16`;
/// one bin per element of `out` (uninitialised), returned initialised. On a Cortex-M with the
/// DSP extension in one assembly call (per sample one LDRSH, one LDR, SMLALBB and SMLALBT into
/// two 64-bit sums, two samples a loop pass), where `rows` holds every bin's row; elsewhere
/// [`stft_bin_sums_rows_portable`], which defines the result (missing row words count as 0).
pub fn stft_bin_sums_rows<'o>(
    older: &[i16],
    newer: &[i16],
    rows: &[u32],
    out: &'o mut [core::mem::MaybeUninit<[i64; 2]>],
) -> &'o mut [[i64; 2]] {
    #[cfg(slipguard_dsp)]
    let done = arm::stft_bin_sums_rows(older, newer, rows, out);
    #[cfg(not(slipguard_dsp))]
    let done = false;
    if !done {
        let n = older.len() + newer.len();
        for (b, o) in out.iter_mut().enumerate() {
            let row = rows.get(b * n..).unwrap_or(&[]);
            o.write(stft_row_sums_portable(
                older,
                newer,
                &row[..n.min(row.len())],
            ));
        }
    }
    // SAFETY: every element of `out` has been written, by the kernel (`arm::stft_bin_sums_rows`
    // returns true only after writing all of them) or by the loop above; `MaybeUninit<T>` has
    // the layout of `T`, and the returned borrow keeps `out` (exclusively) borrowed.
    unsafe { core::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<[i64; 2]>(), out.len()) }
}

/// The reference of [`stft_bin_sums_rows`] for one bin: the i64 sums of the i16 products of
/// the samples (`older`, then `newer`) and the row's words, up to the shorter.
pub fn stft_row_sums_portable(older: &[i16], newer: &[i16], row: &[u32]) -> [i64; 2] {
    let (mut re, mut im) = (0i64, 0i64);
    for (&x, &w) in older.iter().chain(newer).zip(row) {
        re += x as i64 * (w as i16) as i64;
        im += x as i64 * ((w >> 16) as i16) as i64;
    }
    [re, im]
}

#[cfg(slipguard_dsp)]
mod arm {
    use super::{ASM_BLOCKS, ASM_X_BLOCKS, CellParams, IntervalTable, LstmRowParams};
    use crate::MAX_HIDDEN;

    /// Bytes from `h[j]` to `c[j]` where the assembly cell update runs: c must directly follow
    /// h (as in `lstm::LstmState`, `repr(C)`).
    const C_OFFSET: usize = 2 * MAX_HIDDEN;
    use core::mem::MaybeUninit;

    /// One 3-word block: 12 MACs in 14 instructions, 56 bytes (all 32-bit encodings).
    macro_rules! BLOCK {
        () => {
            "ldmia.w r0!, {{r3, r4, r5}}
             ldmia.w r1!, {{r6, r7, r8, r9, r10, r11}}
             sxtb16 r12, r3, ror #8
             sxtb16 r3, r3
             smlad r2, r3, r6, r2
             smlad r2, r12, r7, r2
             sxtb16 r12, r4, ror #8
             sxtb16 r4, r4
             smlad r2, r4, r8, r2
             smlad r2, r12, r9, r2
             sxtb16 r12, r5, ror #8
             sxtb16 r5, r5
             smlad r2, r5, r10, r2
             smlad r2, r12, r11, r2"
        };
    }
    /// `BLOCK` starting the accumulator with SMUAD.
    macro_rules! BLOCK_FIRST {
        () => {
            "ldmia.w r0!, {{r3, r4, r5}}
             ldmia.w r1!, {{r6, r7, r8, r9, r10, r11}}
             sxtb16 r12, r3, ror #8
             sxtb16 r3, r3
             smuad r2, r3, r6
             smlad r2, r12, r7, r2
             sxtb16 r12, r4, ror #8
             sxtb16 r4, r4
             smlad r2, r4, r8, r2
             smlad r2, r12, r9, r2
             sxtb16 r12, r5, ror #8
             sxtb16 r5, r5
             smlad r2, r5, r10, r2
             smlad r2, r12, r11, r2"
        };
    }
    /// One row of the gate pass (see `gate_rows`): leaves for label 2 at a shift outside
    /// 33..=62. z = acc_x·mx + acc_h·mh (64 bits, SMULL + SMLAL); t = hi >> (shift - 33);
    /// (t + 1) >> 1; saturating add of the bias; then the interval: z >> 7 saturated to
    /// -256..=255 (one SSAT: the table's end intervals are flat, so the position z & 127 of an
    /// unsaturated z gives the value of the saturated one), its word `lo << 16 | step` (one
    /// LDR, r12 = 2^6): lo + ((step·pos + 2^6) >> 7).
    macro_rules! GATE_ROW {
        () => {
            "ldm r2!, {{r4, r5, r6, r7}}
             sub r7, r7, #33
             cmp r7, #30
             bhs 2f
             ldrd r8, r9, [r0]
             smull r10, r11, r8, r4
             smlal r10, r11, r9, r5
             asr r11, r11, r7
             add r11, r11, #1
             asr r11, r11, #1
             qadd r11, r11, r6
             ssat r8, #9, r11, asr #7
             ldr r9, [r3, r8, lsl #2]
             and r11, r11, #127
             smlabb r10, r9, r11, r12
             asr r10, r10, #7
             add r9, r10, r9, asr #16
             str r9, [r0], #8"
        };
    }
    /// One unit of the cell update (see `cell_update`):
    /// c' = sat16(((f·c + 2^14) >> 15) + ((i·g + half) >> ig_shift)); q = sat16((c'·q_mul +
    /// q_add) >> 3), Q3.12; tanh(q) by the table; h' = sat16((o·tanh(c') + 2^14) >> 15). The
    /// lookup takes q's interval as v >> 10 saturated to -256..=255 and its position as bits
    /// 3..9 of v = c'·q_mul + q_add (unsaturated: the table's end intervals are flat), scaled
    /// by 2^8 so that the rounding constant is r6's 2^14: lo + ((step·pos·2^8 + 2^14) >> 15).
    /// c' is stored just before the table's and o's loads, so that the three pipeline.
    macro_rules! CELL_UNIT {
        () => {
            "ldr r11, [r0, r1]
             ldrsh r12, [r3, #{coff}]
             smlabb r11, r11, r12, r6
             ldr r12, [r0, r1, lsl #1]
             ldr lr, [r0], #8
             smlabb r12, lr, r12, r7
             asr r12, r12, r8
             add r12, r12, r11, asr #15
             ssat r12, #16, r12
             smlabb lr, r12, r9, r10
             ssat r11, #9, lr, asr #10
             ubfx lr, lr, #3, #7
             lsl lr, lr, #8
             strh r12, [r3, #{coff}]
             ldr r11, [r5, r11, lsl #2]
             ldr r12, [r2], #8
             smlabb lr, r11, lr, r6
             asr lr, lr, #15
             add r11, lr, r11, asr #16
             smlabb r11, r12, r11, r6
             ssat r11, #16, r11, asr #15
             strh r11, [r3], #2"
        };
    }
    /// One leftover word; SMUAD starts the accumulator.
    macro_rules! STUB1 {
        () => {
            "ldr r3, [r0], #4
             ldrd r6, r7, [r1], #8
             sxtb16 r12, r3, ror #8
             sxtb16 r3, r3
             smuad r2, r3, r6
             smlad r2, r12, r7, r2"
        };
    }
    /// Two leftover words; SMUAD starts the accumulator.
    macro_rules! STUB2 {
        () => {
            "ldmia.w r0!, {{r3, r4}}
             ldmia.w r1!, {{r6, r7, r8, r9}}
             sxtb16 r12, r3, ror #8
             sxtb16 r3, r3
             smuad r2, r3, r6
             smlad r2, r12, r7, r2
             sxtb16 r12, r4, ror #8
             sxtb16 r4, r4
             smlad r2, r4, r8, r2
             smlad r2, r12, r9, r2"
        };
    }

    /// See `lstm_gate_rows`.
    #[inline]
    pub(super) fn gate_rows(
        acc: &mut [[i32; 2]],
        params: &[LstmRowParams],
        table: &IntervalTable,
    ) -> usize {
        let n = acc.len().min(params.len());
        if n == 0 {
            return 0;
        }
        let range = acc[..n].as_mut_ptr_range();
        // Entry 256 (in bounds): the interval of z = 0; the SSAT keeps z >> 7 in -256..=255.
        let mid: *const u32 = &table[256];
        let end: *mut [i32; 2];
        // SAFETY: the loop reads params[r] (16 bytes, repr(C) mx, mh, bias_q12, shift) and
        // reads and writes acc[r] for r < n, stopping at `range.end` or at the first row whose
        // shift is outside 33..=62 (before touching its `acc`); the table index
        // 256 + (z >> 7 saturated to -256..=255) is in 0..=511, inside `table`. It saves and
        // restores r4-r11 and changes no memory but `acc`.
        unsafe {
            core::arch::asm!(
                "push {{r4-r11}}",
                // Four rows per loop pass; a count of 4m + 3, 4m + 2 or 4m + 1 enters at the
                // second, third or fourth. r12: the lookup's rounding constant 2^6 (MOV.W leaves
                // the flags).
                "ands r4, r12, #3",
                "mov.w r12, #64",
                "beq 1f",
                "cmp r4, #2",
                "bhi 3f",
                "beq 4f",
                "b 5f",
                "1:",
                GATE_ROW!(),
                "3:",
                GATE_ROW!(),
                "4:",
                GATE_ROW!(),
                "5:",
                GATE_ROW!(),
                "cmp r0, r1",
                "bne 1b",
                "2:",
                "pop {{r4-r11}}",
                inout("r0") range.start => end,
                in("r1") range.end,
                inout("r2") params.as_ptr() => _,
                in("r3") mid,
                inout("r12") n => _,
            );
        }
        // Rows done: `end` is `range.start` advanced by whole rows, within the range.
        (end as usize - range.start as usize) / 8
    }

    /// One folded row of `gate_rows_folded`: the sums (two LDRs, pipelined after the previous
    /// row's STR), the parameters mx, mh, C, d (LDM), z = C·2^32 + acc_x·mx + acc_h·mh in
    /// r10:r6 (SMLAL × 2 onto C as the high word), t = hi >> d, then the interval t >> 7
    /// saturated to -256..=255 (one SSAT, which stands for the saturation of t to i16: the
    /// table's end intervals are flat, so the position t & 127 of an unsaturated t gives the
    /// value of the saturated one), its word `lo << 16 | step` (one LDR, register offset), and
    /// lo + ((step·pos + 2^6) >> 7) with r12 = 2^6.
    macro_rules! GATE_ROW_FOLDED {
        () => {
            "ldr r8, [r0]
             ldr r9, [r0, #4]
             ldm r2!, {{r4, r5, r6, r7}}
             movs r10, #0
             smlal r10, r6, r8, r4
             smlal r10, r6, r9, r5
             asr r6, r6, r7
             ssat r8, #9, r6, asr #7
             ldr r9, [r3, r8, lsl #2]
             and r6, r6, #127
             smlabb r10, r9, r6, r12
             asr r10, r10, #7
             add r9, r10, r9, asr #16
             str r9, [r0], #8"
        };
    }

    /// Row `slg_j` (an assembler symbol) of the 8-row pass of `gate_rows_folded`: as
    /// `GATE_ROW_FOLDED`, with the sums at `r0 + 8·slg_j` and the parameters at
    /// `r2 + 16·slg_j` read by six single LDRs in a row (pipelined after the previous row's STR).
    macro_rules! GATE_ROW_FOLDED_AT {
        () => {
            "ldr.w r8, [r0, #(8 * slg_j)]
             ldr.w r9, [r0, #(8 * slg_j + 4)]
             ldr.w r4, [r2, #(16 * slg_j)]
             ldr.w r5, [r2, #(16 * slg_j + 4)]
             ldr.w r6, [r2, #(16 * slg_j + 8)]
             ldr.w r7, [r2, #(16 * slg_j + 12)]
             movs r10, #0
             smlal r10, r6, r8, r4
             smlal r10, r6, r9, r5
             asr r6, r6, r7
             ssat r8, #9, r6, asr #7
             ldr r9, [r3, r8, lsl #2]
             and r6, r6, #127
             smlabb r10, r9, r6, r12
             asr r10, r10, #7
             add r9, r10, r9, asr #16
             str.w r9, [r0, #(8 * slg_j)]
             .set slg_j, slg_j + 1"
        };
    }

    /// See `lstm_gate_rows_folded`.
    #[inline]
    pub(super) fn gate_rows_folded(
        acc: &mut [[i32; 2]],
        params: &[LstmRowParams],
        table: &IntervalTable,
    ) {
        let n = acc.len().min(params.len());
        if n == 0 {
            return;
        }
        let range = acc[..n].as_mut_ptr_range();
        // Entry 256 (in bounds): the interval of t = 0; the SSAT keeps t >> 7 in -256..=255.
        let mid: *const u32 = &table[256];
        // The first 8·⌊n / 8⌋ rows in passes of 8 (fixed offsets, one pointer update a pass),
        // the rest one row a pass; r1 is where the 8-row passes end.
        let eights = range.start.wrapping_add(n & !7);
        // SAFETY: the loops read params[r] (16 bytes, repr(C) mx, mh, bias_q12, shift) and
        // read and write acc[r] for r < n: 8-row passes up to `eights` (a multiple of 8 rows
        // from the start), then single rows up to `range.end` (n ≥ 1 rows); the table
        // word at 4·(256 + (t >> 7 saturated to -256..=255)) is one of entries 0..=511,
        // inside `table`. It saves and restores r4-r10 and changes no memory but `acc`.
        unsafe {
            core::arch::asm!(
                "push {{r4-r10}}",
                "cmp r0, r1",
                "beq 6f",
                "1:",
                ".set slg_j, 0",
                ".rept 8",
                GATE_ROW_FOLDED_AT!(),
                ".endr",
                "adds r0, r0, #64",
                "adds r2, r2, #128",
                "cmp r0, r1",
                "bne 1b",
                "6:",
                "cmp r0, r11",
                "beq 8f",
                "7:",
                GATE_ROW_FOLDED!(),
                "cmp r0, r11",
                "bne 7b",
                "8:",
                "pop {{r4-r10}}",
                inout("r0") range.start => _,
                in("r1") eights,
                inout("r2") params.as_ptr() => _,
                in("r3") mid,
                in("r12") 64,
                in("r11") range.end,
            );
        }
    }

    /// The assembly part of `dot_i8_i16_fast`: Σ w[k]·v[k] over the first 8·⌊n / 8⌋ terms,
    /// returned with that count; (0, 0) if `w` or `v` is not 4-byte aligned.
    #[inline]
    pub(super) fn dot_natural(w: &[i8], v: &[i16]) -> (usize, i32) {
        let groups = w.len().min(v.len()) / 8;
        if groups == 0
            || !(w.as_ptr() as usize).is_multiple_of(4)
            || !(v.as_ptr() as usize).is_multiple_of(4)
        {
            return (0, 0);
        }
        let sum: i32;
        // SAFETY: the loop reads w[..8·groups] and v[..8·groups] (inside both slices, 4-byte
        // aligned as checked) with LDM, and writes no memory. It saves and restores r4-r11.
        unsafe {
            core::arch::asm!(
                "push {{r4-r11}}",
                "movs r2, #0",
                "1:",
                "ldm r0!, {{r4, r5}}",
                "ldm r1!, {{r6, r7, r8, r9}}",
                // Weight bytes (b0 b1 b2 b3) → halfword pairs (b0, b1) and (b2, b3), the order
                // of the activation words (v0 | v1 << 16), (v2 | v3 << 16).
                "sxtb16 r10, r4",
                "sxtb16 r11, r4, ror #8",
                "pkhbt r12, r10, r11, lsl #16",
                "pkhtb r10, r11, r10, asr #16",
                "smlad r2, r12, r6, r2",
                "smlad r2, r10, r7, r2",
                "sxtb16 r10, r5",
                "sxtb16 r11, r5, ror #8",
                "pkhbt r12, r10, r11, lsl #16",
                "pkhtb r10, r11, r10, asr #16",
                "smlad r2, r12, r8, r2",
                "smlad r2, r10, r9, r2",
                "subs r3, r3, #1",
                "bne 1b",
                "pop {{r4-r11}}",
                inout("r0") w.as_ptr() => _,
                inout("r1") v.as_ptr() => _,
                out("r2") sum,
                inout("r3") groups => _,
                out("r12") _,
            );
        }
        (8 * groups, sum)
    }

    /// The assembly part of `permute_q15_uninit`: groups 0..2·pairs (8 values each pair),
    /// written to out[..4·pairs]; returns the number of groups written (0 if `v` or `out` is not
    /// word-aligned or too short, then nothing is written).
    #[inline]
    pub(super) fn permute_pairs_of_groups(
        v: &[i16],
        out: &mut [MaybeUninit<u32>],
        pairs: usize,
    ) -> usize {
        if pairs == 0
            || v.len() < 8 * pairs
            || out.len() < 4 * pairs
            || !(v.as_ptr() as usize).is_multiple_of(4)
            || !(out.as_ptr() as usize).is_multiple_of(4)
        {
            return 0;
        }
        // SAFETY: reads v[..8·pairs] (4·pairs aligned words inside `v`) and writes
        // out[..4·pairs] (inside `out`, aligned); saves and restores r4-r10.
        unsafe {
            core::arch::asm!(
                "push {{r4-r10}}",
                "1:",
                // (v0 | v1 << 16), (v2 | v3 << 16), … → (v0 | v2 << 16), (v1 | v3 << 16), …
                "ldm r0!, {{r3, r4, r5, r6}}",
                "pkhbt r7, r3, r4, lsl #16",
                "pkhtb r8, r4, r3, asr #16",
                "pkhbt r9, r5, r6, lsl #16",
                "pkhtb r10, r6, r5, asr #16",
                "stm r1!, {{r7, r8, r9, r10}}",
                "subs r2, r2, #1",
                "bne 1b",
                "pop {{r4-r10}}",
                inout("r0") v.as_ptr() => _,
                inout("r1") out.as_mut_ptr() => _,
                inout("r2") pairs => _,
                out("r3") _,
            );
        }
        2 * pairs
    }

    /// What the cell update reads, in the order of its LDM (r0-r5, r7-r10).
    #[repr(C)]
    struct CellArgs {
        gi: *const [i32; 2],
        off: usize,
        go: *const [i32; 2],
        h: *mut i16,
        h_end: *mut i16,
        table: *const u32,
        ig_half: i32,
        ig_shift: u32,
        q_mul: i32,
        q_add: i32,
    }

    /// One segment of `stft_row_sums`: `count` (a low register, consumed) samples from the
    /// pointer `x` (advanced) with the row words from r12 (advanced) into r4:r5 (Σ x·cos) and
    /// r6:r7 (Σ x·sin); an odd count takes one sample first. Labels `$a`, `$b`, `$c`.
    macro_rules! STFT_SEGMENT {
        ($x:literal, $count:literal, $a:literal, $b:literal, $c:literal) => {
            concat!(
                "lsrs ",
                $count,
                ", ",
                $count,
                ", #1\n",
                "bcc ",
                $a,
                "f\n",
                "ldrsh r8, [",
                $x,
                "], #2\n",
                "ldr r9, [r12], #4\n",
                "smlalbb r4, r5, r8, r9\n",
                "smlalbt r6, r7, r8, r9\n",
                $a,
                ":\n",
                "cbz ",
                $count,
                ", ",
                $c,
                "f\n",
                $b,
                ":\n",
                "ldrsh r8, [",
                $x,
                "], #2\n",
                "ldr r9, [r12], #4\n",
                "ldrsh r10, [",
                $x,
                "], #2\n",
                "ldr r11, [r12], #4\n",
                "smlalbb r4, r5, r8, r9\n",
                "smlalbt r6, r7, r8, r9\n",
                "smlalbb r4, r5, r10, r11\n",
                "smlalbt r6, r7, r10, r11\n",
                "subs ",
                $count,
                ", ",
                $count,
                ", #1\n",
                "bne ",
                $b,
                "b\n",
                $c,
                ":"
            )
        };
    }

    /// What `stft_bin_sums_rows` reads: the segments (LDM into r0-r3 for every bin), then the
    /// rows, the first output and one past the last (at +16, +20, +24).
    #[repr(C)]
    struct StftRowArgs {
        older: *const i16,
        older_len: usize,
        newer: *const i16,
        newer_len: usize,
        rows: *const u32,
        out: *mut [i64; 2],
        out_end: *mut [i64; 2],
    }

    /// See `super::stft_bin_sums_rows`: true after writing every element of `out`; false,
    /// writing nothing, where `rows` does not hold every bin's row.
    #[inline]
    pub(super) fn stft_bin_sums_rows(
        older: &[i16],
        newer: &[i16],
        rows: &[u32],
        out: &mut [MaybeUninit<[i64; 2]>],
    ) -> bool {
        let Some(words) = older
            .len()
            .checked_add(newer.len())
            .and_then(|n| n.checked_mul(out.len()))
        else {
            return false;
        };
        if words > rows.len() {
            return false;
        }
        if out.is_empty() {
            return true;
        }
        let range = out.as_mut_ptr_range();
        let args = StftRowArgs {
            older: older.as_ptr(),
            older_len: older.len(),
            newer: newer.as_ptr(),
            newer_len: newer.len(),
            rows: rows.as_ptr(),
            out: range.start.cast(),
            out_end: range.end.cast(),
        };
        // SAFETY: per bin (out.len() ≥ 1 of them) it reads older[..older_len] and
        // newer[..newer_len] (halfwords inside both slices) and the next older_len + newer_len
        // words of `rows` (all bins together `words` ≤ rows.len(), checked above; `[u32]` is
        // aligned), and writes one [i64; 2] of `out` (8-byte aligned for STRD, exclusively
        // borrowed), until the output pointer reaches `out`'s end. It saves and restores r4-r11
        // and lr and restores sp (the arguments' address pushed below the saved registers).
        unsafe {
            core::arch::asm!(
                "push {{r4-r11, lr}}",
                "push {{r0}}",
                "ldr r12, [r0, #16]",
                "ldr lr, [r0, #20]",
                "1:",
                "ldr r0, [sp]",
                "ldm r0, {{r0, r1, r2, r3}}",
                "movs r4, #0",
                "movs r5, #0",
                "movs r6, #0",
                "movs r7, #0",
                STFT_SEGMENT!("r0", "r1", "2", "3", "4"),
                STFT_SEGMENT!("r2", "r3", "5", "6", "7"),
                "strd r4, r5, [lr], #8",
                "strd r6, r7, [lr], #8",
                "ldr r8, [sp]",
                "ldr r8, [r8, #24]",
                "cmp lr, r8",
                "bne 1b",
                "add sp, sp, #4",
                "pop {{r4-r11, lr}}",
                inout("r0") &args as *const StftRowArgs => _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r12") _,
            );
        }
        true
    }

    /// See `lstm_cell_update`.
    #[inline]
    pub(super) fn cell_update(
        gates: &[[i32; 2]],
        hn: usize,
        h: &mut [i16; MAX_HIDDEN],
        c: &mut [i16; MAX_HIDDEN],
        k: CellParams,
        table: &IntervalTable,
    ) -> bool {
        if hn > MAX_HIDDEN
            || gates.len() < 4 * hn
            || c.as_ptr() as usize != h.as_ptr() as usize + C_OFFSET
        {
            return false;
        }
        if hn == 0 {
            return true;
        }
        let h = h[..hn].as_mut_ptr_range();
        let p = CellArgs {
            gi: gates.as_ptr(),
            off: 8 * hn,
            go: gates[3 * hn..].as_ptr(),
            h: h.start,
            h_end: h.end,
            table: &table[256],
            ig_half: k.ig_half,
            ig_shift: k.ig_shift,
            q_mul: k.q_mul,
            q_add: k.q_add,
        };
        // SAFETY: for j < hn the loop reads gates[j], gates[hn + j], gates[2·hn + j] and
        // gates[3·hn + j] (inside `gates`: 4·hn ≤ len), reads and writes h[j] and c[j] (c is
        // C_OFFSET bytes after h, as checked; both exclusively borrowed, hn ≤ MAX_HIDDEN), and
        // reads the table at 256 + (v >> 10 saturated to -256..=255): 0..=511. It saves and
        // restores r4-r11 and lr.
        unsafe {
            core::arch::asm!(
                "push {{r4-r11, lr}}",
                "ldm r0, {{r0, r1, r2, r3, r4, r5, r7, r8, r9, r10}}",
                "mov r6, #16384",
                // Four units per loop pass; a count of 4m + 3, 4m + 2 or 4m + 1 enters at the
                // second, third or fourth (r11: 2 · (count mod 4)).
                "sub r11, r4, r3",
                "ands r11, r11, #6",
                "beq 1f",
                "cmp r11, #4",
                "bhi 3f",
                "beq 4f",
                "b 5f",
                "1:",
                CELL_UNIT!(),
                "3:",
                CELL_UNIT!(),
                "4:",
                CELL_UNIT!(),
                "5:",
                CELL_UNIT!(),
                "cmp r3, r4",
                "bne 1b",
                "pop {{r4-r11, lr}}",
                coff = const C_OFFSET,
                inout("r0") &p as *const CellArgs => _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r12") _,
            );
        }
        true
    }

    /// One chunk of the blocked kernel: 4 rows × 4 values = 16 MACs in 14 instructions,
    /// 56 bytes (all 32-bit encodings). Activation words r8, r9; pair 0's accumulators r2:r3
    /// (SMLALD, 64 bits) and r4 (SMLAD of the SXTB16 low bytes), pair 1's r5:r6 and r7.
    macro_rules! BLOCK_CHUNK {
        () => {
            "ldmia.w r1!, {{r8, r9}}
             ldmia.w r0!, {{r10, r11, r12, lr}}
             smlald r2, r3, r10, r8
             sxtb16 r10, r10
             smlad r4, r10, r8, r4
             smlald r2, r3, r11, r9
             sxtb16 r11, r11
             smlad r4, r11, r9, r4
             smlald r5, r6, r12, r8
             sxtb16 r12, r12
             smlad r7, r12, r8, r7
             smlald r5, r6, lr, r9
             sxtb16 lr, lr
             smlad r7, lr, r9, r7"
        };
    }
    /// b's sums of both pairs from the 64-bit P = 256·B + A and a's sum A: ⌊P / 256⌋ = B +
    /// ⌊A / 256⌋, so B = (the low word of P >> 8) − (A >> 8), exact modulo 2^32 and B fits
    /// 32 bits; into r2 (pair 0) and r5 (pair 1); a's stay in r4 and r7. 3 instructions a pair.
    macro_rules! BLOCK_EXTRACT {
        () => {
            "lsr.w r2, r2, #8
             orr.w r2, r2, r3, lsl #24
             sub.w r2, r2, r4, asr #8
             lsr.w r5, r5, #8
             orr.w r5, r5, r6, lsl #24
             sub.w r5, r5, r7, asr #8"
        };
    }
    /// Clears the six accumulators.
    macro_rules! BLOCK_CLEAR {
        () => {
            "movs r2, #0
             movs r3, #0
             movs r4, #0
             movs r5, #0
             movs r6, #0
             movs r7, #0"
        };
    }

    /// What the blocked kernel reads (one pointer in r0; fields at fixed offsets).
    #[repr(C)]
    struct BlockParams {
        /// +0: first block's first weight word.
        w: *const i8,
        /// +4, +8: x and h as words of value pairs.
        x: *const u32,
        h: *const u32,
        /// +12, +16: first output word and one past the last.
        out: *mut i32,
        out_end: *mut i32,
        /// +20, +24: chunks of the x part (≤ MAX_BLOCK_X_CHUNKS) and of the h part.
        x_chunks: usize,
        h_chunks: usize,
    }

    /// Runs the blocked kernel if the arguments suit it (see `lstm_block_sums`) and returns
    /// true after writing every element of `out`; returns false, writing nothing, otherwise.
    #[inline]
    pub(super) fn lstm_blocks(
        wb: &[i8],
        stride: usize,
        hh_offset: usize,
        x: &[u32],
        h: &[u32],
        out: &mut [MaybeUninit<[i32; 2]>],
    ) -> bool {
        let rows = out.len();
        if rows == 0 {
            return true;
        }
        if !rows.is_multiple_of(super::BLOCK_ROWS)
            || !stride.is_multiple_of(4)
            || !hh_offset.is_multiple_of(4)
            || hh_offset > stride
            || x.len() != hh_offset / 2
            || h.len() != (stride - hh_offset) / 2
            || hh_offset / 4 > super::MAX_BLOCK_X_CHUNKS
            || (stride - hh_offset) / 4 > super::MAX_BLOCK_H_CHUNKS
            || rows.checked_mul(stride).is_none_or(|end| end > wb.len())
            || !(wb.as_ptr() as usize).is_multiple_of(4)
        {
            return false;
        }
        let range = out.as_mut_ptr_range();
        let p = BlockParams {
            w: wb.as_ptr(),
            x: x.as_ptr(),
            h: h.as_ptr(),
            out: range.start.cast::<i32>(),
            out_end: range.end.cast::<i32>(),
            x_chunks: hh_offset / 4,
            h_chunks: (stride - hh_offset) / 4,
        };
        // SAFETY: the checks above guarantee that the kernel reads `wb[..rows·stride]` (inside
        // `wb`, word-aligned: `wb` is and stride is a multiple of 4; each block of 4 rows is
        // x_chunks + h_chunks chunks of 16 bytes = 4·stride bytes), `x[..2·x_chunks]` and
        // `h[..2·h_chunks]` (aligned `[u32]`s, exactly those lengths) once per block, and
        // writes the 2·rows words of `out` (exclusively borrowed, the layout of [[i32; 2]],
        // rows a multiple of 4); the chunk counts ≤ their unrolled copies keep the general
        // kernel's computed jumps inside it, and a full-h kernel runs only at exactly
        // MAX_BLOCK_H_CHUNKS h chunks and its own x chunk count. All save and restore r4-r11,
        // lr and sp.
        unsafe {
            match (p.h_chunks == super::MAX_BLOCK_H_CHUNKS, p.x_chunks) {
                (true, 1) => lstm_block_kernel_full_x1(&p),
                (true, 2) => lstm_block_kernel_full_x2(&p),
                (true, 3) => lstm_block_kernel_full_x3(&p),
                (true, 4) => lstm_block_kernel_full_x4(&p),
                (true, 5) => lstm_block_kernel_full_x5(&p),
                _ => lstm_block_kernel(&p),
            }
        }
        true
    }

    /// SAFETY (for callers): `p` must describe valid, aligned buffers as [`lstm_blocks`] checks.
    #[inline(never)]
    unsafe fn lstm_block_kernel(p: &BlockParams) {
        // Registers in the chunks: r0 weight pointer (one stream, block after block), r1
        // activation pointer, r2-r7 accumulators, r8-r9 activation words, r10-r12 and lr weight
        // words. Stack: [sp] x, [sp+4] x entry, [sp+8] h, [sp+12] h entry, [sp+16] out,
        // [sp+20] out_end. Each part is entered at (end of its unrolled chunks − chunks · 56).
        // SAFETY: see the caller; every memory access is inside the buffers `p` describes.
        unsafe {
            core::arch::asm!(
                "push {{r4-r11, lr}}",
                "sub sp, sp, #24",
                "ldr r1, [r0, #4]",
                "str r1, [sp, #0]",
                "ldr r1, [r0, #8]",
                "str r1, [sp, #8]",
                "ldr r1, [r0, #12]",
                "str r1, [sp, #16]",
                "ldr r1, [r0, #16]",
                "str r1, [sp, #20]",
                "movs r3, #56",
                // x entry. Every ADR sits on a word boundary (as in `lstm_kernel`).
                "ldr r1, [r0, #20]",
                ".p2align 2",
                "adr.w r2, 12f",
                "mls r2, r1, r3, r2",
                "orr r2, r2, #1",
                "str r2, [sp, #4]",
                // h entry.
                "ldr r1, [r0, #24]",
                ".p2align 2",
                "adr.w r2, 22f",
                "mls r2, r1, r3, r2",
                "orr r2, r2, #1",
                "str r2, [sp, #12]",
                "ldr r0, [r0, #0]",
                // Block loop: x part.
                "1:",
                BLOCK_CLEAR!(),
                "ldr r1, [sp, #0]",
                "ldr pc, [sp, #4]",
                "11:",
                ".rept {xchunks}",
                BLOCK_CHUNK!(),
                ".endr",
                "12:",
                ".if (12b - 11b) != 56 * {xchunks}",
                ".error \"dsp blocked kernel: unrolled x chunk is not 56 bytes\"",
                ".endif",
                BLOCK_EXTRACT!(),
                // Rows 4m..4m+3 are a0, b0, a1, b1: x sums to out[r][0].
                "ldr r1, [sp, #16]",
                "str r4, [r1]",
                "str r2, [r1, #8]",
                "str r7, [r1, #16]",
                "str r5, [r1, #24]",
                // h part.
                BLOCK_CLEAR!(),
                "ldr r1, [sp, #8]",
                "ldr pc, [sp, #12]",
                "21:",
                ".rept {hchunks}",
                BLOCK_CHUNK!(),
                ".endr",
                "22:",
                ".if (22b - 21b) != 56 * {hchunks}",
                ".error \"dsp blocked kernel: unrolled h chunk is not 56 bytes\"",
                ".endif",
                BLOCK_EXTRACT!(),
                "ldr r1, [sp, #16]",
                "str r4, [r1, #4]",
                "str r2, [r1, #12]",
                "str r7, [r1, #20]",
                "str r5, [r1, #28]",
                "adds r1, r1, #32",
                "str r1, [sp, #16]",
                "ldr r12, [sp, #20]",
                "cmp r1, r12",
                "bne 1b",
                "add sp, sp, #24",
                "pop {{r4-r11, lr}}",
                xchunks = const super::MAX_BLOCK_X_CHUNKS,
                hchunks = const super::MAX_BLOCK_H_CHUNKS,
                inout("r0") p as *const BlockParams => _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r12") _,
            );
        }
    }

    /// The 12 MAC instructions of one chunk of the full-h kernel (see `BLOCK_CHUNK`, the same
    /// arithmetic): weight words in r4-r7, activation words in r2 (values 4c, 4c+1) and r3;
    /// pair 0's 64-bit sum in r8:r9 and a0's in r10, pair 1's in r11:r12 and a1's in lr.
    /// SXTB16 works in place. 48 bytes.
    macro_rules! FULL_MACS {
        () => {
            "smlald r8, r9, r4, r2
             sxtb16 r4, r4
             smlad r10, r4, r2, r10
             smlald r8, r9, r5, r3
             sxtb16 r5, r5
             smlad r10, r5, r3, r10
             smlald r11, r12, r6, r2
             sxtb16 r6, r6
             smlad lr, r6, r2, lr
             smlald r11, r12, r7, r3
             sxtb16 r7, r7
             smlad lr, r7, r3, lr"
        };
    }

    /// One chunk of the full-h kernel at chunk position `slg_p` (an assembler symbol) from
    /// the bases r1 (activations) and r0 (weights), both 4 bytes before position 0: six LDRs in
    /// a row (16-bit encodings, pipelined: 7 cycles for 6 words), then `FULL_MACS`. 60 bytes;
    /// starting on a word boundary, its 32-bit instructions stay word-aligned.
    macro_rules! FULL_CHUNK {
        () => {
            concat!(
                "ldr r2, [r1, #(8 * slg_p + 4)]
                 ldr r3, [r1, #(8 * slg_p + 8)]
                 ldr r4, [r0, #(16 * slg_p + 4)]
                 ldr r5, [r0, #(16 * slg_p + 8)]
                 ldr r6, [r0, #(16 * slg_p + 12)]
                 ldr r7, [r0, #(16 * slg_p + 16)]
                 ",
                FULL_MACS!(),
                "
                 .set slg_p, slg_p + 1"
            )
        };
    }

    /// The last chunk of a pass of the full-h kernel's h loop (position 7): as `FULL_CHUNK`,
    /// but its last activation and weight loads write their addresses back, advancing r1 by 64
    /// and r0 by 128 for the next pass (64 bytes).
    macro_rules! FULL_CHUNK_LAST {
        () => {
            concat!(
                "ldr r2, [r1, #60]
                 ldr r4, [r0, #116]
                 ldr.w r3, [r1, #64]!
                 ldr r5, [r0, #120]
                 ldr r6, [r0, #124]
                 ldr.w r7, [r0, #128]!
                 ",
                FULL_MACS!()
            )
        };
    }

    /// The last chunk of the full-h kernel's x part (position MAX_BLOCK_X_CHUNKS − 1, run
    /// whenever there is an x part): as `FULL_CHUNK`, but its last activation and weight loads
    /// write their addresses back, advancing r1 by 8 and r0 by 16 · MAX_BLOCK_X_CHUNKS to the h
    /// part's bases (64 bytes).
    macro_rules! FULL_CHUNK_XLAST {
        () => {
            concat!(
                "ldr r2, [r1, #(8 * slg_p + 4)]
                 ldr r4, [r0, #(16 * slg_p + 4)]
                 ldr.w r3, [r1, #(8 * slg_p + 8)]!
                 ldr r5, [r0, #(16 * slg_p + 8)]
                 ldr r6, [r0, #(16 * slg_p + 12)]
                 ldr.w r7, [r0, #(16 * slg_p + 16)]!
                 ",
                FULL_MACS!()
            )
        };
    }

    /// `BLOCK_EXTRACT` for the full-h kernel's registers: b0's sum into r8 (a0's in r10), b1's
    /// into r11 (a1's in lr).
    macro_rules! FULL_EXTRACT {
        () => {
            "lsr.w r8, r8, #8
             orr.w r8, r8, r9, lsl #24
             sub.w r8, r8, r10, asr #8
             lsr.w r11, r11, #8
             orr.w r11, r11, r12, lsl #24
             sub.w r11, r11, lr, asr #8"
        };
    }

    /// Clears the six accumulators of the full-h kernel (UMULL of 0 × 0 clears a pair), with
    /// the given low register as the zero.
    macro_rules! FULL_CLEAR {
        ($z:literal) => {
            concat!(
                "movs ",
                $z,
                ", #0
                 umull r8, r9, ",
                $z,
                ", ",
                $z,
                "
                 umull r11, r12, ",
                $z,
                ", ",
                $z,
                "
                 mov r10, ",
                $z,
                "
                 mov lr, ",
                $z
            )
        };
    }

    /// Chunks of the h part per pass of the full-h kernel's h loop.
    const FULL_PASS_CHUNKS: usize = 8;
    /// Bytes of the h part's activations (64 words): the h loop ends when r1 (4 bytes before
    /// the next pass) is a multiple of this, so the copy is placed with its end − 4 there.
    const FULL_H_BYTES: usize = 8 * super::MAX_BLOCK_H_CHUNKS;
    /// Stack frame of the full-h kernels: out_end, a spare word, out, a spare word, then room
    /// for the activations (x ending where h starts) at any 256-byte phase.
    const FULL_ACT_AT: usize = 16;
    const FULL_FRAME: usize = FULL_ACT_AT + 8 * super::MAX_BLOCK_X_CHUNKS + 2 * FULL_H_BYTES;
    // The h loop: whole passes; the pass-end test needs h to be 256 bytes; the 16-bit loads
    // and ADDs reach the x part's offsets.
    const _: () = assert!(
        super::MAX_BLOCK_H_CHUNKS == 4 * FULL_PASS_CHUNKS
            && FULL_H_BYTES == 256
            && 16 * super::MAX_BLOCK_X_CHUNKS + 16 <= 124
            && FULL_FRAME.is_multiple_of(8)
    );

    /// Defines `$name`, the blocked kernel for a full h part (MAX_BLOCK_H_CHUNKS chunks: the
    /// paper's models, H = 128) and exactly `$x` x chunks (one function per count, 1 to
    /// MAX_BLOCK_X_CHUNKS, so that the block loop has no computed jump and no run-time offset),
    /// laid out for the STM32F4's flash: the whole block loop (0.6 to 0.9 KiB) stays in the ART
    /// accelerator's 1 KiB instruction cache after the first block, instead of streaming a
    /// 2.5 KiB straight-line body from flash at 16 bytes per 6 cycles for each of the 128
    /// blocks. The activations are copied once to the stack, x ending where h starts, h placed
    /// so that the address 4 bytes before its end is a multiple of 256. Per block: the x part,
    /// unrolled, reads chunk position p at `r1 + 8p + 4` and `r0 + 16p + 4`, its last loads
    /// moving both bases on to the h part; then the h loop, 4 passes of 8 chunks whose last
    /// loads advance r1 and r0 (writeback), until r1's low byte is 0; 19 cycles per chunk of 16
    /// MACs, 16-bit loads; then the loop's direct branch back.
    ///
    /// SAFETY (for callers): `p` must describe valid, aligned buffers as [`lstm_blocks`]
    /// checks, with exactly MAX_BLOCK_H_CHUNKS h chunks and `$x` x chunks.
    macro_rules! full_kernel {
        ($name:ident, $x:literal) => {
            #[inline(never)]
            unsafe fn $name(p: &BlockParams) {
                // Registers in the block loop: r0 weights, r1 activations (each 4 bytes before
                // the current position 0), r2-r3 activation words, r4-r7 weight words, r8-r12
                // and lr the accumulators. Stack: [sp] out_end − 4, [sp+8] out − 4 (the block's
                // last store writes it back), then the activation area.
                // SAFETY: see the caller; every memory access is inside the buffers `p`
                // describes or the kernel's own stack frame (x's copy starts at h − 8 · x
                // chunks ≥ the area's start; h's end is at most the frame's end).
                unsafe {
                    core::arch::asm!(
                        "push {{r4-r11, lr}}",
                        "sub sp, sp, #{frame}",
                        // The output pointers 4 bytes early: the block's last store writes back.
                        "ldr r1, [r0, #16]",
                        "subs r1, r1, #4",
                        "str r1, [sp, #0]",
                        "ldr r1, [r0, #12]",
                        "subs r1, r1, #4",
                        "str r1, [sp, #8]",
                        // h's start (r12): the lowest address ≥ the area + 8 · MAX x chunks
                        // that is 4 more than a multiple of 256.
                        "addw r12, sp, #({act_at} + 8 * {xmax} + 251)",
                        "bic r12, r12, #255",
                        "add.w r12, r12, #4",
                        // Copy x (2 words per chunk) to end at h's start, then h after it.
                        "sub.w r2, r12, #(8 * {x})",
                        "ldr r1, [r0, #4]",
                        "movs r3, #{x}",
                        "14:",
                        "ldmia r1!, {{r4, r5}}",
                        "stmia r2!, {{r4, r5}}",
                        "subs r3, r3, #1",
                        "bne 14b",
                        "ldr r1, [r0, #8]",
                        "movs r3, #{hpasses}",
                        "10:",
                        "ldmia r1!, {{r4-r11}}",
                        "stmia r2!, {{r4-r11}}",
                        "subs r3, r3, #1",
                        "bne 10b",
                        // r0: the first block's weights − 4; r1: the x area (position 0) − 4.
                        "ldr r0, [r0, #0]",
                        "subs r0, r0, #4",
                        "subw r1, r12, #(8 * {x} + 4)",
                        FULL_CLEAR!("r2"),
                        // Over the alignment padding.
                        "b.w 11f",
                        // The block loop, on a 1 KiB boundary: it fits the ART's 64 lines of 16
                        // bytes (the bench's per-function stall shows it), and no instruction of
                        // it sits at the end of a 1 KiB page (where QEMU ends a translation block
                        // and the cycle model charges a refill). x part: accumulators clear; its
                        // last chunk moves r0 and r1 on to the h part.
                        ".p2align 10",
                        "11:",
                        ".set slg_p, 0",
                        ".rept {x} - 1",
                        FULL_CHUNK!(),
                        ".endr",
                        FULL_CHUNK_XLAST!(),
                        FULL_EXTRACT!(),
                        // Rows 4m..4m+3 are a0, b0, a1, b1: x sums to out[r][0] (r2 = out − 4).
                        "ldr r2, [sp, #8]",
                        "str.w r10, [r2, #4]",
                        "str.w r8, [r2, #12]",
                        "str.w lr, [r2, #20]",
                        "str.w r11, [r2, #28]",
                        FULL_CLEAR!("r3"),
                        // h loop: passes of 8 chunks until r1's low byte is 0 (after the 4th),
                        // on a word boundary (its 32-bit instructions stay word-aligned).
                        ".p2align 2",
                        "20:",
                        ".set slg_p, 0",
                        ".rept {pass} - 1",
                        FULL_CHUNK!(),
                        ".endr",
                        FULL_CHUNK_LAST!(),
                        "lsls r2, r1, #24",
                        "bne.w 20b",
                        FULL_EXTRACT!(),
                        "ldr r2, [sp, #8]",
                        "ldr r3, [sp, #0]",
                        "str.w r10, [r2, #8]",
                        "str.w r8, [r2, #16]",
                        "str.w lr, [r2, #24]",
                        "str.w r11, [r2, #32]!",
                        "str r2, [sp, #8]",
                        // Back to the x base: r0 is already 4 bytes before the next block, r1
                        // at h's end − 4.
                        "subw r1, r1, #({h_bytes} + 8 * {x})",
                        FULL_CLEAR!("r4"),
                        "cmp r2, r3",
                        "bne.w 11b",
                        "add sp, sp, #{frame}",
                        "pop {{r4-r11, lr}}",
                        x = const $x,
                        frame = const FULL_FRAME,
                        act_at = const FULL_ACT_AT,
                        h_bytes = const FULL_H_BYTES,
                        xmax = const super::MAX_BLOCK_X_CHUNKS,
                        hpasses = const super::MAX_BLOCK_H_CHUNKS / 4,
                        pass = const FULL_PASS_CHUNKS,
                        inout("r0") p as *const BlockParams => _,
                        out("r1") _,
                        out("r2") _,
                        out("r3") _,
                        out("r12") _,
                    );
                }
            }
        };
    }
    full_kernel!(lstm_block_kernel_full_x1, 1);
    full_kernel!(lstm_block_kernel_full_x2, 2);
    full_kernel!(lstm_block_kernel_full_x3, 3);
    full_kernel!(lstm_block_kernel_full_x4, 4);
    full_kernel!(lstm_block_kernel_full_x5, 5);
    // One full-h kernel per x chunk count 1..=MAX_BLOCK_X_CHUNKS (see `lstm_blocks`).
    const _: () = assert!(super::MAX_BLOCK_X_CHUNKS == 5);

    /// What the LSTM kernel reads (one pointer in r0; fields at fixed offsets).
    #[repr(C)]
    struct LstmParams {
        /// +0: first row's first weight word.
        w: *const i8,
        /// +4: permuted x.
        x: *const u32,
        /// +8: permuted h.
        h: *const u32,
        /// +12: first output word.
        out: *mut i32,
        /// +16: one past the last output word.
        out_end: *mut i32,
        /// +20, +24: x part: 3-word blocks (≤ ASM_X_BLOCKS) and words left (0, 1 or 2).
        x_blocks: usize,
        x_rem: usize,
        /// +28, +32: h part: 3-word blocks (≤ ASM_BLOCKS) and words left (0, 1 or 2).
        h_blocks: usize,
        h_rem: usize,
    }

    /// Runs the LSTM kernel if the arguments suit it (see `lstm_gate_sums`) and returns true
    /// after writing every element of `out`; returns false, writing nothing, otherwise.
    #[inline]
    pub(super) fn lstm_rows(
        w: &[i8],
        stride: usize,
        hh_offset: usize,
        x: &[u32],
        h: &[u32],
        out: &mut [MaybeUninit<[i32; 2]>],
    ) -> bool {
        let (xw, hw) = (x.len() / 2, h.len() / 2);
        let rows = out.len();
        if rows == 0 {
            return true;
        }
        let contiguous = hh_offset == 4 * xw && stride == hh_offset + 4 * hw;
        let fits = rows.checked_mul(stride).is_some_and(|end| end <= w.len());
        if !contiguous
            || !fits
            || xw > 3 * ASM_X_BLOCKS + 2
            || hw > 3 * ASM_BLOCKS + 2
            || !(w.as_ptr() as usize).is_multiple_of(4)
        {
            return false;
        }
        let range = out.as_mut_ptr_range();
        let p = LstmParams {
            w: w.as_ptr(),
            x: x.as_ptr(),
            h: h.as_ptr(),
            out: range.start.cast::<i32>(),
            // One past the end of `out`, as i32 words.
            out_end: range.end.cast::<i32>(),
            x_blocks: xw / 3,
            x_rem: xw % 3,
            h_blocks: hw / 3,
            h_rem: hw % 3,
        };
        // SAFETY: the checks above guarantee that the kernel reads `w[..rows·stride]` (inside
        // `w`, word-aligned: `w` is and stride = 4·(xw + hw)), `x[..2·xw]` and `h[..2·hw]`
        // (aligned `[u32]`s), and writes the 2·rows words of `out` (exclusively borrowed, the
        // layout of [[i32; 2]]); the block counts ≤ their unrolled copies and remainders < 3
        // keep the computed jumps inside the kernel. It saves and restores r4-r11, lr and sp.
        unsafe { lstm_kernel(&p) };
        true
    }

    /// SAFETY (for callers): `p` must describe valid, aligned buffers as [`lstm_rows`] checks.
    #[inline(never)]
    unsafe fn lstm_kernel(p: &LstmParams) {
        // Registers: r0 weight pointer (one stream: x part, h part, next row),
        // r1 activation pointer, r2 accumulator, r3-r5 weight words, r6-r11 activation words,
        // r12 scratch, lr output pointer. Stack: [sp] x, [sp+4] x entry, [sp+8] x block entry,
        // [sp+12] h, [sp+16] h entry, [sp+20] h block entry, [sp+24] out_end.
        // Entries: a remainder stub (1 or 2 words, starting with SMUAD so that it also clears
        // the accumulator) or, with no remainder, a stub that clears it; each stub then jumps to
        // the block entry (h: the end of the unrolled blocks - blocks · 56 bytes; x: the SMLAD
        // copy of its one block). An x part of exactly one block (9 to 12 inputs) enters a
        // SMUAD copy of the block directly, which falls through to the store.
        // SAFETY: see the caller; every memory access is inside the buffers `p` describes.
        unsafe {
            core::arch::asm!(
                "push {{r4-r11, lr}}",
                "sub sp, sp, #28",
                "ldr r1, [r0, #4]",
                "str r1, [sp, #0]",
                "ldr r1, [r0, #8]",
                "str r1, [sp, #12]",
                "ldr r1, [r0, #16]",
                "str r1, [sp, #24]",
                "movs r3, #56",
                // h block entry. Every ADR sits on a word boundary (see `kernel`).
                "ldr r1, [r0, #28]",
                ".p2align 2",
                "adr.w r2, 22f",
                "mls r2, r1, r3, r2",
                "orr r2, r2, #1",
                "str r2, [sp, #20]",
                // x block entry after a stub: the SMLAD copy of the block, or none.
                "ldr r1, [r0, #20]",
                ".p2align 2",
                "adr.w r2, 12f",
                "cbz r1, 35f",
                ".p2align 2",
                "adr.w r2, 18f",
                "35:",
                "orr r2, r2, #1",
                "str r2, [sp, #8]",
                // x entry: no remainder: the SMUAD block (falls through to the store) or
                // the clearing stub; else the stub for 1 or 2 words.
                "ldr r3, [r0, #24]",
                "cbnz r3, 36f",
                ".p2align 2",
                "adr.w r2, 14f",
                "cbz r1, 37f",
                ".p2align 2",
                "adr.w r2, 11f",
                "b 37f",
                "36:",
                ".p2align 2",
                "adr.w r2, 15f",
                "cmp r3, #1",
                "beq 37f",
                ".p2align 2",
                "adr.w r2, 16f",
                "37:",
                "orr r2, r2, #1",
                "str r2, [sp, #4]",
                // h entry by remainder.
                "ldr r1, [r0, #32]",
                ".p2align 2",
                "adr.w r2, 24f",
                "cmp r1, #1",
                "bne 33f",
                ".p2align 2",
                "adr.w r2, 25f",
                "33:",
                "cmp r1, #2",
                "bne 34f",
                ".p2align 2",
                "adr.w r2, 26f",
                "34:",
                "orr r2, r2, #1",
                "str r2, [sp, #16]",
                "ldr lr, [r0, #12]",
                "ldr r0, [r0, #0]",
                // Row loop: x part.
                "1:",
                "ldr r1, [sp, #0]",
                "ldr pc, [sp, #4]",
                "11:",
                BLOCK_FIRST!(),
                "12:",
                "str r2, [lr], #4",
                // h part.
                "ldr r1, [sp, #12]",
                "ldr pc, [sp, #16]",
                "21:",
                ".rept {hblocks}",
                BLOCK!(),
                ".endr",
                "22:",
                ".if (22b - 21b) != 56 * {hblocks}",
                ".error \"dsp lstm kernel: unrolled h block is not 56 bytes\"",
                ".endif",
                "str r2, [lr], #4",
                "ldr r12, [sp, #24]",
                "cmp lr, r12",
                "bne 1b",
                "b 9f",
                // x stubs: none, one, two leftover words.
                "14:",
                "movs r2, #0",
                "b 12b",
                "15:",
                STUB1!(),
                "ldr pc, [sp, #8]",
                "16:",
                STUB2!(),
                "ldr pc, [sp, #8]",
                // The x block after a stub.
                "18:",
                BLOCK!(),
                "b 12b",
                // h stubs.
                "24:",
                "movs r2, #0",
                "ldr pc, [sp, #20]",
                "25:",
                STUB1!(),
                "ldr pc, [sp, #20]",
                "26:",
                STUB2!(),
                "ldr pc, [sp, #20]",
                "9:",
                "add sp, sp, #28",
                "pop {{r4-r11, lr}}",
                hblocks = const ASM_BLOCKS,
                inout("r0") p as *const LstmParams => _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r12") _,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    /// `out[r] = Σ_k w[r·stride + k]·v[k]` for every `r < out.len()`, with v in [`permute_q15`]'s
    /// order (`act`): many rows of [`dot_i8_q15_permuted`]. A row that runs past the end of `w`
    /// uses the weights that exist (as [`dot_i8_q15_permuted`]); one starting past it gives 0.
    fn dot_rows_i8_q15_portable(w: &[i8], stride: usize, act: &[u32], out: &mut [i32]) {
        for (r, o) in out.iter_mut().enumerate() {
            let row = r
                .checked_mul(stride)
                .and_then(|s| w.get(s..))
                .unwrap_or(&[]);
            *o = dot_i8_q15_permuted(row, act);
        }
    }

    use super::*;

    #[test]
    fn dot_matches_wide_sum_at_extremes() {
        for n in 0..=130usize {
            let w: Vec<i8> = (0..n)
                .map(|i| {
                    if i % 3 == 0 {
                        -128
                    } else {
                        127 - (i % 7) as i8
                    }
                })
                .collect();
            let v: Vec<i16> = (0..n)
                .map(|i| {
                    if i % 2 == 0 {
                        i16::MIN
                    } else {
                        i16::MAX - i as i16
                    }
                })
                .collect();
            let want: i64 = w.iter().zip(&v).map(|(&a, &b)| a as i64 * b as i64).sum();
            assert_eq!(dot_i8_i16(&w, &v) as i64, want, "n = {n}");
        }
        assert_eq!(dot_i8_i16(&[1, 2, 3], &[1, 1]), 3);
    }

    #[test]
    fn permuted_rows_match_wide_sum() {
        // Extreme and mixed patterns, every length 0..=140 (odd ones included), 3 rows with
        // junk weights past each row's length (they meet the activations' zero padding).
        let stride = 148;
        for n in 0..=MAX_ASM_VALUES {
            let w: Vec<i8> = (0..3 * stride)
                .map(|i| match (i % stride < n, i % 5) {
                    (false, _) => (i * 37) as i8,
                    (true, 0 | 3) => -128,
                    (true, 1) => 127,
                    (true, _) => (i * 13) as i8,
                })
                .collect();
            let v: Vec<i16> = (0..n)
                .map(|i| match i % 4 {
                    0 => i16::MIN,
                    1 => i16::MAX,
                    2 => -(i as i16) * 97,
                    _ => i16::MIN + i as i16,
                })
                .collect();
            let mut act = [0u32; MAX_ASM_VALUES / 2];
            let words = permute_q15(&v, &mut act);
            assert_eq!(words, 2 * n.div_ceil(4));
            let mut out = [0i32; 3];
            dot_rows_i8_q15_portable(&w, stride, &act[..words], &mut out);
            for (r, &o) in out.iter().enumerate() {
                let row = &w[r * stride..][..n];
                let want: i64 = row.iter().zip(&v).map(|(&a, &b)| a as i64 * b as i64).sum();
                assert_eq!(o as i64, want, "n = {n}, row {r}");
                assert_eq!(o, dot_i8_i16(row, &v), "n = {n}, row {r}");
            }
        }
    }

    #[test]
    fn permuted_rows_never_panic_on_odd_sizes() {
        let act = [0x0002_0001u32, 0x0004_0003, 0x0006_0005, 0x0008_0007];
        // v = 1, 3, 2, 4, 5, 7, 6, 8 in natural order.
        let w = [1i8; 10];
        let mut out = [0i32; 4];
        dot_rows_i8_q15_portable(&w, 6, &act, &mut out);
        // Row 0: all 8 weights; row 1 starts at 6: 4 weights (1+3+2+4); row 2 starts past.
        assert_eq!(out, [36, 10, 0, 0]);
        dot_rows_i8_q15_portable(&w, 0, &act[..3], &mut out);
        assert_eq!(out, [10; 4]); // a trailing odd word is ignored
        dot_rows_i8_q15_portable(&[], usize::MAX, &act, &mut out);
        assert_eq!(out, [0; 4]);
        // Too short an output buffer for permute_q15: whole groups only.
        let mut short = [0u32; 3];
        assert_eq!(permute_q15(&[1, 2, 3, 4, 5], &mut short), 2);
        assert_eq!(short[..2], [1 | 3 << 16, 2 | 4 << 16]);
    }
    #[test]
    fn lstm_gate_sums_equal_two_row_kernels() {
        // Contiguous rows (xw = 3, hw = 5), a gapped layout and one too short for its rows.
        let x: Vec<u32> = (0..6u32).map(|i| i.wrapping_mul(0x9E37_79B9)).collect();
        let h: Vec<u32> = (0..10u32)
            .map(|i| i.wrapping_mul(0x85EB_CA6B) ^ 0x8000_7FFF)
            .collect();
        let w: Vec<i8> = (0..200).map(|i| (i * 73 + 11) as i8).collect();
        for (stride, hh, len) in [(32, 12, 160), (40, 16, 200), (32, 12, 100), (0, 0, 0)] {
            let w = &w[..len];
            let mut buf = [core::mem::MaybeUninit::uninit(); 5];
            let got = lstm_gate_sums(w, stride, hh, &x, &h, &mut buf).to_vec();
            let (mut ax, mut ah) = ([0i32; 5], [0i32; 5]);
            dot_rows_i8_q15_portable(w, stride, &x, &mut ax);
            dot_rows_i8_q15_portable(w.get(hh..).unwrap_or(&[]), stride, &h, &mut ah);
            let want: Vec<[i32; 2]> = ax.iter().zip(&ah).map(|(&a, &b)| [a, b]).collect();
            assert_eq!(got, want, "stride {stride}, hh {hh}, len {len}");
            let mut port = [[0i32; 2]; 5];
            lstm_gate_sums_portable(w, stride, hh, &x, &h, &mut port);
            assert_eq!(port.to_vec(), want);
        }
    }
    #[test]
    fn blocked_layout_sums_equal_wide_row_major_sums() {
        // Every x part of 0..=3 chunks and h part of 0..=8 chunks, 8 rows, weights over the
        // whole ±127 range (and -128 in a rows), activations over the whole i16 range: the
        // blocked reference against i64 sums over the row-major weights.
        let mut seed = 0x1357_9bdfu32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        for xc in 0..=3usize {
            for hc in 0..=8usize {
                let (hh, stride, rows) = (4 * xc, 4 * (xc + hc), 8);
                let w: Vec<i8> = (0..rows * stride)
                    .map(|i| {
                        let r = next();
                        if (i / stride) % 2 == 0 && r % 11 == 0 {
                            -128
                        } else {
                            ((r % 255) as i32 - 127) as i8
                        }
                    })
                    .collect();
                let v: Vec<i16> = (0..stride).map(|_| next() as i16).collect();
                let words = |v: &[i16]| -> Vec<u32> {
                    v.chunks(2)
                        .map(|p| p[0] as u16 as u32 | (p[1] as u16 as u32) << 16)
                        .collect()
                };
                let (x, h) = (words(&v[..hh]), words(&v[hh..]));
                let mut packed = vec![0i8; w.len()];
                assert_eq!(pack_lstm_blocks(&w, stride, &mut packed), stride > 0);
                let mut got = vec![[0i32; 2]; rows];
                lstm_block_sums_portable(&packed, stride, hh, &x, &h, &mut got);
                let mut buf = vec![core::mem::MaybeUninit::uninit(); rows];
                let dispatched = lstm_block_sums(&packed, stride, hh, &x, &h, &mut buf).to_vec();
                for r in 0..rows {
                    let row = &w[r * stride..][..stride];
                    let dot = |a: &[i8], b: &[i16]| -> i64 {
                        a.iter().zip(b).map(|(&a, &b)| a as i64 * b as i64).sum()
                    };
                    let want = [dot(&row[..hh], &v[..hh]), dot(&row[hh..], &v[hh..])];
                    assert_eq!(got[r].map(i64::from), want, "x {xc} h {hc} row {r}");
                    assert_eq!(dispatched[r], got[r], "x {xc} h {hc} row {r}");
                }
            }
        }
        // Not representable: b = -128 over a negative a; shapes the layout does not take.
        let mut w = [1i8; 32];
        (w[0], w[8]) = (-1, -128);
        assert!(!pack_lstm_blocks(&w, 8, &mut [0; 32]));
        assert!(!pack_lstm_blocks(&[0; 24], 8, &mut [0; 24]));
        assert!(!pack_lstm_blocks(&[0; 24], 6, &mut [0; 24]));
    }

    #[test]
    fn permute_uninit_equals_permute() {
        let v: Vec<i16> = (0..140).map(|i| (i as i16).wrapping_mul(-4321)).collect();
        for n in 0..=140 {
            for words in [0, 1, 3, 8, 70, 71] {
                let mut want = vec![0u32; words];
                let k = permute_q15(&v[..n], &mut want);
                let mut buf = vec![core::mem::MaybeUninit::uninit(); words];
                let got = permute_q15_uninit(&v[..n], &mut buf);
                assert_eq!(got, &want[..k], "n = {n}, words = {words}");
            }
        }
    }
}
