#include "bg_prepare.h"

#include "bg_initial.h"
#include "bg_param.h"

bg_status bg_prepare_scene(bg_scene_t *s, bg_error_t *err)
{
    if (s->prepared)
        return BG_OK;
    bg_status st = BG_OK;
    if (s->task == BG_TASK_PARAMETERIZE) {
        st = bg_param_setup(s, err);
    } else if (s->initial_kind == BG_INITIAL_INTERPOLATE) {
        const size_t n = (size_t)s->mesh->nv * s->mesh->dim;
        st = bg_initial_interpolate(s, s->initial, &s->prep[s->prep_count++], err);
        for (size_t k = 0; st == BG_OK && k < n; k++)
            if (s->constrained[k])
                s->initial[k] = s->target[k];
    }
    if (st != BG_OK)
        return st;
    s->prepared = 1;
    return BG_OK;
}

bg_status bg_prepare_parse(const char *json, size_t length, const char *path,
                           const bg_scene_options_t *options, bg_scene_t **out, bg_error_t *err)
{
    bg_status st = bg_scene_parse_with(json, length, path, options, out, err);
    if (st == BG_OK && (st = bg_prepare_scene(*out, err)) != BG_OK)
        bg_scene_destroy(out);
    return st;
}

bg_status bg_prepare_load(const char *path, const bg_scene_options_t *options, bg_scene_t **out,
                          bg_error_t *err)
{
    bg_status st = bg_scene_load_with(path, options, out, err);
    if (st == BG_OK && (st = bg_prepare_scene(*out, err)) != BG_OK)
        bg_scene_destroy(out);
    return st;
}
