"""A line as a system: ``python -m harness system build`` of scenarios/library/ato_line.toml (three
spans, 30 s dwells, boarding 4 t then -2 t) and the AtoController FMU's line parameters.

- the built system (RailCarNative <-> AtoController, the ATO stepping first; the line's CSVs
  made at build and packed, ato.payload -> car.payload, est.station_stops -> the ATO) run in
  our master is the harness's run of the scenario (``python -m harness run``, the same
  models.ato.line.LineController): the same trajectory to 1e-9 while the harness runs, the same
  per-span ATO metrics to 1e-9, printed alike by ``system run``;
- a bad line file (line.profile, line.speed_limit_profile) fails the FMU's initialisation with
  a message naming the parameter, the file and the line; a file that is no regular file or is
  too big is refused by stat, before it is opened.
"""
from __future__ import annotations

import os
import zipfile

import numpy as np
import pytest

from conftest import ERROR, OK, ROOT, STATUS_LABEL
from harness.metrics.ato import ato_metrics, format_ato
from harness.systems.ato_run import system_ato_metrics
from harness.systems.cli import main
from harness.systems.ssp import PACKED_DIR, Connection
from harness.systems.ssp_read import read_ssp
from models.units import kmh_to_mps
from test_ssp_span_build import dist, system_and_harness_runs  # noqa: F401  (dist: a fixture)

LINE = ROOT / "scenarios" / "library" / "ato_line.toml"
TRAJECTORY = {"car.position": "car.car.position", "car.speed": "car.car.speed",
              "filter.position": "car.filter.position", "est.mass": "car.est.mass",
              "car.total_mass": "car.car.total_mass", "est.station_stops": "car.est.station_stops"}
STEP = 0.1     # [s]


@pytest.fixture(scope="module")
def line(dist, tmp_path_factory):
    return system_and_harness_runs(LINE, tmp_path_factory.mktemp("line_build") / "ato_line.ssp", dist,
                                   [*TRAJECTORY.values(), "ato.ato.payload"])


def test_the_line_system_is_the_harness_run(line):
    """Trajectory (truth, filter, estimates, the boarded mass, the station count) within 1e-9
    of the harness's over the harness's rows, the demands the harness applied equal to the
    ATO's one row later (it steps first), and the three spans' metrics within 1e-9."""
    ssp, ours, harness, scenario = line
    system = read_ssp(ssp)
    assert system.spec.step_order == ("ato", "car") and system.spec.stop == scenario.duration_s
    n = len(harness.time)                     # the harness stops once the last span is finished
    assert 3500 < n <= len(ours.time)
    assert np.max(np.abs(ours.time[:n] - harness.time)) < 1e-9
    for name, full in TRAJECTORY.items():
        x, y = np.asarray(harness[name], dtype=float), np.asarray(ours[full], dtype=float)[:n]
        assert np.max(np.abs(x - y)) <= 1e-9, f"{name}: {np.max(np.abs(x - y))}"
    assert float(ours["car.car.total_mass"][-1]) == pytest.approx(30.0 + 4.0 - 2.0, abs=1e-12)
    for name in ("traction_force_demand", "brake_force_demand"):
        applied, ato = harness.inputs[name][:n - 1], np.asarray(ours[f"ato.{name}"])[1:n]
        assert np.max(np.abs(applied - ato)) <= 1e-6, name
    want = ato_metrics(scenario, harness, harness.driver_steps)
    got = system_ato_metrics(system, ours)
    assert len(got) == len(want) == 3
    assert format_ato(got) == format_ato(want)
    for g, w in zip(got, want):
        assert g.arrived and w.arrived and g.interventions == w.interventions == 0
        assert abs(g.departure_s - w.departure_s) <= 1e-9, g.span
        for field in ("arrival_error_s", "stop_error_m", "energy_kwh", "margin_mps"):
            assert abs(getattr(g, field) - getattr(w, field)) <= 1e-9, (g.span, field)


def test_the_line_is_packed_and_connected(line):
    """line.profile holds spans 2 and 3 (stop, length, schedule, dwell, boarding: the scenario's
    doubles), line.speed_limit_profile their limits in m/s; ato.payload drives car.payload and
    est.station_stops reaches the ATO."""
    ssp, *_ = line
    system = read_ssp(ssp)
    ato = system.spec.components[1].parameters
    assert Connection("ato.ato.payload", "car.car.payload") in system.spec.connections
    assert Connection("car.est.station_stops", "ato.est.station_stops") in system.spec.connections
    with zipfile.ZipFile(ssp) as z:
        assert ato["line.profile"].startswith(PACKED_DIR)
        spans = z.read(ato["line.profile"]).decode().splitlines()
        limits = z.read(ato["line.speed_limit_profile"]).decode().splitlines()
    assert spans[1] == "stop_m,length_m,schedule_s,dwell_s,boarding_t"
    assert [tuple(float(x) for x in r.split(",")) for r in spans[2:]] == \
        [(1400.0, 1400.0, 100.0, 30.0, 4.0), (1800.0, 1800.0, 120.0, 30.0, -2.0)]
    assert limits[1] == "span,distance_m,speed_limit_mps"
    assert [tuple(float(x) for x in r.split(",")) for r in limits[2:]] == \
        [(2.0, 0.0, kmh_to_mps(70)), (3.0, 0.0, kmh_to_mps(80)), (3.0, 600.0, kmh_to_mps(70))]


def test_system_run_prints_the_lines_metrics(line, capsys):
    ssp, _, harness, scenario = line
    capsys.readouterr()
    assert main(["run", str(ssp), "--output", "ato.ato.span"]) == 0
    out = capsys.readouterr().out
    assert format_ato(ato_metrics(scenario, harness, harness.driver_steps)) in out
    assert "ato.ato.span  3" in out


# ------------------------------------------------------------------ the FMU's line parameters

SPAN1 = {"span.stop": 900.0, "span.length": 950.0, "span.schedule": 80.0}
GOOD_LINE = "stop_m,length_m,schedule_s,dwell_s,boarding_t\n700,0,70,30,4\n"


def _initialise(ato_fmu, slave_factory, values: dict) -> tuple[int, str]:
    s = slave_factory(ato_fmu)
    s.setup(values)
    status = s.exit_init()
    return status, s.log_text()


def test_a_good_line_initialises_and_one_span_stays_the_default(ato_fmu, slave_factory, tmp_path):
    """A line file of one more span initialises; its outputs start at span 1, no payload; the
    default (no line.profile) is one span, as before."""
    (tmp_path / "line.csv").write_text(GOOD_LINE)
    for values in (SPAN1, dict(SPAN1, **{"line.profile": str(tmp_path / "line.csv")})):
        s = slave_factory(ato_fmu)
        s.initialize(values)
        assert (s.get("ato.span"), s.get("ato.payload"), s.get("ato.mode")) == (1, 0.0, 8)
        assert s.do_step(0.0, STEP) == OK, s.log_text()
        assert s.get("ato.span") == 1 and s.get("traction_force_demand") > 0.0


@pytest.mark.parametrize("name, text, words", [
    ("line.profile", "stop,length_m,schedule_s,dwell_s,boarding_t\n700,0,70,30,4\n",
     ["line 1: header must be 'stop_m,length_m,schedule_s,dwell_s,boarding_t'"]),
    ("line.profile", GOOD_LINE + "# next\n800,0,fast,30,0\n", ["line 4: not a number"]),
    ("line.profile", GOOD_LINE + "800,0,80,0,0\n", ["line 3: dwell_s must be > 0"]),
    ("line.profile", GOOD_LINE + "800,700,80,30,0\n", ["line 3: length_m = 700.0 m is shorter"]),
    ("line.profile", GOOD_LINE + "800,0,80,30\n", ["line 3: expected 5 values"]),
    ("line.profile", GOOD_LINE + "800,0,nan,30,0\n", ["line 3: non-finite value"]),
    ("line.profile", GOOD_LINE + "1800,0,20,30,0\n", ["line 3 (span 3): the ATO cannot run this span"]),
    ("line.profile", "stop_m,length_m,schedule_s,dwell_s,boarding_t\n", ["no span"]),
    ("line.speed_limit_profile", "span,distance_m,speed_limit_mps\n3,0,20\n",
     ["line 2: span must be one of line.profile's spans, 2 .. 2, got 3"]),
    ("line.speed_limit_profile", "span,distance_m,speed_limit_mps\n2,10,20\n",
     ["line 2: span 2's first limit must start at distance_m 0"]),
    ("line.speed_limit_profile", "span,distance_m,speed_limit_mps\n2,0,20\n2,0,15\n",
     ["line 3: distance_m must increase"]),
    ("line.speed_limit_profile", "span,distance_m,speed_limit_mps\n2,0,-1\n",
     ["line 2: speed_limit_mps must be > 0"]),
])
def test_a_bad_line_file_is_refused_naming_parameter_file_and_line(ato_fmu, slave_factory, tmp_path,
                                                                  name, text, words):
    (tmp_path / "line.csv").write_text(GOOD_LINE)
    (tmp_path / "bad.csv").write_text(text)
    values = dict(SPAN1, **{"line.profile": str(tmp_path / "line.csv"), name: str(tmp_path / "bad.csv")})
    status, log = _initialise(ato_fmu, slave_factory, values)
    assert status == ERROR, f"exitInitializationMode -> {STATUS_LABEL[status]}\n{log}"
    for w in [f"{name}: {tmp_path / 'bad.csv'}: "] + words:
        assert w in log, f"{w!r} not in the log:\n{log}"


@pytest.mark.parametrize("kind", ["folder", "fifo", "too big", "missing"])
def test_a_line_file_that_is_no_regular_file_is_refused_by_stat(ato_fmu, slave_factory, tmp_path, kind):
    """A folder, a FIFO (opening it would wait for ever), a file over 16 MiB (sparse: no bytes
    written) or a missing file: refused naming line.profile before any read."""
    path = tmp_path / "line.csv"
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "too big":
        with open(path, "wb") as f:
            f.truncate(16 * 1024 * 1024 + 1)
    status, log = _initialise(ato_fmu, slave_factory, dict(SPAN1, **{"line.profile": str(path)}))
    assert status == ERROR
    expected = {"folder": "it is a folder, not a regular file", "fifo": "it is a FIFO, not a regular file",
                "too big": "more than the 16777216 bytes (16 MiB)", "missing": "cannot read"}[kind]
    assert f"line.profile: cannot read '{path}'" in log and expected in log, log


def test_line_limits_without_a_line_are_refused(ato_fmu, slave_factory, tmp_path):
    (tmp_path / "limits.csv").write_text("span,distance_m,speed_limit_mps\n2,0,20\n")
    status, log = _initialise(ato_fmu, slave_factory,
                              dict(SPAN1, **{"line.speed_limit_profile": str(tmp_path / "limits.csv")}))
    assert status == ERROR and "given without line.profile" in log, log
