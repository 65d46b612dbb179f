//! `slipguard replay`: a trial through the firmware's exact path; the frames it would send.

use slipguard_core::units::Millihertz;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Parser, ValueEnum};
use slipguard::replay::{self, Scheduled};

use super::check;
use slipguard_app::profile::ProfileId;
use slipguard_app::replay::OpenWire;
use slipguard_core::protocol::{Command, Message};
use slipguard_core::sample::{PAPER_RATE_HZ, PAPER_RATE_MHZ};
use slipguard_data::eagle::read_tactile_csv;
use slipguard_data::labels::{LabelConfig, annotate};
use slipguard_data::trial::{Outcome, PhaseMarks, SensorKind, Trial, Unit};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Script {
    /// No commands: the firmware boots armed and flags from the first frame.
    None,
    /// Grasp start, lift and release at `--grasp-at`, `--lift-at`, `--release-at` (default: the
    /// trial's grasp and release marks, and with --samples its lift mark).
    Marks,
    /// The QEMU comparison's scenario for Cheez_100_814_top_3 (ping, info, line noise, bad CRC,
    /// unknown type, threshold 0.6, grasp start at 52, release at 300, channel 14 open 150–169).
    Cheez,
}

#[derive(Debug, Parser)]
pub struct Args {
    /// The trial: a recording (.csv, docs/data-format.md), an eagle-shoal trial folder, or a plain
    /// `tactile.csv` (header c0…c15, one row per step; marks from a sibling `<name>.meta.json`).
    /// A folder of recordings (or the eagle-shoal root) replays each trial: `--out` and `--png`
    /// are then folders (`<id>.bin`, `<id>.png`).
    pub trial: PathBuf,
    /// Model blob (default: the shipped model for the trial's rate and sensor, e.g.
    /// models/hand-force/*.bin at 16.7 Hz, models/hand-force-40hz/*.bin at 40 Hz,
    /// models/suction/*.bin; else the golden untrained blob).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Sensor profile (default: the one profile that takes the trial's unit, rate and channel
    /// count; hand: 16 force channels in mN at 16.7 or 40 Hz, suction: 4 pressure channels in
    /// counts at 71 Hz).
    #[arg(long, value_parser = check::profile_id())]
    pub profile: Option<ProfileId>,
    /// Rate of a plain tactile.csv, Hz (> 0).
    #[arg(long, default_value_t = PAPER_RATE_HZ, allow_negative_numbers = true, value_parser = check::positive_f32)]
    pub rate: f32,
    /// Commands sent to the firmware during the replay.
    #[arg(long, value_enum, default_value_t = Script::None)]
    pub script: Script,
    /// With `--script marks`: grasp start before this frame.
    #[arg(long, allow_negative_numbers = true)]
    pub grasp_at: Option<u32>,
    /// With `--script marks`: release before this frame.
    #[arg(long, allow_negative_numbers = true)]
    pub release_at: Option<u32>,
    /// With `--script marks`: lift before this frame (default with --samples: the trial's lift
    /// mark).
    #[arg(long, allow_negative_numbers = true)]
    pub lift_at: Option<u32>,
    /// Send stream mode flags+samples before the first frame (and info), so the frames carry
    /// the samples stream a `slipguard monitor --capture F --record R` records.
    #[arg(long)]
    pub samples: bool,
    /// Disconnect a channel: CHANNEL:FROM:TO (trial steps, TO exclusive); repeatable.
    #[arg(long, value_parser = parse_open_wire)]
    pub open_wire: Vec<OpenWire>,
    /// Write the frames to this file (`-` = stdout).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Send the frames to a serial port, paced at the frame rate (the firmware's timing).
    #[arg(long)]
    pub port: Option<String>,
    /// Baud rate of `--port`.
    #[arg(long, default_value_t = 921_600, allow_negative_numbers = true, value_parser = clap::value_parser!(u32).range(1..))]
    pub baud: u32,
    /// A Fig. 8-style plot (PNG).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Plot one channel's prediction instead of "any channel".
    #[arg(long, allow_negative_numbers = true)]
    pub plot_channel: Option<usize>,
    /// Allow a model whose rate differs from the trial's.
    #[arg(long)]
    pub any_rate: bool,
    /// Replay a blob the firmware would refuse (does not parse, over the build's bounds, rate or
    /// unit not the profile's) after a warning, instead of stopping: the frames are fault frames.
    #[arg(long)]
    pub allow_bad_model: bool,
}

fn parse_open_wire(s: &str) -> Result<OpenWire, String> {
    let v: Vec<usize> = s
        .split(':')
        .map(|x| x.parse::<usize>().map_err(|e| format!("`{x}`: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [channel, from_step, to_step] if from_step <= to_step => Ok(OpenWire {
            channel,
            from_step,
            to_step,
        }),
        _ => Err("expected CHANNEL:FROM:TO with FROM <= TO".into()),
    }
}

#[derive(serde::Deserialize)]
struct Meta {
    label: Vec<i64>,
}

/// Loads any of the accepted trial forms.
pub fn load_trial(path: &Path, rate: f32) -> anyhow::Result<Trial> {
    let cfg = LabelConfig::default();
    if path.is_dir() || slipguard_data::recording::is_recording(path) {
        let mut v = slipguard_data::load_path(path, &cfg, |_, _| {})?;
        if v.len() != 1 {
            bail!("{} holds {} trials; give one", path.display(), v.len());
        }
        return Ok(v.remove(0));
    }
    let (names, samples) = read_tactile_csv(path)?;
    let id = path
        .file_stem()
        .map_or("trial".into(), |s| s.to_string_lossy().into_owned());
    let mut t = Trial::new(id, Unit::MilliNewton, rate, samples);
    t.sensor = SensorKind::Force;
    t.channel_names = names;
    t.source = path.display().to_string();
    let meta = path.with_extension("meta.json");
    if let Ok(text) = std::fs::read_to_string(&meta) {
        let m: Meta =
            serde_json::from_str(&text).with_context(|| format!("reading {}", meta.display()))?;
        if let [l0, l1, l2, l3] = m.label[..] {
            t.marks = PhaseMarks {
                grasp_start: Some(l0 as usize),
                lift_start: Some(l1 as usize),
                open_start: Some(l2 as usize),
                release: None,
            };
            t.outcome = if l3 == 1 {
                Outcome::Success
            } else {
                Outcome::Failure
            };
        }
    }
    t.validate().map_err(anyhow::Error::msg)?;
    let cfg = cfg.scaled_to(t.rate_hz);
    annotate(&mut t, &cfg);
    Ok(t)
}

/// The trials of `path`: one, or every trial of a folder of recordings or dataset.
fn load_trials(path: &Path, rate: f32) -> anyhow::Result<Vec<Trial>> {
    if path.is_dir() {
        let v = slipguard_data::load_path(path, &LabelConfig::default(), |_, _| {})
            .with_context(|| format!("loading {}", path.display()))?;
        return Ok(v);
    }
    Ok(vec![load_trial(path, rate)?])
}

/// Whether the blob's checkpoint (`.safetensors` beside it) was trained on this real trial: a
/// checkpoint without cross-validation trained on every real trial (eagle-shoal folders, 16.7
/// Hz), a fold on every trial but its held-out ones.
pub fn in_sample_note(model: &Path, trial_path: &Path, trial: &Trial) -> Option<String> {
    let ck_path = model.with_extension("safetensors");
    let ck = slipguard_learn::checkpoint::read(&ck_path).ok()?;
    let real = trial_path.is_dir();
    if !real {
        return None;
    }
    let held_out = ck
        .extra
        .get("heldout_trials")
        .is_some_and(|h| h.split(',').any(|id| id == trial.id));
    let trained_on_real = ck.model.config.sample_rate_mhz == PAPER_RATE_MHZ
        && ck.extra.get("val_trials").is_some_and(|v| !v.is_empty());
    (trained_on_real && !held_out).then(|| {
        format!(
            "{} was trained on the real trials, {} among them (in-sample): these flags are not \
             a held-out result (`slipguard train --cv 5` gives fold checkpoints that are)",
            model.display(),
            trial.id
        )
    })
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let trials = load_trials(&a.trial, a.rate)?;
    if trials.len() == 1 {
        let (out, png) = (a.out.clone(), a.png.clone());
        let mut log = Log::Direct;
        return run_one(&a, &trials[0], out.as_deref(), png.as_deref(), &mut log);
    }
    if a.port.is_some() {
        bail!(
            "{} holds {} trials: --port sends one; give one trial",
            a.trial.display(),
            trials.len()
        );
    }
    for dir in [&a.out, &a.png].into_iter().flatten() {
        anyhow::ensure!(
            dir != Path::new("-"),
            "{} holds {} trials: --out and --png are folders here",
            a.trial.display(),
            trials.len()
        );
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    // The trials in parallel (rayon), each through the firmware's own path; their messages
    // are printed in the trials' order and the first trial in error stops the output there,
    // as a sequential run would.
    use rayon::prelude::*;
    let runs: Vec<(Vec<String>, anyhow::Result<()>)> = trials
        .par_iter()
        .map(|t| {
            let out = a.out.as_ref().map(|d| d.join(format!("{}.bin", t.id)));
            let png = a.png.as_ref().map(|d| d.join(format!("{}.png", t.id)));
            let mut log = Log::Buffered(Vec::new());
            let r = run_one(&a, t, out.as_deref(), png.as_deref(), &mut log);
            (log.into_lines(), r)
        })
        .collect();
    for (lines, r) in runs {
        for l in lines {
            eprintln!("{l}");
        }
        r?;
    }
    Ok(())
}

/// Where a replay's messages go: straight to stderr (one trial), or kept for printing in
/// order (a folder's trials run in parallel).
enum Log {
    Direct,
    Buffered(Vec<String>),
}

impl Log {
    fn line(&mut self, l: String) {
        match self {
            Log::Direct => eprintln!("{l}"),
            Log::Buffered(v) => v.push(l),
        }
    }

    fn into_lines(self) -> Vec<String> {
        match self {
            Log::Direct => Vec::new(),
            Log::Buffered(v) => v,
        }
    }
}

fn run_one(
    a: &Args,
    trial: &Trial,
    out_path: Option<&Path>,
    png: Option<&Path>,
    log: &mut Log,
) -> anyhow::Result<()> {
    let trial = trial.clone();
    // The file when one was given, the trial's id within a folder.
    let name = if a.trial.is_file() {
        a.trial.display().to_string()
    } else {
        trial.id.clone()
    };
    let profile = match a.profile {
        None => replay::profile_for(&trial, &name)?,
        Some(id) => id.profile(),
    };
    let model = a
        .model
        .clone()
        .unwrap_or_else(|| replay::default_model_for(&profile, trial.rate_mhz()));
    check_against_profile(a, &profile, &name, &trial)?;
    let (blob, _) = check::load_model("replay", &model, &profile, a.allow_bad_model)?;
    if let Some(note) = in_sample_note(&model, &a.trial, &trial) {
        log.line(format!("replay: note: {note}"));
    }
    let rate_mhz = match replay::check_rate(&trial, blob.as_bytes()) {
        Ok(r) => r.unwrap_or(profile.default_rate_mhz().0),
        Err(e) if a.any_rate => {
            log.line(format!("replay: warning: {e}"));
            trial.rate_mhz().0
        }
        Err(e) => bail!("{e} (use --any-rate to replay anyway)"),
    };
    let (script, mut wires) = command_script(a, &trial);
    wires.extend(a.open_wire.iter().copied());
    let out = replay::replay(profile, blob.as_bytes(), &trial, &script, &wires);
    let frames = replay::decode_stream(&out.wire);
    let n_flags = frames
        .iter()
        .filter(|f| matches!(f.msg, Message::Flags(_)))
        .count();
    let n_faults = frames
        .iter()
        .filter(|f| matches!(f.msg, Message::Fault(_)))
        .count();
    log.line(format!(
        "replay: {} ({} steps, {} Hz) with {}: {} frames ({} flags, {} faults), {} bytes",
        trial.id,
        trial.n_steps(),
        trial.rate_hz,
        model.display(),
        out.frames,
        n_flags,
        n_faults,
        out.wire.len()
    ));
    // A blob with a hand rule (format v2): the frames' hand flag is the fused one.
    if let Some(rule) = slipguard_core::blob::ModelBlob::parse(blob.as_bytes())
        .ok()
        .and_then(|b| b.config.hand_rule)
    {
        let (up, by_rule) = frames
            .iter()
            .filter_map(|f| match f.msg {
                Message::Flags(x) => Some((x.hand_unstable(), x.hand_by_rule())),
                _ => None,
            })
            .fold((0, 0), |(u, r), (h, b)| (u + h as usize, r + b as usize));
        log.line(format!(
            "replay: hand flag fused with the blob's hand rule ({rule}): up in {up} flag frames, \
             {by_rule} of them by the rule alone (status HAND_BY_RULE)"
        ));
    }
    match out_path {
        Some(p) if p == Path::new("-") => std::io::stdout().write_all(&out.wire)?,
        Some(p) => {
            std::fs::write(p, &out.wire).with_context(|| format!("writing {}", p.display()))?
        }
        None => {}
    }
    if let Some(png) = png {
        let flags = replay::flags_by_frame(&frames, Millihertz(rate_mhz), trial.n_steps());
        let title = format!(
            "{} ({}), model {}",
            trial.id,
            trial.outcome,
            model.file_name().unwrap_or_default().to_string_lossy()
        );
        replay::plot_fig8(&trial, &flags, a.plot_channel, &title, png)?;
        log.line(format!("replay: plot {}", png.display()));
    }
    if let Some(name) = &a.port {
        send_paced(name, a.baud, &out.wire)?;
    }
    Ok(())
}

/// Refuses a `--plot-channel`, an `--open-wire` channel or a trial's channel count that the
/// profile does not have (the model takes the profile's channels: more would be dropped, fewer
/// would be zero force).
fn check_against_profile(
    a: &Args,
    profile: &slipguard_app::profile::Profile,
    name: &str,
    trial: &Trial,
) -> anyhow::Result<()> {
    if let Some(c) = a.plot_channel
        && c >= profile.channels
    {
        bail!(
            "--plot-channel {c}: the {} profile has channels 0 to {}",
            profile.name,
            profile.channels - 1
        );
    }
    for w in &a.open_wire {
        if w.channel >= profile.channels {
            bail!(
                "--open-wire {}:{}:{}: channel {} is not one of the {} profile's 0 to {}",
                w.channel,
                w.from_step,
                w.to_step,
                w.channel,
                profile.name,
                profile.channels - 1
            );
        }
    }
    if trial.n_channels() != profile.channels {
        bail!(
            "{}: {} channels, the {} profile has {} (give --profile, or a trial with {} channels)",
            name,
            trial.n_channels(),
            profile.name,
            profile.channels,
            profile.channels
        );
    }
    Ok(())
}

/// Scripted commands: each with the frame it goes before and its encoded bytes.
type ScriptedBytes = Vec<(u32, Vec<u8>)>;

/// The commands sent to the firmware during the replay (`--script`, and with `--samples` the
/// info request and the samples stream first), encoded, and the scripted open wires.
fn command_script(a: &Args, trial: &Trial) -> (ScriptedBytes, Vec<OpenWire>) {
    let (script, wires) = match a.script {
        Script::None => (Vec::new(), Vec::new()),
        Script::Cheez => replay::cheez_script(),
        Script::Marks => {
            let mut cmds = Vec::new();
            if let Some(g) = a.grasp_at.or(trial.marks.grasp_start.map(|g| g as u32)) {
                cmds.push(Scheduled {
                    before_frame: g,
                    command: Command::GraspStart,
                });
            }
            // The lift only echoes a phase mark: by default sent when recording (--samples).
            let lift_mark = trial.marks.lift_start.filter(|_| a.samples);
            if let Some(l) = a.lift_at.or(lift_mark.map(|l| l as u32)) {
                cmds.push(Scheduled {
                    before_frame: l,
                    command: Command::Lift,
                });
            }
            if let Some(r) = a.release_at.or(trial.marks.release.map(|r| r as u32)) {
                cmds.push(Scheduled {
                    before_frame: r,
                    command: Command::Release,
                });
            }
            cmds.sort_by_key(|c| c.before_frame);
            (replay::encode_script(&cmds), Vec::new())
        }
    };
    let script = if a.samples {
        let mut v = replay::encode_script(&[
            Scheduled {
                before_frame: 0,
                command: Command::Info,
            },
            Scheduled {
                before_frame: 0,
                command: Command::StreamMode(slipguard_core::protocol::StreamMode::FlagsAndSamples),
            },
        ]);
        v.extend(script);
        v
    } else {
        script
    };
    (script, wires)
}

/// `--port`: the replay's wire bytes to a serial port, each frame when its last sample's time
/// has passed (its timestamp), replies right after the frame they follow.
fn send_paced(name: &str, baud: u32, wire: &[u8]) -> anyhow::Result<()> {
    let mut port = serialport::new(name, baud)
        .timeout(Duration::from_millis(500))
        .open()
        .with_context(|| format!("opening {name}"))?;
    let start = Instant::now();
    let mut d = slipguard_core::protocol::Deframer::new();
    let mut chunk = Vec::new();
    for &b in wire {
        chunk.push(b);
        if let Some(Ok(f)) = d.push_decode(b) {
            if let Message::Flags(fl) = f.msg {
                let due = Duration::from_micros(fl.timestamp_us as u64);
                if let Some(wait) = due.checked_sub(start.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
            port.write_all(&chunk)?;
            chunk.clear();
        }
    }
    port.write_all(&chunk)?;
    port.flush()?;
    Ok(())
}
