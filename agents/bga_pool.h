/*
 * bga_pool — the coordinator's rotation fit over several agents: the
 * mesh's elements cut into balanced contiguous ranges, one partition per
 * agent, each evaluated in parallel (every agent gets its request before
 * any reply is awaited) and the partial sums combined in partition
 * order, so results do not depend on which agent answers first.
 *
 * bga_rotfit_pool_eval has the contract of bg_elastic_eval followed by
 * bg_elastic_assemble_hessian at the same q: the energy, ∇E overwritten,
 * Hessian contributions added into the caller's values through the
 * global scatter given at creation. Each agent receives a compact scatter
 * map, so its reply carries one value per pattern entry its partition
 * touches (not the global array, not per-element blocks).
 *
 * The pool owns one client per agent and, per agent, the partition's job
 * (released by bga_rotfit_pool_destroy).
 */
#ifndef BGA_POOL_H
#define BGA_POOL_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bg_mesh.h"
#include "bga_client.h"

typedef struct bga_rotfit_pool bga_rotfit_pool_t;

typedef struct bga_pool_config {
    const bg_mesh_t *mesh; /* validated planar or volume mesh (connectivity, and the rest
                              positions unless rest_edges); read during _new */
    double mu, lambda, barrier;
    const int32_t *scatter;       /* ne*T global positions (−1: skipped), or NULL: no Hessian */
    size_t nval;                  /* entries of the caller's value array */
    const char *const *endpoints; /* nagents rotation-fit agents */
    int nagents;
    uint64_t job; /* job id used on every agent */
    int timeout_ms;
    int64_t lease_ms;
    const double *rest_edges; /* ne*dim*dim rest edge matrices, or NULL; read during _new */
    int surface; /* 1: a surface (BG_MESH_SURFACE) for the spokes-and-rims energy: balanced
                    vertex ranges, each agent owning its range's cells (the triangles around
                    them); material, scatter and rest_edges unused, no Hessian */
    const bga_curve_peers_t *curve; /* CURVE keys to reach the agents (bga_client_new_curve);
                                       NULL: plaintext. Borrowed, outlives the pool */
} bga_pool_config_t;

/* Connects, partitions and sets up every agent. Caller owns *out. */
bg_status bga_rotfit_pool_new(const bga_pool_config_t *config, bga_rotfit_pool_t **out,
                              bg_error_t *err);
void bga_rotfit_pool_destroy(bga_rotfit_pool_t **pool);
/* Destroys without releasing the jobs (an agent failed: its lease frees
 * them, and no release request waits for a dead agent). */
void bga_rotfit_pool_abandon(bga_rotfit_pool_t **pool);

/*
 * Energy at q (nv*dim) into *energy; grad (nv*dim) overwritten when
 * non-NULL; Hessian (PSD-projected when `project`) added into values
 * (nval) when non-NULL (the pool must have a scatter). Failures name the
 * agent and the service.
 */
bg_status bga_rotfit_pool_eval(bga_rotfit_pool_t *pool, const double *q, double *energy,
                               double *grad, double *values, int project, bg_error_t *err);

int bga_rotfit_pool_size(const bga_rotfit_pool_t *pool);
/* Agent i's traffic, and its partition's element count. */
bga_traffic_t bga_rotfit_pool_traffic(const bga_rotfit_pool_t *pool, int agent);
int32_t bga_rotfit_pool_elements(const bga_rotfit_pool_t *pool, int agent);
/* Seconds spent combining partial results (the coordinator's share). */
double bga_rotfit_pool_gather_seconds(const bga_rotfit_pool_t *pool);

#endif
