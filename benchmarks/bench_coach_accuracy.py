"""Coach accuracy: the project's D1 RMSE beside the LMMSE limit of the same run (issue #21).

Data from the independent coach of test/reference (coach_ode: a 10-DOF vertical multibody ODE of
the Manchester benchmark coach, solve_ivp), not from the project's code path: a Gaussian draw of
the German low spectrum plus an 8 mm cosine dip over 6 m in the middle of the run (faded in over
the first 80 m of track, so that the coach starts at rest), 20 and 40 m/s, chainage of the
leading wheelset. Sensors: an ADXL355-like accelerometer (white noise 25 ug/sqrt(Hz), 1 kHz)
above the leading bogie or at the car centre, with or without a gyro's pitch rate (0.014
deg/s/sqrt(Hz)).

Limit: the exact finite-record LMMSE of the D1 profile with the true coach, the track spectrum
as prior and the sensors' noise (reference.lmmse.lmmse_estimate) on the same samples, scored
like the project (railgsa_ros.inverse.score.score: D1 on distance, 100 m left out at each end);
beside it the infinite-record posterior RMSE from the spectra (in expectation a lower bound for
any record)
and, with ``--draws N``, the mean +- std of the finite-record LMMSE's RMSE over N records of the
same length drawn from the model (reference.lmmse.synthetic_record): how far one run's limit
strays from its expectation.
Project: railgsa_ros.inverse.pipeline.InversionPipeline on the accelerometer samples with the
vehicle of ``--vehicle`` (a vehicle YAML; default: the quarter car of the default parameters,
labelled so; read by railgsa_ros.vehicle.load_vehicle, which the coach model has to accept, and
the IMU position the project assumes is the file's, the same for both rows of a speed) and
odometry speed; it does not use the gyro, so its cell is the same with and without one. Target
of issue #21: at most 1.5x the limit.

Usage: python benchmarks/bench_coach_accuracy.py [--length 800] [--seed 1] [--vehicle PATH]
    [--draws N] [--quick]
"""

from __future__ import annotations

from pathlib import Path
import sys
import time

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from tables import header, run_options

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))  # the reference package

from reference.coach_ode import MANCHESTER_COACH, simulate, wheelset_offsets
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

from railgsa_ros.inverse.band import band_limits, bandpass_power
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.score import band_distance, score
from railgsa_ros.vehicle import load_vehicle

RATE_HZ = 1000.0
ACC_DENSITY = 25e-6 * G  # m/s^2/sqrt(Hz)
GYRO_DENSITY = np.deg2rad(0.014)  # rad/s/sqrt(Hz)
DIP_M, DIP_DEPTH_M = 6.0, 8e-3
FADE_M = (30.0, 80.0)  # track chainage over which the profile fades in
DX_M = 0.25  # profile grid of the quintic spline
START_NS = 1_700_000_000 * 10 ** 9
POSITIONS = {'above leading bogie': MANCHESTER_COACH['l_c'], 'car centre': 0.0}


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


def coach_run(length_m: float, speed: float, seed: int):
    """(run, truth profile function, dip start) of the reference coach over length_m of record;
    the trailing wheelset starts on the flat track at 1 m."""
    start = 1.0 + wheelset_offsets(MANCHESTER_COACH)[-1]
    dip_at = start + length_m / 2
    u = track(start + length_m + 10.0, dip_at, seed)
    t = np.arange(0.0, length_m / speed, 1.0 / RATE_HZ)
    return simulate(MANCHESTER_COACH, u, speed, t, start_m=start), u, dip_at


def d1_rms(chainage: np.ndarray, u: np.ndarray, margin_m: float = 100.0) -> float:
    """RMS (m) of the D1 band of u over chainage less margin_m at each end, as score sees it."""
    x = np.arange(chainage[0], chainage[-1], DX_M)
    keep = (x >= x[0] + margin_m) & (x <= x[-1] - margin_m)
    return float(np.sqrt(np.mean(band_distance(np.interp(x, chainage, u), DX_M)[keep] ** 2)))


def project_d1(run, accel: np.ndarray, truth: np.ndarray, vehicle, dip_at: float):
    """Score of the project's offline inversion of the accelerometer samples (+g, odometry)."""
    cfg = InversionConfig().with_(rate_hz=RATE_HZ)
    pipe = InversionPipeline(cfg, vehicle, noise_variance=ACC_DENSITY ** 2 * RATE_HZ / 2)
    stamps = START_NS + np.round(run.t * 1e9).astype(np.int64)
    out = Output.concat([pipe.push(stamps, accel + cfg.gravity_mps2, run.speed), pipe.flush()])
    return score(out.chainage_m + run.chainage[0], out.u_m, run.chainage, truth,
                 defect=(dip_at, DIP_M))


def expected_limit(channels: list[Channel], speed: float, length_m: float, draws: int,
                   rng: np.random.Generator) -> str:
    """'mean +- std' (mm) of the finite-record LMMSE's D1 RMSE over ``draws`` model records of
    length_m, scored like the runs ('' for none). Each record is the first quarter of a
    periodic draw: a stretch of a stationary process."""
    if draws == 0:
        return ''
    t = round(length_m / speed * RATE_HZ)
    chain = np.arange(t) * speed / RATE_HZ
    rmse = []
    for _ in range(draws):
        u, y = synthetic_record(MANCHESTER_COACH, channels, speed, RATE_HZ, 4 * t, rng)
        z, _ = lmmse_estimate(MANCHESTER_COACH, channels, speed, y[:, :t], RATE_HZ)
        rmse.append(score(chain, z, chain, u[:t]).rmse * 1e3)
    return f'{np.mean(rmse):.4f} +- {np.std(rmse, ddof=1) if draws > 1 else 0:.4f}'


def main() -> None:
    parser = run_options(__doc__, 800.0)
    parser.add_argument('--vehicle', default=None,
                        help='vehicle YAML for the project (default: quarter car defaults)')
    parser.add_argument('--draws', type=int, default=0,
                        help='model records per case for the expected limit (default 0)')
    parser.add_argument('--quick', action='store_true', help='smoke run: 400 m')
    args = parser.parse_args()
    k = np.linspace(0.0, 4.0, 4001)  # 1/m: the limit's target must be the score's band
    lmin, lmax = band_limits('d1')
    if (lmin, lmax) != D1_M or not np.allclose(band_power(k), bandpass_power(k, 1 / lmax,
                                                                             1 / lmin, 2)):
        raise SystemExit('the reference D1 band differs from the score\'s: limit not optimal')
    length = 400.0 if args.quick else args.length
    vehicle = load_vehicle(args.vehicle) if args.vehicle else None
    label = f'project ({Path(args.vehicle).name})' if args.vehicle else \
        'project (quarter car default)'
    rng = np.random.default_rng(args.seed + 1000)  # sensor noise
    model_rng = np.random.default_rng(args.seed + 2000)  # the model records of --draws
    print(f'Coach accuracy: reference coach (Manchester benchmark), German low + '
          f'{DIP_DEPTH_M * 1e3:g} mm dip over {DIP_M:g} m, {length:g} m per run, D1 RMSE mm')
    header('v m/s', 'IMU', 'gyro', 'true D1 RMS', 'limit (finite-record LMMSE)',
           'infinite-record posterior (expected)', f'limit expected ({args.draws} draws)',
           label, f'{label} / limit', '<= 1.5x', 'dip peak err limit', 'dip peak err project')
    for speed in (20.0, 40.0):
        t0 = time.process_time()
        run, u, dip_at = coach_run(length, speed, args.seed)
        truth = u(run.chainage)
        sim_s = time.process_time() - t0
        gyro = run.pitch_rate() + rng.standard_normal(run.t.size) * GYRO_DENSITY \
            * np.sqrt(RATE_HZ / 2)
        true_rms = d1_rms(run.chainage, truth)
        for name, x_p in POSITIONS.items():
            accel = run.accel(x_p) + rng.standard_normal(run.t.size) * ACC_DENSITY \
                * np.sqrt(RATE_HZ / 2)
            proj = project_d1(run, accel, truth, vehicle, dip_at)
            for with_gyro in (False, True):
                channels = [Channel(x_p, ACC_DENSITY)]
                y = [accel]
                if with_gyro:
                    channels.append(Channel(None, GYRO_DENSITY))
                    y.append(gyro)
                z, _ = lmmse_estimate(MANCHESTER_COACH, channels, speed, np.array(y), RATE_HZ)
                lim = score(run.chainage, z, run.chainage, truth, defect=(dip_at, DIP_M))
                bound = posterior_rmse(MANCHESTER_COACH, channels, speed, RATE_HZ)
                expect = expected_limit(channels, speed, length, args.draws, model_rng)
                ratio = proj.rmse / lim.rmse
                print(f'| {speed:g} | {name} | {"yes" if with_gyro else "no"} | '
                      f'{true_rms * 1e3:.3f} | {lim.rmse * 1e3:.4f} | {bound * 1e3:.4f} | '
                      f'{expect} | '
                      f'{proj.rmse * 1e3:.4f} | {ratio:.2f} | {"yes" if ratio <= 1.5 else "no"} '
                      f'| {lim.peak_error * 1e3:.3f} | {proj.peak_error * 1e3:.3f} |')
        print(f'<!-- {speed:g} m/s: ODE {sim_s:.0f} s CPU, '
              f'all {time.process_time() - t0:.0f} s -->')


if __name__ == '__main__':
    main()
