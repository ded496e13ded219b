"""Speed profiles: distances by hand, standstill, ripple, errors, and the simulate command."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import trapezoid

from railgsa_ros.bag import read_stamped
from railgsa_ros.bag.messages import ODOMETRY, ODOMETRY_FIELDS, POINT_STAMPED
from railgsa_ros.cli.main import main
from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import imu_spec
from railgsa_ros.scenario import run_scenario
from railgsa_ros.speed_profile import PRESETS, parse_speed_profile, speed_profile

BRIEF = 'accel:0-30:60s,cruise:30:120s:ripple=0.5,brake:30-0:40s,stop:10s,accel:0-20:30s'
# by hand: 0.5*30*60 + 30*120 (whole ripple periods add nothing) + 0.5*30*40 + 0 + 0.5*20*30
BRIEF_SEGMENTS_M = [900.0, 3600.0, 600.0, 0.0, 300.0]


def test_profile_integrates_to_the_distances_worked_out_by_hand():
    profile = parse_speed_profile(BRIEF)
    assert profile.duration_s == 260.0
    assert profile.distance_m == sum(BRIEF_SEGMENTS_M)
    t, v = speed_profile(BRIEF, 1000.0)
    assert t[0] == 0.0 and t[-1] == pytest.approx(260.0) and t.size == 260_001
    bounds = np.concatenate([[0], np.cumsum([60, 120, 40, 10, 30])])
    for (lo, hi), expected in zip(itertools.pairwise(bounds), BRIEF_SEGMENTS_M,
                                  strict=True):
        inside = (t >= lo - 1e-9) & (t <= hi + 1e-9)
        assert trapezoid(v[inside], t[inside]) == pytest.approx(expected, abs=1e-3)
    cruise = (t > 60) & (t < 180)
    assert v[cruise].max() == pytest.approx(30.5, abs=1e-4)
    assert v[cruise].min() == pytest.approx(29.5, abs=1e-4)
    assert np.all(v[(t >= 220) & (t <= 230)] == 0.0)
    # continuous at every junction: no sample-to-sample jump beyond the steepest ramp
    assert np.abs(np.diff(v)).max() <= 0.75 / 1000 + 1e-12


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_presets_stop_and_integrate(name):
    profile = parse_speed_profile(name)
    t, v = speed_profile(name, 200.0)
    assert v.min() == 0.0 and np.all(v >= 0)
    assert trapezoid(v, t) == pytest.approx(profile.distance_m, rel=1e-6)


def test_standstill_holds_chainage_and_the_imu_keeps_sampling():
    spec = 'accel:0-20:10s,brake:20-0:10s,stop:20s,accel:0-10:5s'
    profile = parse_speed_profile(spec)
    sensor = imu_spec('adxl355', dropout_fraction=0.0)
    run = run_scenario('german-high', profile, profile.duration_s, 500.0, sensor, seed=4)
    t = run.t_true_s
    assert run.stamps_ns.size == round(profile.duration_s * 500)
    stop = (t >= 20.0) & (t <= 40.0)
    assert np.ptp(run.chainage_m[stop]) == 0.0
    np.testing.assert_array_equal(run.speed_mps[stop], 0.0)
    assert run.chainage_m[stop][0] == pytest.approx(200.0, abs=1e-6)  # 0.5*20*20 by hand
    short = profile.duration_s - t[-1]  # the last sample is one period before the end
    assert run.chainage_m[-1] == pytest.approx(profile.distance_m - 10.0 * short
                                               + 0.5 * 2.0 * short ** 2, abs=1e-6)
    # at rest (after the body settles: its slowest mode decays within ~3 s): noise only
    rest = (t > 25.0) & (t < 40.0)
    az = run.accel[rest, 2] - np.median(run.accel[rest, 2])
    assert np.std(az) == pytest.approx(np.sqrt(run.accel_covariance), rel=0.1)
    assert np.all(np.diff(run.chainage_m) >= 0)


@pytest.mark.parametrize('spec, message', [
    ('accel:0-30:60s,cruise:20:10s', 'starts at 20 m/s but the segment before ends at 30'),
    ('accel:0-100:5s', 'not plausible'),
    ('accel:30-0:60s', 'accel needs V1 > V0'),
    ('brake:0-30:60s', 'brake needs V1 < V0'),
    ('cruise:3:10s:ripple=5', 'below 0'),
    ('cruise:3:10s:wobble=5', 'expected cruise:V:DURs'),
    ('coast:3:10s', 'unknown segment'),
    ('stop:10s', 'never moves'),
    ('stop:-1s', 'finite number >= 0'),
    ('cruise:x:10s', 'speed is not a number'),
    ('', 'empty'),
])
def test_bad_specs_name_the_problem(spec, message):
    with pytest.raises(ConfigError, match=message):
        parse_speed_profile(spec)


def test_simulate_command_with_a_speed_profile(tmp_path: Path, capsys):
    spec = 'accel:0-15:6s,stop:3s,accel:15-20:2s'  # starts from rest, stops, restarts
    out = tmp_path / 'bag'
    assert main(['simulate', '--out', str(out), '--speed-profile', 'accel:0-10:4s,brake:10-0:4s,'
                 'stop:2s,accel:0-5:2s', '--rate', '200', '--odom-rate', '20']) == 0
    odom = read_stamped(out, '/odom', ODOMETRY.msgtype)
    truth = read_stamped(out, '/track/irregularity_truth', POINT_STAMPED.msgtype)
    span = (truth.stamps_ns[-1] - truth.stamps_ns[0]) / 1e9
    assert span == pytest.approx(12.0, abs=0.05)
    assert truth.values[-1, 0] == pytest.approx(40.0 + 5.0, abs=0.05)  # 20 + 20 + 0 + 5 m
    speed = odom.values[:, ODOMETRY_FIELDS['twist.twist.linear'].start]
    assert speed.min() == 0.0 and speed.max() == pytest.approx(10.0, abs=0.1)
    capsys.readouterr()
    assert main(['simulate', '--out', str(tmp_path / 'b2'), '--speed', '3',
                 '--speed-profile', spec]) == 2
    assert 'exclude each other' in capsys.readouterr().err
