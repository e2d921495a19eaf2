/*
 * bg_plan — the basic services a scene needs, and what it leaves out.
 *
 * A job is a complex service built from basic services (DESIGN.md §2.1):
 * rotation-fit, sparse-solve, integration-step. The plan lists those a
 * scene needs with what each will do, and every service or part of one the
 * scene does not need, with the reason (a static scene buys no integration
 * step; a planar scene no 3D SVD path; λ = 0 no volume term; no gravity no
 * mass matrix). The market prices the plan; the report shows it.
 */
#ifndef BG_PLAN_H
#define BG_PLAN_H

#include "bg_scene.h"

#define BG_PLAN_MAX_ITEMS 12

typedef struct bg_plan_item {
    const char *service; /* "rotation-fit", "sparse-solve", "integration-step", or a part */
    char detail[512];    /* what it does for this scene, or why it is left out */
} bg_plan_item_t;

typedef struct bg_plan {
    bg_plan_item_t services[BG_PLAN_MAX_ITEMS];
    int service_count;
    bg_plan_item_t left_out[BG_PLAN_MAX_ITEMS];
    int left_out_count;
} bg_plan_t;

/* Fills plan for the scene solved with the given methods (count ≥ 1). */
void bg_plan_for_scene(const bg_scene_t *scene, const bg_method *methods, int method_count,
                       bg_plan_t *plan);

#endif
