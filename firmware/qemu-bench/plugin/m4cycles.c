/* slipguard's Cortex-M4 cycle ESTIMATE: a QEMU 7.2 TCG plugin (plugin API v1) for
 * `qemu-system-arm -M mps2-an386`. The model and its assumptions are in README.md beside this
 * file; the numbers are estimates for comparing designs, the DWT cycle counter on the chip is
 * the truth.
 *
 * Spans: the guest stores (any value) to MARKER + 8*id to open span `id` (0..MAX_SPANS-1) and
 * to MARKER + 8*id + 4 to close it. A span accumulates over every open/close pair: executions,
 * instructions, base cycles and flash stall cycles. At exit one line per used span:
 *   m4cycles: span ID n N insns I base_cycles B flash_stall S fetch_stall F est_cycles B+S
 * (F, part of S, is the stall of sequential instruction fetch: the fetch-bandwidth term; B+S-F
 * is the estimate with sequential fetch free, fetchbw=0's figure)
 * and, with prof=FILE, one line per instruction address executed while span `profspan` was
 * open: `0xADDR insns cycles stall` (map addresses to functions with arm-none-eabi-nm).
 *
 * Args: addr= (MARKER, default 0x20300000), ws= (flash wait states, 5), refill= (pipeline refill
 * cycles of a taken branch, 2), dlines= / ilines= (ART data / instruction cache lines, 8 / 64),
 * flo= / fhi= (flash address range, default [0, 0x20000000)), fetchbw= (1: sequential fetch from
 * flash has a bandwidth, the default; 0: sequential line changes are free), prof=FILE,
 * profspan=ID.
 *
 * Debian's qemu-system-arm 7.2 ships no qemu-plugin.h: the few API v1 declarations used are
 * written out below. Build: gcc -O2 -shared -fPIC -o libm4cycles.so m4cycles.c */
#include <ctype.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define QEMU_PLUGIN_EXPORT __attribute__((visibility("default")))
typedef uint64_t qemu_plugin_id_t;
typedef uint32_t qemu_plugin_meminfo_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
typedef struct qemu_info_t qemu_info_t;
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_CB_R_REGS, QEMU_PLUGIN_CB_RW_REGS };
enum qemu_plugin_mem_rw { QEMU_PLUGIN_MEM_R = 1, QEMU_PLUGIN_MEM_W, QEMU_PLUGIN_MEM_RW };
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_vcpu_mem_cb_t)(unsigned int, qemu_plugin_meminfo_t, uint64_t, void *);
typedef void (*qemu_plugin_vcpu_udata_cb_t)(unsigned int vcpu_index, void *userdata);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *tb, size_t idx);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *insn);
size_t qemu_plugin_insn_size(const struct qemu_plugin_insn *insn);
char *qemu_plugin_insn_disas(const struct qemu_plugin_insn *insn);
void qemu_plugin_register_vcpu_insn_exec_cb(struct qemu_plugin_insn *insn, qemu_plugin_vcpu_udata_cb_t cb,
                                            enum qemu_plugin_cb_flags flags, void *userdata);
void qemu_plugin_register_vcpu_mem_cb(struct qemu_plugin_insn *insn, qemu_plugin_vcpu_mem_cb_t cb,
                                      enum qemu_plugin_cb_flags flags, enum qemu_plugin_mem_rw rw,
                                      void *userdata);
bool qemu_plugin_mem_is_store(qemu_plugin_meminfo_t info);
void qemu_plugin_outs(const char *string);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);
QEMU_PLUGIN_EXPORT int qemu_plugin_version = 1;

/* Instruction classes whose cost depends on the neighbour (single loads/stores pipeline). */
enum kind { K_OTHER, K_LS1 };

/* One translated instruction. Translations of the same address share one record (the profile
 * is per address), found through a small open-addressing table. */
typedef struct insn_info {
    uint64_t pc;
    uint32_t size;
    uint8_t base;
    uint8_t kind;
    uint64_t prof_insns, prof_cycles, prof_stall;
} insn_info;

#define MAXL 128
typedef struct {
    uint64_t tag[MAXL], age[MAXL];
    int n;
    uint64_t clock;
} lru_t;

/* True on a hit; on a miss the least recently used line is replaced. */
static bool lru_access(lru_t *c, uint64_t line) {
    c->clock++;
    int victim = 0;
    for (int i = 0; i < c->n; i++) {
        if (c->tag[i] == line) {
            c->age[i] = c->clock;
            return true;
        }
        if (c->age[i] < c->age[victim]) victim = i;
    }
    c->tag[victim] = line;
    c->age[victim] = c->clock;
    return false;
}

#define MAX_SPANS 64
typedef struct {
    uint64_t n, insns, base, stall, fstall; /* totals over closed executions */
    uint64_t o_insns, o_base, o_stall, o_fstall; /* counters when it was opened */
    bool open, used;
} span_t;

static lru_t dc, ic;
static uint64_t marker = 0x20300000, flo = 0, fhi = 0x20000000, ws = 5, refill = 2, fetchbw = 1;
/* Totals: instructions, base cycles, all flash stalls, of which sequential-fetch stalls. */
static uint64_t insns, base, stall, fstall, next_pc = ~0ull, last_iline = ~0ull;
/* The prefetch buffer: the line it fetches next (the one after the line last delivered to the
 * core) and the cycle at which that line arrives from flash. */
static uint64_t pref_line = ~0ull, pref_at;
static uint8_t prev_kind;
static insn_info *cur; /* the instruction executing now (data stalls are charged to it) */
static span_t spans[MAX_SPANS];
static const char *prof_file;
static int prof_span = -1;

#define TABLE (1u << 16)
static insn_info *table[TABLE];

static insn_info *lookup(uint64_t pc) {
    uint32_t h = (uint32_t)(pc >> 1) * 2654435761u >> 16;
    for (uint32_t i = 0; i < TABLE; i++) {
        uint32_t k = (h + i) & (TABLE - 1);
        if (!table[k]) {
            table[k] = calloc(1, sizeof(insn_info));
            table[k]->pc = pc;
            return table[k];
        }
        if (table[k]->pc == pc) return table[k];
    }
    return NULL; /* more distinct addresses than the table holds: the guest is not a bench */
}

/* Registers named in {...}, ranges r4-r7 / s16-s31 included. */
static int count_regs(const char *s) {
    const char *a = strchr(s, '{'), *b = a ? strchr(a, '}') : NULL;
    if (!a || !b) return 1;
    int n = 0;
    const char *p = a + 1;
    while (p < b) {
        while (p < b && !isalpha((unsigned char)*p)) p++;
        if (p >= b) break;
        const char *q = p;
        while (q < b && *q != ',') q++;
        const char *dash = memchr(p, '-', q - p);
        if (dash) {
            int lo = atoi(p + 1), hi = atoi(dash + 2);
            n += (hi >= lo) ? hi - lo + 1 : 1;
        } else {
            n++;
        }
        p = q + 1;
    }
    return n ? n : 1;
}

static bool starts(const char *m, const char *p) { return strncmp(m, p, strlen(p)) == 0; }

/* Base cost from the Cortex-M4 TRM instruction timings (see README.md). */
static void classify(const char *d, insn_info *ii) {
    char m[16] = {0};
    int i = 0;
    while (d[i] && !isspace((unsigned char)d[i]) && i < 15) {
        m[i] = d[i];
        i++;
    }
    char *dot = strchr(m, '.');
    if (dot && (starts(dot, ".w") || starts(dot, ".n"))) *dot = 0;
    ii->base = 1;
    ii->kind = K_OTHER;
    if (starts(m, "ldrd") || starts(m, "strd")) ii->base = 3;
    else if (starts(m, "ldm") || starts(m, "stm") || starts(m, "push") || starts(m, "pop"))
        ii->base = 1 + count_regs(d);
    else if (starts(m, "ldr") || starts(m, "str")) {
        ii->base = 2;
        ii->kind = K_LS1;
    } else if (starts(m, "sdiv") || starts(m, "udiv")) ii->base = 6;
    else if (starts(m, "vldm") || starts(m, "vstm") || starts(m, "vpush") || starts(m, "vpop"))
        ii->base = 1 + count_regs(d);
    else if (starts(m, "vldr") || starts(m, "vstr")) ii->base = 2;
    else if (starts(m, "vmla") || starts(m, "vmls") || starts(m, "vfma") || starts(m, "vfms") ||
             starts(m, "vnml") || starts(m, "vfnm"))
        ii->base = 3;
    else if (starts(m, "vdiv") || starts(m, "vsqrt")) ii->base = 14;
}

/* The fetch of a new instruction line (`line`, by the instruction starting at cycle `now`):
 * the stall until it can be decoded. A hit in the ART's instruction cache costs nothing. A miss
 * in flash that is not the next sequential line is a new flash read: ws cycles. The next
 * sequential line is what the prefetch buffer has been reading since the previous line was
 * delivered; a flash read takes ws + 1 cycles (one line of 16 bytes per 6 cycles at 5 wait
 * states), so the core waits for whatever of that is left (fetchbw=1), or not at all
 * (fetchbw=0: sequential fetch free, the model's first version). Either way the prefetch
 * buffer then starts on the line after this one. *fetch_part gets the bandwidth part. */
static uint64_t fetch_line(uint64_t line, uint64_t pc, uint64_t now, uint64_t *fetch_part) {
    bool sequential = line == last_iline + 1;
    bool hit = lru_access(&ic, line);
    uint64_t s = 0;
    *fetch_part = 0;
    if (!hit && pc >= flo && pc < fhi) {
        if (!sequential) {
            s = ws;
        } else if (fetchbw && line == pref_line && pref_at > now) {
            s = pref_at - now;
            *fetch_part = s;
        }
    }
    pref_line = line + 1;
    pref_at = now + s + ws + 1;
    last_iline = line;
    return s;
}

static void on_exec(unsigned int vcpu, void *ud) {
    insn_info *ii = ud;
    uint64_t c = ii->base, s = 0, f = 0;
    if (ii->kind == K_LS1 && prev_kind == K_LS1) c -= 1;
    if (next_pc != ~0ull && ii->pc != next_pc) c += refill;
    prev_kind = ii->kind;
    next_pc = ii->pc + ii->size;
    uint64_t line = ii->pc >> 4;
    /* This instruction starts when everything before it is done. */
    if (line != last_iline) s = fetch_line(line, ii->pc, base + stall, &f);
    insns++;
    base += c;
    stall += s;
    fstall += f;
    cur = ii;
    if (prof_span >= 0 && spans[prof_span].open) {
        ii->prof_insns++;
        ii->prof_cycles += c + s;
        ii->prof_stall += s;
    }
}

static void on_mem(unsigned int vcpu, qemu_plugin_meminfo_t info, uint64_t va, void *ud) {
    if (qemu_plugin_mem_is_store(info)) {
        if (va >= marker && va < marker + 8 * MAX_SPANS) {
            span_t *sp = &spans[(va - marker) / 8];
            if ((va - marker) % 8 == 0) {
                sp->o_insns = insns;
                sp->o_base = base;
                sp->o_stall = stall;
                sp->o_fstall = fstall;
                sp->open = sp->used = true;
            } else if (sp->open) {
                sp->n++;
                sp->insns += insns - sp->o_insns;
                sp->base += base - sp->o_base;
                sp->stall += stall - sp->o_stall;
                sp->fstall += fstall - sp->o_fstall;
                sp->open = false;
            }
        }
        return;
    }
    if (va >= flo && va < fhi && !lru_access(&dc, va >> 4)) {
        stall += ws;
        if (cur && prof_span >= 0 && spans[prof_span].open) {
            cur->prof_cycles += ws;
            cur->prof_stall += ws;
        }
    }
}

static void on_tb(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        insn_info *ii = lookup(qemu_plugin_insn_vaddr(insn));
        if (!ii) continue;
        ii->size = qemu_plugin_insn_size(insn);
        char *d = qemu_plugin_insn_disas(insn);
        classify(d ? d : "", ii);
        free(d);
        qemu_plugin_register_vcpu_insn_exec_cb(insn, on_exec, QEMU_PLUGIN_CB_NO_REGS, ii);
        qemu_plugin_register_vcpu_mem_cb(insn, on_mem, QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_MEM_RW, NULL);
    }
}

static void on_exit_cb(qemu_plugin_id_t id, void *p) {
    char b[256];
    for (int i = 0; i < MAX_SPANS; i++) {
        span_t *s = &spans[i];
        if (!s->used) continue;
        snprintf(b, sizeof b,
                 "m4cycles: span %d n %llu insns %llu base_cycles %llu flash_stall %llu fetch_stall %llu "
                 "est_cycles %llu\n",
                 i, (unsigned long long)s->n, (unsigned long long)s->insns, (unsigned long long)s->base,
                 (unsigned long long)s->stall, (unsigned long long)s->fstall,
                 (unsigned long long)(s->base + s->stall));
        qemu_plugin_outs(b);
    }
    snprintf(b, sizeof b, "m4cycles: total insns %llu base_cycles %llu flash_stall %llu fetch_stall %llu\n",
             (unsigned long long)insns, (unsigned long long)base, (unsigned long long)stall,
             (unsigned long long)fstall);
    qemu_plugin_outs(b);
    if (prof_file) {
        FILE *f = fopen(prof_file, "w");
        if (!f) return;
        for (uint32_t k = 0; k < TABLE; k++) {
            insn_info *ii = table[k];
            if (ii && ii->prof_insns)
                fprintf(f, "0x%llx %llu %llu %llu\n", (unsigned long long)ii->pc,
                        (unsigned long long)ii->prof_insns, (unsigned long long)ii->prof_cycles,
                        (unsigned long long)ii->prof_stall);
        }
        fclose(f);
    }
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc,
                                           char **argv) {
    int dl = 8, il = 64;
    for (int i = 0; i < argc; i++) {
        if (!strncmp(argv[i], "addr=", 5)) marker = strtoull(argv[i] + 5, NULL, 0);
        else if (!strncmp(argv[i], "flo=", 4)) flo = strtoull(argv[i] + 4, NULL, 0);
        else if (!strncmp(argv[i], "fhi=", 4)) fhi = strtoull(argv[i] + 4, NULL, 0);
        else if (!strncmp(argv[i], "ws=", 3)) ws = strtoull(argv[i] + 3, NULL, 0);
        else if (!strncmp(argv[i], "refill=", 7)) refill = strtoull(argv[i] + 7, NULL, 0);
        else if (!strncmp(argv[i], "dlines=", 7)) dl = atoi(argv[i] + 7);
        else if (!strncmp(argv[i], "ilines=", 7)) il = atoi(argv[i] + 7);
        else if (!strncmp(argv[i], "fetchbw=", 8)) fetchbw = strtoull(argv[i] + 8, NULL, 0);
        else if (!strncmp(argv[i], "prof=", 5)) prof_file = strdup(argv[i] + 5);
        else if (!strncmp(argv[i], "profspan=", 9)) prof_span = atoi(argv[i] + 9);
        else {
            fprintf(stderr, "m4cycles: unknown argument '%s'\n", argv[i]);
            return -1;
        }
    }
    if (prof_span >= MAX_SPANS) prof_span = -1;
    if (dl < 1 || dl > MAXL || il < 1 || il > MAXL) {
        fprintf(stderr, "m4cycles: dlines and ilines must be 1..%d\n", MAXL);
        return -1;
    }
    dc.n = dl;
    ic.n = il;
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb);
    qemu_plugin_register_atexit_cb(id, on_exit_cb, NULL);
    return 0;
}
