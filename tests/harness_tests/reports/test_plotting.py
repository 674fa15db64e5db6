"""harness.reports.plotting: the units as plots show them (the CSVs and FMUs keep ASCII powers)."""
import pytest

from harness.reports.plotting import display_unit


@pytest.mark.parametrize("unit, shown", [
    ("N/kN/(m/s)2", "N/kN/(m/s)²"), ("m2/s2", "m²/s²"), ("(N/kN)2/(m/s)3", "(N/kN)²/(m/s)³"),
    ("1/s2", "1/s²"), ("N/kN", "N/kN"), ("m/s", "m/s"), ("kWh", "kWh"), ("1", "1"), ("", "")])
def test_ascii_powers_become_superscripts_and_nothing_else_changes(unit, shown):
    assert display_unit(unit) == shown
