#include "bga_zap.h"

#include <arpa/inet.h>
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <netinet/in.h>
#include <pthread.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <zmq.h>

#include "bg_clock.h"

#define ZAP_ENDPOINT "inproc://zeromq.zap.01"
#define ZAP_FRAMES 8       /* a CURVE request has 7 */
#define ZAP_FRAME_MAX 512  /* bytes kept of one frame (a key is 32, an address ~50) */
#define RELOAD_SECONDS 1.0 /* a changed folder is read again at most this often */
#define CONNECTIONS 64     /* accepted connections whose address a watch remembers */
#define RECENT 64          /* refusals remembered for the repeat rule */
#define LINE_MAX_BYTES 640
#define CMD_STOP "STOP"
#define CMD_WATCH "WATCH"

typedef struct entry {
    char name[BGA_CURVE_NAME_MAX];
    char key[BGA_CURVE_KEY_SIZE];
} entry_t;

typedef struct allow {
    entry_t *e;
    int n;
} allow_t;

/* One watched socket: its monitor's PAIR and what its events tell. */
typedef struct watch {
    void *pair;
    char label[160];
    int server;
    struct {
        int fd;
        char address[80];
    } conn[CONNECTIONS];
    int next_conn;
    uint16_t pending; /* a handshake failure waiting for its DISCONNECTED */
    uint32_t pending_value;
} watch_t;

/* A refusal logged lately: its text's hash, when, and how many since. */
typedef struct recent {
    uint64_t hash;
    double last;
    long repeats;
} recent_t;

struct bga_zap {
    void *ctx;
    void *control; /* PAIR, the owner's end */
    pthread_t thread;
    int started;
    int initial;
    /* The handler thread's alone once it runs. */
    void *rep;        /* the ZAP endpoint */
    void *control_in; /* PAIR, the thread's end */
    char folder[PATH_MAX];
    int use_folder;
    char whose[160];
    allow_t allow;
    double loaded_at;
    struct timespec folder_mtime;
    watch_t *watch[BGA_ZAP_MAX_WATCHES];
    int nwatch;
    recent_t recent[RECENT];
    int next_recent;
    bga_zap_log_fn log;
    void *log_ctx;
};

/* ------------------------------------------------------------ logging */

static uint64_t hash_text(const char *s)
{
    uint64_t h = 1469598103934665603ull;
    for (; *s; s++)
        h = (h ^ (uint8_t)*s) * 1099511628211ull;
    return h;
}

/* Logs line unless the same refusal (`same`: the line without what
 * changes between retries, such as a port) was logged within the repeat
 * window; then it is counted and the next line says how many. */
static void note(bga_zap_t *z, const char *same, const char *line)
{
    if (!z->log)
        return;
    const uint64_t h = hash_text(same);
    const double now = bg_clock_now();
    recent_t *r = NULL;
    for (int i = 0; i < RECENT && !r; i++)
        if (z->recent[i].last > 0 && z->recent[i].hash == h)
            r = &z->recent[i];
    if (r && now - r->last < BGA_ZAP_LOG_REPEAT) {
        r->repeats++;
        return;
    }
    char text[LINE_MAX_BYTES + 96];
    if (r && r->repeats > 0)
        snprintf(text, sizeof text, "%s (and %ld times more since %.0f s ago)", line, r->repeats,
                 now - r->last);
    else
        snprintf(text, sizeof text, "%s", line);
    if (!r) {
        r = &z->recent[z->next_recent];
        z->next_recent = (z->next_recent + 1) % RECENT;
    }
    r->hash = h;
    r->last = now;
    r->repeats = 0;
    z->log(z->log_ctx, text);
}

/* ---------------------------------------------------------- allowlist */

static int by_name(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

static void allow_free(allow_t *a)
{
    free(a->e);
    a->e = NULL;
    a->n = 0;
}

static const entry_t *allow_find(const allow_t *a, const char *key)
{
    for (int i = 0; i < a->n; i++)
        if (strcmp(a->e[i].key, key) == 0)
            return &a->e[i];
    return NULL;
}

/* Adds name ↔ key; a key already listed is refused naming both files. */
static bg_status allow_add(allow_t *a, const char *name, const char *key, const char *where,
                           bg_error_t *err)
{
    const entry_t *dup = allow_find(a, key);
    if (dup)
        return bg_error_set(err, BG_ERR_INVALID,
                            "%s holds the key of '%s' too: a key names one agent", where,
                            dup->name);
    for (int i = 0; i < a->n; i++)
        if (strcmp(a->e[i].name, name) == 0)
            return bg_error_set(err, BG_ERR_INVALID, "%s: the name '%s' is listed twice", where,
                                name);
    if (a->n == BGA_ZAP_MAX_KEYS)
        return bg_error_set(err, BG_ERR_LIMIT, "%s: more than %d keys", where, BGA_ZAP_MAX_KEYS);
    entry_t *e = realloc(a->e, (size_t)(a->n + 1) * sizeof *e);
    if (!e)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the allowlist");
    a->e = e;
    snprintf(e[a->n].name, sizeof e[a->n].name, "%s", name);
    snprintf(e[a->n].key, sizeof e[a->n].key, "%s", key);
    a->n++;
    return BG_OK;
}

/*
 * Every NAME.pub of the folder, in name order (hidden files and other
 * names are not key files). Strict: the first bad file fails the whole.
 * Lenient (z given): a bad file is logged and skipped.
 */
static bg_status load_folder(const char *folder, allow_t *out, bga_zap_t *z, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    DIR *d = opendir(folder);
    if (!d)
        return bg_error_set(err, errno == ENOENT || errno == ENOTDIR ? BG_ERR_INVALID : BG_ERR_IO,
                            "%s: %s", folder, strerror(errno));
    char **names = NULL;
    size_t count = 0, cap = 0;
    bg_status st = BG_OK;
    const size_t suffix = strlen(BGA_CURVE_PUBLIC_SUFFIX);
    for (struct dirent *de; st == BG_OK && (de = readdir(d)) != NULL;) {
        const size_t n = strlen(de->d_name);
        if (de->d_name[0] == '.' || n <= suffix ||
            strcmp(de->d_name + n - suffix, BGA_CURVE_PUBLIC_SUFFIX) != 0)
            continue;
        if (count == BGA_ZAP_MAX_KEYS + 1)
            break;
        if (count == cap) {
            cap = cap ? 2 * cap : 16;
            char **grown = realloc(names, cap * sizeof *names);
            if (!grown) {
                st = bg_error_set(err, BG_ERR_NOMEM, "out of memory reading %s", folder);
                break;
            }
            names = grown;
        }
        if (!(names[count] = strdup(de->d_name)))
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory reading %s", folder);
        else
            count++;
    }
    closedir(d);
    if (st == BG_OK && names)
        qsort(names, count, sizeof *names, by_name);
    for (size_t i = 0; st == BG_OK && i < count; i++) {
        char path[PATH_MAX], name[BGA_CURVE_NAME_MAX], key[BGA_CURVE_KEY_SIZE];
        bg_error_t ferr = BG_ERROR_INIT;
        bg_status fst = BG_OK;
        if (snprintf(path, sizeof path, "%s/%s", folder, names[i]) >= (int)sizeof path)
            fst = bg_error_set(&ferr, BG_ERR_INVALID, "%s/%s: path too long", folder, names[i]);
        if (fst == BG_OK)
            fst = bga_curve_name_of(path, BGA_CURVE_PUBLIC_SUFFIX, name, &ferr);
        if (fst == BG_OK)
            fst = bga_curve_read_public(path, key, &ferr);
        if (fst == BG_OK)
            fst = allow_add(out, name, key, path, &ferr);
        if (fst == BG_OK)
            continue;
        if (!z || fst == BG_ERR_NOMEM) {
            st = bg_error_set(err, fst, "%s", ferr.message);
        } else {
            char line[LINE_MAX_BYTES];
            snprintf(line, sizeof line, "authorized keys: skipped %.500s", ferr.message);
            note(z, line, line);
        }
    }
    for (size_t i = 0; i < count; i++)
        free(names[i]);
    free(names);
    if (st != BG_OK)
        allow_free(out);
    return st;
}

/* The folder read again when it changed or RELOAD_SECONDS passed; a
 * folder that cannot be read keeps the list it had (and says so). */
static void refresh(bga_zap_t *z)
{
    if (!z->use_folder)
        return;
    const double now = bg_clock_now();
    struct stat st;
    const int changed =
        stat(z->folder, &st) == 0 && (st.st_mtim.tv_sec != z->folder_mtime.tv_sec ||
                                      st.st_mtim.tv_nsec != z->folder_mtime.tv_nsec);
    if (!changed && now - z->loaded_at < RELOAD_SECONDS)
        return;
    allow_t fresh;
    bg_error_t err = BG_ERROR_INIT;
    if (load_folder(z->folder, &fresh, z, &err) != BG_OK) {
        char line[LINE_MAX_BYTES];
        snprintf(line, sizeof line,
                 "authorized keys: cannot read them again (%.400s): the %d "
                 "read before still hold",
                 err.message, z->allow.n);
        note(z, line, line);
        z->loaded_at = now;
        return;
    }
    allow_free(&z->allow);
    z->allow = fresh;
    z->loaded_at = now;
    if (changed)
        z->folder_mtime = st.st_mtim;
}

/* -------------------------------------------------------- ZAP requests */

static void send_frame(void *s, const void *data, size_t size, int more)
{
    (void)zmq_send(s, data, size, more ? ZMQ_SNDMORE : 0);
}

/* The metadata of a reply: one ZMTP property, name and value. */
static size_t property(uint8_t *out, const char *name, const char *value)
{
    const size_t n = strlen(name), v = strlen(value);
    size_t k = 0;
    out[k++] = (uint8_t)n;
    memcpy(out + k, name, n);
    k += n;
    out[k++] = (uint8_t)(v >> 24);
    out[k++] = (uint8_t)(v >> 16);
    out[k++] = (uint8_t)(v >> 8);
    out[k++] = (uint8_t)v;
    memcpy(out + k, value, v);
    return k + v;
}

/* One request read, decided and answered (REP: one reply per request). */
static void on_request(bga_zap_t *z)
{
    zmq_msg_t part[ZAP_FRAMES];
    int count = 0, more = 1;
    while (more) {
        zmq_msg_t m;
        zmq_msg_init(&m);
        if (zmq_msg_recv(&m, z->rep, 0) < 0) {
            zmq_msg_close(&m);
            for (int i = 0; i < count; i++)
                zmq_msg_close(&part[i]);
            return;
        }
        more = zmq_msg_more(&m);
        if (count < ZAP_FRAMES)
            part[count++] = m;
        else
            zmq_msg_close(&m);
    }
    const char *status = "400", *text = "the key is not authorized";
    char name[BGA_CURVE_NAME_MAX] = "", key[BGA_CURVE_KEY_SIZE] = "", address[ZAP_FRAME_MAX] = "?";
    if (count >= 4) {
        const size_t n = zmq_msg_size(&part[3]);
        if (n > 0 && n < sizeof address) {
            memcpy(address, zmq_msg_data(&part[3]), n);
            address[n] = '\0';
        }
    }
    const int version_ok =
        count >= 2 && zmq_msg_size(&part[0]) == 3 && memcmp(zmq_msg_data(&part[0]), "1.0", 3) == 0;
    const int curve = count == 7 && zmq_msg_size(&part[5]) == 5 &&
                      memcmp(zmq_msg_data(&part[5]), "CURVE", 5) == 0 &&
                      zmq_msg_size(&part[6]) == 32;
    char line[LINE_MAX_BYTES];
    if (!version_ok) {
        status = "500";
        text = "ZAP version 1.0 only";
    } else if (!curve) {
        text = "CURVE only";
        snprintf(line, sizeof line, "refused %.100s: not a CURVE request (ZAP, %d frames)", address,
                 count);
        note(z, line, line);
    } else {
        zmq_z85_encode(key, zmq_msg_data(&part[6]), 32);
        refresh(z);
        const entry_t *e = allow_find(&z->allow, key);
        if (e) {
            status = "200";
            text = "OK";
            snprintf(name, sizeof name, "%s", e->name);
        } else {
            if (z->use_folder)
                snprintf(line, sizeof line,
                         "refused %.100s: CURVE key %.40s is not among %.159s (%d in %.200s)",
                         address, key, z->whose, z->allow.n, z->folder);
            else
                snprintf(line, sizeof line, "refused %.100s: CURVE key %.40s is not %.159s",
                         address, key, z->whose);
            note(z, line, line);
        }
    }
    /* The reply: version, request id, status code and text, user id, metadata. */
    send_frame(z->rep, "1.0", 3, 1);
    if (count >= 2)
        send_frame(z->rep, zmq_msg_data(&part[1]), zmq_msg_size(&part[1]), 1);
    else
        send_frame(z->rep, "", 0, 1);
    send_frame(z->rep, status, 3, 1);
    send_frame(z->rep, text, strlen(text), 1);
    send_frame(z->rep, name, strlen(name), 1);
    uint8_t meta[64];
    send_frame(z->rep, meta, name[0] ? property(meta, BGA_ZAP_KEY_PROPERTY, key) : 0, 0);
    for (int i = 0; i < count; i++)
        zmq_msg_close(&part[i]);
}

/* ------------------------------------------------------------ watches */

static const char *protocol_reason(uint32_t code, int server)
{
    switch (code) {
    case ZMQ_PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
        return "no CURVE: it speaks another ZeroMQ security mechanism (plaintext)";
    case ZMQ_PROTOCOL_ERROR_ZMTP_CRYPTOGRAPHIC:
        return server ? "its CURVE hello could not be opened: it does not hold this endpoint's "
                        "public key"
                      : "the peer's CURVE answer could not be opened: its public key is not the "
                        "one this process was given";
    default:
        return NULL;
    }
}

/* The port of a sockaddr (0: not IP). */
static unsigned port_of(const struct sockaddr_storage *sa)
{
    if (sa->ss_family == AF_INET)
        return ntohs(((const struct sockaddr_in *)sa)->sin_port);
    if (sa->ss_family == AF_INET6)
        return ntohs(((const struct sockaddr_in6 *)sa)->sin6_port);
    return 0;
}

/*
 * The peer's address of an accepted connection, read from its fd as the
 * event arrives. libzmq may have closed the fd already (a peer refused at
 * once), and the number may then name another socket of the process: the
 * fd counts only while its local port is the listening endpoint's
 * (`local`, the event's tcp://HOST:PORT).
 */
static void remember(watch_t *w, int fd, const char *local)
{
    struct sockaddr_storage sa, mine;
    socklen_t len = sizeof sa, mine_len = sizeof mine;
    char host[64] = "?";
    unsigned port = 0;
    const char *colon = strrchr(local, ':');
    const unsigned listening = colon ? (unsigned)strtoul(colon + 1, NULL, 10) : 0;
    if (getsockname(fd, (struct sockaddr *)&mine, &mine_len) == 0 && port_of(&mine) == listening &&
        getpeername(fd, (struct sockaddr *)&sa, &len) == 0) {
        if (sa.ss_family == AF_INET) {
            const struct sockaddr_in *in = (const struct sockaddr_in *)&sa;
            inet_ntop(AF_INET, &in->sin_addr, host, sizeof host);
            port = ntohs(in->sin_port);
        } else if (sa.ss_family == AF_INET6) {
            const struct sockaddr_in6 *in6 = (const struct sockaddr_in6 *)&sa;
            inet_ntop(AF_INET6, &in6->sin6_addr, host, sizeof host);
            port = ntohs(in6->sin6_port);
        }
    }
    int slot = -1;
    for (int i = 0; i < CONNECTIONS && slot < 0; i++)
        if (w->conn[i].fd == fd)
            slot = i;
    if (slot < 0) {
        slot = w->next_conn;
        w->next_conn = (w->next_conn + 1) % CONNECTIONS;
    }
    w->conn[slot].fd = fd;
    if (port)
        snprintf(w->conn[slot].address, sizeof w->conn[slot].address, "%s:%u", host, port);
    else /* closed before it could be read: the peer's next try shows it */
        snprintf(w->conn[slot].address, sizeof w->conn[slot].address,
                 "a peer gone before its address was read");
}

/* The address an accepted connection had, forgotten as it closes. */
static void recall(watch_t *w, int fd, char *out, size_t size)
{
    snprintf(out, size, "a peer whose address was not read");
    for (int i = 0; i < CONNECTIONS; i++)
        if (w->conn[i].fd == fd && w->conn[i].address[0]) {
            snprintf(out, size, "%s", w->conn[i].address);
            w->conn[i].fd = -1;
            w->conn[i].address[0] = '\0';
            return;
        }
}

/* A server's refused peer: its line, without the port for the repeat rule. */
static void note_server(bga_zap_t *z, watch_t *w, const char *address, const char *why)
{
    char line[LINE_MAX_BYTES], same[LINE_MAX_BYTES];
    snprintf(line, sizeof line, "%s: refused %s (no key shown): %s", w->label, address, why);
    char host[80];
    snprintf(host, sizeof host, "%s", address);
    char *colon = strrchr(host, ':');
    if (colon)
        *colon = '\0';
    snprintf(same, sizeof same, "%s: refused %s: %s", w->label, host, why);
    note(z, same, line);
}

static void on_event(bga_zap_t *z, watch_t *w, uint16_t event, uint32_t value, const char *peer)
{
    char line[LINE_MAX_BYTES], why[256];
    if (w->server) {
        switch (event) {
        case ZMQ_EVENT_ACCEPTED:
            remember(w, (int)value, peer);
            return;
        case ZMQ_EVENT_HANDSHAKE_SUCCEEDED:
            w->pending = 0;
            return;
        case ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL:
        case ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL:
        case ZMQ_EVENT_HANDSHAKE_FAILED_AUTH:
            /* libzmq reports the connection's DISCONNECTED (with its fd)
             * right after, from the same thread: the address comes then. */
            w->pending = event;
            w->pending_value = value;
            return;
        case ZMQ_EVENT_DISCONNECTED: {
            char address[80];
            recall(w, (int)value, address, sizeof address);
            const uint16_t failed = w->pending;
            const uint32_t code = w->pending_value;
            w->pending = 0;
            if (failed == ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL) {
                snprintf(why, sizeof why,
                         "it left during the CURVE handshake (%s): a plaintext peer, or one "
                         "without this endpoint's public key",
                         strerror((int)code));
            } else if (failed == ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL) {
                const char *r = protocol_reason(code, 1);
                if (r)
                    snprintf(why, sizeof why, "%s", r);
                else
                    snprintf(why, sizeof why, "ZeroMQ protocol error 0x%08x in the handshake",
                             (unsigned)code);
            } else {
                return; /* a peer that was in, or a key refusal the ZAP line told */
            }
            note_server(z, w, address, why);
            return;
        }
        default:
            return;
        }
    }
    /* A client: this process refused by the peer it connects to. */
    if (event == ZMQ_EVENT_HANDSHAKE_FAILED_AUTH) {
        snprintf(line, sizeof line,
                 "%s %s: refused this process's CURVE key (ZAP status %u): the peer does not "
                 "list it among its authorized keys",
                 w->label, peer, (unsigned)value);
    } else if (event == ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL) {
        const char *r = protocol_reason(value, 0);
        if (r)
            snprintf(line, sizeof line, "%s %s: handshake refused: %s", w->label, peer, r);
        else
            snprintf(line, sizeof line, "%s %s: handshake refused: ZeroMQ protocol error 0x%08x",
                     w->label, peer, (unsigned)value);
    } else if (event == ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL) {
        snprintf(line, sizeof line,
                 "%s %s: the peer closed the connection during the CURVE handshake (%s): it may "
                 "not speak CURVE, or not be the server whose key this process was given",
                 w->label, peer, strerror((int)value));
    } else {
        return;
    }
    note(z, line, line);
}

/* Every event waiting on a watch: [event u16, value u32] then the address. */
static void on_watch(bga_zap_t *z, watch_t *w)
{
    for (;;) {
        zmq_msg_t head, addr;
        zmq_msg_init(&head);
        if (zmq_msg_recv(&head, w->pair, ZMQ_DONTWAIT) < 0) {
            zmq_msg_close(&head);
            return;
        }
        uint16_t event = 0;
        uint32_t value = 0;
        const int ok = zmq_msg_size(&head) == 6 && zmq_msg_more(&head);
        if (ok) {
            memcpy(&event, zmq_msg_data(&head), 2);
            memcpy(&value, (const uint8_t *)zmq_msg_data(&head) + 2, 4);
        }
        int more = zmq_msg_more(&head);
        zmq_msg_close(&head);
        char peer[256] = "";
        while (more) {
            zmq_msg_init(&addr);
            if (zmq_msg_recv(&addr, w->pair, 0) < 0) {
                zmq_msg_close(&addr);
                return;
            }
            if (!peer[0] && zmq_msg_size(&addr) < sizeof peer) {
                memcpy(peer, zmq_msg_data(&addr), zmq_msg_size(&addr));
                peer[zmq_msg_size(&addr)] = '\0';
            }
            more = zmq_msg_more(&addr);
            zmq_msg_close(&addr);
        }
        if (ok)
            on_event(z, w, event, value, peer);
    }
}

/* ------------------------------------------------------------ thread */

static void close_watch(watch_t *w)
{
    zmq_close(w->pair);
    free(w);
}

/* A command from the owner: STOP (returns 1), or WATCH with the watch. */
static int on_command(bga_zap_t *z)
{
    char cmd[8] = "";
    watch_t *w = NULL;
    const int n = zmq_recv(z->control_in, cmd, sizeof cmd - 1, 0);
    int more = 0;
    size_t more_len = sizeof more;
    zmq_getsockopt(z->control_in, ZMQ_RCVMORE, &more, &more_len);
    if (more && zmq_recv(z->control_in, &w, sizeof w, 0) != (int)sizeof w)
        w = NULL;
    if (n < 0)
        return 0;
    cmd[n < (int)sizeof cmd ? n : (int)sizeof cmd - 1] = '\0';
    if (strcmp(cmd, CMD_STOP) == 0)
        return 1;
    if (strcmp(cmd, CMD_WATCH) == 0 && w) {
        const int ok = z->nwatch < BGA_ZAP_MAX_WATCHES;
        if (ok)
            z->watch[z->nwatch++] = w;
        else
            close_watch(w);
        zmq_send(z->control_in, ok ? "OK" : "FULL", ok ? 2 : 4, 0);
    }
    return 0;
}

static void *handler_main(void *arg)
{
    bga_zap_t *z = arg;
    for (;;) {
        zmq_pollitem_t items[2 + BGA_ZAP_MAX_WATCHES];
        items[0] = (zmq_pollitem_t){z->rep, 0, ZMQ_POLLIN, 0};
        items[1] = (zmq_pollitem_t){z->control_in, 0, ZMQ_POLLIN, 0};
        for (int i = 0; i < z->nwatch; i++)
            items[2 + i] = (zmq_pollitem_t){z->watch[i]->pair, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(items, 2 + z->nwatch, -1) < 0) {
            if (zmq_errno() == EINTR)
                continue;
            break; /* the context is being terminated */
        }
        /* Events first: a handshake's failure is read before a later request. */
        for (int i = 0; i < z->nwatch; i++)
            if (items[2 + i].revents & ZMQ_POLLIN)
                on_watch(z, z->watch[i]);
        if (items[0].revents & ZMQ_POLLIN)
            on_request(z);
        if ((items[1].revents & ZMQ_POLLIN) && on_command(z))
            break;
    }
    for (int i = 0; i < z->nwatch; i++)
        close_watch(z->watch[i]);
    z->nwatch = 0;
    zmq_close(z->rep);
    zmq_close(z->control_in);
    z->rep = z->control_in = NULL;
    return NULL;
}

/* ------------------------------------------------------------ public */

bg_status bga_zap_new(void *zmq_ctx, const bga_zap_config_t *c, bga_zap_t **out, bg_error_t *err)
{
    *out = NULL;
    if (!bga_curve_available())
        return bg_error_set(err, BG_ERR_UNSUPPORTED,
                            "this libzmq was built without CURVE (zmq_has(\"curve\") is 0)");
    bga_zap_t *z = calloc(1, sizeof *z);
    if (!z)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the ZAP handler");
    z->ctx = zmq_ctx;
    z->log = c->log;
    z->log_ctx = c->log_ctx;
    snprintf(z->whose, sizeof z->whose, "%s", c->whose ? c->whose : "the authorized agents' keys");
    bg_status st = BG_OK;
    if (c->folder) {
        z->use_folder = 1;
        if (snprintf(z->folder, sizeof z->folder, "%s", c->folder) >= (int)sizeof z->folder)
            st = bg_error_set(err, BG_ERR_INVALID, "%s: path too long", c->folder);
        struct stat fs;
        if (st == BG_OK && stat(c->folder, &fs) == 0)
            z->folder_mtime = fs.st_mtim;
        if (st == BG_OK)
            st = load_folder(c->folder, &z->allow, NULL, err);
        z->loaded_at = bg_clock_now();
    } else {
        for (int i = 0; st == BG_OK && i < c->count; i++) {
            if (!bga_curve_key_valid(c->keys[i]) || !bga_curve_name_valid(c->names[i]))
                st = bg_error_set(err, BG_ERR_INVALID, "allowlist entry %d: not a named CURVE key",
                                  i);
            else
                st = allow_add(&z->allow, c->names[i], c->keys[i], "allowlist", err);
        }
    }
    z->initial = z->allow.n;
    if (st != BG_OK)
        goto fail;
    const int linger = 0;
    char control[64];
    snprintf(control, sizeof control, "inproc://bga-zap-control-%p", (void *)z);
    z->rep = zmq_socket(zmq_ctx, ZMQ_REP);
    z->control = zmq_socket(zmq_ctx, ZMQ_PAIR);
    z->control_in = zmq_socket(zmq_ctx, ZMQ_PAIR);
    if (!z->rep || !z->control || !z->control_in) {
        st = bg_error_set(err, BG_ERR_IO, "cannot make the ZAP handler's sockets: %s",
                          zmq_strerror(zmq_errno()));
        goto fail;
    }
    zmq_setsockopt(z->rep, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(z->control, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(z->control_in, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_bind(z->rep, ZAP_ENDPOINT) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot bind %s (a second handler?): %s", ZAP_ENDPOINT,
                          zmq_strerror(zmq_errno()));
        goto fail;
    }
    if (zmq_bind(z->control, control) != 0 || zmq_connect(z->control_in, control) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot connect the ZAP handler's control: %s",
                          zmq_strerror(zmq_errno()));
        goto fail;
    }
    /* The handler takes no signal: the daemon's main thread does. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    const int rc = pthread_create(&z->thread, NULL, handler_main, z);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot start the ZAP handler's thread");
        goto fail;
    }
    z->started = 1;
    *out = z;
    return BG_OK;
fail:
    bga_zap_destroy(&z);
    return st;
}

bg_status bga_zap_watch(bga_zap_t *z, void *socket, const char *label, int server, bg_error_t *err)
{
    static const int events = ZMQ_EVENT_ACCEPTED | ZMQ_EVENT_DISCONNECTED |
                              ZMQ_EVENT_HANDSHAKE_SUCCEEDED | ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL |
                              ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL | ZMQ_EVENT_HANDSHAKE_FAILED_AUTH;
    watch_t *w = calloc(1, sizeof *w);
    if (!w)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory watching %s", label);
    for (int i = 0; i < CONNECTIONS; i++)
        w->conn[i].fd = -1;
    snprintf(w->label, sizeof w->label, "%s", label);
    w->server = server;
    char endpoint[96];
    snprintf(endpoint, sizeof endpoint, "inproc://bga-zap-watch-%p", (void *)w);
    const int linger = 0;
    if (zmq_socket_monitor(socket, endpoint, events) != 0 ||
        !(w->pair = zmq_socket(z->ctx, ZMQ_PAIR)) ||
        zmq_setsockopt(w->pair, ZMQ_LINGER, &linger, sizeof linger) != 0 ||
        zmq_connect(w->pair, endpoint) != 0) {
        const int e = zmq_errno();
        if (w->pair)
            zmq_close(w->pair);
        free(w);
        return bg_error_set(err, BG_ERR_IO, "cannot watch %s: %s", label, zmq_strerror(e));
    }
    /* The thread takes the watch over; the answer says it listens. */
    char answer[8] = "";
    if (zmq_send(z->control, CMD_WATCH, strlen(CMD_WATCH), ZMQ_SNDMORE) < 0 ||
        zmq_send(z->control, &w, sizeof w, 0) < 0) {
        close_watch(w);
        return bg_error_set(err, BG_ERR_IO, "cannot watch %s: the ZAP handler is gone", label);
    }
    const int n = zmq_recv(z->control, answer, sizeof answer - 1, 0);
    if (n != 2 || memcmp(answer, "OK", 2) != 0)
        return bg_error_set(err, BG_ERR_LIMIT, "cannot watch %s: %d sockets are watched already",
                            label, BGA_ZAP_MAX_WATCHES);
    return BG_OK;
}

bg_status bga_zap_check_folder(const char *folder, int *count, bg_error_t *err)
{
    allow_t a;
    *count = 0;
    const bg_status st = load_folder(folder, &a, NULL, err);
    if (st == BG_OK)
        *count = a.n;
    allow_free(&a);
    return st;
}

int bga_zap_count(const bga_zap_t *z)
{
    return z->initial;
}

void bga_zap_destroy(bga_zap_t **zp)
{
    bga_zap_t *z = zp ? *zp : NULL;
    if (!z)
        return;
    if (z->started) {
        (void)zmq_send(z->control, CMD_STOP, strlen(CMD_STOP), 0);
        pthread_join(z->thread, NULL);
    } else {
        if (z->rep)
            zmq_close(z->rep);
        if (z->control_in)
            zmq_close(z->control_in);
    }
    if (z->control)
        zmq_close(z->control);
    allow_free(&z->allow);
    free(z);
    *zp = NULL;
}
