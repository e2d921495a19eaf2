#include "bgm_budget.h"

#include <math.h>

#include "bgm_purchase.h"
#include "bgm_role.h"

double bgm_budget_attempts(double deadline, double backoff)
{
    if (!(backoff > 0.0))
        return INFINITY;
    /* Round k + 1 starts only if the backoffs before it, b (2^k - 1) while
     * they double, then 32 b more each, sum to less than the deadline. */
    double rounds = 1.0;
    for (int k = 1; k <= BGM_PU_RETRY_MAX_DOUBLINGS + 1; k++) {
        if (backoff * (ldexp(1.0, k) - 1.0) >= deadline)
            return rounds;
        rounds += 1.0;
    }
    const double top = ldexp(1.0, BGM_PU_RETRY_MAX_DOUBLINGS);
    const double doubled = ldexp(1.0, BGM_PU_RETRY_MAX_DOUBLINGS + 1) - 1.0;
    /* Rounds after those: the positive integers j with b (doubled + top j) < T. */
    const double x = (deadline / backoff - doubled) / top;
    return rounds + (x > 0.0 ? ceil(x) - 1.0 : 0.0);
}

double bgm_budget_calls(int degree, int hops)
{
    double calls = 0.0, level = degree;
    for (int k = 1; k <= hops; k++) {
        calls += level;
        level *= degree - 1;
    }
    return calls;
}

/* One round of discovery and bargaining: the calls, a proposal per call
 * at most, and the bargains with the proposals a round keeps. */
static double catallactic_round(const bgm_config_t *c)
{
    const double calls = bgm_budget_calls(c->agents.overlay_degree, c->catallactic.hops);
    return 2.0 * calls + BGM_PU_MAX_PROPOSALS * (2.0 * c->catallactic.max_rounds + 2.0);
}

static double candidates(const bgm_config_t *c)
{
    return c->baseline.candidates < BGM_MSG_CANDIDATES ? c->baseline.candidates
                                                       : BGM_MSG_CANDIDATES;
}

/* The most parts a bundle splits into on the per-type call markets: a
 * core per part at most, and its memory over every resource seller (or
 * a MiB each, if fewer). */
static double call_parts(const bgm_config_t *c, double nresource)
{
    double cores = 0.0, mib = 0.0;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        cores = fmax(cores, c->services[t].cores);
        mib = fmax(mib, ceil(c->services[t].memory * 1024.0));
    }
    return cores + fmin(nresource, mib);
}

bgm_budget_t bgm_budget_of(const bgm_config_t *c, int mechanism, double horizon, double nresource)
{
    bgm_budget_t b = {0};
    const double delivery = 2.0; /* CONFIRM and TAKE or REFUSE; or CANCEL */
    const double types = c->agents.services_per_agent < BGM_SERVICE_TYPES
                             ? c->agents.services_per_agent
                             : BGM_SERVICE_TYPES;
    switch (mechanism) {
    case BGM_MECH_CENTRAL:
        b.attempts = bgm_budget_attempts(c->demand.deadline, c->catallactic.retry_backoff);
        b.per_round = 4.0; /* BID; ACCEPT and MATCH; the seller's CANCEL */
        /* FREE and a refreshed ASK; one RBID, no retry (an RFAIL ends the
         * bundle), answered by an award, the seller's answer and its RFREE
         * (on refusal or release) per part. */
        b.per_deal =
            delivery + 2.0 +
            (c->central.resource_market == BGM_RM_CALL ? 1.0 + 3.0 * call_parts(c, nresource)
                                                       : 4.0);
        b.per_agent = types; /* an ASK per type sold, or one RASK */
        break;
    case BGM_MECH_CATALLACTIC:
        b.attempts = bgm_budget_attempts(c->demand.deadline, c->catallactic.retry_backoff);
        b.per_round = catallactic_round(c);
        b.per_deal = delivery + b.attempts * catallactic_round(c);
        b.per_agent = 2.0 * (1.0 + 2.0 * horizon / c->catallactic.learning_period);
        break;
    default: {
        const double k = candidates(c);
        b.attempts = bgm_budget_attempts(c->demand.deadline, c->baseline.retry_backoff);
        b.per_round = 2.0 + 2.0 * k; /* QUERY, LIST, orders and answers */
        /* two AVAIL for the slot; the bundle's rounds, each with two
         * AVAIL per rental (every order may rent, a late one too) */
        b.per_deal = delivery + 2.0 + b.attempts * (2.0 + 4.0 * k);
        b.per_agent = types;
        break;
    }
    }
    b.per_request = b.attempts * b.per_round;
    return b;
}

double bgm_budget_messages(const bgm_budget_t *b, double requests, double deals, double agents)
{
    return requests * b->per_request + deals * b->per_deal + agents * b->per_agent;
}
