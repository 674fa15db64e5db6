"""docs/variables.md's tables are generated from fmu_src/variables.py and must stay in sync; the
README stays a way in (the results live under docs/)."""
from pathlib import Path

from fmu_src.variables import docs_block

ROOT = Path(__file__).resolve().parent.parent


def test_variable_tables_match_the_table():
    page = (ROOT / "docs" / "variables.md").read_text(encoding="utf-8")
    block = page.split("<!-- variables:start -->")[1].split("<!-- variables:end -->")[0]
    assert block == docs_block(), "docs/variables.md out of date: python -m fmu_src.variables --update-docs"


def test_every_document_the_readme_links_exists():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    import re
    links = re.findall(r"\]\((docs/[^)#]+)", readme)
    assert len(links) >= 5
    for link in links:
        assert (ROOT / link).is_file(), link
