"""Accuracy of the inversion methods against the exact-physics baseline of the same run.

(a) Paper mode: noise-free nominal vehicle, the paper's profile at 10 m/s, feedback (Eq. 7,
    K = 1000) with no band: relative error max|u_rec - u| / max|u| (target <= 1e-3).
(b) ADXL355 sensor model, German low profile plus an 8 mm cosine dip over 6 m, a 3 mm dipped joint
    and a 0.3 mm weld, 800 m at 10, 20 and 40 m/s, odometry speed: every method with its default
    parameters, scored on distance in D1 (score.score: both signals reach the score in D1 once,
    100 m left out at each end): RMSE (target <= 0.3 mm), correlation (>= 0.95) and peak error
    on the 8 mm dip (<= 0.5 mm). Baseline: FFT of the whole record divided by G(j w), D1-limited.
(c) The multirate band stage (default) against the single-rate FIR (``multirate: false``) on the
    runs of (b): scores of both and the largest and RMS difference of the outputs (mm), both
    samples of the same stamps, the first and last 100 m left out.

Usage: python benchmarks/bench_inverse_accuracy.py [--length 800] [--seed 1]
"""

from __future__ import annotations

import argparse

import numpy as np

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, vertical
from railgsa_ros.inverse.score import exact_inverse, score
from railgsa_ros.scenario import run_scenario
from railgsa_ros.simulate import simulate
from railgsa_ros.track import paper_profile
from railgsa_ros.vehicle import VehicleParams

DIP = (300.0, 6.0)
DEFECTS = f'dip@{DIP[0]:g}:len={DIP[1]:g}:depth=8e-3,joint@450,weld@600'
METHODS = {'spectral (default)': {'method': 'spectral'}, 'feedback': {'method': 'feedback'},
           'kalman (live)': {'method': 'kalman'},
           'kalman + RTS smoother': {'method': 'kalman', 'smoother': True}}


def paper_mode() -> float:
    """Relative error of the feedback inversion of the paper profile, noise-free, no band."""
    dt = 1e-3
    t = np.arange(0.0, 14.0, dt)
    u = paper_profile(10.0 * t)
    a_s, _ = simulate(u, dt, VehicleParams())
    cfg = InversionConfig(method='feedback', band='none', taper_s=0.0)
    out = InversionPipeline(cfg).push(np.round(t * 1e9).astype(np.int64),
                                      a_s + cfg.gravity_mps2, 10.0)
    return float(np.max(np.abs(out.u_m - u)) / np.max(np.abs(u)))


def reconstruct(run, overrides: dict) -> tuple[np.ndarray, np.ndarray]:
    """Run the streaming pipeline over a simulated run (odometry = the run's speed)."""
    pipe = InversionPipeline(InversionConfig(**overrides), noise_variance=run.accel_covariance)
    acc = vertical(run.accel, 'z')
    outs = [pipe.push(run.stamps_ns, acc, run.speed_mps), pipe.flush()]
    chain = np.concatenate([o.chainage_m for o in outs]) + run.chainage_m[0]
    return chain, np.concatenate([o.u_m for o in outs])


def row(name: str, speed: float, s, base_rmse: float) -> str:
    ok = s.rmse <= 0.3e-3 and s.correlation >= 0.95 and s.peak_error <= 0.5e-3
    return (f'| {speed:4.0f} | {name:<22} | {s.rmse * 1e3:8.4f} | {s.correlation:7.4f} | '
            f'{s.peak_error * 1e3:8.4f} | {s.rmse / base_rmse:6.2f} | {"yes" if ok else "no":4} |')


def difference(single: tuple[np.ndarray, np.ndarray], multi: tuple[np.ndarray, np.ndarray],
               margin_m: float = 100.0) -> tuple[float, float]:
    """Largest and RMS difference (m) of two reconstructions of the same samples."""
    chain = single[0]
    keep = (chain >= chain[0] + margin_m) & (chain <= chain[-1] - margin_m)
    diff = multi[1][keep] - single[1][keep]
    return float(np.max(np.abs(diff))), float(np.sqrt(np.mean(diff ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--length', type=float, default=800.0, help='track length, m')
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args()
    err = paper_mode()
    print(f'(a) paper mode, feedback K = 1000, no band, 10 m/s: relative error {err:.2e} '
          f'(target <= 1e-3: {"yes" if err <= 1e-3 else "no"})\n')
    print('(b) ADXL355, German low + 8 mm dip / 3 mm joint / 0.3 mm weld, D1 on distance')
    print('| v m/s | method                 | RMSE mm | corr    | dip peak mm | / base | pass |')
    print('|---|---|---|---|---|---|---|')
    rates = []
    for speed in (10.0, 20.0, 40.0):
        run = run_scenario('german-low', speed, args.length / speed, None, 'adxl355',
                           seed=args.seed, defects=DEFECTS)
        base = exact_inverse(run.stamps_ns, vertical(run.accel, 'z'), speed)
        b = score(run.chainage_m, base, run.chainage_m, run.truth_u_m, defect=DIP)
        for name, overrides in METHODS.items():
            multi = reconstruct(run, overrides)
            s = score(*multi, run.chainage_m, run.truth_u_m, defect=DIP)
            print(row(name, speed, s, b.rmse))
            single = reconstruct(run, {**overrides, 'multirate': False})
            s1 = score(*single, run.chainage_m, run.truth_u_m, defect=DIP)
            rates.append((speed, name, s1.rmse, s.rmse, *difference(single, multi)))
        print(row('exact baseline (FFT)', speed, b, b.rmse))
    print('\n(c) multirate band stage against the single-rate FIR, same runs')
    print('| v m/s | method                 | RMSE single mm | RMSE multirate mm | '
          'max diff mm | RMS diff mm |')
    print('|---|---|---|---|---|---|')
    for speed, name, rmse1, rmse, big, rms in rates:
        print(f'| {speed:4.0f} | {name:<22} | {rmse1 * 1e3:8.4f} | {rmse * 1e3:8.4f} | '
              f'{big * 1e3:9.5f} | {rms * 1e3:9.5f} |')


if __name__ == '__main__':
    main()
