//! The hand-load rule as a baseline detector on recorded trials: the core's
//! [`slipguard_core::decision::LoadRule`] (hand flag while the summed load of the channels in
//! contact is below a fraction of its peak over the last frames) behind the core's contact gate,
//! from the grasp start, scored in the armed window exactly as the models are
//! ([`crate::product`], [`slipguard_data::armed`]). Its two parameters are picked on training
//! trials only, with the models' own criterion ([`crate::product::pick_decision`]): per fold of
//! a cross-validation on the fold's training trials ([`held_out_by_folds`]), or leave one trial
//! out ([`held_out_loto`]).

use slipguard_core::decision::{
    ContactConfig, ContactState, FusedHand, LoadRule, LoadRuleState, Q15,
};
use slipguard_core::sample::InputScale;
use slipguard_data::armed::{ArmedGrasp, ArmedReport};
use slipguard_data::labels::LabelConfig;
use slipguard_data::trial::{Outcome, Trial};

use crate::product::{ArmedError, CurvePoint, armed_window, pick_decision};

/// Fractions of the parameter grid.
pub const FRACTIONS: [f64; 13] = [
    0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8,
];
/// Peak windows of the parameter grid, seconds (frames at the trial's rate, rounded).
pub const WINDOWS_S: [f64; 4] = [0.3, 0.6, 0.9, 1.2];
/// False-alarm share over which the pick is penalised (the trainer's default).
pub const MAX_FALSE_ALARM_RATE: f64 = 0.125;

/// One trial's hand load per step (the rule's only input), with its armed window.
#[derive(Debug, Clone)]
pub struct LoadRun {
    /// Trial id.
    pub trial: String,
    /// Failure or success.
    pub failure: bool,
    /// Armed window `[start, end)`.
    pub window: (usize, usize),
    /// Step duration, ms.
    pub step_ms: f64,
    /// First step run (the grasp start).
    pub start: usize,
    /// Per step: Σ |x| (Q1.15) over the channels in contact; 0 before the grasp start.
    pub loads: Vec<i32>,
}

impl LoadRun {
    /// The rule's flag at every step.
    pub fn flags(&self, rule: &LoadRule) -> Vec<bool> {
        let mut s = LoadRuleState::new();
        self.loads
            .iter()
            .enumerate()
            .map(|(t, &l)| t >= self.start && rule.update(&mut s, l))
            .collect()
    }

    /// The grasp scored with `rule`'s flags.
    pub fn grasp(&self, rule: &LoadRule) -> ArmedGrasp {
        ArmedGrasp {
            trial: self.trial.clone(),
            failure: self.failure,
            start: self.window.0,
            end: self.window.1,
            flags: self.flags(rule),
            step_ms: self.step_ms,
        }
    }
}

/// The hand load of every step of `trial` from its grasp start: each channel's sample rounded
/// to whole sensor units (as the front end delivers it), scaled to Q1.15 by `scale`, through the
/// contact gate; the loads of the channels in contact summed ([`LoadRule::hand_load`]).
pub fn hand_loads(trial: &Trial, scale: &InputScale, contact: &ContactConfig) -> (usize, Vec<i32>) {
    let n = trial.n_steps();
    let start = trial.marks.grasp_start.unwrap_or(0).min(n);
    let mut states = vec![ContactState::new(); trial.n_channels()];
    let mut loads = vec![0i32; n];
    for (t, l) in loads.iter_mut().enumerate().skip(start) {
        *l = LoadRule::hand_load(states.iter_mut().enumerate().map(|(c, s)| {
            let x = scale.to_q15(trial.samples[c][t].round() as i32);
            contact.update(s, x).in_contact().then_some(x)
        }));
    }
    (start, loads)
}

/// The load runs of the trials with contact (`Ok(None)` trials are left out). `scale` and
/// `contact` are the model's (the rule sees what the model sees).
pub fn load_runs(
    trials: &[&Trial],
    scale: &InputScale,
    contact: &ContactConfig,
    cfg: &LabelConfig,
) -> Result<Vec<LoadRun>, ArmedError> {
    let mut out = Vec::new();
    for t in trials {
        let Some(window) = armed_window(t, cfg)? else {
            continue;
        };
        let (start, loads) = hand_loads(t, scale, contact);
        out.push(LoadRun {
            trial: t.id.clone(),
            failure: t.outcome == Outcome::Failure,
            window,
            step_ms: 1000.0 / t.rate_hz as f64,
            start,
            loads,
        });
    }
    Ok(out)
}

/// The rule of a fraction and a window in seconds at `step_ms`.
pub fn rule(fraction: f64, window_s: f64, step_ms: f64) -> LoadRule {
    let frames = (window_s * 1000.0 / step_ms).round();
    LoadRule {
        fraction_q15: Q15::from_f64(fraction).0,
        window: frames.clamp(1.0, slipguard_core::decision::LOAD_WINDOW_MAX as f64) as u8,
    }
}

/// The fraction of a rule (0…1).
pub fn fraction(rule: &LoadRule) -> f64 {
    Q15(rule.fraction_q15).to_f64()
}

/// Picks fraction and window on `runs` (training trials only) by the models' criterion: the
/// largest (share of failures detected ≥ 300 ms ahead) − (share of successes with a false
/// alarm), penalised over [`MAX_FALSE_ALARM_RATE`]; `None` without runs. The step of the first
/// run sets the frames of the windows.
pub fn pick(runs: &[&LoadRun]) -> Option<LoadRule> {
    let step_ms = runs.first()?.step_ms;
    let mut points = Vec::new();
    for &w in &WINDOWS_S {
        for &f in &FRACTIONS {
            let r = rule(f, w, step_ms);
            let grasps: Vec<ArmedGrasp> = runs.iter().map(|x| x.grasp(&r)).collect();
            // The curve point carries the fraction as its threshold and the window in frames
            // as its raise_after, so that the models' pick (and its ties) applies as is.
            points.push(CurvePoint::of(f, r.window, &grasps));
        }
    }
    let best = pick_decision(&points, MAX_FALSE_ALARM_RATE)?;
    Some(LoadRule {
        fraction_q15: Q15::from_f64(best.threshold).0,
        window: best.raise_after,
    })
}

/// The rule scored on held-out trials: the grasps and, per held-out group, the rule picked
/// for it.
#[derive(Debug, Clone)]
pub struct HeldOut {
    /// Every held-out grasp, scored with its group's rule.
    pub grasps: Vec<ArmedGrasp>,
    /// Per group: its held-out trials and the rule picked on the others.
    pub picks: Vec<(Vec<String>, LoadRule)>,
}

/// Cross-validation by the models' folds: each fold's held-out trials scored with the rule
/// picked on the runs outside that fold. Runs in no fold are not scored.
pub fn held_out_by_folds(runs: &[LoadRun], folds: &[Vec<String>]) -> HeldOut {
    let mut out = HeldOut {
        grasps: Vec::new(),
        picks: Vec::new(),
    };
    for fold in folds {
        let train: Vec<&LoadRun> = runs.iter().filter(|r| !fold.contains(&r.trial)).collect();
        let test: Vec<&LoadRun> = runs.iter().filter(|r| fold.contains(&r.trial)).collect();
        let Some(r) = pick(&train) else { continue };
        if test.is_empty() {
            continue;
        }
        out.grasps.extend(test.iter().map(|x| x.grasp(&r)));
        out.picks
            .push((test.iter().map(|x| x.trial.clone()).collect(), r));
    }
    out
}

/// Leave one trial out: every trial scored with the rule picked on all the others.
pub fn held_out_loto(runs: &[LoadRun]) -> HeldOut {
    let folds: Vec<Vec<String>> = runs.iter().map(|r| vec![r.trial.clone()]).collect();
    held_out_by_folds(runs, &folds)
}

/// One line naming the picks: "fraction 0.40, window 10 frames (k of n groups)" per distinct
/// rule, most frequent first.
pub fn picks_summary(h: &HeldOut) -> String {
    let mut counts: Vec<(LoadRule, usize)> = Vec::new();
    for (_, r) in &h.picks {
        match counts.iter_mut().find(|(x, _)| x == r) {
            Some((_, n)) => *n += 1,
            None => counts.push((*r, 1)),
        }
    }
    counts.sort_by_key(|c| std::cmp::Reverse(c.1));
    counts
        .iter()
        .map(|(r, n)| {
            format!(
                "fraction {:.2}, window {} frames ({n} of {})",
                fraction(r),
                r.window,
                h.picks.len()
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Strict fractions of the fused grid (0 = the rule never flags alone).
pub const FUSED_STRICT: [f64; 7] = [0.0, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45];
/// Guard fractions of the fused grid (1 = no guard: every model flag counts).
pub const FUSED_GUARD: [f64; 6] = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0];

/// The fused decision of a strict fraction, a guard fraction and a window in seconds.
pub fn fused(strict: f64, guard: f64, window_s: f64, step_ms: f64) -> FusedHand {
    FusedHand {
        strict: rule(strict, window_s, step_ms),
        guard_q15: if guard >= 1.0 {
            FusedHand::NO_GUARD
        } else {
            Q15::from_f64(guard).0
        },
    }
}

impl LoadRun {
    /// The grasp scored with the fused decision of `model_flags` (the model's hand flag per
    /// step, the same length as the loads) and the hand load.
    pub fn fused_grasp(&self, model_flags: &[bool], f: &FusedHand) -> ArmedGrasp {
        let mut s = LoadRuleState::new();
        let flags = self
            .loads
            .iter()
            .enumerate()
            .map(|(t, &l)| {
                t >= self.start && f.update(&mut s, model_flags.get(t).copied().unwrap_or(false), l)
            })
            .collect();
        ArmedGrasp {
            trial: self.trial.clone(),
            failure: self.failure,
            start: self.window.0,
            end: self.window.1,
            flags,
            step_ms: self.step_ms,
        }
    }
}

/// Picks the fused decision on training pairs (load run, the model's hand flags) by the models'
/// criterion ([`crate::product::pick_score`]); ties go to fewer false-alarm grasps, then to
/// the first in grid order (window, strict, guard ascending). `None` without pairs.
pub fn pick_fused(pairs: &[(&LoadRun, &[bool])]) -> Option<FusedHand> {
    let step_ms = pairs.first()?.0.step_ms;
    let mut best: Option<(f64, usize, FusedHand)> = None;
    for &w in &WINDOWS_S {
        for &st in &FUSED_STRICT {
            for &g in &FUSED_GUARD {
                let f = fused(st, g, w, step_ms);
                let grasps: Vec<ArmedGrasp> =
                    pairs.iter().map(|(r, m)| r.fused_grasp(m, &f)).collect();
                let p = CurvePoint::of(st, f.strict.window, &grasps);
                let sc = crate::product::pick_score(&p, MAX_FALSE_ALARM_RATE);
                if best
                    .as_ref()
                    .is_none_or(|(b, fa, _)| sc > *b || (sc == *b && p.false_alarm_grasps < *fa))
                {
                    best = Some((sc, p.false_alarm_grasps, f));
                }
            }
        }
    }
    best.map(|b| b.2)
}

/// One line naming a fused decision (its `Display`).
pub fn fused_name(f: &FusedHand) -> String {
    f.to_string()
}

/// Fractions of the ceiling sweeps ([`rule_sweep`], [`fused_sweep`]): 0.05 to 0.95 by 0.01.
pub fn sweep_fractions() -> impl Iterator<Item = f64> + Clone {
    (5..=95).map(|i| f64::from(i) / 100.0)
}
/// Peak windows of the ceiling sweeps, seconds (0.3 s steps of the pick grid, halved).
pub const SWEEP_WINDOWS_S: [f64; 7] = [0.3, 0.45, 0.6, 0.75, 0.9, 1.05, 1.2];

/// The rule at every fraction of [`sweep_fractions`] and window of [`SWEEP_WINDOWS_S`], each
/// scored on all of `runs`: its name and its curve point (the fraction as the threshold, the
/// window in frames as `raise_after`). For [`crate::product::frontier_300ms`]: what the best
/// rule for these very runs reaches.
pub fn rule_sweep(runs: &[LoadRun]) -> Vec<(String, CurvePoint)> {
    let Some(step_ms) = runs.first().map(|r| r.step_ms) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for &w in &SWEEP_WINDOWS_S {
        for f in sweep_fractions() {
            let r = rule(f, w, step_ms);
            let grasps: Vec<ArmedGrasp> = runs.iter().map(|x| x.grasp(&r)).collect();
            out.push((
                format!("load < {f:.2}·peak over {} frames", r.window),
                CurvePoint::of(f, r.window, &grasps),
            ));
        }
    }
    out
}

/// Strict fractions of the fused ceiling sweep: 0 (the rule never flags alone) and 0.05–0.60
/// by 0.05.
pub fn sweep_stricts() -> Vec<f64> {
    (0..=12).map(|i| f64::from(i) * 0.05).collect()
}
/// Guard fractions of the fused ceiling sweep: 0.30–1.00 by 0.05 (1 = no guard).
pub fn sweep_guards() -> Vec<f64> {
    (6..=20).map(|i| f64::from(i) * 0.05).collect()
}

/// The fused decision (rule OR (model flag AND load under the guard)) over `stricts` ×
/// `guards` × the windows of [`SWEEP_WINDOWS_S`], with the model's hand flags as given
/// (`pairs`), each scored on all of `pairs`: its name and its point.
pub fn fused_sweep(
    pairs: &[(&LoadRun, &[bool])],
    stricts: &[f64],
    guards: &[f64],
) -> Vec<(String, CurvePoint)> {
    let Some(step_ms) = pairs.first().map(|p| p.0.step_ms) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for &w in &SWEEP_WINDOWS_S {
        for &st in stricts {
            for &g in guards {
                let f = fused(st, g, w, step_ms);
                let grasps: Vec<ArmedGrasp> =
                    pairs.iter().map(|(r, m)| r.fused_grasp(m, &f)).collect();
                out.push((fused_name(&f), CurvePoint::of(st, f.strict.window, &grasps)));
            }
        }
    }
    out
}

/// The hand-load rule beside a model: held out as the model is ([`beside_model`]).
#[derive(Debug, Clone)]
pub struct RuleEval {
    /// "by the model's folds (…)" or "leave one trial out".
    pub how: String,
    /// The picked parameters, summarised.
    pub picks: String,
    /// Per held-out group: its trials and the rule.
    pub per_fold: Vec<(Vec<String>, LoadRule)>,
    /// Held-out grasps, each scored with its fold's rule.
    pub grasps: Vec<ArmedGrasp>,
    /// Held-out figures.
    pub report: ArmedReport,
    /// Its point on the operating curve.
    pub point: CurvePoint,
    /// The rule's own curve: the fractions at a 0.6 s window, on all scored trials.
    pub curve: Vec<CurvePoint>,
}

/// The rule held out as a model is: per fold on the fold's training trials (`folds`: each
/// fold's held-out trials), else leave one trial out; with the model's input scale and
/// contact gate (`config`).
pub fn beside_model(
    trials: &[Trial],
    config: &slipguard_core::blob::ModelConfig,
    folds: Option<&[Vec<String>]>,
) -> Result<RuleEval, ArmedError> {
    let refs: Vec<&Trial> = trials.iter().collect();
    let scale = InputScale::of(config);
    let contact = ContactConfig::of(config);
    let runs = load_runs(&refs, &scale, &contact, &LabelConfig::default())?;
    let (h, how) = if let Some(folds) = folds {
        (
            held_out_by_folds(&runs, folds),
            format!(
                "on each of the model's {} folds' training trials",
                folds.len()
            ),
        )
    } else {
        (
            held_out_loto(&runs),
            "leave one trial out (each trial with the rule picked on the others)".to_string(),
        )
    };
    let report = ArmedReport::of(&h.grasps);
    let first = h.picks.first().map(|(_, r)| *r);
    let point = CurvePoint::of(
        first.map_or(0.0, |r| fraction(&r)),
        first.map_or(0, |r| r.window),
        &h.grasps,
    );
    let curve = FRACTIONS
        .iter()
        .map(|&f| {
            let grasps: Vec<ArmedGrasp> = runs
                .iter()
                .map(|r| r.grasp(&rule(f, 0.6, r.step_ms)))
                .collect();
            let w = runs.first().map_or(0, |r| rule(f, 0.6, r.step_ms).window);
            CurvePoint::of(f, w, &grasps)
        })
        .collect();
    Ok(RuleEval {
        how,
        picks: picks_summary(&h),
        per_fold: h.picks,
        grasps: h.grasps,
        report,
        point,
        curve,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(id: &str, failure: bool, loads: Vec<i32>, window: (usize, usize)) -> LoadRun {
        LoadRun {
            trial: id.into(),
            failure,
            window,
            step_ms: 60.0,
            start: 0,
            loads,
        }
    }

    #[test]
    fn picked_rule_separates_a_fall_from_a_steady_hold() {
        // Failures: load 1000 that falls to 300 twelve steps before the drop at 40; successes:
        // a steady 1000 with a dip to 700. Any fraction in (0.3, 0.7] separates them, and the
        // pick must be one; held out, every failure is detected 720 ms ahead and no success
        // alarms.
        let mut runs = Vec::new();
        for i in 0..4 {
            let mut l = vec![1000; 50];
            l[28..].iter_mut().for_each(|v| *v = 300);
            runs.push(run(&format!("f{i}"), true, l, (10, 40)));
            let mut s = vec![1000; 50];
            s[25] = 700;
            runs.push(run(&format!("s{i}"), false, s, (10, 40)));
        }
        let h = held_out_loto(&runs);
        assert_eq!(h.grasps.len(), 8);
        assert_eq!(h.picks.len(), 8);
        for (_, r) in &h.picks {
            let f = fraction(r);
            assert!(f > 0.3 && f <= 0.7, "{f}");
        }
        let m = slipguard_data::armed::ArmedMetrics::of(&h.grasps);
        assert_eq!((m.detected, m.failures), (4, 4));
        assert_eq!(m.false_alarm_grasps, 0);
        assert_eq!(m.leads_ms, vec![720.0; 4]);
        assert!(picks_summary(&h).contains("of 8"));
    }

    #[test]
    fn windows_in_frames_follow_the_rate() {
        assert_eq!(rule(0.4, 0.6, 60.0).window, 10);
        assert_eq!(rule(0.4, 0.6, 25.0).window, 24);
        assert_eq!(rule(0.4, 100.0, 25.0).window, 64);
        assert_eq!(rule(0.4, 0.6, 60.0).fraction_q15, 13_107);
    }
}
