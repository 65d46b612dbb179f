//! Closed-loop grasp simulation: the physics drops the light grasps, a perfect predictor with
//! the firmware's latency saves most of them, the latency is what it should be, the minimum
//! grip is a real boundary, and the firmware path (golden model, bad blob) is wired in.
use slipguard_host::closed_loop::{
    ControllerConfig, FlagSource, Scenario, Situation, min_grip_needed, run_trial,
};
use slipguard_host::replay::golden_model_path;

const CTL: ControllerConfig = ControllerConfig {
    step_fraction: 0.2,
    rate_mhz: 16_700,
    decision: None,
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
                let on = run_trial(&sc, FlagSource::Oracle, &CTL, None, 1);
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
fn reaction_comes_one_frame_after_the_slip() {
    let period = 1.0 / 16.7;
    let mut checked = 0;
    for i in 0..6 {
        let sc = Scenario::draw(3, i, Situation::Heavy);
        let o = run_trial(&sc, FlagSource::Oracle, &CTL, None, 1);
        let off = run_trial(&sc, FlagSource::Off, &CTL, None, 1);
        let Some(&first) = o.raise_times.first() else {
            continue;
        };
        // The slip time of the uncontrolled run equals the controlled one's until the first
        // raise: the oracle sees it at the next frame boundary, the controller one period
        // (+ 0.61 ms transmission, + 1 ms tick) later.
        let mut c = slipguard_host::closed_loop::Contact::default();
        let mut grip = 0.0;
        let mut t_slip = None;
        for k in 0..8000 {
            let t = k as f64 / 1000.0;
            if t >= slipguard_host::closed_loop::T_CONTACT_S {
                grip += (0.001 / (slipguard_host::closed_loop::ACTUATOR_TAU_S + 0.001))
                    * (sc.initial_grip_n - grip);
            }
            c.tick(&sc, t, grip);
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
        let _ = off;
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
    let blob = slipguard_host::replay::load_blob(&golden_model_path()).unwrap();
    let sc = Scenario::draw(5, 0, Situation::Heavy);
    let o = run_trial(&sc, FlagSource::Model(blob.as_bytes()), &CTL, None, 1);
    // 8 s at 16.7 Hz: 133 frames, the last one still in flight.
    assert!((131..=133).contains(&o.flag_frames), "{}", o.flag_frames);
    assert_eq!(o.fault_frames, 0);
    // The untrained golden model says p ≈ 0.55 ≥ its 0.5 threshold everywhere: the grip goes
    // up every frame after grasp start until the hand's limit.
    assert!(o.unstable_frames > 100);
    assert_eq!(o.final_grip_n, slipguard_host::closed_loop::MAX_GRIP_N);
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
