//! `slipguard monitor`: watch the flag stream from a serial port or a capture file.

use std::io::{IsTerminal, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Parser, ValueEnum};
use slipguard::monitor::{Event, Monitor};
use slipguard_core::protocol::{self, Command, Frame, MAX_WIRE, Message};
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
    /// Write the flag frames as a recording (docs/data-format.md), rewritten every 10 s and at
    /// the end.
    #[arg(long)]
    pub record: Option<PathBuf>,
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
    let _ = write!(out, "{}", mon.view());
    save(&mon)?;
    if let Some(p) = &a.record {
        if mon.received.is_empty() {
            bail!("no flag frame received: {} not written", p.display());
        }
        let _ = writeln!(out, "recording: {}", p.display());
    }
    Ok(())
}
