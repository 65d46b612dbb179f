//! The monitor as a recorder: a trial replayed through the firmware with the samples stream on,
//! recorded and compared with the source; lost frames, marks out of order, channel counts and
//! sizes from the wire that must not be trusted.
use slipguard_core::units::Millihertz;
use std::path::{Path, PathBuf};
use std::process::Command as Process;

use slipguard::monitor::{Monitor, Recorder, parse_command};
use slipguard::replay::{self, Scheduled};
use slipguard_app::profile::Profile;
use slipguard_core::protocol::{
    self, Command, Flags, Frame, Info, MAX_CHANNELS, MAX_WIRE, Message, Reply, ReplyBody,
    ReplyStatus, Samples, StreamMode, mark,
};
use slipguard_data::labels::LabelConfig;
use slipguard_data::recording::read_recording;
use slipguard_data::{PhaseMarks, load_path};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sg-recorder-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn wire(seq: u16, msg: Message) -> Vec<u8> {
    let mut b = [0u8; MAX_WIRE];
    let n = protocol::encode(&Frame { seq, msg }, &mut b);
    b[..n].to_vec()
}

fn samples(t_us: u32, channels: u8, marks: u8, v: i32) -> Message {
    let mut value = [0i32; MAX_CHANNELS];
    value[..channels as usize].fill(v);
    Message::Samples(Samples {
        timestamp_us: t_us,
        status: 0,
        marks,
        channels,
        unit: 0,
        fault: 0,
        value,
    })
}

fn info(rate_mhz: u32) -> Message {
    Message::Reply(Reply {
        request_seq: 0,
        status: ReplyStatus::Ok,
        body: ReplyBody::Info(Info {
            firmware: [0, 1, 0],
            profile: 0,
            channels: 2,
            oversample: 16,
            model_ok: 1,
            variant: 2,
            model_id: 1,
            model_crc: 0x1234_5678,
            sample_rate_mhz: Millihertz(rate_mhz),
            hidden: 8,
            threshold_q15: 16384,
            raise_after: 1,
            clear_after: 1,
            name: [0; 12],
        }),
    })
}

/// Frame `i`'s timestamp at 16.7 Hz, as the firmware stamps it.
fn ts(i: u64) -> u32 {
    ((i + 1) * 1_000_000_000 / 16_700) as u32
}

fn record(bytes: &[u8], path: &Path) -> (Monitor, Result<usize, String>) {
    let mut mon = Monitor::new();
    mon.recorder = Some(Recorder::new(path));
    for c in bytes.chunks(7) {
        mon.push(c, |_| {});
    }
    let (stats, info) = (mon.stats.clone(), mon.info);
    let r = mon.recorder.as_mut().unwrap().finish(&stats, info.as_ref());
    (mon, r)
}

#[test]
fn a_replayed_trial_records_its_forces_and_marks() {
    let dir = tmp("replayed");
    let src_dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/eagle-shoal/trials/Cheez_100_814_top_3");
    let src = load_path(&src_dir, &LabelConfig::default(), |_, _| {})
        .unwrap()
        .remove(0);
    let profile = Profile::HAND;
    let blob = replay::load_blob(&replay::golden_model_path()).unwrap();
    let script = replay::encode_script(&[
        Scheduled {
            before_frame: 0,
            command: Command::Info,
        },
        Scheduled {
            before_frame: 0,
            command: Command::StreamMode(StreamMode::FlagsAndSamples),
        },
        Scheduled {
            before_frame: 52,
            command: Command::GraspStart,
        },
        Scheduled {
            before_frame: 87,
            command: Command::Lift,
        },
        Scheduled {
            before_frame: 300,
            command: Command::Release,
        },
    ]);
    let out = replay::replay(profile, blob.as_bytes(), &src, &script, &[]);
    let path = dir.join("cheez.csv");
    let (mon, rows) = record(&out.wire, &path);
    assert_eq!(rows.unwrap(), src.n_steps());
    assert_eq!(mon.stats.lost, 0);
    let rec = read_recording(&path, &LabelConfig::default()).unwrap();
    assert_eq!(rec.n_channels(), 16);
    assert_eq!(
        (rec.rate_hz, rec.unit.to_string()),
        (16.7, "mN".to_string())
    );
    assert_eq!(
        rec.marks,
        PhaseMarks {
            grasp_start: Some(52),
            lift_start: Some(87),
            open_start: None,
            release: Some(300)
        }
    );
    // The source force, through the ADC emulation (±1 LSB dither), the anti-alias filter and
    // ÷16: where the source held its value for 4 steps the recording is within a few mN.
    let mut checked = 0;
    for c in 0..16 {
        for t in 4..src.n_steps() {
            let s = &src.samples[c];
            if (t - 4..=t).all(|u| s[u] == s[t]) {
                let d = (rec.samples[c][t] - s[t]).abs();
                assert!(
                    d <= 8.0,
                    "c{c} step {t}: recorded {} source {}",
                    rec.samples[c][t],
                    s[t]
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000, "{checked}");
    // A session cut short (Ctrl-C missed, power gone) after a flush: the rows written so far
    // read back, marks from the phase column.
    let cut = dir.join("cut.csv");
    let mut mon = Monitor::new();
    mon.recorder = Some(Recorder::new(&cut));
    mon.push(&out.wire[..out.wire.len() / 2], |_| {});
    let r = mon.recorder.as_mut().unwrap();
    r.flush();
    let part = read_recording(&cut, &LabelConfig::default()).unwrap();
    assert_eq!(part.n_steps(), r.steps());
    assert!(part.n_steps() > 150, "{}", part.n_steps());
    assert_eq!(part.samples[3][..], rec.samples[3][..part.n_steps()]);
    assert_eq!(
        (part.marks.grasp_start, part.marks.lift_start),
        (Some(52), Some(87))
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn lost_frames_are_filled_and_listed_and_a_long_gap_ends_the_recording() {
    let dir = tmp("gaps");
    let mut b = wire(0, info(16_700));
    let mut seq = 1;
    for i in (0..60u64).filter(|i| !(10..13).contains(i)) {
        b.extend(wire(
            seq,
            samples(
                ts(i),
                2,
                if i == 5 { mark::GRASP_START } else { 0 },
                i as i32,
            ),
        ));
        seq += 1;
    }
    // 30 s later (a reset or a cable out): ends the recording.
    b.extend(wire(seq, samples(ts(60 + 500), 2, 0, 1)));
    let path = dir.join("gaps.csv");
    let (_, rows) = record(&b, &path);
    assert_eq!(rows.unwrap(), 60);
    let t = read_recording(&path, &LabelConfig::default()).unwrap();
    assert_eq!(t.extra["monitor_gaps"], "10+3");
    assert!(
        t.extra["monitor_ended"].contains("seq 58"),
        "{}",
        t.extra["monitor_ended"]
    );
    assert_eq!(t.samples[0][9..14], [9.0, 9.0, 9.0, 9.0, 13.0]);
    assert_eq!(t.marks.grasp_start, Some(5));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn marks_out_of_order_are_repaired_or_ignored_with_a_note() {
    let dir = tmp("marks");
    let mut b = wire(0, info(16_700));
    let m = [
        (3, mark::RELEASE),
        (5, mark::LIFT),
        (8, mark::GRASP_START),
        (9, mark::RELEASE),
    ];
    for i in 0..12u64 {
        let bits = m.iter().find(|x| x.0 == i).map_or(0, |x| x.1);
        b.extend(wire(1 + i as u16, samples(ts(i), 2, bits, 7)));
    }
    let path = dir.join("marks.csv");
    let mut mon = Monitor::new();
    mon.recorder = Some(Recorder::new(&path));
    mon.push(&b, |_| {});
    let rec = mon.recorder.as_mut().unwrap();
    let notes = rec.notes.join("\n");
    assert!(
        notes.contains("step 3): release before any grasp start: ignored"),
        "{notes}"
    );
    assert!(
        notes.contains("step 5): lift before any grasp start"),
        "{notes}"
    );
    assert!(
        notes.contains("step 8): grasp start after the first one"),
        "{notes}"
    );
    rec.finish(&Default::default(), None).unwrap();
    let t = read_recording(&path, &LabelConfig::default()).unwrap();
    assert_eq!(
        t.marks,
        PhaseMarks {
            grasp_start: Some(5),
            lift_start: Some(5),
            open_start: None,
            release: Some(9)
        }
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_channel_count_change_ends_the_recording_there() {
    let dir = tmp("channels");
    let mut b = wire(0, info(16_700));
    for i in 0..10u64 {
        b.extend(wire(
            1 + i as u16,
            samples(ts(i), if i < 6 { 2 } else { 4 }, 0, 1),
        ));
    }
    let path = dir.join("ch.csv");
    let (mon, rows) = record(&b, &path);
    assert_eq!(rows.unwrap(), 6);
    let why = mon.recorder.as_ref().unwrap().ended.clone().unwrap();
    assert!(
        why.contains("seq 7") && why.contains("4 channels, the recording has 2"),
        "{why}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn rates_and_timestamps_from_the_wire_size_nothing() {
    // Info says 0xFFFFFFFF mHz; flags and samples jump from 0 to 0xFFFFFFFF µs.
    let dir = tmp("huge");
    let mut b = wire(0, info(u32::MAX));
    let flags = |t: u32| {
        Message::Flags(Flags {
            timestamp_us: t,
            status: 0,
            channels: 2,
            unstable: 0,
            fault: 0,
            overruns: 0,
            skipped: 0,
            p: [slipguard_core::protocol::PUnstable::from_bits(0).unwrap(); MAX_CHANNELS],
        })
    };
    let mut seq = 1;
    for t in [0, 59_880, 119_760, 179_640, u32::MAX, 0, u32::MAX] {
        b.extend(wire(seq, samples(t, 2, 0, 1)));
        b.extend(wire(seq + 1, flags(t)));
        seq += 2;
    }
    let cap = dir.join("huge.bin");
    std::fs::write(&cap, &b).unwrap();
    let rec = dir.join("huge.csv");
    let run = Process::new(env!("CARGO_BIN_EXE_slipguard"))
        .args(["monitor", "--view", "none", "--capture"])
        .arg(&cap)
        .arg("--record")
        .arg(&rec)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("info reply's rate 4294967295 mHz is outside"),
        "{err}"
    );
    assert!(err.contains("recording ended at step 3"), "{err}");
    let t = read_recording(&rec, &LabelConfig::default()).unwrap();
    // 0 and 59 880 µs are both frame 0 at the rate the timestamps give: one dropped.
    assert_eq!(t.n_steps(), 3);
    assert!(err.contains("already recorded"), "{err}");
    // The flag-frame recording (no samples frames) is bounded the same way.
    let flags_only: Vec<u8> = {
        let mut b = wire(0, info(u32::MAX));
        for (i, t) in [0, 59_880, 119_760, u32::MAX].into_iter().enumerate() {
            b.extend(wire(1 + i as u16, flags(t)));
        }
        b
    };
    let mut mon = Monitor::new();
    mon.push(&flags_only, |_| {});
    let t = mon.to_trial("f").unwrap();
    assert!(t.n_steps() <= 3, "{}", t.n_steps());
    assert!(t.extra["monitor_ended"].contains("jumps"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn keyboard_commands_parse() {
    assert_eq!(parse_command("g"), Ok(Command::GraspStart));
    assert_eq!(parse_command("lift"), Ok(Command::Lift));
    assert_eq!(parse_command("r"), Ok(Command::Release));
    assert_eq!(parse_command("i"), Ok(Command::Info));
    assert_eq!(
        parse_command("s 1"),
        Ok(Command::StreamMode(StreamMode::FlagsAndSamples))
    );
    assert_eq!(
        parse_command("stream samples"),
        Ok(Command::StreamMode(StreamMode::Samples))
    );
    assert_eq!(
        parse_command("t 0.3 2 3"),
        Ok(Command::SetThreshold {
            threshold_q15: 9830,
            raise_after: 2,
            clear_after: 3
        })
    );
    assert!(matches!(parse_command("p"), Ok(Command::Ping { .. })));
    for bad in ["t", "t 1.5", "t 0.3 0", "s 3", "g 1", "x", ""] {
        assert!(parse_command(bad).is_err(), "{bad}");
    }
}

/// `slipguard monitor --port … --record` on a pseudo terminal: it sends info and stream mode
/// itself, takes keyboard commands, has the rows on disk within about a second while it runs,
/// and on Ctrl-C (SIGINT) finishes the file with its marks and summary; `--save-raw` keeps the
/// bytes.
#[test]
fn monitor_records_from_a_port_flushes_while_running_and_finishes_on_ctrl_c() {
    use slipguard_core::protocol::Deframer;
    use std::io::{Read, Write};
    use std::process::Stdio;
    use std::time::{Duration, Instant};

    let (mut master, slave) = serialport::TTYPort::pair().expect("openpty");
    let name = serialport::SerialPort::name(&slave).expect("slave path");
    let dir = tmp("port");
    let (rec, raw) = (dir.join("port.csv"), dir.join("port.bin"));
    let mut child = Process::new(env!("CARGO_BIN_EXE_slipguard"))
        .args([
            "monitor",
            "--port",
            &name,
            "--view",
            "none",
            "--seconds",
            "30",
        ])
        .arg("--record")
        .arg(&rec)
        .arg("--save-raw")
        .arg(&raw)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The commands it sends: info and stream mode flags+samples, then the typed lift.
    serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(100)).unwrap();
    let mut d = Deframer::new();
    let mut cmds = Vec::new();
    let mut typed = false;
    let t0 = Instant::now();
    while cmds.len() < 3 && t0.elapsed() < Duration::from_secs(10) {
        if cmds.len() == 2 && !typed {
            child
                .stdin
                .as_mut()
                .unwrap()
                .write_all(b"bogus\nl\n")
                .unwrap();
            typed = true;
        }
        let mut b = [0u8; 64];
        if let Ok(n) = master.read(&mut b) {
            for &x in &b[..n] {
                if let Some(Ok(f)) = d.push_decode(x) {
                    cmds.push(f.msg);
                }
            }
        }
    }
    assert_eq!(
        cmds,
        [
            Message::Command(Command::Info),
            Message::Command(Command::StreamMode(StreamMode::FlagsAndSamples)),
            Message::Command(Command::Lift),
        ]
    );
    // The device's side: 100 samples frames, grasp start at frame 10.
    let mut sent = wire(0, info(16_700));
    for i in 0..100u64 {
        let bits = if i == 10 { mark::GRASP_START } else { 0 };
        sent.extend(wire(1 + i as u16, samples(ts(i), 2, bits, i as i32)));
    }
    master.write_all(&sent).unwrap();
    master.flush().unwrap();
    // Within the flush period (plus slack for a loaded machine) the rows are on disk.
    let t0 = Instant::now();
    loop {
        let text = std::fs::read_to_string(&rec).unwrap_or_default();
        if text
            .lines()
            .filter(|l| l.ends_with(",grasp") || l.ends_with(",pre"))
            .count()
            == 100
        {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "rows not flushed:\n{text}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let unfinished = read_recording(&rec, &LabelConfig::default()).unwrap();
    assert!(!unfinished.extra.contains_key("monitor_stats"));
    // Ctrl-C.
    let st = Process::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "monitor ignores Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(status.success(), "{err}");
    assert!(err.contains("unknown command `bogus`"), "{err}");
    let t = read_recording(&rec, &LabelConfig::default()).unwrap();
    assert_eq!(t.n_steps(), 100);
    assert_eq!(t.marks.grasp_start, Some(10));
    assert!(t.extra["monitor_stats"].contains("lost=0"), "{:?}", t.extra);
    assert_eq!(t.extra["monitor_model_crc"], "0x12345678");
    assert_eq!(std::fs::read(&raw).unwrap(), sent);
    drop(slave);
    std::fs::remove_dir_all(&dir).ok();
}
