"""How well the ATO drove a span: arrival, stop, energy, speed-limit margin, safety (no I/O).

Per span, from the truth the plant recorded (car.speed, car.position) and the demands the
loop applied (result.inputs), with the ATO's calls (harness.run.span_scenario.AtoStep):

  arrival error [s]     the true standstill at the stop (the last time in the span the car comes
                        to rest, interpolated in the step as a constant deceleration) minus the
                        departure (the span controller's first call) minus the schedule
  stop error [m]        true car.position at rest minus the stop mark (> 0: past the mark)
  energy [kWh]          traction work / eta_f - eta x regenerated work (docs/model.md section 9),
                        from the true speeds and the demands as the plant applies them
                        (``step_work``); regen is the configured car's characteristic
  speed-limit margin [m/s]  min over the span of V_lim(s) - V, true speed and position (> 0:
                        never over the limit)
  interventions [steps] calls that gave the safe brake or the supervisor's full brake

studies/ato_closed_loop.py uses ``step_work``, ``energy_kwh``, ``standstill_time`` and
``INTERVENTIONS`` from here: one copy of each.

Before a run, ``span_info`` says per span what the ATO's planner can do for the configured car
(``python -m harness span-info``): the fastest run it plans (the schedule it accepts must be no
shorter), the schedule's margin over it, and the energy of that minimum-time run and of the
schedule's own plan (the planner's works with the same rule as ``energy_kwh``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from models.ato.interface import AtoMode
from models.plant.dynamics import VehicleParams, brake_force_limit, traction_force_limit
from models.planning.span import CarTraction, Span

INTERVENTIONS = (int(AtoMode.SAFE), int(AtoMode.OVERSPEED))
"""Modes that are safety interventions: the safe brake (bad input) and the supervisor's brake."""

J_PER_KWH = 3.6e6
ARRIVAL_BOUND_S = 2.5  # [s] the ATO's target |arrival error| (Meleshin 2011, Sidorenko 1997)
STOP_BOUND_M = 0.3     # [m] the ATO's target |stop error| (Sidorenko 1997)


def step_work(v0: float, v1: float, s0: float, s1: float, traction: float, brake: float,
              truth: VehicleParams, car: CarTraction) -> tuple[float, float]:
    """(traction work [J], regenerated work [J]) of one step from speed v0 to v1 [m/s] and
    position s0 to s1 [m] with the demands [N] held: the demand clipped to the true car's limit
    at the mean speed (what the plant applies), times the distance; of a brake demand the part
    the configured regenerative characteristic ``car.r_max`` takes. A position that restarts
    (s1 < s0: a departure after a station stop) counts s1 as the distance covered."""
    vm = 0.5 * (v0 + v1)
    ds = s1 - s0 if s1 >= s0 else s1
    if brake > 0.0:
        b = min(brake, brake_force_limit(vm, truth))
        return 0.0, min(b, car.r_max(vm)) * ds
    return min(traction, traction_force_limit(vm, truth)) * ds, 0.0


def energy_kwh(traction_work: float, regen_work: float, car: CarTraction) -> float:
    """Energy from the network [kWh]: traction work [J] / eta_f - eta x regenerated work [J]."""
    return (traction_work / car.eta_f - car.eta * regen_work) / J_PER_KWH


def standstill_time(t0: float, h: float, v0: float, ds: float) -> float:
    """When the car came to rest [s] in a step [t0, t0 + h] that started at v0 [m/s] and covered
    ds [m]: a constant deceleration covers ds = v0 tau / 2, so tau = 2 ds / v0 (at most h)."""
    return t0 + min(h, 2.0 * ds / v0) if v0 > 0.0 else t0


@dataclass(frozen=True)
class SpanMetrics:
    span: int                   # 0-based
    schedule_s: float           # [s]
    departure_s: float          # [s] the span controller's first call
    arrival_s: float            # [s] true standstill at the stop (nan: never came to rest)
    arrival_error_s: float      # [s] arrival - departure - schedule
    stop_m: float               # [m] the stop mark
    stop_error_m: float         # [m] true position at rest - stop mark
    energy_kwh: float           # [kWh]
    margin_mps: float           # [m/s] min V_lim(s) - V
    interventions: int          # [steps]
    arrived: bool               # the controller declared the stop and the car stands

    @property
    def on_target(self) -> bool:
        """Arrived, within +-ARRIVAL_BOUND_S of the schedule and +-STOP_BOUND_M of the mark."""
        return (self.arrived and abs(self.arrival_error_s) <= ARRIVAL_BOUND_S
                and abs(self.stop_error_m) <= STOP_BOUND_M)


def span_metrics(k: int, span: Span, rows: range, time, speed, position, traction, brake,
                 truth: VehicleParams, car: CarTraction, departure: float, modes, arrived: bool,
                 h: float) -> SpanMetrics:
    """The metrics of span ``k`` over ``rows`` (result rows from its departure to its last call)
    of the arrays time [s], speed [m/s], position [m] (truth) and the demands [N] applied from
    each row on; ``modes``: the ATO's mode at each of those rows."""
    j0, j1 = rows.start, rows.stop - 1          # departure row, last row of the span
    w_f = w_r = 0.0
    margin = math.inf
    t_rest = math.nan
    for j in range(j0, j1):
        v0, v1, s0, s1 = float(speed[j]), float(speed[j + 1]), float(position[j]), float(position[j + 1])
        f, r = step_work(v0, v1, s0, s1, float(traction[j]), float(brake[j]), truth, car)
        w_f += f
        w_r += r
        margin = min(margin, span.v_lim(s1) - v1)
        if v0 > 0.0 and v1 == 0.0:
            t_rest = standstill_time(float(time[j]), h, v0, s1 - s0 if s1 >= s0 else s1)
    return SpanMetrics(
        span=k, schedule_s=span.schedule, departure_s=departure, arrival_s=t_rest,
        arrival_error_s=t_rest - departure - span.schedule, stop_m=span.stop,
        stop_error_m=float(position[j1]) - span.stop, energy_kwh=energy_kwh(w_f, w_r, car),
        margin_mps=margin, interventions=sum(1 for m in modes if m in INTERVENTIONS),
        arrived=arrived)


def ato_metrics(scenario, result, steps) -> list[SpanMetrics]:
    """Every span's metrics for a run of a span scenario (``result``, a harness RunResult) and
    the ATO's calls ``steps`` (AtoDriver.steps of the run, or harness.run.span_scenario.replay_steps);
    the call at row j saw the outputs of row j and its demands held to row j + 1."""
    setup = scenario.ato_setup()
    vehicle = scenario.chain_setup().config.vehicle
    time, v, x = result.time, result["car.speed"], result["car.position"]
    total = result.signals.get("car.total_mass")
    traction, brake = result.inputs["traction_force_demand"], result.inputs["brake_force_demand"]
    n = min(len(steps), len(time))
    out = []
    for k, ls in enumerate(setup.spans):
        idx = [j for j in range(n) if steps[j].span == k and not steps[j].dwell]
        if not idx:
            break
        j0, j1 = idx[0], idx[-1]
        # the car the plant runs now (passengers boarded so far)
        truth = vehicle if total is None else replace(vehicle, mass=float(total[j0]))
        last = steps[j1]
        arrived = (last.command.mode == int(AtoMode.HOLD) and float(v[j1]) == 0.0)
        out.append(span_metrics(k, ls.span, range(j0, j1 + 1), time, v, x, traction, brake, truth,
                                setup.car, steps[j0].t, [steps[j].command.mode for j in idx],
                                arrived, scenario.step_s))
    return out


HEADER = ("span", "schedule [s]", "arrival err [s]", "stop err [m]", "energy [kWh]",
          "V_lim margin [m/s]", "interventions [steps]", "arrived")


def rows_text(metrics: list[SpanMetrics]) -> list[tuple[str, ...]]:
    return [(str(m.span + 1), f"{m.schedule_s:.1f}", f"{m.arrival_error_s:+.2f}",
             f"{m.stop_error_m:+.3f}", f"{m.energy_kwh:.3f}", f"{m.margin_mps:.3f}",
             str(m.interventions), "yes" if m.arrived else "NO") for m in metrics]


def format_ato(metrics: list[SpanMetrics]) -> str:
    """A fixed-width table, one line per span (units in the header)."""
    body = rows_text(metrics)
    widths = [max(len(h), *(len(b[j]) for b in body)) if body else len(h)
              for j, h in enumerate(HEADER)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(HEADER, widths))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(b, widths)) for b in body]
    if len(metrics) > 1:
        e = sum(m.energy_kwh for m in metrics)
        lines.append(f"line: energy {e:.3f} kWh, worst |arrival err| "
                     f"{max(abs(m.arrival_error_s) for m in metrics):.2f} s, worst |stop err| "
                     f"{max(abs(m.stop_error_m) for m in metrics):.3f} m")
    return "\n".join(lines)


def markdown_ato(metrics: list[SpanMetrics]) -> list[str]:
    """The same table in markdown."""
    return (["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)] +
            ["| " + " | ".join(b) + " |" for b in rows_text(metrics)])


# ------------------------------------------------------------------------------ before a run

@dataclass(frozen=True)
class SpanInfo:
    """What the ATO's planner makes of one span for the configured car, before any run."""
    span: int                          # 0-based
    stop_m: float                      # [m] the stop mark
    schedule_s: float                  # [s]
    fastest_s: float                   # [s] the planner's minimum-time run (limits less limit_margin)
    margin_pct: float                  # [%] schedule / fastest - 1 (< 0: infeasible, refused)
    min_time_energy_kwh: float         # [kWh] of the minimum-time run: traction / eta_f - eta x regen
    min_time_traction_kwh: float       # [kWh] its traction work / eta_f alone
    schedule_energy_kwh: float         # [kWh] of the plan for the schedule (nan: none, infeasible)
    problem: str = ""                  # why the ATO refuses the span ('' : it accepts it)


def span_info(setup) -> list[SpanInfo]:
    """Every span of ``setup`` (harness.run.span_scenario.AtoSetup) as the ATO's planner sees it
    for ``setup.car`` and ``setup.tuning``: the course, planner and planning car are made as
    models.ato.controller.AtoController makes them (a test holds them equal), so that a span
    whose schedule the controller refuses is still described. A span the car cannot run at all
    (a climb it stalls on, a limit its brakes cannot keep) has nan times and its ``problem``."""
    from models.ato.controller import AtoController
    from models.ato.planner import plan_setup
    from models.planning.span import check_span_for_car
    car, tuning = setup.car, setup.tuning
    out = []
    for k, ls in enumerate(setup.spans):
        span = ls.span
        nan = math.nan
        try:
            check_span_for_car(span, car)
            _, planner, plan_car = plan_setup(span, car, tuning)
            qU = planner.envelope(plan_car)
            fastest = planner.min_time(plan_car, qU)
            fast = planner.plan(plan_car, 0.0, 0.0, 0.0, fastest, qU)
        except ValueError as e:
            out.append(SpanInfo(k, span.stop, span.schedule, nan, nan, nan, nan, nan, str(e)))
            continue
        problem, scheduled = "", nan
        try:
            scheduled = AtoController(span, car, tuning).initial_plan.energy_kwh
        except ValueError as e:          # the schedule: too short, too long
            problem = str(e)
        out.append(SpanInfo(k, span.stop, span.schedule, fastest, 100.0 * (span.schedule / fastest - 1.0),
                            fast.energy_kwh, fast.traction_kwh, scheduled, problem))
    return out


INFO_HEADER = ("span", "stop [m]", "schedule [s]", "fastest [s]", "margin [%]", "min-time energy [kWh]",
               "min-time traction [kWh]", "scheduled energy [kWh]")


def format_span_info(infos: list[SpanInfo]) -> str:
    """A fixed-width table, one line per span (units in the header), each refused span's reason
    below it."""
    def num(x: float, fmt: str) -> str:
        return "n/a" if math.isnan(x) else format(x, fmt)
    body = [(str(i.span + 1), f"{i.stop_m:.1f}", f"{i.schedule_s:.1f}", num(i.fastest_s, ".2f"),
             num(i.margin_pct, "+.1f"), num(i.min_time_energy_kwh, ".3f"), num(i.min_time_traction_kwh, ".3f"),
             num(i.schedule_energy_kwh, ".3f")) for i in infos]
    widths = [max(len(h), *(len(b[j]) for b in body)) if body else len(h) for j, h in enumerate(INFO_HEADER)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(INFO_HEADER, widths))]
    for i, b in zip(infos, body):
        lines.append("  ".join(c.rjust(w) for c, w in zip(b, widths)))
        if i.problem:
            lines.append(f"      span {i.span + 1}: the ATO refuses it: {i.problem}")
    return "\n".join(lines)
