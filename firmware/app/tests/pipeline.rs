//! The firmware logic end to end on the host: replay of a real trial with commands, bad blobs,
//! sensor faults, deadlines, and the command script's bytes.

use slipguard_app::app::App;
use slipguard_app::decimate::RATIO;
use slipguard_app::frontend::{FrameInput, Frontend};
use slipguard_app::profile::{AdcCode, Profile};
use slipguard_app::replay::{self, CHEEZ_TRIAL, ScriptItem, cheez_script};
use slipguard_core::blob::{AlignedBlob, CRC32};
use slipguard_core::protocol::{
    self, Command, Deframer, Frame, MAX_WIRE, Message, PUnstable, ReplyBody, ReplyStatus,
    fault_code, msg_type, status,
};
use slipguard_core::units::Millihertz;

const GOLDEN: &[u8] = include_bytes!("../../core/tests/fixtures/bench/model.bin");

fn golden() -> AlignedBlob {
    AlignedBlob::new(GOLDEN)
}

fn wire(f: &Frame) -> Vec<u8> {
    let mut b = [0u8; MAX_WIRE];
    let n = protocol::encode(f, &mut b);
    b[..n].to_vec()
}

fn cmd(seq: u16, c: Command) -> Vec<u8> {
    wire(&Frame {
        seq,
        msg: Message::Command(c),
    })
}

fn decode_stream(bytes: &[u8]) -> Vec<Frame> {
    let mut d = Deframer::new();
    bytes
        .iter()
        .filter_map(|&b| d.push_decode(b))
        .map(|r| r.expect("device frames decode"))
        .collect()
}

fn replay_frames(blob: &[u8], script: &[ScriptItem<'_>]) -> (Vec<u8>, Vec<Frame>) {
    let mut out = Vec::new();
    let n = replay::run(
        Profile::HAND,
        blob,
        &CHEEZ_TRIAL,
        script,
        cheez_script::OPEN_WIRES,
        |b| out.extend_from_slice(b),
    );
    let frames = decode_stream(&out);
    assert_eq!(frames.len(), n);
    (out, frames)
}

#[test]
fn script_bytes_are_the_encoder_output() {
    let mut boot = cmd(1, Command::Ping { token: 0xC0FF_EE00 });
    boot.extend(cmd(2, Command::Info));
    let threshold = cmd(
        5,
        Command::SetThreshold {
            threshold_q15: 19661,
            raise_after: 2,
            clear_after: 2,
        },
    );
    let mut garbage = vec![0x55, 0xAA, 0x00];
    let mut bad = cmd(
        3,
        Command::SetThreshold {
            threshold_q15: 16384,
            raise_after: 1,
            clear_after: 1,
        },
    );
    bad[6] ^= 0x01;
    garbage.extend(bad);
    // Unknown type 0x42 with a good CRC (seq 4, empty body).
    let mut p = vec![1u8, 0x42, 4, 0];
    p.extend(CRC32.checksum(&p).to_le_bytes());
    let mut enc = vec![0u8; 16];
    let n = cobs_encode(&p, &mut enc);
    garbage.extend(&enc[..n]);
    garbage.push(0);
    let pairs: [(&str, &[u8], Vec<u8>); 5] = [
        ("BOOT", cheez_script::BOOT, boot),
        ("GARBAGE", cheez_script::GARBAGE, garbage),
        ("THRESHOLD", cheez_script::THRESHOLD, threshold),
        ("GRASP", cheez_script::GRASP, cmd(6, Command::GraspStart)),
        ("RELEASE", cheez_script::RELEASE, cmd(7, Command::Release)),
    ];
    let mut bad = Vec::new();
    for (name, have, want) in pairs {
        if have != &want[..] {
            println!("CONST {name} {want:?}");
            bad.push(name);
        }
    }
    assert!(
        bad.is_empty(),
        "script constants differ from the encoder: {bad:?}"
    );
}

/// Minimal COBS encoder for the test (independent of the crate's).
fn cobs_encode(src: &[u8], dst: &mut [u8]) -> usize {
    let mut code_at = 0;
    let mut o = 1;
    let mut code = 1u8;
    for &b in src {
        if b == 0 {
            dst[code_at] = code;
            code_at = o;
            o += 1;
            code = 1;
        } else {
            dst[o] = b;
            o += 1;
            code += 1;
        }
    }
    dst[code_at] = code;
    o
}

#[test]
fn replay_of_a_real_trial_answers_every_command_and_flags_the_drop() {
    let blob = golden();
    let (bytes, frames) = replay_frames(blob.as_bytes(), cheez_script::SCRIPT);
    let flags: Vec<_> = frames
        .iter()
        .filter_map(|f| match f.msg {
            Message::Flags(fl) => Some(fl),
            _ => None,
        })
        .collect();
    assert_eq!(flags.len(), 400, "one flag frame per trial step");
    // Sequence numbers: every frame, no gap.
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.seq as usize, i);
    }
    // Replies in order: pong, info, 3 errors, threshold set, grasp started, released.
    let replies: Vec<_> = frames
        .iter()
        .filter(|f| !matches!(f.msg, Message::Flags(_)))
        .collect();
    assert_eq!(replies.len(), 8, "{replies:#?}");
    assert!(
        matches!(replies[0].msg, Message::Reply(r) if r.request_seq == 1
        && r.body == ReplyBody::Pong { token: 0xC0FF_EE00 })
    );
    let Message::Reply(info) = replies[1].msg else {
        panic!()
    };
    let ReplyBody::Info(info) = info.body else {
        panic!()
    };
    assert_eq!(
        (
            info.model_ok,
            info.channels,
            info.sample_rate_mhz,
            info.hidden
        ),
        (1, 16, Millihertz(16_700), 128)
    );
    let errors: Vec<_> = replies[2..5]
        .iter()
        .map(|f| match f.msg {
            Message::Error(e) => (e.error, e.msg_type, e.request_seq),
            _ => panic!("{f:?}"),
        })
        .collect();
    assert_eq!(errors, [(2, 0, 0xFFFF), (5, 0, 0xFFFF), (7, 0x42, 4)]);
    assert!(
        matches!(replies[5].msg, Message::Reply(r) if r.status == ReplyStatus::Ok
        && r.body == ReplyBody::ThresholdSet { threshold_q15: 19661, raise_after: 2, clear_after: 2 })
    );
    // Timestamps from the sample clock; armed until the release at frame 300.
    for (i, f) in flags.iter().enumerate() {
        assert_eq!(
            f.timestamp_us as u64,
            (i as u64 + 1) * 1_000_000_000 / 16_700
        );
        assert_eq!(f.status & status::ARMED != 0, i < 300, "frame {i}");
        assert_eq!(f.channels, 16);
        assert_eq!(f.overruns + f.skipped, 0);
        // The open wire on channel 14 (steps 150..170) is faulted, held 8 frames after; the
        // filter's delay (about 2 frames) shifts its start and end. Nothing else faults.
        let open = (152..180).contains(&i);
        let edge = (149..153).contains(&i) || (170..182).contains(&i);
        if !edge {
            assert_eq!(f.fault, if open { 1 << 14 } else { 0 }, "frame {i}");
            // Not predicted while faulted (nor while out of contact, fault bit clear).
            if open {
                assert_eq!(f.p[14], PUnstable::NONE, "frame {i}");
            }
        }
        // PUnstable::NONE exactly for the channels faulted or out of contact; the hand flag only with
        // a channel in contact.
        for c in 0..16 {
            let none = f.p[c].is_none();
            assert_eq!(!none, f.contact() & (1 << c) != 0, "frame {i} ch {c}");
        }
        if f.hand_unstable() {
            assert_ne!(f.contact(), 0, "frame {i}");
        }
        if i >= 300 {
            assert_eq!(f.unstable, 0);
        }
    }
    let unstable_frames = flags.iter().filter(|f| f.unstable != 0).count();
    let p_max = flags
        .iter()
        .flat_map(|f| f.p.iter().filter_map(|p| p.q15()))
        .max()
        .unwrap()
        .0;
    println!(
        "replay Cheez_100_814_top_3: {} frames, {} bytes, {} flag frames with a flag up, max p {}",
        frames.len(),
        bytes.len(),
        unstable_frames,
        p_max
    );
    // Deterministic: a second run gives the same bytes.
    let (again, _) = replay_frames(blob.as_bytes(), cheez_script::SCRIPT);
    assert_eq!(bytes, again);
}

fn corrupt(offset: usize) -> AlignedBlob {
    let mut b = GOLDEN.to_vec();
    b[offset] ^= 0x10;
    AlignedBlob::new(&b)
}

fn with_rate(rate_mhz: u32) -> AlignedBlob {
    let mut b = GOLDEN.to_vec();
    b[20..24].copy_from_slice(&rate_mhz.to_le_bytes());
    let body = b.len() - 4;
    let crc = CRC32.checksum(&b[..body]);
    b[body..].copy_from_slice(&crc.to_le_bytes());
    AlignedBlob::new(&b)
}

#[test]
fn bad_blobs_give_fault_frames_and_no_flags() {
    let cases = [
        (corrupt(5000), fault_code::BAD_MODEL, 5u8),
        (corrupt(4), fault_code::BAD_MODEL, 3), // version 17: checked before the CRC
        (AlignedBlob::new(&GOLDEN[..1000]), fault_code::BAD_MODEL, 1),
        (AlignedBlob::new(&[0xFF; 4096]), fault_code::BAD_MODEL, 2),
        (with_rate(25_000), fault_code::RATE_MISMATCH, 0),
    ];
    for (blob, code, detail) in cases {
        let (_, frames) = replay_frames(blob.as_bytes(), cheez_script::SCRIPT);
        let faults: Vec<_> = frames
            .iter()
            .filter_map(|f| match f.msg {
                Message::Fault(x) => Some(x),
                Message::Flags(_) => panic!("flags without a model"),
                _ => None,
            })
            .collect();
        // 400 frames at the default 16.7 Hz: one fault frame per 16 frames (once a second).
        assert_eq!(faults.len(), 25);
        assert!(
            faults.iter().all(|f| f.code == code && f.detail == detail),
            "{:?}",
            faults[0]
        );
        // Commands are still answered; those needing a model say so.
        let statuses: Vec<_> = frames
            .iter()
            .filter_map(|f| match f.msg {
                Message::Reply(r) => Some((r.body.msg_type(), r.status)),
                _ => None,
            })
            .collect();
        assert_eq!(
            statuses,
            [
                (msg_type::REPLY | msg_type::PING, ReplyStatus::Ok),
                (msg_type::REPLY | msg_type::INFO, ReplyStatus::Ok),
                (
                    msg_type::REPLY | msg_type::SET_THRESHOLD,
                    ReplyStatus::NoModel
                ),
                (
                    msg_type::REPLY | msg_type::GRASP_START,
                    ReplyStatus::NoModel
                ),
                (msg_type::REPLY | msg_type::RELEASE, ReplyStatus::NoModel),
            ]
        );
    }
    // 40 Hz is a hand rate: accepted.
    let b = with_rate(40_000);
    let app = App::new(Profile::HAND, b.as_bytes());
    assert!(app.model().is_ok());
    assert_eq!(app.rate_mhz(), Millihertz(40_000));
    // The hand model on the suction profile: rate and unit both wrong, rate reported first.
    let g = golden();
    let app = App::new(Profile::SUCTION, g.as_bytes());
    assert!(app.model().is_err());
}

fn scans(level: impl Fn(usize, usize) -> u16, frames: usize) -> Vec<FrameInput> {
    let mut fe = Frontend::new(Profile::HAND);
    let mut out = Vec::new();
    for i in 0..frames * RATIO {
        let mut s = [0u16; 16];
        for (c, v) in s.iter_mut().enumerate() {
            *v = level(i, c) + (i % 2) as u16;
        }
        out.extend(fe.push_scan(AdcCode::from_dma(&s)));
    }
    out
}

#[test]
fn faulted_channels_are_masked_and_not_predicted() {
    let g = golden();
    let mut app = App::new(Profile::HAND, g.as_bytes());
    // Loaded frames before contact begins (3 at 16.7 Hz).
    let on = app.contact_config().on_after as usize;
    let mut p0 = Vec::new();
    // Channel 2 disconnected from frame 5 to 9, channel 7 saturated throughout.
    let inputs = scans(
        |i, c| match c {
            2 if (5 * RATIO..10 * RATIO).contains(&i) => 0,
            7 => 4095,
            _ => 600,
        },
        30,
    );
    for inp in &inputs {
        let Some(Frame {
            msg: Message::Flags(f),
            ..
        }) = app.frame(inp, false)
        else {
            panic!()
        };
        let i = inp.index as usize;
        let back = 10 + Profile::HAND.fault_hold_periods as usize;
        let ch2 = (5..back).contains(&i);
        assert_eq!(f.fault & (1 << 2) != 0, ch2, "frame {i}");
        // Not predicted while faulted, nor (out of contact) until the channel's contact begins
        // again `on` loaded frames after the fault cleared, as at boot.
        let none2 = i + 1 < on || (5..back + on - 1).contains(&i);
        assert_eq!(f.p[2].is_none(), none2, "frame {i}");
        // Back in contact, channel 2 gives what channel 0 (same input) gave at its own onset:
        // the model restarted from zero.
        if i >= back + on - 1 {
            assert_eq!(f.p[2], p0[i - back], "frame {i}");
        }
        assert!(f.fault & (1 << 7) != 0 && f.p[7].is_none() && f.unstable & (1 << 7) == 0);
        assert_eq!(
            f.contact() & (1 << 7),
            0,
            "a faulted channel is not in contact"
        );
        assert_eq!(f.p[0].q15().is_some(), i + 1 >= on, "frame {i}");
        assert_eq!(f.contact() & 1 != 0, i + 1 >= on, "frame {i}");
        p0.push(f.p[0]);
    }
}

#[test]
fn late_frames_are_counted_and_marked() {
    let g = golden();
    let mut app = App::new(Profile::HAND, g.as_bytes());
    let inputs = scans(|_, _| 700, 4);
    let mut got = Vec::new();
    for (k, inp) in inputs.iter().enumerate() {
        if k == 2 {
            app.note_skipped();
            continue;
        }
        let Some(Frame {
            msg: Message::Flags(f),
            ..
        }) = app.frame(inp, k == 1)
        else {
            panic!()
        };
        got.push((f.status & status::LATE != 0, f.overruns, f.skipped));
    }
    assert_eq!(got, [(false, 0, 0), (true, 1, 0), (false, 1, 1)]);
}

#[test]
fn grasp_start_resets_and_tares_release_disarms() {
    let g = golden();
    let mut app = App::new(Profile::HAND, g.as_bytes());
    let mut d = Deframer::new();
    let inputs = scans(|i, _| 600 + (i / 7 % 50) as u16 * 20, 40);
    let mut first = Vec::new();
    for inp in &inputs[..20] {
        first.push(app.frame(inp, false).unwrap());
    }
    let mut replies = Vec::new();
    replay::receive(
        &mut app,
        &mut d,
        &cmd(9, Command::GraspStart),
        |f: &Frame| replies.push(*f),
    );
    // After grasp start the channel states are fresh: frames 20.. equal a fresh app's frames
    // on the same inputs (p values and flags; seq differs).
    let mut fresh = App::new(Profile::HAND, g.as_bytes());
    for inp in &inputs[20..30] {
        let (Some(a), Some(b)) = (app.frame(inp, false), fresh.frame(inp, false)) else {
            panic!()
        };
        let (Message::Flags(a), Message::Flags(b)) = (a.msg, b.msg) else {
            panic!()
        };
        assert_eq!(a.p, b.p);
        assert_eq!(a.unstable, b.unstable);
    }
    replay::receive(&mut app, &mut d, &cmd(10, Command::Release), |f: &Frame| {
        replies.push(*f)
    });
    for inp in &inputs[30..] {
        let Message::Flags(f) = app.frame(inp, false).unwrap().msg else {
            panic!()
        };
        assert_eq!(f.status & status::ARMED, 0);
        assert_eq!(f.unstable, 0);
        assert!(f.p[0].q15().is_some());
    }
    assert_eq!(replies.len(), 2);
    assert!(first.iter().all(|f| matches!(f.msg, Message::Flags(_))));
}

#[test]
fn suction_profile_tares_at_grasp_start() {
    // The golden network relabelled as a 71 Hz pressure model (counts).
    let mut b = GOLDEN.to_vec();
    b[19] = 1;
    b[20..24].copy_from_slice(&71_000u32.to_le_bytes());
    let body = b.len() - 4;
    let crc = CRC32.checksum(&b[..body]);
    b[body..].copy_from_slice(&crc.to_le_bytes());
    let blob = AlignedBlob::new(&b);
    let p = Profile::SUCTION;
    let mut app = App::new(p, blob.as_bytes());
    assert!(app.model().is_ok(), "{:?}", app.model().err());
    let mut fe = Frontend::new(p);
    let mut d = Deframer::new();
    let mut last = None;
    for i in 0..RATIO * 6 {
        let s = [2500 + (i % 2) as u16; 4];
        if let Some(inp) = fe.push_scan(AdcCode::from_dma(&s)) {
            last = app.frame(&inp, false);
        }
    }
    let Some(Frame {
        msg: Message::Flags(f),
        ..
    }) = last
    else {
        panic!()
    };
    assert_eq!((f.channels, f.status & status::TARED), (4, 0));
    let mut r = Vec::new();
    replay::receive(
        &mut app,
        &mut d,
        &cmd(1, Command::GraspStart),
        |f: &Frame| r.push(*f),
    );
    // The tare is the last decimated value: the model input is now ~0 counts.
    assert_eq!(
        p.to_model_units(2500 << 4, (2500 << 4) - (p.zero_counts << 4)),
        0
    );
    for i in 0..RATIO * 2 {
        let s = [2500 + (i % 2) as u16; 4];
        if let Some(inp) = fe.push_scan(AdcCode::from_dma(&s)) {
            let Message::Flags(f) = app.frame(&inp, false).unwrap().msg else {
                panic!()
            };
            assert_eq!(f.status & status::TARED, status::TARED);
        }
    }
}
