"""Coach inversion against its physical limit: D1 RMSE beside the LMMSE posterior of the same run.

A German-spectrum profile (low level, 1-200 m) drives the coach's state space (``lsim``) with
each wheelset's profile at its own position, and ADXL355-like white noise (25 ug/sqrt(Hz) at
1 kHz) and a gyro (``gyro_noise_std_rads``) are added. The pipeline inverts with and without the
pitch rate; the truth is the profile under the reference wheelset through the same zero-phase
D1 band. Printed per case: the run's D1 RMSE, the error std the pipeline reports for its FIR
(``observability.std_m``), the LMMSE limit (``limit_std_m``) and their ratio.

    PYTHONPATH=$PWD python benchmarks/bench_coach_inversion.py [--seconds 120] [--seeds 2]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import fft, signal

from railgsa_ros.config import load_yaml
from railgsa_ros.inverse.band import band_edges_hz, bandpass_power
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.models import load_model
from railgsa_ros.models.coach import CoachModel
from railgsa_ros.track import german_psd, synthesize

RATE_HZ = 1000.0
ACCEL_STD = 25e-6 * 9.80665 * np.sqrt(RATE_HZ / 2)  # ADXL355: 25 ug/sqrt(Hz), m/s^2 per sample
EDGE_S = 30.0  # seconds left out at each end of a run (fade-in, the FIR's reach, the tail)


def coach_at(x_imu_m: float) -> CoachModel:
    """The shipped coach with its primary IMU x_imu_m (m) forward of the car-body centre."""
    doc = load_yaml('config/vehicles/coach.yaml')
    model = load_model({**doc, 'imus': [{'name': 'imu', 'x_m': x_imu_m}]})
    assert isinstance(model, CoachModel)
    return model


def simulate(model: CoachModel, speed: float, seconds: float, seed: int, gyro_std: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(accel (T,) m/s^2 with gravity, pitch rate (T,) rad/s, truth u under the reference
    wheelset (T,) m) at constant speed, noise added."""
    offsets = model.wheel_offsets_m
    length = speed * seconds + offsets.max() - offsets.min() + 10.0
    x, u = synthesize(german_psd, length, 0.02, seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    x_ref = offsets.max() + 5.0 + speed * t
    wheels = np.stack([np.interp(x_ref - d, x, u) for d in offsets], axis=1)  # (T, 4)
    a, b, c, d = model.state_space(model.theta)
    y = signal.lsim((a, b, c, d), wheels, t)[1]
    rng = np.random.default_rng(seed + 1000)
    accel = y[:, 0] + 9.80665 + rng.normal(0.0, ACCEL_STD, t.size)
    rate = y[:, 1] + rng.normal(0.0, gyro_std, t.size)
    return accel, rate, np.interp(x_ref, x, u)


def band_truth(u: np.ndarray, speed: float, config: InversionConfig) -> np.ndarray:
    """u through the zero-phase band |BP|^2 at the speed (FFT of the zero-padded record)."""
    n = fft.next_fast_len(2 * u.size, real=True)
    f = fft.rfftfreq(n, 1.0 / RATE_HZ)
    power = bandpass_power(f, *band_edges_hz(config.band, speed), config.band_order)
    return fft.irfft(fft.rfft(u, n) * power, n)[:u.size]


def d1_rmse(model: CoachModel, speed: float, seconds: float, seed: int, pitch: bool,
            config: InversionConfig) -> tuple[float, InversionPipeline]:
    """D1 RMSE (m) of one simulated run away from its ends, and the pipeline that made it."""
    accel, rate, u = simulate(model, speed, seconds, seed, config.gyro_noise_std_rads)
    channels = ('accel_z', 'pitch_rate') if pitch else ('accel_z',)
    pipe = InversionPipeline(config, model=model, channels=channels,
                             noise_variance=ACCEL_STD ** 2)
    stamps = (np.arange(accel.size) * 1e9 / RATE_HZ).astype(np.int64)
    kw = {'rates': rate} if pitch else {}
    outs = [pipe.push(stamps, accel, speed, **kw), pipe.flush()]
    est = np.concatenate([o.u_m for o in outs])
    keep = slice(int(EDGE_S * RATE_HZ), accel.size - int(EDGE_S * RATE_HZ))
    err = est[keep] - band_truth(u, speed, config)[keep]
    return float(np.sqrt(np.mean(err ** 2))), pipe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=120.0)
    parser.add_argument('--seeds', type=int, default=2)
    args = parser.parse_args()
    config = InversionConfig(noise_std_mps2=ACCEL_STD)
    print('| IMU | v m/s | pitch rate | D1 RMSE mm | reported mm | LMMSE limit mm | ratio |')
    print('|---|---|---|---|---|---|---|')
    for where, x_imu in (('above leading bogie', 9.5), ('car centre', 0.0)):
        model = coach_at(x_imu)
        for speed in (20.0, 40.0):
            for pitch in (False, True):
                runs = [d1_rmse(model, speed, args.seconds, s, pitch, config)
                        for s in range(args.seeds)]
                rmse = float(np.sqrt(np.mean([r[0] ** 2 for r in runs])))
                obs = runs[0][1].observability
                assert obs is not None
                rep, lim = float(obs.std_m(speed)), float(obs.limit_std_m(speed))
                print(f'| {where} | {speed:g} | {"yes" if pitch else "no"} | {rmse * 1e3:.4f} '
                      f'| {rep * 1e3:.4f} | {lim * 1e3:.4f} | {rmse / lim:.2f} |')


if __name__ == '__main__':
    main()
