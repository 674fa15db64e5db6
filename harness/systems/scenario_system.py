"""A span scenario (harness/run/span_scenario.py) as an FMU system: RailCar <-> AtoController.

``system_from_scenario`` turns a scenario with one ``[span]`` or a line of ``[[span]]`` into the SystemSpec that
``python -m harness system build SCENARIO.toml OUT.ssp`` writes, nothing repeated by hand:

- the car (RailCar: the native FMU when the C core covers the scenario's parameters, as
  ``python -m harness run`` chooses, harness.run.fmus.choose) with every ``[parameters]`` value of
  the scenario: the true car, the estimator's prior (est.*), the seed, the track;
- the AtoController, chosen by the same ``--fmu`` (``choose_ato``): ``auto`` the native
  AtoControllerNative.fmu when harness.run.fmus.uncovered says it runs the parameters the system
  gives it (one span, today), else the pythonfmu AtoController.fmu; ``native`` refuses at build,
  with the reason, what the native FMU does not run; ``python`` the pythonfmu FMU. With ``fmi=3``
  (``--fmi 3``) both are the FMI 3.0 natives (RailCarNative3.fmu, AtoControllerNative3.fmu), refused
  at build when missing or when the parameters need the pythonfmu FMU (there is no FMI 3 one).
  Both FMUs of a model have the same variable table (fmu_src.variables), so the parameters below
  are the same whichever runs; ``ScenarioSystem.choice_lines`` says which was chosen and why;
- the AtoController with the span (span.stop, span.length, span.schedule), the configured car
  (every CarTraction field of ``[ato.car]`` as car.<field>) and the tuning (every AtoTuning field
  of ``[ato]`` as ato.<field>), each written out, defaults too, so the FMU's own defaults do not
  decide them;
- the speed limits as a CSV ``distance_m,speed_limit_mps`` made at build (limit_kmh converted to
  m/s as the harness converts them, models.units.kmh_to_mps; written with repr, so the FMU reads
  back the same doubles), packed into the .ssp;
- every profile (track.grade_profile, track.speed_profile; the ATO's span.grade_profile is the
  car's grade file, as the harness's span is) checked at build and packed into the .ssp
  (harness.systems.ssp.PackedFile): the masters hand the FMUs the unpacked copy, whatever the
  working directory;
- a line (several ``[[span]]``): the first span as span.*, the later ones as a CSV made at build
  for the AtoController's line.profile (``line_csv``: stop_m, length_m, schedule_s, dwell_s,
  boarding_t per span) and their limits as one for line.speed_limit_profile (``line_limits_csv``),
  packed as the limits CSV is; the ATO's ato.payload drives the car's car.payload (the boarding
  at each dwell's start) and the car's est.station_stops feeds the ATO (models.ato.line: the
  one line logic the harness's AtoDriver runs too);
- a constant wind as the start value of the car's wind_speed input;
- step_s and duration_s as the system's step and stop time.

What a system cannot be, refused at build with the reason: a scenario without a span (its
driving script is the harness's, not an FMU) and a wind that changes during the run (no FMU
gives it).

The system steps Gauss-Seidel, the ATO first (SystemSpec.step_order ("ato", "car")): the demand
the ATO computes from the car's outputs at t is applied over [t, t + h], as ``python -m harness
run`` applies it, so our master reproduces the harness's run of the scenario. ``jacobi=True``
(``--jacobi``) builds it for libcosim and ecos too, at the price of the Jacobi scheme's one-step (h)
actuator delay (docs/systems.md).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, fields
from pathlib import Path

from harness.run.fmus import BuildError, FmuChoice, choose, native_path, uncovered
from harness.systems.ssp import Component, Connection, PackedFile, SspError, SystemSpec
from harness.textio import InputError

__all__ = ["ATO_FEED", "DEMANDS", "FMI_VERSIONS", "ScenarioSystem", "scenario_system", "system_from_scenario",
           "choose_ato", "fmi3_path", "limits_csv", "line_csv", "line_limits_csv", "is_scenario"]

ATO_FEED = ("filter.speed", "filter.position", "filter.speed_std", "filter.position_std",
            "est.mass", "est.A0", "est.A1", "est.A2", "est.status", "est.samples",
            "est.mass_std", "est.A0_std", "est.A1_std", "est.A2_std", "est.cov_A0_A1",
            "est.cov_A0_A2", "est.cov_A1_A2", "est.station_stops")
"""The car's outputs the ATO reads (inputs of the same names): models.ato.line.READS, the
estimates with their stated uncertainty (the regulator weighs them by it) and the station stops
the estimator has recognised (a line)."""
DEMANDS = ("traction_force_demand", "brake_force_demand")
"""The ATO's outputs the car applies."""
FMI_VERSIONS = (2, 3)
"""The FMI versions a scenario's system is built for (``--fmi``): 2 every kind, 3 the natives."""


@dataclass(frozen=True)
class ScenarioSystem:
    """A scenario's system and the FMU chosen for each of its components (harness.run.fmus.FmuChoice)."""
    spec: SystemSpec
    car: FmuChoice
    ato: FmuChoice

    def choice_lines(self) -> list[str]:
        """What ``system build`` prints: which FMU runs each component, and why."""
        return [f"fmu: car: {self.car.describe()}", f"fmu: ato: {self.ato.describe()}"]


def is_scenario(data: dict) -> bool:
    """Whether parsed TOML is a scenario (harness/run/scenario.py) rather than a system
    description (harness/systems/cli.py): a description has [components]."""
    return "components" not in data


def limits_csv(distances, speeds_mps) -> bytes:
    """The span's speed limits as the AtoController's span.speed_limit_profile reads them: the
    header distance_m,speed_limit_mps and one row per limit, the doubles written exactly (repr)."""
    rows = ["# speed limits [m/s] from each distance [m]: made by python -m harness system build",
            "distance_m,speed_limit_mps"]
    rows += [f"{float(d)!r},{float(v)!r}" for d, v in zip(distances, speeds_mps)]
    return ("\n".join(rows) + "\n").encode("utf-8")


def line_csv(spans) -> bytes:
    """The second and later spans of a line (harness.run.span_scenario.LineSpan) as the
    AtoController's line.profile reads them, the doubles written exactly (repr)."""
    rows = ["# a line's spans after the first: made by python -m harness system build",
            "stop_m,length_m,schedule_s,dwell_s,boarding_t"]
    rows += [",".join(repr(float(x)) for x in (s.span.stop, s.span.length, s.span.schedule,
                                               s.dwell_s, s.boarding_t)) for s in spans[1:]]
    return ("\n".join(rows) + "\n").encode("utf-8")


def line_limits_csv(spans) -> bytes:
    """The speed limits of a line's second and later spans as line.speed_limit_profile reads
    them: span (2, 3, ..), distance_m, speed_limit_mps, the doubles written exactly (repr)."""
    rows = ["# speed limits [m/s] of a line's spans from each distance [m]: made by python -m "
            "harness system build", "span,distance_m,speed_limit_mps"]
    rows += [f"{k},{float(d)!r},{float(v)!r}" for k, s in enumerate(spans[1:], start=2)
             for d, v in zip(s.span.limit_distances, s.span.limit_speeds)]
    return ("\n".join(rows) + "\n").encode("utf-8")


def _system_name(name: str) -> str:
    """A scenario's name as a system name (letters, digits and _)."""
    out = re.sub(r"[^A-Za-z0-9_]", "_", name) or "scenario"
    return out if not out[0].isdigit() else f"_{out}"


def _fields_as_parameters(obj, prefix: str, ato_md, where: str) -> dict:
    """Every field of dataclass ``obj`` as the AtoController parameter ``prefix``.field; a field the
    FMU has no parameter for is refused unless it keeps its default."""
    names = {v.name for v in ato_md.modelVariables if v.causality == "parameter"}
    default = type(obj)()
    out = {}
    for f in fields(obj):
        if not f.init:
            continue
        value = getattr(obj, f.name)
        if f"{prefix}.{f.name}" in names:
            out[f"{prefix}.{f.name}"] = value
        elif value != getattr(default, f.name):
            raise SspError(f"{where}.{f.name} = {value!r}: the AtoController FMU has no parameter "
                           f"{prefix}.{f.name}, so a system cannot set it")
    return out


def fmi3_path(model: str, dist: Path) -> Path:
    """DIST/native/<model>Native3.fmu: the FMI 3.0 native twin of ``model`` (RailCarNative3.fmu,
    AtoControllerNative3.fmu)."""
    fmi2 = native_path(model, dist)
    return fmi2.with_name(f"{fmi2.stem}3.fmu")


def _fmi3_choice(asked: str, model: str, dist: Path, label: str, parameters: dict, where: str) -> FmuChoice:
    """The FMI 3.0 native FMU of ``model`` for ``--fmi 3``, or SspError saying why not: it is the
    only FMI 3 FMU we build, so neither --fmu python nor parameters it does not run can have one."""
    path = fmi3_path(model, dist)
    if asked == "python":
        raise SspError(f"{where}: --fmi 3 --fmu python: the pythonfmu {model}.fmu is FMI 2.0 only; "
                       f"--fmi 3 runs the native {path.name} (--fmu auto or native)")
    why = uncovered(model, parameters)
    if why is not None:
        raise SspError(f"{where}: --fmi 3: {label} sets {why}, which the native {path.name} does not run, "
                       f"and there is no FMI 3 pythonfmu {model} FMU: build with --fmi 2")
    if not path.is_file():
        raise SspError(f"--fmi 3: {path} is missing (build.py builds the FMI 3.0 natives it can; "
                       f"--fmi 2 runs the FMI 2.0 FMUs)")
    return FmuChoice("native", path, asked, "FMI 3.0, as asked (--fmi 3)")


def choose_ato(asked: str, dist: Path, label: str, parameters: dict, where: str) -> FmuChoice:
    """The AtoController FMU for the parameters a system gives it (FMI 2): harness.run.fmus.choose,
    but ``native`` is refused at build (SspError with the reason) when the native FMU would refuse
    the parameters (harness.run.fmus.uncovered), rather than failing in every master at
    initialisation; a missing pythonfmu FMU is refused too."""
    from fmu_src.variables import ATO
    try:
        choice = choose(asked, ATO, dist, [(label, parameters)])
    except (InputError, BuildError) as e:        # a bad --fmu; --fmu native with the native FMU missing
        raise SspError(f"{where}: {e}") from None
    if asked == "native":
        why = uncovered(ATO, parameters)
        if why is not None:
            raise SspError(f"{where}: --fmu native: {label} sets {why}, which the native "
                           f"{choice.path.name} does not run (--fmu auto or python runs the pythonfmu "
                           f"AtoController.fmu)")
    if not choice.path.is_file():
        raise SspError(f"{choice.path}: the AtoController FMU is missing (build the FMUs with: python "
                       f"build.py; --dist names another folder)")
    return choice


def system_from_scenario(path: str | Path, dist: str | Path, fmu: str = "auto",
                         jacobi: bool = False, fmi: int = 2) -> SystemSpec:
    """The system of ``scenario_system`` (the same arguments) without the FMU choices."""
    return scenario_system(path, dist, fmu, jacobi, fmi).spec


def scenario_system(path: str | Path, dist: str | Path, fmu: str = "auto",
                    jacobi: bool = False, fmi: int = 2) -> ScenarioSystem:
    """The RailCar <-> AtoController system of the span scenario at ``path`` (the module's text);
    FMUs from ``dist``; ``fmu``: auto, native or python, for the RailCar FMU (harness.run.fmus.choose)
    and the AtoController FMU (``choose_ato``); ``fmi``: 2, or 3 for the FMI 3.0 natives.
    SspError (or the scenario's own InputError) names the file and the key."""
    from fmu_src.variables import ATO, RAILCAR
    from harness.run.scenario import PATH_PARAMETERS, load_scenario
    from harness.systems.ssp import read_model_description_of

    path, dist = Path(path), Path(dist)
    if fmi not in FMI_VERSIONS:
        raise SspError(f"--fmi {fmi}: expected one of {', '.join(map(str, FMI_VERSIONS))}")
    scenario = load_scenario(path)
    if scenario.ato is None:
        raise SspError(f"{path}: not a span scenario: a system is the car and the AtoController FMU, "
                       f"built from a [span] scenario; a [[driver]] script or [driver_table] is "
                       f"the harness's driver (python -m harness run {path})")
    setup = scenario.ato_setup()
    changing = [w for w in scenario.wind if w.time_s > 0.0]
    if changing:
        raise SspError(f"{path}: wind: the wind changes at t = {changing[0].time_s:g} s; in a system "
                       f"the car's wind_speed input holds its start value all run (no FMU gives a "
                       f"wind over time): give one [[wind]] from time_s = 0, or run it with "
                       f"python -m harness run")
    span = setup.spans[0].span
    params = dict(scenario.parameters)
    for name in PATH_PARAMETERS:
        if params.get(name):
            params[name] = PackedFile(Path(params[name]), parameter=name)
    if scenario.wind:
        params["wind_speed"] = scenario.wind_at(0.0)
    if fmi == 3:
        car = _fmi3_choice(fmu, RAILCAR, dist, scenario.name, scenario.parameters, str(path))
    else:
        try:
            car = choose(fmu, RAILCAR, dist, [(scenario.name, scenario.parameters)])
        except (InputError, BuildError) as e:
            raise SspError(f"{path}: {e}") from None
    # The ATO's model description (the one variable table of both its FMUs) decides which
    # dataclass fields become parameters; the parameters then decide which FMU runs them.
    python_ato = dist / f"{ATO}.fmu"
    if not python_ato.is_file():
        raise SspError(f"{python_ato}: the AtoController FMU is missing (build the FMUs with: python "
                       f"build.py; --dist names another folder)")
    ato_md = read_model_description_of(python_ato, str(python_ato))
    grade = scenario.parameters.get("track.grade_profile", "")
    ato = {"span.stop": span.stop, "span.length": span.length, "span.schedule": span.schedule,
           "span.grade_profile": PackedFile(Path(grade), parameter="track.grade_profile") if grade else "",
           "span.speed_limit_profile": PackedFile(data=limits_csv(span.limit_distances, span.limit_speeds),
                                                  name=f"{_system_name(scenario.name)}_limits.csv",
                                                  parameter="span.limit_kmh"),
           **_fields_as_parameters(setup.car, "car", ato_md, f"{path}: ato.car"),
           **_fields_as_parameters(setup.tuning, "ato", ato_md, f"{path}: ato")}
    connections = ([Connection(f"car.{v}", f"ato.{v}") for v in ATO_FEED]
                   + [Connection(f"ato.{v}", f"car.{v}") for v in DEMANDS])
    if len(setup.spans) > 1:
        stem = _system_name(scenario.name)
        ato["line.profile"] = PackedFile(data=line_csv(setup.spans), name=f"{stem}_line.csv",
                                         parameter="span")
        ato["line.speed_limit_profile"] = PackedFile(data=line_limits_csv(setup.spans),
                                                     name=f"{stem}_line_limits.csv",
                                                     parameter="span.limit_kmh")
        connections.append(Connection("ato.ato.payload", "car.car.payload"))
    named = {k: str(v) if isinstance(v, PackedFile) else v for k, v in ato.items()}   # readable refusals
    ato_choice = (_fmi3_choice(fmu, ATO, dist, scenario.name, named, str(path)) if fmi == 3
                  else choose_ato(fmu, dist, scenario.name, named, str(path)))
    spec = SystemSpec(_system_name(scenario.name), (Component("car", car.path, params),
                                                    Component("ato", ato_choice.path, ato)),
                      tuple(connections), scenario.step_s, 0.0, scenario.duration_s,
                      scenario.purpose or f"RailCar <-> AtoController: {path.name}",
                      () if jacobi else ("ato", "car"))
    return ScenarioSystem(spec, car, ato_choice)
