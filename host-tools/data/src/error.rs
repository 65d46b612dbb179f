//! Typed errors of the data layer. The CLI wraps them in `anyhow` at its edge only.

use std::fmt;
use std::path::PathBuf;

/// Where in a text file something went wrong: 1-based line and column.
///
/// `column` is the 1-based index of the comma-separated field (not the byte
/// offset); `column_name` is the header name of that field when known.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub path: PathBuf,
    pub line: usize,
    pub column: Option<usize>,
    pub column_name: Option<String>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.path.display(), self.line)?;
        if let Some(c) = self.column {
            write!(f, ":{c}")?;
            if let Some(n) = &self.column_name {
                write!(f, " (column `{n}`)")?;
            }
        }
        Ok(())
    }
}

/// Errors of loaders, writers, labelling and the simulator.
#[derive(Debug)]
#[non_exhaustive]
pub enum DataError {
    /// Reading or writing a file failed.
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A CSV file is malformed; `loc` names file, line and column.
    Parse { loc: Location, message: String },
    /// A required column is missing from a header.
    MissingColumn {
        path: PathBuf,
        line: usize,
        column: String,
    },
    /// A required metadata key is missing from a recording.
    MissingMetadata { path: PathBuf, key: String },
    /// A JSON metadata file is malformed or lacks a field.
    Json { path: PathBuf, message: String },
    /// The data has an unexpected shape (rows, channels, marks out of range...).
    Shape { path: PathBuf, message: String },
    /// A folder contains no trials.
    NoTrials { path: PathBuf },
    /// An invalid configuration or argument.
    Config(String),
    /// Drawing a plot failed.
    Plot { path: PathBuf, message: String },
}

impl DataError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }

    /// The location (file, line, column) for parse errors.
    pub fn location(&self) -> Option<&Location> {
        match self {
            DataError::Parse { loc, .. } => Some(loc),
            _ => None,
        }
    }
}

impl fmt::Display for DataError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DataError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            DataError::Parse { loc, message } => write!(f, "{loc}: {message}"),
            DataError::MissingColumn { path, line, column } => write!(
                f,
                "{}:{line}: header lacks the required column `{column}`",
                path.display()
            ),
            DataError::MissingMetadata { path, key } => write!(
                f,
                "{}: recording lacks the required metadata line `# {key}: ...`",
                path.display()
            ),
            DataError::Json { path, message } => write!(f, "{}: {message}", path.display()),
            DataError::Shape { path, message } => write!(f, "{}: {message}", path.display()),
            DataError::NoTrials { path } => write!(f, "{}: no trials found", path.display()),
            DataError::Config(m) => write!(f, "invalid configuration: {m}"),
            DataError::Plot { path, message } => {
                write!(f, "{}: drawing failed: {message}", path.display())
            }
        }
    }
}

// Display already names the cause, so `source` stays `None`: a caller printing the chain
// (`anyhow`'s `{:#}`) shows each cause once.
impl std::error::Error for DataError {}

pub type Result<T> = std::result::Result<T, DataError>;
