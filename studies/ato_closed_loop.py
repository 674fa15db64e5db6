"""The ATO in closed loop with the estimator: Monte Carlo over seeds (issue 20's targets).

    python studies/ato_closed_loop.py [--seeds 100] [--workers 2] [--case NAME ...]
                                      [--controller native|python]

The RailCar chain (models.compiled.open_chain: plant, sensors, estimator, configured like the
RailCar FMU with its default parameters) runs a 2.15 km span (the library's demo grade profile
extended: level, +15, -10, level, +5 permille; 80 km/h with a 60 km/h zone from 900 to 1300 m;
stop mark at 2150 m; schedule 135 s, 9.6 % above the minimum-time run) under
models.ato.controller.AtoController (or its C twin: --controller), one communication step of 0.1 s at a time. Per case and variant,
seeds 1..N (the chain's noise seed):

  arrival   true time of the final standstill at the stop minus the schedule [s] (as
            harness/metrics/ato.py counts it); share within +-2.5 s (Meleshin 2011,
            Sidorenko 1997)
  settle    where the filter's distance is uncertain (filter.position_std above
            AtoTuning.settle_std: the noise cases) the controller stops short, stands and creeps
            on to the mark (models/ato/controller.py): the mean time [s] from the first standstill to the
            final one, over all runs (0: one stop); the first standstill is arrival - settle
  stop      true final stop position minus the stop mark [m]; share within +-0.3 m (Sidorenko
            1997), max
  margin    min over the run of V_lim(s) - V (true speed and position) [m/s]: > 0 = never over
  energy    traction work / eta_f - eta x regenerated work [kWh] (docs/ato.md, The controller), from the
            true speeds and the demands as the plant applies them; "vs manual" against
            models.planning.trajectory.manual_driver on the true car (flat out, coast, brake: what a
            driver does to meet the schedule), "MP" the maximum-principle plan's own saving
  safety    runs with a safe-brake or supervisor intervention
(the per-step energy, the standstill time and what counts as an intervention are
harness/metrics/ato.py's, which the harness's span scenarios report too: one copy)

Variants: identified parameters + re-planning (the regulator), configured coefficients + a
fixed plan (planned once, no re-planning: the reference the issue asks for), configured
coefficients + re-planning (what re-planning alone gives), and the regulator with a one-go stop
(AtoTuning.settle_time = 0: never stop short and settle, so time comes first where the filter's
distance is uncertain; the same as the first variant where it is not).

Cases (the configured car is the RailCar FMU's default 30 t car with Meleshin's (2011)
Rusich resistance; the truth differs): mass +-20 %; A0 off by +-50 %; a 5 m/s headwind; speed-sensor
noise; wet rail (adhesion x 0.5). The speed noise: Meleshin (2011; docs/model.md) says running-time
control to +-2.5 s needs the speed measured within 2 % (never above the truth), a bound
relative to the speed. Two readings, each as 2 sigma (the library's convention) and as 1 sigma.
Relative, as Meleshin writes it (RailCar's sensor.speed_std_rel over a 0.01 m/s floor):

  noise 2 %V (2 sd) sensor.speed_std = 0.01 m/s + 1 % of the speed (ato_speed_noise)
  noise 2 %V (1 sd) sensor.speed_std = 0.01 m/s + 2 % of the speed

and absolute, 2 % of 80 km/h (0.444 m/s) at every speed, the pessimistic reading:

  noise 2 % (2 sd)  sensor.speed_std = 0.222 m/s: the 2 % bound as 2 sigma at 80 km/h (the
                    library's convention for etcs_noisy_sensors). Pessimistic
                    below 80 km/h: at the 7 km/h of the final EP stage 2 % would be 0.04 m/s,
                    this is 0.222 m/s
  noise 2 % (1 sd)  sensor.speed_std = 0.444 m/s: the bound as 1 sigma at every speed, a stress
                    case (a sensor that breaks the bound a third of the time at 80 km/h and by
                    11x at 7 km/h)

Seeded and deterministic (the chain's seed; the controller has no randomness). Processes:
concurrent.futures over --workers (2 by default). --controller native (the default where the C core
is compiled) runs each whole run in C (models/core/ato_closed_loop.c: the C chain under the C
AtoController, the metrics accumulated in C, bit-identical to python_run's; ~5 ms a run against
~200 ms); --controller python runs python_run, the Python AtoController stepped from Python (and
the only one that times the re-plans). Same table, character for character.
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from harness.metrics.ato import INTERVENTIONS, energy_kwh, standstill_time, step_work  # noqa: E402
from models.ato.controller import AtoController  # noqa: E402
from models.ato.interface import AtoTuning  # noqa: E402
from models.plant.dynamics import VehicleParams  # noqa: E402
from models.planning.span import CarTraction, Span  # noqa: E402
from models.plant.track import GradeProfile  # noqa: E402
from models.units import kmh_to_mps  # noqa: E402

V80, V60 = kmh_to_mps(80.0), kmh_to_mps(60.0)
SPAN = Span(2200.0, 135.0, stop=2150.0,
            grade=GradeProfile((0.0, 300.0, 800.0, 1100.0, 1500.0), (0.0, 15.0, -10.0, 0.0, 5.0)),
            limit_distances=(0.0, 900.0, 1300.0), limit_speeds=(V80, V60, V80))
CAR = CarTraction()                 # configured: the RailCar FMU's defaults
STEP = 0.1                          # [s] communication step
HEADWIND = 5.0                      # [m/s]

CASES = {   # name: (RailCar parameter overrides, wind [m/s])
    "nominal": ({}, 0.0),
    "mass +20 %": ({"car.mass": 36.0}, 0.0),
    "mass -20 %": ({"car.mass": 24.0}, 0.0),
    "A0 +50 %": ({"car.A0": 1.5 * CAR.A0}, 0.0),
    "A0 -50 %": ({"car.A0": 0.5 * CAR.A0}, 0.0),
    "headwind 5 m/s": ({}, HEADWIND),
    "noise 2 % (2 sd)": ({"sensor.speed_std": 0.01 * V80}, 0.0),
    "noise 2 % (1 sd)": ({"sensor.speed_std": 0.02 * V80}, 0.0),
    "noise 2 %V (2 sd)": ({"sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.01}, 0.0),
    "noise 2 %V (1 sd)": ({"sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.02}, 0.0),
    "wet rail": ({"car.adhesion_factor": 0.5}, 0.0),
}
VARIANTS = {
    "identified + re-plan": AtoTuning(),
    "configured, fixed plan": AtoTuning(replan=False, use_estimates=False),
    "configured + re-plan": AtoTuning(use_estimates=False),
    "identified, one-go stop": AtoTuning(settle_time=0.0),
}


def railcar_values(seed: int, overrides: dict) -> dict:
    from harness.run.scenario import railcar_values as defaults
    return defaults({**overrides, "seed": seed})


def true_car(overrides: dict, wind: float) -> CarTraction:
    """The car the plant runs, as the planner's CarTraction; a headwind Vw moves A0 and A1
    (docs/model.md, Forces on the car: A0 + A2 Vw^2, A1 + 2 A2 Vw)."""
    kw = {"mass": overrides.get("car.mass", CAR.mass), "A0": overrides.get("car.A0", CAR.A0),
          "adhesion_factor": overrides.get("car.adhesion_factor", CAR.adhesion_factor)}
    kw["A0"] += CAR.A2 * wind * wind
    return CarTraction(**kw, A1=CAR.A1 + 2.0 * CAR.A2 * wind)


CONTROLLERS = ("native", "python")
"""native: the whole run in C (models.compiled.run_ato_closed_loop: the C chain under the C
AtoController, the metrics accumulated in C); python: python_run, the Python AtoController on the
chain open_chain gives. Their rows are equal (tests/model_tests/core/test_core_ato_closed_loop.py);
only python's carry the re-plans' wall times."""
MAX_STEPS = 4000                    # the loop's cap: 400 s, three times the schedule


def default_controller() -> str:
    """native where the C core is compiled and enabled (models.compiled.enabled), else python."""
    from models import compiled
    return "native" if compiled.enabled() else "python"


def run_setup(case: str, seed: int):
    """(RailCar's parameter values, the true car step_work clips with, wind [m/s]) of a run."""
    overrides, wind = CASES[case]
    values = railcar_values(seed, overrides)
    truth = VehicleParams(mass=values["car.mass"], A0=values["car.A0"],
                          adhesion_factor=values["car.adhesion_factor"])
    return values, truth, wind


def python_run(case: str, variant: str, seed: int) -> dict:
    """One closed-loop run with the Python controller; the metrics of the module docstring (the
    loop models/core/ato_closed_loop.c runs in C for the native controller: change both)."""
    from fmu_src.adapter import chain_config
    from models.compiled import open_chain
    values, truth, wind = run_setup(case, seed)
    chain = open_chain(chain_config(values), SPAN.grade)
    ctrl = AtoController(SPAN, CAR, VARIANTS[variant])
    out = chain.outputs()
    t, k = 0.0, 0
    margin = math.inf
    w_f = w_r = 0.0
    t_stop = t_last = None
    interventions = 0
    while k < MAX_STEPS:
        cmd = ctrl.demands(t, out)
        interventions += cmd.mode in INTERVENTIONS
        v0, s0 = out["car.speed"], out["car.position"]
        chain.do_step(t, STEP, cmd.traction, cmd.brake, wind, 0.0)
        k += 1
        t = k * STEP
        out = chain.outputs()
        v1, s1 = out["car.speed"], out["car.position"]
        f, r = step_work(v0, v1, s0, s1, cmd.traction, cmd.brake, truth, CAR)
        w_f += f
        w_r += r
        margin = min(margin, SPAN.v_lim(s1) - v1)
        if v0 > 0.0 and v1 == 0.0 and s1 > 0.5 * SPAN.stop:
            t_last = standstill_time(t - STEP, STEP, v0, s1 - s0)
            t_stop = t_last if t_stop is None else t_stop
        if t_stop is not None and ctrl.finished:
            break
    energy = energy_kwh(w_f, w_r, CAR)
    return {"case": case, "variant": variant, "seed": seed,
            "arrival": (t_last if t_last is not None else math.inf) - SPAN.schedule,
            "settle": (t_last - t_stop) if t_stop is not None else math.inf,
            "stop": out["car.position"] - SPAN.stop, "margin": margin, "energy": energy,
            "interventions": interventions, "replans": ctrl.replans,
            "replan_ms": [1e3 * x for x in ctrl.replan_seconds[1:]]}


METRICS = ("arrival", "settle", "stop", "margin", "energy", "interventions", "replans")
"""A run's metrics (both controllers); besides them a row has case, variant, seed, replan_ms."""


def native_runs(case: str, variant: str, seeds) -> list[dict]:
    """python_run's dicts for each seed, bit for bit, from one call to the C core (the runs differ
    only by the chain's seed); replan_ms is empty: the C controller does not time its re-plans."""
    from fmu_src.adapter import chain_config
    from models.compiled import run_ato_closed_loop
    seeds = list(seeds)
    if not seeds:
        return []
    values, truth, wind = run_setup(case, seeds[0])
    runs = run_ato_closed_loop(chain_config(values), SPAN, CAR, VARIANTS[variant], truth, wind,
                               STEP, MAX_STEPS, seeds)
    return [{"case": case, "variant": variant, "seed": seed, **{k: m[k] for k in METRICS},
             "replan_ms": []} for seed, m in zip(seeds, runs)]


def run_one(case: str, variant: str, seed: int, controller: str | None = None) -> dict:
    """One closed-loop run with ``controller`` (CONTROLLERS; None: default_controller())."""
    return run_batch(case, variant, [seed], controller)[0]


def run_batch(case: str, variant: str, seeds, controller: str | None = None) -> list[dict]:
    """The runs of one case and variant for each seed with ``controller`` (CONTROLLERS; None:
    default_controller())."""
    controller = controller or default_controller()
    if controller == "native":
        return native_runs(case, variant, seeds)
    if controller == "python":
        return [python_run(case, variant, s) for s in seeds]
    raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")


def _batch(args):
    # the controller logs each fallback and supervision event (thousands over a study) to
    # stderr; the table counts the interventions, so its log is left out here
    logging.getLogger("models.ato").setLevel(logging.ERROR)
    return run_batch(*args)


def reference_key(case: str) -> tuple:
    """What a case's references depend on: the true car's overrides and the wind."""
    overrides, wind = CASES[case]
    return (overrides.get("car.mass"), overrides.get("car.A0"), overrides.get("car.adhesion_factor"),
            wind)


def reference(case: str) -> tuple[float, float]:
    """Energy [kWh] of the manual driver and of the maximum-principle plan on the case's true
    car (the planners of models/planning/trajectory.py, 5 m steps)."""
    from models.planning.trajectory import manual_driver, synthesize
    car = true_car(*CASES[case])
    return manual_driver(SPAN, car).energy_kwh, synthesize(SPAN, car).energy_kwh


def references(cases=tuple(CASES)):
    """reference() of each case, computed once per distinct true car."""
    out = {}
    for case in cases:
        key = reference_key(case)
        if key not in out:
            out[key] = reference(case)
    return {c: out[reference_key(c)] for c in cases}


def table(results, refs) -> str:
    head = (f"{'case':17s} {'variant':23s} | {'arrival err [s]':>15s} {'<=2.5s':>6s} | "
            f"{'settle':>6s} | {'stop err [m]':>13s} {'<=0.3m':>6s} {'max':>6s} | {'margin':>6s} | "
            f"{'energy':>6s} {'vs man.':>7s} {'MP':>6s} | {'safety':>6s}")
    lines = [head, "-" * len(head)]
    for case in (c for c in CASES if c in refs):
        e_man, e_mp = refs[case]
        for variant in VARIANTS:
            rs = [r for r in results if r["case"] == case and r["variant"] == variant]
            if not rs:
                continue
            a = np.array([r["arrival"] for r in rs])
            st = np.array([r["stop"] for r in rs])
            e = np.array([r["energy"] for r in rs])
            w = np.mean([r["settle"] for r in rs])
            lines.append(
                f"{case:17s} {variant:23s} | {np.mean(a):+6.2f} +-{np.std(a):5.2f}  "
                f"{100 * np.mean(np.abs(a) <= 2.5):5.0f}% {w:6.1f} | {np.mean(st):+6.3f} +-{np.std(st):5.3f}"
                f" {100 * np.mean(np.abs(st) <= 0.3):5.0f}% {np.max(st):+6.2f} | "
                f"{min(r['margin'] for r in rs):6.3f} | {np.mean(e):6.3f} "
                f"{100 * (np.mean(e) / e_man - 1):+6.1f}% {100 * (e_mp / e_man - 1):+5.1f}% | "
                f"{sum(r['interventions'] > 0 for r in rs):6d}")
        lines.append("")
    return "\n".join(lines)


def study(cases, n_seeds: int, workers: int, controller: str | None = None):
    """(runs, references) of every case and variant for seeds 1..n_seeds, over ``workers``
    processes: each distinct true car's references (Python planners, ~1 s each) a job of its own,
    submitted first, the runs after them."""
    controller = controller or default_controller()
    seeds = list(range(1, n_seeds + 1))
    chunk = max(1, len(seeds) // 4)
    jobs = [(c, v, seeds[i:i + chunk], controller) for c in cases for v in VARIANTS
            for i in range(0, len(seeds), chunk)]
    results = []
    firsts = {reference_key(c): c for c in reversed(cases)}      # the first case of each car
    with ProcessPoolExecutor(max_workers=workers) as pool:
        ref_futures = {key: pool.submit(reference, case) for key, case in firsts.items()}
        for batch in pool.map(_batch, jobs):
            results.extend(batch)
        refs = {c: ref_futures[reference_key(c)].result() for c in cases}
    return results, refs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100, help="seeds per case and variant")
    ap.add_argument("--workers", type=int, default=2, help="processes")
    ap.add_argument("--case", action="append", choices=list(CASES), metavar="NAME",
                    help="run only this case (repeatable; default: all): " + ", ".join(CASES))
    ap.add_argument("--controller", choices=CONTROLLERS, default=default_controller(),
                    help="native: each run in the C core (the default where it is compiled); "
                         "python: the Python AtoController (also times the re-plans); same table")
    args = ap.parse_args(argv)
    cases = args.case or list(CASES)
    t0 = time.perf_counter()
    results, refs = study(cases, args.seeds, args.workers, args.controller)
    print(__doc__.split("\n\n")[0].strip())
    print(f"\nspan: {SPAN.stop:g} m, schedule {SPAN.schedule:g} s; {args.seeds} seeds per row; "
          f"step {STEP} s; controller {args.controller}\n")
    print(table(results, refs))
    ms = np.concatenate([[], *(r["replan_ms"] for r in results if r["replans"])])
    if len(ms):
        timing = (f"re-plan wall time: median {np.median(ms):.1f} ms, 99th percentile "
                  f"{np.percentile(ms, 99):.1f} ms, max {np.max(ms):.1f} ms over {len(ms)} re-plans")
    else:
        timing = (f"re-plans: {sum(r['replans'] for r in results)} (wall time not measured by the "
                  f"native controller: --controller python)")
    print(f"{timing} (one every {VARIANTS['identified + re-plan'].replan_period:g} s); manual-driver "
          f"energy per case [kWh]: " + ", ".join(f"{c} {refs[c][0]:.3f}" for c in cases))
    print("columns: arrival err (final standstill) mean +- sd and share within +-2.5 s; settle = mean s "
          "from the first standstill to the final one (short stop, stand, creep); stop err mean +- sd, share "
          "within +-0.3 m and the largest overrun; margin = smallest V_lim - V over all runs "
          "[m/s]; energy mean [kWh], vs the manual driver on the true car, MP = the "
          "maximum-principle plan's own difference; safety = runs with a safe-brake or "
          "supervisor command")
    print(f"wall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
