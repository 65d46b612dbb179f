//! The hot kernel: int8 × int16 dot products, the LSTM's and the dense layer's only inner loop.
//!
//! This module is the one place allowed to hold DSP intrinsics (`unsafe`, documented where used).
//! Today it is portable Rust; the Cortex-M4 instruction counts it reaches are measured by the
//! QEMU bench (`scripts/qemu-bench.sh`) and reported in the README.

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

#[cfg(test)]
mod tests {
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
}
