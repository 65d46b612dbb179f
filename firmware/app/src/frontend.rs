//! The sampling front end: raw ADC scans in, one [`FrameInput`] per model period out.
//!
//! A scan is one code per channel (the order of the ADC's regular sequence). The front end runs
//! each channel's [`FaultDetector`] on the raw codes and its [`Decimator`] (anti-alias FIR,
//! ÷[`RATIO`]); every [`RATIO`] scans it closes a frame. It keeps the frame index, the sample
//! clock from which timestamps are derived (so they do not depend on when the CPU got round to
//! the frame).

use crate::MAX_CHANNELS;
use crate::decimate::{Decimator, OUT_FRAC_BITS, RATIO};
use crate::fault::FaultDetector;
use crate::profile::{AdcCode, Profile};

/// One model period's worth of input for every channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameInput {
    /// Frame index since boot (0, 1, …): the sample clock.
    pub index: u32,
    /// Filtered, decimated value per channel, 1/16 ADC counts.
    pub value_q4: [i32; MAX_CHANNELS],
    /// Bit c set: channel c is faulted in this frame.
    pub fault: u16,
    /// Fault kinds per channel ([`crate::fault::kind`]).
    pub kinds: [u8; MAX_CHANNELS],
}

/// Decimators and fault detectors of all channels (about 50 bytes per channel).
#[derive(Clone, Debug)]
pub struct Frontend {
    profile: Profile,
    dec: [Decimator; MAX_CHANNELS],
    det: [FaultDetector; MAX_CHANNELS],
    primed: bool,
    index: u32,
}

impl Frontend {
    /// A front end for `profile`.
    pub const fn new(profile: Profile) -> Self {
        Self {
            profile,
            dec: [Decimator::new(); MAX_CHANNELS],
            det: [FaultDetector::new(); MAX_CHANNELS],
            primed: false,
            index: 0,
        }
    }

    /// The profile.
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// Frames produced so far.
    pub fn frames(&self) -> u32 {
        self.index
    }

    /// Feeds one scan (`scan.len()` ≥ channels; extra codes are ignored, missing ones read 0).
    /// Returns a frame every [`RATIO`] scans.
    pub fn push_scan(&mut self, scan: &[AdcCode]) -> Option<FrameInput> {
        let n = self.profile.channels.min(MAX_CHANNELS);
        if !self.primed {
            self.primed = true;
            for c in 0..n {
                let x = scan.get(c).copied().unwrap_or_default();
                self.dec[c].prime(x.0 as i32);
            }
        }
        let mut out = None;
        for c in 0..n {
            let x = scan.get(c).copied().unwrap_or_default();
            self.det[c].push(&self.profile, x);
            if let Some(y) = self.dec[c].push(x.0 as i32) {
                out.get_or_insert([0i32; MAX_CHANNELS])[c] = y;
            }
        }
        let value_q4 = out?;
        let mut input = FrameInput {
            index: self.index,
            value_q4,
            fault: 0,
            kinds: [0; MAX_CHANNELS],
        };
        for c in 0..n {
            let k = self.det[c].end_frame(&self.profile);
            input.kinds[c] = k;
            if k != 0 {
                input.fault |= 1 << c;
            }
        }
        self.index = self.index.wrapping_add(1);
        Some(input)
    }

    /// Feeds a block of interleaved scans (the ring-buffered DMA's half buffer); calls `emit`
    /// for every completed frame. A trailing partial scan is ignored (the DMA block length is a
    /// multiple of the channel count).
    pub fn push_block(&mut self, block: &[AdcCode], mut emit: impl FnMut(FrameInput)) {
        let n = self.profile.channels.max(1);
        for scan in block.chunks_exact(n) {
            if let Some(f) = self.push_scan(scan) {
                emit(f);
            }
        }
    }
}

/// Scans per frame (decimation ratio), re-exported for the board layers.
pub const SCANS_PER_FRAME: usize = RATIO;
/// Fractional bits of [`FrameInput::value_q4`].
pub const VALUE_FRAC_BITS: u32 = OUT_FRAC_BITS;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_frame_per_ratio_scans_with_faults() {
        let p = Profile::HAND;
        let mut f = Frontend::new(p);
        let mut frames = Vec::new();
        for i in 0..RATIO * 5 {
            let mut scan = [AdcCode(1000 + (i % 2) as u16); 16];
            scan[3] = AdcCode(0); // disconnected
            if let Some(fr) = f.push_scan(&scan) {
                frames.push(fr);
            }
        }
        assert_eq!(frames.len(), 5);
        assert_eq!(frames[4].index, 4);
        assert!(frames.iter().all(|fr| fr.fault == 1 << 3));
        // Primed: even the first frame is at the level (1000.5 counts ± filter ripple).
        assert!(
            (frames[0].value_q4[0] - 16008).abs() <= 8,
            "{}",
            frames[0].value_q4[0]
        );
        // push_block gives the same frames.
        let mut g = Frontend::new(p);
        let mut block = Vec::new();
        for i in 0..RATIO * 5 {
            let mut scan = [AdcCode(1000 + (i % 2) as u16); 16];
            scan[3] = AdcCode(0);
            block.extend_from_slice(&scan);
        }
        let mut frames2 = Vec::new();
        g.push_block(&block, |fr| frames2.push(fr));
        assert_eq!(frames, frames2);
    }
}
