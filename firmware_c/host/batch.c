/* The host's batch entry point (not flashed: firmware_c/build.py adds this directory to the host library
 * only): a block of samples handed to the core in one call, for the firmware's file replay
 * (firmware_py/app.py, Firmware.batch). Each sample goes to bw_on_imu / bw_on_baro exactly as one call
 * each would, bw_output_update after every IMU step, so the estimator ends in the same state. */
#include "bw_core.h"

#define BW_BATCH_IMU 0
#define BW_BATCH_BARO 1

/* Sample i is kind[i] at t_us[i] with v[9 i ..]: BW_BATCH_IMU ax ay az gx gy gz mx my mz, BW_BATCH_BARO
 * pressure (hPa), temperature (C). Per sample out: stepped[i] (bw_on_imu's 1), and after it the step
 * count, the mode and the consistency flags (what the caller's bookkeeping of each step reads). Stops
 * after the first sample the caller must act on at once: an IMU step at or after stop_us (its outputs
 * are due), an IMU step whose consistency flags differ from told_flags at or after text_us (a STATUSTEXT
 * is due), an IMU sample that counted a time reset. Returns the number of samples done. */
int bw_on_batch(bw_estimator_t *est, int n, const int64_t *t_us, const int32_t *kind, const double *v,
                int64_t stop_us, int32_t told_flags, int64_t text_us, int32_t *stepped, int64_t *steps,
                int32_t *modes, int32_t *flags)
{
    int i;
    for (i = 0; i < n; i++) {
        const double *x = v + 9 * i;
        int64_t t = t_us[i], resets;
        int s = 0;
        if (kind[i] == BW_BATCH_BARO) {
            bw_on_baro(est, t, (bw_real)x[0], (bw_real)x[1]);
        } else {
            resets = est->counters.time_resets;
            s = bw_on_imu(est, t, (bw_real)x[0], (bw_real)x[1], (bw_real)x[2], (bw_real)x[3], (bw_real)x[4],
                          (bw_real)x[5], (bw_real)x[6], (bw_real)x[7], (bw_real)x[8]) == 1;
            if (s) bw_output_update(est, t);
            if (est->counters.time_resets != resets) {
                s |= 2;
            }
        }
        stepped[i] = s;
        steps[i] = est->step;
        modes[i] = est->ekf.mode;
        flags[i] = est->consistency.flags;
        if (s & 2) return i + 1;
        if ((s & 1) && (t >= stop_us || (est->consistency.flags != told_flags && t >= text_us))) return i + 1;
    }
    return n;
}
