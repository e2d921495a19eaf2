/*
 * Scene helpers shared by the unit tests: load a scene file or parse an
 * inline JSON scene, failing the running cmocka test with the library's
 * message. Include after <cmocka.h>. The caller owns the scene.
 */
#ifndef BG_TEST_SCENES_H
#define BG_TEST_SCENES_H

#include <string.h>

#include "bg_scene.h"

#define SCENES BG_SOURCE_DIR "/configs/scenes/"

static inline bg_scene_t *test_load_scene(const char *path)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    if (bg_scene_load(path, &s, &err) != BG_OK)
        fail_msg("%s", err.message);
    return s;
}

/* name stands for the scene's path in messages. */
static inline bg_scene_t *test_parse_scene(const char *json, const char *name)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    if (bg_scene_parse(json, strlen(json), name, &s, &err) != BG_OK)
        fail_msg("%s: %s", name, err.message);
    return s;
}

#endif
