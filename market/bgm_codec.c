#include "bgm_codec.h"

#include <math.h>
#include <string.h>

_Static_assert(BGA_MARKET_CANDIDATES == BGM_MSG_CANDIDATES, "candidate arrays differ");
_Static_assert(BGM_ROLE_CANDIDATES == BGM_MSG_CANDIDATES, "candidate arrays differ");
_Static_assert(BGA_MARKET_FIRST == BGM_RM_FIRST && BGA_MARKET_LAST == BGM_RM_LAST,
               "market type ranges differ");

/* Wire type = BGM_WIRE_BASE + the world's message number (1..25). */
#define BGM_WIRE_BASE 0x1000

int bgm_codec_type_known(uint16_t type)
{
    return type >= BGM_RM_FIRST && type <= BGM_RM_LAST;
}

const char *bgm_codec_type_name(uint16_t type)
{
    return bgm_codec_type_known(type) ? bga_type_name(type) : "unknown";
}

bg_status bgm_codec_encode_msg(const bgm_msg_t *m, uint64_t job, uint64_t seq, bga_frames_t *out,
                               bg_error_t *err)
{
    const uint16_t type = (uint16_t)(BGM_WIRE_BASE + m->type);
    if (m->type == 0 || !bgm_codec_type_known(type))
        return bg_error_set(err, BG_ERR_INVALID, "market message type %u is not a market type",
                            (unsigned)m->type);
    bga_msg_t w;
    bga_msg_init(&w, type, job, seq);
    w.header.sender = m->from;
    w.header.receiver = m->to;
    w.field[BGA_MK_GOOD].i = m->good;
    w.field[BGA_MK_HOPS].i = m->hops;
    w.field[BGA_MK_NCAND].i = m->ncand;
    w.field[BGA_MK_REQ].i = m->req;
    w.field[BGA_MK_ATTEMPT].i = m->attempt;
    w.field[BGA_MK_ORIGIN].i = m->origin;
    w.field[BGA_MK_PRICE].f = m->price;
    w.field[BGA_MK_A].f = m->a;
    w.field[BGA_MK_B].f = m->b;
    w.field[BGA_MK_C].f = m->c;
    int32_t cand[BGM_MSG_CANDIDATES];
    for (int i = 0; i < BGM_MSG_CANDIDATES; i++)
        cand[i] = m->cand[i] > (uint32_t)BGA_MARKET_MAX_AGENT ? -1 : (int32_t)m->cand[i];
    w.array[BGA_MK_CAND] = (bga_array_t){cand, BGM_MSG_CANDIDATES};
    w.array[BGA_MK_CAND_PRICE] = (bga_array_t){m->cand_price, BGM_MSG_CANDIDATES};
    w.array[BGA_MK_CAND_SPEED] = (bga_array_t){m->cand_speed, BGM_MSG_CANDIDATES};
    return bga_wire_encode(&w, out, err);
}

bga_wire_code bgm_codec_decode_msg(const bga_frame_t *frames, int nframes, bgm_msg_t *m,
                                   bga_wire_error_t *werr)
{
    bga_msg_t w;
    bga_limits_t lim = bga_wire_default_limits();
    memset(m, 0, sizeof *m);
    bga_wire_code c = bga_wire_decode(frames, nframes, &lim, &w, werr);
    if (c != BGA_WIRE_OK)
        return c;
    if (!bgm_codec_type_known(w.header.type))
        return bga_wire_fail(werr, BGA_WIRE_UNEXPECTED, 0, "type",
                             "type 0x%04x is not a market message", (unsigned)w.header.type);
    m->type = (uint16_t)(w.header.type - BGM_WIRE_BASE);
    m->from = (uint32_t)w.header.sender;
    m->to = (uint32_t)w.header.receiver;
    m->good = (int16_t)w.field[BGA_MK_GOOD].i;
    m->hops = (uint16_t)w.field[BGA_MK_HOPS].i;
    m->ncand = (uint16_t)w.field[BGA_MK_NCAND].i;
    m->req = (uint32_t)w.field[BGA_MK_REQ].i;
    m->attempt = (uint32_t)w.field[BGA_MK_ATTEMPT].i;
    m->origin = (uint32_t)w.field[BGA_MK_ORIGIN].i;
    m->price = w.field[BGA_MK_PRICE].f;
    m->a = w.field[BGA_MK_A].f;
    m->b = w.field[BGA_MK_B].f;
    m->c = w.field[BGA_MK_C].f;
    for (int i = 0; i < BGM_MSG_CANDIDATES; i++) {
        m->cand[i] = (uint32_t)bga_msg_i32(&w, BGA_MK_CAND, (size_t)i);
        m->cand_price[i] = bga_msg_f64(&w, BGA_MK_CAND_PRICE, (size_t)i);
        m->cand_speed[i] = bga_msg_f64(&w, BGA_MK_CAND_SPEED, (size_t)i);
    }
    return BGA_WIRE_OK;
}

/* ------------------------------------------------- typed <-> generic */

/* A bid's or query's sellers to leave out travel as its candidates. */
static bg_status exclusions_to_generic(int n, const uint32_t *ids, bgm_msg_t *o, bg_error_t *err)
{
    if (n < 0 || n > BGM_ROLE_CANDIDATES)
        return bg_error_set(err, BG_ERR_INVALID, "exclusions: %d outside [0, %d]", n,
                            BGM_ROLE_CANDIDATES);
    o->ncand = (uint16_t)n;
    memcpy(o->cand, ids, (size_t)n * sizeof *ids);
    return BG_OK;
}

bg_status bgm_codec_to_generic(const bgm_role_msg_t *in, bgm_msg_t *o, bg_error_t *err)
{
    memset(o, 0, sizeof *o);
    if (!bgm_codec_type_known(in->type))
        return bg_error_set(err, BG_ERR_INVALID, "role message type 0x%04x is not a market type",
                            (unsigned)in->type);
    o->type = (uint16_t)(in->type - BGM_WIRE_BASE);
    o->from = in->from;
    o->to = in->to;
    o->req = in->req;
    o->attempt = in->attempt;
    const bgm_role_payload_t *u = &in->u;
    bg_status st = BG_OK;
    switch (in->type) {
    case BGM_RM_BID:
        o->good = (int16_t)u->bid.good; o->price = u->bid.price_per_unit;
        o->a = u->bid.work; o->b = u->bid.deadline; o->cand_price[0] = u->bid.deadline;
        o->origin = u->bid.group;
        st = exclusions_to_generic(u->bid.nexclude, u->bid.exclude, o, err);
        break;
    case BGM_RM_ASK:
        o->good = (int16_t)u->ask.good; o->price = u->ask.reservation_per_unit;
        o->a = u->ask.slots;
        break;
    case BGM_RM_MATCH:
        o->good = (int16_t)u->match.good; o->price = u->match.price_per_unit;
        o->a = u->match.work; o->b = u->match.seller_limit; o->c = u->match.deadline;
        o->origin = u->match.buyer;
        break;
    case BGM_RM_RBID:
        o->a = u->rbid.cores; o->b = u->rbid.memory; o->c = u->rbid.flops;
        o->price = u->rbid.limit_total; o->cand_price[0] = u->rbid.deadline;
        break;
    case BGM_RM_RASK:
        o->a = u->rask.cores; o->b = u->rask.memory; o->c = u->rask.speed;
        o->price = u->rask.cost_rate_per_core; o->cand_price[0] = u->rask.memory_cost_rate;
        break;
    case BGM_RM_RFREE:
        o->a = u->rfree.cores; o->b = u->rfree.memory;
        break;
    case BGM_RM_RAWARD:
        o->origin = u->raward.buyer; o->price = u->raward.rate;
        o->a = u->raward.cores; o->b = u->raward.memory; o->c = u->raward.flops;
        o->cand_price[0] = u->raward.seller_limit; o->cand_price[1] = u->raward.budget;
        break;
    case BGM_RM_RCONFIRM:
        o->good = (int16_t)u->rconfirm.good; o->hops = (uint16_t)u->rconfirm.parts;
        o->price = u->rconfirm.rate; o->a = u->rconfirm.start; o->b = u->rconfirm.end;
        o->c = u->rconfirm.seller_limit_rate;
        o->cand_price[0] = u->rconfirm.part_quantity;
        o->cand_price[1] = u->rconfirm.part_buyer_limit;
        o->cand_price[2] = u->rconfirm.part_seller_cost;
        break;
    case BGM_RM_CONFIRM:
        o->origin = u->confirm.bundle;
        o->price = u->confirm.price_per_unit; o->a = u->confirm.start; o->b = u->confirm.end;
        break;
    case BGM_RM_TAKE:
    case BGM_RM_REFUSE:
        o->origin = u->take.bundle;
        break;
    case BGM_RM_CFP:
        o->good = (int16_t)u->cfp.good; o->hops = (uint16_t)u->cfp.hops;
        o->origin = u->cfp.origin; o->a = u->cfp.work_or_cores; o->b = u->cfp.memory;
        o->c = u->cfp.flops;
        break;
    case BGM_RM_PROPOSE:
        o->price = u->propose.price; o->a = u->propose.speed;
        break;
    case BGM_RM_OFFER:
    case BGM_RM_ACCEPT:
        o->price = u->price.price;
        o->good = (int16_t)u->price.good; o->hops = (uint16_t)(u->price.opening != 0);
        o->a = u->price.work_or_cores; o->b = u->price.memory; o->c = u->price.flops;
        o->cand_price[1] = u->price.budget; o->cand_price[2] = u->price.valid_until;
        break;
    case BGM_RM_GENES:
        for (int i = 0; i < BGM_ROLE_GENES; i++)
            o->cand_price[i] = u->genes.genes[i];
        o->price = u->genes.fitness; o->a = u->genes.request ? 1.0 : 0.0;
        break;
    case BGM_RM_QUERY:
        o->good = (int16_t)u->query.good; o->price = u->query.limit;
        o->a = u->query.cores; o->b = u->query.memory;
        st = exclusions_to_generic(u->query.nexclude, u->query.exclude, o, err);
        break;
    case BGM_RM_LIST:
        if (u->list.ncand < 0 || u->list.ncand > BGM_ROLE_CANDIDATES)
            return bg_error_set(err, BG_ERR_INVALID, "list: ncand %d outside [0, %d]",
                                u->list.ncand, BGM_ROLE_CANDIDATES);
        o->ncand = (uint16_t)u->list.ncand;
        for (int i = 0; i < u->list.ncand; i++) {
            o->cand[i] = u->list.cand[i];
            o->cand_price[i] = u->list.cand_price[i];
            o->cand_speed[i] = u->list.cand_speed[i];
        }
        break;
    case BGM_RM_ORDER:
        o->good = (int16_t)u->order.good; o->price = u->order.price;
        o->a = u->order.work_or_cores; o->b = u->order.memory; o->c = u->order.flops;
        o->cand_price[1] = u->order.budget; o->cand_price[2] = u->order.valid_until;
        break;
    case BGM_RM_AVAIL:
        o->a = u->avail.free_a; o->b = u->avail.free_b;
        break;
    case BGM_RM_RPART:
        o->good = (int16_t)u->rpart.good; o->hops = (uint16_t)u->rpart.parts;
        o->origin = u->rpart.buyer; o->a = u->rpart.quantity; o->b = u->rpart.duration;
        o->price = u->rpart.rate; o->c = u->rpart.buyer_limit;
        o->cand_price[0] = u->rpart.start;
        break;
    default: /* FREE, RFAIL, CANCEL, REJECT: header only */
        break;
    }
    return st;
}

bg_status bgm_codec_from_generic(const bgm_msg_t *g, bgm_role_msg_t *o, bg_error_t *err)
{
    memset(o, 0, sizeof *o);
    const uint16_t type = (uint16_t)(BGM_WIRE_BASE + g->type);
    if (g->type == 0 || !bgm_codec_type_known(type))
        return bg_error_set(err, BG_ERR_INVALID, "market message type %u is not a market type",
                            (unsigned)g->type);
    o->type = type;
    o->from = g->from;
    o->to = g->to;
    o->req = g->req;
    o->attempt = g->attempt;
    bgm_role_payload_t *u = &o->u;
    switch (type) {
    case BGM_RM_BID:
        if (g->ncand > BGM_ROLE_CANDIDATES)
            return bg_error_set(err, BG_ERR_INVALID, "bid: %u exclusions over %d",
                                (unsigned)g->ncand, BGM_ROLE_CANDIDATES);
        u->bid = (bgm_rm_bid_t){g->good, g->price, g->a, g->b, g->origin, g->ncand, {0}};
        memcpy(u->bid.exclude, g->cand, g->ncand * sizeof *g->cand);
        break;
    case BGM_RM_ASK:
        u->ask = (bgm_rm_ask_t){g->good, g->price, g->a};
        break;
    case BGM_RM_MATCH:
        u->match = (bgm_rm_match_t){g->good, g->origin, g->price, g->a, g->b, g->c};
        break;
    case BGM_RM_RBID:
        u->rbid = (bgm_rm_rbid_t){g->a, g->b, g->c, g->price, g->cand_price[0]};
        break;
    case BGM_RM_RASK:
        u->rask = (bgm_rm_rask_t){g->a, g->b, g->c, g->price, g->cand_price[0]};
        break;
    case BGM_RM_RFREE:
        u->rfree = (bgm_rm_rfree_t){g->a, g->b};
        break;
    case BGM_RM_RAWARD:
        u->raward = (bgm_rm_raward_t){g->origin, g->price, g->a,           g->b,
                                      g->c,      g->cand_price[0], g->cand_price[1]};
        break;
    case BGM_RM_RCONFIRM:
        u->rconfirm = (bgm_rm_rconfirm_t){g->good,          g->hops,          g->price,
                                          g->a,             g->b,             g->c,
                                          g->cand_price[0], g->cand_price[1], g->cand_price[2]};
        break;
    case BGM_RM_CONFIRM:
        u->confirm = (bgm_rm_confirm_t){g->origin, g->price, g->a, g->b};
        break;
    case BGM_RM_TAKE:
    case BGM_RM_REFUSE:
        u->take = (bgm_rm_take_t){g->origin};
        break;
    case BGM_RM_CFP:
        u->cfp = (bgm_rm_cfp_t){g->good, g->hops, g->origin, g->a, g->b, g->c};
        break;
    case BGM_RM_PROPOSE:
        u->propose = (bgm_rm_propose_t){g->price, g->a};
        break;
    case BGM_RM_OFFER:
    case BGM_RM_ACCEPT:
        u->price = (bgm_rm_price_t){g->price, g->good, g->hops != 0,      g->a,
                                    g->b,     g->c,    g->cand_price[1], g->cand_price[2]};
        break;
    case BGM_RM_GENES:
        for (int i = 0; i < BGM_ROLE_GENES; i++)
            u->genes.genes[i] = g->cand_price[i];
        u->genes.fitness = g->price;
        u->genes.request = g->a != 0.0;
        break;
    case BGM_RM_QUERY:
        if (g->ncand > BGM_ROLE_CANDIDATES)
            return bg_error_set(err, BG_ERR_INVALID, "query: %u exclusions over %d",
                                (unsigned)g->ncand, BGM_ROLE_CANDIDATES);
        u->query = (bgm_rm_query_t){g->good, g->price, g->a, g->b, g->ncand, {0}};
        memcpy(u->query.exclude, g->cand, g->ncand * sizeof *g->cand);
        break;
    case BGM_RM_LIST:
        if (g->ncand > BGM_ROLE_CANDIDATES)
            return bg_error_set(err, BG_ERR_INVALID, "list: ncand %u over %d", (unsigned)g->ncand,
                                BGM_ROLE_CANDIDATES);
        u->list.ncand = g->ncand;
        for (int i = 0; i < g->ncand; i++) {
            u->list.cand[i] = g->cand[i];
            u->list.cand_price[i] = g->cand_price[i];
            u->list.cand_speed[i] = g->cand_speed[i];
        }
        break;
    case BGM_RM_ORDER:
        u->order = (bgm_rm_order_t){g->good, g->price,         g->a,
                                    g->b,    g->c,     g->cand_price[1], g->cand_price[2]};
        break;
    case BGM_RM_AVAIL:
        u->avail = (bgm_rm_avail_t){g->a, g->b};
        break;
    case BGM_RM_RPART:
        u->rpart = (bgm_rm_rpart_t){g->good,  g->hops,  g->origin, g->a,
                                    g->b,     g->price, g->c,      g->cand_price[0]};
        break;
    default:
        break;
    }
    return BG_OK;
}

bg_status bgm_codec_encode(const bgm_role_msg_t *m, uint64_t seq, bga_frames_t *out,
                           bg_error_t *err)
{
    bgm_msg_t g;
    bg_status st = bgm_codec_to_generic(m, &g, err);
    return st ? st : bgm_codec_encode_msg(&g, m->job, seq, out, err);
}

bga_wire_code bgm_codec_decode(const bga_frame_t *frames, int nframes, bgm_role_msg_t *m,
                               bga_wire_error_t *werr)
{
    bgm_msg_t g;
    bga_wire_code c = bgm_codec_decode_msg(frames, nframes, &g, werr);
    if (c != BGA_WIRE_OK) {
        memset(m, 0, sizeof *m);
        return c;
    }
    bg_error_t e;
    memset(&e, 0, sizeof e);
    if (bgm_codec_from_generic(&g, m, &e) != BG_OK)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "ncand", "%s", e.message);
    /* The job id rides in the header. */
    bga_msg_t h;
    bga_limits_t lim = bga_wire_default_limits();
    if (bga_wire_decode(frames, nframes, &lim, &h, werr) == BGA_WIRE_OK)
        m->job = h.header.job;
    return BGA_WIRE_OK;
}
