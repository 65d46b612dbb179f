//! `slipguard-export upload`'s link logic against the firmware's own upload code over a
//! simulated flash, with the flag stream running, damaged frames and lost replies.

use slipguard_core::units::Millihertz;
use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::time::Duration;

use slipguard_app::app::App;
use slipguard_app::frontend::FrameInput;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{self, Outcome, SimFlash, Uploader};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model_ram::{MODEL_RAM_BYTES, ModelRam};
use slipguard_core::protocol::{self, Command, Deframer, Frame, MAX_WIRE, Message, msg_type};
use slipguard_export::upload::{Link, Options, UploadError};

const FACTORY: &[u8] = include_bytes!("../../firmware/core/tests/fixtures/bench/model.bin");
const NEW: &[u8] = include_bytes!("../../models/hand-force-40hz/hand-force-40hz.bin");
const SUCTION: &[u8] = include_bytes!("../../models/suction/suction.bin");
const SLOT_WORDS: usize = 128 * 1024 / 4;

/// The board: app, uploader and two flash slots behind a byte pipe.
struct Device {
    s0: Vec<u32>,
    s1: Vec<u32>,
    app: Option<App<'static>>,
    up: Uploader,
    rx: Deframer,
    out: VecDeque<u8>,
    frames_in: usize,
    /// Incoming frame indices whose 10th byte is flipped on the wire.
    damage: Vec<usize>,
    /// Incoming frame indices whose reply is lost.
    lose_reply: Vec<usize>,
    /// Incoming frame indices before which the hand controller starts a grasp (armed) or
    /// releases.
    grasp_at: Vec<usize>,
    release_at: Vec<usize>,
    /// Incoming frames lost while the board restarts after a commit.
    restart_frames: usize,
    restarting: usize,
    index: u32,
}

fn leak(b: &[u8]) -> &'static [u8] {
    Box::leak(Box::new(AlignedBlob::new(b))).as_bytes()
}

impl Device {
    fn new() -> Self {
        let s0 = vec![u32::MAX; SLOT_WORDS];
        let mut s1 = vec![u32::MAX; SLOT_WORDS];
        let b = AlignedBlob::new(FACTORY);
        let w: &[u32] = bytemuck::cast_slice(b.as_bytes());
        s1[..w.len()].copy_from_slice(w);
        let active = upload::select(
            &SimFlash::new(&mut s0.clone(), &mut s1.clone()),
            &Profile::HAND,
        );
        assert_eq!(active.map(|a| a.slot), Some(1));
        let app = App::new(Profile::HAND, leak(FACTORY));
        Self {
            s0,
            s1,
            app: Some(app),
            up: Uploader::new(active),
            rx: Deframer::new(),
            out: VecDeque::new(),
            frames_in: 0,
            damage: vec![],
            lose_reply: vec![],
            grasp_at: vec![],
            release_at: vec![],
            restart_frames: 2,
            restarting: 0,
            index: 0,
        }
    }

    fn push_out(&mut self, f: &protocol::Frame) {
        let mut w = [0u8; MAX_WIRE];
        let n = protocol::encode(f, &mut w);
        self.out.extend(&w[..n]);
    }
}

impl Write for Device {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut bytes = buf.to_vec();
        if self.damage.contains(&self.frames_in) && bytes.len() > 10 {
            bytes[10] ^= 0x04;
        }
        let this = self.frames_in;
        for b in bytes {
            let Some(r) = self.rx.push_decode(b) else {
                continue;
            };
            self.frames_in += 1;
            if self.restarting > 0 {
                // The board is restarting: nothing is received.
                self.restarting -= 1;
                continue;
            }
            let app = self.app.as_mut().unwrap();
            for (at, c) in [
                (&self.grasp_at, Command::GraspStart),
                (&self.release_at, Command::Release),
            ] {
                if at.contains(&this) {
                    app.handle(Ok(Frame {
                        seq: 0,
                        msg: Message::Command(c),
                    }));
                }
            }
            let mut flash = SimFlash::new(&mut self.s0, &mut self.s1);
            let (reply, outcome) = self.up.handle(app, &mut flash, r);
            if !self.lose_reply.contains(&this) {
                let mut w = [0u8; MAX_WIRE];
                let n = protocol::encode(&reply, &mut w);
                self.out.extend(&w[..n]);
            }
            if let Outcome::Reload(a) = outcome {
                // The board restarts onto the new slot, as it boots: armed, a new uploader.
                assert!(!app.armed(), "a restart during a grasp");
                let ram: &'static mut ModelRam<MODEL_RAM_BYTES> =
                    Box::leak(Box::new(ModelRam::new()));
                let blob = leak(upload::blob(&flash, Some(a)));
                let (bytes, _) = upload::load(ram, blob);
                self.app = Some(App::new(Profile::HAND, bytes));
                self.up = Uploader::new(upload::select(&flash, &Profile::HAND));
                assert_eq!(self.up.active(), Some(a));
                self.restarting = self.restart_frames;
                self.rx = Deframer::new();
                break;
            }
        }
        // The flag stream goes on meanwhile.
        let input = FrameInput {
            index: self.index,
            value_q4: [124 << 4; 16],
            fault: 0,
            kinds: [0; 16],
        };
        self.index += 1;
        if let Some(f) = self.app.as_mut().unwrap().frame(&input, false) {
            self.push_out(&f);
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Read for Device {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.out.is_empty() {
            return Err(io::ErrorKind::TimedOut.into());
        }
        let n = buf.len().min(self.out.len()).min(7); // the UART delivers in pieces
        for b in buf.iter_mut().take(n) {
            *b = self.out.pop_front().unwrap();
        }
        Ok(n)
    }
}

fn opts(release: bool) -> Options {
    Options {
        release,
        timeout: Duration::from_millis(20),
        erase_timeout: Duration::from_millis(50),
        retries: 5,
        wait_armed: Duration::from_millis(200),
        restart_timeout: Duration::from_secs(2),
    }
}

#[test]
fn upload_cli_makes_the_new_model_active() {
    let mut link = Link::new(Device::new());
    let mut last = 0;
    let u = link
        .upload(NEW, &opts(true), |done, total| {
            assert!(done > last && total == NEW.len());
            last = done;
        })
        .unwrap();
    assert_eq!(last, NEW.len());
    assert_eq!((u.slot, u.seq), (0, 1));
    // The simulated device answers at once, but the test's 20 ms reply timeout can lapse on a
    // loaded host (the device runs the model in debug code for every frame it receives), so a
    // few resends may happen; they must stay within the retries.
    assert!(u.resent <= opts(true).retries, "resent {}", u.resent);
    assert_eq!(u.info.sample_rate_mhz, Millihertz(40_000));
    let mut dev = link.into_inner();
    let booted = upload::select(&SimFlash::new(&mut dev.s0, &mut dev.s1), &Profile::HAND);
    assert_eq!(booted.map(|a| (a.slot, a.seq)), Some((0, 1)));
}

#[test]
fn upload_cli_resumes_after_a_damaged_frame_and_a_lost_reply() {
    let mut dev = Device::new();
    // Frame 0 is release, 1 info, 2 begin, 3.. chunks.
    dev.damage = vec![5, 300];
    dev.lose_reply = vec![9, 200];
    let mut link = Link::new(dev);
    let u = link.upload(NEW, &opts(true), |_, _| {}).unwrap();
    assert_eq!((u.slot, u.seq), (0, 1));
    assert!(u.resent >= 4, "resent {}", u.resent);
    assert_eq!(u.info.sample_rate_mhz, Millihertz(40_000));
}

fn refused(dev: Device, blob: &[u8], release: bool) -> (UploadError, String) {
    let mut link = Link::new(dev);
    let e = link.upload(blob, &opts(release), |_, _| {}).unwrap_err();
    let msg = e.to_string();
    (e, msg)
}

#[test]
fn upload_cli_refusals_say_what_to_fix() {
    // Armed since boot and no --release: nothing written after the wait, and the message says
    // how to go on.
    let (e, msg) = refused(Device::new(), NEW, false);
    assert!(
        matches!(e, UploadError::Armed { stored: false, waited } if waited >= opts(false).wait_armed),
        "{e:?}"
    );
    assert!(
        msg.contains("nothing written") && msg.contains("--release"),
        "{msg}"
    );
    assert_eq!(e.exit_code(), 14);
    // The wrong profile's model: the board's own check, before anything is written.
    let mut link = Link::new(Device::new());
    let e = link.upload(SUCTION, &opts(true), |_, _| {}).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, UploadError::WrongBoard(_)), "{e:?}");
    assert!(
        msg.contains("71.0 Hz")
            && msg.contains("16.7 Hz or 40.0 Hz")
            && msg.contains("nothing written"),
        "{msg}"
    );
    assert_eq!(e.exit_code(), 14);
    assert_eq!(link.into_inner().frames_in, 2, "release and info only");
    // Not a blob: refused locally, nothing sent.
    let mut link = Link::new(Device::new());
    let e = link
        .upload(&[1, 2, 3, 4], &opts(true), |_, _| {})
        .unwrap_err();
    assert_eq!(e.exit_code(), 12);
    assert!(link.into_inner().frames_in == 0);
    // Every code has its own line.
    let lines: Vec<String> = (1..=13)
        .map(|c| slipguard_export::upload::refusal_hint(c, 0, 0))
        .collect();
    for (i, l) in lines.iter().enumerate() {
        assert!(l.contains(": ") && !l.contains('\n'), "{l}");
        assert_eq!(
            lines.iter().filter(|m| *m == l).count(),
            1,
            "code {}",
            i + 1
        );
    }
    assert_eq!(msg_type::UPLOAD_COMMIT, 0x19);
}

#[test]
fn upload_cli_without_a_device_times_out() {
    struct Silent;
    impl Read for Silent {
        fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
            Err(io::ErrorKind::TimedOut.into())
        }
    }
    impl Write for Silent {
        fn write(&mut self, b: &[u8]) -> io::Result<usize> {
            Ok(b.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }
    let mut link = Link::new(Silent);
    let e = link.upload(NEW, &opts(false), |_, _| {}).unwrap_err();
    assert!(matches!(e, UploadError::NoReply { .. }));
    assert!(e.to_string().contains("check the cable"));
    assert_eq!(e.exit_code(), 3);
}

/// A grasp starts during the upload: the chunks go on, the commit is refused as armed and
/// asked again until the hand controller releases; then the board restarts (the info requests
/// meanwhile go unanswered) and runs the new model.
#[test]
fn upload_cli_waits_for_the_release_before_the_commit() {
    let mut dev = Device::new();
    let chunks = NEW.len().div_ceil(protocol::MAX_CHUNK);
    // Frames: 0 release, 1 info, 2 begin, 3.. chunks, then the commit (refused twice).
    let commit = 3 + chunks;
    dev.grasp_at = vec![100];
    dev.release_at = vec![commit + 2];
    dev.restart_frames = 3;
    let mut link = Link::new(dev);
    let mut o = opts(true);
    o.wait_armed = Duration::from_secs(30);
    let u = link.upload(NEW, &o, |_, _| {}).unwrap();
    assert_eq!((u.slot, u.seq), (0, 1));
    assert!(u.waited_armed > Duration::ZERO);
    assert_eq!(u.info.sample_rate_mhz, Millihertz(40_000));
    let mut dev = link.into_inner();
    let booted = upload::select(&SimFlash::new(&mut dev.s0, &mut dev.s1), &Profile::HAND);
    assert_eq!(booted.map(|a| (a.slot, a.seq)), Some((0, 1)));
}

/// Armed through the whole wait: the blob is stored but not committed, the old model runs on,
/// and the message says so.
#[test]
fn upload_cli_armed_at_the_commit_leaves_the_old_model() {
    let mut dev = Device::new();
    dev.grasp_at = vec![100];
    let (e, msg) = refused(dev, NEW, true);
    assert!(
        matches!(e, UploadError::Armed { stored: true, .. }),
        "{e:?}"
    );
    assert!(
        msg.contains("not committed") && msg.contains("old model"),
        "{msg}"
    );
    assert_eq!(e.exit_code(), 14);
}

/// `slipguard-export upload` checks the file before it opens the port: a file that is no blob,
/// or a RAM image, is refused as such (exit 12) with a port that does not exist.
#[test]
fn upload_cli_checks_the_blob_before_the_port() {
    let dir = std::env::temp_dir().join(format!("slipguard-upload-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let junk = dir.join("junk.bin");
    std::fs::write(&junk, [7u8; 100]).unwrap();
    let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
    let image = dir.join("image.bin");
    std::fs::write(&image, ram.load(AlignedBlob::new(NEW).as_bytes()).unwrap()).unwrap();
    for (file, says) in [(&junk, "not a slipguard model blob"), (&image, "RAM image")] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_slipguard-export"))
            .args([
                "upload",
                file.to_str().unwrap(),
                "--port",
                "/nonexistent/tty",
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(12), "{err}");
        assert!(
            err.contains(says) && err.contains(file.to_str().unwrap()),
            "{err}"
        );
        assert!(
            !err.contains("/nonexistent"),
            "the port was opened first: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
