//! Temporary minimal STFT with the agreed API (replaced by the full module).
#![allow(missing_docs)]
use crate::const_math;
pub const MAX_WINDOW: usize = 48;
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum WindowShape {
    Rectangular = 0,
    Hann = 1,
}
impl TryFrom<u8> for WindowShape {
    type Error = StftError;
    fn try_from(v: u8) -> Result<Self, StftError> {
        match v {
            0 => Ok(Self::Rectangular),
            1 => Ok(Self::Hann),
            _ => Err(StftError::BadShape),
        }
    }
}
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StftConfig {
    pub window_len: u8,
    pub first_bin: u8,
    pub n_bins: u8,
    pub shape: WindowShape,
}
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum StftError {
    BadWindow,
    BadBins,
    BadShape,
}
impl core::fmt::Display for StftError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{self:?}")
    }
}
impl StftConfig {
    pub const PAPER: StftConfig = StftConfig {
        window_len: 20,
        first_bin: 1,
        n_bins: 10,
        shape: WindowShape::Rectangular,
    };
    pub fn validate(&self) -> Result<(), StftError> {
        if self.window_len < 4 || self.window_len as usize > MAX_WINDOW {
            return Err(StftError::BadWindow);
        }
        if self.n_bins == 0
            || self.n_bins as usize > super::MAX_BANDS
            || (self.first_bin + self.n_bins - 1) > self.window_len / 2
        {
            return Err(StftError::BadBins);
        }
        Ok(())
    }
}
#[derive(Clone, Debug)]
pub struct StftPlan {
    config: StftConfig,
    cos: [i32; MAX_WINDOW],
    sin: [i32; MAX_WINDOW],
}
impl StftPlan {
    pub fn new(config: StftConfig) -> Result<Self, StftError> {
        config.validate()?;
        let n = config.window_len as u32;
        let mut cos = [0; MAX_WINDOW];
        let mut sin = [0; MAX_WINDOW];
        for m in 0..n {
            let (c, s) = const_math::cos_sin_turn(m, n);
            cos[m as usize] = const_math::round(c * 32768.0) as i32;
            sin[m as usize] = const_math::round(s * 32768.0) as i32;
        }
        Ok(Self { config, cos, sin })
    }
    pub fn config(&self) -> StftConfig {
        self.config
    }
    pub fn step(&self, state: &mut StftState, x: i16, out: &mut [i16]) {
        let n = self.config.window_len as usize;
        state.ring[state.head as usize % MAX_WINDOW] = x;
        state.head = ((state.head as usize + 1) % n) as u8;
        for (b, o) in out.iter_mut().take(self.config.n_bins as usize).enumerate() {
            let k = self.config.first_bin as usize + b;
            let (mut re, mut im) = (0i64, 0i64);
            for i in 0..n {
                let v = state.ring[(state.head as usize + i) % n] as i64;
                let m = (k * i) % n;
                re += v * self.cos[m] as i64;
                im -= v * self.sin[m] as i64;
            }
            let re = re >> 15;
            let im = im >> 15;
            let mag = isqrt((re * re + im * im) as u64) as i64;
            *o = crate::fixed::sat_i16_wide(mag / n as i64);
        }
    }
}
fn isqrt(v: u64) -> u64 {
    let mut r: u64 = 0;
    let mut bit = 1u64 << 62;
    let mut x = v;
    while bit > x {
        bit >>= 2;
    }
    while bit != 0 {
        if x >= r + bit {
            x -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return r;
    while r * r > v {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= v {
        r += 1;
    }
    r
}
#[derive(Clone, Debug)]
pub struct StftState {
    ring: [i16; MAX_WINDOW],
    head: u8,
}
impl StftState {
    pub const fn new() -> Self {
        Self {
            ring: [0; MAX_WINDOW],
            head: 0,
        }
    }
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}
impl Default for StftState {
    fn default() -> Self {
        Self::new()
    }
}
