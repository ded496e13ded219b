"""A coach bag end to end: ``railgsa simulate --vehicle coach.yaml``, ``railgsa invert``, the
live irregularity_node.

Truth: the simulator's ``/track/irregularity_truth`` (the profile at the reference wheelset,
the project's independent multibody simulation: one exact bank per wheelset), band-passed to
EN 13848 D1 on distance by FFT (``score.band_distance``). The D1 error of the VALID outputs is
compared with what the pipeline reports (``observability.std_m``), with the quarter car on the
same bag, and with the coach inverted without its gyro.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from railgsa_ros.cli.main import main
from railgsa_ros.input.options import InputOptions
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.models import load_model
from railgsa_ros.offline import Driver, Source, chunks, nominal_rate_hz, peek, steps
from railgsa_ros.review.truth import load_truth
from railgsa_ros.uncertainty import UncertaintyConfig

COACH = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
SPEED = 20.0


def simulate(out: Path, vehicle: Path, seconds: float, seed: int) -> Path:
    """A coach bag: the project's simulator, BMI088 (accelerometer and gyro), 20 m/s."""
    assert main(['simulate', '--out', str(out), '--vehicle', str(vehicle), '--sensor', 'bmi088',
                 '--speed', str(SPEED), '--duration', str(seconds), '--seed', str(seed)]) == 0
    return out


def centre_coach(tmp: Path) -> Path:
    """The shipped coach with its IMU at the car-body centre."""
    doc = yaml.safe_load(COACH.read_text())
    doc['imus'] = [{'name': 'car_centre', 'x_m': 0.0}]
    path = tmp / 'coach_centre.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp('coach')
    centre = centre_coach(tmp)
    return {'bogie': simulate(tmp / 'bogie', COACH, 100.0, 3),
            'centre': simulate(tmp / 'centre', centre, 100.0, 4), 'centre_yaml': centre}


def d1_errors(bag: Path, stamps_ns: np.ndarray, u_m: np.ndarray) -> np.ndarray:
    """Output minus the D1 truth at the chainage the truth gives each output's stamp (m)."""
    truth = load_truth(bag)
    assert truth.stamps_ns is not None
    x = np.arange(truth.chainage_m[0], truth.chainage_m[-1], 0.25)
    d1 = band_distance(np.interp(x, truth.chainage_m, truth.u_m), 0.25, 'd1')
    at = np.interp(stamps_ns.astype(float), truth.stamps_ns.astype(float), truth.chainage_m)
    return u_m - np.interp(at, x, d1)


def rmse(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values ** 2)))


def invert_csv(bag: Path, out: Path, *vehicle: str) -> dict[str, np.ndarray]:
    """``railgsa invert BAG --csv`` (with ``--vehicle FILE``) read back."""
    assert main(['invert', str(bag), '--csv', str(out), '--quiet', *vehicle]) == 0
    rows = np.genfromtxt(out, delimiter=',', names=True, dtype=None, encoding='utf-8')
    stamps = np.array([round(float(t) * 1e9) for t in rows['t_s']], dtype=np.int64)
    return {'stamps_ns': stamps, 'u_m': rows['u_m'], 'quality': rows['quality']}


def drive(bag: Path, vehicle: Any, gyro: bool = True) -> tuple[Output, Driver]:
    """The offline driver over the bag at its measured rate (``gyro`` False: the Imu
    messages' angular velocity withheld)."""
    source = Source(bag)
    first, pieces = peek(chunks(source))
    config = UncertaintyConfig().with_(
        inversion=InversionConfig(rate_hz=nominal_rate_hz(first, source)))
    driver = Driver(config, vehicle, None, InputOptions())
    if not gyro:
        pieces = (replace(p, angular_velocity=None) for p in pieces)
    out = [Output(s.stamps_ns, s.chainage_m, s.u_m, s.quality, s.speed_mps)
           for s in steps(driver, pieces)]
    return Output.concat(out), driver


def test_invert_a_coach_bag_near_its_reported_error(bags: dict[str, Path],
                                                    tmp_path: Path) -> None:
    """IMU above the leading bogie: the VALID outputs' D1 error is the pipeline's reported
    error std (within sampling error: the error sits in a few narrow nulls) and a small
    fraction of the quarter car's on the same bag; --bands with a coach: the nominal output
    and a warning (no band for a coach yet)."""
    bag = bags['bogie']
    coach = invert_csv(bag, tmp_path / 'coach.csv', '--vehicle', str(COACH))
    quarter = invert_csv(bag, tmp_path / 'quarter.csv')
    valid = coach['quality'] == Quality.VALID
    assert valid.sum() > 10 * 400  # 10 s of VALID outputs
    error = rmse(d1_errors(bag, coach['stamps_ns'][valid], coach['u_m'][valid]))
    _, driver = drive(bag, load_model(COACH))
    assert driver.nominal.channels == ('accel_z', 'pitch_rate')
    pipeline = driver.nominal.pipeline
    assert pipeline is not None and pipeline.observability is not None
    reported = float(pipeline.observability.std_m(SPEED))
    assert reported / 1.5 < error < 1.5 * reported, (error, reported)
    q_valid = quarter['quality'] == Quality.VALID
    quarter_error = rmse(d1_errors(bag, quarter['stamps_ns'][q_valid], quarter['u_m'][q_valid]))
    assert error < quarter_error / 5, (error, quarter_error)
    banded = invert_csv(bag, tmp_path / 'banded.csv', '--vehicle', str(COACH), '--bands')
    np.testing.assert_array_equal(banded['u_m'], coach['u_m'])


def test_the_gyro_lowers_the_car_centre_error(bags: dict[str, Path]) -> None:
    """IMU at the car-body centre: with the pitch rate (REP 103 angular_velocity.y) the D1
    error is lower than from the accelerometer alone, and each is its reported error."""
    model = load_model(bags['centre_yaml'])
    errors, reported = {}, {}
    for gyro in (True, False):
        out, driver = drive(bags['centre'], model, gyro)
        assert driver.nominal.gyro is gyro
        valid = out.quality == Quality.VALID
        errors[gyro] = rmse(d1_errors(bags['centre'], out.stamps_ns[valid], out.u_m[valid]))
        pipeline = driver.nominal.pipeline
        assert pipeline is not None and pipeline.observability is not None
        reported[gyro] = float(pipeline.observability.std_m(SPEED))
        assert reported[gyro] / 1.5 < errors[gyro] < 1.5 * reported[gyro], (errors, reported)
    assert errors[True] < errors[False], errors
    assert reported[True] < reported[False], reported


def test_the_live_node_gives_the_offline_result(bags: dict[str, Path], ros_context: Any) -> None:
    """irregularity_node with ``vehicle_file`` a coach, fed the bag's serialized Imu and
    Odometry messages (IMU in batches of up to 50, as its reader thread takes them; each
    odometry message with the IMU messages logged before it), then flushed: it publishes the
    offline driver's outputs, stamp for stamp."""
    from rclpy.parameter import Parameter

    from railgsa_ros.bag import open_bag
    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    bag = bags['bogie']
    offline, driver = drive(bag, load_model(COACH))
    params = {'vehicle_file': str(COACH), 'rate_hz': driver.nominal.config.rate_hz,
              'idle_flush_s': 3600.0}
    node = IrregularityNode(context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])
    outs: list[Output] = []
    publish = node.emit

    def emit(result: Output | None, live: int) -> Output | None:  # every published output
        if result is not None and len(result):
            outs.append(result)
        return publish(result, live)

    node.emit = emit  # type: ignore[method-assign,assignment]

    imu: list[bytes] = []
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic in ('/imu/data', '/odom')]
        for conn, _, raw in reader.messages(connections=conns):
            if conn.topic == '/odom':
                node.process(imu)
                node.process((), [bytes(raw)])
                imu = []
                continue
            imu.append(bytes(raw))
            if len(imu) == 50:
                node.process(imu)
                imu = []
    node.process(imu)
    node.flush('test')
    assert node.policy is not None and node.policy.channels == ('accel_z', 'pitch_rate')
    live = Output.concat(outs)
    node.destroy_node()
    np.testing.assert_array_equal(live.stamps_ns, offline.stamps_ns)
    np.testing.assert_array_equal(live.quality, offline.quality)
    np.testing.assert_allclose(live.u_m, offline.u_m, rtol=0, atol=1e-12)


def swapped(piece: Any) -> Any:
    """A piece whose IMU messages arrive pairwise swapped (2.5 ms apart: within the re-order
    window), every column of a message with it."""
    order = np.arange(piece.stamps_ns.size)
    pairs = order[:order.size // 2 * 2].reshape(-1, 2)[:, ::-1].ravel()
    order[:pairs.size] = pairs
    return replace(piece, stamps_ns=piece.stamps_ns[order], accel=piece.accel[order],
                   frame_ids=piece.frame_ids[order], covariance=piece.covariance[order],
                   angular_velocity=piece.angular_velocity[order],
                   gyro_covariance=piece.gyro_covariance[order])


def test_reordered_messages_keep_their_pitch_rates(bags: dict[str, Path]) -> None:
    """Messages out of stamp order within the re-order window: the stage re-orders each
    message's pitch rate with its acceleration, so the outputs are those of the ordered
    bag; and the pitch rate counts (a rate taken from the wrong message changes them)."""
    model = load_model(bags['centre_yaml'])
    ordered, _ = drive(bags['centre'], model)
    source = Source(bags['centre'])
    config = UncertaintyConfig().with_(inversion=InversionConfig(
        rate_hz=nominal_rate_hz(next(iter(chunks(source))), source)))
    outs = []
    for shift in (False, True):
        driver = Driver(config, model, None, InputOptions())
        pieces = (swapped(p) for p in chunks(source))
        if shift:  # each rate one message late
            pieces = (replace(p, angular_velocity=np.roll(p.angular_velocity, 1, axis=0))
                      for p in pieces)
        outs.append(Output.concat([Output(s.stamps_ns, s.chainage_m, s.u_m, s.quality,
                                          s.speed_mps) for s in steps(driver, pieces)]))
        assert driver.counters['reordered'] > 0
    np.testing.assert_array_equal(outs[0].stamps_ns, ordered.stamps_ns)
    np.testing.assert_array_equal(outs[0].u_m, ordered.u_m)
    assert not np.array_equal(outs[1].u_m, ordered.u_m, equal_nan=True)
