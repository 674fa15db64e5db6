"""The README's variable tables are generated from fmu_src/variables.py and must stay in sync."""
from pathlib import Path

from fmu_src.variables import readme_block

ROOT = Path(__file__).resolve().parent.parent


def test_readme_variable_tables_match_the_table():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("<!-- variables:start -->")[1].split("<!-- variables:end -->")[0]
    assert block == readme_block(), "README out of date: python -m fmu_src.variables --update-readme"
