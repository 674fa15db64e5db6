"""Which estimator to ship under a speed sensor with relative noise: mass and w0 at the start
of each span's final coast, per configuration (a study, not a test; issue 27).

    python studies/speed_noise_line.py [--seeds 60] [--spans 5] [--ato-seeds 10] [--ato-lines 40]
                                       [--with NAME=VALUE[,NAME=VALUE] ...] [--processes 2]
                                       [--cruise-probability 0.7] [--unknown-car]

Issue 27's target: under sensor.speed_std_rel = 1 % (Meleshin's 2 % as 2 sigma), at the start
of each span's final coast, |est.mass - true mass| <= 2 t and |w0_est(V) - w0_true(V)| <= 1 N/kN
over the span's speed range in >= 95 % of spans, and the stated +-2 sigma covering the error in
90-98 % of them (w0's: pointwise, see "coverage" below). Every run uses sensor.speed_std = 0.01
m/s (a pulse counter's floor at rest) plus sensor.speed_std_rel = 0.01 (1 % of the speed as 1
sigma), as scenarios/library/ato_speed_noise.toml does.

Cases (each a table):

  line  a generated line per seed (seeds 1..N, default 60): ``--spans`` spans of 0.7-2.5 km,
        each driven by harness.run.phases.PhaseDriver (the harness's [[driver]] phases, true speed and distance):
        traction with the car's limit force to the span's cruise speed (40-80 km/h, capped so
        that traction, the final coast and the braking fit the span), a cruise (speed held) on
        70 % of the spans (``--cruise-probability``) up to 15-30 % of the span before the
        braking curve, else none: the coast starts at the cruise speed, after the traction
        alone; then the FINAL COAST (until the braking curve of the stop; cut at 0.3 x the
        cruise speed on a long climb), brake_to_stop at the span's end (0.7 m/s^2 planned), a dwell of 25-40 s at the station where passengers
        board and alight (car.payload drawn in 0-6 t per station, like station_day's
        mass_change_t). Per seed: the car's mass is est.mass_initial (the estimator's nominal
        car, 30 t unless a configuration sets it) times a factor drawn in 0.8-1.2, a wind drawn
        in -5..+5 m/s blows for the whole run, and a grade profile of 250-600 m sections of
        -20..+20 permille is drawn. The plant keys the grade by the distance from the previous
        station (harness/run/span_scenario.py says why), so the spans of one seed's line climb
        the same profile from 0, each to its own length and at its own speeds; the profile
        changes from seed to seed. Every configuration runs the same lines (paired).
  ato_line  the ATO on generated lines (seeds 1..``--ato-lines``, default 40): the lines of
        studies/ato_generated_lines.py (0.7-2.5 km spans, grades -35..+40 permille, 2-3 speed
        limit changes per span, a schedule 4-12 % above the fastest run, dwells of 25-40 s with
        0-4 t boarding or alighting), driven by the ATO (Python) over the chain, with the car's
        mass est.mass_initial x 0.8-1.2 and a wind in -5..+5 m/s drawn per seed (numpy's
        generator seeded [27, 2, seed]). The issue's line "of our own" was an ATO's: here the
        ATO decides where each final coast starts, as it does in service. Every configuration
        runs the same lines, but the ATO steers by the estimates: its coasts (and which spans
        have none) differ between configurations.
  ato   the library's ATO scenarios (scenarios/library/ato_*.toml; the ATO, Python, drives; the
        chain is C), each with its own car, grade, wind and spans, with the speed noise above and
        seed = 1000 x the scenario's seed + k for k = 1..``--ato-seeds``. ato_speed_noise then
        differs from ato_nominal by its seeds only. The ATO steers by the estimates, so its
        coasts differ between configurations.

``--unknown-car``: on both generated cases the car's car.A0, car.A1, car.A2 are drawn per seed
too (generator [27, 3, seed]) in UNKNOWN_CAR, about twice the spread of Meleshin's (2011) Table
1 (A0 0.11-0.89 N/kN, A1 0.004-0.029 N/kN/(m/s), A2 0.004-0.012 N/kN/(m/s)^2 for metro and
suburban cars), while the estimator's prior stays the FMU's default car: a user who does not
know the car. Without it the car's A's are the prior's means (still air).

All run on the models chain (no FMI) in the C core: models.compiled.open_chain picks it when
the core covers the configuration (est.method 0 and 2); the table names any other engine.

Metrics, per span, at the START of its final coast: the first row of the span's last block of
coasting rows (car.mode = COASTING while moving) of at least MIN_COAST_S; a span without one
is counted as "no final coast" and left out of the shares.

  mass error  est.mass - car.total_mass [t]; stated sigma: est.mass_std.
  w0 error    max over V in [0.3 Vmax, Vmax] of |w0_est(V) - w0_true(V)| [N/kN], Vmax the span's
              highest true speed (departure to arrival; the speeds the span travels, the same
              rule for the line and for the ATO's spans); w0_est from est.A0, est.A1, est.A2;
              w0_true what the car meets: the plant's eq. (1) with the wind then blowing,
              models.plant.dynamics.resistance_eq1(V, A0, A1, A2, wind) = A0 + A1 V +
              A2 (V + Vw)|V + Vw| (the truth of harness.metrics.estimation.true_theta for
              V + Vw > 0, where the wind moves A0 and A1; below, with a tailwind, the plant's
              sign). Stated sigma: sqrt(h C h^T), h = (1, V, V^2), C from est.A*_std and
              est.cov_A*_A* at the V where the error is largest.
  coverage    mass: share of spans with |error| <= 2 stated sigma (honest: 95.4 %).
              w0, pointwise: share of the (span, V of the grid) pairs with |err(V)| <= 2 sigma(V),
              sigma(V) = sqrt(h(V) C h(V)^T) (honest: 95.4 %, every span weighing its W0_GRID
              speeds alike). THE TARGET'S FIGURE: the stated +-2 sigma of w0 is a pointwise band
              (est.A*'s covariance gives w0's std at one speed, and an ATO asks w0 at the speed it
              plans for), so "the stated +-2 sigma covering the error in 90-98 %" is judged here.
              w0, at the worst V: the span's largest |err| over the range against 2 sigma at that
              speed, printed with its honest value in brackets: the same test scored on errors
              of the A's drawn (HONEST_DRAWS per span, seeded) from each span's own stated C. That
              value is ~91 %, not 95 %: taking the speed where the error is largest picks the
              direction in which a 3-dimensional error is largest, and a band that holds over
              every speed at once is simultaneous (2.80 sigma for a full-rank C, sqrt of chi2(3)'s
              95 % point), not 2 sigma. Kept so that nobody reads its ~90 % as a miss.
              The A's: share of spans with d^2 = (A - A')^T C^-1 (A - A') <= chi2(3)'s 95 % point
              (7.81; honest: 95 %), A' = (A0 + A2 Vw^2, A1 + 2 A2 Vw, A2) the quadratic the wind
              makes of eq. (1) (harness.metrics.estimation.true_theta). The most sensitive of the
              three (it weighs the least-known direction of C fully): a run's 2nd span, the first
              after est.method 2's prior reweighting at a mass restart, is its tail (seeds
              1-180: 12 % of 2nd spans above 7.81, 4-7 % of the later ones).
              With 300 spans a share of 95 % has a binomial standard error of 1.3 pp (2.2 pp at
              100 spans).

Columns per configuration: spans (without a final coast), shares within the targets (mass,
w0, both, both from the second span of a run on: the first coast of a run sees one span's
data), median and worst |errors|, the +-2 sigma coverages above, and the median of |error| /
stated sigma (for w0 over every (span, V of the grid)); 0.674 if the sigma is the error's
true spread and the error Gaussian: below, the sigma is overstated; above, understated. The
tables go to the terminal and, as markdown, to out/speed_noise/table.md, with a per-scenario
line for the ATO case. Seeded: the numbers repeat. Runtime of the default (40 x 5 ATO-line
spans, 60 x 5 line spans, 10 seeds per ATO scenario, six configurations): ~6 min on 2 cores,
most of it the ATO runs (the ATO is Python; the line alone, --ato-seeds 0 --ato-lines 0: 30 s;
--ato-lines 100: ~15 min; the honest references' draws ~2 s). A span without a final coast
(the ATO goes from traction to braking) is counted in its own column and left out of the shares.
"""
from __future__ import annotations

import argparse
import math
import shlex
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from fmu_src.variables import FORMER_DEFAULTS  # noqa: E402
from harness.run.driver import chain_result  # noqa: E402
from harness.metrics.estimation import true_theta  # noqa: E402
from harness.run.scenario import RAILCAR_PARAMETERS, load_scenario, scenario_from_dict  # noqa: E402
from models.plant.dynamics import COASTING, resistance_eq1  # noqa: E402
import studies.ato_generated_lines as ato_lines_module  # noqa: E402
from studies.ato_generated_lines import line_scenario_with  # noqa: E402

LIBRARY = ROOT / "scenarios" / "library"
OUT = ROOT / "out" / "speed_noise"
SPEED_NOISE = {"sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.01}   # [m/s], [-]

DEFAULT_SEEDS = 60           # generated lines: 300 spans, a share's standard error 1.3 pp (20: 2.2)
MASS_TARGET_T = 2.0          # [t]
W0_TARGET = 1.0              # [N/kN]
SPEED_RANGE_LOW = 0.3        # the span's speed range starts at this share of its top speed
W0_GRID = 60                 # speeds sampled in that range
MIN_COAST_S = 2.0            # [s] a shorter block of coasting rows is a transition, not a coast
STEP_S = 0.1                 # [s] communication step (= sensor.sample_period)

# the coverages' honest values: what an error drawn from the stated covariance itself scores
POINTWISE_HONEST = math.erf(2.0 / math.sqrt(2.0))   # P(|z| <= 2) = 0.9545 for each (span, V)
CHI2_3_95 = 7.814727903251179                      # chi2(3)'s 95 % point (scipy.stats.chi2.ppf(0.95, 3))
Z_MEDIAN_HONEST = 0.6744897501960817               # median |z| of a standard normal
HONEST_DRAWS = 2000          # errors drawn per span for the worst-speed test's honest value
HONEST_SEED = 27             # their generator's seed (the draws repeat)

# the generated line (numbers drawn per seed)
SPAN_LENGTH_M = (700.0, 2500.0)
CRUISE_KMH = (40.0, 80.0)
GRADE_SECTION_M = (250.0, 600.0)
GRADE_PERMILLE = 20.0        # sections of -20..+20 permille
MASS_FACTOR = 0.2            # the car's mass within +-20 % of est.mass_initial
WIND_MPS = 5.0               # constant wind within +-5 m/s
PAYLOAD_T = (0.0, 6.0)       # passengers on board after each station [t]
DWELL_S = (25.0, 40.0)
COAST_SHARE = (0.15, 0.3)    # the final coast's planned share of the span's length
CRUISE_PROBABILITY = 0.7     # spans with a cruise (speed held) before the final coast
ATO_LINE_SEEDS = 40          # ATO-driven generated lines: 200 spans (a share's standard error 1.5 pp)
UNKNOWN_CAR = {"car.A0": (0.1, 2.0), "car.A1": (0.004, 0.06), "car.A2": (0.004, 0.016)}
"""--unknown-car: the ranges [units of eq. (1): N/kN, N/kN/(m/s), N/kN/(m/s)^2] the car's A's are
drawn in, uniformly (Meleshin's (2011) Table 1 spans A0 0.11-0.89, A1 0.004-0.029, A2 0.004-0.012)."""
BRAKE_DECEL = 0.7            # [m/s^2] brake_to_stop's planned deceleration
TRACTION_DECEL_PLAN = 0.35   # [m/s^2] a cautious mean acceleration, for the cruise-speed cap


def _default_std(name: str) -> float:
    return float(RAILCAR_PARAMETERS[name].start)


WIDE_PRIORS = {n: 3.0 * _default_std(n) for n in ("est.A0_std_initial", "est.A1_std_initial",
                                                  "est.A2_std_initial")}
DEFAULT_CONFIGS: tuple[dict, ...] = (
    FORMER_DEFAULTS,
    {},
    {"est.sigma2_method": 0},
    {"est.physical": 1},
    {"est.A0_std_initial": 5.0},
    WIDE_PRIORS,
)
"""The paper's scheme as the FMUs ran it before; the FMUs' defaults (est.method 2, LS on
Sidorenko's slopes, est.sigma2_method 1, A0 prior std 2 N/kN); with the LAG sigma^2; with A0,
A2 >= 0; with the A0 prior std of before (5 N/kN); with A priors 3x the FMU's default stds."""


def config_label(config: dict) -> str:
    """"NAME=VALUE, ..." (est.method 0 marked as the paper's); "FMU defaults" for {}."""
    if not config:
        return "FMU defaults"
    label = ", ".join(f"{k}={v:g}" for k, v in config.items())
    return label + (" (paper)" if config == FORMER_DEFAULTS else "")


def parse_config(text: str) -> dict:
    """"NAME=VALUE[,NAME=VALUE]" -> {FMU name: value} (int for an Integer parameter). ValueError
    naming the item for an unknown name or a value that is not a number."""
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, _, value = item.partition("=")
        name, value = name.strip(), value.strip()
        var = RAILCAR_PARAMETERS.get(name)
        if var is None or not value:
            raise ValueError(f"--with {text!r}: {item!r} is not NAME=VALUE with a RailCar parameter NAME")
        try:
            out[name] = int(value) if var.type == "Integer" else float(value)
        except ValueError:
            raise ValueError(f"--with {text!r}: {name}: expected {'an integer' if var.type == 'Integer' else 'a number'}, "
                             f"got {value!r}") from None
    return out


# ------------------------------------------------------------------------------ the generated line

@dataclass(frozen=True)
class PlannedSpan:
    """One span of a generated line."""
    length_m: float          # the stop mark, from the previous station [m]
    cruise_mps: float        # [m/s]
    coast_from_m: float      # the cruise ends here and the final coast begins [m]
    cruise: bool             # a cruise before the final coast (else the coast follows traction)
    dwell_s: float           # [s] at the station at its end (the last span: none)
    payload_change_t: float  # [t] boarding (< 0: alighting) at the station at its end


@dataclass(frozen=True)
class GeneratedLine:
    """A seed's line: the car, the wind, the grade and the spans."""
    seed: int
    mass_t: float                        # the car without passengers [t]
    wind_mps: float                      # headwind > 0 [m/s], constant
    grade_distances_m: tuple[float, ...]
    grade_permille: tuple[float, ...]
    spans: tuple[PlannedSpan, ...]


def generate_line(seed: int, n_spans: int, nominal_mass_t: float,
                  cruise_probability: float = CRUISE_PROBABILITY) -> GeneratedLine:
    """The line of ``seed`` (deterministic) with ``n_spans`` spans, for an estimator configured
    with a car of ``nominal_mass_t`` [t]; a span cruises before its final coast with
    ``cruise_probability`` (the same draws whatever it is: only the cruises change)."""
    rng = np.random.default_rng([27, seed])
    mass = nominal_mass_t * rng.uniform(1.0 - MASS_FACTOR, 1.0 + MASS_FACTOR)
    wind = rng.uniform(-WIND_MPS, WIND_MPS)
    spans, payload = [], 0.0
    for k in range(n_spans):
        length = rng.uniform(*SPAN_LENGTH_M)
        coast_share = rng.uniform(*COAST_SHARE)
        # traction, the final coast and the braking must fit: v^2 (1/(2 a_t) + 1/(2 a_b)) <= the rest
        room = (1.0 - coast_share) * length
        cap = math.sqrt(room / (0.5 / TRACTION_DECEL_PLAN + 0.5 / BRAKE_DECEL))
        cruise = min(rng.uniform(*CRUISE_KMH) / 3.6, cap)
        coast_from = length - coast_share * length - cruise * cruise / (2.0 * BRAKE_DECEL)
        with_cruise = bool(rng.uniform() < cruise_probability)
        last = k == n_spans - 1
        new_payload = payload if last else rng.uniform(*PAYLOAD_T)
        spans.append(PlannedSpan(length, cruise, coast_from, with_cruise,
                                 0.0 if last else rng.uniform(*DWELL_S), new_payload - payload))
        payload = new_payload
    top = max(s.length_m for s in spans) + 500.0
    distances, x = [0.0], 0.0
    while True:
        x += rng.uniform(*GRADE_SECTION_M)
        if x >= top:
            break
        distances.append(round(x, 1))
    grades = [round(rng.uniform(-GRADE_PERMILLE, GRADE_PERMILLE), 2) for _ in distances]
    return GeneratedLine(seed, mass, wind, tuple(distances), tuple(grades), tuple(spans))


def line_phases(line: GeneratedLine) -> list[dict]:
    """The [[driver]] phases of the line (harness.run.phases)."""
    phases = []
    for s in line.spans:
        # by speed only: until the departure the plant's distance is still the last span's
        phases.append({"action": "traction", "until_speed_mps": s.cruise_mps})
        if s.cruise:
            phases.append({"action": "cruise", "target_speed_mps": s.cruise_mps,
                           "until_distance_m": s.coast_from_m})
        # the final coast; stopped early at 0.3 x cruise (a long climb), then braked to a stop
        phases.append({"action": "coast", "until_brake_curve": True,
                       "until_speed_mps": SPEED_RANGE_LOW * s.cruise_mps})
        phases.append({"action": "brake_to_stop", "stop_at_m": s.length_m, "decel_mps2": BRAKE_DECEL})
        if s.dwell_s > 0.0:
            phases.append({"action": "hold", "until_time_s": s.dwell_s, "mass_change_t": s.payload_change_t})
    phases.append({"action": "hold", "until_time_s": 5.0})
    return phases


def unknown_car(seed: int) -> dict:
    """``--unknown-car``: seed's car.A0, car.A1, car.A2, drawn uniformly in UNKNOWN_CAR."""
    rng = np.random.default_rng([27, 3, seed])
    return {name: float(rng.uniform(*bounds)) for name, bounds in UNKNOWN_CAR.items()}


def ato_line_truth(seed: int, nominal_mass_t: float) -> tuple[float, float]:
    """(car mass [t], headwind [m/s]) of the ATO-driven line ``seed``: the mass within +-20 % of
    ``nominal_mass_t``, the wind within +-5 m/s, as on the generated line."""
    rng = np.random.default_rng([27, 2, seed])
    return (nominal_mass_t * float(rng.uniform(1.0 - MASS_FACTOR, 1.0 + MASS_FACTOR)),
            float(rng.uniform(-WIND_MPS, WIND_MPS)))


def line_scenario(line: GeneratedLine, config: dict, folder: Path, truth: dict | None = None):
    """The line as a harness scenario (harness.run.scenario.scenario_from_dict: the loader's checks),
    its grade profile written to ``folder``; the chain configured with ``config``; ``truth``: more
    of the car's parameters (``unknown_car``)."""
    grade = folder / f"line_grade_{line.seed}.csv"
    grade.write_text("distance_m,grade_permille\n" + "".join(
        f"{d},{g}\n" for d, g in zip(line.grade_distances_m, line.grade_permille)), encoding="utf-8")
    duration = sum(s.length_m / (0.4 * s.cruise_mps) + s.dwell_s + 60.0 for s in line.spans) + 60.0
    data = {"name": f"line_seed{line.seed}", "purpose": "studies/speed_noise_line.py: a generated line",
            "step_s": STEP_S, "duration_s": round(duration, 1), "stop_after_last_phase": True,
            "parameters": {"car.mass": line.mass_t, "track.grade_profile": str(grade), "seed": line.seed,
                           **SPEED_NOISE, **(truth or {}), **config},
            "driver": line_phases(line), "wind": [{"time_s": 0.0, "speed_mps": line.wind_mps}]}
    return scenario_from_dict(data, str(grade.with_suffix(".toml")), folder)


# ------------------------------------------------------------------------------ scoring

@dataclass(frozen=True)
class SpanScore:
    """One span at the start of its final coast; nan where it has none."""
    source: str              # scenario name
    span: int                # 0-based within the run
    coast: bool              # a final coast was found
    mass_err_t: float = math.nan     # est - true [t]
    mass_std_t: float = math.nan     # est.mass_std [t]
    w0_err: float = math.nan         # max |w0_est - w0_true| over the speed range [N/kN]
    w0_std: float = math.nan         # w0_est's std at the speed of that maximum [N/kN]
    v_worst_mps: float = math.nan    # that speed [m/s]
    v_max_mps: float = math.nan      # the span's top speed [m/s]
    coast_at_m: float = math.nan     # where the final coast starts, from the station [m]
    w0_cover_pointwise: float = math.nan   # share of the W0_GRID speeds with |err(V)| <= 2 sigma(V)
    w0_z: tuple = ()                 # |err(V)| / sigma(V) at the W0_GRID speeds [-]
    a_d2: float = math.nan           # (A - A')^T C^-1 (A - A'): the A's against chi2(3) [-]
    a_cov: tuple = ()                # C, est.A*'s stated covariance, as 3 rows
    cruise: bool | None = None       # the generated line's plan: a cruise before the final coast (None: not planned)

    @property
    def mass_ok(self) -> bool:
        return abs(self.mass_err_t) <= MASS_TARGET_T

    @property
    def w0_ok(self) -> bool:
        return self.w0_err <= W0_TARGET


def speed_grid(v_max: float) -> np.ndarray:
    """The W0_GRID speeds [m/s] of a span's speed range [SPEED_RANGE_LOW v_max, v_max]."""
    return np.linspace(SPEED_RANGE_LOW * v_max, v_max, W0_GRID)


def w0_sigma(cov: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """w0_est's stated std sqrt(h C h^T), h = (1, V, V^2), at ``speeds`` [N/kN]."""
    h = np.vstack([np.ones_like(speeds), speeds, speeds * speeds])      # 3 x grid
    return np.sqrt(np.maximum(np.einsum("ig,ij,jg->g", h, cov, h), 0.0))


def honest_worst_speed_cover(cov: np.ndarray, v_max: float, rng: np.random.Generator,
                             draws: int = HONEST_DRAWS) -> float:
    """What the worst-speed w0 test (the largest |err| over the span's speed range against 2 sigma
    at that speed) scores for a covariance that is exactly right: the share of ``draws`` errors
    of the A's drawn from N(0, ``cov``) that pass it on the grid of ``v_max`` [m/s].

    Below 95 %: the largest of a 3-dimensional error's values over the range picks the direction
    in which that error is largest, so the band it needs is simultaneous (2.80 sigma for a full
    rank C, sqrt of chi2(3)'s 95 % point); with C of rank 1 in A0 alone it is the pointwise 95.4 %."""
    speeds = speed_grid(v_max)
    h = np.vstack([np.ones_like(speeds), speeds, speeds * speeds])      # 3 x grid
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    root = vectors * np.sqrt(np.maximum(values, 0.0))                   # root @ root^T = C
    errors = np.abs(rng.standard_normal((draws, 3)) @ root.T @ h)       # draws x grid
    worst = np.argmax(errors, axis=1)
    return float(np.mean(errors[np.arange(draws), worst] <= 2.0 * w0_sigma(cov, speeds)[worst]))


def span_bounds(result) -> list[tuple[int, int]]:
    """(first row, arrival row) of each span of a run: a span starts at the run's start or where
    the plant's distance restarts (departure from a station) and ends where the car comes to
    rest last before the next departure. A span that never comes to rest is left out."""
    v, x = result["car.speed"], result["car.position"]
    starts = [0] + [k for k in range(1, len(x)) if x[k] < x[k - 1]]
    ends = starts[1:] + [len(x)]
    out = []
    for s, e in zip(starts, ends):
        arrivals = [k for k in range(s + 1, e) if v[k] <= 0.0 < v[k - 1]]
        if arrivals:
            out.append((s, arrivals[-1]))
    return out


def final_coast_start(result, first: int, arrival: int, min_rows: int) -> int | None:
    """First row of the last block of >= ``min_rows`` coasting rows (car.mode = COASTING, moving)
    in [first, arrival), or None."""
    coasting = (result["car.mode"][first:arrival] == COASTING) & (result["car.speed"][first:arrival] > 0.0)
    start = None
    k = len(coasting)
    while k > 0:
        if not coasting[k - 1]:
            k -= 1
            continue
        end = k
        while k > 0 and coasting[k - 1]:
            k -= 1
        if end - k >= min_rows:
            start = first + k
            break
    return start


def score_w0(span: SpanScore, A: np.ndarray, cov: np.ndarray, v_max: float, still_air_A: tuple,
             wind: float) -> SpanScore:
    """``span`` with its w0 and A fields filled in: est.A0..A2 ``A`` and their stated covariance
    ``cov`` against the car's ``still_air_A`` (A0, A1, A2) in the ``wind`` [m/s], over the speed
    range of ``v_max`` [m/s]."""
    speeds = speed_grid(v_max)
    truth = resistance_eq1(speeds, *still_air_A, wind)                  # what the car meets
    h = np.vstack([np.ones_like(speeds), speeds, speeds * speeds])      # 3 x grid
    err = np.abs(A @ h - truth)
    worst = int(np.argmax(err))
    sigma = w0_sigma(cov, speeds)
    # the A's against the quadratic the wind makes of the plant's eq. (1): A0', A1', A2
    a_err = A - true_theta(1.0, still_air_A, wind)[1:]
    try:
        d2 = float(a_err @ np.linalg.solve(cov, a_err))
    except np.linalg.LinAlgError:
        d2 = math.nan
    return replace(span, w0_err=float(err[worst]), w0_std=float(sigma[worst]),
                   v_worst_mps=float(speeds[worst]), v_max_mps=v_max,
                   w0_cover_pointwise=float(np.mean(err <= 2.0 * sigma)),
                   w0_z=tuple(float(z) for z in err / sigma), a_d2=d2,
                   a_cov=tuple(tuple(float(x) for x in row) for row in cov))


def score_spans(result, vehicle, name: str) -> list[SpanScore]:
    """Every span of a run (``result``: harness RunResult of the chain; ``vehicle``: the true car,
    models.plant.dynamics.VehicleParams) scored at the start of its final coast."""
    min_rows = int(round(MIN_COAST_S / result.scenario.step_s))
    v = result["car.speed"]
    scores = []
    for i, (first, arrival) in enumerate(span_bounds(result)):
        c = final_coast_start(result, first, arrival, min_rows)
        if c is None:
            scores.append(SpanScore(name, i, False))
            continue
        v_max = float(np.max(v[first:arrival + 1]))
        A = np.array([float(result[f"est.A{j}"][c]) for j in range(3)])
        cov = np.diag([float(result[f"est.A{j}_std"][c]) ** 2 for j in range(3)])
        for (p, q), col in {(0, 1): "est.cov_A0_A1", (0, 2): "est.cov_A0_A2", (1, 2): "est.cov_A1_A2"}.items():
            cov[p, q] = cov[q, p] = float(result[col][c])
        scores.append(score_w0(
            SpanScore(name, i, True,
                      mass_err_t=float(result["est.mass"][c] - result["car.total_mass"][c]),
                      mass_std_t=float(result["est.mass_std"][c]),
                      coast_at_m=float(result["car.position"][c])),
            A, cov, v_max, (vehicle.A0, vehicle.A1, vehicle.A2), result.scenario.wind_at(float(result.time[c]))))
    return scores


# ------------------------------------------------------------------------------ running

def run_job(job: tuple) -> tuple[int, str, list[SpanScore], str]:
    """(config index, case, the run's span scores, the chain's engine) of one job:
    ("line", config index, config, seed, spans, cruise probability, unknown car),
    ("ato_line", config index, config, seed, spans, unknown car) or ("ato", config index,
    config, path, seed)."""
    case, index, config = job[:3]
    nominal = float(config.get("est.mass_initial", RAILCAR_PARAMETERS["est.mass_initial"].start))
    if case == "line":
        seed, n_spans, cruise_probability, unknown = job[3:]
        line = generate_line(seed, n_spans, nominal, cruise_probability)
        with tempfile.TemporaryDirectory(prefix="speed_noise_line_") as folder:
            scenario = line_scenario(line, config, Path(folder), unknown_car(seed) if unknown else None)
            setup = scenario.setup.chain          # resolved while the profile file exists
        chain = setup.open()
        result = chain_result(chain, scenario)
        scores = [replace(sc, cruise=line.spans[sc.span].cruise)
                  for sc in score_spans(result, setup.config.vehicle, scenario.name)]
        return index, case, scores, chain.engine
    if case == "ato_line":
        seed, n_spans, unknown = job[3:]
        mass, wind = ato_line_truth(seed, nominal)
        truth = {"car.mass": mass, **SPEED_NOISE, **(unknown_car(seed) if unknown else {}), **config}
        with tempfile.TemporaryDirectory(prefix="speed_noise_ato_line_") as folder:
            scenario, _ = line_scenario_with(seed, n_spans, truth, wind, Path(folder))
            setup = scenario.setup.chain
            chain = setup.open()
            result = chain_result(chain, scenario)     # the ATO reads the profile as it plans
        return index, case, score_spans(result, setup.config.vehicle, scenario.name), chain.engine
    path, seed = job[3:]
    scenario = load_scenario(path)
    setup = scenario.chain_setup({"seed": seed, **SPEED_NOISE, **config})
    chain = setup.open()
    result = chain_result(chain, scenario)
    return index, case, score_spans(result, setup.config.vehicle, f"{scenario.name}#{seed}"), chain.engine


def ato_paths() -> list[Path]:
    return sorted(LIBRARY.glob("ato_*.toml"))


def jobs_for(configs, seeds: int, spans: int, ato_seeds: int,
             cruise_probability: float = CRUISE_PROBABILITY, ato_lines: int = 0,
             unknown: bool = False) -> list[tuple]:
    """Every job, the longest first (the ATO's generated lines, the library's ato_line, the other
    ATO runs, then the lines)."""
    jobs = [("ato_line", i, c, seed, spans, unknown)
            for seed in range(1, ato_lines + 1) for i, c in enumerate(configs)]
    for path in sorted(ato_paths(), key=lambda p: p.stem != "ato_line"):
        own = int(load_scenario(path).parameter("seed"))
        for k in range(1, ato_seeds + 1):
            jobs += [("ato", i, c, path, 1000 * own + k) for i, c in enumerate(configs)]
    for seed in range(1, seeds + 1):
        jobs += [("line", i, c, seed, spans, cruise_probability, unknown) for i, c in enumerate(configs)]
    return jobs


def compute(configs, seeds: int = DEFAULT_SEEDS, spans: int = 5, ato_seeds: int = 10,
            processes: int = 2, cruise_probability: float = CRUISE_PROBABILITY,
            ato_lines: int = 0, unknown: bool = False) -> dict:
    """{(case, config index): (span scores, engines)} over every job; ``ato_lines``: seeds of the
    ATO-driven generated line; ``unknown``: --unknown-car."""
    jobs = jobs_for(configs, seeds, spans, ato_seeds, cruise_probability, ato_lines, unknown)
    if processes > 1 and len(jobs) > 1:
        with Pool(processes) as pool:
            done = list(pool.imap_unordered(run_job, jobs, chunksize=1))
    else:
        done = [run_job(j) for j in jobs]
    out: dict = {}
    for index, case, scores, engine in done:
        got = out.setdefault((case, index), ([], set()))
        got[0].extend(scores)
        got[1].add(engine)
    for scores, _ in out.values():                      # a fixed order, whatever the pool did
        scores.sort(key=lambda s: (s.source, s.span))
    return out


# ------------------------------------------------------------------------------ tables

HEADER = ("configuration", "spans (no final coast)", "mass err within 2 t [%]", "w0 err within 1 N/kN [%]",
          "both [%]", "both, 1st span [%]", "both, 2nd+ span [%]", "abs mass err median / worst [t]",
          "w0 err median / worst [N/kN]", "mass ±2σ cover [%]", "w0 ±2σ cover pointwise [%] (honest 95.4)",
          "w0 ±2σ cover at the worst V [%] (honest σ)", "A's d² within χ²₃ 95 % [%] (honest 95)",
          "median err/σ mass / w0 pointwise (honest: 0.67)")
"""The table's columns (no "|" in a name: the markdown copy splits cells at it)."""


@dataclass(frozen=True)
class Summary:
    """A configuration's spans on one case; shares in [0, 1] over the spans with a final coast."""
    spans: int
    no_coast: int
    mass_ok: float
    w0_ok: float
    both_ok: float
    both_ok_first: float           # a run's first spans
    both_ok_later: float           # spans after a run's first
    mass_median: float             # |error| [t]
    mass_worst: float
    w0_median: float               # [N/kN]
    w0_worst: float
    mass_cover: float
    w0_cover: float                # the worst speed's |error| within 2 sigma there
    mass_z_median: float           # median |error| / stated sigma [-]: 0.674 for an honest Gaussian
    w0_z_median: float             # the same over every (span, speed of the grid)
    w0_cover_pointwise: float      # share of (span, speed of the grid) with |error| <= 2 sigma: 0.954 honest
    w0_cover_honest: float         # what w0_cover would be for errors drawn from each span's stated C
    a_chi2_cover: float            # share of spans with the A's d^2 <= chi2(3)'s 95 % point: 0.95 honest


def summarise(scores: list[SpanScore]) -> Summary:
    ok = [s for s in scores if s.coast]
    if not ok:
        n = math.nan
        return Summary(len(scores), len(scores), *([n] * 16))
    first = [s for s in ok if s.span == 0]
    later = [s for s in ok if s.span > 0]
    mass = np.abs([s.mass_err_t for s in ok])
    w0 = np.array([s.w0_err for s in ok])
    rng = np.random.default_rng(HONEST_SEED)            # the same draws for every configuration
    honest = [honest_worst_speed_cover(np.array(s.a_cov), s.v_max_mps, rng) for s in ok]
    return Summary(
        len(scores), len(scores) - len(ok),
        float(np.mean([s.mass_ok for s in ok])), float(np.mean([s.w0_ok for s in ok])),
        float(np.mean([s.mass_ok and s.w0_ok for s in ok])),
        float(np.mean([s.mass_ok and s.w0_ok for s in first])) if first else math.nan,
        float(np.mean([s.mass_ok and s.w0_ok for s in later])) if later else math.nan,
        float(np.median(mass)), float(mass.max()), float(np.median(w0)), float(w0.max()),
        float(np.mean([abs(s.mass_err_t) <= 2.0 * s.mass_std_t for s in ok])),
        float(np.mean([s.w0_err <= 2.0 * s.w0_std for s in ok])),
        float(np.median([abs(s.mass_err_t) / s.mass_std_t for s in ok])),
        float(np.median(np.concatenate([s.w0_z for s in ok]))),
        float(np.mean([s.w0_cover_pointwise for s in ok])),     # every span has W0_GRID speeds
        float(np.mean(honest)),
        float(np.mean([s.a_d2 <= CHI2_3_95 for s in ok])))


def _pct(x: float) -> str:
    return "n/a" if x != x else f"{100.0 * x:.1f}"


def _num(x: float, fmt: str) -> str:
    return "n/a" if x != x else fmt.format(x)


def table_cells(configs, results: dict, case: str) -> list[list[str]]:
    cells = []
    for i, config in enumerate(configs):
        if (case, i) not in results:
            continue
        scores, engines = results[(case, i)]
        s = summarise(scores)
        label = config_label(config) + ("" if engines == {"c"} else f" [engine: {', '.join(sorted(engines))}]")
        cells.append([label, f"{s.spans} ({s.no_coast})", _pct(s.mass_ok), _pct(s.w0_ok), _pct(s.both_ok),
                      _pct(s.both_ok_first), _pct(s.both_ok_later),
                      f"{_num(s.mass_median, '{:.2f}')} / {_num(s.mass_worst, '{:.2f}')}",
                      f"{_num(s.w0_median, '{:.2f}')} / {_num(s.w0_worst, '{:.2f}')}",
                      _pct(s.mass_cover), _pct(s.w0_cover_pointwise),
                      f"{_pct(s.w0_cover)} ({_pct(s.w0_cover_honest)})", _pct(s.a_chi2_cover),
                      f"{_num(s.mass_z_median, '{:.2f}')} / {_num(s.w0_z_median, '{:.2f}')}"])
    return cells


def by_scenario_cells(configs, results: dict) -> tuple[tuple, list[list[str]]]:
    """The ATO case per scenario: "both [%] (w0 err median [N/kN])" per configuration."""
    names = [p.stem for p in ato_paths()]
    cells = []
    for i, config in enumerate(configs):
        if ("ato", i) not in results:
            continue
        scores = results[("ato", i)][0]
        row = [config_label(config)]
        for name in names:
            s = summarise([x for x in scores if x.source.split("#")[0] == name])
            row.append(f"{_pct(s.both_ok)} ({_num(s.w0_median, '{:.2f}')})")
        cells.append(row)
    return ("configuration", *names), cells


def first_span_cells(configs, results: dict) -> tuple[tuple, list[list[str]]]:
    """The line case's first spans (with a final coast) within both bounds, "k of n", split by
    the plan: a cruise before the final coast, or the traction alone."""
    cells = []
    for i, config in enumerate(configs):
        if ("line", i) not in results:
            continue
        first = [x for x in results[("line", i)][0] if x.span == 0 and x.coast]
        row = [config_label(config)]
        for cruise in (True, False):
            part = [x for x in first if x.cruise is cruise]
            row.append(f"{sum(x.mass_ok and x.w0_ok for x in part)} of {len(part)}")
        cells.append(row)
    return ("configuration", "after a cruise", "after the traction alone"), cells


def markdown(header: tuple, cells: list[list[str]]) -> str:
    w = [max([len(h)] + [len(c[i]) for c in cells]) for i, h in enumerate(header)]
    lines = ["| " + " | ".join(h.ljust(w[i]) for i, h in enumerate(header)) + " |",
             "|" + "|".join("-" * (n + 2) for n in w) + "|"]
    lines += ["| " + " | ".join(x.ljust(w[i]) for i, x in enumerate(c)) + " |" for c in cells]
    return "\n".join(lines)


def report(configs, results: dict, seeds: int, spans: int, ato_seeds: int, seconds: float | None,
           command: str = "", cruise_probability: float = CRUISE_PROBABILITY, ato_lines: int = 0,
           unknown: bool = False) -> str:
    """Every case's table with its title, as markdown."""
    car = (", the car's A's drawn (--unknown-car: A0 {}-{}, A1 {}-{}, A2 {}-{})".format(
        *(x for b in UNKNOWN_CAR.values() for x in b)) if unknown else "")
    noise = ", ".join(f"{k} = {v:g}" for k, v in SPEED_NOISE.items())
    parts = ["# Mass and w0 at the start of each span's final coast under relative speed noise", "",
             f"{noise}; targets |mass err| <= {MASS_TARGET_T:g} t and w0 err <= {W0_TARGET:g} N/kN "
             f"(max over [{SPEED_RANGE_LOW:g} Vmax, Vmax] of the span) in >= 95 % of spans, ±2σ "
             "covering the error in 90-98 % (w0's: pointwise, over every span and speed of its range; "
             "at the worst V the bracket gives what an honest σ scores, ~91 %). "
             "Models chain, C core unless a row says otherwise."]
    if command:
        parts += ["", f"    {command}"]
    grades, changes, boarding = ato_lines_module.GRADE_PERMILLE, ato_lines_module.LIMIT_CHANGES, \
        ato_lines_module.BOARDING_T
    for case, title in (("ato_line", f"The ATO on generated lines: {ato_lines} seeds x {spans} spans, mass ±20 %, "
                                     f"wind ±5 m/s, grades {grades[0]:+g}..{grades[1]:+g} ‰, "
                                     f"{changes[0]}-{changes[1]} limit changes a span, "
                                     f"boarding {boarding[0]:+g}..{boarding[1]:+g} t{car}"),
                        ("line", f"Generated line: {seeds} seeds x {spans} spans, mass ±20 %, wind ±5 m/s, "
                                 f"grades ±20 ‰, boarding 0-6 t, a cruise before "
                                 f"{100 * cruise_probability:.0f} % of the final coasts{car}"),
                        ("ato", f"ATO scenarios ({', '.join(p.stem for p in ato_paths())}), "
                                f"{ato_seeds} seeds each")):
        cells = table_cells(configs, results, case)
        if cells:
            parts += ["", f"## {title}", "", markdown(HEADER, cells)]
        if cells and case == "ato":
            parts += ["", "Per ATO scenario: both within target [%] (w0 err median [N/kN])", "",
                      markdown(*by_scenario_cells(configs, results))]
        if cells and case == "line":
            parts += ["", "The line's first spans within both bounds, by what came before the final coast", "",
                      markdown(*first_span_cells(configs, results))]
    if seconds is not None:
        parts += ["", f"Computed in {seconds:.0f} s."]
    return "\n".join(parts) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=DEFAULT_SEEDS,
                    help=f"generated lines (seeds 1..N), default {DEFAULT_SEEDS}")
    ap.add_argument("--spans", type=int, default=5, help="spans per generated line, default 5")
    ap.add_argument("--ato-seeds", type=int, default=10, help="seeds per ATO scenario, default 10 (0: no ATO table)")
    ap.add_argument("--with", dest="configs", action="append", default=[], metavar="NAME=VALUE[,NAME=VALUE]",
                    help="a configuration (a row; repeatable); default: the six of DEFAULT_CONFIGS")
    ap.add_argument("--cruise-probability", type=float, default=CRUISE_PROBABILITY,
                    help=f"share of the line's spans with a cruise before the final coast (else it "
                         f"starts at the cruise speed), default {CRUISE_PROBABILITY}")
    ap.add_argument("--ato-lines", type=int, default=ATO_LINE_SEEDS,
                    help=f"generated lines the ATO drives (seeds 1..N), default {ATO_LINE_SEEDS} (0: no such table)")
    ap.add_argument("--unknown-car", action="store_true",
                    help="draw the car's A's per seed on both generated cases (UNKNOWN_CAR); "
                         "the estimator's prior stays the FMU's default car")
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args(argv)
    if args.seeds < 0 or args.spans < 1 or args.ato_seeds < 0 or args.ato_lines < 0:
        ap.error("--seeds, --ato-seeds and --ato-lines must be >= 0, --spans >= 1")
    if not 0.0 <= args.cruise_probability <= 1.0:
        ap.error(f"--cruise-probability must be in [0, 1], got {args.cruise_probability}")
    try:
        configs = [parse_config(c) for c in args.configs] or list(DEFAULT_CONFIGS)
    except ValueError as e:
        ap.error(str(e))
    t0 = time.perf_counter()
    results = compute(configs, args.seeds, args.spans, args.ato_seeds, args.processes,
                      args.cruise_probability, args.ato_lines, args.unknown_car)
    command = "python studies/speed_noise_line.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    text = report(configs, results, args.seeds, args.spans, args.ato_seeds, time.perf_counter() - t0,
                  command.strip(), args.cruise_probability, args.ato_lines, args.unknown_car)
    print(text)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "table.md").write_text(text, encoding="utf-8")
    print(f"written {OUT / 'table.md'}")


if __name__ == "__main__":
    main()
