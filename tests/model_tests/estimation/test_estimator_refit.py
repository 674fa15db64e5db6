"""est.method = 1: the filter-error refit at each station carries the A's over between runs."""
from pathlib import Path

import numpy as np
import pytest

from harness.run.phases import PhaseDriver
from harness.metrics.estimation import w0_relative_rms_error
from harness.run.scenario import load_scenario
from models.chain import ChainConfig, RailCarChain
from models.plant.dynamics import VehicleParams
from models.estimation.online import StationConfig
from models.estimation.identification import IdentifierConfig
from models.plant.track import GradeProfile

ROOT = Path(__file__).resolve().parents[3]
TRUE_A = (0.89, 0.0288, 0.010498)


def run_day(method: int):
    """station_day's driving script on the models chain (four runs, passengers at stops)."""
    s = load_scenario(ROOT / "scenarios" / "library" / "station_day.toml")
    grade = GradeProfile.from_csv_text(Path(s.parameter("track.grade_profile")).read_text(), "grade")
    chain = RailCarChain(ChainConfig(vehicle=VehicleParams(mass=32.0), seed=17,
                                     station=StationConfig(dwell=20.0),
                                     identifier=IdentifierConfig(method=method)), grade)
    driver = PhaseDriver(s.phases, 32.0, 40e3, 45e3)
    payload, speeds = 0.0, []
    for k in range(9000):
        st = chain.plant.state
        f, b, dm = driver.demands(k * 0.1, st.speed, st.position)
        payload += dm
        if driver.finished:
            break
        chain.do_step(k * 0.1, 0.1, f, b, 0.0, payload)
        speeds.append(st.speed)
    return chain, np.array(speeds)


def test_refit_brings_the_resistance_within_a_few_percent():
    """Paper LS: w0 off by ~27 % after a four-station day (measured speed differenced);
    with the refit the carried-over A's are within 5 % RMS over the travelled speeds."""
    chain0, v = run_day(0)
    chain1, _ = run_day(1)
    err = {}
    for m, chain in ((0, chain0), (1, chain1)):
        o = chain.outputs()
        err[m] = w0_relative_rms_error(v, (o["est.A0"], o["est.A1"], o["est.A2"]), TRUE_A)
    refit = chain1.estimator.method       # models.estimation.methods.RefitLS
    assert refit.refit.runs == 3 and refit.failures == 0
    assert err[0] > 0.15          # the known weakness, measured: 27 %
    assert err[1] < 0.05          # measured 3.3 %
    # the refit does not touch the mass identification
    assert chain1.outputs()["est.mass"] == pytest.approx(chain0.outputs()["est.mass"], rel=1e-12)


def test_est_method_is_validated():
    with pytest.raises(ValueError, match="est.method"):
        IdentifierConfig(method=4).validate()
    with pytest.raises(ValueError, match="est.slope_window"):
        IdentifierConfig(method=2, slope_window=1).validate()
    with pytest.raises(ValueError, match="est.physical"):
        IdentifierConfig(physical=2).validate()
