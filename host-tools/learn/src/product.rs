//! The bit-exact core over a whole trial as the firmware runs it: every channel through
//! contact detection and, while in contact, the model (`Model::step_in_contact`), and the
//! hand-level decision over the channels (`HandConfig`), fused with the blob's hand rule when
//! it carries one (format v2, `FusedHand`, as `slipguard_app::app` runs it), from the grasp
//! start (the firmware resets at the controller's grasp-start command) to the end of the
//! trial. Then the grasp's armed window for [`crate::armed`].

use rayon::prelude::*;
use slipguard_batch::BatchModel;
use slipguard_core::decision::{
    ContactConfig, ContactEdge, DecisionState, FusedHand, HandConfig, LoadRule, LoadRuleState,
};
use slipguard_core::model::{ChannelState, GatedOutput, HandState, Model};
use slipguard_core::sample::InputScale;

use slipguard_data::armed::ArmedGrasp;
use slipguard_data::labels::{LabelConfig, detect_release};
use slipguard_data::trial::{Outcome, Trial};

/// What the firmware's decision stage produced on every step of a trial.
#[derive(Debug, Clone, PartialEq)]
pub struct HandRun {
    /// First step run (the grasp start); steps before it have no contact and no flag.
    pub start: usize,
    /// Per step: the hand's p(unstable), Q0.15.
    pub hand_p: Vec<i16>,
    /// Per step: the hand flag the firmware sends: [`Self::model_flag`], fused with the blob's
    /// hand rule when it has one ([`Self::rule`]).
    pub hand_flag: Vec<bool>,
    /// Per step: the model's own hand flag (the hand p through threshold and hysteresis).
    pub model_flag: Vec<bool>,
    /// Per step: the hand load Σ |x| (Q1.15) of the channels in contact
    /// ([`LoadRule::hand_load`]), the rule's input.
    pub hand_load: Vec<i32>,
    /// The blob's hand rule (format v2), fused into [`Self::hand_flag`]; `None` for a v1 blob.
    pub rule: Option<FusedHand>,
    /// Per channel and step: p(unstable) while in contact, else `None`.
    pub channel_p: Vec<Vec<Option<i16>>>,
    /// Per channel and step: the channel's own flag (down without contact).
    pub channel_flag: Vec<Vec<bool>>,
}

impl HandRun {
    /// Channels that were in contact at some step.
    pub fn contact_channels(&self) -> Vec<usize> {
        (0..self.channel_p.len())
            .filter(|&c| self.channel_p[c].iter().any(Option::is_some))
            .collect()
    }

    /// The hand flag for other decision settings, from the stored hand p (the hand's p does
    /// not depend on threshold or hysteresis) and, with a rule, the stored hand load: what an
    /// operating-curve sweep needs.
    pub fn hand_flag_with(&self, hand: &HandConfig) -> Vec<bool> {
        let mut s = DecisionState::default();
        let mut fuse = Fuse::new(self.rule);
        self.hand_p
            .iter()
            .zip(&self.hand_load)
            .enumerate()
            .map(|(t, (&p, &load))| {
                t >= self.start && fuse.update(hand.decision.update(&mut s, p), load)
            })
            .collect()
    }

    /// Stores one step's hand decision: the model's flag, the load and the fused flag.
    fn record(&mut self, t: usize, model_flag: bool, load: i32, fuse: &mut Fuse) {
        self.model_flag[t] = model_flag;
        self.hand_load[t] = load;
        self.hand_flag[t] = fuse.update(model_flag, load);
    }
}

/// The firmware's fusion of the hand flag with the blob's rule (`slipguard_app::app`): the
/// model's flag as it is without a rule.
struct Fuse {
    rule: Option<FusedHand>,
    state: LoadRuleState,
}

impl Fuse {
    fn new(rule: Option<FusedHand>) -> Self {
        Self {
            rule,
            state: LoadRuleState::new(),
        }
    }

    fn update(&mut self, model_flag: bool, load: i32) -> bool {
        match &self.rule {
            Some(r) => r.update(&mut self.state, model_flag, load),
            None => model_flag,
        }
    }
}

/// The hand load of one step: Σ |x| (Q1.15 in the model's scale) of the channels in contact,
/// from the raw samples the model stepped on.
fn step_load(scale: &InputScale, raw: &[i32], in_contact: impl Fn(usize) -> bool) -> i32 {
    LoadRule::hand_load(
        raw.iter()
            .enumerate()
            .map(|(c, &r)| in_contact(c).then(|| scale.to_q15(r))),
    )
}

/// Runs `model` over every channel of `trial` from its grasp start (step 0 without a mark).
/// Sample values are rounded to whole sensor units, as the firmware's front end delivers them.
///
/// The trial's channels step together through the batched core
/// ([`slipguard_batch`], bit-exact with [`Model::step_in_contact`]); a model the batch
/// cannot take (a RAM image) runs channel by channel ([`run_trial_single`], the same numbers).
pub fn run_trial(
    model: &Model<'_>,
    trial: &Trial,
    contact: &ContactConfig,
    hand: &HandConfig,
) -> HandRun {
    if model.is_hand() {
        return run_trial_hand(model, trial, contact, hand);
    }
    match BatchModel::new(model) {
        Ok(batch) => run_trial_batched(&batch, trial, contact, hand),
        Err(_) => run_trial_single(model, trial, contact, hand),
    }
}

/// Whether the controller's lift command has come by step `t` (the trial's lift mark): a
/// hand-level model's input, as the firmware gets it from the lift command.
pub fn lifted_at(trial: &Trial, t: usize) -> bool {
    trial.marks.lift_start.is_some_and(|l| t >= l)
}

/// [`run_trial`] for a hand-level model (`hand-lstm`), as the firmware runs it
/// (`slipguard_app::app`): every channel through its contact gate, one network over the
/// channels in contact with the lift command at the trial's lift mark, the hand decision on its
/// p, fused with the blob's rule. Every contact channel carries the hand's p and flag.
pub fn run_trial_hand(
    model: &Model<'_>,
    trial: &Trial,
    contact: &ContactConfig,
    hand: &HandConfig,
) -> HandRun {
    let mut run = empty_run(trial, model.config().hand_rule);
    let mut fuse = Fuse::new(run.rule);
    let nc = trial.n_channels();
    let mut states = vec![ChannelState::new(); nc];
    let mut hs = HandState::new();
    let mut hand_state = DecisionState::default();
    let mut raw = vec![0i32; nc];
    let mut x = vec![None; nc];
    for t in run.start..trial.n_steps() {
        for c in 0..nc {
            raw[c] = trial.samples[c][t].round() as i32;
            let (edge, v) = model.gate(&mut states[c], contact, raw[c]);
            x[c] = edge.in_contact().then_some(v);
        }
        let p = model.hand_p(&mut hs, &x, lifted_at(trial, t));
        let flag = hand.decision.update(&mut hand_state, p);
        for (c, xc) in x.iter().enumerate() {
            run.channel_p[c][t] = xc.map(|_| p);
            run.channel_flag[c][t] = xc.is_some() && flag;
        }
        run.hand_p[t] = p;
        let load = step_load(model.scale(), &raw, |c| x[c].is_some());
        run.record(t, flag, load, &mut fuse);
    }
    run
}

/// A run with no step yet: `start` and the buffers of `trial`'s length and channels.
fn empty_run(trial: &Trial, rule: Option<FusedHand>) -> HandRun {
    let n = trial.n_steps();
    let nc = trial.n_channels();
    HandRun {
        start: trial.marks.grasp_start.unwrap_or(0).min(n),
        hand_p: vec![0; n],
        hand_flag: vec![false; n],
        model_flag: vec![false; n],
        hand_load: vec![0; n],
        rule,
        channel_p: vec![vec![None; n]; nc],
        channel_flag: vec![vec![false; n]; nc],
    }
}

/// [`run_trial`] with the channels as the lanes of one batch.
pub fn run_trial_batched(
    batch: &BatchModel<'_>,
    trial: &Trial,
    contact: &ContactConfig,
    hand: &HandConfig,
) -> HandRun {
    let model = batch.model();
    let mut run = empty_run(trial, model.config().hand_rule);
    let mut fuse = Fuse::new(run.rule);
    let scale = *model.scale();
    let nc = trial.n_channels();
    let mut states = batch.state(nc);
    let mut hand_state = DecisionState::default();
    let idle = GatedOutput {
        contact: ContactEdge::Idle,
        step: None,
    };
    let (mut raw, mut out) = (vec![0i32; nc], vec![idle; nc]);
    for t in run.start..trial.n_steps() {
        for (c, r) in raw.iter_mut().enumerate() {
            *r = trial.samples[c][t].round() as i32;
        }
        batch.step_in_contact(&mut states, contact, &raw, None, &mut out);
        for (c, o) in out.iter().enumerate() {
            run.channel_p[c][t] = o.step.map(|s| s.p_unstable_q15);
            run.channel_flag[c][t] = o.step.is_some_and(|s| s.unstable);
        }
        let h = hand.update(
            &mut hand_state,
            out.iter().map(|o| o.step.map(|s| s.p_unstable_q15)),
        );
        run.hand_p[t] = h.p_unstable_q15;
        let load = step_load(&scale, &raw, |c| out[c].step.is_some());
        run.record(t, h.unstable, load, &mut fuse);
    }
    run
}

/// [`run_trial`] one channel at a time through [`Model::step_in_contact`] (the firmware's
/// order): the reference of the batched run.
pub fn run_trial_single(
    model: &Model<'_>,
    trial: &Trial,
    contact: &ContactConfig,
    hand: &HandConfig,
) -> HandRun {
    let mut run = empty_run(trial, model.config().hand_rule);
    let mut fuse = Fuse::new(run.rule);
    let nc = trial.n_channels();
    let mut states = vec![ChannelState::new(); nc];
    let mut hand_state = DecisionState::default();
    let mut p_now = vec![None; nc];
    let mut raw = vec![0i32; nc];
    for t in run.start..trial.n_steps() {
        for c in 0..nc {
            raw[c] = trial.samples[c][t].round() as i32;
            let out = model.step_in_contact(&mut states[c], contact, raw[c]);
            p_now[c] = out.step.map(|s| s.p_unstable_q15);
            run.channel_p[c][t] = p_now[c];
            run.channel_flag[c][t] = out.step.is_some_and(|s| s.unstable);
        }
        let h = hand.update(&mut hand_state, p_now.iter().copied());
        run.hand_p[t] = h.p_unstable_q15;
        let load = step_load(model.scale(), &raw, |c| p_now[c].is_some());
        run.record(t, h.unstable, load, &mut fuse);
    }
    run
}

/// Why a trial cannot be scored in its armed window.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum ArmedError {
    /// The trial has no lift mark (the armed window starts at the lift command).
    NoLiftMark {
        /// Trial id.
        trial: String,
    },
    /// A failure without a drop step (not labelled: `slipguard label` finds none).
    NoDrop {
        /// Trial id.
        trial: String,
    },
    /// The outcome is unknown.
    UnknownOutcome {
        /// Trial id.
        trial: String,
    },
    /// No channel ever in contact: nothing a hand controller would act on.
    NoContact {
        /// Trial id.
        trial: String,
    },
    /// A failure whose drop comes at or before its lift mark (an estimated lift mark can be
    /// late): the armed window would be empty.
    DropBeforeLift {
        /// Trial id.
        trial: String,
        /// Drop step.
        drop: usize,
        /// Lift mark.
        lift: usize,
    },
}

impl ArmedError {
    /// The trial it names.
    pub fn trial(&self) -> &str {
        match self {
            ArmedError::NoLiftMark { trial }
            | ArmedError::NoDrop { trial }
            | ArmedError::UnknownOutcome { trial }
            | ArmedError::NoContact { trial }
            | ArmedError::DropBeforeLift { trial, .. } => trial,
        }
    }
}

impl std::fmt::Display for ArmedError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ArmedError::NoLiftMark { trial } => write!(
                f,
                "{trial}: no lift mark (lift_start): the armed window starts at the lift command; \
                 record with the lift command sent, or add `# lift_start: STEP` to the recording"
            ),
            ArmedError::NoDrop { trial } => {
                write!(
                    f,
                    "{trial}: a failure with no drop found in its force (see docs/labels.md)"
                )
            }
            ArmedError::UnknownOutcome { trial } => write!(
                f,
                "{trial}: outcome unknown: set `# outcome: success|failure` in the recording"
            ),
            ArmedError::NoContact { trial } => write!(
                f,
                "{trial}: no channel in contact (no load of the contact threshold): not a grasp \
                 to score"
            ),
            ArmedError::DropBeforeLift { trial, drop, lift } => write!(
                f,
                "{trial}: the drop (step {drop}) comes at or before the lift mark (step {lift}): \
                 no armed window; check the marks"
            ),
        }
    }
}

impl std::error::Error for ArmedError {}

/// The armed window `[start, end)` of an annotated trial: lift start to the release start
/// (success; the trial's end if the grip holds to it) or to the drop (failure). `Ok(None)`
/// for a trial without contact (nothing a hand controller would act on).
pub fn armed_window(
    trial: &Trial,
    cfg: &LabelConfig,
) -> Result<Option<(usize, usize)>, ArmedError> {
    let id = || trial.id.clone();
    if !trial.contact.iter().any(|&c| c) {
        return Ok(None);
    }
    let lift = trial
        .marks
        .lift_start
        .ok_or_else(|| ArmedError::NoLiftMark { trial: id() })?;
    let end = match trial.outcome {
        Outcome::Failure => {
            let drop = trial
                .drop_step
                .ok_or_else(|| ArmedError::NoDrop { trial: id() })?;
            if drop <= lift {
                return Err(ArmedError::DropBeforeLift {
                    trial: id(),
                    drop,
                    lift,
                });
            }
            drop
        }
        Outcome::Success => detect_release(trial, cfg).unwrap_or(trial.n_steps()),
        Outcome::Unknown => return Err(ArmedError::UnknownOutcome { trial: id() }),
    };
    Ok(Some((lift.min(end), end)))
}

/// The trials that can be scored in their armed window, and those skipped with the reason:
/// a trial without contact, a failure with no drop in its force or whose drop comes before its
/// lift mark, and a trial without a lift mark while another trial with contact has one, are
/// skipped (named, not refusing the data set); without any lift mark, or with an unknown
/// outcome, the first such trial is the error.
pub fn scoreable<'t>(
    trials: &[&'t Trial],
    cfg: &LabelConfig,
) -> Result<(Vec<&'t Trial>, Vec<ArmedError>), ArmedError> {
    let any_lift = trials
        .iter()
        .any(|t| t.contact.iter().any(|&c| c) && t.marks.lift_start.is_some());
    let (mut keep, mut skipped) = (Vec::new(), Vec::new());
    for &t in trials {
        match armed_window(t, cfg) {
            Ok(Some(_)) => keep.push(t),
            Ok(None) => skipped.push(ArmedError::NoContact {
                trial: t.id.clone(),
            }),
            Err(e @ (ArmedError::NoDrop { .. } | ArmedError::DropBeforeLift { .. })) => {
                skipped.push(e)
            }
            Err(e @ ArmedError::NoLiftMark { .. }) if any_lift => skipped.push(e),
            Err(e) => return Err(e),
        }
    }
    Ok((keep, skipped))
}

/// The grasp scored on its hand flag, and each contact channel scored on its own flag.
#[derive(Debug, Clone, PartialEq)]
pub struct ScoredGrasp {
    /// Hand level.
    pub hand: ArmedGrasp,
    /// Per contact channel (the comparison the hand-level decision is measured against).
    pub channels: Vec<ArmedGrasp>,
}

/// Scores one run in the trial's armed window (`Ok(None)` for a trial without contact).
pub fn score(
    trial: &Trial,
    run: &HandRun,
    cfg: &LabelConfig,
) -> Result<Option<ScoredGrasp>, ArmedError> {
    let Some((start, end)) = armed_window(trial, cfg)? else {
        return Ok(None);
    };
    let grasp = |flags: Vec<bool>| ArmedGrasp {
        trial: trial.id.clone(),
        failure: trial.outcome == Outcome::Failure,
        start,
        end,
        flags,
        step_ms: 1000.0 / trial.rate_hz as f64,
    };
    Ok(Some(ScoredGrasp {
        hand: grasp(run.hand_flag.clone()),
        // The labelled contact channels (docs/labels.md), as the per-channel paper metrics.
        channels: (0..run.channel_flag.len())
            .filter(|&c| trial.contact.get(c) == Some(&true))
            .map(|c| grasp(run.channel_flag[c].clone()))
            .collect(),
    }))
}

/// Where the firmware's model state starts on a channel: its contact onsets by the core's
/// rule ([`ContactConfig`]) on the model's input scale. Training sequences start at the first
/// onset and end where that contact ends, so that they start where the firmware's state does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnsetRule {
    /// The model's input scaling (raw → Q1.15).
    pub scale: slipguard_core::sample::InputScale,
    /// The contact rule on that scale.
    pub contact: ContactConfig,
}

impl OnsetRule {
    /// The rule of a model with these header settings.
    pub fn of(config: &slipguard_core::blob::ModelConfig) -> Self {
        Self {
            scale: slipguard_core::sample::InputScale::of(config),
            contact: ContactConfig::of(config),
        }
    }

    /// The first contact of `samples` (raw sensor units, from the grasp start): its onset
    /// step and the step at which it ends (exclusive; `samples.len()` if it lasts).
    pub fn first_contact(&self, samples: &[f32]) -> Option<(usize, usize)> {
        use slipguard_core::decision::{ContactEdge, ContactState};
        let mut s = ContactState::new();
        let mut onset = None;
        for (t, &x) in samples.iter().enumerate() {
            let q = self.scale.to_q15(x.round() as i32);
            match (self.contact.update(&mut s, q), onset) {
                (ContactEdge::Began, None) => onset = Some(t),
                (ContactEdge::Ended, Some(on)) => return Some((on, t)),
                _ => {}
            }
        }
        onset.map(|on| (on, samples.len()))
    }
}

/// One point of the operating curve: detection against false-alarm grasps for one decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurvePoint {
    /// Threshold on the hand's p(unstable), 0…1.
    pub threshold: f64,
    /// Consecutive steps at or above it before the hand flag rises.
    pub raise_after: u8,
    /// Detected failures / failures.
    pub detected_rate: f64,
    /// Successes with a false alarm / successes.
    pub false_alarm_grasp_rate: f64,
    /// Median lead of the detected failures, ms (0 with none).
    pub lead_median_ms: f64,
    /// Failures detected at least 300 ms ahead.
    pub detected_300ms: usize,
    /// Failures scored.
    pub failures: usize,
    /// Successes with a false alarm.
    pub false_alarm_grasps: usize,
    /// Successes scored.
    pub successes: usize,
}

impl CurvePoint {
    /// The point of a decision (`threshold`, `raise_after`) from the grasps it flagged.
    pub fn of(threshold: f64, raise_after: u8, grasps: &[ArmedGrasp]) -> Self {
        let m = slipguard_data::armed::ArmedMetrics::of(grasps);
        CurvePoint {
            threshold,
            raise_after,
            detected_rate: m.detected_rate().unwrap_or(0.0),
            false_alarm_grasp_rate: m.false_alarm_grasp_rate().unwrap_or(0.0),
            lead_median_ms: m.lead_median_ms().unwrap_or(0.0),
            detected_300ms: m.detected_early(),
            failures: m.failures,
            false_alarm_grasps: m.false_alarm_grasps,
            successes: m.successes,
        }
    }
}

/// The frontier of `curve` for a grip controller's two numbers: for each count `k` of failures
/// warned at least 300 ms ahead (from 1 to the most any point reaches), the index of the point
/// with at least `k` and the fewest false-alarm grasps (ties: more failures detected, then the
/// longer median lead, then the first in curve order). Picked on the grasps it scores, so an
/// upper bound on what any decision of the swept family, picked elsewhere, reaches on them.
pub fn frontier_300ms(curve: &[CurvePoint]) -> Vec<(usize, usize)> {
    let most = curve.iter().map(|p| p.detected_300ms).max().unwrap_or(0);
    (1..=most)
        .filter_map(|k| {
            curve
                .iter()
                .enumerate()
                .filter(|(_, p)| p.detected_300ms >= k)
                .min_by(|(_, a), (_, b)| {
                    a.false_alarm_grasps
                        .cmp(&b.false_alarm_grasps)
                        .then(b.detected_rate.total_cmp(&a.detected_rate))
                        .then(b.lead_median_ms.total_cmp(&a.lead_median_ms))
                })
                .map(|(i, _)| (k, i))
        })
        .collect()
}

/// A scored run kept for decision sweeps: the run and its armed window.
#[derive(Debug, Clone)]
pub struct WindowedRun {
    /// Trial id.
    pub trial: String,
    /// Failure or success.
    pub failure: bool,
    /// Armed window `[start, end)`.
    pub window: (usize, usize),
    /// Step duration, ms.
    pub step_ms: f64,
    /// The run.
    pub run: HandRun,
}

impl WindowedRun {
    /// The grasp scored with the hand flag of `hand` (recomputed from the stored hand p).
    pub fn grasp_with(&self, hand: &HandConfig) -> ArmedGrasp {
        ArmedGrasp {
            trial: self.trial.clone(),
            failure: self.failure,
            start: self.window.0,
            end: self.window.1,
            flags: self.run.hand_flag_with(hand),
            step_ms: self.step_ms,
        }
    }
}

/// Runs `model` over the trials with contact and keeps each run with its armed window, the
/// trials in parallel (rayon; the runs in the trials' order, the same for any thread count).
pub fn windowed_runs(
    model: &Model<'_>,
    trials: &[&Trial],
    cfg: &LabelConfig,
) -> Result<Vec<WindowedRun>, ArmedError> {
    let contact = ContactConfig::of(model.config());
    let hand = HandConfig::of(model.config());
    let batch = BatchModel::new(model).ok();
    // Collected in order, so that the first trial in error is the one reported.
    let runs: Vec<Result<Option<WindowedRun>, ArmedError>> = trials
        .par_iter()
        .map(|t| {
            let window = match armed_window(t, cfg) {
                Ok(Some(w)) => w,
                // Nothing to score: no contact, or a drop before the lift mark.
                Ok(None) | Err(ArmedError::DropBeforeLift { .. }) => return Ok(None),
                Err(e) => return Err(e),
            };
            let run = match &batch {
                Some(b) => run_trial_batched(b, t, &contact, &hand),
                None => run_trial(model, t, &contact, &hand),
            };
            Ok(Some(WindowedRun {
                trial: t.id.clone(),
                failure: t.outcome == Outcome::Failure,
                window,
                step_ms: 1000.0 / t.rate_hz as f64,
                run,
            }))
        })
        .collect();
    runs.into_iter().filter_map(Result::transpose).collect()
}

/// `base` with the hand decision's threshold on p(unstable) (0…1, stored as the header's Q0.15
/// threshold) and its raise_after (at least 1) replaced: one point of a decision sweep.
pub fn with_decision(base: &HandConfig, threshold: f64, raise_after: u8) -> HandConfig {
    let mut h = *base;
    h.decision.threshold_q15 =
        slipguard_core::decision::Q15::from_f64(threshold).header_threshold() as i16;
    h.decision.raise_after = raise_after.max(1);
    h
}

/// The operating curve over `thresholds` × `raise_after` (the hand's clear_after and k kept).
pub fn operating_curve(
    runs: &[WindowedRun],
    base: &HandConfig,
    thresholds: &[f64],
    raise_after: &[u8],
) -> Vec<CurvePoint> {
    let mut out = Vec::new();
    for &r in raise_after {
        for &th in thresholds {
            let h = with_decision(base, th, r);
            let grasps: Vec<ArmedGrasp> = runs.iter().map(|w| w.grasp_with(&h)).collect();
            out.push(CurvePoint::of(th, r, &grasps));
        }
    }
    out
}

/// Picks the decision on validation runs. Validation sets are small (a fold's validation
/// trials hold one or two failures), so the pick maximises a balanced score rather than a hard
/// bound: the share of failures detected at least 300 ms ahead minus the share of successes
/// with a false alarm; points over `max_false_alarm_rate` lose a further penalty of their
/// excess; ties go to fewer false-alarm grasps, then to the threshold nearest 0.5.
pub fn pick_decision(curve: &[CurvePoint], max_false_alarm_rate: f64) -> Option<CurvePoint> {
    let score = |p: &CurvePoint| pick_score(p, max_false_alarm_rate);
    curve
        .iter()
        .max_by(|a, b| {
            score(a)
                .total_cmp(&score(b))
                .then(b.false_alarm_grasps.cmp(&a.false_alarm_grasps))
                .then(
                    (b.threshold - 0.5)
                        .abs()
                        .total_cmp(&(a.threshold - 0.5).abs()),
                )
        })
        .copied()
}

/// The score [`pick_decision`] maximises: share of failures detected ≥ 300 ms ahead − share of
/// successes with a false alarm − the excess of that share over `max_false_alarm_rate`.
pub fn pick_score(p: &CurvePoint, max_false_alarm_rate: f64) -> f64 {
    let det = if p.failures > 0 {
        p.detected_300ms as f64 / p.failures as f64
    } else {
        0.0
    };
    det - p.false_alarm_grasp_rate - (p.false_alarm_grasp_rate - max_false_alarm_rate).max(0.0)
}

/// Cuts labelled sequences (which start at the grasp start) to where the firmware's model
/// state starts: each keeps the steps from its first contact onset ([`OnsetRule`]) to where
/// that contact ends. A sequence without contact, or whose contact begins only at or after
/// the drop, is dropped. Applied to every training source (real, simulated, closed loop) and
/// to the sequences the paper's metrics are computed on.
pub fn cut_to_contact(
    seqs: Vec<crate::evaluation::Sequence>,
    rule: &OnsetRule,
) -> Vec<crate::evaluation::Sequence> {
    seqs.into_iter()
        .filter_map(|mut s| {
            let (on, off) = rule.first_contact(&s.cs.samples)?;
            if s.cs.drop_index.is_some_and(|d| on >= d) || off <= on {
                return None;
            }
            s.cs.samples = s.cs.samples[on..off].to_vec();
            s.cs.labels = s.cs.labels[on..off.min(s.cs.labels.len())].to_vec();
            s.cs.drop_index = s.cs.drop_index.map(|d| d - on);
            s.lift = s.lift.map(|l| l.saturating_sub(on));
            Some(s)
        })
        .collect()
}

/// Thresholds of the operating curve and of the decision sweep.
pub const CURVE_THRESHOLDS: [f64; 19] = [
    0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85,
    0.9, 0.95,
];
/// raise_after values of the operating curve and of the decision sweep.
pub const CURVE_RAISE_AFTER: [u8; 4] = [1, 2, 3, 4];

/// 95 % bootstrap interval of one of the paper's metrics, resampling whole trials (a trial's
/// channel sequences stay together), [`slipguard_data::armed::BOOTSTRAP_RESAMPLES`] times with
/// a fixed seed.
pub fn bootstrap_paper(
    seqs: &[&crate::evaluation::Sequence],
    preds: &[Vec<slipguard_data::trial::Stability>],
    seed: u64,
    stat: impl Fn(&slipguard_data::metrics::Metrics) -> Option<f64>,
) -> Option<slipguard_data::armed::Interval> {
    use rand::{Rng, SeedableRng};
    let mut ids: Vec<&str> = seqs.iter().map(|s| s.cs.trial_id.as_str()).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.is_empty() {
        return None;
    }
    let by_trial: Vec<Vec<usize>> = ids
        .iter()
        .map(|t| {
            (0..seqs.len())
                .filter(|&i| seqs[i].cs.trial_id == *t)
                .collect()
        })
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut values = Vec::new();
    for _ in 0..slipguard_data::armed::BOOTSTRAP_RESAMPLES {
        let mut s = Vec::new();
        let mut p = Vec::new();
        for _ in 0..ids.len() {
            for &i in &by_trial[rng.random_range(0..by_trial.len())] {
                s.push(seqs[i]);
                p.push(preds[i].clone());
            }
        }
        if let Some(v) = stat(&crate::evaluation::metrics_of(&s, &p)) {
            values.push(v);
        }
    }
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(slipguard_data::armed::Interval {
        lo: slipguard_data::metrics::quantile(&values, 0.025),
        hi: slipguard_data::metrics::quantile(&values, 0.975),
    })
}

/// The sequences the paper's metrics are computed on, from recorded 16.7 Hz force trials, as
/// the firmware's model state sees them: labelled with the paper's durations, from each
/// channel's contact onset by the 16.7 Hz force models' rule.
pub fn sequences_from_contact(trials: &[Trial]) -> Vec<crate::evaluation::Sequence> {
    let rule = OnsetRule::of(&crate::evaluation::force_config(
        slipguard_core::blob::Variant::Lstm,
        false,
        1,
        "",
        slipguard_core::sample::PAPER_RATE_MHZ,
    ));
    cut_to_contact(
        crate::evaluation::sequences_of(trials, &LabelConfig::default()),
        &rule,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use slipguard_data::trial::Unit;

    fn point(d300: usize, fa: usize, det: usize, lead: f64) -> CurvePoint {
        CurvePoint {
            threshold: 0.5,
            raise_after: 1,
            detected_rate: det as f64 / 7.0,
            false_alarm_grasp_rate: fa as f64 / 16.0,
            lead_median_ms: lead,
            detected_300ms: d300,
            failures: 7,
            false_alarm_grasps: fa,
            successes: 16,
        }
    }

    #[test]
    fn the_frontier_takes_the_fewest_false_alarms_at_each_count_of_early_warnings() {
        let curve = [
            point(6, 4, 7, 900.0), // 0
            point(4, 1, 7, 400.0), // 1
            point(6, 3, 6, 700.0), // 2
            point(2, 0, 3, 800.0), // 3
            point(5, 3, 7, 650.0), // 4: ties 2 at k = 5 on false alarms, detects more
            point(6, 3, 6, 800.0), // 5: ties 2 at k = 6 on both, longer lead
        ];
        let f = frontier_300ms(&curve);
        // k = 1, 2: point 3 (0 false alarms); 3, 4: point 1; 5: point 4 (3, more detected);
        // 6: point 5 (3, the longer lead); nothing reaches 7.
        assert_eq!(f, vec![(1, 3), (2, 3), (3, 1), (4, 1), (5, 4), (6, 5)]);
        assert!(frontier_300ms(&[]).is_empty());
    }

    fn trial(id: &str, outcome: Outcome, lift: Option<usize>, drop: Option<usize>) -> Trial {
        let mut t = Trial::new(id, Unit::MilliNewton, 16.7, vec![vec![1000.0; 40]]);
        t.outcome = outcome;
        t.marks.lift_start = lift;
        t.drop_step = drop;
        t
    }

    #[test]
    fn unscoreable_trials_are_skipped_and_named() {
        let cfg = LabelConfig::default();
        let ok_f = trial("f", Outcome::Failure, Some(5), Some(30));
        let ok_s = trial("s", Outcome::Success, Some(5), None);
        let no_drop = trial("nodrop", Outcome::Failure, Some(5), None);
        let no_lift = trial("nolift", Outcome::Success, None, None);
        let early = trial("early", Outcome::Failure, Some(25), Some(20));
        let mut none = trial("none", Outcome::Success, Some(5), None);
        none.contact = vec![false];
        let all = [&ok_f, &ok_s, &no_drop, &no_lift, &early, &none];
        let (keep, skipped) = scoreable(&all, &cfg).unwrap();
        let kept: Vec<&str> = keep.iter().map(|t| t.id.as_str()).collect();
        assert_eq!(kept, ["f", "s"]);
        assert_eq!(
            skipped,
            [
                ArmedError::NoDrop {
                    trial: "nodrop".into()
                },
                ArmedError::NoLiftMark {
                    trial: "nolift".into()
                },
                ArmedError::DropBeforeLift {
                    trial: "early".into(),
                    drop: 20,
                    lift: 25
                },
                ArmedError::NoContact {
                    trial: "none".into()
                }
            ]
        );
        assert!(skipped[2].to_string().contains("before the lift mark"));
        assert!(skipped[0].to_string().starts_with("nodrop: "));
        // Without any lift mark the data set cannot be scored: the first trial is the error.
        let a = trial("a", Outcome::Success, None, None);
        let b = trial("b", Outcome::Failure, None, Some(20));
        assert_eq!(
            scoreable(&[&a, &b], &cfg).unwrap_err(),
            ArmedError::NoLiftMark { trial: "a".into() }
        );
        // An unknown outcome stays an error.
        let u = trial("u", Outcome::Unknown, Some(5), None);
        assert!(matches!(
            scoreable(&[&ok_f, &u], &cfg),
            Err(ArmedError::UnknownOutcome { .. })
        ));
    }
}
