/* plant.h -- the true car of models/plant/dynamics.py: forces, RK4 with inputs held, CarPlant.advance
 * (fixed internal grid, process noise at grid points, station stops) and its outputs. */
#ifndef RAILCAR_PLANT_H
#define RAILCAR_PLANT_H

#include "noise.h"
#include "rc_common.h"
#include "track.h"

enum { RC_STANDSTILL = 0, RC_TRACTION = 1, RC_COASTING = 2, RC_BRAKING = 3 };   /* car.mode */

typedef struct {               /* models.plant.dynamics.VehicleParams */
    double mass;               /* [t] (the chain sets base mass + payload before each step) */
    double A0, A1, A2;         /* [N/kN], [N/kN/(m/s)], [N/kN/(m/s)^2] */
    double gamma;              /* [-] */
    double length;             /* [m] */
    double traction_force_max; /* [N] */
    double traction_power_max; /* [W] */
    double brake_force_max;    /* [N] */
    double adhesion_mass_fraction, adhesion_factor;   /* [-] */
} rc_vehicle;

typedef struct {               /* models.plant.dynamics.PlantState */
    double speed, position, acceleration, traction_force, brake_force, grade;
    int mode;
    double still_time;         /* [s] */
    long stops;
} rc_plant_state;

typedef struct {               /* models.plant.dynamics.CarPlant */
    rc_vehicle p;
    const rc_grade_profile *grade;   /* the chain's */
    double h;                  /* internal step [s] */
    double noise_std;          /* sqrt(noise_psd * h) [m/s] */
    double station_dwell;      /* [s] */
    rc_stream *normal;         /* the "process" stream (the chain's) */
    rc_plant_state state;
    double time;               /* [s] */
    long grid_index;
    double traction_impulse, brake_impulse;   /* [N s] */
} rc_plant;

/* What CarPlant.__init__ refuses (VehicleParams.validate("car."), then solver.step and
 * car.process_noise_psd): RC_BAD_CONFIG with the first bad one named in err (Python's message
 * word for word, the value as repr() prints it), else RC_OK. err may be NULL. */
rc_status rc_plant_validate(const rc_vehicle *p, double step, double noise_psd, rc_error *err);
/* CarPlant.__init__ (parameters validated by the caller, e.g. with rc_plant_validate): the
 * vehicle is copied into pl->p (the caller may change pl->p.mass between advance calls), the
 * grade profile and the stream are the caller's (normal may be NULL when noise_psd is 0).
 * Outputs as Python's: _update_outputs(0, 0, 0) at rest at position 0. The caller may then set
 * pl->state.speed / position and call rc_plant_refresh_outputs (the chain's initial state). */
void rc_plant_init(rc_plant *pl, const rc_vehicle *p, const rc_grade_profile *grade, double step,
                   double noise_psd, double station_dwell, rc_stream *normal);
/* models.plant.dynamics.rk4_step: one RK4 step of h [s] from (v [m/s], x [m]) with the demands
 * [N] and the wind [m/s] held, the car p on the grade profile -> (*v_out, *x_out) (the plant's
 * own step: a car coming to rest inside the step stops there) */
void rc_rk4_step(const rc_vehicle *p, const rc_grade_profile *grade, double v, double x, double h,
                 double traction_demand, double brake_demand, double wind, double *v_out,
                 double *x_out);
/* CarPlant.refresh_outputs(traction_demand, brake_demand, wind) */
void rc_plant_refresh_outputs(rc_plant *pl, double traction_demand, double brake_demand, double wind);
/* CarPlant.advance(t_end, traction_demand, brake_demand, wind): integrate to t_end on the
 * internal grid, noise at each grid point reached; nothing happens unless t_end is beyond the
 * current time by more than 1e-9 max(1, |t_end|) (the outputs are still refreshed, as in Python). */
void rc_plant_advance(rc_plant *pl, double t_end, double traction_demand, double brake_demand,
                      double wind);

#endif
