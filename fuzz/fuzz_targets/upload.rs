//! Model uploads with power cuts: `Uploader` and `App` over a simulated flash (`SimFlash`), driven
//! by a fuzzer-chosen sequence of begins, chunks (in order, resent, damaged, out of order),
//! commits, grasp starts and releases, power cuts at fuzzer-chosen flash operations and reboots.
//! After every reboot the board must run, on the firmware's boot path (`upload::boot`: slot
//! choice, RAM copy, app over the copy), a model the boot path accepts, and it must be the last
//! one whose commit was answered OK (before any commit, the model the board started with).
//! The start state is the factory slot alone or two committed slots at fuzzer-chosen sequence
//! numbers (the wrap after `u32::MAX` included).
#![no_main]

use slipguard_core::units::Millihertz;
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

use slipguard_app::app::App;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{self, Outcome, SimFlash, TRAILER_LEN, Trailer, Uploader};
use slipguard_core::blob::{AlignedBlob, CRC32, InputUnit};
use slipguard_core::float::FloatModel;
use slipguard_core::model::Model;
use slipguard_core::model_ram::ModelRam;
use slipguard_core::protocol::{Chunk, Command, Frame, MAX_CHUNK, Message, ReplyBody, upload_code};
use slipguard_core::quantize::quantize;

static GOLDEN: &[u8] = include_bytes!("../../firmware/core/tests/fixtures/bench/model.bin");

/// RAM copy size: every blob here and its image fit.
const RAM: usize = 16 * 1024;
const HAND: Profile = Profile::HAND;

/// The blobs a host may send: two hand models (16.7 and 40 Hz), one in counts (refused), the
/// first one's RAM image (refused), it padded and truncated.
struct Blobs {
    all: Vec<AlignedBlob>,
    slot_words: usize,
}

fn blobs() -> &'static Blobs {
    static B: OnceLock<Blobs> = OnceLock::new();
    B.get_or_init(|| {
        let golden = AlignedBlob::new(GOLDEN);
        let base = *Model::from_bytes(golden.as_bytes())
            .expect("golden")
            .config();
        let make = |rate: Millihertz, unit: InputUnit, seed: u64| {
            let mut c = base;
            c.hidden = [8, if c.hidden[1] > 0 { 8 } else { 0 }];
            c.sample_rate_mhz = rate;
            c.input_unit = unit;
            let (bytes, _) =
                quantize(&FloatModel::init_like_pytorch(c, seed), &[], None).expect("quantize");
            bytes
        };
        let a = make(base.sample_rate_mhz, InputUnit::MilliNewton, 1);
        let b = make(Millihertz(40_000), InputUnit::MilliNewton, 2);
        let counts = make(base.sample_rate_mhz, InputUnit::Counts, 3);
        let mut ram = Box::new(ModelRam::<RAM>::new());
        let image = ram
            .load(AlignedBlob::new(&a).as_bytes())
            .expect("image")
            .to_vec();
        let padded = [&a[..], &[0u8; 8]].concat();
        let truncated = a[..a.len() - 8].to_vec();
        let all: Vec<AlignedBlob> = [a, b, counts, image, padded, truncated]
            .iter()
            .map(|x| AlignedBlob::new(x))
            .collect();
        let longest = all.iter().map(|x| x.as_bytes().len()).max().unwrap_or(0);
        // Room for the longest and the trailer, in whole KiB.
        let slot_words = (longest + TRAILER_LEN).div_ceil(1024) * 1024 / 4;
        Blobs { all, slot_words }
    })
}

/// The fingerprint of the model the board runs after a reboot on the firmware's boot path, and
/// the sequence number of its slot; panics if the boot path runs no model.
fn reboot(s0: &mut [u32], s1: &mut [u32]) -> (u32, u32) {
    let flash = SimFlash::new(s0, s1);
    let mut ram = Box::new(ModelRam::<RAM>::new());
    let (active, app) = upload::boot(&flash, HAND, &mut ram);
    let m = app
        .model()
        .unwrap_or_else(|e| panic!("the board boots into a model fault: {e:?} ({active:?})"));
    (m.blob().crc, active.expect("a model without a slot").seq)
}

fn fingerprint(blob: &[u8]) -> u32 {
    Model::from_bytes(blob).expect("a valid blob").blob().crc
}

fn put(slot: &mut [u32], at: usize, bytes: &[u8]) {
    for (w, b) in slot[at / 4..].iter_mut().zip(bytes.chunks_exact(4)) {
        *w = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
    }
}

fuzz_target!(|data: &[u8]| {
    let b = blobs();
    let mut input = data.iter().copied();
    let mut next = move || input.next();
    let mut s0 = vec![u32::MAX; b.slot_words];
    let mut s1 = vec![u32::MAX; b.slot_words];
    let a = b.all[0].as_bytes();
    let second = b.all[1].as_bytes();
    // Start state: the factory blob alone, or two committed slots at a chosen sequence number.
    let mut expected = fingerprint(a);
    put(&mut s1, 0, a);
    if next().unwrap_or(0) & 1 == 1 {
        let seq = u32::from_le_bytes([
            next().unwrap_or(0xFF),
            next().unwrap_or(0xFF),
            next().unwrap_or(0xFF),
            next().unwrap_or(0xFF),
        ]);
        let tail = b.slot_words * 4 - TRAILER_LEN;
        let t = |blob: &[u8], seq: u32| Trailer {
            seq,
            len: blob.len() as u32,
            crc: CRC32.checksum(blob),
        };
        put(&mut s1, tail, &t(a, seq).to_bytes());
        let after = upload::next_seq(upload::select(
            &SimFlash::new(&mut s0.clone(), &mut s1.clone()),
            &HAND,
        ));
        put(&mut s0, 0, second);
        put(&mut s0, tail, &t(second, after).to_bytes());
        expected = fingerprint(second);
    }
    let mut ram = Box::new(ModelRam::<RAM>::new());
    'boot: loop {
        let (running, _) = reboot(&mut s0, &mut s1);
        assert_eq!(
            running, expected,
            "the board runs another model than the last committed"
        );
        let mut flash = SimFlash::new(&mut s0, &mut s1);
        let active = upload::select(&flash, &HAND);
        let bytes: &[u8] = ram.load(upload::blob(&flash, active)).unwrap_or(&[]);
        let mut app = App::new(HAND, bytes);
        assert!(app.model().is_ok());
        let mut up = Uploader::new(active);
        // The blob being sent and the next offset the host would send.
        let mut sending: Option<(usize, usize)> = None;
        let mut seq = 0u16;
        loop {
            let Some(op) = next() else {
                break 'boot;
            };
            let mut cmds: Vec<Command> = Vec::new();
            match op % 16 {
                0 | 1 => {
                    let i = next().unwrap_or(0) as usize % b.all.len();
                    let blob = b.all[i].as_bytes();
                    let size = if op & 0x80 != 0 {
                        (next().unwrap_or(0) as u32) << 4
                    } else {
                        blob.len() as u32
                    };
                    let crc = CRC32.checksum(blob) ^ u32::from(op & 0x40 != 0);
                    sending = Some((i, 0));
                    cmds.push(Command::UploadBegin { size, crc });
                }
                // The next chunk(s) in order: one, or every one left.
                2..=6 => {
                    if let Some((i, at)) = sending {
                        let blob = b.all[i].as_bytes();
                        let end = if op % 16 == 6 {
                            blob.len()
                        } else {
                            (at + MAX_CHUNK).min(blob.len())
                        };
                        let mut o = at;
                        while o < end {
                            let e = (o + MAX_CHUNK).min(blob.len());
                            cmds.push(Command::UploadChunk(Chunk::new(o as u32, &blob[o..e])));
                            o = e;
                        }
                        sending = Some((i, end));
                    }
                }
                // A chunk damaged, misplaced or odd-sized.
                7 => {
                    if let Some((i, at)) = sending {
                        let blob = b.all[i].as_bytes();
                        let len = (next().unwrap_or(0) as usize % MAX_CHUNK + 1)
                            .min(blob.len() - at.min(blob.len()));
                        let from = at.min(blob.len() - len);
                        let mut c = Chunk::new(
                            (from as u32).wrapping_add(u32::from(next().unwrap_or(0) & 7) * 4),
                            &blob[from..from + len],
                        );
                        if op & 0x80 != 0 && len > 0 {
                            c.data[0] ^= 1;
                        }
                        cmds.push(Command::UploadChunk(c));
                    }
                }
                8 | 9 => cmds.push(Command::UploadCommit),
                10 => cmds.push(Command::GraspStart),
                11 | 12 => cmds.push(Command::Release),
                // Power is lost at one of the next flash operations.
                13 | 14 => flash.cut_at = Some(flash.ops + usize::from(next().unwrap_or(0) % 8)),
                _ => continue 'boot,
            }
            for c in cmds {
                seq = seq.wrapping_add(1);
                let (reply, outcome) = up.handle(
                    &mut app,
                    &mut flash,
                    Ok(Frame {
                        seq,
                        msg: Message::Command(c),
                    }),
                );
                let ok = matches!(
                    reply.msg,
                    Message::Reply(r) if matches!(r.body, ReplyBody::Upload { code: upload_code::OK, .. })
                );
                if let (Command::UploadCommit, true) = (c, ok) {
                    let Outcome::Reload(new) = outcome else {
                        panic!("commit answered OK without a new slot");
                    };
                    // The slot holds one of the blobs the host sent, whole.
                    let stored = upload::blob(&flash, Some(new));
                    assert!(b.all.iter().any(|x| x.as_bytes() == stored));
                    expected = fingerprint(stored);
                    // The board restarts onto it.
                    continue 'boot;
                }
                assert_eq!(outcome, Outcome::None);
                if flash.cut() {
                    // The board is off.
                    continue 'boot;
                }
            }
        }
    }
    let (running, _) = reboot(&mut s0, &mut s1);
    assert_eq!(
        running, expected,
        "the board runs another model than the last committed"
    );
});
