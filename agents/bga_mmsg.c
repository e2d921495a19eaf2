#include "bga_mmsg.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

static const char *const type_names[] = {
    "?",       "register", "registered", "heartbeat", "order",  "confirm", "refuse", "release",
    "cfp",     "propose",  "offer",      "accept",    "reject", "relay",   "error",
    "rbuy",    "rbought",  "rfail",
};

void bga_mmsg_init(bga_mmsg_t *m, int type)
{
    memset(m, 0, sizeof *m);
    m->type = type;
    m->good = -1;
}

const char *bga_mmsg_type_name(int type)
{
    return type >= BGA_MM_FIRST && type <= BGA_MM_LAST ? type_names[type] : "unknown";
}

int bga_mmsg_is_market(const bga_frame_t *frames, int nframes)
{
    return nframes >= 1 && frames[0].size == BGA_MMSG_HEADER_BYTES &&
           memcmp(frames[0].data, "bgmk", 4) == 0;
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

static int add_num(cJSON *o, const char *k, double v)
{
    return cJSON_AddNumberToObject(o, k, v) != NULL;
}

static int add_array(cJSON *o, const char *k, const double *v, int n)
{
    cJSON *a = cJSON_AddArrayToObject(o, k);
    if (!a)
        return 0;
    for (int i = 0; i < n; i++) {
        cJSON *x = cJSON_CreateNumber(v[i]);
        if (!x || !cJSON_AddItemToArray(a, x)) {
            cJSON_Delete(x);
            return 0;
        }
    }
    return 1;
}

bg_status bga_mmsg_encode(const bga_mmsg_t *m, bga_frames_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    bg_status st = check(m, err);
    if (st != BG_OK)
        return st;
    char *text = NULL;
    cJSON *o = cJSON_CreateObject();
    double nb[BGA_MMSG_MAX_NEIGHBOURS];
    for (int i = 0; i < m->nneighbours; i++)
        nb[i] = m->neighbours[i];
    int ok = o && add_num(o, "job", (double)m->job) && add_num(o, "agent", m->agent) &&
             add_num(o, "target", m->target) && add_num(o, "origin", m->origin) &&
             cJSON_AddStringToObject(o, "name", m->name) &&
             cJSON_AddStringToObject(o, "endpoint", m->endpoint) &&
             add_num(o, "services", m->services) && add_num(o, "resource", m->resource) &&
             add_num(o, "slots", m->slots) && add_num(o, "free_slots", m->free_slots) &&
             add_array(o, "floor", m->floor, BGA_MMSG_GOODS) && add_num(o, "margin", m->margin) &&
             add_num(o, "load_slope", m->load_slope) &&
             add_array(o, "prices", m->prices, BGA_MMSG_GOODS) && add_num(o, "cores", m->cores) &&
             add_num(o, "memory", m->memory) && add_num(o, "free_cores", m->free_cores) &&
             add_num(o, "free_memory", m->free_memory) && add_num(o, "term", m->term) &&
             add_num(o, "good", m->good) &&
             add_num(o, "hops", m->hops) && add_num(o, "attempt", m->attempt) && add_num(o, "quantity", m->quantity) &&
             add_num(o, "price", m->price) && add_array(o, "neighbours", nb, m->nneighbours) &&
             cJSON_AddStringToObject(o, "reason", m->reason);
    if (ok)
        text = cJSON_PrintUnformatted(o);
    if (!ok || !text) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory encoding a market message");
        goto out;
    }
    const size_t len = strlen(text);
    if (len > BGA_MMSG_MAX_BODY) {
        st = bg_error_set(err, BG_ERR_LIMIT, "market message %s: body %zu bytes over the cap %d",
                          bga_mmsg_type_name(m->type), len, BGA_MMSG_MAX_BODY);
        goto out;
    }
    out->data[0] = malloc(BGA_MMSG_HEADER_BYTES);
    out->data[1] = malloc(len ? len : 1);
    if (!out->data[0] || !out->data[1]) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory encoding a market message");
        goto out;
    }
    memcpy(out->data[0], "bgmk", 4);
    out->data[0][4] = (uint8_t)(m->type & 0xff);
    out->data[0][5] = (uint8_t)(m->type >> 8);
    out->size[0] = BGA_MMSG_HEADER_BYTES;
    memcpy(out->data[1], text, len);
    out->size[1] = len;
    out->count = 2;
out:
    if (st != BG_OK)
        bga_frames_free(out);
    free(text);
    cJSON_Delete(o);
    return st;
}

/* Reads a number field within [lo, hi], integral if asked. */
static bg_status get_num(const cJSON *o, const char *k, double lo, double hi, int integral,
                         double *v, bg_error_t *err)
{
    const cJSON *x = cJSON_GetObjectItemCaseSensitive(o, k);
    if (!x)
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' is missing", k);
    if (!cJSON_IsNumber(x) || !isfinite(x->valuedouble) || x->valuedouble < lo ||
        x->valuedouble > hi || (integral && x->valuedouble != floor(x->valuedouble)))
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' is not %s in [%g, %g]",
                            k, integral ? "an integer" : "a number", lo, hi);
    *v = x->valuedouble;
    return BG_OK;
}

static bg_status get_str(const cJSON *o, const char *k, char *dst, size_t cap, bg_error_t *err)
{
    const cJSON *x = cJSON_GetObjectItemCaseSensitive(o, k);
    if (!x || !cJSON_IsString(x))
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' is not a string", k);
    if (strlen(x->valuestring) >= cap)
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' is longer than %zu",
                            k, cap - 1);
    memcpy(dst, x->valuestring, strlen(x->valuestring) + 1);
    return BG_OK;
}

static bg_status get_array(const cJSON *o, const char *k, double *v, int max, int exact, int *n,
                           bg_error_t *err)
{
    const cJSON *a = cJSON_GetObjectItemCaseSensitive(o, k);
    if (!a || !cJSON_IsArray(a))
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' is not an array", k);
    const int count = cJSON_GetArraySize(a);
    if (count > max || (exact && count != max))
        return bg_error_set(err, BG_ERR_INVALID, "market message: field '%s' has %d entries (%s %d)",
                            k, count, exact ? "expected" : "at most", max);
    int i = 0;
    for (const cJSON *x = a->child; x; x = x->next, i++) {
        if (!cJSON_IsNumber(x) || !isfinite(x->valuedouble) || x->valuedouble < 0)
            return bg_error_set(err, BG_ERR_INVALID,
                                "market message: %s[%d] is not a finite number >= 0", k, i);
        v[i] = x->valuedouble;
    }
    *n = count;
    return BG_OK;
}

static const char *const known_keys[] = {
    "job",    "agent", "target", "origin", "name",   "endpoint",   "services", "resource",
    "slots",  "free_slots", "floor", "margin", "load_slope", "prices", "cores", "memory",
    "good",   "hops", "attempt",  "quantity", "price", "neighbours", "reason",
    "free_cores", "free_memory", "term"};

bg_status bga_mmsg_decode(const bga_frame_t *frames, int nframes, bga_mmsg_t *m, bg_error_t *err)
{
    bga_mmsg_init(m, 0);
    if (!bga_mmsg_is_market(frames, nframes))
        return bg_error_set(err, BG_ERR_PARSE, "market message: frame 0 is not a market header");
    if (nframes != 2)
        return bg_error_set(err, BG_ERR_PARSE, "market message: %d frames (expected 2)", nframes);
    if (frames[1].size > BGA_MMSG_MAX_BODY)
        return bg_error_set(err, BG_ERR_LIMIT, "market message: frame 1 is %zu bytes (cap %d)",
                            frames[1].size, BGA_MMSG_MAX_BODY);
    m->type = frames[0].data[4] | (frames[0].data[5] << 8);
    if (m->type < BGA_MM_FIRST || m->type > BGA_MM_LAST)
        return bg_error_set(err, BG_ERR_INVALID, "market message: frame 0: type %d is unknown",
                            m->type);
    cJSON *o = cJSON_ParseWithLength((const char *)frames[1].data, frames[1].size);
    bg_status st = BG_OK;
    if (!o || !cJSON_IsObject(o)) {
        st = bg_error_set(err, BG_ERR_PARSE, "market message: frame 1 is not a JSON object");
        goto out;
    }
    for (const cJSON *x = o->child; x; x = x->next) {
        size_t i = 0;
        while (i < sizeof known_keys / sizeof *known_keys && strcmp(known_keys[i], x->string))
            i++;
        if (i == sizeof known_keys / sizeof *known_keys) {
            st = bg_error_set(err, BG_ERR_INVALID, "market message: unknown field '%s'", x->string);
            goto out;
        }
    }
    double v[11], nb[BGA_MMSG_MAX_NEIGHBOURS];
    int n;
    const double id_max = 4294967295.0;
    if ((st = get_num(o, "job", 0, 9007199254740992.0, 1, &v[0], err)) ||
        (st = get_num(o, "agent", 0, id_max, 1, &v[1], err)) ||
        (st = get_num(o, "target", 0, id_max, 1, &v[2], err)) ||
        (st = get_num(o, "origin", 0, id_max, 1, &v[3], err)) ||
        (st = get_num(o, "services", 0, 7, 1, &v[4], err)) ||
        (st = get_num(o, "resource", 0, 1, 1, &v[5], err)) ||
        (st = get_num(o, "slots", 0, 4096, 1, &v[6], err)) ||
        (st = get_num(o, "free_slots", 0, 4096, 1, &v[7], err)) ||
        (st = get_num(o, "good", -1, BGA_MMSG_GOODS - 1, 1, &v[8], err)) ||
        (st = get_num(o, "hops", 0, 16, 1, &v[9], err)) ||
        (st = get_num(o, "attempt", 0, 1000, 1, &v[10], err)))
        goto out;
    m->attempt = (int)v[10];
    m->job = (uint64_t)v[0];
    m->agent = (uint32_t)v[1];
    m->target = (uint32_t)v[2];
    m->origin = (uint32_t)v[3];
    m->services = (unsigned)v[4];
    m->resource = (int)v[5];
    m->slots = (int)v[6];
    m->free_slots = (int)v[7];
    m->good = (int)v[8];
    m->hops = (int)v[9];
    if ((st = get_num(o, "margin", 0, 1e15, 0, &m->margin, err)) ||
        (st = get_num(o, "load_slope", 0, 1e15, 0, &m->load_slope, err)) ||
        (st = get_num(o, "cores", 0, 1e15, 0, &m->cores, err)) ||
        (st = get_num(o, "memory", 0, 1e15, 0, &m->memory, err)) ||
        (st = get_num(o, "free_cores", 0, 1e15, 0, &m->free_cores, err)) ||
        (st = get_num(o, "free_memory", 0, 1e15, 0, &m->free_memory, err)) ||
        (st = get_num(o, "term", 0, 1e15, 0, &m->term, err)) ||
        (st = get_num(o, "quantity", 0, 1e15, 0, &m->quantity, err)) ||
        (st = get_num(o, "price", 0, 1e15, 0, &m->price, err)) ||
        (st = get_str(o, "name", m->name, sizeof m->name, err)) ||
        (st = get_str(o, "endpoint", m->endpoint, sizeof m->endpoint, err)) ||
        (st = get_str(o, "reason", m->reason, sizeof m->reason, err)) ||
        (st = get_array(o, "floor", m->floor, BGA_MMSG_GOODS, 1, &n, err)) ||
        (st = get_array(o, "prices", m->prices, BGA_MMSG_GOODS, 1, &n, err)) ||
        (st = get_array(o, "neighbours", nb, BGA_MMSG_MAX_NEIGHBOURS, 0, &n, err)))
        goto out;
    m->nneighbours = n;
    for (int i = 0; i < n; i++)
        m->neighbours[i] = (uint32_t)nb[i];
    st = check(m, err);
out:
    cJSON_Delete(o);
    return st;
}
