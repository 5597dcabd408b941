/* Attitude and air (balloon_core/rotation.py, balloon_core/atmosphere.py) and Python's rounding. */
#include "internal.h"

const int BW_MODEL_COLS[BW_NCOL] = {0, 1, 2, 3, 4, 5, 12, 13, 14, 15, 16};

void bw_rotation(const bw_real q[4], bw_real r[9])
{
    const bw_real q0 = q[0], q1 = q[1], q2 = q[2], q3 = q[3];
    r[0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, r[1] = BW_R(2.0) * (q1 * q2 - q0 * q3);
    r[2] = BW_R(2.0) * (q1 * q3 + q0 * q2);
    r[3] = BW_R(2.0) * (q1 * q2 + q0 * q3), r[4] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3;
    r[5] = BW_R(2.0) * (q2 * q3 - q0 * q1);
    r[6] = BW_R(2.0) * (q1 * q3 - q0 * q2), r[7] = BW_R(2.0) * (q2 * q3 + q0 * q1);
    r[8] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3;
}

bw_real bw_air_density(bw_real pressure_pa, bw_real temperature_k)
{
    return pressure_pa / ((bw_real)BW_R_AIR * temperature_k);
}

/* model.py BalloonModel.site_rho_kg_m3: the site's air before the barometer and the thermometer read it, the
 * design's ground pressure, else the standard atmosphere's at the site's altitude (config.py
 * SiteConfig.ground_pressure_pa), at BW_SITE_AIR_K */
double bw_site_air_density(const bw_config_t *c)
{
    double p = c->ground_pressure_hpa == c->ground_pressure_hpa
                   ? c->ground_pressure_hpa * 100.0
                   : 101325.0 * pow(1.0 - BW_LAPSE_K_M * c->altitude_amsl_m / 288.15, BW_G0 / (BW_R_AIR * BW_LAPSE_K_M));
    return p / (BW_R_AIR * BW_SITE_AIR_K);
}

double bw_round_half_even(double v)
{
    double f = floor(v), d = v - f;
    if (d > 0.5 || (d == 0.5 && fmod(f, 2.0) != 0.0))
        return f + 1.0;
    return f;
}
