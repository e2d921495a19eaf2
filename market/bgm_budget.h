/*
 * bgm_budget — the message budget of each mechanism: how many messages a
 * run can send at most, from the mechanism's parameters alone (rounds,
 * hops, overlay degree, candidates, deadline and retry backoff), so that
 * a run's messages per allocation can be checked against a stated bound
 * (market/README.md, "Message budget").
 *
 * Every message of a run is one of three kinds, and each kind is bounded:
 *   - a service request's rounds: at most A rounds (the retry backoff b
 *     doubles with each round, up to 2^5 b, and no round starts past the
 *     deadline T), each of at most `per_round` messages: central, BID,
 *     the auctioneer's ACCEPT and MATCH, the seller's CANCEL (4);
 *     catallactic, the calls of a capped flood (C = D + D(D-1) + ... over
 *     h hops, overlay degree D), a proposal per call at most, and P
 *     bargains of at most 2R + 2 offers and answers (R rounds, P = the
 *     proposals a round keeps); baseline, QUERY, LIST and c orders with
 *     their answers (2 + 2c);
 *   - a deal (a basic seller's agreement, which opens exactly one bundle
 *     request): its delivery (CONFIRM and TAKE or REFUSE, or CANCEL), the
 *     seller's slot announcements (central: FREE and a refreshed ASK;
 *     baseline: two AVAIL), and the bundle's rounds (central: one RBID,
 *     its award, the answer and the seller's RFREE on refusal and on
 *     release; per-type call markets: an RPART, answer and RFREE per
 *     part; catallactic: as a service round; baseline: as a service round
 *     plus two AVAIL per rental);
 *   - an agent's own traffic over the run: registration (ASK per type
 *     sold, RASK) or learning meetings (two GENES each, at most
 *     1 + 2 H / L of them over horizon H with period L).
 * A run sends at most
 *     requests x per_request + deals x per_deal + agents x per_agent
 * messages, where requests and deals are the run's service and bundle
 * requests. More than one deal per request arises only from answers that
 * come after their buyer stopped waiting (a reply timeout) or are lost;
 * the summary reports both counts.
 */
#ifndef BGM_BUDGET_H
#define BGM_BUDGET_H

#include "bgm_config.h"

typedef struct bgm_budget {
    double attempts;    /* A: rounds a request can start before its deadline */
    double per_round;   /* messages one round of a service request can cause */
    double per_request; /* attempts x per_round */
    double per_deal;    /* a deal's delivery and announcements, and its bundle's rounds */
    double per_agent;   /* an agent's registration or learning over the run */
} bgm_budget_t;

/* The budget of `mechanism` under cfg for a run of `horizon` seconds
 * with `nresource` resource sellers (the per-type call markets can split
 * a bundle's memory over every one of them). */
bgm_budget_t bgm_budget_of(const bgm_config_t *cfg, int mechanism, double horizon,
                           double nresource);

/* Rounds a request can start: the largest k with
 * b (1 + 2 + ... + 2^min(i, 5), i < k - 1) < deadline; INFINITY for b <= 0. */
double bgm_budget_attempts(double deadline, double backoff);

/* Calls for proposals one round can send: D + D(D - 1) + ... + D(D - 1)^(h - 1). */
double bgm_budget_calls(int degree, int hops);

/* The bound on a run's messages (see above). */
double bgm_budget_messages(const bgm_budget_t *b, double requests, double deals, double agents);

#endif
