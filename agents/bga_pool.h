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
 *
 * A lost agent: each part keeps its results of the current call, so when
 * one agent fails a call without answering (bga_rotfit_pool_lost_part),
 * its partition can be set up on another agent (bga_rotfit_pool_replace)
 * and the call finished there (bga_rotfit_pool_resume): the other parts
 * are not asked again, and the sums are still taken in partition order.
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
    uint64_t job; /* job id used on every agent, unless jobs is given */
    int timeout_ms;
    int64_t lease_ms;
    const double *rest_edges; /* ne*dim*dim rest edge matrices, or NULL; read during _new */
    int surface; /* 1: a surface (BG_MESH_SURFACE) for the spokes-and-rims energy: balanced
                    vertex ranges, each agent owning its range's cells (the triangles around
                    them); material, scatter and rest_edges unused, no Hessian */
    const bga_curve_peers_t *curve; /* CURVE keys to reach the agents (bga_client_new_curve);
                                       NULL: plaintext. Borrowed, outlives the pool */
    const uint64_t *jobs; /* nagents job ids, one per agent, or NULL: job on all (read
                             during _new) */
} bga_pool_config_t;

/* Connects, partitions and sets up every agent, its clients pinging as
 * bga_client_new sets them (bga_client_set_liveness's defaults). Caller
 * owns *out. */
bg_status bga_rotfit_pool_new(const bga_pool_config_t *config, bga_rotfit_pool_t **out,
                              bg_error_t *err);
/* The same with the clients' liveness given (bga_client_set_liveness),
 * and on a failed set-up the pool is kept: *out is the pool whenever it
 * could be made (each part set up or failed on its own, so a lost part can
 * be replaced: bga_rotfit_pool_lost_part), NULL only when it could not;
 * the caller destroys it either way. */
bg_status bga_rotfit_pool_new_live(const bga_pool_config_t *config, int ping_ms, int lost_ms,
                                   bga_rotfit_pool_t **out, bg_error_t *err);
/* The first part's failure of the last set-up or call (its status and
 * message into err), or BG_OK when every part is set up and answered. */
bg_status bga_rotfit_pool_failure(const bga_rotfit_pool_t *pool, bg_error_t *err);
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

/*
 * After a failed eval: the first partition whose agent failed the call
 * without answering it (lost, timed out, a broken socket) or answered that
 * it holds no state for the job (restarted, lease expired), or −1 when no
 * agent failed that way (a refusal is the call's own failure).
 */
int bga_rotfit_pool_lost_part(const bga_rotfit_pool_t *pool);
/*
 * Sets partition i up again on the agent at endpoint, under job id `job`:
 * cfg must be the configuration the pool was made with (its mesh, scatter
 * and rest data again, read during the call; its endpoints and jobs are
 * not used). The old client goes to *given_up (caller owns it: it may
 * still receive that agent's late answers), NULL when none was replaced.
 */
bg_status bga_rotfit_pool_replace(bga_rotfit_pool_t *pool, int i, const bga_pool_config_t *cfg,
                                  const char *endpoint, uint64_t job, bga_client_t **given_up,
                                  bg_error_t *err);
/*
 * Finishes the last eval (same q, which is read again, and what it asked
 * for) on the parts that have no answer to it yet, then combines all of
 * them as bga_rotfit_pool_eval would have.
 */
bg_status bga_rotfit_pool_resume(bga_rotfit_pool_t *pool, const double *q, double *energy,
                                 double *grad, double *values, bg_error_t *err);
/* Agent i's endpoint now. */
const char *bga_rotfit_pool_endpoint(const bga_rotfit_pool_t *pool, int agent);

int bga_rotfit_pool_size(const bga_rotfit_pool_t *pool);
/* Agent i's traffic, and its partition's element count. */
bga_traffic_t bga_rotfit_pool_traffic(const bga_rotfit_pool_t *pool, int agent);
int32_t bga_rotfit_pool_elements(const bga_rotfit_pool_t *pool, int agent);
/* Seconds spent combining partial results (the coordinator's share). */
double bga_rotfit_pool_gather_seconds(const bga_rotfit_pool_t *pool);

#endif
