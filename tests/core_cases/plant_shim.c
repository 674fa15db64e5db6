/* plant_shim.c -- test-only flat functions around rc_plant for ctypes (tests/model_tests/core/test_core_plant.py).
 * One malloc'd block owns the plant, its "process" stream and a copy of the grade profile. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "plant.h"

typedef struct {
    rc_plant plant;
    rc_stream stream;
    rc_grade_profile grade;
    double *arrays;            /* distances, grades, cum */
} shim;

/* veh: mass, A0, A1, A2, gamma, length, traction_force_max, traction_power_max,
 * brake_force_max, adhesion_mass_fraction, adhesion_factor (VehicleParams' field order);
 * the stream is models.plant.noise.noise_streams(seed, <4 names>)["process"] = child 0 */
void *shim_new(const double *veh, const double *distances, const double *grades, long n,
               double step, double noise_psd, double station_dwell, uint64_t seed)
{
    shim *sh = malloc(sizeof *sh);
    if (!sh) return NULL;
    sh->arrays = malloc(3 * (size_t)n * sizeof(double));
    if (!sh->arrays) { free(sh); return NULL; }
    memcpy(sh->arrays, distances, (size_t)n * sizeof(double));
    memcpy(sh->arrays + n, grades, (size_t)n * sizeof(double));
    rc_grade_cumulate(sh->arrays, sh->arrays + n, n, sh->arrays + 2 * n);
    sh->grade.distances = sh->arrays;
    sh->grade.grades = sh->arrays + n;
    sh->grade.cum = sh->arrays + 2 * n;
    sh->grade.n = n;
    rc_stream_seed(&sh->stream, seed, 0);
    rc_vehicle p = {veh[0], veh[1], veh[2], veh[3], veh[4], veh[5], veh[6], veh[7], veh[8],
                    veh[9], veh[10]};
    rc_plant_init(&sh->plant, &p, &sh->grade, step, noise_psd, station_dwell, &sh->stream);
    return sh;
}

void shim_free(void *h)
{
    shim *sh = h;
    if (!sh) return;
    free(sh->arrays);
    free(sh);
}

int shim_validate(const double *veh, double step, double noise_psd, char *msg, long size)
{
    rc_vehicle p = {veh[0], veh[1], veh[2], veh[3], veh[4], veh[5], veh[6], veh[7], veh[8],
                    veh[9], veh[10]};
    rc_error err;
    rc_status st = rc_plant_validate(&p, step, noise_psd, &err);
    if (size > 0) {
        strncpy(msg, err.msg, (size_t)size - 1);
        msg[size - 1] = '\0';
    }
    return (int)st;
}

void shim_set_mass(void *h, double mass) { ((shim *)h)->plant.p.mass = mass; }

/* what the chain does before refresh_outputs (and what a test may set) */
void shim_set_state(void *h, double speed, double position, double still_time, long stops)
{
    rc_plant_state *s = &((shim *)h)->plant.state;
    s->speed = speed;
    s->position = position;
    s->still_time = still_time;
    s->stops = stops;
}

void shim_set_impulses(void *h, double traction, double brake)
{
    rc_plant *pl = &((shim *)h)->plant;
    pl->traction_impulse = traction;
    pl->brake_impulse = brake;
}

void shim_refresh(void *h, double td, double bd, double wind)
{
    rc_plant_refresh_outputs(&((shim *)h)->plant, td, bd, wind);
}

void shim_advance(void *h, double t_end, double td, double bd, double wind)
{
    rc_plant_advance(&((shim *)h)->plant, t_end, td, bd, wind);
}

#define SHIM_NFIELDS 17
/* speed, position, acceleration, traction_force, brake_force, grade, mode, still_time, stops,
 * time, grid_index, traction_impulse, brake_impulse, h, noise_std, station_dwell, mass */
void shim_read(void *h, double *out)
{
    const rc_plant *pl = &((shim *)h)->plant;
    const rc_plant_state *s = &pl->state;
    double v[SHIM_NFIELDS] = {s->speed, s->position, s->acceleration, s->traction_force,
                              s->brake_force, s->grade, (double)s->mode, s->still_time,
                              (double)s->stops, pl->time, (double)pl->grid_index,
                              pl->traction_impulse, pl->brake_impulse, pl->h, pl->noise_std,
                              pl->station_dwell, pl->p.mass};
    memcpy(out, v, sizeof v);
}

#ifdef SHIM_MAIN
/* The sanitizer run: one plant driven by records on stdin, the state after each on stdout.
 * Header (doubles): 11 vehicle values, step, noise_psd, dwell, seed, n (16 values), then n
 * distances and n grades. Records (8 doubles): op, a, b, c, d, e, f, g -- op 0: set mass a and advance to b
 * with demands c, d and wind e; op 1: set state (a, b, c, d) and refresh with (e, f, g); op 2: set
 * the impulses to (a, b). */
#include <stdio.h>
int main(void)
{
    double head[16];
    if (fread(head, sizeof(double), 16, stdin) != 16) return 2;
    long n = (long)head[15];
    if (n < 1 || n > 100000) return 2;
    double *prof = malloc(2 * (size_t)n * sizeof(double));
    if (!prof || fread(prof, sizeof(double), 2 * (size_t)n, stdin) != 2 * (size_t)n) {
        free(prof);
        return 2;
    }
    void *h = shim_new(head, prof, prof + n, n, head[11], head[12], head[13], (uint64_t)head[14]);
    free(prof);
    if (!h) return 2;
    double r[8], out[SHIM_NFIELDS];
    while (fread(r, sizeof(double), 8, stdin) == 8) {
        if (r[0] == 0.0) {
            shim_set_mass(h, r[1]);
            shim_advance(h, r[2], r[3], r[4], r[5]);
        } else if (r[0] == 1.0) {
            shim_set_state(h, r[1], r[2], r[3], (long)r[4]);
            shim_refresh(h, r[5], r[6], r[7]);
        } else {
            shim_set_impulses(h, r[1], r[2]);
        }
        shim_read(h, out);
        fwrite(out, sizeof(double), SHIM_NFIELDS, stdout);
    }
    shim_free(h);
    return 0;
}
#endif
