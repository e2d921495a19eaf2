#include "bgb_limits.h"

#include <math.h>
#include <stdio.h>
#include <unistd.h>

/* The memory model's terms (see the header): a base, and a coefficient on
 * elements^(4/3). */
#define MODEL_BASE_BYTES (64.0 * 1024 * 1024)
#define MODEL_BYTES_PER_ELEMENT43 120.0
#define MODEL_EXPONENT (4.0 / 3.0)
#define UNKNOWN_RAM ((uint64_t)1 << 30)
#define GIB (1024.0 * 1024 * 1024)

void bgb_limits_default(bgb_limits_t *l)
{
    *l = (bgb_limits_t){.memory_fraction = BGB_LIMITS_MEMORY_FRACTION,
                        .max_work = BGB_LIMITS_MAX_WORK,
                        .max_body = BGB_LIMITS_MAX_BODY,
                        .max_jobs_in_flight = BGB_LIMITS_JOBS_IN_FLIGHT,
                        .max_stored_bytes = BGB_LIMITS_STORED_BYTES,
                        .max_connections = BGB_LIMITS_CONNECTIONS,
                        .max_connections_per_client = BGB_LIMITS_CONNECTIONS_PER_CLIENT,
                        .idle_timeout = BGB_LIMITS_IDLE_TIMEOUT,
                        .request_timeout = BGB_LIMITS_REQUEST_TIMEOUT};
}

uint64_t bgb_limits_ram(void)
{
    const long pages = sysconf(_SC_PHYS_PAGES), size = sysconf(_SC_PAGESIZE);
    return pages > 0 && size > 0 ? (uint64_t)pages * (uint64_t)size : 0;
}

double bgb_limits_job_memory(double elements)
{
    return MODEL_BASE_BYTES + MODEL_BYTES_PER_ELEMENT43 * pow(elements, MODEL_EXPONENT);
}

void bgb_limits_resolve(bgb_limits_t *l, uint64_t ram)
{
    const double budget = l->memory_fraction * (double)(ram ? ram : UNKNOWN_RAM);
    double elements = 0.0;
    if (budget > MODEL_BASE_BYTES)
        elements = floor(
            pow((budget - MODEL_BASE_BYTES) / MODEL_BYTES_PER_ELEMENT43, 1.0 / MODEL_EXPONENT));
    if (elements < 1.0)
        elements = 1.0;
    if (l->max_elements <= 0)
        l->max_elements = (int64_t)elements;
    if (l->max_vertices <= 0)
        l->max_vertices = (int64_t)elements;
}

int bgb_limits_describe(const bgb_limits_t *l, uint64_t ram, char *buf, size_t size)
{
    return snprintf(
        buf, size,
        "  max_elements %lld, max_vertices %lld per job (estimated peak %.2f GiB, at most "
        "%.0f %% of %.1f GiB RAM)\n"
        "  max_work %.3g element-steps per job (elements x steps or frames)\n"
        "  max_body %zu bytes per request\n"
        "  max_jobs_in_flight %d, max_stored_bytes %lld per user\n"
        "  max_connections %u, max_connections_per_client %u\n"
        "  idle_timeout %u s, request_timeout %u s\n",
        (long long)l->max_elements, (long long)l->max_vertices,
        bgb_limits_job_memory((double)l->max_elements) / GIB, 100.0 * l->memory_fraction,
        (double)(ram ? ram : UNKNOWN_RAM) / GIB, l->max_work, l->max_body, l->max_jobs_in_flight,
        (long long)l->max_stored_bytes, l->max_connections, l->max_connections_per_client,
        l->idle_timeout, l->request_timeout);
}
