//! The C decoder header `host-tools/c/slipguard_protocol.h`, generated from the core's wire
//! layout (`slipguard_core::protocol`: [`MsgType`] with its body layouts, [`REPLY_HEAD`], the
//! code tables) and the template `host-tools/c/slipguard_protocol.h.in`, which holds the C that
//! does not depend on the layout (CRC, COBS, the deframer, the structs a controller uses) and
//! reads every offset and length through the generated constants.
//!
//! `host-tools/tests/c_header.rs` fails while the checked-in header differs from [`generate`];
//! `SLIPGUARD_BLESS=1 cargo test -p slipguard --test c_header` rewrites it.

use std::fmt::Write as _;

use slipguard_app::profile::ProfileId;

use slipguard_core::protocol::{
    self, Body, CRC_LEN, Code, DecodeError, HEADER_LEN, MAX_CHANNELS, MAX_CHUNK, MAX_PAYLOAD,
    MAX_WIRE, MsgType, P_NONE, REPLY_HEAD, ReplyStatus, StreamMode, Tail, VERSION, fault_code,
    mark, msg_type, status, upload_code,
};

/// The template the generated constants and layout are put into.
pub const TEMPLATE: &str = include_str!("../c/slipguard_protocol.h.in");

/// Where the generated header is checked in, relative to the `host-tools` folder.
pub const HEADER_PATH: &str = "c/slipguard_protocol.h";

/// `grasp start` → `GRASP_START`.
fn upper(name: &str) -> String {
    name.to_ascii_uppercase().replace(' ', "_")
}

/// A doc text as a C comment: one line, rustdoc link brackets dropped (empty when there is none).
fn comment(doc: &str) -> String {
    let text = doc
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace("[`", "`")
        .replace("`]", "`")
        .replace("*/", "* /");
    if text.is_empty() {
        String::new()
    } else {
        format!(" /* {text} */")
    }
}

/// `#define`s of a code table: bit masks in hex, numbered codes in decimal.
fn codes(out: &mut String, title: &str, prefix: &str, codes: &[Code], bits: bool) {
    let _ = writeln!(out, "\n/* {title} */");
    for c in codes {
        let value = if bits {
            format!("0x{:02X}u", c.value)
        } else {
            format!("{}u", c.value)
        };
        let _ = writeln!(out, "#define {prefix}{} {value}{}", c.name, comment(c.doc));
    }
}

fn constants() -> String {
    let mut o = String::new();
    let _ = writeln!(o, "#define SG_VERSION {VERSION}u");
    let _ = writeln!(o, "#define SG_MAX_CHANNELS {MAX_CHANNELS}u");
    let _ = writeln!(o, "#define SG_HEADER_LEN {HEADER_LEN}u");
    let _ = writeln!(o, "#define SG_CRC_LEN {CRC_LEN}u");
    let _ = writeln!(o, "#define SG_MAX_CHUNK {MAX_CHUNK}u");
    let _ = writeln!(
        o,
        "/* The largest payload is an upload chunk: header, offset, {MAX_CHUNK} data bytes, chunk CRC, CRC. */"
    );
    let _ = writeln!(o, "#define SG_MAX_PAYLOAD {MAX_PAYLOAD}u");
    let _ = writeln!(
        o,
        "/* COBS of the largest payload (one overhead byte) plus the 0x00 delimiter. */"
    );
    let _ = writeln!(o, "#define SG_MAX_WIRE {MAX_WIRE}u");
    let _ = writeln!(o, "#define SG_P_NONE 0x{P_NONE:04X}u");

    let _ = writeln!(o, "\n/* Message types (payload byte 1). */");
    for m in MsgType::ALL {
        let _ = writeln!(
            o,
            "#define SG_T_{} 0x{:02X}u /* {}: {} */",
            upper(m.name()),
            m as u8,
            if m.is_command() {
                "controller -> device"
            } else {
                "device -> controller"
            },
            m.name()
        );
    }
    let _ = writeln!(
        o,
        "#define SG_T_REPLY 0x{:02X}u /* reply type = command type | SG_T_REPLY */",
        msg_type::REPLY
    );

    codes(
        &mut o,
        "Flag-frame status bits.",
        "SG_ST_",
        status::ALL,
        true,
    );
    codes(
        &mut o,
        "Phase marks of a samples frame: the commands handled since the previous frame.",
        "SG_MARK_",
        mark::ALL,
        true,
    );
    let _ = writeln!(o, "\n/* Stream modes (stream-mode command). */");
    for (name, m) in [
        ("FLAGS", StreamMode::Flags),
        ("FLAGS_SAMPLES", StreamMode::FlagsAndSamples),
        ("SAMPLES", StreamMode::Samples),
    ] {
        let _ = writeln!(o, "#define SG_MODE_{name} {}u", m as u8);
    }
    let _ = writeln!(o, "\n/* Reply status (byte 2 of every reply body). */");
    for (name, s) in [
        ("OK", ReplyStatus::Ok),
        ("BAD_ARGUMENT", ReplyStatus::BadArgument),
        ("NO_MODEL", ReplyStatus::NoModel),
    ] {
        let _ = writeln!(o, "#define SG_STATUS_{name} {}u", s as u8);
    }
    let _ = writeln!(
        o,
        "\n/* Sensor profiles (info reply `profile`): slipguard_app::profile::ProfileId. */"
    );
    for id in ProfileId::ALL {
        let p = id.profile();
        let rates: Vec<String> = p
            .rates_mhz
            .iter()
            .map(|r| format!("{} Hz", (*r).hz()))
            .collect();
        let _ = writeln!(
            o,
            "#define SG_PROFILE_{} {}u /* {} channels, {}, {} */",
            upper(p.name),
            id as u8,
            p.channels,
            p.unit,
            rates.join(" or ")
        );
    }
    codes(
        &mut o,
        "Upload reply codes (docs/protocol.md says what to fix for each).",
        "SG_UP_",
        upload_code::ALL,
        false,
    );
    codes(
        &mut o,
        "Fault codes (fault frame body byte 4).",
        "SG_FAULT_",
        fault_code::ALL,
        false,
    );

    let _ = writeln!(
        o,
        "\n/* Return values: SG_OK, SG_PENDING (deframer: no frame ended), or a decode error whose number\n * is the one the device sends in its error frames. */"
    );
    let _ = writeln!(o, "#define SG_OK 0");
    for (name, e) in [
        ("EMPTY", DecodeError::Empty),
        ("COBS", DecodeError::Cobs),
        ("TOO_LONG", DecodeError::TooLong),
        ("TRUNCATED", DecodeError::Truncated { len: 0 }),
        (
            "CRC",
            DecodeError::BadCrc {
                stored: 0,
                computed: 0,
            },
        ),
        ("VERSION", DecodeError::WrongVersion(0)),
        ("TYPE", DecodeError::UnknownType(0)),
        (
            "LENGTH",
            DecodeError::BadLength {
                msg_type: 0,
                len: 0,
            },
        ),
        ("VALUE", DecodeError::BadValue { msg_type: 0 }),
    ] {
        let _ = writeln!(o, "#define SG_E_{name} {}", e.code());
    }
    let _ = write!(o, "#define SG_PENDING (-1)");
    o
}

/// `SG_<PREFIX>_AT_<FIELD>` offsets of a body's fields (and its per-channel tail), and its
/// length constants.
fn body_defines(o: &mut String, prefix: &str, body: &Body) {
    let mut at = 0;
    for f in body.fields {
        let _ = writeln!(
            o,
            "#define {prefix}_AT_{} {at}u /* {:?}:{} */",
            upper(f.name),
            f.ty,
            comment(f.doc)
                .trim_start_matches(" /*")
                .trim_end_matches(" */")
        );
        at += f.ty.size();
    }
    let (min, _) = body.len_range();
    match body.tail {
        Tail::None => {
            let _ = writeln!(o, "#define {prefix}_LEN {min}u");
        }
        Tail::PerChannel(f) => {
            let _ = writeln!(
                o,
                "#define {prefix}_AT_{} {at}u /* {:?} per channel:{} */",
                upper(f.name),
                f.ty,
                comment(f.doc)
                    .trim_start_matches(" /*")
                    .trim_end_matches(" */")
            );
            let _ = writeln!(
                o,
                "#define {prefix}_{}_SIZE {}u",
                upper(f.name),
                f.ty.size()
            );
            let _ = writeln!(o, "#define {prefix}_LEN_MIN {min}u /* + N values */");
        }
        Tail::ChunkData => {
            let _ = writeln!(
                o,
                "#define {prefix}_LEN_MIN {min}u /* 1 data byte; data (1..{MAX_CHUNK} bytes) then the chunk CRC u32 follow the offset */"
            );
        }
    }
}

fn layout() -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "/* Body layouts: byte offsets of each field from the start of the body (payload byte {HEADER_LEN}),\n * and body lengths. Replies: SG_REPLY_* for the head every reply has, then SG_R_<COMMAND>_*\n * offsets counted from the end of that head. */"
    );
    for m in MsgType::ALL {
        body_defines(&mut o, &format!("SG_{}", upper(m.name())), &m.body());
    }
    let head = Body {
        fields: REPLY_HEAD,
        tail: Tail::None,
    };
    body_defines(&mut o, "SG_REPLY", &head);
    let _ = writeln!(o, "#define SG_REPLY_HEAD_LEN SG_REPLY_LEN");
    for m in MsgType::ALL {
        if let Some(b) = m.reply_body() {
            body_defines(&mut o, &format!("SG_R_{}", upper(m.name())), &b);
        }
    }

    let _ = writeln!(
        o,
        "\n/* Shortest body a type byte may carry, -1 for a type v1 does not define (flags and samples:\n * the fixed fields; an upload chunk: one data byte). */"
    );
    let _ = writeln!(o, "static inline int sg_body_len_min(uint8_t t) {{");
    let _ = writeln!(o, "    switch (t) {{");
    let mut max_cases = Vec::new();
    for t in 0..=u8::MAX {
        if let Some((min, max)) = protocol::body_len_range(t) {
            let name = match MsgType::from_u8(t & !msg_type::REPLY) {
                Some(m) if t & msg_type::REPLY != 0 => {
                    format!("SG_T_REPLY | SG_T_{}", upper(m.name()))
                }
                Some(m) => format!("SG_T_{}", upper(m.name())),
                None => unreachable!("a defined length for an undefined type"),
            };
            let _ = writeln!(o, "    case {name}: return {min};");
            if max != min {
                max_cases.push((name, max));
            }
        }
    }
    let _ = writeln!(o, "    default: return -1;\n    }}\n}}");
    let _ = writeln!(
        o,
        "\n/* Longest body a type byte may carry before its fields are read (flags and samples: any, the\n * exact length is checked once N is read). */"
    );
    let _ = writeln!(o, "static inline size_t sg_body_len_max(uint8_t t) {{");
    let _ = writeln!(o, "    switch (t) {{");
    for (name, max) in max_cases {
        if max == usize::MAX {
            let _ = writeln!(o, "    case {name}: return (size_t)-1;");
        } else {
            let _ = writeln!(o, "    case {name}: return {max}u;");
        }
    }
    let _ = writeln!(
        o,
        "    default: {{\n        int n = sg_body_len_min(t);\n        return n < 0 ? 0u : (size_t)n;\n    }}\n    }}\n}}"
    );
    o.pop();
    o
}

/// The header's text: the template with the generated constants and layout put in.
pub fn generate() -> String {
    TEMPLATE
        .replace("@CONSTANTS@", &constants())
        .replace("@LAYOUT@", &layout())
}
