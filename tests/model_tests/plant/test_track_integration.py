"""Track-sensor speed (Boynik et al.) in the chain and the estimator; the Singer filter in the
chain."""
import math

import numpy as np
import pytest

from models.chain import ChainConfig, EstimatorChain, RailCarChain, TrackSensorConfig
from models.estimation.online import StationConfig
from models.filtering.motion_filter import SINGER, FilterConfig
from models.estimation.identification import IdentifierConfig
from models.plant.track import GradeProfile


def drive(chain, seconds=60.0):
    """Traction for 20 s then coast; returns (time, true speed) history and track readings."""
    hist, readings, last = [], [], chain.track_time
    for k in range(int(seconds / 0.1)):
        chain.do_step(k * 0.1, 0.1, 40e3 if k < 200 else 0.0, 0.0, 0.0)
        hist.append((chain.plant.time, chain.plant.state.speed))
        if chain.track_time != last:
            readings.append((chain.track_time, chain.track_speed))
            last = chain.track_time
    return np.array(hist), readings


def test_track_sensor_readings_measure_the_mid_passage_speed():
    """Readings are b / (t2 - t1): the mean speed over the base, i.e. the speed at mid-passage
    (t2 - b/2v), with the error of v^2/b sqrt(delta^2/6) (1 ms timer, base 5 m)."""
    track = TrackSensorConfig(spacing=40.0, base=5.0, resolution=1e-3)
    chain = RailCarChain(ChainConfig(seed=3, process_noise_psd=0.0, track=track), GradeProfile.level())
    hist, readings = drive(chain)
    assert len(readings) >= 15                      # ~700 m travelled, a pair every 40 m
    errors = []
    for stamp, v in readings:
        t_mid = stamp - 0.5 * track.base / v
        errors.append((v - np.interp(t_mid, hist[:, 0], hist[:, 1])) / track.speed_std(v))
    errors = np.array(errors)
    # normalised errors: mean within 4 standard errors of 0, spread of order 1 (quantisation is
    # uniform only on average over speeds, so allow 0.3..2)
    assert abs(errors.mean()) < 4.0 / math.sqrt(len(errors))
    assert 0.3 < errors.std() < 2.0


@pytest.mark.parametrize("kind", [2, SINGER])
def test_a_track_speed_shrinks_the_filters_speed_variance(kind):
    """A speed measurement with a 1 cm/s std after a 0.05 m/s sensor must reduce P_vv."""
    est = EstimatorChain(IdentifierConfig(), FilterConfig(kind=kind), StationConfig(),
                         GradeProfile.level(), None, TrackSensorConfig(base=5.0, resolution=1e-4))
    for k in range(30):
        est.do_step(k * 0.1, 0.1, 30e3, 0.0, 0.1 * k, 0.005 * k * k)
    before = est.estimator.filter.speed_std
    est.do_step(3.0, 0.1, 30e3, 0.0, 3.0, 4.5, track_speed=2.95, track_time=2.98)
    assert est.estimator.track_speeds == 1
    assert est.estimator.filter.speed_std < before
    # the same stamp again is not taken twice
    est.do_step(3.1, 0.1, 30e3, 0.0, 3.1, 4.8, track_speed=2.95, track_time=2.98)
    assert est.estimator.track_speeds == 1


def test_track_settings_are_validated_naming_the_parameter():
    with pytest.raises(ValueError, match="sensor.track_base"):
        TrackSensorConfig(spacing=10.0, base=0.0).validate()
    with pytest.raises(ValueError, match="sensor.track_spacing"):
        TrackSensorConfig(spacing=4.0, base=5.0).validate()


def test_singer_kind_runs_in_the_chain_and_beats_the_sensor():
    """Boynik et al.'s model-free filter as filter.kind = 4: better than the raw speed (RMSE)."""
    chain = RailCarChain(ChainConfig(seed=5, filter=FilterConfig(kind=SINGER)), GradeProfile.level())
    err_f, err_s = [], []
    for k in range(600):
        chain.do_step(k * 0.1, 0.1, 40e3 if k < 200 else 0.0, 0.0, 0.0)
        o = chain.outputs()
        err_f.append(o["filter.speed"] - o["car.speed"])
        err_s.append(o["sensor.speed"] - o["car.speed"])
    assert np.sqrt(np.mean(np.square(err_f))) < 0.8 * np.sqrt(np.mean(np.square(err_s)))


def test_bad_singer_settings_name_the_parameter():
    with pytest.raises(ValueError, match="filter.singer_tau"):
        FilterConfig(kind=SINGER, singer_tau=0.0).validate(False)
    with pytest.raises(ValueError, match="filter.singer_"):
        FilterConfig(kind=SINGER, singer_p0=0.9, singer_p_plus=0.2).validate(False)
