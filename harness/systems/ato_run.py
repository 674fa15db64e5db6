"""The ATO metrics of a system run (harness.metrics.ato) when the system holds an AtoController.

``python -m harness system run`` prints them after the last values: arrival error against the
schedule, stop error, energy, speed-limit margin and interventions, the numbers
``python -m harness run`` prints for a span scenario, from the same functions
(harness.metrics.ato.span_metrics), over the same inputs:

- the truth: the car's car.speed and car.position (the component the ATO's
  traction_force_demand drives), the true car of its parameters (fmu_src.adapter.chain_config,
  with car.total_mass at departure when recorded, as the harness takes it);
- the spans, the configured car and the tuning as the AtoController FMU builds them from its
  parameters (fmu_src.ato_controller.open_line: span.* and a line's line.profile, the profiles
  read from the package);
- the demands the car applied from each row on: in the Jacobi scheme the ATO's outputs recorded
  at row r are the car's inputs over [t_r, t_r+1] (the master's module text); when the ATO steps
  before the car (a step order), those recorded at row r + 1;
- a span's rows (ato.span, as applied): from its first call (the departure; the first span's
  at the start time) to its first holding brake (ato.mode 8: the controller's standstill
  decision), the rest of its rows being the dwell, as harness.metrics.ato.ato_metrics takes the
  AtoDriver's calls; arrived: that row holds the stop with the car at rest, the harness's rule.
"""
from __future__ import annotations

import tempfile
from dataclasses import replace

import numpy as np

from harness.systems.ssp import LoadedSystem, SspError, split_name

__all__ = ["find_ato", "metric_outputs", "system_ato_metrics"]

ATO_MODEL = "AtoController"


def find_ato(system: LoadedSystem) -> tuple[str, str] | None:
    """(ATO component, car component) of a system, or None if it has no AtoController whose
    traction demand drives a car (a component with car.speed and car.position outputs)."""
    for c in system.spec.components:
        if system.models[c.name].modelName != ATO_MODEL:
            continue
        for conn in system.spec.connections:
            if conn.start == f"{c.name}.traction_force_demand":
                car = split_name(conn.end)[0]
                names = {v.name for v in system.models[car].modelVariables if v.causality == "output"}
                if {"car.speed", "car.position"} <= names:
                    return c.name, car
    return None


def metric_outputs(system: LoadedSystem) -> list[str]:
    """The outputs the metrics read ([] if the system has no ATO driving a car)."""
    found = find_ato(system)
    if found is None:
        return []
    ato, car = found
    names = [f"{car}.car.speed", f"{car}.car.position", f"{ato}.traction_force_demand",
             f"{ato}.brake_force_demand", f"{ato}.ato.mode"]
    if any(v.name == "ato.span" for v in system.models[ato].modelVariables):
        names.append(f"{ato}.ato.span")
    if any(v.name == "car.total_mass" for v in system.models[car].modelVariables):
        names.append(f"{car}.car.total_mass")
    return names


def _values(system: LoadedSystem, component: str, model: str, folder: str) -> dict:
    """Every parameter of ``component`` (the FMU's start values, the system's on top), the packed
    profiles unpacked below ``folder``."""
    from fmu_src.variables import variables_for
    from harness.systems.ssp_read import unpack_files
    unpacked = unpack_files(system, folder)
    comp = next(c for c in unpacked.spec.components if c.name == component)
    values = {v.name: v.start for v in variables_for(model) if v.causality in ("parameter", "input")}
    values.update(comp.parameters)
    return values


def system_ato_metrics(system: LoadedSystem, result) -> list:
    """[harness.metrics.ato.SpanMetrics] of the system's spans (one, or a line's), from a run
    (``result``: a harness.systems.master.Result holding ``metric_outputs``). SspError if the
    system has no ATO driving a car or the FMUs' parameters cannot be read."""
    from fmu_src.adapter import ParameterError, chain_config
    from fmu_src.ato_controller import open_line
    from fmu_src.variables import ATO, RAILCAR
    from harness.metrics.ato import span_metrics
    from models.ato.interface import AtoMode
    found = find_ato(system)
    if found is None:
        raise SspError(f"{system.path}: no AtoController driving a car: no ATO metrics")
    ato_name, car_name = found
    missing = [n for n in metric_outputs(system) if n not in result.signals]
    if missing:
        raise SspError(f"{system.path}: the run did not record {', '.join(missing)}")
    with tempfile.TemporaryDirectory(prefix="railcar-ssp-metrics-") as folder:
        try:
            line = open_line(_values(system, ato_name, ATO, folder), None)
            vehicle = chain_config(_values(system, car_name, RAILCAR, folder)).vehicle
        except (ParameterError, ValueError) as e:
            raise SspError(f"{system.path}: the ATO metrics need the FMUs' parameters: {e}") from None
    sig = {n.split(".", 1)[1]: np.asarray(result.signals[n]) for n in metric_outputs(system)}
    order = system.spec.step_order
    ahead = bool(order) and order.index(ato_name) < order.index(car_name)

    def applied(recorded):           # the value applied from each row on (the module's text)
        return np.append(recorded[1:], recorded[-1]) if ahead else recorded
    speed, modes = sig["car.speed"], [int(m) for m in applied(sig["ato.mode"])]
    spans = applied(sig["ato.span"]) if "ato.span" in sig else np.ones(len(result.time))
    out = []
    for k, ls in enumerate(line.spans):
        rows = np.flatnonzero(spans == k + 1)
        if rows.size == 0:
            break
        j0 = int(rows[0])                # the departure (the first span: the start time)
        held = [int(j) for j in rows if j > j0 and modes[j] == int(AtoMode.HOLD)]
        j1 = held[0] if held else int(rows[-1])
        truth = vehicle if "car.total_mass" not in sig else replace(
            vehicle, mass=float(sig["car.total_mass"][j0]))
        arrived = modes[j1] == int(AtoMode.HOLD) and float(speed[j1]) == 0.0
        out.append(span_metrics(k, ls.span, range(j0, j1 + 1), result.time, speed,
                                sig["car.position"], applied(sig["traction_force_demand"]),
                                applied(sig["brake_force_demand"]), truth, line.controllers[0].car,
                                float(result.time[j0]), modes[j0:j1 + 1], arrived,
                                system.spec.step))
    return out
