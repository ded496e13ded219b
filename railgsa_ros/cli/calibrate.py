"""``railgsa calibrate BAG --reference PROFILE.csv``: vehicle parameters from a surveyed stretch.

Estimates the identifiable parameters (k_s and c by default: docs/uq.md, "Calibration") by
Gauss-Newton with a Gaussian prior (``railgsa_ros.calibrate``) on the stretch the reference
covers, and writes a vehicle YAML (``--vehicle`` of every entry point, ``vehicle_file`` of the
nodes) and an uncertainty YAML (``--uncertainty``, ``uncertainty_file``) of the posterior, with
the model discrepancy the calibrated band still leaves on that stretch (``discrepancy_std_m``,
``railgsa_ros.calibrate.discrepancy_std``) that every band adds in variance. With
``--fit-delay`` it also fits the sensor delay (from ``--sensor-delay``, the chip's datasheet
setting, as prior centre) and writes it with its posterior std to a ROS params file
(``--out-params``: ``/**: ros__parameters: sensor_delay_s, delay_std_s``; a copy of
``--base-params``, the file the runs use, with those set) that ``--params`` of every command and
the nodes read.
"""

from __future__ import annotations

import argparse

TOLD_APART = 0.9  # |posterior correlation| of delay and registration beyond which --fit-delay
# refuses: the delay would be the prior's (measured: +0.99 at constant speed with a 2 m prior,
# +0.78 with a 1 cm one, where the fit is within 0.05 ms of the filter's delay)


def register(subparsers: argparse._SubParsersAction) -> None:
    from railgsa_ros.cli.review import add_topic_options

    p = subparsers.add_parser('calibrate', help='vehicle parameters from a reference run',
                              description=__doc__.splitlines()[0])
    p.add_argument('bag', help='rosbag2 bag (directory or file) of the run')
    p.add_argument('--reference', required=True, metavar='CSV',
                   help='surveyed profile: CSV with the header x_m,u_m (chainage from the '
                        'first IMU sample of the bag, plus --offset)')
    p.add_argument('--offset', type=float, default=0.0, metavar='M',
                   help='bag chainage of the reference chainage 0, m (default 0)')
    p.add_argument('--parameters', default='k_s,c', metavar='NAMES',
                   help='parameters to calibrate, comma-separated (default k_s,c)')
    p.add_argument('--vehicle', metavar='YAML', help='nominal vehicle (default Table 1)')
    p.add_argument('--uncertainty', metavar='YAML',
                   help='prior law of the parameters (default Table 3)')
    p.add_argument('--uncertainty-params', metavar='FILE',
                   help='ROS params file with uncertainty_node: ros__parameters: (the band '
                        'terms, e.g. clock_std_ppm, delay_std_s, of the band the discrepancy '
                        'is measured against: give the file the bands run with; default: '
                        'the node defaults)')
    p.add_argument('--fit-delay', action='store_true',
                   help='also fit the sensor delay (needs --out-params; told apart from the '
                        "reference's registration only by speed changes or --registration-sd)")
    p.add_argument('--sensor-delay', metavar='S|CHIP@ODR',
                   help='the delay to start from (prior centre, std 20 ms): seconds or the '
                        "chip's datasheet setting, e.g. bmi088@400Hz (default 0)")
    p.add_argument('--registration-sd', type=float, default=2.0, metavar='M',
                   help="prior std of the reference's registration, m (default 2: a survey "
                        'registered to a metre or two)')
    p.add_argument('--out-params', metavar='YAML',
                   help='ROS params file for the fitted delay (with --fit-delay)')
    p.add_argument('--base-params', metavar='YAML',
                   help='the params file the runs use, copied into --out-params with the delay '
                        'set under "/**" (default: a file with the delay alone)')
    p.add_argument('--speed', type=float, help='constant speed in m/s, overriding odometry')
    add_topic_options(p)
    p.add_argument('--out-vehicle', required=True, metavar='YAML')
    p.add_argument('--out-uncertainty', required=True, metavar='YAML')
    p.add_argument('--overwrite', action='store_true')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import yaml

    from railgsa_ros.bag import read_imu
    from railgsa_ros.calibrate import calibrate, discrepancy_std
    from railgsa_ros.cli._params import uncertainty_params
    from railgsa_ros.cli.invert import sensor_delay
    from railgsa_ros.errors import ConfigError, InputError
    from railgsa_ros.fileio import atomic_output
    from railgsa_ros.input.mounting import Mounting
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.track import load_csv
    from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands
    from railgsa_ros.uncertainty.parameters import load_uncertainty, parse_parameter, table3
    from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams, load_vehicle

    if args.fit_delay != (args.out_params is not None):
        raise ConfigError('--fit-delay and --out-params go together: the fitted delay is '
                          'written to the params file')
    if not args.registration_sd > 0:
        raise ConfigError(f'--registration-sd: expected metres > 0, got {args.registration_sd!r}')
    names = tuple(n.strip() for n in args.parameters.split(',') if n.strip())
    bad = [n for n in names if n not in PARAM_NAMES]
    if bad or not names:
        raise ConfigError(f'--parameters: expected some of {", ".join(PARAM_NAMES)}, got '
                          f'{args.parameters!r}')
    vehicle = load_vehicle(args.vehicle) if args.vehicle else VehicleParams()
    prior = load_uncertainty(args.uncertainty) if args.uncertainty else table3(vehicle)
    terms = (uncertainty_params(args.uncertainty_params, 'calibrate') if args.uncertainty_params
             else UncertaintyConfig())  # the band's terms; its inversion is the bag's below
    ref_x, ref_u = load_csv(args.reference)
    stream = read_imu(args.bag, args.imu_topic, args.odom_topic)
    steps = np.diff(stream.stamps_ns)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f'{args.bag}: {args.imu_topic} needs at least two distinct stamps')
    config = InversionConfig(rate_hz=1e9 / float(np.median(steps)),
                             sensor_delay_s=sensor_delay(args.sensor_delay or '0'))
    if args.speed is not None:
        speed = np.full(stream.stamps_ns.size, args.speed)
    elif stream.odom_stamps_ns.size:
        idx = np.searchsorted(stream.odom_stamps_ns, stream.stamps_ns, side='right') - 1
        speed = stream.speed_mps[np.clip(idx, 0, None)]
    else:
        raise InputError(f'{args.bag}: no odometry on {args.odom_topic}; give --speed')
    reference = (ref_x + args.offset, ref_u)
    up, _ = Mounting(config).vertical(stream.accel, np.isfinite(stream.accel).all(axis=1))
    cal = calibrate(stream.stamps_ns, up, speed, reference, config, vehicle, prior, names,
                    args.fit_delay, args.registration_sd)
    if args.fit_delay:
        if abs(cal.delay_shift_corr) >= TOLD_APART:
            raise InputError(f'calibrate: the sensor delay is not told apart from the '
                             f"reference's registration (correlation "
                             f'{cal.delay_shift_corr:+.2f}: at constant speed they are one '
                             'shift); give --registration-sd of a registered reference, a run '
                             'with speed changes, or leave out --fit-delay')
        config = config.with_(sensor_delay_s=cal.delay_s)
    theta = dict(zip(PARAM_NAMES, (float(v) for v in cal.theta), strict=True))
    posterior = {'names': list(cal.names), 'mean': [float(m) for m in cal.mean],
                 'covariance': [[float(c) for c in row] for row in cal.covariance]}
    uncertain = {**{n: d for n, d in _prior_entries(prior).items() if n not in names},
                 **cal.uncertainty()}
    ucfg = terms.with_(inversion=config, qoi='')
    band = offline_bands(stream.stamps_ns, stream.accel, (stream.stamps_ns, speed),
                         covariance=stream.covariance, config=ucfg, vehicle=cal.vehicle(),
                         dists={n: parse_parameter(n, d) for n, d in uncertain.items()})
    registered = (reference[0] - cal.shift_m, ref_u)  # the fitted registration applied
    discrepancy = discrepancy_std(band, registered, config,
                                  (ucfg.lower_quantile, ucfg.upper_quantile))
    law = {'parameters': uncertain, 'discrepancy_std_m': discrepancy, 'posterior': posterior}
    outputs = [(args.out_vehicle, {'vehicle': theta}), (args.out_uncertainty, law)]
    if args.fit_delay:
        outputs.append((args.out_params, _with_delay(args.base_params, cal.delay_s,
                                                     cal.delay_sd_s)))
    for path, doc in outputs:
        with atomic_output(path, args.overwrite) as tmp:
            tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    std = np.sqrt(np.diag(cal.covariance))
    for n, m, s in zip(cal.names, cal.mean, std, strict=True):
        print(f'{n} = {m:.6g} +- {s:.3g} ({100 * s / m:.2f} %)')
    print(f'reference shifted by {cal.shift_m:+.3f} +- {cal.shift_sd_m:.3f} m on top of '
          f'--offset (its registration, fitted with the parameters)')
    print(f'D1 residual on {cal.points} samples: {cal.rmse_before_m * 1e3:.4f} -> '
          f'{cal.rmse_after_m * 1e3:.4f} mm; Fisher condition number {cal.condition:.3g}')
    print(f'model discrepancy beyond the calibrated band: {discrepancy * 1e3:.4f} mm '
          '(discrepancy_std_m)')
    if args.fit_delay:
        print(f'sensor delay {cal.delay_s * 1e3:.3f} +- {cal.delay_sd_s * 1e3:.3f} ms '
              f'(sensor_delay_s, delay_std_s in {args.out_params}); correlation with the '
              f'registration {cal.delay_shift_corr:+.2f}')
    return 0


def _with_delay(base: str | None, delay_s: float, delay_sd_s: float) -> dict:
    """The params file ``base`` (None: empty) with ``sensor_delay_s`` and ``delay_std_s`` set
    under ``/**`` (both nodes, any namespace: where the inversion's shared values go)."""
    from railgsa_ros.config import load_yaml
    from railgsa_ros.errors import ConfigError

    doc = load_yaml(base) if base else {}
    shared = doc.setdefault('/**', {}) if isinstance(doc, dict) else None
    params = shared.setdefault('ros__parameters', {}) if isinstance(shared, dict) else None
    if not isinstance(params, dict):
        raise ConfigError(f'{base}: expected a ROS params file (a mapping of node sections with '
                          'ros__parameters: mappings)')
    params.update(sensor_delay_s=delay_s, delay_std_s=delay_sd_s)
    return doc


def _prior_entries(prior) -> dict[str, dict[str, str | float]]:
    """Uncertainty-file entries of the prior's normal laws (others are left out)."""
    from railgsa_ros.uq.distributions import Normal

    return {n: {'dist': 'normal', 'mu': d.mu, 'sigma': d.sigma} for n, d in prior.items()
            if isinstance(d, Normal)}
