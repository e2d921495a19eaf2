/*
 * bgm_platform — generated SimGrid platforms (star, cluster of racks,
 * random graph, scale-free graph) as platform XML, with per-host speeds
 * drawn from the experiment's seed. Hosts are "h0".."h{nodes-1}" plus
 * "market" for the auctioneer/directory; routing is Dijkstra over hosts,
 * routers and links, so one generator serves the four topologies. Pure
 * except for writing the file it is given.
 */
#ifndef BGM_PLATFORM_H
#define BGM_PLATFORM_H

#include <stdio.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_rng.h"

#define BGM_RACK_SIZE 16
/* The stream a replication's platform is drawn from (bgm_rng_derive's
 * last argument, with the seed, scenario and replication): every
 * mechanism of a replication runs on the same hosts, and a tool that
 * rebuilds a run's platform draws the same one. */
#define BGM_PLATFORM_STREAM 0xfffffff1ULL

/*
 * Writes the platform of `topology` (bgm_topology: the scenario's, see
 * bgm_config_scenario_topology) for `nodes` hosts to f; the rest of the
 * network comes from cfg. speed (caller-allocated, nodes + 1 entries)
 * receives each host's speed in flops, the market host last: the speeds
 * are drawn first, so they do not depend on the topology.
 */
bg_status bgm_platform_write(FILE *f, const bgm_config_t *cfg, int topology, int nodes,
                             bgm_rng_t *rng, double *speed);

#endif
