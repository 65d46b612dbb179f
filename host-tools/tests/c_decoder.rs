//! The C decoder (`host-tools/c/slipguard_protocol.h`) against the Rust one: compiled with the
//! system C compiler (`cc`, strict C99), run on the golden frames the core's tests pin, on the
//! whole replay stream of the recorded trial (identical to the QEMU build's output), on a
//! corrupted-blob stream and on streams with random damage; its field-by-field output must be
//! the Rust decoder's, error codes included.
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use slipguard_app::profile::Profile;
use slipguard_app::replay::{self as fw, CHEEZ_TRIAL, cheez_script};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{
    self, Command as Cmd, Deframer, Frame, MAX_WIRE, Message, ReplyBody,
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
                .map(|p| p.to_string())
                .collect();
            format!(
                "flags seq={s} t={} st={} n={} unst={} fault={} ovr={} skip={} p={}",
                x.timestamp_us,
                x.status,
                x.channels,
                x.unstable,
                x.fault,
                x.overruns,
                x.skipped,
                p.join(",")
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
                        i.sample_rate_mhz,
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

/// The wire bytes pinned by `slipguard_core::protocol::tests::golden_bytes` (and quoted in
/// docs/protocol.md).
const GOLDEN: [&str; 6] = [
    "080101341240420f04010402020402010101027805ff7fffff06403e8f902000",
    "0401100709efbeadde82cc4de800",
    "0401130809cd4c02038eaa754500",
    "040111090577cade5500",
    "0401900302070109efbeadde8d5b96ac00",
    "03010201010101010b0105443322115e830dd000",
];

#[test]
fn golden_frames_field_by_field() {
    let stream: Vec<u8> = GOLDEN.iter().flat_map(|h| hex(h)).collect();
    let c = run_c(&[], &stream);
    // Independent expectations, from docs/protocol.md's field tables.
    let want = "flags seq=4660 t=1000000 st=1 n=4 unst=2 fault=4 ovr=1 skip=0 p=120,32767,65535,16384\n\
                ping seq=7 token=3735928559\n\
                set_threshold seq=8 thr=19661 raise=2 clear=3\n\
                grasp_start seq=9\n\
                reply seq=3 type=144 rseq=7 status=0 token=3735928559\n\
                fault seq=0 t=0 code=1 detail=5 value=287454020\n";
    assert_eq!(c, want);
    assert_eq!(rust_lines(&stream), want);
    // Encoding commands and the CRC check value.
    let enc = run_c(&["--encode"], &[]);
    assert_eq!(
        enc,
        format!(
            "{}\n{}\n{}\ncrc=cbf43926\n",
            GOLDEN[1], GOLDEN[2], GOLDEN[3]
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
