//! Wire protocol between the firmware and the hand controller (version 1).
//!
//! Byte-by-byte description, timing and examples: `docs/protocol.md`. This module is the only
//! encoder and decoder of it; the firmware, the QEMU build, the host replay and the monitor all
//! use it, and the golden tests pin its bytes.
//!
//! A frame on the wire is `COBS(payload) 00`. The payload is
//!
//! ```text
//! 0  u8   version (1)
//! 1  u8   type
//! 2  u16  seq          sender's frame counter (device: every frame it sends; controller: its commands)
//! 4  ...  body         fixed length per type
//! n  u32  CRC-32/ISO-HDLC of bytes 0..n
//! ```
//!
//! All integers are little-endian. Decoding checks, in this order: COBS, minimum length, CRC,
//! version, type, body length, field values; each failure has its own [`DecodeError`], and
//! nothing here panics on any input.

use crate::blob::CRC32;
use crate::decision::Q15;
use crate::units::Millihertz;

/// Protocol version carried in every frame.
pub const VERSION: u8 = 1;
/// Most channels a flag frame carries.
pub const MAX_CHANNELS: usize = 16;
/// Header bytes before the body (version, type, seq).
pub const HEADER_LEN: usize = 4;
/// Trailing CRC bytes.
pub const CRC_LEN: usize = 4;
/// Largest payload (decoded frame, CRC included) of any v1 message: an upload chunk with
/// [`MAX_CHUNK`] data bytes (header 4 + offset 4 + data + chunk CRC 4 + CRC 4). Below 254, so
/// COBS adds exactly one byte to every frame.
pub const MAX_PAYLOAD: usize = HEADER_LEN + 4 + MAX_CHUNK + 4 + CRC_LEN;
/// Most blob bytes one upload chunk carries.
pub const MAX_CHUNK: usize = 128;
/// Largest frame on the wire: COBS of the largest payload plus the 0x00 delimiter.
pub const MAX_WIRE: usize = cobs::max_encoding_length(MAX_PAYLOAD) + 1;
/// p(unstable) value that means "not predicted" (faulted channel, no model, not running): the
/// bits of [`PUnstable::NONE`].
pub const P_NONE: u16 = PUnstable::NONE.to_bits();

/// One channel's p(unstable) in a flag frame: Q0.15 (`0..=32 767`, +1.0 = 32 768, the model's
/// [`Q15`]) or [`PUnstable::NONE`] (`0xFFFF`) for a channel not predicted on (faulted, not in
/// contact, no model). The decoder refuses every other value, so [`PUnstable::q15`] is the only
/// way from the wire to a probability.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(transparent)]
pub struct PUnstable(u16);

impl PUnstable {
    /// Not predicted on.
    pub const NONE: Self = Self(0xFFFF);

    /// A model's p(unstable); negative values (never produced by the sigmoid) send as 0.
    pub const fn from_q15(p: Q15) -> Self {
        Self(if p.0 < 0 { 0 } else { p.0 as u16 })
    }

    /// `Some(p)` → [`Self::from_q15`], `None` → [`Self::NONE`].
    pub const fn of(p: Option<Q15>) -> Self {
        match p {
            Some(p) => Self::from_q15(p),
            None => Self::NONE,
        }
    }

    /// The probability, or `None` for [`Self::NONE`] (and for any bits above 32 767, which the
    /// decoder never lets through).
    pub const fn q15(self) -> Option<Q15> {
        if self.0 <= i16::MAX as u16 {
            Some(Q15(self.0 as i16))
        } else {
            None
        }
    }

    /// Whether the channel was not predicted on.
    pub const fn is_none(self) -> bool {
        self.0 == Self::NONE.0
    }

    /// The 16 bits on the wire.
    pub const fn to_bits(self) -> u16 {
        self.0
    }

    /// The value of 16 wire bits, if they are one (`0..=32 767` or `0xFFFF`).
    pub const fn from_bits(b: u16) -> Option<Self> {
        if b <= i16::MAX as u16 || b == Self::NONE.0 {
            Some(Self(b))
        } else {
            None
        }
    }
}

/// Declares a module of named `u8` codes and `ALL`, the table of every code with its doc text,
/// from which the C header (`host-tools/c/slipguard_protocol.h`) is generated.
macro_rules! codes {
    ($(#[doc = $mdoc:literal])* pub mod $module:ident {
        $( $(#[doc = $doc:literal])* $name:ident = $value:expr; )*
    }) => {
        $(#[doc = $mdoc])*
        pub mod $module {
            $( $(#[doc = $doc])* pub const $name: u8 = $value; )*
            /// Every code of this module, in declaration order.
            pub const ALL: &[super::Code] = &[$(super::Code {
                name: stringify!($name),
                value: $name,
                doc: concat!($($doc),*),
            }),*];
        }
    };
}

/// One named code of a [`codes!`] table (status bits, upload codes, fault codes …).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Code {
    /// The constant's name.
    pub name: &'static str,
    /// Its value on the wire.
    pub value: u8,
    /// Its doc text.
    pub doc: &'static str,
}

/// Message type (byte 1 of the payload). A reply's type is its command's type | [`msg_type::REPLY`].
/// With [`MsgType::body`] and [`MsgType::reply_body`] this is the protocol's one definition of
/// the wire layout: the body lengths the decoder checks, the C header and the layout tables of
/// `docs/protocol.md` come from it (`host-tools/tests/c_header.rs` fails when the checked-in
/// header or the docs differ from what it generates).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum MsgType {
    /// Device → controller: one frame of flags.
    Flags = 0x01,
    /// Device → controller: a system fault (bad model blob, rate mismatch…); no flags follow.
    Fault = 0x02,
    /// Device → controller: a received frame was rejected (bad CRC, unknown type…).
    Error = 0x03,
    /// Device → controller: one frame of model input per channel (sample stream).
    Samples = 0x04,
    /// Controller → device: ping.
    Ping = 0x10,
    /// Controller → device: grasp start (reset channel states, tare, start flagging).
    GraspStart = 0x11,
    /// Controller → device: release (stop flagging until the next grasp start).
    Release = 0x12,
    /// Controller → device: set threshold and hysteresis.
    SetThreshold = 0x13,
    /// Controller → device: info request.
    Info = 0x14,
    /// Controller → device: the lift starts (a phase mark only).
    Lift = 0x15,
    /// Controller → device: choose flags, flags + samples or samples.
    StreamMode = 0x16,
    /// Controller → device: start a model upload (size, whole-blob CRC).
    UploadBegin = 0x17,
    /// Controller → device: one chunk of the blob being uploaded.
    UploadChunk = 0x18,
    /// Controller → device: check the uploaded blob and make it the active model.
    UploadCommit = 0x19,
}

/// A field's type on the wire (little-endian).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireType {
    /// One byte.
    U8,
    /// Unsigned 16-bit.
    U16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit, two's complement.
    I32,
    /// That many bytes, copied as they are.
    Bytes(usize),
}

impl WireType {
    /// Bytes on the wire.
    pub const fn size(self) -> usize {
        match self {
            Self::U8 => 1,
            Self::U16 => 2,
            Self::U32 | Self::I32 => 4,
            Self::Bytes(n) => n,
        }
    }
}

/// One field of a message body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    /// Its name (the Rust field's, and the C struct member's where there is one).
    pub name: &'static str,
    /// Its wire type.
    pub ty: WireType,
    /// What it holds (the "meaning" column of `docs/protocol.md`).
    pub doc: &'static str,
}

const fn field(name: &'static str, ty: WireType, doc: &'static str) -> Field {
    Field { name, ty, doc }
}

/// What follows a body's fixed fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tail {
    /// Nothing: the body has a fixed length.
    None,
    /// One value per channel, N = the body's `channels` field (1..=[`MAX_CHANNELS`]).
    PerChannel(Field),
    /// 1..=[`MAX_CHUNK`] data bytes, then the chunk's CRC-32 (u32).
    ChunkData,
}

/// The layout of a message body (after the 4-byte header, before the CRC).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Body {
    /// The fixed fields, in wire order.
    pub fields: &'static [Field],
    /// What follows them.
    pub tail: Tail,
}

impl Body {
    /// Bytes of the fixed fields.
    pub const fn fixed_len(&self) -> usize {
        let mut n = 0;
        let mut i = 0;
        while i < self.fields.len() {
            n += self.fields[i].ty.size();
            i += 1;
        }
        n
    }

    /// Body length with `n` per-channel values or `n` chunk data bytes (ignored for a fixed body).
    pub const fn len(&self, n: usize) -> usize {
        match self.tail {
            Tail::None => self.fixed_len(),
            Tail::PerChannel(f) => self.fixed_len() + n * f.ty.size(),
            Tail::ChunkData => self.fixed_len() + n + 4,
        }
    }

    /// The shortest and longest body length the decoder accepts before reading any field: a
    /// per-channel body needs its fixed fields, and its exact length is checked once N is read
    /// (so that N out of range is reported as a bad value, not a bad length).
    pub const fn len_range(&self) -> (usize, usize) {
        match self.tail {
            Tail::None => (self.fixed_len(), self.fixed_len()),
            Tail::PerChannel(_) => (self.len(0), usize::MAX),
            Tail::ChunkData => (self.len(1), self.len(MAX_CHUNK)),
        }
    }

    /// Byte offset of the field `name` in the body, if it is a fixed field.
    pub fn offset_of(&self, name: &str) -> Option<usize> {
        let mut at = 0;
        for f in self.fields {
            if f.name == name {
                return Some(at);
            }
            at += f.ty.size();
        }
        None
    }
}

/// The first fields of every reply body, before the type's own ([`MsgType::reply_body`]).
pub const REPLY_HEAD: &[Field] = &[
    field("request_seq", WireType::U16, "the command's seq"),
    field(
        "status",
        WireType::U8,
        "0 ok, 1 bad argument, 2 no model (the device is in a fault state; nothing changed)",
    ),
];

const NO_FIELDS: Body = Body {
    fields: &[],
    tail: Tail::None,
};

const FLAGS_BODY: Body = Body {
    fields: &[
        field(
            "timestamp_us",
            WireType::U32,
            "time of the frame's last sample in µs since the first ADC scan, from the sample clock",
        ),
        field(
            "status",
            WireType::U8,
            "bit 0 ARMED, bit 1 LATE, bit 2 TARED, bit 3 HAND_UNSTABLE, bit 4 HAND_BY_RULE; others 0",
        ),
        field(
            "channels",
            WireType::U8,
            "N, channels (16 hand, 4 suction), 1…16",
        ),
        field(
            "unstable",
            WireType::U16,
            "bit c: channel c unstable; bits ≥ N are 0",
        ),
        field(
            "fault",
            WireType::U16,
            "bit c: channel c faulted, not predicted on",
        ),
        field(
            "overruns",
            WireType::U16,
            "late frames since boot, saturating",
        ),
        field(
            "skipped",
            WireType::U16,
            "frames acquired but never sent since boot, saturating",
        ),
    ],
    tail: Tail::PerChannel(field(
        "p",
        WireType::U16,
        "p(unstable) of channel c, Q0.15 (0…32 767 = 0…1), or 0xFFFF = not predicted",
    )),
};

const SAMPLES_BODY: Body = Body {
    fields: &[
        field(
            "timestamp_us",
            WireType::U32,
            "the frame's sample clock, as in its flag frame",
        ),
        field("status", WireType::U8, "as in the flag frame"),
        field(
            "marks",
            WireType::U8,
            "bit 0 grasp start, bit 1 lift, bit 2 release; others 0",
        ),
        field("channels", WireType::U8, "N, channels, 1…16"),
        field(
            "unit",
            WireType::U8,
            "unit of value: 0 mN (hand), 1 counts = 1/16 ADC count (suction)",
        ),
        field(
            "fault",
            WireType::U16,
            "bit c: channel c faulted; bits ≥ N are 0",
        ),
    ],
    tail: Tail::PerChannel(field(
        "value",
        WireType::I32,
        "channel c's decimated model input after the live zero, tare and scaling, in `unit`",
    )),
};

const FAULT_BODY: Body = Body {
    fields: &[
        field(
            "timestamp_us",
            WireType::U32,
            "sample clock, as flags; 0 for a sensor stall",
        ),
        field("code", WireType::U8, "fault code (SG_FAULT_*)"),
        field(
            "detail",
            WireType::U8,
            "code 1: the blob error kind, else 0",
        ),
        field("value", WireType::U32, "code-specific value"),
    ],
    tail: Tail::None,
};

const ERROR_BODY: Body = Body {
    fields: &[
        field(
            "error",
            WireType::U8,
            "decode error code of the rejected frame (SG_E_*)",
        ),
        field(
            "msg_type",
            WireType::U8,
            "its type when its CRC was good, else 0",
        ),
        field(
            "request_seq",
            WireType::U16,
            "its seq when its CRC was good, else 0xFFFF",
        ),
    ],
    tail: Tail::None,
};

const TOKEN_BODY: Body = Body {
    fields: &[field("token", WireType::U32, "echoed in the reply")],
    tail: Tail::None,
};

const THRESHOLD_BODY: Body = Body {
    fields: &[
        field(
            "threshold_q15",
            WireType::U16,
            "p(unstable) threshold, Q0.15, 1…32 767",
        ),
        field(
            "raise_after",
            WireType::U8,
            "consecutive frames at or above it before a flag rises, ≥ 1",
        ),
        field(
            "clear_after",
            WireType::U8,
            "consecutive frames below it before a flag clears, ≥ 1",
        ),
    ],
    tail: Tail::None,
};

const MODE_BODY: Body = Body {
    fields: &[field(
        "mode",
        WireType::U8,
        "0 flags, 1 flags + samples, 2 samples",
    )],
    tail: Tail::None,
};

const UPLOAD_BEGIN_BODY: Body = Body {
    fields: &[
        field("size", WireType::U32, "blob length in bytes"),
        field("crc", WireType::U32, "CRC-32/ISO-HDLC of the whole blob"),
    ],
    tail: Tail::None,
};

const UPLOAD_CHUNK_BODY: Body = Body {
    fields: &[field(
        "offset",
        WireType::U32,
        "offset of the data in the blob",
    )],
    tail: Tail::ChunkData,
};

const UPLOAD_REPLY_BODY: Body = Body {
    fields: &[
        field(
            "code",
            WireType::U8,
            "upload code (SG_UP_*): 0 accepted, else why it was refused",
        ),
        field(
            "detail",
            WireType::U8,
            "blob error kind (bad blob), flash step (flash)",
        ),
        field(
            "slot",
            WireType::U8,
            "slot written (begin, chunk) or made active (commit)",
        ),
        field(
            "value",
            WireType::U32,
            "next expected offset, CRC, rate … (see below)",
        ),
    ],
    tail: Tail::None,
};

const INFO_REPLY_BODY: Body = Body {
    fields: &[
        field("version", WireType::U8, "protocol version (1)"),
        field(
            "firmware",
            WireType::Bytes(3),
            "firmware version: major, minor, patch",
        ),
        field(
            "profile",
            WireType::U8,
            "sensor profile id (SG_PROFILE_*: slipguard_app::profile::ProfileId)",
        ),
        field("channels", WireType::U8, "N, channels in flag frames"),
        field("oversample", WireType::U8, "ADC samples per model sample"),
        field(
            "model_ok",
            WireType::U8,
            "1 if the model blob is valid and running",
        ),
        field(
            "variant",
            WireType::U8,
            "blob header byte 16; 0xFF without a model",
        ),
        field("reserved", WireType::U8, "0"),
        field("hidden", WireType::U16, "hidden size of LSTM 0"),
        field("model_id", WireType::U32, "model id from the blob header"),
        field(
            "model_crc",
            WireType::U32,
            "CRC-32 of the model blob (its fingerprint)",
        ),
        field(
            "sample_rate_mhz",
            WireType::U32,
            "model sample rate = frame rate, mHz",
        ),
        field("threshold_q15", WireType::U16, "threshold in force, Q0.15"),
        field("raise_after", WireType::U8, "hysteresis in force"),
        field("clear_after", WireType::U8, "hysteresis in force"),
        field(
            "name",
            WireType::Bytes(12),
            "model name, ASCII, zero padded",
        ),
    ],
    tail: Tail::None,
};

impl MsgType {
    /// Every message type, in code order.
    pub const ALL: [Self; 14] = [
        Self::Flags,
        Self::Fault,
        Self::Error,
        Self::Samples,
        Self::Ping,
        Self::GraspStart,
        Self::Release,
        Self::SetThreshold,
        Self::Info,
        Self::Lift,
        Self::StreamMode,
        Self::UploadBegin,
        Self::UploadChunk,
        Self::UploadCommit,
    ];

    /// The type of a code (a reply's code without [`msg_type::REPLY`]).
    pub const fn from_u8(v: u8) -> Option<Self> {
        let mut i = 0;
        while i < Self::ALL.len() {
            if Self::ALL[i] as u8 == v {
                return Some(Self::ALL[i]);
            }
            i += 1;
        }
        None
    }

    /// Whether the controller sends it (then the device answers with a reply of type
    /// `self | REPLY`).
    pub const fn is_command(self) -> bool {
        self as u8 >= 0x10
    }

    /// The name the docs and the C header use (`SG_T_` + upper case, spaces as `_`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Flags => "flags",
            Self::Fault => "fault",
            Self::Error => "error",
            Self::Samples => "samples",
            Self::Ping => "ping",
            Self::GraspStart => "grasp start",
            Self::Release => "release",
            Self::SetThreshold => "set threshold",
            Self::Info => "info",
            Self::Lift => "lift",
            Self::StreamMode => "stream mode",
            Self::UploadBegin => "upload begin",
            Self::UploadChunk => "upload chunk",
            Self::UploadCommit => "upload commit",
        }
    }

    /// The layout of this type's body (a command's, or a device message's).
    pub const fn body(self) -> Body {
        match self {
            Self::Flags => FLAGS_BODY,
            Self::Samples => SAMPLES_BODY,
            Self::Fault => FAULT_BODY,
            Self::Error => ERROR_BODY,
            Self::Ping => TOKEN_BODY,
            Self::GraspStart | Self::Release | Self::Info | Self::Lift | Self::UploadCommit => {
                NO_FIELDS
            }
            Self::SetThreshold => THRESHOLD_BODY,
            Self::StreamMode => MODE_BODY,
            Self::UploadBegin => UPLOAD_BEGIN_BODY,
            Self::UploadChunk => UPLOAD_CHUNK_BODY,
        }
    }

    /// The fields of the reply to this command after [`REPLY_HEAD`]; `None` for device messages.
    pub const fn reply_body(self) -> Option<Body> {
        Some(match self {
            Self::Flags | Self::Samples | Self::Fault | Self::Error => return None,
            Self::Ping => TOKEN_BODY,
            Self::GraspStart | Self::Release | Self::Lift => NO_FIELDS,
            Self::SetThreshold => THRESHOLD_BODY,
            Self::Info => INFO_REPLY_BODY,
            Self::StreamMode => MODE_BODY,
            Self::UploadBegin | Self::UploadChunk | Self::UploadCommit => UPLOAD_REPLY_BODY,
        })
    }
}

/// Bytes of [`REPLY_HEAD`].
const REPLY_HEAD_LEN: usize = Body {
    fields: REPLY_HEAD,
    tail: Tail::None,
}
.fixed_len();

/// The body length (range) a payload of type byte `t` may have: a device message's or
/// command's from [`MsgType::body`], a reply's [`REPLY_HEAD`] + [`MsgType::reply_body`];
/// `None` for a code v1 does not define.
pub const fn body_len_range(t: u8) -> Option<(usize, usize)> {
    let Some(m) = MsgType::from_u8(t & !msg_type::REPLY) else {
        return None;
    };
    if t & msg_type::REPLY == 0 {
        return Some(m.body().len_range());
    }
    match m.reply_body() {
        Some(b) => Some((
            REPLY_HEAD_LEN + b.fixed_len(),
            REPLY_HEAD_LEN + b.fixed_len(),
        )),
        None => None,
    }
}

/// Message type codes (byte 1 of the payload) as bytes, from [`MsgType`].
pub mod msg_type {
    use super::MsgType;
    /// Device → controller: one frame of flags.
    pub const FLAGS: u8 = MsgType::Flags as u8;
    /// Device → controller: a system fault.
    pub const FAULT: u8 = MsgType::Fault as u8;
    /// Device → controller: a received frame was rejected.
    pub const ERROR: u8 = MsgType::Error as u8;
    /// Device → controller: one frame of model input per channel.
    pub const SAMPLES: u8 = MsgType::Samples as u8;
    /// Controller → device: ping.
    pub const PING: u8 = MsgType::Ping as u8;
    /// Controller → device: grasp start.
    pub const GRASP_START: u8 = MsgType::GraspStart as u8;
    /// Controller → device: release.
    pub const RELEASE: u8 = MsgType::Release as u8;
    /// Controller → device: set threshold and hysteresis.
    pub const SET_THRESHOLD: u8 = MsgType::SetThreshold as u8;
    /// Controller → device: info request.
    pub const INFO: u8 = MsgType::Info as u8;
    /// Controller → device: the lift starts.
    pub const LIFT: u8 = MsgType::Lift as u8;
    /// Controller → device: stream mode.
    pub const STREAM_MODE: u8 = MsgType::StreamMode as u8;
    /// Controller → device: start a model upload.
    pub const UPLOAD_BEGIN: u8 = MsgType::UploadBegin as u8;
    /// Controller → device: one chunk of the blob.
    pub const UPLOAD_CHUNK: u8 = MsgType::UploadChunk as u8;
    /// Controller → device: check the uploaded blob and make it the active model.
    pub const UPLOAD_COMMIT: u8 = MsgType::UploadCommit as u8;
    /// Bit set in the type of a reply: reply type = command type | REPLY.
    pub const REPLY: u8 = 0x80;
}

codes! {
    /// Status bits of flag and samples frames (byte 8).
    pub mod status {
        /// Flagging is on (after boot and grasp start; off after release). When off, the unstable
        /// mask is 0 but p(unstable) is still reported.
        ARMED = 1 << 0;
        /// This frame finished after its deadline (it is still sent; the overrun counter counts it).
        LATE = 1 << 1;
        /// The tare of the suction profile is in force.
        TARED = 1 << 2;
        /// The hand flag: the hand-level decision over the channels in contact
        /// (`decision::HandConfig`) is up. Always 0 while not armed. The board's UNSTABLE line
        /// carries the same bit.
        HAND_UNSTABLE = 1 << 3;
        /// The hand flag is up while the model's own hand flag is down: the model blob's hand
        /// rule (format v2, `decision::FusedHand`) raised it. Always 0 without a rule in the
        /// blob and while not armed; set only with HAND_UNSTABLE.
        HAND_BY_RULE = 1 << 4;
    }
}

/// One frame of per-channel results (type 0x01).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Flags {
    /// Acquisition time of the frame's last sample, in µs since boot, from the sample clock
    /// (frame index × model period), wrapping at 2^32.
    pub timestamp_us: u32,
    /// [`status`] bits.
    pub status: u8,
    /// Number of channels N (1..=16); only `p[..N]` is sent.
    pub channels: u8,
    /// Bit c set: channel c is unstable.
    pub unstable: u16,
    /// Bit c set: channel c is faulted (saturated, stuck or disconnected) and not predicted on.
    pub fault: u16,
    /// Frames that finished after their deadline since boot (saturating).
    pub overruns: u16,
    /// Frames acquired but never processed since boot (saturating).
    pub skipped: u16,
    /// p(unstable) per channel, Q0.15, or [`PUnstable::NONE`].
    pub p: [PUnstable; MAX_CHANNELS],
}

impl Flags {
    /// Body length for `channels` channels.
    pub const fn body_len(channels: usize) -> usize {
        MsgType::Flags.body().len(channels)
    }

    /// Whether the hand flag ([`status::HAND_UNSTABLE`]) is up.
    pub const fn hand_unstable(&self) -> bool {
        self.status & status::HAND_UNSTABLE != 0
    }

    /// Whether the model blob's hand rule raised the hand flag while the model's own hand flag
    /// is down ([`status::HAND_BY_RULE`]).
    pub const fn hand_by_rule(&self) -> bool {
        self.status & status::HAND_BY_RULE != 0
    }

    /// Bit c set: channel c is in contact, i.e. predicted on. A device with a model sends
    /// [`PUnstable::NONE`] exactly for the channels that are faulted or not in contact, so the
    /// mask is the channels below N whose fault bit is clear and whose p is a probability.
    pub fn contact(&self) -> u16 {
        let n = (self.channels as usize).min(MAX_CHANNELS);
        let mut m = 0;
        for (c, &p) in self.p[..n].iter().enumerate() {
            if !p.is_none() && self.fault & (1 << c) == 0 {
                m |= 1 << c;
            }
        }
        m
    }
}

codes! {
    /// Phase-mark bits of a samples frame: the commands handled since the previous frame.
    pub mod mark {
        /// Grasp start (`grasp_start` of a recording).
        GRASP_START = 1 << 0;
        /// Lift (`lift_start` of a recording).
        LIFT = 1 << 1;
        /// Release.
        RELEASE = 1 << 2;
        /// All bits v1 defines.
        KNOWN = GRASP_START | LIFT | RELEASE;
    }
}

/// Which frames the device streams each model period ([`Command::StreamMode`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum StreamMode {
    /// Flag frames only (the boot default).
    #[default]
    Flags = 0,
    /// A samples frame then a flag frame.
    FlagsAndSamples = 1,
    /// Samples frames only (recording; fault frames still go out).
    Samples = 2,
}

impl StreamMode {
    /// The mode of a wire byte.
    pub fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::Flags,
            1 => Self::FlagsAndSamples,
            2 => Self::Samples,
            _ => return None,
        })
    }
    /// Whether flag frames go out.
    pub fn flags(self) -> bool {
        self != Self::Samples
    }
    /// Whether samples frames go out.
    pub fn samples(self) -> bool {
        self != Self::Flags
    }
}

/// One frame of model input (type 0x04): what the model's front end receives for each channel
/// in this frame, in the profile's input unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Samples {
    /// The frame's sample clock, as in [`Flags::timestamp_us`].
    pub timestamp_us: u32,
    /// [`status`] bits, as in the flag frame of the same frame.
    pub status: u8,
    /// [`mark`] bits: phase commands handled since the previous frame.
    pub marks: u8,
    /// Number of channels N (1..=16); only `value[..N]` is sent.
    pub channels: u8,
    /// Unit of `value`: the blob's input-unit code (0 mN, 1 counts = 1/16 ADC count).
    pub unit: u8,
    /// Bit c set: channel c is faulted (its value is not fed to the model).
    pub fault: u16,
    /// Decimated input per channel after tare and scaling: mN (hand) or 1/16 ADC counts
    /// (suction), the `raw` argument of the model's step.
    pub value: [i32; MAX_CHANNELS],
}

impl Samples {
    /// Body length for `channels` channels.
    pub const fn body_len(channels: usize) -> usize {
        MsgType::Samples.body().len(channels)
    }
}

codes! {
    /// Upload reply codes (byte 3 of an upload reply body): 0 accepted, else why the command was
    /// refused. Each refusal says what to fix (`docs/protocol.md`).
    pub mod upload_code {
        /// Accepted.
        OK = 0;
        /// Chunk or commit without an upload in progress: send upload begin.
        NOT_STARTED = 1;
        /// Flagging is armed on a running model: send release first (erasing stalls the CPU).
        ARMED = 2;
        /// Declared size 0, not a multiple of 4 or over the slot (value: largest size).
        WRONG_SIZE = 3;
        /// Chunk at another offset than the next expected one (value: next expected offset).
        OUT_OF_ORDER = 4;
        /// Chunk CRC does not match its data (value: next expected offset).
        BAD_CHUNK = 5;
        /// Chunk runs past the declared size or is not a multiple of 4 bytes (value: next offset).
        CHUNK_LENGTH = 6;
        /// Flash erase, write or read-back failed (detail: 1 erase, 2 write, 3 read-back).
        FLASH = 7;
        /// Commit before every byte arrived (value: bytes received).
        INCOMPLETE = 8;
        /// The whole-blob CRC differs from the one announced (value: CRC of the flash contents).
        BLOB_CRC = 9;
        /// The blob does not parse (detail, value: the blob error as in fault frames).
        BAD_BLOB = 10;
        /// The model's rate is not one the profile runs (value: the model's rate, mHz).
        RATE_MISMATCH = 11;
        /// The model's input unit is not the profile's (value: the model's unit code).
        UNIT_MISMATCH = 12;
        /// This build has no model flash (e.g. a host replay without a flash).
        UNSUPPORTED = 13;
    }
}

codes! {
    /// System fault codes (type 0x02, byte 8).
    pub mod fault_code {
        /// The model blob failed validation (detail: [`crate::blob::BlobError`] kind, value: extra).
        BAD_MODEL = 1;
        /// The model's sample rate is not one the sensor profile runs (value: the model's rate in mHz).
        RATE_MISMATCH = 2;
        /// The ADC/DMA stopped delivering samples (value: frames since the last scan).
        SENSOR_STALL = 3;
        /// The model expects another input unit (mN vs counts) than the sensor profile delivers.
        UNIT_MISMATCH = 4;
    }
}

/// A system fault (type 0x02): the device is up but not predicting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fault {
    /// Time since boot in µs (sample clock or uptime), wrapping.
    pub timestamp_us: u32,
    /// [`fault_code`].
    pub code: u8,
    /// Code-specific detail (for [`fault_code::BAD_MODEL`], the blob error kind).
    pub detail: u8,
    /// Code-specific value.
    pub value: u32,
}

/// A rejected incoming frame (type 0x03).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Error {
    /// [`DecodeError::code`] of the failure.
    pub error: u8,
    /// Type byte of the rejected frame, when it was readable (else 0).
    pub msg_type: u8,
    /// Sequence number of the rejected frame, when it was readable (else 0xFFFF).
    pub request_seq: u16,
}

/// Commands from the hand controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Answered with [`ReplyBody::Pong`] carrying the same token.
    Ping {
        /// Echoed back.
        token: u32,
    },
    /// Reset every channel's state, tare (suction profile) and start flagging.
    GraspStart,
    /// Stop flagging until the next grasp start (so opening the hand is not read as a drop).
    Release,
    /// Set the decision threshold and hysteresis.
    SetThreshold {
        /// p(unstable) threshold, Q0.15, 1..=32767.
        threshold_q15: u16,
        /// Consecutive frames at or above the threshold before the flag rises, >= 1.
        raise_after: u8,
        /// Consecutive frames below the threshold before it clears, >= 1.
        clear_after: u8,
    },
    /// Answered with [`ReplyBody::Info`].
    Info,
    /// The lift starts: echoed as [`mark::LIFT`], nothing else changes.
    Lift,
    /// Choose the frames streamed per model period.
    StreamMode(StreamMode),
    /// Start an upload: erase the inactive model slot.
    UploadBegin {
        /// Blob length in bytes.
        size: u32,
        /// CRC-32/ISO-HDLC of the whole blob.
        crc: u32,
    },
    /// One chunk of the blob.
    UploadChunk(Chunk),
    /// Check the uploaded blob and make it the active model.
    UploadCommit,
}

/// One upload chunk: `data[..len]` at byte `offset` of the blob.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Chunk {
    /// Offset in the blob.
    pub offset: u32,
    /// Data bytes used, 1..=[`MAX_CHUNK`].
    pub len: u8,
    /// The data (bytes past `len` are 0).
    pub data: [u8; MAX_CHUNK],
    /// CRC-32/ISO-HDLC of `data[..len]`, checked again after the write.
    pub crc: u32,
}

impl Chunk {
    /// The chunk of `bytes` (at most [`MAX_CHUNK`], longer input is cut) at `offset`, with its CRC.
    pub fn new(offset: u32, bytes: &[u8]) -> Self {
        let n = bytes.len().min(MAX_CHUNK);
        let mut data = [0u8; MAX_CHUNK];
        data[..n].copy_from_slice(&bytes[..n]);
        Self {
            offset,
            len: n as u8,
            data,
            crc: CRC32.checksum(&bytes[..n]),
        }
    }
    /// The data bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(MAX_CHUNK)]
    }
}

impl Command {
    /// The message type code.
    pub fn msg_type(&self) -> u8 {
        match self {
            Self::Ping { .. } => msg_type::PING,
            Self::GraspStart => msg_type::GRASP_START,
            Self::Release => msg_type::RELEASE,
            Self::SetThreshold { .. } => msg_type::SET_THRESHOLD,
            Self::Info => msg_type::INFO,
            Self::Lift => msg_type::LIFT,
            Self::StreamMode(_) => msg_type::STREAM_MODE,
            Self::UploadBegin { .. } => msg_type::UPLOAD_BEGIN,
            Self::UploadChunk(_) => msg_type::UPLOAD_CHUNK,
            Self::UploadCommit => msg_type::UPLOAD_COMMIT,
        }
    }
}

/// Reply status (byte 6 of every reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum ReplyStatus {
    /// Done.
    Ok = 0,
    /// An argument was out of range; nothing changed.
    BadArgument = 1,
    /// There is no valid model (the device is in a fault state); nothing changed.
    NoModel = 2,
}

impl ReplyStatus {
    fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::Ok,
            1 => Self::BadArgument,
            2 => Self::NoModel,
            _ => return None,
        })
    }
}

/// Device description (reply to [`Command::Info`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Info {
    /// Firmware version (major, minor, patch).
    pub firmware: [u8; 3],
    /// Sensor profile id: the byte of `slipguard_app::profile::ProfileId` (the registry of
    /// profiles lives with the front end that runs them, in the app crate).
    pub profile: u8,
    /// Channels in flag frames.
    pub channels: u8,
    /// ADC samples per model sample (decimation factor).
    pub oversample: u8,
    /// 1 if the model blob is valid and running.
    pub model_ok: u8,
    /// Model variant (blob header byte 16), 0xFF without a model.
    pub variant: u8,
    /// Model id from the blob header.
    pub model_id: u32,
    /// CRC-32 of the model blob (its fingerprint).
    pub model_crc: u32,
    /// Model sample rate (= frame rate; wire: u32 millihertz).
    pub sample_rate_mhz: Millihertz,
    /// Hidden size of LSTM 0.
    pub hidden: u16,
    /// Threshold in force, Q0.15.
    pub threshold_q15: u16,
    /// Hysteresis in force.
    pub raise_after: u8,
    /// Hysteresis in force.
    pub clear_after: u8,
    /// Model name, zero padded.
    pub name: [u8; 12],
}

/// Type-specific part of a reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyBody {
    /// Reply to ping.
    Pong {
        /// The ping's token.
        token: u32,
    },
    /// Reply to grasp start.
    GraspStarted,
    /// Reply to release.
    Released,
    /// Reply to set threshold: the settings now in force.
    ThresholdSet {
        /// Threshold in force.
        threshold_q15: u16,
        /// Hysteresis in force.
        raise_after: u8,
        /// Hysteresis in force.
        clear_after: u8,
    },
    /// Reply to info.
    Info(Info),
    /// Reply to lift.
    Lifted,
    /// Reply to stream mode: the mode now in force.
    StreamMode(StreamMode),
    /// Reply to an upload command (`command` is its type: begin, chunk or commit).
    Upload {
        /// Type of the command answered ([`msg_type::UPLOAD_BEGIN`] …).
        command: u8,
        /// Outcome ([`upload_code`]).
        code: u8,
        /// Code-specific detail (blob error kind, flash step).
        detail: u8,
        /// Slot being written (begin, chunk) or made active (commit).
        slot: u8,
        /// Code-specific value (next expected offset, CRC, rate…).
        value: u32,
    },
}

impl ReplyBody {
    /// The reply's message type code (command type | 0x80).
    pub fn msg_type(&self) -> u8 {
        msg_type::REPLY
            | match self {
                Self::Pong { .. } => msg_type::PING,
                Self::GraspStarted => msg_type::GRASP_START,
                Self::Released => msg_type::RELEASE,
                Self::ThresholdSet { .. } => msg_type::SET_THRESHOLD,
                Self::Info(_) => msg_type::INFO,
                Self::Lifted => msg_type::LIFT,
                Self::StreamMode(_) => msg_type::STREAM_MODE,
                Self::Upload { command, .. } => command & !msg_type::REPLY,
            }
    }
}

/// A reply to one command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply {
    /// `seq` of the command answered.
    pub request_seq: u16,
    /// Outcome.
    pub status: ReplyStatus,
    /// Type-specific fields.
    pub body: ReplyBody,
}

/// Every v1 message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message {
    /// Flag frame.
    Flags(Flags),
    /// Samples frame.
    Samples(Samples),
    /// System fault.
    Fault(Fault),
    /// Rejected incoming frame.
    Error(Error),
    /// Command (controller → device).
    Command(Command),
    /// Reply (device → controller).
    Reply(Reply),
}

impl Message {
    /// The type code.
    pub fn msg_type(&self) -> u8 {
        match self {
            Self::Flags(_) => msg_type::FLAGS,
            Self::Samples(_) => msg_type::SAMPLES,
            Self::Fault(_) => msg_type::FAULT,
            Self::Error(_) => msg_type::ERROR,
            Self::Command(c) => c.msg_type(),
            Self::Reply(r) => r.body.msg_type(),
        }
    }
}

/// A decoded frame: sequence number and message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Sender's sequence number.
    pub seq: u16,
    /// The message.
    pub msg: Message,
}

/// Why a frame was rejected. Each has a stable [`code`](DecodeError::code) sent back in
/// [`Error`] frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Nothing between two delimiters.
    Empty,
    /// The bytes are not valid COBS.
    Cobs,
    /// Longer than any v1 frame ([`MAX_PAYLOAD`] decoded, [`MAX_WIRE`] on the wire).
    TooLong,
    /// Shorter than header + CRC.
    Truncated {
        /// Decoded length.
        len: u8,
    },
    /// The CRC does not match.
    BadCrc {
        /// CRC in the frame.
        stored: u32,
        /// CRC of the bytes received.
        computed: u32,
    },
    /// A protocol version this side does not speak.
    WrongVersion(u8),
    /// A type code v1 does not define.
    UnknownType(u8),
    /// The body length does not match the type.
    BadLength {
        /// Type code.
        msg_type: u8,
        /// Body length received.
        len: u8,
    },
    /// A field holds a value outside its range (e.g. threshold 0, more than 16 channels).
    BadValue {
        /// Type code.
        msg_type: u8,
    },
}

impl DecodeError {
    /// Stable numeric code (byte 4 of an [`Error`] frame).
    pub fn code(&self) -> u8 {
        match self {
            Self::Empty => 1,
            Self::Cobs => 2,
            Self::TooLong => 3,
            Self::Truncated { .. } => 4,
            Self::BadCrc { .. } => 5,
            Self::WrongVersion(_) => 6,
            Self::UnknownType(_) => 7,
            Self::BadLength { .. } => 8,
            Self::BadValue { .. } => 9,
        }
    }
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => write!(f, "empty frame"),
            Self::Cobs => write!(f, "invalid COBS encoding"),
            Self::TooLong => write!(f, "frame longer than {MAX_PAYLOAD} bytes"),
            Self::Truncated { len } => write!(f, "frame truncated: {len} bytes"),
            Self::BadCrc { stored, computed } => write!(
                f,
                "CRC mismatch: stored {stored:#010x}, computed {computed:#010x}"
            ),
            Self::WrongVersion(v) => write!(f, "protocol version {v}, expected {VERSION}"),
            Self::UnknownType(t) => write!(f, "unknown message type {t:#04x}"),
            Self::BadLength { msg_type, len } => {
                write!(f, "message type {msg_type:#04x} with a {len}-byte body")
            }
            Self::BadValue { msg_type } => {
                write!(f, "message type {msg_type:#04x} with a field out of range")
            }
        }
    }
}

#[cfg(any(test, feature = "std"))]
impl std::error::Error for DecodeError {}

/// Little-endian writer over a fixed buffer (callers size it with [`MAX_PAYLOAD`]).
struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl Writer<'_> {
    fn put(&mut self, bytes: &[u8]) {
        let end = (self.pos + bytes.len()).min(self.buf.len());
        let n = end.saturating_sub(self.pos);
        if let Some(dst) = self.buf.get_mut(self.pos..end) {
            dst.copy_from_slice(&bytes[..n]);
        }
        self.pos += bytes.len();
    }
    fn u8(&mut self, v: u8) {
        self.put(&[v]);
    }
    fn u16(&mut self, v: u16) {
        self.put(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.put(&v.to_le_bytes());
    }
}

/// Little-endian reader over a body whose length was checked.
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn u8(&mut self) -> u8 {
        let v = self.buf.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        v
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    fn array<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        for b in &mut a {
            *b = self.u8();
        }
        a
    }
}

/// Writes the payload (header, body, CRC) of `frame` into `out` and returns its length
/// (at most [`MAX_PAYLOAD`]; `out` must hold that many bytes, else the frame is cut and the
/// returned length is 0).
pub fn encode_payload(frame: &Frame, out: &mut [u8]) -> usize {
    let mut w = Writer { buf: out, pos: 0 };
    w.u8(VERSION);
    w.u8(frame.msg.msg_type());
    w.u16(frame.seq);
    match &frame.msg {
        Message::Flags(f) => {
            let n = (f.channels as usize).min(MAX_CHANNELS);
            w.u32(f.timestamp_us);
            w.u8(f.status);
            w.u8(n as u8);
            w.u16(f.unstable);
            w.u16(f.fault);
            w.u16(f.overruns);
            w.u16(f.skipped);
            for &p in &f.p[..n] {
                w.u16(p.to_bits());
            }
        }
        Message::Samples(s) => {
            let n = (s.channels as usize).min(MAX_CHANNELS);
            w.u32(s.timestamp_us);
            w.u8(s.status);
            w.u8(s.marks);
            w.u8(n as u8);
            w.u8(s.unit);
            w.u16(s.fault);
            for &v in &s.value[..n] {
                w.put(&v.to_le_bytes());
            }
        }
        Message::Fault(f) => {
            w.u32(f.timestamp_us);
            w.u8(f.code);
            w.u8(f.detail);
            w.u32(f.value);
        }
        Message::Error(e) => {
            w.u8(e.error);
            w.u8(e.msg_type);
            w.u16(e.request_seq);
        }
        Message::Command(c) => match *c {
            Command::Ping { token } => w.u32(token),
            Command::GraspStart
            | Command::Release
            | Command::Info
            | Command::Lift
            | Command::UploadCommit => {}
            Command::StreamMode(m) => w.u8(m as u8),
            Command::UploadBegin { size, crc } => {
                w.u32(size);
                w.u32(crc);
            }
            Command::UploadChunk(c) => {
                w.u32(c.offset);
                w.put(c.bytes());
                w.u32(c.crc);
            }
            Command::SetThreshold {
                threshold_q15,
                raise_after,
                clear_after,
            } => {
                w.u16(threshold_q15);
                w.u8(raise_after);
                w.u8(clear_after);
            }
        },
        Message::Reply(r) => {
            w.u16(r.request_seq);
            w.u8(r.status as u8);
            match r.body {
                ReplyBody::Pong { token } => w.u32(token),
                ReplyBody::GraspStarted | ReplyBody::Released | ReplyBody::Lifted => {}
                ReplyBody::StreamMode(m) => w.u8(m as u8),
                ReplyBody::Upload {
                    code,
                    detail,
                    slot,
                    value,
                    ..
                } => {
                    w.u8(code);
                    w.u8(detail);
                    w.u8(slot);
                    w.u32(value);
                }
                ReplyBody::ThresholdSet {
                    threshold_q15,
                    raise_after,
                    clear_after,
                } => {
                    w.u16(threshold_q15);
                    w.u8(raise_after);
                    w.u8(clear_after);
                }
                ReplyBody::Info(i) => {
                    w.u8(VERSION);
                    w.put(&i.firmware);
                    w.u8(i.profile);
                    w.u8(i.channels);
                    w.u8(i.oversample);
                    w.u8(i.model_ok);
                    w.u8(i.variant);
                    w.u8(0);
                    w.u16(i.hidden);
                    w.u32(i.model_id);
                    w.u32(i.model_crc);
                    w.u32(i.sample_rate_mhz.0);
                    w.u16(i.threshold_q15);
                    w.u8(i.raise_after);
                    w.u8(i.clear_after);
                    w.put(&i.name);
                }
            }
        }
    }
    let body_end = w.pos;
    if body_end + CRC_LEN > w.buf.len() {
        return 0;
    }
    let crc = CRC32.checksum(&w.buf[..body_end]);
    w.u32(crc);
    w.pos
}

/// Encodes `frame` for the wire (`COBS(payload) 00`) into `out` (at least [`MAX_WIRE`] bytes)
/// and returns the number of bytes to send (0 if `out` is too small).
pub fn encode(frame: &Frame, out: &mut [u8]) -> usize {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = encode_payload(frame, &mut payload);
    if n == 0 {
        return 0;
    }
    match cobs::try_encode(&payload[..n], out) {
        Ok(len) if len < out.len() => {
            out[len] = 0;
            len + 1
        }
        _ => 0,
    }
}

/// Decodes one frame from its wire bytes without the 0x00 delimiter (a trailing 0x00 is
/// tolerated).
pub fn decode(wire: &[u8]) -> Result<Frame, DecodeError> {
    let wire = match wire.split_last() {
        Some((0, rest)) => rest,
        _ => wire,
    };
    if wire.is_empty() {
        return Err(DecodeError::Empty);
    }
    if wire.len() > MAX_WIRE - 1 {
        return Err(DecodeError::TooLong);
    }
    if wire.contains(&0) {
        return Err(DecodeError::Cobs);
    }
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = match cobs::decode(wire, &mut payload) {
        Ok(report) => report.frame_size(),
        Err(cobs::DecodeError::TargetBufTooSmall) => return Err(DecodeError::TooLong),
        Err(_) => return Err(DecodeError::Cobs),
    };
    decode_payload(payload.get(..n).ok_or(DecodeError::TooLong)?)
}

/// Decodes one payload (already COBS-decoded: header, body, CRC).
pub fn decode_payload(payload: &[u8]) -> Result<Frame, DecodeError> {
    let n = payload.len();
    if n > MAX_PAYLOAD {
        return Err(DecodeError::TooLong);
    }
    if n < HEADER_LEN + CRC_LEN {
        return Err(DecodeError::Truncated { len: n as u8 });
    }
    let body_end = n - CRC_LEN;
    let stored = u32::from_le_bytes([
        payload[body_end],
        payload[body_end + 1],
        payload[body_end + 2],
        payload[body_end + 3],
    ]);
    let computed = CRC32.checksum(&payload[..body_end]);
    if stored != computed {
        return Err(DecodeError::BadCrc { stored, computed });
    }
    if payload[0] != VERSION {
        return Err(DecodeError::WrongVersion(payload[0]));
    }
    let t = payload[1];
    let seq = u16::from_le_bytes([payload[2], payload[3]]);
    let body = &payload[HEADER_LEN..body_end];
    let bad_len = DecodeError::BadLength {
        msg_type: t,
        len: body.len() as u8,
    };
    let bad_value = DecodeError::BadValue { msg_type: t };
    // Per-channel bodies are checked again once N is read.
    match body_len_range(t) {
        None => return Err(DecodeError::UnknownType(t)),
        Some((min, max)) if !(min..=max).contains(&body.len()) => return Err(bad_len),
        Some(_) => {}
    }
    let mut r = Reader { buf: body, pos: 0 };
    let msg = match t {
        msg_type::FLAGS => {
            let timestamp_us = r.u32();
            let status = r.u8();
            let channels = r.u8();
            let n = channels as usize;
            if n == 0 || n > MAX_CHANNELS {
                return Err(bad_value);
            }
            if body.len() != Flags::body_len(n) {
                return Err(bad_len);
            }
            let mut f = Flags {
                timestamp_us,
                status,
                channels,
                unstable: r.u16(),
                fault: r.u16(),
                overruns: r.u16(),
                skipped: r.u16(),
                p: [PUnstable::NONE; MAX_CHANNELS],
            };
            for p in &mut f.p[..n] {
                *p = PUnstable::from_bits(r.u16()).ok_or(bad_value)?;
            }
            let valid = if n == 16 { u16::MAX } else { (1u16 << n) - 1 };
            if f.unstable & !valid != 0 || f.fault & !valid != 0 {
                return Err(bad_value);
            }
            Message::Flags(f)
        }
        msg_type::SAMPLES => {
            let timestamp_us = r.u32();
            let status = r.u8();
            let marks = r.u8();
            let channels = r.u8();
            let unit = r.u8();
            let n = channels as usize;
            if n == 0 || n > MAX_CHANNELS || marks & !mark::KNOWN != 0 {
                return Err(bad_value);
            }
            if body.len() != Samples::body_len(n) {
                return Err(bad_len);
            }
            let mut s = Samples {
                timestamp_us,
                status,
                marks,
                channels,
                unit,
                fault: r.u16(),
                value: [0; MAX_CHANNELS],
            };
            for v in &mut s.value[..n] {
                *v = r.u32() as i32;
            }
            let valid = if n == 16 { u16::MAX } else { (1u16 << n) - 1 };
            if s.fault & !valid != 0 {
                return Err(bad_value);
            }
            Message::Samples(s)
        }
        msg_type::FAULT => Message::Fault(Fault {
            timestamp_us: r.u32(),
            code: r.u8(),
            detail: r.u8(),
            value: r.u32(),
        }),
        msg_type::ERROR => Message::Error(Error {
            error: r.u8(),
            msg_type: r.u8(),
            request_seq: r.u16(),
        }),
        msg_type::PING => Message::Command(Command::Ping { token: r.u32() }),
        msg_type::GRASP_START => Message::Command(Command::GraspStart),
        msg_type::RELEASE => Message::Command(Command::Release),
        msg_type::INFO => Message::Command(Command::Info),
        msg_type::LIFT => Message::Command(Command::Lift),
        msg_type::UPLOAD_COMMIT => Message::Command(Command::UploadCommit),
        msg_type::STREAM_MODE => Message::Command(Command::StreamMode(
            StreamMode::from_u8(r.u8()).ok_or(bad_value)?,
        )),
        msg_type::UPLOAD_BEGIN => Message::Command(Command::UploadBegin {
            size: r.u32(),
            crc: r.u32(),
        }),
        msg_type::UPLOAD_CHUNK => {
            let offset = r.u32();
            let n = body.len() - 8;
            let mut data = [0u8; MAX_CHUNK];
            for d in data.iter_mut().take(n) {
                *d = r.u8();
            }
            Message::Command(Command::UploadChunk(Chunk {
                offset,
                len: n as u8,
                data,
                crc: r.u32(),
            }))
        }
        msg_type::SET_THRESHOLD => {
            let threshold_q15 = r.u16();
            let raise_after = r.u8();
            let clear_after = r.u8();
            if threshold_q15 == 0
                || threshold_q15 > i16::MAX as u16
                || raise_after == 0
                || clear_after == 0
            {
                return Err(bad_value);
            }
            Message::Command(Command::SetThreshold {
                threshold_q15,
                raise_after,
                clear_after,
            })
        }
        _ => {
            // A reply: the fixed length was checked above.
            let request_seq = r.u16();
            let status = ReplyStatus::from_u8(r.u8()).ok_or(bad_value)?;
            let body = match t & !msg_type::REPLY {
                msg_type::PING => ReplyBody::Pong { token: r.u32() },
                msg_type::GRASP_START => ReplyBody::GraspStarted,
                msg_type::RELEASE => ReplyBody::Released,
                msg_type::LIFT => ReplyBody::Lifted,
                msg_type::STREAM_MODE => {
                    ReplyBody::StreamMode(StreamMode::from_u8(r.u8()).ok_or(bad_value)?)
                }
                msg_type::UPLOAD_BEGIN | msg_type::UPLOAD_CHUNK | msg_type::UPLOAD_COMMIT => {
                    ReplyBody::Upload {
                        command: t & !msg_type::REPLY,
                        code: r.u8(),
                        detail: r.u8(),
                        slot: r.u8(),
                        value: r.u32(),
                    }
                }
                msg_type::SET_THRESHOLD => ReplyBody::ThresholdSet {
                    threshold_q15: r.u16(),
                    raise_after: r.u8(),
                    clear_after: r.u8(),
                },
                msg_type::INFO => {
                    let version = r.u8();
                    if version != VERSION {
                        return Err(bad_value);
                    }
                    let firmware = r.array::<3>();
                    let profile = r.u8();
                    let channels = r.u8();
                    let oversample = r.u8();
                    let model_ok = r.u8();
                    let variant = r.u8();
                    let _reserved = r.u8();
                    ReplyBody::Info(Info {
                        firmware,
                        profile,
                        channels,
                        oversample,
                        model_ok,
                        variant,
                        hidden: r.u16(),
                        model_id: r.u32(),
                        model_crc: r.u32(),
                        sample_rate_mhz: Millihertz(r.u32()),
                        threshold_q15: r.u16(),
                        raise_after: r.u8(),
                        clear_after: r.u8(),
                        name: r.array::<12>(),
                    })
                }
                _ => return Err(DecodeError::UnknownType(t)),
            };
            Message::Reply(Reply {
                request_seq,
                status,
                body,
            })
        }
    };
    Ok(Frame { seq, msg })
}

/// Best-effort type and sequence number of a payload that failed to decode, for the
/// [`Error`] reply: only when the CRC is good (else the header cannot be trusted).
pub fn error_reply_for(wire: &[u8], err: DecodeError) -> Error {
    let mut e = Error {
        error: err.code(),
        msg_type: 0,
        request_seq: 0xFFFF,
    };
    if matches!(
        err,
        DecodeError::WrongVersion(_)
            | DecodeError::UnknownType(_)
            | DecodeError::BadLength { .. }
            | DecodeError::BadValue { .. }
    ) {
        let wire = match wire.split_last() {
            Some((0, rest)) => rest,
            _ => wire,
        };
        let mut payload = [0u8; MAX_PAYLOAD];
        if let Ok(report) = cobs::decode(wire, &mut payload)
            && report.frame_size() >= HEADER_LEN
        {
            e.msg_type = payload[1];
            e.request_seq = u16::from_le_bytes([payload[2], payload[3]]);
        }
    }
    e
}

/// Splits a byte stream into frames at 0x00 delimiters and resynchronises after garbage: an
/// over-long run is discarded up to the next delimiter and reported once as
/// [`DecodeError::TooLong`].
#[derive(Clone, Debug)]
pub struct Deframer {
    buf: [u8; MAX_WIRE],
    len: usize,
    overflow: bool,
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

/// What [`Deframer::push`] found at a delimiter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Deframed<'a> {
    /// A complete frame's wire bytes (without the delimiter), not yet decoded.
    Frame(&'a [u8]),
    /// A run longer than any frame was dropped.
    Overflow,
}

impl Deframer {
    /// An empty deframer.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_WIRE],
            len: 0,
            overflow: false,
        }
    }

    /// Feeds one byte; at a delimiter returns what ended there (nothing for empty runs, which
    /// senders may use as padding or to resynchronise).
    pub fn push(&mut self, byte: u8) -> Option<Deframed<'_>> {
        if byte == 0 {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflow) {
                return Some(Deframed::Overflow);
            }
            if len == 0 {
                return None;
            }
            return Some(Deframed::Frame(&self.buf[..len]));
        }
        if self.overflow {
            return None;
        }
        match self.buf.get_mut(self.len) {
            Some(slot) if self.len < MAX_WIRE - 1 => {
                *slot = byte;
                self.len += 1;
            }
            _ => {
                self.overflow = true;
                self.len = 0;
            }
        }
        None
    }

    /// Feeds one byte and decodes a completed frame.
    pub fn push_decode(&mut self, byte: u8) -> Option<Result<Frame, (DecodeError, Error)>> {
        match self.push(byte)? {
            Deframed::Overflow => Some(Err((
                DecodeError::TooLong,
                error_reply_for(&[], DecodeError::TooLong),
            ))),
            Deframed::Frame(w) => Some(decode(w).map_err(|e| (e, error_reply_for(w, e)))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wire(frame: &Frame) -> Vec<u8> {
        let mut out = [0u8; MAX_WIRE];
        let n = encode(frame, &mut out);
        assert!(n > 0);
        out[..n].to_vec()
    }

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    /// Wire bits (a probability or `P_NONE`) as flag-frame values.
    fn wire_p(bits: [u16; MAX_CHANNELS]) -> [PUnstable; MAX_CHANNELS] {
        bits.map(|b| PUnstable::from_bits(b).expect("a wire value"))
    }

    fn flags_example() -> Frame {
        let mut p = [P_NONE; MAX_CHANNELS];
        for (i, v) in p.iter_mut().enumerate().take(4) {
            *v = [120, 32767, 0, 16384][i];
        }
        p[2] = P_NONE;
        Frame {
            seq: 0x1234,
            msg: Message::Flags(Flags {
                timestamp_us: 1_000_000,
                status: status::ARMED,
                channels: 4,
                unstable: 0b0010,
                fault: 0b0100,
                overruns: 1,
                skipped: 0,
                p: wire_p(p),
            }),
        }
    }

    /// The hand-flag example of docs/protocol.md: hand flag up (from channel 0), channel 2 out
    /// of contact (p none, fault clear), channel 3 faulted.
    fn hand_flags_example() -> Frame {
        let mut p = [P_NONE; MAX_CHANNELS];
        p[0] = 21000;
        p[1] = 4000;
        Frame {
            seq: 0x0042,
            msg: Message::Flags(Flags {
                timestamp_us: 2_000_000,
                status: status::ARMED | status::HAND_UNSTABLE,
                channels: 4,
                unstable: 0b0001,
                fault: 0b1000,
                overruns: 0,
                skipped: 2,
                p: wire_p(p),
            }),
        }
    }

    /// Pins the hand flag's bytes (computed independently: Python's zlib.crc32 and a
    /// hand-written COBS encoder) and the contact mask a decoder derives from them.
    #[test]
    fn golden_bytes_hand_flag() {
        let f = hand_flags_example();
        let w = wire(&f);
        assert_eq!(
            hex(&w),
            "040101420480841e040904010208010102020d0852a00fffffffffcba393b400"
        );
        let Message::Flags(d) = decode(&w).unwrap().msg else {
            panic!("not flags")
        };
        assert_eq!(decode(&w).unwrap(), f);
        assert_eq!(d.status, 0x09, "status byte: ARMED | HAND_UNSTABLE");
        assert!(d.hand_unstable());
        assert_eq!(d.contact(), 0b0011);
        // The v1 example without the bit: hand flag down; contact = p valid and fault clear.
        let Message::Flags(old) = flags_example().msg else {
            unreachable!()
        };
        assert!(!old.hand_unstable());
        assert_eq!(old.contact(), 0b1011);
    }

    /// Pins the exact bytes of one frame of each kind (the C decoder and docs/protocol.md quote
    /// them). The expected strings were computed independently (Python: zlib.crc32 and a
    /// hand-written COBS encoder).
    #[test]
    fn golden_bytes() {
        let cases: [(Frame, &str); 6] = [
            (
                flags_example(),
                "080101341240420f04010402020402010101027805ff7fffff06403e8f902000",
            ),
            (
                Frame {
                    seq: 7,
                    msg: Message::Command(Command::Ping { token: 0xDEADBEEF }),
                },
                "0401100709efbeadde82cc4de800",
            ),
            (
                Frame {
                    seq: 8,
                    msg: Message::Command(Command::SetThreshold {
                        threshold_q15: 19661,
                        raise_after: 2,
                        clear_after: 3,
                    }),
                },
                "0401130809cd4c02038eaa754500",
            ),
            (
                Frame {
                    seq: 9,
                    msg: Message::Command(Command::GraspStart),
                },
                "040111090577cade5500",
            ),
            (
                Frame {
                    seq: 3,
                    msg: Message::Reply(Reply {
                        request_seq: 7,
                        status: ReplyStatus::Ok,
                        body: ReplyBody::Pong { token: 0xDEADBEEF },
                    }),
                },
                "0401900302070109efbeadde8d5b96ac00",
            ),
            (
                Frame {
                    seq: 0,
                    msg: Message::Fault(Fault {
                        timestamp_us: 0,
                        code: fault_code::BAD_MODEL,
                        detail: 5,
                        value: 0x11223344,
                    }),
                },
                "03010201010101010b0105443322115e830dd000",
            ),
        ];
        for (frame, want) in cases {
            let w = wire(&frame);
            assert_eq!(hex(&w), want, "{frame:?}");
            assert_eq!(*w.last().unwrap(), 0);
            assert!(!w[..w.len() - 1].contains(&0));
            assert_eq!(decode(&w).unwrap(), frame);
        }
    }

    pub(super) fn samples_example() -> Frame {
        let mut value = [0i32; MAX_CHANNELS];
        value[..4].copy_from_slice(&[0, 1500, -1240, 39_710]);
        Frame {
            seq: 0x0102,
            msg: Message::Samples(Samples {
                timestamp_us: 25_000,
                status: status::ARMED,
                marks: mark::GRASP_START | mark::LIFT,
                channels: 4,
                unit: 0,
                fault: 0b1000,
                value,
            }),
        }
    }

    /// Pins the sample stream, phase-mark and upload frames (docs/protocol.md and the C test
    /// quote them); expected strings computed independently (Python: zlib.crc32, hand COBS).
    #[test]
    fn golden_bytes_samples_and_upload() {
        let cases: [(Frame, &str); 7] = [
            (
                samples_example(),
                "0701040201a861010401030402080101010103dc05010728fbffff1e9b01055235fd1e00",
            ),
            (
                Frame {
                    seq: 10,
                    msg: Message::Command(Command::StreamMode(StreamMode::FlagsAndSamples)),
                },
                "0401160a0601ae63a0f400",
            ),
            (
                Frame {
                    seq: 11,
                    msg: Message::Command(Command::Lift),
                },
                "0401150b022903e16000",
            ),
            (
                Frame {
                    seq: 12,
                    msg: Message::Command(Command::UploadBegin {
                        size: 80_444,
                        crc: 0x89AB_CDEF,
                    }),
                },
                "0401170c043c3a0109efcdab8996de50a600",
            ),
            (
                Frame {
                    seq: 13,
                    msg: Message::Command(Command::UploadChunk(Chunk::new(
                        128,
                        &[0x53, 0x47, 0x4d, 0x42, 1, 0, 2, 0],
                    ))),
                },
                "0401180d028001010653474d4201020209c777582428bd968500",
            ),
            (
                Frame {
                    seq: 14,
                    msg: Message::Command(Command::UploadCommit),
                },
                "0401190e05080d8c1400",
            ),
            (
                Frame {
                    seq: 5,
                    msg: Message::Reply(Reply {
                        request_seq: 13,
                        status: ReplyStatus::BadArgument,
                        body: ReplyBody::Upload {
                            command: msg_type::UPLOAD_CHUNK,
                            code: upload_code::OUT_OF_ORDER,
                            detail: 0,
                            slot: 0,
                            value: 256,
                        },
                    }),
                },
                "04019805020d0301040101020101050b7aa05600",
            ),
        ];
        for (frame, want) in cases {
            let w = wire(&frame);
            assert_eq!(hex(&w), want, "{frame:?}");
            assert_eq!(decode(&w).unwrap(), frame);
        }
    }

    /// Wire bytes per frame and the link load of each stream mode, from the encoder's own
    /// frame sizes; docs/protocol.md quotes these numbers. 8N1 = 10 bits per byte.
    #[test]
    fn sample_stream_bandwidth_at_921600_baud() {
        fn wire_len(msg: Message) -> usize {
            let mut out = [0u8; MAX_WIRE];
            encode(&Frame { seq: 0, msg }, &mut out)
        }
        let mut rows = Vec::new();
        for (channels, rate_mhz) in [(16u8, 40_000u64), (4, 71_000)] {
            let flags = wire_len(Message::Flags(Flags {
                timestamp_us: 0,
                status: 0,
                channels,
                unstable: 0,
                fault: 0,
                overruns: 0,
                skipped: 0,
                p: [PUnstable::NONE; MAX_CHANNELS],
            }));
            let samples = wire_len(Message::Samples(Samples {
                timestamp_us: 0,
                status: 0,
                marks: 0,
                channels,
                unit: 0,
                fault: 0,
                value: [0; MAX_CHANNELS],
            }));
            // Header 4 + body + CRC 4, + 1 COBS overhead byte + 1 delimiter.
            assert_eq!(flags, 4 + 14 + 2 * channels as usize + 4 + 2);
            assert_eq!(samples, 4 + 10 + 4 * channels as usize + 4 + 2);
            // Bits per second ×1000 (rate in mHz), as per mille of 921 600 baud.
            let per_mille = |bytes: usize| (bytes as u64 * 10 * rate_mhz) / 921_600;
            rows.push((
                channels,
                flags,
                samples,
                per_mille(flags),
                per_mille(samples),
                per_mille(flags + samples),
            ));
        }
        assert_eq!(
            rows,
            [(16, 56, 84, 24, 36, 60), (4, 32, 36, 24, 27, 52)],
            "update the bandwidth table in docs/protocol.md"
        );
    }

    fn all_kinds() -> Vec<Frame> {
        let info = Info {
            firmware: [0, 1, 0],
            profile: 0,
            channels: 16,
            oversample: 16,
            model_ok: 1,
            variant: 2,
            model_id: 0x5EED_0001,
            model_crc: 0x1234_5678,
            sample_rate_mhz: Millihertz(16_700),
            hidden: 128,
            threshold_q15: 16384,
            raise_after: 1,
            clear_after: 1,
            name: *b"golden-c128\0",
        };
        let mut v = vec![flags_example(), samples_example()];
        v.push(Frame {
            seq: 1,
            msg: Message::Samples(Samples {
                timestamp_us: u32::MAX,
                status: 0xFF,
                marks: mark::KNOWN,
                channels: 16,
                unit: 1,
                fault: 0xFFFF,
                value: [i32::MIN; MAX_CHANNELS],
            }),
        });
        let mut full = [0u16; 16];
        for (i, p) in full.iter_mut().enumerate() {
            *p = (i as u16) * 2000;
        }
        v.push(Frame {
            seq: u16::MAX,
            msg: Message::Flags(Flags {
                timestamp_us: u32::MAX,
                status: 0xFF,
                channels: 16,
                unstable: 0xFFFF,
                fault: 0x8001,
                overruns: u16::MAX,
                skipped: u16::MAX,
                p: wire_p(full),
            }),
        });
        for msg in [
            Message::Fault(Fault {
                timestamp_us: 5,
                code: 2,
                detail: 0,
                value: 40_000,
            }),
            Message::Error(Error {
                error: 5,
                msg_type: 0,
                request_seq: 0xFFFF,
            }),
            Message::Command(Command::Ping { token: 0 }),
            Message::Command(Command::GraspStart),
            Message::Command(Command::Release),
            Message::Command(Command::Info),
            Message::Command(Command::Lift),
            Message::Command(Command::StreamMode(StreamMode::Samples)),
            Message::Command(Command::UploadBegin { size: 1, crc: 2 }),
            Message::Command(Command::UploadChunk(Chunk::new(0, &[0xAB; MAX_CHUNK]))),
            Message::Command(Command::UploadChunk(Chunk::new(u32::MAX, &[0]))),
            Message::Command(Command::UploadCommit),
            Message::Reply(Reply {
                request_seq: 9,
                status: ReplyStatus::Ok,
                body: ReplyBody::Lifted,
            }),
            Message::Reply(Reply {
                request_seq: 9,
                status: ReplyStatus::Ok,
                body: ReplyBody::StreamMode(StreamMode::Flags),
            }),
            Message::Reply(Reply {
                request_seq: 9,
                status: ReplyStatus::Ok,
                body: ReplyBody::Upload {
                    command: msg_type::UPLOAD_COMMIT,
                    code: upload_code::OK,
                    detail: 0,
                    slot: 1,
                    value: 7,
                },
            }),
            Message::Command(Command::SetThreshold {
                threshold_q15: 32767,
                raise_after: 255,
                clear_after: 1,
            }),
            Message::Reply(Reply {
                request_seq: 1,
                status: ReplyStatus::Ok,
                body: ReplyBody::GraspStarted,
            }),
            Message::Reply(Reply {
                request_seq: 2,
                status: ReplyStatus::NoModel,
                body: ReplyBody::Released,
            }),
            Message::Reply(Reply {
                request_seq: 3,
                status: ReplyStatus::BadArgument,
                body: ReplyBody::ThresholdSet {
                    threshold_q15: 100,
                    raise_after: 2,
                    clear_after: 2,
                },
            }),
            Message::Reply(Reply {
                request_seq: 4,
                status: ReplyStatus::Ok,
                body: ReplyBody::Info(info),
            }),
        ] {
            v.push(Frame { seq: 42, msg });
        }
        v
    }

    /// Reads a body by the layout table alone: (field name, value) for every fixed field, then
    /// the per-channel values (`name[c]`) or the chunk's data length and CRC.
    fn read_by_layout(body: &Body, bytes: &[u8]) -> Vec<(String, u64)> {
        let mut out = Vec::new();
        let mut at = 0;
        let le = |b: &[u8]| b.iter().rev().fold(0u64, |v, &x| (v << 8) | x as u64);
        for f in body.fields {
            let n = f.ty.size();
            out.push((f.name.to_string(), le(&bytes[at..at + n.min(8)])));
            at += n;
        }
        match body.tail {
            Tail::None => {}
            Tail::PerChannel(f) => {
                let n = f.ty.size();
                for (c, v) in bytes[at..].chunks(n).enumerate() {
                    out.push((format!("{}[{c}]", f.name), le(v)));
                }
            }
            Tail::ChunkData => {
                out.push(("len".into(), (bytes.len() - at - 4) as u64));
                out.push(("chunk_crc".into(), le(&bytes[bytes.len() - 4..])));
            }
        }
        out
    }

    /// The encoder puts every field where the layout table (the C header's and the docs' source)
    /// says, with the width it says: each frame of every kind is encoded, read back by the table
    /// alone, and compared field by field with the values it was made from.
    #[test]
    fn encoder_follows_the_layout_table() {
        fn expect(msg: &Message) -> Vec<(String, u64)> {
            let v = |pairs: &[(&str, u64)]| -> Vec<(String, u64)> {
                pairs.iter().map(|(n, x)| (n.to_string(), *x)).collect()
            };
            let mut e = match *msg {
                Message::Flags(f) => v(&[
                    ("timestamp_us", f.timestamp_us as u64),
                    ("status", f.status as u64),
                    ("channels", f.channels as u64),
                    ("unstable", f.unstable as u64),
                    ("fault", f.fault as u64),
                    ("overruns", f.overruns as u64),
                    ("skipped", f.skipped as u64),
                ]),
                Message::Samples(s) => v(&[
                    ("timestamp_us", s.timestamp_us as u64),
                    ("status", s.status as u64),
                    ("marks", s.marks as u64),
                    ("channels", s.channels as u64),
                    ("unit", s.unit as u64),
                    ("fault", s.fault as u64),
                ]),
                Message::Fault(f) => v(&[
                    ("timestamp_us", f.timestamp_us as u64),
                    ("code", f.code as u64),
                    ("detail", f.detail as u64),
                    ("value", f.value as u64),
                ]),
                Message::Error(x) => v(&[
                    ("error", x.error as u64),
                    ("msg_type", x.msg_type as u64),
                    ("request_seq", x.request_seq as u64),
                ]),
                Message::Command(c) => match c {
                    Command::Ping { token } => v(&[("token", token as u64)]),
                    Command::SetThreshold {
                        threshold_q15,
                        raise_after,
                        clear_after,
                    } => v(&[
                        ("threshold_q15", threshold_q15 as u64),
                        ("raise_after", raise_after as u64),
                        ("clear_after", clear_after as u64),
                    ]),
                    Command::StreamMode(m) => v(&[("mode", m as u64)]),
                    Command::UploadBegin { size, crc } => {
                        v(&[("size", size as u64), ("crc", crc as u64)])
                    }
                    Command::UploadChunk(ch) => v(&[
                        ("offset", ch.offset as u64),
                        ("len", ch.len as u64),
                        ("chunk_crc", ch.crc as u64),
                    ]),
                    Command::GraspStart
                    | Command::Release
                    | Command::Info
                    | Command::Lift
                    | Command::UploadCommit => vec![],
                },
                Message::Reply(r) => {
                    let mut e = v(&[
                        ("request_seq", r.request_seq as u64),
                        ("status", r.status as u64),
                    ]);
                    e.extend(match r.body {
                        ReplyBody::Pong { token } => v(&[("token", token as u64)]),
                        ReplyBody::ThresholdSet {
                            threshold_q15,
                            raise_after,
                            clear_after,
                        } => v(&[
                            ("threshold_q15", threshold_q15 as u64),
                            ("raise_after", raise_after as u64),
                            ("clear_after", clear_after as u64),
                        ]),
                        ReplyBody::StreamMode(m) => v(&[("mode", m as u64)]),
                        ReplyBody::Upload {
                            code,
                            detail,
                            slot,
                            value,
                            ..
                        } => v(&[
                            ("code", code as u64),
                            ("detail", detail as u64),
                            ("slot", slot as u64),
                            ("value", value as u64),
                        ]),
                        ReplyBody::Info(i) => {
                            let le =
                                |b: &[u8]| b.iter().rev().fold(0u64, |v, &x| (v << 8) | x as u64);
                            v(&[
                                ("version", VERSION as u64),
                                ("firmware", le(&i.firmware)),
                                ("profile", i.profile as u64),
                                ("channels", i.channels as u64),
                                ("oversample", i.oversample as u64),
                                ("model_ok", i.model_ok as u64),
                                ("variant", i.variant as u64),
                                ("reserved", 0),
                                ("hidden", i.hidden as u64),
                                ("model_id", i.model_id as u64),
                                ("model_crc", i.model_crc as u64),
                                ("sample_rate_mhz", i.sample_rate_mhz.0 as u64),
                                ("threshold_q15", i.threshold_q15 as u64),
                                ("raise_after", i.raise_after as u64),
                                ("clear_after", i.clear_after as u64),
                                ("name", le(&i.name[..8])),
                            ])
                        }
                        ReplyBody::GraspStarted | ReplyBody::Released | ReplyBody::Lifted => {
                            vec![]
                        }
                    });
                    e
                }
            };
            match *msg {
                Message::Flags(f) => e.extend(
                    (0..f.channels as usize).map(|c| (format!("p[{c}]"), f.p[c].to_bits() as u64)),
                ),
                Message::Samples(s) => e.extend(
                    (0..s.channels as usize)
                        .map(|c| (format!("value[{c}]"), s.value[c] as u32 as u64)),
                ),
                _ => {}
            }
            e
        }
        let mut kinds = std::collections::BTreeSet::new();
        for f in all_kinds() {
            let mut payload = [0u8; MAX_PAYLOAD];
            let n = encode_payload(&f, &mut payload);
            let t = payload[1];
            let m = MsgType::from_u8(t & !msg_type::REPLY).unwrap();
            let body = &payload[HEADER_LEN..n - CRC_LEN];
            let got = if t & msg_type::REPLY != 0 {
                let head = Body {
                    fields: REPLY_HEAD,
                    tail: Tail::None,
                };
                let mut g = read_by_layout(&head, &body[..head.fixed_len()]);
                g.extend(read_by_layout(
                    &m.reply_body().unwrap(),
                    &body[head.fixed_len()..],
                ));
                g
            } else {
                read_by_layout(&m.body(), body)
            };
            assert_eq!(got, expect(&f.msg), "{f:?}");
            kinds.insert(t);
        }
        // Every device message and command, and the replies with fields, were checked.
        for m in MsgType::ALL {
            assert!(kinds.contains(&(m as u8)), "{m:?} not among the examples");
        }
    }

    #[test]
    fn every_kind_round_trips_and_fits() {
        for f in all_kinds() {
            let mut payload = [0u8; MAX_PAYLOAD];
            let n = encode_payload(&f, &mut payload);
            assert!((HEADER_LEN + CRC_LEN..=MAX_PAYLOAD).contains(&n), "{f:?}");
            assert_eq!(decode_payload(&payload[..n]).unwrap(), f);
            let w = wire(&f);
            assert!(w.len() <= MAX_WIRE);
            assert_eq!(decode(&w[..w.len() - 1]).unwrap(), f);
        }
    }

    /// Re-encodes a payload after `edit`, with a fresh CRC.
    fn with_crc(mut payload: Vec<u8>) -> Vec<u8> {
        let crc = CRC32.checksum(&payload);
        payload.extend_from_slice(&crc.to_le_bytes());
        let mut out = vec![0u8; cobs::max_encoding_length(payload.len()) + 1];
        let n = cobs::encode(&payload, &mut out);
        out.truncate(n);
        out
    }

    fn with_crc_payload(mut payload: Vec<u8>) -> Vec<u8> {
        let crc = CRC32.checksum(&payload);
        payload.extend_from_slice(&crc.to_le_bytes());
        payload
    }

    #[test]
    fn malformed_frames_each_have_their_error() {
        let good = wire(&Frame {
            seq: 9,
            msg: Message::Command(Command::SetThreshold {
                threshold_q15: 1000,
                raise_after: 1,
                clear_after: 1,
            }),
        });
        // Bad CRC: flip one body bit.
        let mut payload = [0u8; MAX_PAYLOAD];
        let n = cobs::decode(&good[..good.len() - 1], &mut payload)
            .unwrap()
            .frame_size();
        let mut p = payload[..n].to_vec();
        p[5] ^= 0x40;
        assert!(matches!(
            decode_payload(&p),
            Err(DecodeError::BadCrc { .. })
        ));
        // Truncated.
        assert_eq!(
            decode_payload(&payload[..5]),
            Err(DecodeError::Truncated { len: 5 })
        );
        assert_eq!(
            decode(&[0x01, 0x01]),
            Err(DecodeError::Truncated { len: 1 })
        );
        // Truncated on the wire = last bytes lost: CRC error or truncated, never a panic.
        for cut in 1..good.len() - 1 {
            assert!(decode(&good[..cut]).is_err(), "cut {cut}");
        }
        // Wrong version, unknown type, bad length, bad value (CRC good each time).
        let body = &payload[..n - CRC_LEN];
        let mut v = body.to_vec();
        v[0] = 2;
        assert_eq!(decode(&with_crc(v)), Err(DecodeError::WrongVersion(2)));
        let mut v = body.to_vec();
        v[1] = 0x42;
        assert_eq!(decode(&with_crc(v)), Err(DecodeError::UnknownType(0x42)));
        let mut v = body.to_vec();
        v.push(0);
        assert_eq!(
            decode(&with_crc(v)),
            Err(DecodeError::BadLength {
                msg_type: msg_type::SET_THRESHOLD,
                len: 5
            })
        );
        let mut v = body.to_vec();
        v[4] = 0;
        v[5] = 0; // threshold 0
        let w = with_crc(v);
        assert_eq!(
            decode(&w),
            Err(DecodeError::BadValue {
                msg_type: msg_type::SET_THRESHOLD
            })
        );
        let e = error_reply_for(&w, decode(&w).unwrap_err());
        assert_eq!((e.error, e.msg_type, e.request_seq), (9, 0x13, 9));
        // Empty, invalid COBS, too long.
        assert_eq!(decode(&[]), Err(DecodeError::Empty));
        assert_eq!(decode(&[0]), Err(DecodeError::Empty));
        assert_eq!(decode(&[0x05, 0x01]), Err(DecodeError::Cobs));
        assert_eq!(decode(&[0x03, 0x00, 0x01]), Err(DecodeError::Cobs));
        assert_eq!(decode(&[0x11; 200]), Err(DecodeError::TooLong));
        // Flags with 17 channels, or a mask bit beyond N.
        let mut v = vec![VERSION, msg_type::FLAGS, 0, 0, 0, 0, 0, 0, 0, 17];
        v.extend_from_slice(&[0; 8 + 34]);
        assert_eq!(
            decode(&with_crc(v)),
            Err(DecodeError::BadValue {
                msg_type: msg_type::FLAGS
            })
        );
        let mut v = vec![VERSION, msg_type::FLAGS, 0, 0, 0, 0, 0, 0, 0, 1, 2, 0];
        v.extend_from_slice(&[0; 6 + 2]);
        assert_eq!(
            decode(&with_crc(v)),
            Err(DecodeError::BadValue {
                msg_type: msg_type::FLAGS
            })
        );
        // Samples: unknown mark bit, 0 channels, a fault bit beyond N, one value short.
        let mut payload = [0u8; MAX_PAYLOAD];
        let n = encode_payload(&tests::samples_example(), &mut payload);
        let body = payload[..n - CRC_LEN].to_vec();
        let bad = |i: usize, v: u8| {
            let mut b = body.clone();
            b[i] = v;
            decode(&with_crc(b))
        };
        let samples_value = Err(DecodeError::BadValue {
            msg_type: msg_type::SAMPLES,
        });
        assert_eq!(bad(9, 0b1000), samples_value);
        assert_eq!(bad(10, 0), samples_value);
        assert_eq!(bad(12, 0x10), samples_value);
        assert_eq!(
            decode(&with_crc(body[..body.len() - 1].to_vec())),
            Err(DecodeError::BadLength {
                msg_type: msg_type::SAMPLES,
                len: 25
            })
        );
        // Stream mode 3; a chunk without data; a chunk over MAX_CHUNK.
        let v = vec![VERSION, msg_type::STREAM_MODE, 0, 0, 3];
        assert_eq!(
            decode(&with_crc(v)),
            Err(DecodeError::BadValue {
                msg_type: msg_type::STREAM_MODE
            })
        );
        let v = vec![
            VERSION,
            msg_type::UPLOAD_CHUNK,
            0,
            0,
            0,
            0,
            0,
            0,
            1,
            2,
            3,
            4,
        ];
        assert_eq!(
            decode(&with_crc(v)),
            Err(DecodeError::BadLength {
                msg_type: msg_type::UPLOAD_CHUNK,
                len: 8
            })
        );
        let mut v = vec![VERSION, msg_type::UPLOAD_CHUNK, 0, 0];
        v.extend_from_slice(&[1; 4 + MAX_CHUNK + 1 + 4]);
        assert_eq!(
            decode_payload(&with_crc_payload(v)),
            Err(DecodeError::TooLong)
        );
    }

    /// Any byte string decodes to a frame or an error, never a panic; the deframer resyncs.
    #[test]
    fn fuzz_never_panics_and_deframer_resyncs() {
        let mut x: u32 = 0x1234_5678;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        for _ in 0..20_000 {
            let len = (next() % 80) as usize;
            let bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let _ = decode(&bytes);
            let _ = decode_payload(&bytes);
        }
        // Random bodies with a good CRC for every type code: decoded or refused, never a panic,
        // and whatever decodes encodes back to the same payload.
        for _ in 0..20_000 {
            let t = next() as u8;
            let len = (next() % (MAX_PAYLOAD as u32 - 7)) as usize;
            let mut p = vec![VERSION, t, next() as u8, next() as u8];
            p.extend((0..len).map(|_| next() as u8));
            let p = with_crc_payload(p);
            // (The info reply's reserved byte is ignored by the decoder, so not compared.)
            if let Ok(f) = decode_payload(&p)
                && t != msg_type::REPLY | msg_type::INFO
            {
                let mut again = [0u8; MAX_PAYLOAD];
                let n = encode_payload(&f, &mut again);
                assert_eq!(&again[..n], &p[..], "{f:?}");
            }
        }
        // A stream: garbage, a good frame, 300 bytes without a delimiter, a good frame.
        let frames = all_kinds();
        let mut stream = vec![0x55, 0x13, 0x00];
        stream.extend(wire(&frames[0]));
        stream.extend(std::iter::repeat_n(0x77u8, 300));
        stream.push(0);
        stream.extend(wire(&frames[2]));
        let mut d = Deframer::new();
        let mut got = Vec::new();
        for b in stream {
            if let Some(r) = d.push_decode(b) {
                got.push(r.map_err(|(e, _)| e));
            }
        }
        assert_eq!(got.len(), 4);
        assert!(got[0].is_err());
        assert_eq!(got[1], Ok(frames[0]));
        assert_eq!(got[2], Err(DecodeError::TooLong));
        assert_eq!(got[3], Ok(frames[2]));
    }
}
