//! The C decoder (`host-tools/c/slipguard_protocol.h`) against the Rust one: compiled with the
//! system C compiler (`cc`, strict C99), run on the golden frames the core's tests pin, on the
//! whole replay stream of the recorded trial (identical to the QEMU build's output), on a
//! corrupted-blob stream, on the trial with the sample stream on and on streams with random
//! damage; its field-by-field output must be the Rust decoder's, error codes included.
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self as fw, CHEEZ_TRIAL, ScriptItem, cheez_script};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{
    self, Command as Cmd, Deframer, Frame, MAX_WIRE, Message, ReplyBody, StreamMode,
};

fn driver() -> &'static Path {
    static EXE: OnceLock<PathBuf> = OnceLock::new();
    EXE.get_or_init(|| {
        let c = Path::new(env!("CARGO_MANIFEST_DIR")).join("c");
        let dir = std::env::temp_dir().join(format!("slipguard-c-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let exe = dir.join("test_decode");
        let out = Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
            .args([
                "-std=c99",
                "-O1",
                "-Wall",
                "-Wextra",
                "-Werror",
                "-pedantic",
                "-I",
            ])
            .arg(&c)
            .arg(c.join("test_decode.c"))
            .arg("-o")
            .arg(&exe)
            .output()
            .expect("running the system C compiler `cc`");
        assert!(
            out.status.success(),
            "cc failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        exe
    })
}

fn run_c(args: &[&str], input: &[u8]) -> String {
    let mut child = Command::new(driver())
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(input).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

/// The Rust decoder's view of a frame, in the C driver's format.
fn line(f: &Frame) -> String {
    let s = f.seq;
    match f.msg {
        Message::Flags(x) => {
            let p: Vec<String> = x.p[..x.channels as usize]
                .iter()
                .map(|p| p.to_bits().to_string())
                .collect();
            format!(
                "flags seq={s} t={} st={} n={} unst={} fault={} ovr={} skip={} p={} hand={} rule={} contact={}",
                x.timestamp_us,
                x.status,
                x.channels,
                x.unstable,
                x.fault,
                x.overruns,
                x.skipped,
                p.join(","),
                x.hand_unstable() as u8,
                x.hand_by_rule() as u8,
                x.contact()
            )
        }
        Message::Samples(x) => {
            let v: Vec<String> = x.value[..x.channels as usize]
                .iter()
                .map(|v| v.to_string())
                .collect();
            format!(
                "samples seq={s} t={} st={} marks={} n={} unit={} fault={} v={}",
                x.timestamp_us,
                x.status,
                x.marks,
                x.channels,
                x.unit,
                x.fault,
                v.join(",")
            )
        }
        Message::Fault(x) => format!(
            "fault seq={s} t={} code={} detail={} value={}",
            x.timestamp_us, x.code, x.detail, x.value
        ),
        Message::Error(x) => format!(
            "error seq={s} error={} type={} rseq={}",
            x.error, x.msg_type, x.request_seq
        ),
        Message::Command(c) => match c {
            Cmd::Ping { token } => format!("ping seq={s} token={token}"),
            Cmd::GraspStart => format!("grasp_start seq={s}"),
            Cmd::Release => format!("release seq={s}"),
            Cmd::Info => format!("info seq={s}"),
            Cmd::Lift => format!("lift seq={s}"),
            Cmd::StreamMode(m) => format!("stream_mode seq={s} mode={}", m as u8),
            Cmd::UploadBegin { size, crc } => {
                format!("upload_begin seq={s} size={size} crc={crc}")
            }
            Cmd::UploadChunk(c) => format!(
                "upload_chunk seq={s} offset={} len={} crc={}",
                c.offset, c.len, c.crc
            ),
            Cmd::UploadCommit => format!("upload_commit seq={s}"),
            Cmd::SetThreshold {
                threshold_q15,
                raise_after,
                clear_after,
            } => format!(
                "set_threshold seq={s} thr={threshold_q15} raise={raise_after} clear={clear_after}"
            ),
        },
        Message::Reply(r) => {
            let head = format!(
                "reply seq={s} type={} rseq={} status={}",
                r.body.msg_type(),
                r.request_seq,
                r.status as u8
            );
            match r.body {
                ReplyBody::Pong { token } => format!("{head} token={token}"),
                ReplyBody::StreamMode(m) => format!("{head} mode={}", m as u8),
                ReplyBody::Upload {
                    code,
                    detail,
                    slot,
                    value,
                    ..
                } => format!("{head} code={code} detail={detail} slot={slot} value={value}"),
                ReplyBody::ThresholdSet {
                    threshold_q15,
                    raise_after,
                    clear_after,
                } => format!("{head} thr={threshold_q15} raise={raise_after} clear={clear_after}"),
                ReplyBody::Info(i) => {
                    let name: String = i
                        .name
                        .iter()
                        .take_while(|&&b| b != 0)
                        .map(|&b| b as char)
                        .collect();
                    format!(
                        "{head} fw={}.{}.{} profile={} n={} os={} ok={} variant={} hidden={} id={} \
                         crc={} rate={} thr={} raise={} clear={} name={name}",
                        i.firmware[0],
                        i.firmware[1],
                        i.firmware[2],
                        i.profile,
                        i.channels,
                        i.oversample,
                        i.model_ok,
                        i.variant,
                        i.hidden,
                        i.model_id,
                        i.model_crc,
                        i.sample_rate_mhz.0,
                        i.threshold_q15,
                        i.raise_after,
                        i.clear_after
                    )
                }
                _ => head,
            }
        }
    }
}

/// The Rust deframer + decoder over a stream, one line per run.
fn rust_lines(stream: &[u8]) -> String {
    let mut d = Deframer::new();
    let mut s = String::new();
    for &b in stream {
        match d.push_decode(b) {
            Some(Ok(f)) => s += &(line(&f) + "\n"),
            Some(Err((e, _))) => s += &format!("bad {}\n", e.code()),
            None => {}
        }
    }
    s
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// The wire bytes pinned by `slipguard_core::protocol::tests::golden_bytes`,
/// `golden_bytes_samples_and_upload` and `golden_bytes_hand_flag` (and quoted in
/// docs/protocol.md).
const GOLDEN: [&str; 14] = [
    "080101341240420f04010402020402010101027805ff7fffff06403e8f902000",
    "0401100709efbeadde82cc4de800",
    "0401130809cd4c02038eaa754500",
    "040111090577cade5500",
    "0401900302070109efbeadde8d5b96ac00",
    "03010201010101010b0105443322115e830dd000",
    "0701040201a861010401030402080101010103dc05010728fbffff1e9b01055235fd1e00",
    "0401160a0601ae63a0f400",
    "0401150b022903e16000",
    "0401170c043c3a0109efcdab8996de50a600",
    "0401180d028001010653474d4201020209c777582428bd968500",
    "0401190e05080d8c1400",
    "04019805020d0301040101020101050b7aa05600",
    "040101420480841e040904010208010102020d0852a00fffffffffcba393b400",
];

#[test]
fn golden_frames_field_by_field() {
    let stream: Vec<u8> = GOLDEN.iter().flat_map(|h| hex(h)).collect();
    let c = run_c(&[], &stream);
    // Independent expectations, from docs/protocol.md's field tables.
    let want = "flags seq=4660 t=1000000 st=1 n=4 unst=2 fault=4 ovr=1 skip=0 p=120,32767,65535,16384 hand=0 rule=0 contact=11\n\
                ping seq=7 token=3735928559\n\
                set_threshold seq=8 thr=19661 raise=2 clear=3\n\
                grasp_start seq=9\n\
                reply seq=3 type=144 rseq=7 status=0 token=3735928559\n\
                fault seq=0 t=0 code=1 detail=5 value=287454020\n\
                samples seq=258 t=25000 st=1 marks=3 n=4 unit=0 fault=8 v=0,1500,-1240,39710\n\
                stream_mode seq=10 mode=1\n\
                lift seq=11\n\
                upload_begin seq=12 size=80444 crc=2309737967\n\
                upload_chunk seq=13 offset=128 len=8 crc=609777607\n\
                upload_commit seq=14\n\
                reply seq=5 type=152 rseq=13 status=1 code=4 detail=0 slot=0 value=256\n\
                flags seq=66 t=2000000 st=9 n=4 unst=1 fault=8 ovr=0 skip=2 p=21000,4000,65535,65535 hand=1 rule=0 contact=3\n";
    assert_eq!(c, want);
    assert_eq!(rust_lines(&stream), want);
    // Encoding commands and the CRC check value.
    let enc = run_c(&["--encode"], &[]);
    assert_eq!(
        enc,
        format!(
            "{}\n{}\n{}\n{}\n{}\ncrc=cbf43926\n",
            GOLDEN[1], GOLDEN[2], GOLDEN[3], GOLDEN[7], GOLDEN[8]
        )
    );
}

#[test]
fn replay_streams_decode_identically() {
    let golden = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/core/tests/fixtures/bench/model.bin"),
    )
    .unwrap();
    let mut corrupt = golden.clone();
    corrupt[5000] ^= 0x10;
    for (name, blob) in [("golden", golden), ("corrupt", corrupt)] {
        let blob = AlignedBlob::new(&blob);
        let mut stream = Vec::new();
        fw::run(
            Profile::HAND,
            blob.as_bytes(),
            &CHEEZ_TRIAL,
            cheez_script::SCRIPT,
            cheez_script::OPEN_WIRES,
            |b| stream.extend_from_slice(b),
        );
        let c = run_c(&[], &stream);
        let r = rust_lines(&stream);
        assert_eq!(c, r, "{name}");
        assert!(!c.contains("bad"), "{name}");
        let flags = c.lines().filter(|l| l.starts_with("flags")).count();
        let faults = c.lines().filter(|l| l.starts_with("fault")).count();
        match name {
            "golden" => {
                assert_eq!((c.lines().count(), flags), (408, 400));
                assert!(c.contains(" fault=16384 ")); // channel 14's open wire
                assert!(c.contains("name=test"));
            }
            _ => assert!(flags == 0 && faults > 0),
        }
    }
}

/// The recorded trial with the sample stream on (stream mode, grasp start, lift, release):
/// every samples frame decodes in C as in Rust, marks included.
#[test]
fn sample_stream_decodes_identically() {
    let golden = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/core/tests/fixtures/bench/model.bin"),
    )
    .unwrap();
    let blob = AlignedBlob::new(&golden);
    let enc = |seq, c| {
        let mut b = [0u8; MAX_WIRE];
        let n = protocol::encode(
            &Frame {
                seq,
                msg: Message::Command(c),
            },
            &mut b,
        );
        b[..n].to_vec()
    };
    let mode = enc(1, Cmd::StreamMode(StreamMode::FlagsAndSamples));
    let grasp = enc(2, Cmd::GraspStart);
    let lift = enc(3, Cmd::Lift);
    let release = enc(4, Cmd::Release);
    let script = [
        ScriptItem {
            before_frame: 0,
            bytes: &mode,
        },
        ScriptItem {
            before_frame: 52,
            bytes: &grasp,
        },
        ScriptItem {
            before_frame: 87,
            bytes: &lift,
        },
        ScriptItem {
            before_frame: 300,
            bytes: &release,
        },
    ];
    let mut stream = Vec::new();
    fw::run(
        Profile::HAND,
        blob.as_bytes(),
        &CHEEZ_TRIAL,
        &script,
        cheez_script::OPEN_WIRES,
        |b| stream.extend_from_slice(b),
    );
    let c = run_c(&[], &stream);
    assert_eq!(c, rust_lines(&stream));
    let samples: Vec<&str> = c.lines().filter(|l| l.starts_with("samples")).collect();
    assert_eq!(samples.len(), 400);
    assert_eq!(c.lines().filter(|l| l.starts_with("flags")).count(), 400);
    for (mark, n) in [
        (" marks=1 ", 1),
        (" marks=2 ", 1),
        (" marks=4 ", 1),
        (" marks=0 ", 397),
    ] {
        assert_eq!(
            samples.iter().filter(|l| l.contains(mark)).count(),
            n,
            "{mark}"
        );
    }
    assert!(samples.iter().all(|l| l.contains(" n=16 unit=0 ")));
    assert!(samples.iter().any(|l| l.contains(" fault=16384 "))); // channel 14's open wire
    // The longest run either deframer keeps is MAX_WIRE - 1 = 145 bytes (an upload chunk);
    // 145 garbage bytes are a bad frame, 146 an overflow, and both resynchronise.
    assert_eq!(MAX_WIRE, 146);
    let chunk = enc(
        5,
        Cmd::UploadChunk(protocol::Chunk::new(0, &[0x5A; protocol::MAX_CHUNK])),
    );
    assert_eq!(chunk.len(), MAX_WIRE);
    let mut s = chunk.clone();
    for n in [145, 146, 300] {
        s.extend(std::iter::repeat_n(0x11u8, n));
        s.push(0);
        s.extend_from_slice(&chunk);
    }
    let c = run_c(&[], &s);
    assert_eq!(c, rust_lines(&s));
    assert_eq!(
        c.lines().filter(|l| l.starts_with("upload_chunk")).count(),
        4
    );
    assert_eq!(c.lines().filter(|l| *l == "bad 3").count(), 2, "{c}");
}

#[test]
fn damaged_streams_same_errors_and_resync() {
    let golden = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/core/tests/fixtures/bench/model.bin"),
    )
    .unwrap();
    let blob = AlignedBlob::new(&golden);
    let mut clean = Vec::new();
    fw::run(
        Profile::HAND,
        blob.as_bytes(),
        &CHEEZ_TRIAL,
        cheez_script::SCRIPT,
        &[],
        |b| clean.extend_from_slice(b),
    );
    let clean = &clean[..6000];
    let mut x: u32 = 0x9E37_79B9;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x
    };
    for _ in 0..20 {
        let mut s = clean.to_vec();
        for _ in 0..30 {
            let i = next() as usize % s.len();
            match next() % 4 {
                0 => s[i] ^= 1 << (next() % 8),
                1 => {
                    s.remove(i);
                }
                2 => s.insert(i, next() as u8),
                _ => {
                    let run: Vec<u8> = (0..next() % 120).map(|_| next() as u8 | 1).collect();
                    s.splice(i..i, run);
                }
            }
        }
        // Some frames with good CRCs but bad contents.
        for msg in [
            Message::Command(Cmd::SetThreshold {
                threshold_q15: 1000,
                raise_after: 1,
                clear_after: 1,
            }),
            Message::Command(Cmd::Info),
        ] {
            let mut b = [0u8; MAX_WIRE];
            let n = protocol::encode(&Frame { seq: 3, msg }, &mut b);
            s.extend_from_slice(&b[..n]);
        }
        let c = run_c(&[], &s);
        assert_eq!(c, rust_lines(&s));
        assert!(c.contains("bad "));
        assert!(c.lines().filter(|l| l.starts_with("flags")).count() > 50);
    }
}
