/*
 * fuzz_scene — the scene JSON (bg_scene_parse_with): the whole input is
 * the scene's text. The options are a broker's, tightened so that no input
 * reaches the disk or builds a big mesh: confined to a folder that does
 * not exist (every file a scene names is refused or not found), and caps
 * small enough that a generated mesh over them is refused before it is
 * built.
 */
#include <stdlib.h>

#include "bg_scene.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    uint8_t *text = NULL;
    size_t length = 0;
    if (fuzz_take_rest(&in, &text, &length) != 1)
        return 0;
    const bg_scene_options_t options = {
        .search_path = "/nonexistent-biotgrid-fuzz",
        .max_vertices = 300,
        .max_elements = 600,
        .max_work = 60000.0,
        .confined = 1,
        .display_name = "fuzz.json",
    };
    bg_scene_t *scene = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_scene_parse_with((const char *)text, length, "/nonexistent-biotgrid-fuzz/scene.json",
                            &options, &scene, &err) == BG_OK) {
        /* What the solvers read first: the targets at a few times. */
        double *x = malloc((size_t)scene->mesh->nv * (size_t)scene->mesh->dim * sizeof *x);
        if (x) {
            bg_scene_targets_at(scene, 0.0, x);
            bg_scene_targets_at(scene, 1.0, x);
            free(x);
        }
    }
    bg_scene_destroy(&scene);
    free(text);
    return 0;
}
