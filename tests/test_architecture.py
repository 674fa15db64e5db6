"""The layers of docs/architecture.md, read from the sources' imports (every import, also those
inside functions): no import circle between modules, and no module imports a layer above its own.

models <- fmu_src <- harness <- studies, benchmarks; inside models and harness the packages are
layered too (ALLOWED below, the same table as docs/architecture.md). A new package or an upward
import fails here with the importing file and line.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOP = ("models", "fmu_src", "harness", "studies", "benchmarks")

# What each part may import besides itself (and the standard library / third-party packages).
# A part is a top-level package or one of its sub-packages; a module directly in a top-level
# package (models/units.py, harness/textio.py) is its package's base part, "models" or "harness".
ALLOWED = {
    "models": set(),
    "models.plant": {"models"},
    "models.filtering": {"models", "models.plant"},
    "models.estimation": {"models", "models.plant", "models.filtering"},
    "models.planning": {"models", "models.plant"},
    "models.ato": {"models", "models.plant", "models.planning"},
    # the composition layer of models: the chain and its C core binding (models/chain.py, compiled.py)
    "models.chain": {"models", "models.plant", "models.filtering", "models.estimation"},
    "fmu_src": {"models*"},
    "fmu_src.build": {"models*", "fmu_src"},
    "harness": {"models*", "fmu_src*"},
    "harness.run": {"models*", "fmu_src*", "harness"},
    "harness.metrics": {"models*", "fmu_src*", "harness", "harness.run"},
    "harness.reports": {"models*", "fmu_src*", "harness", "harness.run", "harness.metrics"},
    "harness.sweep": {"models*", "fmu_src*", "harness", "harness.run", "harness.metrics", "harness.reports"},
    "harness.systems": {"models*", "fmu_src*", "harness", "harness.run", "harness.metrics"},
    "harness.cli": {"models*", "fmu_src*", "harness*"},
    "studies": {"models*", "fmu_src*", "harness*", "studies"},
    "benchmarks": {"models*", "fmu_src*", "harness*", "benchmarks"},
}
COMPOSITION = {"models.chain", "models.compiled"}   # models/chain.py and models/compiled.py


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def part_of(module: str) -> str:
    if module in COMPOSITION:
        return "models.chain"
    if module == "harness.__main__":
        return "harness.cli"
    parts = module.split(".")
    if parts[0] in ("studies", "benchmarks"):
        return parts[0]
    package = ".".join(parts[:2])
    return package if package in ALLOWED else parts[0]


def sources() -> list[Path]:
    return sorted(p for top in TOP for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of a project module in ``path``, absolute or relative."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            found.append((node.lineno, target))
            # "from harness.reports import run_report" imports the module harness.reports.run_report
            found += [(node.lineno, f"{target}.{a.name}") for a in node.names]
    return [(line, m) for line, m in found if m.split(".")[0] in TOP]


def project_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sources()}


def resolve(target: str, known: dict[str, Path]) -> str | None:
    """The project module ``target`` names (``pkg.mod.attr`` -> ``pkg.mod``), or None."""
    while target and target not in known:
        target = target.rpartition(".")[0]
    return target or None


def allowed(src_part: str, dst_part: str) -> bool:
    if src_part == dst_part:
        return True
    for rule in ALLOWED[src_part]:
        if rule.endswith("*") and (dst_part == rule[:-1] or dst_part.startswith(rule[:-1] + ".")):
            return True
        if rule == dst_part:
            return True
    return False


def graph() -> tuple[dict[str, set[str]], list[str]]:
    known = project_modules()
    edges: dict[str, set[str]] = {m: set() for m in known}
    upward, seen = [], set()
    for mod, path in known.items():
        for line, target in imports(path):
            dst = resolve(target, known)
            if dst is None or dst == mod:
                continue
            edges[mod].add(dst)
            message_key = (mod, line, dst)
            if not allowed(part_of(mod), part_of(dst)) and message_key not in seen:
                seen.add(message_key)
                upward.append(f"{path.relative_to(ROOT)}:{line}: {part_of(mod)} imports {dst} "
                              f"({part_of(dst)}), not below it in docs/architecture.md")
    return edges, upward


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_every_part_is_in_the_layer_table():
    parts = {part_of(m) for m in project_modules()}
    assert parts <= set(ALLOWED), f"parts missing from ALLOWED (and docs/architecture.md): {parts - set(ALLOWED)}"


def test_no_module_imports_a_layer_above_its_own():
    _, upward = graph()
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_no_import_circle():
    found = cycles(graph()[0])
    assert not found, "import circles:\n" + "\n".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize("source,dest,expect", [
    ("models.plant", "harness.run", False), ("harness.run", "models.plant", True),
    ("models.plant", "models.estimation", False), ("fmu_src", "harness", False),
    ("harness.reports", "harness.sweep", False), ("harness.sweep", "harness.reports", True)])
def test_the_rule_itself(source, dest, expect):
    assert allowed(source, dest) is expect


def test_a_planted_circle_is_found():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(edges) == [["a", "b", "c"]]


def test_no_python_file_over_600_lines_without_a_reason():
    """A module over 600 lines says why in one line near its top ("Over 600 lines: ...")."""
    long = []
    for p in sources():
        if p.parts[len(ROOT.parts)] not in ("models", "harness", "fmu_src"):
            continue
        text = p.read_text(encoding="utf-8")
        if text.count("\n") > 600 and "Over 600 lines" not in "\n".join(text.splitlines()[:30]):
            long.append(f"{p.relative_to(ROOT)} ({text.count(chr(10))} lines)")
    assert not long, "modules over 600 lines without a reason at their top: " + ", ".join(long)
