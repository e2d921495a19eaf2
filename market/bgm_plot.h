/*
 * bgm_plot — the experiment plots as standalone SVG: one line per
 * mechanism with a marker at every measured point and, where an interval
 * is given, its 95 % confidence band shaded behind the line. Linear axes.
 * Points with a non-finite x or y are skipped (the line breaks there); a
 * non-finite bound leaves the band out at that point. All arrays are
 * borrowed for the call; nothing is kept.
 */
#ifndef BGM_PLOT_H
#define BGM_PLOT_H

#include <stddef.h>

#include "bg_error.h"

#define BGM_PLOT_MAX_SERIES 8

typedef struct bgm_plot_series {
    const char *label;
    const double *x, *y;
    const double *lo, *hi; /* the interval per point, or NULL: no band */
    size_t count;
} bgm_plot_series_t;

typedef struct bgm_plot {
    const char *title;
    const char *x_label;
    const char *y_label;
    const char *note; /* a line under the title (what the bands are), or NULL */
} bgm_plot_t;

/* Writes the plot to path (at most BGM_PLOT_MAX_SERIES series). */
bg_status bgm_plot_write(const char *path, const bgm_plot_t *plot, const bgm_plot_series_t *series,
                         int count, bg_error_t *err);

#endif
