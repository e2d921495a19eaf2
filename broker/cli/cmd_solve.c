#include "cmd_solve.h"

#include "cmd.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bg_dynamics.h"
#include "bg_mesh_io.h"
#include "bg_morph.h"
#include "bg_param.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "bga_backend.h"
#include "bg_file.h"
#include "bg_run.h"
#include "bga_client.h"
#include "bga_service.h"
#include "cmd_job.h"
#include "cmd_runs.h"
#include "cmd_solve_broker.h"

#define CLI_MAX_METHODS 4
/* Room for the ':'-separated mesh folders. */
#define CLI_MESH_PATH_MAX 8192
/* Jobs across agents: at most this many endpoints, each request answered
 * within the timeout (default; --agent-timeout), the job's state on the
 * agents leased for this long (renewed by every request). */
#define CLI_MAX_AGENTS 32
#define CLI_ENDPOINT_MAX 256
#define CLI_AGENT_TIMEOUT_MS 10000
#define CLI_AGENT_LEASE_MS 600000
#define CLI_GRID_STATE_MAX (1 << 20)
#define CLI_BROKER_URL_MAX 1024

typedef struct cli_options {
    const char *scene_path;
    const char *out_dir;
    bg_method methods[CLI_MAX_METHODS];
    int method_count;
    const char *inner;         /* --inner: a dynamic scene's solver.inner, or NULL */
    double tolerance;      /* < 0: the scene's */
    int max_iterations;    /* < 0: the scene's */
    int quiet;
    char mesh_path[CLI_MESH_PATH_MAX];
    const char *agents;    /* --agents list, or NULL */
    int grid;              /* --grid: the running local grid's broker, else its agents */
    const char *grid_dir;  /* --grid-state, or NULL (bg_cmd_grid_dir) */
    int agent_timeout_ms;
    const char *mechanism; /* --mechanism, or NULL: central (a grid with a broker) */
    double budget;         /* --budget, or 0: the broker's */
} cli_options_t;

/* One agent named on the command line or in the grid's state file. */
typedef struct cli_agent {
    char endpoint[CLI_ENDPOINT_MAX];
    unsigned services;     /* BGA_SERVICE_* bits; 0 until known */
    int contacted;         /* a heartbeat or a service call went to it */
    int role;              /* rotation-fit index, CLI_ROLE_SOLVE, _INTEG or _NONE */
} cli_agent;
#define CLI_ROLE_NONE (-1)
#define CLI_ROLE_SOLVE (-2)
#define CLI_ROLE_INTEG (-3)

typedef struct progress {
    int tty;
    int quiet;
} progress_t;

const char bg_cmd_solve_usage[] =
    "usage: biotgrid solve SCENE.json [options]\n"
    "\n"
    "Solves an elastic deformation scene in this process and reports error against run time.\n"
    "\n"
    "  --method M                 one solver; static, morph and parameterize scenes: newton,\n"
    "                             local-global or quasi-newton; dynamic scenes: variational or\n"
    "                             backward-euler;\n"
    "                             surface-edit scenes: local-global (default: the scene's)\n"
    "  --compare M1,M2            run several methods on the same scene, one curve each\n"
    "  --inner M                  dynamic scenes: what minimises each time step's energy,\n"
    "                             newton or quasi-newton (default: the scene's solver.inner,\n"
    "                             else newton)\n"
    "  --tolerance T              stop at relative gradient T, for every method (default: the\n"
    "                             scene's solver.tolerance, else 1e-8)\n"
    "  --max-iterations N         iteration cap for every method (default: the scene's\n"
    "                             solver.max_iterations, which may give one cap per method)\n"
    "  --mesh-path DIR            a folder to look in for a mesh or data file the scene names\n"
    "                             but that is not beside it (repeatable; then the folders of\n"
    "                             $BIOTGRID_MESH_PATH, ':'-separated)\n"
    "  --out DIR                  output directory (default out/<scene name>)\n"
    "  --quiet                    no per-iteration progress\n"
    "  --agents EP1,EP2,...       compute the basic services on these agents (ZeroMQ\n"
    "                             endpoints, each optionally prefixed SERVICES= as in\n"
    "                             rotfit=tcp://127.0.0.1:5555; an endpoint without a prefix\n"
    "                             is asked for its services with a heartbeat)\n"
    "  --grid                     on the running local grid: through its broker when it\n"
    "                             has one (the services bought on its market), else on\n"
    "                             its agents as with --agents\n"
    "  --grid-state DIR           its state directory (default $BIOTGRID_GRID_DIR or out/grid)\n"
    "  --mechanism M              a grid with a broker: central (default), catallactic or\n"
    "                             posted\n"
    "  --budget B                 a grid with a broker: the money each method's job may\n"
    "                             spend (default: the broker's, 1000)\n"
    "  --agent-timeout MS         per request to an agent (default 10000)\n"
    "\n"
    "With agents, rotation-fit is split in balanced element ranges over every rotation-fit\n"
    "agent and every matrix is factored and solved on one sparse-solve agent (the first\n"
    "that serves only sparse-solve, else the first that serves it). The time loop of a\n"
    "dynamic scene and surface-edit's solver run in this process. An agent that fails or\n"
    "stops answering ends the solve with exit 1, naming the agent and the service.\n"
    "\n"
    "On a grid with a broker each method is a job submitted as `biotgrid submit` does\n"
    "(the scene and its files, the method, tolerance and iteration cap in its solver\n"
    "settings), one after another, followed as `submit --wait` follows it; its result\n"
    "files go to DIR (several methods: DIR/<method>/, the combined plot in DIR), and the\n"
    "tables below come from the jobs' reports, with the money each job spent.\n"
    "\n"
    "Every compared method gets the same stopping rule: the same tolerance, and its own\n"
    "iteration cap (the scene's per-method cap, else the common one). The table after the\n"
    "runs says which method reached each accuracy first, and when.\n"
    "\n"
    "Writes DIR/report.json, DIR/error-vs-time.svg, DIR/result.vtu and DIR/result.<mesh\n"
    "format>; dynamic and morph scenes also DIR/<method>.pvd with DIR/frames/, parameterize\n"
    "scenes DIR/<method>-uv.obj.\n"
    "\n"
    "Exit status: 0 every method met its tolerance, 1 one did not (stopped at its iteration\n"
    "cap or a round-off floor; the report is still written), 2 bad input.\n";

const char bg_cmd_validate_usage[] =
    "usage: biotgrid validate SCENE.json [--mesh-path DIR] [--max-vertices N]\n"
    "                         [--max-elements N]\n"
    "\n"
    "Parses and validates a scene as `biotgrid solve` does (mesh, material, handles, task,\n"
    "solver, reference) without solving anything, and prints a summary.\n"
    "\n"
    "  --mesh-path DIR            as for solve (repeatable; then $BIOTGRID_MESH_PATH)\n"
    "  --max-vertices N           refuse a mesh with more vertices (a generated one before\n"
    "  --max-elements N           it is built), as a broker does with its job caps\n"
    "\n"
    "Exit status: 0 valid, 2 invalid with the message solve would give.\n";

static int parse_methods(const char *option, const char *list, cli_options_t *o)
{
    char buf[256];
    if (strlen(list) >= sizeof buf) {
        fprintf(stderr, "biotgrid solve: %s: list too long\n", option);
        return -1;
    }
    strcpy(buf, list);
    o->method_count = 0;
    for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        bg_error_t err = BG_ERROR_INIT;
        if (o->method_count == CLI_MAX_METHODS) {
            fprintf(stderr, "biotgrid solve: at most %d methods in %s\n", CLI_MAX_METHODS,
                    option);
            return -1;
        }
        if (bg_method_parse(tok, &o->methods[o->method_count], &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: %s: %s\n", option, err.message);
            return -1;
        }
        for (int i = 0; i < o->method_count; i++)
            if (o->methods[i] == o->methods[o->method_count]) {
                fprintf(stderr, "biotgrid solve: %s: %s is listed twice\n", option, tok);
                return -1;
            }
        o->method_count++;
    }
    if (o->method_count == 0) {
        fprintf(stderr, "biotgrid solve: %s: no method given\n", option);
        return -1;
    }
    return 0;
}

static int add_mesh_path(char *mesh_path, size_t size, const char *command, const char *folder)
{
    if (bg_cmd_mesh_path_add(mesh_path, size, folder) != 0) {
        fprintf(stderr, "biotgrid %s: --mesh-path: too many folders\n", command);
        return -1;
    }
    return 0;
}

static int finish_mesh_path(char *mesh_path, size_t size, const char *command)
{
    if (bg_cmd_mesh_path_finish(mesh_path, size) != 0) {
        fprintf(stderr, "biotgrid %s: $%s is too long\n", command, BG_CMD_MESH_PATH_ENV);
        return -1;
    }
    return 0;
}

/* 1: --help was printed, 0: go on, -1: bad usage (message printed). */
static int parse_args(int argc, char **argv, cli_options_t *o)
{
    memset(o, 0, sizeof *o);
    o->agent_timeout_ms = CLI_AGENT_TIMEOUT_MS;
    o->tolerance = -1.0;
    o->max_iterations = -1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *value = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bg_cmd_solve_usage, stdout);
            return 1;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
        } else if (strcmp(a, "--grid") == 0) {
            o->grid = 1;
        } else if ((strcmp(a, "--agents") == 0 || strcmp(a, "--grid-state") == 0 ||
                    strcmp(a, "--agent-timeout") == 0 || strcmp(a, "--mechanism") == 0 ||
                    strcmp(a, "--budget") == 0) &&
                   value) {
            i++;
            if (strcmp(a, "--agents") == 0) {
                o->agents = value;
            } else if (strcmp(a, "--grid-state") == 0) {
                o->grid_dir = value;
            } else if (strcmp(a, "--mechanism") == 0) {
                if (!bg_cmd_job_mechanism_ok(value)) {
                    fprintf(stderr, "biotgrid solve: --mechanism: unknown mechanism '%s' "
                                    "(expected central, catallactic or posted)\n", value);
                    return -1;
                }
                o->mechanism = value;
            } else if (strcmp(a, "--budget") == 0) {
                if (bg_cmd_job_budget(value, &o->budget) != 0) {
                    fprintf(stderr, "biotgrid solve: --budget: '%s' is not a positive number\n",
                            value);
                    return -1;
                }
            } else {
                char *end = NULL;
                const long ms = strtol(value, &end, 10);
                if (!end || *end || ms < 10 || ms > 3600000) {
                    fprintf(stderr, "biotgrid solve: --agent-timeout '%s' must be an integer "
                                    "in 10..3600000 (milliseconds)\n", value);
                    return -1;
                }
                o->agent_timeout_ms = (int)ms;
            }
        } else if (strcmp(a, "--inner") == 0) {
            if (!value || (strcmp(value, "newton") != 0 && strcmp(value, "quasi-newton") != 0)) {
                fprintf(stderr, "biotgrid solve: --inner takes newton or quasi-newton%s%s%s\n",
                        value ? " (got '" : "", value ? value : "", value ? "')" : "");
                return -1;
            }
            o->inner = value;
            i++;
        } else if (strcmp(a, "--method") == 0 || strcmp(a, "--compare") == 0 ||
                   strcmp(a, "--tolerance") == 0 || strcmp(a, "--max-iterations") == 0 ||
                   strcmp(a, "--out") == 0 || strcmp(a, "--mesh-path") == 0) {
            if (!value) {
                fprintf(stderr, "biotgrid solve: %s needs a value\n", a);
                return -1;
            }
            i++;
            char *end = NULL;
            if (strcmp(a, "--method") == 0) {
                if (strchr(value, ',')) {
                    fprintf(stderr, "biotgrid solve: --method takes one method; use --compare "
                                    "for several\n");
                    return -1;
                }
                if (parse_methods(a, value, o) != 0)
                    return -1;
            } else if (strcmp(a, "--compare") == 0) {
                if (parse_methods(a, value, o) != 0)
                    return -1;
            } else if (strcmp(a, "--tolerance") == 0) {
                o->tolerance = strtod(value, &end);
                if (!end || *end || !(o->tolerance > 0.0 && o->tolerance < 1.0)) {
                    fprintf(stderr, "biotgrid solve: --tolerance '%s' must be a number in (0, 1)\n",
                            value);
                    return -1;
                }
            } else if (strcmp(a, "--max-iterations") == 0) {
                long n = strtol(value, &end, 10);
                if (!end || *end || n < 1 || n > 1000000) {
                    fprintf(stderr, "biotgrid solve: --max-iterations '%s' must be an integer "
                                    "in 1..1000000\n", value);
                    return -1;
                }
                o->max_iterations = (int)n;
            } else if (strcmp(a, "--mesh-path") == 0) {
                if (add_mesh_path(o->mesh_path, sizeof o->mesh_path, "solve", value) != 0)
                    return -1;
            } else {
                o->out_dir = value;
            }
        } else if (a[0] == '-') {
            fprintf(stderr, "biotgrid solve: unknown option '%s' (see biotgrid solve --help)\n",
                    a);
            return -1;
        } else if (!o->scene_path) {
            o->scene_path = a;
        } else {
            fprintf(stderr, "biotgrid solve: one scene at a time ('%s' and '%s')\n",
                    o->scene_path, a);
            return -1;
        }
    }
    if (!o->scene_path) {
        fputs(bg_cmd_solve_usage, stderr);
        return -1;
    }
    if (o->agents && o->grid) {
        fprintf(stderr, "biotgrid solve: --agents and --grid exclude each other\n");
        return -1;
    }
    if ((o->mechanism || o->budget > 0.0) && !o->grid) {
        fprintf(stderr, "biotgrid solve: --%s buys services on a grid's market: it needs --grid\n",
                o->mechanism ? "mechanism" : "budget");
        return -1;
    }
    return finish_mesh_path(o->mesh_path, sizeof o->mesh_path, "solve");
}

/* Parses (and validates) the scene without preparing it; prints the error. */
static int load_scene(const char *command, const char *path, const bg_scene_options_t *so,
                      bg_scene_t **scene)
{
    bg_error_t err = BG_ERROR_INIT;
    if (bg_scene_load_with(path, so, scene, &err) == BG_OK)
        return 0;
    fprintf(stderr, "biotgrid %s: %s\n", command, err.message);
    if (err.status == BG_ERR_NOT_FOUND)
        fputs(BG_CMD_MESH_HINT, stderr);
    return -1;
}

static void on_progress(void *ctx, bg_method method, const bg_trace_point_t *p)
{
    const progress_t *pr = ctx;
    if (pr->quiet)
        return;
    char error[32] = "-";
    if (isfinite(p->error))
        snprintf(error, sizeof error, "%.3e", p->error);
    if (pr->tty)
        fprintf(stderr, "\r\033[K%-12s iteration %4d  %8.3f s  rel.gradient %.3e  error %s",
                bg_method_name(method), p->iteration, p->seconds, p->relative_gradient, error);
    else
        fprintf(stderr, "%s iteration %d seconds %.4f energy %.15e relative_gradient %.3e error "
                        "%s\n",
                bg_method_name(method), p->iteration, p->seconds, p->energy,
                p->relative_gradient, error);
    fflush(stderr);
}



/* Appends one more output path to the "results:" list in buf. */
static void list_result(char *buf, size_t size, const char *dir, const char *name)
{
    const size_t used = strlen(buf);
    if (used < size)
        snprintf(buf + used, size - used, "\n  %s/%s", dir, name);
}

/* Adds one agent; "SERVICES=ENDPOINT" gives its services. 0, or -1 after a message. */
static int add_agent(cli_agent *agents, int *count, const char *spec, const char *services,
                     const char *where)
{
    if (*count == CLI_MAX_AGENTS) {
        fprintf(stderr, "biotgrid solve: %s: more than %d agents\n", where, CLI_MAX_AGENTS);
        return -1;
    }
    cli_agent *a = &agents[*count];
    memset(a, 0, sizeof *a);
    a->role = CLI_ROLE_NONE;
    const char *eq = strchr(spec, '='), *ep = eq ? eq + 1 : spec;
    char list[64] = "";
    if (eq && (size_t)(eq - spec) < sizeof list)
        memcpy(list, spec, (size_t)(eq - spec));
    else if (services)
        snprintf(list, sizeof list, "%s", services);
    if (strlen(ep) >= sizeof a->endpoint || strncmp(ep, "tcp://", 6) != 0 ||
        (eq && (size_t)(eq - spec) >= sizeof list)) {
        fprintf(stderr, "biotgrid solve: %s: '%s' is not [SERVICES=]tcp://HOST:PORT\n", where,
                spec);
        return -1;
    }
    strcpy(a->endpoint, ep);
    if (list[0]) {
        bg_error_t err = BG_ERROR_INIT;
        a->services = bga_service_parse_list(list, &err);
        if (!a->services) {
            fprintf(stderr, "biotgrid solve: %s: %s: %s\n", where, spec, err.message);
            return -1;
        }
    }
    (*count)++;
    return 0;
}

static int parse_agent_list(const char *list, cli_agent *agents, int *count)
{
    char buf[CLI_MAX_AGENTS * CLI_ENDPOINT_MAX];
    if (strlen(list) >= sizeof buf) {
        fprintf(stderr, "biotgrid solve: --agents: list too long\n");
        return -1;
    }
    strcpy(buf, list);
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save))
        if (add_agent(agents, count, tok, NULL, "--agents") != 0)
            return -1;
    return 0;
}

/* The agents recorded by `biotgrid grid up` in DIR/grid.json. */
static int read_grid_agents(const char *dir, cli_agent *agents, int *count)
{
    char path[4200];
    if (bg_file_join(path, sizeof path, dir, "grid.json") != 0) {
        fprintf(stderr, "biotgrid solve: --grid: state directory name too long\n");
        return -1;
    }
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "biotgrid solve: --grid: no running grid (%s: %s; start one with "
                        "`biotgrid grid up`)\n", path, strerror(errno));
        return -1;
    }
    char *text = malloc(CLI_GRID_STATE_MAX + 1);
    const size_t n = text ? fread(text, 1, CLI_GRID_STATE_MAX, f) : 0;
    fclose(f);
    cJSON *root = NULL;
    if (text) {
        text[n] = '\0';
        root = cJSON_Parse(text);
    }
    free(text);
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "agents");
    int rc = cJSON_IsArray(arr) ? 0 : -1;
    for (const cJSON *a = rc == 0 ? arr->child : NULL; a && rc == 0; a = a->next) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(a, "endpoint");
        const cJSON *sv = cJSON_GetObjectItemCaseSensitive(a, "services");
        if (!cJSON_IsString(e) || !cJSON_IsString(sv))
            rc = -1;
        else
            rc = add_agent(agents, count, e->valuestring, sv->valuestring, path);
    }
    if (rc != 0 || !arr)
        fprintf(stderr, "biotgrid solve: --grid: %s: not a grid state file\n", path);
    cJSON_Delete(root);
    return rc == 0 && arr ? 0 : -1;
}

/*
 * The simple rule for now (the market decides in the next issue): the
 * sparse-solve agent is the first that serves only sparse-solve, else the
 * first that serves it; every other agent serving rotation-fit fits
 * rotations (the solve agent too when it is the only one). Agents of
 * unknown services get a heartbeat. 0, or 1 after a message (exit 1: an
 * agent did not answer), 2 (bad input: a service is missing).
 */
static int assign_agents(cli_agent *agents, int count, int timeout_ms, const char **rotfit,
                         int *nrotfit, const char **solve)
{
    for (int i = 0; i < count; i++) {
        if (agents[i].services)
            continue;
        bga_client_t *c = NULL;
        bga_agent_status_t st;
        bg_error_t err = BG_ERROR_INIT;
        agents[i].contacted = 1;
        if (bga_client_new(agents[i].endpoint, "heartbeat", timeout_ms, &c, &err) != BG_OK ||
            bga_client_heartbeat(c, 0, &st, &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: %s\n", err.message);
            bga_client_destroy(&c);
            return 1;
        }
        bga_client_destroy(&c);
        agents[i].services = st.services;
    }
    int s = -1;
    for (int i = 0; i < count && s < 0; i++)
        if (agents[i].services == BGA_SERVICE_SOLVE)
            s = i;
    for (int i = 0; i < count && s < 0; i++)
        if (agents[i].services & BGA_SERVICE_SOLVE)
            s = i;
    *nrotfit = 0;
    for (int i = 0; i < count; i++)
        if (i != s && (agents[i].services & BGA_SERVICE_ROTFIT)) {
            agents[i].role = *nrotfit;
            rotfit[(*nrotfit)++] = agents[i].endpoint;
        }
    if (*nrotfit == 0 && s >= 0 && (agents[s].services & BGA_SERVICE_ROTFIT)) {
        agents[s].role = 0;
        rotfit[(*nrotfit)++] = agents[s].endpoint;
    }
    if (s < 0 || *nrotfit == 0) {
        fprintf(stderr, "biotgrid solve: the agents given serve no %s\n",
                s < 0 ? "sparse-solve" : "rotation-fit");
        return 2;
    }
    if (agents[s].role == CLI_ROLE_NONE)
        agents[s].role = CLI_ROLE_SOLVE;
    *solve = agents[s].endpoint;
    return 0;
}

static const char *service_names(unsigned services)
{
    switch (services) {
    case BGA_SERVICE_ROTFIT: return "rotation-fit";
    case BGA_SERVICE_SOLVE: return "sparse-solve";
    case BGA_SERVICE_INTEG: return "integration-step";
    default: return "several services";
    }
}

/* What every agent did, for the report and the console. */
static int agents_report(const cli_agent *agents, int count, const bga_backend_t *backend,
                         bg_report_agent_t *out)
{
    const int nrotfit = bga_backend_agents(backend) - 1;
    for (int i = 0; i < count; i++) {
        const cli_agent *a = &agents[i];
        bg_report_agent_t *r = &out[i];
        memset(r, 0, sizeof *r);
        r->endpoint = a->endpoint;
        r->contacted = a->contacted;
        r->service = service_names(a->services);
        if (a->role == CLI_ROLE_NONE)
            continue;
        bga_agent_usage_t u;
        if (a->role != CLI_ROLE_INTEG || !bga_backend_integ_usage(backend, &u))
            u = bga_backend_usage(backend, a->role == CLI_ROLE_SOLVE ? nrotfit : a->role);
        r->service = u.service;
        r->calls = u.traffic.requests;
        r->contacted |= r->calls > 0;
        r->bytes_sent = u.traffic.bytes_sent;
        r->bytes_received = u.traffic.bytes_received;
        r->compute_seconds = u.traffic.agent_seconds;
        r->encode_seconds = u.traffic.encode_seconds;
        r->wait_seconds = u.traffic.wait_seconds;
    }
    return count;
}

static void print_agents(const bg_report_agent_t *r, int count)
{
    printf("\nagents (per service and agent; transit = wait - compute)\n");
    for (int i = 0; i < count; i++) {
        if (!r[i].contacted || r[i].calls == 0) {
            printf("  %-14s %s: %s (the plan does not need it)\n", r[i].service,
                   r[i].endpoint,
                   r[i].contacted ? "asked its services (heartbeat), no service call"
                                  : "not contacted");
            continue;
        }
        printf("  %-14s %s: %lld calls, compute %.3f s, sent %lld B, received %lld B, "
               "encode %.3f s, transit %.3f s, wait %.3f s\n",
               r[i].service, r[i].endpoint, r[i].calls, r[i].compute_seconds, r[i].bytes_sent,
               r[i].bytes_received, r[i].encode_seconds, r[i].wait_seconds - r[i].compute_seconds,
               r[i].wait_seconds);
    }
}

int bg_cmd_solve(int argc, char **argv)
{
    cli_options_t o;
    int rc = parse_args(argc, argv, &o);
    if (rc != 0)
        return rc > 0 ? BG_EXIT_OK : BG_EXIT_BAD_INPUT;
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *scene = NULL;
    bg_solve_result_t runs[CLI_MAX_METHODS];
    bg_solve_result_t reference = BG_SOLVE_RESULT_INIT;
    int run_count = 0;
    int exit_code = BG_EXIT_BAD_INPUT;
    memset(runs, 0, sizeof runs);
    cli_agent agents[CLI_MAX_AGENTS];
    int agent_count = 0;
    bga_backend_t *remote = NULL;
    const bg_backend_t *backend = NULL;
    bg_report_agent_t agent_lines[CLI_MAX_AGENTS];

    const bg_scene_options_t scene_options = {.search_path = o.mesh_path};
    if (load_scene("solve", o.scene_path, &scene_options, &scene) != 0)
        goto out;
    if (o.method_count == 0) {
        o.methods[0] = scene->method;
        o.method_count = 1;
    }
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    if (o.inner && !dynamic) {
        fprintf(stderr, "biotgrid solve: --inner: %s is not a dynamic scene (only a time step has "
                        "an inner solve; choose a static solver with --method)\n",
                o.scene_path);
        goto out;
    }
    if (o.inner)
        scene->inner = strcmp(o.inner, "quasi-newton") == 0 ? BG_METHOD_QUASI_NEWTON
                                                             : BG_METHOD_NEWTON;
    for (int i = 0; i < o.method_count; i++)
        if (bg_method_is_dynamic(o.methods[i]) != dynamic) {
            fprintf(stderr, "biotgrid solve: %s: method %s does not fit a %s scene (use %s)\n",
                    o.scene_path, bg_method_name(o.methods[i]), dynamic ? "dynamic" : "static",
                    dynamic ? "variational or backward-euler"
                            : "newton, local-global or quasi-newton");
            goto out;
        }
    const char *grid_dir = bg_cmd_grid_dir(o.grid_dir);
    char broker[CLI_BROKER_URL_MAX];
    if (o.grid && bg_cmd_grid_broker(grid_dir, broker, sizeof broker)) {
        /* The grid's broker prepares and solves the scene: nothing more here. */
        char token[BG_CMD_TOKEN_MAX];
        bg_cmd_token_find(NULL, grid_dir, token, sizeof token);
        const bg_cmd_broker_solve_t job = {.url = broker,
                                           .token = token,
                                           .scene_path = o.scene_path,
                                           .search_path = o.mesh_path,
                                           .scene = scene,
                                           .methods = o.methods,
                                           .method_count = o.method_count,
                                           .tolerance = o.tolerance,
                                           .max_iterations = o.max_iterations,
                                           .inner = o.inner,
                                           .mechanism = o.mechanism ? o.mechanism : "central",
                                           .budget = o.budget,
                                           .out_dir = o.out_dir,
                                           .quiet = o.quiet};
        exit_code = bg_cmd_solve_on_broker(&job);
        goto out;
    }
    if (o.mechanism || o.budget > 0.0) {
        fprintf(stderr, "biotgrid solve: --%s: the grid in %s has no broker (its agents are used "
                        "directly, without a market)\n",
                o.mechanism ? "mechanism" : "budget", grid_dir);
        goto out;
    }
    if (bg_prepare_scene(scene, &err) != BG_OK) {
        fprintf(stderr, "biotgrid solve: %s\n", err.message);
        exit_code = err.status == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_FAILED;
        goto out;
    }
    if (o.agents || o.grid) {
        if ((o.agents ? parse_agent_list(o.agents, agents, &agent_count)
                      : read_grid_agents(grid_dir, agents, &agent_count)) != 0)
            goto out;
        const char *rotfit[CLI_MAX_AGENTS], *solve = NULL;
        int nrotfit = 0;
        const int arc = assign_agents(agents, agent_count, o.agent_timeout_ms, rotfit, &nrotfit,
                                     &solve);
        if (arc != 0) {
            exit_code = arc == 1 ? BG_EXIT_FAILED : BG_EXIT_BAD_INPUT;
            goto out;
        }
        const bga_backend_config_t bc = {
            rotfit, nrotfit, solve, o.agent_timeout_ms, CLI_AGENT_LEASE_MS, 0, NULL};
        if (bga_backend_new(&bc, &remote, &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: %s\n", err.message);
            goto out;
        }
        /* The time loop's state goes to the first integration-step agent
         * (a static job never opens it, so never contacts that agent). */
        for (int i = 0; i < agent_count; i++)
            if (agents[i].role == CLI_ROLE_NONE && (agents[i].services & BGA_SERVICE_INTEG)) {
                if (bga_backend_set_integ(remote, agents[i].endpoint, &err) != BG_OK) {
                    fprintf(stderr, "biotgrid solve: %s\n", err.message);
                    goto out;
                }
                agents[i].role = CLI_ROLE_INTEG;
                break;
            }
        backend = bga_backend_services(remote);
    }
    const double tolerance = o.tolerance > 0 ? o.tolerance : scene->tolerance;
    char out_dir[4096];
    if (o.out_dir)
        snprintf(out_dir, sizeof out_dir, "%s", o.out_dir);
    else
        snprintf(out_dir, sizeof out_dir, "out/%s", scene->name);
    if (bg_cmd_make_directories(out_dir) != 0) {
        fprintf(stderr, "biotgrid solve: cannot create the output directory %s: %s\n", out_dir,
                strerror(errno));
        goto out;
    }
    progress_t pr = {isatty(fileno(stderr)), o.quiet};
    fprintf(stderr, "%s: %s, %d vertices, %d elements (%s)\n", scene->name,
            bg_mesh_kind_name(bg_mesh_kind_of(scene->mesh)), (int)scene->mesh->nv,
            (int)scene->mesh->ne, scene->mesh_source);

    const double *ref = NULL;
    if (scene->reference_kind == BG_REFERENCE_NEWTON && scene->task == BG_TASK_STATIC &&
        !o.quiet)
        fprintf(stderr, "computing the reference solution (Newton to its round-off floor)\n");
    if (bg_run_reference(scene, NULL, &reference, &ref, &err) != BG_OK) {
        fprintf(stderr, "biotgrid solve: reference solve: %s\n", err.message);
        exit_code = BG_EXIT_FAILED;
        goto out;
    }

    int all_converged = 1;
    for (int i = 0; i < o.method_count; i++) {
        const int max_iterations = o.max_iterations > 0
                                       ? o.max_iterations
                                       : bg_scene_max_iterations(scene, o.methods[i]);
        const bg_run_options_t ro = {.method = o.methods[i],
                                     .tolerance = tolerance,
                                     .max_iterations = max_iterations,
                                     .frames_prefix = "frames/",
                                     .progress = on_progress,
                                     .progress_ctx = &pr,
                                     .backend = backend};
        const bg_status st = bg_run_method(scene, &ro, ref, out_dir, &runs[i], &err);
        if (st != BG_OK) {
            if (pr.tty && !o.quiet)
                fputc('\n', stderr);
            fprintf(stderr, "biotgrid solve: %s: %s\n", bg_method_name(o.methods[i]),
                    err.message);
            exit_code = err.status == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_FAILED;
            goto out;
        }
        run_count++;
        if (pr.tty && !o.quiet)
            fputc('\n', stderr);
        bg_cmd_runs_print_run(scene, &runs[i], max_iterations, tolerance);
        all_converged &= runs[i].converged;
    }

    bg_plan_t plan;
    bg_plan_for_scene(scene, o.methods, o.method_count, &plan);
    if (remote && !backend && plan.service_count < BG_PLAN_MAX_ITEMS) {
        plan.services[plan.service_count].service = "surface-edit";
        snprintf(plan.services[plan.service_count++].detail,
                 sizeof plan.services[0].detail,
                 "surface-edit runs in process: its per-vertex rotations have no agent "
                 "service yet");
    }
    const int lines = remote ? agents_report(agents, agent_count, remote, agent_lines) : 0;
    char report_path[4200], plot_path[4200], result_paths[8500];
    if (bg_file_join(report_path, sizeof report_path, out_dir, "report.json") != 0 ||
        bg_file_join(plot_path, sizeof plot_path, out_dir, "error-vs-time.svg") != 0) {
        fprintf(stderr, "biotgrid solve: output directory name too long\n");
        goto out;
    }
    if (bg_report_write_agents(report_path, scene, &plan, runs, run_count,
                               remote ? agent_lines : NULL, lines, &err) != BG_OK ||
        bg_report_write_plot(plot_path, scene, runs, run_count, &err) != BG_OK ||
        bg_run_write_results(out_dir, scene, &runs[0], result_paths, sizeof result_paths,
                              &err) !=
            BG_OK) {
        fprintf(stderr, "biotgrid solve: %s\n", err.message);
        exit_code = BG_EXIT_FAILED;
        goto out;
    }
    for (int i = 0; i < run_count; i++) {
        char name[96];
        if (dynamic || scene->task == BG_TASK_MORPH) {
            snprintf(name, sizeof name, "%s.pvd (frames/%s-*.vtu)", bg_method_name(runs[i].method),
                     bg_method_name(runs[i].method));
            list_result(result_paths, sizeof result_paths, out_dir, name);
        } else if (scene->task == BG_TASK_PARAMETERIZE) {
            snprintf(name, sizeof name, "%s-uv.obj", bg_method_name(runs[i].method));
            list_result(result_paths, sizeof result_paths, out_dir, name);
        }
    }
    bg_cmd_runs_print_tables(scene, runs, run_count, tolerance);
    if (remote)
        print_agents(agent_lines, lines);
    printf("\nresults:\n  %s\n  %s\n  %s\n", report_path, plot_path, result_paths);
    exit_code = all_converged ? BG_EXIT_OK : BG_EXIT_FAILED;
out:
    for (int i = 0; i < CLI_MAX_METHODS; i++)
        bg_solve_result_release(&runs[i]);
    bg_solve_result_release(&reference);
    bga_backend_destroy(&remote);
    bg_scene_destroy(&scene);
    return exit_code;
}

int bg_cmd_validate(int argc, char **argv)
{
    const char *path = NULL;
    char mesh_path[CLI_MESH_PATH_MAX] = "";
    bg_scene_options_t so = {0};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bg_cmd_validate_usage, stdout);
            return BG_EXIT_OK;
        } else if (strcmp(a, "--mesh-path") == 0 || strcmp(a, "--max-vertices") == 0 ||
                   strcmp(a, "--max-elements") == 0) {
            if (i + 1 == argc) {
                fprintf(stderr, "biotgrid validate: %s needs a value\n", a);
                return BG_EXIT_BAD_INPUT;
            }
            const char *value = argv[++i];
            if (strcmp(a, "--mesh-path") == 0) {
                if (add_mesh_path(mesh_path, sizeof mesh_path, "validate", value) != 0)
                    return BG_EXIT_BAD_INPUT;
                continue;
            }
            char *end = NULL;
            long long n = strtoll(value, &end, 10);
            if (!end || *end || n < 1) {
                fprintf(stderr, "biotgrid validate: %s '%s' must be a positive integer\n", a,
                        value);
                return BG_EXIT_BAD_INPUT;
            }
            if (strcmp(a, "--max-vertices") == 0)
                so.max_vertices = n;
            else
                so.max_elements = n;
        } else if (a[0] == '-') {
            fprintf(stderr, "biotgrid validate: unknown option '%s' (see biotgrid validate "
                            "--help)\n", a);
            return BG_EXIT_BAD_INPUT;
        } else if (path) {
            fprintf(stderr, "biotgrid validate: one scene at a time ('%s' and '%s')\n", path, a);
            return BG_EXIT_BAD_INPUT;
        } else {
            path = a;
        }
    }
    if (!path) {
        fputs(bg_cmd_validate_usage, stderr);
        return BG_EXIT_BAD_INPUT;
    }
    if (finish_mesh_path(mesh_path, sizeof mesh_path, "validate") != 0)
        return BG_EXIT_BAD_INPUT;
    bg_scene_t *scene = NULL;
    so.search_path = mesh_path;
    if (load_scene("validate", path, &so, &scene) != 0)
        return BG_EXIT_BAD_INPUT;
    static const char *const tasks[] = {"static", "dynamic", "morph", "parameterize",
                                        "surface-edit"};
    printf("%s: valid: %s task, %s, %d vertices, %d elements (%s), %d handles, method %s\n",
           path, tasks[scene->task], bg_mesh_kind_name(bg_mesh_kind_of(scene->mesh)),
           (int)scene->mesh->nv, (int)scene->mesh->ne, scene->mesh_source,
           (int)scene->handle_count, bg_method_name(scene->method));
    bg_scene_destroy(&scene);
    return BG_EXIT_OK;
}
