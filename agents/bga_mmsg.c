#include "bga_mmsg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const char *const type_names[] = {
    "?",       "register", "registered", "heartbeat", "order",  "confirm", "refuse", "release",
    "cfp",     "propose",  "offer",      "accept",    "reject", "relay",   "error",
    "rbuy",    "rbought",  "rfail",
};

_Static_assert(BGA_MMSG_GOODS == BGA_LIVE_GOODS, "the live schema's price arrays hold every good");
_Static_assert(BGA_LIVE_LAST - BGA_LIVE_FIRST + 1 == BGA_MM_LAST,
               "one wire type per market message type");

void bga_mmsg_init(bga_mmsg_t *m, int type)
{
    memset(m, 0, sizeof *m);
    m->type = type;
    m->good = -1;
    m->serves = -1;
}

const char *bga_mmsg_type_name(int type)
{
    return type >= BGA_MM_FIRST && type <= BGA_MM_LAST ? type_names[type] : "unknown";
}

int bga_mmsg_is_market(const bga_frame_t *frames, int nframes)
{
    if (nframes < 1 || frames[0].size != BGA_WIRE_HEADER_BYTES || memcmp(frames[0].data, "bgwp", 4))
        return 0;
    const unsigned type = frames[0].data[6] | (unsigned)frames[0].data[7] << 8;
    return type >= BGA_LIVE_FIRST && type <= BGA_LIVE_LAST;
}

/* Range checks shared by encode and decode, so nothing is sent that a
 * peer would refuse. */
static bg_status check(const bga_mmsg_t *m, bg_error_t *err)
{
    if (m->type < BGA_MM_FIRST || m->type > BGA_MM_LAST)
        return bg_error_set(err, BG_ERR_INVALID, "market message: type %d is unknown", m->type);
    if (m->good < -1 || m->good >= BGA_MMSG_GOODS)
        return bg_error_set(err, BG_ERR_INVALID, "market message: good %d is out of range", m->good);
    if (m->slots < 0 || m->slots > 4096 || m->free_slots < 0 || m->free_slots > m->slots)
        return bg_error_set(err, BG_ERR_INVALID, "market message: slots/free_slots out of range");
    if (m->attempt < 0 || m->attempt > 1000)
        return bg_error_set(err, BG_ERR_INVALID, "market message: attempt %d out of [0, 1000]",
                            m->attempt);
    if (m->serves < -1 || m->serves > 2)
        return bg_error_set(err, BG_ERR_INVALID, "market message: serves %d is not a service",
                            m->serves);
    if (m->parent > ((uint64_t)1 << 53))
        return bg_error_set(err, BG_ERR_INVALID, "market message: parent %llu is over 2^53",
                            (unsigned long long)m->parent);
    if (m->epoch > ((uint64_t)1 << 53) || (m->epoch != 0 && m->type != BGA_MM_REGISTERED) ||
        (m->type == BGA_MM_REGISTERED && m->job != 0))
        return bg_error_set(err, BG_ERR_INVALID,
                            "market message: epoch %llu (only in registered, at most 2^53, "
                            "with no job)",
                            (unsigned long long)m->epoch);
    if (m->hops < 0 || m->hops > 16)
        return bg_error_set(err, BG_ERR_INVALID, "market message: hops %d out of [0, 16]", m->hops);
    if (m->nneighbours < 0 || m->nneighbours > BGA_MMSG_MAX_NEIGHBOURS)
        return bg_error_set(err, BG_ERR_INVALID, "market message: too many neighbours");
    const double v[] = {m->margin,     m->load_slope,  m->cores,    m->memory, m->quantity,
                        m->price,      m->free_cores,  m->free_memory, m->term};
    const char *n[] = {"margin", "load_slope", "cores",       "memory", "quantity",
                       "price",  "free_cores", "free_memory", "term"};
    for (int i = 0; i < 9; i++)
        if (!isfinite(v[i]) || v[i] < 0 || v[i] > 1e15)
            return bg_error_set(err, BG_ERR_INVALID, "market message: %s is not a finite value >= 0",
                                n[i]);
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        if (!isfinite(m->floor[g]) || m->floor[g] < 0 || !isfinite(m->prices[g]) ||
            m->prices[g] < 0)
            return bg_error_set(err, BG_ERR_INVALID,
                                "market message: floor[%d]/prices[%d] not a finite value >= 0", g, g);
    return BG_OK;
}

/* Frame sizes a market message may have: its texts are capped by the
 * struct and the rest is a few hundred bytes. */
static const bga_limits_t LIMITS = {BGA_MMSG_MAX_BYTES, BGA_MMSG_MAX_BYTES};

bg_status bga_mmsg_encode(const bga_mmsg_t *m, bga_frames_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    bg_status st = check(m, err);
    if (st != BG_OK)
        return st;
    const char *texts[] = {m->name, m->endpoint, m->reason};
    const size_t caps[] = {sizeof m->name, sizeof m->endpoint, sizeof m->reason};
    for (int t = 0; t < 3; t++)
        if (!memchr(texts[t], 0, caps[t]))
            return bg_error_set(err, BG_ERR_INVALID, "market message: %s is not terminated",
                                t == 0 ? "name" : t == 1 ? "endpoint" : "reason");
    int32_t nb[BGA_MMSG_MAX_NEIGHBOURS];
    for (int i = 0; i < m->nneighbours; i++) {
        if (m->neighbours[i] > INT32_MAX)
            return bg_error_set(err, BG_ERR_INVALID, "market message: neighbour id %u is over %d",
                                (unsigned)m->neighbours[i], INT32_MAX);
        nb[i] = (int32_t)m->neighbours[i];
    }
    const double capacity[4] = {m->cores, m->memory, m->free_cores, m->free_memory};
    bga_msg_t w;
    bga_msg_init(&w, (uint16_t)(BGA_LIVE_FIRST - 1 + m->type),
                 m->type == BGA_MM_REGISTERED ? m->epoch : m->job, 0);
    const int64_t ints[] = {m->agent, m->target,     m->origin, m->services, m->resource,
                            m->slots, m->free_slots, m->good,   m->hops,     m->attempt};
    for (int f = BGA_LM_AGENT; f <= BGA_LM_ATTEMPT; f++)
        w.field[f].i = ints[f - BGA_LM_AGENT];
    w.field[BGA_LM_MARGIN].f = m->margin;
    w.field[BGA_LM_LOAD_SLOPE].f = m->load_slope;
    w.field[BGA_LM_TERM].f = m->term;
    w.field[BGA_LM_QUANTITY].f = m->quantity;
    w.field[BGA_LM_PRICE].f = m->price;
    w.field[BGA_LM_PARENT].i = (int64_t)m->parent;
    w.field[BGA_LM_SERVES].i = m->serves;
    w.array[BGA_LM_FLOOR] = (bga_array_t){m->floor, BGA_MMSG_GOODS};
    w.array[BGA_LM_PRICES] = (bga_array_t){m->prices, BGA_MMSG_GOODS};
    w.array[BGA_LM_CAPACITY] = (bga_array_t){capacity, 4};
    w.array[BGA_LM_NEIGHBOURS] = (bga_array_t){nb, (size_t)m->nneighbours};
    for (int t = 0; t < 3; t++)
        w.array[BGA_LM_NAME + t] = (bga_array_t){texts[t], strlen(texts[t])};
    st = bga_wire_encode(&w, out, err);
    if (st != BG_OK)
        return st;
    size_t total = 0;
    for (int i = 0; i < out->count; i++)
        total += out->size[i];
    if (total > BGA_MMSG_MAX_BYTES) {
        bga_frames_free(out);
        return bg_error_set(err, BG_ERR_LIMIT, "market message %s: %zu bytes over the cap %d",
                            bga_mmsg_type_name(m->type), total, BGA_MMSG_MAX_BYTES);
    }
    return BG_OK;
}

/* A decoded text array into a NUL-terminated buffer of `cap` bytes. */
static bg_status get_text(const bga_msg_t *w, int array, const char *name, char *dst, size_t cap,
                          bg_error_t *err)
{
    const size_t n = w->array[array].count;
    if (n >= cap)
        return bg_error_set(err, BG_ERR_LIMIT, "market message: %s has %zu bytes (at most %zu)",
                            name, n, cap - 1);
    if (n > 0)
        memcpy(dst, w->array[array].data, n);
    dst[n] = '\0';
    return BG_OK;
}

bg_status bga_mmsg_decode(const bga_frame_t *frames, int nframes, bga_mmsg_t *m, bg_error_t *err)
{
    bga_mmsg_init(m, 0);
    bga_msg_t w;
    bga_wire_error_t werr;
    const bga_wire_code wc = bga_wire_decode(frames, nframes, &LIMITS, &w, &werr);
    if (wc != BGA_WIRE_OK)
        return bg_error_set(err,
                            wc == BGA_WIRE_OVERSIZE ? BG_ERR_LIMIT
                            : wc == BGA_WIRE_TRUNCATED || wc == BGA_WIRE_BAD_MAGIC ||
                                    wc == BGA_WIRE_FRAME_COUNT
                                ? BG_ERR_PARSE
                                : BG_ERR_INVALID,
                            "market message: %s", werr.message);
    if (w.header.type < BGA_LIVE_FIRST || w.header.type > BGA_LIVE_LAST)
        return bg_error_set(err, BG_ERR_INVALID,
                            "market message: frame 0: type 0x%04x (%s) is not a live market "
                            "message (0x%04x..0x%04x)",
                            (unsigned)w.header.type, bga_type_name(w.header.type),
                            BGA_LIVE_FIRST, BGA_LIVE_LAST);
    if (w.array[BGA_LM_NEIGHBOURS].count > BGA_MMSG_MAX_NEIGHBOURS)
        return bg_error_set(err, BG_ERR_LIMIT, "market message: %zu neighbours (at most %d)",
                            w.array[BGA_LM_NEIGHBOURS].count, BGA_MMSG_MAX_NEIGHBOURS);
    m->type = w.header.type - BGA_LIVE_FIRST + 1;
    m->job = w.header.job;
    if (m->type == BGA_MM_REGISTERED) {
        m->epoch = m->job;
        m->job = 0;
    }
    m->agent = (uint32_t)w.field[BGA_LM_AGENT].i;
    m->target = (uint32_t)w.field[BGA_LM_TARGET].i;
    m->origin = (uint32_t)w.field[BGA_LM_ORIGIN].i;
    m->services = (unsigned)w.field[BGA_LM_SERVICES].i;
    m->resource = (int)w.field[BGA_LM_RESOURCE].i;
    m->slots = (int)w.field[BGA_LM_SLOTS].i;
    m->free_slots = (int)w.field[BGA_LM_FREE_SLOTS].i;
    m->good = (int)w.field[BGA_LM_GOOD].i;
    m->hops = (int)w.field[BGA_LM_HOPS].i;
    m->attempt = (int)w.field[BGA_LM_ATTEMPT].i;
    m->margin = w.field[BGA_LM_MARGIN].f;
    m->load_slope = w.field[BGA_LM_LOAD_SLOPE].f;
    m->term = w.field[BGA_LM_TERM].f;
    m->quantity = w.field[BGA_LM_QUANTITY].f;
    m->price = w.field[BGA_LM_PRICE].f;
    m->parent = (uint64_t)w.field[BGA_LM_PARENT].i;
    m->serves = (int)w.field[BGA_LM_SERVES].i;
    bga_msg_copy_f64(&w, BGA_LM_FLOOR, m->floor);
    bga_msg_copy_f64(&w, BGA_LM_PRICES, m->prices);
    double capacity[4];
    bga_msg_copy_f64(&w, BGA_LM_CAPACITY, capacity);
    m->cores = capacity[0];
    m->memory = capacity[1];
    m->free_cores = capacity[2];
    m->free_memory = capacity[3];
    m->nneighbours = (int)w.array[BGA_LM_NEIGHBOURS].count;
    for (int i = 0; i < m->nneighbours; i++)
        m->neighbours[i] = (uint32_t)bga_msg_i32(&w, BGA_LM_NEIGHBOURS, (size_t)i);
    bg_status st;
    if ((st = get_text(&w, BGA_LM_NAME, "name", m->name, sizeof m->name, err)) ||
        (st = get_text(&w, BGA_LM_ENDPOINT, "endpoint", m->endpoint, sizeof m->endpoint, err)) ||
        (st = get_text(&w, BGA_LM_REASON, "reason", m->reason, sizeof m->reason, err)))
        return st;
    return check(m, err);
}
