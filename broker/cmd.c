#include "cmd.h"

#include <stdlib.h>
#include <string.h>

#include "bg_file.h"

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
    return bg_file_make_directories(path);
}
