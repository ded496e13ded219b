"""In-core throughput of the inversion methods against scipy.signal.sosfilt in the same run.

Each method runs the streaming ``InversionPipeline`` (sanitiser, chainage, method, D1 band FIR)
over the same samples, pushed in chunks as ``railgsa invert`` does, flush included. The floor is
``scipy.signal.sosfilt`` over the same samples with a filter of equal order: the order of the
rational filter the method realises, 4 n for the zero-phase band |BP|^2 (prototype order n) plus
the states of its model (4 for the quarter vehicle, 7 for the Kalman model). Ratio = method time /
floor time (lower is better). A second floor is the FIR work itself: ``scipy.signal.oaconvolve``
of the same samples with the method's band FIR (2 D + 1 taps, per parameter set), offline. Times
are the best of ``--repeat`` runs, pipeline construction (filter design) included.

Usage: python benchmarks/bench_inverse_throughput.py [--seconds 600] [--rate 1000] [--bank 19]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import signal

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.kalman import N_STATE
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.vehicle import VehicleParams

CHUNK = 65536
STATES = {'spectral': 4, 'feedback': 4, 'kalman': N_STATE}


def best_time(func, repeat: int) -> float:
    """Shortest wall time (s) of ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=600.0, help='record length, s')
    parser.add_argument('--rate', type=float, default=1000.0, help='IMU rate, Hz')
    parser.add_argument('--speed', type=float, default=20.0, help='m/s')
    parser.add_argument('--bank', type=int, default=19, help='parameter sets of the bank rows')
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    n = int(args.seconds * args.rate)
    rng = np.random.default_rng(0)
    stamps = np.round(np.arange(n) * 1e9 / args.rate).astype(np.int64)
    acc = 9.80665 + 0.05 * rng.standard_normal(n)
    nominal = VehicleParams().as_array()
    bank = nominal * rng.uniform(0.8, 1.2, (args.bank, 5))

    def pipeline_run(cfg: InversionConfig, vehicle: np.ndarray) -> None:
        pipe = InversionPipeline(cfg, vehicle)
        for i in range(0, n, CHUNK):
            pipe.push(stamps[i:i + CHUNK], acc[i:i + CHUNK], args.speed)
        pipe.flush()

    print(f'{n} samples at {args.rate:g} Hz, {args.speed:g} m/s, D1 band, chunks of {CHUNK}')
    print('| method | P | order | FIR taps | samples/s | sosfilt samples/s | ratio | '
          'oaconvolve samples/s | ratio |')
    print('|---|---|---|---|---|---|---|---|---|')
    for method in ('spectral', 'feedback', 'kalman'):
        cfg = InversionConfig(method=method, rate_hz=args.rate, frame_id='')
        order = 4 * cfg.band_order + STATES[method]
        sos = signal.butter(order, 0.1, output='sos')
        for p, vehicle in ((1, nominal), (args.bank, bank)):
            t_method = best_time(lambda c=cfg, v=vehicle: pipeline_run(c, v), args.repeat)
            x = np.broadcast_to(acc, (p, n))
            t_floor = best_time(lambda s=sos, x=x: signal.sosfilt(s, x, axis=-1), args.repeat)
            taps = np.ones((1, 2 * InversionPipeline(cfg, vehicle).delay_samples + 1))
            t_fir = best_time(lambda x=x, h=taps: signal.oaconvolve(x, h, axes=-1), args.repeat)
            print(f'| {method} | {p} | {order} | {taps.size} | {n / t_method:.3g} | '
                  f'{n / t_floor:.3g} | {t_method / t_floor:.1f} | {n / t_fir:.3g} | '
                  f'{t_method / t_fir:.1f} |')


if __name__ == '__main__':
    main()
