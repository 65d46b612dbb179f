//! Sensor profiles: which channels are sampled, how fast, how raw counts become the model's
//! input unit, and what counts as a sensor fault. Chosen at build time (firmware Cargo feature
//! `profile-suction`, default hand); the model rate comes from the blob header and must be one
//! of the profile's rates ([`Profile::check_rate`]).

use crate::decimate::{OUT_FRAC_BITS, RATIO};
use slipguard_core::blob::InputUnit;
use slipguard_core::sample::PAPER_RATE_MHZ;

/// Profile id in the info reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ProfileId {
    /// 16 fingertip force channels.
    Hand = 0,
    /// 4 suction-cup pressure channels.
    Suction = 1,
}

/// A sensor profile.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Profile {
    /// Which one.
    pub id: ProfileId,
    /// Short name for logs.
    pub name: &'static str,
    /// Channels scanned and predicted on.
    pub channels: usize,
    /// Model rates this front end runs, mHz; the first is the default (used without a model).
    pub rates_mhz: &'static [u32],
    /// Unit the model's raw input must be in.
    pub unit: InputUnit,
    /// ADC full-scale code (12-bit: 4095).
    pub adc_max: u16,
    /// Live zero: the code of zero load (the front end's offset), counts.
    pub zero_counts: i32,
    /// Model input units per 1/16 count: `(value_q4 − zero·16) · num / den`.
    pub scale_num: i32,
    /// See `scale_num`.
    pub scale_den: i32,
    /// A code below this means the sensor is disconnected (the live zero is missing).
    pub disconnected_below: u16,
    /// A code at or above this means the input is saturated (front end at its rail).
    pub saturated_at: u16,
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
        rates_mhz: &[PAPER_RATE_MHZ, 40_000],
        unit: InputUnit::MilliNewton,
        adc_max: 4095,
        zero_counts: 124,
        scale_num: 10,
        scale_den: 1 << OUT_FRAC_BITS,
        disconnected_below: 62,
        saturated_at: 4080,
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
        rates_mhz: &[71_000],
        unit: InputUnit::Counts,
        adc_max: 4095,
        zero_counts: 0,
        scale_num: 1,
        scale_den: 1,
        disconnected_below: 80,
        saturated_at: 4080,
        debounce_scans: 16,
        stuck_periods: 71,
        fault_hold_periods: 18,
        tare: true,
    };

    /// Default model rate (before a model is loaded, or when it is bad).
    pub fn default_rate_mhz(&self) -> u32 {
        self.rates_mhz.first().copied().unwrap_or(PAPER_RATE_MHZ)
    }

    /// Whether the model rate is one this profile runs.
    pub fn check_rate(&self, rate_mhz: u32) -> bool {
        self.rates_mhz.contains(&rate_mhz)
    }

    /// ADC scans per second for a model rate, in mHz (model rate × RATIO).
    pub fn scan_rate_mhz(&self, rate_mhz: u32) -> u32 {
        rate_mhz.saturating_mul(RATIO as u32)
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
    pub fn to_counts(&self, value: i32) -> u16 {
        let den = self.scale_num.max(1) as i64 * (1 << OUT_FRAC_BITS);
        let num = value as i64 * self.scale_den as i64;
        let c = self.zero_counts as i64 + (2 * num + den).div_euclid(2 * den);
        c.clamp(0, self.adc_max as i64) as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_scaling_round_trips_on_whole_counts() {
        let p = Profile::HAND;
        assert_eq!(p.to_counts(0), 124);
        assert_eq!(p.to_counts(149), 139);
        assert_eq!(p.to_counts(33_367), 3461);
        assert_eq!(p.to_counts(100_000), 4095);
        assert_eq!(p.to_counts(-5_000), 0);
        assert_eq!(p.to_model_units(139 << 4, 0), 150);
        assert_eq!(p.to_model_units(124 << 4, 0), 0);
        assert_eq!(p.to_model_units((124 << 4) - 1, 0), -1); // -0.625 rounds away from zero
        assert!(p.check_rate(PAPER_RATE_MHZ) && p.check_rate(40_000) && !p.check_rate(71_000));
        let s = Profile::SUCTION;
        assert_eq!(s.to_model_units(3000 << 4, 2000 << 4), 1000 << 4);
        assert!(s.check_rate(71_000));
        assert_eq!(s.scan_rate_mhz(71_000), 1_136_000);
    }
}
