"""In-core throughput of the inversion methods against scipy.signal.sosfilt in the same run.

Each method runs the streaming ``InversionPipeline`` (sanitiser, chainage, method, D1 band FIR)
over the same samples, pushed in chunks as ``railgsa invert`` does, flush included, once with the
band FIR at the input rate (``multirate: false``) and once at fs / R (``multirate: true``). The
floor is ``scipy.signal.sosfilt`` over the same samples with a filter of equal order: the order of
the rational filter the method realises, 4 n for the zero-phase band |BP|^2 (prototype order n)
plus the states of its model (4 for the quarter vehicle, 7 for the Kalman model). Ratio = method
time / floor time (lower is better). A second floor is the FIR work itself:
``scipy.signal.oaconvolve`` of the same samples with a single-rate band FIR of the same delay
(2 D + 1 taps per parameter set), offline. Times are the best of ``--repeat`` runs, pipeline
construction (filter design) included. ``push(1)`` is the mean cost of pushing one sample at a
time (the node's worst case) once the delay line is full.

Usage: python benchmarks/bench_inverse_throughput.py [--seconds 600] [--rate 1000] [--bank 19]
(OPENBLAS_NUM_THREADS=1 avoids oversubscribing shared cores.)
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import time

import numpy as np
from scipy import signal

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.kalman import N_STATE
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.vehicle import VehicleParams

CHUNK = 65536
SINGLE_PUSHES = 2000  # one-sample pushes timed after the delay line is full
STATES = {'spectral': 4, 'feedback': 4, 'kalman': N_STATE}


def best_time(func: Callable[[], object], repeat: int) -> float:
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
    parser.add_argument('--methods', nargs='+', default=list(STATES), choices=list(STATES))
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

    def push_cost(cfg: InversionConfig, vehicle: np.ndarray) -> float:
        """Mean time (s) of a one-sample push with the delay line full."""
        pipe = InversionPipeline(cfg, vehicle)
        start = pipe.delay_samples + 1
        pipe.push(stamps[:start], acc[:start], args.speed)
        t0 = time.perf_counter()
        for i in range(start, start + SINGLE_PUSHES):
            pipe.push(stamps[i:i + 1], acc[i:i + 1], args.speed)
        return (time.perf_counter() - t0) / SINGLE_PUSHES

    print(f'{n} samples at {args.rate:g} Hz, {args.speed:g} m/s, D1 band, chunks of {CHUNK}')
    print('| method | band FIR | P | order | samples/s | sosfilt samples/s | ratio | '
          'oaconvolve samples/s | ratio | push(1) us |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    for method in args.methods:
        single = InversionConfig(method=method, rate_hz=args.rate, frame_id='', multirate=False)
        order = 4 * single.band_order + STATES[method]
        sos = signal.butter(order, 0.1, output='sos')
        for p, vehicle in ((1, nominal), (args.bank, bank)):
            x = np.broadcast_to(acc, (p, n))
            taps = np.ones((1, 2 * InversionPipeline(single, vehicle).delay_samples + 1))
            for cfg in (single, single.with_(multirate=True)):
                pipe = InversionPipeline(cfg, vehicle)
                if pipe.decimation == 1 and cfg.multirate:
                    continue  # R < 2: the multirate row would repeat the single-rate one
                fir = f'{taps.size} taps at fs' if pipe.decimation == 1 else (
                    f'{pipe.band_taps} taps at fs/{pipe.decimation}')
                t_method = best_time(lambda c=cfg, v=vehicle: pipeline_run(c, v), args.repeat)
                t_floor = best_time(lambda s=sos, x=x: signal.sosfilt(s, x, axis=-1),
                                    args.repeat)
                t_fir = best_time(lambda x=x, h=taps: signal.oaconvolve(x, h, axes=-1),
                                  args.repeat)
                t_push = push_cost(cfg, vehicle)
                print(f'| {method} | {fir} | {p} | {order} | {n / t_method:.3g} | '
                      f'{n / t_floor:.3g} | {t_method / t_floor:.1f} | {n / t_fir:.3g} | '
                      f'{t_method / t_fir:.2f} | {t_push * 1e6:.0f} |')


if __name__ == '__main__':
    main()
