//! Model upload over the serial link into one of two flash slots, and the choice of the active
//! slot at boot. Portable: the board layer implements [`Flash`] over its flash driver (sectors
//! 10 and 11 of the STM32F405); the host tests use [`SimFlash`], which can lose power at any
//! write.
//!
//! Slot layout (one erase sector each): the blob from byte 0 (so a slot is read exactly as the
//! single model region was), and a [`Trailer`] in the last [`TRAILER_LEN`] bytes, written last:
//!
//! ```text
//! slot_len − 20  u32  magic "SGSL"
//! slot_len − 16  u32  sequence number (the active slot's + 1)
//! slot_len − 12  u32  blob length
//! slot_len −  8  u32  CRC-32 of the blob
//! slot_len −  4  u32  CRC-32 of the 16 bytes above
//! ```
//!
//! A slot is valid when its trailer is intact and its blob has the trailer's CRC and passes the
//! stored-model check ([`check_stored`], the one check commit and boot share); slot
//! [`FACTORY_SLOT`] with an erased trailer holds the blob flashed with the firmware (sequence 0).
//! At boot [`select`] picks the valid slot with the newer sequence number (serial-number
//! arithmetic, so the choice survives the wrap after `u32::MAX`), and [`load`] gives the bytes
//! the app runs (the blob's RAM copy); [`boot`] is the whole path, as the host tests and fuzzers
//! run it.
//!
//! An upload ([`Uploader`]): begin erases the slot that is not active; chunks are written in
//! order, each checked against its CRC before and after the write; commit checks the whole
//! blob's CRC and the model ([`check_stored`]: parse, rate and unit against the profile), then
//! writes the trailer and reads back that [`select`] now picks the new slot. Until that last
//! write the active slot is untouched and the new one invalid, so a power loss at any point
//! boots the previous model; after it, the new one. A refused chunk leaves the upload where it
//! was (resend it, or resume at the offset the reply names); a new begin restarts from scratch.
//!
//! While flagging is armed (a grasp may be in progress) begin and commit are refused with
//! `ARMED`: begin would stall the CPU for the sector erase, commit would restart the board.
//! Chunks are stored (a chunk's write stalls the CPU well under a millisecond), and the upload
//! stays complete, so the host commits again after release. After an accepted commit the board
//! handles nothing more ([`receive`] stops there): it sends the reply and restarts onto the new
//! model, never during a grasp.

use crate::app::{App, SystemFault, check_stored};
use crate::profile::Profile;
use slipguard_core::blob::CRC32;
use slipguard_core::model_ram::{LoadError, ModelRam};
use slipguard_core::protocol::{
    Chunk, Command, DecodeError, Error, Frame, Message, ReplyBody, ReplyStatus, msg_type,
    upload_code,
};

/// Model slots.
pub const SLOTS: u8 = 2;
/// The slot the firmware image's default model is flashed into (without a trailer).
pub const FACTORY_SLOT: u8 = 1;
/// Trailer bytes at the end of each slot.
pub const TRAILER_LEN: usize = 20;
/// Flash program granularity: offsets and lengths of writes are multiples of it (STM32F4 with
/// 32-bit parallelism).
pub const WRITE_ALIGN: usize = 4;
/// Trailer magic.
pub const TRAILER_MAGIC: [u8; 4] = *b"SGSL";

/// A failed flash operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FlashError {
    /// Erasing the slot failed.
    Erase,
    /// Programming failed (or the range is outside the slot / misaligned).
    Write,
}

impl core::fmt::Display for FlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Erase => write!(f, "flash erase failed"),
            Self::Write => write!(f, "flash write failed"),
        }
    }
}

impl core::error::Error for FlashError {}

/// The two model slots as the board's flash driver sees them.
pub trait Flash {
    /// Bytes per slot (one erase sector; 128 KiB on the F405).
    fn slot_len(&self) -> usize;
    /// Erases slot `slot` (all bytes 0xFF).
    fn erase(&mut self, slot: u8) -> Result<(), FlashError>;
    /// Programs `data` at `offset` of slot `slot` (both multiples of [`WRITE_ALIGN`]; the
    /// bytes must be erased).
    fn write(&mut self, slot: u8, offset: usize, data: &[u8]) -> Result<(), FlashError>;
    /// The slot's bytes as memory-mapped (4-byte aligned); empty for an unknown slot.
    fn read(&self, slot: u8) -> &[u8];
}

/// A slot's trailer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trailer {
    /// Higher wins at boot.
    pub seq: u32,
    /// Blob length.
    pub len: u32,
    /// CRC-32 of the blob.
    pub crc: u32,
}

impl Trailer {
    /// The trailer's bytes.
    pub fn to_bytes(&self) -> [u8; TRAILER_LEN] {
        let mut b = [0u8; TRAILER_LEN];
        b[0..4].copy_from_slice(&TRAILER_MAGIC);
        b[4..8].copy_from_slice(&self.seq.to_le_bytes());
        b[8..12].copy_from_slice(&self.len.to_le_bytes());
        b[12..16].copy_from_slice(&self.crc.to_le_bytes());
        let crc = CRC32.checksum(&b[..16]);
        b[16..20].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// Parses trailer bytes: `None` when the magic or the CRC is wrong (e.g. a cut write).
    pub fn from_bytes(b: &[u8]) -> Option<Self> {
        let w = |i: usize| -> Option<u32> {
            Some(u32::from_le_bytes(b.get(i..i + 4)?.try_into().ok()?))
        };
        if b.get(0..4)? != TRAILER_MAGIC || w(16)? != CRC32.checksum(b.get(..16)?) {
            return None;
        }
        Some(Self {
            seq: w(4)?,
            len: w(8)?,
            crc: w(12)?,
        })
    }
}

/// The slot to run from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Active {
    /// Slot index.
    pub slot: u8,
    /// Its sequence number (0: the factory blob).
    pub seq: u32,
    /// Blob length.
    pub len: usize,
}

/// Whether `slot` holds a valid model for `profile`, and which.
pub fn slot_state(flash: &impl Flash, profile: &Profile, slot: u8) -> Option<Active> {
    let bytes = flash.read(slot);
    let tail = bytes.len().checked_sub(TRAILER_LEN)?;
    let trailer = &bytes[tail..];
    let (seq, len) = if trailer.iter().all(|&b| b == 0xFF) {
        if slot != FACTORY_SLOT {
            return None;
        }
        // The factory blob: its own header gives the length, its own CRC is checked below.
        let len = u32::from_le_bytes(bytes.get(8..12)?.try_into().ok()?) as usize;
        (0, len)
    } else {
        let t = Trailer::from_bytes(trailer)?;
        let blob = bytes
            .get(..t.len as usize)
            .filter(|_| t.len as usize <= tail)?;
        if CRC32.checksum(blob) != t.crc {
            return None;
        }
        (t.seq, t.len as usize)
    };
    let blob = bytes.get(..len).filter(|_| len <= tail)?;
    check_stored(profile, blob).ok()?;
    Some(Active { slot, seq, len })
}

/// Whether sequence number `a` is newer than `b`. 0 is the factory blob's (a slot without a
/// trailer: the blob flashed with the firmware, or an upload into that slot that was never
/// committed), older than every committed number; committed numbers skip 0 and compare in
/// serial-number arithmetic (RFC 1982): `a` is ahead of `b` by less than half the number space,
/// so 1 is newer than `u32::MAX`. The two slots' numbers differ by one (each commit numbers the
/// active slot's + 1), far inside it.
pub fn newer(a: u32, b: u32) -> bool {
    match (a, b) {
        (0, _) => false,
        (_, 0) => true,
        // The difference as a signed count: positive while `a` is less than 2^31 ahead.
        _ => (a.wrapping_sub(b) as i32) > 0,
    }
}

/// The sequence number a commit gives the new slot: the active one's + 1, skipping 0 (the
/// factory blob's) at the wrap.
pub fn next_seq(active: Option<Active>) -> u32 {
    match active.map_or(0, |a| a.seq).wrapping_add(1) {
        0 => 1,
        s => s,
    }
}

/// The slot to boot from: the valid one with the newer sequence number ([`newer`]; `None`: no
/// valid model in either slot; the app then runs in a system fault and an upload can fix it).
pub fn select(flash: &impl Flash, profile: &Profile) -> Option<Active> {
    (0..SLOTS)
        .filter_map(|s| slot_state(flash, profile, s))
        .reduce(|a, b| if newer(b.seq, a.seq) { b } else { a })
}

/// The bytes the app runs for the active slot's `blob` (empty without one): its RAM copy
/// ([`ModelRam::load`]), or `blob` itself where it lies when the copy is refused (a blob larger
/// than the buffer runs from flash; a bad one is reported by the app). The error says why, for
/// the boot log.
pub fn load<'a, const N: usize>(
    ram: &'a mut ModelRam<N>,
    blob: &'a [u8],
) -> (&'a [u8], Result<(), LoadError>) {
    match ram.load(blob) {
        Ok(copy) => (copy, Ok(())),
        Err(e) => (blob, Err(e)),
    }
}

/// The whole boot path as the board runs it: [`select`], the slot's [`blob`], [`load`] into
/// `ram`, and the app over the result. For the host (the board layer does the same steps with
/// its flash's `'static` bytes).
pub fn boot<'a, const N: usize>(
    flash: &'a impl Flash,
    profile: Profile,
    ram: &'a mut ModelRam<N>,
) -> (Option<Active>, App<'a>) {
    let active = select(flash, &profile);
    let (bytes, _) = load(ram, blob(flash, active));
    (active, App::new(profile, bytes))
}

/// Whether flagging is on with a model running: what refuses an upload's begin and commit.
fn flagging(app: &App<'_>) -> bool {
    app.armed() && app.model().is_ok()
}

/// The blob bytes of the active slot (empty without one), for [`App::new`] or [`App::reload`].
pub fn blob(flash: &impl Flash, active: Option<Active>) -> &[u8] {
    active
        .and_then(|a| flash.read(a.slot).get(..a.len))
        .unwrap_or(&[])
}

/// What the board layer must do after a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[must_use]
pub enum Outcome {
    /// Nothing beyond sending the reply.
    None,
    /// A new model is active in this slot: send the reply, then restart onto it (the firmware
    /// resets and boots it; a board layer without a reset reloads the app in place,
    /// [`App::reload`] over [`load`] of [`blob`]). Flagging is off: the commit was refused
    /// otherwise.
    Reload(Active),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct InProgress {
    slot: u8,
    size: u32,
    crc: u32,
    next: u32,
}

/// The upload state machine (one per board).
#[derive(Clone, Debug)]
pub struct Uploader {
    active: Option<Active>,
    job: Option<InProgress>,
}

/// An upload reply: (code, detail, value).
type Refusal = (u8, u8, u32);

impl Uploader {
    /// After boot with `active` (the result of [`select`]).
    pub const fn new(active: Option<Active>) -> Self {
        Self { active, job: None }
    }

    /// The active slot.
    pub fn active(&self) -> Option<Active> {
        self.active
    }

    /// The slot an upload writes into: the one that is not active.
    pub fn target(&self) -> u8 {
        match self.active {
            Some(a) => (a.slot + 1) % SLOTS,
            None => 0,
        }
    }

    /// Answers one received frame: upload commands here, everything else by `app`. The reply
    /// is numbered by the app; on [`Outcome::Reload`] the board layer reloads the app.
    pub fn handle<F: Flash>(
        &mut self,
        app: &mut App<'_>,
        flash: &mut F,
        received: Result<Frame, (DecodeError, Error)>,
    ) -> (Frame, Outcome) {
        let Ok(Frame {
            seq,
            msg: Message::Command(cmd),
        }) = received
        else {
            return (app.handle(received), Outcome::None);
        };
        let armed = flagging(app);
        let profile = *app.profile();
        let result = match cmd {
            Command::UploadBegin { size, crc } => self.begin(flash, armed, size, crc),
            Command::UploadChunk(c) => self.chunk(flash, &c),
            Command::UploadCommit => self.commit(flash, &profile, armed),
            _ => return (app.handle(received), Outcome::None),
        };
        let (code, detail, value, outcome) = match result {
            Ok((value, outcome)) => (upload_code::OK, 0, value, outcome),
            Err((code, detail, value)) => (code, detail, value, Outcome::None),
        };
        let slot = match outcome {
            Outcome::Reload(a) => a.slot,
            Outcome::None => self.job.map_or(self.target(), |j| j.slot),
        };
        let status = if code == upload_code::OK {
            ReplyStatus::Ok
        } else {
            ReplyStatus::BadArgument
        };
        let body = ReplyBody::Upload {
            command: cmd.msg_type(),
            code,
            detail,
            slot,
            value,
        };
        (app.reply(seq, status, body), outcome)
    }

    /// Begin: checks the size, erases the target slot. Value: the slot's capacity.
    fn begin<F: Flash>(
        &mut self,
        flash: &mut F,
        armed: bool,
        size: u32,
        crc: u32,
    ) -> Result<(u32, Outcome), Refusal> {
        let capacity = flash.slot_len().saturating_sub(TRAILER_LEN) as u32;
        if armed {
            return Err((upload_code::ARMED, 0, 0));
        }
        // A restart abandons any upload in progress.
        self.job = None;
        if size == 0 || size > capacity || !(size as usize).is_multiple_of(WRITE_ALIGN) {
            return Err((upload_code::WRONG_SIZE, 0, capacity));
        }
        let slot = self.target();
        flash.erase(slot).map_err(|_| (upload_code::FLASH, 1, 0))?;
        self.job = Some(InProgress {
            slot,
            size,
            crc,
            next: 0,
        });
        Ok((capacity, Outcome::None))
    }

    /// One chunk, in order. Value: the next expected offset.
    fn chunk<F: Flash>(&mut self, flash: &mut F, c: &Chunk) -> Result<(u32, Outcome), Refusal> {
        let Some(job) = self.job.as_mut() else {
            return Err((upload_code::NOT_STARTED, 0, 0));
        };
        let data = c.bytes();
        if CRC32.checksum(data) != c.crc {
            return Err((upload_code::BAD_CHUNK, 0, job.next));
        }
        if c.offset != job.next {
            return Err((upload_code::OUT_OF_ORDER, 0, job.next));
        }
        let end = job.next as usize + data.len();
        if end > job.size as usize || !data.len().is_multiple_of(WRITE_ALIGN) {
            return Err((upload_code::CHUNK_LENGTH, 0, job.next));
        }
        flash
            .write(job.slot, job.next as usize, data)
            .map_err(|_| (upload_code::FLASH, 2, job.next))?;
        let written = flash.read(job.slot).get(job.next as usize..end);
        if written.map(|w| CRC32.checksum(w)) != Some(c.crc) {
            return Err((upload_code::FLASH, 3, job.next));
        }
        job.next = end as u32;
        Ok((job.next, Outcome::None))
    }

    /// Commit: whole-blob CRC, model check, then the trailer. Value: the new sequence number.
    /// Refused while `armed`, the upload kept (value: the bytes stored), to be committed after
    /// release.
    fn commit<F: Flash>(
        &mut self,
        flash: &mut F,
        profile: &Profile,
        armed: bool,
    ) -> Result<(u32, Outcome), Refusal> {
        let Some(job) = self.job else {
            return Err((upload_code::NOT_STARTED, 0, 0));
        };
        if job.next != job.size {
            return Err((upload_code::INCOMPLETE, 0, job.next));
        }
        if armed {
            return Err((upload_code::ARMED, 0, job.next));
        }
        // From here on the upload is over, accepted or not: a refused blob needs a new begin.
        self.job = None;
        let bytes = flash.read(job.slot);
        let blob = bytes.get(..job.size as usize).unwrap_or(&[]);
        let computed = CRC32.checksum(blob);
        if computed != job.crc {
            return Err((upload_code::BLOB_CRC, 0, computed));
        }
        if let Err(e) = check_stored(profile, blob) {
            return Err(match e {
                SystemFault::BadModel(b) => {
                    let (detail, value) = b.wire_detail();
                    (upload_code::BAD_BLOB, detail, value)
                }
                SystemFault::RateMismatch(r) => (upload_code::RATE_MISMATCH, 0, r),
                SystemFault::UnitMismatch => {
                    let unit = slipguard_core::model::Model::from_bytes(blob)
                        .map_or(0xFF, |m| m.config().input_unit as u32);
                    (upload_code::UNIT_MISMATCH, 0, unit)
                }
            });
        }
        let seq = next_seq(self.active);
        let trailer = Trailer {
            seq,
            len: job.size,
            crc: job.crc,
        };
        let at = flash.slot_len() - TRAILER_LEN;
        flash
            .write(job.slot, at, &trailer.to_bytes())
            .map_err(|_| (upload_code::FLASH, 2, 0))?;
        // The new slot must now be the one a reboot chooses: the reply says what boots.
        let new = select(flash, profile).filter(|a| a.slot == job.slot && a.seq == seq);
        let Some(new) = new else {
            return Err((upload_code::FLASH, 3, 0));
        };
        self.active = Some(new);
        Ok((seq, Outcome::Reload(new)))
    }
}

/// Feeds received bytes through the deframer, the uploader and the app (as
/// [`crate::replay::receive`], with uploads); every reply goes to `sink`. Returns the slot to
/// restart onto when a commit made a new model active (the board sends the replies first):
/// the bytes after that commit are not handled (the board restarts; the host waits for it).
pub fn receive<F: Flash>(
    up: &mut Uploader,
    app: &mut App<'_>,
    flash: &mut F,
    deframer: &mut slipguard_core::protocol::Deframer,
    bytes: &[u8],
    mut sink: impl FnMut(&Frame),
) -> Option<Active> {
    for &b in bytes {
        if let Some(r) = deframer.push_decode(b) {
            let (reply, outcome) = up.handle(app, flash, r);
            sink(&reply);
            if let Outcome::Reload(a) = outcome {
                return Some(a);
            }
        }
    }
    None
}

/// Every upload command is a [`msg_type`] the uploader answers.
pub fn is_upload(t: u8) -> bool {
    matches!(
        t,
        msg_type::UPLOAD_BEGIN | msg_type::UPLOAD_CHUNK | msg_type::UPLOAD_COMMIT
    )
}

/// A flash in RAM with NOR semantics (erase to 0xFF, programming clears bits) that can lose
/// power before any operation: for the host tests and RAM-backed slots under QEMU.
pub struct SimFlash<'a> {
    slots: [&'a mut [u32]; SLOTS as usize],
    /// Operations (erase or write) done so far.
    pub ops: usize,
    /// Power is lost at this operation: it is done halfway (the first half of the words), it
    /// and every later one fail.
    pub cut_at: Option<usize>,
}

impl<'a> SimFlash<'a> {
    /// Two slots over word buffers of equal length.
    pub fn new(slot0: &'a mut [u32], slot1: &'a mut [u32]) -> Self {
        Self {
            slots: [slot0, slot1],
            ops: 0,
            cut_at: None,
        }
    }

    fn op(&mut self) -> Result<bool, FlashError> {
        let i = self.ops;
        self.ops += 1;
        match self.cut_at {
            Some(c) if i > c => Err(FlashError::Write),
            Some(c) if i == c => Ok(true),
            _ => Ok(false),
        }
    }

    /// Whether power was lost.
    pub fn cut(&self) -> bool {
        self.cut_at.is_some_and(|c| self.ops > c)
    }
}

impl Flash for SimFlash<'_> {
    fn slot_len(&self) -> usize {
        self.slots[0].len() * 4
    }

    fn erase(&mut self, slot: u8) -> Result<(), FlashError> {
        let half = self.op().map_err(|_| FlashError::Erase)?;
        let s = self.slots.get_mut(slot as usize).ok_or(FlashError::Erase)?;
        let n = if half { s.len() / 2 } else { s.len() };
        s[..n].fill(u32::MAX);
        if half { Err(FlashError::Erase) } else { Ok(()) }
    }

    fn write(&mut self, slot: u8, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        if !offset.is_multiple_of(WRITE_ALIGN) || !data.len().is_multiple_of(WRITE_ALIGN) {
            return Err(FlashError::Write);
        }
        let half = self.op()?;
        let s = self.slots.get_mut(slot as usize).ok_or(FlashError::Write)?;
        let words = s
            .get_mut(offset / 4..(offset + data.len()) / 4)
            .ok_or(FlashError::Write)?;
        let n = if half { words.len() / 2 } else { words.len() };
        for (w, b) in words.iter_mut().zip(data.chunks_exact(4)).take(n) {
            *w &= u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
        }
        if half { Err(FlashError::Write) } else { Ok(()) }
    }

    fn read(&self, slot: u8) -> &[u8] {
        match self.slots.get(slot as usize) {
            Some(s) => bytemuck::cast_slice(s),
            None => &[],
        }
    }
}
