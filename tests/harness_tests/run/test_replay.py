"""Replay: a RailCar run's log through RailCarEstimator, and log validation."""
from pathlib import Path

import numpy as np
import pytest

from harness.run.replay import LogError, read_log, write_log
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def default_run(built_fmus):
    with FmuRunner(built_fmus["RailCar"]) as runner:
        return runner.run(load_scenario(ROOT / "scenarios" / "default.toml"))


def test_replay_of_a_railcar_log_identifies_the_same_mass(built_fmus, default_run, tmp_path):
    """Same data, same algorithm: the mass agrees with RailCar's own estimate, with only the
    profiles and the sensor noise given (the other parameters the FMU's defaults, as the run's;
    the bit-for-bit replay with the run's parameters is below)."""
    path = write_log(tmp_path / "log.csv", default_run)
    log = read_log(path)
    s = default_run.scenario
    params = {n: s.parameter(n) for n in ("track.grade_profile", "track.speed_profile",
                                          "sensor.speed_std", "sensor.position_std")}
    with FmuRunner(built_fmus["RailCarEstimator"]) as runner:
        signals, _ = runner.replay(log, params)
    m_car = default_run["est.mass"][-1]
    assert signals["est.mass"][-1] == pytest.approx(m_car, rel=1e-3)
    assert abs(signals["est.mass"][-1] - 34.0) / 34.0 < 0.01
    # the replayed filter beats the raw sensor as RailCar's does
    v = default_run["car.speed"]
    assert np.sqrt(np.mean((signals["filter.speed"][1:] - v[1:]) ** 2)) < \
        np.sqrt(np.mean((log.columns["sensor.speed"] - v) ** 2))


def test_speed_in_kmh_is_converted_at_the_edge(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("time [s],traction_force [N],brake_force [N],sensor.speed [km/h],sensor.position [m]\n"
                 "0,0,0,36,0\n0.1,0,0,72,1\n")
    assert read_log(p).columns["sensor.speed"] == pytest.approx([10.0, 20.0], rel=1e-15)


@pytest.mark.parametrize("text,needle", [
    ("time,traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]\n0,0,0,0,0\n1,0,0,0,0\n",
     "line 1, column 1: header cell 'time' is not 'name [unit]'"),
    ("time [s],traction_force [N],brake_force [N],sensor.speed [m/s]\n0,0,0,0\n1,0,0,0\n",
     "missing column 'sensor.position [m]'"),
    ("time [s],traction_force [kN],brake_force [N],sensor.speed [m/s],sensor.position [m]\n0,0,0,0,0\n1,0,0,0,0\n",
     "column 'traction_force' must be in [N], got [kN]"),
    ("time [s],traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]\n0,0,0,0,0\n1,0,x,0,0\n",
     "line 3, column 'brake_force': not a number: 'x'"),
    ("time [s],traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]\n0,0,0,0,0\n0,0,0,0,0\n",
     "line 3: time must increase"),
])
def test_bad_logs_name_file_line_and_column(tmp_path, text, needle):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(LogError) as e:
        read_log(p)
    assert "bad.csv" in str(e.value) and needle in str(e.value)


def test_replay_cli_runs_and_writes_estimates(built_fmus, default_run, tmp_path, capsys):
    from harness.__main__ import main
    log = write_log(tmp_path / "log.csv", default_run)
    grade = default_run.scenario.parameter("track.grade_profile")
    rc = main(["replay", str(log), "--param", f"track.grade_profile={grade}", "--out", str(tmp_path / "o"),
               "--dist", str(built_fmus["RailCar"].parent)])
    assert rc == 0
    assert "mass error at the end" in capsys.readouterr().out
    header = (tmp_path / "o" / "estimates.csv").read_text().splitlines()[0]
    assert header.startswith("time [s],est.mass [t]")
    assert main(["replay", str(log), "--param", "no.such=1", "--dist", str(built_fmus["RailCar"].parent)]) == 2


# ------------------------------------------------------------------- replaying a run bit for bit

def chain_run_with_interval_forces(scenario):
    """``scenario`` on the models' Python chain (bit-identical to both RailCar FMUs), checking
    that its outputs harness.run.replay.INTERVAL_FORCES are, row by row, the forces its estimator
    was fed (0 at t = 0; row k + 1 holds the interval [t_k, t_k+1]'s means)."""
    from harness.run.driver import chain_result
    from harness.run.replay import INTERVAL_FORCES
    from models.chain import RailCarChain
    setup = scenario.setup.chain
    chain = RailCarChain(setup.config, setup.grade, setup.speed)
    fed = [(0.0, 0.0)]
    propagate = chain.estimator.propagate

    def recording(traction, brake, dt):
        fed.append((traction, brake))
        return propagate(traction, brake, dt)
    chain.estimator.propagate = recording
    result = chain_result(chain, scenario)
    assert len(fed) == len(result.time)           # one sample per row: step_s = sensor.sample_period
    for j, name in enumerate(INTERVAL_FORCES):
        assert result[name].tobytes() == np.array([f[j] for f in fed]).tobytes(), name
    return result


def read_estimates(path: Path) -> dict[str, np.ndarray]:
    lines = path.read_text().splitlines()
    names = [c.split(" [")[0] for c in lines[0].split(",")]
    rows = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    return {n: rows[:, j] for j, n in enumerate(names)}


def test_a_log_with_the_interval_forces_replays_to_the_runs_estimates_bit_for_bit(built_fmus, tmp_path, capsys):
    """The log carries what the run's estimator saw: the measurements and forces in full
    precision, the estimator's parameters beside it, the uniform step. The replay on the native
    RailCarEstimator then gives the run's every est.* bit for bit, one row later (it outputs at
    row k + 1 what it identified from the samples up to row k). filter.* are close, not equal:
    the replay's is the one-step prediction, the run's the posterior."""
    from harness.__main__ import main
    from harness.run.replay import RUN_ESTIMATES, read_log_parameters
    run = chain_run_with_interval_forces(load_scenario(ROOT / "scenarios" / "default.toml"))
    log = write_log(tmp_path / "run.csv", run)
    items, forces = read_log_parameters(log)
    assert forces == "interval_mean" and "sensor.speed_std=0.05" in items and len(items) == 37
    dist = str(built_fmus["RailCar"].parent)
    assert main(["replay", str(log), "--out", str(tmp_path / "o"), "--dist", dist, "--fmu", "native"]) == 0
    out = capsys.readouterr().out
    assert "parameters: run.params (37), then --param" in out
    assert "est.* vs the run's own  bit for bit" in out, out
    replayed = read_estimates(tmp_path / "o" / "estimates.csv")
    for name in RUN_ESTIMATES:
        assert replayed[name][1:].tobytes() == run[name][:-1].tobytes(), name
    prediction, posterior = replayed["filter.speed"][1:], run["filter.speed"][:-1]
    assert not np.array_equal(prediction, posterior)
    assert np.sqrt(np.mean((prediction - posterior) ** 2)) < 0.05      # [m/s]: the same filter
    # control: a parameter that differs from the run's (--param overrides the log's) breaks it
    assert main(["replay", str(log), "--out", str(tmp_path / "p"), "--dist", dist, "--fmu", "native",
                 "--param", "est.batch_size=49"]) == 0
    assert "not bit for bit" in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["native", "python"])
def test_a_railcar_fmu_runs_log_replays_to_its_estimates_bit_for_bit(built_fmus, tmp_path, capsys, kind):
    """`harness run SCEN --log LOG` then `harness replay LOG`, both on the FMUs of one kind:
    RailCar outputs the forces its estimator was fed (INTERVAL_FORCES), the log carries them, and
    RailCarEstimator gives the run's every est.* bit for bit one row later, which the replay says."""
    from harness.__main__ import main
    from harness.run.replay import RUN_ESTIMATES, read_log_parameters
    dist, log = str(built_fmus["RailCar"].parent), tmp_path / "run" / "log.csv"
    assert main(["run", str(ROOT / "scenarios" / "default.toml"), "--out", str(tmp_path / "run"),
                 "--log", str(log), "--dist", dist, "--fmu", kind]) == 0
    assert read_log_parameters(log)[1] == "interval_mean"
    run = read_log(log).columns
    assert run["traction_force"][0] > 0.0 and run["brake_force"].max() > 0.0   # it drove and braked
    capsys.readouterr()
    assert main(["replay", str(log), "--out", str(tmp_path / "o"), "--dist", dist, "--fmu", kind]) == 0
    out = capsys.readouterr().out
    assert f"fmu: {kind}" in out and "est.* vs the run's own  bit for bit" in out, out
    replayed = read_estimates(tmp_path / "o" / "estimates.csv")
    assert len(replayed["est.mass"]) == len(run["est.mass"]) > 1000
    for name in RUN_ESTIMATES:
        assert replayed[name][1:].tobytes() == run[name][:-1].tobytes(), name
    assert replayed["est.mass"][-1] != replayed["est.mass"][1]       # identified, not the prior


def test_a_run_without_the_interval_forces_says_why_its_replay_differs(built_fmus, default_run, tmp_path, capsys):
    """A run result without INTERVAL_FORCES (a RailCar FMU built before them) is logged with the
    forces at the next row, and the replay says that this is why its est.* are not the run's."""
    from dataclasses import replace

    from harness.__main__ import main
    from harness.run.replay import INTERVAL_FORCES
    assert all(n in default_run.signals for n in INTERVAL_FORCES)
    older = replace(default_run, signals={n: x for n, x in default_run.signals.items()
                                          if n not in INTERVAL_FORCES})
    log = write_log(tmp_path / "log.csv", older)
    assert "# forces: next_row" in (tmp_path / "log.params").read_text(encoding="utf-8")
    assert main(["replay", str(log), "--out", str(tmp_path / "o"), "--dist", str(built_fmus["RailCar"].parent),
                 "--fmu", "native"]) == 0
    out = capsys.readouterr().out
    assert "est.* vs the run's own  not bit for bit" in out
    assert "the run recorded no car.traction_force_mean / car.brake_force_mean" in out
