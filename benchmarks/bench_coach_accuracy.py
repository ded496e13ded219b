"""Coach accuracy: the project's coach inversion beside the LMMSE limit of one run (issue #21).

Data from the independent coach of test/reference (coach_ode: a 10-DOF vertical multibody ODE,
solve_ivp), not from the project's code path, with the parameters of the vehicle file
(``--vehicle``, default config/vehicles/coach.yaml) mapped by reference.project_map (contact
per wheel -> per wheelset, spacings -> semi-spacings; test_coach_against_reference holds the two
to 1e-6): a Gaussian draw of the German low spectrum plus an 8 mm cosine dip over 6 m in the
middle of the run (faded in over the first 80 m of track, so that the coach starts at rest), 20
and 40 m/s, chainage of the file's reference wheelset. Sensors: an ADXL355-like accelerometer
(white noise 25 ug/sqrt(Hz), 1 kHz) above the leading bogie or at the car centre, with or
without a gyro's pitch rate (0.014 deg/s/sqrt(Hz)).

Limit: the exact finite-record LMMSE of the D1 profile with the true coach, the track spectrum
as prior and the sensors' noise (reference.lmmse.lmmse_estimate) on the same samples, scored
like the project (railgsa_ros.inverse.score.score: D1 on distance, 100 m left out at each end);
beside it the infinite-record posterior RMSE from the spectra (in expectation a lower bound for
any record) and, with ``--draws N``, the mean +- std of the finite-record LMMSE's RMSE over N
records of the same length drawn from the model (reference.lmmse.synthetic_record): how far one
run's limit strays from its expectation.

Project: railgsa_ros.inverse.pipeline.InversionPipeline with the file's coach, its IMU moved to
the case's position (dataclasses.replace of the geometry), channels accel_z (+ pitch_rate with
the gyro), the sensors' noise as the config's noise_std_mps2 / gyro_noise_std_rads, odometry
speed; its VALID and DEGRADED outputs scored like the limit. Beside it what the pipeline
reports: ``observability.std_m`` (its FIR's error std) and ``limit_std_m`` (its LMMSE limit).
Last column, a diagnostic: the ratio over the scored points at least two band windows
(``window_half_width``) before the run's end.
Target of issue #21: at most 1.5x the limit.

Robustness: the truth's suspension (k_p, c_p, k_s, c_s) 10-20 % off the file (factors drawn
from the seed, printed), the project inverting with the file's values (nominal) and with the
true ones: the error the calibration has to remove.

Usage: python benchmarks/bench_coach_accuracy.py [--length 800] [--seed 1] [--vehicle PATH]
    [--draws N] [--quick] [--no-robustness]
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
import sys
import time

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from tables import header, run_options

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))  # the reference package

from reference.coach_ode import CoachRun, Params, simulate, wheelset_offsets
from reference.lmmse import (
    D1_M,
    Channel,
    G,
    band_power,
    lmmse_estimate,
    posterior_rmse,
    synthesize_profile,
    synthetic_record,
)
from reference.project_map import reference_params

from railgsa_ros.inverse.band import band_limits, bandpass_power
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import band_distance, score
from railgsa_ros.models import load_model
from railgsa_ros.models.coach import PARAM_NAMES, CoachModel, ImuPosition

RATE_HZ = 1000.0
ACC_DENSITY = 25e-6 * G  # m/s^2/sqrt(Hz)
GYRO_DENSITY = np.deg2rad(0.014)  # rad/s/sqrt(Hz)
CONFIG = InversionConfig(rate_hz=RATE_HZ, noise_std_mps2=ACC_DENSITY * np.sqrt(RATE_HZ / 2),
                         gyro_noise_std_rads=GYRO_DENSITY * np.sqrt(RATE_HZ / 2))
DIP_M, DIP_DEPTH_M = 6.0, 8e-3
FADE_M = (30.0, 80.0)  # track chainage over which the profile fades in
DX_M = 0.25  # profile grid of the quintic spline and of the scores, m
MARGIN_M = 100.0  # left out of the scores at each end of a run (the band-pass's edges)
START_NS = 1_700_000_000 * 10 ** 9
DEFAULT_VEHICLE = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
SUSPENSION = ('k_p', 'c_p', 'k_s', 'c_s')  # the robustness rows' off parameters
OFF_RANGE = (0.10, 0.20)  # their relative error, either sign


@dataclass(frozen=True)
class Truth:
    """A simulated run of the reference coach: the run, the profile, the dip's start (m) and
    the reference's parameters; on a DX_M grid x over the run's chainage, the D1 band of the
    profile under the reference wheelset (zero-phase on distance, as the score applies it)."""

    run: CoachRun
    u: BSpline
    dip_at: float
    params: Params

    @property
    def profile(self) -> np.ndarray:
        """The profile (m) under the reference wheelset at each sample."""
        return self.u(self.run.chainage)

    @cached_property
    def x(self) -> np.ndarray:
        return np.arange(self.run.chainage[0], self.run.chainage[-1], DX_M)

    @cached_property
    def band(self) -> np.ndarray:
        return band_distance(self.u(self.x), DX_M)


def track(length_m: float, dip_at_m: float, seed: int) -> BSpline:
    """Rail profile u(x) (m): German low, faded in over FADE_M, plus the cosine dip at dip_at_m,
    as a C4 quintic spline (smooth enough for the integrator)."""
    n = int(np.ceil(length_m / DX_M)) + 1
    x = np.arange(n) * DX_M
    u = synthesize_profile(2 * n, DX_M, np.random.default_rng(seed))[:n]  # not periodic
    u *= 0.5 - 0.5 * np.cos(np.pi * np.clip((x - FADE_M[0]) / np.diff(FADE_M), 0.0, 1.0))
    phase = np.clip((x - dip_at_m) / DIP_M, 0.0, 1.0)
    u -= DIP_DEPTH_M / 2 * (1.0 - np.cos(2 * np.pi * phase))
    return make_interp_spline(x, u, k=5)


def coach_run(params: Params, reference: int, length_m: float, speed: float,
              seed: int) -> Truth:
    """The reference coach over length_m of record; the last wheelset starts on the flat
    track at 1 m."""
    start = 1.0 + wheelset_offsets(params, reference).max()
    dip_at = start + length_m / 2
    u = track(start + length_m + 10.0, dip_at, seed)
    t = np.arange(0.0, length_m / speed, 1.0 / RATE_HZ)
    run = simulate(params, u, speed, t, start_m=start, reference=reference)
    return Truth(run, u, dip_at, params)


def scored(truth: Truth, chain: np.ndarray, used: np.ndarray) -> np.ndarray:
    """The grid points (bool (X,)) that are scored: MARGIN_M or more from the run's ends and
    within DX_M / 2 of a used output (at chainage ``chain``, ``used``: VALID or DEGRADED)."""
    x, c = truth.x, chain[used]
    j = np.clip(np.searchsorted(c, x), 1, max(c.size - 1, 1))
    near = np.minimum(np.abs(x - c[j - 1]), np.abs(c[j] - x)) <= DX_M / 2 if c.size > 1 \
        else np.zeros(x.size, bool)
    return near & (x >= x[0] + MARGIN_M) & (x <= x[-1] - MARGIN_M)


def errors(truth: Truth, chain: np.ndarray, u: np.ndarray, keep: np.ndarray
           ) -> tuple[float, float]:
    """(D1 RMSE, dip peak error) m of the estimate u at chainage ``chain`` over the grid points
    ``keep``; the peak error as ``score.score``'s (|extreme - extreme| over the dip +- its
    length)."""
    x = truth.x
    rec = np.interp(x, chain, u)
    win = keep & (x >= truth.dip_at - DIP_M) & (x <= truth.dip_at + 2 * DIP_M)
    peak = float(abs(rec[win][np.argmax(np.abs(rec[win]))]
                     - truth.band[win][np.argmax(np.abs(truth.band[win]))])) if win.any() \
        else float('nan')
    return float(np.sqrt(np.mean((rec - truth.band)[keep] ** 2))), peak


def at_imu(model: CoachModel, x_m: float) -> CoachModel:
    """The file's coach with its one IMU x_m (m) forward of the car-body centre."""
    return CoachModel(model.params, replace(model.geometry,
                                            imus=(ImuPosition('imu', x_m),)))


def project_d1(truth: Truth, data: list[np.ndarray], model: CoachModel, theta: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, InversionPipeline]:
    """The project's offline inversion of the data (accelerometer first, then the pitch rate
    if given; +g, odometry) with the coach's parameters theta: chainage (m, the truth's axis),
    u (m), which outputs are VALID or DEGRADED, and the pipeline."""
    run = truth.run
    channels = ('accel_z', 'pitch_rate')[:len(data)]
    pipe = InversionPipeline(CONFIG, theta, model=model, channels=channels)
    stamps = START_NS + np.round(run.t * 1e9).astype(np.int64)
    rates = {'rates': data[1]} if len(data) > 1 else {}
    out = Output.concat([pipe.push(stamps, data[0] + CONFIG.gravity_mps2, run.speed, **rates),
                         pipe.flush()])
    return out.chainage_m + run.chainage[0], out.u_m, out.graded <= Quality.DEGRADED, pipe


def window_m(pipe: InversionPipeline, speed: float) -> float:
    """Half-width (m) of the band window that grades the pipeline's outputs at speed (m/s)."""
    return float(pipe.window_half_width(np.array([speed]))[0]) / RATE_HZ * speed


def limit_d1(truth: Truth, channels: list[Channel], data: list[np.ndarray],
             reference: int) -> np.ndarray:
    """The finite-record LMMSE estimate (m) of the D1 profile from the data, true coach."""
    z, _ = lmmse_estimate(truth.params, channels, float(truth.run.speed[0]), np.array(data),
                          RATE_HZ, reference=reference)
    return z


def expected_limit(params: Params, channels: list[Channel], speed: float, length_m: float,
                   draws: int, reference: int, rng: np.random.Generator) -> str:
    """'mean +- std' (mm) of the finite-record LMMSE's D1 RMSE over ``draws`` model records of
    length_m, scored like the runs ('' for none). Each record is the first quarter of a
    periodic draw: a stretch of a stationary process."""
    if draws == 0:
        return ''
    t = round(length_m / speed * RATE_HZ)
    chain = np.arange(t) * speed / RATE_HZ
    rmse = []
    for _ in range(draws):
        u, y = synthetic_record(params, channels, speed, RATE_HZ, 4 * t, rng,
                                reference=reference)
        z, _ = lmmse_estimate(params, channels, speed, y[:, :t], RATE_HZ, reference=reference)
        rmse.append(score(chain, z, chain, u[:t]).rmse * 1e3)
    return f'{np.mean(rmse):.4f} +- {np.std(rmse, ddof=1) if draws > 1 else 0:.4f}'


def sensors(truth: Truth, x_p: float, rng: np.random.Generator
            ) -> tuple[list[Channel], list[np.ndarray]]:
    """The accelerometer at x_p and the gyro: channels and noisy data (m/s^2 without g, rad/s)."""
    run = truth.run
    noise = rng.standard_normal((2, run.t.size)) * np.sqrt(RATE_HZ / 2)
    return ([Channel(x_p, ACC_DENSITY), Channel(None, GYRO_DENSITY)],
            [run.accel(x_p) + noise[0] * ACC_DENSITY, run.pitch_rate() + noise[1] * GYRO_DENSITY])


def off_suspension(model: CoachModel, rng: np.random.Generator) -> np.ndarray:
    """theta of the file's coach with the SUSPENSION parameters OFF_RANGE off, random signs."""
    factors = np.ones(len(PARAM_NAMES))
    for name in SUSPENSION:
        factors[PARAM_NAMES.index(name)] = 1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(*OFF_RANGE)
    return model.theta * factors


def main() -> None:
    parser = run_options(__doc__, 1600.0)
    parser.add_argument('--vehicle', default=str(DEFAULT_VEHICLE),
                        help='coach file (default: config/vehicles/coach.yaml)')
    parser.add_argument('--draws', type=int, default=0,
                        help='model records per case for the expected limit (default 0)')
    parser.add_argument('--quick', action='store_true', help='smoke run: 800 m')
    parser.add_argument('--no-robustness', action='store_true',
                        help='leave out the robustness table')
    args = parser.parse_args()
    k = np.linspace(0.0, 4.0, 4001)  # 1/m: the limit's target must be the score's band
    lmin, lmax = band_limits('d1')
    if (lmin, lmax) != D1_M or not np.allclose(band_power(k), bandpass_power(k, 1 / lmax,
                                                                             1 / lmin, 2)):
        raise SystemExit('the reference D1 band differs from the score\'s: limit not optimal')
    model = load_model(args.vehicle)
    if not isinstance(model, CoachModel):
        raise SystemExit(f'{args.vehicle}: not a coach file (model: coach)')
    geometry = model.geometry
    reference = geometry.reference_wheelset - 1
    params = reference_params(dict(zip(PARAM_NAMES, model.theta, strict=True)),
                              geometry.bogie_spacing_m, geometry.wheelbase_m)
    positions = {'above leading bogie': geometry.bogie_spacing_m / 2, 'car centre': 0.0}
    length = 800.0 if args.quick else args.length
    rng = np.random.default_rng(args.seed + 1000)  # sensor noise
    model_rng = np.random.default_rng(args.seed + 2000)  # the model records of --draws
    print(f'Coach accuracy: reference coach with the parameters of {Path(args.vehicle).name}, '
          f'German low + {DIP_DEPTH_M * 1e3:g} mm dip over {DIP_M:g} m, {length:g} m per run, '
          f'D1 RMSE mm over the points where the project\'s output is VALID or DEGRADED')
    header('v m/s', 'IMU', 'gyro', 'scored m', 'true D1 RMS', 'limit (finite-record LMMSE)',
           'limit, whole record', 'infinite-record posterior',
           f'limit expected ({args.draws} draws)', 'project', 'project / limit', '<= 1.5x',
           'project reports (std_m)', 'its limit (limit_std_m)', 'dip peak err limit',
           'dip peak err project', 'project / limit, 2 windows from the end')
    for speed in (20.0, 40.0):
        t0 = time.process_time()
        truth = coach_run(params, reference, length, speed, args.seed)
        sim_s = time.process_time() - t0
        everywhere = scored(truth, truth.x, np.ones(truth.x.size, bool))
        for name, x_p in positions.items():
            channels, data = sensors(truth, x_p, rng)
            for count in (1, 2):
                z = limit_d1(truth, channels[:count], data[:count], reference)
                chain, u, used, pipe = project_d1(truth, data[:count], at_imu(model, x_p),
                                                  model.theta)
                keep = scored(truth, chain, used)
                lim = errors(truth, truth.run.chainage, z, keep)
                proj = errors(truth, chain, u, keep)
                obs = pipe.observability
                assert obs is not None
                bound = posterior_rmse(params, channels[:count], speed, RATE_HZ,
                                       reference=reference)
                expect = expected_limit(params, channels[:count], speed, length, args.draws,
                                        reference, model_rng)
                ratio = proj[0] / lim[0]
                inner = keep & (truth.x <= truth.x[-1] - 2 * window_m(pipe, speed))
                inner_ratio = errors(truth, chain, u, inner)[0] / errors(
                    truth, truth.run.chainage, z, inner)[0]
                print(f'| {speed:g} | {name} | {"yes" if count == 2 else "no"} | '
                      f'{keep.sum() * DX_M:.0f} | '
                      f'{np.sqrt(np.mean(truth.band[keep] ** 2)) * 1e3:.3f} | '
                      f'{lim[0] * 1e3:.4f} | '
                      f'{errors(truth, truth.run.chainage, z, everywhere)[0] * 1e3:.4f} | '
                      f'{bound * 1e3:.4f} | {expect} | {proj[0] * 1e3:.4f} | {ratio:.2f} | '
                      f'{"yes" if ratio <= 1.5 else "no"} | {obs.std_m(speed) * 1e3:.4f} | '
                      f'{obs.limit_std_m(speed) * 1e3:.4f} | {lim[1] * 1e3:.3f} | '
                      f'{proj[1] * 1e3:.3f} | {inner_ratio:.2f} |', flush=True)
        print(f'<!-- {speed:g} m/s: ODE {sim_s:.0f} s CPU, '
              f'all {time.process_time() - t0:.0f} s -->', flush=True)
    if not args.no_robustness:
        robustness(model, positions, length, args.seed, rng)


def robustness(model: CoachModel, positions: dict[str, float], length: float, seed: int,
               rng: np.random.Generator) -> None:
    """The robustness table: the truth's suspension off the file, 20 m/s; each estimate
    scored where the project's nominal inversion is VALID or DEGRADED."""
    true_theta = off_suspension(model, np.random.default_rng(seed + 3000))
    geometry = model.geometry
    reference = geometry.reference_wheelset - 1
    params = reference_params(dict(zip(PARAM_NAMES, true_theta, strict=True)),
                              geometry.bogie_spacing_m, geometry.wheelbase_m)
    factor = true_theta / model.theta
    off = ', '.join(f'{n} {factor[PARAM_NAMES.index(n)] - 1:+.0%}' for n in SUSPENSION)
    print(f'\nRobustness: the true suspension off the file ({off}), 20 m/s, D1 RMSE mm')
    header('IMU', 'gyro', 'limit (true coach)', 'project, file parameters', '/ limit',
           'project, true parameters', '/ limit')
    truth = coach_run(params, reference, length, 20.0, seed)
    for name, x_p in positions.items():
        channels, data = sensors(truth, x_p, rng)
        for count in (1, 2):
            z = limit_d1(truth, channels[:count], data[:count], reference)
            chain, u, used, _ = project_d1(truth, data[:count], at_imu(model, x_p), model.theta)
            keep = scored(truth, chain, used)
            lim = errors(truth, truth.run.chainage, z, keep)[0]
            nominal = errors(truth, chain, u, keep)[0]
            chain, u, _, _ = project_d1(truth, data[:count], at_imu(model, x_p), true_theta)
            true = errors(truth, chain, u, keep)[0]
            print(f'| {name} | {"yes" if count == 2 else "no"} | {lim * 1e3:.4f} | '
                  f'{nominal * 1e3:.4f} | {nominal / lim:.2f} | {true * 1e3:.4f} | '
                  f'{true / lim:.2f} |', flush=True)


if __name__ == '__main__':
    main()
