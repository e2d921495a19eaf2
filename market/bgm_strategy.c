#include "bgm_strategy.h"

/* Gene ranges for a fresh population, in pack order. Stubborn (high
 * acquisitiveness) or impatient (low satisfaction) agents rarely trade, so
 * the initial population starts moderate; learning and mutation may then
 * take any gene anywhere in [0, 1]. */
static const double gene_lo[BGM_GENE_COUNT] = {0.0, 0.1, 0.0, 0.5, 0.6};
static const double gene_hi[BGM_GENE_COUNT] = {0.5, 0.5, 0.5, 0.95, 1.0};

static double clamp01(double x)
{
    return x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x);
}

void bgm_genes_pack(const bgm_genes_t *g, double out[BGM_GENE_COUNT])
{
    out[0] = g->acquisitiveness;
    out[1] = g->price_step;
    out[2] = g->price_next;
    out[3] = g->weight_memory;
    out[4] = g->satisfaction;
}

void bgm_genes_unpack(bgm_genes_t *g, const double in[BGM_GENE_COUNT])
{
    g->acquisitiveness = clamp01(in[0]);
    g->price_step = clamp01(in[1]);
    g->price_next = clamp01(in[2]);
    g->weight_memory = clamp01(in[3]);
    g->satisfaction = clamp01(in[4]);
}

void bgm_genes_random(bgm_genes_t *g, bgm_rng_t *rng)
{
    double v[BGM_GENE_COUNT];
    for (int i = 0; i < BGM_GENE_COUNT; i++)
        v[i] = gene_lo[i] + (gene_hi[i] - gene_lo[i]) * bgm_rng_uniform(rng);
    bgm_genes_unpack(g, v);
}

void bgm_genes_mutate(bgm_genes_t *g, const bgm_learning_t *p, bgm_rng_t *rng)
{
    double v[BGM_GENE_COUNT];
    bgm_genes_pack(g, v);
    for (int i = 0; i < BGM_GENE_COUNT; i++)
        if (bgm_rng_uniform(rng) < p->mutation)
            v[i] += p->sigma * bgm_rng_normal(rng);
    bgm_genes_unpack(g, v);
}

int bgm_genes_learn(bgm_genes_t *self, double self_fitness, const bgm_genes_t *other,
                    double other_fitness, const bgm_learning_t *p, bgm_rng_t *rng)
{
    int imitated = 0;
    if (other_fitness > self_fitness && bgm_rng_uniform(rng) < p->imitation) {
        *self = *other;
        imitated = 1;
    }
    bgm_genes_mutate(self, p, rng);
    return imitated;
}

double bgm_memory_update(double memory, double price, double weight_memory)
{
    if (memory <= 0.0)
        return price;
    return weight_memory * memory + (1.0 - weight_memory) * price;
}

/* Fitness smoothing and the step of the opening-price markup. */
#define BGM_FITNESS_DECAY 0.9
#define BGM_MARKUP_STEP 0.1

void bgm_outcome_learn(const bgm_genes_t *g, double *fitness, double *markup, int success,
                       double surplus_share)
{
    if (success) {
        *fitness = BGM_FITNESS_DECAY * *fitness + (1.0 - BGM_FITNESS_DECAY) * surplus_share;
        *markup += g->price_next * BGM_MARKUP_STEP * (1.0 - *markup);
    } else {
        *fitness *= BGM_FITNESS_DECAY;
        *markup -= g->price_next * BGM_MARKUP_STEP * *markup;
    }
}
