"""Accuracy of PEM5 + PCE on the paper's scenarios against a converged reference and brute force.

For the inverse and forward scenarios (t = 7 s, paper profile, 10 m/s) and k_s, k_us, c normal
with coefficient of variation 0.1 and the paper's 1/3: PEM5 order 2 (projection, 19 runs) and
order 3 (regression, 40 runs), Gauss order 4 (125 runs) and order 7 (512 runs) against each
other and against brute-force Saltelli/Jansen Monte Carlo (N_BASE (n + 2) runs). Times include
the model runs and the surrogate delta.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from railgsa_ros.uncertainty.scenarios import make_scenario
from railgsa_ros.uq import AliasingWarning, Normal, analyze, monte_carlo_indices
from railgsa_ros.vehicle import VehicleParams

N_BASE = 4096  # brute force: N_BASE (n + 2) runs
METHODS = [('pem5 o2', dict(rule='pem5', order=2)), ('pem5 o3 (ols)', dict(rule='pem5', order=3)),
           ('gauss o4', dict(rule='gauss', order=4)), ('gauss o7', dict(rule='gauss', order=7))]


def errors(res, ref) -> str:
    """Largest absolute errors of S1, ST, delta and the relative error of std against ref."""
    return (f'{np.max(np.abs(res.sobol_first - ref.sobol_first)):.4f} | '
            f'{np.max(np.abs(res.sobol_total - ref.sobol_total)):.4f} | '
            f'{abs(res.std / ref.std - 1):.4f} | {np.max(np.abs(res.delta - ref.delta)):.4f}')


def main() -> None:
    warnings.simplefilter('ignore', AliasingWarning)
    nominal = VehicleParams()
    print('Errors against the Gauss order-7 PCE (512 runs) and against brute force; the last row '
          'of each block gives the brute-force values.')
    print('| scenario | CoV | method | runs | S1 err vs o7 | ST err vs o7 | std rel err vs o7 | '
          'delta err vs o7 | S1 err vs MC | ST err vs MC | std rel err vs MC | delta err vs MC '
          '| time s |')
    print('|' + '---|' * 13)
    for cov in (0.1, 1 / 3):
        dists = {n: Normal(getattr(nominal, n), cov * getattr(nominal, n), lower=0.0)
                 for n in ('k_s', 'k_us', 'c')}
        for kind in ('inverse', 'forward'):
            model = make_scenario(kind, 7.0, dists)
            law = list(dists.values())
            results = {}
            for name, kw in METHODS:
                t0 = time.perf_counter()
                results[name] = (analyze(model, law, **kw), time.perf_counter() - t0)
            t0 = time.perf_counter()
            mc = monte_carlo_indices(model, law, N_BASE)
            t_mc = time.perf_counter() - t0
            ref = results['gauss o7'][0]
            for name, (res, wall) in results.items():
                print(f'| {kind} | {cov:.2f} | {name} | {res.n_evaluations} | '
                      f'{errors(res, ref)} | {errors(res, mc)} | {wall:.2f} |')
            print(f'| {kind} | {cov:.2f} | brute force MC | {mc.n_evaluations} | '
                  f'{errors(mc, ref)} | S1 {np.round(mc.sobol_first, 3).tolist()} | '
                  f'ST {np.round(mc.sobol_total, 3).tolist()} | std {mc.std:.4g} | '
                  f'delta {np.round(mc.delta, 3).tolist()} | {t_mc:.1f} |')


if __name__ == '__main__':
    main()
