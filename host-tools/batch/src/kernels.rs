//! The batched path's kernels: the matrix product, the gate pass, the cell update and the
//! STFT bin sums for many channels (lanes) at once, structure of arrays.
//!
//! `#![allow(unsafe_code)]`: this module is the crate's one exception to `unsafe_code = "deny"`
//! (Cargo.toml), for the x86-64 AVX2 and AVX-512 VNNI intrinsics; every `unsafe` block has a
//! `// SAFETY:` line (`clippy::undocumented_unsafe_blocks` is denied). Everything else in the
//! crate is safe code.
//!
//! - [`batch_pair_sums`]: the LSTM's and the dense layer's sums for many channels, i16-pair
//!   weights × lane-contiguous activations: VPMADDWD tiles of 6 or 4 rows × 16 lanes (AVX2) or
//!   VPDPWSSD tiles of 8 rows × 32 lanes (AVX-512 F + VNNI), taken first where the CPU has it
//!   ([`PairSumsPath`]); reference [`batch_pair_sums_portable`]. The portable pair-sum loop does
//!   not become VPMADDWD under LLVM (it gives VPMULLD on widened lanes, about a third of the
//!   throughput), hence the intrinsics.
//! - [`batch_gate_rows`] and [`batch_cell_update`]: the gate pass and the cell update, 8 lanes
//!   at a time with gathered table lookups (AVX2); the lanes and rows they leave, and every
//!   lane on other CPUs, run the single path's code ([`crate::gate_rows`], [`crate::cell_update`]).
//! - [`stft_bin_sums`]: one STFT bin's sums over many lanes, [`stft_bin_sums_portable`]
//!   compiled for AVX2.
//!
//! Each path is chosen at run time (`is_x86_feature_detected!`, cached by the standard library)
//! and gives the same numbers as its portable reference: the sums are exact integer sums, the
//! rest is the single path's arithmetic (tests `batch_kernels.rs`).
#![allow(unsafe_code)]

use slipguard_core::dsp::{CellParams, LstmRowParams, interval_table};

/// Rows per register tile of [`batch_pair_sums`]'s x86-64 kernel.
pub const BATCH_TILE_ROWS: usize = 4;
/// Lanes (channels) per register tile of [`batch_pair_sums`]'s x86-64 kernel: two 8-lane
/// AVX2 registers.
pub const BATCH_TILE_LANES: usize = 16;

/// The pair product of two words of two i16 halves: `lo(a)·lo(b) + hi(a)·hi(b)` (PMADDWD's
/// lane, SMLAD's product pair).
#[inline(always)]
pub fn madd_pair(a: u32, b: u32) -> i32 {
    let lo = |v: u32| v as u16 as i16 as i32;
    // `>> 16`: the word's upper i16 half (the pair's second element).
    let hi = |v: u32| (v >> 16) as u16 as i16 as i32;
    // |each product| ≤ 2^30: the sum of two wraps only for (-2^15)² + (-2^15)², which int8
    // weights never meet; wrapping is what PMADDWD does.
    (lo(a) * lo(b)).wrapping_add(hi(a) * hi(b))
}

/// Which code runs the whole tiles of [`batch_pair_sums`] : what
/// [`batch_pair_sums_on`] returns and [`PairSumsPath::best`] detects. Every path gives the
/// same numbers as [`batch_pair_sums_portable`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum PairSumsPath {
    /// [`batch_pair_sums_portable`], all in Rust.
    Portable,
    /// x86-64 AVX2: VPMADDWD + VPADDD tiles of 6 or 4 rows × 16 lanes.
    Avx2,
    /// x86-64 AVX-512 F + VNNI: VPDPWSSD (multiply-add and accumulate in one instruction)
    /// tiles of 8 or 4 rows × 32 or 16 lanes, 32 registers.
    Avx512Vnni,
}

impl PairSumsPath {
    /// The fastest path this CPU runs (detected at run time; cached by the standard library).
    pub fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f")
                && std::is_x86_feature_detected!("avx512vnni")
            {
                return Self::Avx512Vnni;
            }
            if std::is_x86_feature_detected!("avx2") {
                return Self::Avx2;
            }
        }
        Self::Portable
    }

    /// Whether this CPU runs the path.
    pub fn available(self) -> bool {
        match self {
            Self::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Self::Avx2 => std::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Self::Avx512Vnni => {
                std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx512vnni")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// A short name for reports (`portable`, `avx2`, `avx512-vnni`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Portable => "portable",
            Self::Avx2 => "avx2",
            Self::Avx512Vnni => "avx512-vnni",
        }
    }
}

/// The batched LSTM's matrix product, many channels at once : for every row
/// `r < out.len() / lanes` and lane `l < lanes`,
/// `out[r·lanes + l] = Σ_p madd_pair(w[r·pairs + p], x[p·x_stride + l])` over `p < pairs`.
///
/// `w` holds each row's weights as i16 pairs (two consecutive inputs per word), `x` each
/// input pair's values for consecutive lanes (structure of arrays), so one weight word, broadcast,
/// meets 16 lanes' activations in two PMADDWDs. The sums wrap in `i32` (they never overflow
/// for int8 weights: < 2^23 per pair, < 2^30 for 128 pairs), so the order of summation does
/// not change them: every path gives the same numbers as [`batch_pair_sums_portable`].
///
/// Runs [`PairSumsPath::best`] through [`batch_pair_sums_on`]: on x86-64 with AVX-512 F and
/// VNNI, whole tiles of [`BATCH_TILE_ROWS`] rows × [`BATCH_TILE_LANES`] lanes in
/// `x86::pair_sums_avx512` (per input pair and 8 rows × 32 lanes: 2 lane loads, 8 broadcast
/// weights, 16 VPDPWSSD); with AVX2 only, in `x86::pair_sums_avx2` (per input pair and
/// 4 rows × 16 lanes: 2 lane loads, 4 broadcast weights, 8 VPMADDWD and 8 VPADDD); the rows
/// and lanes outside whole tiles, and other targets, run the portable code.
pub fn batch_pair_sums(
    w: &[u32],
    pairs: usize,
    x: &[u32],
    x_stride: usize,
    lanes: usize,
    out: &mut [i32],
) {
    batch_pair_sums_on(PairSumsPath::best(), w, pairs, x, x_stride, lanes, out);
}

/// [`batch_pair_sums`] on the path `want` where this CPU has it, else on the best one below
/// it (AVX-512 VNNI, then AVX2, then portable); returns the path that ran the whole tiles
/// ([`PairSumsPath::Portable`] also when there are none, or the slices are too short for
/// the kernels). The numbers are the same on every path; this is for tests and reports.
pub fn batch_pair_sums_on(
    want: PairSumsPath,
    w: &[u32],
    pairs: usize,
    x: &[u32],
    x_stride: usize,
    lanes: usize,
    out: &mut [i32],
) -> PairSumsPath {
    if lanes == 0 || pairs == 0 {
        out.fill(0);
        return PairSumsPath::Portable;
    }
    let rows = out.len() / lanes;
    let fits =
        x_stride >= lanes && w.len() >= rows * pairs && x.len() >= (pairs - 1) * x_stride + lanes;
    #[cfg(target_arch = "x86_64")]
    if fits {
        let (tr, tl) = (
            rows / BATCH_TILE_ROWS * BATCH_TILE_ROWS,
            lanes / BATCH_TILE_LANES * BATCH_TILE_LANES,
        );
        let ran = if want == PairSumsPath::Avx512Vnni && PairSumsPath::Avx512Vnni.available() {
            // SAFETY: AVX-512 F and VNNI are present (detected above); the kernel reads
            // w[..tr·pairs] and x[p·x_stride + l] for p < pairs, l < tl ≤ lanes, and writes
            // out[r·lanes + l] for r < tr ≤ rows, l < tl: all inside the slices by `fits`
            // and rows = out.len() / lanes.
            unsafe { x86::pair_sums_avx512(w, pairs, x, x_stride, lanes, tr, tl, out) };
            PairSumsPath::Avx512Vnni
        } else if want != PairSumsPath::Portable && PairSumsPath::Avx2.available() {
            // SAFETY: AVX2 is present (detected above); the same bounds as above.
            unsafe { x86::pair_sums_avx2(w, pairs, x, x_stride, lanes, tr, tl, out) };
            PairSumsPath::Avx2
        } else {
            PairSumsPath::Portable
        };
        if ran != PairSumsPath::Portable {
            // The lanes past the last whole tile, then the rows past it.
            if tl < lanes {
                for r in 0..tr {
                    pair_sums_cell_range(w, pairs, x, x_stride, lanes, r, tl..lanes, out);
                }
            }
            for r in tr..rows {
                pair_sums_cell_range(w, pairs, x, x_stride, lanes, r, 0..lanes, out);
            }
            return if tr > 0 && tl > 0 {
                ran
            } else {
                PairSumsPath::Portable
            };
        }
    }
    let _ = (fits, want);
    batch_pair_sums_portable(w, pairs, x, x_stride, lanes, out);
    PairSumsPath::Portable
}

/// The reference of [`batch_pair_sums`], all in Rust (missing weights or activations count 0).
pub fn batch_pair_sums_portable(
    w: &[u32],
    pairs: usize,
    x: &[u32],
    x_stride: usize,
    lanes: usize,
    out: &mut [i32],
) {
    if lanes == 0 {
        return;
    }
    for r in 0..out.len() / lanes {
        pair_sums_cell_range(w, pairs, x, x_stride, lanes, r, 0..lanes, out);
    }
}

/// Row `r` of [`batch_pair_sums_portable`] for the lanes in `range`.
#[allow(clippy::too_many_arguments)]
fn pair_sums_cell_range(
    w: &[u32],
    pairs: usize,
    x: &[u32],
    x_stride: usize,
    lanes: usize,
    r: usize,
    range: core::ops::Range<usize>,
    out: &mut [i32],
) {
    let row = w.get(r * pairs..).unwrap_or(&[]);
    for l in range {
        let mut acc = 0i32;
        for (p, &wp) in row.iter().take(pairs).enumerate() {
            let xv = x.get(p * x_stride + l).copied().unwrap_or(0);
            acc = acc.wrapping_add(madd_pair(wp, xv));
        }
        if let Some(o) = out.get_mut(r * lanes + l) {
            *o = acc;
        }
    }
}

/// Whether [`batch_gate_rows`] takes row `p`: the fast requantisation form, shift 33..=62.
pub fn batch_gate_row_fast(p: &LstmRowParams) -> bool {
    (p.shift as u32).wrapping_sub(33) < 30
}

/// The batched LSTM's gate pass where it runs fast : for each row r with
/// [`batch_gate_row_fast`] and each lane l below the returned count,
/// `gates[r·lanes + l] = f(requant(rows[r], acc_x[r·lanes + l], acc_h[r·lanes + l]))` with
/// f = tanh for the cell-candidate rows `2·hn..3·hn` and σ for the others (the single path's
/// `lstm::requant` and table lookups). With AVX2 (detected at run time) the lanes in whole
/// groups of 8 (`x86::gate_rows_avx2`); otherwise none (returns 0). The caller
/// (`batch`) does the rest with the single path's code.
pub fn batch_gate_rows(
    acc_x: &[i32],
    acc_h: &[i32],
    rows: &[LstmRowParams],
    hn: usize,
    lanes: usize,
    gates: &mut [i16],
) -> usize {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (detected above); the function is safe code compiled for it.
        return unsafe { x86::gate_rows_avx2(acc_x, acc_h, rows, hn, lanes, gates) };
    }
    let _ = (acc_x, acc_h, rows, hn, lanes, gates);
    0
}

/// The batched LSTM's cell update where it runs fast , for the lanes below the
/// returned count of the `lanes` lanes starting at lane `c0` of a state with row stride
/// `stride`: for each unit j < `hn` and lane i, `lstm::cell_unit` (with `k`'s constants) from
/// the gates `gates[(g·hn + j)·lanes + i]` (i, f, g, o) on `c[j·stride + c0 + i]`, writing c'
/// there and h' into the low (j even) or high (j odd) half of `h[(j / 2)·stride + c0 + i]`;
/// lanes with `on[i]` false keep their c and h. With AVX2 (detected at run time) the lanes in
/// whole groups of 8; otherwise none (returns 0).
#[allow(clippy::too_many_arguments)]
pub fn batch_cell_update(
    gates: &[i16],
    hn: usize,
    lanes: usize,
    k: CellParams,
    on: &[bool],
    h: &mut [u32],
    c: &mut [i16],
    stride: usize,
    c0: usize,
) -> usize {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (detected above); the function is safe code compiled for it.
        return unsafe { x86::cell_update_avx2(gates, hn, lanes, k, on, h, c, stride, c0) };
    }
    let _ = (gates, hn, lanes, k, on, h, c, stride, c0);
    0
}

/// One STFT time step of one bin for many lanes : `re[i] += xw[i]·c`,
/// `im[i] += xw[i]·s` in i64 (Q2.30 × Q1.15; exact, see `StftPlan::step`). With AVX2
/// (detected at run time) the same code compiled for AVX2 (VPMULDQ, four lanes a register).
pub fn stft_bin_sums(xw: &[i32], c: i16, s: i16, re: &mut [i64], im: &mut [i64]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (detected above); the function is safe code compiled for it.
        unsafe { x86::stft_bin_sums_avx2(xw, c, s, re, im) };
        return;
    }
    stft_bin_sums_portable(xw, c, s, re, im);
}

/// The code of [`stft_bin_sums`] (inlined into each target's copy).
#[inline(always)]
pub fn stft_bin_sums_portable(xw: &[i32], c: i16, s: i16, re: &mut [i64], im: &mut [i64]) {
    let (c, s) = (i64::from(c), i64::from(s));
    for ((&v, r), m) in xw.iter().zip(re.iter_mut()).zip(im.iter_mut()) {
        *r += i64::from(v) * c;
        *m += i64::from(v) * s;
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{BATCH_TILE_LANES, BATCH_TILE_ROWS, CellParams, LstmRowParams, interval_table};
    use core::arch::x86_64::{
        __m128i, __m256i, _mm_cvtsi32_si128, _mm_loadu_si128, _mm_storeu_si128, _mm256_add_epi32,
        _mm256_add_epi64, _mm256_and_si256, _mm256_blend_epi32, _mm256_blendv_epi8,
        _mm256_castsi256_si128, _mm256_cvtepi16_epi32, _mm256_i32gather_epi32, _mm256_loadu_si256,
        _mm256_madd_epi16, _mm256_max_epi32, _mm256_min_epi32, _mm256_mul_epi32,
        _mm256_mullo_epi32, _mm256_or_si256, _mm256_packs_epi32, _mm256_permute4x64_epi64,
        _mm256_set1_epi32, _mm256_setzero_si256, _mm256_sll_epi32, _mm256_sra_epi32,
        _mm256_srai_epi32, _mm256_srli_epi64, _mm256_storeu_si256, _mm512_dpwssd_epi32,
        _mm512_loadu_si512, _mm512_set1_epi32, _mm512_setzero_si512, _mm512_storeu_si512,
    };
    use slipguard_core::activation::IntervalTable;

    /// 8 lanes of `table` lookups ([`slipguard_core::activation::lookup`]) at the Q3.12 inputs `x`
    /// (i32 lanes within the i16 range): interval k = (x >> 7) + 256 (0..=511), position
    /// x & 127, its word `lo << 16 | step` by one 8-lane gather, lo + ((step·pos + 2^6) >> 7).
    #[target_feature(enable = "avx2")]
    fn lookup8(table: &IntervalTable, x: __m256i) -> __m256i {
        let k = _mm256_add_epi32(_mm256_srai_epi32::<7>(x), _mm256_set1_epi32(256));
        let pos = _mm256_and_si256(x, _mm256_set1_epi32(127));
        // SAFETY: k is in 0..=511 for every i16 input, so each 4-byte element k lies inside
        // the table's 512 words (`table` is a whole IntervalTable); AVX2 is on.
        let w = unsafe { _mm256_i32gather_epi32::<4>(table.as_ptr() as *const i32, k) };
        let lo = _mm256_srai_epi32::<16>(w);
        let step = _mm256_and_si256(w, _mm256_set1_epi32(0xFFFF));
        let frac = _mm256_add_epi32(_mm256_mullo_epi32(step, pos), _mm256_set1_epi32(64));
        _mm256_add_epi32(lo, _mm256_srai_epi32::<7>(frac))
    }

    /// sat16 of i32 lanes, still as i32 lanes.
    #[target_feature(enable = "avx2")]
    fn sat16(v: __m256i) -> __m256i {
        _mm256_max_epi32(
            _mm256_min_epi32(v, _mm256_set1_epi32(i16::MAX as i32)),
            _mm256_set1_epi32(i16::MIN as i32),
        )
    }

    /// 8 i16 from `s` (at least 8 long) as i32 lanes.
    #[target_feature(enable = "avx2")]
    fn load_i16x8(s: &[i16]) -> __m256i {
        assert!(s.len() >= 8);
        // SAFETY: 16 bytes inside `s` (checked above), unaligned load.
        _mm256_cvtepi16_epi32(unsafe { _mm_loadu_si128(s.as_ptr() as *const __m128i) })
    }

    /// The 8 i32 lanes of `v` (within the i16 range) into `d[..8]`.
    #[target_feature(enable = "avx2")]
    fn store_i16x8(d: &mut [i16], v: __m256i) {
        assert!(d.len() >= 8);
        // packs: [v0..3, v0..3 | v4..7, v4..7]; qwords 0 and 2 hold v0..7 in order.
        let p = _mm256_permute4x64_epi64::<0b1000>(_mm256_packs_epi32(v, v));
        // SAFETY: 16 bytes inside `d` (checked above), unaligned store.
        unsafe { _mm_storeu_si128(d.as_mut_ptr() as *mut __m128i, _mm256_castsi256_si128(p)) };
    }

    /// [`super::batch_gate_rows`] with 8 lanes per pass: the requantisation of
    /// `lstm::requant`'s fast form (shift 33..=62: z = 2^k·2^32 + acc_x·mx + acc_h·mh, its
    /// high word >> (k + 1), + bias, sat16) with VPMULDQ on the even and odd lanes, then the
    /// table lookup by gather, on the rows of the fast form; returns the lanes done (the
    /// caller does the rest).
    ///
    /// The bias is added without saturation after clamping it to ±2^30: the high word is
    /// below 2^30 in magnitude (|z| < 2^61 plus the half, see `lstm::requant`), so after the
    /// shift |t| < 2^29, t + bias cannot wrap, and any bias beyond ±2^30 saturates the i16
    /// result either way: the same number as the saturating add.
    #[target_feature(enable = "avx2")]
    pub(super) fn gate_rows_avx2(
        acc_x: &[i32],
        acc_h: &[i32],
        rows: &[LstmRowParams],
        hn: usize,
        lanes: usize,
        gates: &mut [i16],
    ) -> usize {
        let (sig, tanh) = (interval_table(false), interval_table(true));
        let n8 = lanes / 8 * 8;
        for (r, p) in rows.iter().enumerate() {
            let table = if (2 * hn..3 * hn).contains(&r) {
                tanh
            } else {
                sig
            };
            let span = r * lanes..(r + 1) * lanes;
            let (Some(g), Some(a), Some(b)) = (
                gates.get_mut(span.clone()),
                acc_x.get(span.clone()),
                acc_h.get(span),
            ) else {
                return 0;
            };
            if !super::batch_gate_row_fast(p) {
                continue;
            }
            let k = (p.shift as u32).wrapping_sub(33);
            let mx = _mm256_set1_epi32(p.mx);
            let mh = _mm256_set1_epi32(p.mh);
            // The row's requantize shift is `shift` on the 64-bit product; the high word
            // already drops 32, so `k + 1 = shift − 32` remains, and `1 << k` rounds half up
            // before it (as the core's `lstm::requant`).
            let half = _mm256_set1_epi32(1 << (k & 31));
            let cnt = _mm_cvtsi32_si128((k + 1) as i32);
            // Bias Q3.12 (the core's `LstmRowParams::bias_q12`), clamped to ±2^30 so the i32 add cannot wrap.
            let bias = _mm256_set1_epi32(p.bias_q12.clamp(-(1 << 30), 1 << 30));
            for i in (0..n8).step_by(8) {
                // SAFETY: i + 8 ≤ n8 ≤ lanes = a.len() = b.len(); unaligned loads.
                let (ax, ah) = unsafe {
                    (
                        _mm256_loadu_si256(a.as_ptr().add(i) as *const __m256i),
                        _mm256_loadu_si256(b.as_ptr().add(i) as *const __m256i),
                    )
                };
                let even = _mm256_add_epi64(_mm256_mul_epi32(ax, mx), _mm256_mul_epi32(ah, mh));
                let (axo, aho) = (_mm256_srli_epi64::<32>(ax), _mm256_srli_epi64::<32>(ah));
                let odd = _mm256_add_epi64(_mm256_mul_epi32(axo, mx), _mm256_mul_epi32(aho, mh));
                // High words: the even lanes' moved down, the odd lanes' in place.
                let hi = _mm256_blend_epi32::<0b1010_1010>(_mm256_srli_epi64::<32>(even), odd);
                let t = _mm256_sra_epi32(_mm256_add_epi32(hi, half), cnt);
                let z = sat16(_mm256_add_epi32(t, bias));
                store_i16x8(&mut g[i..], lookup8(table, z));
            }
        }
        n8
    }

    /// [`super::batch_cell_update`] with 8 lanes per pass (`lstm::cell_unit`'s
    /// arithmetic in i32 lanes: every product of two i16 and its rounding half fit, see there;
    /// the cell → Q3.12 conversion in its `q_mul`/`q_add` form; tanh by gather); returns the
    /// lanes done (the caller does the rest).
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn cell_update_avx2(
        gates: &[i16],
        hn: usize,
        lanes: usize,
        k: CellParams,
        on: &[bool],
        h: &mut [u32],
        c: &mut [i16],
        stride: usize,
        c0: usize,
    ) -> usize {
        let n8 = lanes / 8 * 8;
        let tanh = interval_table(true);
        // Q0.15 × Q0.15 products are Q0.30; `+ 2^14` then `>> 15` rounds them back to Q0.15.
        let round15 = _mm256_set1_epi32(1 << 14);
        let ig_half = _mm256_set1_epi32(k.ig_half);
        let ig_cnt = _mm_cvtsi32_si128(k.ig_shift as i32);
        let (q_mul, q_add) = (_mm256_set1_epi32(k.q_mul), _mm256_set1_epi32(k.q_add));
        let gate = |g: usize, j: usize| gates.get((g * hn + j) * lanes..(g * hn + j + 1) * lanes);
        for p in 0..hn.div_ceil(2) {
            let Some(hw) = h.get_mut(p * stride + c0..p * stride + c0 + lanes) else {
                return 0;
            };
            for u in 0..2 {
                let j = 2 * p + u;
                if j >= hn {
                    break;
                }
                let (Some(gi), Some(gf), Some(gg), Some(go), Some(cj), Some(on)) = (
                    gate(0, j),
                    gate(1, j),
                    gate(2, j),
                    gate(3, j),
                    c.get_mut(j * stride + c0..j * stride + c0 + lanes),
                    on.get(..lanes),
                ) else {
                    return 0;
                };
                // h is stored two i16 units a word: unit u is bits 16u..16u+15, so keep the other
                // half and shift the new value up by 16u.
                let keep = _mm256_set1_epi32(!(0xffff_u32 << (16 * u)) as i32);
                let up = _mm_cvtsi32_si128(16 * u as i32);
                for i in (0..n8).step_by(8) {
                    let (vi, vf) = (load_i16x8(&gi[i..]), load_i16x8(&gf[i..]));
                    let (vg, vo) = (load_i16x8(&gg[i..]), load_i16x8(&go[i..]));
                    let cv = load_i16x8(&cj[i..]);
                    let fc = _mm256_srai_epi32::<15>(_mm256_add_epi32(
                        _mm256_mullo_epi32(vf, cv),
                        round15,
                    ));
                    let ig = _mm256_sra_epi32(
                        _mm256_add_epi32(_mm256_mullo_epi32(vi, vg), ig_half),
                        ig_cnt,
                    );
                    let cn = sat16(_mm256_add_epi32(fc, ig));
                    let cq = sat16(_mm256_srai_epi32::<3>(_mm256_add_epi32(
                        _mm256_mullo_epi32(cn, q_mul),
                        q_add,
                    )));
                    let th = lookup8(tanh, cq);
                    let hv = sat16(_mm256_srai_epi32::<15>(_mm256_add_epi32(
                        _mm256_mullo_epi32(vo, th),
                        round15,
                    )));
                    // The lanes that step: on[i] as all-ones lanes.
                    let mut m = [0i32; 8];
                    for (m, &o) in m.iter_mut().zip(&on[i..i + 8]) {
                        *m = -(o as i32);
                    }
                    // SAFETY: 32 bytes of the local array `m`, unaligned load.
                    let mask = unsafe { _mm256_loadu_si256(m.as_ptr() as *const __m256i) };
                    store_i16x8(&mut cj[i..], _mm256_blendv_epi8(cv, cn, mask));
                    let w = &mut hw[i..i + 8];
                    // SAFETY: 32 bytes inside `w` (8 words), unaligned load and store.
                    unsafe {
                        let old = _mm256_loadu_si256(w.as_ptr() as *const __m256i);
                        let bits =
                            _mm256_sll_epi32(_mm256_and_si256(hv, _mm256_set1_epi32(0xffff)), up);
                        let new = _mm256_or_si256(_mm256_and_si256(old, keep), bits);
                        _mm256_storeu_si256(
                            w.as_mut_ptr() as *mut __m256i,
                            _mm256_blendv_epi8(old, new, mask),
                        );
                    }
                }
            }
        }
        n8
    }

    /// [`super::stft_bin_sums_portable`] compiled for AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) fn stft_bin_sums_avx2(xw: &[i32], c: i16, s: i16, re: &mut [i64], im: &mut [i64]) {
        super::stft_bin_sums_portable(xw, c, s, re, im)
    }

    /// [`super::batch_pair_sums`] over rows `..rows` (a multiple of [`BATCH_TILE_ROWS`]) and
    /// lanes `..tile_lanes` (a multiple of [`BATCH_TILE_LANES`]). Rows go in tiles of 6 (12
    /// accumulator registers: 6 rows × 2 × 8 lanes, with the two activation registers and the
    /// broadcast weight 15 of the 16) as long as the rest stays a multiple of 4, then tiles of
    /// 4: 2 activation loads per 12 VPMADDWD instead of per 8.
    ///
    /// # Safety
    /// AVX2 must be available; `w.len() ≥ rows·pairs`, `x.len() ≥ (pairs − 1)·x_stride +
    /// tile_lanes`, `out.len() ≥ (rows − 1)·lanes + tile_lanes`.
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn pair_sums_avx2(
        w: &[u32],
        pairs: usize,
        x: &[u32],
        x_stride: usize,
        lanes: usize,
        rows: usize,
        tile_lanes: usize,
        out: &mut [i32],
    ) {
        // An even number of 6-row tiles leaves a multiple of 4 rows (rows is one).
        let six = rows / 12 * 12;
        for r0 in (0..six).step_by(6) {
            // SAFETY: rows r0..r0 + 6 ≤ rows; the caller's contract for the rest.
            unsafe { tile::<6>(w, pairs, x, x_stride, lanes, r0, tile_lanes, out) };
        }
        for r0 in (six..rows).step_by(BATCH_TILE_ROWS) {
            // SAFETY: rows r0..r0 + 4 ≤ rows (rows − six is a multiple of 4).
            unsafe { tile::<BATCH_TILE_ROWS>(w, pairs, x, x_stride, lanes, r0, tile_lanes, out) };
        }
    }

    /// [`super::batch_pair_sums`] over rows `..rows` (a multiple of [`BATCH_TILE_ROWS`]) and
    /// lanes `..tile_lanes` (a multiple of [`BATCH_TILE_LANES`]) with AVX-512 F and VNNI:
    /// tiles of 8 rows while they fit (then one of 4) × 32 lanes (then one of 16), one
    /// VPDPWSSD per row and 16 lanes and input pair, each weight word broadcast once per
    /// tile row: 16 accumulators, 2 activation loads per 16 VPDPWSSD.
    ///
    /// # Safety
    /// AVX-512 F and VNNI must be available; `w.len() ≥ rows·pairs`, `x.len() ≥ (pairs − 1)·
    /// x_stride + tile_lanes`, `out.len() ≥ (rows − 1)·lanes + tile_lanes`.
    #[target_feature(enable = "avx512f,avx512vnni")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn pair_sums_avx512(
        w: &[u32],
        pairs: usize,
        x: &[u32],
        x_stride: usize,
        lanes: usize,
        rows: usize,
        tile_lanes: usize,
        out: &mut [i32],
    ) {
        let eight = rows / 8 * 8;
        let wide = tile_lanes / 32 * 32;
        for r0 in (0..rows).step_by(BATCH_TILE_ROWS) {
            let big = r0 < eight;
            if big && r0 % 8 != 0 {
                continue; // the second half of an 8-row tile
            }
            for l0 in (0..wide).step_by(32) {
                // SAFETY: rows r0..r0 + 8 (or + 4) ≤ rows, lanes l0..l0 + 32 ≤ tile_lanes; the
                // caller's contract for the rest.
                unsafe {
                    if big {
                        tile512::<8, 2>(w, pairs, x, x_stride, lanes, r0, l0, out)
                    } else {
                        tile512::<4, 2>(w, pairs, x, x_stride, lanes, r0, l0, out)
                    }
                }
            }
            if wide < tile_lanes {
                // SAFETY: as above, lanes wide..wide + 16 = tile_lanes.
                unsafe {
                    if big {
                        tile512::<8, 1>(w, pairs, x, x_stride, lanes, r0, wide, out)
                    } else {
                        tile512::<4, 1>(w, pairs, x, x_stride, lanes, r0, wide, out)
                    }
                }
            }
        }
    }

    /// Rows `r0..r0 + R`, lanes `l0..l0 + 16·L` of [`pair_sums_avx512`]: R·L accumulators
    /// over all pairs, then one store each.
    ///
    /// # Safety
    /// As [`pair_sums_avx512`], with r0 + R ≤ its `rows` and l0 + 16·L ≤ its `tile_lanes`.
    #[target_feature(enable = "avx512f,avx512vnni")]
    #[allow(clippy::too_many_arguments)]
    #[inline]
    unsafe fn tile512<const R: usize, const L: usize>(
        w: &[u32],
        pairs: usize,
        x: &[u32],
        x_stride: usize,
        lanes: usize,
        r0: usize,
        l0: usize,
        out: &mut [i32],
    ) {
        let (wp, xp, op) = (w.as_ptr(), x.as_ptr(), out.as_mut_ptr());
        let mut acc = [[_mm512_setzero_si512(); L]; R];
        for p in 0..pairs {
            let mut xv = [_mm512_setzero_si512(); L];
            for (j, v) in xv.iter_mut().enumerate() {
                // SAFETY: p·x_stride + l0 + 16·L ≤ (pairs − 1)·x_stride + tile_lanes ≤ x.len()
                // (caller's contract); unaligned load.
                *v = unsafe { _mm512_loadu_si512(xp.add(p * x_stride + l0 + 16 * j).cast()) };
            }
            for (rr, a) in acc.iter_mut().enumerate() {
                // SAFETY: (r0 + rr)·pairs + p < rows·pairs ≤ w.len().
                let wv = _mm512_set1_epi32(unsafe { *wp.add((r0 + rr) * pairs + p) } as i32);
                for (a, &v) in a.iter_mut().zip(&xv) {
                    *a = _mm512_dpwssd_epi32(*a, wv, v);
                }
            }
        }
        for (rr, a) in acc.iter().enumerate() {
            for (j, &v) in a.iter().enumerate() {
                // SAFETY: (r0 + rr)·lanes + l0 + 16·L ≤ (rows − 1)·lanes + tile_lanes ≤
                // out.len() (caller's contract); unaligned store.
                unsafe { _mm512_storeu_si512(op.add((r0 + rr) * lanes + l0 + 16 * j).cast(), v) };
            }
        }
    }

    /// Rows `r0..r0 + R` of [`pair_sums_avx2`], every lane tile: 2R accumulators over all
    /// pairs, then one store each.
    ///
    /// # Safety
    /// As [`pair_sums_avx2`], with r0 + R ≤ its `rows`.
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    #[inline]
    unsafe fn tile<const R: usize>(
        w: &[u32],
        pairs: usize,
        x: &[u32],
        x_stride: usize,
        lanes: usize,
        r0: usize,
        tile_lanes: usize,
        out: &mut [i32],
    ) {
        let (wp, xp, op) = (w.as_ptr(), x.as_ptr(), out.as_mut_ptr());
        for l0 in (0..tile_lanes).step_by(BATCH_TILE_LANES) {
            let mut acc = [[_mm256_setzero_si256(); 2]; R];
            for p in 0..pairs {
                // SAFETY: p·x_stride + l0 + 16 ≤ (pairs − 1)·x_stride + tile_lanes ≤ x.len()
                // (caller's contract); unaligned loads.
                let (xa, xb) = unsafe {
                    let at = xp.add(p * x_stride + l0);
                    (
                        _mm256_loadu_si256(at as *const __m256i),
                        _mm256_loadu_si256(at.add(8) as *const __m256i),
                    )
                };
                for (rr, a) in acc.iter_mut().enumerate() {
                    // SAFETY: (r0 + rr)·pairs + p < rows·pairs ≤ w.len().
                    let wv = _mm256_set1_epi32(unsafe { *wp.add((r0 + rr) * pairs + p) } as i32);
                    a[0] = _mm256_add_epi32(a[0], _mm256_madd_epi16(wv, xa));
                    a[1] = _mm256_add_epi32(a[1], _mm256_madd_epi16(wv, xb));
                }
            }
            for (rr, a) in acc.iter().enumerate() {
                // SAFETY: (r0 + rr)·lanes + l0 + 16 ≤ (rows − 1)·lanes + tile_lanes ≤ out.len().
                unsafe {
                    let at = op.add((r0 + rr) * lanes + l0);
                    _mm256_storeu_si256(at as *mut __m256i, a[0]);
                    _mm256_storeu_si256(at.add(8) as *mut __m256i, a[1]);
                }
            }
        }
    }
}
