"""Accuracy floors on short runs (the full table: benchmarks/bench_inverse_accuracy.py)."""

import numpy as np
import pytest

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, vertical
from railgsa_ros.inverse.score import exact_inverse, score
from railgsa_ros.scenario import run_scenario

DIP = (200.0, 6.0)  # start, length (m) of the 8 mm cosine dip
DEFECTS = f'dip@{DIP[0]}:len={DIP[1]}:depth=8e-3,joint@260,weld@150'


@pytest.fixture(scope='module')
def adxl_run():
    """20 s at 20 m/s over German low track with isolated defects, ADXL355 model."""
    return run_scenario('german-low', 20.0, 20.0, None, 'adxl355', seed=3, defects=DEFECTS)


def reconstruct(run, **overrides):
    pipe = InversionPipeline(InversionConfig(**overrides), noise_variance=run.accel_covariance)
    acc = vertical(run.accel, 'z')
    outs = [pipe.push(run.stamps_ns, acc, run.speed_mps), pipe.flush()]
    chain = np.concatenate([o.chainage_m for o in outs]) + run.chainage_m[0]
    return chain, np.concatenate([o.u_m for o in outs])


@pytest.mark.parametrize('method, extra', [('spectral', {}), ('feedback', {}),
                                           ('kalman', {'smoother': True})])
def test_d1_accuracy_floors(adxl_run, method, extra):
    chain, u = reconstruct(adxl_run, method=method, **extra)
    s = score(chain, u, adxl_run.chainage_m, adxl_run.truth_u_m, defect=DIP, margin_m=80.0)
    assert s.rmse <= 0.3e-3
    assert s.correlation >= 0.95
    assert s.peak_error <= 0.5e-3


def test_live_kalman_is_a_usable_but_weaker_estimate(adxl_run):
    chain, u = reconstruct(adxl_run, method='kalman')
    s = score(chain, u, adxl_run.chainage_m, adxl_run.truth_u_m, defect=DIP, margin_m=80.0)
    assert s.correlation >= 0.7
    assert s.rmse <= 1.5e-3


def test_default_method_is_close_to_the_exact_physics_baseline(adxl_run):
    chain, u = reconstruct(adxl_run)
    base = exact_inverse(adxl_run.stamps_ns, vertical(adxl_run.accel, 'z'), 20.0)
    s = score(chain, u, adxl_run.chainage_m, adxl_run.truth_u_m, margin_m=80.0)
    b = score(adxl_run.chainage_m, base, adxl_run.chainage_m, adxl_run.truth_u_m, margin_m=80.0)
    assert b.rmse < 0.05e-3
    assert s.rmse <= 3 * b.rmse + 0.01e-3
