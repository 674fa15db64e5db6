"""Scripted scenarios run whole in the C core, many per call (issue 31): the batch engine's
harness side.

``run_batch(scenarios, overrides)`` gives, for each scenario, the RunResult that
harness.run.driver.run_on_chain(scenario, overrides) gives -- the same arrays bit for bit
(tests/harness_tests/run/test_batch_runs.py) -- but the driver, the wind, the payload and the chain
step in C (models.batch, models/core/scenario_driver.c) without returning to Python per step.
Here a Scenario becomes the C driver's script (``script_of``: its phases or time table as
Scenario.new_driver builds them, its wind schedule, step, duration and stop_after_last_phase) and
the C arrays become RunResults. A span scenario (the ATO drives: harness.run.span_scenario's
AtoDriver) becomes a span script (``span_script_of``: its line's spans, configured car and tuning
as Scenario.new_driver builds them) run by models/core/span_driver.c, the C twin of the AtoDriver
in drive(): its RunResult carries the same driver_steps (every AtoStep) and driver_log lines
(tests/harness_tests/run/test_batch_spans.py). A run the C core cannot take (``not_covered``: an
estimator it does not cover, no compiled models._batch, RAILCAR_PURE_PYTHON set; a span run that
logged more lines than the C side keeps) runs on run_on_chain, the Python loop, with the same
result; ``ENGINES`` counts the runs each way.
"""
from __future__ import annotations

import collections
from typing import Sequence

import numpy as np

from models import batch
from models.chain import ChainConfig, StepRejected
from models.ato.interface import AtoCommand
from models.compiled import (INTEGER_OUTPUTS, OUTPUT_NAMES, chain_values, core_not_covered,
                             dataclass_values, enabled, validate)
from models.plant.track import GradeProfile, SpeedProfile

from harness.run.driver import chain_result
from harness.run.phases import ACTIONS, INPUTS, PhaseDriver, TimeTable
from harness.run.result import RunResult
from harness.run.scenario import Scenario
from harness.run.span_scenario import AtoStep

assert batch.ACTIONS == ACTIONS, "models.batch.ACTIONS must list harness.run.phases.ACTIONS in order"
assert batch.OUTPUTS == len(OUTPUT_NAMES), "models.batch.OUTPUTS must count models.compiled.OUTPUT_NAMES"
assert OUTPUT_NAMES[batch.SPAN_STATION_STOPS] == "est.station_stops", \
    "models.batch.SPAN_STATION_STOPS must be est.station_stops' column in models.compiled.OUTPUT_NAMES"

ENGINES: collections.Counter = collections.Counter()
"""Runs made by run_batch per engine: "c" (the batch engine) and "python" (run_on_chain)."""


def script_of(scenario: Scenario) -> np.ndarray:
    """The scenario's driver, wind schedule and run length as the C driver's flat script
    (models.batch.script_values). ValueError naming the scenario for a span scenario."""
    driver = scenario.new_driver()
    common = dict(step_s=scenario.step_s, duration_s=scenario.duration_s,
                  stop_after_last_phase=scenario.stop_after_last_phase,
                  wind=[(w.time_s, w.speed_mps) for w in scenario.wind])
    if isinstance(driver, PhaseDriver):
        phases = [{name: getattr(p, name) for name in batch.PHASE_FIELDS} for p in driver.phases]
        return batch.script_values(mass_t=driver.mass_t, traction_force_max=driver.f_max,
                                   brake_force_max=driver.b_max, phases=phases, **common)
    if isinstance(driver, TimeTable):
        return batch.script_values(mass_t=0.0, traction_force_max=0.0, brake_force_max=0.0,
                                   table=(driver.time_s, driver.traction_N, driver.brake_N), **common)
    raise ValueError(f"{scenario.name}: the batch engine runs scripted scenarios ([[driver]] phases, "
                     f"[driver_table]); this one's driver is {type(driver).__name__}")


def span_script_of(scenario: Scenario) -> np.ndarray:
    """A span scenario's ATO (the AtoDriver Scenario.new_driver builds: scenario.ato_setup()), wind
    schedule and run length as the C span driver's flat script (models.batch.span_script_values).
    ValueError naming the scenario for a scenario that is not a span scenario."""
    setup = scenario.ato_setup()
    if setup is None:
        raise ValueError(f"{scenario.name}: not a span scenario (no [span] or [[span]]): script_of "
                         f"gives its script")
    spans = [dict(length=s.span.length, schedule=s.span.schedule, stop=s.span.stop,
                  dwell_s=s.dwell_s, boarding_t=s.boarding_t,
                  limit_distances=s.span.limit_distances, limit_speeds=s.span.limit_speeds,
                  grade_distances=s.span.grade.distances, grades=s.span.grade.grades)
             for s in setup.spans]
    return batch.span_script_values(step_s=scenario.step_s, duration_s=scenario.duration_s,
                                    stop_after_last_phase=scenario.stop_after_last_phase,
                                    car=dataclass_values(setup.car),
                                    tuning=dataclass_values(setup.tuning), spans=spans,
                                    wind=[(w.time_s, w.speed_mps) for w in scenario.wind])


def not_covered(scenario: Scenario, setup=None) -> str | None:
    """Why the C batch engine does not run this scenario (then run_batch runs it on
    run_on_chain), or None when it does; ``setup``: its chain's (fmu_src.adapter.ChainSetup),
    default the scenario's own."""
    if not batch.available():
        return "the C scenario runner (models._batch) is not compiled"
    if not enabled():
        return "the C core is switched off (RAILCAR_PURE_PYTHON) or not compiled (models._railcar)"
    return core_not_covered((setup or scenario.chain_setup()).config.identifier)


def run_batch(scenarios: Sequence[Scenario], overrides: Sequence[dict | None] | None = None,
              setups: Sequence | None = None) -> list[RunResult]:
    """run_on_chain(scenarios[i], overrides[i]) for every i, the covered ones (``not_covered``) in C in
    one call; each result's ``engine`` says which ran it ("c" or "python": a span run whose ATO
    logged more lines than the C side keeps is run again on run_on_chain). ``overrides``: RailCar
    parameters by FMU name per run (e.g. {"seed": 5}), as run_on_chain takes them: they configure
    the chain, the driver is the scenario's own.
    ``setups``: scenarios[i].chain_setup(overrides[i]) when the caller has them already (their
    profile files are not read again). Raises as run_on_chain: ValueError naming the parameter,
    StepRejected naming the run and the step."""
    overrides = list(overrides) if overrides is not None else [None] * len(scenarios)
    if len(overrides) != len(scenarios):
        raise ValueError(f"overrides: one per scenario ({len(scenarios)}), got {len(overrides)}")
    if setups is None:
        setups = [sc.chain_setup(ov) for sc, ov in zip(scenarios, overrides)]
    elif len(setups) != len(scenarios):
        raise ValueError(f"setups: one per scenario ({len(scenarios)}), got {len(setups)}")
    results: list[RunResult | None] = [None] * len(scenarios)
    todo, runs, span_todo, span_runs = [], [], [], []
    for i, (sc, setup) in enumerate(zip(scenarios, setups)):
        if not_covered(sc, setup) is not None:
            results[i] = _on_python(sc, setup)
            continue
        if sc.ato is not None:
            span_todo.append(i)
            span_runs.append((setup.config, setup.grade, setup.speed, span_script_of(sc)))
        else:
            todo.append(i)
            runs.append((setup.config, setup.grade, setup.speed, script_of(sc)))
    if runs:
        done = run_chains(runs)
        for r, i in enumerate(todo):
            results[i] = result_of(scenarios[i], done, r)
            results[i].engine = "c"
        ENGINES["c"] += len(runs)
    if span_runs:
        done = run_chains(span_runs, spans=True)
        for r, i in enumerate(span_todo):
            if done.log_lines[r] > len(done.log[r]):     # the C side kept only the first lines
                results[i] = _on_python(scenarios[i], setups[i])
                continue
            results[i] = span_result_of(scenarios[i], done, r)
            results[i].engine = "c"
            ENGINES["c"] += 1
    return results


def _on_python(scenario: Scenario, setup) -> RunResult:
    """run_on_chain of ``scenario`` on its chain ``setup`` (made once), counted and labelled."""
    result = chain_result(setup.open(), scenario)
    result.engine = "python"
    ENGINES["python"] += 1
    return result


def chain_arrays(cfg: ChainConfig, grade: GradeProfile, speed: SpeedProfile | None) -> tuple:
    """The C chain's flat configuration and profiles, as models.compiled.CompiledChain hands them
    to the core. ValueError naming the setting if the configuration is invalid or the C core does
    not cover it."""
    cfg = validate(cfg, speed, 0.0)
    why = core_not_covered(cfg.identifier)
    if why:
        raise ValueError(f"the C core does not cover {why}")
    config = np.array(chain_values(cfg, 0.0), dtype=float)
    sd, sv = (speed.distances, speed.speeds) if speed is not None else ((), ())
    return tuple(np.ascontiguousarray(a, dtype=float)
                 for a in (config, grade.distances, grade.grades, sd, sv))


def run_chains(runs: Sequence[tuple[ChainConfig, GradeProfile, SpeedProfile | None, np.ndarray]],
               spans: bool = False) -> batch.BatchRuns:
    """Each run (chain configuration, grade profile, speed profile or None, script) whole in C
    (models.batch.run_scripts; ``spans``: span scripts, models.batch.run_spans), on a fresh chain
    each. ValueError naming the run and the setting before any run starts (a line the ATO
    refuses: when its run starts); StepRejected naming the run and the step."""
    flat = []
    for r, (cfg, grade, speed, script) in enumerate(runs):
        try:
            flat.append((*chain_arrays(cfg, grade, speed), script))
        except ValueError as e:
            raise ValueError(f"run {r}: {e}") from None
    return batch.run_spans(flat, StepRejected) if spans else batch.run_scripts(flat, StepRejected)


TRANSPOSE_ROWS = 512
"""Rows per block of ``_columns``' transposition: a block (512 x 34 doubles, 139 kB) stays in the
cache while it is turned; the whole run at once (2.4 MB for 9000 steps) does not."""


def _columns(rows: np.ndarray) -> np.ndarray:
    """``rows`` (steps x outputs) transposed into a new C-ordered array (outputs x steps), a block of
    TRANSPOSE_ROWS rows at a time: the same values as ``rows.T.copy()``, ~1/3 less time for a
    station_day run (0.3 vs 0.45 ms, measured), a run's largest cost after the engine's own."""
    out = np.empty((rows.shape[1], rows.shape[0]))
    for first in range(0, rows.shape[0], TRANSPOSE_ROWS):
        out[:, first:first + TRANSPOSE_ROWS] = rows[first:first + TRANSPOSE_ROWS].T
    return out


def result_of(scenario: Scenario, done: batch.BatchRuns, r: int) -> RunResult:
    """Run ``r`` of ``done`` as drive()'s Trace.result makes it: its own copies of the rows
    written, the integer outputs as integers, the last step's inputs repeated on the last row."""
    rows = int(done.rows[r])
    columns = _columns(done.outputs[r, :rows])
    signals = {name: (columns[j].astype(np.int64) if name in INTEGER_OUTPUTS else columns[j])
               for j, name in enumerate(OUTPUT_NAMES)}
    u = done.inputs[r, :rows - 1]
    held = np.zeros((len(INPUTS), max(rows, 1)))         # one column per input, the last step's repeated
    if len(u):
        held[:, :len(u)] = u.T
        held[:, len(u):] = u[-1][:, None]
    h = scenario.step_s
    return RunResult(scenario, np.arange(rows) * h, signals, {},
                     inputs={n: held[j] for j, n in enumerate(INPUTS)},
                     driver_steps=None, driver_log=[])


def span_result_of(scenario: Scenario, done: batch.SpanRuns, r: int) -> RunResult:
    """Span run ``r`` of ``done`` as ``result_of`` makes it, with the AtoDriver's records: every
    call as an AtoStep (driver_steps) and its log lines headed by the scenario's name (driver_log)."""
    result = result_of(scenario, done, r)
    steps = []
    for t, span, traction, brake, mode, planned, stage, dwell, payload in \
            done.steps[r, :int(done.calls[r])].tolist():
        steps.append(AtoStep(t, int(span), AtoCommand(traction, brake, int(mode), planned, int(stage)),
                             dwell=bool(dwell), payload_change=payload))
    result.driver_steps = tuple(steps)
    result.driver_log = [f"{scenario.name or 'ATO'}: {line}" for line in done.log[r]]
    return result
