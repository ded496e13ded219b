"""Calibration from a reference run against simulation truth (issue 12 item 6)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from railgsa_ros.bag.run import write_run
from railgsa_ros.calibrate import calibrate, discrepancy_std
from railgsa_ros.cli.main import main
from railgsa_ros.imu import accel_covariance, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import score
from railgsa_ros.inverse.sensor import sensor_delay_s
from railgsa_ros.scenario import run_scenario
from railgsa_ros.track import save_csv
from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands
from railgsa_ros.uncertainty.coverage import truth_at
from railgsa_ros.uncertainty.parameters import load_discrepancy, load_uncertainty
from railgsa_ros.uq.distributions import Normal
from railgsa_ros.vehicle import VehicleParams, load_vehicle

NOMINAL = VehicleParams()
TRUE = NOMINAL.as_array() * np.array([1.0, 1.0, 1.15, 0.90, 0.85])  # the mismatch
PRIOR = {k: Normal(getattr(NOMINAL, k), 0.1 * getattr(NOMINAL, k), lower=0.0)
         for k in ('k_s', 'k_us', 'c')}
STRETCH = (300.0, 900.0)  # m from the first sample: 500 m scored after the 50 m margins
REST_M = 950.0  # the rest of the run starts here


@pytest.fixture(scope='module')
def run():
    return run_scenario('german-low', 30.0, 70.0, None, 'bmi088', seed=1, vehicle=TRUE)


def _calibrate(run, names=None):
    """k_s and c (or ``names``) calibrated on STRETCH of ``run`` from PRIOR."""
    return calibrate(run.stamps_ns, run.accel[:, 2], run.speed_mps, _reference(run),
                     InversionConfig(rate_hz=run.rate_hz), NOMINAL, PRIOR,
                     **({} if names is None else {'names': names}))


@pytest.fixture(scope='module')
def calibrated(run):
    """The default calibration of ``run`` (one fit shared by the tests that read it)."""
    return _calibrate(run)


def _reference(run):
    x = run.chainage_m - run.chainage_m[0]
    keep = (x >= STRETCH[0]) & (x <= STRETCH[1])  # after the filters' warm-up (INVALID)
    return x[keep], run.truth_u_m[keep]


def _rest_rmse(run, theta) -> float:
    """D1 RMSE of the reconstruction with theta on the run beyond the calibration stretch."""
    pipe = InversionPipeline(InversionConfig(rate_hz=run.rate_hz), theta)
    out = Output.concat([pipe.push(run.stamps_ns, run.accel[:, 2], run.speed_mps),
                         pipe.flush()])
    rest = (out.chainage_m > REST_M) & (out.quality != Quality.INVALID)
    return score(out.chainage_m[rest] + run.chainage_m[0], out.u_m[rest], run.chainage_m,
                 run.truth_u_m).rmse


def test_calibration_recovers_k_s_and_c_and_the_true_parameter_accuracy(run, calibrated):
    cal = calibrated
    true = TRUE[[2, 4]]
    std = np.sqrt(np.diag(cal.covariance))
    assert np.all(np.abs(cal.mean - true) < np.maximum(4 * std, 0.02 * true))
    assert np.all(std < 0.25 * np.array([PRIOR['k_s'].std(), PRIOR['c'].std()]))  # narrower
    nominal, truth, calibrated = (_rest_rmse(run, t) for t in (NOMINAL.as_array(), TRUE,
                                                                cal.theta))
    assert calibrated <= 1.3 * truth < nominal


def _posterior_band(run, cal, noise_variance: float | None, discrepancy_m: float = 0.0):
    """The 95 % band of the whole run with the posterior law of ``cal`` (a calibration on
    STRETCH), the band's accelerometer variance (m/s^2)^2 (None: the policy measures it) and
    ``discrepancy_m``: (band, inversion config, quantiles)."""
    config = InversionConfig(rate_hz=run.rate_hz)
    law = {**PRIOR, **{n: Normal(d['mu'], d['sigma'], lower=0.0)
                       for n, d in cal.uncertainty().items()}}
    ucfg = UncertaintyConfig(inversion=config, qoi='', discrepancy_std_m=discrepancy_m)
    band = offline_bands(run.stamps_ns, run.accel, (run.stamps_ns, run.speed_mps), config=ucfg,
                         vehicle=cal.vehicle(), dists=law,
                         noise_variance=noise_variance)
    return band, config, (ucfg.lower_quantile, ucfg.upper_quantile)


def _rest_coverage(run, band) -> float:
    """Share of the rest of the run (published samples, 100 m end margin) whose D1 truth is
    inside the band."""
    truth = truth_at(run, band, InversionConfig(rate_hz=run.rate_hz))
    keep = ((band.chainage_m > REST_M) & (band.chainage_m < band.chainage_m[-1] - 100.0)
            & (band.quality != Quality.INVALID))
    hit = (truth[keep] >= band.lower_m[keep]) & (truth[keep] <= band.upper_m[keep])
    return float(np.mean(hit))


def test_discrepancy_makes_the_calibrated_band_hold_the_truth_on_the_rest():
    """An error source in no band term (the accelerometer 4x noisier than the band is told, no
    clock drift: a stationary error): the calibrated band misses the truth; the discrepancy
    measured on the reference stretch brings the rest of the run near the nominal 95 %."""
    noisy = imu_spec('bmi088', clock_drift_ppm=0.0,
                     noise_density=4 * imu_spec('bmi088').noise_density)
    extra = run_scenario('german-low', 30.0, 45.0, None, noisy, seed=1, vehicle=TRUE)
    told = float(accel_covariance(imu_spec('bmi088')))
    cal = _calibrate(extra)
    band, config, quantiles = _posterior_band(extra, cal, told)
    gap = discrepancy_std(band, _reference(extra), config, quantiles)
    assert _rest_coverage(extra, band) < 0.8
    widened, *_ = _posterior_band(extra, cal, told, gap)
    assert 0.90 <= _rest_coverage(extra, widened) <= 0.99


def test_discrepancy_is_zero_on_exact_physics():
    """Noise-free exact physics and an exact reference: nothing is left beyond the band."""
    exact = run_scenario('german-low', 30.0, 35.0, None, 'ideal', seed=2, vehicle=TRUE)
    band, config, quantiles = _posterior_band(exact, _calibrate(exact), None)
    half = np.nanmean(band.upper_m - band.lower_m) / 2
    assert discrepancy_std(band, _reference(exact), config, quantiles) <= 0.01 * half


def test_k_us_is_not_identifiable(run, calibrated):
    """Fisher information: adding k_us raises the condition number by orders of magnitude and
    its posterior stays an order of magnitude wider (relative) than those of k_s and c."""
    two = calibrated
    three = _calibrate(run, ('k_s', 'k_us', 'c'))
    assert three.condition > 100 * two.condition
    rel = np.sqrt(np.diag(three.covariance)) / three.mean
    assert rel[1] > 10 * max(rel[0], rel[2])


def test_cli_writes_vehicle_and_uncertainty_files_every_entry_point_reads(run, tmp_path, capsys):
    bag = write_run(tmp_path / 'run', run)
    ref = tmp_path / 'ref.csv'
    save_csv(ref, *_reference(run))
    prior = tmp_path / 'prior.yaml'
    prior.write_text('parameters:\n' + ''.join(
        f'  {k}: {{dist: normal, mu: {d.mu!r}, sigma: {d.sigma!r}}}\n' for k, d in PRIOR.items()))
    veh, unc = tmp_path / 'veh.yaml', tmp_path / 'unc.yaml'
    assert main(['calibrate', str(bag), '--reference', str(ref), '--uncertainty', str(prior),
                 '--out-vehicle', str(veh), '--out-uncertainty', str(unc)]) == 0
    assert 'k_s = ' in capsys.readouterr().out
    vehicle = load_vehicle(veh)
    assert vehicle.k_s == pytest.approx(TRUE[2], rel=0.03)
    law = load_uncertainty(unc)
    assert set(law) == {'k_s', 'k_us', 'c'} and law['k_us'] == PRIOR['k_us']
    assert law['k_s'].sigma < 0.25 * PRIOR['k_s'].sigma
    assert load_discrepancy(unc) > 0.0  # the BMI088 run's uncompensated delay and drift
    assert main(['invert', str(bag), '--vehicle', str(veh), '--csv', str(tmp_path / 'u.csv'),
                 '--bands', '--uncertainty', str(unc)]) == 0
    # a reference that does not belong to the run is refused, not fitted
    assert main(['calibrate', str(bag), '--reference', str(ref), '--offset', '37',
                 '--out-vehicle', str(tmp_path / 'v2.yaml'),
                 '--out-uncertainty', str(tmp_path / 'u2.yaml')]) == 2
    assert 'does not match' in capsys.readouterr().err


def test_a_misregistered_reference_is_fitted_not_bent_into_the_vehicle(run, calibrated):
    """A reference 0.3 m off (a survey registered to a few decimetres) gives the same vehicle:
    its shift is a parameter of the fit (without it, 0.1 m made k_s 8 SD and c 16 SD off)."""
    x, u = _reference(run)
    shifted = calibrate(run.stamps_ns, run.accel[:, 2], run.speed_mps, (x + 0.3, u),
                        InversionConfig(rate_hz=run.rate_hz), NOMINAL, PRIOR)
    assert shifted.shift_m - calibrated.shift_m == pytest.approx(0.3, abs=0.01)
    std = np.sqrt(np.diag(calibrated.covariance))
    assert np.all(np.abs(shifted.mean - calibrated.mean) < std)


def test_the_sensor_delay_is_fitted_and_written_where_every_command_reads_it(tmp_path, capsys):
    """A BMI088 at 200 Hz ODR (its datasheet's 80 Hz cut-off: 5.24 ms, simulated with its chip
    filter; clock drift and jitter off, so the delay is the filter's alone) at 30 m/s with a
    registered reference (--registration-sd 1 cm): --fit-delay recovers the delay from no
    prior knowledge (prior centre 0, std 20 ms) within its posterior std, writes it to the
    params file, and railgsa invert --params FILE then scores as well as with the datasheet
    delay given by hand and better than without."""
    spec = imu_spec('bmi088@200Hz', clock_drift_ppm=0.0, stamp_jitter_s=0.0)
    run = run_scenario('german-low', 30.0, 40.0, None, spec, seed=1, vehicle=TRUE)
    bag = write_run(tmp_path / 'run', run)
    ref = tmp_path / 'ref.csv'
    save_csv(ref, *_reference(run))
    out = {k: tmp_path / f'{k}.yaml' for k in ('veh', 'unc', 'params')}
    base = tmp_path / 'base.yaml'  # the params file the runs use: kept, the delay set in it
    base.write_text('/**:\n  ros__parameters:\n    band: d1\n    sensor_delay_s: 0.0\n')
    assert main(['calibrate', str(bag), '--reference', str(ref), '--registration-sd', '0.01',
                 '--fit-delay', '--out-params', str(out['params']), '--base-params', str(base),
                 '--out-vehicle', str(out['veh']), '--out-uncertainty', str(out['unc'])]) == 0
    assert 'sensor delay' in capsys.readouterr().out
    fitted = yaml.safe_load(out['params'].read_text())['/**']['ros__parameters']
    assert fitted['band'] == 'd1'
    tau = sensor_delay_s('bmi088@200Hz')
    assert abs(fitted['sensor_delay_s'] - tau) < max(2 * fitted['delay_std_s'], 0.5e-3)
    assert fitted['delay_std_s'] < 1e-3
    errors = {}
    for name, extra in (('fitted', ['--params', str(out['params'])]),
                        ('datasheet', ['--sensor-delay', 'bmi088@200Hz']), ('none', [])):
        csv = tmp_path / f'{name}.csv'
        assert main(['invert', str(bag), '--vehicle', str(out['veh']), '--csv', str(csv),
                     *extra]) == 0
        data = np.genfromtxt(csv, delimiter=',', names=True)
        ok = np.isfinite(data['u_m']) & (data['chainage_m'] > 100.0)
        errors[name] = score(data['chainage_m'][ok] + run.chainage_m[0], data['u_m'][ok],
                             run.chainage_m, run.truth_u_m).rmse
    assert errors['fitted'] < 1.1 * errors['datasheet'] and errors['fitted'] < errors['none']
    # --fit-delay without a file to write it to is refused
    assert main(['calibrate', str(bag), '--reference', str(ref), '--fit-delay',
                 '--out-vehicle', str(out['veh']), '--out-uncertainty', str(out['unc']),
                 '--overwrite']) == 2
    capsys.readouterr()
    # at constant speed a reference registered to 2 m cannot tell a delay from its shift
    assert main(['calibrate', str(bag), '--reference', str(ref), '--fit-delay',
                 '--out-params', str(tmp_path / 'p2.yaml'), '--out-vehicle',
                 str(tmp_path / 'v2.yaml'), '--out-uncertainty', str(tmp_path / 'u2.yaml')]) == 2
    assert 'not told apart' in capsys.readouterr().err
    assert not (tmp_path / 'p2.yaml').exists()
