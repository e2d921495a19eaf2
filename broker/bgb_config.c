#include "bgb_config.h"

#include <cJSON.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "bg_json.h"
#include "bga_mmsg.h"
#include "bga_service.h"

/* A configuration file larger than this is refused before it is read. */
#define CONFIG_MAX_BYTES (1 << 20)

/* The keys of a broker config, in two groups: the broker's own (who it is,
 * where it listens, its keys, store, fixed pool and market) and how its
 * jobs run and recover and its limits, which a grid config's broker
 * object may also give (bgb_config_grid_setting). One list of names each,
 * so a setting added to the broker passes through a grid config too. */
#define CONFIG_OWN_KEYS(X)                                                                        \
    X(name) X(address) X(tls_cert) X(tls_key) X(insecure) X(curve_key) X(authorized_agents)      \
    X(port) X(endpoint) X(state_dir) X(agents) X(market)
#define CONFIG_GRID_KEYS(X)                                                                       \
    X(max_jobs) X(agent_timeout_ms) X(agent_liveness_ms) X(agent_recovery) X(stop_grace_ms)      \
    X(memory_fraction) X(max_vertices) X(max_elements) X(max_work) X(max_body)                   \
    X(max_jobs_in_flight) X(max_stored_bytes) X(max_connections) X(max_connections_per_client)   \
    X(idle_timeout) X(request_timeout)
#define CONFIG_KEY_NAME(k) #k,
static const char *const CONFIG_KEYS[] = {
    CONFIG_OWN_KEYS(CONFIG_KEY_NAME) CONFIG_GRID_KEYS(CONFIG_KEY_NAME) NULL};
static const char *const CONFIG_GRID_SETTINGS[] = {CONFIG_GRID_KEYS(CONFIG_KEY_NAME) NULL};

int bgb_config_grid_setting(const char *key)
{
    for (const char *const *k = CONFIG_GRID_SETTINGS; *k; k++)
        if (strcmp(*k, key) == 0)
            return 1;
    return 0;
}

static char *dup_or_null(const char *s)
{
    return s ? strdup(s) : NULL;
}

bg_status bgb_config_init(bgb_config_t *c, bg_error_t *err)
{
    memset(c, 0, sizeof *c);
    c->name = strdup("biotgrid");
    c->address = strdup("127.0.0.1");
    c->endpoint = strdup("tcp://127.0.0.1:5570");
    c->state_dir = strdup("out/broker");
    c->port = 8080;
    c->max_jobs = 4;
    bgb_limits_default(&c->limits);
    c->agent_timeout_ms = 10000;
    c->agent_liveness_ms = 2000;
    c->agent_recovery = 1;
    c->stop_grace_ms = 30000;
    bgb_market_config_default(&c->market);
    if (!c->name || !c->address || !c->endpoint || !c->state_dir) {
        bgb_config_release(c);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker's configuration");
    }
    return BG_OK;
}

void bgb_config_release(bgb_config_t *c)
{
    if (!c)
        return;
    free(c->name);
    free(c->address);
    free(c->tls_cert);
    free(c->tls_key);
    free(c->curve_key);
    free(c->authorized_agents);
    free(c->endpoint);
    free(c->state_dir);
    for (int i = 0; i < c->agent_count; i++)
        free(c->agents[i].endpoint);
    memset(c, 0, sizeof *c);
}

static bg_status replace_string(char **slot, const cJSON *item, const char *path, const char *field,
                                bg_error_t *err)
{
    const char *s = NULL;
    bg_status st = bg_json_string(item, path, field, &s, err);
    if (st != BG_OK)
        return st;
    if (!*s)
        return bg_json_fail(err, BG_ERR_INVALID, path, field, "must not be empty");
    char *copy = strdup(s);
    if (!copy)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    free(*slot);
    *slot = copy;
    return BG_OK;
}

static bg_status read_agents(const cJSON *arr, const char *path, bgb_config_t *c, bg_error_t *err)
{
    if (!cJSON_IsArray(arr))
        return bg_json_fail(err, BG_ERR_INVALID, path, "agents", "expected an array, got %s",
                            bg_json_type_name(arr));
    static const char *const keys[] = {"endpoint", "services", "name", NULL};
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, arr)
    {
        char field[BG_JSON_PATH_MAX], sub[BG_JSON_PATH_MAX];
        bg_json_path_index(field, "agents", i);
        if (i >= BGB_CONFIG_MAX_AGENTS)
            return bg_json_fail(err, BG_ERR_INVALID, path, field, "more than %d agents",
                                BGB_CONFIG_MAX_AGENTS);
        bg_status st = bg_json_expect_object(e, path, field, err);
        if (st == BG_OK)
            st = bg_json_check_keys(e, path, field, keys, err);
        if (st != BG_OK)
            return st;
        const char *ep = NULL, *services = NULL;
        bg_json_path_key(sub, field, "endpoint");
        st = bg_json_string(cJSON_GetObjectItemCaseSensitive(e, "endpoint"), path, sub, &ep, err);
        if (st != BG_OK)
            return st;
        if (strncmp(ep, "tcp://", 6) != 0 || strlen(ep) > 200)
            return bg_json_fail(err, BG_ERR_INVALID, path, sub,
                                "'%s' is not tcp://HOST:PORT (at most 200 bytes)", ep);
        bg_json_path_key(sub, field, "services");
        st = bg_json_string(cJSON_GetObjectItemCaseSensitive(e, "services"), path, sub, &services,
                            err);
        if (st != BG_OK)
            return st;
        bg_error_t perr = BG_ERROR_INIT;
        const unsigned bits = bga_service_parse_list(services, &perr);
        if (bits == 0)
            return bg_json_fail(err, BG_ERR_INVALID, path, sub, "%s", perr.message);
        c->agents[i].endpoint = strdup(ep);
        if (!c->agents[i].endpoint)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        c->agents[i].services = bits;
        c->agent_count = ++i;
    }
    return BG_OK;
}

bg_status bgb_config_market_read(const cJSON *obj, const char *path, bgb_market_config_t *m,
                                 bg_error_t *err)
{
    static const char *const keys[] = {
        "period",         "k",    "heartbeat_timeout", "reply_timeout", "buy_timeout",
        "overlay_degree", "hops", "max_rounds",        "max_contracts", NULL};
    bg_status st;
    if ((st = bg_json_expect_object(obj, path, "market", err)) != BG_OK ||
        (st = bg_json_check_keys(obj, path, "market", keys, err)) != BG_OK)
        return st;
    const struct {
        const char *key;
        double *at;
    } times[] = {{"period", &m->period},
                 {"heartbeat_timeout", &m->heartbeat_timeout},
                 {"reply_timeout", &m->reply_timeout},
                 {"buy_timeout", &m->buy_timeout}};
    const struct {
        const char *key;
        double lo, hi;
        int *at;
    } counts[] = {{"overlay_degree", 1, BGA_MMSG_MAX_NEIGHBOURS, &m->overlay_degree},
                  {"hops", 1, 16, &m->hops},
                  {"max_rounds", 1, 1000, &m->max_rounds}};
    const cJSON *item;
    cJSON_ArrayForEach(item, obj)
    {
        char field[BG_JSON_PATH_MAX];
        bg_json_path_key(field, "market", item->string);
        const char *k = item->string;
        int64_t v = 0;
        if (strcmp(k, "k") == 0)
            st = bg_json_number_in(item, path, field, 0, 1, &m->k, err);
        else if (strcmp(k, "max_contracts") == 0) {
            st = bg_json_integer(item, path, field, 1, 1e7, &v, err);
            m->max_contracts = (size_t)v;
        }
        for (size_t i = 0; i < sizeof times / sizeof times[0]; i++)
            if (strcmp(k, times[i].key) == 0) {
                st = bg_json_number_in(item, path, field, 0, 3600, times[i].at, err);
                if (st == BG_OK && !(*times[i].at > 0 && *times[i].at < 3600))
                    st = bg_json_fail(err, BG_ERR_INVALID, path, field,
                                      "%.17g s is outside (0, 3600)", *times[i].at);
            }
        for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++)
            if (strcmp(k, counts[i].key) == 0) {
                st = bg_json_integer(item, path, field, counts[i].lo, counts[i].hi, &v, err);
                *counts[i].at = (int)v;
            }
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

/* The integer limits' keys (bgb_limits.h), their ranges and where they go. */
typedef enum { LIMIT_I64, LIMIT_INT, LIMIT_UNSIGNED, LIMIT_SIZE } limit_kind;
static const struct {
    const char *key;
    double lo, hi;
    size_t offset;
    limit_kind kind;
} INTEGER_LIMITS[] = {
    {"max_vertices", 1, 5e7, offsetof(bgb_limits_t, max_vertices), LIMIT_I64},
    {"max_elements", 1, 2e8, offsetof(bgb_limits_t, max_elements), LIMIT_I64},
    {"max_body", 1024, 1 << 30, offsetof(bgb_limits_t, max_body), LIMIT_SIZE},
    {"max_jobs_in_flight", 1, 1e6, offsetof(bgb_limits_t, max_jobs_in_flight), LIMIT_INT},
    {"max_stored_bytes", 1, 1e15, offsetof(bgb_limits_t, max_stored_bytes), LIMIT_I64},
    {"max_connections", 1, 1e5, offsetof(bgb_limits_t, max_connections), LIMIT_UNSIGNED},
    {"max_connections_per_client", 1, 1e5, offsetof(bgb_limits_t, max_connections_per_client),
     LIMIT_UNSIGNED},
    {"idle_timeout", 1, 3600, offsetof(bgb_limits_t, idle_timeout), LIMIT_UNSIGNED},
    {"request_timeout", 1, 3600, offsetof(bgb_limits_t, request_timeout), LIMIT_UNSIGNED},
};

/* One of the limits' keys into *l; BG_ERR_INVALID naming the field. */
static bg_status read_limit(const cJSON *item, const char *path, const char *k, bgb_limits_t *l,
                            bg_error_t *err)
{
    if (strcmp(k, "memory_fraction") == 0) {
        bg_status st = bg_json_number_in(item, path, k, 0, 1, &l->memory_fraction, err);
        if (st == BG_OK && !(l->memory_fraction > 0))
            st = bg_json_fail(err, BG_ERR_INVALID, path, k, "must be in (0, 1]");
        return st;
    }
    if (strcmp(k, "max_work") == 0)
        return bg_json_number_in(item, path, k, 1, 1e18, &l->max_work, err);
    for (size_t i = 0; i < sizeof INTEGER_LIMITS / sizeof INTEGER_LIMITS[0]; i++) {
        if (strcmp(k, INTEGER_LIMITS[i].key) != 0)
            continue;
        int64_t v = 0;
        bg_status st =
            bg_json_integer(item, path, k, INTEGER_LIMITS[i].lo, INTEGER_LIMITS[i].hi, &v, err);
        if (st != BG_OK)
            return st;
        char *at = (char *)l + INTEGER_LIMITS[i].offset;
        switch (INTEGER_LIMITS[i].kind) {
        case LIMIT_I64:
            *(int64_t *)(void *)at = v;
            break;
        case LIMIT_INT:
            *(int *)(void *)at = (int)v;
            break;
        case LIMIT_UNSIGNED:
            *(unsigned *)(void *)at = (unsigned)v;
            break;
        case LIMIT_SIZE:
            *(size_t *)(void *)at = (size_t)v;
            break;
        }
        return BG_OK;
    }
    return bg_json_fail(err, BG_ERR_INVALID, path, k, "unknown limit");
}

bg_status bgb_config_read(const char *path, bgb_config_t *c, bg_error_t *err)
{
    cJSON *root = NULL;
    bg_status st = bg_json_load(path, CONFIG_MAX_BYTES, &root, err);
    if (st == BG_OK)
        st = bgb_config_read_object(root, path, c, err);
    cJSON_Delete(root);
    return st;
}

bg_status bgb_config_read_object(const cJSON *root, const char *path, bgb_config_t *c,
                                 bg_error_t *err)
{
    bg_status st = BG_OK;
    if ((st = bg_json_expect_object(root, path, NULL, err)) != BG_OK ||
        (st = bg_json_check_keys(root, path, NULL, CONFIG_KEYS, err)) != BG_OK)
        return st;
    const cJSON *item;
    cJSON_ArrayForEach(item, root)
    {
        const char *k = item->string;
        int64_t v = 0;
        if (strcmp(k, "name") == 0)
            st = replace_string(&c->name, item, path, k, err);
        else if (strcmp(k, "address") == 0)
            st = replace_string(&c->address, item, path, k, err);
        else if (strcmp(k, "tls_cert") == 0)
            st = replace_string(&c->tls_cert, item, path, k, err);
        else if (strcmp(k, "tls_key") == 0)
            st = replace_string(&c->tls_key, item, path, k, err);
        else if (strcmp(k, "insecure") == 0) {
            if (!cJSON_IsBool(item))
                st = bg_json_fail(err, BG_ERR_INVALID, path, k, "must be true or false");
            c->insecure = cJSON_IsTrue(item);
        } else if (strcmp(k, "endpoint") == 0)
            st = replace_string(&c->endpoint, item, path, k, err);
        else if (strcmp(k, "curve_key") == 0)
            st = replace_string(&c->curve_key, item, path, k, err);
        else if (strcmp(k, "authorized_agents") == 0)
            st = replace_string(&c->authorized_agents, item, path, k, err);
        else if (strcmp(k, "state_dir") == 0)
            st = replace_string(&c->state_dir, item, path, k, err);
        else if (strcmp(k, "agents") == 0)
            st = read_agents(item, path, c, err);
        else if (strcmp(k, "market") == 0)
            st = bgb_config_market_read(item, path, &c->market, err);
        else if (strcmp(k, "port") == 0) {
            st = bg_json_integer(item, path, k, 0, 65535, &v, err);
            c->port = (int)v;
        } else if (strcmp(k, "max_jobs") == 0) {
            st = bg_json_integer(item, path, k, 1, BGB_CONFIG_MAX_JOBS, &v, err);
            c->max_jobs = (int)v;
        } else if (strcmp(k, "agent_timeout_ms") == 0) {
            st = bg_json_integer(item, path, k, 1, 3600000, &v, err);
            c->agent_timeout_ms = (int)v;
        } else if (strcmp(k, "agent_liveness_ms") == 0) {
            st = bg_json_integer(item, path, k, 100, 600000, &v, err);
            c->agent_liveness_ms = (int)v;
        } else if (strcmp(k, "agent_recovery") == 0) {
            st = bg_json_bool(item, path, k, &c->agent_recovery, err);
        } else if (strcmp(k, "stop_grace_ms") == 0) {
            st = bg_json_integer(item, path, k, 0, 3600000, &v, err);
            c->stop_grace_ms = (int)v;
        } else {
            st = read_limit(item, path, k, &c->limits, err);
        }
        if (st != BG_OK)
            return st;
    }
    return st;
}

bg_status bgb_config_copy(bgb_config_t *to, const bgb_config_t *from, bg_error_t *err)
{
    *to = *from;
    to->name = dup_or_null(from->name);
    to->address = dup_or_null(from->address);
    to->tls_cert = dup_or_null(from->tls_cert);
    to->tls_key = dup_or_null(from->tls_key);
    to->curve_key = dup_or_null(from->curve_key);
    to->authorized_agents = dup_or_null(from->authorized_agents);
    to->endpoint = dup_or_null(from->endpoint);
    to->state_dir = dup_or_null(from->state_dir);
    int ok = to->name && to->address && to->endpoint && to->state_dir &&
             (!from->tls_cert || to->tls_cert) && (!from->tls_key || to->tls_key) &&
             (!from->curve_key || to->curve_key) &&
             (!from->authorized_agents || to->authorized_agents);
    for (int i = 0; i < from->agent_count; i++) {
        to->agents[i].endpoint = dup_or_null(from->agents[i].endpoint);
        ok &= to->agents[i].endpoint != NULL;
    }
    if (!ok) {
        bgb_config_release(to);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker's configuration");
    }
    return BG_OK;
}
