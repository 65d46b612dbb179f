//! The one `Trial` type every tool reads: a multi-channel time series of one grasp
//! with its phase marks, outcome, drop step and per-channel contact flags.

use slipguard_core::units::Millihertz;
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// Physical unit of the samples.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Unit {
    /// Millinewton (fingertip force sensors).
    MilliNewton,
    /// Raw ADC counts (e.g. the 16-bit suction-cup pressure sensors).
    Counts,
    /// Anything else, by name.
    Other(String),
}

impl fmt::Display for Unit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unit::MilliNewton => f.write_str("mN"),
            Unit::Counts => f.write_str("counts"),
            Unit::Other(s) => f.write_str(s),
        }
    }
}

impl Unit {
    /// The model input unit these samples are in (a blob header's, a sensor profile's); `None`
    /// for a unit no model takes.
    pub fn input_unit(&self) -> Option<slipguard_core::blob::InputUnit> {
        use slipguard_core::blob::InputUnit;
        match self {
            Unit::MilliNewton => Some(InputUnit::MilliNewton),
            Unit::Counts => Some(InputUnit::Counts),
            Unit::Other(_) => None,
        }
    }
}

impl FromStr for Unit {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.trim() {
            "mN" => Unit::MilliNewton,
            "counts" => Unit::Counts,
            other => Unit::Other(other.to_string()),
        })
    }
}

/// What kind of sensor produced the samples.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SensorKind {
    /// Fingertip normal-force sensors (piezo-resistive pads).
    Force,
    /// Suction-cup vacuum/pressure sensors.
    Pressure,
    /// Anything else, by name.
    Other(String),
}

impl fmt::Display for SensorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SensorKind::Force => f.write_str("force"),
            SensorKind::Pressure => f.write_str("pressure"),
            SensorKind::Other(s) => f.write_str(s),
        }
    }
}

impl FromStr for SensorKind {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.trim() {
            "force" => SensorKind::Force,
            "pressure" => SensorKind::Pressure,
            other => SensorKind::Other(other.to_string()),
        })
    }
}

/// Why `other` cannot join a data set that starts with `first` (read from `first_path`): a
/// different rate (more than 0.5 % apart), unit or sensor, in one line naming both values and
/// the fix; `None` when they match.
pub fn same_rate_and_unit(
    first: &Trial,
    first_path: &std::path::Path,
    other: &Trial,
) -> Option<String> {
    let what = if (other.rate_hz - first.rate_hz).abs() > 0.005 * first.rate_hz {
        format!("{} Hz", other.rate_hz)
    } else if other.unit != first.unit {
        format!("unit {}", other.unit)
    } else if other.sensor != first.sensor {
        format!("sensor {}", other.sensor)
    } else {
        return None;
    };
    let was = if what.ends_with(" Hz") {
        format!("{} Hz", first.rate_hz)
    } else if other.unit != first.unit {
        format!("unit {}", first.unit)
    } else {
        format!("sensor {}", first.sensor)
    };
    Some(format!(
        "{what}, but {} is {was}: one data set is one rate and one sensor (a model runs at \
         one), so put the recordings of each in their own folder",
        first_path.display()
    ))
}

/// Outcome of the grasp.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Outcome {
    /// The object was held until the release.
    Success,
    /// The object was dropped.
    Failure,
    /// Not known (e.g. an unlabelled recording).
    Unknown,
}

impl fmt::Display for Outcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Outcome::Success => "success",
            Outcome::Failure => "failure",
            Outcome::Unknown => "unknown",
        })
    }
}

impl FromStr for Outcome {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "success" => Ok(Outcome::Success),
            "failure" => Ok(Outcome::Failure),
            "unknown" | "" => Ok(Outcome::Unknown),
            other => Err(format!(
                "outcome must be success, failure or unknown, not `{other}`"
            )),
        }
    }
}

/// Stability label of one time step (the paper's two classes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stability {
    Stable,
    Unstable,
}

impl Stability {
    /// `0` = stable, `1` = unstable (the recording format's `label` column).
    pub fn code(self) -> u8 {
        match self {
            Stability::Stable => 0,
            Stability::Unstable => 1,
        }
    }

    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Stability::Stable),
            1 => Some(Stability::Unstable),
            _ => None,
        }
    }

    pub fn is_unstable(self) -> bool {
        self == Stability::Unstable
    }
}

/// Grasp phase of one time step, derived from the phase marks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Phase {
    /// Before the grasp starts (hand approaching, no contact intended).
    Pre,
    /// Fingers closing and squeezing (from grasp start).
    Grasp,
    /// Lifting and holding (from lift start).
    Lift,
    /// From the third mark on (in eagle-shoal: `l2`, the end of the lift window).
    Open,
    /// From the controller's release command on (the hand opens; recorded by the monitor).
    Release,
}

impl Phase {
    pub fn name(self) -> &'static str {
        match self {
            Phase::Pre => "pre",
            Phase::Grasp => "grasp",
            Phase::Lift => "lift",
            Phase::Open => "open",
            Phase::Release => "release",
        }
    }
}

impl FromStr for Phase {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "pre" => Ok(Phase::Pre),
            "grasp" => Ok(Phase::Grasp),
            "lift" => Ok(Phase::Lift),
            "open" => Ok(Phase::Open),
            "release" => Ok(Phase::Release),
            other => Err(format!(
                "phase must be pre, grasp, lift, open or release, not `{other}`"
            )),
        }
    }
}

/// Step indices (0-based, on the trial's own timeline) of the phase changes.
///
/// For eagle-shoal these are the dataset's `l0`, `l1`, `l2` label numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PhaseMarks {
    /// Fingers start closing (`l0`).
    pub grasp_start: Option<usize>,
    /// Lift starts (`l1`).
    pub lift_start: Option<usize>,
    /// Third mark (`l2`): the end of the lift window in which slip is judged;
    /// called "open start" in the issue. In eagle-shoal it is *not* the moment
    /// the hand opens (see docs/labels.md).
    pub open_start: Option<usize>,
    /// The controller's release command (the hand opens); the monitor records it from the
    /// samples stream's phase marks. Not in eagle-shoal.
    pub release: Option<usize>,
}

impl fmt::Display for PhaseMarks {
    /// "grasp/lift/open" steps (the data set's l0/l1/l2), "-" where a mark is missing: the
    /// marks column of `label --stats`, `simulate` and `dataset`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = |x: Option<usize>| x.map_or("-".to_string(), |v| v.to_string());
        write!(
            f,
            "{}/{}/{}",
            m(self.grasp_start),
            m(self.lift_start),
            m(self.open_start)
        )
    }
}

impl PhaseMarks {
    /// Phase of step `t`.
    pub fn phase_at(&self, t: usize) -> Phase {
        let after = |m: Option<usize>| m.is_some_and(|m| t >= m);
        if after(self.release) {
            Phase::Release
        } else if after(self.open_start) {
            Phase::Open
        } else if after(self.lift_start) {
            Phase::Lift
        } else if after(self.grasp_start) {
            Phase::Grasp
        } else {
            Phase::Pre
        }
    }
}

/// The [`Trial::extra`] key that says the marks were estimated from the force (value `true`).
pub const LABEL_ESTIMATED_KEY: &str = "label_estimated";

/// The grasp setting of a trial id: the id without its last two `_` fields (eagle-shoal's
/// `<Object>_<A>_<B>_<direction>_<index>` → `<Object>_<A>_<B>`), or the whole id when it has
/// fewer than three fields ([`Trial::grasp_setting`]).
pub fn setting_of_id(id: &str) -> String {
    let parts: Vec<&str> = id.split('_').collect();
    if parts.len() >= 3 {
        parts[..parts.len() - 2].join("_")
    } else {
        id.to_string()
    }
}

/// One grasp trial (or one recording) of any sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Trial {
    /// Short identifier, e.g. the eagle-shoal folder name.
    pub id: String,
    /// Where it came from (path, dataset commit, simulator seed...).
    pub source: String,
    pub sensor: SensorKind,
    pub unit: Unit,
    /// Sample rate in Hz (16.7 for eagle-shoal).
    pub rate_hz: f32,
    /// Channel names (`c0`..`c15`).
    pub channel_names: Vec<String>,
    /// Samples, channel-major: `samples[channel][step]`.
    pub samples: Vec<Vec<f32>>,
    pub marks: PhaseMarks,
    pub outcome: Outcome,
    /// Step at which the held object is lost (failures only); see `labels`.
    pub drop_step: Option<usize>,
    /// Per channel: did it touch the object? Channels that never do are kept,
    /// marked `false`, and excluded from per-channel labels.
    pub contact: Vec<bool>,
    /// Ground-truth start of incipient slip (simulator only).
    pub slip_onset_step: Option<usize>,
    /// Per-step stability labels stored with a recording (`label` column), if any.
    pub step_labels: Option<Vec<Option<Stability>>>,
    /// Further key/value metadata (kept verbatim by the recording format).
    pub extra: BTreeMap<String, String>,
}

impl Trial {
    /// A trial with samples and rate; everything else empty/unknown.
    pub fn new(id: impl Into<String>, unit: Unit, rate_hz: f32, samples: Vec<Vec<f32>>) -> Self {
        let n = samples.len();
        Trial {
            id: id.into(),
            source: String::new(),
            sensor: match unit {
                Unit::MilliNewton => SensorKind::Force,
                Unit::Counts => SensorKind::Pressure,
                Unit::Other(_) => SensorKind::Other("unknown".into()),
            },
            unit,
            rate_hz,
            channel_names: (0..n).map(|i| format!("c{i}")).collect(),
            samples,
            marks: PhaseMarks::default(),
            outcome: Outcome::Unknown,
            drop_step: None,
            contact: vec![true; n],
            slip_onset_step: None,
            step_labels: None,
            extra: BTreeMap::new(),
        }
    }

    /// The sample rate as blob headers and sensor profiles give it (16.7 Hz → 16 700 mHz).
    pub fn rate_mhz(&self) -> Millihertz {
        Millihertz::from_hz(self.rate_hz as f64)
    }

    pub fn n_channels(&self) -> usize {
        self.samples.len()
    }

    /// Number of time steps (all channels have the same length).
    pub fn n_steps(&self) -> usize {
        self.samples.first().map_or(0, Vec::len)
    }

    /// Duration of one step in milliseconds.
    pub fn step_ms(&self) -> f32 {
        1000.0 / self.rate_hz
    }

    /// Time of step `t` in seconds.
    pub fn time_s(&self, t: usize) -> f64 {
        t as f64 / self.rate_hz as f64
    }

    /// One time step across all channels.
    pub fn row(&self, t: usize) -> Vec<f32> {
        self.samples.iter().map(|c| c[t]).collect()
    }

    /// Sum over the given channels at every step.
    pub fn sum_over(&self, channels: &[usize]) -> Vec<f32> {
        (0..self.n_steps())
            .map(|t| channels.iter().map(|&c| self.samples[c][t]).sum())
            .collect()
    }

    /// Sum over all channels at every step.
    pub fn total(&self) -> Vec<f32> {
        let all: Vec<usize> = (0..self.n_channels()).collect();
        self.sum_over(&all)
    }

    /// Whether the trial's phase marks and outcome were estimated from its force rather than
    /// recorded (eagle-shoal trials without `label.txt`: `meta.json`'s `label_estimated`, the
    /// method in data/eagle-shoal/README.md and docs/labels.md). Kept in [`Self::extra`] under
    /// [`LABEL_ESTIMATED_KEY`] so that a recording written from the trial keeps it.
    pub fn label_estimated(&self) -> bool {
        self.extra
            .get(LABEL_ESTIMATED_KEY)
            .is_some_and(|v| v == "true")
    }

    /// The grasp setting the trial repeats: object, grip force and weight (`Cheez_100_814` of
    /// eagle-shoal's `Cheez_100_814_top_8`), from the metadata keys `object`, `a` and `b` when
    /// present, else the id without its last two `_` fields (direction and index), else the
    /// id. Trials of one setting are near-repeats: cross-validation that must tell a user what
    /// to expect on a new object or weight holds a whole setting out ([`Self::grasp_setting`]
    /// is the group).
    pub fn grasp_setting(&self) -> String {
        if let (Some(o), Some(a), Some(b)) = (
            self.extra.get("object"),
            self.extra.get("a"),
            self.extra.get("b"),
        ) {
            return format!("{o}_{a}_{b}");
        }
        setting_of_id(&self.id)
    }

    /// Indices of channels marked as in contact.
    pub fn contact_channels(&self) -> Vec<usize> {
        self.contact
            .iter()
            .enumerate()
            .filter_map(|(i, &c)| c.then_some(i))
            .collect()
    }

    /// Check internal consistency: equal channel lengths, names, contact flags,
    /// marks within the trial and in order.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.n_steps();
        if self.samples.is_empty() {
            return Err("trial has no channels".into());
        }
        if let Some((i, c)) = self.samples.iter().enumerate().find(|(_, c)| c.len() != n) {
            return Err(format!(
                "channel {i} has {} steps, channel 0 has {n}",
                c.len()
            ));
        }
        if self.channel_names.len() != self.n_channels() {
            return Err("channel_names and samples differ in length".into());
        }
        if self.contact.len() != self.n_channels() {
            return Err("contact and samples differ in length".into());
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(format!("sample rate {} Hz is not positive", self.rate_hz));
        }
        let marks = [
            ("grasp_start", self.marks.grasp_start),
            ("lift_start", self.marks.lift_start),
            ("open_start", self.marks.open_start),
            ("release", self.marks.release),
            ("drop_step", self.drop_step),
            ("slip_onset_step", self.slip_onset_step),
        ];
        for (name, m) in marks {
            if let Some(m) = m
                && m >= n
            {
                return Err(format!("{name} {m} is beyond the last step {}", n - 1));
            }
        }
        let ordered: Vec<usize> = [
            self.marks.grasp_start,
            self.marks.lift_start,
            self.marks.open_start,
            self.marks.release,
        ]
        .into_iter()
        .flatten()
        .collect();
        if ordered.windows(2).any(|w| w[0] > w[1]) {
            return Err(format!(
                "phase marks out of order: grasp {:?}, lift {:?}, open {:?}, release {:?}",
                self.marks.grasp_start,
                self.marks.lift_start,
                self.marks.open_start,
                self.marks.release
            ));
        }
        if let Some(l) = &self.step_labels
            && l.len() != n
        {
            return Err(format!("{} step labels for {n} steps", l.len()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::PhaseMarks;

    #[test]
    fn phase_marks_print_as_grasp_lift_open_with_a_dash_for_a_missing_one() {
        let m = PhaseMarks {
            grasp_start: Some(64),
            lift_start: None,
            open_start: Some(149),
            release: Some(200),
        };
        assert_eq!(m.to_string(), "64/-/149");
        assert_eq!(PhaseMarks::default().to_string(), "-/-/-");
        assert_eq!(format!("{:>10}", m.to_string()), "  64/-/149");
    }
}
