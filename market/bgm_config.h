/*
 * bgm_config — experiment configuration: parsing and validation.
 *
 * An experiment is a JSON object (see README "Market experiments"). Every
 * key is checked: unknown keys, wrong types, out-of-range values and
 * missing required fields are rejected with a message naming the field by
 * its path ("factors.nodes[2]"). Parsing is a pure function over a buffer.
 * The scenarios are the Cartesian product [topology x] nodes x density x
 * dynamics, in that nesting order (topology slowest, when it is a factor).
 */
#ifndef BGM_CONFIG_H
#define BGM_CONFIG_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

#define BGM_SERVICE_TYPES 3
#define BGM_MAX_MECHANISMS 3
#define BGM_MAX_LEVELS 8
#define BGM_MAX_DYNAMICS 8
#define BGM_MAX_PLANS 8
#define BGM_NAME_MAX 64
#define BGM_PATH_MAX 1024
#define BGM_CONFIG_MAX_BYTES (1 << 20)
#define BGM_MAX_NODES 20000
#define BGM_MAX_REPLICATIONS 1000

typedef enum bgm_mechanism {
    BGM_MECH_CENTRAL = 0,
    BGM_MECH_CATALLACTIC = 1,
    BGM_MECH_BASELINE = 2
} bgm_mechanism;

/* How the central market clears the resource layer: the combinatorial
 * exchange for whole bundles, or a call market per resource type. */
typedef enum bgm_resource_market { BGM_RM_EXCHANGE = 0, BGM_RM_CALL = 1 } bgm_resource_market;

typedef enum bgm_topology {
    BGM_TOPO_STAR = 0,
    BGM_TOPO_CLUSTER = 1,
    BGM_TOPO_RANDOM = 2,
    BGM_TOPO_SCALEFREE = 3
} bgm_topology;
#define BGM_TOPOLOGIES 4

extern const char *const bgm_service_names[BGM_SERVICE_TYPES];
extern const char *const bgm_mechanism_names[BGM_MAX_MECHANISMS];
extern const char *const bgm_resource_market_names[2];
extern const char *const bgm_topology_names[BGM_TOPOLOGIES];

typedef struct bgm_dynamics {
    char name[BGM_NAME_MAX];
    double node_failure_rate; /* failures per node per simulated second */
    double node_repair_mean;  /* mean downtime, s */
    double link_failure_rate; /* access-link outages per node per second */
    double link_repair_mean;
} bgm_dynamics_t;

typedef struct bgm_service_cfg {
    double flops_per_unit;
    int cores;
    double memory; /* GiB */
    double cost_per_unit;
} bgm_service_cfg_t;

typedef struct bgm_plan_cfg {
    int services[BGM_SERVICE_TYPES]; /* 1 when the plan buys that type */
    double weight;
} bgm_plan_cfg_t;

typedef struct bgm_config {
    char name[BGM_NAME_MAX];
    uint64_t seed;
    int replications;
    double duration; /* s of job arrivals */
    double drain;    /* s after arrivals stop */
    int mechanisms[BGM_MAX_MECHANISMS];
    int mechanism_count;

    int nodes[BGM_MAX_LEVELS];
    int node_levels;
    double density[BGM_MAX_LEVELS];
    int density_levels;
    int dynamics_index[BGM_MAX_LEVELS]; /* into dynamics[] */
    int dynamics_levels;
    bgm_dynamics_t dynamics[BGM_MAX_DYNAMICS];
    int dynamics_count;
    /* factors.topology: the levels (bgm_topology), or none (0 levels):
     * then network.topology serves every scenario and no output names it. */
    int topology[BGM_TOPOLOGIES];
    int topology_levels;

    struct {
        int topology;                /* without factors.topology */
        char platform[BGM_PATH_MAX]; /* user platform XML, or "" (see bgm_config_load) */
        double latency;              /* s */
        double bandwidth;            /* bytes/s */
        double speed;                /* flops */
        double speed_spread;         /* relative, [0, 1) */
        int degree;                  /* random and scale-free graphs' mean degree */
        int message_bytes;           /* simulated size of a message */
    } network;

    struct {
        double complex_per_node;
        int service_slots;
        int services_per_agent;
        int resource_cores;
        double resource_memory;
        int overlay_degree;
    } agents;

    struct {
        double interarrival_mean; /* per complex agent, s */
        int work_min, work_max;
        double valuation_mean; /* per unit of work */
        double valuation_spread;
        double deadline; /* s after arrival */
        bgm_plan_cfg_t plans[BGM_MAX_PLANS];
        int plan_count;
        double shock_time;   /* < 0: no shock */
        double shock_factor; /* arrival rate multiplier after shock_time */
    } demand;

    bgm_service_cfg_t services[BGM_SERVICE_TYPES];

    struct {
        double core_cost;   /* per core-second */
        double memory_cost; /* per GiB-second */
        double cost_spread;
    } resources;

    struct {
        double period;
        double k;
        int exact_limit;
        long greedy_budget;
        int optimum_limit;   /* pairs of the offline optimum's program; null above */
        int resource_market; /* bgm_resource_market */
    } central;

    struct {
        int hops;
        double discovery_timeout;
        double reply_timeout;
        int max_rounds;
        double learning_period;
        double imitation;
        double mutation;
        double mutation_sigma;
        double retry_backoff;
    } catallactic;

    struct {
        double markup;
        int candidates;
        double retry_backoff;
    } baseline;

    struct {
        double convergence_tolerance; /* relative band for price convergence */
        double price_bucket;          /* s, for price-over-time plots */
    } metrics;
} bgm_config_t;

/* Parses and validates a config held in memory; name is the file as
 * messages name it (NULL: "<config>"). Messages are bg_json's:
 * "<name>: <field>: <text>", with line and column for syntax errors;
 * repeated keys are rejected. */
bg_status bgm_config_parse(const char *text, size_t length, const char *name, bgm_config_t *cfg,
                           bg_error_t *err);
/* Reads and parses a file (capped at BGM_CONFIG_MAX_BYTES); a file that
 * cannot be read is BG_ERR_IO with the reason. A relative
 * network.platform is resolved against the config's folder (and stored
 * so), and must be readable: BG_ERR_INVALID naming the file otherwise. */
bg_status bgm_config_load(const char *path, bgm_config_t *cfg, bg_error_t *err);

int bgm_config_scenario_count(const bgm_config_t *cfg);
/* Decodes scenario index s into its factor levels. */
void bgm_config_scenario(const bgm_config_t *cfg, int s, int *nodes, double *density,
                         const bgm_dynamics_t **dynamics);
/* Scenario s's topology (bgm_topology): its factors.topology level, or
 * network.topology. */
int bgm_config_scenario_topology(const bgm_config_t *cfg, int s);
/* The index scenario s's random streams are derived from (with the seed
 * and the replication): s without its topology level. Scenarios that
 * differ only in topology draw the same jobs, agents and host speeds
 * (common random numbers, as across mechanisms), and each equals the
 * scenario of the same config given that topology alone. Without a
 * topology factor it is s. */
int bgm_config_scenario_stream(const bgm_config_t *cfg, int s);
/* A scenario's name in the outputs: "n40_d2_static", or with a topology
 * factor (topology not NULL) "random_n40_d2_static". */
void bgm_config_scenario_label(char *buf, size_t n, const char *topology, int nodes, double density,
                               const char *dynamics);
/* Agents in a scenario: complex + basic-service + resource (+1 market). */
int bgm_config_agent_count(const bgm_config_t *cfg, int nodes, double density);

#endif
