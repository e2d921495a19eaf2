/*
 * The generated platforms' graphs (bgm_platform), read back from the XML
 * they write: the random graph and the scale-free graph connect every
 * host, have the number of links their construction gives, and the
 * scale-free one has hubs (its largest degree well above its mean) where
 * the random one has none.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_config.h"
#include "bgm_platform.h"
#include "bgm_rng.h"

#define NODES 200

typedef struct graph {
    int deg[NODES];
    int adj[NODES][NODES / 2];
    int links; /* host-to-host links */
} graph_t;

/* Writes the platform of `topology` with mean degree `degree` and reads
 * its host-to-host routes back into g. */
static void generate(const char *topology, int degree, graph_t *g)
{
    char json[256];
    snprintf(json, sizeof json,
             "{\"name\":\"p\",\"seed\":3,\"replications\":1,\"duration\":10,"
             "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[%d],\"density\":[1]},"
             "\"network\":{\"topology\":\"%s\",\"degree\":%d}}",
             NODES, topology, degree);
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_config_parse(json, strlen(json), NULL, &cfg, &err))
        fail_msg("config: %s", err.message);
    char *text = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&text, &len);
    assert_non_null(f);
    bgm_rng_t rng;
    bgm_rng_derive(&rng, 3, 0, 0, BGM_PLATFORM_STREAM);
    double speed[NODES + 1];
    assert_int_equal(bgm_platform_write(f, &cfg, cfg.network.topology, NODES, &rng, speed), BG_OK);
    assert_int_equal(fclose(f), 0);
    memset(g, 0, sizeof *g);
    for (const char *p = text; (p = strstr(p, "<route src=\"h")); p++) {
        int a, b;
        if (sscanf(p, "<route src=\"h%d\" dst=\"h%d\"", &a, &b) != 2)
            continue; /* h0 to the core router */
        assert_true(a >= 0 && a < NODES && b >= 0 && b < NODES && a != b);
        assert_true(g->deg[a] < NODES / 2 && g->deg[b] < NODES / 2);
        g->adj[a][g->deg[a]++] = b;
        g->adj[b][g->deg[b]++] = a;
        g->links++;
    }
    free(text);
}

static int connected(const graph_t *g)
{
    int seen[NODES] = {0}, queue[NODES], head = 0, tail = 0;
    seen[0] = 1;
    queue[tail++] = 0;
    while (head < tail) {
        int u = queue[head++];
        for (int k = 0; k < g->deg[u]; k++)
            if (!seen[g->adj[u][k]]) {
                seen[g->adj[u][k]] = 1;
                queue[tail++] = g->adj[u][k];
            }
    }
    return tail == NODES;
}

static int max_degree(const graph_t *g)
{
    int m = 0;
    for (int i = 0; i < NODES; i++)
        m = g->deg[i] > m ? g->deg[i] : m;
    return m;
}

static void test_scale_free(void **state)
{
    (void)state;
    static graph_t g;
    generate("scale-free", 4, &g);
    /* m = 2: a clique of 3 hosts (3 links), then 2 links for each of the
     * other 197. */
    assert_int_equal(g.links, 3 + 2 * (NODES - 3));
    assert_true(connected(&g));
    for (int i = 0; i < NODES; i++)
        assert_true(g.deg[i] >= 2);
    /* Preferential attachment grows hubs: with mean degree 4 the largest
     * is several times that (about sqrt(n) m in expectation). */
    assert_true(max_degree(&g) >= 4 * 4);
}

static void test_random_graph(void **state)
{
    (void)state;
    static graph_t g;
    generate("random", 4, &g);
    /* A ring (NODES links) plus up to 2 chords per host. */
    assert_true(g.links > NODES && g.links <= NODES + 2 * NODES);
    assert_true(connected(&g));
    /* Uniform chords give no hubs: a Poisson-like degree far below the
     * scale-free graph's largest. */
    assert_true(max_degree(&g) < 4 * 4);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_scale_free),
        cmocka_unit_test(test_random_graph),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
