//! The model blob's copy in zero-wait-state RAM.
//!
//! On the STM32F4 the flash runs at 5 wait states behind the ART accelerator, whose data side
//! holds 8 lines of 16 bytes: the LSTM streams its ~70 KiB of int8 weights through it every
//! channel step and stalls on nearly every line. A copy in SRAM is read at one word per cycle.
//! [`ModelRam::load`] validates a blob where it lies (CRC, version, sizes: [`ModelBlob::parse`])
//! and copies exactly the blob's bytes into the buffer; the caller then parses the copy
//! (the CRC is checked again, now on what will run). Call it at boot, and again after a new
//! blob has been written to the model region (drop every [`crate::model::Model`] that borrows
//! the copy first: the borrow checker insists).
//!
//! The buffer must not live in the STM32F405's CCM if a DMA stream is ever to read the model;
//! the kernels themselves read it from either (both have no wait states).

use crate::blob::{BlobError, ModelBlob};

/// Bytes a [`ModelRam`] holds by default: a single-LSTM model of the paper's size (variant (c),
/// hidden 128, 11 inputs) is 80 432 bytes; 80 KiB leaves room for 16 more inputs' worth of
/// rows. A larger blob (e.g. a dual model with two 128-unit LSTMs) does not fit and runs from
/// where it lies.
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
    /// and copies its bytes into the buffer; returns the copy, ready for
    /// [`crate::model::Model::from_bytes`]. On an error nothing is copied and the previous
    /// contents stay.
    pub fn load(&mut self, src: &[u8]) -> Result<&[u8], LoadError> {
        let len = ModelBlob::parse(src)?.len;
        let (Some(from), Some(to)) = (src.get(..len), self.bytes.get_mut(..len)) else {
            return Err(LoadError::TooLarge {
                len: len as u32,
                capacity: N as u32,
            });
        };
        to.copy_from_slice(from);
        self.len = len;
        Ok(self.bytes())
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

    fn golden() -> AlignedBlob {
        AlignedBlob::new(include_bytes!("../tests/fixtures/bench/model.bin"))
    }

    #[test]
    fn copy_parses_to_the_same_model() {
        let src = golden();
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        // A model region longer than the blob: only the blob is copied.
        let mut region = src.as_bytes().to_vec();
        region.extend_from_slice(&[0xFF; 100]);
        let region = AlignedBlob::new(&region);
        let copy = ram.load(region.as_bytes()).unwrap();
        assert_eq!(copy, src.as_bytes());
        assert_eq!(copy.as_ptr() as usize % 4, 0);
        let (a, b) = (ModelBlob::parse(copy).unwrap(), src.parse().unwrap());
        assert_eq!((a.crc, a.len), (b.crc, b.len));
        assert_eq!(a.lstm[0].weights, b.lstm[0].weights);
    }

    #[test]
    fn refuses_bad_and_large_blobs_keeping_the_copy() {
        let src = golden();
        let mut ram = Box::new(ModelRam::<MODEL_RAM_BYTES>::new());
        ram.load(src.as_bytes()).unwrap();
        let mut bad = src.as_bytes().to_vec();
        bad[5000] ^= 0x10;
        let bad = AlignedBlob::new(&bad);
        assert!(matches!(
            ram.load(bad.as_bytes()),
            Err(LoadError::Blob(BlobError::BadCrc { .. }))
        ));
        let mut small = Box::new(ModelRam::<1024>::new());
        assert_eq!(
            small.load(src.as_bytes()),
            Err(LoadError::TooLarge {
                len: src.as_bytes().len() as u32,
                capacity: 1024
            })
        );
        assert!(small.bytes().is_empty());
        assert_eq!(ram.bytes(), src.as_bytes());
    }
}
