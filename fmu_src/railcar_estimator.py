"""RailCarEstimator FMU: identification and filter on measurements from anywhere."""
from pythonfmu import Fmi2Slave

from fmu_src.adapter import estimator_settings, track_settings, guarded_step, initialise, not_initialised, load_profiles, register_variables
from fmu_src.variables import ESTIMATOR
from models.compiled import open_estimator_chain


class RailCarEstimator(Fmi2Slave):
    author = "rail-car FMU team"
    description = "Rail-car parameter identification (LS, eqs. (3)-(12)) and Kalman filter on measurements"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = register_variables(self, ESTIMATOR)
        self.chain = None

    def _build(self):
        v = self.values
        ident, filt, station = estimator_settings(v)
        grade, speed = load_profiles(v, self.resources)
        return open_estimator_chain(ident, filt, station, grade, speed, track_settings(v))

    def exit_initialization_mode(self):
        self.chain = initialise(self._build)

    def do_step(self, current_time, step_size):
        if self.chain is None:
            return not_initialised(self)
        v = self.values

        def step():
            self.chain.do_step(current_time, step_size, v["traction_force"], v["brake_force"],
                               v["sensor.speed"], v["sensor.position"], v["sensor.track_speed"],
                               v["sensor.track_time"])
            v.update(self.chain.outputs())
        return guarded_step(self, step)
