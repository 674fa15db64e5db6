/* ato_tuning.h -- the host's side of the ATO controller (models/ato/interface.py) for the C core:
 * the inputs it reads in INPUTS / STATED_INPUTS order, the AtoMode codes, and AtoTuning (the
 * settings, their defaults and AtoTuning.__post_init__'s checks with its messages).
 *
 * The controller's parts (the supervisor, ato_supervision.h; the re-planner, motion and
 * stopping) read one `const ato_tuning *`: its fields have AtoTuning's names, in its order;
 * bool fields are 0/1 ints, int fields ints (an fmi2Integer), the rest doubles.
 *
 * Units: V [m/s], t [s], force [N], mass [t], distance [m], acceleration [m/s^2].
 */
#ifndef RAILCAR_ATO_TUNING_H
#define RAILCAR_ATO_TUNING_H

#include <stddef.h>

#include "rc_common.h"

/* interface.INPUTS: the estimator's outputs the controller reads, indices into its value array */
enum {
    ATO_IN_SPEED = 0,            /* filter.speed [m/s] */
    ATO_IN_POSITION = 1,         /* filter.position [m] */
    ATO_IN_SPEED_STD = 2,        /* filter.speed_std [m/s] */
    ATO_IN_MASS = 3,             /* est.mass [t] */
    ATO_IN_A0 = 4,               /* est.A0 [N/kN] */
    ATO_IN_A1 = 5,               /* est.A1 [N/kN/(m/s)] */
    ATO_IN_A2 = 6,               /* est.A2 [N/kN/(m/s)^2] */
    ATO_IN_STATUS = 7,           /* est.status (0..3) */
    ATO_IN_SAMPLES = 8,          /* est.samples */
    ATO_IN_POSITION_STD = 9,     /* filter.position_std [m] */
    ATO_N_INPUTS = 10,
    /* interface.STATED_INPUTS, after them (optional: their prior where not finite) */
    ATO_IN_MASS_STD = 10,        /* est.mass_std [t] */
    ATO_IN_A0_STD = 11,
    ATO_IN_A1_STD = 12,
    ATO_IN_A2_STD = 13,
    ATO_IN_COV_A0_A1 = 14,
    ATO_IN_COV_A0_A2 = 15,
    ATO_IN_COV_A1_A2 = 16,
    ATO_N_ALL_INPUTS = 17        /* interface.ALL_INPUTS */
};

/* The FMU name of input `index` (ALL_INPUTS order); NULL outside [0, ATO_N_ALL_INPUTS) */
const char *ato_input_name(int index);
/* STATED_INPUTS' prior of input `index` (ATO_N_INPUTS ..); NaN for the others */
double ato_stated_prior(int index);

/* interface.AtoMode */
typedef enum {
    ATO_MODE_TG = 0,             /* full traction */
    ATO_MODE_C = 1,              /* speed holding by traction */
    ATO_MODE_VB = 2,             /* coasting */
    ATO_MODE_SR = 3,             /* speed holding by the regenerative brake */
    ATO_MODE_RK = 4,             /* regenerative braking (along a braking curve) */
    ATO_MODE_ST = 5,             /* holding by regenerative + mechanical brake */
    ATO_MODE_TM = 6,             /* braking with the mechanical brake */
    ATO_MODE_EP = 7,             /* relay stages of the electro-pneumatic brake */
    ATO_MODE_HOLD = 8,           /* holding brake at the stop mark */
    ATO_MODE_SAFE = 9,           /* safe brake: an input was bad */
    ATO_MODE_OVERSPEED = 10,     /* the supervisor brakes */
    ATO_MODE_CREEP = 11,         /* stopped short of the mark: creeping on */
    ATO_MODE_SETTLE = 12         /* standing short of the mark while the distance settles */
} ato_mode;

#define ATO_MAX_EP_STAGES 32     /* interface.MAX_EP_STAGES */
#define ATO_MAX_MASS_BAND 5.0    /* interface.MAX_MASS_BAND */

/* interface.AtoTuning, field for field (the defaults and why: there) */
typedef struct {
    int replan;                  /* bool */
    int use_estimates;           /* bool */
    double replan_period;        /* [s] */
    double grid_step;            /* [m] */
    double time_tol;             /* [s] */
    int min_samples;             /* int */
    double mass_band;
    double limit_margin;         /* [m/s] */
    double k_sigma;
    double gap_sigma;
    double supervisor_gap;       /* [m/s] */
    double mass_reserve;
    double brake_share;
    double approach_gain;        /* [1/s] */
    double brake_integral_gain;  /* [1/s^2] */
    double brake_integral_max;   /* [m/s^2] */
    double a_ep;                 /* [m/s^2] */
    int ep_stages;               /* int */
    double relay_hysteresis;     /* [m/s] */
    double relay_stage_speed;    /* [m/s] */
    double relay_dwell;          /* [s] */
    double stand_speed;          /* [m/s] */
    double stand_time;           /* [s] */
    double creep_speed;          /* [m/s] */
    double creep_accel;          /* [m/s^2] */
    double stop_window;          /* [m] */
    double aim_sigma;
    double aim_max;              /* [m] */
    double settle_std;           /* [m] */
    double settle_sigma;
    double settle_aim_max;       /* [m] */
    double settle_time;          /* [s] */
    double settle_window;        /* [m] */
    double creep_aim;            /* [m] */
    double safe_brake;
    double hold_brake;
    double config_mass_std;
    double config_resistance_std; /* [N/kN] */
    double est_gate;
    double time_reserve;
} ato_tuning;

/* AtoTuning() */
void ato_tuning_defaults(ato_tuning *tuning);

/* A field of ato_tuning by its AtoTuning name, for hosts that set them by name (the FMU's
 * ato.<name> parameters) and for the checks, which walk them in AtoTuning's order. */
typedef enum { ATO_FIELD_BOOL = 0, ATO_FIELD_INT = 1, ATO_FIELD_REAL = 2 } ato_field_kind;
typedef struct {
    const char *name;            /* AtoTuning's field name */
    ato_field_kind kind;         /* int (BOOL, INT) or double (REAL) in ato_tuning */
    size_t offset;               /* offsetof(ato_tuning, name) */
} ato_tuning_field;

#define ATO_N_TUNING_FIELDS 40
/* Field k (0 .. ATO_N_TUNING_FIELDS - 1, AtoTuning's order); NULL outside */
const ato_tuning_field *ato_tuning_field_at(int k);
/* The field named `name`, or NULL */
const ato_tuning_field *ato_tuning_field_named(const char *name);

/* AtoTuning.__post_init__: RC_OK, or RC_BAD_CONFIG with its ValueError's text in err (the
 * first bad field in AtoTuning's order, each field's rules in Python's order; floats as repr()
 * writes them). `prefix` replaces "tuning." before the field's name (the FMU says "ato.",
 * fmu_src.adapter._fmu_names); NULL: "tuning.". err may be NULL. */
rc_status ato_tuning_validate(const ato_tuning *tuning, const char *prefix, rc_error *err);

#endif
