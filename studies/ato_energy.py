"""Energy of the planners on four spans (issue 20, the pure part; a study, not a test).

    python studies/ato_energy.py

For each span: the minimum-time run, the schedule, and the energy [kWh] (traction / eta_f minus
eta times regenerated energy) of

  manual   the minimum-time run up to a coast point, then coasting and the braking curve
           (issue 20's reference: "flat-out then coast/brake, what a manual driver does")
  MP       Meleshin's (2011) maximum-principle plan (models.planning.trajectory.synthesize)
  DP       Sidorenko's (1997) DP, K = 2 traction applications, 25 m stages, 121 speeds
  BF       the brute-force optimum: DP over speed only, every 5 m, 6 controls, 201 and 401
           speeds (two grid sizes show how far the discretised optimum is from converged)

with the saving of MP (and DP) against the manual driver and the gaps to the finer BF. The car
is models.planning.span.CarTraction's default (the RailCar FMU's 30 t car, 40 kN / 400 kW drive,
eta_f = 0.9, eta = 0.6). Every plan meets the schedule within 0.01 s. Deterministic; ~1 min
of CPU on one core.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from models.planning.span import CarTraction, Span  # noqa: E402
from models.plant.track import GradeProfile  # noqa: E402
from models.planning.trajectory import brute_force, dp_plan, manual_driver, min_time_run, synthesize  # noqa: E402
from models.units import kmh_to_mps  # noqa: E402

CAR = CarTraction()
V80, V60 = kmh_to_mps(80.0), kmh_to_mps(60.0)

SPANS = (
    ("flat 1.5 km", Span(1500.0, 95.0, limit_speeds=(V80,))),
    ("hump 1.8 km (+-30 permille)", Span(1800.0, 110.0, limit_speeds=(V80,), grade=GradeProfile(
        (0.0, 400.0, 900.0, 1400.0), (0.0, 30.0, -30.0, 0.0)))),
    ("60 km/h zone 2.0 km", Span(2000.0, 121.0, limit_distances=(0.0, 800.0, 1100.0),
                                 limit_speeds=(V80, V60, V80))),
    ("60 km/h zone 2.0 km", Span(2000.0, 127.0, limit_distances=(0.0, 800.0, 1100.0),
                                 limit_speeds=(V80, V60, V80))),
    # a loose schedule on a longer zone span: here the optimum coasts into the zone and powers
    # at its end, a structure the maximum-principle synthesis does not build (its largest gap)
    ("60 km/h zone 2.5 km", Span(2500.0, 167.0, limit_distances=(0.0, 1000.0, 1400.0),
                                 limit_speeds=(V80, V60, V80))),
)


def rows():
    for name, span in SPANS:
        plans = {}
        seconds = {}
        for key, fun in (("manual", manual_driver), ("MP", synthesize), ("DP", dp_plan),
                         ("BF201", lambda s, c: brute_force(s, c, n_speeds=201)),
                         ("BF401", lambda s, c: brute_force(s, c, n_speeds=401))):
            t0 = time.perf_counter()
            plans[key] = fun(span, CAR)
            seconds[key] = time.perf_counter() - t0
        yield name, span, min_time_run(span, CAR), plans, seconds


def pct(a, b):
    return 100.0 * (a / b - 1.0)


def main():
    print(__doc__.split("\n\n")[0].strip())
    print()
    head = (f"{'span':28s} {'T_min':>6s} {'sched':>6s} | {'manual':>7s} {'MP':>7s} {'DP':>7s} "
            f"{'BF201':>7s} {'BF401':>7s} kWh | {'MP sav':>6s} {'DP sav':>6s} | {'MP-BF':>6s} "
            f"{'DP-BF':>6s} {'BF201-401':>9s} % | tract. man/MP/DP")
    print(head)
    print("-" * len(head))
    timing = []
    for name, span, fast, p, sec in rows():
        e = {k: v.energy_kwh for k, v in p.items()}
        worst = max(abs(v.running_time_s - span.schedule) for v in p.values())
        assert worst <= 0.01, (name, worst)
        print(f"{name:28s} {fast.running_time_s:6.1f} {span.schedule:6.1f} | {e['manual']:7.4f} "
              f"{e['MP']:7.4f} {e['DP']:7.4f} {e['BF201']:7.4f} {e['BF401']:7.4f}     | "
              f"{-pct(e['MP'], e['manual']):6.2f} {-pct(e['DP'], e['manual']):6.2f} | "
              f"{pct(e['MP'], e['BF401']):6.2f} {pct(e['DP'], e['BF401']):6.2f} "
              f"{pct(e['BF201'], e['BF401']):9.2f}   | {p['manual'].traction_applications}/"
              f"{p['MP'].traction_applications}/{p['DP'].traction_applications}")
        timing.append((name, sec))
    print()
    print("sav = saving against the manual driver; X-BF = gap to the 401-speed brute force "
          "(negative: X is below it, the brute force being a discretised upper bound).")
    print("planner wall time [s]: " + "; ".join(
        f"{n[:12]}: " + " ".join(f"{k} {v:.1f}" for k, v in s.items()) for n, s in timing))


if __name__ == "__main__":
    main()
