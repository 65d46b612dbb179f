//! Unit newtypes for values that cross module and crate boundaries (stabilizer's unit types):
//! the type says the unit, so a rate in hertz cannot be passed where millihertz are meant. The
//! Q formats have theirs beside their arithmetic ([`crate::decision::Q15`] for p(unstable) and
//! thresholds, [`crate::protocol::PUnstable`] for p on the wire).

/// A sample rate in millihertz: the unit of the blob header's rate, the sensor profiles' rates
/// and the info reply's (16.7 Hz = `Millihertz(16_700)`). Every rate that crosses a module or
/// crate boundary has this type; recordings and command lines give hertz ([`Millihertz::from_hz`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(transparent)]
pub struct Millihertz(pub u32);

impl Millihertz {
    /// `hz` rounded to the nearest millihertz (negative and NaN give 0, saturated at `u32::MAX`).
    pub const fn from_hz(hz: f64) -> Self {
        let m = crate::const_math::round(hz * 1000.0);
        Self(if m >= u32::MAX as f64 {
            u32::MAX
        } else if m > 0.0 {
            m as u32
        } else {
            0
        })
    }

    /// The rate in hertz.
    pub const fn hz(self) -> f64 {
        self.0 as f64 / 1000.0
    }

    /// The rate in hertz, as `f32` (recordings' and trials' `rate_hz`).
    pub const fn hz_f32(self) -> f32 {
        self.0 as f32 / 1000.0
    }
}

/// `16.7 Hz`, `40 Hz`: the shortest decimal hertz.
impl core::fmt::Display for Millihertz {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (whole, milli) = (self.0 / 1000, self.0 % 1000);
        if milli == 0 {
            write!(f, "{whole} Hz")
        } else if milli % 100 == 0 {
            write!(f, "{whole}.{} Hz", milli / 100)
        } else if milli % 10 == 0 {
            write!(f, "{whole}.{:02} Hz", milli / 10)
        } else {
            write!(f, "{whole}.{milli:03} Hz")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn millihertz_from_hertz_and_shown_in_hertz() {
        assert_eq!(Millihertz::from_hz(16.7), Millihertz(16_700));
        assert_eq!(Millihertz::from_hz(f64::from(16.7f32)), Millihertz(16_700));
        assert_eq!(Millihertz::from_hz(70.9996), Millihertz(71_000));
        assert_eq!(Millihertz::from_hz(-3.0), Millihertz(0));
        assert_eq!(Millihertz::from_hz(f64::NAN), Millihertz(0));
        assert_eq!(Millihertz::from_hz(1e12), Millihertz(u32::MAX));
        assert_eq!(Millihertz(16_700).hz(), 16.7);
        let shown = [16_700, 40_000, 71_000, 17_750, 1, 25_125].map(|m| Millihertz(m).to_string());
        assert_eq!(
            shown,
            [
                "16.7 Hz",
                "40 Hz",
                "71 Hz",
                "17.75 Hz",
                "0.001 Hz",
                "25.125 Hz"
            ]
        );
    }
}
