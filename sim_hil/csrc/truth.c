/* The truth's derivative and RK4 step in C: a line-for-line twin of sim_hil/dynamics.py (``derivative``,
 * ``_offset_accelerations``, ``rk4_step``) and sim_hil/rope.py (``rope_derivative``), for speed only.
 *
 * Every expression keeps the Python one's operand order, with no contraction into fused multiply-adds
 * (-ffp-contract=off) and the same libm (sqrt, pow, sin, cos), so the results match the Python
 * reference to the last bit on the same machine; tests/unit/test_truth_native.py holds them within a
 * stated tolerance instead (a libm or a compiler may differ in the last place).
 *
 * The parameters come as one struct of doubles whose field order is sim_hil/native.py's PARAM_FIELDS
 * (its size is checked at load). */
#include <math.h>
#include <stddef.h>

typedef struct {
    /* constants (balloon_core/atmosphere.py, sim_hil/rope.py): named once, in Python */
    double g0, r_air, lapse_k_m, isa_exp, ground_stiffness_n_m, ground_friction_ratio;
    /* BalloonPhysics */
    double radius_m, volume_m3, mass_kg, inertia_kgm2, drag_factor, added_mass_coefficient, tether_length_m;
    double rope_kg_m, tether_k_n_m, tether_c_ns_m, rope_drag_factor, rot_damping_nms, fluid_acceleration;
    double ground_pressure_pa, ground_temperature_k, isa_density, reynolds_drag, frontal_area_m2;
    double air_viscosity_pas, drag_crisis_reynolds, drag_crisis_exponent, static_moment_kgm, inertia_z_kgm2;
    double shear_exponent, shear_reference_m, veer_rad_m, yaw_moment_m3;
    /* LumpedRope (has_rope 0: the paper's rope) */
    double has_rope, segments, seg_length_m, node_mass_kg, seg_k_n_m, seg_c_ns_m, rope_drag_factor_m2;
    double rope_shear_exponent, rope_shear_reference_m, ground_c_ns_m, seg_rate_mps, rope_veer_rad_m;
    double airborne_below_m;
} sim_params;

#define MAX_SEGMENTS 200
#define MAX_STATE (13 + 6 * (MAX_SEGMENTS - 1))

size_t bw_sim_params_size(void) { return sizeof(sim_params); }
int bw_sim_max_state(void) { return MAX_STATE; }

static double shear_factor(double exponent, double reference_m, double height_m) {
    if (exponent == 0.0) return 1.0;
    if (height_m <= 0.0) return 0.0;
    return pow(height_m / reference_m, exponent);
}

static void profile_wind(double exponent, double reference_m, double veer_rad_m, double height_m, double wn,
                         double we, double *on, double *oe) {
    double sf = shear_factor(exponent, reference_m, height_m);
    if (veer_rad_m == 0.0) {
        *on = sf * wn;
        *oe = sf * we;
        return;
    }
    double a = veer_rad_m * (height_m - reference_m);
    double c = cos(a), s = sin(a);
    *on = sf * (c * wn - s * we);
    *oe = sf * (s * wn + c * we);
}

static void rotation(double q0, double q1, double q2, double q3, double *r) {
    r[0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3;
    r[1] = 2.0 * (q1 * q2 - q0 * q3);
    r[2] = 2.0 * (q1 * q3 + q0 * q2);
    r[3] = 2.0 * (q1 * q2 + q0 * q3);
    r[4] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3;
    r[5] = 2.0 * (q2 * q3 - q0 * q1);
    r[6] = 2.0 * (q1 * q3 - q0 * q2);
    r[7] = 2.0 * (q2 * q3 + q0 * q1);
    r[8] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3;
}

static double density_at(const sim_params *ph, double height_m) {
    double t0 = ph->ground_temperature_k;
    if (ph->isa_density == 0.0) return ph->ground_pressure_pa / (ph->r_air * t0);
    double temp = t0 - ph->lapse_k_m * height_m;
    return ph->ground_pressure_pa * pow(temp / t0, ph->isa_exp) / (ph->r_air * temp);
}

static double sphere_drag_coefficient(double re, double crisis_re, double crisis_exponent) {
    double x = re / 5.0;
    double y = re / crisis_re;
    return 24.0 / re + 2.6 * x / (1.0 + pow(x, 1.52)) +
           0.411 * pow(y, 0.06 - crisis_exponent) / (1.0 + pow(y, -crisis_exponent)) +
           0.25 * (re / 1.0e6) / (1.0 + re / 1.0e6);
}

static double drag_per_speed(const sim_params *ph, double rho, double speed) {
    if (ph->reynolds_drag == 0.0) return rho * ph->drag_factor * speed;
    if (speed <= 0.0) return 0.0;
    double re = speed * 2.0 * ph->radius_m * rho / ph->air_viscosity_pas;
    double cd = sphere_drag_coefficient(re, ph->drag_crisis_reynolds, ph->drag_crisis_exponent);
    return 0.5 * rho * cd * ph->frontal_area_m2 * speed;
}

/* rope.py rope_derivative: writes d(nodes)/dt (6 (N - 1) values) to out, the force on the balloon to
 * force_top; returns the top segment's tension */
static double rope_derivative(const sim_params *ph, const double *nodes, const double *top, double wn, double we,
                              double wd, double rho, double *out, double *force_top) {
    int n = (int)ph->segments - 1;
    double m = ph->node_mass_kg, l0 = ph->seg_length_m, k = ph->seg_k_n_m, c = ph->seg_c_ns_m;
    double kd = rho * ph->rope_drag_factor_m2;
    double px[MAX_SEGMENTS + 1], py[MAX_SEGMENTS + 1], pz[MAX_SEGMENTS + 1];
    double vx[MAX_SEGMENTS + 1], vy[MAX_SEGMENTS + 1], vz[MAX_SEGMENTS + 1];
    double fx[MAX_SEGMENTS + 1], fy[MAX_SEGMENTS + 1], fz[MAX_SEGMENTS + 1];
    px[0] = py[0] = pz[0] = vx[0] = vy[0] = vz[0] = 0.0;
    for (int i = 0; i < n; i++) {
        px[i + 1] = nodes[3 * i];
        py[i + 1] = nodes[3 * i + 1];
        pz[i + 1] = nodes[3 * i + 2];
        vx[i + 1] = nodes[3 * n + 3 * i];
        vy[i + 1] = nodes[3 * n + 3 * i + 1];
        vz[i + 1] = nodes[3 * n + 3 * i + 2];
    }
    px[n + 1] = top[0];
    py[n + 1] = top[1];
    pz[n + 1] = top[2];
    vx[n + 1] = top[3];
    vy[n + 1] = top[4];
    vz[n + 1] = top[5];
    for (int i = 0; i < n + 2; i++) fx[i] = fy[i] = fz[i] = 0.0;
    double t_top = 0.0;
    for (int j = 0; j < n + 1; j++) {
        double dx = px[j + 1] - px[j], dy = py[j + 1] - py[j], dz = pz[j + 1] - pz[j];
        double length = sqrt(dx * dx + dy * dy + dz * dz);
        double ex, ey, ez;
        if (length > 1e-9) {
            ex = dx / length;
            ey = dy / length;
            ez = dz / length;
        } else {
            ex = ey = 0.0;
            ez = -1.0;
        }
        double tension = 0.0;
        if (length > l0) {
            double rate = ex * (vx[j + 1] - vx[j]) + ey * (vy[j + 1] - vy[j]) + ez * (vz[j + 1] - vz[j]) -
                          ph->seg_rate_mps;
            tension = k * (length - l0) + c * rate;
            if (tension < 0.0) tension = 0.0;
            fx[j] += tension * ex;
            fy[j] += tension * ey;
            fz[j] += tension * ez;
            fx[j + 1] -= tension * ex;
            fy[j + 1] -= tension * ey;
            fz[j + 1] -= tension * ez;
        }
        if (j == n) t_top = tension;
        if (kd > 0.0) {
            double swn, swe;
            if (ph->rope_veer_rad_m == 0.0) {
                double sf = shear_factor(ph->rope_shear_exponent, ph->rope_shear_reference_m, -0.5 * (pz[j] + pz[j + 1]));
                swn = sf * wn;
                swe = sf * we;
            } else {
                profile_wind(ph->rope_shear_exponent, ph->rope_shear_reference_m, ph->rope_veer_rad_m,
                             -0.5 * (pz[j] + pz[j + 1]), wn, we, &swn, &swe);
            }
            double ux = swn - 0.5 * (vx[j] + vx[j + 1]);
            double uy = swe - 0.5 * (vy[j] + vy[j + 1]);
            double uz = wd - 0.5 * (vz[j] + vz[j + 1]);
            double along = ux * ex + uy * ey + uz * ez;
            ux = ux - along * ex;
            uy = uy - along * ey;
            uz = uz - along * ez;
            double half = 0.5 * kd * sqrt(ux * ux + uy * uy + uz * uz);
            fx[j] += half * ux;
            fy[j] += half * uy;
            fz[j] += half * uz;
            fx[j + 1] += half * ux;
            fy[j + 1] += half * uy;
            fz[j + 1] += half * uz;
        }
    }
    double inv_m = 1.0 / m;
    double weight = m * ph->g0;
    for (int i = 0; i < 3 * n; i++) out[i] = nodes[3 * n + i];
    for (int i = 1; i < n + 1; i++) {
        double ax = fx[i], ay = fy[i], az = fz[i] + weight;
        double depth = pz[i];
        if (depth > 0.0) {
            double cg = ph->ground_c_ns_m;
            double push = ph->ground_stiffness_n_m * depth + cg * vz[i];
            if (push > 0.0) az -= push;
            double cf = ph->ground_friction_ratio * cg;
            ax -= cf * vx[i];
            ay -= cf * vy[i];
        }
        int b = 3 * n + 3 * (i - 1);
        out[b] = ax * inv_m;
        out[b + 1] = ay * inv_m;
        out[b + 2] = az * inv_m;
    }
    force_top[0] = fx[n + 1];
    force_top[1] = fy[n + 1];
    force_top[2] = fz[n + 1] + 0.5 * weight;
    return t_top;
}

/* dynamics.py _offset_accelerations: the 10 values after the velocity */
static void offset_accelerations(const sim_params *ph, double fn, double fe, double fd, double ftn, double fte,
                                 double ftd, double m_eff, double q0, double q1, double q2, double q3, double p,
                                 double q, double r, double tz, double *out) {
    double rad = ph->radius_m, sm = ph->static_moment_kgm;
    double ix = ph->inertia_kgm2, iz = ph->inertia_z_kgm2, c = ph->rot_damping_nms;
    double R[9];
    rotation(q0, q1, q2, q3, R);
    double r00 = R[0], r01 = R[1], r02 = R[2], r10 = R[3], r11 = R[4], r12 = R[5], r20 = R[6], r21 = R[7], r22 = R[8];
    double bx = r00 * fn + r10 * fe + r20 * fd;
    double by = r01 * fn + r11 * fe + r21 * fd;
    double bz = r02 * fn + r12 * fe + r22 * fd;
    double fbx = r00 * ftn + r10 * fte + r20 * ftd;
    double fby = r01 * ftn + r11 * fte + r21 * ftd;
    double sg = sm * ph->g0;
    double mx = -rad * fby - sg * r21 - c * p - q * r * (iz - ix);
    double my = rad * fbx + sg * r20 - c * q - p * r * (ix - iz);
    bx -= sm * p * r;
    by -= sm * q * r;
    double det = m_eff * ix - sm * sm;
    double ax = (ix * bx - sm * my) / det;
    double dq = (m_eff * my - sm * bx) / det;
    double ay = (ix * by + sm * mx) / det;
    double dp = (m_eff * mx + sm * by) / det;
    double az = (bz + sm * (p * p + q * q)) / m_eff;
    double dr = -c * r / iz;
    if (tz != 0.0) dr += tz / iz;
    out[0] = r00 * ax + r01 * ay + r02 * az;
    out[1] = r10 * ax + r11 * ay + r12 * az;
    out[2] = r20 * ax + r21 * ay + r22 * az;
    out[3] = 0.5 * (-q1 * p - q2 * q - q3 * r);
    out[4] = 0.5 * (q0 * p + q2 * r - q3 * q);
    out[5] = 0.5 * (q0 * q - q1 * r + q3 * p);
    out[6] = 0.5 * (q0 * r + q1 * q - q2 * p);
    out[7] = dp;
    out[8] = dq;
    out[9] = dr;
}

/* dynamics.py yaw_moment_nm: the asymmetric sphere's yaw moment about its body z, N m */
static double yaw_moment(const sim_params *ph, double rho, double un, double ue, double ud, double speed, double r00,
                         double r10, double r20, double r01, double r11, double r21) {
    double ubx = r00 * un + r10 * ue + r20 * ud;
    double uby = r01 * un + r11 * ue + r21 * ud;
    double uh = sqrt(ubx * ubx + uby * uby);
    if (uh <= 0.0) return 0.0;
    return rho * ph->yaw_moment_m3 * speed * speed * uby / uh;
}

/* dynamics.py derivative: d(state)/dt into out; returns the tether tension at the balloon.
 * w: the reference wind (n, e, d, dn, de, dd) */
double bw_sim_derivative(const sim_params *ph, const double *s, const double *w, double *out) {
    double pn = s[0], pe = s[1], pd = s[2], vn = s[3], ve = s[4], vd = s[5];
    double q0 = s[6], q1 = s[7], q2 = s[8], q3 = s[9], p = s[10], q = s[11], r = s[12];
    double wn = w[0], we = w[1], wd = w[2], dwn = w[3], dwe = w[4], dwd = w[5];
    double wn_ref = wn, we_ref = we;
    if (ph->veer_rad_m != 0.0) {
        profile_wind(ph->shear_exponent, ph->shear_reference_m, ph->veer_rad_m, -pd, wn_ref, we_ref, &wn, &we);
        profile_wind(ph->shear_exponent, ph->shear_reference_m, ph->veer_rad_m, -pd, w[3], w[4], &dwn, &dwe);
    } else if (ph->shear_exponent != 0.0) {
        double sf = shear_factor(ph->shear_exponent, ph->shear_reference_m, -pd);
        wn = sf * wn;
        we = sf * we;
        dwn = sf * dwn;
        dwe = sf * dwe;
    }
    double rad = ph->radius_m;
    double rho = density_at(ph, -pd);
    double rho_v = rho * ph->volume_m3;
    double R[9];
    rotation(q0, q1, q2, q3, R);
    double r00 = R[0], r01 = R[1], zx = R[2], r10 = R[3], r11 = R[4], zy = R[5], r20 = R[6], r21 = R[7], zz = R[8];
    double an = pn + rad * zx, ae = pe + rad * zy, ad = pd + rad * zz;
    double on = r00 * p + r01 * q + zx * r;
    double oe = r10 * p + r11 * q + zy * r;
    double od = r20 * p + r21 * q + zz * r;
    double avn = vn + rad * (oe * zz - od * zy);
    double ave = ve + rad * (od * zx - on * zz);
    double avd = vd + rad * (on * zy - oe * zx);
    double dist = sqrt(an * an + ae * ae + ad * ad);
    double length = ph->tether_length_m;
    double tension = 0.0;
    double ftn = 0.0, fte = 0.0, ftd = 0.0;
    double airborne = 0.0;
    if (ph->has_rope != 0.0) {
        double top[6] = {an, ae, ad, avn, ave, avd};
        double ft[3];
        tension = rope_derivative(ph, s + 13, top, wn_ref, we_ref, wd, rho, out + 13, ft);
        ftn = ft[0];
        fte = ft[1];
        ftd = ft[2];
    } else if (dist > length) {
        double rate = (an * avn + ae * ave + ad * avd) / dist;
        tension = ph->tether_k_n_m * (dist - length) + ph->tether_c_ns_m * rate;
        if (tension < 0.0) tension = 0.0;
        ftn = -tension * an / dist;
        fte = -tension * ae / dist;
        ftd = -tension * ad / dist;
        airborne = length;
    } else {
        airborne = ad < 0.0 ? -ad : 0.0;
        if (airborne > length) airborne = length;
    }
    if (ph->has_rope == 0.0) ftd += ph->rope_kg_m * ph->g0 * airborne;
    double un = wn - vn, ue = we - ve, ud = wd - vd;
    double speed = sqrt(un * un + ue * ue + ud * ud);
    double kd = ph->reynolds_drag != 0.0 ? drag_per_speed(ph, rho, speed) : rho * ph->drag_factor * speed;
    double fan = kd * un, fae = kd * ue, fad = kd * ud;
    if (ph->has_rope == 0.0 && ph->rope_drag_factor > 0.0 && dist > 0.0) {
        double en = an / dist, ee = ae / dist, ed = ad / dist;
        double rn = wn - 0.5 * vn, re = we - 0.5 * ve, rd = wd - 0.5 * vd;
        double along = rn * en + re * ee + rd * ed;
        double cn = rn - along * en, ce = re - along * ee, cd = rd - along * ed;
        double cs = sqrt(cn * cn + ce * ce + cd * cd);
        double kr = 0.5 * rho * ph->rope_drag_factor * (dist < length ? dist : length) * cs;
        ftn += kr * cn;
        fte += kr * ce;
        ftd += kr * cd;
    }
    double ca_rho_v = ph->added_mass_coefficient * rho_v;
    double fk = (rho_v + ca_rho_v) * ph->fluid_acceleration;
    out[0] = vn;
    out[1] = ve;
    out[2] = vd;
    if (ph->static_moment_kgm != 0.0) {
        double tz = ph->yaw_moment_m3 != 0.0
                        ? yaw_moment(ph, rho, un, ue, ud, speed, r00, r10, r20, r01, r11, r21) : 0.0;
        offset_accelerations(ph, fk * dwn + fan + ftn, fk * dwe + fae + fte,
                             fk * dwd + fad + ftd + (ph->mass_kg - rho_v) * ph->g0, ftn, fte, ftd,
                             ph->mass_kg + ca_rho_v, q0, q1, q2, q3, p, q, r, tz, out + 3);
        return tension;
    }
    double inv_m = 1.0 / (ph->mass_kg + ca_rho_v);
    out[3] = (fk * dwn + fan + ftn) * inv_m;
    out[4] = (fk * dwe + fae + fte) * inv_m;
    out[5] = (fk * dwd + fad + ftd + (ph->mass_kg - rho_v) * ph->g0) * inv_m;
    double fbx = r00 * ftn + r10 * fte + r20 * ftd;
    double fby = r01 * ftn + r11 * fte + r21 * ftd;
    double inv_i = 1.0 / ph->inertia_kgm2;
    double c = ph->rot_damping_nms;
    out[10] = (-rad * fby - c * p) * inv_i;
    out[11] = (rad * fbx - c * q) * inv_i;
    out[12] = (-c * r) * inv_i;
    if (ph->yaw_moment_m3 != 0.0)
        out[12] += yaw_moment(ph, rho, un, ue, ud, speed, r00, r10, r20, r01, r11, r21) * inv_i;
    out[6] = 0.5 * (-q1 * p - q2 * q - q3 * r);
    out[7] = 0.5 * (q0 * p + q2 * r - q3 * q);
    out[8] = 0.5 * (q0 * q - q1 * r + q3 * p);
    out[9] = 0.5 * (q0 * r + q1 * q - q2 * p);
    return tension;
}

/* rope.py anchor_tension_n: the bottom segment's pull on the anchor */
static double anchor_tension(const sim_params *ph, const double *nodes) {
    int n = (int)ph->segments - 1;
    double x = nodes[0], y = nodes[1], z = nodes[2];
    double length = sqrt(x * x + y * y + z * z);
    if (length <= ph->seg_length_m || length < 1e-9) return 0.0;
    double rate = (x * nodes[3 * n] + y * nodes[3 * n + 1] + z * nodes[3 * n + 2]) / length - ph->seg_rate_mps;
    double t = ph->seg_k_n_m * (length - ph->seg_length_m) + ph->seg_c_ns_m * rate;
    return t > 0.0 ? t : 0.0;
}

/* rope.py rope_airborne: every node off the ground */
static int rope_airborne(const sim_params *ph, const double *nodes) {
    int n = (int)ph->segments - 1;
    for (int i = 0; i < n; i++)
        if (!(nodes[3 * i + 2] < ph->airborne_below_m)) return 0;
    return 1;
}

/* dynamics.py rk4_step with its k1 computed here (``k1`` out): step j of a wind table whose rows (n, e, d,
 * dn, de, dd) are at half steps, rows 2j, 2j + 1, 2j + 2 the wind at t, t + h/2, t + h. s is advanced in
 * place; returns the tension at the state before the step. With ``pre`` (else NULL) the state before the
 * step is copied there, followed by the lumped rope's anchor tension and whether it is airborne (1, 0)
 * there (the truth table's columns; 0, 0 with the paper's rope). */
double bw_sim_step(const sim_params *ph, double *s, int n_state, double h, const double *wind, int j, double *k1,
                   double *pre) {
    double k2[MAX_STATE], k3[MAX_STATE], k4[MAX_STATE], tmp[MAX_STATE];
    const double *w0 = wind + 12 * (size_t)j, *wm = w0 + 6, *w1 = w0 + 12;
    double tension = bw_sim_derivative(ph, s, w0, k1);
    if (pre != NULL) {
        for (int i = 0; i < n_state; i++) pre[i] = s[i];
        int rope = ph->has_rope != 0.0;
        pre[n_state] = rope ? anchor_tension(ph, s + 13) : 0.0;
        pre[n_state + 1] = rope ? rope_airborne(ph, s + 13) : 0.0;
    }
    double h2 = 0.5 * h;
    for (int i = 0; i < n_state; i++) tmp[i] = s[i] + h2 * k1[i];
    bw_sim_derivative(ph, tmp, wm, k2);
    for (int i = 0; i < n_state; i++) tmp[i] = s[i] + h2 * k2[i];
    bw_sim_derivative(ph, tmp, wm, k3);
    for (int i = 0; i < n_state; i++) tmp[i] = s[i] + h * k3[i];
    bw_sim_derivative(ph, tmp, w1, k4);
    double h6 = h / 6.0;
    for (int i = 0; i < n_state; i++) s[i] = s[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    double nrm = 1.0 / sqrt(pow(s[6], 2.0) + pow(s[7], 2.0) + pow(s[8], 2.0) + pow(s[9], 2.0));
    s[6] *= nrm;
    s[7] *= nrm;
    s[8] *= nrm;
    s[9] *= nrm;
    return tension;
}

/* ``count`` steps (j, j + 1, ...) of bw_sim_step, k1 and ``pre`` from the first: one IMU period in one call */
double bw_sim_steps(const sim_params *ph, double *s, int n_state, double h, const double *wind, int j, int count,
                    double *k1, double *pre) {
    double tension = bw_sim_step(ph, s, n_state, h, wind, j, k1, pre);
    double k[MAX_STATE];
    for (int i = 1; i < count; i++) bw_sim_step(ph, s, n_state, h, wind, j + i, k, NULL);
    return tension;
}
