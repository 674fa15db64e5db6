"""Run one catalogue case of tests/fmu_tests/test_fmu_calls.py in a fresh process and print what happened.

    python driver.py CASE.json

CASE.json: {"fmus": {"RailCar": UNZIPDIR, ...}, "steps": [[op, ...], ...]}. Every step records
its FMI status, any value it read and the log messages the FMU sent meanwhile; the records are
printed as one JSON line after the marker ``CASE-RESULT``, once every step has run. If the FMU
kills the process, the marker never appears and the test sees the signal.

Ops (``label`` names an instance; variables by name, or an int for a raw value reference):

    ["new", label, fmu, {opts}]      fmi2Instantiate through fmpy's FMU2Slave; opts: logging
                                     (bool), logger "null" (NULL logger) / functions "null" (NULL
                                     callbacks), guid, raw {"type", "resources", "name"} (raw call)
    ["init", label, {params}]        setupExperiment(0), enterInitializationMode, set, exit
    ["call", label, method, *args]   an fmpy FMU2Slave method (setReal, doStep, reset, ...)
    ["raw", target, function, *args] the C function itself, status as returned; target: a label
                                     (also after it was freed), [label, fmu] (the library of
                                     another FMU), "null" or "garbage"; args:
                                     {"vr": [...]}, {"real": [...]}, {"int": [...]}, {"bool":
                                     [...]}, {"str": [...]} (an item ["hex", "ff"]: raw bytes),
                                     {"out": "real"|"int"|"bool"|"str"|"status", "n": n}, "NULL",
                                     ints (size_t/int), floats (double)
    ["get", label, [names]]          typed getters by name: the values
    ["run", label, n]                n steps of 0.1 s from the instance's time with the standard
                                     inputs; then the standard outputs (statuses and values)
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any pythonfmu FMU is loaded)

import ctypes
import json
import math
import sys
from pathlib import Path

from fmpy import calloc, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2Boolean, fmi2CallbackAllocateMemoryTYPE,
                       fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE,
                       fmi2Integer, fmi2Real, fmi2String, fmi2ValueReference)
from fmpy.logging import addLoggerProxy

STEP = 0.1
OUTPUTS = {"RailCar": ["car.speed", "car.position", "sensor.speed", "est.mass", "filter.speed",
                       "filter.position_std"],
           "RailCarEstimator": ["est.mass", "est.A0", "filter.speed", "filter.position",
                                "filter.speed_std"]}


def estimator_inputs(k: int) -> dict:
    """A plausible measured run (as tests/fmu_tests/test_fmu_fmpy.py): 20 kN on 30 t from rest."""
    t = k * STEP
    return {"traction_force": 20e3, "brake_force": 0.0,
            "sensor.speed": 0.6 * t + 0.05 * math.sin(7.0 * k), "sensor.position": 0.3 * t * t}


class Case:
    def __init__(self, fmus: dict[str, str]):
        self.fmus = {}
        for name, unzipdir in fmus.items():
            md = read_model_description(str(Path(unzipdir, "modelDescription.xml")))
            lib = Path(unzipdir, "binaries", "linux64", f"{md.coSimulation.modelIdentifier}.so")
            # our own handle keeps the library mapped after fmpy's freeInstance unloads it,
            # so that calls after fmi2FreeInstance reach the FMU (as in a host that keeps it)
            self.fmus[name] = {"md": md, "vars": {v.name: v for v in md.modelVariables},
                               "lib": ctypes.CDLL(str(lib)), "unzipdir": unzipdir}
        self.inst: dict[str, dict] = {}
        self.log: list[list] = []
        self.records: list[dict] = []
        self.keep: list = []

    # -- logging
    def callbacks(self, logger: bool = True) -> fmi2CallbackFunctions:
        def record(_env, instance, status, category, message):
            self.log.append([int(status), category.decode("utf-8", "replace") if category else None,
                             message.decode("utf-8", "replace") if message else "",
                             instance.decode("utf-8", "replace") if instance else None])
        cb = fmi2CallbackFunctions()
        if logger:
            cb.logger = fmi2CallbackLoggerTYPE(record)
            addLoggerProxy(ctypes.byref(cb))           # formats the variadic message in C
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.keep.append(cb)
        return cb

    # -- helpers
    def vr(self, label: str, ref):
        return ref if isinstance(ref, int) else self.fmus[self.inst[label]["fmu"]]["vars"][ref].valueReference

    def type_of(self, label: str, name: str) -> str:
        return self.fmus[self.inst[label]["fmu"]]["vars"][name].type

    def status_of(self, fn, *args):
        try:
            value = fn(*args)
            return 0, value
        except FMICallException as e:
            return e.status, None

    def set_by_name(self, label: str, values: dict) -> list[int]:
        fmu = self.inst[label]["slave"]
        statuses = []
        for name, value in values.items():
            setter = {"Real": fmu.setReal, "Integer": fmu.setInteger, "String": fmu.setString,
                      "Boolean": fmu.setBoolean}[self.type_of(label, name)]
            statuses.append(self.status_of(setter, [self.vr(label, name)], [value])[0])
        return statuses

    def get_by_name(self, label: str, names: list[str]) -> tuple[int, list]:
        fmu, out, worst = self.inst[label]["slave"], [], 0
        for name in names:
            getter = {"Real": fmu.getReal, "Integer": fmu.getInteger, "String": fmu.getString,
                      "Boolean": fmu.getBoolean}[self.type_of(label, name)]
            status, value = self.status_of(getter, [self.vr(label, name)])
            worst = max(worst, status)
            v = value[0] if value is not None else None
            out.append(v.decode("utf-8") if isinstance(v, bytes) else v)
        return worst, out

    # -- ops
    def op_new(self, label, fmu_name, opts=None):
        opts = opts or {}
        md, unzipdir = self.fmus[fmu_name]["md"], self.fmus[fmu_name]["unzipdir"]
        slave = FMU2Slave(guid=opts.get("guid", md.guid), unzipDirectory=unzipdir,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=label)
        cb = None if opts.get("functions") == "null" else self.callbacks(opts.get("logger") != "null")
        self.inst[label] = {"fmu": fmu_name, "slave": slave, "time": 0.0}
        raw = opts.get("raw")
        if raw is not None:
            resources = raw.get("resources", Path(unzipdir, "resources").as_uri())
            name = raw.get("name", label)
            slave.component = slave.dll.fmi2Instantiate(
                None if name is None else name.encode(), raw.get("type", 1),
                (opts.get("guid", md.guid)).encode(),
                None if resources is None else resources.encode(),
                None if cb is None else ctypes.byref(cb), 0, int(opts.get("logging", True)))
        else:
            try:
                slave.instantiate(callbacks=cb, loggingOn=opts.get("logging", True))
            except Exception:
                slave.component = None
        return {"ok": bool(slave.component)}

    def op_init(self, label, params=None):
        fmu = self.inst[label]["slave"]
        statuses = [self.status_of(fmu.setupExperiment, None, 0.0)[0],
                    self.status_of(fmu.enterInitializationMode)[0],
                    *self.set_by_name(label, params or {}),
                    self.status_of(fmu.exitInitializationMode)[0]]
        self.inst[label]["time"] = 0.0
        return {"status": statuses[-1], "statuses": statuses}

    def op_call(self, label, method, *args):
        fmu = self.inst[label]["slave"]
        if method in ("setReal", "setInteger", "setBoolean", "setString", "getReal",
                      "getInteger", "getBoolean", "getString"):
            args = ([self.vr(label, r) for r in args[0]], *args[1:])
        status, value = self.status_of(getattr(fmu, method), *args)
        if method == "doStep" and status == 0:
            self.inst[label]["time"] = args[0] + args[1]
        if method == "reset" and status == 0:
            self.inst[label]["time"] = 0.0
        if isinstance(value, (list, tuple)):
            value = [v.decode("utf-8") if isinstance(v, bytes) else v for v in value]
        elif not isinstance(value, (int, float, str, type(None))):
            value = None
        return {"status": status, "value": value}

    def op_raw(self, target, function, *args):
        if isinstance(target, list):               # [label, fmu]: label's component, fmu's library
            label, fmu_name = target
        else:
            label = target if target not in ("null", "garbage") else None
            fmu_name = self.inst[label]["fmu"] if label else next(iter(self.fmus))
        lib = self.fmus[fmu_name]["lib"]               # no argtypes: the C function as it is
        component = {"null": None, "garbage": 0x1234}.get(target) if label is None \
            else self.inst[label]["slave"].component
        cargs, outs = [], []
        for a in args:
            if a == "NULL":
                cargs.append(None)
            elif isinstance(a, dict) and "out" in a:
                ctype = {"real": fmi2Real, "int": fmi2Integer, "bool": fmi2Boolean,
                         "str": fmi2String, "status": ctypes.c_int}[a["out"]]
                arr = (ctype * max(1, a.get("n", 1)))()
                outs.append((arr, a.get("n", 1)))
                cargs.append(arr)
            elif isinstance(a, dict):
                (kind, values), = a.items()
                ctype = {"vr": fmi2ValueReference, "real": fmi2Real, "int": fmi2Integer,
                         "bool": fmi2Boolean, "str": fmi2String}[kind]
                if kind == "vr":
                    values = [self.vr(label, v) for v in values]
                if kind == "str":
                    values = [None if v is None else bytes.fromhex(v[1]) if isinstance(v, list)
                              else v.encode() for v in values]
                cargs.append((ctype * max(1, len(values)))(*values))
            elif isinstance(a, float):
                cargs.append(ctypes.c_double(a))
            elif isinstance(a, int):
                cargs.append(ctypes.c_size_t(a))   # nvr, nCategories, kinds, flags: 64-bit regs
            else:
                raise ValueError(f"raw argument {a!r}")
        fn = getattr(lib, function)
        fn.restype = None if function == "fmi2FreeInstance" else ctypes.c_int
        status = fn(ctypes.c_void_p(component), *cargs)
        values = [[v.decode("utf-8", "replace") if isinstance(v, bytes) else v
                   for v in list(arr)[:n]] for arr, n in outs]
        return {"status": status, "value": values[0] if len(values) == 1 else values}

    def op_get(self, label, names):
        status, values = self.get_by_name(label, names)
        return {"status": status, "value": values}

    def op_run(self, label, n):
        inst = self.inst[label]
        fmu, fmu_name = inst["slave"], inst["fmu"]
        statuses = []
        for _ in range(n):
            t = inst["time"]
            if fmu_name == "RailCarEstimator":
                statuses += self.set_by_name(label, estimator_inputs(round(t / STEP)))
            status = self.status_of(fmu.doStep, t, STEP)[0]
            statuses.append(status)
            if status == 0:
                inst["time"] = t + STEP
        status, values = self.get_by_name(label, OUTPUTS[fmu_name])
        statuses.append(status)
        return {"status": max(statuses), "statuses": statuses, "value": values,
                "time": inst["time"]}

    def run(self, steps):
        for step in steps:
            assert hasattr(self, "op_" + step[0]), f"unknown op {step[0]!r} in {step!r}"
            mark = len(self.log)
            record = getattr(self, "op_" + step[0])(*step[1:])
            record["op"] = step
            record["log"] = self.log[mark:]
            check_record(record)
            self.records.append(record)
            sys.stdout.flush()


FMI2_STATUSES = range(5)     # fmi2OK, Warning, Discard, Error, Fatal


def check_record(record: dict) -> None:
    """What no FMU may ever do, whatever the case: return or log a status that is not an
    fmi2Status (a garbage int from a broken binary). A failure ends the process without the
    CASE-RESULT marker, so the test fails naming this assertion."""
    statuses = record.get("statuses", [record.get("status")])
    for status in statuses:
        assert status is None or status in FMI2_STATUSES, f"{record['op']}: status {status!r}"
    for message in record["log"]:
        assert message[0] in FMI2_STATUSES, f"{record['op']}: logged status {message!r}"


def main() -> None:
    spec = json.loads(Path(sys.argv[1]).read_text())
    case = Case(spec["fmus"])
    case.run(spec["steps"])
    print("CASE-RESULT " + json.dumps(case.records))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
