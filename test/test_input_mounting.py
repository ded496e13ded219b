"""Sensor mounting against ground truth: a simulated run with car-body lateral and longitudinal
motion read by a sensor rotated by a known roll and pitch (scipy's Rotation, ``mount_sim``):
the estimated tilt, the dip depths against the upright sensor, the configured rotation, the
flags and findings; an upright sensor unchanged."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.imu import imu_spec
from railgsa_ros.input import mounting
from railgsa_ros.input.findings import OK, WARN
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.mount_sim import horizontal_motion, mounted
from railgsa_ros.samples import pieces
from railgsa_ros.scenario import run_scenario

DIPS = ((950.0, 6e-3), (1150.0, 4e-3))  # chainage m, depth m: after the estimate settles
#: every 5 s over 70 s: braking at 1 m/s^2 from 10 s, traction at 1 m/s^2 from 30 s
SPEED = np.array([22.0, 22, 22, 17, 17, 17, 17, 22, 22, 22, 22, 22, 22, 22, 22])


@pytest.fixture(scope='module')
def body():
    """70 s at about 20 m/s (ADXL355 model, two dips) with braking, a 20 s curve of 0.6 m/s^2
    cant deficiency and lateral (0.15 m/s^2 RMS) and longitudinal vibration in the car body."""
    defects = ','.join(f'dip@{x:g}:len=6:depth={d:g}' for x, d in DIPS)
    run = run_scenario('german-low', SPEED, 70.0, None, imu_spec('adxl355', dropout_fraction=0),
                       seed=4, defects=defects)
    accel = run.accel.copy()
    accel[:, :2] += horizontal_motion(run.t_true_s, run.speed_mps, 4, curve=(20.0, 20.0, 0.6))
    return run, accel


def invert(run, accel, **config) -> tuple[Output, InputStage]:
    """The run through the policy: odometry first, then the IMU in chunks, then flush."""
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz, **config))
    outs = [policy.odometry(run.stamps_ns[::20], run.speed_mps[::20])]
    for sl in pieces(run.stamps_ns.size, 20000):
        outs.append(policy.imu(run.stamps_ns[sl], accel[sl]))
    outs.append(policy.flush())
    return Output.concat(outs), policy


def depths(out: Output) -> np.ndarray:
    """Depth (m) of each dip: the lowest published u within 5 m of its centre."""
    return np.array([-np.nanmin(np.where(np.abs(out.chainage_m - x) < 5, out.u_m, np.nan))
                     for x, _ in DIPS])


def tilt_deg(roll: float, pitch: float) -> float:
    up = Rotation.from_euler('xy', [roll, pitch], degrees=True).inv().apply([0.0, 0.0, 1.0])
    return float(np.degrees(np.arccos(up[2])))


@pytest.fixture(scope='module')
def upright(body):
    run, accel = body
    return invert(run, accel, mounting='axis')


@pytest.mark.parametrize('roll, pitch', [(20.0, -10.0), (-28.0, 18.0)])
def test_tilted_sensor_estimate_gives_the_upright_dips_and_reports_the_tilt(
        body, upright, roll, pitch):
    run, accel = body
    ref, _ = upright
    tilted = mounted(accel, roll, pitch)
    out, policy = invert(run, tilted)  # the default: mounting estimate
    # the reported tilt: within 1 deg of the truth (3 mg bias and the curve move the median)
    assert abs(policy.mounting.tilt_deg - tilt_deg(roll, pitch)) < 1.0
    finding = {f.key: f for f in policy.findings}['mounting']
    assert finding.level == OK and f'{policy.mounting.tilt_deg:.2f} deg' in finding.message
    # dips within 1.5 % of the upright sensor's (the axis as is: 6-17 % too shallow)
    assert np.all(np.abs(depths(out) / depths(ref) - 1) < 0.015), depths(out) / depths(ref)
    plain, _ = invert(run, tilted, mounting='axis')
    assert np.all(depths(plain) / depths(ref) < 0.97)
    # DEGRADED until the estimate settles (30 blocks: the first one short), VALID after
    t = (out.stamps_ns - run.stamps_ns[0]) / 1e9
    early = (t > 1) & (t < mounting.SETTLE_S - mounting.BLOCK_S + mounting.FIRST_S)
    assert np.all(out.quality[early] >= Quality.DEGRADED)
    late = (t > mounting.SETTLE_S) & (t < 60)
    # settled, the mounting adds no flag: the upright sensor's qualities (VALID, or DEGRADED
    # where the braking changes the speed across a band window)
    assert np.array_equal(out.quality[late], ref.quality[late])
    assert np.mean(ref.quality[late] == Quality.VALID) > 0.5
    assert policy.counters['mounting_degraded'] > 0


def test_axis_mode_on_a_tilted_sensor_is_degraded_with_a_finding_naming_the_angle(body):
    """The QA case: 25 deg of roll read as it is, never VALID, a WARN saying what to set."""
    run, accel = body
    out, policy = invert(run, mounted(accel, 25.0, 0.0), mounting='axis')
    assert not np.any(out.quality == Quality.VALID)
    finding = {f.key: f for f in policy.findings}['mounting']
    assert finding.level == WARN and policy.status.level == WARN
    roll = float(finding.message.split('set mount_roll_deg ')[1].split()[0])
    assert abs(roll - 25.0) < 1.0 and 'DEGRADED' in finding.message
    assert policy.counters['mounting_degraded'] == policy.counters['accepted']


def test_configured_rotation_is_honoured(body, upright):
    """mounting rotation with the true roll and pitch: the upright result (exact physics, no
    settling: VALID as the upright sensor); a rotation 5 deg off is DEGRADED."""
    run, accel = body
    ref, _ = upright
    tilted = mounted(accel, -15.0, 12.0)
    out, _ = invert(run, tilted, mounting='rotation', mount_roll_deg=-15.0,
                    mount_pitch_deg=12.0)
    assert np.array_equal(out.quality, ref.quality)
    ok = np.isfinite(ref.u_m)
    assert np.max(np.abs(out.u_m[ok] - ref.u_m[ok])) < 1e-9
    off, _ = invert(run, tilted, mounting='rotation', mount_roll_deg=-15.0, mount_pitch_deg=7.0)
    assert not np.any(off.quality == Quality.VALID)


@pytest.mark.parametrize('extra', [{}, {'gravity_mps2': 0.0}])
def test_upright_sensor_is_unchanged(body, upright, extra):
    """The default (estimate) on an upright sensor projects nothing: the bytes of the axis
    as is; with gravity_mps2 0 (gravity removed by the driver) the estimate is off."""
    run, accel = body
    ref, _ = upright if not extra else invert(run, accel, mounting='axis', **extra)
    out, policy = invert(run, accel, **extra)
    for name in ('stamps_ns', 'u_m', 'quality'):
        assert getattr(out, name).tobytes() == getattr(ref, name).tobytes(), name
    # only the first block before any estimate (inside the warm-up, INVALID anyway)
    first = round(mounting.FIRST_S * run.rate_hz)
    assert policy.counters.get('mounting_degraded', 0) == (0 if extra else first)
    if not extra:
        assert policy.mounting.tilt_deg < 1.0
        assert {f.key: f.level for f in policy.findings}['mounting'] == OK


def test_tilt_beyond_max_tilt_is_degraded(body):
    run, accel = body
    out, policy = invert(run, mounted(accel, 30.0, 0.0), max_tilt_deg=20.0)
    assert not np.any(out.quality == Quality.VALID)
    assert 'max_tilt_deg' in {f.key: f for f in policy.findings}['mounting'].message


@pytest.mark.parametrize('axis', ['z', '-z', 'x', '-y'])
def test_up_vector_is_scipys_rotation_and_roll_pitch_invert_it(axis):
    e = np.array(mounting.axis_vector(axis))
    for roll, pitch in [(0.0, 0.0), (12.0, -30.0), (-100.0, 45.0)]:
        truth = Rotation.from_euler('xy', [roll, pitch], degrees=True).inv().apply(e)
        up = mounting.up_vector(axis, roll, pitch)
        assert np.allclose(up, truth, atol=1e-15)
        rp = mounting.roll_pitch_deg(up, axis)
        assert (rp is None) == (axis[-1] != 'z')
        if rp is not None:
            assert np.allclose(rp, (roll, pitch), atol=1e-9)


def test_invert_reports_the_tilt(tmp_path, capsys):
    """railgsa invert on a bag of a sensor rolled 25 deg: the mounting finding (WARN while the
    estimate settles, a 20 s run) with the angle among its warnings."""
    run = run_scenario('german-low', 25.0, 20.0, 500.0, 'adxl355', seed=2)
    bag = write_run(tmp_path / 'tilted', replace(run, accel=mounted(run.accel, 25.0, 0.0)))
    assert main(['invert', str(bag), '--csv', str(tmp_path / 'u.csv')]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if 'tilted' in x)
    assert line.startswith('warning: sensor tilted') and 'settles' in line
    assert abs(float(line.split('tilted ')[1].split()[0]) - 25.0) < 1.0
