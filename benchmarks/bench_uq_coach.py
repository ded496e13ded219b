"""The coach's windowed sensitivities (issue 21 item 4): PCE/PEM against SALib at equal accuracy.

Scenario (``uncertainty.wiener_scenario``): a record of the shipped coach (IMU above the
leading bogie, ADXL355-like noise, German low, --speed, default 20 m/s) inverted by the LMMSE
design of each parameter set; the output is the D1 estimate at the samples of a 10 s window
(every 0.2 s: 51 outputs).
The uncertain parameters are all ten of ``config/uncertainty_coach.yaml``. Windowed indices
aggregate the window's outputs by their variances (S_i = sum_k V_k S_ik / sum_k V_k). The
reference is brute force: Saltelli/Jansen Monte Carlo with --reference x 12 runs
(``uq.validate.monte_carlo_indices``). Each method's design grows until max |error| over the
ten aggregated S1 and ST < --tol (default 0.05: at 20 m/s the response is strongly
non-additive in m_c, J_c, k_s, c_s and no design here reaches 0.05; at 40 m/s 0.01 is reached)
(or its largest size); printed: every design's error, the first
passing design, its runs, wall time and the ratio of SALib's runs to ours, the reference's
indices and the delta at the window's most uncertain output (on the order-3 PCE). Needs the
bench extra (SALib).

    PYTHONPATH=$PWD python benchmarks/bench_uq_coach.py [--largest-salib 1024] [--reference N]
        [--speed 20]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from SALib.analyze import sobol as salib_sobol
from SALib.sample import sobol as salib_sample
from tables import header

from railgsa_ros.models import load_model
from railgsa_ros.uncertainty.parameters import load_uncertainty
from railgsa_ros.uncertainty.wiener_scenario import make_wiener_scenario, window_indices
from railgsa_ros.uq import AliasingWarning, analyze
from railgsa_ros.uq.delta import delta_indices
from railgsa_ros.uq.pce import PCE
from railgsa_ros.uq.validate import monte_carlo_indices

TIMES = 30.0 + 0.2 * np.arange(51)  # s: a 10 s window (200 m at 20 m/s)


def ours(model, dists, **kwargs):
    def fn():
        res = analyze(model, dists, delta=False, **kwargs)
        var = res.std ** 2
        return res.n_evaluations, window_indices(var, res.sobol_first), \
            window_indices(var, res.sobol_total)
    return fn


def salib(model, problem, n_base, seed=0):
    def fn():
        x = salib_sample.sample(problem, n_base, calc_second_order=False, seed=seed)
        y = model(x)
        s1, st = [], []
        for k in range(y.shape[1]):
            si = salib_sobol.analyze(problem, y[:, k], calc_second_order=False,
                                     num_resamples=2, seed=seed)
            s1.append(si['S1'])
            st.append(si['ST'])
        var = np.var(y, axis=0)
        return len(x), window_indices(var, np.array(s1)), window_indices(var, np.array(st))
    return fn


def first_pass(trials, ref, tol):
    """Run (label, fn) trials in order; stop at the first within tol of the reference."""
    for label, fn in trials:
        start = time.perf_counter()
        runs, s1, st = fn()
        wall = time.perf_counter() - start
        err = float(max(np.max(np.abs(s1 - ref[0])), np.max(np.abs(st - ref[1]))))
        if err < tol:
            return label, runs, wall, err
        print(f'  {label}: {runs} runs, max err {err:.4f}', flush=True)
    return f'{label} (fails)', runs, wall, err


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--largest-salib', type=int, default=1024, help='largest SALib N')
    parser.add_argument('--reference', type=int, default=4096, help='brute-force N')
    parser.add_argument('--speed', type=float, default=20.0, help='m/s')
    parser.add_argument('--tol', type=float, default=0.05, help='accuracy to reach')
    args = parser.parse_args()
    warnings.simplefilter('ignore', AliasingWarning)
    model = load_model('config/vehicles/coach.yaml')
    law = load_uncertainty('config/uncertainty_coach.yaml', model)
    dists, names = list(law.values()), list(law)
    scenario = make_wiener_scenario(model, law, TIMES, args.speed, duration_s=70.0,
                                    rate_hz=max(25.0, 1.25 * args.speed))
    start = time.perf_counter()
    brute = monte_carlo_indices(scenario, dists, args.reference)
    var = brute.std ** 2
    pair = (window_indices(var, brute.sobol_first), window_indices(var, brute.sobol_total))
    print(f'reference: Saltelli/Jansen, {args.reference * 12} runs, '
          f'{time.perf_counter() - start:.0f} s; window std {np.sqrt(var.mean()) * 1e3:.4f} mm',
          flush=True)
    peak = int(np.argmax(var))  # delta of the window's most uncertain output, on a surrogate
    pce = analyze(scenario, dists, rule='lstsq', order=3, size=4 * 286, delta=False).pce
    delta = delta_indices(PCE(pce.alpha, pce.coef[:, [peak]], pce.germ), len(dists))[0]
    header('parameter', 'S1 (window)', 'ST (window)', f'delta at t = {TIMES[peak]:g} s')
    for i, name in enumerate(names):
        print(f'| {name} | {pair[0][i]:.3f} | {pair[1][i]:.3f} | {delta[i]:.3f} |', flush=True)
    problem = {'num_vars': len(names), 'names': names, 'dists': ['truncnorm'] * len(names),
               'bounds': [[0.0, d.mu + 40 * d.sigma, d.mu, d.sigma] for d in dists]}
    sizes = [2 ** k for k in range(7, 1 + int(np.log2(args.largest_salib)))]
    rows = {
        'railgsa pem3 order 1': first_pass(
            [('pem3 o1', ours(scenario, dists, rule='pem3', order=1))], pair, args.tol),
        'railgsa pem5 order 2': first_pass(
            [('pem5 o2', ours(scenario, dists, rule='pem5', order=2))], pair, args.tol),
        'railgsa lstsq order 2': first_pass(
            [(f'N={n}', ours(scenario, dists, rule='lstsq', order=2, size=n, seed=1))
             for n in (150, 300, 600)], pair, args.tol),
        'railgsa lstsq order 3': first_pass(
            [(f'N={n}', ours(scenario, dists, rule='lstsq', order=3, size=n, seed=1))
             for n in (572, 1144, 2288)], pair, args.tol),
        'SALib Saltelli (Sobol seq.)': first_pass(
            [(f'N={n}', salib(scenario, problem, n)) for n in sizes], pair, args.tol),
    }
    print(f'\nmodel runs to reach {args.tol} on every windowed S1 and ST (10 parameters)')
    header('method', 'first passing design', 'runs', 'wall s', 'max err', 'SALib runs / ours')
    salib_runs = rows['SALib Saltelli (Sobol seq.)'][1]
    for method, (label, runs, wall, err) in rows.items():
        print(f'| {method} | {label} | {runs} | {wall:.1f} | {err:.4f} | '
              f'{salib_runs / runs:.0f}x |')


if __name__ == '__main__':
    main()
