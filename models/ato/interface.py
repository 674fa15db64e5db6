"""What a host sees of the ATO controller (models/ato/controller.py): the estimator's outputs it
reads (``INPUTS``), the command it returns each step (``AtoCommand`` with its ``AtoMode``) and its
settings (``AtoTuning``, each default justified beside it). The AtoController FMU
(fmu_src/ato_controller.py), the harness and the span scenarios' ``[ato]`` table use these.

Units: V [m/s], t [s], force [N], mass [t], distance [m], acceleration [m/s^2].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import IntEnum

MAX_EP_STAGES = 32       # tuning.ep_stages: EP brakes have a handful of stages (Sidorenko 1997)
MAX_MASS_BAND = 5.0      # tuning.mass_band: the estimator reports est.mass within a factor 5
#                          of its start (OnlineEstimator.MASS_RANGE): a wider band admits nothing

INPUTS = ("filter.speed", "filter.position", "filter.speed_std", "est.mass", "est.A0",
          "est.A1", "est.A2", "est.status", "est.samples", "filter.position_std")
"""The outputs the controller reads, by their FMU names."""

STATED_INPUTS = (("est.mass_std", 10.0), ("est.A0_std", 2.0), ("est.A1_std", 0.1),
                 ("est.A2_std", 0.02), ("est.cov_A0_A1", 0.0), ("est.cov_A0_A2", 0.0),
                 ("est.cov_A1_A2", 0.0))
"""The estimates' stated uncertainty, which the regulator weighs them by (models/ato/controller.py
blend_estimates), with the value used where a host does not give one (or gives one that is
not finite): the estimator's prior (fmu_src/variables.py est.*_std_initial), which gives
est.* little weight. Optional: a host that passes only INPUTS still runs (with that prior)."""

ALL_INPUTS = INPUTS + tuple(name for name, _ in STATED_INPUTS)
"""Everything the controller reads: what a host should pass (the AtoController FMU's inputs)."""


class AtoMode(IntEnum):
    """AtoCommand.mode. 0..6 are the modes of Meleshin's (2011) Table 2
    (models.planning.engine.Mode)."""
    TG = 0          # full traction
    C = 1           # speed holding by traction
    VB = 2          # coasting
    SR = 3          # speed holding by the regenerative brake
    RK = 4          # regenerative braking (along a braking curve)
    ST = 5          # holding by regenerative + mechanical brake
    TM = 6          # braking with the mechanical brake (along a braking curve)
    EP = 7          # relay stages of the electro-pneumatic brake (AtoCommand.ep_stage)
    HOLD = 8        # holding brake at the stop mark
    SAFE = 9        # safe brake: an input was bad (models/ato/supervision.py; reason logged)
    OVERSPEED = 10  # the supervisor brakes: the speed is above the supervision curve
    CREEP = 11      # stopped short of the mark: creeping on
    SETTLE = 12     # standing short of the mark while the filter's distance settles


UPPER_BOUNDS = {   # AtoTuning field: (largest value, why), each found absurd at 1e300
    "grid_step": (100.0, "m: 1e300 refused every schedule as infeasible without naming the grid"),
    "limit_margin": (5.0, "m/s below every limit: 1e300 refused every limit"),
    "time_tol": (2.5, "the planner's tolerance cannot exceed the running-time target itself: "
                      "1e300 arrived 24 s late"),
    "k_sigma": (10.0, "sigmas of filter.speed_std: 1e300 never left the station"),
    "gap_sigma": (10.0, "sigmas of filter.speed_std: 1e300 never left the station"),
    "supervisor_gap": (5.0, "m/s below the supervision curve: 1e300 never left the station"),
    "mass_reserve": (1.0, "a share of the planned mass: 1e300 never left the station"),
    "stand_time": (10.0, "s at rest before the car counts as standing: 1e300 never finished a "
                         "stop, 60 outlasted the estimator's station dwell"),
    "aim_sigma": (10.0, "sigmas of filter.speed_std short of the mark"),
    "config_mass_std": (1.0, "a share of car.mass"),
    "config_resistance_std": (100.0, "N/kN: 100 times any car's resistance uncertainty"),
    "est_gate": (100.0, "combined sigmas"),
}
"""Upper bounds of AtoTuning fields whose largest values leave a useless controller (a car
that never departs or never finishes its stop); the others run (tests/model_tests/ato/
test_tuning_bounds.py drives each at 1e300 or at its bound)."""


@dataclass(frozen=True)
class AtoCommand:
    """One step's output: demands [N], the mode, the planned speed [m/s], the EP stage."""
    traction: float
    brake: float
    mode: int
    planned_speed: float
    ep_stage: int = 0


@dataclass(frozen=True)
class AtoTuning:
    """The controller's settings (defaults justified in the comments)."""
    replan: bool = True               # the running-time regulator re-plans the rest of the span
    use_estimates: bool = True        # re-plan and feed forward with est.* when usable
    replan_period: float = 2.0        # [s] a few s: the arrival error a step of model error
    #                                   builds up in 2 s is far below the 2.5 s target
    grid_step: float = 10.0           # [m] re-planner's grid (0.4 % energy of synthesize's)
    time_tol: float = 0.05            # [s] re-plan's running-time tolerance (1/50 of 2.5 s)
    min_samples: int = 100            # est.samples before est.* are used (10 s at 0.1 s)
    mass_band: float = 1.6            # the blended mass kept in [car.mass / this, car.mass x this]
    #                                   (the library's cars: 24 t empty to 44 t crush-loaded)
    limit_margin: float = 0.5         # [m/s] planned speeds stay this far below V_lim
    #                                   (1.8 km/h, about Meleshin's (2011) 2 % speed error at
    #                                   80 km/h)
    k_sigma: float = 3.0              # supervisor: filter.speed + k_sigma * filter.speed_std
    gap_sigma: float = 2.5            # and gap_sigma x filter.speed_std more: under speed noise
    #                                   filter.speed jumps by up to ~2 sigma in one update (0.4
    #                                   m/s at sigma 0.2), which woke the supervisor in every run
    #                                   at 2 % of V as 1 sigma (0.5 / 1.5: still 100 % / 60 %)
    supervisor_gap: float = 0.1       # [m/s] the controller keeps filter.speed + k_sigma *
    #                                   filter.speed_std this far below the supervision curve
    mass_reserve: float = 0.2         # supervisor's curves: this share more mass than planned
    #                                   (the planned curves use 0.85 x 40 kN, the supervisor
    #                                   45 kN / 1.2 = 37.5 kN per planned mass: never inside)
    brake_share: float = 0.85         # planned braking curves use this share of the electric
    #                                   brake: the rest (and the mechanical brake) is reserve
    approach_gain: float = 1.0        # [1/s] speed feedback of holding and curve tracking
    brake_integral_gain: float = 0.5  # [1/s^2] integral feedback on the final braking curve
    brake_integral_max: float = 0.3   # [m/s^2] its bound (anti-windup: ~25 % of the curve)
    a_ep: float = 1.0                 # [m/s^2] programmed deceleration of the EP stage (a
    #                                   metro service rate; 0.7 costs 1 s and 2 % energy)
    ep_stages: int = 6                # EP brake stages of car.mech_force_max / ep_stages
    relay_hysteresis: float = 0.03    # [m/s] relay on above +, off below - this speed error
    relay_stage_speed: float = 0.1    # [m/s] one more stage per this much further error
    relay_dwell: float = 0.3          # [s] between stage changes (an EP valve's response)
    stand_speed: float = 0.05         # [m/s] at or below for stand_time: the car stands
    stand_time: float = 0.5           # [s]
    creep_speed: float = 0.3          # [m/s] creeping to the mark after a short stop
    creep_accel: float = 0.2          # [m/s^2]
    stop_window: float = 0.15         # [m] standing closer than this to the aim: arrived
    aim_sigma: float = 1.0            # aim this many filter.speed_std x (the EP stage's
    aim_max: float = 0.5              # duration) short of the mark, at most aim_max [m] (3:
    #                                   stops 0.06 m short on average, 1: 0.02 m)
    settle_std: float = 0.13          # [m] filter.position_std above this at the final braking
    #                                   curve and still at the EP stage: stop short, stand, creep
    #                                   on (else one stop). +-0.3 m in 95 % needs an error sd of
    #                                   0.3 / 1.96 = 0.15 m, and under speed noise the filter
    #                                   claims ~15 % too little (its distance lags): 0.13 m
    settle_sigma: float = 6.0         # the short stop aims this many filter.position_std short
    settle_aim_max: float = 1.5       # [m] at most
    settle_time: float = 5.0          # [s] standing before the creep (the filter's distance
    #                                   catches up with the car at rest; < track.station_dwell);
    #                                   0: never a short stop. 3 s: 95 % / 81 % within 0.3 m at
    #                                   0.222 / 0.444 m/s speed noise, 4.5-6 s: 96-98 % / 86-91 %
    settle_window: float = 0.05       # [m] the stop_window after the stand: the creep gets
    #                                   within a few cm, a wider window only adds error
    creep_aim: float = 0.05           # [m] the creep after the stand aims this far short:
    #                                   after 5 s the filter's distance still lags ~0.05 m
    safe_brake: float = 1.0           # share of car.brake_force_max on a bad input
    hold_brake: float = 0.5           # share of car.brake_force_max held at the stop (at least
    #                                   the last EP stage)
    # the regulator's blend of est.* and the configured car (controller.blend_estimates)
    config_mass_std: float = 0.1      # the configured car.mass's own uncertainty, a share of it
    #                                   (a metro car's load: 24-44 t around 30 t is ~+-2 sigma)
    config_resistance_std: float = 1.0  # [N/kN] the configured resistance's own uncertainty
    #                                   (a 5 m/s headwind adds 1.4 N/kN at 40 km/h, A0 +50 % 0.45)
    est_gate: float = 3.0             # est.* further from the configured car than this many
    #                                   combined sigmas get no weight, nearer than est_gate - 1
    #                                   full weight, linear between (stated stds that are 5x too
    #                                   small under speed noise put them 5-7 sigma away)
    time_reserve: float = 0.01        # re-plans aim time_reserve x (remaining time)^2 /
    #                                   schedule early (1 s of a 100 s span at departure, 0.25 s
    #                                   half-way, 0 at the mark) x (1 - the blend's gate
    #                                   factor): while est.* and the configured car disagree,
    #                                   room for a model error that shows only late. 0.03 left
    #                                   the time unused on coasts (studies/ato_generated_lines.py,
    #                                   speed noise: 92 % of spans within 2.5 s; 0.01: 100 %;
    #                                   0: 100 %, but the combination 97 % against 98 %)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("bool",):
                if not isinstance(v, bool):
                    raise ValueError(f"tuning.{f.name} must be True or False, got {v!r}")
                continue
            if f.type == "int":
                if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                    raise ValueError(f"tuning.{f.name} must be an integer >= 1, got {v!r}")
                if f.name == "ep_stages" and v > MAX_EP_STAGES:
                    raise ValueError(f"tuning.ep_stages must be in [1, {MAX_EP_STAGES}], got {v!r}: "
                                     f"the relay switches one stage per relay_dwell, and a stage "
                                     f"of car.mech_force_max / {v} corrects next to nothing")
                continue
            try:
                x = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"tuning.{f.name} must be a number, got {v!r}") from None
            if not math.isfinite(x) or x < 0.0:
                raise ValueError(f"tuning.{f.name} must be finite and >= 0, got {v!r}")
            if f.name == "mass_band" and not 1.0 <= x <= MAX_MASS_BAND:
                raise ValueError(f"tuning.mass_band must be in [1, {MAX_MASS_BAND:g}], got {v!r} "
                                 f"(the estimator reports est.mass within a factor 5 of its start: "
                                 f"a wider band admits nothing more)")
            positive = ("replan_period", "grid_step", "time_tol", "approach_gain", "a_ep",
                        "relay_stage_speed", "stand_speed", "creep_speed", "brake_share",
                        "creep_accel", "safe_brake", "hold_brake", "config_mass_std",
                        "config_resistance_std")
            if f.name in positive and x == 0.0:
                raise ValueError(f"tuning.{f.name} must be > 0, got {v!r}")
            if f.name == "est_gate" and x < 1.0:
                raise ValueError(f"tuning.est_gate must be >= 1, got {v!r} (full weight "
                                 f"ends est_gate - 1 sigmas from the configured car)")
            if f.name in UPPER_BOUNDS and x > UPPER_BOUNDS[f.name][0]:
                high, why = UPPER_BOUNDS[f.name]
                raise ValueError(f"tuning.{f.name} must be <= {high:g}, got {v!r} ({why})")
            if f.name == "time_reserve" and x > 0.2:
                raise ValueError(f"tuning.time_reserve must be in [0, 0.2], got {v!r} (a share "
                                 f"of the remaining running time planned early)")
            shares = ("brake_share", "safe_brake", "hold_brake")
            if f.name in shares and x > 1.0:
                raise ValueError(f"tuning.{f.name} must be in (0, 1], got {v!r}")
