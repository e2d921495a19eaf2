/*
 * bench_market_science — the market-science comparison tables, from one
 * command (market/README.md, "Market science").
 *
 *   bench_market_science [--biotgrid PATH] [--config CATNETS] [--out DIR]
 *                        [--jobs N] [--replications R] [--quick]
 *
 * Runs `biotgrid sim` (PATH, default the build's) on experiments derived
 * from catnets.json (seed 4242, the settings of issues 30 and 31) and
 * prints Markdown tables of the summaries: mean and half-width of the 95 %
 * Student-t interval over replications ("n=1" when one replication gives
 * none).
 *   size:     cluster, density 2, static, 40, 130 and 400 nodes, R
 *             replications (default 5);
 *   topology: 130 nodes, density 1, static and churn, on the cluster, the
 *             random graph and the scale-free graph (factors.topology: one
 *             experiment, the same as configs/experiments/topology.json),
 *             R replications.
 * Columns: allocation rate, messages per allocation, the bound the
 * mechanism's parameters put on them (message_bound), timeouts per service
 * request (both layers), access time median and p99. The machine's load
 * (`uptime`) is printed before and after: the runs share the machine.
 * A binary that lacks a metric or a topology prints "-" for it, and one
 * that refuses factors.topology gets one experiment per topology (the
 * same figures: a topology factor's levels equal the topologies run
 * alone), so the same command gives the "before" tables with an older
 * build.
 * --quick runs tiny sizes (a smoke test for CTest).
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bg_file.h"

#ifndef BGM_BIOTGRID
#define BGM_BIOTGRID "biotgrid"
#endif
#ifndef BGM_CATNETS
#define BGM_CATNETS "configs/experiments/catnets.json"
#endif

#define MAX_TEXT (64u << 20)
#define PATH_LEN 4096

typedef struct opts {
    const char *biotgrid, *config, *out;
    int jobs, replications, quick;
} opts_t;

/* The load of the machine, as `uptime` prints it. */
static void print_uptime(const char *when)
{
    char line[256] = "";
    FILE *p = popen("uptime", "r");
    if (p) {
        if (!fgets(line, sizeof line, p))
            line[0] = '\0';
        pclose(p);
    }
    line[strcspn(line, "\n")] = '\0';
    printf("Machine load %s: `%s`\n\n", when, line[0] ? line : "(uptime unavailable)");
}

static cJSON *int_array(const int *v, int n)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; a && i < n; i++)
        cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
    return a;
}

/* Replaces (or adds) obj[key] with item. */
static void set(cJSON *obj, const char *key, cJSON *item)
{
    if (cJSON_GetObjectItemCaseSensitive(obj, key))
        cJSON_ReplaceItemInObjectCaseSensitive(obj, key, item);
    else
        cJSON_AddItemToObject(obj, key, item);
}

/*
 * Writes DIR/NAME.json: catnets.json with its name, seed 4242,
 * replications, the factors (nodes, one density, the dynamics listed) and
 * the topology replaced: network.topology when ntopo is 1, else
 * factors.topology (and no network.topology). Returns 0 on success.
 */
static int write_config(const opts_t *o, const char *name, const char *const *topology, int ntopo,
                        const int *nodes, int nnodes, double density, const char *const *dynamics,
                        int ndyn, int replications, char *path)
{
    char *text = NULL;
    size_t len = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_file_read_all(o->config, MAX_TEXT, &text, &len, &err)) {
        fprintf(stderr, "bench_market_science: %s\n", err.message);
        return -1;
    }
    cJSON *root = cJSON_Parse(text);
    free(text);
    cJSON *net = root ? cJSON_GetObjectItemCaseSensitive(root, "network") : NULL;
    if (!net) {
        fprintf(stderr, "bench_market_science: %s: not a catnets-like config\n", o->config);
        cJSON_Delete(root);
        return -1;
    }
    set(root, "name", cJSON_CreateString(name));
    set(root, "seed", cJSON_CreateNumber(4242));
    set(root, "replications", cJSON_CreateNumber(replications));
    if (o->quick) {
        set(root, "duration", cJSON_CreateNumber(40));
        set(root, "drain", cJSON_CreateNumber(30));
    }
    cJSON *f = cJSON_CreateObject();
    if (ntopo > 1)
        cJSON_AddItemToObject(f, "topology", cJSON_CreateStringArray(topology, ntopo));
    cJSON_AddItemToObject(f, "nodes", int_array(nodes, nnodes));
    cJSON *d = cJSON_CreateArray();
    cJSON_AddItemToArray(d, cJSON_CreateNumber(density));
    cJSON_AddItemToObject(f, "density", d);
    cJSON_AddItemToObject(f, "dynamics", cJSON_CreateStringArray(dynamics, ndyn));
    set(root, "factors", f);
    if (ntopo > 1)
        cJSON_DeleteItemFromObjectCaseSensitive(net, "topology");
    else
        set(net, "topology", cJSON_CreateString(topology[0]));
    char *out = cJSON_Print(root);
    cJSON_Delete(root);
    snprintf(path, PATH_LEN, "%s/%s.json", o->out, name);
    FILE *fp = out ? fopen(path, "w") : NULL;
    int rc = fp && fputs(out, fp) >= 0 ? 0 : -1;
    if (fp && fclose(fp) != 0)
        rc = -1;
    free(out);
    return rc;
}

/* Runs `biotgrid sim CONFIG --out DIR --jobs N --quiet`; its exit status. */
static int run_sim(const opts_t *o, const char *config, const char *dir)
{
    char jobs[16];
    snprintf(jobs, sizeof jobs, "%d", o->jobs);
    fflush(stdout);
    pid_t pid = fork();
    if (pid < 0)
        return -1;
    if (pid == 0) {
        char *argv[] = {
            (char *)o->biotgrid, "sim", (char *)config, "--out", (char *)dir, "--jobs", jobs,
            "--quiet",           NULL};
        execv(o->biotgrid, argv);
        _exit(127);
    }
    int status = 0;
    if (waitpid(pid, &status, 0) < 0)
        return -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

static cJSON *load_summary(const char *dir)
{
    char path[PATH_LEN], *text = NULL;
    size_t len = 0;
    bg_error_t err = BG_ERROR_INIT;
    const int n = snprintf(path, sizeof path, "%s/summary.json", dir);
    if (n < 0 || (size_t)n >= sizeof path)
        return NULL;
    if (bg_file_read_all(path, MAX_TEXT, &text, &len, &err))
        return NULL;
    cJSON *s = cJSON_Parse(text);
    free(text);
    return s;
}

/* A metric's mean, or NAN when the summary does not have it. */
static double mean_of(const cJSON *metrics, const char *name, double *half)
{
    const cJSON *m = cJSON_GetObjectItemCaseSensitive(metrics, name);
    const cJSON *mean = m ? cJSON_GetObjectItemCaseSensitive(m, "mean") : NULL;
    const cJSON *ci = m ? cJSON_GetObjectItemCaseSensitive(m, "ci95") : NULL;
    *half = NAN;
    if (cJSON_IsArray(ci) && cJSON_GetArraySize(ci) == 2)
        *half =
            (cJSON_GetArrayItem(ci, 1)->valuedouble - cJSON_GetArrayItem(ci, 0)->valuedouble) / 2.0;
    return cJSON_IsNumber(mean) ? mean->valuedouble : NAN;
}

/* "mean ± half" with `digits` decimals; "-" when missing. */
static void cell(const cJSON *metrics, const char *name, int digits)
{
    double half;
    const double v = mean_of(metrics, name, &half);
    if (isnan(v))
        printf(" - |");
    else if (isnan(half))
        printf(" %.*f |", digits, v);
    else
        printf(" %.*f ± %.*f |", digits, v, digits, half);
}

/* Timeouts per service request: the summary's figure when it has one,
 * else timeouts over requests (the means). */
static void timeouts_cell(const cJSON *metrics)
{
    double half;
    if (!isnan(mean_of(metrics, "timeouts_per_request", &half))) {
        cell(metrics, "timeouts_per_request", 2);
        return;
    }
    const double t = mean_of(metrics, "timeouts", &half), r = mean_of(metrics, "requests", &half);
    if (isnan(t) || isnan(r) || r <= 0)
        printf(" - |");
    else
        printf(" %.2f |", t / r);
}

/* One table row per result: "| nodes |" (label_key "nodes"), or
 * "| topology | dynamics |" with the topology from label, or from each
 * result's "topology" when label is NULL. */
static void rows(const cJSON *summary, const char *label_key, const char *label)
{
    const cJSON *results = cJSON_GetObjectItemCaseSensitive(summary, "results");
    const cJSON *r;
    cJSON_ArrayForEach(r, results)
    {
        const cJSON *metrics = cJSON_GetObjectItemCaseSensitive(r, "metrics");
        const cJSON *mech = cJSON_GetObjectItemCaseSensitive(r, "mechanism");
        const cJSON *key = cJSON_GetObjectItemCaseSensitive(r, label_key);
        const cJSON *dyn = cJSON_GetObjectItemCaseSensitive(r, "dynamics");
        const cJSON *reps = cJSON_GetObjectItemCaseSensitive(summary, "replications");
        if (label_key && !strcmp(label_key, "nodes"))
            printf("| %d |", cJSON_IsNumber(key) ? key->valueint : 0);
        else
            printf("| %s | %s |",
                   label                 ? label
                   : cJSON_IsString(key) ? key->valuestring
                                         : "?",
                   cJSON_IsString(dyn) ? dyn->valuestring : "?");
        printf(" %s |", cJSON_IsString(mech) ? mech->valuestring : "?");
        cell(metrics, "allocation_rate", 3);
        cell(metrics, "messages_per_allocation", 1);
        cell(metrics, "message_bound", 0);
        timeouts_cell(metrics);
        cell(metrics, "access_time_median", 2);
        cell(metrics, "access_time_p99", 2);
        printf(" %d |\n", cJSON_IsNumber(reps) ? reps->valueint : 0);
    }
}

static const char *const table_head =
    " mechanism | allocation rate | messages per allocation | bound | timeouts per request | "
    "access median (s) | access p99 (s) | n |\n";

static int study_size(const opts_t *o)
{
    static const int full[] = {40, 130, 400}, quick[] = {8, 16};
    static const char *const dyn[] = {"static"};
    char path[PATH_LEN], dir[PATH_LEN];
    static const char *const cluster[] = {"cluster"};
    if (write_config(o, "science-size", cluster, 1, o->quick ? quick : full, o->quick ? 2 : 3, 2.0,
                     dyn, 1, o->replications, path))
        return 1;
    snprintf(dir, sizeof dir, "%s/science-size", o->out);
    printf("### Size: cluster, density 2, static (`%s`)\n\n", path);
    const int rc = run_sim(o, path, dir);
    cJSON *s = rc == 0 ? load_summary(dir) : NULL;
    if (!s) {
        printf("biotgrid sim failed (exit %d)\n\n", rc);
        return 1;
    }
    printf("| nodes |%s|---|---|---|---|---|---|---|---|---|\n", table_head);
    rows(s, "nodes", NULL);
    printf("\n");
    cJSON_Delete(s);
    return 0;
}

/* The topology table from one experiment per topology: for a build that
 * refuses factors.topology (it prints a row of "-" for a topology the
 * build lacks). */
static int study_topology_apart(const opts_t *o, const char *const *topologies, int ntopo,
                                const int *nodes, const char *const *dyn)
{
    int failed = 0;
    for (int t = 0; t < ntopo; t++) {
        char name[64], path[PATH_LEN], dir[PATH_LEN];
        snprintf(name, sizeof name, "science-%s", topologies[t]);
        if (write_config(o, name, &topologies[t], 1, nodes, 1, 1.0, dyn, 2, o->replications, path))
            return 1;
        snprintf(dir, sizeof dir, "%s/%s", o->out, name);
        const int rc = run_sim(o, path, dir);
        cJSON *s = rc == 0 ? load_summary(dir) : NULL;
        if (!s) {
            printf("| %s | - | (biotgrid sim exit %d: not in this build?) | | | | | | | |\n",
                   topologies[t], rc);
            failed = 1;
            continue;
        }
        rows(s, NULL, topologies[t]);
        cJSON_Delete(s);
    }
    return failed;
}

static int study_topology(const opts_t *o)
{
    static const char *const topologies[] = {"cluster", "random", "scale-free"};
    static const char *const dyn[] = {"static", "churn"};
    const int nodes[] = {o->quick ? 16 : 130};
    char path[PATH_LEN], dir[PATH_LEN];
    if (write_config(o, "science-topology", topologies, 3, nodes, 1, 1.0, dyn, 2, o->replications,
                     path))
        return 1;
    snprintf(dir, sizeof dir, "%s/science-topology", o->out);
    printf("### Topology: %d nodes, density 1, static and churn (`%s`)\n\n", nodes[0], path);
    printf("| topology | dynamics |%s|---|---|---|---|---|---|---|---|---|---|\n", table_head);
    const int rc = run_sim(o, path, dir);
    int failed = 0;
    cJSON *s = rc == 0 ? load_summary(dir) : NULL;
    if (rc == 2) {
        /* Exit 2 is a refused config: a build without factors.topology. */
        failed = study_topology_apart(o, topologies, 3, nodes, dyn);
        printf("\n(one experiment per topology: this build refused factors.topology)\n");
    } else if (!s) {
        printf("| - | - | (biotgrid sim exit %d) | | | | | | | |\n", rc);
        failed = 1;
    } else {
        rows(s, "topology", NULL);
    }
    cJSON_Delete(s);
    printf("\n");
    return failed;
}

static int usage(void)
{
    fprintf(stderr, "usage: bench_market_science [--biotgrid PATH] [--config CATNETS] [--out DIR] "
                    "[--jobs N] [--replications R] [--quick]\n");
    return 2;
}

int main(int argc, char **argv)
{
    opts_t o = {BGM_BIOTGRID, BGM_CATNETS, "bench-science", 2, 5, 0};
    for (int i = 1; i < argc; i++) {
        const int more = i + 1 < argc;
        if (!strcmp(argv[i], "--quick"))
            o.quick = 1;
        else if (!strcmp(argv[i], "--biotgrid") && more)
            o.biotgrid = argv[++i];
        else if (!strcmp(argv[i], "--config") && more)
            o.config = argv[++i];
        else if (!strcmp(argv[i], "--out") && more)
            o.out = argv[++i];
        else if (!strcmp(argv[i], "--jobs") && more)
            o.jobs = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--replications") && more)
            o.replications = atoi(argv[++i]);
        else
            return usage();
    }
    if (o.jobs < 1 || o.replications < 1)
        return usage();
    if (o.quick)
        o.replications = 2;
    if (bg_file_make_directories(o.out)) {
        perror(o.out);
        return 1;
    }
    printf("## Market science tables (`biotgrid sim`: %s; seed 4242)\n\n", o.biotgrid);
    print_uptime("before");
    int rc = study_size(&o);
    rc |= study_topology(&o);
    print_uptime("after");
    /* A quick run is the suite's smoke test: every table must have come. */
    return o.quick ? rc : 0;
}
