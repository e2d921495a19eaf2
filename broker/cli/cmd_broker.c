/*
 * biotgrid broker [--config FILE] [--address A] [--port N] [--tls-cert F --tls-key F]
 *                 [--insecure] [--endpoint EP] [--state-dir DIR] [--ready-file FILE]
 *
 * Starts the broker, prints "broker NAME ready on URL, agents at
 * ENDPOINT" (URL http[s]://ADDR:PORT), writes "URL ENDPOINT PID" to the ready file
 * if asked (written to a temporary name and renamed, so a reader never
 * sees half a line), and runs until SIGTERM or SIGINT.
 */
#include "cmd_broker.h"

#include "cmd.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bgb_broker.h"

const char bg_cmd_broker_usage[] =
    "usage: biotgrid broker [--config FILE] [--address A] [--port N]\n"
    "                       [--tls-cert FILE --tls-key FILE] [--insecure]\n"
    "                       [--endpoint ENDPOINT] [--state-dir DIR] [--ready-file FILE]\n"
    "Runs the broker: the REST API (default http://127.0.0.1:8080), the job store\n"
    "(STATE_DIR/broker.sqlite, default out/broker) and the ZeroMQ endpoint agents\n"
    "connect to (default tcp://127.0.0.1:5570), until SIGTERM or SIGINT.\n"
    "  --config FILE       JSON object with keys name, address, port, tls_cert,\n"
    "                      tls_key, insecure, endpoint,\n"
    "                      state_dir, max_jobs, agent_timeout_ms, the limits\n"
    "                      (memory_fraction, max_vertices, max_elements, max_work,\n"
    "                      max_body, max_jobs_in_flight, max_stored_bytes,\n"
    "                      max_connections, max_connections_per_client,\n"
    "                      idle_timeout, request_timeout; printed at start),\n"
    "                      agents ([{\"endpoint\", \"services\"}]),\n"
    "                      market ({period, k, heartbeat_timeout, reply_timeout,\n"
    "                      buy_timeout, overlay_degree, hops, max_rounds,\n"
    "                      max_contracts}: the live market's settings)\n"
    "  --address A         REST IPv4 address (default 127.0.0.1; 0.0.0.0: every one)\n"
    "  --port N            REST port (0: an ephemeral one); overrides the config\n"
    "  --tls-cert FILE     serve REST over TLS with this PEM certificate (chain)...\n"
    "  --tls-key FILE      ...and its PEM private key; clients trust it with --cacert\n"
    "  --insecure          serve plain HTTP beyond loopback anyway: without TLS an\n"
    "                      address other than 127.x is refused, as it would show\n"
    "                      every bearer token to the network\n"
    "  --endpoint EP       ZeroMQ ROUTER endpoint (port * : an ephemeral one)\n"
    "  --state-dir DIR     where the store and the jobs' folders live\n"
    "  --ready-file FILE   write \"URL ENDPOINT PID\" there once serving\n"
    "Agents started with `biotgrid agent --broker ENDPOINT` sell on its live market;\n"
    "each job buys its plan's services there (its mechanism: central, catallactic or\n"
    "posted; at most its budget) and runs on the agents it bought. With no agent on\n"
    "the market, a job runs on the config's agents without contracts, or waits.\n";

static int set_string(char **slot, const char *value)
{
    char *copy = strdup(value);
    if (!copy)
        return -1;
    free(*slot);
    *slot = copy;
    return 0;
}

int bg_cmd_broker(int argc, char **argv)
{
    bg_error_t err = BG_ERROR_INIT;
    bgb_config_t config;
    bgb_broker_t *broker = NULL;
    const char *ready_file = NULL;
    int rc = BG_EXIT_BAD_INPUT;
    if (bgb_config_init(&config, &err) != BG_OK) {
        fprintf(stderr, "biotgrid broker: %s\n", err.message);
        return BG_EXIT_FAILED;
    }
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bg_cmd_broker_usage, stdout);
            rc = BG_EXIT_OK;
            goto out;
        }
        if (strcmp(a, "--insecure") == 0) {
            config.insecure = 1;
            continue;
        }
        static const char *const valued[] = {"--config",   "--port",     "--endpoint",
                                             "--state-dir", "--ready-file", "--address",
                                             "--tls-cert", "--tls-key",  NULL};
        int known = 0;
        for (int k = 0; valued[k]; k++)
            known |= strcmp(a, valued[k]) == 0;
        if (!known) {
            fprintf(stderr, "biotgrid broker: unknown option '%s' (see biotgrid broker --help)\n",
                    a);
            goto out;
        }
        if (i + 1 == argc) {
            fprintf(stderr, "biotgrid broker: %s needs a value\n", a);
            goto out;
        }
        const char *v = argv[++i];
        if (strcmp(a, "--config") == 0) {
            if (bgb_config_read(v, &config, &err) != BG_OK) {
                fprintf(stderr, "biotgrid broker: %s\n", err.message);
                goto out;
            }
        } else if (strcmp(a, "--port") == 0) {
            char *end = NULL;
            const long p = strtol(v, &end, 10);
            if (!end || *end || p < 0 || p > 65535) {
                fprintf(stderr, "biotgrid broker: --port '%s' must be an integer in [0, 65535]\n",
                        v);
                goto out;
            }
            config.port = (int)p;
        } else if (strcmp(a, "--ready-file") == 0) {
            ready_file = v;
        } else if (set_string(strcmp(a, "--endpoint") == 0    ? &config.endpoint
                              : strcmp(a, "--address") == 0   ? &config.address
                              : strcmp(a, "--tls-cert") == 0  ? &config.tls_cert
                              : strcmp(a, "--tls-key") == 0   ? &config.tls_key
                                                              : &config.state_dir,
                              v) != 0) {
            fprintf(stderr, "biotgrid broker: out of memory\n");
            rc = BG_EXIT_FAILED;
            goto out;
        }
    }
    bg_cmd_stop_on_signals();
    if (bgb_broker_start(&config, &broker, &err) != BG_OK) {
        fprintf(stderr, "biotgrid broker: %s\n", err.message);
        rc = err.status == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_FAILED;
        goto out;
    }
    char url[128];
    if (bgb_broker_rest_url(broker, url, sizeof url) != 0) {
        fprintf(stderr, "biotgrid broker: the REST address %s is too long\n", config.address);
        rc = BG_EXIT_BAD_INPUT;
        goto out;
    }
    char ready[1024];
    const int ready_length = snprintf(ready, sizeof ready, "%s %s %ld\n", url,
                                      bgb_broker_endpoint(broker), (long)getpid());
    if (ready_file && (ready_length >= (int)sizeof ready ||
                       bg_cmd_write_ready_file(ready_file, ready) != 0)) {
        fprintf(stderr, "biotgrid broker: cannot write the ready file %s\n", ready_file);
        rc = BG_EXIT_FAILED;
        goto out;
    }
    char limits[1024];
    bgb_limits_describe(bgb_broker_limits(broker), bgb_limits_ram(), limits, sizeof limits);
    printf("broker %s ready on %s, agents at %s\nlimits:\n%s", config.name, url,
           bgb_broker_endpoint(broker), limits);
    fflush(stdout);
    bg_cmd_wait_for_stop();
    rc = BG_EXIT_OK;
out:
    bgb_broker_stop(&broker);
    bgb_config_release(&config);
    return rc;
}
