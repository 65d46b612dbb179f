//! `slipguard-export upload`'s link logic against the firmware's own upload code over a
//! simulated flash, with the flag stream running, damaged frames and lost replies.

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::time::Duration;

use slipguard_app::app::App;
use slipguard_app::frontend::FrameInput;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{self, Outcome, SimFlash, Uploader};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::protocol::{self, Deframer, MAX_WIRE, msg_type, upload_code};
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
            let mut flash = SimFlash::new(&mut self.s0, &mut self.s1);
            let app = self.app.as_mut().unwrap();
            let (reply, outcome) = self.up.handle(app, &mut flash, r);
            if let Outcome::Reload(a) = outcome {
                let blob = leak(upload::blob(&flash, Some(a)));
                let app = self.app.take().unwrap();
                self.app = Some(app.reload(blob));
            }
            if !self.lose_reply.contains(&this) {
                self.push_out(&reply);
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
    assert_eq!(u.info.sample_rate_mhz, 40_000);
    let mut dev = link.into_inner();
    let booted = upload::select(&SimFlash::new(&mut dev.s0, &mut dev.s1), &Profile::HAND);
    assert_eq!(booted.map(|a| (a.slot, a.seq)), Some((0, 1)));
}

#[test]
fn upload_cli_resumes_after_a_damaged_frame_and_a_lost_reply() {
    let mut dev = Device::new();
    // Frame 0 is release, 1 begin, 2.. chunks.
    dev.damage = vec![5, 300];
    dev.lose_reply = vec![9, 200];
    let mut link = Link::new(dev);
    let u = link.upload(NEW, &opts(true), |_, _| {}).unwrap();
    assert_eq!((u.slot, u.seq), (0, 1));
    assert!(u.resent >= 4, "resent {}", u.resent);
    assert_eq!(u.info.sample_rate_mhz, 40_000);
}

fn refused(dev: Device, blob: &[u8], release: bool) -> (UploadError, String) {
    let mut link = Link::new(dev);
    let e = link.upload(blob, &opts(release), |_, _| {}).unwrap_err();
    let msg = e.to_string();
    (e, msg)
}

#[test]
fn upload_cli_refusals_say_what_to_fix() {
    let (e, msg) = refused(Device::new(), NEW, false);
    assert!(matches!(
        e,
        UploadError::Refused {
            code: upload_code::ARMED,
            ..
        }
    ));
    assert!(msg.contains("send release first"), "{msg}");
    assert_eq!(e.exit_code(), 14);
    let (e, msg) = refused(Device::new(), SUCTION, true);
    assert!(matches!(
        e,
        UploadError::Refused {
            code: upload_code::RATE_MISMATCH,
            value: 71_000,
            ..
        }
    ));
    assert!(
        msg.contains("71.0 Hz") && msg.contains("train and export"),
        "{msg}"
    );
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
