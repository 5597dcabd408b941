/* The post-flight smoother's recorder (postflight/smoother.py SmootherRecorder), host build only: built
 * with BW_HOST_RECORDER (firmware_c/build.py defines it for the host library; the Cortex-M4F build never
 * sees it, its code, RAM and instruction counts are those without a recorder).
 *
 * The filter (ekf.c) tells the active recorder every prediction (F), every fusion (h, 1/S, innovation, K;
 * the three-row vector fusions) and every inhibition (the chain is cut), at the very places ekf.py calls
 * ``WindEkf.recorder``. The recorder folds them, in double, into Pi, g, G between two output grid points;
 * host/reprocess.c makes the grid (postflight/reprocess.py _Run.feed) and hands each point to Python. A
 * recorder is active only during a host/reprocess.c call, for the one filter it names (``ekf``). */
#ifndef BW_RECORDER_H
#define BW_RECORDER_H

#include "bw_core.h"

#ifdef BW_HOST_RECORDER
typedef struct bw_recorder {
    const bw_ekf_t *ekf; /* the filter it records */
    double Pi[BW_N][BW_N], g[BW_N], G[BW_N][BW_N], tmp[BW_N][BW_N];
    int32_t linked; /* the next grid point links to the one before (no break in between) */
    /* the grid (postflight/reprocess.py _Run): the chain's signature, the grid's step, gaps, the air */
    int32_t sig_init, sig_mode, sig_resets, gap;
    int64_t every, last_grid, prev_us;
    double press, temp;
} bw_recorder_t;

extern __thread bw_recorder_t *bw_recorder_active;

void bw_recorder_reset(bw_recorder_t *r);
void bw_recorder_broken(bw_recorder_t *r);
#endif

#endif
