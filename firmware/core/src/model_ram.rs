//! The model blob's copy in zero-wait-state RAM.
//!
//! On the STM32F4 the flash runs at 5 wait states behind the ART accelerator, whose data side
//! holds 8 lines of 16 bytes: the LSTM streams its ~70 KiB of int8 weights through it every
//! channel step and stalls on nearly every line. A copy in SRAM is read at one word per cycle.
//! [`ModelRam::load`] validates a blob where it lies (CRC, version, sizes: [`ModelBlob::parse`])
//! and copies it into the buffer as a RAM image (the LSTM weights re-laid for the
//! register-blocked kernel, [`crate::dsp::lstm_block_sums`], the LSTM row parameters folded for
//! the gate pass, [`crate::lstm::fold_row`]; the image carries its own CRC);
//! the caller then parses the copy (the CRC is checked again, now on what will run). Call it at boot, and again after a new
//! blob has been written to the model region (drop every [`crate::model::Model`] that borrows
//! the copy first: the borrow checker insists).
//!
//! The buffer must not live in the STM32F405's CCM if a DMA stream is ever to read the model;
//! the kernels themselves read it from either (both have no wait states).

use crate::blob::{BlobError, CRC_LEN, CRC32, IMAGE_MAGIC, LstmRowParams, ModelBlob};
use crate::dsp::pack_lstm_blocks;
use crate::lstm::fold_row;

/// Bytes a [`ModelRam`] holds by default: a single-LSTM model of the paper's size (variant (c),
/// hidden 128, 11 inputs) is 80 432 bytes, its RAM image 4 more; 80 KiB holds any single-LSTM
/// model of the build's bounds. A larger blob (a dual model with two 128-unit LSTMs) does not
/// fit and runs from where it lies.
pub const MODEL_RAM_BYTES: usize = 80 * 1024;

/// Why [`ModelRam::load`] refused a blob (the buffer is then unchanged).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LoadError {
    /// The source is not a valid blob.
    Blob(BlobError),
    /// A valid blob longer than the buffer.
    TooLarge {
        /// The blob's length in bytes.
        len: u32,
        /// The buffer's capacity in bytes.
        capacity: u32,
    },
}

impl core::fmt::Display for LoadError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Blob(e) => write!(f, "model not copied to RAM: {e}"),
            Self::TooLarge { len, capacity } => write!(
                f,
                "model blob of {len} bytes does not fit the {capacity}-byte RAM copy; it runs from flash"
            ),
        }
    }
}

impl core::error::Error for LoadError {}

impl From<BlobError> for LoadError {
    fn from(e: BlobError) -> Self {
        Self::Blob(e)
    }
}

/// A 4-byte aligned RAM buffer for one model blob, `N` bytes (a multiple of 4).
#[derive(Clone)]
#[repr(C, align(4))]
pub struct ModelRam<const N: usize = MODEL_RAM_BYTES> {
    bytes: [u8; N],
    len: usize,
}

impl<const N: usize> ModelRam<N> {
    const WORDS: () = assert!(N.is_multiple_of(4), "ModelRam size must be a multiple of 4");

    /// An empty buffer (all zero, so a `static` lands in `.bss`).
    pub const fn new() -> Self {
        let () = Self::WORDS;
        Self {
            bytes: [0; N],
            len: 0,
        }
    }

    /// Validates the blob at the start of `src` (a model region may be longer than its blob)
    /// and copies it into the buffer as a RAM image ([`IMAGE_MAGIC`]: the LSTM weights in the
    /// blocked layout of [`pack_lstm_blocks`], which the register-blocked kernel reads); if the
    /// weights cannot take that layout, or the image does not fit but the blob does, as a plain
    /// copy of the blob. Returns the copy, ready for [`crate::model::Model::from_bytes`]: the
    /// image is parsed before it is returned and must describe the same model (fingerprint,
    /// length, header), else the plain copy is returned instead, so whatever blob `src` holds,
    /// the copy parses exactly when `src` does. `src` must be a blob (`SGMB`): a RAM image is
    /// not loaded again (its weights are already re-laid; it exists only in RAM). On an error
    /// nothing is copied and the previous contents stay.
    pub fn load(&mut self, src: &[u8]) -> Result<&[u8], LoadError> {
        if src.get(..4) == Some(&IMAGE_MAGIC[..]) {
            return Err(LoadError::Blob(BlobError::BadMagic));
        }
        let blob = ModelBlob::parse(src)?;
        let len = blob.len;
        let too_large = LoadError::TooLarge {
            len: len as u32,
            capacity: N as u32,
        };
        let (Some(from), Some(to)) = (src.get(..len), self.bytes.get_mut(..len)) else {
            return Err(too_large);
        };
        to.copy_from_slice(from);
        self.len = len;
        if len + CRC_LEN <= N && self.relayout(&blob, src) {
            self.bytes[..4].copy_from_slice(&IMAGE_MAGIC);
            let crc = CRC32.checksum(&self.bytes[..len]);
            self.bytes[len..len + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
            self.len = len + CRC_LEN;
        }
        let same = |b: ModelBlob<'_>| (b.crc, b.len, b.config) == (blob.crc, blob.len, blob.config);
        if self.len == len || !ModelBlob::parse(self.bytes()).is_ok_and(same) {
            // A plain copy (row-major weights, still read from RAM).
            self.bytes[..len].copy_from_slice(&src[..len]);
            self.len = len;
        }
        Ok(self.bytes())
    }

    /// Rewrites the copy's LSTM weight tensors in the blocked layout and their row parameters
    /// in the folded form of [`fold_row`] (the rounding half and the bias in one addend, for
    /// the gate pass); false if one cannot be.
    fn relayout(&mut self, blob: &ModelBlob<'_>, src: &[u8]) -> bool {
        let offset = |p: usize| p.wrapping_sub(src.as_ptr() as usize);
        blob.lstms().iter().all(|l| {
            let at = offset(l.weights.as_ptr() as usize);
            let Some(dst) = self.bytes.get_mut(at..at + l.weights.len()) else {
                return false;
            };
            if !pack_lstm_blocks(l.weights, l.row_len, bytemuck::cast_slice_mut(dst)) {
                return false;
            }
            let at = offset(l.rows.as_ptr() as usize);
            let len = core::mem::size_of_val(l.rows);
            let Some(Ok(dst)) = self
                .bytes
                .get_mut(at..at + len)
                .map(bytemuck::try_cast_slice_mut::<u8, LstmRowParams>)
            else {
                return false;
            };
            l.rows.iter().zip(dst).all(|(p, d)| match fold_row(p) {
                Some(f) => {
                    *d = f;
                    true
                }
                None => false,
            })
        })
    }

    /// The blob copied by the last successful [`Self::load`] (empty before).
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len.min(N)]
    }

    /// Capacity in bytes.
    pub const fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize> Default for ModelRam<N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::blob::AlignedBlob;
    use crate::model::{ChannelState, Model};

    fn golden() -> AlignedBlob {
        AlignedBlob::new(include_bytes!("../tests/fixtures/bench/model.bin"))
    }

    /// Every step's p, flag and state equal on the blob and on its copy.
    fn same_steps(a: &[u8], b: &[u8]) {
        let (ma, mb) = (Model::from_bytes(a).unwrap(), Model::from_bytes(b).unwrap());
        let (mut sa, mut sb) = (ChannelState::new(), ChannelState::new());
        let input = include_bytes!("../tests/fixtures/bench/input.bin");
        for (i, v) in input.chunks_exact(4).enumerate() {
            let v = i32::from_le_bytes([v[0], v[1], v[2], v[3]]);
            assert_eq!(ma.step(&mut sa, v), mb.step(&mut sb, v), "step {i}");
            assert_eq!(sa.lstm, sb.lstm, "step {i}");
        }
    }

    #[test]
    fn image_runs_the_same_model() {
        let src = golden();
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        // A model region longer than the blob: only the blob is copied.
        let mut region = src.as_bytes().to_vec();
        region.extend_from_slice(&[0xFF; 100]);
        let region = AlignedBlob::new(&region);
        let copy = ram.load(region.as_bytes()).unwrap().to_vec();
        assert_eq!(copy.len(), src.as_bytes().len() + 4);
        assert_eq!(copy[..4], IMAGE_MAGIC);
        let copy = AlignedBlob::new(&copy);
        let (a, b) = (copy.parse().unwrap(), src.parse().unwrap());
        // The fingerprint stays the blob's CRC; the weights are re-laid and the row
        // parameters folded, the rest is the same.
        assert_eq!((a.crc, a.len, a.config), (b.crc, b.len, b.config));
        assert!(a.lstm[0].blocked && !b.lstm[0].blocked);
        assert_ne!(a.lstm[0].weights, b.lstm[0].weights);
        let folded: Vec<_> = b.lstm[0]
            .rows
            .iter()
            .map(|p| fold_row(p).unwrap())
            .collect();
        assert_eq!(a.lstm[0].rows, &folded[..]);
        assert_ne!(a.lstm[0].rows, b.lstm[0].rows);
        same_steps(src.as_bytes(), copy.as_bytes());
        // A flipped bit anywhere in the image is caught by its own CRC.
        for at in [2, 3000, 40_000, copy.as_bytes().len() - 6] {
            let mut bad = copy.as_bytes().to_vec();
            bad[at] ^= 0x04;
            let bad = AlignedBlob::new(&bad);
            assert!(
                matches!(
                    bad.parse(),
                    Err(BlobError::BadCrc { .. } | BlobError::BadMagic)
                ),
                "byte {at}"
            );
        }
    }

    #[test]
    fn an_image_is_not_loaded_again() {
        // A RAM image parses (it is what runs), but it is not a blob to load: refused, the
        // copy unchanged.
        let src = golden();
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        let image = ram.load(src.as_bytes()).unwrap().to_vec();
        let again = AlignedBlob::new(&image);
        assert!(again.parse().is_ok());
        assert_eq!(
            ram.load(again.as_bytes()),
            Err(LoadError::Blob(BlobError::BadMagic))
        );
        assert!(ram.bytes() == image);
    }

    #[test]
    fn weights_the_layout_cannot_hold_give_a_plain_copy() {
        // b = -128 over a negative a does not fit the layout's halfword: a plain copy.
        let src = golden();
        let b = src.parse().unwrap();
        let at = b.lstm[0].weights.as_ptr() as usize - src.as_bytes().as_ptr() as usize;
        let stride = b.lstm[0].row_len;
        let mut bytes = src.as_bytes().to_vec();
        bytes[at] = (-5i8) as u8;
        bytes[at + stride] = (-128i8) as u8;
        let n = bytes.len() - 4;
        let crc = CRC32.checksum(&bytes[..n]);
        bytes[n..].copy_from_slice(&crc.to_le_bytes());
        let edited = AlignedBlob::new(&bytes);
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        let copy = ram.load(edited.as_bytes()).unwrap().to_vec();
        assert!(copy == edited.as_bytes(), "not a plain copy");
        same_steps(edited.as_bytes(), AlignedBlob::new(&copy).as_bytes());
    }

    #[test]
    fn rows_that_cannot_fold_give_a_plain_copy() {
        // A shift of 32 (valid in a blob, below the folded form's 33..=62): a plain copy, and
        // an image whose rows are not folded is refused by the parser.
        let src = golden();
        let b = src.parse().unwrap();
        let at = b.lstm[0].rows.as_ptr() as usize - src.as_bytes().as_ptr() as usize;
        let mut bytes = src.as_bytes().to_vec();
        bytes[at + 12..at + 16].copy_from_slice(&32i32.to_le_bytes());
        let n = bytes.len() - 4;
        let crc = CRC32.checksum(&bytes[..n]);
        bytes[n..].copy_from_slice(&crc.to_le_bytes());
        let edited = AlignedBlob::new(&bytes);
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        let copy = ram.load(edited.as_bytes()).unwrap().to_vec();
        assert!(copy == edited.as_bytes(), "not a plain copy");
        same_steps(edited.as_bytes(), AlignedBlob::new(&copy).as_bytes());
        // The golden image with one row unfolded (d = 31) and its CRC redone.
        let mut image = ram.load(src.as_bytes()).unwrap().to_vec();
        image[at + 12..at + 16].copy_from_slice(&31i32.to_le_bytes());
        let m = image.len() - 4;
        let crc = CRC32.checksum(&image[..m]);
        image[m..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            AlignedBlob::new(&image).parse().err(),
            Some(BlobError::QuantParam(
                crate::blob::TensorKind::LstmRowParams
            ))
        );
    }

    #[test]
    fn refuses_bad_and_large_blobs_keeping_the_copy() {
        let src = golden();
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        let image = ram.load(src.as_bytes()).unwrap().to_vec();
        let mut bad = src.as_bytes().to_vec();
        bad[5000] ^= 0x10;
        let bad = AlignedBlob::new(&bad);
        assert!(matches!(
            ram.load(bad.as_bytes()),
            Err(LoadError::Blob(BlobError::BadCrc { .. }))
        ));
        let mut small = Box::new(ModelRam::<1024>::new());
        // The image would not fit, the blob does: a plain copy.
        let mut exact = Box::new(ModelRam::<80_432>::new());
        assert!(exact.load(src.as_bytes()).unwrap() == src.as_bytes());
        assert_eq!(
            small.load(src.as_bytes()),
            Err(LoadError::TooLarge {
                len: src.as_bytes().len() as u32,
                capacity: 1024
            })
        );
        assert!(small.bytes().is_empty());
        assert!(ram.bytes() == image, "the refused load changed the copy");
    }
}
