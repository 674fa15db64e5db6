/* config.c -- the chains' configurations from flat arrays of numbers, the one format the
 * Python binding (models/_railcar.c) and C hosts (tests/core_cases/chain_driver.c) share. One
 * optional value may follow the configuration: est.slope_window, which est.method 2 needs (the
 * native FMUs append it after their flat configuration, fmu_src/c/native_common.c; without it
 * slope_window is 0). est.A0_drift_std and est.A1_drift_std were added after the filter's numbers,
 * so the fixed indices below (seed, batch_size, frozen, method, ..., filter.kind) stayed. */
#include "rc_fp_contract.h"
#include "railcar.h"

#include <stddef.h>
#include <string.h>

/* See railcar.h: the order of models/compiled.py's _config_values */
long rc_chain_config_from_values(rc_chain_config *c, const double *v, long n)
{
    memset(c, 0, sizeof *c);      /* padding included: the chain's FMU state holds these bytes */
    double *f[] = {
        &c->vehicle.mass, &c->vehicle.A0, &c->vehicle.A1, &c->vehicle.A2, &c->vehicle.gamma,
        &c->vehicle.length, &c->vehicle.traction_force_max, &c->vehicle.traction_power_max,
        &c->vehicle.brake_force_max, &c->vehicle.adhesion_mass_fraction,
        &c->vehicle.adhesion_factor,
        &c->solver_step, &c->process_noise_psd, &c->sample_period, NULL /* seed */,
        &c->initial_speed, &c->initial_position,
        &c->station.dwell, &c->station.speed_threshold, &c->station.position_threshold,
        &c->identifier.dt, NULL /* batch_size */, &c->identifier.forgetting, &c->identifier.gamma,
        &c->identifier.mass_initial, &c->identifier.mass_std_initial, &c->identifier.A0_initial,
        &c->identifier.A1_initial, &c->identifier.A2_initial, &c->identifier.A0_std_initial,
        &c->identifier.A1_std_initial, &c->identifier.A2_std_initial,
        &c->identifier.sigma2_initial, &c->identifier.speed_std, NULL /* frozen */,
        &c->identifier.run_forgetting, NULL /* method */, NULL /* physical */,
        NULL /* sigma2_method */,
        &c->filter.dt, &c->filter.speed_std, &c->filter.position_std,
        &c->filter.position_std_rel, &c->filter.gamma, NULL /* kind */, &c->filter.length,
        &c->filter.singer_tau, &c->filter.singer_p0, &c->filter.singer_p_plus,
        &c->filter.singer_p_minus, &c->filter.singer_w_max_plus, &c->filter.singer_w_max_minus,
        &c->filter.speed_std_rel,
        &c->identifier.A0_drift_std, &c->identifier.A1_drift_std,   /* appended (models/compiled.py) */
        &c->track_spacing, &c->track_base, &c->track_resolution, &c->track_jitter,
        &c->start_time,
    };
    const long count = (long)(sizeof f / sizeof f[0]);
    if (n != count && n != count + 1)
        return count;
    for (long k = 0; k < count; k++)
        if (f[k])
            *f[k] = v[k];
    c->seed = (long)v[14];
    c->identifier.batch_size = (long)v[21];
    c->identifier.frozen = v[34] != 0.0;
    c->method = (int)v[36];
    c->slope_window = n > count ? (long)v[count] : 0;
    c->physical = (int)v[37];
    c->sigma2_method = (int)v[38];
    c->filter.kind = (int)v[44];
    return 0;
}

/* See railcar.h: the order of models/compiled.py's CompiledEstimatorChain */
long rc_estchain_config_from_values(rc_estchain_config *c, const double *v, long n)
{
    memset(c, 0, sizeof *c);      /* padding included: the chain's FMU state holds these bytes */
    double *f[] = {
        &c->identifier.dt, NULL /* batch_size */, &c->identifier.forgetting, &c->identifier.gamma,
        &c->identifier.mass_initial, &c->identifier.mass_std_initial, &c->identifier.A0_initial,
        &c->identifier.A1_initial, &c->identifier.A2_initial, &c->identifier.A0_std_initial,
        &c->identifier.A1_std_initial, &c->identifier.A2_std_initial,
        &c->identifier.sigma2_initial, &c->identifier.speed_std, NULL /* frozen */,
        &c->identifier.run_forgetting, NULL /* method */, NULL /* physical */,
        NULL /* sigma2_method */,
        &c->filter.dt, &c->filter.speed_std, &c->filter.position_std,
        &c->filter.position_std_rel, &c->filter.gamma, NULL /* kind */, &c->filter.length,
        &c->filter.singer_tau, &c->filter.singer_p0, &c->filter.singer_p_plus,
        &c->filter.singer_p_minus, &c->filter.singer_w_max_plus, &c->filter.singer_w_max_minus,
        &c->filter.speed_std_rel,
        &c->identifier.A0_drift_std, &c->identifier.A1_drift_std,   /* appended (models/compiled.py) */
        &c->station.dwell, &c->station.speed_threshold, &c->station.position_threshold,
        &c->track_base, &c->track_resolution, &c->track_jitter,
    };
    const long count = (long)(sizeof f / sizeof f[0]);
    if (n != count && n != count + 1)
        return count;
    for (long k = 0; k < count; k++)
        if (f[k])
            *f[k] = v[k];
    c->identifier.batch_size = (long)v[1];
    c->identifier.frozen = v[14] != 0.0;
    c->method = (int)v[16];
    c->slope_window = n > count ? (long)v[count] : 0;
    c->physical = (int)v[17];
    c->sigma2_method = (int)v[18];
    c->filter.kind = (int)v[24];
    return 0;
}
