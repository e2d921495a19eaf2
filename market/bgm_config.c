#include "bgm_config.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_json.h"
#include "bg_file.h"

const char *const bgm_service_names[BGM_SERVICE_TYPES] = {"rotation-fit", "sparse-solve",
                                                          "integration-step"};
const char *const bgm_mechanism_names[BGM_MAX_MECHANISMS] = {"central", "catallactic",
                                                             "baseline"};
const char *const bgm_topology_names[BGM_TOPOLOGIES] = {"star", "cluster", "random", "scale-free"};
const char *const bgm_resource_market_names[2] = {"exchange", "call"};

typedef enum ftype { F_INT, F_LONG, F_NUM, F_STR, F_U64 } ftype;

/* One scalar field of a JSON object: where it goes and what it may hold. */
typedef struct field {
    const char *name;
    ftype type;
    void *dst;
    double min, max;
    int required;
    size_t str_cap;
} field_t;

#define FIELD_END {NULL, F_INT, NULL, 0, 0, 0, 0}

/* Rejects keys not listed in names (NULL-terminated), naming the valid
 * ones, and repeated keys. */
static bg_status check_keys(const char *nm, const cJSON *obj, const char *path,
                            const char *const *names, bg_error_t *err)
{
    return bg_json_check_keys(obj, nm, path, names, err);
}

static bg_status get_number(const char *nm, const cJSON *item, const char *path, double min,
                            double max, int integral, double *out, bg_error_t *err)
{
    if (integral) {
        int64_t v = 0;
        bg_status st = bg_json_integer(item, nm, path, min, max, &v, err);
        if (st == BG_OK)
            *out = (double)v;
        return st;
    }
    return bg_json_number_in(item, nm, path, min, max, out, err);
}

/* Parses the listed scalar fields of obj; other keys are the caller's
 * (extra) or unknown. */
static bg_status parse_fields(const char *nm, const cJSON *obj, const char *path, const field_t *f,
                              const char *const *extra, bg_error_t *err)
{
    const char *names[48];
    size_t n = 0;
    for (const field_t *p = f; p->name; p++)
        names[n++] = p->name;
    for (const char *const *e = extra; e && *e; e++)
        names[n++] = *e;
    names[n] = NULL;
    bg_status st = bg_json_expect_object(obj, nm, path, err);
    if (st)
        return st;
    st = check_keys(nm, obj, path, names, err);
    if (st)
        return st;
    for (const field_t *p = f; p->name; p++) {
        char fp[BG_JSON_PATH_MAX];
        bg_json_path_key(fp, path, p->name);
        const cJSON *it = cJSON_GetObjectItemCaseSensitive(obj, p->name);
        if (!it) {
            if (p->required)
                return bg_json_fail(err, BG_ERR_INVALID, nm, fp, "missing (a required field)");
            continue;
        }
        double v = 0.0;
        switch (p->type) {
        case F_STR:
            if (!cJSON_IsString(it) || strlen(it->valuestring) >= p->str_cap ||
                it->valuestring[0] == '\0')
                return bg_json_fail(err, BG_ERR_INVALID, nm, fp,
                                    "must be a non-empty string shorter than %zu", p->str_cap);
            memcpy(p->dst, it->valuestring, strlen(it->valuestring) + 1);
            continue;
        case F_INT:
        case F_LONG:
        case F_U64:
            st = get_number(nm, it, fp, p->min, p->max, 1, &v, err);
            break;
        case F_NUM:
            st = get_number(nm, it, fp, p->min, p->max, 0, &v, err);
            break;
        }
        if (st)
            return st;
        if (p->type == F_INT)
            *(int *)p->dst = (int)v;
        else if (p->type == F_LONG)
            *(long *)p->dst = (long)v;
        else if (p->type == F_U64)
            *(uint64_t *)p->dst = (uint64_t)v;
        else
            *(double *)p->dst = v;
    }
    return BG_OK;
}

static void set_defaults(bgm_config_t *c)
{
    memset(c, 0, sizeof *c);
    c->drain = 60.0;
    c->dynamics_count = 1;
    snprintf(c->dynamics[0].name, BGM_NAME_MAX, "static");
    c->dynamics[0].node_repair_mean = 30.0;
    c->dynamics[0].link_repair_mean = 10.0;
    c->network.topology = BGM_TOPO_STAR;
    c->network.latency = 0.005;
    c->network.bandwidth = 1.25e8;
    c->network.speed = 1e9;
    c->network.speed_spread = 0.5;
    c->network.degree = 4;
    c->network.message_bytes = 256;
    c->agents.complex_per_node = 1.0;
    c->agents.service_slots = 2;
    c->agents.services_per_agent = 2;
    c->agents.resource_cores = 4;
    c->agents.resource_memory = 8.0;
    c->agents.overlay_degree = 6;
    c->demand.interarrival_mean = 60.0;
    c->demand.work_min = 1;
    c->demand.work_max = 8;
    c->demand.valuation_mean = 3.0;
    c->demand.valuation_spread = 0.5;
    c->demand.deadline = 60.0;
    c->demand.plan_count = 2;
    c->demand.plans[0] = (bgm_plan_cfg_t){{1, 1, 0}, 0.5};
    c->demand.plans[1] = (bgm_plan_cfg_t){{1, 1, 1}, 0.5};
    c->demand.shock_time = -1.0;
    c->demand.shock_factor = 1.0;
    static const bgm_service_cfg_t svc[BGM_SERVICE_TYPES] = {
        {2e9, 1, 1.0, 0.4}, {5e9, 2, 4.0, 0.8}, {3e9, 1, 2.0, 0.6}};
    memcpy(c->services, svc, sizeof svc);
    c->resources.core_cost = 0.1;
    c->resources.memory_cost = 0.02;
    c->resources.cost_spread = 0.5;
    c->central.period = 1.0;
    c->central.k = 0.5;
    c->central.exact_limit = 400;
    c->central.greedy_budget = 1000000;
    c->central.optimum_limit = 250000;
    c->central.resource_market = BGM_RM_EXCHANGE;
    c->catallactic.hops = 2;
    c->catallactic.discovery_timeout = 0.5;
    c->catallactic.reply_timeout = 0.5;
    c->catallactic.max_rounds = 12;
    c->catallactic.learning_period = 30.0;
    c->catallactic.imitation = 0.3;
    c->catallactic.mutation = 0.05;
    c->catallactic.mutation_sigma = 0.1;
    c->catallactic.retry_backoff = 2.0;
    c->baseline.markup = 0.3;
    c->baseline.candidates = 8;
    c->baseline.retry_backoff = 2.0;
    c->metrics.convergence_tolerance = 0.1;
    c->metrics.price_bucket = 10.0;
}

static int name_index(const char *s, const char *const *names, int n)
{
    for (int i = 0; i < n; i++)
        if (strcmp(s, names[i]) == 0)
            return i;
    return -1;
}

static bg_status parse_array(const char *nm, const cJSON *obj, const char *key, const char *path, int max,
                             const cJSON **arr, int *count, bg_error_t *err)
{
    *arr = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!*arr)
        return bg_json_fail(err, BG_ERR_INVALID, nm, path, "missing (a required field)");
    if (!cJSON_IsArray(*arr) || cJSON_GetArraySize(*arr) < 1 || cJSON_GetArraySize(*arr) > max)
        return bg_json_fail(err, BG_ERR_INVALID, nm, path, "must be an array of 1 to %d items",
                            max);
    *count = cJSON_GetArraySize(*arr);
    return BG_OK;
}

static bg_status parse_dynamics(const char *nm, const cJSON *obj, bgm_config_t *c, bg_error_t *err)
{
    if (!cJSON_IsObject(obj))
        return bg_json_expect_object(obj, nm, "dynamics", err);
    c->dynamics_count = 0;
    for (const cJSON *d = obj->child; d; d = d->next) {
        if (c->dynamics_count >= BGM_MAX_DYNAMICS)
            return bg_json_fail(err, BG_ERR_LIMIT, nm, "dynamics", "has more than %d entries",
                                BGM_MAX_DYNAMICS);
        bgm_dynamics_t *dy = &c->dynamics[c->dynamics_count];
        char path[BG_JSON_PATH_MAX];
        bg_json_path_key(path, "dynamics", d->string);
        if (strlen(d->string) == 0 || strlen(d->string) >= BGM_NAME_MAX)
            return bg_json_fail(err, BG_ERR_INVALID, nm, path, "a name of 1 to %d characters",
                                BGM_NAME_MAX - 1);
        snprintf(dy->name, BGM_NAME_MAX, "%s", d->string);
        dy->node_repair_mean = 30.0;
        dy->link_repair_mean = 10.0;
        field_t f[] = {{"node_failure_rate", F_NUM, &dy->node_failure_rate, 0, 1, 0, 0},
                       {"node_repair_mean", F_NUM, &dy->node_repair_mean, 1e-3, 1e6, 0, 0},
                       {"link_failure_rate", F_NUM, &dy->link_failure_rate, 0, 1, 0, 0},
                       {"link_repair_mean", F_NUM, &dy->link_repair_mean, 1e-3, 1e6, 0, 0},
                       FIELD_END};
        bg_status st = parse_fields(nm, d, path, f, NULL, err);
        if (st)
            return st;
        c->dynamics_count++;
    }
    return BG_OK;
}

static bg_status parse_plans(const char *nm, const cJSON *arr, bgm_config_t *c, bg_error_t *err)
{
    if (!cJSON_IsArray(arr) || cJSON_GetArraySize(arr) < 1 ||
        cJSON_GetArraySize(arr) > BGM_MAX_PLANS)
        return bg_json_fail(err, BG_ERR_INVALID, nm, "demand.plans",
                            "must be an array of 1 to %d plans", BGM_MAX_PLANS);
    c->demand.plan_count = 0;
    for (const cJSON *p = arr->child; p; p = p->next) {
        char path[BG_JSON_PATH_MAX];
        int i = c->demand.plan_count;
        bg_json_path_index(path, "demand.plans", i);
        bgm_plan_cfg_t *pl = &c->demand.plans[i];
        memset(pl, 0, sizeof *pl);
        field_t f[] = {{"weight", F_NUM, &pl->weight, 1e-9, 1e9, 1, 0}, FIELD_END};
        static const char *const extra[] = {"services", NULL};
        bg_status st = parse_fields(nm, p, path, f, extra, err);
        if (st)
            return st;
        const cJSON *sv = cJSON_GetObjectItemCaseSensitive(p, "services");
        if (!cJSON_IsArray(sv) || cJSON_GetArraySize(sv) < 1)
        {
            char sp[BG_JSON_PATH_MAX];
            bg_json_path_key(sp, path, "services");
            return bg_json_fail(err, BG_ERR_INVALID, nm, sp,
                                "must be a non-empty array of service names");
        }
        int k = 0;
        for (const cJSON *s = sv->child; s; s = s->next, k++) {
            int t = cJSON_IsString(s) ? name_index(s->valuestring, bgm_service_names,
                                                   BGM_SERVICE_TYPES)
                                      : -1;
            if (t < 0)
            {
                char sp[BG_JSON_PATH_MAX], spi[BG_JSON_PATH_MAX];
                bg_json_path_key(sp, path, "services");
                bg_json_path_index(spi, sp, k);
                return bg_json_fail(err, BG_ERR_INVALID, nm, spi,
                                    "must be one of rotation-fit, sparse-solve, integration-step");
            }
            pl->services[t] = 1;
        }
        c->demand.plan_count++;
    }
    return BG_OK;
}

/*
 * factors.topology: a list of distinct topology names, each level a set
 * of scenarios on that generated platform. It replaces network.topology
 * (both given is refused: which one holds would be a guess) and cannot go
 * with network.platform (a user platform is not generated).
 */
static bg_status parse_topology_factor(const char *nm, const cJSON *root, const cJSON *fac,
                                       bgm_config_t *c, bg_error_t *err)
{
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(fac, "topology");
    c->topology_levels = 0;
    if (!arr)
        return BG_OK;
    if (!cJSON_IsArray(arr) || cJSON_GetArraySize(arr) < 1 ||
        cJSON_GetArraySize(arr) > BGM_TOPOLOGIES)
        return bg_json_fail(err, BG_ERR_INVALID, nm, "factors.topology",
                            "must be an array of 1 to %d topology names", BGM_TOPOLOGIES);
    const cJSON *net = cJSON_GetObjectItemCaseSensitive(root, "network");
    if (cJSON_IsObject(net) && cJSON_GetObjectItemCaseSensitive(net, "topology"))
        return bg_json_fail(err, BG_ERR_INVALID, nm, "factors.topology",
                            "network.topology is given too: name the topologies in one place");
    if (cJSON_IsObject(net) && cJSON_GetObjectItemCaseSensitive(net, "platform"))
        return bg_json_fail(err, BG_ERR_INVALID, nm, "factors.topology",
                            "cannot go with network.platform (a user platform is not generated)");
    int i = 0;
    for (const cJSON *x = arr->child; x; x = x->next, i++) {
        char tp[BG_JSON_PATH_MAX];
        bg_json_path_index(tp, "factors.topology", i);
        const int k =
            cJSON_IsString(x) ? name_index(x->valuestring, bgm_topology_names, BGM_TOPOLOGIES) : -1;
        if (k < 0)
            return bg_json_fail(err, BG_ERR_INVALID, nm, tp,
                                "must be star, cluster, random or scale-free");
        for (int j = 0; j < i; j++)
            if (c->topology[j] == k)
                return bg_json_fail(err, BG_ERR_INVALID, nm, tp, "repeats '%s'",
                                    bgm_topology_names[k]);
        c->topology[i] = k;
    }
    c->topology_levels = i;
    return BG_OK;
}

static bg_status parse_root(const char *nm, const cJSON *root, bgm_config_t *c, bg_error_t *err)
{
    bg_status st;
    static const char *const extra[] = {"mechanisms", "factors",  "dynamics",  "network",
                                        "agents",     "demand",   "services",  "resources",
                                        "central",    "catallactic", "baseline", "metrics",
                                        "description", NULL};
    field_t top[] = {{"name", F_STR, c->name, 0, 0, 1, BGM_NAME_MAX},
                     {"seed", F_U64, &c->seed, 0, 9007199254740992.0, 1, 0},
                     {"replications", F_INT, &c->replications, 1, BGM_MAX_REPLICATIONS, 1, 0},
                     {"duration", F_NUM, &c->duration, 1e-3, 1e7, 1, 0},
                     {"drain", F_NUM, &c->drain, 0, 1e7, 0, 0},
                     FIELD_END};
    if ((st = parse_fields(nm, root, "", top, extra, err)))
        return st;
    const cJSON *d = cJSON_GetObjectItemCaseSensitive(root, "description");
    if (d && !cJSON_IsString(d))
        return bg_json_fail(err, BG_ERR_INVALID, nm, "description", "expected a string, got %s",
                            bg_json_type_name(d));

    const cJSON *arr;
    int n;
    if ((st = parse_array(nm, root, "mechanisms", "mechanisms", BGM_MAX_MECHANISMS, &arr, &n, err)))
        return st;
    c->mechanism_count = 0;
    for (const cJSON *m = arr->child; m; m = m->next) {
        char mp[BG_JSON_PATH_MAX];
        bg_json_path_index(mp, "mechanisms", c->mechanism_count);
        int k = cJSON_IsString(m) ? name_index(m->valuestring, bgm_mechanism_names,
                                               BGM_MAX_MECHANISMS)
                                  : -1;
        if (k < 0)
            return bg_json_fail(err, BG_ERR_INVALID, nm, mp,
                                "must be central, catallactic or baseline");
        for (int j = 0; j < c->mechanism_count; j++)
            if (c->mechanisms[j] == k)
                return bg_json_fail(err, BG_ERR_INVALID, nm, mp, "repeats '%s'",
                                    bgm_mechanism_names[k]);
        c->mechanisms[c->mechanism_count++] = k;
    }

    const cJSON *dyn = cJSON_GetObjectItemCaseSensitive(root, "dynamics");
    if (dyn && (st = parse_dynamics(nm, dyn, c, err)))
        return st;

    const cJSON *fac = cJSON_GetObjectItemCaseSensitive(root, "factors");
    if (!fac)
        return bg_json_fail(err, BG_ERR_INVALID, nm, "factors", "missing (a required field)");
    if ((st = bg_json_expect_object(fac, nm, "factors", err)))
        return st;
    static const char *const fnames[] = {"nodes", "density", "dynamics", "topology", NULL};
    if ((st = check_keys(nm, fac, "factors", fnames, err)))
        return st;
    if ((st = parse_array(nm, fac, "nodes", "factors.nodes", BGM_MAX_LEVELS, &arr, &c->node_levels, err)))
        return st;
    int i = 0;
    for (const cJSON *x = arr->child; x; x = x->next, i++) {
        char p[64];
        double v;
        snprintf(p, sizeof p, "factors.nodes[%d]", i);
        if ((st = get_number(nm, x, p, 1, BGM_MAX_NODES, 1, &v, err)))
            return st;
        c->nodes[i] = (int)v;
    }
    if ((st = parse_array(nm, fac, "density", "factors.density", BGM_MAX_LEVELS, &arr,
                          &c->density_levels, err)))
        return st;
    i = 0;
    for (const cJSON *x = arr->child; x; x = x->next, i++) {
        char p[64];
        snprintf(p, sizeof p, "factors.density[%d]", i);
        if ((st = get_number(nm, x, p, 0.01, 64, 0, &c->density[i], err)))
            return st;
    }
    const cJSON *fd = cJSON_GetObjectItemCaseSensitive(fac, "dynamics");
    if (!fd) {
        c->dynamics_levels = 1;
        c->dynamics_index[0] = 0;
    } else {
        if ((st = parse_array(nm, fac, "dynamics", "factors.dynamics", BGM_MAX_LEVELS, &arr,
                              &c->dynamics_levels, err)))
            return st;
        i = 0;
        for (const cJSON *x = arr->child; x; x = x->next, i++) {
            int k = -1;
            for (int j = 0; cJSON_IsString(x) && j < c->dynamics_count; j++)
                if (strcmp(x->valuestring, c->dynamics[j].name) == 0)
                    k = j;
            if (k < 0)
            {
                char dp[BG_JSON_PATH_MAX];
                bg_json_path_index(dp, "factors.dynamics", i);
                return bg_json_fail(err, BG_ERR_INVALID, nm, dp,
                                    "must name an entry of 'dynamics'");
            }
            c->dynamics_index[i] = k;
        }
    }

    if ((st = parse_topology_factor(nm, root, fac, c, err)))
        return st;

    const cJSON *o;
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "network"))) {
        char topo[16] = "star";
        field_t f[] = {{"topology", F_STR, topo, 0, 0, 0, sizeof topo},
                       {"platform", F_STR, c->network.platform, 0, 0, 0, BGM_PATH_MAX},
                       {"latency", F_NUM, &c->network.latency, 0, 10, 0, 0},
                       {"bandwidth", F_NUM, &c->network.bandwidth, 1e3, 1e12, 0, 0},
                       {"speed", F_NUM, &c->network.speed, 1e6, 1e15, 0, 0},
                       {"speed_spread", F_NUM, &c->network.speed_spread, 0, 0.95, 0, 0},
                       {"degree", F_INT, &c->network.degree, 1, 64, 0, 0},
                       {"message_bytes", F_INT, &c->network.message_bytes, 1, 1 << 24, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "network", f, NULL, err)))
            return st;
        c->network.topology = name_index(topo, bgm_topology_names, BGM_TOPOLOGIES);
        if (c->network.topology < 0)
            return bg_json_fail(err, BG_ERR_INVALID, nm, "network.topology",
                                "must be star, cluster, random or scale-free");
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "agents"))) {
        field_t f[] = {{"complex_per_node", F_NUM, &c->agents.complex_per_node, 0.01, 64, 0, 0},
                       {"service_slots", F_INT, &c->agents.service_slots, 1, 1024, 0, 0},
                       {"services_per_agent", F_INT, &c->agents.services_per_agent, 1, 3, 0, 0},
                       {"resource_cores", F_INT, &c->agents.resource_cores, 1, 4096, 0, 0},
                       {"resource_memory", F_NUM, &c->agents.resource_memory, 0.1, 1e6, 0, 0},
                       {"overlay_degree", F_INT, &c->agents.overlay_degree, 1, 32, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "agents", f, NULL, err)))
            return st;
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "demand"))) {
        static const char *const dx[] = {"plans", "shock", NULL};
        field_t f[] = {{"interarrival_mean", F_NUM, &c->demand.interarrival_mean, 1e-3, 1e9, 0, 0},
                       {"work_min", F_INT, &c->demand.work_min, 1, 1e6, 0, 0},
                       {"work_max", F_INT, &c->demand.work_max, 1, 1e6, 0, 0},
                       {"valuation_mean", F_NUM, &c->demand.valuation_mean, 1e-6, 1e9, 0, 0},
                       {"valuation_spread", F_NUM, &c->demand.valuation_spread, 0, 0.95, 0, 0},
                       {"deadline", F_NUM, &c->demand.deadline, 1e-3, 1e9, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "demand", f, dx, err)))
            return st;
        if (c->demand.work_max < c->demand.work_min)
            return bg_json_fail(err, BG_ERR_INVALID, nm, "demand.work_max",
                                "must be >= demand.work_min");
        const cJSON *pl = cJSON_GetObjectItemCaseSensitive(o, "plans");
        if (pl && (st = parse_plans(nm, pl, c, err)))
            return st;
        const cJSON *sh = cJSON_GetObjectItemCaseSensitive(o, "shock");
        if (sh) {
            field_t fs[] = {{"time", F_NUM, &c->demand.shock_time, 0, 1e9, 1, 0},
                            {"factor", F_NUM, &c->demand.shock_factor, 0.01, 100, 1, 0},
                            FIELD_END};
            if ((st = parse_fields(nm, sh, "demand.shock", fs, NULL, err)))
                return st;
        }
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "services"))) {
        static const char *const sn[] = {"rotation-fit", "sparse-solve", "integration-step", NULL};
        if (!cJSON_IsObject(o))
            return bg_json_expect_object(o, nm, "services", err);
        if ((st = check_keys(nm, o, "services", sn, err)))
            return st;
        for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
            const cJSON *s = cJSON_GetObjectItemCaseSensitive(o, bgm_service_names[t]);
            if (!s)
                continue;
            char p[64];
            snprintf(p, sizeof p, "services.%s", bgm_service_names[t]);
            bgm_service_cfg_t *sv = &c->services[t];
            field_t f[] = {{"flops_per_unit", F_NUM, &sv->flops_per_unit, 1, 1e18, 0, 0},
                           {"cores", F_INT, &sv->cores, 1, 4096, 0, 0},
                           {"memory", F_NUM, &sv->memory, 0, 1e6, 0, 0},
                           {"cost_per_unit", F_NUM, &sv->cost_per_unit, 0, 1e9, 0, 0},
                           FIELD_END};
            if ((st = parse_fields(nm, s, p, f, NULL, err)))
                return st;
        }
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "resources"))) {
        field_t f[] = {{"core_cost", F_NUM, &c->resources.core_cost, 0, 1e9, 0, 0},
                       {"memory_cost", F_NUM, &c->resources.memory_cost, 0, 1e9, 0, 0},
                       {"cost_spread", F_NUM, &c->resources.cost_spread, 0, 0.95, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "resources", f, NULL, err)))
            return st;
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "central"))) {
        char rm[16] = "exchange";
        field_t f[] = {{"period", F_NUM, &c->central.period, 1e-3, 1e6, 0, 0},
                       {"k", F_NUM, &c->central.k, 0, 1, 0, 0},
                       {"exact_limit", F_INT, &c->central.exact_limit, 0, 1e6, 0, 0},
                       {"greedy_budget", F_LONG, &c->central.greedy_budget, 0, 1e12, 0, 0},
                       {"optimum_limit", F_INT, &c->central.optimum_limit, 0, 1e7, 0, 0},
                       {"resource_market", F_STR, rm, 0, 0, 0, sizeof rm},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "central", f, NULL, err)))
            return st;
        c->central.resource_market = name_index(rm, bgm_resource_market_names, 2);
        if (c->central.resource_market < 0)
            return bg_json_fail(err, BG_ERR_INVALID, nm, "central.resource_market",
                                "must be exchange or call");
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "catallactic"))) {
        field_t f[] = {{"hops", F_INT, &c->catallactic.hops, 1, 8, 0, 0},
                       {"discovery_timeout", F_NUM, &c->catallactic.discovery_timeout, 1e-4, 1e6, 0, 0},
                       {"reply_timeout", F_NUM, &c->catallactic.reply_timeout, 1e-4, 1e6, 0, 0},
                       {"max_rounds", F_INT, &c->catallactic.max_rounds, 1, 1000, 0, 0},
                       {"learning_period", F_NUM, &c->catallactic.learning_period, 1e-3, 1e9, 0, 0},
                       {"imitation", F_NUM, &c->catallactic.imitation, 0, 1, 0, 0},
                       {"mutation", F_NUM, &c->catallactic.mutation, 0, 1, 0, 0},
                       {"mutation_sigma", F_NUM, &c->catallactic.mutation_sigma, 0, 1, 0, 0},
                       {"retry_backoff", F_NUM, &c->catallactic.retry_backoff, 1e-4, 1e6, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "catallactic", f, NULL, err)))
            return st;
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "baseline"))) {
        field_t f[] = {{"markup", F_NUM, &c->baseline.markup, 0, 10, 0, 0},
                       {"candidates", F_INT, &c->baseline.candidates, 1, 64, 0, 0},
                       {"retry_backoff", F_NUM, &c->baseline.retry_backoff, 1e-4, 1e6, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "baseline", f, NULL, err)))
            return st;
    }
    if ((o = cJSON_GetObjectItemCaseSensitive(root, "metrics"))) {
        field_t f[] = {{"convergence_tolerance", F_NUM, &c->metrics.convergence_tolerance, 1e-4, 1, 0, 0},
                       {"price_bucket", F_NUM, &c->metrics.price_bucket, 1e-3, 1e9, 0, 0},
                       FIELD_END};
        if ((st = parse_fields(nm, o, "metrics", f, NULL, err)))
            return st;
    }
    return BG_OK;
}

/* The name configs parsed from memory go by in messages. */
#define BGM_CONFIG_MEMORY_NAME "<config>"

bg_status bgm_config_parse(const char *text, size_t length, const char *name, bgm_config_t *cfg,
                           bg_error_t *err)
{
    const char *nm = name ? name : BGM_CONFIG_MEMORY_NAME;
    set_defaults(cfg);
    if (length > BGM_CONFIG_MAX_BYTES)
        return bg_json_fail(err, BG_ERR_LIMIT, nm, NULL, "%zu bytes exceed the limit of %d bytes",
                            length, BGM_CONFIG_MAX_BYTES);
    cJSON *root = NULL;
    bg_status st = bg_json_parse(text, length, nm, &root, err);
    if (st)
        return st;
    if (!cJSON_IsObject(root)) {
        st = bg_json_fail(err, BG_ERR_INVALID, nm, NULL, "an experiment is a JSON object, got %s",
                          bg_json_type_name(root));
        goto out;
    }
    st = parse_root(nm, root, cfg, err);
out:
    cJSON_Delete(root);
    return st;
}

/* A relative network.platform names a file next to the config: it is
 * rewritten relative to the working directory (or left absolute), and
 * must be readable now, before any run starts. */
static bg_status resolve_platform(const char *path, bgm_config_t *cfg, bg_error_t *err)
{
    char *plat = cfg->network.platform;
    if (!plat[0])
        return BG_OK;
    const char *slash = strrchr(path, '/');
    if (plat[0] != '/' && slash) {
        char joined[2 * BGM_PATH_MAX];
        int n = snprintf(joined, sizeof joined, "%.*s/%s", (int)(slash - path), path, plat);
        if (n < 0 || (size_t)n >= BGM_PATH_MAX)
            return bg_json_fail(err, BG_ERR_LIMIT, path, "network.platform",
                                "'%s' relative to the config is longer than %d bytes", plat,
                                BGM_PATH_MAX - 1);
        memcpy(plat, joined, (size_t)n + 1);
    }
    FILE *f = fopen(plat, "r");
    if (!f)
        return bg_json_fail(err, BG_ERR_INVALID, path, "network.platform", "cannot open '%s': %s",
                            plat, strerror(errno));
    fclose(f);
    return BG_OK;
}

bg_status bgm_config_load(const char *path, bgm_config_t *cfg, bg_error_t *err)
{
    char *text = NULL;
    size_t length = 0;
    bg_status st = bg_file_read_all(path, BGM_CONFIG_MAX_BYTES, &text, &length, err);
    if (st == BG_OK)
        st = bgm_config_parse(text, length, path, cfg, err);
    if (st == BG_OK)
        st = resolve_platform(path, cfg, err);
    free(text);
    return st;
}

/* Scenarios on one topology: nodes x density x dynamics. */
static int per_topology(const bgm_config_t *c)
{
    return c->node_levels * c->density_levels * c->dynamics_levels;
}

int bgm_config_scenario_count(const bgm_config_t *c)
{
    return per_topology(c) * (c->topology_levels > 0 ? c->topology_levels : 1);
}

void bgm_config_scenario(const bgm_config_t *c, int s, int *nodes, double *density,
                         const bgm_dynamics_t **dynamics)
{
    int dy = s % c->dynamics_levels;
    int de = (s / c->dynamics_levels) % c->density_levels;
    int no = (s / (c->dynamics_levels * c->density_levels)) % c->node_levels;
    *nodes = c->nodes[no];
    *density = c->density[de];
    *dynamics = &c->dynamics[c->dynamics_index[dy]];
}

int bgm_config_scenario_topology(const bgm_config_t *c, int s)
{
    return c->topology_levels > 0 ? c->topology[s / per_topology(c)] : c->network.topology;
}

int bgm_config_scenario_stream(const bgm_config_t *c, int s)
{
    return s % per_topology(c);
}

void bgm_config_scenario_label(char *buf, size_t n, const char *topology, int nodes, double density,
                               const char *dynamics)
{
    if (topology)
        snprintf(buf, n, "%s_n%d_d%g_%s", topology, nodes, density, dynamics);
    else
        snprintf(buf, n, "n%d_d%g_%s", nodes, density, dynamics);
}

int bgm_config_agent_count(const bgm_config_t *c, int nodes, double density)
{
    int cx = (int)lround(nodes * c->agents.complex_per_node);
    int per = (int)lround(nodes * density);
    if (cx < 1)
        cx = 1;
    if (per < 1)
        per = 1;
    return cx + 2 * per;
}
