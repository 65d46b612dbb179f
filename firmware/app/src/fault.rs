//! Per-channel sensor fault detection on the raw ADC codes, before the filter:
//!
//! - **disconnected**: the code stays below the profile's live zero band
//!   ([`Profile::disconnected_below`]) for [`Profile::debounce_scans`] scans (open wire: the
//!   conditioning amplifier's offset is missing);
//! - **saturated**: the code stays at or above [`Profile::saturated_at`] as long (amplifier at
//!   its rail, force over range);
//! - **stuck**: exactly the same code for [`Profile::stuck_periods`] model periods (a live
//!   sensor and ADC always show at least an LSB of noise; a frozen multiplexer or a shorted
//!   input does not).
//!
//! A channel is faulted in a frame if any condition held at any scan of the frame or ended less
//! than [`Profile::fault_hold_periods`] frames ago. Faulted channels are reported in the fault
//! mask and not predicted on; their model state is reset when they come back.

use crate::decimate::RATIO;
use crate::profile::{AdcCode, Profile};

/// Fault kind bits.
pub mod kind {
    /// Open input.
    pub const DISCONNECTED: u8 = 1 << 0;
    /// Input at the rail.
    pub const SATURATED: u8 = 1 << 1;
    /// Input frozen.
    pub const STUCK: u8 = 1 << 2;
}

/// One channel's detector (12 bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultDetector {
    low_run: u16,
    high_run: u16,
    same_run: u32,
    last: AdcCode,
    /// Kinds seen during the current frame.
    seen: u8,
    /// Kinds reported last frame (for logs).
    reported: u8,
    /// Frames left to hold the fault.
    hold: u16,
}

impl FaultDetector {
    /// A detector with no history.
    pub const fn new() -> Self {
        Self {
            low_run: 0,
            high_run: 0,
            same_run: 0,
            last: AdcCode(u16::MAX),
            seen: 0,
            reported: 0,
            hold: 0,
        }
    }

    /// Feeds one raw code.
    #[inline]
    pub fn push(&mut self, p: &Profile, code: AdcCode) {
        self.low_run = if code < p.disconnected_below {
            self.low_run.saturating_add(1)
        } else {
            0
        };
        self.high_run = if code >= p.saturated_at {
            self.high_run.saturating_add(1)
        } else {
            0
        };
        self.same_run = if code == self.last {
            self.same_run.saturating_add(1)
        } else {
            0
        };
        self.last = code;
        if self.low_run >= p.debounce_scans {
            self.seen |= kind::DISCONNECTED;
        }
        if self.high_run >= p.debounce_scans {
            self.seen |= kind::SATURATED;
        }
        if self.same_run >= p.stuck_periods as u32 * RATIO as u32 {
            self.seen |= kind::STUCK;
        }
    }

    /// Ends a frame: returns the fault kinds to report for it (0 = healthy).
    pub fn end_frame(&mut self, p: &Profile) -> u8 {
        let seen = core::mem::take(&mut self.seen);
        if seen != 0 {
            self.hold = p.fault_hold_periods;
            self.reported = seen;
            seen
        } else if self.hold > 0 {
            self.hold -= 1;
            self.reported.max(1)
        } else {
            self.reported = 0;
            0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(p: &Profile, codes: impl IntoIterator<Item = u16>) -> Vec<u8> {
        let mut d = FaultDetector::new();
        let mut out = Vec::new();
        for (i, c) in codes.into_iter().enumerate() {
            d.push(p, AdcCode(c));
            if (i + 1) % RATIO == 0 {
                out.push(d.end_frame(p));
            }
        }
        out
    }

    #[test]
    fn detects_each_fault_and_holds_it() {
        let p = Profile::HAND;
        // Noisy healthy signal: never a fault.
        let healthy = (0..RATIO * 100).map(|i| 124 + (i % 3) as u16);
        assert!(run(&p, healthy).iter().all(|&k| k == 0));
        // Open wire for 2 frames, then healthy: faulted 2 + hold frames.
        let codes = (0..RATIO * 20).map(|i| {
            if (RATIO..3 * RATIO).contains(&i) {
                3
            } else {
                500 + (i % 2) as u16
            }
        });
        let k = run(&p, codes);
        assert_eq!(k[0], 0);
        assert_eq!(k[1], kind::DISCONNECTED);
        assert_eq!(k[2], kind::DISCONNECTED);
        let faulted = k.iter().filter(|&&x| x != 0).count();
        assert_eq!(faulted, 2 + p.fault_hold_periods as usize);
        // A short glitch (below the debounce) is not a fault.
        let codes = (0..RATIO * 4).map(|i| if i == 20 { 4095 } else { 900 + (i % 2) as u16 });
        assert!(run(&p, codes).iter().all(|&k| k == 0));
        // Saturation.
        let k = run(&p, (0..RATIO * 2).map(|_| 4095));
        assert_eq!(k[0] & kind::SATURATED, kind::SATURATED);
        // Stuck: a constant mid-range code for the stuck time.
        let n = p.stuck_periods as usize + 2;
        let k = run(&p, (0..RATIO * n).map(|_| 2000));
        assert_eq!(k[p.stuck_periods as usize - 2], 0);
        assert_eq!(k[n - 1], kind::STUCK);
    }
}
