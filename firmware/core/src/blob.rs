//! Model blob formats v1, v2 and v3: parsed zero-copy from `&[u8]` (flash on the target, an aligned
//! buffer on the host). The byte-by-byte layout is in `docs/model-format.md`; this module is its
//! only parser and (behind `std`) its only writer.
//!
//! Layout: a 64-byte header, a tensor directory of 16-byte entries, the tensors (each at a
//! 4-byte aligned offset), and a CRC-32 (ISO-HDLC, as zlib's `crc32`) of everything before it.
//! Version 2 is version 1 plus one more tensor, the hand-rule record ([`TensorKind::HandRule`]:
//! the fused hand decision [`FusedHand`]); a model without a rule is written as version 1.
//! Version 3 is version 2's layout for the hand-level variant ([`Variant::HandLstm`], one LSTM
//! over the hand features of [`crate::features::hand`]), which versions 1 and 2 do not define:
//! a v3 blob holds that variant and its hand-rule record, nothing else.
//! All integers are little-endian. The blob must start at a 4-byte aligned address so that the
//! `i32` tables can be read in place.
//!
//! Every malformed blob returns its own [`BlobError`]; nothing here panics on data.

use bytemuck::{Pod, Zeroable};

use crate::features::FeatureLayout;
use crate::features::hand::HAND_FEATURES;
use crate::features::stft::{StftConfig, StftError, WindowShape};
use crate::load_rule::{FusedHand, LOAD_WINDOW_MAX, LoadRule};
use crate::units::Millihertz;
use crate::{MAX_HIDDEN, MAX_INPUT};

/// First four bytes of every blob.
pub const MAGIC: [u8; 4] = *b"SGMB";
/// First four bytes of a *RAM image* of a blob ([`crate::model_ram::ModelRam::load`]): the
/// blob with magic `SGMI`, its LSTM weight tensors in the blocked layout of
/// [`crate::dsp::pack_lstm_blocks`] (same length), its own CRC-32 still in place (the model's
/// fingerprint, checked on the source before the copy), followed by 4 bytes: the CRC-32 of the
/// image's first `total length` bytes. Built in RAM, never written to flash or sent.
pub const IMAGE_MAGIC: [u8; 4] = *b"SGMI";
/// The newest format version this parser reads (it reads every version from
/// [`VERSION_1`]): a hand-level model ([`Variant::HandLstm`]) with its hand rule.
pub const VERSION: u16 = 3;
/// The version of a per-channel model with a hand rule ([`ModelConfig::hand_rule`]).
pub const VERSION_2: u16 = 2;
/// The version of a blob without a hand rule (the writer still writes it, byte for byte).
pub const VERSION_1: u16 = 1;
/// Size of the fixed header.
pub const HEADER_LEN: usize = 64;
/// Size of one tensor directory entry.
pub const DIR_ENTRY_LEN: usize = 16;
/// Size of the trailing CRC.
pub const CRC_LEN: usize = 4;
/// Most tensors a blob can hold (feature norm, 2 × LSTM weights and row params, dense weights
/// and params, and in v2 the hand-rule record).
pub const MAX_TENSORS: usize = 8;
/// The CRC used by the blob (CRC-32/ISO-HDLC: zlib, PNG, Ethernet).
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Which network the blob holds: one of the paper's four (Fig. 5), run per channel, or the
/// hand-level LSTM over all contact channels together. One name each: the enum variant
/// is the paper's name, [`Variant::name`] its spelling in the CLIs, checkpoints, settings and
/// JSON; the paper's letters (`a` … `d`, [`Variant::letter`]) are accepted as aliases at the
/// command-line edge only ([`Variant::from_letter`]). Every `match` on it is exhaustive, so a
/// new variant stops the compiler at each place that must say what it does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Variant {
    /// (a) LSTM on the force.
    Lstm = 0,
    /// (b) STFT & LSTM: LSTM on the STFT bands.
    StftLstm = 1,
    /// (c) (Data + STFT) & LSTM: one LSTM on the force and the bands.
    DataStftLstm = 2,
    /// (d) LSTM + STFT & LSTM: a force LSTM and a band LSTM, hidden states concatenated into the dense layer.
    LstmStftLstm = 3,
    /// Hand-level LSTM (not the paper's): one LSTM per hand over the hand features of all
    /// contact channels together ([`crate::features::hand`], including the STFT of the hand's
    /// load), one p(unstable) per frame. Format v3 only.
    HandLstm = 4,
}

impl Variant {
    /// All variants, in format order.
    pub const ALL: [Variant; 5] = [
        Self::Lstm,
        Self::StftLstm,
        Self::DataStftLstm,
        Self::LstmStftLstm,
        Self::HandLstm,
    ];

    /// The paper's four, the variants that run one network per channel.
    pub const PER_CHANNEL: [Variant; 4] = [
        Self::Lstm,
        Self::StftLstm,
        Self::DataStftLstm,
        Self::LstmStftLstm,
    ];

    /// Decodes the header byte.
    pub fn from_u8(v: u8) -> Option<Self> {
        Self::ALL.get(v as usize).copied()
    }
    /// Whether the network sees the force sample (and d(t) when enabled).
    pub fn uses_force(self) -> bool {
        match self {
            Self::Lstm | Self::DataStftLstm | Self::LstmStftLstm => true,
            Self::StftLstm | Self::HandLstm => false,
        }
    }
    /// Whether one network runs per hand over all contact channels (else one per channel).
    pub fn is_hand(self) -> bool {
        match self {
            Self::HandLstm => true,
            Self::Lstm | Self::StftLstm | Self::DataStftLstm | Self::LstmStftLstm => false,
        }
    }
    /// Whether the blob's STFT setting is used: the channel's bands, or for the hand-level
    /// variant the STFT of the hand load (its band-share feature).
    pub fn uses_bands(self) -> bool {
        match self {
            Self::StftLstm | Self::DataStftLstm | Self::LstmStftLstm | Self::HandLstm => true,
            Self::Lstm => false,
        }
    }
    /// Number of LSTMs.
    pub fn lstm_count(self) -> usize {
        match self {
            Self::Lstm | Self::StftLstm | Self::DataStftLstm | Self::HandLstm => 1,
            Self::LstmStftLstm => 2,
        }
    }
    /// The variant's one name: CLIs, checkpoints, exporter settings, JSON, tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Lstm => "lstm",
            Self::StftLstm => "stft-lstm",
            Self::DataStftLstm => "data-stft-lstm",
            Self::LstmStftLstm => "lstm-stft-lstm",
            Self::HandLstm => "hand-lstm",
        }
    }
    /// The paper's letter for the variant (Fig. 5: (a) to (d)); `h` for the hand-level
    /// variant, which is not the paper's.
    pub fn letter(self) -> char {
        match self {
            Self::Lstm => 'a',
            Self::StftLstm => 'b',
            Self::DataStftLstm => 'c',
            Self::LstmStftLstm => 'd',
            Self::HandLstm => 'h',
        }
    }
    /// The variant of a paper's letter as a command line gives it (`c` or `(c)`): the CLIs'
    /// alias, not a name ([`FromStr`](core::str::FromStr) takes [`Variant::name`] only).
    pub fn from_letter(s: &str) -> Option<Self> {
        let s = s.trim();
        let l = s
            .strip_prefix('(')
            .and_then(|s| s.strip_suffix(')'))
            .unwrap_or(s);
        Self::ALL.into_iter().find(|v| l.chars().eq([v.letter()]))
    }

    /// A command line's variant: [`Variant::name`] or the paper's letter ([`Variant::from_letter`]).
    pub fn from_cli(s: &str) -> Result<Self, UnknownName> {
        Self::from_letter(s).map_or_else(|| s.trim().parse(), Ok)
    }
}

/// Unit of the raw samples the blob's input scaling expects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum InputUnit {
    /// Force in millinewtons (fingertip sensors).
    MilliNewton = 0,
    /// Raw converter counts (e.g. 16-bit suction pressure).
    Counts = 1,
}

/// A name that is not one of the model vocabulary's: [`Variant`], [`InputUnit`] or
/// [`WindowShape`], as the CLIs, checkpoint metadata and exporter settings write them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UnknownName {
    /// What was being named ("variant", "input unit", "STFT window").
    pub what: &'static str,
    /// The accepted names, comma-separated.
    pub expected: &'static str,
}

impl core::fmt::Display for UnknownName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "unknown {} (expected {})", self.what, self.expected)
    }
}

#[cfg(feature = "std")]
impl std::error::Error for UnknownName {}

impl core::fmt::Display for Variant {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for Variant {
    type Err = UnknownName;

    /// Parses [`Variant::name`] (the CLIs also take the paper's letter: [`Variant::from_cli`]).
    fn from_str(s: &str) -> Result<Self, UnknownName> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s.trim())
            .ok_or(UnknownName {
                what: "variant",
                expected: "lstm, stft-lstm, data-stft-lstm, lstm-stft-lstm, hand-lstm (on a command line also a, b, c, d, h)",
            })
    }
}

impl InputUnit {
    /// Name used by the CLIs, checkpoints and exporter settings.
    pub fn name(self) -> &'static str {
        match self {
            Self::MilliNewton => "mN",
            Self::Counts => "counts",
        }
    }
}

impl core::fmt::Display for InputUnit {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for InputUnit {
    type Err = UnknownName;

    /// Parses [`InputUnit::name`].
    fn from_str(s: &str) -> Result<Self, UnknownName> {
        [Self::MilliNewton, Self::Counts]
            .into_iter()
            .find(|u| u.name() == s.trim())
            .ok_or(UnknownName {
                what: "input unit",
                expected: "mN, counts",
            })
    }
}

impl core::fmt::Display for WindowShape {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            WindowShape::Rectangular => "rectangular",
            WindowShape::Hann => "hann",
        })
    }
}

impl core::str::FromStr for WindowShape {
    type Err = UnknownName;

    /// Parses `rectangular` or `hann` (the [`Display`](core::fmt::Display) names).
    fn from_str(s: &str) -> Result<Self, UnknownName> {
        match s.trim() {
            "rectangular" => Ok(WindowShape::Rectangular),
            "hann" => Ok(WindowShape::Hann),
            _ => Err(UnknownName {
                what: "STFT window",
                expected: "rectangular, hann",
            }),
        }
    }
}

/// Flag bits of header byte 17.
pub mod flags {
    /// The force difference d(t) = x(t) - x(t-1) (paper eq. 3) is an input of the force LSTM.
    pub const FORCE_DIFF: u8 = 1 << 0;
    /// All bits v1 defines.
    pub const KNOWN: u8 = FORCE_DIFF;
}

/// Everything in the header except the tensor sizes: what the firmware and host tools need to
/// run and describe the model. Shared by the quantized blob and the float reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ModelConfig {
    /// Identifier chosen by the exporter (e.g. a hash of the float weights).
    pub model_id: u32,
    /// Short ASCII name, zero padded.
    pub name: [u8; 12],
    /// Network variant.
    pub variant: Variant,
    /// Whether d(t) is an input of the force LSTM.
    pub force_diff: bool,
    /// Sample rate the model was trained at (header: u32 millihertz, 16 700 = 16.7 Hz).
    pub sample_rate_mhz: Millihertz,
    /// Unit of raw samples.
    pub input_unit: InputUnit,
    /// Raw value (in `input_unit`) that maps to 0 in the Q1.15 input.
    pub input_offset: i32,
    /// Raw span (in `input_unit`) that maps to +1.0 in the Q1.15 input; > 0.
    pub input_full_scale: i32,
    /// STFT settings; all zero for [`Variant::Lstm`].
    pub stft: StftConfig,
    /// Hidden size of each LSTM (second is 0 unless [`Variant::LstmStftLstm`]).
    pub hidden: [u16; 2],
    /// Cell state format of each LSTM: c is Q(15-C).C with C = this (1..=15).
    pub cell_frac_bits: [u8; 2],
    /// Decision threshold on p(unstable), Q0.15 (1..=32767).
    pub threshold_q15: u16,
    /// Consecutive steps at or above the threshold before the flag rises (>= 1).
    pub raise_after: u8,
    /// Consecutive steps below the threshold before the flag clears (>= 1).
    pub clear_after: u8,
    /// The fused hand decision the firmware runs in place of the model's hand flag alone
    /// (format v2's hand-rule record); `None` in a v1 blob: the model's hand flag as it is.
    pub hand_rule: Option<FusedHand>,
}

impl ModelConfig {
    /// The features per step this header describes.
    /// (The hand-level variant has no per-channel features: an empty layout.)
    pub fn feature_layout(&self) -> FeatureLayout {
        if self.variant.is_hand() {
            return FeatureLayout {
                force: false,
                diff: false,
                bands: 0,
            };
        }
        FeatureLayout {
            force: self.variant.uses_force(),
            diff: self.force_diff,
            bands: self.band_features(),
        }
    }
    /// Number of force-path features (force and d(t)) feeding the first LSTM or the shared one.
    pub fn force_features(&self) -> usize {
        if self.variant.uses_force() {
            1 + self.force_diff as usize
        } else {
            0
        }
    }
    /// Number of STFT band features (0 for the hand-level variant, whose STFT gives one
    /// feature among [`HAND_FEATURES`]).
    pub fn band_features(&self) -> usize {
        if self.variant.uses_bands() && !self.variant.is_hand() {
            self.stft.n_bins as usize
        } else {
            0
        }
    }
    /// Total features per step (rows of the normalisation table).
    pub fn feature_count(&self) -> usize {
        if self.variant.is_hand() {
            return HAND_FEATURES;
        }
        // d(t) is also allowed as the only non-band input of the STFT variant.
        let diff_only = !self.variant.uses_force() && self.force_diff;
        self.force_features() + diff_only as usize + self.band_features()
    }
    /// Input size of LSTM `k`: features are ordered [force, d(t), bands] and the dual variant
    /// splits them after the force path.
    pub fn lstm_inputs(&self, k: usize) -> usize {
        match self.variant {
            Variant::Lstm | Variant::StftLstm | Variant::DataStftLstm | Variant::HandLstm => {
                match k {
                    0 => self.feature_count(),
                    _ => 0,
                }
            }
            Variant::LstmStftLstm => match k {
                0 => self.force_features(),
                1 => self.band_features(),
                _ => 0,
            },
        }
    }
    /// Sample rate in Hz.
    pub fn sample_rate_hz(&self) -> f32 {
        self.sample_rate_mhz.hz_f32()
    }
    /// Multiply-accumulates per step in the LSTMs and the dense layer (STFT excluded): per
    /// channel in contact, or per frame for the hand-level variant.
    pub fn macs_per_step(&self) -> usize {
        let mut macs = 0;
        let mut dense_in = 0;
        for k in 0..self.variant.lstm_count() {
            let h = self.hidden[k] as usize;
            macs += 4 * h * (self.lstm_inputs(k) + h);
            dense_in += h;
        }
        macs + 2 * dense_in
    }
    /// The name as text (up to the first zero byte; non-ASCII shown as '?').
    pub fn name_str(&self) -> &str {
        let end = self
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(self.name.len());
        core::str::from_utf8(&self.name[..end]).unwrap_or("?")
    }
}

/// What a tensor holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum TensorKind {
    /// Per-feature normalisation, [`FeatureNorm`] rows.
    FeatureNorm = 1,
    /// LSTM weights, int8, 4H rows of [W_ih row (padded to 4) | W_hh row (padded to 4)].
    LstmWeights = 2,
    /// LSTM per-row requantisation, [`LstmRowParams`] rows.
    LstmRowParams = 3,
    /// Dense weights, int8, 2 rows over the (padded) concatenated hidden states.
    DenseWeights = 4,
    /// Dense per-row requantisation, [`DenseRowParams`] rows.
    DenseRowParams = 5,
    /// The hand-rule record (format v2 only): i32, 1 row × 3, `[strict_q15, guard_q15,
    /// window]` ([`hand_rule_record`]).
    HandRule = 6,
}

impl TensorKind {
    fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            1 => Self::FeatureNorm,
            2 => Self::LstmWeights,
            3 => Self::LstmRowParams,
            4 => Self::DenseWeights,
            5 => Self::DenseRowParams,
            6 => Self::HandRule,
            _ => return None,
        })
    }
}

/// Element type codes of the directory.
pub mod dtype {
    /// Signed 8-bit.
    pub const I8: u8 = 1;
    /// Signed 32-bit little-endian.
    pub const I32: u8 = 2;
}

/// The feature-norm tensor's element (defined with the front end that applies it).
pub use crate::features::FeatureNorm;

/// Largest |bias_q12| of a folded row ([`crate::lstm::fold_row`]): with it the 64-bit sum's
/// high word cannot overflow (see `lstm::requant_folded`).
pub const FOLDED_ADDEND_MAX: i64 = 1 << 30;

/// An LSTM row-parameter tensor's element (defined with the kernels that apply it).
pub use crate::dsp::LstmRowParams;

/// Per-row requantisation of one dense output: `logit_q12 = round(acc·m / 2^shift) + bias_q12`
/// with `acc = Σ w·h` (h Q0.15) and m = s·2^(shift-3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct DenseRowParams {
    /// Weight multiplier.
    pub m: i32,
    /// Bias, Q3.12 (in `i32`: a logit is not saturated before the two are subtracted).
    pub bias_q12: i32,
    /// Exponent of m, 1..=62.
    pub shift: i32,
}

/// One LSTM's tensors, borrowed from the blob.
#[derive(Clone, Copy, Debug)]
pub struct LstmTensors<'a> {
    /// Input size I.
    pub inputs: usize,
    /// Hidden size H.
    pub hidden: usize,
    /// Offset of the W_hh part inside a row: I rounded up to a multiple of 4.
    pub hh_offset: usize,
    /// Row length in bytes: hh_offset + H rounded up to a multiple of 4.
    pub row_len: usize,
    /// Cell state fractional bits C (c is Q(15-C).C).
    pub cell_frac_bits: u32,
    /// 4H rows × `row_len` int8 weights, gate order i, f, g, o (as PyTorch): row-major as in
    /// the blob, or in the blocked layout of [`crate::dsp::pack_lstm_blocks`] if `blocked`.
    pub weights: &'a [i8],
    /// `weights` are in the blocked layout (a RAM image, [`IMAGE_MAGIC`]).
    pub blocked: bool,
    /// 4H rows of requantisation parameters, same order; in a RAM image (`blocked`) in the
    /// folded form of [`crate::lstm::fold_row`] (`bias_q12` the folded addend C, `shift` d).
    pub rows: &'a [LstmRowParams],
}

/// The dense layer's tensors, borrowed from the blob.
#[derive(Clone, Copy, Debug)]
pub struct DenseTensors<'a> {
    /// Row length: the padded hidden sizes of the LSTMs, concatenated.
    pub row_len: usize,
    /// 2 rows × `row_len` int8 weights: logit of "stable" (class 0), then "unstable" (class 1).
    pub weights: &'a [i8],
    /// 2 rows of requantisation parameters.
    pub rows: &'a [DenseRowParams],
}

/// A parsed, validated model blob. Cheap to copy; borrows the bytes.
#[derive(Clone, Copy, Debug)]
pub struct ModelBlob<'a> {
    /// Header fields.
    pub config: ModelConfig,
    /// Stored CRC-32 (also the blob's fingerprint).
    pub crc: u32,
    /// Total length in bytes, CRC included.
    pub len: usize,
    /// Normalisation of each feature, in feature order [force, d(t), bands].
    pub norm: &'a [FeatureNorm],
    /// The LSTMs (the second has `hidden == 0` unless dual).
    pub lstm: [LstmTensors<'a>; 2],
    /// The dense layer.
    pub dense: DenseTensors<'a>,
}

/// Why a blob was refused. Each kind of damage has its own variant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BlobError {
    /// Fewer bytes than the header, or than the length the header declares.
    Truncated {
        /// Bytes needed.
        needed: u32,
        /// Bytes present.
        present: u32,
    },
    /// The first four bytes are not `SGMB`.
    BadMagic,
    /// A format version this firmware cannot read.
    UnsupportedVersion(u16),
    /// The header length or declared total length is impossible.
    BadLength,
    /// The CRC-32 does not match the contents.
    BadCrc {
        /// CRC stored in the blob.
        stored: u32,
        /// CRC of the bytes present.
        computed: u32,
    },
    /// The blob does not start at a 4-byte aligned address, or a tensor offset is not 4-aligned.
    Misaligned,
    /// Unknown variant byte.
    UnknownVariant(u8),
    /// Unknown or reserved flag bits, input unit, or reserved bytes not zero.
    UnknownField,
    /// A size over the static bounds (hidden > MAX_HIDDEN, inputs > MAX_INPUT, bands > MAX_BANDS).
    OverBounds,
    /// Sizes that contradict the variant (e.g. a second LSTM in a single-LSTM model).
    InconsistentSizes,
    /// STFT settings the core cannot run.
    Stft(StftError),
    /// Sample rate, input scale or decision settings out of range.
    BadSetting,
    /// A directory entry with an unknown kind or element type.
    UnknownTensor,
    /// A tensor listed twice.
    DuplicateTensor(TensorKind),
    /// A tensor the variant needs is missing.
    MissingTensor(TensorKind),
    /// A tensor whose shape, type or byte length does not match the header.
    TensorShape(TensorKind),
    /// A tensor that reaches outside the data area.
    TensorOutOfBounds(TensorKind),
    /// A requantisation shift outside 1..=62 or a cell format outside 1..=15.
    QuantParam(TensorKind),
    /// A hand-rule record out of range (fractions 0..=32 767, window 1..=[`LOAD_WINDOW_MAX`]).
    BadHandRule,
}

impl BlobError {
    /// The stable detail code and value this error is reported with on the wire (the fault
    /// reply's detail, docs/protocol.md). Exhaustive: a new variant needs its own code here.
    pub fn wire_detail(self) -> (u8, u32) {
        match self {
            BlobError::Truncated { needed, .. } => (1, needed),
            BlobError::BadMagic => (2, 0),
            BlobError::UnsupportedVersion(v) => (3, v as u32),
            BlobError::BadLength => (4, 0),
            BlobError::BadCrc { computed, .. } => (5, computed),
            BlobError::Misaligned => (6, 0),
            BlobError::UnknownVariant(v) => (7, v as u32),
            BlobError::UnknownField => (8, 0),
            BlobError::OverBounds => (9, 0),
            BlobError::InconsistentSizes => (10, 0),
            BlobError::Stft(_) => (11, 0),
            BlobError::BadSetting => (12, 0),
            BlobError::UnknownTensor => (13, 0),
            BlobError::DuplicateTensor(k) => (14, k as u32),
            BlobError::MissingTensor(k) => (15, k as u32),
            BlobError::TensorShape(k) => (16, k as u32),
            BlobError::TensorOutOfBounds(k) => (17, k as u32),
            BlobError::QuantParam(k) => (18, k as u32),
            BlobError::BadHandRule => (19, 0),
        }
    }
}

impl core::fmt::Display for BlobError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated { needed, present } => {
                write!(f, "model blob truncated: {present} bytes, need {needed}")
            }
            Self::BadMagic => write!(f, "not a slipguard model blob (magic is not SGMB)"),
            Self::UnsupportedVersion(v) => {
                write!(
                    f,
                    "model blob format version {v} is not supported (this build reads {VERSION_1} to {VERSION})"
                )
            }
            Self::BadLength => write!(f, "model blob header or total length is impossible"),
            Self::BadCrc { stored, computed } => write!(
                f,
                "model blob CRC mismatch: stored {stored:#010x}, computed {computed:#010x} (corrupt or partly written)"
            ),
            Self::Misaligned => write!(f, "model blob or one of its tensors is not 4-byte aligned"),
            Self::UnknownVariant(v) => write!(f, "unknown model variant {v}"),
            Self::UnknownField => write!(
                f,
                "unknown flag, unit or non-zero reserved field in the header"
            ),
            Self::OverBounds => write!(
                f,
                "model sizes exceed this build's bounds (hidden <= {MAX_HIDDEN}, inputs <= {MAX_INPUT})"
            ),
            Self::InconsistentSizes => write!(f, "model sizes contradict its variant"),
            Self::Stft(e) => write!(f, "bad STFT settings: {e}"),
            Self::BadSetting => write!(
                f,
                "sample rate, input scale or decision setting out of range"
            ),
            Self::UnknownTensor => write!(f, "tensor directory entry of unknown kind or type"),
            Self::DuplicateTensor(k) => write!(f, "tensor {k:?} listed twice"),
            Self::MissingTensor(k) => write!(f, "tensor {k:?} missing"),
            Self::TensorShape(k) => write!(f, "tensor {k:?} has the wrong shape, type or length"),
            Self::TensorOutOfBounds(k) => {
                write!(f, "tensor {k:?} lies outside the blob's data area")
            }
            Self::QuantParam(k) => write!(
                f,
                "tensor {k:?} holds a quantisation parameter out of range"
            ),
            Self::BadHandRule => write!(
                f,
                "hand-rule record out of range (strict and guard fractions 0..=32767 in Q0.15, window 1..={LOAD_WINDOW_MAX} frames)"
            ),
        }
    }
}

#[cfg(any(test, feature = "std"))]
impl std::error::Error for BlobError {}

/// Little-endian field readers over a slice already checked to be long enough.
fn u16_at(b: &[u8], o: usize) -> u16 {
    match b.get(o..o + 2) {
        Some(s) => u16::from_le_bytes([s[0], s[1]]),
        None => 0,
    }
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    match b.get(o..o + 4) {
        Some(s) => u32::from_le_bytes([s[0], s[1], s[2], s[3]]),
        None => 0,
    }
}

/// `n` rounded up to a multiple of 4 (row padding for word loads).
pub const fn pad4(n: usize) -> usize {
    (n + 3) & !3
}

#[derive(Clone, Copy)]
struct DirEntry {
    dtype: u8,
    rows: usize,
    cols: usize,
    offset: usize,
    len: usize,
}

impl<'a> ModelBlob<'a> {
    /// Parses and validates a blob. `bytes` may be longer than the blob (a flash region): the
    /// header's total length bounds it.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, BlobError> {
        let present = bytes.len() as u32;
        if bytes.len() < HEADER_LEN {
            return Err(BlobError::Truncated {
                needed: HEADER_LEN as u32,
                present,
            });
        }
        let image = bytes[0..4] == IMAGE_MAGIC;
        if !image && bytes[0..4] != MAGIC {
            return Err(BlobError::BadMagic);
        }
        let version = u16_at(bytes, 4);
        if !(VERSION_1..=VERSION).contains(&version) {
            return Err(BlobError::UnsupportedVersion(version));
        }
        // Versions 2 and 3 are version 1 plus the hand-rule record.
        let with_rule = version >= VERSION_2;
        let header_len = u16_at(bytes, 6) as usize;
        let total = u32_at(bytes, 8) as usize;
        if header_len != HEADER_LEN || total < HEADER_LEN + CRC_LEN {
            return Err(BlobError::BadLength);
        }
        if bytes.len() < total {
            return Err(BlobError::Truncated {
                needed: total as u32,
                present,
            });
        }
        let body = total - CRC_LEN;
        if image {
            // A RAM image: its own CRC after the blob's bytes covers the re-laid weights and
            // the blob's CRC (checked on the source when the image was made).
            let stored = u32_at(bytes, total);
            if bytes.len() < total + CRC_LEN {
                return Err(BlobError::Truncated {
                    needed: (total + CRC_LEN) as u32,
                    present,
                });
            }
            let computed = CRC32.checksum(&bytes[..total]);
            if stored != computed {
                return Err(BlobError::BadCrc { stored, computed });
            }
        }
        let bytes = &bytes[..total];
        let stored = u32_at(bytes, body);
        if !image {
            let computed = CRC32.checksum(&bytes[..body]);
            if stored != computed {
                return Err(BlobError::BadCrc { stored, computed });
            }
        }
        if bytes.as_ptr().align_offset(4) != 0 {
            return Err(BlobError::Misaligned);
        }
        // The hand-level variant exists from v3 on (an unknown variant byte to v1 and v2), and
        // v3 holds nothing else.
        let hand_byte = bytes[16] == Variant::HandLstm as u8;
        if hand_byte && version != VERSION {
            return Err(BlobError::UnknownVariant(bytes[16]));
        }
        let mut config = parse_config(bytes)?;
        if config.variant.is_hand() != (version == VERSION) {
            return Err(BlobError::InconsistentSizes);
        }

        let tensor_count = u16_at(bytes, 48) as usize;
        let lstm_count = config.variant.lstm_count();
        let expected_tensors = 1 + 2 * lstm_count + 2 + with_rule as usize;
        if tensor_count > MAX_TENSORS {
            return Err(BlobError::InconsistentSizes);
        }
        let data_start = HEADER_LEN + tensor_count * DIR_ENTRY_LEN;
        if data_start > body {
            return Err(BlobError::Truncated {
                needed: (data_start + CRC_LEN) as u32,
                present: total as u32,
            });
        }

        // Directory: slot 0 norm, 1/2 LSTM0 weights/params, 3/4 LSTM1, 5/6 dense, 7 hand rule.
        let mut slots: [Option<DirEntry>; MAX_TENSORS] = [None; MAX_TENSORS];
        for i in 0..tensor_count {
            let e = &bytes[HEADER_LEN + i * DIR_ENTRY_LEN..HEADER_LEN + (i + 1) * DIR_ENTRY_LEN];
            let kind = TensorKind::from_u8(e[0]).ok_or(BlobError::UnknownTensor)?;
            let index = e[1] as usize;
            let dt = e[2];
            if (dt != dtype::I8 && dt != dtype::I32) || e[3] != 0 {
                return Err(BlobError::UnknownTensor);
            }
            let slot = match kind {
                TensorKind::FeatureNorm => 0,
                TensorKind::LstmWeights if index < lstm_count => 1 + 2 * index,
                TensorKind::LstmRowParams if index < lstm_count => 2 + 2 * index,
                TensorKind::DenseWeights => 5,
                TensorKind::DenseRowParams => 6,
                // A v1 blob has no hand rule: the kind is unknown to v1.
                TensorKind::HandRule if with_rule => 7,
                TensorKind::HandRule => return Err(BlobError::UnknownTensor),
                _ => return Err(BlobError::InconsistentSizes),
            };
            if !matches!(kind, TensorKind::LstmWeights | TensorKind::LstmRowParams) && index != 0 {
                return Err(BlobError::InconsistentSizes);
            }
            if slots[slot].is_some() {
                return Err(BlobError::DuplicateTensor(kind));
            }
            let entry = DirEntry {
                dtype: dt,
                rows: u16_at(e, 4) as usize,
                cols: u16_at(e, 6) as usize,
                offset: u32_at(e, 8) as usize,
                len: u32_at(e, 12) as usize,
            };
            if entry.offset < data_start
                || entry
                    .offset
                    .checked_add(entry.len)
                    .is_none_or(|end| end > body)
            {
                return Err(BlobError::TensorOutOfBounds(kind));
            }
            if !entry.offset.is_multiple_of(4) {
                return Err(BlobError::Misaligned);
            }
            slots[slot] = Some(entry);
        }
        if tensor_count != expected_tensors {
            // Report the first missing one.
            let kinds = [
                TensorKind::FeatureNorm,
                TensorKind::LstmWeights,
                TensorKind::LstmRowParams,
                TensorKind::LstmWeights,
                TensorKind::LstmRowParams,
                TensorKind::DenseWeights,
                TensorKind::DenseRowParams,
                TensorKind::HandRule,
            ];
            for (slot, kind) in kinds.iter().enumerate() {
                let needed = match slot {
                    3 | 4 => lstm_count == 2,
                    7 => with_rule,
                    _ => true,
                };
                if needed && slots[slot].is_none() {
                    return Err(BlobError::MissingTensor(*kind));
                }
            }
            return Err(BlobError::InconsistentSizes);
        }
        let get = |slot: usize, kind: TensorKind| slots[slot].ok_or(BlobError::MissingTensor(kind));

        let n_features = config.feature_count();
        let norm: &[FeatureNorm] = i32_table(
            bytes,
            get(0, TensorKind::FeatureNorm)?,
            n_features,
            3,
            TensorKind::FeatureNorm,
        )?;
        for n in norm {
            if !(1..=62).contains(&n.shift) {
                return Err(BlobError::QuantParam(TensorKind::FeatureNorm));
            }
        }

        let empty = LstmTensors {
            inputs: 0,
            hidden: 0,
            hh_offset: 0,
            row_len: 0,
            cell_frac_bits: 0,
            weights: &[],
            blocked: false,
            rows: &[],
        };
        let mut lstm = [empty; 2];
        let mut dense_len = 0;
        for (k, l) in lstm.iter_mut().enumerate().take(lstm_count) {
            let inputs = config.lstm_inputs(k);
            let hidden = config.hidden[k] as usize;
            let hh_offset = pad4(inputs);
            let row_len = hh_offset + pad4(hidden);
            let we = get(1 + 2 * k, TensorKind::LstmWeights)?;
            let weights = i8_table(bytes, we, 4 * hidden, row_len, TensorKind::LstmWeights)?;
            let pe = get(2 + 2 * k, TensorKind::LstmRowParams)?;
            let rows: &[LstmRowParams] =
                i32_table(bytes, pe, 4 * hidden, 4, TensorKind::LstmRowParams)?;
            // A RAM image's rows are folded (`lstm::fold_row`): d in 1..=30, |C| ≤ 2^30.
            let bad = |r: &LstmRowParams| {
                if image {
                    !(1..=30).contains(&r.shift) || (r.bias_q12 as i64).abs() > FOLDED_ADDEND_MAX
                } else {
                    !(1..=62).contains(&r.shift)
                }
            };
            if rows.iter().any(bad) {
                return Err(BlobError::QuantParam(TensorKind::LstmRowParams));
            }
            *l = LstmTensors {
                inputs,
                hidden,
                hh_offset,
                row_len,
                cell_frac_bits: config.cell_frac_bits[k] as u32,
                weights,
                blocked: image,
                rows,
            };
            dense_len += pad4(hidden);
        }
        let weights = i8_table(
            bytes,
            get(5, TensorKind::DenseWeights)?,
            2,
            dense_len,
            TensorKind::DenseWeights,
        )?;
        let rows: &[DenseRowParams] = i32_table(
            bytes,
            get(6, TensorKind::DenseRowParams)?,
            2,
            3,
            TensorKind::DenseRowParams,
        )?;
        if rows.iter().any(|r| !(1..=62).contains(&r.shift)) {
            return Err(BlobError::QuantParam(TensorKind::DenseRowParams));
        }
        if with_rule {
            let record: &[[i32; 3]] = i32_table(
                bytes,
                get(7, TensorKind::HandRule)?,
                1,
                3,
                TensorKind::HandRule,
            )?;
            let record = record
                .first()
                .ok_or(BlobError::TensorShape(TensorKind::HandRule))?;
            config.hand_rule = Some(hand_rule_of_record(*record)?);
        }
        Ok(Self {
            config,
            crc: stored,
            len: total,
            norm,
            lstm,
            dense: DenseTensors {
                row_len: dense_len,
                weights,
                rows,
            },
        })
    }

    /// The LSTMs the variant uses.
    pub fn lstms(&self) -> &[LstmTensors<'a>] {
        &self.lstm[..self.config.variant.lstm_count()]
    }
}

fn i8_table(
    bytes: &[u8],
    e: DirEntry,
    rows: usize,
    cols: usize,
    kind: TensorKind,
) -> Result<&[i8], BlobError> {
    if e.dtype != dtype::I8 || e.rows != rows || e.cols != cols || e.len != rows * cols {
        return Err(BlobError::TensorShape(kind));
    }
    let raw = bytes
        .get(e.offset..e.offset + e.len)
        .ok_or(BlobError::TensorOutOfBounds(kind))?;
    Ok(bytemuck::cast_slice(raw))
}

fn i32_table<T: Pod>(
    bytes: &[u8],
    e: DirEntry,
    rows: usize,
    cols: usize,
    kind: TensorKind,
) -> Result<&[T], BlobError> {
    if e.dtype != dtype::I32
        || e.rows != rows
        || e.cols != cols
        || e.len != rows * cols * 4
        || core::mem::size_of::<T>() != cols * 4
    {
        return Err(BlobError::TensorShape(kind));
    }
    let raw = bytes
        .get(e.offset..e.offset + e.len)
        .ok_or(BlobError::TensorOutOfBounds(kind))?;
    bytemuck::try_cast_slice(raw).map_err(|_| BlobError::Misaligned)
}

/// The hand-rule record of format v2 (one i32 row): `[strict fraction Q0.15, guard fraction
/// Q0.15 (32 767 = [`FusedHand::NO_GUARD`]), window in frames]`. Refuses a rule the record
/// cannot hold or the firmware cannot run ([`BlobError::BadHandRule`]): fractions outside
/// 0..=32 767, a window outside 1..=[`LOAD_WINDOW_MAX`].
pub fn hand_rule_record(rule: &FusedHand) -> Result<[i32; 3], BlobError> {
    let record = record_of(rule);
    hand_rule_of_record(record)?;
    Ok(record)
}

/// The record's three values, unchecked.
fn record_of(rule: &FusedHand) -> [i32; 3] {
    [
        rule.strict.fraction_q15 as i32,
        rule.guard_q15 as i32,
        rule.strict.window as i32,
    ]
}

/// The fused hand decision of a v2 hand-rule record ([`hand_rule_record`]), range-checked.
pub fn hand_rule_of_record(record: [i32; 3]) -> Result<FusedHand, BlobError> {
    let [strict, guard, window] = record;
    let fraction = 0..=i16::MAX as i32;
    if !fraction.contains(&strict)
        || !fraction.contains(&guard)
        || !(1..=LOAD_WINDOW_MAX as i32).contains(&window)
    {
        return Err(BlobError::BadHandRule);
    }
    // All three checked to fit: strict and guard in 0..=i16::MAX, window in 1..=64.
    Ok(FusedHand {
        strict: LoadRule {
            fraction_q15: strict as i16,
            window: window as u8,
        },
        guard_q15: guard as i16,
    })
}

fn parse_config(b: &[u8]) -> Result<ModelConfig, BlobError> {
    let variant = Variant::from_u8(b[16]).ok_or(BlobError::UnknownVariant(b[16]))?;
    let flag_bits = b[17];
    if flag_bits & !flags::KNOWN != 0 || u16_at(b, 50) != 0 {
        return Err(BlobError::UnknownField);
    }
    let lstm_count = b[18] as usize;
    let input_unit = match b[19] {
        0 => InputUnit::MilliNewton,
        1 => InputUnit::Counts,
        _ => return Err(BlobError::UnknownField),
    };
    let sample_rate_mhz = Millihertz(u32_at(b, 20));
    let input_offset = u32_at(b, 24) as i32;
    let input_full_scale = u32_at(b, 28) as i32;
    let shape = match WindowShape::try_from(b[35]) {
        Ok(s) => s,
        Err(_) if !variant.uses_bands() => WindowShape::Rectangular,
        Err(e) => return Err(BlobError::Stft(e)),
    };
    let stft = StftConfig {
        window_len: b[32],
        first_bin: b[33],
        n_bins: b[34],
        shape,
    };
    let threshold_q15 = u16_at(b, 36);
    let raise_after = b[38];
    let clear_after = b[39];
    let hidden = [u16_at(b, 40), u16_at(b, 42)];
    let inputs = [b[44], b[45]];
    let cell_frac_bits = [b[46], b[47]];
    let mut name = [0u8; 12];
    name.copy_from_slice(&b[52..64]);

    if variant.is_hand() && flag_bits & flags::FORCE_DIFF != 0 {
        // d(t) is a per-channel input.
        return Err(BlobError::InconsistentSizes);
    }
    let config = ModelConfig {
        model_id: u32_at(b, 12),
        name,
        variant,
        force_diff: flag_bits & flags::FORCE_DIFF != 0,
        sample_rate_mhz,
        input_unit,
        input_offset,
        input_full_scale,
        stft,
        hidden,
        cell_frac_bits,
        threshold_q15,
        raise_after,
        clear_after,
        hand_rule: None,
    };

    if variant.uses_bands() {
        stft.validate().map_err(BlobError::Stft)?;
    } else if b[32..36] != [0, 0, 0, 0] {
        return Err(BlobError::InconsistentSizes);
    }
    if sample_rate_mhz.0 == 0 || input_full_scale <= 0 {
        return Err(BlobError::BadSetting);
    }
    if threshold_q15 == 0 || threshold_q15 > i16::MAX as u16 || raise_after == 0 || clear_after == 0
    {
        return Err(BlobError::BadSetting);
    }
    if lstm_count != variant.lstm_count() {
        return Err(BlobError::InconsistentSizes);
    }
    for k in 0..2 {
        let used = k < lstm_count;
        let h = hidden[k] as usize;
        let i = inputs[k] as usize;
        if used {
            if h > MAX_HIDDEN || i > MAX_INPUT {
                return Err(BlobError::OverBounds);
            }
            if h == 0 || i == 0 || i != config.lstm_inputs(k) {
                return Err(BlobError::InconsistentSizes);
            }
            if !(1..=15).contains(&cell_frac_bits[k]) {
                return Err(BlobError::QuantParam(TensorKind::LstmRowParams));
            }
        } else if h != 0 || i != 0 || cell_frac_bits[k] != 0 {
            return Err(BlobError::InconsistentSizes);
        }
    }
    Ok(config)
}

/// The tensors of a blob in host memory, for the writer.
#[cfg(any(test, feature = "std"))]
#[derive(Clone, Debug, PartialEq)]
pub struct BlobTensors {
    /// Feature normalisation rows.
    pub norm: Vec<FeatureNorm>,
    /// Per LSTM: int8 weights (4H × row_len, padding zero) and row parameters.
    pub lstm: Vec<(Vec<i8>, Vec<LstmRowParams>)>,
    /// Dense int8 weights (2 × row_len, padding zero) and row parameters.
    pub dense: (Vec<i8>, Vec<DenseRowParams>),
}

/// A blob in a 4-byte aligned host buffer, as flash would hold it.
#[cfg(any(test, feature = "std"))]
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AlignedBlob {
    words: Vec<u32>,
    len: usize,
}

#[cfg(any(test, feature = "std"))]
impl AlignedBlob {
    /// Copies bytes into an aligned buffer.
    pub fn new(bytes: &[u8]) -> Self {
        let mut words = vec![0u32; bytes.len().div_ceil(4)];
        bytemuck::cast_slice_mut::<u32, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Self {
            words,
            len: bytes.len(),
        }
    }
    /// The blob's bytes, 4-byte aligned.
    pub fn as_bytes(&self) -> &[u8] {
        &bytemuck::cast_slice::<u32, u8>(&self.words)[..self.len]
    }
    /// Parses the blob.
    pub fn parse(&self) -> Result<ModelBlob<'_>, BlobError> {
        ModelBlob::parse(self.as_bytes())
    }
}

/// Serialises a model: format v1 without a hand rule, v2 with one ([`ModelConfig::hand_rule`],
/// its record last), v3 for the hand-level variant (always with a record: without a rule, the
/// one that passes the model's flag alone, [`FusedHand::MODEL_ONLY`]). The only writer of the
/// format. A rule out of range ([`hand_rule_record`]) is written as given and refused by the
/// parser: check it first.
#[cfg(any(test, feature = "std"))]
pub fn write_blob(config: &ModelConfig, tensors: &BlobTensors) -> Vec<u8> {
    let lstm_count = config.variant.lstm_count();
    let mut config = *config;
    if config.variant.is_hand() && config.hand_rule.is_none() {
        config.hand_rule = Some(FusedHand::MODEL_ONLY);
    }
    let config = &config;
    let version = if config.variant.is_hand() {
        VERSION
    } else if config.hand_rule.is_some() {
        VERSION_2
    } else {
        VERSION_1
    };
    let mut h = Vec::with_capacity(HEADER_LEN);
    h.extend_from_slice(&MAGIC);
    h.extend_from_slice(&version.to_le_bytes());
    h.extend_from_slice(&(HEADER_LEN as u16).to_le_bytes());
    h.extend_from_slice(&0u32.to_le_bytes()); // total length, patched below
    h.extend_from_slice(&config.model_id.to_le_bytes());
    h.push(config.variant as u8);
    h.push(if config.force_diff {
        flags::FORCE_DIFF
    } else {
        0
    });
    h.push(lstm_count as u8);
    h.push(config.input_unit as u8);
    h.extend_from_slice(&config.sample_rate_mhz.0.to_le_bytes());
    h.extend_from_slice(&config.input_offset.to_le_bytes());
    h.extend_from_slice(&config.input_full_scale.to_le_bytes());
    if config.variant.uses_bands() {
        let s = config.stft;
        h.extend_from_slice(&[s.window_len, s.first_bin, s.n_bins, s.shape as u8]);
    } else {
        h.extend_from_slice(&[0; 4]);
    }
    h.extend_from_slice(&config.threshold_q15.to_le_bytes());
    h.push(config.raise_after);
    h.push(config.clear_after);
    for k in 0..2 {
        let v = if k < lstm_count { config.hidden[k] } else { 0 };
        h.extend_from_slice(&v.to_le_bytes());
    }
    for k in 0..2 {
        h.push(if k < lstm_count {
            config.lstm_inputs(k) as u8
        } else {
            0
        });
    }
    for k in 0..2 {
        h.push(if k < lstm_count {
            config.cell_frac_bits[k]
        } else {
            0
        });
    }
    let tensor_count = 3 + 2 * lstm_count + config.hand_rule.is_some() as usize;
    h.extend_from_slice(&(tensor_count as u16).to_le_bytes());
    h.extend_from_slice(&0u16.to_le_bytes());
    h.extend_from_slice(&config.name);
    debug_assert_eq!(h.len(), HEADER_LEN);

    // (kind, index, dtype, rows, cols, bytes)
    let mut items: Vec<(TensorKind, u8, u8, usize, usize, Vec<u8>)> = Vec::new();
    items.push((
        TensorKind::FeatureNorm,
        0,
        dtype::I32,
        tensors.norm.len(),
        3,
        bytemuck::cast_slice(&tensors.norm).to_vec(),
    ));
    for (k, (w, p)) in tensors.lstm.iter().enumerate() {
        let rows = p.len();
        let cols = w.len().checked_div(rows).unwrap_or(0);
        items.push((
            TensorKind::LstmWeights,
            k as u8,
            dtype::I8,
            rows,
            cols,
            bytemuck::cast_slice(w).to_vec(),
        ));
        items.push((
            TensorKind::LstmRowParams,
            k as u8,
            dtype::I32,
            rows,
            4,
            bytemuck::cast_slice(p).to_vec(),
        ));
    }
    let (dw, dp) = &tensors.dense;
    items.push((
        TensorKind::DenseWeights,
        0,
        dtype::I8,
        2,
        dw.len() / 2,
        bytemuck::cast_slice(dw).to_vec(),
    ));
    items.push((
        TensorKind::DenseRowParams,
        0,
        dtype::I32,
        dp.len(),
        3,
        bytemuck::cast_slice(dp).to_vec(),
    ));
    if let Some(rule) = &config.hand_rule {
        let record = record_of(rule);
        items.push((
            TensorKind::HandRule,
            0,
            dtype::I32,
            1,
            3,
            bytemuck::cast_slice(&record).to_vec(),
        ));
    }

    let mut out = h;
    let dir_start = out.len();
    out.resize(dir_start + items.len() * DIR_ENTRY_LEN, 0);
    for (i, (kind, index, dt, rows, cols, data)) in items.iter().enumerate() {
        let offset = pad4(out.len());
        out.resize(offset, 0);
        out.extend_from_slice(data);
        let e = &mut out[dir_start + i * DIR_ENTRY_LEN..dir_start + (i + 1) * DIR_ENTRY_LEN];
        e[0] = *kind as u8;
        e[1] = *index;
        e[2] = *dt;
        e[3] = 0;
        e[4..6].copy_from_slice(&(*rows as u16).to_le_bytes());
        e[6..8].copy_from_slice(&(*cols as u16).to_le_bytes());
        e[8..12].copy_from_slice(&(offset as u32).to_le_bytes());
        e[12..16].copy_from_slice(&(data.len() as u32).to_le_bytes());
    }
    let body = pad4(out.len());
    out.resize(body, 0);
    let total = (body + CRC_LEN) as u32;
    out[8..12].copy_from_slice(&total.to_le_bytes());
    let crc = CRC32.checksum(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}
