/*
 * Scene helpers shared by the unit tests: load a scene file or parse an
 * inline JSON scene, failing the running cmocka test with the library's
 * message. Files a scene names by a bare name ("bunny.mesh") are found in
 * the build's public meshes (BG_MESH_DIR), as `biotgrid solve` finds them.
 * Include after <cmocka.h>. The caller owns the scene.
 */
#ifndef BG_TEST_SCENES_H
#define BG_TEST_SCENES_H

#include <string.h>

#include "bg_prepare.h"
#include "bg_scene.h"

#define SCENES BG_SOURCE_DIR "/configs/scenes/"
/* The public meshes the build makes (cmake/Meshes.cmake). Scenes are
 * parsed and prepared (bg_scene_prepare), ready to solve. */
#define MESHES BG_MESH_DIR "/"

static inline bg_scene_t *test_load_scene(const char *path)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    const bg_scene_options_t o = {.search_path = BG_MESH_DIR};
    if (bg_scene_load_with(path, &o, &s, &err) != BG_OK || bg_prepare_scene(s, &err) != BG_OK)
        fail_msg("%s", err.message);
    return s;
}

/* name stands for the scene's path in messages. */
static inline bg_scene_t *test_parse_scene(const char *json, const char *name)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    const bg_scene_options_t o = {.search_path = BG_MESH_DIR};
    if (bg_scene_parse_with(json, strlen(json), name, &o, &s, &err) != BG_OK ||
        bg_prepare_scene(s, &err) != BG_OK)
        fail_msg("%s: %s", name, err.message);
    return s;
}

#endif
