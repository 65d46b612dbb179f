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
//!   (docs/data-format.md; the columns are described on [`Monitor::to_trial`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use slipguard_core::decision::Q15;
use slipguard_core::protocol::{
    DecodeError, Deframer, Fault, Flags, Frame, Info, MAX_CHANNELS, Message, P_NONE, ReplyBody,
    status,
};

use slipguard_data::trial::{Outcome, SensorKind, Stability, Trial, Unit};

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
#[derive(Clone, Debug, Default)]
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
                if self.keep {
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
            Message::Samples(_) | Message::Command(_) => {}
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
    pub fn rate_mhz(&self) -> Option<u32> {
        if let Some(i) = self.info
            && i.sample_rate_mhz > 0
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
        Some(((1e9 / period_us) / 10.0).round() as u32 * 10)
    }

    /// The live view: one line per channel (state, p(unstable), bar) and the counters.
    pub fn view(&self) -> String {
        let mut s = String::new();
        match &self.last_flags {
            None => s.push_str("no flag frame yet\n"),
            Some(f) => {
                let _ = writeln!(
                    s,
                    "t = {:.3} s  {}{}{}  overruns {}  skipped {}",
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
                    f.overruns,
                    f.skipped
                );
                for c in 0..(f.channels as usize).min(MAX_CHANNELS) {
                    let bit = 1u16 << c;
                    let (state, p) = if f.fault & bit != 0 {
                        ("FAULT   ", None)
                    } else if f.unstable & bit != 0 {
                        ("UNSTABLE", Some(f.p[c]))
                    } else {
                        ("stable  ", Some(f.p[c]))
                    };
                    let p = p.filter(|&p| p != P_NONE);
                    let bar = p.map_or(String::new(), |p| {
                        "#".repeat(((p as u32 * 20 + 16384) / 32768) as usize)
                    });
                    let pv = p.map_or("   -  ".to_string(), |p| {
                        format!("{:.3} ", Q15(p as i16).to_f64())
                    });
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
        let rate_mhz = self.rate_mhz().unwrap_or(16_700);
        let n = self
            .received
            .iter()
            .map(|r| r.flags.channels as usize)
            .max()
            .unwrap_or(1)
            .min(MAX_CHANNELS);
        // Frame index from the sample clock: t = (index + 1) · 10⁹ / rate_mHz.
        let index =
            |t_us: u64| ((t_us as f64 * rate_mhz as f64 / 1e9).round() as i64 - 1).max(0) as u64;
        let i0 = index(first.t_us);
        let mut rows: BTreeMap<u64, &Flags> = BTreeMap::new();
        for r in &self.received {
            let i = index(r.t_us);
            if i >= i0 {
                rows.insert(i - i0, &r.flags);
            }
        }
        let len = rows.keys().next_back().map_or(0, |&k| k as usize + 1);
        let mut samples = vec![vec![-1.0f32; len]; n + 3];
        let mut labels = vec![None; len];
        samples[n + 2].fill(1.0);
        for (&k, f) in &rows {
            let k = k as usize;
            for (c, ch) in samples.iter_mut().enumerate().take(n) {
                let p = f.p[c];
                ch[k] = if p == P_NONE || c >= f.channels as usize {
                    -1.0
                } else {
                    Q15(p as i16).to_f64() as f32
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
            rate_mhz as f32 / 1000.0,
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
        Some(t)
    }
}
