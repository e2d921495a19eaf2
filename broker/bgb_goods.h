/*
 * bgb_goods — the live market's vocabulary: the goods traded on its two
 * layers and the mechanisms a job may buy under, with their names as the
 * REST API, the job store and the CSV exports spell them. Numbered as the
 * simulator's (bgm_role.h BGM_GOOD_*, bgm_mechanism), so the same audit
 * reads a live grid's log and a simulation's.
 */
#ifndef BGB_GOODS_H
#define BGB_GOODS_H

/* Goods, numbered as the simulator's (bgm_role.h BGM_GOOD_*). */
typedef enum bgb_good {
    BGB_GOOD_ROTFIT = 0,
    BGB_GOOD_SOLVE = 1,
    BGB_GOOD_INTEG = 2,
    BGB_GOOD_CORES = 3,
    BGB_GOOD_MEMORY = 4,
    BGB_GOODS = 5
} bgb_good;

typedef enum bgb_mechanism {
    BGB_MECH_CENTRAL = 0,
    BGB_MECH_CATALLACTIC = 1,
    BGB_MECH_POSTED = 2
} bgb_mechanism;

#define BGB_MECHANISMS 3

/* "central", "catallactic", "posted" ("unknown" out of range); parse
 * returns -1 on an unknown name or NULL. */
const char *bgb_mechanism_name(bgb_mechanism m);
int bgb_mechanism_parse(const char *name);
/* "rotation-fit", "sparse-solve", "integration-step", "cores", "memory"
 * ("unknown" out of range). */
const char *bgb_good_name(int good);

#endif
