#include "cmd.h"

#include <limits.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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

int bg_cmd_mesh_folder(char *buf, size_t size)
{
    char exe[PATH_MAX];
    const ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n <= 0)
        return -1;
    exe[n] = '\0';
    char *slash = strrchr(exe, '/');
    if (!slash)
        return -1;
    *slash = '\0';
    char folder[PATH_MAX + sizeof BG_CMD_MESH_FOLDER + 8], real[PATH_MAX];
    if (snprintf(folder, sizeof folder, "%s/../" BG_CMD_MESH_FOLDER, exe) >= (int)sizeof folder)
        return -1;
    /* Messages name the folder as users would type it; a folder that does
     * not exist (no meshes made) is kept as it is. */
    const char *name = bg_file_canonical(folder, real, sizeof real) == 0 ? real : folder;
    const int written = snprintf(buf, size, "%s", name);
    return written > 0 && (size_t)written < size ? 0 : -1;
}

int bg_cmd_mesh_path_finish(char *buf, size_t size)
{
    const char *env = getenv(BG_CMD_MESH_PATH_ENV);
    if (env && bg_cmd_mesh_path_add(buf, size, env) != 0)
        return -1;
    char folder[PATH_MAX + sizeof BG_CMD_MESH_FOLDER + 8];
    /* No folder of its own (no /proc): the user's folders still serve. */
    return bg_cmd_mesh_folder(folder, sizeof folder) == 0 ? bg_cmd_mesh_path_add(buf, size, folder)
                                                          : 0;
}

const char *bg_cmd_grid_dir(const char *option)
{
    const char *env = getenv(BG_CMD_GRID_DIR_ENV);
    return option ? option : env && env[0] ? env : BG_CMD_GRID_DIR;
}

int bg_cmd_make_directories(const char *path)
{
    return bg_file_make_directories(path);
}

volatile sig_atomic_t bg_cmd_stop_requested;

static pthread_mutex_t stop_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t stop_cond = PTHREAD_COND_INITIALIZER;
static sigset_t stop_signals;

/* The one place SIGTERM and SIGINT are received: every thread blocks them
 * and this one takes them with sigwait, so no handler ever runs on a
 * thread's stack. (METIS, through CHOLMOD, installs its own SIGTERM
 * handler while it orders a matrix, one that longjmps to the ordering
 * thread's stack: delivered to another thread, it crashed the broker.) */
static void *stop_waiter(void *arg)
{
    (void)arg;
    for (;;) {
        int sig = 0;
        if (sigwait(&stop_signals, &sig) != 0)
            continue;
        pthread_mutex_lock(&stop_lock);
        bg_cmd_stop_requested = 1;
        pthread_cond_broadcast(&stop_cond);
        pthread_mutex_unlock(&stop_lock);
    }
    return NULL;
}

void bg_cmd_daemon_reexec(char **argv)
{
    sigset_t set, old;
    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    pthread_sigmask(SIG_BLOCK, &set, &old);
    if (sigismember(&old, SIGTERM) && sigismember(&old, SIGINT))
        return; /* born blocked: every thread has the mask */
    /* A signal that arrives from here on stays pending across the exec
     * and is taken by the new image's waiter. */
    /* The program's own path, so that its name (comm) stays "biotgrid". */
    char self[PATH_MAX];
    const ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n > 0) {
        self[n] = '\0';
        execv(self, argv);
    }
    /* No /proc: go on; a stop signal may then reach a library's thread. */
}

void bg_cmd_stop_on_signals(void)
{
    sigemptyset(&stop_signals);
    sigaddset(&stop_signals, SIGTERM);
    sigaddset(&stop_signals, SIGINT);
    pthread_sigmask(SIG_BLOCK, &stop_signals, NULL);
    pthread_t waiter;
    if (pthread_create(&waiter, NULL, stop_waiter, NULL) == 0) {
        pthread_detach(waiter);
    } else {
        /* No thread to take them: the default action (exit) stays. */
        pthread_sigmask(SIG_UNBLOCK, &stop_signals, NULL);
    }
}

void bg_cmd_wait_for_stop(void)
{
    pthread_mutex_lock(&stop_lock);
    while (!bg_cmd_stop_requested)
        pthread_cond_wait(&stop_cond, &stop_lock);
    pthread_mutex_unlock(&stop_lock);
}

int bg_cmd_write_ready_file(const char *path, const char *line)
{
    char tmp[PATH_MAX];
    if (snprintf(tmp, sizeof tmp, "%s.tmp", path) >= (int)sizeof tmp)
        return -1;
    FILE *f = fopen(tmp, "w");
    if (!f)
        return -1;
    const int ok = fputs(line, f) >= 0;
    if (fclose(f) != 0 || !ok)
        return -1;
    return rename(tmp, path);
}
