/*
 * bgm_rng — the only source of randomness in the market library.
 *
 * xoshiro256** seeded through splitmix64. Every stream is derived from
 * (experiment seed, scenario, replication, stream id) by bgm_rng_derive, so
 * an agent's draws do not depend on the order in which other agents draw:
 * the same config and seed give the same run on any machine.
 * A bgm_rng_t is a plain value: caller-allocated, no cleanup.
 */
#ifndef BGM_RNG_H
#define BGM_RNG_H

#include <stdint.h>

typedef struct bgm_rng {
    uint64_t s[4];
} bgm_rng_t;

/* Seeds a stream from one 64-bit value (any value, including 0, is valid). */
void bgm_rng_seed(bgm_rng_t *rng, uint64_t seed);

/* Seeds the stream identified by (seed, scenario, replication, stream). */
void bgm_rng_derive(bgm_rng_t *rng, uint64_t seed, uint64_t scenario, uint64_t replication,
                    uint64_t stream);

uint64_t bgm_rng_next(bgm_rng_t *rng);
/* Uniform in [0, 1), 53 bits. */
double bgm_rng_uniform(bgm_rng_t *rng);
/* Uniform integer in [0, n); n > 0. */
uint32_t bgm_rng_below(bgm_rng_t *rng, uint32_t n);
/* Exponential with the given mean (> 0). */
double bgm_rng_exponential(bgm_rng_t *rng, double mean);
/* Standard normal (Box-Muller, one value per call). */
double bgm_rng_normal(bgm_rng_t *rng);

#endif
