/* The taut tether's quasi-static shape (firmware_py/estimator/catenary.py). */
#include "internal.h"

static void drag(bw_real kq, bw_real wn, bw_real we, bw_real tn, bw_real te, bw_real td, bw_real q[3])
{
    bw_real along = wn * tn + we * te;
    bw_real un = wn - along * tn, ue = we - along * te, ud = -along * td;
    bw_real s = kq * BW_SQRT(un * un + ue * ue + ud * ud);
    q[0] = s * un, q[1] = s * ue, q[2] = s * ud;
}

void bw_rope_chord(bw_real fn, bw_real fe, bw_real fd, bw_real length_m, bw_real weight_n_m, bw_real drag_kg_m2,
                   bw_real wn, bw_real we, bw_real chord[3])
{
    bw_real h = length_m / (bw_real)BW_SHAPE_STEPS, x = BW_R(0.0), y = BW_R(0.0), z = BW_R(0.0), q[3];
    int i;
    for (i = 0; i < BW_SHAPE_STEPS; i++) {
        bw_real m = BW_SQRT(fn * fn + fe * fe + fd * fd), tn, te, td, hn, he, hd, mm;
        if (m < BW_R(1e-9))
            break;
        tn = fn / m, te = fe / m, td = fd / m;
        drag(drag_kg_m2, wn, we, tn, te, td, q);
        hn = fn - BW_R(0.5) * h * q[0], he = fe - BW_R(0.5) * h * q[1], hd = fd - BW_R(0.5) * h * (weight_n_m + q[2]);
        mm = BW_SQRT(hn * hn + he * he + hd * hd);
        if (mm < BW_R(1e-9))
            break;
        tn = hn / mm, te = he / mm, td = hd / mm;
        drag(drag_kg_m2, wn, we, tn, te, td, q);
        x += h * tn;
        y += h * te;
        z += h * td;
        fn -= h * q[0];
        fe -= h * q[1];
        fd -= h * (weight_n_m + q[2]);
    }
    chord[0] = -x, chord[1] = -y, chord[2] = -z;
}

bw_real bw_anchored_rope_spread(bw_real weight_n_m, bw_real span_m, bw_real height_m)
{
    bw_real rho, u;
    int i;
    if (span_m <= BW_R(1e-6) * BW_MAX(height_m, BW_R(1.0)) || height_m <= BW_R(0.0))
        return BW_R(0.0);
    rho = height_m / span_m;
    if (rho < BW_R(1e-3)) {
        u = BW_R(2.0) * rho;
    } else { /* (cosh u - 1) / u = rho: Newton from above the root (f convex, f(0) = 0, f'(0) < 0) */
        u = rho <= BW_R(1.0) ? BW_R(1.0) + BW_R(4.0) * rho
                             : BW_LOG(BW_R(4.0) * rho) + BW_LOG(BW_LOG(BW_R(4.0) * rho) + BW_R(1.0)) + BW_R(1.0);
        for (i = 0; i < BW_ANCHORED_NEWTON_STEPS; i++) {
            bw_real ex = BW_EXP(u);
            u -= (BW_R(0.5) * (ex + BW_R(1.0) / ex) - BW_R(1.0) - rho * u) / (BW_R(0.5) * (ex - BW_R(1.0) / ex) - rho);
        }
    }
    return weight_n_m * span_m / u * BW_HYPOT(BW_R(1.0), BW_R(1.0) - BW_EXP(-u));
}

double bw_calm_weight_share(double lift_n, double rope_weight_n)
{
    double v_top = lift_n, v_bottom = lift_n - rope_weight_n;
    if (rope_weight_n <= 1e-9 * (lift_n > 1.0 ? lift_n : 1.0))
        return 0.5 * rope_weight_n;
    if (v_bottom <= 1e-6 * v_top)
        return rope_weight_n;
    return v_top - rope_weight_n / log(v_top / v_bottom);
}

bw_real bw_effective_rod(bw_real fn, bw_real fe, bw_real fd, bw_real cn, bw_real ce, bw_real cd, bw_real rope_weight_n)
{
    bw_real ch = BW_SQRT(cn * cn + ce * ce), t_over_c, w;
    if (ch < BW_R(1e-6))
        return BW_R(NAN);
    t_over_c = -(fn * cn + fe * ce) / (ch * ch); /* T_c / |chord| */
    w = fd + t_over_c * cd;
    return BW_MIN(BW_MAX(w, BW_R(0.0)), BW_R(1.5) * rope_weight_n);
}
