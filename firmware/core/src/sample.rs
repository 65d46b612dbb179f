//! Sample stage: a raw sensor reading (mN, or converter counts) to the model's Q1.15 input.

use crate::blob::ModelConfig;
use crate::units::Millihertz;

/// The paper's sample rate: the paper and its dataset (eagle-shoal) state 16.7 Hz for their
/// 60 ms step (exactly 1/0.06 s = 16.667 Hz). Every blob, recording and figure made at the
/// paper's rate carries this value, so it stays 16 700 mHz.
pub const PAPER_RATE_MHZ: Millihertz = Millihertz(16_700);

/// [`PAPER_RATE_MHZ`] in Hz, as the host tools and recordings write it.
pub const PAPER_RATE_HZ: f32 = PAPER_RATE_MHZ.hz_f32();

/// The blob's input scaling: `x = (raw - offset) / full_scale`, saturated to Q1.15.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputScale {
    /// Raw value that maps to 0 (sensor units, e.g. mN or counts).
    pub offset: i32,
    /// Raw span that maps to +1.0 (sensor units), > 0.
    pub full_scale: i32,
}

impl InputScale {
    /// The scaling a model was trained with.
    pub fn of(config: &ModelConfig) -> Self {
        Self {
            offset: config.input_offset,
            full_scale: config.input_full_scale.max(1),
        }
    }

    /// Raw reading → Q1.15 (+1.0 = `full_scale` sensor units above `offset`), rounded toward
    /// zero and saturated, so a sensor over its nominal range reads as full scale, never wraps.
    #[inline]
    pub fn to_q15(&self, raw: i32) -> i16 {
        // i64: (raw - offset) · 2^15 needs up to 48 bits. The `<< 15` makes the quotient Q1.15.
        let num = (raw as i64 - self.offset as i64) << 15;
        crate::fixed::sat_i16_wide(num / self.full_scale.max(1) as i64)
    }

    /// The float reference's view of the same mapping (clamped to the Q1.15 range).
    pub fn to_real(&self, raw: f32) -> f32 {
        ((raw - self.offset as f32) / self.full_scale.max(1) as f32).clamp(-1.0, 32767.0 / 32768.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scales_and_saturates() {
        let s = InputScale {
            offset: 0,
            full_scale: 10_000,
        };
        assert_eq!(s.to_q15(5_000), 16384);
        assert_eq!(s.to_q15(10_000), i16::MAX);
        assert_eq!(s.to_q15(33_367), i16::MAX);
        assert_eq!(s.to_q15(-20_000), i16::MIN);
        assert_eq!(s.to_q15(1), 3); // 3.2768 rounded toward zero
        let p = InputScale {
            offset: 6400,
            full_scale: 4096,
        };
        assert_eq!(p.to_q15(6400 - 2048), -16384);
        assert_eq!(p.to_q15(i32::MIN), i16::MIN);
        assert_eq!(
            InputScale {
                offset: i32::MIN,
                full_scale: 1
            }
            .to_q15(i32::MAX),
            i16::MAX
        );
    }
}
