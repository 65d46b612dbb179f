//! The model line the board (defmt) and the QEMU application (semihosting) log at boot, written
//! once: `model 0x… 'name' variant … hidden … at … mHz, blob … bytes CRC 0x… (built-in default
//! … bytes)`.

use core::fmt;

use slipguard_core::model::Model;

/// The boot log's description of the model that runs, with the size of the default blob built
/// into the image (they differ when the MODEL region was re-flashed on its own).
#[derive(Clone, Copy, Debug)]
pub struct ModelLine<'a> {
    /// The model read from the MODEL region.
    pub model: &'a Model<'a>,
    /// Bytes of the default blob in the image.
    pub default_blob_len: usize,
}

impl fmt::Display for ModelLine<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = self.model.config();
        write!(
            f,
            "model {:#010x} '{}' variant {} hidden {} at {} mHz, blob {} bytes CRC {:#010x} (built-in default {} bytes)",
            c.model_id,
            c.name_str(),
            c.variant.name(),
            c.hidden[0],
            c.sample_rate_mhz.0,
            self.model.blob().len,
            self.model.blob().crc,
            self.default_blob_len
        )
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for ModelLine<'_> {
    fn format(&self, f: defmt::Formatter<'_>) {
        let c = self.model.config();
        defmt::write!(
            f,
            "model {:#010x} '{}' variant {} hidden {} at {} mHz, blob {} bytes CRC {:#010x} (built-in default {} bytes)",
            c.model_id,
            c.name_str(),
            c.variant.name(),
            c.hidden[0],
            c.sample_rate_mhz.0,
            self.model.blob().len,
            self.model.blob().crc,
            self.default_blob_len
        )
    }
}
