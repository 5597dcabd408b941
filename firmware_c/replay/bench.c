/* Host timing of the C core's step: the whole stream in memory, each bw_on_imu timed with the
 * monotonic clock, repeated; prints "steps N median_ns M p99_ns P" (benchmarks/bench_speed.py). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "bw_core.h"

typedef struct {
    int64_t t_us;
    int32_t kind, pad;
    double v[9];
} record_t;

static bw_estimator_t est;

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    FILE *in;
    bw_config_t cfg;
    record_t *r;
    double *dt;
    long n = 0, cap = 1 << 16, k, m = 0, warm;
    int rep, reps = 3;
    if (argc < 2 || (in = fopen(argv[1], "rb")) == NULL || fread(&cfg, sizeof cfg, 1, in) != 1)
        return 2;
    warm = argc > 2 ? atol(argv[2]) : 0;
    r = malloc(sizeof *r * (size_t)cap); /* the benchmark's own buffer; the core allocates nothing */
    while (r != NULL && fread(&r[n], sizeof *r, 1, in) == 1)
        if (++n == cap)
            r = realloc(r, sizeof *r * (size_t)(cap *= 2));
    fclose(in);
    dt = malloc(sizeof *dt * (size_t)(n * reps));
    if (r == NULL || dt == NULL)
        return 2;
    for (rep = 0; rep < reps; rep++) {
        long imu = 0;
        bw_init(&est, &cfg);
        for (k = 0; k < n; k++) {
            double t0, t1;
            if (r[k].kind == 1) {
                bw_on_baro(&est, r[k].t_us, (bw_real)r[k].v[0], (bw_real)r[k].v[1]);
                continue;
            }
            if (r[k].kind != 0)
                continue;
            t0 = now_ns();
            if (bw_on_imu(&est, r[k].t_us, (bw_real)r[k].v[0], (bw_real)r[k].v[1], (bw_real)r[k].v[2],
                          (bw_real)r[k].v[3], (bw_real)r[k].v[4], (bw_real)r[k].v[5], (bw_real)r[k].v[6],
                          (bw_real)r[k].v[7], (bw_real)r[k].v[8]))
                bw_output_update(&est, r[k].t_us);
            t1 = now_ns();
            if (imu++ >= warm)
                dt[m++] = t1 - t0;
        }
    }
    qsort(dt, (size_t)m, sizeof *dt, cmp);
    printf("steps %ld median_ns %.0f p99_ns %.0f\n", m, dt[m / 2], dt[(long)(0.99 * (double)m)]);
    free(r);
    free(dt);
    return 0;
}
