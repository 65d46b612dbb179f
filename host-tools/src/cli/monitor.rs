//! `slipguard monitor`: watch the flag stream from a serial port or a capture file.

use std::io::{IsTerminal, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Parser, ValueEnum};
use slipguard::monitor::{Event, Monitor};
use slipguard_core::protocol::{
    self, Command, Frame, MAX_WIRE, Message, ReplyBody, ReplyStatus, StreamMode,
};
use slipguard_data::recording::write_recording;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum View {
    /// A table redrawn in place when stdout is a terminal, else nothing until the summary.
    Auto,
    /// The table, redrawn in place.
    Table,
    /// One line per event (frame, corrupt run, gap).
    Lines,
    /// Only the final summary.
    None,
}

#[derive(Debug, Parser)]
pub struct Args {
    /// Serial port (e.g. /dev/ttyUSB0) the firmware's USART1 is connected to.
    #[arg(long, conflicts_with = "capture", required_unless_present = "capture")]
    pub port: Option<String>,
    /// Baud rate (8N1, no flow control).
    #[arg(long, default_value_t = 921_600, value_parser = clap::value_parser!(u32).range(1..))]
    pub baud: u32,
    /// Read a capture file (raw bytes as received) instead of a port.
    #[arg(long)]
    pub capture: Option<PathBuf>,
    /// Write the flag frames as a recording (docs/data-format.md), rewritten every 10 s and at
    /// the end.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Stop after this many flag frames.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub frames: Option<u64>,
    /// Stop after this many seconds (port only).
    #[arg(long, value_parser = super::check::positive)]
    pub seconds: Option<f64>,
    /// Port only: send an info command first (learns the frame rate and the model).
    #[arg(long)]
    pub info: bool,
    /// Port only: send grasp start first (resets the channels and arms flagging).
    #[arg(long)]
    pub grasp_start: bool,
    /// How to show the stream.
    #[arg(long, value_enum, default_value_t = View::Auto)]
    pub view: View,
}

fn send(port: &mut dyn Write, seq: u16, cmd: Command) -> anyhow::Result<()> {
    let mut buf = [0u8; MAX_WIRE];
    let n = protocol::encode(
        &Frame {
            seq,
            msg: Message::Command(cmd),
        },
        &mut buf,
    );
    port.write_all(&buf[..n])?;
    port.flush()?;
    Ok(())
}

fn describe(ev: &Event) -> String {
    match ev {
        Event::Frame { frame, lost } => {
            let gap = if *lost > 0 {
                format!(" ({lost} lost before)")
            } else {
                String::new()
            };
            format!("seq {:5} {}{gap}", frame.seq, message_line(&frame.msg))
        }
        Event::Corrupt(e) => format!("corrupt run: {e} (resynchronised at the next delimiter)"),
    }
}

fn stream_name(m: StreamMode) -> &'static str {
    match m {
        StreamMode::Flags => "flags",
        StreamMode::FlagsAndSamples => "flags and samples",
        StreamMode::Samples => "samples",
    }
}

fn command_line(c: &Command) -> String {
    match *c {
        Command::Ping { token } => format!("ping token={token}"),
        Command::GraspStart => "grasp start".into(),
        Command::Release => "release".into(),
        Command::SetThreshold {
            threshold_q15,
            raise_after,
            clear_after,
        } => format!(
            "set threshold p>={:.3} raise_after={raise_after} clear_after={clear_after}",
            threshold_q15 as f64 / 32768.0
        ),
        Command::Info => "info".into(),
        Command::Lift => "lift".into(),
        Command::StreamMode(m) => format!("stream mode {}", stream_name(m)),
        Command::UploadBegin { size, crc } => format!("upload begin size={size} crc={crc:#010x}"),
        Command::UploadChunk(ch) => format!("upload chunk offset={} len={}", ch.offset, ch.len),
        Command::UploadCommit => "upload commit".into(),
    }
}

/// One readable line per message (names and numbers, no Rust debug output).
fn message_line(m: &Message) -> String {
    let t = |us: u32| us as f64 / 1e6;
    match m {
        Message::Flags(f) => format!(
            "flags t={:.3}s unstable={:#06x} fault={:#06x}",
            t(f.timestamp_us),
            f.unstable,
            f.fault
        ),
        Message::Samples(s) => format!(
            "samples t={:.3}s channels={} fault={:#06x}",
            t(s.timestamp_us),
            s.channels,
            s.fault
        ),
        Message::Fault(f) => format!(
            "system fault t={:.3}s code={} detail={} value={} (docs/protocol.md lists the codes)",
            t(f.timestamp_us),
            f.code,
            f.detail,
            f.value
        ),
        Message::Error(e) => format!(
            "error: the device rejected frame seq {} (type {:#04x}), error code {}",
            e.request_seq, e.msg_type, e.error
        ),
        Message::Command(c) => format!("command {}", command_line(c)),
        Message::Reply(r) => {
            let status = match r.status {
                ReplyStatus::Ok => "ok",
                ReplyStatus::BadArgument => "bad argument",
                ReplyStatus::NoModel => "no model",
            };
            let body = match r.body {
                ReplyBody::Pong { token } => format!("pong token={token}"),
                ReplyBody::GraspStarted => "grasp started".into(),
                ReplyBody::Released => "released".into(),
                ReplyBody::ThresholdSet {
                    threshold_q15,
                    raise_after,
                    clear_after,
                } => format!(
                    "threshold set p>={:.3} raise_after={raise_after} clear_after={clear_after}",
                    threshold_q15 as f64 / 32768.0
                ),
                ReplyBody::Info(i) => format!(
                    "info firmware {}.{}.{} profile {} channels={} model {} id={:#010x} crc={:#010x}",
                    i.firmware[0],
                    i.firmware[1],
                    i.firmware[2],
                    if i.profile == 1 { "suction" } else { "hand" },
                    i.channels,
                    if i.model_ok == 1 { "ok" } else { "refused" },
                    i.model_id,
                    i.model_crc
                ),
                ReplyBody::Lifted => "lifted".into(),
                ReplyBody::StreamMode(m) => format!("stream mode {}", stream_name(m)),
                ReplyBody::Upload {
                    command,
                    code,
                    detail,
                    slot,
                    value,
                } => format!(
                    "upload type={command:#04x} code={code} detail={detail} slot={slot} value={value}"
                ),
            };
            format!("reply to seq {} ({status}): {body}", r.request_seq)
        }
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut mon = Monitor::new();
    mon.keep = a.record.is_some();
    let view = match a.view {
        View::Auto if std::io::stdout().is_terminal() => View::Table,
        View::Auto => View::None,
        v => v,
    };
    let id = a
        .record
        .as_ref()
        .and_then(|p| p.file_stem())
        .map_or("monitor".to_string(), |s| s.to_string_lossy().into_owned());
    let save = |mon: &Monitor| -> anyhow::Result<()> {
        if let (Some(path), Some(t)) = (&a.record, mon.to_trial(&id)) {
            write_recording(&t, path)?;
        }
        Ok(())
    };
    let mut out = std::io::stdout().lock();
    let on_event = |ev: &Event, out: &mut dyn Write| {
        if view == View::Lines {
            let _ = writeln!(out, "{}", describe(ev));
        }
    };
    let done = |mon: &Monitor| a.frames.is_some_and(|n| mon.stats.flags >= n);

    if let Some(path) = &a.capture {
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        for chunk in bytes.chunks(64) {
            mon.push(chunk, |e| on_event(e, &mut out));
            if done(&mon) {
                break;
            }
        }
    } else {
        let name = a.port.as_deref().unwrap_or_default();
        let mut port = serialport::new(name, a.baud)
            .timeout(Duration::from_millis(50))
            .open()
            .with_context(|| format!("opening {name} at {} baud", a.baud))?;
        eprintln!("monitor: reading {name} at {} baud", a.baud);
        let mut seq = 0u16;
        if a.info {
            send(&mut port, seq, Command::Info)?;
            seq += 1;
        }
        if a.grasp_start {
            send(&mut port, seq, Command::GraspStart)?;
        }
        let start = Instant::now();
        let (mut last_draw, mut last_save) = (Instant::now(), Instant::now());
        let mut buf = [0u8; 1024];
        loop {
            match port.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => mon.push(&buf[..n], |e| on_event(e, &mut out)),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                // A pseudo terminal whose other end closed reports EIO: the end of the stream.
                Err(e) if e.raw_os_error() == Some(5) => break,
                Err(e) => return Err(e).context(format!("reading {name}")),
            }
            if done(&mon)
                || a.seconds
                    .is_some_and(|s| start.elapsed().as_secs_f64() >= s)
            {
                break;
            }
            if view == View::Table && last_draw.elapsed() >= Duration::from_millis(200) {
                last_draw = Instant::now();
                let _ = write!(out, "\x1b[H\x1b[2J{}", mon.view());
                let _ = out.flush();
            }
            if last_save.elapsed() >= Duration::from_secs(10) {
                last_save = Instant::now();
                save(&mon)?;
            }
        }
    }
    if view == View::Table {
        let _ = write!(out, "\x1b[H\x1b[2J");
    }
    if view == View::Table {
        let _ = write!(out, "{}", mon.view());
    } else {
        // Lines and none: the counts once, after the stream.
        let _ = writeln!(out, "summary: {}", mon.stats.summary());
    }
    save(&mon)?;
    if let Some(p) = &a.record {
        if mon.received.is_empty() {
            bail!("no flag frame received: {} not written", p.display());
        }
        let _ = writeln!(out, "recording: {}", p.display());
    }
    Ok(())
}
