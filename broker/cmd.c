#include "cmd.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

int bg_cmd_mesh_path_add(char *buf, size_t size, const char *folder)
{
    const size_t used = strlen(buf), add = strlen(folder);
    if (add == 0)
        return 0;
    if (used + (used > 0) + add + 1 > size)
        return -1;
    if (used > 0)
        buf[used] = ':';
    memcpy(buf + used + (used > 0), folder, add + 1);
    return 0;
}

int bg_cmd_mesh_path_finish(char *buf, size_t size)
{
    const char *env = getenv(BG_CMD_MESH_PATH_ENV);
    return env ? bg_cmd_mesh_path_add(buf, size, env) : 0;
}

int bg_cmd_make_directories(const char *path)
{
    char buf[4096];
    size_t len = strlen(path);
    if (len == 0 || len >= sizeof buf) {
        errno = ENAMETOOLONG;
        return -1;
    }
    memcpy(buf, path, len + 1);
    for (size_t i = 1; i <= len; i++) {
        if (buf[i] == '/' || buf[i] == '\0') {
            char saved = buf[i];
            buf[i] = '\0';
            if (mkdir(buf, 0755) != 0 && errno != EEXIST)
                return -1;
            buf[i] = saved;
        }
    }
    struct stat st;
    if (stat(path, &st) != 0)
        return -1;
    if (!S_ISDIR(st.st_mode)) {
        errno = ENOTDIR;
        return -1;
    }
    return 0;
}
