"""The thin layer between pythonfmu and ``models``: registration, parameters, errors.

Every slave callback that computes is wrapped so that no Python exception escapes during a
step: bad inputs are logged, naming the variable and value, and the step is discarded (do_step
returns False -> fmi2Discard). Bad parameters are found in exit_initialization_mode, which
raises ParameterError naming the parameter (file, line): the FMU's binary (fmu_src/c) returns
fmi2Error with that message and keeps the instance safe to reset or free.
"""
from __future__ import annotations

import os
import re
import stat
import traceback
from dataclasses import dataclass
from pathlib import Path

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

from models.estimation.online import StationConfig
from models.filtering.motion_filter import FilterConfig
from models.estimation.identification import IdentifierConfig
from models.plant.track import GradeProfile, ProfileError, SpeedProfile

from .variables import Var, variables_for

_CAUSALITY = {"parameter": Fmi2Causality.parameter, "input": Fmi2Causality.input,
              "output": Fmi2Causality.output}
_VARIABILITY = {"fixed": Fmi2Variability.fixed, "continuous": Fmi2Variability.continuous,
                "discrete": Fmi2Variability.discrete}
_TYPE = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_INITIAL = {"exact": Fmi2Initial.exact, "calculated": Fmi2Initial.calculated}


class ParameterError(ValueError):
    """A parameter or profile the FMU cannot start with; the message names it."""


def register_variables(slave, fmu: str) -> dict:
    """Register the table's variables of ``fmu`` on ``slave``; returns the live value dict."""
    values: dict = {}
    for var in variables_for(fmu):
        values[var.name] = var.start
        kwargs = dict(causality=_CAUSALITY[var.causality],
                      variability=_VARIABILITY[var.variability],
                      description=var.description,
                      getter=(lambda n=var.name: values[n]))
        if var.causality == "output":
            kwargs["initial"] = _INITIAL[var.initial]
        else:
            kwargs["setter"] = _setter(slave, values, var)
        start = None if var.initial == "calculated" else var.start   # no start: computed
        slave.register_variable(_TYPE[var.type](var.name, start=start, **kwargs))
    return values


def _setter(slave, values: dict, var: Var):
    """A parameter is fixed once the model is built: a later set is refused and logged (the
    FMU's own binary refuses it with fmi2Error before it gets here; this guards the pythonfmu
    binary used where no C compiler was found)."""
    if var.causality != "parameter":
        def set_value(v, name=var.name):
            values[name] = v
        return set_value

    def set_parameter(v, name=var.name):
        if getattr(slave, "chain", None) is not None:
            slave.log(f"set {name} = {v!r} refused: a parameter cannot change after initialisation "
                      f"(it keeps {values[name]!r})", Fmi2Status.error)
            return
        values[name] = v
    return set_parameter


def resolve_profile_path(path: str, resources: str | None) -> Path:
    """A relative path is looked up in the FMU's resources/ first, then the working directory."""
    p = Path(path)
    if p.is_absolute():
        return p
    if resources:
        candidate = Path(resources) / p
        try:
            if candidate.is_file():
                return candidate
        except OSError:                  # a name the file system refuses (too long): not there
            pass
    return Path(os.getcwd()) / p


# The most bytes a profile parameter's file may have (models/core/profile.h RC_PROFILE_MAX_BYTES,
# the native FMUs' twin). A 100 km line's grade profile at 1 m resolution ("100000.0,-12.5" and
# a line break a row) is about 1.6 MB, a tenth of it; the bound stops a wrong file (/dev/zero's
# like, a log, a disc image) from filling the memory.
PROFILE_MAX_BYTES = 16 * 1024 * 1024
_PROFILE_MAX_TEXT = f"{PROFILE_MAX_BYTES} bytes (16 MiB)"

# stat's kinds a profile may not be, as the C reader names them (it has no S_ISSOCK under C99:
# a socket is "not a regular file" in both). On Windows os.stat reports a folder as S_IFDIR, a
# device such as NUL as S_IFCHR and a pipe as S_IFIFO, so the rule holds there too.
_NOT_A_FILE = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a device"),
               (stat.S_ISBLK, "a device"))


def read_profile_text(values: dict, param: str, resources: str | None) -> tuple[str, str] | None:
    """(text, path) of the profile CSV parameter ``param`` names (None: empty), found by
    ``resolve_profile_path``; ParameterError names the parameter and the file. The file must be
    a regular file of at most PROFILE_MAX_BYTES, which os.stat tells before it is opened
    (opening a FIFO waits for a writer for ever, /dev/zero never ends); the messages are the
    native FMUs' (models/core/profile.c rc_profile_read_file)."""
    raw = values[param]
    if not raw:
        return None
    path = resolve_profile_path(raw, resources)
    cannot = f"{param}: cannot read '{raw}' (looked for {path})"
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = next((k for test, k in _NOT_A_FILE if test(st.st_mode)), None)
            raise ParameterError(f"{cannot}: it is {kind}, not a regular file" if kind
                                 else f"{cannot}: it is not a regular file")
        if st.st_size > PROFILE_MAX_BYTES:
            raise ParameterError(f"{cannot}: it has {st.st_size} bytes, more than the "
                                 f"{_PROFILE_MAX_TEXT} a profile may have")
        with open(path, "rb") as f:
            data = f.read(PROFILE_MAX_BYTES + 1)
    except OSError as e:
        raise ParameterError(f"{cannot}: {e.strerror}") from None
    if len(data) > PROFILE_MAX_BYTES:
        raise ParameterError(f"{cannot}: it grew past the {_PROFILE_MAX_TEXT} a profile may have "
                             f"while it was read")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ParameterError(f"{param}: {path}: not UTF-8 text (byte offset {e.start})") from None
    # the universal newlines of a file opened as text, as Path.read_text gave them before
    return text.replace("\r\n", "\n").replace("\r", "\n"), str(path)


def read_grade(values: dict, param: str, resources: str | None) -> GradeProfile:
    """The grade profile the parameter ``param`` names (level track if empty); ParameterError
    names the parameter, the file and the line."""
    src = read_profile_text(values, param, resources)
    try:
        return GradeProfile.from_csv_text(*src) if src else GradeProfile.level()
    except ProfileError as e:
        raise ParameterError(f"{param}: {e}") from None


def load_profiles(values: dict, resources: str | None) -> tuple[GradeProfile, SpeedProfile | None]:
    """Read track.grade_profile and track.speed_profile; ParameterError names file and line."""
    grade = read_grade(values, "track.grade_profile", resources)
    speed_src = read_profile_text(values, "track.speed_profile", resources)
    try:
        speed = SpeedProfile.from_csv_text(*speed_src) if speed_src else None
    except ProfileError as e:
        raise ParameterError(f"track.speed_profile: {e}") from None
    return grade, speed


def initialise(build):
    """Build the model chain from the parameters; raise ParameterError with a clear message
    if it fails (the binary logs it, once)."""
    try:
        return build()
    except (ValueError, ParameterError) as e:
        raise ParameterError(f"initialisation failed: {e}") from None


def not_initialised(slave) -> bool:
    """doStep before a successful exitInitializationMode: say so, discard the step."""
    slave.log("doStep refused: the instance is not initialised (call exitInitializationMode "
              "first; after a failed initialisation, reset or free the instance)", Fmi2Status.error)
    return False


def guarded_step(slave, step) -> bool:
    """Run one step; on bad input or any failure log it and discard the step (return False)."""
    from models.chain import StepRejected
    values = getattr(slave, "values", {})
    rejected = values.get("filter.rejected", 0)
    try:
        step()
        if values.get("filter.rejected", 0) != rejected:
            n = values["filter.rejected"] - rejected
            slave.log(f"{n} measurement(s) refused by the innovation gate in this step (a spike, a "
                      f"dropout; filter.rejected = {values['filter.rejected']})", Fmi2Status.warning)
        return True
    except StepRejected as e:
        slave.log(f"step discarded: {e}", Fmi2Status.discard)
        return False
    except Exception as e:  # the FMU never takes its host down
        slave.log(f"step failed: {type(e).__name__}: {e}", Fmi2Status.error)
        slave.log(traceback.format_exc(), Fmi2Status.ok, category="logAll")   # debug: with loggingOn
        return False


def estimator_settings(v: dict) -> tuple[IdentifierConfig, FilterConfig, StationConfig]:
    """est.*, sensor noise, filter.kind and track.station_dwell -> configs (both FMUs)."""
    ident = IdentifierConfig(
        batch_size=int(v["est.batch_size"]), forgetting=v["est.forgetting"], gamma=v["est.gamma"],
        method=int(v["est.method"]), slope_window=int(v["est.slope_window"]),
        physical=int(v["est.physical"]), sigma2_method=int(v["est.sigma2_method"]),
        run_forgetting=v["est.run_forgetting"],
        A0_drift_std=v["est.A0_drift_std"], A1_drift_std=v["est.A1_drift_std"],
        mass_initial=v["est.mass_initial"], mass_std_initial=v["est.mass_std_initial"],
        A0_initial=v["est.A0_initial"], A1_initial=v["est.A1_initial"], A2_initial=v["est.A2_initial"],
        A0_std_initial=v["est.A0_std_initial"], A1_std_initial=v["est.A1_std_initial"],
        A2_std_initial=v["est.A2_std_initial"], sigma2_initial=v["est.sigma2_initial"])
    filt = FilterConfig(speed_std=v["sensor.speed_std"], position_std=v["sensor.position_std"],
                        position_std_rel=v["sensor.position_std_rel"],
                        speed_std_rel=v["sensor.speed_std_rel"], kind=int(v["filter.kind"]),
                        length=v["car.length"], singer_tau=v["filter.singer_tau"],
                        singer_p0=v["filter.singer_p0"], singer_p_plus=v["filter.singer_p_plus"],
                        singer_p_minus=v["filter.singer_p_minus"],
                        singer_w_max_plus=v["filter.singer_w_max_plus"],
                        singer_w_max_minus=v["filter.singer_w_max_minus"])
    return ident, filt, StationConfig(dwell=v["track.station_dwell"])


def track_settings(v: dict):
    """sensor.track_* parameters -> TrackSensorConfig (spacing only exists in RailCar)."""
    from models.chain import TrackSensorConfig
    return TrackSensorConfig(spacing=v.get("sensor.track_spacing", 0.0), base=v["sensor.track_base"],
                             resolution=v["sensor.track_resolution"], jitter=v["sensor.track_jitter"])


def chain_config(v: dict):
    """RailCar's parameter values -> models.chain.ChainConfig (also used by studies)."""
    from models.chain import ChainConfig
    from models.plant.dynamics import VehicleParams
    vehicle = VehicleParams(
        mass=v["car.mass"], A0=v["car.A0"], A1=v["car.A1"], A2=v["car.A2"], gamma=v["car.gamma"],
        length=v["car.length"], traction_force_max=v["car.traction_force_max"],
        traction_power_max=v["car.traction_power_max"], brake_force_max=v["car.brake_force_max"],
        adhesion_mass_fraction=v["car.adhesion_mass_fraction"], adhesion_factor=v["car.adhesion_factor"])
    ident, filt, station = estimator_settings(v)
    return ChainConfig(vehicle=vehicle, solver_step=v["solver.step"],
                       process_noise_psd=v["car.process_noise_psd"],
                       sample_period=v["sensor.sample_period"], seed=int(v["seed"]),
                       initial_speed=v["car.initial_speed"], initial_position=v["car.initial_position"],
                       station=station, identifier=ident, filter=filt, track=track_settings(v))


@dataclass(frozen=True)
class ChainSetup:
    """RailCar's models chain as its parameters configure it: the ChainConfig and the track
    profiles (grade; the speed profile V_zad(X) or None)."""
    config: object                      # models.chain.ChainConfig
    grade: GradeProfile
    speed: SpeedProfile | None

    def open(self, start_time: float = 0.0):
        """The chain (models.compiled.open_chain: C where the core covers the configuration)."""
        from models.compiled import open_chain
        return open_chain(self.config, self.grade, self.speed, start_time=start_time)


def chain_setup(v: dict, resources: str | None) -> ChainSetup:
    """RailCar's parameter values -> its chain's configuration and profiles, as the FMU builds
    them at initialisation (``chain_config``, ``load_profiles`` with the FMU's ``resources``
    folder). Raises ValueError (ParameterError for a profile), naming the parameter."""
    return ChainSetup(chain_config(v), *load_profiles(v, resources))


# ------------------------------------------------------------------------------- AtoController
SPEED_LIMIT_COLUMNS = ("distance_m", "speed_limit_mps")


def open_ato(v: dict, resources: str | None):
    """AtoController's parameter values -> models.ato.controller.AtoController (span, configured car,
    tuning; the profiles read as RailCar reads its own, ``resolve_profile_path``). Raises
    ParameterError naming the parameter (a profile: its file and line): an infeasible schedule,
    a stop mark beyond the span, a limit the brakes cannot keep, a bad tuning value."""
    from models.ato.controller import AtoController
    from models.ato.interface import AtoTuning
    from models.planning.span import CarTraction, Span
    from models.plant.track import parse_profile_csv
    from .variables import _CAR_ROWS, _TUNING_ROWS, _TUNING_ROWS_APPENDED

    grade = read_grade(v, "span.grade_profile", resources)
    limit_src = read_profile_text(v, "span.speed_limit_profile", resources)
    if limit_src:
        try:
            distances, limits = parse_profile_csv(*limit_src, SPEED_LIMIT_COLUMNS)
        except ProfileError as e:
            raise ParameterError(f"span.speed_limit_profile: {e}") from None
    else:
        distances, limits = [0.0], [v["span.speed_limit"]]
    stop = v["span.stop"]
    length = v["span.length"] or stop
    try:
        span = Span(length, v["span.schedule"], stop, grade, tuple(distances), tuple(limits))
        car = CarTraction(**{f: v[f"car.{f}"] for f, _, _ in _CAR_ROWS})
        tuning = AtoTuning(**{f: v[f"ato.{f}"] for f, _, _ in (*_TUNING_ROWS, *_TUNING_ROWS_APPENDED)})
        return AtoController(span, car, tuning)
    except ValueError as e:
        raise ParameterError(_fmu_names(str(e), bool(limit_src))) from None


def _fmu_names(message: str, profile: bool) -> str:
    """models' messages say tuning.x and span.limit_speeds[k]: name the FMU's parameters."""
    def limit(m):
        return f"span.speed_limit_profile row {int(m.group(2)) + 1}" if profile else "span.speed_limit"
    message = re.sub(r"span\.limit_(speeds|distances)\[(\d+)\]", limit, message)
    return message.replace("tuning.", "ato.")
