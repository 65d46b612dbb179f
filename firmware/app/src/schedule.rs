//! Frame timing: the sample clock, per-frame deadlines and the overrun / skipped counters.
//!
//! A frame's input is complete when the ADC has delivered its last scan (time `available`).
//! Its deadline is one model period later, when the next frame's input is complete: a frame
//! finished after that is **late** (still sent, with the LATE status bit, and counted in
//! `overruns`). A frame whose input could not even be queued for inference (the queue was full
//! because inference fell more than a frame behind), or whose output could not be queued for the
//! UART, is **skipped** and counted in `skipped`. Both counters go out in every flag frame, so
//! no frame is ever lost silently; sequence numbers cover transmission losses.

use slipguard_core::units::Millihertz;

/// Deadline accounting for one model rate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Deadline {
    /// Model period, µs (rounded down).
    pub period_us: u32,
}

impl Deadline {
    /// For a model rate in mHz.
    pub const fn for_rate_mhz(rate_mhz: Millihertz) -> Self {
        let r = if rate_mhz.0 == 0 {
            1
        } else {
            rate_mhz.0 as u64
        };
        Self {
            period_us: (1_000_000_000u64 / r) as u32,
        }
    }

    /// Whether a frame whose input was complete at `available_us` and that finished at
    /// `done_us` (same clock) missed its deadline.
    pub fn is_late(&self, available_us: u64, done_us: u64) -> bool {
        done_us.saturating_sub(available_us) > self.period_us as u64
    }
}

/// Time of the last sample of frame `index` in µs since the first scan, from the sample clock,
/// wrapping at 2^32 (71.6 minutes).
pub fn frame_timestamp_us(index: u32, rate_mhz: Millihertz) -> u32 {
    let r = if rate_mhz.0 == 0 {
        1
    } else {
        rate_mhz.0 as u64
    };
    ((index as u64 + 1) * 1_000_000_000 / r) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadlines_and_timestamps() {
        let d = Deadline::for_rate_mhz(Millihertz(16_700));
        assert_eq!(d.period_us, 59_880);
        assert!(!d.is_late(1000, 1000 + 59_880));
        assert!(d.is_late(1000, 1000 + 59_881));
        assert!(!d.is_late(5000, 10)); // clock oddities never count as late
        assert_eq!(frame_timestamp_us(0, Millihertz(16_700)), 59_880);
        assert_eq!(frame_timestamp_us(166, Millihertz(16_700)), 10_000_000);
        assert_eq!(frame_timestamp_us(39, Millihertz(40_000)), 1_000_000);
    }
}
