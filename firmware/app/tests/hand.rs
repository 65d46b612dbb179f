//! The hand decision through the app: contact gating of every channel, the model restart at
//! each contact onset, the hand flag in the flag frame, the threshold command, and a blob's
//! hand rule (format v2) fused with the hand flag.

use slipguard_app::app::{App, FrameResult};
use slipguard_app::decimate::RATIO;
use slipguard_app::frontend::{FrameInput, Frontend};
use slipguard_app::profile::{AdcCode, Profile};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::decision::{FusedHand, LoadRule, Q15};
use slipguard_core::float::FloatModel;
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::protocol::{
    self, Command, Frame, MAX_WIRE, Message, PUnstable, ReplyBody, ReplyStatus, status,
};
use slipguard_core::quantize::quantize;

const GOLDEN: &[u8] = include_bytes!("../../core/tests/fixtures/bench/model.bin");

/// ADC counts of 0 mN in the hand profile (its live zero) and of 4760 mN (loaded).
const IDLE: u16 = 124;
const LOADED: u16 = 600;

/// A model of the bench model's kind whose p(unstable) is about 0.9 whatever the input:
/// dense weights 0, biases −1.1 / +1.1 (softmax: 1 / (1 + e^−2.2) = 0.90).
fn high_p_blob() -> AlignedBlob {
    const_p_blob(1.1, None)
}

/// A model of the bench model's kind whose p(unstable) is σ(2·`b`) whatever the input (dense
/// weights 0, biases −b / +b), with `rule` in the blob (format v2) when given.
fn const_p_blob(b: f32, rule: Option<FusedHand>) -> AlignedBlob {
    let bench = AlignedBlob::new(GOLDEN);
    let mut config = *Model::from_bytes(bench.as_bytes()).unwrap().config();
    config.hidden = [16, 0];
    config.hand_rule = rule;
    let mut m = FloatModel::init_like_pytorch(config, 7);
    m.dense.w.iter_mut().for_each(|w| *w = 0.0);
    m.dense.b = vec![-b, b];
    let trace: Vec<f32> = (0..400).map(|i| 1000.0 + (i % 50) as f32 * 40.0).collect();
    m.fit_normalisation(&[&trace]);
    let (blob, _) = quantize(&m, &[&trace], None).unwrap();
    AlignedBlob::new(&blob)
}

/// Frames of the hand profile with `level(frame, channel)` ADC counts (±1 count of noise).
fn frames(level: impl Fn(usize, usize) -> u16, n: usize) -> Vec<FrameInput> {
    let mut fe = Frontend::new(Profile::HAND);
    let mut out = Vec::new();
    for i in 0..n * RATIO {
        let mut s = [0u16; 16];
        for (c, v) in s.iter_mut().enumerate() {
            *v = level(i / RATIO, c) + (i % 2) as u16;
        }
        out.extend(fe.push_scan(AdcCode::from_dma(&s)));
    }
    out
}

fn flags_of(f: Option<Frame>) -> protocol::Flags {
    let f = f.expect("a flag frame");
    // Through the wire: what a controller decodes.
    let mut b = [0u8; MAX_WIRE];
    let n = protocol::encode(&f, &mut b);
    match protocol::decode(&b[..n]).unwrap().msg {
        Message::Flags(x) => x,
        m => panic!("{m:?}"),
    }
}

fn set_threshold(app: &mut App<'_>, threshold_q15: u16, raise_after: u8, clear_after: u8) {
    let reply = app.handle(Ok(Frame {
        seq: 1,
        msg: Message::Command(Command::SetThreshold {
            threshold_q15,
            raise_after,
            clear_after,
        }),
    }));
    let Message::Reply(r) = reply.msg else {
        panic!("{reply:?}")
    };
    assert_eq!(r.status, ReplyStatus::Ok);
    assert_eq!(
        r.body,
        ReplyBody::ThresholdSet {
            threshold_q15,
            raise_after,
            clear_after
        }
    );
}

#[test]
fn a_channel_without_contact_never_raises_the_hand_flag() {
    let blob = high_p_blob();
    let mut app = App::new(Profile::HAND, blob.as_bytes());
    // Flag as soon as p ≥ 1/32768 in one frame: every channel the model runs on is flagged.
    set_threshold(&mut app, 1, 1, 1);
    let on = app.contact_config().on_after as usize;
    let off = app.contact_config().off_after as usize;
    // Channel 3 loaded in frames 20..40, every other channel unloaded (0…10 mN) throughout.
    let inputs = frames(
        |i, c| {
            if c == 3 && (20..40).contains(&i) {
                LOADED
            } else {
                IDLE
            }
        },
        80,
    );
    let mut raised = Vec::new();
    for inp in &inputs {
        let r = app.infer(inp);
        let i = r.index as usize;
        let f = flags_of(app.emit(&r, false));
        assert_eq!(f.hand_unstable(), r.hand_unstable, "frame {i}");
        // Only channel 3 is ever in contact, predicted on or flagged.
        assert_eq!(r.contact & !(1 << 3), 0, "frame {i}");
        assert_eq!(r.unstable & !(1 << 3), 0, "frame {i}");
        for c in (0..16).filter(|&c| c != 3) {
            assert_eq!(r.p[c], PUnstable::NONE, "frame {i} ch {c}");
        }
        if r.contact == 0 {
            assert_eq!(r.hand_p_q15, 0, "frame {i}");
            assert_eq!(r.p[3], PUnstable::NONE, "frame {i}");
        } else {
            assert!(r.hand_p_q15 > 29_000, "frame {i}: p {}", r.hand_p_q15);
        }
        // With clear_after 1 the hand flag is exactly "a channel in contact".
        assert_eq!(r.hand_unstable, r.contact != 0, "frame {i}");
        if r.hand_unstable {
            raised.push(i);
        }
    }
    // The load reaches the model about 2 frames after the ADC (the filter's delay); contact
    // begins after `on` loaded frames and ends after `off` unloaded ones.
    let first = *raised.first().expect("the hand flag rises in contact");
    let last = *raised.last().unwrap();
    assert!((20 + on - 1..20 + on + 3).contains(&first), "first {first}");
    assert!((40 + off - 1..40 + off + 3).contains(&last), "last {last}");
    assert_eq!(raised.len(), last - first + 1, "one run: {raised:?}");
}

/// Runs `inputs` through the app, returning each frame's result.
fn run(app: &mut App<'_>, inputs: &[FrameInput]) -> Vec<FrameResult> {
    inputs
        .iter()
        .map(|inp| {
            let r = app.infer(inp);
            app.emit(&r, false);
            r
        })
        .collect()
}

#[test]
fn at_each_contact_onset_a_channel_gives_a_fresh_models_output() {
    let blob = AlignedBlob::new(GOLDEN);
    let mut app = App::new(Profile::HAND, blob.as_bytes());
    // Channel 5: a varying load in frames 5..45, unloaded, loaded again from 70 (a second
    // contact, whose model state must not carry over from the first).
    let load = |i: usize| LOADED + ((i * 37) % 23) as u16 * 25;
    let inputs = frames(
        |i, c| {
            if c == 5 && ((5..45).contains(&i) || i >= 70) {
                load(i)
            } else {
                IDLE
            }
        },
        110,
    );
    let results = run(&mut app, &inputs);
    let bit = 1u16 << 5;
    let onsets: Vec<usize> = (1..results.len())
        .filter(|&i| results[i].contact & bit != 0 && results[i - 1].contact & bit == 0)
        .collect();
    assert_eq!(onsets.len(), 2, "two contacts");
    let model = Model::from_bytes(blob.as_bytes()).unwrap();
    for &on in &onsets {
        // Reference: a fresh model fed the channel's input from the onset.
        let mut fresh = ChannelState::new();
        let mut n = 0;
        for r in results[on..].iter().take_while(|r| r.contact & bit != 0) {
            let want = model.step(&mut fresh, r.value[5]).p_unstable_q15.max(0) as u16;
            assert_eq!(r.p[5].to_bits(), want, "onset {on}, frame {}", r.index);
            n += 1;
        }
        assert!(n >= 20, "onset {on}: {n} frames in contact");
    }
    // The test can fail: a model run through every frame since boot (no restart) gives other
    // values at the second onset.
    let mut ungated = ChannelState::new();
    let cont: Vec<u16> = results
        .iter()
        .map(|r| model.step(&mut ungated, r.value[5]).p_unstable_q15.max(0) as u16)
        .collect();
    let on = onsets[1];
    assert_ne!(
        results[on].p[5].to_bits(),
        cont[on],
        "restart at onset {on}"
    );
}

#[test]
fn the_hand_flag_goes_out_in_the_flag_frame_and_reads_0_when_disarmed() {
    let blob = high_p_blob();
    let mut app = App::new(Profile::HAND, blob.as_bytes());
    let inputs = frames(|_, c| if c < 2 { LOADED } else { IDLE }, 30);
    let mut ups = 0;
    for (k, inp) in inputs.iter().enumerate() {
        if k == 20 {
            let r = app.handle(Ok(Frame {
                seq: 2,
                msg: Message::Command(Command::Release),
            }));
            assert!(matches!(r.msg, Message::Reply(r) if r.status == ReplyStatus::Ok));
        }
        let r = app.infer(inp);
        let f = flags_of(app.emit(&r, false));
        assert_eq!(f.hand_unstable(), r.hand_unstable);
        assert_eq!(f.status & status::HAND_UNSTABLE != 0, r.hand_unstable);
        assert_eq!(
            f.contact(),
            r.contact,
            "frame {k}: contact derived from p and fault"
        );
        assert_eq!(f.p, r.p);
        if k >= 20 {
            // Disarmed: no hand flag, no channel flag, p still reported.
            assert_eq!(f.status & (status::ARMED | status::HAND_UNSTABLE), 0);
            assert_eq!(f.unstable, 0);
            assert_eq!(f.contact(), 0b11, "frame {k}");
            assert!(r.hand_p_q15 > 29_000);
        } else if f.hand_unstable() {
            ups += 1;
            assert_eq!(f.status & status::ARMED, status::ARMED);
            assert_ne!(f.contact(), 0);
        }
    }
    assert!(ups >= 10, "the hand flag was up in {ups} armed frames");
}

#[test]
fn the_threshold_command_sets_the_hand_decision_too() {
    let blob = high_p_blob();
    let mut app = App::new(Profile::HAND, blob.as_bytes());
    let inputs = frames(|_, c| if c == 9 { LOADED } else { IDLE }, 60);
    // p ≈ 0.9 < 32767/32768: with the highest threshold neither channel nor hand flags.
    set_threshold(&mut app, 32_767, 1, 1);
    assert_eq!(app.hand_config().decision.threshold_q15, 32_767);
    let a = run(&mut app, &inputs[..20]);
    assert!(a.iter().any(|r| r.contact != 0 && r.hand_p_q15 > 29_000));
    assert!(a.iter().all(|r| !r.hand_unstable && r.unstable == 0));
    // Threshold 0.5, raise after 3 frames: the hand flag rises on the third frame in contact.
    set_threshold(&mut app, 16_384, 3, 2);
    let d = app.hand_config().decision;
    assert_eq!(
        (d.threshold_q15, d.raise_after, d.clear_after),
        (16_384, 3, 2)
    );
    let b = run(&mut app, &inputs[20..40]);
    let hand: Vec<bool> = b.iter().map(|r| r.hand_unstable).collect();
    assert_eq!(&hand[..4], [false, false, true, true], "{hand:?}");
    assert!(hand[2..].iter().all(|&h| h));
    // Back up: the flag clears after 2 frames below.
    set_threshold(&mut app, 32_767, 1, 2);
    let c = run(&mut app, &inputs[40..]);
    let hand: Vec<bool> = c.iter().map(|r| r.hand_unstable).collect();
    assert_eq!(&hand[..3], [true, false, false], "{hand:?}");
}

/// The rule of the fused tests: the rule alone under 0.4 of the peak over 10 frames, the
/// model's flag while the load is under `guard` of it.
fn rule(strict: f64, guard: f64) -> FusedHand {
    FusedHand {
        strict: LoadRule {
            fraction_q15: Q15::from_f64(strict).0,
            window: 10,
        },
        guard_q15: Q15::from_f64(guard).0,
    }
}

/// Channels 2 and 7 loaded from frame 10; from frame 50 channel 7 drops to about a quarter of
/// its load and channel 2 to about a half (both stay in contact: ≥ 500 mN).
fn drop_at_50(i: usize, c: usize) -> u16 {
    let full = LOADED;
    let part = |k: u16| IDLE + (LOADED - IDLE) / k;
    match (c, i) {
        (2 | 7, 0..10) => IDLE,
        (2 | 7, 10..50) => full,
        (2, _) => part(2),
        (7, _) => part(4),
        _ => IDLE,
    }
}

/// The rule by hand in f64 on the frames' model inputs (mN): the hand load is the sum of the
/// contact channels' inputs; up while it is below `f` of its peak over the last 10 frames.
fn below_peak(results: &[FrameResult], f: f64) -> Vec<bool> {
    let loads: Vec<f64> = results
        .iter()
        .map(|r| {
            (0..16)
                .filter(|c| r.contact & (1 << c) != 0)
                .map(|c| r.value[c].abs() as f64)
                .sum()
        })
        .collect();
    (0..loads.len())
        .map(|t| {
            let peak = loads[t.saturating_sub(9)..=t]
                .iter()
                .copied()
                .fold(0.0, f64::max);
            peak > 0.0 && loads[t] < f * peak
        })
        .collect()
}

#[test]
fn a_blob_rule_raises_the_hand_flag_on_a_load_drop_with_the_model_flag_low() {
    // p ≈ σ(−2.2) = 0.10: the model's hand flag never rises (threshold of the bench model).
    let inputs = frames(drop_at_50, 90);
    let v2 = const_p_blob(-1.1, Some(rule(0.4, 1.0)));
    assert_eq!(&v2.as_bytes()[4..6], &[2, 0], "a v2 blob");
    let mut app = App::new(Profile::HAND, v2.as_bytes());
    assert_eq!(app.hand_rule(), Some(rule(0.4, 1.0)));
    let mut results = Vec::new();
    let mut wire = Vec::new();
    for inp in &inputs {
        let r = app.infer(inp);
        wire.push(flags_of(app.emit(&r, false)));
        results.push(r);
    }
    let model_threshold = app.hand_config().decision.threshold_q15;
    assert!(results.iter().all(|r| r.hand_p_q15 < model_threshold));
    let want = below_peak(&results, 0.4);
    let hand: Vec<bool> = results.iter().map(|r| r.hand_unstable).collect();
    assert_eq!(hand, want);
    let up: Vec<usize> = (0..hand.len()).filter(|&i| hand[i]).collect();
    // The drop reaches the model a frame or two after the ADC; the flag holds while the full
    // load is in the 10-frame window, then clears.
    assert!(!up.is_empty() && up[0] >= 50 && up[0] <= 53, "{up:?}");
    assert!(*up.last().unwrap() <= 63, "{up:?}");
    for (k, (r, f)) in results.iter().zip(&wire).enumerate() {
        // The model's own flag is down, so every raise is the rule's, on the wire too.
        assert_eq!(r.hand_by_rule, r.hand_unstable, "frame {k}");
        assert_eq!(f.hand_unstable(), r.hand_unstable, "frame {k}");
        assert_eq!(f.hand_by_rule(), r.hand_by_rule, "frame {k}");
        assert_eq!(f.status & status::HAND_BY_RULE != 0, r.hand_by_rule);
    }
    // The same model without the rule (v1) never raises the hand flag on the same frames.
    let v1 = const_p_blob(-1.1, None);
    assert_eq!(&v1.as_bytes()[4..6], &[1, 0], "a v1 blob");
    let mut plain = App::new(Profile::HAND, v1.as_bytes());
    let r1 = run(&mut plain, &inputs);
    assert!(r1.iter().all(|r| !r.hand_unstable && !r.hand_by_rule));
    // Grasp start resets the rule's peak: right after it, the low load is the peak.
    let mut app = App::new(Profile::HAND, v2.as_bytes());
    run(&mut app, &inputs[..51]);
    app.handle(Ok(Frame {
        seq: 3,
        msg: Message::Command(Command::GraspStart),
    }));
    let after = run(&mut app, &inputs[51..]);
    assert!(
        after.iter().all(|r| !r.hand_unstable),
        "no old peak after grasp start"
    );
    // Disarmed, the rule raises nothing either.
    let mut app = App::new(Profile::HAND, v2.as_bytes());
    run(&mut app, &inputs[..40]);
    app.handle(Ok(Frame {
        seq: 4,
        msg: Message::Command(Command::Release),
    }));
    let off = run(&mut app, &inputs[40..]);
    assert!(off.iter().all(|r| !r.hand_unstable && !r.hand_by_rule));
}

#[test]
fn a_blob_guard_blocks_the_model_flag_at_full_load() {
    // p ≈ 0.9: the model's hand flag is up in every frame with contact; the rule alone never
    // flags (strict 0), and the model's flag counts only under 0.8 of the peak.
    let inputs = frames(drop_at_50, 90);
    let blob = const_p_blob(1.1, Some(rule(0.0, 0.8)));
    let mut app = App::new(Profile::HAND, blob.as_bytes());
    let results = run(&mut app, &inputs);
    let model_threshold = app.hand_config().decision.threshold_q15;
    let want = below_peak(&results, 0.8);
    for (k, r) in results.iter().enumerate() {
        let model_up = r.contact != 0 && r.hand_p_q15 >= model_threshold;
        assert_eq!(r.hand_unstable, model_up && want[k], "frame {k}");
        assert!(!r.hand_by_rule, "frame {k}: the model's flag was up");
    }
    // Held at full load (frames 20..50, in contact): the model's flag is up, the guard holds
    // the hand flag down.
    assert!(
        results[20..50]
            .iter()
            .all(|r| r.contact != 0 && !r.hand_unstable)
    );
    assert!(
        results[50..56].iter().any(|r| r.hand_unstable),
        "the drop passes"
    );
    // Without the guard (v1) the same model flags at full load.
    let v1 = const_p_blob(1.1, None);
    let mut plain = App::new(Profile::HAND, v1.as_bytes());
    let r1 = run(&mut plain, &inputs);
    assert!(r1[20..50].iter().all(|r| r.hand_unstable));
}
