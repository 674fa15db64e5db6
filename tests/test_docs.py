"""The README's variable tables are generated from fmu_src/variables.py and must stay in sync."""
from pathlib import Path

from fmu_src.variables import BOTH, markdown_table

ROOT = Path(__file__).resolve().parent.parent


def test_readme_variable_tables_match_the_table():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("<!-- variables:start -->")[1].split("<!-- variables:end -->")[0]
    expected = "\n" + "\n\n".join(f"### `{n}`\n\n{markdown_table(n)}" for n in BOTH) + "\n"
    assert block == expected, "README variables out of date: run python -m fmu_src.variables"
