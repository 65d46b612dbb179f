//! Labelling as in the paper (section III-A), made configurable.
//!
//! * **Contact**: a channel touches the object if its deviation from its
//!   pre-grasp baseline reaches `contact_threshold` for `contact_min_run`
//!   consecutive steps inside the contact window. Channels that never do are
//!   *marked* (`contact = false`) and get no per-channel labels.
//! * **Drop step**: between lift start (`l1`) and open start (`l2`), the first
//!   step at which the summed deviation of the contact channels falls below
//!   `drop_fraction` of its maximum in that window and *stays* below for
//!   `drop_hold_steps` steps (the paper: "the item will drop when the force is
//!   at 0"). The hold requirement skips brief dips (Cheez_100_814_top_3 dips at
//!   100 but loses the object at 121).
//! * **Labels**: the sequence is `sequence_len` (160) steps from grasp start;
//!   success trials are stable throughout; in failures every step from
//!   `unstable_lead_steps` (20) before the drop on is unstable.
//!
//! All thresholds are in [`LabelConfig`]; docs/labels.md explains the choices.

use crate::trial::{Outcome, Stability, Trial, Unit};

/// Thresholds of contact detection, drop detection and labelling.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelConfig {
    /// Contact threshold for force channels, mN above baseline.
    pub contact_threshold_mn: f32,
    /// Contact threshold for pressure channels, counts away from baseline.
    pub contact_threshold_counts: f32,
    /// Consecutive steps at or above the threshold needed to call it contact.
    pub contact_min_run: usize,
    /// Drop when the contact sum falls below this fraction of its lift-window peak.
    pub drop_fraction: f32,
    /// ... and stays below it for this many steps (clipped at the trial end).
    pub drop_hold_steps: usize,
    /// A lift-window peak below this (mN) means nothing was held: no drop is detected.
    pub min_peak_mn: f32,
    /// Same for pressure channels, in counts.
    pub min_peak_counts: f32,
    /// Steps before the drop from which every step is unstable (paper: 20 = 1.2 s).
    pub unstable_lead_steps: usize,
    /// Sequence length from grasp start (paper: 160).
    pub sequence_len: usize,
}

impl Default for LabelConfig {
    fn default() -> Self {
        LabelConfig {
            contact_threshold_mn: 500.0,
            contact_threshold_counts: 1500.0,
            contact_min_run: 3,
            drop_fraction: 0.05,
            drop_hold_steps: 10,
            min_peak_mn: 1000.0,
            min_peak_counts: 3000.0,
            unstable_lead_steps: 20,
            sequence_len: 160,
        }
    }
}

impl LabelConfig {
    pub fn contact_threshold(&self, unit: &Unit) -> f32 {
        match unit {
            Unit::Counts => self.contact_threshold_counts,
            _ => self.contact_threshold_mn,
        }
    }

    pub fn min_peak(&self, unit: &Unit) -> f32 {
        match unit {
            Unit::Counts => self.min_peak_counts,
            _ => self.min_peak_mn,
        }
    }

    /// The defaults are in steps at the paper's 16.7 Hz; this keeps their
    /// *durations* at another rate (lead 1.2 s, sequence 9.58 s, hold 0.6 s,
    /// contact run 0.18 s).
    pub fn scaled_to(&self, rate_hz: f32) -> Self {
        let k = rate_hz / crate::eagle::EAGLE_RATE_HZ;
        let sc = |s: usize| ((s as f32 * k).round() as usize).max(1);
        LabelConfig {
            unstable_lead_steps: sc(self.unstable_lead_steps),
            sequence_len: sc(self.sequence_len),
            drop_hold_steps: sc(self.drop_hold_steps),
            contact_min_run: sc(self.contact_min_run),
            ..self.clone()
        }
    }

    pub fn check(&self) -> Result<(), String> {
        if !(0.0..1.0).contains(&self.drop_fraction) {
            return Err(format!(
                "drop_fraction {} not in [0, 1)",
                self.drop_fraction
            ));
        }
        if self.sequence_len == 0 || self.contact_min_run == 0 || self.drop_hold_steps == 0 {
            return Err("sequence_len, contact_min_run and drop_hold_steps must be > 0".into());
        }
        Ok(())
    }
}

/// Per-channel baseline: the median of the steps before grasp start (at least
/// 5 of them), else of the first 10 steps; 0 for force channels whose median is
/// below 0 or unknown. A pressure channel (counts) recorded from the board is tared at
/// grasp start (the suction profile's `tare`): the pre-grasp steps are absolute pressure and
/// the grasp-start step is near 0, so its baseline is 0, the tare's zero (else a cup that
/// lets go, back at the tare's 0, would never count as a drop).
pub fn baselines(trial: &Trial) -> Vec<f32> {
    let n = trial.n_steps();
    let end = match trial.marks.grasp_start {
        Some(g) if g >= 5 => g,
        _ => n.min(10),
    };
    trial
        .samples
        .iter()
        .map(|c| {
            if end == 0 {
                return 0.0;
            }
            let mut v: Vec<f32> = c[..end].to_vec();
            v.sort_by(f32::total_cmp);
            let median = v[v.len() / 2];
            match trial.marks.grasp_start.and_then(|g| c.get(g)) {
                Some(&at_grasp)
                    if trial.unit == Unit::Counts && at_grasp.abs() < TARE_SHARE * median.abs() =>
                {
                    0.0
                }
                _ => median,
            }
        })
        .collect()
}

/// A pressure channel whose grasp-start value is below this share of its pre-grasp median
/// (in magnitude) was tared there ([`baselines`]).
pub const TARE_SHARE: f32 = 0.1;

/// Absolute deviation of every sample from its channel's baseline.
pub fn deviations(trial: &Trial) -> Vec<Vec<f32>> {
    let base = baselines(trial);
    trial
        .samples
        .iter()
        .zip(base)
        .map(|(c, b)| c.iter().map(|&x| (x - b).abs()).collect())
        .collect()
}

/// Contact flags over `[start, end)`: deviation ≥ threshold for `contact_min_run`
/// consecutive steps.
pub fn detect_contact(trial: &Trial, start: usize, end: usize, cfg: &LabelConfig) -> Vec<bool> {
    let dev = deviations(trial);
    contact_from_dev(
        &dev,
        start,
        end,
        cfg.contact_threshold(&trial.unit),
        cfg.contact_min_run,
    )
}

fn contact_from_dev(dev: &[Vec<f32>], start: usize, end: usize, thr: f32, run: usize) -> Vec<bool> {
    dev.iter()
        .map(|c| {
            let end = end.min(c.len());
            let mut r = 0;
            for &x in c.get(start..end).unwrap_or(&[]) {
                r = if x >= thr { r + 1 } else { 0 };
                if r >= run {
                    return true;
                }
            }
            false
        })
        .collect()
}

/// Result of the drop search, with the numbers it was based on.
#[derive(Debug, Clone, PartialEq)]
pub struct DropDetection {
    /// First step of the lasting collapse, if any.
    pub step: Option<usize>,
    /// First step below the threshold at all (may be a brief dip).
    pub first_dip: Option<usize>,
    /// Channels whose sum was watched.
    pub channels: Vec<usize>,
    /// Peak of the contact sum in the search window.
    pub peak: f32,
    /// `drop_fraction * peak`.
    pub threshold: f32,
    /// Search window `[start, end)`.
    pub window: (usize, usize),
}

/// Find the drop step (see the module docs). Works on any unit: it watches the
/// deviation from baseline of the channels in contact during grasp and lift.
pub fn detect_drop(trial: &Trial, cfg: &LabelConfig) -> DropDetection {
    let n = trial.n_steps();
    let g = trial.marks.grasp_start.unwrap_or(0).min(n);
    let start = trial.marks.lift_start.unwrap_or(g).min(n);
    // The lift window ends at the third mark, else at the controller's release.
    let end = trial
        .marks
        .open_start
        .or(trial.marks.release)
        .unwrap_or(n)
        .min(n)
        .max(start);
    let dev = deviations(trial);
    let contact = contact_from_dev(
        &dev,
        g,
        end,
        cfg.contact_threshold(&trial.unit),
        cfg.contact_min_run,
    );
    let channels: Vec<usize> = (0..contact.len()).filter(|&c| contact[c]).collect();
    let sum: Vec<f32> = (0..n)
        .map(|t| channels.iter().map(|&c| dev[c][t]).sum())
        .collect();
    let peak = sum[start..end].iter().copied().fold(0.0f32, f32::max);
    let threshold = cfg.drop_fraction * peak;
    let mut out = DropDetection {
        step: None,
        first_dip: None,
        channels,
        peak,
        threshold,
        window: (start, end),
    };
    if peak < cfg.min_peak(&trial.unit) {
        return out;
    }
    // Only look for a drop after the contact sum has been above threshold in the window.
    let mut armed = false;
    for s in start..end {
        if sum[s] >= threshold {
            armed = true;
            continue;
        }
        if !armed {
            continue;
        }
        out.first_dip.get_or_insert(s);
        let hold_end = (s + cfg.drop_hold_steps).min(n);
        if sum[s..hold_end].iter().all(|&x| x < threshold) {
            out.step = Some(s);
            break;
        }
    }
    out
}

/// Release search. The hold level is the median of the contact channels' summed deviation
/// over the loaded steps (sum ≥ the contact threshold) of the first [`RELEASE_LEVEL_SECONDS`]
/// after the lift start. The hand has let go at the first step, after the sum has reached
/// the level's [`RELEASE_HIGH`] share, where it falls below [`RELEASE_GONE`] of the level and
/// stays there for [`RELEASE_HOLD_SECONDS`]; the release starts right after the last step
/// before that at or above [`RELEASE_HIGH`] of the level (the start of the final decline).
/// On the 16 real successes with contact it lands 94–143 steps after the lift start, where
/// the force curves show the hand opening (docs/labels.md).
pub const RELEASE_GONE: f32 = 0.1;
/// Share of the hold level the final decline starts from.
pub const RELEASE_HIGH: f32 = 0.8;
/// How long the contact sum must stay gone to call it a release, seconds (5 steps at 16.7 Hz).
pub const RELEASE_HOLD_SECONDS: f32 = 0.3;
/// Span after the lift start over which the hold level is measured, seconds (100 steps).
pub const RELEASE_LEVEL_SECONDS: f32 = 6.0;

/// Release start (see [`RELEASE_GONE`]): `None` without a lift mark, without contact or when
/// the grip holds to the end of the trial.
pub fn detect_release(trial: &Trial, cfg: &LabelConfig) -> Option<usize> {
    let n = trial.n_steps();
    let lift = trial.marks.lift_start?;
    if lift >= n {
        return None;
    }
    let g = trial.marks.grasp_start.unwrap_or(0).min(lift);
    let level_end = (lift + (RELEASE_LEVEL_SECONDS * trial.rate_hz).round() as usize).min(n);
    let thr = cfg.contact_threshold(&trial.unit);
    let dev = deviations(trial);
    let contact = contact_from_dev(&dev, g, level_end, thr, cfg.contact_min_run);
    let channels: Vec<usize> = (0..contact.len()).filter(|&c| contact[c]).collect();
    let sum: Vec<f32> = (0..n)
        .map(|t| channels.iter().map(|&c| dev[c][t]).sum())
        .collect();
    let mut loaded: Vec<f32> = sum[lift..level_end]
        .iter()
        .copied()
        .filter(|&x| x >= thr)
        .collect();
    if loaded.is_empty() {
        return None;
    }
    loaded.sort_by(f32::total_cmp);
    let level = loaded[loaded.len() / 2];
    let (gone, high) = (RELEASE_GONE * level, RELEASE_HIGH * level);
    let run = ((RELEASE_HOLD_SECONDS * trial.rate_hz).round() as usize).max(1);
    let held = (lift..n).find(|&s| sum[s] >= high)?;
    let let_go =
        (held..n.saturating_sub(run - 1)).find(|&s| sum[s..s + run].iter().all(|&x| x < gone))?;
    let decline = (held..let_go)
        .rev()
        .find(|&t| sum[t] >= high)
        .unwrap_or(held);
    Some(decline + 1)
}

/// Fill `trial.drop_step` (failures and unknown outcomes, if not already set)
/// and `trial.contact` with the configured rules.
///
/// The contact window runs from grasp start to the drop for failures (so that
/// fingers pressing on each other after the object fell do not count), else
/// over the labelled sequence (or the rest of the trial if longer).
pub fn annotate(trial: &mut Trial, cfg: &LabelConfig) {
    if trial.drop_step.is_none() && trial.outcome != Outcome::Success {
        trial.drop_step = detect_drop(trial, cfg).step;
    }
    let n = trial.n_steps();
    let g = trial.marks.grasp_start.unwrap_or(0).min(n);
    let end = match (trial.outcome, trial.drop_step) {
        (Outcome::Success, _) | (_, None) => (g + cfg.sequence_len).min(n),
        (_, Some(d)) => d.max(g),
    };
    trial.contact = detect_contact(trial, g, end, cfg);
}

/// Why a trial got no labels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LabelStatus {
    Labelled,
    /// A failure in which no lasting drop was found.
    NoDrop,
    /// Outcome unknown.
    UnknownOutcome,
}

/// Labels of one trial: trial-level per step, plus which channels carry them.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialLabels {
    pub id: String,
    pub outcome: Outcome,
    pub status: LabelStatus,
    /// First step of the sequence (grasp start).
    pub seq_start: usize,
    /// Steps in the sequence (`sequence_len`, or fewer if the trial ends first).
    pub seq_len: usize,
    pub drop_step: Option<usize>,
    /// Absolute step from which every step is unstable.
    pub unstable_from: Option<usize>,
    /// One label per sequence step (empty unless `Labelled`).
    pub steps: Vec<Stability>,
    /// Per channel: carries labels (touches the object) or is excluded.
    pub contact: Vec<bool>,
}

impl TrialLabels {
    /// Labels for channel `c`, or `None` if the channel never touches the object.
    pub fn channel(&self, c: usize) -> Option<&[Stability]> {
        (self.status == LabelStatus::Labelled && self.contact.get(c) == Some(&true))
            .then_some(self.steps.as_slice())
    }

    pub fn n_unstable(&self) -> usize {
        self.steps.iter().filter(|s| s.is_unstable()).count()
    }

    pub fn n_stable(&self) -> usize {
        self.steps.len() - self.n_unstable()
    }

    /// Drop step relative to the sequence start, if inside the sequence.
    pub fn drop_index(&self) -> Option<usize> {
        self.drop_step
            .filter(|&d| d >= self.seq_start && d < self.seq_start + self.seq_len)
            .map(|d| d - self.seq_start)
    }
}

/// Label an annotated trial (call [`annotate`] first, or let [`label_trial`] do it).
pub fn label_annotated(trial: &Trial, cfg: &LabelConfig) -> TrialLabels {
    let n = trial.n_steps();
    let seq_start = trial.marks.grasp_start.unwrap_or(0).min(n);
    let seq_len = cfg.sequence_len.min(n - seq_start);
    let mut out = TrialLabels {
        id: trial.id.clone(),
        outcome: trial.outcome,
        status: LabelStatus::Labelled,
        seq_start,
        seq_len,
        drop_step: trial.drop_step,
        unstable_from: None,
        steps: Vec::new(),
        contact: trial.contact.clone(),
    };
    match (trial.outcome, trial.drop_step) {
        (Outcome::Success, _) => out.steps = vec![Stability::Stable; seq_len],
        (Outcome::Failure, Some(d)) => {
            let from = d.saturating_sub(cfg.unstable_lead_steps).max(seq_start);
            out.unstable_from = Some(from);
            out.steps = (seq_start..seq_start + seq_len)
                .map(|t| {
                    if t >= from {
                        Stability::Unstable
                    } else {
                        Stability::Stable
                    }
                })
                .collect();
        }
        (Outcome::Failure, None) => out.status = LabelStatus::NoDrop,
        (Outcome::Unknown, _) => out.status = LabelStatus::UnknownOutcome,
    }
    out
}

/// Annotate a copy of the trial and label it.
pub fn label_trial(trial: &Trial, cfg: &LabelConfig) -> TrialLabels {
    let mut t = trial.clone();
    annotate(&mut t, cfg);
    label_annotated(&t, cfg)
}

/// One channel's training sequence: samples and labels of the 160-step window.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSequence {
    pub trial_id: String,
    pub channel: usize,
    pub samples: Vec<f32>,
    pub labels: Vec<Stability>,
    /// Drop step relative to the sequence start.
    pub drop_index: Option<usize>,
    pub outcome: Outcome,
}

/// The per-channel sequences of a labelled trial (contact channels only).
pub fn channel_sequences(trial: &Trial, labels: &TrialLabels) -> Vec<ChannelSequence> {
    (0..trial.n_channels())
        .filter_map(|c| {
            let l = labels.channel(c)?;
            Some(ChannelSequence {
                trial_id: trial.id.clone(),
                channel: c,
                samples: trial.samples[c][labels.seq_start..labels.seq_start + labels.seq_len]
                    .to_vec(),
                labels: l.to_vec(),
                drop_index: labels.drop_index(),
                outcome: labels.outcome,
            })
        })
        .collect()
}

/// Label balance over many trials.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabelStats {
    pub trials: usize,
    pub labelled: usize,
    pub skipped: usize,
    pub failures_with_drop: usize,
    /// Trial-level steps.
    pub stable_steps: usize,
    pub unstable_steps: usize,
    /// Per-channel sequences (contact channels of labelled trials).
    pub channel_sequences: usize,
    pub excluded_channels: usize,
    pub channel_stable_steps: usize,
    pub channel_unstable_steps: usize,
}

impl LabelStats {
    pub fn from_labels(all: &[TrialLabels]) -> Self {
        let mut s = LabelStats {
            trials: all.len(),
            ..Default::default()
        };
        for l in all {
            if l.status != LabelStatus::Labelled {
                s.skipped += 1;
                continue;
            }
            s.labelled += 1;
            if l.outcome == Outcome::Failure {
                s.failures_with_drop += 1;
            }
            s.stable_steps += l.n_stable();
            s.unstable_steps += l.n_unstable();
            let nc = l.contact.iter().filter(|&&c| c).count();
            s.channel_sequences += nc;
            s.excluded_channels += l.contact.len() - nc;
            s.channel_stable_steps += nc * l.n_stable();
            s.channel_unstable_steps += nc * l.n_unstable();
        }
        s
    }

    /// Share of stable steps (trial level), in [0, 1].
    pub fn stable_share(&self) -> f64 {
        let t = self.stable_steps + self.unstable_steps;
        if t == 0 {
            0.0
        } else {
            self.stable_steps as f64 / t as f64
        }
    }

    /// Share of stable steps over the per-channel sequences, in [0, 1].
    pub fn channel_stable_share(&self) -> f64 {
        let t = self.channel_stable_steps + self.channel_unstable_steps;
        if t == 0 {
            0.0
        } else {
            self.channel_stable_steps as f64 / t as f64
        }
    }
}
