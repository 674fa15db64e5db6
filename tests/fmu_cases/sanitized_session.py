"""A hostile session against RailCar with its binary built under -fsanitize=address,undefined
(tests/fmu_tests/test_fmu_sanitized.py runs it with the sanitizer runtimes preloaded): good runs with
reset and free, failed initialisations, a second free and a doStep on a freed instance. Any
sanitizer report aborts the process; the last line says it got through."""
import pythonfmu  # noqa: F401  (before the FMU is loaded)

import ctypes
import sys

from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

ERROR = 3
unzipdir = sys.argv[1]
md = read_model_description(unzipdir)
vr = {v.name: v.valueReference for v in md.modelVariables}


def new(name: str) -> FMU2Slave:
    f = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier="RailCar", instanceName=name)
    f.instantiate()
    return f


for _ in range(20):                                   # good runs, reset, free
    f = new("good")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    t = 0.0
    for i in range(200):
        f.setReal([vr["traction_force_demand"]], [30e3 if i < 100 else 0.0])
        f.doStep(t, 0.1)
        t += 0.1
        mass, speed = f.getReal([vr["est.mass"], vr["car.speed"]])
    assert 20.0 < mass < 45.0 and speed > 0.0, (mass, speed)
    f.reset()
    f.freeInstance()

for _ in range(20):                                   # failed initialisation, then misuse
    f = new("bad")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["car.mass"]], [0.0])
    try:
        f.exitInitializationMode()
        raise AssertionError("car.mass = 0 was accepted")
    except AssertionError:
        raise
    except Exception:
        pass
    lib, c = f.dll, f.component
    lib.fmi2DoStep.restype = ctypes.c_int
    lib.fmi2FreeInstance(c)
    lib.fmi2FreeInstance(c)                            # a second free
    assert lib.fmi2DoStep(c, ctypes.c_double(0.0), ctypes.c_double(0.1), 1) == ERROR
print("SANITIZED-SESSION-DONE")
