//! Sensor profiles: which channels are sampled, how fast, how raw counts become the model's
//! input unit, and what counts as a sensor fault. Chosen at build time (firmware Cargo feature
//! `profile-suction`, default hand); the model rate comes from the blob header and must be one
//! of the profile's rates ([`Profile::check_rate`]).
//!
//! This module is the one registry of profiles: [`ProfileId::ALL`] lists them,
//! [`ProfileId::profile`] gives each one's constants, [`Profile::lookup`] finds the profile for
//! a model's or a recording's unit, rate and channel count (refusing, never guessing, when none
//! or several fit). The host tools, the exporter's uploader, the replay scenarios and the C
//! header generator all go through it. A new profile is a new [`ProfileId`] variant: the compiler
//! then stops at every `match` that must say what the profile does (its constants here, its
//! default model folder in the host tools, its simulator in `train`); docs/architecture.md lists
//! the files.

use crate::decimate::{OUT_FRAC_BITS, RATIO};
use slipguard_core::blob::InputUnit;
use slipguard_core::sample::PAPER_RATE_MHZ;
use slipguard_core::units::Millihertz;

/// One raw ADC conversion result: a 12-bit code, `0..=4095` over 0 V … V_ref, before the
/// front end's filter and oversampling (which give the 1/16-count values the model is fed). What
/// the DMA writes, what fault detection and the profiles' thresholds are in.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    bytemuck::Pod,
    bytemuck::Zeroable,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(transparent)]
pub struct AdcCode(pub u16);

impl AdcCode {
    /// The codes of a DMA buffer, unchanged (`AdcCode` is `u16` on the bus).
    pub fn from_dma(words: &[u16]) -> &[AdcCode] {
        bytemuck::cast_slice(words)
    }
}

/// Profile id in the info reply (wire byte, `SG_PROFILE_*` in the C header).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ProfileId {
    /// 16 fingertip force channels.
    Hand = 0,
    /// 4 suction-cup pressure channels.
    Suction = 1,
}

impl ProfileId {
    /// Every profile, in id order (index = id).
    pub const ALL: [ProfileId; 2] = [Self::Hand, Self::Suction];

    /// The profile's constants.
    pub const fn profile(self) -> Profile {
        match self {
            Self::Hand => Profile::HAND,
            Self::Suction => Profile::SUCTION,
        }
    }

    /// The id of a wire byte (info reply, replay scenario), if it is one.
    pub fn from_u8(b: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|p| *p as u8 == b)
    }

    /// The profile's name (`hand`, `suction`): what the CLIs parse and print.
    pub const fn name(self) -> &'static str {
        self.profile().name
    }
}

// The registry is consistent: each id's profile carries that id, and `ALL` is in id order.
const _: () = {
    let mut i = 0;
    while i < ProfileId::ALL.len() {
        assert!(ProfileId::ALL[i] as usize == i);
        assert!(ProfileId::ALL[i].profile().id as usize == i);
        i += 1;
    }
};

impl core::fmt::Display for ProfileId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for ProfileId {
    type Err = UnknownProfile;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or(UnknownProfile)
    }
}

/// A profile name that is not in the registry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UnknownProfile;

impl core::fmt::Display for UnknownProfile {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("unknown sensor profile (expected ")?;
        for (i, p) in ProfileId::ALL.into_iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(p.name())?;
        }
        f.write_str(")")
    }
}

impl core::error::Error for UnknownProfile {}

/// What is known of a model or a recording when its profile is looked up ([`Profile::lookup`]):
/// `None` = not known, any profile fits that part.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProfileQuery {
    /// The input unit (a model's header, a recording's unit).
    pub unit: Option<InputUnit>,
    /// The sample rate.
    pub rate_mhz: Option<Millihertz>,
    /// Channels the data has (a profile fits with at least as many).
    pub channels: Option<usize>,
}

impl ProfileQuery {
    /// A query on the unit and rate of a model or recording.
    pub const fn unit_rate(unit: InputUnit, rate_mhz: Millihertz) -> Self {
        Self {
            unit: Some(unit),
            rate_mhz: Some(rate_mhz),
            channels: None,
        }
    }
    /// Whether `p` fits.
    pub fn fits(&self, p: &Profile) -> bool {
        self.unit.is_none_or(|u| u == p.unit)
            && self.rate_mhz.is_none_or(|r| p.check_rate(r))
            && self.channels.is_none_or(|c| c <= p.channels)
    }
}

/// No profile, or more than one, fits a query ([`Profile::lookup`]); `Display` names the query
/// and the profiles there are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ProfileError {
    /// No profile takes this unit, rate and channel count.
    NoneFits(ProfileQuery),
    /// Several do: the caller must name one (`--profile`).
    Ambiguous(ProfileQuery),
}

#[cfg(feature = "defmt")]
impl defmt::Format for ProfileQuery {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(
            f,
            "unit {} rate_mhz {} channels {}",
            self.unit,
            self.rate_mhz,
            self.channels
        )
    }
}

impl core::fmt::Display for ProfileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let q = match self {
            Self::NoneFits(q) => {
                f.write_str("no sensor profile takes")?;
                q
            }
            Self::Ambiguous(q) => {
                f.write_str("more than one sensor profile takes")?;
                q
            }
        };
        if let Some(c) = q.channels {
            write!(f, " {c} channels")?;
        }
        if let Some(r) = q.rate_mhz {
            write!(f, " at {r}")?;
        }
        if let Some(u) = q.unit {
            write!(f, " in {u}")?;
        }
        f.write_str(" (profiles: ")?;
        for (i, id) in ProfileId::ALL.into_iter().enumerate() {
            let p = id.profile();
            if i > 0 {
                f.write_str("; ")?;
            }
            write!(f, "{} {} channels in {} at", p.name, p.channels, p.unit)?;
            for (k, r) in p.rates_mhz.iter().enumerate() {
                let sep = if k == 0 { " " } else { " or " };
                write!(f, "{sep}{r}")?;
            }
        }
        f.write_str(")")?;
        if matches!(self, Self::Ambiguous(_)) {
            f.write_str(": name one with --profile")?;
        }
        Ok(())
    }
}

impl core::error::Error for ProfileError {}

/// A sensor profile.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Profile {
    /// Which one.
    pub id: ProfileId,
    /// Short name for logs.
    pub name: &'static str,
    /// Channels scanned and predicted on.
    pub channels: usize,
    /// Model rates this front end runs; the first is the default (used without a model).
    pub rates_mhz: &'static [Millihertz],
    /// Unit the model's raw input must be in.
    pub unit: InputUnit,
    /// ADC full-scale code (12-bit: 4095).
    pub adc_max: AdcCode,
    /// Live zero: the code of zero load (the front end's offset), counts.
    pub zero_counts: i32,
    /// Model input units per 1/16 count: `(value_q4 − zero·16) · num / den`.
    pub scale_num: i32,
    /// See `scale_num`.
    pub scale_den: i32,
    /// A code below this means the sensor is disconnected (the live zero is missing).
    pub disconnected_below: AdcCode,
    /// A code at or above this means the input is saturated (front end at its rail).
    pub saturated_at: AdcCode,
    /// Consecutive scans a disconnected or saturated reading must last to become a fault.
    pub debounce_scans: u16,
    /// A code repeated exactly this many model periods (× RATIO scans) means a stuck channel.
    pub stuck_periods: u16,
    /// Model periods a fault is held after its cause is gone.
    pub fault_hold_periods: u16,
    /// Tare at grasp start: the model sees the value relative to the one at grasp start.
    pub tare: bool,
}

impl Profile {
    /// (a) Hand: 16 piezo-resistive fingertip force sensors on ADC1 (see the firmware README
    /// for the pins). Front end: each sensor's conditioning amplifier outputs 0.1 V at no load
    /// plus 2.9 V over 0…36 N (live zero: 124 counts; 10 mN per count), so 0 V means an open
    /// wire and 3.3 V a saturated amplifier. 16.7 Hz (the dataset's and the paper's rate) or
    /// 40 Hz (the DoraHand's), oversampled ×16.
    pub const HAND: Profile = Profile {
        id: ProfileId::Hand,
        name: "hand",
        channels: 16,
        rates_mhz: &[PAPER_RATE_MHZ, Millihertz(40_000)],
        unit: InputUnit::MilliNewton,
        adc_max: AdcCode(4095),
        zero_counts: 124,
        scale_num: 10,
        scale_den: 1 << OUT_FRAC_BITS,
        disconnected_below: AdcCode(62),
        saturated_at: AdcCode(4080),
        debounce_scans: 8,
        stuck_periods: 33,
        fault_hold_periods: 8,
        tare: false,
    };

    /// (b) Suction: 4 vacuum sensors (ratiometric, 0.2…4.7 V divided to 0.13…3.1 V: live zero
    /// 160 counts) on the same internal ADC1, 71 Hz (the paper's pressure rate) oversampled ×16
    /// (1136 scans/s); the internal 12-bit ADC with 16× oversampling gives the 16-bit counts the
    /// model takes (1/16 count units), relative to the pressure at grasp start (tare).
    pub const SUCTION: Profile = Profile {
        id: ProfileId::Suction,
        name: "suction",
        channels: 4,
        rates_mhz: &[Millihertz(71_000)],
        unit: InputUnit::Counts,
        adc_max: AdcCode(4095),
        zero_counts: 0,
        scale_num: 1,
        scale_den: 1,
        disconnected_below: AdcCode(80),
        saturated_at: AdcCode(4080),
        debounce_scans: 16,
        stuck_periods: 71,
        fault_hold_periods: 18,
        tare: true,
    };

    /// The registry's profile for what is known of a model or a recording: the one profile that
    /// fits ([`ProfileQuery::fits`]), else an error naming the query and the profiles.
    pub fn lookup(q: ProfileQuery) -> Result<Profile, ProfileError> {
        let mut fits = ProfileId::ALL
            .into_iter()
            .map(ProfileId::profile)
            .filter(|p| q.fits(p));
        match (fits.next(), fits.next()) {
            (Some(p), None) => Ok(p),
            (None, _) => Err(ProfileError::NoneFits(q)),
            (Some(_), Some(_)) => Err(ProfileError::Ambiguous(q)),
        }
    }

    /// Default model rate (before a model is loaded, or when it is bad).
    pub fn default_rate_mhz(&self) -> Millihertz {
        self.rates_mhz.first().copied().unwrap_or(PAPER_RATE_MHZ)
    }

    /// Whether the model rate is one this profile runs.
    pub fn check_rate(&self, rate_mhz: Millihertz) -> bool {
        self.rates_mhz.contains(&rate_mhz)
    }

    /// ADC scans per second for a model rate (model rate × RATIO).
    pub fn scan_rate_mhz(&self, rate_mhz: Millihertz) -> Millihertz {
        Millihertz(rate_mhz.0.saturating_mul(RATIO as u32))
    }

    /// Decimator output (1/16 counts) minus tare → model input unit.
    #[inline]
    pub fn to_model_units(&self, value_q4: i32, tare_q4: i32) -> i32 {
        let v = value_q4 as i64 - tare_q4 as i64 - ((self.zero_counts as i64) << OUT_FRAC_BITS);
        let num = v * self.scale_num as i64;
        let den = self.scale_den.max(1) as i64;
        // Round half away from zero.
        let q = if num >= 0 {
            (num + den / 2) / den
        } else {
            (num - den / 2) / den
        };
        q.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }

    /// Model input (unit as [`Self::unit`]) → ADC code, the inverse of [`Self::to_model_units`]
    /// rounded to a whole count and clamped to the ADC range (used to emulate the sensor from a
    /// recorded trial).
    pub fn to_counts(&self, value: i32) -> AdcCode {
        let den = self.scale_num.max(1) as i64 * (1 << OUT_FRAC_BITS);
        let num = value as i64 * self.scale_den as i64;
        let c = self.zero_counts as i64 + (2 * num + den).div_euclid(2 * den);
        self.clamp_code(c)
    }

    /// A code computed in a wider type (an emulated sensor's code plus its noise), clamped to
    /// the ADC's range `0..=adc_max`.
    pub fn clamp_code(&self, code: i64) -> AdcCode {
        AdcCode(code.clamp(0, self.adc_max.0 as i64) as u16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_scaling_round_trips_on_whole_counts() {
        let p = Profile::HAND;
        assert_eq!(p.to_counts(0), AdcCode(124));
        assert_eq!(p.to_counts(149), AdcCode(139));
        assert_eq!(p.to_counts(33_367), AdcCode(3461));
        assert_eq!(p.to_counts(100_000), AdcCode(4095));
        assert_eq!(p.to_counts(-5_000), AdcCode(0));
        assert_eq!(p.to_model_units(139 << 4, 0), 150);
        assert_eq!(p.to_model_units(124 << 4, 0), 0);
        assert_eq!(p.to_model_units((124 << 4) - 1, 0), -1); // -0.625 rounds away from zero
        assert!(
            p.check_rate(PAPER_RATE_MHZ)
                && p.check_rate(Millihertz(40_000))
                && !p.check_rate(Millihertz(71_000))
        );
        let s = Profile::SUCTION;
        assert_eq!(s.to_model_units(3000 << 4, 2000 << 4), 1000 << 4);
        assert!(s.check_rate(Millihertz(71_000)));
        assert_eq!(s.scan_rate_mhz(Millihertz(71_000)), Millihertz(1_136_000));
    }

    #[test]
    fn the_registry_finds_each_profile_and_refuses_what_none_or_several_fit() {
        use InputUnit::{Counts, MilliNewton};
        let q = |unit, rate_mhz, channels| ProfileQuery {
            unit,
            rate_mhz,
            channels,
        };
        // A model's unit and rate, a recording's unit, rate and channels.
        assert_eq!(
            Profile::lookup(q(Some(MilliNewton), Some(Millihertz(16_700)), None)),
            Ok(Profile::HAND)
        );
        assert_eq!(
            Profile::lookup(q(Some(MilliNewton), Some(Millihertz(40_000)), Some(16))),
            Ok(Profile::HAND)
        );
        assert_eq!(
            Profile::lookup(q(Some(Counts), Some(Millihertz(71_000)), Some(4))),
            Ok(Profile::SUCTION)
        );
        // Nothing takes 40 Hz counts, 16 suction channels or 17 force channels.
        for bad in [
            q(Some(Counts), Some(Millihertz(40_000)), None),
            q(Some(Counts), Some(Millihertz(71_000)), Some(16)),
            q(Some(MilliNewton), Some(Millihertz(16_700)), Some(17)),
        ] {
            assert_eq!(Profile::lookup(bad), Err(ProfileError::NoneFits(bad)));
        }
        // Knowing only a channel count of 4 fits both: refused, not guessed.
        let open = q(None, None, Some(4));
        assert_eq!(Profile::lookup(open), Err(ProfileError::Ambiguous(open)));
        let msg =
            ProfileError::NoneFits(q(Some(Counts), Some(Millihertz(40_000)), None)).to_string();
        assert_eq!(
            msg,
            "no sensor profile takes at 40 Hz in counts (profiles: hand 16 channels in mN at \
             16.7 Hz or 40 Hz; suction 4 channels in counts at 71 Hz)"
        );
        assert!(
            ProfileError::Ambiguous(open)
                .to_string()
                .ends_with("name one with --profile")
        );
        // Ids, names and wire bytes round-trip; nothing else parses.
        for id in ProfileId::ALL {
            assert_eq!(ProfileId::from_u8(id as u8), Some(id));
            assert_eq!(id.name().parse::<ProfileId>(), Ok(id));
            assert_eq!(id.profile().id, id);
        }
        assert_eq!(ProfileId::from_u8(2), None);
        assert_eq!("force".parse::<ProfileId>(), Err(UnknownProfile));
        assert_eq!(
            UnknownProfile.to_string(),
            "unknown sensor profile (expected hand, suction)"
        );
    }
}
