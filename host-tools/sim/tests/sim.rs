//! Simulator: determinism per seed and its documented statistics (docs/simulator.md).
use slipguard_data::labels::{LabelConfig, detect_drop};
use slipguard_data::recording::to_string;
use slipguard_data::{Outcome, Stability};
use slipguard_sim::force::{self, ForceSimConfig, Intent};
use slipguard_sim::suction::{self, SuctionSimConfig};
use slipguard_sim::validate::{band_3_5, mean_spectrum, trial_stats};

#[test]
fn force_is_deterministic_per_seed() {
    let cfg = ForceSimConfig::default();
    let a = force::simulate_batch(11, 3, 0.5, &cfg, |_| {});
    let b = force::simulate_batch(11, 3, 0.5, &cfg, |_| {});
    let c = force::simulate_batch(12, 3, 0.5, &cfg, |_| {});
    for i in 0..3 {
        assert_eq!(to_string(&a[i]), to_string(&b[i]));
        assert_ne!(a[i].samples, c[i].samples);
    }
    // Trial i does not depend on the batch size.
    let one = force::simulate_trial(11, 2, None, 0.5, &cfg);
    assert_eq!(one, a[2]);
}

#[test]
fn force_statistics() {
    let cfg = ForceSimConfig::default();
    let lcfg = LabelConfig::default();
    let n = 40;
    let mut fails = 0;
    let mut detected_ok = 0;
    let mut pre = Vec::new();
    let mut hold = Vec::new();
    let stats: Vec<_> = (0..n)
        .map(|i| {
            let intent = if i % 2 == 0 {
                Intent::Drop
            } else {
                Intent::Hold
            };
            force::simulate_trial(21, i, Some(intent), 0.0, &cfg)
        })
        .collect();
    for (i, t) in stats.iter().enumerate() {
        // Shape, ADC range and whole-number values.
        assert_eq!((t.n_channels(), t.n_steps()), (16, 400));
        assert!(
            t.samples
                .iter()
                .flatten()
                .all(|&x| (0.0..=33_000.0).contains(&x) && x.fract() == 0.0)
        );
        let l1 = t.marks.lift_start.unwrap();
        if i % 2 == 1 {
            assert_eq!(t.outcome, Outcome::Success, "{}: hold intent dropped", t.id);
            assert!(
                t.step_labels
                    .as_ref()
                    .unwrap()
                    .iter()
                    .flatten()
                    .all(|s| *s == Stability::Stable)
            );
        } else if t.outcome == Outcome::Failure {
            fails += 1;
            let d = t.drop_step.unwrap();
            let onset = t.slip_onset_step.unwrap();
            // Documented: drop 8-70 steps after lift start; slip onset before the drop.
            assert!(d >= l1 + 8 && d <= l1 + 70, "{}: drop {d}, lift {l1}", t.id);
            assert!(
                onset < d && onset >= l1,
                "{}: onset {onset}, drop {d}",
                t.id
            );
            // The labeller finds (nearly) the simulator's drop on the noisy data.
            let mut u = t.clone();
            u.drop_step = None;
            if detect_drop(&u, &lcfg)
                .step
                .is_some_and(|s| s.abs_diff(d) <= 2)
            {
                detected_ok += 1;
            }
        }
        let s = trial_stats(t, &lcfg);
        if let Some(p) = s.spectrum_pre_drop {
            pre.push(p);
        }
        if let Some(h) = s.spectrum_hold {
            hold.push(h);
        }
    }
    assert!(fails >= 18, "only {fails} of 20 drop-intent trials dropped");
    assert!(
        detected_ok * 10 >= fails * 8,
        "labeller matched {detected_ok} of {fails}"
    );
    // Stick-slip puts more of the pre-drop fluctuation power into 3-5 Hz than a calm hold.
    let p = band_3_5(
        &mean_spectrum(&pre.iter().collect::<Vec<_>>()).unwrap(),
        16.7,
    );
    let h = band_3_5(
        &mean_spectrum(&hold.iter().collect::<Vec<_>>()).unwrap(),
        16.7,
    );
    assert!(p > h, "3-5 Hz share pre-drop {p} vs hold {h}");
}

#[test]
fn force_at_40_hz_keeps_timing() {
    let t16 = force::simulate_trial(3, 0, Some(Intent::Drop), 0.0, &ForceSimConfig::default());
    let t40 = force::simulate_trial(
        3,
        0,
        Some(Intent::Drop),
        0.0,
        &ForceSimConfig::at_rate(40.0),
    );
    assert_eq!(t40.n_steps(), 958);
    assert_eq!(t40.rate_hz, 40.0);
    let secs = |t: &slipguard_data::Trial, s: usize| s as f64 / t.rate_hz as f64;
    let d16 = secs(&t16, t16.drop_step.unwrap());
    let d40 = secs(&t40, t40.drop_step.unwrap());
    assert!((d16 - d40).abs() < 0.15, "drop at {d16} s vs {d40} s");
    // 40 Hz labels keep the 1.2 s lead: 48 steps.
    let l = t40.step_labels.as_ref().unwrap();
    let first_unstable = l
        .iter()
        .position(|s| *s == Some(Stability::Unstable))
        .unwrap();
    assert_eq!(t40.drop_step.unwrap() - first_unstable, 48);
}

#[test]
fn suction_statistics() {
    let cfg = SuctionSimConfig::default();
    let (a, b) = suction::simulate_trial(4, 1, Some(true), 0.0, &cfg);
    let (a2, _) = suction::simulate_trial(4, 1, Some(true), 0.0, &cfg);
    assert_eq!(a, a2, "deterministic");
    assert_eq!((a.n_channels(), a.n_steps(), a.rate_hz), (4, 852, 71.0));
    assert_eq!((b.n_steps(), b.rate_hz), (213, 17.75));
    // Decimation is the boxcar mean of 4 (before rounding, so within 1 count + noise).
    let mean4: f32 = a.samples[0][40..44].iter().sum::<f32>() / 4.0;
    assert!((b.samples[0][10] - mean4).abs() <= 1.0);
    let mut drops = 0;
    let mut base = Vec::new();
    for i in 0..20 {
        let (hi, _) = suction::simulate_trial(9, i, Some(i % 2 == 0), 0.0, &cfg);
        assert!(
            hi.samples
                .iter()
                .flatten()
                .all(|&x| (0.0..=65535.0).contains(&x) && x.fract() == 0.0)
        );
        let g = hi.marks.grasp_start.unwrap();
        for c in 0..4 {
            base.push(hi.samples[c][..g].iter().sum::<f32>() / g as f32);
        }
        if i % 2 == 0 && hi.outcome == Outcome::Failure {
            drops += 1;
            let d = hi.drop_step.unwrap();
            // After the detachment every cup reads its baseline again (±100 counts).
            let end = hi.marks.open_start.unwrap();
            for c in 0..4 {
                assert!((hi.samples[c][(d + 20).min(end)] - cfg.baselines[c] as f32).abs() < 100.0);
            }
        }
        if i % 2 == 1 {
            assert_eq!(hi.outcome, Outcome::Success, "{}", hi.id);
        }
    }
    assert!(drops >= 8, "{drops} of 10 leak trials detached");
    base.sort_by(f32::total_cmp);
    let med = base[base.len() / 2];
    assert!((med - 6400.0).abs() < 120.0, "baseline median {med}");
}

/// Slip comes before (or with) the drop in every simulated suction failure, at both rates:
/// `slipguard simulate --sensor suction` wrote a `slip_onset_step` after its `drop_step` when
/// the cup detached before the leak began.
#[test]
fn suction_slip_onset_never_follows_the_drop() {
    let cfg = suction::SuctionSimConfig::default();
    let mut failures = 0;
    for seed in 1..=3 {
        for i in 0..60 {
            let (hi, lo) = suction::simulate_trial(seed, i, Some(true), 1.0, &cfg);
            for t in [&hi, &lo] {
                if let (Some(s), Some(d)) = (t.slip_onset_step, t.drop_step) {
                    failures += 1;
                    assert!(s <= d, "{}: slip onset {s} after the drop {d}", t.id);
                }
            }
        }
    }
    assert!(failures > 100, "only {failures} failures with a slip onset");
}
