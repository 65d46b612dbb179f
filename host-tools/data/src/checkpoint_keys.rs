//! Keys of the model settings as checkpoint `__metadata__` and the exporter's settings write
//! them (docs/checkpoint.md, docs/export.md): one list for the trainer (`slipguard-learn`,
//! which writes and reads checkpoints) and the exporter (`slipguard-export`, which reads them
//! and its own settings files). Host-only file vocabulary: here, in the crate both stand on,
//! rather than in the `no_std` core (the board never sees a checkpoint) or in either of them
//! (the exporter must not depend on the trainer's ML stack, and the trainer need not carry the
//! exporter's importers). The values the keys name parse with the core's model vocabulary
//! (`Variant`, `InputUnit`, `WindowShape` in `slipguard_core::blob`).

/// Settings format version, `"1"`.
pub const FORMAT: &str = "slipguard.format";
/// Model name (≤ 12 ASCII characters go into the blob header).
pub const NAME: &str = "name";
/// `lstm`, `stft-lstm`, `data-stft-lstm` or `lstm-stft-lstm`.
pub const VARIANT: &str = "variant";
/// `"true"` when d(t) = x(t) − x(t−1) is an input.
pub const FORCE_DIFF: &str = "force_diff";
/// Sample rate in Hz, e.g. `"16.7"`.
pub const SAMPLE_RATE_HZ: &str = "sample_rate_hz";
/// `mN` or `counts`.
pub const INPUT_UNIT: &str = "input_unit";
/// Raw value mapped to 0.
pub const INPUT_OFFSET: &str = "input_offset";
/// Raw span mapped to +1.0.
pub const INPUT_FULL_SCALE: &str = "input_full_scale";
/// STFT window length N in samples.
pub const STFT_WINDOW_LEN: &str = "stft_window";
/// First DFT bin used.
pub const STFT_FIRST_BIN: &str = "stft_first_bin";
/// Number of bins (bands).
pub const STFT_N_BINS: &str = "stft_bins";
/// `rectangular` or `hann`.
pub const STFT_WINDOW: &str = "stft_shape";
/// Hidden sizes, comma separated (`"128"`, or `"64,64"` for the dual variant); informative,
/// the reader takes them from the tensor shapes.
pub const HIDDEN: &str = "hidden";
/// Decision threshold on p(unstable), e.g. `"0.5"`.
pub const THRESHOLD: &str = "threshold";
/// Consecutive steps ≥ threshold before the flag rises.
pub const RAISE_AFTER: &str = "raise_after";
/// Consecutive steps < threshold before the flag clears.
pub const CLEAR_AFTER: &str = "clear_after";
/// JSON array of the feature means (Q1.15 units as reals), order [force, d(t), bands].
pub const NORM_MEAN: &str = "norm_mean";
/// JSON array of the feature standard deviations.
pub const NORM_STD: &str = "norm_std";
/// The hand rule's strict fraction of the recent peak (0…1; 0 = the rule never flags
/// alone): with [`HAND_RULE_GUARD`] and [`HAND_RULE_WINDOW_S`] the blob's hand rule
/// ([`slipguard_core::blob::ModelConfig::hand_rule`], format v2). Absent: no rule (format v1).
pub const HAND_RULE_FRACTION: &str = "hand_rule_fraction";
/// The hand rule's guard fraction (0…1; 1 = no guard: every model flag counts).
pub const HAND_RULE_GUARD: &str = "hand_rule_guard";
/// The hand rule's peak window, seconds (1 to 64 frames at the model's rate).
pub const HAND_RULE_WINDOW_S: &str = "hand_rule_window_s";
