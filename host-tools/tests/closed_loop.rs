//! Closed-loop grasp simulation: the physics drops the light grasps, a perfect predictor with
//! the firmware's latency saves most of them, the latency is what it should be, the minimum
//! grip is a real boundary, and the firmware path (golden model, bad blob) is wired in.
use slipguard::replay::golden_model_path;
use slipguard_core::units::Millihertz;
use slipguard_learn::closed_loop::{
    ControllerConfig, FLAG_FRAME_S, FlagSource, INFERENCE_S, Latency, Scenario, Situation,
    T_LIFT_S, min_grip_needed, run_trial,
};

const CTL: ControllerConfig = ControllerConfig {
    step_fraction: 0.2,
    rate_mhz: Millihertz(16_700),
    decision: None,
    settle_s: 0.0,
    hold_off_s: 0.0,
    latency: Latency::Deadline,
};

#[test]
fn off_drops_and_oracle_prevents() {
    let (mut drops_off, mut prevented) = (0, 0);
    for sit in Situation::ALL {
        let mut off_here = 0;
        for i in 0..5 {
            let sc = Scenario::draw(7, i, sit);
            let off = run_trial(&sc, FlagSource::Off, &CTL, None, 1);
            assert_eq!(off.increases, 0);
            assert_eq!(off.final_grip_n, sc.initial_grip_n);
            if off.dropped {
                off_here += 1;
                let on = run_trial(&sc, FlagSource::Oracle { delay_frames: 0 }, &CTL, None, 1);
                if !on.dropped {
                    prevented += 1;
                    assert!(on.increases > 0);
                    assert!(on.final_grip_n > sc.initial_grip_n);
                }
            }
        }
        // A light grip drops in most trials of every situation.
        assert!(off_here >= 3, "{sit:?}: {off_here}/5 dropped");
        drops_off += off_here;
    }
    assert!(
        2 * prevented > drops_off,
        "perfect predictor prevented {prevented} of {drops_off}"
    );
}

#[test]
fn hold_off_spaces_the_raises() {
    // The perfect detector flags every frame of a slip, so without a hold-off some raises are
    // one period apart; with 0.2 s no two raises are closer than that, and the first raise
    // comes at the same time.
    let (mut close, mut checked) = (0, 0);
    for i in 0..6 {
        let sc = Scenario::draw(3, i, Situation::GradualWeight);
        let src = FlagSource::Oracle { delay_frames: 0 };
        let free = run_trial(&sc, src, &CTL, None, 1);
        let held_ctl = ControllerConfig {
            hold_off_s: 0.2,
            ..CTL
        };
        let held = run_trial(&sc, src, &held_ctl, None, 1);
        let gaps = |o: &slipguard_learn::closed_loop::Outcome| -> Vec<f64> {
            o.raise_times.windows(2).map(|w| w[1] - w[0]).collect()
        };
        close += gaps(&free).iter().filter(|&&g| g < 0.1).count();
        assert!(
            gaps(&held).iter().all(|&g| g >= 0.2 - 1e-9),
            "{:?}",
            gaps(&held)
        );
        assert_eq!(free.raise_times.first(), held.raise_times.first());
        checked += usize::from(held.raise_times.len() >= 2);
    }
    assert!(
        close >= 1 && checked >= 1,
        "{close} close raises, {checked} trials checked"
    );
}

#[test]
fn reaction_comes_one_frame_after_the_slip() {
    let period = 1.0 / 16.7;
    let mut checked = 0;
    for i in 0..6 {
        let sc = Scenario::draw(3, i, Situation::Heavy);
        let o = run_trial(&sc, FlagSource::Oracle { delay_frames: 0 }, &CTL, None, 1);
        let off = run_trial(&sc, FlagSource::Off, &CTL, None, 1);
        let Some(&first) = o.raise_times.first() else {
            continue;
        };
        // The slip time of the uncontrolled run equals the controlled one's until the first
        // raise: the oracle sees it at the next frame boundary, the controller one period
        // (+ 0.61 ms transmission, + 1 ms tick) later.
        let mut c = slipguard_learn::closed_loop::Contact::default();
        let mut grip = 0.0;
        let mut t_slip = None;
        for k in 0..8000 {
            let t = k as f64 / 1000.0;
            if t >= slipguard_learn::closed_loop::T_CONTACT_S {
                grip += (0.001 / (slipguard_learn::closed_loop::ACTUATOR_TAU_S + 0.001))
                    * (sc.initial_grip_n - grip);
            }
            sc.tick(&mut c, t, grip);
            if c.t_slip.is_some() {
                t_slip = c.t_slip;
                break;
            }
        }
        let t_slip = t_slip.expect("slips");
        let lag = first - t_slip;
        assert!(
            lag >= period && lag <= 2.0 * period + 0.003,
            "trial {i}: raise {first:.4} s, slip {t_slip:.4} s"
        );
        // The oracle two frames late raises exactly two periods later (the grip has not moved
        // before its first raise, so the slip is the same).
        let late = run_trial(&sc, FlagSource::Oracle { delay_frames: 2 }, &CTL, None, 1);
        let Some(&late_first) = late.raise_times.first() else {
            // Dropped before the late flag arrived (flags of a lost object do not count).
            assert!(late.dropped, "trial {i}");
            continue;
        };
        let d = late_first - first;
        assert!((d - 2.0 * period).abs() < 0.0015, "trial {i}: {d:.4} s");
        let _ = off;
        // With the firmware's modelled latency the same flag arrives as soon as the frame is
        // inferred: 1 period − INFERENCE_S (10.7 ms) − 0.61 ms sooner than at the deadline, to within the
        // 1 ms tick (the grip has not moved before the first raise, so the slip is the same).
        let fw = ControllerConfig {
            latency: Latency::MODELLED,
            ..CTL
        };
        let o = run_trial(&sc, FlagSource::Oracle { delay_frames: 0 }, &fw, None, 1);
        let fw_first = o
            .raise_times
            .first()
            .copied()
            .expect("the firmware latency raises too");
        let sooner = first - fw_first;
        let expected = period - INFERENCE_S;
        assert!(
            (sooner - expected).abs() <= 0.0015,
            "trial {i}: {sooner:.4} s sooner, expected {expected:.4} s"
        );
        assert!(fw_first - t_slip >= INFERENCE_S + FLAG_FRAME_S, "trial {i}");
        checked += 1;
    }
    assert!(checked >= 4);
}

#[test]
fn minimum_grip_is_a_boundary() {
    for sit in Situation::ALL {
        let sc = Scenario::draw(11, 0, sit);
        let m = min_grip_needed(&sc, &CTL);
        assert!(m > sc.initial_grip_n, "{sit:?}: the initial grip is light");
        assert!(!run_trial(&sc, FlagSource::Off, &CTL, Some(m), 1).dropped);
        assert!(run_trial(&sc, FlagSource::Off, &CTL, Some(0.95 * m), 1).dropped);
    }
}

#[test]
fn firmware_in_the_loop() {
    let blob = slipguard::replay::load_blob(&golden_model_path()).unwrap();
    let sc = Scenario::draw(5, 0, Situation::Heavy);
    let o = run_trial(&sc, FlagSource::Model(blob.as_bytes()), &CTL, None, 1);
    // 8 s at 16.7 Hz: 133 frames, the last one still in flight.
    assert!((131..=133).contains(&o.flag_frames), "{}", o.flag_frames);
    assert_eq!(o.fault_frames, 0);
    // The untrained golden model says p ≈ 0.55 ≥ its 0.5 threshold everywhere: the hand flag is
    // up on nearly every frame from the pads' contact onset on (99 of 133 measured), and the grip
    // goes up every frame from the lift command until the hand's limit.
    assert!(
        o.unstable_frames > 90,
        "unstable frames {}",
        o.unstable_frames
    );
    assert_eq!(o.final_grip_n, slipguard_learn::closed_loop::MAX_GRIP_N);
    // A corrupted blob: fault frames only, no grip change (the controller keeps its policy).
    let mut b = std::fs::read(golden_model_path()).unwrap();
    b[5000] ^= 0x10;
    let bad = slipguard_core::blob::AlignedBlob::new(&b);
    let o = run_trial(&sc, FlagSource::Model(bad.as_bytes()), &CTL, None, 1);
    assert_eq!((o.flag_frames, o.increases), (0, 0));
    assert!(o.fault_frames >= 7);
    let off = run_trial(&sc, FlagSource::Off, &CTL, None, 1);
    assert_eq!(o.dropped, off.dropped);
    // The controller's set-threshold command reaches the firmware: at a threshold of 0.9 the
    // golden model's p ≈ 0.55 never flags, so the grip never rises and the trial ends as "off".
    let strict = ControllerConfig {
        decision: Some((29_491, 1, 1)),
        ..CTL
    };
    let o = run_trial(&sc, FlagSource::Model(blob.as_bytes()), &strict, None, 1);
    assert_eq!((o.unstable_frames, o.increases), (0, 0));
    assert_eq!(o.dropped, off.dropped);
}

#[test]
fn recorded_frames_match_the_pad_physics() {
    // The frames recorded for training are the front end's output in model units (mN), one per
    // period from grasp start on, and match the pad physics.
    let sc = Scenario::draw(5, 1, Situation::SuddenWeight);
    let o = run_trial(&sc, FlagSource::Off, &CTL, None, 1);
    let period = 1.0 / 16.7;
    assert!((o.frames[0].t - slipguard_learn::closed_loop::T_CONTACT_S).abs() <= period);
    assert!((126..=129).contains(&o.frames.len()), "{}", o.frames.len());
    let ch = sc.p.contacts[0];
    let grip_mn = 1000.0 * sc.initial_grip_n * sc.p.gains[ch];
    // Before the lift the pad reads its share of the grip (shear cross-talk is zero then).
    let f = o.frames.iter().find(|f| f.t > 1.2).unwrap();
    let expect = sc.p.shares[0] * grip_mn;
    assert!(
        (f.model_units[ch] as f64 - expect).abs() < 0.05 * expect + 30.0,
        "{} vs {expect}",
        f.model_units[ch]
    );
    // Channels without contact read about zero.
    let free = (0..16).find(|c| !sc.p.contacts.contains(c)).unwrap();
    assert!(o.frames.iter().all(|f| f.model_units[free].abs() < 60));
}

#[test]
fn teacher_false_alarms_raise_the_grip_without_slip() {
    // A grip twice the minimum never slips, so every raise the teacher makes is a false alarm;
    // without false alarms it makes none, and the false alarms do not change the sensor noise.
    // The first heavy object of seed 5 that leaves room below the hand's limit for the raises.
    let sc = (0..20)
        .map(|i| Scenario::draw(5, i, Situation::Heavy))
        .map(|sc| Scenario {
            initial_grip_n: 2.0 * min_grip_needed(&sc, &CTL),
            ..sc
        })
        .find(|sc| sc.initial_grip_n < 20.0)
        .expect("a light heavy object");
    let teacher = |false_alarm_hz| FlagSource::Teacher {
        act_prob: 1.0,
        false_alarm_hz,
    };
    let quiet = run_trial(&sc, teacher(0.0), &CTL, None, 7);
    assert_eq!(quiet.increases, 0);
    assert!(quiet.frames.iter().all(|f| f.rho < 0.85));
    let noisy = run_trial(&sc, teacher(2.0), &CTL, None, 7);
    assert!(!noisy.dropped);
    // About 2/s over 7.7 s of grasp, 1–8 frames each.
    assert!(
        (4..=100).contains(&noisy.increases),
        "{} raises",
        noisy.increases
    );
    assert!(noisy.frames.iter().all(|f| f.rho < 0.85));
    assert!(noisy.final_grip_n > sc.initial_grip_n);
    // The first frame (before any raise reached the fingers) is the same noise draw.
    assert_eq!(quiet.frames[0].model_units, noisy.frames[0].model_units);
}

#[test]
fn training_sequences_with_a_policy_in_the_loop() {
    use slipguard_data::trial::{Outcome, Stability};
    use slipguard_learn::closed_loop::{TrainingConfig, training_sequences};
    // The untrained golden model (p ≈ 0.55 everywhere, above any policy threshold drawn) in the
    // loop: the controller raises the grip on every frame from grasp start, so nothing drops
    // (with the teacher, some of these light grips do) and the physics labels end stable.
    let blob = slipguard::replay::load_blob(&golden_model_path()).unwrap();
    let teacher = TrainingConfig::default();
    let cfg = TrainingConfig {
        policy: Some(blob),
        policy_share: 1.0,
        ..teacher.clone()
    };
    let seqs = training_sequences(900, 4, &cfg);
    let taught = training_sequences(900, 4, &teacher);
    assert!(taught.iter().any(|s| s.cs.outcome == Outcome::Failure));
    assert_ne!(seqs[0].cs, taught[0].cs);
    for s in seqs
        .iter()
        .filter(|s| s.cs.samples.iter().any(|&x| x.abs() >= 60.0))
    {
        assert_eq!(s.cs.outcome, Outcome::Success, "{}", s.cs.trial_id);
        assert_eq!(*s.cs.labels.last().unwrap(), Stability::Stable);
    }
}

#[test]
fn training_sequences_are_labelled_by_the_physics() {
    use slipguard_data::trial::{Outcome, Stability};
    use slipguard_learn::closed_loop::training_sequences;
    let cfg = slipguard_learn::closed_loop::TrainingConfig::default();
    let seqs = training_sequences(900, 8, &cfg);
    // Same seed, same sequences.
    assert_eq!(seqs.len(), training_sequences(900, 8, &cfg).len());
    assert_eq!(seqs[0].cs, training_sequences(900, 1, &cfg)[0].cs);
    let mut trials = std::collections::BTreeMap::<&str, Vec<_>>::new();
    for s in &seqs {
        assert_eq!(s.cs.samples.len(), s.cs.labels.len());
        assert!(s.cs.drop_index.is_none());
        trials.entry(s.cs.trial_id.as_str()).or_default().push(s);
    }
    assert_eq!(trials.len(), 8);
    let (mut dropped, mut unstable_steps) = (0, 0);
    for (id, chans) in &trials {
        // One channel without contact, always stable, reading about zero.
        let free: Vec<_> = chans
            .iter()
            .filter(|s| s.cs.samples.iter().all(|&x| x.abs() < 60.0))
            .collect();
        assert_eq!(free.len(), 1, "{id}");
        assert!(free[0].cs.labels.iter().all(|&l| l == Stability::Stable));
        // The contact channels share one label track (the object's slip state).
        let contact: Vec<_> = chans
            .iter()
            .filter(|s| !std::ptr::eq(**s, *free[0]))
            .collect();
        assert!(!contact.is_empty());
        for s in &contact {
            assert_eq!(s.cs.labels, contact[0].cs.labels, "{id}");
        }
        let labels = &contact[0].cs.labels;
        // Nothing slips before the lift: labels before it are stable, except the lead
        // (0.3 s = 5 frames) before a slip right after the lift.
        let lift = contact[0].lift.expect("lift inside the trial");
        assert!(
            labels[..lift - 5].iter().all(|&l| l == Stability::Stable),
            "{id}"
        );
        unstable_steps += labels.iter().filter(|&&l| l == Stability::Unstable).count();
        if contact[0].cs.outcome == Outcome::Failure {
            dropped += 1;
            // A dropped object is unstable at the end, and the pads read about zero.
            assert_eq!(*labels.last().unwrap(), Stability::Unstable, "{id}");
        }
    }
    assert!(dropped >= 1 && unstable_steps > 0);
}

#[test]
fn shipped_40hz_model_in_the_loop() {
    // The shipped closed-loop model (models/hand-force-40hz, trained on closed-loop seeds 101 and
    // 102, threshold picked on seed 2) on seed 3, which neither saw. With prediction off every
    // light grasp drops; with the model most are kept at a grip of the order of the minimum,
    // by slip prediction alone: no raise comes before the lift, and ignoring the flags of the
    // first 0.5 s after grasp start changes nothing (docs/integration.md has the seed-1 report:
    // 155 of 200). With the firmware's latency, as `slipguard closed-loop` runs by default.
    let blobs = slipguard::replay::shipped_blobs("hand-force-40hz");
    let blob = slipguard::replay::load_blob(&blobs[0]).unwrap();
    let ctl = ControllerConfig {
        rate_mhz: Millihertz(40_000),
        latency: Latency::MODELLED,
        ..CTL
    };
    let settled = ControllerConfig {
        settle_s: 0.5,
        ..ctl
    };
    let (mut drops_off, mut prevented) = (0, 0);
    let mut ratio = Vec::new();
    for sit in Situation::ALL {
        for i in 0..6 {
            let sc = Scenario::draw(3, i, sit);
            let off = run_trial(&sc, FlagSource::Off, &ctl, None, 1);
            let on = run_trial(&sc, FlagSource::Model(blob.as_bytes()), &ctl, None, 1);
            let on_settled = run_trial(&sc, FlagSource::Model(blob.as_bytes()), &settled, None, 1);
            assert_eq!(on.fault_frames, 0);
            let first = on.raise_times.first().copied().unwrap_or(f64::INFINITY);
            assert!(first >= T_LIFT_S, "{sit:?} {i}: raise at {first:.2} s");
            assert_eq!(on.raise_times, on_settled.raise_times, "{sit:?} {i}");
            if off.dropped {
                drops_off += 1;
                prevented += usize::from(!on.dropped);
            }
            ratio.push(on.final_grip_n / min_grip_needed(&sc, &ctl));
        }
    }
    ratio.sort_by(f64::total_cmp);
    let median = ratio[ratio.len() / 2];
    assert!(drops_off >= 20, "{drops_off}");
    assert!(
        5 * prevented >= 3 * drops_off,
        "prevented {prevented} of {drops_off}"
    );
    assert!(
        median < 1.8,
        "final grip / minimum needed, median {median:.2}"
    );
}
