//! `slipguard-export upload`: sends a model blob to the firmware over its serial link
//! (docs/protocol.md, "Model upload"). The file is checked first, before the port is opened
//! ([`check_blob`]); then an info request, and the board's own model check for its sensor
//! profile ([`check_board`]) before anything is written; begin, chunks of 128 bytes with their
//! CRC, commit; then info requests until the restarted board runs the new model. Frames the
//! device streams meanwhile (flags, samples) are skipped; a lost or damaged frame is resent, an
//! out-of-order reply resumes at the offset the device names. While flagging is armed (a grasp)
//! the board refuses begin and commit: the upload waits for the release ([`Options::wait_armed`])
//! and never sends one itself once the upload has begun. Every refusal becomes an error whose
//! message says what happened and what to do.

use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

use slipguard_app::app::{SystemFault, check_stored};
use slipguard_app::profile::ProfileId;
use slipguard_core::blob::{CRC32, IMAGE_MAGIC, ModelBlob};
use slipguard_core::protocol::{
    self, Chunk, Command, Deframer, Frame, Info, MAX_CHUNK, MAX_WIRE, Message, ReplyBody,
    ReplyStatus, msg_type, upload_code,
};

/// Why an upload failed.
#[derive(Debug)]
#[non_exhaustive]
pub enum UploadError {
    /// The file is not a valid blob (checked before anything is sent).
    Blob(String),
    /// The serial port failed.
    Io(io::Error),
    /// No reply in time, after every retry.
    NoReply {
        /// The command that went unanswered.
        what: &'static str,
    },
    /// The device refused a command.
    Refused {
        /// The upload reply code.
        code: u8,
        /// Its detail byte.
        detail: u8,
        /// Its value.
        value: u32,
    },
    /// The device answered the final info with another model than the one sent.
    NotActive {
        /// The CRC the device reports.
        running: u32,
        /// The CRC of the blob sent.
        sent: u32,
    },
    /// The board's sensor profile does not run this model (its own check, made here before
    /// anything is written).
    WrongBoard(String),
    /// Flagging stayed armed (a grasp) for the whole wait.
    Armed {
        /// Whether the blob was already stored (the commit was refused) or nothing was written
        /// (begin was refused).
        stored: bool,
        /// How long the upload waited for the release.
        waited: Duration,
    },
}

impl UploadError {
    /// Process exit code: 12 invalid blob (as `export`/`inspect`), 3 I/O or no reply, 14 the
    /// device refused (or would: another profile; or armed), 13 the model did not become active.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Blob(_) => 12,
            Self::Io(_) | Self::NoReply { .. } => 3,
            Self::Refused { .. } | Self::WrongBoard(_) | Self::Armed { .. } => 14,
            Self::NotActive { .. } => 13,
        }
    }
}

impl std::fmt::Display for UploadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Blob(m) => write!(
                f,
                "not a model blob: {m}; re-export it with slipguard-export"
            ),
            Self::Io(e) => write!(
                f,
                "serial port: {e}; check --port and that nothing else holds it"
            ),
            Self::NoReply { what } => write!(
                f,
                "no reply to {what}: check the cable, the port and --baud (921600), and that the firmware is running"
            ),
            Self::Refused {
                code,
                detail,
                value,
            } => f.write_str(&refusal_hint(*code, *detail, *value)),
            Self::NotActive { running, sent } => write!(
                f,
                "the commit was accepted, but the device still runs model CRC {running:#010x}, not the uploaded {sent:#010x}: it restarts onto the new model after the commit (never while armed); check for fault frames, power-cycle it, or upload again"
            ),
            Self::WrongBoard(m) => write!(f, "nothing written: {m}"),
            Self::Armed {
                stored: false,
                waited,
            } => write!(
                f,
                "nothing written: flagging stayed armed for {:.1} s (a grasp in progress, or no release since the board started): release the hand, or pass --release when it is open, and run the upload again (--wait-armed waits longer)",
                waited.as_secs_f64()
            ),
            Self::Armed {
                stored: true,
                waited,
            } => write!(
                f,
                "the blob is on the board but not committed: flagging was armed (a grasp started during the upload) and stayed so for {:.1} s; the old model still runs. Run the upload again once the hand is released (--wait-armed waits longer)",
                waited.as_secs_f64()
            ),
        }
    }
}

impl std::error::Error for UploadError {}

impl From<io::Error> for UploadError {
    fn from(e: io::Error) -> Self {
        Self::Io(e)
    }
}

/// One line per refusal code: what happened and what to fix (the table in docs/protocol.md).
pub fn refusal_hint(code: u8, detail: u8, value: u32) -> String {
    use upload_code::*;
    match code {
        NOT_STARTED => "device refused: no upload in progress (it was restarted or a commit was refused): run the upload again".into(),
        ARMED => "device refused: flagging is armed (a grasp): send release first (add --release) while the hand is open, or wait for the release".into(),
        WRONG_SIZE => format!(
            "device refused: blob size is 0, not a multiple of 4, or over the slot's {value} bytes: export a smaller model"
        ),
        OUT_OF_ORDER => format!("device refused: chunk out of order (expects offset {value}): run the upload again"),
        BAD_CHUNK => format!("device refused: chunk CRC mismatch at offset {value} after retries: check the cable and the baud rate"),
        CHUNK_LENGTH => format!("device refused: chunk past the announced size at offset {value}: the file changed during the upload"),
        FLASH => format!(
            "device refused: flash {} failed at offset {value}: retry; if it persists the model sector is worn",
            match detail {
                1 => "erase",
                2 => "write",
                _ => "read-back",
            }
        ),
        INCOMPLETE => format!("device refused: commit after {value} bytes, blob incomplete: run the upload again"),
        BLOB_CRC => format!("device refused: the blob arrived with CRC {value:#010x}, not the file's: run the upload again"),
        BAD_BLOB => format!(
            "device refused: the blob does not parse (blob error {detail}, value {value}, see docs/protocol.md): re-export the model with slipguard-export"
        ),
        RATE_MISMATCH => format!(
            "device refused: the model runs at {:.1} Hz, a rate this firmware's sensor profile does not run: train and export at the profile's rate (info shows it)",
            value as f64 / 1000.0
        ),
        UNIT_MISMATCH => format!(
            "device refused: the model takes {} but the sensor profile delivers the other unit: export with --input-unit for this profile",
            if value == 0 { "mN" } else { "counts" }
        ),
        UNSUPPORTED => "device refused: this firmware build has no model flash: flash the board firmware".into(),
        c => format!("device refused with unknown code {c} (detail {detail}, value {value}): update slipguard-export"),
    }
}

/// What a successful upload reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Uploaded {
    /// Slot now active.
    pub slot: u8,
    /// Its sequence number.
    pub seq: u32,
    /// The device's info after the upload.
    pub info: Info,
    /// Chunks resent (lost or damaged frames).
    pub resent: u32,
    /// Time spent waiting for flagging to go off (begin or commit refused as armed).
    pub waited_armed: Duration,
}

/// Upload settings.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Send release before begin (the device refuses an upload while armed).
    pub release: bool,
    /// Reply timeout for chunks and commit.
    pub timeout: Duration,
    /// Reply timeout for begin (erasing a 128 KiB sector takes up to 2 s).
    pub erase_timeout: Duration,
    /// Resends of one command before giving up.
    pub retries: u32,
    /// How long to keep asking while the board refuses begin or commit as armed (a grasp in
    /// progress), every `timeout`; zero: give up at the first refusal.
    pub wait_armed: Duration,
    /// How long the board may take to restart onto the new model after the commit.
    pub restart_timeout: Duration,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            release: false,
            timeout: Duration::from_millis(500),
            erase_timeout: Duration::from_secs(5),
            retries: 5,
            wait_armed: Duration::from_secs(10),
            restart_timeout: Duration::from_secs(5),
        }
    }
}

/// Checks a file before anything is sent (before the port is opened): a blob that parses (CRC,
/// version, sizes), not a RAM image, a whole number of 4-byte words. Returns its fingerprint
/// (its own CRC, what info reports as `model_crc`).
pub fn check_blob(blob: &[u8]) -> Result<u32, UploadError> {
    let aligned = slipguard_core::blob::AlignedBlob::new(blob);
    let parsed =
        ModelBlob::parse(aligned.as_bytes()).map_err(|e| UploadError::Blob(e.to_string()))?;
    if blob.get(..4) == Some(&IMAGE_MAGIC[..]) {
        return Err(UploadError::Blob(
            "this is a RAM image (magic SGMI), which the board makes from a blob in its RAM; upload the blob (SGMB) it was made from".into(),
        ));
    }
    if !blob.len().is_multiple_of(4) {
        return Err(UploadError::Blob(format!(
            "{} bytes is not a whole number of 4-byte words",
            blob.len()
        )));
    }
    Ok(parsed.crc)
}

/// The board's own model check ([`check_stored`]) for the sensor profile its info reports, so
/// that a model of the wrong rate or unit is refused before anything is written; a profile this
/// tool does not know is left to the board.
pub fn check_board(blob: &[u8], info: &Info) -> Result<(), UploadError> {
    let Some(profile) = ProfileId::from_u8(info.profile).map(ProfileId::profile) else {
        return Ok(());
    };
    let aligned = slipguard_core::blob::AlignedBlob::new(blob);
    match check_stored(&profile, aligned.as_bytes()) {
        Ok(_) => Ok(()),
        Err(SystemFault::RateMismatch(r)) => {
            let rates: Vec<String> = profile
                .rates_mhz
                .iter()
                .map(|&x| format!("{:.1} Hz", x.hz()))
                .collect();
            Err(UploadError::WrongBoard(format!(
                "the model runs at {:.1} Hz, the board's {} profile runs {}: train and export at one of those rates",
                r as f64 / 1000.0,
                profile.name,
                rates.join(" or ")
            )))
        }
        Err(SystemFault::UnitMismatch) => Err(UploadError::WrongBoard(format!(
            "the board's {} profile delivers {}, the model takes the other unit: export with --input-unit {}",
            profile.name,
            profile.unit.name(),
            profile.unit.name()
        ))),
        Err(SystemFault::BadModel(e)) => Err(UploadError::Blob(e.to_string())),
    }
}

/// A serial link to the device: writes go out, reads return what arrived (a read timeout is
/// an `io::ErrorKind::TimedOut` or `WouldBlock`, as serialport's).
pub struct Link<P> {
    port: P,
    deframer: Deframer,
    seq: u16,
    /// Bytes read but not yet decoded (what followed a reply in the same read).
    pending: std::collections::VecDeque<u8>,
}

/// A reply or an error frame answering one command.
enum Answer {
    Reply(ReplyStatus, ReplyBody),
    /// The device rejected the frame (damaged on the wire).
    Rejected,
}

impl<P: Read + Write> Link<P> {
    /// Wraps an open port.
    pub fn new(port: P) -> Self {
        Self {
            port,
            deframer: Deframer::new(),
            seq: 0x4000,
            pending: std::collections::VecDeque::new(),
        }
    }

    /// The port.
    pub fn into_inner(self) -> P {
        self.port
    }

    fn send(&mut self, c: Command) -> Result<u16, UploadError> {
        self.seq = self.seq.wrapping_add(1);
        let mut w = [0u8; MAX_WIRE];
        let n = protocol::encode(
            &Frame {
                seq: self.seq,
                msg: Message::Command(c),
            },
            &mut w,
        );
        self.port.write_all(&w[..n])?;
        self.port.flush()?;
        Ok(self.seq)
    }

    /// Waits for the answer to command `seq` of type `t`, skipping the stream; `None` on
    /// timeout. The timeout counts from the last byte received (a reply under way is not cut
    /// off), and the port is read at least once, so a descheduled host does not time out a
    /// reply that has already arrived.
    fn wait(&mut self, seq: u16, t: u8, timeout: Duration) -> Result<Option<Answer>, UploadError> {
        let mut end = Instant::now() + timeout;
        let mut buf = [0u8; 256];
        let mut first = true;
        while first || Instant::now() < end {
            first = false;
            if self.pending.is_empty() {
                let n = match self.port.read(&mut buf) {
                    Ok(n) => n,
                    Err(e)
                        if matches!(
                            e.kind(),
                            io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
                        ) =>
                    {
                        0
                    }
                    Err(e) => return Err(e.into()),
                };
                if n > 0 {
                    end = Instant::now() + timeout;
                }
                self.pending.extend(&buf[..n]);
            }
            while let Some(b) = self.pending.pop_front() {
                match self.deframer.push_decode(b) {
                    Some(Ok(Frame {
                        msg: Message::Reply(r),
                        ..
                    })) if r.request_seq == seq && r.body.msg_type() == t | msg_type::REPLY => {
                        return Ok(Some(Answer::Reply(r.status, r.body)));
                    }
                    Some(Ok(Frame {
                        msg: Message::Error(e),
                        ..
                    })) if e.request_seq == seq || e.request_seq == 0xFFFF => {
                        return Ok(Some(Answer::Rejected));
                    }
                    _ => {}
                }
            }
        }
        Ok(None)
    }

    /// Sends `c` until it is answered (resending on a rejected frame or a timeout).
    fn call(
        &mut self,
        c: Command,
        what: &'static str,
        timeout: Duration,
        retries: u32,
        resent: &mut u32,
    ) -> Result<(ReplyStatus, ReplyBody), UploadError> {
        for attempt in 0..=retries {
            if attempt > 0 {
                *resent += 1;
            }
            let seq = self.send(c)?;
            match self.wait(seq, c.msg_type(), timeout)? {
                Some(Answer::Reply(s, b)) => return Ok((s, b)),
                Some(Answer::Rejected) | None => continue,
            }
        }
        Err(UploadError::NoReply { what })
    }

    /// The device's info.
    pub fn info(&mut self, timeout: Duration) -> Result<Info, UploadError> {
        let mut resent = 0;
        match self.call(Command::Info, "info", timeout, 3, &mut resent)? {
            (_, ReplyBody::Info(i)) => Ok(i),
            _ => Err(UploadError::NoReply { what: "info" }),
        }
    }

    /// Sends `c` (an upload command) until it is answered, and while the board refuses it as
    /// armed, again every `timeout` until `opt.wait_armed` is spent (`waited` grows by the time
    /// spent). Returns (code, detail, slot, value).
    fn upload_call(
        &mut self,
        c: Command,
        what: &'static str,
        timeout: Duration,
        opt: &Options,
        resent: &mut u32,
        waited: &mut Duration,
    ) -> Result<(u8, u8, u8, u32), UploadError> {
        let mut armed_since: Option<Instant> = None;
        loop {
            let r = match self.call(c, what, timeout, opt.retries, resent)? {
                (
                    _,
                    ReplyBody::Upload {
                        code,
                        detail,
                        slot,
                        value,
                        ..
                    },
                ) => (code, detail, slot, value),
                _ => return Err(UploadError::NoReply { what }),
            };
            if r.0 != upload_code::ARMED {
                *waited += armed_since.map_or(Duration::ZERO, |t| t.elapsed());
                return Ok(r);
            }
            let since = *armed_since.get_or_insert_with(Instant::now);
            let left = opt.wait_armed.saturating_sub(since.elapsed());
            if left.is_zero() {
                *waited += since.elapsed();
                return Ok(r);
            }
            std::thread::sleep(opt.timeout.min(left));
        }
    }

    /// Uploads `blob`; `progress` gets (bytes acknowledged, total).
    pub fn upload(
        &mut self,
        blob: &[u8],
        opt: &Options,
        mut progress: impl FnMut(usize, usize),
    ) -> Result<Uploaded, UploadError> {
        let fingerprint = check_blob(blob)?;
        let mut resent = 0;
        let mut waited = Duration::ZERO;
        if opt.release {
            self.call(
                Command::Release,
                "release",
                opt.timeout,
                opt.retries,
                &mut resent,
            )?;
        }
        // The board's profile runs this model? Checked before anything is written.
        check_board(blob, &self.info(opt.timeout)?)?;
        let begin = Command::UploadBegin {
            size: blob.len() as u32,
            crc: CRC32.checksum(blob),
        };
        let (code, detail, _, value) = self.upload_call(
            begin,
            "upload begin",
            opt.erase_timeout,
            opt,
            &mut resent,
            &mut waited,
        )?;
        match code {
            upload_code::OK => {}
            upload_code::ARMED => {
                return Err(UploadError::Armed {
                    stored: false,
                    waited,
                });
            }
            _ => {
                return Err(UploadError::Refused {
                    code,
                    detail,
                    value,
                });
            }
        }
        let mut offset = 0usize;
        let mut tries = 0;
        while offset < blob.len() {
            let end = (offset + MAX_CHUNK).min(blob.len());
            let chunk = Command::UploadChunk(Chunk::new(offset as u32, &blob[offset..end]));
            let (code, detail, _, value) = self.upload_call(
                chunk,
                "upload chunk",
                opt.timeout,
                opt,
                &mut resent,
                &mut waited,
            )?;
            match code {
                upload_code::OK => {
                    offset = value as usize;
                    tries = 0;
                    progress(offset, blob.len());
                }
                // A resent chunk the device already has, or a chunk damaged in between:
                // resume where the device says.
                upload_code::OUT_OF_ORDER | upload_code::BAD_CHUNK if tries < opt.retries => {
                    tries += 1;
                    resent += 1;
                    offset = value as usize;
                }
                _ => {
                    return Err(UploadError::Refused {
                        code,
                        detail,
                        value,
                    });
                }
            }
        }
        let (code, detail, slot, value) = self.upload_call(
            Command::UploadCommit,
            "upload commit",
            opt.erase_timeout,
            opt,
            &mut resent,
            &mut waited,
        )?;
        match code {
            upload_code::OK => {}
            upload_code::ARMED => {
                return Err(UploadError::Armed {
                    stored: true,
                    waited,
                });
            }
            // A commit resent after its reply was lost finds no upload in progress on the
            // restarted board: the info says whether the first one took.
            upload_code::NOT_STARTED => {}
            _ => {
                return Err(UploadError::Refused {
                    code,
                    detail,
                    value,
                });
            }
        }
        // The board restarts onto the new model: ask until it runs it.
        let info = self.await_model(fingerprint, opt)?;
        if code != upload_code::OK && info.model_crc != fingerprint {
            return Err(UploadError::Refused {
                code,
                detail,
                value,
            });
        }
        if info.model_ok != 1 || info.model_crc != fingerprint {
            return Err(UploadError::NotActive {
                running: info.model_crc,
                sent: fingerprint,
            });
        }
        Ok(Uploaded {
            slot,
            seq: value,
            info,
            resent,
            waited_armed: waited,
        })
    }

    /// Info requests until the device runs the model with `fingerprint` (it restarts after a
    /// commit; requests sent meanwhile go unanswered) or `opt.restart_timeout` is spent; the
    /// last info answered.
    fn await_model(&mut self, fingerprint: u32, opt: &Options) -> Result<Info, UploadError> {
        let start = Instant::now();
        let mut last = None;
        loop {
            match self.info(opt.timeout) {
                Ok(i) if i.model_ok == 1 && i.model_crc == fingerprint => return Ok(i),
                Ok(i) => last = Some(i),
                Err(UploadError::NoReply { .. }) => {}
                Err(e) => return Err(e),
            }
            if start.elapsed() >= opt.restart_timeout {
                return last.ok_or(UploadError::NoReply {
                    what: "info after the commit (the board did not come back)",
                });
            }
            std::thread::sleep(opt.timeout / 4);
        }
    }
}
