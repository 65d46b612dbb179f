//! Band-limited resampling of a trial to another frame rate (e.g. the 16.7 Hz real trials to
//! the hand profile's 40 Hz), with its marks and labels moved to the new time base by time.
//!
//! **Method** (windowed-sinc interpolation, offline: the whole trial is known). Output step `k`
//! is at `t_k = k / rate_out` seconds, on the same time origin as the input (step 0 at 0 s);
//! the output ends at the last output step not after the input's last step. Each output sample
//! is a weighted sum of the input samples around `t_k`:
//!
//! ```text
//! y(t_k) = Σ_n x[n] · h(t_k − n / rate_in) / Σ_n h(t_k − n / rate_in)
//! h(τ)   = sinc(2 f_c τ) · blackman(τ / (HALF_WIDTH / (2 f_c)))
//! f_c    = ROLL_OFF · min(rate_in, rate_out) / 2
//! ```
//!
//! The low-pass cut-off `f_c` is below the lower of the two Nyquist frequencies, so upsampling
//! reconstructs the input's band without its images and downsampling removes what the new rate
//! cannot hold. The kernel spans [`HALF_WIDTH`] zero crossings either side (Blackman window:
//! stop band below −70 dB; transition band about 2.6 Hz wide at 16.7 → 40 Hz, so the pass
//! band reaches about 6 Hz). The weights are normalised to sum to 1, so a constant stays exactly
//! constant; beyond the trial's ends the first and last samples are held (force pads sit at a
//! non-zero baseline, and zero padding would ring at the ends).
//!
//! **Marks and labels**: a step index `m` (grasp start, lift, third mark, release, drop step,
//! slip onset) becomes the first output step at or after its time, `ceil(m · rate_out /
//! rate_in)` (less than one output step, 25 ms at 40 Hz, after the same second); each output
//! step's stability label is the one of the last input step at or before its time, so a label
//! change lands on the same output step as a mark at that input step. Per-channel contact
//! flags are kept. A hand-written kernel: the one offline interpolation is shorter than driving a
//! streaming resampler crate chunk by chunk with its delay compensation (docs/model-format.md,
//! "Resampling recordings").

use std::fmt;

use crate::trial::Trial;

/// Zero crossings of the sinc on each side of the output instant.
pub const HALF_WIDTH: f64 = 16.0;
/// Cut-off as a share of the lower Nyquist frequency.
pub const ROLL_OFF: f64 = 0.9;

/// Why a trial cannot be resampled.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum ResampleError {
    /// The target rate is not a finite number above 0.
    BadRate(f32),
    /// The trial is inconsistent ([`Trial::validate`]) or has no steps.
    BadTrial(String),
}

impl fmt::Display for ResampleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResampleError::BadRate(r) => {
                write!(f, "target rate {r} Hz is not a finite number above 0")
            }
            ResampleError::BadTrial(m) => write!(f, "cannot resample the trial: {m}"),
        }
    }
}

impl std::error::Error for ResampleError {}

/// Number of output steps: those at or before the input's last step in time.
pub fn output_len(n_in: usize, rate_in: f64, rate_out: f64) -> usize {
    if n_in == 0 {
        return 0;
    }
    // The small epsilon keeps an output instant that falls exactly on the last input step.
    ((n_in - 1) as f64 * rate_out / rate_in + 1e-9).floor() as usize + 1
}

/// First output step at or after the time of input step `m`, within `0..n_out` (the epsilon
/// keeps an instant that falls exactly on `m`'s time from moving a step on by rounding).
pub fn map_step(m: usize, rate_in: f64, rate_out: f64, n_out: usize) -> usize {
    ((m as f64 * rate_out / rate_in - 1e-9).ceil().max(0.0) as usize).min(n_out.saturating_sub(1))
}

/// Last input step at or before the time of output step `k`, within `0..n_in`.
pub fn source_step(k: usize, rate_in: f64, rate_out: f64, n_in: usize) -> usize {
    ((k as f64 * rate_in / rate_out + 1e-9).floor() as usize).min(n_in.saturating_sub(1))
}

fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-12 {
        1.0
    } else {
        let px = std::f64::consts::PI * x;
        px.sin() / px
    }
}

/// Blackman window on `u` in [−1, 1] (0 outside).
fn blackman(u: f64) -> f64 {
    if u.abs() >= 1.0 {
        return 0.0;
    }
    let a = std::f64::consts::PI * (u + 1.0);
    0.42 - 0.5 * a.cos() + 0.08 * (2.0 * a).cos()
}

/// One series from `rate_in` to `rate_out` (the method in the module docs).
pub fn resample_series(x: &[f32], rate_in: f64, rate_out: f64) -> Vec<f32> {
    let n_out = output_len(x.len(), rate_in, rate_out);
    let fc = ROLL_OFF * rate_in.min(rate_out) / 2.0;
    // Kernel half-width in seconds, and in input steps.
    let half_s = HALF_WIDTH / (2.0 * fc);
    let half_n = (half_s * rate_in).ceil() as i64;
    let last = x.len() as i64 - 1;
    (0..n_out)
        .map(|k| {
            let t = k as f64 / rate_out;
            let centre = (t * rate_in).floor() as i64;
            let (mut acc, mut norm) = (0.0f64, 0.0f64);
            for n in centre - half_n..=centre + half_n + 1 {
                let tau = t - n as f64 / rate_in;
                let w = sinc(2.0 * fc * tau) * blackman(tau / half_s);
                acc += w * x[n.clamp(0, last) as usize] as f64;
                norm += w;
            }
            (acc / norm) as f32
        })
        .collect()
}

/// `trial` at `rate_hz`: every channel resampled, marks, drop step, slip onset and step
/// labels moved to the new time base by time; the source rate is kept in the metadata key
/// `resampled_from_hz`.
pub fn to_rate(trial: &Trial, rate_hz: f32) -> Result<Trial, ResampleError> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(ResampleError::BadRate(rate_hz));
    }
    trial.validate().map_err(ResampleError::BadTrial)?;
    let n_in = trial.n_steps();
    if n_in == 0 {
        return Err(ResampleError::BadTrial("it has no steps".into()));
    }
    let (r_in, r_out) = (trial.rate_hz as f64, rate_hz as f64);
    let n_out = output_len(n_in, r_in, r_out);
    let map = |m: Option<usize>| m.map(|m| map_step(m, r_in, r_out, n_out));
    let mut out = trial.clone();
    out.rate_hz = rate_hz;
    out.samples = trial
        .samples
        .iter()
        .map(|c| resample_series(c, r_in, r_out))
        .collect();
    out.marks.grasp_start = map(trial.marks.grasp_start);
    out.marks.lift_start = map(trial.marks.lift_start);
    out.marks.open_start = map(trial.marks.open_start);
    out.marks.release = map(trial.marks.release);
    out.drop_step = map(trial.drop_step);
    out.slip_onset_step = map(trial.slip_onset_step);
    out.step_labels = trial.step_labels.as_ref().map(|l| {
        (0..n_out)
            .map(|k| l[source_step(k, r_in, r_out, n_in)])
            .collect()
    });
    out.extra
        .insert("resampled_from_hz".into(), trial.rate_hz.to_string());
    out.validate().map_err(ResampleError::BadTrial)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trial::{Outcome, Stability, Unit};

    /// The real trials' rate as the trials state it (`Trial::rate_hz`).
    const PAPER: f64 = slipguard_core::sample::PAPER_RATE_HZ as f64;

    fn sine(rate: f64, n: usize, f: f64, amp: f64, offset: f64) -> Vec<f32> {
        (0..n)
            .map(|k| {
                (offset + amp * (2.0 * std::f64::consts::PI * f * k as f64 / rate).sin()) as f32
            })
            .collect()
    }

    /// Largest error against the analytically sampled sine, away from the ends by the kernel.
    fn interior_error(y: &[f32], want: &[f32], rate_out: f64) -> f64 {
        let margin = (HALF_WIDTH / (ROLL_OFF * PAPER) * rate_out).ceil() as usize + 1;
        y[margin..y.len() - margin]
            .iter()
            .zip(&want[margin..])
            .map(|(a, b)| (a - b).abs() as f64)
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_sine_below_nyquist_matches_the_sine_sampled_at_the_new_rate() {
        // 400 steps at 16.7 Hz (an eagle-shoal trial's length), sines up to 5 Hz (the source's
        // Nyquist is 8.3 Hz), 2 000 mN around a 3 000 mN baseline.
        for f in [0.5, 2.0, 5.0] {
            let x = sine(PAPER, 400, f, 2000.0, 3000.0);
            let y = resample_series(&x, PAPER, 40.0);
            assert_eq!(
                y.len(),
                956,
                "399 steps at 16.7 Hz = 23.89 s → steps 0..=955 at 40 Hz"
            );
            let want = sine(40.0, y.len(), f, 2000.0, 3000.0);
            let err = interior_error(&y, &want, 40.0);
            // Measured: 0.04 mN at 0.5 Hz, 0.008 at 2 Hz, 0.17 at 5 Hz (of 2 000 mN).
            assert!(err < 0.4, "{f} Hz: max error {err} mN");
        }
    }

    #[test]
    fn above_the_cut_off_nothing_passes_when_the_rate_goes_down() {
        // 12 Hz at 40 Hz cannot be held at 16.7 Hz (Nyquist 8.3 Hz): it must not alias to 4.7 Hz.
        let x = sine(40.0, 960, 12.0, 1000.0, 0.0);
        let y = resample_series(&x, 40.0, PAPER);
        // Measured: 1.1 (0.1 %).
        let margin = 12;
        let peak = y[margin..y.len() - margin]
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            peak < 2.0,
            "12 Hz through a 16.7 Hz resampling: {peak} of 1000"
        );
    }

    #[test]
    fn a_constant_stays_constant_to_the_ends() {
        let y = resample_series(&[1234.0; 50], PAPER, 40.0);
        assert!(y.iter().all(|v| (v - 1234.0).abs() < 1e-2), "{y:?}");
    }

    #[test]
    fn marks_and_labels_keep_their_seconds() {
        let n = 400;
        let mut t = Trial::new(
            "t",
            Unit::MilliNewton,
            PAPER as f32,
            vec![vec![0.0; n], vec![5.0; n]],
        );
        t.marks.grasp_start = Some(30);
        t.marks.lift_start = Some(61);
        t.marks.open_start = Some(250);
        t.drop_step = Some(121);
        t.outcome = Outcome::Failure;
        t.contact = vec![false, true];
        t.step_labels = Some(
            (0..n)
                .map(|s| {
                    (s >= 30).then_some(if s >= 101 {
                        Stability::Unstable
                    } else {
                        Stability::Stable
                    })
                })
                .collect(),
        );
        let r = to_rate(&t, 40.0).expect("resamples");
        assert_eq!(r.rate_hz, 40.0);
        assert_eq!(r.n_steps(), 956);
        assert_eq!(r.contact, t.contact);
        let secs = |s: usize, rate: f64| s as f64 / rate;
        for (a, b) in [
            (t.marks.grasp_start, r.marks.grasp_start),
            (t.marks.lift_start, r.marks.lift_start),
            (t.marks.open_start, r.marks.open_start),
            (t.drop_step, r.drop_step),
        ] {
            let (a, b) = (a.unwrap(), b.unwrap());
            let late = secs(b, 40.0) - secs(a, PAPER);
            assert!(
                (0.0..1.0 / 40.0).contains(&late),
                "step {a} at 16.7 Hz ({} s) became {b} at 40 Hz ({} s)",
                secs(a, PAPER),
                secs(b, 40.0)
            );
        }
        // Step 30 = 1.796 s = step 71.86 at 40 Hz → 72; drop 121 = 7.246 s = 289.8 → 290:
        // the first 40 Hz steps at or after them.
        assert_eq!(r.marks.grasp_start, Some(72));
        assert_eq!(r.drop_step, Some(290));
        // Each output step takes the label of the last input step at or before it,
        // floor(k · 16.7 / 40): labelled from k = 72 (input 30.06 → 30, with the grasp mark),
        // unstable from k = 242 (input 101.04 → 101; k = 241 is input 100.6 → 100).
        let l = r.step_labels.as_ref().unwrap();
        assert_eq!(l.iter().position(Option::is_some), Some(72));
        assert_eq!(
            l.iter().position(|s| *s == Some(Stability::Unstable)),
            Some(242)
        );
        assert_eq!(
            r.extra.get("resampled_from_hz").map(String::as_str),
            Some("16.7")
        );
    }

    #[test]
    fn bad_rates_and_trials_are_refused() {
        let t = Trial::new("t", Unit::MilliNewton, 16.7, vec![vec![1.0; 10]]);
        assert_eq!(to_rate(&t, 0.0), Err(ResampleError::BadRate(0.0)));
        assert!(matches!(
            to_rate(&t, f32::NAN),
            Err(ResampleError::BadRate(_))
        ));
        let mut bad = t.clone();
        bad.drop_step = Some(10);
        assert!(matches!(
            to_rate(&bad, 40.0),
            Err(ResampleError::BadTrial(_))
        ));
    }
}
