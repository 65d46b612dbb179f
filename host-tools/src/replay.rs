//! Host replay of a trial through the firmware: a thin wrapper around
//! [`slipguard_app::replay::run`], the same function the QEMU build is compared with byte for
//! byte (`scripts/qemu-replay.sh`). This module only converts a [`Trial`] to the firmware's
//! model-rate input, builds the command script, decodes the frames for the Fig. 8-style plot and
//! picks the default model blob.

use std::path::{Path, PathBuf};

use plotters::prelude::*;
use slipguard_app::profile::{Profile, ProfileId, ProfileQuery};
use slipguard_app::replay::{self as fw, OpenWire, ScriptItem};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model::Model;
use slipguard_core::protocol::{self, Command, Deframer, Flags, Frame, MAX_WIRE, Message};
use slipguard_core::units::Millihertz;

use slipguard_data::error::{DataError, Result};
use slipguard_data::labels::{LabelConfig, label_annotated};
use slipguard_data::trial::{Trial, Unit};

/// The golden variant (c) blob (random PyTorch-init weights) of the core's tests, in the source
/// tree: for tests and scripts only (no run-time default uses it).
pub fn golden_model_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/core/tests/fixtures/bench/model.bin")
}

/// The default model blobs for a profile: every `<models>/<dir>/*.bin` of the shipped models
/// ([`slipguard_data::shipped::models_dir`]; `hand-force` for the hand, `suction` for suction),
/// sorted.
pub fn default_models(profile: &Profile) -> Vec<PathBuf> {
    shipped_blobs(default_models_dir(profile.id))
}

/// The shipped models' folder of a profile (under [`slipguard_data::shipped::models_dir`]).
pub fn default_models_dir(id: ProfileId) -> &'static str {
    match id {
        ProfileId::Hand => "hand-force",
        ProfileId::Suction => "suction",
    }
}

/// The shipped model for a trial's rate on a profile: the first blob (in [`default_models`]
/// order, then every other `models/*/` folder by name) whose header has the rate `rate_mhz`
/// and the profile's input unit, else the profile's first default model (the caller's rate
/// check then names the mismatch).
pub fn default_model_for(profile: &Profile, rate_mhz: Millihertz) -> PathBuf {
    let defaults = default_models(profile);
    let root = slipguard_data::shipped::models_dir();
    let mut dirs: Vec<String> = std::fs::read_dir(&root)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    dirs.sort();
    let fits = |p: &PathBuf| {
        load_blob(p).ok().is_some_and(|b| {
            Model::from_bytes(b.as_bytes()).is_ok_and(|m| {
                m.config().sample_rate_mhz == Millihertz(rate_mhz.0)
                    && m.config().input_unit == profile.unit
            })
        })
    };
    defaults
        .iter()
        .cloned()
        .chain(dirs.iter().flat_map(|d| shipped_blobs(d)))
        .find(fits)
        .or_else(|| defaults.first().cloned())
        // No blob at all (an empty $SLIPGUARD_MODELS): the folder, which the caller's load names.
        .unwrap_or(root)
}

/// The blobs (`*.bin`, sorted) of `<models>/<dir>/` ([`slipguard_data::shipped::models_dir`]);
/// empty if there are none.
pub fn shipped_blobs(dir: &str) -> Vec<PathBuf> {
    let dir = slipguard_data::shipped::models_dir().join(dir);
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "bin"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Reads a model blob into 4-byte aligned memory (as flash is).
pub fn load_blob(path: &Path) -> Result<AlignedBlob> {
    let b = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    Ok(AlignedBlob::new(&b))
}

/// The registry's profile for a trial's unit, rate and channel count ([`Profile::lookup`]); when
/// none fits, an error that starts with `name` (the file or trial the user gave) and says what
/// the trial holds and which profiles there are.
pub fn profile_for(trial: &Trial, name: &str) -> Result<Profile> {
    let shape = |message: String| DataError::Shape {
        path: name.into(),
        message,
    };
    let unit = trial.unit.input_unit().ok_or_else(|| {
        shape(format!(
            "samples in {}, which no sensor profile takes (mN or counts)",
            trial.unit
        ))
    })?;
    Profile::lookup(ProfileQuery {
        unit: Some(unit),
        rate_mhz: Some(trial.rate_mhz()),
        channels: Some(trial.n_channels()),
    })
    .map_err(|e| shape(e.to_string()))
}

/// The trial as the firmware replay's input: `steps × channels` little-endian `i32` (values
/// rounded to whole units), channels padded with zeros or cut to the profile's.
pub fn trial_bytes(trial: &Trial, profile: &Profile) -> Vec<u8> {
    let n = profile.channels;
    let mut out = Vec::with_capacity(trial.n_steps() * n * 4);
    for t in 0..trial.n_steps() {
        for c in 0..n {
            let v = trial.samples.get(c).map_or(0.0, |s| s[t]);
            out.extend_from_slice(&(v.round() as i32).to_le_bytes());
        }
    }
    out
}

/// Checks a blob as the firmware does at boot ([`slipguard_app::app::check_model`]: it parses
/// within the build's bounds, its rate is one the profile runs, its input unit the profile's);
/// returns its settings or, in words, why the firmware would only send fault frames.
pub fn check_blob(
    profile: &Profile,
    blob: &[u8],
) -> std::result::Result<slipguard_core::blob::ModelConfig, String> {
    use slipguard_app::app::{SystemFault, check_model};
    match check_model(profile, blob) {
        Ok(m) => Ok(*m.config()),
        Err(SystemFault::BadModel(e)) => Err(format!("not a valid model blob: {e}")),
        Err(SystemFault::RateMismatch(r)) => Err(format!(
            "the model runs at {} Hz, the {} profile at {} Hz",
            r as f64 / 1000.0,
            profile.name,
            profile
                .rates_mhz
                .iter()
                .map(|r| format!("{}", (*r).hz()))
                .collect::<Vec<_>>()
                .join(" or ")
        )),
        Err(SystemFault::UnitMismatch) => {
            let unit = Model::from_bytes(blob).map(|m| m.config().input_unit.to_string());
            Err(format!(
                "the model takes {} input, the {} profile delivers {}",
                unit.unwrap_or_default(),
                profile.name,
                profile.unit
            ))
        }
    }
}

/// Checks that a blob's frame rate is the trial's (within 1 %); returns the model rate in mHz.
pub fn check_rate(trial: &Trial, blob: &[u8]) -> std::result::Result<Option<u32>, String> {
    let Ok(m) = Model::from_bytes(blob) else {
        return Ok(None); // the firmware reports a bad blob itself (fault frames)
    };
    let r = m.config().sample_rate_mhz;
    let t = trial.rate_hz as f64 * 1000.0;
    if (r.0 as f64 - t).abs() > 0.01 * t {
        return Err(format!(
            "the model runs at {} Hz but the trial is sampled at {} Hz",
            r.hz(),
            trial.rate_hz
        ));
    }
    Ok(Some(r.0))
}

/// A command the replay script sends before a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Scheduled {
    /// Frame (= trial step) the command's bytes precede.
    pub before_frame: u32,
    /// The command.
    pub command: Command,
}

/// Encodes scheduled commands (seq 1, 2, … in order) into a script for the firmware replay.
pub fn encode_script(cmds: &[Scheduled]) -> Vec<(u32, Vec<u8>)> {
    cmds.iter()
        .enumerate()
        .map(|(i, s)| {
            let mut b = [0u8; MAX_WIRE];
            let n = protocol::encode(
                &Frame {
                    seq: i as u16 + 1,
                    msg: Message::Command(s.command),
                },
                &mut b,
            );
            (s.before_frame, b[..n].to_vec())
        })
        .collect()
}

/// Result of a replay.
#[derive(Clone, Debug)]
pub struct Replayed {
    /// The bytes the firmware would send.
    pub wire: Vec<u8>,
    /// Frames sent.
    pub frames: usize,
}

/// Runs the firmware replay: `script` as raw (before_frame, bytes) items.
pub fn replay(
    profile: Profile,
    blob: &[u8],
    trial: &Trial,
    script: &[(u32, Vec<u8>)],
    open_wires: &[OpenWire],
) -> Replayed {
    let bytes = trial_bytes(trial, &profile);
    let fw_trial = fw::Trial::new(&bytes, profile.channels);
    let items: Vec<ScriptItem<'_>> = script
        .iter()
        .map(|(f, b)| ScriptItem {
            before_frame: *f,
            bytes: b,
        })
        .collect();
    let mut wire = Vec::new();
    let frames = fw::run(profile, blob, &fw_trial, &items, open_wires, |b| {
        wire.extend_from_slice(b)
    });
    Replayed { wire, frames }
}

/// The QEMU comparison's scenario ([`fw::cheez_script`]) as script items.
pub fn cheez_script() -> (Vec<(u32, Vec<u8>)>, Vec<OpenWire>) {
    (
        fw::cheez_script::SCRIPT
            .iter()
            .map(|s| (s.before_frame, s.bytes.to_vec()))
            .collect(),
        fw::cheez_script::OPEN_WIRES.to_vec(),
    )
}

/// Decodes a byte stream (every frame, in order; undecodable runs skipped).
pub fn decode_stream(wire: &[u8]) -> Vec<Frame> {
    let mut d = Deframer::new();
    wire.iter()
        .filter_map(|&b| d.push_decode(b))
        .filter_map(|r| r.ok())
        .collect()
}

/// The flag frames of a stream, indexed by frame index (from the timestamp and `rate_mhz`).
pub fn flags_by_frame(frames: &[Frame], rate_mhz: Millihertz, len: usize) -> Vec<Option<Flags>> {
    let mut v = vec![None; len];
    for f in frames {
        if let Message::Flags(fl) = f.msg {
            let i = (fl.timestamp_us as f64 * rate_mhz.0 as f64 / 1e9).round() as i64 - 1;
            if let Some(slot) = usize::try_from(i).ok().and_then(|i| v.get_mut(i)) {
                *slot = Some(fl);
            }
        }
    }
    v
}
/// A plot in the style of the paper's Fig. 8, in seconds, with the firmware's convention
/// 1 = unstable (the flag): the sensor summed over the shown channels (scaled 0–1, thin grey),
/// the largest p(unstable) (thin light blue), labels (orange dashed), prediction (blue: any
/// channel flagged, or only `channel` when given), grasp / lift / drop marks and the legend
/// right of the data. Faulted frames are shaded grey; the title's second line says the outcome
/// and whether the flag came in time.
pub fn plot_fig8(
    trial: &Trial,
    flags: &[Option<Flags>],
    channel: Option<usize>,
    title: &str,
    path: &Path,
) -> Result<()> {
    let perr = |e: &dyn std::fmt::Display| DataError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let n = trial.n_steps();
    let rate = trial.rate_hz;
    let t = |i: usize| i as f32 / rate;
    let chans: Vec<usize> = match channel {
        Some(c) => vec![c],
        None => {
            let c = trial.contact_channels();
            if c.is_empty() {
                (0..trial.n_channels()).collect()
            } else {
                c
            }
        }
    };
    let force = trial.sum_over(&chans);
    let fmax = force.iter().copied().fold(1e-9f32, f32::max);
    let labels: Option<Vec<Option<f32>>> = trial
        .step_labels
        .as_ref()
        .map(|l| l.iter().map(|s| s.map(|s| s.code() as f32)).collect())
        .or_else(|| {
            let l = label_annotated(trial, &LabelConfig::default().scaled_to(trial.rate_hz));
            (!l.steps.is_empty()).then(|| {
                let mut v = vec![None; n];
                for (j, s) in l.steps.iter().enumerate() {
                    v[l.seq_start + j] = Some(s.code() as f32);
                }
                v
            })
        });
    let mask = channel.map_or(u16::MAX, |c| 1u16 << c);
    let flagged: Vec<bool> = flags
        .iter()
        .map(|f| f.is_some_and(|f| f.unstable & mask != 0))
        .collect();
    let pred: Vec<(f32, f32)> = flags
        .iter()
        .enumerate()
        .filter_map(|(i, f)| f.map(|f| (t(i), if f.unstable & mask != 0 { 1.0 } else { 0.0 })))
        .collect();
    let pmax: Vec<(f32, f32)> = flags
        .iter()
        .enumerate()
        .filter_map(|(i, f)| {
            let f = (*f)?;
            let p = (0..f.channels as usize)
                .filter(|&c| mask & (1 << c) != 0)
                .filter_map(|c| f.p[c].q15())
                .max()?;
            Some((t(i), p.to_f64() as f32))
        })
        .collect();
    let verdict = crate::plot::flag_verdict(
        &flagged,
        trial.outcome == slipguard_data::trial::Outcome::Failure,
        trial.drop_step,
        rate,
    );
    let (y0, y1) = crate::plot::FIG8_Y;
    let root = BitMapBackend::new(crate::plot::writable(path)?, (1240, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(&e))?;
    let body = crate::plot::draw_title(&root, title, &verdict).map_err(|e| perr(&e))?;
    let (plot, legend) = crate::plot::split_legend(&body);
    let mut chart = ChartBuilder::on(&plot)
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(crate::plot::fig8_x_range(t(n.max(1))), y0..y1)
        .map_err(|e| perr(&e))?;
    chart
        .configure_mesh()
        .x_desc(format!("seconds ({rate} Hz, {n} steps)"))
        .y_desc("flag: 1 = unstable, 0 = stable")
        .x_label_formatter(&|v| format!("{v:.1}"))
        .y_labels(3)
        .y_label_formatter(&|v| format!("{v:.1}"))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| perr(&e))?;
    for (i, f) in flags.iter().enumerate() {
        if let Some(f) = f
            && f.fault & mask != 0
        {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(t(i), y0), (t(i + 1), y1)],
                    BLACK.mix(0.08).filled(),
                )))
                .map_err(|e| perr(&e))?;
        }
    }
    let sensor = match trial.unit {
        Unit::MilliNewton => "force",
        Unit::Counts => "pressure",
        Unit::Other(_) => "sensor",
    };
    use crate::plot::Key;
    let mut keys = Vec::new();
    let grey = RGBColor(120, 120, 120);
    chart
        .draw_series(LineSeries::new(
            (0..n).map(|i| (t(i), force[i] / fmax)),
            grey.stroke_width(1),
        ))
        .map_err(|e| perr(&e))?;
    keys.push(Key::solid(
        format!("{sensor} ({}), scaled 0–1", trial.unit),
        grey,
        1,
    ));
    let light = RGBColor(120, 170, 230);
    chart
        .draw_series(LineSeries::new(pmax, light.stroke_width(1)))
        .map_err(|e| perr(&e))?;
    keys.push(Key::solid("max p(unstable)", light, 1));
    if let Some(l) = labels {
        let pts: Vec<(f32, f32)> = l
            .iter()
            .enumerate()
            .filter_map(|(i, v)| v.map(|v| (t(i), v + 0.03)))
            .collect();
        let purple = crate::plot::LABEL_COLOR;
        chart
            .draw_series(DashedLineSeries::new(pts, 9, 5, purple.stroke_width(3)))
            .map_err(|e| perr(&e))?;
        keys.push(Key::dashed("label", purple, 3, (6, 4)));
    }
    let blue = RGBColor(0, 60, 200);
    chart
        .draw_series(LineSeries::new(pred, blue.stroke_width(3)))
        .map_err(|e| perr(&e))?;
    keys.push(Key::solid("prediction (flag)", blue, 3));
    let at = |m: Option<usize>| m.filter(|&m| m < n).map(t);
    keys.extend(
        crate::plot::draw_fig8_marks(
            &mut chart,
            at(trial.marks.grasp_start),
            at(trial.marks.lift_start),
            at(trial.drop_step),
        )
        .map_err(|e| perr(&e))?,
    );
    if flags.iter().flatten().any(|f| f.fault & mask != 0) {
        keys.push(Key::solid(
            "shaded: sensor fault",
            RGBColor(200, 200, 200),
            6,
        ));
    }
    crate::plot::draw_keys(&legend, 8, &keys).map_err(|e| perr(&e))?;
    root.present().map_err(|e| perr(&e))
}
