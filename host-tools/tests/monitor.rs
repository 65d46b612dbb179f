//! The flag-stream monitor: loss and corruption counts on a stream with known damage, the golden
//! frame decoded field by field, and the `slipguard monitor` binary reading a pseudo terminal.
use slipguard_core::units::Millihertz;
use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use slipguard::monitor::{Event, Monitor};
use slipguard_core::protocol::{self, Flags, Frame, MAX_WIRE, Message, P_NONE, PUnstable, status};

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// The golden flag frame pinned by `slipguard_core::protocol::tests::golden_bytes` (copied
/// here as bytes; the expected fields are those of docs/protocol.md's example).
const GOLDEN_FLAGS: &str = "080101341240420f04010402020402010101027805ff7fffff06403e8f902000";

/// COBS encoding with the delimiter (written here independently of the `cobs` crate).
fn cobs(payload: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8];
    let mut code_at = 0;
    for &b in payload {
        if b == 0 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
        } else {
            out.push(b);
            if out.len() - code_at == 0xFF {
                out[code_at] = 0xFF;
                code_at = out.len();
                out.push(0);
            }
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out.push(0);
    out
}

/// COBS decoding of one frame (delimiter excluded), the inverse of [`cobs`].
fn uncobs(wire: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < wire.len() {
        let code = wire[i] as usize;
        out.extend_from_slice(&wire[i + 1..i + code]);
        i += code;
        if code < 0xFF && i < wire.len() {
            out.push(0);
        }
    }
    out
}

/// The frame's payload with one bit of the body flipped, re-encoded: a bad CRC.
fn with_flipped_bit(wire: &[u8], byte: usize) -> Vec<u8> {
    let mut p = uncobs(&wire[..wire.len() - 1]);
    p[byte] ^= 0x08;
    cobs(&p)
}

fn flag_frame(seq: u16) -> Vec<u8> {
    let mut p = [0u16; 16];
    for (c, v) in p.iter_mut().enumerate() {
        *v = (seq * 100 + c as u16 * 7) % 32768;
    }
    let f = Frame {
        seq,
        msg: Message::Flags(Flags {
            timestamp_us: (seq as u32 + 1) * 59_880,
            status: status::ARMED,
            channels: 16,
            unstable: if seq.is_multiple_of(5) { 0b11 } else { 0 },
            fault: 0,
            overruns: 0,
            skipped: 0,
            p: p.map(|b| PUnstable::from_bits(b).unwrap()),
        }),
    };
    let mut b = [0u8; MAX_WIRE];
    let n = protocol::encode(&f, &mut b);
    b[..n].to_vec()
}

/// 30 flag frames (seq 0..30) with damage: line noise with a delimiter before frame 2 (a corrupt
/// run, nothing lost), noise without a delimiter glued to frame 5 (frame 5 corrupt and lost),
/// a flipped bit in frame 9 (bad CRC, lost), frame 14 missing (lost, not corrupt), 300 bytes
/// without a delimiter before frame 20 (too long, frame 20 lost), frame 25 cut short (lost).
fn damaged_stream() -> (Vec<u8>, Vec<u16>) {
    let mut s = Vec::new();
    let mut intact = Vec::new();
    for seq in 0..30u16 {
        let mut f = flag_frame(seq);
        match seq {
            2 => s.extend_from_slice(&[0x55, 0xAA, 0x13, 0x00]),
            5 => s.extend_from_slice(&[0x42, 0x42, 0x42]),
            9 => f = with_flipped_bit(&f, 10),
            14 => continue,
            20 => s.extend(std::iter::repeat_n(0x77u8, 300)),
            25 => {
                let n = f.len();
                f.drain(n - 6..n - 1);
            }
            _ => {}
        }
        if ![5, 9, 20, 25].contains(&seq) {
            intact.push(seq);
        }
        s.extend_from_slice(&f);
    }
    (s, intact)
}

#[test]
fn counts_lost_and_corrupt_frames_and_resynchronises() {
    let (stream, intact) = damaged_stream();
    // Any chunking gives the same result.
    for chunk in [1usize, 7, 64, 4096] {
        let mut m = Monitor::new();
        let mut seqs = Vec::new();
        let mut gaps = Vec::new();
        for c in stream.chunks(chunk) {
            m.push(c, |e| {
                if let Event::Frame { frame, lost } = e {
                    seqs.push(frame.seq);
                    if *lost > 0 {
                        gaps.push((frame.seq, *lost));
                    }
                }
            });
        }
        assert_eq!(seqs, intact, "chunk {chunk}");
        assert_eq!(gaps, vec![(6, 1), (10, 1), (15, 1), (21, 1), (26, 1)]);
        let s = &m.stats;
        assert_eq!(s.flags, 25);
        assert_eq!(s.lost, 5);
        // Corrupt runs: noise before 2, frame 5, frame 9, the 300-byte run (+ frame 20
        // swallowed by it: the deframer drops up to the next delimiter), frame 25.
        assert_eq!(s.corrupt, 5, "{s:?}");
        assert_eq!(s.corrupt_crc, 1, "{s:?}"); // frame 9
        assert_eq!(s.corrupt_too_long, 1);
        assert_eq!(s.bytes, stream.len() as u64);
        // Every frame that arrived intact is bit-identical to what was sent.
        for r in &m.received {
            let mut b = [0u8; MAX_WIRE];
            let n = protocol::encode(
                &Frame {
                    seq: r.seq,
                    msg: Message::Flags(r.flags),
                },
                &mut b,
            );
            assert_eq!(&b[..n], &flag_frame(r.seq)[..]);
        }
        assert_eq!(m.rate_mhz(), Some(Millihertz(16_700)));
        // The recording has a row per frame index, lost rows marked.
        let t = m.to_trial("t").unwrap();
        assert_eq!(t.n_steps(), 30);
        let lost_col = t.channel_names.iter().position(|n| n == "lost").unwrap();
        let lost: Vec<usize> = (0..30).filter(|&k| t.samples[lost_col][k] == 1.0).collect();
        assert_eq!(lost, vec![5, 9, 14, 20, 25]);
        let labels = t.step_labels.as_ref().unwrap();
        assert_eq!(labels[10].unwrap().code(), 1);
        assert_eq!(labels[11].unwrap().code(), 0);
        assert!(labels[5].is_none());
        assert!((t.samples[1][3] - (300.0 + 7.0) / 32768.0).abs() < 1e-7);
    }
}

#[test]
fn golden_flag_frame_field_by_field() {
    let mut m = Monitor::new();
    m.push(&hex(GOLDEN_FLAGS), |_| {});
    let f = m.last_flags.expect("decoded");
    assert_eq!(m.received[0].seq, 0x1234);
    assert_eq!(f.timestamp_us, 1_000_000);
    assert_eq!(f.status, status::ARMED);
    assert_eq!(f.channels, 4);
    assert_eq!(f.unstable, 0b0010);
    assert_eq!(f.fault, 0b0100);
    assert_eq!((f.overruns, f.skipped), (1, 0));
    let bits: Vec<u16> = f.p[..4].iter().map(|p| p.to_bits()).collect();
    assert_eq!(bits, [120, 32767, P_NONE, 16384]);
    let view = m.view();
    assert!(view.contains("c1  UNSTABLE p=1.000"), "{view}");
    assert!(view.contains("c2  FAULT"), "{view}");
    assert!(!view.contains("HAND"), "{view}");
    // The same frame with a bit flipped is a corrupt run, not a frame.
    let good = hex(GOLDEN_FLAGS);
    assert_eq!(cobs(&uncobs(&good[..good.len() - 1])), good);
    let bad = with_flipped_bit(&good, 6);
    let mut m = Monitor::new();
    m.push(&bad, |_| {});
    assert_eq!(
        (m.stats.frames, m.stats.corrupt, m.stats.corrupt_crc),
        (0, 1, 1)
    );
}

/// `slipguard monitor --port` on the slave side of a pseudo-terminal pair; the test writes the
/// damaged stream into the master side.
#[test]
fn monitor_binary_reads_a_pseudo_terminal() {
    let (mut master, slave) = serialport::TTYPort::pair().expect("openpty");
    let name = serialport::SerialPort::name(&slave).expect("slave path");
    let dir = std::env::temp_dir().join(format!("slipguard-monitor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rec = dir.join("mon.csv");
    let mut child = Command::new(env!("CARGO_BIN_EXE_slipguard"))
        .args([
            "monitor", "--port", &name, "--baud", "921600", "--frames", "25",
        ])
        .args(["--view", "lines", "--seconds", "20", "--record"])
        .arg(&rec)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until it has opened the port.
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    assert!(line.contains("reading"), "{line}");
    let (stream, _) = damaged_stream();
    for c in stream.chunks(50) {
        master.write_all(c).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    master.flush().unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(t0.elapsed() < Duration::from_secs(25), "monitor hangs");
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut out = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut out).unwrap();
    assert!(status.success(), "{out}");
    assert!(out.contains("flags=25 "), "{out}");
    assert!(
        out.contains(" corrupt=5 ") && out.contains(" lost=5 "),
        "{out}"
    );
    assert!(
        out.contains("seq     6 flags") && out.contains("(1 lost before)"),
        "{out}"
    );
    assert!(out.contains("corrupt run: CRC mismatch"), "{out}");
    let t =
        slipguard_data::recording::parse_recording(&std::fs::read_to_string(&rec).unwrap(), &rec)
            .unwrap();
    assert_eq!(t.n_steps(), 30);
    assert_eq!(t.rate_hz, 16.7);
    drop(slave);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The live view names the hand flag, and says when the blob's hand rule alone raised it
/// (status bit 4, HAND_BY_RULE; docs/protocol.md).
#[test]
fn the_view_shows_the_hand_flag_and_hand_by_rule() {
    let view = |st: u8| {
        let mut flags = Flags {
            timestamp_us: 59_880,
            status: st,
            channels: 2,
            unstable: 0,
            fault: 0,
            overruns: 0,
            skipped: 0,
            p: [PUnstable::NONE; 16],
        };
        flags.p[0] = PUnstable::from_bits(100).unwrap();
        let mut b = [0u8; MAX_WIRE];
        let n = protocol::encode(
            &Frame {
                seq: 1,
                msg: Message::Flags(flags),
            },
            &mut b,
        );
        let mut m = Monitor::new();
        m.push(&b[..n], |_| {});
        m.view()
    };
    let by_model = view(status::ARMED | status::HAND_UNSTABLE);
    assert!(
        by_model.contains("ARMED  HAND UNSTABLE  overruns"),
        "{by_model}"
    );
    let by_rule = view(status::ARMED | status::HAND_UNSTABLE | status::HAND_BY_RULE);
    assert!(
        by_rule.contains("ARMED  HAND UNSTABLE (HAND_BY_RULE)  overruns"),
        "{by_rule}"
    );
    assert!(!view(status::ARMED).contains("HAND"));
}
