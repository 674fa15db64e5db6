/* plant.c -- see plant.h; the bodies of models/plant/dynamics.py's held_input_dynamics, _rk4 and
 * CarPlant, expression for expression (operand order and association as in Python). */
#include "rc_fp_contract.h"
#include "plant.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* held_input_dynamics's bound values for one advance (the mass may change between calls) */
typedef struct {
    double k_adh, frac, f_max, p_max, b_max, a0, a1, a2, inv_weight, k_acc, length;
    double traction_demand, brake_demand, wind;
    int braking;
    const rc_grade_profile *grade;
} dyn;

static void dyn_bind_vehicle(dyn *d, const rc_vehicle *p, const rc_grade_profile *grade,
                             double traction_demand, double brake_demand, double wind)
{
    d->k_adh = 1000.0 * p->mass * p->adhesion_mass_fraction * RC_G * p->adhesion_factor;
    d->frac = p->adhesion_mass_fraction;
    d->f_max = p->traction_force_max;
    d->p_max = p->traction_power_max;
    d->b_max = p->brake_force_max;
    d->a0 = p->A0;
    d->a1 = p->A1;
    d->a2 = p->A2;
    d->inv_weight = 1.0 / (p->mass * RC_G);
    d->k_acc = RC_G / 1000.0 / (1.0 + p->gamma);
    d->length = p->length;
    d->grade = grade;
    d->traction_demand = traction_demand;
    d->brake_demand = brake_demand;
    d->wind = wind;
    d->braking = brake_demand > 0.0;
}

static void dyn_bind(dyn *d, const rc_plant *pl, double traction_demand, double brake_demand,
                     double wind)
{
    dyn_bind_vehicle(d, &pl->p, pl->grade, traction_demand, brake_demand, wind);
}

/* forces(v) -> (F, B) */
static void dyn_forces(const dyn *d, double v, double *f, double *b)
{
    double adh = d->k_adh * (0.161 + 7.5 / (fabs(v) * 3.6 + 44.0));   /* Curtius-Kniffler psi_k */
    if (d->braking) {
        double lim = adh / d->frac;
        double bd = d->brake_demand;
        *f = 0.0;
        *b = (bd < lim && bd < d->b_max) ? bd : (lim < d->b_max ? lim : d->b_max);
        return;
    }
    double lim = d->f_max;
    if (v > 0.0 && d->p_max / v < lim)
        lim = d->p_max / v;
    if (adh < lim)
        lim = adh;
    *f = d->traction_demand < lim ? d->traction_demand : lim;
    *b = 0.0;
}

/* accel(v, x) -> dV/dt */
static double dyn_accel(const dyn *d, double v, double x)
{
    double f, b;
    dyn_forces(d, v, &f, &b);
    double va = v + d->wind;
    double spec = (f - b) * d->inv_weight - (d->a0 + d->a1 * v + d->a2 * va * fabs(va))
                  - rc_grade_average(d->grade, x, d->length);
    double a = d->k_acc * spec;
    return (v > 0.0 || a > 0.0) ? a : 0.0;          /* at rest: no backward roll */
}

/* models.plant.dynamics._rk4 */
static void rk4(const dyn *d, double v, double x, double h, double *v_out, double *x_out)
{
    if (v <= 0.0 && dyn_accel(d, 0.0, x) <= 0.0) {
        *v_out = 0.0;
        *x_out = x;
        return;
    }
    double k1v = dyn_accel(d, v > 0.0 ? v : 0.0, x);
    double v2 = v + 0.5 * h * k1v;
    double k2v = dyn_accel(d, v2 > 0.0 ? v2 : 0.0, x + 0.5 * h * v);
    double v3 = v + 0.5 * h * k2v;
    double k3v = dyn_accel(d, v3 > 0.0 ? v3 : 0.0, x + 0.5 * h * v2);
    double v4 = v + h * k3v;
    double k4v = dyn_accel(d, v4 > 0.0 ? v4 : 0.0, x + h * v3);
    double v_new = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    double x_new = x + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4);
    if (v_new < 0.0) {
        double t_stop = h * v / (v - v_new);       /* comes to rest inside the step */
        *v_out = 0.0;
        *x_out = x + 0.5 * v * t_stop;
        return;
    }
    *v_out = v_new;
    *x_out = x_new;
}

void rc_rk4_step(const rc_vehicle *p, const rc_grade_profile *grade, double v, double x, double h,
                 double traction_demand, double brake_demand, double wind, double *v_out,
                 double *x_out)
{
    dyn d;
    dyn_bind_vehicle(&d, p, grade, traction_demand, brake_demand, wind);
    rk4(&d, v, x, h, v_out, x_out);
}

/* CarPlant._update_outputs */
static void update_outputs(rc_plant *pl, const dyn *d)
{
    rc_plant_state *s = &pl->state;
    double f, b;
    dyn_forces(d, s->speed, &f, &b);
    double a = dyn_accel(d, s->speed, s->position);
    double grade = rc_grade_average(pl->grade, s->position, pl->p.length);
    s->acceleration = a;
    s->traction_force = f;
    s->brake_force = b;
    s->grade = grade;
    if (s->speed <= 0.0 && a <= 0.0)
        s->mode = RC_STANDSTILL;
    else if (b > 0.0)
        s->mode = RC_BRAKING;
    else if (f > 0.0)
        s->mode = RC_TRACTION;
    else
        s->mode = RC_COASTING;
}

static rc_status bad(rc_error *err, const char *name, const char *rule, double v)
{
    if (err) {
        char val[48];
        rc_repr(v, val, (int)sizeof val);
        snprintf(err->msg, sizeof err->msg, "%s %s, got %s", name, rule, val);
    }
    return RC_BAD_CONFIG;
}

rc_status rc_plant_validate(const rc_vehicle *p, double step, double noise_psd, rc_error *err)
{
    const char *names[] = {"car.mass", "car.A0", "car.A1", "car.A2", "car.gamma", "car.length",
                           "car.traction_force_max", "car.traction_power_max",
                           "car.brake_force_max", "car.adhesion_mass_fraction",
                           "car.adhesion_factor"};
    const double values[] = {p->mass, p->A0, p->A1, p->A2, p->gamma, p->length,
                             p->traction_force_max, p->traction_power_max, p->brake_force_max,
                             p->adhesion_mass_fraction, p->adhesion_factor};
    if (err) err->msg[0] = '\0';
    for (int i = 0; i < 11; i++)                    /* VehicleParams.validate, field order */
        if (!isfinite(values[i]))
            return bad(err, names[i], "must be finite", values[i]);
    const int positive[] = {0, 6, 7, 8};
    for (int i = 0; i < 4; i++)
        if (values[positive[i]] <= 0)
            return bad(err, names[positive[i]], "must be > 0", values[positive[i]]);
    const int nonnegative[] = {4, 5, 1, 2, 3};      /* gamma, length, A0, A1, A2 */
    for (int i = 0; i < 5; i++)
        if (values[nonnegative[i]] < 0)
            return bad(err, names[nonnegative[i]], "must be >= 0", values[nonnegative[i]]);
    if (!(0 < p->adhesion_mass_fraction && p->adhesion_mass_fraction <= 1))
        return bad(err, names[9], "must be in (0, 1]", p->adhesion_mass_fraction);
    if (!(0 < p->adhesion_factor && p->adhesion_factor <= 1.5))
        return bad(err, names[10], "must be in (0, 1.5]", p->adhesion_factor);
    if (!(step > 0 && isfinite(step)))
        return bad(err, "solver.step", "must be > 0", step);
    if (!(noise_psd >= 0 && isfinite(noise_psd)))
        return bad(err, "car.process_noise_psd", "must be >= 0", noise_psd);
    return RC_OK;
}

void rc_plant_init(rc_plant *pl, const rc_vehicle *p, const rc_grade_profile *grade, double step,
                   double noise_psd, double station_dwell, rc_stream *normal)
{
    pl->p = *p;
    pl->grade = grade;
    pl->h = step;
    pl->noise_std = sqrt(noise_psd * step);
    pl->station_dwell = station_dwell;
    pl->normal = normal;
    pl->state.speed = 0.0;
    pl->state.position = 0.0;
    pl->state.acceleration = 0.0;
    pl->state.traction_force = 0.0;
    pl->state.brake_force = 0.0;
    pl->state.grade = 0.0;
    pl->state.mode = RC_STANDSTILL;
    pl->state.still_time = 0.0;
    pl->state.stops = 0;
    pl->time = 0.0;
    pl->grid_index = 0;
    pl->traction_impulse = 0.0;
    pl->brake_impulse = 0.0;
    rc_plant_refresh_outputs(pl, 0.0, 0.0, 0.0);
}

void rc_plant_refresh_outputs(rc_plant *pl, double traction_demand, double brake_demand, double wind)
{
    dyn d;
    dyn_bind(&d, pl, traction_demand, brake_demand, wind);
    update_outputs(pl, &d);
}

void rc_plant_advance(rc_plant *pl, double t_end, double traction_demand, double brake_demand,
                      double wind)
{
    rc_plant_state *s = &pl->state;
    double eps = 1e-9 * rc_max(1.0, fabs(t_end));
    dyn d;
    dyn_bind(&d, pl, traction_demand, brake_demand, wind);
    while (pl->time < t_end - eps) {
        double t_grid = (double)(pl->grid_index + 1) * pl->h;    /* next_grid_time() */
        double t_next = t_grid <= t_end + eps ? t_grid : t_end;
        double h = t_next - pl->time;
        int was_still = s->speed <= 0.0;
        if (was_still && s->still_time >= pl->station_dwell && s->position != 0.0) {
            /* departure after a station stop: distance counts from this station */
            if (dyn_accel(&d, 0.0, s->position) > 0.0) {
                s->position = 0.0;
                s->stops += 1;
            }
        }
        double f0, b0, f1, b1;
        dyn_forces(&d, s->speed, &f0, &b0);
        rk4(&d, s->speed, s->position, h, &s->speed, &s->position);
        dyn_forces(&d, s->speed, &f1, &b1);
        pl->traction_impulse += 0.5 * (f0 + f1) * h;
        pl->brake_impulse += 0.5 * (b0 + b1) * h;
        pl->time = t_next;
        if (fabs(t_next - t_grid) <= eps) {
            pl->grid_index += 1;
            pl->time = (double)pl->grid_index * pl->h;
            if (s->speed > 0.0 && pl->noise_std > 0.0)
                s->speed = rc_max(0.0, s->speed + pl->noise_std * rc_stream_normal(pl->normal));
        }
        if (s->speed <= 0.0)
            s->still_time = was_still ? s->still_time + h : 0.0;
        else
            s->still_time = 0.0;
    }
    update_outputs(pl, &d);
}
