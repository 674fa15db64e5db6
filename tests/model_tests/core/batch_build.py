"""Building models._batch from the C core with one or more sources replaced (a one-ulp mutation),
for the tests that show the bit-identity tests catch it (test_core_run_metrics.py,
test_core_scenario_driver.py): the other sources compiled once per module, then linked with the
replaced ones and imported from their folder."""
from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sysconfig
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
FLAGS = ["-std=c99", "-O1", "-ffp-contract=off", "-fno-fast-math", "-fPIC", "-Wall", "-Wextra",
         "-Werror"]
ONE_ULP = "(1.0 + 2.220446049250313e-16)"


def gcc() -> str:
    path = shutil.which("gcc")
    assert path, "gcc is needed (it builds the C core on every supported machine)"
    return path


def compile_objects(directory: Path, excluded: tuple[Path, ...]) -> list[Path]:
    """The batch binding and every core source but ``excluded``, compiled into ``directory``."""
    sources = [ROOT / "models" / "_batch.c", *(p for p in sorted(CORE.glob("*.c")) if p not in excluded)]
    proc = subprocess.run([gcc(), *FLAGS, f"-I{sysconfig.get_paths()['include']}", f"-I{CORE}", "-c",
                           *map(str, sources)], cwd=directory, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return sorted(directory.glob("*.o"))


def build_batch(objects: list[Path], sources: dict[str, str], directory: Path, extra_flags=()):
    """models._batch linked from ``objects`` and ``sources`` (core file name -> its text),
    imported from ``directory`` (made here)."""
    directory.mkdir()
    paths = []
    for name, text in sources.items():
        paths.append(directory / name)
        paths[-1].write_text(text)
    so = directory / f"_batch{sysconfig.get_config_var('EXT_SUFFIX')}"
    proc = subprocess.run([gcc(), *FLAGS, *extra_flags, "-shared", f"-I{CORE}", *map(str, paths),
                           *map(str, objects), "-lm", "-o", str(so)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    spec = importlib.util.spec_from_file_location("_batch", so)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
