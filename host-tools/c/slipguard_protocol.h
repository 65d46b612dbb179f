/*
 * slipguard_protocol.h: decoder for the slipguard flag-stream protocol, version 1, for hand
 * controllers written in C or C++. One header, no dependencies beyond <stdint.h> and
 * <stddef.h> (freestanding), no allocation, no global state; C99 and C++.
 *
 * The byte-by-byte description is docs/protocol.md; this header implements its "C decoder"
 * section and is tested against the Rust decoder (host-tools/tests/c_decoder.rs) on the
 * golden frames and on whole replay streams.
 *
 * Use:
 *     sg_deframer d;  sg_deframer_init(&d);
 *     for each received byte b:
 *         sg_frame f;
 *         int r = sg_deframer_push(&d, b, &f);
 *         if (r == SG_OK)            ... use f (f.type tells which union member is valid)
 *         else if (r != SG_PENDING)  ... a corrupt run (r = error code 1..9); count it
 *
 * Encoding commands (grasp start, lift, release, set threshold, stream mode, ping, info):
 * sg_encode_command. Model uploads are sent by `slipguard-export upload`; this header decodes
 * their replies (and the upload commands' headers, for logging).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef SLIPGUARD_PROTOCOL_H
#define SLIPGUARD_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define SG_VERSION 1u
#define SG_MAX_CHANNELS 16u
#define SG_HEADER_LEN 4u
#define SG_CRC_LEN 4u
#define SG_MAX_CHUNK 128u
/* The largest payload is an upload chunk: header 4 + offset 4 + 128 data + chunk CRC 4 + CRC 4. */
#define SG_MAX_PAYLOAD 144u
/* COBS of the largest payload (one overhead byte) plus the 0x00 delimiter. */
#define SG_MAX_WIRE 146u
#define SG_P_NONE 0xFFFFu

/* Message types (payload byte 1). */
#define SG_T_FLAGS 0x01u
#define SG_T_FAULT 0x02u
#define SG_T_ERROR 0x03u
#define SG_T_SAMPLES 0x04u
#define SG_T_PING 0x10u
#define SG_T_GRASP_START 0x11u
#define SG_T_RELEASE 0x12u
#define SG_T_SET_THRESHOLD 0x13u
#define SG_T_INFO 0x14u
#define SG_T_LIFT 0x15u
#define SG_T_STREAM_MODE 0x16u
#define SG_T_UPLOAD_BEGIN 0x17u
#define SG_T_UPLOAD_CHUNK 0x18u
#define SG_T_UPLOAD_COMMIT 0x19u
#define SG_T_REPLY 0x80u /* reply type = command type | SG_T_REPLY */

/* Flag-frame status bits. */
#define SG_ST_ARMED 0x01u
#define SG_ST_LATE 0x02u
#define SG_ST_TARED 0x04u
#define SG_ST_HAND_UNSTABLE 0x08u /* the hand flag (the UNSTABLE line); 0 while not armed */

/* Phase marks of a samples frame: the commands handled since the previous frame. */
#define SG_MARK_GRASP_START 0x01u
#define SG_MARK_LIFT 0x02u
#define SG_MARK_RELEASE 0x04u

/* Stream modes (stream-mode command). */
#define SG_MODE_FLAGS 0u
#define SG_MODE_FLAGS_SAMPLES 1u
#define SG_MODE_SAMPLES 2u

/* Upload reply codes (docs/protocol.md says what to fix for each). */
#define SG_UP_OK 0u
#define SG_UP_NOT_STARTED 1u
#define SG_UP_ARMED 2u
#define SG_UP_WRONG_SIZE 3u
#define SG_UP_OUT_OF_ORDER 4u
#define SG_UP_BAD_CHUNK 5u
#define SG_UP_CHUNK_LENGTH 6u
#define SG_UP_FLASH 7u
#define SG_UP_INCOMPLETE 8u
#define SG_UP_BLOB_CRC 9u
#define SG_UP_BAD_BLOB 10u
#define SG_UP_RATE_MISMATCH 11u
#define SG_UP_UNIT_MISMATCH 12u
#define SG_UP_UNSUPPORTED 13u

/* Fault codes (fault frame byte 8). */
#define SG_FAULT_BAD_MODEL 1u
#define SG_FAULT_RATE_MISMATCH 2u
#define SG_FAULT_SENSOR_STALL 3u
#define SG_FAULT_UNIT_MISMATCH 4u

/* Return values: SG_OK, SG_PENDING (deframer: no frame ended), or a decode error whose number
 * is the one the device sends in its error frames. */
#define SG_OK 0
#define SG_E_EMPTY 1
#define SG_E_COBS 2
#define SG_E_TOO_LONG 3
#define SG_E_TRUNCATED 4
#define SG_E_CRC 5
#define SG_E_VERSION 6
#define SG_E_TYPE 7
#define SG_E_LENGTH 8
#define SG_E_VALUE 9
#define SG_PENDING (-1)

typedef struct {
    uint32_t timestamp_us; /* last sample of the frame, µs since the first scan (wraps) */
    uint8_t status;        /* SG_ST_* */
    uint8_t channels;      /* N, 1..16 */
    uint16_t unstable;     /* bit c: channel c unstable */
    uint16_t fault;        /* bit c: channel c faulted */
    uint16_t overruns;
    uint16_t skipped;
    uint16_t p[SG_MAX_CHANNELS]; /* Q0.15 p(unstable), SG_P_NONE = not predicted; [N..] = SG_P_NONE */
} sg_flags;

/* One frame of model input (sample stream). */
typedef struct {
    uint32_t timestamp_us; /* as in flag frames */
    uint8_t status;        /* SG_ST_* */
    uint8_t marks;         /* SG_MARK_* */
    uint8_t channels;      /* N, 1..16 */
    uint8_t unit;          /* 0 mN (hand), 1 counts = 1/16 ADC count (suction) */
    uint16_t fault;        /* bit c: channel c faulted */
    int32_t value[SG_MAX_CHANNELS]; /* model input of channel c in `unit`; [N..] = 0 */
} sg_samples;

typedef struct {
    uint32_t timestamp_us;
    uint8_t code; /* SG_FAULT_* */
    uint8_t detail;
    uint32_t value;
} sg_fault;

typedef struct {
    uint8_t error;        /* SG_E_* of the frame the device rejected */
    uint8_t msg_type;     /* its type when its CRC was good, else 0 */
    uint16_t request_seq; /* its seq when its CRC was good, else 0xFFFF */
} sg_error;

typedef struct {
    uint8_t firmware[3];
    uint8_t profile; /* 0 hand, 1 suction */
    uint8_t channels;
    uint8_t oversample;
    uint8_t model_ok;
    uint8_t variant;
    uint16_t hidden;
    uint32_t model_id;
    uint32_t model_crc;
    uint32_t sample_rate_mhz;
    uint16_t threshold_q15;
    uint8_t raise_after;
    uint8_t clear_after;
    char name[13]; /* 12 bytes from the wire + a terminating 0 */
} sg_info;

/* A command (controller -> device) or the fields of a reply. */
typedef struct {
    uint32_t token;         /* ping / pong */
    uint16_t threshold_q15; /* set threshold / its reply */
    uint8_t raise_after;
    uint8_t clear_after;
    uint8_t mode;           /* stream mode / its reply: SG_MODE_* */
    uint32_t size;          /* upload begin: blob bytes */
    uint32_t crc;           /* upload begin: blob CRC-32; upload chunk: chunk CRC-32 */
    uint32_t offset;        /* upload chunk: offset (decoded only, data not kept) */
    uint8_t len;            /* upload chunk: data bytes */
} sg_args;

/* Reply to an upload command (begin, chunk, commit). */
typedef struct {
    uint8_t code;   /* SG_UP_* */
    uint8_t detail; /* blob error kind (SG_UP_BAD_BLOB), flash step (SG_UP_FLASH) */
    uint8_t slot;   /* slot written, or made active by a commit */
    uint32_t value; /* next expected offset, CRC, rate... (docs/protocol.md) */
} sg_upload;

typedef struct {
    uint16_t request_seq;
    uint8_t status; /* 0 ok, 1 bad argument, 2 no model */
    sg_args args;   /* pong token, threshold in force, stream mode in force */
    sg_info info;   /* reply to info */
    sg_upload upload; /* reply to an upload command */
} sg_reply;

typedef struct {
    uint8_t type; /* SG_T_*; replies have SG_T_REPLY set */
    uint16_t seq;
    union {
        sg_flags flags;
        sg_samples samples;
        sg_fault fault;
        sg_error error;
        sg_args command;
        sg_reply reply;
    } u;
} sg_frame;

/* CRC-32/ISO-HDLC (zlib crc32): reflected 0x04C11DB7, init and xorout 0xFFFFFFFF. */
static inline uint32_t sg_crc32(const uint8_t *data, size_t len) {
    uint32_t crc = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < len; i++) {
        crc ^= data[i];
        for (k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return crc ^ 0xFFFFFFFFu;
}

/* COBS-decodes `len` bytes (no 0x00 delimiter) into `out` (capacity `cap`). Returns the decoded
 * length, or -SG_E_COBS (a zero byte or a code running past the end) / -SG_E_TOO_LONG. */
/* Whether the hand flag of a flag frame is up. */
static inline int sg_flags_hand_unstable(const sg_flags *f) {
    return (f->status & SG_ST_HAND_UNSTABLE) != 0;
}

/* Contact mask of a flag frame: bit c set while channel c is in contact, i.e. predicted on. The
 * device sends SG_P_NONE exactly for the channels faulted (fault bit set) or out of contact. */
static inline uint16_t sg_flags_contact(const sg_flags *f) {
    uint16_t m = 0;
    unsigned c;
    for (c = 0; c < f->channels && c < SG_MAX_CHANNELS; c++)
        if (f->p[c] != SG_P_NONE && !(f->fault & (1u << c))) m = (uint16_t)(m | (1u << c));
    return m;
}

static inline int sg_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap) {
    size_t i = 0, o = 0;
    while (i < len) {
        size_t code = in[i], j;
        if (code == 0 || i + code > len) return -SG_E_COBS;
        for (j = 1; j < code; j++) {
            if (in[i + j] == 0) return -SG_E_COBS;
            if (o >= cap) return -SG_E_TOO_LONG;
            out[o++] = in[i + j];
        }
        i += code;
        if (code < 0xFF && i < len) {
            if (o >= cap) return -SG_E_TOO_LONG;
            out[o++] = 0;
        }
    }
    return (int)o;
}

static inline uint16_t sg_u16(const uint8_t *b) { return (uint16_t)(b[0] | (b[1] << 8)); }
static inline uint32_t sg_u32(const uint8_t *b) {
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}

/* Body length of the fixed-size types, -1 for flags, samples, upload chunks and unknown types. */
static inline int sg_fixed_body_len(uint8_t t) {
    switch (t) {
    case SG_T_FAULT: return 10;
    case SG_T_ERROR: return 4;
    case SG_T_PING: return 4;
    case SG_T_GRASP_START: case SG_T_RELEASE: case SG_T_INFO: case SG_T_LIFT:
    case SG_T_UPLOAD_COMMIT: return 0;
    case SG_T_SET_THRESHOLD: return 4;
    case SG_T_STREAM_MODE: return 1;
    case SG_T_UPLOAD_BEGIN: return 8;
    case SG_T_REPLY | SG_T_PING: return 7;
    case SG_T_REPLY | SG_T_GRASP_START: case SG_T_REPLY | SG_T_RELEASE:
    case SG_T_REPLY | SG_T_LIFT: return 3;
    case SG_T_REPLY | SG_T_SET_THRESHOLD: return 7;
    case SG_T_REPLY | SG_T_INFO: return 43;
    case SG_T_REPLY | SG_T_STREAM_MODE: return 4;
    case SG_T_REPLY | SG_T_UPLOAD_BEGIN: case SG_T_REPLY | SG_T_UPLOAD_CHUNK:
    case SG_T_REPLY | SG_T_UPLOAD_COMMIT: return 10;
    default: return -1;
    }
}

/* Decodes one payload (header, body, CRC; already COBS-decoded). Checks in the protocol's order:
 * length, CRC, version, type, body length, field values. Returns SG_OK or SG_E_*. */
static inline int sg_decode_payload(const uint8_t *p, size_t n, sg_frame *f) {
    size_t body_len, c;
    const uint8_t *b;
    uint8_t t;
    if (n > SG_MAX_PAYLOAD) return SG_E_TOO_LONG;
    if (n < SG_HEADER_LEN + SG_CRC_LEN) return SG_E_TRUNCATED;
    if (sg_u32(p + n - SG_CRC_LEN) != sg_crc32(p, n - SG_CRC_LEN)) return SG_E_CRC;
    if (p[0] != SG_VERSION) return SG_E_VERSION;
    t = p[1];
    b = p + SG_HEADER_LEN;
    body_len = n - SG_HEADER_LEN - SG_CRC_LEN;
    if (t == SG_T_FLAGS) {
        if (body_len < 14) return SG_E_LENGTH;
    } else if (t == SG_T_SAMPLES) {
        if (body_len < 10) return SG_E_LENGTH;
    } else if (t == SG_T_UPLOAD_CHUNK) {
        if (body_len < 4 + 1 + 4 || body_len > 4 + SG_MAX_CHUNK + 4) return SG_E_LENGTH;
    } else {
        int want = sg_fixed_body_len(t);
        if (want < 0) return SG_E_TYPE;
        if ((size_t)want != body_len) return SG_E_LENGTH;
    }
    f->type = t;
    f->seq = sg_u16(p + 2);
    switch (t) {
    case SG_T_FLAGS: {
        sg_flags *fl = &f->u.flags;
        uint16_t valid;
        fl->timestamp_us = sg_u32(b);
        fl->status = b[4];
        fl->channels = b[5];
        if (fl->channels == 0 || fl->channels > SG_MAX_CHANNELS) return SG_E_VALUE;
        if (body_len != 14u + 2u * fl->channels) return SG_E_LENGTH;
        fl->unstable = sg_u16(b + 6);
        fl->fault = sg_u16(b + 8);
        fl->overruns = sg_u16(b + 10);
        fl->skipped = sg_u16(b + 12);
        for (c = 0; c < SG_MAX_CHANNELS; c++) {
            fl->p[c] = c < fl->channels ? sg_u16(b + 14 + 2 * c) : (uint16_t)SG_P_NONE;
            if (c < fl->channels && fl->p[c] > 0x7FFFu && fl->p[c] != SG_P_NONE) return SG_E_VALUE;
        }
        valid = fl->channels == 16 ? 0xFFFFu : (uint16_t)((1u << fl->channels) - 1u);
        if ((fl->unstable & ~valid) || (fl->fault & ~valid)) return SG_E_VALUE;
        return SG_OK;
    }
    case SG_T_SAMPLES: {
        sg_samples *sm = &f->u.samples;
        uint16_t valid;
        sm->timestamp_us = sg_u32(b);
        sm->status = b[4];
        sm->marks = b[5];
        sm->channels = b[6];
        sm->unit = b[7];
        if (sm->channels == 0 || sm->channels > SG_MAX_CHANNELS) return SG_E_VALUE;
        if (sm->marks & ~(SG_MARK_GRASP_START | SG_MARK_LIFT | SG_MARK_RELEASE)) return SG_E_VALUE;
        if (body_len != 10u + 4u * sm->channels) return SG_E_LENGTH;
        sm->fault = sg_u16(b + 8);
        for (c = 0; c < SG_MAX_CHANNELS; c++)
            sm->value[c] = c < sm->channels ? (int32_t)sg_u32(b + 10 + 4 * c) : 0;
        valid = sm->channels == 16 ? 0xFFFFu : (uint16_t)((1u << sm->channels) - 1u);
        if (sm->fault & ~valid) return SG_E_VALUE;
        return SG_OK;
    }
    case SG_T_FAULT:
        f->u.fault.timestamp_us = sg_u32(b);
        f->u.fault.code = b[4];
        f->u.fault.detail = b[5];
        f->u.fault.value = sg_u32(b + 6);
        return SG_OK;
    case SG_T_ERROR:
        f->u.error.error = b[0];
        f->u.error.msg_type = b[1];
        f->u.error.request_seq = sg_u16(b + 2);
        return SG_OK;
    case SG_T_PING:
        f->u.command.token = sg_u32(b);
        return SG_OK;
    case SG_T_GRASP_START: case SG_T_RELEASE: case SG_T_INFO: case SG_T_LIFT:
    case SG_T_UPLOAD_COMMIT:
        return SG_OK;
    case SG_T_STREAM_MODE:
        f->u.command.mode = b[0];
        return b[0] > SG_MODE_SAMPLES ? SG_E_VALUE : SG_OK;
    case SG_T_UPLOAD_BEGIN:
        f->u.command.size = sg_u32(b);
        f->u.command.crc = sg_u32(b + 4);
        return SG_OK;
    case SG_T_UPLOAD_CHUNK:
        f->u.command.offset = sg_u32(b);
        f->u.command.len = (uint8_t)(body_len - 8);
        f->u.command.crc = sg_u32(b + body_len - 4);
        return SG_OK;
    case SG_T_SET_THRESHOLD:
        f->u.command.threshold_q15 = sg_u16(b);
        f->u.command.raise_after = b[2];
        f->u.command.clear_after = b[3];
        if (f->u.command.threshold_q15 == 0 || f->u.command.threshold_q15 > 0x7FFFu ||
            f->u.command.raise_after == 0 || f->u.command.clear_after == 0)
            return SG_E_VALUE;
        return SG_OK;
    default: { /* a reply; its length was checked */
        sg_reply *r = &f->u.reply;
        r->request_seq = sg_u16(b);
        r->status = b[2];
        if (r->status > 2) return SG_E_VALUE;
        b += 3;
        switch (t & (uint8_t)~SG_T_REPLY) {
        case SG_T_PING: r->args.token = sg_u32(b); break;
        case SG_T_SET_THRESHOLD:
            r->args.threshold_q15 = sg_u16(b);
            r->args.raise_after = b[2];
            r->args.clear_after = b[3];
            break;
        case SG_T_STREAM_MODE:
            r->args.mode = b[0];
            if (b[0] > SG_MODE_SAMPLES) return SG_E_VALUE;
            break;
        case SG_T_UPLOAD_BEGIN: case SG_T_UPLOAD_CHUNK: case SG_T_UPLOAD_COMMIT:
            r->upload.code = b[0];
            r->upload.detail = b[1];
            r->upload.slot = b[2];
            r->upload.value = sg_u32(b + 3);
            break;
        case SG_T_INFO: {
            sg_info *i = &r->info;
            if (b[0] != SG_VERSION) return SG_E_VALUE;
            for (c = 0; c < 3; c++) i->firmware[c] = b[1 + c];
            i->profile = b[4];
            i->channels = b[5];
            i->oversample = b[6];
            i->model_ok = b[7];
            i->variant = b[8];
            /* b[9] reserved */
            i->hidden = sg_u16(b + 10);
            i->model_id = sg_u32(b + 12);
            i->model_crc = sg_u32(b + 16);
            i->sample_rate_mhz = sg_u32(b + 20);
            i->threshold_q15 = sg_u16(b + 24);
            i->raise_after = b[26];
            i->clear_after = b[27];
            for (c = 0; c < 12; c++) i->name[c] = (char)b[28 + c];
            i->name[12] = 0;
            break;
        }
        default: break; /* grasp started, lifted, released: no fields */
        }
        return SG_OK;
    }
    }
}

/* Decodes one frame from its wire bytes without the delimiter (a trailing 0x00 is tolerated). */
static inline int sg_decode(const uint8_t *wire, size_t len, sg_frame *f) {
    uint8_t payload[SG_MAX_PAYLOAD];
    int n;
    if (len > 0 && wire[len - 1] == 0) len--;
    if (len == 0) return SG_E_EMPTY;
    if (len > SG_MAX_WIRE - 1) return SG_E_TOO_LONG;
    n = sg_cobs_decode(wire, len, payload, sizeof payload);
    if (n < 0) return -n;
    return sg_decode_payload(payload, (size_t)n, f);
}

/* Splits a byte stream at 0x00 delimiters and resynchronises after garbage: a run longer than
 * any frame is dropped up to the next delimiter and reported once as SG_E_TOO_LONG. */
typedef struct {
    uint8_t buf[SG_MAX_WIRE];
    size_t len;
    int overflow;
} sg_deframer;

static inline void sg_deframer_init(sg_deframer *d) {
    d->len = 0;
    d->overflow = 0;
}

/* Feeds one byte. Returns SG_PENDING until a delimiter ends a non-empty run, then SG_OK with
 * `*f` filled, or the run's error (SG_E_*). Empty runs (00 00) are ignored. */
static inline int sg_deframer_push(sg_deframer *d, uint8_t byte, sg_frame *f) {
    if (byte == 0) {
        size_t len = d->len;
        d->len = 0;
        if (d->overflow) {
            d->overflow = 0;
            return SG_E_TOO_LONG;
        }
        if (len == 0) return SG_PENDING;
        return sg_decode(d->buf, len, f);
    }
    if (d->overflow) return SG_PENDING;
    if (d->len < SG_MAX_WIRE - 1) {
        d->buf[d->len++] = byte;
    } else {
        d->overflow = 1;
        d->len = 0;
    }
    return SG_PENDING;
}

/* Encodes a command for the device: `type` one of SG_T_PING (args->token), SG_T_GRASP_START,
 * SG_T_LIFT, SG_T_RELEASE, SG_T_SET_THRESHOLD (args->threshold_q15, raise_after, clear_after),
 * SG_T_STREAM_MODE (args->mode), SG_T_INFO;
 * `args` may be NULL for the commands without fields. Writes COBS(payload) 00 into `out`
 * (at least SG_MAX_WIRE bytes) and returns the number of bytes to send, 0 for an unknown type. */
static inline size_t sg_encode_command(uint8_t type, uint16_t seq, const sg_args *args, uint8_t *out) {
    uint8_t p[SG_HEADER_LEN + 4 + SG_CRC_LEN];
    size_t n = 0, i, code_at = 0, o = 1;
    uint32_t crc;
    p[n++] = SG_VERSION;
    p[n++] = type;
    p[n++] = (uint8_t)seq;
    p[n++] = (uint8_t)(seq >> 8);
    switch (type) {
    case SG_T_PING:
        if (!args) return 0;
        for (i = 0; i < 4; i++) p[n++] = (uint8_t)(args->token >> (8 * i));
        break;
    case SG_T_SET_THRESHOLD:
        if (!args) return 0;
        p[n++] = (uint8_t)args->threshold_q15;
        p[n++] = (uint8_t)(args->threshold_q15 >> 8);
        p[n++] = args->raise_after;
        p[n++] = args->clear_after;
        break;
    case SG_T_STREAM_MODE:
        if (!args || args->mode > SG_MODE_SAMPLES) return 0;
        p[n++] = args->mode;
        break;
    case SG_T_GRASP_START: case SG_T_RELEASE: case SG_T_INFO: case SG_T_LIFT: break;
    default: return 0;
    }
    crc = sg_crc32(p, n);
    for (i = 0; i < 4; i++) p[n++] = (uint8_t)(crc >> (8 * i));
    /* COBS: payloads here are < 254 bytes, so one code byte per zero. */
    for (i = 0; i < n; i++) {
        if (p[i] == 0) {
            out[code_at] = (uint8_t)(o - code_at);
            code_at = o++;
        } else {
            out[o++] = p[i];
        }
    }
    out[code_at] = (uint8_t)(o - code_at);
    out[o++] = 0;
    return o;
}

#ifdef __cplusplus
}
#endif

#endif /* SLIPGUARD_PROTOCOL_H */
