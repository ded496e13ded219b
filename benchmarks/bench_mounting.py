"""Tilted sensor: dip depths, reported tilt and D1 error against the upright sensor.

A simulated run (ADXL355 model, German low track, three 6 m dips of 4-8 mm) gets car-body
horizontal motion (``mount_sim.horizontal_motion``: braking dv/dt, a curve's cant deficiency,
lateral and longitudinal vibration) and is read by a sensor rotated by a known roll and pitch
(``mount_sim.mounted``). Each row inverts it through the input policy (default spectral D1)
with one ``mounting`` setting and compares with the upright sensor's result on the same run:
the dips' depth ratio, the D1 RMS difference over the VALID samples, the reported tilt.

    python benchmarks/bench_mounting.py [--seed 1] [--duration 150]
"""

from __future__ import annotations

import argparse

import numpy as np

from railgsa_ros.imu import imu_spec
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.mount_sim import horizontal_motion, mounted
from railgsa_ros.samples import pieces
from railgsa_ros.scenario import run_scenario

DIPS = ((1500.0, 8e-3), (2100.0, 4e-3), (2600.0, 6e-3))  # chainage m, depth m


def simulate(seed: int, duration: float, brake: bool):
    # every 10 s: braking at 1 m/s^2 from 40 s, traction at 1 m/s^2 from 80 s
    speed = np.interp(np.linspace(0, 150, 16), [0, 40, 50, 80, 90, 150],
                      [25.0, 25, 15, 15, 25, 25]) if brake else 20.0
    defects = ','.join(f'dip@{x:g}:len=6:depth={d:g}' for x, d in DIPS)
    run = run_scenario('german-low', speed, duration, None,
                       imu_spec('adxl355', dropout_fraction=0.0), seed=seed, defects=defects)
    body = run.accel.copy()
    body[:, :2] += horizontal_motion(run.t_true_s, run.speed_mps, seed,
                                     curve=(40.0, 40.0, 0.6))
    return run, body


def invert(run, accel, **config) -> tuple[Output, InputStage]:
    policy = InputStage(InversionConfig(rate_hz=run.rate_hz, **config))
    outs = [policy.odometry(run.stamps_ns[::20], run.speed_mps[::20])]
    cov = np.zeros((run.stamps_ns.size, 9))
    cov[:, [0, 4, 8]] = run.accel_covariance
    for sl in pieces(run.stamps_ns.size):
        outs.append(policy.imu(run.stamps_ns[sl], accel[sl], None, cov[sl]))
    outs.append(policy.flush())
    return Output.concat(outs), policy


def depths(out: Output) -> np.ndarray:
    return np.array([-np.nanmin(np.where(np.abs(out.chainage_m - x) < 5, out.u_m, np.nan))
                     for x, _ in DIPS])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--duration', type=float, default=150.0)
    args = parser.parse_args()
    print('| motion | roll, pitch deg | mounting | tilt reported deg | dip depth / upright '
          '(min..max) | D1 RMS diff mm | max diff mm (published samples) | '
          'VALID / upright VALID |')
    print('|---|---|---|---|---|---|---|---|')
    for brake in (False, True):
        run, body = simulate(args.seed, args.duration, brake)
        ref, _ = invert(run, body, mounting='axis')
        ref_d, ref_ok = depths(ref), ref.quality == Quality.VALID
        cases = [(0.0, 0.0, 'estimate', {}), (1.5, -1.0, 'axis', {}),
                 (1.5, -1.0, 'estimate', {}), (20.0, -10.0, 'axis', {}),
                 (20.0, -10.0, 'estimate', {}), (-28.0, 18.0, 'estimate', {}),
                 (-28.0, 18.0, 'rotation', {'mount_roll_deg': -28.0, 'mount_pitch_deg': 18.0}),
                 (20.0, -10.0, 'rotation', {'mount_roll_deg': 22.0, 'mount_pitch_deg': -10.0}),
                 (20.0, -10.0, 'rotation', {'mount_roll_deg': 20.0, 'mount_pitch_deg': -5.0})]
        for roll, pitch, mode, extra in cases:
            out, policy = invert(run, mounted(body, roll, pitch), mounting=mode, **extra)
            ok = np.isfinite(out.u_m) & ref_ok  # every published sample, flagged or not
            diff = out.u_m[ok] - ref.u_m[ok] if ok.any() else np.full(1, np.nan)
            ratio = depths(out) / ref_d
            truth = np.degrees(np.arccos(np.cos(np.radians(roll)) * np.cos(np.radians(pitch))))
            print(f'| {"braking, curve" if brake else "curve"} | {roll:g}, {pitch:g} '
                  f'(tilt {truth:.2f}) | {mode} | {policy.mounting.tilt_deg:.2f} | '
                  f'{ratio.min():.4f}..{ratio.max():.4f} | '
                  f'{np.sqrt(np.mean(diff ** 2)) * 1e3:.4f} | {np.max(np.abs(diff)) * 1e3:.4f} | '
                  f'{np.count_nonzero(out.quality == Quality.VALID)} / '
                  f'{np.count_nonzero(ref_ok)} |')


if __name__ == '__main__':
    main()
