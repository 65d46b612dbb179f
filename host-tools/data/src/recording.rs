//! slipguard's own recording format (CSV with a metadata preamble), version 1.
//! The byte-exact description with an example is in docs/data-format.md.
//!
//! ```text
//! # slipguard-recording v1
//! # id: sim-force-0000
//! # sensor: force
//! # unit: mN
//! # rate_hz: 16.7
//! # outcome: failure
//! # grasp_start: 2
//! # lift_start: 3
//! # drop_step: 4
//! time_s,c0,c1,phase,label
//! 0.000000,0,0,pre,0
//! ...
//! ```

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use crate::csvtext::{
    Line, Record, check_width, from_line, lines, parse_error, parse_number, read_text, records,
    strip_bom,
};
use crate::error::{DataError, Result};
use crate::labels::{LabelConfig, annotate};
use crate::trial::{Outcome, Phase, PhaseMarks, SensorKind, Stability, Trial, Unit};

/// First line of every recording.
pub const MAGIC: &str = "# slipguard-recording v1";

/// Highest `rate_hz` a recording may state (reader and writer).
pub const MAX_RATE_HZ: f32 = 100_000.0;
/// Lowest `rate_hz` a recording may state (reader and writer).
pub const MIN_RATE_HZ: f32 = 0.001;
/// Most data rows of one recording (reader and writer): 2^20 steps, 4.1 h at 71 Hz, 64 MiB of
/// 16-channel samples in memory.
pub const MAX_STEPS: usize = 1 << 20;

/// The values a sensor of `unit` can physically report (reader and writer refuse others):
/// force within ±1 000 000 mN (1 kN, far beyond any fingertip or gripper); counts within
/// ±65 535: a converter of at most 16 bits, and the suction profile records pressure relative to
/// its tare at grasp start (the samples stream's value), so a value may fall below the zero.
/// `None` (any finite value) for other units.
pub fn physical_range(unit: &Unit) -> Option<(f32, f32)> {
    match unit {
        Unit::MilliNewton => Some((-1.0e6, 1.0e6)),
        Unit::Counts => Some((-65_535.0, 65_535.0)),
        Unit::Other(_) => None,
    }
}

/// Largest recording file the reader opens: 1 GiB (2^20 rows of 16 force channels take about
/// 100 MiB as the writer writes them).
pub const MAX_BYTES: u64 = 1 << 30;

const KNOWN_KEYS: [&str; 12] = [
    "id",
    "sensor",
    "unit",
    "rate_hz",
    "outcome",
    "grasp_start",
    "lift_start",
    "open_start",
    "release",
    "drop_step",
    "slip_onset_step",
    "source",
];

/// Is this file a slipguard recording (starts with [`MAGIC`])?
pub fn is_recording(path: &Path) -> bool {
    use std::io::Read;
    let mut buf = [0u8; 24];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut buf))
        .map(|_| &buf[..] == MAGIC.as_bytes())
        .unwrap_or(false)
}

/// Format a sample: integers without a decimal point, else the shortest
/// representation that reads back to the same f32.
fn fmt_value(v: f32) -> String {
    if v.fract() == 0.0 && v.abs() < 1e9 {
        format!("{}", v as i64)
    } else {
        format!("{v}")
    }
}

/// The preamble and header of a recording (everything before the data rows).
fn head(trial: &Trial, has_phase: bool) -> String {
    let mut s = String::new();
    s.push_str(MAGIC);
    s.push('\n');
    let one_line = |v: &str| v.replace(['\n', '\r'], " ");
    let _ = writeln!(s, "# id: {}", one_line(&trial.id));
    let _ = writeln!(s, "# sensor: {}", one_line(&trial.sensor.to_string()));
    let _ = writeln!(s, "# unit: {}", one_line(&trial.unit.to_string()));
    let _ = writeln!(s, "# rate_hz: {}", trial.rate_hz);
    let _ = writeln!(s, "# outcome: {}", trial.outcome);
    let marks = [
        ("grasp_start", trial.marks.grasp_start),
        ("lift_start", trial.marks.lift_start),
        ("open_start", trial.marks.open_start),
        ("release", trial.marks.release),
        ("drop_step", trial.drop_step),
        ("slip_onset_step", trial.slip_onset_step),
    ];
    for (k, v) in marks {
        if let Some(v) = v {
            let _ = writeln!(s, "# {k}: {v}");
        }
    }
    if !trial.source.is_empty() {
        let _ = writeln!(s, "# source: {}", one_line(&trial.source));
    }
    for (k, v) in &trial.extra {
        let _ = writeln!(s, "# {k}: {}", one_line(v));
    }
    s.push_str("time_s");
    for n in &trial.channel_names {
        s.push(',');
        s.push_str(n);
    }
    if has_phase {
        s.push_str(",phase");
    }
    if trial.step_labels.is_some() {
        s.push_str(",label");
    }
    s.push('\n');
    s
}

/// One data row without labels.
fn row(s: &mut String, decimals: usize, time_s: f64, values: impl Iterator<Item = f32>) {
    let _ = write!(s, "{:.*}", decimals, time_s);
    for v in values {
        s.push(',');
        s.push_str(&fmt_value(v));
    }
}

/// Render a trial in the recording format (LF line endings, final newline).
pub fn to_string(trial: &Trial) -> String {
    let has_phase = trial.marks != PhaseMarks::default();
    let mut s = head(trial, has_phase);
    let decimals = time_decimals(trial.rate_hz);
    for t in 0..trial.n_steps() {
        row(
            &mut s,
            decimals,
            trial.time_s(t),
            trial.samples.iter().map(|c| c[t]),
        );
        if has_phase {
            s.push(',');
            s.push_str(trial.marks.phase_at(t).name());
        }
        if let Some(l) = &trial.step_labels {
            s.push(',');
            if let Some(l) = l[t] {
                let _ = write!(s, "{}", l.code());
            }
        }
        s.push('\n');
    }
    s
}

/// A recording written row by row as the data arrives (the monitor's recorder): the preamble
/// and header of a trial without marks, then one row per [`Appender::push`] with the `phase`
/// column (which carries the marks), buffered until [`Appender::flush`]. The buffer reaches the
/// file in whole rows, so a file whose writer died after a flush reads back with every row
/// flushed (only its final summary metadata is missing).
#[derive(Debug)]
pub struct Appender {
    file: std::io::BufWriter<std::fs::File>,
    path: std::path::PathBuf,
    rate_hz: f32,
    decimals: usize,
    channels: usize,
    steps: usize,
    phase: Phase,
}

impl Appender {
    /// Creates `path` with the preamble of `meta` (id, unit, rate, channel names, source and
    /// extra keys; its samples only give the channel count, its marks and labels are ignored).
    pub fn create(path: &Path, meta: &Trial) -> Result<Self> {
        let mut m = meta.clone();
        m.marks = PhaseMarks::default();
        m.step_labels = None;
        m.drop_step = None;
        m.slip_onset_step = None;
        let shape = |message| DataError::Shape {
            path: path.to_path_buf(),
            message,
        };
        check_meta(&m).map_err(shape)?;
        let f = std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
        let mut file = std::io::BufWriter::new(f);
        file.write_all(head(&m, true).as_bytes())
            .map_err(|e| DataError::io(path, e))?;
        Ok(Self {
            file,
            path: path.to_path_buf(),
            rate_hz: m.rate_hz,
            decimals: time_decimals(m.rate_hz),
            channels: m.n_channels(),
            steps: 0,
            phase: Phase::Pre,
        })
    }

    /// Appends one step. Refused: another channel count, a non-finite value, a phase that
    /// goes back, more than [`MAX_STEPS`] rows.
    pub fn push(&mut self, values: &[f32], phase: Phase) -> Result<()> {
        let shape = |message| DataError::Shape {
            path: self.path.clone(),
            message,
        };
        if values.len() != self.channels {
            return Err(shape(format!(
                "step {}: {} values for {} channels",
                self.steps,
                values.len(),
                self.channels
            )));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(shape(format!("step {}: a value is not finite", self.steps)));
        }
        if (phase as u8) < (self.phase as u8) {
            return Err(shape(format!(
                "step {}: phase goes back from {} to {}",
                self.steps,
                self.phase.name(),
                phase.name()
            )));
        }
        if self.steps >= MAX_STEPS {
            return Err(shape(format!(
                "more than {MAX_STEPS} steps (the format's maximum length)"
            )));
        }
        let mut s = String::new();
        row(
            &mut s,
            self.decimals,
            self.steps as f64 / self.rate_hz as f64,
            values.iter().copied(),
        );
        s.push(',');
        s.push_str(phase.name());
        s.push('\n');
        self.file
            .write_all(s.as_bytes())
            .map_err(|e| DataError::io(&self.path, e))?;
        self.steps += 1;
        self.phase = phase;
        Ok(())
    }

    /// Rows written so far.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Hands the buffered rows to the operating system.
    pub fn flush(&mut self) -> Result<()> {
        self.file.flush().map_err(|e| DataError::io(&self.path, e))
    }
}

/// Writes `trial` to `path` through a temporary file beside it and a rename, so `path` holds
/// either its previous contents or the whole new recording.
pub fn replace_recording(trial: &Trial, path: &Path) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    write_recording(trial, &tmp)?;
    std::fs::rename(&tmp, path).map_err(|e| DataError::io(path, e))
}

/// Decimals of the `time_s` column: 6, more above 100 Hz so that a step is at least 10^4
/// units of the last digit (the reader's 5 % rate check and strictly increasing times hold at
/// every rate up to [`MAX_RATE_HZ`]).
pub fn time_decimals(rate_hz: f32) -> usize {
    let digits = (rate_hz.max(1.0) as f64).log10().ceil() as usize;
    (digits + 4).max(6)
}

/// What the reader would refuse in a trial the writer is given: rate and length bounds,
/// channel names, finite values, metadata keys (so every file written reads back).
pub fn check_writable(trial: &Trial) -> std::result::Result<(), String> {
    if trial.n_steps() == 0 || trial.n_steps() > MAX_STEPS {
        return Err(format!(
            "{} steps: a recording holds 1..={MAX_STEPS}",
            trial.n_steps()
        ));
    }
    check_meta(trial)
}

/// [`check_writable`] but the number of steps.
fn check_meta(trial: &Trial) -> std::result::Result<(), String> {
    trial.validate()?;
    if !(MIN_RATE_HZ..=MAX_RATE_HZ).contains(&trial.rate_hz) {
        return Err(format!(
            "rate {} Hz is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz",
            trial.rate_hz
        ));
    }
    for (i, n) in trial.channel_names.iter().enumerate() {
        if n.is_empty()
            || ["time_s", "phase", "label"].contains(&n.as_str())
            || n.chars()
                .any(|c| c == ',' || c == '"' || c == '#' || c.is_whitespace())
            || trial.channel_names[..i].contains(n)
        {
            return Err(format!(
                "channel name `{n}` cannot be a column (empty, reserved, repeated, or with a \
                 comma, quote, `#` or space)"
            ));
        }
        if let Some(t) = trial.samples[i].iter().position(|v| !v.is_finite()) {
            return Err(format!("channel `{n}` step {t} is not a finite number"));
        }
        if let Some((lo, hi)) = physical_range(&trial.unit)
            && let Some(t) = trial.samples[i].iter().position(|v| !(lo..=hi).contains(v))
        {
            return Err(format!(
                "channel `{n}` step {t}: {} {} is outside the sensor's physical range {lo}..={hi}",
                trial.samples[i][t], trial.unit
            ));
        }
    }
    for k in trial.extra.keys() {
        if k.is_empty()
            || !k
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
            || KNOWN_KEYS.contains(&k.as_str())
        {
            return Err(format!(
                "metadata key `{k}` must be lower-case letters, digits and `_`, and not one of \
                 the format's own keys"
            ));
        }
    }
    Ok(())
}

/// Write a trial to `path` in the recording format.
pub fn write_recording(trial: &Trial, path: &Path) -> Result<()> {
    check_writable(trial).map_err(|message| DataError::Shape {
        path: path.to_path_buf(),
        message,
    })?;
    let mut f = std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
    f.write_all(to_string(trial).as_bytes())
        .map_err(|e| DataError::io(path, e))
}

/// Read a recording and annotate it (contact flags; drop step if not stated and
/// the outcome is not success) with `cfg` scaled to the recording's rate.
pub fn read_recording(path: &Path, cfg: &LabelConfig) -> Result<Trial> {
    // The file's size is checked before it is read into memory.
    let len = std::fs::metadata(path)
        .map_err(|e| DataError::io(path, e))?
        .len();
    if len > MAX_BYTES {
        return Err(DataError::Shape {
            path: path.to_path_buf(),
            message: format!(
                "{len} bytes: a recording holds at most {MAX_BYTES} (split it; at most \
                 {MAX_STEPS} rows)"
            ),
        });
    }
    let text = read_text(path)?;
    let mut trial = parse_recording(&text, path)?;
    // `cfg` counts steps at the paper's rate: the same durations at the recording's.
    let cfg = cfg.scaled_to(trial.rate_hz);
    annotate(&mut trial, &cfg);
    Ok(trial)
}

/// Parse recording text without annotating (`path` is only used in errors). The steps, in
/// the order their errors are reported: the preamble (magic line and `# key: value`
/// metadata; rate, unit and outcome), the header's columns, the rows, the time column against
/// the stated rate, the phase marks, then the trial itself, validated.
pub fn parse_recording(text: &str, path: &Path) -> Result<Trial> {
    let text = strip_bom(text);
    let meta = Preamble::read(text, path)?;
    let rate_hz = meta.rate_hz()?;
    let unit = meta.unit()?;
    let outcome = meta.outcome()?;
    // Header and rows: the CSV body after the preamble.
    let body_line = meta.entries.len() + 2;
    let mut body = records(path, from_line(text, body_line), body_line)?.into_iter();
    let header = body
        .next()
        .ok_or_else(|| parse_error(path, body_line, None, None, "missing header line"))?;
    let columns = Columns::read(path, &header)?;
    let rows = Rows::read(path, body, &columns, &unit, rate_hz)?;
    rows.check_time(path, &meta, rate_hz, header.number)?;
    let marks = meta.marks(&rows.phases)?;
    meta.into_trial(unit, rate_hz, outcome, marks, columns, rows)
}

/// A recording's metadata: the `# key: value` lines after the magic line, in file order, each
/// with its 1-based line number (errors about a value name its line).
struct Preamble<'p> {
    path: &'p Path,
    entries: Vec<(String, String, usize)>,
}

impl<'p> Preamble<'p> {
    /// The magic line, then every `#` line up to the header, each checked by [`Self::entry`].
    fn read(text: &str, path: &'p Path) -> Result<Self> {
        let mut it = lines(text).peekable();
        let first = it
            .next()
            .ok_or_else(|| parse_error(path, 1, None, None, "empty file"))?;
        if first.text != MAGIC {
            return Err(parse_error(
                path,
                1,
                None,
                None,
                format!("first line must be `{MAGIC}`"),
            ));
        }
        let mut meta = Preamble {
            path,
            entries: Vec::new(),
        };
        while let Some(l) = it.next_if(|l| l.text.starts_with('#')) {
            let (k, v) = meta.entry(&l)?;
            meta.entries.push((k, v, l.number));
        }
        Ok(meta)
    }

    /// One metadata line as (key, value), both trimmed: `# key: value` with a key of
    /// lower-case letters, digits and `_` that is not given yet.
    fn entry(&self, l: &Line<'_>) -> Result<(String, String)> {
        let path = self.path;
        let body = l.text[1..].trim_start();
        let Some((k, v)) = body.split_once(':') else {
            return Err(parse_error(
                path,
                l.number,
                None,
                None,
                "metadata line must be `# key: value`",
            ));
        };
        let k = k.trim();
        if k.is_empty()
            || !k
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        {
            return Err(parse_error(
                path,
                l.number,
                None,
                None,
                format!("metadata key `{k}` must be lower-case letters, digits and `_`"),
            ));
        }
        if self.get(k).is_some() {
            return Err(parse_error(
                path,
                l.number,
                None,
                None,
                format!("metadata key `{k}` given twice"),
            ));
        }
        Ok((k.to_string(), v.trim().to_string()))
    }

    /// The entry of key `k`, if given.
    fn get(&self, k: &str) -> Option<&(String, String, usize)> {
        self.entries.iter().find(|(mk, _, _)| mk == k)
    }

    /// The line of key `k` for an error about it (1, the magic line, when it is not given).
    fn line_of(&self, k: &str) -> usize {
        self.get(k).map_or(1, |m| m.2)
    }

    /// Key `k` as a step index, if given.
    fn step(&self, k: &str) -> Result<Option<usize>> {
        match self.get(k) {
            None => Ok(None),
            Some((_, v, line)) => v.parse::<usize>().map(Some).map_err(|_| {
                parse_error(
                    self.path,
                    *line,
                    None,
                    None,
                    format!("`{k}` must be a step index (non-negative integer), not `{v}`"),
                )
            }),
        }
    }

    /// `rate_hz` (required), within [`MIN_RATE_HZ`]..=[`MAX_RATE_HZ`].
    fn rate_hz(&self) -> Result<f32> {
        match self.get("rate_hz") {
            None => Err(DataError::MissingMetadata {
                path: self.path.to_path_buf(),
                key: "rate_hz".into(),
            }),
            Some((_, v, line)) => match v.parse::<f32>() {
                Ok(r) if (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&r) => Ok(r),
                _ => Err(parse_error(
                    self.path,
                    *line,
                    None,
                    None,
                    format!("rate_hz must be a number in {MIN_RATE_HZ}..={MAX_RATE_HZ}, not `{v}`"),
                )),
            },
        }
    }

    /// `unit` (required; any text is a unit).
    fn unit(&self) -> Result<Unit> {
        match self.get("unit") {
            None => Err(DataError::MissingMetadata {
                path: self.path.to_path_buf(),
                key: "unit".into(),
            }),
            Some((_, v, _)) => Ok(v.parse().expect("infallible")),
        }
    }

    /// `outcome` (unknown when not given).
    fn outcome(&self) -> Result<Outcome> {
        match self.get("outcome") {
            None => Ok(Outcome::Unknown),
            Some((_, v, line)) => v
                .parse::<Outcome>()
                .map_err(|m| parse_error(self.path, *line, None, None, m)),
        }
    }

    /// The phase marks from the metadata and/or the phase column (`phases`, one per row, may
    /// be empty); where both give a mark they must agree.
    fn marks(&self, phases: &[Phase]) -> Result<PhaseMarks> {
        let mut marks = PhaseMarks {
            grasp_start: self.step("grasp_start")?,
            lift_start: self.step("lift_start")?,
            open_start: self.step("open_start")?,
            release: self.step("release")?,
        };
        if phases.is_empty() {
            return Ok(marks);
        }
        let first = |p: Phase| phases.iter().position(|&q| q as u8 >= p as u8);
        let from_col = [
            ("grasp_start", first(Phase::Grasp), &mut marks.grasp_start),
            ("lift_start", first(Phase::Lift), &mut marks.lift_start),
            // A recording may go from lift straight to release: only an `open` row marks open.
            (
                "open_start",
                phases.iter().position(|&q| q == Phase::Open),
                &mut marks.open_start,
            ),
            ("release", first(Phase::Release), &mut marks.release),
        ];
        for (k, col, m) in from_col {
            match (*m, col) {
                (Some(a), Some(b)) if a != b => {
                    return Err(parse_error(
                        self.path,
                        self.line_of(k),
                        None,
                        None,
                        format!("`{k}: {a}` disagrees with the phase column (step {b})"),
                    ));
                }
                (None, Some(b)) => *m = Some(b),
                _ => {}
            }
        }
        Ok(marks)
    }

    /// The trial: the parsed parts, the remaining metadata (id, sensor, drop and slip steps,
    /// source, unknown keys kept in `extra`), validated.
    fn into_trial(
        self,
        unit: Unit,
        rate_hz: f32,
        outcome: Outcome,
        marks: PhaseMarks,
        columns: Columns,
        rows: Rows,
    ) -> Result<Trial> {
        let path = self.path;
        let id = self.get("id").map_or_else(
            || {
                path.file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default()
            },
            |m| m.1.clone(),
        );
        let mut trial = Trial::new(id, unit, rate_hz, rows.samples);
        trial.channel_names = columns.channel_names;
        if let Some((_, v, _)) = self.get("sensor") {
            trial.sensor = v.parse::<SensorKind>().expect("infallible");
        }
        trial.marks = marks;
        trial.outcome = outcome;
        trial.drop_step = self.step("drop_step")?;
        trial.slip_onset_step = self.step("slip_onset_step")?;
        trial.source = self
            .get("source")
            .map_or_else(|| format!("recording {}", path.display()), |m| m.1.clone());
        if columns.label.is_some() {
            trial.step_labels = Some(rows.labels);
        }
        for (k, v, _) in &self.entries {
            if !KNOWN_KEYS.contains(&k.as_str()) {
                trial.extra.insert(k.clone(), v.clone());
            }
        }
        trial.validate().map_err(|message| DataError::Shape {
            path: path.to_path_buf(),
            message,
        })?;
        Ok(trial)
    }
}

/// The header's columns: `time_s` first, then the channels, then optionally `phase` and
/// `label` (0-based field indices).
struct Columns {
    /// Fields per row.
    width: usize,
    channel_names: Vec<String>,
    phase: Option<usize>,
    label: Option<usize>,
}

impl Columns {
    /// The columns of header record `header`, their names and order checked.
    fn read(path: &Path, header: &Record) -> Result<Self> {
        let cols: Vec<&str> = header.fields.iter().map(String::as_str).collect();
        if cols[0] != "time_s" {
            return Err(DataError::MissingColumn {
                path: path.to_path_buf(),
                line: header.number,
                column: "time_s (first column)".into(),
            });
        }
        let mut out = Columns {
            width: cols.len(),
            channel_names: Vec::new(),
            phase: None,
            label: None,
        };
        for (i, &c) in cols.iter().enumerate().skip(1) {
            out.add(c, i)
                .map_err(|m| parse_error(path, header.number, Some(i + 1), Some(c), m))?;
        }
        if out.channel_names.is_empty() {
            return Err(DataError::MissingColumn {
                path: path.to_path_buf(),
                line: header.number,
                column: "at least one channel".into(),
            });
        }
        Ok(out)
    }

    /// Column `i` named `c` (after `time_s`), or what is wrong with it there.
    fn add(&mut self, c: &str, i: usize) -> std::result::Result<(), String> {
        match c {
            "phase" => {
                if self.phase.is_some() || self.label.is_some() {
                    return Err(
                        "`phase` must come once, after the channels and before `label`".into(),
                    );
                }
                self.phase = Some(i);
            }
            "label" => {
                if self.label.is_some() {
                    return Err("`label` given twice".into());
                }
                self.label = Some(i);
            }
            "" => return Err("empty column name".into()),
            "time_s" => return Err("`time_s` must be the first column only".into()),
            _ => {
                if self.phase.is_some() || self.label.is_some() {
                    return Err("channel columns must come before `phase` and `label`".into());
                }
                if self.channel_names.iter().any(|n| n == c) {
                    return Err(format!("channel `{c}` given twice"));
                }
                self.channel_names.push(c.to_string());
            }
        }
        Ok(())
    }
}

/// A time step longer than 1.5 periods: (previous time, its line, time, its line).
type Gap = (f64, usize, f64, usize);

/// The data rows, column by column.
struct Rows {
    /// Time of each row with its line.
    times: Vec<(f64, usize)>,
    /// Per channel, one sample per row.
    samples: Vec<Vec<f32>>,
    /// One per row when there is a phase column, else empty.
    phases: Vec<Phase>,
    /// One per row when there is a label column, else empty.
    labels: Vec<Option<Stability>>,
    /// The first gap (reported after the rate check, [`Rows::check_time`]).
    gap: Option<Gap>,
}

impl Rows {
    /// Every row after the header, each checked by [`Rows::push`].
    fn read(
        path: &Path,
        body: impl Iterator<Item = Record>,
        cols: &Columns,
        unit: &Unit,
        rate_hz: f32,
    ) -> Result<Self> {
        let mut rows = Rows {
            times: Vec::new(),
            samples: vec![Vec::new(); cols.channel_names.len()],
            phases: Vec::new(),
            labels: Vec::new(),
            gap: None,
        };
        for r in body {
            rows.push(path, r, cols, unit, rate_hz)?;
        }
        Ok(rows)
    }

    /// One row: its width, then its time ([`Rows::push_time`]), samples
    /// ([`Rows::push_samples`]), phase and label ([`Rows::push_phase`], [`Rows::push_label`]).
    fn push(
        &mut self,
        path: &Path,
        r: Record,
        cols: &Columns,
        unit: &Unit,
        rate_hz: f32,
    ) -> Result<()> {
        let (line, f) = (r.number, r.fields);
        if f[0].starts_with('#') {
            return Err(parse_error(
                path,
                line,
                Some(1),
                None,
                "metadata lines (`#`) are only allowed before the header",
            ));
        }
        check_width(path, line, &f, cols.width)?;
        self.push_time(path, line, &f[0], rate_hz)?;
        self.push_samples(path, line, &f, cols, unit)?;
        if let Some(pc) = cols.phase {
            self.push_phase(path, line, pc, &f[pc])?;
        }
        if let Some(lc) = cols.label {
            self.push_label(path, line, lc, &f[lc])?;
        }
        Ok(())
    }

    /// The row's time: after the previous row's (the first gap of more than 1.5 periods
    /// noted), within [`MAX_STEPS`] rows.
    fn push_time(&mut self, path: &Path, line: usize, field: &str, rate_hz: f32) -> Result<()> {
        let t = parse_number(path, line, 1, "time_s", field)?;
        let t: f64 = field.parse().unwrap_or(t as f64);
        if let Some(&(prev, _)) = self.times.last()
            && t <= prev
        {
            return Err(parse_error(
                path,
                line,
                Some(1),
                Some("time_s"),
                format!("time {t} is not after the previous row's {prev}"),
            ));
        }
        if let Some(&(prev, prev_line)) = self.times.last()
            && self.gap.is_none()
            && (t - prev) * rate_hz as f64 > 1.5
        {
            self.gap = Some((prev, prev_line, t, line));
        }
        if self.times.len() == MAX_STEPS {
            return Err(parse_error(
                path,
                line,
                None,
                None,
                format!("more than {MAX_STEPS} data rows (the format's maximum length)"),
            ));
        }
        self.times.push((t, line));
        Ok(())
    }

    /// The row's samples, one per channel, each within the unit's physical range.
    fn push_samples(
        &mut self,
        path: &Path,
        line: usize,
        f: &[String],
        cols: &Columns,
        unit: &Unit,
    ) -> Result<()> {
        for (c, samples_c) in self.samples.iter_mut().enumerate() {
            let name = &cols.channel_names[c];
            let v = parse_number(path, line, c + 2, name, &f[c + 1])?;
            if let Some((lo, hi)) = physical_range(unit)
                && !(lo..=hi).contains(&v)
            {
                return Err(parse_error(
                    path,
                    line,
                    Some(c + 2),
                    Some(name),
                    format!("{v} {unit} is outside the sensor's physical range {lo}..={hi} {unit}"),
                ));
            }
            samples_c.push(v);
        }
        Ok(())
    }

    /// The row's phase (column index `pc`): a phase name that does not go back.
    fn push_phase(&mut self, path: &Path, line: usize, pc: usize, field: &str) -> Result<()> {
        let p: Phase = field
            .parse()
            .map_err(|m: String| parse_error(path, line, Some(pc + 1), Some("phase"), m))?;
        if let Some(&prev) = self.phases.last()
            && (p as u8) < (prev as u8)
        {
            return Err(parse_error(
                path,
                line,
                Some(pc + 1),
                Some("phase"),
                format!("phase goes back from {} to {}", prev.name(), p.name()),
            ));
        }
        self.phases.push(p);
        Ok(())
    }

    /// The row's label (column index `lc`): 0 (stable), 1 (unstable) or empty.
    fn push_label(&mut self, path: &Path, line: usize, lc: usize, field: &str) -> Result<()> {
        let v = field.trim();
        self.labels.push(match v {
            "" => None,
            "0" => Some(Stability::Stable),
            "1" => Some(Stability::Unstable),
            _ => {
                return Err(parse_error(
                    path,
                    line,
                    Some(lc + 1),
                    Some("label"),
                    format!("label must be 0 (stable), 1 (unstable) or empty, not `{v}`"),
                ));
            }
        });
        Ok(())
    }

    /// The time column as a whole: at least one row, a mean step within 5 % of the stated
    /// rate's, then no gap (`header_line`: the header's line).
    fn check_time(
        &self,
        path: &Path,
        meta: &Preamble<'_>,
        rate_hz: f32,
        header_line: usize,
    ) -> Result<()> {
        let times = &self.times;
        let n = times.len();
        if n == 0 {
            return Err(parse_error(
                path,
                header_line + 1,
                None,
                None,
                "no data rows",
            ));
        }
        if n >= 2 {
            let mean_dt = (times[n - 1].0 - times[0].0) / (n - 1) as f64;
            let want = 1.0 / rate_hz as f64;
            if (mean_dt - want).abs() > 0.05 * want {
                return Err(parse_error(
                    path,
                    meta.line_of("rate_hz"),
                    None,
                    None,
                    format!(
                        "rate_hz {rate_hz} does not match the time column (mean step {mean_dt:.6} s = {:.3} Hz)",
                        1.0 / mean_dt
                    ),
                ));
            }
        }
        if let Some((prev, prev_line, t, line)) = self.gap {
            return Err(parse_error(
                path,
                line,
                Some(1),
                Some("time_s"),
                format!(
                    "time jumps from {prev} s (line {prev_line}) to {t} s, about {:.0} steps at \
                     {rate_hz} Hz: rows are missing (lost frames); the monitor fills such gaps and \
                     lists them under `monitor_gaps`",
                    (t - prev) * rate_hz as f64 - 1.0
                ),
            ));
        }
        Ok(())
    }
}
