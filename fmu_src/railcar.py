"""RailCar FMU: car dynamics (plant), sensors, parameter identification and Kalman filter."""
from pythonfmu import Fmi2Slave

from fmu_src.adapter import chain_setup, guarded_step, initialise, not_initialised, register_variables
from fmu_src.variables import RAILCAR


class RailCar(Fmi2Slave):
    author = "rail-car FMU team"
    description = "Rail-car motion: dynamics eq. (2), sensors, least-squares identification, Kalman filter"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.values = register_variables(self, RAILCAR)
        self.chain = None
        self.start_time = 0.0

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.start_time = float(start_time)

    def _build(self):
        chain = chain_setup(self.values, self.resources).open(self.start_time)   # C where covered
        self.values.update(chain.outputs())
        return chain

    def exit_initialization_mode(self):
        self.chain = initialise(self._build)

    def do_step(self, current_time, step_size):
        if self.chain is None:
            return not_initialised(self)
        v = self.values

        def step():
            self.chain.do_step(current_time, step_size, v["traction_force_demand"],
                               v["brake_force_demand"], v["wind_speed"], v["car.payload"])
            v.update(self.chain.outputs())
        return guarded_step(self, step)
