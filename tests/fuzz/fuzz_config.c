/*
 * fuzz_config — the market experiment's config (bgm_config_parse): the
 * whole input is the JSON text. A config that parses is walked as the
 * experiment runner walks it (every scenario, its agent count, topology
 * and stream index).
 */
#include <stdlib.h>

#include "bgm_config.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    uint8_t *text = NULL;
    size_t length = 0;
    bgm_config_t *cfg = malloc(sizeof *cfg);
    if (cfg && fuzz_take_rest(&in, &text, &length) == 1) {
        bg_error_t err = BG_ERROR_INIT;
        if (bgm_config_parse((const char *)text, length, "fuzz.json", cfg, &err) == BG_OK) {
            const int scenarios = bgm_config_scenario_count(cfg);
            for (int s = 0; s < scenarios; s++) {
                int nodes = 0;
                double density = 0.0;
                const bgm_dynamics_t *dynamics = NULL;
                bgm_config_scenario(cfg, s, &nodes, &density, &dynamics);
                if (!dynamics || bgm_config_agent_count(cfg, nodes, density) < 1)
                    abort();
                const int topology = bgm_config_scenario_topology(cfg, s);
                const int stream = bgm_config_scenario_stream(cfg, s);
                if (topology < 0 || topology >= BGM_TOPOLOGIES || stream < 0 || stream > s)
                    abort();
            }
        } else if (!err.message[0]) {
            abort();
        }
    }
    free(cfg);
    free(text);
    return 0;
}
