"""One `harness run` from the TOML to the report, counted: the scenario resolved once (no chain
built to check it), the model run once on the FMU and once as the oracle filter, never for a
plot; a span scenario's ATO log goes into the result and the run's own output, naming the
scenario, never to stderr. Counted by wrapping the constructors (the native FMU runs in C, so
every Python estimator built in this process is the harness's own)."""
from __future__ import annotations

import functools
import re
from pathlib import Path

import pytest

import models.ato.controller
import models.chain
import models.compiled
import models.batch
import models.estimation.online
from harness.__main__ import main
from harness.run import runner as runner_module
from harness.run import scenario as scenario_module

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def counts(monkeypatch) -> dict:
    """How many of each thing the process builds from here on."""
    seen: dict = {}

    def count(owner, name, key):
        original = getattr(owner, name)

        @functools.wraps(original)
        def counted(*args, **kwargs):
            seen[key] = seen.get(key, 0) + 1
            return original(*args, **kwargs)
        monkeypatch.setattr(owner, name, counted)

    count(runner_module.FmuRunner, "_instantiate", "fmu instance")
    count(models.chain.RailCarChain, "__init__", "python chain")
    count(models.compiled, "open_chain", "chain opened")
    count(models.estimation.online.OnlineEstimator, "__init__", "estimator")
    count(models.batch, "oracle_filter", "oracle")
    count(models.compiled, "validate", "configuration checked")
    count(scenario_module, "resolve_setup", "setup resolved")
    count(models.ato.controller.AtoController, "__init__", "ATO controller")
    return seen


def test_one_run_runs_the_model_twice_fmu_and_oracle(built_fmus, counts, tmp_path, capsys):
    dist = Path(built_fmus["RailCar"]).parent
    assert main(["run", str(ROOT / "scenarios" / "default.toml"), "--out", str(tmp_path),
                 "--dist", str(dist), "--fmu", "native"]) == 0
    assert counts == {"setup resolved": 1, "configuration checked": 1, "fmu instance": 1, "oracle": 1}
    assert (tmp_path / "summary.md").is_file()


def test_a_span_scenario_logs_into_its_result_naming_it(built_fmus, counts, tmp_path, capsys):
    """ato_speed_noise with the paper's estimator (est.method 0): the ATO's blend gives the
    estimates no weight once (their resistance lies sigmas from the configured car's under the
    speed noise). The line is in the run's output and summary.md with the scenario's name, not on
    stderr; the controllers are built once to check the file and once for the run (one span)."""
    dist = Path(built_fmus["RailCar"]).parent
    library = ROOT / "scenarios" / "library"
    path = tmp_path / "ato_speed_noise.toml"
    path.write_text((library / "ato_speed_noise.toml").read_text()
                    .replace('"../profiles/', f'"{library.parent / "profiles"}/')
                    .replace("[parameters]\n", '[parameters]\n"est.method" = 0\n'))
    assert main(["run", str(path), "--out", str(tmp_path), "--dist", str(dist), "--fmu", "native"]) == 0
    cap = capsys.readouterr()
    assert "ATO at t" not in cap.err
    [line] = [x for x in cap.out.splitlines() if "ATO at t" in x]
    said = re.fullmatch(r"log: ato_speed_noise: span 1: ATO at t = (\d+\.\d\d) s: est\.A0\.\.A2 lie "
                        r"\d+\.\d stated sigmas from the configured resistance: no weight for est\.\*",
                        line.strip())
    assert said, line
    assert (f"ato_speed_noise: span 1: ATO at t = {said.group(1)} s"
            in (tmp_path / "summary.md").read_text(encoding="utf-8"))
    assert counts == {"setup resolved": 1, "configuration checked": 1, "fmu instance": 1, "oracle": 1,
                      "ATO controller": 2}


def test_library_commands_keep_the_ato_log_off_stderr(built_fmus, tmp_path, capsys):
    """`report` (the library table) prints no ATO log line: it stays in each result."""
    dist = Path(built_fmus["RailCar"]).parent
    assert main(["report", "ato_speed_noise", "--out", str(tmp_path), "--dist", str(dist)]) == 0
    cap = capsys.readouterr()
    assert "ATO at t" not in cap.err and "ATO at t" not in cap.out
    assert "ato_speed_noise" in cap.out
