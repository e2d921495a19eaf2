/* cmd_agent — `biotgrid agent`: runs one agent daemon (bga_agent). */
#ifndef CMD_AGENT_H
#define CMD_AGENT_H

#include <cjson/cJSON.h>

#include "bga_agent.h"

/* What one agent is started with: the config keys of `agent --config`
 * and of each entry of a grid config's "agents". */
typedef struct bg_agent_spec {
    char listen[BGA_AGENT_ENDPOINT_MAX];
    char services[128];
    char name[64];
    int slots;
} bg_agent_spec_t;

/* Defaults: tcp://127.0.0.1:* (an ephemeral port), all services, 4 slots. */
void bg_agent_spec_default(bg_agent_spec_t *spec);

/*
 * Reads the keys listen, services, slots and name of a JSON object into
 * spec (keys absent keep their value). Unknown keys, wrong types, bad
 * values: a message naming `where` and the key on stderr, and 2.
 */
int bg_agent_spec_parse(const cJSON *obj, const char *where, bg_agent_spec_t *spec);

/* argv[0] is "agent". Returns the exit status: 0 after SIGTERM/SIGINT,
 * 1 when the loop fails, 2 on bad options or a bad config. */
/* The --help text, also `biotgrid help agent` and the manual page. */
extern const char bg_cmd_agent_usage[];

int bg_cmd_agent(int argc, char **argv);

#endif
