/* ato_motion.c -- the ATO re-planner's car and its motion: the C twin of models/ato/motion.py,
 * expression by expression (Python's operand order; math.sqrt, abs, ceil as libm's). */
#include "rc_fp_contract.h"
#include "ato_motion.h"

void rc_ato_plancar_init(rc_ato_plancar *pc, const rc_ato_car *car, double mass, double A0,
                         double A1, double A2, double brake_share, double brake_mass)
{
    pc->mass = mass;
    pc->A0 = A0;
    pc->A1 = A1;
    pc->A2 = A2;
    pc->brake_mass = brake_mass;
    pc->inv_pg_brake = 1.0 / (brake_mass * RC_G);
    pc->pg = mass * RC_G;
    pc->inv_pg = 1.0 / pc->pg;
    pc->m_in = 1000.0 * mass * (1.0 + car->gamma);
    pc->k_acc = RC_G / 1000.0 / (1.0 + car->gamma);       /* acceleration_gain(gamma) */
    pc->f_force = car->traction_force_max;
    pc->f_power = car->traction_power_max;
    pc->k_adh = 1000.0 * mass * car->adhesion_mass_fraction * RC_G * car->adhesion_factor;
    pc->frac = car->adhesion_mass_fraction;
    pc->r_force = car->regen_force_max;
    pc->r_power = car->regen_power_max;
    pc->v_fade = car->regen_fade_speed;
    pc->b_total = car->brake_force_max;
    pc->share = brake_share;
    pc->eta_f = car->eta_f;
    pc->eta = car->eta;
}

double rc_ato_pc_adhesion(const rc_ato_plancar *c, double v)
{
    return c->k_adh * (0.161 + 7.5 / (fabs(v) * 3.6 + 44.0));
}

double rc_ato_pc_f_max(const rc_ato_plancar *c, double v)
{
    double f = c->f_force;
    if (v > 0.0 && c->f_power / v < f)
        f = c->f_power / v;
    double a = rc_ato_pc_adhesion(c, v);
    return a < f ? a : f;
}

double rc_ato_pc_r_full(const rc_ato_plancar *c, double v)
{
    double r = c->r_force;
    if (v > 0.0 && c->r_power / v < r)
        r = c->r_power / v;
    double a = rc_ato_pc_adhesion(c, v);
    return a < r ? a : r;
}

double rc_ato_pc_b_service(const rc_ato_plancar *c, double v)
{
    double r = rc_ato_pc_r_full(c, v);
    double lim = rc_ato_pc_adhesion(c, v) / c->frac;
    lim = lim < c->b_total ? lim : c->b_total;
    return c->share * (r < lim ? r : lim);
}

double rc_ato_pc_w0(const rc_ato_plancar *c, double v)
{
    return c->A0 + v * (c->A1 + c->A2 * v);
}

double rc_ato_pc_w_slope(const rc_ato_plancar *c, double v)
{
    return c->pg * (c->A1 + 2.0 * c->A2 * v);
}

double rc_ato_pc_hold_regen_speed(const rc_ato_plancar *c, double v_c)
{
    double e = c->eta * c->eta_f;
    double a1 = c->A1, a2 = c->A2;
    double slope = a1 + 2.0 * a2 * v_c;
    if (e <= 0.0 || slope <= 0.0)
        return INFINITY;
    double target = v_c * v_c * slope / e;
    if (a2 <= 0.0)
        return a1 > 0.0 ? sqrt(target / a1) : INFINITY;
    double v = rc_max(v_c, pow(target / (2.0 * a2), 1.0 / 3.0));
    for (int k = 0; k < 50; k++) {
        double fv = v * v * (a1 + 2.0 * a2 * v) - target;
        double dv = fv / (2.0 * v * a1 + 6.0 * a2 * v * v);
        v -= dv;
        if (fabs(dv) <= 1e-12 * v)
            break;
    }
    return v;
}

double rc_ato_accel(const rc_ato_plancar *c, double v, double g, int kind)
{
    double w = c->A0 + v * (c->A1 + c->A2 * v) + g;
    if (kind == RC_ATO_K_TG)
        return c->k_acc * (rc_ato_pc_f_max(c, v) * c->inv_pg - w);
    if (kind == RC_ATO_K_BRAKE)
        return c->k_acc * (-rc_ato_pc_b_service(c, v) * c->inv_pg_brake - w);
    return -c->k_acc * w;
}

double rc_ato_free_step(const rc_ato_plancar *c, double q0, double h, double g, int kind,
                        double *v_mid)
{
    double v0 = q0 > 0.0 ? sqrt(q0) : 0.0;
    double qm = q0 + h * rc_ato_accel(c, v0, g, kind);
    double vm = qm > 0.0 ? sqrt(qm) : 0.0;
    *v_mid = vm;
    return q0 + 2.0 * h * rc_ato_accel(c, vm, g, kind);
}

void rc_ato_coast_step(const rc_ato_plancar *c, double q0, double p0, double h, double g,
                       double k_lam, double *q1, double *p1)
{
    double a0c = c->A0 + g, a1 = c->A1, a2 = c->A2, k = c->k_acc, m = c->m_in, pg = c->pg;
    double v0 = q0 > 0.0 ? sqrt(q0) : 0.0;
    double qm = q0 - h * k * (a0c + v0 * (a1 + a2 * v0));
    double pm = v0 > 0.0 ? p0 + 0.5 * h * (pg * (a1 + 2.0 * a2 * v0) * p0 - k_lam / q0) / (m * v0)
                         : p0;
    double vm = qm > 0.0 ? sqrt(qm) : 0.0;
    *q1 = q0 - 2.0 * h * k * (a0c + vm * (a1 + a2 * vm));
    *p1 = vm > 0.0 ? p0 + h * (pg * (a1 + 2.0 * a2 * vm) * pm - k_lam / qm) / (m * vm) : pm;
}

int rc_ato_hold_forces(const rc_ato_plancar *c, double q0, double q1, double h, double g,
                       double *F, double *R, double *M)
{
    double vm = 0.5 * ((q0 > 0 ? sqrt(q0) : 0.0) + (q1 > 0 ? sqrt(q1) : 0.0));
    /* specific_force_eq2(accel, w0, grade, gain) = accel / gain + w0 + grade */
    double net = c->pg * ((q1 - q0) / (2.0 * h) / c->k_acc + rc_ato_pc_w0(c, vm) + g);
    if (net >= 0.0) {
        *F = net;
        *R = 0.0;
        *M = 0.0;
        return net <= rc_ato_pc_f_max(c, vm);
    }
    double b = -net;
    double r = vm >= c->v_fade ? rc_ato_pc_r_full(c, vm) : 0.0;
    r = b < r ? b : r;
    *F = 0.0;
    *R = r;
    *M = b - r;
    return 1;
}

double rc_ato_step_time(double h, double q0, double q1)
{
    double v = (q0 > 0 ? sqrt(q0) : 0.0) + (q1 > 0 ? sqrt(q1) : 0.0);
    return v > 0.0 ? 2.0 * h / v : INFINITY;
}

void rc_ato_trace_start(rc_ato_trace *tr, double s, double q, double t)
{
    tr->n = 1;
    tr->s[0] = s;
    tr->q[0] = q;
    tr->t[0] = t;
    tr->n_coasts = 0;
}

rc_status rc_ato_trace_add(rc_ato_trace *tr, double s, double q, double dt, int mode, double wF,
                           double wR)
{
    int n = tr->n;
    if (n >= tr->cap)
        return RC_MATH;
    tr->s[n] = s;
    tr->q[n] = q;
    tr->t[n] = tr->t[n - 1] + dt;
    tr->mode[n - 1] = mode;
    tr->wF[n - 1] = wF;
    tr->wR[n - 1] = wR;
    tr->n = n + 1;
    return RC_OK;
}

static int trace_index(const rc_ato_trace *tr, double x)
{
    int k = rc_ato_bisect_right(tr->s, tr->n, x) - 1;
    k = k < tr->n - 1 ? k : tr->n - 1;
    return k > 0 ? k : 0;
}

void rc_ato_trace_cut_at(const rc_ato_trace *tr, double x, rc_ato_trace *out)
{
    int k = trace_index(tr, x);
    for (int j = 0; j <= k; j++) {
        out->s[j] = tr->s[j];
        out->q[j] = tr->q[j];
        out->t[j] = tr->t[j];
    }
    for (int j = 0; j < k; j++) {
        out->mode[j] = tr->mode[j];
        out->wF[j] = tr->wF[j];
        out->wR[j] = tr->wR[j];
    }
    out->n = k + 1;
    out->n_coasts = 0;
    if (x > tr->s[k] + 1e-9 && k + 1 < tr->n) {
        double w = (x - tr->s[k]) / (tr->s[k + 1] - tr->s[k]);
        out->s[k + 1] = x;
        out->q[k + 1] = tr->q[k] + w * (tr->q[k + 1] - tr->q[k]);
        out->t[k + 1] = tr->t[k] + w * (tr->t[k + 1] - tr->t[k]);
        out->mode[k] = tr->mode[k];
        out->wF[k] = w * tr->wF[k];
        out->wR[k] = w * tr->wR[k];
        out->n = k + 2;
    }
}

double rc_ato_q_at(const rc_ato_trace *tr, double x)
{
    int k = trace_index(tr, x);
    if (x > tr->s[k] + 1e-9 && k + 1 < tr->n)
        return tr->q[k] + (x - tr->s[k]) / (tr->s[k + 1] - tr->s[k]) * (tr->q[k + 1] - tr->q[k]);
    return tr->q[k];
}

void rc_ato_resistance_margins(double a0, double a1, double a2, double v_lo, double v_hi,
                               double out[3])
{
    out[0] = a1 + 2.0 * a2 * v_lo;
    out[1] = a1 + 2.0 * a2 * v_hi;
    out[2] = a0 + 0.5 * v_hi * (a1 + 0.5 * a2 * v_hi);
}

static double w0_variance(const double *stated, double v)
{
    double s0 = stated[0], s1 = stated[1], s2 = stated[2];
    double c01 = stated[3], c02 = stated[4], c12 = stated[5];
    double v2 = v * v;
    double var = (s0 * s0 + v2 * s1 * s1 + v2 * v2 * s2 * s2
                  + 2.0 * (v * c01 + v2 * c02 + v * v2 * c12));
    return var > 0.0 ? var : 0.0;
}

void rc_ato_blend_estimates(const double configured[4], const double estimated[4],
                            const double stated[7], double ramp, double config_mass_std,
                            double config_resistance_std, double gate, const double *speeds,
                            int n_speeds, double mass_band, double gate_prev, double gate_step,
                            double out[8])
{
    double m_c = configured[0], a0_c = configured[1], a1_c = configured[2], a2_c = configured[3];
    double m_e = estimated[0], a0_e = estimated[1], a1_e = estimated[2], a2_e = estimated[3];
    double sd_m = stated[0];
    const double *res = stated + 1;
    if (ramp <= 0.0 || sd_m < 0.0 || res[0] < 0.0 || res[1] < 0.0 || res[2] < 0.0) {
        double keep[8] = {m_c, a0_c, a1_c, a2_c, 0.0, 0.0, 0.0, INFINITY};
        for (int k = 0; k < 8; k++)
            out[k] = keep[k];
        return;
    }
    double var_c = config_resistance_std * config_resistance_std;
    double var_sum = 0.0, d = 0.0;
    for (int k = 0; k < n_speeds; k++) {
        double v = speeds[k];
        double var = w0_variance(res, v);
        var_sum += var;
        double dw = (a0_e - a0_c) + v * ((a1_e - a1_c) + v * (a2_e - a2_c));
        double dv = fabs(dw) / sqrt(var + var_c);
        d = dv > d ? dv : d;
    }
    double var_e = var_sum / n_speeds;
    double g = rc_min(rc_max(gate - d, 0.0), 1.0);
    g = rc_min(rc_max(g, gate_prev - gate_step), gate_prev + gate_step);
    double w_r = ramp * g * var_c / (var_c + var_e);
    double mc2 = config_mass_std * config_mass_std;
    double w_m = ramp * g * mc2 / (mc2 + sd_m * sd_m);
    double v_lo = speeds[0], v_hi = speeds[n_speeds - 1];
    double fc[3], fe[3];
    rc_ato_resistance_margins(a0_c, a1_c, a2_c, v_lo, v_hi, fc);
    rc_ato_resistance_margins(a0_e, a1_e, a2_e, v_lo, v_hi, fe);
    for (int k = 0; k < 3; k++) {
        if (fc[k] > 0.0 && fe[k] < 0.5 * fc[k]) {
            double w_max = 0.5 * fc[k] / (fc[k] - fe[k]);
            w_r = w_max < w_r ? w_max : w_r;
        }
    }
    double mass = m_c + w_m * (m_e - m_c);
    mass = rc_min(rc_max(mass, m_c / mass_band), m_c * mass_band);
    out[0] = mass;
    out[1] = a0_c + w_r * (a0_e - a0_c);
    out[2] = a1_c + w_r * (a1_e - a1_c);
    out[3] = a2_c + w_r * (a2_e - a2_c);
    out[4] = w_m;
    out[5] = w_r;
    out[6] = g;
    out[7] = d;
}

double rc_ato_heavier_mass(double planned, double est_mass, int identifying, double configured,
                           double mass_band)
{
    if (identifying && isfinite(est_mass) && est_mass > planned)
        return rc_max(planned, rc_min(est_mass, mass_band * configured));
    return planned;
}

double rc_ato_braking_mass(double mass, double configured)
{
    if (mass <= configured)
        return configured;
    return configured + RC_ATO_BRAKE_MASS_STEP * ceil((mass - configured) / RC_ATO_BRAKE_MASS_STEP);
}
