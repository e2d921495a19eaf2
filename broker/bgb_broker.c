#include "bgb_broker.h"

#include <cJSON.h>
#include <gnutls/gnutls.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_file.h"
#include "bga_curve.h"
#include "bga_service.h"
#include "bga_zap.h"
#include "bgb_coord.h"
#include "bgb_loop.h"
#include "bgb_rest.h"
#include "bgb_store.h"

#define BROKER_PATH_MAX 4096
/* A certificate chain or a key file larger than this is not a PEM file. */
#define BROKER_PEM_MAX (1 << 20)
#define MASK(s) (1u << (s))

struct bgb_broker {
    bgb_config_t config;
    bgb_store_t *store;
    bgb_loop_t *loop;
    bgb_coord_t *coord;
    bgb_rest_t *rest;
    char *pool_json; /* the fixed pool as a JSON array, for GET /v1/agents */
    char *tls_cert, *tls_key; /* PEM texts read from the config's files, or NULL */
};

/* The fixed pool's agents (source "config") as a JSON array. */
static char *pool_json(const bgb_config_t *c)
{
    cJSON *arr = cJSON_CreateArray();
    for (int i = 0; arr && i < c->agent_count; i++) {
        cJSON *a = cJSON_CreateObject();
        cJSON_AddStringToObject(a, "endpoint", c->agents[i].endpoint);
        cJSON *s = cJSON_AddArrayToObject(a, "services");
        for (unsigned bit = BGA_SERVICE_ROTFIT; bit <= BGA_SERVICE_INTEG; bit <<= 1)
            if (c->agents[i].services & bit)
                cJSON_AddItemToArray(s, cJSON_CreateString(bga_service_name(bit)));
        cJSON_AddStringToObject(a, "source", "config");
        cJSON_AddItemToArray(arr, a);
    }
    char *text = arr ? cJSON_PrintUnformatted(arr) : NULL;
    cJSON_Delete(arr);
    return text;
}

/* bgb_rest's live views (REST threads): the loop renders them; the agents'
 * list is the fixed pool followed by the market's directory. */
static char *rest_view(void *ctx, int what)
{
    bgb_broker_t *b = ctx;
    char *live = bgb_loop_view(b->loop, what);
    if (what != BGB_REST_VIEW_AGENTS || !live)
        return live;
    cJSON *all = cJSON_Parse(b->pool_json), *market = cJSON_Parse(live);
    free(live);
    char *text = NULL;
    if (cJSON_IsArray(all) && cJSON_IsArray(market)) {
        while (market->child) {
            cJSON *item = cJSON_DetachItemViaPointer(market, market->child);
            cJSON_AddItemToArray(all, item);
        }
        text = cJSON_PrintUnformatted(all);
    }
    cJSON_Delete(all);
    cJSON_Delete(market);
    return text;
}

/* Every contract is a "contract" event of its job, written by the store's
 * writer thread: the market loop never waits for the disk. */
static void on_contract(void *ctx, const char *label, const bgb_contract_t *row)
{
    bgb_broker_t *b = ctx;
    if (!label[0])
        return;
    /* Built with cJSON: an agent's name is the agent's own text. */
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return;
    cJSON_AddStringToObject(o, "service", bgb_good_name(row->good));
    cJSON_AddNumberToObject(o, "agent_id", row->seller);
    cJSON_AddStringToObject(o, "agent", row->seller_name);
    cJSON_AddStringToObject(o, "mechanism", bgb_mechanism_name((bgb_mechanism)row->mechanism));
    cJSON_AddNumberToObject(o, "quantity", row->quantity);
    cJSON_AddNumberToObject(o, "price", row->price);
    cJSON_AddNumberToObject(o, "buyer_limit", row->buyer_limit);
    cJSON_AddNumberToObject(o, "seller_limit", row->seller_limit);
    cJSON_AddNumberToObject(o, "use", row->use);
    if (row->clearing)
        cJSON_AddNumberToObject(o, "clearing", (double)row->clearing);
    cJSON_AddNumberToObject(o, "time", row->time);
    char *json = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    if (!json)
        return;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_store_add_event_later(b->store, label, "contract", json, &err) == BG_ERR_LIMIT)
        (void)bgb_store_add_event(b->store, label, "contract", json, &err);
    free(json);
}

static void on_queued(void *ctx)
{
    bgb_broker_t *b = ctx;
    if (b->coord)
        bgb_coord_notify(b->coord);
}

/* A job is being cancelled (REST thread): its contracts are settled first. */
static void on_cancel(void *ctx, const char *id)
{
    bgb_broker_t *b = ctx;
    if (b->loop)
        bgb_loop_settle(b->loop, id);
}

/* Jobs a previous broker process left half done (see the header). */
static bg_status recover(bgb_broker_t *b, bg_error_t *err)
{
    for (int state = BGB_JOB_ALLOCATING; state <= BGB_JOB_RUNNING; state++) {
        for (;;) {
            bgb_job_t jobs[16];
            int count = 0;
            int64_t next = 0;
            bg_status st = bgb_store_list(b->store, state, 0, 16, jobs, &count, &next, err);
            if (st != BG_OK)
                return st;
            for (int i = 0; i < count && st == BG_OK; i++) {
                st = state == BGB_JOB_ALLOCATING
                         ? bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_ALLOCATING),
                                                BGB_JOB_QUEUED,
                                                "the broker restarted before the job's services "
                                                "were bought: queued again",
                                                err)
                         : bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_RUNNING),
                                                BGB_JOB_QUEUED,
                                                "the broker restarted while the job was running: "
                                                "queued again, it runs again from its start",
                                                err);
                /* The agents drop what they held for it as soon as they
                 * hear this broker's epoch, so it runs once, afresh. */
                if (st == BG_OK && state == BGB_JOB_RUNNING)
                    st = bgb_store_add_event(b->store, jobs[i].id, "restarted",
                                             "{\"reason\":\"the broker restarted while the job "
                                             "was running\",\"from\":\"running\"}",
                                             err);
            }
            for (int i = 0; i < count; i++)
                bgb_job_release(&jobs[i]);
            if (st != BG_OK)
                return st;
            if (count == 0)
                break;
        }
    }
    return BG_OK;
}

/*
 * ZeroMQ beyond loopback without CURVE would let anyone on the network
 * register as an agent and read every job's meshes: refused unless the
 * operator says --insecure. With CURVE, the key pair is read (pair) and a
 * fixed pool is refused: its agents would be reached in clear, with keys
 * nobody vouched for.
 */
static bg_status curve_check(const bgb_config_t *c, bga_curve_keypair_t *pair, bg_error_t *err)
{
    if (!c->curve_key != !c->authorized_agents)
        return bg_error_set(err, BG_ERR_INVALID, "%s",
                            c->curve_key ? "--curve-key needs --authorized-agents DIR, the folder "
                                           "of the agents' public keys (NAME.pub)"
                                         : "--authorized-agents needs --curve-key FILE, the "
                                           "broker's secret key (biotgrid keygen)");
    if (!c->curve_key) {
        if (!c->insecure && !bga_curve_endpoint_is_loopback(c->endpoint))
            return bg_error_set(err, BG_ERR_INVALID,
                                "--curve-key: the agents' endpoint %s is beyond loopback and "
                                "without CURVE anyone who reaches it could register as an agent "
                                "and read the jobs: give --curve-key FILE --authorized-agents "
                                "DIR (biotgrid keygen), or --insecure to run it in clear anyway",
                                c->endpoint);
        return BG_OK;
    }
    if (c->agent_count > 0)
        return bg_error_set(err, BG_ERR_INVALID,
                            "agents: a fixed pool's agents would be reached without CURVE: with "
                            "--curve-key agents register on the market (biotgrid agent --broker "
                            "ENDPOINT --curve-key FILE --broker-key FILE)");
    bg_error_t kerr = BG_ERROR_INIT;
    bg_status st = bga_curve_read_secret(c->curve_key, pair, &kerr);
    if (st != BG_OK)
        return bg_error_set(err, st == BG_ERR_UNSUPPORTED ? st : BG_ERR_INVALID, "--curve-key %s",
                            kerr.message);
    /* The folder read now, so a bad one is refused before any state is made. */
    int keys = 0;
    bg_error_t ferr = BG_ERROR_INIT;
    if ((st = bga_zap_check_folder(c->authorized_agents, &keys, &ferr)) != BG_OK)
        return bg_error_set(err, st == BG_ERR_NOMEM ? st : BG_ERR_INVALID, "--authorized-agents %s",
                            ferr.message);
    return BG_OK;
}

/* Plain HTTP beyond loopback would carry every bearer token in clear:
 * refused unless the operator says --insecure. */
static bg_status transport_check(const bgb_config_t *c, bg_error_t *err)
{
    if (!c->tls_cert != !c->tls_key)
        return bg_error_set(err, BG_ERR_INVALID,
                            "--tls-cert and --tls-key go together (tls_cert and tls_key)");
    if (!c->tls_cert && !c->insecure && !bgb_rest_address_is_loopback(c->address))
        return bg_error_set(err, BG_ERR_INVALID,
                            "the REST address %s is beyond loopback and plain HTTP would "
                            "show every bearer token to the network: give --tls-cert FILE "
                            "--tls-key FILE, or --insecure to serve it in clear anyway",
                            c->address);
    return BG_OK;
}

static bg_status read_pem(const char *path, const char *option, char **text, bg_error_t *err)
{
    *text = NULL;
    if (!path)
        return BG_OK;
    size_t length = 0;
    bg_error_t read_err = BG_ERROR_INIT;
    if (bg_file_read_all(path, BROKER_PEM_MAX, text, &length, &read_err) != BG_OK)
        return bg_error_set(err, BG_ERR_INVALID, "%s: %s", option, read_err.message);
    if (strlen(*text) != length || !strstr(*text, "-----BEGIN ")) {
        free(*text);
        *text = NULL;
        return bg_error_set(err, BG_ERR_INVALID, "%s %s: not a PEM file", option, path);
    }
    return BG_OK;
}

bg_status bgb_broker_start(const bgb_config_t *config, bgb_broker_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_broker_t *b = calloc(1, sizeof *b);
    if (!b)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker");
    bg_status st = bgb_config_copy(&b->config, config, err);
    if (st != BG_OK) {
        free(b);
        return st;
    }
    bgb_limits_resolve(&b->config.limits, bgb_limits_ram());
    char path[BROKER_PATH_MAX + 32];
    bga_curve_keypair_t pair;
    memset(&pair, 0, sizeof pair);
    if ((st = transport_check(&b->config, err)) != BG_OK ||
        (st = curve_check(&b->config, &pair, err)) != BG_OK ||
        (st = read_pem(b->config.tls_cert, "--tls-cert", &b->tls_cert, err)) != BG_OK ||
        (st = read_pem(b->config.tls_key, "--tls-key", &b->tls_key, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/jobs", b->config.state_dir);
    if ((st = bg_file_make_directories_mode(path, 0700, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/broker.sqlite", b->config.state_dir);
    if ((st = bgb_store_open(path, &b->store, err)) != BG_OK || (st = recover(b, err)) != BG_OK)
        goto out;
    bgb_loop_config_t lc = {.endpoint = b->config.endpoint,
                            .market = b->config.market,
                            .on_contract = on_contract,
                            .contract_ctx = b,
                            .curve = b->config.curve_key ? &pair : NULL,
                            .authorized_agents = b->config.authorized_agents,
                            .log = b->config.log,
                            .log_ctx = b->config.log_ctx};
    lc.market.name = b->config.name;
    st = bgb_loop_start(&lc, &b->loop, err);
    memset(&pair, 0, sizeof pair); /* the loop keeps its copy */
    if (st != BG_OK)
        goto out;
    if ((st = bgb_coord_start(&b->config, b->store, b->loop, &b->coord, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/uploads", b->config.state_dir);
    if ((st = bg_file_make_directories_mode(path, 0700, err)) != BG_OK)
        goto out;
    if (!(b->pool_json = pool_json(&b->config))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the agents' list");
        goto out;
    }
    const bgb_rest_config_t rc = {.agents_json = b->pool_json,
                                  .address = b->config.address,
                                  .port = (uint16_t)b->config.port,
                                  .tls_cert_pem = b->tls_cert,
                                  .tls_key_pem = b->tls_key,
                                  .limits = &b->config.limits,
                                  .work_dir = path,
                                  .name = b->config.name,
                                  .market = "live",
                                  .view = rest_view,
                                  .view_ctx = b,
                                  .on_queued = on_queued,
                                  .queued_ctx = b,
                                  .on_cancel = on_cancel};
    bg_error_t rest_err = BG_ERROR_INIT;
    st = bgb_rest_start(&rc, b->store, &b->rest, &rest_err);
    if (st != BG_OK && b->tls_cert)
        bg_error_set(err, st, "--tls-cert %s, --tls-key %s: %s", b->config.tls_cert,
                     b->config.tls_key, rest_err.message);
    else if (st != BG_OK)
        bg_error_set(err, st, "%s", rest_err.message);
out:
    if (st != BG_OK)
        bgb_broker_stop(&b);
    *out = b;
    return st;
}

uint16_t bgb_broker_rest_port(const bgb_broker_t *b)
{
    return bgb_rest_port(b->rest);
}

int bgb_broker_rest_url(const bgb_broker_t *b, char *buf, size_t size)
{
    const int n = snprintf(buf, size, "%s://%s:%u", bgb_rest_tls(b->rest) ? "https" : "http",
                           b->config.address, (unsigned)bgb_rest_port(b->rest));
    return n < 0 || (size_t)n >= size ? -1 : 0;
}

const bgb_limits_t *bgb_broker_limits(const bgb_broker_t *b)
{
    return &b->config.limits;
}

const char *bgb_broker_endpoint(const bgb_broker_t *b)
{
    return bgb_loop_endpoint(b->loop);
}

int bgb_broker_curve(const bgb_broker_t *b, char public_key[BGA_CURVE_KEY_SIZE], int *keys)
{
    const bga_curve_peers_t *curve = bgb_loop_curve(b->loop);
    if (!curve)
        return 0;
    snprintf(public_key, BGA_CURVE_KEY_SIZE, "%s", curve->self->public_key);
    *keys = bgb_loop_authorized_keys(b->loop);
    return 1;
}

void bgb_broker_stop(bgb_broker_t **bp)
{
    bgb_broker_t *b = bp ? *bp : NULL;
    if (!b)
        return;
    /* No new jobs (REST answers 503, and goes on serving the rest), no
     * new coordinators, running jobs finish within the stop grace (or are
     * queued again); then the event streams get their last events and
     * REST stops; then the market, then the store (its writer commits
     * what is queued). */
    bgb_rest_drain(b->rest);
    bgb_coord_drain(b->coord, b->config.stop_grace_ms / 1000.0);
    bgb_rest_stop(&b->rest);
    bgb_coord_stop(&b->coord);
    bgb_loop_stop(&b->loop);
    bgb_store_destroy(&b->store);
    free(b->pool_json);
    free(b->tls_cert);
    if (b->tls_key) {
        gnutls_memset(b->tls_key, 0, strlen(b->tls_key));
        free(b->tls_key);
    }
    bgb_config_release(&b->config);
    free(b);
    *bp = NULL;
}
