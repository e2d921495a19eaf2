/*
 * bgb_broker — the broker daemon as a library: it wires together the
 * durable store (bgb_store), the market loop that owns the agents' ZeroMQ
 * endpoint and the live market (bgb_loop, an actor), the job coordinators
 * and their dispatcher (bgb_coord), and the REST API (bgb_rest), and stops
 * them in the reverse order.
 *
 * Threads: the REST server's own; the market loop; the store's writer; the
 * dispatcher; one coordinator per job. They share no state but through
 * those modules' interfaces: REST tells the dispatcher a job was queued,
 * coordinators buy and release through the loop's inproc pipe, and the
 * loop's contract rows reach the store through its writer thread.
 *
 * Restart: at start, jobs left in allocating are put back in queued
 * (nothing was bought for them), and so are jobs left running, with a
 * "restarted" event: they run again from their start, once, as the
 * agents drop the dead broker's contracts and job state the moment they
 * hear this broker's epoch (bgb_market_epoch, sent in REGISTERED); queued
 * jobs are picked up again.
 */
#ifndef BGB_BROKER_H
#define BGB_BROKER_H

#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>

#include "bg_error.h"
#include "bga_curve.h"
#include "bgb_config.h"

typedef struct bgb_broker bgb_broker_t;

/* Opens the store, recovers jobs, binds REST and ZeroMQ, starts the
 * threads. config is copied. Caller owns *out (bgb_broker_stop).
 *
 * Transport security comes first: config->tls_cert and tls_key (PEM
 * files, both or neither; read and checked as a pair) make REST speak
 * TLS; a REST address beyond loopback without them is BG_ERR_INVALID
 * naming --tls-cert, unless config->insecure. Likewise the agents'
 * endpoint: config->curve_key and authorized_agents (both or neither)
 * make it speak CURVE, admitting the keys in that folder, each agent
 * under its key's name (bgb_loop.h); an endpoint beyond loopback without
 * them is BG_ERR_INVALID naming --curve-key, unless config->insecure; a
 * fixed pool (config->agents) with CURVE is BG_ERR_INVALID. */
bg_status bgb_broker_start(const bgb_config_t *config, bgb_broker_t **out, bg_error_t *err);

/* The limits in force: the configuration's, with the job size caps it
 * left at 0 resolved for this machine (bgb_limits_resolve). */
const bgb_limits_t *bgb_broker_limits(const bgb_broker_t *broker);

/* The REST port and the ROUTER endpoint actually bound. */
uint16_t bgb_broker_rest_port(const bgb_broker_t *broker);
/* The REST base URL clients use, "http[s]://ADDRESS:PORT", into buf;
 * -1 when it does not fit. */
int bgb_broker_rest_url(const bgb_broker_t *broker, char *buf, size_t size);
const char *bgb_broker_endpoint(const bgb_broker_t *broker);
/* Over CURVE: 1, the broker's public key and how many agents' keys the
 * folder held at start; 0 in plaintext. */
int bgb_broker_curve(const bgb_broker_t *broker, char public_key[BGA_CURVE_KEY_SIZE], int *keys);

/* Stops REST, waits for the coordinators (a running solve finishes
 * first), stops the loop, closes the store; accepts NULL. */
void bgb_broker_stop(bgb_broker_t **broker);

#endif
