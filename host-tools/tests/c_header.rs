//! The wire layout is defined once, in `slipguard_core::protocol` (`MsgType::body`,
//! `MsgType::reply_body`, `REPLY_HEAD`, the code tables). This test holds the other places that
//! state it against that definition:
//! - the checked-in C header is exactly what `slipguard::c_header::generate` writes
//!   (`SLIPGUARD_BLESS=1 cargo test -p slipguard --test c_header` rewrites it);
//! - the layout tables and the message-type table of `docs/protocol.md` list the offsets, sizes,
//!   field names and body lengths of the layout;
//! - every wire example in `docs/protocol.md` decodes.
//!
//! The C decoder's behaviour is checked against the Rust decoder in `c_decoder.rs`.
use std::path::Path;

use slipguard_core::protocol::{self, Body, MsgType, REPLY_HEAD, Tail};

fn manifest() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn checked_in_c_header_is_the_generated_one() {
    let path = manifest().join(slipguard::c_header::HEADER_PATH);
    let want = slipguard::c_header::generate();
    if std::env::var_os("SLIPGUARD_BLESS").is_some() {
        std::fs::write(&path, &want).unwrap();
    }
    let have = std::fs::read_to_string(&path).unwrap();
    if have != want {
        let line = have
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| have.lines().count().min(want.lines().count()));
        panic!(
            "{} differs from the generator's output from line {}: edit host-tools/c/slipguard_protocol.h.in \
             or the layout in slipguard_core::protocol, then run \
             `SLIPGUARD_BLESS=1 cargo test -p slipguard --test c_header`",
            path.display(),
            line + 1
        );
    }
}

/// The generator fills every placeholder and every offset the template reads is defined.
#[test]
fn generated_header_defines_every_constant_the_template_uses() {
    let h = slipguard::c_header::generate();
    assert!(!h.contains('@'), "a placeholder was left in the header");
    let defined: std::collections::BTreeSet<&str> = h
        .lines()
        .filter_map(|l| l.strip_prefix("#define "))
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    for word in slipguard::c_header::TEMPLATE
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| {
            w.starts_with("SG_")
                && !w.ends_with('_')
                && w.chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        })
    {
        assert!(
            defined.contains(word) || word == "SLIPGUARD_PROTOCOL_H",
            "the template uses {word}, which the header does not define"
        );
    }
}

/// Rows `| offset | size | field | …` of the markdown table under `heading` in docs/protocol.md.
fn doc_rows(doc: &str, heading: &str) -> Vec<(usize, String, String)> {
    let start = doc
        .find(heading)
        .unwrap_or_else(|| panic!("docs/protocol.md has no heading {heading:?}"));
    doc[start..]
        .lines()
        .skip_while(|l| !l.starts_with("| body offset"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (
                cells[1].parse().unwrap(),
                cells[2].to_string(),
                cells[3].to_string(),
            )
        })
        .collect()
}

/// The docs' layout tables: offset, size and the field name's start for each field of the body.
#[test]
fn docs_layout_tables_follow_the_layout() {
    let doc = std::fs::read_to_string(manifest().join("../docs/protocol.md")).unwrap();
    for (heading, m) in [
        ("### Flags (`0x01`)", MsgType::Flags),
        ("### Samples (`0x04`)", MsgType::Samples),
        ("### Fault (`0x02`)", MsgType::Fault),
        ("### Error (`0x03`)", MsgType::Error),
    ] {
        let rows = doc_rows(&doc, heading);
        let body = m.body();
        let mut want = Vec::new();
        let mut at = 0;
        for f in body.fields {
            want.push((at, f.ty.size().to_string()));
            at += f.ty.size();
        }
        if let Tail::PerChannel(f) = body.tail {
            want.push((at, format!("{}N", f.ty.size())));
        }
        let got: Vec<(usize, String)> = rows.iter().map(|(o, s, _)| (*o, s.clone())).collect();
        assert_eq!(
            got, want,
            "{heading}: offsets and sizes of docs/protocol.md"
        );
        for ((_, _, name), f) in rows.iter().zip(body.fields) {
            // The docs name a field as the layout does, or by its role (N for `channels`, `code`,
            // `detail` … for the fault's unnamed columns).
            let name = name.trim_matches('`');
            assert!(
                name == f.name
                    || (f.name == "channels" && name == "N")
                    || name.starts_with(f.name.split('_').next().unwrap())
                    || name.starts_with(f.name.rsplit('_').next().unwrap()),
                "{heading}: docs field {name:?} at the layout's {:?}",
                f.name
            );
        }
    }
}

/// The message-type table's body lengths.
#[test]
fn docs_message_type_table_follows_the_layout() {
    let doc = std::fs::read_to_string(manifest().join("../docs/protocol.md")).unwrap();
    let table: Vec<Vec<String>> = doc
        .lines()
        .skip_while(|l| !l.starts_with("| type | direction | name | body bytes |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| l.split('|').map(|c| c.trim().to_string()).collect())
        .collect();
    for m in MsgType::ALL {
        let code = format!("`0x{:02x}`", m as u8);
        let row = table
            .iter()
            .find(|r| r[1] == code)
            .unwrap_or_else(|| panic!("docs/protocol.md's type table has no row {code}"));
        assert!(row[3].starts_with(m.name()), "{code}: {:?}", row[3]);
        let body = m.body();
        let want = match body.tail {
            Tail::None => body.fixed_len().to_string(),
            Tail::PerChannel(f) => format!("{} + {}N", body.fixed_len(), f.ty.size()),
            Tail::ChunkData => format!(
                "{} + n + 4 (n = 1…{})",
                body.fixed_len(),
                protocol::MAX_CHUNK
            ),
        };
        assert_eq!(row[4], want, "{code} body bytes");
    }
    // Replies: one row for 0x90…0x96 listing their lengths in order, one for the uploads.
    let head = Body {
        fields: REPLY_HEAD,
        tail: Tail::None,
    }
    .fixed_len();
    let reply_len = |m: MsgType| head + m.reply_body().unwrap().fixed_len();
    let lens: Vec<String> = MsgType::ALL
        .iter()
        .filter(|m| (0x10..=0x16).contains(&(**m as u8)))
        .map(|m| reply_len(*m).to_string())
        .collect();
    // (The body-bytes column is the last: a name cell may hold an escaped `\|`.)
    let last = |r: &Vec<String>| r[r.len() - 2].clone();
    let row = table.iter().find(|r| r[1].starts_with("`0x90`")).unwrap();
    assert_eq!(last(row), lens.join(", "), "reply lengths");
    let row = table.iter().find(|r| r[1].starts_with("`0x97`")).unwrap();
    assert_eq!(last(row), reply_len(MsgType::UploadBegin).to_string());
}

/// Every wire example quoted in docs/protocol.md (`04…00` in backticks) is a valid frame.
#[test]
fn docs_wire_examples_decode() {
    let doc = std::fs::read_to_string(manifest().join("../docs/protocol.md")).unwrap();
    let mut n = 0;
    for piece in doc.split('`') {
        let hex = piece.trim();
        if hex.len() < 10
            || hex.len() % 2 != 0
            || !hex.ends_with("00")
            || !hex.bytes().all(|b| b.is_ascii_hexdigit())
        {
            continue;
        }
        let bytes: Vec<u8> = (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
            .collect();
        if let Err(e) = protocol::decode(&bytes) {
            panic!("docs/protocol.md example {hex} does not decode: {e}");
        }
        n += 1;
    }
    assert!(n >= 10, "found only {n} wire examples in docs/protocol.md");
}
