"""``railgsa gsa``: uncertainty and global sensitivity of the paper's scenarios (Section 8)."""

from __future__ import annotations

import argparse
from typing import Any

#: output std (m or m/s^2) below which the output counts as constant: 1e-12 m is a
#: thousandth of a nanometre of irregularity, far below any sensor (the flat start of a
#: profile gives 1e-14 to 1e-35, shares of rounding errors)
FLAT_STD = 1e-12


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``gsa`` subcommand."""
    p = subparsers.add_parser(
        'gsa', help='uncertainty and Sobol/Borgonovo sensitivities by PEM + polynomial chaos',
        description='Propagate uncertain vehicle parameters through the inverse reconstruction '
                    '(irregularity at time T) or the forward simulation (car-body acceleration '
                    'at T) with a Hermite PCE fitted on PEM points; report mean, std, '
                    'quantiles, Sobol first/total and Borgonovo delta indices.')
    p.add_argument('--scenario', choices=('inverse', 'forward'), default='inverse')
    p.add_argument('--time', type=float, default=7.0, metavar='T',
                   help='time in s, a multiple of the 0.5 ms simulation step (default 7)')
    p.add_argument('--profile', default='paper', metavar='SPEC',
                   help='german-low|german-high|fra-N|paper|file:CSV (default paper)')
    p.add_argument('--speed', type=float, default=10.0, metavar='MPS', help='m/s (default 10)')
    p.add_argument('--uncertainty', metavar='FILE.yaml',
                   help='uncertain parameters (default: Table 3, sigma = mu / 3)')
    p.add_argument('--vehicle', metavar='FILE',
                   help='nominal vehicle YAML (default Table 1); a coach file (model: coach) '
                        'inverts a simulated record of it with each parameter set\'s LMMSE '
                        'design (scenario inverse, German low; --uncertainty required, T at '
                        'least 25 s into the 100 s record)')
    p.add_argument('--rule', choices=('pem3', 'pem5', 'gauss', 'lstsq'), default='pem5')
    p.add_argument('--order', type=int, default=3, help='PCE total order (default 3)')
    p.add_argument('--gain', type=float, default=1000.0, help='feedback gain K^c (default 1000)')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    p.add_argument('--plot', metavar='DIR', help='write histogram.png and sensitivity.png')
    p.add_argument('--validate', type=int, metavar='N',
                   help='also run brute-force Monte Carlo with N (n + 2) model runs')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the analysis and print text or JSON."""
    import json
    import warnings

    import numpy as np

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fileio import atomic_output, refuse_overlap, writable_dir
    from railgsa_ros.models import load_model
    from railgsa_ros.uncertainty.parameters import load_uncertainty, table3
    from railgsa_ros.uncertainty.scenarios import make_scenario
    from railgsa_ros.uncertainty.wiener_scenario import make_wiener_scenario
    from railgsa_ros.uq import AliasingWarning, analyze, validate
    from railgsa_ros.vehicle import VehicleParams, load_vehicle

    if args.order < 1:
        raise ConfigError(f'--order: expected an integer >= 1, got {args.order}')
    if args.validate is not None and args.validate < 2:
        raise ConfigError(f'--validate: expected a number of base samples >= 2, got '
                          f'{args.validate}')
    if args.seed < 0:
        raise ConfigError(f'--seed: expected an integer >= 0, got {args.seed}')
    folder = None
    if args.plot:  # before the analysis: a read-only or missing place fails at once
        refuse_overlap(args.plot, (args.vehicle, args.uncertainty, args.profile[5:]
                                   if args.profile.startswith('file:') else None))
        folder = writable_dir(args.plot)
    model = load_model(args.vehicle) if args.vehicle else None
    if model is not None and model.kind != 'quarter_car':  # a regularised (LMMSE) inverse
        if args.scenario != 'inverse' or args.profile != 'paper':
            raise ConfigError(f'--vehicle: the {model.kind} has the inverse scenario on German '
                              'low track only (no --scenario forward, no --profile)')
        dists = load_uncertainty(args.uncertainty, model)
        scenario: Any = make_wiener_scenario(model, dists, args.time, args.speed,
                                             seed=args.seed)
    else:
        vehicle = load_vehicle(args.vehicle) if args.vehicle else VehicleParams()
        dists = load_uncertainty(args.uncertainty) if args.uncertainty else table3(vehicle)
        scenario = make_scenario(args.scenario, args.time, dists, args.profile, args.speed,
                                 vehicle, args.gain, seed=args.seed)
    names = list(dists)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', AliasingWarning)
        result = analyze(scenario, list(dists.values()), order=args.order, rule=args.rule,
                         seed=args.seed)
    notes = [str(w.message) for w in caught if issubclass(w.category, AliasingWarning)]
    delta = result.delta
    assert delta is not None  # analyze computes it by default
    first, total = result.sobol_first, result.sobol_total
    if not float(result.std) > FLAT_STD:  # shares of a rounding-error variance: undefined
        first = total = delta = np.full(len(names), np.nan)
        notes.append(f'the output does not vary with the parameters at t = {args.time:g} s '
                     f'(std {float(result.std):.3g} {scenario.unit}): the sensitivity indices '
                     'are undefined (NaN); choose a time where the response has begun')
    q = result.quantiles([0.025, 0.5, 0.975])
    out = {
        'scenario': args.scenario, 'time_s': args.time, 'unit': scenario.unit,
        'parameters': {n: {'mean': d.mean(), 'std': d.std()} for n, d in dists.items()},
        'mean': float(result.mean), 'std': float(result.std),
        'quantiles': {'2.5%': float(q[0]), '50%': float(q[1]), '97.5%': float(q[2])},
        **{key: {n: round(x, 6) if np.isfinite(x) else None  # null: undefined
                 for n, x in zip(names, values.tolist(), strict=True)}
           for key, values in (('sobol_first', first), ('sobol_total', total),
                               ('delta', delta))},
        'n_evaluations': result.n_evaluations, 'rule': args.rule, 'order': args.order,
        'fit': result.fit, 'notes': notes,
    }
    if args.validate is not None:
        check = validate(scenario, list(dists.values()), n_base=args.validate, seed=args.seed,
                         result=result)
        out['validation'] = {'n_evaluations': check.monte_carlo.n_evaluations,
                             'cost_ratio': check.cost_ratio, 'errors': check.errors}
    if folder is not None:
        from railgsa_ros.uq.plots import plot_histogram, plot_sensitivities

        label = {'inverse': 'reconstructed irregularity', 'forward': 'car-body acceleration'}
        with atomic_output(folder / 'histogram.png', overwrite=True) as tmp:  # disk full: 1 line
            plot_histogram(result, tmp,
                           f'{label[args.scenario]} at t = {args.time:g} s [{scenario.unit}]')
        with atomic_output(folder / 'sensitivity.png', overwrite=True) as tmp:
            plot_sensitivities(result, names, tmp,
                               f'{args.scenario} simulation, t = {args.time:g} s')
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f'{args.scenario} at t = {args.time:g} s: mean {out["mean"]:.6g} {scenario.unit}, '
          f'std {out["std"]:.4g}, 95 % interval [{q[0]:.6g}, {q[2]:.6g}]')
    print(f'{result.n_evaluations} model runs, rule {args.rule}, order {args.order} '
          f'({result.fit})')
    print(f'{"parameter":<10}{"S_first":>10}{"S_total":>10}{"delta":>10}')
    for i, name in enumerate(names):
        print(f'{name:<10}{first[i]:10.4f}{total[i]:10.4f}'
              f'{delta[i]:10.4f}')
    for note in notes:
        print(f'note: {note}')
    if args.validate is not None:
        v = out['validation']
        errs = ', '.join(f'{k} {e:.4f}' for k, e in v['errors'].items())
        print(f'brute force: {v["n_evaluations"]} runs ({v["cost_ratio"]:.0f}x); errors {errs}')
    return 0
