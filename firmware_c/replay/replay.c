/* Replay a recorded sample stream through the C core and write what it outputs after every IMU
 * sample (docs/porting.md, "What the harness proves"). The same program runs on the host (stdio) and on
 * the Cortex-M4F under QEMU (newlib's semihosting: the host's files); on the target it also counts the
 * instructions of every bw_on_imu with SysTick (QEMU -icount: one instruction per virtual nanosecond).
 *
 *   replay STREAM.bin OUT.bin [STATS.txt]
 *
 * STREAM.bin: 46 little-endian doubles (bw_config_t), then records of 88 bytes: int64 t_us, int32 kind
 * (0 IMU: ax ay az gx gy gz mx my mz; 1 baro: pressure_hpa temperature_c; 2 coast: seconds; 3 winch:
 * line_length_m speed_mps tension_n; 4 ground reference: pressure_hpa temperature_c), int32 0,
 * 9 doubles. OUT.bin: per IMU record, int64 time_usec, int32 advanced, mode, reset_count, flags, then
 * 5 + 2 x 19 floats: wind_x, wind_y, var_horiz, wind_alt, horiz_accuracy, x[19], P diagonal[19]. */
#include <stdio.h>
#include <string.h>

#include "bw_core.h"

#ifdef BW_TARGET_M4
#define SYST_CSR (*(volatile unsigned long *)0xE000E010u)
#define SYST_RVR (*(volatile unsigned long *)0xE000E014u)
#define SYST_CVR (*(volatile unsigned long *)0xE000E018u)
/* the board's 25 MHz SysTick under QEMU -icount shift=0 (one instruction a virtual ns): 40 instructions a tick */
#define INSTRUCTIONS_PER_TICK 40u
static void timer_start(void)
{
    SYST_RVR = 0x00FFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 5u; /* processor clock, enabled, no interrupt */
}
static unsigned long timer_now(void)
{
    return SYST_CVR;
}
#endif

typedef struct {
    int64_t t_us;
    int32_t kind, pad;
    double v[9];
} record_t;

typedef struct {
    int64_t time_usec;
    int32_t advanced, mode, reset_count, flags;
    float f[5 + 2 * BW_N];
} out_t;

static bw_estimator_t est; /* static memory: the whole filter */

#ifdef BW_TARGET_M4
#define HIST 8192u                   /* instruction counts in ticks of 40: up to 327 680 a step */
#define PAINT_BYTES 6144u            /* the stack below the caller's, painted to find how deep a step goes */
static unsigned long hist[HIST];
static unsigned long stack_depth(int paint)
{
    unsigned long sp, k;
    volatile unsigned char *p;
    __asm volatile("mov %0, sp" : "=r"(sp));
    p = (volatile unsigned char *)(sp - 64u); /* below this frame */
    if (paint) {
        for (k = 0; k < PAINT_BYTES; k++)
            p[-(long)k] = 0xA5u;
        return 0;
    }
    for (k = PAINT_BYTES; k > 0; k--)
        if (p[-(long)(k - 1)] != 0xA5u)
            return k + 64u;
    return 0;
}
#endif
int main(int argc, char **argv)
{
    FILE *in, *out;
    bw_config_t cfg;
    record_t r;
    out_t o;
    bw_wind_cov_t w;
    unsigned long n_steps = 0;
#ifdef BW_TARGET_M4
    unsigned long worst = 0, deepest = 0, n_imu = 0;
    timer_start();
#endif
    if (argc < 3) {
        fprintf(stderr, "usage: replay STREAM.bin OUT.bin [STATS.txt]\n");
        return 2;
    }
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (in == NULL || out == NULL) {
        fprintf(stderr, "replay: cannot open %s or %s\n", argv[1], argv[2]);
        return 2;
    }
    if (fread(&cfg, sizeof cfg, 1, in) != 1 || bw_init(&est, &cfg) != 0) {
        fprintf(stderr, "replay: %s has no valid configuration\n", argv[1]);
        return 2;
    }
    while (fread(&r, sizeof r, 1, in) == 1) {
        int advanced, i;
        if (r.kind == 1) {
            bw_on_baro(&est, r.t_us, (bw_real)r.v[0], (bw_real)r.v[1]);
            continue;
        }
        if (r.kind == 2) {
            bw_coast(&est, (bw_real)r.v[0]);
            continue;
        }
        if (r.kind == 3 || r.kind == 4) { /* from the ground: on the sensor clock of its arrival */
            int64_t t = est.t_last_us > 0 ? est.t_last_us : 0;
            if (r.kind == 3)
                bw_on_winch(&est, t, (bw_real)r.v[0], (bw_real)r.v[1], (bw_real)r.v[2]);
            else
                bw_on_ground_baro(&est, t, (bw_real)r.v[0], (bw_real)r.v[1]);
            continue;
        }
        {
#ifdef BW_TARGET_M4
            unsigned long t0, t1, ticks;
            int measure_stack = n_imu++ % 50u == 0u;
            if (measure_stack)
                stack_depth(1);
            t0 = timer_now();
#endif
            advanced = bw_on_imu(&est, r.t_us, (bw_real)r.v[0], (bw_real)r.v[1], (bw_real)r.v[2], (bw_real)r.v[3],
                                 (bw_real)r.v[4], (bw_real)r.v[5], (bw_real)r.v[6], (bw_real)r.v[7], (bw_real)r.v[8]);
            if (advanced)
                bw_output_update(&est, r.t_us);
#ifdef BW_TARGET_M4
            t1 = timer_now();
            ticks = (t0 - t1) & 0x00FFFFFFu; /* SysTick counts down */
            if (measure_stack) {
                unsigned long depth = stack_depth(0);
                if (depth > deepest)
                    deepest = depth;
            }
            if (advanced && est.step > 0) {
                hist[ticks < HIST ? ticks : HIST - 1u]++;
                if (ticks > worst)
                    worst = ticks;
            }
#endif
        }
        if (r.kind == 0 && advanced)
            n_steps++;
        bw_wind_cov(&est, &w);
        memset(&o, 0, sizeof o);
        o.time_usec = w.time_usec;
        o.advanced = advanced;
        o.mode = est.ekf.mode;
        o.reset_count = est.ekf.reset_count;
        o.flags = est.consistency.flags;
        o.f[0] = w.wind_x, o.f[1] = w.wind_y, o.f[2] = w.var_horiz, o.f[3] = w.wind_alt, o.f[4] = w.horiz_accuracy;
        for (i = 0; i < BW_N; i++) {
            o.f[5 + i] = (float)est.ekf.x[i];
            o.f[5 + BW_N + i] = (float)est.ekf.P[i][i];
        }
        fwrite(&o, sizeof o, 1, out);
    }
    fclose(in);
    fclose(out);
#ifdef BW_TARGET_M4
    if (argc > 3) {
        unsigned long seen = 0, median = 0, k;
        FILE *st = fopen(argv[3], "w");
        for (k = 0; k < HIST; k++) {
            seen += hist[k];
            if (2u * seen >= n_steps) {
                median = k;
                break;
            }
        }
        if (st != NULL) {
            fprintf(st, "steps %lu median_instructions %lu worst_instructions %lu estimator_bytes %lu stack_bytes %lu\n",
                    n_steps, median * INSTRUCTIONS_PER_TICK, worst * INSTRUCTIONS_PER_TICK, (unsigned long)sizeof est,
                    deepest);
            fclose(st);
        }
    }
#endif
    return 0;
}
