#include "bg_plan.h"

#include <stdio.h>

#include "bg_static.h"

static void add(bg_plan_item_t *items, int *count, const char *service, const char *detail)
{
    if (*count >= BG_PLAN_MAX_ITEMS)
        return;
    items[*count].service = service;
    snprintf(items[*count].detail, sizeof items[*count].detail, "%s", detail);
    (*count)++;
}

void bg_plan_for_scene(const bg_scene_t *scene, const bg_method *methods, int method_count,
                       bg_plan_t *plan)
{
    plan->service_count = 0;
    plan->left_out_count = 0;
    const int planar = scene->mesh->dim == 2;
    int newton = 0, local_global = 0, quasi_newton = 0;
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    /* A time integrator's services are those of its inner solve. */
    const int inner_qn = dynamic && scene->inner == BG_METHOD_QUASI_NEWTON;
    for (int i = 0; i < method_count; i++) {
        const int integrates = bg_method_is_dynamic(methods[i]);
        newton |= methods[i] == BG_METHOD_NEWTON || (integrates && !inner_qn);
        local_global |= methods[i] == BG_METHOD_LOCAL_GLOBAL;
        quasi_newton |= methods[i] == BG_METHOD_QUASI_NEWTON || (integrates && inner_qn);
    }
    if (scene->task == BG_TASK_SURFACE_EDIT)
        add(plan->services, &plan->service_count, "rotation-fit",
            "one rotation per vertex over its spokes and rims (polar decomposition, "
            "warm-started)");
    else
    add(plan->services, &plan->service_count, "rotation-fit",
        planar ? "closed-form 2D rotation per triangle"
               : "polar decomposition per tetrahedron (Newton on SO(3), warm-started), "
                 "rotation-variant SVD where det F <= eps");
    char detail[512];
    /* Series (time steps, morph frames) keep the factored Newton matrix
     * and take L-BFGS steps on it (bg_dynamics, bg_morph). */
    const int series = dynamic || scene->task == BG_TASK_MORPH;
    int continues = 0;
    for (int i = 0; i < method_count; i++)
        continues |= bg_static_continues(scene, methods[i]);
    /* Local/global and quasi-newton share one matrix, the Laplacian: its
     * solve is local/global's step and quasi-newton's initial Hessian. */
    const int laplacian = local_global || quasi_newton;
    snprintf(detail, sizeof detail, "%s%s%s%s",
             !newton  ? ""
             : series ? "CHOLMOD: one symbolic analysis; the Newton matrix factored when it goes "
                        "stale, L-BFGS steps on it in between"
                      : continues
                          ? "CHOLMOD: a symbolic analysis per continuation stage, a numeric "
                            "factorization per Newton iteration (exact Hessian first near the "
                            "solution)"
                          : "CHOLMOD: one symbolic analysis, a numeric factorization per Newton "
                            "iteration (exact Hessian first near the solution)",
             newton && laplacian ? "; " : "",
             !laplacian ? ""
             : dynamic
                 ? "CHOLMOD: the Laplacian plus the inertia term c M factored once per "
                   "coefficient c (the midpoint rule's, and backward Euler's for a redone step), "
                   "one block solve of the coordinates per iteration"
             : scene->task == BG_TASK_MORPH
                 ? "CHOLMOD: the Laplacian factored once per frame, one block solve of the "
                   "coordinates per iteration"
                 : "CHOLMOD: the Laplacian factored once, one block solve of the coordinates per "
                   "iteration",
             !quasi_newton ? ""
             : local_global ? " (local/global's step; quasi-newton's L-BFGS initial Hessian)"
                            : " (the L-BFGS initial Hessian)");
    add(plan->services, &plan->service_count, "sparse-solve", detail);
    if (continues) {
        snprintf(detail, sizeof detail,
                 "%s, lambda = %g mu > 100 mu (nearly incompressible): stages of growing "
                 "lambda from 10 mu, doubling, each warm-started from the last; iterations and "
                 "times total the stages",
                 newton && quasi_newton ? "Newton and quasi-newton"
                 : newton               ? "Newton"
                                        : "quasi-newton",
                 scene->material.lambda / scene->material.mu);
        add(plan->services, &plan->service_count, "continuation", detail);
    }
    for (int i = 0; i < scene->prep_count; i++)
        add(plan->services, &plan->service_count, "starting-guess", scene->prep[i].name);
    const double *g = scene->gravity;
    const int weighted = g[0] != 0.0 || g[1] != 0.0 || g[2] != 0.0;
    if (dynamic || weighted)
        add(plan->services, &plan->service_count, "mass-matrix",
            dynamic ? "lumped masses rho V/(n+1) per vertex: inertia and weight"
                    : "lumped masses rho V/(n+1) per vertex: the weight");

    if (dynamic) {
        snprintf(detail, sizeof detail, "%d steps of h = %g s, each a %s solve with the "
                 "inertia term (%s)", scene->dynamic.steps, scene->dynamic.dt,
                 inner_qn ? "quasi-newton" : "Newton",
                 method_count > 1 ? "variational midpoint and backward Euler"
                 : methods[0] == BG_METHOD_BACKWARD_EULER ? "backward Euler"
                                                          : "variational midpoint");
        add(plan->services, &plan->service_count, "integration-step", detail);
    } else {
        add(plan->left_out, &plan->left_out_count, "integration-step",
            scene->task == BG_TASK_MORPH ? "morph: a sequence of static solves, no time "
                                           "integration"
                                         : "static scene: no time integration");
    }
    if (scene->task == BG_TASK_MORPH)
        add(plan->services, &plan->service_count, "rotation-fit/target",
            "rotations fitted against the target rest shape too: E(M0 -> x) and E(M1 -> x)");
    if (planar)
        add(plan->left_out, &plan->left_out_count, "rotation-fit/svd",
            "planar scene: the 2D closed form covers inverted triangles, no 3D SVD path");
    if (scene->material.lambda == 0.0)
        add(plan->left_out, &plan->left_out_count, "volume-term",
            "lambda = 0: no (tr Y - n)^2 term (the plain as-rigid-as-possible energy)");
    /* bg_static builds the masses exactly when this says so. */
    if (!dynamic && !weighted)
        add(plan->left_out, &plan->left_out_count, "mass-matrix",
            scene->task == BG_TASK_PARAMETERIZE
                ? "parameterization: a static map of the surface to the plane, no masses"
                : "no gravity: the lumped mass matrix is not built");
}
