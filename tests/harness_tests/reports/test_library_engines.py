"""``python -m harness report --engine fmu|batch|auto`` (harness/reports/library_report.py, issue 31).

- the table is the same string whichever engine ran the library (the FMU or the C batch engine),
  but for the line naming the engine: over the whole library (slow: it builds and runs the FMUs);
- ``--engine batch`` runs no FMU (none is built); a scenario the C core does not cover is refused
  (exit 2) naming its file and the setting; ``--engine batch --fmu ...`` is refused (exit 2);
- ``auto`` takes the batch engine where the core covers the scenario and the FMU elsewhere, and
  the FMU for all when a --fmu is given; each row records its engine and library.md names it;
- a run the batch engine hands to run_on_chain (the C core switched off) is labelled the Python
  reference, not the C engine.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from harness.__main__ import _run_batch_each, main
from harness.reports.library_report import (ENGINE_BATCH, ENGINE_FMU, ENGINE_REFERENCE, EngineChoice, Row,
                                            choose_engines, engine_choice_lines, engine_line, ran_on_line)
from harness.run.regress import library_scenarios
from harness.run.scenario import load_scenario
from harness.textio import InputError

ROOT = Path(__file__).resolve().parents[3]
LEVEL_RUN = ROOT / "scenarios" / "library" / "level_run.toml"
ENGINE_LINE_PREFIXES = ("FMU (python -m harness report", "Engine (python -m harness report")


def cut_level_run(folder: Path, name: str, parameters: str = "") -> Path:
    """level_run cut to 60 s, named ``name``, with ``parameters`` (TOML lines) added to its [parameters]."""
    text = LEVEL_RUN.read_text(encoding="utf-8")
    for part in ('name = "level_run"', "duration_s = 400.0", "[parameters]\n"):
        assert part in text, f"level_run.toml no longer has {part!r}: update the test"
    text = (text.replace('name = "level_run"', f'name = "{name}"').replace("duration_s = 400.0", "duration_s = 60.0")
            .replace("[parameters]\n", f"[parameters]\n{parameters}"))
    path = folder / f"{name}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def use_library(monkeypatch, paths: list[Path]) -> None:
    """The report's library is ``paths`` (harness.run.regress.library_scenarios, read per command)."""
    monkeypatch.setattr("harness.run.regress.library_scenarios", lambda: list(paths))


def table_lines(out: str) -> list[str]:
    """The printed report without the lines naming what ran (engine:, fmu:) and where it wrote."""
    return [line for line in out.splitlines() if not line.startswith(("engine: ", "fmu: ", "table: "))]


# ------------------------------------------------------------------------------ choosing

def test_choose_engines_for_each_engine_and_fmu(tmp_path):
    covered = load_scenario(LEVEL_RUN)
    method3 = load_scenario(cut_level_run(tmp_path, "method3", '"est.method" = 3\n'))
    both = [covered, method3]
    assert choose_engines(both, "fmu") == {s.name: EngineChoice(ENGINE_FMU, "--engine fmu") for s in both}
    auto = choose_engines(both, "auto")
    assert auto[covered.name] == EngineChoice(ENGINE_BATCH, "--engine auto: the C core covers it")
    assert auto[method3.name].engine == ENGINE_FMU and "est.method 1 or 3" in auto[method3.name].why
    assert {c.engine for c in choose_engines(both, "auto", "native").values()} == {ENGINE_FMU}
    assert choose_engines([covered], "batch") == {covered.name: EngineChoice(ENGINE_BATCH, "--engine batch")}
    with pytest.raises(InputError) as refused:
        choose_engines(both, "batch")
    message = str(refused.value)
    assert str(method3.path) in message and "est.method 1 or 3" in message and str(LEVEL_RUN) not in message
    with pytest.raises(InputError, match="--fmu python .* --engine batch runs no FMU"):
        choose_engines([covered], "batch", "python")
    with pytest.raises(InputError, match="--engine fast: expected one of auto, batch, fmu"):
        choose_engines([covered], "fast")
    lines = engine_choice_lines(auto)
    assert lines[0] == f"engine: batch for {covered.name} (--engine auto: the C core covers it)"
    assert lines[1].startswith(f"engine: fmu for {method3.name} (--engine auto: the C batch engine does not")
    assert engine_choice_lines(choose_engines(both, "fmu")) == ["engine: fmu for all 2 scenarios (--engine fmu)"]


def test_engine_line_names_what_ran_each_row():
    def row(name, engine, fmu=""):
        return Row(name, 0.05, None, "not run here", fmu=fmu, engine=engine)
    fmus = [row("a", ENGINE_FMU, "native"), row("b", ENGINE_FMU, "native")]
    assert ran_on_line(fmus) == "FMU (python -m harness report --fmu): native for all 2 scenarios."
    batch = [row("a", ENGINE_BATCH), row("b", ENGINE_BATCH)]
    assert ran_on_line(batch) == "Engine (python -m harness report --engine): C batch engine for all 2 scenarios."
    mixed = [row("a", ENGINE_BATCH), row("b", ENGINE_FMU, "python"), row("c", ENGINE_BATCH),
             row("d", ENGINE_REFERENCE)]
    assert engine_line(mixed) == ("C batch engine: a, c; python FMU: b; Python reference (run_on_chain): d")
    assert ran_on_line(mixed).startswith("Engine (python -m harness report --engine): C batch engine: a, c;")


# ------------------------------------------------------------------------------ the command, no FMU

def test_batch_engine_runs_the_report_without_an_fmu(tmp_path, capsys):
    dist = tmp_path / "no_dist"            # never built: the batch engine runs no FMU
    assert main(["report", "level_run", "ato_nominal", "--engine", "batch", "--dist", str(dist),
                 "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "engine: batch for all 2 scenarios (--engine batch)" in out.splitlines()
    assert not any(line.startswith("fmu: ") for line in out.splitlines()) and not dist.exists()
    assert "level_run" in out and "ATO, per span:" in out
    md = (tmp_path / "out" / "library.md").read_text(encoding="utf-8").splitlines()
    assert "Engine (python -m harness report --engine): C batch engine for all 2 scenarios." in md


def test_batch_engine_refuses_an_uncovered_scenario_by_name(tmp_path, monkeypatch, capsys):
    method3 = cut_level_run(tmp_path, "method3", '"est.method" = 3\n')
    use_library(monkeypatch, [LEVEL_RUN, method3])
    dist = tmp_path / "no_dist"
    assert main(["report", "--engine", "batch", "--dist", str(dist), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --engine batch: the C batch engine does not cover {method3}: "
                                               f"est.method 1 or 3"), err
    assert not dist.exists() and not (tmp_path / "out" / "library.md").exists()


@pytest.mark.parametrize("fmu", ["python", "native", "auto"])
def test_batch_engine_with_an_fmu_is_refused(tmp_path, capsys, fmu):
    assert main(["report", "level_run", "--engine", "batch", "--fmu", fmu, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: --fmu {fmu} picks the FMU of --engine fmu; --engine batch runs no FMU (whole runs "
                   f"in the C core): give one of the two"]


def test_a_run_handed_to_the_python_reference_is_labelled_so(tmp_path, monkeypatch):
    scenario = load_scenario(cut_level_run(tmp_path, "short"))
    (_, covered, engine), = _run_batch_each([scenario])
    assert engine == ENGINE_BATCH and covered.fmu == ""
    monkeypatch.setenv("RAILCAR_PURE_PYTHON", "1")      # run_batch falls back to run_on_chain
    (_, reference, engine), = _run_batch_each([scenario])
    assert engine == ENGINE_REFERENCE
    assert reference["est.mass"].tobytes() == covered["est.mass"].tobytes()   # the same run, bit for bit


# ------------------------------------------------------------------------------ with the FMUs

@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return Path(built_fmus["RailCar"]).parent


@pytest.mark.slow
def test_the_whole_library_gives_one_table_on_either_engine(dist, tmp_path, capsys):
    printed, written, codes = {}, {}, {}
    for engine in ("fmu", "batch"):
        codes[engine] = main(["report", "--engine", engine, "--dist", str(dist), "--out", str(tmp_path / engine)])
        printed[engine] = capsys.readouterr().out
        written[engine] = (tmp_path / engine / "library.md").read_text(encoding="utf-8").splitlines()
    names = [p.stem for p in library_scenarios()]
    assert len(names) >= 19
    assert codes["fmu"] == codes["batch"]
    assert table_lines(printed["fmu"]) == table_lines(printed["batch"])
    body = [line for line in table_lines(printed["batch"]) if line.split(" ", 1)[0] in names]
    assert {line.split(" ", 1)[0] for line in body} == set(names)            # every scenario has its row
    assert "engine: fmu for all" in printed["fmu"] and "engine: batch for all" in printed["batch"]
    assert ([x for x in written["fmu"] if not x.startswith(ENGINE_LINE_PREFIXES)]
            == [x for x in written["batch"] if not x.startswith(ENGINE_LINE_PREFIXES)])
    assert f"Engine (python -m harness report --engine): C batch engine for all {len(names)} scenarios." \
        in written["batch"]
    assert f"FMU (python -m harness report --fmu): native for all {len(names)} scenarios." in written["fmu"]


@pytest.mark.slow
def test_auto_runs_the_uncovered_scenario_on_the_fmu(dist, tmp_path, monkeypatch, capsys):
    short, method3 = cut_level_run(tmp_path, "short"), cut_level_run(tmp_path, "method3", '"est.method" = 3\n')
    use_library(monkeypatch, [short, method3])
    code = main(["report", "--engine", "auto", "--dist", str(dist), "--out", str(tmp_path / "out")])
    assert code == 0                                # both cut runs meet the targets on either engine
    out = capsys.readouterr().out.splitlines()
    assert "engine: batch for short (--engine auto: the C core covers it)" in out
    assert [x for x in out if x.startswith("fmu: ")] == [
        f"fmu: python {dist / 'RailCar.fmu'} for method3 (--fmu auto: {method3} sets est.method = 3, which the "
        f"native FMU does not cover)"]
    md = (tmp_path / "out" / "library.md").read_text(encoding="utf-8").splitlines()
    assert "Engine (python -m harness report --engine): C batch engine: short; python FMU: method3." in md
    rows = [x.split(" | ")[0] for x in md if x.startswith("| short") or x.startswith("| method3")]
    assert rows == ["| short", "| method3"]                       # the library's order, whichever ran it
