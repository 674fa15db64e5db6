"""The one closed loop that runs a scenario, on the RailCar FMU or on a models chain.

``drive`` advances one communication step of ``scenario.step_s`` [s] at a time: a driver
(harness.run.phases: Driver, PhaseDriver, TimeTable; harness.run.span_scenario.AtoDriver) turns
the outputs after the previous step into demands, a stepper advances with them, the scenario's
wind and the payload boarded so far held over the step. FmuRunner.run (the RailCar FMU,
harness.run.runner.FmuStepper) and run_on_chain (a models chain, ChainStepper) both run it, so
phases, time tables, wind, payload, stop_after_last_phase and the step count exist once; the
trace becomes a RunResult (harness.run.result) with the driver's records.

Imports go one way: driver -> scenario -> span_scenario -> phases (and result); the driver
protocols and phase drivers live in harness.run.phases, RunResult in harness.run.result.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from harness.run.phases import INPUTS, Driver, Stepper
from harness.run.result import RunResult
from harness.run.scenario import Scenario


@dataclass
class Trace:
    """What ``drive`` saw: the outputs at t = 0 and after every step, and each step's inputs
    (INPUTS order); ``finished``: the run ended early because the driver had finished."""
    outputs: list[Mapping[str, float]]
    inputs: list[list[float]]
    finished: bool = False
    driver: object = field(default=None, repr=False)

    def result(self, scenario: Scenario, names: Sequence[str] | None = None, **extra) -> RunResult:
        """A RunResult of the outputs ``names`` (default: all the stepper gave) at k * step_s [s];
        the last step's inputs are repeated on the last row (held), and the driver's records
        (its ``steps`` and ``log_lines``, if it has them) go with it. ``extra``: RunResult's
        units, log, fmu."""
        rows = self.outputs
        names = list(rows[0]) if names is None else names
        h = scenario.step_s
        u = np.array(self.inputs + self.inputs[-1:] if self.inputs else [[0.0] * len(INPUTS)])
        u = u.reshape(-1, len(INPUTS))
        return RunResult(scenario, np.array([k * h for k in range(len(rows))]),
                         {n: np.array([r[n] for r in rows]) for n in names}, extra.pop("units", {}),
                         inputs={n: u[:, j] for j, n in enumerate(INPUTS)},
                         driver_steps=_steps(self.driver),
                         driver_log=list(getattr(self.driver, "log_lines", ())), **extra)


def _steps(driver) -> tuple | None:
    steps = getattr(driver, "steps", None)
    return None if steps is None else tuple(steps)


def drive(stepper: Stepper, scenario: Scenario, driver: Driver | None = None,
          max_steps: int | None = None,
          until: Callable[[Mapping[str, float]], bool] | None = None) -> Trace:
    """Run ``scenario`` on ``stepper`` in a closed loop with ``driver`` (default: the scenario's
    own, ``scenario.new_driver()``) for duration_s / step_s steps (at most ``max_steps``). At
    t_k = k * step_s the driver gets the outputs after the last step; its demands, the
    scenario's wind at t_k and the payload boarded so far [t] are held over [t_k, t_k+1]. The
    run ends early when the driver has finished and the scenario says stop_after_last_phase, or
    when ``until(outputs)`` is true after a step."""
    driver = scenario.new_driver() if driver is None else driver
    h = scenario.step_s
    steps = int(round(scenario.duration_s / h))
    out = stepper.outputs()
    trace = Trace([out], [], driver=driver)
    payload = 0.0
    for k in range(steps if max_steps is None else min(steps, max_steps)):
        t = k * h
        d = driver.demands(t, out)
        payload += getattr(d, "payload_change_t", 0.0)
        if driver.finished and scenario.stop_after_last_phase:
            trace.finished = True
            break
        u = [d.traction, d.brake, scenario.wind_at(t), payload]
        trace.inputs.append(u)
        stepper.do_step(t, h, u)
        out = stepper.outputs()
        trace.outputs.append(out)
        if until is not None and until(out):
            break
    return trace


class ChainStepper:
    """A models chain (models.chain.RailCarChain, models.compiled.CompiledChain: no FMI) as a
    Stepper; its outputs are all of the chain's, in its order."""

    def __init__(self, chain):
        self.chain = chain

    def outputs(self) -> Mapping[str, float]:
        return self.chain.outputs()

    def do_step(self, t: float, h: float, inputs: Sequence[float]) -> None:
        self.chain.do_step(t, h, *inputs)


def run_on_chain(scenario: Scenario, overrides: dict | None = None,
                 driver: Driver | None = None) -> RunResult:
    """The scenario on a models chain built as the RailCar FMU builds it (Scenario.chain_setup:
    its parameters with ``overrides`` by FMU name, e.g. {"est.method": 2, "seed": 5}), run by
    ``chain_result``. Raises ValueError, naming the parameter, if the configuration rejects one."""
    return chain_result(scenario.chain_setup(overrides).open(), scenario, driver)


def chain_result(chain, scenario: Scenario, driver: Driver | None = None) -> RunResult:
    """Drive a models chain through the scenario (``drive``) and return a RunResult of all its
    outputs with each step's inputs (INPUTS), as FmuRunner.run's would be."""
    return drive(ChainStepper(chain), scenario, driver).result(scenario)


def drive_chain(chain, scenario: Scenario, max_steps: int | None = None,
                demands: list | None = None) -> list[dict]:
    """``chain.outputs()`` at t = 0 and after every step of the scenario's own driver (at most
    ``max_steps`` steps); ``demands``, when given, receives each step's inputs as a tuple in
    INPUTS order: traction and brake demand [N], wind [m/s], payload [t]."""
    trace = drive(ChainStepper(chain), scenario, max_steps=max_steps)
    if demands is not None:
        demands.extend(tuple(u) for u in trace.inputs)
    return trace.outputs
