"""False alarms of the review's exceedance list: band-edge classes against probabilities (item 5).

Simulated runs with known truth: German high track with a 14 mm cosine dip (a real alert-limit
exceedance at 108 km/h, AL 8 mm) and a 6 mm dip (none), TRUE vehicles drawn from the realistic law
(CoV 0.1), BMI088-like sensors drawn around the preset. The bands and the per-sample probability
P(|u| > AL) (``uncertainty.exceedance``, the band's germ samples and sensor terms) are computed
with the paper's Table 3 (sigma = mu / 3) and with the realistic law. Every stretch the review
lists (``review.exceedances.find_exceedances``: band far edge beyond a limit) is checked against
the band-passed truth: a false alarm when the truth does not pass the alert limit there. Printed:
listed stretches by confidence, false alarms among them, and the false alarms and misses left when
the list keeps only stretches with P >= 0.5 or >= 0.9.

Usage: python benchmarks/bench_uq_exceedance.py [--runs 6] [--length 2000]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from railgsa_ros.imu import accel_covariance, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.review.exceedances import find_exceedances
from railgsa_ros.review.limits import en13848_limits
from railgsa_ros.scenario import run_scenario
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.coverage import draw_sensor, draw_vehicle
from railgsa_ros.uncertainty.exceedance import exceedance_probability
from railgsa_ros.uncertainty.parameters import table3
from railgsa_ros.uncertainty.stream import UncertaintyStream, band_statistics
from railgsa_ros.uq.distributions import Normal
from railgsa_ros.vehicle import VehicleParams

NOMINAL = VehicleParams()
SPEED = 30.0
DEFECTS = 'dip@600:len=6:depth=14e-3,dip@1300:len=6:depth=6e-3'
THRESHOLDS = (0.5, 0.9)


def realistic() -> dict[str, Normal]:
    return {k: Normal(getattr(NOMINAL, k), 0.1 * getattr(NOMINAL, k), lower=0.0)
            for k in ('k_s', 'k_us', 'c')}


def analyse(run, law) -> list[tuple[str, float, bool]]:
    """(confidence, P, truth passes AL) of every listed stretch of one run."""
    config = UncertaintyConfig(inversion=InversionConfig(rate_hz=run.rate_hz), qoi='')
    stream = UncertaintyStream(config, NOMINAL, law, accel_covariance(imu_spec('bmi088')))
    out = Output.concat([stream.pipeline.push(run.stamps_ns, run.accel[:, 2], run.speed_mps),
                         stream.pipeline.flush()], channels=stream.design.points)
    design = stream.design
    sensor = stream.terms.std(out.stamps_ns, design.projector[0] @ out.u_m, out.speed_mps,
                              out.quality)
    lower, mean, upper = band_statistics(design, (0.025, 0.975), out.u_m, sensor)
    limits = en13848_limits('d1')
    alert = limits.at(out.speed_mps)[:, 0]
    prob = exceedance_probability(design, out.u_m, alert, sensor)
    chain = out.chainage_m + run.chainage_m[0]
    x = np.arange(run.chainage_m[0], run.chainage_m[-1], 0.25)
    truth = np.interp(chain, x, band_distance(np.interp(x, run.chainage_m, run.truth_u_m), 0.25))
    rows = []
    for e in find_exceedances(chain, mean, out.speed_mps, out.stamps_ns, limits, lower, upper):
        near = (chain >= e.start_m - 1.0) & (chain <= e.end_m + 1.0)
        rows.append((e.confidence, float(prob[near].max()),
                     bool(np.max(np.abs(truth[near])) > alert[near].min())))
    real = np.abs(truth) > alert
    return rows, int(np.any(real[(chain > 590) & (chain < 615)]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=6)
    parser.add_argument('--length', type=float, default=2000.0, help='m per run')
    parser.add_argument('--seed', type=int, default=3)
    args = parser.parse_args()
    print(f'{args.runs} runs of {args.length:g} m at {SPEED * 3.6:g} km/h, German high, '
          f'defects {DEFECTS}')
    print('| band law | listed (certain/likely/possible) | false alarms listed | real | '
          + ' | '.join(f'P >= {t}: kept, false, missed' for t in THRESHOLDS) + ' |')
    print('|---|---|---|---|' + '---|' * len(THRESHOLDS))
    for label, law in (('Table 3 (sigma = mu/3)', table3(NOMINAL)), ('CoV 0.1', realistic())):
        rng = np.random.default_rng(args.seed)
        rows, real = [], 0
        for r in range(args.runs):
            run = run_scenario('german-high', SPEED, args.length / SPEED, None,
                               draw_sensor('bmi088', rng), seed=200 + r, defects=DEFECTS,
                               vehicle=draw_vehicle(NOMINAL, realistic(), rng))
            found, has_real = analyse(run, law)
            rows += found
            real += has_real
        conf = Counter(c for c, _, _ in rows)
        false = sum(not t for _, _, t in rows)
        cells = []
        for th in THRESHOLDS:
            kept = [(p, t) for _, p, t in rows if p >= th]
            true_rows = sum(t for _, _, t in rows)
            cells.append(f'{len(kept)}, {sum(not t for _, t in kept)}, '
                         f'{true_rows - sum(t for _, t in kept)}')
        print(f'| {label} | {len(rows)} ({conf["certain"]}/{conf["likely"]}/{conf["possible"]}) '
              f'| {false} | {real} | ' + ' | '.join(cells) + ' |')


if __name__ == '__main__':
    main()
