"""AtoController FMU: the train operation of one span (models.ato.controller) closed around the estimator.

Each doStep(t, h) reads the estimator's outputs at t (inputs of the same names), asks
models.ato.controller.AtoController for the command and holds it as the outputs for the next step: in a
system the car applies it one communication step later (an actuator delay of h). After
initialisation the outputs are a holding brake.

Bad parameters fail exitInitializationMode with a message naming them (an infeasible or too
long schedule, a stop mark that is not a positive distance or lies beyond the span, a limit the
brakes cannot keep, a re-planning grid too fine for the span, a tuning value out of its bounds,
a profile file that cannot be read). A step whose size or time is bad is discarded as RailCar's
is (models.chain.check_step: h finite, > 0 and <= 3600 s; the time finite and continuing the
last step's end), logged, and nothing changes. Bad inputs never fail a step: an input that is
missing, not finite, outside physics or inconsistent with the others gives the safe brake
(ato.mode 9) and a warning naming the input and its value (models/ato/supervision.py).
"""
import math

from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

from fmu_src.adapter import (ParameterError, initialise, not_initialised, open_ato,
                             register_variables, resolve_profile_path)
from fmu_src.variables import ATO, variables_for
from models.ato.interface import AtoMode
from models.chain import StepRejected, check_step

READS = tuple(v.name for v in variables_for(ATO) if v.causality == "input")
PROFILE_PARAMETERS = ("span.grade_profile", "span.speed_limit_profile")


def check_span_parameters(v: dict, resources) -> None:
    """The span.* values open_ato combines (span.length 0 stands for span.stop), each checked
    under its own name first; the profile file names resolved (a name the file system refuses,
    too long or with a NUL, names the parameter). Raises ParameterError."""
    stop, length, schedule = v["span.stop"], v["span.length"], v["span.schedule"]
    if not (math.isfinite(stop) and stop > 0.0):
        raise ParameterError(f"span.stop = {stop!r} m must be finite and > 0 (the stop mark's "
                             f"distance from the departure station)")
    if not (math.isfinite(length) and length >= 0.0):
        raise ParameterError(f"span.length = {length!r} m must be finite and >= 0 (0: span.stop)")
    if not (math.isfinite(schedule) and schedule > 0.0):
        raise ParameterError(f"span.schedule = {schedule!r} s must be finite and > 0")
    for name in PROFILE_PARAMETERS:
        raw = v[name]
        if not raw:
            continue
        try:
            path = resolve_profile_path(raw, resources)
            path.is_file()
        except (OSError, ValueError) as e:
            shown = raw if len(raw) <= 80 else f"{raw[:60]}...({len(raw)} characters)"
            reason = getattr(e, "strerror", None) or str(e)
            raise ParameterError(f"{name}: cannot use '{shown}' as a file name: {reason}") from None


class AtoController(Fmi2Slave):
    author = "rail-car FMU team"
    description = ("Train operation for one span: energy-efficient running-time regulator, targeted "
                   "stopping with relay-staged EP brake, speed supervision (Meleshin 2011, Sidorenko 1997)")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = register_variables(self, ATO)
        self.controller = None
        self.logged = 0
        self.start_time = 0.0
        self.time = None          # [s] the end of the last step taken (the next one starts there)

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.start_time = float(start_time)

    def _build(self):
        check_span_parameters(self.values, self.resources)
        ctrl = open_ato(self.values, self.resources)
        hold = ctrl.tuning.hold_brake * ctrl.car.brake_force_max
        self._publish(ctrl, 0.0, hold, int(AtoMode.HOLD), 0.0, 0)
        return ctrl

    def exit_initialization_mode(self):
        self.controller = initialise(self._build)
        self.time = self.start_time

    def _publish(self, ctrl, traction, brake, mode, planned, stage):
        v = self.values
        v["traction_force_demand"], v["brake_force_demand"] = float(traction), float(brake)
        v["ato.mode"], v["ato.planned_speed"], v["ato.ep_stage"] = int(mode), float(planned), int(stage)
        v["ato.finished"] = bool(ctrl.finished)
        v["ato.replans"] = int(ctrl.replans)
        v["ato.using_estimates"] = ctrl.using_estimates
        v["ato.predicted_arrival"] = float(ctrl.plan.arrival)

    def _check_step(self, current_time, step_size) -> None:
        """RailCar's rules (models.chain): raise StepRejected naming the bad size or time."""
        check_step(current_time, step_size)
        if abs(current_time - self.time) > 1e-9 * max(1.0, abs(current_time)):
            raise StepRejected(f"current time {current_time!r} s does not continue the FMU's "
                               f"time {self.time!r} s")

    def do_step(self, current_time, step_size):
        """True, or Fmi2Status.warning (also true) when the command is the safe brake for a bad
        input; False (fmi2Discard) for a bad step size or time, with nothing changed."""
        ctrl = self.controller
        if ctrl is None:
            return not_initialised(self)
        try:
            self._check_step(current_time, step_size)
        except StepRejected as e:
            self.log(f"step discarded: {e}", Fmi2Status.discard)
            return False
        try:
            cmd = ctrl.demands(current_time, {n: self.values[n] for n in READS})
            self._publish(ctrl, cmd.traction, cmd.brake, cmd.mode, cmd.planned_speed, cmd.ep_stage)
        except Exception as e:   # models.ato.controller never raises here; if it did, brake, never crash
            self.log(f"t = {current_time:.3f} s: {type(e).__name__}: {e}: safe brake", Fmi2Status.error)
            safe = ctrl.tuning.safe_brake * ctrl.car.brake_force_max
            self._publish(ctrl, 0.0, safe, int(AtoMode.SAFE), 0.0, 0)
        for t, reason in ctrl.events[self.logged:]:
            self.log(f"t = {t:.3f} s: {reason}", Fmi2Status.warning)
        self.logged = len(ctrl.events)
        self.time = current_time + step_size
        return Fmi2Status.warning if self.values["ato.mode"] == AtoMode.SAFE else True
