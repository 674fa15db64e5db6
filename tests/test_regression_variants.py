"""The estimator options beyond the FMU's defaults, pinned to stored references (FMI cross-check
layout, tests/regression/variants/): station_day with every issue-5 option on at once, run on
the models chain (the FMU runs the same code; tests/fmu_tests/test_fmu_fmpy.py checks the options reach
it). The defaults run the C core (models/core via models/compiled.py) and are pinned by the
library's references (test_regression.py); these options run the Python chain, which nothing
else pins number by number. The variants are harness.run.regress.VARIANTS; the references hold
every RailCar output, with the tolerances of harness.run.regress.FLOAT_TOLERANCES (integers exact).

This module only checks; it never writes a reference. Checking and rewriting from the command line:
    python -m harness regress --variants [NAME ...]             check (as these tests do)
    python -m harness regress --variants --update [NAME ...]    rewrite after a deliberate change
"""
from __future__ import annotations

import pytest

from harness.__main__ import main
from harness.run import regress
from harness.run.regress import VARIANT_REFERENCES, VARIANTS, compare, run_variant


@pytest.fixture(scope="module")
def variant_results():
    return {name: run_variant(name) for name in VARIANTS}


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_matches_its_reference(variant_results, name):
    c = compare(variant_results[name], VARIANT_REFERENCES)
    assert c.ok, "\n".join(c.problems)


def test_the_variants_are_what_they_say(variant_results):
    """Each variant ran its own options (a different estimate from the other), under its own name."""
    a, b = (variant_results[n] for n in ("station_day_all_options", "station_day_coast_ekf"))
    assert a.scenario.name == "station_day_all_options" and b.scenario.name == "station_day_coast_ekf"
    assert abs(a["est.A0"][-1] - b["est.A0"][-1]) > 1e-6


def test_update_and_check_are_separate_commands(variant_results, tmp_path, monkeypatch, capsys):
    """--variants --update writes (here into a scratch folder), a second --update leaves every file
    byte-identical, and --variants checks against what was written; exit codes 0."""
    monkeypatch.setattr(regress, "VARIANT_REFERENCES", tmp_path)
    monkeypatch.setattr(regress, "run_variant", lambda name: variant_results[name])
    name = "station_day_coast_ekf"
    assert main(["regress", "--variants", "--update", name]) == 0
    assert capsys.readouterr().out.startswith(f"new {name}\n")
    written = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(written) == [f"{name}_in.csv", f"{name}_ref.csv", f"{name}_ref.opt"]
    assert main(["regress", "--variants", "--update", name]) == 0
    assert capsys.readouterr().out == f"unchanged {name} (3 files byte-identical)\n"
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == written
    assert main(["regress", "--variants", name]) == 0
    assert capsys.readouterr().out == f"ok   {name}\n"


def test_a_variant_reference_lacking_columns_says_the_variants_command(variant_results, tmp_path,
                                                                      monkeypatch):
    name = "station_day_all_options"
    for f in VARIANT_REFERENCES.glob(f"{name}_*"):
        (tmp_path / f.name).write_bytes(f.read_bytes())
    ref = tmp_path / f"{name}_ref.csv"
    lines = ref.read_text().splitlines()
    dropped = lines[0].rsplit(",", 1)[1].strip('"').split(" [")[0]   # the last column's output name
    ref.write_text("\n".join(line.rsplit(",", 1)[0] for line in lines) + "\n")   # drop the last column
    monkeypatch.setattr(regress, "VARIANT_REFERENCES", tmp_path)
    c = compare(variant_results[name], tmp_path)
    assert not c.ok
    assert (f"{name}: reference lacks columns {dropped}; regenerate with "
            f"python -m harness regress --variants --update {name}") in c.problems, c.problems


def test_an_unknown_variant_is_invalid_input(capsys):
    assert main(["regress", "--variants", "no_such_variant"]) == 2
    assert "unknown variant(s): no_such_variant" in capsys.readouterr().err
