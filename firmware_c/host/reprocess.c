/* Post-flight reprocessing on the C core (host only: firmware_c/build.py adds host/ to the host library
 * and defines BW_HOST_RECORDER): a block of samples through the estimator with the smoother's recorder
 * active (include/bw_recorder.h), the output grid made as postflight/reprocess.py _Run.feed makes it, and
 * each grid point (t, x, P, Pi, g, G, linked, and what the product needs beside the state) written into
 * the caller's arrays: the block storage of postflight/smoother.py SmootherRecorder. */
#include <math.h>
#include <string.h>

#include "bw_core.h"
#include "bw_recorder.h"

#define REPROCESS_IMU 0
#define REPROCESS_BARO 1
#define GAP_STEPS 1.5 /* reprocess.py GAP_STEPS */
#define N_EXTRA 11    /* per grid point beside the state: see bw_reprocess_batch */

__thread bw_recorder_t *bw_recorder_active = 0;

size_t bw_sizeof_recorder(void)
{
    return sizeof(bw_recorder_t);
}

void bw_recorder_reset(bw_recorder_t *r)
{
    int i;
    memset(r->Pi, 0, sizeof r->Pi);
    for (i = 0; i < BW_N; i++)
        r->Pi[i][i] = 1.0;
    memset(r->g, 0, sizeof r->g);
    memset(r->G, 0, sizeof r->G);
}

/* SmootherRecorder.broken: the state was re-placed rather than fused, the chain to the last point is cut */
void bw_recorder_broken(bw_recorder_t *r)
{
    r->linked = 0;
    bw_recorder_reset(r);
}

static void signature(const bw_estimator_t *est, int32_t sig[3])
{
    sig[0] = est->initialised, sig[1] = est->ekf.mode, sig[2] = est->ekf.reset_count;
}

/* A new recorder for est's filter, the grid every ``every`` filter steps (reprocess.py _Run.feed's start) */
void bw_recorder_init(bw_recorder_t *r, const bw_estimator_t *est, int64_t every)
{
    int32_t sig[3];
    memset(r, 0, sizeof *r);
    r->ekf = &est->ekf;
    bw_recorder_reset(r);
    signature(est, sig);
    r->sig_init = sig[0], r->sig_mode = sig[1], r->sig_resets = sig[2];
    r->every = every;
    r->prev_us = -1;
    r->press = r->temp = (double)NAN;
}

static int64_t floordiv(int64_t a, int64_t b)
{
    int64_t q = a / b;
    return (a % b != 0 && (a < 0) != (b < 0)) ? q - 1 : q;
}

/* Samples 0 .. n-1 (kind[i] at t_us[i], v[9 i ..]: REPROCESS_IMU ax ay az gx gy gz mx my mz, REPROCESS_BARO
 * pressure (hPa), temperature (C)) through the estimator as reprocess.py _Run.feed takes them, the recorder
 * active. Each grid point goes to slot *ngrid of the arrays (capacity cap): t, x (N), P (N x N), Pi, g, G
 * (double), linked (a byte), extra (N_EXTRA: mode, unconfirmed, consistency flags, inflation, the reported
 * accuracy, IMU samples missing since the point before, the tether's length, the rope's reel rate, WINCH_STATUS
 * rejected so far, pressure (hPa), temperature (C)). Stops after the sample that fills the last slot.
 * Returns the number of samples done. */
int bw_reprocess_batch(bw_estimator_t *est, bw_recorder_t *r, int n, const int64_t *t_us, const int32_t *kind,
                       const double *v, int cap, int32_t *ngrid, int64_t *gt, double *gx, double *gP, double *gPi,
                       double *gg, double *gG, uint8_t *glinked, double *gextra)
{
    bw_recorder_t *before = bw_recorder_active;
    const bw_ekf_t *e = &est->ekf;
    int i, k, j;
    bw_recorder_active = r;
    for (i = 0; i < n && *ngrid < cap; i++) {
        const double *x = v + 9 * i;
        const int64_t t = t_us[i];
        int32_t sig[3];
        int advanced;
        int64_t grid;
        if (kind[i] == REPROCESS_BARO) {
            r->press = x[0], r->temp = x[1];
            bw_on_baro(est, t, (bw_real)x[0], (bw_real)x[1]);
            continue;
        }
        if (r->prev_us >= 0 && (double)(t - r->prev_us) > GAP_STEPS * (double)est->dt_us)
            r->gap = 1;
        if (t > r->prev_us)
            r->prev_us = t;
        advanced = bw_on_imu(est, t, (bw_real)x[0], (bw_real)x[1], (bw_real)x[2], (bw_real)x[3], (bw_real)x[4],
                             (bw_real)x[5], (bw_real)x[6], (bw_real)x[7], (bw_real)x[8]) == 1;
        signature(est, sig);
        if (sig[0] != r->sig_init || sig[1] != r->sig_mode || sig[2] != r->sig_resets) {
            bw_recorder_broken(r);
            r->sig_init = sig[0], r->sig_mode = sig[1], r->sig_resets = sig[2];
            r->last_grid = floordiv(est->step, r->every) - 1; /* a grid point right after the cut starts it */
        }
        grid = floordiv(est->step, r->every);
        if (advanced && grid > r->last_grid) {
            const int64_t m = *ngrid;
            double *ex = gextra + N_EXTRA * m;
            const int heard = est->winch_samples > 0;
            r->last_grid = grid;
            gt[m] = est->t_last_us;
            for (k = 0; k < BW_N; k++) {
                gx[BW_N * m + k] = (double)e->x[k];
                gg[BW_N * m + k] = r->g[k];
                for (j = 0; j < BW_N; j++) {
                    gP[BW_N * BW_N * m + BW_N * k + j] = (double)e->P[k][j];
                    gPi[BW_N * BW_N * m + BW_N * k + j] = r->Pi[k][j];
                    gG[BW_N * BW_N * m + BW_N * k + j] = r->G[k][j];
                }
            }
            glinked[m] = (uint8_t)(r->linked != 0);
            ex[0] = e->mode;
            ex[1] = est->unconfirmed;
            ex[2] = est->consistency.flags;
            ex[3] = (double)est->consistency.inflation;
            ex[4] = (double)bw_wind_accuracy(est);
            ex[5] = r->gap;
            ex[6] = heard ? (double)e->m.tether_length_m : (double)NAN;
            ex[7] = heard ? (double)e->rope_rate_mps : (double)NAN;
            ex[8] = (double)est->winch_rejected;
            ex[9] = r->press;
            ex[10] = r->temp;
            r->gap = 0;
            r->linked = 1;
            bw_recorder_reset(r);
            *ngrid += 1;
        }
    }
    bw_recorder_active = before;
    return i;
}
