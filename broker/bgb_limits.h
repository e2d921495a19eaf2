/*
 * bgb_limits — what the broker accepts, sized to the machine it runs on.
 *
 * Every limit holds by default: a job's size and work are checked from the
 * scene before anything is allocated (bgb_jobscene), a request's body,
 * a user's jobs in flight and stored bytes, and the connections are capped
 * (bgb_rest). A configuration may set any of them; those it leaves at 0
 * are derived here from the machine: the size of one job from its
 * estimated peak memory against a fraction of the RAM.
 *
 * The memory model (bgb_limits_job_memory) is measured, not derived: peak
 * resident memory of a Newton solve on generated boxes of 6,000 to 384,000
 * tetrahedra fits 64 MiB + 120 bytes × elements^(4/3) within 10 % (the
 * exponent is a nested-dissection Cholesky factor's fill in 3D; planar and
 * surface meshes fill less, so the model errs on the safe side for them).
 */
#ifndef BGB_LIMITS_H
#define BGB_LIMITS_H

#include <stddef.h>
#include <stdint.h>

/* Defaults that do not depend on the machine. */
#define BGB_LIMITS_MEMORY_FRACTION 0.25
#define BGB_LIMITS_MAX_WORK 2e9
#define BGB_LIMITS_MAX_BODY ((size_t)64 << 20)
#define BGB_LIMITS_JOBS_IN_FLIGHT 64
#define BGB_LIMITS_STORED_BYTES ((int64_t)2 << 30)
#define BGB_LIMITS_CONNECTIONS 2048u
#define BGB_LIMITS_CONNECTIONS_PER_CLIENT 512u
#define BGB_LIMITS_IDLE_TIMEOUT 15u
#define BGB_LIMITS_REQUEST_TIMEOUT 60u

typedef struct bgb_limits {
    double memory_fraction;   /* of the RAM one job's estimated peak may take */
    int64_t max_vertices;     /* per job; 0: from memory_fraction */
    int64_t max_elements;     /* per job; 0: from memory_fraction */
    double max_work;          /* elements × steps (dynamic) or × frames (morph) per job */
    size_t max_body;          /* bytes of one request's body */
    int max_jobs_in_flight;   /* per user: queued, allocating and running */
    int64_t max_stored_bytes; /* per user: the files of their jobs, inputs and results */
    unsigned max_connections; /* open at once */
    unsigned max_connections_per_client; /* open at once from one address */
    unsigned idle_timeout;               /* s a connection may stay silent */
    unsigned request_timeout;            /* s a request has to arrive whole, body included */
} bgb_limits_t;

/* The defaults above; the job size caps 0 (derived by bgb_limits_resolve). */
void bgb_limits_default(bgb_limits_t *limits);

/* The machine's physical memory in bytes (0 if unknown). */
uint64_t bgb_limits_ram(void);

/* Estimated peak memory of one job of `elements` elements, in bytes. */
double bgb_limits_job_memory(double elements);

/* Fills the job size caps left at 0 from ram_bytes (0: unknown, then 1 GiB
 * is assumed): the most elements whose estimated peak stays within
 * memory_fraction of the RAM, and as many vertices. */
void bgb_limits_resolve(bgb_limits_t *limits, uint64_t ram_bytes);

/* A multi-line description of the limits in force ("  name value (why)\n"
 * per limit), for the broker to print at start; returns what snprintf
 * returns. */
int bgb_limits_describe(const bgb_limits_t *limits, uint64_t ram_bytes, char *buf, size_t size);

#endif
