//! `slipguard monitor`: watch the flag stream from a serial port or a capture file, record the
//! samples stream, send commands from the keyboard or options.

use std::io::{BufRead, IsTerminal, Read, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Parser, ValueEnum};
use slipguard::monitor::{Event, FLUSH_EVERY, Monitor, Recorder, parse_command};
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
    /// Baud rate, bit/s (≥ 1; 8N1, no flow control).
    #[arg(long, default_value_t = 921_600, value_parser = clap::value_parser!(u32).range(1..), allow_negative_numbers = true)]
    pub baud: u32,
    /// Read a capture file (raw bytes as received) instead of a port.
    #[arg(long)]
    pub capture: Option<PathBuf>,
    /// Record the samples stream (the model's input per channel and the phase marks grasp
    /// start, lift, release) as a training recording (docs/data-format.md), flushed every second
    /// and finished with its summary at the end or on Ctrl-C. Without samples frames, the flag
    /// frames are written instead (p(unstable) per channel). With --port, stream mode
    /// flags+samples is sent unless --stream-mode says otherwise.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Keep every received byte in this file (a capture `--capture` reads back).
    #[arg(long)]
    pub save_raw: Option<PathBuf>,
    /// Port only: send stream mode first: flags, flags+samples or samples.
    #[arg(long, value_parser = parse_stream_mode)]
    pub stream_mode: Option<StreamMode>,
    /// Port only: send a command at the start (repeatable, in order): grasp, lift, release,
    /// ping, info, `threshold 0.3`, `stream 1` (the keyboard's commands, see below).
    #[arg(long, value_parser = parse_command)]
    pub send: Vec<Command>,
    /// Port only: do not read commands from standard input. By default each line typed is a
    /// command: g grasp start, l lift, r release, t 0.3 threshold, s 0|1|2 stream mode, p ping,
    /// i info.
    #[arg(long)]
    pub no_keys: bool,
    /// Stop after this many flag frames (count ≥ 1).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..), allow_negative_numbers = true)]
    pub frames: Option<u64>,
    /// Stop after this many seconds (s > 0; port only).
    #[arg(long, value_parser = super::check::positive, allow_negative_numbers = true)]
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

fn parse_stream_mode(s: &str) -> Result<StreamMode, String> {
    match parse_command(&format!("s {s}"))? {
        Command::StreamMode(m) => Ok(m),
        _ => unreachable!("`s` parses to a stream mode"),
    }
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
                    slipguard_app::profile::ProfileId::from_u8(i.profile)
                        .map_or("unknown", |p| p.name()),
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

/// Checks before any byte is read that an output file can be written at `path`: its folder
/// exists and the path is not a folder. Creates the file to prove it (the recorder writes it
/// from the first samples frame on), and removes it again if it did not exist, so that a
/// session that records nothing leaves nothing behind.
pub fn check_output_file(option: &str, path: &std::path::Path) -> anyhow::Result<()> {
    if path.is_dir() {
        bail!("{option} {}: is a folder; give a file name", path.display());
    }
    let folder = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !folder.is_dir() {
        bail!(
            "{option} {}: the folder {} does not exist; create it first (mkdir -p {})",
            path.display(),
            folder.display(),
            folder.display()
        );
    }
    let existed = path.exists();
    std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .with_context(|| format!("{option} {}: cannot be written", path.display()))?;
    if !existed {
        let _ = std::fs::remove_file(path);
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.capture.is_some() && (a.stream_mode.is_some() || !a.send.is_empty()) {
        bail!("--stream-mode and --send need --port (a capture cannot be sent commands)");
    }
    if let Some(p) = &a.record {
        check_output_file("--record", p)?;
    }
    if let Some(p) = &a.save_raw {
        check_output_file("--save-raw", p)?;
    }
    let mut mon = Monitor::new();
    mon.keep = a.record.is_some();
    mon.recorder = a.record.as_deref().map(Recorder::new);
    let view = match a.view {
        View::Auto if std::io::stdout().is_terminal() => View::Table,
        View::Auto => View::None,
        v => v,
    };
    let mut raw = match &a.save_raw {
        Some(p) => Some(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?,
        )),
        None => None,
    };
    let mut out = std::io::stdout().lock();
    let on_event = |ev: &Event, out: &mut dyn Write| {
        if view == View::Lines {
            let _ = writeln!(out, "{}", describe(ev));
        }
    };
    let done = |mon: &Monitor| a.frames.is_some_and(|n| mon.stats.flags >= n);
    // Ctrl-C ends the session; the recording is finished below.
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let mut read_error = None;

    if let Some(path) = &a.capture {
        // Read in pieces: a capture of any length takes constant memory.
        let mut f =
            std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
        let mut buf = [0u8; 4096];
        'read: loop {
            let n = f
                .read(&mut buf)
                .with_context(|| format!("reading {}", path.display()))?;
            if n == 0 {
                break;
            }
            if let Some(r) = &mut raw {
                r.write_all(&buf[..n])?;
            }
            // 64 bytes at a time: `--frames` stops close to the frame it counts.
            for chunk in buf[..n].chunks(64) {
                mon.push(chunk, |e| on_event(e, &mut out));
                if done(&mon) || stop.load(Ordering::SeqCst) {
                    break 'read;
                }
            }
        }
    } else {
        let name = a.port.as_deref().unwrap_or_default();
        let mut port = serialport::new(name, a.baud)
            .timeout(Duration::from_millis(50))
            .open()
            .with_context(|| format!("opening {name} at {} baud", a.baud))?;
        eprintln!("monitor: reading {name} at {} baud", a.baud);
        let mut start_cmds = Vec::new();
        if a.info || a.record.is_some() {
            start_cmds.push(Command::Info);
        }
        match a.stream_mode {
            Some(m) => start_cmds.push(Command::StreamMode(m)),
            None if a.record.is_some() => {
                eprintln!("monitor: recording: sending stream mode flags+samples");
                start_cmds.push(Command::StreamMode(StreamMode::FlagsAndSamples));
            }
            None => {}
        }
        if a.grasp_start {
            start_cmds.push(Command::GraspStart);
        }
        start_cmds.extend(a.send.iter().copied());
        let mut seq = 0u16;
        for c in start_cmds {
            send(&mut port, seq, c)?;
            seq = seq.wrapping_add(1);
        }
        // Keyboard commands: one per line, parsed on a reader thread.
        let (tx, rx) = std::sync::mpsc::channel::<String>();
        if !a.no_keys {
            eprintln!(
                "monitor: commands: g grasp start, l lift, r release, t 0.3 threshold, \
                 s 0|1|2 stream mode, p ping, i info (Enter after each; Ctrl-C ends)"
            );
            std::thread::spawn(move || {
                for line in std::io::stdin().lock().lines() {
                    let Ok(line) = line else { break };
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
        }
        let start = Instant::now();
        let (mut last_draw, mut last_flush) = (Instant::now(), Instant::now());
        let mut buf = [0u8; 1024];
        loop {
            match port.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    if let Some(r) = &mut raw {
                        r.write_all(&buf[..n])?;
                    }
                    mon.push(&buf[..n], |e| on_event(e, &mut out))
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                // A pseudo terminal whose other end closed reports EIO: the end of the stream.
                Err(e) if e.raw_os_error() == Some(5) => break,
                Err(e) => {
                    // A pulled cable: finish the recording, then report.
                    read_error = Some(anyhow::Error::new(e).context(format!("reading {name}")));
                    break;
                }
            }
            while let Ok(line) = rx.try_recv() {
                if line.trim().is_empty() {
                    continue;
                }
                match parse_command(&line) {
                    Ok(c) => {
                        send(&mut port, seq, c)?;
                        seq = seq.wrapping_add(1);
                        eprintln!("monitor: sent {c:?}");
                    }
                    Err(e) => eprintln!("monitor: {e}"),
                }
            }
            if done(&mon)
                || stop.load(Ordering::SeqCst)
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
            if last_flush.elapsed() >= FLUSH_EVERY {
                last_flush = Instant::now();
                if let Some(r) = &mut mon.recorder {
                    r.flush();
                }
                if let Some(r) = &mut raw {
                    r.flush()?;
                }
            }
        }
    }
    if let Some(r) = &mut raw {
        r.flush()?;
    }
    // A port that sent nothing at all: the session shows no stream, so it is an error that
    // says what to check, not a summary with bytes=0.
    if let Some(name) = &a.port
        && mon.stats.bytes == 0
        && read_error.is_none()
    {
        bail!(
            "no byte received from {name} at {} baud{}: check that the board is powered and runs \
             the slipguard firmware, the wiring (board TX to the adapter's RX, common ground), \
             the port name, and that the baud rate matches the firmware's (921600 by default)",
            a.baud,
            if a.info {
                "; the info command got no reply"
            } else {
                ""
            }
        );
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
    if let Some(path) = &a.record {
        let stats = mon.stats.clone();
        let info = mon.info;
        let rec = mon.recorder.as_mut().expect("recorder with --record");
        for n in &rec.notes {
            eprintln!("monitor: {}: {n}", path.display());
        }
        if rec.steps() > 0 || rec.error.is_some() {
            let rows = rec
                .finish(&stats, info.as_ref())
                .map_err(anyhow::Error::msg)?;
            let _ = writeln!(
                out,
                "recording: {} ({rows} steps of samples)",
                path.display()
            );
        } else if let Some(t) = mon.to_trial(&rec_id(path)) {
            write_recording(&t, path)?;
            let _ = writeln!(
                out,
                "recording: {} ({} flag frames; no samples frame: send stream mode flags+samples \
                 to record the sensor values)",
                path.display(),
                t.n_steps()
            );
        } else {
            bail!(
                "no samples or flag frame received: {} not written",
                path.display()
            );
        }
    }
    match read_error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

fn rec_id(path: &std::path::Path) -> String {
    path.file_stem()
        .map_or("monitor".to_string(), |s| s.to_string_lossy().into_owned())
}
