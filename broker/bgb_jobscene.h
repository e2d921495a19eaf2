/*
 * bgb_jobscene — a job's scene as the broker takes it, the one loader the
 * REST API (at submission) and the job's coordinator (before it runs) share:
 * the files uploaded with it written into a folder of their own, the scene
 * parsed against those files alone (confined: an absolute path or one that
 * leaves the folder is refused) under the broker's size caps, and its plan,
 * computed once. Parsing runs no solve, so a submission is validated in
 * milliseconds; the coordinator then prepares the scene (bg_prepare_scene).
 */
#ifndef BGB_JOBSCENE_H
#define BGB_JOBSCENE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bg_plan.h"
#include "bg_scene.h"
#include "bgb_store.h"

/* What a job may be, at most (0: the engine's own caps). */
typedef struct bgb_jobscene_limits {
    int64_t max_vertices;
    int64_t max_elements;
} bgb_jobscene_limits_t;

typedef struct bgb_jobscene {
    bg_scene_t *scene; /* owned: parsed, not prepared */
    bg_plan_t plan;    /* the scene's own method's plan */
} bgb_jobscene_t;

#define BGB_JOBSCENE_INIT                                                                          \
    {                                                                                              \
        NULL,                                                                                      \
        {                                                                                          \
            {{0}}, 0, {{0}}, 0                                                                     \
        }                                                                                          \
    }

/*
 * Writes files[0..count) into the existing folder dir, each created new
 * (O_EXCL, mode 0600): names were checked by the store's rule
 * (bgb_store_check_file_name). BG_ERR_IO naming the file.
 */
bg_status bgb_jobscene_unpack(const char *dir, const bgb_file_t *files, int count, bg_error_t *err);

/* Removes what bgb_jobscene_unpack wrote (the names given) and the folder. */
void bgb_jobscene_remove(const char *dir, const bgb_file_t *files, int count);

/*
 * Parses the scene text (json, length bytes) against the files in dir
 * (NULL: a job without files, whose every file reference is then not
 * found), named "scene" in messages, under limits (NULL: none), and plans
 * it, into *out (bgb_jobscene_release). Errors are the parser's: a 422's
 * message, naming the field.
 */
bg_status bgb_jobscene_load(const char *json, size_t length, const char *dir,
                            const bgb_jobscene_limits_t *limits, bgb_jobscene_t *out,
                            bg_error_t *err);

/* The plan as JSON text, {"services": [{"service", "detail"}], "left_out":
 * [{"service", "reason"}]} (caller frees; NULL for memory). */
char *bgb_jobscene_plan_json(const bgb_jobscene_t *js);

/* Whether the plan buys an integration step (a dynamic scene). */
int bgb_jobscene_needs_integ(const bgb_jobscene_t *js);

void bgb_jobscene_release(bgb_jobscene_t *js);

#endif
