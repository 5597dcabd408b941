/* The wind's process noise from the spectrum the filter expects (firmware_py/estimator/tuning.py);
 * at start only, in double. */
#include "internal.h"

static double kaimal_felt_psd(double f_hz, double mean_mps, double ti, double diameter_m)
{
    double u = mean_mps > BW_MIN_WIND_MPS ? mean_mps : BW_MIN_WIND_MPS;
    double sigma = ti * u, t = BW_KAIMAL_LENGTH_M / u, x = 3.141592653589793 * f_hz * diameter_m / u;
    double sinc = x > 1e-9 ? sin(x) / x : 1.0;
    return 4.0 * sigma * sigma * t / pow(1.0 + 6.0 * f_hz * t, 5.0 / 3.0) * sinc * sinc;
}

/* tuning.py kaimal_window_share: the share of the along-wind Kaimal variance a window sees about its mean */
double bw_kaimal_window_share(double window_s, double mean_mps)
{
    double x = window_s * (mean_mps > BW_MIN_WIND_MPS ? mean_mps : BW_MIN_WIND_MPS) / BW_KAIMAL_LENGTH_M;
    return 1.0 - pow(1.0 + 0.465 * pow(x, 0.714), -1.538);
}

void bw_wind_process(double mean_mps, double ti, double diameter_m, double *tau_s, double *q_rate, double *q_walk)
{
    const int points = 40;
    double u = mean_mps > BW_MIN_WIND_MPS ? mean_mps : BW_MIN_WIND_MPS, lo = BW_BAND_HZ_0, hi = BW_BAND_HZ_1;
    double acc = 0.0, tau;
    int i;
    for (i = 0; i < points; i++) {
        double f = lo * pow(hi / lo, (double)i / (points - 1)), w = 2.0 * 3.141592653589793 * f;
        acc += log(kaimal_felt_psd(f, u, ti, diameter_m) * w * w / 2.0);
    }
    *q_walk = exp(acc / points); /* geometric mean: least squares on log S */
    tau = diameter_m / u;
    *tau_s = tau;
    *q_rate = *q_walk / (tau * tau);
}
