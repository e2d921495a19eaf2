/*
 * bg_svg — line plots as standalone SVG files (no dependencies), for the
 * error-against-run-time plots of solves and the plots of experiments.
 *
 * One plot, several labelled series, linear or logarithmic axes with
 * readable tick labels, a legend. Points with non-finite coordinates, or
 * non-positive ones on a logarithmic axis, are skipped (a series breaks
 * there); a plot with nothing to draw still writes a valid SVG that says
 * so. All arrays are borrowed for the duration of the call.
 */
#ifndef BG_SVG_H
#define BG_SVG_H

#include <stddef.h>

#include "bg_error.h"

typedef struct bg_svg_series {
    const char *label;
    const double *x;
    const double *y;
    size_t count;
} bg_svg_series_t;

typedef struct bg_svg_plot {
    const char *title;
    const char *x_label;
    const char *y_label;
    int log_x;
    int log_y;
} bg_svg_plot_t;

/* Renders the plot to an SVG document in memory; caller frees *svg. */
bg_status bg_svg_render(const bg_svg_plot_t *plot, const bg_svg_series_t *series, int series_count,
                        char **svg, size_t *length, bg_error_t *err);

/* Renders and writes the plot to path. */
bg_status bg_svg_write(const char *path, const bg_svg_plot_t *plot, const bg_svg_series_t *series,
                       int series_count, bg_error_t *err);

#endif
