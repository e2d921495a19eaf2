#include "bgm_sim.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bg_error.h"
#include "bg_svg.h"
#include "bgm_config.h"
#include "bgm_evq.h"
#include "bgm_platform.h"
#include "bgm_rng.h"
#include "bgm_simdriver.h"
#include "bgm_stats.h"
#include "bgm_world.h"

#define BGM_EXIT_OK 0
#define BGM_EXIT_FAIL 1
#define BGM_EXIT_USAGE 2
#define BGM_MAX_JOBS 256
#define BGM_MAX_RUNS 100000
/* Blocks at least this large are mapped on their own (see run_child). */
#define BGM_MMAP_THRESHOLD (128 * 1024)
#define BGM_PLATFORM_STREAM 0xfffffff1ULL
#define BGM_COPY_CHUNK 65536
#define BGM_BAR_WIDTH 30

typedef struct sim_opts {
    const char *config_path;
    char out[BGM_PATH_MAX];
    int jobs;
    int inprocess;
    int timing;
    int quiet;
} sim_opts_t;

typedef struct run_id {
    int scenario, mechanism, replication;
} run_id_t;

static void part_path(char *buf, size_t n, const char *out, const run_id_t *r, const char *ext)
{
    snprintf(buf, n, "%s/.parts/s%03d_m%d_r%03d.%s", out, r->scenario, r->mechanism,
             r->replication, ext);
}

static int make_dirs(const char *path)
{
    char tmp[2 * BGM_PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s", path);
    for (char *p = tmp + 1; *p; p++) {
        if (*p != '/')
            continue;
        *p = '\0';
        if (mkdir(tmp, 0755) != 0 && errno != EEXIST)
            return -1;
        *p = '/';
    }
    if (mkdir(tmp, 0755) != 0 && errno != EEXIST)
        return -1;
    return 0;
}

static const char SIM_USAGE[] =
    "usage: biotgrid sim EXPERIMENT.json [--out DIR] [--jobs N] "
    "[--engine simgrid|inprocess] [--timing] [--quiet]\n";

/* Returns 0 to run, 1 after --help, -1 on a bad argument (message printed). */
static int parse_args(int argc, char **argv, sim_opts_t *o)
{
    memset(o, 0, sizeof *o);
    o->jobs = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--out") == 0 && i + 1 < argc) {
            snprintf(o->out, sizeof o->out, "%s", argv[++i]);
        } else if (strcmp(a, "--jobs") == 0 && i + 1 < argc) {
            char *end = NULL;
            long v = strtol(argv[++i], &end, 10);
            if (!end || *end || v < 1 || v > BGM_MAX_JOBS) {
                fprintf(stderr, "biotgrid sim: --jobs must be an integer in [1, %d]\n",
                        BGM_MAX_JOBS);
                return -1;
            }
            o->jobs = (int)v;
        } else if (strcmp(a, "--engine") == 0 && i + 1 < argc) {
            const char *e = argv[++i];
            if (strcmp(e, "inprocess") == 0)
                o->inprocess = 1;
            else if (strcmp(e, "simgrid") != 0) {
                fprintf(stderr, "biotgrid sim: --engine must be simgrid or inprocess\n");
                return -1;
            }
        } else if (strcmp(a, "--timing") == 0) {
            o->timing = 1;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(SIM_USAGE, stdout);
            return 1;
        } else if (a[0] == '-' || o->config_path) {
            fprintf(stderr, "biotgrid sim: unexpected argument '%s'\n", a);
            return -1;
        } else {
            o->config_path = a;
        }
    }
    if (!o->config_path) {
        fputs(SIM_USAGE, stderr);
        return -1;
    }
    return 0;
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
     * mechanisms of a replication run on the same hosts. */
    bgm_rng_t prng;
    bgm_rng_derive(&prng, cfg->seed, (uint64_t)id->scenario, (uint64_t)id->replication,
                   BGM_PLATFORM_STREAM);
    part_path(xml, sizeof xml, o->out, id, "xml");
    int user = cfg->network.platform[0] != '\0';
    {
        FILE *f = fopen(xml, "w");
        if (!f) {
            st = bg_error_set(&err, BG_ERR_IO, "%s: cannot write platform", xml);
            goto out;
        }
        st = bgm_platform_write(f, cfg, nodes, &prng, speed);
        if (fclose(f) != 0 || st) {
            st = bg_error_set(&err, BG_ERR_IO, "%s: cannot write platform", xml);
            goto out;
        }
    }
    bgm_world_params_t wp = {cfg, id->scenario, cfg->mechanisms[id->mechanism], id->replication,
                             nodes, density, dyn, user ? NULL : speed};
    w = bgm_world_new(&wp, &err);
    if (!w) {
        st = err.status ? err.status : BG_ERR_NOMEM;
        goto out;
    }
    long messages = 0;
    double end_time = 0.0;
    if (o->inprocess) {
        bgm_evq_stats_t es;
        st = bgm_evq_run_world(w, cfg->network.latency * 2.0, cfg->network.bandwidth, &es);
        if (st)
            bg_error_set(&err, st, "simulation failed: %s", bg_strerror(st));
        messages = es.messages;
        end_time = es.end_time;
    } else {
        bgm_sim_stats_t ss = {0, 0, 0.0};
        bgm_simdriver_init();
        st = bgm_simdriver_run(w, user ? cfg->network.platform : xml, user, &ss, &err);
        messages = ss.messages;
        end_time = ss.end_time;
    }
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
    if (st)
        fprintf(stderr, "biotgrid sim: scenario %d mechanism %s replication %d: %s\n",
                id->scenario, bgm_mechanism_names[cfg->mechanisms[id->mechanism]],
                id->replication, err.message);
    bgm_world_destroy(&w);
    free(speed);
    return st ? BGM_EXIT_FAIL : BGM_EXIT_OK;
}

/* ----------------------------------------------------------- parent side */

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void progress(const sim_opts_t *o, int done, int total, double t0)
{
    if (o->quiet || !isatty(fileno(stderr)))
        return;
    double el = now_seconds() - t0;
    double eta = done > 0 ? el * (double)(total - done) / (double)done : 0.0;
    int fill = total > 0 ? BGM_BAR_WIDTH * done / total : BGM_BAR_WIDTH;
    char bar[BGM_BAR_WIDTH + 1];
    for (int i = 0; i < BGM_BAR_WIDTH; i++)
        bar[i] = i < fill ? '#' : '-';
    bar[BGM_BAR_WIDTH] = '\0';
    fprintf(stderr, "\r[%s] %d/%d runs  %.0fs elapsed  ETA %.0fs ", bar, done, total, el, eta);
    if (done == total)
        fputc('\n', stderr);
    fflush(stderr);
}

static int run_all(const bgm_config_t *cfg, const sim_opts_t *o, const run_id_t *runs, int n)
{
    pid_t pids[BGM_MAX_JOBS];
    int slot_run[BGM_MAX_JOBS];
    double slot_t0[BGM_MAX_JOBS];
    int active = 0, next = 0, done = 0, failed = 0;
    double t0 = now_seconds();
    progress(o, 0, n, t0);
    while (done < n) {
        while (active < o->jobs && next < n) {
            fflush(NULL);
            pid_t pid = fork();
            if (pid < 0) {
                perror("biotgrid sim: fork");
                return -1;
            }
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
            return -1;
        for (int i = 0; i < active; i++) {
            if (pids[i] != pid)
                continue;
            const run_id_t *r = &runs[slot_run[i]];
            if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
                failed++;
                fprintf(stderr, "biotgrid sim: run s%d m%d r%d failed\n", r->scenario,
                        r->mechanism, r->replication);
            }
            if (o->timing) {
                char path[BGM_PATH_MAX + 64];
                long msgs = 0, rss = 0;
                unsigned agents = 0;
                double end = 0;
                part_path(path, sizeof path, o->out, r, "stats");
                FILE *f = fopen(path, "r");
                if (f) {
                    if (fscanf(f, "%ld %lf %ld %u", &msgs, &end, &rss, &agents) != 4)
                        msgs = 0;
                    fclose(f);
                }
                double wall = now_seconds() - slot_t0[i];
                fprintf(stderr,
                        "timing: scenario %d %s rep %d: agents %u wall %.2f s, messages %ld "
                        "(%.0f msg/s), peak RSS %ld KiB (%.1f KiB/agent)\n",
                        r->scenario, bgm_mechanism_names[cfg->mechanisms[r->mechanism]],
                        r->replication, agents, wall, msgs, wall > 0 ? msgs / wall : 0.0, rss,
                        agents ? (double)rss / agents : 0.0);
            }
            pids[i] = pids[active - 1];
            slot_run[i] = slot_run[active - 1];
            slot_t0[i] = slot_t0[active - 1];
            active--;
            break;
        }
        done++;
        progress(o, done, n, t0);
    }
    return failed ? -1 : 0;
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

/* A scenario's factors and its name in the outputs ("n40_d2_static"). */
typedef struct scenario {
    int nodes;
    double density;
    const bgm_dynamics_t *dyn;
    char name[BGM_NAME_MAX * 2];
} scenario_t;

static void scenario_of(const bgm_config_t *cfg, int s, scenario_t *out)
{
    bgm_config_scenario(cfg, s, &out->nodes, &out->density, &out->dyn);
    snprintf(out->name, sizeof out->name, "n%d_d%g_%s", out->nodes, out->density,
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

typedef struct plot_data {
    double *mean; /* [scenario][mechanism][metric] replication means */
} plot_data_t;

static bg_status write_summary(const bgm_config_t *cfg, const sim_opts_t *o, const double *met,
                               double *means)
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
                means[((size_t)(s * nm + m)) * BGM_M_COUNT + (size_t)k] = sm.mean;
                cJSON *x = cJSON_CreateObject();
                cJSON_AddItemToObject(x, "mean", num_or_null(sm.mean));
                cJSON *ci = cJSON_CreateArray();
                cJSON_AddItemToArray(ci, num_or_null(sm.lo));
                cJSON_AddItemToArray(ci, num_or_null(sm.hi));
                cJSON_AddItemToObject(x, "ci95", ci);
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
    fputs("scenario,nodes,density,dynamics,agents,mechanism,replication,seed", f);
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
                fprintf(f, "%s,%d,%g,%s,%d,%s,%d,%llu", name, nodes, density, dyn->name,
                        bgm_config_agent_count(cfg, nodes, density) + 1,
                        bgm_mechanism_names[cfg->mechanisms[m]], r,
                        (unsigned long long)cfg->seed);
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

/* Mean of a metric over the scenarios sharing a factor level, per
 * mechanism: the x axis is the level (agents or churn rate). */
static bg_status plot_factor(const bgm_config_t *cfg, const sim_opts_t *o, const double *means,
                             int metric, int by_churn, const char *file, const char *title,
                             const char *ylabel, bg_error_t *err)
{
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count;
    int nlev = by_churn ? cfg->dynamics_levels : cfg->node_levels;
    double x[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS], y[BGM_MAX_MECHANISMS][BGM_MAX_LEVELS];
    bg_svg_series_t series[BGM_MAX_MECHANISMS];
    for (int m = 0; m < nm; m++) {
        for (int l = 0; l < nlev; l++) {
            double sx = 0, sy = 0;
            int cnt = 0, cy = 0;
            for (int s = 0; s < ns; s++) {
                int nodes;
                double density;
                const bgm_dynamics_t *dyn;
                bgm_config_scenario(cfg, s, &nodes, &density, &dyn);
                int level = by_churn ? s % cfg->dynamics_levels
                                     : s / (cfg->dynamics_levels * cfg->density_levels);
                if (level != l)
                    continue;
                sx += by_churn ? dyn->node_failure_rate
                               : (double)(bgm_config_agent_count(cfg, nodes, density) + 1);
                cnt++;
                double v = means[((size_t)(s * nm + m)) * BGM_M_COUNT + (size_t)metric];
                if (isfinite(v)) {
                    sy += v;
                    cy++;
                }
            }
            x[m][l] = cnt ? sx / cnt : NAN;
            y[m][l] = cy ? sy / cy : NAN;
        }
        series[m] = (bg_svg_series_t){bgm_mechanism_names[cfg->mechanisms[m]], x[m], y[m],
                                      (size_t)nlev};
    }
    bg_svg_plot_t plot = {title, by_churn ? "node failure rate (1/s per node)" : "agents",
                          ylabel, 0, 0};
    char path[BGM_PATH_MAX + 256];
    snprintf(path, sizeof path, "%s/%s", o->out, file);
    return bg_svg_write(path, &plot, series, nm, err);
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
        st = BG_ERR_NOMEM;
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
        bg_svg_series_t series[BGM_MAX_MECHANISMS];
        for (int m = 0; m < nm; m++) {
            size_t base = ((size_t)m * BGM_SERVICE_TYPES + (size_t)g) * cap;
            series[m] = (bg_svg_series_t){bgm_mechanism_names[cfg->mechanisms[m]], xs + base,
                                          ys + base, cnt[m][g]};
        }
        char title[128], path[BGM_PATH_MAX + 256];
        snprintf(title, sizeof title, "Price of %s over time (first scenario, replication 0)",
                 bgm_service_names[g]);
        snprintf(path, sizeof path, "%s/price_%s.svg", o->out, bgm_service_names[g]);
        bg_svg_plot_t plot = {title, "simulated time (s)", "mean price per unit of work", 0, 0};
        st = bg_svg_write(path, &plot, series, nm, err);
    }
out:
    free(xs);
    free(ys);
    return st;
}

static void remove_parts(const sim_opts_t *o, const run_id_t *runs, int n)
{
    static const char *const exts[] = {"met", "contracts", "agents", "prices", "stats"};
    char path[BGM_PATH_MAX + 64];
    for (int i = 0; i < n; i++)
        for (size_t e = 0; e < sizeof exts / sizeof exts[0]; e++) {
            part_path(path, sizeof path, o->out, &runs[i], exts[e]);
            remove(path);
        }
    snprintf(path, sizeof path, "%s/.parts", o->out);
    rmdir(path);
}

int bgm_sim_command(int argc, char **argv)
{
    sim_opts_t o;
    bgm_config_t *cfg = NULL;
    run_id_t *runs = NULL;
    double *met = NULL, *means = NULL;
    int rc = BGM_EXIT_FAIL;
    bg_error_t err = BG_ERROR_INIT;
    const int parsed = parse_args(argc, argv, &o);
    if (parsed != 0)
        return parsed > 0 ? 0 : BGM_EXIT_USAGE;
    cfg = malloc(sizeof *cfg);
    if (!cfg)
        goto out;
    if (bgm_config_load(o.config_path, cfg, &err)) {
        fprintf(stderr, "biotgrid sim: %s: %s\n", o.config_path, err.message);
        rc = err.status == BG_ERR_IO ? BGM_EXIT_FAIL : BGM_EXIT_USAGE;
        goto out;
    }
    if (!o.out[0])
        snprintf(o.out, sizeof o.out, "out/sim/%s", cfg->name);
    char parts[BGM_PATH_MAX + 256];
    snprintf(parts, sizeof parts, "%s/.parts", o.out);
    if (make_dirs(parts)) {
        fprintf(stderr, "biotgrid sim: %s: cannot create output directory\n", o.out);
        goto out;
    }
    int ns = bgm_config_scenario_count(cfg), nm = cfg->mechanism_count, nr = cfg->replications;
    long total = (long)ns * nm * nr;
    if (total > BGM_MAX_RUNS) {
        fprintf(stderr, "biotgrid sim: %ld runs exceed the cap of %d\n", total, BGM_MAX_RUNS);
        rc = BGM_EXIT_USAGE;
        goto out;
    }
    runs = malloc((size_t)total * sizeof *runs);
    met = malloc((size_t)total * BGM_M_COUNT * sizeof *met);
    means = malloc((size_t)ns * (size_t)nm * BGM_M_COUNT * sizeof *means);
    if (!runs || !met || !means)
        goto out;
    int n = 0;
    for (int s = 0; s < ns; s++)
        for (int m = 0; m < nm; m++)
            for (int r = 0; r < nr; r++)
                runs[n++] = (run_id_t){s, m, r};
    if (!o.quiet)
        fprintf(stderr, "biotgrid sim: %s, seed %llu: %d scenarios x %d mechanisms x %d replications\n",
                cfg->name, (unsigned long long)cfg->seed, ns, nm, nr);
    if (run_all(cfg, &o, runs, n))
        goto out;
    for (int i = 0; i < n; i++) {
        char path[BGM_PATH_MAX + 64];
        part_path(path, sizeof path, o.out, &runs[i], "met");
        FILE *f = fopen(path, "rb");
        size_t got = f ? fread(met + (size_t)i * BGM_M_COUNT, sizeof(double), BGM_M_COUNT, f) : 0;
        if (f)
            fclose(f);
        if (got != BGM_M_COUNT) {
            fprintf(stderr, "biotgrid sim: %s: missing run output\n", path);
            goto out;
        }
    }
    if (write_summary(cfg, &o, met, means) || write_replications(cfg, &o, met) ||
        merge_csv(&o, runs, n, "contracts.csv", "contracts",
                  "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,"
                  "quantity,price,buyer_limit,seller_limit\n") ||
        merge_csv(&o, runs, n, "agents.csv", "agents",
                  "scenario,replication,mechanism,agent,role,good,capacity,limit\n")) {
        fprintf(stderr, "biotgrid sim: %s: cannot write outputs\n", o.out);
        goto out;
    }
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
    for (size_t i = 0; i < sizeof plots / sizeof plots[0]; i++)
        for (int churn = 0; churn < 2; churn++) {
            char file[128], title[160];
            snprintf(file, sizeof file, "%s_vs_%s.svg", plots[i].name, churn ? "churn" : "size");
            snprintf(title, sizeof title, "%s against %s", plots[i].title,
                     churn ? "churn" : "network size");
            if (plot_factor(cfg, &o, means, plots[i].metric, churn, file, title, plots[i].ylabel,
                            &err))
                fprintf(stderr, "biotgrid sim: plot %s: %s\n", file, err.message);
        }
    if (plot_prices(cfg, &o, runs, n, &err))
        fprintf(stderr, "biotgrid sim: price plots: %s\n", err.message);
    remove_parts(&o, runs, n);
    if (!o.quiet)
        fprintf(stderr, "biotgrid sim: wrote %s/{summary.json,replications.csv,contracts.csv,agents.csv,*.svg}\n",
                o.out);
    rc = BGM_EXIT_OK;
out:
    free(cfg);
    free(runs);
    free(met);
    free(means);
    return rc;
}
