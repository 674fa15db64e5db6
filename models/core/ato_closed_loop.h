/* ato_closed_loop.h -- one closed-loop run of the ATO study in the C core: the RailCar chain
 * (railcar.h: plant -> sensors -> estimator) driven over one span by the ATO controller
 * (ato_controller.h), one communication step at a time, with the run's metrics accumulated as the
 * Python loop of studies/ato_closed_loop.py (python_run) accumulates them with
 * harness/metrics/ato.py (step_work, standstill_time, energy_kwh, INTERVENTIONS): same calls in the
 * same order, Python's operand order, so the metrics are bit-identical
 * (tests/model_tests/core/test_core_ato_closed_loop.py).
 *
 *   ato_closed_loop *run = malloc(sizeof *run);      -- ~200 kB: not on a stack
 *   ato_closed_loop_init(run, &chain_cfg, &span, &car, &tuning, &loop, msg);
 *   ato_closed_loop_run(run, &result, msg);
 *   ato_closed_loop_free(run); free(run);
 *
 * The struct points into itself (the chain): initialise it where it stays, never copy it. The span
 * and car structs and their arrays are the caller's and must outlive the run. Nothing is allocated
 * per step; the replan wall times Python measures are not measured here (the re-plans are counted).
 * Units: s [m], V [m/s], t [s], force [N], mass [t], work [J], energy [kWh].
 */
#ifndef RAILCAR_ATO_CLOSED_LOOP_H
#define RAILCAR_ATO_CLOSED_LOOP_H

#include "ato_controller.h"
#include "railcar.h"

/* The chain output (railcar.h's order) each controller input (ato_tuning.h's ATO_IN_*, ALL_INPUTS
 * order) is read from: models/compiled.py's OUTPUT_NAMES.index(name) (a test holds them equal) */
extern const int ATO_LOOP_INPUT_OUTPUTS[ATO_N_ALL_INPUTS];

typedef struct {
    double step;                /* [s] the communication step (the study: 0.1) */
    double wind;                /* [m/s] the wind the chain is stepped with */
    long max_steps;             /* the loop stops after this many steps (the study: 4000) */
    rc_vehicle truth;           /* the car the plant runs as step_work clips the demands with it
                                   (models.plant.dynamics.VehicleParams) */
} ato_loop_config;

typedef struct {                /* the dict studies/ato_closed_loop.py's run returns */
    double arrival;             /* [s] the final standstill at the stop minus the schedule; inf: none */
    double settle;              /* [s] the final standstill minus the first; inf: none */
    double stop;                /* [m] the true final position minus the stop mark */
    double margin;              /* [m/s] min over the run of V_lim(s) - V (truth) */
    double energy;              /* [kWh] energy_kwh of the run's traction and regenerated work */
    long interventions;         /* [steps] commands in a safe-brake or supervisor mode */
    long replans;               /* the controller's re-plans */
    long steps;                 /* communication steps run */
    int finished;               /* the controller declared the stop (AtoController.finished) */
} ato_loop_result;

typedef struct {
    rc_chain chain;
    ato_controller ctrl;
    ato_loop_config loop;
    rc_ato_car truth;           /* loop.truth with the fields the adhesion limit reads */
    int chain_ready, ctrl_ready, done;
} ato_closed_loop;

/* CarTraction's 18 fields in declaration order (mass .. eta) into car */
void ato_car_from_values(rc_ato_car *car, const double *values);
/* AtoTuning's ATO_N_TUNING_FIELDS values in its field order into tuning (bools and ints truncated) */
void ato_tuning_from_values(ato_tuning *tuning, const double *values);

/* The chain (rc_chain_init), then the controller (AtoController(span, car, tuning)): RC_OK, or
 * RC_BAD_CONFIG / RC_MATH with the refusal's text in msg (ATO_TEXT_SIZE chars; may be NULL): the
 * loop's own settings ("step", "max_steps", "wind", "truth car.<field>") first, then the chain's
 * message, then AtoController's ValueError word for word. Nothing is left allocated on a refusal. */
rc_status ato_closed_loop_init(ato_closed_loop *run, const rc_chain_config *chain_cfg,
                               const rc_ato_span *span, const rc_ato_car *car,
                               const ato_tuning *tuning, const ato_loop_config *loop, char *msg);
/* The run, once after init: RC_OK with the metrics in *result, or RC_REJECTED with the chain's
 * message (a step it refused; the metrics so far in *result), or RC_BAD_CONFIG when run again. */
rc_status ato_closed_loop_run(ato_closed_loop *run, ato_loop_result *result, char *msg);
void ato_closed_loop_free(ato_closed_loop *run);

#endif
