//! Strict reading of numeric CSV text, reporting errors with file, 1-based line and 1-based
//! column. Bodies (header and rows) go through the `csv` crate; the line helpers serve the
//! hand-read `# key: value` preamble of recordings. A UTF-8 byte order mark at the start of a
//! file is accepted (and dropped) by every reader.

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

/// The text from 1-based line `line` on (empty if the text has fewer lines).
pub(crate) fn from_line(text: &str, line: usize) -> &str {
    let mut off = 0;
    for _ in 1..line {
        match text[off..].find('\n') {
            Some(i) => off += i + 1,
            None => return "",
        }
    }
    &text[off..]
}

/// `text` without a leading UTF-8 byte order mark.
pub(crate) fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// One record of a CSV body: its 1-based file line and its trimmed fields.
pub(crate) struct Record {
    pub number: usize,
    pub fields: Vec<String>,
}

/// The records (header and rows) of the CSV body `body`, which starts at file line
/// `first_line`, read with `csv::ReaderBuilder`: comma-separated, fields trimmed, blank lines
/// skipped, rows of any width (callers check the width and name the column).
pub(crate) fn records(
    path: &Path,
    body: &str,
    first_line: usize,
) -> Result<Vec<Record>, DataError> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(body.as_bytes());
    // The file line of a byte offset into `body` (csv's own line count skips blank lines).
    let (mut seen, mut line) = (0usize, first_line);
    let mut file_line = |p: Option<&csv::Position>| {
        let mut at = p.map_or(seen, |p| (p.byte() as usize).min(body.len()));
        // A record's position is where the reader started, before the blank lines it skipped.
        while body
            .as_bytes()
            .get(at)
            .is_some_and(|b| matches!(b, b'\r' | b'\n'))
        {
            at += 1;
        }
        if at >= seen {
            line += body.as_bytes()[seen..at]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            seen = at;
        }
        line
    };
    let mut out = Vec::new();
    for r in reader.records() {
        let r = r.map_err(|e| {
            let line = file_line(e.position());
            parse_error(path, line, None, None, e.to_string())
        })?;
        let number = file_line(r.position());
        if r.iter().all(str::is_empty) {
            continue; // a line of white space only
        }
        out.push(Record {
            number,
            fields: r.iter().map(str::to_string).collect(),
        });
    }
    Ok(out)
}

/// Reads a text file as UTF-8 (without a leading byte order mark).
pub(crate) fn read_text(path: &Path) -> Result<String, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let text = String::from_utf8(bytes).map_err(|e| {
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
    })?;
    Ok(match strip_bom(&text).len() {
        n if n == text.len() => text,
        _ => strip_bom(&text).to_string(),
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
    fields: &[String],
    expected: usize,
) -> Result<(), DataError> {
    let got = fields.len();
    if got != expected {
        let col = got.min(expected) + 1;
        let msg = if got < expected {
            format!("row has {got} fields, header has {expected}")
        } else {
            format!("row has {got} fields, header has only {expected}")
        };
        return Err(parse_error(path, line, Some(col), None, msg));
    }
    Ok(())
}
