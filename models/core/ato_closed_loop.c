/* ato_closed_loop.c -- one ATO closed-loop run (studies/ato_closed_loop.py's python_run) in the C
 * core; see ato_closed_loop.h. The metric helpers are harness/metrics/ato.py's functions of the
 * same name, in their operand order. */
#include "rc_fp_contract.h"
#include "ato_closed_loop.h"

#include <stdio.h>
#include <string.h>

#define J_PER_KWH 3.6e6          /* harness/metrics/ato.py J_PER_KWH */
#define OUT_SPEED 0              /* car.speed in the chain's outputs */
#define OUT_POSITION 1           /* car.position */

const int ATO_LOOP_INPUT_OUTPUTS[ATO_N_ALL_INPUTS] = {
    23,     /* filter.speed */
    24,     /* filter.position */
    25,     /* filter.speed_std */
    12,     /* est.mass */
    14,     /* est.A0 */
    15,     /* est.A1 */
    16,     /* est.A2 */
    27,     /* est.status */
    21,     /* est.samples */
    26,     /* filter.position_std */
    13,     /* est.mass_std */
    17,     /* est.A0_std */
    18,     /* est.A1_std */
    19,     /* est.A2_std */
    29,     /* est.cov_A0_A1 */
    30,     /* est.cov_A0_A2 */
    31,     /* est.cov_A1_A2 */
};

void ato_car_from_values(rc_ato_car *car, const double *values)
{
    double *fields[18] = {&car->mass, &car->A0, &car->A1, &car->A2, &car->gamma, &car->length,
                          &car->traction_force_max, &car->traction_power_max, &car->brake_force_max,
                          &car->regen_force_max, &car->regen_power_max, &car->regen_fade_speed,
                          &car->regen_off_speed, &car->mech_force_max, &car->adhesion_mass_fraction,
                          &car->adhesion_factor, &car->eta_f, &car->eta};
    for (int k = 0; k < 18; k++)
        *fields[k] = values[k];
}

void ato_tuning_from_values(ato_tuning *tuning, const double *values)
{
    ato_tuning_defaults(tuning);
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        char *at = (char *)tuning + f->offset;
        if (f->kind == ATO_FIELD_REAL)
            *(double *)at = values[k];
        else
            *(int *)at = (int)values[k];
    }
}

static void copy_msg(char *msg, const char *text)
{
    if (msg != NULL)
        snprintf(msg, ATO_TEXT_SIZE, "%s", text);
}

/* models.plant.dynamics.traction_force_limit(v, truth) */
static double traction_force_limit(const rc_ato_car *truth, double v)
{
    double f = truth->traction_force_max;
    if (v > 0.0)
        f = rc_min(f, truth->traction_power_max / v);
    return rc_min(f, rc_ato_adhesion_force_limit(truth, v));
}

/* step_work: the step's traction work and regenerated work [J] into *traction_work, *regen_work */
static void step_work(double v0, double v1, double s0, double s1, double traction, double brake,
                      const rc_ato_car *truth, const rc_ato_car *car, double *traction_work,
                      double *regen_work)
{
    double vm = 0.5 * (v0 + v1);
    double ds = s1 >= s0 ? s1 - s0 : s1;
    if (brake > 0.0) {
        double b = rc_min(brake, rc_ato_brake_total_max(truth, vm));  /* brake_force_limit */
        *traction_work = 0.0;
        *regen_work = rc_min(b, rc_ato_r_max(car, vm)) * ds;
        return;
    }
    *traction_work = rc_min(traction, traction_force_limit(truth, vm)) * ds;
    *regen_work = 0.0;
}

/* standstill_time(t0, h, v0, ds) [s] */
static double standstill_time(double t0, double h, double v0, double ds)
{
    return v0 > 0.0 ? t0 + rc_min(h, 2.0 * ds / v0) : t0;
}

/* energy_kwh(traction_work, regen_work, car) [kWh] */
static double energy_kwh(double traction_work, double regen_work, const rc_ato_car *car)
{
    return (traction_work / car->eta_f - car->eta * regen_work) / J_PER_KWH;
}

static rc_status refuse(char *msg, const char *name, const char *rule, double value)
{
    char repr[40];
    rc_repr(value, repr, (int)sizeof repr);
    if (msg != NULL)
        snprintf(msg, ATO_TEXT_SIZE, "%s must be %s, got %s", name, rule, repr);
    return RC_BAD_CONFIG;
}

rc_status ato_closed_loop_init(ato_closed_loop *run, const rc_chain_config *chain_cfg,
                               const rc_ato_span *span, const rc_ato_car *car,
                               const ato_tuning *tuning, const ato_loop_config *loop, char *msg)
{
    rc_error err;
    memset(run, 0, sizeof *run);
    copy_msg(msg, "");
    if (!(loop->step > 0.0 && isfinite(loop->step)))
        return refuse(msg, "step", "> 0 and finite", loop->step);
    if (loop->max_steps < 0)
        return refuse(msg, "max_steps", ">= 0", (double)loop->max_steps);
    if (!isfinite(loop->wind))
        return refuse(msg, "wind", "finite", loop->wind);
    if (rc_plant_validate(&loop->truth, 1.0, 0.0, &err) != RC_OK) {
        if (msg != NULL)
            snprintf(msg, ATO_TEXT_SIZE, "truth %s", err.msg);
        return RC_BAD_CONFIG;
    }
    run->loop = *loop;
    /* the truth as the ATO's car struct: only the fields the plant's force limits read */
    run->truth.mass = loop->truth.mass;
    run->truth.traction_force_max = loop->truth.traction_force_max;
    run->truth.traction_power_max = loop->truth.traction_power_max;
    run->truth.brake_force_max = loop->truth.brake_force_max;
    run->truth.adhesion_mass_fraction = loop->truth.adhesion_mass_fraction;
    run->truth.adhesion_factor = loop->truth.adhesion_factor;
    rc_status st = rc_chain_init(&run->chain, chain_cfg, &err);
    if (st != RC_OK) {
        copy_msg(msg, err.msg);
        return st;
    }
    run->chain_ready = 1;
    st = ato_controller_init(&run->ctrl, span, car, tuning, msg);
    if (st != RC_OK) {
        ato_closed_loop_free(run);
        return st;
    }
    run->ctrl_ready = 1;
    return RC_OK;
}

void ato_closed_loop_free(ato_closed_loop *run)
{
    if (run->ctrl_ready)
        ato_controller_free(&run->ctrl);
    if (run->chain_ready)
        rc_chain_free(&run->chain);
    run->ctrl_ready = run->chain_ready = 0;
}

rc_status ato_closed_loop_run(ato_closed_loop *run, ato_loop_result *result, char *msg)
{
    rc_chain *chain = &run->chain;
    ato_controller *ctrl = &run->ctrl;
    const rc_ato_span *span = ctrl->span;
    const double h = run->loop.step, wind = run->loop.wind;
    double out[RC_CHAIN_OUTPUTS], inputs[ATO_N_ALL_INPUTS];
    double t = 0.0, margin = INFINITY, w_f = 0.0, w_r = 0.0, t_stop = 0.0, t_last = 0.0;
    int has_stop = 0, has_last = 0;
    long k = 0, interventions = 0;
    rc_status st = RC_OK;
    rc_error err;
    copy_msg(msg, "");
    memset(result, 0, sizeof *result);
    if (!run->ctrl_ready || run->done) {
        copy_msg(msg, run->done ? "the closed loop has run: initialise it again"
                                : "the closed loop was not initialised");
        return RC_BAD_CONFIG;
    }
    run->done = 1;
    rc_chain_outputs(chain, out);
    while (k < run->loop.max_steps) {
        for (int i = 0; i < ATO_N_ALL_INPUTS; i++)
            inputs[i] = out[ATO_LOOP_INPUT_OUTPUTS[i]];
        ato_command cmd = ato_controller_demands(ctrl, t, inputs);
        interventions += cmd.mode == ATO_MODE_SAFE || cmd.mode == ATO_MODE_OVERSPEED;
        double v0 = out[OUT_SPEED], s0 = out[OUT_POSITION];
        st = rc_chain_step(chain, t, h, cmd.traction, cmd.brake, wind, 0.0, &err);
        if (st != RC_OK) {
            copy_msg(msg, err.msg);
            break;
        }
        k += 1;
        t = (double)k * h;
        rc_chain_outputs(chain, out);
        double v1 = out[OUT_SPEED], s1 = out[OUT_POSITION], f, r;
        step_work(v0, v1, s0, s1, cmd.traction, cmd.brake, &run->truth, ctrl->car, &f, &r);
        w_f += f;
        w_r += r;
        margin = rc_min(margin, rc_ato_v_lim(span, s1) - v1);
        if (v0 > 0.0 && v1 == 0.0 && s1 > 0.5 * span->stop) {
            t_last = standstill_time(t - h, h, v0, s1 - s0);
            has_last = 1;
            if (!has_stop) {
                t_stop = t_last;
                has_stop = 1;
            }
        }
        if (has_stop && ato_controller_finished(ctrl))
            break;
    }
    result->arrival = (has_last ? t_last : INFINITY) - span->schedule;
    result->settle = has_stop ? t_last - t_stop : INFINITY;
    result->stop = out[OUT_POSITION] - span->stop;
    result->margin = margin;
    result->energy = energy_kwh(w_f, w_r, ctrl->car);
    result->interventions = interventions;
    result->replans = ctrl->replans;
    result->steps = k;
    result->finished = ato_controller_finished(ctrl);
    return st;
}
