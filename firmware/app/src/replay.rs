//! Replay of a recorded trial through exactly the firmware's path, producing the bytes the
//! firmware would send. Used by the host (`slipguard replay`, issue 7, wraps [`run`]) and
//! mirrored step by step by the QEMU build (`firmware/qemu-app`), whose output must equal it
//! byte for byte.
//!
//! The trial is at the model rate (e.g. the dataset's 16.7 Hz, in the profile's unit). The
//! emulated sensor ([`EmulatedSensor`]) turns each step into [`RATIO`] ADC scans: the value
//! converted to an ADC code ([`Profile::to_counts`]), held for the step, plus a deterministic
//! ±1 LSB dither (ADC noise, so a live channel is never mistaken for a stuck one). From there on
//! the code is the firmware's: [`Frontend`] (fault detection, anti-alias filter, ÷16) and
//! [`App`], with the script's command bytes fed through the same deframer just before the frame
//! they are scheduled for, as the inference task does when a command and a frame are both
//! pending.

use crate::MAX_CHANNELS;
use crate::app::App;
use crate::decimate::RATIO;
use crate::frontend::{FrameInput, Frontend};
use crate::profile::{AdcCode, Profile};
use slipguard_core::protocol::{self, Deframer, Frame, MAX_WIRE};

/// A trial at the model rate: `steps × channels` values, row-major, as little-endian `i32`
/// (the format of `fixtures/*.bin`).
#[derive(Clone, Copy, Debug)]
pub struct Trial<'a> {
    bytes: &'a [u8],
    /// Values per step.
    pub channels: usize,
}

impl<'a> Trial<'a> {
    /// Wraps little-endian `i32` rows of `channels` values (a trailing partial row is ignored).
    pub const fn new(bytes: &'a [u8], channels: usize) -> Self {
        Self { bytes, channels }
    }
    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.bytes.len() / (4 * self.channels.max(1))
    }
    /// Value of `channel` at `step` (0 outside the trial).
    pub fn value(&self, step: usize, channel: usize) -> i32 {
        let i = 4 * (step * self.channels + channel);
        match self.bytes.get(i..i + 4) {
            Some(b) if channel < self.channels => i32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            _ => 0,
        }
    }
}

/// The Cheez_100_814_top_3 trial of the eagle-shoal dataset (CDLA-Permissive-1.0, see
/// `fixtures/README.md`): 400 steps × 16 forces in mN at 16.7 Hz; dropped after the lift.
pub const CHEEZ_TRIAL: Trial<'static> =
    Trial::new(include_bytes!("../fixtures/Cheez_100_814_top_3.bin"), 16);

/// An injected open wire: `channel` reads code 0 during trial steps `from_step..to_step`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OpenWire {
    /// Channel.
    pub channel: usize,
    /// First trial step without the sensor.
    pub from_step: usize,
    /// First trial step with the sensor back.
    pub to_step: usize,
}

/// Turns model-rate trial values into ADC scans (see the module docs), optionally with open
/// wires injected.
#[derive(Clone, Debug)]
pub struct EmulatedSensor<'f> {
    profile: Profile,
    rng: u32,
    open: &'f [OpenWire],
}

impl<'f> EmulatedSensor<'f> {
    /// A sensor with the fixed dither seed.
    pub const fn new(profile: Profile) -> Self {
        Self::with_open_wires(profile, &[])
    }

    /// A sensor whose channels disconnect as `open` says.
    pub const fn with_open_wires(profile: Profile, open: &'f [OpenWire]) -> Self {
        Self {
            profile,
            rng: 0x2545_F491,
            open,
        }
    }

    fn dither(&mut self) -> i32 {
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.rng = x;
        (x % 3) as i32 - 1
    }

    /// One scan for trial step `step` (every call advances the dither).
    pub fn scan(&mut self, trial: &Trial<'_>, step: usize, out: &mut [AdcCode; MAX_CHANNELS]) {
        for (c, o) in out.iter_mut().enumerate().take(self.profile.channels) {
            let code = self.profile.to_counts(trial.value(step, c)).0 as i64 + self.dither() as i64;
            let open = self
                .open
                .iter()
                .any(|w| w.channel == c && (w.from_step..w.to_step).contains(&step));
            *o = if open {
                AdcCode(0)
            } else {
                self.profile.clamp_code(code)
            };
        }
    }
}

/// Command bytes that arrive just before frame `before_frame` is processed.
#[derive(Clone, Copy, Debug)]
pub struct ScriptItem<'a> {
    /// Frame index the bytes precede.
    pub before_frame: u32,
    /// Raw bytes as received on the UART (any number of frames, or garbage).
    pub bytes: &'a [u8],
}

/// Feeds received bytes through the deframer and the app; every reply goes to `sink`.
/// The inference task of every board layer calls this for each received chunk.
pub fn receive(
    app: &mut App<'_>,
    deframer: &mut Deframer,
    bytes: &[u8],
    mut sink: impl FnMut(&Frame),
) {
    for &b in bytes {
        if let Some(r) = deframer.push_decode(b) {
            let reply = app.handle(r);
            sink(&reply);
        }
    }
}

/// Encodes a frame for the UART.
pub fn wire(frame: &Frame, out: &mut [u8; MAX_WIRE]) -> usize {
    protocol::encode(frame, out)
}

/// Runs `trial` through the firmware path with `blob`, the command `script` and the injected
/// `open_wires`; every frame the firmware would send goes to `sink` as wire bytes. Returns the
/// number of frames sent.
pub fn run(
    profile: Profile,
    blob: &[u8],
    trial: &Trial<'_>,
    script: &[ScriptItem<'_>],
    open_wires: &[OpenWire],
    mut sink: impl FnMut(&[u8]),
) -> usize {
    let mut app = App::new(profile, blob);
    let mut frontend = Frontend::new(profile);
    let mut sensor = EmulatedSensor::with_open_wires(profile, open_wires);
    let mut deframer = Deframer::new();
    let mut sent = 0;
    let mut buf = [0u8; MAX_WIRE];
    let mut scan = [AdcCode(0); MAX_CHANNELS];
    for step in 0..trial.steps() {
        for _ in 0..RATIO {
            sensor.scan(trial, step, &mut scan);
            let Some(input) = frontend.push_scan(&scan) else {
                continue;
            };
            for item in script.iter().filter(|s| s.before_frame == input.index) {
                receive(&mut app, &mut deframer, item.bytes, |f| {
                    let n = wire(f, &mut buf);
                    sink(&buf[..n]);
                    sent += 1;
                });
            }
            app.frames(&input, false, |f| {
                let n = wire(f, &mut buf);
                sink(&buf[..n]);
                sent += 1;
            });
        }
    }
    sent
}

/// The frame inputs of a trial, without the app (for tests and plots).
pub fn frame_inputs(
    profile: Profile,
    trial: &Trial<'_>,
    mut each: impl FnMut(&FrameInput),
) -> usize {
    let mut frontend = Frontend::new(profile);
    let mut sensor = EmulatedSensor::new(profile);
    let mut scan = [AdcCode(0); MAX_CHANNELS];
    let mut n = 0;
    for step in 0..trial.steps() {
        for _ in 0..RATIO {
            sensor.scan(trial, step, &mut scan);
            if let Some(input) = frontend.push_scan(&scan) {
                each(&input);
                n += 1;
            }
        }
    }
    n
}

/// The scenario the QEMU comparison uses on [`CHEEZ_TRIAL`]: ping and info at boot, line noise,
/// a corrupted frame (bad CRC) and an unknown type, a threshold change, grasp start at the
/// trial's grasp label (step 52), release at step 300; and channel 14's wire open during steps
/// 150–169.
pub mod cheez_script {
    use super::{OpenWire, ScriptItem};

    /// Channel 14 disconnected for 20 steps.
    pub const OPEN_WIRES: &[OpenWire] = &[OpenWire {
        channel: 14,
        from_step: 150,
        to_step: 170,
    }];

    /// Ping (seq 1, token 0xC0FFEE00) then info (seq 2).
    pub const BOOT: &[u8] = &[
        0x04, 0x01, 0x10, 0x01, 0x01, 0x08, 0xEE, 0xFF, 0xC0, 0xF4, 0x52, 0x36, 0xAE, 0x00, 0x04,
        0x01, 0x14, 0x02, 0x05, 0x57, 0xD1, 0xE1, 0xB0, 0x00,
    ];
    /// Line noise, then a set-threshold frame with a flipped bit (bad CRC), then a frame of
    /// unknown type 0x42 with a good CRC.
    pub const GARBAGE: &[u8] = &[
        0x55, 0xAA, 0x00, 0x04, 0x01, 0x13, 0x03, 0x01, 0x08, 0x41, 0x01, 0x01, 0x1D, 0xA7, 0xAC,
        0x67, 0x00, 0x04, 0x01, 0x42, 0x04, 0x05, 0xD3, 0x24, 0x8A, 0x8E, 0x00,
    ];
    /// Set threshold 0.6 (19661), raise after 2, clear after 2 (seq 5).
    pub const THRESHOLD: &[u8] = &[
        0x04, 0x01, 0x13, 0x05, 0x09, 0xCD, 0x4C, 0x02, 0x02, 0xC6, 0x89, 0xEC, 0x8E, 0x00,
    ];
    /// Grasp start (seq 6).
    pub const GRASP: &[u8] = &[0x04, 0x01, 0x11, 0x06, 0x05, 0xB8, 0xD6, 0x46, 0xD2, 0x00];
    /// Release (seq 7).
    pub const RELEASE: &[u8] = &[0x04, 0x01, 0x12, 0x07, 0x05, 0xA0, 0x59, 0x1B, 0xC9, 0x00];

    /// The script.
    pub const SCRIPT: &[ScriptItem<'static>] = &[
        ScriptItem {
            before_frame: 0,
            bytes: BOOT,
        },
        ScriptItem {
            before_frame: 10,
            bytes: GARBAGE,
        },
        ScriptItem {
            before_frame: 20,
            bytes: THRESHOLD,
        },
        ScriptItem {
            before_frame: 52,
            bytes: GRASP,
        },
        ScriptItem {
            before_frame: 300,
            bytes: RELEASE,
        },
    ];
}

/// The field scenario the QEMU comparison also runs: the sample stream on, the phase commands,
/// an upload of a second model into the flash's free slot while the frames go on, and a grasp
/// start on the new model. [`field_script::commands`] gives the command bytes before each frame;
/// [`run_field`] is the host side.
pub mod field_script {
    use slipguard_core::protocol::{
        self, Chunk, Command, Frame, MAX_CHUNK, MAX_WIRE, Message, StreamMode,
    };

    /// Stream mode flags + samples before this frame.
    pub const STREAM_AT: u32 = 0;
    /// Grasp start (the trial's label).
    pub const GRASP_AT: u32 = 52;
    /// Lift.
    pub const LIFT_AT: u32 = 87;
    /// Release (an upload needs flagging off).
    pub const RELEASE_AT: u32 = 300;
    /// Upload begin; the chunks follow from the next frame on.
    pub const UPLOAD_AT: u32 = 301;
    /// Chunks before each frame (about what a stop-and-wait host gets through in a period).
    pub const CHUNKS_PER_FRAME: u32 = 8;
    /// Grasp start on the new model.
    pub const GRASP_AGAIN_AT: u32 = 390;

    /// The frame the commit precedes, for a blob of `len` bytes.
    pub const fn commit_at(len: usize) -> u32 {
        let chunks = len.div_ceil(MAX_CHUNK) as u32;
        UPLOAD_AT + 1 + chunks.div_ceil(CHUNKS_PER_FRAME)
    }

    /// Calls `sink` with the wire bytes of each command scheduled before frame `frame`, when
    /// `upload` is the blob sent (command seq numbers from 1 in script order).
    pub fn commands(frame: u32, upload: &[u8], mut sink: impl FnMut(&[u8])) {
        let mut send = |seq: u32, c: Command| {
            let mut w = [0u8; MAX_WIRE];
            let n = protocol::encode(
                &Frame {
                    seq: seq as u16,
                    msg: Message::Command(c),
                },
                &mut w,
            );
            sink(&w[..n]);
        };
        let chunks = upload.len().div_ceil(MAX_CHUNK) as u32;
        match frame {
            STREAM_AT => send(1, Command::StreamMode(StreamMode::FlagsAndSamples)),
            GRASP_AT => send(2, Command::GraspStart),
            LIFT_AT => send(3, Command::Lift),
            RELEASE_AT => send(4, Command::Release),
            UPLOAD_AT => send(
                5,
                Command::UploadBegin {
                    size: upload.len() as u32,
                    crc: slipguard_core::blob::CRC32.checksum(upload),
                },
            ),
            GRASP_AGAIN_AT => send(7 + chunks, Command::GraspStart),
            f if f == commit_at(upload.len()) => send(6 + chunks, Command::UploadCommit),
            f if f > UPLOAD_AT => {
                let first = (f - UPLOAD_AT - 1) * CHUNKS_PER_FRAME;
                for i in first..(first + CHUNKS_PER_FRAME).min(chunks) {
                    let at = i as usize * MAX_CHUNK;
                    let end = (at + MAX_CHUNK).min(upload.len());
                    send(
                        6 + i,
                        Command::UploadChunk(Chunk::new(at as u32, &upload[at..end])),
                    );
                }
            }
            _ => {}
        }
    }
}

/// Runs `trial` through the firmware path with the field script: the app starts on the model
/// `flash` selects at boot (its RAM copy `model`, as the firmware copies it), `second` is
/// uploaded into the other slot, and after the commit the app reloads from `second_ram` (its
/// RAM copy; the flash contents must equal it, else the app reloads without a model). Every
/// frame goes to `sink` as wire bytes; returns (frames sent, frame index of the reload).
pub fn run_field<F: crate::upload::Flash>(
    profile: Profile,
    model: &[u8],
    second_ram: &[u8],
    flash: &mut F,
    trial: &Trial<'_>,
    mut sink: impl FnMut(&[u8]),
) -> (usize, Option<u32>) {
    let mut app = App::new(profile, model);
    let mut up = crate::upload::Uploader::new(crate::upload::select(flash, &profile));
    let mut frontend = Frontend::new(profile);
    let mut sensor = EmulatedSensor::new(profile);
    let mut deframer = Deframer::new();
    let mut sent = 0;
    let mut reloaded = None;
    let mut buf = [0u8; MAX_WIRE];
    let mut scan = [AdcCode(0); MAX_CHANNELS];
    for step in 0..trial.steps() {
        for _ in 0..RATIO {
            sensor.scan(trial, step, &mut scan);
            let Some(input) = frontend.push_scan(&scan) else {
                continue;
            };
            let mut reload = None;
            field_script::commands(input.index, second_ram, |bytes| {
                let r =
                    crate::upload::receive(&mut up, &mut app, flash, &mut deframer, bytes, |f| {
                        let n = wire(f, &mut buf);
                        sink(&buf[..n]);
                        sent += 1;
                    });
                reload = reload.or(r);
            });
            if let Some(a) = reload {
                let same = crate::upload::blob(flash, Some(a)) == second_ram;
                app = app.reload(if same { second_ram } else { &[] });
                reloaded = Some(input.index);
            }
            app.frames(&input, false, |f| {
                let n = wire(f, &mut buf);
                sink(&buf[..n]);
                sent += 1;
            });
        }
    }
    (sent, reloaded)
}

/// A field scenario given at run time instead of compiled in (the QEMU build's `field` feature
/// reads one from memory that QEMU's `-device loader` filled; `replay_field --scenario` reads
/// the same file): the sensor profile, the trial and the blob the field script uploads.
///
/// Layout, little-endian: magic [`MAGIC`], the [`ProfileId`](crate::profile::ProfileId) byte
/// and three zero bytes, the trial's length in bytes (`u32`), the blob's (`u32`), the trial
/// (steps × the profile's channels `i32`, as [`Trial`]), the blob. The trial's length is a
/// multiple of 4, so the blob keeps the scenario's 4-byte alignment (a blob must be aligned).
pub mod scenario {
    use super::Trial;
    use crate::profile::{Profile, ProfileId};

    /// First bytes of a scenario.
    pub const MAGIC: [u8; 4] = *b"SGSC";
    /// Bytes before the trial.
    pub const HEADER: usize = 16;

    /// A parsed scenario, borrowing its bytes.
    #[derive(Clone, Copy, Debug)]
    pub struct Scenario<'a> {
        /// The sensor profile the trial is for.
        pub profile: Profile,
        /// The trial, at the model rate.
        pub trial: Trial<'a>,
        /// The blob the field script uploads.
        pub upload: &'a [u8],
    }

    /// Why bytes are not a scenario.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    #[non_exhaustive]
    pub enum ScenarioError {
        /// The bytes do not start with [`MAGIC`] (no scenario loaded).
        NoMagic,
        /// The profile byte names no profile.
        Profile(u8),
        /// The lengths do not fit the bytes, or the trial is not whole steps.
        Length,
    }

    impl core::fmt::Display for ScenarioError {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            match self {
                Self::NoMagic => write!(f, "no scenario (magic SGSC missing)"),
                Self::Profile(p) => write!(
                    f,
                    "scenario profile {p} is neither 0 (hand) nor 1 (suction)"
                ),
                Self::Length => write!(
                    f,
                    "scenario lengths do not fit: the trial must be whole steps of the profile's channels and both parts inside the bytes"
                ),
            }
        }
    }

    /// The header for a trial of `trial_len` bytes and a blob of `upload_len` bytes.
    pub fn header(profile: &Profile, trial_len: usize, upload_len: usize) -> [u8; HEADER] {
        let mut h = [0u8; HEADER];
        h[..4].copy_from_slice(&MAGIC);
        h[4] = profile.id as u8;
        h[8..12].copy_from_slice(&(trial_len as u32).to_le_bytes());
        h[12..16].copy_from_slice(&(upload_len as u32).to_le_bytes());
        h
    }

    /// Parses a scenario at the start of `bytes` (anything after it is ignored).
    pub fn parse(bytes: &[u8]) -> Result<Scenario<'_>, ScenarioError> {
        let h = bytes.get(..HEADER).ok_or(ScenarioError::NoMagic)?;
        if h[..4] != MAGIC {
            return Err(ScenarioError::NoMagic);
        }
        let profile = ProfileId::from_u8(h[4])
            .ok_or(ScenarioError::Profile(h[4]))?
            .profile();
        let len = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]) as usize;
        let (trial_len, upload_len) = (len(8), len(12));
        let step = 4 * profile.channels;
        let trial_end = HEADER.checked_add(trial_len).ok_or(ScenarioError::Length)?;
        let end = trial_end
            .checked_add(upload_len)
            .ok_or(ScenarioError::Length)?;
        if trial_len == 0 || trial_len % step != 0 || end > bytes.len() {
            return Err(ScenarioError::Length);
        }
        Ok(Scenario {
            profile,
            trial: Trial::new(&bytes[HEADER..trial_end], profile.channels),
            upload: &bytes[trial_end..end],
        })
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn a_scenario_parses_back_and_bad_ones_say_why() {
            // Written by hand: suction, 2 steps of 4 channels, a 4-byte blob.
            let mut b = [0u8; HEADER + 32 + 4 + 3];
            b[..16].copy_from_slice(&[b'S', b'G', b'S', b'C', 1, 0, 0, 0, 32, 0, 0, 0, 4, 0, 0, 0]);
            b[16 + 4 * 5..16 + 4 * 6].copy_from_slice(&(-7i32).to_le_bytes());
            b[48..52].copy_from_slice(&[9, 8, 7, 6]);
            assert_eq!(header(&Profile::SUCTION, 32, 4), b[..16]);
            let s = parse(&b).unwrap();
            assert_eq!(s.profile, Profile::SUCTION);
            assert_eq!(s.trial.steps(), 2);
            assert_eq!(s.trial.value(1, 1), -7);
            assert_eq!(s.upload, &[9, 8, 7, 6]);
            assert_eq!(parse(&[0u8; 64]).unwrap_err(), ScenarioError::NoMagic);
            let mut p = b;
            p[4] = 2;
            assert_eq!(parse(&p).unwrap_err(), ScenarioError::Profile(2));
            // As hand: 32 bytes are not whole 16-channel steps.
            let mut h = b;
            h[4] = 0;
            assert_eq!(parse(&h).unwrap_err(), ScenarioError::Length);
            // The blob runs past the end.
            assert_eq!(parse(&b[..50]).unwrap_err(), ScenarioError::Length);
        }
    }
}
