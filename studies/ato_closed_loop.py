"""The ATO in closed loop with the estimator: Monte Carlo over seeds (issue 20's targets).

    python studies/ato_closed_loop.py [--seeds 100] [--workers 2] [--case NAME ...]

The RailCar chain (models.compiled.open_chain: plant, sensors, estimator, configured like the
RailCar FMU with its default parameters) runs a 2.15 km span (the library's demo grade profile
extended: level, +15, -10, level, +5 permille; 80 km/h with a 60 km/h zone from 900 to 1300 m;
stop mark at 2150 m; schedule 135 s, 9.6 % above the minimum-time run) under
models.ato.controller.AtoController, one communication step of 0.1 s at a time. Per case and variant,
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
concurrent.futures over --workers (2 by default).
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


def run_one(case: str, variant: str, seed: int) -> dict:
    """One closed-loop run; the metrics of the module docstring."""
    from fmu_src.adapter import chain_config
    from models.compiled import open_chain
    overrides, wind = CASES[case]
    values = railcar_values(seed, overrides)
    chain = open_chain(chain_config(values), SPAN.grade)
    ctrl = AtoController(SPAN, CAR, VARIANTS[variant])
    truth = VehicleParams(mass=values["car.mass"], A0=values["car.A0"],
                          adhesion_factor=values["car.adhesion_factor"])
    out = chain.outputs()
    t, k = 0.0, 0
    margin = math.inf
    w_f = w_r = 0.0
    t_stop = t_last = None
    interventions = 0
    while k < 4000:
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


def _batch(args):
    # the controller logs each fallback and supervision event (thousands over a study) to
    # stderr; the table counts the interventions, so its log is left out here
    logging.getLogger("models.ato").setLevel(logging.ERROR)
    case, variant, seeds = args
    return [run_one(case, variant, s) for s in seeds]


def references(cases=tuple(CASES)):
    """Energy [kWh] of the manual driver and of the maximum-principle plan on each case's true
    car (the planners of models/planning/trajectory.py, 5 m steps)."""
    from models.planning.trajectory import manual_driver, synthesize
    out = {}
    for case in cases:
        overrides, wind = CASES[case]
        key = (overrides.get("car.mass"), overrides.get("car.A0"),
               overrides.get("car.adhesion_factor"), wind)
        if key not in out:
            car = true_car(overrides, wind)
            out[key] = (manual_driver(SPAN, car).energy_kwh, synthesize(SPAN, car).energy_kwh)
        out[case] = out[key]
    return {c: out[c] for c in cases}


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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100, help="seeds per case and variant")
    ap.add_argument("--workers", type=int, default=2, help="processes")
    ap.add_argument("--case", action="append", choices=list(CASES), metavar="NAME",
                    help="run only this case (repeatable; default: all): " + ", ".join(CASES))
    args = ap.parse_args(argv)
    cases = args.case or list(CASES)
    t0 = time.perf_counter()
    seeds = list(range(1, args.seeds + 1))
    chunk = max(1, len(seeds) // 4)
    jobs = [(c, v, seeds[i:i + chunk]) for c in cases for v in VARIANTS
            for i in range(0, len(seeds), chunk)]
    results = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        refs_future = pool.submit(references, tuple(cases))
        for batch in pool.map(_batch, jobs):
            results.extend(batch)
        refs = refs_future.result()
    print(__doc__.split("\n\n")[0].strip())
    print(f"\nspan: {SPAN.stop:g} m, schedule {SPAN.schedule:g} s; {args.seeds} seeds per row; "
          f"step {STEP} s\n")
    print(table(results, refs))
    ms = np.concatenate([r["replan_ms"] for r in results if r["replans"]])
    print(f"re-plan wall time: median {np.median(ms):.1f} ms, 99th percentile "
          f"{np.percentile(ms, 99):.1f} ms, max {np.max(ms):.1f} ms over {len(ms)} re-plans "
          f"(one every {VARIANTS['identified + re-plan'].replan_period:g} s); manual-driver "
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
