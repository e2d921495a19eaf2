#include "bgm_platform.h"

#include <stdlib.h>

/* The market host sits on a fat link next to the core router: the
 * auctioneer should not be the bottleneck by construction. */
#define BGM_MARKET_BW_FACTOR 10.0
#define BGM_CORE_BW_FACTOR 10.0
#define BGM_MAX_CHORDS 32

static void link_to(FILE *f, const char *id, double bw, double lat)
{
    fprintf(f, "  <link id=\"%s\" bandwidth=\"%.6gBps\" latency=\"%.9gs\"/>\n", id, bw, lat);
}

static void route(FILE *f, const char *src, const char *dst, const char *link)
{
    fprintf(f, "  <route src=\"%s\" dst=\"%s\"><link_ctn id=\"%s\"/></route>\n", src, dst, link);
}

/* A link e<n> between hosts i and j (routes go to rt). */
static void edge(FILE *f, FILE *rt, int *nl, int i, int j, double bw, double lat)
{
    char a[32], b[32], l[32];
    snprintf(l, sizeof l, "e%d", (*nl)++);
    snprintf(a, sizeof a, "h%d", i);
    snprintf(b, sizeof b, "h%d", j);
    link_to(f, l, bw, lat);
    route(rt, a, b, l);
}

/* A ring for connectivity plus degree/2 random chords per host. */
static void random_graph(FILE *f, FILE *rt, const bgm_config_t *c, int nodes, bgm_rng_t *rng)
{
    const double bw = c->network.bandwidth, lat = c->network.latency;
    int extra = c->network.degree / 2;
    int nl = 0;
    for (int i = 0; i < nodes && nodes > 1; i++) {
        if (nodes == 2 && i == 1)
            break;
        edge(f, rt, &nl, i, (i + 1) % nodes, bw, lat);
    }
    for (int i = 0; i < nodes && nodes > 3; i++) {
        int chosen[BGM_MAX_CHORDS];
        int nc = 0;
        for (int k = 0; k < extra && k < BGM_MAX_CHORDS; k++) {
            /* Chords go to higher indices only, so a pair is listed once. */
            int j = (int)bgm_rng_below(rng, (uint32_t)nodes);
            int dup = 0;
            for (int q = 0; q < nc; q++)
                dup |= chosen[q] == j;
            if (dup || j <= i + 1 || (i == 0 && j == nodes - 1))
                continue;
            chosen[nc++] = j;
            edge(f, rt, &nl, i, j, bw, lat);
        }
    }
}

/*
 * A scale-free graph by preferential attachment (Barabasi and Albert,
 * "Emergence of scaling in random networks", Science 286, 1999): the
 * first m + 1 hosts form a clique, then each host links to m distinct
 * earlier hosts drawn with probability proportional to their degree
 * (uniformly from the list of every link's two ends), m = degree / 2 (at
 * least 1). Mean degree about 2m, a few hubs of high degree and many
 * hosts of degree m: the shape measured in unstructured peer-to-peer
 * overlays (Ripeanu, Foster and Iamnitchi, "Mapping the Gnutella
 * network", IEEE Internet Computing 6(1), 2002).
 */
static bg_status scale_free(FILE *f, FILE *rt, const bgm_config_t *c, int nodes, bgm_rng_t *rng)
{
    const double bw = c->network.bandwidth, lat = c->network.latency;
    int m = c->network.degree / 2 > 0 ? c->network.degree / 2 : 1;
    if (m > BGM_MAX_CHORDS)
        m = BGM_MAX_CHORDS;
    const int core = m + 1 < nodes ? m + 1 : nodes;
    int *ends =
        malloc(((size_t)core * (size_t)core + 2 * (size_t)m * (size_t)nodes) * sizeof *ends);
    if (!ends)
        return BG_ERR_NOMEM;
    size_t nends = 0;
    int nl = 0;
    for (int i = 0; i < core; i++)
        for (int j = i + 1; j < core; j++) {
            edge(f, rt, &nl, i, j, bw, lat);
            ends[nends++] = i;
            ends[nends++] = j;
        }
    for (int i = core; i < nodes; i++) {
        int chosen[BGM_MAX_CHORDS];
        int nc = 0;
        while (nc < m && nc < i) {
            int j = nends ? ends[bgm_rng_below(rng, (uint32_t)nends)]
                          : (int)bgm_rng_below(rng, (uint32_t)i);
            int dup = 0;
            for (int q = 0; q < nc; q++)
                dup |= chosen[q] == j;
            if (!dup)
                chosen[nc++] = j;
        }
        for (int q = 0; q < nc; q++) {
            edge(f, rt, &nl, chosen[q], i, bw, lat);
            ends[nends++] = chosen[q];
            ends[nends++] = i;
        }
    }
    free(ends);
    return BG_OK;
}

bg_status bgm_platform_write(FILE *f, const bgm_config_t *c, int topology, int nodes,
                             bgm_rng_t *rng, double *speed)
{
    /* The DTD wants every link before the first route: routes go to a
     * memory stream first and are appended at the end. */
    char *routes_text = NULL;
    size_t routes_len = 0;
    FILE *rt = open_memstream(&routes_text, &routes_len);
    if (!rt)
        return BG_ERR_NOMEM;
    bg_status st = BG_OK;
    double bw = c->network.bandwidth, lat = c->network.latency;
    fprintf(f, "<?xml version='1.0'?>\n"
               "<!DOCTYPE platform SYSTEM \"https://simgrid.org/simgrid.dtd\">\n"
               "<platform version=\"4.1\">\n<zone id=\"grid\" routing=\"DijkstraCache\">\n");
    for (int i = 0; i < nodes; i++) {
        speed[i] = c->network.speed *
                   (1.0 + c->network.speed_spread * (2.0 * bgm_rng_uniform(rng) - 1.0));
        fprintf(f, "  <host id=\"h%d\" speed=\"%.9gf\"/>\n", i, speed[i]);
    }
    speed[nodes] = c->network.speed;
    fprintf(f, "  <host id=\"market\" speed=\"%.9gf\"/>\n", speed[nodes]);
    fprintf(f, "  <router id=\"core\"/>\n");
    char a[64], b[64], l[64];
    switch (topology) {
    case BGM_TOPO_STAR:
        for (int i = 0; i < nodes; i++) {
            snprintf(l, sizeof l, "l%d", i);
            snprintf(a, sizeof a, "h%d", i);
            link_to(f, l, bw, lat);
            route(rt, a, "core", l);
        }
        break;
    case BGM_TOPO_CLUSTER: {
        int racks = (nodes + BGM_RACK_SIZE - 1) / BGM_RACK_SIZE;
        for (int r = 0; r < racks; r++) {
            snprintf(a, sizeof a, "rack%d", r);
            snprintf(l, sizeof l, "up%d", r);
            fprintf(f, "  <router id=\"%s\"/>\n", a);
            link_to(f, l, bw * BGM_CORE_BW_FACTOR, lat);
            route(rt, a, "core", l);
        }
        for (int i = 0; i < nodes; i++) {
            snprintf(l, sizeof l, "l%d", i);
            snprintf(a, sizeof a, "h%d", i);
            snprintf(b, sizeof b, "rack%d", i / BGM_RACK_SIZE);
            link_to(f, l, bw, lat / 10.0);
            route(rt, a, b, l);
        }
        break;
    }
    case BGM_TOPO_RANDOM:
        random_graph(f, rt, c, nodes, rng);
        break;
    default:
        st = scale_free(f, rt, c, nodes, rng);
        break;
    }
    if (st) {
        fclose(rt);
        goto out;
    }
    if (topology == BGM_TOPO_RANDOM || topology == BGM_TOPO_SCALEFREE) {
        /* The core router joins host 0 so the market reaches everyone. */
        link_to(f, "l0", bw * BGM_CORE_BW_FACTOR, lat);
        route(rt, "h0", "core", "l0");
    }
    link_to(f, "lmarket", bw * BGM_MARKET_BW_FACTOR, lat);
    route(rt, "market", "core", "lmarket");
    if (fclose(rt) != 0) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    fwrite(routes_text, 1, routes_len, f);
    fprintf(f, "</zone>\n</platform>\n");
    if (ferror(f))
        st = BG_ERR_IO;
out:
    free(routes_text);
    return st;
}
