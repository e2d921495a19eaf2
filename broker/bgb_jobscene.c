#include "bgb_jobscene.h"

#include <cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#define JOBSCENE_PATH_MAX 4096
/* A folder that mkdtemp never creates (no six-character suffix): a job
 * without files is parsed as if it lived there, so nothing it names is
 * found and nothing touches the disk. */
#define JOBSCENE_NO_FOLDER "/nonexistent/bgb-job-none"

bg_status bgb_jobscene_unpack(const char *dir, const bgb_file_t *files, int count, bg_error_t *err)
{
    for (int i = 0; i < count; i++) {
        char path[JOBSCENE_PATH_MAX + BGB_STORE_MAX_FILE_NAME + 2];
        if (snprintf(path, sizeof path, "%s/%s", dir, files[i].name) >= (int)sizeof path)
            return bg_error_set(err, BG_ERR_INVALID, "%s: path too long", dir);
        const int fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
        if (fd < 0)
            return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", files[i].name,
                                strerror(errno));
        size_t done = 0;
        while (done < files[i].size) {
            const ssize_t n = write(fd, files[i].data + done, files[i].size - done);
            if (n < 0 && errno == EINTR)
                continue;
            if (n <= 0) {
                const int e = errno;
                close(fd);
                return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", files[i].name,
                                    strerror(e));
            }
            done += (size_t)n;
        }
        if (close(fd) != 0)
            return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", files[i].name,
                                strerror(errno));
    }
    return BG_OK;
}

void bgb_jobscene_remove(const char *dir, const bgb_file_t *files, int count)
{
    for (int i = 0; i < count; i++) {
        char path[JOBSCENE_PATH_MAX + BGB_STORE_MAX_FILE_NAME + 2];
        if (snprintf(path, sizeof path, "%s/%s", dir, files[i].name) < (int)sizeof path)
            unlink(path);
    }
    rmdir(dir);
}

bg_status bgb_jobscene_load(const char *json, size_t length, const char *dir,
                            const bgb_jobscene_limits_t *limits, bgb_jobscene_t *out,
                            bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    char scene_path[JOBSCENE_PATH_MAX + 16];
    if (snprintf(scene_path, sizeof scene_path, "%s/scene.json", dir ? dir : JOBSCENE_NO_FOLDER) >=
        (int)sizeof scene_path)
        return bg_error_set(err, BG_ERR_INVALID, "the job's folder name is too long");
    const bg_scene_options_t options = {.max_vertices = limits ? limits->max_vertices : 0,
                                        .max_elements = limits ? limits->max_elements : 0,
                                        .confined = 1,
                                        .display_name = "scene"};
    bg_status st = bg_scene_parse_with(json, length, scene_path, &options, &out->scene, err);
    if (st != BG_OK)
        return st;
    bg_plan_for_scene(out->scene, &out->scene->method, 1, &out->plan);
    return BG_OK;
}

char *bgb_jobscene_plan_json(const bgb_jobscene_t *js)
{
    cJSON *o = cJSON_CreateObject();
    cJSON *services = cJSON_AddArrayToObject(o, "services");
    cJSON *left_out = cJSON_AddArrayToObject(o, "left_out");
    for (int i = 0; services && i < js->plan.service_count; i++) {
        cJSON *item = cJSON_CreateObject();
        cJSON_AddStringToObject(item, "service", js->plan.services[i].service);
        cJSON_AddStringToObject(item, "detail", js->plan.services[i].detail);
        cJSON_AddItemToArray(services, item);
    }
    for (int i = 0; left_out && i < js->plan.left_out_count; i++) {
        cJSON *item = cJSON_CreateObject();
        cJSON_AddStringToObject(item, "service", js->plan.left_out[i].service);
        cJSON_AddStringToObject(item, "reason", js->plan.left_out[i].detail);
        cJSON_AddItemToArray(left_out, item);
    }
    char *text = services && left_out ? cJSON_PrintUnformatted(o) : NULL;
    cJSON_Delete(o);
    return text;
}

int bgb_jobscene_needs_integ(const bgb_jobscene_t *js)
{
    for (int i = 0; i < js->plan.service_count; i++)
        if (strcmp(js->plan.services[i].service, "integration-step") == 0)
            return 1;
    return 0;
}

void bgb_jobscene_release(bgb_jobscene_t *js)
{
    if (!js)
        return;
    bg_scene_destroy(&js->scene);
    memset(js, 0, sizeof *js);
}
