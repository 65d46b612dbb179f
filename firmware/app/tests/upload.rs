//! Model upload into the two flash slots, against a simulated flash: every refusal with its
//! code, resume and restart, and a power cut at every flash operation of an upload (the board
//! must boot a valid model afterwards, the old one until the trailer is written).

use slipguard_app::app::App;
use slipguard_app::profile::Profile;
use slipguard_app::upload::{
    self, Active, FACTORY_SLOT, Flash, Outcome, SimFlash, TRAILER_LEN, Uploader,
};
use slipguard_core::blob::{AlignedBlob, CRC32};
use slipguard_core::model_ram::ModelRam;
use slipguard_core::protocol::{
    self, Chunk, Command, Deframer, Frame, MAX_CHUNK, MAX_WIRE, Message, ReplyBody, ReplyStatus,
    upload_code,
};
use slipguard_core::units::Millihertz;

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
        Self::holding(FACTORY)
    }
    /// Slot 0 erased, `factory` in slot 1 without a trailer.
    fn holding(factory: &[u8]) -> Self {
        let s0 = vec![u32::MAX; SLOT_WORDS];
        let mut s1 = vec![u32::MAX; SLOT_WORDS];
        let b = AlignedBlob::new(factory);
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

/// A blob's fingerprint: its own CRC (the last 4 bytes of its header's total length), what
/// info reports as `model_crc`.
fn fingerprint(blob: &[u8]) -> u32 {
    let total = u32::from_le_bytes(blob[8..12].try_into().unwrap()) as usize;
    u32::from_le_bytes(blob[total - 4..total].try_into().unwrap())
}

type Ram = ModelRam<{ slipguard_core::model_ram::MODEL_RAM_BYTES }>;

/// An app over the model the board boots (the chosen slot's RAM copy), leaving the flash free
/// for the uploader (every blob here fits the RAM copy; `reboot` runs the board's own path).
fn app_over<'r>(
    flash: &impl Flash,
    profile: Profile,
    ram: &'r mut Ram,
) -> (Option<Active>, App<'r>) {
    let active = upload::select(flash, &profile);
    let bytes: &'r [u8] = ram.load(upload::blob(flash, active)).unwrap_or(&[]);
    (active, App::new(profile, bytes))
}

/// Reboots as the firmware does (`upload::boot`: slot choice, RAM copy, app over the copy) and
/// returns the active slot and the fingerprint of the model the app runs (`None`: the app is
/// in a model fault).
fn reboot(flash: &impl Flash, profile: Profile) -> (Option<Active>, Option<u32>) {
    let mut ram = Box::new(Ram::new());
    let (active, app) = upload::boot(flash, profile, &mut ram);
    let running = app.model().ok().map(|m| m.blob().crc);
    (active, running)
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
    assert_eq!(app.rate_mhz(), Millihertz(16_700));
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
    assert_eq!(app.rate_mhz(), Millihertz(40_000));
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

/// A small model with the bench model's settings (hidden 8, PyTorch-style init with `seed`) at
/// `rate_mhz`: the power-cut tests upload it at every cut, so its few flash operations keep them
/// fast.
fn small(rate_mhz: u32, seed: u64) -> Vec<u8> {
    use slipguard_core::float::FloatModel;
    let golden = AlignedBlob::new(FACTORY);
    let mut c = *slipguard_core::model::Model::from_bytes(golden.as_bytes())
        .unwrap()
        .config();
    c.hidden = [8, 0];
    c.sample_rate_mhz = Millihertz(rate_mhz);
    let (bytes, _) =
        slipguard_core::quantize::quantize(&FloatModel::init_like_pytorch(c, seed), &[], None)
            .unwrap();
    bytes
}

/// The commands of a whole upload of `blob`.
fn upload_cmds(blob: &[u8]) -> Vec<Command> {
    std::iter::once(Command::UploadBegin {
        size: blob.len() as u32,
        crc: crc(blob),
    })
    .chain(
        blob.chunks(MAX_CHUNK)
            .enumerate()
            .map(|(i, c)| Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c))),
    )
    .chain(std::iter::once(Command::UploadCommit))
    .collect()
}

/// Power lost at operation `cut` of an upload of `blob` over `board` (booted as the firmware
/// boots, released); returns the number of flash operations done and what the reboot runs.
fn cut_upload(board: &mut Board, blob: &[u8], cut: usize) -> (usize, Option<Active>, Option<u32>) {
    cut_commands(board, &upload_cmds(blob), cut)
}

/// Power lost at operation `cut` of `cmds` (see [`cut_upload`]).
fn cut_commands(
    board: &mut Board,
    cmds: &[Command],
    cut: usize,
) -> (usize, Option<Active>, Option<u32>) {
    let mut flash = board.flash();
    let mut ram = Box::new(Ram::new());
    let (active, mut app) = app_over(&flash, HAND, &mut ram);
    assert!(app.model().is_ok());
    released(&mut app);
    let mut up = Uploader::new(active);
    flash.cut_at = Some(cut);
    for &c in cmds {
        if flash.cut() {
            break; // the board is off
        }
        let (_, o) = up.handle(
            &mut app,
            &mut flash,
            Ok(Frame {
                seq: 0,
                msg: Message::Command(c),
            }),
        );
        if let Outcome::Reload(_) = o {
            break; // it restarts
        }
    }
    let ops = flash.ops;
    let (booted, running) = reboot(&board.flash(), HAND);
    (ops, booted, running)
}

/// From the factory state and from two uploaded slots: a cut at every erase and write boots
/// the old model until the trailer is complete, the new one after; never nothing. After the
/// reboot a fresh upload is cut at every operation again (nested cuts) and still boots the old
/// or the new model, and a third upload completes and boots, after every pair of cuts.
#[test]
fn upload_power_cut_at_every_write_boots_a_valid_model() {
    let (old_blob, new_blob) = (small(16_700, 1), small(40_000, 2));
    let (old_fp, new_fp) = (fingerprint(&old_blob), fingerprint(&new_blob));
    let factory = Board::holding(&old_blob);
    // Two trailer slots: the old model uploaded into slot 0 first (seq 1).
    let mut two = Board::holding(&old_blob);
    let (_, booted, _) = cut_upload(&mut two, &old_blob, usize::MAX);
    assert_eq!(booted.map(|a| (a.slot, a.seq)), Some((0, 1)));
    // Operations: 1 erase, one write per chunk, the trailer.
    let total = 1 + new_blob.len().div_ceil(MAX_CHUNK) + 1;
    let copy = |b: &Board| Board {
        s0: b.s0.clone(),
        s1: b.s1.clone(),
    };
    // Two trailer slots past 2^31 (the factory slot at 0x8000_0000, slot 0 at 0x8000_0001):
    // the next upload goes into the factory slot, and until its trailer is written that slot
    // has none, as a factory blob: it must still lose (found by the `upload` fuzz target).
    let mut high = copy(&two);
    let t = upload::Trailer {
        seq: 0x8000_0000,
        len: old_blob.len() as u32,
        crc: crc(&old_blob),
    };
    let tail = (SLOT_WORDS * 4 - TRAILER_LEN) / 4;
    for (w, b) in high.s1[tail..].iter_mut().zip(t.to_bytes().chunks_exact(4)) {
        *w = u32::from_ne_bytes(b.try_into().unwrap());
    }
    let (_, booted, _) = cut_upload(&mut high, &old_blob, usize::MAX);
    assert_eq!(booted.map(|a| (a.slot, a.seq)), Some((0, 0x8000_0001)));
    for (start, old, new) in [
        (&factory, (1, 0), (0, 1)),
        (&two, (0, 1), (1, 2)),
        (&high, (0, 0x8000_0001), (1, 0x8000_0002)),
    ] {
        let (ops, booted, running) = cut_upload(&mut copy(start), &new_blob, usize::MAX);
        assert_eq!(ops, total);
        assert_eq!(booted.map(|a| (a.slot, a.seq)), Some(new));
        assert_eq!(running, Some(new_fp));
        // Every byte written, no commit (the power went between the last chunk and it).
        let cmds = upload_cmds(&new_blob);
        let (_, booted, running) =
            cut_commands(&mut copy(start), &cmds[..cmds.len() - 1], usize::MAX);
        assert_eq!(booted.map(|a| (a.slot, a.seq)), Some(old), "uncommitted");
        assert_eq!(running, Some(old_fp), "uncommitted");
        for cut in 0..total {
            // A cut at any operation, the trailer write (the last) included, leaves the old slot
            // the newest valid one: the old model boots.
            let mut board = copy(start);
            let (_, booted, running) = cut_upload(&mut board, &new_blob, cut);
            assert_eq!(
                booted.map(|a| (a.slot, a.seq)),
                Some(old),
                "cut at operation {cut}"
            );
            assert_eq!(running, Some(old_fp), "cut {cut}");
            for cut2 in (0..total).chain([usize::MAX]) {
                let mut again = copy(&board);
                let (_, booted, running) = cut_upload(&mut again, &new_blob, cut2);
                let (want, fp) = if cut2 == usize::MAX {
                    (new, new_fp)
                } else {
                    (old, old_fp)
                };
                assert_eq!(
                    (booted.map(|a| (a.slot, a.seq)), running),
                    (Some(want), Some(fp)),
                    "cuts {cut}, {cut2}"
                );
                // Then a whole upload completes and boots.
                let seq = booted.unwrap().seq;
                let (_, booted, running) = cut_upload(&mut again, &old_blob, usize::MAX);
                assert_eq!(booted.map(|a| a.seq), Some(seq + 1), "cuts {cut}, {cut2}");
                assert_eq!(running, Some(old_fp), "cuts {cut}, {cut2}");
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
    assert_eq!(app.rate_mhz(), Millihertz(40_000));
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
    let after = |v: &[Frame]| -> Vec<[slipguard_core::protocol::PUnstable; 16]> {
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
    assert!(after(&field).iter().flatten().all(|p| p.is_none()));
    let held = |v: &[Frame]| -> Vec<[slipguard_core::protocol::PUnstable; 16]> {
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

/// Every blob form the tools can produce, uploaded to a board of each profile and rebooted as
/// the firmware boots (`upload::boot`): the shipped v1 blobs of each profile, their RAM images
/// (`SGMI`, what `ModelRam::load` makes), images without their trailing CRC, truncated blobs and
/// padded ones. A commit is accepted exactly when the boot path then runs that model; a refused
/// one leaves the old model running. Which forms a profile accepts is the table below, not the
/// code's own check.
#[test]
fn commit_accepts_exactly_what_the_boot_path_runs() {
    const HAND_16: &[u8] = include_bytes!("../../../models/hand-force/hand-force.bin");
    let models: [(&str, &[u8]); 4] = [
        ("bench", FACTORY),
        ("hand-force", HAND_16),
        ("hand-force-40hz", NEW),
        ("suction", SUCTION),
    ];
    for (profile, factory, runs) in [
        (
            HAND,
            FACTORY,
            &["bench", "hand-force", "hand-force-40hz"][..],
        ),
        (Profile::SUCTION, SUCTION, &["suction"][..]),
    ] {
        for (name, blob) in models {
            let mut ram = Box::new(Ram::new());
            let image = ram
                .load(AlignedBlob::new(blob).as_bytes())
                .unwrap()
                .to_vec();
            assert_eq!(&image[..4], b"SGMI");
            let pad = |tail: &[u8]| [blob, tail].concat();
            let half = (blob.len() / 2) & !3;
            // (form, bytes, a model the profile runs)
            let ok = runs.contains(&name);
            let forms: Vec<(&str, Vec<u8>, bool)> = vec![
                ("blob", blob.to_vec(), ok),
                ("padded with 4 zero bytes", pad(&[0; 4]), ok),
                ("padded with 64 erased bytes", pad(&[0xFF; 64]), ok),
                (
                    "padded with an image CRC",
                    pad(&image[image.len() - 4..]),
                    ok,
                ),
                ("RAM image", image.clone(), false),
                ("RAM image padded", [&image[..], &[0; 8]].concat(), false),
                (
                    "RAM image without its CRC",
                    image[..image.len() - 4].to_vec(),
                    false,
                ),
                ("truncated by 4", blob[..blob.len() - 4].to_vec(), false),
                ("truncated to half", blob[..half].to_vec(), false),
            ];
            for (form, bytes, want) in forms {
                let what = format!("{name} {form} on the {} profile", profile.name);
                let mut board = Board::holding(factory);
                let mut flash = board.flash();
                let (before, running) = reboot(&flash, profile);
                assert_eq!(running, Some(fingerprint(factory)), "{what}: factory boot");
                let mut ram = Box::new(Ram::new());
                let (active, mut app) = app_over(&flash, profile, &mut ram);
                released(&mut app);
                let mut up = Uploader::new(active);
                let (r, outcome) = upload_all(&mut up, &mut app, &mut flash, &bytes);
                let (code, _, slot, seq, _) = upload_reply(&r);
                let (after, running) = reboot(&flash, profile);
                if code == upload_code::OK {
                    assert!(want, "{what}: accepted");
                    assert_eq!(
                        outcome,
                        Outcome::Reload(Active {
                            slot,
                            seq,
                            len: bytes.len()
                        })
                    );
                    assert_eq!(after.map(|a| (a.slot, a.seq)), Some((slot, seq)), "{what}");
                    assert_eq!(running, Some(fingerprint(&bytes)), "{what}: runs");
                } else {
                    assert!(!want, "{what}: refused with code {code}");
                    assert_eq!(outcome, Outcome::None);
                    assert_eq!(after, before, "{what}: the old slot stays");
                    assert_eq!(
                        running,
                        Some(fingerprint(factory)),
                        "{what}: the old model runs"
                    );
                }
            }
        }
    }
}

/// While flagging is armed (a grasp) begin and commit are refused with `ARMED` and the slots stay
/// as they were; chunks are stored, and the commit goes through after release. An accepted
/// commit ends the handling of the bytes it came with (the board restarts): a grasp start right
/// behind it is not handled, so the restart never falls into a grasp.
#[test]
fn armed_refuses_begin_and_commit_and_nothing_restarts_in_a_grasp() {
    let mut board = Board::factory();
    let mut flash = board.flash();
    let mut ram = Box::new(Ram::new());
    let (active, mut app) = app_over(&flash, HAND, &mut ram);
    let mut up = Uploader::new(active);
    let begin = Command::UploadBegin {
        size: NEW.len() as u32,
        crc: crc(NEW),
    };
    // Armed after boot: begin refused before any erase.
    assert_eq!(
        code_of(send(&mut up, &mut app, &mut flash, 1, begin)),
        (upload_code::ARMED, 0, 0)
    );
    assert_eq!(flash.ops, 0);
    released(&mut app);
    assert_eq!(
        code_of(send(&mut up, &mut app, &mut flash, 2, begin)).0,
        upload_code::OK
    );
    // A grasp starts mid-upload: the chunks are still stored.
    let (r, _) = send(&mut up, &mut app, &mut flash, 3, Command::GraspStart);
    assert!(matches!(r.msg, Message::Reply(x) if x.status == ReplyStatus::Ok));
    assert!(app.armed());
    for (i, c) in NEW.chunks(MAX_CHUNK).enumerate() {
        let chunk = Command::UploadChunk(Chunk::new((i * MAX_CHUNK) as u32, c));
        assert_eq!(
            code_of(send(&mut up, &mut app, &mut flash, 4, chunk)).0,
            upload_code::OK
        );
    }
    // Commit while armed: refused, nothing written, the upload kept (value: bytes stored).
    let ops = flash.ops;
    assert_eq!(
        code_of(send(
            &mut up,
            &mut app,
            &mut flash,
            5,
            Command::UploadCommit
        )),
        (upload_code::ARMED, 0, NEW.len() as u32)
    );
    assert_eq!(flash.ops, ops);
    assert_eq!(reboot(&flash, HAND).1, Some(fingerprint(FACTORY)));
    // Release, then the commit and a grasp start in one burst of bytes: the commit goes
    // through, the grasp start is left for the restarted board.
    released(&mut app);
    let mut bytes = Vec::new();
    for (seq, c) in [(6, Command::UploadCommit), (7, Command::GraspStart)] {
        let mut w = [0u8; MAX_WIRE];
        let n = protocol::encode(
            &Frame {
                seq,
                msg: Message::Command(c),
            },
            &mut w,
        );
        bytes.extend_from_slice(&w[..n]);
    }
    let mut replies = Vec::new();
    let reload = upload::receive(
        &mut up,
        &mut app,
        &mut flash,
        &mut Deframer::new(),
        &bytes,
        |f| replies.push(*f),
    );
    assert_eq!(replies.len(), 1, "only the commit is answered");
    assert_eq!(upload_reply(&replies[0]).0, upload_code::OK);
    assert_eq!(reload.map(|a| (a.slot, a.seq)), Some((0, 1)));
    assert!(!app.armed(), "no grasp start before the restart");
    assert_eq!(reboot(&flash, HAND), (reload, Some(fingerprint(NEW))));
}

/// Sequence numbers wrap: with the active slot at `u32::MAX`, the next commit numbers the new
/// slot 1 (0 is the factory blob's), says so, and a reboot picks it (then 2, and so on).
#[test]
fn slot_choice_survives_the_sequence_wrap() {
    // The factory slot given a trailer at u32::MAX − 1: the next upload gets u32::MAX.
    let mut board = Board::factory();
    let t = upload::Trailer {
        seq: u32::MAX - 1,
        len: FACTORY.len() as u32,
        crc: crc(FACTORY),
    };
    let tail = (SLOT_WORDS * 4 - TRAILER_LEN) / 4;
    for (w, b) in board.s1[tail..]
        .iter_mut()
        .zip(t.to_bytes().chunks_exact(4))
    {
        *w = u32::from_ne_bytes(b.try_into().unwrap());
    }
    let mut flash = board.flash();
    assert_eq!(
        reboot(&flash, HAND).0.map(|a| (a.slot, a.seq)),
        Some((1, u32::MAX - 1))
    );
    let mut ram = Box::new(Ram::new());
    let (active, mut app) = app_over(&flash, HAND, &mut ram);
    released(&mut app);
    let mut up = Uploader::new(active);
    let (r, _) = upload_all(&mut up, &mut app, &mut flash, NEW);
    assert_eq!(upload_reply(&r).3, u32::MAX);
    assert_eq!(
        reboot(&flash, HAND).0.map(|a| (a.slot, a.seq)),
        Some((0, u32::MAX))
    );
    let mut expected = [(1, 1), (0, 2), (1, 3)].into_iter();
    for blob in [FACTORY, NEW, FACTORY] {
        let (want_slot, want_seq) = expected.next().unwrap();
        let mut ram = Box::new(Ram::new());
        let (active, mut app) = app_over(&flash, HAND, &mut ram);
        released(&mut app);
        let mut up = Uploader::new(active);
        let (r, o) = upload_all(&mut up, &mut app, &mut flash, blob);
        let (code, _, slot, seq, _) = upload_reply(&r);
        assert_eq!((code, slot, seq), (upload_code::OK, want_slot, want_seq));
        assert!(matches!(o, Outcome::Reload(a) if (a.slot, a.seq) == (slot, seq)));
        let (booted, running) = reboot(&flash, HAND);
        assert_eq!(
            booted.map(|a| (a.slot, a.seq)),
            Some((slot, seq)),
            "after {seq}"
        );
        assert_eq!(running, Some(fingerprint(blob)));
    }
    assert!(upload::newer(1, u32::MAX) && !upload::newer(u32::MAX, 1));
    assert!(upload::newer(1, 0) && !upload::newer(5, 5));
    // The factory blob (0, no trailer) is older than every committed number, past 2^31 too.
    assert!(upload::newer(0x8000_0001, 0) && !upload::newer(0, 0x8000_0001));
}
