/*
 * Test driver for slipguard_protocol.h (host-tools/tests/c_decoder.rs builds and runs it).
 *   test_decode < stream.bin   one line per delimiter-terminated run: the frame's fields, or
 *                              "bad <error code>"
 *   test_decode --encode       the golden commands of docs/protocol.md, as hex
 */
#include <stdio.h>
#include <string.h>

#include "slipguard_protocol.h"

static void print_frame(const sg_frame *f) {
    unsigned c;
    switch (f->type) {
    case SG_T_FLAGS: {
        const sg_flags *x = &f->u.flags;
        printf("flags seq=%u t=%lu st=%u n=%u unst=%u fault=%u ovr=%u skip=%u p=", f->seq,
               (unsigned long)x->timestamp_us, x->status, x->channels, x->unstable, x->fault,
               x->overruns, x->skipped);
        for (c = 0; c < x->channels; c++) printf(c ? ",%u" : "%u", x->p[c]);
        printf(" hand=%d rule=%d contact=%u\n", sg_flags_hand_unstable(x), sg_flags_hand_by_rule(x),
               sg_flags_contact(x));
        break;
    }
    case SG_T_SAMPLES: {
        const sg_samples *x = &f->u.samples;
        printf("samples seq=%u t=%lu st=%u marks=%u n=%u unit=%u fault=%u v=", f->seq,
               (unsigned long)x->timestamp_us, x->status, x->marks, x->channels, x->unit, x->fault);
        for (c = 0; c < x->channels; c++) printf(c ? ",%ld" : "%ld", (long)x->value[c]);
        printf("\n");
        break;
    }
    case SG_T_FAULT:
        printf("fault seq=%u t=%lu code=%u detail=%u value=%lu\n", f->seq,
               (unsigned long)f->u.fault.timestamp_us, f->u.fault.code, f->u.fault.detail,
               (unsigned long)f->u.fault.value);
        break;
    case SG_T_ERROR:
        printf("error seq=%u error=%u type=%u rseq=%u\n", f->seq, f->u.error.error,
               f->u.error.msg_type, f->u.error.request_seq);
        break;
    case SG_T_PING:
        printf("ping seq=%u token=%lu\n", f->seq, (unsigned long)f->u.command.token);
        break;
    case SG_T_GRASP_START: printf("grasp_start seq=%u\n", f->seq); break;
    case SG_T_RELEASE: printf("release seq=%u\n", f->seq); break;
    case SG_T_INFO: printf("info seq=%u\n", f->seq); break;
    case SG_T_LIFT: printf("lift seq=%u\n", f->seq); break;
    case SG_T_STREAM_MODE: printf("stream_mode seq=%u mode=%u\n", f->seq, f->u.command.mode); break;
    case SG_T_UPLOAD_BEGIN:
        printf("upload_begin seq=%u size=%lu crc=%lu\n", f->seq, (unsigned long)f->u.command.size,
               (unsigned long)f->u.command.crc);
        break;
    case SG_T_UPLOAD_CHUNK:
        printf("upload_chunk seq=%u offset=%lu len=%u crc=%lu\n", f->seq,
               (unsigned long)f->u.command.offset, f->u.command.len,
               (unsigned long)f->u.command.crc);
        break;
    case SG_T_UPLOAD_COMMIT: printf("upload_commit seq=%u\n", f->seq); break;
    case SG_T_SET_THRESHOLD:
        printf("set_threshold seq=%u thr=%u raise=%u clear=%u\n", f->seq,
               f->u.command.threshold_q15, f->u.command.raise_after, f->u.command.clear_after);
        break;
    default: {
        const sg_reply *r = &f->u.reply;
        printf("reply seq=%u type=%u rseq=%u status=%u", f->seq, f->type, r->request_seq, r->status);
        switch (f->type & (uint8_t)~SG_T_REPLY) {
        case SG_T_PING: printf(" token=%lu", (unsigned long)r->args.token); break;
        case SG_T_SET_THRESHOLD:
            printf(" thr=%u raise=%u clear=%u", r->args.threshold_q15, r->args.raise_after,
                   r->args.clear_after);
            break;
        case SG_T_STREAM_MODE: printf(" mode=%u", r->args.mode); break;
        case SG_T_UPLOAD_BEGIN: case SG_T_UPLOAD_CHUNK: case SG_T_UPLOAD_COMMIT:
            printf(" code=%u detail=%u slot=%u value=%lu", r->upload.code, r->upload.detail,
                   r->upload.slot, (unsigned long)r->upload.value);
            break;
        case SG_T_INFO: {
            const sg_info *i = &r->info;
            printf(" fw=%u.%u.%u profile=%u n=%u os=%u ok=%u variant=%u hidden=%u id=%lu crc=%lu "
                   "rate=%lu thr=%u raise=%u clear=%u name=%s",
                   i->firmware[0], i->firmware[1], i->firmware[2], i->profile, i->channels,
                   i->oversample, i->model_ok, i->variant, i->hidden, (unsigned long)i->model_id,
                   (unsigned long)i->model_crc, (unsigned long)i->sample_rate_mhz,
                   i->threshold_q15, i->raise_after, i->clear_after, i->name);
            break;
        }
        default: break;
        }
        printf("\n");
    }
    }
}

static void hex(const uint8_t *b, size_t n) {
    size_t i;
    for (i = 0; i < n; i++) printf("%02x", b[i]);
    printf("\n");
}

int main(int argc, char **argv) {
    if (argc > 1 && strcmp(argv[1], "--encode") == 0) {
        uint8_t out[SG_MAX_WIRE];
        sg_args a;
        memset(&a, 0, sizeof a);
        a.token = 0xDEADBEEFu;
        hex(out, sg_encode_command(SG_T_PING, 7, &a, out));
        a.threshold_q15 = 19661;
        a.raise_after = 2;
        a.clear_after = 3;
        hex(out, sg_encode_command(SG_T_SET_THRESHOLD, 8, &a, out));
        hex(out, sg_encode_command(SG_T_GRASP_START, 9, NULL, out));
        a.mode = SG_MODE_FLAGS_SAMPLES;
        hex(out, sg_encode_command(SG_T_STREAM_MODE, 10, &a, out));
        hex(out, sg_encode_command(SG_T_LIFT, 11, NULL, out));
        printf("crc=%08lx\n", (unsigned long)sg_crc32((const uint8_t *)"123456789", 9));
        return 0;
    }
    {
        sg_deframer d;
        int ch;
        sg_deframer_init(&d);
        while ((ch = getchar()) != EOF) {
            sg_frame f;
            int r = sg_deframer_push(&d, (uint8_t)ch, &f);
            if (r == SG_OK)
                print_frame(&f);
            else if (r != SG_PENDING)
                printf("bad %d\n", r);
        }
    }
    return 0;
}
