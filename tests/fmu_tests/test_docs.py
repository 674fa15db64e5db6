"""docs/variables.md's tables are generated from fmu_src/variables.py and must stay in sync; the
README stays a way in (the results live under docs/). The documentation stands alone: every
relative link resolves to a file of the repository (and a #heading to a heading of it), and no
page points outside the repository (../shared) or to a tracker's numbers ("issue 17")."""
import re
import subprocess
from pathlib import Path

import pytest

from fmu_src.variables import docs_block

ROOT = Path(__file__).resolve().parents[2]

USER_DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
"""The pages a user reads: the README and everything under docs/."""

LINKED_DOCS = USER_DOCS + [ROOT / "CHANGELOG.md"]
"""Pages whose links are checked (the changelog may name issues, but its links must work)."""


def test_variable_tables_match_the_table():
    page = (ROOT / "docs" / "variables.md").read_text(encoding="utf-8")
    block = page.split("<!-- variables:start -->")[1].split("<!-- variables:end -->")[0]
    assert block == docs_block(), "docs/variables.md out of date: python -m fmu_src.variables --update-docs"


def test_every_document_the_readme_links_exists():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\((docs/[^)#]+)", readme)
    assert len(links) >= 5
    for link in links:
        assert (ROOT / link).is_file(), link


# ------------------------------------------------------------------ links and outside references

FENCE = re.compile(r"^ *```.*?^ *```[^\n]*$", re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$", re.M)
OUTSIDE = [
    (re.compile(r"\.\./shared|shared/(spec|seeds)"), "a path outside the repository"),
    (re.compile(r"\bMODEL\.md|\bFMU_INTERFACE\.md"), "a spec file outside the repository"),
    (re.compile(r"\bissues?\s*[#-]?\s*\d+", re.I), "an issue number"),
]


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are not links)."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)      # a link keeps its text
    text = re.sub(r"[^\w\- ]", "", text.replace("`", "").strip().lower())
    return text.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a page's headings (a repeated heading gets -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    for _, title in HEADING.findall(FENCE.sub("", text)):
        s = slug(title)
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def repository_files() -> set[Path] | None:
    """Files a clone has or would have (tracked, or new and not ignored); None without git."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    return {(ROOT / line).resolve() for line in out.splitlines() if line}


def broken_links(page: Path, text: str, files: set[Path] | None) -> list[str]:
    """Each relative link of ``text`` (the page ``page``) that does not resolve, with why."""
    bad = []
    for target in LINK.findall(prose(text)):
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):       # http:, https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page.resolve()
        if not dest.is_relative_to(ROOT):
            bad.append(f"{target}: outside the repository")
            continue
        if dest.is_dir():
            if files is not None and not any(f.is_relative_to(dest) for f in files):
                bad.append(f"{target}: no file of the repository under it")
            continue
        if not dest.is_file() or (files is not None and dest not in files):
            bad.append(f"{target}: no such file in the repository")
            continue
        if anchor and dest.suffix == ".md":
            if anchor not in anchors(dest.read_text(encoding="utf-8")):
                bad.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    return bad


def outside_references(text: str) -> list[str]:
    """Mentions a reader of the clone cannot follow: ../shared, the spec files, issue numbers."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        for pattern, what in OUTSIDE:
            m = pattern.search(line)
            if m:
                found.append(f"line {number}: {what}: {m.group(0)!r}")
    return found


@pytest.mark.parametrize("page", LINKED_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    text = page.read_text(encoding="utf-8")
    assert broken_links(page, text, repository_files()) == []


KNOWN_OUTSIDE: dict[str, str] = {}
"""Pages known to break the rule, each failing on purpose until fixed (xfail strict)."""


def _user_doc_params():
    for page in USER_DOCS:
        name = str(page.relative_to(ROOT))
        marks = [pytest.mark.xfail(strict=True, reason=KNOWN_OUTSIDE[name])] if name in KNOWN_OUTSIDE else []
        yield pytest.param(page, id=name, marks=marks)


@pytest.mark.parametrize("page", list(_user_doc_params()))
def test_no_reference_outside_the_repository(page):
    assert outside_references(page.read_text(encoding="utf-8")) == []


def test_the_pages_have_links_to_check():
    """The link test is not vacuous: the README links docs/model.md's sections, and docs/ links
    back to model.md's references."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/model.md#pitfalls" in LINK.findall(prose(readme))
    assert sum(len(LINK.findall(prose(p.read_text(encoding="utf-8")))) for p in USER_DOCS) >= 40
    assert any("model.md#references" in LINK.findall(prose(p.read_text(encoding="utf-8")))
               for p in USER_DOCS)


def test_the_checks_catch_what_they_are_for():
    """Negative controls: each kind of fault is found, and its correct twin is not."""
    page = ROOT / "docs" / "model.md"
    files = repository_files()
    assert broken_links(page, "[a](core.md) [b](../README.md#quick-start) [w](https://x.y/z)", files) == []
    assert broken_links(page, "[t](#references) [d](../models)", files) == []
    assert len(broken_links(page, "[a](cores.md)", files)) == 1                  # no such file
    assert len(broken_links(page, "[b](../README.md#quick-starts)", files)) == 1  # no such heading
    assert len(broken_links(page, "[c](#no-such-heading)", files)) == 1
    assert len(broken_links(page, "[d](../../shared/spec/MODEL.md)", files)) == 1  # outside
    assert broken_links(page, "`[e](cores.md)` and\n```\n[f](cores.md)\n```\n", files) == []  # code
    if files is not None:                     # built, ignored by git: not in a clone
        assert len(broken_links(ROOT / "README.md", "[g](dist/RailCar.fmu)", files)) == 1
    assert slug("Kalman filters of speed and distance") == "kalman-filters-of-speed-and-distance"
    assert slug("Limits and known traps") == "limits-and-known-traps"
    assert slug("The C model core (`models/core/`)") == "the-c-model-core-modelscore"
    assert anchors("# A\n## A\n```\n# B\n```\n") == {"a", "a-1"}
    for fault in ("see ../shared/spec/MODEL.md", "shared/seeds/001", "as in MODEL.md §4",
                  "FMU_INTERFACE.md", "issue 17", "Issue 5's table", "issues 7 and 16",
                  "the issue-5 targets", "issue #18"):
        assert len(outside_references(fault)) >= 1, fault
    for fine in ("issues a warning", "the model.md page", "a shared library", "seed 003",
                 "known issue: none"):
        assert outside_references(fine) == [], fine
