"""Accuracy of PEM5 + PCE on the paper's scenarios against a converged reference and brute force.

For the inverse and forward scenarios (t = 7 s, paper profile, 10 m/s) and k_s, k_us, c normal
with coefficient of variation 0.1 and the paper's 1/3: PEM5 order 2 (projection, 19 runs) and
order 3 (regression, 40 runs) and Gauss order 4 (125 runs) against a Gauss order-7 PCE (512 runs,
the reference) and brute-force Saltelli/Jansen Monte Carlo.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from railgsa_ros.uq import AliasingWarning, Normal, analyze, monte_carlo_indices
from railgsa_ros.uq.scenarios import make_scenario
from railgsa_ros.vehicle import VehicleParams

N_BASE = 2048  # brute force: N_BASE (n + 2) runs
METHODS = [('pem5 o2', dict(rule='pem5', order=2)), ('pem5 o3 (ols)', dict(rule='pem5', order=3)),
           ('gauss o4', dict(rule='gauss', order=4))]


def main() -> None:
    warnings.simplefilter('ignore', AliasingWarning)
    nominal = VehicleParams()
    print('| scenario | CoV | method | runs | max err S1 | max err ST | rel err std | '
          'max err delta | time s |')
    print('|---|---|---|---|---|---|---|---|---|')
    for cov in (0.1, 1 / 3):
        dists = {n: Normal(getattr(nominal, n), cov * getattr(nominal, n), lower=0.0)
                 for n in ('k_s', 'k_us', 'c')}
        for kind in ('inverse', 'forward'):
            model = make_scenario(kind, 7.0, dists)
            law = list(dists.values())
            ref = analyze(model, law, rule='gauss', order=7)
            t0 = time.perf_counter()
            mc = monte_carlo_indices(model, law, N_BASE)
            t_mc = time.perf_counter() - t0
            rows = [(name, analyze(model, law, **kw)) for name, kw in METHODS]
            for name, res in rows:
                t0 = time.perf_counter()
                analyze(model, law, delta=False, **dict(METHODS)[name])
                dt = time.perf_counter() - t0
                print(f'| {kind} | {cov:.2f} | {name} | {res.n_evaluations} | '
                      f'{np.max(np.abs(res.sobol_first - ref.sobol_first)):.4f} | '
                      f'{np.max(np.abs(res.sobol_total - ref.sobol_total)):.4f} | '
                      f'{abs(res.std / ref.std - 1):.4f} | '
                      f'{np.max(np.abs(res.delta - ref.delta)):.4f} | {dt:.2f} |')
            print(f'| {kind} | {cov:.2f} | brute force MC | {mc.n_evaluations} | '
                  f'{np.max(np.abs(mc.sobol_first - ref.sobol_first)):.4f} | '
                  f'{np.max(np.abs(mc.sobol_total - ref.sobol_total)):.4f} | '
                  f'{abs(mc.std / ref.std - 1):.4f} | '
                  f'{np.max(np.abs(mc.delta - ref.delta)):.4f} | {t_mc:.1f} |')
            print(f'| {kind} | {cov:.2f} | reference gauss o7 | {ref.n_evaluations} | '
                  f'S1 {np.round(ref.sobol_first, 3).tolist()} | '
                  f'ST {np.round(ref.sobol_total, 3).tolist()} | std {ref.std:.4g} | '
                  f'delta {np.round(ref.delta, 3).tolist()} | |')


if __name__ == '__main__':
    main()
