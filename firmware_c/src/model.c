/* The estimator's balloon model (firmware_py/estimator/model.py): the generated functions'
 * parameters and the free / taut configuration at one state. */
#include "internal.h"

/* model.py rope_pickup_n: lambda vd^2, the pull that picks the rope up while climbing with part of it on the ground */
static bw_real rope_pickup_n(const bw_model_t *m, bw_real pd, bw_real vd)
{
    bw_real height = -pd - m->radius_m;
    if (vd >= BW_R(0.0) || height <= BW_R(0.0) || height >= m->tether_length_m)
        return BW_R(0.0);
    return m->rope_kg_m * vd * vd;
}

/* (m_eff, push, c, lift, rope_w, rope_slope, kr, att_n, att_e, att_d) for air density rho */
static void parameters(const bw_model_t *m, bw_real rho, bw_real pd, bw_real pickup_n, int taut, const bw_real attach[3],
                       bw_real rope_weight_n, bw_real par[10])
{
    bw_real rho_v = rho * m->volume_m3;
    bw_real m_eff = m->mass_kg + (bw_real)BW_ADDED_MASS_COEFFICIENT * rho_v;
    bw_real lam_g = m->lam_g;
    bw_real rope_w, slope;
    if (taut) {
        rope_w = rope_weight_n != rope_weight_n ? lam_g * m->tether_length_m : rope_weight_n;
        slope = BW_R(0.0);
    } else {
        bw_real height = -pd - m->radius_m;
        if (height <= BW_R(0.0)) {
            rope_w = slope = BW_R(0.0);
        } else if (height >= m->tether_length_m) {
            rope_w = lam_g * m->tether_length_m;
            slope = BW_R(0.0);
        } else { /* lambda g (-pd - r), written as rope_w + slope * pd */
            rope_w = -lam_g * m->radius_m + pickup_n;
            slope = -lam_g;
        }
    }
    par[0] = m_eff;
    par[1] = (BW_R(1.0) + (bw_real)BW_ADDED_MASS_COEFFICIENT) * rho_v;
    par[2] = rho * m->half_cd_area_m2;
    par[3] = (rho_v - m->mass_kg) * (bw_real)BW_G0;
    par[4] = rope_w;
    par[5] = slope;
    par[6] = taut ? rho * m->rope_drag_m2 : BW_R(0.0);
    par[7] = attach[0];
    par[8] = attach[1];
    par[9] = attach[2];
}

void bw_accelerations(const bw_model_t *m, bw_real rho, const bw_real s[BW_NCOL], int taut, bw_forces_t *out)
{
    int i;
    const bw_real pickup = taut ? BW_R(0.0) : rope_pickup_n(m, s[2], s[5]); /* model.py: the ascent's pick-up */
    parameters(m, rho, s[2], pickup, taut, out->attach_ned, out->rope_weight_n, out->params);
    out->m_eff_kg = out->params[0];
    if (taut) {
        bw_real r[BW_TAUT_MODEL_SIZE];
        if (m->rope_drag_m2 > BW_R(0.0)) /* the paper's rod carries rope drag */
            bw_taut_model(s, out->params, r);
        else
            bw_taut_model_plain(s, out->params, r);
        if (r[3] > BW_R(0.0)) {
            out->an = r[0], out->ae = r[1], out->ad = r[2];
            out->tension_n = r[3] * out->params[0];
            for (i = 0; i < 3 * BW_NCOL; i++)
                out->ja[i] = r[4 + i];
            for (i = 0; i < BW_NCOL; i++)
                out->jpull[i] = r[4 + 3 * BW_NCOL + i];
            out->taut = 1;
            return;
        }
    }
    {
        bw_real r[BW_FREE_MODEL_SIZE];
        bw_free_model(s, out->params, r);
        out->an = r[0], out->ae = r[1], out->ad = r[2];
        for (i = 0; i < 3 * BW_NCOL; i++)
            out->ja[i] = r[3 + i];
        if (pickup > BW_R(0.0)) /* lambda vd^2 is in the parameter rope_w: its d a_d / d vd (model.py) */
            out->ja[2 * BW_NCOL + 5] += BW_R(2.0) * pickup / (s[5] * out->params[0]);
        out->tension_n = BW_R(0.0);
        out->taut = 0;
    }
}
