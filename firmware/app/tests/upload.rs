//! Model upload into the two flash slots, against a simulated flash: every refusal with its
//! code, resume and restart, and a power cut at every flash operation of an upload (the board
//! must boot a valid model afterwards, the old one until the trailer is written).

use slipguard_app::app::App;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{
    self, Active, FACTORY_SLOT, Flash, Outcome, SimFlash, TRAILER_LEN, Uploader,
};
use slipguard_core::blob::{AlignedBlob, CRC32};
use slipguard_core::protocol::{
    self, Chunk, Command, Deframer, Frame, MAX_CHUNK, MAX_WIRE, Message, P_NONE, ReplyBody,
    ReplyStatus, upload_code,
};

/// 16.7 Hz hand model (the factory model here).
const FACTORY: &[u8] = include_bytes!("../../core/tests/fixtures/bench/model.bin");
/// 40 Hz hand model: the upload.
const NEW: &[u8] = include_bytes!("../../../models/hand-force-40hz/hand-force-40hz.bin");
/// 71 Hz suction model: wrong rate (and unit) for the hand profile.
const SUCTION: &[u8] = include_bytes!("../../../models/suction/suction.bin");
/// One F405 sector.
const SLOT_WORDS: usize = 128 * 1024 / 4;
const HAND: Profile = Profile::HAND;

struct Board {
    s0: Vec<u32>,
    s1: Vec<u32>,
}

impl Board {
    /// Slot 0 erased, the factory blob in slot 1 without a trailer (as the firmware image
    /// flashes it).
    fn factory() -> Self {
        let s0 = vec![u32::MAX; SLOT_WORDS];
        let mut s1 = vec![u32::MAX; SLOT_WORDS];
        let b = AlignedBlob::new(FACTORY);
        let words: &[u32] = bytemuck::cast_slice(b.as_bytes());
        s1[..words.len()].copy_from_slice(words);
        Self { s0, s1 }
    }
    fn flash(&mut self) -> SimFlash<'_> {
        SimFlash::new(&mut self.s0, &mut self.s1)
    }
}

fn crc(b: &[u8]) -> u32 {
    CRC32.checksum(b)
}

/// (code, detail, slot, value, status) of an upload reply.
fn upload_reply(f: &Frame) -> (u8, u8, u8, u32, ReplyStatus) {
    match f.msg {
        Message::Reply(r) => match r.body {
            ReplyBody::Upload {
                code,
                detail,
                slot,
                value,
                ..
            } => (code, detail, slot, value, r.status),
            b => panic!("not an upload reply: {b:?}"),
        },
        ref m => panic!("not a reply: {m:?}"),
    }
}

/// Sends one command through the wire encoding, the deframer and the uploader.
fn send(
    up: &mut Uploader,
    app: &mut App<'_>,
    flash: &mut impl Flash,
    seq: u16,
    c: Command,
) -> (Frame, Outcome) {
    let mut w = [0u8; MAX_WIRE];
    let n = protocol::encode(
        &Frame {
            seq,
            msg: Message::Command(c),
        },
        &mut w,
    );
    let mut d = Deframer::new();
    let mut out = None;
    for &b in &w[..n] {
        if let Some(r) = d.push_decode(b) {
            out = Some(up.handle(app, flash, r));
        }
    }
    out.expect("one frame")
}

/// Begin, every chunk, commit; returns the commit's reply and outcome.
fn upload_all(
    up: &mut Uploader,
    app: &mut App<'_>,
    flash: &mut impl Flash,
    blob: &[u8],
) -> (Frame, Outcome) {
    let (r, _) = send(
        up,
        app,
        flash,
        1,
        Command::UploadBegin {
            size: blob.len() as u32,
            crc: crc(blob),
        },
    );
    assert_eq!(upload_reply(&r).0, upload_code::OK, "begin");
    for (i, c) in blob.chunks(MAX_CHUNK).enumerate() {
        let (r, _) = send(
            up,
            app,
            flash,
            2,
            Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c)),
        );
        let (code, _, _, next, _) = upload_reply(&r);
        assert_eq!(code, upload_code::OK, "chunk {i}");
        assert_eq!(next as usize, (i * MAX_CHUNK + c.len()).min(blob.len()));
    }
    send(up, app, flash, 3, Command::UploadCommit)
}

fn released(app: &mut App<'_>) {
    let mut d = Deframer::new();
    let mut w = [0u8; MAX_WIRE];
    let n = protocol::encode(
        &Frame {
            seq: 0,
            msg: Message::Command(Command::Release),
        },
        &mut w,
    );
    for &b in &w[..n] {
        if let Some(r) = d.push_decode(b) {
            app.handle(r);
        }
    }
    assert!(!app.armed());
}

#[test]
fn upload_replaces_the_model_and_the_next_boot_keeps_it() {
    let mut board = Board::factory();
    let mut flash = board.flash();
    let active = upload::select(&flash, &HAND);
    assert_eq!(
        active,
        Some(Active {
            slot: FACTORY_SLOT,
            seq: 0,
            len: FACTORY.len()
        })
    );
    let ram = AlignedBlob::new(upload::blob(&flash, active));
    let mut app = App::new(HAND, ram.as_bytes());
    assert_eq!(app.rate_mhz(), 16_700);
    let mut up = Uploader::new(active);
    // Armed on a running model: refused, nothing erased.
    let (r, _) = send(
        &mut up,
        &mut app,
        &mut flash,
        1,
        Command::UploadBegin {
            size: NEW.len() as u32,
            crc: crc(NEW),
        },
    );
    assert_eq!(upload_reply(&r).0, upload_code::ARMED);
    assert_eq!(flash.ops, 0);
    released(&mut app);
    let (r, outcome) = upload_all(&mut up, &mut app, &mut flash, NEW);
    assert_eq!(
        upload_reply(&r),
        (upload_code::OK, 0, 0, 1, ReplyStatus::Ok)
    );
    let Outcome::Reload(new) = outcome else {
        panic!("no reload")
    };
    assert_eq!((new.slot, new.seq, new.len), (0, 1, NEW.len()));
    // The board reloads: the flags now come from the 40 Hz model; seq numbers carry on.
    let seq_before = r.seq;
    let ram2 = AlignedBlob::new(upload::blob(&flash, Some(new)));
    let mut app = app.reload(ram2.as_bytes());
    assert_eq!(app.rate_mhz(), 40_000);
    assert_eq!(app.info().model_crc, crc(&NEW[..NEW.len() - 4]));
    assert!(app.model().is_ok());
    let (r, _) = send(&mut up, &mut app, &mut flash, 9, Command::Info);
    assert_eq!(r.seq, seq_before.wrapping_add(1));
    // A reboot picks it; the factory model is still there, older.
    assert_eq!(upload::select(&flash, &HAND), Some(new));
    assert_eq!(
        upload::slot_state(&flash, &HAND, FACTORY_SLOT).map(|a| a.seq),
        Some(0)
    );
    // The next upload goes to the other slot (over the factory model) with seq 2.
    let (r, outcome) = upload_all(&mut up, &mut app, &mut flash, FACTORY);
    assert_eq!(upload_reply(&r).0, upload_code::OK);
    assert!(matches!(outcome, Outcome::Reload(a) if a.slot == 1 && a.seq == 2));
    assert_eq!(
        upload::select(&flash, &HAND).map(|a| (a.slot, a.seq)),
        Some((1, 2))
    );
}

/// Power lost at operation `cut` of an upload of `NEW` over a board in state `start`; returns
/// what boots afterwards.
fn cut_upload(start: &Board, cut: usize) -> (Board, Option<Active>, usize) {
    let mut board = Board {
        s0: start.s0.clone(),
        s1: start.s1.clone(),
    };
    let mut flash = board.flash();
    let active = upload::select(&flash, &HAND);
    let ram = AlignedBlob::new(upload::blob(&flash, active));
    let mut app = App::new(HAND, ram.as_bytes());
    released(&mut app);
    let mut up = Uploader::new(active);
    flash.cut_at = Some(cut);
    let cmds = std::iter::once(Command::UploadBegin {
        size: NEW.len() as u32,
        crc: crc(NEW),
    })
    .chain(
        NEW.chunks(MAX_CHUNK)
            .enumerate()
            .map(|(i, c)| Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c))),
    )
    .chain(std::iter::once(Command::UploadCommit));
    for c in cmds {
        if flash.cut() {
            break; // the board is off
        }
        let _ = up.handle(
            &mut app,
            &mut flash,
            Ok(Frame {
                seq: 0,
                msg: Message::Command(c),
            }),
        );
    }
    let ops = flash.ops;

    let booted = upload::select(&board.flash(), &HAND);
    (board, booted, ops)
}

/// From the factory state and from two uploaded slots: a cut at every erase and write boots
/// the old model until the trailer is complete, the new one after; never nothing. After the
/// reboot a new upload completes.
#[test]
fn upload_power_cut_at_every_write_boots_a_valid_model() {
    let factory = Board::factory();
    // Two trailer slots: upload the factory model into slot 0 first (seq 1).
    let mut two = Board::factory();
    {
        let mut flash = two.flash();
        let active = upload::select(&flash, &HAND);
        let ram = AlignedBlob::new(upload::blob(&flash, active));
        let mut app = App::new(HAND, ram.as_bytes());
        released(&mut app);
        let mut up = Uploader::new(active);
        let (_, o) = upload_all(&mut up, &mut app, &mut flash, FACTORY);
        assert!(matches!(o, Outcome::Reload(a) if a.slot == 0 && a.seq == 1));
    }
    let chunks = NEW.len().div_ceil(MAX_CHUNK);
    // Operations: 1 erase, one write per chunk, the trailer.
    let total = 1 + chunks + 1;
    for (start, old, new) in [(&factory, (1, 0), (0, 1)), (&two, (0, 1), (1, 2))] {
        let (_, booted, ops) = cut_upload(start, usize::MAX);
        assert_eq!(ops, total);
        assert_eq!(booted.map(|a| (a.slot, a.seq)), Some(new));
        for cut in 0..total {
            let (mut board, booted, _) = cut_upload(start, cut);
            let want = if cut < total - 1 { old } else { new };
            // A cut during the trailer write (the last operation) leaves half a trailer: old.
            let want = if cut == total - 1 { old } else { want };
            let got = booted.map(|a| (a.slot, a.seq));
            assert_eq!(got, Some(want), "cut at operation {cut}");
            // The chosen slot's model runs.
            let flash = board.flash();
            let ram = AlignedBlob::new(upload::blob(&flash, booted));
            assert!(App::new(HAND, ram.as_bytes()).model().is_ok(), "cut {cut}");
            // After the reboot a fresh upload completes (every 64th cut, for time).
            if cut % 64 == 0 {
                let mut flash = board.flash();
                let mut app = App::new(HAND, ram.as_bytes());
                released(&mut app);
                let mut up = Uploader::new(booted);
                let (r, o) = upload_all(&mut up, &mut app, &mut flash, NEW);
                assert_eq!(
                    upload_reply(&r).0,
                    upload_code::OK,
                    "resume after cut {cut}"
                );
                assert!(matches!(o, Outcome::Reload(a) if a.seq == want.1 + 1));
            }
        }
    }
}

struct Session {
    board: Board,
}

impl Session {
    fn new() -> Self {
        Self {
            board: Board::factory(),
        }
    }
    /// Runs `f` with a released app over the factory model and a fresh uploader; then checks
    /// the factory model still boots.
    fn run(&mut self, f: impl FnOnce(&mut Uploader, &mut App<'_>, &mut SimFlash<'_>)) {
        let mut flash = self.board.flash();
        let active = upload::select(&flash, &HAND);
        let ram = AlignedBlob::new(upload::blob(&flash, active));
        let mut app = App::new(HAND, ram.as_bytes());
        released(&mut app);
        let mut up = Uploader::new(active);
        f(&mut up, &mut app, &mut flash);
        assert_eq!(
            upload::select(&flash, &HAND).map(|a| (a.slot, a.seq)),
            Some((FACTORY_SLOT, 0)),
            "a refused upload leaves the old model active"
        );
    }
}

fn code_of(r: (Frame, Outcome)) -> (u8, u8, u32) {
    assert_eq!(r.1, Outcome::None);
    let (code, detail, _, value, status) = upload_reply(&r.0);
    assert_eq!(status == ReplyStatus::Ok, code == upload_code::OK);
    (code, detail, value)
}

#[test]
fn upload_wrong_size_order_and_incomplete_are_refused() {
    Session::new().run(|up, app, flash| {
        let cap = (128 * 1024 - TRAILER_LEN) as u32;
        // Chunk and commit before begin.
        let c0 = Chunk::new(0, &NEW[..MAX_CHUNK]);
        assert_eq!(
            code_of(send(up, app, flash, 1, Command::UploadChunk(c0))).0,
            upload_code::NOT_STARTED
        );
        assert_eq!(
            code_of(send(up, app, flash, 1, Command::UploadCommit)).0,
            upload_code::NOT_STARTED
        );
        for size in [0, cap + 4, 1001] {
            assert_eq!(
                code_of(send(
                    up,
                    app,
                    flash,
                    2,
                    Command::UploadBegin { size, crc: 0 }
                )),
                (upload_code::WRONG_SIZE, 0, cap),
                "size {size}"
            );
        }
        assert_eq!(flash.ops, 0, "nothing erased for a wrong size");
        let begin = Command::UploadBegin {
            size: 256,
            crc: crc(&NEW[..256]),
        };
        assert_eq!(code_of(send(up, app, flash, 3, begin)).0, upload_code::OK);
        // Out of order: the reply names the offset to resume at.
        let c1 = Chunk::new(128, &NEW[128..256]);
        assert_eq!(
            code_of(send(up, app, flash, 4, Command::UploadChunk(c1))),
            (upload_code::OUT_OF_ORDER, 0, 0)
        );
        assert_eq!(
            code_of(send(up, app, flash, 5, Command::UploadChunk(c0))),
            (upload_code::OK, 0, 128)
        );
        // The same chunk again (a lost reply): out of order, resume at 128.
        assert_eq!(
            code_of(send(up, app, flash, 6, Command::UploadChunk(c0))),
            (upload_code::OUT_OF_ORDER, 0, 128)
        );
        // Not a multiple of 4; past the declared size.
        let odd = Chunk::new(128, &NEW[128..131]);
        assert_eq!(
            code_of(send(up, app, flash, 7, Command::UploadChunk(odd))),
            (upload_code::CHUNK_LENGTH, 0, 128)
        );
        assert_eq!(
            code_of(send(up, app, flash, 8, Command::UploadCommit)),
            (upload_code::INCOMPLETE, 0, 128)
        );
        assert_eq!(
            code_of(send(up, app, flash, 9, Command::UploadChunk(c1))),
            (upload_code::OK, 0, 256)
        );
        let past = Chunk::new(256, &NEW[256..260]);
        assert_eq!(
            code_of(send(up, app, flash, 10, Command::UploadChunk(past))),
            (upload_code::CHUNK_LENGTH, 0, 256)
        );
        // All 256 bytes are there, the CRC matches, but 256 bytes are no model.
        let (code, detail, _) = code_of(send(up, app, flash, 11, Command::UploadCommit));
        assert_eq!((code, detail), (upload_code::BAD_BLOB, 1), "truncated blob");
    });
}

/// A chunk whose CRC does not match its data, and a chunk frame corrupted on the wire: the
/// upload stays where it was and resumes with the resent chunk.
#[test]
fn upload_corrupt_chunk_and_corrupt_frame_resume() {
    Session::new().run(|up, app, flash| {
        let begin = Command::UploadBegin {
            size: NEW.len() as u32,
            crc: crc(NEW),
        };
        assert_eq!(code_of(send(up, app, flash, 1, begin)).0, upload_code::OK);
        let mut bad = Chunk::new(0, &NEW[..MAX_CHUNK]);
        bad.data[7] ^= 0x20;
        assert_eq!(
            code_of(send(up, app, flash, 2, Command::UploadChunk(bad))),
            (upload_code::BAD_CHUNK, 0, 0)
        );
        // A bit flipped on the wire: an error frame (bad CRC), no upload reply, no change.
        let mut w = [0u8; MAX_WIRE];
        let n = protocol::encode(
            &Frame {
                seq: 3,
                msg: Message::Command(Command::UploadChunk(Chunk::new(0, &NEW[..MAX_CHUNK]))),
            },
            &mut w,
        );
        w[40] ^= 0x01;
        let mut d = Deframer::new();
        let mut replies = Vec::new();
        for &b in &w[..n] {
            if let Some(r) = d.push_decode(b) {
                replies.push(up.handle(app, flash, r));
            }
        }
        assert_eq!(replies.len(), 1);
        assert!(matches!(replies[0].0.msg, Message::Error(e) if e.error == 5));
        // Resend everything: completes (commit skipped, so the factory model stays).
        for (i, c) in NEW.chunks(MAX_CHUNK).enumerate() {
            let r = send(
                up,
                app,
                flash,
                4,
                Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c)),
            );
            assert_eq!(code_of(r).0, upload_code::OK, "chunk {i}");
        }
        // Restart: a new begin erases again and expects offset 0.
        assert_eq!(code_of(send(up, app, flash, 5, begin)).0, upload_code::OK);
        let c1 = Chunk::new(MAX_CHUNK as u32, &NEW[MAX_CHUNK..2 * MAX_CHUNK]);
        assert_eq!(
            code_of(send(up, app, flash, 6, Command::UploadChunk(c1))),
            (upload_code::OUT_OF_ORDER, 0, 0)
        );
        assert_eq!(
            code_of(send(up, app, flash, 7, Command::UploadCommit)),
            (upload_code::INCOMPLETE, 0, 0)
        );
    });
}

fn upload_refusal(blob: &[u8], announced_crc: u32) -> (u8, u8, u32) {
    let mut out = None;
    Session::new().run(|up, app, flash| {
        let begin = Command::UploadBegin {
            size: blob.len() as u32,
            crc: announced_crc,
        };
        assert_eq!(code_of(send(up, app, flash, 1, begin)).0, upload_code::OK);
        for (i, c) in blob.chunks(MAX_CHUNK).enumerate() {
            let r = send(
                up,
                app,
                flash,
                2,
                Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c)),
            );
            assert_eq!(code_of(r).0, upload_code::OK);
        }
        out = Some(code_of(send(up, app, flash, 3, Command::UploadCommit)));
        // Refused at commit: the upload is over, a new begin is needed.
        assert_eq!(
            code_of(send(up, app, flash, 4, Command::UploadCommit)).0,
            upload_code::NOT_STARTED
        );
    });
    out.unwrap()
}

fn recrc(mut b: Vec<u8>) -> Vec<u8> {
    let body = b.len() - 4;
    let c = crc(&b[..body]);
    b[body..].copy_from_slice(&c.to_le_bytes());
    b
}

#[test]
fn upload_bad_blob_is_refused_and_the_old_model_stays() {
    // Whole-blob CRC differs from the announced one (a transfer the chunk CRCs missed).
    let got = upload_refusal(NEW, crc(NEW) ^ 1);
    assert_eq!(got, (upload_code::BLOB_CRC, 0, crc(NEW)));
    // A blob corrupted before sending (announced CRC matches): its own CRC fails (detail 5).
    let mut b = NEW.to_vec();
    b[5000] ^= 0x10;
    let got = upload_refusal(&b, crc(&b));
    assert_eq!((got.0, got.1), (upload_code::BAD_BLOB, 5));
    // Bad magic.
    let mut b = NEW.to_vec();
    b[0] = b'X';
    let got = upload_refusal(&b, crc(&b));
    assert_eq!((got.0, got.1), (upload_code::BAD_BLOB, 2));
}

#[test]
fn upload_rate_and_unit_mismatch_are_refused() {
    let got = upload_refusal(SUCTION, crc(SUCTION));
    assert_eq!(got, (upload_code::RATE_MISMATCH, 0, 71_000));
    // The 40 Hz hand model relabelled as counts.
    let mut b = NEW.to_vec();
    b[19] = 1;
    let b = recrc(b);
    let got = upload_refusal(&b, crc(&b));
    assert_eq!(got, (upload_code::UNIT_MISMATCH, 0, 1));
}

/// Without the uploader (a board with no model flash) upload commands are refused as such.
#[test]
fn upload_unsupported_without_flash() {
    let ram = AlignedBlob::new(FACTORY);
    let mut app = App::new(HAND, ram.as_bytes());
    let r = app.handle(Ok(Frame {
        seq: 1,
        msg: Message::Command(Command::UploadCommit),
    }));
    assert_eq!(upload_reply(&r).0, upload_code::UNSUPPORTED);
}

/// No valid model at all (a new hand: rate mismatch): boot in a system fault, upload into
/// slot 0 while the (non-predicting) app is armed, and run the new model.
#[test]
fn upload_into_a_board_without_a_usable_model() {
    let mut s0 = vec![u32::MAX; SLOT_WORDS];
    let mut s1 = vec![u32::MAX; SLOT_WORDS];
    let b = AlignedBlob::new(SUCTION);
    let words: &[u32] = bytemuck::cast_slice(b.as_bytes());
    s1[..words.len()].copy_from_slice(words);
    let mut flash = SimFlash::new(&mut s0, &mut s1);
    assert_eq!(upload::select(&flash, &HAND), None);
    let ram = AlignedBlob::new(SUCTION);
    let mut app = App::new(HAND, ram.as_bytes());
    assert!(app.model().is_err());
    let mut up = Uploader::new(None);
    let (r, o) = upload_all(&mut up, &mut app, &mut flash, NEW);
    assert_eq!(
        upload_reply(&r),
        (upload_code::OK, 0, 0, 1, ReplyStatus::Ok)
    );
    let Outcome::Reload(a) = o else { panic!() };
    let ram2 = AlignedBlob::new(upload::blob(&flash, Some(a)));
    let app = app.reload(ram2.as_bytes());
    assert!(app.model().is_ok());
    assert_eq!(app.rate_mhz(), 40_000);
}

/// The field script on a recorded trial (`replay::run_field`, the host side of the QEMU
/// comparison): sample stream on, grasp start, lift, release, then an upload of another model
/// while the frames go on, a grasp start, and the flags come from the new model (equal to an app
/// that ran it all along after the same grasp start, unlike the old one's).
#[test]
fn upload_during_a_replayed_trial_then_flags_from_the_new_model() {
    use slipguard_app::replay::{self, CHEEZ_TRIAL, field_script};
    use slipguard_core::protocol::Flags;

    const SECOND: &[u8] = include_bytes!("../../../models/hand-force/hand-force.bin");
    let run = |model: &[u8], second: &[u8]| -> (Vec<Frame>, Option<u32>) {
        let mut board = Board::factory();
        let mut flash = board.flash();
        let ram = AlignedBlob::new(model);
        let ram2 = AlignedBlob::new(second);
        let mut bytes = Vec::new();
        let (n, reloaded) = replay::run_field(
            HAND,
            ram.as_bytes(),
            ram2.as_bytes(),
            &mut flash,
            &CHEEZ_TRIAL,
            |b| bytes.extend_from_slice(b),
        );
        let mut d = Deframer::new();
        let frames: Vec<Frame> = bytes
            .iter()
            .filter_map(|&b| d.push_decode(b))
            .map(|r| r.unwrap())
            .collect();
        assert_eq!(frames.len(), n);
        (frames, reloaded)
    };
    let (field, reloaded) = run(FACTORY, SECOND);
    assert_eq!(reloaded, Some(field_script::commit_at(SECOND.len())));
    assert!(reloaded.unwrap() < field_script::GRASP_AGAIN_AT);
    // Every upload command answered OK; seq numbers run on across the reload.
    let codes: Vec<u8> = field
        .iter()
        .filter_map(|f| match f.msg {
            Message::Reply(r) => match r.body {
                ReplyBody::Upload { code, .. } => Some(code),
                _ => None,
            },
            _ => None,
        })
        .collect();
    assert_eq!(codes.len(), 2 + SECOND.len().div_ceil(MAX_CHUNK));
    assert!(codes.iter().all(|&c| c == upload_code::OK));
    for (i, f) in field.iter().enumerate() {
        assert_eq!(f.seq, i as u16);
    }
    let after = |v: &[Frame]| -> Vec<[u16; 16]> {
        v.iter()
            .filter_map(|f| match f.msg {
                Message::Flags(x) => Some(x),
                _ => None,
            })
            .skip(field_script::GRASP_AGAIN_AT as usize)
            .map(|f: Flags| f.p)
            .collect()
    };
    let new_ref = run(SECOND, SECOND).0;
    let old_ref = run(FACTORY, FACTORY).0;
    assert_eq!(after(&field).len(), 10);
    assert_eq!(after(&field), after(&new_ref), "flags from the new model");
    // The trial is over by then: every channel is unloaded, out of contact and so not run
    // (p none, fault clear), whichever model is loaded; the old and the new model's frames
    // differ before, while the hand holds the object.
    assert_eq!(after(&field), after(&old_ref));
    assert!(after(&field).iter().flatten().all(|&p| p == P_NONE));
    let held = |v: &[Frame]| -> Vec<[u16; 16]> {
        v.iter()
            .filter_map(|f| match f.msg {
                Message::Flags(x) => Some(x.p),
                _ => None,
            })
            .take(300)
            .collect()
    };
    assert_ne!(
        held(&new_ref),
        held(&old_ref),
        "the two models differ in contact"
    );
    // The sample stream went on through the upload, with its three marks.
    let marks: Vec<u8> = field
        .iter()
        .filter_map(|f| match f.msg {
            Message::Samples(s) => Some(s.marks),
            _ => None,
        })
        .collect();
    assert_eq!(marks.len(), 400);
    assert_eq!(marks.iter().filter(|&&m| m != 0).count(), 4);
}

/// Random upload commands (sizes, offsets, data, CRCs, commits) with power cuts: never a panic,
/// never a write to the running slot, and the board always boots the factory model (random data
/// never passes the commit's checks).
#[test]
fn upload_random_commands_and_cuts_never_lose_the_model() {
    let mut x: u32 = 0xC0FF_EE11;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x
    };
    for round in 0..40 {
        let mut board = Board::factory();
        let factory_slot = board.s1.clone();
        {
            let mut flash = board.flash();
            if round % 2 == 1 {
                flash.cut_at = Some((next() % 64) as usize);
            }
            let ram = AlignedBlob::new(FACTORY);
            let mut app = App::new(HAND, ram.as_bytes());
            released(&mut app);
            let mut up = Uploader::new(upload::select(&flash, &HAND));
            let size = [256u32, 1000, 4096, 0, 200_000][(next() % 5) as usize];
            for _ in 0..200 {
                let c = match next() % 10 {
                    0 => Command::UploadBegin { size, crc: next() },
                    1 => Command::UploadCommit,
                    _ => {
                        let len = 1 + (next() % MAX_CHUNK as u32) as usize;
                        let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
                        let mut c =
                            Chunk::new((next() % 8) * MAX_CHUNK as u32 * (next() % 2), &data);
                        if next() % 4 == 0 {
                            c.crc ^= 1;
                        }
                        Command::UploadChunk(c)
                    }
                };
                let (r, o) = up.handle(
                    &mut app,
                    &mut flash,
                    Ok(Frame {
                        seq: 1,
                        msg: Message::Command(c),
                    }),
                );
                assert_eq!(o, Outcome::None);
                assert!(matches!(r.msg, Message::Reply(_)));
            }
        }
        assert_eq!(
            board.s1, factory_slot,
            "round {round}: the running slot was written"
        );
        let booted = upload::select(&board.flash(), &HAND);
        assert_eq!(
            booted.map(|a| (a.slot, a.seq)),
            Some((FACTORY_SLOT, 0)),
            "round {round}"
        );
    }
}
