/* bg_clock — monotonic wall time in seconds, for traces and benchmarks. */
#ifndef BG_CLOCK_H
#define BG_CLOCK_H

double bg_clock_now(void);

#endif
