//! Features: what the LSTM sees at each step (in progress).
pub mod stft;

/// Most STFT bands a model may use.
pub const MAX_BANDS: usize = 16;
