/*
 * slow_clients — misbehaving HTTP clients against a REST server, and a
 * well-behaved probe beside them.
 *
 *   slow_clients HOST PORT CLIENTS SECONDS [--idle]
 *
 * Opens CLIENTS connections that each send half a request (the headers of
 * a POST announcing a 1 MB body, then one byte of it; with --idle, nothing
 * at all) and then hold the connection open, sending one more byte every
 * 2 s (a slowloris). Meanwhile, every 0.25 s for SECONDS, a probe connects
 * afresh and asks GET /healthz with a 2 s deadline. Prints one line:
 *   clients H held of C, probes OK/N answered, worst probe T s
 * and exits 0 when at least 95 % of the probes were answered with 200, 1
 * otherwise. Every socket it opens is closed before it exits.
 */
#define _DEFAULT_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_CLIENTS 4000
#define PROBE_PERIOD 0.25
#define PROBE_DEADLINE 2.0
#define TRICKLE_PERIOD 2.0

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int connect_to(const struct sockaddr_in *addr, double deadline)
{
    const int fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    if (connect(fd, (const struct sockaddr *)addr, sizeof *addr) != 0 && errno != EINPROGRESS) {
        close(fd);
        return -1;
    }
    struct pollfd p = {fd, POLLOUT, 0};
    const int ms = (int)((deadline - now()) * 1e3);
    int err = 0;
    socklen_t len = sizeof err;
    if (ms <= 0 || poll(&p, 1, ms) != 1 || getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len) != 0 ||
        err != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

/* One GET /healthz on a fresh connection: 1 when answered 200 in time. */
static int probe(const struct sockaddr_in *addr, double *seconds)
{
    const double t0 = now(), deadline = t0 + PROBE_DEADLINE;
    const int fd = connect_to(addr, deadline);
    int ok = 0;
    if (fd >= 0) {
        static const char req[] =
            "GET /healthz HTTP/1.1\r\nHost: probe\r\nConnection: close\r\n\r\n";
        if (send(fd, req, sizeof req - 1, MSG_NOSIGNAL) == (ssize_t)(sizeof req - 1)) {
            char buf[64];
            size_t got = 0;
            while (got < 12) {
                struct pollfd p = {fd, POLLIN, 0};
                const int ms = (int)((deadline - now()) * 1e3);
                if (ms <= 0 || poll(&p, 1, ms) != 1)
                    break;
                const ssize_t n = recv(fd, buf + got, sizeof buf - 1 - got, 0);
                if (n <= 0)
                    break;
                got += (size_t)n;
            }
            buf[got] = '\0';
            ok = strncmp(buf, "HTTP/1.1 200", 12) == 0 || strncmp(buf, "HTTP/1.0 200", 12) == 0;
        }
        close(fd);
    }
    *seconds = now() - t0;
    return ok;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fputs("usage: slow_clients HOST PORT CLIENTS SECONDS [--idle]\n", stderr);
        return 2;
    }
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t)atoi(argv[2]));
    const int clients = atoi(argv[3]);
    const double seconds = atof(argv[4]);
    const int idle = argc > 5 && strcmp(argv[5], "--idle") == 0;
    if (inet_pton(AF_INET, argv[1], &addr.sin_addr) != 1 || clients < 0 || clients > MAX_CLIENTS ||
        !(seconds > 0)) {
        fputs("slow_clients: bad arguments\n", stderr);
        return 2;
    }
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < (rlim_t)clients + 64) {
        rl.rlim_cur = rl.rlim_max < (rlim_t)clients + 64 ? rl.rlim_max : (rlim_t)clients + 64;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    static int fds[MAX_CLIENTS];
    int held = 0;
    static const char head[] = "POST /v1/jobs HTTP/1.1\r\nHost: slow\r\nContent-Type: "
                               "application/json\r\nContent-Length: 1000000\r\n\r\n{";
    for (int i = 0; i < clients; i++) {
        const int fd = connect_to(&addr, now() + 1.0);
        if (fd < 0)
            continue;
        if (!idle)
            (void)send(fd, head, sizeof head - 1, MSG_NOSIGNAL);
        fds[held++] = fd;
    }
    int probes = 0, answered = 0;
    double worst = 0.0, next_trickle = now() + TRICKLE_PERIOD;
    const double end = now() + seconds;
    while (now() < end) {
        double t = 0.0;
        answered += probe(&addr, &t);
        probes++;
        worst = t > worst ? t : worst;
        if (!idle && now() >= next_trickle) {
            for (int i = 0; i < held; i++)
                (void)send(fds[i], " ", 1, MSG_NOSIGNAL | MSG_DONTWAIT);
            next_trickle = now() + TRICKLE_PERIOD;
        }
        const double rest = PROBE_PERIOD - t;
        if (rest > 0)
            usleep((useconds_t)(rest * 1e6));
    }
    /* How many of the slow connections the server still kept open. */
    int open = 0;
    for (int i = 0; i < held; i++) {
        struct pollfd p = {fds[i], POLLIN, 0};
        char c;
        const int r = poll(&p, 1, 0);
        open += r == 0 || (r == 1 && recv(fds[i], &c, 1, MSG_PEEK | MSG_DONTWAIT) > 0);
        close(fds[i]);
    }
    printf("clients %d held of %d (%d still open at the end), probes %d/%d answered, worst probe "
           "%.3f s\n",
           held, clients, open, answered, probes, worst);
    return probes > 0 && answered * 100 >= probes * 95 ? 0 : 1;
}
