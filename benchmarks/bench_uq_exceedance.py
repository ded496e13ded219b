"""False alarms of the review's exceedance list: band-edge classes against probabilities (item 5).

Simulated runs with known truth: German high track with a 14 mm cosine dip (a real alert-limit
exceedance at 108 km/h, AL 8 mm) and a 6 mm dip (none), TRUE vehicles drawn from the realistic law
(CoV 0.1), BMI088-like sensors drawn around the preset. Each run is written as a rosbag2 bag and
reviewed as ``railgsa review`` does (``review.stream.run_stream``: ``offline.Driver``, the input
policy, the band with its sensor and gap terms and P(|u| > limit) from the band's germ samples),
with the paper's Table 3 (sigma = mu / 3) and with the realistic law as the band's law. Every
stretch the review lists is checked against the band-passed truth: a false alarm when the truth
does not pass the stretch's limit there. Printed: listed stretches by confidence (the default,
``--min-probability 0``: every stretch), false alarms among them, the real exceedances, and the
false alarms and misses left when the list keeps only stretches with P >= 0.5 or >= 0.9.

Usage: python benchmarks/bench_uq_exceedance.py [--runs 6] [--length 2000]
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
import tempfile

import numpy as np
from tables import header

from railgsa_ros.bag.run import write_run
from railgsa_ros.imu import accel_covariance, imu_spec
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.offline import Source
from railgsa_ros.review.stream import run_stream
from railgsa_ros.scenario import run_scenario
from railgsa_ros.standards.en13848 import Limits, en13848_table
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.uncertainty.coverage import draw_sensor, draw_vehicle
from railgsa_ros.uncertainty.parameters import table3
from railgsa_ros.uq.distributions import Normal
from railgsa_ros.vehicle import VehicleParams

NOMINAL = VehicleParams()
SPEED = 30.0
DEFECTS = 'dip@600:len=6:depth=14e-3,dip@1300:len=6:depth=6e-3'
THRESHOLDS = (0.5, 0.9)


def realistic() -> dict[str, Normal]:
    return {k: Normal(getattr(NOMINAL, k), 0.1 * getattr(NOMINAL, k), lower=0.0)
            for k in ('k_s', 'k_us', 'c')}


def analyse(run, law, bag: Path) -> tuple[list[tuple[str, float, bool]], int]:
    """(confidence, P, truth passes the stretch's limit) of every stretch the review of the
    run's bag lists, and whether the truth passes the alert limit at the 14 mm dip."""
    write_run(bag, run, accel_variance=accel_covariance(imu_spec('bmi088')), overwrite=True)
    review, _ = run_stream(Source(bag), UncertaintyConfig(qoi=''), NOMINAL, law,
                           Limits(en13848_table(), 'd1'))
    x = np.arange(0.0, run.chainage_m[-1] - run.chainage_m[0], 0.25)
    truth = band_distance(np.interp(x, run.chainage_m - run.chainage_m[0], run.truth_u_m), 0.25)
    rows = []
    for e in review.exceedances:
        near = (x >= e.start_m - 1.0) & (x <= e.end_m + 1.0)
        rows.append((e.confidence, e.probability, bool(np.max(np.abs(truth[near])) > e.limit_m)))
    alert = Limits(en13848_table(), 'd1').at(np.zeros(1), np.array([SPEED]))[0, 0]
    dip = (x > 590) & (x < 615)
    return rows, int(np.max(np.abs(truth[dip])) > alert)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=6)
    parser.add_argument('--length', type=float, default=2000.0, help='m per run')
    parser.add_argument('--seed', type=int, default=3)
    args = parser.parse_args()
    print(f'{args.runs} runs of {args.length:g} m at {SPEED * 3.6:g} km/h, German high, '
          f'defects {DEFECTS}')
    header('band law', 'listed (certain/likely/possible)', 'false alarms listed', 'real',
           *(f'P >= {t}: kept, false, missed' for t in THRESHOLDS))
    tmp = tempfile.TemporaryDirectory(prefix='railgsa_exceedance_')
    for label, law in (('Table 3 (sigma = mu/3)', table3(NOMINAL)), ('CoV 0.1', realistic())):
        rng = np.random.default_rng(args.seed)
        rows, real = [], 0
        for r in range(args.runs):
            run = run_scenario('german-high', SPEED, args.length / SPEED, None,
                               draw_sensor('bmi088', rng), seed=200 + r, defects=DEFECTS,
                               vehicle=draw_vehicle(NOMINAL, realistic(), rng))
            found, has_real = analyse(run, law, Path(tmp.name) / 'run')
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
    tmp.cleanup()


if __name__ == '__main__':
    main()
