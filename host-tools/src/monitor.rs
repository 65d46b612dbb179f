//! Flag-stream monitor: the hand controller's side of `docs/protocol.md`.
//!
//! [`Monitor::push`] takes raw bytes as they arrive (serial port, capture file, pseudo
//! terminal), splits them into frames with the core's resynchronising
//! [`Deframer`], decodes them with the core's decoder (the only one), and keeps
//!
//! * the latest flag frame (per-channel state, p(unstable), fault) for the live view;
//! * counters: frames by kind, **corrupt** runs (anything between two `0x00` that does not
//!   decode: bad CRC, bad COBS, over-long, …) and **lost** frames (gaps in the device's
//!   sequence numbers, which number every frame it sends: a corrupted frame is also a lost
//!   one, a frame that vanished entirely is only a lost one);
//! * every flag frame, to write a recording ([`Monitor::to_trial`]) in our CSV format
//!   (docs/data-format.md; the columns are described on [`Monitor::to_trial`]);
//! * with a [`Recorder`] attached, the samples stream (the model's input per channel and the
//!   phase marks) written row by row as a training recording.
//!
//! Every size taken from the wire is bounded before anything is allocated: rates outside the
//! recording format's range are ignored, a timestamp jump of more than a second ends a
//! recording rather than filling it, and no recording grows past
//! [`slipguard_data::recording::MAX_STEPS`] rows.

use slipguard_core::units::Millihertz;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use slipguard_core::protocol::{
    Command, DecodeError, Deframer, Fault, Flags, Frame, Info, MAX_CHANNELS, Message, ReplyBody,
    Samples, StreamMode, mark, status,
};
use slipguard_core::sample::PAPER_RATE_MHZ;

use slipguard_data::recording::{self, Appender, MAX_RATE_HZ, MAX_STEPS, MIN_RATE_HZ};
use slipguard_data::trial::{Outcome, Phase, PhaseMarks, SensorKind, Stability, Trial, Unit};

/// Whether a frame rate (mHz) from the wire is one a recording can state.
pub fn rate_ok(rate_mhz: Millihertz) -> bool {
    let hz = rate_mhz.hz();
    (MIN_RATE_HZ as f64..=MAX_RATE_HZ as f64).contains(&hz)
}

/// Frame index of a frame timestamp: the firmware stamps frame `i` with
/// `(i + 1) · 10⁹ / rate_mHz` µs (rounded down), so this rounds back to `i`.
fn frame_index(t_us: u64, rate_mhz: Millihertz) -> u64 {
    ((t_us as f64 * rate_mhz.0 as f64 / 1e9).round() as u64).saturating_sub(1)
}

/// Counters of a monitoring session.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Bytes received.
    pub bytes: u64,
    /// Frames that decoded (any kind).
    pub frames: u64,
    /// Flag frames.
    pub flags: u64,
    /// Fault frames.
    pub faults: u64,
    /// Error frames (the device rejected something we sent).
    pub errors: u64,
    /// Replies to commands.
    pub replies: u64,
    /// Frames of a controller → device type (an echo or a loop-back on the line).
    pub commands: u64,
    /// Runs between delimiters that did not decode.
    pub corrupt: u64,
    /// … of which the CRC did not match.
    pub corrupt_crc: u64,
    /// … of which were longer than any frame (garbage without a delimiter).
    pub corrupt_too_long: u64,
    /// Frames missing from the sequence numbers (corrupted or never received).
    pub lost: u64,
    /// Times the sequence number went backwards (device reset).
    pub restarts: u64,
    /// Flag frames with the LATE bit.
    pub late: u64,
    /// Last `overruns` counter reported by the device.
    pub overruns: u16,
    /// Last `skipped` counter reported by the device.
    pub skipped: u16,
}

impl Stats {
    /// One line `key=value …` (stable, for scripts).
    pub fn summary(&self) -> String {
        format!(
            "bytes={} frames={} flags={} faults={} errors={} replies={} commands={} corrupt={} \
             corrupt_crc={} corrupt_too_long={} lost={} restarts={} late={} overruns={} skipped={}",
            self.bytes,
            self.frames,
            self.flags,
            self.faults,
            self.errors,
            self.replies,
            self.commands,
            self.corrupt,
            self.corrupt_crc,
            self.corrupt_too_long,
            self.lost,
            self.restarts,
            self.late,
            self.overruns,
            self.skipped
        )
    }
}

/// What one delimiter produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// A frame decoded; `lost` frames were missing before it (sequence gap).
    Frame {
        /// The frame.
        frame: Frame,
        /// Frames missing between the previous good frame and this one.
        lost: u32,
    },
    /// A run that did not decode.
    Corrupt(DecodeError),
}

/// A flag frame with its unwrapped timestamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Received {
    /// Device sequence number.
    pub seq: u16,
    /// Timestamp in µs since the device's first scan, unwrapped past 2^32.
    pub t_us: u64,
    /// The flags.
    pub flags: Flags,
}

/// The monitor state.
#[derive(Debug, Default)]
pub struct Monitor {
    deframer: Deframer,
    expected_seq: Option<u16>,
    last_ts: Option<u32>,
    ts_high: u64,
    /// Counters.
    pub stats: Stats,
    /// Latest flag frame.
    pub last_flags: Option<Flags>,
    /// Latest fault frame.
    pub last_fault: Option<Fault>,
    /// Device description, if an info reply was seen.
    pub info: Option<Info>,
    /// Every flag frame received (for the recording).
    pub received: Vec<Received>,
    /// Whether to keep [`Self::received`] (a long session without a recording need not).
    pub keep: bool,
    /// The samples stream's recorder, if recording.
    pub recorder: Option<Recorder>,
}

impl Monitor {
    /// A monitor that keeps every flag frame.
    pub fn new() -> Self {
        Self {
            keep: true,
            ..Default::default()
        }
    }

    /// Feeds received bytes; `on` sees every event in order.
    pub fn push(&mut self, bytes: &[u8], mut on: impl FnMut(&Event)) {
        self.stats.bytes += bytes.len() as u64;
        for &b in bytes {
            let Some(r) = self.deframer.push_decode(b) else {
                continue;
            };
            let ev = match r {
                Ok(frame) => {
                    let lost = self.account(&frame);
                    Event::Frame { frame, lost }
                }
                Err((e, _)) => {
                    self.stats.corrupt += 1;
                    match e {
                        DecodeError::BadCrc { .. } => self.stats.corrupt_crc += 1,
                        DecodeError::TooLong => self.stats.corrupt_too_long += 1,
                        _ => {}
                    }
                    Event::Corrupt(e)
                }
            };
            on(&ev);
        }
    }

    fn account(&mut self, frame: &Frame) -> u32 {
        self.stats.frames += 1;
        if let Message::Command(_) = frame.msg {
            // Not the device's numbering.
            self.stats.commands += 1;
            return 0;
        }
        let mut lost = 0;
        if let Some(e) = self.expected_seq {
            let gap = frame.seq.wrapping_sub(e);
            if gap >= 0x8000 {
                self.stats.restarts += 1;
                self.last_ts = None;
            } else {
                lost = gap as u32;
                self.stats.lost += gap as u64;
            }
        }
        self.expected_seq = Some(frame.seq.wrapping_add(1));
        match frame.msg {
            Message::Flags(f) => {
                self.stats.flags += 1;
                if f.status & status::LATE != 0 {
                    self.stats.late += 1;
                }
                self.stats.overruns = f.overruns;
                self.stats.skipped = f.skipped;
                let t_us = self.unwrap_ts(f.timestamp_us);
                self.last_flags = Some(f);
                if self.keep && self.received.len() < MAX_STEPS {
                    self.received.push(Received {
                        seq: frame.seq,
                        t_us,
                        flags: f,
                    });
                }
            }
            Message::Fault(f) => {
                self.stats.faults += 1;
                self.last_fault = Some(f);
            }
            Message::Error(_) => self.stats.errors += 1,
            Message::Reply(r) => {
                self.stats.replies += 1;
                if let ReplyBody::Info(i) = r.body {
                    self.info = Some(i);
                }
            }
            Message::Samples(smp) => {
                let t_us = self.unwrap_ts(smp.timestamp_us);
                let info = self.info;
                if let Some(r) = &mut self.recorder {
                    r.push(frame.seq, t_us, &smp, info.as_ref());
                }
            }
            Message::Command(_) => {}
        }
        lost
    }

    fn unwrap_ts(&mut self, ts: u32) -> u64 {
        if let Some(prev) = self.last_ts
            && ts < prev
        {
            self.ts_high += 1 << 32;
        }
        self.last_ts = Some(ts);
        self.ts_high + ts as u64
    }

    /// Frame rate in mHz: from an info reply, else the median spacing of consecutive flag
    /// frames' timestamps, else `None`.
    pub fn rate_mhz(&self) -> Option<Millihertz> {
        if let Some(i) = self.info
            && rate_ok(i.sample_rate_mhz)
        {
            return Some(i.sample_rate_mhz);
        }
        let mut d: Vec<u64> = self
            .received
            .windows(2)
            .filter(|w| w[1].seq == w[0].seq.wrapping_add(1) && w[1].t_us > w[0].t_us)
            .map(|w| w[1].t_us - w[0].t_us)
            .collect();
        if d.is_empty() {
            return None;
        }
        d.sort_unstable();
        let period_us = d[d.len() / 2] as f64;
        // Timestamps are rounded down to whole µs: round the rate to 10 mHz.
        let r = ((1e9 / period_us) / 10.0).round() as u32 * 10;
        rate_ok(Millihertz(r)).then_some(Millihertz(r))
    }

    /// The live view: one line per channel (state, p(unstable), bar) and the counters.
    pub fn view(&self) -> String {
        let mut s = String::new();
        match &self.last_flags {
            None => s.push_str("no flag frame yet\n"),
            Some(f) => {
                let _ = writeln!(
                    s,
                    "t = {:.3} s  {}{}{}{}  overruns {}  skipped {}",
                    f.timestamp_us as f64 / 1e6,
                    if f.status & status::ARMED != 0 {
                        "ARMED"
                    } else {
                        "disarmed"
                    },
                    if f.status & status::LATE != 0 {
                        " LATE"
                    } else {
                        ""
                    },
                    if f.status & status::TARED != 0 {
                        " TARED"
                    } else {
                        ""
                    },
                    // The hand flag, and whether the blob's hand rule alone raised it (format
                    // v2; the model's own hand flag down).
                    match (f.hand_unstable(), f.hand_by_rule()) {
                        (true, true) => "  HAND UNSTABLE (HAND_BY_RULE)",
                        (true, false) => "  HAND UNSTABLE",
                        _ => "",
                    },
                    f.overruns,
                    f.skipped
                );
                for c in 0..(f.channels as usize).min(MAX_CHANNELS) {
                    let bit = 1u16 << c;
                    let (state, p) = if f.fault & bit != 0 {
                        ("FAULT   ", None)
                    } else if f.unstable & bit != 0 {
                        ("UNSTABLE", f.p[c].q15())
                    } else {
                        ("stable  ", f.p[c].q15())
                    };
                    let bar = p.map_or(String::new(), |p| {
                        "#".repeat(((p.0 as u32 * 20 + 16384) / 32768) as usize)
                    });
                    let pv = p.map_or("   -  ".to_string(), |p| format!("{:.3} ", p.to_f64()));
                    let _ = writeln!(s, "c{c:<2} {state} p={pv}{bar}");
                }
            }
        }
        if let Some(f) = &self.last_fault {
            let _ = writeln!(
                s,
                "last FAULT frame: code {} detail {} value {} (t = {:.3} s)",
                f.code,
                f.detail,
                f.value,
                f.timestamp_us as f64 / 1e6
            );
        }
        let _ = writeln!(s, "{}", self.stats.summary());
        s
    }

    /// The flag frames as a recording (docs/data-format.md): one row per frame index from the
    /// first received flag frame to the last (time `0` = the first), at the device's frame
    /// rate. Columns `p0`…`p{N-1}`: p(unstable) in 0…1, `-1` when not predicted (faulted
    /// channel) or the frame was lost; `unstable_mask` and `fault_mask`: the frame's masks as
    /// decimal integers; `lost`: 1 for a frame that never arrived intact. `label`: 1 if any
    /// channel was flagged, 0 if none, empty for a lost frame. Counters and the first frame's
    /// index and timestamp go in the metadata (`monitor_*`). `None` without flag frames.
    pub fn to_trial(&self, id: &str) -> Option<Trial> {
        let first = self.received.first()?;
        let rate_mhz = self.rate_mhz().unwrap_or(PAPER_RATE_MHZ);
        let n = self
            .received
            .iter()
            .map(|r| r.flags.channels as usize)
            .max()
            .unwrap_or(1)
            .min(MAX_CHANNELS);
        // Frame index from the sample clock: t = (index + 1) · 10⁹ / rate_mHz.
        let index =
            |t_us: u64| ((t_us as f64 * rate_mhz.0 as f64 / 1e9).round() as i64 - 1).max(0) as u64;
        let i0 = index(first.t_us);
        // Rows in arrival order; a jump of more than a second (or back) ends the recording
        // there, so no timestamp from the wire sizes a buffer.
        let max_jump = (rate_mhz.0 as u64 / 1000).max(1);
        let mut rows: BTreeMap<u64, &Flags> = BTreeMap::new();
        let mut ended = None;
        let mut prev = 0u64;
        for r in &self.received {
            let i = index(r.t_us);
            let k = i.checked_sub(i0);
            match k {
                Some(k) if k <= prev + max_jump && (k as usize) < MAX_STEPS => {
                    rows.insert(k, &r.flags);
                    prev = prev.max(k);
                }
                _ => {
                    ended = Some(format!(
                        "flag frame seq {} (t = {:.6} s) jumps from step {prev} to frame index \
                         {i}: recording ended at step {prev}",
                        r.seq,
                        r.t_us as f64 / 1e6
                    ));
                    break;
                }
            }
        }
        let len = rows.keys().next_back().map_or(0, |&k| k as usize + 1);
        let mut samples = vec![vec![-1.0f32; len]; n + 3];
        let mut labels = vec![None; len];
        samples[n + 2].fill(1.0);
        for (&k, f) in &rows {
            let k = k as usize;
            for (c, ch) in samples.iter_mut().enumerate().take(n) {
                ch[k] = match f.p[c].q15() {
                    Some(p) if c < f.channels as usize => p.to_f64() as f32,
                    _ => -1.0,
                };
            }
            samples[n][k] = f.unstable as f32;
            samples[n + 1][k] = f.fault as f32;
            samples[n + 2][k] = 0.0;
            labels[k] = Some(if f.unstable != 0 {
                Stability::Unstable
            } else {
                Stability::Stable
            });
        }
        let mut t = Trial::new(
            id,
            Unit::Other("p_unstable".into()),
            rate_mhz.hz_f32(),
            samples,
        );
        t.sensor = SensorKind::Other("flags".into());
        t.outcome = Outcome::Unknown;
        t.channel_names = (0..n)
            .map(|c| format!("p{c}"))
            .chain(["unstable_mask".into(), "fault_mask".into(), "lost".into()])
            .collect();
        t.contact = vec![false; n + 3];
        t.step_labels = Some(labels);
        t.source = "slipguard monitor".into();
        let e = &mut t.extra;
        e.insert("monitor_first_frame_index".into(), i0.to_string());
        e.insert("monitor_first_timestamp_us".into(), first.t_us.to_string());
        e.insert("monitor_stats".into(), self.stats.summary());
        if let Some(i) = self.info {
            e.insert("monitor_model_crc".into(), format!("{:#010x}", i.model_crc));
        }
        if let Some(why) = ended {
            e.insert("monitor_ended".into(), why);
        }
        Some(t)
    }
}

/// Longest gap the recorder fills (holding the last values), in seconds of frames; a longer
/// one (a device reset, a cable out for a while) ends the recording.
pub const MAX_FILL_S: u64 = 1;

/// How often the recorder hands its rows to the operating system.
pub const FLUSH_EVERY: Duration = Duration::from_secs(1);

/// Samples frames buffered while the frame rate is not known yet (no info reply).
const RATE_PROBE: usize = 4;

/// Writes the samples stream as a training recording (docs/data-format.md): one row per frame,
/// the model's input per channel in its unit (mN for the hand profile, 1/16 ADC counts for
/// suction: the samples frame's `value`), and the phase column from the frames' phase marks
/// (grasp start, lift, release). Rows go to the file as they arrive, flushed at least every
/// [`FLUSH_EVERY`]; [`Recorder::finish`] rewrites the file with the marks and the session's
/// summary in its metadata.
///
/// Bad input is repaired or refused, never trusted: a gap of lost frames (from the frame
/// timestamps) of at most [`MAX_FILL_S`] is filled with the last values and listed under
/// `monitor_gaps`; a longer gap, a timestamp going back, a change of channel count or unit, or
/// [`MAX_STEPS`] rows end the recording (`monitor_ended`); marks out of order are repaired or
/// ignored. Each event adds a line to [`Recorder::notes`] naming the frame and the step.
#[derive(Debug)]
pub struct Recorder {
    path: PathBuf,
    id: String,
    file: Option<Appender>,
    pending: Vec<(u16, u64, Samples)>,
    rate_mhz: Option<Millihertz>,
    first_index: u64,
    first_t_us: u64,
    channels: usize,
    unit: u8,
    values: Vec<Vec<f32>>,
    phase: Phase,
    marks: PhaseMarks,
    gaps: Vec<(usize, u64)>,
    /// What was repaired or refused, one line each, in order.
    pub notes: Vec<String>,
    /// Why the recording stopped taking frames, if it did.
    pub ended: Option<String>,
    /// The first write error, if any (the recording stops there).
    pub error: Option<String>,
    last_flush: Instant,
}

impl Recorder {
    /// A recorder writing to `path` (created at the first samples frame whose rate is known).
    pub fn new(path: &Path) -> Self {
        let id = path
            .file_stem()
            .map_or("monitor".to_string(), |s| s.to_string_lossy().into_owned());
        Self {
            path: path.to_path_buf(),
            id,
            file: None,
            pending: Vec::new(),
            rate_mhz: None,
            first_index: 0,
            first_t_us: 0,
            channels: 0,
            unit: 0,
            values: Vec::new(),
            phase: Phase::Pre,
            marks: PhaseMarks::default(),
            gaps: Vec::new(),
            notes: Vec::new(),
            ended: None,
            error: None,
            last_flush: Instant::now(),
        }
    }

    /// Rows recorded so far.
    pub fn steps(&self) -> usize {
        self.values.first().map_or(0, Vec::len)
    }

    /// The frame rate used, mHz.
    pub fn rate_mhz(&self) -> Option<Millihertz> {
        self.rate_mhz
    }

    fn end(&mut self, why: String) {
        if self.ended.is_none() {
            self.notes.push(why.clone());
            self.ended = Some(why);
        }
    }

    /// Takes one samples frame (`t_us` unwrapped past 2^32, `info` the device's last info
    /// reply, if any).
    pub fn push(&mut self, seq: u16, t_us: u64, s: &Samples, info: Option<&Info>) {
        if self.ended.is_some() || self.error.is_some() {
            return;
        }
        if self.rate_mhz.is_none() {
            match info.map(|i| i.sample_rate_mhz) {
                Some(r) if rate_ok(r) => self.rate_mhz = Some(r),
                Some(r) if self.pending.is_empty() => self.notes.push(format!(
                    "info reply's rate {} mHz is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz: \
                     ignored, the rate comes from the frame timestamps",
                    r.0
                )),
                _ => {}
            }
        }
        if self.rate_mhz.is_none() {
            self.pending.push((seq, t_us, *s));
            if self.pending.len() < RATE_PROBE {
                return;
            }
            // The shortest spacing of the first frames (a lost frame only lengthens one).
            let dt = self
                .pending
                .windows(2)
                .filter_map(|w| w[1].1.checked_sub(w[0].1).filter(|&d| d > 0))
                .min();
            let r = dt.map(|d| ((1e9 / d as f64) / 10.0).round() as u32 * 10);
            match r.filter(|&r| rate_ok(Millihertz(r))) {
                Some(r) => self.rate_mhz = Some(Millihertz(r)),
                None => {
                    let (seq, t, _) = self.pending[RATE_PROBE - 1];
                    self.pending.clear();
                    self.end(format!(
                        "samples frame seq {seq} (t = {:.6} s): the first {RATE_PROBE} frames' \
                         timestamps give no frame rate in {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz and no \
                         info reply gave one: nothing recorded (send info, `i`)",
                        t as f64 / 1e6
                    ));
                    return;
                }
            }
            for (seq, t, s) in std::mem::take(&mut self.pending) {
                self.take(seq, t, &s);
            }
            return;
        }
        self.take(seq, t_us, s);
    }

    fn take(&mut self, seq: u16, t_us: u64, s: &Samples) {
        if self.ended.is_some() || self.error.is_some() {
            return;
        }
        let rate = self.rate_mhz.expect("rate known");
        let index = frame_index(t_us, rate);
        let n = (s.channels as usize).min(MAX_CHANNELS);
        let at = |step: usize| {
            format!(
                "samples frame seq {seq} (t = {:.6} s, step {step})",
                t_us as f64 / 1e6
            )
        };
        if self.file.is_none()
            && let Err(e) = self.open(t_us, index, n, s.unit)
        {
            self.error = Some(e);
            return;
        }
        let next = self.steps();
        if n != self.channels {
            return self.end(format!(
                "{}: {n} channels, the recording has {}: recording ended (one recording holds \
                 one channel count; the model takes the profile's)",
                at(next),
                self.channels
            ));
        }
        if s.unit != self.unit {
            return self.end(format!(
                "{}: unit code {} after {}: recording ended",
                at(next),
                s.unit,
                self.unit
            ));
        }
        let Some(k) = index.checked_sub(self.first_index) else {
            return self.end(format!(
                "{}: timestamp before the recording's first frame (device reset?): recording \
                 ended",
                at(next)
            ));
        };
        if k < next as u64 {
            self.notes.push(format!(
                "{}: frame index {k} already recorded (repeated or out of order): dropped",
                at(next)
            ));
            return;
        }
        let gap = k - next as u64;
        let max_fill = (rate.0 as u64 / 1000).max(1) * MAX_FILL_S;
        if gap > max_fill {
            return self.end(format!(
                "{}: the timestamp jumps {gap} frames ({:.3} s) past the last recorded step: \
                 more than {MAX_FILL_S} s lost or a device reset; recording ended at step {next}",
                at(next),
                gap as f64 * 1000.0 / rate.0 as f64
            ));
        }
        if next + gap as usize >= MAX_STEPS {
            return self.end(format!(
                "{}: {MAX_STEPS} steps, the recording format's maximum: recording ended",
                at(next)
            ));
        }
        if gap > 0 {
            self.notes.push(format!(
                "{}: {gap} frame(s) lost before it: steps {next}..{} hold the last values \
                 (listed under monitor_gaps)",
                at(next + gap as usize),
                next + gap as usize
            ));
            self.gaps.push((next, gap));
            let last: Vec<f32> = self
                .values
                .iter()
                .map(|c| c.last().copied().unwrap_or(0.0))
                .collect();
            for _ in 0..gap {
                if !self.row(&last) {
                    return;
                }
            }
        }
        let step = self.steps();
        self.apply_marks(s.marks, &at(step), step);
        let v: Vec<f32> = s.value[..n].iter().map(|&x| x as f32).collect();
        self.row(&v);
        self.flush_if_due();
    }

    fn open(&mut self, t_us: u64, index: u64, n: usize, unit: u8) -> Result<(), String> {
        self.first_index = index;
        self.first_t_us = t_us;
        self.channels = n;
        self.unit = unit;
        self.values = vec![Vec::new(); n];
        let meta = self.meta(vec![Vec::new(); n]);
        let f = Appender::create(&self.path, &meta).map_err(|e| e.to_string())?;
        self.file = Some(f);
        Ok(())
    }

    fn meta(&self, samples: Vec<Vec<f32>>) -> Trial {
        let rate = self.rate_mhz.unwrap_or(PAPER_RATE_MHZ);
        let unit = if self.unit == 0 {
            Unit::MilliNewton
        } else {
            Unit::Counts
        };
        let mut t = Trial::new(&self.id, unit, rate.hz_f32(), samples);
        t.source = "slipguard monitor (samples stream)".into();
        t.extra.insert(
            "monitor_first_frame_index".into(),
            self.first_index.to_string(),
        );
        t.extra.insert(
            "monitor_first_timestamp_us".into(),
            self.first_t_us.to_string(),
        );
        t.extra
            .insert("monitor_unit_code".into(), self.unit.to_string());
        t
    }

    fn apply_marks(&mut self, bits: u8, at: &str, step: usize) {
        if bits & mark::GRASP_START != 0 {
            if self.phase == Phase::Pre {
                self.phase = Phase::Grasp;
                self.marks.grasp_start = Some(step);
            } else {
                self.notes.push(format!(
                    "{at}: grasp start after the first one: ignored (one grasp per recording)"
                ));
            }
        }
        if bits & mark::LIFT != 0 {
            match self.phase {
                Phase::Pre => {
                    self.notes.push(format!(
                        "{at}: lift before any grasp start: grasp_start set to the lift's step"
                    ));
                    self.marks.grasp_start = Some(step);
                    self.marks.lift_start = Some(step);
                    self.phase = Phase::Lift;
                }
                Phase::Grasp => {
                    self.marks.lift_start = Some(step);
                    self.phase = Phase::Lift;
                }
                _ => self
                    .notes
                    .push(format!("{at}: lift after the lift or the release: ignored")),
            }
        }
        if bits & mark::RELEASE != 0 {
            match self.phase {
                Phase::Pre => self
                    .notes
                    .push(format!("{at}: release before any grasp start: ignored")),
                Phase::Release => self.notes.push(format!("{at}: a second release: ignored")),
                _ => {
                    self.marks.release = Some(step);
                    self.phase = Phase::Release;
                }
            }
        }
    }

    /// Appends one row (file and memory); false once writing failed.
    fn row(&mut self, v: &[f32]) -> bool {
        let Some(f) = &mut self.file else {
            return false;
        };
        if let Err(e) = f.push(v, self.phase) {
            self.error = Some(e.to_string());
            return false;
        }
        for (c, x) in self.values.iter_mut().zip(v) {
            c.push(*x);
        }
        true
    }

    /// Flushes the rows when [`FLUSH_EVERY`] has passed since the last flush.
    pub fn flush_if_due(&mut self) {
        if self.last_flush.elapsed() >= FLUSH_EVERY {
            self.flush();
        }
    }

    /// Hands the rows to the operating system now.
    pub fn flush(&mut self) {
        self.last_flush = Instant::now();
        if let Some(f) = &mut self.file
            && let Err(e) = f.flush()
            && self.error.is_none()
        {
            self.error = Some(e.to_string());
        }
    }

    /// The recording as a trial (marks and the session's summary in its metadata), if any row
    /// was recorded.
    pub fn to_trial(&self, stats: &Stats, info: Option<&Info>) -> Option<Trial> {
        if self.steps() == 0 {
            return None;
        }
        let mut t = self.meta(self.values.clone());
        t.marks = self.marks;
        let e = &mut t.extra;
        e.insert("monitor_stats".into(), stats.summary());
        if let Some(i) = info {
            e.insert("monitor_model_crc".into(), format!("{:#010x}", i.model_crc));
        }
        if !self.gaps.is_empty() {
            let g: Vec<String> = self.gaps.iter().map(|(s, n)| format!("{s}+{n}")).collect();
            e.insert("monitor_gaps".into(), g.join(" "));
        }
        if let Some(why) = &self.ended {
            e.insert("monitor_ended".into(), why.clone());
        }
        Some(t)
    }

    /// Finishes the file: rewrites it whole (through a temporary file) with the marks and the
    /// summary. Returns the number of rows; an error if nothing was recorded or writing failed.
    pub fn finish(&mut self, stats: &Stats, info: Option<&Info>) -> Result<usize, String> {
        self.flush();
        if let Some(e) = &self.error {
            return Err(format!("writing {}: {e}", self.path.display()));
        }
        let t = self.to_trial(stats, info).ok_or_else(|| {
            format!(
                "no samples frame recorded: {} not written (send stream mode flags+samples, `s 1`)",
                self.path.display()
            )
        })?;
        self.file = None;
        recording::replace_recording(&t, &self.path).map_err(|e| e.to_string())?;
        Ok(t.n_steps())
    }
}

/// Parses a command as typed at the monitor's keyboard or given to `--send`:
/// `g`/`grasp`, `l`/`lift`, `r`/`release`, `p`/`ping`, `i`/`info`, `t 0.3`/`threshold 0.3`
/// (optionally the raise and clear counts: `t 0.3 2 2`), `s 1`/`stream flags+samples` (0
/// flags, 1 flags+samples, 2 samples).
pub fn parse_command(line: &str) -> Result<Command, String> {
    let mut w = line.split_whitespace();
    let head = w.next().unwrap_or("");
    let args: Vec<&str> = w.collect();
    let none = |c: Command| {
        if args.is_empty() {
            Ok(c)
        } else {
            Err(format!("`{head}` takes no argument"))
        }
    };
    match head {
        "g" | "grasp" | "grasp-start" => none(Command::GraspStart),
        "l" | "lift" => none(Command::Lift),
        "r" | "release" => none(Command::Release),
        "p" | "ping" => none(Command::Ping { token: 0x5149_4E47 }),
        "i" | "info" => none(Command::Info),
        "t" | "threshold" => {
            let num = |i: usize, d: u8| -> Result<u8, String> {
                args.get(i).map_or(Ok(d), |a| {
                    a.parse::<u8>()
                        .ok()
                        .filter(|&v| v >= 1)
                        .ok_or(format!("`{a}`: frames must be 1..=255"))
                })
            };
            let p: f64 = args
                .first()
                .and_then(|a| a.parse().ok())
                .filter(|p: &f64| *p > 0.0 && *p < 1.0)
                .ok_or("threshold needs p(unstable) in (0, 1), e.g. `t 0.3`")?;
            if args.len() > 3 {
                return Err("threshold takes p and at most two counts: `t 0.3 2 2`".into());
            }
            let q = slipguard_core::decision::Q15::from_f64(p).0.max(1) as u16;
            Ok(Command::SetThreshold {
                threshold_q15: q,
                raise_after: num(1, 1)?,
                clear_after: num(2, 1)?,
            })
        }
        "s" | "stream" | "stream-mode" => {
            let m = match args[..] {
                ["0" | "flags"] => StreamMode::Flags,
                ["1" | "flags+samples"] => StreamMode::FlagsAndSamples,
                ["2" | "samples"] => StreamMode::Samples,
                _ => {
                    return Err("stream mode is 0 (flags), 1 (flags+samples) or 2 (samples)".into());
                }
            };
            Ok(Command::StreamMode(m))
        }
        _ => Err(format!(
            "unknown command `{line}`: g grasp start, l lift, r release, t P threshold, \
             s 0|1|2 stream mode, p ping, i info"
        )),
    }
}
