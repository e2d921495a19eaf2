/*
 * bgm_strategy — the catallactic strategy genes and their decentralized
 * evolutionary learning.
 *
 * Genes, each in [0, 1] (Eymann et al. 2005):
 *   acquisitiveness  probability of NOT conceding in a bargaining round;
 *   price_step       fraction of the gap to the other side's offer conceded;
 *   price_next       how far the next opening price moves after a success
 *                    (up for a seller, down for a buyer) or a failure;
 *   weight_memory    smoothing of the remembered market price;
 *   satisfaction     probability of continuing rather than walking away
 *                    after a round without concession.
 * Learning: when two agents meet they exchange (genes, fitness); the less
 * fit copies the fitter with probability p_imitate, then every gene
 * mutates with probability p_mutate by a normal step of sigma, clamped.
 */
#ifndef BGM_STRATEGY_H
#define BGM_STRATEGY_H

#include "bgm_rng.h"

typedef struct bgm_genes {
    double acquisitiveness;
    double price_step;
    double price_next;
    double weight_memory;
    double satisfaction;
} bgm_genes_t;

#define BGM_GENE_COUNT 5

typedef struct bgm_learning {
    double imitation; /* p_imitate */
    double mutation;  /* p_mutate per gene */
    double sigma;     /* mutation step */
} bgm_learning_t;

/* Draws genes uniformly in the ranges that let bargaining converge. */
void bgm_genes_random(bgm_genes_t *g, bgm_rng_t *rng);
void bgm_genes_mutate(bgm_genes_t *g, const bgm_learning_t *p, bgm_rng_t *rng);
/* One meeting seen from `self`; returns 1 if self imitated other. */
int bgm_genes_learn(bgm_genes_t *self, double self_fitness, const bgm_genes_t *other,
                    double other_fitness, const bgm_learning_t *p, bgm_rng_t *rng);
/* Exponential smoothing of a remembered price by weight_memory. */
double bgm_memory_update(double memory, double price, double weight_memory);
/* After a bargain (success with the surplus share it earned, or a
 * failure): fitness is smoothed towards the share (or decays), and the
 * opening markup moves up after a success and down after a failure, by
 * price_next, staying in [0, 1). Shared by every role that bargains. */
void bgm_outcome_learn(const bgm_genes_t *g, double *fitness, double *markup, int success,
                       double surplus_share);
/* Packs/unpacks genes into an array (for messages). */
void bgm_genes_pack(const bgm_genes_t *g, double out[BGM_GENE_COUNT]);
void bgm_genes_unpack(bgm_genes_t *g, const double in[BGM_GENE_COUNT]);

#endif
