#include "bgm_rng.h"

#include <math.h>

static uint64_t splitmix64(uint64_t *x)
{
    uint64_t z = (*x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

static uint64_t rotl(uint64_t x, int k)
{
    return (x << k) | (x >> (64 - k));
}

void bgm_rng_seed(bgm_rng_t *rng, uint64_t seed)
{
    uint64_t x = seed;
    for (int i = 0; i < 4; i++)
        rng->s[i] = splitmix64(&x);
}

void bgm_rng_derive(bgm_rng_t *rng, uint64_t seed, uint64_t scenario, uint64_t replication,
                    uint64_t stream)
{
    /* Chain the coordinates through splitmix64 so nearby tuples give
     * unrelated streams. */
    uint64_t x = seed;
    uint64_t h = splitmix64(&x);
    x = h ^ (scenario * 0xd1342543de82ef95ULL);
    h = splitmix64(&x);
    x = h ^ (replication * 0x9e3779b97f4a7c15ULL);
    h = splitmix64(&x);
    x = h ^ (stream * 0xbf58476d1ce4e5b9ULL);
    bgm_rng_seed(rng, splitmix64(&x));
}

uint64_t bgm_rng_next(bgm_rng_t *rng)
{
    uint64_t *s = rng->s;
    uint64_t result = rotl(s[1] * 5, 7) * 9;
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

double bgm_rng_uniform(bgm_rng_t *rng)
{
    return (double)(bgm_rng_next(rng) >> 11) * 0x1.0p-53;
}

uint32_t bgm_rng_below(bgm_rng_t *rng, uint32_t n)
{
    /* Multiply-shift; the bias is below 2^-32 for the n used here. */
    return (uint32_t)(((bgm_rng_next(rng) >> 32) * (uint64_t)n) >> 32);
}

double bgm_rng_exponential(bgm_rng_t *rng, double mean)
{
    return -mean * log1p(-bgm_rng_uniform(rng));
}

double bgm_rng_normal(bgm_rng_t *rng)
{
    double u1 = bgm_rng_uniform(rng);
    double u2 = bgm_rng_uniform(rng);
    if (u1 < 1e-300)
        u1 = 1e-300;
    return sqrt(-2.0 * log(u1)) * cos(2.0 * 3.14159265358979323846 * u2);
}
