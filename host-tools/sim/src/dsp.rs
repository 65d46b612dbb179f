//! Small signal helpers for reports: DFT magnitudes, the paper's STFT
//! (20-step rectangular window, shift 1), band powers.

use std::f64::consts::PI;

/// Magnitudes of the DFT bins `0..=n/2` of `x` (rectangular window, no scaling).
pub fn dft_magnitudes(x: &[f32]) -> Vec<f64> {
    let n = x.len();
    (0..=n / 2)
        .map(|k| {
            let (mut re, mut im) = (0.0f64, 0.0f64);
            for (t, &v) in x.iter().enumerate() {
                let a = -2.0 * PI * (k * t) as f64 / n as f64;
                re += v as f64 * a.cos();
                im += v as f64 * a.sin();
            }
            (re * re + im * im).sqrt()
        })
        .collect()
}

/// Frequency (Hz) of bin `k` for a window of `n` samples at `rate_hz`.
pub fn bin_hz(k: usize, n: usize, rate_hz: f64) -> f64 {
    k as f64 * rate_hz / n as f64
}

/// STFT as in the paper: rectangular window of `win` steps, shifted by one step;
/// row `t` is the window ending at step `t` (rows start at `win - 1`).
pub fn stft(x: &[f32], win: usize) -> Vec<Vec<f64>> {
    if x.len() < win || win == 0 {
        return Vec::new();
    }
    (win..=x.len())
        .map(|end| dft_magnitudes(&x[end - win..end]))
        .collect()
}

/// Mean power spectrum (|X|², bins `0..=win/2`) of the *first difference*
/// `d(t) = f(t) − f(t−1)` over all `win`-step windows of `x[start..end]`
/// (shift 1), each normalised by `win`. Differencing removes the slow force level so
/// the spectrum shows the fluctuations the paper's STFT feature sees.
pub fn mean_diff_power(x: &[f32], start: usize, end: usize, win: usize) -> Option<Vec<f64>> {
    let end = end.min(x.len());
    if end <= start + win {
        return None;
    }
    let d: Vec<f32> = (start + 1..end).map(|t| x[t] - x[t - 1]).collect();
    let rows = stft(&d, win);
    if rows.is_empty() {
        return None;
    }
    let mut acc = vec![0.0; rows[0].len()];
    for r in &rows {
        for (a, m) in acc.iter_mut().zip(r) {
            *a += m * m / win as f64;
        }
    }
    let k = rows.len() as f64;
    Some(acc.into_iter().map(|a| a / k).collect())
}

/// Share of the power in `[lo_hz, hi_hz]` (bins by centre frequency), excluding DC.
pub fn band_share(power: &[f64], win: usize, rate_hz: f64, lo_hz: f64, hi_hz: f64) -> f64 {
    let total: f64 = power.iter().skip(1).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let band: f64 = power
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(k, _)| {
            let f = bin_hz(*k, win, rate_hz);
            f >= lo_hz && f <= hi_hz
        })
        .map(|(_, p)| p)
        .sum();
    band / total
}

/// Median of a slice (NaN-free), `None` if empty.
pub fn median(v: &[f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    Some(slipguard_data::metrics::quantile(&s, 0.5))
}
