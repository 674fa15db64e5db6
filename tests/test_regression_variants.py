"""The estimator options beyond the FMU's defaults, pinned to stored references (FMI cross-check
layout, tests/regression/variants/): station_day with every issue-5 option on at once, run on
the models chain (the FMU runs the same code; tests/fmu_tests/test_fmu_fmpy.py checks the options reach
it). The defaults run the C core (models/core via models/compiled.py) and are pinned by the
library's references (test_regression.py); these options run the Python chain, which nothing
else pins number by number. Tolerances: harness.run.regress.KEY_SIGNALS.

To rewrite the references after a deliberate change:
    RAILCAR_UPDATE_VARIANTS=1 python -m pytest tests/test_regression_variants.py
"""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import pytest

from harness.run.driver import run_on_chain
from harness.run.regress import REFERENCES, compare, write_reference
from harness.run.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
FOLDER = REFERENCES / "variants"
VARIANTS = {
    # LS on seed 004's slopes, A0 and A2 kept physical, sigma^2 by likelihood, slow forgetting
    "station_day_all_options": ("station_day", {"est.method": 2, "est.physical": 1,
                                                "est.sigma2_method": 1, "est.run_forgetting": 0.1}),
    # the coasting EKF for the A's with the same options
    "station_day_coast_ekf": ("station_day", {"est.method": 3, "est.physical": 1,
                                              "est.sigma2_method": 1, "est.run_forgetting": 0.1}),
}


def _run(name: str):
    base, params = VARIANTS[name]
    s = load_scenario(ROOT / "scenarios" / "library" / f"{base}.toml")
    return run_on_chain(replace(s, name=name), params)


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_matches_its_reference(name):
    result = _run(name)
    if os.environ.get("RAILCAR_UPDATE_VARIANTS"):
        write_reference(result, FOLDER)
    c = compare(result, FOLDER)
    assert c.ok, "\n".join(c.problems)
