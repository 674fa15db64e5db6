"""AtoController FMU: the train operation of one span (models.ato.controller) closed around the estimator.

Each doStep(t, h) reads the estimator's outputs at t (inputs of the same names), asks
models.ato.controller.AtoController for the command and holds it as the outputs for the next step: in a
system the car applies it one communication step later (an actuator delay of h). After
initialisation the outputs are a holding brake. Bad parameters fail exitInitializationMode with
a message naming them (an infeasible schedule, a stop mark beyond the span, a limit the brakes
cannot keep); at run time nothing fails: a missing or non-finite input gives the safe brake
(ato.mode 9), logged as a warning.
"""
from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

from fmu_src.adapter import initialise, not_initialised, open_ato, register_variables
from fmu_src.variables import ATO, variables_for
from models.ato.interface import AtoMode

READS = tuple(v.name for v in variables_for(ATO) if v.causality == "input")


class AtoController(Fmi2Slave):
    author = "rail-car FMU team"
    description = ("Train operation for one span: energy-efficient running-time regulator, targeted "
                   "stopping with relay-staged EP brake, speed supervision (Meleshin 2011, Sidorenko 1997)")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = register_variables(self, ATO)
        self.controller = None
        self.logged = 0

    def _build(self):
        ctrl = open_ato(self.values, self.resources)
        hold = ctrl.tuning.hold_brake * ctrl.car.brake_force_max
        self._publish(ctrl, 0.0, hold, int(AtoMode.HOLD), 0.0, 0)
        return ctrl

    def exit_initialization_mode(self):
        self.controller = initialise(self._build)

    def _publish(self, ctrl, traction, brake, mode, planned, stage):
        v = self.values
        v["traction_force_demand"], v["brake_force_demand"] = float(traction), float(brake)
        v["ato.mode"], v["ato.planned_speed"], v["ato.ep_stage"] = int(mode), float(planned), int(stage)
        v["ato.finished"] = bool(ctrl.finished)
        v["ato.replans"] = int(ctrl.replans)
        v["ato.using_estimates"] = ctrl.using_estimates
        v["ato.predicted_arrival"] = float(ctrl.plan.arrival)

    def do_step(self, current_time, step_size):
        ctrl = self.controller
        if ctrl is None:
            return not_initialised(self)
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
        return True
