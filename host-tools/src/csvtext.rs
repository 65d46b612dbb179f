//! A small, strict reader for plain numeric CSV text (no quoting), reporting
//! errors with file, 1-based line and 1-based column.

use std::path::Path;

use crate::error::{DataError, Location};

/// One non-empty line with its 1-based line number.
pub(crate) struct Line<'a> {
    pub number: usize,
    pub text: &'a str,
}

/// Lines of `text` with 1-based numbers, a trailing `\r` removed.
pub(crate) fn lines(text: &str) -> impl Iterator<Item = Line<'_>> {
    text.split('\n').enumerate().map(|(i, l)| Line {
        number: i + 1,
        text: l.strip_suffix('\r').unwrap_or(l),
    })
}

pub(crate) fn read_text(path: &Path) -> Result<String, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        // Find the line of the first invalid byte.
        let upto = e.utf8_error().valid_up_to();
        let data = e.as_bytes();
        let line = data[..upto].iter().filter(|&&b| b == b'\n').count() + 1;
        DataError::Parse {
            loc: Location {
                path: path.to_path_buf(),
                line,
                column: None,
                column_name: None,
            },
            message: "not valid UTF-8".into(),
        }
    })
}

pub(crate) fn parse_error(
    path: &Path,
    line: usize,
    column: Option<usize>,
    column_name: Option<&str>,
    message: impl Into<String>,
) -> DataError {
    DataError::Parse {
        loc: Location {
            path: path.to_path_buf(),
            line,
            column,
            column_name: column_name.map(str::to_string),
        },
        message: message.into(),
    }
}

/// Parse one numeric field (finite f32).
pub(crate) fn parse_number(
    path: &Path,
    line: usize,
    col: usize,
    name: &str,
    field: &str,
) -> Result<f32, DataError> {
    let f = field.trim();
    if f.is_empty() {
        return Err(parse_error(
            path,
            line,
            Some(col),
            Some(name),
            "empty value",
        ));
    }
    match f.parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(parse_error(
            path,
            line,
            Some(col),
            Some(name),
            format!("`{f}` is not a finite number"),
        )),
    }
}

/// Check a data row has exactly `expected` fields.
pub(crate) fn check_width(
    path: &Path,
    line: usize,
    fields: &[&str],
    expected: usize,
) -> Result<(), DataError> {
    if fields.len() != expected {
        let col = fields.len().min(expected) + 1;
        let msg = if fields.len() < expected {
            format!("row has {} fields, header has {expected}", fields.len())
        } else {
            format!(
                "row has {} fields, header has only {expected}",
                fields.len()
            )
        };
        return Err(parse_error(path, line, Some(col), None, msg));
    }
    Ok(())
}
