#include "bgm_sim.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bg_error.h"
#include "bg_file.h"
#include "bgm_config.h"
#include "bgm_evq.h"
#include "bgm_platform.h"
#include "bgm_plot.h"
#include "bgm_rng.h"
#include "bgm_simdriver.h"
#include "bgm_stats.h"
#include "bgm_world.h"

#define BGM_MAX_RUNS 100000
/* Blocks at least this large are mapped on their own (see run_child). */
#define BGM_MMAP_THRESHOLD (128 * 1024)
#define BGM_COPY_CHUNK 65536

typedef bgm_sim_options_t sim_opts_t;

typedef struct run_id {
    int scenario, mechanism, replication;
} run_id_t;

static void part_path(char *buf, size_t n, const char *out, const run_id_t *r, const char *ext)
{
    snprintf(buf, n, "%s/.parts/s%03d_m%d_r%03d.%s", out, r->scenario, r->mechanism,
             r->replication, ext);
}

/* ------------------------------------------------------------ child side */

static bg_status write_part(const char *path, bgm_world_t *w,
                            bg_status (*fn)(const bgm_world_t *, FILE *))
{
    FILE *f = fopen(path, "w");
    if (!f)
        return BG_ERR_IO;
    bg_status st = fn(w, f);
    if (fclose(f) != 0 && !st)
        st = BG_ERR_IO;
    return st;
}

/* Runs one replication and writes its parts; the process exits after. */
static int run_child(const bgm_config_t *cfg, const sim_opts_t *o, const run_id_t *id)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = BG_OK;
    bgm_world_t *w = NULL;
    double *speed = NULL;
    char path[BGM_PATH_MAX + 64], xml[BGM_PATH_MAX + 64];
    int nodes;
    double density;
    const bgm_dynamics_t *dyn;
    /* A fixed mmap threshold: glibc otherwise raises it to the size of the
     * largest block freed, after which the market's large temporary books
     * stay resident in the heap instead of going back to the system. */
    mallopt(M_MMAP_THRESHOLD, BGM_MMAP_THRESHOLD);
    bgm_config_scenario(cfg, id->scenario, &nodes, &density, &dyn);
    speed = malloc(((size_t)nodes + 1) * sizeof *speed);
    if (!speed) {
        st = bg_error_set(&err, BG_ERR_NOMEM, "out of memory");
        goto out;
    }
    /* The platform depends on (seed, scenario, replication) only, so all
     * mechanisms of a replication run on the same hosts; the scenario's
     * stream index leaves its topology out, so every topology of a
     * topology factor gets the same host speeds and jobs. */
    const int stream = bgm_config_scenario_stream(cfg, id->scenario);
    const int topology = bgm_config_scenario_topology(cfg, id->scenario);
    bgm_rng_t prng;
    bgm_rng_derive(&prng, cfg->seed, (uint64_t)stream, (uint64_t)id->replication,
                   BGM_PLATFORM_STREAM);
    part_path(xml, sizeof xml, o->out, id, "xml");
    int user = cfg->network.platform[0] != '\0';
    if (!user) {
        FILE *f = fopen(xml, "w");
        if (!f) {
            st = bg_error_set(&err, BG_ERR_IO, "%s: cannot write platform", xml);
            goto out;
        }
        st = bgm_platform_write(f, cfg, topology, nodes, &prng, speed);
        if (fclose(f) != 0 || st) {
            st = bg_error_set(&err, BG_ERR_IO, "%s: cannot write platform", xml);
            goto out;
        }
    }
    if (user || !o->inprocess)
        bgm_simdriver_init();
    if (user) {
        /* The economics see the user's hosts: each node's resource agents
         * sell cores at the speed of the host the node runs on. */
        bgm_simdriver_load(cfg->network.platform);
        if ((st = bgm_simdriver_user_speeds((uint32_t)nodes, speed, &err)))
            goto out;
    } else if (!o->inprocess) {
        bgm_simdriver_load(xml);
    }
    const char *named = cfg->topology_levels > 0 ? bgm_topology_names[topology] : NULL;
    bgm_world_params_t wp = {
        cfg,   stream, cfg->mechanisms[id->mechanism], id->replication, nodes, density, dyn,
        speed, named};
    w = bgm_world_new(&wp, &err);
    if (!w) {
        st = err.status ? err.status : BG_ERR_NOMEM;
        goto out;
    }
    long messages = 0;
    double end_time = 0.0;
    if (o->inprocess) {
        bgm_evq_stats_t es;
        if (o->wire)
            st = bgm_evq_run_world_wire(w, cfg->network.latency * 2.0, cfg->network.bandwidth,
                                        &es, &err);
        else if ((st = bgm_evq_run_world(w, cfg->network.latency * 2.0, cfg->network.bandwidth,
                                         &es)))
            bg_error_set(&err, st, "simulation failed: %s", bg_strerror(st));
        messages = es.messages;
        end_time = es.end_time;
    } else {
        bgm_sim_stats_t ss = {0, 0, 0.0};
        st = bgm_simdriver_run(w, user, &ss, &err);
        messages = ss.messages;
        end_time = ss.end_time;
    }
    if (!user)
        remove(xml);
    if (st)
        goto out;
    double m[BGM_M_COUNT];
    if ((st = bgm_world_metrics(w, m))) {
        bg_error_set(&err, st, "metrics failed");
        goto out;
    }
    part_path(path, sizeof path, o->out, id, "met");
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(m, sizeof m, 1, f) != 1) {
        if (f)
            fclose(f);
        st = bg_error_set(&err, BG_ERR_IO, "%s: cannot write", path);
        goto out;
    }
    fclose(f);
    part_path(path, sizeof path, o->out, id, "contracts");
    if ((st = write_part(path, w, bgm_world_write_contracts)))
        goto io;
    part_path(path, sizeof path, o->out, id, "agents");
    if ((st = write_part(path, w, bgm_world_write_agents)))
        goto io;
    part_path(path, sizeof path, o->out, id, "prices");
    if ((st = write_part(path, w, bgm_world_write_prices)))
        goto io;
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    part_path(path, sizeof path, o->out, id, "stats");
    f = fopen(path, "w");
    if (f) {
        fprintf(f, "%ld %.6f %ld %u\n", messages, end_time, ru.ru_maxrss,
                bgm_world_agent_count(w));
        fclose(f);
    }
    goto out;
io:
    bg_error_set(&err, st, "%s: cannot write", path);
out:
    if (st) {
        /* The parent reports it: a child writes its message, not to a console. */
        part_path(path, sizeof path, o->out, id, "err");
        FILE *e = fopen(path, "w");
        if (e) {
            fprintf(e, "%d %s", (int)(err.status ? err.status : st),
                    err.message[0] ? err.message : bg_strerror(st));
            fclose(e);
        }
    }
    bgm_world_destroy(&w);
    free(speed);
    return st ? 1 : 0;
}

/* ----------------------------------------------------------- parent side */

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Reads a failed run's message into err (the first failure is kept). */
static void run_failure(const sim_opts_t *o, const bgm_config_t *cfg, const run_id_t *r,
                        bg_error_t *err)
{
    char path[BGM_PATH_MAX + 64], text[BG_ERROR_MESSAGE_MAX] = "";
    int code = BG_ERR_NUMERIC;
    part_path(path, sizeof path, o->out, r, "err");
    FILE *f = fopen(path, "r");
    if (f) {
        if (fscanf(f, "%d ", &code) != 1)
            code = BG_ERR_NUMERIC;
        size_t n = fread(text, 1, sizeof text - 1, f);
        text[n] = '\0';
        fclose(f);
        remove(path);
    }
    bg_error_set(err, code < 0 ? (bg_status)code : BG_ERR_NUMERIC,
                 "scenario %d, mechanism %s, replication %d: %s", r->scenario,
                 bgm_mechanism_names[cfg->mechanisms[r->mechanism]], r->replication,
                 text[0] ? text : "the run's process died");
}

/* Fills a finished run's report from its stats part. */
static void run_report(const sim_opts_t *o, const bgm_config_t *cfg, const run_id_t *r,
                       int failed, double wall, bgm_sim_run_report_t *rep)
{
    char path[BGM_PATH_MAX + 64];
    double end = 0;
    *rep = (bgm_sim_run_report_t){r->scenario, r->replication,
                                  bgm_mechanism_names[cfg->mechanisms[r->mechanism]],
                                  failed, 0, wall, 0, 0};
    part_path(path, sizeof path, o->out, r, "stats");
    FILE *f = fopen(path, "r");
    if (f) {
        if (fscanf(f, "%ld %lf %ld %u", &rep->messages, &end, &rep->peak_rss_kib, &rep->agents) !=
            4)
            rep->messages = rep->peak_rss_kib = rep->agents = 0;
        fclose(f);
    }
}

static bg_status run_all(const bgm_config_t *cfg, const sim_opts_t *o, const run_id_t *runs, int n,
                         const bgm_sim_observer_t *obs, bg_error_t *err)
{
    pid_t pids[BGM_SIM_MAX_JOBS];
    int slot_run[BGM_SIM_MAX_JOBS];
    double slot_t0[BGM_SIM_MAX_JOBS];
    int active = 0, next = 0, done = 0;
    bg_status st = BG_OK;
    while (done < n) {
        while (active < o->jobs && next < n) {
            fflush(NULL);
            pid_t pid = fork();
            if (pid < 0)
                return bg_error_set(err, BG_ERR_NOMEM, "cannot start a run: %s", strerror(errno));
            if (pid == 0)
                _exit(run_child(cfg, o, &runs[next]));
            pids[active] = pid;
            slot_run[active] = next;
            slot_t0[active] = now_seconds();
            active++;
            next++;
        }
        int status = 0;
        pid_t pid = wait(&status);
        if (pid < 0)
            return bg_error_set(err, BG_ERR_NOMEM, "waiting for the runs: %s", strerror(errno));
        for (int i = 0; i < active; i++) {
            if (pids[i] != pid)
                continue;
            const run_id_t *r = &runs[slot_run[i]];
            int failed = !WIFEXITED(status) || WEXITSTATUS(status) != 0;
            if (failed) {
                run_failure(o, cfg, r, err);
                if (st == BG_OK)
                    st = err->status ? err->status : BG_ERR_NUMERIC;
            }
            done++;
            if (obs && obs->run_done) {
                bgm_sim_run_report_t rep;
                run_report(o, cfg, r, failed, now_seconds() - slot_t0[i], &rep);
                obs->run_done(obs->ctx, done, n, &rep);
            }
            pids[i] = pids[active - 1];
            slot_run[i] = slot_run[active - 1];
            slot_t0[i] = slot_t0[active - 1];
            active--;
            break;
        }
    }
    return st;
}

static bg_status append_file(FILE *dst, const char *src_path)
{
    FILE *s = fopen(src_path, "rb");
    if (!s)
        return BG_ERR_IO;
    char buf[BGM_COPY_CHUNK];
    size_t k;
    while ((k = fread(buf, 1, sizeof buf, s)) > 0)
        if (fwrite(buf, 1, k, dst) != k) {
            fclose(s);
            return BG_ERR_IO;
        }
    fclose(s);
    return BG_OK;
}

static bg_status merge_csv(const sim_opts_t *o, const run_id_t *runs, int n, const char *name,
                           const char *ext, const char *header)
{
    char path[BGM_PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/%s", o->out, name);
    FILE *f = fopen(path, "w");
    if (!f)
        return BG_ERR_IO;
    bg_status st = BG_OK;
    fputs(header, f);
    for (int i = 0; i < n && !st; i++) {
        part_path(path, sizeof path, o->out, &runs[i], ext);
        st = append_file(f, path);
    }
    if (fclose(f) != 0 && !st)
        st = BG_ERR_IO;
    return st;
}

/* A scenario's factors and its name in the outputs ("n40_d2_static",
 * "random_n40_d2_static" with a topology factor). topology is NULL
 * without a topology factor: the outputs do not name it then. */
typedef struct scenario {
    int nodes;
    double density;
    const bgm_dynamics_t *dyn;
    const char *topology;
    char name[BGM_NAME_MAX * 2];
} scenario_t;

static void scenario_of(const bgm_config_t *cfg, int s, scenario_t *out)
{
    bgm_config_scenario(cfg, s, &out->nodes, &out->density, &out->dyn);
    out->topology =
        cfg->topology_levels > 0 ? bgm_topology_names[bgm_config_scenario_topology(cfg, s)] : NULL;
    bgm_config_scenario_label(out->name, sizeof out->name, out->topology, out->nodes, out->density,
                              out->dyn->name);
}

static void fmt_value(char *buf, size_t n, double v)
{
    if (isfinite(v))
        snprintf(buf, n, "%.9g", v);
    else
        buf[0] = '\0';
}

static cJSON *num_or_null(double v)
{
    /* Round through a fixed format so the JSON is stable across libm. */
    if (!isfinite(v))
        return cJSON_CreateNull();
    char b[64];
    snprintf(b, sizeof b, "%.9g", v);
    return cJSON_CreateNumber(strtod(b, NULL));
}

static bg_status write_summary(const bgm_config_t *cfg, const sim_opts_t *o, const double *met)
{
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count, nr = cfg->replications;
    bg_status st = BG_OK;
    char path[BGM_PATH_MAX + 64];
    char *text = NULL;
    cJSON *root = cJSON_CreateObject();
    if (!root)
        return BG_ERR_NOMEM;
    cJSON_AddStringToObject(root, "experiment", cfg->name);
    {
        char seed[32];
        snprintf(seed, sizeof seed, "%llu", (unsigned long long)cfg->seed);
        cJSON_AddItemToObject(root, "seed", cJSON_CreateNumber((double)cfg->seed));
        cJSON_AddStringToObject(root, "seed_string", seed);
    }
    cJSON_AddNumberToObject(root, "replications", nr);
    cJSON_AddStringToObject(root, "engine", o->inprocess ? "inprocess" : "simgrid");
    cJSON_AddStringToObject(root, "resource_market",
                            bgm_resource_market_names[cfg->central.resource_market]);
    cJSON_AddStringToObject(root, "confidence", "95% Student-t over replications");
    cJSON *arr = cJSON_AddArrayToObject(root, "results");
    for (int s = 0; s < ns; s++) {
        scenario_t sc;
        scenario_of(cfg, s, &sc);
        const int nodes = sc.nodes;
        const double density = sc.density;
        const bgm_dynamics_t *dyn = sc.dyn;
        const char *name = sc.name;
        for (int m = 0; m < nm; m++) {
            cJSON *e = cJSON_CreateObject();
            cJSON_AddItemToArray(arr, e);
            cJSON_AddStringToObject(e, "scenario", name);
            if (sc.topology)
                cJSON_AddStringToObject(e, "topology", sc.topology);
            cJSON_AddNumberToObject(e, "nodes", nodes);
            cJSON_AddItemToObject(e, "density", num_or_null(density));
            cJSON_AddStringToObject(e, "dynamics", dyn->name);
            cJSON_AddNumberToObject(e, "agents", bgm_config_agent_count(cfg, nodes, density) + 1);
            cJSON_AddStringToObject(e, "mechanism", bgm_mechanism_names[cfg->mechanisms[m]]);
            const double *base = met + ((size_t)(s * nm + m) * (size_t)nr) * BGM_M_COUNT;
            double ex = 0, gr = 0;
            for (int r = 0; r < nr; r++) {
                ex += base[(size_t)r * BGM_M_COUNT + BGM_M_COMBEX_EXACT];
                gr += base[(size_t)r * BGM_M_COUNT + BGM_M_COMBEX_GREEDY];
            }
            const char *wd = cfg->mechanisms[m] != BGM_MECH_CENTRAL || ex + gr == 0 ? "none"
                             : gr == 0                                              ? "exact"
                             : ex == 0                                              ? "greedy"
                                       : "exact+greedy";
            cJSON_AddStringToObject(e, "winner_determination", wd);
            cJSON *mets = cJSON_AddObjectToObject(e, "metrics");
            for (int k = 0; k < BGM_M_COUNT; k++) {
                bgm_summary_t sm = bgm_summarize(base + k, (size_t)nr, BGM_M_COUNT);
                cJSON *x = cJSON_CreateObject();
                cJSON_AddItemToObject(x, "mean", num_or_null(sm.mean));
                if (sm.n >= 2) {
                    cJSON *ci = cJSON_CreateArray();
                    cJSON_AddItemToArray(ci, num_or_null(sm.lo));
                    cJSON_AddItemToArray(ci, num_or_null(sm.hi));
                    cJSON_AddItemToObject(x, "ci95", ci);
                } else {
                    /* [mean, mean] would claim a certainty one value
                     * cannot give. */
                    cJSON_AddNullToObject(x, "ci95");
                    cJSON_AddStringToObject(x, "ci95_null",
                                            sm.n == 1 ? "one value: an interval needs at least "
                                                        "two replications"
                                                      : "no replication has a value");
                }
                cJSON_AddNumberToObject(x, "n", (double)sm.n);
                cJSON_AddItemToObject(mets, bgm_metric_names[k], x);
            }
        }
    }
    text = cJSON_Print(root);
    if (!text) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    snprintf(path, sizeof path, "%s/summary.json", o->out);
    FILE *f = fopen(path, "w");
    if (!f || fputs(text, f) < 0 || fputc('\n', f) == EOF) {
        st = BG_ERR_IO;
        if (f)
            fclose(f);
        goto out;
    }
    if (fclose(f) != 0)
        st = BG_ERR_IO;
out:
    free(text);
    cJSON_Delete(root);
    return st;
}

static bg_status write_replications(const bgm_config_t *cfg, const sim_opts_t *o,
                                    const double *met)
{
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count, nr = cfg->replications;
    char path[BGM_PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/replications.csv", o->out);
    FILE *f = fopen(path, "w");
    if (!f)
        return BG_ERR_IO;
    fputs(cfg->topology_levels > 0
              ? "scenario,topology,nodes,density,dynamics,agents,mechanism,replication,seed"
              : "scenario,nodes,density,dynamics,agents,mechanism,replication,seed",
          f);
    for (int k = 0; k < BGM_M_COUNT; k++)
        fprintf(f, ",%s", bgm_metric_names[k]);
    fputc('\n', f);
    for (int s = 0; s < ns; s++) {
        scenario_t sc;
        scenario_of(cfg, s, &sc);
        const int nodes = sc.nodes;
        const double density = sc.density;
        const bgm_dynamics_t *dyn = sc.dyn;
        const char *name = sc.name;
        for (int m = 0; m < nm; m++)
            for (int r = 0; r < nr; r++) {
                fputs(name, f);
                if (sc.topology)
                    fprintf(f, ",%s", sc.topology);
                fprintf(f, ",%d,%g,%s,%d,%s,%d,%llu", nodes, density, dyn->name,
                        bgm_config_agent_count(cfg, nodes, density) + 1,
                        bgm_mechanism_names[cfg->mechanisms[m]], r, (unsigned long long)cfg->seed);
                const double *v = met + (((size_t)(s * nm + m) * (size_t)nr) + (size_t)r) * BGM_M_COUNT;
                for (int k = 0; k < BGM_M_COUNT; k++) {
                    char b[64];
                    fmt_value(b, sizeof b, v[k]);
                    fprintf(f, ",%s", b);
                }
                fputc('\n', f);
            }
    }
    return fclose(f) == 0 ? BG_OK : BG_ERR_IO;
}

/* Scenario s's level of a factor: its node count's index, or its
 * dynamics' index. */
static int factor_level(const bgm_config_t *cfg, int s, int by_churn)
{
    return by_churn ? s % cfg->dynamics_levels
                    : s / (cfg->dynamics_levels * cfg->density_levels) % cfg->node_levels;
}

/*
 * A metric against one factor of the experiment (nodes, or churn as the
 * dynamics' node failure rate), one line per mechanism. A point is the
 * mean over replications of the mean over the scenarios at that level;
 * its band is the 95 % Student-t interval of that mean over the
 * replications, the scenarios of a replication taken together (with one
 * scenario per level it is summary.json's ci95 of that scenario). One
 * replication: no band (the interval is null).
 */
static bg_status plot_factor(const bgm_config_t *cfg, const sim_opts_t *o, const double *met,
                             int metric, int by_churn, const char *file, const char *title,
                             const char *ylabel, bg_error_t *err)
{
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count, nr = cfg->replications;
    int nlev = by_churn ? cfg->dynamics_levels : cfg->node_levels;
    double x[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS], y[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS];
    double lo[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS], hi[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS];
    bgm_plot_series_t series[BGM_MAX_MECHANISMS];
    double *per_rep = malloc((size_t)nr * sizeof *per_rep);
    if (!per_rep)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the plots");
    for (int m = 0; m < nm; m++) {
        for (int l = 0; l < nlev; l++) {
            x[m][l] = by_churn ? cfg->dynamics[cfg->dynamics_index[l]].node_failure_rate
                               : (double)cfg->nodes[l];
            for (int r = 0; r < nr; r++) {
                double sum = 0.0;
                int cnt = 0;
                for (int s = 0; s < ns; s++) {
                    if (factor_level(cfg, s, by_churn) != l)
                        continue;
                    double v = met[(((size_t)(s * nm + m) * (size_t)nr) + (size_t)r) * BGM_M_COUNT +
                                   (size_t)metric];
                    if (isfinite(v)) {
                        sum += v;
                        cnt++;
                    }
                }
                per_rep[r] = cnt ? sum / cnt : NAN;
            }
            bgm_summary_t sm = bgm_summarize(per_rep, (size_t)nr, 1);
            y[m][l] = sm.mean;
            lo[m][l] = sm.lo;
            hi[m][l] = sm.hi;
        }
        series[m] = (bgm_plot_series_t){bgm_mechanism_names[cfg->mechanisms[m]], x[m], y[m],
                                        lo[m], hi[m], (size_t)nlev};
    }
    free(per_rep);
    bgm_plot_t plot = {title, by_churn ? "node failure rate (1/s per node)" : "nodes", ylabel,
                       nr > 1 ? "points: means over replications; bands: 95 % confidence intervals"
                              : "one replication: no confidence interval"};
    char path[BGM_PATH_MAX + 256];
    snprintf(path, sizeof path, "%s/%s", o->out, file);
    return bgm_plot_write(path, &plot, series, nm, err);
}

static bg_status write_plots(const bgm_config_t *cfg, const sim_opts_t *o, const double *met,
                             bg_error_t *err)
{
    static const struct {
        int metric;
        const char *name, *title, *ylabel;
    } plots[] = {
        {BGM_M_ALLOCATION_RATE, "allocation_rate", "Allocation rate", "allocated / requested"},
        {BGM_M_MESSAGES_PER_ALLOCATION, "messages_per_allocation", "Messages per allocation",
         "messages"},
        {BGM_M_ACCESS_TIME_MEDIAN, "access_time", "Median service access time",
         "request to contract (s)"},
    };
    bg_status st = BG_OK;
    for (size_t i = 0; i < sizeof plots / sizeof plots[0] && !st; i++)
        for (int churn = 0; churn < 2 && !st; churn++) {
            char file[128], title[160];
            snprintf(file, sizeof file, "%s_vs_%s.svg", plots[i].name, churn ? "churn" : "size");
            snprintf(title, sizeof title, "%s against %s", plots[i].title,
                     churn ? "churn" : "network size");
            st = plot_factor(cfg, o, met, plots[i].metric, churn, file, title, plots[i].ylabel,
                             err);
        }
    return st;
}

static bg_status plot_prices(const bgm_config_t *cfg, const sim_opts_t *o, const run_id_t *runs,
                             int nruns, bg_error_t *err)
{
    bg_status st = BG_OK;
    int nm = cfg->mechanism_count;
    size_t cap = (size_t)ceil((cfg->duration + cfg->drain) / cfg->metrics.price_bucket) + 2;
    double *xs = calloc(cap * (size_t)nm * BGM_SERVICE_TYPES, sizeof *xs);
    double *ys = calloc(cap * (size_t)nm * BGM_SERVICE_TYPES, sizeof *ys);
    size_t cnt[BGM_MAX_MECHANISMS][BGM_SERVICE_TYPES];
    memset(cnt, 0, sizeof cnt);
    if (!xs || !ys) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the price plots");
        goto out;
    }
    /* Scenario 0, replication 0 of each mechanism: one trajectory. */
    for (int i = 0; i < nruns; i++) {
        const run_id_t *r = &runs[i];
        if (r->scenario != 0 || r->replication != 0)
            continue;
        char path[BGM_PATH_MAX + 64];
        part_path(path, sizeof path, o->out, r, "prices");
        FILE *f = fopen(path, "r");
        if (!f)
            continue;
        int g;
        double t, p;
        while (fscanf(f, "%d,%lf,%lf", &g, &t, &p) == 3) {
            if (g < 0 || g >= BGM_SERVICE_TYPES)
                continue;
            size_t *c = &cnt[r->mechanism][g];
            if (*c >= cap)
                continue;
            size_t base = ((size_t)r->mechanism * BGM_SERVICE_TYPES + (size_t)g) * cap;
            xs[base + *c] = t;
            ys[base + *c] = p;
            (*c)++;
        }
        fclose(f);
    }
    for (int g = 0; g < BGM_SERVICE_TYPES && !st; g++) {
        bgm_plot_series_t series[BGM_MAX_MECHANISMS];
        for (int m = 0; m < nm; m++) {
            size_t base = ((size_t)m * BGM_SERVICE_TYPES + (size_t)g) * cap;
            series[m] = (bgm_plot_series_t){bgm_mechanism_names[cfg->mechanisms[m]], xs + base,
                                            ys + base, NULL, NULL, cnt[m][g]};
        }
        char title[128], path[BGM_PATH_MAX + 256];
        snprintf(title, sizeof title, "Price of %s over time (first scenario, replication 0)",
                 bgm_service_names[g]);
        snprintf(path, sizeof path, "%s/price_%s.svg", o->out, bgm_service_names[g]);
        bgm_plot_t plot = {title, "simulated time (s)", "mean price per unit of work",
                           "one point per price bucket (metrics.price_bucket)"};
        st = bgm_plot_write(path, &plot, series, nm, err);
    }
out:
    free(xs);
    free(ys);
    return st;
}

static void remove_parts(const sim_opts_t *o, const run_id_t *runs, int n)
{
    static const char *const exts[] = {"met", "contracts", "agents", "prices", "stats", "err"};
    char path[BGM_PATH_MAX + 64];
    for (int i = 0; i < n; i++)
        for (size_t e = 0; e < sizeof exts / sizeof exts[0]; e++) {
            part_path(path, sizeof path, o->out, &runs[i], exts[e]);
            remove(path);
        }
    snprintf(path, sizeof path, "%s/.parts", o->out);
    rmdir(path);
}

bg_status bgm_sim_check_platform(const bgm_config_t *cfg, bg_error_t *err)
{
    const char *plat = cfg->network.platform;
    if (!plat[0])
        return BG_OK;
    fflush(NULL);
    pid_t pid = fork();
    if (pid < 0)
        return bg_error_set(err, BG_ERR_NOMEM, "cannot check the platform: %s", strerror(errno));
    if (pid == 0) {
        /* SimGrid reports a bad file with a backtrace and aborts: keep it
         * off the console, the parent says what is wrong. */
        if (!freopen("/dev/null", "w", stdout) || !freopen("/dev/null", "w", stderr))
            _exit(3);
        bgm_simdriver_init();
        bgm_simdriver_load(plat);
        double speed[2];
        bg_error_t e = BG_ERROR_INIT;
        _exit(bgm_simdriver_user_speeds(1, speed, &e) == BG_OK && speed[0] > 0.0 ? 0 : 4);
    }
    int status = 0;
    if (waitpid(pid, &status, 0) != pid)
        return bg_error_set(err, BG_ERR_NOMEM, "cannot check the platform: %s", strerror(errno));
    if (WIFEXITED(status) && WEXITSTATUS(status) == 0)
        return BG_OK;
    if (WIFEXITED(status) && WEXITSTATUS(status) == 4)
        return bg_error_set(err, BG_ERR_INVALID, "%s: the platform has no host with a speed", plat);
    return bg_error_set(err, BG_ERR_INVALID,
                        "%s: SimGrid cannot load this platform (not a valid platform XML file)",
                        plat);
}

bg_status bgm_sim_run(const bgm_config_t *cfg, bgm_sim_options_t *o,
                      const bgm_sim_observer_t *obs, bg_error_t *err)
{
    run_id_t *runs = NULL;
    double *met = NULL;
    bg_status st = BG_OK;
    if (o->jobs < 1 || o->jobs > BGM_SIM_MAX_JOBS)
        return bg_error_set(err, BG_ERR_INVALID, "jobs must be in [1, %d], got %d",
                            BGM_SIM_MAX_JOBS, o->jobs);
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count, nr = cfg->replications;
    long total = (long)ns * nm * nr;
    if (total > BGM_MAX_RUNS)
        return bg_error_set(err, BG_ERR_LIMIT, "%ld runs exceed the cap of %d", total,
                            BGM_MAX_RUNS);
    if ((st = bgm_sim_check_platform(cfg, err)))
        return st;
    if (!o->out[0])
        snprintf(o->out, sizeof o->out, "out/sim/%s", cfg->name);
    char parts[BGM_PATH_MAX + 256];
    snprintf(parts, sizeof parts, "%s/.parts", o->out);
    if (bg_file_make_directories(parts))
        return bg_error_set(err, BG_ERR_IO, "%s: cannot create the output folder: %s", o->out,
                            strerror(errno));
    runs = malloc((size_t)total * sizeof *runs);
    met = malloc((size_t)total * BGM_M_COUNT * sizeof *met);
    if (!runs || !met) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %ld runs", total);
        goto out;
    }
    int n = 0;
    for (int s = 0; s < ns; s++)
        for (int m = 0; m < nm; m++)
            for (int r = 0; r < nr; r++)
                runs[n++] = (run_id_t){s, m, r};
    if (obs && obs->start)
        obs->start(obs->ctx, ns, nm, nr);
    if ((st = run_all(cfg, o, runs, n, obs, err)))
        goto out;
    for (int i = 0; i < n; i++) {
        char path[BGM_PATH_MAX + 64];
        part_path(path, sizeof path, o->out, &runs[i], "met");
        FILE *f = fopen(path, "rb");
        size_t got = f ? fread(met + (size_t)i * BGM_M_COUNT, sizeof(double), BGM_M_COUNT, f) : 0;
        if (f)
            fclose(f);
        if (got != BGM_M_COUNT) {
            st = bg_error_set(err, BG_ERR_IO, "%s: missing run output", path);
            goto out;
        }
    }
    if (write_summary(cfg, o, met) || write_replications(cfg, o, met) ||
        merge_csv(o, runs, n, "contracts.csv", "contracts",
                  "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,"
                  "quantity,price,buyer_limit,seller_limit\n") ||
        merge_csv(o, runs, n, "agents.csv", "agents",
                  "scenario,replication,mechanism,agent,role,good,capacity,limit\n")) {
        st = bg_error_set(err, BG_ERR_IO, "%s: cannot write the outputs", o->out);
        goto out;
    }
    if ((st = write_plots(cfg, o, met, err)) || (st = plot_prices(cfg, o, runs, n, err)))
        goto out;
    remove_parts(o, runs, n);
out:
    free(runs);
    free(met);
    return st;
}
