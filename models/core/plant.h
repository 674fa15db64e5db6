/* plant.h -- the true car of models/dynamics.py: forces, RK4 with inputs held, CarPlant.advance
 * (fixed internal grid, process noise at grid points, station stops) and its outputs. */
#ifndef RAILCAR_PLANT_H
#define RAILCAR_PLANT_H

#include "noise.h"
#include "track.h"

enum { RC_STANDSTILL = 0, RC_TRACTION = 1, RC_COASTING = 2, RC_BRAKING = 3 };   /* car.mode */

typedef struct {               /* models.dynamics.VehicleParams */
    double mass;               /* [t] (the chain sets base mass + payload before each step) */
    double A0, A1, A2;         /* [N/kN], [N/kN/(m/s)], [N/kN/(m/s)^2] */
    double gamma;              /* [-] */
    double length;             /* [m] */
    double traction_force_max; /* [N] */
    double traction_power_max; /* [W] */
    double brake_force_max;    /* [N] */
    double adhesion_mass_fraction, adhesion_factor;   /* [-] */
} rc_vehicle;

typedef struct {               /* models.dynamics.PlantState */
    double speed, position, acceleration, traction_force, brake_force, grade;
    int mode;
    double still_time;         /* [s] */
    long stops;
} rc_plant_state;

typedef struct {               /* models.dynamics.CarPlant */
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

/* CarPlant.__init__ (parameters validated by the caller) */
void rc_plant_init(rc_plant *pl, const rc_vehicle *p, const rc_grade_profile *grade, double step,
                   double noise_psd, double station_dwell, rc_stream *normal);
/* CarPlant.refresh_outputs(traction_demand, brake_demand, wind) */
void rc_plant_refresh_outputs(rc_plant *pl, double traction_demand, double brake_demand, double wind);
/* CarPlant.advance(t_end, traction_demand, brake_demand, wind) */
void rc_plant_advance(rc_plant *pl, double t_end, double traction_demand, double brake_demand,
                      double wind);

#endif
