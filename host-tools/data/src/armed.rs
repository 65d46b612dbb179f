//! Product-mode metrics: what a grip controller sees. Per grasp, the detector is **armed** from
//! the lift start (the controller's lift command) to the release start (successes; detected
//! from the force, `labels::detect_release`) or to the drop (failures). Before the lift and
//! after the release nothing counts.
//!
//! * **detected**: a failure with a flag up at some step of its armed window (which ends at
//!   the drop, so the flag came before the drop).
//! * **lead**: drop − first flagged step of the armed window, in ms.
//! * **false-alarm grasp**: a success with a flag up at some step of its armed window.
//! * **false alarms per minute**: rising edges of the flag in the armed windows of successes
//!   (a flag already up when the window opens counts as one) per minute of their armed time.
//!
//! The same metrics serve the hand-level flag (one flag per grasp) and the per-channel flags
//! (each contact channel scored as a grasp of its own). Every rate comes with a 95 %
//! bootstrap interval over trials ([`bootstrap`]): the real data have 7 failure trials.

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::metrics::quantile;

/// The lead a warning needs to give the controller time to tighten the grip: 0.3 s.
pub const EARLY_LEAD_MS: f64 = 300.0;
/// A lead this close below a threshold counts as reaching it: leads are whole frames, and 5
/// frames at 16.7 Hz (299.4 ms) are the 0.3 s the product is judged by.
pub const LEAD_TOLERANCE_MS: f64 = 1.0;

/// One grasp (or one channel of a grasp) scored in its armed window.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmedGrasp {
    /// Trial the grasp comes from (bootstrap resamples trials, not channels).
    pub trial: String,
    /// The object was dropped.
    pub failure: bool,
    /// First armed step (the lift start), index into `flags`.
    pub start: usize,
    /// End of the armed window, exclusive: the release start (success) or the drop (failure).
    pub end: usize,
    /// The flag at every step of the trial.
    pub flags: Vec<bool>,
    /// Duration of one step in ms.
    pub step_ms: f64,
}

impl ArmedGrasp {
    fn window(&self) -> &[bool] {
        let end = self.end.min(self.flags.len());
        &self.flags[self.start.min(end)..end]
    }

    /// First flagged step of the armed window (absolute index).
    pub fn first_flag(&self) -> Option<usize> {
        self.window()
            .iter()
            .position(|&f| f)
            .map(|i| i + self.start)
    }

    /// Rising edges in the armed window (a flag up at the window's start counts).
    pub fn alarms(&self) -> usize {
        let w = self.window();
        (0..w.len())
            .filter(|&i| w[i] && (i == 0 || !w[i - 1]))
            .count()
    }

    /// Armed time in minutes.
    pub fn armed_minutes(&self) -> f64 {
        self.window().len() as f64 * self.step_ms / 60_000.0
    }

    /// Lead of a detected failure, ms.
    pub fn lead_ms(&self) -> Option<f64> {
        if !self.failure {
            return None;
        }
        self.first_flag()
            .map(|f| (self.end - f) as f64 * self.step_ms)
    }
}

/// The armed-window figures of a set of grasps.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ArmedMetrics {
    /// Grasps scored.
    pub grasps: usize,
    /// Of which failures.
    pub failures: usize,
    /// Failures detected in their armed window.
    pub detected: usize,
    /// Leads of the detected failures, ms.
    pub leads_ms: Vec<f64>,
    /// Successes.
    pub successes: usize,
    /// Successes with a flag in their armed window.
    pub false_alarm_grasps: usize,
    /// Rising edges in the armed windows of successes.
    pub false_alarms: usize,
    /// Armed minutes of the successes.
    pub success_armed_minutes: f64,
}

impl ArmedMetrics {
    /// Scores `grasps`.
    pub fn of<'a>(grasps: impl IntoIterator<Item = &'a ArmedGrasp>) -> Self {
        let mut m = ArmedMetrics::default();
        for g in grasps {
            m.grasps += 1;
            if g.failure {
                m.failures += 1;
                if let Some(l) = g.lead_ms() {
                    m.detected += 1;
                    m.leads_ms.push(l);
                }
            } else {
                m.successes += 1;
                let a = g.alarms();
                m.false_alarms += a;
                m.false_alarm_grasps += (a > 0) as usize;
                m.success_armed_minutes += g.armed_minutes();
            }
        }
        m
    }

    /// Detected failures / failures (0…1), `None` without failures.
    pub fn detected_rate(&self) -> Option<f64> {
        ratio(self.detected, self.failures)
    }

    /// Successes with a false alarm / successes (0…1), `None` without successes.
    pub fn false_alarm_grasp_rate(&self) -> Option<f64> {
        ratio(self.false_alarm_grasps, self.successes)
    }

    /// False alarms per minute of armed time of the successes.
    pub fn false_alarms_per_min(&self) -> Option<f64> {
        (self.success_armed_minutes > 0.0)
            .then(|| self.false_alarms as f64 / self.success_armed_minutes)
    }

    /// Median lead of the detected failures, ms.
    pub fn lead_median_ms(&self) -> Option<f64> {
        if self.leads_ms.is_empty() {
            return None;
        }
        let mut v = self.leads_ms.clone();
        v.sort_by(f64::total_cmp);
        Some(quantile(&v, 0.5))
    }

    /// Failures detected with a lead of at least `ms`, counting a lead within
    /// [`LEAD_TOLERANCE_MS`] of it as reaching it (leads are whole frames: 5 frames at 16.7 Hz
    /// are 299.4 ms, which counts as 0.3 s).
    pub fn detected_with_lead(&self, ms: f64) -> usize {
        self.leads_ms
            .iter()
            .filter(|&&l| l >= ms - LEAD_TOLERANCE_MS)
            .count()
    }

    /// Failures warned at least [`EARLY_LEAD_MS`] ahead (the product's early-warning count).
    pub fn detected_early(&self) -> usize {
        self.detected_with_lead(EARLY_LEAD_MS)
    }
}

fn ratio(a: usize, b: usize) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

/// A 95 % interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// 2.5 % quantile.
    pub lo: f64,
    /// 97.5 % quantile.
    pub hi: f64,
}

/// Resamples per bootstrap interval.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// 95 % percentile-bootstrap interval of `stat` over `grasps`, resampling whole trials with
/// replacement (a trial's channels stay together), [`BOOTSTRAP_RESAMPLES`] times with a fixed
/// seed so that reports are reproducible. Resamples where `stat` is undefined (e.g. no
/// failure drawn) are skipped; `None` if all are.
pub fn bootstrap(
    grasps: &[ArmedGrasp],
    seed: u64,
    stat: impl Fn(&ArmedMetrics) -> Option<f64>,
) -> Option<Interval> {
    let mut trials: Vec<&str> = grasps.iter().map(|g| g.trial.as_str()).collect();
    trials.sort_unstable();
    trials.dedup();
    if trials.is_empty() {
        return None;
    }
    let by_trial: Vec<Vec<&ArmedGrasp>> = trials
        .iter()
        .map(|t| grasps.iter().filter(|g| g.trial == *t).collect())
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut values = Vec::with_capacity(BOOTSTRAP_RESAMPLES);
    for _ in 0..BOOTSTRAP_RESAMPLES {
        let draw = (0..trials.len()).flat_map(|_| {
            let i = rng.random_range(0..by_trial.len());
            by_trial[i].iter().copied()
        });
        let m = ArmedMetrics::of(draw.collect::<Vec<_>>());
        if let Some(v) = stat(&m) {
            values.push(v);
        }
    }
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(Interval {
        lo: quantile(&values, 0.025),
        hi: quantile(&values, 0.975),
    })
}

/// A paired difference between two detectors on the same grasps: `b`'s figure minus `a`'s,
/// its point value and its 95 % percentile-bootstrap interval, resampling whole trials with
/// replacement and taking each drawn trial's grasps from both detectors (the pairing).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairedDifference {
    /// `stat(b) − stat(a)` on the grasps as they are.
    pub value: f64,
    /// 95 % interval over [`BOOTSTRAP_RESAMPLES`] resamples; `None` when `stat` is undefined
    /// on every resample.
    pub ci: Option<Interval>,
}

/// [`PairedDifference`] of `stat` between detector `a` and detector `b` over the same trials
/// (`a` and `b` hold one grasp per trial each, matched by trial id; trials in only one of them
/// are left out). Seeded, so reports are reproducible.
pub fn paired_difference(
    a: &[ArmedGrasp],
    b: &[ArmedGrasp],
    seed: u64,
    stat: impl Fn(&ArmedMetrics) -> f64,
) -> PairedDifference {
    let pairs: Vec<(&ArmedGrasp, &ArmedGrasp)> = a
        .iter()
        .filter_map(|ga| b.iter().find(|gb| gb.trial == ga.trial).map(|gb| (ga, gb)))
        .collect();
    let diff = |draw: &[(&ArmedGrasp, &ArmedGrasp)]| {
        let ma = ArmedMetrics::of(draw.iter().map(|p| p.0));
        let mb = ArmedMetrics::of(draw.iter().map(|p| p.1));
        stat(&mb) - stat(&ma)
    };
    let value = diff(&pairs);
    if pairs.is_empty() {
        return PairedDifference { value, ci: None };
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut values: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| {
            let draw: Vec<(&ArmedGrasp, &ArmedGrasp)> = (0..pairs.len())
                .map(|_| pairs[rng.random_range(0..pairs.len())])
                .collect();
            diff(&draw)
        })
        .filter(|v| v.is_finite())
        .collect();
    if values.is_empty() {
        return PairedDifference { value, ci: None };
    }
    values.sort_by(f64::total_cmp);
    PairedDifference {
        value,
        ci: Some(Interval {
            lo: quantile(&values, 0.025),
            hi: quantile(&values, 0.975),
        }),
    }
}

/// The armed-window figures with their intervals, as `slipguard eval --json` writes them.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmedReport {
    /// Point figures.
    pub metrics: ArmedMetrics,
    /// 95 % interval of the detected rate.
    pub detected_rate_ci: Option<Interval>,
    /// 95 % interval of the false-alarm grasp rate.
    pub false_alarm_grasp_rate_ci: Option<Interval>,
    /// 95 % interval of the false alarms per minute.
    pub false_alarms_per_min_ci: Option<Interval>,
    /// 95 % interval of the median lead.
    pub lead_median_ms_ci: Option<Interval>,
}

impl ArmedReport {
    /// Scores `grasps` and bootstraps the intervals (seed fixed per figure).
    pub fn of(grasps: &[ArmedGrasp]) -> Self {
        Self {
            metrics: ArmedMetrics::of(grasps),
            detected_rate_ci: bootstrap(grasps, 1, ArmedMetrics::detected_rate),
            false_alarm_grasp_rate_ci: bootstrap(grasps, 2, ArmedMetrics::false_alarm_grasp_rate),
            false_alarms_per_min_ci: bootstrap(grasps, 3, ArmedMetrics::false_alarms_per_min),
            lead_median_ms_ci: bootstrap(grasps, 4, ArmedMetrics::lead_median_ms),
        }
    }

    /// One line: detected (with lead), false-alarm grasps and rate, each with its interval.
    pub fn summary(&self) -> String {
        let m = &self.metrics;
        let ci = |i: Option<Interval>, pct: bool| {
            i.map_or(String::new(), |i| {
                if pct {
                    format!(" [{:.0}–{:.0} %]", 100.0 * i.lo, 100.0 * i.hi)
                } else {
                    format!(" [{:.0}–{:.0}]", i.lo, i.hi)
                }
            })
        };
        format!(
            "detected {}/{}{} (≥ 300 ms ahead: {}), lead median {}{}; false-alarm grasps {}/{}{}, {:.2} false alarms per armed minute{}",
            m.detected,
            m.failures,
            ci(self.detected_rate_ci, true),
            m.detected_early(),
            m.lead_median_ms()
                .map_or("-".into(), |l| format!("{l:.0} ms")),
            ci(self.lead_median_ms_ci, false),
            m.false_alarm_grasps,
            m.successes,
            ci(self.false_alarm_grasp_rate_ci, true),
            m.false_alarms_per_min().unwrap_or(0.0),
            self.false_alarms_per_min_ci
                .map_or(String::new(), |i| format!(" [{:.2}–{:.2}]", i.lo, i.hi)),
        )
    }

    /// The figures as JSON under `prefix` (`armed.detected_rate`, … and `…_ci: [lo, hi]`).
    pub fn to_json(&self, prefix: &str) -> serde_json::Map<String, serde_json::Value> {
        use serde_json::{Value, json};
        let m = &self.metrics;
        let ci = |i: Option<Interval>| i.map_or(Value::Null, |i| json!([i.lo, i.hi]));
        let opt = |v: Option<f64>| v.map_or(Value::Null, |v| json!(v));
        let mut o = serde_json::Map::new();
        let mut put = |k: &str, v: Value| {
            o.insert(format!("{prefix}.{k}"), v);
        };
        put("grasps", json!(m.grasps));
        put("failures", json!(m.failures));
        put("successes", json!(m.successes));
        put("detected", json!(m.detected));
        put("detected_rate", opt(m.detected_rate()));
        put("detected_rate_ci", ci(self.detected_rate_ci));
        put("lead_median_ms", opt(m.lead_median_ms()));
        put("lead_median_ms_ci", ci(self.lead_median_ms_ci));
        put("leads_ms", json!(m.leads_ms));
        put("false_alarm_grasps", json!(m.false_alarm_grasps));
        put("false_alarm_grasp_rate", opt(m.false_alarm_grasp_rate()));
        put(
            "false_alarm_grasp_rate_ci",
            ci(self.false_alarm_grasp_rate_ci),
        );
        put("false_alarms", json!(m.false_alarms));
        put("armed_minutes_successes", json!(m.success_armed_minutes));
        put("false_alarms_per_min", opt(m.false_alarms_per_min()));
        put("false_alarms_per_min_ci", ci(self.false_alarms_per_min_ci));
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn g(trial: &str, failure: bool, start: usize, end: usize, up: &[usize]) -> ArmedGrasp {
        let mut flags = vec![false; 40];
        for &i in up {
            flags[i] = true;
        }
        ArmedGrasp {
            trial: trial.into(),
            failure,
            start,
            end,
            flags,
            step_ms: 60.0,
        }
    }

    #[test]
    fn only_the_armed_window_counts() {
        // Failure armed 10..30 (drop at 30): flags at 5 (before the lift) and 31 (after the
        // drop) do not count; the flag at 22 does, 8 steps = 480 ms ahead.
        let f = g("a", true, 10, 30, &[5, 22, 23, 31]);
        assert_eq!(f.first_flag(), Some(22));
        assert_eq!(f.lead_ms(), Some(480.0));
        let missed = g("b", true, 10, 30, &[5, 30, 31]);
        assert_eq!(missed.lead_ms(), None);
        // Success armed 10..30: closing (3) and release (35) flags are outside; two alarms
        // inside, one of them already up at the window's start.
        let s = g("c", false, 10, 30, &[3, 9, 10, 11, 20, 35]);
        assert_eq!(s.alarms(), 2);
        let quiet = g("d", false, 10, 30, &[3, 35]);
        let m = ArmedMetrics::of([&f, &missed, &s, &quiet]);
        assert_eq!((m.grasps, m.failures, m.detected), (4, 2, 1));
        assert_eq!(m.detected_rate(), Some(0.5));
        assert_eq!((m.false_alarm_grasps, m.false_alarms), (1, 2));
        assert_eq!(m.false_alarm_grasp_rate(), Some(0.5));
        // 2 alarms in 2 × 20 steps × 60 ms = 2.4 s = 0.04 min → 50 per minute.
        assert!((m.false_alarms_per_min().unwrap() - 50.0).abs() < 1e-9);
        assert_eq!(m.lead_median_ms(), Some(480.0));
    }

    #[test]
    fn bootstrap_brackets_the_point_and_resamples_trials() {
        // 10 failure trials, 7 detected: the interval holds 0.7 and is wide.
        let grasps: Vec<ArmedGrasp> = (0..10)
            .map(|i| {
                let up: &[usize] = if i < 7 { &[20] } else { &[] };
                g(&format!("t{i}"), true, 10, 30, up)
            })
            .collect();
        let ci = bootstrap(&grasps, 1, ArmedMetrics::detected_rate).unwrap();
        assert!(ci.lo < 0.7 && ci.hi > 0.7, "{ci:?}");
        assert!(ci.lo > 0.3 && ci.hi <= 1.0, "{ci:?}");
        // All detected: the interval collapses to the point.
        let all: Vec<ArmedGrasp> = (0..5)
            .map(|i| g(&format!("t{i}"), true, 10, 30, &[20]))
            .collect();
        let ci = bootstrap(&all, 1, ArmedMetrics::detected_rate).unwrap();
        assert_eq!((ci.lo, ci.hi), (1.0, 1.0));
        // Undefined everywhere (no successes): no interval.
        assert_eq!(
            bootstrap(&all, 1, ArmedMetrics::false_alarm_grasp_rate),
            None
        );
    }
}
