/*
 * biotgrid grid up [FILE] [--state DIR] [--broker-port N] [--broker-endpoint EP]
 *                                          start the grid's agents and broker
 * biotgrid grid status [--state DIR]       ping every recorded agent, the broker
 * biotgrid grid down [--state DIR] [--grace SECONDS]
 *
 * FILE (default configs/grids/local.json) is {"name": ..., "agents":
 * [{"name", "services", "slots", "listen"}, ...], "broker": {"port",
 * "endpoint", "market", ...}, "host": {"cores", "memory"}} (market: the
 * broker's live-market settings, as in its config, bgb_broker.h; the
 * broker object's other keys, those bgb_config_grid_setting names, go to the broker's
 * config as they are: how jobs run and recover, and the limits; host:
 * the cores and GiB the grid's machine sells on the live market, given to
 * every agent as --cores and --memory, default what the machine has; its
 * first agent to register sells them, the others stand by). With a
 * "broker" object (or a --broker-* option), `up` starts `biotgrid broker`
 * first, with a config in DIR/broker.json (no
 * fixed pool) and its store in DIR/broker/, records its URL, endpoint and
 * PID in the state file, and gives every agent `--broker ENDPOINT` (the
 * endpoint the broker actually bound), so the agents register and sell on
 * its live market; `down` stops it before the agents (its running jobs
 * need them). `up` starts each agent
 * as its own process (this executable, `agent --ready-file
 * DIR/NAME.ready`, in a new session so a terminal's signals do not reach
 * it), waits until each has written its endpoint and answers a heartbeat,
 * and writes DIR/grid.json (name, endpoint, PID, services, slots per
 * agent). If any agent fails, every agent started so far is stopped.
 * `down` sends SIGTERM to the broker, then to each recorded agent, SIGKILL
 * to any still alive after the grace (default 5 s), says for each what it
 * did, and removes the state file once nothing of the grid runs (else it
 * keeps what still runs and exits 1). A PID is signalled only while /proc
 * shows the process the state recorded (PID and start time), so a
 * recycled PID is never hit. `up` on a grid some of whose processes died
 * keeps what runs and starts the rest (a broker again on its endpoint and
 * port, with its store). DIR defaults to $BIOTGRID_GRID_DIR or out/grid
 * and is resolved to its canonical path.
 *
 * "security": "curve" in FILE makes every ZeroMQ link of the grid speak
 * CURVE: `up` keeps a key pair per process in DIR/keys (made once, kept
 * across ups: NAME.key, NAME.pub, broker.key, broker.pub), gives the
 * broker the folder DIR/authorized of its agents' public keys (a remote
 * agent's NAME.pub may be added there) and each agent its key and the
 * broker's; `up` and `status` reach the agents with the broker's key.
 * Without it ("none", the default) every endpoint must be loopback (exit
 * 2 naming the one that is not). `status` also lists the agents
 * registered with the grid's broker that `up` did not start.
 */
#include "cmd_grid.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <pwd.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bg_clock.h"
#include "bg_file.h"
#include "bg_mesh_io.h"
#include "bga_client.h"
#include "bga_curve.h"
#include "bgb_broker.h"
#include "bgb_client.h"
#include "bgb_tokens.h"
#include "cmd.h"
#include "cmd_agent.h"
#include "cmd_job.h"
#include "cmd_token.h"

#define GRID_MAX_AGENTS 64
#define GRID_KEYS "keys"             /* DIR/keys: the grid's key pairs */
#define GRID_AUTHORIZED "authorized" /* DIR/authorized: the agents' public keys */
#define GRID_READY_SECONDS 10.0
#define GRID_PING_MS 2000

typedef struct grid_agent {
    bg_agent_spec_t spec;
    char endpoint[BGA_AGENT_ENDPOINT_MAX];
    long pid;
    /* The process's start time (/proc/PID/stat field 22) once its command
     * line was seen to be ours: an exiting process has an empty command
     * line before it is a zombie, and must still count as running. */
    unsigned long long start_time;
} grid_agent;

typedef struct grid {
    char name[64];
    int count;
    grid_agent agent[GRID_MAX_AGENTS];
    int has_broker;
    grid_agent broker; /* spec.name "broker", spec.listen its ZeroMQ endpoint */
    int broker_port;
    char broker_url[128];
    char market[2048]; /* the broker's "market" object, compact JSON ("" none) */
    char settings[1024];        /* bgb_config_grid_setting keys given, compact JSON ("" none) */
    char cores[32], memory[32]; /* the "host" object's, as agent options ("" none) */
    int curve;                  /* "security": "curve" */
} grid;

/* The broker's name among the grid's processes (its ready and log files). */
#define GRID_BROKER_NAME "broker"

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static int path_join(char *out, size_t cap, const char *dir, const char *file)
{
    if (snprintf(out, cap, "%s/%s", dir, file) >= (int)cap) {
        fprintf(stderr, "biotgrid grid: path %s/%s is too long\n", dir, file);
        return -1;
    }
    return 0;
}

static cJSON *read_json(const char *path, size_t cap)
{
    char *text = NULL;
    size_t len = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_file_read_all(path, cap, &text, &len, &err) != BG_OK) {
        fprintf(stderr, "biotgrid grid: %s\n", err.message);
        return NULL;
    }
    cJSON *root = cJSON_ParseWithLength(text, len);
    free(text);
    if (!root)
        fprintf(stderr, "biotgrid grid: %s: malformed JSON\n", path);
    return root;
}

static void broker_defaults(grid *g)
{
    g->has_broker = 1;
    snprintf(g->broker.spec.name, sizeof g->broker.spec.name, "%s", GRID_BROKER_NAME);
    if (!g->broker.spec.listen[0])
        snprintf(g->broker.spec.listen, sizeof g->broker.spec.listen, "tcp://127.0.0.1:5570");
}

/* The settings of `obj` that pass to the broker as they are: checked as the
 * broker will read them, so a bad value is this command's error, not a
 * broker that never starts; kept in g->settings. 0, or 2 with a message. */
static int read_broker_settings(const cJSON *obj, const char *path, grid *g)
{
    cJSON *pass = cJSON_CreateObject();
    int rc = pass ? 0 : 2;
    for (const cJSON *k = obj->child; rc == 0 && k; k = k->next)
        if (bgb_config_grid_setting(k->string) &&
            !cJSON_AddItemToObject(pass, k->string, cJSON_Duplicate(k, 1)))
            rc = 2;
    bgb_config_t scratch;
    bg_error_t err = BG_ERROR_INIT;
    if (rc == 0 && pass->child) {
        char where[PATH_MAX + 16];
        snprintf(where, sizeof where, "%s: broker", path);
        if (bgb_config_init(&scratch, &err) != BG_OK) {
            rc = 2;
        } else {
            if (bgb_config_read_object(pass, where, &scratch, &err) != BG_OK)
                rc = 2;
            bgb_config_release(&scratch);
        }
        char *text = rc == 0 ? cJSON_PrintUnformatted(pass) : NULL;
        if (rc == 0 && (!text || strlen(text) >= sizeof g->settings)) {
            snprintf(err.message, sizeof err.message, "%s: broker: settings longer than %zu bytes",
                     path, sizeof g->settings - 1);
            rc = 2;
        } else if (rc == 0) {
            snprintf(g->settings, sizeof g->settings, "%s", text);
        }
        free(text);
    }
    if (rc != 0)
        fprintf(stderr, "biotgrid grid: %s\n", err.message[0] ? err.message : "out of memory");
    cJSON_Delete(pass);
    return rc;
}

/* The "broker" object: port (0: ephemeral), endpoint, market and the
 * settings above. */
static int read_broker_config(const cJSON *obj, const char *path, grid *g)
{
    g->broker_port = 8080;
    if (read_broker_settings(obj, path, g) != 0)
        return 2;
    for (const cJSON *k = obj->child; k; k = k->next) {
        if (bgb_config_grid_setting(k->string))
            continue;
        if (strcmp(k->string, "port") == 0 && cJSON_IsNumber(k) && k->valuedouble >= 0 &&
            k->valuedouble <= 65535 && k->valuedouble == (double)(int)k->valuedouble) {
            g->broker_port = (int)k->valuedouble;
        } else if (strcmp(k->string, "market") == 0) {
            /* Checked here as the broker will read it, so a bad value is
             * this command's error, not a broker that never starts. */
            bgb_market_config_t mc;
            bgb_market_config_default(&mc);
            bg_error_t err = BG_ERROR_INIT;
            char *text = NULL;
            if (bgb_config_market_read(k, path, &mc, &err) != BG_OK) {
                fprintf(stderr, "biotgrid grid: %s\n", err.message);
                return 2;
            }
            if (!(text = cJSON_PrintUnformatted(k)) || strlen(text) >= sizeof g->market) {
                fprintf(stderr, "biotgrid grid: %s: broker.market: longer than %zu bytes\n", path,
                        sizeof g->market - 1);
                free(text);
                return 2;
            }
            snprintf(g->market, sizeof g->market, "%s", text);
            free(text);
        } else if (strcmp(k->string, "endpoint") == 0 && cJSON_IsString(k) &&
                   strncmp(k->valuestring, "tcp://", 6) == 0 &&
                   strlen(k->valuestring) < sizeof g->broker.spec.listen) {
            snprintf(g->broker.spec.listen, sizeof g->broker.spec.listen, "%s", k->valuestring);
        } else {
            fprintf(stderr,
                    "biotgrid grid: %s: broker.%s: unknown key or wrong value (port: integer "
                    "in [0, 65535], endpoint: tcp://HOST:PORT, market: an object, or a setting "
                    "the broker's config takes: max_jobs, agent_timeout_ms, agent_liveness_ms, "
                    "agent_recovery, stop_grace_ms, the limits)\n",
                    path, k->string);
            return 2;
        }
    }
    broker_defaults(g);
    return 0;
}

/* The "host" object: the cores and GiB the machine sells. */
static int read_host_config(const cJSON *obj, const char *path, grid *g)
{
    for (const cJSON *k = obj->child; k; k = k->next) {
        const int cores = strcmp(k->string, "cores") == 0;
        if ((cores || strcmp(k->string, "memory") == 0) && cJSON_IsNumber(k) &&
            k->valuedouble > 0 && k->valuedouble <= (cores ? 1e6 : 1e9)) {
            snprintf(cores ? g->cores : g->memory, sizeof g->cores, "%.17g", k->valuedouble);
        } else {
            fprintf(stderr,
                    "biotgrid grid: %s: host.%s: unknown key or wrong value (cores: a number in "
                    "(0, 1e6], memory: GiB in (0, 1e9])\n",
                    path, k->string);
            return 2;
        }
    }
    return 0;
}

/* The grid config: names unique and usable as file names. */
static int read_grid_config(const char *path, grid *g)
{
    memset(g, 0, sizeof *g);
    cJSON *root = read_json(path, 1 << 20);
    if (!root)
        return 2;
    int rc = 0;
    snprintf(g->name, sizeof g->name, "grid");
    for (cJSON *it = root->child; it && rc == 0; it = it->next) {
        if (strcmp(it->string, "name") == 0 && cJSON_IsString(it)) {
            snprintf(g->name, sizeof g->name, "%s", it->valuestring);
        } else if (strcmp(it->string, "agents") == 0 && cJSON_IsArray(it)) {
            for (cJSON *a = it->child; a && rc == 0; a = a->next) {
                char where[PATH_MAX + 32];
                snprintf(where, sizeof where, "%s: agents[%d]", path, g->count);
                if (g->count == GRID_MAX_AGENTS) {
                    fprintf(stderr, "biotgrid grid: %s: more than %d agents\n", where,
                            GRID_MAX_AGENTS);
                    rc = 2;
                    break;
                }
                grid_agent *ga = &g->agent[g->count];
                bg_agent_spec_default(&ga->spec);
                snprintf(ga->spec.name, sizeof ga->spec.name, "agent-%d", g->count + 1);
                rc = bg_agent_spec_parse(a, where, &ga->spec);
                bg_error_t err = BG_ERROR_INIT;
                if (rc == 0 && !bga_service_parse_list(ga->spec.services, &err)) {
                    fprintf(stderr, "biotgrid grid: %s: services: %s\n", where, err.message);
                    rc = 2;
                }
                if (rc == 0 && (strspn(ga->spec.name, "abcdefghijklmnopqrstuvwxyz"
                                                      "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-") !=
                                    strlen(ga->spec.name) ||
                                !ga->spec.name[0])) {
                    fprintf(stderr,
                            "biotgrid grid: %s: name '%s' must be letters, digits, "
                            "'-' or '_'\n",
                            where, ga->spec.name);
                    rc = 2;
                }
                if (rc == 0 && strcmp(ga->spec.name, GRID_BROKER_NAME) == 0) {
                    fprintf(stderr, "biotgrid grid: %s: the name '%s' is the broker's\n", where,
                            GRID_BROKER_NAME);
                    rc = 2;
                }
                for (int j = 0; rc == 0 && j < g->count; j++)
                    if (strcmp(g->agent[j].spec.name, ga->spec.name) == 0) {
                        fprintf(stderr, "biotgrid grid: %s: name '%s' repeats agents[%d]\n", where,
                                ga->spec.name, j);
                        rc = 2;
                    }
                g->count++;
            }
        } else if (strcmp(it->string, "broker") == 0 && cJSON_IsObject(it)) {
            rc = read_broker_config(it, path, g);
        } else if (strcmp(it->string, "host") == 0 && cJSON_IsObject(it)) {
            rc = read_host_config(it, path, g);
        } else if (strcmp(it->string, "security") == 0 && cJSON_IsString(it) &&
                   (strcmp(it->valuestring, "curve") == 0 ||
                    strcmp(it->valuestring, "none") == 0)) {
            g->curve = strcmp(it->valuestring, "curve") == 0;
        } else if (strcmp(it->string, "security") == 0) {
            fprintf(stderr,
                    "biotgrid grid: %s: security: \"curve\" (every ZeroMQ link encrypted, keys "
                    "made by grid up) or \"none\" (loopback only)\n",
                    path);
            rc = 2;
        } else {
            fprintf(stderr,
                    "biotgrid grid: %s: unknown key or wrong type '%s' (name: string, "
                    "agents: array, broker: object, host: object, security: string)\n",
                    path, it->string);
            rc = 2;
        }
    }
    if (rc == 0 && g->count == 0) {
        fprintf(stderr, "biotgrid grid: %s: no agents\n", path);
        rc = 2;
    }
    cJSON_Delete(root);
    return rc;
}

/* The state letter of process pid (0: no such process) and its start
 * time in clock ticks since boot (field 22 of /proc/PID/stat). */
static char proc_state(long pid, unsigned long long *start_time)
{
    char path[64], stat_text[1024];
    snprintf(path, sizeof path, "/proc/%ld/stat", pid);
    FILE *f = fopen(path, "r");
    if (!f)
        return 0;
    const size_t n = fread(stat_text, 1, sizeof stat_text - 1, f);
    fclose(f);
    stat_text[n] = 0;
    /* The command name in parentheses may hold anything: fields count
     * from the last ')'. */
    const char *close_paren = strrchr(stat_text, ')');
    if (!close_paren || close_paren[1] != ' ' || !close_paren[2])
        return 0;
    const char state = close_paren[2];
    *start_time = 0;
    const char *p = close_paren + 2;
    for (int field = 3; field < 22 && p; field++) {
        p = strchr(p, ' ');
        if (p)
            p++;
    }
    if (p)
        *start_time = strtoull(p, NULL, 10);
    return state;
}

/* Whether pid is alive and still this grid's agent `name`: its command
 * line holds the ready-file path of the grid directory. A zombie counts
 * as gone. */
static int is_our_agent(long pid, const char *dir, const char *name)
{
    char path[64], want[PATH_MAX + 80];
    unsigned long long start = 0;
    const char state = proc_state(pid, &start);
    if (!state || state == 'Z')
        return 0;
    snprintf(path, sizeof path, "/proc/%ld/cmdline", pid);
    FILE *f = fopen(path, "rb");
    if (!f)
        return 0;
    char cmd[8192];
    const size_t m = fread(cmd, 1, sizeof cmd - 1, f);
    fclose(f);
    for (size_t i = 0; i < m; i++)
        if (cmd[i] == 0)
            cmd[i] = ' ';
    cmd[m] = 0;
    snprintf(want, sizeof want, "--ready-file %s/%s.ready ", dir, name);
    return strstr(cmd, want) != NULL;
}

/* Whether the process recorded as a still runs: its PID names a live
 * process with the recorded start time (a PID reused by another process
 * has another), or, for a record without one, whose command line names
 * the grid's ready file. A zombie counts as gone. */
static int runs_now(const grid_agent *a, const char *dir)
{
    if (a->pid <= 0)
        return 0;
    unsigned long long start = 0;
    const char state = proc_state(a->pid, &start);
    if (!state || state == 'Z')
        return 0;
    return a->start_time ? start == a->start_time : is_our_agent(a->pid, dir, a->spec.name);
}

/* Whether agent a still runs. `children`: a is this process's child (in
 * `up`), tracked by waitpid, which also reaps it; otherwise it is known
 * only by its PID and command line. A stopped agent's pid becomes 0. */
static int still_runs(grid_agent *a, const char *dir, int children);

/* SIGTERM to the broker, SIGKILL after grace seconds; 1 if it needed SIGKILL. */
static int stop_broker(grid *g, const char *dir, double grace, int children)
{
    grid_agent *a = &g->broker;
    if (!g->has_broker || !still_runs(a, dir, children))
        return 0;
    kill((pid_t)a->pid, SIGTERM);
    const double deadline = bg_clock_now() + grace;
    while (still_runs(a, dir, children) && bg_clock_now() < deadline)
        sleep_ms(20);
    if (!still_runs(a, dir, children))
        return 0;
    fprintf(stderr, "biotgrid grid: the broker (pid %ld) still runs %.1f s after SIGTERM: SIGKILL\n",
            a->pid, grace);
    kill((pid_t)a->pid, SIGKILL);
    while (still_runs(a, dir, children))
        sleep_ms(10);
    return 1;
}

/* SIGTERM, then SIGKILL after grace seconds, for every agent of g still
 * running, after the broker. Returns how many agents needed SIGKILL. */
static int stop_agents(grid *g, const char *dir, double grace, int children)
{
    stop_broker(g, dir, grace, children);
    for (int i = 0; i < g->count; i++)
        if (still_runs(&g->agent[i], dir, children))
            kill((pid_t)g->agent[i].pid, SIGTERM);
    const double deadline = bg_clock_now() + grace;
    int killed = 0;
    for (int i = 0; i < g->count; i++) {
        grid_agent *a = &g->agent[i];
        while (still_runs(a, dir, children) && bg_clock_now() < deadline)
            sleep_ms(20);
        if (still_runs(a, dir, children)) {
            fprintf(stderr,
                    "biotgrid grid: %s (pid %ld) still runs %.1f s after SIGTERM: "
                    "SIGKILL\n",
                    a->spec.name, a->pid, grace);
            kill((pid_t)a->pid, SIGKILL);
            killed++;
        }
    }
    for (int i = 0; i < g->count; i++) /* SIGKILL is not instant either */
        while (still_runs(&g->agent[i], dir, children))
            sleep_ms(10);
    return killed;
}

static int write_state(const grid *g, const char *dir)
{
    cJSON *root = cJSON_CreateObject(), *arr = cJSON_AddArrayToObject(root, "agents");
    cJSON_AddStringToObject(root, "name", g->name);
    cJSON_AddStringToObject(root, "security", g->curve ? "curve" : "none");
    for (int i = 0; i < g->count; i++) {
        cJSON *a = cJSON_CreateObject();
        cJSON_AddStringToObject(a, "name", g->agent[i].spec.name);
        cJSON_AddStringToObject(a, "endpoint", g->agent[i].endpoint);
        cJSON_AddNumberToObject(a, "pid", (double)g->agent[i].pid);
        cJSON_AddNumberToObject(a, "start_time", (double)g->agent[i].start_time);
        cJSON_AddStringToObject(a, "services", g->agent[i].spec.services);
        cJSON_AddNumberToObject(a, "slots", g->agent[i].spec.slots);
        cJSON_AddItemToArray(arr, a);
    }
    if (g->has_broker) {
        cJSON *br = cJSON_AddObjectToObject(root, "broker");
        cJSON_AddStringToObject(br, "url", g->broker_url);
        cJSON_AddStringToObject(br, "endpoint", g->broker.endpoint);
        cJSON_AddNumberToObject(br, "pid", (double)g->broker.pid);
        cJSON_AddNumberToObject(br, "start_time", (double)g->broker.start_time);
    }
    char *text = cJSON_Print(root);
    cJSON_Delete(root);
    char path[PATH_MAX], tmp[PATH_MAX];
    if (!text || path_join(path, sizeof path, dir, "grid.json") ||
        path_join(tmp, sizeof tmp, dir, "grid.json.tmp")) {
        free(text);
        return -1;
    }
    FILE *f = fopen(tmp, "w");
    int ok = f && fputs(text, f) >= 0;
    if (f && fclose(f) != 0)
        ok = 0;
    free(text);
    if (!ok || rename(tmp, path) != 0) {
        fprintf(stderr, "biotgrid grid: cannot write %s: %s\n", path, strerror(errno));
        return -1;
    }
    return 0;
}

/* A process's recorded start time (0: not recorded, an older state file). */
static unsigned long long recorded_start(const cJSON *obj)
{
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(obj, "start_time");
    return cJSON_IsNumber(t) && t->valuedouble > 0 ? (unsigned long long)t->valuedouble : 0;
}

/* The recorded grid; 1 when there is none, 2 when it is malformed. */
static int read_state(const char *dir, grid *g)
{
    memset(g, 0, sizeof *g);
    char path[PATH_MAX];
    if (path_join(path, sizeof path, dir, "grid.json"))
        return 2;
    if (access(path, F_OK) != 0)
        return 1;
    cJSON *root = read_json(path, 1 << 20);
    if (!root)
        return 2;
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(root, "name");
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "agents");
    int rc = cJSON_IsString(name) && cJSON_IsArray(arr) ? 0 : 2;
    if (rc == 0)
        snprintf(g->name, sizeof g->name, "%s", name->valuestring);
    const cJSON *security = cJSON_GetObjectItemCaseSensitive(root, "security");
    g->curve = cJSON_IsString(security) && strcmp(security->valuestring, "curve") == 0;
    for (const cJSON *a = rc == 0 ? arr->child : NULL; a && g->count < GRID_MAX_AGENTS;
         a = a->next) {
        const cJSON *n = cJSON_GetObjectItemCaseSensitive(a, "name");
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(a, "endpoint");
        const cJSON *p = cJSON_GetObjectItemCaseSensitive(a, "pid");
        const cJSON *s = cJSON_GetObjectItemCaseSensitive(a, "services");
        if (!cJSON_IsString(n) || !cJSON_IsString(e) || !cJSON_IsNumber(p) || !cJSON_IsString(s)) {
            rc = 2;
            break;
        }
        grid_agent *ga = &g->agent[g->count++];
        snprintf(ga->spec.name, sizeof ga->spec.name, "%s", n->valuestring);
        snprintf(ga->spec.services, sizeof ga->spec.services, "%s", s->valuestring);
        snprintf(ga->endpoint, sizeof ga->endpoint, "%s", e->valuestring);
        ga->pid = (long)p->valuedouble;
        ga->start_time = recorded_start(a);
    }
    const cJSON *br = cJSON_GetObjectItemCaseSensitive(root, "broker");
    if (rc == 0 && br) {
        const cJSON *u = cJSON_GetObjectItemCaseSensitive(br, "url");
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(br, "endpoint");
        const cJSON *p = cJSON_GetObjectItemCaseSensitive(br, "pid");
        if (cJSON_IsString(u) && cJSON_IsString(e) && cJSON_IsNumber(p)) {
            broker_defaults(g);
            snprintf(g->broker_url, sizeof g->broker_url, "%s", u->valuestring);
            snprintf(g->broker.endpoint, sizeof g->broker.endpoint, "%s", e->valuestring);
            g->broker.pid = (long)p->valuedouble;
            g->broker.start_time = recorded_start(br);
        } else {
            rc = 2;
        }
    }
    if (rc == 2)
        fprintf(stderr, "biotgrid grid: %s: not a grid state file\n", path);
    cJSON_Delete(root);
    return rc;
}

/* Forks `self ARGS... --ready-file DIR/NAME.ready` in its own session,
 * output to DIR/NAME.log; the ready file comes last so that is_our_agent
 * finds it in the command line. */
static long spawn_process(const char *self, const char *dir, const char *name,
                          const char *const *args)
{
    char ready[PATH_MAX], log[PATH_MAX], tmp[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s.ready", name);
    if (path_join(ready, sizeof ready, dir, tmp))
        return -1;
    snprintf(tmp, sizeof tmp, "%s.log", name);
    if (path_join(log, sizeof log, dir, tmp))
        return -1;
    const char *argv[32];
    int n = 0;
    argv[n++] = self;
    for (int i = 0; args[i] && n < 29; i++)
        argv[n++] = args[i];
    argv[n++] = "--ready-file";
    argv[n++] = ready;
    argv[n] = NULL;
    unlink(ready);
    fflush(NULL);
    const pid_t pid = fork();
    if (pid != 0)
        return (long)pid;
    setsid();
    const int fd = open(log, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int null = open("/dev/null", O_RDONLY);
    if (fd >= 0) {
        dup2(fd, 1);
        dup2(fd, 2);
    }
    if (null >= 0)
        dup2(null, 0);
    execv(self, (char *const *)argv);
    _exit(127);
}

/* broker: the broker's ROUTER endpoint the agent sells on, or NULL; with
 * it the host's cores and memory when the config gives them. */
static long spawn_agent(const char *self, const char *dir, const grid *g, const grid_agent *a,
                        const char *broker)
{
    char slots[16], key[PATH_MAX], broker_key[PATH_MAX];
    snprintf(slots, sizeof slots, "%d", a->spec.slots);
    const char *args[24] = {"agent",   "--listen", a->spec.listen, "--services", a->spec.services,
                            "--slots", slots,      "--name",       a->spec.name};
    int n = 9;
    if (g->curve) {
        snprintf(key, sizeof key, "%s/%s/%s%s", dir, GRID_KEYS, a->spec.name,
                 BGA_CURVE_SECRET_SUFFIX);
        snprintf(broker_key, sizeof broker_key, "%s/%s/%s%s", dir, GRID_KEYS, GRID_BROKER_NAME,
                 BGA_CURVE_PUBLIC_SUFFIX);
        args[n++] = "--curve-key";
        args[n++] = key;
        args[n++] = "--broker-key";
        args[n++] = broker_key;
    }
    if (broker) {
        args[n++] = "--broker";
        args[n++] = broker;
        if (g->cores[0]) {
            args[n++] = "--cores";
            args[n++] = g->cores;
        }
        if (g->memory[0]) {
            args[n++] = "--memory";
            args[n++] = g->memory;
        }
    }
    args[n] = NULL;
    return spawn_process(self, dir, a->spec.name, args);
}

/* DIR/broker.json: the broker's settings. It has no fixed pool: the
 * agents, started after it, register on its market. */
static int write_broker_config(const grid *g, const char *dir, char *path, size_t cap)
{
    char store[PATH_MAX];
    if (path_join(path, cap, dir, "broker.json") || path_join(store, sizeof store, dir, "broker"))
        return -1;
    cJSON *root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "name", g->name);
    cJSON_AddNumberToObject(root, "port", g->broker_port);
    cJSON_AddStringToObject(root, "endpoint", g->broker.spec.listen);
    cJSON_AddStringToObject(root, "state_dir", store);
    if (g->market[0])
        cJSON_AddItemToObject(root, "market", cJSON_Parse(g->market));
    cJSON *settings = g->settings[0] ? cJSON_Parse(g->settings) : NULL;
    for (cJSON *k = settings ? settings->child : NULL; k; k = k->next)
        cJSON_AddItemToObject(root, k->string, cJSON_Duplicate(k, 1));
    cJSON_Delete(settings);
    if (g->curve) {
        char key[PATH_MAX], authorized[PATH_MAX];
        snprintf(key, sizeof key, "%s/%s/%s%s", dir, GRID_KEYS, GRID_BROKER_NAME,
                 BGA_CURVE_SECRET_SUFFIX);
        snprintf(authorized, sizeof authorized, "%s/%s", dir, GRID_AUTHORIZED);
        cJSON_AddStringToObject(root, "curve_key", key);
        cJSON_AddStringToObject(root, "authorized_agents", authorized);
    }
    char *text = cJSON_Print(root);
    cJSON_Delete(root);
    FILE *f = text ? fopen(path, "w") : NULL;
    int ok = f && fputs(text, f) >= 0;
    if (f && fclose(f) != 0)
        ok = 0;
    free(text);
    if (!ok)
        fprintf(stderr, "biotgrid grid: cannot write %s: %s\n", path, strerror(errno));
    return ok ? 0 : -1;
}

/* For `up`, whose children the agents are: whether child pid has exited
 * (reaping it). Before its exec a child's command line is still this
 * one's, so is_our_agent cannot tell yet. */
static int child_exited(long pid)
{
    int status;
    return waitpid((pid_t)pid, &status, WNOHANG) == (pid_t)pid;
}

static int still_runs(grid_agent *a, const char *dir, int children)
{
    if (a->pid <= 0)
        return 0;
    int gone;
    if (children) {
        gone = child_exited(a->pid);
    } else {
        /* Known by PID: ours while the process with the recorded start
         * time lives, through its exit. */
        gone = !runs_now(a, dir);
        if (!gone && !a->start_time)
            (void)proc_state(a->pid, &a->start_time);
    }
    if (gone) {
        a->pid = 0;
        return 0;
    }
    return 1;
}

static int read_ready_file(const char *dir, grid_agent *a)
{
    char path[PATH_MAX], tmp[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s.ready", a->spec.name);
    if (path_join(path, sizeof path, dir, tmp))
        return -1;
    FILE *f = fopen(path, "r");
    if (!f)
        return -1;
    long pid = 0;
    const int n = fscanf(f, "%255s %ld", a->endpoint, &pid);
    fclose(f);
    return n == 2 && pid == a->pid ? 0 : -1;
}

/* The broker's ready file: "URL ENDPOINT PID". */
static int read_broker_ready(const char *dir, grid *g)
{
    char path[PATH_MAX];
    if (path_join(path, sizeof path, dir, GRID_BROKER_NAME ".ready"))
        return -1;
    FILE *f = fopen(path, "r");
    if (!f)
        return -1;
    long pid = 0;
    const int n = fscanf(f, "%127s %255s %ld", g->broker_url, g->broker.endpoint, &pid);
    fclose(f);
    return n == 3 && pid == g->broker.pid ? 0 : -1;
}

/* A CURVE grid's agents are known by their NAME.pub: key_of's answer. */
static bg_status known_key(void *ctx, const char *endpoint, char key[BGA_CURVE_KEY_SIZE],
                           bg_error_t *err)
{
    (void)endpoint;
    (void)err;
    snprintf(key, BGA_CURVE_KEY_SIZE, "%s", (const char *)ctx);
    return BG_OK;
}

/* Pings agent a; over CURVE as the broker (the one key agents admit),
 * expecting the agent's key from DIR/keys. */
static int ping(const grid *g, const char *dir, const grid_agent *a, bga_agent_status_t *st,
                char *msg, size_t cap)
{
    bga_client_t *c = NULL;
    bg_error_t err = BG_ERROR_INIT;
    bga_curve_keypair_t pair;
    char key[BGA_CURVE_KEY_SIZE] = "", path[PATH_MAX];
    bga_curve_peers_t peers = {&pair, known_key, key};
    bg_status s = BG_OK;
    if (g->curve) {
        snprintf(path, sizeof path, "%s/%s/%s%s", dir, GRID_KEYS, GRID_BROKER_NAME,
                 BGA_CURVE_SECRET_SUFFIX);
        s = bga_curve_read_secret(path, &pair, &err);
        snprintf(path, sizeof path, "%s/%s/%s%s", dir, GRID_KEYS, a->spec.name,
                 BGA_CURVE_PUBLIC_SUFFIX);
        if (s == BG_OK)
            s = bga_curve_read_public(path, key, &err);
    }
    if (s == BG_OK)
        s = bga_client_new_curve(a->endpoint, a->spec.services, GRID_PING_MS,
                                 g->curve ? &peers : NULL, &c, &err);
    memset(&pair, 0, sizeof pair);
    if (s == BG_OK)
        s = bga_client_heartbeat(c, 0, st, &err);
    bga_client_destroy(&c);
    if (s != BG_OK)
        snprintf(msg, cap, "%s", err.message);
    return s == BG_OK ? 0 : -1;
}

static int any_alive(const grid *g, const char *dir)
{
    for (int i = 0; i < g->count; i++)
        if (runs_now(&g->agent[i], dir))
            return 1;
    return g->has_broker && runs_now(&g->broker, dir);
}

/* Starts the broker once the agents are ready; 1 on failure (the caller stops everything). */
static int start_broker(grid *g, const char *self, const char *dir)
{
    char config[PATH_MAX];
    if (write_broker_config(g, dir, config, sizeof config) != 0)
        return 1;
    const char *args[] = {"broker", "--config", config, NULL};
    g->broker.pid = spawn_process(self, dir, GRID_BROKER_NAME, args);
    if (g->broker.pid < 0) {
        fprintf(stderr, "biotgrid grid: cannot start the broker: %s\n", strerror(errno));
        g->broker.pid = 0;
        return 1;
    }
    const double deadline = bg_clock_now() + GRID_READY_SECONDS;
    int exited = 0;
    while (read_broker_ready(dir, g) != 0 && bg_clock_now() < deadline &&
           !(exited = child_exited(g->broker.pid)))
        sleep_ms(20);
    if (exited)
        g->broker.pid = 0;
    if (read_broker_ready(dir, g) != 0) {
        fprintf(stderr, "biotgrid grid: the broker %s (see %s/%s.log)\n",
                exited ? "exited before it was ready" : "did not become ready within 10 s", dir,
                GRID_BROKER_NAME);
        return 1;
    }
    (void)proc_state(g->broker.pid, &g->broker.start_time);
    printf("%-12s %-28s pid %-7ld REST %s\n", GRID_BROKER_NAME, g->broker.endpoint,
           g->broker.pid, g->broker_url);
    return 0;
}

/* The local user's name as a token's user ("local" when it has none a
 * token may carry). */
static void local_user(char *out, size_t size)
{
    const char *env = getenv("USER");
    const struct passwd *pw = getpwuid(getuid());
    const char *name = env && bgb_tokens_valid_user(env) ? env
                       : pw && bgb_tokens_valid_user(pw->pw_name) ? pw->pw_name
                                                                  : "local";
    snprintf(out, size, "%s", name);
}

/* An admin token for the local user in DIR/token (0600), which every
 * client command reads by default: the README's commands need no option. */
static int write_token(const char *dir)
{
    char state[PATH_MAX], path[PATH_MAX], user[BGB_USER_MAX + 1];
    char token[BGB_TOKEN_SIZE], message[BG_ERROR_MESSAGE_MAX + 64];
    local_user(user, sizeof user);
    if (path_join(state, sizeof state, dir, "broker") || path_join(path, sizeof path, dir,
                                                                    BG_CMD_TOKEN_FILE))
        return -1;
    if (bg_cmd_token_make(state, user, 1, token, sizeof token, message, sizeof message) != 0) {
        fprintf(stderr, "biotgrid grid: cannot make a token: %s\n", message);
        return -1;
    }
    char line[BGB_TOKEN_SIZE + 2];
    snprintf(line, sizeof line, "%s\n", token);
    bg_error_t err = BG_ERROR_INIT;
    if (bg_file_write_all(path, line, strlen(line), 0600, &err) != BG_OK) {
        fprintf(stderr, "biotgrid grid: %s\n", err.message);
        return -1;
    }
    printf("%-12s an admin token for %s in %s\n", "token", user, path);
    return 0;
}

/*
 * A grid without keys stays on this machine: with "security": "none" every
 * endpoint must be loopback; "curve" needs the broker that holds the
 * agents' keys. 2 with the message, else 0.
 */
static int check_security(const grid *g, const char *file)
{
    if (g->curve && !g->has_broker) {
        fprintf(stderr,
                "biotgrid grid: %s: security \"curve\" needs a \"broker\" object (or "
                "--broker-port): the broker holds the agents' keys\n",
                file);
        return 2;
    }
    if (g->curve)
        return 0;
    const char *where = NULL, *endpoint = NULL;
    char agent[96];
    if (g->has_broker && !bga_curve_endpoint_is_loopback(g->broker.spec.listen)) {
        where = "broker.endpoint";
        endpoint = g->broker.spec.listen;
    }
    for (int i = 0; !where && i < g->count; i++)
        if (!bga_curve_endpoint_is_loopback(g->agent[i].spec.listen)) {
            snprintf(agent, sizeof agent, "agents[%d].listen", i);
            where = agent;
            endpoint = g->agent[i].spec.listen;
        }
    if (!where)
        return 0;
    fprintf(stderr,
            "biotgrid grid: %s: %s %s is beyond loopback: add \"security\": \"curve\" to the "
            "config (grid up makes the keys) so the grid's links are encrypted\n",
            file, where, endpoint);
    return 2;
}

/* DIR/keys/NAME.{key,pub}: kept when there (checked), else made. */
static int ensure_pair(const char *keys, const char *name)
{
    char prefix[PATH_MAX], secret[PATH_MAX + 8];
    snprintf(prefix, sizeof prefix, "%s/%s", keys, name);
    snprintf(secret, sizeof secret, "%s%s", prefix, BGA_CURVE_SECRET_SUFFIX);
    bga_curve_keypair_t pair;
    bg_error_t err = BG_ERROR_INIT;
    bg_status s = access(secret, F_OK) == 0 ? bga_curve_read_secret(secret, &pair, &err)
                                            : bga_curve_generate(&pair, &err);
    if (s == BG_OK && access(secret, F_OK) != 0)
        s = bga_curve_write(prefix, &pair, &err);
    memset(&pair, 0, sizeof pair);
    if (s != BG_OK) {
        fprintf(stderr, "biotgrid grid: %s\n", err.message);
        return -1;
    }
    return 0;
}

/*
 * The grid's keys: a pair for the broker and for each agent in DIR/keys
 * (0700), and each agent's public key copied to DIR/authorized/NAME.pub,
 * the broker's allowlist (other files there, a remote agent's key, are
 * left as they are).
 */
static int make_keys(const grid *g, const char *dir)
{
    char keys[PATH_MAX], authorized[PATH_MAX];
    bg_error_t err = BG_ERROR_INIT;
    if (path_join(keys, sizeof keys, dir, GRID_KEYS) ||
        path_join(authorized, sizeof authorized, dir, GRID_AUTHORIZED))
        return -1;
    if (bg_file_make_directories_mode(keys, 0700, &err) != BG_OK ||
        bg_file_make_directories_mode(authorized, 0700, &err) != BG_OK) {
        fprintf(stderr, "biotgrid grid: %s\n", err.message);
        return -1;
    }
    if (ensure_pair(keys, GRID_BROKER_NAME) != 0)
        return -1;
    for (int i = 0; i < g->count; i++) {
        char from[PATH_MAX + 80], to[PATH_MAX + 80], key[BGA_CURVE_KEY_SIZE + 1];
        const char *name = g->agent[i].spec.name;
        snprintf(from, sizeof from, "%s/%s%s", keys, name, BGA_CURVE_PUBLIC_SUFFIX);
        snprintf(to, sizeof to, "%s/%s%s", authorized, name, BGA_CURVE_PUBLIC_SUFFIX);
        if (ensure_pair(keys, name) != 0 || bga_curve_read_public(from, key, &err) != BG_OK) {
            if (err.message[0])
                fprintf(stderr, "biotgrid grid: %s\n", err.message);
            return -1;
        }
        strcat(key, "\n");
        if (bg_file_write_all(to, key, strlen(key), 0644, &err) != BG_OK) {
            fprintf(stderr, "biotgrid grid: %s\n", err.message);
            return -1;
        }
    }
    printf("%-12s CURVE: key pairs in %s, the broker admits the keys in %s\n", "security", keys,
           authorized);
    return 0;
}

/* Whether the broker's REST API answers /healthz (no token needed); the
 * reason into msg when it does not. */
static int broker_health(const char *url, char *msg, size_t size)
{
    const bgb_client_config_t config = {
        .url = url, .cacert = bg_cmd_cacert_find(NULL), .connect_timeout_ms = GRID_PING_MS,
        .timeout_ms = GRID_PING_MS};
    bgb_client_t *client = NULL;
    cJSON *doc = NULL;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = bgb_client_new(&config, &client, &err);
    if (st == BG_OK)
        st = bgb_client_health(client, &doc, &err);
    cJSON_Delete(doc);
    bgb_client_destroy(&client);
    if (st != BG_OK)
        snprintf(msg, size, "%s", err.message);
    return st == BG_OK ? 0 : -1;
}

/* The REST port of a recorded URL "http[s]://HOST:PORT" (-1: none). */
static int url_port(const char *url)
{
    const char *colon = strrchr(url, ':');
    char *end = NULL;
    const long p = colon ? strtol(colon + 1, &end, 10) : -1;
    return colon && end && !*end && p > 0 && p <= 65535 ? (int)p : -1;
}

/*
 * `up` on a grid some of whose processes still run: the config must name
 * the same grid (its name and agents). What runs is kept; a dead broker is
 * started again on the endpoint and REST port it had, with its store, so
 * the agents that kept running find it there and its jobs are recovered;
 * dead agents are started again. 1 on failure.
 */
static int adopt_running(grid *g, const grid *old, const char *dir)
{
    if (strcmp(g->name, old->name) != 0 || g->count != old->count) {
        fprintf(stderr,
                "biotgrid grid: another grid (%s, %d agents) is up in %s: `biotgrid grid down "
                "--state %s` first\n",
                old->name, old->count, dir, dir);
        return 1;
    }
    if (g->curve != old->curve) {
        fprintf(stderr,
                "biotgrid grid: the grid up in %s runs with security \"%s\" where the config "
                "says \"%s\": `biotgrid grid down --state %s` first\n",
                dir, old->curve ? "curve" : "none", g->curve ? "curve" : "none", dir);
        return 1;
    }
    for (int i = 0; i < g->count; i++) {
        if (strcmp(g->agent[i].spec.name, old->agent[i].spec.name) != 0) {
            fprintf(stderr,
                    "biotgrid grid: the grid up in %s has agent '%s' where the config has "
                    "'%s': `biotgrid grid down --state %s` first\n",
                    dir, old->agent[i].spec.name, g->agent[i].spec.name, dir);
            return 1;
        }
        if (runs_now(&old->agent[i], dir)) {
            g->agent[i].pid = old->agent[i].pid;
            g->agent[i].start_time = old->agent[i].start_time;
            snprintf(g->agent[i].endpoint, sizeof g->agent[i].endpoint, "%s",
                     old->agent[i].endpoint);
        }
    }
    if (old->has_broker) {
        g->has_broker = 1;
        snprintf(g->broker.spec.listen, sizeof g->broker.spec.listen, "%s", old->broker.endpoint);
        snprintf(g->broker_url, sizeof g->broker_url, "%s", old->broker_url);
        snprintf(g->broker.endpoint, sizeof g->broker.endpoint, "%s", old->broker.endpoint);
        const int port = url_port(old->broker_url);
        if (port > 0)
            g->broker_port = port;
        if (runs_now(&old->broker, dir)) {
            g->broker.pid = old->broker.pid;
            g->broker.start_time = old->broker.start_time;
        }
    }
    return 0;
}

static int grid_up(const char *file, const char *dir, int broker_port, const char *broker_ep)
{
    grid g;
    int rc = read_grid_config(file, &g);
    if (rc)
        return rc;
    if (broker_port >= 0 || broker_ep) {
        if (!g.has_broker)
            g.broker_port = 8080;
        if (broker_ep)
            snprintf(g.broker.spec.listen, sizeof g.broker.spec.listen, "%s", broker_ep);
        broker_defaults(&g);
        if (broker_port >= 0)
            g.broker_port = broker_port;
    }
    if ((rc = check_security(&g, file)) != 0)
        return rc;
    grid old;
    const int adopting = read_state(dir, &old) == 0 && any_alive(&old, dir);
    if (adopting && adopt_running(&g, &old, dir) != 0)
        return 1;
    if (g.curve && make_keys(&g, dir) != 0)
        return 1;
    char self[PATH_MAX];
    const ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n <= 0) {
        fprintf(stderr, "biotgrid grid: cannot find this executable: %s\n", strerror(errno));
        return 1;
    }
    self[n] = 0;
    /* On failure only what this call started is stopped. */
    grid started = g;
    started.count = 0;
    started.has_broker = 0;
    int kept = 0, starting = 0;
    if (g.has_broker && g.broker.pid > 0) {
        printf("%-12s %-28s pid %-7ld REST %s (kept: it runs)\n", GRID_BROKER_NAME,
               g.broker.endpoint, g.broker.pid, g.broker_url);
        kept++;
    } else if (g.has_broker) {
        rc = start_broker(&g, self, dir);
        started.has_broker = 1;
        started.broker = g.broker;
        starting++;
        if (rc != 0) {
            stop_agents(&started, dir, 5.0, 1);
            return 1;
        }
    }
    for (int i = 0; i < g.count; i++) {
        if (g.agent[i].pid > 0)
            continue;
        g.agent[i].pid =
            spawn_agent(self, dir, &g, &g.agent[i], g.has_broker ? g.broker.endpoint : NULL);
        if (g.agent[i].pid < 0) {
            fprintf(stderr, "biotgrid grid: cannot start %s: %s\n", g.agent[i].spec.name,
                    strerror(errno));
            g.agent[i].pid = 0;
            stop_agents(&started, dir, 5.0, 1);
            return 1;
        }
        started.agent[started.count++] = g.agent[i];
        starting++;
    }
    const double deadline = bg_clock_now() + GRID_READY_SECONDS;
    for (int i = 0, k = 0; i < g.count && rc == 0; i++) {
        grid_agent *a = &g.agent[i];
        const int ours = k < started.count && started.agent[k].pid == a->pid;
        int exited = 0;
        if (ours) {
            while (read_ready_file(dir, a) != 0 && bg_clock_now() < deadline &&
                   !(exited = child_exited(a->pid)))
                sleep_ms(20);
            if (exited)
                started.agent[k].pid = a->pid = 0; /* reaped: nothing to stop */
            k++;
        }
        bga_agent_status_t st;
        char msg[BG_ERROR_MESSAGE_MAX] = "";
        if (ours && read_ready_file(dir, a) != 0) {
            fprintf(stderr, "biotgrid grid: %s %s (see %s/%s.log)\n", a->spec.name,
                    exited ? "exited before it was ready" : "did not become ready within 10 s", dir,
                    a->spec.name);
            rc = 1;
        } else if (ping(&g, dir, a, &st, msg, sizeof msg) != 0) {
            fprintf(stderr, "biotgrid grid: %s\n", msg);
            rc = 1;
        } else {
            if (ours)
                (void)proc_state(a->pid, &a->start_time);
            else
                kept++;
            printf("%-12s %-28s pid %-7ld services %-18s slots %lld%s\n", a->spec.name,
                   a->endpoint, a->pid, a->spec.services, (long long)st.slots,
                   ours ? "" : " (kept: it runs)");
        }
    }
    if (rc == 0 && write_state(&g, dir) != 0)
        rc = 1;
    if (rc != 0) {
        stop_agents(&started, dir, 5.0, 1);
        return rc;
    }
    char token_path[PATH_MAX];
    const int has_token = path_join(token_path, sizeof token_path, dir, BG_CMD_TOKEN_FILE) == 0 &&
                          access(token_path, R_OK) == 0;
    /* A kept store keeps its tokens: the user's stays valid. */
    if (g.has_broker && !(adopting && has_token) && write_token(dir) != 0) {
        stop_agents(&started, dir, 5.0, 1);
        return 1;
    }
    if (adopting)
        printf("grid %s up again in %s: %d processes kept, %d started\n", g.name, dir, kept,
               starting);
    else if (g.has_broker)
        printf("grid %s up: %d agents, broker on %s, state in %s/grid.json\n", g.name, g.count,
               g.broker_url, dir);
    else
        printf("grid %s up: %d agents, state in %s/grid.json\n", g.name, g.count, dir);
    return 0;
}

/* Whether the grid started an agent of this name. */
static int ours(const grid *g, const char *name)
{
    for (int i = 0; i < g->count; i++)
        if (strcmp(g->agent[i].spec.name, name) == 0)
            return 1;
    return 0;
}

/*
 * The agents registered with the grid's broker that `up` did not start
 * (GET /v1/agents with the grid's token): one line each, their address,
 * liveness, slots and key. They do not make the grid degraded; a broker
 * that does not answer does (1).
 */
static int other_agents(const grid *g, const char *dir)
{
    char token[BG_CMD_TOKEN_MAX];
    bg_cmd_token_find(NULL, dir, token, sizeof token);
    const bgb_client_config_t cc = {.url = g->broker_url,
                                    .token = token[0] ? token : NULL,
                                    .cacert = bg_cmd_cacert_find(NULL),
                                    .connect_timeout_ms = GRID_PING_MS,
                                    .timeout_ms = 2 * GRID_PING_MS};
    bgb_client_t *client = NULL;
    cJSON *doc = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_client_new(&cc, &client, &err) != BG_OK ||
        bgb_client_agents(client, &doc, &err) != BG_OK) {
        printf("%-12s %-28s the agents it knows are not listed: %s\n", GRID_BROKER_NAME,
               g->broker_url, err.message);
        bgb_client_destroy(&client);
        return 1;
    }
    const cJSON *list = cJSON_GetObjectItemCaseSensitive(doc, "agents"), *a;
    int others = 0;
    cJSON_ArrayForEach(a, list)
    {
        const char *name = bg_cmd_string_of(a, "name"), *source = bg_cmd_string_of(a, "source");
        const cJSON *services = cJSON_GetObjectItemCaseSensitive(a, "services");
        /* Each daemon once: its service seller (its resource seller has no services). */
        if (!name || !source || strcmp(source, "market") != 0 ||
            cJSON_GetArraySize(services) == 0 || ours(g, name))
            continue;
        const char *endpoint = bg_cmd_string_of(a, "endpoint");
        const char *address = bg_cmd_string_of(a, "address");
        const char *key = bg_cmd_string_of(a, "key");
        const double slots = bg_cmd_number_of(a, "slots");
        const double free_slots = bg_cmd_number_of(a, "free_slots");
        printf("%-12s %-28s registered from %s, not started by this grid: %s, %.0f of %.0f slots "
               "free, %s%s\n",
               name, endpoint ? endpoint : "?", address && address[0] ? address : "?",
               cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(a, "alive")) ? "up" : "silent",
               free_slots, slots, key ? "CURVE key " : "no key (plaintext)", key ? key : "");
        others++;
    }
    if (others)
        printf("%-12s %d agent%s registered with the broker beside the grid's\n", "", others,
               others == 1 ? "" : "s");
    cJSON_Delete(doc);
    bgb_client_destroy(&client);
    return 0;
}

static int grid_status(const char *dir)
{
    grid g;
    const int rc = read_state(dir, &g);
    if (rc == 1) {
        printf("no grid is up in %s\n", dir);
        return 1;
    }
    if (rc)
        return rc;
    int bad = 0;
    for (int i = 0; i < g.count; i++) {
        const grid_agent *a = &g.agent[i];
        bga_agent_status_t st;
        char msg[BG_ERROR_MESSAGE_MAX] = "";
        if (!runs_now(a, dir)) {
            printf("%-12s %-28s pid %-7ld not running\n", a->spec.name, a->endpoint, a->pid);
            bad = 1;
        } else if (ping(&g, dir, a, &st, msg, sizeof msg) != 0) {
            printf("%-12s %-28s pid %-7ld not answering: %s\n", a->spec.name, a->endpoint, a->pid,
                   msg);
            bad = 1;
        } else {
            printf("%-12s %-28s pid %-7ld up, %lld jobs, %lld of %lld slots free\n", a->spec.name,
                   a->endpoint, a->pid, (long long)st.jobs, (long long)st.free_slots,
                   (long long)st.slots);
        }
    }
    if (g.has_broker) {
        char msg[BG_ERROR_MESSAGE_MAX] = "";
        if (!runs_now(&g.broker, dir)) {
            printf("%-12s %-28s pid %-7ld not running\n", GRID_BROKER_NAME, g.broker.endpoint,
                   g.broker.pid);
            bad = 1;
        } else if (broker_health(g.broker_url, msg, sizeof msg) != 0) {
            printf("%-12s %-28s pid %-7ld REST %s not answering: %s\n", GRID_BROKER_NAME,
                   g.broker.endpoint, g.broker.pid, g.broker_url, msg);
            bad = 1;
        } else {
            printf("%-12s %-28s pid %-7ld up, REST %s%s\n", GRID_BROKER_NAME, g.broker.endpoint,
                   g.broker.pid, g.broker_url, g.curve ? ", CURVE" : "");
            bad |= other_agents(&g, dir);
        }
    }
    printf("grid %s: %s\n", g.name,
           bad ? "degraded (`biotgrid grid up` again starts what is missing)" : "up");
    return bad;
}

/* How stopping a process went. */
typedef enum { STOP_NOT_RUNNING, STOP_TERM, STOP_KILL, STOP_FAILED } stop_outcome;

/* Signals every process of procs[0..n) that still runs with SIGTERM, waits
 * up to grace seconds for all of them, then SIGKILLs the others and waits
 * at most 5 s more. Each outcome into out[i], with a line saying it into
 * what[i]. Returns how many still run. */
static int stop_processes(grid_agent *const *procs, int n, const char *dir, double grace,
                          stop_outcome *out, char (*what)[160])
{
    long pid[GRID_MAX_AGENTS + 1];
    for (int i = 0; i < n; i++) {
        pid[i] = procs[i]->pid;
        out[i] = STOP_NOT_RUNNING;
        if (!still_runs(procs[i], dir, 0)) {
            unsigned long long start = 0;
            snprintf(what[i], sizeof what[i], "was not running (pid %ld %s)", pid[i],
                     pid[i] > 0 && proc_state(pid[i], &start) ? "is another process now"
                                                              : "is gone");
        } else if (kill((pid_t)pid[i], SIGTERM) != 0) {
            out[i] = STOP_FAILED;
            snprintf(what[i], sizeof what[i], "NOT stopped: SIGTERM to pid %ld: %s", pid[i],
                     strerror(errno));
        } else {
            out[i] = STOP_TERM;
        }
    }
    for (int pass = 0; pass < 2; pass++) {
        const double deadline = bg_clock_now() + (pass == 0 ? grace : 5.0);
        for (int i = 0; i < n; i++)
            while (out[i] != STOP_NOT_RUNNING && out[i] != STOP_FAILED &&
                   still_runs(procs[i], dir, 0) && bg_clock_now() < deadline)
                sleep_ms(pass == 0 ? 20 : 10);
        for (int i = 0; i < n && pass == 0; i++)
            if (out[i] == STOP_TERM && still_runs(procs[i], dir, 0)) {
                kill((pid_t)pid[i], SIGKILL);
                out[i] = STOP_KILL;
            }
    }
    int left = 0;
    for (int i = 0; i < n; i++) {
        if (out[i] == STOP_TERM)
            snprintf(what[i], sizeof what[i], "stopped (pid %ld, SIGTERM)", pid[i]);
        else if (out[i] == STOP_KILL && !still_runs(procs[i], dir, 0))
            snprintf(what[i], sizeof what[i], "stopped (pid %ld, SIGKILL after %.1f s of SIGTERM)",
                     pid[i], grace);
        else if (out[i] == STOP_KILL) {
            out[i] = STOP_FAILED;
            snprintf(what[i], sizeof what[i], "NOT stopped: pid %ld still runs after SIGKILL",
                     pid[i]);
        }
        left += out[i] == STOP_FAILED;
    }
    return left;
}

/*
 * Stops the broker first (its running jobs need the agents), then every
 * agent, each only while it is provably the process the state recorded
 * (PID and start time). Says what it did for each. The state file is
 * removed once nothing of the grid runs; otherwise it is rewritten with
 * what still runs and the exit status is 1.
 */
static int grid_down(const char *dir, double grace)
{
    grid g;
    const int rc = read_state(dir, &g);
    if (rc == 1) {
        printf("no grid is up in %s\n", dir);
        return 0;
    }
    if (rc)
        return rc;
    /* The broker first, alone: its running jobs need the agents. Then the
     * agents, all at once (one grace for all). */
    stop_outcome out[GRID_MAX_AGENTS];
    char what[GRID_MAX_AGENTS][160];
    grid_agent *procs[GRID_MAX_AGENTS];
    int left = 0, stopped = 0;
    if (g.has_broker) {
        procs[0] = &g.broker;
        left += stop_processes(procs, 1, dir, grace, out, what);
        printf("%-12s %s\n", GRID_BROKER_NAME, what[0]);
        stopped += out[0] == STOP_TERM || out[0] == STOP_KILL;
    }
    for (int i = 0; i < g.count; i++)
        procs[i] = &g.agent[i];
    left += stop_processes(procs, g.count, dir, grace, out, what);
    for (int i = 0; i < g.count; i++) {
        printf("%-12s %s\n", g.agent[i].spec.name, what[i]);
        stopped += out[i] == STOP_TERM || out[i] == STOP_KILL;
    }
    char path[PATH_MAX];
    if (left) {
        /* Keep the record of what still runs, so a later `down` finds it. */
        grid rest = g;
        rest.count = 0;
        for (int i = 0; i < g.count; i++)
            if (g.agent[i].pid > 0)
                rest.agent[rest.count++] = g.agent[i];
        rest.has_broker = g.has_broker && g.broker.pid > 0;
        (void)write_state(&rest, dir);
        printf("grid %s: %d processes stopped, %d still run: the state in %s/grid.json "
               "keeps them\n",
               g.name, stopped, left, dir);
        return 1;
    }
    if (path_join(path, sizeof path, dir, "grid.json") == 0)
        unlink(path);
    printf("grid %s down: %d processes stopped, none of the grid runs\n", g.name, stopped);
    return 0;
}

const char bg_cmd_grid_usage[] =
    "usage: biotgrid grid up [FILE] [--state DIR] [--broker-port N] [--broker-endpoint EP]\n"
    "       biotgrid grid status [--state DIR]\n"
    "       biotgrid grid down [--state DIR] [--grace SECONDS]\n"
    "FILE defaults to configs/grids/local.json, DIR to $BIOTGRID_GRID_DIR or out/grid.\n"
    "With a \"broker\" object in FILE (or a --broker-* option) `up` also starts the\n"
    "broker (REST on --broker-port, 0: an ephemeral port; agents' endpoint\n"
    "--broker-endpoint) and `down` stops it first. The agents sell the machine's\n"
    "cores and memory on the broker's market, one of them for all (the others stand\n"
    "by); a \"host\" object in FILE, {\"cores\": N, \"memory\": GIB}, says how many.\n"
    "\"security\": \"curve\" in FILE encrypts every ZeroMQ link of the grid: `up` keeps a\n"
    "key pair per process in DIR/keys and the broker admits the agents' public keys\n"
    "in DIR/authorized (add a remote agent's NAME.pub there); without it every\n"
    "endpoint must be loopback. `status` also lists the agents registered with the\n"
    "broker that `up` did not start, with their address and key.\n";

static void usage(FILE *out)
{
    fputs(bg_cmd_grid_usage, out);
}

int bg_cmd_grid(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    const char *sub = argv[1], *file = "configs/grids/local.json";
    const char *dir = bg_cmd_grid_dir(NULL);
    double grace = 5.0;
    int broker_port = -1;
    const char *broker_ep = NULL;
    if (strcmp(sub, "--help") == 0 || strcmp(sub, "-h") == 0) {
        usage(stdout);
        return 0;
    }
    for (int i = 2; i < argc; i++) {
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            usage(stdout); /* one page for the three verbs: `grid up --help` too */
            return 0;
        } else if (strcmp(argv[i], "--state") == 0 && i + 1 < argc) {
            dir = argv[++i];
        } else if (strcmp(argv[i], "--grace") == 0 && i + 1 < argc) {
            char *end;
            grace = strtod(argv[++i], &end);
            if (*end || !(grace >= 0.0 && grace <= 600.0)) {
                fprintf(stderr,
                        "biotgrid grid: --grace '%s' is not a number of seconds in "
                        "[0, 600]\n",
                        argv[i]);
                return 2;
            }
        } else if (strcmp(argv[i], "--broker-port") == 0 && i + 1 < argc &&
                   strcmp(sub, "up") == 0) {
            char *end;
            const long p = strtol(argv[++i], &end, 10);
            if (*end || p < 0 || p > 65535) {
                fprintf(stderr, "biotgrid grid: --broker-port '%s' is not a port in [0, 65535]\n",
                        argv[i]);
                return 2;
            }
            broker_port = (int)p;
        } else if (strcmp(argv[i], "--broker-endpoint") == 0 && i + 1 < argc &&
                   strcmp(sub, "up") == 0) {
            broker_ep = argv[++i];
            if (strncmp(broker_ep, "tcp://", 6) != 0 || strlen(broker_ep) >= BGA_AGENT_ENDPOINT_MAX) {
                fprintf(stderr, "biotgrid grid: --broker-endpoint '%s' is not tcp://HOST:PORT\n",
                        broker_ep);
                return 2;
            }
        } else if (argv[i][0] != '-' && strcmp(sub, "up") == 0 && i == 2) {
            file = argv[i];
        } else {
            fprintf(stderr, "biotgrid grid: unexpected argument '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    const int up = strcmp(sub, "up") == 0;
    if (!up && strcmp(sub, "status") != 0 && strcmp(sub, "down") != 0) {
        fprintf(stderr, "biotgrid grid: unknown subcommand '%s'\n", sub);
        usage(stderr);
        return 2;
    }
    /* One grid, one name: ./x, x and /abs/x are the same state folder, and
     * the processes' command lines name it canonically. */
    if (up && bg_cmd_make_directories(dir) != 0) {
        fprintf(stderr, "biotgrid grid: cannot create %s: %s\n", dir, strerror(errno));
        return 1;
    }
    char canonical[PATH_MAX];
    if (bg_file_canonical(dir, canonical, sizeof canonical) != 0) {
        if (errno == ENOENT && !up) {
            printf("no grid is up in %s (no such folder)\n", dir);
            return strcmp(sub, "down") == 0 ? 0 : 1;
        }
        fprintf(stderr, "biotgrid grid: %s: %s\n", dir, strerror(errno));
        return 1;
    }
    if (up)
        return grid_up(file, canonical, broker_port, broker_ep);
    if (strcmp(sub, "status") == 0)
        return grid_status(canonical);
    if (strcmp(sub, "down") == 0)
        return grid_down(canonical, grace);
    fprintf(stderr, "biotgrid grid: unknown subcommand '%s'\n", sub);
    usage(stderr);
    return 2;
}
