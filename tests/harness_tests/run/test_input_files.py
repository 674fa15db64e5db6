"""Every file a user names to the harness (a scenario, a profile, a demand table, a replay log,
a sweep's base scenario) is checked by os.stat before it is opened (harness.textio.read_bytes):
a FIFO is refused by name and never opened (opening it would wait for a writer for ever), a
file over the bound is refused with its size, a folder is named as one. The FIFO tests run
inside conftest's fifo_released: a reader that opened the FIFO would be let go there and the
test fails on it instead of hanging.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from conftest import fifo_released
from harness.run.replay import read_log
from harness.run.scenario import ScenarioError, load_scenario
from harness.sweep.spec import SweepError, load_sweep
from harness.textio import InputError, read_bytes, read_text

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture()
def fifo(tmp_path) -> Path:
    p = tmp_path / "pipe.csv"
    os.mkfifo(p)
    return p


def test_a_fifo_is_refused_by_name_unopened(fifo):
    with fifo_released(fifo) as opened:
        with pytest.raises(InputError) as e:
            read_text(fifo)
    assert str(e.value) == f"{fifo}: it is a FIFO, not a regular file"
    assert not opened                      # no reader had to be let go


def test_a_file_over_the_bound_and_a_folder_are_refused(tmp_path):
    p = tmp_path / "big.csv"
    p.write_bytes(b"x" * 101)
    assert read_bytes(p, limit=101) == b"x" * 101
    with pytest.raises(InputError, match=r"big.csv: it has 101 bytes, more than the 100 bytes \(9.53674e-05 MiB\)"):
        read_bytes(p, limit=100)
    with pytest.raises(InputError, match="is a folder, not a file"):
        read_text(tmp_path)
    with pytest.raises(InputError, match="cannot read: No such file"):
        read_text(tmp_path / "missing.csv")


def test_a_scenario_a_profile_a_log_and_a_sweep_base_that_are_fifos(fifo, tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(f'name = "s"\n[parameters]\n"track.grade_profile" = "{fifo.as_posix()}"\n'
                        f'[[driver]]\naction = "coast"\nfor_s = 1.0\n', encoding="utf-8")
    sweep = tmp_path / "w.toml"
    sweep.write_text(f'scenario = "{fifo.as_posix()}"\nseeds = 2\n', encoding="utf-8")
    with fifo_released(fifo) as opened:
        with pytest.raises(ScenarioError, match=r'parameters."track.grade_profile": .*pipe.csv: it is a FIFO, '
                                                r'not a regular file'):
            load_scenario(scenario)
        with pytest.raises(ScenarioError, match="pipe.csv: it is a FIFO, not a regular file"):
            load_scenario(fifo)
        with pytest.raises(InputError, match="pipe.csv: it is a FIFO, not a regular file"):
            read_log(fifo)
        with pytest.raises(SweepError, match=r"w.toml: scenario: .*pipe.csv: it is a FIFO, not a regular file"):
            load_sweep(sweep)
    assert not opened


def test_a_fifo_on_the_command_line_is_one_line_and_exit_code_2(fifo, capsys):
    from harness.__main__ import main
    with fifo_released(fifo) as opened:
        assert main(["span-info", str(fifo)]) == 2
        assert main(["replay", str(fifo)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {fifo}: it is a FIFO, not a regular file"] * 2
    assert not opened
