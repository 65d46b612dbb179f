//! Argument checks shared by the subcommands: clap value parsers for the ranges clap's own
//! ranged integer parsers do not cover (floats, names), and the model-blob check every
//! subcommand that reads a blob runs before any work. Each refusal is one line that names the
//! value and the allowed range (clap adds the argument's name).

use std::path::Path;

use anyhow::bail;
use slipguard::replay::{check_blob, load_blob};
use slipguard_app::profile::{Profile, ProfileId};
use slipguard_core::blob::{AlignedBlob, ModelConfig};
use slipguard_core::units::Millihertz;

/// clap parser: an integer in `lo..=hi` as `usize` (clap's ranged parsers stop at u64).
macro_rules! usize_in {
    ($range:expr) => {
        clap::builder::RangedU64ValueParser::<usize>::new().range($range)
    };
}
pub(crate) use usize_in;

/// A finite number in `ok`, else the value and the allowed `range` in words.
fn float(s: &str, range: &str, ok: impl Fn(f64) -> bool) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && ok(v) => Ok(v),
        Ok(v) => Err(format!("{v} is not in the allowed range {range}")),
        Err(_) => Err(format!(
            "`{s}` is not a number in the allowed range {range}"
        )),
    }
}

/// clap parser: a probability threshold, strictly between 0 and 1.
pub fn open_unit(s: &str) -> Result<f64, String> {
    float(s, "0 < x < 1", |v| v > 0.0 && v < 1.0)
}

/// clap parser: strictly between 0 and 1, as f32.
pub fn open_unit_f32(s: &str) -> Result<f32, String> {
    open_unit(s).map(|v| v as f32)
}

/// clap parser: a share or rate of occurrence, 0 ≤ x ≤ 1.
pub fn unit(s: &str) -> Result<f64, String> {
    float(s, "0 ≤ x ≤ 1", |v| (0.0..=1.0).contains(&v))
}

/// clap parser: a share strictly below 1 (0 ≤ x < 1).
pub fn share_below_one(s: &str) -> Result<f64, String> {
    float(s, "0 ≤ x < 1", |v| (0.0..1.0).contains(&v))
}

/// clap parser: a finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    float(s, "x > 0", |v| v > 0.0)
}

/// clap parser: a finite number > 0, as f32.
pub fn positive_f32(s: &str) -> Result<f32, String> {
    positive(s).map(|v| v as f32)
}

/// clap parser: a finite number ≥ 0.
pub fn non_negative(s: &str) -> Result<f64, String> {
    float(s, "x ≥ 0", |v| v >= 0.0)
}

/// clap parser: a finite number ≥ 0, as f32.
pub fn non_negative_f32(s: &str) -> Result<f32, String> {
    non_negative(s).map(|v| v as f32)
}

/// clap parser: a duration in seconds within `lo..=hi` (durations are seconds at every rate;
/// the command converts them to steps at the data's rate).
pub fn seconds_in(lo: f32, hi: f32) -> impl Fn(&str) -> Result<f32, String> + Clone {
    move |s: &str| match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!("`{s}` is not a duration in {lo}..={hi} s")),
    }
}

/// Steps of `seconds` at `rate_hz`, rounded to the nearest step (0 s → 0 steps).
pub fn steps_at(seconds: f32, rate_hz: f32) -> usize {
    (seconds * rate_hz).round() as usize
}

/// clap parser: a model name that fits the blob's name field (printable ASCII, 1 to 12 bytes).
pub fn blob_name(s: &str) -> Result<String, String> {
    // The size of `ModelConfig::name`.
    let max = std::mem::size_of_val(&[0u8; 12]);
    if s.is_empty() || s.len() > max || !s.bytes().all(|b| b.is_ascii_graphic() || b == b' ') {
        Err(format!(
            "`{s}` ({} bytes) does not fit the blob's name field: 1 to {max} printable ASCII characters",
            s.len()
        ))
    } else {
        Ok(s.to_string())
    }
}

/// clap parser: a sensor profile's name in the registry (`hand`, `suction`; the help lists them).
pub fn profile_id() -> impl clap::builder::TypedValueParser<Value = ProfileId> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(ProfileId::ALL.map(ProfileId::name))
        .try_map(|s: String| s.parse::<ProfileId>())
}

/// The word `--sensor` (train, simulate) uses for a profile's sensor: the hand's `force` pads,
/// the `suction` cups. A new profile adds its word here (the `match` is exhaustive).
pub fn sensor_word(p: ProfileId) -> &'static str {
    match p {
        ProfileId::Hand => "force",
        ProfileId::Suction => "suction",
    }
}

/// clap parser of `--sensor`: a profile's sensor word ([`sensor_word`]; the help lists them).
pub fn sensor() -> impl clap::builder::TypedValueParser<Value = ProfileId> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(ProfileId::ALL.map(sensor_word)).try_map(
        |s: String| {
            ProfileId::ALL
                .into_iter()
                .find(|p| sensor_word(*p) == s)
                .ok_or("unknown sensor")
        },
    )
}

/// A frame rate in Hz that one of the sensor profiles runs (`--rate-hz`, `--rate`).
pub fn profile_rate(flag: &str, rate_hz: f64, profiles: &[Profile]) -> anyhow::Result<Millihertz> {
    let mhz = (rate_hz * 1000.0).round();
    let ok: Vec<Millihertz> = profiles.iter().flat_map(|p| p.rates_mhz).copied().collect();
    if rate_hz.is_finite() && ok.iter().any(|&r| r.0 as f64 == mhz) {
        return Ok(Millihertz(mhz as u32));
    }
    let list: Vec<String> = ok.iter().map(|r| format!("{}", r.hz())).collect();
    bail!(
        "{flag} {rate_hz}: the sensor profile runs {} Hz only",
        list.join(" or ")
    )
}

/// Reads a model blob and checks it as the firmware does at boot (it parses, within the build's
/// bounds, a rate and input unit the profile runs). A blob that fails is refused, or with
/// `allow_bad` run anyway after a warning (the firmware then sends fault frames only).
pub fn load_model(
    tool: &str,
    path: &Path,
    profile: &Profile,
    allow_bad: bool,
) -> anyhow::Result<(AlignedBlob, Option<ModelConfig>)> {
    let blob = load_blob(path)?;
    match check_blob(profile, blob.as_bytes()) {
        Ok(cfg) => Ok((blob, Some(cfg))),
        Err(why) if allow_bad => {
            eprintln!(
                "{tool}: warning: {}: {why}; running anyway (--allow-bad-model): the firmware \
                 sends fault frames only",
                path.display()
            );
            Ok((blob, None))
        }
        Err(why) => bail!(
            "{}: {why} (give a blob from `slipguard train` or `slipguard-export`, or \
             --allow-bad-model to run it anyway)",
            path.display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's 1.2 s label lead is its 20 steps at 16.7 Hz, and the same duration at the
    /// other profiles' rates (48 steps at 40 Hz, 85 at 71 Hz); 0 s stays 0 steps.
    #[test]
    fn durations_become_steps_at_the_data_rate() {
        assert_eq!(steps_at(1.2, slipguard_core::sample::PAPER_RATE_HZ), 20);
        assert_eq!(steps_at(1.2, 40.0), 48);
        assert_eq!(steps_at(1.2, 71.0), 85);
        assert_eq!(steps_at(0.6, 40.0), 24);
        assert_eq!(steps_at(0.0, 40.0), 0);
        let p = seconds_in(0.0, 60.0);
        assert_eq!(p("0.5"), Ok(0.5));
        assert!(p("-1").unwrap_err().contains("0..=60 s"));
        assert!(p("61").is_err());
        assert!(p("NaN").is_err());
    }
}
