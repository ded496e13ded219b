"""Coverage of the coach's band (issue 21 item 4): an ensemble with known truth.

Each run draws its TRUE coach from the stated prior (``config/uncertainty_coach.yaml``: all ten
parameters) and its TRUE sensor around the preset (``uncertainty.coverage.draw_sensor``), and is
simulated by the project's coach simulator (``run_scenario(vehicle=...)``: German low, D1, the
preset's dropouts, clock drift and jitter). The band inverts with the NOMINAL coach: the bank of
the rule's points (theta (P, 10)) through the LMMSE design, the band's terms with the nominal
estimator's own error std (``observability.std_m``) and the preset's stated clock; every level's
band comes from one run of the bank (``uncertainty.coverage.bank_coverage``). Printed: per run,
then pooled over the runs, the fraction of the VALID and DEGRADED points away from the ends
whose D1 truth lies inside the 50 / 95 / 99 % bands (target for 95 %: 92-98 %), the mean
half-widths, and the same without the estimator's error term.

    PYTHONPATH=$PWD python benchmarks/bench_uq_coach_coverage.py [--runs 20] [--duration 80]
        [--speeds 20,40] [--imu bogie|centre] [--rule pem3|pem5] [--total-only]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from tables import header

from railgsa_ros.config import load_yaml
from railgsa_ros.imu import accel_covariance, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.models import load_model
from railgsa_ros.models.coach import CoachModel, CoachParams
from railgsa_ros.scenario import run_scenario
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.coverage import bank_coverage, draw_sensor, draw_vehicle
from railgsa_ros.uncertainty.parameters import load_uncertainty
from railgsa_ros.uncertainty.surrogate import build_design

PRIOR = 'config/uncertainty_coach.yaml'
CASES = {'bogie': (9.5, 'adxl355', ('accel_z',)),  # IMU x (m), preset, data channels
         'centre': (0.0, 'bmi088', ('accel_z', 'pitch_rate'))}


def coach(x_imu_m: float) -> CoachModel:
    """The shipped coach with its one IMU x_imu_m (m) forward of the car-body centre."""
    doc = load_yaml('config/vehicles/coach.yaml')
    model = load_model({**doc, 'imus': [{'name': 'imu', 'x_m': x_imu_m}]})
    assert isinstance(model, CoachModel)
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=20)
    parser.add_argument('--duration', type=float, default=80.0, help='s per run')
    parser.add_argument('--speeds', default='20,40', help='m/s, cycled over the runs')
    parser.add_argument('--imu', choices=tuple(CASES), default='bogie')
    parser.add_argument('--rule', choices=('pem3', 'pem5'), default='pem5')
    parser.add_argument('--seed', type=int, default=21)
    parser.add_argument('--total-only', action='store_true',
                        help='skip the band without the estimator term (half the time)')
    args = parser.parse_args()
    x_imu, preset, channels = CASES[args.imu]
    model = coach(x_imu)
    dists = load_uncertainty(PRIOR, model)
    spec = imu_spec(preset)
    inversion = InversionConfig(rate_hz=spec.output_rate_hz)
    config = UncertaintyConfig(rule=args.rule, order=1 if args.rule == 'pem3' else 2,
                               clock_std_ppm=spec.clock_drift_ppm, inversion=inversion)
    design = build_design(config, model, dists)
    speeds = [float(v) for v in args.speeds.split(',')]
    rng = np.random.default_rng(args.seed)
    template: InversionPipeline | None = None
    rows: dict[bool, list] = {True: [], False: []}
    print(f'coach, IMU {args.imu} (x = {x_imu:g} m), {preset}, channels {", ".join(channels)}; '
          f'prior {PRIOR}; rule {args.rule} ({design.points} points); {args.runs} runs of '
          f'{args.duration:g} s at {args.speeds} m/s, German low, D1')
    header('run', 'v m/s', 'estimator term', '50 %', '95 %', '99 %', '95 % half-width mm',
           'points', 's')
    for r in range(args.runs):
        start = time.perf_counter()
        theta = draw_vehicle(model, dists, rng)
        truth = CoachModel(CoachParams(*theta.tolist()), model.geometry)
        speed = speeds[r % len(speeds)]
        run = run_scenario('german-low', speed, args.duration, None, draw_sensor(preset, rng),
                           seed=1000 + r, vehicle=truth)
        if template is None:  # built once (the bank's design), copied for every run
            if run.gyro is not None:
                inversion = inversion.with_(gyro_noise_std_rads=float(np.sqrt(
                    run.gyro_covariance)))
                config = config.with_(inversion=inversion)
            template = InversionPipeline(inversion, design.theta, accel_covariance(spec),
                                         model=model, nominal=model.theta, channels=channels)
        for estimator in (True,) if args.total_only else (True, False):
            cov = bank_coverage(run, copy.deepcopy(template), design, config,
                                estimator=estimator)
            rows[estimator].append((cov.inside, cov.half_width_m, cov.samples))
            print(f'| {r} | {speed:g} | {"yes" if estimator else "no"} | '
                  + ' | '.join(f'{x:.3f}' for x in cov.inside)
                  + f' | {cov.half_width_m[1] * 1e3:.4f} | {cov.samples} | '
                  f'{time.perf_counter() - start:.0f} |', flush=True)
    print(f'\npooled over {args.runs} runs (mean of the runs; +- the binomial standard error '
          'over the runs at 95 %)')
    header('band', '50 %', '95 %', '99 %', '50 % half-width mm', '95 % half-width mm',
           '99 % half-width mm')
    se = np.sqrt(0.95 * 0.05 / args.runs)
    for estimator, label in ((True, 'total band'), (False, 'without the estimator term')):
        if not rows[estimator]:
            continue
        inside = np.mean([row[0] for row in rows[estimator]], axis=0)
        width = np.mean([row[1] for row in rows[estimator]], axis=0) * 1e3
        print(f'| {label} | {inside[0]:.3f} | {inside[1]:.3f} +- {se:.3f} | {inside[2]:.3f} | '
              + ' | '.join(f'{w:.4f}' for w in width) + ' |')


if __name__ == '__main__':
    main()
