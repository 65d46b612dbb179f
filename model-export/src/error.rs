//! The exporter's errors. Each kind of refusal has its own variant and its own process exit
//! code (documented in `docs/export.md`), so scripts and CI can tell a truncated file from a
//! model the firmware cannot run.

use std::path::PathBuf;

use slipguard_core::blob::BlobError;

/// Why an import, export, inspection or verification failed.
#[derive(Debug)]
pub enum ExportError {
    /// A file could not be read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The command line is inconsistent (clap reports its own usage errors with the same code).
    Usage(String),
    /// The file is not a readable container of its format (truncated, corrupt, wrong format).
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A tensor the model needs is missing, or tensors are named so that no model can be matched.
    MissingTensor {
        /// The tensor (or name pattern) expected.
        tensor: String,
        /// What was found instead.
        msg: String,
    },
    /// A tensor has the wrong shape (or element type) for the declared variant.
    Shape {
        /// The tensor's name in the file.
        tensor: String,
        /// Shape expected.
        expected: String,
        /// Shape found.
        found: String,
    },
    /// A weight is NaN or infinite.
    NotFinite {
        /// The tensor's name in the file.
        tensor: String,
        /// Flat index of the first bad value.
        index: usize,
        /// Where that is in the file's own layout (empty when not known).
        at: String,
    },
    /// A construct the firmware cannot run: bidirectional, peepholes, projection, clipping,
    /// stacked layers, activations other than σ/tanh, a dense layer that is not 2 logits.
    Unsupported {
        /// The tensor, node or layer that carries it.
        tensor: String,
        /// What it is and what the firmware needs instead.
        msg: String,
    },
    /// A size over the firmware's static bounds (hidden > 128, too many inputs).
    OverBounds {
        /// The tensor.
        tensor: String,
        /// What is over which bound.
        msg: String,
    },
    /// A model setting (metadata key, settings file or option) is missing or invalid.
    Settings {
        /// The key.
        key: String,
        /// What is wrong.
        msg: String,
    },
    /// Calibration or verification data could not be loaded or is empty.
    Data(String),
    /// A model blob failed to parse.
    Blob {
        /// The blob file.
        path: PathBuf,
        /// The parser's error.
        source: BlobError,
    },
    /// `verify` ran but the quantized model does not agree with the float model well enough.
    VerifyFailed(String),
}

impl ExportError {
    /// Process exit code of this error (docs/export.md, "Exit codes").
    pub fn exit_code(&self) -> i32 {
        match self {
            Self::Usage(_) => 2,
            Self::Io { .. } => 3,
            Self::Format { .. } => 4,
            Self::MissingTensor { .. } => 5,
            Self::Shape { .. } => 6,
            Self::NotFinite { .. } => 7,
            Self::Unsupported { .. } => 8,
            Self::OverBounds { .. } => 9,
            Self::Settings { .. } => 10,
            Self::Data(_) => 11,
            Self::Blob { .. } => 12,
            Self::VerifyFailed(_) => 13,
        }
    }

    /// Shorthand for [`ExportError::Format`].
    pub fn format(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            msg: msg.into(),
        }
    }
    /// Shorthand for [`ExportError::Unsupported`].
    pub fn unsupported(tensor: impl Into<String>, msg: impl Into<String>) -> Self {
        Self::Unsupported {
            tensor: tensor.into(),
            msg: msg.into(),
        }
    }
    /// Shorthand for [`ExportError::MissingTensor`].
    pub fn missing(tensor: impl Into<String>, msg: impl Into<String>) -> Self {
        Self::MissingTensor {
            tensor: tensor.into(),
            msg: msg.into(),
        }
    }
    /// Shorthand for [`ExportError::Shape`].
    pub fn shape(
        tensor: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        Self::Shape {
            tensor: tensor.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }
    /// Shorthand for [`ExportError::Settings`].
    pub fn settings(key: impl Into<String>, msg: impl Into<String>) -> Self {
        Self::Settings {
            key: key.into(),
            msg: msg.into(),
        }
    }
    /// Shorthand for [`ExportError::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

impl std::fmt::Display for ExportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Self::Usage(m) => write!(f, "{m}"),
            Self::Format { path, msg } => write!(f, "{}: {msg}", path.display()),
            Self::MissingTensor { tensor, msg } => write!(f, "missing tensor `{tensor}`: {msg}"),
            Self::Shape {
                tensor,
                expected,
                found,
            } => write!(
                f,
                "tensor `{tensor}` has shape {found}, expected {expected}"
            ),
            Self::NotFinite { tensor, index, at } => write!(
                f,
                "tensor `{tensor}` has a NaN or infinite value at flat index {index}{at}"
            ),
            Self::Unsupported { tensor, msg } => write!(f, "`{tensor}`: {msg}"),
            Self::OverBounds { tensor, msg } => write!(f, "`{tensor}`: {msg}"),
            Self::Settings { key, msg } => write!(f, "setting `{key}`: {msg}"),
            Self::Data(m) => write!(f, "data: {m}"),
            Self::Blob { path, source } => write!(f, "{}: {source}", path.display()),
            Self::VerifyFailed(m) => write!(f, "verification failed: {m}"),
        }
    }
}

impl std::error::Error for ExportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Blob { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// Result with [`ExportError`].
pub type Result<T, E = ExportError> = std::result::Result<T, E>;

/// Checks that every value is finite.
pub fn check_finite(tensor: &str, v: &[f32]) -> Result<()> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(ExportError::NotFinite {
            tensor: tensor.into(),
            index,
            at: String::new(),
        }),
        None => Ok(()),
    }
}

/// Checks that every value of a tensor is finite, in the file's own layout: the error names the
/// element by its index in the file's shape (e.g. element `[3, 17]` of `kernel` [11, 64]) and
/// its flat index there, before any transposition or gate reordering.
pub fn check_finite_in(tensor: &str, shape: &[usize], v: &[f32]) -> Result<()> {
    let Some(index) = v.iter().position(|x| !x.is_finite()) else {
        return Ok(());
    };
    let mut rest = index;
    let mut idx = vec![0usize; shape.len()];
    for (k, &d) in shape.iter().enumerate().rev() {
        if d > 0 {
            idx[k] = rest % d;
            rest /= d;
        }
    }
    let join = |d: &[usize]| {
        d.iter()
            .map(|x| x.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    Err(ExportError::NotFinite {
        tensor: tensor.into(),
        index,
        at: format!(
            " = {}, element [{}] of its shape [{}] as stored in the file",
            v[index],
            join(&idx),
            join(shape)
        ),
    })
}
