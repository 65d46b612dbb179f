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
use slipguard_core::protocol::{self, Command, Frame, MAX_WIRE, Message, StreamMode};
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
    #[arg(long, default_value_t = 921_600)]
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
    /// Stop after this many flag frames.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Stop after this many seconds (port only).
    #[arg(long)]
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
            match frame.msg {
                Message::Flags(f) => format!(
                    "seq {:5} flags t={:.3}s unstable={:#06x} fault={:#06x}{gap}",
                    frame.seq,
                    f.timestamp_us as f64 / 1e6,
                    f.unstable,
                    f.fault
                ),
                m => format!("seq {:5} {m:?}{gap}", frame.seq),
            }
        }
        Event::Corrupt(e) => format!("corrupt run: {e} (resynchronised at the next delimiter)"),
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.capture.is_some() && (a.stream_mode.is_some() || !a.send.is_empty()) {
        bail!("--stream-mode and --send need --port (a capture cannot be sent commands)");
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
    if view == View::Table {
        let _ = write!(out, "\x1b[H\x1b[2J");
    }
    let _ = write!(out, "{}", mon.view());
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
