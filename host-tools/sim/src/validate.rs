//! Simulator validation against real trials: per-phase force levels, drop
//! dynamics, 0–8 Hz spectra. `slipguard simulate --validate` writes the report.

use std::fmt::Write as _;

use crate::dsp::{bin_hz, mean_diff_power};
use slipguard_data::labels::{LabelConfig, annotate};
use slipguard_data::metrics::{Spread, quantile};
use slipguard_data::trial::{Outcome, Trial};

/// STFT window of the paper (20 steps, rectangular).
pub const SPECTRUM_WIN: usize = 20;

/// Numbers measured on one trial (force trials with marks).
#[derive(Debug, Clone, PartialEq)]
pub struct TrialStats {
    pub id: String,
    pub outcome: Outcome,
    pub n_contact: usize,
    /// Steps from grasp start to the first contact step.
    pub contact_delay: Option<f64>,
    /// Median contact-sum over the 5 steps before lift start (mN).
    pub grasp_level: Option<f64>,
    /// Median contact-sum from lift start to the drop (failures) or to l2 (mN).
    pub lift_level: Option<f64>,
    /// Max contact-sum in the lift window / grasp level.
    pub lift_rise: Option<f64>,
    /// Failures: drop step − lift start.
    pub drop_after_lift: Option<f64>,
    /// Failures: steps from the last step at ≥ 80 % of the pre-drop level to the drop.
    pub fall_steps: Option<f64>,
    /// Share of idle-channel samples that read exactly 0.
    pub idle_zero_share: f64,
    /// 99th percentile of idle-channel samples (mN).
    pub idle_p99: f64,
    /// Share of rows identical to the previous row (during contact).
    pub repeat_share: f64,
    /// Relative power spectrum of the 1st difference (bins 1..=10), failure pre-drop window.
    pub spectrum_pre_drop: Option<Vec<f64>>,
    /// Same for a hold window (l1+5 .. l1+45) of successes.
    pub spectrum_hold: Option<Vec<f64>>,
}

fn median_of(v: &[f32]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s: Vec<f64> = v.iter().map(|&x| x as f64).collect();
    s.sort_by(f64::total_cmp);
    Some(quantile(&s, 0.5))
}

fn rel_spectrum(t: &Trial, chans: &[usize], start: usize, end: usize) -> Option<Vec<f64>> {
    let mut acc = vec![0.0; SPECTRUM_WIN / 2 + 1];
    let mut k = 0;
    for &c in chans {
        if let Some(p) = mean_diff_power(&t.samples[c], start, end, SPECTRUM_WIN) {
            let tot: f64 = p.iter().skip(1).sum();
            if tot > 0.0 {
                for (a, v) in acc.iter_mut().zip(&p) {
                    *a += v / tot;
                }
                k += 1;
            }
        }
    }
    (k > 0).then(|| {
        acc[0] = 0.0;
        acc.into_iter().map(|a| a / k as f64).collect()
    })
}

/// Measure one trial (annotating a copy with `cfg` for contact flags).
pub fn trial_stats(trial: &Trial, cfg: &LabelConfig) -> TrialStats {
    let mut t = trial.clone();
    annotate(&mut t, cfg);
    let chans = t.contact_channels();
    let n = t.n_steps();
    let s = t.sum_over(&chans);
    let l0 = t.marks.grasp_start.unwrap_or(0);
    let l1 = t.marks.lift_start.unwrap_or(l0);
    let l2 = t.marks.open_start.unwrap_or(n);
    let drop = t.drop_step.filter(|_| t.outcome == Outcome::Failure);
    let lift_end = drop.unwrap_or(l2).max(l1);
    let thr = cfg.contact_threshold(&t.unit);
    let first_contact = (l0..n).find(|&i| chans.iter().any(|&c| t.samples[c][i] >= thr));
    let grasp_level = median_of(&s[l1.saturating_sub(5)..l1]);
    let lift_level = median_of(&s[l1..lift_end]);
    let lift_max = s[l1..lift_end].iter().copied().fold(0.0f32, f32::max) as f64;
    let (mut fall, mut dal) = (None, None);
    if let Some(d) = drop {
        dal = Some(d as f64 - l1 as f64);
        if let Some(level) =
            median_of(&s[d.saturating_sub(10).max(l1)..d.saturating_sub(2).max(l1 + 1)])
        {
            let last_high = (l1..d).rev().find(|&i| s[i] as f64 >= 0.8 * level);
            fall = last_high.map(|i| (d - i) as f64);
        }
    }
    let idle: Vec<usize> = (0..t.n_channels()).filter(|c| !t.contact[*c]).collect();
    let mut idle_vals: Vec<f64> = idle
        .iter()
        .flat_map(|&c| t.samples[c][..lift_end.min(n)].iter().map(|&x| x as f64))
        .collect();
    idle_vals.sort_by(f64::total_cmp);
    let idle_zero_share = if idle_vals.is_empty() {
        0.0
    } else {
        idle_vals.iter().filter(|&&x| x == 0.0).count() as f64 / idle_vals.len() as f64
    };
    let idle_p99 = if idle_vals.is_empty() {
        0.0
    } else {
        quantile(&idle_vals, 0.99)
    };
    let rows: Vec<Vec<f32>> = (l0..lift_end).map(|i| t.row(i)).collect();
    let repeat_share = if rows.len() > 1 {
        rows.windows(2).filter(|w| w[0] == w[1]).count() as f64 / (rows.len() - 1) as f64
    } else {
        0.0
    };
    let spectrum_pre_drop = drop.and_then(|d| rel_spectrum(&t, &chans, d.saturating_sub(40), d));
    let spectrum_hold = (t.outcome == Outcome::Success)
        .then(|| rel_spectrum(&t, &chans, l1 + 5, l1 + 45))
        .flatten();
    TrialStats {
        id: t.id.clone(),
        outcome: t.outcome,
        n_contact: chans.len(),
        contact_delay: first_contact.map(|f| (f - l0) as f64),
        grasp_level,
        lift_level,
        lift_rise: grasp_level.filter(|&g| g > 0.0).map(|g| lift_max / g),
        drop_after_lift: dal,
        fall_steps: fall,
        idle_zero_share,
        idle_p99,
        repeat_share,
        spectrum_pre_drop,
        spectrum_hold,
    }
}

/// Mean of relative spectra.
pub fn mean_spectrum(v: &[&Vec<f64>]) -> Option<Vec<f64>> {
    let first = v.first()?;
    let mut acc = vec![0.0; first.len()];
    for s in v {
        for (a, x) in acc.iter_mut().zip(s.iter()) {
            *a += x;
        }
    }
    Some(acc.into_iter().map(|a| a / v.len() as f64).collect())
}

/// Share of a relative spectrum in 3–5 Hz (bins at 16.7 Hz, 20-step window).
pub fn band_3_5(spec: &[f64], rate_hz: f64) -> f64 {
    spec.iter()
        .enumerate()
        .filter(|(k, _)| {
            let f = bin_hz(*k, SPECTRUM_WIN, rate_hz);
            (3.0..=5.0).contains(&f)
        })
        .map(|(_, v)| v)
        .sum()
}

/// One compared quantity.
#[derive(Debug, Clone)]
pub struct Comparison {
    pub name: &'static str,
    pub unit: &'static str,
    pub real: Option<Spread>,
    pub sim: Option<Spread>,
}

impl Comparison {
    /// Does the simulated median fall inside the real interquartile range
    /// (widened by 10 % of the real median)?
    pub fn agrees(&self) -> Option<bool> {
        let (r, s) = (self.real?, self.sim?);
        let slack = 0.1 * r.median.abs();
        Some(s.median >= r.q25 - slack && s.median <= r.q75 + slack)
    }
}

/// Build the comparison table from real and simulated stats.
pub fn compare(real: &[TrialStats], sim: &[TrialStats]) -> Vec<Comparison> {
    type Getter = fn(&TrialStats) -> Option<f64>;
    let items: [(&'static str, &'static str, Getter); 10] = [
        ("contact channels", "", |s| {
            Some(s.n_contact as f64).filter(|&n| n > 0.0)
        }),
        ("first contact after grasp start", "steps", |s| {
            s.contact_delay
        }),
        ("grasp level (5 steps before lift)", "mN", |s| s.grasp_level),
        ("lift/hold level (lift start to drop or l2)", "mN", |s| {
            s.lift_level
        }),
        ("lift peak / grasp level", "x", |s| s.lift_rise),
        ("drop after lift start (failures)", "steps", |s| {
            s.drop_after_lift
        }),
        ("fall time 80 % -> drop (failures)", "steps", |s| {
            s.fall_steps
        }),
        ("idle samples reading 0", "share", |s| {
            Some(s.idle_zero_share)
        }),
        ("idle 99th percentile", "mN", |s| Some(s.idle_p99)),
        ("repeated rows", "share", |s| Some(s.repeat_share)),
    ];
    items
        .iter()
        .map(|(name, unit, f)| {
            let r: Vec<f64> = real.iter().filter_map(f).collect();
            let s: Vec<f64> = sim.iter().filter_map(f).collect();
            Comparison {
                name,
                unit,
                real: Spread::of(&r),
                sim: Spread::of(&s),
            }
        })
        .collect()
}

/// Render the comparison as Markdown rows.
pub fn comparison_table(rows: &[Comparison]) -> String {
    let mut s = String::new();
    s.push_str("| quantity | unit | real median [IQR] (n) | sim median [IQR] (n) | sim median within real IQR ±10 % |\n");
    s.push_str("|---|---|---|---|---|\n");
    let f = |sp: Option<Spread>| {
        sp.map_or("n/a".to_string(), |s| {
            format!("{} [{} – {}] ({})", g(s.median), g(s.q25), g(s.q75), s.n)
        })
    };
    for r in rows {
        let verdict = match r.agrees() {
            Some(true) => "yes",
            Some(false) => "**no**",
            None => "n/a",
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} |",
            r.name,
            r.unit,
            f(r.real),
            f(r.sim),
            verdict
        );
    }
    s
}

/// Compact number format.
pub fn g(x: f64) -> String {
    if x.abs() >= 100.0 {
        format!("{x:.0}")
    } else if x.abs() >= 1.0 {
        format!("{x:.2}")
    } else {
        format!("{x:.3}")
    }
}
