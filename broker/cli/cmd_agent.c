/*
 * biotgrid agent [--config FILE] [--listen ENDPOINT] [--services LIST] [--slots N]
 *                [--name NAME] [--ready-file FILE]
 *                [--broker ENDPOINT [--floor X] [--margin X] [--load-slope X]
 *                 [--cores N] [--memory GIB] [--core-floor X] [--memory-floor X]
 *                 [--resource-margin X] [--resource-load-slope X] [--lease S]]
 *                [--curve-key FILE --broker-key FILE] [--insecure]
 *
 * With --broker the agent also sells on the broker's live market
 * (bga_market): it registers, heartbeats, sells at its price policy and
 * computes only for jobs whose contract it holds, with the cores and
 * memory bought for it from its host's resource sellers; the daemon is one
 * of those too (its second role), with the host's cores and memory unless
 * --cores/--memory say otherwise (--cores 0: no resource role).
 * Binds, prints "agent NAME ready on ENDPOINT" (the resolved port) on
 * stdout, writes "ENDPOINT PID" to the ready file if asked (written to a
 * temporary name and renamed, so a reader never sees half of it), serves
 * until SIGTERM or SIGINT, finishes the request in progress and exits 0.
 * Command-line options override the config file's keys.
 *
 * With --curve-key (its secret key file) and --broker-key (the broker's
 * public key file) every socket of the agent speaks CURVE: its listening
 * socket admits only the broker's key (the broker's coordinators present
 * it) and its market connection expects the broker's; its name defaults
 * to the key file's (NAME.key). Without keys, an endpoint beyond loopback
 * (--listen or --broker) is refused (exit 2 naming --curve-key) unless
 * --insecure. Refusals are printed on stderr with the peer's address and
 * key.
 */
#include "cmd_agent.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bg_mesh_io.h"
#include "bga_agent.h"
#include "cmd.h"

const char bg_cmd_agent_usage[] =
    "usage: biotgrid agent [--config FILE] [--listen ENDPOINT] [--services LIST]\n"
    "                      [--slots N] [--name NAME] [--ready-file FILE]\n"
    "                      [--broker ENDPOINT [--floor X] [--margin X] [--load-slope X]\n"
    "                       [--cores N] [--memory GIB] [--core-floor X] [--memory-floor X]\n"
    "                       [--resource-margin X] [--resource-load-slope X] [--lease S]]\n"
    "                      [--curve-key FILE --broker-key FILE] [--insecure]\n"
    "  --listen ENDPOINT   ZeroMQ endpoint to bind (default tcp://127.0.0.1:*,\n"
    "                      an ephemeral port; the resolved one is printed)\n"
    "  --services LIST     rotfit,solve,integ or all (default all)\n"
    "  --slots N           jobs held at once (default 4)\n"
    "  --config FILE       JSON object with keys listen, services, slots, name\n"
    "  --broker ENDPOINT   sell on the broker's market at that ZeroMQ endpoint; compute\n"
    "                      only for jobs whose contract this agent holds\n"
    "  --floor X           price floor per unit of work (default 1)\n"
    "  --margin X          markup over the floor (default 0.2)\n"
    "  --load-slope X      price rise at full load, relative (default 0.5)\n"
    "  --cores N           cores its resource role sells (default: the host's; 0: none)\n"
    "  --memory GIB        memory its resource role sells, GiB (default: the host's)\n"
    "  --core-floor X      resource floor per core-second, > 0 (default 1e-5)\n"
    "  --memory-floor X    resource floor per GiB-second, > 0 (default 2e-6)\n"
    "  --resource-margin X, --resource-load-slope X\n"
    "                      the resource role's markup and load slope (default 0.2, 0.5)\n"
    "  --lease S           seconds a service contract's resources are rented (default 3600)\n"
    "  --curve-key FILE    this agent's CURVE secret key (biotgrid keygen; mode 0600):\n"
    "                      every socket speaks CURVE, the name defaults to FILE's (NAME.key)\n"
    "  --broker-key FILE   the broker's public key (.pub): the only key the agent's\n"
    "                      socket admits, and the key its market connection expects\n"
    "  --insecure          listen or reach the broker beyond loopback without keys\n"
    "                      (refused otherwise: every message would travel in clear)\n";

/* A refusal on one of the agent's sockets (the ZAP handler's thread). */
static void say_refusal(void *ctx, const char *line)
{
    fprintf(stderr, "agent %s: %s\n", (const char *)ctx, line);
}

/* The broker's ERROR answer, said once until it changes. */
static void say_refused(void *ctx, const char *why)
{
    fprintf(stderr, "agent %s: the broker says: %s\n", (const char *)ctx, why);
}

/* The resource role's standing, said once per change. */
static void say_standby(void *ctx, const char *why)
{
    if (why)
        fprintf(stderr, "agent %s: resource role stands by: %s\n", (const char *)ctx, why);
    else
        fprintf(stderr, "agent %s: resource role now sells its host's cores and memory\n",
                (const char *)ctx);
}

static void say_new_epoch(void *ctx, uint64_t previous, uint64_t epoch)
{
    fprintf(stderr,
            "agent %s: the broker restarted (epoch %llu, was %llu): the previous broker's "
            "contracts and jobs dropped\n",
            (const char *)ctx, (unsigned long long)epoch, (unsigned long long)previous);
}

static void usage(FILE *out)
{
    fputs(bg_cmd_agent_usage, out);
}

typedef struct options {
    bg_agent_spec_t spec;
    const char *ready_file;
    const char *broker;
    const char *curve_key, *broker_key;
    int insecure;
    double floor, margin, load_slope;
    double cores, memory, core_floor, memory_floor, res_margin, res_load_slope, lease;
} options;

static int parse_money(const char *text, const char *opt, double *v)
{
    char *end;
    errno = 0;
    const double x = strtod(text, &end);
    if (errno || *end || end == text || !(x >= 0 && x <= 1e9)) {
        fprintf(stderr, "biotgrid agent: %s: '%s' is not a number in [0, 1e9]\n", opt, text);
        return 2;
    }
    *v = x;
    return 0;
}

void bg_agent_spec_default(bg_agent_spec_t *spec)
{
    memset(spec, 0, sizeof *spec);
    snprintf(spec->listen, sizeof spec->listen, "tcp://127.0.0.1:*");
    snprintf(spec->services, sizeof spec->services, "all");
    spec->slots = 4;
}

static int parse_slots(const char *text, const char *where, int *slots)
{
    char *end;
    errno = 0;
    const long v = strtol(text, &end, 10);
    if (errno || *end || end == text || v < 1 || v > 4096) {
        fprintf(stderr, "biotgrid agent: %s: slots '%s' is not an integer in [1, 4096]\n", where,
                text);
        return 2;
    }
    *slots = (int)v;
    return 0;
}

static int copy_string(char *dst, size_t cap, const char *src, const char *where, const char *key)
{
    if (strlen(src) >= cap) {
        fprintf(stderr, "biotgrid: %s: %s is longer than %zu characters\n", where, key, cap - 1);
        return 2;
    }
    memcpy(dst, src, strlen(src) + 1);
    return 0;
}

int bg_agent_spec_parse(const cJSON *obj, const char *where, bg_agent_spec_t *spec)
{
    if (!cJSON_IsObject(obj)) {
        fprintf(stderr, "biotgrid: %s: not a JSON object\n", where);
        return 2;
    }
    for (const cJSON *it = obj->child; it; it = it->next) {
        const char *key = it->string;
        int rc = 0;
        if (strcmp(key, "slots") == 0) {
            if (!cJSON_IsNumber(it) || it->valuedouble != (int)it->valuedouble ||
                it->valuedouble < 1 || it->valuedouble > 4096) {
                fprintf(stderr, "biotgrid: %s: slots must be an integer in [1, 4096]\n", where);
                rc = 2;
            } else {
                spec->slots = (int)it->valuedouble;
            }
        } else if (strcmp(key, "listen") == 0 || strcmp(key, "services") == 0 ||
                   strcmp(key, "name") == 0) {
            char *dst = key[0] == 'l' ? spec->listen : key[0] == 's' ? spec->services : spec->name;
            const size_t cap = key[0] == 'l'   ? sizeof spec->listen
                               : key[0] == 's' ? sizeof spec->services
                                               : sizeof spec->name;
            if (!cJSON_IsString(it)) {
                fprintf(stderr, "biotgrid: %s: %s must be a string\n", where, key);
                rc = 2;
            } else {
                rc = copy_string(dst, cap, it->valuestring, where, key);
            }
        } else {
            fprintf(stderr, "biotgrid: %s: unknown key '%s'\n", where, key);
            rc = 2;
        }
        if (rc)
            return rc;
    }
    return 0;
}

/* Reads the config file's keys into o. */
static int read_config(const char *path, options *o)
{
    char *text = NULL;
    size_t len = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_file_read_all(path, 1 << 16, &text, &len, &err) != BG_OK) {
        fprintf(stderr, "biotgrid agent: %s\n", err.message);
        return 2;
    }
    cJSON *root = cJSON_ParseWithLength(text, len);
    free(text);
    int rc;
    if (!root) {
        fprintf(stderr, "biotgrid agent: %s: malformed JSON\n", path);
        rc = 2;
    } else {
        rc = bg_agent_spec_parse(root, path, &o->spec);
    }
    cJSON_Delete(root);
    return rc;
}

/*
 * The transport's security from the options: with --curve-key and
 * --broker-key the key pair and the broker's key (2 on a bad or missing
 * file, or one without the other); without them an endpoint beyond
 * loopback is refused unless --insecure.
 */
static int security(options *o, bga_curve_keypair_t *pair, char *broker_key)
{
    bg_error_t err = BG_ERROR_INIT;
    if (!o->curve_key != !o->broker_key) {
        fprintf(stderr, "biotgrid agent: %s\n",
                o->curve_key ? "--curve-key needs --broker-key FILE, the broker's public key: "
                               "the only key this agent's socket admits"
                             : "--broker-key needs --curve-key FILE, this agent's secret key "
                               "(biotgrid keygen)");
        return 2;
    }
    if (!o->curve_key) {
        const char *beyond = !bga_curve_endpoint_is_loopback(o->spec.listen) ? o->spec.listen
                             : o->broker && !bga_curve_endpoint_is_loopback(o->broker) ? o->broker
                                                                                       : NULL;
        if (beyond && !o->insecure) {
            fprintf(stderr,
                    "biotgrid agent: --curve-key: %s is beyond loopback and every message "
                    "would travel in clear: give --curve-key FILE --broker-key FILE (biotgrid "
                    "keygen), or --insecure to run without keys anyway\n",
                    beyond);
            return 2;
        }
        return 0;
    }
    if (bga_curve_read_secret(o->curve_key, pair, &err) != BG_OK) {
        fprintf(stderr, "biotgrid agent: --curve-key %s\n", err.message);
        return err.status == BG_ERR_UNSUPPORTED ? 1 : 2;
    }
    bg_error_t perr = BG_ERROR_INIT;
    if (bga_curve_read_public(o->broker_key, broker_key, &perr) != BG_OK) {
        fprintf(stderr, "biotgrid agent: --broker-key %s\n", perr.message);
        return 2;
    }
    /* The name the broker binds to the key: the key file's, unless given. */
    char name[BGA_CURVE_NAME_MAX];
    if (!o->spec.name[0] &&
        bga_curve_name_of(o->curve_key, BGA_CURVE_SECRET_SUFFIX, name, NULL) == BG_OK)
        snprintf(o->spec.name, sizeof o->spec.name, "%s", name);
    return 0;
}

static int parse_args(int argc, char **argv, options *o)
{
    const char *config = NULL;
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--config") == 0 && i + 1 < argc)
            config = argv[i + 1];
    if (config && read_config(config, o) != 0)
        return 2;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return -1;
        }
        if (strcmp(a, "--insecure") == 0) {
            o->insecure = 1;
            continue;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "biotgrid agent: unknown option or missing value: '%s'\n", a);
            usage(stderr);
            return 2;
        }
        const char *v = argv[++i];
        int rc = 0;
        /* The price policy and the resource role: numbers in [0, 1e9]. */
        const struct {
            const char *flag;
            double *dst;
        } numbers[] = {{"--floor", &o->floor},
                       {"--margin", &o->margin},
                       {"--load-slope", &o->load_slope},
                       {"--cores", &o->cores},
                       {"--memory", &o->memory},
                       {"--core-floor", &o->core_floor},
                       {"--memory-floor", &o->memory_floor},
                       {"--resource-margin", &o->res_margin},
                       {"--resource-load-slope", &o->res_load_slope},
                       {"--lease", &o->lease}};
        double *money = NULL;
        for (size_t k = 0; k < sizeof numbers / sizeof *numbers; k++)
            if (strcmp(a, numbers[k].flag) == 0)
                money = numbers[k].dst;
        if (strcmp(a, "--config") == 0)
            continue;
        else if (strcmp(a, "--listen") == 0)
            rc = copy_string(o->spec.listen, sizeof o->spec.listen, v, "--listen", "the endpoint");
        else if (strcmp(a, "--services") == 0)
            rc =
                copy_string(o->spec.services, sizeof o->spec.services, v, "--services", "the list");
        else if (strcmp(a, "--name") == 0)
            rc = copy_string(o->spec.name, sizeof o->spec.name, v, "--name", "the name");
        else if (strcmp(a, "--slots") == 0)
            rc = parse_slots(v, "--slots", &o->spec.slots);
        else if (strcmp(a, "--ready-file") == 0)
            o->ready_file = v;
        else if (strcmp(a, "--broker") == 0)
            o->broker = v;
        else if (strcmp(a, "--curve-key") == 0)
            o->curve_key = v;
        else if (strcmp(a, "--broker-key") == 0)
            o->broker_key = v;
        else if (money)
            rc = parse_money(v, a, money);
        else {
            fprintf(stderr, "biotgrid agent: unknown option '%s'\n", a);
            usage(stderr);
            return 2;
        }
        if (rc)
            return rc;
    }
    return 0;
}

int bg_cmd_agent(int argc, char **argv)
{
    options o;
    memset(&o, 0, sizeof o);
    bg_agent_spec_default(&o.spec);
    bga_market_config_t mc;
    bga_market_config_default(&mc);
    o.floor = mc.floor[0];
    o.margin = mc.margin;
    o.load_slope = mc.load_slope;
    o.cores = mc.cores;
    o.memory = mc.memory;
    o.core_floor = mc.res_floor[0];
    o.memory_floor = mc.res_floor[1];
    o.res_margin = mc.res_margin;
    o.res_load_slope = mc.res_load_slope;
    o.lease = mc.lease;
    const int prc = parse_args(argc, argv, &o);
    if (prc != 0)
        return prc < 0 ? 0 : prc;
    if (!(o.lease > 0 && o.lease <= 1e7) || o.cores > 1e6) {
        fprintf(stderr, "biotgrid agent: %s\n",
                o.cores > 1e6 ? "--cores: at most 1e6" : "--lease: must be in (0, 1e7] seconds");
        return 2;
    }
    /* A resource seller prices from its costs (bgm_resource): a zero cost
     * would post free cores, so the resource floors must be positive. */
    if (!(o.core_floor > 0) || !(o.memory_floor > 0)) {
        fprintf(stderr, "biotgrid agent: %s: must be > 0\n",
                o.core_floor > 0 ? "--memory-floor" : "--core-floor");
        return 2;
    }
    bg_error_t err = BG_ERROR_INIT;
    const unsigned services = bga_service_parse_list(o.spec.services, &err);
    if (!services) {
        fprintf(stderr, "biotgrid agent: --services: %s\n", err.message);
        return 2;
    }
    bga_curve_keypair_t pair;
    char broker_key[BGA_CURVE_KEY_SIZE] = "";
    const int src = security(&o, &pair, broker_key);
    if (src != 0)
        return src;
    bg_agent_spec_t *sp = &o.spec;
    if (!sp->name[0])
        snprintf(sp->name, sizeof sp->name, "agent-%ld", (long)getpid());
    bga_agent_config_t cfg = {.listen = sp->listen,
                              .service = {sp->slots, services, sp->name, {0, 0}},
                              .poll_ms = 100,
                              .curve = o.curve_key ? &pair : NULL,
                              .broker_key = o.curve_key ? broker_key : NULL,
                              .log = say_refusal,
                              .log_ctx = sp->name};
    if (o.broker) {
        mc.broker = o.broker;
        mc.services = services;
        mc.slots = sp->slots;
        for (int g = 0; g < BGA_MMSG_GOODS; g++)
            mc.floor[g] = o.floor;
        mc.margin = o.margin;
        mc.load_slope = o.load_slope;
        mc.cores = o.cores;
        mc.memory = o.memory;
        mc.res_floor[0] = o.core_floor;
        mc.res_floor[1] = o.memory_floor;
        mc.res_margin = o.res_margin;
        mc.res_load_slope = o.res_load_slope;
        mc.lease = o.lease;
        mc.on_standby = say_standby;
        mc.standby_ctx = sp->name;
        mc.on_refused = say_refused;
        mc.refused_ctx = sp->name;
        mc.on_new_epoch = say_new_epoch;
        mc.epoch_ctx = sp->name;
        cfg.market = &mc;
    }
    bga_agent_t *agent = NULL;
    const bg_status made = bga_agent_new(&cfg, &agent, &err);
    memset(&pair, 0, sizeof pair); /* the socket holds its copy */
    if (made != BG_OK) {
        fprintf(stderr, "biotgrid agent: %s\n", err.message);
        return err.status == BG_ERR_IO || err.status == BG_ERR_INVALID ? 2 : 1;
    }
    bg_cmd_stop_on_signals();
    int rc = 0;
    char ready[1024];
    const int ready_length =
        snprintf(ready, sizeof ready, "%s %ld\n", bga_agent_endpoint(agent), (long)getpid());
    if (o.ready_file && (ready_length >= (int)sizeof ready ||
                         bg_cmd_write_ready_file(o.ready_file, ready) != 0)) {
        fprintf(stderr, "biotgrid agent: cannot write the ready file %s: %s\n", o.ready_file,
                strerror(errno));
        rc = 1;
        goto out;
    }
    printf("agent %s ready on %s (services %s, %d slots)\n", sp->name, bga_agent_endpoint(agent),
           sp->services, sp->slots);
    fflush(stdout);
    if (bga_agent_run(agent, &bg_cmd_stop_requested, &err) != BG_OK) {
        fprintf(stderr, "biotgrid agent %s: %s\n", sp->name, err.message);
        rc = 1;
    }
    const bga_service_stats_t s = bga_agent_stats(agent);
    fprintf(stderr,
            "agent %s stopping: %lld requests, %lld errors, %lld released, %lld "
            "expired, %.3f s computing\n",
            sp->name, (long long)s.requests, (long long)s.errors, (long long)s.released,
            (long long)s.expired, s.compute_seconds);
out:
    bga_agent_destroy(&agent);
    return rc;
}
