"""RunResult: what one run of a scenario gives, for the metrics and the reports to read.

A result carries the scenario it ran (``scenario``: resolved once when loaded, its car, profiles
and ATO in ``scenario.setup``), the recorded outputs over time, the inputs the loop held over
each step, the FMU's log, and what the driver recorded (a span scenario's ATO calls and the
ATO's log lines). Nothing a consumer needs has to be rebuilt or re-simulated from it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from harness.run.scenario import Scenario, ScenarioSetup


INPUT_UNITS = {"traction_force_demand": "N", "brake_force_demand": "N", "wind_speed": "m/s",
               "car.payload": "t"}
"""The unit of each of the loop's inputs (harness.run.phases.INPUTS: the demands applied, the wind
(headwind > 0), the passengers boarded so far)."""


@dataclass
class RunResult:
    """Recorded outputs of one run: ``signals[name]`` is an array over ``time`` [s].

    ``inputs``: the loop's inputs (harness.run.phases.INPUTS) held over [t_k, t_k+1];
    ``driver_steps``: the ATO's calls row by row (harness.run.span_scenario.AtoStep) of a span
    scenario, else None; ``driver_log``: the driver's log lines, each starting with the
    scenario's name (the ATO's "estimates not usable", ...), kept here instead of printed."""
    scenario: Scenario
    time: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str]
    log: list[str] = field(default_factory=list)
    inputs: dict[str, np.ndarray] = field(default_factory=dict)   # held over [t_k, t_k+1]
    fmu: str = ""                  # which FMU ran: "native" or "python" (FmuRunner.kind); "" no FMU
    engine: str = ""               # run_batch's loop: "c" its C engine, "python" run_on_chain; "" not run_batch
    driver_steps: tuple | None = None
    driver_log: list[str] = field(default_factory=list)

    @property
    def setup(self) -> ScenarioSetup:
        """The scenario as resolved once at loading: every parameter, the chain's configuration
        and profiles, the ATO (harness.run.scenario.ScenarioSetup)."""
        return self.scenario.setup

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        return self.signals[name]
