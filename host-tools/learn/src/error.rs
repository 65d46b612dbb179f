//! Typed errors of training, checkpoints and evaluation. Candle's, safetensors' and the
//! core's errors are wrapped; the CLI adds `anyhow` at its edge only.

use std::fmt;
use std::path::PathBuf;

use slipguard_core::blob::BlobError;
use slipguard_core::float::FloatModelError;
use slipguard_data::DataError;

/// Errors of [`crate::train`], [`crate::checkpoint`] and [`crate::evaluation`].
#[derive(Debug)]
#[non_exhaustive]
pub enum LearnError {
    /// Reading or writing a file failed.
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Something went wrong with the named file (the cause is `source`).
    File {
        path: PathBuf,
        source: Box<LearnError>,
    },
    /// Checkpoint metadata or tensors are missing or malformed.
    Checkpoint(String),
    /// The safetensors container does not read or write.
    Safetensors(safetensors::SafeTensorError),
    /// A candle operation failed.
    #[cfg(feature = "train")]
    Candle(candle_core::Error),
    /// The float weights do not form a model the core can run.
    Model(FloatModelError),
    /// A quantized blob does not parse.
    Blob(BlobError),
    /// Training cannot start or did not converge (no data, non-finite loss).
    Training(String),
    /// The data layer failed.
    Data(DataError),
}

impl fmt::Display for LearnError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LearnError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            LearnError::File { path, source } => write!(f, "{}: {source}", path.display()),
            LearnError::Checkpoint(m) => write!(f, "checkpoint: {m}"),
            LearnError::Safetensors(e) => write!(f, "safetensors: {e}"),
            #[cfg(feature = "train")]
            LearnError::Candle(e) => write!(f, "candle: {e}"),
            LearnError::Model(e) => write!(f, "{e}"),
            LearnError::Blob(e) => write!(f, "blob does not parse: {e}"),
            LearnError::Training(m) => write!(f, "training: {m}"),
            LearnError::Data(e) => write!(f, "{e}"),
        }
    }
}

// Display already names the cause, so `source` stays `None`: a caller printing the chain
// (`anyhow`'s `{:#}`) shows each cause once.
impl std::error::Error for LearnError {}

#[cfg(feature = "train")]
impl From<candle_core::Error> for LearnError {
    fn from(e: candle_core::Error) -> Self {
        LearnError::Candle(e)
    }
}

impl From<safetensors::SafeTensorError> for LearnError {
    fn from(e: safetensors::SafeTensorError) -> Self {
        LearnError::Safetensors(e)
    }
}

impl From<FloatModelError> for LearnError {
    fn from(e: FloatModelError) -> Self {
        LearnError::Model(e)
    }
}

impl From<BlobError> for LearnError {
    fn from(e: BlobError) -> Self {
        LearnError::Blob(e)
    }
}

impl From<DataError> for LearnError {
    fn from(e: DataError) -> Self {
        LearnError::Data(e)
    }
}

pub type Result<T> = std::result::Result<T, LearnError>;
