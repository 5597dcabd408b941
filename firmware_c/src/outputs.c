/* WIND_COV's fields (firmware_py/estimator/outputs.py): horiz_accuracy from the filter, var_horiz the
 * variability of the 1 Hz low-passed wind over the last 60 s (a 60-slot ring). */
#include "internal.h"

#define WINDOW BW_WINDCOV_WINDOW_S

void bw_output_reset(bw_estimator_t *est)
{
    est->out.primed = 0;
    est->out.count = 0;
    est->out.next_slot_us = 0;
}

void bw_output_update(bw_estimator_t *est, int64_t t_us)
{
    bw_windcov_out_t *o = &est->out;
    const bw_real wn = est->ekf.x[BW_WIND_N], we = est->ekf.x[BW_WIND_E];
    const bw_real a = o->alpha;
    if (!o->primed) {
        o->ln = wn, o->le = we, o->primed = 1;
        o->next_slot_us = t_us;
    }
    o->ln += a * (wn - o->ln);
    o->le += a * (we - o->le);
    if (est->ekf.mode == BW_MODE_GROUND) {
        o->count = 0; /* the wind is not observed on the ground */
        o->next_slot_us = t_us;
        return;
    }
    if (t_us >= o->next_slot_us) {
        int k = (int)(o->count % WINDOW);
        o->ring_n[k] = o->ln;
        o->ring_e[k] = o->le;
        o->count += 1;
        o->next_slot_us += 1000000;
    }
}

static bw_real variability(const bw_windcov_out_t *o)
{
    bw_real mn = BW_R(0.0), me = BW_R(0.0), var = BW_R(0.0);
    int i;
    if (o->count < WINDOW)
        return BW_R(NAN);
    for (i = 0; i < WINDOW; i++)
        mn += o->ring_n[i], me += o->ring_e[i];
    mn /= (bw_real)WINDOW, me /= (bw_real)WINDOW;
    for (i = 0; i < WINDOW; i++)
        var += (o->ring_n[i] - mn) * (o->ring_n[i] - mn) + (o->ring_e[i] - me) * (o->ring_e[i] - me);
    return BW_SQRT(var / (bw_real)(WINDOW - 1));
}

void bw_wind_cov(const bw_estimator_t *est, bw_wind_cov_t *out)
{
    out->time_usec = est->t_last_us > 0 ? est->t_last_us : 0;
    out->wind_z = out->var_vert = NAN;
    out->vert_accuracy = 0.0f;
    if (!est->initialised) {
        out->wind_x = out->wind_y = out->var_horiz = out->wind_alt = out->horiz_accuracy = NAN;
        return;
    }
    out->wind_x = (float)est->ekf.x[BW_WIND_N];
    out->wind_y = (float)est->ekf.x[BW_WIND_E];
    out->var_horiz = (float)variability(&est->out);
    out->wind_alt = (float)(est->out.site_altitude_m - (double)est->ekf.x[BW_POS_D]);
    out->horiz_accuracy = (float)bw_wind_accuracy(est);
}
