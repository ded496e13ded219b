"""railgsa check, analysis side (ROS-free): simulated IMU streams with known rate, jitter,
gravity axis, noise density and stamp faults give the exact verdicts."""

from __future__ import annotations

from dataclasses import replace
import json
import math

import numpy as np
import pytest

from railgsa_ros.health import FAIL, PASS, WARN, Observation, checklist, exit_code, format_items
from railgsa_ros.health.imu_checks import (
    gravity_item,
    jitter_item,
    measured_rate,
    monotonic_item,
    noise_item,
    rate_item,
)
from railgsa_ros.health.items import Item, items_json
from railgsa_ros.health.system_checks import (
    TopicStats,
    node_item,
    odom_item,
    output_item,
    output_stats,
)
from railgsa_ros.imu import PRESETS, UG, ImuSpec, measure

T0_NS = 1_700_000_000 * 10**9


def stream(spec: ImuSpec, duration_s: float = 10.0, motion_mps2: float = 0.0,
           seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Delivered (stamps_ns, accel (N, 3)) of ``spec`` at rest, or with a 2 Hz vertical
    car-body motion of amplitude ``motion_mps2``."""
    t = np.arange(0.0, duration_s, 1.0 / (4 * spec.output_rate_hz))
    s = measure(t, motion_mps2 * np.sin(2 * np.pi * 2.0 * t), spec, seed=seed)
    return s.stamps_ns[s.valid] + T0_NS, s.accel[s.valid]


@pytest.fixture(scope='module')
def adxl() -> tuple[np.ndarray, np.ndarray]:
    return stream(PRESETS['adxl355'])


@pytest.fixture(scope='module')
def bmi() -> tuple[np.ndarray, np.ndarray]:
    return stream(PRESETS['bmi088'])


def number(text: str, index: int = 0) -> float:
    """The index-th number in an item's value text."""
    import re

    return float(re.findall(r'-?\d+\.?\d*(?:e-?\d+)?', text)[index])


@pytest.mark.parametrize('preset', ['adxl355', 'bmi088'])
def test_healthy_sensor_at_rest_passes_with_its_own_figures(preset: str, adxl: tuple,
                                                             bmi: tuple) -> None:
    spec = PRESETS[preset]
    stamps, accel = adxl if preset == 'adxl355' else bmi
    rate, jitter, order, gravity, noise = (
        rate_item(stamps, spec.output_rate_hz, 10.0), jitter_item(stamps, spec.output_rate_hz),
        monotonic_item(stamps), gravity_item(accel), noise_item(stamps, accel, spec))
    assert [i.status for i in (rate, jitter, order, gravity, noise)] == [PASS] * 5
    drifted = spec.output_rate_hz / (1 + 1e-6 * spec.clock_drift_ppm)
    assert number(rate.value) == pytest.approx(drifted, rel=1e-4)
    assert number(jitter.value) == pytest.approx(spec.stamp_jitter_s * 1e3, rel=0.15)
    assert order.value.startswith('0 out of order, 0 duplicates')
    assert gravity.value.startswith('+z')
    assert number(gravity.value) == pytest.approx(9.80665 * (1 + spec.scale_factor)
                                                     + spec.bias[2], abs=0.01)
    densities = [number(noise.value, k) for k in range(3)]  # x, y, z in ug/sqrt(Hz)
    np.testing.assert_allclose(densities, spec.noise_density / UG, rtol=0.15)
    assert 'moving' not in noise.value


@pytest.mark.parametrize(('columns', 'signs', 'label', 'hint'), [
    ([0, 1, 2], [1, -1, -1], '-z', 'upside down'),     # turned over (180 deg about x)
    ([2, 0, 1], [1, 1, 1], '+x', 'rotated'),           # z axis points forward
    ([0, 2, 1], [1, -1, 1], '-y', 'rotated'),          # lying on its side
])
def test_gravity_on_another_axis_or_inverted_fails(columns: list, signs: list, label: str,
                                                   hint: str, adxl: tuple) -> None:
    item = gravity_item(adxl[1][:, columns] * signs)
    assert item.status == FAIL and item.value.startswith(label) and hint in item.hint


@pytest.mark.parametrize(('tilt_deg', 'status'), [(3.0, PASS), (8.0, WARN), (30.0, FAIL)])
def test_tilted_sensor_by_angle(tilt_deg: float, status: str, adxl: tuple) -> None:
    c, s = math.cos(math.radians(tilt_deg)), math.sin(math.radians(tilt_deg))
    rotated = adxl[1] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T
    item = gravity_item(rotated)
    assert item.status == status
    assert number(item.value, 2) == pytest.approx(tilt_deg, abs=0.3)  # 3 mg x, y bias: 0.25 deg


def test_gravity_in_g_instead_of_m_per_s2_fails(adxl: tuple) -> None:
    item = gravity_item(adxl[1] / 9.80665)
    assert item.status == FAIL and 'units' in item.hint


def test_wrong_preset_fails_on_rate_and_noise(adxl: tuple, bmi: tuple) -> None:
    adxl_spec, bmi_spec = PRESETS['adxl355'], PRESETS['bmi088']
    # a BMI088 checked as an ADXL355: 400 Hz instead of 1000, about 175 instead of 22.5 ug
    rate = rate_item(bmi[0], adxl_spec.output_rate_hz, 10.0)
    noise = noise_item(*bmi, adxl_spec)
    assert rate.status == FAIL and number(rate.value) == pytest.approx(400.0, rel=1e-4)
    assert noise.status == FAIL and 'noisier' in noise.hint
    assert number(noise.value, 2) == pytest.approx(175.0, rel=0.2)
    # an ADXL355 checked as a BMI088: quieter than the preset
    noise = noise_item(*adxl, bmi_spec)
    assert noise.status == FAIL and 'quieter' in noise.hint


def test_noise_above_the_preset_only_warns_on_a_moving_train() -> None:
    spec = PRESETS['adxl355']
    quiet = replace(spec, noise_density=spec.noise_density / 4)  # sensor is 4x the preset
    at_rest = noise_item(*stream(spec), quiet)
    moving = noise_item(*stream(spec, motion_mps2=0.5), quiet)
    assert at_rest.status == FAIL and 'moving' not in at_rest.value
    assert moving.status == WARN and moving.value.endswith('moving') and 'at rest' in moving.hint
    # the car-body motion (2 Hz) leaves the band's density at the sensor's
    assert number(moving.value, 2) == pytest.approx(spec.noise_density / UG, rel=0.15)


@pytest.mark.parametrize(('jitter_s', 'status'), [(0.3e-3, WARN), (0.7e-3, FAIL)])
def test_stamp_jitter_measured_and_judged(jitter_s: float, status: str) -> None:
    spec = replace(PRESETS['ideal'], stamp_jitter_s=jitter_s)
    stamps, _ = stream(spec)
    item = jitter_item(stamps, 1000.0)
    assert item.status == status
    assert number(item.value) == pytest.approx(jitter_s * 1e3, rel=0.1)


def test_rate_mismatch_lost_samples_and_slow_delivery() -> None:
    stamps, _ = stream(PRESETS['ideal'])
    assert rate_item(stamps, 1025.0, 10.0).status == FAIL   # 2.4 % off
    good = rate_item(stamps, 1015.0, 10.0)                  # 1.5 % off
    assert good.status == PASS and good.value == '1000.0 Hz, 0.0% lost, 1000 msg/s received'
    keep = np.random.default_rng(0).random(stamps.size) > 0.1
    item = rate_item(stamps[keep], 1000.0, 10.0)
    assert item.status == WARN and number(item.value, 1) == pytest.approx(10.0, abs=1.0)
    late = rate_item(stamps, 1000.0, 12.0)  # 10 s of stamps arrived in 12 s
    assert late.status == WARN and late.value.endswith('833 msg/s received')
    assert 'falls behind real time' in late.hint


@pytest.mark.parametrize(('jitter_s', 'lost', 'burst_s', 'rel'), [
    (1e-4, 0.5, 0.002, 2e-5),    # half the samples lost in 2 ms bursts
    (2.5e-4, 0.3, 0.003, 2e-3),  # jitter a quarter period and 30 % lost
    (1e-4, 0.05, 0.5, 2e-5),     # long bursts
])
def test_rate_robust_to_dropouts_and_jitter(jitter_s: float, lost: float, burst_s: float,
                                            rel: float) -> None:
    spec = replace(PRESETS['ideal'], clock_drift_ppm=50.0, stamp_jitter_s=jitter_s,
                   dropout_fraction=lost, dropout_burst_s=burst_s)
    stamps, _ = stream(spec)
    assert measured_rate(stamps) == pytest.approx(1000.0 / (1 + 50e-6), rel=rel)


def test_out_of_order_and_duplicate_stamps_counted_exactly() -> None:
    stamps, _ = stream(PRESETS['ideal'], duration_s=1.0)
    bad = stamps.copy()
    bad[[100, 200]] = bad[[200, 100]]   # swapped: 101..200 fall below 200's stamp: 100
    bad[500] = bad[499]                 # one duplicate
    bad[700] = bad[10]                  # one far in the past
    item = monotonic_item(bad)
    assert item.status == FAIL
    assert item.value.startswith(f'101 out of order, 1 duplicates in {stamps.size} (by up to')
    local = stamps.copy()
    local[[100, 101]] = local[[101, 100]]  # 1 ms behind: the nodes re-order it
    item = monotonic_item(local)
    assert item.status == WARN and 'reorder_window_s' in item.hint
    assert item.value == f'1 out of order, 0 duplicates in {stamps.size} (by up to 1 ms)'
    local[300] = local[300] - 60_000_000  # 60 ms behind: beyond the 50 ms window
    assert monotonic_item(local).status == FAIL


def test_no_data_fails_every_imu_item_without_raising() -> None:
    empty, none3 = np.zeros(0, np.int64), np.zeros((0, 3))
    spec = PRESETS['adxl355']
    items = [rate_item(empty, 1000.0, 1.0), jitter_item(empty, 1000.0), monotonic_item(empty),
             gravity_item(none3), noise_item(empty, none3, spec)]
    assert [i.status for i in items] == [FAIL] * 5
    nan = np.full((5000, 3), np.nan)
    assert gravity_item(nan).status == FAIL
    assert noise_item(np.arange(5000) * 10**6 + T0_NS, nan, spec).status == FAIL


def test_odometry_nodes_and_outputs() -> None:
    t = np.arange(100) * 20_000_000 + T0_NS
    assert odom_item(t[:0], np.zeros(0), 2.0).status == FAIL
    assert odom_item(t, np.full(100, 20.0), 2.0) == Item(
        'odometry', PASS, '50.0 Hz, speed 20 m/s', '>= 1 Hz, finite speed')
    assert odom_item(t[:1], np.array([20.0]), 2.0).status == WARN
    assert odom_item(t, np.r_[np.full(99, 20.0), np.nan], 2.0).status == FAIL
    assert node_item('irregularity_node', {'irregularity_node'}).status == PASS
    assert node_item('uncertainty_node', {'irregularity_node'}).status == FAIL
    assert output_item('track/irregularity', TopicStats(2000, 0), 2.0, 1000.0).status == PASS
    assert output_item('track/irregularity', TopicStats(2000, 1), 2.0, 1000.0).status == FAIL
    assert output_item('track/irregularity', TopicStats(0, 0), 2.0, 1000.0).status == FAIL
    assert output_item('track/irregularity', TopicStats(900, 0), 2.0, 1000.0).status == WARN
    assert output_item('track/irregularity', TopicStats(2000, 0, 300), 2.0, 1000.0).status == PASS
    assert output_item('track/irregularity', TopicStats(2000, 0, 2000), 2.0, 1000.0).status == WARN


def test_output_stats_count_only_unflagged_non_finite_values() -> None:
    nan = np.nan
    points = np.array([[1.0, 0, 1e-3], [2.0, 1, -1e-3], [3.0, 2, nan],  # valid, degraded, invalid
                       [4.0, 0, nan], [5.0, 2, 1e-3], [nan, 2, nan], [6.0, 0, np.inf]])
    assert output_stats(points, quality_in_y=True) == TopicStats(7, 3, 1)
    bands = np.array([[-1e-3, 0.0, 1e-3], [nan, nan, nan], [nan, 0.0, 1e-3], [0.0, np.inf, 1.0]])
    assert output_stats(bands, quality_in_y=False) == TopicStats(4, 2, 1)


def test_checklist_text_json_and_exit_code(adxl: tuple) -> None:
    spec = PRESETS['adxl355']
    odom_t = np.arange(500) * 20_000_000 + T0_NS
    good = Observation(10.0, *adxl, odom_t, np.full(500, 20.0),
                       frozenset({'irregularity_node', 'uncertainty_node'}),
                       {'track/irregularity': TopicStats(9900), 'track/irregularity_band':
                        TopicStats(9900)})
    items = checklist(good, spec)
    assert [i.status for i in items] == [PASS] * len(items) and exit_code(items) == 0
    assert [i.name for i in items] == [
        'imu rate', 'stamp jitter', 'stamp order', 'gravity axis', 'noise density', 'odometry',
        'node irregularity_node', 'output track/irregularity', 'node uncertainty_node',
        'output track/irregularity_band']
    assert format_items(items).splitlines()[-1] == 'result: PASS (0 failed, 0 warnings)'
    bare = checklist(Observation(10.0, *adxl), spec)
    assert exit_code(bare) == 1
    assert [i.name for i in bare if i.status == FAIL] == [
        'odometry', 'node irregularity_node', 'output track/irregularity',
        'node uncertainty_node', 'output track/irregularity_band']
    text = format_items(bare)
    assert 'FAIL  node uncertainty_node' in text and text.endswith('(5 failed, 0 warnings)')
    doc = json.loads(items_json(bare))
    assert doc['status'] == FAIL and len(doc['items']) == 10
    assert doc['items'][0] == {'name': 'imu rate', 'status': PASS, 'value': bare[0].value,
                               'expected': '1000 Hz +- 2%', 'hint': ''}
